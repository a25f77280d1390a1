"""Box-level traffic simulation with exact ground truth, for testing and benchmarking the tracker.

Vehicles (boxes in metres) drive at constant speeds along the lanes of a straight road seen by a calibrated
camera, in both directions.  Each frame gives their projected 3D box corners, convex hulls, 2D boxes and
reference points (centre of the bottom-front edge), plus a detector model with misses, false positives and
box noise.  No pixels are rendered: this isolates the tracker from the detector (the rendered scenes of
``trafficcal synth`` test the whole chain).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from ..detection.records import Detections
from ..geometry import Camera, rotation_matrix
from .box3d import CORNER_BITS


@dataclass
class SimFrame:
    """Ground truth of one frame: vehicles fully inside the image."""

    t: float
    ids: np.ndarray  # (N,) vehicle ids ≥ 1
    boxes: np.ndarray  # (N, 4) 2D boxes of the projected 3D boxes
    hulls: list[np.ndarray]  # convex hulls (K, 2)
    corners_px: np.ndarray  # (N, 8, 2) order box3d.CORNER_BITS
    ref_px: np.ndarray  # (N, 2)
    ref_world: np.ndarray  # (N, 2) metres, world frame of the camera (x along VP1)
    directions: np.ndarray  # (N,) +1 towards VP1, -1 opposite


@dataclass
class Scene:
    camera: Camera
    image_size: tuple[int, int]
    frames: list[SimFrame] = field(default_factory=list)


def default_camera(image_size: tuple[int, int] = (960, 540), pan: float = 12.0, tilt: float = 18.0,
                   roll: float = 0.0, height: float = 8.0, hfov: float = 60.0) -> Camera:
    w, h = image_size
    f = w / 2 / np.tan(np.radians(hfov) / 2)
    K = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]])
    R = rotation_matrix(pan, tilt, roll)
    return Camera.from_KRt(K, R, -R @ np.array([0.0, 0.0, height]))


def simulate(camera: Camera, image_size: tuple[int, int] = (960, 540), duration: float = 20.0, fps: float = 25.0,
             lanes: tuple[tuple[float, int], ...] = ((-5.25, 1), (-1.75, 1), (1.75, -1), (5.25, -1)),
             rate: float = 0.4, seed: int = 0, drop: float = 0.0, min_size: float = 24.0) -> Scene:
    """Vehicles arriving per lane as a Poisson process (``rate`` per second), speeds 60–110 km/h.

    ``lanes`` are (lateral offset in metres, direction).  ``drop`` is the fraction of frames the camera drops
    (timestamps keep the true times).  Vehicles smaller than ``min_size`` pixels (box diagonal) are left out of
    the ground truth, as a detector would miss them.
    """
    rng = np.random.default_rng(seed)
    w, h = image_size
    xs = np.linspace(-50, 300, 1401)
    visible_x = []
    for y, _ in lanes:
        px = camera.world_to_image(np.stack([xs, np.full_like(xs, y), np.zeros_like(xs)], axis=1))
        inside = np.all((px > 0) & (px < [w, h]), axis=1) & (xs > 2)
        visible_x.append((xs[inside].min(), xs[inside].max()) if inside.any() else (0.0, 0.0))
    vehicles = []  # (id, lane y, direction, speed, length, width, height, x at t=0)
    vid = 1
    for (y, d), (lo, hi) in zip(lanes, visible_x):
        if hi <= lo:
            continue
        t = rng.exponential(1 / rate) - 3.0
        last_speed = None
        while t < duration:
            speed = rng.uniform(60, 110) / 3.6
            if last_speed is not None:
                speed = min(speed, last_speed)  # no overtaking within a lane
            length = rng.choice([rng.uniform(3.8, 5.0), rng.uniform(6, 12)], p=[0.85, 0.15])
            width = rng.uniform(1.7, 2.0) if length < 6 else rng.uniform(2.3, 2.55)
            height = rng.uniform(1.35, 1.9) if length < 6 else rng.uniform(2.6, 3.6)
            start = lo - 8 - length if d > 0 else hi + 8 + length
            vehicles.append((vid, y, d, speed, length, width, height, start - d * speed * t))
            vid += 1
            last_speed = speed
            t += max(rng.exponential(1 / rate), 1.5)
    scene = Scene(camera, image_size)
    if not vehicles:
        return scene
    V = np.array(vehicles, np.float64)  # columns: id, y, direction, speed, length, width, height, x at t=0
    vid, y, d, speed, length, width, height, x_at0 = V.T
    bits = CORNER_BITS.astype(np.float64)
    n_frames = int(duration * fps)
    for k in range(n_frames):
        if drop and rng.random() < drop:
            continue
        t = k / fps
        xc = x_at0 + d * speed * t
        lo = np.stack([xc - length / 2, y - width / 2, np.zeros_like(xc)], axis=1)
        hi = np.stack([xc + length / 2, y + width / 2, height], axis=1)
        X = lo[:, None, :] + bits[None] * (hi - lo)[:, None, :]  # (V, 8, 3)
        in_front = np.all(camera.world_to_camera(X)[..., 2] > 0.5, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            px = camera.world_to_image(X)
        inside = np.all((px >= 1) & (px <= [w - 2, h - 2]), axis=(1, 2))
        big = np.hypot(*np.moveaxis(px.max(axis=1) - px.min(axis=1), -1, 0)) >= min_size
        sel = np.flatnonzero(in_front & inside & big)
        px = px[sel]
        front = np.stack([xc[sel] + d[sel] * length[sel] / 2, y[sel], np.zeros(len(sel))], axis=1)
        hulls = [cv2.convexHull(p.astype(np.float32)).reshape(-1, 2).astype(np.float64) for p in px]
        boxes = np.concatenate([px.min(axis=1), px.max(axis=1)], axis=1) if len(sel) else np.zeros((0, 4))
        scene.frames.append(SimFrame(t, vid[sel].astype(np.int64), boxes, hulls, px.reshape(-1, 8, 2),
                                     camera.world_to_image(front).reshape(-1, 2), front[:, :2],
                                     d[sel].astype(np.int64)))
    return scene


def detect(frame: SimFrame, rng: np.random.Generator, image_size: tuple[int, int], miss: float = 0.0,
           fp_rate: float = 0.0, noise: float = 0.0) -> tuple[Detections, list[np.ndarray], np.ndarray]:
    """A simulated detector: drops each vehicle with probability ``miss``, adds Poisson(``fp_rate``) false boxes
    per frame and jitters boxes and hulls by ``noise`` of their size.  Returns (detections, hulls, gt ids with 0
    for false positives)."""
    keep = rng.random(len(frame.ids)) >= miss
    boxes = frame.boxes[keep].copy()
    hulls = [frame.hulls[i].copy() for i in np.flatnonzero(keep)]
    ids = frame.ids[keep].copy()
    if noise > 0 and len(boxes):
        size = np.hypot(boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1])
        jitter = rng.normal(0, noise, (len(boxes), 4)) * size[:, None]
        boxes += jitter
        for k, hl in enumerate(hulls):
            c = hl.mean(axis=0)
            sx = 1 + (jitter[k, 2] - jitter[k, 0]) / max(size[k], 1)
            hulls[k] = (hl - c) * sx + c + jitter[k, :2] / 2 + jitter[k, 2:] / 2
    n_fp = rng.poisson(fp_rate)
    if n_fp:
        w, h = image_size
        x0 = rng.uniform(0, w - 60, n_fp)
        y0 = rng.uniform(h * 0.3, h - 60, n_fp)
        s = rng.uniform(20, 60, n_fp)
        fp = np.stack([x0, y0, x0 + s, y0 + s * 0.8], axis=1)
        boxes = np.vstack([boxes, fp])
        hulls += [np.array([[b[0], b[1]], [b[2], b[1]], [b[2], b[3]], [b[0], b[3]]]) for b in fp]
        ids = np.concatenate([ids, np.zeros(n_fp, np.int64)])
    n = len(boxes)
    det = Detections(boxes, np.full(n, 0.9), np.full(n, 2), np.full(n, "car", dtype=object))
    return det, hulls, ids


def vehicle_passing(camera: Camera, size: tuple[float, float, float], lane: float, x_start: float, speed_kmh: float,
                    direction: int = -1, image_size: tuple[int, int] = (960, 540), duration: float = 6.0,
                    fps: float = 25.0) -> Scene:
    """One vehicle (length, width, height in metres) driving along the road at ``lane`` (metres across it) from
    ``x_start`` (metres along it) at a constant speed, cut by the image borders as a camera cuts it: each frame's
    hull and box are the visible part of its projected 3D box (frames where none of it is visible are left
    out).  A tall vehicle near a steep camera leaves the frame at the top while its front is in view."""
    w, h = image_size
    length, width, height = size
    rect = np.array([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]], np.float32)
    bits = CORNER_BITS.astype(np.float64)
    scene = Scene(camera, image_size)
    for k in range(int(duration * fps)):
        t = k / fps
        xc = x_start + direction * speed_kmh / 3.6 * t
        lo = np.array([xc - length / 2, lane - width / 2, 0.0])
        X = lo + bits * (np.array([xc + length / 2, lane + width / 2, height]) - lo)
        if np.any(camera.world_to_camera(X)[:, 2] < 0.5):
            continue
        px = camera.world_to_image(X)
        hull = cv2.convexHull(px.astype(np.float32)).reshape(-1, 2)
        area, visible = cv2.intersectConvexConvex(hull, rect)
        if area <= 1.0 or visible is None:
            continue
        vis = visible.reshape(-1, 2).astype(np.float64)
        front = np.array([[xc + direction * length / 2, lane, 0.0]])
        scene.frames.append(SimFrame(t, np.array([1]), np.concatenate([vis.min(axis=0), vis.max(axis=0)])[None],
                                     [vis], px[None], camera.world_to_image(front).reshape(1, 2), front[:, :2],
                                     np.array([direction])))
    return scene
