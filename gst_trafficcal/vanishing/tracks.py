"""VP1 evidence: straight tracks of points on moving vehicles (paper §4.1, after Dubská et al. ITS 2015).

Shi–Tomasi corners are detected inside the foreground of a background model (``foreground.py``), followed with pyramidal
KLT (forward-backward checked) on a reduced-resolution grey image, and every finished track that is long,
moving and straight becomes one homogeneous line (total-least-squares fit of its positions) and one projective
motion fit (``constant_speed.py``: how far along that line its vanishing point is).  Each track keeps only
running sums (Σx, Σy, Σx², Σxy, Σy² and the motion fit's), so memory and time do not grow with the track length.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import NamedTuple

import cv2
import numpy as np

from .constant_speed import N_SUMS, LaneMotion, fit_motion, motion_terms


@dataclass
class TrackParams:
    """Tuning of :class:`MotionLines` (pixel values at the analysis resolution)."""

    max_corners: int = 400
    min_distance: int = 6
    quality: float = 0.01
    min_length: int = 8            # observations
    max_length: int = 60           # a track is emitted (and restarted) after this many observations
    min_motion: float = 12.0       # px between first and last point
    max_residual: float = 0.6      # px, RMS distance of the points to their fitted line
    min_step: float = 0.3          # px per step: slower points are static (parked cars, noise)
    fb_error: float = 0.7          # px, forward-backward KLT error
    detect_every: int = 2          # new corners every n-th analysed frame
    warmup: int = 0                # analysed frames before detecting corners

    def spaced(self, ratio: float) -> "TrackParams":
        """These parameters for frames ``ratio`` times further apart than those they were set for (0.08 s, the
        calibrator's ``frame_spacing``): the same track duration and corner-detection interval in fewer frames, the
        same speed (px/s) in larger steps; ``self`` at a ratio of 1.  At 5 fps a track needed 8 observations over
        1.6 s instead of 0.64 s, and its tracks and their VP1 lagged the 25 fps stream's (docs/vpdetect.md)."""
        if ratio == 1.0:
            return self
        min_length = max(3, math.ceil(self.min_length / ratio - 1e-9))
        return replace(self, min_length=min_length, max_length=max(min_length, round(self.max_length / ratio)),
                       min_step=self.min_step * ratio, detect_every=max(1, round(self.detect_every / ratio)))


def fit_lines(sums: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Total-least-squares lines of point sets from their sums (N, 6) = (n, Σx, Σy, Σxx, Σxy, Σyy).

    Returns homogeneous lines (N, 3) with unit normals and the RMS residual (N,).
    """
    n = sums[:, 0]
    mx, my = sums[:, 1] / n, sums[:, 2] / n
    cxx = sums[:, 3] / n - mx * mx
    cxy = sums[:, 4] / n - mx * my
    cyy = sums[:, 5] / n - my * my
    half = 0.5 * (cxx - cyy)
    root = np.sqrt(half * half + cxy * cxy)
    small = 0.5 * (cxx + cyy) - root          # variance across the line
    theta = 0.5 * np.arctan2(2 * cxy, cxx - cyy)  # direction of the line
    nx, ny = -np.sin(theta), np.cos(theta)
    lines = np.stack([nx, ny, -(nx * mx + ny * my)], axis=1)
    return lines, np.sqrt(np.maximum(small, 0.0))


class FinishedTracks(NamedTuple):
    """The straight tracks finished by one :meth:`MotionLines.update` (analysis-scale pixels)."""

    lines: np.ndarray     # (K, 3) homogeneous lines, unit normals
    lengths: np.ndarray   # (K,) px between first and last point
    motion: LaneMotion    # their projective motion fits (those that have one; not index-aligned with lines)


class MotionLines:
    """Streaming KLT tracker producing one line per finished straight track (coordinates at analysis scale)."""

    def __init__(self, params: TrackParams | None = None) -> None:
        self.p = params or TrackParams()
        self.prev: np.ndarray | None = None
        self.frames = 0
        self.pts = np.zeros((0, 2), np.float32)
        self.start = np.zeros((0, 2), np.float32)
        self.sums = np.zeros((0, 6))
        self.t0 = np.zeros(0)                 # time of each track's first point
        self.motion = np.zeros((0, N_SUMS))   # its motion sums (constant_speed.motion_terms)

    def update(self, gray: np.ndarray, fg: np.ndarray, t: float | None = None) -> FinishedTracks:
        """Feed the next analysed frame, its foreground mask (any size, 0/255) and its time in seconds (None:
        the frame count, for evenly spaced frames); returns the straight tracks finished now."""
        self.frames += 1
        t = float(self.frames if t is None else t)
        out_lines: list[np.ndarray] = []
        out_len: list[np.ndarray] = []
        out_motion: list[LaneMotion] = []
        if self.prev is not None and len(self.pts):
            nxt, st, _ = cv2.calcOpticalFlowPyrLK(self.prev, gray, self.pts.reshape(-1, 1, 2), None,
                                                  winSize=(15, 15), maxLevel=2)
            back, st2, _ = cv2.calcOpticalFlowPyrLK(gray, self.prev, nxt, None, winSize=(15, 15), maxLevel=2)
            nxt = nxt.reshape(-1, 2)
            fb = np.linalg.norm(back.reshape(-1, 2) - self.pts, axis=1)
            step = np.linalg.norm(nxt - self.pts, axis=1)
            h, w = gray.shape
            alive = ((st.ravel() == 1) & (st2.ravel() == 1) & (fb < self.p.fb_error) & (step >= self.p.min_step)
                     & (nxt[:, 0] >= 0) & (nxt[:, 1] >= 0) & (nxt[:, 0] < w - 1) & (nxt[:, 1] < h - 1))
            x, y = nxt[:, 0].astype(np.float64), nxt[:, 1].astype(np.float64)
            self.sums[alive] += np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], axis=1)[alive]
            self.motion[alive] += motion_terms(t - self.t0, x - self.start[:, 0], y - self.start[:, 1])[alive]
            self.pts = nxt
            full = alive & (self.sums[:, 0] >= self.p.max_length)
            done = ~alive | full
            if done.any():
                lines, lengths, motion = self._accept(done)
                out_lines.append(lines)
                out_len.append(lengths)
                out_motion.append(motion)
            keep = ~done
            self.pts, self.start, self.sums = self.pts[keep], self.start[keep], self.sums[keep]
            self.t0, self.motion = self.t0[keep], self.motion[keep]
        if self.frames > self.p.warmup and self.frames % self.p.detect_every == 0:
            self._detect(gray, fg, t)
        self.prev = gray.copy()
        if not out_lines:
            return FinishedTracks(np.zeros((0, 3)), np.zeros(0), LaneMotion.empty())
        return FinishedTracks(np.concatenate(out_lines), np.concatenate(out_len), LaneMotion.concatenate(out_motion))

    def _accept(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, LaneMotion]:
        """Lines, lengths and motion fits of the straight tracks among the finished ones (boolean mask)."""
        sums = self.sums[idx]
        motion = np.linalg.norm(self.pts[idx] - self.start[idx], axis=1)
        ok = (sums[:, 0] >= self.p.min_length) & (motion >= self.p.min_motion)
        if not ok.any():
            return np.zeros((0, 3)), np.zeros(0), LaneMotion.empty()
        lines, resid = fit_lines(sums[ok])
        straight = resid <= self.p.max_residual
        sel = np.flatnonzero(idx)[ok][straight]
        fits = fit_motion(self.motion[sel], self.sums[sel, 0], self.start[sel])
        return lines[straight], motion[ok][straight], fits

    def _detect(self, gray: np.ndarray, fg: np.ndarray, t: float = 0.0) -> None:
        room = self.p.max_corners - len(self.pts)
        if room <= 10 or not fg.any():
            return
        mask = cv2.resize(fg, (gray.shape[1], gray.shape[0]), interpolation=cv2.INTER_NEAREST)
        if len(self.pts):  # no new corners next to tracked ones
            taken = np.zeros_like(mask)
            xy = np.clip(np.round(self.pts).astype(np.int64), 0, [mask.shape[1] - 1, mask.shape[0] - 1])
            taken[xy[:, 1], xy[:, 0]] = 255
            d = 2 * self.p.min_distance + 1
            taken = cv2.dilate(taken, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (d, d)))
            mask[taken > 0] = 0
        x, y, bw, bh = cv2.boundingRect(mask)  # corners only where the mask is: skip the rest of the image
        if bw < 8 or bh < 8:
            return
        corners = cv2.goodFeaturesToTrack(gray[y:y + bh, x:x + bw], room, self.p.quality, self.p.min_distance,
                                          mask=mask[y:y + bh, x:x + bw], blockSize=5)
        if corners is None:
            return
        c = corners.reshape(-1, 2).astype(np.float32) + np.float32([x, y])
        x, y = c[:, 0].astype(np.float64), c[:, 1].astype(np.float64)
        self.pts = np.concatenate([self.pts, c])
        self.start = np.concatenate([self.start, c])
        self.sums = np.concatenate([self.sums, np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], axis=1)])
        self.t0 = np.concatenate([self.t0, np.full(len(c), t)])
        self.motion = np.concatenate([self.motion, np.zeros((len(c), N_SUMS))])  # the first point adds 0 (t = 0)
