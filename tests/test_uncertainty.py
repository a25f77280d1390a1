"""A speed's uncertainty (uncertainty.py): from the vehicle's own samples and from the calibration."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gst_trafficcal.calibration import Calibration
from gst_trafficcal.measurement import SpeedMeter
from gst_trafficcal.speed import vehicle_speed
from gst_trafficcal.uncertainty import (DEFAULT_MODEL, calibration_pct, is_manual, sample_spread, speed_uncertainty,
                                        view_sensitivity)

from .test_vanishing_conditioning import preset_camera


def straight_track(camera, speed_kmh: float, noise_px: float, n: int = 60, fps: float = 25.0, seed: int = 0):
    """Image points of a vehicle driving at ``speed_kmh`` along the road (x) in the middle of a lane, with
    ``noise_px`` of normal noise per coordinate, and their times."""
    t = np.arange(n) / fps
    start = np.array([camera.pp[0], camera.pp[1] * 1.5])  # below the image's centre, towards VP1 from there
    w0 = camera.to_world(start[None])[0]
    along = camera.to_world((start + 0.01 * (camera.vp1 - start))[None])[0] - w0
    world = w0 + np.outer(speed_kmh / 3.6 * t, along / np.linalg.norm(along))
    px = camera.world_to_image(world)
    return px + np.random.default_rng(seed).normal(0, noise_px, px.shape), t


def test_scattered_samples_give_a_larger_spread():
    rng = np.random.default_rng(1)
    tight, loose = 80 + rng.normal(0, 0.5, 40), 80 + rng.normal(0, 4.0, 40)
    assert 0 < sample_spread(tight, 8) < sample_spread(loose, 8)
    assert sample_spread(loose, 32) < sample_spread(loose, 8)  # more independent pairs: a firmer median
    assert sample_spread([80.0], 1) == 0.0 and sample_spread([], 1) == 0.0
    # one wild sample moves a robust spread little
    assert sample_spread(np.r_[tight, 400.0], 8) == pytest.approx(sample_spread(tight, 8), rel=0.3)


def test_a_noisier_track_has_a_larger_uncertainty():
    cam, _ = preset_camera("highway_day")
    spreads = []
    for noise in (0.0, 0.3, 1.5):
        px, t = straight_track(cam, 80.0, noise)
        m = vehicle_speed(cam, px, t)
        assert m.measured and m.speed_kmh == pytest.approx(80.0, rel=0.05)
        spreads.append(m.spread_kmh)
    assert spreads[0] < 0.01 and spreads[0] < spreads[1] < spreads[2]
    u = [speed_uncertainty(80.0, s, 1.0) for s in spreads]
    assert u[0] == pytest.approx(DEFAULT_MODEL.z * np.hypot(DEFAULT_MODEL.track_floor_pct, 1.0) / 100 * 80)
    assert u[0] <= u[1] < u[2]


def test_the_calibrations_part_grows_with_the_views_sensitivity():
    oblique, size = preset_camera("highway_day")
    along, size_along = preset_camera("vp2_far")
    auto = [Calibration(oblique, size, source="vpdetect+bbscale"), Calibration(along, size_along, source="vpdetect")]
    s_oblique, s_along = (view_sensitivity(c) for c in auto)
    assert s_oblique < 1.0 < 2.0 < s_along  # a view along the road is poorly conditioned
    p_oblique, p_along = (calibration_pct(c) for c in auto)
    assert DEFAULT_MODEL.scale_pct < p_oblique < p_along
    assert [calibration_pct(auto[0], s) for s in (0.1, 1, 4, 16)] == sorted(calibration_pct(auto[0], s)
                                                                             for s in (0.1, 1, 4, 16))
    # a speed's U grows with it too
    assert speed_uncertainty(80, 0.2, p_oblique) < speed_uncertainty(80, 0.2, p_along)
    # a calibration from road measurements: its own, smaller part, whatever the view
    manual = Calibration(along, size_along, source="manual-calibration")
    assert is_manual(manual) and not is_manual(auto[1])
    assert calibration_pct(manual) == DEFAULT_MODEL.manual_pct < p_oblique
    # no scale: no uncertainty; a view whose conditioning cannot be computed: taken as poorly conditioned
    assert calibration_pct(Calibration(along.with_scale(None), size_along, source="vpdetect")) is None
    assert calibration_pct(auto[0], float("nan")) == calibration_pct(auto[0], DEFAULT_MODEL.unknown_speed_pct)
    # the speedometer's meter keeps the calibration's part per view: a new scale keeps it, new VPs change it
    meter = SpeedMeter()
    u = [meter.uncertainty(80.0, 0.2, c) for c in (auto[0], auto[1], replace(auto[1], camera=along.with_scale(
        2 * along.scale)), auto[0], manual)]
    assert u[0] == pytest.approx(speed_uncertainty(80, 0.2, p_oblique), abs=0.01) and u[3] == u[0]
    assert u[1] == u[2] == pytest.approx(speed_uncertainty(80, 0.2, p_along), abs=0.01)
    assert u[4] == pytest.approx(speed_uncertainty(80, 0.2, DEFAULT_MODEL.manual_pct), abs=0.01)
    assert meter.uncertainty(None, 0.2, auto[0]) is None and meter.uncertainty(80.0, 0.2, None) is None
