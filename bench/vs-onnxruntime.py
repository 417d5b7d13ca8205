#!/usr/bin/env python3
"""relocd's inference (tract) against onnxruntime's, one thread each, same ONNX files, same input.

    python3 bench/vs-onnxruntime.py [--relocd BINARY] [--iterations 200] [MODEL ...]

For each model (default: every models/*.onnx) it times `relocd bench --stage inference` on a held-out
test frame (models/fixtures/parity/test-seed3000-000000.png) and onnxruntime on the same frame
normalised as the model's contract says, and prints both medians and relocd / onnxruntime.
Needs onnxruntime, numpy and pillow (pinned in models/requirements.txt). BINARY defaults to the release
build (`cargo build --release`); TRACT_CPU_ISA in the environment reaches relocd (e.g. the Atom's
generic kernels), not onnxruntime.
"""

import argparse
import glob
import json
import os
import statistics
import subprocess
import sys
import time

import numpy as np
import onnxruntime as ort
from PIL import Image

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FRAME = os.path.join(ROOT, "models/fixtures/parity/test-seed3000-000000.png")
CONTRACT_KEY = "relocd.contract"


def onnxruntime_median_ms(path, iterations):
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    session = ort.InferenceSession(path, options, providers=["CPUExecutionProvider"])
    contract = json.loads(session.get_modelmeta().custom_metadata_map[CONTRACT_KEY])["input"]
    _, _, height, width = contract["shape"]
    image = np.asarray(Image.open(FRAME).convert("RGB").resize((width, height), Image.BOX), np.float32)
    x = image.transpose(2, 0, 1)[None] * contract["scale"]
    x = (x - np.array(contract["mean"], np.float32)[:, None, None]) / np.array(contract["std"], np.float32)[:, None, None]
    feed = {contract["name"]: x.astype(np.float32)}
    for _ in range(3):
        session.run(None, feed)
    times = []
    for _ in range(iterations):
        started = time.perf_counter()
        session.run(None, feed)
        times.append((time.perf_counter() - started) * 1e3)
    return statistics.median(times)


def relocd_median_ms(binary, path, iterations):
    output = subprocess.run(
        [binary, "bench", "--json", "--stage", "inference", "--iterations", str(iterations),
         "--model", path, "--frame", FRAME],
        check=True, capture_output=True, text=True).stdout
    report = json.loads(output)
    return report["stages"]["inference_ms"], report["isa"]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--relocd", default=os.path.join(
        os.environ.get("CARGO_TARGET_DIR", os.path.join(ROOT, "target")), "release", "relocd"))
    parser.add_argument("--iterations", type=int, default=200)
    parser.add_argument("models", nargs="*")
    args = parser.parse_args()
    models = args.models or sorted(glob.glob(os.path.join(ROOT, "models", "*.onnx")))
    if not os.path.exists(args.relocd):
        sys.exit(f"error: no relocd at {args.relocd}: build it (cargo build --release) or pass --relocd")

    print(f"{'model':<40} {'relocd ms':>10} {'onnxruntime ms':>15} {'ratio':>7}  tract kernels")
    for path in models:
        tract, isa = relocd_median_ms(args.relocd, path, args.iterations)
        onnxruntime = onnxruntime_median_ms(path, args.iterations)
        print(f"{os.path.basename(path):<40} {tract:>10.3f} {onnxruntime:>15.3f} {tract / onnxruntime:>7.2f}  {isa}")
    print(f"(medians of {args.iterations} single-thread runs each; onnxruntime {ort.__version__})")


if __name__ == "__main__":
    main()
