"""Overlay drawing (overlay.py) on BGR images and straight into I420/NV12/packed/grey planes."""

from __future__ import annotations

from functools import partial

import cv2
import numpy as np
import pytest

from gst_trafficcal.geometry import Camera, rotation_matrix
from gst_trafficcal.overlay import (
    BOX_EDGES, GridCache, OverlayOptions, PanelPlacer, Style, VehicleCounter, VehicleMark, bgr_to_yuv,
    calibration_status, canvas_for_bgr, canvas_for_planes, draw_overlay, mark_label, marks_from_params, wrap_lines,
)
from gst_trafficcal.tracking.box3d import EDGES
from gst_trafficcal.tracking.tracker import Observation, Track, TrackState
from gst_trafficcal.tracking.vehicle_meta import vehicle_fields

W, H = 320, 240
GREY = (128, 128, 128)
STYLE = Style()
NO_TEXT = OverlayOptions(labels=False, speeds=False, counters=False)


def _camera() -> Camera:
    K = np.array([[300.0, 0, W / 2], [0, 300.0, H / 2], [0, 0, 1]])
    R = rotation_matrix(20.0, 15.0, 0.0)
    return Camera.from_KRt(K, R, -R @ np.array([0.0, 0.0, 6.0]))


def _road_point(cam: Camera, x: float, y: float) -> tuple[float, float]:
    """The image point of road point (x, y) metres."""
    return tuple(float(v) for v in cam.world_to_image(np.array([x, y, 0.0])))


def _corners(cam: Camera, x: float, y: float, size=(4.5, 1.8, 1.5)) -> np.ndarray:
    X = np.array([[x + (i & 1) * size[0], y + ((i >> 1) & 1) * size[1], ((i >> 2) & 1) * size[2]] for i in range(8)])
    return cam.world_to_image(X)


def _i420(bgr: np.ndarray) -> list[np.ndarray]:
    flat = cv2.cvtColor(bgr, cv2.COLOR_BGR2YUV_I420).ravel()
    n, q = W * H, W * H // 4
    return [flat[:n].reshape(H, W).copy(), flat[n:n + q].reshape(H // 2, W // 2).copy(),
            flat[n + q:].reshape(H // 2, W // 2).copy()]


def _i420_to_bgr(planes: list[np.ndarray]) -> np.ndarray:
    return cv2.cvtColor(np.concatenate([p.ravel() for p in planes]).reshape(H * 3 // 2, W), cv2.COLOR_YUV2BGR_I420)


def _marks() -> list[VehicleMark]:
    cam = _camera()
    return [
        VehicleMark((40, 150, 110, 200), 7, "car", 64.25),  # plain 2D box, direction unknown
        VehicleMark((0, 0, 0, 0), 8, "truck", None, corners=_corners(cam, 14.0, 1.0), direction="towards_vp1"),
    ]


def test_bgr_to_yuv_matches_the_standard_values() -> None:
    assert bgr_to_yuv((255, 255, 255)) == (235, 128, 128)
    assert bgr_to_yuv((0, 0, 0)) == (16, 128, 128)
    assert bgr_to_yuv((0, 0, 255)) == (81, 90, 240)  # BT.601 limited-range red
    assert bgr_to_yuv((0, 255, 0)) == (145, 54, 34)
    assert bgr_to_yuv((0, 0, 255), full_range=True) == (76, 85, 255)
    assert bgr_to_yuv((0, 0, 255), kr=0.2126, kb=0.0722)[0] == 63  # BT.709
    # and what OpenCV's own BT.601 I420 conversion gives
    for color in [(0, 255, 255), (255, 0, 255), (0, 220, 255), (30, 140, 200)]:
        y, u, v = (p[0, 0] for p in _i420(np.full((H, W, 3), color, np.uint8)))
        np.testing.assert_allclose(bgr_to_yuv(color), (y, u, v), atol=2)


def test_2d_and_3d_boxes_are_drawn_where_the_vehicles_are() -> None:
    img = np.full((H, W, 3), GREY, np.uint8)
    marks = _marks()
    draw_overlay(canvas_for_bgr(img), marks, None, NO_TEXT)
    yellow = np.all(img == STYLE.box_unknown_bgr, axis=2)
    green = np.all(img == STYLE.box_towards_bgr, axis=2)
    # 2D box: its outline, nothing inside or outside
    assert yellow[150, 40:111].mean() > 0.9 and yellow[150:201, 110].mean() > 0.9
    assert not yellow[160:190, 50:100].any()
    band = np.zeros((H, W), bool)
    band[146:205, 36:115] = True
    assert not yellow[~band].any()
    # 3D box: every edge midpoint is green, and green only near the box's edges
    c = marks[1].corners
    mids = np.round(c[BOX_EDGES].mean(axis=1)).astype(int)
    near = cv2.dilate(green.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert near[mids[:, 1], mids[:, 0]].all()
    edge_mask = np.zeros((H, W), np.uint8)
    for a, b in BOX_EDGES:
        cv2.line(edge_mask, tuple(np.round(c[a]).astype(int)), tuple(np.round(c[b]).astype(int)), 1, 7)
    assert not (green & (edge_mask == 0)).any()
    np.testing.assert_array_equal(BOX_EDGES, EDGES)  # the tracker's corner order


def test_i420_and_nv12_planes_get_the_same_drawing_as_bgr() -> None:
    base = np.full((H, W, 3), GREY, np.uint8)
    cam = _camera()
    ref = base.copy()
    draw_overlay(canvas_for_bgr(ref), _marks(), cam, OverlayOptions())
    planes = _i420(base)
    draw_overlay(canvas_for_planes(planes, "I420"), _marks(), cam, OverlayOptions())
    got = _i420_to_bgr(planes)
    drawn_ref = np.any(np.abs(ref.astype(int) - base) > 12, axis=2)
    drawn_yuv = np.any(np.abs(got.astype(int) - base) > 12, axis=2)
    overlap = (drawn_ref & drawn_yuv).sum() / drawn_ref.sum()
    assert overlap > 0.9 and (drawn_yuv & ~cv2.dilate(drawn_ref.astype(np.uint8), np.ones((5, 5))).astype(bool)).sum() == 0
    # where the reference has a thick line's colour the YUV drawing has nearly the same colour
    yellow = np.all(ref == STYLE.box_unknown_bgr, axis=2)
    inner = cv2.erode(yellow.astype(np.uint8), np.ones((2, 2), np.uint8)).astype(bool)
    err = np.abs(got[inner].astype(int) - STYLE.box_unknown_bgr).max(axis=1)
    assert np.median(err) < 25
    # NV12 is the same data with U and V interleaved
    nv = _i420(base)
    uv = np.dstack([nv[1], nv[2]])
    draw_overlay(canvas_for_planes([nv[0], uv], "NV12"), _marks(), cam, OverlayOptions())
    np.testing.assert_array_equal(nv[0], planes[0])
    np.testing.assert_array_equal(uv[..., 0], planes[1])
    np.testing.assert_array_equal(uv[..., 1], planes[2])


def test_packed_and_grey_formats() -> None:
    base = np.full((H, W, 3), GREY, np.uint8)
    cam = _camera()
    ref = base.copy()
    draw_overlay(canvas_for_bgr(ref), _marks(), cam, OverlayOptions())
    rgb = base[..., ::-1].copy()
    draw_overlay(canvas_for_planes([rgb], "RGB"), _marks(), cam, OverlayOptions())
    np.testing.assert_array_equal(rgb[..., ::-1], ref)
    bgrx = np.dstack([base, np.zeros((H, W), np.uint8)])
    draw_overlay(canvas_for_planes([bgrx], "BGRx"), _marks(), cam, OverlayOptions())
    np.testing.assert_array_equal(bgrx[..., :3], ref)
    grey = np.full((H, W), 128, np.uint8)
    draw_overlay(canvas_for_planes([grey], "GRAY8"), _marks(), cam, NO_TEXT)
    y_green = bgr_to_yuv(STYLE.box_towards_bgr, full_range=True)[0]
    green = np.all(ref == STYLE.box_towards_bgr, axis=2)
    assert np.mean(grey[green] == y_green) > 0.9


def test_drawing_into_strided_views_leaves_row_padding_alone() -> None:
    """Plane views with row padding (as GStreamer lays frames out) are drawn in place, padding untouched."""
    stride, cstride = W + 64, W // 2 + 32
    raw = np.full(stride * H + 2 * cstride * (H // 2), 77, np.uint8)
    y = np.ndarray((H, W), np.uint8, raw, 0, (stride, 1))
    u = np.ndarray((H // 2, W // 2), np.uint8, raw, stride * H, (cstride, 1))
    v = np.ndarray((H // 2, W // 2), np.uint8, raw, stride * H + cstride * H // 2, (cstride, 1))
    y[...], u[...], v[...] = 126, 128, 128
    draw_overlay(canvas_for_planes([y, u, v], "I420"), _marks(), _camera(), OverlayOptions())
    assert (y != 126).any() and (u != 128).any() and (v != 128).any()
    pad_y = raw[:stride * H].reshape(H, stride)[:, W:]
    pad_c = raw[stride * H:].reshape(H, cstride)[:, W // 2:]
    assert (pad_y == 77).all() and (pad_c == 77).all()


def test_far_vanishing_points_and_huge_coordinates_are_clipped() -> None:
    img = np.full((H, W, 3), GREY, np.uint8)
    canvas = canvas_for_bgr(img)
    canvas.segments(np.array([[[-1e12, 120.0], [1e12, 120.0]], [[5e9, 5e9], [6e9, 6e9]]]), (0, 0, 255), 1)
    red = (img[..., 2] > 180) & (img[..., 1] < 100)
    assert red[119:122].any(axis=0).all() and not red[:118].any() and not red[123:].any()
    # a camera whose VP2 is almost at infinity still gets its grid
    K = np.array([[300.0, 0, W / 2], [0, 300.0, H / 2], [0, 0, 1]])
    R = rotation_matrix(1e-5, 15.0, 0.0)
    cam = Camera.from_KRt(K, R, -R @ np.array([0.0, 0.0, 6.0]))
    assert np.abs(cam.vp2).max() > 1e8
    draw_overlay(canvas, [], cam, OverlayOptions())
    across = np.abs(img.astype(int) - STYLE.grid_across_bgr).max(axis=2) < 40
    assert across.sum() > 100


def test_labels_counters_and_toggles() -> None:
    m = VehicleMark((40, 150, 110, 200), 7, "car", 64.25)
    assert mark_label(m, OverlayOptions()) == ["#7 car 64.2 km/h"]
    assert mark_label(m, OverlayOptions(speeds=False)) == ["#7 car"]
    assert mark_label(m, OverlayOptions(labels=False)) == ["64.2 km/h"]
    assert mark_label(VehicleMark((0, 0, 1, 1), None, "car"), OverlayOptions()) == ["car"]
    img = np.full((H, W, 3), GREY, np.uint8)
    draw_overlay(canvas_for_bgr(img), [m], None, OverlayOptions(boxes=False, counters=False))
    white = np.all(img > 200, axis=2)
    black = np.all(img == 0, axis=2)
    ys, xs = np.nonzero(black)
    assert white.sum() > 30 and ys.max() <= 150 and xs.min() >= 38  # the label sits on its box
    img = np.full((H, W, 3), GREY, np.uint8)
    img[:, ::2] = 64  # stripes: the video under the counters panel
    before = img.copy()
    draw_overlay(canvas_for_bgr(img), [m], None, OverlayOptions(boxes=False, labels=False, speeds=False),
                 counter_lines=["vehicles: 3"])
    ys, xs = np.nonzero(np.any(img != before, axis=2))
    assert ys.min() == 8 and xs.min() == 8  # the counter panel in the top-left corner
    # translucent: darkened, the stripes still there (text aside)
    a = STYLE.panel_alpha
    panel = img[ys.min():ys.max() + 1, xs.min():xs.max() + 1, 0]
    levels = {int(GREY[0] * (1 - a) + 0.5), int(64 * (1 - a) + 0.5)}
    assert 0 < a < 1 and np.isin(panel, list(levels)).mean() > 0.6 and set(np.unique(panel)) >= levels
    img = np.full((H, W, 3), GREY, np.uint8)
    draw_overlay(canvas_for_bgr(img), [m], _camera(),
                 OverlayOptions(grid=False, horizon=False, boxes=False, labels=False, speeds=False, counters=False),
                 counter_lines=["x"])
    assert (img == GREY).all()


def _panel_frames(placer: PanelPlacer, boxes_per_frame, status: str | None = None) -> np.ndarray:
    """Draw frames with the vehicles of each item of ``boxes_per_frame`` (2D boxes) through ``placer``; the last
    frame's mask of pixels the panel or the status line darkened (the boxes are drawn in their own colours)."""
    for boxes in boxes_per_frame:
        img = np.full((H, W, 3), GREY, np.uint8)
        marks = [VehicleMark(tuple(b), k + 1, "car") for k, b in enumerate(boxes)]
        draw_overlay(canvas_for_bgr(img), marks, None, OverlayOptions(boxes=False, labels=False, speeds=False),
                     ["vehicles: 12", "in view: 1"], status=status, placer=placer)
    return img.max(axis=2) < 60


def test_the_counters_panel_moves_off_the_traffic() -> None:
    """Vehicles keep passing under the top-left corner (the far traffic of a view along the road): after the first
    ten seconds the panel goes to the top right, the status line stays at the bottom left, where nothing passes."""
    placer = PanelPlacer()
    far = [[(20 + 3 * (i % 30), 5, 70 + 3 * (i % 30), 40)] for i in range(300)]
    dark = _panel_frames(placer, far[:100], status="calibrating: no speeds yet")
    assert dark[8:30, 8:60].mean() > 0.3 and not dark[8:30, W - 60:W - 8].any()  # not yet: it settles first
    dark = _panel_frames(placer, far[100:], status="calibrating: no speeds yet")
    assert placer.panel == "top-right" and placer.status == "bottom-left"
    assert dark[8:30, W - 60:W - 8].mean() > 0.3 and not dark[:40, :W // 2].any()
    assert dark[H - 20:H - 10, 8:60].mean() > 0.3


def test_the_counters_panel_stays_put_for_a_vehicle_now_and_then() -> None:
    """One vehicle under the panel, then an empty road: no reason to move; traffic everywhere alike: none either."""
    placer = PanelPlacer()
    dark = _panel_frames(placer, [[(10, 5, 90, 45)]] + [[]] * 400)
    assert placer.panel == "top-left" and dark[8:30, 8:60].mean() > 0.3
    everywhere = [[(0, 0, W, H)]] * 400
    _panel_frames(placer, everywhere)
    assert placer.panel == "top-left"


def test_the_status_line_keeps_off_a_wide_panel_on_a_small_frame() -> None:
    """A 320x180 stream with eight lanes and class speed limits (the panel's limits line, one item, is wider than
    half the frame; the panel stays top left, its corner free) and traffic at both bottom corners: the status line
    would go to the free top right, but there it would cover the panel, so it takes the quieter bottom corner
    instead; a vehicle box with NaNs is left out of the map."""
    w, h = 320, 180
    placer = PanelPlacer()
    lanes = "  ".join(f"lane {k}: {k + 10}" for k in range(8))
    for i in range(300):
        img = np.full((h, w, 3), GREY, np.uint8)
        marks = [VehicleMark((10.0, 120.0, 110.0, 175.0), 1, "car"),
                 VehicleMark((200.0, 150.0, 230.0, 175.0), 2, "car"), VehicleMark((np.nan, 0.0, 5.0, 5.0), 3, "car")]
        draw_overlay(canvas_for_bgr(img), marks, None, OverlayOptions(boxes=False, labels=False, speeds=False),
                     ["vehicles: 12", "over 80 km/h (truck 60, bus 60): 3", lanes], status="calibrating: no speeds yet",
                     placer=placer)
    assert placer.panel == "top-left" and placer.status == "bottom-right"
    dark = img.max(axis=2) < 60
    rows = np.flatnonzero(dark[:, :w // 4].any(axis=1))  # the panel, top left
    assert rows.min() == 8 and not dark[rows.max() + 2:h // 2, w // 2:].any()  # nothing beside it on the right


def test_a_fixed_panel_position_and_a_wrong_one() -> None:
    placer = PanelPlacer("bottom-right")
    dark = _panel_frames(placer, [[(200, 150, 300, 230)]] * 300, status="finding the scale: no speeds yet")
    assert (placer.panel, placer.status) == ("bottom-right", "top-right")  # whatever the traffic
    assert dark[H - 30:H - 10, W - 60:W - 10].mean() > 0.3 and dark[8:20, W - 60:W - 10].mean() > 0.3
    assert not dark[:, :W // 3].any()
    with pytest.raises(ValueError, match="'middle' is none of auto, top-left, top-right, bottom-left, bottom-right"):
        PanelPlacer("middle")


def test_counters_of_many_lanes_wrap_within_half_the_frame() -> None:
    """Eight lanes on a 320x240 frame: the lane line breaks between lanes (never inside one) and the panel stays in
    the frame's left half; a line that fits is left alone."""
    lanes = "  ".join(f"lane {k}: {k + 10}" for k in range(8))
    fs = 0.35
    wrapped = wrap_lines(["vehicles: 60", lanes], W / 2, fs)
    assert wrapped[0] == "vehicles: 60" and len(wrapped) >= 3
    assert "  ".join(wrapped[1:]) == lanes  # every lane, in order, each whole
    assert all(cv2.getTextSize(t, cv2.FONT_HERSHEY_SIMPLEX, fs, 1)[0][0] <= W / 2 for t in wrapped)
    assert wrap_lines(["a  b"], 1.0, fs) == ["a", "b"] and wrap_lines(["a  b"], 1000.0, fs) == ["a  b"]
    img = np.full((H, W, 3), GREY, np.uint8)
    before = img.copy()
    draw_overlay(canvas_for_bgr(img), [], None, OverlayOptions(font_scale=fs), counter_lines=["vehicles: 60", lanes])
    ys, xs = np.nonzero(np.any(img != before, axis=2))
    assert xs.min() == 8 and xs.max() < 8 + W / 2 + 8 and ys.max() > 8 + 3 * 10  # several lines, left half


def test_vehicle_counter_counts_each_track_once() -> None:
    c = VehicleCounter()
    c.update([VehicleMark((0, 0, 1, 1), 1), VehicleMark((0, 0, 1, 1), 2, direction="away_from_vp1", lane=0),
              VehicleMark((0, 0, 1, 1), None)])
    c.update([VehicleMark((0, 0, 1, 1), 1, direction="towards_vp1", lane=1), VehicleMark((0, 0, 1, 1), 2)])
    c.update([VehicleMark((0, 0, 1, 1), 3, direction="towards_vp1", lane=1)])
    assert c.total == 3
    assert c.by_direction() == {"towards_vp1": 2, "away_from_vp1": 1}
    assert c.by_lane() == {0: 1, 1: 2}
    assert c.lines() == ["vehicles: 3", "towards VP1: 2  away: 1", "lane 0: 1  lane 1: 2"]
    c.update([VehicleMark((0, 0, 1, 1), 4)])  # no direction (tracked before the calibration): the counts add up
    assert c.lines()[:2] == ["vehicles: 4", "towards VP1: 2  away: 1  unknown: 1"]


def test_vehicle_counter_counts_a_track_once_in_view_long_enough() -> None:
    """min_seen_s (trafficoverlay without speedometer): a track seen for less is a flicker or a fragment, not counted
    — unless the end of the stream cut it short; one never counted is forgotten with the departed."""
    c = VehicleCounter(min_seen_s=0.5)
    for k in range(10):  # 0.4 s at 25 fps: #1 in view throughout, #2 for two frames
        c.update([VehicleMark((0, 0, 1, 1), 1, direction="towards_vp1")] +
                 ([VehicleMark((0, 0, 1, 1), 2)] if k < 2 else []), None, k / 25)
    assert c.total == 0
    c.update([VehicleMark((0, 0, 1, 1), 1, direction="towards_vp1")], None, 0.5)
    assert c.total == 1 and c.by_direction() == {"towards_vp1": 1}
    c.update([VehicleMark((0, 0, 1, 1), 3, direction="away_from_vp1", lane=2)], None, 0.56)
    c.end(0.6, 0.3)  # #3 seen at the end (cut short) counts with its values; #2 left before
    assert c.total == 2 and c.by_direction() == {"towards_vp1": 1, "away_from_vp1": 1} and c.by_lane() == {2: 1}
    c2 = VehicleCounter(min_seen_s=0.5)
    c2.update([VehicleMark((0, 0, 1, 1), 7)], None, 0.0)
    for k in range(1, VehicleCounter.FORGET_AFTER + 60):
        c2.update([], None, k / 25)
    c2.end(20.0, 1.0)
    assert c2.total == 0 and not c2._first_seen
    assert VehicleCounter().total == 0  # without min_seen_s every track counts at once (as before)
    c3 = VehicleCounter()
    c3.update([VehicleMark((0, 0, 1, 1), 1)], None, 0.0)
    assert c3.total == 1


def test_vehicles_over_the_speed_limit_are_drawn_in_red_and_counted() -> None:
    slow = VehicleMark((20, 40, 90, 90), 1, "car", 64.0, direction="towards_vp1")
    fast = VehicleMark((150, 40, 220, 90), 2, "car", 91.5, direction="towards_vp1")
    img = np.full((H, W, 3), GREY, np.uint8)
    draw_overlay(canvas_for_bgr(img), [slow, fast], None,
                 OverlayOptions(counters=False, labels=False, speed_limit_kmh=80.0))
    red = np.all(img == STYLE.speeding_bgr, axis=2)
    green = np.all(img == STYLE.box_towards_bgr, axis=2)
    assert red[40:91, 150:221].sum() > 100 and not red[:, :120].any()  # the fast one's box and label, only
    assert green[40:91, 20:91].sum() > 100 and not green[:, 130:].any()
    img = np.full((H, W, 3), GREY, np.uint8)
    draw_overlay(canvas_for_bgr(img), [slow, fast], None, OverlayOptions(counters=False))  # no limit: no red
    assert not np.all(img == STYLE.speeding_bgr, axis=2).any()
    c = VehicleCounter(speed_limit_kmh=80.0)
    c.update([slow, fast, VehicleMark((0, 0, 1, 1), 3)])  # vehicle 3: no speed yet
    c.update([VehicleMark((0, 0, 1, 1), 3, speed_kmh=85.0), VehicleMark((0, 0, 1, 1), 2, speed_kmh=90.0)])
    assert c.speeding == 2 and c.lines()[-1] == "over 80 km/h: 2"
    for _ in range(2 * VehicleCounter.FORGET_AFTER):  # they leave: still counted once
        c.update([])
    assert c.speeding == 2 and not c.seen and not c._speed
    assert "over" not in " ".join(VehicleCounter().lines())
    # a class with a limit of its own: the truck at 70 is over its 60, drawn and counted; the car at 70 is not
    from gst_trafficcal.traffic_stats import parse_speed_limit

    limit = parse_speed_limit("80,truck=60")
    truck = VehicleMark((20, 40, 90, 90), 1, "truck", 70.0, direction="towards_vp1")
    car = VehicleMark((150, 40, 220, 90), 2, "car", 70.0, direction="towards_vp1")
    img = np.full((H, W, 3), GREY, np.uint8)
    draw_overlay(canvas_for_bgr(img), [truck, car], None,
                 OverlayOptions(counters=False, labels=False, speed_limit_kmh=limit))
    red = np.all(img == STYLE.speeding_bgr, axis=2)
    assert red[40:91, 20:91].sum() > 100 and not red[:, 130:].any()
    c = VehicleCounter(speed_limit_kmh=limit)
    c.update([truck, car])
    assert c.speeding == 1 and c.lines()[-1] == "over 80 km/h (truck 60): 1"


def test_marks_from_the_tracker_structure() -> None:
    """The tracker's "trafficcal-vehicle" fields (tracking.vehicle_meta) and the "speed" structure."""
    cam = _camera()
    corners = _corners(cam, 12.0, -1.0)
    obs = Observation(t=1.0, box=np.array([10.0, 20, 60, 80]), det_box=np.array([10.0, 20, 60, 80]), score=0.9,
                      label="car", corners_px=corners, ref_px=np.array([33.0, 70.0]), ref_road=np.array([2.0, -0.2]))
    track = Track(id=5, state=TrackState.CONFIRMED, observations=[obs], direction=-1)
    fields = vehicle_fields(track, obs, cam, "abc")
    m = marks_from_params((10, 20, 60, 80), "car", 5, {"trafficcal-vehicle": fields,
                                                       "speed": {"speed_kmh": 71.5, "lane": 2}})
    np.testing.assert_allclose(m.corners, corners)
    assert m.ref_point == (33.0, 70.0) and m.direction == "away_from_vp1" and m.speed_kmh == 71.5
    assert m.lane == 2 and m.track_id == 5 and m.label == "car"
    # the speedometer's class (from the vehicle's measured size) replaces the detector's label
    van = marks_from_params((10, 20, 60, 80), "car", 5, {"speed": {"speed_kmh": 71.5, "label": "van"}})
    assert van.label == "van" and mark_label(van, OverlayOptions()) == ["#5 van 71.5 km/h"]
    # a plain detection, and a vehicle not yet in 3D
    plain = marks_from_params((1, 2, 3, 4), "bus", None, {"detection": {"label": "bus"}})
    assert plain.corners is None and plain.direction is None and plain.speed_kmh is None
    no3d = marks_from_params((1, 2, 3, 4), "car", 2, {"trafficcal-vehicle": vehicle_fields(track, obs, None)})
    assert no3d.corners is None and no3d.ref_point is None
    # cut by the top edge: the structure carries the box (for the meter), the overlay does not draw it
    cut = Observation(t=1.0, box=np.array([10.0, 0, 60, 80]), det_box=np.array([10.0, 0, 60, 80]), score=0.9,
                      label="truck", truncated=True, cut_top=True, corners_px=corners)
    cut_fields = vehicle_fields(track, cut, cam, "abc")
    assert cut_fields["cut_top"] and "box3d" in cut_fields and not cut_fields["has_3d"]
    m = marks_from_params((10, 0, 60, 80), "truck", 5, {"trafficcal-vehicle": cut_fields})
    assert m.corners is None and m.ref_point is None and m.track_id == 5


def test_a_vehicle_keeps_its_class_while_the_speedometer_withholds_its_speed() -> None:
    """The speedometer's class of a vehicle stays on it in the frames where its live speed (and class) is withheld,
    instead of flipping back to the detector's; other vehicles keep the detector's; the memory is bounded."""
    from gst_trafficcal.overlay import GivenClasses

    given = GivenClasses()
    frames = [{"speed": {"speed_kmh": 40.0, "label": "van"}}, {}, {"speed": {"speed_kmh": 41.0, "label": "van"}}, {}]
    assert [marks_from_params((1, 2, 30, 40), "car", 7, p, given).label for p in frames] == ["van"] * 4
    assert [marks_from_params((1, 2, 30, 40), "car", 7, p).label for p in frames] == ["van", "car", "van", "car"]
    assert marks_from_params((1, 2, 30, 40), "car", 8, {}, given).label == "car"
    assert marks_from_params((1, 2, 30, 40), "bus", None, {}, given).label == "bus"  # no track: nothing to keep
    for i in range(100, 100 + GivenClasses.LIMIT):
        given.label(i, "truck", "car")
    assert given.label(7, None, "car") == "car" and given.label(100 + GivenClasses.LIMIT - 1, "", "car") == "truck"


@pytest.mark.parametrize("fmt", ["I420", "NV12"])
def test_text_is_drawn_in_luma_on_a_neutral_box(fmt: str) -> None:
    """Label text: white luma on a black box whose chroma is neutral (no colour fringes under 4:2:0)."""
    planes = _i420(np.full((H, W, 3), GREY, np.uint8))
    if fmt == "NV12":
        planes = [planes[0], np.dstack([planes[1], planes[2]])]
    canvas = canvas_for_planes(planes, fmt)
    canvas.label((51, 101), ["#12 car 88.0 km/h"], 0.5)
    y = planes[0]
    box = y[60:101, 50:200]
    assert (box == 16).sum() > 200 and (box > 200).sum() > 30
    chroma = planes[1:] if fmt == "I420" else [planes[1][..., 0], planes[1][..., 1]]
    for c in chroma:
        assert (c == 128).all()  # grey background and black/white label: no chroma anywhere


def test_vehicle_counter_counts_only_vehicles_that_moved() -> None:
    """min_passing_m (trafficoverlay without speedometer): a track counts once its reference points moved that far
    along the road (speedometer's min-moved, first against last quarter): a parked car is never counted, however long
    it stands in view and though its point jumps by its length now and then, nor when the end of the stream cuts it;
    a passing car is, within its first second.  Without a scale the distance assumes a camera 7 m up (the grid's)."""
    cam = _camera()
    rng = np.random.default_rng(5)

    def ref(x: float, y: float, camera: Camera = cam) -> tuple[float, float]:
        return tuple(float(v) for v in camera.world_to_image(np.array([x, y, 0.0])))

    c = VehicleCounter(min_seen_s=0.5, min_passing_m=3.0)
    for k in range(25 * 120):  # 2 minutes: #1 parked at x = 12 m (its point 4.5 m further in one frame in ten)
        parked = VehicleMark((0, 0, 1, 1), 1, ref_point=ref(12.0 + 4.5 * (k % 10 == 0) + rng.normal(0, 0.1), 2.0))
        passing = [VehicleMark((0, 0, 1, 1), 2, ref_point=ref(5.0 + 0.5 * (k - 100), -1.75))] if k >= 100 else []
        c.update([parked] + passing, cam, k / 25)
        if k == 100 + 25:  # #2 at 12.5 m/s for a second
            assert set(c.seen) == {2}
    assert c.total == 1 and set(c.seen) == {2}
    assert len(c._trails[1].points) <= 128  # an even sample of the parked car's whole stay
    c.end(120.0, 1.0)
    assert c.total == 1
    # no scale: the same picture read with a camera 7 m above the road
    unscaled = Camera(cam.vp1, cam.vp2, cam.pp)
    c2 = VehicleCounter(min_seen_s=0.5, min_passing_m=3.0)
    seven = unscaled.with_scale(7.0)
    for k in range(50):
        c2.update([VehicleMark((0, 0, 1, 1), 1, ref_point=ref(12.0, 2.0, seven)),
                   VehicleMark((0, 0, 1, 1), 2, ref_point=ref(5.0 + 0.5 * k, -1.75, seven))], unscaled, k / 25)
    assert set(c2.seen) == {2}
    # no reference points (before the vanishing points): counted on the time in view, as speedometer reports it
    c3 = VehicleCounter(min_seen_s=0.5, min_passing_m=3.0)
    for k in range(15):
        c3.update([VehicleMark((0, 0, 1, 1), 1)], None, k / 25)
    assert c3.total == 1


def _drive(c: VehicleCounter, cam: Camera, xs: np.ndarray, fps: float = 25.0, y: float = 2.0) -> list[int]:
    """Feed track #1 at road positions ``xs`` (metres along the road, one per frame) through ``c``; the frames at
    which it was counted (empty: never)."""
    counted = []
    for k, x in enumerate(xs):
        ref = tuple(float(v) for v in cam.world_to_image(np.array([x, y, 0.0])))
        c.update([VehicleMark((0, 0, 1, 1), 1, ref_point=ref)], cam, k / fps)
        if 1 in c.seen:
            counted.append(k)
    return counted


@pytest.mark.parametrize("fps", [25, 5])
def test_vehicle_counter_counts_a_vehicle_that_stands_then_drives(fps: int) -> None:
    """A vehicle that stands for a minute (a queue at lights, a car leaving its parking place) and then drives off
    counts once it has driven min_passing_m: a steady movement along the road over its latest points at full rate.
    The quarter medians of its whole stay alone never counted it (its even sample's last quarter mostly stands).
    At 5 fps too within 3 s: the latest points are those of 2.6 s (13), where 64 (12.8 s there) never counted it in
    its 4 s of driving."""
    cam = _camera()
    rng = np.random.default_rng(7)
    stand = 12.0 + rng.normal(0, 0.1, fps * 60)
    t = np.arange(1, fps * 4 + 1) / fps  # then 4 s from a standstill at 2 m/s² up to 8 m/s
    drive = 12.0 + np.where(t < 4, t ** 2, 16 + 8 * (t - 4)) + rng.normal(0, 0.1, len(t))
    c = VehicleCounter(min_seen_s=0.5, min_passing_m=3.0)
    counted = _drive(c, cam, np.concatenate([stand, drive]), fps)
    assert counted and len(stand) < counted[0] <= len(stand) + fps * 3, counted[:1]  # within 3 s of driving off
    assert c.total == 1
    c.end(len(stand) / fps + 4, 1.0)
    assert c.total == 1


def test_vehicle_counter_without_speedometer_counts_directions_from_its_own_points() -> None:
    """own_directions (trafficoverlay with no speedometer upstream): each counted vehicle's direction along the road
    is decided from what the counter saw of it, as speedometer decides it (measurement.direction_along_road): by its
    reference points, or its box centres while it has none; a direction the marks give wins.  Before, all of them
    counted as unknown_direction."""
    cam = _camera()
    at = partial(_road_point, cam)
    c = VehicleCounter(min_seen_s=0.5, min_passing_m=3.0, own_directions=True)
    for k in range(50):  # 2 s at 25 fps, 10 m/s
        x = 0.4 * k
        marks = [VehicleMark((0, 0, 1, 1), 1, ref_point=at(5.0 + x, -1.75)),  # towards VP1 (along +x)
                 VehicleMark((0, 0, 1, 1), 2, ref_point=at(30.0 - x, 1.75)),  # away from it
                 VehicleMark((0, 0, 1, 1), 3, ref_point=at(5.0 + x, -5.25), direction="away_from_vp1")]
        bx, by = at(30.0 - x, 5.25)  # no reference point: its box moves away from VP1
        marks.append(VehicleMark((bx - 20, by - 10, bx + 20, by + 10), 4))
        c.update(marks, cam, k / 25)
    counts = c.summary()
    assert [counts[k] for k in ("total", "towards_vp1", "away_from_vp1", "unknown_direction")] == [4, 1, 3, 0]
    assert c.seen[1][0] == "towards_vp1" and c.seen[2][0] == c.seen[3][0] == c.seen[4][0] == "away_from_vp1"
    plain = VehicleCounter(min_seen_s=0.5, min_passing_m=3.0)  # the default (speedometer upstream says it)
    for k in range(50):
        plain.update([VehicleMark((0, 0, 1, 1), 1, ref_point=at(5.0 + 0.4 * k, -1.75))], cam, k / 25)
    assert plain.summary()["unknown_direction"] == 1


def test_vehicle_counter_without_speedometer_gives_a_direction_to_tracks_counted_at_the_end() -> None:
    """own_directions: a track the counter counts only at the end of the stream (in view 0.3 s, under
    ``min_seen_s``: the end cut it short) gets the direction its points show, as the tracks counted before did —
    by its reference points, or its box centres when it has none.  Before, both landed in unknown_direction (their
    points were kept only from when they counted)."""
    cam = _camera()
    at = partial(_road_point, cam)
    c = VehicleCounter(min_seen_s=0.5, min_passing_m=3.0, own_directions=True)
    for k in range(8):  # 0.3 s at 25 fps, 10 m/s
        x = 0.4 * k
        bx, by = at(30.0 - x, 5.25)  # no reference point: its box moves away from VP1
        c.update([VehicleMark((0, 0, 1, 1), 1, ref_point=at(5.0 + x, -1.75)),
                  VehicleMark((bx - 20, by - 10, bx + 20, by + 10), 2)], cam, k / 25)
    assert c.total == 0
    c.end(7 / 25, 1.0)
    assert c.seen[1][0] == "towards_vp1" and c.seen[2][0] == "away_from_vp1", c.seen
    assert c.summary()["unknown_direction"] == 0 and not c._paths.keys() - c.seen.keys()


@pytest.mark.parametrize("fps", [25, 5])
@pytest.mark.parametrize("jump_m, first_s", [(0.0, 0), (4.5, 43), (-4.5, 43), (4.5, 6), (-4.5, 6)])
def test_vehicle_counter_never_counts_a_parked_vehicle_whose_point_jumps_for_seconds(jump_m: float, first_s: int,
                                                                                      fps: int) -> None:
    """A parked vehicle is never counted though its point jitters, or jumps by its length (its front hidden by a
    passing vehicle) for 2 s every 15 s from ``first_s`` on, and back: one big step among still ones is no steady
    movement.  Early in its stay (6 s) the even sample's last quarter is short enough for the jump to hold it: the
    move must also hold all along the latest points (at 5 fps those of the same 5.1 s)."""
    cam = _camera()
    rng = np.random.default_rng(11)
    k = np.arange(fps * 120)
    jumped = (k >= fps * first_s) & ((k - fps * first_s) % (fps * 15) < fps * 2)
    xs = 12.0 + jump_m * jumped + rng.normal(0, 0.15, len(k))
    c = VehicleCounter(min_seen_s=0.5, min_passing_m=3.0)
    assert not _drive(c, cam, xs, fps)
    c.end(len(k) / fps, 1.0)
    assert c.total == 0


def test_vehicle_counter_derives_lanes_from_reference_points() -> None:
    """Without lanes in the metadata, the lanes come from where the reference points lie on the road."""
    cam = _camera()
    rng = np.random.default_rng(2)
    c = VehicleCounter()
    lanes = rng.choice(2, 40, p=[0.7, 0.3])
    for frame in range(5):
        marks = []
        for k, lane in enumerate(lanes):
            world = [12.0 + frame, (-1.75, 1.75)[lane] + rng.normal(0, 0.2), 0.0]
            ref = tuple(cam.world_to_image(np.array(world)))
            marks.append(VehicleMark((0, 0, 1, 1), k + 1, "car", ref_point=ref))
        c.update(marks, cam)
    assert c.by_lane() == {0: int(np.sum(lanes == 0)), 1: int(np.sum(lanes == 1))}
    assert c.lines()[-1] == f"lane 0: {np.sum(lanes == 0)}  lane 1: {np.sum(lanes == 1)}"
    # lanes given in the metadata win; no calibration: no derived lanes
    c2 = VehicleCounter()
    c2.update([VehicleMark((0, 0, 1, 1), 1, ref_point=(10.0, 200.0), lane=3)], cam)
    c2.update([VehicleMark((0, 0, 1, 1), 2, ref_point=(10.0, 200.0))], None)
    assert c2.by_lane() == {3: 1}


def test_vehicle_counter_forgets_departed_vehicles_but_keeps_their_counts() -> None:
    """A long stream: vehicles that left are folded into totals (bounded memory), the counts do not change."""
    cam = _camera()
    c = VehicleCounter()
    n_frames, per_vehicle = 3000, 20  # a new vehicle every 10 frames, each seen for 20 frames
    for frame in range(n_frames):
        marks = []
        for vid in range(max(0, frame // 10 - 1), frame // 10 + 1):
            if vid * 10 <= frame < vid * 10 + per_vehicle:
                lane = vid % 3
                ref = tuple(cam.world_to_image(np.array([14.0, -3.5 + 3.5 * lane, 0.0])))
                marks.append(VehicleMark((0, 0, 1, 1), vid + 1, "car", ref_point=ref,
                                         direction="towards_vp1" if vid % 4 else "away_from_vp1"))
        c.update(marks, cam)
    n = n_frames // 10
    assert c.total == n and len(c.seen) < 40 and len(c.offsets) < 40  # old vehicles forgotten
    assert c.by_direction() == {"towards_vp1": n - n // 4, "away_from_vp1": n // 4}
    assert c.by_lane() == {0: n // 3, 1: n // 3, 2: n // 3}


def test_vehicles_measured_after_they_left_are_counted_by_their_final_values() -> None:
    """Vehicles tracked before the calibration leave "unknown"; speedometer's event for each (left()) moves them to
    their direction, lane and speeding count, whether they are still remembered or already folded into the totals."""
    c = VehicleCounter(speed_limit_kmh=80.0)
    c.update([VehicleMark((0, 0, 1, 1), 1), VehicleMark((0, 0, 1, 1), 2)])  # no calibration yet
    for _ in range(2 * VehicleCounter.FORGET_AFTER):  # both left long ago: folded into the totals
        c.update([])
    c.update([VehicleMark((0, 0, 1, 1), 3), VehicleMark((0, 0, 1, 1), 4, direction="towards_vp1")])
    assert c.by_direction() == {None: 3, "towards_vp1": 1} and c.by_lane() == {} and c.speeding == 0
    assert c.lines()[1] == "towards VP1: 1  away: 0  unknown: 3"
    # the calibration converges: speedometer measures all four
    assert c.left(1, "away_from_vp1", 0, 95.0, "car") and c.left(2, "towards_vp1", 1, 60.0, "car")
    assert c.left(3, "towards_vp1", 1, 85.0, "car") and c.left(4, "towards_vp1", 2, None, "car")
    assert c.by_direction() == {"towards_vp1": 3, "away_from_vp1": 1}
    assert c.by_lane() == {0: 1, 1: 2, 2: 1} and c.speeding == 2 and c.total == 4
    assert c.summary() == {"total": 4, "towards_vp1": 3, "away_from_vp1": 1, "unknown_direction": 0,
                           "lane_0": 1, "lane_1": 2, "lane_2": 1, "over_limit": 2}
    # measured again with the final calibration (remeasure): moved, never counted twice; the files' values win,
    # none included (vehicle 3's direction was the tracker's, the files have none)
    assert c.left(1, "away_from_vp1", 1, 70.0, "car") and c.left(3, None, None, None, "car")
    assert c.by_lane() == {1: 2, 2: 1} and c.speeding == 0 and c.total == 4
    assert c.by_direction() == {"towards_vp1": 2, "away_from_vp1": 1, None: 1}
    assert not c.left(99, "towards_vp1", 0, 50.0, "car") and c.total == 4  # never seen here: ignored
    # once lanes come from speedometer, a vehicle still in view is in no lane until it leaves
    cam = _camera()
    ref = tuple(cam.world_to_image(np.array([14.0, 0.0, 0.0])))
    c.update([VehicleMark((0, 0, 1, 1), 5, ref_point=ref, direction="towards_vp1")], cam)
    assert c.by_lane() == {1: 2, 2: 1} and c.total == 5
    c.left(5, "towards_vp1", 0, 50.0, "car")
    assert c.by_lane() == {0: 1, 1: 2, 2: 1}
    # a vehicle seen as two tracks (lost for a moment, a new id): speedometer measured them as one, so is it counted
    c.update([VehicleMark((0, 0, 1, 1), 6, direction="towards_vp1", speed_kmh=90.0)])
    for _ in range(2 * VehicleCounter.FORGET_AFTER):  # track 6 long gone; track 8 still in view
        c.update([VehicleMark((0, 0, 1, 1), 8, direction="towards_vp1")])
    assert c.total == 7 and c.speeding == 1
    assert c.left(8, "towards_vp1", 1, 88.0, "car", merged=[6, 99])  # 99: never counted here, nothing to undo
    assert c.total == 6 and c.speeding == 1 and c.by_direction() == {"towards_vp1": 4, "away_from_vp1": 1, None: 1}
    assert c.by_lane() == {0: 1, 1: 3, 2: 1} and 6 not in c._done_ids
    # tracks speedometer found to be no vehicle passing (a piece of one, a parked car): out of the counts, whether
    # already folded into the totals (vehicle 1: away, lane 1) or still remembered (track 9), once
    c.update([VehicleMark((0, 0, 1, 1), 9, direction="away_from_vp1")])
    assert c.total == 7
    c.not_vehicles([1, 9, 9, 123])
    assert c.total == 5 and c.by_direction() == {"towards_vp1": 4, None: 1} and c.by_lane() == {0: 1, 1: 2, 2: 1}


def test_the_panel_says_when_no_speed_can_be_shown_yet() -> None:
    cam = _camera()
    assert calibration_status(None) == "calibrating: no speeds yet"
    assert calibration_status(Camera(cam.vp1, cam.vp2, cam.pp, None)) == "finding the scale: no speeds yet"
    assert calibration_status(cam) is None
    img = np.full((H, W, 3), GREY, np.uint8)  # drawn at the bottom left, not into the counters at the top
    draw_overlay(canvas_for_bgr(img), [], None, OverlayOptions(), ["vehicles: 0"], status=calibration_status(None))
    dark = img.max(axis=2) < 60
    assert dark[H - 20:H - 8, 8:60].mean() > 0.5 and (img[H - 24:H - 8, 8:150].min(axis=2) > 200).any()
    assert not dark[H // 2 - 20:H // 2 + 20].any()


def test_the_overlay_grid_is_no_denser_at_1080p_than_the_report_picture() -> None:
    """The cells along the road stop at a thirty-sixth of the frame height (drawing.grid_min_cell_px), as in the
    report's calibration picture: at 1080p the far field is not a solid mesh."""
    from gst_trafficcal.drawing import grid_min_cell_px, road_grid_segments

    K = np.array([[1800.0, 0, 960], [0, 1800.0, 540], [0, 0, 1]])
    R = rotation_matrix(20.0, 12.0, 0.0)
    cam = Camera.from_KRt(K, R, -R @ np.array([0.0, 0.0, 6.0]))
    grid, _ = GridCache().get(cam, (1920, 1080), 3.0)
    assert grid_min_cell_px(1080) == 30.0 and grid_min_cell_px(360) == 14.0
    dense = road_grid_segments(cam, (1920, 1080), 3.0)  # the old rule: 12 px cells
    same = road_grid_segments(cam, (1920, 1080), 3.0, min_cell_px=30.0)
    assert len(grid.across) == len(same.across) < len(dense.across)


def test_labels_of_vehicles_side_by_side_do_not_cover_each_other() -> None:
    """A queue: three labels wanted at nearly the same place. The first (the nearest vehicle's) stays where it was
    wanted, the others move above it; none overlap and all stay inside the frame, also at the frame's top."""
    from gst_trafficcal.overlay import place_labels

    wanted = np.array([[100, 120, 90, 16], [110, 118, 90, 16], [95, 125, 60, 16], [300, 2, 50, 16], [310, 0, 50, 16]])
    got = place_labels(wanted, (W, H))
    assert tuple(got[0]) == (100, 120) and tuple(got[3]) == (W - 50, 2)  # clipped to the frame, else as wanted
    boxes = np.column_stack([got, wanted[:, 2:]])
    for i in range(len(boxes)):
        x, y, w, h = boxes[i]
        assert 0 <= x <= W - w and 0 <= y <= H - h
        for j in range(i):
            a = boxes[j]
            assert not (x < a[0] + a[2] and a[0] < x + w and y < a[1] + a[3] and a[1] < y + h), (i, j, boxes)
    assert got[1][1] < 120 and got[2][1] < got[1][1]  # moved up, one above the other
    assert got[4][1] > 2  # no room above the frame's top: below the one there


def test_crowded_labels_never_overlap_while_there_is_room() -> None:
    """Random crowds of labels (a queue at a junction): no two overlap and each stays in the frame."""
    from gst_trafficcal.overlay import place_labels

    rng = np.random.default_rng(3)
    for _ in range(50):
        n = int(rng.integers(2, 12))
        wanted = np.column_stack([rng.uniform(-20, W, n), rng.uniform(-20, H, n), rng.uniform(40, 120, n),
                                  np.full(n, 14.0)])
        got = np.column_stack([place_labels(wanted, (W, H)), wanted[:, 2:]])
        for i in range(n):
            x, y, w, h = got[i]
            assert 0 <= x <= W - w and 0 <= y <= H - h
            for j in range(i):
                a = got[j]
                assert not (x < a[0] + a[2] and a[0] < x + w and y < a[1] + a[3] and a[1] < y + h)
