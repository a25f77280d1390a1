"""FrameJitter: frame times of arrival told from a camera's own, however many frames it drops."""

from __future__ import annotations

import re

import numpy as np

from gst_trafficcal.frame_jitter import RETIME_WINDOW, FrameJitter, retimed


def said(times, interval: float | None = None) -> list[str]:
    jitter = FrameJitter(interval)
    return [text for t in times if (text := jitter.add(float(t)))]


def test_a_cameras_own_times_are_not_said_to_jitter():
    """Constant 25 fps, with every 7th frame dropped, and 29.97 fps in whole milliseconds (33 and 34 ms)."""
    dropped = [k / 25 for k in range(1000) if k % 7]
    assert said(dropped) == []
    assert said(np.round(np.arange(1000) / 29.97, 3)) == []
    # a live stream's leaky queue behind a slow machine: half the frames dropped, up to three in a row (its caps
    # say 25 fps; without them the median interval, 80 ms, makes the 40 ms ones stray from it, but the times do
    # not come back to a line as times of arrival do: not said either)
    rng = np.random.default_rng(1)
    kept = np.cumsum(rng.choice([1, 2, 3, 4], size=1000, p=[0.5, 0.2, 0.2, 0.1])) / 25
    assert said(kept, interval=1 / 25) == [] and said(kept) == []


def test_a_variable_frame_rate_timed_at_capture_is_not_said_nor_smoothed_as_jitter():
    """Intervals that vary themselves (a phone's frame rate in low light, timed at capture: 30-45 ms at random, or
    drifting between 33 and 40 ms) are the frames' true times: not said to jitter, so retime=auto keeps them
    (smoothed onto a line, the random ones' 5-frame durations were 6 % off at the median).  The same frames'
    times of arrival — each delayed by 0-40 ms — are said."""
    rng = np.random.default_rng(2)
    random_rate = np.cumsum(rng.uniform(0.030, 0.045, 1500))
    drifting = np.cumsum(0.0365 + 0.0035 * np.sin(np.arange(1500) / 80) + rng.normal(0, 0.001, 1500))
    for times in (random_rate, drifting):
        assert said(times, interval=1 / 30) == [] and said(times) == []
        arrived = np.maximum.accumulate(times + rng.uniform(0, 0.04, len(times)))
        assert said(arrived, interval=1 / 30) != []
    smoothed = retimed(random_rate, 1 / 30)
    true, off = random_rate[5:] - random_rate[:-5], smoothed[5:] - smoothed[:-5]
    assert np.median(np.abs(off - true)[100:] / true[100:]) > 0.03  # what smoothing them would have done


def test_times_of_arrival_are_said_once():
    """Frames of 25 fps delayed by 0-40 ms each: the intervals vary by about 12 ms; said once, with what to do."""
    rng = np.random.default_rng(0)
    times = np.maximum.accumulate(np.arange(1000) / 25 + rng.uniform(0, 0.04, 1000))
    texts = said(times)
    assert len(texts) == 1 and re.search(r"intervals of (39|40|41) ms vary by 1\d ms", texts[0]), texts
    assert "do-timestamp=true" in texts[0]
    assert said(times, interval=1 / 25) != []  # the same with the caps' rate


def test_smoothed_times_are_near_the_true_ones():
    """12.5 fps delayed by 0-40 ms each (times of arrival): the 5-frame durations a speed divides by are off by
    16 ms (1σ) as they arrive, by under 5 ms smoothed; a camera's own times come out as they went in."""
    true = np.arange(600) / 12.5
    rng = np.random.default_rng(0)
    arrived = np.maximum.accumulate(true + rng.uniform(0, 0.04, true.size))
    smoothed = retimed(arrived, 1 / 12.5)
    durations = lambda t: t[5:] - t[:-5]  # noqa: E731  (a τ-pair's duration, τ = 5)
    raw_error, error = durations(arrived) - durations(true), durations(smoothed) - durations(true)
    assert np.std(raw_error) > 0.014 and np.std(error[RETIME_WINDOW:]) < 0.005, (np.std(raw_error), np.std(error))
    assert np.all(np.diff(smoothed) > 0)
    assert np.allclose(retimed(true, 1 / 12.5), true, atol=1e-9)


def test_dropped_frames_stay_gaps_in_the_smoothed_times():
    """A leaky queue drops a quarter of 25 fps frames, up to three in a row, before the frames are timed as they
    arrive (0-20 ms late): each smoothed interval is the whole number of frame intervals that passed, and so is
    every 5-frame duration, within a few ms (a plain line fit over the frames kept would spread them evenly)."""
    rng = np.random.default_rng(2)
    frames = np.cumsum(rng.choice([1, 2, 3, 4], size=800, p=[0.75, 0.1, 0.1, 0.05]))
    true = frames / 25
    arrived = np.maximum.accumulate(true + rng.uniform(0, 0.02, true.size))
    smoothed = retimed(arrived, 1 / 25)
    gaps = np.round(np.diff(smoothed) * 25)
    assert np.array_equal(gaps[RETIME_WINDOW:], np.diff(frames)[RETIME_WINDOW:])
    error = (smoothed[5:] - smoothed[:-5]) - (true[5:] - true[:-5])
    assert np.abs(error[RETIME_WINDOW:]).max() < 0.006 and np.std(error[RETIME_WINDOW:]) < 0.002, error
    assert np.allclose(retimed(true, 1 / 25), true, atol=1e-9)  # no jitter: the times as they were


def test_the_warning_says_whether_the_times_are_smoothed():
    rng = np.random.default_rng(0)
    times = np.maximum.accumulate(np.arange(200) / 25 + rng.uniform(0, 0.04, 200))
    smoothed = FrameJitter(1 / 25, smoothed=True)
    text = next(text for t in times if (text := smoothed.add(float(t))))
    assert "smoothed by a line fit over the last 50 frames (speedometer retime)" in text, text
    assert "smooth them (speedometer retime=auto)" in said(times, 1 / 25)[0]
