"""Vehicle ROI metadata in DL Streamer's layout: write, read back, update -- on buffers and through pipelines."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.gst

from gst_trafficcal.gst._gi import GLib, Gst, GstVideo  # noqa: E402
from gst_trafficcal.gst.element import register_plugin_file  # noqa: E402
from gst_trafficcal.gst.meta import (HULL, add_vehicle_roi, detections_from_rois, hull_params, read_vehicle_rois,  # noqa: E402
                                     roi_hull, update_roi_params)
from gst_trafficcal.gst.pipeline import run_pipeline  # noqa: E402

PLUGINS = Path(__file__).resolve().parent / "gst_plugins" / "python"
SIZE = (640, 360)


def _buffer() -> Gst.Buffer:
    return Gst.Buffer.new_allocate(None, 16, None)


def test_round_trip_on_a_buffer() -> None:
    buf = _buffer()
    extra = {
        "trafficcal-vehicle": {"ref_point": np.array([321.25, 200.5]), "box3d": np.arange(16.0).reshape(8, 2),
                               "lane": np.int64(2), "visible": True, "track_ms": 2**40},
        "speed": {"speed_kmh": 87.25, "label": "car", "model_name": "bbscale", "confidence": 0.75},
    }
    i0 = add_vehicle_roi(buf, SIZE, (10.5, 20.25, 110.75, 90.0), "car", 0.9, 2, params=extra)
    i1 = add_vehicle_roi(buf, SIZE, (300, 100, 420, 200), "truck", 0.6, 7, object_id=12)
    assert (i0, i1) == (0, 1)
    r0, r1 = read_vehicle_rois(buf, SIZE)
    assert r0.meta_id == 0 and r0.label == "car" and r0.label_id == 2 and r0.object_id is None
    assert r0.box == pytest.approx((10.5, 20.25, 110.75, 90.0), abs=1e-9)
    assert r0.confidence == pytest.approx(0.9)
    tv = r0.params["trafficcal-vehicle"]
    assert tv["ref_point"] == [321.25, 200.5] and tv["box3d"] == np.arange(16.0).reshape(8, 2).tolist()
    assert tv["lane"] == 2 and tv["visible"] is True and tv["track_ms"] == 2**40
    assert r0.params["speed"] == extra["speed"]
    assert (r1.meta_id, r1.label, r1.label_id, r1.object_id) == (1, "truck", 7, 12)
    assert r1.params["object_id"] == {"id": 12}


def test_rois_of_another_detector_are_updated_by_place() -> None:
    """A detector of another make adds ROI metas the standard way (gst_buffer_add_video_region_of_interest_meta,
    every id 0): each update reaches its own ROI, not the first one (the tracker put every vehicle's id and box
    on the first box)."""
    buf = _buffer()
    for x in (10, 200, 400):
        meta = GstVideo.buffer_add_video_region_of_interest_meta(buf, "car", x, 50, 60, 40)
        assert meta.id == 0
    rois = read_vehicle_rois(buf, SIZE)
    assert [r.index for r in rois] == [0, 1, 2] and {r.meta_id for r in rois} == {0}
    assert [r.box[0] for r in rois] == [10, 200, 400]
    for r in rois:
        update_roi_params(buf, r.index, "object_id", {"id": r.index + 7})
    assert [(r.box[0], r.object_id) for r in read_vehicle_rois(buf, SIZE)] == [(10, 7), (200, 8), (400, 9)]
    with pytest.raises(KeyError, match="no region-of-interest meta number 3"):
        update_roi_params(buf, 3, "object_id", {"id": 1})


def test_hulls_travel_with_the_rois_into_detections() -> None:
    buf = _buffer()
    hull = np.array([[10.25, 20.5], [60.0, 21.0], [58.5, 44.75], [11.0, 40.0]])
    add_vehicle_roi(buf, SIZE, (10, 20, 61, 46), "car", 0.8, 2, params=hull_params(hull))
    add_vehicle_roi(buf, SIZE, (100, 100, 140, 130), "car", 0.7, 2, params=hull_params(None))
    rois = read_vehicle_rois(buf, SIZE)
    assert rois[0].params[HULL]["points"] == hull.tolist() and HULL not in rois[1].params
    assert np.array_equal(roi_hull(rois[0]), hull) and roi_hull(rois[1]) is None
    det = detections_from_rois(rois)
    assert np.array_equal(det.hulls[0], hull) and det.hulls[1] is None
    assert detections_from_rois(rois[1:]).hulls is None  # no ROI with an outline: a boxes-only record


def test_layout_is_what_dl_streamer_tools_read() -> None:
    """Plain PyGObject/GstVideo consumers find the ROI by id with DL Streamer's field names and types."""
    buf = _buffer()
    add_vehicle_roi(buf, SIZE, (64.0, 36.0, 192.0, 108.0), "bus", 0.5, 5, object_id=3)
    meta = GstVideo.buffer_get_video_region_of_interest_meta_id(buf, 0)
    assert GLib.quark_to_string(meta.roi_type) == "bus"
    assert (meta.x, meta.y, meta.w, meta.h) == (64, 36, 128, 72)
    det = meta.get_param("detection")
    assert [det.nth_field_name(i) for i in range(det.n_fields())] == [
        "x_min", "y_min", "x_max", "y_max", "confidence", "label_id", "label"]
    assert "x_min=(double)" in det.to_string() and "label_id=(int)5" in det.to_string()
    for name, want in (("x_min", 0.1), ("y_min", 0.1), ("x_max", 0.3), ("y_max", 0.3)):
        ok, value = det.get_double(name)
        assert ok and value == pytest.approx(want, abs=1e-12)
    assert det.get_value("confidence") == 0.5 and det.get_value("label") == "bus"
    ok, label_id = det.get_int("label_id")
    assert ok and label_id == 5
    ok, oid = meta.get_param("object_id").get_int("id")
    assert ok and oid == 3


def test_boxes_are_clipped_to_the_frame_and_bad_input_rejected() -> None:
    buf = _buffer()
    add_vehicle_roi(buf, SIZE, (-20.0, 300.0, 100.0, 400.0), "car", 0.8, 2)
    (roi,) = read_vehicle_rois(buf, SIZE)
    assert roi.box == (0.0, 300.0, 100.0, 360.0)
    with pytest.raises(ValueError, match="invalid box"):
        add_vehicle_roi(buf, SIZE, (50.0, 10.0, 40.0, 20.0), "car", 0.8, 2)
    with pytest.raises(ValueError, match="invalid box"):
        add_vehicle_roi(buf, SIZE, (float("nan"), 10.0, 40.0, 20.0), "car", 0.8, 2)
    with pytest.raises(ValueError, match="object_id"):
        add_vehicle_roi(buf, SIZE, (1, 1, 2, 2), "car", 0.8, 2, object_id=0)
    with pytest.raises(TypeError, match="cannot store dict"):
        add_vehicle_roi(buf, SIZE, (1, 1, 2, 2), "car", 0.8, 2, params={"x": {"nested": {"a": 1}}})
    with pytest.raises(ValueError, match="written from the arguments"):
        add_vehicle_roi(buf, SIZE, (1, 1, 2, 2), "car", 0.8, 2, params={"object_id": {"id": 4}})


def test_update_replaces_a_structure_in_place() -> None:
    buf = _buffer()
    for k in range(3):
        add_vehicle_roi(buf, SIZE, (10 * k, 10, 10 * k + 5, 20), "car", 0.5, 2, params={"speed": {"speed_kmh": 1.0}})
    update_roi_params(buf, 1, "object_id", {"id": 42})
    update_roi_params(buf, 1, "speed", {"speed_kmh": 55.5, "label": "car"})
    update_roi_params(buf, 1, "speed", {"speed_kmh": 56.5})
    rois = read_vehicle_rois(buf, SIZE)
    assert [r.object_id for r in rois] == [None, 42, None]
    assert [r.params["speed"] for r in rois] == [{"speed_kmh": 1.0}, {"speed_kmh": 56.5}, {"speed_kmh": 1.0}]
    meta = GstVideo.buffer_get_video_region_of_interest_meta_id(buf, 1)
    assert meta.get_param("speed").get_value("speed_kmh") == 56.5  # exactly one "speed" left
    with pytest.raises(KeyError, match="no region-of-interest meta number 9"):
        update_roi_params(buf, 9, "speed", {"speed_kmh": 1.0})


def test_reader_sees_foreign_rois_with_duplicate_ids() -> None:
    """ROIs added by other elements (default id 0, no params) are all listed, with their integer box."""
    buf = _buffer()
    GstVideo.buffer_add_video_region_of_interest_meta(buf, "face", 1, 2, 3, 4)
    GstVideo.buffer_add_video_region_of_interest_meta(buf, "face", 5, 6, 7, 8)
    rois = read_vehicle_rois(buf, SIZE)
    assert [(r.label, r.box, r.confidence, r.object_id) for r in rois] == [
        ("face", (1.0, 2.0, 4.0, 6.0), 0.0, None), ("face", (5.0, 6.0, 12.0, 14.0), 0.0, None)]


def test_non_writable_buffer_is_refused_with_a_clear_error() -> None:
    buf = _buffer()
    pipeline_side = Gst.Sample.new(buf, None, None, None)  # a second owner: the buffer is shared now
    with pytest.raises(RuntimeError, match="not writable"):
        add_vehicle_roi(buf, SIZE, (1, 1, 2, 2), "car", 0.8, 2)
    del pipeline_side


def test_rois_travel_through_a_pipeline_to_appsink_and_a_downstream_element() -> None:
    """appsrc ! tcmarker (writes) ! queue ! tccheck (reads, posts a message) ! appsink (reads)."""
    register_plugin_file(PLUGINS / "tcmarker.py")
    register_plugin_file(PLUGINS / "tccheck.py")
    w, h = 322, 242
    frames = []
    boxes = [(40, 30, 90, 70), (100, 120, 181, 201), (0, 0, 322, 10)]
    for x0, y0, x1, y1 in boxes:
        f = np.full((h, w, 3), 30, np.uint8)
        f[y0:y1, x0:x1] = 250
        frames.append(f)
    frames.append(np.full((h, w, 3), 30, np.uint8))  # nothing bright: no ROI
    plain: list[tuple] = []  # what a consumer using only PyGObject/GstVideo (no gst_trafficcal) reads

    def read_plain(buffer: Gst.Buffer, info: GstVideo.VideoInfo) -> None:
        meta = GstVideo.buffer_get_video_region_of_interest_meta_id(buffer, 0)
        if meta is None:
            plain.append(None)
            return
        det = meta.get_param("detection")
        plain.append((GLib.quark_to_string(meta.roi_type), meta.x, meta.y, meta.w, meta.h,
                      det.get_double("x_min")[1] * w, det.get_double("y_max")[1] * h, det.get_int("label_id")[1],
                      meta.get_param("tc-test").get_value("count")))

    run = run_pipeline("appsrc name=src ! tcmarker ! queue ! tccheck ! appsink name=sink", frames,
                       f"video/x-raw,format=NV12,width={w},height={h},framerate=25/1", on_buffer=read_plain)
    assert plain[3] is None
    for got, (x0, y0, x1, y1) in zip(plain, boxes):
        assert got[:5] == ("car", x0, y0, x1 - x0, y1 - y0)
        assert got[5:] == (pytest.approx(x0), pytest.approx(y1), 2, (x1 - x0) * (y1 - y0))
    assert [len(f.rois) for f in run.frames] == [1, 1, 1, 0]
    for frame, box in zip(run.frames, boxes):
        roi = frame.rois[0]
        assert roi.box == pytest.approx(box) and roi.label == "car" and roi.label_id == 2 and roi.meta_id == 0
        assert roi.params["tc-test"]["count"] == (box[2] - box[0]) * (box[3] - box[1])
        assert roi.params["tc-test"]["pts"] == pytest.approx(frame.pts)
    checks = [m.fields for m in run.messages if m.name == "tccheck"]
    assert [c["rois"] for c in checks] == [1, 1, 1, 0]
    assert [c["box"] for c in checks[:3]] == [pytest.approx(list(b)) for b in boxes]


PLAIN_FIELDS = [
    {"t": 12.04, "state": "confirmed", "direction": -1, "occluded": False, "has_3d": True, "big": 2**40,
     "small": -(2**31), "edge": 2**31 - 1, "over": 2**31, "hull_box": [100.5, 200.25, 300.125, 400.0],
     "box3d": [[100.0 + i, 200.5 - i / 3] for i in range(8)], "calibration_id": ""},
    {"inf": float("inf"), "minus_inf": float("-inf"), "zero": -0.0, "tiny": 5e-324, "huge": 1.7976931348623157e308,
     "third": 1 / 3, "whole": 400.0},
    {"quoted": 'a "b" \\c', "space": "two words", "tab": "x\ty\n", "utf8": "Brno–Kraví hora é", "null": "NULL",
     "digits": "123", "word": "true", "path": "/a/b-c_d+e:f.g", "semi": "a;b,c=d<e>(f)"},
]


@pytest.mark.parametrize("fields", PLAIN_FIELDS, ids=["vehicle", "doubles", "strings"])
def test_structures_written_as_text_equal_those_built_field_by_field(fields) -> None:
    """make_structure writes plain fields as text parsed by GStreamer in one call: the structure must be the one
    setting each field as a GObject value gives (same serialisation: same types and the same doubles)."""
    from gst_trafficcal.gst import meta

    text = meta._structure_text("trafficcal-vehicle", fields)
    assert text is not None  # the fast path is taken for all of these
    by_text = meta.make_structure("trafficcal-vehicle", fields)
    by_field = Gst.Structure.new_empty("trafficcal-vehicle")
    for key, value in fields.items():
        by_field.set_value(key, meta._gvalue(value))
    assert by_text.to_string() == by_field.to_string()
    assert meta.structure_to_dict(by_text) == meta.structure_to_dict(by_field) == fields


def test_not_a_number_is_written_as_text_too() -> None:
    from gst_trafficcal.gst import meta

    fields = {"x": float("nan"), "row": [float("nan"), 1.0], "pairs": [[2.0, float("nan")]]}
    by_field = Gst.Structure.new_empty("n")
    for key, value in fields.items():
        by_field.set_value(key, meta._gvalue(value))
    assert meta._structure_text("n", fields) is not None
    assert meta.make_structure("n", fields).to_string() == by_field.to_string()
    got = meta.structure_to_dict(meta.make_structure("n", fields))
    assert np.isnan(got["x"]) and np.isnan(got["row"][0]) and got["pairs"][0][0] == 2.0


def test_structures_with_other_values_are_built_field_by_field() -> None:
    from gst_trafficcal.gst import meta

    fields = {"lane": np.int64(2), "ints": [1, 2], "mixed": [[1, 2.5]], "tuple": (1.0, 2.0), "empty": []}
    assert meta._structure_text("speed", fields) is None
    got = meta.structure_to_dict(meta.make_structure("speed", fields))
    assert got == {"lane": 2, "ints": [1, 2], "mixed": [[1.0, 2.5]], "tuple": [1.0, 2.0], "empty": []}


def test_reader_can_skip_structures_it_does_not_need() -> None:
    buf = _buffer()
    params = {"trafficcal-vehicle": {"t": 1.5, "box3d": [[1.0, 2.0]] * 8}, "speed": {"speed_kmh": 50.5},
              HULL: {"points": [[1.0, 2.0], [3.0, 4.0], [5.0, 1.0]]}}
    add_vehicle_roi(buf, SIZE, (10, 20, 110, 90), "car", 0.9, 2, object_id=7, params=params)
    whole, = read_vehicle_rois(buf, SIZE)
    some, = read_vehicle_rois(buf, SIZE, only=("trafficcal-vehicle",))
    assert set(whole.params) == {"detection", "object_id", "trafficcal-vehicle", "speed", HULL}
    assert set(some.params) == {"detection", "object_id", "trafficcal-vehicle"}
    assert some.params["trafficcal-vehicle"] == whole.params["trafficcal-vehicle"] == params["trafficcal-vehicle"]
    assert (some.box, some.object_id, some.label, some.confidence) == (whole.box, 7, "car", whole.confidence)
