"""BrnoCompSpeed formats: gt_data.pkl loading/saving and the results JSON reader/writer."""

from __future__ import annotations

import json
import os
import pickle

import numpy as np
import pytest

from gst_trafficcal.brnocompspeed import (BrnoCalibration, DistanceMeasurement, GroundTruth, GtCar, LineCrossing,
                                          Results, Track, gt_to_raw, load_gt_data, load_results, save_gt_data,
                                          save_results)
from gst_trafficcal.errors import InputError

from .conftest import BRNO, RECORDINGS, require_shared


def assert_same_gt(a: GroundTruth, b: GroundTruth) -> None:
    assert a.fps == b.fps and a.invalid_lanes == b.invalid_lanes and a.cars == b.cars
    assert np.array_equal(a.measurement_lines, b.measurement_lines)
    assert np.array_equal(a.lane_div_lines, b.lane_div_lines)
    assert len(a.distances) == len(b.distances)
    for x, y in zip(a.distances, b.distances):
        assert np.array_equal(x.p1, y.p1) and np.array_equal(x.p2, y.p2)
        assert (x.distance, x.to_vp1) == (y.distance, y.to_vp1)


@pytest.mark.parametrize("recording", RECORDINGS)
def test_load_real_gt(recording):
    path = require_shared(BRNO / recording / "gt_data.pkl")
    gt = load_gt_data(path)
    with open(path, "rb") as f:
        raw = pickle.load(f, encoding="latin1")
    assert gt.source == path
    assert gt.fps == raw["fps"] and gt.fps in (25.0, 50.0)
    assert gt.measurement_lines.shape == (len(raw["measurementLines"]), 3)
    assert np.array_equal(gt.lane_div_lines, np.array(raw["laneDivLines"]))
    assert len(gt.cars) == len(raw["cars"]) and len(gt.distances) == len(raw["distanceMeasurement"])
    for car, rc in zip(gt.cars, raw["cars"]):
        assert car.car_id == rc["carId"] and car.lanes == frozenset(rc["laneIndex"]) and car.valid == rc["valid"]
        assert car.match_time == rc["intersections"][-1]["videoTime"]
    d0, r0 = gt.distances[0], raw["distanceMeasurement"][0]
    assert np.array_equal(d0.p1, r0["p1"][:2] / r0["p1"][2]) and d0.distance == r0["distance"]
    assert gt.distances_to_vp1.any() and (~gt.distances_to_vp1).any()


def test_save_gt_round_trip_and_official_structure(tmp_path):
    src = require_shared(BRNO / "session1_left" / "gt_data.pkl")
    gt = load_gt_data(src)
    out = tmp_path / "gt_data.pkl"
    save_gt_data(gt, out)
    back = load_gt_data(out)
    assert_same_gt(back, gt)
    with open(src, "rb") as f:
        orig = pickle.load(f, encoding="latin1")
    with open(out, "rb") as f:
        mine = pickle.load(f, encoding="latin1")
    assert set(mine) == set(orig)
    assert set(mine["cars"][0]) == set(orig["cars"][0])
    assert set(mine["distanceMeasurement"][0]) == set(orig["distanceMeasurement"][0])
    assert mine["distanceMeasurement"][0]["p1"].shape == (3,) and isinstance(mine["cars"][0]["laneIndex"], set)
    assert np.allclose(mine["measurementLines"], orig["measurementLines"], rtol=0, atol=0)


def _tiny_gt() -> GroundTruth:
    lines = np.array([[0.0, 1.0, -800.0], [0.0, 1.0, -300.0]])
    lanes = np.array([[1.0, 0.0, -100.0], [1.0, 0.0, -500.0], [1.0, 0.0, -900.0]])
    return GroundTruth(
        fps=50.0, measurement_lines=lines, lane_div_lines=lanes, invalid_lanes=frozenset({1}),
        distances=(DistanceMeasurement(np.array([200.0, 700.0]), np.array([200.0, 400.0]), 6.0, True),
                   DistanceMeasurement(np.array([200.0, 700.0]), np.array([400.0, 700.0]), 3.5, False)),
        cars=(GtCar(3, frozenset({0}), True, 80.5, (LineCrossing(1, 1.5), LineCrossing(0, 2.0)), -3.25),))


def test_save_gt_synthetic(tmp_path):
    gt = _tiny_gt()
    save_gt_data(gt, tmp_path / "a" / "gt_data.pkl")
    back = load_gt_data(tmp_path / "a" / "gt_data.pkl")
    assert_same_gt(back, gt)
    assert back.invalid_lanes == {1} and back.cars[0].match_time == 2.0


def test_gt_errors(tmp_path):
    missing = tmp_path / "nope.pkl"
    with pytest.raises(InputError, match="nope.pkl: no such file"):
        load_gt_data(missing)
    garbage = tmp_path / "garbage.pkl"
    garbage.write_bytes(os.urandom(64) + b"not a pickle")
    with pytest.raises(InputError, match="garbage.pkl: not a readable gt_data pickle"):
        load_gt_data(garbage)
    wrong = tmp_path / "wrong.pkl"
    wrong.write_bytes(pickle.dumps({"fps": 50.0, "cars": []}, protocol=2))
    with pytest.raises(InputError, match=r"wrong.pkl: not a BrnoCompSpeed gt_data.pkl \(missing key"):
        load_gt_data(wrong)


@pytest.mark.parametrize("change, message", [
    (lambda raw: raw["cars"][0].update(speed=np.float64("nan")), r"cars\[0\].speed must be a finite number, got nan"),
    (lambda raw: raw["cars"][0]["intersections"][-1].update(videoTime=np.float64("inf")),
     r"cars\[0\] videoTime must be a finite number, got inf"),
    (lambda raw: raw["distanceMeasurement"][1].update(distance=0.0),
     r"distanceMeasurement\[1\].distance must be a positive number, got 0.0"),
])
def test_gt_with_values_no_measurement_has_is_refused(tmp_path, change, message):
    """Found by QA: one car's NaN speed made every speed statistic of the evaluation NaN (printed as nothing), one NaN
    crossing time dropped every system car as seen after the last ground-truth car (recall 0), and a segment 0 m
    long gave infinite relative errors -- each without a word."""
    raw = gt_to_raw(_tiny_gt())
    change(raw)
    path = tmp_path / "gt_data.pkl"
    path.write_bytes(pickle.dumps(raw, protocol=2))
    with pytest.raises(InputError, match=rf"gt_data.pkl: not a BrnoCompSpeed gt_data.pkl \({message}\)"):
        load_gt_data(path)


def test_files_are_written_whole_or_not_at_all(tmp_path):
    """save_results and save_gt_data write through fileio.atomic_write: a write that fails half-way leaves the
    earlier file as it was (it was cut to '{"cars": [' ), and a folder at the path is an InputError naming it
    (was IsADirectoryError)."""
    out = tmp_path / "system.json"
    good = Results(None, (Track(7, np.array([1, 2, 3]), np.ones((3, 2))),))
    save_results(good, out)
    before = out.read_text()
    with pytest.raises(TypeError):  # a car id json cannot write
        save_results(Results(None, (good.cars[0], Track(object(), np.array([1]), np.ones((1, 2))))), out)
    assert out.read_text() == before and sorted(p.name for p in tmp_path.iterdir()) == ["system.json"]
    (tmp_path / "folder").mkdir()
    with pytest.raises(InputError, match="folder: a folder, not a regular file: cannot write BrnoCompSpeed results"):
        save_results(good, tmp_path / "folder")
    with pytest.raises(InputError, match="folder: a folder, not a regular file: cannot write ground truth"):
        save_gt_data(_tiny_gt(), tmp_path / "folder")


class _Evil:
    def __reduce__(self):
        return (os.system, ("echo pwned",))


def test_gt_loader_refuses_code(tmp_path):
    evil = tmp_path / "evil.pkl"
    evil.write_bytes(pickle.dumps({"fps": _Evil()}, protocol=2))
    with pytest.raises(InputError, match="refusing to load"):
        load_gt_data(evil)


def test_results_real_file_round_trip(tmp_path):
    path = require_shared(BRNO / "session0_center" / "system_dubska_bmvc14.json")
    res = load_results(path)
    raw = json.loads(path.read_text())
    assert len(res.cars) == len(raw["cars"])
    assert res.calibration.vp1 == tuple(raw["camera_calibration"]["vp1"])
    assert res.calibration.scale == raw["camera_calibration"]["scale"]
    c0 = raw["cars"][0]
    assert np.array_equal(res.cars[0].pos[:, 0], c0["posX"]) and np.array_equal(res.cars[0].frames, c0["frames"])
    out = tmp_path / "r.json"
    save_results(res, out)
    again = json.loads(out.read_text())
    assert again["camera_calibration"] == raw["camera_calibration"]
    assert again["cars"][:5] == raw["cars"][:5]
    assert isinstance(again["cars"][0]["frames"][0], int)


@pytest.mark.parametrize("with_calibration", [True, False])
def test_results_are_written_a_car_at_a_time_as_json_dumps_would(tmp_path, with_calibration):
    """The file is the text of ``json.dumps`` of the whole document, but never whole in memory: a long run's 2000
    vehicles (some 3 MB) are written with less than a tenth of that at the peak."""
    import tracemalloc

    from gst_trafficcal.brnocompspeed import results_to_dict

    rng = np.random.default_rng(5)
    cars = [Track(i, np.arange(40) + 25.0 * i, rng.uniform(0, 1920, (40, 2))) for i in range(2000)]
    cars[1] = Track(1, np.array([3.0, 4.5, 6.0]), np.ones((3, 2)))  # a frame number that is not whole stays as it is
    calibration = BrnoCalibration((1.0, 2.0), (3.0, 4.0), (960.5, 540.5), 0.01) if with_calibration else None
    res, out = Results(calibration, tuple(cars)), tmp_path / "system.json"
    tracemalloc.start()
    try:
        save_results(res, out)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    text = out.read_text()
    assert text == json.dumps(results_to_dict(res))
    assert json.loads(text)["cars"][1]["frames"] == [3, 4.5, 6] and len(text) > 3_000_000
    assert peak < len(text) / 10, (peak, len(text))
    save_results(Results(calibration, ()), out)  # no vehicles yet
    assert json.loads(out.read_text())["cars"] == []


def test_results_write_read():
    res = Results(BrnoCalibration((1.0, 2.0), (3.0, 4.0), (960.5, 540.5), 0.01),
                  (Track(7, np.array([1, 2, 3]), np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 6.5]])),))
    assert res.calibration.to_dict() == {"vp1": [1.0, 2.0], "vp2": [3.0, 4.0], "pp": [960.5, 540.5], "scale": 0.01}


@pytest.mark.parametrize("doc, message", [
    ({"cars": [{"id": 1, "frames": [1, 2, 3], "posX": [1.0, 2.0], "posY": [1.0, 2.0, 3.0]}]},
     r"cars\[0\] \(id 1\) has lists of different lengths: frames 3, posX 2, posY 3"),
    ({"cars": [{"id": 1, "frames": [1], "posX": [1.0]}]}, r"cars\[0\] has no 'posY'"),
    ({"camera_calibration": {"vp1": [1, 2], "vp2": [3, 4], "pp": [960.5, 540.5], "scale": -1}, "cars": []},
     "scale must be a positive number"),
    ({"camera_calibration": {"vp1": [1, 2], "pp": [960.5, 540.5], "scale": 1}}, "has no 'vp2'"),
    ({"cars": [{"id": 1, "frames": [1], "posX": ["a"], "posY": [2.0]}]}, "posX must be a list of numbers"),
    ([1, 2, 3], "top level is not a JSON object"),
])
def test_results_errors(tmp_path, doc, message):
    path = tmp_path / "sys.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match="sys.json: not a BrnoCompSpeed results file .*" + message):
        load_results(path)


def test_results_unreadable(tmp_path):
    with pytest.raises(InputError, match="absent.json: no such file"):
        load_results(tmp_path / "absent.json")
    bad = tmp_path / "bad.json"
    bad.write_text('{"cars": [')
    with pytest.raises(InputError, match="bad.json: not valid JSON"):
        load_results(bad)


def test_scalar_positions_are_flagged(tmp_path):
    path = tmp_path / "s.json"
    path.write_text(json.dumps({"cars": [{"id": 1, "frames": 5, "posX": 10.0, "posY": 20.0},
                                         {"id": 2, "frames": [5], "posX": [10.0], "posY": [20.0]}]}))
    res = load_results(path)
    assert res.cars[0].scalar_positions and not res.cars[1].scalar_positions
    assert res.cars[0].pos.shape == (1, 2) and res.calibration is None
