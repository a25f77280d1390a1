"""Road-grid and horizon geometry of the calibration picture (drawing.py)."""

from __future__ import annotations

import numpy as np
import pytest

from gst_trafficcal.drawing import clip_segments, draw_calibration, horizon_segment, road_grid_segments
from gst_trafficcal.geometry import Camera, rotation_matrix

SIZE = (960, 540)


def _camera(pan: float = 15.0, tilt: float = 20.0, roll: float = 2.0, scale: float | None = 7.5) -> Camera:
    K = np.array([[900.0, 0, 480], [0, 900.0, 270], [0, 0, 1]])
    R = rotation_matrix(pan, tilt, roll)
    t = -R @ np.array([0.0, 0.0, 7.5])
    cam = Camera.from_KRt(K, R, t)
    return cam if scale is not None else cam.with_scale(None)


def _line_point_distance(segments: np.ndarray, point: np.ndarray) -> np.ndarray:
    d = segments[:, 1] - segments[:, 0]
    v = point - segments[:, 0]
    return np.abs(d[:, 0] * v[:, 1] - d[:, 1] * v[:, 0]) / np.linalg.norm(d, axis=1)


def test_clip_segments() -> None:
    segs = np.array([[[-10, 5], [20, 5]], [[5, -100], [5, 100]], [[-5, -5], [-1, -1]], [[1, 1], [3, 3]]], float)
    out, idx = clip_segments(segs, 10, 8)
    assert idx.tolist() == [0, 1, 3]
    np.testing.assert_allclose(out[0], [[0, 5], [9, 5]])
    np.testing.assert_allclose(out[1], [[5, 0], [5, 7]])
    np.testing.assert_allclose(out[2], segs[3])


@pytest.mark.parametrize("pan,tilt,roll", [(15, 20, 2), (-30, 12, -3), (60, 30, 0)])
def test_grid_lines_converge_at_the_vanishing_points(pan: float, tilt: float, roll: float) -> None:
    cam = _camera(pan, tilt, roll)
    grid = road_grid_segments(cam, SIZE, 3.0)
    assert len(grid.along) > 20 and len(grid.across) > 20
    scale = np.linalg.norm(SIZE)
    assert _line_point_distance(grid.along, cam.vp1).max() < 1e-6 * max(scale, np.linalg.norm(cam.vp1))
    assert _line_point_distance(grid.across, cam.vp2).max() < 1e-6 * max(scale, np.linalg.norm(cam.vp2))
    for segs in (grid.along, grid.across):  # inside the frame and below the horizon
        assert segs.min() >= -2 - 1e-9 and segs[..., 0].max() <= SIZE[0] + 1 and segs[..., 1].max() <= SIZE[1] + 1
        a, b, c = cam.horizon
        side = np.sign(a * cam.vp3[0] + b * cam.vp3[1] + c)
        assert np.all((segs @ np.array([a, b]) + c) * side > 0)


def test_grid_cells_are_spacing_metres_on_the_road() -> None:
    cam = _camera()
    grid = road_grid_segments(cam, SIZE, 2.5)
    assert grid.spacing_m == 2.5
    world = cam.to_world(grid.along.reshape(-1, 2))  # lines towards VP1 have constant y = k * spacing
    k = world[:, 1] / 2.5
    np.testing.assert_allclose(k, np.round(k), atol=1e-6)
    world = cam.to_world(grid.across.reshape(-1, 2))
    k = world[:, 0] / 2.5
    np.testing.assert_allclose(k, np.round(k), atol=1e-6)


def test_grid_without_scale_and_horizon() -> None:
    cam = _camera(tilt=12, scale=None)
    grid = road_grid_segments(cam, SIZE, 3.0)
    assert len(grid.along) and len(grid.across)
    seg = horizon_segment(cam, SIZE)
    assert seg is not None
    for vp in (cam.vp1, cam.vp2):
        assert _line_point_distance(seg[None], vp)[0] < 1e-6 * np.linalg.norm(vp)
    # a camera looking steeply down has its horizon above the frame
    steep = _camera(tilt=70)
    assert horizon_segment(steep, SIZE) is None


def test_draw_calibration_paints_grid_and_horizon() -> None:
    cam = _camera(tilt=12)
    img = np.zeros((SIZE[1], SIZE[0], 3), np.uint8)
    draw_calibration(img, cam, 3.0, thickness=1)
    painted = img.any(axis=2)
    assert 0.01 < painted.mean() < 0.5
    # the horizon row band is painted red-ish where the horizon runs
    seg = horizon_segment(cam, SIZE)
    mid = np.round(seg.mean(axis=0)).astype(int)
    patch = img[mid[1] - 2:mid[1] + 3, mid[0] - 2:mid[0] + 3].reshape(-1, 3)
    assert (patch[:, 2] > 150).any() and (patch[:, 2] > patch[:, 1] + 60).any()


def test_a_1080p_picture_is_no_denser_than_a_540p_one() -> None:
    """The same view at twice the resolution (and twice the line width) stops its grid where the 540p picture
    does, not further towards the horizon with cells a 1080p screen shows at half the size."""
    small = _camera()
    K = np.array([[1800.0, 0, 960], [0, 1800.0, 540], [0, 0, 1]])
    R = rotation_matrix(15.0, 20.0, 2.0)
    big = Camera.from_KRt(K, R, -R @ np.array([0.0, 0.0, 7.5]))
    tops = []
    for cam, (w, h), thick in ((small, SIZE, 1), (big, (1920, 1080), 2)):
        img = np.zeros((h, w, 3), np.uint8)
        draw_calibration(img, cam, 3.0, thickness=thick, horizon=False)
        tops.append(np.flatnonzero(img.any(axis=(1, 2)))[0] * SIZE[1] / h)
    assert tops[1] >= tops[0] - 2, tops


def test_draw_calibration_blends_the_grid_with_opacity() -> None:
    cam = _camera(tilt=12)
    grey = np.full((SIZE[1], SIZE[0], 3), 128, np.uint8)
    full, half = grey.copy(), grey.copy()
    draw_calibration(full, cam, 3.0, horizon=False)
    draw_calibration(half, cam, 3.0, horizon=False, opacity=0.5)
    d_full = np.abs(full.astype(int) - 128)
    d_half = np.abs(half.astype(int) - 128)
    assert d_full.max() > 100 and not (d_half > 0)[d_full == 0].any()
    assert np.all(np.abs(d_half - 0.5 * d_full) <= 1.0)


def test_lane_paths_are_drawn_in_their_lanes_colours_and_named() -> None:
    """Each vehicle's reference points in its lane's colour (grey without a lane); each lane named below where its
    vehicles came nearest; two lanes ending side by side get labels that do not overlap; a path of one point or of
    NaNs draws nothing."""
    from gst_trafficcal.drawing import NO_LANE_BGR, draw_lane_paths, lane_bgr

    img = np.zeros((360, 640, 3), np.uint8)
    paths = [(0, np.array([[100.0, 50.0], [100.0, 200.0]])), (0, np.array([[104.0, 60.0], [104.0, 210.0]])),
             (1, np.array([[130.0, 50.0], [130.0, 200.0]])), (None, np.array([[500.0, 50.0], [500.0, 300.0]])),
             (2, np.array([[300.0, 100.0]])), (3, np.full((4, 2), np.nan))]
    draw_lane_paths(img, paths)

    def near(bgr, rows, cols=slice(None)):  # pixels of about that colour (lines and text are anti-aliased)
        return np.argwhere(np.abs(img[rows, cols].astype(int) - bgr).max(axis=-1) < 40)

    assert near(lane_bgr(0), slice(120, 121), slice(99, 102)).size
    assert near(lane_bgr(1), slice(120, 121), slice(129, 132)).size
    assert near(NO_LANE_BGR, slice(120, 121), slice(499, 502)).size and lane_bgr(0) != lane_bgr(1)
    # the labels, off the paths' own columns: lane 0's under its lowest end (y 210), lane 1's — which would
    # overlap it there — moved above it
    zero = [(y, x) for y, x in near(lane_bgr(0), slice(None)) if y > 211]
    one = [(y, x) for y, x in near(lane_bgr(1), slice(None)) if not 128 <= x <= 132]
    assert len(zero) > 10 and len(one) > 10
    assert max(y for y, _ in one) < min(y for y, _ in zero)
    assert not near(lane_bgr(2), slice(None)).size and not near(lane_bgr(3), slice(None)).size
