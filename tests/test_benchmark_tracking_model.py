"""benchmarks/tracking.py --model: another vehicleseg file, refused with one line when it cannot be used."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "benchmarks" / "tracking.py"), "--presets", "", "--no-fps", *args],
                          capture_output=True, text=True, timeout=120)


def test_a_missing_or_foreign_model_is_refused_at_start_up(tmp_path):
    r = _run("--detector", "vehicleseg", "--model", str(tmp_path / "nope.onnx"))
    assert r.returncode == 2 and "model file not found" in r.stderr and "Traceback" not in r.stderr
    bad = tmp_path / "bad.onnx"
    bad.write_text("not a model")
    r = _run("--detector", "vehicleseg", "--model", str(bad))
    assert r.returncode == 2 and "not a usable ONNX model" in r.stderr and "Traceback" not in r.stderr


def test_model_is_only_for_the_segmenter():
    r = _run("--detector", "oracle", "--model", "x.onnx")
    assert r.returncode == 2 and "--model is for --detector vehicleseg" in r.stderr


def test_make_detector_takes_the_given_file(load_benchmark):
    tr = load_benchmark("tracking")
    shipped = ROOT / "gst_trafficcal" / "detection" / "weights" / "vehicleseg.onnx"
    det = tr.make_detector("vehicleseg", str(shipped))
    assert Path(det.path).resolve() == shipped.resolve()
