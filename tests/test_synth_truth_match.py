"""Measured vehicles matched to a render's per-frame truth (synth.truth_match): speed error, class and size."""

from __future__ import annotations

import json

import numpy as np

from gst_trafficcal.brnocompspeed import load_results
from gst_trafficcal.calibration import Calibration
from gst_trafficcal.outputs import BrnoResultsWriter, VehicleEvent
from gst_trafficcal.synth.truth_match import label_accuracy, match_measured
from gst_trafficcal.tracking.simulate import default_camera

SIZE = (960, 540)


def _files(tmp_path, offsets):
    """frames.jsonl with a bus at x=100 and an estate at x=600 (10 frames); one results track per offset."""
    with open(tmp_path / "frames.jsonl", "w") as fh:
        for f in range(10):
            for vid, cls, x, size in ((7, "bus", 100.0, [12.0, 2.5, 3.2]), (8, "estate", 600.0, [4.6, 1.8, 1.5])):
                fh.write(json.dumps({"frame": f, "id": vid, "class": cls, "ref": [x, 300.0 + 5 * f], "size": size,
                                     "speed_kmh": 80.0 if vid == 7 else 60.0}) + "\n")
    writer = BrnoResultsWriter(tmp_path / "system.json", fps=25.0)
    for k, x in enumerate(offsets, 1):
        writer.add(k, np.arange(10) / 25.0, [[x, 300.0 + 5 * f] for f in range(10)])
    writer.write(Calibration(default_camera(SIZE), SIZE, source="test"))
    return tmp_path / "frames.jsonl", load_results(tmp_path / "system.json")


def test_each_measured_vehicle_is_matched_to_the_rendered_one_it_follows(tmp_path):
    frames, results = _files(tmp_path, [101.0, 599.0, 300.0])  # the third follows nothing (200 px from both)
    events = [VehicleEvent(1, "truck", 0.0, 0.36, 81.0, length_m=13.2, width_m=2.5, height_m=3.2),
              VehicleEvent(2, "car", 0.0, 0.36, 59.5), VehicleEvent(3, "car", 0.0, 0.36, 70.0),
              VehicleEvent(4, "car", 0.0, 0.36, None, reason="track too short")]
    got = match_measured(frames, events, results, SIZE)
    assert [(m.vehicle_id, m.rendered_id, m.rendered_class, m.label) for m in got] == [(1, 7, "bus", "truck"),
                                                                                       (2, 8, "car", "car")]
    assert got[0].speed_error_kmh == 1.0 and got[1].speed_error_kmh == -0.5
    assert got[0].rendered_size == (12.0, 2.5, 3.2) and got[0].size == (13.2, 2.5, 3.2) and got[1].size is None
    assert label_accuracy(got) == 0.5 and label_accuracy([]) is None
    # a tighter matching distance (5 px at 960 wide) drops nothing here; 0.5 px drops both
    assert len(match_measured(frames, events, results, SIZE, max_distance=0.005)) == 2
    assert match_measured(frames, events, results, SIZE, max_distance=0.0005) == []
    assert match_measured(tmp_path / "none.jsonl", events, results, SIZE) == []


def test_two_rendered_vehicles_with_one_id_are_two_vehicles(tmp_path):
    """BrnoCompSpeed's session0_center gives one car id to two or three cars, and a replay renders each with its
    recorded id: the truth is keyed by id, model, lane and direction, so each measured vehicle is scored against the
    car it follows.  Keyed by id alone, the second car's records replaced the first's in the frames both are in."""
    with open(tmp_path / "frames.jsonl", "w") as fh:
        for f in range(10):
            for lane, x, speed in ((0, 100.0, 80.0), (1, 600.0, 60.0)):
                fh.write(json.dumps({"frame": f, "id": 11, "model": "octavia", "lane": lane, "direction": "towards",
                                     "class": "sedan", "ref": [x, 300.0 + 5 * f], "size": [4.5, 1.7, 1.4],
                                     "speed_kmh": speed}) + "\n")
    writer = BrnoResultsWriter(tmp_path / "system.json", fps=25.0)
    for k, x in enumerate((101.0, 599.0), 1):
        writer.add(k, np.arange(10) / 25.0, [[x, 300.0 + 5 * f] for f in range(10)])
    writer.write(Calibration(default_camera(SIZE), SIZE, source="test"))
    events = [VehicleEvent(1, "car", 0.0, 0.36, 81.0), VehicleEvent(2, "car", 0.0, 0.36, 59.0)]
    got = match_measured(tmp_path / "frames.jsonl", events, load_results(tmp_path / "system.json"), SIZE)
    assert [(m.vehicle_id, m.rendered_id, m.speed_error_kmh) for m in got] == [(1, 11, 1.0), (2, 11, -1.0)]
