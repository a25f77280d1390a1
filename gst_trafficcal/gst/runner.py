"""Run a complete ``gst-launch``-style pipeline in-process, with progress, calibration and clear errors.

What ``trafficcal run`` and ``trafficcal demo`` use instead of a ``gst-launch-1.0`` subprocess: the same
pipeline description through ``Gst.parse_launch``, a bus loop that reports the stream position and duration
(for a progress bar), collects every ``trafficcal-calibration`` message (the calibration the run ended with)
and the elements' own messages, and turns an ERROR into :class:`PipelineError` with the element's words.
Our elements must be findable: :func:`ensure_elements` puts ``elements/`` on the plugin path of this process.

    outcome = run_pipeline_file(description, progress=lambda pos, dur: ...)
    outcome.calibration, outcome.messages, outcome.warnings

A run may last weeks (a live camera): of the elements' messages — several per vehicle — the outcome keeps only the
latest :data:`MESSAGES_KEPT`; ``on_message`` sees every one (count or sum there what must cover the whole run).  Of
the calibrations posted before the last camera move it keeps what its answers need (:meth:`RunOutcome.add`), and
each kind of warning once (:meth:`RunOutcome.warn`).
"""

from __future__ import annotations

import re
import signal
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

from ..calibration import Calibration, latest_per_view, same_vanishing_points
from ._gi import Gst
from .calibration_event import parse_calibration_message
from .element import register_plugin_file
from .env import elements_dir
from .meta import structure_to_dict
from .pipeline import BusMessage, PipelineError

__all__ = ["Move", "PipelineError", "RunFailed", "RunOutcome", "ensure_elements", "missing_elements",
           "run_pipeline_file"]

Progress = Callable[[float, "float | None"], None]

MESSAGES_KEPT = 1000  # element messages an outcome keeps, the latest (a busy road's day posts 50 000 and more)
MOVES_KEPT = 20  # camera moves an outcome keeps in full, the latest (a PTZ camera on patrol moves hundreds of times a
# day, 1-2 kB each with the calibrations around it); the earlier ones are counted (RunOutcome.moves_earlier)


class Move(NamedTuple):
    """A camera move vpdetect announced during a run."""

    t: float  # when the camera moved (stream seconds)
    before: Calibration | None  # the calibration with a scale in force until then, if any
    known: Calibration | None = None  # the calibration of a view seen before, taken up again (None: learnt anew)


@dataclass
class _Folded:
    """What the calibrations posted before the last camera move leave for :class:`RunOutcome`'s answers: the moves
    (their calibrations without their view pictures), the calibration with a scale in force at the end, every view's
    vanishing points, and the last calibration with a scale and a view of each view (with its picture: saved for the
    next part).  Bounded by the camera's views and :data:`MOVES_KEPT`, however many calibrations were posted and
    however often the camera moved: of the moves before the latest ones only how many, the first's and the last's
    time are kept (``earlier``)."""

    moves: list[Move] = field(default_factory=list)
    earlier: tuple[int, float | None, float | None] = (0, None, None)  # moves not kept: (count, first t, last t)
    before: Calibration | None = None
    seen: list[Calibration] = field(default_factory=list)  # one per vanishing points, without its view picture
    scaled: list[Calibration] = field(default_factory=list)  # one per view: latest_per_view


def _without_view(cal: Calibration | None) -> Calibration | None:
    return cal if cal is None or cal.view is None else replace(cal, view=None)


def _moves(cals: Iterable[Calibration], out: list[Move], before: Calibration | None
           ) -> tuple[list[Move], Calibration | None]:
    """:attr:`RunOutcome.moves` on from ``out`` (a copy is extended) and ``before`` (the calibration with a scale in
    force) over ``cals``; the moves and the calibration with a scale in force after them."""
    out = list(out)
    for c in cals:
        if c.moved_at is not None:
            known = c if c.camera is not None else None
            if not out or out[-1].t != c.moved_at:  # the same news passed on by several elements
                out.append(Move(float(c.moved_at), before, known))
            elif known is not None and (out[-1].known is None or known.camera.scale is not None):
                out[-1] = out[-1]._replace(known=known)
            before = known if known is not None and known.camera.scale is not None else None
        elif c.camera is not None and c.camera.scale is not None:
            before = c
    return out, before


def _latest_moves(moves: list[Move], earlier: tuple[int, float | None, float | None]
                  ) -> tuple[list[Move], tuple[int, float | None, float | None]]:
    """The latest :data:`MOVES_KEPT` of ``moves`` and the count and times of those before them, on from
    ``earlier`` (the ones left out already)."""
    cut = len(moves) - MOVES_KEPT
    if cut <= 0:
        return moves, earlier
    n, first, _ = earlier
    return moves[cut:], (n + cut, moves[0].t if first is None else first, moves[cut - 1].t)


@dataclass
class RunOutcome:
    """What the bus said during a run that reached end-of-stream."""

    # (element name, calibration): those since the last camera move when posted through add — the earlier ones are
    # folded into what the answers below need (a PTZ camera on patrol posts a few per move, 12 kB each with its view
    # picture: kept, they grew a run by 9 MB a day); all when given whole
    calibrations: list[tuple[str, Calibration]] = field(default_factory=list)
    # other element messages, in order: the latest MESSAGES_KEPT (every one kept grew a run's memory by about 3 kB
    # per vehicle without end; on_message of run_pipeline_file sees them all)
    messages: deque[BusMessage] = field(default_factory=lambda: deque(maxlen=MESSAGES_KEPT))
    # the elements' warnings, each kind once: a warning like one before (the same words, other numbers: a PTZ camera's
    # every move) is counted into the first one's line (see warn)
    warnings: list[str] = field(default_factory=list)
    position_s: float | None = None  # last position seen
    duration_s: float | None = None
    stopped: str = ""  # why the run ended before the stream did ("interrupted", "duration"); "" at the stream's end
    stopped_by: str = ""  # "interrupted": the signal that did it: "SIGINT" (Ctrl-C), "SIGTERM" (a service stopped) or
    # "SIGHUP" (the terminal that started it closed: an SSH session ended)
    live: bool = False  # the source was live (a camera): it does not wait for us
    frames_in: int = 0  # frames that reached the live queue (see run_pipeline_file's ``live_queue``), live or not
    frames_dropped: int = 0  # of those, dropped to keep up with a live source (never from a file)
    _kinds: dict[str, list] = field(default_factory=dict, init=False, repr=False)  # warn's: kind -> [line, first, n]
    _folded: _Folded = field(default_factory=_Folded, init=False, repr=False)  # calibrations before the last move

    def add(self, element: str, cal: Calibration) -> None:
        """A calibration posted by ``element``.  At a camera move the ones before are folded (:class:`_Folded`):
        the answers stay those of every calibration posted, the memory that of the views and the moves."""
        if cal.moved_at is not None and self.calibrations:
            f, cals = self._folded, [c for _, c in self.calibrations]
            moves, before = _moves(cals, f.moves, f.before)
            f.moves, f.earlier = _latest_moves(moves, f.earlier)
            f.moves = [Move(m.t, _without_view(m.before), _without_view(m.known)) for m in f.moves]
            f.before = _without_view(before)
            for c in cals:
                if c.camera is not None:
                    f.seen = latest_per_view(f.seen, _without_view(c))
                if c.camera is not None and c.camera.scale is not None and c.view is not None:
                    f.scaled = latest_per_view(f.scaled, c)
            self.calibrations = []
        self.calibrations.append((element, cal))

    @property
    def calibration(self) -> Calibration | None:
        """The calibration the run ended with: the last one posted, preferring one with a scale (the one
        speedometer measured with) over a later one without; when the camera moved, one of the new view only."""
        cals = [c for _, c in self.calibrations]
        moved = [i for i, c in enumerate(cals) if c.moved_at is not None]
        if moved:  # the new view's: not the old one's, even if an element further down posted it a little later
            old = self._folded.seen + [c for c in cals[:moved[-1]] if c.camera is not None]
            t = cals[moved[-1]].moved_at  # (a view seen before and taken up again carries the move itself)
            cals = [c for c in cals[moved[-1]:]
                    if c.moved_at == t or not any(same_vanishing_points(c, o) for o in old)]
        if not cals:
            return None
        with_scale = [c for c in cals if c.camera is not None and c.camera.scale is not None]
        return with_scale[-1] if with_scale else cals[-1]

    @property
    def moves(self) -> list[Move]:
        """The latest :data:`MOVES_KEPT` times the camera moved (:attr:`moves_earlier` counts the others): when, the
        calibration with a scale in force before, and the known view's calibration vpdetect took up again (the one
        with the most said about it, e.g. bbscale's with the scale)."""
        return self._moves_and_earlier()[0]

    @property
    def moves_earlier(self) -> tuple[int, float | None, float | None]:
        """The moves before :attr:`moves`, not kept: how many, when the first and the last of them were (None, None
        when there are none)."""
        return self._moves_and_earlier()[1]

    def _moves_and_earlier(self) -> tuple[list[Move], tuple[int, float | None, float | None]]:
        moves = _moves((c for _, c in self.calibrations), self._folded.moves, self._folded.before)[0]
        return _latest_moves(moves, self._folded.earlier)

    @property
    def scaled_views(self) -> list[Calibration]:
        """The last calibration with a scale and a view posted for each view (vanishing points) in the run."""
        out = list(self._folded.scaled)
        for _, c in self.calibrations:
            if c.camera is not None and c.camera.scale is not None and c.view is not None:
                out = latest_per_view(out, c)
        return out

    def warn(self, text: str) -> None:
        """Add a warning to ``warnings``: one of a kind not seen yet as it is; one like an earlier one (the same
        text but for its numbers and names with digits) only counted into that one's line, which then ends with how
        many more there were and the last of them.  So a run that lasts weeks keeps one line per kind of warning,
        and prints them once (a PTZ camera on patrol warned once per move).  The element that warned (the text's
        first word, before ": ") is kept as it is: vpdetect0's warnings and vpdetect1's (two cameras in one
        pipeline) are kinds of their own, not one line counting both."""
        source, sep, words = text.partition(": ")
        kind = f"{source}{sep}{_NUMBERS.sub('#', words)}" if sep and " " not in source else _NUMBERS.sub("#", text)
        seen = self._kinds.get(kind)
        if seen is None:
            self._kinds[kind] = [len(self.warnings), text, 1]
            self.warnings.append(text)
            return
        seen[2] += 1
        self.warnings[seen[0]] = f"{seen[1]} (and {seen[2] - 1} more like it, the last: {text})"

    def named(self, name: str) -> list[dict[str, Any]]:
        """The fields of every element message with structure ``name`` among those kept (the latest
        :data:`MESSAGES_KEPT`)."""
        return [m.fields for m in self.messages if m.name == name]


_NUMBERS = re.compile(r"[\w.+\-]*\d[\w.+\-]*")  # what tells warnings of one kind apart: numbers, ids, times


class RunFailed(PipelineError):
    """An element posted an ERROR; ``outcome`` holds what the bus said before it."""

    def __init__(self, text: str, outcome: RunOutcome) -> None:
        super().__init__(text)
        self.outcome = outcome


_registered = False
_broken: dict[str, str] = {}  # plugin file stem -> why it could not be loaded


def ensure_elements() -> None:
    """Register every element of ``elements/python/`` in this process, once (no plugin-path set-up needed).

    A plugin file that fails to import does not stop the others; a pipeline that names it then fails with
    the import error in its message.
    """
    global _registered
    if _registered:
        return
    for path in sorted((elements_dir() / "python").glob("*.py")):
        try:
            register_plugin_file(path)
        except Exception as exc:  # noqa: BLE001 -- reported when a pipeline uses the element
            _broken[path.stem] = f"{path.name}: {type(exc).__name__}: {exc}"
    _registered = True


def missing_elements(names: Iterable[str]) -> list[str]:
    """Those of ``names`` that no installed GStreamer plugin provides."""
    ensure_elements()
    return [n for n in names if Gst.ElementFactory.find(n) is None]


WRITE_ERRORS = (Gst.ResourceError.WRITE, Gst.ResourceError.NO_SPACE_LEFT, Gst.ResourceError.OPEN_WRITE,
                Gst.ResourceError.CLOSE)


def _error_text(msg: Gst.Message) -> str:
    err, debug = msg.parse_error()
    src = msg.src.get_name() if msg.src else "pipeline"
    text = f"{src}: {err.message}"
    location = msg.src.get_property("location") if msg.src and msg.src.find_property("location") else None
    if location and any(err.matches(Gst.ResourceError.quark(), code) for code in WRITE_ERRORS):
        # a sink that cannot write (a full disk: the overlay video): which file, and why — GStreamer's words say
        # neither ("Could not write to resource.")
        why = err.message.rstrip(".")
        if debug and "Error while writing" in debug:
            why = debug.rsplit(": ", 1)[-1].strip()
        text = f"{src}: {location}: cannot write ({why})"
    if err.matches(Gst.StreamError.quark(), Gst.StreamError.TYPE_NOT_FOUND) or \
            err.matches(Gst.StreamError.quark(), Gst.StreamError.WRONG_TYPE) or \
            err.matches(Gst.StreamError.quark(), Gst.StreamError.DEMUX) or \
            err.matches(Gst.StreamError.quark(), Gst.StreamError.CODEC_NOT_FOUND):
        text += " (not a video this GStreamer can decode)"
    return text


def _query_time(pipeline: Gst.Element, what: str) -> float | None:
    ok, value = (pipeline.query_position if what == "position" else pipeline.query_duration)(Gst.Format.TIME)
    return value / Gst.SECOND if ok and value >= 0 else None


def _end_stream_at(pad: Gst.Pad, seconds: float, on_end: Callable[[], None]) -> None:
    """Make ``pad`` end the stream at the first buffer ``seconds`` after the first one: that buffer and every later
    one are dropped, and an end-of-stream goes in their place (upstream then stops with flow EOS)."""
    state: dict[str, Any] = {"t0": None, "ended": False}

    def probe(pad: Gst.Pad, info: Gst.PadProbeInfo) -> Gst.PadProbeReturn:
        buf = info.get_buffer()
        if buf is None or buf.pts == Gst.CLOCK_TIME_NONE:
            return Gst.PadProbeReturn.OK
        if state["t0"] is None:
            state["t0"] = buf.pts
        if state["ended"]:
            return Gst.PadProbeReturn.DROP
        if (buf.pts - state["t0"]) / Gst.SECOND >= seconds - 1e-6:
            state["ended"] = True
            on_end()
            pad.send_event(Gst.Event.new_eos())
            return Gst.PadProbeReturn.DROP
        return Gst.PadProbeReturn.OK

    pad.add_probe(Gst.PadProbeType.BUFFER, probe)


#: the signals that end a run as the end of the stream would: Ctrl-C; a service stopped (systemctl, docker, Kubernetes);
#: the terminal that started the run closed (an SSH session ended: the run, killed at once before, left status.json
#: saying "running")
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

LIVE_QUEUE_BUFFERS = 25  # frames a live run's queue holds (a second at 25 fps) before it drops the oldest


def _count_through(queue: Gst.Element) -> Callable[[], tuple[int, int]]:
    """Count the buffers into ``queue`` and those it dropped: a function giving (in, dropped) so far.

    A leaky queue drops its oldest frames, so the frames that went in before one coming out and never came out
    themselves were dropped.  The frames are known by their timestamps, noted as they go in (frames without one all
    look alike: their drops go uncounted).  So the counts only ever grow, whichever streaming thread moves while
    they are read: in - out - queued, read while two threads change them, could be one off for a moment."""
    lock = threading.Lock()
    waiting: deque[int] = deque(maxlen=4096)  # timestamps of the frames gone in and not yet out or dropped
    counts = [0, 0]  # in, dropped

    def went_in(_pad: Gst.Pad, info: Gst.PadProbeInfo) -> Gst.PadProbeReturn:
        with lock:
            counts[0] += 1
            waiting.append(info.get_buffer().pts)
        return Gst.PadProbeReturn.OK

    def came_out(_pad: Gst.Pad, info: Gst.PadProbeInfo) -> Gst.PadProbeReturn:
        pts = info.get_buffer().pts
        with lock:
            if pts in waiting:  # else noted too long ago to be known (4096 frames)
                while waiting.popleft() != pts:
                    counts[1] += 1
        return Gst.PadProbeReturn.OK

    queue.get_static_pad("sink").add_probe(Gst.PadProbeType.BUFFER, went_in)
    queue.get_static_pad("src").add_probe(Gst.PadProbeType.BUFFER, came_out)

    def counted() -> tuple[int, int]:
        with lock:
            return counts[0], counts[1]
    return counted


def run_pipeline_file(description: str, progress: Progress | None = None,
                      on_message: Callable[[BusMessage], None] | None = None, poll_s: float = 0.25,
                      stop_after_s: float | None = None, drain_timeout_s: float = 60.0,
                      stop_element: str = "",
                      on_calibration: Callable[[str, Calibration], None] | None = None,
                      live_queue: str = "",
                      on_frames: Callable[[int, int], None] | None = None) -> RunOutcome:
    """Play ``description`` to end-of-stream; ``progress(position_s, duration_s or None)`` every ``poll_s``;
    ``on_message`` gets each element message, ``on_calibration(element name, calibration)`` each calibration.

    ``live_queue``: the name of a ``queue`` in front of the analysis.  When the source turns out to be live (a
    camera: what feeds the queue answers a latency query as live), that queue holds up to :data:`LIVE_QUEUE_BUFFERS`
    frames and then drops the oldest (leaky downstream), so a machine too slow for the stream falls behind by at
    most that much instead of without end (a live source does not wait: its packets pile up in memory, or are lost,
    and the measurements lag further and further behind the road).  Our elements measure from timestamps, so a
    dropped frame costs samples, not correctness.  ``outcome.frames_in`` / ``frames_dropped`` count the frames;
    ``on_frames(dropped, in)`` is told the counts as they change.  A file is never dropped from: it
    waits for us.

    The run ends early, as ``gst-launch-1.0 -e`` does, by an end-of-stream sent into the pipeline — so every
    element finishes as at the stream's end (speedometer writes the vehicles still in view, mp4mux completes a
    playable file): after ``stop_after_s`` seconds of video (``outcome.stopped`` "duration"; exactly, at the first
    frame that late, when the description has an element named ``stop_element`` on the decoded video, else when
    the pipeline's position gets there), or on Ctrl-C, SIGTERM — what ``systemctl stop``, ``docker stop`` and
    Kubernetes send — or SIGHUP — the terminal that started it closed, e.g. its SSH session ended — ("interrupted",
    ``outcome.stopped_by`` the signal; a second one, or no end-of-stream within ``drain_timeout_s``, stops it at
    once).
    Raises :class:`PipelineError` when the description does not parse, :class:`RunFailed` (with the outcome so
    far) when an element posts an ERROR; the pipeline is stopped first, so elements write what they have.
    """
    ensure_elements()
    try:
        pipeline = Gst.parse_launch(description)
    except Exception as exc:  # GLib.Error from the parser: unknown element, bad property, ...
        text = f"cannot build the pipeline: {getattr(exc, 'message', exc)}"
        why = [w for name, w in _broken.items() if name in description]
        raise PipelineError(text + (f" (the element failed to load: {'; '.join(why)})" if why else "")) from None
    out = RunOutcome()
    bus = pipeline.get_bus()
    mask = Gst.MessageType.ERROR | Gst.MessageType.EOS | Gst.MessageType.ELEMENT | Gst.MessageType.WARNING
    error: str | None = None
    drain_until: float | None = None  # monotonic deadline once an end-of-stream was sent

    def finish_early(why: str) -> None:
        nonlocal drain_until
        if drain_until is None:
            out.stopped = why
            drain_until = time.monotonic() + drain_timeout_s
            pipeline.send_event(Gst.Event.new_eos())

    head = pipeline.get_by_name(stop_element) if stop_after_s is not None and stop_element else None
    if head is not None:
        _end_stream_at(head.get_static_pad("sink"), stop_after_s, lambda: setattr(out, "stopped", "duration"))
    started = False

    def step() -> str | None:
        """One poll of the bus: None to go on, "eos" at the end, else the error text."""
        msg = bus.timed_pop_filtered(int(poll_s * Gst.SECOND), mask)
        if drain_until is not None and time.monotonic() > drain_until:
            return f"the pipeline did not finish within {drain_timeout_s:g} s of being told to stop"
        if msg is None:
            if not started:  # no ERROR explains the failure
                return "the pipeline failed to start"
            pos = _query_time(pipeline, "position")
            if pos is not None:
                out.position_s = pos
                out.duration_s = out.duration_s or _query_time(pipeline, "duration")
                if progress is not None:
                    progress(pos, out.duration_s if stop_after_s is None else
                             min(stop_after_s, out.duration_s or stop_after_s))
                if stop_after_s is not None and head is None and pos >= stop_after_s:
                    finish_early("duration")
            return None
        if msg.type == Gst.MessageType.ERROR:
            return _error_text(msg)
        if msg.type == Gst.MessageType.EOS:
            out.position_s = _query_time(pipeline, "position") or out.position_s  # where the stream really ended
            return "eos"
        if msg.type == Gst.MessageType.WARNING:
            w, _ = msg.parse_warning()
            out.warn(f"{msg.src.get_name() if msg.src else 'pipeline'}: {w.message}")
            return None
        cal = parse_calibration_message(msg)
        if cal is not None:
            out.add(msg.src.get_name() if msg.src else "", cal)
            if on_calibration is not None:
                on_calibration(*out.calibrations[-1])
            return None
        s = msg.get_structure()
        if s is not None:
            bm = BusMessage(msg.src.get_name() if msg.src else "", s.get_name(), structure_to_dict(s))
            out.messages.append(bm)
            if on_message is not None:
                on_message(bm)
        return None

    interrupts = []

    def on_signal(signum, frame) -> None:  # Ctrl-C, SIGTERM or SIGHUP: finish the stream; a second one: stop at once
        interrupts.append(signum)
        if len(interrupts) > 1:
            raise KeyboardInterrupt

    # only where the signals reach us (the main thread), and not one a process was told to ignore (Ctrl-C in a
    # background job, SIGHUP under nohup)
    main = threading.current_thread() is threading.main_thread()
    previous = {sig: signal.signal(sig, on_signal) for sig in STOP_SIGNALS
                if main and signal.getsignal(sig) is not signal.SIG_IGN}
    queue = pipeline.get_by_name(live_queue) if live_queue else None
    counted = _count_through(queue) if queue is not None else None  # () -> (frames in, dropped), from the start

    def decide_live() -> bool:
        """Once what feeds the queue answers a latency query (the source linked): whether it is live; then the
        queue is made leaky for a live one.  False while it cannot tell yet.  (Asked upstream of the queue: the
        pipeline's own answer is the sinks', and a sink that does not sync calls every stream not live.)"""
        query = Gst.Query.new_latency()
        if not queue.get_static_pad("sink").peer_query(query):
            return False
        out.live = bool(query.parse_latency()[0])
        if out.live:
            queue.set_property("max-size-buffers", LIVE_QUEUE_BUFFERS)
            queue.set_property("leaky", 2)  # downstream: the oldest queued frame goes
        return True

    decided = queue is None
    try:
        started = pipeline.set_state(Gst.State.PLAYING) != Gst.StateChangeReturn.FAILURE
        while True:
            result = step()
            if not decided and started:
                decided = decide_live()
            if counted is not None:
                frames_in, dropped = counted()
                if on_frames is not None and (frames_in, dropped) != (out.frames_in, out.frames_dropped):
                    on_frames(dropped, frames_in)
                out.frames_in, out.frames_dropped = frames_in, dropped
            if interrupts:
                if not out.stopped_by:
                    out.stopped_by = signal.Signals(interrupts[0]).name
                finish_early("interrupted")
            if result is not None:
                error = None if result == "eos" else result
                break
    finally:
        for sig, handler in previous.items():  # (None: one not set from Python, e.g. in an embedding program)
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
        pipeline.set_state(Gst.State.NULL)  # elements close their files (speedometer keeps every vehicle)
    if error is not None:
        raise RunFailed(error, out)
    if out.duration_s is not None and progress is not None and not out.stopped:
        progress(out.duration_s, out.duration_s)
    return out
