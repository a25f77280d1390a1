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


@pytest.fixture(scope="module")
def kraten():
    """The first 18 s of kraten_cars.mp4 (real urban traffic, 640x360, 25 fps), grey."""
    from .conftest import VIDEOS

    cap = cv2.VideoCapture(str(require_shared(VIDEOS / "kraten_cars.mp4")))
    frames = []
    while len(frames) < 450:
        ok, f = cap.read()
        if not ok:
            break
        frames.append(cv2.cvtColor(f, cv2.COLOR_BGR2GRAY))
    assert len(frames) == 450
    return frames


def _watch(frames, change, at=250, fps=25.0):
    """ViewMonitor over the clip, the calibration's view from its first 5 s, ``change`` applied from frame ``at``:
    [(event, time it was noticed)]."""
    from gst_trafficcal.vanishing.view import ViewMonitor

    acc = ViewAccumulator()
    for f in frames[:125]:
        acc.add(f)
    monitor = ViewMonitor(acc.view(), frames[0].shape[1])
    events = []
    for i, f in enumerate(frames):
        if not monitor.wants():
            monitor.skip()
            continue
        e = monitor.add(change(f) if i >= at else f, i / fps)
        if e is not None:
            events.append((e, i / fps))
    return events


@pytest.mark.parametrize("how", ["shift 2 %", "zoom 2 %", "roll 1°"])
def test_a_camera_moved_mid_stream_is_noticed_and_dated(kraten, how):
    """Moved at 10 s: noticed within two seconds, dated at most half a second early, never late (what was seen
    before the date is all the old view's)."""
    change = {"shift 2 %": lambda f: np.roll(f, 13, axis=1), "zoom 2 %": lambda f: _zoomed(f, 1.02),
              "roll 1°": lambda f: _rotated(f, 1.0)}[how]
    events = _watch(kraten, change)
    assert [e.kind for e, _ in events] == ["moved"], events
    event, noticed = events[0]
    assert 9.5 <= event.t <= 10.0 and noticed <= 12.0, (event.t, noticed)
    assert event.match.displaced and event.match.similarity > 0.6


@pytest.mark.parametrize("how", ["unchanged", "dusk (a third of the light)"])
def test_traffic_and_light_are_not_a_move_mid_stream(kraten, how):
    change = {"unchanged": lambda f: f, "dusk (a third of the light)": lambda f: (f / 3).astype(np.uint8)}[how]
    assert _watch(kraten, change) == []


def test_a_scene_no_longer_recognised_is_said_but_not_taken_for_a_move(kraten):
    """Mirrored from 10 s (the gradients of another scene): reported as unrecognised after five seconds of it, not
    as a move — darkness, fog or a covered lens look the same to the monitor, and must not throw the calibration
    away."""
    events = _watch(kraten, lambda f: f[:, ::-1].copy())
    assert [e.kind for e, _ in events] == ["unrecognised"], events
    assert not events[0][0].match.recognised and 15.0 <= events[0][1] <= 17.5


def test_a_library_of_views_tells_which_preset_the_camera_shows(kraten):
    """Two presets of one camera (kraten_cars.mp4 and the same picture 40 px to the right): each median view is
    found as itself — through traffic, a little light or a tenth of a degree of a PTZ's imprecise return — and a
    view excluded or another scene as none; ReturnWatcher confirms the preset when a stream comes back to it and
    dates the return like the monitor."""
    from gst_trafficcal.vanishing.view import ReturnWatcher, ViewLibrary

    def median(frames):
        acc = ViewAccumulator()
        for f in frames:
            acc.add(f)
        return acc.view()

    other = lambda f: np.roll(f, 40, axis=1)  # noqa: E731
    library = ViewLibrary()
    library.add("home", median(kraten[:125]), 640)
    library.add("preset2", median([other(f) for f in kraten[:125]]), 640)
    assert len(library) == 2
    later = kraten[250:375]
    assert library.find(median(later))[0] == "home"
    assert library.find(median([other(f) for f in later]))[0] == "preset2"
    assert library.find(median([_rotated((0.8 * f).astype(np.uint8), 0.1) for f in later]))[0] == "home"
    assert library.find(median(later), exclude="home") is None
    assert library.find(median([f[:, ::-1].copy() for f in later])) is None
    assert library.find(None) is None
    # a stream learning an unknown view (shifted 13 px) comes back to preset 2 at 10 s
    watcher = ReturnWatcher(library)
    found = None
    for i, f in enumerate(kraten):
        out = watcher.add(other(f) if i >= 250 else np.roll(f, 13, axis=1), i / 25.0)
        if out is not None and found is None:
            found = (out, i / 25.0)
    (key, t, match), noticed = found
    assert key == "preset2" and 9.5 <= t <= 10.0 and noticed <= 12.0 and not match.moved
