"""The vpdetect element in real GStreamer pipelines: learning, events/bus messages, file load/save, bad input."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from gst_trafficcal.calibration import Calibration, load_calibration, save_calibration
from gst_trafficcal.geometry import Camera
from gst_trafficcal.gst.element import register_plugin_file
from gst_trafficcal.gst.pipeline import PipelineError, run_pipeline

from .test_vanishing import FPS, H, W, cached_scene, render_scene

ROOT = Path(__file__).resolve().parents[1]
CAPS = f"video/x-raw,format=I420,width={W},height={H},framerate=15/1"
FAST = "min-duration=8 max-duration=60"


@pytest.fixture(scope="module", autouse=True)
def _register():
    register_plugin_file(ROOT / "elements" / "python" / "vpdetect.py")


@pytest.fixture(scope="module")
def frames():
    import cv2

    return [cv2.cvtColor(f, cv2.COLOR_GRAY2BGR) for f in cached_scene(24.0)]


def _states(run):
    return [m.fields["state"] for m in run.messages if m.name == "trafficcal-calibration"]


def test_learns_passes_frames_through_and_announces_each_state(frames, tmp_path):
    out = tmp_path / "cams" / "cam1" / "cal.json"  # its folders made when the calibration is saved
    run = run_pipeline(f"appsrc name=src ! vpdetect {FAST} calibration-file={out} ! appsink name=sink",
                       frames, CAPS, fps=FPS)
    assert len(run.frames) == len(frames)
    assert _states(run) == ["learning", "vps"]
    assert [c.state for c in run.calibrations] == ["learning", "vps"]
    assert run.frames[0].calibration.state == "learning"
    final = run.frames[-1].calibration
    assert final.state == "vps" and final.camera is not None and final.camera.scale is None
    saved = load_calibration(out)
    assert saved.id == final.id and saved.state == "vps"
    msg = [m for m in run.messages if m.name == "trafficcal-calibration"][-1]
    assert re.fullmatch(r"vpdetect\d+", msg.source) and msg.fields["focal"] > 0  # numbered per process


def test_constant_speed_property_switches_the_move_of_vp1_along_the_lanes(frames):
    """On (default), the calibration says how far VP1 moved along the lanes and on how many tracks (event fields
    confidence_vp1_along_px / confidence_speed_tracks); off, VP1 is the tracks' lines' meeting point alone."""
    finals = {}
    for prop in ("", "constant-speed=false"):
        run = run_pipeline(f"appsrc name=src ! vpdetect {FAST} {prop} ! appsink name=sink", frames, CAPS, fps=FPS)
        finals[prop] = run.frames[-1].calibration
        msg = [m for m in run.messages if m.name == "trafficcal-calibration"][-1]
        assert ("confidence_vp1_along_px" in msg.fields) == (prop == "")
    on, off = finals[""], finals["constant-speed=false"]
    assert on.state == off.state == "vps"
    assert on.confidence["speed_tracks"] >= 100
    moved = np.linalg.norm(on.camera.vp1 - off.camera.vp1)  # along the lanes, then across them
    assert moved == pytest.approx(np.hypot(on.confidence["vp1_along_px"], on.confidence["vp1_across_px"]), abs=0.05)


def test_loads_an_existing_file_without_learning(tmp_path):
    cam = Camera(np.array([300.0, -80.0]), np.array([-900.0, -20.0]), np.array([W / 2, H / 2]))
    path = save_calibration(Calibration(cam, (W, H), state="vps", source="test"), tmp_path / "c.json")
    blank = [np.zeros((H, W, 3), np.uint8)] * 3
    for mode in ("auto", "fixed"):
        run = run_pipeline(f"appsrc name=src ! vpdetect mode={mode} calibration-file={path} ! appsink name=sink",
                           blank, CAPS, fps=FPS)
        assert _states(run) == ["vps"]
        assert run.frames[0].calibration.id == Calibration(cam, (W, H), state="vps").id


def test_static_video_fails_at_eos_with_the_reason(tmp_path):
    """Nothing learnt, nothing saved — and no folder left behind: the calibration file's folders, checked writable
    at start (made and removed again), are made only when a calibration is saved (once, every run that learnt
    nothing left them empty)."""
    import cv2

    static = [cv2.cvtColor(f, cv2.COLOR_GRAY2BGR) for f in render_scene(3.0, traffic=False)]
    out = tmp_path / "cams" / "cam1" / "never.json"
    run = run_pipeline(f"appsrc name=src ! vpdetect min-duration=1 calibration-file={out} ! appsink name=sink",
                       static, CAPS, fps=FPS)
    assert _states(run) == ["learning", "failed"]
    failed = run.calibrations[-1]
    assert failed.state == "failed" and failed.reason.startswith("no traffic")
    assert not out.exists() and list(tmp_path.iterdir()) == []  # nothing learnt, nothing saved, no empty folders


def test_bad_configuration_and_caps_are_clear_errors(tmp_path):
    blank = [np.zeros((H, W, 3), np.uint8)]
    with pytest.raises(PipelineError, match="mode=fixed needs calibration-file"):
        run_pipeline("appsrc name=src ! vpdetect mode=fixed ! appsink name=sink", blank, CAPS)
    with pytest.raises(PipelineError, match="no such file|not found"):
        run_pipeline(f"appsrc name=src ! vpdetect mode=fixed calibration-file={tmp_path / 'x.json'} ! "
                     "appsink name=sink", blank, CAPS)
    with pytest.raises(PipelineError, match="unknown mode"):
        run_pipeline("appsrc name=src ! vpdetect mode=sometimes ! appsink name=sink", blank, CAPS)
    with pytest.raises(PipelineError, match="focal range"):
        run_pipeline("appsrc name=src ! vpdetect focal-range=9,1 ! appsink name=sink", blank, CAPS)
    with pytest.raises(PipelineError, match=r"vpdetect: the minimum duration \(30 s\) is longer than the maximum "
                                            r"\(10 s\)"):
        run_pipeline("appsrc name=src ! vpdetect min-duration=30 max-duration=10 ! appsink name=sink", blank, CAPS)
    with pytest.raises(PipelineError, match="vpdetect: zone 'a,b c,d e,f': polygon 1 is not a list of x,y numbers"):
        run_pipeline('appsrc name=src ! vpdetect zone="a,b c,d e,f" ! appsink name=sink', blank, CAPS)
    with pytest.raises(PipelineError, match=rf"vpdetect: zone 5000,0 6000,0 6000,50: it covers no pixel of the "
                                            rf"{W}x{H} frame"):
        run_pipeline('appsrc name=src ! vpdetect zone="5000,0 6000,0 6000,50" ! appsink name=sink', blank, CAPS)
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(PipelineError, match="not valid JSON"):
        run_pipeline(f"appsrc name=src ! vpdetect calibration-file={bad} ! appsink name=sink", blank, CAPS)
    with pytest.raises(PipelineError, match="YUY2"):
        run_pipeline(f"videotestsrc num-buffers=2 ! video/x-raw,format=YUY2,width={W},height={H} ! vpdetect ! "
                     "fakesink")
    (tmp_path / "plain").write_text("a file, not a folder")  # a calibration to learn that could not be saved:
    for mode in ("learn", "auto"):  # said at start, not after the minutes of video the learning takes
        with pytest.raises(PipelineError, match=r"vpdetect: .*plain/c\.json: cannot write the calibration file there "
                                                r"\(.*plain is not a folder\)"):
            run_pipeline(f"appsrc name=src ! vpdetect mode={mode} calibration-file={tmp_path / 'plain' / 'c.json'} "
                         "! appsink name=sink", blank, CAPS)


def test_a_calibration_file_through_a_symlink_stays_a_link_and_a_named_pipe_is_refused(frames, tmp_path):
    """The learnt calibration is written whole and renamed into place: through a symlink onto its target (the link
    stays, the target gets the calibration), where once the link was replaced by a regular file. A named pipe would
    be replaced by a regular file: refused at start, naming it."""
    import os
    import stat

    (tmp_path / "etc").mkdir()
    (tmp_path / "etc" / "cam1.json").write_text('{"old": true}')
    link = tmp_path / "cal.json"
    link.symlink_to("etc/cam1.json")
    run_pipeline(f"appsrc name=src ! vpdetect {FAST} mode=learn calibration-file={link} ! appsink name=sink",
                 frames, CAPS, fps=FPS)
    assert link.is_symlink() and os.readlink(link) == "etc/cam1.json"
    assert load_calibration(tmp_path / "etc" / "cam1.json").state == "vps"
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    with pytest.raises(PipelineError, match=rf"vpdetect: {fifo}: a named pipe, not a regular file: cannot write the "
                                            "calibration file there"):
        run_pipeline(f"appsrc name=src ! vpdetect {FAST} mode=learn calibration-file={fifo} ! appsink name=sink",
                     frames[:2], CAPS, fps=FPS)
    assert stat.S_ISFIFO(fifo.lstat().st_mode)


def test_gst_launch_documents_every_property():
    import os
    import subprocess
    import tempfile

    from gst_trafficcal.gst.env import gst_environment

    env = dict(os.environ)
    env.update(gst_environment())
    env["GST_REGISTRY"] = str(Path(tempfile.mkdtemp()) / "registry.bin")
    out = subprocess.run(["gst-inspect-1.0", "vpdetect"], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    for prop in ("calibration-file", "mode", "min-duration", "max-duration", "downscale", "focal-range", "horizon-max",
                 "method", "constant-speed", "view-check"):
        assert prop in out.stdout


def test_element_and_cli_calibrate_a_clip_alike(tmp_path):
    """The element (Y plane of the decoder's I420) and `calibrate_video` (the CLI's path: OpenCV's FFmpeg decode of
    the same file) analyse the same luma frames with the same timestamps, so they give the same calibration."""
    import cv2

    from gst_trafficcal.diamond import angle_between
    from gst_trafficcal.geometry import homogeneous
    from gst_trafficcal.vanishing.calibrator import CalibratorConfig, calibrate_video

    clip = tmp_path / "cuboids.mp4"
    writer = cv2.VideoWriter(str(clip), cv2.VideoWriter_fourcc(*"mp4v"), FPS, (W, H))
    for f in cached_scene(24.0):
        writer.write(cv2.cvtColor(f, cv2.COLOR_GRAY2BGR))
    writer.release()
    cli = calibrate_video(clip, CalibratorConfig(min_duration=8.0, max_duration=60.0)).calibration
    run = run_pipeline(f"filesrc location={clip} ! decodebin ! videoconvert ! video/x-raw,format=I420 ! "
                       f"vpdetect {FAST} ! appsink name=sink")
    elem = run.frames[-1].calibration
    assert cli.state == elem.state == "vps"
    a, b = cli.camera, elem.camera
    for p, q in ((a.vp1, b.vp1), (a.vp2, b.vp2)):
        assert angle_between(homogeneous(p), homogeneous(q), a.pp, a.focal) < 1e-4
    # (BGR -> COLOR_BGR2GRAY in the CLI, as before, moved the focal length by 0.05 % and VP1 by 0.15 px here)
    assert abs(a.focal - b.focal) < 1e-5 * a.focal
    assert cli.confidence["seconds"] == pytest.approx(elem.confidence["seconds"], abs=1e-6)
    # both keep the view they were learnt on (the same thumbnails of the same luma frames)
    from gst_trafficcal.vanishing.view import compare_views, decode_view

    (v1, w1), (v2, w2) = decode_view(cli.view), decode_view(elem.view)
    assert w1 == w2 == W and np.abs(v1.astype(int) - v2).max() <= 2 and not compare_views(v1, v2, W).moved


@pytest.fixture(scope="module")
def learnt(frames, tmp_path_factory):
    """A calibration vpdetect learnt on the scene and saved, with the view it was learnt on."""
    path = tmp_path_factory.mktemp("learnt") / "cal.json"
    run_pipeline(f"appsrc name=src ! vpdetect {FAST} calibration-file={path} ! appsink name=sink", frames, CAPS,
                 fps=FPS)
    return path


def test_the_saved_calibration_holds_the_view_it_was_learnt_on(learnt, frames):
    from gst_trafficcal.vanishing.view import VIEW_WIDTH, ViewAccumulator, compare_views, decode_view

    view, width = decode_view(load_calibration(learnt).view)
    assert width == W and view.shape == (round(VIEW_WIDTH * H / W), VIEW_WIDTH)
    acc = ViewAccumulator()
    for f in frames[:100]:  # the first seconds of the same scene (its traffic passing)
        acc.add(f[:, :, 0])
    match = compare_views(view, acc.view(), W)
    assert not match.moved and match.similarity > 0.9, match


def _shifted(frames, dx):
    return [np.roll(f, dx, axis=1) for f in frames]


@pytest.mark.parametrize("case", ["same view", "moved, auto", "moved, fixed", "moved, check off"])
def test_a_moved_camera_is_noticed(learnt, frames, tmp_path, case):
    """The file's calibration is used for its own view; a camera moved by 5 % of the width is noticed: mode auto
    learns anew (and replaces the file), mode fixed warns and keeps the file's calibration."""
    path = tmp_path / "cal.json"
    path.write_text(learnt.read_text())
    stored = load_calibration(path)
    clip = frames if case == "same view" else _shifted(frames, W // 20)
    props = {"same view": "", "moved, auto": "", "moved, fixed": "mode=fixed",
             "moved, check off": "view-check=false"}[case]
    run = run_pipeline(f"appsrc name=src ! vpdetect {FAST} calibration-file={path} {props} ! appsink name=sink",
                       clip, CAPS, fps=FPS)
    warned = [w for w in run.warnings if "camera view differs" in w]
    final = run.calibrations[-1]
    if case == "same view":
        assert _states(run) == ["learning", "vps"] and final.id == stored.id and not warned  # held 5 s, then used
    elif case == "moved, auto":
        assert len(warned) == 1 and "learning a new calibration" in warned[0] and "shifted by (+" in warned[0]
        assert _states(run) == ["learning", "learning", "vps"] and final.id != stored.id
        assert load_calibration(path).id == final.id  # the new calibration replaced the file
    elif case == "moved, fixed":
        assert len(warned) == 1 and "recalibrate" in warned[0]
        assert _states(run) == ["vps"] and final.id == stored.id and load_calibration(path).id == stored.id
    else:
        assert _states(run) == ["vps"] and final.id == stored.id and not warned


def test_a_second_vpdetect_says_it_replaces_the_calibration_from_upstream(learnt, frames):
    """Two vpdetects in one chain (a pipeline assembled by hand): the second, learning its own, replaces the first
    one's calibration downstream, and says so once instead of in silence."""
    run = run_pipeline(f"appsrc name=src ! vpdetect mode=fixed calibration-file={learnt} ! vpdetect {FAST} ! "
                       "appsink name=sink", frames[:30], CAPS, fps=FPS)
    said = [w for w in run.warnings if "a calibration also comes from upstream" in w]
    assert len(said) == 1 and "(vpdetect, vps; another vpdetect?)" in said[0] and "keep one of them" in said[0], \
        run.warnings
    alone = run_pipeline(f"appsrc name=src ! vpdetect mode=fixed calibration-file={learnt} ! appsink name=sink",
                         frames[:30], CAPS, fps=FPS)
    assert not [w for w in alone.warnings if "from upstream" in w]


def test_started_again_it_finds_the_known_view_as_a_new_one_would(learnt, frames, tmp_path):
    """views-dir holds the scene's calibration: each run of the same pipeline (NULL, then PLAYING again: an NVR
    reconnecting) recognises the view at the start (an INFO) and uses its calibration. Before, the second run took
    the first run's view for the one in force and said the camera had moved "at 0.0 s" (a warning, with moved_at,
    so speedometer discarded the tracks seen before)."""
    from gst_trafficcal.calibration import save_view
    from gst_trafficcal.gst._gi import Gst

    known = load_calibration(learnt)
    views = tmp_path / "views"
    save_view(known, views)
    pipeline = Gst.parse_launch(f"appsrc name=src ! vpdetect {FAST} views-dir={views} ! appsink name=sink")
    first, second = (run_pipeline(pipeline, frames[:75], CAPS, fps=FPS) for _ in range(2))
    for run in (first, second):
        assert [c.moved_at for c in run.calibrations] == [None, None] and run.calibrations[-1].id == known.id
        assert len(run.infos) == 1 and "the stream shows a view calibrated before" in run.infos[0], run.infos
        assert run.warnings == []
    assert [c.id for c in second.calibrations] == [c.id for c in first.calibrations]


def test_a_known_view_is_used_only_for_a_picture_turned_the_same_way(learnt, frames, tmp_path):
    """views-dir keeps each view with the ``orientation`` its picture was turned by (a camera mounted upside down,
    ``videoflip video-direction=180 ! vpdetect orientation=180``): a vpdetect of that orientation uses it at the
    start; one of another orientation (the camera re-mounted, or another one) does not — a camera mounted another
    way is another view — says why, and learns its own, kept with its own orientation; a scale added to the view
    (bbscale, speedometer) keeps the view's orientation.  Before, the views folder
    kept no orientation: the view was used whatever the orientation, and the calibration-file it was written to
    then said how the picture of the other mounting was turned."""
    from gst_trafficcal.calibration import load_views, save_view, view_key
    from gst_trafficcal.imaging import orientation_of_file

    known = load_calibration(learnt)
    views = tmp_path / "views"
    views.mkdir()
    save_calibration(known, views / f"{view_key(known)}.json", orientation="180")  # as save_view(known, views, "180")
    same = run_pipeline(f"appsrc name=src ! vpdetect {FAST} orientation=180 views-dir={views} ! appsink name=sink",
                        frames[:75], CAPS, fps=FPS)
    assert same.calibrations[-1].id == known.id and same.warnings == [], same.warnings
    other = run_pipeline(f"appsrc name=src ! vpdetect {FAST} views-dir={views} ! appsink name=sink", frames, CAPS,
                         fps=FPS)
    assert other.infos == [] and other.calibrations[0].state == "learning", other.infos
    assert any("views-dir" in w and "orientation 180, not auto" in w and "not used" in w for w in other.warnings), \
        other.warnings
    assert other.calibrations[-1].camera is not None
    # (the rendered scene gives the very same vanishing points, so the new view's file is the old one's: the
    # view learnt last is kept, with its orientation)
    assert [c.id for c in load_views(views, known.image_size, "auto")[0]] == [other.calibrations[-1].id]
    kept = tmp_path / "kept"
    save_view(known, kept, "180")
    assert orientation_of_file(kept / f"{view_key(known)}.json") == "180"
    save_view(known.with_scale(0.05), kept)  # a scale kept with the view later (bbscale): its orientation stays
    assert orientation_of_file(kept / f"{view_key(known)}.json") == "180"


def test_a_mode_set_while_running_applies_from_the_next_start_only():
    """mode=fixed set while the stream runs is answered "applies from the next start", and so it does: a frame-size
    change later in the run is a new view learnt, as in the mode the element started in (before, the new mode was
    read there and the pipeline stopped: "... at 0.8 s;  is a calibration of 160x120 frames", naming no file); the
    next start is in mode fixed (which needs a calibration-file)."""
    from gst_trafficcal.gst._gi import Gst

    pipeline = Gst.parse_launch("videotestsrc num-buffers=30 pattern=ball ! video/x-raw,format=I420,width=160,"
                                "height=120,framerate=25/1 ! videoscale ! capsfilter name=cf caps=video/x-raw,"
                                "width=160,height=120 ! vpdetect name=v ! appsink name=sink")
    vpdetect, seen = pipeline.get_by_name("v"), []

    def probe(pad, info):
        seen.append(info.get_buffer().pts)
        if len(seen) == 10:
            vpdetect.set_property("mode", "fixed")
        elif len(seen) == 20:
            pipeline.get_by_name("cf").set_property("caps", Gst.Caps.from_string("video/x-raw,width=80,height=60"))
        return Gst.PadProbeReturn.OK

    vpdetect.get_static_pad("src").add_probe(Gst.PadProbeType.BUFFER, probe)
    run = run_pipeline(pipeline)
    assert run.frames[-1].frame_size == (80, 60)
    assert run.warnings[0] == ("v: vpdetect: mode was set to 'fixed' while the stream runs; it is read when the "
                               "element starts, so the change applies from the next start (set it in the NULL or "
                               "READY state: a prerolled PAUSED pipeline has started)")
    assert [w for w in run.warnings if "frame size changed" in w] == [
        "v: vpdetect: the frame size changed from 160x120 to 80x60 at 0.8 s: another view; learning a new calibration"]
    assert vpdetect.get_property("mode") == "fixed"
    with pytest.raises(PipelineError, match="mode=fixed needs calibration-file"):
        run_pipeline(pipeline)


def test_one_calibration_file_or_views_dir_given_to_two_vpdetects_is_refused_at_start(tmp_path):
    """Two vpdetects learning into one calibration-file or one views-dir (a tee's branches, two cameras' pipelines
    of one NVR process): an error at start naming the file and the other writer, as for speedometer's outputs
    (gst.file_claims). Before, each replaced the other's calibration without a word. Reading one file (mode fixed)
    is no writing; a file written by a pipeline that has stopped is free again."""
    cal, views = tmp_path / "cal.json", tmp_path / "views"
    views.mkdir()
    src = "videotestsrc num-buffers=3 ! video/x-raw,format=I420,width=160,height=120,framerate=15/1 ! tee name=t"

    def two(first: str, second: str) -> str:
        return f"{src} t. ! queue ! vpdetect {first} ! fakesink t. ! queue ! vpdetect {second} ! fakesink"

    with pytest.raises(PipelineError, match=r"calibration-file .*cal.json is written already by .*GstVpdetect:"
                                            r"vpdetect\d+ \(its calibration-file\): two vpdetects learning into one"):
        run_pipeline(two(f"calibration-file={cal}", f"mode=learn calibration-file={tmp_path / '.' / cal.name}"))
    with pytest.raises(PipelineError, match=r"views-dir .*views is written already by .*vpdetect\d+ \(its "
                                            r"views-dir\)"):
        run_pipeline(two(f"views-dir={views}", f"views-dir={tmp_path / 'x' / '..' / 'views'}"))
    with pytest.raises(PipelineError, match=r"views-dir .*cal.json is also its calibration-file"):
        run_pipeline(f"{src} ! vpdetect calibration-file={cal} views-dir={cal} ! fakesink")
    other = tmp_path / "other"
    run_pipeline(two(f"calibration-file={cal} views-dir={views}", f"calibration-file={other / 'cal.json'} "
                                                                  f"views-dir={other}"))
    save_calibration(Calibration(Camera(np.array([100.0, -80.0]), np.array([-900.0, -20.0]), np.array([80.0, 60.0])),
                                 (160, 120), state="vps"), cal)
    run_pipeline(two(f"mode=fixed calibration-file={cal}", f"mode=fixed calibration-file={cal}"))  # readers only
    for _ in range(2):  # the claims of the refused runs and of a finished one are given back
        run_pipeline(f"{src} ! vpdetect calibration-file={cal} views-dir={views} ! fakesink")
