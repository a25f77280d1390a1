"""benchmarks/vp1_constant_speed.py: its road distance error on the rendered cuboid clip (zero for the true camera,
opposite signs for VP1 moved either way along the lanes) and its summary table."""

import numpy as np


def test_road_distance_error_measures_vp1_along_the_lanes(load_benchmark, cuboid_clip_dense):
    from gst_trafficcal.calibration import load_calibration
    from gst_trafficcal.geometry import Camera

    b = load_benchmark("vp1_constant_speed")
    cam = load_calibration(cuboid_clip_dense / "calibration.json").camera
    pairs = b.reference_pairs(cuboid_clip_dense)
    assert len(pairs[2]) > 100 and np.all(pairs[2] >= 0.5)
    assert abs(b.road_distance_error(pairs, cam, cam.scale)) < 0.05
    centre = np.concatenate([pairs[0], pairs[1]]).mean(axis=0)
    along = (cam.vp1 - centre) / np.linalg.norm(cam.vp1 - centre)
    errors = [b.road_distance_error(pairs, Camera(cam.vp1 + s * along, cam.vp2, cam.pp), cam.scale) for s in (-3, 3)]
    assert min(abs(e) for e in errors) > 0.5 and errors[0] * errors[1] < 0, errors
    # a larger true scale with the same vanishing points: every distance grows by the same factor
    assert abs(b.road_distance_error(pairs, cam, 1.1 * cam.scale) - 10.0) < 0.1


def test_table_summarises_the_scenes(load_benchmark):
    b = load_benchmark("vp1_constant_speed")
    rows = [b.Row("a", "replays", 300, 12.0, 0.02, 13.0, 1.0, 0.4, 0.05, -12.0, -1.0),
            b.Row("b", "replays", 400, 5.0, None, 5.0, 6.0, 0.1, 0.12, 1.0, 2.0),
            b.Row("c", "synth", note="no vanishing points (too short)")]
    text = b.table(rows)
    assert "| a | 300 | +12.0 (+2.0 %) | 13.0 → 1.0 | 0.400 → 0.050 | -12.00 → -1.00 |" in text
    assert "| c | 0 | – | – → – | – → – | – → – | no vanishing points (too short)" in text
    assert "**2 scenes**" in text and "6.50 → 1.50 mean" in text and text.count("better on 1 of 2") == 3
    assert "replays/" not in text  # one folder among the scenes with results: no per-folder rows
    rows.append(b.Row("d", "synth", 100, 1.0, 0.01, 2.0, 1.0, 0.2, 0.1, 4.0, 1.0))
    text = b.table(rows)
    assert "**replays/2 scenes**" in text and "**synth/1 scenes**" in text and "**3 scenes**" in text
    assert "4.00 → 1.00 mean, 4.00 → 1.00 median, better on 1 of 1" in text
