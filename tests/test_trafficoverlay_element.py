"""The ``trafficoverlay`` element through real pipelines: H.264/MP4 files decoded again, tee, formats, grid."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

pytestmark = pytest.mark.gst

from gst_trafficcal.calibration import Calibration, save_calibration  # noqa: E402
from gst_trafficcal.geometry import Camera, rotation_matrix  # noqa: E402
from gst_trafficcal.gst._gi import Gst  # noqa: E402
from gst_trafficcal.gst.buffers import frame_bgr, video_info_from_caps  # noqa: E402
from gst_trafficcal.gst.element import register_plugin_file  # noqa: E402
from gst_trafficcal.gst.env import gst_environment  # noqa: E402
from gst_trafficcal.gst.pipeline import PipelineError, run_pipeline  # noqa: E402
from gst_trafficcal.overlay import Style  # noqa: E402

from .conftest import DETECTORS, VIDEOS, first_frames, require_shared, serve_rtsp, track_spans  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PLUGINS = Path(__file__).resolve().parent / "gst_plugins"
W, H = 320, 240
GREY_SRC = f"videotestsrc num-buffers=8 pattern=solid-color foreground-color=0xff808080 ! video/x-raw,width={W},height={H},framerate=25/1"
STYLE = Style()
BOX = [100.0, 100.0, 180.0, 160.0]  # the 2D ROI
ENCODE = "x264enc tune=zerolatency speed-preset=ultrafast ! mp4mux"


@pytest.fixture(scope="module", autouse=True)
def _elements() -> None:
    register_plugin_file(ROOT / "elements" / "python" / "trafficoverlay.py")
    register_plugin_file(PLUGINS / "python" / "tcroisource.py")


def _camera() -> Camera:
    K = np.array([[300.0, 0, W / 2], [0, 300.0, H / 2], [0, 0, 1]])
    R = rotation_matrix(20.0, 12.0, 0.0)
    return Camera.from_KRt(K, R, -R @ np.array([0.0, 0.0, 6.0]))


def _corners(x: float, y: float) -> list[list[float]]:
    X = np.array([[x + (i & 1) * 4.5, y + ((i >> 1) & 1) * 1.8, ((i >> 2) & 1) * 1.5] for i in range(8)])
    return _camera().world_to_image(X).tolist()


def _rois_prop(rois: list[dict]) -> str:
    return 'rois="' + json.dumps(rois).replace('"', '\\"') + '"'


def _roi_2d(object_id: int | None = 3, speed: float | None = 55.5) -> dict:
    roi = {"box": BOX, "label": "car"}
    if object_id is not None:
        roi["object_id"] = object_id
    if speed is not None:
        roi["params"] = {"speed": {"speed_kmh": speed}}
    return roi


def _roi_3d() -> dict:
    """A tracked vehicle as the tracker describes it (tracking.vehicle_meta layout)."""
    corners = _corners(14.0, 1.0)
    c = np.array(corners)
    box = [float(c[:, 0].min()), float(c[:, 1].min()), float(c[:, 0].max()), float(c[:, 1].max())]
    return {"box": box, "label": "truck", "object_id": 8,
            "params": {"trafficcal-vehicle": {"direction": 1, "has_3d": True, "box3d": corners,
                                              "ref_x": float(c[1, 0]), "ref_y": float(c[1, 1])},
                       "speed": {"speed_kmh": 81.0, "lane": 1}}}


def _near(img: np.ndarray, color: tuple[int, int, int], tol: int) -> np.ndarray:
    return np.abs(img.astype(int) - color).max(axis=2) <= tol


def _decode(path: Path) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, f = cap.read()
        if not ok:
            break
        frames.append(f)
    cap.release()
    return frames


def _box_band(box: list[float], grow: int) -> np.ndarray:
    m = np.zeros((H, W), bool)
    x0, y0, x1, y1 = (int(round(v)) for v in box)
    m[max(0, y0 - grow):y1 + grow + 1, max(0, x0 - grow):x1 + grow + 1] = True
    return m


def test_overlay_in_an_h264_mp4_file(tmp_path: Path) -> None:
    """videotestsrc -> ROIs -> trafficoverlay -> x264enc -> mp4mux -> file; decoded with OpenCV (no counters panel:
    on this small frame the car's label would keep off it, below its box's top edge)."""
    out = tmp_path / "overlay.mp4"
    run_pipeline(f"{GREY_SRC},format=I420 ! tcroisource {_rois_prop([_roi_2d(), _roi_3d()])} ! "
                 f"trafficoverlay draw-grid=false draw-horizon=false draw-counters=false line-thickness=4 ! {ENCODE} ! "
                 f"filesink location={out}")
    frames = _decode(out)
    assert len(frames) >= 5 and frames[0].shape == (H, W, 3)
    f = frames[len(frames) // 2]
    yellow = _near(f, STYLE.box_unknown_bgr, 60)  # direction unknown: the 2D box
    x0, y0, x1, y1 = (int(v) for v in BOX)
    edges = np.concatenate([yellow[y0, x0 + 5:x1 - 5], yellow[y1, x0 + 5:x1 - 5], yellow[y0 + 5:y1 - 5, x0],
                            yellow[y0 + 5:y1 - 5, x1]])
    assert edges.mean() > 0.9
    assert not yellow[y0 + 6:y1 - 6, x0 + 6:x1 - 6].any()  # not inside
    assert not (yellow & ~_box_band(BOX, 6)).any()  # nor anywhere else
    green = _near(f, STYLE.box_towards_bgr, 60)  # the 3D box of a vehicle moving towards VP1
    c = np.array(_roi_3d()["params"]["trafficcal-vehicle"]["box3d"])
    mids = np.round((c[[0, 2, 4, 6]] + c[[1, 3, 5, 7]]) / 2).astype(int)  # midpoints of the 4 edges along VP1
    near = cv2.dilate(green.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    assert near[mids[:, 1], mids[:, 0]].all()
    assert not (green & ~_box_band(_roi_3d()["box"], 6)).any()
    # the labels: white text on black boxes above each vehicle
    label_area = f[max(0, y0 - 30):y0, x0:x0 + 120]
    assert (label_area.max(axis=2) < 40).mean() > 0.3 and (label_area.min(axis=2) > 200).any()
    cv2.imwrite(str(tmp_path / "frame.png"), f)


def _run_tee(fmt: str) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Run src -> ROIs -> tee -> (trafficoverlay -> appsink "drawn", appsink "raw"); BGR copies of both."""
    desc = (f"{GREY_SRC},format={fmt} ! tcroisource {_rois_prop([_roi_2d()])} ! tee name=t "
            "t. ! queue ! trafficoverlay draw-grid=false ! appsink name=drawn sync=false "
            "t. ! queue ! appsink name=raw sync=false")
    pipeline = Gst.parse_launch(desc)
    got: dict[str, list[np.ndarray]] = {"drawn": [], "raw": []}

    def on_sample(sink, name: str) -> Gst.FlowReturn:  # appsink holds EOS back until its samples are pulled
        sample = sink.emit("pull-sample")
        with frame_bgr(sample.get_buffer(), video_info_from_caps(sample.get_caps())) as bgr:
            got[name].append(bgr.copy())
        return Gst.FlowReturn.OK

    for name in got:
        sink = pipeline.get_by_name(name)
        sink.set_property("emit-signals", True)
        sink.connect("new-sample", on_sample, name)
    pipeline.set_state(Gst.State.PLAYING)
    try:
        msg = pipeline.get_bus().timed_pop_filtered(60 * Gst.SECOND, Gst.MessageType.EOS | Gst.MessageType.ERROR)
        assert msg is not None and msg.type == Gst.MessageType.EOS, msg and msg.parse_error()
    finally:
        pipeline.set_state(Gst.State.NULL)
    return got["drawn"], got["raw"]


@pytest.mark.parametrize("fmt", ["I420", "NV12", "BGR", "RGB", "BGRx", "GRAY8"])
def test_shared_buffers_after_a_tee_are_copied_not_drawn_on(fmt: str) -> None:
    drawn, raw = _run_tee(fmt)
    assert len(drawn) == len(raw) == 8
    for d, r in zip(drawn, raw):
        assert np.abs(r.astype(int) - r[0, 0]).max() <= 2  # the other branch still sees the plain grey frame
        changed = np.abs(d.astype(int) - r).max(axis=2) > 20
        assert changed[int(BOX[1]), int(BOX[0]) + 5:int(BOX[2]) - 5].mean() > 0.9  # the box's top edge
        if fmt != "GRAY8":
            yellow = _near(d, STYLE.box_unknown_bgr, 60)
            assert yellow[int(BOX[1]), int(BOX[0]) + 5:int(BOX[2]) - 5].mean() > 0.9


def test_grid_and_horizon_from_the_calibration(tmp_path: Path) -> None:
    cal_path = save_calibration(Calibration(_camera(), (W, H), source="test"), tmp_path / "cal.json")

    def frame(extra: str, source_cal: bool) -> np.ndarray:
        frames = []
        src_cal = f"calibration-file={cal_path}" if source_cal else ""
        run_pipeline(f"{GREY_SRC},format=I420 ! tcroisource {src_cal} ! trafficoverlay {extra} ! "
                     "videoconvert ! video/x-raw,format=BGR ! appsink name=sink",
                     on_buffer=lambda b, i: frames.append(_bgr(b, i)) if not frames else None)
        return frames[0]

    cam = _camera()
    a, b, c = cam.horizon
    ys, xs = np.mgrid[0:H, 0:W]
    below = (a * xs + b * ys + c) * np.sign(a * cam.vp3[0] + b * cam.vp3[1] + c) > 3
    above = (a * xs + b * ys + c) * np.sign(a * cam.vp3[0] + b * cam.vp3[1] + c) < -3
    for extra, source_cal in (("", True), (f"calibration-file={cal_path}", False)):
        f = frame(extra + " draw-counters=false", source_cal)
        grid = _near(f, STYLE.grid_along_bgr, 50) | _near(f, STYLE.grid_across_bgr, 50)
        assert grid[below].mean() > 0.05 and not grid[above].any()
        red = _near(f, STYLE.horizon_bgr, 60)
        assert red.sum() > W and not red[below & ~np.roll(below, -6, axis=0)].all()
    f = frame("draw-grid=false draw-horizon=false draw-counters=false", True)
    assert np.abs(f.astype(int) - f[0, 0]).max() <= 2  # everything off: untouched


def _bgr(buffer: Gst.Buffer, info) -> np.ndarray:
    with frame_bgr(buffer, info) as bgr:
        return bgr.copy()


def _two_vehicles(props: str) -> np.ndarray:
    """The last BGR frame of trafficoverlay (with ``props``) over the 55.5 km/h car and the 81 km/h truck."""
    frames = []
    run_pipeline(f"{GREY_SRC},format=BGR ! tcroisource {_rois_prop([_roi_2d(object_id=4), _roi_3d()])} ! "
                 f"trafficoverlay {props} ! appsink name=sink",
                 on_buffer=lambda b, i: frames.append(_bgr(b, i)))
    return frames[-1]


def test_property_toggles_and_counters() -> None:
    frame = _two_vehicles
    full = frame("")
    assert _near(full, STYLE.box_unknown_bgr, 10).any() and _near(full, STYLE.box_towards_bgr, 10).any()
    counters = full[:40, :70]  # "vehicles: 0" (8 frames: none in view 0.5 s yet) and "in view: 2"
    # the translucent counters panel darkens the grey picture (128 -> 58) under white text
    assert (counters.max(axis=2) < 70).mean() > 0.4 and (counters.min(axis=2) > 200).any()
    no_boxes = frame("draw-boxes=false")
    assert not _near(no_boxes, STYLE.box_unknown_bgr, 10).any()
    assert not _near(no_boxes, STYLE.box_towards_bgr, 10).any()
    bare = frame("draw-boxes=false draw-labels=false draw-speeds=false draw-counters=false")
    assert np.abs(bare.astype(int) - bare[0, 0]).max() <= 2
    speeds_only = frame("draw-boxes=false draw-labels=false draw-counters=false")
    assert (speeds_only.max(axis=2) < 10).any()  # the speed labels remain


def test_speed_limit_draws_the_faster_vehicle_in_red() -> None:
    """speed-limit=70: the 81 km/h truck's 3D box turns red, the 55.5 km/h car keeps its colour."""
    def frame(props: str) -> np.ndarray:
        return _two_vehicles(f"draw-counters=false {props}")

    limited = frame("speed-limit=70")
    red = _near(limited, STYLE.speeding_bgr, 10)
    c = np.array(_roi_3d()["box"])
    assert red[int(c[1]):int(c[3]) + 1, int(c[0]):int(c[2]) + 1].sum() > 50
    assert not _near(limited, STYLE.box_towards_bgr, 10).any()
    assert _near(limited, STYLE.box_unknown_bgr, 10).any()  # the slower car, unchanged
    assert not _near(frame(""), STYLE.speeding_bgr, 10).any()  # no limit, no red
    assert not _near(frame("speed-limit=90"), STYLE.speeding_bgr, 10).any()  # both under it
    # a truck limit of its own: the truck (81 km/h) over its 70, the car held to the 90 of everyone else
    by_class = _near(frame("speed-limit=90 class-limits=truck=70"), STYLE.speeding_bgr, 10)
    assert by_class[int(c[1]):int(c[3]) + 1, int(c[0]):int(c[2]) + 1].sum() > 50
    cars_only = _near(frame("class-limits=car=50"), STYLE.speeding_bgr, 10)  # the car over 50, trucks unlimited
    x0, y0, x1, y1 = (int(v) for v in BOX)
    assert cars_only[y0:y1 + 1, x0:x1 + 1].sum() > 50 and not cars_only[int(c[1]):int(c[3]) + 1, int(c[0]):int(c[2]) + 1].any()


def test_the_counters_panel_keeps_off_the_traffic() -> None:
    """The panel's corner: fixed by panel-position, or (auto, the default) moved off a corner vehicles keep passing
    under — 12 s of a car under the top left; a wrong corner name is an error at start naming the property."""
    def panel(props: str, rois: list[dict], frames: int = 8) -> np.ndarray:
        out = []
        run_pipeline(f"{GREY_SRC.replace('num-buffers=8', f'num-buffers={frames}')},format=BGR ! tcroisource "
                     f"{_rois_prop(rois)} ! trafficoverlay draw-boxes=false draw-labels=false draw-speeds=false "
                     f"{props} ! appsink name=sink", on_buffer=lambda b, i: out.append(_bgr(b, i)))
        return out[-1].max(axis=2) < 70  # the panel's translucent dark box

    car = [{"box": [20.0, 5.0, 120.0, 50.0], "label": "car", "object_id": 4}]
    assert panel("", car)[8:30, 8:60].mean() > 0.3
    right = panel("panel-position=bottom-right", car)
    assert right[H - 30:H - 10, W - 60:W - 10].mean() > 0.3 and not right[:, :W // 4].any()
    assert right[8:20, W - 60:W - 10].mean() > 0.3  # no calibration: the status line, above the panel
    moved = panel("", car, frames=300)
    assert moved[8:30, W - 60:W - 10].mean() > 0.3 and not moved[:H // 2, :W // 2].any()
    with pytest.raises(PipelineError, match=r"trafficoverlay: panel-position 'left' is none of auto, top-left"):
        run_pipeline(f"{GREY_SRC} ! trafficoverlay panel-position=left ! fakesink")


def test_plain_detections_without_ids() -> None:
    """ROIs straight from a detector (no object_id, no trafficcal-vehicle) get their 2D box and label."""
    frames = []
    run_pipeline(f"{GREY_SRC},format=NV12 ! tcroisource {_rois_prop([_roi_2d(object_id=None, speed=None)])} ! "
                 "trafficoverlay ! videoconvert ! video/x-raw,format=BGR ! appsink name=sink",
                 on_buffer=lambda b, i: frames.append(_bgr(b, i)))
    f = frames[0]
    yellow = _near(f, STYLE.box_unknown_bgr, 60)
    assert yellow[int(BOX[1]), int(BOX[0]) + 5:int(BOX[2]) - 5].mean() > 0.9


def test_detections_no_track_holds_yet_are_drawn_faint_and_unlabelled() -> None:
    """A tracker upstream that has not confirmed a detection (min-hits not reached): the overlay draws its box thin and
    grey, without the class label a tracked vehicle gets, so that it does not look like a confirmed vehicle; without
    a tracker (test_plain_detections_without_ids) the same detection is a vehicle: yellow box and label."""
    register_plugin_file(ROOT / "elements" / "python" / "tracker.py")
    frames = []
    run_pipeline(f"{GREY_SRC},format=BGR ! tcroisource {_rois_prop([_roi_2d(object_id=None, speed=None)])} ! "
                 "tracker min-hits=1000 background=false ! trafficoverlay draw-counters=false ! appsink name=sink",
                 on_buffer=lambda b, i: frames.append(_bgr(b, i)))
    f = frames[-1]
    x0, y0, x1, y1 = (int(v) for v in BOX)
    assert not _near(f, STYLE.box_unknown_bgr, 60).any()
    grey = _near(f, STYLE.tentative_bgr, 12)
    assert grey[y0, x0 + 5:x1 - 5].mean() > 0.9 and not grey[y0 + 3, x0 + 5:x1 - 5].any()  # a 1 px line
    assert np.abs(f.astype(int) - 128)[:y0 - 1].max() <= 2  # nothing above the box: no label


def _kraten_still(tmp_path: Path, frame: int = 1000) -> tuple[Path, Path]:
    """One frame of kraten_cars.mp4 as a PNG (its cars then stand still, as parked cars do) and the clip's
    calibration (tests/test_speedometer_element.py's)."""
    from .test_speedometer_element import KRATEN_CALIBRATION

    cap = cv2.VideoCapture(str(require_shared(VIDEOS / "kraten_cars.mp4")))
    cap.set(cv2.CAP_PROP_POS_FRAMES, frame)
    ok, image = cap.read()
    cap.release()
    assert ok
    still, cal = tmp_path / "still.png", tmp_path / "kraten.json"
    cv2.imwrite(str(still), image)
    cal.write_text(json.dumps(KRATEN_CALIBRATION))
    return still, cal


@pytest.mark.shared
def test_parked_vehicles_are_not_counted_without_speedometer(tmp_path: Path) -> None:
    """``vehicledetect ! tracker ! trafficoverlay``, no speedometer: 3 s of a still of kraten_cars.mp4, whose cars
    NanoDet finds though they stand (as parked cars do).  The tracker follows them for the whole 3 s, but the overlay
    counts none of them — they moved under speedometer's ``min-moved`` (3 m along the road); before, every track in
    view 0.5 s was counted, parked cars once per time they were found again."""
    register_plugin_file(ROOT / "elements" / "python" / "vpdetect.py")
    register_plugin_file(ROOT / "elements" / "python" / "vehicledetect.py")
    register_plugin_file(ROOT / "elements" / "python" / "tracker.py")
    still, cal = _kraten_still(tmp_path)
    run = run_pipeline(f"filesrc location={still} ! pngdec ! imagefreeze num-buffers=75 ! video/x-raw,framerate=25/1 ! "
                       f"videoconvert ! video/x-raw,format=I420 ! vpdetect calibration-file={cal} ! vehicledetect "
                       f"model={require_shared(DETECTORS / 'nanodet_hpc203.onnx')} ! tracker ! trafficoverlay ! "
                       "appsink name=sink")
    spans = track_spans(run.frames)
    assert sum(b - a >= 2.0 for a, b in spans.values()) >= 3, spans  # parked cars, tracked
    counts = [m.fields for m in run.messages if m.name == "trafficcal-overlay-counts"]
    assert len(counts) == 1 and counts[0]["total"] == 0, counts


@pytest.mark.shared
def test_without_speedometer_the_counts_have_directions(tmp_path: Path) -> None:
    """``vehicledetect ! tracker ! trafficoverlay calibration-file=...``, no speedometer: 12 s of kraten_cars.mp4.
    The overlay counts each vehicle towards or away from VP1 by its own track's motion along the road (as speedometer
    decides it: here from the boxes' centres, the tracker having no calibration for reference points), from its first
    sighting on; before, every one of them was `unknown_direction`, and then still one whose direction was not yet
    decided from the points seen after it counted.  (``vpdetect calibration-file=... ! ... ! tracker ! speedometer !
    trafficoverlay`` counts 9 in these 12 s, all towards VP1, as the overlay alone does with vpdetect before it.)"""
    register_plugin_file(ROOT / "elements" / "python" / "vehicledetect.py")
    register_plugin_file(ROOT / "elements" / "python" / "tracker.py")
    _, cal = _kraten_still(tmp_path)
    video, model = require_shared(VIDEOS / "kraten_cars.mp4"), require_shared(DETECTORS / "nanodet_hpc203.onnx")
    pipeline = Gst.parse_launch(f"filesrc location={video} ! decodebin ! videoconvert ! video/x-raw,format=I420 ! "
                                f"vehicledetect name=d model={model} ! tracker ! "
                                f"trafficoverlay calibration-file={cal} ! fakesink")
    first_frames(pipeline.get_by_name("d").get_static_pad("sink"), 300)  # exactly (identity eos-after is not)
    run = run_pipeline(pipeline)
    counts = [m.fields for m in run.messages if m.name == "trafficcal-overlay-counts"]
    assert len(counts) == 1, counts
    c = counts[0]
    assert c["total"] >= 7 and c["towards_vp1"] == c["total"] and c["away_from_vp1"] == 0, c


@pytest.mark.parametrize("fmt", ["GRAY8", "I420"])
def test_grey_frames_are_said_to_get_a_grey_overlay(fmt: str) -> None:
    """A monochrome camera's GRAY8 is drawn on as it comes (in grey); the element says so once, with the way to
    colour that keeps the vehicles' metadata (a converter in front of the chain, not before the overlay)."""
    run = run_pipeline(f"{GREY_SRC},format={fmt} ! trafficoverlay ! appsink name=sink")
    grey = [i for i in run.infos if "GRAY8" in i]
    assert len(run.frames) == 8
    assert (len(grey) == 1 and "videoconvert ! video/x-raw,format=I420 ! vpdetect" in grey[0]) if fmt == "GRAY8" \
        else not grey, run.infos


def test_bad_calibration_file_is_a_readable_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(PipelineError, match=r"trafficoverlay: .*bad\.json: not valid JSON"):
        run_pipeline(f"{GREY_SRC},format=I420 ! trafficoverlay calibration-file={bad} ! fakesink")


def test_a_calibration_of_another_frame_size_is_an_error(tmp_path: Path) -> None:
    """Its grid and horizon would be drawn in the wrong place: refused, as vpdetect and speedometer refuse it."""
    big = save_calibration(Calibration(_camera(), (2 * W, 2 * H), source="test"), tmp_path / "big.json")
    with pytest.raises(PipelineError, match=rf"trafficoverlay: .*big\.json is a calibration of {2 * W}x{2 * H} "
                                            rf"images but the video is {W}x{H}"):
        run_pipeline(f"{GREY_SRC},format=I420 ! trafficoverlay calibration-file={big} ! fakesink")


def test_a_property_read_at_start_set_while_running_is_warned_about() -> None:
    """speed-limit is read when the element starts: set while the stream runs it is said to apply from the next
    start (gst-inspect: "changeable only in NULL or READY state"), and so it does: get_property answers the new value
    but the element goes on with the one it started with until it stops; the draw-* toggles apply at once, silently.
    """
    pipeline = Gst.parse_launch(f"{GREY_SRC} ! trafficoverlay name=o ! fakesink")
    overlay = pipeline.get_by_name("o")
    assert int(overlay.find_property("speed-limit").flags) & Gst.PARAM_MUTABLE_READY
    assert int(overlay.find_property("draw-grid").flags) & Gst.PARAM_MUTABLE_PLAYING
    overlay.set_property("speed-limit", 80.0)  # before the start: read at start, nothing to say
    done, kept = [], []

    def at_third_frame(pad, info):
        if not done and info.get_buffer().pts >= 3 * Gst.SECOND // 25:
            done.append(True)
            overlay.set_property("speed-limit", 50.0)
            overlay.set_property("draw-grid", False)
            kept.append((overlay.speed_limit, overlay.get_property("speed-limit"), overlay.draw_grid))
        return Gst.PadProbeReturn.OK

    overlay.get_static_pad("sink").add_probe(Gst.PadProbeType.BUFFER, at_third_frame)
    bus = pipeline.get_bus()
    pipeline.set_state(Gst.State.PLAYING)
    warnings = []
    try:
        while True:
            msg = bus.timed_pop_filtered(30 * Gst.SECOND, Gst.MessageType.EOS | Gst.MessageType.ERROR |
                                         Gst.MessageType.WARNING)
            assert msg is not None and msg.type != Gst.MessageType.ERROR, msg and msg.parse_error()
            if msg.type == Gst.MessageType.EOS:
                break
            warnings.append(msg.parse_warning()[0].message)
    finally:
        pipeline.set_state(Gst.State.NULL)
    assert done and warnings == ["trafficoverlay: speed-limit was set to 50.0 while the stream runs; it is read when "
                                 "the element starts, so the change applies from the next start (set it in the "
                                 "NULL or READY state: a prerolled PAUSED pipeline has started)"]
    assert kept == [(80.0, 50.0, False)]  # in force / answered / a live property
    assert overlay.speed_limit == 50.0  # stopped: in force from the next start


def test_started_again_without_a_calibration_it_draws_no_grid(tmp_path: Path) -> None:
    """The same pipeline run again (NULL, then PLAYING: an NVR reconnecting) after its calibration source lost its
    file: in the second run the overlay has no calibration and draws nothing, as a new one would (before, the base
    class kept the first run's calibration and the old road grid was drawn over the new stream)."""
    cal_path = save_calibration(Calibration(_camera(), (W, H), source="test"), tmp_path / "cal.json")
    pipeline = Gst.parse_launch(f"{GREY_SRC},format=I420 ! tcroisource name=s calibration-file={cal_path} ! "
                                "trafficoverlay draw-counters=false ! videoconvert ! video/x-raw,format=BGR ! "
                                "appsink name=sink")
    first: list[np.ndarray] = []
    second: list[np.ndarray] = []
    run_pipeline(pipeline, on_buffer=lambda b, i: first.append(_bgr(b, i)))
    pipeline.get_by_name("s").set_property("calibration-file", "")
    run = run_pipeline(pipeline, on_buffer=lambda b, i: second.append(_bgr(b, i)))
    assert run.calibrations == [] and len(second) == len(first) == 8
    assert np.abs(first[0].astype(int) - first[0][0, 0]).max() > 20  # run 1: the grid and horizon
    for f in second:
        assert np.abs(f.astype(int) - f[0, 0]).max() <= 2  # run 2: the plain grey frame


def test_gst_inspect_documents_every_property(tmp_path: Path) -> None:
    env = dict(os.environ, **gst_environment(), GST_REGISTRY=str(tmp_path / "registry.bin"))
    out = subprocess.run(["gst-inspect-1.0", "trafficoverlay"], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    for prop in ("draw-grid", "draw-horizon", "draw-boxes", "draw-labels", "draw-speeds", "draw-counters",
                 "grid-spacing", "line-thickness", "font-scale", "calibration-file", "speed-limit", "class-limits",
                 "panel-position", "zone"):
        assert prop in out.stdout
    assert "Draws the road grid, horizon, 3D vehicle boxes" in out.stdout


# --------------------------------------------------------------------------- pipelines/nvr-overlay.sh

SCRIPT = ROOT / "pipelines" / "nvr-overlay.sh"
CLIP = ROOT.parent / "shared" / "data" / "videos" / "sobral_simple_vehicle_counting_video.avi"  # 320x176, 374 frames


@pytest.fixture(scope="module")
def script_env(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    registry = tmp_path_factory.mktemp("gstreg") / "registry.bin"
    return dict(os.environ, GST_REGISTRY=str(registry))


def _script(env: dict[str, str], *args: str, **extra: str) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", str(SCRIPT), *args], env={**env, **extra}, capture_output=True, text=True,
                          timeout=300)


def _exists(env: dict[str, str], element: str) -> bool:
    full = dict(env, **gst_environment())
    return subprocess.run(["gst-inspect-1.0", "--exists", element], env=full, timeout=120).returncode == 0


def test_nvr_overlay_check_names_exactly_the_missing_elements(script_env: dict[str, str]) -> None:
    out = _script(script_env, "--check")
    wanted = ["uridecodebin", "videoconvert", "trafficoverlay", "h264parse", "x264enc", "vpdetect", "vehicledetect",
              "tracker", "speedometer", "mp4mux", "matroskamux", "mpegtsmux"]
    missing = [e for e in wanted if not _exists(script_env, e)]
    assert "trafficoverlay" not in missing
    if missing:
        assert out.returncode == 1 and out.stderr.strip() == f"nvr-overlay: missing element(s): {' '.join(missing)}"
    else:
        assert out.returncode == 0 and "all elements are installed" in out.stdout


def test_nvr_overlay_bad_input_is_a_clear_error(script_env: dict[str, str], tmp_path: Path) -> None:
    out = _script(script_env, str(tmp_path / "none.mp4"), str(tmp_path / "o.mp4"))
    assert out.returncode == 2 and "none.mp4: no such file" in out.stderr
    clip = require_clip()
    out = _script(script_env, str(clip), str(tmp_path / "o.avi"))
    assert out.returncode == 2 and "o.avi: unknown container (use .mp4, .mkv or .ts, or udp:// / srt://)" in out.stderr
    out = _script(script_env, str(clip), "udp://nohost", ANALYSIS="")
    assert out.returncode == 2 and "udp://nohost: expected udp://HOST:PORT" in out.stderr
    out = _script(script_env, str(clip), str(tmp_path / "o.mp4"), ENCODER="nosuchenc bitrate=1", ANALYSIS="")
    assert out.returncode == 2 and "GStreamer element 'nosuchenc' is not installed" in out.stderr
    out = _script(script_env, str(clip), str(tmp_path / "nodir" / "o.mp4"), ANALYSIS="")
    assert out.returncode == 2 and "nodir does not exist or is not writable" in out.stderr


def require_clip() -> Path:
    if not CLIP.exists():
        pytest.skip(f"needs the shared test data: {CLIP} is absent")
    return CLIP


def _frames(path: Path) -> list[np.ndarray]:
    return _decode(path)


def test_nvr_overlay_records_the_overlay_of_a_calibration(script_env: dict[str, str], tmp_path: Path) -> None:
    """The script's plumbing (uridecodebin, overlay, x264enc, fragmented MP4) on a real clip, analysis off."""
    clip = require_clip()
    w, h = 320, 176
    K = np.array([[350.0, 0, w / 2], [0, 350.0, h / 2], [0, 0, 1]])
    R = rotation_matrix(-60.0, 25.0, 0.0)
    cal_path = save_calibration(Calibration(Camera.from_KRt(K, R, -R @ np.array([0.0, 0.0, 8.0])), (w, h)),
                                tmp_path / "cal.json")
    for ext in ("mp4",):  # .mkv: see the RTSP test
        out_path = tmp_path / f"nvr.{ext}"
        out = _script(script_env, clip.as_uri(), str(out_path), str(cal_path), ANALYSIS="",
                      OVERLAY_OPTS="draw-counters=false")
        assert out.returncode == 0, out.stderr
        assert "trafficoverlay calibration-file=" in out.stderr  # the pipeline is printed
        frames = _frames(out_path)
        src = _frames(clip)
        assert len(frames) == len(src) == 374
        grid = (_near(frames[50], STYLE.grid_along_bgr, 60) | _near(frames[50], STYLE.grid_across_bgr, 60))
        grid_src = (_near(src[50], STYLE.grid_along_bgr, 60) | _near(src[50], STYLE.grid_across_bgr, 60))
        assert grid.sum() > 10 * max(1, grid_src.sum())


def test_nvr_overlay_full_chain(script_env: dict[str, str], tmp_path: Path) -> None:
    """With every element installed: decode, analyse, draw and record a real clip."""
    clip = require_clip()
    missing = [e for e in ("vpdetect", "vehicledetect", "tracker") if not _exists(script_env, e)]
    if missing:
        pytest.skip(f"elements not installed yet: {', '.join(missing)}")
    out_path = tmp_path / "nvr.mp4"
    out = _script(script_env, str(clip), str(out_path), str(tmp_path / "learned.json"))
    assert out.returncode == 0, out.stderr
    assert len(_frames(out_path)) == 374


@pytest.fixture
def rtsp_url():
    """An RTSP server in this process streaming 2 s of test video (needs gir1.2-gst-rtsp-server-1.0)."""
    yield from serve_rtsp(f"( {GREY_SRC.replace('num-buffers=8', 'num-buffers=50')},format=I420 ! "
                          "x264enc tune=zerolatency speed-preset=ultrafast key-int-max=10 ! "
                          "rtph264pay name=pay0 pt=96 )", "test")


def test_nvr_overlay_reads_rtsp(script_env: dict[str, str], tmp_path: Path, rtsp_url: str) -> None:
    """An RTSP camera in, the overlay recorded (the stream ends after 50 frames: the server sends EOS)."""
    out_path = tmp_path / "cam.mkv"
    out = _script(script_env, rtsp_url, str(out_path), ANALYSIS="", OVERLAY_OPTS="draw-counters=true")
    assert out.returncode == 0, out.stderr
    assert f"uri={rtsp_url}" in out.stderr
    frames = _frames(out_path)
    assert 40 <= len(frames) <= 50
    panel = frames[-1][8:30, 8:60]  # the counters panel: a translucent dark box with white text
    assert (panel.max(axis=2) < 80).mean() > 0.3 and (panel.min(axis=2) > 180).any()


def test_nvr_overlay_streams_mpeg_ts_over_udp(script_env: dict[str, str], tmp_path: Path) -> None:
    """udp:// output is paced in real time: a 2 s clip made here keeps the test short."""
    import socket

    clip = tmp_path / "short.mp4"
    run_pipeline(f"{GREY_SRC.replace('num-buffers=8', 'num-buffers=50')},format=I420 ! {ENCODE} ! "
                 f"filesink location={clip}")
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.5)
    port = sock.getsockname()[1]
    proc = subprocess.Popen(["bash", str(SCRIPT), str(clip), f"udp://127.0.0.1:{port}"],
                            env={**script_env, "ANALYSIS": ""}, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    received = bytearray()
    try:
        while proc.poll() is None or len(received) == 0:
            try:
                received += sock.recv(65536)
            except socket.timeout:
                if proc.poll() is not None:
                    break
    finally:
        proc.wait(timeout=120)
        sock.close()
    assert proc.returncode == 0, proc.stderr.read().decode()
    assert len(received) > 10_000 and len(received) % 188 == 0 and received[0] == 0x47  # MPEG-TS packets
    assert all(received[k] == 0x47 for k in range(0, len(received), 188))


@pytest.mark.shared
def test_a_file_gives_the_same_count_run_after_run_behind_a_late_display(tmp_path: Path) -> None:
    """kraten_cars.mp4's first 150 frames through ``vehicledetect ! tracker ! trafficoverlay calibration-file=...``,
    into a sink as a display is (sync, QoS) whose every frame is late: every frame is analysed and the count is the
    one of a sink that does not sync, run after run.  Before, the sink's QoS events reached the decoder and
    videoconvert, which skipped frames as the load came (in a run before the fix,
    vehicledetect never saw the frames at 0.12, 0.2, 0.28, 0.36 and 0.4 s, among others)."""
    from .test_gst_element import LATE_SINK
    from .test_speedometer_element import KRATEN_CALIBRATION

    register_plugin_file(ROOT / "elements" / "python" / "vehicledetect.py")
    register_plugin_file(ROOT / "elements" / "python" / "tracker.py")
    cal = tmp_path / "kraten.json"
    cal.write_text(json.dumps(KRATEN_CALIBRATION))
    video = require_shared(VIDEOS / "kraten_cars.mp4")

    def play(sink: str) -> tuple[dict, list[float]]:
        pipeline = Gst.parse_launch(f"filesrc location={video} ! decodebin ! videoconvert ! vehicledetect name=d ! "
                                    f"tracker ! trafficoverlay calibration-file={cal} ! {sink}")
        times = first_frames(pipeline.get_by_name("d").get_static_pad("sink"), 150)
        run = run_pipeline(pipeline)
        counts = [m.fields for m in run.messages if m.name == "trafficcal-overlay-counts"]
        assert len(counts) == 1, counts
        return counts[0], times

    want, times = play("fakesink")
    assert len(times) == 150 and want["total"] >= 3
    for _ in range(2):
        assert play(LATE_SINK) == (want, times)
