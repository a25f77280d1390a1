"""benchmarks/calibration.py: a scene rendered earlier scored as it is, with CalibratorConfig fields set from the
command line (the rendered 12 s cuboid clip, too short for VP2 under the default evidence threshold)."""


def test_config_fields_reach_the_calibrator(load_benchmark, cuboid_clip_dense):
    b = load_benchmark("calibration")
    default = b.score(cuboid_clip_dense, "edgelets", 60.0)
    assert default["state"] == "failed" and "too few edges on vehicles for VP2" in default["reason"]
    assert "ratio_mean" not in default
    # every edgelet (not only those inside the boxes), and a lower threshold: 2315 of them in its 12 s
    row = b.score(cuboid_clip_dense, "edgelets", 60.0, {"min_edgelets": 1000, "interior_edges": 0.0})
    assert row["state"] == "vps" and row["ratio_mean"] < 0.05
    assert abs(row["focal_signed"]) == row["focal_err"] and row["focal_err"] < 0.1
    # the interior ones alone (about 400) are enough for a VP2 too
    row = b.score(cuboid_clip_dense, "edgelets", 60.0, {"min_edgelets": 300})
    assert row["state"] == "vps" and row["ratio_mean"] < 0.05
    # and a focal range the scene's camera is far outside of: no second vanishing point is accepted
    narrow = b.score(cuboid_clip_dense, "edgelets", 60.0, {"min_edgelets": 300, "focal_range": (1.0, 2.0)})
    assert narrow["state"] == "failed" and "ratio_mean" not in narrow
