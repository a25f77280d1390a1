"""vehicleseg's training recipes: the road surface is drawn from dark asphalt to light concrete on its own random
stream (every other field of a recipe as before), and training seeds stay clear of the benchmarks'."""

from __future__ import annotations

from collections import Counter

from gst_trafficcal.synth.scenario import ROAD_SURFACE_DEFAULT, scenario_from_dict

from training.vehicleseg.data import SEED_BASE, random_recipe

SURFACE_FIELDS = ("surface", "surface_texture", "joints")


def _without_surface(recipe) -> dict:
    scen = dict(recipe.scenario)
    scen["road"] = {k: v for k, v in scen["road"].items() if k not in SURFACE_FIELDS}
    return {"scenario": scen, "jpeg": recipe.jpeg_quality, "kenney": recipe.kenney_share, "base": recipe.base}


def test_mixed_surfaces_change_only_the_road_surface():
    kinds = Counter()
    for i in range(60):
        mixed, plain = random_recipe(i, 10.0), random_recipe(i, 10.0, surfaces="asphalt")
        assert _without_surface(mixed) == _without_surface(plain)
        assert plain.scenario["road"]["surface"] == list(ROAD_SURFACE_DEFAULT) and plain.surface == "asphalt"
        road = mixed.scenario["road"]
        kinds[mixed.surface] += 1
        if mixed.surface == "asphalt":
            assert road["surface"] == list(ROAD_SURFACE_DEFAULT) and road["surface_texture"] == 1.0
        else:
            assert min(road["surface"]) > 0.35 and road["surface_texture"] <= 1.2
        scenario_from_dict(mixed.scenario)  # valid
        assert mixed.seed == SEED_BASE + i >= 1000
    assert kinds["asphalt"] >= 10 and kinds["worn"] >= 10 and kinds["concrete"] >= 10, kinds


def test_overhead_profile_puts_the_camera_above_a_lane_looking_down_the_road():
    """The ``overhead`` profile (BrnoCompSpeed's kind of view): every recipe valid, the camera within 2 m of the
    centre of a lane with traffic, and (on a straight road) the lane under it, somewhere 10-80 m ahead, in the picture."""
    import numpy as np

    from gst_trafficcal.synth.camera import build_camera
    from gst_trafficcal.synth.scene import RoadLayout

    resolutions, straight = Counter(), 0
    for i in range(40):
        recipe = random_recipe(i, 10.0, profile="overhead")
        scen = scenario_from_dict(recipe.scenario)
        lay = RoadLayout(scen.road)
        centres = [lay.lane_centre(d, k) for d in scen.traffic.directions for k in range(scen.road.lanes)]
        assert min(abs(scen.camera.offset - c) for c in centres) <= 2.0
        assert 6.0 <= scen.camera.height <= 14.0 and scen.camera.hfov >= 30.0
        resolutions[tuple(scen.camera.resolution)] += 1
        assert random_recipe(i, 10.0).scenario["traffic"] == recipe.scenario["traffic"]  # only view and light
        if scen.road.curve_radius:
            continue
        cam = build_camera(scen.camera)
        ahead = np.array([[x, scen.camera.offset, 0.0] for x in np.linspace(10.0, 80.0, 15)])
        uv = cam.project(ahead)
        w, h = scen.camera.resolution
        inside = (uv[:, 0] > 0) & (uv[:, 0] < w) & (uv[:, 1] > 0) & (uv[:, 1] < h)
        assert inside.sum() >= 3, (i, uv)
        straight += 1
    assert straight >= 25, straight
    assert resolutions[(1920, 1080)] >= 8, resolutions
