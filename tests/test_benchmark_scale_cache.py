"""benchmarks/scale.py keeps per-scene results in --work; their cache is named for the detector's weights, so a
re-trained model never reuses an earlier model's results."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from gst_trafficcal.detection import vehicleseg
from gst_trafficcal.detection.models import sha256_of
from gst_trafficcal.errors import InputError

ROOT = Path(__file__).resolve().parents[1]


def _scale_benchmark():
    spec = importlib.util.spec_from_file_location("scale_benchmark", ROOT / "benchmarks" / "scale.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_cache_key_follows_the_weights(tmp_path):
    key = _scale_benchmark().detector_key
    assert key("vehicleseg") == f"vehicleseg-{sha256_of(vehicleseg.WEIGHTS)[:8]}"
    same = tmp_path / "vehicleseg.onnx"
    same.write_bytes(vehicleseg.WEIGHTS.read_bytes())
    assert key(str(same)) == key("vehicleseg")  # the same weights elsewhere share the results
    retrained = tmp_path / "retrained.onnx"
    retrained.write_bytes(vehicleseg.WEIGHTS.read_bytes() + b"\0")
    assert key(str(retrained)).startswith("retrained-") and key(str(retrained))[-8:] != key("vehicleseg")[-8:]
    with pytest.raises(InputError, match="model file not found"):
        key(str(tmp_path / "missing.onnx"))
