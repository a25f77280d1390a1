"""Manual-calibration baseline (ManualCalib + ManualScale): exact synthetic scene, real markings, CLI."""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from gst_trafficcal.brnocompspeed import DistanceMeasurement, GroundTruth, GtCar, LineCrossing, load_gt_data
from gst_trafficcal.calibration import load_calibration
from gst_trafficcal.errors import GeometryError, InputError
from gst_trafficcal.evaluation import ErrorStats, evaluate_calibration
from gst_trafficcal.geometry import Camera, line_through, rotation_matrix
from gst_trafficcal.manual_calibration import (batch_plane_distances, calibrate_manual, image_centre,
                                               intersect_lines_lsq, manual_scale, size_doubt)

from .conftest import BRNO, RECORDINGS, ROOT, require_shared

PP = np.array([960.5, 540.5])


def _camera(pan=20.0, tilt=14.0, roll=3.0, f=1800.0, height=7.5) -> Camera:
    K = np.array([[f, 0, PP[0]], [0, f, PP[1]], [0, 0, 1]])
    R = rotation_matrix(pan, tilt, roll)
    return Camera.from_KRt(K, R, -R @ np.array([0.0, 0.0, height]))


def _synthetic_gt(cam: Camera) -> GroundTruth:
    """Road markings of a straight 3-lane road seen by ``cam``: dividers, segments along and across it."""
    img = lambda X: cam.world_to_image(np.asarray(X, float))  # noqa: E731
    dividers = [-1.75 - 3.5 * k for k in range(4)] + [1.75]
    lane_lines = np.array([line_through(img([25.0, y, 0]), img([60.0, y, 0])) for y in sorted(dividers)])
    distances = []
    for y in (-1.75, -5.25, -8.75):
        for x0 in (25.0, 31.0, 37.0):
            distances.append(DistanceMeasurement(img([x0, y, 0]), img([x0 + 6.0, y, 0]), 6.0, True))
    for x in (26.0, 42.0):
        for y0 in (-1.75, -5.25, -8.75):
            distances.append(DistanceMeasurement(img([x, y0, 0]), img([x, y0 - 3.5, 0]), 3.5, False))
    lines = np.array([line_through(img([30.0, 0, 0]), img([30.0, -10, 0])),
                      line_through(img([45.0, 0, 0]), img([45.0, -10, 0]))])
    car = GtCar(0, frozenset({0}), True, 80.0, (LineCrossing(1, 1.0), LineCrossing(0, 1.7)))
    return GroundTruth(50.0, lines, lane_lines, frozenset(), tuple(distances), (car,))


def test_intersect_lines_lsq_exact_and_degenerate():
    p = np.array([1234.5, -321.0])
    lines = np.array([line_through(p, p + d) for d in ([100.0, 7.0], [-3.0, 50.0], [40.0, 40.0])]) * [[2], [1], [5]]
    assert intersect_lines_lsq(lines) == pytest.approx(p, abs=1e-7)
    with pytest.raises(GeometryError, match="parallel"):
        intersect_lines_lsq(np.array([[0.0, 1.0, -3.0], [0.0, 2.0, -10.0]]))


def test_batch_plane_distances_agree_with_camera():
    cam = _camera()
    rng = np.random.default_rng(0)
    p1, p2 = rng.uniform([100, 600], [1800, 1000], (2, 7, 2))
    vp2s = np.array([cam.vp2, _camera(pan=30, f=2500).vp2])
    vp2s[1] = cam.vp2 * 1.1 + [0, 40]  # some other VP2 on the right side
    got = batch_plane_distances(cam.vp1, vp2s, PP, p1, p2)
    for k, v in enumerate(vp2s):
        ref = Camera(cam.vp1, v, PP).plane_distance(p1, p2)
        ratio = got[k] / ref
        assert ratio == pytest.approx(np.full(7, ratio[0]), rel=1e-9)  # equal up to one factor per camera


@pytest.mark.parametrize("pan, tilt, roll, f", [(20.0, 14.0, 3.0, 1800.0), (-35.0, 9.0, -2.0, 3200.0),
                                                  (8.0, 22.0, 0.0, 1200.0)])
def test_recovers_synthetic_camera(pan, tilt, roll, f):
    truth = _camera(pan, tilt, roll, f)
    gt = _synthetic_gt(truth)
    result = calibrate_manual(gt)
    cam = result.camera
    assert cam.vp1 == pytest.approx(truth.vp1, rel=1e-9, abs=1e-6)
    assert cam.focal == pytest.approx(truth.focal, rel=2e-3)
    assert cam.scale == pytest.approx(truth.scale, rel=2e-3)
    assert result.cost_m < 0.02 and result.n_vp1_segments == 9 and result.n_vp2_segments == 6
    rep = evaluate_calibration(gt, cam)
    assert rep.ratio_abs.max < 2e-3 and rep.dist_all_abs_m.max < 0.02
    assert manual_scale(truth.with_scale(None), gt.distances_p1, gt.distances_p2, gt.distances_m) == \
        pytest.approx(truth.scale, rel=1e-9)


@pytest.mark.parametrize("pan, tilt, roll, f", [(20.0, 14.0, 3.0, 1800.0), (-35.0, 9.0, -2.0, 3200.0)])
def test_grid_search_without_first_guess(pan, tilt, roll, f):
    """VP2 segments on one image line give no intersection: the grid search alone must find VP2."""
    truth = _camera(pan, tilt, roll, f)
    gt = _synthetic_gt(truth)
    one_line = gt.distances[:12]  # 9 along the road, then the 3 across it at x = 26 m (collinear)
    gt = GroundTruth(gt.fps, gt.measurement_lines, gt.lane_div_lines, gt.invalid_lanes, one_line, gt.cars)
    assert sum(not d.to_vp1 for d in gt.distances) == 3
    result = calibrate_manual(gt)
    assert result.vp2_initial is None
    assert result.camera.focal == pytest.approx(truth.focal, rel=1e-4)
    assert result.camera.scale == pytest.approx(truth.scale, rel=1e-4)
    assert evaluate_calibration(gt, result.camera).ratio_abs.max < 1e-4


def test_image_centre_convention():
    assert image_centre((1920, 1080)).tolist() == [960.5, 540.5]


def test_real_recordings_land_near_the_paper():
    """The paper's ManualCalib: mean distance-ratio error 0.02, median 0.01 (all BrnoCompSpeed sessions)."""
    ratios, to_vp1 = [], []
    for rec in RECORDINGS:
        gt = load_gt_data(require_shared(BRNO / rec / "gt_data.pkl"))
        cam = calibrate_manual(gt).camera
        assert cam.pp.tolist() == [960.5, 540.5]
        ratios.append(evaluate_calibration(gt, cam).ratio_abs)
        p1, p2, d, t = gt.distances_p1, gt.distances_p2, gt.distances_m, gt.distances_to_vp1
        to_vp1.append(np.abs(cam.distance(p1[t], p2[t]) - d[t]))
    per_recording_mean = np.mean([r.mean for r in ratios])
    assert per_recording_mean < 0.03
    assert max(r.mean for r in ratios) < 0.1
    assert ErrorStats.of(np.concatenate(to_vp1)).mean < 0.15  # paper: 0.10 m


def test_errors():
    cam = _camera()
    gt = _synthetic_gt(cam)
    only_vp1 = GroundTruth(gt.fps, gt.measurement_lines, gt.lane_div_lines, gt.invalid_lanes,
                           tuple(d for d in gt.distances if d.to_vp1), gt.cars)
    with pytest.raises(InputError, match="towards VP2 \\(0\\)"):
        calibrate_manual(only_vp1)
    parallel = GroundTruth(gt.fps, gt.measurement_lines, np.array([[1.0, 0, -10], [1.0, 0, -20]]),
                           gt.invalid_lanes, gt.distances, gt.cars)
    with pytest.raises(GeometryError, match="lane dividers: the lines are parallel"):
        calibrate_manual(parallel)


def _run(*args: str) -> subprocess.CompletedProcess:
    exe = ROOT / ".venv" / "bin" / "trafficcal"
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "gst_trafficcal"]
    return subprocess.run(cmd + list(args), capture_output=True, text=True, timeout=300)


def test_cli_calibrate_manual_then_eval(tmp_path):
    rec = require_shared(BRNO / "session2_left")
    out = tmp_path / "manual.json"
    proc = _run("calibrate-manual", "--gt", str(rec / "gt_data.pkl"), "-o", str(out))
    assert proc.returncode == 0, proc.stderr
    cal = load_calibration(out)
    assert cal.source == "manual-calibration" and cal.state == "calibrated"
    doc = json.loads(out.read_text())
    assert doc["camera_calibration"]["pp"] == [960.5, 540.5]
    assert doc["camera_calibration"]["scale"] == pytest.approx(cal.camera.brno_scale())
    report = tmp_path / "eval.json"
    proc = _run("eval", "--gt", str(rec / "gt_data.pkl"), "--calibration", str(out), "--json", str(report))
    assert proc.returncode == 0, proc.stderr
    ev = json.loads(report.read_text())
    assert ev["calibration"]["ratio_error"]["mean"] < 0.05
    # the same numbers as the library gives
    gt = load_gt_data(rec / "gt_data.pkl")
    lib = evaluate_calibration(gt, calibrate_manual(gt).camera)
    assert ev["distance"]["to_vp1"]["abs_m"]["mean"] == pytest.approx(lib.dist_vp1_abs_m.mean, rel=1e-9)


def test_cli_calibrate_manual_bad_input(tmp_path):
    bad = tmp_path / "gt.pkl"
    bad.write_text("this is not a pickle")
    for args, message in [(["--gt", str(tmp_path / "none.pkl")], "none.pkl: no such file"),
                          (["--gt", str(bad)], "gt.pkl: not a readable gt_data pickle")]:
        proc = _run("calibrate-manual", *args, "-o", str(tmp_path / "o.json"))
        assert proc.returncode == 2
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("trafficcal: error: ") and message in lines[0]
    assert not (tmp_path / "o.json").exists()


def test_cli_calibrate_manual_of_a_smaller_recording(cuboid_clip, tmp_path):
    """BrnoCompSpeed's ground truth holds no frame size: with --image the size is the picture's (the true camera
    back), without it 1920x1080 is assumed and markings all in its top-left quarter are warned about; a calibration
    named .png with --image (its picture would overwrite it) is refused before any work."""
    truth = load_calibration(cuboid_clip / "calibration.json")
    assert truth.image_size == (480, 270)
    out = tmp_path / "manual.json"
    proc = _run("calibrate-manual", "--gt", str(cuboid_clip / "gt_data.pkl"), "--image",
                str(cuboid_clip / "video.mp4"), "-o", str(out))
    assert proc.returncode == 0 and "warning" not in proc.stderr, proc.stderr
    cal = load_calibration(out)
    assert cal.image_size == (480, 270) and (out.with_suffix(".png")).is_file()
    assert cal.camera.focal == pytest.approx(truth.camera.focal, rel=0.02)
    assert cal.camera.scale == pytest.approx(truth.camera.scale, rel=0.02)
    proc = _run("calibrate-manual", "--gt", str(cuboid_clip / "gt_data.pkl"), "-o", str(tmp_path / "big.json"))
    assert proc.returncode == 0
    assert "every road marking lies in the top-left quarter of the 1920x1080 frame" in proc.stderr
    png = tmp_path / "cal.png"
    proc = _run("calibrate-manual", "--gt", str(cuboid_clip / "gt_data.pkl"), "--image",
                str(cuboid_clip / "video.mp4"), "-o", str(png))
    assert proc.returncode == 2 and "name the calibration .json" in proc.stderr and not png.exists()


def test_cli_calibrate_manual_writes_its_picture_whole_or_not_at_all(cuboid_clip, tmp_path):
    """The picture beside the calibration is written whole, then renamed (fileio.atomic_write_image): a disk that
    fills up meanwhile (a file-size limit below the picture's size) leaves the earlier picture as it was, no
    temporary file, and one line saying so; before, cv2.imwrite left the first part of a picture in its place."""
    import resource

    out, png = tmp_path / "manual.json", tmp_path / "manual.png"
    png.write_bytes(b"the earlier picture")
    exe = ROOT / ".venv" / "bin" / "trafficcal"
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "gst_trafficcal"]
    limit = 32 * 1024  # the calibration (~2 kB) fits, the picture (480x270) does not
    proc = subprocess.run(cmd + ["calibrate-manual", "--gt", str(cuboid_clip / "gt_data.pkl"), "--image",
                                 str(cuboid_clip / "video.mp4"), "-o", str(out)], capture_output=True, text=True,
                          timeout=300, preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit)))
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert proc.stderr.strip().splitlines()[-1] == f"trafficcal: error: {png}: cannot write picture (File too large)"
    assert load_calibration(out).state == "calibrated"
    assert png.read_bytes() == b"the earlier picture"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["manual.json", "manual.png"]  # no temporary file
    proc = _run("calibrate-manual", "--gt", str(cuboid_clip / "gt_data.pkl"), "--image",
                str(cuboid_clip / "video.mp4"), "-o", str(out))
    assert proc.returncode == 0 and cv2.imread(str(png)).shape == (270, 480, 3), proc.stderr[-2000:]


def test_size_doubt_tells_markings_outside_the_frame_from_markings_in_its_corner() -> None:
    """Outside the frame: certainly measured in another size; all in its top-left quarter: perhaps; else none."""
    outside = size_doubt(np.array([[100.0, 100.0], [2000.0, 500.0]]), (1920, 1080))
    assert outside is not None and outside.outside
    assert outside.text == "a road marking at (2000, 500) lies outside the 1920x1080 frame"
    corner = size_doubt(np.array([[100.0, 100.0], [900.0, 500.0]]), (1920, 1080))
    assert corner is not None and not corner.outside and "top-left quarter" in corner.text
    assert size_doubt(np.array([[100.0, 100.0], [1500.0, 900.0], [np.nan, 5.0]]), (1920, 1080)) is None
    assert size_doubt(np.empty((0, 2)), (1920, 1080)) is None
