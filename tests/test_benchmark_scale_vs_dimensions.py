"""benchmarks/scale_vs_dimensions.py: a scene's scale error against the median sizes of its measured cars."""

import json

import numpy as np


def test_a_correction_by_a_median_the_errors_follow_exactly_leaves_no_error(load_benchmark):
    b = load_benchmark("scale_vs_dimensions")
    x = np.array([1.0, 2.0, 3.5, 4.0, 6.0])
    assert np.allclose(b.leave_one_out(2.0 * x - 5.0, x), 0.0)
    noisy = np.array([1.0, -1.0, 1.0, -1.0, 1.0])  # nothing to do with x: the correction cannot help
    assert np.mean(np.abs(b.leave_one_out(noisy, x))) >= np.mean(np.abs(noisy - noisy.mean()))


def test_scene_rows_take_the_measured_cars_of_fully_automatic_runs(load_benchmark, tmp_path):
    b = load_benchmark("scale_vs_dimensions")
    (tmp_path / "s1" / "auto").mkdir(parents=True)
    cars = [{"label": "car", "length_m": 4.0, "width_m": 1.8, "height_m": 1.5, "speed_kmh": 80.0},
            {"label": "car", "length_m": 5.0, "width_m": 2.0, "height_m": 1.4, "speed_kmh": 70.0},
            {"label": "car", "length_m": 4.5, "width_m": 1.9, "height_m": 1.6, "speed_kmh": 75.0},
            {"label": "truck", "length_m": 12.0, "width_m": 2.5, "height_m": 3.5, "speed_kmh": 70.0},
            {"label": "car", "length_m": 9.0, "width_m": 9.0, "height_m": 9.0, "speed_kmh": None}]
    (tmp_path / "s1" / "auto" / "vehicles.jsonl").write_text("".join(json.dumps(c) + "\n" for c in cars))
    rows = [{"scene": "s1", "mode": "auto", "scale_err_pct": 1.5, "road_err_pct": -0.5,
             "dims_log_ratio": [[0.1, 0.0, 0.0], [0.3, 0.0, 0.0]]},
            {"scene": "s1", "mode": "manual", "scale_err_pct": 0.0, "road_err_pct": 0.0, "dims_log_ratio": []},
            {"scene": "s2", "mode": "auto", "scale_err_pct": None, "road_err_pct": None, "dims_log_ratio": []}]
    (got,) = b.scene_rows(rows, tmp_path)
    assert got[:3] == ("s1", 1.5, -0.5)
    assert np.allclose(np.exp(got[3]), [4.5, 1.9, 1.5]) and np.allclose(got[4], [0.2, 0.0, 0.0])
