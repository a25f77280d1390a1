"""Background model, blob grouping and the tracking pipeline: synthetic frames and a real traffic clip."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from gst_trafficcal.detection.records import Detections, box_iou
from gst_trafficcal.errors import InputError
from gst_trafficcal.tracking.background import (BackgroundModel, blob_boxes, chroma_from_bgr,
                                                chroma_from_planes, group_hulls)
from gst_trafficcal.tracking.pipeline import TrackingPipeline

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
CLIP = SHARED / "data" / "videos" / "kraten_cars.mp4"


def textured_background(h=360, w=640, seed=0):
    rng = np.random.default_rng(seed)
    bg = cv2.resize(rng.integers(60, 140, (h // 8, w // 8)).astype(np.uint8), (w, h), interpolation=cv2.INTER_LINEAR)
    return bg


def test_moving_block_is_foreground_and_its_hull_is_found():
    bg = textured_background()
    model = BackgroundModel(work_width=320)
    rng = np.random.default_rng(1)
    for k in range(50):
        frame = bg.copy()
        x = 20 + 8 * k
        frame[150:210, x:x + 90] = 220  # a bright vehicle moving right
        frame = cv2.add(frame, rng.integers(0, 4, frame.shape, dtype=np.uint8))
        mask = model.apply(frame)
    assert model.ready and model.scale == 2.0
    boxes = blob_boxes(mask, model.scale, min_area=500)
    assert len(boxes) == 1
    assert np.allclose(boxes[0], [x, 150, x + 90, 210], atol=4)
    hulls = group_hulls(mask, np.array([[x - 10, 140, x + 100, 220], [10, 10, 60, 60]], float), model.scale)
    assert hulls[1] is None  # no foreground in the second box
    h = hulls[0]
    assert np.allclose([h[:, 0].min(), h[:, 1].min(), h[:, 0].max(), h[:, 1].max()], [x, 150, x + 89, 209], atol=3)
    # the background did not absorb the moving block: it is still the texture where the block was
    assert np.abs(model.background()[75:105, (x - 60) // 2:(x - 20) // 2].astype(int)
                  - cv2.resize(bg, (320, 180))[75:105, (x - 60) // 2:(x - 20) // 2]).mean() < 8


def test_blobs_grouped_by_detections():
    mask = np.zeros((100, 200), np.uint8)
    mask[20:40, 20:50] = 255  # two blobs of one vehicle (e.g. split by a windscreen)
    mask[42:60, 22:55] = 255
    mask[30:60, 120:160] = 255  # another vehicle
    hulls = group_hulls(mask, np.array([[15, 15, 60, 65], [110, 25, 170, 65]], float))
    a, b = hulls
    assert a[:, 1].min() <= 20 and a[:, 1].max() >= 59  # both blobs in one hull
    assert b[:, 0].min() >= 119 and b[:, 0].max() <= 160.5


def _vehicle_with_shadow(bg_bgr: np.ndarray, x: int) -> np.ndarray:
    """A red box with a dark (but still red) side face and a cast shadow beside its base whose darkening ramps
    from 0.2 at the vehicle to 0.9 (a soft contact shadow), on the grey textured road ``bg_bgr``."""
    frame = bg_bgr.astype(np.float32)
    ramp = np.linspace(0.2, 0.9, 30)[None, :, None]
    frame[180:215, x + 90:x + 120] *= ramp  # shadow to the right of the vehicle, at its base
    frame[150:215, x:x + 60] = (40, 40, 200)  # lit face
    frame[150:215, x + 60:x + 90] = (8, 8, 45)  # dark side face: darker than the road, colour kept
    return np.clip(frame, 0, 255).astype(np.uint8)


def test_colour_tests_keep_dark_faces_and_drop_shadows():
    """With the U, V planes the outline is the vehicle: its dark side face stays, the cast shadow at its base
    goes; with brightness alone the side face passes the shadow test or the shadow stays."""
    bg = cv2.cvtColor(textured_background(), cv2.COLOR_GRAY2BGR)
    rng = np.random.default_rng(2)
    colour, grey = BackgroundModel(work_width=320), BackgroundModel(work_width=320)
    for k in range(40):
        frame = bg.copy() if k < 30 else _vehicle_with_shadow(bg, x := 100 + 6 * k)
        frame = cv2.add(frame, rng.integers(0, 3, frame.shape, dtype=np.uint8))
        gray = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        mask_c = colour.apply(gray, chroma_from_bgr(frame))
        mask_g = grey.apply(gray)
    truth = np.array([x, 150, x + 89, 214], float)
    box = np.array([[x - 20, 140, x + 130, 225]], float)
    hull_c = group_hulls(mask_c, box, colour.scale)[0]
    hull_g = group_hulls(mask_g, box, grey.scale)[0]
    extent = lambda h: np.array([h[:, 0].min(), h[:, 1].min(), h[:, 0].max(), h[:, 1].max()])  # noqa: E731
    assert np.abs(extent(hull_c) - truth).max() <= 4
    assert np.abs(extent(hull_g) - truth).max() > 8  # what the colour tests fix


def test_chroma_planes_of_raw_formats():
    bgr = np.zeros((6, 8, 3), np.uint8)
    bgr[...] = (30, 60, 200)
    uv = chroma_from_bgr(bgr)
    assert uv.shape == (3, 4, 2) and uv[..., 1].min() > 150 and uv[..., 0].max() < 128  # red: V high, U low
    i420 = cv2.cvtColor(bgr, cv2.COLOR_BGR2YUV_I420)
    planes = [i420[:6], i420[6:].reshape(-1)[:12].reshape(3, 4), i420[6:].reshape(-1)[12:].reshape(3, 4)]
    assert np.array_equal(chroma_from_planes(planes, "I420"), uv)
    assert np.array_equal(chroma_from_planes([planes[0], uv], "NV12"), uv)
    assert np.array_equal(chroma_from_planes([cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)], "RGB"), uv)
    assert chroma_from_planes([planes[0]], "GRAY8") is None
    with pytest.raises(InputError, match="U, V"):
        BackgroundModel().apply(np.zeros((10, 10), np.uint8), np.zeros((5, 5), np.uint8))


def test_bad_background_input():
    with pytest.raises(InputError):
        BackgroundModel(alpha=1.5)
    with pytest.raises(InputError, match="grey"):
        BackgroundModel().apply(np.zeros((10, 10, 3), np.uint8))


@pytest.mark.shared
def test_real_clip_tracks_are_plausible_and_stable():
    if not CLIP.exists():
        pytest.skip(f"{CLIP} not available (needs ../shared test data)")
    cap = cv2.VideoCapture(str(CLIP))
    pipe = TrackingPipeline()
    max_dup = 0.0
    times = []
    for _ in range(600):  # 24 s
        ok, frame = cap.read()
        if not ok:
            break
        t = cap.get(cv2.CAP_PROP_POS_MSEC) / 1000
        times.append(t)
        res, det = pipe.process(cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY), t)
        boxes = np.array([tr.last.box for tr in res.tracks]).reshape(-1, 4)
        if len(boxes) > 1:
            iou = box_iou(boxes, boxes)
            np.fill_diagonal(iou, 0)
            max_dup = max(max_dup, iou.max())
    cap.release()
    assert len(times) == 600
    tracks = pipe.flush()
    durations = np.array([tr.timestamps[-1] - tr.timestamps[0] for tr in tracks])
    assert 15 <= (durations >= 1.0).sum() <= 60  # vehicles passing in 24 s of urban traffic
    assert np.median(durations) >= 1.0
    assert max_dup < 0.5  # never two tracks on one vehicle
    for tr in tracks:  # ids stay on one vehicle: no jumps between neighbours
        assert set(tr.timestamps) <= set(times)
        b = np.array([o.det_box for o in tr.observations])
        c = (b[:, :2] + b[:, 2:]) / 2
        diag = np.hypot(b[:, 2] - b[:, 0], b[:, 3] - b[:, 1])
        if len(b) > 1:  # displacement per frame interval (a track may coast over a few frames)
            frames = np.maximum(np.round(np.diff(tr.timestamps) * 25), 1)
            assert (np.linalg.norm(np.diff(c, axis=0), axis=1) / frames / diag[1:]).max() < 1.0
