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
