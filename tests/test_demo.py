"""The README's main job (`trafficcal demo`) end to end on a short built-in scene."""

from __future__ import annotations

import json
import subprocess
import sys

import cv2

from gst_trafficcal.outputs import read_events


def test_demo_writes_every_output(tmp_path):
    out = tmp_path / "demo"
    proc = subprocess.run([sys.executable, "-m", "gst_trafficcal", "demo", "--preset", "qvga_12fps", "--duration",
                           "8", "--out", str(out)], capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-2000:] + proc.stdout[-2000:]
    for name in ("scene/video.mp4", "scene/gt_data.pkl", "calibration.json", "calibration_auto.json",
                 "vehicles.jsonl", "vehicles.csv", "system.json", "evaluation.json", "overlay.mp4", "report.html"):
        assert (out / name).is_file(), name
    evaluation = json.loads((out / "evaluation.json").read_text())
    # the manual baseline on exact synthetic road markings is close to perfect
    assert evaluation["calibration"]["ratio_error"]["mean"] < 0.02
    assert "recall" in evaluation and "false_positives" in evaluation
    assert read_events(out / "vehicles.jsonl").events, "the pipeline tracked no vehicle"
    cap = cv2.VideoCapture(str(out / "overlay.mp4"))
    frames = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    ok, frame = cap.read()
    cap.release()
    assert ok and frame.shape[:2] == (240, 320) and frames >= 90  # 8 s at 12.5 fps
    assert "data:image/png;base64," in (out / "report.html").read_text()
    assert "Against the ground truth" in proc.stdout
    assert "vehicle classes right" in proc.stdout  # the labels by size, against the render's classes
    from gst_trafficcal.calibration import load_calibration

    auto, printed = load_calibration(out / "calibration_auto.json"), " ".join(proc.stdout.split())
    if auto.camera is not None:  # the automatic VPs with how firmly the view pins the speeds down
        assert f"VP2 lies {auto.conditioning().vp2_widths:.1f} image widths away" in printed
    else:
        assert "Automatic VPs (vpdetect): not converged" in printed
