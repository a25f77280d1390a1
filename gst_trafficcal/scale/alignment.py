"""Alignment of a 3D vehicle model with one detected vehicle at many candidate scene scales (paper §4.3).

What "scale" means here.  Our road plane is ``n·X + 1 = 0`` in camera coordinates (plane units, the camera one
unit above the road) and the scene scale λ is metres per plane unit (= the camera height in metres).  A model
measured in metres placed in a scene of scale λ is therefore the model scaled by 1/λ, standing on the road
plane with the centre of its base on the road point B under the image point b, its length along the road
direction (world x, towards VP1, or the opposite for the other traffic direction).  The camera sees it from the
paper's viewpoint φ = −Rᵀ b̄ (R = [ū, v̄, w̄] normalised): placing the model in 3D and projecting it through
the camera *is* rendering it at that viewpoint, with the perspective of the real lens rather than an affine
approximation.  The front and rear base points F, R of the placed model lie on the road plane l/λ units apart,
so λ_ij = l / ‖F_ij − R_ij‖ (computed here through the image, as the paper does) returns the candidate λ_j:
the search over scales is a search over λ itself.

Only the model's image bounding box enters the IoU, so the exact shortcut projects the mesh vertices (its convex
hull suffices) and takes their bounding box, vectorised over all candidate scales; :mod:`.silhouette` renders
the silhouette with moderngl instead and gives the same boxes within a pixel.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import lru_cache

import numpy as np

from ..errors import GeometryError, InputError
from ..geometry import Camera
from ..vehicles.catalogue import VehicleModel
from ..vehicles.mesh import VehicleMesh, mesh_for


@dataclass(frozen=True)
class AlignModel:
    """A vehicle type prepared for alignment: its real length (metres), the points whose image bounding box is
    the model's (convex-hull vertices of the mesh, metres, vehicle frame x forward / y left / z up, origin at
    the centre of the base) and the full mesh (for rendering)."""

    name: str
    length: float
    hull: np.ndarray  # (K, 3) float64
    mesh: VehicleMesh = field(repr=False, compare=False)

    @property
    def front(self) -> np.ndarray:
        return np.array([self.length / 2, 0.0, 0.0])

    @property
    def rear(self) -> np.ndarray:
        return np.array([-self.length / 2, 0.0, 0.0])


def hull_vertices(vertices: np.ndarray) -> np.ndarray:
    """Vertices of the convex hull (the projected bounding box of a mesh is that of its hull's vertices)."""
    from scipy.spatial import ConvexHull, QhullError

    V = np.unique(np.asarray(vertices, np.float64), axis=0)
    try:
        return V[ConvexHull(V).vertices]
    except (QhullError, ValueError):  # flat or tiny meshes: every vertex
        return V


def align_model(model: VehicleModel, mesh: VehicleMesh | None = None) -> AlignModel:
    """The alignment model of a catalogue type (its mesh file or procedural mesh at its real dimensions)."""
    if mesh is None:
        mesh = _cached_mesh(model)
    return AlignModel(model.name, float(model.length), hull_vertices(mesh.vertices), mesh)


@lru_cache(maxsize=64)
def _cached_mesh(model: VehicleModel) -> VehicleMesh:
    return mesh_for(model, np.random.default_rng(0))


@dataclass(frozen=True)
class Observation:
    """One detected vehicle: ``box`` (x0, y0, x1, y1) pixels, ``base`` = centre b of the base of its 3D box in
    pixels (on the road), ``heading`` +1 when it moves towards VP1 (front towards VP1), -1 otherwise;
    ``track_id`` groups observations of one vehicle; ``type_probs`` maps type names to the classifier's (track
    mean) probabilities when a classifier is present."""

    box: tuple[float, float, float, float]
    base: tuple[float, float]
    heading: float = 1.0
    track_id: int = 0
    type_probs: dict | None = None
    body_shape: str = "box"  # the body the 3D box that gave b holds (tracking.shapes; "box" = the plain box)
    roll: float = 0.0  # radians: box and b are in the image turned by −roll about the principal point (scale.roll)


def heading_from_track(cam: Camera, points_px) -> float:
    """+1 when a track's road-plane points (pixels, in time order) move towards VP1 (world +x), else -1."""
    from ..tracking.box3d import pixels_to_road

    road = pixels_to_road(cam, np.asarray(points_px, np.float64).reshape(-1, 2))
    road = road[np.all(np.isfinite(road), axis=1)]
    if len(road) < 2:
        raise InputError("a heading needs at least two road points of the track")
    return 1.0 if road[-1, 0] >= road[0, 0] else -1.0


def vehicle_to_camera(cam: Camera, heading: float) -> np.ndarray:
    """3x3 rotation taking vehicle-frame vectors (x forward, y left, z up) into camera coordinates."""
    s = 1.0 if heading >= 0 else -1.0
    return cam.rotation * np.array([s, s, 1.0])


def base_point(cam: Camera, base_px) -> np.ndarray:
    """Road-plane point B (camera coordinates, plane units) under the image point b; GeometryError above the
    horizon."""
    B = cam.to_road(np.asarray(base_px, np.float64).reshape(2))
    if not (np.all(np.isfinite(B)) and B[2] > 0):
        raise GeometryError(f"base point {tuple(np.round(base_px, 1))} is not on the visible road (above the horizon)")
    return B


def projected_boxes(cam: Camera, points: np.ndarray, base_px, heading: float, lambdas: np.ndarray) -> np.ndarray:
    """Image bounding boxes (S, 4) = x0, y0, x1, y1 of model points (K, 3, metres) placed at b for each candidate
    scale λ (S,): X = B + M p / λ, projected through the camera.  NaN rows where a point falls behind the
    camera.  Each image axis is computed as one contiguous (S, K) plane and reduced along K (ten times faster than
    reducing an (S, K, 2) stack, with the same arithmetic)."""
    B = base_point(cam, base_px)
    A = np.asarray(points, np.float64) @ vehicle_to_camera(cam, heading).T  # (K, 3)
    inv = (1.0 / np.asarray(lambdas, np.float64))[:, None]
    z = B[2] + inv * A[:, 2]  # (S, K)
    boxes = np.empty((len(inv), 4))
    with np.errstate(divide="ignore", invalid="ignore"):
        for d in (0, 1):
            u = cam.focal * (B[d] + inv * A[:, d])
            u /= z
            u += cam.pp[d]
            boxes[:, d] = u.min(axis=1)
            boxes[:, d + 2] = u.max(axis=1)
    boxes[(z <= 1e-9).any(axis=1)] = np.nan
    return boxes


def box_iou(boxes: np.ndarray, box) -> np.ndarray:
    """IoU of boxes (..., 4) with one box (4,), all (x0, y0, x1, y1); NaN boxes give 0."""
    boxes = np.asarray(boxes, np.float64)
    b = np.asarray(box, np.float64)
    iw = np.minimum(boxes[..., 2], b[2]) - np.maximum(boxes[..., 0], b[0])
    ih = np.minimum(boxes[..., 3], b[3]) - np.maximum(boxes[..., 1], b[1])
    inter = np.clip(iw, 0, None) * np.clip(ih, 0, None)
    area = (boxes[..., 2] - boxes[..., 0]) * (boxes[..., 3] - boxes[..., 1])
    union = area + (b[2] - b[0]) * (b[3] - b[1]) - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        iou = inter / union
    return np.where(np.isfinite(iou), iou, 0.0)


def loose_iou(boxes: np.ndarray, box, loose=None) -> np.ndarray:
    """IoU of model boxes (S, 4) with the detected box when some edges of the detected box (x0, y0, x1, y1) are
    known to be biased one way: ``loose[k]`` = +1 means edge k counts only when it lies inside the model box (a
    cast or contact shadow can only extend a box, so on that side the box says how far the vehicle reaches at
    most), -1 only when it lies outside (a part the detector loses, e.g. a grey roof on a grey road, can only
    shrink it), 0 both ways.  ``loose`` None or all 0 is the plain IoU."""
    b = np.asarray(box, np.float64)
    if loose is None or not any(loose):
        return box_iou(boxes, b)
    boxes = np.asarray(boxes, np.float64)
    lo = np.sign(np.asarray(loose, np.float64))
    out = np.array([-1.0, -1.0, 1.0, 1.0])  # the outward direction of each edge
    m = np.where(np.isfinite(boxes), boxes, b)
    # the edge's signed excess beyond the model (outward positive); the free direction is clipped to zero
    excess = (b - m) * out
    excess = np.where(lo > 0, np.minimum(excess, 0.0), np.where(lo < 0, np.maximum(excess, 0.0), excess))
    d = m + excess * out
    iw = np.minimum(boxes[..., 2], d[..., 2]) - np.maximum(boxes[..., 0], d[..., 0])
    ih = np.minimum(boxes[..., 3], d[..., 3]) - np.maximum(boxes[..., 1], d[..., 1])
    inter = np.clip(iw, 0, None) * np.clip(ih, 0, None)
    area = (boxes[..., 2] - boxes[..., 0]) * (boxes[..., 3] - boxes[..., 1])
    union = area + (d[..., 2] - d[..., 0]) * (d[..., 3] - d[..., 1]) - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        iou = inter / union
    return np.where(np.isfinite(iou), iou, 0.0)


def lambdas_from_base_points(cam: Camera, model: AlignModel, base_px, heading: float,
                             lambdas: np.ndarray) -> np.ndarray:
    """λ_ij = l / ‖F_ij − R_ij‖: the placed model's front and rear base points projected into the image and back
    onto the road plane (as the paper does with the rendered model's points)."""
    B = base_point(cam, base_px)
    M = vehicle_to_camera(cam, heading)
    inv = 1.0 / np.asarray(lambdas, np.float64)
    ends = np.stack([B + inv[:, None] * (M @ model.front), B + inv[:, None] * (M @ model.rear)], axis=1)
    road = cam.to_road(cam.from_road(ends))  # (S, 2, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        return model.length / np.linalg.norm(road[:, 0] - road[:, 1], axis=-1)


@dataclass
class Alignment:
    """Result of aligning one model with one observation: candidate scales, their model boxes, IoUs, the λ_ij
    of each candidate and the viewpoint φ (unit, world frame, from the vehicle towards the camera)."""

    model: str
    lambdas: np.ndarray
    boxes: np.ndarray
    iou: np.ndarray
    lambda_ij: np.ndarray
    viewpoint: np.ndarray
    base: tuple[float, float] = (0.0, 0.0)

    @property
    def best(self) -> int:
        return int(np.argmax(self.iou))

    def kept(self, threshold: float) -> np.ndarray:
        return self.iou > threshold


def corrected_base(cam: Camera, model: AlignModel, obs: Observation, lam: float) -> tuple[float, float]:
    """The base point b corrected for the 3D-box construction: the tracker's b is the base centre of the box
    built from the vehicle's silhouette (:mod:`gst_trafficcal.tracking.box3d`), which for a car body (not a box)
    sits off the true centre of its base by an amount that depends on the viewpoint.  The model placed at b with
    scale λ shows that offset: build the same box from the model's projected hull, and move b back by the
    difference between that box's base centre and the model's own base centre (road-plane coordinates)."""
    from ..tracking.box3d import boxes_from_fits, fit_shapes, pixels_to_road, world_to_pixels

    X = base_point(cam, obs.base) + (model.hull @ vehicle_to_camera(cam, obs.heading).T) / float(lam)
    # the same construction as the tracker's: the plain box, or the body shape its track held
    fits = fit_shapes(cam, [cam.from_road(X)], () if obs.body_shape == "box" else None)
    k = fits.names.index(obs.body_shape) if obs.body_shape in fits.names else 0
    box = boxes_from_fits(cam, fits, np.array([k]))
    if not box.valid[0]:
        return tuple(float(v) for v in obs.base)
    x0, x1, y0, y1, _ = box.params[0]
    b_road = pixels_to_road(cam, np.asarray(obs.base, np.float64))
    shift = np.array([(x0 + x1) / 2, (y0 + y1) / 2]) - b_road
    if not np.all(np.isfinite(shift)):
        return tuple(float(v) for v in obs.base)
    px = world_to_pixels(cam, np.array([*(b_road - shift), 0.0]))
    return float(px[0]), float(px[1])


def fitted_base(cam: Camera, model: AlignModel, obs: Observation, lam: float) -> tuple[float, float]:
    """The base point b that makes the model's box fit the detected box best: a joint least-squares fit of b
    (pixels) and λ to the four box edges (three unknowns, four equations), started at the tracker's b and
    ``lam``.  The tracker's b comes from the 3D box of the vehicle's silhouette; for a car body that is not a box
    it sits off the model's base centre by up to a tenth of the car's length, which moves the model's box and
    costs IoU and λ (measured: the correct type on the exact 2D box gives λ 5-10 % off with the tracker's b,
    within 0.5 % with the fitted b).  Returns the tracker's b when the fit fails."""
    from scipy.optimize import least_squares

    box = np.asarray(obs.box, np.float64)
    h = max(float(box[3] - box[1]), 1.0)

    def residuals(p: np.ndarray) -> np.ndarray:
        try:
            b = projected_boxes(cam, model.hull, p[:2], obs.heading, np.exp(p[2:3]))[0]
        except GeometryError:
            return np.full(4, 10.0)
        r = (b - box) / h
        return np.where(np.isfinite(r), r, 10.0)

    x0 = np.array([float(obs.base[0]), float(obs.base[1]), np.log(float(lam))])
    try:
        sol = least_squares(residuals, x0, x_scale=np.array([h / 4, h / 4, 0.05]), diff_step=1e-4, max_nfev=200)
    except (ValueError, np.linalg.LinAlgError):
        return tuple(float(v) for v in obs.base)
    if not (np.all(np.isfinite(sol.x)) and np.hypot(*(sol.x[:2] - x0[:2])) < 2 * h):
        return tuple(float(v) for v in obs.base)
    return float(sol.x[0]), float(sol.x[1])


def coarse_lambdas(lo: float = 0.5, hi: float = 500.0, n: int = 160) -> np.ndarray:
    """Geometric grid of candidate scales (camera heights in metres) for the first pass."""
    return np.geomspace(lo, hi, n)


def candidate_lambdas(cam: Camera, model: AlignModel, obs: Observation, n: int = 121, span: float = 0.15,
                      renderer=None) -> np.ndarray:
    """Candidate scales for one observation: a coarse geometric sweep finds the scale of best IoU, then ``n``
    geometric steps cover ±``span`` (relative) around it — the range where IoU can exceed any useful threshold
    (a box 15 % too large or small has IoU ≤ 0.76)."""
    coarse = coarse_lambdas()
    boxes = projected_boxes(cam, model.hull, obs.base, obs.heading, coarse) if renderer is None else \
        renderer.boxes(cam, model, obs, coarse, coarse=True)
    iou = box_iou(boxes, obs.box)
    if not iou.max() > 0:
        return np.geomspace(coarse[0], coarse[-1], n)
    c = coarse[int(np.argmax(iou))]
    step = coarse[1] / coarse[0]
    return np.geomspace(c / (step * (1 + span)), c * step * (1 + span), n)


def align(cam: Camera, model: AlignModel, obs: Observation, lambdas: np.ndarray | None = None,
          renderer=None, refine_base: bool | str = False, loose=None) -> Alignment:
    """Model boxes and IoUs at candidate scales for one observation.  ``renderer`` = None uses the exact
    projection shortcut, else an object with ``boxes(cam, model, obs, lambdas)`` (e.g.
    :class:`.silhouette.SilhouetteRenderer`).  ``refine_base`` aligns once, moves b at the best scale and aligns
    again (``Alignment.base`` is the b used): True or "box3d" = b corrected for the 3D-box construction
    (:func:`corrected_base`), "fit" = b fitted jointly with λ to the box (:func:`fitted_base`); False = the
    tracker's b as is (the paper).  ``loose``: edges of the detected box that may extend beyond the model
    without penalty (:func:`loose_iou`)."""
    if refine_base:
        first = align(cam, model, obs, lambdas, renderer, loose=loose)
        if first.iou.max() > 0:
            move = fitted_base if refine_base == "fit" else corrected_base
            obs = replace(obs, base=move(cam, model, obs, first.lambdas[first.best]))
            try:
                return align(cam, model, obs, lambdas, renderer, loose=loose)
            except GeometryError:
                return first
        return first
    x0, y0, x1, y1 = (float(v) for v in obs.box)
    if not (x1 > x0 and y1 > y0):
        raise InputError(f"detected box {obs.box} is empty (need x0 < x1 and y0 < y1)")
    if lambdas is None:
        lambdas = candidate_lambdas(cam, model, obs, renderer=renderer)
    lambdas = np.asarray(lambdas, np.float64)
    boxes = projected_boxes(cam, model.hull, obs.base, obs.heading, lambdas) if renderer is None else \
        renderer.boxes(cam, model, obs, lambdas)
    iou = loose_iou(boxes, obs.box, loose)
    lam_ij = lambdas_from_base_points(cam, model, obs.base, obs.heading, lambdas)
    return Alignment(model.name, lambdas, boxes, iou, lam_ij, cam.viewpoint(np.asarray(obs.base, float)),
                     tuple(float(v) for v in obs.base))
