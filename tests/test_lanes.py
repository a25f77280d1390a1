"""Lane model: lane centres from vehicles' lateral offsets; checked on BrnoCompSpeed tracks against its lanes."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from gst_trafficcal.brnocompspeed import load_gt_data, load_results
from gst_trafficcal.calibration import Calibration
from gst_trafficcal.evaluation import lanes_of_points
from gst_trafficcal.lanes import LaneModel, lane_centres, lateral_offset

from .conftest import BRNO, require_shared


def test_lane_centres_of_synthetic_traffic() -> None:
    rng = np.random.default_rng(5)
    true = np.array([-5.25, -1.75, 1.75])
    lanes = rng.choice(3, size=300, p=[0.5, 0.3, 0.2])
    offsets = true[lanes] + rng.normal(0, 0.35, 300)
    offsets = np.append(offsets, [0.0, 10.0])  # a vehicle between lanes, a stray far away
    c = lane_centres(offsets)
    np.testing.assert_allclose(c, true, atol=0.25)
    m = LaneModel()
    got = [m.assign(o) for o in offsets[:300]]
    agree = np.mean(np.array(got[50:]) == lanes[50:])  # once the model has seen some traffic
    assert agree > 0.97
    assert m.lane_of(10.0) is None and m.lane_of(float("nan")) is None
    assert lane_centres(np.array([])).size == 0
    np.testing.assert_allclose(lane_centres(np.array([1.0, 1.1, 0.9])), [1.0], atol=0.1)


def _full_grid_centres(y: np.ndarray, lane_width_m: float) -> np.ndarray:
    """lane_centres as it was written first: the density on one grid from the least offset to the greatest."""
    bw = lane_width_m / 5.0
    grid = np.arange(y.min() - 2 * bw, y.max() + 2 * bw + bw / 4, bw / 4)
    density = np.exp(-0.5 * ((grid[:, None] - y[None, :]) / bw) ** 2).sum(axis=1)
    peaks = np.flatnonzero((density[1:-1] >= density[:-2]) & (density[1:-1] > density[2:])) + 1
    if peaks.size == 0:
        return np.array([float(np.median(y))])
    kept: list[int] = []
    for p in peaks[np.argsort(-density[peaks])]:
        if all(abs(grid[p] - grid[k]) >= 0.5 * lane_width_m for k in kept):
            kept.append(p)
    centres = np.sort(grid[kept])
    share = np.bincount(np.argmin(np.abs(y[:, None] - centres[None, :]), axis=1), minlength=len(centres)) / y.size
    return centres[share >= 0.03] if (share >= 0.03).any() else centres


def test_a_stray_offset_far_across_the_road_costs_nothing() -> None:
    """Found by QA: the density was summed on one grid from the least offset to the greatest, a fifth of a lane
    over 4 apart, for every offset at once: 300 vehicles and one stray 10 km across the road (a reference point by
    the horizon; the overlay's counters take every track's) took 275 MB and 0.9 s, 3000 of them 2.7 GB and 10 s,
    at every new vehicle. The grid now skips the empty stretches, exactly: the same centres to the last bit."""
    import tracemalloc

    rng = np.random.default_rng(3)
    for _ in range(300):
        n = int(rng.integers(1, 60))
        y = rng.choice(rng.uniform(-30, 30, int(rng.integers(1, 6))), n) + rng.normal(0, rng.uniform(0.05, 1.5), n)
        if rng.random() < 0.3:  # strays between and beyond the lanes
            y = np.append(y, rng.uniform(-500, 500, int(rng.integers(1, 4))))
        width = float(rng.choice([3.5, 3.0, 1.0, 7.0]))
        assert np.array_equal(lane_centres(y, width), _full_grid_centres(y, width))
    y = np.append(rng.normal(0.0, 0.3, 300), 1e4)
    tracemalloc.start()
    try:
        centres = lane_centres(y)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 20e6, peak
    np.testing.assert_allclose(centres, [0.0], atol=0.1)


@pytest.mark.parametrize("width", [0.0, -3.5, float("nan"), float("inf")])
def test_a_lane_width_that_is_no_width_is_a_value_error(width: float) -> None:
    """0 was numpy's 'Maximum allowed size exceeded' (a grid step of 0), a negative width one lane whatever the
    traffic."""
    with pytest.raises(ValueError, match="lane width must be a positive number of metres"):
        lane_centres(np.array([-1.75, 1.75]), width)
    with pytest.raises(ValueError, match="lane width must be a positive number of metres"):
        LaneModel(width)


def test_lateral_offset() -> None:
    assert lateral_offset(np.array([1.0, np.nan, 2.0, 3.0])) == 2.0
    assert np.isnan(lateral_offset(np.array([np.nan])))


@pytest.mark.parametrize("recording", ["session0_center", "session2_right"])
def test_lanes_of_real_tracks_match_the_dataset_lanes(recording: str) -> None:
    """Tracks of a real system (dubska_bmvc14) and its own calibration; lanes as BrnoCompSpeed's dividers say."""
    rec = require_shared(BRNO / recording)
    gt = load_gt_data(rec / "gt_data.pkl")
    res = load_results(rec / "system_dubska_bmvc14.json")
    cam = Calibration.from_brno_block(res.calibration.to_dict()).camera
    model = LaneModel()
    ours, theirs = [], []
    for t in res.cars:
        ours.append(model.assign(lateral_offset(cam.to_world(t.pos)[:, 1])))
        theirs.append(int(lanes_of_points(t.pos[len(t.pos) // 2][None], gt.lane_div_lines)[0]))
    pairs = [(a, b) for a, b in zip(theirs, ours) if a >= 0]
    n_lanes = len({a for a, _ in pairs})
    assert len(model.centres) == n_lanes
    # the dataset numbers lanes from the other side: lane k is our n-1-k
    agree = np.mean([b == n_lanes - 1 - a for a, b in pairs])
    assert agree > 0.97, Counter(pairs).most_common(6)


def test_the_model_keeps_the_latest_vehicles_only():
    """A camera measured for weeks: the model learns from the latest MAX_OFFSETS vehicles (every one so far grew
    the memory, and the density recomputed at each vehicle took 0.2 s a vehicle after 25 000 vehicles); the lanes
    found are the same, and follow a lane moved for roadworks."""
    rng = np.random.default_rng(3)
    model = LaneModel()
    n = LaneModel.MAX_OFFSETS
    for y in np.array([-1.75, 1.75])[rng.integers(0, 2, 3 * n)] + rng.normal(0, 0.3, 3 * n):
        model.add(y)
    assert len(model.offsets) == n
    assert np.allclose(model.centres, [-1.75, 1.75], atol=0.1)
    for y in np.array([-1.75, 2.75])[rng.integers(0, 2, n)] + rng.normal(0, 0.3, n):  # the left lane moved 1 m
        model.add(y)
    assert np.allclose(model.centres, [-1.75, 2.75], atol=0.1)
