"""Calibration JSON: round trip, BrnoCompSpeed block, and clear errors for files that are not ours."""

from __future__ import annotations

import json

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
