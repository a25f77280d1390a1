"""Vehicle speed from a track of road-plane reference points (paper §4.4).

v = median_i  λ‖P(i+τ) − P(i)‖ / (t(i+τ) − t(i)),  τ = 5 observations by default, with times from buffer
timestamps (never frame counts: frames can be dropped).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .geometry import Camera
from .uncertainty import sample_spread

DEFAULT_TAU = 5
MIN_POINTS = DEFAULT_TAU + 1


@dataclass(frozen=True)
class SpeedMeasurement:
    """A vehicle's measured speed, or why it has none."""

    speed_kmh: float | None
    n_pairs: int
    reason: str = ""

    @property
    def measured(self) -> bool:
        return self.speed_kmh is not None


def track_arrays(points_px, times_s, tau: int) -> tuple[np.ndarray, np.ndarray]:
    """One track's reference points as (N, 2) pixels and its times as (N,) seconds, both float; ValueError naming the
    problem for a ``tau`` under 1 (τ = 0 was a numpy broadcasting error, a negative τ a speed from the track's
    ends), points that are not pairs of pixels (an (N, 3) array was read as 1.5 N points) or a count of times that
    does not match."""
    if isinstance(tau, bool) or not isinstance(tau, (int, np.integer)) or tau < 1:
        raise ValueError(f"tau must be a whole number of observations from 1, got {tau!r}")
    px = np.asarray(points_px, dtype=np.float64)
    if px.size == 0:
        px = px.reshape(0, 2)
    if px.ndim != 2 or px.shape[1] != 2:
        raise ValueError(f"points must be an (N, 2) array of image pixels, got shape {px.shape}")
    times = np.asarray(times_s, dtype=np.float64).reshape(-1)
    if len(px) != len(times):
        raise ValueError(f"track has {len(px)} points but {len(times)} timestamps")
    return px, times


def pair_samples(camera: Camera, points_px: np.ndarray, times_s: np.ndarray, tau: int = DEFAULT_TAU,
                 checks: SpeedChecks | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Speeds in km/h between observations i and i+τ of one track (points (N, 2) pixels, times (N,) seconds) and
    each pair's mid-time (s); pairs without a finite speed are left out.  With ``checks`` the pairs of a vehicle
    that covers less than ``checks.min_pair_m`` in τ observations are taken further apart (:func:`pair_step`)."""
    return _pair_samples(camera, *track_arrays(points_px, times_s, tau), tau, checks)


def _pair_samples(camera: Camera, points_px: np.ndarray, times_s: np.ndarray, tau: int,
                  checks: SpeedChecks | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`pair_samples` of arrays :func:`track_arrays` checked already (the callers that check them first)."""
    if len(points_px) <= tau:
        return np.empty(0), np.empty(0)
    metres = camera.distance(points_px[tau:], points_px[:-tau])
    if checks is not None and (wider := pair_step(metres, len(points_px), tau, checks)) != tau:
        tau = wider
        metres = camera.distance(points_px[tau:], points_px[:-tau])
    dt = np.abs(times_s[tau:] - times_s[:-tau])
    with np.errstate(divide="ignore", invalid="ignore"):
        v = metres / dt * 3.6
    ok = np.isfinite(v)
    return v[ok], ((times_s[tau:] + times_s[:-tau]) / 2)[ok]


def pairwise_speeds(camera: Camera, points_px: np.ndarray, times_s: np.ndarray, tau: int = DEFAULT_TAU) -> np.ndarray:
    """Speeds in km/h between observations i and i+τ of one track (points (N, 2) pixels, times (N,) seconds)."""
    return pair_samples(camera, points_px, times_s, tau)[0]


def track_speed(camera: Camera | None, points_px: np.ndarray, times_s: np.ndarray,
                tau: int = DEFAULT_TAU) -> SpeedMeasurement:
    """Median speed of one track, with a reason when it cannot be measured."""
    points_px, times_s = track_arrays(points_px, times_s, tau)
    if camera is None or camera.scale is None:
        return SpeedMeasurement(None, 0, "no calibration with scale")
    if len(points_px) <= tau:
        return SpeedMeasurement(None, 0, f"track too short ({len(points_px)} points, needs more than {tau})")
    v = _pair_samples(camera, points_px, times_s, tau)[0]
    if v.size == 0:
        return SpeedMeasurement(None, 0, "no usable point pairs (points above the horizon or equal timestamps)")
    return SpeedMeasurement(float(np.median(v)), int(v.size))


# --------------------------------------------------------------------------- robust per-vehicle speed (the product)

AGREEMENT = 0.1  # a τ-pair speed "agrees" when within 10 % of the vehicle's own motion at that time
MAX_ACCELERATION = 6.0  # m/s²: a change of speed beyond this is not a road vehicle's smooth motion (firm braking ~6)


@dataclass(frozen=True)
class SpeedChecks:
    """What a vehicle's reference points must satisfy before its speed is published (else: unmeasured + reason).

    * ``jump_m`` / ``jump_px``: a reference point farther than max(``jump_m``, ``jump_px`` pixels at that point)
      plus 10 % of the distance travelled since the last kept point from where the vehicle's median velocity
      predicts it does not continue the vehicle: an ID switch, a merge with a neighbour or a degenerate 3D box.
      The points are chained in time order; the chain with the most points is the vehicle, the rest is dropped.
    * ``coarse_m_per_px`` (off by default): points where one pixel spans more than this on the road (far away,
      where the reference point is least reliable) are left out when enough finer ones remain for ``min_pairs``
      τ-pairs.  Measured on the 12 replays and the demo scene (manual calibration): 0.25 m/px moved the mean
      error 0.946 -> 0.941 km/h (demo 0.57 -> 0.54) but made exact simulated tracks with rectangle hulls worse
      (max 0.07 -> 0.31 km/h): no clear gain, so it is not the default.
    * ``min_distance_m``: the kept reference points must span at least this distance.
    * ``min_pair_m``: a τ-pair spans at least this much road — for a vehicle slower than that in τ observations
      the pairs are taken further apart.  A reference point's own noise (0.1–0.3 m) is then a few per cent of a
      sample instead of tens of per cent, and it no longer biases the median up (a noisy pair's length grows in
      quadrature: at 12 km/h and 25 fps, τ = 5 spans 0.67 m and 0.2 m of noise per coordinate adds ~8 % to a
      pair's expected length; the simulated vehicle of tests/test_speed.py comes out 14 % fast).
      Vehicles faster than ``min_pair_m`` per τ observations (on the replays' motorways nearly all) are measured
      with the paper's τ as before.
    * ``min_agreement``: share of the τ-pair speeds within 10 % of the vehicle's own motion at their time: of one
      constant speed (their median) or of a constant change of speed (their robust trend, :func:`speed_trend`),
      whichever more samples follow — a vehicle braking for a junction agrees with itself, a reference point that
      wanders along the vehicle or between vehicles does not.
    """

    jump_m: float = 2.5
    jump_px: float = 4.0
    coarse_m_per_px: float | None = None
    min_pairs: int = 5
    min_distance_m: float = 3.0
    min_pair_m: float = 4.0
    min_agreement: float = 0.6


@dataclass(frozen=True)
class VehicleSpeed:
    """:func:`vehicle_speed`'s result: the speed (or None and why), and which points it was measured from."""

    speed_kmh: float | None
    n_pairs: int
    reason: str
    kept: np.ndarray  # (N,) bool: the reference points the speed was measured from (the vehicle's own)
    agreement: float = 0.0  # share of τ-pair speeds within 10 % of the vehicle's own motion (median or trend)
    spread_kmh: float = 0.0  # 1σ of the median from its samples' spread (uncertainty.sample_spread)

    @property
    def measured(self) -> bool:
        return self.speed_kmh is not None


def metres_per_pixel(camera: Camera, points_px: np.ndarray) -> np.ndarray:
    """(N,) road distance spanned by one pixel at each image point (the larger of the two image directions)."""
    p = np.asarray(points_px, np.float64).reshape(-1, 2)
    w = camera.to_world(p)[:, :2]
    dx = np.linalg.norm(camera.to_world(p + [1.0, 0.0])[:, :2] - w, axis=1)
    dy = np.linalg.norm(camera.to_world(p + [0.0, 1.0])[:, :2] - w, axis=1)
    return np.maximum(dx, dy)


def speed_trend(mid: np.ndarray, speeds: np.ndarray, at: np.ndarray, max_samples: int = 64) -> np.ndarray:
    """A vehicle's speed at times ``at`` as its τ-pair speeds (km/h, at their pairs' mid-times) say it changes: the
    samples' robust linear trend over time (Theil–Sen: the median of the pairwise slopes, through the medians; on
    at most ``max_samples`` samples spread over the track, so a long track costs no more), i.e. a constant change
    of speed.  A trend steeper than :data:`MAX_ACCELERATION`, or fewer than four samples, gives the median (one
    constant speed)."""
    mid = np.asarray(mid, np.float64).reshape(-1)
    speeds = np.asarray(speeds, np.float64).reshape(-1)
    at = np.asarray(at, np.float64)
    if len(speeds) == 0:
        return np.full(at.shape, np.nan)
    if len(speeds) >= 4 and np.ptp(mid) > 0:
        pick = np.unique(np.linspace(0, len(speeds) - 1, min(len(speeds), max_samples)).round().astype(int))
        t, v = mid[pick], speeds[pick]
        i, j = np.triu_indices(len(t), 1)
        dt = t[j] - t[i]
        ok = dt > 0
        # scipy.stats.theilslopes computes the same slope and intercept, plus confidence limits that cost ten
        # times as much; this runs for every vehicle in view on every frame (the live speed)
        slope = float(np.median((v[j] - v[i])[ok] / dt[ok]))
        if abs(slope) / 3.6 <= MAX_ACCELERATION:
            return float(np.median(v) - slope * np.median(t)) + slope * at
    return np.full(at.shape, float(np.median(speeds)))


def _median_velocity(world: np.ndarray, times: np.ndarray, tau: int) -> np.ndarray:
    """Median (component-wise) road velocity over τ-pairs, m/s (zero when there are none)."""
    k = min(tau, len(world) - 1)
    if k < 1:
        return np.zeros(2)
    dt = times[k:] - times[:-k]
    ok = dt > 0
    if not ok.any():
        return np.zeros(2)
    return np.median((world[k:] - world[:-k])[ok] / dt[ok, None], axis=0)


def consistent_chain(world: np.ndarray, times: np.ndarray, tolerance_m: np.ndarray, tau: int = DEFAULT_TAU
                     ) -> np.ndarray:
    """(N,) bool: the longest chain of points (time order) that each continue the previous kept point of their
    chain at the track's median velocity within ``tolerance_m`` (N,) plus 10 % of the distance travelled.

    One pass, each point joins the chain that predicts it best or starts a new one; isolated outliers end up in
    chains of their own, and after an ID switch the other vehicle's points form a second chain.
    """
    n = len(world)
    if n == 0:
        return np.zeros(0, bool)
    v = _median_velocity(world, times, tau)
    speed = float(np.linalg.norm(v))
    step = np.linalg.norm(np.diff(world, axis=0) - v * np.diff(times)[:, None], axis=1)
    if np.all(step <= tolerance_m[1:] + 0.1 * speed * np.abs(np.diff(times))):
        return np.ones(n, bool)  # every point continues the previous one: one chain (the usual case, vectorised)
    chains: list[list[int]] = []
    for i in range(n):
        best, best_d = None, np.inf
        for c, chain in enumerate(chains):
            j = chain[-1]
            dt = times[i] - times[j]
            d = float(np.linalg.norm(world[i] - world[j] - v * dt))
            if d <= tolerance_m[i] + 0.1 * speed * abs(dt) and d < best_d:
                best, best_d = c, d
        if best is None:
            chains.append([i])
        else:
            chains[best].append(i)
    keep = np.zeros(n, bool)
    keep[max(chains, key=len)] = True
    return keep


def pair_step(metres: np.ndarray, n: int, tau: int, checks: SpeedChecks) -> int:
    """How many observations apart the speed pairs of a track of ``n`` points are, given the road distances (m) of
    its τ-pairs: τ, or more when τ observations span less road than ``checks.min_pair_m`` (a slow vehicle) — but
    never more than half the track (as many pairs as the spacing, so a short track or live window keeps its
    samples) nor so far that fewer than ``checks.min_pairs`` remain."""
    finite = metres[np.isfinite(metres)]
    step = float(np.median(finite)) / tau if len(finite) else 0.0
    if step <= 0 or step * tau >= checks.min_pair_m:
        return tau
    return int(max(tau, min(np.ceil(checks.min_pair_m / step), (n - 1) // 2, n - checks.min_pairs)))


def vehicle_speed(camera: Camera | None, points_px: np.ndarray, times_s: np.ndarray, tau: int = DEFAULT_TAU,
                  checks: SpeedChecks = SpeedChecks()) -> VehicleSpeed:
    """A vehicle's speed as the product publishes it: the paper's median of τ-pair speeds over the reference
    points that are the vehicle's own (:func:`consistent_chain`), preferring the near road where a pixel is
    short, and only when the samples agree and span enough road (:class:`SpeedChecks`); else None and why."""
    px, times = track_arrays(points_px, times_s, tau)
    none = np.zeros(len(px), bool)
    if camera is None or camera.scale is None:
        return VehicleSpeed(None, 0, "no calibration with scale", none)
    if len(px) <= tau:
        return VehicleSpeed(None, 0, f"track too short ({len(px)} points, needs more than {tau})", none)
    world = camera.to_world(px)[:, :2]
    mpp = metres_per_pixel(camera, px)
    finite = np.all(np.isfinite(world), axis=1) & np.isfinite(mpp)
    idx = np.flatnonzero(finite)
    keep = np.zeros(len(px), bool)
    keep[idx[consistent_chain(world[idx], times[idx], np.maximum(checks.jump_m, checks.jump_px * mpp[idx]),
                              tau)]] = True
    fine = keep & (mpp <= (np.inf if checks.coarse_m_per_px is None else checks.coarse_m_per_px))
    if fine.sum() >= checks.min_pairs + tau:  # enough near points: leave out the far ones (coarse pixels)
        keep = fine
    k = np.flatnonzero(keep)
    if len(k) <= tau:
        return VehicleSpeed(None, 0, f"the reference points do not follow one vehicle (longest consistent run "
                            f"{len(k)} of {len(px)} points: ID switch or merged vehicles)", keep)
    span = float(np.linalg.norm(world[k[-1]] - world[k[0]]))
    if span < checks.min_distance_m:
        return VehicleSpeed(None, 0, f"track too short on the road ({span:.1f} m, needs "
                            f"{checks.min_distance_m:g} m)", keep)
    v, mid = _pair_samples(camera, px[k], times[k], tau, checks)
    if v.size == 0:
        return VehicleSpeed(None, 0, "no usable point pairs (equal timestamps)", keep)
    med = float(np.median(v))
    # the samples agree with one constant speed (their median) or with a constant change of speed (their trend)
    agree = float(np.mean(np.abs(v - med) <= AGREEMENT * med)) if med > 0 else 0.0
    if med > 0 and agree < checks.min_agreement:
        trend = speed_trend(mid, v, mid)
        agree = max(agree, float(np.mean(np.abs(v - trend) <= AGREEMENT * np.abs(trend))))
    if agree < checks.min_agreement:
        return VehicleSpeed(None, int(v.size), f"speed samples disagree (only {100 * agree:.0f} % within "
                            f"{100 * AGREEMENT:.0f} % of the vehicle's own motion, median {med:.1f} km/h, needs "
                            f"{100 * checks.min_agreement:.0f} %)", keep, agree)
    # the pairs lie ``step`` observations apart (τ, or more for a slow vehicle): about (N - 1) / step independent ones
    step = max(1, len(k) - int(v.size))
    return VehicleSpeed(med, int(v.size), "", keep, agree, sample_spread(v, (len(k) - 1) / step))
