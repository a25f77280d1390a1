"""Static occluders (lamp poles, sign posts, tree trunks in front of the road) learned from where vehicles are seen.

A pole between the camera and the road cuts every vehicle that passes behind it: its outline shrinks against the
pole, vanishes, and comes back on the other side, often as two fragments for a while.  A tracker that trusts those
boxes loses the vehicle at the pole (the box's speed drops while one edge stays stuck to the pole) and starts a new
track behind it: one vehicle, two tracks, and under BrnoCompSpeed's counting rule a false positive (15 of the 31
false positives of the learned segmenter on the ten 60 s synth presets came from the pole of ``left_side``).

The map needs no knowledge of the scene.  It keeps, per pixel of a small work image,

* how often a vehicle's outline covered it (``coverage``), and
* the orientation in which those vehicles moved (double-angle sums, so both directions of travel agree); once the
  camera is calibrated, ``vp1`` replaces it: on a straight road vehicles move along the lines through VP1,

and a pixel is an occluder when, *along the local direction of travel*, vehicles are regularly seen on both sides
of it within ``reach`` but (almost) never on it, in a region that stands across the flow.  Looking along the
motion is what tells a pole across the lanes from a median strip or a lane edge: those run along the motion, so
the coverage beside them along it is their own.

The tracker asks which edges of a detection's box touch an occluder (:meth:`OccluderMap.cut_sides`).  Such a
vehicle is not fully visible: it is not measured (no 3D box, like one cut by the image border), its box does not
update the track's 2D filter (the track coasts, on the road when it has 3D boxes), it is matched to a track with
its cut edges completed to that track's predicted size (:func:`complete_boxes`), and a fragment of a vehicle
matched in the same frame starts no track.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import InputError

SIDES = ("left", "top", "right", "bottom")  # box edges x0, y0, x1, y1


@dataclass
class OccluderMap:
    """Per-pixel statistics of where vehicles are seen and the static occluders they imply.

    ``work_width``: width of the statistics image (pixels; the frame is reduced to it); ``reach``: widest occluder
    bridged, as a fraction of the image width (vehicles must be seen within this distance on both sides);
    ``min_support``: frames of vehicle coverage needed on each side; ``max_ratio``: an occluder pixel is covered at
    most this fraction of its sides' coverage; ``min_across``: an occluder region is at least half as long across
    the direction of travel as along it, and at least this fraction of the image width; ``refresh``: frames
    between recomputations of the map;
    ``margin``: work pixels beyond a box edge searched for an occluder; ``side_fraction``: fraction of that strip
    the occluder must fill for the edge to count as cut.
    """

    work_width: int = 240
    reach: float = 0.05
    min_support: float = 5.0
    max_ratio: float = 0.25
    refresh: int = 25
    margin: int = 2
    side_fraction: float = 0.3
    min_speed: float = 2.0  # px/s: slower tracks do not vote for the direction of travel
    min_across: float = 0.02  # an occluder region spans at least this fraction of the image width across the flow
    vp1: np.ndarray | None = None  # the road's vanishing point (full-resolution pixels) once the camera is known

    def __post_init__(self) -> None:
        if self.work_width < 32:
            raise InputError(f"occluder map work width must be at least 32 pixels, got {self.work_width}")
        if not 0 < self.reach < 0.5:
            raise InputError(f"occluder reach is a fraction of the image width in (0, 0.5), got {self.reach}")
        self.reset()

    def reset(self) -> None:
        self.size: tuple[int, int] | None = None  # full-resolution (width, height)
        self.scale = 1.0  # full-resolution pixels per work pixel
        self.frames = 0
        self.coverage: np.ndarray | None = None
        self._c2: np.ndarray | None = None  # sum of cos 2θ of the direction of travel
        self._s2: np.ndarray | None = None  # sum of sin 2θ
        self.mask: np.ndarray | None = None  # bool work image: static occluder
        self._integral: np.ndarray | None = None

    def _start(self, size: tuple[int, int]) -> None:
        self.reset()
        w, h = int(size[0]), int(size[1])
        self.size = (w, h)
        ww = min(self.work_width, w)
        self.scale = w / ww
        wh = max(1, int(round(h / self.scale)))
        self.coverage = np.zeros((wh, ww), np.float32)
        self._c2 = np.zeros((wh, ww), np.float32)
        self._s2 = np.zeros((wh, ww), np.float32)
        self.mask = np.zeros((wh, ww), bool)
        self._integral = np.zeros((wh + 1, ww + 1), np.float64)

    @property
    def ready(self) -> bool:
        """Whether any occluder is known."""
        return self.mask is not None and bool(self.mask.any())

    # ----------------------------------------------------------------- learning
    def add(self, size: tuple[int, int], hulls: list[np.ndarray | None],
            velocities: np.ndarray | None = None) -> None:
        """One frame: the outlines (convex hulls, Kx2 full-resolution pixels) of the vehicles seen and, per hull,
        the image velocity (px/s) of its track (NaN rows: unknown, they add coverage only)."""
        if self.size != (int(size[0]), int(size[1])):
            self._start(size)
        vel = np.full((len(hulls), 2), np.nan) if velocities is None else np.asarray(velocities, np.float64)
        label = np.zeros(self.coverage.shape, np.uint16)  # hull k + 1 per pixel (a later hull over an earlier)
        for k, h in enumerate(hulls):
            if h is not None and len(h) >= 3:
                cv2.fillPoly(label, [np.round(np.asarray(h, np.float64) / self.scale - 0.5).astype(np.int32)], k + 1)
        self.coverage += label > 0
        moving = np.all(np.isfinite(vel), axis=1) & (np.hypot(vel[:, 0], vel[:, 1]) >= self.min_speed)
        if moving.any() and self.vp1 is None:  # per hull: cos, sin of twice its direction of travel (else 0)
            a = 2.0 * np.arctan2(vel[:, 1], vel[:, 0])
            self._c2 += np.concatenate([[0.0], np.where(moving, np.cos(a), 0.0)]).astype(np.float32)[label]
            self._s2 += np.concatenate([[0.0], np.where(moving, np.sin(a), 0.0)]).astype(np.float32)[label]
        self.frames += 1
        if self.frames % self.refresh == 0:
            self.update_mask()

    def update_mask(self) -> None:
        """Recompute the occluder mask from the statistics so far."""
        if self.coverage is None:
            return
        wh, ww = self.coverage.shape
        r = max(2, int(round(self.reach * ww)))
        gx, gy = np.meshgrid(np.arange(ww, dtype=np.float32), np.arange(wh, dtype=np.float32))
        if self.vp1 is not None:  # a straight road: vehicles move along the lines through its vanishing point
            dx, dy = self.vp1[0] / self.scale - 0.5 - gx, self.vp1[1] / self.scale - 0.5 - gy
            norm = np.maximum(np.hypot(dx, dy), 1e-6)
            ux, uy = (dx / norm).astype(np.float32), (dy / norm).astype(np.float32)
            c2, s2 = ux * ux - uy * uy, 2.0 * ux * uy
            known = np.ones_like(self.coverage, bool)
        else:  # as the tracks moved, smoothed over the reach so that it is known on the occluder itself
            k = (2 * r + 1, 2 * r + 1)
            c2 = cv2.boxFilter(self._c2, -1, k, normalize=False, borderType=cv2.BORDER_CONSTANT)
            s2 = cv2.boxFilter(self._s2, -1, k, normalize=False, borderType=cv2.BORDER_CONSTANT)
            known = np.hypot(c2, s2) >= 1.0
            theta = 0.5 * np.arctan2(s2, c2)
            ux, uy = np.cos(theta).astype(np.float32), np.sin(theta).astype(np.float32)
        ahead = np.zeros_like(self.coverage)
        behind = np.zeros_like(self.coverage)
        for step in range(1, r + 1, max(1, r // 6)):  # at most 6 samples a side (coverage varies smoothly)
            for sign, best in ((1.0, ahead), (-1.0, behind)):
                seen = cv2.remap(self.coverage, gx + sign * step * ux, gy + sign * step * uy, cv2.INTER_LINEAR,
                                 borderMode=cv2.BORDER_CONSTANT, borderValue=0)
                np.maximum(best, seen, out=best)
        sides = np.minimum(ahead, behind)
        mask = known & (sides >= self.min_support) & (self.coverage <= self.max_ratio * sides)
        self.mask = self._across_the_flow(mask, c2, s2)
        self._integral = cv2.integral(self.mask.astype(np.uint8)).astype(np.float64)

    def _across_the_flow(self, mask: np.ndarray, c2: np.ndarray, s2: np.ndarray) -> np.ndarray:
        """The parts of ``mask`` that stand across the traffic: connected regions at least half as long across
        the local direction of travel as along it, and at least ``min_across`` of the image width across it.  An
        occluder that cuts vehicles in two blocks the flow over a vehicle's height (a pole, a post, a trunk, a
        bridge; a pole seen across diagonal traffic measured 15 work pixels across, 17 along); what runs along the
        flow (the edge of a lane vehicles rarely cover, where coverage is low on every side: 40 along, 5 across)
        and isolated pixels are not one."""
        n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
        if n <= 1:
            return mask
        ys, xs = np.nonzero(labels)
        lab = labels[ys, xs]
        # mean direction of travel per region (double-angle sums), then each pixel's position along and across it
        a = 0.5 * np.arctan2(np.bincount(lab, s2[ys, xs], n), np.bincount(lab, c2[ys, xs], n))
        ux, uy = np.cos(a)[lab], np.sin(a)[lab]
        along = xs * ux + ys * uy
        across = -xs * uy + ys * ux

        def extent(v: np.ndarray) -> np.ndarray:
            lo = np.full(n, np.inf)
            hi = np.full(n, -np.inf)
            np.minimum.at(lo, lab, v)
            np.maximum.at(hi, lab, v)
            return hi - lo + 1.0

        len_along, len_across = extent(along), extent(across)
        keep = (len_across >= 0.5 * len_along) & (len_across >= self.min_across * mask.shape[1])
        keep[0] = False
        return keep[labels]

    # ----------------------------------------------------------------- queries
    def cut_sides(self, boxes: np.ndarray) -> np.ndarray:
        """(N, 4) bool per box (xyxy full-resolution pixels): whether its left, top, right, bottom edge touches a
        static occluder (the vehicle may go on behind it)."""
        boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
        out = np.zeros((len(boxes), 4), bool)
        if not len(boxes) or not self.ready:
            return out
        wh, ww = self.mask.shape
        b = boxes / self.scale
        x0, y0 = np.floor(b[:, 0]), np.floor(b[:, 1])
        x1, y1 = np.ceil(b[:, 2]), np.ceil(b[:, 3])
        m = self.margin
        # strips just outside each edge (one work pixel inside it, ``margin`` outside), along the whole edge
        strips = np.stack([
            np.stack([x0 - m, y0, x0 + 1, y1], axis=1),
            np.stack([x0, y0 - m, x1, y0 + 1], axis=1),
            np.stack([x1 - 1, y0, x1 + m, y1], axis=1),
            np.stack([x0, y1 - 1, x1, y1 + m], axis=1),
        ], axis=1)  # (N, 4 sides, 4)
        sx0 = np.clip(strips[..., 0], 0, ww).astype(np.intp)
        sy0 = np.clip(strips[..., 1], 0, wh).astype(np.intp)
        sx1 = np.clip(strips[..., 2], 0, ww).astype(np.intp)
        sy1 = np.clip(strips[..., 3], 0, wh).astype(np.intp)
        ii = self._integral
        count = ii[sy1, sx1] - ii[sy0, sx1] - ii[sy1, sx0] + ii[sy0, sx0]
        area = (sx1 - sx0).clip(min=0) * (sy1 - sy0).clip(min=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            out = (area > 0) & (count >= self.side_fraction * area)
        return out

    def full_mask(self) -> np.ndarray | None:
        """The occluder mask at the frame's resolution (for drawing and tests)."""
        if self.mask is None or self.size is None:
            return None
        return cv2.resize(self.mask.astype(np.uint8), self.size, interpolation=cv2.INTER_NEAREST).astype(bool)


def complete_boxes(det: np.ndarray, cut: np.ndarray, pred: np.ndarray) -> np.ndarray:
    """The box a vehicle would have if the static occluder did not hide part of it: per (track, detection) pair,
    the detection's edges that are not cut, and the track's predicted size across the cut ones.

    ``det`` (N, 4), ``cut`` (N, 4) bool (left, top, right, bottom), ``pred`` (T, 4): returns (T, N, 4).  Along an
    axis cut on one side the box keeps its free edge and extends to the predicted size; cut on both sides it spans
    the prediction; and across the cut axis the fragment is only part of the vehicle, so the predicted extent is
    placed as near to the prediction as it can while still containing the fragment.
    """
    det = np.asarray(det, np.float64).reshape(-1, 4)
    pred = np.asarray(pred, np.float64).reshape(-1, 4)
    cut = np.asarray(cut, bool).reshape(-1, 4)
    out = np.broadcast_to(det[None], (len(pred), len(det), 4)).copy()
    if not cut.any() or not len(pred):
        return out
    axes = ((0, 2), (1, 3))
    for lo, hi in axes:  # along a cut axis
        size = (pred[:, hi] - pred[:, lo])[:, None]  # (T, 1)
        dlo, dhi = det[None, :, lo], det[None, :, hi]
        c_lo, c_hi = cut[None, :, lo], cut[None, :, hi]
        both = c_lo & c_hi
        out[..., lo] = np.where(both, np.minimum(dlo, pred[:, lo, None]),
                                np.where(c_lo, np.minimum(dlo, dhi - size), dlo))
        out[..., hi] = np.where(both, np.maximum(dhi, pred[:, hi, None]),
                                np.where(c_hi, np.maximum(dhi, dlo + size), dhi))
    for (lo, hi), (other_lo, other_hi) in ((axes[0], axes[1]), (axes[1], axes[0])):
        # across a cut axis (this one not cut): the predicted extent, moved as little as possible to contain the
        # fragment
        across = (cut[None, :, other_lo] | cut[None, :, other_hi]) & ~(cut[None, :, lo] | cut[None, :, hi])
        size = (pred[:, hi] - pred[:, lo])[:, None]
        dlo, dhi = det[None, :, lo], det[None, :, hi]
        placed = np.minimum(np.maximum(pred[:, lo, None], dhi - size), dlo)
        wider = across & (size > dhi - dlo)
        out[..., lo] = np.where(wider, placed, out[..., lo])
        out[..., hi] = np.where(wider, placed + size, out[..., hi])
    return out
