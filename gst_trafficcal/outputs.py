"""Per-vehicle result files: JSON-lines events, CSV, and BrnoCompSpeed results JSON.

Designed so that nothing already measured is lost:

* :class:`JsonlEventWriter` and :class:`CsvEventWriter` write one line per vehicle *as it leaves*, each
  line with a single unbuffered ``write`` (then ``fsync``), so a crash or a full disk keeps every earlier
  line. A line that cannot be written whole (a full disk) is cut off again, so the file ends with the last complete
  line, and :class:`InputError` names the file; the writer stays usable. (A fragment left by a crash, or by a pipe
  that cannot be cut back, is ended with a newline by the next write, so :func:`read_events` skips only it.)
* :class:`EventWriters` fans one event out to several writers and writes to *all* of them before raising
  the first error, so a full disk under one file does not cost the others their line.
* :class:`BrnoResultsWriter` collects reference-point tracks and writes the BrnoCompSpeed results file
  (``camera_calibration`` + ``cars`` with ``frames``/``posX``/``posY``) atomically (temporary file, fsync,
  rename): readers never see half a file, and a failed write leaves the previous version intact.

Event fields (the JSON keys and the CSV columns, in this order) are :data:`EVENT_FIELDS`; ``speed_kmh`` is
null when the vehicle was not measured and ``reason`` then says why.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import stat
import tempfile
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np

from .brnocompspeed import (
    BrnoCalibration, Track, car_json, write_results_text,
)
from .calibration import Calibration
from .clock import clock_time, parse_start_time
from .errors import InputError
from .fileio import atomic_write, atomic_write_text, replace_target

EVENT_FIELDS: tuple[str, ...] = (
    "id", "label", "first_timestamp_s", "last_timestamp_s", "speed_kmh", "speed_uncertainty_kmh", "reason", "lane",
    "direction",
    "calibration_id", "n_samples", "length_m", "width_m", "height_m", "first_time", "last_time", "run",
)

TOWARDS_VP1 = "towards_vp1"
AWAY_FROM_VP1 = "away_from_vp1"
DIRECTIONS = (TOWARDS_VP1, AWAY_FROM_VP1)


def direction_name(direction: int | str | None) -> str | None:
    """The event's direction string for a tracker direction (+1 towards VP1, -1 away, 0/None unknown)."""
    if direction is None or direction == "" or direction == 0:
        return None
    if isinstance(direction, str):
        if direction not in DIRECTIONS:
            raise ValueError(f"unknown direction {direction!r} (expected one of {', '.join(DIRECTIONS)})")
        return direction
    return TOWARDS_VP1 if direction > 0 else AWAY_FROM_VP1


def _opt_float(v: Any) -> float | None:
    if v is None or v == "":
        return None
    f = float(v)
    return f if math.isfinite(f) else None


def _opt_int(v: Any) -> int | None:
    if v is None or v == "":
        return None
    return int(v)


@dataclass(frozen=True)
class VehicleEvent:
    """One vehicle that left the scene: what the event file records about it."""

    id: int
    label: str
    first_timestamp_s: float | None
    last_timestamp_s: float | None
    speed_kmh: float | None
    reason: str = ""  # why speed_kmh is None ("" when measured)
    lane: int | None = None
    direction: str | None = None  # TOWARDS_VP1 / AWAY_FROM_VP1 / None (unknown)
    calibration_id: str | None = None
    n_samples: int = 0  # speed samples (point pairs) behind the median
    speed_uncertainty_kmh: float | None = None  # half-width of the ~95 % interval speed ± U (uncertainty.py)
    length_m: float | None = None  # median 3D-box dimensions (metres), when a calibration with a scale gave them
    width_m: float | None = None
    height_m: float | None = None
    first_time: str | None = None  # ISO 8601 date and time of the first / last sighting, when the stream's start
    last_time: str | None = None  # time is known (clock.py)
    run: str | None = None  # the run that wrote it (:func:`new_run_id`): runs appended to one file reuse track ids

    def __post_init__(self) -> None:
        object.__setattr__(self, "id", int(self.id))
        object.__setattr__(self, "label", str(self.label))
        for name in ("first_timestamp_s", "last_timestamp_s", "speed_kmh", "speed_uncertainty_kmh", "length_m",
                     "width_m", "height_m"):
            object.__setattr__(self, name, _opt_float(getattr(self, name)))
        object.__setattr__(self, "lane", _opt_int(self.lane))
        object.__setattr__(self, "direction", direction_name(self.direction))
        object.__setattr__(self, "calibration_id", self.calibration_id or None)
        object.__setattr__(self, "n_samples", int(self.n_samples or 0))
        for name in ("first_time", "last_time", "run"):
            object.__setattr__(self, name, str(getattr(self, name)) if getattr(self, name) else None)
        for name in ("first_time", "last_time"):  # refused here, where the file is named (from_dict), not later
            value = getattr(self, name)
            if value is not None and _iso_time(value) is None:
                raise ValueError(f"{name} {value!r} is not an ISO 8601 date and time")
        reason = str(self.reason or "")
        if self.speed_kmh is None and not reason:
            reason = "not measured"
        if self.speed_kmh is not None:
            reason = ""
        else:
            object.__setattr__(self, "speed_uncertainty_kmh", None)
        object.__setattr__(self, "reason", reason)

    @property
    def measured(self) -> bool:
        return self.speed_kmh is not None

    def with_clock(self, start: datetime | None) -> "VehicleEvent":
        """The event with ``first_time``/``last_time`` = ``start`` + its timestamps (unchanged for no start)."""
        if start is None:
            return self
        return replace(self, first_time=clock_time(start, self.first_timestamp_s),
                       last_time=clock_time(start, self.last_timestamp_s))

    def moved(self, shift_s: float, ndigits: int | None = None) -> "VehicleEvent":
        """The event with its timestamps ``shift_s`` seconds later (rounded to ``ndigits`` decimals if given): a
        part's vehicles put on another stream's clock.  An event without timestamps, or no shift: unchanged."""
        if not shift_s or self.first_timestamp_s is None or self.last_timestamp_s is None:
            return self

        def later(t: float) -> float:
            return t + shift_s if ndigits is None else round(t + shift_s, ndigits)

        return replace(self, first_timestamp_s=later(self.first_timestamp_s),
                       last_timestamp_s=later(self.last_timestamp_s))

    def stream_started(self) -> datetime | None:
        """The date and time of its stream's time 0 (its first sighting's date less its timestamp); None undated."""
        if not self.first_time or self.first_timestamp_s is None:
            return None
        return parse_start_time(self.first_time) - timedelta(seconds=self.first_timestamp_s)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready dict with the keys of :data:`EVENT_FIELDS`, in that order."""
        d = asdict(self)
        return {k: d[k] for k in EVENT_FIELDS}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "event") -> "VehicleEvent":
        missing = [k for k in ("id", "speed_kmh") if k not in d]
        if missing:
            raise InputError(f"{where}: not a vehicle event (missing {', '.join(missing)})")
        try:
            kwargs = {"label": "", "first_timestamp_s": None, "last_timestamp_s": None}
            kwargs.update({k: d[k] for k in EVENT_FIELDS if k in d})
            return cls(**kwargs)
        except (TypeError, ValueError) as exc:
            raise InputError(f"{where}: bad vehicle event ({exc})") from None


def _iso_time(text: str) -> datetime | None:
    """``text`` as a date and time (as :func:`~gst_trafficcal.clock.parse_start_time` reads it), else None."""
    try:
        return parse_start_time(text)
    except InputError:
        return None


def new_run_id(now: datetime | None = None) -> str:
    """An id for one run of the speedometer: the UTC time it started and four random hex digits
    (``20261206T053500Z-3f9a``). Every event of the run carries it, so the events of runs appended to one file
    (whose track ids start again at 1) stay apart: (run, id) names one vehicle."""
    import secrets
    from datetime import timezone

    now = (now or datetime.now(timezone.utc)).astimezone(timezone.utc)
    return f"{now:%Y%m%dT%H%M%SZ}-{secrets.token_hex(2)}"


def stream_start(events: Iterable[VehicleEvent]) -> datetime | None:
    """The date and time of stream time 0 from the first event that carries one (None: no event is dated)."""
    return next((s for e in events if (s := e.stream_started()) is not None), None)


def on_one_clock(events: Sequence[VehicleEvent]) -> tuple[datetime | None, list[VehicleEvent]]:
    """Events of several runs appended to one file (speedometer ``append``), each run's timestamps from its own
    stream start, put on the clock of the earliest: (that start, the events with their timestamps moved). A run is
    told by its start (date and time less timestamp) more than half a second from another's; undated events stay
    as they are. A single run's events come back unchanged."""
    starts = [e.stream_started() for e in events]
    dated = [s for s in starts if s is not None]
    if not dated:
        return None, list(events)
    first = min(dated)
    shifts = [0.0 if s is None else (s - first).total_seconds() for s in starts]
    return first, [e.moved(shift) if shift > 0.5 else e for e, shift in zip(events, shifts)]


def reason_kind(reason: str) -> str:
    """A reason without its numbers: the text before the first bracket or colon ("track too short (4 reference
    points, needs 10)" -> "track too short"), so vehicles left unmeasured for the same cause count together."""
    return reason.split("(")[0].split(":")[0].strip()


def unmeasured_by_kind(events: Iterable[VehicleEvent]) -> list[tuple[str, int]]:
    """(reason kind, vehicles) of the unmeasured ``events``, most frequent first (ties in first-seen order)."""
    return Counter(reason_kind(e.reason) for e in events if not e.measured).most_common()


# --------------------------------------------------------------------------- line-at-a-time files


class _LineFile:
    """A file written one complete line at a time, unbuffered, each line synced to disk.  ``lazy``: opened now (a
    path that cannot be written is an error at once) but emptied only by :meth:`begin` or the first line, so that a
    pipeline that never started keeps the earlier run's file."""

    def __init__(self, path: str | Path, append: bool = False, fsync: bool = True, lazy: bool = False) -> None:
        self.path = Path(path)
        self.fsync = fsync
        self._broken = False  # the last write stopped mid-line
        self.pending = lazy and not append  # to be emptied at begin()
        try:
            if self.path.parent != Path(""):
                self.path.parent.mkdir(parents=True, exist_ok=True)
            self._f = open(self.path, "ab" if append or lazy else "wb", buffering=0)
        except OSError as exc:
            raise InputError(f"{self.path}: cannot open for writing ({exc.strerror or exc})") from None
        if append and not self.empty:  # an earlier run cut mid-line (a crash): its fragment ends before our first line
            try:
                with open(self.path, "rb") as fh:
                    fh.seek(-1, os.SEEK_END)
                    self._broken = fh.read(1) != b"\n"
            except OSError:
                pass

    @property
    def empty(self) -> bool:
        try:
            return os.fstat(self._f.fileno()).st_size == 0
        except OSError:
            return False

    def begin(self) -> None:
        """Empty a lazily opened file (the run has really started); nothing otherwise."""
        if self.pending:
            try:
                if stat.S_ISREG(os.fstat(self._f.fileno()).st_mode):  # not /dev/null, a pipe, /dev/full
                    self._f.truncate(0)
            except OSError as exc:
                raise InputError(f"{self.path}: cannot write ({exc.strerror or exc})") from None
            self.pending = False

    def _end(self) -> int | None:
        """The size of a regular file (where the next line begins: it is opened for appending); None for a pipe or
        device, which cannot be cut back."""
        try:
            st = os.fstat(self._f.fileno())
        except OSError:
            return None
        return st.st_size if stat.S_ISREG(st.st_mode) else None

    def _cut_back(self, end: int | None) -> bool:
        """Truncate the file to ``end`` (where the failed line began), so that no fragment of it stays; False when
        that is not possible (a pipe, a device, a failing truncate)."""
        if end is None:
            return False
        try:
            os.ftruncate(self._f.fileno(), end)
        except OSError:
            return False
        return True

    def write_line(self, text: str) -> None:
        """Write ``text`` as one line.  When it cannot be written whole (a full disk) the file is cut back to where
        the line began, so that it ends with the last complete line, and InputError says so."""
        if self._f.closed:
            raise InputError(f"{self.path}: writer already closed")
        self.begin()
        data = (("\n" if self._broken else "") + text.rstrip("\n") + "\n").encode("utf-8")
        view, done, end = memoryview(data), 0, self._end()
        try:
            while done < len(data):
                n = self._f.write(view[done:])
                if not n:
                    raise OSError(28, "no space left on device (short write)")
                done += n
            if self.fsync:
                try:
                    os.fsync(self._f.fileno())
                except OSError as exc:
                    if exc.errno not in (22, 95):  # EINVAL/EOPNOTSUPP: special files (pipes, /dev/...)
                        raise
        except OSError as exc:
            if not self._cut_back(end):  # the fragment stays: the next line starts on a line of its own
                self._broken = self._broken or done > 0
            raise InputError(f"{self.path}: cannot write ({exc.strerror or exc}); "
                             "every earlier line is kept") from None
        self._broken = False

    def close(self) -> None:
        if not self._f.closed:
            try:
                self._f.close()
            except OSError as exc:
                raise InputError(f"{self.path}: cannot close ({exc.strerror or exc})") from None


class JsonlEventWriter:
    """Vehicle events as JSON lines: one object per vehicle, written (and synced) when it is given."""

    def __init__(self, path: str | Path, append: bool = False, fsync: bool = True, lazy: bool = False) -> None:
        self._file = _LineFile(path, append, fsync, lazy)
        self.path = self._file.path
        self.count = 0

    def begin(self) -> None:
        self._file.begin()

    def write(self, event: VehicleEvent, extra: Mapping[str, Any] | None = None) -> None:
        """One line: ``extra`` fields (e.g. the part of a batch it came from) first, then the event's."""
        self._file.write_line(self.line(event, extra))
        self.count += 1

    @staticmethod
    def line(event: VehicleEvent, extra: Mapping[str, Any] | None = None) -> str:
        """The event's JSON line (without the newline), ``extra`` fields first."""
        return json.dumps({**(extra or {}), **event.to_dict()}, separators=(", ", ": "))

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> "JsonlEventWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class CsvEventWriter:
    """Vehicle events as CSV with the columns :data:`EVENT_FIELDS` (empty cell = null), after ``extra_columns``
    (given with each event) if any."""

    def __init__(self, path: str | Path, append: bool = False, fsync: bool = True,
                 extra_columns: Sequence[str] = (), lazy: bool = False) -> None:
        self.extra_columns = tuple(extra_columns)
        header = self._row(self.extra_columns + EVENT_FIELDS)
        # appending: the file's first line, read once here (begin() checks it); a file of other columns (an
        # earlier version's) is kept aside whole and a new one begun
        self._first = self._first_line(path) if append else None
        self.kept_aside = None
        if isinstance(self._first, str) and self._first.rstrip("\r\n") != header.rstrip("\n"):
            from .fileio import keep_aside

            self.kept_aside, self._first = keep_aside(path), None  # (its place: a new file, headed at begin())
        self._file = _LineFile(path, append, fsync, lazy)
        self.path = self._file.path
        self.count = 0
        self._headed = False
        if not self._file.pending:
            self.begin()

    def begin(self) -> None:
        """The header, unless the file has it already (appending: then it must be ours)."""
        self._file.begin()
        header = self._row(self.extra_columns + EVENT_FIELDS)
        if self._file.empty:
            self._file.write_line(header)
        elif not self._headed:
            self._check_header(header)
        self._headed = True

    @staticmethod
    def _first_line(path: str | Path) -> str | OSError | None:
        """The first line of a regular, non-empty file at ``path`` (through a symlink); None when it is empty,
        absent or not a regular file (a pipe is never read); the OSError when it cannot be read (said by
        :meth:`_check_header`, as one that cannot be opened is when it is opened for writing)."""
        from .fileio import link_target

        target = link_target(path)
        try:
            st = target.stat()
        except OSError:
            return None
        if not stat.S_ISREG(st.st_mode) or st.st_size == 0:
            return None
        try:
            with open(target, newline="") as fh:
                return fh.readline()
        except OSError as exc:
            return exc

    def _check_header(self, header: str) -> None:
        """Appending rows under another header would shift every column: refused at start, naming the file.
        The first line is the one read at start (read now only if the file was empty, absent or not a regular
        one then and has lines now)."""
        first = self._first if self._first is not None else self._first_line(self.path)
        if first is None:
            return  # not a regular file: nothing to check
        if isinstance(first, OSError):
            self._file.close()
            raise InputError(f"{self.path}: cannot read its header to append ({first.strerror or first})") from None
        if first.rstrip("\r\n") != header.rstrip("\n"):
            self._file.close()
            raise InputError(f"{self.path}: its columns ({first.strip()[:200]}) are not the ones written now "
                             f"({header.strip()}); append to a new CSV file (the JSON-lines file takes both)")

    @staticmethod
    def _row(values: Sequence[Any]) -> str:
        buf = io.StringIO()
        csv.writer(buf, lineterminator="\n").writerow(["" if v is None else v for v in values])
        return buf.getvalue()

    def write(self, event: VehicleEvent, extra: Mapping[str, Any] | None = None) -> None:
        if not self._headed:  # a lazily opened file written before begin()
            self.begin()
        d = event.to_dict()
        extra = extra or {}
        self._file.write_line(self._row([extra.get(k) for k in self.extra_columns] + [d[k] for k in EVENT_FIELDS]))
        self.count += 1

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> "CsvEventWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def attempt_all(steps: Iterable[Callable[[], object]]) -> None:
    """Run every step even when one fails: a failing output never costs the others their data. Their InputErrors
    are then raised as one, joined by "; "."""
    errors = []
    for step in steps:
        try:
            step()
        except InputError as exc:
            errors.append(str(exc))
    if errors:
        raise InputError("; ".join(errors))


@dataclass
class EventWriters:
    """Several event writers fed together; a failing one never stops the others getting the event."""

    writers: list[JsonlEventWriter | CsvEventWriter] = field(default_factory=list)

    @classmethod
    def open(cls, jsonl: str | Path | None = None, csv_path: str | Path | None = None,
             append: bool = False, fsync: bool = True, extra_columns: Sequence[str] = (),
             lazy: bool = False) -> "EventWriters":
        """``lazy``: the files are emptied (and the CSV gets its header) only at :meth:`begin` or the first event."""
        out = cls()
        try:
            if jsonl:
                out.writers.append(JsonlEventWriter(jsonl, append, fsync, lazy))
            if csv_path:
                out.writers.append(CsvEventWriter(csv_path, append, fsync, extra_columns, lazy))
        except InputError:
            out.close()
            raise
        return out

    def begin(self) -> None:
        attempt_all(w.begin for w in self.writers)

    @property
    def kept_aside(self) -> list[tuple[Path, Path]]:
        """(path, where its earlier file went) for each CSV appended to that had other columns."""
        return [(w.path, w.kept_aside) for w in self.writers if getattr(w, "kept_aside", None) is not None]

    def write(self, event: VehicleEvent, extra: Mapping[str, Any] | None = None) -> None:
        attempt_all(lambda w=w: w.write(event, extra) for w in self.writers)

    def close(self) -> None:
        attempt_all(w.close for w in self.writers)

    def __enter__(self) -> "EventWriters":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(frozen=True)
class EventLog:
    """Events read back from a JSON-lines file; ``skipped`` counts broken lines (interrupted writes)."""

    events: list[VehicleEvent]
    skipped: int = 0


def read_events(path: str | Path) -> EventLog:
    """Read a JSON-lines event file; lines cut short by a crash or a full disk are skipped and counted."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError:
        raise InputError(f"{path}: no such event file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    events, skipped = [], 0
    for lineno, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        try:
            d = json.loads(line)
        except json.JSONDecodeError:
            skipped += 1
            continue
        if not isinstance(d, dict):
            raise InputError(f"{path}:{lineno}: not a vehicle event (expected a JSON object)")
        events.append(VehicleEvent.from_dict(d, where=f"{path}:{lineno}"))
    if skipped and not events:
        raise InputError(f"{path}: not a JSON-lines event file (no line is a JSON object)")
    return EventLog(events, skipped)


def read_events_csv(path: str | Path) -> list[VehicleEvent]:
    """Read back a CSV written by :class:`CsvEventWriter` (rows cut short are skipped)."""
    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8") as f:
            rows = list(csv.DictReader(f))
    except FileNotFoundError:
        raise InputError(f"{path}: no such event file") from None
    except (OSError, csv.Error, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read CSV ({exc})") from None
    out = []
    for k, row in enumerate(rows, 2):
        if None in row or any(v is None for v in row.values()):  # wrong number of cells: a cut line
            continue
        out.append(VehicleEvent.from_dict(row, where=f"{path}:{k}"))
    return out


# --------------------------------------------------------------------------- BrnoCompSpeed results


def frames_from_times(times_s: np.ndarray, fps: float) -> np.ndarray:
    """BrnoCompSpeed frame numbers for timestamps (t·fps, snapped to integers within 1e-3 frame)."""
    f = np.asarray(times_s, dtype=np.float64) * float(fps)
    r = np.round(f)
    return np.where(np.abs(f - r) < 1e-3, r, f)


def brno_calibration(cal: Calibration | None) -> BrnoCalibration | None:
    """The ``camera_calibration`` block of ``cal`` (None without vanishing points and scale)."""
    if cal is None or cal.camera is None or cal.camera.scale is None:
        return None
    c = cal.camera
    return BrnoCalibration(tuple(map(float, c.vp1)), tuple(map(float, c.vp2)), tuple(map(float, c.pp)),
                           float(c.brno_scale()))


class BrnoResultsWriter:
    """Collects vehicles' reference-point tracks; :meth:`write` saves the BrnoCompSpeed results atomically.

    ``fps`` converts buffer timestamps (seconds) into the format's frame numbers (t·fps), which the official
    evaluation divides by the recording's fps again.  Each car is kept as its JSON text in an anonymous file beside
    the results (gone when the writer is closed, or the process ends however it ends), not in memory: a camera
    measured for a week holds no more memory on its last day than on its first.
    """

    def __init__(self, path: str | Path, fps: float) -> None:
        if not (fps > 0 and math.isfinite(fps)):
            raise InputError(f"{path}: BrnoCompSpeed results need a positive frame rate, got {fps}")
        self.path = Path(path)
        self.fps = float(fps)
        self._revised: dict[int, str | None] = {}  # vehicles measured again: their car's JSON, None to leave out
        # checked now, so that a results file that cannot be written (its folder, or a named pipe or device at the
        # path, which the rename would replace) is an error at the start, not at the end
        folder = replace_target(self.path, "BrnoCompSpeed results").parent
        try:
            folder.mkdir(parents=True, exist_ok=True)
            self._cars = tempfile.TemporaryFile(dir=folder, buffering=0)  # a car's JSON per line
        except OSError as exc:
            raise InputError(f"{self.path}: cannot write BrnoCompSpeed results there "
                             f"({exc.strerror or exc})") from None

    def add(self, vehicle_id: int, times_s: Iterable[float], points_px: Iterable[Sequence[float]]) -> bool:
        """Add one vehicle's reference points (pixels) and their timestamps; rows with NaN are dropped.

        Returns False (and adds nothing) when no finite point remains.  InputError naming the results file when
        the car cannot be held (a full disk); the cars added before are kept.
        """
        car = self._car(vehicle_id, times_s, points_px)
        if car is None:
            return False
        line = (car + "\n").encode("utf-8")
        try:
            if self._cars is None:
                raise OSError("the writer was closed")
            end = self._cars.seek(0, os.SEEK_END)
            try:
                done = 0
                while done < len(line):  # unbuffered: what failed is not written later behind our back
                    done += self._cars.write(line[done:])
            except OSError:
                self._cars.truncate(end)  # no half car
                raise
        except OSError as exc:
            raise InputError(f"{self.path}: cannot hold vehicle {vehicle_id} for the BrnoCompSpeed results "
                             f"({exc.strerror or exc}); the vehicles before it are kept") from None
        return True

    def revise(self, vehicle_id: int, times_s: Iterable[float] | None, points_px: Iterable[Sequence[float]] | None
               ) -> None:
        """A vehicle measured again (:meth:`VehicleOutputs.revise`): its car replaced by these points, or left out
        (None: no longer measured)."""
        self._revised[int(vehicle_id)] = (None if times_s is None or points_px is None
                                          else self._car(vehicle_id, times_s, points_px))

    def _car(self, vehicle_id: int, times_s: Iterable[float], points_px: Iterable[Sequence[float]]) -> str | None:
        """A car's JSON from its reference points and timestamps, rows with NaN dropped; None when none is left."""
        t = np.asarray(list(times_s), dtype=np.float64).reshape(-1)
        p = np.asarray(list(points_px), dtype=np.float64).reshape(-1, 2)
        if len(t) != len(p):
            raise ValueError(f"vehicle {vehicle_id}: {len(p)} points but {len(t)} timestamps")
        keep = np.isfinite(t) & np.all(np.isfinite(p), axis=1)
        if not keep.any():
            return None
        return car_json(Track(id=int(vehicle_id), frames=frames_from_times(t[keep], self.fps), pos=p[keep]))

    def cars(self) -> Iterator[str]:
        """The cars' JSON text, in the order they were added (revised ones replaced); ValueError, at once, when
        closed (they are gone: the file is never rewritten without them)."""
        if self._cars is None:
            raise ValueError(f"{self.path}: the BrnoCompSpeed writer was closed, its cars are gone")
        lines = self._lines(self._cars.fileno())
        if not self._revised:
            return lines
        revised = dict(self._revised)
        return (car for car in (revised.get(int(json.loads(line)["id"]), line) for line in lines) if car is not None)

    @staticmethod
    def _lines(fd: int) -> Iterator[str]:
        at, rest = 0, b""
        while chunk := os.pread(fd, 1 << 20, at):
            at += len(chunk)
            lines = (rest + chunk).split(b"\n")
            rest = lines.pop()
            yield from (car.decode("utf-8") for car in lines if car)

    def write(self, calibration: Calibration | None) -> Path:
        """Write (or rewrite) the file atomically; on failure the previous version stays and InputError says why."""
        cars = self.cars()

        def text(tmp: Path) -> None:
            with tmp.open("w", encoding="utf-8") as out:
                write_results_text(out, brno_calibration(calibration), cars,
                                   calibration.image_size if calibration is not None else None)

        atomic_write(self.path, text, "BrnoCompSpeed results")
        return self.path

    def close(self) -> None:
        """Let go of the held cars (their file is deleted); the results file stays as last written."""
        if self._cars is not None:
            self._cars.close()
            self._cars = None


def checkpoint_interval(write_s: float, minimum_s: float = 10.0, share: float = 0.01) -> float:
    """Seconds of stream between rewrites of a growing results file whose last rewrite took ``write_s`` seconds: at
    least ``minimum_s``, and long enough that rewriting costs at most ``share`` of the time.  The BrnoCompSpeed file
    holds every vehicle's reference points; rewritten every 10 s it would, after a week of a busy camera (175 000
    vehicles: 0.7 GB, about 3.5 s to write on the 2-core machine), stall the stream for a third of the time."""
    return max(float(minimum_s), float(write_s) / share)


def revise_event_file(path: str | Path, new: Mapping[tuple[str | None, int], VehicleEvent], csv_file: bool) -> int:
    """Replace, in a JSON-lines or CSV event file, each event whose (run, id) is in ``new`` by the new one; the file
    rewritten atomically (through a symlink: its target).  Returns how many lines were replaced: none when the
    events went to a named pipe or a device (/dev/null), whose lines are gone and which must not be replaced."""
    path = Path(path)
    if path.exists() and not path.is_file():
        return 0
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise InputError(f"{path}: cannot read it to revise its vehicles ({exc.strerror or exc})") from None
    lines, done = text.splitlines(keepends=True), 0
    if csv_file:
        header = next(csv.reader(lines[:1]), [])
        col = {name: k for k, name in enumerate(header)}
        if "id" not in col:
            return 0
        for k in range(1, len(lines)):
            row = next(csv.reader([lines[k]]), [])
            if len(row) != len(header):
                continue
            key = (row[col["run"]] or None if "run" in col else None, _opt_int(row[col["id"]]))
            if key in new:
                d = new[key].to_dict()
                row = [d[name] if name in d else row[j] for j, name in enumerate(header)]
                lines[k] = CsvEventWriter._row(row)
                done += 1
    else:
        for k, line in enumerate(lines):
            try:
                d = json.loads(line)
                key = (d.get("run"), int(d["id"]))
            except (ValueError, KeyError, TypeError):
                continue
            if key in new:
                extra = {f: v for f, v in d.items() if f not in EVENT_FIELDS}
                lines[k] = JsonlEventWriter.line(new[key], extra) + "\n"
                done += 1
    if done:
        atomic_write_text(path, "".join(lines), "vehicle events")
    return done


class VehicleOutputs:
    """Every per-vehicle output of a run behind one object (what ``speedometer`` and ``trafficcal run`` use).

    ``vehicle()`` writes the event to the JSONL/CSV files at once and keeps the reference points for the
    BrnoCompSpeed file, which ``close(calibration)`` writes atomically at the end (``checkpoint`` any time
    before). Any path may be None (that output is skipped). Errors are InputError naming the file, raised
    only after every other output got its data.
    """

    def __init__(self, events_jsonl: str | Path | None = None, events_csv: str | Path | None = None,
                 brno_json: str | Path | None = None, fps: float | None = None, append: bool = False,
                 fsync: bool = True, lazy: bool = False) -> None:
        if brno_json is not None and fps is None:
            raise InputError(f"{brno_json}: BrnoCompSpeed results need the video's frame rate")
        self.brno = BrnoResultsWriter(brno_json, fps) if brno_json is not None else None
        self.events = EventWriters.open(events_jsonl, events_csv, append, fsync, lazy=lazy)
        self.count = 0
        self.started = not lazy  # lazy: the files of an earlier run stay as they are until begin()

    def begin(self) -> None:
        """The run has really started (its video arrives): the event files are emptied, and closing writes the
        BrnoCompSpeed file.  A pipeline that fails before this (a missing input, an unreachable camera) leaves the
        files of the run before as they were."""
        self.started = True
        self.events.begin()

    def vehicle(self, event: VehicleEvent, times_s: Iterable[float] | None = None,
                points_px: Iterable[Sequence[float]] | None = None) -> None:
        """One vehicle that left: its event and (for BrnoCompSpeed) its reference points and timestamps."""
        self.started = True
        self.count += 1
        steps = [lambda: self.events.write(event)]
        if self.brno is not None and times_s is not None and points_px is not None:
            steps.insert(0, lambda: self.brno.add(event.id, times_s, points_px))
        attempt_all(steps)

    def revise(self, measured: Sequence[tuple[VehicleEvent, np.ndarray | None, np.ndarray | None]]) -> None:
        """Vehicles measured again at the end (``SpeedMeter.remeasure``): each one's line in the event files
        replaced in place — the line of the same ``run`` and ``id``; other runs' lines and any line that does not
        parse stay as they are — each file rewritten atomically, and its car in the BrnoCompSpeed results replaced.
        Closes the event writers first (nothing may be written after). InputError naming a file that could not be
        rewritten; that file then keeps the first measurement."""
        if not measured:
            return
        new = {(e.run, e.id): e for e, _, _ in measured}
        if self.brno is not None:
            for e, times, points in measured:
                self.brno.revise(e.id, times if e.measured else None, points if e.measured else None)
        self.events.close()
        attempt_all(lambda w=w: revise_event_file(w.path, new, isinstance(w, CsvEventWriter))
                    for w in self.events.writers)

    def checkpoint(self, calibration: Calibration | None) -> None:
        """Rewrite the BrnoCompSpeed file now (atomically) with what has been collected."""
        if self.brno is not None:
            self.brno.write(calibration)

    def close(self, calibration: Calibration | None) -> None:
        """Write the BrnoCompSpeed file (once the run started) and close the event files (both attempted even if
        one fails)."""
        attempt_all((lambda: self.checkpoint(calibration) if self.started else None, self.events.close,
                     self.brno.close if self.brno is not None else lambda: None))


# --------------------------------------------------------------------------- per-frame JSON (gvametaconvert's shape)


def frame_record(rois: Iterable[Any], frame_size: tuple[int, int], timestamp_s: float | None,
                 source: str = "") -> dict[str, Any]:
    """One frame's vehicles in the JSON shape of DL Streamer's ``gvametaconvert``.

    ``rois`` are ``gst.meta.RoiRecord``-like objects (``meta_id``, ``label``, ``box`` pixels, ``confidence``,
    ``label_id``, ``object_id``, ``params``). Each object carries ``detection`` {``bounding_box`` normalised
    ``x_min``.. ``y_max``, ``confidence``, ``label``, ``label_id``}, the clipped integer ``x, y, w, h``,
    ``region_id``, ``roi_type``, ``id`` (track id) when tracked, and every further parameter structure under its
    own name (e.g. ``"speed"``, ``"trafficcal-vehicle"``). ``timestamp`` is the PTS in nanoseconds.
    """
    w, h = int(frame_size[0]), int(frame_size[1])
    objects = []
    for r in rois:
        x0, y0, x1, y1 = (float(v) for v in r.box)
        cx0, cy0 = min(max(x0, 0.0), w), min(max(y0, 0.0), h)
        cx1, cy1 = min(max(x1, 0.0), w), min(max(y1, 0.0), h)
        obj: dict[str, Any] = {
            "detection": {"bounding_box": {"x_min": cx0 / w, "y_min": cy0 / h, "x_max": cx1 / w, "y_max": cy1 / h},
                          "confidence": float(r.confidence), "label": str(r.label), "label_id": int(r.label_id)},
            "x": int(round(cx0)), "y": int(round(cy0)), "w": int(round(cx1 - cx0)), "h": int(round(cy1 - cy0)),
            "region_id": int(r.meta_id), "roi_type": str(r.label),
        }
        if r.object_id is not None:
            obj["id"] = int(r.object_id)
        for name, fields in r.params.items():
            if name not in ("detection", "object_id"):
                obj[name] = _json_safe(fields)
        objects.append(obj)
    out: dict[str, Any] = {"objects": objects, "resolution": {"height": h, "width": w}}
    if source:
        out["source"] = source
    if timestamp_s is not None:
        out["timestamp"] = int(round(timestamp_s * 1e9))
    return out


def _json_safe(v: Any) -> Any:
    """Plain JSON values (NaN/inf -> None, numpy -> Python)."""
    if isinstance(v, dict):
        return {str(k): _json_safe(x) for k, x in v.items()}
    if isinstance(v, (list, tuple, np.ndarray)):
        return [_json_safe(x) for x in v]
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


class FrameJsonlWriter:
    """Per-frame JSON lines in gvametaconvert's shape (:func:`frame_record`), one line per frame, synced like
    the event files (``fsync`` off by default: a line per frame)."""

    def __init__(self, path: str | Path, append: bool = False, fsync: bool = False,
                 skip_empty: bool = False, lazy: bool = False) -> None:
        self._file = _LineFile(path, append, fsync, lazy)
        self.path = self._file.path
        self.skip_empty = skip_empty
        self.count = 0

    def begin(self) -> None:
        self._file.begin()

    def write(self, rois: Iterable[Any], frame_size: tuple[int, int], timestamp_s: float | None,
              source: str = "") -> None:
        record = frame_record(rois, frame_size, timestamp_s, source)
        if self.skip_empty and not record["objects"]:
            return
        self._file.write_line(json.dumps(record, separators=(",", ":")))
        self.count += 1

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> "FrameJsonlWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
