"""``vehicledetect model=vehicleseg`` in real GStreamer pipelines: ROIs with hulls, and the tracker using them."""

from __future__ import annotations

import os
import subprocess

import numpy as np
import pytest

pytestmark = pytest.mark.gst

from gst_trafficcal.gst.element import register_plugin_file  # noqa: E402
from gst_trafficcal.gst.env import gst_environment  # noqa: E402
from gst_trafficcal.gst.meta import HULL  # noqa: E402
from gst_trafficcal.gst.pipeline import PipelineError, run_pipeline  # noqa: E402

from .conftest import ROOT, VIDEOS, cut_after, require_shared  # noqa: E402

ELEMENTS = ROOT / "elements" / "python"


@pytest.fixture(scope="module", autouse=True)
def _elements() -> None:
    for name in ("vpdetect", "vehicledetect", "tracker"):
        register_plugin_file(ELEMENTS / f"{name}.py")


def test_tracker_builds_its_3d_boxes_from_the_segmenter_hulls(cuboid_clip):
    video, cal = cuboid_clip / "video.mp4", cuboid_clip / "calibration.json"
    run = run_pipeline(f"filesrc location={video} ! decodebin ! videoconvert ! video/x-raw,format=I420 ! "
                       f"vpdetect mode=fixed calibration-file={cal} ! vehicledetect model=vehicleseg ! tracker ! "
                       "appsink name=sink")
    rois = [r for f in run.frames for r in f.rois]
    assert len(rois) >= 100
    tracked = with_3d = 0
    for roi in rois:
        points = np.array(roi.params[HULL]["points"], float)
        assert points.ndim == 2 and points.shape[1] == 2 and len(points) >= 3
        x0, y0, x1, y1 = roi.box
        # the box is the hull's extent (clipped to the frame in the ROI)
        assert np.all(points >= (x0 - 0.5 - 1e-3, y0 - 0.5 - 1e-3)) and np.all(points <= (x1 + 1e-3, y1 + 1e-3))
        v = roi.params.get("trafficcal-vehicle")
        if v is None:
            continue
        tracked += 1
        # the tracked hull is the segmenter's, not one from the tracker's own background model
        assert np.allclose(v["hull_box"], [*points.min(axis=0), *points.max(axis=0)], atol=1e-6)
        with_3d += bool(v["has_3d"])
    assert tracked >= 0.5 * len(rois) and with_3d >= 50, (tracked, with_3d, len(rois))


def test_a_bad_model_stops_the_pipeline_at_start_up(cuboid_clip, tmp_path):
    junk = tmp_path / "seg.onnx"
    junk.write_bytes(b"not an onnx file" * 10)
    for model, message in ((junk, f"{junk}: not a usable ONNX model"),
                           ("/nonexistent/seg.onnx", "model file not found: /nonexistent/seg.onnx")):
        with pytest.raises(PipelineError, match=message):
            run_pipeline(f"filesrc location={cuboid_clip / 'video.mp4'} ! decodebin ! videoconvert ! "
                         f"vehicledetect model={model} model-format=vehicleseg ! fakesink")


@pytest.mark.shared
def test_gst_launch_tracks_a_real_clip_with_the_segmenter(tmp_path):
    clip = require_shared(VIDEOS / "abhishek_highway.mp4")
    env = dict(os.environ, **gst_environment(), GST_REGISTRY=str(tmp_path / "registry.bin"))
    out = subprocess.run(["gst-launch-1.0", "-m", "filesrc", f"location={clip}", "!", "decodebin", "!",
                          "videoconvert", "!", "vehicledetect", "model=vehicleseg", "!", "tracker", "!", "fakesink"],
                         env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    tracks = [line for line in out.stdout.splitlines() if "trafficcal-track" in line]
    assert len(tracks) >= 5, out.stdout[-2000:]  # 11 s of a busy highway


@pytest.mark.shared
def test_full_hd_frames_reach_the_segmenter_reduced_from_their_yuv_planes():
    """At 1080p the element hands vehicleseg its work image reduced from the I420 planes (no full-size BGR copy);
    the vehicles are the ones the library finds on the full frames converted whole (a real clip scaled to 1920x1080
    by videoscale): the same count on nearly every frame, the same boxes to a pixel or two."""
    from gst_trafficcal.detection.factory import detect, reduced_size
    from gst_trafficcal.detection.vehicleseg import VehicleSegDetector
    from gst_trafficcal.gst.buffers import frame_bgr

    clip = require_shared(VIDEOS / "kraten_cars.mp4")
    library = VehicleSegDetector()
    assert reduced_size(library, (1920, 1080)) == (480, 270)
    assert reduced_size(library, (640, 360)) is None  # small frames: converted whole, as before
    found: list[np.ndarray] = []

    def full_frame(buffer, info) -> None:
        with frame_bgr(buffer, info) as bgr:
            found.append(detect(library, bgr, buffer.pts / 1e9).boxes)

    run = run_pipeline(cut_after(f"filesrc location={clip} ! decodebin ! videoconvert ! videoscale ! "
                                 "video/x-raw,format=I420,width=1920,height=1080 ! identity name=cut ! "
                                 "vehicledetect model=vehicleseg ! appsink name=sink", 300), on_buffer=full_frame)
    assert len(run.frames) == len(found) == 300
    same_count = diffs = 0
    corner: list[float] = []
    for frame, boxes in zip(run.frames, found):
        got = np.array([r.box for r in frame.rois], float).reshape(-1, 4)
        same_count += len(got) == len(boxes)
        for box in boxes:  # the element's nearest box to each of the library's
            if len(got):
                corner.append(float(np.abs(got - box).max(axis=1).min()))
        diffs += len(got) != len(boxes)
    corner_a = np.array(corner)
    assert sum(len(b) for b in found) >= 500  # a busy street: vehicles on most frames
    assert same_count >= 0.95 * len(found), diffs
    assert np.median(corner_a) <= 0.5 and np.mean(corner_a <= 2.5) >= 0.9, np.percentile(corner_a, [50, 90, 99])
