"""imaging.fit: the detectors' reduction of a frame."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gst_trafficcal.imaging import fit


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
