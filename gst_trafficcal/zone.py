"""The detection zone: the part of the frame where vehicles are looked for.

A camera often sees more than the road it should measure: a parking lot, a side road, a footpath, a slip road
with traffic of its own.  Vehicles there would be counted and measured, parked cars taken for slow ones, and a side
road's traffic would pull the first vanishing point off the measured road.  A zone is one or more polygons of the
frame; ``vehicledetect`` drops the vehicles whose box's bottom centre (where they touch the road) lies outside it,
and ``vpdetect`` learns only from the motion and the edges inside it.

Written as ``"x,y x,y x,y ..."`` with polygons separated by ``;``: in pixels of the frame, or, when every
coordinate lies in 0..1, in fractions of its width and height (the same zone for any resolution of a stream).

A calibration file learnt or measured in a zone keeps it as its field ``zone`` (``trafficcal calibrate --zone``,
``trafficcal run --zone``); :func:`zone_of_file` reads it back for a report made again or a run given the file.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from .detection.records import Detections
from .errors import InputError
from .fileio import json_text_field

WHOLE_FRAME = "all"
"""The zone text for the whole frame: as no zone, but said explicitly (over the zone a calibration file keeps)."""
SYNTAX = "'x,y x,y x,y ...' (pixels, or fractions 0..1 of the width and height), polygons separated by ';'"


@dataclass(frozen=True)
class Zone:
    """One or more polygons (each Kx2, K ≥ 3) in pixels, or in fractions of the frame when ``relative``.

    Coordinates follow the boxes' convention: pixel (i, j) is the square [i, i + 1) x [j, j + 1), so a box whose
    bottom is the frame's (y1 = height) stands on its last row, and "0,0 1,0 1,1 0,1" covers every pixel."""

    polygons: tuple[np.ndarray, ...]
    relative: bool
    _masks: dict = field(default_factory=dict, compare=False, repr=False)  # (width, height) -> uint8 mask

    def pixels(self, size: tuple[int, int]) -> list[np.ndarray]:
        """The polygons in pixels of a ``size`` (width, height) frame."""
        scale = np.array(size, np.float64) if self.relative else np.ones(2)
        return [p * scale for p in self.polygons]

    def mask(self, size: tuple[int, int]) -> np.ndarray:
        """HxW uint8 mask of a ``size`` (width, height) frame: 255 on the pixels whose centre the zone covers and on
        those its outline passes through (cv2.fillPoly), 0 elsewhere; made once per size."""
        m = self._masks.get(tuple(size))
        if m is None:
            m = np.zeros((size[1], size[0]), np.uint8)
            # cv2 puts pixel centres at integer coordinates; ours lie at i + 0.5
            cv2.fillPoly(m, [np.round((p - 0.5) * 16).astype(np.int32) for p in self.pixels(size)], 255,
                         cv2.LINE_8, 4)
            self._masks[tuple(size)] = m
        return m

    def contains(self, points: np.ndarray, size: tuple[int, int]) -> np.ndarray:
        """Which of the Nx2 pixel ``points`` lie inside the zone (points outside the frame, whose right and bottom
        edges still count as in it, do not)."""
        p = np.asarray(points, np.float64).reshape(-1, 2)
        ok = np.isfinite(p).all(axis=1) & (p >= 0).all(axis=1) & (p <= np.asarray(size)).all(axis=1)
        out = np.zeros(len(p), bool)
        i = np.minimum(np.floor(p[ok]).astype(int), np.asarray(size) - 1)
        out[ok] = self.mask(size)[i[:, 1], i[:, 0]] > 0
        return out

    def keep(self, detections: Detections, size: tuple[int, int]) -> Detections:
        """The vehicles that stand in the zone: their box's bottom centre, where they touch the road, lies inside."""
        return detections[self.contains(detections.bottom_centers, size)] if len(detections) else detections

    def check(self, size: tuple[int, int]) -> str | None:
        """Why this zone cannot be used on a ``size`` (width, height) frame, or None: it covers none of its pixels."""
        if not self.mask(size).any():
            return f"zone {self}: it covers no pixel of the {size[0]}x{size[1]} frame"
        return None

    def doubt(self, size: tuple[int, int]) -> str | None:
        """A warning when a zone in pixels looks written for another frame than a ``size`` one (it reaches past it,
        or covers under 0.5 % of it), or None."""
        if self.relative:
            return None
        far = np.concatenate(self.polygons).max(axis=0)
        hint = "written for another resolution? Fractions 0..1 of the width and height fit any"
        if (far > np.array(size) + 1).any():
            return f"zone {self} reaches to {far[0]:g},{far[1]:g}, beyond the {size[0]}x{size[1]} frame: {hint}"
        share = np.count_nonzero(self.mask(size)) / (size[0] * size[1])
        if share < 0.005:
            return f"zone {self} covers only {100 * share:.2g} % of the {size[0]}x{size[1]} frame: {hint}"
        return None

    def __str__(self) -> str:
        fmt = "{:g},{:g}"
        return "; ".join(" ".join(fmt.format(*xy) for xy in p) for p in self.polygons)


def parse_zone(text: str, option: str = "") -> Zone | None:
    """The zone ``text`` describes (see the module docstring), None for an empty text or ``all`` (the whole frame);
    InputError naming what is wrong otherwise (after ``option``, e.g. "--zone", when it came from a command-line
    option)."""
    try:
        return _parse_zone(text)
    except InputError as exc:
        if not option:
            raise
        raise InputError(f"{option}: {exc}") from None


def _parse_zone(text: str) -> Zone | None:
    text = (text or "").strip()
    if not text or text.lower() == WHOLE_FRAME:
        return None
    polygons = []
    for k, part in enumerate(text.split(";")):
        if not part.strip():
            continue
        what = f"zone {text!r}: polygon {k + 1}"
        pairs = [pair.split(",") for pair in re.sub(r"\s*,\s*", ",", part).split()]  # "x, y" as "x,y"
        if any(len(xy) != 2 for xy in pairs):
            raise InputError(f"{what} has a point without exactly two coordinates; expected {SYNTAX}")
        try:
            pts = np.array([[float(x), float(y)] for x, y in pairs], np.float64)
        except ValueError:
            raise InputError(f"{what} is not a list of x,y numbers; expected {SYNTAX}") from None
        if not np.isfinite(pts).all():
            raise InputError(f"{what} has a coordinate that is not a finite number")
        pts = pts[np.r_[True, np.any(np.diff(pts, axis=0) != 0, axis=1)]]  # a point repeated in a row: once
        if len(pts) > 3 and np.array_equal(pts[0], pts[-1]):  # closed as GIS tools write rings: the last is the first
            pts = pts[:-1]
        if len(pts) < 3:
            raise InputError(f"{what} has {len(pts)} points; a zone needs at least 3")
        if np.linalg.matrix_rank(pts - pts.mean(axis=0), tol=1e-9) < 2:
            raise InputError(f"{what} encloses no area (its points lie on a line)")
        if _crosses_itself(pts):
            raise InputError(f"{what} crosses itself: give its corners in order around it")
        polygons.append(pts)
    if not polygons:
        raise InputError(f"zone {text!r}: no polygon; expected {SYNTAX}")
    every = np.concatenate(polygons)
    if (every < 0).any():
        raise InputError(f"zone {text!r}: negative coordinates; expected {SYNTAX}")
    relative = bool((every <= 1.0).all())
    if not relative and ((every > 0) & (every < 1)).any():
        raise InputError(f"zone {text!r}: mixes fractions of the frame (between 0 and 1) with pixels (above 1): "
                         "give every coordinate one way")
    return Zone(tuple(polygons), relative)


def _crosses_itself(pts: np.ndarray) -> bool:
    """Whether two edges of the closed polygon ``pts`` (Kx2) that do not share a corner cross or touch (corners
    written out of order: "0,0 1,1 1,0 0,1" for a square)."""
    a, b = pts, np.roll(pts, -1, axis=0)  # edge i runs from a[i] to b[i]
    k = len(pts)

    def side(p, q, r):  # sign of the turn p -> q -> r, for every pair of edges at once
        return np.sign((q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0]))

    i, j = np.triu_indices(k, 2)
    apart = (j - i) % k > 1 if k > 3 else np.zeros(len(i), bool)
    apart &= ~((i == 0) & (j == k - 1))  # the last edge meets the first at corner 0
    i, j = i[apart], j[apart]
    d1, d2 = side(a[j], b[j], a[i]), side(a[j], b[j], b[i])
    d3, d4 = side(a[i], b[i], a[j]), side(a[i], b[i], b[j])
    return bool(np.any((d1 * d2 <= 0) & (d3 * d4 <= 0) & ~((d1 == 0) & (d2 == 0))))


def zone_of_file(path: str | Path) -> Zone | None:
    """The detection zone a calibration file was learnt or measured in (its field ``zone``), None when it has none;
    InputError naming the file when it cannot be read or the zone is not one."""
    text = json_text_field(path, "zone", "calibration file", f"a text {SYNTAX}")
    return None if text is None else parse_zone(text, f"{path}: field 'zone'")


def given_or_kept(text: str, option: str, calibration: str | Path | None) -> Zone | None:
    """The zone ``text`` gives (``option`` names it in errors); with none given (an empty text, not ``all``), the
    one the ``calibration`` file keeps (:func:`zone_of_file`): a run or report given a camera's calibration keeps to
    the road it was learnt on."""
    where = parse_zone(text, option)
    if where is None and not (text or "").strip() and calibration is not None:
        where = zone_of_file(calibration)
    return where
