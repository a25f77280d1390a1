"""FrameJitter: frame times of arrival told from a camera's own, however many frames it drops."""

from __future__ import annotations

import re

import numpy as np

from gst_trafficcal.frame_jitter import FrameJitter


def said(times, interval: float | None = None) -> list[str]:
    jitter = FrameJitter(interval)
    return [text for t in times if (text := jitter.add(float(t)))]


def test_a_cameras_own_times_are_not_said_to_jitter():
    """Constant 25 fps, with every 7th frame dropped, and 29.97 fps in whole milliseconds (33 and 34 ms)."""
    dropped = [k / 25 for k in range(1000) if k % 7]
    assert said(dropped) == []
    assert said(np.round(np.arange(1000) / 29.97, 3)) == []
    # a live stream's leaky queue behind a slow machine: half the frames dropped, up to three in a row (its caps
    # say 25 fps; without them the median interval, 80 ms, would make the 40 ms ones look like jitter)
    rng = np.random.default_rng(1)
    kept = np.cumsum(rng.choice([1, 2, 3, 4], size=1000, p=[0.5, 0.2, 0.2, 0.1])) / 25
    assert said(kept, interval=1 / 25) == [] and said(kept) != []


def test_times_of_arrival_are_said_once():
    """Frames of 25 fps delayed by 0-40 ms each: the intervals vary by about 12 ms; said once, with what to do."""
    rng = np.random.default_rng(0)
    times = np.maximum.accumulate(np.arange(1000) / 25 + rng.uniform(0, 0.04, 1000))
    texts = said(times)
    assert len(texts) == 1 and re.search(r"intervals of (39|40|41) ms vary by 1\d ms", texts[0]), texts
    assert "do-timestamp=true" in texts[0]
    assert said(times, interval=1 / 25) != []  # the same with the caps' rate
