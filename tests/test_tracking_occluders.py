"""Static occluders (tracking/occluders.py) and the tracker behind them.

* the map, from outlines painted with a pole across two streams of traffic and a median strip between them:
  the pole is found, the median (which runs along the motion) is not;
* which box edges touch the occluder, and boxes completed with a track's size;
* a real render of the ``left_side`` preset (seed 0: a lamp pole in front of the near carriageway) through the
  learned segmenter and the library tracking pipeline: with the occluder map the vehicles passing behind the
  pole keep one track each (BrnoCompSpeed counting rule: the false positives go), without it they do not.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gst_trafficcal.tracking.occluders import OccluderMap, complete_boxes
from gst_trafficcal.tracking.tracker import Tracker, TrackerConfig
from gst_trafficcal.detection.records import Detections

SIZE = (640, 360)
POLE = (300, 316)  # columns hidden by the pole
STREAMS = ((100, 140, +1), (200, 240, -1))  # rows of two streams of traffic and their directions; median between


def _stream_hulls(t: float, period: float = 1.2, speed: float = 200.0, length: float = 70.0):
    """Outlines (clipped by the pole, i.e. up to two fragments per vehicle) and velocities of the vehicles at ``t``."""
    hulls, vel = [], []
    for y0, y1, d in STREAMS:
        for k in range(max(0, int(t / period) - 4), int(t / period) + 1):  # vehicle k enters at t = k * period
            start = (t - k * period) * speed
            x0 = start - length if d > 0 else SIZE[0] - start
            x1 = x0 + length
            for a, b in ((x0, min(x1, POLE[0])), (max(x0, POLE[1]), x1)):
                a, b = max(a, 0.0), min(b, SIZE[0] - 1.0)
                if b - a >= 3:
                    hulls.append(np.array([[a, y0], [b, y0], [b, y1], [a, y1]], np.float64))
                    vel.append((d * speed, 0.0))
    return hulls, np.array(vel, np.float64).reshape(-1, 2)


def _learned_map(frames: int = 250) -> OccluderMap:
    occ = OccluderMap()
    for k in range(frames):
        hulls, vel = _stream_hulls(k / 25.0)
        occ.add(SIZE, hulls, vel)
    occ.update_mask()
    return occ


def test_map_finds_a_pole_across_the_traffic_but_not_a_median_along_it():
    occ = _learned_map()
    mask = occ.full_mask()
    assert mask.shape == (SIZE[1], SIZE[0])
    for y0, y1, _ in STREAMS:  # the pole where traffic passes behind it
        inner = mask[y0 + 8:y1 - 8, POLE[0] + 2:POLE[1] - 2]
        assert inner.mean() > 0.9, inner.mean()
    # the median between the streams is never covered either, and vehicles are seen on both sides of it, but
    # across the motion: not an occluder (an isotropic hole filling would mark it)
    assert not mask[STREAMS[0][1] + 4:STREAMS[1][0] - 4].any()
    # nothing away from the pole
    away = mask.copy()
    away[:, POLE[0] - 8:POLE[1] + 8] = False
    assert away.sum() == 0


def test_map_needs_traffic_on_both_sides():
    occ = OccluderMap()
    for k in range(250):  # the same traffic, but it all ends at the pole (a road end, not an occluder)
        hulls, vel = _stream_hulls(k / 25.0)
        keep = [i for i, h in enumerate(hulls) if h[:, 0].max() <= POLE[0]]
        occ.add(SIZE, [hulls[i] for i in keep], vel[keep])
    occ.update_mask()
    assert not occ.ready


def test_cut_sides_of_boxes_at_the_pole():
    occ = _learned_map()
    y0, y1 = STREAMS[0][:2]
    boxes = np.array([[POLE[0] - 50, y0, POLE[0], y1],  # ends at the pole: right edge cut
                      [POLE[1], y0, POLE[1] + 40, y1],  # starts behind it: left edge cut
                      [40, y0, 110, y1],  # far from it
                      [POLE[1] + 60, STREAMS[1][0], POLE[1] + 130, STREAMS[1][1]]], np.float64)
    cut = occ.cut_sides(boxes)
    assert cut.tolist() == [[False, False, True, False], [True, False, False, False],
                            [False, False, False, False], [False, False, False, False]]


def test_complete_boxes_keeps_free_edges_and_takes_the_tracks_size():
    pred = np.array([[95.0, 45, 155, 85], [0, 0, 10, 10]])
    det = np.array([[100.0, 50, 130, 80], [300, 50, 320, 80]])
    cut = np.array([[False, False, True, False], [True, False, False, False]])
    out = complete_boxes(det, cut, pred)
    assert out.shape == (2, 2, 4)
    # right edge cut: the left edge and the predicted width (60); across, the predicted height placed to contain it
    np.testing.assert_allclose(out[0, 0], [100, 45, 160, 85])
    np.testing.assert_allclose(out[0, 1], [260, 45, 320, 85])  # left edge cut: ends at its right edge
    np.testing.assert_allclose(complete_boxes(det, np.zeros((2, 4), bool), pred)[1, 0], det[0])  # nothing cut


def _track_ids_per_vehicle(config: TrackerConfig) -> tuple[Tracker, dict[int, set[int]]]:
    """Feed the painted traffic (no calibration) to the library tracker; the confirmed track ids each vehicle of
    the first stream got after the first 10 s (the map is learned from the traffic before)."""
    tracker = Tracker(config)
    ids: dict[int, set[int]] = {}
    for k in range(400):
        t = k / 25.0
        hulls, _ = _stream_hulls(t)
        boxes = np.array([[h[:, 0].min(), h[:, 1].min(), h[:, 0].max(), h[:, 1].max()] for h in hulls])
        det = Detections(boxes.reshape(-1, 4), np.ones(len(boxes)), np.full(len(boxes), 2),
                         np.full(len(boxes), "car", dtype=object))
        res = tracker.update(t, det, hulls, image_size=SIZE)
        for i, b in enumerate(boxes):
            if t >= 10.0 and res.track_ids[i] and b[1] == STREAMS[0][0]:
                vehicle = int(np.floor((t * 200.0 - (b[0] + b[2]) / 2) / 240.0))  # whose span holds the box centre
                ids.setdefault(vehicle, set()).add(int(res.track_ids[i]))
    return tracker, ids


def test_tracker_keeps_one_track_per_vehicle_through_the_pole():
    """Without a calibration (2D): the vehicles' fragments at the pole and their emergence behind it keep their
    track; the same traffic without the occluder map splits every vehicle in two."""
    tracker, ids = _track_ids_per_vehicle(TrackerConfig())
    assert tracker.occluders.ready
    assert len(ids) >= 6
    assert all(len(v) == 1 for v in ids.values()), ids
    _, split = _track_ids_per_vehicle(TrackerConfig(occluders=False))
    assert sum(len(v) > 1 for v in split.values()) >= len(split) // 2, split


def test_cut_observations_are_not_measured():
    tracker, _ = _track_ids_per_vehicle(TrackerConfig())
    obs = [o for tr in tracker.tracks + tracker.finished for o in tr.observations if o.t >= 10.0]  # map learned
    at_pole = [o for o in obs if abs(o.box[2] - POLE[0]) < 1 or abs(o.box[0] - POLE[1]) < 1]
    assert at_pole and all(o.truncated for o in at_pole)
    free = [o for o in obs if o.box[2] < POLE[0] - 20 and o.box[0] > 20]
    assert free and not any(o.truncated for o in free)


# ---------------------------------------------------------------------------------------------- a real render
# left_side with its default seed has a lamp pole on the near verge, in front of the carriageway that comes
# towards the camera (x = 221..243 at 640 px wide); 20 s at 640x360 and 25 fps with twice the preset's traffic, so
# that many vehicles pass behind it (at 12.5 fps or 480x270 the fragments rarely made tracks of their own)
POLE_SCENE = {"base": "left_side", "duration": 20, "seed": 0, "camera": {"resolution": [640, 360]},
              "traffic": {"flow": 1400}}


@pytest.fixture(scope="module")
def pole_run(tmp_path_factory):
    """The render, its frames and the learned segmenter's detections (run once)."""
    from gst_trafficcal.detection.factory import create_detector, detect
    from gst_trafficcal.synth.generate import generate
    from gst_trafficcal.synth.scenario import scenario_from_dict

    out = tmp_path_factory.mktemp("pole_clip")
    generate(scenario_from_dict(POLE_SCENE), out)
    cap = cv2.VideoCapture(str(out / "video.mp4"))
    detector = create_detector("vehicleseg")
    frames = []
    while True:
        ok, bgr = cap.read()
        if not ok:
            break
        t = cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
        frames.append((t, cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY), detect(detector, bgr, t)))
    return out, frames


def _counting_rule(scene, frames, config: TrackerConfig):
    """Recall and false positives (BrnoCompSpeed's counting rule, the project's evaluator) of the library tracking
    pipeline's tracks, with the scene's true calibration; and the pipeline."""
    from gst_trafficcal.brnocompspeed import BrnoCalibration, Results, Track as BrnoTrack, load_gt_data
    from gst_trafficcal.calibration import load_calibration
    from gst_trafficcal.evaluation import evaluate_speeds, lanes_of_points, prepare_tracks
    from gst_trafficcal.tracking.pipeline import TrackingPipeline

    cal = load_calibration(scene / "calibration.json")
    cam = cal.camera
    gt = load_gt_data(scene / "gt_data.pkl")
    pipe = TrackingPipeline(config=config)
    pipe.set_camera(cam)
    for t, gray, det in frames:
        pipe.process(gray, t, det)
    cars = []
    for tr in pipe.flush():
        px, _ = tr.reference_points()
        ok = np.all(np.isfinite(px), axis=1)
        lanes = lanes_of_points(px[ok], gt.lane_div_lines)
        ok[ok] &= (lanes >= 0) & ~np.isin(lanes, list(gt.invalid_lanes))
        if ok.sum() >= 2:
            cars.append(BrnoTrack(tr.id, np.round(tr.timestamps[ok] * gt.fps).astype(np.int64), px[ok]))
    brno = BrnoCalibration(tuple(cam.vp1), tuple(cam.vp2), tuple(cam.pp), cam.brno_scale())
    report = evaluate_speeds(gt, prepare_tracks(Results(brno, tuple(cars)), gt, *cal.image_size), cam)
    return report.recall, report.false_positives, pipe


def test_render_with_a_pole_one_track_per_vehicle(pole_run):
    scene, frames = pole_run
    recall_off, fp_off, _ = _counting_rule(scene, frames, TrackerConfig(occluders=False, coast_on_road=False))
    recall_on, fp_on, pipe = _counting_rule(scene, frames, TrackerConfig())
    # the scene has the problem: vehicles cut in two by the pole become two tracks, one of them a false positive
    # (measured: 11 false positives without the occluder map and road coasting, 4 with; recall 0.92 both)
    assert fp_off >= 6, (recall_off, fp_off)
    assert fp_on <= fp_off - 4, (fp_off, fp_on)
    assert recall_on >= recall_off - 1e-9, (recall_off, recall_on)
    # the learned occluder is mostly the pole (its columns; in this dense traffic a patch of the far field, where
    # vehicles are small and queue, comes out too)
    mask = pipe.tracker.occluders.full_mask()
    assert mask[:, 205:255].sum() > 500
    assert mask[:, 205:255].sum() >= 0.75 * mask.sum(), (mask[:, 205:255].sum(), mask.sum())
