"""Edgelets (paper §4.1) and the ITS15 gradient baseline on rendered straight edges."""

from __future__ import annotations

import cv2
import numpy as np

from gst_trafficcal.vanishing.edgelets import (Edgelets, detect_edgelets, detect_gradient_edgels, interior, seeds,
                                               towards)


def _edge_image(theta_deg: float, size: int = 120, noise: float = 3.0, seed: int = 0) -> np.ndarray:
    """A straight step edge through the image centre at ``theta_deg``, anti-aliased (8x supersampled), blurred
    like a lens and with sensor noise."""
    s = 8
    y, x = np.mgrid[0:size * s, 0:size * s] / s
    t = np.radians(theta_deg)
    side = (-(x - size / 2) * np.sin(t) + (y - size / 2) * np.cos(t)) > 0
    big = np.where(side, 60, 190).astype(np.float32)
    g = cv2.GaussianBlur(cv2.resize(big, (size, size), interpolation=cv2.INTER_AREA), (0, 0), 0.8)
    return np.clip(g + np.random.default_rng(seed).normal(0, noise, g.shape), 0, 255).astype(np.uint8)


def _orientation_errors(detect) -> np.ndarray:
    errors = []
    for theta in np.arange(0, 180, 7.5) + 1.3:
        e = detect(_edge_image(theta), None)
        e = e.subset(np.abs(e.points - 60).max(axis=1) < 50)  # away from the image border
        assert len(e) > 10
        ang = np.degrees(np.arctan2(e.directions[:, 1], e.directions[:, 0]))
        errors.append(np.abs((ang - theta + 90) % 180 - 90))
    return np.concatenate(errors)


def test_edgelet_orientation_is_accurate_at_every_angle_and_beats_gradients():
    edg = _orientation_errors(detect_edgelets)
    grad = _orientation_errors(detect_gradient_edgels)
    assert np.median(edg) < 0.8 and np.percentile(edg, 90) < 1.5
    assert np.percentile(edg, 90) < np.percentile(grad, 90)
    assert np.median(edg) < np.median(grad)


def test_edgelets_lie_on_the_edge_and_straight_edges_have_high_quality():
    g = _edge_image(33.0, noise=1.0)
    e = detect_edgelets(g, None)
    t = np.radians(33.0)
    dist = np.abs(-(e.points[:, 0] - 60) * np.sin(t) + (e.points[:, 1] - 60) * np.cos(t))
    assert np.median(dist) < 0.6
    assert np.percentile(e.quality, 5) > 2.5  # elongated neighbourhood: first singular value dominates
    # a blob-like corner has a low ratio of singular values
    corner = np.full((60, 60), 60, np.uint8)
    corner[30:, 30:] = 190
    c = detect_edgelets(cv2.GaussianBlur(corner, (0, 0), 0.8), None)
    near = np.linalg.norm(c.points - 29.5, axis=1) < 4.0
    assert near.any() and c.quality[near].min() < 0.85 * np.percentile(e.quality, 5)


def test_lines_of_edgelets_pass_through_their_points_along_their_direction():
    e = Edgelets(np.array([[10.0, 20.0], [5.0, 5.0]]), np.array([[1.0, 0.0], [0.6, 0.8]]), np.ones(2), np.ones(2))
    lines = e.lines()
    assert np.allclose(np.sum(lines * np.c_[e.points, np.ones(2)], axis=1), 0)
    ahead = e.points + 7 * e.directions
    assert np.allclose(np.sum(lines * np.c_[ahead, np.ones(2)], axis=1), 0)


def test_edgelets_pointing_at_a_vanishing_point_are_recognised_finite_and_infinite():
    pts = np.array([[100.0, 100.0], [200.0, 300.0], [50.0, 400.0]])
    vp = np.array([300.0, -500.0])
    d = vp - pts
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    perp = np.c_[-d[:, 1], d[:, 0]]
    e = Edgelets.concat([Edgelets(pts, d, np.ones(3), np.ones(3)), Edgelets(pts, perp, np.ones(3), np.ones(3))])
    assert towards(e, np.r_[vp, 1.0], 2.0).tolist() == [True] * 3 + [False] * 3
    horizontal = Edgelets(pts, np.tile([1.0, 0.0], (3, 1)), np.ones(3), np.ones(3))
    assert towards(horizontal, np.array([1.0, 0.0, 0.0]), 1.0).all()  # VP at infinity along x
    assert not towards(horizontal, np.array([0.0, 1.0, 0.0]), 1.0).any()


def test_seeds_only_inside_the_mask_and_empty_images_give_no_edgelets():
    g = _edge_image(10.0)
    mask = np.zeros((30, 30), np.uint8)  # any size: resized to the image
    mask[:, :15] = 255
    e = detect_edgelets(g, mask)
    assert len(e) > 0 and e.points[:, 0].max() < 61
    assert len(detect_edgelets(np.full((50, 50), 128, np.uint8), None)) == 0
    assert len(detect_gradient_edgels(g, np.zeros_like(g))) == 0
    ys, xs = seeds(np.zeros((20, 20), np.float32), None, 1.0, 10)
    assert len(ys) == 0


def _jagged_edge_image(theta_deg: float, size: int = 160, seed: int = 0) -> np.ndarray:
    """A straight edge at ``theta_deg`` drawn without anti-aliasing (each pixel fully one side or the other, as the
    synth renderer draws vehicles), then the optics blur of the renders (sigma 0.6) and sensor noise."""
    y, x = np.mgrid[0:size, 0:size].astype(np.float64)
    t = np.radians(theta_deg)
    side = (-(x - size / 2) * np.sin(t) + (y - size / 2) * np.cos(t)) > 0
    g = cv2.GaussianBlur(np.where(side, 60, 190).astype(np.float32), (0, 0), 0.6)
    return np.clip(g + np.random.default_rng(seed).normal(0, 2.0, g.shape), 0, 255).astype(np.uint8)


def _signed_errors(theta: float, along: int) -> np.ndarray:
    e = detect_edgelets(_jagged_edge_image(theta), None, blur=1.0, along=along)
    e = e.subset(np.abs(e.points - 80).max(axis=1) < 60)
    assert len(e) > 10
    ang = np.degrees(np.arctan2(e.directions[:, 1], e.directions[:, 0]))
    return (ang - theta + 90) % 180 - 90


def test_long_orientation_window_removes_pixel_locking_of_jagged_near_horizontal_edges():
    # a 2.5° staircase steps every 23 px: a 9 px window sees a flat run or a step, so the edgelets' median
    # orientation locks towards 0° (the Diamond Space then follows that mode); 17 px along the edge sees the slope
    for theta in (2.5, 3.5, 5.0):
        short = np.median(_signed_errors(theta, along=4))
        long_ = np.median(_signed_errors(theta, along=8))
        assert abs(long_) < 0.5 * abs(short), (theta, short, long_)
    # and the long window does not hurt steeper edges
    assert abs(np.median(_signed_errors(17.0, along=8))) < 0.3


def test_interior_edgelets_are_those_with_a_changed_image_on_both_sides():
    """A dark car body on a mid-grey road with a light window band across it: the body's outline has the road on
    one side, the band's two edges have the body and the window — both unlike the road — on theirs."""
    road = np.full((120, 200), 100, np.uint8)
    frame = road.copy()
    frame[40:90, 50:150] = 40  # body
    frame[58:68, 50:150] = 160  # window band across the whole body
    frame = cv2.GaussianBlur(frame, (0, 0), 0.8)
    e = detect_edgelets(frame, threshold=6.0, max_seeds=5000)
    e = e.subset(e.quality >= 2.5)
    x, y = e.points[:, 0], e.points[:, 1]
    inside_x = (x > 60) & (x < 140)
    on_band = inside_x & ((np.abs(y - 57.5) < 1.5) | (np.abs(y - 67.5) < 1.5))
    on_outline = inside_x & ((np.abs(y - 39.5) < 1.5) | (np.abs(y - 89.5) < 1.5))
    assert on_band.sum() > 20 and on_outline.sum() > 20
    half = cv2.resize(road, (100, 60), interpolation=cv2.INTER_AREA).astype(np.float32)  # a coarser background
    keep = interior(e, frame, half, 0.5, threshold=15.0)
    assert keep[on_band].all() and not keep[on_outline].any()
    # the same image as its own background: nothing changed, nothing is interior
    assert not interior(e, frame, frame.astype(np.float32), 1.0, threshold=15.0).any()
    assert interior(e.subset(np.zeros(len(e), bool)), frame, half, 0.5, 15.0).shape == (0,)
