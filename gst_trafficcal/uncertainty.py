"""How sure a vehicle's speed is: the half-width U of an interval (speed ± U) meant to hold the true speed for about
95 % of vehicles.

Two independent parts, added in quadrature (1σ each, then times :data:`Z95`):

* the track's own: the robust spread of the vehicle's τ-pair speeds (1.4826 × their median absolute deviation)
  over √(the number of independent pairs) — overlapping pairs share their points — times 1.2533 (a median is that
  much less efficient than a mean), times ``track_factor`` (fitted: the samples' neighbouring errors partly cancel
  in the median), never less than a floor of ``track_floor_pct`` % of the speed (the reference point's own bias on
  a vehicle, which its samples cannot show);
* the calibration's, relative to the speed: a manual calibration (road measurements: ``manual_pct`` %), or for an
  automatic one (vpdetect) a scale term (``scale_pct`` %) and a vanishing-point term ``vp_pct_per_root`` × √(the
  view's sensitivity, % of speed per 0.1° of VP2: :mod:`gst_trafficcal.vanishing.conditioning`) — the VPs stretch
  the road more on a view along the road, but less than in proportion (the edges towards a far VP2 are found more
  precisely in angle).  A calibration whose conditioning cannot be computed is taken as a poorly conditioned one
  (``unknown_speed_pct``, the 2 % at which vpdetect warns).

The constants were fitted on the 21 calibrated benchmark scenes (nine synth, twelve replays; fitted on either set
alone, the other set's coverage was 0.903 and 0.994); see
docs/outputs.md "Speed uncertainty" and ``benchmarks/speed_uncertainty.py``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .calibration import Calibration

Z95 = 1.96  # a normal distribution holds 95 % within ±1.96 σ
MAD_TO_SIGMA = 1.4826
MEDIAN_EFFICIENCY = 1.2533  # σ of a median over σ of a mean of the same normal samples, √(π/2)


@dataclass(frozen=True)
class UncertaintyModel:
    """The constants of :func:`speed_uncertainty` (1σ values in % of the speed)."""

    track_factor: float = 0.70  # fitted: the spread over √(n / step) overstates the median's own error
    track_floor_pct: float = 0.5  # assumed: a reference point's bias on one vehicle, which its samples cannot show
    scale_pct: float = 1.55  # fitted (synth and replays)
    vp_pct_per_root: float = 1.35  # fitted (synth and replays)
    manual_pct: float = 1.0  # ManualCalib's distances towards VP1: 0.83 % mean (docs/results/manual_calibration.md)
    unknown_speed_pct: float = 2.0
    z: float = Z95


DEFAULT_MODEL = UncertaintyModel()


def sample_spread(samples_kmh, n_independent: float) -> float:
    """1σ of a median speed (km/h) from its τ-pair speed samples: their robust spread over √(independent pairs);
    0 for fewer than two samples."""
    v = np.asarray(samples_kmh, np.float64).reshape(-1)
    v = v[np.isfinite(v)]
    if len(v) < 2:
        return 0.0
    mad = float(np.median(np.abs(v - np.median(v))))
    return MEDIAN_EFFICIENCY * MAD_TO_SIGMA * mad / math.sqrt(max(1.0, float(n_independent)))


def is_manual(cal: Calibration) -> bool:
    """Whether a calibration comes from measurements (road markings, a scene's known camera) rather than from the
    automatic calibrator: everything vpdetect did not find."""
    return "vpdetect" not in cal.source


def calibration_pct(cal: Calibration | None, speed_pct: float | None = None,
                    model: UncertaintyModel = DEFAULT_MODEL) -> float | None:
    """1σ of the calibration's relative speed error, in %; None without a calibration with a scale.  ``speed_pct``:
    the view's sensitivity when known already (else computed; :data:`UncertaintyModel.unknown_speed_pct` when it
    cannot be)."""
    if cal is None or cal.camera is None or cal.camera.scale is None:
        return None
    if is_manual(cal):
        return model.manual_pct
    if speed_pct is None:
        speed_pct = view_sensitivity(cal)
    if speed_pct is None or not math.isfinite(speed_pct):
        speed_pct = model.unknown_speed_pct
    return math.hypot(model.scale_pct, model.vp_pct_per_root * math.sqrt(max(0.0, speed_pct)))


def view_sensitivity(cal: Calibration) -> float | None:
    """The view's sensitivity (% of speed per 0.1° of VP2), None when it cannot be computed."""
    try:
        pct = cal.conditioning().speed_pct
    except Exception:  # noqa: BLE001 - any geometry the conditioning cannot handle: the model's assumption
        return None
    return None if pct is None else float(pct)


def speed_uncertainty(speed_kmh: float, spread_kmh: float, calibration_pct_: float,
                      model: UncertaintyModel = DEFAULT_MODEL) -> float:
    """Half-width (km/h) of the ~95 % interval around ``speed_kmh``: the track's part (``spread_kmh``, 1σ from
    :func:`sample_spread`, at least the floor) and the calibration's (``calibration_pct_``, 1σ in %) in
    quadrature."""
    v = abs(float(speed_kmh))
    track = max(model.track_factor * float(spread_kmh), model.track_floor_pct / 100 * v)
    return model.z * math.hypot(track, calibration_pct_ / 100 * v)
