"""Ground truth of a synthetic video: BrnoCompSpeed's gt_data.pkl, per-frame JSON lines, a contact sheet.

Measurement lines are images of road lines x = const (across the road, towards VP2), placed like the dataset's in
the well-resolved near part of the road (:func:`line_positions`: the far line where a typical car's 2D box is
still ``measurement.far_car_span`` of the image width, the near line where cars stay in the frame); lane
dividing lines are images of lane boundaries y = const (towards VP1); a car's crossing time of a measurement
line is the exact time its reference point (centre of the bottom-front edge) reaches that x.  As in the
dataset, a car's crossings are listed by decreasing line id and end with line 0, the line the evaluation
matches on; cars that do not cross line 0 inside the video are left out of gt_data.pkl (they are still in
frames.jsonl).  Distance segments run along a dashed lane divider (one dash period, towards VP1) and across
the lanes (one lane width, towards VP2).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..brnocompspeed import DistanceMeasurement, GroundTruth, GtCar, LineCrossing, save_gt_data
from ..geometry import line_through
from .camera import SynthCamera
from .scene import RoadLayout
from .traffic import Vehicle


@dataclass
class SceneLines:
    """World positions behind the gt_data.pkl lines."""

    line_x: list[float]  # world x of measurement lines 0, 1, 2 (line 0 nearest the camera)
    boundaries_y: list[float]  # lane boundaries, image left to right (lane k between k and k+1)
    invalid_lanes: set[int]  # pseudo-lanes without traffic (a median)


def _in_image(cam: SynthCamera, X: np.ndarray, margin: float = 0.02) -> np.ndarray:
    W, H = cam.size
    p = cam.project(X)
    return (cam.depth(X) > 0) & (p[..., 0] >= margin * W) & (p[..., 0] <= (1 - margin) * W) & \
        (p[..., 1] >= margin * H) & (p[..., 1] <= (1 - margin) * H)


def visible_x_range(cam: SynthCamera, y_lo: float, y_hi: float, x_lo: float, x_hi: float) -> tuple[float, float]:
    """Range of world x where the road cross-section [y_lo, y_hi] is entirely in the image."""
    xs = np.linspace(x_lo, x_hi, 2000)
    ok = np.ones_like(xs, bool)
    for y in np.linspace(y_lo, y_hi, 5):
        ok &= _in_image(cam, np.column_stack([xs, np.full_like(xs, y), np.zeros_like(xs)]))
    if not ok.any():
        # fall back to where at least the middle of that section is visible
        ok = _in_image(cam, np.column_stack([xs, np.full_like(xs, (y_lo + y_hi) / 2), np.zeros_like(xs)]))
    if not ok.any():
        return float(x_lo), float(x_hi)
    return float(xs[ok].min()), float(xs[ok].max())


CAR = (4.5, 1.8, 1.5)  # length, width, height (metres) of the typical car behind the line placement rule


def lane_centres(layout: RoadLayout, directions: list[int]) -> list[tuple[int, float]]:
    """(direction, world y) of the centre of every lane carrying traffic."""
    return [(d, layout.lane_centre(d, k)) for d in directions for k in range(layout.road.lanes)]


def car_size_px(cam: SynthCamera, x: np.ndarray, y: float) -> np.ndarray:
    """Diagonal (pixels) of the 2D box of a typical car (:data:`CAR`, centred on road position (x, y), along the
    road): how large a car looks there (the tracking benchmark's size measure).  Cars reaching behind the camera
    get 0."""
    L, w, h = CAR
    x = np.asarray(x, float)
    corners = np.array([[dx, dy, z] for dx in (-L / 2, L / 2) for dy in (-w / 2, w / 2) for z in (0.0, h)])
    X = np.stack([x, np.full_like(x, y), np.zeros_like(x)], axis=-1)[..., None, :] + corners  # (..., 8, 3)
    p = cam.project(X)
    size = np.linalg.norm(p.max(axis=-2) - p.min(axis=-2), axis=-1)
    return np.where(np.all(cam.depth(X) > 0, axis=-1), size, 0.0)


def car_in_frame(cam: SynthCamera, x: np.ndarray, lanes: list[tuple[int, float]]) -> np.ndarray:
    """Whether a typical car in every lane is entirely in the image from one car length before to one car length
    after its front crosses road position x (its body trails behind the front in its direction of travel)."""
    L, w, h = CAR
    ok = np.ones(np.shape(x), bool)
    for d, y in lanes:
        s = 1.0 if d == 0 else -1.0
        for front in (x - L, x + L):
            for along in (front, front - s * L):
                for dy in (-w / 2, w / 2):
                    for z in (0.0, h):
                        ok &= _in_image(cam, np.stack([along, np.full_like(x, y + dy), np.full_like(x, z)], -1))
    return ok


def line_positions(cam: SynthCamera, layout: RoadLayout, directions: list[int], far_car_span: float = 0.06,
                   x_end: float | None = None) -> list[float]:
    """World x of measurement lines 0, 1, 2, placed like BrnoCompSpeed's, in the well-resolved part of the road:
    line 0 at the nearest position where a car in every lane is entirely in the frame around its crossing, line 2
    at the farthest position where a typical car (:data:`CAR`) in every lane still has a 2D box diagonal of
    ``far_car_span`` x image width (and is in the frame), line 1 half-way between (in metres).  Where no position
    meets the size rule the lines fall back to the nearest 40 m in view (no preset needs it)."""
    road = layout.road
    if x_end is None:
        x_end = road.length if not road.curve_radius else road.curve_start - 10.0  # lines stay on the straight
    W = cam.size[0]
    ys = [y for d in directions for y in layout.carriageway_edges(d)]
    x0, x1 = visible_x_range(cam, min(ys), max(ys), 1.0, x_end)
    xs = np.linspace(x0, x1, 4000)
    lanes = lane_centres(layout, directions)
    near = car_in_frame(cam, xs, lanes)
    span = np.min([car_size_px(cam, xs, y) for _, y in lanes], axis=0)
    good = near & (span >= far_car_span * W)
    if near.any():
        xn = float(xs[near].min())
    else:
        xn = x0
    if good.any() and xs[good].max() > xn + 1.0:
        xf = float(xs[good].max())
    else:
        xf = min(x1, xn + 40.0)
    if xf - xn < 1.0:  # no room for cars in the frame: spread the lines over the visible road instead
        xn, xf = x0 + 0.1 * (x1 - x0), x1 - 0.1 * (x1 - x0)
    return [xn, (xn + xf) / 2, xf]


def scene_lines(cam: SynthCamera, layout: RoadLayout, directions: list[int], far_car_span: float = 0.06) -> SceneLines:
    """Measurement lines (:func:`line_positions`), lane boundaries and invalid lanes of a synthetic scene."""
    road = layout.road
    line_x = line_positions(cam, layout, directions, far_car_span)
    bounds = sorted(layout.lane_boundaries(), reverse=True)  # +y (left) first = image left when looking along +x
    if cam.R[0, 1] > 0:  # world +y points right in the image: reverse to keep image left-to-right order
        bounds = bounds[::-1]
    invalid = set()
    if road.directions == 2:
        inner = {round(road.median / 2, 9), round(-road.median / 2, 9)}
        for k in range(len(bounds) - 1):
            if {round(bounds[k], 9), round(bounds[k + 1], 9)} == inner:
                invalid.add(k)
    return SceneLines(line_x=[float(x) for x in line_x], boundaries_y=bounds, invalid_lanes=invalid)


def lane_index(lines: SceneLines, y: float) -> int:
    b = lines.boundaries_y
    for k in range(len(b) - 1):
        if min(b[k], b[k + 1]) <= y <= max(b[k], b[k + 1]):
            return k
    return 0


def build_gt_data(cam: SynthCamera, layout: RoadLayout, lines: SceneLines, vehicles: list[Vehicle], fps: float,
                  duration: float) -> GroundTruth:
    road = layout.road
    P = lambda x, y: cam.project(np.array([x, y, 0.0]))  # noqa: E731
    y_lo, y_hi = min(lines.boundaries_y), max(lines.boundaries_y)
    mlines = np.array([line_through(P(x, y_lo), P(x, y_hi)) for x in lines.line_x])
    xa, xb = lines.line_x[0], lines.line_x[-1]
    ldl = np.array([line_through(P(xa, y), P(xb, y)) for y in lines.boundaries_y])
    # distances: dash periods along a divider (or the edge line of a one-lane road), lane widths across
    dists = []
    period = road.dash + road.gap
    d0 = 0 if 0 in {v.direction for v in vehicles} or road.directions == 1 else 1
    lo, hi = layout.carriageway_edges(d0)
    y_div = lo + road.lane_width if road.lanes > 1 else lo
    k0 = np.ceil(lines.line_x[0] / period)
    starts = [k * period for k in range(int(k0), int(k0) + 8) if (k + 1) * period <= lines.line_x[-1] + period]
    for x in starts[:4]:
        dists.append(DistanceMeasurement(P(x, y_div), P(x + period, y_div), float(period), True))
    for x in (lines.line_x[0], lines.line_x[-1]):
        for k in range(road.lanes):
            dists.append(DistanceMeasurement(P(x, lo + k * road.lane_width), P(x, lo + (k + 1) * road.lane_width),
                                             float(road.lane_width), False))
    cars = []
    for v in vehicles:
        crossings = []
        for i, x in enumerate(lines.line_x):
            t = v.time_at_front(x)
            if 0.0 <= t < duration:
                crossings.append(LineCrossing(i, float(t)))
        if not crossings or crossings[0].line != 0:
            continue  # the evaluation matches on the crossing of line 0: it must be in the video
        # the dataset lists crossings by decreasing line id, ending with line 0 (its match time)
        crossings.sort(key=lambda c: -c.line)
        cars.append(GtCar(car_id=v.id, lanes=frozenset({lane_index(lines, v.y)}), valid=True,
                          speed=float(v.speed * 3.6), intersections=tuple(crossings),
                          time_intersection_last_shifted=crossings[-1].video_time))
    return GroundTruth(fps=float(fps), measurement_lines=mlines, lane_div_lines=ldl,
                       invalid_lanes=frozenset(lines.invalid_lanes), distances=tuple(dists), cars=tuple(cars))


def save_ground_truth(gt: GroundTruth, path: Path) -> None:
    save_gt_data(gt, path)


def silhouette_area(pts: np.ndarray, tris: np.ndarray | None, max_side: int = 8192) -> float:
    """Area in pixels of the union of projected triangles (the unoccluded silhouette, inside the image or not),
    rasterised with 1/16 px vertex precision on a mask covering the projection; falls back to the convex hull
    for huge or degenerate projections."""
    x0, y0 = np.floor(pts.min(axis=0)).astype(int) - 1
    x1, y1 = np.ceil(pts.max(axis=0)).astype(int) + 1
    if tris is None or not len(tris) or x1 - x0 > max_side or y1 - y0 > max_side:
        return float(cv2.contourArea(cv2.convexHull(pts.astype(np.float32))))
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    # pixel (i, j) is covered when its centre is inside: shift by +0.5 to the corner-based raster of fillPoly
    poly = np.round((pts[tris] - [x0, y0] + 0.5) * 16).astype(np.int32)
    cv2.fillPoly(mask, list(poly), 1, lineType=cv2.LINE_8, shift=4)
    return float(cv2.countNonZero(mask))


class SilhouetteAreas:
    """Unoccluded silhouette areas per vehicle: rasterised exactly every ``every`` frames, in between the convex
    hull's area times the last measured solidity (silhouette / hull changes slowly with the viewpoint)."""

    def __init__(self, every: int = 5):
        self.every = every
        self._solidity: dict[int, tuple[int, float]] = {}

    def __call__(self, vid: int, frame: int, pts: np.ndarray, tris: np.ndarray | None) -> float:
        hull = float(cv2.contourArea(cv2.convexHull(pts.astype(np.float32))))
        last = self._solidity.get(vid)
        if last is not None and frame - last[0] < self.every:
            return hull * last[1]
        exact = silhouette_area(pts, tris)
        self._solidity[vid] = (frame, exact / hull if hull > 0 else 1.0)
        return exact

    def forget(self, keep: set[int]) -> None:
        for k in [k for k in self._solidity if k not in keep]:
            del self._solidity[k]


def vehicle_record(frame: int, t: float, v: Vehicle, cam: SynthCamera, verts_world: np.ndarray, mask_count: int,
                   lane: int, H: np.ndarray | None, tris: np.ndarray | None = None,
                   areas: SilhouetteAreas | None = None) -> dict | None:
    """One JSON-lines record (pixel coordinates in the delivered, possibly shaken, frame)."""
    from .imaging import apply_homography

    W, Hh = cam.size
    if not np.all(cam.depth(verts_world) > 0.1):
        return None
    pts = cam.project(verts_world)
    corners = cam.project(v.box_corners(t))
    ref_w = v.reference_point(t)
    ref = cam.project(ref_w)
    area = areas(v.id, frame, pts, tris) if areas is not None else silhouette_area(pts, tris)
    if H is not None:
        pts, corners, ref = (apply_homography(H, a) for a in (pts, corners, ref))
    x0, y0 = pts.min(axis=0)
    x1, y1 = pts.max(axis=0)
    if x1 < -0.5 or y1 < -0.5 or x0 > W - 0.5 or y0 > Hh - 0.5:
        return None
    box = [float(max(x0, -0.5)), float(max(y0, -0.5)), float(min(x1, W - 0.5)), float(min(y1, Hh - 0.5))]
    return {
        "frame": frame, "time": round(t, 6), "id": v.id, "class": v.body_style, "model": v.model_name,
        "box": [round(b, 3) for b in box], "visible": round(min(mask_count / max(area, 1e-9), 1.0), 4),
        "box3d": np.round(corners, 3).tolist(), "ref": np.round(ref, 4).tolist(),
        "world": np.round(v.centre(t), 4).tolist(), "ref_world": np.round(ref_w, 4).tolist(),
        "speed_kmh": round(v.speed * 3.6, 4), "lane": lane, "direction": v.direction,
        "size": [round(v.length, 4), round(v.width, 4), round(v.height, 4)],
        **({"shake": np.round(H, 10).tolist()} if H is not None else {}),
    }


def perfect_results(records: list[dict], cal_block: dict, fps: float, min_visible: float = 0.0) -> dict:
    """A BrnoCompSpeed results dict an ideal system would produce (tracks = the ground-truth reference points)."""
    tracks: dict[int, dict] = {}
    for r in records:
        if r["visible"] < min_visible:
            continue
        tr = tracks.setdefault(r["id"], {"id": r["id"], "frames": [], "posX": [], "posY": []})
        tr["frames"].append(int(round(r["time"] * fps)))
        tr["posX"].append(r["ref"][0])
        tr["posY"].append(r["ref"][1])
    return {"camera_calibration": cal_block, "cars": list(tracks.values())}


def read_jsonl(path: Path) -> list[dict]:
    with open(path, encoding="utf-8") as f:
        return [json.loads(line) for line in f if line.strip()]


def records_by_frame(path: Path) -> dict[int, list[dict]]:
    """A render's per-frame truth (``frames.jsonl``: one record per vehicle and frame), grouped by frame number."""
    out: dict[int, list[dict]] = {}
    for r in read_jsonl(path):
        out.setdefault(int(r["frame"]), []).append(r)
    return out


def contact_sheet(frames: list[tuple[float, np.ndarray, list[dict]]], path: Path, cols: int = 3) -> None:
    """Tile a few frames (with ground-truth boxes and reference points drawn) into one PNG (InputError when it cannot
    be written)."""
    from ..fileio import atomic_write_image

    if not frames:
        return
    tiles = []
    for t, img, recs in frames:
        im = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
        for r in recs:
            x0, y0, x1, y1 = (int(round(v)) for v in r["box"])
            if max(x1 - x0, y1 - y0) < 12:  # too small to annotate legibly
                continue
            cv2.rectangle(im, (x0, y0), (x1, y1), (0, 255, 255), 1)
            c = r["box3d"]
            for a, b in ((0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6),
                         (3, 7)):
                cv2.line(im, tuple(int(round(v)) for v in c[a]), tuple(int(round(v)) for v in c[b]), (0, 200, 0), 1)
            cv2.circle(im, tuple(int(round(v)) for v in r["ref"]), max(2, im.shape[1] // 400), (0, 0, 255), -1)
        cv2.putText(im, f"t={t:.2f}s", (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 2)
        scale = 480 / im.shape[1]
        tiles.append(cv2.resize(im, (480, int(round(im.shape[0] * scale))), interpolation=cv2.INTER_AREA))
    h = max(t.shape[0] for t in tiles)
    tiles = [cv2.copyMakeBorder(t, 0, h - t.shape[0], 0, 0, cv2.BORDER_CONSTANT) for t in tiles]
    while len(tiles) % cols:
        tiles.append(np.zeros_like(tiles[0]))
    rows = [np.hstack(tiles[i:i + cols]) for i in range(0, len(tiles), cols)]
    atomic_write_image(path, np.vstack(rows), "preview picture")  # whole or not at all; an error said, not ignored
