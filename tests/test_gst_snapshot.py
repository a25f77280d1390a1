"""One frame of a video file through GStreamer (gst/snapshot.py), where OpenCV's FFmpeg may refuse the file."""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest

from gst_trafficcal.gst.snapshot import first_frame_bgr

from .conftest import VIDEOS, require_shared

pytestmark = pytest.mark.gst


def test_the_first_frame_is_the_one_opencv_decodes():
    path = require_shared(VIDEOS / "kraten_cars.mp4")
    frame = first_frame_bgr(path)
    cap = cv2.VideoCapture(str(path))
    ok, expected = cap.read()
    cap.release()
    assert ok and frame is not None and frame.shape == expected.shape and frame.dtype == np.uint8
    # the same picture (the two decoders' YUV to BGR conversions differ by a few levels)
    assert np.abs(frame.astype(int) - expected.astype(int)).mean() < 4.0


def test_a_truncated_mp4_opencv_refuses_still_gives_its_first_frame(tmp_path):
    """An MP4 with its index first, cut at 65 % of its bytes: FFmpeg stops at "error reading header", GStreamer
    plays what is there (and the run measures it, so its pictures come from there too)."""
    path = require_shared(VIDEOS / "kraten_cars.mp4")
    data = path.read_bytes()
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(data[:int(len(data) * 0.65)])
    cap = cv2.VideoCapture(str(cut))
    refused = not cap.read()[0]
    cap.release()
    assert refused  # what makes the fallback needed
    frame = first_frame_bgr(cut)
    assert frame is not None and np.array_equal(frame, first_frame_bgr(path))


def test_not_a_video_or_missing_is_none_at_once(tmp_path):
    text = tmp_path / "notes.mp4"
    text.write_text("not a video\n" * 100)
    for path in (text, tmp_path / "missing.mp4"):
        t0 = time.monotonic()
        assert first_frame_bgr(path, timeout_s=60) is None
        assert time.monotonic() - t0 < 30  # the decoding error ends the wait, not the timeout


def test_a_rotated_or_squeezed_video_is_pictured_as_the_elements_see_it(tmp_path):
    """A phone's video (frames stored 640x360, its display matrix turning them a quarter clockwise) and a 640x360
    picture stored as 480x360 pixels of 4/3: the picture is upright and of square pixels, as trafficcal run's
    elements see it (videoflip video-direction=auto, videoscale) and as OpenCV turns it (the same frame)."""
    from gst_trafficcal.cli.run import first_frame

    from .conftest import encoded, rotation_tagged

    turned = rotation_tagged(encoded(tmp_path / "stored.mp4", "width=640,height=360", frames=3), tmp_path / "r.mp4")
    squeezed = encoded(tmp_path / "par.mp4", "width=480,height=360,pixel-aspect-ratio=4/3", frames=3)
    for video, shape in ((turned, (640, 360, 3)), (squeezed, (360, 640, 3))):
        frame, opencv = first_frame_bgr(video), first_frame(video)
        assert frame.shape == shape and opencv.shape == shape
        assert np.abs(frame.astype(int) - opencv.astype(int)).mean() < 4.0


def _first(video, chain):
    """The first frame of ``video`` through ``decodebin ! videoconvert ! CHAIN`` as BGR."""
    from gst_trafficcal.gst._gi import Gst
    from gst_trafficcal.gst.buffers import frame_bgr, video_info_from_caps

    pipeline = Gst.parse_launch(" ! ".join([f"filesrc location={video}", "decodebin", "videoconvert", *chain,
                                            "videoconvert", "video/x-raw,format=BGR", "appsink name=sink"]))
    pipeline.set_state(Gst.State.PAUSED)
    try:
        assert pipeline.get_state(10 * Gst.SECOND)[0] == Gst.StateChangeReturn.SUCCESS
        sample = pipeline.get_by_name("sink").emit("try-pull-preroll", 0)
        with frame_bgr(sample.get_buffer(), video_info_from_caps(sample.get_caps())) as bgr:
            return np.array(bgr, copy=True)
    finally:
        pipeline.set_state(Gst.State.NULL)


# a stored frame as its display matrix shows it (independent of the code under test)
SHOWN = {90: lambda f: np.rot90(f, -1), 180: lambda f: f[::-1, ::-1], 270: lambda f: np.rot90(f, 1),
         "horiz": lambda f: f[:, ::-1], "vert": lambda f: f[::-1], "ul-lr": lambda f: f.swapaxes(0, 1),
         "ur-ll": lambda f: f[::-1, ::-1].swapaxes(0, 1)}


@pytest.mark.parametrize("degrees", [90, 180, 270, "horiz", "vert", "ul-lr", "ur-ll"])
def test_the_pipelines_turn_a_rotated_video_as_opencv_does(tmp_path, capsys, degrees):
    """The videoflip trafficcal run and the scripts put before the elements for a file's rotation or mirroring
    (read before the pipeline starts) shows the frames as the display matrix says, as OpenCV's frames do
    (trafficcal calibrate, the report's picture), as the snapshot does, and as GStreamer's videoflip
    video-direction=auto does by the tag where GStreamer 1.22 tags it (not ur-ll).  Mirrored matrices were read as
    OpenCV's rotation (a horizontal mirroring as turned by 180°: the picture upside down) or not at all (ur-ll)."""
    from gst_trafficcal.cli.run import direction_of, first_frame
    from gst_trafficcal.gst.chains import analysed_video, main
    from gst_trafficcal.vanishing.frames import luma_frames

    from .conftest import encoded, rotation_tagged

    stored = encoded(tmp_path / "stored.mp4", "width=320,height=180", frames=3)
    video = rotation_tagged(stored, tmp_path / "r.mp4", degrees)
    assert direction_of(video) == direction_of(f"file://{video}") != "identity"
    frame = _first(video, analysed_video(direction_of(video)))
    expected = SHOWN[degrees](_first(stored, []))
    assert frame.shape == expected.shape == ((180, 320, 3) if degrees in (180, "horiz", "vert") else (320, 180, 3))
    assert main(["analysed", str(video)]) == 0  # the scripts' (pipelines/lib.sh)
    assert capsys.readouterr().out.split()[:2] == ["videoflip", f"video-direction={direction_of(video)}"]
    for other in (expected, first_frame(video), first_frame_bgr(video), luma_frames(video).first_bgr):
        assert other.shape == frame.shape
        assert np.abs(frame.astype(int) - other.astype(int)).mean() < 4.0
    if degrees != "ur-ll":
        assert np.abs(frame.astype(int) - _first(video, analysed_video(None)).astype(int)).mean() < 4.0
