"""Pictures of a calibration (the paper's Figure 9): road-plane grid towards VP1/VP2 and the horizon.

The geometry is kept apart from the pixels: :func:`road_grid_segments` and :func:`horizon_segment` return
image line segments (clipped to the frame), which :func:`draw_calibration` paints on a BGR image and the
overlay (``gst_trafficcal.overlay``) paints straight into YUV planes.

The grid lies on the road plane in the world frame of :mod:`gst_trafficcal.geometry` (x towards VP1, y
across the road): lines of constant y converge at VP1, lines of constant x at VP2. With a scale the cells
are ``spacing_m`` metres; without one the grid is drawn in plane units assuming a camera height of
:data:`ASSUMED_HEIGHT_M` (the picture then shows the vanishing points only, not distances).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from .geometry import Camera

ASSUMED_HEIGHT_M = 7.0
"""Camera height used to lay out the grid when the calibration has no scale yet."""

MAX_RANGE_M = 150.0
"""The grid never extends further than this from the camera (beyond, lines crowd at the horizon)."""


def clip_segments(segments: np.ndarray, width: int, height: int, margin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Clip image segments (N, 2, 2) to the frame grown by ``margin`` (Liang–Barsky, vectorised).

    Returns (clipped segments (M, 2, 2), indices (M,) of the input segments that remain visible).
    """
    s = np.asarray(segments, dtype=np.float64).reshape(-1, 2, 2)
    p0, d = s[:, 0], s[:, 1] - s[:, 0]
    lo = np.array([-margin, -margin])
    hi = np.array([width - 1 + margin, height - 1 + margin])
    t0, t1 = np.zeros(len(s)), np.ones(len(s))
    ok = np.all(np.isfinite(s), axis=(1, 2))
    with np.errstate(divide="ignore", invalid="ignore"):
        for axis in range(2):
            for bound, sign in ((lo[axis], -1.0), (hi[axis], 1.0)):
                # inside when sign * (p0 + t d - bound) <= 0
                q = sign * (p0[:, axis] - bound)
                p = sign * d[:, axis]
                parallel = p == 0
                ok &= ~(parallel & (q > 0))
                t = -q / p
                entering = p < 0
                t0 = np.where(~parallel & entering, np.maximum(t0, t), t0)
                t1 = np.where(~parallel & ~entering, np.minimum(t1, t), t1)
    ok &= t0 <= t1
    idx = np.flatnonzero(ok)
    out = np.stack([p0[idx] + t0[idx, None] * d[idx], p0[idx] + t1[idx, None] * d[idx]], axis=1)
    return out, idx


def world_camera(camera: Camera) -> Camera:
    """The camera with a scale (ASSUMED_HEIGHT_M when it has none): for laying out the grid in metres, and for
    trafficoverlay's counter to tell a parked car from a passing one before the scale is known."""
    return camera if camera.scale is not None else camera.with_scale(ASSUMED_HEIGHT_M)


def visible_road_box(camera: Camera, image_size: tuple[int, int], horizon_margin: float = 0.06,
                     max_range_m: float = MAX_RANGE_M) -> tuple[float, float, float, float] | None:
    """(x_min, x_max, y_min, y_max) in world metres of the road seen at least ``horizon_margin``·height
    below the horizon; None when no part of the frame shows the road."""
    cam = world_camera(camera)
    w, h = image_size
    xs, ys = np.meshgrid(np.linspace(0, w - 1, 33), np.linspace(0, h - 1, 33))
    pts = np.stack([xs.ravel(), ys.ravel()], axis=1)
    rays = camera.rays(pts)
    sin_below = -(rays @ camera.normal) / np.linalg.norm(rays, axis=1)  # sine of the angle below the horizon
    keep = sin_below > np.sin(np.arctan(horizon_margin * h / camera.focal))
    if not keep.any():
        return None
    world = cam.to_world(pts[keep])
    world = world[np.all(np.isfinite(world), axis=1)]
    if not len(world):
        return None
    dist_xy = np.linalg.norm(world[:, :2], axis=1)
    world = world[dist_xy <= max_range_m]
    if not len(world):
        return None
    return float(world[:, 0].min()), float(world[:, 0].max()), float(world[:, 1].min()), float(world[:, 1].max())


@dataclass(frozen=True)
class RoadGrid:
    """Image segments of the road grid: ``along`` converge at VP1, ``across`` at VP2 (each (N, 2, 2) pixels)."""

    along: np.ndarray
    across: np.ndarray
    spacing_m: float


def grid_min_cell_px(height: int, thickness: int = 1) -> float:
    """The shortest grid cell (pixels along the road) drawn in a picture ``height`` pixels tall: a thirty-sixth of
    the height, so a 1080p picture is no denser than a 540p one, and never below what the line width leaves
    readable."""
    return max(8.0 + 6.0 * thickness, height / 36.0)


def road_grid_segments(camera: Camera, image_size: tuple[int, int], spacing_m: float = 3.0,
                       max_lines: int = 200, pieces: int = 24, min_cell_px: float = 12.0) -> RoadGrid:
    """The grid of the road plane with ``spacing_m`` cells over the visible road, clipped to the frame.

    Each grid line is cut into ``pieces`` sub-segments in the world, so the parts behind the camera or beyond
    the visible road never reach the picture; the grid stops where its cells along the road shrink below
    ``min_cell_px`` pixels (towards the horizon).
    """
    w, h = image_size
    empty = RoadGrid(np.zeros((0, 2, 2)), np.zeros((0, 2, 2)), spacing_m)
    if not spacing_m > 0:
        raise ValueError(f"grid spacing must be positive, got {spacing_m}")
    box = visible_road_box(camera, image_size)
    if box is None:
        return empty
    cam = world_camera(camera)
    x0, x1, y0, y1 = box
    # widen the spacing if the road box would need too many lines
    step = spacing_m * max(1.0, np.ceil(max((x1 - x0), (y1 - y0)) / spacing_m / max_lines))
    gx = np.arange(np.floor(x0 / step), np.ceil(x1 / step) + 1) * step
    gy = np.arange(np.floor(y0 / step), np.ceil(y1 / step) + 1) * step
    # stop where consecutive lines across the road come closer than min_cell_px in the image
    yc = 0.5 * (y0 + y1)
    a = cam.world_to_image(np.stack([gx, np.full_like(gx, yc), np.zeros_like(gx)], axis=1))
    b = cam.world_to_image(np.stack([gx + step, np.full_like(gx, yc), np.zeros_like(gx)], axis=1))
    with np.errstate(invalid="ignore"):
        gx = gx[np.linalg.norm(a - b, axis=1) >= min_cell_px]
    if len(gx) == 0:
        return empty
    x0, x1 = float(gx.min()), float(gx.max())
    t = np.linspace(0.0, 1.0, pieces + 1)

    def project(lines_world: np.ndarray) -> np.ndarray:  # (L, pieces+1, 3) -> segments
        cam_pts = cam.world_to_camera(lines_world)
        img = cam.from_road(cam_pts)
        seg = np.stack([img[:, :-1], img[:, 1:]], axis=2).reshape(-1, 2, 2)
        front = (cam_pts[:, :-1, 2] > 1e-3) & (cam_pts[:, 1:, 2] > 1e-3)
        seg = seg[front.reshape(-1)]
        return clip_segments(seg, w, h, margin=2.0)[0]

    xs = x0 + t * (x1 - x0)
    along = np.stack([np.broadcast_to(xs, (len(gy), len(t))), np.repeat(gy[:, None], len(t), 1),
                      np.zeros((len(gy), len(t)))], axis=2)
    ys = y0 + t * (y1 - y0)
    across = np.stack([np.repeat(gx[:, None], len(t), 1), np.broadcast_to(ys, (len(gx), len(t))),
                       np.zeros((len(gx), len(t)))], axis=2)
    return RoadGrid(project(along), project(across), float(step))


def horizon_segment(camera: Camera, image_size: tuple[int, int]) -> np.ndarray | None:
    """The horizon (line through VP1 and VP2) clipped to the frame as a (2, 2) segment, None when off-frame."""
    return line_segment(camera.horizon, image_size)


def line_segment(line: np.ndarray, image_size: tuple[int, int]) -> np.ndarray | None:
    """A homogeneous image line (a, b, c) clipped to the frame as a (2, 2) segment, None when off-frame."""
    w, h = image_size
    a, b, c = np.asarray(line, dtype=np.float64) / np.hypot(line[0], line[1])
    big = 4.0 * (w + h)
    centre = np.array([w / 2.0, h / 2.0])
    foot = centre - (a * centre[0] + b * centre[1] + c) * np.array([a, b])  # the line's point nearest it
    direction = np.array([-b, a])
    seg = np.stack([foot - big * direction, foot + big * direction])[None]
    out, _ = clip_segments(seg, w, h)
    return out[0] if len(out) else None


# --------------------------------------------------------------------------- BGR pictures

GRID_ALONG_BGR = (0, 220, 255)  # lines towards VP1: amber
GRID_ACROSS_BGR = (255, 200, 0)  # lines towards VP2: azure
HORIZON_BGR = (60, 60, 255)  # red
ZONE_BGR = (211, 0, 148)  # violet: the detection zone's outline


def draw_segments(image: np.ndarray, segments: np.ndarray, color: tuple[int, ...], thickness: int = 1,
                  line_type: int = cv2.LINE_AA) -> None:
    """Draw (N, 2, 2) pixel segments on ``image`` in place (sub-pixel positions, one cv2 call)."""
    if len(segments) == 0:
        return
    pts = np.round(np.asarray(segments, np.float64) * 16).astype(np.int32)
    cv2.polylines(image, pts, False, color, thickness, line_type, 4)


def zone_segments(polygons: Sequence[np.ndarray], size: tuple[int, int] | None = None) -> np.ndarray:
    """(N, 2, 2) segments outlining closed pixel polygons (each Kx2): the detection zone
    (:meth:`gst_trafficcal.zone.Zone.pixels`); with the frame's ``size`` its edges along the frame's right and
    bottom borders (x = width, y = height) are moved onto the last column and row, to be seen."""
    if not len(polygons):
        return np.zeros((0, 2, 2))
    seg = np.concatenate([np.stack([p, np.roll(p, -1, axis=0)], axis=1) for p in map(np.asarray, polygons)])
    return seg if size is None else np.minimum(seg, np.asarray(size, np.float64) - 1)


def draw_calibration(image: np.ndarray, camera: Camera, spacing_m: float = 3.0, thickness: int = 1,
                     horizon: bool = True, opacity: float = 1.0) -> np.ndarray:
    """Draw the road grid and the horizon of ``camera`` on a BGR image in place; returns the image.

    The grid stops where its cells along the road get shorter than a thirty-sixth of the picture's height (and
    never below what its line width leaves readable), so a 1080p picture is no denser than a 540p one;
    ``opacity`` < 1 blends it in, for pictures whose own marks must stand out above it.
    """
    h, w = image.shape[:2]
    grid = road_grid_segments(camera, (w, h), spacing_m, min_cell_px=grid_min_cell_px(h, thickness))
    layer = image.copy() if opacity < 1.0 else image
    draw_segments(layer, grid.along, GRID_ALONG_BGR, thickness)
    draw_segments(layer, grid.across, GRID_ACROSS_BGR, thickness)
    if layer is not image:
        cv2.addWeighted(layer, opacity, image, 1.0 - opacity, 0.0, dst=image)
    if horizon:
        seg = horizon_segment(camera, (w, h))
        if seg is not None:
            draw_segments(image, seg[None], HORIZON_BGR, thickness + 1)
    return image


LANE_BGR = ((0, 200, 255), (255, 160, 0), (80, 220, 80), (200, 80, 255), (0, 90, 255), (255, 255, 0),
            (160, 160, 255), (255, 80, 160))
"""Colours of lanes 0, 1, ... (repeating); vehicles without a lane are drawn grey."""
NO_LANE_BGR = (150, 150, 150)


def lane_bgr(lane: int | None) -> tuple[int, int, int]:
    return NO_LANE_BGR if lane is None else LANE_BGR[lane % len(LANE_BGR)]


def draw_lane_paths(image: np.ndarray, paths: list[tuple[int | None, np.ndarray]], thickness: int = 1) -> np.ndarray:
    """Draw each vehicle's reference points (``(lane, (N, 2) pixels)``) as a line in its lane's colour, and name
    each lane ("lane 2") where its vehicles came nearest to the camera (the lowest points, the labels kept apart):
    which lane number is where, for the report's per-lane counts.  In place; returns the image."""
    h, w = image.shape[:2]
    nearest: dict[int, list[np.ndarray]] = {}
    for lane, pts in paths:
        p = np.asarray(pts, np.float64).reshape(-1, 2)
        p = p[np.all(np.isfinite(p), axis=1)]
        if len(p) < 2:
            continue
        cv2.polylines(image, [np.round(p).astype(np.int32)], False, lane_bgr(lane), thickness, cv2.LINE_AA)
        if lane is not None:
            nearest.setdefault(lane, []).append(p[np.argmax(p[:, 1])])
    scale = max(0.4, h / 900)
    font, weight = cv2.FONT_HERSHEY_SIMPLEX, max(1, int(round(scale * 2)))
    placed: list[tuple[int, int, int, int]] = []
    for lane in sorted(nearest, key=lambda k: -float(np.median(np.array(nearest[k])[:, 1]))):
        x, y = np.median(np.array(nearest[lane]), axis=0)
        text = f"lane {lane}"
        (tw, th), base = cv2.getTextSize(text, font, scale, weight)
        x0 = int(np.clip(x - tw / 2, 2, w - tw - 2))
        y0 = int(np.clip(y + th + 6, th + 2, h - base - 2))
        while any(x0 < bx1 and bx0 < x0 + tw and y0 - th < by1 and by0 < y0 + base for bx0, by0, bx1, by1 in placed):
            y0 -= th + base + 4  # above the label already there
        if y0 - th < 0:
            continue
        cv2.rectangle(image, (x0 - 2, y0 - th - 2), (x0 + tw + 2, y0 + base), (0, 0, 0), -1)
        cv2.putText(image, text, (x0, y0), font, scale, lane_bgr(lane), weight, cv2.LINE_AA)
        placed.append((x0 - 2, y0 - th - 2, x0 + tw + 2, y0 + base))
    return image
