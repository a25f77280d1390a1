"""``pipelines/calibrate.sh`` and ``pipelines/measure.sh`` run as written (gst-launch-1.0) on a rendered clip."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gst_trafficcal.brnocompspeed import load_results
from gst_trafficcal.calibration import Calibration, load_calibration, save_calibration
from gst_trafficcal.geometry import Camera
from gst_trafficcal.outputs import read_events, read_events_csv

pytestmark = pytest.mark.gst

ROOT = Path(__file__).resolve().parents[1]
PIPELINES = ROOT / "pipelines"

@pytest.fixture(scope="module")
def clip(cuboid_clip_dense) -> Path:
    """The shared cuboid clip (tests/conftest.py)."""
    return cuboid_clip_dense


@pytest.fixture(scope="module", autouse=True)
def _registry(tmp_path_factory) -> None:
    """The module's private GStreamer registry (fresh element metadata), in pytest's temporary folder."""
    global REGISTRY
    REGISTRY = tmp_path_factory.mktemp("registry") / "registry.bin"


REGISTRY = Path()


def script(name: str, *args, **env: str) -> subprocess.CompletedProcess:
    """Run pipelines/NAME with the module's private GStreamer registry."""
    e = dict(os.environ, GST_REGISTRY=str(REGISTRY))
    e.update(env)
    return subprocess.run(["bash", str(PIPELINES / name), *map(str, args)], capture_output=True, text=True,
                          timeout=300, env=e)


@pytest.mark.parametrize("name", ["calibrate.sh", "measure.sh"])
def test_check_finds_every_element(name):
    proc = script(name, "--check")
    assert proc.returncode == 0, proc.stderr
    assert "all elements are installed" in proc.stdout


@pytest.mark.parametrize("name, args", [("calibrate.sh", ["{missing}", "{tmp}/cal.json"]),
                                        ("measure.sh", ["{missing}", "{tmp}/out"]),
                                        ("measure.sh", ["{video}", "{tmp}/out", "{missing}"]),
                                        ("calibrate.sh", ["only-one-argument"]),
                                        ("calibrate.sh", ["{video}", "{tmp}"]),  # a folder as the calibration
                                        ("nvr-overlay.sh", ["{video}", "{folder}"])])
def test_bad_arguments_are_one_clear_line(clip, tmp_path, name, args):
    fill = {"missing": tmp_path / "absent.mp4", "tmp": tmp_path, "video": clip / "video.mp4",
            "folder": tmp_path / "rec.mp4"}
    (tmp_path / "rec.mp4").mkdir()
    proc = script(name, *[a.format(**fill) for a in args])
    assert proc.returncode == 2
    prefix = name.split(".")[0]
    assert proc.stderr.startswith(f"{prefix}: error: ") and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    if "{folder}" in args or args[-1] == "{tmp}":  # a folder where a file is written: said so
        assert ": a folder, not a " in proc.stderr, proc.stderr
    assert not (tmp_path / "out" / "vehicles.jsonl").exists()


@pytest.fixture(scope="module")
def cuboid_video(tmp_path_factory) -> Path:
    """The vanishing-point tests' 24 s cuboid traffic scene (exact camera), as an MPEG-4 file."""
    import cv2

    from .test_vanishing import FPS, H, W, cached_scene

    path = tmp_path_factory.mktemp("cuboid") / "cuboid.mp4"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), FPS, (W, H))
    for frame in cached_scene(24.0):
        writer.write(cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR))
    writer.release()
    return path


def test_calibrate_learns_the_vanishing_points(cuboid_video, tmp_path):
    from .test_vanishing import H, W, scene_camera

    out = tmp_path / "cal.json"
    proc = script("calibrate.sh", cuboid_video, out, VPDETECT_OPTS="min-duration=8")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert f"wrote {out}" in proc.stdout and "vpdetect mode=learn" in proc.stderr
    cal = load_calibration(out)
    truth = scene_camera()
    assert cal.state == "vps" and cal.source == "vpdetect" and cal.camera.scale is None
    assert cal.image_size == (W, H)
    # the script delivers what vpdetect learnt (its accuracy is tested in test_vpdetect_element/test_vanishing):
    # VP1 within a few pixels; VP2, ~900 px outside the frame, within 10 % of its distance from the centre
    # (measured 1.8 px and 2-23 px as the edgelet stage evolved)
    assert np.hypot(*(cal.camera.vp1 - truth.vp1)) < 5.0, (cal.camera.vp1, truth.vp1)
    far = np.hypot(*(truth.vp2 - truth.pp))
    assert np.hypot(*(cal.camera.vp2 - truth.vp2)) < 0.1 * far, (cal.camera.vp2, truth.vp2)
    assert not list(tmp_path.glob(".calibrate.*"))  # no temporary file left behind


def static_video(path: Path) -> Path:
    """Four seconds of a static test pattern (no traffic) at 320x240, as an MP4 file."""
    subprocess.run(["gst-launch-1.0", "-q", "videotestsrc", "num-buffers=50", "pattern=smpte", "!",
                    "video/x-raw,width=320,height=240,framerate=25/2", "!", "x264enc", "!", "mp4mux", "!",
                    "filesink", f"location={path}"], check=True, capture_output=True, timeout=120)
    return path


def test_calibrate_says_why_when_the_video_has_no_traffic(tmp_path):
    """Four seconds of a static test pattern: no vehicle moves, so no calibration; vpdetect's reason is shown."""
    video = static_video(tmp_path / "static.mp4")
    out = tmp_path / "cal.json"
    out.write_text("an earlier calibration\n")
    proc = script("calibrate.sh", video, out)
    assert proc.returncode == 1, proc.stderr[-2000:]
    assert "calibrate: error: the calibration did not converge: " in proc.stderr
    reason = proc.stderr.split("did not converge: ")[1].strip()
    assert reason, proc.stderr
    assert out.read_text() == "an earlier calibration\n"  # not replaced by nothing
    assert not list(tmp_path.glob(".calibrate.*"))


def test_files_whose_names_a_uri_escapes_are_played(tmp_path):
    """A file name with '#', '%' or a space, in a folder with a space: input_uri writes the file:// URI
    percent-encoded, as Gst.filename_to_uri does. "cam #1.mp4" was opened as "cam " (the rest read as the URI's
    fragment) and "50%.mp4" as an escape: the pipeline failed with gst-launch-1.0's "Resource not found"."""
    from gst_trafficcal.gst._gi import Gst

    folder = tmp_path / "camera one"
    folder.mkdir()
    video = static_video(folder / "cam #1 50% é.mp4")
    uri = subprocess.run(["bash", "-c", '. "$0/lib.sh"; input_uri "$1"', PIPELINES, video], capture_output=True,
                         text=True, check=True).stdout.strip()
    assert uri == Gst.filename_to_uri(str(video))
    out = tmp_path / "out"
    proc = script("measure.sh", video, out)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert f"measure: 0 vehicles (0 with a speed) in {out / 'vehicles.jsonl'}" in proc.stdout


def test_nvr_overlay_takes_a_calibration_in_a_folder_with_a_space(tmp_path):
    """The default analysis chain was a string split again into words: calibration-file=/my cam/cal.json became
    two words and gst-launch-1.0 said 'no element "cam"'."""
    folder = tmp_path / "my cam"
    folder.mkdir()
    video = static_video(folder / "in.mp4")
    cam = Camera([160.0 + 3000.0, 40.0], [160.0 - 900.0, 60.0], [160.5, 120.5], 8.0)
    cal = save_calibration(Calibration(cam, (320, 240)), folder / "cal.json")
    proc = script("nvr-overlay.sh", video, folder / "overlay.mkv", cal)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert f"vpdetect calibration-file={cal} ! vehicledetect" in proc.stderr
    assert (folder / "overlay.mkv").stat().st_size > 1000


@pytest.mark.parametrize("name, muxer", [("o.MP4", "mp4mux fragment-duration=1000"), ("o.Mkv", "matroskamux"),
                                         ("o.TS", "mpegtsmux")])
def test_nvr_overlay_takes_the_container_from_the_extension_in_any_case(tmp_path, name, muxer):
    """A camera's recording named rec.MP4 was refused as an "unknown container" (exit code 2): the extension is
    read whatever its case. (The input does not exist: the pipeline is started with that muxer, then fails.)"""
    proc = script("nvr-overlay.sh", "file:///nonexistent/nope.mp4", tmp_path / name)
    assert proc.returncode not in (0, 2), proc.stderr[-2000:]
    assert f"! h264parse ! {muxer} ! filesink location={tmp_path / name}" in proc.stderr.splitlines()[0]


def test_uri_schemes_are_read_in_any_case(tmp_path):
    """URI schemes are case-insensitive (RFC 3986): nvr-overlay's output UDP://HOST:PORT is the UDP stream
    udp://HOST:PORT (it was refused as "unsupported output URI", exit code 2), SRT:// the SRT one, and an input
    RTSP://... the live camera rtsp://... is (a leaky queue and the stall watchdog; it was taken for a file)."""
    from .conftest import closed_port

    video = static_video(tmp_path / "in.mp4")
    port = closed_port()
    proc = script("nvr-overlay.sh", video, f"UDP://127.0.0.1:{port}", ANALYSIS="")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert f"! mpegtsmux alignment=7 ! udpsink host=127.0.0.1 port={port}" in proc.stderr
    proc = script("nvr-overlay.sh", "file:///nonexistent/nope.mp4", f"Srt://127.0.0.1:{port}", ANALYSIS="")
    assert f"! srtsink uri=srt://127.0.0.1:{port}" in proc.stderr.splitlines()[0]
    for name in ("nvr-overlay.sh", "measure.sh"):
        proc = script(name, f"RTSP://127.0.0.1:{closed_port()}/cam", tmp_path / "o.mkv" if name[0] == "n" else
                      tmp_path / "out", STALL_TIMEOUT="1")
        first = proc.stderr.splitlines()[0]
        assert "uridecodebin uri=rtsp://127.0.0.1:" in first and "! watchdog timeout=1000 !" in first, first
        assert "queue leaky=downstream max-size-buffers=25" in first, first


def test_nvr_overlay_records_a_video_of_an_odd_size(tmp_path):
    """A 321x241 video (MJPEG, VP8/VP9 allow odd sizes): the recording is scaled by a pixel to 320x240 for x264,
    which refused the odd size ("Can not initialize x264 encoder") and the script failed."""
    video = tmp_path / "odd.avi"
    subprocess.run(["gst-launch-1.0", "-q", "videotestsrc", "num-buffers=25", "pattern=smpte", "!",
                    "video/x-raw,width=321,height=241,framerate=25/1", "!", "jpegenc", "!", "avimux", "!",
                    "filesink", f"location={video}"], check=True, capture_output=True, timeout=120)
    proc = script("nvr-overlay.sh", video, tmp_path / "overlay.mp4", ANALYSIS="")
    assert proc.returncode == 0, proc.stderr[-2000:]
    import cv2

    cap = cv2.VideoCapture(str(tmp_path / "overlay.mp4"))
    assert (cap.get(cv2.CAP_PROP_FRAME_WIDTH), cap.get(cv2.CAP_PROP_FRAME_HEIGHT)) == (320, 240)
    assert cap.read()[0]
    cap.release()


def test_measure_writes_vehicles_and_matches_trafficcal_run(clip, tmp_path):
    """The product card's chain from a URI with the true calibration; the same numbers as `trafficcal run`."""
    out = tmp_path / "measure"
    proc = script("measure.sh", (clip / "video.mp4").as_uri(), out, clip / "calibration.json")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "vpdetect mode=fixed" in proc.stderr and "! vehicledetect ! speedometer" in proc.stderr
    assert "start-datetime" not in proc.stderr  # a file: no clock unless given
    events = read_events(out / "vehicles.jsonl").events
    measured = [e for e in events if e.measured]
    assert len(events) >= 10 and len(measured) >= 4, events
    assert f"{len(events)} vehicles ({len(measured)} with a speed)" in proc.stdout
    assert [e.to_dict() for e in read_events_csv(out / "vehicles.csv")] == [e.to_dict() for e in events]
    counts = (out / "intervals.csv").read_text().splitlines()  # the 12 s clip: one quarter hour, watched 12 s
    assert len(counts) >= 2 and counts[-1].startswith(f"0:00:00,0:15:00,12.0,all,all,{len(events)},{len(measured)},")
    truth = load_calibration(clip / "calibration.json").camera
    results = load_results(out / "system.json")
    assert results.calibration.scale == pytest.approx(truth.brno_scale())
    # rendered speeds of this scene: 60-110 km/h
    assert all(40 < e.speed_kmh < 140 for e in measured), measured

    run_out = tmp_path / "run"
    run = subprocess.run([sys.executable, "-m", "gst_trafficcal", "run", clip / "video.mp4", "--out", run_out,
                          "--calibration", clip / "calibration.json", "--no-overlay", "--detector", "background"],
                         capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    ran = read_events(run_out / "vehicles.jsonl").events
    key = lambda e: (e.first_timestamp_s, e.last_timestamp_s)  # noqa: E731 -- ids may be numbered differently
    assert sorted((key(e), e.speed_kmh) for e in ran if e.measured) == \
        sorted((key(e), e.speed_kmh) for e in measured)


def test_measure_dates_the_vehicles_of_a_live_source_and_of_a_recording_when_told(clip, tmp_path):
    proc = script("measure.sh", "rtsp://127.0.0.1:9/none", tmp_path / "live")  # nothing listens: fails fast
    assert proc.returncode != 0 and " start-datetime=now " in proc.stderr.splitlines()[0] + " "
    # a live camera does not wait: the analysis drops the oldest frames beyond a second of them, a file never
    assert " ! queue leaky=downstream max-size-buffers=25 max-size-bytes=0 max-size-time=0 ! vpdetect" in \
        proc.stderr.splitlines()[0]
    proc = script("measure.sh", clip / "video.mp4", tmp_path / "rec", clip / "calibration.json",
                  SPEEDOMETER_OPTS="start-datetime=2026-12-05T08:00:00Z")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert " ! queue ! vpdetect" in proc.stderr.splitlines()[0]
    events = read_events(tmp_path / "rec" / "vehicles.jsonl").events
    assert events and all(e.first_time == f"2026-12-05T08:00:{e.first_timestamp_s:06.3f}+00:00" for e in events)


def test_measure_started_again_on_a_live_source_keeps_the_earlier_results(clip, tmp_path):
    """A service running measure.sh on a camera, started again into its OUT_DIR: the earlier run's results move to
    OUT_DIR/earlier-<time>/ before the new run writes (a stream cannot be measured again); a file's are replaced."""
    live = tmp_path / "live"
    live.mkdir()
    (live / "vehicles.jsonl").write_text('{"id": 1}\n{"id": 2}\n')
    (live / "system.json").write_text('{"cars": []}')
    proc = script("measure.sh", "rtsp://127.0.0.1:9/none", live)  # nothing listens: fails fast, after keeping
    kept = list(live.glob("earlier-*"))
    assert len(kept) == 1 and (kept[0] / "vehicles.jsonl").read_text() == '{"id": 1}\n{"id": 2}\n', proc.stderr
    assert (kept[0] / "system.json").read_text() == '{"cars": []}'  # this run writes its own
    assert f"measure: kept the earlier run's 2 vehicles of a live stream in {kept[0]}" in proc.stderr
    script("measure.sh", "rtsp://127.0.0.1:9/none", live)  # nothing new measured: nothing more kept
    assert len(list(live.glob("earlier-*"))) == 1
    rec = tmp_path / "rec"
    rec.mkdir()
    (rec / "vehicles.jsonl").write_text('{"id": 1}\n')
    proc = script("measure.sh", clip / "video.mp4", rec, clip / "calibration.json")
    assert proc.returncode == 0 and not list(rec.glob("earlier-*")), proc.stderr[-2000:]
    assert read_events(rec / "vehicles.jsonl").events[0].label  # this run's vehicles


def test_measure_started_again_on_a_live_source_keeps_what_a_symlinked_output_leads_to(tmp_path):
    """An output that is a symlink (OUT_DIR/vehicles.jsonl -> a file elsewhere, as `trafficcal run` allows): the file
    it leads to is moved to OUT_DIR/earlier-<time>/ and the link stays for this run's file, as `trafficcal run` does.
    Before, the link itself was moved: earlier-*/vehicles.jsonl was a link (a relative one then led nowhere) and the
    new run wrote a regular file where the user's link had been."""
    live, data = tmp_path / "live", tmp_path / "data"
    live.mkdir()
    data.mkdir()
    (data / "today.jsonl").write_text('{"id": 1}\n{"id": 2}\n')
    (live / "vehicles.jsonl").symlink_to(Path("..") / "data" / "today.jsonl")  # relative, as ln -s makes it
    proc = script("measure.sh", "rtsp://127.0.0.1:9/none", live)  # nothing listens: fails fast, after keeping
    kept = list(live.glob("earlier-*"))
    assert len(kept) == 1, proc.stderr
    assert not (kept[0] / "vehicles.jsonl").is_symlink(), proc.stderr
    assert (kept[0] / "vehicles.jsonl").read_text() == '{"id": 1}\n{"id": 2}\n'
    assert (live / "vehicles.jsonl").is_symlink() and os.readlink(live / "vehicles.jsonl") == "../data/today.jsonl"
    assert f"measure: kept the earlier run's 2 vehicles of a live stream in {kept[0]}" in proc.stderr


def test_calibrate_writes_through_a_symlink_and_keeps_the_files_permissions(cuboid_video, tmp_path):
    """CALIBRATION given as a symlink (a camera's current calibration, linked from where a service reads it) and an
    earlier file there readable by its group only: the new calibration goes to the file the link leads to, the
    link stays and the mode stays, as the Python side's atomic_write does. Before, `mv -f` replaced the link with
    a regular file of a new file's mode."""
    store = tmp_path / "store"
    store.mkdir()
    (store / "cam1.json").write_text("an earlier calibration\n")
    (store / "cam1.json").chmod(0o640)
    link = tmp_path / "cal.json"
    link.symlink_to(store / "cam1.json")
    proc = script("calibrate.sh", cuboid_video, link, VPDETECT_OPTS="min-duration=8")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert f"wrote {link}" in proc.stdout
    assert link.is_symlink() and os.readlink(link) == str(store / "cam1.json")
    assert load_calibration(store / "cam1.json").state == "vps"
    assert (store / "cam1.json").stat().st_mode & 0o777 == 0o640
    assert not list(tmp_path.glob(".calibrate.*")) and not list(store.glob(".calibrate.*"))


def test_calibrate_refuses_a_named_pipe_as_its_output_at_once(clip, tmp_path):
    """Something other than a regular file at CALIBRATION (a named pipe) is one line at the start, as the Python
    side's writable_file says it; before, the whole video was calibrated and `mv` then replaced the pipe."""
    fifo = tmp_path / "cal.json"
    os.mkfifo(fifo)
    proc = script("calibrate.sh", clip / "video.mp4", fifo)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr[-2000:]
    assert proc.stderr.startswith(f"calibrate: error: {fifo}: not a regular file: cannot write the calibration")


def test_measure_without_a_scale_keeps_vehicles_and_says_why(clip, tmp_path):
    d = json.loads((clip / "calibration.json").read_text())
    d.update(scale=None, state="vps")
    d.pop("camera", None)
    d["camera_calibration"]["scale"] = None
    cal = tmp_path / "vps.json"
    cal.write_text(json.dumps(d))
    proc = script("measure.sh", clip / "video.mp4", tmp_path / "out", cal)
    assert proc.returncode == 0, proc.stderr[-2000:]
    events = read_events(tmp_path / "out" / "vehicles.jsonl").events
    assert len(events) >= 10 and not any(e.measured for e in events)
    assert all("no scale" in e.reason or "too short" in e.reason or "reference point" in e.reason for e in events)
    assert "measure: note: no vehicle has a speed" in proc.stderr


def test_measure_notes_the_first_reason_however_big_the_events_file(tmp_path):
    """No vehicle with a speed in a large events file (here a service's, appended to run after run): the note names
    the first vehicle's reason. It used to be cut from `grep | head -n 1`, and head's early exit killed grep with
    SIGPIPE: under pipefail the script ended with 141 and no note. 5000 lines give grep far more to write than a
    pipe holds (64 kB), so that happened every time."""
    out = tmp_path / "out"
    out.mkdir()
    first, later = "the calibration has no scale (the stream ended before the scale was known)", "too short"
    lines = [json.dumps({"id": i, "label": "car", "first_timestamp_s": i / 10, "last_timestamp_s": i / 10 + 2,
                         "speed_kmh": None, "reason": first if i == 1 else later, "lane": None, "direction": None})
             for i in range(1, 5001)]
    (out / "vehicles.jsonl").write_text("\n".join(lines) + "\n")
    proc = script("measure.sh", static_video(tmp_path / "static.mp4"), out, SPEEDOMETER_OPTS="append=true")
    assert proc.returncode == 0, proc.stderr[-2000:]
    total = len((out / "vehicles.jsonl").read_text().splitlines())
    assert total >= 5000 and f"measure: {total} vehicles (0 with a speed) in {out / 'vehicles.jsonl'}" in proc.stdout
    assert f"measure: note: no vehicle has a speed (first reason: {first}); speeds need a calibration" in proc.stderr


@pytest.mark.parametrize("name, uri, out, earlier, append", [
    ("measure.sh", "file:///nonexistent/nope.mp4", "out", 0, False),
    ("measure.sh", "file:///nonexistent/nope.mp4", "out", 2, True),
    ("measure.sh", "file:///nonexistent/nope.mp4", "out", 2, False),
    ("measure.sh", "rtsp://127.0.0.1:9/x", "out", 0, False),
    ("nvr-overlay.sh", "file:///nonexistent/nope.mp4", "o.mkv", 0, False)])
def test_a_failed_pipeline_is_said_to_have_failed(tmp_path, name, uri, out, earlier, append):
    """A source that cannot be played: gst-launch-1.0's error, then one line saying the pipeline failed (and what
    the events file holds, if anything) and its exit code; no summary as if it had succeeded. The run before's
    events file is left as it was, whether this run was to add to it or to replace it."""
    prefix = name.split(".")[0]
    events = tmp_path / out / "vehicles.jsonl"
    env = {}
    before = "".join(f'{{"id": {i}, "speed_kmh": 80.0}}\n' for i in range(earlier))
    if earlier:  # the run before's events file
        events.parent.mkdir()
        events.write_text(before)
    if append:
        env["SPEEDOMETER_OPTS"] = "append=true"
    proc = script(name, uri, tmp_path / out, STALL_TIMEOUT="3", **env)  # now and then rtspsrc waits, silent
    assert proc.returncode not in (0, 2), proc.stderr[-2000:]  # gst-launch-1.0's code, not a usage error's
    assert f"{prefix}: " not in proc.stdout and "vehicles (" not in proc.stdout + proc.stderr, proc.stdout
    so_far = f"; {events} holds {earlier} vehicles" if earlier else ""
    assert proc.stderr.strip().splitlines()[-1] == \
        f"{prefix}: error: the pipeline failed (gst-launch-1.0 exit code {proc.returncode}){so_far}", proc.stderr
    if earlier:
        assert events.read_text() == before


def test_measure_on_a_source_that_sends_nothing_stops_after_stall_timeout(tmp_path):
    """A live source that never sends a frame (a UDP port nobody sends to; now and then an RTSP camera whose
    connection failed without rtspsrc saying so, which used to leave measure.sh waiting for ever) ends the run with
    GStreamer's watchdog error after STALL_TIMEOUT seconds, so a service is restarted; a bad value stops at once."""
    from .conftest import closed_port

    uri = f"udp://127.0.0.1:{closed_port()}"
    proc = script("measure.sh", uri, tmp_path / "out", STALL_TIMEOUT="2")
    assert proc.returncode != 0 and "Watchdog triggered" in proc.stderr, proc.stderr[-2000:]
    assert f"uridecodebin uri={uri} ! watchdog timeout=2000 ! videoconvert" in proc.stderr  # as trafficcal run
    assert proc.stderr.strip().splitlines()[-1].startswith("measure: error: the pipeline failed (gst-launch-1.0 exit")
    assert "measure: " not in proc.stdout  # no summary as if it had succeeded
    bad = script("measure.sh", uri, tmp_path / "bad", STALL_TIMEOUT="soon")
    assert bad.returncode == 2 and "STALL_TIMEOUT must be a number of seconds, got 'soon'" in bad.stderr


@pytest.fixture
def rtsp_clip(clip):
    """The clip served live over RTSP by a server in this process (needs gir1.2-gst-rtsp-server-1.0)."""
    from .conftest import serve_rtsp

    yield from serve_rtsp(f"( filesrc location={clip / 'video.mp4'} ! qtdemux ! h264parse ! rtph264pay name=pay0 "
                          "pt=96 )", "clip")


def test_measure_stopped_by_sigterm_completes_its_files(clip, rtsp_clip, tmp_path):
    """SIGTERM to the script alone (what docker stop sends to a container's first process, systemctl stop to a
    service's): gst-launch-1.0 would die at once, or run on with the script gone; the script passes it on as Ctrl-C
    and waits, so the stream is ended, every file completed and the summary printed."""
    import signal
    import time

    out = tmp_path / "out"
    env = dict(os.environ, GST_REGISTRY=str(REGISTRY))
    proc = subprocess.Popen(["bash", str(PIPELINES / "measure.sh"), rtsp_clip, str(out),
                             str(clip / "calibration.json")], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env)
    events = out / "vehicles.jsonl"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None and not (events.is_file() and events.read_text()):
        time.sleep(0.2)
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 0, stderr[-2000:]
    written = read_events(events).events
    assert f"measure: {len(written)} vehicles" in stdout, stdout + stderr[-2000:]
    assert len(written) >= 2 and max(e.last_timestamp_s for e in written) < 11.5  # stopped before the clip's end
    assert load_results(out / "system.json").calibration is not None  # completed at the end of the stream
    assert read_events_csv(out / "vehicles.csv") == written


@pytest.mark.parametrize("name", ["calibrate.sh", "measure.sh", "nvr-overlay.sh"])
@pytest.mark.parametrize("flag", ["--help", "-h"])
def test_help_prints_the_usage_header(name, flag):
    """--help and -h print the script's header comment (usage, arguments, environment) to stdout and succeed."""
    header = []
    for line in (PIPELINES / name).read_text().splitlines()[1:]:
        if not line.startswith("#"):
            break
        header.append(line[2:] if line.startswith("# ") else line[1:])
    proc = script(name, flag)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    assert proc.stdout == "\n".join(header) + "\n"
    assert f"pipelines/{name} INPUT " in proc.stdout and "STALL_TIMEOUT" in proc.stdout


def matroska_finalised(path: Path) -> bool:
    """Whether matroskamux completed the file at the end of the stream: it writes the Segment with an unknown size
    (0x01ffffffffffffff) and puts the real one in when it finishes (with the duration and the index)."""
    data = path.read_bytes()
    pos = data.find(bytes.fromhex("18538067"))  # the Segment element, after the EBML header
    size = data[pos + 4:pos + 12]
    return pos > 0 and size[0] == 0x01 and int.from_bytes(size[1:], "big") == len(data) - pos - 12


def processes_mentioning(text: str) -> list[int]:
    """The pids of the running processes whose command line contains text."""
    pids = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            if text.encode() in cmdline.read_bytes():
                pids.append(int(cmdline.parent.name))
        except OSError:
            pass
    return pids


def test_nvr_overlay_stopped_by_sigterm_completes_the_recording(rtsp_clip, tmp_path):
    """SIGTERM to nvr-overlay.sh alone (systemctl stop, docker stop) ends it as Ctrl-C does: gst-launch-1.0 ends the
    stream (EOS), the recording is completed and the script waits for that. It used to exit at once with 143 (an
    interrupted wait under set -e), leaving gst-launch-1.0 to finish the file on its own, orphaned."""
    import signal
    import time

    from gst_trafficcal.gst._gi import Gst

    out = tmp_path / "overlay.mkv"
    env = dict(os.environ, GST_REGISTRY=str(REGISTRY))
    # its output in files, not pipes: a pipe stays open (communicate() waits) as long as an orphan holds it
    with open(tmp_path / "stdout", "w") as o, open(tmp_path / "stderr", "w") as e:
        proc = subprocess.Popen(["bash", str(PIPELINES / "nvr-overlay.sh"), rtsp_clip, str(out)], stdout=o,
                                stderr=e, env=env)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None and not (out.is_file() and out.stat().st_size > 50_000):
        time.sleep(0.2)
    time.sleep(3)  # recording: a few seconds of the 12 s stream
    assert proc.poll() is None, (tmp_path / "stderr").read_text()[-2000:]
    proc.send_signal(signal.SIGTERM)
    proc.wait(timeout=120)
    left = processes_mentioning(f"location={out}")  # gst-launch-1.0 still running without the script
    finalised = matroska_finalised(out)
    stdout, stderr = (tmp_path / "stdout").read_text(), (tmp_path / "stderr").read_text()
    try:
        assert not left, f"gst-launch-1.0 ({left}) outlived the script (exit code {proc.returncode})"
        assert proc.returncode == 0, stderr[-2000:]
        assert "Forcing EOS on the pipeline" in stdout, stdout[-2000:]
        assert finalised
    finally:
        deadline = time.monotonic() + 60  # an orphan (the old script) finishes on its own: let it
        while left and time.monotonic() < deadline:
            time.sleep(0.2)
            left = processes_mentioning(f"location={out}")
    import gi

    gi.require_version("GstPbutils", "1.0")
    from gi.repository import GstPbutils

    info = GstPbutils.Discoverer.new(30 * Gst.SECOND).discover_uri(out.as_uri())
    assert info.get_result() == GstPbutils.DiscovererResult.OK and info.get_video_streams()
    assert 1.0 < info.get_duration() / Gst.SECOND < 11.5  # what was recorded until the stop, before the clip's end


@pytest.fixture
def rtsp_clip_dropped_on_stop(clip):
    """The clip served live over RTSP by a server that closes the connection when the client asks PAUSE or
    TEARDOWN."""
    from .conftest import serve_rtsp

    yield from serve_rtsp(f"( filesrc location={clip / 'video.mp4'} ! qtdemux ! h264parse ! rtph264pay name=pay0 "
                          "pt=96 )", "clip", drop_on_stop=True)


@pytest.mark.parametrize("name", ["nvr-overlay.sh", "measure.sh"])
def test_a_camera_dropping_the_connection_as_it_is_stopped_is_a_clean_stop(name, clip, rtsp_clip_dropped_on_stop,
                                                                            tmp_path):
    """SIGTERM: the stream is ended (EOS) and every output completed; then gst-launch-1.0 stops the source, and a
    camera that closes the connection on its PAUSE or TEARDOWN (rtspsrc sends either) makes rtspsrc fail. That used
    to end the script with gst-launch's exit code 1 (a service stopped shown as failed; now and then in CI, from the
    test server); it says so and succeeds."""
    import signal
    import time

    out = tmp_path / ("overlay.mkv" if name == "nvr-overlay.sh" else "out")
    done = out if name == "nvr-overlay.sh" else out / "vehicles.jsonl"
    args = [rtsp_clip_dropped_on_stop, str(out)]
    if name == "measure.sh":
        args.append(str(clip / "calibration.json"))
    with open(tmp_path / "stdout", "w") as o, open(tmp_path / "stderr", "w") as e:
        proc = subprocess.Popen(["bash", str(PIPELINES / name), *args], stdout=o, stderr=e,
                                env=dict(os.environ, GST_REGISTRY=str(REGISTRY)))
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None and not (done.is_file() and done.stat().st_size):
        time.sleep(0.2)
    assert proc.poll() is None, (tmp_path / "stderr").read_text()[-2000:]
    proc.send_signal(signal.SIGTERM)
    proc.wait(timeout=120)
    stdout, stderr = (tmp_path / "stdout").read_text(), (tmp_path / "stderr").read_text()
    assert "EOS received - stopping pipeline" in stdout, stdout[-2000:]
    assert "GstRTSPSrc:source: " in stderr, stderr[-2000:]  # the source did fail as it was stopped
    assert proc.returncode == 0, stderr[-2000:]
    prefix = name.removesuffix(".sh")
    assert f"{prefix}: note: the stream was ended and every output completed before the source failed" in stderr
    if name == "nvr-overlay.sh":
        assert matroska_finalised(out)
    else:
        written = read_events(out / "vehicles.jsonl").events
        assert f"measure: {len(written)} vehicles" in stdout and len(written) >= 1, stdout[-2000:]
        assert load_results(out / "system.json").calibration is not None


def test_measure_analyses_a_rotated_video_upright(tmp_path):
    """A phone's video (frames stored 640x360, turned a quarter by its display matrix) is measured as it is shown,
    360x640, as trafficcal run does: a calibration of that picture is taken (vpdetect refused it before)."""
    from .conftest import encoded, rotation_tagged
    from .test_run import PORTRAIT

    video = rotation_tagged(encoded(tmp_path / "stored.mp4", "width=640,height=360", frames=25), tmp_path / "p.mp4")
    cal = tmp_path / "portrait.json"
    cal.write_text(json.dumps(PORTRAIT))
    proc = script("measure.sh", video, tmp_path / "out", cal)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "videoflip video-direction=90r ! videoscale" in proc.stderr


def test_the_calibration_keeps_orientation_for_measure_and_overlay(cuboid_video, tmp_path):
    """calibrate.sh with ORIENTATION keeps it in the calibration (field orientation, as trafficcal calibrate does);
    measure.sh and nvr-overlay.sh given that file without ORIENTATION turn the picture by it and say so (they
    analysed the stored picture before, which the calibration does not fit); ORIENTATION=auto overrides it."""
    from .conftest import encoded
    from .test_vanishing import H, W

    cal = tmp_path / "cal.json"
    proc = script("calibrate.sh", cuboid_video, cal, VPDETECT_OPTS="min-duration=8", ORIENTATION="horiz")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "videoflip video-direction=horiz ! videoscale" in proc.stderr
    assert json.loads(cal.read_text())["orientation"] == "horiz"
    short = encoded(tmp_path / "short.mp4", f"width={W},height={H}", frames=10, src=cuboid_video)
    for name, out in (("measure", tmp_path / "out"), ("nvr-overlay", tmp_path / "overlay.mp4")):
        run = script(f"{name}.sh", short, out, cal, ORIENTATION="")
        assert run.returncode == 0, run.stderr[-2000:]
        assert f"{name}: orientation kept in {cal}: horiz (ORIENTATION=auto" in run.stderr
        assert "videoflip video-direction=horiz ! videoscale" in run.stderr
    auto = script("measure.sh", short, tmp_path / "auto", cal, ORIENTATION="auto")
    assert auto.returncode == 0 and "kept in" not in auto.stderr, auto.stderr[-2000:]
    assert "videoflip video-direction=identity ! videoscale" in auto.stderr


def test_measure_turns_an_untagged_video_as_orientation_says(tmp_path):
    """ORIENTATION=90r (trafficcal run --orientation's values): a camera on its side, whose video has no tag, is
    measured upright and a calibration of the upright picture is taken; a bad value is one line before any work."""
    from .conftest import encoded
    from .test_run import PORTRAIT

    video = encoded(tmp_path / "stored.mp4", "width=640,height=360", frames=25)
    cal = tmp_path / "portrait.json"
    cal.write_text(json.dumps(PORTRAIT))
    proc = script("measure.sh", video, tmp_path / "out", cal, ORIENTATION="90r")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "videoflip video-direction=90r ! videoscale" in proc.stderr
    bad = script("measure.sh", video, tmp_path / "bad", cal, ORIENTATION="sideways")
    assert bad.returncode == 2 and bad.stderr.strip() == (
        "measure: error: ORIENTATION must be one of auto, identity, 90r, 180, 90l, horiz, vert, ul-lr, ur-ll, got "
        "'sideways'")
    assert "ORIENTATION" in script("measure.sh", "--help").stdout


def test_lib_takes_uri_schemes_in_any_case(tmp_path):
    """lib.sh's own checks read a URI's scheme in any case (RFC 3986), not only after input_uri lower-cased it:
    is_live_uri took RTSP://cam/stream for a file (no leaky queue, no stall watchdog)."""
    def lib(call: str, *args) -> subprocess.CompletedProcess:
        return subprocess.run(["bash", "-c", f'die() {{ echo "$*" >&2; exit 2; }}; . "$0/lib.sh"; {call}',
                               PIPELINES, *map(str, args)], capture_output=True, text=True, timeout=30)

    for uri in ("RTSP://cam/stream", "Udp://239.0.0.1:5000", "SRT://cam:9000", "rtsp://cam/stream"):
        assert lib('is_live_uri "$1"', uri).returncode == 0, uri
    for uri in ("FILE:///v.mp4", "HTTP://host/v.mp4", "/data/rtsp.mp4"):
        assert lib('is_live_uri "$1"', uri).returncode == 1, uri
    assert "leaky=downstream" in lib('analysis_queue "$1"', "RTSP://cam/stream").stdout
    assert lib('lower_scheme "$1"', "UDP://Host:5000/Path").stdout == "udp://Host:5000/Path\n"
    assert lib('lower_scheme "$1"', "/Data/Cam.mp4").stdout == "/Data/Cam.mp4\n"
    (tmp_path / "vehicles.jsonl").write_text("{}\n")  # a file's earlier results are replaced, not kept aside
    assert lib('keep_earlier_live "$1" "$2"', "FILE:///v.mp4", tmp_path).stdout == ""
    assert not list(tmp_path.glob("earlier-*"))


def test_lib_says_which_elements_are_missing_and_exits_2():
    """require_elements (the three scripts' one check): nothing and on for installed elements; else one line each
    naming the element and where it comes from, and exit code 2."""
    def require(*elements: str) -> subprocess.CompletedProcess:
        return subprocess.run(["bash", "-c", '. "$0/lib.sh"; require_elements measure some-package "$@"; echo on',
                               PIPELINES, *elements], capture_output=True, text=True, timeout=60)

    ok = require("identity", "videoconvert")
    assert ok.returncode == 0 and ok.stdout == "on\n" and ok.stderr == "", ok.stderr
    bad = require("identity", "nosuchelement")
    assert bad.returncode == 2 and bad.stdout == "", bad.stdout
    assert bad.stderr.splitlines() == ["measure: error: GStreamer element 'nosuchelement' is not installed (install "
                                       "the GStreamer plugin that provides it, e.g. some-package)"]
