"""The detection zone: the part of the frame where vehicles are looked for.

A camera often sees more than the road it should measure: a parking lot, a side road, a footpath, a slip road
with traffic of its own.  Vehicles there would be counted and measured, parked cars taken for slow ones, and a side
road's traffic would pull the first vanishing point off the measured road.  A zone is one or more polygons of the
frame; ``vehicledetect`` drops the vehicles whose box's bottom centre (where they touch the road) lies outside it,
and ``vpdetect`` learns only from the motion and the edges inside it.

Written as ``"x,y x,y x,y ..."`` with polygons separated by ``;``: in pixels of the frame, or, when every
coordinate lies in 0..1, in fractions of its width and height (the same zone for any resolution of a stream).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from .errors import InputError

SYNTAX = "'x,y x,y x,y ...' (pixels, or fractions 0..1 of the width and height), polygons separated by ';'"


@dataclass(frozen=True)
class Zone:
    """One or more polygons (each Kx2, K ≥ 3) in pixels, or in fractions of the frame when ``relative``."""

    polygons: tuple[np.ndarray, ...]
    relative: bool
    _masks: dict = field(default_factory=dict, compare=False, repr=False)  # (width, height) -> uint8 mask

    def pixels(self, size: tuple[int, int]) -> list[np.ndarray]:
        """The polygons in pixels of a ``size`` (width, height) frame."""
        scale = np.array(size, np.float64) if self.relative else np.ones(2)
        return [p * scale for p in self.polygons]

    def mask(self, size: tuple[int, int]) -> np.ndarray:
        """HxW uint8 mask of a ``size`` (width, height) frame: 255 on the pixels whose centre (at integer
        coordinates) the zone covers, 0 elsewhere; made once per size."""
        m = self._masks.get(tuple(size))
        if m is None:
            m = np.zeros((size[1], size[0]), np.uint8)
            cv2.fillPoly(m, [np.round(p * 16).astype(np.int32) for p in self.pixels(size)], 255, cv2.LINE_8, 4)
            self._masks[tuple(size)] = m
        return m

    def contains(self, points: np.ndarray, size: tuple[int, int]) -> np.ndarray:
        """Which of the Nx2 pixel ``points`` lie inside the zone (points outside the frame do not)."""
        p = np.round(np.asarray(points, np.float64).reshape(-1, 2))
        ok = np.isfinite(p).all(axis=1) & (p[:, 0] >= 0) & (p[:, 1] >= 0) & (p[:, 0] < size[0]) & (p[:, 1] < size[1])
        out = np.zeros(len(p), bool)
        i = p[ok].astype(int)
        out[ok] = self.mask(size)[i[:, 1], i[:, 0]] > 0
        return out

    def holds_boxes(self, boxes: np.ndarray, size: tuple[int, int]) -> np.ndarray:
        """Which of the Nx4 pixel boxes (x0, y0, x1, y1) stand in the zone: their bottom centre, where a vehicle
        touches the road, lies inside it."""
        return self.contains(box_anchors(boxes), size)

    def check(self, size: tuple[int, int]) -> str | None:
        """Why this zone cannot be used on a ``size`` (width, height) frame, or None: it covers none of its pixels."""
        if not self.mask(size).any():
            return f"zone {self}: it covers no pixel of the {size[0]}x{size[1]} frame"
        return None

    def beyond(self, size: tuple[int, int]) -> str | None:
        """A warning when a zone in pixels reaches past a ``size`` frame (written for another resolution?), or
        None."""
        if self.relative:
            return None
        far = np.concatenate(self.polygons).max(axis=0)
        if (far > np.array(size) + 1).any():
            return (f"zone {self} reaches to {far[0]:g},{far[1]:g}, beyond the {size[0]}x{size[1]} frame: written for "
                    f"another resolution? Fractions 0..1 of the width and height fit any")
        return None

    def __str__(self) -> str:
        fmt = "{:g},{:g}"
        return "; ".join(" ".join(fmt.format(*xy) for xy in p) for p in self.polygons)


def box_anchors(boxes: np.ndarray) -> np.ndarray:
    """Nx2 bottom centres of Nx4 boxes (x0, y0, x1, y1): where a vehicle touches the road in the image."""
    b = np.asarray(boxes, np.float64).reshape(-1, 4)
    return np.stack([(b[:, 0] + b[:, 2]) / 2, b[:, 3]], axis=1)


def parse_zone(text: str) -> Zone | None:
    """The zone ``text`` describes (see the module docstring), None for an empty text; InputError naming what is
    wrong otherwise."""
    text = (text or "").strip()
    if not text:
        return None
    polygons = []
    for k, part in enumerate(p for p in text.split(";") if p.strip()):
        try:
            pts = np.array([[float(v) for v in pair.split(",")] for pair in part.split()], np.float64)
        except ValueError:
            raise InputError(f"zone {text!r}: polygon {k + 1} is not a list of x,y numbers; expected {SYNTAX}") \
                from None
        if pts.ndim != 2 or pts.shape[1] != 2:
            raise InputError(f"zone {text!r}: polygon {k + 1} has a point without exactly two coordinates; "
                             f"expected {SYNTAX}")
        if not np.isfinite(pts).all():
            raise InputError(f"zone {text!r}: polygon {k + 1} has a coordinate that is not a finite number")
        if len(pts) < 3:
            raise InputError(f"zone {text!r}: polygon {k + 1} has {len(pts)} points; a zone needs at least 3")
        if abs(cv2.contourArea(pts.astype(np.float32))) <= 0:
            raise InputError(f"zone {text!r}: polygon {k + 1} encloses no area (its points lie on a line)")
        polygons.append(pts)
    if not polygons:
        raise InputError(f"zone {text!r}: no polygon; expected {SYNTAX}")
    every = np.concatenate(polygons)
    if (every < 0).any():
        raise InputError(f"zone {text!r}: negative coordinates; expected {SYNTAX}")
    relative = bool((every <= 1.0).all())
    return Zone(tuple(polygons), relative)
