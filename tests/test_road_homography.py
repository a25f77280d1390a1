"""The calibration as a road-plane homography and four correspondences (road_homography.py, calibration.json)."""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from gst_trafficcal.brnocompspeed import load_gt_data
from gst_trafficcal.calibration import Calibration, load_calibration
from gst_trafficcal.errors import GeometryError
from gst_trafficcal.geometry import Camera, rotation_matrix
from gst_trafficcal.road_homography import image_to_road, road_homography

from .conftest import BRNO, RECORDINGS, require_shared

SIZE = (1280, 720)


def _camera(pan: float, tilt: float, roll: float, f: float = 1100.0, height: float = 7.0) -> Camera:
    K = np.array([[f, 0, 640.0], [0, f, 360.0], [0, 0, 1]])
    R = rotation_matrix(pan, tilt, roll)
    return Camera.from_KRt(K, R, -R @ np.array([0.0, 0.0, height]))


@pytest.mark.parametrize("pan,tilt,roll", [(15, 20, 2), (-30, 12, -3), (60, 30, 0), (5, 8, 4)])
def test_the_homography_maps_image_points_to_their_road_metres(pan, tilt, roll):
    cam = _camera(pan, tilt, roll)
    H = image_to_road(cam)
    rng = np.random.default_rng(1)
    world = np.column_stack([rng.uniform(8, 80, 50), rng.uniform(-15, 15, 50), np.zeros(50)])
    img = cam.world_to_image(world)
    back = cv2.perspectiveTransform(img.reshape(-1, 1, 2), H).reshape(-1, 2)
    np.testing.assert_allclose(back, world[:, :2], atol=1e-6 * 80)
    # and distances through it are the calibration's own
    d = np.linalg.norm(back[1:] - back[:-1], axis=1)
    np.testing.assert_allclose(d, cam.distance(img[1:], img[:-1]), rtol=1e-8)


@pytest.mark.parametrize("pan,tilt,roll", [(15, 20, 2), (-30, 12, -3), (60, 30, 0), (5, 8, 4)])
def test_four_points_inside_the_frame_below_the_horizon_give_the_same_matrix(pan, tilt, roll):
    cam = _camera(pan, tilt, roll)
    rh = road_homography(cam, SIZE)
    src = rh.source_px
    assert src.shape == (4, 2) and np.all(src == np.round(src))
    assert np.all((src >= 0) & (src <= [SIZE[0] - 1, SIZE[1] - 1]))
    a, b, c = cam.horizon
    below = (a * src[:, 0] + b * src[:, 1] + c) * np.sign(b) > 50  # well below the horizon, in pixels
    assert below.all(), (src, cam.horizon)
    np.testing.assert_allclose(rh.target_m, cam.to_world(src)[:, :2], atol=1e-9)
    H = cv2.getPerspectiveTransform(src.astype(np.float32), rh.target_m.astype(np.float32))
    np.testing.assert_allclose(H / H[2, 2], rh.image_to_road_m, rtol=2e-4, atol=1e-7)


def test_no_road_in_the_frame_is_an_error_and_the_calibration_file_goes_without_it():
    up = _camera(20, -25, 0)  # looking up: the horizon below the frame
    with pytest.raises(GeometryError):
        road_homography(up, SIZE)
    d = Calibration(up, SIZE, "calibrated", source="test").to_dict()
    assert "camera" in d and "road_homography" not in d


def test_no_scale_no_homography():
    cam = _camera(15, 20, 2).with_scale(None)
    with pytest.raises(GeometryError, match="scale"):
        image_to_road(cam)
    assert "road_homography" not in Calibration(cam, SIZE, "vps", source="test").to_dict()


@pytest.mark.parametrize("name", [r for r in RECORDINGS if r.endswith("center")])
def test_a_real_manual_calibration_file_measures_the_road_through_plain_opencv(name, tmp_path):
    """What an integrator does with calibration.json and nothing of ours: calibrate-manual on a BrnoCompSpeed
    recording's measurements, then cv2.perspectiveTransform with the file's matrix over the recording's measured
    segments — the lengths calibrate-manual reports (its calibration's), within its own error of the tape."""
    gt_path = require_shared(BRNO / name / "gt_data.pkl")
    out = tmp_path / "cal.json"
    subprocess.run([sys.executable, "-m", "gst_trafficcal", "calibrate-manual", "--gt", str(gt_path), "-o", str(out)],
                   check=True, capture_output=True)
    raw = json.loads(out.read_text())
    H = np.array(raw["road_homography"]["image_to_road_m"])
    gt = load_gt_data(gt_path)
    p1 = cv2.perspectiveTransform(gt.distances_p1.reshape(-1, 1, 2), H).reshape(-1, 2)
    p2 = cv2.perspectiveTransform(gt.distances_p2.reshape(-1, 1, 2), H).reshape(-1, 2)
    lengths = np.linalg.norm(p1 - p2, axis=1)
    cam = load_calibration(out).camera
    np.testing.assert_allclose(lengths, cam.distance(gt.distances_p1, gt.distances_p2), rtol=1e-7)
    assert np.median(np.abs(lengths - gt.distances_m) / gt.distances_m) < 0.1, (lengths, gt.distances_m)
    # the four points lie on the road in the recording's own frame, and loading ignores the derived block
    src = np.array(raw["road_homography"]["source_px"])
    assert np.all((src >= 0) & (src < [1920, 1080]))
    assert load_calibration(out).to_dict()["road_homography"] == raw["road_homography"]
