"""Speed statistics for traffic engineers: V85 and the vehicles over a speed limit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gst_trafficcal.errors import InputError
from gst_trafficcal.traffic_stats import check_limit, is_over_limit, speed_stats


def test_v85_and_the_other_figures_of_known_speeds() -> None:
    speeds = np.arange(1.0, 101.0)  # 1 .. 100 km/h
    s = speed_stats(speeds)
    assert s.n == 100 and s.mean == pytest.approx(50.5) and s.median == pytest.approx(50.5)
    assert s.v85 == pytest.approx(85.15) and s.p95 == pytest.approx(95.05) and s.max == 100.0
    assert s.limit_kmh is None and s.over_limit is None and s.share_over is None


def test_over_the_limit_is_strictly_faster() -> None:
    s = speed_stats([49.9, 50.0, 50.1, 80.0, None, float("nan")], limit_kmh=50)
    assert s.n == 4  # None and NaN are not measured speeds
    assert s.over_limit == 2 and s.share_over == pytest.approx(0.5) and s.limit_kmh == 50.0
    assert s.v85 == pytest.approx(np.percentile([49.9, 50.0, 50.1, 80.0], 85))


def test_no_speeds() -> None:
    s = speed_stats([], limit_kmh=80)
    assert s.n == 0 and s.mean is None and s.v85 is None and s.over_limit == 0 and s.share_over is None


def test_limits() -> None:
    assert check_limit(None) is None and check_limit(0) is None and check_limit(80) == 80.0
    for bad in (-5, math.inf, math.nan):
        with pytest.raises(InputError, match="speed limit"):
            check_limit(bad)
    assert is_over_limit(81.0, 80.0) and not is_over_limit(80.0, 80.0)
    assert not is_over_limit(None, 80.0) and not is_over_limit(float("nan"), 80.0)
    assert not is_over_limit(200.0, 0.0) and not is_over_limit(200.0, None)
