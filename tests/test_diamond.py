"""Diamond Space: mapping of the projective plane, rasterisation, sub-cell peaks for finite and infinite VPs."""

from __future__ import annotations

import numpy as np
import pytest

from gst_trafficcal.diamond import DiamondSpace, focal_mask, from_diamond, rasterise, to_diamond

W, H = 1920, 1080


def _bundle(rng, vp, n, noise_px=0.5, outliers=0):
    """n noisy lines through vp (pixels (2,) or homogeneous direction (3,) with w=0) + random outlier lines."""
    pts = rng.uniform([0, 0], [W, H], (n, 2))
    vp = np.asarray(vp, float)
    d = vp[:2] / np.linalg.norm(vp[:2]) if vp.shape == (3,) else vp - pts
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    q = pts + d * 200 + rng.normal(0, noise_px, (n, 2))
    p = pts + rng.normal(0, noise_px, (n, 2))
    lines = np.cross(np.c_[p, np.ones(n)], np.c_[q, np.ones(n)])
    if outliers:
        a = rng.uniform([0, 0], [W, H], (outliers, 2))
        b = rng.uniform([0, 0], [W, H], (outliers, 2))
        lines = np.r_[lines, np.cross(np.c_[a, np.ones(outliers)], np.c_[b, np.ones(outliers)])]
    return lines


def _angle_deg(p, q, ds):
    a, b = ds.points_to_normalised(p), ds.points_to_normalised(q)
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    return float(np.degrees(np.arccos(min(1.0, abs(a @ b)))))


def test_mapping_round_trip_covers_the_whole_plane():
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(1000, 3)) * [5, 5, 1]
    pts[:10, 2] = 0  # points at infinity
    uv = to_diamond(pts)
    assert np.all(np.abs(uv).sum(axis=1) <= 1 + 1e-12)
    assert np.allclose(np.abs(uv[:10]).sum(axis=1), 1.0)  # infinity = the border of the diamond
    back = from_diamond(uv)
    cos = np.abs(np.sum(back * pts, axis=1)) / np.linalg.norm(back, axis=1) / np.linalg.norm(pts, axis=1)
    assert np.allclose(cos, 1.0)


def test_a_line_becomes_a_polyline_through_the_cells_of_its_points():
    rng = np.random.default_rng(2)
    for _ in range(20):
        line = rng.normal(size=3)
        line /= np.linalg.norm(line)
        acc = rasterise(line[None], np.ones(1), 128)
        # points of the line, mapped into the diamond, fall into (or next to) voted cells
        t = rng.normal(size=(200, 2))
        a, b = np.linalg.svd(line[None])[2][1:]  # basis of the line's points
        pts = t[:, :1] * a + t[:, 1:] * b
        uv = to_diamond(pts)
        iu = np.clip(np.floor((uv[:, 0] + 1) / (2 / 128)).astype(int), 0, 127)
        iv = np.clip(np.floor((uv[:, 1] + 1) / (2 / 128)).astype(int), 0, 127)
        padded = np.pad(acc, 1)
        near = sum(padded[iv + 1 + dv, iu + 1 + du] for dv in (-1, 0, 1) for du in (-1, 0, 1))
        assert np.all(near > 0)
        # about one vote per crossed column/row: the polyline is thin
        assert acc.sum() <= 4 * 64 + 1


@pytest.mark.parametrize("vp", [(900.0, -300.0), (960.0, 540.0), (5000.0, 400.0), (-40000.0, 150.0),
                                (1.0, 0.02, 0.0), (0.0, 1.0, 0.0)])
def test_peak_is_found_far_below_one_cell_with_noise_and_outliers(vp):
    rng = np.random.default_rng(3)
    ds = DiamondSpace.for_image(W, H, 128)
    ds.insert(_bundle(rng, vp, 1500, noise_px=0.5, outliers=500))
    peak = ds.find_peak()
    truth = np.r_[vp, 1.0] if len(vp) == 2 else np.asarray(vp)
    cell = np.degrees(ds._cell_angle(ds.points_to_normalised(truth) / np.linalg.norm(ds.points_to_normalised(truth))))
    err = _angle_deg(peak.point, truth, ds)
    assert err < 0.1 * cell, (peak.xy, err, cell)
    assert err < 0.05
    assert peak.support > 0.5


def test_weights_decide_between_two_bundles():
    rng = np.random.default_rng(4)
    ds = DiamondSpace.for_image(W, H, 128)
    ds.insert(_bundle(rng, (500.0, -200.0), 300), np.full(300, 1.0))
    ds.insert(_bundle(rng, (3000.0, 100.0), 300), np.full(300, 3.0))
    assert _angle_deg(ds.find_peak().point, np.array([3000.0, 100.0, 1.0]), ds) < 0.05


def test_mask_restricts_the_peak_to_plausible_focal_lengths():
    rng = np.random.default_rng(5)
    ds = DiamondSpace.for_image(W, H, 128)
    vp1 = np.array([1100.0, -400.0])
    pp = np.array([W / 2, H / 2])
    strong, weak = (1200.0, -350.0), (-3000.0, 900.0)  # the strong one gives an imaginary focal length
    ds.insert(_bundle(rng, strong, 800))
    ds.insert(_bundle(rng, weak, 300))
    assert _angle_deg(ds.find_peak().point, np.r_[strong, 1.0], ds) < 0.1
    peak = ds.find_peak(focal_mask(vp1, pp, (500.0, 5000.0)))
    assert _angle_deg(peak.point, np.r_[weak, 1.0], ds) < 0.1
    f = np.sqrt(-np.dot(peak.xy - pp, vp1 - pp))
    assert 500 <= f <= 5000


def test_nothing_voted_gives_no_peak_and_bad_sizes_are_refused():
    ds = DiamondSpace.for_image(W, H, 64)
    assert ds.find_peak() is None
    ds.insert(np.zeros((3, 3)))  # degenerate lines are ignored
    assert ds.find_peak() is None
    with pytest.raises(ValueError):
        DiamondSpace(size=7)
    with pytest.raises(ValueError):
        ds.insert(np.ones((3, 3)), np.ones(2))


def test_horizon_mask_excludes_the_vertical_vanishing_point():
    from gst_trafficcal.diamond import all_of, horizon_mask

    rng = np.random.default_rng(6)
    ds = DiamondSpace.for_image(W, H, 128)
    vp1, pp = np.array([1100.0, -400.0]), np.array([W / 2, H / 2])
    vp3, vp2 = (900.0, 6000.0), (-3000.0, 800.0)  # both give a real focal length with vp1
    ds.insert(_bundle(rng, vp3, 900))
    ds.insert(_bundle(rng, vp2, 300))
    focal = focal_mask(vp1, pp, (300.0, 20000.0))
    assert _angle_deg(ds.find_peak(focal).point, np.r_[vp3, 1.0], ds) < 0.1
    peak = ds.find_peak(all_of(focal, horizon_mask(vp1, 30.0)))
    assert _angle_deg(peak.point, np.r_[vp2, 1.0], ds) < 0.1


def test_anchored_lines_are_refined_by_angle_at_their_points():
    rng = np.random.default_rng(7)
    vp = np.array([-4000.0, 300.0])
    pts = rng.uniform([0, 300], [W, H], (3000, 2))
    ang = np.arctan2(*(vp - pts).T[::-1]) + np.radians(rng.normal(0, 1.0, len(pts)))
    normals = np.c_[-np.sin(ang), np.cos(ang)]
    lines = np.c_[normals, -(normals * pts).sum(axis=1)]
    ds = DiamondSpace.for_image(W, H, 128)
    ds.insert(lines, points=pts)
    assert ds.anchors is not None
    assert _angle_deg(ds.find_peak().point, np.r_[vp, 1.0], ds) < 0.3
    with pytest.raises(ValueError):
        ds.insert(lines[:2], points=pts[:3])


def test_a_far_vanishing_point_is_polished_by_a_robust_angular_fit():
    """A VP2 ten image widths away from 3000 anchored lines with 0.3° of noise and a quarter of unrelated lines: the
    peak lies within a tenth of a degree; the soft-L1 polish keeps the point when too few lines are near
    it or when the polished point would leave the mask."""
    from gst_trafficcal.diamond import _polish_angular

    rng = np.random.default_rng(3)
    vp = np.array([-19000.0, 400.0])
    pts = rng.uniform([0, 500], [W, H], (3000, 2))
    ang = np.arctan2(*(vp - pts).T[::-1]) + np.radians(rng.normal(0, 0.3, len(pts)))
    ang[:750] = rng.uniform(-np.pi, np.pi, 750)
    normals = np.c_[-np.sin(ang), np.cos(ang)]
    lines = np.c_[normals, -(normals * pts).sum(axis=1)]
    ds = DiamondSpace.for_image(W, H, 128)
    ds.insert(lines, points=pts)
    assert _angle_deg(ds.find_peak().point, np.r_[vp, 1.0], ds) < 0.15

    p = ds.points_to_normalised(np.r_[vp + [4000.0, 0.0], 1.0])
    p /= np.linalg.norm(p)
    ln, an = ds.lines, ds.anchors
    ab = np.linalg.norm(ln[:, :2], axis=1)

    def residual(q):
        dist = np.maximum(np.linalg.norm(q[:2][None, :] - an * q[2], axis=1) * ab, 1e-12)
        return (ln @ q) / dist, dist

    w = ds.weights
    polished = _polish_angular(p, w, residual, None, ds.points_to_pixels)
    assert _angle_deg(ds.points_to_pixels(polished), np.r_[vp, 1.0], ds) < 0.15 < _angle_deg(
        ds.points_to_pixels(p), np.r_[vp, 1.0], ds)
    assert np.array_equal(_polish_angular(p, w, residual, lambda x: np.zeros(len(x), bool), ds.points_to_pixels), p)
    few = np.zeros_like(w)
    few[750:755] = 1.0

    def residual_few(q):
        r, d = residual(q)
        return np.where(few > 0, r, 1.0), d
    assert np.array_equal(_polish_angular(p, w, residual_few, None, ds.points_to_pixels), p)
