"""Trains one relocalisation network on frames rendered by `relocd render`.

    python models/train.py --train DATA/train [DATA/train-realism ...] --val DATA/val [...] \
        --arch squeezenet --width 0.5 --representation half-point --epochs 20 --seed 1 \
        --out models/build/squeezenet-half-point

Several training (or validation) recordings are concatenated in the order given.

Loss (no hand-tuned weights): a per-frame Gaussian negative log-likelihood for the position and a von
Mises one for the heading, each with its own predicted uncertainty (Kendall & Gal 2017's heteroscedastic
form, which balances the tasks by itself and gives every frame a confidence), weighted by the detached
sigma^(2*beta) as in beta-NLL (Seitzer et al. 2022) so that hard frames are not simply given up; plus
binary cross-entropy per fold bit. Augmentation: horizontal flips (a flipped image is the long-axis
mirror pose), brightness, contrast, white balance and noise.
"""

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from relocnet.data import load_recordings
from relocnet.fold import fold, mirror_long_axis
from relocnet.nets import RelocNet, count_macs, count_parameters

BETA = 0.5


def folded_targets(poses, representation, flipped):
    x, y, theta = poses[:, 0], poses[:, 1], poses[:, 2]
    if flipped:
        x, y, theta = mirror_long_axis(x, y, theta)
    fx, fy, ftheta, bits = fold(x, y, theta, representation)
    return torch.tensor(np.stack([fx, fy, np.cos(ftheta), np.sin(ftheta)], 1), dtype=torch.float32), torch.tensor(bits)


def to_input(images_uint8):
    """uint8 NHWC -> normalised float NCHW, exactly as relocd's preprocessing: (rgb / 255 - 0.5) / 0.25."""
    x = images_uint8.permute(0, 3, 1, 2).float().div_(255.0)
    return x.sub_(0.5).div_(0.25).contiguous(memory_format=torch.channels_last)


def augment_photometric(x, generator):
    """Brightness, contrast, per-channel gain and noise on normalised inputs."""
    n = x.shape[0]
    rgb = x * 0.25 + 0.5
    gain = torch.empty(n, 1, 1, 1).uniform_(0.75, 1.25, generator=generator)
    channel = torch.empty(n, 3, 1, 1).uniform_(0.9, 1.1, generator=generator)
    contrast = torch.empty(n, 1, 1, 1).uniform_(0.8, 1.2, generator=generator)
    mean = rgb.mean(dim=(1, 2, 3), keepdim=True)
    rgb = (rgb - mean) * contrast + mean
    rgb = rgb * gain * channel
    noise = torch.empty(n, 1, 1, 1).uniform_(0.0, 0.02, generator=generator)
    rgb = rgb + torch.randn(rgb.shape, generator=generator) * noise
    return ((rgb.clamp(0, 1) - 0.5) / 0.25).contiguous(memory_format=torch.channels_last)


def losses(outputs, targets, bits):
    position, heading, fold_logits, log_sigma, log_kappa = outputs
    squared = ((position - targets[:, :2]) ** 2).sum(1, keepdim=True)
    sigma_sq = torch.exp(2 * log_sigma)
    position_nll = squared / (2 * sigma_sq) + 2 * log_sigma
    position_loss = (position_nll * sigma_sq.detach() ** BETA).mean()
    cos_error = (heading * targets[:, 2:4]).sum(1, keepdim=True)
    kappa = torch.exp(log_kappa)
    heading_nll = kappa * (1 - cos_error) + torch.log(torch.special.i0e(kappa)) + 0.5 * math.log(2 * math.pi)
    heading_loss = (heading_nll * (1 / kappa.detach()) ** BETA).mean()
    fold_loss = F.binary_cross_entropy_with_logits(fold_logits, bits) if bits.shape[1] else position.new_zeros(())
    return position_loss, heading_loss, fold_loss


@torch.no_grad()
def evaluate(net, images, targets, bits, batch=256):
    net.eval()
    location, heading, fold_error = [], [], []
    for start in range(0, len(images), batch):
        x = to_input(images[start : start + batch])
        position, head, fold_logits, _, _ = net(x)
        t = targets[start : start + batch]
        location.append((position - t[:, :2]).norm(dim=1))
        heading.append(torch.rad2deg(torch.acos((head * t[:, 2:4]).sum(1).clamp(-1, 1))))
        if bits.shape[1]:
            fold_error.append(((torch.sigmoid(fold_logits) > 0.5).float() != bits[start : start + batch]).float().mean(1))
    net.train()
    result = {
        "location_median_m": torch.cat(location).median().item(),
        "location_mean_m": torch.cat(location).mean().item(),
        "heading_median_deg": torch.cat(heading).median().item(),
        "heading_mean_deg": torch.cat(heading).mean().item(),
    }
    if fold_error:
        result["fold_error_mean"] = torch.cat(fold_error).mean().item()
    return result


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--train", required=True, type=Path, nargs="+", help="training recordings (concatenated)")
    parser.add_argument("--val", required=True, type=Path, nargs="+", help="validation recordings (concatenated)")
    parser.add_argument("--arch", choices=["squeezenet", "alexnet"], default="squeezenet")
    parser.add_argument("--width", type=float, default=0.5)
    parser.add_argument("--representation", default="half-point")
    parser.add_argument("--epochs", type=int, default=20)
    parser.add_argument("--batch", type=int, default=64)
    parser.add_argument("--lr", type=float, default=3e-3)
    parser.add_argument("--weight-decay", type=float, default=1e-4)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--limit", type=int, default=0, help="use only the first N frames of each training recording (0: all)")
    parser.add_argument("--init", type=Path, help="continue from this run directory's weights.pt (a new schedule)")
    parser.add_argument("--out", required=True, type=Path)
    args = parser.parse_args()

    torch.manual_seed(args.seed)
    np.random.seed(args.seed)
    torch.set_num_threads(args.threads)
    generator = torch.Generator().manual_seed(args.seed)
    args.out.mkdir(parents=True, exist_ok=True)

    train_images, train_poses = load_recordings(args.train, args.limit)
    val_images, val_poses = load_recordings(args.val)
    train_images = torch.from_numpy(train_images)
    targets = [folded_targets(train_poses, args.representation, flipped) for flipped in (False, True)]
    val_targets, val_bits = folded_targets(val_poses, args.representation, False)
    val_images = torch.from_numpy(val_images)

    net = RelocNet(args.arch, args.width, args.representation).to(memory_format=torch.channels_last)
    if args.init:
        net.load_state_dict(torch.load(args.init / "weights.pt"))
        print(f"continuing from {args.init}")
    macs, parameters = count_macs(net), count_parameters(net)
    print(f"{args.arch} width {args.width} {args.representation}: {macs / 1e6:.1f} M MACs, {parameters / 1e6:.2f} M parameters")
    steps_per_epoch = len(train_images) // args.batch
    optimiser = torch.optim.AdamW(net.parameters(), lr=args.lr, weight_decay=args.weight_decay)
    schedule = torch.optim.lr_scheduler.OneCycleLR(
        optimiser, max_lr=args.lr, total_steps=args.epochs * steps_per_epoch, pct_start=0.15
    )
    log = {"args": {k: str(v) for k, v in vars(args).items()}, "macs": macs, "parameters": parameters, "epochs": []}
    if args.init:
        earlier = json.loads((args.init / "training.json").read_text())
        log["continued_from"] = {"run": args.init.name, "epochs": len(earlier["epochs"]),
                                 "train_seconds": earlier["train_seconds"], "lr": earlier["args"]["lr"]}
    started = time.time()
    for epoch in range(args.epochs):
        order = torch.randperm(len(train_images), generator=generator)
        totals = torch.zeros(3)
        for step in range(steps_per_epoch):
            index = order[step * args.batch : (step + 1) * args.batch]
            flip = torch.rand(len(index), generator=generator) < 0.5
            images = train_images[index]
            images = torch.where(flip[:, None, None, None], images.flip(2), images)
            t = torch.where(flip[:, None], targets[1][0][index], targets[0][0][index])
            b = torch.where(flip[:, None], targets[1][1][index], targets[0][1][index])
            x = augment_photometric(to_input(images), generator)
            parts = losses(net(x), t, b)
            loss = sum(parts)
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
            schedule.step()
            totals += torch.tensor([p.item() for p in parts])
        metrics = evaluate(net, val_images, val_targets, val_bits)
        entry = {"epoch": epoch + 1, "seconds": round(time.time() - started, 1), "loss": (totals / steps_per_epoch).tolist(), "val": metrics}
        log["epochs"].append(entry)
        print(json.dumps(entry), flush=True)
        torch.save(net.state_dict(), args.out / "weights.pt")
    log["train_seconds"] = round(time.time() - started, 1)
    (args.out / "training.json").write_text(json.dumps(log, indent=1))


if __name__ == "__main__":
    main()
