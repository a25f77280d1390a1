"""BrnoCompSpeed evaluation metrics, reimplemented (vectorised) after the dataset's official ``code/eval.py``.

What the official code does, and therefore what this module does, step by step:

* **Prefilter** system cars: drop cars first seen (``frames[0] / fps``) at or after the last ground-truth
  crossing time; drop cars whose positions are plain numbers; drop points within 10 px of the 1920x1080
  border; drop cars left with ≤ 5 points, cars with any point outside the lane dividers, cars with any point
  in an invalid lane, and cars with fewer than 6 points between the first and last measurement lines.
* **Crossing** of a track with a measurement line: take the 6 points nearest to the line (stable order),
  fit y = a·x + b (``scipy.stats.linregress``), intersect with the line; fit frame number against the
  distance of the projected points from the fitted line's x-axis crossing and evaluate it at the
  intersection.  Identical x coordinates: the code was written for the scipy of its time, which returned
  ``0/0 = NaN`` for the slope (today's scipy raises instead); the NaN makes the car an intersection error.
* A car whose crossings with the first and last lines are not finite or not in a lane is an *error* and
  counts as a false positive.  Otherwise its lane is the lane of the crossing of ``measurementLines[0]``
  and its match time (``timeIntersectionLast``) is that crossing's frame / fps.
* **Speed** ("median" mode, τ = 5): median over i of scale·‖P(i+5) − P(i)‖ / (|f(i+5) − f(i)| / fps),
  in km/h, over the car's points in file order.  ("full" mode: the distance between the two crossings.)
* **Matching**: for each ground-truth car in order, among cars in one of its lanes, the one whose match time
  is nearest to the ground truth's ``intersections[-1].videoTime`` (first in file order on ties), if nearer
  than 0.2 s.  In the dataset that is the crossing of ``measurementLines[0]``, the *last* line cars cross
  (ground-truth crossings are listed in time order).  A system car may match several ground-truth cars.  Recall over valid ground-truth cars;
  speed errors over matched valid ones; false positives = unmatched cars whose match time lies in
  [first, last) ground-truth time, plus the intersection errors.
* **Calibration**: distance-ratio error over all pairs (i < j) of measured segments,
  |‖P₁ⁱ−P₂ⁱ‖/‖P₁ʲ−P₂ʲ‖ − dᵢ/dⱼ| (and relative to dᵢ/dⱼ in %); distance errors with scale over all segments
  and over those towards VP1, in metres and %.

Statistics are mean, median, ``np.percentile`` 95 / 99 (linear interpolation, as the code) and max.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from itertools import combinations
from typing import Any, Literal, Sequence

import numpy as np

from .brnocompspeed import GroundTruth, Results, Track
from .errors import InputError
from .geometry import Camera

WIDTH = 1920
HEIGHT = 1080
SAFE_BORDER_OFFSET = 10  # px
MIN_POINTS = 6  # a car needs > 5 points, >= 6 of them between the measurement lines
AROUND = 6  # points used to fit a crossing
MAX_TIME_DIFF = 0.2  # s
SPEED_TAU = 5  # frames between the points of one median-mode speed sample

SpeedMode = Literal["median", "full"]


# --------------------------------------------------------------------------- statistics


@dataclass(frozen=True)
class ErrorStats:
    """Summary of a list of errors as the official tables print it (plus the 99th percentile)."""

    n: int
    mean: float
    median: float
    p95: float
    p99: float
    max: float

    @classmethod
    def of(cls, errors: Sequence[float] | np.ndarray) -> "ErrorStats":
        e = np.asarray(errors, dtype=float).ravel()
        if e.size == 0:
            return cls(0, math.nan, math.nan, math.nan, math.nan, math.nan)
        return cls(int(e.size), float(np.mean(e)), float(np.median(e)), float(np.percentile(e, 95.0)),
                   float(np.percentile(e, 99.0)), float(np.max(e)))

    def to_dict(self) -> dict[str, float | int | None]:
        def clean(v: float) -> float | None:
            return None if math.isnan(v) else v

        return {"mean": clean(self.mean), "median": clean(self.median), "p95": clean(self.p95),
                "p99": clean(self.p99), "max": clean(self.max), "n": self.n}


# --------------------------------------------------------------------------- image-line helpers


def _line_values(points: np.ndarray, lines: np.ndarray) -> np.ndarray:
    """l·[x, y, 1] for points (N, 2) and lines (L, 3) -> (L, N)."""
    return (lines[:, 0:1] * points[:, 0] + lines[:, 1:2] * points[:, 1]) + lines[:, 2:3]


def points_between_lines(points: np.ndarray, l1: np.ndarray, l2: np.ndarray) -> np.ndarray:
    """The official ``isPointBetweenLines`` for many points: (p·l1)(p·l2)(n1·n2) ≤ 0."""
    v = _line_values(np.asarray(points, float), np.stack([l1, l2]))
    return v[0] * v[1] * float(np.dot(l1[:2], l2[:2])) <= 0


def lanes_of_points(points: np.ndarray, lane_div_lines: np.ndarray) -> np.ndarray:
    """Lane index of each point (N, 2): the first k with the point between dividers k and k+1, else -1."""
    points = np.asarray(points, float).reshape(-1, 2)
    lines = np.asarray(lane_div_lines, float)
    v = _line_values(points, lines)  # (L, N)
    dots = np.sum(lines[:-1, :2] * lines[1:, :2], axis=1)  # (L-1,)
    between = v[:-1] * v[1:] * dots[:, None] <= 0  # (L-1, N); NaN compares False
    lane = np.argmax(between, axis=0)
    return np.where(between.any(axis=0), lane, -1)


# --------------------------------------------------------------------------- prefilter


@dataclass(frozen=True)
class _Flat:
    """All points of many tracks concatenated, with per-point track index."""

    pos: np.ndarray  # (P, 2)
    frames: np.ndarray  # (P,)
    owner: np.ndarray  # (P,) index of the track


def _flatten(tracks: Sequence[Track]) -> _Flat:
    if not tracks:
        return _Flat(np.zeros((0, 2)), np.zeros(0), np.zeros(0, dtype=np.intp))
    lengths = np.array([len(t.frames) for t in tracks])
    return _Flat(np.concatenate([t.pos for t in tracks]), np.concatenate([t.frames for t in tracks]).astype(float),
                 np.repeat(np.arange(len(tracks)), lengths))


def _per_track_all(mask: np.ndarray, owner: np.ndarray, n: int) -> np.ndarray:
    return np.bincount(owner[~mask], minlength=n) == 0


def prefilter(tracks: Sequence[Track], gt: GroundTruth, width: int = WIDTH, height: int = HEIGHT) -> list[Track]:
    """The official ``prefilterData``: the cars (with border points removed) that take part in matching."""
    if not gt.cars:
        raise InputError(f"{gt.source or 'ground truth'}: has no ground-truth cars to match against")
    max_time = max(c.match_time for c in gt.cars)
    cars = [t for t in tracks if t.frames[0] / gt.fps < max_time and not t.scalar_positions]
    # remove points near the image border (strict inequalities, as the code)
    flat = _flatten(cars)
    b = SAFE_BORDER_OFFSET
    x, y = flat.pos[:, 0], flat.pos[:, 1]
    keep = (x > b) & (x < width - b) & (y > b) & (y < height - b)
    trimmed = []
    splits = np.cumsum([len(t.frames) for t in cars])[:-1]
    for t, k in zip(cars, np.split(keep, splits) if cars else []):
        if np.count_nonzero(k) > MIN_POINTS - 1:
            trimmed.append(Track(t.id, t.frames[k], t.pos[k], t.scalar_positions))
    if not trimmed:
        return []
    flat = _flatten(trimmed)
    n = len(trimmed)
    lanes = lanes_of_points(flat.pos, gt.lane_div_lines)
    ok = _per_track_all(lanes >= 0, flat.owner, n)
    if gt.invalid_lanes:
        ok &= _per_track_all(~np.isin(lanes, list(gt.invalid_lanes)), flat.owner, n)
    lines = gt.measurement_lines
    x, y = flat.pos[:, 0], flat.pos[:, 1]
    inside = (x >= 0) & (x <= width) & (y >= 0) & (y <= height)
    between = inside & points_between_lines(flat.pos, lines[0], lines[-1])
    ok &= np.bincount(flat.owner[between], minlength=n) >= MIN_POINTS
    return [t for t, good in zip(trimmed, ok) if good]


# --------------------------------------------------------------------------- crossings


@dataclass(frozen=True)
class Crossings:
    """Spatio-temporal crossings of N tracks with one line."""

    point: np.ndarray  # (N, 3) homogeneous image point (last coordinate 1; NaN/inf on failure)
    frame: np.ndarray  # (N,) fractional frame number
    identical_x: np.ndarray  # (N,) how many of the two fits (spatial, temporal) met identical x values


def _linregress_rows(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row-wise least-squares slope and intercept as the scipy of the official code computed them.

    slope = cov(x, y) / var(x) (population moments), intercept = ȳ − slope·x̄; identical x gives 0/0 = NaN.
    """
    n = x.shape[1]
    xmean = x.sum(axis=1) / n
    ymean = y.sum(axis=1) / n
    xm = x - xmean[:, None]
    ym = y - ymean[:, None]
    ssxm = np.einsum("ij,ij->i", xm, xm) / n
    ssxym = np.einsum("ij,ij->i", xm, ym) / n
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = ssxym / ssxm
        intercept = ymean - slope * xmean
    return slope, intercept


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", over="ignore"):
        return np.cross(a, b)


def _crossings_same_length(pos: np.ndarray, frames: np.ndarray, line: np.ndarray) -> Crossings:
    """Crossings for a block of tracks padded to a common length (padding = NaN)."""
    n_tracks = pos.shape[0]
    with np.errstate(invalid="ignore"):
        dist = np.abs(line[0] * pos[..., 0] + line[1] * pos[..., 1] + line[2]) / np.linalg.norm(line[:2])
    dist = np.where(np.isnan(pos[..., 0]), np.inf, dist)
    order = np.argsort(dist, axis=1, kind="stable")[:, :AROUND]
    rows = np.arange(n_tracks)[:, None]
    xs, ys, fs = pos[rows, order, 0], pos[rows, order, 1], frames[rows, order]
    identical_x = (xs.max(axis=1) == xs.min(axis=1)).astype(np.int8)
    a, c = _linregress_rows(xs, ys)
    spatial = np.stack([a, -np.ones_like(a), c], axis=1)  # y = a x + c  <=>  [a, -1, c]·[x, y, 1] = 0
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        inter = _cross(spatial, np.broadcast_to(line, spatial.shape))
        inter = inter / inter[:, 2:3]
        origin = _cross(spatial, np.broadcast_to([0.0, 1.0, 0.0], spatial.shape))  # fitted line ∩ {y = 0}
        origin = origin / origin[:, 2:3]
        # orthogonal projection of each point on the fitted line (official pointToLineProjection)
        cperp = xs * spatial[:, 1:2] - ys * spatial[:, 0:1]
        perp = np.stack([np.broadcast_to(-spatial[:, 1:2], cperp.shape),
                         np.broadcast_to(spatial[:, 0:1], cperp.shape), cperp], axis=-1)
        proj = _cross(np.broadcast_to(spatial[:, None, :], perp.shape), perp)
        proj = proj / proj[..., 2:3]
        dists = np.linalg.norm(origin[:, None, :] - proj, axis=-1)
        t_slope, t_icpt = _linregress_rows(dists, fs)
        identical_x += dists.max(axis=1) == dists.min(axis=1)
        frame = t_slope * np.linalg.norm(inter - origin, axis=1) + t_icpt
    return Crossings(inter, frame, identical_x)


def crossings(tracks: Sequence[Track], line: np.ndarray, block: int = 256) -> Crossings:
    """The official ``getCarTimeAndSpatialIntersection`` for every track (each needs ≥ 6 points)."""
    line = np.asarray(line, dtype=float)
    n = len(tracks)
    point, frame, ident = np.empty((n, 3)), np.empty(n), np.zeros(n, dtype=np.int8)
    if n == 0:
        return Crossings(point, frame, ident)
    lengths = np.array([len(t.frames) for t in tracks])
    if lengths.min() < AROUND:
        raise ValueError(f"every track needs at least {AROUND} points to fit a line crossing")
    by_len = np.argsort(lengths, kind="stable")  # similar lengths together keep padding small
    for start in range(0, n, block):
        idx = by_len[start:start + block]
        m = lengths[idx].max()
        pos = np.full((len(idx), m, 2), np.nan)
        frames = np.zeros((len(idx), m))
        for r, i in enumerate(idx):
            pos[r, :lengths[i]] = tracks[i].pos
            frames[r, :lengths[i]] = tracks[i].frames
        c = _crossings_same_length(pos, frames, line)
        point[idx], frame[idx], ident[idx] = c.point, c.frame, c.identical_x
    return Crossings(point, frame, ident)


# --------------------------------------------------------------------------- tracks ready for matching


@dataclass(frozen=True)
class PreparedTracks:
    """Calibration-independent part of the evaluation of one results file against one ground truth."""

    tracks: tuple[Track, ...]  # after the prefilter
    ok: np.ndarray  # (N,) crossings finite and in a lane (else an "intersection error")
    lane: np.ndarray  # (N,) lane of the crossing of measurementLines[0] (-1 if not ok)
    time_last: np.ndarray  # (N,) s, crossing of measurementLines[0]  (official "timeIntersectionLast")
    time_first: np.ndarray  # (N,) s, crossing of measurementLines[-1]
    point_last: np.ndarray  # (N, 2) px
    point_first: np.ndarray  # (N, 2) px
    frame_last: np.ndarray  # (N,)
    frame_first: np.ndarray  # (N,)
    identical_x: int  # line fits (linregress calls) that met identical x values
    n_input: int  # cars in the results file

    @property
    def n_errors(self) -> int:
        return int(np.count_nonzero(~self.ok))


def prepare_tracks(results: Results, gt: GroundTruth, width: int = WIDTH, height: int = HEIGHT) -> PreparedTracks:
    """Prefilter and line crossings (the parts of the official evaluation that need no calibration)."""
    tracks = prefilter(results.cars, gt, width, height)
    # the official code fits every line (only the outer two are used); all fits count towards identical_x
    every = [crossings(tracks, line) for line in gt.measurement_lines]
    last, first = every[0], every[-1]  # official "end" = lines[0], "start" = lines[-1]
    finite = (np.all(np.isfinite(last.point), axis=1) & np.all(np.isfinite(first.point), axis=1)
              & np.isfinite(last.frame) & np.isfinite(first.frame))
    with np.errstate(invalid="ignore"):
        lane_last = lanes_of_points(last.point[:, :2], gt.lane_div_lines)
        lane_first = lanes_of_points(first.point[:, :2], gt.lane_div_lines)
    ok = finite & (lane_last >= 0) & (lane_first >= 0)
    return PreparedTracks(
        tracks=tuple(tracks), ok=ok, lane=np.where(ok, lane_last, -1),
        time_last=last.frame / gt.fps, time_first=first.frame / gt.fps,
        point_last=last.point[:, :2], point_first=first.point[:, :2],
        frame_last=last.frame, frame_first=first.frame,
        identical_x=int(sum(int(c.identical_x.sum()) for c in every)),
        n_input=len(results.cars))


# --------------------------------------------------------------------------- speeds


def median_speeds(tracks: Sequence[Track], camera: Camera, fps: float, tau: int = SPEED_TAU) -> np.ndarray:
    """Per track, the median of λ‖P(i+τ) − P(i)‖ / (|f(i+τ) − f(i)| / fps) in km/h (NaN if < τ+1 points)."""
    n = len(tracks)
    out = np.full(n, np.nan)
    if n == 0:
        return out
    flat = _flatten(tracks)
    lengths = np.bincount(flat.owner, minlength=n)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    local = np.arange(len(flat.owner)) - starts[flat.owner]
    i = np.flatnonzero(local < (lengths - tau)[flat.owner])  # samples whose i+τ is in the same track
    road = camera.to_road(flat.pos)
    with np.errstate(divide="ignore", invalid="ignore"):
        dist = camera.scale * np.linalg.norm(road[i] - road[i + tau], axis=1)
        speed = dist / (np.abs(flat.frames[i] - flat.frames[i + tau]) / fps) * 3.6
    owner = flat.owner[i]
    has_nan = np.bincount(owner[np.isnan(speed)], minlength=n) > 0
    order = np.lexsort((speed, owner))  # grouped by track, sorted by speed within it (NaN last)
    s, cnt = speed[order], np.bincount(owner, minlength=n)
    first = np.concatenate([[0], np.cumsum(cnt)[:-1]])
    valid = cnt > 0
    lo = first + (cnt - 1) // 2
    hi = first + cnt // 2
    with np.errstate(invalid="ignore"):
        med = np.where(valid, 0.5 * (s[np.minimum(lo, len(s) - 1)] + s[np.minimum(hi, len(s) - 1)]), np.nan) \
            if len(s) else np.full(n, np.nan)
        # np.median returns the middle value itself for odd counts (0.5*(a+a) == a exactly unless inf)
        odd = valid & (cnt % 2 == 1)
        med[odd] = s[lo[odd]]
    med[has_nan] = np.nan
    return med


def full_speeds(prepared: PreparedTracks, camera: Camera, fps: float) -> np.ndarray:
    """Official "full" mode: distance between the two line crossings over the time between them, km/h."""
    with np.errstate(divide="ignore", invalid="ignore"):
        d = camera.distance(prepared.point_first, prepared.point_last)
        return d / (np.abs(prepared.frame_last - prepared.frame_first) / fps) * 3.6


# --------------------------------------------------------------------------- matching


@dataclass(frozen=True)
class Matching:
    """Result of matching ground-truth cars with system cars."""

    track_of_gt: np.ndarray  # (G,) index into PreparedTracks.tracks, -1 when unmatched
    valid: np.ndarray  # (G,) ground-truth car is valid
    recall: float
    false_positives: int
    n_matched: int
    n_matched_valid: int


def match(gt: GroundTruth, prepared: PreparedTracks) -> Matching:
    """Official ``computeMatches`` + ``computeRecall`` + ``computeFalsePositives`` (a ground truth without cars:
    no match, recall NaN, only the tracks' intersection errors as false positives)."""
    g = len(gt.cars)
    t_gt = np.array([c.match_time for c in gt.cars])
    valid = np.array([c.valid for c in gt.cars], dtype=bool)
    n_lanes = max([len(gt.lane_div_lines)] + [max(c.lanes) + 1 for c in gt.cars if c.lanes])
    lane_ok = np.zeros((g, n_lanes + 1), dtype=bool)  # last column: "no lane" (never matches)
    for k, c in enumerate(gt.cars):
        lane_ok[k, [lane for lane in c.lanes if lane >= 0]] = True
    cand = np.flatnonzero(prepared.ok)
    track_of_gt = np.full(g, -1)
    if cand.size:
        dt = np.abs(prepared.time_last[cand][None, :] - t_gt[:, None])  # (G, C)
        dt = np.where(lane_ok[:, prepared.lane[cand]], dt, np.inf)
        best = np.argmin(dt, axis=1)  # first in file order on ties, like a stable sort
        hit = dt[np.arange(g), best] < MAX_TIME_DIFF
        track_of_gt[hit] = cand[best[hit]]
    matched = track_of_gt >= 0
    n_valid = int(np.count_nonzero(valid))
    recall = float(np.count_nonzero(matched & valid) / n_valid) if n_valid else math.nan
    ids = [prepared.tracks[i].id for i in track_of_gt[matched]]
    matched_ids = set(ids)
    # the false positives are counted in the ground truth's time span: none without a ground-truth car (the
    # official code stops there with numpy's "zero-size array to reduction operation", and so did this)
    lo, hi = (t_gt.min(), t_gt.max()) if g else (0.0, 0.0)
    fp = sum(1 for i in cand if lo <= prepared.time_last[i] < hi and prepared.tracks[i].id not in matched_ids)
    return Matching(track_of_gt, valid, recall, fp + prepared.n_errors, int(np.count_nonzero(matched)),
                    int(np.count_nonzero(matched & valid)))


# --------------------------------------------------------------------------- calibration metrics


@dataclass(frozen=True)
class CalibrationReport:
    focal: float
    ratio_abs: ErrorStats
    ratio_rel_pct: ErrorStats
    dist_all_abs_m: ErrorStats | None
    dist_all_rel_pct: ErrorStats | None
    dist_vp1_abs_m: ErrorStats | None
    dist_vp1_rel_pct: ErrorStats | None
    segments: list[dict[str, Any]] = field(default_factory=list)


def evaluate_calibration(gt: GroundTruth, camera: Camera) -> CalibrationReport:
    """Distance-ratio errors over all pairs of segments, and distance errors with scale (if any)."""
    p1, p2, d = gt.distances_p1, gt.distances_p2, gt.distances_m
    to_vp1 = gt.distances_to_vp1
    plane = camera.plane_distance(p1, p2)
    pairs = np.array(list(combinations(range(len(d)), 2)), dtype=np.intp).reshape(-1, 2)
    ratio_img = plane[pairs[:, 0]] / plane[pairs[:, 1]]
    ratio_real = d[pairs[:, 0]] / d[pairs[:, 1]]
    ratio_abs = np.abs(ratio_img - ratio_real)
    ratio_rel = ratio_abs / ratio_real * 100
    segments = [{"p1": p1[k].tolist(), "p2": p2[k].tolist(), "distance_m": float(d[k]),
                 "to_vp1": bool(to_vp1[k])} for k in range(len(d))]
    stats: list[ErrorStats | None] = [None] * 4
    if camera.scale is not None:
        measured = camera.scale * plane
        err = np.abs(measured - d)
        rel = err / d * 100
        stats = [ErrorStats.of(err), ErrorStats.of(rel), ErrorStats.of(err[to_vp1]), ErrorStats.of(rel[to_vp1])]
        for k, s in enumerate(segments):
            s["measured_m"] = float(measured[k])
    return CalibrationReport(camera.focal, ErrorStats.of(ratio_abs), ErrorStats.of(ratio_rel), *stats,
                             segments=segments)


# --------------------------------------------------------------------------- speed metrics


@dataclass(frozen=True)
class SpeedReport:
    abs_kmh: ErrorStats
    rel_pct: ErrorStats
    recall: float
    false_positives: int
    matched: int
    matched_valid: int
    n_cars: int  # cars in the results file
    n_cars_after_prefilter: int
    n_intersection_errors: int
    linregress_identical_x: int
    n_gt_cars: int
    n_gt_valid: int
    errors_abs_kmh: np.ndarray  # per matched valid car, in ground-truth order
    errors_rel_pct: np.ndarray
    cars: list[dict[str, Any]] = field(default_factory=list)


def evaluate_speeds(gt: GroundTruth, prepared: PreparedTracks, camera: Camera,
                    mode: SpeedMode = "median") -> SpeedReport:
    """Speed errors, recall and false positives of prepared tracks measured with ``camera``."""
    if camera.scale is None:
        raise InputError("the calibration has no scale: speeds in km/h cannot be measured")
    m = match(gt, prepared)
    if mode == "median":
        speeds = median_speeds(prepared.tracks, camera, gt.fps)
    elif mode == "full":
        speeds = full_speeds(prepared, camera, gt.fps)
    else:
        raise ValueError(f"unknown speed mode {mode!r}")
    gt_speed = np.array([c.speed for c in gt.cars])
    use = (m.track_of_gt >= 0) & m.valid
    measured = speeds[m.track_of_gt[use]]
    err_abs = np.abs(gt_speed[use] - measured)
    err_rel = err_abs / gt_speed[use] * 100
    cars = []
    for k in np.flatnonzero(m.track_of_gt >= 0):
        i = m.track_of_gt[k]
        cars.append({"gt_id": gt.cars[k].car_id, "id": prepared.tracks[i].id, "valid": bool(m.valid[k]),
                     "lane": int(prepared.lane[i]), "gt_speed_kmh": float(gt_speed[k]),
                     "speed_kmh": float(speeds[i]), "error_kmh": float(speeds[i] - gt_speed[k])})
    return SpeedReport(ErrorStats.of(err_abs), ErrorStats.of(err_rel), m.recall, m.false_positives, m.n_matched,
                       m.n_matched_valid, prepared.n_input, len(prepared.tracks), prepared.n_errors,
                       prepared.identical_x, len(gt.cars), int(np.count_nonzero(m.valid)), err_abs, err_rel, cars)


# --------------------------------------------------------------------------- everything


@dataclass(frozen=True)
class Evaluation:
    calibration: CalibrationReport | None
    speed: SpeedReport | None

    def to_dict(self, per_item: bool = True) -> dict[str, Any]:
        """The ``trafficcal eval --json`` document."""
        out: dict[str, Any] = {}
        c = self.calibration
        if c is not None:
            out["calibration"] = {"focal": c.focal, "ratio_error": c.ratio_abs.to_dict(),
                                  "ratio_error_pct": c.ratio_rel_pct.to_dict()}
            if c.dist_all_abs_m is not None:
                out["distance"] = {
                    "all": {"abs_m": c.dist_all_abs_m.to_dict(), "rel_pct": c.dist_all_rel_pct.to_dict()},
                    "to_vp1": {"abs_m": c.dist_vp1_abs_m.to_dict(), "rel_pct": c.dist_vp1_rel_pct.to_dict()},
                }
            if per_item:
                out["calibration"]["segments"] = c.segments
        s = self.speed
        if s is not None:
            out["speed"] = {"abs_kmh": s.abs_kmh.to_dict(), "rel_pct": s.rel_pct.to_dict()}
            out["recall"] = s.recall
            out["false_positives"] = s.false_positives
            out["matched"] = s.matched
            out["matched_valid"] = s.matched_valid
            out["counts"] = {"cars": s.n_cars, "cars_after_prefilter": s.n_cars_after_prefilter,
                             "intersection_errors": s.n_intersection_errors,
                             "linregress_identical_x": s.linregress_identical_x,
                             "gt_cars": s.n_gt_cars, "gt_valid": s.n_gt_valid}
            if per_item:
                out["cars"] = s.cars
        return out


def evaluate(gt: GroundTruth, camera: Camera, results: Results | None = None, mode: SpeedMode = "median",
             prepared: PreparedTracks | None = None) -> Evaluation:
    """Full evaluation: calibration metrics always, speed metrics when system tracks are given (their border filter
    in the results' frame size when the file gives one, else BrnoCompSpeed's 1920x1080)."""
    calib = evaluate_calibration(gt, camera)
    speed = None
    if prepared is None and results is not None:
        prepared = prepare_tracks(results, gt, *(results.image_size or (WIDTH, HEIGHT)))
    if prepared is not None:
        speed = evaluate_speeds(gt, prepared, camera, mode)
    return Evaluation(calib, speed)


# --------------------------------------------------------------------------- plot


_PLAIN_TICKS = (0.1, 0.2, 0.5, 1, 2, 3, 5, 10, 20, 50, 100, 200, 500)


def plot_format(path) -> str:
    """The image format of ``path`` from its extension (png, svg, pdf, ...): InputError for a folder, for a name
    without an extension (matplotlib would write NAME.png instead) and for one it cannot write."""
    from pathlib import Path

    from matplotlib.backend_bases import FigureCanvasBase

    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: is a folder; give the plot's file name (e.g. {path / 'errors.png'})")
    kind = path.suffix.lower().lstrip(".")
    formats = FigureCanvasBase.get_supported_filetypes()
    if kind not in formats:
        raise InputError(f"{path}: " + (f"'.{kind}' is not an image format" if kind else "no extension") +
                         f" (one of: {', '.join('.' + k for k in sorted(formats))})")
    return kind


def plot_cumulative_errors(errors: dict[str, np.ndarray], path, unit: str = "km/h", what: str = "absolute speed",
                           threshold: float = 3.0) -> None:
    """PNG cumulative histogram of errors per system, like the official plot (paper's Figure 8).

    1000 bins from 0 to max + 1, log x axis from 0.1 with plain ticks (0.1, 0.2, 0.5, 1, 2, 3, 5, ...), grey dashed
    line at ``threshold`` in the legend.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FixedLocator, FuncFormatter, MultipleLocator, NullLocator

    arrays = {k: np.asarray(v, float) for k, v in errors.items() if len(v)}
    if not arrays:
        raise InputError("no matched cars: nothing to plot")
    max_err = max(float(np.max(v)) for v in arrays.values())
    bins = np.linspace(0, max_err + 1, 1000, endpoint=True)
    fig, ax = plt.subplots(figsize=(8, 5))
    try:
        for label, e in arrays.items():
            hist = np.cumsum(np.histogram(e, bins=bins)[0] / len(e))
            ax.semilogx(bins[:-1], hist, label=f"{label} (n={len(e)})", linewidth=2)
        ax.plot([threshold, threshold], [0, 1], ls="--", color="grey", linewidth=2, label=f"{threshold:g} {unit}")
        ax.xaxis.set_major_locator(FixedLocator([t for t in _PLAIN_TICKS if t <= 2 * max_err + 1]))
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.xaxis.set_minor_locator(NullLocator())  # plain numbers, no 3×10⁻¹ labels running into each other
        ax.yaxis.set_major_locator(MultipleLocator(0.2))
        ax.yaxis.set_minor_locator(MultipleLocator(0.1))
        ax.grid(which="major", axis="both", linewidth=0.5, linestyle="--", alpha=0.3)
        ax.grid(which="minor", axis="both", linewidth=0.5, linestyle="--", alpha=0.15)
        ax.set_ylim(0, 1)
        # the threshold line in view, and a margin after the largest error: the curve visibly reaches 1
        ax.set_xlim(0.1, max(1.15 * max_err, 1.2 * threshold))
        ax.set_xlabel(f"Error [{unit}]")
        ax.set_ylabel("portion of vehicles")
        ax.set_title(f"Cumulative histogram of {what} errors")
        ax.legend(loc="lower right")
        fig.tight_layout()
        fig.savefig(path, dpi=100, format=plot_format(path) if isinstance(path, (str, os.PathLike)) else "png")
    except OSError as exc:
        raise InputError(f"{path}: cannot write plot ({exc.strerror or exc})") from None
    finally:
        plt.close(fig)
