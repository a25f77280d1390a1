"""The traffic camera model of the paper (§3): two vanishing points, a principal point and a scale.

Conventions (all vectorised over leading axes):

* Image points are pixels in the uncentred image frame; ``pp`` is the principal point.
* Camera coordinates: x right, y down, z forward (optical axis); the image point ``p`` is the ray
  ``p̄ = [p - pp, f]``.
* ``f = sqrt(-(u - pp)·(v - pp))`` for the vanishing points ``u`` (VP1, direction of traffic) and ``v`` (VP2,
  perpendicular to traffic, parallel to the road).
* The road plane is ``n·X + δ = 0`` with δ = 1 and ``n`` the unit normal pointing from the road towards the
  camera, so the camera is one *plane unit* above the road.  The scale λ converts plane units to metres,
  hence **λ is the camera height above the road in metres**.
* World frame (metres): origin on the road below the camera, x towards VP1 (the forward-pointing one of the
  two directions), z up, y = z × x.  ``X_cam = R X_world + t``.

BrnoCompSpeed uses another scale convention (its ``code/loading.py``): uncentred 3D pixel coordinates with the
camera centre at ``(pp, 0)`` and the road plane ``[n, 10]``; :meth:`Camera.from_brno` and
:meth:`Camera.brno_scale` convert exactly.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass, field, replace

import numpy as np

from .errors import GeometryError

BRNO_PLANE_OFFSET = 10.0  # BrnoCompSpeed's constant term of the road plane


def _as_points(a, name: str) -> np.ndarray:
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim == 0 or arr.shape[-1] != 2:
        raise GeometryError(f"{name} must have 2 coordinates in its last axis, got shape {arr.shape}")
    return arr


def _as_point(a, name: str) -> np.ndarray:
    """One image point (2,) of ``a``; GeometryError naming it for anything else (2x2 was numpy's 'cannot reshape',
    a single number an IndexError)."""
    arr = np.asarray(a, dtype=np.float64)
    if arr.size != 2:
        raise GeometryError(f"{name} must be one image point (x, y), got shape {arr.shape}")
    return arr.reshape(2)


def homogeneous(points: np.ndarray) -> np.ndarray:
    """(..., 2) -> (..., 3) with a trailing 1."""
    points = np.asarray(points, dtype=np.float64)
    return np.concatenate([points, np.ones(points.shape[:-1] + (1,))], axis=-1)


def line_through(p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    """Homogeneous line through two image points, normalised so that ‖(a, b)‖ = 1."""
    line = np.cross(homogeneous(p1), homogeneous(p2))
    return line / np.linalg.norm(line[..., :2], axis=-1, keepdims=True)


def focal_from_vps(vp1, vp2, pp) -> np.ndarray:
    """Focal length from two orthogonal vanishing points (NaN where it would be imaginary)."""
    d = -np.sum((np.asarray(vp1, float) - pp) * (np.asarray(vp2, float) - pp), axis=-1)
    with np.errstate(invalid="ignore"):
        return np.where(d > 0, np.sqrt(np.maximum(d, 0.0)), np.nan)


def rotation_matrix(pan_deg: float, tilt_deg: float, roll_deg: float) -> np.ndarray:
    """World→camera rotation for a camera above the road (world x forward along the road, z up).

    pan turns the camera left of the road direction, tilt looks down, roll turns the image clockwise.
    At zero angles the camera looks horizontally along world +x.
    """
    p, t, r = np.radians([pan_deg, tilt_deg, roll_deg])
    # base: camera x = -world y, camera y = -world z, camera z = world x
    base = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    rz = np.array([[np.cos(p), -np.sin(p), 0], [np.sin(p), np.cos(p), 0], [0, 0, 1]])  # pan about world z
    rx = np.array([[1, 0, 0], [0, np.cos(t), -np.sin(t)], [0, np.sin(t), np.cos(t)]])  # tilt about camera x
    rr = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1]])  # roll about camera z
    return rr @ rx @ base @ rz.T


@dataclass(frozen=True)
class Camera:
    """Calibration of a traffic camera: VP1, VP2, principal point (pixels) and scale λ (metres per plane unit)."""

    vp1: np.ndarray
    vp2: np.ndarray
    pp: np.ndarray
    scale: float | None = None
    _f: float = field(init=False, repr=False, compare=False)
    _n: np.ndarray = field(init=False, repr=False, compare=False)
    _R: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        vp1, vp2, pp = (_as_point(v, name) for v, name in ((self.vp1, "vp1"), (self.vp2, "vp2"), (self.pp, "pp")))
        if not (np.all(np.isfinite(vp1)) and np.all(np.isfinite(vp2)) and np.all(np.isfinite(pp))):
            raise GeometryError("vanishing points and principal point must be finite")
        if self.scale is not None and not (isinstance(self.scale, numbers.Real) and not isinstance(self.scale, bool)
                                           and np.isfinite(self.scale) and self.scale > 0):
            shown = self.scale if isinstance(self.scale, numbers.Real) else repr(self.scale)
            raise GeometryError(f"scale must be a positive number, got {shown}")
        dot = float(np.dot(vp1 - pp, vp2 - pp))
        if not dot < 0:
            raise GeometryError(
                "vanishing points give an imaginary focal length: VP1 and VP2 must lie on opposite sides of the "
                f"principal point ((vp1-pp)·(vp2-pp) = {dot:.6g} ≥ 0)")
        f = np.sqrt(-dot)
        w = np.cross(np.append(vp1 - pp, f), np.append(vp2 - pp, f))
        norm = np.linalg.norm(w)
        if not norm > 1e-12 * f * f:
            raise GeometryError("vanishing points give a degenerate road plane (VP1 and VP2 coincide)")
        n = w / norm
        if n[1] + n[2] > 0:  # make n point from the road towards the camera (upwards in the image)
            n = -n
        object.__setattr__(self, "vp1", vp1)
        object.__setattr__(self, "vp2", vp2)
        object.__setattr__(self, "pp", pp)
        object.__setattr__(self, "scale", None if self.scale is None else float(self.scale))
        object.__setattr__(self, "_f", float(f))
        object.__setattr__(self, "_n", n)
        u = np.append(vp1 - pp, f)
        d1 = u / np.linalg.norm(u)
        d1 = d1 - n * np.dot(d1, n)  # exact orthogonality despite rounding
        d1 /= np.linalg.norm(d1)
        R = np.stack([d1, np.cross(n, d1), n], axis=1)
        R.setflags(write=False)
        object.__setattr__(self, "_R", R)  # computed once: every projection to the world uses it

    # ----------------------------------------------------------------- derived quantities
    @property
    def focal(self) -> float:
        return self._f

    @property
    def normal(self) -> np.ndarray:
        """Unit road-plane normal in camera coordinates, pointing from the road to the camera."""
        return self._n.copy()

    @property
    def vp3(self) -> np.ndarray:
        """Vanishing point of the road normal (pixels; may be very far for a camera looking horizontally)."""
        n = self._n
        if abs(n[2]) < 1e-15:
            raise GeometryError("VP3 is at infinity (optical axis parallel to the road)")
        return self.pp + self._f * n[:2] / n[2]

    @property
    def horizon(self) -> np.ndarray:
        """Horizon as a homogeneous image line (a, b, c) with ‖(a, b)‖ = 1: a·x + b·y + c = 0."""
        return line_through(self.vp1, self.vp2)

    @property
    def K(self) -> np.ndarray:
        f = self._f
        return np.array([[f, 0.0, self.pp[0]], [0.0, f, self.pp[1]], [0.0, 0.0, 1.0]])

    @property
    def rotation(self) -> np.ndarray:
        """World→camera rotation (read-only): columns are world x (towards VP1, forward), y, z (up) in camera
        coordinates."""
        return self._R

    def rays(self, points) -> np.ndarray:
        """Camera-frame rays p̄ = [p - pp, f] of image points (..., 2) -> (..., 3)."""
        p = _as_points(points, "points")
        return np.concatenate([p - self.pp, np.full(p.shape[:-1] + (1,), self._f)], axis=-1)

    # ----------------------------------------------------------------- projections
    def to_road(self, points) -> np.ndarray:
        """Image points (..., 2) -> road-plane points (..., 3) in camera coordinates and plane units (δ = 1).

        Points on or above the horizon have no road point and give inf/NaN or a point behind the camera.
        """
        rays = self.rays(points)
        with np.errstate(divide="ignore", invalid="ignore"):
            return -rays / (rays @ self._n)[..., None]

    def from_road(self, points3d) -> np.ndarray:
        """Camera-frame 3D points (..., 3) -> image pixels (..., 2)."""
        P = np.asarray(points3d, dtype=np.float64)
        return self.pp + self._f * P[..., :2] / P[..., 2:3]

    def _require_scale(self) -> float:
        if self.scale is None:
            raise GeometryError("this calibration has no scale: distances in metres are unknown")
        return self.scale

    def distance(self, p1, p2) -> np.ndarray:
        """Road-plane distance in metres between image points p1 and p2 (..., 2)."""
        return self._require_scale() * np.linalg.norm(self.to_road(p1) - self.to_road(p2), axis=-1)

    def plane_distance(self, p1, p2) -> np.ndarray:
        """Road-plane distance in plane units (no scale needed)."""
        return np.linalg.norm(self.to_road(p1) - self.to_road(p2), axis=-1)

    # ----------------------------------------------------------------- world frame
    def to_KRt(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pinhole K, R, t (X_cam = R X_world + t) with the world frame described in the module docstring."""
        lam = self._require_scale()
        return self.K, self.rotation, -lam * self._n

    def to_world(self, points) -> np.ndarray:
        """Image points (..., 2) -> world coordinates in metres on the road plane (z = 0)."""
        lam = self._require_scale()
        cam = self.to_road(points) * lam
        world = (cam + lam * self._n) @ self.rotation
        world[..., 2] = 0.0 * world[..., 2]  # exactly on the plane (keeps NaN where the ray misses)
        return world

    def world_to_camera(self, X) -> np.ndarray:
        """World points in metres (..., 3) -> camera coordinates in metres."""
        lam = self._require_scale()
        return np.asarray(X, dtype=np.float64) @ self.rotation.T - lam * self._n

    def world_to_image(self, X) -> np.ndarray:
        """World points in metres (..., 3) -> image pixels (..., 2)."""
        return self.from_road(self.world_to_camera(X))

    @classmethod
    def from_KRt(cls, K, R, t, direction=None) -> "Camera":
        """From any pinhole camera looking at the world plane z = 0 (z up) with traffic along ``direction``.

        ``direction`` is a 2D direction in the world plane (default: world x).  K must have square pixels and
        no skew.  The scale is the camera height above the plane.
        """
        K = np.asarray(K, dtype=np.float64)
        R = np.asarray(R, dtype=np.float64)
        t = np.asarray(t, dtype=np.float64).reshape(3)
        if abs(K[0, 1]) > 1e-9 * K[0, 0] or abs(K[0, 0] - K[1, 1]) > 1e-9 * K[0, 0]:
            raise GeometryError("K must have zero skew and square pixels (fx == fy)")
        f, pp = K[0, 0], K[:2, 2]
        d = np.array([1.0, 0.0] if direction is None else direction, dtype=np.float64)
        if d.shape != (2,) or not np.all(np.isfinite(d)) or not np.linalg.norm(d) > 0:
            raise GeometryError(f"the traffic direction must be a 2D direction in the road plane (x, y, not both 0), "
                                f"got {np.asarray(direction).tolist()!r}")
        d = np.append(d / np.linalg.norm(d), 0.0)
        e = np.cross([0.0, 0.0, 1.0], d)
        vps = []
        for world_dir in (d, e):
            c = R @ world_dir
            if abs(c[2]) < 1e-12:
                raise GeometryError("a road direction is parallel to the image plane: its vanishing point is at "
                                    "infinity and the two-VP model cannot describe this camera")
            vps.append(pp + f * c[:2] / c[2])
        height = float((-R.T @ t)[2])
        if not height > 0:
            raise GeometryError(f"camera is not above the road plane (height {height:.6g})")
        return cls(vps[0], vps[1], pp, height)

    # ----------------------------------------------------------------- BrnoCompSpeed convention
    def _brno_offset(self) -> float:
        """|n_b·(pp, 0) + 10|: the camera's distance from BrnoCompSpeed's road plane, in its units."""
        n = self._n
        nb = n if n[2] > 0 else -n  # BrnoCompSpeed orients the normal towards VP3 seen in front of the camera
        return abs(float(np.dot(nb[:2], self.pp)) + BRNO_PLANE_OFFSET)

    @classmethod
    def from_brno(cls, vp1, vp2, pp, brno_scale: float | None) -> "Camera":
        """Camera from a BrnoCompSpeed ``camera_calibration`` block (its scale convention)."""
        cam = cls(vp1, vp2, pp)
        if brno_scale is None:
            return cam
        return cam.with_scale(float(brno_scale) * cam._brno_offset())

    def brno_scale(self) -> float:
        """The scale in BrnoCompSpeed's convention (metres per unit of its road-plane coordinates)."""
        return self._require_scale() / self._brno_offset()

    def with_scale(self, scale: float | None) -> "Camera":
        return replace(self, scale=scale)

    def viewpoint(self, points) -> np.ndarray:
        """Unit viewing direction φ = −Rᵀ b̄ in the world frame for image points b (..., 2) (paper §4.3)."""
        rays = self.rays(points)
        rays = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
        return -rays @ self.rotation
