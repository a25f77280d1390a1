"""The earlier automatic scale of Dubská, Sochor, Herout (BMVC 2014), the paper's "BMVC14" baseline.

Each vehicle's tight 3D bounding box (built from its image convex hull and the vanishing points,
:mod:`gst_trafficcal.tracking.box3d`) is measured up to scale — length, width, height in plane units.  The
median of each dimension over all vehicles is matched with a known typical car size, giving three scales
λ_d = c_d / median(d); the scene scale is the smallest of the three (their Fig. 4).  The default car size
(4.2 m x 1.5 m x 1.7 m) is the one that figure shows.  The box's tightness depends on the viewpoint, which is
the systematic error that BBScale removes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..geometry import Camera

BMVC14_CAR_SIZE = (4.2, 1.5, 1.7)  # length, width, height in metres (Dubská et al. 2014, Fig. 4)


@dataclass
class BaselineScale:
    """λ (None when there were no usable boxes), the three per-dimension scales and the vehicle count."""

    scale: float | None
    status: str
    per_dimension: tuple[float, float, float] | None = None
    n_vehicles: int = 0


def bmvc14_scale(box_params: np.ndarray, car_size: tuple[float, float, float] = BMVC14_CAR_SIZE,
                 valid: np.ndarray | None = None) -> BaselineScale:
    """Scale from 3D boxes ``box_params`` (N, 5) = x0, x1, y0, y1, h in plane units (as
    :class:`~gst_trafficcal.tracking.box3d.Boxes3D.params`)."""
    P = np.asarray(box_params, np.float64).reshape(-1, 5)
    dims = np.stack([P[:, 1] - P[:, 0], P[:, 3] - P[:, 2], P[:, 4]], axis=1)
    ok = np.all(np.isfinite(dims) & (dims > 0), axis=1)
    if valid is not None:
        ok &= np.asarray(valid, bool)
    if not ok.any():
        return BaselineScale(None, "no valid 3D vehicle boxes")
    med = np.median(dims[ok], axis=0)
    lam = np.asarray(car_size, np.float64) / med
    return BaselineScale(float(lam.min()), "ok", tuple(float(v) for v in lam), int(ok.sum()))


def bmvc14_scale_from_hulls(cam: Camera, hulls: Sequence[np.ndarray],
                            car_size: tuple[float, float, float] = BMVC14_CAR_SIZE) -> BaselineScale:
    """The baseline from vehicles' image convex hulls (pixels) through Dubská's plain (tight) 3D box
    construction, as the paper's BMVC14 does (no car body shapes)."""
    from ..tracking.box3d import boxes_from_hulls

    if len(hulls) == 0:
        return BaselineScale(None, "no vehicle hulls")
    boxes = boxes_from_hulls(cam, list(hulls), shapes=())
    return bmvc14_scale(boxes.params, car_size, boxes.valid)
