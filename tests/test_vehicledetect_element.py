"""The ``vehicledetect`` element in real GStreamer pipelines on a real clip."""

from __future__ import annotations

import os
import subprocess

import cv2
import numpy as np
import pytest

pytestmark = [pytest.mark.gst, pytest.mark.shared]

from gst_trafficcal.detection.onnx_detector import OnnxDetector  # noqa: E402
from gst_trafficcal.detection.records import box_iou  # noqa: E402
from gst_trafficcal.gst.element import register_plugin_file  # noqa: E402
from gst_trafficcal.gst.env import gst_environment  # noqa: E402
from gst_trafficcal.gst.pipeline import PipelineError, run_pipeline  # noqa: E402

from .conftest import DETECTORS, ROOT, VIDEOS, cut_after, require_shared  # noqa: E402

ELEMENT = ROOT / "elements" / "python" / "vehicledetect.py"
CLIP = "abhishek_highway.mp4"
CAPS = "video/x-raw,format=BGR,width=640,height=360,framerate=30/1"


@pytest.fixture(scope="module", autouse=True)
def _element() -> None:
    register_plugin_file(ELEMENT)


@pytest.fixture(scope="module")
def frames() -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(require_shared(VIDEOS / CLIP)))
    out = []
    while len(out) < 130:
        ok, frame = cap.read()
        assert ok
        out.append(frame)
    return out


@pytest.fixture(scope="module")
def nanodet():
    return require_shared(DETECTORS / "nanodet_hpc203.onnx")


def test_onnx_rois_match_the_library(frames, nanodet):
    sample = frames[100:124]
    run = run_pipeline(f"appsrc name=src ! vehicledetect model={nanodet} threshold=0.4 ! appsink name=sink",
                       sample, CAPS)
    assert len(run.frames) == len(sample)
    lib = OnnxDetector(nanodet, threshold=0.4)
    n_rois = 0
    for sf, frame in zip(run.frames, sample):
        expected = lib(frame)
        assert len(sf.rois) == len(expected)
        n_rois += len(sf.rois)
        for k, roi in enumerate(sf.rois):
            assert roi.meta_id == k and roi.label in {"car", "bus", "truck", "motorcycle"}
            det = roi.params["detection"]
            assert det["label"] == roi.label and det["label_id"] in (2, 3, 5, 7)
            assert 0.4 <= det["confidence"] <= 1.0
            assert 0.0 <= det["x_min"] < det["x_max"] <= 1.0 and 0.0 <= det["y_min"] < det["y_max"] <= 1.0
            np.testing.assert_allclose([det["x_min"] * 640, det["y_min"] * 360], roi.box[:2], atol=1e-3)
        if len(expected):
            iou = box_iou(expected.boxes, np.array([r.box for r in sf.rois]))
            assert (iou.max(axis=1) > 0.95).all()
    assert n_rois >= 3 * len(sample)  # several vehicles in every frame of this stretch


@pytest.mark.parametrize("model,reduced", [("nanodet_hpc203.onnx", (320, 320)), ("FastestDet.onnx", (352, 352))])
def test_full_hd_frames_reach_an_onnx_model_reduced_from_their_yuv_planes(model, reduced):
    """At 1080p the element hands an ONNX detector (no tiles) the frame already reduced to its network image —
    both models stretch the frame to their square input — from the I420 planes; the ROIs are the library's on
    the full frames converted whole (the clip scaled to 1920x1080 by videoscale), to rounding."""
    from gst_trafficcal.detection.factory import reduced_size
    from gst_trafficcal.gst.buffers import frame_bgr

    lib = OnnxDetector(require_shared(DETECTORS / model), threshold=0.4)
    assert reduced_size(lib, (1920, 1080)) == reduced
    assert reduced_size(OnnxDetector(DETECTORS / model, tiles=(2, 1)), (1920, 1080)) is None
    expected: list = []

    def full_frame(buffer, info) -> None:
        with frame_bgr(buffer, info) as bgr:
            expected.append(lib(bgr))

    run = run_pipeline(cut_after(f"filesrc location={require_shared(VIDEOS / CLIP)} ! decodebin ! videoconvert ! "
                                 "videoscale ! video/x-raw,format=I420,width=1920,height=1080 ! identity name=cut ! "
                                 f"vehicledetect model={DETECTORS / model} threshold=0.4 ! appsink name=sink", 60),
                       on_buffer=full_frame)
    assert len(run.frames) == len(expected) == 60
    same = matched = total = 0
    for frame, exp in zip(run.frames, expected):
        got = np.array([r.box for r in frame.rois], float).reshape(-1, 4)
        same += len(got) == len(exp)
        total += len(exp)
        if len(exp) and len(got):
            matched += int((box_iou(exp.boxes, got).max(axis=1) > 0.9).sum())
    assert total >= 60 and same >= 0.8 * len(expected) and matched >= 0.9 * total, (same, matched, total)


def test_tiles_property_reaches_the_detector(frames, nanodet):
    sample = frames[100:103]
    run = run_pipeline(f"appsrc name=src ! vehicledetect model={nanodet} tiles=2x1 ! appsink name=sink", sample, CAPS)
    lib = OnnxDetector(nanodet, threshold=0.4, tiles=(2, 1))
    assert [len(sf.rois) for sf in run.frames] == [len(lib(f)) for f in sample]
    with pytest.raises(PipelineError, match="tiles must look like"):
        run_pipeline(f"appsrc name=src ! vehicledetect model={nanodet} tiles=3 ! appsink name=sink", sample, CAPS)


def test_zone_keeps_the_vehicles_standing_in_it(frames, nanodet):
    """zone = the left half of the frame (fractions): the ROIs are the library's vehicles whose box's bottom centre
    lies there, the right half's are dropped; a zone that is not one is an error at start naming it."""
    sample = frames[100:124]
    run = run_pipeline(f"appsrc name=src ! vehicledetect model={nanodet} zone=\"0,0 0.5,0 0.5,1 0,1\" ! "
                       "appsink name=sink", sample, CAPS)
    lib = OnnxDetector(nanodet, threshold=0.4)
    left = right = 0
    for sf, frame in zip(run.frames, sample):
        b = lib(frame).boxes
        centre = (b[:, 0] + b[:, 2]) / 2
        clear = np.abs(centre - 320) > 2  # not on the zone's edge
        left += int((clear & (centre < 320)).sum())
        right += int((clear & (centre > 320)).sum())
        got = np.array([r.box for r in sf.rois], float).reshape(-1, 4)
        np.testing.assert_allclose(got, b[centre < 320], atol=0.01)  # the same vehicles, in the same order
    assert left >= len(sample) and right >= len(sample)  # vehicles on both sides all along
    with pytest.raises(PipelineError, match=r"vehicledetect: zone '0,0 1,1': polygon 1 has 2 points"):
        run_pipeline("appsrc name=src ! vehicledetect zone=\"0,0 1,1\" ! appsink name=sink", sample[:2], CAPS)
    with pytest.raises(PipelineError, match=r"vehicledetect: zone 700,0 900,0 900,100: it covers no pixel of the "
                                            r"640x360 frame"):
        run_pipeline("appsrc name=src ! vehicledetect zone=\"700,0 900,0 900,100\" ! appsink name=sink",
                     sample[:2], CAPS)
    tiny = run_pipeline("appsrc name=src ! vehicledetect zone=\"10,10 30,10 30,20\" ! appsink name=sink", sample[:2],
                        CAPS)  # a zone in pixels written for a larger frame, perhaps: a warning, the run goes on
    assert len(tiny.frames) == 2 and [w for w in tiny.warnings if "vehicledetect: zone 10,10 30,10 30,20 covers only"
                                      in w and "written for another resolution?" in w]


def test_interval_leaves_frames_in_between_empty(frames, nanodet):
    sample = frames[100:112]
    run = run_pipeline(f"appsrc name=src ! vehicledetect model={nanodet} interval=3 ! appsink name=sink",
                       sample, CAPS)
    counts = [len(sf.rois) for sf in run.frames]
    assert all(c == 0 for i, c in enumerate(counts) if i % 3)
    assert all(c > 0 for i, c in enumerate(counts) if i % 3 == 0), counts


def test_background_default_on_i420(frames):
    run = run_pipeline("appsrc name=src ! videoconvert ! video/x-raw,format=I420 ! vehicledetect ! "
                       "appsink name=sink", frames, CAPS)
    late = run.frames[100:]
    assert all(r.label == "car" for sf in late for r in sf.rois)
    assert sum(len(sf.rois) for sf in late) >= 2 * len(late)


def test_background_average_property_reaches_the_detector(frames):
    run = run_pipeline("appsrc name=src ! videoconvert ! video/x-raw,format=I420 ! vehicledetect background=average ! "
                       "appsink name=sink", frames, CAPS)
    assert all(not sf.rois for sf in run.frames[:25])  # the moving average reports nothing during its warm-up
    late = run.frames[100:]
    assert sum(len(sf.rois) for sf in late) >= 2 * len(late)


def test_options_the_detector_does_not_use_are_said_at_start(frames, nanodet):
    """labels, tiles and threshold are an ONNX model's: set with the built-in detector (or vehicleseg) they change
    nothing, and the start says so once; with the ONNX model they are used, and nothing is said."""
    run = run_pipeline("appsrc name=src ! videoconvert ! vehicledetect labels=car tiles=2x1 threshold=0.6 ! "
                       "appsink name=sink", frames[:3], CAPS)
    assert [w.split(": ", 1)[1] for w in run.warnings] == [
        "vehicledetect: labels, threshold, tiles are not used by the built-in background detector; ignored"]
    run = run_pipeline(f"appsrc name=src ! videoconvert ! vehicledetect model={nanodet} labels=car tiles=2x1 "
                       "threshold=0.6 ! appsink name=sink", frames[:3], CAPS)
    assert not run.warnings
    run = run_pipeline(f"appsrc name=src ! videoconvert ! vehicledetect model={nanodet} background=average ! "
                       "appsink name=sink", frames[:3], CAPS)
    assert [w.split(": ", 1)[1] for w in run.warnings] == [
        f"vehicledetect: background is not used by model {nanodet}; ignored"]


def test_class_ids_the_model_does_not_have_are_said_at_start(frames, nanodet):
    """NanoDet has COCO's 80 classes: labels naming only ids beyond them would find nothing, in silence — an error
    at start; some of them beside ones it has: a warning naming them."""
    with pytest.raises(PipelineError, match=r"the model has 80 classes \(ids 0 to 79\); labels names only class "
                                            r"id\(s\) 99"):
        run_pipeline(f"appsrc name=src ! videoconvert ! vehicledetect model={nanodet} labels=99:alien ! "
                     "appsink name=sink", frames[:3], CAPS)
    run = run_pipeline(f"appsrc name=src ! videoconvert ! vehicledetect model={nanodet} labels=2:car,99:alien,120:x "
                       "! appsink name=sink", frames[:3], CAPS)
    assert [w.split(": ", 1)[1] for w in run.warnings] == [
        f"vehicledetect: model {nanodet} has 80 classes; labels' class id(s) 99, 120 are not among them and are "
        "never found"]
    assert any(r.label == "car" for f in run.frames for r in f.rois)


def test_bad_background_method_fails_at_start(frames):
    with pytest.raises(PipelineError, match="background method must be mog2 or average"):
        run_pipeline("appsrc name=src ! videoconvert ! vehicledetect background=median ! appsink name=sink",
                     frames[:3], CAPS)


@pytest.mark.parametrize("model,message", [("/nonexistent/model.onnx", "model file not found: /nonexistent/model.onnx"),
                                           ("JUNK", "not a usable ONNX model")])
def test_bad_model_fails_at_start_naming_it(frames, tmp_path, model, message):
    if model == "JUNK":
        model = tmp_path / "junk.onnx"
        model.write_text("not a model")
    with pytest.raises(PipelineError, match=message):
        run_pipeline(f"appsrc name=src ! vehicledetect model={model} ! appsink name=sink", frames[:3], CAPS)


def test_gst_launch_and_inspect(tmp_path, nanodet):
    env = dict(os.environ, **gst_environment(), GST_REGISTRY=str(tmp_path / "registry.bin"))
    out = subprocess.run(["gst-inspect-1.0", "vehicledetect"], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    for prop in ("model", "model-format", "labels", "threshold", "interval", "threads", "tiles"):
        assert f"  {prop} " in out.stdout, prop
    clip = require_shared(VIDEOS / "sobral_simple_vehicle_counting_video.avi")
    out = subprocess.run(["gst-launch-1.0", "filesrc", f"location={clip}", "!", "decodebin", "!", "videoconvert",
                          "!", "vehicledetect", f"model={nanodet}", "interval=2", "threads=2", "!", "fakesink"],
                         env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]


def test_a_second_detector_says_the_frames_came_with_detections(frames, nanodet):
    """vehicledetect after another detector (two in one chain, or a DL Streamer detector before ours) adds its
    vehicles to those already there, and says once that a vehicle may be counted twice."""
    sample = frames[100:104]
    run = run_pipeline(f"appsrc name=src ! vehicledetect model={nanodet} ! vehicledetect model={nanodet} ! "
                       "appsink name=sink", sample, CAPS)
    lib = OnnxDetector(nanodet, threshold=0.4)
    assert [len(sf.rois) for sf in run.frames] == [2 * len(lib(f)) for f in sample] and len(run.frames[0].rois) > 0
    said = [w for w in run.warnings if "the frames already carry detections" in w]
    assert len(said) == 1 and "counted twice" in said[0]
    alone = run_pipeline(f"appsrc name=src ! vehicledetect model={nanodet} ! appsink name=sink", sample, CAPS)
    assert not [w for w in alone.warnings if "already carry" in w]
