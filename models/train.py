"""Trains one relocalisation network on frames rendered by `relocd render`.

    python models/train.py --train DATA/train [DATA/train-realism ...] --val DATA/val [...] \
        --arch squeezenet --width 0.5 --representation half-point --epochs 20 --seed 1 \
        --out models/build/squeezenet-half-point [--device auto|cuda|cpu]

Several training (or validation) recordings are concatenated in the order given. `--init RUN` continues
a run from its weights.pt, `--init-onnx FILE` an exported fp32 file (the committed default, say: its
batch norms are re-derived by relocnet/unfold.py), each with a new schedule.

Devices: on the CPU (the default when no GPU is present) the batch defaults to 64 and the passes run in
fp32, or with `--precision bf16` in bf16 autocast (1.4-1.7x the frames per second on a 2-core AMD EPYC
with AVX512-BF16; CPUs without native bf16 emulate it, which was not measured). With `--device cuda`
(or `auto` when a GPU is present) the frames, targets and augmentation live on the GPU, the passes run
in bf16 autocast, and the batch defaults to 256; the recipe (loss, augmentation, schedule, seeds) is
the same, the random streams are the GPU's.

After the last epoch the predicted uncertainties are calibrated on the validation frames (never the
test sets): one scale for the position sigma and one for the heading's 1/sqrt(kappa), each the smallest
factor >= 1 that leaves at most 2% of the validation frames beyond 3 sigma. training.json keeps them
and export.py builds them into the exported graph.

Loss (no hand-tuned weights): a per-frame Gaussian negative log-likelihood for the position and a von
Mises one for the heading, each with its own predicted uncertainty (Kendall & Gal 2017's heteroscedastic
form, which balances the tasks by itself and gives every frame a confidence), weighted by the detached
sigma^(2*beta) as in beta-NLL (Seitzer et al. 2022) so that hard frames are not simply given up; plus
binary cross-entropy per fold bit. Augmentation: horizontal flips (a flipped image is the long-axis
mirror pose), brightness, contrast, white balance and noise.
"""

import argparse
import copy
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
from relocnet.unfold import unfold

BETA = 0.5
# Share of validation frames allowed beyond 3 sigma after calibration (the target on test is <= 5%).
CALIBRATION_SHARE = 0.02
# Training frames whose statistics re-derive the batch norms of an exported file (--init-onnx).
ONNX_STATISTICS_FRAMES = 512


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


def augment(images_uint8, generator):
    """uint8 NHWC frames -> normalised float NCHW (channels_last) with brightness, contrast, per-channel
    gain and noise, drawn from `generator` on the frames' device.

    One fused pass of what the recipe defines on the frames' [0, 1] values: contrast about the frame's
    mean, then gain times channel gain, then Gaussian noise, clamped to [0, 1] and normalised as
    `to_input` does. Contrast and gains are one scale and one offset per frame and channel."""
    n, device = images_uint8.shape[0], images_uint8.device
    gain = torch.empty(n, 1, 1, 1, device=device).uniform_(0.75, 1.25, generator=generator)
    channel = torch.empty(n, 3, 1, 1, device=device).uniform_(0.9, 1.1, generator=generator)
    contrast = torch.empty(n, 1, 1, 1, device=device).uniform_(0.8, 1.2, generator=generator)
    noise = torch.empty(n, 1, 1, 1, device=device).uniform_(0.0, 0.02, generator=generator)
    levels = images_uint8.permute(0, 3, 1, 2).contiguous()
    mean = levels.sum(dim=(1, 2, 3), keepdim=True, dtype=torch.float32) / (levels[0].numel() * 255.0)
    scale = contrast * gain * channel
    rgb = torch.randn(levels.shape, generator=generator, device=device).mul_(noise)
    rgb.addcmul_(levels, scale / 255.0).add_(mean * (1 - contrast) * gain * channel).clamp_(0, 1)
    return rgb.sub_(0.5).div_(0.25).contiguous(memory_format=torch.channels_last)


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
def predict(net, images, targets, batch=256):
    """Per-frame location error (m), heading error (rad), position sigma (m), kappa and fold
    probabilities on (images, targets), in fp32."""
    net.eval()
    location, heading, sigma, kappa, fold = [], [], [], [], []
    for start in range(0, len(images), batch):
        x = to_input(images[start : start + batch])
        position, head, fold_logits, log_sigma, log_kappa = net(x)
        t = targets[start : start + batch]
        location.append((position - t[:, :2]).norm(dim=1))
        heading.append(torch.acos((head * t[:, 2:4]).sum(1).clamp(-1, 1)))
        sigma.append(torch.exp(log_sigma[:, 0]))
        kappa.append(torch.exp(log_kappa[:, 0]))
        fold.append(torch.sigmoid(fold_logits))
    net.train()
    return tuple(torch.cat(parts) for parts in (location, heading, sigma, kappa, fold))


def evaluate(net, images, targets, bits, batch=256):
    location, heading, sigma, kappa, fold = predict(net, images, targets, batch)
    heading = torch.rad2deg(heading)
    result = {
        "location_median_m": location.median().item(),
        "location_mean_m": location.mean().item(),
        "heading_median_deg": heading.median().item(),
        "heading_mean_deg": heading.mean().item(),
        "beyond_3_sigma": (location > 3 * sigma).float().mean().item(),
    }
    if bits.shape[1]:
        result["fold_error_mean"] = ((fold > 0.5).float() != bits).float().mean().item()
    return result


def calibrate(net, images, targets):
    """Scales for the position sigma and the heading's 1/sqrt(kappa): the smallest factors >= 1 that
    leave at most CALIBRATION_SHARE of the frames beyond 3 sigma (on validation frames)."""
    location, heading, sigma, kappa, _ = predict(net, images, targets)
    position_ratio = (location / sigma).double().cpu().numpy()
    heading_ratio = (heading * kappa.sqrt()).double().cpu().numpy()
    quantile = 1 - CALIBRATION_SHARE
    position_scale = max(1.0, float(np.quantile(position_ratio, quantile)) / 3)
    heading_scale = max(1.0, float(np.quantile(heading_ratio, quantile)) / 3)
    share = lambda ratio, scale: float((ratio > 3 * scale).mean())  # noqa: E731
    return {
        "position_sigma_scale": position_scale,
        "heading_kappa_scale": 1 / heading_scale**2,
        "validation_frames": len(position_ratio),
        "target_share_beyond_3_sigma": CALIBRATION_SHARE,
        "validation_beyond_3_sigma": {
            "position_before": share(position_ratio, 1.0), "position_after": share(position_ratio, position_scale),
            "heading_before": share(heading_ratio, 1.0), "heading_after": share(heading_ratio, heading_scale),
        },
    }


def train_step(net, optimiser, images, targets, generator, autocast):
    """One step of the recipe on a batch of uint8 frames: flips, photometric augmentation, loss, update.
    `autocast` is the device type to run the passes in bf16 autocast on, or None for fp32. Returns the
    three loss terms."""
    index, train_images = images
    flip = torch.rand(len(index), generator=generator, device=train_images.device) < 0.5
    batch = train_images[index]
    batch = torch.where(flip[:, None, None, None], batch.flip(2), batch)
    t = torch.where(flip[:, None], targets[1][0][index], targets[0][0][index])
    b = torch.where(flip[:, None], targets[1][1][index], targets[0][1][index])
    x = augment(batch, generator)
    if autocast:
        with torch.autocast(autocast, dtype=torch.bfloat16):
            outputs = net(x)
        parts = losses([output.float() for output in outputs], t, b)
    else:
        parts = losses(net(x), t, b)
    loss = sum(parts)
    optimiser.zero_grad(set_to_none=True)
    loss.backward()
    optimiser.step()
    return parts


def seconds_per_step(net, args, train_images, targets, device, autocast, warmup=5, steps=20):
    """Times training steps on a throw-away copy of the net (the run's random streams are restored)."""
    cuda = device.type == "cuda"
    states = (torch.get_rng_state(), torch.cuda.get_rng_state(device) if cuda else None)
    probe = copy.deepcopy(net)
    optimiser = torch.optim.AdamW(probe.parameters(), lr=0.0)
    generator = torch.Generator(device=device).manual_seed(12345)
    for step in range(warmup + steps):
        if step == warmup:
            if cuda:
                torch.cuda.synchronize(device)
            started = time.time()
        index = torch.randint(len(train_images), (args.batch,), generator=generator, device=device)
        train_step(probe, optimiser, (index, train_images), targets, generator, autocast)
    if cuda:
        torch.cuda.synchronize(device)
    torch.set_rng_state(states[0])
    if cuda:
        torch.cuda.set_rng_state(states[1], device)
    return (time.time() - started) / steps


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--train", required=True, type=Path, nargs="+", help="training recordings (concatenated)")
    parser.add_argument("--val", required=True, type=Path, nargs="+", help="validation recordings (concatenated)")
    parser.add_argument("--arch", choices=["squeezenet", "alexnet"], default="squeezenet")
    parser.add_argument("--width", type=float, default=0.5)
    parser.add_argument("--representation", default="half-point")
    parser.add_argument("--epochs", type=int, default=20)
    parser.add_argument("--batch", type=int, help="frames per step (default 64 on the CPU, 256 on a GPU)")
    parser.add_argument("--lr", type=float, default=3e-3)
    parser.add_argument("--weight-decay", type=float, default=1e-4)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--threads", type=int, default=2, help="CPU threads")
    parser.add_argument("--device", choices=["auto", "cuda", "cpu"], default="auto",
                        help="cuda: GPU with bf16 autocast and the data on the GPU; auto: cuda when present")
    parser.add_argument("--precision", choices=["auto", "fp32", "bf16"], default="auto",
                        help="forward and backward passes in fp32 or bf16 autocast; auto: bf16 on a GPU, fp32 on "
                             "the CPU (bf16 pays on CPUs with native bf16: AVX512-BF16 or AMX)")
    parser.add_argument("--limit", type=int, default=0, help="use only the first N frames of each training recording (0: all)")
    parser.add_argument("--time-budget", type=float, default=0,
                        help="seconds of training: times a few steps first and trains min(--epochs, what fits) epochs "
                             "(the number is logged; pass it as --epochs to repeat the run)")
    parser.add_argument("--init", type=Path, help="continue from this run directory's weights.pt (a new schedule)")
    parser.add_argument("--init-onnx", type=Path,
                        help=f"continue from an exported fp32 ONNX file (its batch norms re-derived on "
                             f"{ONNX_STATISTICS_FRAMES} of the training frames; a new schedule), e.g. the committed default")
    parser.add_argument("--out", required=True, type=Path)
    args = parser.parse_args()
    if args.init and args.init_onnx:
        parser.error("--init and --init-onnx: one or the other")

    if args.device == "auto":
        args.device = "cuda" if torch.cuda.is_available() else "cpu"
    device = torch.device(args.device)
    cuda = device.type == "cuda"
    if args.batch is None:
        args.batch = 256 if cuda else 64
    if args.precision == "auto":
        args.precision = "bf16" if cuda else "fp32"
    autocast = device.type if args.precision == "bf16" else None
    torch.manual_seed(args.seed)
    np.random.seed(args.seed)
    torch.set_num_threads(args.threads)
    generator = torch.Generator(device=device).manual_seed(args.seed)
    if cuda:
        torch.backends.cudnn.benchmark = True
    args.out.mkdir(parents=True, exist_ok=True)

    train_images, train_poses = load_recordings(args.train, args.limit)
    val_images, val_poses = load_recordings(args.val)
    train_images = torch.from_numpy(train_images).to(device)
    targets = [tuple(t.to(device) for t in folded_targets(train_poses, args.representation, flipped))
               for flipped in (False, True)]
    val_targets, val_bits = (t.to(device) for t in folded_targets(val_poses, args.representation, False))
    val_images = torch.from_numpy(val_images).to(device)

    net = RelocNet(args.arch, args.width, args.representation)
    if args.init:
        net.load_state_dict(torch.load(args.init / "weights.pt", map_location="cpu"))
        print(f"continuing from {args.init}")
    if args.init_onnx:
        frames = train_images[:: max(1, len(train_images) // ONNX_STATISTICS_FRAMES)][:ONNX_STATISTICS_FRAMES]
        try:
            net, exported = unfold(args.init_onnx, frames.cpu().numpy())
        except ValueError as error:
            parser.error(str(error))
        training = exported["training"]
        if (training["architecture"], float(training["width"]), exported["representation"]) != \
                (args.arch, args.width, args.representation):
            parser.error(f"{args.init_onnx} is {training['architecture']} width {training['width']} "
                         f"{exported['representation']}, not what --arch, --width and --representation ask")
        net.train()
        print(f"continuing from {args.init_onnx} ({exported['model_id']})")
    net = net.to(memory_format=torch.channels_last)
    macs, parameters = count_macs(net), count_parameters(net)
    net.to(device)
    print(f"{args.arch} width {args.width} {args.representation}: {macs / 1e6:.1f} M MACs, {parameters / 1e6:.2f} M parameters;"
          f" {len(train_images)} training frames, batch {args.batch}, on {device}"
          + (f" ({torch.cuda.get_device_name(device)})" if cuda else f" ({args.threads} threads)")
          + (", bf16 autocast" if autocast else ", fp32"), flush=True)
    steps_per_epoch = len(train_images) // args.batch
    budget = None
    if args.time_budget > 0:
        step_seconds = seconds_per_step(net, args, train_images, targets, device, autocast)
        # 5% for the validation pass after each epoch.
        fitting = int(args.time_budget / (1.05 * step_seconds * steps_per_epoch))
        budget = {"seconds": args.time_budget, "measured_seconds_per_step": round(step_seconds, 5),
                  "requested_epochs": args.epochs, "epochs": max(1, min(args.epochs, fitting))}
        args.epochs = budget["epochs"]
        print(f"time budget {args.time_budget:.0f} s at {step_seconds * 1e3:.1f} ms per step: {args.epochs} epochs", flush=True)
    optimiser = torch.optim.AdamW(net.parameters(), lr=args.lr, weight_decay=args.weight_decay)
    schedule = torch.optim.lr_scheduler.OneCycleLR(
        optimiser, max_lr=args.lr, total_steps=args.epochs * steps_per_epoch, pct_start=0.15
    )
    log = {"args": {k: str(v) for k, v in vars(args).items()}, "macs": macs, "parameters": parameters, "epochs": []}
    if budget:
        log["time_budget"] = budget
    if args.init:
        earlier = json.loads((args.init / "training.json").read_text())
        log["continued_from"] = {"run": args.init.name, "epochs": len(earlier["epochs"]),
                                 "train_seconds": earlier["train_seconds"], "lr": earlier["args"]["lr"]}
    if args.init_onnx:
        log["continued_from"] = {"model": exported["model_id"], "epochs": training["epochs"],
                                 "train_seconds": training["train_seconds"],
                                 "continued_from": training.get("continued_from")}
    if args.init or args.init_onnx:
        log["start_val"] = evaluate(net, val_images, val_targets, val_bits)
        print(json.dumps({"start_val": log["start_val"]}), flush=True)
    started = time.time()
    for epoch in range(args.epochs):
        order = torch.randperm(len(train_images), generator=generator, device=device)
        totals = torch.zeros(3, device=device)
        for step in range(steps_per_epoch):
            index = order[step * args.batch : (step + 1) * args.batch]
            parts = train_step(net, optimiser, (index, train_images), targets, generator, autocast)
            schedule.step()
            totals += torch.stack([p.detach().float() for p in parts])
        metrics = evaluate(net, val_images, val_targets, val_bits)
        entry = {"epoch": epoch + 1, "seconds": round(time.time() - started, 1),
                 "loss": (totals / steps_per_epoch).tolist(), "val": metrics}
        log["epochs"].append(entry)
        print(json.dumps(entry), flush=True)
        torch.save({k: v.cpu() for k, v in net.state_dict().items()}, args.out / "weights.pt")
    log["train_seconds"] = round(time.time() - started, 1)
    log["device"] = torch.cuda.get_device_name(device) if cuda else f"cpu, {args.threads} threads"
    log["sigma_calibration"] = calibrate(net, val_images, val_targets)
    print(json.dumps({"sigma_calibration": log["sigma_calibration"]}), flush=True)
    (args.out / "training.json").write_text(json.dumps(log, indent=1))


if __name__ == "__main__":
    main()
