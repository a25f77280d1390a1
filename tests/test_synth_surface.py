"""The road surface's appearance (road.surface, road.surface_texture, road.joints): strict fields, defaults that
keep the presets' dark asphalt, and a light surface that really renders lighter."""

from __future__ import annotations

import tempfile

import cv2
import numpy as np
import pytest

from gst_trafficcal.errors import InputError
from gst_trafficcal.synth.camera import build_camera
from gst_trafficcal.synth.generate import generate
from gst_trafficcal.synth.scenario import (ROAD_SURFACE_DEFAULT, RoadSpec, load_preset, load_scenario,
                                           preset_names, scenario_from_dict)
from gst_trafficcal.synth.scene import RoadLayout


def test_defaults_are_the_dark_asphalt_of_every_preset():
    road = RoadSpec()
    assert road.surface == [0.30, 0.30, 0.31] == list(ROAD_SURFACE_DEFAULT)
    assert road.surface_texture == 1.0 and road.joints == 0.0
    for name in preset_names():
        r = load_preset(name).road
        assert (r.surface, r.surface_texture, r.joints) == ([0.30, 0.30, 0.31], 1.0, 0.0), name


def test_surface_fields_load_and_inherit(tmp_path):
    f = tmp_path / "concrete.yaml"
    f.write_text("base: highway_day\nroad: {surface: [0.7, 0.69, 0.66], surface_texture: 0.5, joints: 5}\n")
    scen = load_scenario(f)
    assert scen.road.surface == [0.7, 0.69, 0.66] and scen.road.surface_texture == 0.5 and scen.road.joints == 5.0
    assert scen.road.lanes == load_preset("highway_day").road.lanes
    assert scenario_from_dict({"road": {"surface": [0.5, 0.5, 0.5], "joints": 6}}).road.joints == 6.0


def test_the_light_road_benchmark_scenes_load_with_their_surfaces():
    """benchmarks/scenes/: the BrnoCompSpeed-like camera over dark asphalt, light asphalt, concrete and worn asphalt."""
    from pathlib import Path

    scenes = Path(__file__).resolve().parents[1] / "benchmarks" / "scenes"
    loaded = {f.stem: load_scenario(f) for f in sorted(scenes.glob("brno_*.yaml"))}
    assert len(loaded) == 4
    for name, scen in loaded.items():
        assert scen.camera.resolution == [1920, 1080] and scen.camera.height == 9, name
        assert scen.traffic.models, name  # catalogue traffic, as the replays
    assert loaded["brno_dark_overcast_s1"].road.surface == list(ROAD_SURFACE_DEFAULT)
    assert min(loaded["brno_light_overcast_s1"].road.surface) >= 2 * min(ROAD_SURFACE_DEFAULT)
    assert loaded["brno_concrete_overcast_s2"].road.joints == 5.0


def test_bad_surface_values_are_clear_errors():
    with pytest.raises(InputError, match=r"unknown field 'road.surfase' \(did you mean 'surface'\?\)"):
        scenario_from_dict({"road": {"surfase": [0.6, 0.6, 0.6]}})
    with pytest.raises(InputError, match=r"'road.surface' must be an RGB colour \[r, g, b\]"):
        scenario_from_dict({"road": {"surface": [0.6, 0.6]}})
    with pytest.raises(InputError, match=r"'road.surface' must be a list"):
        scenario_from_dict({"road": {"surface": 0.6}})
    with pytest.raises(InputError, match=r"'road.surface\[1\]' must be a number from 0.02 to 0.95, got 1.5"):
        scenario_from_dict({"road": {"surface": [0.6, 1.5, 0.6]}})
    with pytest.raises(InputError, match=r"'road.surface_texture' must be a number from 0 to 2"):
        scenario_from_dict({"road": {"surface_texture": -1}})
    with pytest.raises(InputError, match=r"'road.joints \(0 = none\)' must be a number from 2 to 50, got 0.5"):
        scenario_from_dict({"road": {"joints": 0.5}})


def _road_pixels(road: dict, lighting: str = "overcast", detail: bool = False, along: int = 60,
                 ahead: tuple[float, float] = (12.0, 50.0)) -> np.ndarray:
    """Grey levels of the imaged frame on the lanes ``ahead`` m ahead of the camera (no traffic); ``detail``: their
    difference from the frame smoothed over ~10 px (the surface's texture, without haze and vignetting); ``along``:
    sample positions along each lane."""
    scen = scenario_from_dict({"base": "highway_day", "duration": 0.1, "seed": 3, "road": road,
                               "traffic": {"flow": 0}, "lighting": {"preset": lighting},
                               "camera": {"resolution": [640, 360]}})
    frames: list = []
    with tempfile.TemporaryDirectory() as d:
        generate(scen, d, write_video=False, keep_masks=frames)
    grey = cv2.cvtColor(frames[-1][1], cv2.COLOR_RGB2GRAY).astype(float)
    if detail:
        grey -= cv2.GaussianBlur(grey, (0, 0), 5.0)
    cam, lay = build_camera(scen.camera), RoadLayout(scen.road)
    pts = []
    for d in range(scen.road.directions):
        for lane in range(scen.road.lanes):  # lane centres +- 1 m: no markings
            c = lay.lane_centre(d, lane)
            xs, ys = np.meshgrid(np.linspace(*ahead, along), np.linspace(c - 1.0, c + 1.0, 6))
            pts.append(np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], 1))
    uv = np.round(cam.project(np.concatenate(pts))).astype(int)
    h, w = grey.shape
    ok = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    assert ok.sum() > 500
    return grey[uv[ok, 1], uv[ok, 0]]


def test_light_surface_renders_lighter_with_its_texture_contrast():
    dark = _road_pixels({})
    light = _road_pixels({"surface": [0.62, 0.62, 0.63]})
    # overcast: the default asphalt is ~65 grey levels, a 0.62 albedo ~125 (BrnoCompSpeed's roads: 140-190)
    assert 45 < np.median(dark) < 85 and np.median(light) > np.median(dark) + 45
    flat = _road_pixels({"surface": [0.62, 0.62, 0.63], "surface_texture": 0.0})
    assert abs(np.median(flat) - np.median(light)) < 20  # the texture varies the surface around its albedo
    # the texture contrast scales the grain, patches and wheel paths (flat: the sensor noise is left)
    fine = [np.std(_road_pixels({"surface": [0.62, 0.62, 0.63], "surface_texture": t}, detail=True))
            for t in (0.0, 1.0, 2.0)]
    assert fine[0] < 0.6 * fine[1] and fine[2] > 1.5 * fine[1], fine
    same = _road_pixels({"surface": [0.62, 0.62, 0.63], "surface_texture": 1.0})
    np.testing.assert_array_equal(same, light)


def test_concrete_joints_show():
    # dark joints across the lanes every 4 m: sampled every 2 cm along the near lanes, a few % of the road is
    # darker than its surroundings by more than 8 grey levels, against almost none without joints
    joints = _road_pixels({"surface": [0.62, 0.62, 0.63], "surface_texture": 0.3, "joints": 4.0}, detail=True,
                          along=700, ahead=(10.0, 24.0))
    smooth = _road_pixels({"surface": [0.62, 0.62, 0.63], "surface_texture": 0.3}, detail=True, along=700,
                          ahead=(10.0, 24.0))
    assert (joints < -8).mean() > max(4 * (smooth < -8).mean(), 0.008), ((joints < -8).mean(), (smooth < -8).mean())
