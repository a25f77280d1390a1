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
