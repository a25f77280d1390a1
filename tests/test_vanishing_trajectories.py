"""VP1 from vehicle trajectories: straight lanes seen by a known camera give its VP1 back; bent and short tracks
do not vote."""

from __future__ import annotations

import numpy as np

from gst_trafficcal.geometry import Camera, rotation_matrix
from gst_trafficcal.vanishing.trajectories import (robust_intersection, trajectory_lines, vp1_from_trajectories,
                                                  vp1_with_trajectory_votes)

W, H = 1920, 1080


def camera(pan: float = 20.0, tilt: float = 12.0, roll: float = 2.0, height: float = 8.0, f: float = 2000.0):
    K = np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1.0]])
    R = rotation_matrix(pan, tilt, roll)
    t = -R @ np.array([0.0, 0.0, height])
    return Camera.from_KRt(K, R, t), K, R, t


def project(K, R, t, X):
    p = (K @ (R @ np.asarray(X, np.float64).T + t[:, None])).T
    return p[:, :2] / p[:, 2:]


def lane_tracks(K, R, t, rng, n=12, noise=0.5):
    """Reference points of vehicles driving along the road (world x) in four lanes, seen while 15-60 m away."""
    out = []
    for i in range(n):
        y = (-6.0, -2.5, 2.5, 6.0)[i % 4] + rng.normal(0, 0.2)
        x = np.linspace(15.0, 60.0, 40)
        px = project(K, R, t, np.stack([x, np.full_like(x, y), np.zeros_like(x)], axis=1))
        out.append(px + rng.normal(0, noise, px.shape))
    return out


def test_straight_lanes_give_the_cameras_vp1():
    cam, K, R, t = camera()
    rng = np.random.default_rng(3)
    vp = vp1_from_trajectories(lane_tracks(K, R, t, rng))
    assert vp is not None
    # within 2 px of a VP1 ~2000 px from the points (0.05 degrees), from half-pixel noise
    assert np.linalg.norm(vp.point - cam.vp1) < 2.0
    assert vp.inliers.all() and vp.spread < 1.0


def test_a_lane_change_is_left_out():
    cam, K, R, t = camera()
    rng = np.random.default_rng(4)
    tracks = lane_tracks(K, R, t, rng)
    x = np.linspace(15.0, 60.0, 40)
    y = np.linspace(-6.0, 6.0, 40)  # drives diagonally across the road: a straight line, but not to VP1
    tracks.append(project(K, R, t, np.stack([x, y, np.zeros_like(x)], axis=1)))
    vp = vp1_from_trajectories(tracks)
    assert vp is not None
    assert not vp.inliers[-1] and vp.inliers[:-1].all()
    assert np.linalg.norm(vp.point - cam.vp1) < 2.0
    # the same lines without the robust step: the lane change pulls the point away
    lines, spans = trajectory_lines(tracks)
    plain = np.linalg.lstsq(lines[:, :2] * np.sqrt(spans)[:, None], -lines[:, 2] * np.sqrt(spans), rcond=None)[0]
    assert np.linalg.norm(plain - cam.vp1) > 5.0


def test_short_bent_and_few_tracks_do_not_vote():
    cam, K, R, t = camera()
    rng = np.random.default_rng(5)
    good = lane_tracks(K, R, t, rng, n=5)
    short = [trk[:10] for trk in lane_tracks(K, R, t, rng, n=4)]  # 10 points: fewer than 15
    a = np.linspace(0, np.pi, 40)
    bent = [np.stack([900 + 200 * np.cos(a), 700 + 200 * np.sin(a)], axis=1)]  # an arc: not straight
    lines, spans = trajectory_lines(good + short + bent)
    assert len(lines) == 5 and np.all(spans > 100)
    assert vp1_from_trajectories(good + short + bent) is None  # 5 straight ones, 8 needed
    assert vp1_from_trajectories(good + short + bent, min_lines=5) is not None
    nan_track = lane_tracks(K, R, t, rng, n=1)[0]
    nan_track[::3] = np.nan  # frames without a reference point are skipped, not fatal
    assert len(trajectory_lines([nan_track])[0]) == 1


def test_parallel_lines_have_no_intersection():
    lines = np.array([[0.0, 1.0, -10.0], [0.0, 1.0, -20.0], [0.0, 2.0, -60.0]])  # y = 10, 20, 30
    assert robust_intersection(lines) is None
    assert robust_intersection(lines[:1]) is None


def test_trajectory_votes_pull_a_biased_accumulator_towards_vp1():
    from gst_trafficcal.diamond import DiamondSpace

    cam, K, R, t = camera()
    rng = np.random.default_rng(6)
    # the calibrator's evidence: 300 short, noisy lines towards a VP1 that is 25 px off (a bias of its KLT tracks)
    biased = cam.vp1 + np.array([20.0, 15.0])
    starts = np.stack([rng.uniform(200, 1700, 300), rng.uniform(500, 1050, 300)], axis=1)
    ends = starts + 0.1 * (biased - starts) + rng.normal(0, 1.0, (300, 2))
    ones = np.ones((300, 1))
    klt = np.cross(np.hstack([starts, ones]), np.hstack([ends, ones]))
    ds = DiamondSpace.for_image(W, H, size=128)
    ds.insert(klt, np.full(300, 40.0))
    before = ds.weights.sum()
    alone = ds.find_peak().xy
    assert np.linalg.norm(alone - biased) < 5.0
    tracks = lane_tracks(K, R, t, rng, n=16)
    err = {share: np.linalg.norm(vp1_with_trajectory_votes(ds, tracks, share=share).xy - cam.vp1)
           for share in (1.0, 4.0)}
    # the more weight the trajectories get, the nearer the peak comes to the true VP1 (25 -> 18.5 -> 10.5 px)
    e0 = np.linalg.norm(alone - cam.vp1)
    assert err[4.0] < 0.5 * e0 and err[4.0] < err[1.0] < 0.85 * e0
    # the calibrator's accumulator is untouched
    assert ds.weights.sum() == before and np.allclose(ds.find_peak().xy, alone)
    assert vp1_with_trajectory_votes(ds, tracks[:5]) is None  # fewer than 8 straight trajectories
