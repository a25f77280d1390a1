"""benchmarks/end_to_end.py: the split of a run's speed error into its scale part (λ err) and its vanishing-point
part (road err at the true λ), on the rendered cuboid clip's per-frame truth, and the per-scene table that shows
both."""

import numpy as np


def test_road_error_is_the_vanishing_points_part_alone(load_benchmark, cuboid_clip_dense, tmp_path):
    from gst_trafficcal.calibration import load_calibration
    from gst_trafficcal.geometry import Camera

    b = load_benchmark("end_to_end")
    vp1 = load_benchmark("vp1_constant_speed")
    cam = load_calibration(cuboid_clip_dense / "calibration.json").camera
    assert abs(b.vp_road_error(cuboid_clip_dense, cam, cam.scale)) < 0.05
    # the run's own λ does not enter: only its vanishing points, measured at the scene's true scale
    assert abs(b.vp_road_error(cuboid_clip_dense, cam.with_scale(2 * cam.scale), cam.scale)) < 0.05
    # VP2 moved out along the horizon (a longer focal length): the road is stretched, by what vp1_constant_speed's
    # road distance error says for the same reference points
    moved = Camera(cam.vp1, cam.vp1 + 1.3 * (cam.vp2 - cam.vp1), cam.pp)
    err = b.vp_road_error(cuboid_clip_dense, moved, cam.scale)
    assert abs(err) > 1.0
    assert err == vp1.road_distance_error(vp1.reference_pairs(cuboid_clip_dense), moved, cam.scale)
    # nothing to measure against: no per-frame truth, or no true scale
    assert b.vp_road_error(tmp_path, cam, cam.scale) is None
    assert b.vp_road_error(cuboid_clip_dense, cam, None) is None


def test_scene_table_shows_both_parts(load_benchmark):
    b = load_benchmark("end_to_end")
    row = b.Row("session3_center", "replay", "auto", frames=3000, state="calibrated (vpdetect+bbscale)",
                has_vps=True, has_scale=True, scale_err_pct=-2.3, road_err_pct=-5.86, vehicles=21, measured=15,
                errors_kmh=[4.0, 5.0])
    no_vps = b.Row("zoom", "synth", "auto", state="vps (vpdetect)")
    text = b.scene_table([row, no_vps])
    header = text.splitlines()[0].split("|")
    cells = text.splitlines()[2].split("|")
    assert cells[header.index(" λ err % ")] == " -2.3 "
    assert cells[header.index(" road err % at true λ ")] == " -5.9 "
    assert text.splitlines()[3].split("|")[header.index(" road err % at true λ ")] == " – "
    figs = b.pooled([row, no_vps])
    assert figs["scale_err_mean_abs_pct"] == 2.3 and np.isclose(figs["road_err_mean_abs_pct"], 5.86)
