"""Whether a stream's frame times jitter: times of arrival (a source with ``do-timestamp=true``, frames decoded in
bursts) rather than of capture.  A speed is road distance over the time between two sightings, so a frame time off
by some milliseconds puts the speed off; the speedometer says so once (:class:`FrameJitter`).

Measured with ``.venv/bin/python benchmarks/frame_jitter.py`` (the speedometer tests' cuboid clip, 12.5 fps, the
true boxes; each frame delayed by a random 0..J ms, seeds 0-2): the mean speed error of 0.16 km/h (15 of 18 vehicles
measured) became 0.19-0.26 at 0-20 ms, 0.27-0.40 at 0-40 ms and 0.39-0.75 km/h at 0-80 ms with 13 measured; the
warning came at 0-40 and 0-80 ms.  Smoothed by a line fit over the last 50 frames' times (possible for a
constant-rate stream without dropped frames; not done by the elements) the 0-80 ms runs measured 15 again at 0.29-0.35.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

WINDOW = 100  # frame intervals looked at together
LIMIT = 0.1  # the intervals' median deviation from their median, as a fraction of it, above which they jitter


@dataclass
class FrameJitter:
    """Frame times in; once, the text saying that their intervals jitter (their median absolute deviation over
    :data:`WINDOW` intervals above :data:`LIMIT` of the median interval).  A camera's own timestamps keep a constant
    interval (0 deviation), and so do dropped frames: whole multiples of the caps' ``interval``, however many, and a
    few among many when the caps give no rate."""

    interval: float | None = None  # the caps' frame interval (s) when they give a rate, else the intervals' median
    window: int = WINDOW
    limit: float = LIMIT
    said: bool = False
    _last: float | None = None
    _intervals: list[float] = field(default_factory=list)

    def add(self, t: float) -> str | None:
        """The frame at ``t`` (seconds, increasing); the warning's text the first time a window of intervals
        jitters, else None."""
        last, self._last = self._last, t
        if self.said or last is None or t <= last:
            return None
        self._intervals.append(t - last)
        if len(self._intervals) < self.window:
            return None
        dts, self._intervals = np.array(self._intervals), []
        median = self.interval or float(np.median(dts))
        # deviation from the nearest whole number of frame intervals: frames dropped (a leaky queue behind a slow
        # machine, a camera's own drops) leave whole multiples of the caps' interval, however many they are
        spread = float(np.median(np.abs(dts - median * np.maximum(np.round(dts / median), 1))))
        if median <= 0 or spread <= self.limit * median:
            return None
        self.said = True
        return (f"the frame times jitter: intervals of {median * 1000:.0f} ms vary by {spread * 1000:.0f} ms (median "
                f"deviation over {len(dts)} frames, from {dts.min() * 1000:.0f} to {dts.max() * 1000:.0f} ms), as "
                "times of arrival do (a source with do-timestamp=true, frames decoded in bursts), not times of "
                "capture; a speed is distance over time, so the speeds scatter and fewer vehicles are measured: "
                "time the frames by the camera's own timestamps (drop do-timestamp=true; an RTSP camera's rtspsrc "
                "gives them); said once")
