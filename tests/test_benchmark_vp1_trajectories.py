"""benchmarks/vp1_trajectories.py on the rendered cuboid clip: the vehicles' reference-point trajectories, tracked
with vehicleseg and the true camera, meet at its VP1; the ratio error it reports is zero for the true camera."""

import numpy as np


def test_trajectories_of_a_rendered_clip_meet_at_vp1(load_benchmark, cuboid_clip_dense):
    from gst_trafficcal.calibration import load_calibration
    from gst_trafficcal.diamond import angle_between
    from gst_trafficcal.geometry import Camera, homogeneous
    from gst_trafficcal.vanishing.trajectories import vp1_from_trajectories

    vt = load_benchmark("vp1_trajectories")
    cam = load_calibration(cuboid_clip_dense / "calibration.json").camera
    trajs = vt.reference_trajectories(cuboid_clip_dense, cam)
    assert len(trajs) >= 10  # 12 s of two-way traffic at 1500 vehicles/h
    # 480x270: trajectories are shorter than at full HD, so the thresholds are scaled down
    vp = vp1_from_trajectories(trajs, min_lines=5, min_points=10, min_span=30.0)
    assert vp is not None and vp.inliers.sum() >= 5
    err = angle_between(homogeneous(vp.point), homogeneous(cam.vp1), cam.pp, cam.focal)
    assert err < 1.0, f"VP1 from trajectories {vp.point} vs {cam.vp1}: {err:.2f} degrees"
    segments = vt.scene_segments(cuboid_clip_dense)
    assert vt.ratio_error(segments, cam) < 1e-9
    moved = Camera(cam.vp1 + np.array([5.0, 5.0]), cam.vp2, cam.pp)
    assert vt.ratio_error(segments, moved) > 0.01


def test_table_counts_the_scenes_each_vp1_wins(load_benchmark):
    vt = load_benchmark("vp1_trajectories")
    rows = [vt.Row("a", 20, 18, 0.2, 0.1, 0.010, 0.005, 3.0, 2.0),
            vt.Row("b", 20, 20, 0.1, 0.3, 0.004, 0.008, 1.0, 1.5),
            vt.Row("c", note="the calibrator found no vanishing points")]
    text = vt.table(rows)
    assert "| c | 0 (0) | –° → –° | – → – | – → – | –°, –, – | the calibrator found no vanishing points" in text
    assert "**2 scenes**" in text and text.count("better on 1 of 2") == 3
