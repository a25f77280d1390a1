"""How firmly a view pins down the speeds: the conditioning of a calibration's second vanishing point.

Where a camera looks along the road, VP2 lies tens of image widths away and the vehicles' edges towards it are all
but parallel. A tiny turn of those edges then moves VP2 far along the horizon, the focal length with it, and every
distance along the road stretches or shrinks: the speeds are only as good as VP2's last hundredth of a degree.
Where the camera sees the road obliquely, VP2 lies a few image widths away and the same turn changes the speeds by a
fraction of a per cent.

:func:`view_conditioning` measures this on the calibration itself: the line from the road's middle in the image to
VP2 is turned by ``turn_deg`` about that point (an error in the edges' image angle), VP2 moved to where the turned
line meets the horizon (VP1 and the horizon kept), and the road's unit steps along the traffic measured with the
moved VP2 at the same camera height. The median relative change is how much the speeds would change. It is a
property of the view, not an error estimate: how much of it a calibration shows depends on how well its VP2 was
found (docs/vpdetect.md "How firmly a view pins down the speeds").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import GeometryError
from ..geometry import Camera, homogeneous

TURN_DEG = 0.1
"""The turn of the lines towards VP2 the sensitivity is given for (degrees of image angle)."""
POOR_PCT = 2.0
"""Speeds that change by this much (%) or more under :data:`TURN_DEG` make a poorly conditioned view."""
ROAD_HEIGHTS = 20.0
"""Road points farther than this many camera heights from the camera are not where speeds are measured."""


@dataclass(frozen=True)
class Conditioning:
    """A view's sensitivity to VP2: ``speed_pct`` (%) the speeds change by when the lines towards VP2 turn by
    ``turn_deg`` (inf: so little turn puts VP2 on the other side of the horizon's infinity; NaN: no road in view);
    ``vp2_widths``: VP2's distance from the principal point in image widths."""

    vp2_widths: float
    speed_pct: float
    turn_deg: float = TURN_DEG

    @property
    def poor(self) -> bool:
        return bool(self.speed_pct >= POOR_PCT)

    def to_dict(self) -> dict[str, float | bool | None]:
        return {"vp2_image_widths": round(self.vp2_widths, 2), "turn_deg": self.turn_deg,
                "speed_pct": round(self.speed_pct, 3) if math.isfinite(self.speed_pct) else None, "poor": self.poor}

    def describe(self, advice: bool = True) -> str:
        """One line for people: the sensitivity, and (``advice``) what to do when it is poor."""
        if not math.isfinite(self.speed_pct):
            change = "cannot be said (no road in view)" if math.isnan(self.speed_pct) else "is unbounded"
        else:
            change = f"changes the speeds by {self.speed_pct:.1f} %"
        text = (f"VP2 lies {self.vp2_widths:.1f} image widths away; a {self.turn_deg:g}° error in the edges "
                f"towards it {change}")
        if self.poor and not advice:
            text += " (a poorly conditioned view)"
        elif self.poor:
            text += ADVICE
        return text


ADVICE = (": the camera looks along the road, which pins the speed scale down poorly — expect automatic speeds a few "
          "per cent off; a view that sees the road more obliquely, or a calibration from road measurements "
          "(trafficcal calibrate-manual --measurements), measures better")
"""What :meth:`Conditioning.describe` adds for a poor view (how a warning that gave the advice is recognised)."""


def road_points(camera: Camera, image_size: tuple[int, int], max_heights: float = ROAD_HEIGHTS,
                grid: tuple[int, int] = (48, 27)) -> np.ndarray:
    """Image points (N, 2) on a ``grid`` over the image whose road point lies in front of the camera within
    ``max_heights`` camera heights of it (a camera that sees no road that near: all its road points)."""
    w, h = image_size
    u, v = np.meshgrid(np.linspace(0, w - 1, grid[0]), np.linspace(0, h - 1, grid[1]))
    p = np.stack([u.ravel(), v.ravel()], axis=1)
    X = camera.to_road(p)
    with np.errstate(invalid="ignore"):
        ahead = np.all(np.isfinite(X), axis=1) & (X[:, 2] > 0)
        near = ahead & (np.linalg.norm(X, axis=1) <= max_heights)
    return p[near] if near.any() else p[ahead]


def turned_vp2(camera: Camera, anchor: np.ndarray, turn_deg: float) -> np.ndarray:
    """Where the line from ``anchor`` to VP2, turned by ``turn_deg`` about ``anchor``, meets the horizon."""
    a = math.radians(turn_deg)
    d = camera.vp2 - anchor
    d = np.array([math.cos(a) * d[0] - math.sin(a) * d[1], math.sin(a) * d[0] + math.cos(a) * d[1]])
    x = np.cross(np.cross(homogeneous(anchor), homogeneous(anchor + d)), camera.horizon)
    if abs(x[2]) < 1e-12 * np.linalg.norm(x[:2]):
        raise GeometryError("the turned line runs parallel to the horizon")
    return x[:2] / x[2]


def road_stretch(camera: Camera, other: Camera, points: np.ndarray) -> float:
    """Median relative change (%) of unit road steps along the traffic (VP1) starting at ``points`` when measured
    with ``other``'s vanishing points instead of ``camera``'s, at the same camera height."""
    X = camera.to_road(points)
    q = camera.from_road(X + camera.rotation[:, 0])
    ratio = other.plane_distance(points, q) / camera.plane_distance(points, q)
    return float(100 * np.median(ratio - 1))


def view_conditioning(camera: Camera, image_size: tuple[int, int], turn_deg: float = TURN_DEG) -> Conditioning:
    """The :class:`Conditioning` of ``camera``'s view: the larger of the stretches by the lines towards VP2 turned
    by ±``turn_deg`` about the road's middle in the image."""
    widths = float(np.linalg.norm(camera.vp2 - camera.pp) / image_size[0])
    points = road_points(camera, image_size)
    if not len(points):
        return Conditioning(widths, math.nan, turn_deg)
    anchor = points.mean(axis=0)
    worst = 0.0
    for sign in (1.0, -1.0):
        try:
            other = Camera(camera.vp1, turned_vp2(camera, anchor, sign * turn_deg), camera.pp)
        except GeometryError:  # VP2 pushed through infinity: the focal length is not pinned down at all
            return Conditioning(widths, math.inf, turn_deg)
        worst = max(worst, abs(road_stretch(camera, other, points)))
    return Conditioning(widths, worst, turn_deg)
