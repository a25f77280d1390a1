"""A long run's state on disk, for monitoring: ``trafficcal run`` keeps ``--out/status.json`` up to date.

A camera measured for days runs unattended (a service, a container): whoever watches it — a monitoring system, an
operator's script, a video-management system — needs to know without reading logs whether the stream is connected,
whether the pipeline keeps up with the camera, whether the calibration is complete and when the last vehicle
passed. :class:`StatusFile` holds that as one JSON object and rewrites it atomically at most every ``every_s``
seconds while the run goes on (a reader never sees half a file), and at once when the state changes.

Fields (``STATUS_FIELDS``; null where unknown): ``state`` (starting, running, reconnecting, finished, interrupted,
failed), ``source`` (the input; a URI without its password), ``part`` / ``parts_done`` (the file or connection
being measured, and how many are done), ``position_s`` / ``duration_s`` (stream seconds; no duration for a live
stream), ``speed_x`` (stream seconds measured per wall-clock second since the last update; in the final states, over
the whole run), ``frames`` /
``frames_dropped`` (the frames that reached the analysis, and those a live stream dropped because the
machine could not keep up: a live camera does not wait), ``calibration`` (``state``, ``id``, ``source``,
``scale_m`` of the calibration in force), ``orientation`` (how the picture is turned: ``--orientation``),
``vehicles`` / ``measured`` (finished vehicles and those with a speed, the whole run), ``last_vehicle_s`` (the
stream time the last one left), ``last_vehicle_at``, ``camera_moves``, ``warnings`` (the last five),
``error`` (the last failure), ``next_attempt_at`` (when reconnecting), ``stream_lost_at`` (since when a live stream
is being connected again), ``started_at``, ``state_since``,
``updated_at`` (ISO 8601 with the UTC offset), ``pid`` and ``host`` of the process.  :func:`health` judges a status
as a health check would (``trafficcal status``).  A failure to write it is reported once and never stops the
measurement.
"""

from __future__ import annotations

import json
import os
import socket
import time
import types
import typing
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

from .errors import InputError
from .fileio import atomic_write_text

STATES = ("starting", "running", "reconnecting", "finished", "interrupted", "failed")


def now_iso() -> str:
    """This machine's clock with its UTC offset, to the millisecond."""
    return datetime.now().astimezone().isoformat(timespec="milliseconds")


@dataclass
class RunStatus:
    """The record written to status.json (see the module doc)."""

    source: str = ""
    state: str = "starting"
    part: str = ""
    parts_done: int = 0
    position_s: float | None = None
    duration_s: float | None = None
    speed_x: float | None = None
    frames: int = 0  # frames that reached the analysis (all parts)
    frames_dropped: int = 0  # of those, dropped to stay in real time
    calibration: dict[str, Any] | None = None
    orientation: str = "auto"  # --orientation: how the picture was turned (auto: as the video says)
    vehicles: int = 0
    measured: int = 0
    last_vehicle_s: float | None = None
    last_vehicle_at: str | None = None
    camera_moves: int = 0
    warnings: list[str] = field(default_factory=list)
    error: str = ""
    next_attempt_at: str | None = None
    stream_lost_at: str | None = None  # since when a live stream is being connected again (null while running)
    started_at: str = field(default_factory=now_iso)
    state_since: str = field(default_factory=now_iso)  # when ``state`` last changed
    updated_at: str = ""
    pid: int = field(default_factory=os.getpid)
    host: str = field(default_factory=socket.gethostname)


STATUS_FIELDS = tuple(RunStatus.__dataclass_fields__)
REQUIRED_FIELDS = ("state", "updated_at")  # every status.json has had these


def calibration_fields(cal) -> dict[str, Any]:
    """What status.json says about a :class:`~gst_trafficcal.calibration.Calibration`; ``speed_sensitivity_pct``:
    how much the speeds change under a 0.1° error of VP2 (vanishing/conditioning.py; None before the vanishing
    points or when unbounded)."""
    scale = cal.camera.scale if cal.camera is not None else None
    sensitivity = cal.conditioning().to_dict()["speed_pct"] if cal.camera is not None else None
    return {"state": cal.state, "id": cal.id, "source": cal.source,
            "scale_m": None if scale is None else round(float(scale), 4), "speed_sensitivity_pct": sensitivity}


class StatusFile:
    """Keeps ``path`` holding the :class:`RunStatus` of a run; ``every_s``: least wall time between rewrites while
    nothing but the position and counts changed.  ``warn(text)`` is told once when the file cannot be written."""

    def __init__(self, path: str | Path, source: str, every_s: float = 5.0,
                 warn: Callable[[str], None] | None = None, clock: Callable[[], float] = time.monotonic) -> None:
        if every_s <= 0:
            raise InputError(f"the status file's interval must be positive, got {every_s:g} s")
        self.path, self.every_s, self.warn, self.clock = Path(path), float(every_s), warn, clock
        self.status = RunStatus(source=source)
        self._written_at: float | None = None
        self._rate_from: tuple[float, float] | None = None  # (wall, position) at the last rate update
        self._began = clock()  # when the run began (wall): the final speed_x is over the whole run
        self._stream_s = 0.0  # stream seconds measured in all (every part)
        self._last_position: float | None = None
        self._failed = False
        self.write()

    def update(self, force: bool = False, **changes: Any) -> None:
        """Change fields (a new ``state`` is written at once, other changes when ``every_s`` has passed)."""
        unknown = set(changes) - set(STATUS_FIELDS)
        if unknown:
            raise TypeError(f"unknown status fields: {', '.join(sorted(unknown))}")
        if "state" in changes and changes["state"] not in STATES:
            raise ValueError(f"state must be one of {', '.join(STATES)}, got {changes['state']!r}")
        new_state = changes.get("state", self.status.state)
        if new_state != self.status.state:
            force = True
            self.status.state_since = now_iso()
            if new_state == "reconnecting" and self.status.stream_lost_at is None:
                self.status.stream_lost_at = self.status.state_since
            elif new_state == "running":
                self.status.stream_lost_at = None
        for name, value in changes.items():
            setattr(self.status, name, value)
        if new_state in FINAL_STATES:  # the last interval's rate said nothing of the run (0.008 after a failure)
            self.status.speed_x = self.overall_speed_x()
        if force or self._written_at is None or self.clock() - self._written_at >= self.every_s:
            self.write()

    def overall_speed_x(self) -> float | None:
        """Stream seconds measured per wall-clock second over the whole run so far (None before any)."""
        wall = self.clock() - self._began
        return round(self._stream_s / wall, 3) if self._stream_s > 0 and wall > 0 else None

    def position(self, position_s: float, duration_s: float | None) -> None:
        """The stream position now (the rate ``speed_x`` follows from it)."""
        now = self.clock()
        last, self._last_position = self._last_position, position_s
        # (back to an earlier position: a new part, measured from its start)
        self._stream_s += position_s - last if last is not None and position_s >= last else max(position_s, 0.0)
        if self._rate_from is None or position_s < self._rate_from[1]:
            self._rate_from = (now, position_s)
        elif now - self._rate_from[0] >= min(self.every_s, 5.0):
            self.status.speed_x = round((position_s - self._rate_from[1]) / (now - self._rate_from[0]), 3)
            self._rate_from = (now, position_s)
        self.update(position_s=round(position_s, 3), duration_s=duration_s, state="running")

    def vehicle(self, t_s: float | None, measured: bool) -> None:
        """A vehicle finished (stream time ``t_s`` it left)."""
        self.update(vehicles=self.status.vehicles + 1, measured=self.status.measured + bool(measured),
                    last_vehicle_s=t_s, last_vehicle_at=now_iso())

    def warning(self, text: str) -> None:
        self.update(warnings=(self.status.warnings + [text])[-5:])

    def write(self) -> None:
        """Rewrite the file now (atomically)."""
        self.status.updated_at = now_iso()
        self._written_at = self.clock()
        try:
            atomic_write_text(self.path, json.dumps(asdict(self.status), indent=1) + "\n", "the run's status")
        except InputError as exc:
            if not self._failed and self.warn is not None:
                self.warn(f"{exc}; the run goes on without it")
            self._failed = True


def read_status(path: str | Path) -> RunStatus:
    """A status.json read back (fields it lacks keep their defaults; unknown ones are ignored); InputError for a file
    that is not one: not JSON, no ``state`` or ``updated_at``, a field of the wrong type, a state not in ``STATES``."""
    from .fileio import read_json

    data = read_json(path, "run's status")
    if not isinstance(data, dict):
        raise InputError(f"{path}: not a run's status (a JSON object expected)")
    missing = [name for name in REQUIRED_FIELDS if name not in data]
    if missing:  # another JSON file (a calibration.json given by mistake): no status, not a hung run
        raise InputError(f"{path}: not a run's status (no {' or '.join(missing)}; trafficcal run writes status.json "
                         "in its --out)")
    data.setdefault("state_since", data.get("updated_at", ""))  # files of an earlier version: no such fields
    data.setdefault("host", "")
    fields = {k: v for k, v in data.items() if k in STATUS_FIELDS}
    hints = typing.get_type_hints(RunStatus)
    for name, value in fields.items():
        if not _of_type(value, hints[name]):
            shown = json.dumps(value)[:60]
            raise InputError(f"{path}: not a run's status ({name} is {shown}, not {_named(hints[name])})")
    if fields["state"] not in STATES:  # read as "dancing since ..." and counted in no trafficcal_state series
        shown = json.dumps(fields["state"])[:60]
        raise InputError(f"{path}: not a run's status (state is {shown}, not one of {', '.join(STATES)})")
    return RunStatus(**fields)


def _named(hint: Any) -> str:
    """A type hint as the JSON it stands for: 'a number or null'."""
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return " or ".join(_named(arg) for arg in typing.get_args(hint))
    names = {int: "a whole number", float: "a number", str: "a string", list: "a list", dict: "an object",
             type(None): "null"}
    return names.get(typing.get_origin(hint) or hint, str(hint))


def _of_type(value: Any, hint: Any) -> bool:
    """Whether a JSON value fits a RunStatus field's type hint (numbers: not booleans)."""
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return any(_of_type(value, arg) for arg in typing.get_args(hint))
    if hint is type(None) or hint is Any:
        return value is None or hint is Any
    if hint in (int, float):
        return isinstance(value, (int, float) if hint is float else int) and not isinstance(value, bool)
    if typing.get_origin(hint) is list:
        return isinstance(value, list) and all(_of_type(v, typing.get_args(hint)[0]) for v in value)
    return isinstance(value, typing.get_origin(hint) or hint)


FINAL_STATES = ("finished", "interrupted", "failed")
CLOCK_SKEW_S = 5.0  # how far in the future a status's updated_at may lie before the clocks are said to differ


def age_s(iso: str | None, now: datetime) -> float | None:
    """Seconds from the ISO 8601 time ``iso`` to ``now`` (None when there is no readable time; negative when ``iso``
    lies after ``now``: the clock that wrote it is ahead)."""
    try:
        return (now - datetime.fromisoformat(iso)).total_seconds()
    except (TypeError, ValueError):
        return None


def dated_ahead(age: float | None) -> bool:
    """Whether a status of age ``age`` (:func:`age_s`) lies more than :data:`CLOCK_SKEW_S` in the future: the clock
    that wrote it is ahead, so its age says nothing."""
    return age is not None and age < -CLOCK_SKEW_S


def _process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: it exists
        return True
    return True


def process_started(pid: int) -> float | None:
    """When process ``pid`` of this machine started (seconds since the epoch, to a second: /proc's start time after
    boot plus the boot time), None where /proc does not tell."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        ticks = int(stat[stat.rindex(")") + 2:].split()[19])  # field 22, starttime (the name may hold spaces)
        boot = next(int(line.split()[1]) for line in Path("/proc/stat").read_text().splitlines()
                    if line.startswith("btime "))
        return boot + ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError, StopIteration):
        return None


def _run_alive(status: RunStatus) -> bool:
    """Whether the process of ``status`` (of this machine) still runs: its pid is taken, and not by a process started
    after the run did — after a crash or a reboot the number goes to another process, and the run restarted into
    the same --out was refused for good ("another run is writing there") while that process lived."""
    if not status.pid or not _process_alive(status.pid):
        return False
    started, run_started = process_started(status.pid), None
    try:
        run_started = datetime.fromisoformat(status.started_at).timestamp()
    except (TypeError, ValueError):
        pass
    # (the run's process starts before it writes started_at; /proc's boot time is whole seconds: 2 s of slack)
    return started is None or run_started is None or started <= run_started + 2.0


def still_running(status: RunStatus, now: datetime | None = None, max_age_s: float = 60.0) -> bool:
    """Whether the run that wrote ``status`` is still going: not ended, and its process alive — on this machine
    checked, on another (a shared folder) taken at its word while the file is younger than ``max_age_s``."""
    if status.state in FINAL_STATES:
        return False
    if status.host == socket.gethostname():
        return bool(status.pid) and status.pid != os.getpid() and _run_alive(status)
    age = age_s(status.updated_at, now or datetime.now().astimezone())
    return age is not None and age <= max_age_s


def health(status: RunStatus, max_age_s: float = 60.0, now: datetime | None = None) -> list[str]:
    """Why ``status`` is not healthy (empty: healthy), as a container or service health check asks.

    Unhealthy: the run failed; a run not ended whose file was not updated for ``max_age_s`` (the process hangs or
    is gone) or whose process is gone (checked on the machine that wrote it); a stream lost (reconnecting) for
    longer than ``max_age_s``; ``updated_at`` more than ``CLOCK_SKEW_S`` in the future (the writer's clock is ahead:
    its age, so whether it hangs, cannot be told — in an ended run's status too: a file from another machine's
    clock, or one written after this machine's clock was set back, whose times cannot be trusted).  A run that
    finished or was interrupted ended as it should: healthy."""
    now = now or datetime.now().astimezone()
    why = []
    if status.state == "failed":
        why.append(f"the run failed: {status.error or 'no reason recorded'}")
    age = age_s(status.updated_at, now)
    ahead = dated_ahead(age)
    if ahead:
        clocks = ("this machine's clock was set back since" if status.host == socket.gethostname() else
                  f"the clocks of the writer{f' ({status.host})' if status.host else ''} and this machine differ")
        doubt = ("its times cannot be trusted" if status.state in FINAL_STATES else
                 "whether the run hangs cannot be told")
        why.append(f"updated_at lies {-age:.0f} s in the future: {clocks}; {doubt}")
    if status.state in FINAL_STATES:
        return why
    if not ahead and (age is None or age > max_age_s):
        why.append("status not updated for " + ("an unknown time" if age is None else f"{age:.0f} s") +
                   f" (more than {max_age_s:g} s): the run hangs or is gone")
    if status.host == socket.gethostname() and status.pid and not _run_alive(status):
        why.append(f"process {status.pid} is not running any more")
    lost = age_s(status.stream_lost_at, now) if status.stream_lost_at else None
    if status.state in ("reconnecting", "starting") and lost is not None and lost > max_age_s:
        why.append(f"no stream for {lost:.0f} s ({status.error or 'connection lost'}); still trying")
    return why
