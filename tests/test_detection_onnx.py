"""The real FastestDet and NanoDet files on real BrnoCompSpeed frames and a real traffic clip.

Expected boxes were read off the frames by eye (drawn and checked); each test asserts that the
detector finds those vehicles (IoU >= 0.5), labels them as vehicles and gives plausible sizes.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gst_trafficcal.detection.onnx_detector import OnnxDetector
from gst_trafficcal.detection.records import box_iou

from .conftest import BRNO, DETECTORS, VIDEOS, require_shared

pytestmark = pytest.mark.shared

MODELS = {"fastestdet": "FastestDet.onnx", "nanodet": "nanodet_hpc203.onnx"}
VEHICLES = {"car", "bus", "truck", "motorcycle"}


@pytest.fixture(scope="module", params=sorted(MODELS))
def detector(request):
    path = require_shared(DETECTORS / MODELS[request.param])
    det = OnnxDetector(path, threshold=0.4, threads=2)
    assert det.model_format == request.param  # recognised from the output shapes alone
    return det


def screen(recording: str) -> np.ndarray:
    image = cv2.imread(str(require_shared(BRNO / recording / "screen.png")))
    assert image is not None and image.shape == (1080, 1920, 3)
    return image


def assert_found(det, expected, iou=0.5):
    assert len(det), "no vehicle found"
    assert set(det.labels) <= VEHICLES
    overlap = box_iou(np.array(expected, np.float64), det.boxes)
    assert (overlap.max(axis=1) >= iou).all(), (det.boxes.astype(int).tolist(), overlap.max(axis=1))


def test_session0_center_cars(detector):
    det = detector(screen("session0_center"))
    # the silver car near the camera on the far carriageway and a red car parked on the left
    assert_found(det, [[1530, 677, 1757, 812], [140, 335, 222, 402]])
    assert ((det.widths > 20) & (det.widths < 700) & (det.heights > 15) & (det.heights < 500)).all()


def test_session1_left_car(detector):
    det = detector(screen("session1_left"))
    assert_found(det, [[1422, 100, 1712, 245]], iou=0.7)
    assert det.scores.max() >= 0.5


def test_session2_right_car_by_fastestdet():
    det = OnnxDetector(require_shared(DETECTORS / MODELS["fastestdet"]), threshold=0.4)(screen("session2_right"))
    assert_found(det, [[1070, 0, 1243, 85]])  # the blue car entering at the top edge


def clip_frame(name: str, index: int) -> np.ndarray:
    cap = cv2.VideoCapture(str(require_shared(VIDEOS / name)))
    for _ in range(index + 1):
        ok, frame = cap.read()
        assert ok
    cap.release()
    return frame


def test_highway_clip_vehicles(detector):
    frame = clip_frame("abhishek_highway.mp4", 150)
    det = detector(frame)
    # the white car and the van on the far carriageway, the dark SUV in the near lane
    assert_found(det, [[146, 142, 192, 174], [230, 132, 284, 174], [382, 237, 444, 295]])
    # agnostic NMS: no vehicle reported twice
    iou = box_iou(det.boxes, det.boxes)
    np.fill_diagonal(iou, 0)
    assert iou.max(initial=0) < 0.5


def test_threshold_and_labels_filter(detector):
    frame = clip_frame("abhishek_highway.mp4", 150)
    everything = detector(frame)
    strict = OnnxDetector(detector.path, threshold=0.9)(frame)
    assert len(strict) < len(everything)
    cars_only = OnnxDetector(detector.path, labels="2:car", threshold=0.4)(frame)
    assert set(cars_only.labels) <= {"car"}
    renamed = OnnxDetector(detector.path, labels="2:vehicle,7:vehicle,5:vehicle", threshold=0.4)(frame)
    assert len(renamed) and set(renamed.labels) == {"vehicle"}


def test_grey_input_is_accepted(detector):
    frame = clip_frame("abhishek_highway.mp4", 150)
    det = detector(cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY))
    assert_found(det, [[382, 237, 444, 295]])


def test_tiles_find_the_distant_car_on_the_road():
    image = screen("session0_center")
    path = require_shared(DETECTORS / MODELS["nanodet"])
    distant = [[388, 260, 445, 305]]  # red car on the road, ~57 px wide: too small for one 320 px input
    whole = OnnxDetector(path, threshold=0.4)(image)
    assert len(whole) == 0 or box_iou(np.array(distant, np.float64), whole.boxes).max() < 0.5
    tiled = OnnxDetector(path, threshold=0.4, tiles=(3, 2))(image)
    assert_found(tiled, distant + [[1530, 677, 1757, 812], [140, 335, 222, 402]])
    iou = box_iou(tiled.boxes, tiled.boxes)
    np.fill_diagonal(iou, 0)
    assert iou.max(initial=0) < 0.5  # vehicles in the tile overlaps are reported once


def test_tile_grid_covers_the_frame():
    from gst_trafficcal.detection.onnx_detector import tile_grid

    grid = tile_grid(1920, 1080, 3, 2)
    assert len(grid) == 6
    assert min(g[0] for g in grid) == 0 and max(g[2] for g in grid) == 1920
    assert min(g[1] for g in grid) == 0 and max(g[3] for g in grid) == 1080
    assert grid[0][2] > grid[1][0]  # neighbours overlap
    assert tile_grid(640, 360, 1, 1) == [(0, 0, 640, 360)]


@pytest.mark.parametrize("letterbox,size", [("center", (320, 180)), ("none", (320, 320))])
def test_a_frame_handed_over_reduced_gives_the_full_frames_boxes(letterbox, size):
    """``reduced_size`` is the image ``prepare`` makes of a whole frame (inside the letterbox, or the stretched
    network image); that image with the frame's size gives the boxes of the full frame, in the frame's pixels."""
    from gst_trafficcal.imaging import fit

    det = OnnxDetector(require_shared(DETECTORS / "nanodet_hpc203.onnx"), threshold=0.3,
                       preprocess={"letterbox": letterbox})
    image = screen("session0_center")
    assert det.reduced_size((1920, 1080)) == size
    full = det(image)
    small = det(fit(image, size), frame_size=(1920, 1080))
    assert len(full) >= 2 and len(small) == len(full)
    np.testing.assert_allclose(small.boxes, full.boxes, atol=0.5)
