"""``trafficcal run VIDEO --out DIR``: calibrate and measure every vehicle in one pass through the GStreamer elements.

The pipeline is the product's own chain (what ``gst-launch-1.0`` runs, so the numbers are the same)::

    filesrc ! decodebin ! videoconvert ! videoscale ! I420,1:1 ! queue ! vpdetect ! vehicledetect ! queue ! tracker
      [! bbscale]
      ! speedometer
      [! trafficoverlay ! x264enc ! mp4mux fragment-duration=1000 ! filesink overlay.mp4]

run in-process by :mod:`gst_trafficcal.gst.runner` (progress from the pipeline's position and duration).
``vpdetect`` learns the vanishing points (or, with ``--calibration``, loads the given file: mode fixed);
``bbscale`` is inserted when that element is installed. Outputs in ``--out``: ``calibration.json`` (the
calibration the run ended with), ``system.json`` (BrnoCompSpeed results), ``vehicles.jsonl``, ``vehicles.csv``,
``overlay.mp4`` and ``report.html`` (+ ``evaluation.json`` with ``--gt``).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import os
import re

import click

from ..errors import InputError
from ..gst.chains import EVEN_I420, analysed_video

EMPTY_ZONE_S = 60.0  # seconds of a stream without a vehicle in the zone before the run says the zone may be wrong
OUTPUTS = ("calibration.json", "system.json", "vehicles.jsonl", "vehicles.csv", "intervals.csv", "overlay.mp4",
           "report.html", "evaluation.json")


def is_uri(text: str | Path) -> bool:
    """Whether ``text`` is a URI (``rtsp://cam/stream``, ``file:///v.mp4``, ``http://...``) rather than a path."""
    return isinstance(text, str) and re.match(r"^[A-Za-z][A-Za-z0-9+.-]*://", text) is not None


TCP_PORTS = {"http": 80, "https": 443, "rtsp": 554, "rtsps": 322, "rtmp": 1935}  # schemes over TCP: default ports


def unreachable(uri: str, timeout_s: float = 3.0) -> str | None:
    """Why a network URI's server cannot be reached ("cam7:554: Connection refused", "no such host"), or None when
    a TCP connection opens (or the URI is not one over TCP): GStreamer's sources fail with "Internal data stream
    error" alone."""
    import socket
    from urllib.parse import urlsplit

    parts = urlsplit(uri)
    scheme = parts.scheme.lower()
    if scheme not in TCP_PORTS or not parts.hostname:
        return None
    try:
        port = parts.port or TCP_PORTS[scheme]
    except ValueError:  # a port that is not a number
        return f"{parts.hostname}: not a valid port"
    try:
        socket.create_connection((parts.hostname, port), timeout=timeout_s).close()
    except socket.gaierror:
        return f"{parts.hostname}: no such host"
    except OSError as exc:
        return f"{parts.hostname}:{port}: {exc.strerror or exc or 'no answer'}"
    return None


STALL_TIMEOUT_S = 30.0  # a URI that sends no frame this long ends the run with an error instead of a hang


def stall_timeout_s() -> float:
    """``STALL_TIMEOUT_S``, or the environment's ``STALL_TIMEOUT`` (seconds; 0: wait for ever), as the scripts read
    it; InputError when it is not a number."""
    text = os.environ.get("STALL_TIMEOUT", "").strip()
    try:
        value = float(text) if text else STALL_TIMEOUT_S
    except ValueError:
        raise InputError(f"STALL_TIMEOUT must be a number of seconds, got {text!r}") from None
    if not value >= 0:
        raise InputError(f"STALL_TIMEOUT must be a number of seconds, got {text!r}")
    return value


def source_elements(video: Path | str) -> list[str]:
    """The pipeline's source: ``filesrc ! decodebin`` for a file, ``uridecodebin`` for a URI (a live camera), then
    GStreamer's ``watchdog`` (when installed): a camera that stops sending, or whose connection fails without the
    source saying so (now and then rtspsrc reports "Open failed" and waits for ever), ends the run with an error
    after :func:`stall_timeout_s` seconds without a frame (pipelines/lib.sh does the same for the scripts)."""
    if is_uri(video):
        from ..gst.runner import missing_elements

        ms = int(round(stall_timeout_s() * 1000))
        stall = [] if ms == 0 or missing_elements(["watchdog"]) else [f"watchdog timeout={ms}"]
        return [f"uridecodebin uri={quote(video)}", *stall]
    return [f"filesrc location={quote(video)}", "decodebin"]


def direction_of(video: Path | str, orientation: str = "auto") -> str | None:
    """The videoflip video-direction that shows a video file's frames as its display matrix says (a phone's turned
    picture, a mirrored one: :func:`gst_trafficcal.imaging.video_direction`); None for a stream, or a file whose
    matrix cannot be read (then the tag GStreamer reads turns it: ``video-direction=auto``).  An ``orientation``
    other than auto (``--orientation``: a camera mounted on its side, whose RTP stream carries no tag) is that
    video-direction, whatever the file or stream says."""
    from ..imaging import AUTO, video_direction

    if orientation != AUTO:
        return orientation
    return None if is_stream(video) else video_direction(local_file(str(video)) or video)


def frame_picture(video: Path | str, orientation: str = "auto"):
    """How OpenCV's frames of ``video`` become the picture the run analyses (:func:`direction_of`), and whether it
    is the stored one turned a quarter (its pixels' aspect ratio inverted, as videoflip inverts it): for a file
    :func:`gst_trafficcal.imaging.opencv_picture`; for a stream (no tag OpenCV reads) the ``orientation`` given,
    nothing for auto (:class:`gst_trafficcal.imaging.OpenCVPicture`)."""
    from ..imaging import AUTO, DIRECTIONS, OpenCVPicture, apply_direction, opencv_picture, swaps_axes

    if is_stream(video):
        if orientation == AUTO:
            return OpenCVPicture()
        return OpenCVPicture(lambda frame: apply_direction(frame, DIRECTIONS[orientation]), swaps_axes(orientation))
    return opencv_picture(local_file(str(video)) or video, orientation)


def orientation_option(what: str):
    """The ``--orientation`` option of the commands that analyse a video (``what``: how they use it); its value is
    None when not given (auto, or the one a --calibration file keeps: :func:`given_orientation`)."""
    from ..imaging import ORIENTATIONS

    return click.option("--orientation", default=None, metavar="|".join(ORIENTATIONS),
                        help="How the camera's picture is turned before it is analysed" + what + ": auto (as a file's "
                             "rotation or mirroring says, or a stream's tag) or videoflip's video-direction, "
                             "whatever the video says — for a camera mounted on its side or upside "
                             "down, or one imaging a mirror, whose RTSP stream carries no tag: 90r (a quarter turn "
                             "clockwise), 180, 90l (counter-clockwise), horiz / vert (mirrored left-right / "
                             "top-bottom), ul-lr / ur-ll (mirrored about a diagonal), identity (as stored). Kept in "
                             "the calibration file (docs/run.md).")


def given_orientation(text: str | None, calibration: Path | None) -> tuple[str, bool]:
    """The orientation ``--orientation`` gives (a one-line InputError for a bad one), or with none given the one
    the ``calibration`` file keeps (:func:`gst_trafficcal.imaging.orientation_of_file`; auto when it keeps none);
    and whether it came from the file."""
    from ..imaging import AUTO, check_orientation, orientation_of_file

    if text is not None:
        return check_orientation(text), False
    kept = orientation_of_file(calibration) if calibration is not None else None
    return (AUTO, False) if kept is None else (kept, True)


def shown_source(video: Path | str) -> str:
    """The input as printed and written into reports and status: a URI without its password
    (``rtsp://admin:***@cam/stream``)."""
    from ..publish import redacted

    return redacted(str(video)) if is_uri(video) else str(video)


def quote(value: str | Path) -> str:
    """A property value for a pipeline description (double-quoted: paths with spaces survive parse_launch)."""
    return '"' + str(value).replace("\\", "\\\\").replace('"', '\\"') + '"'


@dataclass(frozen=True)
class RunPaths:
    """Where ``trafficcal run`` writes each output inside ``out``."""

    out: Path

    calibration = property(lambda self: self.out / "calibration.json")
    results = property(lambda self: self.out / "system.json")
    events = property(lambda self: self.out / "vehicles.jsonl")
    csv = property(lambda self: self.out / "vehicles.csv")
    intervals = property(lambda self: self.out / "intervals.csv")
    overlay = property(lambda self: self.out / "overlay.mp4")
    report = property(lambda self: self.out / "report.html")
    evaluation = property(lambda self: self.out / "evaluation.json")


STOP_ELEMENT = "tcstart"  # the first element on the decoded video: --duration ends the stream there, exactly
QUEUE = "queue max-size-buffers=4 max-size-bytes=0 max-size-time=0"
LIVE_QUEUE = "tcqueue"  # the queue in front of the analysis: leaky for a live source (gst.runner.run_pipeline_file)
DEFAULT_DETECTOR = "vehicleseg"  # trafficcal run / demo; the element's own default (no model) is the background one
BACKGROUND = "background"  # --detector value for vehicledetect without a model


def model_of(detector: Path | str | None) -> str:
    """vehicledetect's ``model`` for a ``--detector`` value: "" for the built-in background detector."""
    return "" if detector in (None, "", BACKGROUND) else str(detector)


def check_detector(detector: Path | str | None) -> str:
    """:func:`model_of` ``detector``, opened once now so that a missing, corrupt or unknown model is a one-line
    error before any work (not a failed pipeline, or a lost calibration, later)."""
    model = model_of(detector)
    if model:
        from ..detection.factory import create_detector

        create_detector(model)
    return model


def detector_option(what: str):
    """The ``--detector`` option of the commands that detect vehicles (``what``: how they use it)."""
    return click.option("--detector", default=DEFAULT_DETECTOR, show_default=True,
                        help=f"vehicledetect's model{what}: vehicleseg (the shipped learned vehicle segmenter: boxes "
                             "and outlines; the most accurate automatic scale and recall, docs/vehicleseg.md), an "
                             "ONNX detector file or installed model name, or background (vehicledetect's built-in "
                             "background subtraction, no weights, the fastest).")


# overlay.mp4's encoder and muxer: a fragment each second, so a run killed outright (kill -9, a power cut, the OOM
# killer) leaves a playable video up to its last second; a plain mp4mux writes the index only at the end, and such a
# run's overlay of hours could not be played at all
OVERLAY_ENCODER = "x264enc speed-preset=veryfast tune=zerolatency ! mp4mux fragment-duration=1000"


def pipeline_description(video: Path | str, paths: RunPaths, calibration: Path | None = None,
                         detector: Path | str | None = None,
                         overlay: bool = True, bbscale: bool = False, queues: bool = True,
                         scale_regression: Path | None = None, body_shapes: str = "auto",
                         speed_limit: "SpeedLimit | float" = 0.0, start_time: str = "", events_url: str = "",
                         calibration_mode: str = "fixed", interval_min: float = 15.0,
                         views_dir: Path | None = None, zone: str = "", orientation: str = "auto") -> str:
    """The gst-launch description ``trafficcal run`` plays (also printed, so it can be re-run by hand).

    With ``queues`` two ``queue`` elements split the chain into three streaming threads (decoding; vpdetect and
    vehicledetect; tracker onwards), so the stages run on more than one core; the numbers do not change (every
    element still sees every buffer and the calibration events in stream order).  ``speed_limit`` (km/h, 0: none)
    goes to speedometer (its messages say which vehicles were over it) and trafficoverlay (drawn in red, counted);
    ``start_time`` (ISO 8601, the date and time the video starts) to speedometer, which then dates every vehicle;
    ``events_url`` to speedometer, which POSTs every vehicle's event there; speedometer keeps intervals.csv (a row
    per ``interval_min`` minutes, lane and direction) as the intervals close, and for a file (not a URI) measures
    the vehicles measured under an earlier calibration again with the final one at the end (``remeasure``).
    ``calibration_mode``: vpdetect's mode
    with ``calibration`` — fixed (a calibration the user gave) or auto (one carried over from an earlier file:
    learnt anew if the camera moved); ``views_dir``: vpdetect's folder of the camera's views; ``zone``
    (:mod:`gst_trafficcal.zone`) to vpdetect, vehicledetect and trafficoverlay, which draws it.  The elements get
    the video upright and of square pixels (:func:`~gst_trafficcal.gst.chains.analysed_video`; ``orientation``: as
    :func:`direction_of` takes it, and to vpdetect when not auto, which keeps it with the views it learns and in
    its calibration-file); overlay.mp4 is of an
    even size (:data:`~gst_trafficcal.gst.chains.EVEN_I420`): a video of an odd one (1281x721, which VP8/VP9 and
    MJPEG allow) is scaled by a pixel there, since x264 cannot encode 4:2:0 of an odd size (it refused, and the
    whole run failed).
    """
    from ..traffic_stats import as_limit

    limit = as_limit(speed_limit or None).properties()
    limit = f" {limit}" if limit else ""
    clock = f" start-datetime={quote(start_time)}" if start_time else ""
    clock += f" events-url={quote(events_url)}" if events_url else ""
    vp = f"vpdetect mode={calibration_mode} calibration-file={quote(calibration)}" if calibration else "vpdetect"
    if views_dir is not None:
        vp += f" views-dir={quote(views_dir)}"
    if orientation != "auto":  # kept with the views it learns, and in its calibration-file (a carried calibration)
        vp += f" orientation={orientation}"
    model = model_of(detector)
    det = f"vehicledetect model={quote(model)}" if model else "vehicledetect"
    where = f" zone={quote(zone)}" if zone else ""
    vp, det = vp + where, det + where
    # upright and of square pixels, as the camera model needs them (gst.chains)
    chain = [*source_elements(video), f"videoconvert name={STOP_ELEMENT}",
             *analysed_video(direction_of(video, orientation)),
             *([f"{QUEUE} name={LIVE_QUEUE}"] if queues else []), vp, det, *([QUEUE] if queues else []),
             "tracker" if body_shapes == "auto" else f"tracker body-shapes={body_shapes}"]
    if bbscale:
        chain.append(f"bbscale regression-file={quote(scale_regression)}" if scale_regression else "bbscale")
    chain.append(f"speedometer events-file={quote(paths.events)} csv-file={quote(paths.csv)} "
                 f"results-file={quote(paths.results)} intervals-file={quote(paths.intervals)} "
                 f"interval={interval_min:g}{limit}{clock}{'' if is_uri(video) else ' remeasure=true'}")
    if overlay:
        chain += [f"trafficoverlay{limit}{where}", "videoconvert", "videoscale", EVEN_I420,
                  "queue max-size-buffers=8",
                  OVERLAY_ENCODER,
                  f"filesink location={quote(paths.overlay)}"]
    else:
        chain.append("fakesink")
    return " ! ".join(chain)


@dataclass
class RunSummary:
    """What one pass produced."""

    calibration: Any  # Calibration | None: the one the run ended with
    events: list = field(default_factory=list)  # VehicleEvent
    warnings: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)  # output files that could not be written
    duration_s: float | None = None
    stopped: str = ""  # "interrupted" (Ctrl-C, SIGTERM, SIGHUP) or "duration" (--duration): ended before the stream did
    stopped_by: str = ""  # "interrupted": "SIGINT", "SIGTERM" or "SIGHUP"
    position_s: float | None = None  # how far into the stream the run got
    moves: list = field(default_factory=list)  # gst.runner.Move: when the camera moved, the calibrations around it
    # (the latest gst.runner.MOVES_KEPT); the moves before those: how many, the first's and the last's time
    moves_earlier: tuple[int, float | None, float | None] = (0, None, None)
    discarded: int = 0  # tracks seen only between a camera move and its notice (not vehicles, not reported)
    not_counted: tuple[int, int] = (0, 0)  # tracks that were no vehicle passing, not reported: (brief, stationary)
    remeasured: int = 0  # vehicles measured under an earlier calibration, measured again with the final one at the end
    remeasured_speeds: int = 0  # of those, how many got a speed
    scaled: list = field(default_factory=list)  # every calibration with a scale and a view posted (one per view)

    @property
    def watched_s(self) -> float | None:
        """Seconds of video the run went through (the stream's duration when it ended by itself at its end)."""
        return self.position_s if self.stopped or ended_short(self) else self.duration_s or self.position_s

    @property
    def has_scale(self) -> bool:
        c = self.calibration
        return c is not None and c.camera is not None and c.camera.scale is not None


def _stamp(path: Path) -> tuple[int, int, int] | None:
    """What tells one version of a file from another (inode, size, modification time), None when there is none."""
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_ino, st.st_size, st.st_mtime_ns


def _read_vehicle_events(paths: RunPaths, earlier: dict | None = None) -> list:
    """The events the speedometer wrote: the JSON lines, or the CSV when the JSON lines could not be written.  A
    file still as it was before the run (``earlier``: :func:`_stamp` per path) is an earlier run's, not read."""
    from ..outputs import read_events, read_events_csv

    found: list = []
    for reader, path in ((lambda p: read_events(p).events, paths.events), (read_events_csv, paths.csv)):
        if earlier and path in earlier and earlier[path] is not None and _stamp(path) == earlier[path]:
            continue
        try:
            events = reader(path) if path.is_file() else []  # not /dev/full & co. (endless)
        except InputError:
            continue
        if len(events) > len(found):
            found = events
    return found


def earlier_status(out_dir: Path):
    """The status.json an earlier run left in ``out_dir`` (``run_status.RunStatus``); None when there is none or
    it cannot be read (this run's own replaces it)."""
    from ..run_status import read_status

    if not (out_dir / "status.json").is_file():
        return None
    try:
        return read_status(out_dir / "status.json")
    except InputError:
        return None


def refuse_a_busy_out(out_dir: Path, earlier) -> None:
    """InputError when the run of ``earlier`` (``out_dir``'s status) is still writing into ``out_dir`` (not ended,
    its process alive): two runs would overwrite each other's files."""
    from datetime import datetime

    from ..run_status import age_s, dated_ahead, still_running

    if earlier is not None and still_running(earlier):
        age = age_s(earlier.updated_at, datetime.now().astimezone())
        if dated_ahead(age):  # another machine's, taken at its word: it cannot be told
            raise InputError(f"{out_dir}: another run may be writing there (process {earlier.pid} on {earlier.host}"
                             f", reading {earlier.source}): its status.json is dated {-age:.0f} s in the future, "
                             f"the clocks of {earlier.host or 'its machine'} and this one differ, so whether it "
                             f"still runs cannot be told: stop that run, or remove {out_dir / 'status.json'} if it "
                             "is gone (and set the clocks right: NTP)")
        raise InputError(f"{out_dir}: another run is writing there (process {earlier.pid} on {earlier.host}, "
                         f"{earlier.state} since {earlier.state_since}, reading {earlier.source}): give another "
                         "--out, or stop that run first")


def set_aside_earlier_live_run(out_dir: Path, live: bool, earlier=None,
                               inputs: tuple[Path | None, ...] = ()) -> tuple[Path, int] | None:
    """A live stream cannot be measured again: when ``out_dir`` holds an earlier run's vehicles and that run read a
    live stream (``earlier``, its status: the source is a URI; without one: when this run reads one, ``live``), its
    outputs move to ``out_dir/earlier-<its start>/`` instead of being replaced, so a service restarted after a
    crash or a reboot keeps what it measured.  A file's run is replaced as before (it can be run again).  Files
    that are ``inputs`` of this run (``--calibration OUT/calibration.json``) are copied there, not moved; of an
    output that is a symlink the file it leads to is moved, the link stays (this run's file is written through
    it).  Returns the folder and the number of vehicles kept there, or None."""
    import shutil
    from datetime import datetime

    from ..fileio import free_path, link_target

    vehicles = out_dir / "vehicles.jsonl"
    if not vehicles.is_file() or vehicles.stat().st_size == 0:
        return None
    started = datetime.fromtimestamp(vehicles.stat().st_mtime)
    if earlier is not None:
        live = is_uri(earlier.source)
        try:
            started = datetime.fromisoformat(earlier.started_at)
        except ValueError:
            pass  # no readable start: the time of its last vehicle
    if not live:
        return None
    folder = free_path(out_dir / f"earlier-{started:%Y%m%d-%H%M%S}")
    folder.mkdir(parents=True)
    with vehicles.open("rb") as f:
        count = sum(1 for line in f if line.strip())
    for name in OUTPUTS + ("status.json", "parts.csv"):
        path = out_dir / name
        if path.exists():
            if any(_same(path, given) for given in inputs if given is not None):
                shutil.copy2(path, folder / name)
            elif path.is_symlink():  # the link stays for this run's file, what it leads to is kept
                target = link_target(path)
                if target.is_file():
                    shutil.move(target, folder / name)
            else:
                path.rename(folder / name)
    return folder, count


def measure_video(video: Path | str, out_dir: Path, description: str, console, label: str = "measuring",
                  keep: tuple[Path, ...] = (), stop_after_s: float | None = None, status=None,
                  zone=None, orientation: str = "auto") -> RunSummary:
    """Play ``description`` (see :func:`pipeline_description`) with a progress bar; read back what it wrote.

    ``stop_after_s``: end the run there (an end-of-stream, as Ctrl-C does: every output is completed).
    ``status``: a :class:`~gst_trafficcal.run_status.StatusFile` kept up to date with the position, the vehicles and
    the calibration.  ``zone``: the detection zone of the run (gst_trafficcal.zone.Zone), kept in calibration.json,
    as ``orientation`` (--orientation, when not auto: a run given that file turns the picture the same way).

    Earlier outputs in ``out_dir`` are removed first, except the files in ``keep`` (inputs of this run, such as a
    calibration file given inside ``out_dir``); an output that is a symlink stays one: the file it leads to is
    removed and the new one written through it (:func:`~gst_trafficcal.fileio.remove_earlier`).
    On an element error the vehicles already written stay in the files; the error is raised as InputError
    after ``calibration.json`` got the calibration known by then.
    """
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from ..calibration import save_calibration
    from ..fileio import remove_earlier
    from ..gst.runner import PipelineError, RunFailed, run_pipeline_file
    from .terminal import stderr_console

    paths = RunPaths(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    for name in OUTPUTS:  # nothing stale from an earlier run (speedometer truncates the event files itself); a
        stale = out_dir / name  # symlink stays, the file it leads to goes (written through the link again)
        if name not in (paths.events.name, paths.csv.name) and not any(_same(stale, k) for k in keep):
            remove_earlier(stale)
    earlier = {p: _stamp(p) for p in (paths.events, paths.csv)}  # a run that fails before the speedometer replaced
    # them must not report the earlier run's vehicles as its own
    def hidden(text: str) -> str:  # a message without the URI's password
        return text.replace(str(video), shown_source(video))

    counts = Counter()
    moves: set = set()  # the moves' dates (several elements pass the same news on)
    moves_before = status.status.camera_moves if status is not None else 0  # earlier parts'

    def on_message(m) -> None:  # the outcome keeps only the latest messages: what covers the run is counted here
        if m.name == "trafficcal-speed":
            counts["vehicles"] += 1
            counts["measured"] += m.fields.get("speed_kmh") is not None
            if status is not None:
                status.vehicle(m.fields.get("last_timestamp_s"), m.fields.get("speed_kmh") is not None)
        elif m.name == "trafficcal-discarded":  # (a running count)
            counts["discarded"] = max(counts["discarded"], int(m.fields.get("tracks", 0)))
        elif m.name == "trafficcal-not-counted":  # (running counts: the last one holds)
            counts["brief"], counts["stationary"] = int(m.fields.get("brief", 0)), int(m.fields.get("stationary", 0))
        elif m.name == "trafficcal-remeasured":
            counts["remeasured"] += int(m.fields.get("vehicles", 0))
            counts["remeasured_speeds"] += int(m.fields.get("measured", 0))

    scaled = [False]  # calibration.json holds one with a scale of the current view

    def on_calibration(_element: str, cal) -> None:
        # calibration.json as soon as the run knows one (the one it ends with is written again at the end): a run
        # killed outright (kill -9, a power cut) left none, and its restart had to learn the camera anew
        scaled[0] &= cal.moved_at is None
        if cal.camera is not None and (cal.camera.scale is not None or not scaled[0]):
            try:
                save_calibration(cal, paths.calibration, zone=zone, orientation=orientation)
                scaled[0] |= cal.camera.scale is not None
            except InputError:
                pass  # said when it is written at the end
        if status is None:
            return
        from ..run_status import calibration_fields

        if cal.moved_at is not None:
            moves.add(cal.moved_at)
        status.update(calibration=calibration_fields(cal), camera_moves=moves_before + len(moves))

    failure: str | None = None
    with Progress(TextColumn("[progress.description]{task.description}"), BarColumn(),
                  TextColumn("{task.fields[time]}"), TextColumn("{task.fields[cars]}"),
                  TimeRemainingColumn(), console=stderr_console(), transient=False) as bar:  # progress: stderr
        task = bar.add_task(label, total=None, time="", cars="")

        def progress(pos: float, dur: float | None) -> None:
            bar.update(task, completed=pos, total=dur if dur else None,
                       time=f"{pos:.1f}/{dur:.1f} s" if dur else f"{pos:.1f} s",
                       cars=f"{counts['vehicles']} vehicles, {counts['measured']} measured")
            if status is not None:
                status.position(pos, dur)

        def on_frames(dropped: int, frames: int) -> None:
            if status is not None:
                status.update(frames_dropped=dropped_before + dropped, frames=frames_before + frames)

        dropped_before = status.status.frames_dropped if status is not None else 0  # earlier parts'
        frames_before = status.status.frames if status is not None else 0
        try:
            outcome = run_pipeline_file(description, progress=progress, on_message=on_message,
                                        stop_after_s=stop_after_s, stop_element=STOP_ELEMENT,
                                        on_calibration=on_calibration, live_queue=LIVE_QUEUE,
                                        on_frames=on_frames)
        except RunFailed as exc:
            outcome, failure = exc.outcome, str(exc)
        except PipelineError as exc:
            raise InputError(hidden(f"{video}: {exc}")) from None
        on_frames(outcome.frames_dropped, outcome.frames_in)  # every frame, also those after the last poll
        if outcome.position_s is not None:  # where the stream really ended: a truncated file's last poll may have
            # said its header's end
            progress(outcome.position_s, outcome.duration_s if stop_after_s is None else
                     min(stop_after_s, outcome.duration_s or stop_after_s))
    if failure is None and ended_short(outcome) is not None:  # (the file is probed for audio only then; a run an
        # element stopped, a full disk, ended where it failed: the file is not short for that)
        outcome.warnings.append(f"{shown_source(video)}: {ended_short(outcome, audio=_has_audio(video))}")
    if outcome.frames_dropped:  # a live camera faster than this machine: frames dropped to stay in real time
        share = outcome.frames_dropped / max(outcome.frames_in, 1)
        outcome.warnings.append(
            f"this machine could not keep up with the live stream: {outcome.frames_dropped} of {outcome.frames_in} "
            f"frames ({100 * share:.0f} %) were dropped to stay in real time; the vehicles are measured from the "
            "frames kept (--no-overlay, --detector background or a faster machine keep more)")
    summary = RunSummary(outcome.calibration, _read_vehicle_events(paths, earlier), outcome.warnings,
                         duration_s=outcome.duration_s, stopped=outcome.stopped, stopped_by=outcome.stopped_by,
                         position_s=outcome.position_s,
                         moves=outcome.moves, moves_earlier=outcome.moves_earlier,
                         discarded=counts["discarded"], not_counted=(counts["brief"], counts["stationary"]),
                         remeasured=counts["remeasured"], remeasured_speeds=counts["remeasured_speeds"],
                         scaled=outcome.scaled_views)
    if status is not None:
        for w in outcome.warnings:
            status.warning(w)
        if failure is not None:
            status.update(error=failure)
            for e in summary.events[counts["vehicles"]:]:  # written as the pipeline stopped, after the bus loop
                status.vehicle(e.last_timestamp_s, e.measured)
    if summary.calibration is not None:
        try:
            save_calibration(summary.calibration, paths.calibration, zone=zone, orientation=orientation)
        except InputError as exc:
            summary.errors.append(str(exc))
    if failure is not None:
        if "Watchdog triggered" in failure:  # source_elements' watchdog: no frame for STALL_TIMEOUT seconds
            failure = (f"no frame for {stall_timeout_s():g} s: the source stopped sending or never connected "
                       "(STALL_TIMEOUT sets how long to wait)")
        if not outcome.position_s and not summary.events:  # nothing was decoded: the input is at fault
            why = unreachable(video) if is_uri(video) else None
            raise InputError(hidden(f"{video}: cannot be processed: {failure}" + (f" ({why})" if why else "")))
        kept = (f"the {len(summary.events)} vehicles that finished before it are written "
                f"(in {paths.events.name} and {paths.csv.name}, where the disk allowed)")
        raise InputError(hidden(f"{video}: the run stopped: {failure}; {kept}"))
    return summary


def readable_video(video: Path, out_dir: Path | None, zone=None, orientation: str = "auto"):
    """The first frame of a video file, checked before anything in ``out_dir`` is replaced: InputError when none can
    be decoded (not a video, empty, damaged) or when the detection ``zone`` covers no pixel of its frames — an
    earlier run's outputs there stay as they were (None: a new folder, there are none to speak of); the frame turned
    by ``orientation`` (:func:`first_frame`)."""
    import cv2

    frame = first_frame(video, orientation)
    untouched = f"; the earlier outputs in {out_dir} are left as they were" if out_dir is not None else ""
    if frame is None:
        raise InputError(f"{video}: cannot be processed: no frame could be decoded from it (not a video, empty, or "
                         f"damaged){untouched}")
    if cv2.haveImageReader(str(video)):  # a JPEG or PNG plays as one frame: a run with no vehicle, and no word why
        raise InputError(f"{video}: a picture, not a video: speeds are measured on video (pictures of a camera taken "
                         f"at a fixed rate: make a video of them first, e.g. with ffmpeg){untouched}")
    wrong = zone.check((frame.shape[1], frame.shape[0])) if zone is not None else None
    if wrong:
        raise InputError(f"{video}: the detection {wrong}{untouched}")
    return frame


def _same(a: Path, b: Path) -> bool:
    try:
        return a.exists() and Path(b).exists() and a.samefile(b)
    except OSError:
        return False


def lane_paths(results_path: Path, events: list) -> list:
    """(lane, reference points in pixels) of every measured vehicle in the BrnoCompSpeed results file, for the
    report's picture of the lanes; none when the file cannot be read."""
    from ..brnocompspeed import load_results
    from ..report import measured_paths

    try:
        return measured_paths(load_results(results_path).cars, events)
    except (OSError, ValueError, InputError):
        return []


def first_frame(video: Path | str, orientation: str = "auto"):
    """A BGR frame from the video or stream (for the calibration picture) as the elements see it (upright, of square
    pixels: the calibration's image size; turned by ``orientation`` as :func:`direction_of` takes it), or None (a
    stream that is gone gives up within seconds).  A file
    OpenCV's FFmpeg refuses (a truncated MP4 that GStreamer still plays) is read through GStreamer; FFmpeg's own
    complaints stay off the console (OPENCV_FFMPEG_LOGLEVEL, unless set)."""
    import cv2

    from ..fileio import quiet_ffmpeg
    from ..imaging import capture_par

    with quiet_ffmpeg():  # a refusal is handled here
        if is_uri(video):
            cap = cv2.VideoCapture(str(video), cv2.CAP_FFMPEG, [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, 5000,
                                                                cv2.CAP_PROP_READ_TIMEOUT_MSEC, 5000])
        else:
            cap = cv2.VideoCapture(str(video))
        try:
            ok, frame = cap.read()
            par = capture_par(cap)
        finally:
            cap.release()
    if ok:  # upright already (OpenCV applies a rotated file's display matrix; a mirrored one's flip: the fix-up)
        return frame_picture(video, orientation).frame(frame, par)
    if is_uri(video) or not Path(video).is_file():
        return None
    from ..gst.snapshot import first_frame_bgr

    return first_frame_bgr(video, orientation=orientation)


def evaluate_run(gt_path: Path, summary: RunSummary, paths: RunPaths):
    """BrnoCompSpeed evaluation of ``system.json`` against ``gt_path`` (None without a scale)."""
    import json

    from ..brnocompspeed import load_gt_data, load_results
    from ..evaluation import evaluate, prepare_tracks

    gt = load_gt_data(gt_path)
    if not summary.has_scale:
        return None
    results = load_results(paths.results)
    w, h = summary.calibration.image_size
    ev = evaluate(gt, summary.calibration.camera, prepared=prepare_tracks(results, gt, width=w, height=h))
    paths.evaluation.write_text(json.dumps(ev.to_dict(per_item=False), indent=2))
    return ev


def print_moves(console, summary: RunSummary) -> None:
    """One line per camera move vpdetect noticed (the latest gst.runner.MOVES_KEPT; one line counts the earlier
    ones): when, and which calibration measured the vehicles before."""
    since = float("-inf")
    n_earlier, first, last = summary.moves_earlier
    if n_earlier:
        n = sum(e.first_timestamp_s < last for e in summary.events)
        console.print(f"[yellow]The camera moved {n_earlier + len(summary.moves)} times[/]: {n_earlier} times from "
                      f"{first:.1f} s to {last:.1f} s ({n} vehicles seen until then, each measured with the "
                      f"calibration in force as it passed), then the latest {len(summary.moves)}:", highlight=False)
        since = last
    for t, before, known in summary.moves:
        n = sum(since <= e.first_timestamp_s < t for e in summary.events)
        since = t
        used = (f"calibration {before.id} (scale {before.camera.scale:.3f} m)" if before is not None
                else "the calibration then in force")
        then = ("vpdetect learnt the new view from there" if known is None else
                f"it went back to a view calibrated before: calibration {known.id}"
                + (f" (scale {known.camera.scale:.3f} m)" if known.camera.scale is not None else "")
                + " measured from there at once")
        console.print(f"[yellow]The camera moved at {t:.1f} s[/]: the {n} vehicles seen before were measured with "
                      f"{used}, cut at the move; {then}", highlight=False)
    if summary.discarded:
        console.print(f"{summary.discarded} tracks seen only between the move and the moment it was noticed were not "
                      "counted as vehicles (the detector still compared the new picture with the old view)",
                      highlight=False)


def print_not_counted(console, not_counted: tuple[int, int], indent: str = "") -> None:
    """The line on the tracks speedometer did not count as vehicles ((brief, stationary); nothing when none)."""
    if any(not_counted):
        from ..report import not_counted_text

        console.print(indent + not_counted_text(*not_counted), highlight=False)


def print_remeasured(console, n: int, events_url: str = "", indent: str = "", speeds: int | None = None) -> None:
    """The line on the vehicles speedometer's ``remeasure`` measured again at the end (nothing when none);
    ``speeds``: how many of them got a speed."""
    if not n:
        return
    from ..publish import redacted

    got = f" ({speeds} of them with a speed)" if speeds is not None and speeds < n else ""
    sent = f" (and sent again to {redacted(events_url)}, with revised: true)" if events_url else ""
    console.print(f"{indent}{n} vehicles that left while the calibration was still settling were measured again with "
                  f"the final one{got}{sent}", highlight=False)


def print_vehicles(console, events: list, speed_limit: "SpeedLimit | float | None" = None) -> None:
    """Counts and speeds (mean, V85, over the limit) per lane and direction, per class, and why vehicles were not
    measured (by kind of reason)."""
    from rich.table import Table

    from ..outputs import unmeasured_by_kind
    from ..traffic_stats import as_limit, event_stats

    speed_limit = as_limit(speed_limit)
    measured = [e for e in events if e.measured]
    table = Table(title=f"{len(events)} vehicles, {len(measured)} measured (speeds in km/h)")
    cols = ("lane", "direction", "vehicles", "measured", "mean", "V85")
    for col in cols + (("over limit",) if speed_limit else ()):  # fits 80 columns: no direction cut to "away_fr…"
        table.add_column(col, justify="right", no_wrap=col == "direction", min_width=13 if col == "direction" else None)
    groups = Counter((e.lane, e.direction) for e in events)
    for (lane, direction), n in sorted(groups.items(), key=lambda kv: (kv[0][0] is None, kv[0][0] or 0,
                                                                        str(kv[0][1]))):
        st = event_stats([e for e in measured if e.lane == lane and e.direction == direction], speed_limit)
        row = ["?" if lane is None else str(lane), direction or "?", str(n), str(st.n),
               "–" if st.mean is None else f"{st.mean:.1f}", "–" if st.v85 is None else f"{st.v85:.1f}"]
        table.add_row(*row, *([str(st.over_limit)] if speed_limit else []))
    console.print(table)
    st = event_stats(measured, speed_limit)
    if st.n:
        line = f"  speeds: mean {st.mean:.1f}, median {st.median:.1f}, V85 {st.v85:.1f}, max {st.max:.1f} km/h"
        if speed_limit:
            line += (f"; {st.over_limit} of {st.n} over the {speed_limit.describe()} limit "
                     f"({100 * st.share_over:.0f} %)")
        console.print(line, highlight=False, soft_wrap=True)
    classes = Counter(e.label or "unknown" for e in events)
    if classes:
        console.print("  classes: " + ", ".join(f"{label} {n}" for label, n in classes.most_common()))
    kinds = unmeasured_by_kind(events)
    for kind, n in kinds:
        console.print(f"  not measured: {n} x {kind}")
    if kinds:
        console.print("  (each vehicle's reason, with its figures: vehicles.jsonl, report.html)")


@click.command(name="run")
@click.argument("videos", metavar="VIDEO|URI...", nargs=-1, required=True)
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Folder for the outputs (created; earlier outputs there are replaced).")
@click.option("--calibration", "calibration_path", type=click.Path(path_type=Path), default=None,
              help="Calibration JSON to use instead of learning one (ours, or a BrnoCompSpeed camera_calibration); "
                   "with a scale, speeds are measured.")
@click.option("--gt", "gt_path", type=click.Path(path_type=Path), default=None,
              help="BrnoCompSpeed ground truth (gt_data.pkl): adds the error table and plot to the report.")
@detector_option("")
@click.option("--scale-regression", "regression_path", type=click.Path(path_type=Path), default=None,
              help="Scale-correction regression (trafficcal fit-scale) for bbscale's λ: the paper's BBScaleReg.")
@click.option("--body-shapes", type=click.Choice(["auto", "cars", "box"]), default="auto", show_default=True,
              help="The tracker's 3D box: auto = car body shapes for a segmenter's outlines (vehicleseg), the plain "
                   "box for the background detector's hulls; box = always the plain box (steadier on outlines that "
                   "keep a soft shadow halo); cars = always the body shapes. See docs/tracking.md.")
@click.option("--speed-limit", default="", metavar="KMH[,CLASS=KMH...]",
              help="Posted speed limit in km/h, and classes with limits of their own (e.g. 80,truck=60,bus=60; "
                   "classes: car, van, bus, truck, motorcycle): the overlay draws vehicles over their limit in red "
                   "and counts them, the report and the summary give how many and which share of the measured "
                   "vehicles were faster (V85, the speed 85 % do not exceed, is always given).")
@click.option("--start-time", default="", metavar="ISO8601|now|auto",
              help="Date and time the video starts (e.g. 2026-12-05T08:00:00+01:00; without an offset: this "
                   "machine's local time; 'now' for a live stream: the clock at its first frame; 'auto': each "
                   "file's from the date and time in its name, e.g. cam7_20261205_080000.mp4): every vehicle then "
                   "carries the date and time it passed (first_time, last_time), and intervals.csv is aligned to "
                   "the clock (with several files, also one for all of them in --out).")
@click.option("--interval", "interval_min", type=click.FloatRange(min=0.01, max=10080), default=15.0,
              show_default=True, help="Minutes per row of intervals.csv (the traffic count per interval, lane and "
                                      "direction: vehicles, classes, mean speed, V85, over the limit).")
@click.option("--duration", "duration_s", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Stop after this many seconds of video (a live stream otherwise runs until Ctrl-C). Either way the "
                   "run ends as at the end of the stream: every vehicle in view is written and every output "
                   "completed.")
@click.option("--events-url", default="", metavar="URL",
              help="Also POST each vehicle's event as JSON to this http(s):// URL as it leaves (a webhook of your "
                   "traffic or video-management system; http://user:password@host/... for basic authentication; "
                   "with TRAFFICCAL_EVENTS_SECRET set, each POST is signed: X-Trafficcal-Signature-256). "
                   "Sent in the background and retried: a receiver that is down never stops the run, and every "
                   "vehicle is still in the files.")
@click.option("--reconnect", is_flag=True,
              help="For a live stream: when it fails or ends (a camera rebooting, the network gone), connect again "
                   "(after 1 s, doubling to a minute while it keeps failing) until Ctrl-C or --duration; each "
                   "connection's outputs in --out/YYYYmmdd-HHMMSS/, the calibration carried over from one to the "
                   "next (checked against the view).")
@click.option("--split-every", "split_every", default="", metavar="PERIOD",
              help="With --reconnect: end each connection at the next multiple of PERIOD on the clock (24h: at "
                   "midnight; also 1h, 15m, 90s) and connect again at once, so every day (or hour) has its own "
                   "folder, outputs and report.html, and a connection up for weeks holds one period's vehicles in "
                   "memory.")
@click.option("--zone", default="", metavar="'x,y x,y x,y ...'",
              help="Where vehicles are looked for: a polygon of the frame in pixels, or in fractions 0..1 of its "
                   "width and height (several: separated by ';'). Vehicles whose box's bottom centre lies outside "
                   "are neither counted nor measured, and the calibration learns only from the traffic inside — "
                   "leave out a side road, a parking lot or a footpath. Drawn on overlay.mp4, kept in "
                   "calibration.json. Default: the zone the --calibration file keeps (trafficcal calibrate --zone), "
                   "else the whole frame; 'all': the whole frame.")
@orientation_option(" (default: the one the --calibration file keeps, else auto)")
@click.option("--no-overlay", is_flag=True, help="Do not encode overlay.mp4 (faster).")
@click.option("--status-interval", "status_s", type=click.FloatRange(min=0.1), default=5.0, show_default=True,
              metavar="SECONDS",
              help="Seconds between rewrites of --out/status.json, the run's state for monitoring while it goes on: "
                   "running / reconnecting / finished / interrupted / failed, the stream position and how fast it "
                   "is measured against real time, the calibration in force, vehicles so far and when the last "
                   "one passed, camera moves, the last warnings (docs/run.md).")
def command(videos: tuple[str, ...], out_dir: Path, calibration_path: Path | None, gt_path: Path | None,
            detector: str | None, regression_path: Path | None, body_shapes: str, speed_limit: str,
            start_time: str, interval_min: float, duration_s: float | None, events_url: str,
            reconnect: bool, no_overlay: bool, status_s: float = 5.0, split_every: str = "", zone: str = "",
            orientation: str | None = None) -> None:
    """Calibrate and measure every vehicle of VIDEO (a file, or the URI of a stream: rtsp://, http://, file://)
    in one pass through the GStreamer elements. Ctrl-C (or --duration, or SIGTERM: a service stopped, or SIGHUP: the
    SSH session that started it closed) ends the run as the end of the stream would, with every output complete; a
    second Ctrl-C stops at once.

    Writes to --out: calibration.json, system.json (BrnoCompSpeed results), vehicles.jsonl, vehicles.csv,
    intervals.csv (the traffic count per --interval, lane and direction), overlay.mp4 (unless --no-overlay),
    report.html, and with --gt evaluation.json; status.json says all along what the run is doing.
    Speeds need a scale: bbscale finds it in the same pass (or a --calibration file with a scale gives it); until
    it is known the vehicles wait, and without one they are written with speed null and the reason.

    Several files of one camera (recordings split into parts): each is measured into --out/NAME/ in turn, and the
    calibration the first ones found (with its scale) carries over to the next — checked against each file's view,
    so a camera moved in between is calibrated anew, and a view seen in an earlier file gets its calibration at
    once (--out/views/); a table of every file ends the run, --out/vehicles.jsonl and vehicles.csv hold every
    file's vehicles with the part they came from. A file that fails does not stop the others.
    """
    import sys

    from rich.console import Console

    from ..calibration import load_calibration
    from ..clock import AUTO, NOW, parse_start_time

    console = Console()
    inputs = [check_input(v) for v in videos]
    if len(inputs) > 1 and any(is_uri(v) for v in inputs):
        raise InputError("a stream (URI) runs alone: give one URI, or several files")
    if len(inputs) > 1 and gt_path is not None:
        raise InputError("--gt is the ground truth of one video: give one file with it")
    live_clock = start_time.strip().lower() == NOW
    if live_clock and not is_uri(inputs[0]):
        raise InputError("--start-time now is for live streams (the clock at the first frame); for a file give the "
                         "date and time the recording starts")
    starts = None  # --start-time auto: each file's start from its name
    if start_time.strip().lower() == AUTO:
        starts = [names_start(v) for v in inputs]
        start = starts[0]
    else:
        start = None if live_clock else parse_start_time(start_time, "--start-time")  # bad: one line, before work
    if len(inputs) > 1 and start is not None and starts is None:
        raise InputError("--start-time is the start of one recording: with several files give --start-time auto "
                         "(each file's date and time from its name) or run them one by one")
    if calibration_path is not None:
        given = load_calibration(calibration_path)  # unreadable/corrupt: a one-line InputError now, not mid-run
        if given.camera is None:
            raise InputError(f"{calibration_path}: holds no vanishing points (state {given.state}"
                             + (f": {given.reason}" if given.reason else "") + ")")
    if gt_path is not None:
        from ..brnocompspeed import load_gt_data

        load_gt_data(gt_path)  # fail before the long run, not after
    if regression_path is not None:
        from ..scale.regression import load_regression

        load_regression(regression_path)  # unreadable or not a regression: a one-line error now
    check_detector(detector)
    if events_url:
        from ..publish import check_url

        check_url(events_url, "--events-url")  # not an http(s) URL: one line now, not an element error later
    from ..traffic_stats import parse_speed_limit

    limit = parse_speed_limit(speed_limit, "--speed-limit")  # a bad one: one line, before any work
    from ..zone import given_or_kept

    # a bad one: one line now, not an element error after the pipeline started; none given: the calibration's
    where = given_or_kept(zone, "--zone", calibration_path)
    notes: list[tuple[str, str]] = []  # where a setting came from: diagnostics (stderr), and run.log once made
    if where is not None and not zone.strip():
        notes.append(("Zone", f"kept in {calibration_path}: {where} (--zone all: the whole frame)"))
    zone = "" if where is None else str(where)
    orientation, kept_orientation = given_orientation(orientation, calibration_path)  # bad: one line, before work
    if kept_orientation:
        notes.append(("Orientation", f"kept in {calibration_path}: {orientation} (--orientation auto: as the "
                                     "video says)"))
    from .terminal import stderr_console

    for head, text in notes:
        stderr_console().print(f"[bold]{head}[/] {text}", highlight=False)
    if reconnect and not is_uri(inputs[0]):
        raise InputError("--reconnect is for a live stream (a URI): a file is read to its end once")
    split_s = None
    if split_every:
        from ..clock import parse_period

        split_s = parse_period(split_every, "--split-every")
        if not reconnect:
            raise InputError("--split-every is for a live stream with --reconnect (each period a connection of its "
                             "own)")
    from ..fileio import folder_made_for, writable_dir
    from ..run_status import StatusFile

    with folder_made_for(out_dir) as new:  # a refusal below leaves no empty --out made for it
        writable_dir(out_dir, "output folder (--out)")  # one line now, not a traceback or an error after the video
        earlier = earlier_status(out_dir)
        refuse_a_busy_out(out_dir, earlier)
        first = None  # one file: checked before anything in --out changes, status.json included (an operator
        if len(inputs) == 1 and not is_uri(inputs[0]):  # watching it keeps the earlier run's; the refusal is the
            first = readable_video(inputs[0], None if new else out_dir, where, orientation)  # exit code's)
    kept = set_aside_earlier_live_run(out_dir, is_uri(inputs[0]), earlier, (calibration_path, gt_path, regression_path))
    if kept is not None:
        console.print(f"[bold]Kept[/] the earlier run's outputs ({kept[1]} vehicles of a live stream, which cannot be "
                      f"measured again) in {kept[0]}", highlight=False)
    status = StatusFile(out_dir / "status.json", shown_source(inputs[0]) if len(inputs) == 1 else
                        f"{len(inputs)} files: {', '.join(shown_source(v) for v in inputs)}", every_s=status_s,
                        warn=lambda text: say(console, text))
    status.update(orientation=orientation, force=True)  # how the picture was turned: a later run's must match
    options = RunOptions(detector, regression_path, body_shapes, limit, interval_min, duration_s, events_url,
                         no_overlay, gt_path, live_clock, start, status=status, split_every_s=split_s, zone=zone,
                         orientation=orientation)
    from .terminal import RunLog, quiet_when_the_terminal_is_gone, say

    log = RunLog(out_dir / "run.log")  # what the screen said that must outlive it: warnings, errors, the end
    log.line(f"trafficcal run started: {status.status.source} into {out_dir} (process {status.status.pid} on "
             f"{status.status.host})")
    for head, text in notes:
        log.line(f"{head} {text}")
    with quiet_when_the_terminal_is_gone(log):  # (the terminal gone with the SSH session: the outputs still complete)
        with stop_signals_as_ctrl_c():  # a service stopped (systemctl/docker stop, Kubernetes), or the SSH session
            # that started the run closed, loses nothing either
            failed = _run_inputs(console, inputs, out_dir, calibration_path, options, starts, reconnect, status, first)
        if new and failed and failed != "interrupted" and len(inputs) > 1 and not reconnect:
            from .run_parts import remove_a_refused_run

            if remove_a_refused_run(out_dir, inputs, new):  # every file refused: nothing new is left, as for one file
                log.close()  # (its run.log went with the rest)
                raise InputError(failed)
        status.update(state="interrupted" if failed == "interrupted" else "failed" if failed else "finished",
                      error=failed if failed and failed != "interrupted" else status.status.error,
                      next_attempt_at=None, force=True)
        s = status.status
        log.line(f"trafficcal run {s.state}: {s.vehicles} vehicles, {s.measured} measured" +
                 (f", at {s.position_s:.1f} s of the stream" if s.position_s is not None else ""))
        sys.stdout.flush()
        if failed == "interrupted":
            sys.exit(130)  # the shell's code for Ctrl-C; every output above is complete
        if failed:
            raise InputError(failed)


def _run_inputs(console: Any, inputs: list[str], out_dir: Path, calibration_path: Path | None, options: RunOptions,
                starts: list, reconnect: bool, status: Any, first: Any = None) -> str:
    """The run itself: a live stream with reconnection, one file or URI, or several files; "" when it ended by
    itself, "interrupted", or what failed.  status.json says "failed" or "interrupted" before an error or a second
    Ctrl-C leaves.  ``first``: the first frame of a single file, checked already (:func:`readable_video`)."""
    try:
        if reconnect:
            from .run_parts import run_stream

            return run_stream(console, inputs[0], out_dir, calibration_path, options)
        if len(inputs) == 1:
            summary = run_one(console, inputs[0], out_dir, calibration_path, options, first=first)
            return "interrupted" if summary.stopped == "interrupted" else ""
        from .run_parts import run_files

        return run_files(console, inputs, out_dir, calibration_path, options, starts)
    except (InputError, KeyboardInterrupt) as exc:
        status.update(state="failed" if isinstance(exc, InputError) else "interrupted",
                      error=str(exc) if isinstance(exc, InputError) else status.status.error)
        raise


def ended_short(outcome: Any, audio: bool | None = False) -> str | None:
    """Why a file's stream ended well before the duration its header states (a truncated copy, a recording cut
    off by a full disk or a crash), or None: the end of the stream looks like the end of any file, so without this
    a run over half a file reads as a run over all of it.  ``outcome``: a gst.runner.RunOutcome or a RunSummary;
    ``audio``: the file also holds audio (or None: unknown), which may simply run on past the video's end — the
    header states the longest stream's duration."""
    end, length = outcome.position_s, outcome.duration_s
    if outcome.stopped or end is None or not length or end >= length - max(1.0, 0.02 * length):
        return None
    if audio is not False:
        return (f"the video ends at {end:.1f} s of the {length:.1f} s its file states: its audio may run on "
                "longer, or the file is truncated or damaged; the vehicles up to there are measured")
    return (f"the video ends at {end:.1f} s of the {length:.1f} s its header states: the file is probably "
            "truncated or damaged; the vehicles up to there are measured")


def _has_audio(video: Path | str) -> bool | None:
    """Whether a local file holds audio (gst.discover), None for a stream or when it cannot tell."""
    if is_uri(video) or not Path(video).is_file():
        return None
    from ..gst.discover import has_audio

    return has_audio(video)


@contextmanager
def stop_signals_as_ctrl_c():
    """SIGTERM — what systemctl stop, docker stop and Kubernetes send — and SIGHUP — the terminal that started the
    run closed (an SSH session ended) — handled as Ctrl-C while the run lasts: inside a pipeline the stream is ended
    and every output completed (gst.runner), between pipelines (a reconnection's wait) KeyboardInterrupt.  Left alone
    where a program ignores the signal (SIGHUP under nohup) or outside the main thread."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    ours = [sig for sig in (signal.SIGTERM, signal.SIGHUP) if signal.getsignal(sig) is signal.SIG_DFL]
    for sig in ours:
        signal.signal(sig, signal.default_int_handler)
    try:
        yield
    finally:
        for sig in ours:
            signal.signal(sig, signal.SIG_DFL)


def names_start(video: Path | str) -> Any:
    """--start-time auto: the date and time in a file's name (a one-line error for a URI or a name without one)."""
    from ..clock import start_from_name

    if is_uri(video):
        raise InputError("--start-time auto reads each file's date and time from its name; for a live stream give "
                         "--start-time now")
    start = start_from_name(Path(video).name)
    if start is None:
        raise InputError(f"--start-time auto: no date and time in the name {Path(video).name!r} (e.g. "
                         "cam7_20261205_080000.mp4, 2026-12-05_08-00-00.mp4)")
    return start


def local_file(uri: str) -> str | None:
    """The path a ``file://`` URI names (``file:///data/cam%207.mp4`` → ``/data/cam 7.mp4``), or None for any other
    URI: a local file is read, checked and measured again as a file is, whatever way it is given."""
    from urllib.parse import unquote, urlsplit

    parts = urlsplit(uri)
    if parts.scheme.lower() != "file" or parts.netloc not in ("", "localhost"):
        return None
    return unquote(parts.path)


def is_stream(text: str | Path) -> bool:
    """Whether ``text`` is a URI read as a stream: any but a ``file://`` URI of this machine (:func:`local_file`)."""
    return is_uri(text) and local_file(str(text)) is None


def check_input(video: str) -> Path | str:
    """A URI as it is, a ``file://`` URI as the file it names; a file as a Path (click's usage error when it is
    missing or a directory)."""
    if is_stream(video):
        return video
    video = local_file(video) or video
    if not Path(video).is_file():
        raise click.BadParameter(f"File {video!r} does not exist." if not Path(video).exists() else
                                 f"{video!r} is a directory.", param_hint="'VIDEO|URI'")
    return Path(video)


@dataclass(frozen=True)
class RunOptions:
    """The settings of ``trafficcal run`` that every input of it shares."""

    detector: str | None = None
    regression_path: Path | None = None
    body_shapes: str = "auto"
    speed_limit: Any = None  # traffic_stats.SpeedLimit
    interval_min: float = 15.0
    duration_s: float | None = None
    events_url: str = ""
    no_overlay: bool = False
    gt_path: Path | None = None
    live_clock: bool = False
    start: Any = None  # datetime of the video's start, or None
    views_dir: Path | None = None  # vpdetect views-dir: the camera's views kept across parts (files, connections)
    status: Any = None  # run_status.StatusFile of --out/status.json, or None
    split_every_s: float | None = None  # --split-every: a live stream's connections end on this grid of the clock
    zone: str = ""  # --zone: where vehicles are looked for (gst_trafficcal.zone)
    orientation: str = "auto"  # --orientation: how the picture is turned (imaging.check_orientation)


def report_warnings(warnings: Sequence[str]) -> list[str]:
    """The run's warnings for report.html: all but vpdetect's on a poorly conditioned view, which the report's
    calibration section says itself."""
    from ..vanishing.conditioning import ADVICE

    return [w for w in warnings if ADVICE not in w]


def run_one(console, video: Path | str, out_dir: Path, calibration_path: Path | None, options: RunOptions,
            calibration_mode: str = "fixed", first: Any = None) -> "RunSummary":
    """One input of ``trafficcal run``: play it, print what it found, write intervals.csv and report.html;
    returns what it produced (InputError when an output could not be written).  ``first``: the file's first frame
    when the caller checked it already (:func:`readable_video`), else it is checked here."""
    from ..clock import NOW
    from ..gst.env import elements_dir
    from ..outputs import stream_start
    from ..report import ReportInputs, write_report
    from ..zone import parse_zone
    detector, regression_path, body_shapes = options.detector, options.regression_path, options.body_shapes
    speed_limit, interval_min, duration_s = options.speed_limit, options.interval_min, options.duration_s
    events_url, no_overlay, gt_path = options.events_url, options.no_overlay, options.gt_path
    live_clock, start = options.live_clock, options.start
    paths = RunPaths(out_dir)
    bbscale = (elements_dir() / "python" / "bbscale.py").exists()
    description = pipeline_description(video, paths, calibration_path, detector, overlay=not no_overlay,
                                       bbscale=bbscale, scale_regression=regression_path, body_shapes=body_shapes,
                                       speed_limit=speed_limit,
                                       start_time=NOW if live_clock else start.isoformat() if start else "",
                                       events_url=events_url, calibration_mode=calibration_mode,
                                       interval_min=interval_min, views_dir=options.views_dir, zone=options.zone,
                                       orientation=options.orientation)
    shown = description.replace(str(video), shown_source(video))  # no password on the screen
    if events_url:
        from ..publish import redacted

        shown = shown.replace(events_url, redacted(events_url))
    console.print(f"[bold]Pipeline[/] {shown}", highlight=False, soft_wrap=True)
    zone = parse_zone(options.zone)
    # (a part's folder of several files not made yet: there are no earlier outputs to speak of)
    frame = first if first is not None or is_uri(video) else readable_video(video, out_dir if out_dir.is_dir() else
                                                                            None, zone, options.orientation)
    summary = measure_video(video, out_dir, description, console,
                            keep=(calibration_path,) if calibration_path is not None else (), stop_after_s=duration_s,
                            status=options.status, zone=zone, orientation=options.orientation)
    if live_clock:  # the speedometer took the clock at the first frame: the events say when that was
        start = stream_start(summary.events)
    if summary.stopped:
        at = f"{summary.position_s:.1f} s" if summary.position_s is not None else "the start"
        why = "--duration reached" if summary.stopped != "interrupted" else \
            f"stopped ({summary.stopped_by})" if summary.stopped_by in ("SIGTERM", "SIGHUP") else "interrupted (Ctrl-C)"
        from .terminal import log_line, stderr_console

        stderr_console().print(f"[yellow]{why}[/] at {at}: the outputs cover the video up to there", highlight=False)
        log_line(f"{why} at {at}: the outputs cover the video up to there")

    cal = summary.calibration
    if cal is None or cal.camera is None:
        why = cal.reason if cal is not None and cal.reason else "the stream ended before it converged"
        console.print(f"[bold]Calibration[/]: no vanishing points ({why})")
    else:
        c = cal.camera
        scale = f"scale {c.scale:.3f} m" if c.scale is not None else "no scale"
        console.print(f"[bold]Calibration[/] ({cal.source}, {cal.state}): VP1 ({c.vp1[0]:.1f}, {c.vp1[1]:.1f}), "
                      f"VP2 ({c.vp2[0]:.1f}, {c.vp2[1]:.1f}), f = {c.focal:.0f} px, {scale}", highlight=False)
        from ..vanishing.conditioning import ADVICE
        from .calibrate import print_conditioning

        print_conditioning(console, cal, warned=any(ADVICE in w for w in summary.warnings))
    print_moves(console, summary)
    print_remeasured(console, summary.remeasured, events_url, speeds=summary.remeasured_speeds)
    print_vehicles(console, summary.events, speed_limit)
    print_not_counted(console, summary.not_counted)
    watched = (summary.position_s or 0) >= EMPTY_ZONE_S or (not is_uri(video) and not summary.stopped)  # a whole
    if options.zone and not summary.events and watched:  # file, or a minute: the zone, not the road, is the likelier
        # fault (a run stopped early, a short reconnection or a quiet night's part may just have had no vehicle)
        empty = (f"no vehicle stood in the detection zone ({options.zone}) in {summary.position_s or 0:.0f} s: check "
                 "where it lies (overlay.mp4, or the grid picture of trafficcal calibrate --zone)")
        summary.warnings.append(empty)
        if options.status is not None:
            options.status.warning(empty)
    from .terminal import say

    for w in summary.warnings:
        say(console, w)

    ev = None
    if gt_path is not None:
        ev = evaluate_run(gt_path, summary, paths)
        if ev is not None and ev.speed is not None and ev.speed.abs_kmh.n:
            s = ev.speed.abs_kmh
            console.print(f"[bold]Against {gt_path.name}[/]: speed error {s.mean:.2f} mean / {s.median:.2f} median "
                          f"/ {s.p95:.2f} p95 km/h, recall {ev.speed.recall:.3f}, false positives "
                          f"{ev.speed.false_positives}", highlight=False)
        elif ev is None:
            say(console, f"no evaluation against {gt_path.name}: the calibration has no scale")
    try:
        write_report(paths.report, ReportInputs(
            events=summary.events, calibration=cal, evaluation=ev,
            frame=first_frame(video, options.orientation) if frame is None else frame,
            ground_truth_name=str(gt_path or ""),
            title=f"gst-trafficcal run: {getattr(video, 'name', None) or shown_source(video)}",
            source=shown_source(video),
            speed_limit_kmh=speed_limit, interval_s=60 * interval_min, start_time=start,
            covered=[(0.0, summary.watched_s)] if summary.watched_s else None,
            remeasured=(summary.remeasured, summary.remeasured_speeds), not_counted=summary.not_counted,
            paths=() if summary.moves else lane_paths(paths.results, summary.events),  # moved: not on this frame
            zone=zone, warnings=report_warnings(summary.warnings)))
    except InputError as exc:
        summary.errors.append(str(exc))
    written = [n for n in OUTPUTS if (out_dir / n).exists()]
    console.print(f"[bold]Wrote[/] {out_dir}: {', '.join(written)}", highlight=False)
    if summary.errors:
        raise InputError("; ".join(summary.errors))
    n = len(summary.events)
    if summary.moves and (cal is None or not summary.has_scale):
        after = sum(e.first_timestamp_s >= summary.moves[-1][0] for e in summary.events)
        click.echo(f"trafficcal: warning: the camera moved at {summary.moves[-1][0]:.1f} s and the new view's "
                   f"calibration was not complete when the run ended: the {after} vehicles since are written "
                   "unmeasured with the reason; the ones before were measured with the calibration in force then",
                   err=True)
    elif cal is None or cal.camera is None:
        why = cal.reason if cal is not None and cal.reason else "the stream ended before it converged"
        click.echo(f"trafficcal: warning: no speeds: the calibration did not converge ({why}); {n} vehicles "
                   "written unmeasured with the reason. Use a longer video, or give --calibration CAL.json "
                   "(with a scale)", err=True)
    elif not summary.has_scale:
        click.echo(f"trafficcal: warning: no speeds: speeds need a scale, and none is known (the calibration has "
                   f"vanishing points only); {n} vehicles written with speed null and the reason. Give "
                   "--calibration CAL.json with a scale (e.g. from `trafficcal calibrate-manual`)"
                   + ("; bbscale found none (its warning above says why)" if bbscale else
                      ", or install the bbscale element"), err=True)
    return summary
