"""Whether a stream's frame times jitter: times of arrival (a source with ``do-timestamp=true``, frames decoded in
bursts) rather than of capture.  A speed is road distance over the time between two sightings, so a frame time off
by some milliseconds puts the speed off; the speedometer says so once (:class:`FrameJitter`) and, by default, then
takes the τ-pairs' durations from the times smoothed by a line fit (:class:`FrameRetimer`, speedometer ``retime``).

Measured with ``.venv/bin/python benchmarks/frame_jitter.py`` (the speedometer tests' cuboid clip, 12.5 fps, the
true boxes; each frame delayed by a random 0..J ms, seeds 0-2): the mean speed error of 0.16 km/h (15 of 18 vehicles
measured) became 0.19-0.27 at 0-20 ms, 0.27-0.40 at 0-40 ms and 0.38-0.75 km/h at 0-80 ms with 13 measured; the
warning came at 0-40 and 0-80 ms.  With the times smoothed once the warning came (speedometer retime=auto, the
default) 0.17-0.19 at 0-40 ms and 0.24-0.36 km/h at 0-80 ms with 14 measured (docs/speedometer.md has the table).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

WINDOW = 100  # frame intervals looked at together
LIMIT = 0.1  # the intervals' median deviation from their median, as a fraction of it, above which they jitter
RETIME_WINDOW = 50  # frames the smoothing line is fitted to (4 s at 12.5 fps, 2 s at 25 fps)
RECOUNT = 5  # latest frames that, all a frame interval off the smoothing line, are counted again
RETIME_MODES = ("auto", "off", "always")  # speedometer retime: smooth once FrameJitter found jitter, never, always
SPAN = 5  # frames of the durations a speed divides by (speedometer tau's default): how the times are told apart
REVERTS = 0.5  # the SPAN-frame durations' variance over SPAN times the intervals': below it the times revert to a line


@dataclass
class FrameJitter:
    """Frame times in; once, the text saying that their intervals jitter (their median absolute deviation over
    :data:`WINDOW` intervals above :data:`LIMIT` of the median interval) about a steady rate.  A camera's own
    timestamps keep a constant interval (0 deviation), and so do dropped frames: whole multiples of the caps'
    ``interval``, however many, and a few among many when the caps give no rate.  Intervals that vary while the
    times do not come back to a line (:func:`reverts`: a variable frame rate, a phone's in low light, timed at
    capture) are not said: they are the frames' true times, which smoothing would put off."""

    interval: float | None = None  # the caps' frame interval (s) when they give a rate, else the intervals' median
    window: int = WINDOW
    limit: float = LIMIT
    smoothed: bool = False  # the speeds' durations come from smoothed times (FrameRetimer): the warning says so
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
        off = dts - median * np.maximum(np.round(dts / median), 1)
        spread = float(np.median(np.abs(off)))
        if median <= 0 or spread <= self.limit * median or not reverts(dts):
            return None
        self.said = True
        return (f"the frame times jitter: intervals of {median * 1000:.0f} ms vary by {spread * 1000:.0f} ms (median "
                f"deviation over {len(dts)} frames, from {dts.min() * 1000:.0f} to {dts.max() * 1000:.0f} ms), as "
                "times of arrival do (a source with do-timestamp=true, frames decoded in bursts), not times of "
                "capture; a speed is distance over time, so such times scatter the speeds and lose vehicles: "
                + ("the speeds' durations are now taken from the times smoothed by a line fit over the last "
                   f"{RETIME_WINDOW} frames (speedometer retime); the camera's own timestamps are better still"
                   if self.smoothed else "smooth them (speedometer retime=auto) or time the frames by the camera's "
                   "own timestamps")
                + " (drop do-timestamp=true; an RTSP camera's rtspsrc gives them); said once")


def reverts(intervals: np.ndarray, span: int = SPAN) -> bool:
    """Whether frame times with these ``intervals`` (seconds) come back to a line, as
    times of arrival do: a frame delayed makes its interval long and the next one short, so the durations over
    ``span`` frames vary about as much as single intervals (the variance ratio is 1/span), while a rate that varies
    itself adds the intervals' variations up (the ratio is 1 for independent intervals, more for a drifting rate).
    Only times that come back to a line are smoothed well by one (at 0-40 ms of delay the ratio is 0.2; the times of
    30-45 ms intervals at random, smoothed, gave 5-frame durations 5.7 % off at the median: ``benchmarks/
    frame_jitter.py --series``)."""
    if len(intervals) <= 2 * span or not np.var(intervals) > 0:
        return False
    walk = np.cumsum(intervals)  # (variances: the mean interval takes no part)
    return float(np.var(walk[span:] - walk[:-span]) / (span * np.var(intervals))) < REVERTS


@dataclass
class FrameRetimer:
    """Frame times in, smoothed times out (seconds): each frame's time on a robust line (Theil-Sen: the median of
    the pairwise slopes, the median intercept) fitted to the last :data:`RETIME_WINDOW` frames' (frame count,
    time), its own included, so the jitter of times of arrival leaves the τ-pairs' durations — until that many
    frames came, on the line of the caps' interval's slope through their median (a free slope fitted to a few
    frames puts the latest time far off: at 12.5 fps and 0-40 ms of delay the first 10 frames' 5-frame durations
    were off by 12 ms (1σ, 20 seeds), on this line by 7, as they arrived by 16).  Streaming: one fit over the
    window per frame, no later frame looked at.

    Frames dropped on the way (a leaky queue, the camera) stay gaps: the frame count goes on by the whole number
    of the caps' frame intervals between the time a line of that slope through the window gives the frame before
    and this frame's time, at least one; when the latest :data:`RECOUNT` frames all lie a frame off that line
    (one frame delayed by over half an interval was taken for a drop) they are counted again.  Delays that spread
    over a frame interval or more (bursts of many frames) cannot be told from dropped frames.  The smoothed times
    keep increasing."""

    interval: float  # the caps' frame interval (s)
    window: int = RETIME_WINDOW
    _k: np.ndarray = field(default_factory=lambda: np.zeros(0))  # frame counts of the window's frames
    _t: np.ndarray = field(default_factory=lambda: np.zeros(0))  # ... and their times
    _line: tuple[float, float] | None = None  # (slope, intercept) of the latest fit
    _last: float | None = None  # the latest time given
    _out: float | None = None  # the latest smoothed time

    def __post_init__(self) -> None:
        if not self.interval > 0:
            raise ValueError(f"the frame interval must be positive, got {self.interval}")

    def add(self, t: float) -> float:
        """The smoothed time of the frame at ``t`` (a time not after the one before: the smoothed time before)."""
        if self._last is not None and t <= self._last:
            return float(self._out)
        if self._last is None:
            k = 0.0
        else:  # the frames since the one before, counted against the line of slope one frame interval
            frame, offset = self._counting_line()
            k = self._k[-1] + max(1.0, float(np.round((t - offset - frame * self._k[-1]) / frame)))
        self._last = t
        self._k = np.append(self._k[-(self.window - 1):], k)
        self._t = np.append(self._t[-(self.window - 1):], t)
        out = t
        if len(self._k) >= 3:
            self._fit()
            self._recount()
            slope, intercept = self._line
            out = intercept + slope * self._k[-1]
        if self._out is not None:
            out = max(out, self._out + 1e-6)
        self._out = out
        return out

    def _fit(self) -> None:
        if len(self._k) < self.window:  # a few frames: their free slope would put the latest time far off
            self._line = self._counting_line()
            return
        i, j = np.triu_indices(len(self._k), 1)
        slope = float(np.median((self._t[j] - self._t[i]) / (self._k[j] - self._k[i])))
        self._line = (slope, float(np.median(self._t - slope * self._k)))

    def _counting_line(self) -> tuple[float, float]:
        """(slope, intercept) of the line frames are counted against: its slope is the caps' frame interval — not
        the window's fitted slope, whose error the window's length would multiply and which frames counted wrong
        would pull further off — and its intercept the median over the window."""
        return self.interval, float(np.median(self._t - self.interval * self._k))

    def _recount(self) -> None:
        """A frame delayed by over half an interval is counted as a drop, one early by as much misses one: the
        latest :data:`RECOUNT` frames then all lie a frame interval off the counting line, and are counted
        again."""
        if len(self._k) <= 2 * RECOUNT:
            return
        frame, offset = self._counting_line()
        off = float(np.round(np.median(self._t[-RECOUNT:] - offset - frame * self._k[-RECOUNT:]) / frame))
        if off == 0:
            return
        # from the latest count step that can take the change (a step stays at least one frame)
        steps = np.diff(self._k)[-RECOUNT:]  # steps into the latest RECOUNT frames
        fits = np.flatnonzero(steps + off >= 1)
        if fits.size == 0:
            return
        self._k[len(self._k) - RECOUNT + fits[-1 if off < 0 else 0]:] += off
        self._fit()


def retimed(times: np.ndarray, interval: float, window: int = RETIME_WINDOW) -> np.ndarray:
    """Frame times (seconds, increasing) smoothed one after another as :class:`FrameRetimer` does in a stream."""
    retimer = FrameRetimer(interval, window)
    return np.array([retimer.add(float(t)) for t in times], np.float64)
