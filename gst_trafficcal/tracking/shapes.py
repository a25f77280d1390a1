"""Body shapes for the 3D box construction: the box touches the hull's tangents where a car body would.

Dubská's construction (:mod:`.box3d`) assumes that each of the six tangent lines touches a *corner* of the
vehicle's box.  A car is not a box: its bumpers are rounded and stand above the road, its wheels are set in from
the ends, its cabin is narrower and shorter than its body.  The tangents then touch the body somewhere inside the
box's faces, and the corner assumption moves the box: with the exact rendered silhouettes of the synth scenes the
reference point (centre of the bottom-front edge) lands 0.5-0.9 m off along the road, although a box-shaped
vehicle's is exact.

A :class:`BodyShape` is a body in *unit box coordinates* (x, y, z in [0, 1] from the box's low to its high
faces).  Scaled to a box ``(x0, x1, y0, y1, h)`` its point touched by a tangent is the one extreme along the
tangent's normal, and "that point on the tangent" stays linear in the five unknowns
(``(1 - a) x0 + a x1`` ...), so the same batched least-squares solve fits a car body to the six tangents.  The
shapes are the vehicle catalogue's passenger-car body styles and its trucks and bus at their mean dimensions (the
same meshes bbscale aligns), mirrored front/back and left/right because a frame does not tell which end is the
front; the plain box is one of them.  Per vehicle the shape that explains the six tangents best wins, among those
its plain box's proportions allow (:func:`.box3d.allowed_shapes`: car bodies for car-proportioned boxes, truck and
bus bodies for long ones) — by misfit alone a sedan's sloped ends explain a truck's silhouette best.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

#: (section axes u, v) of the three tangent pairs (VP1: y-z, VP2: x-z, VP3: x-y), as in box3d._SECTIONS
SECTION_AXES = ((1, 2), (0, 2), (0, 1))

#: the catalogue body styles (style, variant) used as car shapes by default
CAR_STYLES = (("sedan", "liftback"), ("sedan", "notchback"), ("estate", ""), ("hatchback", ""), ("suv", ""))
#: ... and as long-vehicle shapes: a truck's or bus's wheels are set in under an overhang (a semitrailer's rear
#: stands a metre above the road), so its box, too, is not where Dubská's corners put it
LONG_STYLES = (("truck", "rigid"), ("truck", "articulated"), ("bus", ""))


@dataclass(frozen=True, eq=False)
class BodyShape:
    """A body in unit box coordinates: for each tangent section, the vertices (K_s, 2) of the convex hull of
    the body's projection onto that section's plane (only they can touch a tangent)."""

    name: str
    sections: tuple[np.ndarray, np.ndarray, np.ndarray]
    kind: str = "car"  # "box", "car" or "long": which vehicles may hold it (box3d.proportions_class)

    @property
    def is_box(self) -> bool:
        return self.name == "box"


def _hull_2d(points: np.ndarray) -> np.ndarray:
    import cv2

    hull = cv2.convexHull(np.asarray(points, np.float32).reshape(-1, 1, 2)).reshape(-1, 2)
    return hull.astype(np.float64)


def shape_from_points(name: str, unit_points: np.ndarray, mirror: bool = True, kind: str = "car") -> BodyShape:
    """A body shape from points in unit box coordinates (N, 3); ``mirror`` adds the front/back and left/right
    mirror images (a frame does not tell the front)."""
    U = np.asarray(unit_points, np.float64).reshape(-1, 3)
    if mirror:
        U = np.concatenate([U, U * [-1, 1, 1] + [1, 0, 0], U * [1, -1, 1] + [0, 1, 0], U * [-1, -1, 1] + [1, 1, 0]])
    return BodyShape(name, tuple(_hull_2d(U[:, list(ax)]) for ax in SECTION_AXES), kind)


@lru_cache(maxsize=1)
def box_shape() -> BodyShape:
    """The plain box (Dubská's construction): its corners."""
    from .box3d import CORNER_BITS  # box3d imports this module: imported when first needed

    return shape_from_points("box", CORNER_BITS.astype(np.float64), mirror=False, kind="box")


def unit_coordinates(vertices: np.ndarray) -> np.ndarray:
    """Mesh vertices (N, 3) -> unit box coordinates of their bounding box."""
    V = np.asarray(vertices, np.float64).reshape(-1, 3)
    lo, hi = V.min(axis=0), V.max(axis=0)
    return (V - lo) / np.maximum(hi - lo, 1e-9)


@lru_cache(maxsize=1)
def default_shapes() -> tuple[BodyShape, ...]:
    """The box, the catalogue's passenger-car body styles and its long vehicles (procedural meshes at the styles'
    mean dimensions), in that order."""
    from ..vehicles.catalogue import VehicleModel, style_distributions
    from ..vehicles.mesh import mesh_for

    styles = style_distributions()
    shapes = [box_shape()]
    for kind, which in (("car", CAR_STYLES), ("long", LONG_STYLES)):
        for style, variant in which:
            dist = styles[style]
            own = dist.variants.get(variant, (0.0, None))[1] if variant else None
            L, W, H = (own or dist).mean
            ratio = (own or dist).wheelbase_ratio[0]
            model = VehicleModel(name=f"shape_{style}_{variant or 'default'}", body_style=style, length=L, width=W,
                                 height=H, wheelbase=ratio * L, variant=variant)
            mesh = mesh_for(model, np.random.default_rng(0))
            shapes.append(shape_from_points(f"{style}{'_' + variant if variant else ''}",
                                            unit_coordinates(mesh.vertices), kind=kind))
    return tuple(shapes)
