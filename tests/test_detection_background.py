"""The weight-free background detector on a real traffic clip, checked against NanoDet."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gst_trafficcal.detection.background import BackgroundDetector
from gst_trafficcal.detection.onnx_detector import OnnxDetector
from gst_trafficcal.detection.records import box_iou

from .conftest import BRNO, DETECTORS, VIDEOS, require_shared

pytestmark = pytest.mark.shared


@pytest.fixture(scope="module")
def frames() -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(require_shared(VIDEOS / "abhishek_highway.mp4")))
    out = []
    while len(out) < 161:
        ok, frame = cap.read()
        assert ok
        out.append(frame)
    return out


@pytest.fixture(scope="module")
def nanodet_boxes(frames) -> dict[int, np.ndarray]:
    det = OnnxDetector(require_shared(DETECTORS / "nanodet_hpc203.onnx"), threshold=0.35)
    return {i: det(frames[i]).boxes for i in range(100, 161, 10)}


@pytest.mark.parametrize("method", ["mog2", "average"])
def test_finds_the_moving_cars_nanodet_sees(frames, nanodet_boxes, method):
    bg = BackgroundDetector(method=method)
    matched = total = 0
    for i, frame in enumerate(frames):
        det = bg(frame)  # every frame, in order: the model learns the road
        if i not in nanodet_boxes:
            continue
        assert len(det) >= 2, f"frame {i}: only {len(det)} blobs"
        assert set(det.labels) == {"car"} and ((det.scores > 0) & (det.scores <= 1)).all()
        ref = nanodet_boxes[i]
        total += len(ref)
        if len(ref) and len(det):
            matched += int((box_iou(ref, det.boxes).max(axis=1) >= 0.5).sum())
    assert total >= 25
    assert matched >= 0.6 * total, (matched, total)


def test_static_scene_gives_nothing_after_warm_up(frames):
    bg = BackgroundDetector()
    for _ in range(30):
        det = bg(frames[0])
    assert len(det) == 0


def test_grey_input_and_mask(frames):
    h, w = frames[0].shape[:2]
    masked = BackgroundDetector(mask=np.zeros((h, w), np.uint8))
    grey = BackgroundDetector()
    for frame in frames[:120]:
        g = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        m, d = masked(g), grey(g)
    assert len(m) == 0 and len(d) >= 2
    assert (d.boxes[:, 2] <= w).all() and (d.boxes[:, 3] <= h).all()


def test_bad_method():
    with pytest.raises(ValueError):
        BackgroundDetector(method="median")


def _road_clip(vehicle: str, n: int = 60) -> tuple[list[np.ndarray], list[tuple[int, int, int, int]]]:
    """A real empty-road frame (BrnoCompSpeed session0_center, 960x540) with one vehicle driving across it:
    ``"grey"``: a silver body, a dark windscreen and grille, and a cast shadow to its right
    (the road darkened by a constant factor, its texture kept); ``"dark"``: a uniformly dark body, no shadow.
    Returns the frames and the vehicle's box in each."""
    road = cv2.imread(str(require_shared(BRNO / "session0_center" / "screen.png")), cv2.IMREAD_GRAYSCALE)
    road = cv2.resize(road, (960, 540), interpolation=cv2.INTER_AREA)
    frames, boxes = [], []
    w, h, y0 = 120, 70, 380
    for i in range(n):
        img = road.astype(np.float32)
        x0 = 60 + 8 * max(i - 30, 0)
        if i >= 30:
            if vehicle == "grey":
                img[y0 + 10:y0 + h + 10, x0 + w:x0 + w + 45] *= 0.55  # cast shadow, attached to the right side
                level = float(np.median(road[y0:y0 + h, x0:x0 + w]))
                img[y0:y0 + h, x0:x0 + w] = level * np.linspace(1.35, 1.1, h)[:, None]  # shaded silver body
                img[y0 + 12:y0 + 30, x0 + 15:x0 + w - 15] = level * 0.45  # windscreen
                img[y0 + h - 12:y0 + h:3, x0 + 5:x0 + w - 5] = level * 0.3  # grille
            else:
                img[y0:y0 + h, x0:x0 + w] = 35.0
            boxes.append((x0, y0, x0 + w, y0 + h))
        else:
            boxes.append((0, 0, 0, 0))
        frames.append(np.clip(img, 0, 255).astype(np.uint8))
    return frames, boxes


@pytest.mark.parametrize("vehicle", ["grey", "dark"])
def test_average_peels_the_cast_shadow_off_the_box(vehicle):
    """The moving average with shadow peeling boxes the vehicle without its cast shadow; a dark vehicle (dark and
    smooth everywhere, like a shadow) keeps its whole box; without peeling the shadow widens the box."""
    frames, truth = _road_clip(vehicle)
    peeled, whole = BackgroundDetector(method="average"), BackgroundDetector(method="average", peel=False)
    ious, right, right0 = [], [], []
    for frame, box in zip(frames, truth):
        d, d0 = peeled(frame), whole(frame)
        if box[2] == 0:
            continue
        g = np.array([box], np.float64)
        assert len(d) >= 1 and len(d0) >= 1
        iou = box_iou(g, d.boxes)[0]
        ious.append(iou.max())
        right.append(d.boxes[np.argmax(iou), 2] - box[2])
        right0.append(d0.boxes[np.argmax(box_iou(g, d0.boxes)[0]), 2] - box[2])
    # measured: grey 0.80 (the grille's dark bottom rows are peeled too), dark 1.0
    assert np.median(ious) >= 0.75, ious
    assert abs(np.median(right)) <= 8, right  # the box ends at the vehicle, not at the shadow's end (45 px on)
    if vehicle == "grey":
        assert np.median(right0) >= 30, right0  # without peeling the shadow is in the box
