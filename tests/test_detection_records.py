"""Detections record, box IoU and the label map."""

from __future__ import annotations

import numpy as np
import pytest

from gst_trafficcal.detection.labels import COCO91_TO_80, LabelMap
from gst_trafficcal.detection.onnx_detector import nms
from gst_trafficcal.detection.records import Detections, box_iou
from gst_trafficcal.errors import InputError


def sample() -> Detections:
    return Detections([[0, 0, 10, 10], [5, 5, 25, 15], [100, 100, 110, 140]], [0.9, 0.5, 0.7], [2, 7, 2],
                      ["car", "truck", "car"])


def test_indexing_filtering_and_geometry():
    d = sample()
    assert len(d) == 3 and d.boxes.dtype == np.float32
    assert list(d[d.scores > 0.6].labels) == ["car", "car"]
    assert len(d[1]) == 1 and d[1].labels[0] == "truck"
    assert list(d.with_label("truck").class_ids) == [7]
    np.testing.assert_allclose(d.centers[1], [15, 10])
    np.testing.assert_allclose(d.bottom_centers[2], [105, 140])
    np.testing.assert_allclose(d.areas, [100, 200, 400])
    np.testing.assert_allclose(d.scaled(2, 0.5).boxes[1], [10, 2.5, 50, 7.5])
    clipped = d.clipped(20, 20)
    assert len(clipped) == 2 and clipped.boxes[:, 2:].max() <= 20
    rows = list(d)
    assert rows[0].box == (0.0, 0.0, 10.0, 10.0) and rows[0].label == "car" and rows[0].class_id == 2
    merged = Detections.merge([d, Detections.empty(), d[0]])
    assert len(merged) == 4 and merged.labels[-1] == "car"
    assert len(Detections.empty()) == 0 and len(Detections.merge([])) == 0
    with pytest.raises(ValueError):
        Detections([[0, 0, 1, 1]], [1.0], [2], ["a", "b"])


def test_box_iou():
    a = np.array([[0, 0, 10, 10]])
    b = np.array([[0, 0, 10, 10], [5, 0, 15, 10], [20, 20, 30, 30], [0, 0, 0, 0]])
    np.testing.assert_allclose(box_iou(a, b)[0], [1.0, 50 / 150, 0.0, 0.0])
    assert box_iou(np.zeros((0, 4)), b).shape == (0, 4)


def test_nms_agnostic_and_per_class():
    boxes = np.array([[0, 0, 10, 10], [1, 0, 11, 10], [50, 50, 60, 60]], np.float32)
    scores = np.array([0.9, 0.8, 0.7], np.float32)
    assert list(nms(boxes, scores, 0.5)) == [0, 2]
    assert sorted(nms(boxes, scores, 0.5, np.array([2, 7, 2]))) == [0, 1, 2]
    assert len(nms(np.zeros((0, 4)), np.zeros(0), 0.5)) == 0


def test_label_map_parsing():
    assert LabelMap.parse("").names == {2: "car", 3: "motorcycle", 5: "bus", 7: "truck"}
    assert LabelMap.parse("2:car, 7=car").names == {2: "car", 7: "car"}
    assert LabelMap.parse("car,truck").names == {2: "car", 7: "truck"}
    lm = LabelMap.parse("0:vehicle,4:van")
    assert list(lm.lookup(np.array([4, 0, 9]))) == ["van", "vehicle", ""]
    assert list(lm.keep(np.array([0, 1, 4]))) == [True, False, True]
    assert str(LabelMap.coco()) == "2:car,3:motorcycle,5:bus,7:truck"
    for bad in ("x:car", "2:", "-1:car", "boat"):
        with pytest.raises(InputError):
            LabelMap.parse(bad)


def test_coco91_table():
    assert len(COCO91_TO_80) == 80
    assert [COCO91_TO_80[i] for i in (3, 4, 6, 8)] == [2, 3, 5, 7]  # car, motorcycle, bus, truck


def test_detections_carry_hulls_through_selection_and_merging():
    hulls = [np.array([[0, 0], [4, 0], [4, 3]], float), None, np.array([[10, 10], [12, 10], [12, 14]], float)]
    d = Detections(np.array([[0, 0, 5, 4], [1, 1, 2, 2], [10, 10, 13, 15]]), [0.9, 0.5, 0.7], [2, 2, 2],
                   ["car"] * 3, hulls)
    sub = d[np.array([2, 0])]
    assert np.array_equal(sub.hulls[0], hulls[2]) and np.array_equal(sub.hulls[1], hulls[0])
    assert d.above(0.6).hulls[1] is not None and len(d.above(0.6).hulls) == 2
    merged = Detections.merge([d, Detections(np.array([[0, 0, 1, 1]]), [0.3], [2], ["car"])])
    assert len(merged.hulls) == 4 and merged.hulls[3] is None and merged.hulls[1] is None
    half = d.scaled(0.5)
    assert np.allclose(half.hulls[0], (hulls[0] + 0.5) * 0.5 - 0.5)
    assert [x.hull is None for x in d] == [False, True, False]
    assert Detections.merge([Detections.empty(), d[[1]]]).hulls is not None
    with pytest.raises(ValueError, match="2 hulls for 3 boxes"):
        Detections(d.boxes, d.scores, d.class_ids, d.labels, hulls[:2])
    with pytest.raises(ValueError, match="Kx2"):
        Detections(d.boxes, d.scores, d.class_ids, d.labels, [np.zeros(3), None, None])
