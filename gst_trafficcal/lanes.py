"""Lanes from where vehicles drive: clusters of their lateral offsets on the road plane.

Each vehicle contributes one lateral offset: the median world ``y`` (metres across the road, see
:mod:`gst_trafficcal.geometry`) of its reference points. Lane centres are the peaks of a kernel density of
the offsets seen so far (bandwidth a fifth of a lane, peaks closer than half a lane merged, tiny peaks
dropped), numbered 0, 1, ... in order of increasing ``y``: world y points to the left when looking towards
VP1, so lane 0 is the rightmost lane seen in the direction of VP1. A vehicle's lane is the nearest centre, if it is
within one lane width; the model is refined with every vehicle, so early vehicles of a stream are assigned
with fewer samples than later ones. It keeps the latest :attr:`LaneModel.MAX_OFFSETS` offsets: the density over
every vehicle so far, recomputed at each one, cost 0.2 s a vehicle after a busy day and 2 s after a week.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

DEFAULT_LANE_WIDTH_M = 3.5


def check_lane_width(lane_width_m: float) -> float:
    """The lane width as a float; ValueError unless it is a positive number of metres (0 made the density's grid
    step 0: numpy's 'Maximum allowed size exceeded'; a negative one gave a single lane whatever the traffic)."""
    width = float(lane_width_m)
    if not (np.isfinite(width) and width > 0):
        raise ValueError(f"lane width must be a positive number of metres, got {lane_width_m!r}")
    return width


GRID_BLOCK = 256  # grid points whose density is summed at once (memory: GRID_BLOCK x offsets)


def _density_grid(y: np.ndarray, bw: float) -> tuple[np.ndarray, np.ndarray]:
    """(grid, density): the kernel density of offsets ``y`` at the points, bw/4 apart, of the lattice from
    ``min(y) - 2 bw`` that lie within 2 bw of an offset, or between offsets less than 8 bw apart.  Where offsets are
    further apart the density only falls and rises again (no peak), so those stretches are left out: one stray
    vehicle 10 km across the road (a reference point by the horizon) made a grid of 57,000 points, summed over
    every offset at once (hundreds of MB for a day's vehicles).  The grid points kept are exactly the full grid's,
    with the same densities, in blocks of :data:`GRID_BLOCK`."""
    ys = np.sort(y)
    step, g0 = bw / 4, ys[0] - 2 * bw
    breaks = np.flatnonzero(np.diff(ys) > 8 * bw) + 1
    runs = zip(np.r_[0, breaks], np.r_[breaks, len(ys)] - 1)
    # lattice indices k (grid = g0 + k·step) covering each run of offsets from its first - 2 bw to its last + 2 bw
    # (ending as np.arange(g0, y[-1] + 2 bw + step, step) ends)
    spans = [np.arange(np.floor((ys[a] - 2 * bw - g0) / step), np.ceil((ys[b] + 2 * bw + step - g0) / step))
             for a, b in runs]
    grid = g0 + np.concatenate(spans) * ((g0 + step) - g0)  # np.arange's own step: the same grid to the last bit
    density = np.empty(len(grid))
    for k in range(0, len(grid), GRID_BLOCK):
        g = grid[k:k + GRID_BLOCK]
        density[k:k + GRID_BLOCK] = np.exp(-0.5 * ((g[:, None] - y[None, :]) / bw) ** 2).sum(axis=1)
    return grid, density


def lane_centres(offsets: np.ndarray, lane_width_m: float = DEFAULT_LANE_WIDTH_M,
                 min_share: float = 0.03) -> np.ndarray:
    """Lane centres (metres, increasing) from lateral offsets of many vehicles."""
    lane_width_m = check_lane_width(lane_width_m)
    y = np.asarray(offsets, np.float64).reshape(-1)
    y = y[np.isfinite(y)]
    if y.size == 0:
        return np.zeros(0)
    bw = lane_width_m / 5.0
    grid, density = _density_grid(y, bw)
    interior = (density[1:-1] >= density[:-2]) & (density[1:-1] > density[2:])
    peaks = np.flatnonzero(interior) + 1
    if peaks.size == 0:
        return np.array([float(np.median(y))])
    # strongest first; a weaker peak within half a lane of a kept one is the same lane
    kept: list[int] = []
    for p in peaks[np.argsort(-density[peaks])]:
        if all(abs(grid[p] - grid[k]) >= 0.5 * lane_width_m for k in kept):
            kept.append(p)
    # drop peaks carried by only a few vehicles (stray tracks between lanes)
    centres = np.sort(grid[kept])
    owner = np.argmin(np.abs(y[:, None] - centres[None, :]), axis=1)
    share = np.bincount(owner, minlength=len(centres)) / y.size
    return centres[share >= min_share] if (share >= min_share).any() else centres


@dataclass
class LaneModel:
    """Online lane model (see the module docstring)."""

    lane_width_m: float = DEFAULT_LANE_WIDTH_M
    offsets: list[float] = field(default_factory=list)  # the latest MAX_OFFSETS vehicles'
    _centres: np.ndarray | None = field(default=None, repr=False)

    # vehicles the lanes are found from, the latest (as the overlay's counters keep): a few hours of a busy road,
    # 3 ms a vehicle; every vehicle so far grew the memory and the time per vehicle without end
    MAX_OFFSETS: ClassVar[int] = 2000

    def __post_init__(self) -> None:
        self.lane_width_m = check_lane_width(self.lane_width_m)

    def add(self, offset_m: float) -> None:
        if np.isfinite(offset_m):
            self.offsets.append(float(offset_m))
            del self.offsets[:-self.MAX_OFFSETS]
            self._centres = None

    @property
    def centres(self) -> np.ndarray:
        if self._centres is None:
            self._centres = lane_centres(np.array(self.offsets), self.lane_width_m)
        return self._centres

    def lane_of(self, offset_m: float) -> int | None:
        """Index of the lane at ``offset_m`` (None when there is no lane within one lane width)."""
        c = self.centres
        if c.size == 0 or not np.isfinite(offset_m):
            return None
        k = int(np.argmin(np.abs(c - offset_m)))
        return k if abs(c[k] - offset_m) <= self.lane_width_m else None

    def assign(self, offset_m: float) -> int | None:
        """Add a vehicle's offset to the model and return its lane."""
        self.add(offset_m)
        return self.lane_of(offset_m)


def lateral_offset(world_y_m: np.ndarray) -> float:
    """A vehicle's lateral offset: the median of its reference points' world ``y`` (NaN when none is finite)."""
    y = np.asarray(world_y_m, np.float64)
    y = y[np.isfinite(y)]
    return float(np.median(y)) if y.size else float("nan")
