"""The calibration as a road-plane homography, for tools that take one (cv2.perspectiveTransform, supervision's
ViewTransformer, a VMS's own speed zones).

Users of those tools pick four image points of a road rectangle by hand and type in its size; a calibration has
the whole plane, so it can hand them the same thing exactly: the 3x3 matrix from image pixels to road metres in
the calibration's world frame (origin on the road below the camera, x along the traffic towards VP1, y across it,
to the left looking towards VP1; :mod:`gst_trafficcal.geometry`), and four image points with their road
coordinates for tools that want correspondences.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import GeometryError
from .geometry import Camera


@dataclass(frozen=True)
class RoadHomography:
    """``image_to_road_m`` maps homogeneous image pixels to road metres (x, y, 1); ``source_px`` are four image
    points on the road (a quadrilateral well below the horizon, inside the frame) and ``target_m`` their road
    coordinates, so ``cv2.getPerspectiveTransform(source_px, target_m)`` is the same matrix."""

    image_to_road_m: np.ndarray
    source_px: np.ndarray
    target_m: np.ndarray

    def to_dict(self) -> dict:
        return {"image_to_road_m": self.image_to_road_m.tolist(), "source_px": self.source_px.tolist(),
                "target_m": self.target_m.tolist()}


def image_to_road(camera: Camera) -> np.ndarray:
    """3x3 homography from image pixels to road-plane metres (world x, y), normalised to H[2, 2] = 1."""
    K, R, t = camera.to_KRt()  # needs the scale
    road_to_image = K @ np.column_stack([R[:, 0], R[:, 1], t])  # a world point (x, y, 0) seen by the camera
    H = np.linalg.inv(road_to_image)
    return H / H[2, 2]


def road_points(camera: Camera, image_size: tuple[int, int], margin: float = 0.1,
                below_horizon: float = 1 / 3) -> np.ndarray:
    """Four image points on the road, (4, 2) whole pixels: ``margin`` of the frame in from its sides and bottom,
    and a row ``below_horizon`` of the way from the horizon (or the frame's top, if the horizon is above it) down
    to the bottom row — far enough below the horizon that a pixel there is not metres of road."""
    w, h = image_size
    x0, x1 = margin * (w - 1), (1 - margin) * (w - 1)
    bottom = (1 - margin) * (h - 1)
    a, b, c = camera.horizon
    if abs(b) < 1e-9:
        raise GeometryError("the horizon is vertical in the image: no image rows lie on the road")
    horizon_y = max(-(a * x + c) / b for x in (x0, x1))  # its lower end over the two columns
    top = max(horizon_y, 0.0) + below_horizon * (bottom - max(horizon_y, 0.0))
    if not top < bottom:
        raise GeometryError("the horizon lies at or below the frame's bottom rows: no road in view")
    pts = np.round([[x0, top], [x1, top], [x1, bottom], [x0, bottom]])  # whole pixels: easy to read and type
    if not np.all(camera.rays(pts) @ camera.normal < 0):  # below the horizon: the rays meet the road ahead
        raise GeometryError("the frame's lower part does not look at the road (camera upside down?)")
    return pts


def road_homography(camera: Camera, image_size: tuple[int, int]) -> RoadHomography:
    """The calibration's road-plane homography and four correspondences (:class:`RoadHomography`)."""
    H = image_to_road(camera)
    source = road_points(camera, image_size)
    return RoadHomography(H, source, camera.to_world(source)[:, :2])
