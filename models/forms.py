"""Derives the other int8 forms of an exported model from its fp32 file, keeping the contract.

    python models/forms.py --fp32 models/squeezenet-half-point.fp32.onnx --calibration DATA/val \
        --form weights-int8 --form qoperator

Forms (see the performance section of models/README.md for what each costs in tract):

- `weights-int8` -> NAME.w8.onnx: every Conv and Gemm weight stored as int8 with one symmetric scale per
  output channel, restored by a DequantizeLinear that tract folds into a constant at load. Activations
  stay fp32, so it runs at fp32 speed with a file 3.8x smaller; no calibration needed.
- `qoperator` -> NAME.qop.onnx: integer convolutions (QLinearConv) with per-tensor scales, calibrated with
  onnxruntime's static MinMax on the rendered frames. Only operators with standard ONNX integer forms are
  quantised (Conv, MaxPool; ReLU folds into the convolution's output range), so tract loads it and fuses
  the re-quantisation into its integer matrix product. The head (Gemm) keeps fp32 activations with int8
  weights as in `weights-int8`.

Deterministic: the same fp32 file and calibration frames give the same bytes.
"""

import argparse
import copy
import json
import tempfile
from pathlib import Path

import numpy as np
import onnx
import onnxruntime
from onnx import helper, numpy_helper
from onnxruntime.quantization import QuantFormat, QuantType, quantize_static
from onnxruntime.quantization.shape_inference import quant_pre_process
from PIL import Image

from relocnet.data import calibration_images
from relocnet.onnxfile import Frames, normalise, read_contract, with_contract

MODELS = Path(__file__).resolve().parent
PARITY_FRAMES = MODELS / "fixtures" / "parity"
# form: (file suffix, the contract's quantisation, tract-against-onnxruntime parity tolerance). Weights-only
# files compute in fp32 on both sides (strict); integer convolutions may round one int8 step apart.
FORMS = {
    "weights-int8": ("w8", "int8 weights only (per output channel, symmetric), fp32 activations; DequantizeLinear folded at load", 1e-4),
    "qoperator": ("qop", "int8 QOperator (QLinearConv, MaxPool), per-tensor, onnxruntime static MinMax calibration; head fp32 with int8 weights", 2e-2),
}


def weights_int8(model):
    """Replaces each Conv/Gemm weight initialiser with int8 + per-output-channel scale + DequantizeLinear."""
    initialisers = {tensor.name: tensor for tensor in model.graph.initializer}
    new_nodes = []
    for node in model.graph.node:
        if node.op_type in ("Conv", "Gemm") and node.input[1] in initialisers:
            if node.op_type == "Gemm":
                transposed = any(a.name == "transB" and a.i == 1 for a in node.attribute)
                if not transposed:
                    raise SystemExit(f"{node.name}: Gemm without transB is not supported")
            name = node.input[1]
            weight = numpy_helper.to_array(initialisers[name]).astype(np.float32)
            reduce_axes = tuple(range(1, weight.ndim))
            scale = np.abs(weight).max(axis=reduce_axes) / 127.0
            scale = np.where(scale > 0, scale, 1.0).astype(np.float32)
            shape = (-1,) + (1,) * (weight.ndim - 1)
            quantised = np.clip(np.round(weight / scale.reshape(shape)), -127, 127).astype(np.int8)
            model.graph.initializer.remove(initialisers[name])
            model.graph.initializer.extend([
                numpy_helper.from_array(quantised, f"{name}_int8"),
                numpy_helper.from_array(scale, f"{name}_scale"),
                numpy_helper.from_array(np.zeros_like(scale, dtype=np.int8), f"{name}_zero_point"),
            ])
            new_nodes.append(helper.make_node("DequantizeLinear", [f"{name}_int8", f"{name}_scale", f"{name}_zero_point"],
                                              [name], name=f"{name}_DequantizeLinear", axis=0))
        new_nodes.append(node)
    del model.graph.node[:]
    model.graph.node.extend(new_nodes)
    return model


def integer_concats(model):
    """Keeps SqueezeNet's fire-module concatenations in uint8.

    onnxruntime writes `QLinearConv -> DequantizeLinear -> Concat [-> MaxPool] -> QuantizeLinear`
    because its QLinearConcat is a Microsoft extension tract does not load. Giving the concatenated
    convolutions the scale and zero point of that QuantizeLinear makes the float detour an identity, so
    the Concat (and MaxPool) run on the uint8 tensors and tract sees one integer chain.
    """
    producer = {output: node for node in model.graph.node for output in node.output}
    consumers = {}
    for node in model.graph.node:
        for name in node.input:
            consumers.setdefault(name, []).append(node)
    removed = set()
    for concat in [node for node in model.graph.node if node.op_type == "Concat"]:
        dequantise = [producer.get(name) for name in concat.input]
        if not all(d is not None and d.op_type == "DequantizeLinear" for d in dequantise):
            continue
        convs = [producer.get(d.input[0]) for d in dequantise]
        if not all(c is not None and c.op_type == "QLinearConv" and len(consumers[c.output[0]]) == 1 for c in convs):
            continue
        chain = [concat]
        while len(consumers.get(chain[-1].output[0], [])) == 1 and consumers[chain[-1].output[0]][0].op_type == "MaxPool":
            chain.append(consumers[chain[-1].output[0]][0])
        after = consumers.get(chain[-1].output[0], [])
        if len(after) != 1 or after[0].op_type != "QuantizeLinear":
            continue
        quantise = after[0]
        for conv in convs:
            conv.input[6], conv.input[7] = quantise.input[1], quantise.input[2]
        concat.input[:] = [d.input[0] for d in dequantise]
        chain[-1].output[0] = quantise.output[0]
        removed.update(id(node) for node in dequantise + [quantise])
    kept = [node for node in model.graph.node if id(node) not in removed]
    del model.graph.node[:]
    model.graph.node.extend(kept)
    del model.graph.value_info[:]  # the recorded float types of the rewired tensors are stale
    used = {name for node in model.graph.node for name in node.input}
    unused = [tensor for tensor in model.graph.initializer if tensor.name not in used]
    for tensor in unused:
        model.graph.initializer.remove(tensor)
    return model


def qoperator(fp32_path, out_path, images):
    with tempfile.TemporaryDirectory() as scratch:
        prepared = Path(scratch) / "prepared.onnx"
        quant_pre_process(str(fp32_path), str(prepared))
        quantize_static(str(prepared), str(out_path), Frames(images),
                        quant_format=QuantFormat.QOperator, per_channel=False,
                        activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8,
                        op_types_to_quantize=["Conv", "MaxPool", "Relu"])
    onnx.save(weights_int8(integer_concats(onnx.load(out_path))), out_path)


def add_to_parity_fixture(stem, suffix, path, tolerance):
    """Adds onnxruntime's outputs for `path` on the parity frames to the model's parity fixture."""
    fixture_path = PARITY_FRAMES / f"{stem}.json"
    fixture = json.loads(fixture_path.read_text())
    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    names = [output.name for output in session.get_outputs()]
    fixture["tolerance"][suffix] = tolerance
    for entry in fixture["frames"]:
        x = normalise(np.asarray(Image.open(PARITY_FRAMES / entry["file"]).convert("RGB"))[None])
        values = session.run(names, {"image": x})
        entry["outputs"][suffix] = {name: value.reshape(-1).tolist() for name, value in zip(names, values)}
    fixture_path.write_text(json.dumps(fixture, indent=1) + "\n")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fp32", required=True, type=Path, help="NAME.fp32.onnx with its contract")
    parser.add_argument("--calibration", type=Path, nargs="+", help="rendered recordings for calibration (qoperator)")
    parser.add_argument("--calibration-frames", type=int, default=512)
    parser.add_argument("--form", action="append", choices=sorted(FORMS), required=True)
    args = parser.parse_args()

    contract = read_contract(args.fp32)
    stem = args.fp32.name.removesuffix(".fp32.onnx")
    for form in args.form:
        suffix, description, tolerance = FORMS[form]
        out = args.fp32.with_name(f"{stem}.{suffix}.onnx")
        if form == "weights-int8":
            onnx.save(weights_int8(onnx.load(args.fp32)), out)
        else:
            if args.calibration is None:
                raise SystemExit("--form qoperator needs --calibration")
            qoperator(args.fp32, out, calibration_images(args.calibration, args.calibration_frames))
        document = copy.deepcopy(contract)
        document["model_id"] = f"{stem}-{suffix}-v{contract['model_id'].rsplit('-v', 1)[1]}"
        document["training"]["quantisation"] = description
        if form == "qoperator":
            document["training"]["calibration"] = {"recordings": [path.name for path in args.calibration],
                                                   "frames": args.calibration_frames}
        with_contract(out, document)
        add_to_parity_fixture(stem, suffix, out, tolerance)
        print(f"{form}: {out} ({out.stat().st_size / 1e6:.2f} MB)")


if __name__ == "__main__":
    main()
