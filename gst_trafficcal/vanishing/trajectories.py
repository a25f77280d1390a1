"""VP1 from whole vehicle trajectories: the tracker's road-plane reference points, one straight line per vehicle.

The calibrator's VP1 (:mod:`.tracks`) comes from short KLT tracks of corners on the vehicles (at most 60
observations).  A tracked vehicle's reference point (the centre of the bottom-front edge of its 3D box) is a point
on the road that moves along its lane for the whole traversal, so its image trajectory is a long straight line
through VP1 — a second, independent estimate once a first calibration has given the tracker its 3D boxes.  The
trajectory's direction hardly depends on which VPs built the boxes (the point's error along the road stays on the
line).  Measured against the calibrator's in ``benchmarks/vp1_trajectories.py`` (docs/vpdetect.md, "Stop 24"),
alone (:func:`vp1_from_trajectories`) and as extra votes in the calibrator's own VP1 accumulator
(:func:`vp1_with_trajectory_votes`).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..diamond import DiamondSpace, Peak
from ..errors import GeometryError
from ..manual_calibration import intersect_lines_lsq
from .tracks import fit_lines


@dataclass(frozen=True)
class TrajectoryVP:
    """A vanishing point from trajectory lines: ``point`` (pixels), the lines that voted (``lines`` (N, 3), unit
    normals) and the ``inliers`` (N,) the robust fit kept, and their RMS distance from the point (``spread``,
    pixels)."""

    point: np.ndarray
    lines: np.ndarray
    inliers: np.ndarray
    spread: float


def trajectory_lines(tracks: Sequence[np.ndarray], min_points: int = 15, min_span: float = 100.0,
                     max_rms: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """Total-least-squares lines of image trajectories (each (K, 2) pixels; NaN rows are skipped) that are long
    (``min_points`` points spanning ``min_span`` px end to end) and straight (RMS distance from the line at most
    ``max_rms`` px).  Returns the lines (N, 3, unit normals) and their spans (N,) in pixels."""
    sums, spans = [], []
    for pts in tracks:
        p = np.asarray(pts, np.float64).reshape(-1, 2)
        p = p[np.all(np.isfinite(p), axis=1)]
        if len(p) < min_points:
            continue
        span = float(np.linalg.norm(p[-1] - p[0]))
        if span < min_span:
            continue
        x, y = p[:, 0], p[:, 1]
        sums.append([len(p), x.sum(), y.sum(), (x * x).sum(), (x * y).sum(), (y * y).sum()])
        spans.append(span)
    if not sums:
        return np.zeros((0, 3)), np.zeros(0)
    lines, rms = fit_lines(np.array(sums))
    keep = rms <= max_rms
    return lines[keep], np.array(spans)[keep]


def robust_intersection(lines: np.ndarray, weights: np.ndarray | None = None, cutoff: float = 2.5,
                        iterations: int = 10) -> tuple[np.ndarray, np.ndarray] | None:
    """Weighted least-squares intersection of lines (N, 3) that drops, again and again, the lines farther than
    ``cutoff`` robust standard deviations (1.4826 MAD of the distances) from the current point (lane changes,
    a bent trajectory).  Returns (point (2,), inliers (N,)), or None for fewer than two lines or parallel ones."""
    lines = np.asarray(lines, np.float64).reshape(-1, 3)
    norm = np.linalg.norm(lines[:, :2], axis=1)
    ok = norm > 0
    if ok.sum() < 2:
        return None
    L = np.where(ok[:, None], lines / np.where(ok, norm, 1.0)[:, None], 0.0)
    w = np.ones(len(L)) if weights is None else np.asarray(weights, np.float64).reshape(len(L))
    inl = ok.copy()
    point = None
    for _ in range(iterations):
        try:
            point = intersect_lines_lsq(L[inl], w[inl])
        except GeometryError:  # the lines left are parallel
            return None
        d = np.abs(L[:, :2] @ point + L[:, 2])
        scale = 1.4826 * np.median(d[inl]) + 1e-9
        new = ok & (d <= cutoff * scale)
        if new.sum() < 2 or np.array_equal(new, inl):
            break
        inl = new
    return point, inl


def vp1_from_trajectories(tracks: Sequence[np.ndarray], min_lines: int = 8, **line_options) -> TrajectoryVP | None:
    """VP1 as the robust intersection of the straight trajectories among ``tracks`` (image points of each
    vehicle's reference point, pixels), each weighted by its span; None with fewer than ``min_lines`` straight
    trajectories (``line_options``: :func:`trajectory_lines`'s thresholds)."""
    lines, spans = trajectory_lines(tracks, **line_options)
    if len(lines) < min_lines:
        return None
    got = robust_intersection(lines, spans)
    if got is None:
        return None
    point, inliers = got
    d = lines[inliers, :2] @ point + lines[inliers, 2]
    return TrajectoryVP(point, lines, inliers, float(np.sqrt(np.mean(d * d))))


def vp1_with_trajectory_votes(ds: DiamondSpace, tracks: Sequence[np.ndarray], share: float = 0.25,
                              min_lines: int = 8, **line_options) -> Peak | None:
    """VP1 of the calibrator's accumulator ``ds`` (its KLT track lines; left unchanged) with the straight
    trajectories among ``tracks`` voted in as well, weighted by span and together ``share`` of the weight already
    in it; None with fewer than ``min_lines`` straight trajectories or no peak."""
    lines, spans = trajectory_lines(tracks, **line_options)
    total = float(ds.weights.sum())
    if len(lines) < min_lines or total <= 0:
        return None
    both = copy.deepcopy(ds)
    both.insert(lines, share * total * spans / spans.sum())
    return both.find_peak()
