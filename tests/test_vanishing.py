"""VP1 from tracks, VP2 from edgelets, the streaming calibrator and `trafficcal calibrate` on real and exact inputs."""

from __future__ import annotations

import functools

import cv2
import numpy as np
import pytest

from gst_trafficcal.diamond import angle_between
from gst_trafficcal.errors import InputError
from gst_trafficcal.geometry import Camera, homogeneous, rotation_matrix
from gst_trafficcal.vanishing.calibrator import CalibratorConfig, VPCalibrator
from gst_trafficcal.vanishing.edgelets import detect_edgelets, detect_gradient_edgels, towards
from gst_trafficcal.vanishing.tracks import fit_lines



# ------------------------------------------------------------------ an exact moving-cuboid scene
W, H, FPS = 480, 270, 15.0


def scene_camera() -> Camera:
    """Camera 7 m above a straight road, panned, tilted and slightly rolled (exact VPs)."""
    f = 420.0
    K = np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1.0]])
    R = rotation_matrix(25.0, 14.0, 3.0)
    C = np.array([0.0, -7.0, 7.0])  # camera centre (world): beside the road, 7 m up
    return Camera.from_KRt(K, R, -R @ C)


def box_corners(x: float, y: float, length=4.4, width=1.8, height=1.5) -> np.ndarray:
    dx, dy = length / 2, width / 2
    base = np.array([[x + dx, y + dy], [x + dx, y - dy], [x - dx, y - dy], [x - dx, y + dy]])
    return np.vstack([np.c_[base, np.zeros(4)], np.c_[base, np.full(4, height)]])


FACES = [(0, 1, 2, 3), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
SHADES = [40, 215, 150, 95, 175, 120]


def render_scene(seconds: float, seed: int = 0, traffic: bool = True, camera: Camera | None = None
                 ) -> list[np.ndarray]:
    """Grey frames of cuboid vehicles driving along world x on a textured road, drawn with OpenCV (seen by
    :func:`scene_camera` unless another ``camera`` is given)."""
    cam = scene_camera() if camera is None else camera
    rng = np.random.default_rng(seed)
    bg = cv2.GaussianBlur(rng.normal(110, 25, (H, W)).astype(np.float32), (0, 0), 2.0)
    for lane_y in (-3.5, 0.0, 3.5, 7.0):  # painted lines towards VP1
        pts = cam.world_to_image(np.array([[-5.0, lane_y - 1.75, 0], [400.0, lane_y - 1.75, 0]]))
        cv2.line(bg, tuple(np.int32(pts[0])), tuple(np.int32(pts[1])), 200, 1, cv2.LINE_AA)
    cars = [(rng.uniform(0, 8), lane, rng.uniform(15, 30) * (1 if lane < 3 else -1))
            for lane in (-1.75, 1.75, 5.25, 8.75) for _ in range(6)]
    cars = [(t0 + k * 3.0 * 2, lane, v) for k, (t0, lane, v) in enumerate(cars)]
    frames = []
    for i in range(int(seconds * FPS)):
        t = i / FPS
        img = bg.copy()
        if traffic:
            drawn = []
            for t0, lane, v in cars:
                x = 5.0 + v * ((t - t0) % 10.0) if v > 0 else 150.0 + v * ((t - t0) % 10.0)
                X = box_corners(x, lane)
                depth = cam.world_to_camera(X)[:, 2]
                if np.any(depth < 1.0):
                    continue
                drawn.append((depth.mean(), cam.world_to_image(X), X))
            for _, px, X in sorted(drawn, key=lambda d: -d[0]):
                cc = cam.world_to_camera(X)
                order = sorted(range(6), key=lambda k: -cc[list(FACES[k]), 2].mean())
                for k in order:
                    cv2.fillConvexPoly(img, np.int32(np.round(px[list(FACES[k])] * 16)), SHADES[k], cv2.LINE_AA, 4)
        img += rng.normal(0, 2.0, img.shape).astype(np.float32)
        frames.append(np.clip(img, 0, 255).astype(np.uint8))
    return frames


@functools.lru_cache(maxsize=2)
def cached_scene(seconds: float) -> tuple[np.ndarray, ...]:
    """The 24 s traffic scene, rendered once per test session (shared with the element tests)."""
    return tuple(render_scene(seconds))


@pytest.fixture(scope="module")
def cuboid_frames():
    return cached_scene(24.0)


def _fast_config(**kw) -> CalibratorConfig:
    base = dict(min_duration=8.0, check_interval=2.0, min_tracks=40, min_edgelets=800)
    base.update(kw)
    return CalibratorConfig(**base)


# ------------------------------------------------------------------ edgelets
@pytest.mark.parametrize("deg", [2.0, 17.0, 45.0, 71.0, 88.0, 123.0])
def test_edgelet_orientation_and_quality_on_a_straight_edge(deg):
    img = np.full((160, 160), 60, np.uint8)
    t = np.radians(deg)
    d, n, c = np.array([np.cos(t), np.sin(t)]), np.array([-np.sin(t), np.cos(t)]), np.array([80.0, 80.0])
    poly = np.array([c - d * 300, c + d * 300, c + d * 300 + n * 300, c - d * 300 + n * 300])
    cv2.fillPoly(img, [np.int32(poly * 16)], 180, cv2.LINE_AA, 4)
    for orientation in ("svd", "tensor"):
        e = detect_edgelets(img, None, orientation=orientation)
        e = e.subset(np.linalg.norm(e.points - c, axis=1) < 50)
        assert len(e) >= 5
        ang = np.degrees(np.arctan2(e.directions[:, 1], e.directions[:, 0]))
        err = (ang - deg + 90) % 180 - 90
        assert np.abs(err).max() < 1.5, (orientation, err)
        assert np.median(np.abs((e.points - c) @ n)) < 1.5  # on the edge
        assert np.median(e.quality) > 2.0  # elongated neighbourhood
    g = detect_gradient_edgels(img, None)
    assert len(g) >= 10


def test_edgelet_quality_is_low_on_a_corner_blob():
    img = np.full((60, 60), 60, np.uint8)
    cv2.circle(img, (30, 30), 3, 200, -1)
    e = detect_edgelets(img, None)
    assert len(e) and np.median(e.quality) < 1.6


def test_edgelets_respect_the_mask_and_empty_masks():
    img = np.zeros((100, 100), np.uint8)
    img[:, 50:] = 200
    mask = np.zeros((50, 50), np.uint8)  # any size: resized to the image
    assert len(detect_edgelets(img, mask)) == 0
    mask[:25] = 255
    e = detect_edgelets(img, mask)
    assert len(e) and np.all(e.points[:, 1] < 52)


def test_towards_selects_edgelets_pointing_at_a_point_also_at_infinity():
    from gst_trafficcal.vanishing.edgelets import Edgelets

    pts = np.array([[0.0, 0.0], [10.0, 0.0]])
    dirs = np.array([[1.0, 0.0], [0.0, 1.0]])
    e = Edgelets(pts, dirs, np.ones(2), np.ones(2))
    assert towards(e, np.array([100.0, 0.0, 1.0]), 2).tolist() == [True, False]
    assert towards(e, np.array([0.0, 1.0, 0.0]), 2).tolist() == [False, True]


def test_fit_lines_recovers_a_track_line_from_running_sums():
    rng = np.random.default_rng(0)
    t = np.linspace(0, 50, 30)
    x, y = 10 + 0.8 * t, 20 + 0.6 * t + rng.normal(0, 0.1, t.size)
    sums = np.array([[t.size, x.sum(), y.sum(), (x * x).sum(), (x * y).sum(), (y * y).sum()]])
    line, resid = fit_lines(sums)
    assert np.abs(line[0] @ np.array([10 + 0.8 * 25, 20 + 0.6 * 25, 1.0])) < 0.1
    assert abs(abs(line[0, :2] @ np.array([0.6, -0.8])) - 1) < 1e-3
    assert resid[0] < 0.2


# ------------------------------------------------------------------ calibrator on exact frames
def test_calibrator_finds_both_vanishing_points_of_an_exact_scene(cuboid_frames):
    cam = scene_camera()
    cal = VPCalibrator((W, H), _fast_config())
    changes = [cal.add(f, i / FPS) for i, f in enumerate(cuboid_frames)]
    result = cal.finish()
    assert result.state == "vps", result.reason
    assert sum(changes) == 1
    est = result.camera
    f = cam.focal
    assert angle_between(homogeneous(est.vp1), homogeneous(cam.vp1), cam.pp, f) < 0.5
    assert angle_between(homogeneous(est.vp2), homogeneous(cam.vp2), cam.pp, f) < 2.0
    assert abs(est.focal - f) / f < 0.08
    assert 0 < result.confidence["vp1"] <= 1 and 0 < result.confidence["vp2"] <= 1
    assert result.camera.scale is None


def test_calibrator_moves_vp1_along_the_lanes_only_when_asked(cuboid_frames):
    """The constant-speed step (vanishing/constant_speed.py) reports how far it moved VP1 and on how many tracks;
    switched off, VP1 is the Diamond Space's peak."""
    cam = scene_camera()
    results = {}
    for key, kw in ((True, {}), (False, {"vp1_constant_speed": False}), ("capped", {"max_along": 1e-4})):
        cal = VPCalibrator((W, H), _fast_config(**kw))
        for i, f in enumerate(cuboid_frames):
            cal.add(f, i / FPS)
        results[key] = (cal.finish(), cal)
    (with_speed, cal_on), (without, cal_off) = results[True], results[False]
    # a move larger than max_along (a share of VP1's distance from the tracks) is refused and reported
    capped, cal_capped = results["capped"]
    assert "vp1_along_px" not in capped.confidence
    assert capped.confidence["vp1_along_refused_px"] == with_speed.confidence["vp1_along_px"]
    assert np.allclose(capped.camera.vp1, without.camera.vp1)
    assert 0 < abs(cal_capped.along.relative) < 0.01
    assert with_speed.state == without.state == "vps"
    assert with_speed.confidence["speed_tracks"] >= 100 and "vp1_along_px" in with_speed.confidence
    assert "vp1_along_px" not in without.confidence and cal_off.along is None
    assert np.allclose(without.camera.vp1, cal_off.vp1_diamond.xy)
    # moved along the lanes, then across them to where the tracks' lines meet (vp1_across_lines)
    moved = np.linalg.norm(with_speed.camera.vp1 - cal_on.vp1_diamond.xy)
    assert "vp1_across_px" in with_speed.confidence and "vp1_across_px" not in capped.confidence
    assert abs(moved - np.hypot(with_speed.confidence["vp1_along_px"], with_speed.confidence["vp1_across_px"])) < 0.05
    assert np.linalg.norm(with_speed.camera.vp1 - cam.vp1) < 1.0


def test_calibrator_learns_only_inside_its_zone(cuboid_frames):
    """A zone over the whole frame changes nothing; over the left half, fewer tracks and edgelets, still both
    vanishing points; over a corner no vehicle crosses, nothing to learn from, and the reason says where; a zone
    that covers no pixel of the frame is refused."""
    from gst_trafficcal.zone import parse_zone

    def run(zone: str):
        cal = VPCalibrator((W, H), _fast_config(zone=parse_zone(zone)))
        for i, f in enumerate(cuboid_frames):
            cal.add(f, i / FPS)
        return cal.finish(), cal

    (plain, p), (whole, w), (half, h), (corner, c) = (run(z) for z in (
        "", "0,0 1,0 1,1 0,1", "0,0 0.5,0 0.5,1 0,1", "0,0 40,0 40,30 0,30"))
    assert whole.state == plain.state == "vps" and (w.n_tracks, w.n_edgelets) == (p.n_tracks, p.n_edgelets)
    assert np.allclose(whole.camera.vp1, plain.camera.vp1) and np.allclose(whole.camera.vp2, plain.camera.vp2)
    assert half.state == "vps" and 0 < h.n_tracks < 0.5 * p.n_tracks and 0 < h.n_edgelets < 0.6 * p.n_edgelets
    assert angle_between(homogeneous(half.camera.vp1), homogeneous(plain.camera.vp1), p.pp, plain.camera.focal) < 0.5
    assert corner.state == "failed" and c.n_tracks == 0
    assert corner.reason.startswith("no traffic: only 0 straight vehicle tracks inside the zone"), corner.reason
    with pytest.raises(InputError, match="zone 500,0 600,0 600,50: it covers no pixel of the 480x270 frame"):
        VPCalibrator((W, H), _fast_config(zone=parse_zone("500,0 600,0 600,50")))


def test_calibrator_on_static_and_tiny_inputs_says_why():
    static = render_scene(6.0, traffic=False)
    cal = VPCalibrator((W, H), _fast_config(min_duration=1.0))
    for i, f in enumerate(static):
        cal.add(f, i / FPS)
    res = cal.finish()
    assert res.state == "failed" and res.reason.startswith("no traffic"), res.reason
    one = VPCalibrator((W, H), _fast_config())
    one.add(static[0], 0.0)
    assert one.finish().reason.startswith("too short")
    assert VPCalibrator((W, H)).finish().reason.startswith("no frames")
    with pytest.raises(InputError):
        VPCalibrator((8, 8))
    with pytest.raises(InputError):
        VPCalibrator((W, H)).add(np.zeros((10, 10), np.uint8), 0.0)
    with pytest.raises(InputError):
        VPCalibrator((W, H), CalibratorConfig(focal_range=(100.0, 50.0)))


def test_calibrator_gives_up_at_max_duration(cuboid_frames):
    """Not converged by max_duration (here: far too few tracks asked for): failed, with the reason, at 6 s; a
    minimum longer than the maximum, which could only ever fail, is refused."""
    with pytest.raises(InputError, match=r"the minimum duration \(100 s\) is longer than the maximum \(6 s\)"):
        _fast_config(min_duration=100.0, max_duration=6.0)
    cal = VPCalibrator((W, H), _fast_config(min_duration=6.0, max_duration=6.0, min_tracks=10**6))
    for i, f in enumerate(cuboid_frames):
        cal.add(f, i / FPS)
        if cal.done:
            break
    assert cal.state == "failed" and "need 1000000" in cal.reason, cal.reason
    assert cal.t < 8.5
