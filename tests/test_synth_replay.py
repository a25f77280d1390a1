"""Replay mode: BrnoCompSpeed cars rendered over the recording's own frame at their real times and lanes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gst_trafficcal.brnocompspeed import load_gt_data
from gst_trafficcal.errors import InputError
from gst_trafficcal.evaluation import lanes_of_points
from gst_trafficcal.synth.generate import generate
from gst_trafficcal.synth.groundtruth import read_jsonl
from gst_trafficcal.synth.scenario import scenario_from_dict
from gst_trafficcal.synth.traffic import cuboid_models

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "brnocompspeed"


_box_model = cuboid_models(4.4, 1.8, 1.5)

@pytest.fixture(scope="module")
def replayed(tmp_path_factory):
    if not (SHARED / "session0_center" / "gt_data.pkl").exists():
        pytest.skip("../shared/data/brnocompspeed is not available")
    tmp = tmp_path_factory.mktemp("replay")
    block = json.loads((SHARED / "dubska_calibrations.json").read_text())["session0_center"]["dubska_optimal_calib"]
    (tmp / "cal.json").write_text(json.dumps(block))
    scen = scenario_from_dict({"duration": 2.5, "imaging": {"fps": 25, "noise": 0}, "replay": {
        "gt_data": str(SHARED / "session0_center" / "gt_data.pkl"), "calibration": str(tmp / "cal.json"),
        "start": 0.5}})
    res = generate(scen, tmp / "out", model_factory=_box_model, box_vehicles=True, write_video=False)
    return scen, tmp / "out", res


def test_replayed_cars_cross_the_real_line_at_the_real_time_in_the_real_lane(replayed):
    scen, out, res = replayed
    real = load_gt_data(SHARED / "session0_center" / "gt_data.pkl")
    gt = load_gt_data(out / "gt_data.pkl")
    np.testing.assert_allclose(gt.measurement_lines, real.measurement_lines)
    wanted = [c for c in real.cars if 0.5 <= c.intersections[-1].video_time < 3.0]
    assert [c.car_id for c in gt.cars] == [c.car_id for c in wanted] and len(wanted) >= 1
    recs = read_jsonl(out / "frames.jsonl")
    line0 = real.measurement_lines[0]
    for car in wanted:
        track = [r for r in recs if r["id"] == car.car_id]
        t = np.array([r["time"] for r in track])
        refs = np.array([r["ref"] for r in track])
        side = refs @ line0[:2] + line0[2]
        k = np.flatnonzero(np.sign(side[:-1]) != np.sign(side[1:]))
        assert len(k) == 1
        i = k[0]
        t_cross = t[i] + (t[i + 1] - t[i]) * side[i] / (side[i] - side[i + 1])
        assert t_cross == pytest.approx(car.intersections[-1].video_time - 0.5, abs=1e-3)
        lanes = lanes_of_points(refs[i:i + 2], real.lane_div_lines)
        assert set(lanes.tolist()) == set(car.lanes)
        assert track[0]["speed_kmh"] == pytest.approx(car.speed)


def test_replay_without_calibration_is_a_clear_error(tmp_path):
    if not (SHARED / "session0_center" / "gt_data.pkl").exists():
        pytest.skip("../shared/data/brnocompspeed is not available")
    scen = scenario_from_dict({"replay": {"gt_data": str(SHARED / "session0_center" / "gt_data.pkl")}})
    with pytest.raises(InputError, match="replay.calibration is required"):
        generate(scen, tmp_path, model_factory=_box_model, write_video=False)


def test_a_car_without_a_measured_speed_drives_past_at_its_lanes_median_speed(tmp_path):
    """BrnoCompSpeed's invalid cars have speed 0; replayed at 0 km/h they stood across line 0 for the whole clip
    and hid the cars behind them.  They now cross line 0 at their real time at the lane's median speed."""
    gt_path = SHARED / "session2_center" / "gt_data.pkl"
    if not gt_path.exists():
        pytest.skip("../shared/data/brnocompspeed is not available")
    real = load_gt_data(gt_path)
    car = next(c for c in real.cars if c.car_id == 1)
    assert car.speed == 0 and not car.valid
    lane_speeds = [c.speed for c in real.cars if c.speed > 0 and set(car.lanes) <= set(c.lanes)]
    block = json.loads((SHARED / "dubska_calibrations.json").read_text())["session2_center"]["dubska_optimal_calib"]
    (tmp_path / "cal.json").write_text(json.dumps(block))
    start = car.intersections[-1].video_time - 1.0
    scen = scenario_from_dict({"duration": 2.0, "imaging": {"fps": 25, "noise": 0}, "replay": {
        "gt_data": str(gt_path), "calibration": str(tmp_path / "cal.json"), "start": start}})
    generate(scen, tmp_path / "out", model_factory=_box_model, box_vehicles=True, write_video=False)
    track = [r for r in read_jsonl(tmp_path / "out" / "frames.jsonl") if r["id"] == car.car_id]
    assert track, "the invalid car is rendered"
    assert track[0]["speed_kmh"] == pytest.approx(float(np.median(lane_speeds)))
    refs = np.array([r["ref"] for r in track])
    side = refs @ real.measurement_lines[0][:2] + real.measurement_lines[0][2]
    assert np.sign(side[0]) != np.sign(side[-1]), "it crosses line 0 during the clip"
    replayed = next(c for c in load_gt_data(tmp_path / "out" / "gt_data.pkl").cars if c.car_id == car.car_id)
    assert replayed.speed == 0 and not replayed.valid, "still invalid in the ground truth (not scored)"
