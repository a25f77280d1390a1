"""benchmarks/frame_jitter.py --series: the simulated time series it reports on — times of arrival are said to
jitter and smoothing brings their durations nearer the capture times'; a variable frame rate timed at capture is not
said, and smoothing it would have put its exact durations off."""

from __future__ import annotations


def test_series_tell_arrival_from_a_variable_rate(load_benchmark):
    rows = {name: (said, raw, smooth) for name, said, raw, smooth in load_benchmark("frame_jitter").series_table(3)}
    for name in ("arrival 25 fps, 0-40 ms", "arrival 25 fps, 0-40 ms, 10 % dropped", "arrival 12.5 fps, 0-80 ms"):
        said, raw, smooth = rows[name]
        assert said == 3 and smooth < raw / 3, (name, rows[name])
    for name in ("variable rate 30-45 ms at random", "variable rate drifting 33-40 ms"):
        said, raw, smooth = rows[name]
        assert said == 0 and raw == 0 and smooth > 0.01, (name, rows[name])
