"""ONNX-side helpers shared by export.py and forms.py (no torch): the contract in the metadata, the
contract's input normalisation, and a calibration reader for onnxruntime's static quantisation."""

import json

import numpy as np
import onnx
from onnxruntime.quantization import CalibrationDataReader

CONTRACT_KEY = "relocd.contract"
MEAN, STD, SCALE = [0.5, 0.5, 0.5], [0.25, 0.25, 0.25], 1.0 / 255.0


def normalise(images_uint8):
    """uint8 NHWC -> float32 NCHW, the contract's normalisation."""
    x = images_uint8.astype(np.float32).transpose(0, 3, 1, 2) * SCALE
    return ((x - np.array(MEAN, np.float32)[:, None, None]) / np.array(STD, np.float32)[:, None, None]).astype(np.float32)


class Frames(CalibrationDataReader):
    """Feeds uint8 NHWC images one at a time to onnxruntime's calibration."""

    def __init__(self, images):
        self.batches = iter([{"image": normalise(images[i : i + 1])} for i in range(len(images))])

    def get_next(self):
        return next(self.batches, None)


def read_contract(path):
    """The contract document of an ONNX file."""
    return contract_of(onnx.load(path), path)


def contract_of(model, path):
    """The contract document of a loaded ONNX model (read from `path`, named in the error)."""
    document = next((entry.value for entry in model.metadata_props if entry.key == CONTRACT_KEY), None)
    if document is None:
        raise ValueError(f"{path}: no {CONTRACT_KEY} metadata (not a relocd model?)")
    return json.loads(document)


def with_contract(path, document):
    """Replaces the file's metadata with the contract `document`."""
    model = onnx.load(path)
    del model.metadata_props[:]
    entry = model.metadata_props.add()
    entry.key, entry.value = CONTRACT_KEY, json.dumps(document)
    onnx.save(model, path)
