"""Evaluates exported models on rendered recordings with onnxruntime (no torch): the oracle errors
(folded prediction against folded truth, as `relocd replay` reports them) and how well the predicted
uncertainty covers them: the share of frames whose position error exceeds 3 position_sigma and whose
heading error exceeds 3 / sqrt(heading_kappa).

    python models/evaluate.py --model models/squeezenet-half-point.w8.onnx [--model ...] \
        --data DATA/test DATA/test-realism [--json FILE]
    python models/evaluate.py --model models/squeezenet-half-point.w8.onnx --images IMAGE...

Prints one JSON line per (model, recording). Frames must be at the model's input size (160x120).
`--images` takes image files without poses (real camera images, say), reduces each to the input size
by whole-block means as relocd's preprocessing does (640x480 -> 4x4 blocks; rounded to 8 bits here)
and prints the predicted uncertainty of each, then its medians: there is no error to compare it with.
`relocd replay --metrics-json` stays the reference for the accuracy figures; this adds the 3-sigma
shares, which replay does not report.
"""

import argparse
import json
from pathlib import Path

import numpy as np
import onnxruntime
from PIL import Image

from relocnet.data import load_recording
from relocnet.fold import fold
from relocnet.onnxfile import normalise, read_contract


def predict(session, names, images):
    """The model's outputs on uint8 NHWC `images`, each output stacked over the frames."""
    outputs = {name: [] for name in names}
    for image in images:  # the exported graphs take one frame at a time
        for name, value in zip(names, session.run(names, {"image": normalise(image[None])})):
            outputs[name].append(value.reshape(-1))
    return {name: np.stack(values) for name, values in outputs.items()}


def evaluate(session, names, representation, images, poses):
    outputs = predict(session, names, images)
    fx, fy, ftheta, _ = fold(poses[:, 0], poses[:, 1], poses[:, 2], representation)
    location = np.hypot(outputs["position"][:, 0] - fx, outputs["position"][:, 1] - fy)
    heading = np.arccos(np.clip(outputs["heading"][:, 0] * np.cos(ftheta) + outputs["heading"][:, 1] * np.sin(ftheta), -1, 1))
    sigma = outputs["position_sigma"][:, 0]
    kappa = outputs["heading_kappa"][:, 0]
    return {
        "frames": len(images),
        "location_median_cm": round(float(np.median(location)) * 100, 1),
        "location_mean_cm": round(float(np.mean(location)) * 100, 1),
        "heading_median_deg": round(float(np.degrees(np.median(heading))), 2),
        "heading_mean_deg": round(float(np.degrees(np.mean(heading))), 2),
        "position_beyond_3_sigma": round(float(np.mean(location > 3 * sigma)), 4),
        "heading_beyond_3_sigma": round(float(np.mean(heading > 3 / np.sqrt(kappa))), 4),
        "position_sigma_median_cm": round(float(np.median(sigma)) * 100, 1),
        "heading_spread_median_deg": round(float(np.degrees(np.median(1 / np.sqrt(kappa)))), 2),
    }


def reduce_to_input(path, width=160, height=120):
    """An image file as the network's uint8 input: means of whole blocks (rounded to 8 bits)."""
    try:
        image = np.asarray(Image.open(path).convert("RGB"), np.float32)
    except OSError as error:  # PIL's UnidentifiedImageError is one
        raise SystemExit(f"{path}: not a readable image ({error})") from error
    rows, columns = image.shape[:2]
    block = rows // height
    if block < 1 or rows != block * height or columns != block * width:
        raise SystemExit(f"{path}: {columns}x{rows} is not a whole multiple of {width}x{height}")
    return np.round(image.reshape(height, block, width, block, 3).mean(axis=(1, 3))).astype(np.uint8)


def uncertainties(session, names, images):
    """Per image: the predicted position sigma (cm) and the heading's spread 1/sqrt(kappa) (degrees)."""
    outputs = predict(session, names, images)
    sigma = outputs["position_sigma"][:, 0] * 100
    spread = np.degrees(1 / np.sqrt(outputs["heading_kappa"][:, 0]))
    return [(round(float(s), 1), round(float(h), 2)) for s, h in zip(sigma, spread)]


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", required=True, type=Path, action="append")
    parser.add_argument("--data", type=Path, nargs="+", default=[], help="rendered recordings (with true poses)")
    parser.add_argument("--images", type=Path, nargs="+", default=[], help="image files without poses")
    parser.add_argument("--limit", type=int, default=0, help="only the first N frames of each recording")
    parser.add_argument("--json", type=Path, help="also write all results to this file")
    args = parser.parse_args()
    if not args.data and not args.images:
        parser.error("nothing to evaluate: give --data or --images")
    results = []
    recordings = [(path, *load_recording(path)) for path in args.data]
    unposed = [reduce_to_input(path) for path in args.images]
    for model in args.model:
        contract = read_contract(model)
        representation = contract["representation"]
        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = 1
        session = onnxruntime.InferenceSession(str(model), options, providers=["CPUExecutionProvider"])
        names = [output.name for output in session.get_outputs()]
        for path, images, poses in recordings:
            end = args.limit or None
            result = {"model": model.name, "model_id": contract["model_id"], "data": path.name,
                      **evaluate(session, names, representation, images[:end], poses[:end])}
            print(json.dumps(result), flush=True)
            results.append(result)
        if unposed:
            rows = uncertainties(session, names, unposed)
            for path, (sigma, spread) in zip(args.images, rows):
                result = {"model": model.name, "image": str(path), "position_sigma_cm": sigma, "heading_spread_deg": spread}
                print(json.dumps(result), flush=True)
                results.append(result)
            summary = {"model": model.name, "model_id": contract["model_id"], "images": len(rows),
                       "position_sigma_median_cm": float(np.median([sigma for sigma, _ in rows])),
                       "heading_spread_median_deg": float(np.median([spread for _, spread in rows]))}
            print(json.dumps(summary), flush=True)
            results.append(summary)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1) + "\n")


if __name__ == "__main__":
    main()
