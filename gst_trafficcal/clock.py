"""Wall-clock times of stream timestamps: when a vehicle passed, as an ISO 8601 date and time.

Stream timestamps (buffer PTS, seconds) say when in the video something happened; an NVR or a traffic count
needs the date and time.  A recording's start time is given (``speedometer start-datetime=``, ``trafficcal run
--start-time``) or read from its file name, where NVRs and cameras put it (:func:`start_from_name`, ``--start-time
auto``); for a live source ``now`` takes the machine's clock at the first frame, less that frame's timestamp (off
by the pipeline's latency, typically a fraction of a second).
"""

from __future__ import annotations

import re
from datetime import datetime, timedelta

from .errors import InputError

NOW = "now"
AUTO = "auto"  # trafficcal run --start-time auto: each file's start from the date and time in its name

# 20261205_080000, 2026-12-05_08-00-00, 2026-12-05T08:00:00, 20261205-0800 (seconds optional): how NVRs and
# cameras name their recordings
_NAME_TIME = re.compile(r"(?<!\d)(\d{4})-?(\d{2})-?(\d{2})[T_\- ]?(\d{2})[-_:.h]?(\d{2})(?:[-_:.m]?(\d{2}))?(?!\d)")


def parse_start_time(text: str | None, where: str = "start time") -> datetime | None:
    """The time of stream time 0 from ISO 8601 text (``2026-12-05T08:00:00+01:00``, ``...Z``; without an offset:
    the machine's local time); None for "" or None.  ``now`` is not a time: the caller takes the clock
    (:func:`start_from_now`).  InputError naming ``where`` for anything else."""
    if not text:
        return None
    s = text.strip()
    if s.endswith(("Z", "z")):  # Python 3.10's fromisoformat does not read "Z"
        s = s[:-1] + "+00:00"
    try:
        t = datetime.fromisoformat(s)
    except ValueError:
        raise InputError(f"{where}: {text!r} is not an ISO 8601 date and time (e.g. 2026-12-05T08:00:00+01:00, "
                         f"or '{NOW}' for a live source)") from None
    return t.astimezone() if t.tzinfo is None else t


def start_from_now(first_timestamp_s: float, now: datetime | None = None) -> datetime:
    """Stream time 0 of a live source whose frame with timestamp ``first_timestamp_s`` arrives ``now``."""
    now = now if now is not None else datetime.now().astimezone()
    return now - timedelta(seconds=float(first_timestamp_s))


def clock_time(start: datetime, timestamp_s: float | None) -> str | None:
    """``start`` + ``timestamp_s`` as ISO 8601 with milliseconds and ``start``'s UTC offset (None for no time)."""
    if timestamp_s is None:
        return None
    return (start + timedelta(seconds=float(timestamp_s))).isoformat(timespec="milliseconds")


def start_from_name(name: str) -> datetime | None:
    """The date and time a recording's file name gives (``cam7_20261205_080000.mp4``, ``2026-12-05_08-00-00.mp4``,
    ``...T08:00:00``; seconds optional), in the machine's local time; None when it holds none.  The last one wins
    (a camera name may carry digits first)."""
    found = None
    for m in _NAME_TIME.finditer(name):
        y, mo, d, h, mi, sec = (int(g) if g else 0 for g in m.groups())
        try:
            found = datetime(y, mo, d, h, mi, sec)
        except ValueError:  # 20261399_...: digits, not a date
            continue
    return None if found is None else found.astimezone()


_PERIOD_UNITS = {"s": 1.0, "m": 60.0, "h": 3600.0, "d": 86400.0}


def parse_period(text: str, where: str = "period") -> float:
    """Seconds of a period written as a number and a unit: ``90s``, ``15m``, ``1h``, ``24h``, ``1d``."""
    m = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([smhd])\s*", str(text).lower())
    if m is None or float(m.group(1)) <= 0:
        raise InputError(f"{where}: {text!r} is not a period (a positive number and s, m, h or d: 24h, 15m, 90s)")
    return float(m.group(1)) * _PERIOD_UNITS[m.group(2)]


def next_boundary(now: datetime, every_s: float) -> datetime:
    """The next time after ``now`` on the clock's grid of ``every_s`` seconds counted from midnight (24h: midnight;
    1h: the full hours; a period that does not divide the day starts again at midnight)."""
    midnight = now.replace(hour=0, minute=0, second=0, microsecond=0)
    k = int((now - midnight).total_seconds() // every_s) + 1
    return min(midnight + timedelta(seconds=k * every_s), midnight + timedelta(days=1))
