"""A person's road measurements (road_measurements.py) and `trafficcal calibrate-manual --measurements`: an exact
scene, a BrnoCompSpeed recording's markings written as such a file, the picture, and bad input."""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest
import yaml

from gst_trafficcal.brnocompspeed import load_gt_data
from gst_trafficcal.calibration import load_calibration
from gst_trafficcal.errors import InputError
from gst_trafficcal.geometry import Camera, rotation_matrix
from gst_trafficcal.manual_calibration import RoadMarkings, calibrate_manual
from gst_trafficcal.drawing import line_segment
from gst_trafficcal.road_measurements import fit_line, load_road_measurements, road_measurements_dict

from .conftest import BRNO, ROOT, require_shared

SIZE = (1280, 720)


def _camera() -> Camera:
    """A camera 9 m above the road, looking along it more than across (pan 12°)."""
    f = 1500.0
    K = np.array([[f, 0, SIZE[0] / 2 + 0.5], [0, f, SIZE[1] / 2 + 0.5], [0, 0, 1]])
    R = rotation_matrix(12.0, 11.0, 1.0)
    return Camera.from_KRt(K, R, -R @ np.array([0.0, 2.0, 9.0]))


def _measurements(cam: Camera) -> dict:
    """What a person would measure on a 3-lane road seen by ``cam``: two dividers by three points each, dashes
    (6 m) along the traffic and lane widths (3.5 m) across it; pixels rounded to a tenth."""
    img = lambda x, y: np.round(cam.world_to_image(np.array([x, y, 0.0])), 1).tolist()  # noqa: E731
    dividers = [[img(x, y) for x in (30.0, 45.0, 70.0)] for y in (-1.75, -5.25)]
    segments = [{"from": img(x, y), "to": img(x + 6.0, y), "metres": 6.0, "direction": "along"}
                for y in (-1.75, -5.25) for x in (32.0, 44.0)]
    segments += [{"from": img(x, -1.75), "to": img(x, -5.25), "metres": 3.5, "direction": "across"}
                 for x in (34.0, 50.0)]
    return {"image_size": list(SIZE), "lane_dividers": dividers, "segments": segments}


def _run(*args) -> subprocess.CompletedProcess:
    exe = ROOT / ".venv" / "bin" / "trafficcal"
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "gst_trafficcal"]
    return subprocess.run(cmd + [str(a) for a in args], capture_output=True, text=True, timeout=300)


def test_fit_line_and_its_image_border_points():
    rng = np.random.default_rng(3)
    t = rng.uniform(-300, 300, 50)
    pts = np.c_[400 + 0.6 * t, 200 + 0.8 * t] + rng.normal(0, 0.2, (50, 2))
    line = fit_line(pts)
    assert np.hypot(*line[:2]) == pytest.approx(1.0)
    assert abs(abs(line[:2] @ np.array([0.8, -0.6])) - 1) < 1e-4  # the normal of direction (0.6, 0.8)
    ends = line_segment(line, SIZE)
    assert np.all(np.abs(np.c_[ends, np.ones(2)] @ line) < 1e-6)
    assert np.all((ends >= 0) & (ends <= np.array(SIZE) - 1 + 1e-6)) and np.linalg.norm(ends[1] - ends[0]) > 500
    assert line_segment(np.array([0.0, 1.0, 10.0]), SIZE) is None  # y = -10: above the image


def test_cli_recovers_the_camera_from_measurements_of_an_exact_scene(tmp_path):
    cam = _camera()
    path = tmp_path / "road.yaml"
    path.write_text(yaml.safe_dump(_measurements(cam)))
    out = tmp_path / "cal.json"
    proc = _run("calibrate-manual", "--measurements", path, "-o", out)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    got = load_calibration(out)
    assert got.image_size == SIZE and got.source == "manual-calibration" and got.state == "calibrated"
    c = got.camera
    assert c.focal == pytest.approx(cam.focal, rel=2e-3)
    assert c.scale == pytest.approx(cam.scale, rel=2e-3)
    assert np.linalg.norm(c.vp1 - cam.vp1) < 0.5
    # the table: each segment's measured and calibrated length
    text = " ".join(proc.stdout.split())
    assert "Segments" in text and text.count(" along ") == 4 and text.count(" across ") == 2
    lengths = c.distance(np.array([s["from"] for s in _measurements(cam)["segments"]]),
                         np.array([s["to"] for s in _measurements(cam)["segments"]]))
    assert np.abs(lengths - np.array([6.0] * 4 + [3.5] * 2)).max() < 0.05
    # JSON is read too, the same numbers
    path_json = tmp_path / "road.json"
    path_json.write_text(json.dumps(_measurements(cam)))
    assert _run("calibrate-manual", "--measurements", path_json, "-o", tmp_path / "j.json").returncode == 0
    assert load_calibration(tmp_path / "j.json").id == got.id


def test_a_recordings_markings_as_a_file_give_the_same_calibration_and_a_picture(tmp_path):
    rec = require_shared(BRNO / "session3_center")
    gt = load_gt_data(rec / "gt_data.pkl")
    path = tmp_path / "road.json"
    path.write_text(json.dumps(road_measurements_dict(RoadMarkings.from_gt(gt), (1920, 1080))))
    markings, size = load_road_measurements(path)
    assert size == (1920, 1080) and len(markings.metres) == len(gt.distances)
    out = tmp_path / "cal.json"
    proc = _run("calibrate-manual", "--measurements", path, "-o", out, "--image", rec / "screen.png")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    from_file, from_gt = load_calibration(out).camera, calibrate_manual(gt).camera
    assert from_file.focal == pytest.approx(from_gt.focal, rel=1e-4)
    assert from_file.scale == pytest.approx(from_gt.scale, rel=1e-4)
    assert np.linalg.norm(from_file.vp1 - from_gt.vp1) < 0.1
    png = cv2.imread(str(out.with_suffix(".png")))
    screen = cv2.imread(str(rec / "screen.png"))
    assert png.shape == screen.shape
    changed = np.any(np.abs(png.astype(int) - screen) > 30, axis=2)
    assert 0.02 < changed.mean() < 0.5  # the grid, the dividers and the segments drawn, the scene still there
    a = np.round(markings.p1[0] * 0.8 + markings.p2[0] * 0.2).astype(int)  # on the first segment (along: green)
    patch = png[a[1] - 2:a[1] + 3, a[0] - 2:a[0] + 3].reshape(-1, 3).astype(int)
    assert np.any((patch[:, 1] > 150) & (patch[:, 0] < 80) & (patch[:, 2] < 80))


@pytest.mark.parametrize("change, message", [
    (lambda d: d.pop("segments"), "segments must list the measured road segments"),
    (lambda d: d["lane_dividers"].pop(), "lane_dividers must list at least two lines"),
    (lambda d: d["lane_dividers"][1].__setitem__(0, [1, "x"]), "lane_dividers[1][0] must be an image point"),
    (lambda d: d["segments"][2].__setitem__("metres", -6), "segments[2].metres must be a positive number"),
    (lambda d: d["segments"][1].pop("to"), "segments[1] lacks to"),
    (lambda d: d["segments"][0].__setitem__("direction", "sideways"), "segments[0].direction must be 'along'"),
    (lambda d: d.__setitem__("image_size", [1280]), "image_size must be [width, height]"),
    (lambda d: d.__setitem__("lanes", 3), "unknown field(s) lanes"),
    (lambda d: d.__setitem__("segments", [s for s in d["segments"] if s["direction"] == "along"]),
     "needs measured segments both towards VP1 (4) and towards VP2 (0)"),
])
def test_bad_measurements_are_one_line_errors_naming_the_entry(tmp_path, change, message):
    d = _measurements(_camera())
    change(d)
    path = tmp_path / "road.yaml"
    path.write_text(yaml.safe_dump(d))
    proc = _run("calibrate-manual", "--measurements", path, "-o", tmp_path / "cal.json")
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and lines[0].startswith("trafficcal: error: "), proc.stderr
    assert str(path) in lines[0] and message in lines[0], lines[0]
    assert not (tmp_path / "cal.json").exists()


def test_bad_invocations(tmp_path):
    path = tmp_path / "road.yaml"
    path.write_text(yaml.safe_dump(_measurements(_camera())))
    out = tmp_path / "cal.json"
    neither = _run("calibrate-manual", "-o", out)
    assert neither.returncode == 2 and "give either --gt or --measurements" in neither.stderr
    both = _run("calibrate-manual", "--gt", tmp_path / "gt.pkl", "--measurements", path, "-o", out)
    assert both.returncode == 2 and "give either --gt or --measurements" in both.stderr
    size = _run("calibrate-manual", "--measurements", path, "-o", out, "--image-size", "1920x1080")
    assert size.returncode == 2 and "image_size 1280x720 differs from --image-size 1920x1080" in size.stderr
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((360, 640, 3), np.uint8))
    wrong = _run("calibrate-manual", "--measurements", path, "-o", out, "--image", small)
    assert wrong.returncode == 2 and "it is 640x360, the measurements are for 1280x720" in wrong.stderr
    clip = tmp_path / "small.avi"  # a video: its first frame is the picture
    writer = cv2.VideoWriter(str(clip), cv2.VideoWriter_fourcc(*"MJPG"), 25, (640, 360))
    for _ in range(3):
        writer.write(np.full((360, 640, 3), 90, np.uint8))
    writer.release()
    video = _run("calibrate-manual", "--measurements", path, "-o", out, "--image", clip)
    assert video.returncode == 2 and "small.avi: it is 640x360, the measurements are for 1280x720" in video.stderr
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"not a picture")
    unreadable = _run("calibrate-manual", "--measurements", path, "-o", out, "--image", junk)
    assert unreadable.returncode == 2 and "neither a picture nor a video" in unreadable.stderr
    assert not out.exists()  # every one of them before any output


def test_an_output_that_cannot_be_written_is_refused_before_the_calibration(tmp_path):
    """-o and its picture are checked at start (fileio.writable_file, as fit-scale and run do): a path that cannot
    be written is one line naming it, before the grid search, and no calibration is left without its picture.
    Before, the calibration was computed and written first, then the picture failed."""
    import os

    path = tmp_path / "road.yaml"
    path.write_text(yaml.safe_dump(_measurements(_camera())))
    picture = tmp_path / "frame.png"
    cv2.imwrite(str(picture), np.zeros((SIZE[1], SIZE[0], 3), np.uint8))
    out = tmp_path / "cal.json"
    (tmp_path / "cal.png").mkdir()  # where the picture would go
    proc = _run("calibrate-manual", "--measurements", path, "-o", out, "--image", picture)
    assert proc.returncode == 2 and proc.stderr.strip().splitlines() == [
        f"trafficcal: error: {tmp_path / 'cal.png'}: a folder, so it cannot be the picture"], proc.stderr
    assert not out.exists() and not proc.stdout.strip()
    (tmp_path / "plain").write_text("a file, not a folder")
    link = tmp_path / "linked.json"  # a symlink into a folder that cannot be made: checked at its target
    link.symlink_to("plain/cal.json")
    proc = _run("calibrate-manual", "--measurements", path, "-o", link)
    assert proc.returncode == 2 and proc.stderr.strip().splitlines() == [
        f"trafficcal: error: {link}: cannot write the calibration file (-o) there ({tmp_path / 'plain'} is not a "
        "folder)"], proc.stderr
    assert os.readlink(link) == "plain/cal.json" and not proc.stdout.strip()
    broken = tmp_path / "broken.yaml"
    broken.write_text("lane_dividers: [[1, 2]\n")
    with pytest.raises(InputError, match="broken.yaml: not a readable road measurements file"):
        load_road_measurements(broken)
    with pytest.raises(InputError, match="nowhere.yaml: no such file"):
        load_road_measurements(tmp_path / "nowhere.yaml")
