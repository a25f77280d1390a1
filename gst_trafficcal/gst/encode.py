"""H.264 MP4 writer fed through ``appsrc`` with explicit timestamps (for videos with dropped frames).

The synthetic generator's plain writer pipes raw frames to ``gst-launch-1.0``, which can only number them
at a constant rate; when frames are dropped the video must keep the real capture times (a gap in the
PTS), so those frames are pushed here with their own PTS and duration.
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np

from ..errors import InputError
from ._gi import Gst


class AppsrcH264Writer:
    """Push I420 frames with PTS (seconds) into ``appsrc ! <encoder chain, ending in a filesink>`` writing ``path``."""

    def __init__(self, path: Path, size: tuple[int, int], fps: float, encoder_chain: str):
        W, H = size
        fr = Fraction(fps).limit_denominator(1001)
        self.path = path
        self.frame_dur = int(round(Gst.SECOND / fps))
        desc = (f"appsrc name=src format=time is-live=false block=true max-bytes={W * H * 6} "
                f"caps=video/x-raw,format=I420,width={W},height={H},framerate=0/1,"
                f"max-framerate={fr.numerator}/{fr.denominator} ! " + encoder_chain + " name=tcout")
        try:
            self.pipeline = Gst.parse_launch(desc)
        except Exception as exc:  # GLib.Error
            raise InputError(f"cannot build the encoder pipeline: {exc}") from None
        self.pipeline.get_by_name("tcout").set_property("location", str(path))  # not parsed: any path works
        self.src = self.pipeline.get_by_name("src")
        self.pipeline.set_state(Gst.State.PLAYING)

    def push(self, i420: np.ndarray, pts: float | None) -> None:
        buf = Gst.Buffer.new_wrapped(i420.tobytes())
        if pts is not None:
            buf.pts = int(round(pts * Gst.SECOND))
            buf.duration = self.frame_dur
        if self.src.emit("push-buffer", buf) != Gst.FlowReturn.OK:
            self._raise_bus_error()

    def _raise_bus_error(self) -> None:
        msg = self.pipeline.get_bus().pop_filtered(Gst.MessageType.ERROR)
        detail = msg.parse_error()[0].message if msg is not None else "pipeline refused the frame"
        self.pipeline.set_state(Gst.State.NULL)
        raise InputError(f"{self.path}: video encoding failed: {detail}")

    def close(self) -> None:
        self.src.emit("end-of-stream")
        bus = self.pipeline.get_bus()
        msg = bus.timed_pop_filtered(600 * Gst.SECOND, Gst.MessageType.EOS | Gst.MessageType.ERROR)
        self.pipeline.set_state(Gst.State.NULL)
        if msg is None:
            raise InputError(f"{self.path}: video encoder did not finish")
        if msg.type == Gst.MessageType.ERROR:
            raise InputError(f"{self.path}: video encoding failed: {msg.parse_error()[0].message}")
