"""Traffic statistics as traffic engineers read them: V85, vehicles over a speed limit, counts per interval.

V85, the speed 85 % of the vehicles do not exceed, is what speed limits are set and checked against; the share
over the posted limit is what enforcement asks for; a traffic count is tabulated per time interval (15 min by
default), lane and direction, with the classes.  Used by ``report.html``, ``trafficcal run`` (``intervals.csv``),
``trafficcal report`` and the overlay's counters.
"""

from __future__ import annotations

import csv
import io
from array import array
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np

from .errors import InputError
from .fileio import atomic_write_text


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


@dataclass(frozen=True)
class SpeedLimit:
    """A posted speed limit: ``kmh`` for every vehicle, and classes with limits of their own (``by_class``: trucks
    and buses often have lower ones).  False when there is none at all."""

    kmh: float | None = None
    by_class: tuple[tuple[str, float], ...] = ()

    def for_label(self, label: str | None) -> float | None:
        """The limit a vehicle of class ``label`` is held to (None: none)."""
        return dict(self.by_class).get(label or "", self.kmh)

    def is_over(self, speed_kmh: float | None, label: str | None = None) -> bool:
        return is_over_limit(speed_kmh, self.for_label(label))

    def __bool__(self) -> bool:
        return self.kmh is not None or bool(self.by_class)

    def describe(self) -> str:
        """"80 km/h (truck 60, bus 60)", "truck 60 km/h" — for table headings and messages."""
        classes = ", ".join(f"{c} {v:g}" for c, v in self.by_class)
        if self.kmh is None:
            return f"{classes} km/h" if classes else "no limit"
        return f"{self.kmh:g} km/h" + (f" ({classes})" if classes else "")

    def properties(self) -> str:
        """The elements' properties for it: speed-limit and class-limits (empty without a limit)."""
        out = [f"speed-limit={self.kmh:g}"] if self.kmh is not None else []
        if self.by_class:
            out.append("class-limits=" + ",".join(f"{c}={v:g}" for c, v in self.by_class))
        return " ".join(out)


#: the classes vehicles are reported as (vehicles.classify.LABEL_OF_STYLE's labels), which may have limits of their own
VEHICLE_CLASSES = ("car", "van", "bus", "truck", "motorcycle")


def parse_speed_limit(text: str | float | None, what: str = "speed limit", classes_only: bool = False) -> SpeedLimit:
    """``80``, ``80,truck=60,bus=60`` or ``truck=60`` (km/h; 0 or empty: none) as a :class:`SpeedLimit`;
    InputError naming ``what`` for anything else (``classes_only``: only ``CLASS=KMH`` pairs are valid), also for a
    limit given twice (``80,90`` held every vehicle to 90 without a word; ``truck=60,truck=50`` described both and
    applied 50)."""
    if text is None or isinstance(text, (int, float)):
        return SpeedLimit(check_limit(text))
    form = ("CLASS=KMH,... (e.g. truck=60,bus=60)" if classes_only
            else "KMH or KMH,CLASS=KMH,... (e.g. 80,truck=60,bus=60)")
    kmh, by_class, general = None, [], False
    for part in (p.strip() for p in str(text).split(",")):
        if not part:
            continue
        name, sep, value = part.partition("=")
        try:
            number = float(value if sep else name)
        except ValueError:
            raise InputError(f"{what}: {text!r} is not {form}") from None
        try:
            v = check_limit(number)
        except InputError:
            raise InputError(f"{what}: {part!r}: a limit is a positive number of km/h (0: none)") from None
        if not sep:
            if general:
                raise InputError(f"{what}: {text!r} gives the limit for every vehicle twice")
            kmh, general = v, True
        elif v is not None and name.strip().lower() in VEHICLE_CLASSES:
            if name.strip().lower() in dict(by_class):
                raise InputError(f"{what}: {text!r} gives the limit for {name.strip().lower()} twice")
            by_class.append((name.strip().lower(), v))
        elif v is not None and name.strip():  # a typo ("lorry", "trucks") would leave that class unchecked
            raise InputError(f"{what}: {name.strip()!r} is no vehicle class (classes: {', '.join(VEHICLE_CLASSES)})")
        else:
            raise InputError(f"{what}: {part!r} needs a class name and a positive limit (e.g. truck=60)")
    return SpeedLimit(kmh, tuple(by_class))


def element_limit(speed_limit: float, class_limits: str) -> SpeedLimit:
    """The limit of an element's ``speed-limit`` (km/h, 0: none) and ``class-limits`` (``truck=60,bus=60``)
    properties; InputError naming class-limits when it is not CLASS=KMH pairs."""
    classes = parse_speed_limit(class_limits, "class-limits", classes_only=True)
    if classes.kmh is not None:
        raise InputError(f"class-limits {class_limits!r}: CLASS=KMH pairs only (the limit for every vehicle is "
                         "speed-limit)")
    return SpeedLimit(check_limit(speed_limit), classes.by_class)


def as_limit(limit: "SpeedLimit | float | None") -> SpeedLimit:
    """A limit given as a number (km/h; None or 0: none) or already a :class:`SpeedLimit`."""
    return limit if isinstance(limit, SpeedLimit) else SpeedLimit(check_limit(limit))


def check_limit(limit_kmh: float | None) -> float | None:
    """The limit as a float; None for none (None or 0); InputError for a negative or non-finite one."""
    if limit_kmh is None or limit_kmh == 0:
        return None
    limit = float(limit_kmh)
    if not np.isfinite(limit) or limit < 0:
        raise InputError(f"speed limit must be a positive number of km/h (0: none), got {limit_kmh!r}")
    return limit


def is_over_limit(speed_kmh: float | None, limit_kmh: "SpeedLimit | float | None", label: str | None = None) -> bool:
    """True when a measured speed exceeds a set limit (a limit of None or 0 means none; a :class:`SpeedLimit`: the
    one of the vehicle's class ``label``)."""
    if isinstance(limit_kmh, SpeedLimit):
        limit_kmh = limit_kmh.for_label(label)
    return bool(limit_kmh) and speed_kmh is not None and bool(np.isfinite(speed_kmh)) and speed_kmh > limit_kmh


def speed_stats(speeds_kmh: Iterable[float], limit_kmh: "SpeedLimit | float | None" = None,
                labels: Iterable[str | None] | None = None) -> SpeedStats:
    """Mean, median, V85, 95th percentile and maximum of the finite speeds, and how many exceed the limit — each
    vehicle its class's when ``labels`` (one per speed) are given."""
    speeds = list(speeds_kmh)
    names = list(labels) if labels is not None else [None] * len(speeds)
    if len(names) != len(speeds):
        raise ValueError(f"{len(names)} labels for {len(speeds)} speeds")
    keep = [(float(v), n) for v, n in zip(speeds, names) if v is not None and np.isfinite(v)]
    v = np.asarray([k[0] for k in keep], np.float64)
    limit = as_limit(limit_kmh)
    over = sum(limit.is_over(s, n) for s, n in keep) if limit else None
    if not len(v):
        return SpeedStats(0, limit_kmh=limit.kmh, over_limit=over)
    p50, p85, p95 = np.percentile(v, [50, 85, 95])
    return SpeedStats(len(v), float(v.mean()), float(p50), float(p85), float(p95), float(v.max()), limit.kmh, over)


def event_stats(events: Iterable, limit: "SpeedLimit | float | None" = None) -> SpeedStats:
    """:func:`speed_stats` of the vehicles' measured speeds, each held to its class's limit."""
    measured = [e for e in events if e.speed_kmh is not None]
    return speed_stats([e.speed_kmh for e in measured], limit, [e.label for e in measured])


# --------------------------------------------------------------------------- counts per time interval

CLASS_COLUMNS = ("car", "van", "bus", "truck", "motorcycle")
"""Vehicle classes with a column of their own in the interval table (others are counted under ``other``)."""

INTERVAL_FIELDS: tuple[str, ...] = (
    "interval_start", "interval_end", "observed_s", "lane", "direction", "vehicles", "measured", "mean_kmh",
    "median_kmh",
    "v85_kmh", "max_kmh", "over_limit", *CLASS_COLUMNS, "other",
)


@dataclass(frozen=True)
class IntervalRow:
    """Vehicles that passed in one time interval, in one lane and direction (``lane``/``direction`` None and
    ``total`` True: all of them)."""

    start: str  # ISO 8601 date and time when the stream's clock is known, else stream time "H:MM:SS"
    end: str
    lane: int | None
    direction: str | None
    vehicles: int
    speeds: SpeedStats
    classes: dict[str, int]
    total: bool = False
    observed_s: float | None = None  # seconds of the interval the video covers (None: not known)

    def to_dict(self) -> dict[str, object]:
        """The CSV row (keys :data:`INTERVAL_FIELDS`; None for an unknown lane, direction or speed)."""
        s = self.speeds
        d: dict[str, object] = {
            "interval_start": self.start, "interval_end": self.end,
            "observed_s": None if self.observed_s is None else round(self.observed_s, 1),
            "lane": "all" if self.total else self.lane, "direction": "all" if self.total else self.direction,
            "vehicles": self.vehicles, "measured": s.n,
            "mean_kmh": _round(s.mean), "median_kmh": _round(s.median), "v85_kmh": _round(s.v85),
            "max_kmh": _round(s.max), "over_limit": s.over_limit}
        d.update({c: self.classes.get(c, 0) for c in CLASS_COLUMNS})
        d["other"] = sum(n for c, n in self.classes.items() if c not in CLASS_COLUMNS)
        return d


def _round(v: float | None) -> float | None:
    return None if v is None else round(v, 2)


def _stream_clock(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


def interval_rows(events: Iterable, interval_s: float = 900.0, start: datetime | None = None,
                  limit_kmh: "SpeedLimit | float | None" = None,
                  covered: Sequence[tuple[float, float]] | None = None) -> list[IntervalRow]:
    """Counts, speeds (mean, median, V85, max, over the limit) and classes per time interval, lane and direction,
    plus one row with every vehicle of the interval — the traffic count traffic engineers tabulate.

    A vehicle belongs to the interval of the middle of its time in view.  With ``start`` (the date and time of
    stream time 0) intervals are aligned to the clock (15 min: :00, :15, :30, :45) and named by date and time;
    without it they count from the start of the stream.  Vehicles without timestamps (or NaN ones) are left out.

    ``covered``: the spans of stream time (s) the video covers.  Then every interval they reach has its row of all
    vehicles even when none passed (a count of zero, not a gap), and each row says how many seconds of its interval
    were watched (``observed_s``: less than the interval at the ends of a recording, across a gap between files or
    while a live stream was down) — a count over part of an interval is not comparable with a whole one.
    """
    _check_interval(interval_s)
    limit = as_limit(limit_kmh)
    offset = _clock_offset(start)
    midnight = None if start is None else start - timedelta(seconds=offset)
    groups: dict[int, list] = {}
    for e in events:
        if e.first_timestamp_s is None or e.last_timestamp_s is None:
            continue
        t = offset + 0.5 * (e.first_timestamp_s + e.last_timestamp_s)
        if not np.isfinite(t):  # a NaN or infinite timestamp tells no time either (numpy's error before)
            continue
        groups.setdefault(int(np.floor(t / interval_s)), []).append(e)
    observed: dict[int, float] = {}
    for a, b in covered or ():
        a, b = offset + float(a), offset + float(b)
        if not (np.isfinite(a) and np.isfinite(b)):
            raise InputError(f"a covered span of stream time must be two finite numbers of seconds, got {a!r} to "
                             f"{b!r}")
        for k in range(int(np.floor(a / interval_s)), int(np.ceil(b / interval_s))):
            seen = min(b, (k + 1) * interval_s) - max(a, k * interval_s)
            if seen > 0:
                observed[k] = observed.get(k, 0.0) + seen
                groups.setdefault(k, [])
    rows = []
    for k in sorted(groups):
        a, b = k * interval_s, (k + 1) * interval_s
        if midnight is not None:
            name = [(midnight + timedelta(seconds=x)).isoformat(timespec="seconds") for x in (a, b)]
        else:
            name = [_stream_clock(a), _stream_clock(b)]
        members = groups[k]
        seen = min(observed.get(k, 0.0), interval_s) if covered is not None else None
        keys = sorted({(e.lane, e.direction) for e in members},
                      key=lambda kv: (kv[0] is None, kv[0] or 0, kv[1] or "~"))
        for lane, direction in keys:
            sub = [e for e in members if e.lane == lane and e.direction == direction]
            rows.append(_row(name, lane, direction, sub, limit, observed_s=seen))
        rows.append(_row(name, None, None, members, limit, total=True, observed_s=seen))
    return rows


def last_boundary(t: float, interval_s: float, start: datetime | None = None) -> float:
    """The stream time (s) of the latest interval boundary at or before stream time ``t`` (intervals aligned as
    :func:`interval_rows` aligns them)."""
    _check_interval(interval_s)
    offset = _clock_offset(start)
    return float(np.floor((offset + t) / interval_s) * interval_s - offset)


def _check_interval(interval_s: float) -> None:
    """InputError unless ``interval_s`` is a positive, finite number of seconds (an infinite one made every interval
    start at NaN: numpy's "cannot convert float NaN to integer")."""
    if not (isinstance(interval_s, (int, float, np.number)) and 0 < interval_s < float("inf")):
        raise InputError(f"interval must be a positive, finite number of seconds, got {interval_s!r}")


def _clock_offset(start: datetime | None) -> float:
    """Seconds from midnight to stream time 0 (0 without a start): intervals are aligned to the clock by it."""
    if start is None:
        return 0.0
    return (start - start.replace(hour=0, minute=0, second=0, microsecond=0)).total_seconds()


def _row(name: list[str], lane, direction, events: list, limit: SpeedLimit, total: bool = False,
         observed_s: float | None = None) -> IntervalRow:
    classes: dict[str, int] = {}
    for e in events:
        classes[e.label or "unknown"] = classes.get(e.label or "unknown", 0) + 1
    return IntervalRow(name[0], name[1], lane, direction, len(events), event_stats(events, limit), classes, total,
                       observed_s)


def write_intervals_csv(path: str | Path, rows: Sequence[IntervalRow]) -> Path:
    """The interval table as CSV (columns :data:`INTERVAL_FIELDS`, empty cell = unknown), written atomically."""
    return atomic_write_text(path, intervals_csv_text(rows), "interval table")


def intervals_csv_text(rows: Sequence[IntervalRow], header: bool = True) -> str:
    """The CSV text of ``rows`` (:func:`write_intervals_csv`), with the header line or without."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=INTERVAL_FIELDS, lineterminator="\n")
    if header:
        w.writeheader()
    for r in rows:
        w.writerow({k: "" if v is None else v for k, v in r.to_dict().items()})
    return buf.getvalue()


@dataclass(frozen=True, slots=True)
class CountedVehicle:
    """What the interval table needs of a vehicle event (the attributes :func:`interval_rows` reads)."""

    first_timestamp_s: float
    last_timestamp_s: float
    lane: int | None
    direction: str | None
    speed_kmh: float | None
    label: str | None


class CountedVehicles:
    """Many vehicles' :class:`CountedVehicle` fields in packed columns (37 bytes a vehicle instead of an event's
    half kilobyte): a stream counted for weeks stays small.  Labels and directions are stored once each."""

    def __init__(self) -> None:
        self._times = array("d")  # first, last per vehicle
        self._speeds = array("d")  # NaN: not measured
        self._lanes = array("h")  # -1: no lane
        self._names = array("H")  # label code, direction code per vehicle
        self._ids = array("q")  # the event's id per vehicle (for revise)
        self._codes: dict[str | None, int] = {}
        self._words: list[str | None] = []

    def _code(self, word: str | None) -> int:
        if word not in self._codes:
            self._codes[word] = len(self._words)
            self._words.append(word)
        return self._codes[word]

    def append(self, event) -> None:
        """Keep a vehicle event's counted fields (an event without both timestamps is left out, as in
        :func:`interval_rows`)."""
        if event.first_timestamp_s is None or event.last_timestamp_s is None:
            return
        speed, lane, names = self._fields(event)
        self._times.extend((float(event.first_timestamp_s), float(event.last_timestamp_s)))
        self._speeds.append(speed)
        self._lanes.append(lane)
        self._names.extend(names)
        self._ids.append(int(event.id))

    def _fields(self, event) -> tuple[float, int, tuple[int, int]]:
        """The packed speed (NaN: not measured), lane (-1: none) and label and direction codes of an event."""
        return (np.nan if event.speed_kmh is None else float(event.speed_kmh),
                -1 if event.lane is None else int(event.lane), (self._code(event.label), self._code(event.direction)))

    def revise(self, event) -> bool:
        """Replace the counted fields of the last vehicle with ``event``'s id (measured again); False when none."""
        for k in range(len(self._ids) - 1, -1, -1):
            if self._ids[k] == int(event.id):
                self._speeds[k], self._lanes[k], names = self._fields(event)
                self._names[2 * k:2 * k + 2] = array("H", names)
                return True
        return False

    def __len__(self) -> int:
        return len(self._speeds)

    def __iter__(self):
        for k in range(len(self._speeds)):
            yield self[k]

    def __getitem__(self, k: int) -> CountedVehicle:
        w, speed, lane = self._words, self._speeds[k], self._lanes[k]
        return CountedVehicle(self._times[2 * k], self._times[2 * k + 1], None if lane < 0 else lane,
                              w[self._names[2 * k + 1]], None if speed != speed else speed, w[self._names[2 * k]])


class IntervalTable:
    """``intervals.csv`` kept while a stream plays: the speedometer's vehicles (:meth:`vehicle`) and frame times
    (:meth:`frame`) in; the file rewritten (atomically) once an interval has ended and ``grace_s`` more have passed
    (time for the vehicles in view at its end to leave), and at the end (:meth:`close`) with every interval, the
    last one partial.  The interval still open is on disk too, as it grows: its rows, with the seconds of it watched
    so far, are written after the closed ones whenever a vehicle was counted since the last write and ``open_every_s``
    of stream time have passed, and replaced when it closes — a process that is killed (kill -9, a power cut) loses
    at most that last minute's vehicles.  Those writes recount only the open interval's vehicles (the closed rows'
    text is kept from the last close), so a table of weeks costs a file write, not a recount, each time."""

    def __init__(self, path: str | Path, interval_s: float = 900.0, start: datetime | None = None,
                 limit: "SpeedLimit | float | None" = None, grace_s: float = 30.0, open_every_s: float = 60.0) -> None:
        _check_interval(interval_s)
        self.path = Path(path)
        self.interval_s, self.start, self.limit, self.grace_s = float(interval_s), start, limit, float(grace_s)
        self.open_every_s = float(open_every_s)
        self.events = CountedVehicles()
        self.first_t: float | None = None
        self.last_t: float | None = None
        self._dt = 0.0  # the last frame's duration: the video covers it too
        self._written_until: float | None = None  # stream time up to which the file holds closed intervals
        self._closed_text = ""  # the closed intervals' rows as last written (CSV, no header)
        self._open = array("q")  # which of ``events`` are counted in the intervals not closed yet (8 bytes each)
        self._open_written_t: float | None = None  # stream time of the last write of the open interval
        self._changed = False  # a vehicle counted since the last write

    def frame(self, t: float) -> bool:
        """A frame at stream time ``t`` (s); True when the file was rewritten."""
        if self.first_t is None:
            self.first_t = t
        if self.last_t is not None and t > self.last_t:
            self._dt = t - self.last_t
        self.last_t = max(t, self.last_t if self.last_t is not None else t)
        closed = last_boundary(t - self.grace_s, self.interval_s, self.start)
        if closed > self.first_t and (self._written_until is None or closed > self._written_until):
            self._written_until = closed
            self._write(closed)
            return True
        if self._changed and (self._open_written_t is None or t - self._open_written_t >= self.open_every_s):
            self._write_open()
            return True
        return False

    def vehicle(self, event) -> None:
        n = len(self.events)
        self.events.append(event)
        if len(self.events) > n and (self._written_until is None or
                                     self._middle(self.events[n]) >= self._written_until):
            self._open.append(n)
            self._changed = True

    def revise(self, event) -> None:
        """A vehicle measured again at the end (speedometer ``remeasure``): its counted fields replaced."""
        self.events.revise(event)

    def set_start(self, start: datetime | None) -> None:
        """The date and time of stream time 0, when it becomes known at the first frame (a live clock)."""
        self.start = start

    def close(self) -> None:
        """Every interval the stream reached, the open one too (its ``observed_s`` says how much of it)."""
        if self.first_t is not None:
            self._write(self.last_t + self._dt, keep=False)
        else:
            write_intervals_csv(self.path, [])

    @staticmethod
    def _middle(e) -> float:
        return 0.5 * (e.first_timestamp_s + e.last_timestamp_s)

    def _write(self, until: float, keep: bool = True) -> None:
        """Every interval up to stream time ``until`` counted anew (the vehicles that left late included); with
        ``keep`` that text is kept as the closed rows and the open interval's rows follow it."""
        events = [e for e in self.events if self._middle(e) < until]
        rows = interval_rows(events, self.interval_s, self.start, self.limit, covered=[(self.first_t, until)])
        if not keep:
            write_intervals_csv(self.path, rows)
            return
        self._closed_text = intervals_csv_text(rows, header=False)
        self._open = array("q", (k for k in self._open if self._middle(self.events[k]) >= until))
        self._write_open()

    def _write_open(self) -> None:
        """The closed rows as last counted, then the open interval's up to the last frame (the seconds of it watched
        so far); nothing of it before its first frame."""
        self._changed, self._open_written_t = False, self.last_t
        since = self.first_t if self._written_until is None else max(self.first_t, self._written_until)
        until = self.last_t + self._dt
        events = [e for e in (self.events[k] for k in self._open) if self._middle(e) < until]
        rows = interval_rows(events, self.interval_s, self.start, self.limit,
                             covered=[(since, until)]) if until > since else []
        atomic_write_text(self.path, intervals_csv_text([]) + self._closed_text + intervals_csv_text(rows, False),
                          "interval table")
