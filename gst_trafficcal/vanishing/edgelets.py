"""VP2 evidence: edgelets on moving vehicles (paper §4.1) and the gradient-orientation baseline ("ITS15").

Edgelets, exactly as the paper describes: seeds s_i are local maxima of the gradient magnitude
E = ‖∇I‖ above a threshold (here also inside the moving regions); from the 9x9 neighbourhood of a seed the
matrix X_i has rows w_k (m_k - x_i, n_k - y_i) with w_k = E at the neighbour; the edge orientation is the first
singular vector of X_i and the quality the ratio of its singular values.  X_iᵀX_i is 2x2, so its eigen
decomposition is closed-form and all seeds are processed at once.

The baseline of Dubská et al. (ITS 2015) instead takes the edge orientation from the gradient direction at
each seed (perpendicular to ∇I), which is poorly resolved near multiples of 45° on a 3x3 Sobel.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

RADIUS = 4  # 9x9 neighbourhood
_DY, _DX = np.mgrid[-RADIUS:RADIUS + 1, -RADIUS:RADIUS + 1]
# the 9x9 neighbourhood without its corners (a disc of radius 4.5): a full square is 41 % longer along its
# diagonals, which biases every orientation towards 45° by up to 3° (measured on anti-aliased straight edges)
_DISC = (_DX ** 2 + _DY ** 2).ravel() <= (RADIUS + 0.5) ** 2
_DX = _DX.ravel()[_DISC].astype(np.float64)
_DY = _DY.ravel()[_DISC].astype(np.float64)


@dataclass(frozen=True)
class Edgelets:
    """Edge segments: seed points (N, 2), unit directions (N, 2), quality (N,) and magnitude (N,)."""

    points: np.ndarray
    directions: np.ndarray
    quality: np.ndarray
    magnitude: np.ndarray

    def __len__(self) -> int:
        return len(self.points)

    def lines(self) -> np.ndarray:
        """Homogeneous lines (N, 3) through the seeds along the edge directions (unit normals)."""
        nx, ny = -self.directions[:, 1], self.directions[:, 0]
        return np.stack([nx, ny, -(nx * self.points[:, 0] + ny * self.points[:, 1])], axis=1)

    def subset(self, keep: np.ndarray) -> "Edgelets":
        return Edgelets(self.points[keep], self.directions[keep], self.quality[keep], self.magnitude[keep])

    def scaled(self, factor: float) -> "Edgelets":
        """Points multiplied by ``factor`` (analysis resolution -> image pixels)."""
        return Edgelets(self.points * factor, self.directions, self.quality, self.magnitude)

    @staticmethod
    def concat(items: list["Edgelets"]) -> "Edgelets":
        if not items:
            return EMPTY
        return Edgelets(*(np.concatenate([getattr(e, f) for e in items]) for f in
                          ("points", "directions", "quality", "magnitude")))


EMPTY = Edgelets(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0))


def gradients(gray: np.ndarray, blur: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sobel gradients (grey levels per pixel) of a lightly smoothed image and their magnitude."""
    # float before smoothing: rounding a blurred image back to 8 bits restores a staircase (VP2 2.8° -> 4.9°)
    g = cv2.GaussianBlur(gray, (3, 3), 0).astype(np.float32) if not blur else \
        cv2.GaussianBlur(gray.astype(np.float32), (0, 0), blur)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3, scale=0.125)
    return gx, gy, cv2.magnitude(gx, gy)


def seeds(mag: np.ndarray, mask: np.ndarray | None, threshold: float, max_seeds: int) -> tuple[np.ndarray, np.ndarray]:
    """(ys, xs) of local maxima (3x3) of ``mag`` above ``threshold`` inside ``mask``, strongest ``max_seeds``.

    (Seeds at every pixel of the ridge, i.e. maxima across the edge only, were tried: VP2 3.6° instead of 2.8° on
    highway_day, 4.6° instead of 3.8° on the cuboid scene in the same geometry.)"""
    peak = (mag >= cv2.dilate(mag, np.ones((3, 3), np.uint8))) & (mag > threshold)
    if mask is not None:
        peak &= cv2.resize(mask, (mag.shape[1], mag.shape[0]), interpolation=cv2.INTER_NEAREST) > 0
    border = np.zeros_like(peak)
    border[RADIUS:-RADIUS, RADIUS:-RADIUS] = True
    ys, xs = np.nonzero(peak & border)
    if len(ys) > max_seeds:
        top = np.argpartition(-mag[ys, xs], max_seeds)[:max_seeds]
        ys, xs = ys[top], xs[top]
    return ys, xs


def _crop(gray: np.ndarray, mask: np.ndarray | None):
    """(gray, mask) cut to the bounding box of the mask (+ margin), and the offset; (None, ...) if it is empty.

    The mask is resized to the image first; gradients are then computed only where seeds can be."""
    if mask is None:
        return gray, None, 0, 0
    h, w = gray.shape
    mask = cv2.resize(mask, (w, h), interpolation=cv2.INTER_NEAREST)
    x, y, bw, bh = cv2.boundingRect(mask)
    if bw == 0 or bh == 0:
        return None, None, 0, 0
    m = RADIUS + 3
    x0, y0, x1, y1 = max(x - m, 0), max(y - m, 0), min(x + bw + m, w), min(y + bh + m, h)
    if x1 - x0 <= 2 * RADIUS + 2 or y1 - y0 <= 2 * RADIUS + 2:
        return None, None, 0, 0
    return gray[y0:y1, x0:x1], mask[y0:y1, x0:x1], x0, y0


def detect_edgelets(gray: np.ndarray, mask: np.ndarray | None = None, threshold: float = 6.0,
                    max_seeds: int = 1500, orientation: str = "subpixel", blur: float = 0.0,
                    along: int = RADIUS) -> Edgelets:
    """Edgelets of a grey image, seeds restricted to ``mask`` (uint8, any size, resized to the image).

    ``orientation="svd"`` is the paper's (first singular vector of X).  On a pixel grid it is biased by
    0.4-1° for sharp straight edges (the sampled ridge is a staircase whose offsets correlate with the position
    along the edge inside a 9-pixel window; measured on anti-aliased edges, see docs/vpdetect.md), which moves a
    far VP2 by degrees.  ``"subpixel"`` (default) starts from it and refines the direction by a weighted
    total-least-squares line through the sub-pixel ridge of the magnitude in each column (or row) of the 9x9
    patch: bias below 0.1°.  ``"tensor"`` uses the gradient structure tensor of the patch (bias up to 0.4°).
    The quality is always the paper's singular-value ratio.  ``blur``: Gaussian sigma of the smoothing before
    Sobel (0: a 3x3 kernel); the calibrator uses 1.0 (highway_day VP2 error 3.6° -> 2.8°).
    """
    gray, mask, x0, y0 = _crop(gray, mask)
    if gray is None:
        return EMPTY
    gx, gy, mag = gradients(gray, blur)
    ys, xs = seeds(mag, mask, threshold, max_seeds)
    if not len(ys):
        return EMPTY
    wk = mag[ys[:, None] + _DY.astype(np.int64)[None, :], xs[:, None] + _DX.astype(np.int64)[None, :]]
    w2 = wk.astype(np.float64) ** 2
    # moments about the weighted centroid of the patch rather than the integer seed pixel: the seed lies up
    # to half a pixel off the edge, which tilts the orientation by ~1° (measured); the centroid is also a
    # sub-pixel position of the edgelet
    sw = np.maximum(w2.sum(axis=1), 1e-12)
    cx, cy = (w2 @ _DX) / sw, (w2 @ _DY) / sw
    sxx = w2 @ (_DX * _DX) - sw * cx * cx
    sxy = w2 @ (_DX * _DY) - sw * cx * cy
    syy = w2 @ (_DY * _DY) - sw * cy * cy
    half = 0.5 * (sxx - syy)
    root = np.sqrt(half * half + sxy * sxy)
    l1 = 0.5 * (sxx + syy) + root
    l2 = np.maximum(0.5 * (sxx + syy) - root, 1e-12)
    theta = 0.5 * np.arctan2(2 * sxy, sxx - syy)  # first eigenvector of XᵀX = first singular vector of X
    if orientation == "subpixel":
        theta = _subpixel_orientation(mag, ys, xs, theta, along=along)
    elif orientation == "tensor":
        oy, ox = ys[:, None] + _DY.astype(np.int64)[None, :], xs[:, None] + _DX.astype(np.int64)[None, :]
        gxk, gyk = gx[oy, ox].astype(np.float64), gy[oy, ox].astype(np.float64)
        jxx, jxy, jyy = (gxk * gxk).sum(1), (gxk * gyk).sum(1), (gyk * gyk).sum(1)
        theta = 0.5 * np.arctan2(2 * jxy, jxx - jyy) + np.pi / 2  # edge = perpendicular to the mean gradient
    elif orientation != "svd":
        raise ValueError(f"unknown edgelet orientation {orientation!r} (subpixel, svd or tensor)")
    d = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    q = np.sqrt(l1 / l2)  # ratio of the singular values of X
    return Edgelets(np.stack([xs + cx + x0, ys + cy + y0], axis=1), d, q, mag[ys, xs].astype(np.float64))


_OFF = np.arange(-RADIUS, RADIUS + 1)


def _subpixel_orientation(mag: np.ndarray, ys: np.ndarray, xs: np.ndarray, theta0: np.ndarray,
                          min_support: int = 3, along: int = RADIUS) -> np.ndarray:
    """Edge directions (radians) from the sub-pixel ridge of ``mag`` in the 9x9 patch of each seed.

    For edges closer to horizontal (by ``theta0``) each column's maximum is refined with a parabola across
    the edge; for the others each row's.  A weighted total-least-squares line through those points (weights
    = ridge magnitude, columns under half the strongest ignored) gives the direction; it is refitted without
    the ridge points more than 0.75 px off it (another edge meeting this one inside the patch).  Where fewer
    than ``min_support`` columns remain, the paper's orientation ``theta0`` is kept.  (Dropping edgelets with
    fewer than 6 supporting columns, i.e. corners and curves, was tried: no measurable change of VP2.)
    """
    horiz = np.abs(np.cos(theta0)) >= np.abs(np.sin(theta0))
    alo = np.arange(-along, along + 1)
    pad = 2 * along + RADIUS
    padded = cv2.copyMakeBorder(mag, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=0)
    yc, xc = ys + pad, xs + pad
    # (n, across, along): rows across the edge, columns along it (transposed for steep edges); each column's
    # window is centred on the first estimate of the edge, so long windows follow slanted edges
    slope = np.where(horiz, np.tan(theta0), 1.0 / np.where(horiz, 1.0, np.tan(theta0)))
    shift = np.rint(slope[:, None] * alo[None, :]).astype(np.int64)
    shift = np.clip(shift, -along, along)
    across = _OFF[None, :, None] + shift[:, None, :]
    rr = np.where(horiz[:, None, None], yc[:, None, None] + across, yc[:, None, None] + alo[None, None, :])
    cc = np.where(horiz[:, None, None], xc[:, None, None] + alo[None, None, :], xc[:, None, None] + across)
    patch = padded[rr, cc].astype(np.float64)
    n, size = len(patch), 2 * RADIUS + 1
    ncol = 2 * along + 1
    r = np.argmax(patch, axis=1)
    rc = np.clip(r, 1, size - 2)
    ii, jj = np.arange(n)[:, None], np.arange(ncol)[None, :]
    lo, c, hi = patch[ii, rc - 1, jj], patch[ii, rc, jj], patch[ii, rc + 1, jj]
    den = lo - 2 * c + hi
    sub = np.clip(np.where(den < 0, 0.5 * (lo - hi) / np.where(den < 0, den, -1.0), 0.0), -0.5, 0.5)
    yy = rc + sub - RADIUS + shift
    xx = np.broadcast_to(alo[None, :].astype(np.float64), yy.shape)
    w = c * (c > 0.5 * c.max(axis=1, keepdims=True)) * (r > 0) * (r < size - 1)
    t = _tls_angle(w, xx, yy)
    # second pass without the ridge points off the first line (another edge meeting this one in the patch)
    res = np.abs(-np.sin(t)[:, None] * (xx - _wmean(w, xx)[:, None]) + np.cos(t)[:, None] * (yy - _wmean(w, yy)[:, None]))
    w = w * (res < 0.75)
    t = _tls_angle(w, xx, yy)
    ok = (w > 0).sum(axis=1) >= min_support
    return np.where(ok, np.where(horiz, t, np.pi / 2 - t), theta0)


def _wmean(w: np.ndarray, v: np.ndarray) -> np.ndarray:
    return (w * v).sum(axis=1) / np.maximum(w.sum(axis=1), 1e-12)


def _tls_angle(w: np.ndarray, xx: np.ndarray, yy: np.ndarray) -> np.ndarray:
    """Direction angle of the weighted total-least-squares line through the points (xx, yy) of each row."""
    dx, dy = xx - _wmean(w, xx)[:, None], yy - _wmean(w, yy)[:, None]
    return 0.5 * np.arctan2(2 * (w * dx * dy).sum(axis=1), (w * dx * dx).sum(axis=1) - (w * dy * dy).sum(axis=1))


def detect_gradient_edgels(gray: np.ndarray, mask: np.ndarray | None = None, threshold: float = 6.0,
                           max_seeds: int = 1500) -> Edgelets:
    """The ITS15 baseline: same seeds, orientation perpendicular to the Sobel gradient, quality = magnitude."""
    gray, mask, x0, y0 = _crop(gray, mask)
    if gray is None:
        return EMPTY
    gx, gy, mag = gradients(gray)
    ys, xs = seeds(mag, mask, threshold, max_seeds)
    if not len(ys):
        return EMPTY
    m = mag[ys, xs].astype(np.float64)
    d = np.stack([-gy[ys, xs], gx[ys, xs]], axis=1) / np.maximum(m, 1e-9)[:, None]
    return Edgelets(np.stack([xs + x0, ys + y0], axis=1).astype(np.float64), d, m, m)


def interior(e: Edgelets, image: np.ndarray, background: np.ndarray, bg_scale: float, threshold: float,
             offset: float = 3.0) -> np.ndarray:
    """Bool (N,): edgelets inside a vehicle — the image ``offset`` pixels to either side of the edge (along its
    normal) differs from the background by more than ``threshold`` grey levels on *both* sides — rather than on
    its outline against the road.  Creases, windows, lights and bumper lines are straight 3D edges across the
    vehicle; the outline of a rounded body (and its shadow) is not, and tilts with the viewing angle, which moves
    a far VP2 by degrees (docs/vpdetect.md, stop 30).  ``image``: the grey image the edgelets were found in;
    ``background``: a background model of it at ``bg_scale`` of its size (e.g. the calibrator's foreground
    model)."""
    from scipy.ndimage import map_coordinates

    if not len(e):
        return np.zeros(0, bool)
    bg = np.asarray(background, np.float32)
    normal = np.stack([-e.directions[:, 1], e.directions[:, 0]], axis=1)
    least = np.full(len(e), np.inf)
    for side in (1.0, -1.0):
        q = e.points + side * offset * normal
        # sampled straight into float: no float copy of the whole frame per searched frame
        a = map_coordinates(image, [q[:, 1], q[:, 0]], order=1, mode="nearest", output=np.float32)
        qb = (q + 0.5) * bg_scale - 0.5  # pixel centres at integers in both images
        b = map_coordinates(bg, [qb[:, 1], qb[:, 0]], order=1, mode="nearest")
        least = np.minimum(least, np.abs(a - b))
    return least > threshold


def towards(e: Edgelets, vp: np.ndarray, max_angle_deg: float) -> np.ndarray:
    """Bool (N,): edgelets whose line passes within ``max_angle_deg`` of the homogeneous point ``vp``."""
    vp = np.asarray(vp, dtype=np.float64)
    to_vp = vp[:2][None, :] - e.points * vp[2]  # direction from each seed to vp (also for vp at infinity)
    norm = np.linalg.norm(to_vp, axis=1)
    sin = np.abs(e.directions[:, 0] * to_vp[:, 1] - e.directions[:, 1] * to_vp[:, 0]) / np.maximum(norm, 1e-12)
    return sin < np.sin(np.radians(max_angle_deg))
