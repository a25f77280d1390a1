"""BrnoCompSpeed evaluator: reproduces the official code's numbers on real data, plus unit cases and the CLI."""

from __future__ import annotations

import json
import subprocess
import sys
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest

from gst_trafficcal.brnocompspeed import (DistanceMeasurement, GroundTruth, GtCar, LineCrossing, Results, Track,
                                          load_gt_data, load_results)
from gst_trafficcal.evaluation import (ErrorStats, PreparedTracks, crossings, evaluate, lanes_of_points, match,
                                       median_speeds, prepare_tracks, prefilter)
from gst_trafficcal.geometry import Camera

from .conftest import BRNO, ROOT, require_shared

REFERENCE = BRNO / "official_eval_dubska_sessions0-3.json"
REL = 1e-6


def _reference_keys() -> list[str]:
    if not REFERENCE.exists():
        return ["reference-absent"]
    return sorted(json.loads(REFERENCE.read_text())["results"])


@lru_cache(maxsize=1)
def _reference() -> dict:
    return json.loads(REFERENCE.read_text())["results"]


@lru_cache(maxsize=None)
def _prepared(recording: str) -> tuple[GroundTruth, PreparedTracks]:
    gt = load_gt_data(BRNO / recording / "gt_data.pkl")
    return gt, prepare_tracks(load_results(BRNO / recording / "system_dubska_bmvc14.json"), gt)


def _stats_match(mine: ErrorStats, ref: dict) -> None:
    assert mine.n == ref["n"]
    for key in ("mean", "median", "p95", "max"):
        assert getattr(mine, key) == pytest.approx(ref[key], rel=REL, abs=1e-12), key


@pytest.mark.parametrize("entry", _reference_keys())
def test_matches_official_evaluation(entry):
    """Every number of the official code's output, for all 60 (recording, system) pairs."""
    require_shared(REFERENCE)
    ref = _reference()[entry]
    recording, system = entry.split("/")
    gt, prepared = _prepared(recording)
    if system == "system_dubska_bmvc14":  # the file's own calibration block
        block = load_results(BRNO / recording / "system_dubska_bmvc14.json").calibration.to_dict()
    else:
        cals = json.loads((BRNO / "dubska_calibrations.json").read_text())
        block = cals[recording][system.removeprefix("system_")]["camera_calibration"]
    assert block == ref["camera_calibration"]
    cam = Camera.from_brno(block["vp1"], block["vp2"], block["pp"], block["scale"])
    ev = evaluate(gt, cam, prepared=prepared)
    s, c = ev.speed, ev.calibration
    # counts
    assert s.n_cars_after_prefilter == ref["n_cars_after_prefilter"]
    assert s.n_intersection_errors == ref["n_intersection_errors"]
    assert s.linregress_identical_x == ref["linregress_identical_x_fallbacks"]
    assert (s.n_gt_cars, s.n_gt_valid) == (ref["n_gt_cars"], ref["n_gt_valid"])
    assert (s.matched, s.matched_valid) == (ref["n_matched"], ref["n_matched_valid"])
    assert s.false_positives == ref["false_positives"]
    assert s.recall == pytest.approx(ref["recall"], rel=REL)
    assert c.focal == pytest.approx(ref["focal"], rel=REL)
    # speed errors
    _stats_match(s.abs_kmh, {**ref["speed"]["abs_kmh"], "n": ref["speed"]["n"]})
    _stats_match(s.rel_pct, {**ref["speed"]["rel_pct"], "n": ref["speed"]["n"]})
    # calibration: distance ratios, distances with scale (all, towards VP1)
    _stats_match(c.ratio_abs, {**ref["calib_ratio"]["abs"], "n": ref["calib_ratio"]["n"]})
    _stats_match(c.ratio_rel_pct, {**ref["calib_ratio"]["rel_pct"], "n": ref["calib_ratio"]["n"]})
    n = ref["calib_dist_with_scale"]["n"]
    _stats_match(c.dist_all_abs_m, {**ref["calib_dist_with_scale"]["abs_m"], "n": n})
    _stats_match(c.dist_all_rel_pct, {**ref["calib_dist_with_scale"]["rel_pct"], "n": n})
    n = ref["dist_toVP1"]["n"]
    _stats_match(c.dist_vp1_abs_m, {**ref["dist_toVP1"]["abs_m"], "n": n})
    _stats_match(c.dist_vp1_rel_pct, {**ref["dist_toVP1"]["rel_pct"], "n": n})


# ----------------------------------------------------------------------------- unit cases on a small scene

LINES = np.array([[0.0, 1.0, -800.0], [0.0, 1.0, -300.0]])  # y = 800 (lines[0]) and y = 300 (lines[-1])
LANES = np.array([[1.0, 0.0, -100.0], [1.0, 0.0, -500.0], [1.0, 0.0, -900.0]])  # x = 100 | 500 | 900


def _gt(cars, invalid=frozenset()) -> GroundTruth:
    return GroundTruth(fps=50.0, measurement_lines=LINES, lane_div_lines=LANES, invalid_lanes=invalid,
                       distances=(DistanceMeasurement(np.array([300.0, 900.0]), np.array([320.0, 200.0]), 20.0, True),
                                  DistanceMeasurement(np.array([300.0, 900.0]), np.array([700.0, 900.0]), 3.5, False),
                                  DistanceMeasurement(np.array([320.0, 200.0]), np.array([650.0, 210.0]), 3.5,
                                                      False)),
                       cars=tuple(cars))


def _gt_car(car_id, lane, t, valid=True, speed=70.0):
    return GtCar(car_id, frozenset({lane}), valid, speed, (LineCrossing(1, t - 0.5), LineCrossing(0, t)))


def _track(track_id, x0, y0, vy, f0, n=60, dx=0.0):
    frames = np.arange(f0, f0 + n)
    return Track(track_id, frames, np.column_stack([x0 + dx * (frames - f0), y0 + vy * (frames - f0)]))


def test_lanes_of_points():
    pts = np.array([[50.0, 1.0], [100.0, 1.0], [300.0, 5.0], [700.0, 5.0], [950.0, 5.0], [np.nan, 3.0]])
    assert lanes_of_points(pts, LANES).tolist() == [-1, 0, 0, 1, -1, -1]


def test_crossing_of_straight_track_is_exact():
    # moving down 10 px per frame along x = 300 + 0.5 (y - 200) / 10 ... a slanted straight line
    t = _track(1, 300.0, 200.0, 10.0, 100, n=80, dx=0.5)
    c = crossings([t], LINES[0])
    # y = 800 at frame 100 + 60 = 160, x = 300 + 0.5 * 60 = 330
    assert c.point[0] == pytest.approx([330.0, 800.0, 1.0], abs=1e-9)
    assert c.frame[0] == pytest.approx(160.0, abs=1e-9)
    assert c.identical_x[0] == 0


def test_vertical_track_is_an_intersection_error_like_the_old_scipy():
    """Identical x: old scipy's linregress returned slope 0/0 = NaN, so the car cannot be measured."""
    gt = _gt([_gt_car(0, 0, 3.0)])
    vertical = _track(5, 300.0, 150.0, 10.0, 50, n=80)  # x constant
    slanted = _track(6, 305.0, 150.0, 10.0, 50, n=80, dx=0.1)
    prepared = prepare_tracks(Results(None, (vertical, slanted)), gt)
    assert prepared.ok.tolist() == [False, True]
    # the spatial fit of each line; the temporal fits then see NaN distances, which are not "identical"
    assert prepared.identical_x == 2
    m = match(gt, prepared)
    # the slanted car crosses y = 800 at frame 50 + 65 = 115 -> 2.3 s: 0.7 s from the gt time: no match
    assert m.n_matched == 0 and m.false_positives == 1  # only the intersection error (2.3 s is before 3.0 s)


def test_prefilter_rules():
    gt = _gt([_gt_car(0, 0, 3.0), _gt_car(1, 1, 20.0)], invalid=frozenset({1}))
    ok = _track(1, 300.0, 150.0, 10.0, 10, dx=0.1)
    late = _track(2, 300.0, 150.0, 10.0, 1000)  # first frame at 20 s = last gt time: dropped
    short = _track(3, 300.0, 150.0, 10.0, 10, n=5)
    outside = _track(4, 950.0, 150.0, 10.0, 10)  # right of the last divider
    invalid_lane = _track(5, 700.0, 150.0, 10.0, 10)
    border = Track(6, np.arange(8), np.array([[300.0, 5.0]] * 3 + [[300.0, 600.0 + k] for k in range(5)]))
    not_between = _track(7, 300.0, 850.0, 1.0, 10, n=30)  # stays below lines[0]
    scalar = Track(8, np.array([10.0]), np.array([[300.0, 500.0]]), scalar_positions=True)
    kept = prefilter([ok, late, short, outside, invalid_lane, border, not_between, scalar], gt)
    assert [t.id for t in kept] == [1]
    # border points are removed point-wise before counting: 5 inner points of track 6 remain -> too few
    gt2 = _gt([_gt_car(0, 0, 3.0)])
    border6 = Track(6, np.arange(9), np.array([[300.0, 5.0]] * 3 + [[300.0 + k, 600.0 + k] for k in range(6)]))
    kept = prefilter([border6], gt2)
    assert len(kept) == 1 and len(kept[0].frames) == 6 and kept[0].frames[0] == 3


def test_matching_nearest_in_time_lane_checked_first_on_ties():
    gt = _gt([_gt_car(0, 0, 2.0), _gt_car(1, 1, 2.0), _gt_car(2, 0, 9.0, valid=False), _gt_car(3, 0, 30.0)])
    # tracks crossing y = 800 at frame f0 + 60 (vy = 10 px/frame from y = 200)
    a = _track(10, 300.0, 200.0, 10.0, 40, dx=0.1)  # 100 / 50 = 2.0 s, lane 0
    b = _track(11, 310.0, 200.0, 10.0, 40, dx=0.1)  # same time, lane 0: a wins (first in file order)
    c = _track(12, 600.0, 200.0, 10.0, 45, dx=0.1)  # 2.1 s, lane 1
    d = _track(13, 300.0, 200.0, 10.0, 395, dx=0.1)  # 9.1 s, lane 0 -> matches the invalid gt car
    e = _track(14, 300.0, 200.0, 10.0, 700, dx=0.1)  # 15.2 s, in [2, 30): an unmatched false positive
    prepared = prepare_tracks(Results(None, (a, b, c, d, e)), gt)
    m = match(gt, prepared)
    ids = [None if i < 0 else prepared.tracks[i].id for i in m.track_of_gt]
    assert ids == [10, 12, 13, None]
    assert m.n_matched == 3 and m.n_matched_valid == 2 and m.recall == pytest.approx(2 / 3)
    assert m.false_positives == 2  # b (unmatched, 2.0 s) and e


def test_a_ground_truth_without_cars_matches_nothing():
    """No ground-truth car (a recording's empty minute): nothing matched, recall NaN, no false positive outside the
    ground truth's (empty) time span, and the speed report is empty — numpy's "zero-size array to reduction
    operation minimum which has no identity" before."""
    tracks = Results(None, (_track(10, 300.0, 200.0, 10.0, 40, dx=0.1),))
    prepared = prepare_tracks(tracks, _gt([_gt_car(0, 0, 2.0)]))  # the same scene's lines and lanes
    gt = _gt([])
    m = match(gt, prepared)
    assert m.track_of_gt.size == 0 and np.isnan(m.recall) and m.false_positives == 0 and m.n_matched == 0
    cam = Camera([500.0, -2000.0], [5000.0, 700.0], [500.0, 500.0], 10.0)
    speed = evaluate(gt, cam, prepared=prepared).speed
    assert speed.n_gt_cars == 0 and speed.matched == 0 and speed.cars == [] and np.isnan(speed.recall)


def test_median_speed_equals_per_car_median():
    rng = np.random.default_rng(3)
    cam = Camera.from_brno([300.0, -200.0], [9000.0, 300.0], [960.5, 540.5], 0.015)
    tracks = []
    for k, n in enumerate([6, 7, 12, 31, 2]):
        frames = np.sort(rng.choice(np.arange(200), size=n, replace=False))
        tracks.append(Track(k, frames, rng.uniform([200, 400], [1700, 1000], size=(n, 2))))
    got = median_speeds(tracks, cam, fps=50.0)
    for t, v in zip(tracks, got):
        if len(t.frames) <= 5:
            assert np.isnan(v)
            continue
        samples = [cam.distance(t.pos[i], t.pos[i + 5]) / (abs(t.frames[i + 5] - t.frames[i]) / 50.0) * 3.6
                   for i in range(len(t.frames) - 5)]
        assert v == pytest.approx(np.median(samples), rel=1e-12)


def test_error_stats_use_numpy_linear_percentiles():
    e = np.array([4.0, 1.0, 3.0, 2.0, 10.0])
    s = ErrorStats.of(e)
    assert (s.n, s.mean, s.median, s.max) == (5, 4.0, 3.0, 10.0)
    assert s.p95 == pytest.approx(8.8) and s.p99 == pytest.approx(9.76)
    assert ErrorStats.of([]).to_dict()["mean"] is None


def test_calibration_only_evaluation():
    gt = require_shared(BRNO / "session0_left" / "gt_data.pkl")
    gt = load_gt_data(gt)
    cam = Camera.from_brno([-370.809, -37.1511], [7377.43, 26.0692], [960.5, 540.5], None)
    ev = evaluate(gt, cam)
    assert ev.speed is None and ev.calibration.dist_all_abs_m is None
    d = ev.to_dict()
    assert set(d) == {"calibration"} and d["calibration"]["ratio_error"]["n"] == 91


# ----------------------------------------------------------------------------- command line

def _run(*args: str) -> subprocess.CompletedProcess:
    exe = ROOT / ".venv" / "bin" / "trafficcal"
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "gst_trafficcal"]
    return subprocess.run(cmd + list(args), capture_output=True, text=True, timeout=300)


def test_cli_eval_results_json_and_plot(tmp_path):
    rec = require_shared(BRNO / "session0_center")
    out, png = tmp_path / "eval.json", tmp_path / "speed.png"
    proc = _run("eval", "--gt", str(rec / "gt_data.pkl"), "--results", str(rec / "system_dubska_bmvc14.json"),
                "--json", str(out), "--plot", str(png))
    assert proc.returncode == 0, proc.stderr
    assert "recall" in proc.stdout and "distance ratio" in proc.stdout
    doc = json.loads(out.read_text())
    ref = json.loads(REFERENCE.read_text())["results"]["session0_center/system_dubska_bmvc14"]
    stats = {"mean", "median", "p95", "p99", "max"}
    assert stats <= set(doc["calibration"]["ratio_error"])
    for group in ("all", "to_vp1"):
        for unit in ("abs_m", "rel_pct"):
            assert stats <= set(doc["distance"][group][unit])
    for unit in ("abs_kmh", "rel_pct"):
        assert stats <= set(doc["speed"][unit])
    assert doc["speed"]["abs_kmh"]["mean"] == pytest.approx(ref["speed"]["abs_kmh"]["mean"], rel=REL)
    assert doc["recall"] == pytest.approx(ref["recall"], rel=REL)
    assert doc["false_positives"] == ref["false_positives"] and doc["matched"] == ref["n_matched"]
    assert doc["calibration"]["ratio_error"]["median"] == pytest.approx(ref["calib_ratio"]["abs"]["median"], rel=REL)
    assert doc["distance"]["to_vp1"]["rel_pct"]["p95"] == pytest.approx(ref["dist_toVP1"]["rel_pct"]["p95"], rel=REL)
    assert len(doc["cars"]) == ref["n_matched"]
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


def test_cli_eval_calibration_only(tmp_path):
    rec = require_shared(BRNO / "session1_right")
    cal = tmp_path / "cal.json"
    cals = json.loads((BRNO / "dubska_calibrations.json").read_text())
    block = cals["session1_right"]["dubska_optimal_calib"]["camera_calibration"]
    cal.write_text(json.dumps({"camera_calibration": block}))
    out = tmp_path / "e.json"
    proc = _run("eval", "--gt", str(rec / "gt_data.pkl"), "--calibration", str(cal), "--json", str(out))
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(out.read_text())
    ref = json.loads(REFERENCE.read_text())["results"]["session1_right/system_dubska_optimal_calib"]
    assert "speed" not in doc and "recall" not in doc
    assert doc["distance"]["all"]["abs_m"]["max"] == pytest.approx(ref["calib_dist_with_scale"]["abs_m"]["max"],
                                                                   rel=REL)


def _bad_inputs(tmp_path: Path) -> list[tuple[list[str], str]]:
    rec = BRNO / "session0_center"
    gt, res = str(rec / "gt_data.pkl"), str(rec / "system_dubska_bmvc14.json")
    corrupt_pkl = tmp_path / "corrupt.pkl"
    corrupt_pkl.write_bytes(b"\x80\x02}q\x00(X\x03\x00\x00\x00fps")
    corrupt_json = tmp_path / "corrupt.json"
    corrupt_json.write_text('{"camera_calibration": {"vp1": [1, 2]')
    uneven = tmp_path / "uneven.json"
    doc = json.loads(Path(res).read_text())
    doc["cars"][3]["posY"] = doc["cars"][3]["posY"][:-1]
    uneven.write_text(json.dumps(doc))
    wrong_side = tmp_path / "wrong_side.json"
    doc["cars"] = []
    doc["camera_calibration"]["vp2"] = [-500.0, -300.0]  # same side of pp as VP1: imaginary focal
    wrong_side.write_text(json.dumps(doc))
    small = tmp_path / "small.json"  # our calibration of a 640x360 camera against 1920x1080 ground truth
    small.write_text(json.dumps({"format": "gst-trafficcal-calibration", "version": 1, "image_size": [640, 360],
                                 "state": "vps", "vp1": [300.0, -60.0], "vp2": [8700.0, 360.0], "pp": [320.0, 180.0]}))
    return [
        (["--gt", str(tmp_path / "missing.pkl"), "--results", res], "missing.pkl: no such file"),
        (["--gt", str(corrupt_pkl), "--results", res], "corrupt.pkl: not a readable gt_data pickle"),
        (["--gt", gt, "--results", str(corrupt_json)], "corrupt.json: not valid JSON"),
        (["--gt", gt, "--results", str(uneven)], "uneven.json: not a BrnoCompSpeed results file (cars[3]"),
        (["--gt", gt, "--results", str(wrong_side)], "wrong_side.json: camera_calibration: vanishing points give "
                                                     "an imaginary focal length"),
        (["--gt", gt, "--calibration", str(wrong_side)], "wrong_side.json: vanishing points give an imaginary"),
        (["--gt", gt, "--calibration", str(small)], f"gt_data.pkl: a road marking at"),
        (["--gt", gt, "--calibration", str(small)], f"lies outside the 640x360 frame ({small}'s image_size): the "
                                                    "ground truth and what is scored are of different frame sizes"),
        (["--gt", gt, "--calibration", str(small), "--image-size", "1920x1080"],
         "small.json: calibration is for 640x360 frames, the recording's are 1920x1080 (--image-size)"),
        (["--gt", gt, "--results", res, "--plot", str(tmp_path)], f"{tmp_path}: is a folder; give the plot's file"),
        (["--gt", gt, "--results", res, "--plot", str(tmp_path / "e.txt")], "'.txt' is not an image format (one of"),
        (["--gt", gt, "--results", res, "--plot", str(tmp_path / "e")], "e: no extension (one of: "),
        (["--gt", gt, "--results", str(small)], "small.json: no 'cars' list, so no vehicles to score (a calibration "
                                                "file? give it as --calibration)"),
    ]


def test_cli_eval_bad_input(tmp_path):
    require_shared(BRNO / "session0_center")
    for args, message in _bad_inputs(tmp_path):
        proc = _run("eval", *args)
        assert proc.returncode == 2, (args, proc.stderr)
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("trafficcal: error: "), proc.stderr
        assert message in lines[0], (message, lines[0])
        assert "Traceback" not in proc.stderr
