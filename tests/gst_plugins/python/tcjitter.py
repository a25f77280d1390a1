"""Test element ``tcjitter``: frames timed by when they arrive, as a source with ``do-timestamp=true`` times them.

Each buffer's PTS is delayed by a random ``0 .. jitter`` seconds (seeded: the same times every run) and kept
increasing by at least a millisecond, as arrival times on a busy machine or network are: the frames' true times
plus a varying latency.  The frames themselves are untouched.

With ``smooth`` > 1 the jittered times are then smoothed as a constant-rate stream's could be: each frame is given
the time of a line fitted to the last ``smooth`` frames' (index, jittered time), the frame's own included (for
benchmarks/frame_jitter.py: what smoothed times would do to the speeds; it takes no frame to be missing).
"""

from collections import deque

import random

from gst_trafficcal.gst._gi import GObject, Gst, GstBase

_RW = GObject.ParamFlags.READWRITE


class TcJitter(GstBase.BaseTransform):
    __gtype_name__ = "GstTcJitter"
    __gstmetadata__ = ("tcjitter", "Filter/Video", "gst-trafficcal test: frames timed by a jittery arrival",
                       "gst-trafficcal tests")
    __gsttemplates__ = (Gst.PadTemplate.new("sink", Gst.PadDirection.SINK, Gst.PadPresence.ALWAYS,
                                            Gst.Caps.new_any()),
                        Gst.PadTemplate.new("src", Gst.PadDirection.SRC, Gst.PadPresence.ALWAYS,
                                            Gst.Caps.new_any()))
    __gproperties__ = {
        "jitter": (float, "Jitter", "Largest delay added to a frame's time (seconds)", 0.0, 10.0, 0.0, _RW),
        "seed": (int, "Seed", "Seed of the delays", 0, 2**31 - 1, 0, _RW),
        "smooth": (int, "Smooth", "Frames of the line fit that smooths the jittered times (0, 1: none)", 0, 10000, 0,
                   _RW),
    }

    def __init__(self):
        super().__init__()
        self.jitter, self.seed, self.smooth = 0.0, 0, 0
        self._rng, self._last, self._recent, self._k, self._smoothed = None, None, deque(), 0, 0

    def do_get_property(self, prop):
        return getattr(self, prop.name)

    def do_set_property(self, prop, value):
        setattr(self, prop.name, value)

    def do_start(self):
        self._rng, self._last, self._recent, self._k, self._smoothed = random.Random(self.seed), None, deque(), 0, 0
        return True

    def do_transform_ip(self, buffer):
        if buffer.pts == Gst.CLOCK_TIME_NONE:
            return Gst.FlowReturn.OK
        pts = buffer.pts + int(self._rng.uniform(0.0, self.jitter) * Gst.SECOND)
        if self._last is not None:
            pts = max(pts, self._last + Gst.MSECOND)
        self._last = pts
        if self.smooth > 1:
            import numpy as np

            self._recent.append((self._k, pts))
            self._k += 1
            while len(self._recent) > self.smooth:
                self._recent.popleft()
            if len(self._recent) >= 3:
                k, t = np.array(self._recent, dtype=np.float64).T
                slope, intercept = np.polyfit(k, t, 1)
                pts = max(int(intercept + slope * k[-1]), self._smoothed + 1 if self._smoothed else 0)
            self._smoothed = pts
        buffer.pts = pts
        buffer.dts = Gst.CLOCK_TIME_NONE
        return Gst.FlowReturn.OK


GObject.type_register(TcJitter)
__gstelementfactory__ = ("tcjitter", Gst.Rank.NONE, TcJitter)
