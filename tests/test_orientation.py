"""--orientation (ORIENTATION for the scripts): a camera mounted on its side, upside down or imaging a mirror, whose
video carries no rotation tag (RTP has none), analysed upright by trafficcal run, calibrate, report and the scripts
alike; the orientation kept in the calibration file and status.json."""

from __future__ import annotations

import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from gst_trafficcal.calibration import load_calibration

from .conftest import encoded, rotation_tagged, serve_rtsp
from .test_run import PORTRAIT, one_line_error, trafficcal


@pytest.fixture(scope="module")
def stored(tmp_path_factory) -> Path:
    """An untagged 640x360 clip of 25 frames: a camera mounted on its side sends this (no display matrix)."""
    return encoded(tmp_path_factory.mktemp("orientation") / "stored.mp4", "width=640,height=360", frames=25)


@pytest.fixture(scope="module")
def portrait(tmp_path_factory) -> Path:
    """A calibration of the upright 360x640 picture."""
    path = tmp_path_factory.mktemp("portrait") / "portrait.json"
    path.write_text(json.dumps(PORTRAIT))
    return path


@pytest.fixture(scope="module")
def turned_run(stored, portrait, tmp_path_factory):
    """trafficcal run of the untagged clip with --orientation 90r and the calibration of its upright picture."""
    out = tmp_path_factory.mktemp("turned") / "out"
    return out, trafficcal("run", stored, "--out", out, "--calibration", portrait, "--orientation", "90r")


def test_an_untagged_file_is_analysed_turned_as_orientation_says(turned_run):
    """With --orientation 90r the stored 640x360 frames are turned a quarter clockwise: the calibration of the
    upright 360x640 picture is accepted, the overlay is 360 wide, and calibration.json and status.json keep 90r."""
    out, proc = turned_run
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "videoflip video-direction=90r ! videoscale" in proc.stdout
    assert load_calibration(out / "calibration.json").image_size == (360, 640)
    assert json.loads((out / "calibration.json").read_text())["orientation"] == "90r"
    assert json.loads((out / "status.json").read_text())["orientation"] == "90r"
    cap = cv2.VideoCapture(str(out / "overlay.mp4"))
    assert cap.read()[1].shape == (640, 360, 3)
    cap.release()


def test_without_orientation_the_upright_calibration_is_refused(stored, portrait, tmp_path):
    """Without --orientation (auto) nothing turns an untagged video: the upright calibration does not fit."""
    proc = trafficcal("run", stored, "--out", tmp_path / "out", "--calibration", portrait, "--no-overlay")
    assert proc.returncode != 0 and "360x640" in proc.stdout + proc.stderr


def test_a_calibration_file_keeps_its_orientation(stored, turned_run, tmp_path):
    """A run given the calibration.json of a turned run turns the picture the same way without being told; an
    explicit --orientation auto overrides it (and the upright calibration then does not fit the stored frames)."""
    out, _ = turned_run
    proc = trafficcal("run", stored, "--out", tmp_path / "again",
                      "--calibration", out / "calibration.json", "--no-overlay")
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    # a note, not a result: on stderr (`run ... > results.txt` keeps it out of the file) and in run.log
    assert "Orientation kept in" in proc.stderr and "90r (--orientation auto" in " ".join(proc.stderr.split())
    assert "kept in" not in proc.stdout
    assert f"Orientation kept in {out / 'calibration.json'}: 90r" in (tmp_path / "again" / "run.log").read_text()
    assert "videoflip video-direction=90r ! videoscale" in proc.stdout
    auto = trafficcal("run", stored, "--out", tmp_path / "auto", "--calibration", out / "calibration.json",
                      "--no-overlay", "--orientation", "auto")
    assert auto.returncode != 0 and "videoflip video-direction=identity" in auto.stdout


@pytest.mark.parametrize("tag,orientation,size", [(None, "90r", (360, 640)), (90, "identity", (640, 360)),
                                                  (90, "horiz", (640, 360)), (None, "ul-lr", (360, 640))])
def test_calibrate_sees_the_frames_the_run_sees(stored, tmp_path, tag, orientation, size):
    """OpenCV's frames (trafficcal calibrate, its --scale, the report's picture) are turned as the run's videoflip
    turns them, overriding a file's tag too (OpenCV turns a tagged file by itself: that is undone)."""
    from gst_trafficcal.cli.run import first_frame
    from gst_trafficcal.gst.snapshot import first_frame_bgr
    from gst_trafficcal.vanishing.frames import luma_frames

    video = stored if tag is None else rotation_tagged(stored, tmp_path / "tagged.mp4", tag)
    gst = first_frame_bgr(video, orientation=orientation)  # the run's chain: videoflip video-direction=...
    assert gst.shape[1::-1] == size
    frames = luma_frames(video, orientation)
    assert frames.size == size
    for frame in (first_frame(video, orientation), frames.first_bgr):
        assert frame.shape == gst.shape
        assert float(np.mean(np.abs(frame.astype(int) - gst.astype(int)))) < 6.0  # the same picture, decoded twice


def test_calibrate_keeps_the_orientation(stored, tmp_path):
    """trafficcal calibrate --orientation 90r learns on the upright picture and keeps 90r for the run."""
    out = tmp_path / "cal.json"
    proc = trafficcal("calibrate", stored, "-o", out, "--orientation", "90r", "--no-progress")
    assert proc.returncode in (0, 1), proc.stdout[-2000:] + proc.stderr[-2000:]  # 1 s of colour bars: no VPs
    saved = json.loads(out.read_text())
    assert saved["orientation"] == "90r" and saved["image_size"] == [360, 640]


@pytest.fixture(scope="module")
def rtsp_stored(stored):
    """The untagged clip served live over RTSP (no tag travels over RTP)."""
    yield from serve_rtsp(f"( filesrc location={stored} ! qtdemux ! h264parse ! rtph264pay name=pay0 pt=96 )",
                          "side")


def test_a_stream_is_analysed_turned_as_orientation_says(rtsp_stored, portrait, tmp_path):
    """A camera on its side over RTSP: --orientation 90r turns its frames, the upright calibration is accepted."""
    out = tmp_path / "live"
    proc = trafficcal("run", rtsp_stored, "--out", out, "--calibration", portrait, "--orientation", "90r",
                      "--no-overlay")
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "videoflip video-direction=90r ! videoscale" in proc.stdout
    assert load_calibration(out / "calibration.json").image_size == (360, 640)


def test_a_bad_orientation_is_one_line(stored, tmp_path):
    for command in (("run", stored, "--out", tmp_path / "out"), ("calibrate", stored, "-o", tmp_path / "c.json"),
                    ("report", "--events", tmp_path / "none.jsonl", "--out", tmp_path / "r.html")):
        line = one_line_error(trafficcal(*command, "--orientation", "sideways"))
        assert line == ("trafficcal: error: --orientation must be one of auto, identity, 90r, 180, 90l, horiz, "
                        "vert, ul-lr, ur-ll, got 'sideways'")
    assert not (tmp_path / "out").exists() and not (tmp_path / "c.json").exists()


def test_a_file_opencv_refuses_is_turned_too(tmp_path):
    """A truncated MP4 OpenCV refuses gives its first frame through GStreamer (run's and report's picture), turned
    by the orientation as well (the orientation was passed as the snapshot's timeout: a traceback)."""
    from gst_trafficcal.cli.run import first_frame

    from .conftest import VIDEOS, require_shared

    path = require_shared(VIDEOS / "kraten_cars.mp4")
    data = path.read_bytes()
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(data[:int(len(data) * 0.65)])
    upright, turned = first_frame(cut), first_frame(cut, "90r")
    assert turned.shape == (upright.shape[1], upright.shape[0], 3)
    rotated = np.rot90(upright, -1).astype(int)  # a quarter clockwise (turned in I420: chroma sited anew)
    assert float(np.mean(np.abs(turned.astype(int) - rotated))) < 4.0


@pytest.fixture(scope="module")
def squeezed(tmp_path_factory) -> Path:
    """An untagged clip of 480x360 pixels of aspect ratio 4/3 (a 640x360 picture stored squeezed, as a DVR's D1)."""
    return encoded(tmp_path_factory.mktemp("squeezed") / "squeezed.mp4",
                   "width=480,height=360,pixel-aspect-ratio=4/3", frames=25)


@pytest.mark.parametrize("tag,orientation", [(None, "90r"), (90, "auto"), (270, "90r"), (None, "ul-lr")])
def test_non_square_pixels_turned_a_quarter(squeezed, tmp_path, tag, orientation):
    """Pixels of 4/3 turned a quarter: videoflip swaps the caps' pixel-aspect-ratio (360x480 of 3/4), videoscale
    makes 270x480 of it; OpenCV's frames (calibrate, the report's picture) were squared by the stored 4/3: 480x480."""
    from gst_trafficcal.cli.run import first_frame
    from gst_trafficcal.gst.snapshot import first_frame_bgr
    from gst_trafficcal.vanishing.frames import luma_frames

    video = squeezed if tag is None else rotation_tagged(squeezed, tmp_path / "tagged.mp4", tag)
    gst = first_frame_bgr(video, orientation=orientation)
    assert gst.shape[1::-1] == (270, 480)
    frames = luma_frames(video, orientation)
    assert frames.size == (270, 480) and next(iter(frames))[1].shape == (480, 270)
    for frame in (first_frame(video, orientation), frames.first_bgr):
        assert frame.shape == gst.shape
        assert float(np.mean(np.abs(frame.astype(int) - gst.astype(int)))) < 6.0  # the same picture, decoded twice


def test_calibrate_and_run_agree_on_non_square_pixels_turned(squeezed, tmp_path):
    """trafficcal calibrate --orientation 90r of 4/3 pixels writes the size trafficcal run analyses (270x480): a
    run given that calibration accepts it."""
    cal = tmp_path / "cal.json"
    proc = trafficcal("calibrate", squeezed, "-o", cal, "--orientation", "90r", "--no-progress")
    assert proc.returncode in (0, 1), proc.stdout[-2000:] + proc.stderr[-2000:]  # 1 s of colour bars: no VPs
    assert json.loads(cal.read_text())["image_size"] == [270, 480]
    data = dict(PORTRAIT, image_size=[270, 480], pp=[135.0, 240.0], vp1=[135.0, -400.0], orientation="90r")
    cal.write_text(json.dumps(data))
    run = trafficcal("run", squeezed, "--out", tmp_path / "out", "--calibration", cal, "--no-overlay")
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    assert load_calibration(tmp_path / "out" / "calibration.json").image_size == (270, 480)


def test_a_run_of_several_files_keeps_its_views_with_its_orientation(stored, portrait, tmp_path):
    """trafficcal run of several files keeps the camera's views in --out/views/ (vpdetect views-dir): with
    --orientation 90r they are views of the picture turned by 90r — the view kept there is used, and each view the
    run adds is kept with 90r.  Before, the run gave vpdetect no orientation: the view kept with 90r was refused
    ("a view of the picture turned by orientation 90r, not auto ...: not used") and the calibration's view, with its
    scale, was written back as auto, for a run of the stored picture to take up."""
    from dataclasses import replace

    from gst_trafficcal.calibration import load_views, save_calibration, save_view
    from gst_trafficcal.imaging import orientation_of_file
    from gst_trafficcal.vanishing.view import encode_view

    thumbnail = np.tile(np.linspace(0, 255, 90, dtype=np.uint8), (160, 1))  # the upright picture's, 90 x 160
    cal = load_calibration(portrait)
    cal = replace(cal, view=encode_view(thumbnail, 360))
    given = save_calibration(cal, tmp_path / "given.json", orientation="90r")
    out = tmp_path / "out"
    save_view(cal, out / "views", "90r")
    proc = trafficcal("run", stored, stored, "--out", out, "--calibration", given, "--no-overlay")
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    said = " ".join((proc.stdout + proc.stderr).split())
    assert "not used" not in said, said[-2000:]
    assert re.search(r"vpdetect mode=fixed [^!]*orientation=90r", said)
    views, skipped = load_views(out / "views", (360, 640), "90r")
    assert skipped == [] and len(views) == 1
    assert [orientation_of_file(p) for p in (out / "views").glob("*.json")] == ["90r"]
