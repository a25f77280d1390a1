"""Speed statistics as traffic engineers read them: V85 and vehicles over a speed limit.

V85, the speed 85 % of the vehicles do not exceed, is what speed limits are set and checked against; the share
over the posted limit is what enforcement asks for.  Used by ``report.html``, ``trafficcal run`` and the
overlay's counters.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np

from .errors import InputError


@dataclass(frozen=True)
class SpeedStats:
    """Summary of measured speeds (km/h); the figures are None without speeds, the limit ones without a limit."""

    n: int
    mean: float | None = None
    median: float | None = None
    v85: float | None = None  # 85th percentile
    p95: float | None = None
    max: float | None = None
    limit_kmh: float | None = None
    over_limit: int | None = None  # vehicles strictly faster than the limit

    @property
    def share_over(self) -> float | None:
        """Fraction of the vehicles over the limit (None without a limit or without vehicles)."""
        if self.over_limit is None or not self.n:
            return None
        return self.over_limit / self.n


def check_limit(limit_kmh: float | None) -> float | None:
    """The limit as a float; None for none (None or 0); InputError for a negative or non-finite one."""
    if limit_kmh is None or limit_kmh == 0:
        return None
    limit = float(limit_kmh)
    if not np.isfinite(limit) or limit < 0:
        raise InputError(f"speed limit must be a positive number of km/h (0: none), got {limit_kmh!r}")
    return limit


def is_over_limit(speed_kmh: float | None, limit_kmh: float | None) -> bool:
    """True when a measured speed exceeds a set limit (a limit of None or 0 means none)."""
    return bool(limit_kmh) and speed_kmh is not None and np.isfinite(speed_kmh) and speed_kmh > limit_kmh


def speed_stats(speeds_kmh: Iterable[float], limit_kmh: float | None = None) -> SpeedStats:
    """Mean, median, V85, 95th percentile and maximum of the finite speeds, and how many exceed ``limit_kmh``."""
    v = np.asarray([s for s in speeds_kmh if s is not None], np.float64)
    v = v[np.isfinite(v)]
    limit = check_limit(limit_kmh)
    over = int(np.count_nonzero(v > limit)) if limit is not None else None
    if not len(v):
        return SpeedStats(0, limit_kmh=limit, over_limit=over)
    p50, p85, p95 = np.percentile(v, [50, 85, 95])
    return SpeedStats(len(v), float(v.mean()), float(p50), float(p85), float(p95), float(v.max()), limit, over)
