"""Exports a trained network to ONNX with its contract in the metadata, quantises it to int8 (QDQ,
calibrated on rendered frames) and writes a parity fixture of onnxruntime's outputs.

    python models/export.py --run RUN_DIR --calibration DATA/val [DATA/val-realism ...] \
        --name squeezenet-half-point --data 1000:16000:black --data 1001:16000:hall-realism [--keep-fp32] \
        [--camera-height 0.38,0.55 --camera-pitch=-10,25 --max-camera-roll 5]

--data names each training recording as SEED:FRAMES:KIND (KIND: black, asymmetric or hall-realism, the
`relocd render` surroundings) for the contract, and --camera-height/--camera-pitch/--max-camera-roll
the camera range the training frames were rendered with (the flags given to `relocd render`; their
defaults are the renderer's); calibration frames are shared equally between the calibration recordings.
The run's sigma calibration (train.py) is built into the graph's position_sigma and heading_kappa and
recorded in the contract.

Writes models/<name>.int8.onnx (and models/<name>.fp32.onnx with --keep-fp32), and
models/fixtures/parity/<name>.json with onnxruntime's outputs for the checked-in parity frames.
"""

import argparse
import json
import math
import tempfile
import tomllib
from pathlib import Path

import numpy as np
import onnx
import onnxruntime
import torch
from onnxruntime.quantization import QuantFormat, QuantType, quantize_static
from onnxruntime.quantization.shape_inference import quant_pre_process
from PIL import Image

from relocnet.data import calibration_images
from relocnet.nets import Exported, RelocNet, output_names
from relocnet.onnxfile import MEAN, SCALE, STD, Frames, normalise, with_contract

MODELS = Path(__file__).resolve().parent
REPO = MODELS.parent
PARITY_FRAMES = MODELS / "fixtures" / "parity"
OUTPUT_MEANINGS = {
    "position": "camera ground position (x, y) in the folded field, metres, field frame",
    "heading": "camera ground heading in the folded field as (cos, sin); includes the head yaw",
    "fold_probabilities": "probability that each fold bit is set, in the representation's bit order",
    "position_sigma": "predicted standard deviation of the position, metres",
    "heading_kappa": "predicted von Mises concentration of the heading",
}


def contract(args, log, representation, name, quantisation):
    field = tomllib.loads((REPO / "src" / "geometry" / "spl_2025.toml").read_text())
    train_args = log["args"]
    return {
        "contract_version": 1,
        "model_id": f"{name}-{quantisation.split()[0]}-v{args.version}",
        "representation": representation,
        "input": {"name": "image", "shape": [1, 3, 120, 160], "layout": "NCHW", "colour": "RGB",
                  "scale": SCALE, "mean": MEAN, "std": STD},
        "outputs": {key: OUTPUT_MEANINGS[key] for key in output_names(representation)},
        "field": field,
        "camera": {"width": 640, "height": 480, "horizontal_fov": math.radians(54.7), "vertical_fov": math.radians(42.5)},
        "training": {
            "architecture": train_args["arch"], "width": float(train_args["width"]),
            "macs": log["macs"], "parameters": log["parameters"],
            "epochs": int(train_args["epochs"]), "seed": int(train_args["seed"]), "train_seconds": log["train_seconds"],
            "continued_from": log.get("continued_from"),
            "data": [{"renderer": "relocd render", "seed": seed, "frames": frames, "size": "160x120",
                      "surroundings": kind} for seed, frames, kind in args.data],
            "camera_range": {"height_m": list(args.camera_height), "pitch_deg_down": list(args.camera_pitch),
                             "max_roll_deg": args.max_camera_roll},
            "device": log.get("device", "cpu"), "batch": int(train_args.get("batch") or 64),
            "sigma_calibration": log.get("sigma_calibration"),
            "calibration": {"recordings": [path.name for path in args.calibration], "frames": args.calibration_frames},
            "quantisation": quantisation,
        },
    }


def value_range(text):
    """Parses LOW,HIGH (as `relocd render` takes its ranges)."""
    low, high = (float(value) for value in text.split(","))
    if low > high:
        raise argparse.ArgumentTypeError(f"{text}: expected LOW,HIGH with LOW <= HIGH")
    return low, high


def data_set(text):
    """Parses SEED:FRAMES:KIND."""
    seed, frames, kind = text.split(":")
    if kind not in ("black", "asymmetric", "hall-realism"):
        raise argparse.ArgumentTypeError(f"unknown surroundings '{kind}' (black, asymmetric, hall-realism)")
    return int(seed), int(frames), kind


def last_gemm(path):
    gemms = [node.name for node in onnx.load(path).graph.node if node.op_type == "Gemm"]
    return gemms[-1]


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--run", required=True, type=Path, help="training output directory (weights.pt, training.json)")
    parser.add_argument("--calibration", required=True, type=Path, nargs="+", help="rendered recordings for int8 calibration")
    parser.add_argument("--calibration-frames", type=int, default=512)
    parser.add_argument("--name", required=True)
    parser.add_argument("--data", required=True, type=data_set, action="append",
                        help="a training recording as SEED:FRAMES:KIND, once per recording")
    parser.add_argument("--version", type=int, default=1, help="model version, in the model id (raise it on every retrain)")
    parser.add_argument("--keep-fp32", action="store_true")
    parser.add_argument("--camera-height", type=value_range, default=(0.45, 0.53),
                        help="camera height range of the training frames, m (render's --camera-height)")
    parser.add_argument("--camera-pitch", type=value_range, default=(0.0, 20.0),
                        help="camera pitch range of the training frames, degrees down (render's --camera-pitch)")
    parser.add_argument("--max-camera-roll", type=float, default=3.0,
                        help="largest camera roll of the training frames, degrees (render's --max-camera-roll)")
    args = parser.parse_args()

    log = json.loads((args.run / "training.json").read_text())
    train_args = log["args"]
    representation = train_args["representation"]
    net = RelocNet(train_args["arch"], float(train_args["width"]), representation)
    net.load_state_dict(torch.load(args.run / "weights.pt", map_location="cpu"))
    net.eval()
    scales = log.get("sigma_calibration") or {}
    exported = Exported(net, scales.get("position_sigma_scale", 1.0), scales.get("heading_kappa_scale", 1.0))
    names = output_names(representation)

    with tempfile.TemporaryDirectory() as scratch:
        scratch = Path(scratch)
        fp32 = scratch / "fp32.onnx"
        torch.onnx.export(exported, torch.zeros(1, 3, 120, 160), str(fp32), dynamo=False, opset_version=13,
                          input_names=["image"], output_names=names, do_constant_folding=True)
        prepared = scratch / "prepared.onnx"
        quant_pre_process(str(fp32), str(prepared))
        images = calibration_images(args.calibration, args.calibration_frames)
        int8 = MODELS / f"{args.name}.int8.onnx"
        quantize_static(str(prepared), str(int8), Frames(images),
                        quant_format=QuantFormat.QDQ, per_channel=False, activation_type=QuantType.QUInt8,
                        weight_type=QuantType.QInt8, nodes_to_exclude=[last_gemm(prepared)])
        with_contract(int8, contract(args, log, representation, args.name,
                                     "int8 QDQ, onnxruntime static MinMax calibration, per-tensor, output layer fp32"))
        files = {"int8": int8}
        if args.keep_fp32:
            kept = MODELS / f"{args.name}.fp32.onnx"
            onnx.save(onnx.load(fp32), kept)
            with_contract(kept, contract(args, log, representation, args.name, "fp32 none"))
            files["fp32"] = kept

    # Relative tolerances. fp32 is the strict check of the wiring (preprocessing, layout, output order).
    # int8: onnxruntime runs QDQ as integer convolutions, tract as f32 convolutions between Quantize and
    # Dequantize, so an activation near a rounding boundary can land one int8 step apart. Most frames agree
    # to 1e-6; measured worst 1.0e-2 (default model, one frame's position), so 2e-2.
    fixture = {"tolerance": {"fp32": 1e-4, "int8": 2e-2}, "frames": []}
    frames = sorted(PARITY_FRAMES.glob("*.png"))
    for frame in frames:
        x = normalise(np.asarray(Image.open(frame).convert("RGB"))[None])
        entry = {"file": frame.name, "outputs": {}}
        for kind, path in files.items():
            session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
            values = session.run(names, {"image": x})
            entry["outputs"][kind] = {name: value.reshape(-1).tolist() for name, value in zip(names, values)}
        fixture["frames"].append(entry)
    (PARITY_FRAMES / f"{args.name}.json").write_text(json.dumps(fixture, indent=1) + "\n")
    for kind, path in files.items():
        print(f"{kind}: {path.relative_to(REPO)} ({path.stat().st_size / 1e6:.2f} MB)")


if __name__ == "__main__":
    main()
