"""Vehicle classes from 3D dimensions: the catalogue's styles, the detector's own classes, and the speed meter's
events (exact simulated boxes through the measurement stage)."""

from __future__ import annotations

import numpy as np
import pytest

from gst_trafficcal.calibration import Calibration
from gst_trafficcal.measurement import Sighting, SpeedMeter
from gst_trafficcal.tracking.simulate import default_camera, vehicle_passing
from gst_trafficcal.vehicles.catalogue import BODY_STYLES, style_distributions
from gst_trafficcal.vehicles.classify import LABEL_OF_STYLE, MAX_Z, classify_dimensions, refined_label

SIZE = (960, 540)


def test_every_catalogue_style_at_its_mean_dimensions_is_its_own_class():
    styles = style_distributions()
    dims = [d.mean for d in styles.values()] + [v[1].mean for d in styles.values() for v in d.variants.values()
                                                  if v[1] is not None]
    want = [LABEL_OF_STYLE[n] for n in styles] + [LABEL_OF_STYLE[n] for n, d in styles.items()
                                                   for v in d.variants.values() if v[1] is not None]
    got = classify_dimensions(np.array(dims))
    assert [c.label for c in got] == want
    assert all(c.worst_z < 1e-9 and c.margin > 0 for c in got)
    assert {c.style for c in got} == set(styles)


def test_every_body_style_has_a_label():
    assert set(LABEL_OF_STYLE) == set(BODY_STYLES)


def test_measured_dimensions_within_their_error_keep_the_class():
    # a hatchback measured 10 % long and 8 % wide, a van 10 % short, a rigid truck, a bus, a motorcycle
    got = classify_dimensions([[4.5, 1.87, 1.5], [4.7, 2.0, 2.2], [9.0, 2.5, 3.4], [12.3, 2.5, 3.1], [2.2, 0.8, 1.4]])
    assert [c.label for c in got] == ["car", "van", "truck", "bus", "motorcycle"]


def test_dimensions_no_class_explains_leave_the_detector_label():
    """A car measured at half its length is no motorcycle (its width says so): the detector's label stays."""
    (odd,) = classify_dimensions([[1.81, 1.91, 1.57]])
    assert odd.worst_z > MAX_Z
    assert refined_label("car", odd) == "car"


def test_only_class_agnostic_labels_are_refined():
    (bus,) = classify_dimensions([[12.0, 2.55, 3.15]])
    (car,) = classify_dimensions([[4.5, 1.8, 1.5]])
    assert refined_label("car", bus) == "bus" and refined_label("vehicle", bus) == "bus"
    assert refined_label("truck", car) == "truck"  # a detector's own class is kept
    assert refined_label("car", None) == "car"


@pytest.mark.parametrize("dims", [[0.0, 1.8, 1.5], [4.5, np.nan, 1.5], [-4.5, 1.8, 1.5]])
def test_impossible_dimensions_are_refused(dims):
    with pytest.raises(ValueError, match="positive metres"):
        classify_dimensions([dims])


@pytest.mark.parametrize("size, label", [((12.0, 2.55, 3.15), "bus"), ((5.3, 2.0, 2.3), "van"),
                                         ((4.4, 1.78, 1.47), "car"), ((2.1, 0.8, 1.5), "motorcycle"),
                                         ((9.0, 1.9, 0.5), "car")])
def test_the_speed_meter_reports_the_class_and_dimensions_of_a_car_labelled_vehicle(size, label):
    """A detector that calls every vehicle "car": the event names the class the measured 3D boxes give, and
    carries those dimensions; a shape no vehicle has (9 m long, half a metre tall: a flat, broken box) keeps the
    detector's label and reports no dimensions."""
    cam = default_camera(SIZE, tilt=14.0, height=9.0, hfov=50.0)
    scene = vehicle_passing(cam, size, lane=1.75, x_start=70.0, speed_kmh=70.0, direction=-1, image_size=SIZE,
                            duration=3.0)
    meter = SpeedMeter(calibration=Calibration(camera=cam, image_size=SIZE, state="calibrated", source="test"))
    events, live = [], []
    whole = 0
    for f in scene.frames:
        full = np.concatenate([f.corners_px[0].min(axis=0), f.corners_px[0].max(axis=0)])
        cut = not np.allclose(full, f.boxes[0], atol=1e-6)
        whole += not cut
        s = Sighting(1, "car", f.t, tuple(f.boxes[0]), 0.9, truncated=cut, corners_px=f.corners_px[0],
                     ref_px=f.ref_px[0], hull=f.hulls[0])
        out = meter.update(f.t, [s])
        events += out.finished
        live += [out.speeds[1].label] if 1 in out.speeds else []
    events += meter.flush()
    assert whole >= 20 and live[-1] == label  # the "speed" ROI structure names it while it is in view
    (event,) = [m.event for m in events]
    assert event.measured and event.label == label
    if size[2] < 1.0:
        assert (event.length_m, event.width_m, event.height_m) == (None, None, None)
    else:
        np.testing.assert_allclose([event.length_m, event.width_m, event.height_m], size, rtol=0.01)


def test_a_car_measured_short_and_narrow_is_no_motorcycle(load_benchmark):
    """A car seen only in part or from afar measures small, and the smallest class is where it lands: kraten_cars'
    far-side cars measured 2.3–3.0 m by 1.0–1.3 m were called motorcycles, live on the video and in the events.  A
    motorcycle is claimed only when the dimensions say so by MOTORCYCLE_MARGIN; kraten's scooter (1.33 x 0.64 m)
    and a catalogue motorcycle still are, and 99 % of the catalogue's motorcycles with the measurement noise."""
    from gst_trafficcal.vehicles.classify import MOTORCYCLE_MARGIN

    cars = classify_dimensions([[3.02, 0.99, 1.33], [2.32, 1.25, 1.56], [2.89, 1.18, 1.39], [2.71, 1.32, 1.34]])
    assert [c.label for c in cars] == ["motorcycle"] * 4 and all(c.worst_z <= MAX_Z for c in cars)
    assert [refined_label("car", c) for c in cars] == ["car"] * 4
    bikes = classify_dimensions([[1.33, 0.64, 1.23], [2.15, 0.8, 1.5], [2.3, 0.9, 1.5]])
    assert [refined_label("car", c) for c in bikes] == ["motorcycle"] * 3
    kept = load_benchmark("live_classes").kept_share(4000)  # drawn with the measurement noise, as it measures
    assert kept >= 0.98, (kept, MOTORCYCLE_MARGIN)
