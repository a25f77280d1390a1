"""The ``tracker`` element in real GStreamer pipelines: ROI metas in, object ids and 3D data out."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

pytestmark = pytest.mark.gst

from gst_trafficcal.calibration import Calibration, save_calibration  # noqa: E402
from gst_trafficcal.gst.buffers import buffer_from_bgr, video_info_from_caps  # noqa: E402
from gst_trafficcal.gst.element import register_plugin_file  # noqa: E402
from gst_trafficcal.gst.env import gst_environment  # noqa: E402
from gst_trafficcal.gst.meta import add_vehicle_roi  # noqa: E402
from gst_trafficcal.gst.pipeline import run_pipeline  # noqa: E402
from gst_trafficcal.tracking.simulate import default_camera, simulate  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
ELEMENT = ROOT / "elements" / "python" / "tracker.py"
TEST_PLUGINS = ROOT / "tests" / "gst_plugins"
SIZE = (960, 540)
CAPS = f"video/x-raw,format=I420,width={SIZE[0]},height={SIZE[1]},framerate=25/1"


@pytest.fixture(scope="module", autouse=True)
def _elements() -> None:
    register_plugin_file(ELEMENT)
    register_plugin_file(TEST_PLUGINS / "python" / "tcmarker.py")  # publishes a calibration file downstream


@pytest.fixture(scope="module")
def scene():
    return simulate(default_camera(SIZE), SIZE, duration=7.0, seed=2)


EMPTY = 1.2  # seconds of empty road first: the background model learns the road, not the vehicles


def render(scene, colour=None):
    """Grey textured road with the vehicles' silhouettes painted far to near (nearer ones occlude); grey
    silhouettes, or all in ``colour`` (BGR)."""
    rng = np.random.default_rng(0)
    bg = cv2.resize(rng.integers(70, 120, (SIZE[1] // 6, SIZE[0] // 6)).astype(np.uint8), SIZE)
    cam = scene.camera
    images = []
    for f in scene.frames:
        img = cv2.cvtColor(bg, cv2.COLOR_GRAY2BGR)
        if f.t < EMPTY:
            images.append(img)
            continue
        depth = [cam.world_to_camera(np.append(r, 0.0))[2] for r in f.ref_world]
        for k in np.argsort(depth)[::-1]:
            paint = colour if colour is not None else (int(170 + 10 * (f.ids[k] % 8)),) * 3
            cv2.fillPoly(img, [np.round(f.hulls[k]).astype(np.int32)], paint)
        images.append(img)
    return images


def buffers(scene, images, with_rois=True):
    info = video_info_from_caps(CAPS)
    out = []
    for f, img in zip(scene.frames, images):
        buf = buffer_from_bgr(img, info)
        if with_rois and f.t >= EMPTY:
            for box in f.boxes:
                add_vehicle_roi(buf, SIZE, box, "car", 0.9, 2)
        out.append(buf)
    return out


@pytest.fixture(scope="module")
def images(scene):
    return render(scene)


@pytest.fixture(scope="module")
def calibration_file(scene, tmp_path_factory):
    cal = Calibration(scene.camera, SIZE, source="test")
    return save_calibration(cal, tmp_path_factory.mktemp("cal") / "cal.json")


def match_gt(scene, run):
    """(gt id, object id, roi params, frame) for every ROI, matched to the ground truth by its box."""
    rows = []
    for f, sf in zip(scene.frames, run.frames):
        assert abs(sf.pts - f.t) < 1e-6  # times are the buffers' PTS
        assert f.t >= EMPTY or not sf.rois
        for roi in sf.rois:
            k = int(np.argmin(np.abs(f.boxes - np.array(roi.box)).sum(axis=1)))
            rows.append((int(f.ids[k]), roi.object_id, roi.params, f, k))
    return rows


@pytest.mark.parametrize("options", ["", "peel=true"])
def test_ids_and_3d_reference_points_with_calibration(scene, images, calibration_file, options):
    run = run_pipeline(f"appsrc name=src ! tcmarker threshold=255 calibration-file={calibration_file} ! "
                       f"tracker {options} ! appsink name=sink", buffers(scene, images), CAPS)
    assert len(run.frames) == len(scene.frames)
    rows = match_gt(scene, run)
    ids = [(g, o) for g, o, *_ in rows if o is not None]
    assert len(ids) >= 0.8 * len(rows)
    gt_to_obj, obj_to_gt = {}, {}
    for g, o in ids:
        gt_to_obj.setdefault(g, set()).add(o)
        obj_to_gt.setdefault(o, set()).add(g)
    assert all(len(v) == 1 for v in gt_to_obj.values()), gt_to_obj  # one id per vehicle
    assert all(len(v) == 1 for v in obj_to_gt.values()), obj_to_gt  # one vehicle per id
    errors, metres = [], []
    for g, o, params, f, k in rows:
        if o is None:
            continue
        v = params["trafficcal-vehicle"]
        assert v["state"] == "confirmed" and v["calibration_id"]
        if v["has_3d"]:
            assert len(v["box3d"]) == 8 and len(v["box3d"][0]) == 2
            errors.append(np.hypot(v["ref_x"] - f.ref_px[k, 0], v["ref_y"] - f.ref_px[k, 1]))
            if f.ref_world[k, 0] < 50:  # a pixel is half a metre at 80 m in this low, shallow view
                metres.append(np.hypot(v["world_x"] - f.ref_world[k, 0], v["world_y"] - f.ref_world[k, 1]))
    assert len(errors) >= 100 and len(metres) >= 50
    assert np.median(errors) < 2.5 and np.median(metres) < 0.25, (np.median(errors), np.median(metres))
    ended = [m for m in run.messages if m.name == "trafficcal-track"]
    assert {m.fields["id"] for m in ended} == set(obj_to_gt)  # every track reported when it ends (or at EOS)
    assert all(m.fields["last"] > m.fields["first"] and m.fields["label"] == "car" for m in ended)


def _median_ref_error(scene, run) -> float:
    errors = [np.hypot(p["trafficcal-vehicle"]["ref_x"] - f.ref_px[k, 0], p["trafficcal-vehicle"]["ref_y"] - f.ref_px[k, 1])
              for g, o, p, f, k in match_gt(scene, run) if o is not None and p["trafficcal-vehicle"]["has_3d"]]
    assert len(errors) >= 100
    return float(np.median(errors))


def test_colour_outlines_vehicles_as_bright_as_the_road(scene, calibration_file):
    """Magenta vehicles with the road's brightness (luma ~103 on a 70-120 road): the colour test outlines them
    (colour=true, default, from the I420 U/V planes); brightness alone sees almost nothing of them and the 3D
    boxes fall back to the detection rectangles."""
    images = render(scene, colour=(200, 60, 150))
    errs = {}
    for colour in ("true", "false"):
        run = run_pipeline(f"appsrc name=src ! tcmarker threshold=255 calibration-file={calibration_file} ! "
                           f"tracker colour={colour} ! appsink name=sink", buffers(scene, images), CAPS)
        errs[colour] = _median_ref_error(scene, run)
    assert errs["true"] < 2.5 and errs["false"] > 2 * errs["true"], errs


def test_tracks_in_2d_without_calibration(scene, images):
    run = run_pipeline("appsrc name=src ! tracker ! appsink name=sink", buffers(scene, images), CAPS)
    rows = match_gt(scene, run)
    tracked = [(g, o, p) for g, o, p, *_ in rows if o is not None]
    assert len(tracked) >= 0.8 * len(rows)
    assert all(not p["trafficcal-vehicle"]["has_3d"] and "ref_x" not in p["trafficcal-vehicle"] for *_, p in tracked)
    per_gt = {}
    for g, o, _ in tracked:
        per_gt.setdefault(g, set()).add(o)
    assert all(len(v) == 1 for v in per_gt.values())


def test_blob_detection_mode_adds_rois(scene, images, calibration_file):
    run = run_pipeline(f"appsrc name=src ! tcmarker threshold=255 calibration-file={calibration_file} ! "
                       "tracker blob-detection=true ! appsink name=sink", buffers(scene, images, with_rois=False),
                       CAPS)
    late = [sf for sf, f in zip(run.frames, scene.frames) if f.t >= 2.0]
    areas = [np.prod(f.boxes[:, 2:] - f.boxes[:, :2], axis=1) for f in scene.frames if f.t >= 2.0]
    n_big = sum(int((a >= 800).sum()) for a in areas)  # well above the element's min-blob-area
    n_all = sum(len(a) for a in areas)
    n_rois = sum(len(sf.rois) for sf in late)
    assert 0.6 * n_big <= n_rois <= n_all  # blobs of vehicles overlapping in the image merge into one
    with_id = [r for sf in late for r in sf.rois if r.object_id is not None]
    assert len(with_id) >= 0.5 * n_big
    # measured unless touching the border or partly hidden by a nearer vehicle
    assert np.mean([r.params["trafficcal-vehicle"]["has_3d"] for r in with_id]) >= 0.7


def test_gst_inspect_documents_every_property(tmp_path):
    env = dict(os.environ, **gst_environment(), GST_REGISTRY=str(tmp_path / "registry.bin"))
    out = subprocess.run(["gst-inspect-1.0", "tracker"], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    for prop in ("min-hits", "max-lost", "iou-threshold", "drop-occluded", "background", "background-width",
                 "blob-detection", "min-blob-area", "colour", "peel", "body-shapes"):
        assert prop in out.stdout, prop
    assert "object_id" in out.stdout


def test_bad_body_shapes_value_is_an_error_at_start_up(tmp_path):
    env = dict(os.environ, **gst_environment(), GST_REGISTRY=str(tmp_path / "registry.bin"))
    out = subprocess.run(["gst-launch-1.0", "videotestsrc", "num-buffers=3", "!", "tracker", "body-shapes=cuboid",
                          "!", "fakesink"], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode != 0
    assert "body-shapes must be auto, cars or box" in out.stdout + out.stderr


@pytest.mark.shared
def test_gst_launch_tracks_a_real_clip(tmp_path):
    clip = ROOT.parent / "shared" / "data" / "videos" / "kraten_cars.mp4"
    if not clip.exists():
        pytest.skip(f"{clip} not available (needs ../shared test data)")
    env = dict(os.environ, **gst_environment(), GST_REGISTRY=str(tmp_path / "registry.bin"))
    out = subprocess.run(["gst-launch-1.0", "-m", "filesrc", f"location={clip}", "!", "decodebin", "!",
                          "videoconvert", "!", "tracker", "blob-detection=true", "!", "fakesink"],
                         env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    tracks = [line for line in out.stdout.splitlines() if "trafficcal-track" in line]
    assert len(tracks) >= 30  # the 47 s clip carries dozens of vehicles
