"""Reading relocd recordings (frames.jsonl + frame files) into arrays, cached beside the recording."""

import json
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from PIL import Image

# Recordings with more frames than this are decoded by several processes (one per core).
PARALLEL_DECODE_FRAMES = 4000


def _decode(directory, files, width, height):
    images = np.empty((len(files), height, width, 3), np.uint8)
    for i, file in enumerate(files):
        image = Image.open(directory / file).convert("RGB")
        if image.size != (width, height):
            raise ValueError(f"{file} is {image.size}, expected {(width, height)}")
        images[i] = np.asarray(image)
    return images


def load_recording(directory, width=160, height=120):
    """Returns (images uint8 [N, H, W, 3], poses float64 [N, 3] as x, y, theta).

    Frames must already be `width` x `height` (render them at the model's size). The decoded arrays
    are cached in `directory/frames-<W>x<H>.npz` and reused while frames.jsonl is unchanged.
    """
    directory = Path(directory)
    index = directory / "frames.jsonl"
    cache = directory / f"frames-{width}x{height}.npz"
    if cache.exists() and cache.stat().st_mtime >= index.stat().st_mtime:
        cached = np.load(cache)
        return cached["images"], cached["poses"]
    records = [json.loads(line) for line in index.read_text().splitlines() if line.strip()]
    files = [record["file"] for record in records]
    workers = os.cpu_count() or 1
    if len(files) > PARALLEL_DECODE_FRAMES and workers > 1:
        chunk = -(-len(files) // workers)
        with ProcessPoolExecutor(workers) as pool:
            parts = pool.map(_decode, *zip(*[(directory, files[i : i + chunk], width, height)
                                             for i in range(0, len(files), chunk)]))
            images = np.concatenate(list(parts))
    else:
        images = _decode(directory, files, width, height)
    poses = np.array([(r["pose"]["x"], r["pose"]["y"], r["pose"]["theta"]) for r in records], np.float64).reshape(-1, 3)
    np.savez(cache, images=images, poses=poses)
    return images, poses


def load_recordings(directories, limit=0, width=160, height=120):
    """Like `load_recording`, for several recordings concatenated in the order given; `limit` > 0 keeps
    only the first `limit` frames of each."""
    loaded = [load_recording(directory, width, height) for directory in directories]
    end = limit or None
    return (np.concatenate([images[:end] for images, _ in loaded]),
            np.concatenate([poses[:end] for _, poses in loaded]))


def calibration_images(directories, count):
    """The first `count` frames for int8 calibration, an equal share from each recording (in order)."""
    share = -(-count // len(directories))
    images = [load_recording(directory)[0][:share] for directory in directories]
    return np.concatenate(images)[:count]
