"""The streaming speed measurement stage on exact simulated tracks (no pixels): speeds, late calibration, reasons."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest

from gst_trafficcal.calibration import Calibration
from gst_trafficcal.measurement import MeasuredVehicle, Sighting, SpeedMeter, speed_params, steady_label
from gst_trafficcal.outputs import AWAY_FROM_VP1, TOWARDS_VP1
from gst_trafficcal.tracking.pipeline import TrackingPipeline
from gst_trafficcal.tracking.simulate import default_camera, simulate
from gst_trafficcal.tracking.tracker import TrackerConfig
from gst_trafficcal.tracking.vehicle_meta import vehicle_fields

SIZE = (960, 540)
LANES = ((-5.25, 1), (-1.75, 1), (1.75, -1), (5.25, -1))


@pytest.fixture(scope="module")
def scene():
    return simulate(default_camera(SIZE), SIZE, duration=24.0, fps=25.0, lanes=LANES, rate=0.35, seed=4)


@pytest.fixture(scope="module")
def scene5():
    """The same traffic at 5 fps (an NVR substream)."""
    return simulate(default_camera(SIZE), SIZE, duration=24.0, fps=5.0, lanes=LANES, rate=0.35, seed=4)


@pytest.fixture(scope="module")
def truth(scene):
    """Per vehicle id: (speed km/h from the world reference points, direction, lane offset y, n frames)."""
    world: dict[int, list] = {}
    for f in scene.frames:
        for i, vid in enumerate(f.ids):
            world.setdefault(int(vid), []).append((f.t, *f.ref_world[i], int(f.directions[i])))
    out = {}
    for vid, rows in world.items():
        a = np.array(rows)
        speed = np.hypot(*(a[-1, 1:3] - a[0, 1:3])) / (a[-1, 0] - a[0, 0]) * 3.6 if len(a) > 1 else np.nan
        out[vid] = (speed, int(a[0, 3]), float(np.median(a[:, 2])), len(a))
    return out


def cal_of(camera, scale=True) -> Calibration:
    cam = camera if scale else camera.with_scale(None)
    return Calibration(camera=cam, image_size=SIZE, state="calibrated" if scale else "vps", source="test")


def sightings(frame, with_3d=True) -> list[Sighting]:
    """Exact sightings of one simulated frame (3D box corners, or only the hull when ``with_3d`` is False)."""
    return [Sighting(int(vid), "car", frame.t, tuple(frame.boxes[i]), 0.9,
                     corners_px=frame.corners_px[i] if with_3d else None,
                     ref_px=frame.ref_px[i] if with_3d else None, hull=frame.hulls[i])
            for i, vid in enumerate(frame.ids)]


def run(scene, meter: SpeedMeter, with_3d=True, calibrate_at: float | None = None, cal=None) -> list[MeasuredVehicle]:
    out = []
    for f in scene.frames:
        if calibrate_at is not None and f.t >= calibrate_at and meter.calibration is None:
            out += meter.set_calibration(cal)
        out += meter.update(f.t, sightings(f, with_3d)).finished
    return out + meter.flush()


def check_against_truth(events: list[MeasuredVehicle], truth, min_track_length=10) -> int:
    """Every vehicle seen long enough is measured within 0.05 km/h, in its direction; returns how many."""
    by_id = {m.event.id: m.event for m in events}
    assert sorted(by_id) == sorted(truth), "one event per vehicle"
    n = 0
    for vid, (speed, direction, _, frames) in truth.items():
        e = by_id[vid]
        if frames < min_track_length:
            assert e.speed_kmh is None and "too short" in e.reason
            continue
        assert e.speed_kmh == pytest.approx(speed, abs=0.05), (vid, e)
        assert e.direction == (TOWARDS_VP1 if direction > 0 else AWAY_FROM_VP1)
        # τ = 5 pairs, further apart for a vehicle covering less than 4 m in five frames (speed.pair_step)
        tau = max(5, min(int(np.ceil(4.0 / (speed / 3.6 / 25.0))), (frames - 1) // 2, frames - 5))
        assert e.n_samples == frames - tau and e.calibration_id is not None
        n += 1
    return n


def test_exact_tracks_give_exact_speeds_directions_and_lanes(scene, truth):
    meter = SpeedMeter(calibration=cal_of(scene.camera))
    events = run(scene, meter)
    assert check_against_truth(events, truth) >= 20
    # lanes: once every lane has been seen, lane k is the k-th GT lane by increasing lateral offset
    offsets = sorted({round(truth[m.event.id][2], 2) for m in events})
    assert len(offsets) == 4
    measured = [m.event for m in events if m.event.measured]
    late = measured[len(measured) // 2:]
    assert [e.lane for e in late] == [offsets.index(round(truth[e.id][2], 2)) for e in late]
    # the BrnoCompSpeed reference points are the exact ones
    m = next(m for m in events if m.event.measured)
    f_ref = {round(f.t, 6): f.ref_px[list(f.ids).index(m.event.id)] for f in scene.frames if m.event.id in f.ids}
    np.testing.assert_allclose(m.points_px, [f_ref[round(t, 6)] for t in m.times_s], atol=1e-6)


def test_vehicles_are_reported_when_they_leave_not_only_at_the_end(scene):
    meter = SpeedMeter(calibration=cal_of(scene.camera), end_after=1.0)
    during = []
    for f in scene.frames:
        for m in meter.update(f.t, sightings(f)).finished:
            assert f.t - m.event.last_timestamp_s > 1.0  # left: unseen for more than end_after
            assert f.t - m.event.last_timestamp_s < 1.0 + 2 / 25
            during.append(m)
    at_end = meter.flush()
    assert len(during) >= 10
    assert all(m.event.last_timestamp_s >= scene.frames[-1].t - 1.0 for m in at_end)  # still in view at the end


def test_live_speed_for_the_roi_structure(scene, truth):
    meter = SpeedMeter(calibration=cal_of(scene.camera))
    seen = {}
    for f in scene.frames:
        out = meter.update(f.t, sightings(f))
        for vid, live in out.speeds.items():
            seen[vid] = live
    assert len(seen) >= 20
    for vid, live in seen.items():
        assert live.speed_kmh == pytest.approx(truth[vid][0], abs=0.05)
        assert live.confidence == 1.0 and live.n_samples >= 5
    p = speed_params(next(iter(seen.values())), "car")
    assert set(p) == {"speed_kmh", "label", "model_name", "confidence", "speed_uncertainty_kmh"}
    assert 0 < p["speed_uncertainty_kmh"] < 0.1 * p["speed_kmh"]


def test_live_speed_uses_a_bounded_window(scene, truth, monkeypatch):
    import gst_trafficcal.measurement as measurement

    monkeypatch.setattr(measurement, "LIVE_WINDOW", 30)
    meter = SpeedMeter(calibration=cal_of(scene.camera))
    n = 0
    for f in scene.frames[:300]:
        for vid, live in meter.update(f.t, sightings(f)).speeds.items():
            assert live.n_samples <= 30 - 5 and live.speed_kmh == pytest.approx(truth[vid][0], abs=0.05)
            n += 1
    assert n > 100


def test_live_speed_is_made_as_often_in_time_at_5_fps(scene5):
    """At 5 fps the ROI's estimate is made again at every observation (0.2 s apart: LIVE_EVERY's 5 frames at 25 fps),
    not every 5 (1 s, the same estimate repeated)."""
    meter = SpeedMeter(calibration=cal_of(scene5.camera))
    last: dict[int, object] = {}
    made = repeated = 0
    for f in scene5.frames:
        for vid, live in meter.update(f.t, sightings(f)).speeds.items():
            if vid in last:
                made += live is not last[vid]
                repeated += live is last[vid]
            last[vid] = live
    assert made > 100 and repeated == 0, (made, repeated)


def test_live_speed_is_made_every_few_frames_and_at_once_with_a_new_scale(scene, truth):
    """The ROI's estimate is made again every LIVE_EVERY observations of a vehicle (the frames between repeat it);
    a new calibration makes every vehicle's again on the next frame."""
    from gst_trafficcal.measurement import LIVE_EVERY

    meter = SpeedMeter(calibration=cal_of(scene.camera))
    history: dict[int, list[float]] = {}
    half = len(scene.frames) // 2
    for f in scene.frames[:half]:
        for vid, live in meter.update(f.t, sightings(f)).speeds.items():
            history.setdefault(vid, []).append(live.speed_kmh)
    for values in history.values():  # a value stands for LIVE_EVERY frames before the next one replaces it
        runs = [len(list(g)) for _, g in itertools.groupby(values)]
        assert all(r % LIVE_EVERY == 0 for r in runs[:-1])
    assert sum(len(v) >= 3 * LIVE_EVERY for v in history.values()) >= 5
    before = {vid: v[-1] for vid, v in history.items()}
    meter.set_calibration(cal_of(scene.camera.with_scale(scene.camera.scale * 1.1)))
    f = scene.frames[half]
    after = meter.update(f.t, sightings(f)).speeds
    both = [vid for vid in after if vid in before]
    assert len(both) >= 3
    for vid in both:  # the same vehicle, one frame later, measured at the new scale
        assert after[vid].speed_kmh == pytest.approx(1.1 * before[vid], rel=0.02)


def test_vehicles_seen_before_the_vanishing_points_are_measured_when_they_come(scene, truth):
    """No calibration for the first 12 s: boxes come from the kept hulls; one pass measures every vehicle."""
    meter = SpeedMeter()
    events = run(scene, meter, with_3d=False, calibrate_at=12.0, cal=cal_of(scene.camera))
    early = [m for m in events if m.event.last_timestamp_s < 11.0]
    assert len(early) >= 5
    check_against_truth(events, truth)


def test_hull_box_alone_is_enough_when_the_vanishing_points_come_late(scene, truth):
    """An upstream tracker's structure carries only the hull's box: the 3D box from that rectangle (measured:
    within 0.07 km/h on these exact boxes)."""
    meter = SpeedMeter()
    events = []
    for f in scene.frames:
        boxes_only = [Sighting(int(v), "car", f.t, tuple(f.boxes[i])) for i, v in enumerate(f.ids)]
        events += meter.update(f.t, boxes_only).finished
    events += meter.set_calibration(cal_of(scene.camera)) + meter.flush()
    measured = [m.event for m in events if m.event.measured]
    assert len(measured) >= 20
    for e in measured:
        assert e.speed_kmh == pytest.approx(truth[e.id][0], abs=0.2), e


def test_vehicles_wait_for_the_scale(scene, truth):
    meter = SpeedMeter(calibration=cal_of(scene.camera, scale=False))
    out = []
    for f in scene.frames[: len(scene.frames) // 2]:
        out += meter.update(f.t, sightings(f)).finished
    assert out == [] and meter.waiting >= 3  # left, but no scale yet
    out += meter.set_calibration(cal_of(scene.camera))
    assert len(out) >= 3 and all(m.event.speed_kmh is not None or "short" in m.event.reason for m in out)
    for f in scene.frames[len(scene.frames) // 2:]:
        out += meter.update(f.t, sightings(f)).finished
    check_against_truth(out + meter.flush(), truth)


def test_at_most_max_waiting_vehicles_wait_for_the_scale_the_oldest_go_out_unmeasured(scene, truth):
    """A camera that does not calibrate: beyond ``max_waiting`` vehicles the oldest is written unmeasured as the next
    one leaves (bounded memory; the counts reach the files); those still held are measured when the scale comes."""
    meter = SpeedMeter(calibration=cal_of(scene.camera, scale=False), max_waiting=2)
    half = len(scene.frames) // 2
    out = []
    for f in scene.frames[:half]:
        finished = meter.update(f.t, sightings(f)).finished
        assert meter.waiting <= 2
        out += finished
    assert len(out) >= 2 and meter.waiting == 2
    assert all(m.event.speed_kmh is None and "while 2 later vehicles left" in m.event.reason for m in out)
    gone = [m.event.last_timestamp_s for m in out]
    held = meter.set_calibration(cal_of(scene.camera))
    assert len(held) == 2 and min(m.event.last_timestamp_s for m in held) >= max(gone)  # the oldest went first
    for f in scene.frames[half:]:
        out += meter.update(f.t, sightings(f)).finished
    events = out + held + meter.flush()
    assert sorted(m.event.id for m in events) == sorted(truth)  # every vehicle once
    with pytest.raises(ValueError, match="max_waiting"):
        SpeedMeter(max_waiting=0)


@pytest.mark.parametrize("cal, words", [(None, "no calibration"), ("vps", "no scale")])
def test_stream_ending_before_calibration_reports_every_vehicle_unmeasured(scene, truth, cal, words):
    meter = SpeedMeter(calibration=None if cal is None else cal_of(scene.camera, scale=False))
    events = run(scene, meter)
    assert sorted(m.event.id for m in events) == sorted(truth)
    assert all(m.event.speed_kmh is None and words in m.event.reason for m in events)


def test_dropped_frames_use_timestamps(truth):
    scene = simulate(default_camera(SIZE), SIZE, duration=24.0, fps=25.0, lanes=LANES, rate=0.35, seed=4, drop=0.3)
    meter = SpeedMeter(calibration=cal_of(scene.camera))
    events = run(scene, meter)
    measured = [m.event for m in events if m.event.measured]
    assert len(measured) >= 15
    for e in measured:
        assert e.speed_kmh == pytest.approx(truth[e.id][0], abs=0.05)


def test_sightings_from_the_tracker_structure_match_the_tracker(scene, truth):
    """Through the real tracker and the "trafficcal-vehicle" fields it writes (what the element reads)."""
    cal = cal_of(scene.camera)
    pipe = TrackingPipeline(config=TrackerConfig(), background=None)
    pipe.set_camera(scene.camera)
    meter = SpeedMeter(calibration=cal)
    events = []
    from gst_trafficcal.detection.records import Detections
    for f in scene.frames:
        det = Detections(f.boxes, np.full(len(f.ids), 0.9), np.full(len(f.ids), 2), np.full(len(f.ids), "car", object))
        result = pipe.tracker.update(f.t, det, f.hulls, image_size=SIZE)
        sights = []
        for i in range(len(det)):
            tr = result.track_of(i)
            if tr is not None:
                fields = vehicle_fields(tr, tr.last, scene.camera, cal.id)
                sights.append(Sighting.from_fields(tr.id, tr.label, 0.9, fields))
        events += meter.update(f.t, sights).finished
    events += meter.flush()
    measured = [m.event for m in events if m.event.measured]
    assert len(measured) >= 15
    # tracker ids are its own: compare the set of speeds with the truth's (each within 0.5 km/h of a true one)
    true_speeds = np.array([s for s, _, _, n in truth.values() if n >= 10])
    for e in measured:
        assert np.abs(true_speeds - e.speed_kmh).min() < 0.5, e


def test_a_truck_never_seen_whole_is_measured_through_the_tracker_structure():
    """A truck whose roof stays above a steep camera's frame while its front is in view: the tracker writes the
    boxes of its top-cut silhouettes (``cut_top``, ``box3d`` without a reference point) and the meter, which
    measures from the structure alone, gives its speed."""
    from gst_trafficcal.detection.records import Detections
    from gst_trafficcal.tracking.simulate import vehicle_passing

    cam = default_camera(SIZE, tilt=20.0, height=7.0, hfov=40.0)
    scene = vehicle_passing(cam, (16.5, 2.5, 4.0), lane=1.75, x_start=60.0, speed_kmh=80.0, direction=-1,
                            image_size=SIZE)
    cal = cal_of(cam)
    pipe = TrackingPipeline(config=TrackerConfig(), background=None)
    pipe.set_camera(cam)
    meter = SpeedMeter(calibration=cal)
    events, cut = [], 0
    for f in scene.frames:
        det = Detections(f.boxes, np.array([0.9]), np.array([7]), np.array(["truck"], dtype=object))
        tr = pipe.tracker.update(f.t, det, f.hulls, image_size=SIZE).track_of(0)
        sights = []
        if tr is not None:
            fields = vehicle_fields(tr, tr.last, cam, cal.id)
            if fields["cut_top"]:
                cut += 1
                assert fields["truncated"] and "box3d" in fields and "ref_x" not in fields
            sights.append(Sighting.from_fields(tr.id, tr.label, 0.9, fields))
        events += meter.update(f.t, sights).finished
    events += meter.flush()
    assert cut >= 30
    (event,) = [m.event for m in events]
    assert event.measured and event.speed_kmh == pytest.approx(80.0, abs=0.1)
    assert event.direction == AWAY_FROM_VP1  # coming towards the camera, away from VP1


def test_bad_settings_and_time_going_backwards(scene):
    with pytest.raises(ValueError, match="min_track_length"):
        SpeedMeter(tau=5, min_track_length=5)
    with pytest.raises(ValueError, match="tau"):
        SpeedMeter(tau=0)
    meter = SpeedMeter()
    meter.update(1.0, [])
    with pytest.raises(ValueError, match="backwards"):
        meter.update(0.5, [])


def _longest_overlapping_pair(scene):
    """Two vehicles of the same direction in view together for the most frames: (id a, id b, frames)."""
    seen: dict[int, set] = {}
    direction = {}
    for k, f in enumerate(scene.frames):
        for i, vid in enumerate(f.ids):
            seen.setdefault(int(vid), set()).add(k)
            direction[int(vid)] = int(f.directions[i])
    pairs = [(len(seen[a] & seen[b]), a, b) for a in seen for b in seen
             if a < b and direction[a] == direction[b]]
    n, a, b = max(pairs)
    return a, b, sorted(seen[a] & seen[b])


def test_id_switch_is_measured_from_the_vehicle_with_most_points_only(scene, truth):
    """The tracker's id jumps from vehicle a to vehicle b half way through their common frames (an ID switch):
    the event for a's id gets the speed of the part with more points, and the results file only its points."""
    a, b, common = _longest_overlapping_pair(scene)
    switch = scene.frames[common[len(common) // 3]].t  # a's id follows b from here on
    meter = SpeedMeter(calibration=cal_of(scene.camera))
    events = []
    for f in scene.frames:
        ss = []
        for s in sightings(f):
            if s.id == a and f.t >= switch:
                continue  # a is lost...
            if s.id == b and f.t >= switch:
                s = Sighting(a, s.label, s.t, s.box, s.confidence, corners_px=s.corners_px, ref_px=s.ref_px,
                             hull=s.hull)  # ...and its id follows b
            ss.append(s)
        events += meter.update(f.t, ss).finished
    events += meter.flush()
    m = next(m for m in events if m.event.id == a)
    n_a = sum(1 for f in scene.frames if f.t < switch and a in f.ids)
    n_b = sum(1 for f in scene.frames if f.t >= switch and b in f.ids)
    kept = b if n_b > n_a else a
    assert m.event.measured and m.event.speed_kmh == pytest.approx(truth[kept][0], abs=0.05)
    assert len(m.times_s) == max(n_a, n_b)
    assert np.all(m.times_s >= switch) if kept == b else np.all(m.times_s < switch)


def test_two_sightings_with_one_id_in_a_frame_keep_the_vehicle_the_track_follows(scene, truth):
    """A tracker that gives vehicle b's sighting a's id too (two sightings with one id in a frame, for as long as
    both are in view): a's track keeps the sighting that continues its motion, b is measured from its own, every
    vehicle exactly; the dropped sightings are counted for the caller to say. Before, both went into a's points
    and a was reported with a speed that was neither vehicle's, or unmeasured, without a word."""
    from dataclasses import replace

    first, second, common = _longest_overlapping_pair(scene)
    for a, b in ((first, second), (second, first)):  # a seen first (a track to continue), or b (a new track)
        meter = SpeedMeter(calibration=cal_of(scene.camera))
        events = []
        for f in scene.frames:
            ss = sightings(f)
            ids = [s.id for s in ss]
            if a in ids and b in ids:
                ss.insert(ids.index(a), replace(ss[ids.index(b)], id=a))  # before a's own: not kept for coming first
            events += meter.update(f.t, ss).finished
        events += meter.flush()
        check_against_truth(events, truth)
        assert meter.duplicates == len(common) and meter.first_duplicate == (a, scene.frames[common[0]].t)


def test_a_time_that_is_no_number_is_refused(scene):
    """A frame or a sighting with a NaN time (a buffer without a timestamp taken as NaN) is a ValueError, as a
    time going backwards is; it used to be taken in silence: a vehicle last seen at NaN never left."""
    meter = SpeedMeter(calibration=cal_of(scene.camera))
    with pytest.raises(ValueError, match="a frame's time must be a finite number of seconds, got nan"):
        meter.update(float("nan"), [])
    s = sightings(scene.frames[10])[0]
    with pytest.raises(ValueError, match=rf"vehicle {s.id}: its time must be a finite number of seconds, got nan"):
        meter.update(1.0, [Sighting(s.id, s.label, float("nan"), s.box)])
    assert meter.t is None  # the refused frames left nothing behind
    meter.update(0.5, [s])


def test_degenerate_3d_boxes_are_ignored(scene, truth):
    """Some sightings carry a 3D box whose base is at the camera's foot, far outside the image (a degenerate
    box solve upstream): those frames give no reference point, the vehicle is still measured exactly."""
    meter = SpeedMeter(calibration=cal_of(scene.camera))
    events = []
    for k, f in enumerate(scene.frames):
        ss = sightings(f)
        if k % 3 == 0:
            ss = [Sighting(s.id, s.label, s.t, s.box, s.confidence,
                           corners_px=np.vstack([np.tile([480.0, 9000.0], (4, 1)), s.corners_px[4:]]),
                           ref_px=np.array([480.0, 9000.0]), hull=s.hull) for s in ss]
        events += meter.update(f.t, ss).finished
    events += meter.flush()
    measured = [m for m in events if m.event.measured]
    assert len(measured) >= 20
    for m in measured:
        assert m.event.speed_kmh == pytest.approx(truth[m.event.id][0], abs=0.05)
        assert np.all(m.points_px[:, 1] < SIZE[1])


def test_vehicles_never_seen_whole_keep_their_direction(scene, truth):
    """A vehicle without a single 3D box (always truncated) is not measured, but its event still says which way it
    went (from its 2D boxes), so the counts per direction hold it; one seen in a single frame has none."""
    meter = SpeedMeter(calibration=cal_of(scene.camera))
    events = []
    for f in scene.frames:
        events += meter.update(f.t, [Sighting(s.id, s.label, s.t, s.box, s.confidence, truncated=True)
                                     for s in sightings(f, with_3d=False)]).finished
    events += meter.flush()
    assert sorted(m.event.id for m in events) == sorted(truth)
    assert all(m.event.speed_kmh is None and m.event.lane is None for m in events)
    assert all(m.event.reason.startswith("no reference point") for m in events if truth[m.event.id][3] >= 10)
    for m in events:
        direction, frames = truth[m.event.id][1], truth[m.event.id][3]
        assert m.event.direction == (None if frames < 2 else TOWARDS_VP1 if direction > 0 else AWAY_FROM_VP1), m


def test_wandering_reference_points_are_reported_unmeasured(scene, truth):
    """A vehicle whose reference point wanders along it (blobs merging and splitting) gives τ-pair speeds that
    disagree: it is reported with the reason and no points (so the results file does not carry it), and it has
    no live speed on its ROI."""
    vid = max(truth, key=lambda v: truth[v][3])
    rng = np.random.default_rng(2)
    meter = SpeedMeter(calibration=cal_of(scene.camera))
    events, live = [], []
    for f in scene.frames:
        ss = []
        for s in sightings(f):
            if s.id == vid:  # slide the whole box along the road by up to +-1.2 m each frame
                X = scene.camera.to_world(s.corners_px[:4])
                X[:, 0] += rng.uniform(-1.2, 1.2)
                corners = np.vstack([scene.camera.world_to_image(X), s.corners_px[4:]])
                s = Sighting(s.id, s.label, s.t, s.box, s.confidence, corners_px=corners, ref_px=None, hull=s.hull)
            ss.append(s)
        out = meter.update(f.t, ss)
        events += out.finished
        live.append(vid in out.speeds)
    events += meter.flush()
    m = next(m for m in events if m.event.id == vid)
    assert not m.event.measured and "disagree" in m.event.reason
    assert len(m.points_px) == 0 and len(m.times_s) == 0
    assert not any(live)
    assert sum(e.event.measured for e in events) >= 20  # the others are not affected


def test_a_vehicle_lost_for_a_moment_is_measured_as_one(scene, truth):
    """The detector loses a vehicle for 0.4 s and the tracker gives it a new id: the two tracks are one vehicle
    (reported once, under the later id, measured over both); no other vehicle of the scene is joined to another."""
    vid = max(truth, key=lambda v: truth[v][3])
    times = [f.t for f in scene.frames if vid in f.ids]
    cut = times[len(times) // 2]
    new_id = 10_000
    meter = SpeedMeter(calibration=cal_of(scene.camera))
    events = []
    for f in scene.frames:
        ss = []
        for s in sightings(f):
            if s.id == vid and cut <= f.t < cut + 0.4:
                continue  # lost
            if s.id == vid and f.t >= cut + 0.4:
                s = Sighting(new_id, s.label, s.t, s.box, s.confidence, corners_px=s.corners_px, ref_px=s.ref_px,
                             hull=s.hull)
            ss.append(s)
        events += meter.update(f.t, ss).finished
    events += meter.flush()
    by_id = {m.event.id: m for m in events}
    assert vid not in by_id and len(events) == len(truth)  # nothing else joined, nothing lost
    m = by_id[new_id]
    assert m.event.first_timestamp_s == pytest.approx(times[0]) and m.event.last_timestamp_s == pytest.approx(times[-1])
    assert m.event.speed_kmh == pytest.approx(truth[vid][0], abs=0.05)
    assert len(m.times_s) == len(times) - round(0.4 * 25)
    assert m.merged_ids == (vid,) and all(e.merged_ids == () for e in events if e is not m)  # for the counters
    others = [e for e in events if e.event.id != new_id]
    check_against_truth(others, {v: t for v, t in truth.items() if v != vid})
    # without stitching: two vehicles
    meter = SpeedMeter(calibration=cal_of(scene.camera), stitch_gap=0)
    n = 0
    for f in scene.frames:
        ss = [s if not (s.id == vid and f.t >= cut + 0.4) else
              Sighting(new_id, s.label, s.t, s.box, s.confidence, corners_px=s.corners_px, hull=s.hull)
              for s in sightings(f) if not (s.id == vid and cut <= f.t < cut + 0.4)]
        n += len(meter.update(f.t, ss).finished)
    assert n + len(meter.flush()) == len(truth) + 1



def test_a_vehicle_lost_for_a_moment_before_the_calibration_is_one_vehicle(scene, truth):
    """As above, but both tracks leave before any calibration exists (vpdetect learns for the first 25 s of a file):
    when the calibration with scale comes, the waiting vehicles are stitched as those that leave later are — one
    vehicle, under the later id.  Before stop 54 they were measured as they stood: the synth left_side scene
    reported four vehicles twice that way (docs/speedometer.md "Stop 54")."""
    early = {v: t for v, t in truth.items() if t[3] >= 60 and _last_time(scene, v) < 12.0}
    vid = max(early, key=lambda v: early[v][3])
    times = [f.t for f in scene.frames if vid in f.ids]
    cut, new_id = times[len(times) // 2], 10_000

    def count(stitch_gap: float) -> list[MeasuredVehicle]:
        meter, out = SpeedMeter(stitch_gap=stitch_gap), []
        for f in scene.frames:
            if f.t >= 18.0 and meter.calibration is None:
                assert meter.waiting >= 3
                out += meter.set_calibration(cal_of(scene.camera))
            ss = [s if not (s.id == vid and f.t >= cut + 0.4) else replace(s, id=new_id)
                  for s in sightings(f, with_3d=False) if not (s.id == vid and cut <= f.t < cut + 0.4)]
            out += meter.update(f.t, ss).finished
        return out + meter.flush()

    events = count(1.0)
    by_id = {m.event.id: m for m in events}
    assert vid not in by_id and len(events) == len(truth)  # nothing else joined, nothing lost
    m = by_id[new_id]
    assert m.merged_ids == (vid,) and m.event.first_timestamp_s == pytest.approx(times[0])
    assert m.event.speed_kmh == pytest.approx(truth[vid][0], rel=0.03)
    assert len(count(0.0)) == len(truth) + 1  # without stitching: two vehicles


def _last_time(scene, vid: int) -> float:
    return max(f.t for f in scene.frames if vid in f.ids)

def _moved(t: float) -> Calibration:
    return Calibration(None, SIZE, state="learning", source="vpdetect", reason=f"the camera moved at {t} s",
                       moved_at=t)


def test_a_moved_camera_ends_what_the_old_view_saw_with_its_calibration(scene, truth):
    """vpdetect says at 12.6 s that the camera moved at 12 s: every vehicle seen before is measured with the old
    calibration (those in view cut at 12 s, their ids not taken up again), the vehicles after wait for the new
    calibration (here the same camera at a 10 % larger scale, so that which one measured a vehicle shows)."""
    old = cal_of(scene.camera)
    new = cal_of(scene.camera.with_scale(scene.camera.scale * 1.1))
    meter = SpeedMeter(calibration=old)
    out = []
    for f in scene.frames:
        if meter.calibration is old and f.t >= 12.6:
            cut = meter.set_calibration(_moved(12.0))
            assert len(cut) >= 3 and all(m.event.last_timestamp_s < 12.0 for m in cut)
            out += cut
        if meter.calibration is not old and meter.calibration is not new and f.t >= 20.0:
            out += meter.set_calibration(new)
        out += meter.update(f.t, sightings(f)).finished
    out += meter.flush()
    ids = [m.event.id for m in out]
    assert len(ids) == len(set(ids)), "one event per vehicle: a track cut by the move does not come back"
    before = [m.event for m in out if m.event.first_timestamp_s < 12.0]
    after = [m.event for m in out if m.event.first_timestamp_s >= 12.0]
    assert len(before) >= 10 and len(after) >= 5
    assert all(e.calibration_id == old.id and e.last_timestamp_s < 12.0 for e in before)
    assert all(e.calibration_id == new.id for e in after)
    for e in before + after:  # constant speeds: a cut track measures its vehicle's speed
        if e.measured:
            k = 1.0 if e.calibration_id == old.id else 1.1
            assert e.speed_kmh == pytest.approx(k * truth[e.id][0], abs=0.1), e
    assert sum(e.measured for e in before) >= 8 and sum(e.measured for e in after) >= 4


def test_a_camera_moved_before_the_scale_reports_the_old_views_vehicles_unmeasured(scene, truth):
    meter = SpeedMeter(calibration=cal_of(scene.camera, scale=False))
    out = []
    for f in scene.frames[: 12 * 25]:
        out += meter.update(f.t, sightings(f)).finished
    assert out == [] and meter.waiting >= 3
    out += meter.set_calibration(_moved(11.5))
    assert meter.waiting == 0 and len(out) >= 6
    assert all(not m.event.measured and "the camera moved at 11.5 s, before the calibration of the view it was seen "
               "in had a scale" in m.event.reason for m in out)


def test_tracks_seen_only_between_a_move_and_its_notice_are_not_vehicles(scene, truth):
    """The camera moved at 12 s, noticed at 13.6 s; the tracker starts again at the notice (new ids).  What the
    old view's background made of the shifted picture in between — here the real sightings of 12–13.6 s under
    ids of their own, plus a one-frame blob — is not reported; the vehicles themselves are, once, under the ids
    they get after the notice; a track of the window that the tracker carries on past the notice is a vehicle."""
    meter = SpeedMeter(calibration=cal_of(scene.camera))
    out, blind_ids, carried = [], set(), None
    for f in scene.frames:
        if meter.calibration.moved_at is None and f.t >= 13.6:
            out += meter.set_calibration(_moved(12.0))
        ss = []
        for s in sightings(f):
            if 12.0 <= f.t < 13.6:  # the window: other ids, a tracker that does not know yet
                if carried is None and f.t >= 13.0:
                    carried = s.id + 20_000  # this one goes on after the notice under the same id
                new = s.id + (20_000 if s.id + 20_000 == carried else 10_000)
                blind_ids.add(new)
                s = Sighting(new, s.label, s.t, s.box, s.confidence, corners_px=s.corners_px, hull=s.hull)
            elif f.t >= 13.6:  # started again at the notice
                new = carried if s.id + 20_000 == carried else s.id + 30_000
                s = Sighting(new, s.label, s.t, s.box, s.confidence, corners_px=s.corners_px, hull=s.hull)
            ss.append(s)
        if 12.0 <= f.t < 12.04:
            ss.append(Sighting(99_999, "car", f.t, (10.0, 10.0, 40.0, 30.0), 0.5))  # a blob for one frame
            blind_ids.add(99_999)
        out += meter.update(f.t, ss).finished
    out += meter.flush()
    ids = {m.event.id for m in out}
    assert carried in ids and not (ids & (blind_ids - {carried}))
    assert meter.discarded == len(blind_ids) - 1 >= 3
    assert all(m.event.first_timestamp_s < 12.0 or m.event.first_timestamp_s >= 13.6 or m.event.id == carried
               for m in out)


def test_tracks_that_are_no_vehicle_passing_are_not_reported(scene, truth):
    """Beside the simulated traffic: a piece of a vehicle tracked under an id of its own for 0.2 s, a parked
    car (one vehicle's box held still for 6 s, its track on a passing vehicle for 0.6 s of them), a box creeping
    1.5 m along the road in 2 s, one going 6 m, and a second track on a vehicle starting in the last 0.4 s.  The
    piece, the parked car and the 1.5 m one are no vehicles passing — not reported, counted by reason, their ids
    handed out once —; the 6 m one and the track the end of the stream cut short are vehicles, as is every
    simulated one."""
    from gst_trafficcal.measurement import BRIEF, STATIONARY, not_a_vehicle

    meter = SpeedMeter(calibration=cal_of(scene.camera))
    still = next(s for f in scene.frames[200:] for s in sightings(f))  # a box somewhere on the road
    end = scene.frames[-1].t
    out = []
    for f in scene.frames:
        ss = sightings(f)
        if 5.0 <= f.t < 5.2 and ss:  # a second track on the first vehicle in view, for five frames
            s = ss[0]
            ss.append(Sighting(70_001, s.label, s.t, s.box, s.confidence, corners_px=s.corners_px, hull=s.hull))
        if 8.0 <= f.t < 14.0:  # parked; for 0.6 s its track is on a vehicle passing it (merged with it)
            s = ss[0] if 10.0 <= f.t < 10.6 and ss else still
            ss.append(Sighting(70_002, "car", f.t, s.box, 0.9, corners_px=s.corners_px, hull=s.hull))
        for vid, metres in ((70_004, 1.5), (70_005, 6.0)):  # creeping along the road for 2 s
            if 15.0 <= f.t < 17.0:
                X = scene.camera.to_world(still.corners_px[:4])
                X[:, 0] += metres * (f.t - 15.0) / 2.0
                corners = np.vstack([scene.camera.world_to_image(X), still.corners_px[4:]])
                ss.append(Sighting(vid, "car", f.t, still.box, 0.9, corners_px=corners))
        if f.t > end - 0.4 and ss:  # a second track on the first vehicle in view, cut by the end
            s = ss[0]
            ss.append(Sighting(70_003, s.label, s.t, s.box, s.confidence, corners_px=s.corners_px, hull=s.hull))
        out += meter.update(f.t, ss).finished
    out += meter.flush()
    ids = [m.event.id for m in out]
    assert sorted(ids) == sorted([*truth, 70_003, 70_005])
    assert meter.not_counted == {BRIEF: 1, STATIONARY: 2}
    assert sorted(meter.take_not_counted_ids()) == [70_001, 70_002, 70_004] and meter.take_not_counted_ids() == []
    assert not_a_vehicle(0.4, None) == BRIEF and not_a_vehicle(2.0, 2.9) == STATIONARY
    assert not_a_vehicle(0.5, None) == not_a_vehicle(2.0, 3.0) == ""


@pytest.mark.parametrize("missed", [False, True])
@pytest.mark.parametrize("fps", [25, 5])
def test_a_vehicle_that_stands_then_drives_off_unmeasured_is_still_reported(scene, scene5, truth, fps, missed):
    """A box standing for 16 s (a queue at lights) that then drives 16 m off in 4 s, from a standstill: left without
    a speed, it is still a vehicle passing, as trafficoverlay's counter has it (its latest points drove steadily
    along the road).  The quarter medians of its whole stay alone took it for a parked one (its last quarter mostly
    stands) and it was not reported.  At 5 fps the latest points are those of 2.6 s, as at 25 fps (13, not 64:
    12.8 s there, mostly standing, and it was not reported).  ``missed``: it drives off at 8 m/s and the detector
    misses it for 0.6 s after its first second of driving; the points after the miss, 4.8 m on, start another
    consistent run than the standing one, and the drive-off was judged on that longest run alone (its latest points
    mostly standing): "stationary", not reported, while the overlay, judging all the latest points, counted it."""
    scene = scene if fps == 25 else scene5
    meter = SpeedMeter(calibration=cal_of(scene.camera))
    still = next(s for f in scene.frames[8 * fps:] for s in sightings(f))
    out = []
    for f in scene.frames:
        ss = sightings(f)
        if 2.0 <= f.t < 22.0 and not (missed and 19.0 <= f.t < 19.6):
            X = scene.camera.to_world(still.corners_px[:4])
            s = max(0.0, f.t - 18.0)
            X[:, 0] += 8.0 * s if missed else s ** 2
            corners = np.vstack([scene.camera.world_to_image(X), still.corners_px[4:]])
            ss.append(Sighting(70_006, "car", f.t, still.box, 0.9, corners_px=corners))
        out += meter.update(f.t, ss).finished
    out += meter.flush()
    mine = [m.event for m in out if m.event.id == 70_006]
    assert len(mine) == 1 and mine[0].speed_kmh is None and mine[0].reason, mine
    assert not meter.not_counted and 70_006 not in meter.take_not_counted_ids()


def test_remeasure_measures_the_early_vehicles_again_with_the_final_calibration(scene, truth):
    """keep_measured (a file): the scale moves by 10 % at 16 s; at the end remeasure() measures every vehicle that
    left under the first scale again with the final one (same ids, the final calibration's id, speeds 10 % up),
    leaves the later ones alone, and forgets them; without keep_measured it has nothing to do."""
    first = cal_of(scene.camera)
    final = cal_of(scene.camera.with_scale(scene.camera.scale * 1.1))
    meter = SpeedMeter(calibration=first, keep_measured=True)
    out = []
    for f in scene.frames:
        if meter.calibration is first and f.t >= 16.0:
            out += meter.set_calibration(final)
        out += meter.update(f.t, sightings(f)).finished
    out += meter.flush()
    early = {m.event.id: m.event for m in out if m.event.calibration_id == first.id}
    assert len(early) >= 6 and len(out) - len(early) >= 5
    again = meter.remeasure()
    assert sorted(m.event.id for m in again) == sorted(early)
    assert [m.event.last_timestamp_s for m in again] == sorted(m.event.last_timestamp_s for m in again)
    for m in again:
        e, was = m.event, early[m.event.id]
        assert e.calibration_id == final.id and e.measured == was.measured
        if e.measured:
            assert e.speed_kmh == pytest.approx(1.1 * was.speed_kmh, rel=1e-6)
            assert e.speed_kmh == pytest.approx(1.1 * truth[e.id][0], abs=0.1)
            assert len(m.points_px) == len(m.times_s) > 0
    assert meter.remeasure() == []  # forgotten
    plain = SpeedMeter(calibration=first)
    run(scene, plain)
    plain.set_calibration(final)
    assert plain.remeasure() == []


def test_remeasure_leaves_the_vehicles_of_a_view_before_a_camera_move(scene, truth):
    """Vehicles measured before the camera moved belong to the old view: remeasure() never measures them with the
    new view's calibration."""
    old = cal_of(scene.camera)
    new = cal_of(scene.camera.with_scale(scene.camera.scale * 1.1))
    meter = SpeedMeter(calibration=old, keep_measured=True)
    for f in scene.frames:
        if meter.calibration is old and f.t >= 12.6:
            meter.set_calibration(_moved(12.0))
        if meter.calibration is not old and meter.calibration is not new and f.t >= 20.0:
            meter.set_calibration(new)
        meter.update(f.t, sightings(f))
    meter.flush()
    assert all(m.event.first_timestamp_s >= 12.0 for m in meter.remeasure())


def test_a_live_class_changes_only_when_two_refreshes_in_a_row_give_it() -> None:
    """A vehicle whose size lies between two classes gets car, van, car, van from its refreshes: it keeps showing
    the first; one that keeps giving van switches at the second."""
    def shown(sizes: list[str]) -> list[str]:
        out, state = [], ("", "")
        for new in sizes:
            state = steady_label(*state, new)
            out.append(state[0])
        return out

    assert shown(["car", "van", "car", "van", "car"]) == ["car"] * 5
    assert shown(["car", "van", "van", "van", "car", "truck", "truck"]) == ["car", "car", "van", "van", "van", "van",
                                                                            "truck"]
    assert shown(["motorcycle"]) == ["motorcycle"]


def test_a_frame_with_the_time_of_the_frame_before_is_left_out_of_the_speeds(scene, truth):
    """Every 4th frame stamped with the time of the frame before it (a recorder repeating a timestamp; the stream
    clock gives a frame out of order the time before it): its sightings lie a frame further on at no later time, so
    τ-pairs across one were a fifth too fast, the points disagreed with the vehicle's motion and no vehicle was
    measured.  They are left out of the tracks: the speeds stay exact."""
    meter = SpeedMeter(calibration=cal_of(scene.camera))
    out, prev = [], None
    for k, f in enumerate(scene.frames):
        t = prev if k % 4 == 3 and prev is not None else f.t
        out += meter.update(t, [replace(s, t=t) for s in sightings(f)]).finished
        prev = t
    measured = [m.event for m in out + meter.flush() if m.event.measured]
    assert len(measured) >= 15
    for e in measured:
        assert e.speed_kmh == pytest.approx(truth[e.id][0], abs=0.05), e
    frames = scene.frames  # the vehicles already seen in the frame before (a track's first sighting is kept)
    assert meter.same_time == sum(len(set(f.ids) & set(frames[k - 1].ids)) for k, f in enumerate(frames) if k % 4 == 3)
