"""benchmarks/scale_vs_dimensions.py: a scene's scale error against the median sizes of its measured cars."""

import json

import numpy as np

from gst_trafficcal.outputs import VehicleEvent


def test_a_correction_by_a_median_the_errors_follow_exactly_leaves_no_error(load_benchmark):
    b = load_benchmark("scale_vs_dimensions")
    x = np.array([1.0, 2.0, 3.5, 4.0, 6.0])
    assert np.allclose(b.leave_one_out(2.0 * x - 5.0, x), 0.0)
    noisy = np.array([1.0, -1.0, 1.0, -1.0, 1.0])  # nothing to do with x: the correction cannot help
    assert np.mean(np.abs(b.leave_one_out(noisy, x))) >= np.mean(np.abs(noisy - noisy.mean()))


def test_scene_rows_take_the_measured_cars_of_fully_automatic_runs(load_benchmark, tmp_path):
    b = load_benchmark("scale_vs_dimensions")
    (tmp_path / "s1" / "auto").mkdir(parents=True)
    cars = [("car", 4.0, 1.8, 1.5, 80.0), ("car", 5.0, 2.0, 1.4, 70.0), ("car", 4.5, 1.9, 1.6, 75.0),
            ("truck", 12.0, 2.5, 3.5, 70.0), ("car", 9.0, 9.0, 9.0, None)]
    events = [VehicleEvent(k, label, 0.0, 1.0, speed, reason="" if speed else "track too short", length_m=length,
                           width_m=width, height_m=height)
              for k, (label, length, width, height, speed) in enumerate(cars)]
    (tmp_path / "s1" / "auto" / "vehicles.jsonl").write_text("".join(json.dumps(e.to_dict()) + "\n" for e in events))
    rows = [{"scene": "s1", "mode": "auto", "scale_err_pct": 1.5, "road_err_pct": -0.5,
             "dims_log_ratio": [[0.1, 0.0, 0.0], [0.3, 0.0, 0.0]]},
            {"scene": "s1", "mode": "manual", "scale_err_pct": 0.0, "road_err_pct": 0.0, "dims_log_ratio": []},
            {"scene": "s2", "mode": "auto", "scale_err_pct": None, "road_err_pct": None, "dims_log_ratio": []}]
    (got,) = b.scene_rows(rows, tmp_path)
    assert got[:3] == ("s1", 1.5, -0.5)
    assert np.allclose(np.exp(got[3]), [4.5, 1.9, 1.5]) and np.allclose(got[4], [0.2, 0.0, 0.0])
