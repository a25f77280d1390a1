"""benchmarks/calibration.py: a scene rendered earlier scored as it is, with CalibratorConfig fields set from the
command line (the rendered 12 s cuboid clip, too short for VP2 under the default evidence threshold)."""

import re


def test_config_fields_reach_the_calibrator(load_benchmark, cuboid_clip_dense):
    b = load_benchmark("calibration")
    default = b.score(cuboid_clip_dense, "edgelets", 60.0)
    # shorter than the 20 s vpdetect waits for, which the reason says first (stop 45), then what was missing
    assert default["state"] == "failed" and re.match(r"too short: 1[12]\.\d s of video, need at least 20 s; VP1 found "
                                                     r"at ", default["reason"])
    assert "too few edges on vehicles for VP2" in default["reason"]
    assert "ratio_mean" not in default
    # every edgelet (not only those inside the boxes), and a lower threshold: 2315 of them in its 12 s
    row = b.score(cuboid_clip_dense, "edgelets", 60.0, {"min_edgelets": 1000, "interior_edges": 0.0})
    assert row["state"] == "vps" and row["ratio_mean"] < 0.05
    assert abs(row["focal_signed"]) == row["focal_err"] and row["focal_err"] < 0.1
    # the interior ones alone (about 400) are enough for a VP2 too
    row = b.score(cuboid_clip_dense, "edgelets", 60.0, {"min_edgelets": 300})
    assert row["state"] == "vps" and row["ratio_mean"] < 0.05
    # the view's conditioning, from the run's VPs and from the scene's own camera (an oblique view: well conditioned)
    from gst_trafficcal.vanishing.conditioning import view_conditioning

    assert row["sens_pct"] == view_conditioning(row["_camera"], (480, 270)).speed_pct
    assert 0 < row["sens_true_pct"] < 2 and abs(row["sens_pct"] / row["sens_true_pct"] - 1) < 0.5
    # and a focal range the scene's camera is far outside of: no second vanishing point is accepted
    narrow = b.score(cuboid_clip_dense, "edgelets", 60.0, {"min_edgelets": 300, "focal_range": (1.0, 2.0)})
    assert narrow["state"] == "failed" and "ratio_mean" not in narrow


def test_scene_folders_are_checked_before_any_run(tmp_path, cuboid_clip_dense):
    """A missing or incomplete --scenes folder stops the benchmark at once, naming what is missing."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    (tmp_path / "half").mkdir()
    (tmp_path / "half" / "video.mp4").write_bytes(b"")
    scenes = f"{cuboid_clip_dense},{tmp_path / 'half'},{tmp_path / 'nowhere'}"
    proc = subprocess.run([sys.executable, str(root / "benchmarks" / "calibration.py"), "--presets", "",
                           "--scenes", scenes], capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    assert f"{tmp_path / 'half'}: no calibration.json" in proc.stderr
    assert f"{tmp_path / 'nowhere'}: no video.mp4" in proc.stderr
    assert str(cuboid_clip_dense) + ":" not in proc.stderr and proc.stdout == ""


def test_conditioning_summary_counts_and_ranks(load_benchmark):
    b = load_benchmark("calibration")
    rows = [{"scene": "a", "sens_pct": 0.3, "road_err_pct": -0.2},
            {"scene": "b", "sens_pct": 12.0, "road_err_pct": -4.0},
            {"scene": "c", "sens_pct": 4.0, "road_err_pct": 0.5}, {"scene": "d", "sens_pct": 1.5, "road_err_pct": 3.0},
            {"scene": "e", "sens_pct": float("inf"), "road_err_pct": 5.0}, {"scene": "f", "state": "failed"}]
    text = b.conditioning_summary(rows)
    assert "over 5 runs: Spearman rho 0.90" in text  # ranks 1,4,3,2,5 against 1,4,2,3,5: 1 - 6·2/120
    assert "called poor (>= 2 %): 3, of which road err >= 2 %: 2 (b, e)" in text
    assert "not called poor but road err >= 2 %: 1 (d)" in text
    assert "poor views 3.17 %, the others 1.60 %" in text
    assert "fewer than 3" in b.conditioning_summary(rows[:2])
