"""How firmly a view pins down the speeds (vanishing/conditioning.py): the geometry on exact cameras, the
calibration file, and vpdetect's warning in a real pipeline."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from gst_trafficcal.calibration import Calibration, load_calibration, save_calibration
from gst_trafficcal.diamond import angle_between
from gst_trafficcal.geometry import Camera, homogeneous, rotation_matrix
from gst_trafficcal.synth.camera import build_camera
from gst_trafficcal.synth.scenario import load_preset
from gst_trafficcal.vanishing.conditioning import (ADVICE, POOR_PCT, road_points, road_stretch, turned_vp2,
                                                   view_conditioning)

from .test_vanishing import FPS, H, W, render_scene, scene_camera

ROOT = Path(__file__).resolve().parents[1]


def preset_camera(name: str) -> tuple[Camera, tuple[int, int]]:
    cam = build_camera(load_preset(name).camera)
    return cam.calibration_camera(), cam.size


def along_road_camera() -> Camera:
    """8 m above the second lane of the cuboid scene, looking along the road (pan 5°): VP2 ~11 image widths away."""
    f = 450.0
    K = np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1.0]])
    R = rotation_matrix(5.0, 10.0, 0.0)
    return Camera.from_KRt(K, R, -R @ np.array([0.0, 3.0, 8.0]))


def test_oblique_views_are_well_conditioned_and_views_along_the_road_are_not():
    oblique, size = preset_camera("highway_day")
    along, size_along = preset_camera("vp2_far")
    a, b = view_conditioning(oblique, size), view_conditioning(along, size_along)
    assert a.vp2_widths < 4 and a.speed_pct < 1.0 and not a.poor
    assert b.vp2_widths > 30 and b.speed_pct > 5 * POOR_PCT and b.poor
    assert "calibrate-manual" in b.describe() and b.describe(advice=False).endswith("(a poorly conditioned view)")
    assert a.describe() == a.describe(advice=False) and a.describe().endswith(f"by {a.speed_pct:.1f} %")
    # a smaller turn, a proportionally smaller change (the sensitivity is a derivative, not a threshold effect)
    half = view_conditioning(oblique, size, turn_deg=0.05)
    assert half.speed_pct == pytest.approx(a.speed_pct / 2, rel=0.05)


def test_the_turned_vp2_is_on_the_horizon_at_the_turned_angle():
    cam = scene_camera()
    anchor = road_points(cam, (W, H)).mean(axis=0)
    for turn in (0.1, -0.1, 1.0):
        vp2 = turned_vp2(cam, anchor, turn)
        assert abs(float(cam.horizon @ homogeneous(vp2))) < 1e-6 * np.linalg.norm(vp2)
        a, b = cam.vp2 - anchor, vp2 - anchor
        angle = math.degrees(math.atan2(a[0] * b[1] - a[1] * b[0], a @ b))
        assert angle == pytest.approx(turn, abs=1e-9)


def test_road_stretch_is_what_the_other_camera_measures_of_one_metre_steps():
    """Independent of the plane units: world points 1 m apart along the traffic, imaged by the true camera and
    measured in metres by the other at the true height."""
    cam = scene_camera()
    pts = road_points(cam, (W, H))
    other = Camera(cam.vp1, turned_vp2(cam, pts.mean(axis=0), 0.5), cam.pp)
    assert road_stretch(cam, cam, pts) == pytest.approx(0.0, abs=1e-9)
    world = cam.to_world(pts)
    step = cam.world_to_image(world + np.array([1.0, 0.0, 0.0]))
    metres = other.with_scale(cam.scale).distance(pts, step)
    assert road_stretch(cam, other, pts) == pytest.approx(100 * np.median(metres - 1.0), abs=1e-6)
    # only road within ROAD_HEIGHTS of the camera, all of it in the image and in front of the camera
    X = cam.to_road(pts)
    assert len(pts) > 100 and np.all(X[:, 2] > 0) and np.all(np.linalg.norm(X, axis=1) <= 20.0 + 1e-9)


def test_unbounded_and_undefined_cases():
    # VP2 a million pixels away (f 978 px): 0.1° takes it through infinity, the focal length is not pinned down
    far = Camera([481.0, 60.0], [-1e6, 60.0], [480.0, 270.0])
    c = view_conditioning(far, (960, 540))
    assert math.isinf(c.speed_pct) and c.poor and c.to_dict()["speed_pct"] is None
    assert "unbounded" in c.describe()
    # a telephoto view (f 14832 px) whose road all lies beyond ROAD_HEIGHTS: measured on the road it sees
    tele = Camera([700.0, 60.0], [-1e6, 60.0], [480.0, 270.0])
    seen = road_points(tele, (960, 540))
    assert len(seen) > 100 and np.all(np.linalg.norm(tele.to_road(seen), axis=1) > 20.0)
    # horizon below the image: the camera sees no road
    sky = Camera([5000.0, 800.0], [-5000.0, 800.0], [480.0, 270.0])
    c = view_conditioning(sky, (960, 540))
    assert math.isnan(c.speed_pct) and not c.poor and "no road in view" in c.describe()


def test_the_calibration_file_carries_it_and_loading_ignores_it(tmp_path):
    cam, size = preset_camera("vp2_far")
    cal = Calibration(cam, size, source="test")
    path = save_calibration(cal, tmp_path / "cal.json")
    d = json.loads(path.read_text())
    expected = view_conditioning(cam, size)
    assert d["conditioning"]["poor"] is True and d["conditioning"]["speed_pct"] == round(expected.speed_pct, 3)
    assert d["conditioning"]["vp2_image_widths"] == pytest.approx(expected.vp2_widths, abs=0.01)
    assert load_calibration(path).id == cal.id
    with pytest.raises(Exception, match="no vanishing points"):
        Calibration(None, size, state="learning").conditioning()


def test_vpdetect_warns_once_about_a_view_along_the_road():
    import cv2

    from gst_trafficcal.gst.element import register_plugin_file
    from gst_trafficcal.gst.pipeline import run_pipeline

    register_plugin_file(ROOT / "elements" / "python" / "vpdetect.py")
    cam = along_road_camera()
    assert view_conditioning(cam, (W, H)).poor
    frames = [cv2.cvtColor(f, cv2.COLOR_GRAY2BGR) for f in render_scene(24.0, camera=cam)]
    caps = f"video/x-raw,format=I420,width={W},height={H},framerate=15/1"
    # the cuboid scene's plain noise road gives the view check too little to hold on to: off here
    run = run_pipeline("appsrc name=src ! vpdetect min-duration=8 max-duration=60 view-check=false ! "
                       "appsink name=sink", frames, caps, fps=FPS)
    cal = run.frames[-1].calibration
    assert cal.state == "vps"
    warned = [w for w in run.warnings if "image widths away" in w]
    assert len(warned) == 1 and warned[0].endswith(ADVICE)  # the advice trafficcal run does not repeat
    assert f"{cal.conditioning().speed_pct:.1f} %" in warned[0]
    # its VP2 came out where such views put it: far from the true one (the focal length with it)
    assert angle_between(homogeneous(cal.camera.vp2), homogeneous(cam.vp2), cam.pp, cam.focal) > 0.1


def test_vpdetect_says_nothing_about_an_oblique_view():
    import cv2

    from gst_trafficcal.gst.element import register_plugin_file
    from gst_trafficcal.gst.pipeline import run_pipeline

    from .test_vanishing import cached_scene

    register_plugin_file(ROOT / "elements" / "python" / "vpdetect.py")
    frames = [cv2.cvtColor(f, cv2.COLOR_GRAY2BGR) for f in cached_scene(24.0)]
    caps = f"video/x-raw,format=I420,width={W},height={H},framerate=15/1"
    run = run_pipeline("appsrc name=src ! vpdetect min-duration=8 max-duration=60 ! appsink name=sink", frames, caps,
                       fps=FPS)
    assert run.frames[-1].calibration.state == "vps"
    assert not [w for w in run.warnings if "image widths away" in w]


def test_the_cli_warns_of_a_view_along_the_road_on_stderr(capsys):
    """trafficcal run/calibrate/demo: the warning about a poorly conditioned view is a diagnostic, on stderr with the
    other warnings (it was printed on stdout with the results); an oblique view's plain "View:" line is a result."""
    from rich.console import Console

    from gst_trafficcal.cli.calibrate import print_conditioning

    print_conditioning(Console(), Calibration(along_road_camera(), (W, H)))
    said = capsys.readouterr()
    assert said.out == "" and " ".join(said.err.split()).startswith("warning: ") and ADVICE in " ".join(
        said.err.split()), said
    cam, size = preset_camera("highway_day")
    print_conditioning(Console(), Calibration(cam, size))
    said = capsys.readouterr()
    assert said.err == "" and " ".join(said.out.split()).startswith("View: "), said
