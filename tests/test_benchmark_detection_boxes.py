"""benchmarks/detection_boxes.py's table rows: a scene whose scored window holds no vehicle (a sparse scene) gives
a row of dashes instead of NaN and numpy warnings, and does not disturb the pooled row."""

from __future__ import annotations

import warnings


def test_a_scene_without_scored_vehicles_gives_dashes_not_nan(load_benchmark):
    bench = load_benchmark("detection_boxes")
    empty = dict(scene="sparse", vehicles=0, tp=0, detections=3, good=3, ious=[], dx=[], dy=[], fps=90.0)
    busy = dict(scene="busy", vehicles=2, tp=2, detections=2, good=2, ious=[0.9, 0.8],
                dx=[[0.02, -0.01], [0.04, 0.01]], dy=[[0.0, 0.02], [-0.02, 0.0]], fps=90.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "Mean of empty slice"
        row = bench.summary("sparse", [empty])
        pooled = bench.summary("all", [empty, busy])
    assert "nan" not in row and row.startswith("| sparse | 0 | — | 1.000 |")
    assert pooled == "| all | 2 | 1.000 | 1.000 | 0.85 | +0.03 / +0.00 | -0.01 / +0.01 |"
