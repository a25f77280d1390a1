"""Boxes in the de-rolled image: the image turned about the principal point until the horizon is level.

BBScale compares the detector's axis-aligned box with the model's. Under a rolled camera a vehicle stands tilted in
the image, and an axis-aligned box of a tilted body takes its extent from the body's corners, which a segmenter's
soft outline rounds off: on the strong_roll preset (12° of roll) the boxes came out narrow and λ 4.6 % high, on the
same scene without roll −0.2 % (docs/bbscale_streaming.md, "Stop 39").  Turning the hull and the camera alike by
the horizon's tilt keeps the geometry (a rotation of the image plane about the principal point is a rotation of the
camera about its optical axis) and lets the boxes be taken where the vehicles stand upright.  Only for a
segmentation's outlines (the case measured); a rectangle detector's box, or a background model's hull, is aligned as
it is.
"""

from __future__ import annotations

import math

import numpy as np

from ..geometry import Camera

MIN_TILT_DEG = 1.0
"""Below this tilt of the horizon the boxes are the image's own (the paper's): a degree turns a box's width by
less than a pixel."""


def horizon_tilt(cam: Camera) -> float:
    """The horizon's angle to the image rows (radians, in (−π/2, π/2]; positive clockwise on screen, y down)."""
    d = np.asarray(cam.vp2, np.float64) - np.asarray(cam.vp1, np.float64)
    a = math.atan2(float(d[1]), float(d[0]))
    return (a + math.pi / 2) % math.pi - math.pi / 2


def derolled_points(points, pp, angle: float) -> np.ndarray:
    """Pixel points (N, 2) turned by −``angle`` about ``pp`` (the horizon of that tilt becomes level)."""
    c, s = math.cos(angle), math.sin(angle)
    p = np.asarray(points, np.float64).reshape(-1, 2) - np.asarray(pp, np.float64)
    return np.stack([c * p[:, 0] + s * p[:, 1], -s * p[:, 0] + c * p[:, 1]], axis=1) + np.asarray(pp, np.float64)


def derolled_camera(cam: Camera, angle: float) -> Camera:
    """The same camera turned about its optical axis so that its image is :func:`derolled_points` of ``cam``'s."""
    vp1, vp2 = derolled_points(np.stack([cam.vp1, cam.vp2]), cam.pp, angle)
    return Camera(vp1, vp2, np.asarray(cam.pp, np.float64), cam.scale)


def derolled_box(hull, pp, angle: float) -> tuple[float, float, float, float]:
    """x0, y0, x1, y1 of a hull (K, 2 pixels) in the image turned by −``angle`` about ``pp``."""
    p = derolled_points(hull, pp, angle)
    return float(p[:, 0].min()), float(p[:, 1].min()), float(p[:, 0].max()), float(p[:, 1].max())


def tilt_to_use(cam: Camera | None) -> float | None:
    """The horizon's tilt when it is large enough for de-rolled boxes (:data:`MIN_TILT_DEG`), else None."""
    if cam is None:
        return None
    a = horizon_tilt(cam)
    return a if abs(math.degrees(a)) >= MIN_TILT_DEG else None


def derolled_fields(cam: Camera | None, hull, silhouette: bool) -> dict:
    """``derolled_box`` and ``roll`` of a sighting (the tracker's structure, the scale stage's :class:`Sighting`)
    when ``cam``'s horizon is tilted enough and ``hull`` is a segmentation's outline (``silhouette``, the case
    measured); else nothing."""
    tilt = tilt_to_use(cam) if hull is not None and silhouette else None
    return {} if tilt is None else {"derolled_box": derolled_box(hull, cam.pp, tilt), "roll": tilt}
