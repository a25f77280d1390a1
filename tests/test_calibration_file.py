"""Calibration JSON: round trip, BrnoCompSpeed block, and clear errors for files that are not ours."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from gst_trafficcal.calibration import Calibration, load_calibration, save_calibration
from gst_trafficcal.errors import GeometryError, InputError
from gst_trafficcal.geometry import Camera, rotation_matrix

from .conftest import BRNO, require_shared


def _calibration(scale=8.0) -> Calibration:
    K = np.array([[1200.0, 0, 960], [0, 1200.0, 540], [0, 0, 1]])
    R = rotation_matrix(25, 18, 2)
    cam = Camera.from_KRt(K, R, -R @ np.array([0, 2.0, scale]))
    return Calibration(cam, (1920, 1080), source="test", confidence={"vp1": 0.9})


def test_round_trip(tmp_path):
    cal = _calibration()
    path = save_calibration(cal, tmp_path / "sub" / "cal.json")
    back = load_calibration(path)
    assert back.id == cal.id and back.state == "calibrated" and back.source == "test"
    assert np.allclose(back.camera.vp1, cal.camera.vp1) and back.camera.scale == pytest.approx(8.0)
    data = json.loads(path.read_text())
    assert data["format"] == "gst-trafficcal-calibration" and data["version"] == 1
    assert np.allclose(data["camera"]["K"], cal.camera.K)
    # the BrnoCompSpeed block loads back to the same camera through its own scale convention
    brno = Calibration.from_brno_block(data["camera_calibration"])
    assert brno.camera.scale == pytest.approx(8.0, rel=1e-9)


def test_without_scale_is_vps_state(tmp_path):
    cal = _calibration().with_scale(None)
    assert cal.state == "vps"
    back = load_calibration(save_calibration(cal, tmp_path / "c.json"))
    assert back.camera.scale is None and back.state == "vps"
    assert json.loads((tmp_path / "c.json").read_text())["camera_calibration"]["scale"] is None


def test_a_moved_camera_is_kept_in_the_file(tmp_path):
    cal = Calibration(None, (1920, 1080), state="learning", source="vpdetect", reason="the camera moved at 12.5 s",
                      moved_at=12.5)
    back = load_calibration(save_calibration(cal, tmp_path / "c.json"))
    assert back.moved_at == 12.5 and back.id == cal.id and back.reason == cal.reason
    assert back.id != Calibration(None, (1920, 1080), state="learning").id  # not the start's learning state
    (tmp_path / "bad.json").write_text(json.dumps(dict(json.loads((tmp_path / "c.json").read_text()),
                                                       moved_at="soon")))
    with pytest.raises(InputError, match="bad.json: field 'moved_at' must be a number"):
        load_calibration(tmp_path / "bad.json")


def test_reads_brnocompspeed_results_file():
    path = require_shared(BRNO / "session0_center" / "system_dubska_bmvc14.json")
    cal = load_calibration(path)
    assert cal.source == "brnocompspeed"
    assert cal.camera.brno_scale() == pytest.approx(0.0144311, rel=1e-9)


@pytest.mark.parametrize("content, message", [
    ("{not json", "not valid JSON"),
    ("[1, 2]", "expected a JSON object"),
    ('{"format": "something-else"}', "not a gst-trafficcal calibration"),
    ('{"format": "gst-trafficcal-calibration", "version": 99}', "unsupported calibration version"),
    ('{"format": "gst-trafficcal-calibration", "version": 1, "vp1": [1, 2], "vp2": "x", "pp": [960, 540]}',
     "'vp2' must be a list of two numbers"),
    ('{"format": "gst-trafficcal-calibration", "version": 1, "state": "bogus"}', "unknown calibration state"),
    # found by QA: each was a ValueError/TypeError traceback, a message without the file's name, or a boolean
    # taken for the number 1 (an image 1 pixel wide, a scale of 1 m)
    ('{"format": "gst-trafficcal-calibration", "version": 1}', "state 'calibrated' needs the vanishing points"),
    ('{"format": "gst-trafficcal-calibration", "version": 1, "state": "vps", "vp2": [1, 2]}', "has no 'vp1'"),
    ('{"format": "gst-trafficcal-calibration", "version": 1, "state": "learning", "confidence": {"vp1": "high"}}',
     "'confidence' must be an object of numbers"),
    ('{"format": "gst-trafficcal-calibration", "version": 1, "state": "learning", "confidence": {"vp1": null}}',
     "'confidence' must be an object of numbers"),
    ('{"format": "gst-trafficcal-calibration", "version": 1, "state": "learning", "image_size": [true, 1080]}',
     "'image_size' must be"),
    ('{"format": "gst-trafficcal-calibration", "version": 1, "vp1": [3000, 200], "vp2": [-1500, 250], '
     '"pp": [960, 540], "scale": true}', "'scale' must be a number or null"),
    ('{"camera_calibration": {"vp1": [3000, 200], "vp2": [-1500, 250], "pp": [960, 540], "scale": "abc"}}',
     "'camera_calibration.scale' must be a number or null"),
    ('{"camera_calibration": {"vp1": [3000, 200], "vp2": [-1500, 250], "pp": [960, 540], "scale": [1]}}',
     "'camera_calibration.scale' must be a number or null"),
    ('{"camera_calibration": {"vp2": [-1500, 250], "pp": [960, 540], "scale": 0.01}}',
     "camera_calibration has no 'vp1'"),
    ('{"camera_calibration": {"vp1": [3000, 200, 0], "vp2": [-1500, 250], "pp": [960, 540], "scale": 0.01}}',
     "camera_calibration.vp1 is a point at infinity"),
])
def test_corrupt_files_give_clear_errors(tmp_path, content, message):
    path = tmp_path / "bad.json"
    path.write_text(content)
    with pytest.raises(InputError, match=message) as info:
        load_calibration(path)
    assert str(path) in str(info.value)


def test_missing_file_and_wrong_side_vps(tmp_path):
    with pytest.raises(InputError, match="nope.json: no such file"):
        load_calibration(tmp_path / "nope.json")
    path = tmp_path / "wrong.json"
    path.write_text(json.dumps({"format": "gst-trafficcal-calibration", "version": 1, "vp1": [1200, 100],
                                "vp2": [3000, 200], "pp": [960, 540], "scale": 5.0}))
    with pytest.raises(GeometryError, match="imaginary focal"):
        load_calibration(path)


def test_a_cameras_views_are_kept_one_file_per_view(tmp_path):
    """A views folder (vpdetect views-dir): one JSON per view, named by its vanishing points; a calibration of that
    view with a scale is not replaced by one without; loading skips, and says why, what is not a usable view."""
    from dataclasses import replace

    from gst_trafficcal.calibration import load_views, save_view, view_key
    from gst_trafficcal.vanishing.view import encode_view

    view = encode_view(np.full((90, 160), 128, np.uint8), 1920)
    scaled = replace(_calibration(), view=view, moved_at=30.0)
    bare = scaled.with_scale(None)
    other = replace(_calibration(scale=6.0).with_scale(None), camera=Camera(
        _calibration().camera.vp1 + [300.0, 0.0], _calibration().camera.vp2, _calibration().camera.pp), view=view)
    folder = tmp_path / "views"
    assert view_key(scaled) == view_key(bare) == bare.id
    assert save_view(bare, folder) == folder / f"{bare.id}.json"
    assert save_view(scaled, folder) == folder / f"{bare.id}.json"  # the scale comes: replaced
    assert save_view(bare, folder) is None  # ... and not lost again
    assert save_view(other, folder) is not None and save_view(_calibration(), folder) is None  # no view: not kept
    (folder / "broken.json").write_text("{")
    save_calibration(replace(other, image_size=(1280, 720)), folder / "small.json")
    found, skipped = load_views(folder, (1920, 1080))
    assert sorted(c.id for c in found) == sorted([scaled.id, other.id])
    assert all(c.moved_at is None for c in found)  # a view, not a move
    assert len(skipped) == 2 and any("broken.json" in s for s in skipped) and \
        any("small.json: a calibration of 1280x720 frames" in s for s in skipped)
    assert load_views(tmp_path / "none", (1920, 1080)) == ([], [])
    (tmp_path / "file").write_text("")
    with pytest.raises(InputError, match="cannot create the views folder"):
        save_view(bare, tmp_path / "file" / "views")


def test_a_calibration_file_keeps_the_zone_it_was_learnt_in(tmp_path) -> None:
    """save_calibration(zone=) writes the zone's text; zone_of_file reads it back (None for a file without one);
    the calibration itself loads as before; a broken zone in a file is an error naming the file; 'all' is none."""
    from gst_trafficcal.zone import parse_zone, zone_of_file

    cal = _calibration()
    zone = parse_zone("0.1,0.4 0.9,0.4 1,1 0,1; 0,0 0.05,0 0.05,0.05")
    kept = zone_of_file(save_calibration(cal, tmp_path / "zone.json", zone=zone))
    assert kept.relative and str(kept) == str(zone) and np.array_equal(kept.mask((96, 54)), zone.mask((96, 54)))
    assert load_calibration(tmp_path / "zone.json").id == cal.id
    assert zone_of_file(save_calibration(cal, tmp_path / "bare.json")) is None
    assert parse_zone("all") is None and parse_zone(" ALL ") is None
    text = (tmp_path / "zone.json").read_text().replace('"0.1,0.4', '"0.1,0.4 7')
    (tmp_path / "broken.json").write_text(text)
    with pytest.raises(InputError, match=re.escape(f"{tmp_path / 'broken.json'}: field 'zone': zone '0.1,0.4 7")):
        zone_of_file(tmp_path / "broken.json")


def test_brnocompspeed_points_may_be_homogeneous(tmp_path):
    """A camera_calibration block's points as [x, y, w] (as BrnoCompSpeed's results reader takes them) give the
    same camera as [x, y]."""
    block = {"vp1": [3000, 200], "vp2": [-1500, 250], "pp": [960, 540], "scale": 0.01}
    plain, homogeneous = tmp_path / "plain.json", tmp_path / "homogeneous.json"
    plain.write_text(json.dumps({"camera_calibration": block}))
    homogeneous.write_text(json.dumps({"camera_calibration": {**block, "vp1": [6000, 400, 2], "pp": [960, 540, 1]}}))
    a, b = load_calibration(plain).camera, load_calibration(homogeneous).camera
    assert np.allclose(a.vp1, b.vp1) and np.allclose(a.vp2, b.vp2) and a.focal == pytest.approx(b.focal)
