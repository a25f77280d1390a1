"""Dates and times of stream timestamps (``clock.py``)."""

from __future__ import annotations

import pytest

from gst_trafficcal.errors import InputError


def test_start_times() -> None:
    from datetime import datetime, timedelta, timezone

    from gst_trafficcal.clock import clock_time, parse_start_time, start_from_now

    utc = parse_start_time("2026-12-05T08:00:00Z")
    assert utc == datetime(2026, 12, 5, 8, tzinfo=timezone.utc)
    assert clock_time(utc, 61.25) == "2026-12-05T08:01:01.250+00:00" and clock_time(utc, None) is None
    local = parse_start_time("2026-12-05 08:00:00")  # no offset: the machine's local time
    assert local.tzinfo is not None and local.replace(tzinfo=None) == datetime(2026, 12, 5, 8)
    assert parse_start_time("") is None and parse_start_time(None) is None
    for bad in ("yesterday", "now", "2026-13-45T00:00:00"):
        with pytest.raises(InputError, match="ISO 8601"):
            parse_start_time(bad)
    now = datetime(2026, 12, 5, 8, 0, 10, tzinfo=timezone.utc)
    assert start_from_now(10.0, now) == now - timedelta(seconds=10)


def test_a_recordings_start_from_its_file_name() -> None:
    from datetime import datetime

    from gst_trafficcal.clock import start_from_name

    local = lambda *a: datetime(*a).astimezone()  # noqa: E731
    assert start_from_name("cam7_20261205_080000.mp4") == local(2026, 12, 5, 8, 0, 0)
    assert start_from_name("2026-12-05_08-15-30.mp4") == local(2026, 12, 5, 8, 15, 30)
    assert start_from_name("ch01_2026-12-05T23:59:59.mkv") == local(2026, 12, 5, 23, 59, 59)
    assert start_from_name("north_20261205-0745.mp4") == local(2026, 12, 5, 7, 45)  # no seconds
    assert start_from_name("cam2_20261205_080000_20261205_090000.mp4") == local(2026, 12, 5, 9, 0)  # the last one
    for none in ("video.mp4", "20261399_080000.mp4", "cam_12345678_123456.mp4", "2026120508.mp4"):
        assert start_from_name(none) is None, none


def test_periods_and_the_next_boundary_on_the_clock() -> None:
    from datetime import datetime, timezone

    from gst_trafficcal.clock import next_boundary, parse_period

    assert [parse_period(t) for t in ("24h", "1d", "15m", "90s", "1.5h")] == [86400, 86400, 900, 90, 5400]
    for bad in ("", "24", "h", "0h", "-1h", "1w"):
        with pytest.raises(InputError, match="is not a period"):
            parse_period(bad, "--split-every")
    now = datetime(2026, 12, 5, 13, 47, 12, tzinfo=timezone.utc)
    assert next_boundary(now, 86400) == datetime(2026, 12, 6, tzinfo=timezone.utc)  # midnight
    assert next_boundary(now, 3600) == datetime(2026, 12, 5, 14, tzinfo=timezone.utc)  # the next full hour
    assert next_boundary(now, 7 * 3600) == datetime(2026, 12, 5, 14, tzinfo=timezone.utc)  # 0, 7, 14, 21 h
    assert next_boundary(datetime(2026, 12, 5, 22, tzinfo=timezone.utc), 7 * 3600) == datetime(2026, 12, 6,
                                                                                              tzinfo=timezone.utc)
    assert next_boundary(datetime(2026, 12, 5, 14, tzinfo=timezone.utc), 3600) == datetime(2026, 12, 5, 15,
                                                                                           tzinfo=timezone.utc)
