"""benchmarks/end_to_end.py: the split of a run's speed error into its scale part (λ err) and its vanishing-point
part (road err at the true λ), on the rendered cuboid clip's per-frame truth, and the per-scene table that shows
both; scene_fps."""

import json
import shutil
from pathlib import Path

import numpy as np

from .conftest import BRNO, require_shared


def test_road_error_is_the_vanishing_points_part_alone(load_benchmark, cuboid_clip_dense, tmp_path):
    from gst_trafficcal.calibration import load_calibration
    from gst_trafficcal.geometry import Camera

    b = load_benchmark("end_to_end")
    vp1 = load_benchmark("vp1_constant_speed")
    cam = load_calibration(cuboid_clip_dense / "calibration.json").camera
    assert abs(vp1.vp_road_error(cuboid_clip_dense, cam, cam.scale)) < 0.05
    # the run's own λ does not enter: only its vanishing points, measured at the scene's true scale
    assert abs(vp1.vp_road_error(cuboid_clip_dense, cam.with_scale(2 * cam.scale), cam.scale)) < 0.05
    # VP2 moved out along the horizon (a longer focal length): the road is stretched, by what vp1_constant_speed's
    # road distance error says for the same reference points
    moved = Camera(cam.vp1, cam.vp1 + 1.3 * (cam.vp2 - cam.vp1), cam.pp)
    err = vp1.vp_road_error(cuboid_clip_dense, moved, cam.scale)
    assert abs(err) > 1.0
    assert err == vp1.road_distance_error(vp1.reference_pairs(cuboid_clip_dense), moved, cam.scale)
    # nothing to measure against: no per-frame truth, or no true scale
    assert vp1.vp_road_error(tmp_path, cam, cam.scale) is None
    assert vp1.vp_road_error(cuboid_clip_dense, cam, None) is None


def test_scene_table_shows_both_parts(load_benchmark):
    b = load_benchmark("end_to_end")
    row = b.Row("session3_center", "replay", "auto", frames=3000, state="calibrated (vpdetect+bbscale)",
                has_vps=True, has_scale=True, scale_err_pct=-2.3, road_err_pct=-5.86, vehicles=21, measured=15,
                errors_kmh=[4.0, 5.0], truth_errors_kmh=[-3.0, -1.0, 1.0])
    no_vps = b.Row("zoom", "synth", "auto", state="vps (vpdetect)")
    text = b.scene_table([row, no_vps])
    header = text.splitlines()[0].split("|")
    cells = text.splitlines()[2].split("|")
    assert cells[header.index(" λ err % ")] == " -2.3 "
    assert cells[header.index(" road err % at true λ ")] == " -5.9 "
    assert text.splitlines()[3].split("|")[header.index(" road err % at true λ ")] == " – "
    # every measured vehicle: the mean of the absolute errors, their 95th percentile and the signed mean (a bias)
    assert cells[header.index(" every measured vehicle: n, mean / p95 km/h (signed mean) ")] == " 3, 1.67 / 2.80 (-1.00) "
    figs = b.pooled([row, no_vps])
    assert figs["scale_err_mean_abs_pct"] == 2.3 and np.isclose(figs["road_err_mean_abs_pct"], 5.86)


def test_reported_labels_are_scored_against_the_rendered_classes(load_benchmark, tmp_path):
    """Each measured vehicle is matched to the rendered vehicle its reference points follow; its label is scored
    against that vehicle's class (body styles named as the classifier's labels)."""
    import json

    from gst_trafficcal.calibration import Calibration
    from gst_trafficcal.outputs import BrnoResultsWriter, VehicleEvent
    from gst_trafficcal.tracking.simulate import default_camera

    b = load_benchmark("end_to_end")
    size = (960, 540)
    frames = tmp_path / "frames.jsonl"
    with open(frames, "w") as fh:
        for f in range(10):
            for vid, cls, x in ((7, "bus", 100.0), (8, "estate", 600.0)):
                fh.write(json.dumps({"frame": f, "id": vid, "class": cls, "ref": [x, 300.0 + 5 * f],
                                     "size": [12.0, 2.5, 3.2] if vid == 7 else [4.6, 1.8, 1.5],
                                     "speed_kmh": 80.0 if vid == 7 else 60.0}) + "\n")
    writer = BrnoResultsWriter(tmp_path / "system.json", fps=25.0)
    times = np.arange(10) / 25.0
    writer.add(1, times, [[101.0, 300.0 + 5 * f] for f in range(10)])  # follows the bus
    writer.add(2, times, [[599.0, 300.0 + 5 * f] for f in range(10)])  # follows the estate
    writer.write(Calibration(default_camera(size), size, source="test"))
    events = [VehicleEvent(1, "truck", 0.0, 0.36, 81.0, length_m=13.2, width_m=2.5, height_m=3.2),
              VehicleEvent(2, "car", 0.0, 0.36, 59.5),
              VehicleEvent(3, "car", 0.0, 0.36, None, reason="track too short")]
    got = b.truth_matches(frames, events, tmp_path / "system.json", size)
    assert [(m.speed_error_kmh, m.rendered_class, m.label, m.rendered_size, m.size) for m in got] == [
        (1.0, "bus", "truck", (12.0, 2.5, 3.2), (13.2, 2.5, 3.2)), (-0.5, "car", "car", (4.6, 1.8, 1.5), None)]
    rows = [b.Row("s", "synth", "auto", classes=[(m.rendered_class, m.label) for m in got] + [("bus", "bus")],
                  dims_log_ratio=[np.log(np.divide(got[0].size, got[0].rendered_size)).tolist()])]
    text = b.class_table(rows)
    cells = text.splitlines()[2].split("|")
    header = text.splitlines()[0].split("|")
    assert cells[header.index(" labelled right ")] == " 0.667 "
    assert cells[header.index(" bus ")] == " 1/2 (truck 1) " and cells[header.index(" car ")] == " 1/1 "
    assert cells[header.index(" van ")] == " – "
    assert np.isclose(b.pooled(rows)["class_accuracy"], 2 / 3)
    assert b.pooled(rows)["dimensions"] == {"vehicles": 1, "median": [0.095, 0.0, 0.0], "robust_std": [0.0, 0.0, 0.0]}
    assert "log(reported / rendered) length, width, height median [0.095, 0.0, 0.0]" in text


def test_the_traffic_count_is_scored_against_the_vehicles_that_passed(load_benchmark, tmp_path):
    """A rendered vehicle counts when it is at least half visible and as large as the detectors' smallest vehicle in
    10 frames; the count table gives each group's reported against rendered total and the scenes' count errors."""
    import json

    b = load_benchmark("end_to_end")
    size = (960, 540)
    frames = tmp_path / "frames.jsonl"
    with open(frames, "w") as fh:
        for f in range(12):
            for vid, box, visible in ((1, [0, 0, 40, 30], 1.0),  # 1200 px² >= 0.15 % of 960x540 (778 px²)
                                      (2, [0, 0, 20, 20], 1.0),  # too small: far down the road
                                      (3, [0, 0, 60, 40], 0.3)):  # mostly hidden
                fh.write(json.dumps({"frame": f, "id": vid, "box": box, "visible": visible}) + "\n")
            if f < 9:  # large and visible, but in nine frames only
                fh.write(json.dumps({"frame": f, "id": 4, "box": [0, 0, 60, 40], "visible": 1.0}) + "\n")
    assert b.passing_vehicles(frames, size) == 1
    with open(frames, "a") as fh:  # a replay's second car of the same recorded id (session0_center's ids 11, 25)
        for f in range(12):
            fh.write(json.dumps({"frame": f, "id": 1, "box": [100, 0, 140, 30], "visible": 1.0, "model": "b"}) + "\n")
    assert b.passing_vehicles(frames, size) == 2
    assert b.passing_vehicles(tmp_path / "none.jsonl", size) is None
    rows = [b.Row("a", "replay", "auto", vehicles=22, rendered=20), b.Row("b", "replay", "auto", vehicles=9,
                                                                             rendered=10),
            b.Row("c", "replay", "auto", vehicles=5, rendered=None)]
    line = b.count_table(rows).splitlines()[2]
    assert line == "| replay (2) | auto | 31 | 30 | +3.3 % | 10.0 % (a +10 %) |"


# scene_fps: a scene's frame rate for the benchmarks that read its truth by frame (count_breakdown,
# speed_uncertainty): the one the scores take (gt_data.pkl), then the render's scenario.json, then 25 said on stderr


def _scenario_fps(scene: Path, fps: float) -> None:
    (scene / "scenario.json").write_text(json.dumps({"imaging": {"fps": fps}}))


def test_scene_fps_takes_the_ground_truths_frame_rate_before_the_scenarios(load_benchmark, tmp_path, capsys):
    gt = require_shared(BRNO / "session0_center" / "gt_data.pkl")
    shutil.copy(gt, tmp_path / "gt_data.pkl")
    _scenario_fps(tmp_path, 12.5)  # another rate: which of the two was read shows
    assert load_benchmark("end_to_end").scene_fps(tmp_path) == 25.0  # the recording's own (real BrnoCompSpeed)
    assert capsys.readouterr().err == ""


def test_scene_fps_without_a_ground_truth_is_the_scenarios(load_benchmark, tmp_path, capsys):
    _scenario_fps(tmp_path, 12.5)
    assert load_benchmark("end_to_end").scene_fps(tmp_path) == 12.5
    assert capsys.readouterr().err == ""


def test_scene_fps_without_either_is_25_and_says_so(load_benchmark, tmp_path, capsys):
    (tmp_path / "scenario.json").write_text("{not json")
    assert load_benchmark("end_to_end").scene_fps(tmp_path) == 25.0
    err = capsys.readouterr().err
    assert str(tmp_path) in err and "taking 25 fps" in err
    (tmp_path / "scenario.json").unlink()  # none at all: the same
    assert load_benchmark("end_to_end").scene_fps(tmp_path) == 25.0
    assert "taking 25 fps" in capsys.readouterr().err
