"""Base class for our in-place video elements (vpdetect, vehicledetect, tracker, ...).

A subclass sets ``__gstmetadata__`` (and ``__gproperties__`` if any), implements
:meth:`TrafficcalTransform.transform_frame` and registers itself in its plugin file::

    class VpDetect(TrafficcalTransform):
        __gstmetadata__ = ("vpdetect", "Filter/Analyzer/Video", "...", "gst-trafficcal")

        def transform_frame(self, buffer):
            with self.gray(buffer) as gray:          # HxW uint8 view, valid inside the block
                result = library_call(gray, self.buffer_t)
            if result.calibration_changed:
                self.publish_calibration(result.calibration)
            return Gst.FlowReturn.OK

    GObject.type_register(VpDetect)          # with __gtype_name__ = "GstVpdetect": elements named vpdetect0...
    __gstelementfactory__ = ("vpdetect", Gst.Rank.NONE, VpDetect)

What the base does:

- pad templates accepting raw video in :data:`~gst_trafficcal.gst.buffers.SUPPORTED_FORMATS`;
  other caps are refused at negotiation with an error naming the caps and the remedy (videoconvert);
- runs in place; passthrough off by default so buffers are writable (metadata, drawing); set the
  class attribute ``PASSTHROUGH = True`` in elements that only look at frames;
- properties declared in ``__gproperties__`` are plain attributes initialised to their defaults
  (``"min-score"`` <-> ``self.min_score``): no ``do_get_property``/``do_set_property`` needed; a
  :data:`READY_ONLY` one set while the stream runs is kept aside until the element stops, so ``self.<name>`` holds
  the value the run started with all along the run;
- ``self.video_info`` / ``self.frame_size`` cached from the negotiated caps (hook :meth:`on_caps`);
- ``self.buffer_t``: the time of the buffer being transformed, in seconds — its stream time (its timestamp mapped
  by the segment: a file's own time, from 0 even when its timestamps start elsewhere), never going backwards
  (:class:`~gst_trafficcal.gst.buffers.StreamClock`: parts joined by ``concat``, a seek back), the same in every
  element (after a jump the first element's clock offset goes downstream before the frame, :mod:`.clock_event`:
  frames flushed between two elements do not put them apart); None when the buffer has no timestamp;
- hook :meth:`on_jump` at the first timed buffer after the stream jumped (a flushing seek, either way; timestamps
  gone back: parts joined by ``concat``; another stream whose times do not go on: ``input-selector`` switched):
  nothing seen before it continues after it (tracks end there);
- keeps the latest calibration received from upstream in ``self.calibration`` (hook
  :meth:`on_calibration`) and forwards the sticky event downstream; other custom downstream events (speedometer's
  finished vehicles) go to hook :meth:`on_custom_event`;
- :meth:`publish_calibration` sends a new calibration downstream (sticky event, before the next
  buffer or before EOS) and posts it on the bus; :meth:`post_element_message`, :meth:`post_warning`,
  :meth:`post_error` for the bus; hook :meth:`on_eos` runs before EOS goes downstream;
- keeps the QoS events of a sink that syncs (frames late) from a file's decoder: a file's every frame is analysed
  (from a live source they go upstream, which may skip late frames);
- ``do_stop`` forgets the run (calibration, clock, caps, said-once flags): an element started again (an NVR's
  reconnect) begins as a new one. Subclasses set their own per-run state in ``do_start`` (never in ``__init__``
  alone) and call ``super().do_stop()`` last when they override ``do_stop``.

Never keep a reference to a buffer after ``transform_frame`` returns (copy the data you need).
"""

from __future__ import annotations

import importlib.util
import os
import re
import traceback
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from ..calibration import Calibration
from ._gi import GLib, GObject, Gst, GstBase, GstVideo
from .buffers import (SUPPORTED_FORMATS, StreamClock, format_name, frame_bgr, frame_gray, frame_planes,
                      stream_seconds, video_caps_string, video_info_from_caps)
from .calibration_event import calibration_event, calibration_message, parse_calibration_event
from .clock_event import GivenClock, clock_event, parse_clock_event
from .meta import make_structure
from .segment_clocks import SEGMENTS


READY_ONLY = GObject.ParamFlags(int(GObject.ParamFlags.READWRITE) | Gst.PARAM_MUTABLE_READY)
"""Flags of a property the element reads when it starts: gst-inspect-1.0 says "changeable only in NULL or READY
state", and a change while the stream runs is answered with a warning (it applies from the next start)."""
LIVE = GObject.ParamFlags(int(GObject.ParamFlags.READWRITE) | Gst.PARAM_MUTABLE_PLAYING)
"""Flags of a property read for every frame: changing it while the stream runs takes effect at once."""


NEW_STREAM_FRAMES = 2
"""Frames looked at after another stream starts (input-selector switched) for one that does not go on from the last:
the old source's frame on its way when the switch came may still pass after the new one's STREAM_START."""


def video_pad_templates(formats: tuple[str, ...] = SUPPORTED_FORMATS) -> tuple[Gst.PadTemplate, Gst.PadTemplate]:
    """(src, sink) always-pad templates for raw video in ``formats``."""
    caps = Gst.Caps.from_string(video_caps_string(formats))
    return (
        Gst.PadTemplate.new("src", Gst.PadDirection.SRC, Gst.PadPresence.ALWAYS, caps),
        Gst.PadTemplate.new("sink", Gst.PadDirection.SINK, Gst.PadPresence.ALWAYS, caps),
    )


class TrafficcalTransform(GstBase.BaseTransform):
    """In-place raw-video transform shared by all gst-trafficcal elements (see the module doc)."""

    __gstmetadata__ = ("trafficcal-base", "Filter/Video", "gst-trafficcal base class", "gst-trafficcal")
    __gsttemplates__ = video_pad_templates()

    PASSTHROUGH: bool = False
    """True for elements that never modify buffers (not even metadata): avoids buffer copies."""

    def __init__(self) -> None:
        super().__init__()
        self.set_in_place(True)
        self.set_passthrough(self.PASSTHROUGH)
        self._next_start: dict[str, Any] = {}  # READY_ONLY properties set while streaming: applied at the stop
        self._reset_run()
        for pspec in self.list_properties():  # property "min-score" <-> attribute self.min_score
            if pspec.owner_type.is_a(TrafficcalTransform.__gtype__):  # declared in Python, not by GstBaseTransform
                setattr(self, _attr(pspec.name), pspec.default_value)

    def _reset_run(self) -> None:
        """The state of one run (start to stop), as a new element has it: set at creation and again at every stop,
        so that an element started again (an NVR's reconnect: NULL or READY, then PLAYING) behaves like a new one
        instead of carrying the last run's calibration, clock and caps into the next."""
        self.video_info: GstVideo.VideoInfo | None = None
        self.frame_size: tuple[int, int] | None = None
        self.calibration: Calibration | None = None
        self.stream_clock = StreamClock()
        self.buffer_t: float | None = None
        self._segment: Gst.Segment | None = None  # the last SEGMENT event's: buffer_t is stream time
        self._segment_seqnum: int | None = None  # its seqnum (a seek's after a flushing seek)
        self._timed_seqnum: int | None = None  # the segment seqnum of the last frame timed
        self._stream_id: tuple[str, int | None] | None = None  # the last STREAM_START's stream-id and group-id
        self._new_stream = 0  # frames left to look at after another stream started (NEW_STREAM_FRAMES)
        self._flushed_mid_run = False  # a FLUSH_STOP (a flushing seek) after frames: on_jump at the next timed one
        # the last FLUSH_STOP's seqnum and how many of that seqnum came: a seek the source performs twice (asked of a
        # pipeline with a tee, by both sinks) flushes twice with one seqnum, and each flush is decided on anew
        self._flushes: tuple[int, int] | None = None
        self._given_offset: GivenClock | None = None  # the clock an element upstream gave the next frame
        self._said_untimed = False  # warn_untimed: said once per run
        self._said_non_square = False  # warn_non_square: said once per run
        self._views_warned = False  # keep_scale_view: said once per run
        self._pending_calibration: Calibration | None = None
        self._refused_caps: set[str] = set()
        self._streaming = False  # caps negotiated, until stopped: READY_ONLY properties are read by now
        self._framed = False  # a frame came in this run
        self._live: bool | None = None  # whether the source is live (_upstream_live), once asked
        self._held_at_caps: list[tuple[bool, str]] = []  # (an error?, text) about these caps, said at the first frame

    # ------------------------------------------------------------------ properties

    def do_get_property(self, prop: GObject.ParamSpec) -> Any:
        """Properties declared in ``__gproperties__`` are plain attributes (dashes become underscores); a READY_ONLY
        one set while the stream runs answers its new value, which the element reads from the next start."""
        name = _attr(prop.name)
        return self._next_start[name] if name in self._next_start else getattr(self, name)

    def do_set_property(self, prop: GObject.ParamSpec, value: Any) -> None:
        """Set the attribute; a READY_ONLY property set while the stream runs is kept aside until the element stops
        (the attribute, which the element may read at any time — after a camera move, at a size change, at the end —
        keeps the value it started with), so that the change really applies from the next start, as warned."""
        if self._streaming and int(prop.flags) & Gst.PARAM_MUTABLE_READY:
            self.post_warning(f"{self.get_factory().get_name()}: {prop.name} was set to {value!r} while the stream "
                              "runs; it is read when the element starts, so the change applies from the next start "
                              "(set it in the NULL or READY state: a prerolled PAUSED pipeline has started)")
            self._next_start[_attr(prop.name)] = value
            return
        self._next_start.pop(_attr(prop.name), None)
        setattr(self, _attr(prop.name), value)

    # ------------------------------------------------------------------ hooks for subclasses
    def on_caps(self, info: GstVideo.VideoInfo) -> None:
        """Called when caps are (re)negotiated; ``self.video_info``/``self.frame_size`` are set."""

    def on_calibration(self, cal: Calibration) -> bool:
        """Called for each calibration event from upstream; return False to not forward it."""
        return True

    def on_eos(self) -> None:
        """Called at end of stream before EOS goes downstream (post final messages, save files, publish)."""

    def on_custom_event(self, event: Gst.Event) -> bool:
        """Called for each non-sticky custom downstream event from upstream (e.g. speedometer's finished vehicles,
        :mod:`.vehicle_event`); return False to not forward it."""
        return True

    def on_jump(self, t: float) -> None:
        """Called before the frame at ``t`` (its ``buffer_t``) when the stream jumped just before it: a flushing seek
        (a player seeking back or forward) or timestamps gone back (parts joined by ``concat``).  The frames before
        and after show other moments: what follows a vehicle (tracks, measurements) ends there."""

    def transform_frame(self, buffer: Gst.Buffer) -> Gst.FlowReturn:
        """Process one frame in place (override this, not ``do_transform_ip``)."""
        return Gst.FlowReturn.OK

    # ------------------------------------------------------------------ frame access
    def gray(self, buffer: Gst.Buffer) -> Any:
        """``frame_gray(buffer, self.video_info)``: context manager yielding HxW uint8."""
        return frame_gray(buffer, self.video_info)

    def bgr(self, buffer: Gst.Buffer, size: tuple[int, int] | None = None) -> Any:
        """``frame_bgr(buffer, self.video_info, size)``: context manager yielding HxWx3 uint8 BGR (reduced to
        ``size`` when given)."""
        return frame_bgr(buffer, self.video_info, size)

    @contextmanager
    def planes(self, buffer: Gst.Buffer, writable: bool = False) -> Iterator[list[np.ndarray]]:
        """``frame_planes(buffer, self.video_info, writable)``."""
        with frame_planes(buffer, self.video_info, writable) as planes:
            yield planes

    @contextmanager
    def gray_and_chroma(self, buffer: Gst.Buffer, colour: bool) -> Iterator[tuple[np.ndarray, np.ndarray | None]]:
        """The frame's luma and, when ``colour``, its U/V planes (H' x W' x 2, the background model's ``chroma``;
        None for GRAY8 or when not asked): what the tracker stage feeds its background model."""
        from ..tracking.background import chroma_from_planes

        with self.gray(buffer) as gray:
            if not colour:
                yield gray, None
                return
            with self.planes(buffer) as planes:
                yield gray, chroma_from_planes(planes, format_name(self.video_info))

    # ------------------------------------------------------------------ calibration and bus
    def publish_calibration(self, cal: Calibration) -> None:
        """Send ``cal`` downstream (sticky event ahead of the next buffer) and post it on the bus."""
        self.calibration = cal
        self._pending_calibration = cal
        self.post_message(calibration_message(self, cal))

    def file_calibration_mismatch(self, cal: Calibration | None, path: str) -> str | None:
        """What is wrong when ``cal`` (read from the ``calibration-file`` at ``path``) was made for another frame
        size than the negotiated video's (its vanishing points are pixels of that size); None when it fits."""
        if cal is None or self.frame_size is None or tuple(cal.image_size) == tuple(self.frame_size):
            return None
        (w, h), (vw, vh) = cal.image_size, self.frame_size
        return (f"{path} is a calibration of {w}x{h} images but the video is {vw}x{vh} (its vanishing points are "
                f"pixels of {w}x{h}): calibrate this video's size (without the file, or trafficcal calibrate), or "
                f"scale the video to {w}x{h} before the elements (videoscale ! video/x-raw,width={w},height={h})")

    def refuse_size(self, text: str, error: bool = True) -> None:
        """Say ``text`` (an ERROR, or a WARNING when not ``error``) about the negotiated frame size: now once frames
        have come, else at the first frame if the caps still stand then.  Before the first frame the size may change:
        a stream's rotation is known from its tag, and ``videoflip video-direction=auto`` announces the stored size
        first and the turned one when the tag comes, before any frame (a calibration of the upright picture was
        refused at the first caps)."""
        if self._framed:
            (self.post_error if error else self.post_warning)(text)
        else:
            self._held_at_caps.append((error, text))

    def claim_files(self, files: Mapping[str, str], why: str | None = None) -> None:
        """Claim the output files (and folders) of ``files`` (property name -> path; empty: none) for this element
        until :meth:`release_files`: an InputError naming the other writer (and ``why`` that is wrong) when another
        running element in this process writes one of them already (:mod:`gst_trafficcal.gst.file_claims`)."""
        from .file_claims import claim

        self.release_files()
        self._claimed = claim(self, files, **({} if why is None else {"why": why}))

    def release_files(self) -> None:
        """Give back what :meth:`claim_files` claimed (at a failed start, and at the stop)."""
        from .file_claims import release

        release(self, getattr(self, "_claimed", []))
        self._claimed: list[str] = []

    def keep_scale_view(self, cal: Calibration, folder: str) -> None:
        """Keep ``cal`` (a scale found for a view) in the camera's views ``folder`` (``views-dir``, as vpdetect reads
        it), so that after a restart vpdetect announces the view with its scale at once; a folder that cannot be
        written is a warning, once, never an error (the measurement goes on)."""
        from ..calibration import save_view
        from ..errors import InputError

        if not folder:
            return
        try:
            save_view(cal, folder)
        except InputError as exc:
            if not self._views_warned:
                self._views_warned = True
                self.post_warning(f"{self.get_factory().get_name()}: the scale is not kept for a restart: {exc}")

    def post_element_message(self, name: str, fields: Mapping[str, Any]) -> bool:
        """Post an element message whose structure is ``name`` with ``fields`` (``gst-launch-1.0 -m`` shows it)."""
        return self.post_message(Gst.Message.new_element(self, make_structure(name, fields)))

    def post_error(self, text: str, debug: str | None = None, code: Gst.CoreError = Gst.CoreError.FAILED) -> None:
        """Post a GStreamer ERROR message from this element (the pipeline stops; the text is what users see)."""
        err = GLib.Error.new_literal(Gst.CoreError.quark(), text, int(code))
        self.post_message(Gst.Message.new_error(self, err, debug or ""))

    def post_warning(self, text: str, debug: str | None = None) -> None:
        """Post a GStreamer WARNING message (``gst-launch-1.0`` prints it; the pipeline goes on)."""
        err = GLib.Error.new_literal(Gst.CoreError.quark(), text, int(Gst.CoreError.FAILED))
        self.post_message(Gst.Message.new_warning(self, err, debug or ""))

    def warn_untimed(self, name: str, what: str) -> None:
        """Say once that buffers come without timestamps and what ``name`` does with them (``what``), with the fix:
        an image sequence read without a frame rate is the usual cause."""
        if not self._said_untimed:
            self._said_untimed = True
            self.post_warning(f"{name}: buffers without timestamps {what}: give the source a frame rate (an image "
                              'sequence: multifilesrc ... caps="image/jpeg,framerate=25/1")')

    def warn_non_square(self, info: GstVideo.VideoInfo, name: str) -> None:
        """Say once that the caps' pixels are not square (pixel-aspect-ratio more than 1 % off 1/1: a DVR's D1, a
        picture stored squeezed): the camera model takes image pixels as square, so the calibration and every speed
        would be off (35 % with 4/3), with the fix."""
        par = info.par_n / info.par_d if info.par_n > 0 and info.par_d > 0 else 1.0
        if abs(par - 1.0) > 0.01 and not self._said_non_square:
            self._said_non_square = True
            self.post_warning(f"{name}: the video's pixels are not square (pixel-aspect-ratio "
                              f"{info.par_n}/{info.par_d}): the calibration and the speeds take them as square "
                              "and would be off; put videoscale ! video/x-raw,pixel-aspect-ratio=1/1 before the "
                              "elements (trafficcal run does)")

    def zone_fits(self, zone: Any, size: tuple[int, int], name: str) -> bool:
        """Check a detection ``zone`` (gst_trafficcal.zone.Zone) against frames of ``size``: an ERROR (False) when it
        covers none of their pixels, a WARNING when it looks written for another resolution (both said at the first
        frame if these caps still stand then: :meth:`refuse_size`); ``name`` starts the text."""
        wrong = zone.check(size)
        if wrong:
            self.refuse_size(f"{name}: {wrong}")
            return False
        doubt = zone.doubt(size)
        if doubt:
            self.refuse_size(f"{name}: {doubt}", error=False)
        return True

    def post_info(self, text: str) -> None:
        """Post a GStreamer INFO message: something a user should know, not wrong (``gst-launch-1.0`` prints an
        INFO's debug text, so that is the text too)."""
        err = GLib.Error.new_literal(Gst.CoreError.quark(), text, int(Gst.CoreError.FAILED))
        self.post_message(Gst.Message.new_info(self, err, text))

    # ------------------------------------------------------------------ GstBaseTransform vfuncs
    def do_accept_caps(self, direction: Gst.PadDirection, caps: Gst.Caps) -> bool:
        ok = GstBase.BaseTransform.do_accept_caps(self, direction, caps)
        if not ok and direction == Gst.PadDirection.SINK and caps.is_fixed():
            key = caps.to_string()
            template = self.sinkpad.get_pad_template_caps()
            # only caps our template can never take (a converter in front would have avoided them): a
            # refusal of acceptable-looking caps is part of normal negotiation and must stay silent
            if key not in self._refused_caps and not caps.can_intersect(template):
                self._refused_caps.add(key)
                self.post_error(
                    f"cannot handle {key}: this element needs raw video in one of "
                    f"{', '.join(_template_formats(template))} (put videoconvert in front of it)",
                    debug=f"refused by accept-caps on the sink pad; accepted: {template.to_string()}",
                    code=Gst.CoreError.NEGOTIATION,
                )
        return ok

    def do_set_caps(self, incaps: Gst.Caps, outcaps: Gst.Caps) -> bool:
        try:
            info = video_info_from_caps(incaps)
        except ValueError as exc:
            self.post_error(str(exc), code=Gst.CoreError.NEGOTIATION)
            return False
        self.video_info = info
        self.frame_size = (int(info.width), int(info.height))
        self._streaming = True
        self._held_at_caps = []  # what was wrong with the caps before these no longer applies
        self.on_caps(info)
        return True

    def do_sink_event(self, event: Gst.Event) -> bool:
        cal = None
        if event.type == Gst.EventType.CUSTOM_DOWNSTREAM_STICKY:
            try:
                cal = parse_calibration_event(event)
            except Exception as exc:  # a corrupt calibration from upstream: say so, keep the old one, forward
                self.post_warning(f"ignoring invalid calibration event: {exc}")
        if cal is not None:
            self.calibration = cal
            if not self.on_calibration(cal):
                return True  # consumed: not forwarded
        elif event.type == Gst.EventType.CUSTOM_DOWNSTREAM and (given := parse_clock_event(event)) is not None:
            self._given_offset = given  # the frames after it follow it (transform: by offset or by time)
        elif event.type == Gst.EventType.CUSTOM_DOWNSTREAM:
            try:
                if not self.on_custom_event(event):
                    return True
            except Exception as exc:  # a bad event from upstream: say so, forward it, go on
                self.post_warning(f"ignoring invalid {event.get_structure().get_name()} event: {exc}")
        elif event.type == Gst.EventType.STREAM_START:  # another stream after frames: input-selector switched
            has_group, group = event.parse_group_id()  # the same file twice has one stream-id, not one group
            stream_id = (event.parse_stream_start(), group if has_group else None)
            if self._stream_id not in (None, stream_id) and self.stream_clock.last is not None:
                self._new_stream = NEW_STREAM_FRAMES
            self._stream_id = stream_id
        elif event.type == Gst.EventType.SEGMENT:
            self._segment = event.parse_segment().copy()
            self._segment_seqnum = event.get_seqnum()
        elif event.type == Gst.EventType.FLUSH_STOP:  # a flushing seek: the next frame is another moment
            self._flushed_mid_run = self._flushed_mid_run or self.stream_clock.last is not None
            self._given_offset = None
            flush = event.get_seqnum()
            self._flushes = (flush, self._flushes[1] + 1 if self._flushes and self._flushes[0] == flush else 1)
        elif event.type == Gst.EventType.EOS:
            try:
                self.on_eos()
            except Exception as exc:
                self.post_error(f"{type(exc).__name__}: {exc}", debug=traceback.format_exc())
            self._push_pending_calibration()  # published at EOS: still reaches downstream
        return GstBase.BaseTransform.do_sink_event(self, event)

    def do_src_event(self, event: Gst.Event) -> bool:
        """A QoS event (a sink that syncs saying its frames come late: a busy machine, a display) goes upstream only
        from a live source: there the decoder and videoconvert may skip late frames, as a camera cannot wait. A
        file waits for us, so it stays with us: every frame is analysed and a file gives the same vehicles, run
        after run (before, a sink such as autovideosink made the frames upstream of our elements skipped as the
        machine's load came, and the vehicles and counts changed from run to run)."""
        if event.type == Gst.EventType.QOS and not self._upstream_live():
            return True
        return GstBase.BaseTransform.do_src_event(self, event)

    def _upstream_live(self) -> bool:
        """Whether what feeds this element is live (answers a latency query as live); asked once per run, and
        taken as live while it cannot tell (no answer yet: keep GStreamer's own behaviour)."""
        if self._live is None:
            query = Gst.Query.new_latency()
            if not self.sinkpad.peer_query(query):
                return True
            self._live = bool(query.parse_latency()[0])
        return self._live

    def _push_pending_calibration(self) -> None:
        if self._pending_calibration is not None:
            cal, self._pending_calibration = self._pending_calibration, None
            self.srcpad.push_event(calibration_event(cal))

    def do_transform_ip(self, buffer: Gst.Buffer) -> Gst.FlowReturn:
        self._framed = True
        held, self._held_at_caps = self._held_at_caps, []
        for error, text in held:  # the caps refused before the first frame (refuse_size) stand: say it now
            (self.post_error if error else self.post_warning)(text)
        if any(error for error, _ in held):
            return Gst.FlowReturn.ERROR
        self._push_pending_calibration()
        clock = self.stream_clock
        jumps, offset, pts_s = len(clock.jumps), clock.offset, stream_seconds(buffer, self._segment)
        given, self._given_offset = self._given_offset, (self._given_offset if pts_s is None else None)
        seqnum, tell, switched = self._segment_seqnum, False, False
        if self._new_stream and pts_s is not None:  # another stream's first frames: a jump unless its times go on
            self._new_stream -= 1
            switched = given is not None or (not self._flushed_mid_run and not clock.continues(pts_s))
            if switched:  # decided: the frames after it are this stream's
                self._flushed_mid_run, self._new_stream = True, 0
        jump_key = self._jump_key(seqnum)
        with SEGMENTS.lock:  # one decision per flushing seek for the elements of every branch (segment_clocks)
            if given is not None and pts_s is not None:  # an element upstream timed this frame after a jump
                self.buffer_t = clock.follow(pts_s, _followed_offset(given, pts_s, seqnum))
            elif self._flushed_mid_run and _goes_on(clock, pts_s, decided := SEGMENTS.decided(jump_key)):
                self.buffer_t = clock.follow(pts_s, decided)  # an element on another branch of a tee timed it first
                tell = True
            else:
                if self._flushed_mid_run:  # go on after the latest frame of any branch, not only after ours (also of
                    # this segment's, timed by another branch before the source performed its seek a second time)
                    clock.catch_up(SEGMENTS.reached(self._timed_seqnum))
                    clock.catch_up(SEGMENTS.reached(seqnum))
                self.buffer_t = clock(pts_s, flushed=self._flushed_mid_run)
                if self.buffer_t is not None and self._flushed_mid_run:
                    SEGMENTS.decide(jump_key, clock.offset)
                # the elements downstream go on from another last frame (frames were flushed between): tell them
                tell = self.buffer_t is not None and (self._flushed_mid_run or clock.offset != offset)
            if self.buffer_t is not None:
                if switched:
                    clock.switches.append(self.buffer_t)
                SEGMENTS.reach(seqnum, self.buffer_t)
                self._timed_seqnum = seqnum
        if tell:
            self.srcpad.push_event(clock_event(clock.offset, seqnum or 0, self.buffer_t))
        try:
            if self.buffer_t is not None and (self._flushed_mid_run or len(clock.jumps) > jumps):
                self._flushed_mid_run = False
                self.on_jump(self.buffer_t)
            return self.transform_frame(buffer)
        except Exception as exc:  # a Python exception must stop the pipeline with a readable error
            self.post_error(f"{type(exc).__name__}: {exc}", debug=traceback.format_exc())
            return Gst.FlowReturn.ERROR

    def _jump_key(self, seqnum: int | None) -> tuple[int, int] | None:
        """What the decision at a jump into segment ``seqnum`` is shared under (segment_clocks): the segment and
        which of its flushes it follows (0: none, e.g. another stream after an input-selector switch)."""
        if seqnum is None:
            return None
        return seqnum, self._flushes[1] if self._flushes and self._flushes[0] == seqnum else 0

    def do_stop(self) -> bool:
        """The run is over: its state goes (a start again begins as a new element would) and the READY_ONLY
        properties set while it ran take effect. Subclasses that override this call it last."""
        self._reset_run()
        while self._next_start:
            name, value = self._next_start.popitem()
            setattr(self, name, value)
        return True


def upstream_element(element: Gst.Element, factory_name: str) -> Gst.Element | None:
    """The element made by ``factory_name`` feeding ``element`` (directly, through other elements or through bins),
    or None: how an element learns what runs before it (a tracker, bbscale, vehicledetect)."""
    seen = set()
    pads = list(element.sinkpads)
    while pads:
        peer = pads.pop().get_peer()
        if peer is None:
            continue
        if isinstance(peer, Gst.GhostPad):  # the src pad of a bin: continue inside it
            peer = peer.get_target() or peer
        owner = peer.get_parent()
        if isinstance(owner, Gst.GhostPad):  # the inner side of a bin's sink ghost pad: continue outside
            pads.append(owner)
            continue
        if not isinstance(owner, Gst.Element) or owner in seen:
            continue
        seen.add(owner)
        factory = owner.get_factory()
        if factory is not None and factory.get_name() == factory_name:
            return owner
        pads.extend(owner.sinkpads)
    return None


def _followed_offset(given: GivenClock, pts_s: float, seqnum: int | None) -> float:
    """The offset to time the frame at stream time ``pts_s`` (in the segment ``seqnum``) by what an element upstream
    ``given``: its offset in its own segment; in another (an element between made its own segment: its stream
    times may differ), the offset that gives this frame the time it gave it."""
    if given.time is None or seqnum in (None, given.seqnum):
        return given.offset
    return given.time - pts_s


def _goes_on(clock: StreamClock, pts_s: float | None, offset: float | None) -> bool:
    """Whether ``offset`` gives the frame at stream time ``pts_s`` a time after the last one of ``clock``."""
    return (pts_s is not None and offset is not None
            and (clock.last is None or round(pts_s + offset, 9) > clock.last))


def _attr(prop_name: str) -> str:
    return prop_name.replace("-", "_")


def _template_formats(template: Gst.Caps) -> list[str]:
    """Format names listed in pad template caps, in order."""
    formats: list[str] = []
    for i in range(template.get_size()):
        value = template.get_structure(i).get_value("format")
        for f in [value] if isinstance(value, str) else list(value or []):
            if f not in formats:
                formats.append(f)
    return formats


GObject.type_register(TrafficcalTransform)


def register_plugin_file(path: str | os.PathLike) -> str:
    """Register the element of a gst-python plugin file in this process; returns its factory name.

    For tests: makes ``elements/python/<name>.py`` usable by ``Gst.parse_launch`` without relying
    on GST_PLUGIN_PATH having been set before GStreamer was initialised. A factory that already
    exists (e.g. loaded by the plugin loader) is left alone.
    """
    path = Path(path)
    spec = importlib.util.spec_from_file_location(f"_tc_plugin_{path.stem}", path)
    if spec is None or spec.loader is None:
        raise FileNotFoundError(f"{path}: not a Python plugin file")
    module = importlib.util.module_from_spec(spec)
    name = _factory_name(path)
    existing = Gst.ElementFactory.find(name) if name is not None else None
    if existing is not None and existing.load() is not None:
        return name
    spec.loader.exec_module(module)
    name, rank, cls = module.__gstelementfactory__
    if not Gst.Element.register(None, name, rank, cls):
        raise RuntimeError(f"{path}: could not register element {name!r}")
    return name


def _factory_name(path: Path) -> str | None:
    """The factory name declared in a plugin file, read without importing it."""
    m = re.search(r"__gstelementfactory__\s*=\s*\(\s*[\"']([^\"']+)[\"']", path.read_text(encoding="utf-8"))
    return m.group(1) if m else None
