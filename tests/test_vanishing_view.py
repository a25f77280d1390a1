"""Has the camera moved since it was calibrated? (``vanishing/view.py``) on real BrnoCompSpeed frames."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from gst_trafficcal.calibration import Calibration, load_calibration, save_calibration
from gst_trafficcal.errors import InputError
from gst_trafficcal.geometry import Camera
from gst_trafficcal.vanishing.view import (ViewAccumulator, compare_views, decode_view, encode_view,
                                           thumbnail)

from .conftest import BRNO, require_shared


def _frame(name: str) -> np.ndarray:
    return cv2.cvtColor(cv2.imread(str(require_shared(BRNO / name / "screen.png"))), cv2.COLOR_BGR2GRAY)


@pytest.fixture(scope="module")
def scene() -> np.ndarray:
    return _frame("session0_center")


def _rotated(img, deg):
    h, w = img.shape
    return cv2.warpAffine(img, cv2.getRotationMatrix2D((w / 2, h / 2), deg, 1.0), (w, h))


def _zoomed(img, k):
    h, w = img.shape
    big = cv2.resize(img, None, fx=k, fy=k)
    y, x = (big.shape[0] - h) // 2, (big.shape[1] - w) // 2
    return big[y:y + h, x:x + w]


def test_light_and_weather_are_not_a_move(scene):
    rng = np.random.default_rng(0)
    for changed in (scene * 0.6, 255 * (scene / 255.0) ** 1.8, scene + rng.normal(0, 12, scene.shape),
                    cv2.GaussianBlur(scene, (0, 0), 3), np.roll(scene, 10, axis=1)):
        m = compare_views(thumbnail(scene), thumbnail(np.clip(changed, 0, 255).astype(np.uint8)), scene.shape[1])
        assert not m.moved and m.similarity > 0.9, m


@pytest.mark.parametrize("how, check", [
    ("shift 2 %", lambda m: m.shift[0] == pytest.approx(38, abs=3)),
    ("zoom 3 %", lambda m: m.zoom == pytest.approx(0.03, abs=0.006)),
    ("roll 1°", lambda m: abs(m.rotation_deg) == pytest.approx(1.0, abs=0.2)),
    ("another camera", lambda m: m.similarity < 0.5),
])
def test_a_moved_camera_is_a_move(scene, how, check):
    moved = {"shift 2 %": lambda: np.roll(scene, 38, axis=1), "zoom 3 %": lambda: _zoomed(scene, 1.03),
             "roll 1°": lambda: _rotated(scene, 1.0), "another camera": lambda: _frame("session0_left")}[how]()
    m = compare_views(thumbnail(scene), thumbnail(moved), scene.shape[1])
    assert m.moved and check(m), m


def test_the_median_leaves_the_traffic_out(scene):
    rng = np.random.default_rng(1)
    acc = ViewAccumulator(every=1, keep=15)
    for _ in range(15):  # a dark "vehicle" somewhere in each frame
        f = scene.copy()
        x, y = rng.integers(0, 1700), rng.integers(300, 900)
        f[y:y + 150, x:x + 220] = 30
        acc.add(f)
    assert acc.count == 15 and np.abs(acc.view().astype(int) - thumbnail(scene)).max() <= 3


def test_view_in_the_calibration_file(scene, tmp_path):
    cam = Camera(np.array([160.0, 45.0]), np.array([12000.0, 670.0]), np.array([960.0, 540.0]), 8.9)
    view = encode_view(thumbnail(scene), 1920)
    path = save_calibration(Calibration(cam, (1920, 1080), view=view), tmp_path / "cal.json")
    back = load_calibration(path)
    img, width = decode_view(back.view)
    assert width == 1920 and np.array_equal(img, thumbnail(scene))
    assert back.id == Calibration(cam, (1920, 1080)).id  # the view is not part of the calibration's identity
    d = json.loads(path.read_text())
    d["view"] = {"png": "not base64!", "frame_width": 1920}
    path.write_text(json.dumps(d))
    with pytest.raises(InputError, match="'view' is broken"):
        decode_view(load_calibration(path).view, str(path))
    d["view"] = "a string"
    path.write_text(json.dumps(d))
    with pytest.raises(InputError, match="field 'view'"):
        load_calibration(path)
