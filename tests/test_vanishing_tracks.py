"""VP1 evidence: straight KLT tracks of moving textured objects become lines through their vanishing point."""

from __future__ import annotations

import cv2
import numpy as np

from gst_trafficcal.diamond import DiamondSpace
from gst_trafficcal.vanishing.tracks import MotionLines, TrackParams, fit_lines


def _sums(pts: np.ndarray) -> np.ndarray:
    x, y = pts[:, 0], pts[:, 1]
    return np.array([len(x), x.sum(), y.sum(), (x * x).sum(), (x * y).sum(), (y * y).sum()])


def test_fit_lines_is_total_least_squares():
    rng = np.random.default_rng(0)
    sets, truth = [], []
    for _ in range(50):
        p = rng.uniform(0, 500, 2)
        d = rng.normal(size=2)
        d /= np.linalg.norm(d)
        t = rng.uniform(-100, 100, 30)
        pts = p + t[:, None] * d + rng.normal(0, 0.3, (30, 2))
        sets.append(_sums(pts))
        centred = pts - pts.mean(axis=0)
        n = np.linalg.svd(centred)[2][1]  # normal = smallest right singular vector
        truth.append((np.r_[n, -n @ pts.mean(axis=0)], np.sqrt(np.linalg.svd(centred)[1][1] ** 2 / 30)))
    lines, resid = fit_lines(np.array(sets))
    for (want, r), got, rr in zip(truth, lines, resid):
        assert np.allclose(got, want) or np.allclose(got, -want)
        assert abs(rr - r) < 1e-9


def _textured_patch(rng, size=24) -> np.ndarray:
    p = rng.integers(0, 255, (size // 4, size // 4)).astype(np.uint8)
    return cv2.resize(p, (size, size), interpolation=cv2.INTER_NEAREST)


def test_tracks_of_objects_moving_towards_a_point_pass_through_it():
    """Textured squares slide along straight paths towards VP = (320, -200) on a flat background: the track
    lines pass close to it and their Diamond Space peak is on it."""
    rng = np.random.default_rng(1)
    vp = np.array([320.0, -200.0])
    starts = np.array([[60.0, 420.0], [250.0, 430.0], [420.0, 400.0], [560.0, 440.0], [150.0, 300.0]])
    patches = [_textured_patch(rng) for _ in starts]
    bg = cv2.GaussianBlur(rng.integers(90, 110, (480, 640)).astype(np.uint8), (0, 0), 2)
    objects = np.zeros(bg.shape, np.float32)
    alpha0 = np.zeros(bg.shape, np.float32)
    for (x, y), patch in zip(starts.astype(int), patches):
        objects[y - 12:y + 12, x - 12:x + 12] = patch
        alpha0[y - 12:y + 12, x - 12:x + 12] = 1.0
    tracker = MotionLines(TrackParams(max_length=25, detect_every=1))
    lines = []
    for k in range(40):
        # perspective-like motion: the objects shrink towards vp, so every point of them moves on a line
        # through vp (as points on a vehicle driving away do)
        sigma = 1.0 - 0.012 * k
        m = np.float32([[sigma, 0, vp[0] * (1 - sigma)], [0, sigma, vp[1] * (1 - sigma)]])
        layer = cv2.warpAffine(objects, m, (640, 480))
        alpha = cv2.warpAffine(alpha0, m, (640, 480))
        frame = np.clip(bg * (1 - alpha) + layer, 0, 255).astype(np.uint8)
        fg = (cv2.dilate(alpha, np.ones((9, 9), np.uint8)) > 0).astype(np.uint8) * 255
        found, lengths, _ = tracker.update(frame, fg)
        assert np.all(lengths >= 0)
        lines.append(found)
    lines = np.concatenate(lines)
    assert len(lines) >= 20
    dist = np.abs(lines @ np.r_[vp, 1.0]) / np.linalg.norm(lines[:, :2], axis=1)
    assert np.median(dist) < 2.0 and np.percentile(dist, 90) < 6.0
    ds = DiamondSpace.for_image(640, 480, 128)
    ds.insert(lines)
    assert np.linalg.norm(ds.find_peak().xy - vp) < 5.0  # 0.5 degree seen from the tracks


def test_no_motion_no_tracks():
    rng = np.random.default_rng(2)
    frame = cv2.GaussianBlur(rng.integers(0, 255, (120, 160)).astype(np.uint8), (0, 0), 1.5)
    tracker = MotionLines()
    fg = np.full_like(frame, 255)  # even with everything marked as moving
    for _ in range(30):
        lines, _, _ = tracker.update(frame, fg)
        assert len(lines) == 0
