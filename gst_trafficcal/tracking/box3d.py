"""3D bounding boxes of vehicles from their image convex hulls and the three vanishing points.

Dubská et al. (BMVC 2014) build the box from the tangent lines that the three vanishing points send to the
blob's convex hull: two from VP1 (along the road), two from VP2 (across the road) and two from VP3 (the road
normal).  We solve the same construction in the road's own frame, which makes it exact, vectorised over
vehicles and free of the case analysis over VP positions (both traffic directions, cameras left or right of the
road, VPs near infinity):

* World frame in *plane units* (the camera is 1 unit above the road, see :mod:`gst_trafficcal.geometry`):
  x towards VP1, y across the road, z up, camera at (0, 0, 1).
* A tangent line from VP1 is the image of a plane that contains the camera centre and the x direction, so it
  is a ray from the camera's (y, z) = (0, 1) in the y-z cross-section; the box's cross-section is the
  rectangle [y0, y1] x [0, h].  Likewise VP2 gives rays in the x-z section from (0, 1) and VP3 gives rays in
  the top view (x-y) from the camera foot (0, 0).
* The hull point with the extreme angle in each section gives the tangent ray; the rectangle corner it touches
  follows from the signs of the ray direction alone, and "corner on ray" is linear in the five unknowns
  (x0, x1, y0, y1, h).  Six equations, five unknowns: as in Dubská's construction the box touches five
  tangents, and the sixth must lie inside its silhouette (the box encloses the hull); of the six candidates the
  smallest admissible box wins.  All vehicles are solved at once (batched 5x5 systems).  A true box is recovered
  exactly; for a real vehicle (a cabin narrower than the body) the box keeps the footprint from the ground and
  vertical tangents and takes its height from the top ones, which is what the reference point needs.
"""

from __future__ import annotations

import warnings
from collections import deque
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Sequence

import numpy as np

from ..geometry import Camera
from .shapes import BodyShape, box_shape, default_shapes

#: order of the 8 corners: index = ix + 2*iy + 4*iz with ix -> (x0, x1), iy -> (y0, y1), iz -> (0, h)
CORNER_BITS = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)])

#: a box's image corners may lie this share of its hull's box size outside that box (see :func:`corners_fit_hulls`)
BOX_FIT_TOLERANCE = 1.0

#: the 12 edges as pairs of corner indices (for drawing)
EDGES = np.array([(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1])

# (world axes of the section: u, v), (unknown index of u lo/hi, of v lo/hi; -1 = the constant 0), camera point
_SECTIONS = (
    ((1, 2), ((2, 3), (-1, 4)), (0.0, 1.0)),  # VP1 tangents: y-z section
    ((0, 2), ((0, 1), (-1, 4)), (0.0, 1.0)),  # VP2 tangents: x-z section
    ((0, 1), ((0, 1), (2, 3)), (0.0, 0.0)),  # VP3 tangents: top view
)


@dataclass
class Boxes3D:
    """3D boxes of N vehicles.

    ``params`` (N, 5) = x0, x1, y0, y1, h in plane units of the world frame; ``corners_world`` (N, 8, 3) plane
    units; ``corners_px`` (N, 8, 2) image pixels (order :data:`CORNER_BITS`); ``valid`` (N,) False where the
    hull gave no box (points above the horizon, camera over the vehicle, degenerate solve); ``residual`` (N,)
    how far (an angle in radians) the one tangent the box does not touch lies inside its silhouette: 0 for a
    perfect box, larger for shapes far from a box.
    """

    params: np.ndarray
    corners_world: np.ndarray
    corners_px: np.ndarray
    valid: np.ndarray
    residual: np.ndarray

    def __len__(self) -> int:
        return len(self.params)

    def reference_points(self, camera: Camera, direction: np.ndarray | float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """Centre of the bottom-front edge: (world plane units (N, 2) x, y; pixels (N, 2)).

        ``direction`` is +1 for vehicles moving towards VP1 (front at x1) and -1 for the opposite traffic
        direction (front at x0).
        """
        direction = np.broadcast_to(np.asarray(direction, np.float64), (len(self),))
        x = np.where(direction >= 0, self.params[:, 1], self.params[:, 0])
        y = 0.5 * (self.params[:, 2] + self.params[:, 3])
        road = np.stack([x, y], axis=1)
        return road, world_to_pixels(camera, np.concatenate([road, np.zeros((len(self), 1))], axis=1))


def world_rays(camera: Camera, points: np.ndarray) -> np.ndarray:
    """Image points (..., 2) -> directions of their viewing rays in the world frame (..., 3)."""
    return camera.rays(points) @ camera.rotation


def world_to_pixels(camera: Camera, X: np.ndarray) -> np.ndarray:
    """World points in plane units (..., 3) -> pixels (camera at (0, 0, 1))."""
    cam = np.asarray(X, np.float64) @ camera.rotation.T - camera.normal
    return camera.from_road(cam)


def pixels_to_road(camera: Camera, points: np.ndarray) -> np.ndarray:
    """Image points (..., 2) on the road -> world road-plane coordinates (..., 2) in plane units (x along VP1)."""
    w = world_rays(camera, points)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -1.0 / w[..., 2]
    return w[..., :2] * s[..., None]


def box_heights(camera: Camera, corners_px: np.ndarray) -> np.ndarray:
    """Heights (N,) in plane units of 3D boxes given by their image corners (N, 8, 2; order :data:`CORNER_BITS`):
    per vertical edge the point of the top corner's viewing ray nearest the vertical through the bottom corner's
    road point (camera at (0, 0, 1)), the median over the four edges (the image keeps no box parameters)."""
    c = np.asarray(corners_px, np.float64).reshape(-1, 8, 2)
    bottom = pixels_to_road(camera, c[:, :4])  # (N, 4, 2) road points of the bottom corners
    w = world_rays(camera, c[:, 4:])  # (N, 4, 3) rays through the top corners (same x, y bits + 4)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.sum(bottom * w[..., :2], axis=-1) / np.sum(w[..., :2] ** 2, axis=-1)
        return np.nanmedian(1.0 + s * w[..., 2], axis=1) if len(c) else np.zeros(0)


def _pad_hulls(hulls: Sequence[np.ndarray]) -> np.ndarray:
    """List of (K_i, 2) hulls -> (N, K, 2), padded by repeating each hull's first point."""
    k = max(len(h) for h in hulls)
    out = np.empty((len(hulls), k, 2), np.float64)
    for i, h in enumerate(hulls):
        h = np.asarray(h, np.float64).reshape(-1, 2)
        out[i, : len(h)] = h
        out[i, len(h):] = h[0]
    return out


def _tangents(camera: Camera, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The six tangent rays of each hull (N, K, 2 pixels): their directions (N, 6, 2) in the sections of
    :data:`_SECTIONS` (two per section, the one with the smaller angle first) and whether every hull point lies
    below the horizon and the hull spans less than a half-turn in every section (N,)."""
    n = len(pts)
    W = world_rays(camera, pts)  # (N, K, 3)
    valid = np.all(W[..., 2] < -1e-9, axis=1)  # every hull point below the horizon
    dirs = np.zeros((n, 6, 2))
    for s, ((iu, iv), _, _) in enumerate(_SECTIONS):
        D = W[..., [iu, iv]]
        D = D / np.linalg.norm(D, axis=-1, keepdims=True)
        m = D.mean(axis=1, keepdims=True)
        ang = np.arctan2(m[..., 0] * D[..., 1] - m[..., 1] * D[..., 0], np.sum(m * D, axis=-1))
        valid &= (ang.max(axis=1) - ang.min(axis=1)) < np.pi - 1e-3
        dirs[:, 2 * s] = D[np.arange(n), ang.argmin(axis=1)]
        dirs[:, 2 * s + 1] = D[np.arange(n), ang.argmax(axis=1)]
    return dirs, valid


def _corner_equations(dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dubská's equations: each tangent ray touches the box corner that the signs of its direction select.
    Returns A (N, 6, 5), b (N, 6) and the touched corner's unknown indices (N, 6, 2; -1 = the constant 0)."""
    n = len(dirs)
    A = np.zeros((n, 6, 5))
    b = np.zeros((n, 6))
    sel = np.zeros((n, 6, 2), np.int64)
    for s, (_, ((ulo, uhi), (vlo, vhi)), (qu, qv)) in enumerate(_SECTIONS):
        for row in (2 * s, 2 * s + 1):
            d = dirs[:, row]
            sign = _SIGNS[row]
            # the rectangle lies on one side of the ray: the touched corner minimises sign*cross(d, c - q)
            cu = np.where(sign * d[:, 1] > 0, uhi, ulo)
            cv = np.where(sign * d[:, 0] > 0, vlo, vhi)
            # equation d_u * c_v - d_v * c_u = d_u * q_v - d_v * q_u
            np.add.at(A, (np.arange(n), row, cu), -d[:, 1])
            has_v = cv >= 0
            A[np.arange(n)[has_v], row, cv[has_v]] += d[has_v, 0]
            b[:, row] = d[:, 0] * qv - d[:, 1] * qu
            sel[:, row] = np.stack([cu, cv], axis=1)
    return A, b, sel


#: per tangent row: the unknowns of its touched point (u_lo, u_hi, v_lo, v_hi; 5 = the constant 0) and the
#: section's camera point
_ROW_COLS = np.array([[ulo, uhi, vlo if vlo >= 0 else 5, vhi] for _, ((ulo, uhi), (vlo, vhi)), _ in _SECTIONS
                      for _ in range(2)])
_ROW_Q = np.array([q for *_, q in _SECTIONS for _ in range(2)], np.float64)


def _shape_equations(dirs: np.ndarray, theta: np.ndarray, sections: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The equations with body shapes scaled to the boxes ``theta`` (N, 5): each tangent ray touches the
    shape's point extreme along the ray's normal, at unit coordinates (a, c) of its section, i.e. at
    ((1 - a) u_lo + a u_hi, (1 - c) v_lo + c v_hi), still linear in the unknowns.  ``sections``: the shape
    points of each tangent row's section, (N or 1, 6, K, 2).  Returns A (N, 6, 5), b (N, 6) and the distance of
    each touched point from its section's camera point (N, 6), the equations' natural weight."""
    n = len(dirs)
    th = np.concatenate([theta, np.zeros((n, 1))], axis=1)[:, _ROW_COLS]  # (N, 6, 4)
    P = np.broadcast_to(sections, (n, *sections.shape[1:]))  # (N, 6, K, 2)
    cu = th[..., :1] + P[..., 0] * (th[..., 1:2] - th[..., :1])  # (N, 6, K) touched-point candidates
    cv = th[..., 2:3] + P[..., 1] * (th[..., 3:4] - th[..., 2:3])
    du, dv = dirs[..., :1], dirs[..., 1:]  # (N, 6, 1)
    qu, qv = _ROW_Q[:, :1], _ROW_Q[:, 1:]
    k = (_SIGNS[:, None] * (du * (cv - qv) - dv * (cu - qu))).argmin(axis=2)[..., None]  # (N, 6, 1)
    a = np.take_along_axis(P[..., 0], k, axis=2)[..., 0]
    c = np.take_along_axis(P[..., 1], k, axis=2)[..., 0]
    du, dv = du[..., 0], dv[..., 0]
    A = np.zeros((n, 6, 6))
    vals = np.stack([-dv * (1 - a), -dv * a, du * (1 - c), du * c], axis=2)  # (N, 6, 4), distinct columns
    A[np.arange(n)[:, None, None], np.arange(6)[None, :, None], _ROW_COLS[None]] = vals
    b = du * _ROW_Q[:, 1] - dv * _ROW_Q[:, 0]
    rng = np.hypot(np.take_along_axis(cu, k, axis=2)[..., 0] - _ROW_Q[:, 0],
                   np.take_along_axis(cv, k, axis=2)[..., 0] - _ROW_Q[:, 1])
    return A[..., :5], b, rng


def _shape_residual(A: np.ndarray, b: np.ndarray, rng: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """RMS angle (radians) by which the six tangents miss the touched points of the fitted body (N,)."""
    r = (np.einsum("nij,nj->ni", A, theta) - b) / np.maximum(rng, 1e-9)
    return np.sqrt(np.mean(r ** 2, axis=1))


@lru_cache(maxsize=8)
def _row_sections(shapes: tuple[BodyShape, ...]) -> np.ndarray:
    """Every shape's points of each tangent row's section, (S, 6, K, 2), padded by repeating the last point."""
    k = max(len(p) for sh in shapes for p in sh.sections)
    pad = [[np.concatenate([p, np.repeat(p[-1:], k - len(p), 0)]) for p in sh.sections] for sh in shapes]
    return np.stack([np.stack([sec[r // 2] for r in range(6)]) for sec in pad])


def _fit_shapes(dirs: np.ndarray, theta: np.ndarray, shapes: Sequence[BodyShape], valid: np.ndarray,
                iterations: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """For every (vehicle, shape) pair at once: the least-squares box whose scaled body touches the six tangents,
    started at ``theta`` (N, 5; the touched points depend on the box's proportions, so a few fixed-point rounds).
    Returns boxes (S, N, 5) and residuals (S, N)."""
    n, m = len(dirs), len(shapes)
    sections = np.repeat(_row_sections(tuple(shapes)), n, axis=0)  # (S*N, 6, K, 2)
    D = np.tile(dirs, (m, 1, 1))
    th = np.tile(theta, (m, 1))
    ok_rows = np.tile(valid, m)
    for _ in range(iterations):
        A, b, rng = _shape_equations(D, np.nan_to_num(th), sections)
        new = _weighted_solve(A, b, 1.0 / np.maximum(rng, 1e-6), ok_rows & np.all(np.isfinite(th), axis=1))
        with np.errstate(invalid="ignore"):
            ok = np.all(np.isfinite(new), axis=1) & (new[:, 1] > new[:, 0]) & (new[:, 3] > new[:, 2]) & (new[:, 4] > 0)
        th = np.where(ok[:, None], new, np.nan)
    A, b, rng = _shape_equations(D, np.nan_to_num(th), sections)
    res = np.where(np.all(np.isfinite(th), axis=1), _shape_residual(A, b, rng, th), np.inf)
    return th.reshape(m, n, 5), res.reshape(m, n)


def _is_rectangle(pts: np.ndarray) -> np.ndarray:
    """(N,) whether each hull (N, K, 2) is an axis-aligned rectangle: every point on two of its box's sides."""
    lo, hi = pts.min(axis=1, keepdims=True), pts.max(axis=1, keepdims=True)
    on = (np.isclose(pts, lo, atol=1e-6) | np.isclose(pts, hi, atol=1e-6)).all(axis=2)
    return on.all(axis=1)


@dataclass
class ShapeFits:
    """Every body shape fitted to every hull: ``params`` (S, N, 5) boxes (x0, x1, y0, y1, h, plane units; NaN
    where the shape was not fitted), ``fit`` (S, N) how far (RMS angle, radians) the six tangents miss the
    fitted body (inf where not fitted), ``names`` (S,) of the shapes (the plain box first when present), and the
    padded hulls (N, K, 2) and tangent validity (N,) the boxes are checked against."""

    params: np.ndarray
    fit: np.ndarray
    names: tuple[str, ...]
    pts: np.ndarray
    valid: np.ndarray
    kinds: tuple[str, ...] = ()  # (S,) each shape's kind ("box", "car", "long"; shapes.BodyShape.kind)

    def best(self) -> np.ndarray:
        """(N,) index of the shape that explains each hull's tangents best, of those its plain box's proportions
        allow (:func:`allowed_shapes`)."""
        ok = allowed_shapes(self.kinds, proportions_class(self.params[0]))
        return np.where(ok, self.fit, np.inf).argmin(axis=0)


def fit_shapes(camera: Camera, hulls: Sequence[np.ndarray] | np.ndarray,
               shapes: Sequence[BodyShape] | None = None) -> ShapeFits:
    """Fit the plain box (Dubská's construction) and each body shape to each convex hull (pixels).

    ``shapes`` defaults to the box and the catalogue's car and long-vehicle bodies
    (:func:`.shapes.default_shapes`); ``()`` is the plain box alone.  A hull that is an upright rectangle (a
    detector's box standing in for a missing outline) says nothing about the body and is fitted with the box only."""
    if isinstance(hulls, np.ndarray) and hulls.ndim == 3:
        pts = hulls.astype(np.float64)
    elif len(hulls) == 0:
        pts = np.zeros((0, 1, 2))
    else:
        pts = _pad_hulls(hulls)
    n = len(pts)
    shapes = default_shapes() if shapes is None else tuple(shapes)
    bodies = [s for s in shapes if not s.is_box]
    names, kinds = ("box", *(s.name for s in bodies)), ("box", *(s.kind for s in bodies))
    if n == 0:
        k = len(names)
        return ShapeFits(np.zeros((k, 0, 5)), np.zeros((k, 0)), names, pts, np.zeros(0, bool), kinds)
    dirs, valid = _tangents(camera, pts)
    A, b, sel = _corner_equations(dirs)
    theta, _ = _tightest_box(A, b, sel, valid)
    start = np.where(np.all(np.isfinite(theta), axis=1)[:, None], theta, np.nan)
    box_fit = _shape_residual(*_shape_equations(dirs, np.nan_to_num(start), _row_sections((box_shape(),))), start)
    params, fit = [theta], [np.where(np.isfinite(box_fit), box_fit, np.inf)]
    if bodies:
        ok = ~_is_rectangle(pts)
        ths, fits = _fit_shapes(dirs, np.where(ok[:, None], start, np.nan), bodies, valid)
        params += list(ths)
        fit += list(np.where(ok[None], fits, np.inf))
    return ShapeFits(np.stack(params), np.stack(fit), names, pts, valid, kinds)


#: the plain box's proportions (length / width, height / width) that tell which body shapes a vehicle may hold:
#: the catalogue's car styles are 2.2-2.8 and 0.8-0.95, a van about 2.6 and 1.15; a rigid truck 3.8 and 1.4, an
#: articulated one 6.4 and 1.55, a bus 4.7 and 1.2 (longer than LONG); a motorcycle with its rider 2.7 and 1.9
#: and a tall van up to 1.5 (neither: the plain box only)
LONG, TALL = 3.5, 1.2

#: a truck or a bus stands 3-4 m tall, a car 1.4-1.7 m, a van up to 2.5 m: a box is "long" only when it is also
#: at least TALLER times as tall as the scene's typical vehicle (:class:`TypicalHeight`).  Where the vanishing
#: directions meet at a narrow angle (a low camera looking along the road, its far lane) the plain box of a
#: rounded car comes out 1.5-3x too long for its width, but its height stays the cars' (measured over ten
#: catalogue renders and two with semitrailers: cars classed long 0.9-1.45x the typical height, trucks and
#: buses 2.0-2.9x; docs/tracking.md)
TALLER = 1.6


@dataclass
class TypicalHeight:
    """The scene's typical vehicle height, plane units: the median of the plain-box heights of the last ``size``
    vehicles (each the median over the fits that chose its shape), once ``least`` are known (else None).  Most
    traffic is cars, so it is a car's height; a road of trucks alone makes it a truck's, and then no vehicle is
    taller: the bodies fall back to the cars' (the box always stays allowed)."""

    size: int = 200
    least: int = 5
    heights: deque = field(default_factory=deque, repr=False)

    def __post_init__(self) -> None:
        self.heights = deque(self.heights, maxlen=self.size)

    def add(self, height: float | None) -> None:
        if height is not None and np.isfinite(height) and height > 0:
            self.heights.append(float(height))

    def clear(self) -> None:
        self.heights.clear()

    @property
    def value(self) -> float | None:
        return self.value_with(())

    def value_with(self, provisional: Sequence[float]) -> float | None:
        """The value counting also the ``provisional`` heights of vehicles not yet chosen (the scene's first
        vehicles: those in view stand in for the ones to come)."""
        h = list(self.heights) + [v for v in provisional if np.isfinite(v) and v > 0]
        return float(np.median(h)) if len(h) >= self.least else None


def proportions_class(boxes: np.ndarray, typical_height: float | None = None) -> np.ndarray:
    """Per vehicle, from its plain boxes ``boxes`` (..., 5: x0, x1, y0, y1, h; medians over the leading axis
    when 3-D, i.e. (M, N, 5) for M boxes of N vehicles): "long" (a truck, a bus), "car", "stretched" or "other"
    (N,).  With the scene's ``typical_height`` (plane units) a long box must also be :data:`TALLER` than it, else
    it is "stretched": a car's whose box came out long (its width short: its height / width is not judged either;
    it may hold the car bodies, but its outline is no evidence for the scale)."""
    b = np.asarray(boxes, np.float64)
    b = b.reshape(1, -1, 5) if b.ndim < 3 else b
    width = np.abs(b[..., 3] - b[..., 2])
    with np.errstate(divide="ignore", invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns (no box): "other"
        length = np.nanmedian(np.abs(b[..., 1] - b[..., 0]) / width, axis=0)
        height = np.nanmedian(b[..., 4] / width, axis=0)
        tall = np.ones(length.shape, bool) if typical_height is None else \
            np.nanmedian(b[..., 4], axis=0) >= TALLER * typical_height
    car = (length <= LONG) & (height <= TALL)
    stretched = (length > LONG) & ~tall  # a car whose box came out long: its height / width is off as well
    return np.where((length > LONG) & tall, "long", np.where(car, "car", np.where(stretched, "stretched", "other")))


def track_class(boxes: np.ndarray, typical_height: float | None = None) -> str:
    """:func:`proportions_class` of one track from its plain boxes ``boxes`` (N, 5) (medians over them)."""
    return str(proportions_class(np.asarray(boxes, np.float64).reshape(-1, 1, 5), typical_height)[0])


def allowed_shapes(kinds: Sequence[str], classes: np.ndarray) -> np.ndarray:
    """(S, N) which of the shapes of ``kinds`` (S,) each vehicle of ``classes`` (N,) may hold: the box, and a car
    the car bodies, a long vehicle the truck and bus bodies.  The misfit alone cannot choose among all of them: a
    sedan's sloped ends explain a truck's silhouette best of all (measured on the synth trucks) and put its front
    metres ahead of the cab."""
    k = np.asarray(kinds)[:, None]
    c = np.asarray(classes)[None, :]
    return (k == "box") | ((k == "car") & ((c == "car") | (c == "stretched"))) | ((k == "long") & (c == "long"))


def track_choice(fit: np.ndarray, kinds: Sequence[str], vehicle_class: str) -> int:
    """The one body shape for all of a track's silhouettes: of the shapes its class allows (``vehicle_class``,
    :func:`track_class` of its plain boxes; :func:`allowed_shapes`; ``kinds`` (S,) of the fitted shapes), the
    least summed misfit over its fits ``fit`` (N, S), each capped at 1 radian so that one bad outline cannot
    decide (0 = the box, also for no fits)."""
    fit = np.asarray(fit, np.float64)
    if not fit.size:
        return 0
    allowed = allowed_shapes(kinds[:fit.shape[1]], np.array([vehicle_class]))[:, 0]
    total = np.where(allowed, np.sum(np.minimum(fit, 1.0), axis=0), np.inf)
    return int(np.argmin(total)) if np.isfinite(total).any() else 0


def boxes_from_fits(camera: Camera, fits: ShapeFits, choice: np.ndarray | None = None) -> Boxes3D:
    """The boxes of the chosen shape per hull (``choice`` (N,) shape indices; default: each hull's best)."""
    n = fits.pts.shape[0]
    k = fits.best() if choice is None else np.asarray(choice, np.int64).reshape(n)
    theta = fits.params[k, np.arange(n)] if n else np.zeros((0, 5))
    resid = fits.fit[k, np.arange(n)] if n else np.zeros(0)
    return _boxes(camera, theta, fits.valid.copy(), fits.pts, resid)


def boxes_from_hulls(camera: Camera, hulls: Sequence[np.ndarray] | np.ndarray,
                     shapes: Sequence[BodyShape] | None = None) -> Boxes3D:
    """3D boxes standing on the road whose silhouettes are tangent to the given convex hulls (pixels).

    ``hulls`` is a list of (K_i, 2) point arrays (any points of the blob work; only the extreme ones matter) or
    an (N, K, 2) array.  ``shapes`` (default: the box and the catalogue's car bodies, :func:`.shapes.default_shapes`)
    are the bodies the box may hold: per vehicle, the one that explains its six tangents best gives the box (an
    exact box silhouette keeps the plain box, exactly); ``()`` is Dubská's plain construction.
    """
    if not isinstance(hulls, np.ndarray) and len(hulls) == 0:
        z = np.zeros((0,))
        return Boxes3D(np.zeros((0, 5)), np.zeros((0, 8, 3)), np.zeros((0, 8, 2)), z.astype(bool), z)
    return boxes_from_fits(camera, fit_shapes(camera, hulls, shapes))


def _boxes(camera: Camera, theta: np.ndarray, valid: np.ndarray, pts: np.ndarray, resid: np.ndarray) -> Boxes3D:
    """Corners, pixels and validity of boxes ``theta`` (N, 5) fitted to the padded hulls ``pts``."""
    n = len(theta)
    x0, x1, y0, y1, h = theta.T
    with np.errstate(invalid="ignore"):
        valid &= np.all(np.isfinite(theta), axis=1) & (x1 > x0) & (y1 > y0) & (h > 0) & (h < 1)
    lo = theta[:, [0, 2]]
    hi = theta[:, [1, 3]]
    corners = np.empty((n, 8, 3))
    corners[..., 0] = np.where(CORNER_BITS[:, 0] == 1, hi[:, None, 0], lo[:, None, 0])
    corners[..., 1] = np.where(CORNER_BITS[:, 1] == 1, hi[:, None, 1], lo[:, None, 1])
    corners[..., 2] = CORNER_BITS[:, 2] * h[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        px = world_to_pixels(camera, corners)
    valid &= corners_fit_hulls(px, pts.min(axis=1), pts.max(axis=1))
    return Boxes3D(theta, corners, px, valid, np.where(valid, resid, np.inf))


def corners_fit_hulls(corners_px: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                      tolerance: float = BOX_FIT_TOLERANCE) -> np.ndarray:
    """(N,) whether each box's image corners (N, 8, 2) lie within its hull's bounding box (corners ``lo``, ``hi``,
    (N, 2) each) widened by ``tolerance`` of that box's size on each side.  A box tangent to the hull projects to about the hull's box (a little larger: a box
    is fuller than a rounded vehicle); a degenerate solve, e.g. on a rectangle seen almost along the road with
    VP2 far away, puts its base at the camera's foot, far outside the image, and its reference point would give
    an absurd speed."""
    corners_px, lo, hi = (np.asarray(a, np.float64) for a in (corners_px, lo, hi))
    margin = tolerance * np.maximum(hi - lo, 1.0) + 1.0
    with np.errstate(invalid="ignore"):
        inside = (corners_px >= (lo - margin)[:, None]) & (corners_px <= (hi + margin)[:, None])
    return np.all(inside, axis=(1, 2))


_SIGNS = np.array([1.0, -1.0, 1.0, -1.0, 1.0, -1.0])
_Q = np.array([[0, 1], [0, 1], [0, 1], [0, 1], [0, 0], [0, 0]], np.float64)  # camera point of each row


def _tightest_box(A: np.ndarray, b: np.ndarray, sel: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The smallest box that touches five of the six tangents and encloses the sixth (Dubská's construction).

    Each candidate drops one tangent; a candidate is admissible when the dropped tangent still lies inside the
    box's silhouette (the box encloses the hull).  Candidates that drop a tangent touching the box's top are
    preferred (a cabin narrower than the body leaves the top tangents slack while the ground and vertical
    tangents touch the body), then the smallest volume.  For a perfect box all six candidates coincide.  Returns the
    parameters (N, 5) and the disagreement of the dropped tangent (angle, radians) as a fit residual.
    """
    n = len(A)
    rows = np.array([[j for j in range(6) if j != k] for k in range(6)])  # (6, 5): rows kept by candidate k
    A5 = A[:, rows]  # (N, 6, 5, 5)
    b5 = b[:, rows]  # (N, 6, 5)
    with np.errstate(invalid="ignore", over="ignore"):
        scale = np.abs(A5).max(axis=(2, 3), keepdims=True)
        det = np.linalg.det(A5 / np.maximum(scale, 1e-300))
    ok = valid[:, None] & (np.abs(det) > 1e-12)
    theta = np.full((n, 6, 5), np.nan)
    if ok.any():
        theta[ok] = np.linalg.solve(A5[ok], b5[ok][..., None])[..., 0]
    k6 = np.arange(6)
    viol = _SIGNS * (np.einsum("nkj,nkj->nk", A, theta) - b)  # dropped row k evaluated at candidate k
    vals = np.concatenate([theta, np.zeros((n, 6, 1))], axis=2)  # index -1 (the constant 0) -> column 5
    cu = np.take_along_axis(vals, np.where(sel[:, :, 0] < 0, 5, sel[:, :, 0])[..., None], axis=2)[..., 0]
    cv = np.take_along_axis(vals, np.where(sel[:, :, 1] < 0, 5, sel[:, :, 1])[..., None], axis=2)[..., 0]
    q = _Q[k6]
    rng = np.hypot(cu - q[:, 0], cv - q[:, 1])
    x0, x1, y0, y1, h = np.moveaxis(theta, 2, 0)
    with np.errstate(invalid="ignore"):
        # h < 1 (below the camera): the degenerate box of no extent at the camera's foot reaching up to the camera
        # is admissible for every hull and has the smallest volume (zero), but is no vehicle
        admissible = (ok & np.isfinite(viol) & (viol / np.maximum(rng, 1e-9) <= 1e-7) & (x1 > x0) & (y1 > y0)
                      & (h > 0) & (h < 1 - 1e-6))
        vol = (x1 - x0) * (y1 - y0) * h
    # prefer dropping a tangent that touches the roof: a vehicle is box-like near the road, not on top
    vol = np.where(sel[:, :, 1] == 4, vol, vol * 1e6)
    vol = np.where(admissible, vol, np.inf)
    pick = vol.argmin(axis=1)
    best_vol = vol[np.arange(n), pick]
    best = theta[np.arange(n), pick]
    best_res = -viol[np.arange(n), pick] / np.maximum(rng[np.arange(n), pick], 1e-9)
    best_res = np.where(np.isfinite(best_vol), best_res, np.inf)
    none = ~np.isfinite(best_vol) & valid
    if none.any():  # no admissible candidate (numerical corner cases): weighted least squares over all six
        An, bn, sn = A[none], b[none], sel[none]
        fb = _weighted_solve(An, bn, np.ones((len(An), 6)), valid[none])
        for _ in range(2):
            fb = _weighted_solve(An, bn, 1.0 / np.maximum(_corner_ranges(fb, sn), 1e-6), valid[none])
        best[none] = fb
        r = (np.einsum("nij,nj->ni", An, fb) - bn) / _corner_ranges(fb, sn)
        best_res[none] = np.sqrt(np.mean(r ** 2, axis=1))
    return best, best_res


def _weighted_solve(A: np.ndarray, b: np.ndarray, w: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Batched weighted least squares (exact solve for square systems); NaN where singular or invalid."""
    Aw = A * w[..., None]
    bw = b * w
    AtA = np.einsum("nki,nkj->nij", Aw, Aw)
    Atb = np.einsum("nki,nk->ni", Aw, bw)
    with np.errstate(invalid="ignore", over="ignore"):
        scale = np.einsum("nii->n", AtA) / 5
        ok = valid & (np.abs(np.linalg.det(AtA / np.maximum(scale, 1e-300)[:, None, None])) > 1e-12)
    theta = np.full((len(A), 5), np.nan)
    if ok.any():
        theta[ok] = np.linalg.solve(AtA[ok], Atb[ok][..., None])[..., 0]
    return theta


def _corner_ranges(theta: np.ndarray, sel: np.ndarray) -> np.ndarray:
    """Distance from the section's camera point to the touched corner of each constraint (N, 6)."""
    vals = np.concatenate([theta, np.zeros((len(theta), 1))], axis=1)  # index -1 -> 0
    c = np.take_along_axis(vals[:, None, :], np.where(sel < 0, 5, sel).reshape(len(theta), 12)[:, None, :],
                           axis=2).reshape(len(theta), 6, 2)
    q = np.array([[0, 1], [0, 1], [0, 1], [0, 1], [0, 0], [0, 0]], np.float64)
    r = np.linalg.norm(c - q, axis=-1)
    return np.where(np.isfinite(r), r, 1.0)


def box_from_hull(camera: Camera, hull: np.ndarray) -> Boxes3D:
    """Convenience: the 3D box of one hull (a :class:`Boxes3D` of length 1)."""
    return boxes_from_hulls(camera, [np.asarray(hull, np.float64).reshape(-1, 2)])
