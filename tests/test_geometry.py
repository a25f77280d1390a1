"""Camera model: round trips through random pinhole cameras, and the BrnoCompSpeed scale convention."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gst_trafficcal.errors import GeometryError
from gst_trafficcal.geometry import Camera, focal_from_vps, rotation_matrix

from .conftest import BRNO, RECORDINGS, require_shared

cameras = st.tuples(
    st.floats(2.0, 80.0) | st.floats(-80.0, -2.0),  # pan (not 0: VP2 would be at infinity)
    st.floats(3.0, 70.0),                            # tilt down
    st.floats(-25.0, 25.0),                          # roll
    st.floats(300.0, 6000.0),                        # focal (px)
    st.floats(3.0, 30.0),                            # height (m)
    st.floats(-15.0, 15.0),                          # lateral offset of the camera (m)
)


def make_pinhole(pan, tilt, roll, focal, height, offset):
    K = np.array([[focal, 0, 960.0], [0, focal, 540.0], [0, 0, 1]])
    R = rotation_matrix(pan, tilt, roll)
    C = np.array([0.0, offset, height])
    return K, R, -R @ C, C


def project(K, R, t, X):
    x = (K @ (R @ X.T + t[:, None])).T
    return x[:, :2] / x[:, 2:]


def road_points_in_view(R, C, rng, n=20):
    """Random road points (z = 0) in front of the camera, 5..200 m along its viewing direction."""
    fwd = R[2] * np.array([1, 1, 0])
    fwd /= np.linalg.norm(fwd)
    side = np.array([-fwd[1], fwd[0], 0])
    a = rng.uniform(5, 200, n)
    b = rng.uniform(-0.3, 0.3, n) * a
    X = C * np.array([1, 1, 0]) + a[:, None] * fwd + b[:, None] * side
    keep = (R @ (X - C).T)[2] > 1.0
    return X[keep]


@settings(max_examples=300, deadline=None)
@given(cameras, st.integers(0, 2**31 - 1))
def test_random_cameras_recovered(params, seed):
    pan, tilt, roll, focal, height, offset = params
    K, R, t, C = make_pinhole(*params)
    cam = Camera.from_KRt(K, R, t)
    assert cam.focal == pytest.approx(focal, rel=1e-6)
    assert cam.scale == pytest.approx(height, rel=1e-6)
    # the recovered rotation equals the truth up to the choice of the forward direction of the road
    K2, R2, t2 = cam.to_KRt()
    assert np.allclose(K2, K, rtol=1e-6)
    flip = np.diag(np.sign(np.diag(R.T @ R2)))
    assert np.allclose(R2, R @ flip, atol=1e-6)
    assert np.linalg.det(R2) == pytest.approx(1.0)
    assert np.allclose(-R2.T @ t2, [0, 0, height], atol=1e-6 * height)
    # road distances in metres
    X = road_points_in_view(R, C, np.random.default_rng(seed))
    if len(X) < 2:
        return
    p = project(K, R, t, X)
    truth = np.linalg.norm(X[1:] - X[:-1], axis=1)
    measured = cam.distance(p[1:], p[:-1])
    assert np.allclose(measured, truth, rtol=1e-6)
    # image -> world -> image, and world -> image agrees with the pinhole
    assert np.allclose(cam.world_to_image(cam.to_world(p)), p, atol=1e-6 * focal)
    assert np.allclose(cam.from_road(cam.to_road(p)), p, atol=1e-6 * focal)
    # the horizon passes through both VPs, VP3 is orthogonal to the road
    assert abs(np.dot(cam.horizon, [*cam.vp1, 1])) < 1e-6 * np.linalg.norm(cam.vp1 - cam.pp) + 1e-6
    assert abs(np.dot(cam.normal, cam.rotation[:, 0])) < 1e-9
    # round trip through K, R, t
    back = Camera.from_KRt(K2, R2, t2)
    assert np.allclose(back.vp1, cam.vp1, rtol=1e-6) and np.allclose(back.vp2, cam.vp2, rtol=1e-6)


@settings(max_examples=100, deadline=None)
@given(cameras)
def test_brno_scale_round_trip(params):
    cam = Camera.from_KRt(*make_pinhole(*params)[:3])
    back = Camera.from_brno(cam.vp1, cam.vp2, cam.pp, cam.brno_scale())
    assert back.scale == pytest.approx(cam.scale, rel=1e-9)


def test_focal_formula():
    assert focal_from_vps([1000.0, 500.0], [-3000.0, 600.0], [960.0, 540.0]) == pytest.approx(
        np.sqrt(-np.dot([40.0, -40.0], [-3960.0, 60.0])))
    assert np.isnan(focal_from_vps([1000.0, 500.0], [3000.0, 600.0], [960.0, 540.0]))


@pytest.mark.parametrize("vp1, vp2, message", [
    ([1000.0, 100.0], [3000.0, 200.0], "imaginary focal"),       # both VPs on the same side
    ([960.0, 540.0], [3000.0, 200.0], "imaginary focal"),        # VP1 at the principal point
    ([float("nan"), 0.0], [3000.0, 200.0], "finite"),
])
def test_rejects_impossible_vanishing_points(vp1, vp2, message):
    with pytest.raises(GeometryError, match=message):
        Camera(vp1, vp2, [960.0, 540.0])


@pytest.mark.parametrize("kwargs, message", [
    (dict(vp1=[[1000.0, 100.0], [1.0, 2.0]]), r"vp1 must be one image point \(x, y\), got shape \(2, 2\)"),
    (dict(pp=960.0), r"pp must be one image point \(x, y\), got shape \(\)"),
    (dict(scale="8"), "scale must be a positive number, got '8'"),
    (dict(scale=True), "scale must be a positive number, got True"),
])
def test_a_camera_of_wrong_shapes_or_types_is_a_geometry_error(kwargs, message):
    """Found by QA: a 2x2 vanishing point was numpy's 'cannot reshape', a single number an IndexError, a scale given
    as text a TypeError from np.isfinite, and True a scale of 1 m."""
    args = dict(vp1=[1000.0, 100.0], vp2=[-3000.0, 200.0], pp=[960.0, 540.0], scale=None) | kwargs
    with pytest.raises(GeometryError, match=message):
        Camera(**args)
    with pytest.raises(GeometryError, match=r"points must have 2 coordinates in its last axis, got shape \(\)"):
        Camera([1000.0, 100.0], [-3000.0, 200.0], [960.0, 540.0]).to_road(5.0)
    assert Camera(np.array([1000, 100]), [-3000, 200], np.array([[960, 540]]), np.int64(8)).scale == 8.0


def test_rejects_camera_below_road_and_vp_at_infinity():
    K, R, t, C = make_pinhole(20, 10, 0, 1000, 5, 0)
    with pytest.raises(GeometryError, match="not above the road"):
        Camera.from_KRt(K, R, -R @ (C * [1, 1, -1]))
    K, R, t, C = make_pinhole(0.0, 10, 0, 1000, 5, 0)  # looking straight along the road: VP2 at infinity
    with pytest.raises(GeometryError, match="infinity"):
        Camera.from_KRt(K, R, t)


@pytest.mark.parametrize("direction", [[0, 0], [1.0, float("nan")], [1.0, 0.0, 0.0]])
def test_from_krt_refuses_a_traffic_direction_that_is_none(direction):
    """A zero, NaN or 3D traffic direction is said as such; [0, 0] was divided by its zero length (numpy's
    "invalid value encountered in divide") and ended in "an imaginary focal length ((vp1-pp)·(vp2-pp) = nan)"."""
    import warnings

    K, R, t, _ = make_pinhole(20, 10, 0, 1000, 5, 0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(GeometryError, match=r"the traffic direction must be a 2D direction in the road plane "
                                                r"\(x, y, not both 0\), got \["):
            Camera.from_KRt(K, R, t, direction=direction)


def test_distance_needs_scale():
    cam = Camera([1000.0, 100.0], [-3000.0, 200.0], [960.0, 540.0])
    with pytest.raises(GeometryError, match="no scale"):
        cam.distance([0, 800], [100, 900])


def _official_projection(vp1, vp2, pp, p):
    """BrnoCompSpeed's road-plane projection (code/loading.py), written out independently for comparison."""
    f = np.sqrt(-np.dot(vp1 - pp, vp2 - pp))
    w = np.cross(np.append(vp1 - pp, f), np.append(vp2 - pp, f))
    vp3 = w[:2] / w[2] * f + pp
    n = np.append(vp3, f) - np.append(pp, 0)
    plane = np.append(n / np.linalg.norm(n), 10.0)
    origin = np.append(pp, 0.0)
    ray = np.append(p, f) - origin
    tt = -np.dot(plane, np.append(origin, 1)) / np.dot(plane[:3], ray)
    return origin + tt * ray


def test_brno_convention_matches_official_projection_and_ground_truth():
    calibs = json.loads(require_shared(BRNO / "dubska_calibrations.json").read_text())
    rel_errors = []
    for rec in RECORDINGS:
        with open(BRNO / rec / "gt_data.pkl", "rb") as fh:
            gt = pickle.load(fh, encoding="latin1")
        block = calibs[rec]["dubska_optimal_calib"]["camera_calibration"]
        vp1, vp2, pp = (np.asarray(block[k], float) for k in ("vp1", "vp2", "pp"))
        cam = Camera.from_brno(vp1, vp2, pp, block["scale"])
        for seg in gt["distanceMeasurement"]:
            p1, p2 = seg["p1"][:2] / seg["p1"][2], seg["p2"][:2] / seg["p2"][2]
            official = block["scale"] * np.linalg.norm(
                _official_projection(vp1, vp2, pp, p1) - _official_projection(vp1, vp2, pp, p2))
            ours = float(cam.distance(p1, p2))
            assert ours == pytest.approx(official, rel=1e-9)
            rel_errors.append(abs(ours - seg["distance"]) / seg["distance"])
    # calibrations optimised on the ground truth reproduce the measured distances within a few percent
    assert np.median(rel_errors) < 0.04
