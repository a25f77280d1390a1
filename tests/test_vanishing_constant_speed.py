"""VP1 along the lanes from constant-speed perspective motion (gst_trafficcal.vanishing.constant_speed)."""

from __future__ import annotations

import numpy as np
import pytest

from gst_trafficcal.geometry import Camera
from gst_trafficcal.vanishing.constant_speed import (LaneMotion, fit_motion, motion_terms, predicted_kappa,
                                                     vp1_across_lines, vp1_along_lanes)
from gst_trafficcal.vanishing.tracks import fit_lines
from gst_trafficcal.vanishing.tracks import MotionLines, TrackParams
from tests.test_vanishing import FPS, cached_scene, scene_camera


def _track_sums(px: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """(sums, count, origin) of one track's points as MotionLines keeps them."""
    rel = px - px[0]
    return motion_terms(t - t[0], rel[:, 0], rel[:, 1]).sum(axis=0), float(len(px)), px[0]


def _road_tracks(cam: Camera, n: int, rng, noise: float = 0.0, points: int = 30):
    """Image tracks of road points driving along world x at constant speed (both directions), with their times."""
    out = []
    while len(out) < n:
        y = rng.uniform(-6, 6)
        x0 = rng.uniform(10, 80)
        v = rng.uniform(15, 35) * rng.choice([-1, 1])
        t = np.arange(points) / 12.5
        X = np.stack([x0 + v * t, np.full(points, y), np.zeros(points)], axis=1)
        if np.any(cam.world_to_camera(X)[:, 2] < 2.0):
            continue
        px = cam.world_to_image(X) + rng.normal(0, noise, (points, 2))
        out.append((px, t))
    return out


def _motion(tracks) -> LaneMotion:
    s = [_track_sums(px, t) for px, t in tracks]
    return fit_motion(np.array([a for a, _, _ in s]), np.array([b for _, b, _ in s]), np.array([c for _, _, c in s]))


def test_fit_motion_gives_the_inverse_distance_to_vp1_exactly_and_honest_variances():
    cam = scene_camera()
    rng = np.random.default_rng(0)
    exact = _motion(_road_tracks(cam, 60, rng))
    assert len(exact) == 60
    truth = predicted_kappa(cam.vp1, exact)
    assert np.allclose(exact.kappa, truth, rtol=1e-6)
    # the direction of motion is along the track's line through VP1, signs: towards VP1 (κ > 0) and away
    to_vp = cam.vp1 - exact.points
    cross = to_vp[:, 0] * exact.directions[:, 1] - to_vp[:, 1] * exact.directions[:, 0]
    assert np.all(np.abs(cross) / np.linalg.norm(to_vp, axis=1) < 1e-6)
    assert (exact.kappa > 0).sum() > 10 and (exact.kappa < 0).sum() > 10

    noisy = _motion(_road_tracks(cam, 400, np.random.default_rng(1), noise=0.3))
    z = (noisy.kappa - predicted_kappa(cam.vp1, noisy)) / np.sqrt(noisy.variance)
    assert 0.7 < np.std(z) < 1.4 and abs(np.median(z)) < 0.2


def test_fit_motion_leaves_out_short_and_degenerate_tracks():
    t = np.arange(4) / 10.0
    short = _track_sums(np.c_[t * 10, t * 5], t)
    static = _track_sums(np.tile([[5.0, 5.0]], (20, 1)), np.arange(20) / 10.0)
    m = fit_motion(np.array([short[0], static[0]]), np.array([short[1], static[1]]),
                   np.array([short[2], static[2]]))
    assert len(m) == 0
    # points that only jitter (a parked car's corner): whatever comes out is finite, nothing raises
    rng = np.random.default_rng(5)
    jitter = [_track_sums(np.tile([[5.0, 5.0]], (20, 1)) + rng.normal(0, 0.3, (20, 2)), np.arange(20) / 10.0)
              for _ in range(200)]
    m = fit_motion(np.array([a for a, _, _ in jitter]), np.array([b for _, b, _ in jitter]),
                   np.array([c for _, _, c in jitter]))
    assert np.all(np.isfinite(m.kappa)) and np.all(m.variance > 0)
    assert len(LaneMotion.concatenate([])) == 0


def test_vp1_along_lanes_undoes_a_shift_along_the_lanes_despite_outliers():
    cam = scene_camera()
    rng = np.random.default_rng(2)
    m = _motion(_road_tracks(cam, 300, rng, noise=0.3))
    # a fifth of the tracks are something else (a braking car, a slipping feature): random κ
    bad = rng.random(len(m)) < 0.2
    kappa = np.where(bad, rng.normal(0, 3 * np.abs(m.kappa).mean(), len(m)), m.kappa)
    m = LaneMotion(m.points, m.directions, kappa, m.variance)
    centre = m.points.mean(axis=0)
    along = (cam.vp1 - centre) / np.linalg.norm(cam.vp1 - centre)
    across = np.array([-along[1], along[0]])
    for shift in (-15.0, 12.0):
        start = cam.vp1 + shift * along + 0.5 * across
        fit = vp1_along_lanes(start, m, image_width=640)
        assert fit is not None
        assert abs((fit.vp1 - cam.vp1) @ along) < 1.0, (shift, fit)
        assert abs(fit.shift_px + shift) < 1.0
        assert fit.relative == pytest.approx(fit.shift_px / np.linalg.norm(start - centre))
        assert 0.7 < fit.inliers < 0.9
    assert vp1_along_lanes(cam.vp1, LaneMotion(*(getattr(m, f)[:10] for f in ("points", "directions", "kappa",
                                                                              "variance"))), 640) is None
    # a start far outside the search range: the best point is at its edge, so no answer
    assert vp1_along_lanes(cam.vp1 + 0.8 * np.linalg.norm(cam.vp1 - centre) * along, m, 640) is None



def _lines_of(tracks) -> np.ndarray:
    """Total-least-squares lines (N, 3) of image tracks, as MotionLines fits them."""
    sums = np.array([[len(px), px[:, 0].sum(), px[:, 1].sum(), (px[:, 0] ** 2).sum(), (px[:, 0] * px[:, 1]).sum(),
                      (px[:, 1] ** 2).sum()] for px, _ in tracks])
    return fit_lines(sums)[0]


def test_vp1_across_lines_moves_vp1_across_the_lanes_to_where_the_tracks_meet():
    """A VP1 right along the lanes but off across them (the Diamond Space's peak) comes back across to where
    the tracks' lines meet; its position along the lanes is kept; outlier lines do not pull it."""
    cam = scene_camera()
    rng = np.random.default_rng(4)
    tracks = _road_tracks(cam, 300, rng, noise=0.2)
    lines = _lines_of(tracks)
    # a tenth of the lines are something else (a lane change, a slipping feature): random directions
    bad = rng.random(len(lines)) < 0.1
    theta = rng.uniform(0, np.pi, bad.sum())
    pts = np.array([px.mean(axis=0) for px, _ in tracks])[bad]
    lines[bad] = np.stack([np.sin(theta), -np.cos(theta), -(np.sin(theta) * pts[:, 0] - np.cos(theta) * pts[:, 1])],
                          axis=1)
    centre = np.array([px.mean(axis=0) for px, _ in tracks]).mean(axis=0)
    along = (cam.vp1 - centre) / np.linalg.norm(cam.vp1 - centre)
    across = np.array([-along[1], along[0]])
    for off in (-1.5, 0.8):
        start = cam.vp1 + off * across
        moved, offset = vp1_across_lines(start, centre, lines, np.ones(len(lines)), image_width=640)
        e = (start - centre) / np.linalg.norm(start - centre)
        assert offset == pytest.approx((moved - start) @ np.array([-e[1], e[0]]))  # the signed move it reports
        assert abs((moved - cam.vp1) @ across) < 0.15, (off, moved - cam.vp1)
        assert abs((moved - start) @ along) < 0.05 * abs(off)  # perpendicular to the centroid's line only
    # lines that do not say where (none, or VP1 far outside the search) leave VP1 as it is
    far = cam.vp1 + 40 * across
    for vp, lns in ((far, lines), (cam.vp1, np.zeros((0, 3)))):
        kept, offset = vp1_across_lines(vp, centre, lns, np.ones(len(lns)), 640)
        assert np.array_equal(kept, vp) and offset == 0.0


def test_klt_tracks_of_a_rendered_scene_put_vp1_where_it_is():
    """OpenCV's KLT on the rendered cuboid traffic (exact perspective, constant speeds): the tracks' projective
    motion fits agree with the true VP1 and bring a VP1 moved 10 px along the lanes back."""
    cam = scene_camera()
    frames = cached_scene(24.0)
    lines = MotionLines(TrackParams())
    parts = []
    for i, f in enumerate(frames[:200]):
        fg = np.full_like(f, 255)
        parts.append(lines.update(f, fg, i / FPS).motion)
    m = LaneMotion.concatenate(parts)
    assert len(m) > 100
    ratio = m.kappa / predicted_kappa(cam.vp1, m)
    assert abs(np.median(ratio) - 1) < 0.03
    centre = m.points.mean(axis=0)
    along = (cam.vp1 - centre) / np.linalg.norm(cam.vp1 - centre)
    fit = vp1_along_lanes(cam.vp1 + 10 * along, m, image_width=frames[0].shape[1])
    assert fit is not None and abs((fit.vp1 - cam.vp1) @ along) < 2.0, fit


@pytest.mark.parametrize("factor", [0.5, 2.0])
def test_scaled_motion_is_the_same_geometry_in_a_larger_image(factor):
    cam = scene_camera()
    m = _motion(_road_tracks(cam, 20, np.random.default_rng(3), noise=0.2))
    s = m.scaled(factor)
    assert np.allclose(s.points, factor * m.points) and np.allclose(s.directions, m.directions)
    assert np.allclose(predicted_kappa(factor * cam.vp1, s), predicted_kappa(cam.vp1, m) / factor)
    assert np.allclose(s.variance, m.variance / factor ** 2)
