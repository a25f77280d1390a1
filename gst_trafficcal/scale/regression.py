"""Scale-correcting linear regression λ_reg = α λ* + β (paper §4.3), fitted on training scenes (by default with
β = 0: see :func:`fit_regression`).

The regression absorbs what BBScale gets systematically wrong (meshes that are not exactly the real cars, the
3D-box base offset).  It is fitted by least squares on pairs (λ*, true λ) — synthetic scenes with their exact
scale, BrnoCompSpeed replays with ManualScale — and stored as a small JSON file::

    {"format": "gst-trafficcal-scale-regression", "version": 1, "alpha": 1.01, "beta": -0.02,
     "n_scenes": 12, "scenes": [{"name": "...", "raw": 7.1, "true": 7.0}, ...]}
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import InputError
from ..fileio import atomic_write_text

FORMAT = "gst-trafficcal-scale-regression"
VERSION = 1


@dataclass(frozen=True)
class ScaleRegression:
    """λ_reg = alpha · λ* + beta; ``scenes`` records what it was fitted on (name, raw, true)."""

    alpha: float = 1.0
    beta: float = 0.0
    scenes: tuple = field(default=(), compare=False)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.alpha) and math.isfinite(self.beta)) or self.alpha <= 0:
            raise InputError(f"scale regression needs a finite alpha > 0 and a finite beta, got "
                             f"alpha={self.alpha!r}, beta={self.beta!r}")

    def apply(self, raw):
        """λ_reg for λ* (scalar or array)."""
        return self.alpha * np.asarray(raw, np.float64) + self.beta if not np.isscalar(raw) else \
            float(self.alpha * raw + self.beta)

    def to_dict(self) -> dict:
        return {"format": FORMAT, "version": VERSION, "alpha": self.alpha, "beta": self.beta,
                "n_scenes": len(self.scenes), "scenes": [dict(s) for s in self.scenes]}


FORMS = ("ratio", "affine")


def fit_regression(raw: Sequence[float], true: Sequence[float], names: Sequence[str] | None = None,
                   min_scenes: int = 2, form: str = "ratio") -> ScaleRegression:
    """α, β from pairs (λ*, true λ).

    ``form="ratio"`` (default): β = 0, α = mean(true / raw) — one parameter.  ``"affine"``: least-squares α, β,
    the paper's form; with a single scene (or scenes of equal λ*) it falls back to the ratio.  Why the ratio is
    the default: the training scenes' λ span a narrow range (BrnoCompSpeed 7.7–11 m) and BBScale's error is a
    relative one, so the slope and offset of an affine fit are poorly determined.  Left out in turn
    (``--regression-form affine|ratio`` of benchmarks/scale.py and end_to_end.py), the ratio did better on every
    set measured: scale error median affine → ratio, replays MOG2 2.21 → 1.96 %, vehicleseg 2.28 → 2.10 %,
    synth MOG2 3.22 → 2.03 %; fully automatic speeds on the replays, mean, MOG2 2.85 → 2.63 km/h, vehicleseg
    6.13 → 3.64 km/h (docs/bbscale_streaming.md).  InputError for no usable pairs or an unknown form."""
    if form not in FORMS:
        raise InputError(f"scale regression form must be one of {', '.join(FORMS)}, got {form!r}")
    r = np.asarray(raw, np.float64).ravel()
    y = np.asarray(true, np.float64).ravel()
    if r.shape != y.shape:
        raise InputError(f"scale regression: {len(r)} estimated scales but {len(y)} true scales")
    names = list(names) if names is not None else [f"scene{i}" for i in range(len(r))]
    ok = np.isfinite(r) & np.isfinite(y) & (r > 0) & (y > 0)
    if not ok.any():
        raise InputError("scale regression: no training scene with both an estimated and a true scale")
    scenes = tuple({"name": str(n), "raw": float(a), "true": float(b)}
                   for n, a, b, k in zip(names, r, y, ok) if k)
    r, y = r[ok], y[ok]
    if form == "ratio" or len(r) < min_scenes or np.ptp(r) < 1e-9 * max(1.0, r.max()):
        return ScaleRegression(float(np.mean(y / r)), 0.0, scenes)
    A = np.column_stack([r, np.ones_like(r)])
    (alpha, beta), *_ = np.linalg.lstsq(A, y, rcond=None)
    if alpha <= 0:  # a nonsensical fit (too few or contradictory scenes): fall back to the ratio
        return ScaleRegression(float(np.mean(y / r)), 0.0, scenes)
    return ScaleRegression(float(alpha), float(beta), scenes)


def leave_one_out(raw: Sequence[float | None], true: Sequence[float], names: Sequence[str] | None = None,
                  groups: Sequence[object] | None = None, train: Sequence[bool] | None = None, form: str = "ratio",
                  min_others: int = 1) -> list[ScaleRegression | None]:
    """Per scene i, the regression fitted on the *other* scenes of its group (``groups``, e.g. synth vs replays;
    one group when None) that may train (``train``, e.g. only those where the stage converged; all with a λ*
    when None) — cross-validation of :func:`fit_regression`.  None where fewer than ``min_others`` scenes are
    left to train on."""
    n = len(raw)
    groups = list(groups) if groups is not None else [0] * n
    train = list(train) if train is not None else [True] * n
    names = list(names) if names is not None else [f"scene{i}" for i in range(n)]
    out: list[ScaleRegression | None] = []
    for i in range(n):
        js = [j for j in range(n) if j != i and groups[j] == groups[i] and train[j] and raw[j] is not None]
        if len(js) < min_others:
            out.append(None)
            continue
        try:
            out.append(fit_regression([raw[j] for j in js], [true[j] for j in js], [names[j] for j in js],
                                      form=form))
        except InputError:
            out.append(None)
    return out


def save_regression(reg: ScaleRegression, path: str | Path) -> None:
    atomic_write_text(Path(path), json.dumps(reg.to_dict(), indent=2) + "\n", "scale regression file")


def load_regression(path: str | Path) -> ScaleRegression:
    """Read a regression file; InputError naming the file when it is missing, not JSON or not ours."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"scale regression file {p} not found")
    try:
        d = json.loads(p.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"scale regression file {p} is not valid JSON ({exc})") from None
    if not isinstance(d, dict) or d.get("format") != FORMAT:
        raise InputError(f"{p}: not a gst-trafficcal scale regression file (write one with trafficcal fit-scale)")
    if d.get("version") != VERSION:
        raise InputError(f"{p}: unsupported scale regression version {d.get('version')!r} (this is {VERSION})")
    try:
        alpha, beta = float(d["alpha"]), float(d["beta"])
    except (KeyError, TypeError, ValueError):
        raise InputError(f"{p}: fields 'alpha' and 'beta' must be numbers") from None
    try:
        return ScaleRegression(alpha, beta, tuple(d.get("scenes") or ()))
    except InputError as exc:
        raise InputError(f"{p}: {exc}") from None
