"""imaging.fit: the detectors' reduction of a frame; imaging.squared: OpenCV's frames in square pixels."""

from __future__ import annotations

import subprocess

import cv2
import numpy as np
import pytest

from fractions import Fraction

from gst_trafficcal.imaging import capture_par, fit, square_size, squared

from .conftest import encoded


def test_a_reduction_by_four_is_the_mean_of_each_four_by_four_block():
    """1920x1080 -> 480x270 (bilinear to twice the size, then area): every output pixel the mean of its 16."""
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (1080, 1920, 3), dtype=np.uint8)
    blocks = image.reshape(270, 4, 480, 4, 3).astype(np.float64).mean(axis=(1, 3))
    got = fit(image, (480, 270))
    assert got.shape == (270, 480, 3) and got.dtype == np.uint8
    assert np.abs(got - blocks).max() <= 1.0  # rounding of the two steps


@pytest.mark.parametrize("size", [(480, 270), (320, 320), (1280, 720)])
def test_any_size_is_close_to_a_direct_area_reduction_or_an_enlargement(size):
    rng = np.random.default_rng(1)
    image = cv2.GaussianBlur(rng.integers(0, 256, (360, 640), dtype=np.uint8), (0, 0), 3)  # a smooth picture
    got = fit(image, size)
    ref = cv2.resize(image, size, interpolation=cv2.INTER_AREA if size[0] < 640 else cv2.INTER_LINEAR)
    assert got.shape == (size[1], size[0]) and np.abs(got.astype(int) - ref).mean() < 1.0


@pytest.mark.gst
@pytest.mark.parametrize("width,height,par", [(480, 360, "4/3"), (704, 576, "12/11"), (101, 75, "4/3"),
                                              (100, 80, "10/11"), (720, 576, "16/11"), (640, 360, "1/1")])
def test_the_square_size_is_the_one_videoscale_gives(width, height, par):
    """The size of square pixels OpenCV's frames are scaled to (trafficcal calibrate, the report's picture) is the
    one trafficcal run's ``videoscale ! video/x-raw,pixel-aspect-ratio=1/1`` negotiates (rounded half up)."""
    proc = subprocess.run(["gst-launch-1.0", "-v", "videotestsrc", "num-buffers=1", "!",
                           f"video/x-raw,width={width},height={height},pixel-aspect-ratio={par}", "!", "videoscale",
                           "!", "video/x-raw,pixel-aspect-ratio=1/1", "!", "fakesink"],
                          capture_output=True, text=True, timeout=60, check=True)
    caps = [ln for ln in proc.stdout.splitlines() if "fakesink0.GstPad:sink: caps" in ln][0]
    n, d = map(int, par.split("/"))
    assert f"width=(int){square_size(width, height, Fraction(n, d))[0]}, height=(int){height}," in caps, caps


@pytest.mark.gst
def test_a_video_of_non_square_pixels_is_read_in_square_ones(tmp_path):
    """A 480x360 video of pixel-aspect-ratio 4/3 (a 640x360 picture stored squeezed): OpenCV decodes the stored
    pixels and states the ratio; squared gives the 640x360 frame GStreamer's videoscale makes of it."""
    video = encoded(tmp_path / "par.mp4", "width=480,height=360,pixel-aspect-ratio=4/3", frames=3)
    cap = cv2.VideoCapture(str(video))
    ok, frame = cap.read()
    par = capture_par(cap)
    cap.release()
    assert ok and frame.shape == (360, 480, 3) and par == Fraction(4, 3)
    assert squared(frame, par).shape == (360, 640, 3) and squared(frame, Fraction(1)) is frame
