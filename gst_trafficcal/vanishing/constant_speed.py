"""VP1 along the lanes from the perspective acceleration of points that move at constant speed.

A point moving along a straight road line at constant speed moves in the image along a line through VP1,
and perspective makes it speed up when it comes towards the camera and slow down when it drives away:
its image position along the line is a 1D projective function of time, ``s(t) = (A + B t) / (1 + β t)``,
which tends to the line's vanishing point ``B / β``.  So every short KLT track of a vehicle says not only
*which line* VP1 lies on (the Diamond Space's evidence) but also *how far along it*: the inverse distance
from the track to VP1, ``κ = 1 / (s_∞ − s)``.  The Diamond Space fixes VP1 well across the lanes but poorly
along them (the lane lines meet at small angles); a point off along the lanes stretches or shrinks the road
with distance, which no single scale undoes (speeds 7–12 % off on BrnoCompSpeed views whose VP1 is close).
:func:`vp1_along_lanes` moves VP1 along the lanes to where the tracks' κ say it is.

The fit is linear in (A_x, B_x, A_y, B_y, β) after multiplying by ``1 + β t``, so each track keeps running
sums only (:data:`N_SUMS` of them, :func:`motion_terms`), like the line fit of ``tracks.py``.  Exact for any
track length (a quadratic in t is not: its curvature underestimates κ by 3–11 % on 1–4 s tracks).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

N_SUMS = 14
"""Columns of :func:`motion_terms`: Σt, Σt², Σtx, Σty, Σt²x, Σt²y, Σtx², Σty², Σt²x², Σt²y², Σx, Σy, Σx², Σy²
(x, y relative to the track's first point, t seconds since it)."""

MIN_POINTS = 6
NOISE_FLOOR_PX = 0.05  # KLT positions are float32 sub-pixel estimates: no track is more precise than this


def motion_terms(t: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The per-point terms (K, :data:`N_SUMS`) whose sums over a track :func:`fit_motion` needs."""
    t, x, y = (np.asarray(v, np.float64) for v in (t, x, y))
    t2 = t * t
    return np.stack([t, t2, t * x, t * y, t2 * x, t2 * y, t * x * x, t * y * y, t2 * x * x, t2 * y * y,
                     x, y, x * x, y * y], axis=1)


@dataclass(frozen=True)
class LaneMotion:
    """Per track: where it was (mean time), its unit direction of motion, the inverse distance κ from there to
    its vanishing point along that direction (1/px; negative when the point moves away from it) and κ's
    variance.  Pixels of whatever image the tracks were measured in (:meth:`scaled` converts)."""

    points: np.ndarray      # (N, 2)
    directions: np.ndarray  # (N, 2)
    kappa: np.ndarray       # (N,)
    variance: np.ndarray    # (N,)

    def __len__(self) -> int:
        return len(self.kappa)

    @classmethod
    def empty(cls) -> "LaneMotion":
        return cls(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0))

    def scaled(self, factor: float) -> "LaneMotion":
        """The same tracks in an image ``factor`` times larger."""
        return LaneMotion(self.points * factor, self.directions, self.kappa / factor, self.variance / factor ** 2)

    @classmethod
    def concatenate(cls, parts: list["LaneMotion"]) -> "LaneMotion":
        if not parts:
            return cls.empty()
        return cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in ("points", "directions", "kappa",
                                                                                "variance")))


def _moments(sums: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The sums as two (N, 3, 3) tables of Σ tᵃ xᵇ and Σ tᵃ yᵇ (a, b = 0, 1, 2)."""
    St, St2, Stx, Sty, St2x, St2y, Stx2, Sty2, St2x2, St2y2, Sx, Sy, Sx2, Sy2 = sums.T
    tx = np.stack([np.stack([n, Sx, Sx2], -1), np.stack([St, Stx, Stx2], -1), np.stack([St2, St2x, St2x2], -1)], 1)
    ty = np.stack([np.stack([n, Sy, Sy2], -1), np.stack([St, Sty, Sty2], -1), np.stack([St2, St2y, St2y2], -1)], 1)
    return tx, ty


def _shift(table: np.ndarray, dt: np.ndarray, dx: np.ndarray) -> np.ndarray:
    """Σ (t − dt)ᵃ (x − dx)ᵇ from the table of Σ tᵃ xᵇ (binomial expansion, per track)."""
    def binomial(d: np.ndarray) -> np.ndarray:
        o, z = np.ones_like(d), np.zeros_like(d)
        return np.stack([np.stack([o, z, z], -1), np.stack([-d, o, z], -1), np.stack([d * d, -2 * d, o], -1)], 1)
    return np.einsum("kai,kij,kbj->kab", binomial(dt), table, binomial(dx))


def fit_motion(sums: np.ndarray, counts: np.ndarray, origins: np.ndarray) -> LaneMotion:
    """Projective motion fits of tracks from their sums (N, :data:`N_SUMS`), point counts (N,) and the points
    their coordinates are relative to (N, 2).  Tracks with too few points or a degenerate fit are left out.

    The sums are first moved to the track's mean time and position (exactly, by binomial expansion), where the
    fit is well conditioned and the noise of the positions has a simple effect (corrected below)."""
    sums = np.asarray(sums, np.float64).reshape(-1, N_SUMS)
    n = np.asarray(counts, np.float64).reshape(-1)
    origins = np.asarray(origins, np.float64).reshape(-1, 2)
    ok = n >= MIN_POINTS
    sums, n, origins = sums[ok], n[ok], origins[ok]
    if not len(n):
        return LaneMotion.empty()
    tx, ty = _moments(sums, n)
    tb, mx, my = tx[:, 1, 0] / n, tx[:, 0, 1] / n, ty[:, 0, 1] / n
    tx, ty = _shift(tx, tb, mx), _shift(ty, tb, my)
    St2 = tx[:, 2, 0]
    Stx, St2x, Stx2, St2x2, Sx2 = tx[:, 1, 1], tx[:, 2, 1], tx[:, 1, 2], tx[:, 2, 2], tx[:, 0, 2]
    Sty, St2y, Sty2, St2y2, Sy2 = ty[:, 1, 1], ty[:, 2, 1], ty[:, 1, 2], ty[:, 2, 2], ty[:, 0, 2]
    # x (1 + β t) = A_x + B_x t, the same for y with the same β; unknowns (A_x, B_x, A_y, B_y, β); Σt = Σx = Σy = 0
    z = np.zeros_like(n)
    M = np.stack([np.stack([n, z, z, z, -Stx], -1), np.stack([z, St2, z, z, -St2x], -1),
                  np.stack([z, z, n, z, -Sty], -1), np.stack([z, z, z, St2, -St2y], -1),
                  np.stack([-Stx, -St2x, -Sty, -St2y, St2x2 + St2y2], -1)], axis=1)
    rhs = np.stack([z, Stx, z, Sty, -(Stx2 + Sty2)], axis=1)
    good = np.linalg.cond(M) < 1e12
    M, rhs, n, origins = M[good], rhs[good], n[good], origins[good]
    mean = np.stack([mx[good], my[good]], axis=1)
    St2, Sx2, Sy2 = St2[good], Sx2[good], Sy2[good]
    if not len(n):
        return LaneMotion.empty()
    theta = np.linalg.solve(M, rhs[..., None])[..., 0]
    ss = Sx2 + Sy2 - np.einsum("ki,ki->k", theta, rhs)
    noise2 = np.maximum(ss / (2 * n - 5), 0.0)
    # the β column holds t·x and t·y, noisy like the positions: their noise adds σ²Σt² (per coordinate) to its
    # normal-matrix entry, which pulls β (and κ) towards zero; take it out
    M[:, 4, 4] -= 2 * noise2 * St2
    well = np.linalg.cond(M) < 1e12  # the correction can leave a noisy, barely moving track without a solution
    M, rhs, n, mean, origins, noise2 = M[well], rhs[well], n[well], mean[well], origins[well], noise2[well]
    if not len(n):
        return LaneMotion.empty()
    sigma2 = np.maximum(noise2, NOISE_FLOOR_PX ** 2)
    Mi = np.linalg.inv(M)
    theta = np.einsum("kij,kj->ki", Mi, rhs)
    A, B, b = theta[:, [0, 2]], theta[:, [1, 3]], theta[:, 4]
    D = B - b[:, None] * A  # the velocity's direction at the mean time
    L = np.linalg.norm(D, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        kappa = b / L  # κ = β / |B − β A| at t = 0 (the mean time)
        L3 = L ** 3
        grad = np.stack([b * b * D[:, 0] / L3, -b * D[:, 0] / L3, b * b * D[:, 1] / L3, -b * D[:, 1] / L3,
                         1 / L + b * np.einsum("ki,ki->k", D, A) / L3], axis=1)
        var = sigma2 * np.einsum("ki,kij,kj->k", grad, Mi, grad)
        directions = D / L[:, None]
    points = A + mean + origins
    keep = (np.isfinite(kappa) & np.isfinite(var) & (var > 0) & (L > 0) & np.all(np.isfinite(points), axis=1))
    return LaneMotion(points[keep], directions[keep], kappa[keep], var[keep])


@dataclass(frozen=True)
class AlongLanes:
    """VP1 moved along the lanes by :func:`vp1_along_lanes`."""

    vp1: np.ndarray        # (2,) pixels
    shift_px: float        # distance moved (positive: away from the tracks)
    relative: float        # ... as a share of VP1's distance from the tracks' centroid before the move
    tracks: int            # tracks used
    inliers: float         # share of them within 3 robust σ of the fitted κ


def predicted_kappa(vp: np.ndarray, motion: LaneMotion) -> np.ndarray:
    """κ that each track of ``motion`` would have if its vanishing point were ``vp`` (on its line)."""
    with np.errstate(divide="ignore"):
        return 1.0 / np.einsum("ki,ki->k", np.asarray(vp, np.float64) - motion.points, motion.directions)


def vp1_along_lanes(vp1: np.ndarray, motion: LaneMotion, image_width: float, min_tracks: int = 30,
                    search: float = 0.3, steps: int = 241, clip: float = 9.0) -> AlongLanes | None:
    """VP1 moved along the line from the tracks' centroid through ``vp1`` to where the tracks' κ agree best
    (a truncated quadratic of the κ residuals over their standard deviations, the deviations scaled by a robust
    estimate from a first pass).  The inverse distance q = 1/|VP1 − centroid| is searched within ± ``search``
    of its value (at least ± ``search`` / ``image_width``).  None with fewer than ``min_tracks`` tracks, a VP1 on
    the tracks, or a best point at the edge of the search (the evidence does not say)."""
    vp1 = np.asarray(vp1, np.float64).reshape(2)
    if len(motion) < min_tracks or not np.all(np.isfinite(vp1)):
        return None
    c = motion.points.mean(axis=0)
    e = vp1 - c
    dist = float(np.linalg.norm(e))
    if dist < 1e-6:
        return None
    e /= dist
    q0 = 1.0 / dist
    along = motion.directions @ e  # (e · d): how each track's line runs relative to the search direction
    offset = np.einsum("ki,ki->k", c - motion.points, motion.directions)
    sd = np.sqrt(motion.variance)
    qs = q0 + search * max(q0, 1.0 / image_width) * np.linspace(-1.0, 1.0, steps)

    def residuals(q: np.ndarray) -> np.ndarray:  # (len(q), N) κ residuals in standard deviations
        with np.errstate(divide="ignore", invalid="ignore"):
            pred = q[:, None] / (along[None, :] + q[:, None] * offset[None, :])
        r = (motion.kappa[None, :] - pred) / sd[None, :]
        return np.where(np.isfinite(r), r, np.inf)

    scale = 1.0
    for _ in range(2):  # the second pass with the noise level the first one's residuals show
        cost = np.minimum((residuals(qs) / scale) ** 2, clip).sum(axis=1)
        k = int(np.argmin(cost))
        r = residuals(qs[k:k + 1])[0]
        scale = max(float(np.sqrt(np.median(r[np.isfinite(r)] ** 2) / 0.455)), 1e-6)  # median of χ²(1) = 0.455
    if k in (0, steps - 1) or qs[k] <= 0:
        return None
    lo, hi = qs[max(k - 1, 0)], qs[min(k + 1, steps - 1)]
    fine = np.linspace(lo, hi, 41)
    cost = np.minimum((residuals(fine) / scale) ** 2, clip).sum(axis=1)
    q = float(fine[int(np.argmin(cost))])
    new = c + e / q
    r = residuals(np.array([q]))[0] / scale
    shift = float(1.0 / q - dist)
    return AlongLanes(new, shift, shift / dist, int(len(motion)), float(np.mean(np.abs(r) < 3.0)))


def vp1_across_lines(vp1: np.ndarray, centroid: np.ndarray, lines: np.ndarray, weights: np.ndarray,
                     image_width: float, span: float = 4.0, steps: int = 801) -> tuple[np.ndarray, float]:
    """VP1 moved *across* the lanes — perpendicular to the line from the tracks' ``centroid`` through it — to
    where the tracks' ``lines`` (N, 3 homogeneous, image pixels) pass closest: the least pseudo-Huber sum of their
    weighted distances in pixels (scale half a pixel per 960 of width), searched within ± ``span`` such pixels.
    Returns the point and the signed move in pixels (+: along (−e_y, e_x), e the unit direction from the centroid
    to VP1 — to the right of it on screen, y down).

    The Diamond Space's peak lies 0.5–0.8 px across the lanes from the true VP1 on the synth scenes, although the
    tracks' lines pass within 0.1–0.4 px of it (its refinement weighs the lines' algebraic residuals, not their
    distances), and :func:`vp1_along_lanes` then searches along a line that misses VP1: along the lanes that costs
    1–2.5 % of road length on views whose VP1 is near the image (docs/vpdetect.md, "Stop 39")."""
    vp1 = np.asarray(vp1, np.float64).reshape(2)
    e = vp1 - np.asarray(centroid, np.float64).reshape(2)
    dist = float(np.linalg.norm(e))
    lines = np.asarray(lines, np.float64).reshape(-1, 3)
    w = np.asarray(weights, np.float64).reshape(-1)
    if dist < 1e-9 or not len(lines):
        return vp1, 0.0
    n = np.array([-e[1], e[0]]) / dist
    unit = image_width / 960.0
    norm = np.linalg.norm(lines[:, :2], axis=1)
    ok = (norm > 0) & np.isfinite(w) & (w > 0)
    lines, w = lines[ok] / norm[ok, None], w[ok]
    offsets = np.linspace(-span, span, steps) * unit
    pts = vp1[None, :] + offsets[:, None] * n[None, :]
    z = (pts @ lines[:, :2].T + lines[None, :, 2]) / (0.5 * unit)
    cost = (w[None, :] * (np.sqrt(1.0 + z * z) - 1.0)).sum(axis=1)
    k = int(np.argmin(cost))
    if k in (0, steps - 1):  # the lines do not say where within the search: leave VP1 as it is
        return vp1, 0.0
    return pts[k], float(offsets[k])
