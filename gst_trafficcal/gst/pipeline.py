"""Run a pipeline to completion from Python: feed frames through ``appsrc``, collect what reaches ``appsink``.

For tests and tools that must exercise elements through real GStreamer pipelines (GstCheck's harness
is not usable from Python). The description names its ends ``appsrc name=src`` (optional) and
``appsink name=sink`` (optional; without it the run waits for EOS on the bus)::

    run = run_pipeline("appsrc name=src ! vpdetect ! appsink name=sink", frames, caps="video/x-raw,...")
    run.frames[-1].calibration, run.frames[0].rois, run.messages

Errors posted on the bus raise :class:`PipelineError` with the element's message.
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..calibration import Calibration
from ._gi import Gst, GstVideo
from .buffers import buffer_from_bgr, buffer_from_planes, format_name, frame_gray, pts_seconds, video_info_from_caps
from .calibration_event import parse_calibration_event
from .meta import RoiRecord, read_vehicle_rois, structure_to_dict


class PipelineError(RuntimeError):
    """An ERROR message on the bus, or a pipeline that cannot be built or does not finish."""


@dataclass
class SinkFrame:
    """What one buffer carried when it reached the appsink."""

    index: int
    pts: float | None
    frame_size: tuple[int, int]
    format: str
    rois: list[RoiRecord]
    calibration: Calibration | None  # latest calibration event received before this buffer
    gray: np.ndarray | None = None  # a copy of the grey image when keep_gray=True


@dataclass
class BusMessage:
    source: str
    name: str
    fields: dict[str, Any]


@dataclass
class PipelineRun:
    frames: list[SinkFrame] = field(default_factory=list)
    messages: list[BusMessage] = field(default_factory=list)
    calibrations: list[Calibration] = field(default_factory=list)  # every calibration event at the sink
    warnings: list[str] = field(default_factory=list)  # WARNING messages: "element: text"
    infos: list[str] = field(default_factory=list)  # INFO messages: "element: text"


def _error_text(msg: Gst.Message) -> str:
    err, debug = msg.parse_error()
    src = msg.src.get_name() if msg.src else "pipeline"
    return f"{src}: {err.message}" + (f" ({debug})" if debug else "")


def run_pipeline(
    description: str | Gst.Pipeline,
    frames: Iterable[np.ndarray | Sequence[np.ndarray] | Gst.Buffer] | None = None,
    caps: str | None = None,
    *,
    fps: float = 25.0,
    on_buffer: Callable[[Gst.Buffer, GstVideo.VideoInfo], None] | None = None,
    keep_gray: bool = False,
    timeout: float = 120.0,
) -> PipelineRun:
    """Run ``description`` until EOS and return what reached ``appsink name=sink``.

    ``description`` may also be a pipeline built before (and run before: it is left in NULL), to run the same
    element instances again, as an NVR restarts a pipeline when it reconnects.

    ``frames`` (pushed into ``appsrc name=src`` with ``caps``, timestamps i/fps) may be packed BGR
    images (converted to the caps' format), lists of planes (laid out with the caps' strides) or
    ready ``Gst.Buffer`` objects (which keep their own timestamps when they have them: timestamps going back).
    ``on_buffer(buffer, video_info)`` is called for each sink buffer while it is valid (do not keep the buffer).
    ``timeout`` (seconds) guards against hangs only.
    """
    if isinstance(description, Gst.Pipeline):
        pipeline, description = description, description.get_name()
    else:
        try:
            pipeline = Gst.parse_launch(description)
        except Exception as exc:  # GLib.Error from the parser
            raise PipelineError(f"cannot build pipeline {description!r}: {exc}") from None
    src = pipeline.get_by_name("src")
    sink = pipeline.get_by_name("sink")
    run = PipelineRun()
    order: collections.deque[Calibration | None] = collections.deque()
    latest: list[Calibration | None] = [None]

    if sink is not None:
        sink.set_property("sync", False)
        sink.set_property("emit-signals", False)

        def probe(pad: Gst.Pad, info: Gst.PadProbeInfo) -> Gst.PadProbeReturn:
            if info.type & Gst.PadProbeType.BUFFER:
                order.append(latest[0])
            else:
                cal = parse_calibration_event(info.get_event())
                if cal is not None:
                    latest[0] = cal
                    run.calibrations.append(cal)
            return Gst.PadProbeReturn.OK

        probe_id = sink.get_static_pad("sink").add_probe(
            Gst.PadProbeType.BUFFER | Gst.PadProbeType.EVENT_DOWNSTREAM, probe
        )

    if frames is not None and src is None:
        raise PipelineError(f"frames given but the pipeline has no 'appsrc name=src': {description!r}")
    if src is not None:
        if caps is None:
            raise PipelineError("appsrc frames need caps")
        src.set_property("caps", Gst.Caps.from_string(caps))
        src.set_property("format", Gst.Format.TIME)
        src.set_property("block", True)  # back-pressure: the feeder waits instead of queueing every frame
    bus = pipeline.get_bus()
    while bus.pop() is not None:  # a pipeline run before: what its stop posted is not this run's
        pass
    feeder_error: list[BaseException] = []
    feeder = None
    try:
        if pipeline.set_state(Gst.State.PLAYING) == Gst.StateChangeReturn.FAILURE:
            _raise_bus_error(bus, run, f"pipeline {description!r} failed to start")
        if src is not None:
            feeder = threading.Thread(target=_feed, args=(src, frames or [], caps, fps, feeder_error), daemon=True)
            feeder.start()
        deadline = time.monotonic() + timeout
        index = 0
        while True:
            if feeder_error:
                raise feeder_error[0]
            if sink is not None:
                sample = sink.emit("try-pull-sample", 20 * Gst.MSECOND)
                if sample is not None:
                    run.frames.append(_sink_frame(sample, index, order, on_buffer, keep_gray))
                    index += 1
                    continue
            # the pipeline posts EOS once every sink got it (appsink: once all samples were pulled)
            if _drain_bus(bus, run, wait=sink is None):
                break
            if time.monotonic() > deadline:
                raise PipelineError(f"pipeline did not finish within {timeout:.0f} s: {description!r}")
    finally:
        pipeline.set_state(Gst.State.NULL)  # unblocks a feeder waiting in push-buffer
        if feeder is not None:
            feeder.join(timeout=10)
        if sink is not None:  # a pipeline run again reports to its own run only
            sink.get_static_pad("sink").remove_probe(probe_id)
    return run


def _feed(src: Gst.Element, frames: Iterable[Any], caps: str, fps: float, errors: list[BaseException]) -> None:
    """Push ``frames`` then end-of-stream (runs in its own thread; exceptions go to ``errors``)."""
    try:
        duration = int(Gst.SECOND / fps)
        info = None
        for i, frame in enumerate(frames):
            if isinstance(frame, Gst.Buffer):
                buf = frame  # as is: lets tests offer caps we do not support
            else:
                info = info or video_info_from_caps(caps)
                if isinstance(frame, np.ndarray) and frame.ndim == 3 and frame.shape[2] == 3:
                    buf = buffer_from_bgr(frame, info)  # packed BGR image
                elif isinstance(frame, np.ndarray) and frame.ndim == 2:
                    buf = buffer_from_planes([frame], info)  # a single-plane (grey) image
                else:
                    buf = buffer_from_planes(list(frame), info)  # explicit planes
            if not (isinstance(frame, Gst.Buffer) and frame.pts != Gst.CLOCK_TIME_NONE):  # a ready one keeps its own
                buf.pts = i * duration
                buf.duration = duration
            if src.emit("push-buffer", buf) != Gst.FlowReturn.OK:
                return  # flushing or an error: the bus carries the reason
        src.emit("end-of-stream")
    except BaseException as exc:  # noqa: BLE001 -- handed to the main thread
        errors.append(exc)


def _sink_frame(sample: Gst.Sample, index: int, order: collections.deque, on_buffer: Any, keep_gray: bool) -> SinkFrame:
    buf = sample.get_buffer()
    info = GstVideo.VideoInfo.new_from_caps(sample.get_caps())
    size = (int(info.width), int(info.height))
    gray = None
    if keep_gray:
        with frame_gray(buf, info) as g:
            gray = g.copy()
    if on_buffer is not None:
        on_buffer(buf, info)
    return SinkFrame(index=index, pts=pts_seconds(buf), frame_size=size, format=format_name(info),
                     rois=read_vehicle_rois(buf, size), calibration=order.popleft() if order else None, gray=gray)


def _drain_bus(bus: Gst.Bus, run: PipelineRun, wait: bool) -> bool:
    """Handle pending bus messages; True at EOS. Raises PipelineError on ERROR."""
    mask = (Gst.MessageType.ERROR | Gst.MessageType.EOS | Gst.MessageType.ELEMENT | Gst.MessageType.WARNING
            | Gst.MessageType.INFO)
    while True:
        msg = bus.timed_pop_filtered(50 * Gst.MSECOND if wait else 0, mask)
        if msg is None:
            return False
        if msg.type == Gst.MessageType.ERROR:
            raise PipelineError(_error_text(msg))
        if msg.type == Gst.MessageType.EOS:
            return True
        if msg.type == Gst.MessageType.WARNING:
            w, _ = msg.parse_warning()
            run.warnings.append(f"{msg.src.get_name() if msg.src else 'pipeline'}: {w.message}")
            continue
        if msg.type == Gst.MessageType.INFO:
            i, _ = msg.parse_info()
            run.infos.append(f"{msg.src.get_name() if msg.src else 'pipeline'}: {i.message}")
            continue
        s = msg.get_structure()
        if s is not None:
            run.messages.append(BusMessage(msg.src.get_name() if msg.src else "", s.get_name(), structure_to_dict(s)))


def _raise_bus_error(bus: Gst.Bus, run: PipelineRun, fallback: str) -> None:
    _drain_bus(bus, run, wait=True)
    raise PipelineError(fallback)
