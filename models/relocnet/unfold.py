"""A trainable network from an exported fp32 ONNX file, so that training can go on from a committed model
when its weights.pt is not at hand.

The export folds each batch norm into the convolution before it (W' = W * gamma / sigma, and a bias),
which leaves nothing for training-mode batch norm to work with. `unfold` puts the batch norms back so
that the network in eval mode computes exactly what the file computes: each convolution keeps the
folded W' (without bias), and its batch norm gets the mean and variance of W' * x over the given frames
as running statistics, gamma = sqrt(variance + eps) and beta = mean + the folded bias. In training mode
batch norm then normalises with the batch's statistics, which are close to those running ones, so the
network goes on from where the file left it. The sigma calibration built into the file's outputs is
left out (it is the contract's `training.sigma_calibration`); train.py calibrates anew after training.
The unfolded network is checked against the file with onnxruntime before it is handed back.
"""

import numpy as np
import onnx
import onnxruntime
import torch
from onnx import numpy_helper
from torch import nn

from .fold import FOLD_BITS
from .nets import ARCHITECTURES, RelocNet, output_names
from .onnxfile import contract_of, normalise

# Frames on which the unfolded network is checked against the file (onnxruntime), and the largest
# difference allowed in any raw output (position in m, heading, fold probabilities).
CHECK_FRAMES = 8
CHECK_TOLERANCE = 1e-4


def _conv_bn_pairs(net):
    """(convolution, batch norm) of each conv_bn block, in the order the forward pass runs them."""
    pairs = []
    for module in net.modules():
        if isinstance(module, nn.Sequential) and len(module) == 3 and isinstance(module[0], nn.Conv2d) \
                and isinstance(module[1], nn.BatchNorm2d):
            pairs.append((module[0], module[1]))
    return pairs


def _node_weights(model, op_type, path):
    """The (weight, bias) initialisers of each `op_type` node, in graph order."""
    initialisers = {tensor.name: numpy_helper.to_array(tensor) for tensor in model.graph.initializer}
    weights = []
    for node in model.graph.node:
        if node.op_type == op_type:
            arrays = [initialisers.get(name) for name in node.input[1:3]]
            if any(array is None for array in arrays):
                raise ValueError(f"{path}: {op_type} node {node.name} has no constant weight and bias "
                                 "(not an fp32 export?)")
            weights.append(arrays)
    return weights


def unfold(path, images, batch=256):
    """Returns (RelocNet in eval mode, the file's contract) for the fp32 ONNX file at `path`, its batch
    norms re-derived on `images` (uint8 NHWC frames of the network's input size, a few hundred do)."""
    try:
        model = onnx.load(str(path))
    except Exception as error:  # protobuf's DecodeError, an OSError, ...
        raise ValueError(f"{path}: not a readable ONNX file ({error})") from error
    contract = contract_of(model, path)
    training = contract.get("training", {})
    if training.get("architecture") not in ARCHITECTURES or "width" not in training:
        raise ValueError(f"{path}: the contract names no known architecture and width "
                         f"({training.get('architecture')!r}; known: {', '.join(ARCHITECTURES)})")
    if contract.get("representation") not in FOLD_BITS:
        raise ValueError(f"{path}: unknown representation {contract.get('representation')!r}")
    net = RelocNet(training["architecture"], float(training["width"]), contract["representation"])
    pairs = _conv_bn_pairs(net)
    convs = _node_weights(model, "Conv", path)
    if len(convs) != len(pairs):
        raise ValueError(f"{path}: {len(convs)} convolutions, the network has {len(pairs)} (not an fp32 export?)")
    gemms = _node_weights(model, "Gemm", path)
    linears = [net.fc[1], net.out]
    if len(gemms) != len(linears):
        raise ValueError(f"{path}: {len(gemms)} fully connected layers, the network has {len(linears)}")
    folded_bias = []
    with torch.no_grad():
        for (conv, norm), (weight, bias) in zip(pairs, convs):
            if tuple(weight.shape) != tuple(conv.weight.shape):
                raise ValueError(f"{path}: a convolution of shape {weight.shape}, expected {tuple(conv.weight.shape)}")
            conv.weight.copy_(torch.from_numpy(weight.copy()))
            folded_bias.append(torch.from_numpy(bias.copy()))
            # Identity with the folded bias, so that the forward pass below is the file's.
            norm.running_mean.zero_()
            norm.running_var.fill_(1.0 - norm.eps)
            norm.weight.fill_(1.0)
            norm.bias.copy_(folded_bias[-1])
        for linear, (weight, bias) in zip(linears, gemms):
            if tuple(weight.shape) != tuple(linear.weight.shape):
                raise ValueError(f"{path}: a fully connected layer of shape {weight.shape}, expected "
                                 f"{tuple(linear.weight.shape)}")
            linear.weight.copy_(torch.from_numpy(weight.copy()))
            linear.bias.copy_(torch.from_numpy(bias.copy()))

    # The statistics of each convolution's output over the frames, in float64.
    sums = [torch.zeros(conv.out_channels, dtype=torch.float64) for conv, _ in pairs]
    squares = [torch.zeros_like(total) for total in sums]
    counts = [0] * len(pairs)

    def hook(index):
        def record(_, __, output):
            values = output.detach().double().transpose(0, 1).reshape(output.shape[1], -1)
            sums[index] += values.sum(1)
            squares[index] += (values * values).sum(1)
            counts[index] += values.shape[1]
        return record

    hooks = [conv.register_forward_hook(hook(index)) for index, (conv, _) in enumerate(pairs)]
    net.eval()
    with torch.no_grad():
        for start in range(0, len(images), batch):
            net(torch.from_numpy(normalise(images[start : start + batch])))
    for handle in hooks:
        handle.remove()
    with torch.no_grad():
        for (_, norm), total, square, count, bias in zip(pairs, sums, squares, counts, folded_bias):
            mean = total / count
            variance = (square / count - mean * mean).clamp(min=0)
            norm.running_mean.copy_(mean.float())
            norm.running_var.copy_(variance.float())
            norm.weight.copy_(torch.sqrt(variance + norm.eps).float())
            norm.bias.copy_((mean + bias.double()).float())
    _check_against_file(net, path, contract, images[:CHECK_FRAMES])
    return net, contract


def _check_against_file(net, path, contract, images):
    """Raises unless the unfolded network (eval mode) gives the file's position, heading and fold
    probabilities on `images` (the sigma outputs carry the calibration, which the network leaves out)."""
    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    names = output_names(contract["representation"])
    with torch.no_grad():
        for image in images:
            x = normalise(image[None])
            expected = dict(zip(names, session.run(names, {"image": x})))
            position, heading, fold_logits, _, _ = net(torch.from_numpy(x))
            got = {"position": position, "heading": heading, "fold_probabilities": torch.sigmoid(fold_logits)}
            for name, value in got.items():
                if name in expected:
                    difference = float(np.abs(expected[name] - value.numpy()).max())
                    if difference > CHECK_TOLERANCE:
                        raise ValueError(f"{path}: the unfolded network's {name} is {difference:.2e} off the file's")
