"""``PeeledBackground``: the background detector's peeled foreground as the tracker's hull source."""

from __future__ import annotations

import numpy as np
import pytest

from gst_trafficcal.detection.background import BackgroundDetector
from gst_trafficcal.errors import InputError
from gst_trafficcal.tracking.peeled import PeeledBackground
from gst_trafficcal.tracking.pipeline import TrackingPipeline

from .test_detection_background import _road_clip

pytestmark = pytest.mark.shared


def _hull_right_edges(pipe: TrackingPipeline, frames, truth, detect) -> list[float]:
    out = []
    for k, (frame, box) in enumerate(zip(frames, truth)):
        res, used = pipe.process(frame, k / 25.0, detect(frame))
        if box[2] == 0 or not len(used):
            continue
        i = int(np.argmax(used.boxes[:, 2] - used.boxes[:, 0]))
        tr = pipe.tracker.tracks
        obs = [t.last for t in tr if t.last_t == k / 25.0 and np.allclose(t.last.det_box, used.boxes[i])]
        if obs and obs[0].hull is not None:
            out.append(float(obs[0].hull[:, 0].max()) - box[2])
    return out


def test_hull_ends_at_the_vehicle_not_at_its_shadow():
    """A silver vehicle with a 45 px cast shadow on a real road: the peeled mask's hull stops at the vehicle."""
    frames, truth = _road_clip("grey")
    det = BackgroundDetector(method="average")
    peeled = _hull_right_edges(TrackingPipeline(background=PeeledBackground()), frames, truth, det)
    assert len(peeled) >= 20
    assert abs(np.median(peeled)) <= 8, peeled


def test_shares_a_detector_run_by_the_caller():
    frames, _ = _road_clip("grey")
    det = BackgroundDetector(method="average")
    shared = PeeledBackground(det)
    own = PeeledBackground()
    for frame in frames:
        det(frame)
        a, b = shared.use(), own.apply(frame)
    assert shared.ready and own.ready and shared.scale == own.scale == 2.0
    np.testing.assert_array_equal(a, b)
    assert a.any()


def test_needs_the_peeling_detector():
    with pytest.raises(InputError):
        PeeledBackground(BackgroundDetector(method="mog2"))
