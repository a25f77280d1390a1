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


def test_a_detections_cache_gives_the_same_scores_without_the_detector(load_benchmark, cuboid_clip, tmp_path,
                                                                        monkeypatch):
    """--cache: the second run of a scene reads the first one's detections (tracker variants compared on the same
    detections, in a fraction of the time) and scores exactly as the first did."""
    from dataclasses import asdict

    tr = load_benchmark("tracking")
    first = asdict(tr.evaluate_scene("cuboid", cuboid_clip, "vehicleseg", cache=tmp_path))
    assert len(list(tmp_path.glob("*-vehicleseg-*.pkl"))) == 1

    def no_detector(*args, **kwargs):
        raise AssertionError("the detector ran although its detections were cached")

    monkeypatch.setattr(tr, "make_detector", no_detector)
    again = asdict(tr.evaluate_scene("cuboid", cuboid_clip, "vehicleseg", cache=tmp_path))
    assert {k: v for k, v in again.items() if k != "tracker_fps"} == \
        {k: v for k, v in first.items() if k != "tracker_fps"} and first["ref_points"] > 0
    variant = asdict(tr.evaluate_scene("cuboid", cuboid_clip, "vehicleseg", cache=tmp_path,
                                       tracker={"body_shapes": "box"}))  # a tracker variant on the same detections
    assert variant["frames"] == first["frames"] and variant["ap50"] == first["ap50"]

    monkeypatch.undo()  # a cache file cut short (a run stopped while writing) is detected again and rewritten
    cached = next(tmp_path.glob("*-vehicleseg-*.pkl"))
    whole = cached.read_bytes()
    cached.write_bytes(whole[: len(whole) // 2])
    redone = asdict(tr.evaluate_scene("cuboid", cuboid_clip, "vehicleseg", cache=tmp_path))
    assert redone["ref_points"] == first["ref_points"] and redone["ap50"] == first["ap50"]
    assert cached.read_bytes() == whole and not list(tmp_path.glob("*.part"))
