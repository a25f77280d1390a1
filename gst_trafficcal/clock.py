"""Wall-clock times of stream timestamps: when a vehicle passed, as an ISO 8601 date and time.

Stream timestamps (buffer PTS, seconds) say when in the video something happened; an NVR or a traffic count
needs the date and time.  A recording's start time is given (``speedometer start-datetime=``, ``trafficcal run
--start-time``); for a live source ``now`` takes the machine's clock at the first frame, less that frame's
timestamp (off by the pipeline's latency, typically a fraction of a second).
"""

from __future__ import annotations

from datetime import datetime, timedelta

from .errors import InputError

NOW = "now"


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
