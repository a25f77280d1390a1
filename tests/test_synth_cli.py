"""`trafficcal synth` end to end through the command line, with the real vehicle catalogue and encoder."""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from gst_trafficcal.brnocompspeed import load_gt_data
from gst_trafficcal.calibration import load_calibration


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "gst_trafficcal", "synth", *args], capture_output=True, text=True,
                          timeout=300)


def test_synth_preset_end_to_end(tmp_path):
    pytest.importorskip("gst_trafficcal.vehicles.mesh", reason="vehicle catalogue (gst_trafficcal.vehicles) missing")
    out = tmp_path / "out"
    r = _run("--preset", "qvga_12fps", "--duration", "4", "--seed", "3", "--out", str(out), "--no-progress")
    assert r.returncode == 0, r.stderr
    for name in ("video.mp4", "gt_data.pkl", "calibration.json", "frames.jsonl", "preview.png", "scenario.json"):
        assert (out / name).stat().st_size > 0, name
    cap = cv2.VideoCapture(str(out / "video.mp4"))
    frames = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        frames.append(img)
    assert len(frames) == 50  # 4 s at 12.5 fps
    assert frames[0].shape == (240, 320, 3)
    cal = load_calibration(out / "calibration.json")
    assert cal.image_size == (320, 240) and cal.camera.scale == pytest.approx(8.0)
    load_gt_data(out / "gt_data.pkl")
    recs = [json.loads(line) for line in (out / "frames.jsonl").read_text().splitlines()]
    assert recs and {"frame", "time", "id", "box", "visible", "box3d", "ref", "world", "class", "model"} <= set(recs[0])
    # vehicles differ from frame to frame: the video is not a still
    assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).mean() > 1.0
    # same seed, same ground truth
    out2 = tmp_path / "again, with spaces"  # a path the encoder's pipeline description must not split
    r = _run("--preset", "qvga_12fps", "--duration", "4", "--seed", "3", "--out", str(out2), "--no-progress")
    assert r.returncode == 0, r.stderr
    assert (out2 / "frames.jsonl").read_text() == (out / "frames.jsonl").read_text()
    assert cv2.VideoCapture(str(out2 / "video.mp4")).read()[0]


def test_synth_with_dropped_frames_into_a_path_with_spaces(tmp_path):
    """Dropped frames go through the appsrc writer (real timestamps with gaps): it too takes any path."""
    pytest.importorskip("gst_trafficcal.vehicles.mesh", reason="vehicle catalogue (gst_trafficcal.vehicles) missing")
    f = tmp_path / "s.yaml"
    f.write_text("base: qvga_12fps\nduration: 2\nimaging: {drop_rate: 0.3}\n")
    out = tmp_path / "drop ped" / "it's here"
    r = _run("--scenario", str(f), "--out", str(out), "--no-progress")
    assert r.returncode == 0, r.stderr
    dropped = int(r.stdout.split("frames (")[1].split(" dropped")[0])
    cap = cv2.VideoCapture(str(out / "video.mp4"))
    n = 0
    while cap.read()[0]:
        n += 1
    assert dropped > 0 and n == 25 - dropped, (r.stdout, n)


def test_synth_seed_must_be_a_whole_number_from_zero(tmp_path):
    r = _run("--preset", "qvga_12fps", "--seed", "-1", "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and "--seed" in r.stderr and "Traceback" not in r.stderr
    f = tmp_path / "s.yaml"
    f.write_text("base: qvga_12fps\nseed: -3\n")
    r = _run("--scenario", str(f), "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and "field 'seed' must be a whole number from 0, got -3" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "o").exists()


def test_synth_scenario_file_errors_are_one_line(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text("base: highway_day\ntraffic:\n  flwo: 100\n")
    r = _run("--scenario", str(f), "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and "traffic.flwo" in r.stderr and "did you mean 'flow'" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    f.write_text("camera: {pan: -60, tilt: 60, offset: -40}\n")
    r = _run("--scenario", str(f), "--out", str(tmp_path / "o"), "--no-progress")
    assert r.returncode == 2 and "impossible camera" in r.stderr and "Traceback" not in r.stderr
    r = _run("--out", str(tmp_path / "o"))
    assert r.returncode == 2 and "exactly one of --preset" in r.stderr
