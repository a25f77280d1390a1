"""Scene scale λ* from many aligned vehicles: kernel density over the kept λ_ij weighted by IoU (paper eq. 9).

The density is estimated over log λ: IoU falls off symmetrically in log scale (a model box k times too large
or too small overlaps equally), so a kernel in log λ has its mode at the best match, whereas a kernel in λ would
lean towards larger scales.  The argmax is taken on a discretised grid (default 0.05 % steps).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Iterable, Mapping

import numpy as np

from ..errors import GeometryError, TrafficcalError
from ..geometry import Camera
from .alignment import AlignModel, Alignment, Observation, align

DEFAULT_IOU_THRESHOLD = 0.85


def kde_mode(values: np.ndarray, weights: np.ndarray, bw_method=None, step: float = 5e-4) -> float:
    """argmax over λ of a weighted Gaussian KDE (scipy.stats.gaussian_kde) of log λ, evaluated on a grid of
    relative spacing ``step``."""
    from scipy.stats import gaussian_kde

    v = np.log(np.asarray(values, np.float64))
    w = np.asarray(weights, np.float64)
    ok = np.isfinite(v) & np.isfinite(w) & (w > 0)
    v, w = v[ok], w[ok]
    if len(v) == 0:
        raise ValueError("no values for the kernel density")
    if len(v) == 1 or np.ptp(v) < 1e-12:
        return float(np.exp(np.average(v, weights=w)))
    kde = gaussian_kde(v, bw_method=bw_method, weights=w)
    bw = float(np.sqrt(kde.covariance[0, 0]))
    grid = np.arange(v.min() - 3 * bw, v.max() + 3 * bw + step, step)
    return float(np.exp(grid[int(np.argmax(kde(grid)))]))


class LogDensity:
    """The weighted Gaussian density of log λ that :func:`kde_mode` maximises, kept as it grows: every value added
    goes into a bin of ``step`` (a hundredth of the 5 % kernel), so its memory and the cost of its mode stay the same
    after a week of vehicles as after ten, where the KDE over every value kept grew with each (a busy camera's
    scale stage spent a quarter of its CPU time there within minutes).  ``mode(bandwidth)`` is the argmax of the
    binned values smoothed by a kernel of ``bandwidth`` in log λ, widened as scipy's weighted KDE widens it (its
    unbiased weighted variance); it agrees with :func:`kde_mode` with that bandwidth to within a step."""

    def __init__(self, step: float = 5e-4) -> None:
        self.step = float(step)
        self._bins: dict[int, float] = {}
        self.count = 0  # values added
        self._w1 = 0.0  # sum of weights
        self._w2 = 0.0  # sum of squared weights
        self._wv = 0.0  # sum of weight * log value
        self._lo, self._hi = np.inf, -np.inf  # range of log values

    def __len__(self) -> int:
        return self.count

    def add(self, values: np.ndarray, weights: np.ndarray) -> None:
        """Add positive ``values`` (λ) with positive ``weights``; the others are left out."""
        with np.errstate(invalid="ignore", divide="ignore"):  # zero or negative λ: left out below, not a warning
            v = np.log(np.asarray(values, np.float64))
        w = np.asarray(weights, np.float64)
        ok = np.isfinite(v) & np.isfinite(w) & (w > 0)
        v, w = v[ok], w[ok]
        if not len(v):
            return
        idx, inverse = np.unique(np.round(v / self.step).astype(np.int64), return_inverse=True)
        sums = np.bincount(inverse, weights=w)
        for i, x in zip(idx.tolist(), sums.tolist()):
            self._bins[i] = self._bins.get(i, 0.0) + x
        self.count += len(v)
        self._w1 += float(w.sum())
        self._w2 += float(np.sum(w * w))
        self._wv += float(np.sum(w * v))
        self._lo, self._hi = min(self._lo, float(v.min())), max(self._hi, float(v.max()))

    def mode(self, bandwidth: float) -> float:
        """λ at the density's maximum for a kernel of ``bandwidth`` (log λ); ValueError when empty."""
        if not self.count:
            raise ValueError("no values for the kernel density")
        if self.count == 1 or self._hi - self._lo < 1e-12:
            return float(np.exp(self._wv / self._w1))
        share = self._w2 / self._w1 ** 2  # scipy's weighted KDE divides the variance by 1 - sum of w^2 (w summing to 1)
        bw = float(bandwidth) / np.sqrt(max(1.0 - share, 1e-12))
        reach = int(np.ceil(3 * bw / self.step)) + 1
        first = min(self._bins)
        hist = np.zeros(max(self._bins) - first + 1)
        idx = np.fromiter(self._bins.keys(), np.int64, len(self._bins))
        hist[idx - first] = np.fromiter(self._bins.values(), np.float64, len(self._bins))
        kernel = np.exp(-0.5 * (np.arange(-reach, reach + 1) * self.step / bw) ** 2)
        density = np.convolve(hist, kernel)  # index j: bin first - reach + j
        return float(np.exp((first - reach + int(np.argmax(density))) * self.step))


@dataclass
class ScaleEstimate:
    """λ* (None when it cannot be estimated, ``status`` says why), the matches it rests on and per-observation
    chosen model names."""

    scale: float | None
    status: str
    lambdas: np.ndarray = field(repr=False)
    weights: np.ndarray = field(repr=False)
    n_observations: int = 0
    n_matched: int = 0
    n_tracks: int = 0
    models_used: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.scale is not None


def with_track_mean_types(observations: Iterable[Observation]) -> list[Observation]:
    """Replace each observation's classifier probabilities by the mean over its track (the paper classifies
    single detections and averages over the track); observations without probabilities count as all-zero."""
    obs = list(observations)
    sums: dict[int, dict[str, float]] = {}
    counts: dict[int, int] = {}
    for o in obs:
        counts[o.track_id] = counts.get(o.track_id, 0) + 1
        acc = sums.setdefault(o.track_id, {})
        for name, p in (o.type_probs or {}).items():
            acc[name] = acc.get(name, 0.0) + float(p)
    return [replace(o, type_probs={k: v / counts[o.track_id] for k, v in sums[o.track_id].items()} or None)
            for o in obs]


def _candidates(obs: Observation, models: Mapping[str, AlignModel]) -> list[AlignModel]:
    if obs.type_probs:
        return [models[n] for n, p in obs.type_probs.items() if n in models and p > 0]
    return list(models.values())


def estimate_scale(cam: Camera, observations: Iterable[Observation], models: Mapping[str, AlignModel] | AlignModel,
                   iou_threshold: float = DEFAULT_IOU_THRESHOLD, min_vehicles: int = 1, renderer=None,
                   bw_method=None, refine_base: bool = True) -> ScaleEstimate:
    """λ* from observations of vehicles of known types.

    With ``type_probs`` on an observation (a classifier's track-mean probabilities) the types it names are
    aligned and their matches weighted by IoU x probability; without, every model is tried and the one with
    the best peak IoU is taken for that observation (the match quality decides).  Matches with IoU above
    ``iou_threshold`` enter the density.  ``refine_base`` (our addition to the paper, on by default) corrects
    each b for the 3D-box construction it came from (:func:`.alignment.corrected_base`; b must be the base
    centre of the :mod:`~gst_trafficcal.tracking.box3d` box of the vehicle's hull); False is the paper's
    method.  Never raises for data that give no scale: the status says why.
    """
    if isinstance(models, AlignModel):
        models = {models.name: models}
    lams, wts, tracks, used = [], [], set(), {}
    n_obs = n_matched = 0
    for obs in observations:
        n_obs += 1
        best: tuple[float, Alignment, float] | None = None
        for model in _candidates(obs, models):
            try:
                a = align(cam, model, obs, renderer=renderer, refine_base=refine_base)
            except (GeometryError, TrafficcalError):
                continue
            p = float(obs.type_probs.get(model.name, 0.0)) if obs.type_probs else 1.0
            if obs.type_probs:
                keep = a.kept(iou_threshold)
                if keep.any():
                    lams.append(a.lambda_ij[keep])
                    wts.append(a.iou[keep] * p)
            if best is None or a.iou.max() > best[0]:
                best = (float(a.iou.max()), a, p)
        if best is None or not best[0] > iou_threshold:
            continue
        n_matched += 1
        tracks.add(obs.track_id)
        used[best[1].model] = used.get(best[1].model, 0) + 1
        if not obs.type_probs:
            a = best[1]
            keep = a.kept(iou_threshold)
            lams.append(a.lambda_ij[keep])
            wts.append(a.iou[keep])
    lam = np.concatenate(lams) if lams else np.zeros(0)
    w = np.concatenate(wts) if wts else np.zeros(0)
    base = dict(lambdas=lam, weights=w, n_observations=n_obs, n_matched=n_matched, n_tracks=len(tracks),
                models_used=used)
    if n_obs == 0:
        return ScaleEstimate(None, "no vehicle observations", **base)
    if n_matched == 0:
        return ScaleEstimate(None, f"no vehicle matched a catalogue model with IoU > {iou_threshold:g} "
                                   f"({n_obs} observations)", **base)
    if len(tracks) < min_vehicles:
        return ScaleEstimate(None, f"too few matched vehicles: {len(tracks)} < {min_vehicles}", **base)
    return ScaleEstimate(kde_mode(lam, w, bw_method=bw_method), "ok", **base)
