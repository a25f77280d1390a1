"""vehicleseg's outline construction (sub-pixel hull of the probability's level line) and the training loss
weights that keep shadows out of the mask (``training.vehicleseg.targets.mask_weights``)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gst_trafficcal.detection.vehicleseg import VehicleSegDetector, outline_hull
from gst_trafficcal.errors import InputError

from training.vehicleseg.targets import BOUNDARY_WEIGHT, HARD_WEIGHT, SHADOW_WEIGHT, mask_weights


def coverage(poly: np.ndarray, shape: tuple[int, int], sub: int = 16) -> np.ndarray:
    """Fraction of each pixel (pixel i spans [i, i+1]) inside a convex polygon, by supersampling."""
    big = np.zeros((shape[0] * sub, shape[1] * sub), np.uint8)
    cv2.fillConvexPoly(big, np.round(poly * sub * 16).astype(np.int32), 255, shift=4)
    return cv2.resize(big.astype(np.float32) / 255, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)


def support(poly: np.ndarray, normal: np.ndarray) -> float:
    return float((poly @ normal).max())


def test_outline_hull_follows_a_slanted_edge_within_a_fraction_of_a_pixel():
    # a 30 degree rotated rectangle, as a probability map equal to its pixel coverage
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    corners = np.array([[-14, -7], [14, -7], [14, 7], [-14, 7]], float) @ np.array([[c, s], [-s, c]]) + (30, 25)
    prob = coverage(corners, (50, 60))
    inst = (prob > 0.5).astype(np.int32)
    ys, xs = np.nonzero(inst)
    sl = (slice(ys.min(), ys.max() + 1), slice(xs.min(), xs.max() + 1))
    hull = outline_hull(prob, inst, 1, sl)
    squares = cv2.convexHull((np.stack([xs, ys], 1)[:, None].astype(np.float32) +
                              np.array([[0, 0], [1, 0], [0, 1], [1, 1]], np.float32)).reshape(-1, 2)).reshape(-1, 2)
    for angle in (30, 120, 210, 300):  # the sides' normals: the tangents the tracker uses
        n = np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle))])
        true = support(corners, n)
        assert abs(support(hull, n) - true) <= 0.3, (angle, support(hull, n), true)
    for angle in (75, 165, 255, 345):  # towards the corners, which a level line rounds a little
        n = np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle))])
        assert -0.6 <= support(hull, n) - support(corners, n) <= 0.3, angle
    # the whole-pixel hull sticks out by more along the slanted sides (what the sub-pixel outline removes)
    n = np.array([np.cos(np.radians(120)), np.sin(np.radians(120))])
    assert support(squares, n) - support(corners, n) > 0.4


def test_outline_hull_parts_touching_vehicles_and_stops_at_the_border():
    prob = np.zeros((20, 30), np.float32)
    prob[5:15, 0:12] = 1.0  # cut by the left border
    prob[5:15, 12:25] = 1.0  # touches the first one
    inst = np.zeros((20, 30), np.int32)
    inst[5:15, 0:12] = 1
    inst[5:15, 12:25] = 2
    a = outline_hull(prob, inst, 1, (slice(5, 15), slice(0, 12)))
    b = outline_hull(prob, inst, 2, (slice(5, 15), slice(12, 25)))
    assert a[:, 0].min() == pytest.approx(0.0, abs=0.13) and a[:, 0].max() == pytest.approx(12.0, abs=0.13)
    assert b[:, 0].min() == pytest.approx(12.0, abs=0.13) and b[:, 0].max() == pytest.approx(25.0, abs=0.13)
    assert a[:, 1].min() == pytest.approx(5.0, abs=0.13) and a[:, 1].max() == pytest.approx(15.0, abs=0.13)


def test_mask_threshold_must_be_a_probability():
    with pytest.raises(InputError, match="mask_threshold"):
        VehicleSegDetector(mask_threshold=1.0)


def test_mask_weights_single_out_faint_shadows_next_to_vehicles_and_the_outline():
    fg = np.zeros((40, 60), np.float32)
    fg[10:20, 10:30] = 1.0  # a vehicle
    known = np.ones_like(fg, bool)
    diff = np.zeros_like(fg)
    diff[10:20, 10:30] = 60  # the vehicle changed the image
    diff[20:24, 10:30] = 10  # a soft shadow just below it (less than CHANGED)
    diff[30:34, 40:50] = 10  # the same faint change far from any vehicle: noise, not a shadow
    diff[2:5, 40:50] = 40  # a strong change with no vehicle: a beam or a ghost
    known[0, 0] = False
    w = mask_weights(fg, known, diff)
    assert w[0, 0] == 0
    assert w[22, 20] == SHADOW_WEIGHT
    assert w[32, 45] == 1.0
    assert w[3, 45] == HARD_WEIGHT
    assert w[15, 20] == 1.0  # inside the vehicle
    assert w[10, 20] == BOUNDARY_WEIGHT  # its outline
    assert w[20, 20] == SHADOW_WEIGHT * BOUNDARY_WEIGHT  # the shadow pixel on the outline
    off = mask_weights(fg, known, diff, shadow_weight=0.0, boundary_weight=1.0)
    assert off[22, 20] == 1.0 and off[10, 20] == 1.0 and off[3, 45] == HARD_WEIGHT  # the first model's loss
