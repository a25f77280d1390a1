"""The paper's manual-calibration baseline (§5, "ManualCalib + ManualScale") from BrnoCompSpeed markings.

* **VP1** = least-squares intersection of the lane-divider lines: with normalised normals, solve
  ``A u = -b`` (rows of A: line normals, b: their constant terms).
* **VP2**: the dataset has no lines perpendicular to the traffic, but the measured segments *towards VP2*
  lie on such lines, so their least-squares intersection is the first guess.  It is refined by a grid
  search: for a focal length f the orthogonality constraint ``(u − pp)·(v − pp) = −f²`` restricts v to a
  line perpendicular to ``u − pp``; a point on it is fixed by the angle φ of ``v − pp`` seen from the
  principal point.  The grid runs over plausible f (log-spaced) × φ (all directions opposite to VP1),
  plus the first guess, then zooms in around the best cell.  The objective is the paper's
  ``Σ |λ‖P₁ − P₂‖ − d|`` over the segments towards VP2, with λ from ManualScale.
* **Scale** (ManualScale) = mean of ``d / ‖P₁ − P₂‖`` over the segments towards VP1.

The principal point is the image centre in the dataset's convention, ``(W/2 + 0.5, H/2 + 0.5)``
(960.5, 540.5 for 1920x1080, as in every BrnoCompSpeed calibration).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .brnocompspeed import GroundTruth
from .errors import GeometryError, InputError
from .geometry import Camera

DEFAULT_FOCAL_RANGE = (0.3, 25.0)  # plausible focal lengths, in multiples of the image width
COARSE_GRID = (160, 360)  # focal lengths x angles
ZOOM_GRID = 41
ZOOM_STEPS = 6


def image_centre(image_size: tuple[int, int]) -> np.ndarray:
    """Principal point at the image centre, BrnoCompSpeed's convention (960.5, 540.5 for 1920x1080)."""
    w, h = image_size
    return np.array([w / 2 + 0.5, h / 2 + 0.5])


def intersect_lines_lsq(lines: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Least-squares intersection of homogeneous lines (L, 3): normalise normals, solve A u = −b (each row
    scaled by √weight when ``weights`` (L,) are given: weighted point-to-line distances)."""
    lines = np.asarray(lines, dtype=float).reshape(-1, 3)
    norm = np.linalg.norm(lines[:, :2], axis=1)
    if len(lines) < 2 or np.any(norm == 0):
        raise GeometryError("need at least two proper lines to intersect")
    if weights is not None:
        norm = norm / np.sqrt(np.asarray(weights, dtype=float).reshape(len(lines)))
    A = lines[:, :2] / norm[:, None]
    b = lines[:, 2] / norm
    sol, _, rank, _ = np.linalg.lstsq(A, -b, rcond=None)
    if rank < 2:
        raise GeometryError("the lines are parallel: their intersection is at infinity")
    return sol


def segment_lines(p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    """Homogeneous lines through segment end points (S, 2) -> (S, 3)."""
    ones = np.ones((len(p1), 1))
    return np.cross(np.hstack([p1, ones]), np.hstack([p2, ones]))


def manual_scale(camera: Camera, p1: np.ndarray, p2: np.ndarray, d: np.ndarray) -> float:
    """ManualScale: λ = mean of d / ‖P₁ − P₂‖ (road-plane units) over the given segments."""
    plane = camera.plane_distance(p1, p2)
    return float(np.mean(np.asarray(d, float) / plane))


def batch_plane_distances(vp1: np.ndarray, vp2: np.ndarray, pp: np.ndarray, p1: np.ndarray,
                          p2: np.ndarray) -> np.ndarray:
    """Road-plane distances (up to one scale per camera) for K cameras sharing VP1 and pp.

    vp2 (K, 2), segment ends (S, 2) -> (K, S).  Same model as ``Camera.plane_distance`` (plane normal
    w = ū × v̄, P = p̄ / (p̄·w)) but vectorised over candidate cameras for the grid search; the common
    factor of each camera cancels once λ is fitted.
    """
    a = np.asarray(vp1, float) - pp
    b = np.asarray(vp2, float) - pp
    f = np.sqrt(-(b @ a))  # (K,)
    w = np.cross(np.column_stack([np.broadcast_to(a, b.shape), f]), np.column_stack([b, f]))  # (K, 3)

    def road(p: np.ndarray) -> np.ndarray:
        rays = np.empty((len(f), len(p), 3))
        rays[..., :2] = p - pp
        rays[..., 2] = f[:, None]
        return rays / np.einsum("ksi,ki->ks", rays, w)[..., None]

    return np.linalg.norm(road(p1) - road(p2), axis=-1)


def _candidates(vp1: np.ndarray, pp: np.ndarray, f: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """VP2 for focal lengths f and angles φ on the orthogonality line: (…,) -> (…, 2)."""
    a = vp1 - pp
    an = np.linalg.norm(a)
    ah = a / an
    e = np.array([-ah[1], ah[0]])
    r = f ** 2 / an
    return pp - r[..., None] * ah + (r * np.tan(phi))[..., None] * e


def _f_phi(vp1: np.ndarray, vp2: np.ndarray, pp: np.ndarray) -> tuple[float, float] | None:
    """Inverse of ``_candidates`` (None if the pair gives an imaginary focal length)."""
    a = vp1 - pp
    an = np.linalg.norm(a)
    f2 = -float(np.dot(a, vp2 - pp))
    if not f2 > 0:
        return None
    e = np.array([-a[1], a[0]]) / an
    return float(np.sqrt(f2)), float(np.arctan2(np.dot(vp2 - pp, e), f2 / an))


@dataclass(frozen=True)
class ManualCalibration:
    """Result of the manual baseline: the camera (with ManualScale λ) and how it was found."""

    camera: Camera
    vp2_initial: np.ndarray | None  # least-squares intersection of the VP2 segments (None if degenerate)
    cost_m: float  # Σ |λ‖P₁ − P₂‖ − d| over the segments towards VP2, metres
    n_vp1_segments: int
    n_vp2_segments: int


def segment_angles(vp2: np.ndarray, p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    """Angle (rad) between each segment (S) and the direction from its midpoint to each VP2 (K, 2) -> (K, S)."""
    t = p2 - p1
    m = 0.5 * (p1 + p2)
    to_v = vp2[:, None, :] - m
    cross = t[:, 0] * to_v[..., 1] - t[:, 1] * to_v[..., 0]
    dot = np.sum(t * to_v, axis=-1)
    return np.abs(np.arctan(cross / np.where(dot == 0, 1e-300, dot)))


def _costs(vp1, pp, vp2, p1, p2, d, to_vp1) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        plane = batch_plane_distances(vp1, vp2, pp, p1, p2)
        lam = np.mean(d[to_vp1] / plane[:, to_vp1], axis=1)
        cost = np.sum(np.abs(lam[:, None] * plane[:, ~to_vp1] - d[~to_vp1]), axis=1)
        # tie-breaker: how far (≈ metres) each segment's far end misses the direction towards VP2
        cost = cost + np.sum(d[~to_vp1] * segment_angles(vp2, p1[~to_vp1], p2[~to_vp1]), axis=1)
    return np.where(np.isfinite(cost), cost, np.inf)


@dataclass(frozen=True, eq=False)
class RoadMarkings:
    """What the manual calibration needs: lines that run with the traffic (lane dividers, kerbs) and road
    segments of measured length, along the traffic (towards VP1) or across it (towards VP2); image pixels."""

    lane_lines: np.ndarray  # (L, 3) homogeneous image lines
    p1: np.ndarray  # (S, 2) segment ends
    p2: np.ndarray  # (S, 2)
    metres: np.ndarray  # (S,) measured lengths
    to_vp1: np.ndarray  # (S,) bool: along the traffic
    source: str = "road markings"

    @classmethod
    def from_gt(cls, gt: GroundTruth) -> "RoadMarkings":
        """A BrnoCompSpeed ground truth's lane dividers and measured segments."""
        return cls(np.asarray(gt.lane_div_lines, float).reshape(-1, 3), gt.distances_p1, gt.distances_p2,
                   gt.distances_m, gt.distances_to_vp1, str(gt.source or "ground truth"))


@dataclass(frozen=True)
class SizeDoubt:
    """Why road markings look measured in frames of another size: ``text`` says it, ``outside`` when some lie
    outside the frame (certainly another size) rather than all in its top-left quarter (perhaps)."""
    text: str
    outside: bool


def size_doubt(points: np.ndarray, size: tuple[int, int]) -> SizeDoubt | None:
    """Why road markings at image ``points`` (N x 2 pixels) look measured in frames of another size than ``size``
    (None when they fit): some lie outside it, or all in its top-left quarter (a smaller recording's, read as
    1920x1080 — BrnoCompSpeed's ground truth holds no frame size)."""
    pts = np.asarray(points, float).reshape(-1, 2)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    w, h = size
    if not len(pts):
        return None
    out = pts[(pts[:, 0] < -1) | (pts[:, 0] > w + 1) | (pts[:, 1] < -1) | (pts[:, 1] > h + 1)]
    if len(out):
        return SizeDoubt(f"a road marking at ({out[0, 0]:.0f}, {out[0, 1]:.0f}) lies outside the {w}x{h} frame",
                         outside=True)
    if np.all(pts[:, 0] <= w / 2) and np.all(pts[:, 1] <= h / 2):
        return SizeDoubt(f"every road marking lies in the top-left quarter of the {w}x{h} frame", outside=False)
    return None


def calibrate_manual(gt: GroundTruth, image_size: tuple[int, int] = (1920, 1080), pp=None,
                     focal_range: tuple[float, float] = DEFAULT_FOCAL_RANGE) -> ManualCalibration:
    """ManualCalib + ManualScale from the lane dividers and measured segments of a ground truth."""
    return calibrate_markings(RoadMarkings.from_gt(gt), image_size, pp, focal_range)


def calibrate_markings(m: RoadMarkings, image_size: tuple[int, int] = (1920, 1080), pp=None,
                       focal_range: tuple[float, float] = DEFAULT_FOCAL_RANGE) -> ManualCalibration:
    """ManualCalib + ManualScale from road markings (:class:`RoadMarkings`)."""
    where = m.source
    pp = image_centre(image_size) if pp is None else np.asarray(pp, float)
    if len(m.lane_lines) < 2:
        raise InputError(f"{where}: needs at least two lane-divider lines for VP1")
    p1, p2, d, to_vp1 = m.p1, m.p2, np.asarray(m.metres, float), np.asarray(m.to_vp1, bool)
    n1, n2 = int(np.count_nonzero(to_vp1)), int(np.count_nonzero(~to_vp1))
    if n1 == 0 or n2 == 0:
        raise InputError(f"{where}: needs measured segments both towards VP1 ({n1}) and towards VP2 ({n2})")
    try:
        vp1 = intersect_lines_lsq(m.lane_lines)
    except GeometryError as exc:
        raise GeometryError(f"{where}: lane dividers: {exc}") from None
    if np.linalg.norm(vp1 - pp) < 1e-6 * image_size[0]:
        raise GeometryError(f"{where}: VP1 coincides with the principal point (camera looking along the road)")
    try:
        vp2_init = intersect_lines_lsq(segment_lines(p1[~to_vp1], p2[~to_vp1])) if n2 >= 2 else None
    except GeometryError:
        vp2_init = None

    # coarse grid over (f, φ), plus the first guess
    w = image_size[0]
    f_lo, f_hi = focal_range[0] * w, focal_range[1] * w
    eps = 1e-4
    fs = np.geomspace(f_lo, f_hi, COARSE_GRID[0])
    phis = np.linspace(-np.pi / 2 + eps, np.pi / 2 - eps, COARSE_GRID[1])
    F, PHI = (g.ravel() for g in np.meshgrid(fs, phis, indexing="ij"))
    init = _f_phi(vp1, vp2_init, pp) if vp2_init is not None else None
    if init is not None:
        F, PHI = np.append(F, init[0]), np.append(PHI, init[1])
    cost = _costs(vp1, pp, _candidates(vp1, pp, F, PHI), p1, p2, d, to_vp1)
    k = int(np.argmin(cost))
    if not np.isfinite(cost[k]):
        raise GeometryError(f"{where}: no plausible VP2 found (focal lengths {f_lo:.0f}-{f_hi:.0f} px)")
    best_f, best_phi, best_cost = F[k], PHI[k], cost[k]
    # zoom in around the best cell
    df = np.log(fs[1] / fs[0]) * 2
    dphi = (phis[1] - phis[0]) * 2
    for _ in range(ZOOM_STEPS):
        zf = best_f * np.exp(np.linspace(-df, df, ZOOM_GRID))
        zphi = np.clip(np.linspace(best_phi - dphi, best_phi + dphi, ZOOM_GRID), -np.pi / 2 + eps, np.pi / 2 - eps)
        F, PHI = (g.ravel() for g in np.meshgrid(zf, zphi, indexing="ij"))
        cost = _costs(vp1, pp, _candidates(vp1, pp, F, PHI), p1, p2, d, to_vp1)
        k = int(np.argmin(cost))
        if cost[k] < best_cost:
            best_f, best_phi, best_cost = F[k], PHI[k], cost[k]
        df, dphi = df / 4, dphi / 4

    vp2 = _candidates(vp1, pp, np.array(best_f), np.array(best_phi))
    camera = Camera(vp1, vp2, pp)
    scale = manual_scale(camera, p1[to_vp1], p2[to_vp1], d[to_vp1])
    camera = camera.with_scale(scale)
    cost_m = float(np.sum(np.abs(camera.distance(p1[~to_vp1], p2[~to_vp1]) - d[~to_vp1])))
    return ManualCalibration(camera, vp2_init, cost_m, n1, n2)
