"""The networks: a SqueezeNet-1.1-style net (fire modules) and an AlexNet-style net, both ending in the
same pose head. Channel counts scale with `width`; the input is 3 x 120 x 160 by default.

The head keeps the spatial layout (a 1x1 reduction, then flatten and a fully connected layer) because
where lines and goals appear in the image is what tells the pose.
"""

import torch
from torch import nn
import torch.nn.functional as F

from .fold import FOLD_BITS

# Half extents of the carpet (SPL 2025: 9 x 6 m field plus 0.7 m border): position outputs are
# predicted in [-1, 1] and scaled to metres inside the graph.
CARPET_HALF_EXTENT = (5.2, 3.7)
LOG_SIGMA_RANGE = (-5.0, 2.0)
LOG_KAPPA_RANGE = (-2.0, 9.0)


def conv_bn(in_channels, out_channels, kernel, stride=1, padding=0):
    return nn.Sequential(
        nn.Conv2d(in_channels, out_channels, kernel, stride, padding, bias=False),
        nn.BatchNorm2d(out_channels),
        nn.ReLU(inplace=True),
    )


class Fire(nn.Module):
    """SqueezeNet's fire module: 1x1 squeeze, then parallel 1x1 and 3x3 expands, concatenated."""

    def __init__(self, in_channels, squeeze, expand):
        super().__init__()
        self.squeeze = conv_bn(in_channels, squeeze, 1)
        self.expand1 = conv_bn(squeeze, expand, 1)
        self.expand3 = conv_bn(squeeze, expand, 3, padding=1)

    def forward(self, x):
        x = self.squeeze(x)
        return torch.cat([self.expand1(x), self.expand3(x)], 1)


def scaled(channels, width):
    return max(8, int(round(channels * width / 8)) * 8)


def squeezenet_features(width):
    c = lambda n: scaled(n, width)  # noqa: E731
    layers = nn.Sequential(
        conv_bn(3, c(64), 3, stride=2),
        nn.MaxPool2d(3, 2, ceil_mode=True),
        Fire(c(64), c(16), c(64)),
        Fire(2 * c(64), c(16), c(64)),
        nn.MaxPool2d(3, 2, ceil_mode=True),
        Fire(2 * c(64), c(32), c(128)),
        Fire(2 * c(128), c(32), c(128)),
        nn.MaxPool2d(3, 2, ceil_mode=True),
        Fire(2 * c(128), c(48), c(192)),
        Fire(2 * c(192), c(48), c(192)),
        Fire(2 * c(192), c(64), c(256)),
        Fire(2 * c(256), c(64), c(256)),
    )
    return layers, 2 * c(256)


def alexnet_features(width):
    c = lambda n: scaled(n, width)  # noqa: E731
    layers = nn.Sequential(
        conv_bn(3, c(64), 5, stride=2, padding=2),
        nn.MaxPool2d(3, 2, ceil_mode=True),
        conv_bn(c(64), c(192), 5, padding=2),
        nn.MaxPool2d(3, 2, ceil_mode=True),
        conv_bn(c(192), c(384), 3, padding=1),
        conv_bn(c(384), c(256), 3, padding=1),
        conv_bn(c(256), c(256), 3, padding=1),
        nn.MaxPool2d(3, 2, ceil_mode=True),
    )
    return layers, c(256)


ARCHITECTURES = {"squeezenet": squeezenet_features, "alexnet": alexnet_features}


class RelocNet(nn.Module):
    """Features, then the pose head: position (m), heading (unit vector), fold-bit logits, and the
    per-frame uncertainty (log sigma of the position in m, log kappa of the heading)."""

    def __init__(self, architecture, width, representation, input_size=(120, 160), reduced=32, hidden=256):
        super().__init__()
        self.features, channels = ARCHITECTURES[architecture](width)
        self.reduce = conv_bn(channels, reduced, 1)
        with torch.no_grad():
            h, w = self.reduce(self.features(torch.zeros(1, 3, *input_size))).shape[2:]
        self.fc = nn.Sequential(nn.Flatten(), nn.Linear(reduced * h * w, hidden), nn.ReLU(inplace=True), nn.Dropout(0.2))
        self.bits = FOLD_BITS[representation]
        self.out = nn.Linear(hidden, 2 + 2 + self.bits + 2)
        self.register_buffer("position_scale", torch.tensor(CARPET_HALF_EXTENT))

    def forward(self, image):
        raw = self.out(self.fc(self.reduce(self.features(image))))
        position = torch.tanh(raw[:, 0:2]) * self.position_scale
        heading = F.normalize(raw[:, 2:4], dim=1, eps=1e-6)
        fold_logits = raw[:, 4 : 4 + self.bits]
        log_sigma = raw[:, 4 + self.bits : 5 + self.bits].clamp(*LOG_SIGMA_RANGE)
        log_kappa = raw[:, 5 + self.bits : 6 + self.bits].clamp(*LOG_KAPPA_RANGE)
        return position, heading, fold_logits, log_sigma, log_kappa


class Exported(nn.Module):
    """What goes into the ONNX file: probabilities and uncertainties instead of logits and logs, the
    uncertainties scaled by the validation calibration (train.py's `calibrate`; 1 leaves them as
    trained)."""

    def __init__(self, net, position_sigma_scale=1.0, heading_kappa_scale=1.0):
        super().__init__()
        self.net = net
        self.position_sigma_scale = float(position_sigma_scale)
        self.heading_kappa_scale = float(heading_kappa_scale)

    def forward(self, image):
        position, heading, fold_logits, log_sigma, log_kappa = self.net(image)
        outputs = [position, heading]
        if self.net.bits:
            outputs.append(torch.sigmoid(fold_logits))
        sigma, kappa = torch.exp(log_sigma), torch.exp(log_kappa)
        if self.position_sigma_scale != 1.0:
            sigma = sigma * self.position_sigma_scale
        if self.heading_kappa_scale != 1.0:
            kappa = kappa * self.heading_kappa_scale
        return (*outputs, sigma, kappa)


def output_names(representation):
    names = ["position", "heading"]
    if FOLD_BITS[representation]:
        names.append("fold_probabilities")
    return names + ["position_sigma", "heading_kappa"]


def count_macs(net, input_size=(120, 160)):
    """Multiply-accumulates of one forward pass (convolutions and linear layers)."""
    macs = 0

    def conv_hook(module, _, output):
        nonlocal macs
        kernel = module.kernel_size[0] * module.kernel_size[1] * module.in_channels // module.groups
        macs += output.numel() * kernel

    def linear_hook(module, _, output):
        nonlocal macs
        macs += output.numel() * module.in_features

    hooks = [m.register_forward_hook(conv_hook) for m in net.modules() if isinstance(m, nn.Conv2d)]
    hooks += [m.register_forward_hook(linear_hook) for m in net.modules() if isinstance(m, nn.Linear)]
    was_training = net.training
    net.eval()
    with torch.no_grad():
        net(torch.zeros(1, 3, *input_size))
    net.train(was_training)
    for hook in hooks:
        hook.remove()
    return macs


def count_parameters(net):
    return sum(p.numel() for p in net.parameters())
