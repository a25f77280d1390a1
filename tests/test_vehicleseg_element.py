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

from .conftest import ROOT, VIDEOS, require_shared  # noqa: E402

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
