"""``trafficcal run``: one pass through the GStreamer elements on a rendered clip, its outputs, and bad input."""

from __future__ import annotations

import html
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from gst_trafficcal.brnocompspeed import load_results
from gst_trafficcal.calibration import load_calibration
from gst_trafficcal.drawing import ZONE_BGR
from gst_trafficcal.outputs import read_events, read_events_csv
from gst_trafficcal.run_status import read_status

from .conftest import count_frames, serve_rtsp

pytestmark = pytest.mark.gst


@pytest.fixture(scope="module")
def clip(cuboid_clip) -> Path:
    """The shared cuboid clip (tests/conftest.py)."""
    return cuboid_clip


def trafficcal(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "gst_trafficcal", *map(str, args)], capture_output=True, text=True,
                          timeout=300)


def user_lines(stderr: str) -> list[str]:
    """stderr without GStreamer's harmless PyGObject warnings."""
    return [ln for ln in stderr.splitlines() if ln.strip() and "should be floating" not in ln]


def one_line_error(proc: subprocess.CompletedProcess) -> str:
    """The run's one error line on stderr (beside the progress bar's last state, also on stderr since stop 54)."""
    assert proc.returncode == 2, proc.stdout[-1500:] + proc.stderr[-1500:]
    lines = [ln for ln in user_lines(proc.stderr) if "━" not in ln]
    assert len(lines) == 1 and lines[0].startswith("trafficcal: error: "), proc.stderr
    assert "Traceback" not in proc.stderr
    return lines[0]


START = "2026-12-05T07:59:55+01:00"  # the clip's 12 s span 08:00: two 15-minute intervals


@pytest.fixture(scope="module")
def with_truth(clip, tmp_path_factory):
    """The run with the clip's true calibration (scale known) and its ground truth."""
    out = tmp_path_factory.mktemp("run")
    proc = trafficcal("run", clip / "video.mp4", "--out", out, "--calibration", clip / "calibration.json",
                      "--gt", clip / "gt_data.pkl", "--speed-limit", "80", "--start-time", START)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    return out, proc


def test_run_writes_every_output(clip, with_truth):
    out, proc = with_truth
    assert "! vehicledetect model=\"vehicleseg\" !" in proc.stdout  # the default detector: the shipped segmenter
    for name in ("calibration.json", "system.json", "vehicles.jsonl", "vehicles.csv", "intervals.csv", "overlay.mp4",
                 "report.html", "evaluation.json"):
        assert (out / name).is_file(), name
    truth = load_calibration(clip / "calibration.json")
    cal = load_calibration(out / "calibration.json")
    assert cal.camera.scale == pytest.approx(truth.camera.scale)
    assert cal.camera.vp1 == pytest.approx(truth.camera.vp1) and cal.camera.vp2 == pytest.approx(truth.camera.vp2)
    events = read_events(out / "vehicles.jsonl").events
    assert len(events) >= 8 and sum(e.measured for e in events) >= 3, events
    assert [e.to_dict() for e in read_events_csv(out / "vehicles.csv")] == [e.to_dict() for e in events]
    # every measured speed is a plausible motorway speed (the scene's traffic: about 60-110 km/h)
    assert all(40 < e.speed_kmh < 140 for e in events if e.measured), events
    results = load_results(out / "system.json")
    assert results.calibration.scale == pytest.approx(truth.camera.brno_scale())
    assert {t.id for t in results.cars} <= {e.id for e in events}
    ev = json.loads((out / "evaluation.json").read_text())
    assert ev["matched"] >= 1 and ev["speed"]["abs_kmh"]["max"] < 3.0, ev
    cap = cv2.VideoCapture(str(out / "overlay.mp4"))
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    ok, frame = cap.read()
    cap.release()
    assert ok and frame.shape[:2] == (270, 480) and n == 150
    report = (out / "report.html").read_text()
    assert report.count("data:image/png;base64,") >= 3  # calibration picture, histogram, cumulative errors
    assert "Per lane" in report and "gt_data.pkl" in report
    assert report.count("data:image/png;base64,") >= 4 and 'alt="where the lanes are"' in report  # lanes pictured
    # the progress bar on stderr, the results on stdout (a run's `> file` gets the results only)
    assert "measuring" in proc.stderr and "measuring" not in proc.stdout and "Against gt_data.pkl" in proc.stdout
    assert not [ln for ln in user_lines(proc.stderr) if "warning" in ln], proc.stderr
    cond = load_calibration(out / "calibration.json").conditioning()  # how firmly the view pins the speeds down
    assert f"View: VP2 lies {cond.vp2_widths:.1f} image widths away" in " ".join(proc.stdout.split())
    assert "speeds change under a 0.1° error of VP2" in report
    # --speed-limit 80: to the overlay and the meter, counted in the summary and the report
    assert (' speed-limit=80 start-datetime="2026-12-05T07:59:55+01:00" remeasure=true ! trafficoverlay speed-limit=80 !'
            in proc.stdout)  # a file: the vehicles measured while the calibration settled are measured again
    speeds = [e.speed_kmh for e in events if e.measured]
    over = sum(v > 80 for v in speeds)
    assert f"V85 {np.percentile(speeds, 85):.1f}" in proc.stdout
    assert f"{over} of {len(speeds)} over the 80 km/h limit" in proc.stdout
    assert "over 80 km/h" in report
    # --start-time: every vehicle dated; the count per 15 min aligned to the clock (the 12 s clip spans 08:00)
    from datetime import datetime, timedelta

    start = datetime.fromisoformat(START)
    for e in events:
        assert datetime.fromisoformat(e.first_time) == start + timedelta(seconds=round(e.first_timestamp_s, 3))
    import csv

    with open(out / "intervals.csv", newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["lane"] == "all"]
    mids = [start + timedelta(seconds=0.5 * (e.first_timestamp_s + e.last_timestamp_s)) for e in events]
    eight = datetime.fromisoformat("2026-12-05T08:00:00+01:00")
    want = [(r0, n) for r0, n in (("2026-12-05T07:45:00+01:00", sum(m < eight for m in mids)),
                                  ("2026-12-05T08:00:00+01:00", sum(m >= eight for m in mids))) if n]
    assert [(r["interval_start"], int(r["vehicles"])) for r in rows] == want and len(want) == 2
    assert [float(r["observed_s"]) for r in rows] == pytest.approx([5.0, 7.0], abs=0.1)  # 07:59:55 to 08:00:07
    assert "Per interval (15 min)" in report and "first seen" in report
    assert "(5 s watched)" in report and "(7 s watched)" in report  # two quarter hours, each watched in part
    # status.json: the finished run's state, as monitoring reads it
    status = read_status(out / "status.json")
    assert status.state == "finished" and status.error == "" and status.source == str(clip / "video.mp4")
    assert (status.vehicles, status.measured) == (len(events), sum(e.measured for e in events))
    assert status.last_vehicle_s == pytest.approx(max(e.last_timestamp_s for e in events), abs=1e-6)
    assert status.calibration["id"] == cal.id and status.calibration["scale_m"] == pytest.approx(cal.camera.scale,
                                                                                               abs=1e-4)
    assert status.calibration["speed_sensitivity_pct"] == round(cal.conditioning().speed_pct, 3)
    assert status.position_s == pytest.approx(12.0, abs=0.2) and status.duration_s == pytest.approx(12.0, abs=0.2)
    assert status.camera_moves == 0 and (status.speed_x is None or status.speed_x > 0)
    assert (status.frames, status.frames_dropped) == (150, 0)  # every frame of the file, none dropped
    shown = trafficcal("status", out)  # for people and health checks: ended as it should, exit 0
    assert shown.returncode == 0 and "status.json: finished since" in shown.stdout, shown.stdout + shown.stderr
    assert f"speeds {cal.conditioning().speed_pct:.1f} % per 0.1° of VP2" in shown.stdout
    assert f"{len(events)}, {sum(e.measured for e in events)} measured" in shown.stdout and "healthy" in shown.stdout


def test_stream_ending_before_calibration_converges(clip, tmp_path):
    """12 s are too short to learn VP2 (vpdetect needs 20 s): every vehicle kept, unmeasured, with the reason."""
    proc = trafficcal("run", clip / "video.mp4", "--out", tmp_path, "--no-overlay")
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    cal = load_calibration(tmp_path / "calibration.json")
    assert cal.state == "failed" and cal.camera is None and cal.reason
    events = read_events(tmp_path / "vehicles.jsonl").events
    assert len(events) >= 5
    assert all(not e.measured and e.reason.startswith("no calibration") for e in events), events
    assert f"not measured: {len(events)} x no calibration\n" in proc.stdout  # one line for one cause
    assert not (tmp_path / "overlay.mp4").exists()
    assert "did not converge" in proc.stderr and cal.reason in " ".join(proc.stderr.split())
    report = (tmp_path / "report.html").read_text()
    assert "no calibration" in report
    # the run's warnings in the report too, as on the terminal (bbscale's says only there why there is no scale)
    assert "<h2>Warnings</h2>" in report and "bbscale: no scale: waiting for the vanishing points" in report


def test_a_video_of_an_odd_size_runs_with_its_overlay(clip, tmp_path):
    """A 481x271 video (VP8, VP9 and MJPEG allow odd sizes; an NVR's cropped export): the run measures it and
    overlay.mp4 is scaled by a pixel to 480x270 — x264 cannot encode 4:2:0 of an odd size, and its refusal ("Can not
    initialize x264 encoder") failed the whole run."""
    from gst_trafficcal.gst.pipeline import run_pipeline

    from .conftest import cut_after

    odd = tmp_path / "odd.webm"
    run_pipeline(cut_after(f"filesrc location={clip / 'video.mp4'} ! decodebin ! identity name=cut ! videoconvert ! "
                           f"videoscale ! video/x-raw,width=481,height=271 ! vp8enc deadline=1 ! webmmux ! "
                           f"filesink location={odd}", 75), timeout=120)
    proc = trafficcal("run", odd, "--out", tmp_path / "out", "--detector", "background")
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    cap = cv2.VideoCapture(str(tmp_path / "out" / "overlay.mp4"))
    assert (cap.get(cv2.CAP_PROP_FRAME_WIDTH), cap.get(cv2.CAP_PROP_FRAME_HEIGHT)) == (480, 270)
    assert cap.get(cv2.CAP_PROP_FRAME_COUNT) == 75  # every frame of the odd-size video, none lost to the scaling
    cap.release()


@pytest.mark.shared
def test_a_video_of_non_square_pixels_is_measured_in_square_ones(tmp_path):
    """kraten_cars.mp4 stored 480x360 with pixel-aspect-ratio 4/3 (shown 640x360, as DVRs store D1): the run scales
    it to square pixels, so the 640x360 calibration fits and the speeds are the square clip's.  Learnt on the
    squeezed pixels, the calibration made every speed 35 % too high (mean 41.3 km/h against 30.5 over 47 s);
    with this calibration the run was refused (a calibration of 640x360 images but the video is 480x360)."""
    from .conftest import VIDEOS, encoded, require_shared

    kraten = require_shared(VIDEOS / "kraten_cars.mp4")
    cal = tmp_path / "kraten.json"
    cal.write_text(json.dumps({"format": "gst-trafficcal-calibration", "version": 1, "state": "calibrated",
                               "source": "test", "image_size": [640, 360], "vp1": [284.665, -60.182],
                               "vp2": [7089.213, 345.467], "pp": [320.0, 180.0], "scale": 9.4156}))
    speeds = {}
    for name, caps in (("square", "width=640,height=360"), ("squeezed", "width=480,height=360,pixel-aspect-ratio=4/3")):
        video = encoded(tmp_path / f"{name}.mp4", caps, frames=200, src=kraten)  # the same 200 frames, exactly
        proc = trafficcal("run", video, "--out", tmp_path / name, "--calibration", cal, "--no-overlay")
        assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
        events = read_events(tmp_path / name / "vehicles.jsonl").events
        speeds[name] = sorted(e.speed_kmh for e in events if e.measured)
    assert len(speeds["square"]) >= 4 and len(speeds["squeezed"]) >= 4
    ratio = np.median(speeds["squeezed"]) / np.median(speeds["square"])
    assert 0.95 < ratio < 1.05, speeds


def test_without_a_scale_vehicles_are_written_and_the_command_says_so(clip, tmp_path):
    d = json.loads((clip / "calibration.json").read_text())
    d.update(scale=None, state="vps")
    d.pop("camera", None)
    d["camera_calibration"]["scale"] = None
    (tmp_path / "vps.json").write_text(json.dumps(d))
    out = tmp_path / "out"
    proc = trafficcal("run", clip / "video.mp4", "--out", out, "--calibration", tmp_path / "vps.json",
                      "--no-overlay")
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    events = read_events(out / "vehicles.jsonl").events
    assert len(events) >= 5
    cal = load_calibration(out / "calibration.json")
    if cal.camera.scale is None:  # no scale stage found one: said clearly, every vehicle with the reason
        assert "speeds need a scale" in proc.stderr
        assert all(not e.measured and e.reason for e in events)
        assert any("no scale" in e.reason for e in events), events
    else:  # bbscale (when installed) found the scale: then vehicles are measured and nothing is said
        assert cal.source != "synth" and any(e.measured for e in events)
        assert "speeds need a scale" not in proc.stderr


def test_not_a_video(clip, tmp_path):
    """A file that is not a video, and a zone that covers none of a video's frame, are refused before anything in
    --out is replaced: an earlier run's outputs there stay as they were (its vehicles are not passed off as this
    run's), and so does its status.json — what an operator's monitoring reads still describes the outputs in --out
    (the refusal is the command's one line and exit code); it once said "failed" with the refusal instead."""
    from gst_trafficcal.run_status import StatusFile

    bad = tmp_path / "notes.mp4"
    bad.write_text("this is not a video\n" * 50)
    out = tmp_path / "out"
    out.mkdir()
    StatusFile(out / "status.json", str(clip / "video.mp4")).update(state="finished", vehicles=7, measured=6)
    earlier = {name: f"the earlier run's {name}\n" for name in ("vehicles.jsonl", "vehicles.csv", "calibration.json",
                                                                 "system.json", "report.html")}
    for name, text in earlier.items():
        (out / name).write_text(text)
    earlier["status.json"] = (out / "status.json").read_text()
    line = one_line_error(trafficcal("run", bad, "--out", out, "--no-overlay"))
    assert str(bad) in line and "not a video" in line and f"the earlier outputs in {out} are left as they were" in line
    assert {name: (out / name).read_text() for name in earlier} == earlier
    (tmp_path / "empty.mp4").write_bytes(b"")
    line = one_line_error(trafficcal("run", tmp_path / "empty.mp4", "--out", out, "--no-overlay"))
    assert "no frame could be decoded" in line and {name: (out / name).read_text() for name in earlier} == earlier
    spaced = tmp_path / "cam 7.mp4"  # a file:// URI is the file it names: checked as one (%20 is its space)
    spaced.write_text("this is not a video either\n" * 50)
    line = one_line_error(trafficcal("run", spaced.as_uri(), "--out", out, "--no-overlay"))
    assert f"{spaced}: cannot be processed" in line and "%20" not in line
    assert {name: (out / name).read_text() for name in earlier} == earlier
    line = one_line_error(trafficcal("run", clip / "video.mp4", "--out", out, "--no-overlay", "--zone",
                                     "5000,5000 6000,5000 6000,6000"))
    assert "the detection zone 5000,5000 6000,5000 6000,6000: it covers no pixel of the" in line
    assert {name: (out / name).read_text() for name in earlier} == earlier


def test_a_refused_video_leaves_no_new_out_folder(clip, tmp_path):
    """--out is made (and checked writable) before the video is looked at; when the video is then refused, the
    folders made for it are removed again and the refusal speaks of no earlier outputs. Before, an empty --out (and
    the folders on the way to it) stayed behind, and the line said "the earlier outputs in ... are left as they
    were" of a folder that had none."""
    bad = tmp_path / "notes.mp4"
    bad.write_text("this is not a video\n" * 50)
    out = tmp_path / "new" / "out"
    line = one_line_error(trafficcal("run", bad, "--out", out, "--no-overlay"))
    assert line.endswith(f"{bad}: cannot be processed: no frame could be decoded from it (not a video, empty, or "
                         "damaged)"), line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.mp4"]
    line = one_line_error(trafficcal("run", clip / "video.mp4", "--out", out, "--no-overlay", "--zone",
                                     "5000,5000 6000,5000 6000,6000"))
    assert "it covers no pixel of the" in line and sorted(p.name for p in tmp_path.iterdir()) == ["notes.mp4"]
    (tmp_path / "new").mkdir()  # what was there before stays
    one_line_error(trafficcal("run", bad, "--out", out, "--no-overlay"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["new", "notes.mp4"] and not out.exists()


def test_a_run_failing_before_the_speedometer_started_has_no_vehicles_of_an_earlier_run(with_truth, tmp_path):
    """The event files a run reads back after a failure are its own only if they changed since it started: an
    earlier run's, untouched (the pipeline failed before the speedometer replaced them), are not its vehicles."""
    import shutil

    from gst_trafficcal.cli.run import RunPaths, _read_vehicle_events, _stamp

    paths = RunPaths(tmp_path)
    shutil.copy(with_truth[0] / "vehicles.jsonl", paths.events)
    earlier = {p: _stamp(p) for p in (paths.events, paths.csv)}
    assert _read_vehicle_events(paths, earlier) == [] and len(_read_vehicle_events(paths)) > 1
    first = paths.events.read_text().splitlines(keepends=True)[0]
    paths.events.write_text(first)  # the speedometer replaced it: this run's one vehicle
    assert [e.id for e in _read_vehicle_events(paths, earlier)] == [read_events(paths.events).events[0].id]


@pytest.mark.parametrize("command", ["run", "demo", "calibrate", "fit-scale"])
def test_a_bad_detector_is_refused_before_any_work(clip, tmp_path, command):
    """The commands sharing --detector open the model first: a missing file is one line naming it, before a render,
    a VP stage (calibrate --scale would lose the vanishing points it found) or a pass over the video."""
    missing = tmp_path / "missing.onnx"
    out = tmp_path / "out"
    args = {"run": [clip / "video.mp4", "--out", out, "--no-overlay"],
            "demo": ["--out", out, "--duration", "4"],
            "calibrate": [clip / "video.mp4", "-o", out / "cal.json", "--scale", "--no-progress"],
            "fit-scale": ["--train", clip, "-o", out / "reg.json"]}[command]
    line = one_line_error(trafficcal(command, *args, "--detector", missing))
    assert str(missing) in line and "not found" in line
    assert not out.exists()


@pytest.mark.parametrize("command", ["run", "calibrate"])
def test_an_output_folder_that_cannot_be_made_is_refused_before_the_run(clip, tmp_path, command):
    """Not a traceback, and not an error once the whole video was read: one line naming the folder."""
    args = {"run": ["--out", "/proc/trafficcal-out"], "calibrate": ["-o", "/proc/trafficcal-out/cal.json"]}[command]
    line = one_line_error(trafficcal(command, clip / "video.mp4", *args))
    assert line == ("trafficcal: error: /proc/trafficcal-out: cannot create the output folder (--out)"
                    if command == "run" else "trafficcal: error: /proc/trafficcal-out/cal.json: cannot write the "
                    "calibration file (-o) there") + " (No such file or directory)"


def test_bad_speed_limit_is_refused_before_the_run(clip, tmp_path):
    line = one_line_error(trafficcal("run", clip / "video.mp4", "--out", tmp_path, "--speed-limit", "80,trucks"))
    assert line == ("trafficcal: error: --speed-limit: '80,trucks' is not KMH or KMH,CLASS=KMH,... "
                    "(e.g. 80,truck=60,bus=60)")


def test_bad_start_time_is_refused_before_the_run(clip, tmp_path):
    line = one_line_error(trafficcal("run", clip / "video.mp4", "--out", tmp_path, "--start-time", "8 o'clock"))
    assert "--start-time" in line and "ISO 8601" in line
    assert not (tmp_path / "vehicles.jsonl").exists()


def test_eval_of_a_runs_files_gives_the_runs_evaluation(clip, with_truth, tmp_path):
    """trafficcal eval on a 480x270 run's system.json scores it in the frame size the file states (image_size), as
    the run did: the same figures as its evaluation.json; its calibration.json is scored in its own size."""
    out, _ = with_truth
    proc = trafficcal("eval", "--gt", clip / "gt_data.pkl", "--results", out / "system.json", "--json",
                      tmp_path / "e.json")
    assert proc.returncode == 0, proc.stderr
    again, run = json.loads((tmp_path / "e.json").read_text()), json.loads((out / "evaluation.json").read_text())
    assert again["speed"] == run["speed"] and again["matched"] == run["matched"] and again["recall"] == run["recall"]
    proc = trafficcal("eval", "--gt", clip / "gt_data.pkl", "--calibration", out / "calibration.json")
    assert proc.returncode == 0 and "focal length: " in proc.stdout, proc.stderr
    line = one_line_error(trafficcal("eval", "--gt", clip / "gt_data.pkl", "--calibration", out / "calibration.json",
                                     "--image-size", "1920x1080"))
    assert "calibration is for 480x270 frames, the recording's are 1920x1080 (--image-size)" in line


def test_missing_video(tmp_path):
    proc = trafficcal("run", tmp_path / "absent.mp4", "--out", tmp_path / "out")
    assert proc.returncode == 2 and "does not exist" in proc.stderr and "Traceback" not in proc.stderr
    proc = trafficcal("run", (tmp_path / "absent.mp4").as_uri(), "--out", tmp_path / "out")
    assert proc.returncode == 2 and f"'{tmp_path / 'absent.mp4'}' does not exist" in proc.stderr
    from gst_trafficcal.cli.run import local_file

    assert local_file("file://localhost/v%20a.mp4") == "/v a.mp4" and local_file("file://nas/v.mp4") is None
    assert local_file("rtsp://cam/stream") is None


def test_a_stream_whose_server_cannot_be_reached_says_why(tmp_path):
    """GStreamer's sources say only "Internal data stream error": the run adds what a connection attempt found."""
    from gst_trafficcal.cli.run import unreachable

    from .conftest import closed_port

    port = closed_port()
    uri = f"http://user:secret@127.0.0.1:{port}/cam.mp4"
    line = one_line_error(trafficcal("run", uri, "--out", tmp_path / "out", "--no-overlay"))
    assert line.endswith(f"(127.0.0.1:{port}: Connection refused)") and "secret" not in line, line
    assert unreachable("rtsp://nosuchhost.invalid/stream") == "nosuchhost.invalid: no such host"
    assert unreachable("file:///tmp/v.mp4") is None and unreachable("udp://127.0.0.1:5000") is None
    import socket

    with socket.socket() as server:  # a server that is up: reachable, whatever it then says
        server.bind(("127.0.0.1", 0))
        server.listen()
        assert unreachable(f"rtsp://127.0.0.1:{server.getsockname()[1]}/x") is None


@pytest.mark.parametrize("content, words", [
    ("{not json", "calibration"),
    (json.dumps({"format": "gst-trafficcal-calibration", "version": 1, "state": "failed", "image_size": [480, 270],
                 "reason": "too short"}), "no vanishing points"),
    (None, "calibration"),  # no such file
])
def test_unreadable_calibration_file(clip, tmp_path, content, words):
    cal = tmp_path / "cal.json"
    if content is not None:
        cal.write_text(content)
    line = one_line_error(trafficcal("run", clip / "video.mp4", "--out", tmp_path / "out", "--calibration", cal))
    assert str(cal) in line and words in line
    assert not (tmp_path / "out").exists()  # refused before the run


def test_unreadable_ground_truth_is_refused_before_the_run(clip, tmp_path):
    gt = tmp_path / "gt_data.pkl"
    gt.write_bytes(b"not a pickle")
    line = one_line_error(trafficcal("run", clip / "video.mp4", "--out", tmp_path / "out", "--gt", gt))
    assert str(gt) in line
    assert not (tmp_path / "out").exists()


def test_the_overlay_of_a_run_killed_outright_is_playable(tmp_path):
    """overlay.mp4 as the run encodes it (OVERLAY_ENCODER), the encoder killed with SIGKILL (kill -9, a power cut,
    the OOM killer: no end-of-stream): the video up to its last fragment plays. A plain mp4mux wrote its index only
    at the end: OpenCV decoded 0 frames ("moov atom not found") of a killed run's overlay, however long it ran."""
    import signal
    import time

    from gst_trafficcal.cli.run import EVEN_I420, OVERLAY_ENCODER

    video = tmp_path / "overlay.mp4"
    proc = subprocess.Popen(["gst-launch-1.0", "-q", *f"videotestsrc is-live=true ! video/x-raw,width=160,height=120,"
                             f"framerate=25/1 ! videoconvert ! {EVEN_I420} ! {OVERLAY_ENCODER} ! "
                             f"filesink location={video}".split()])
    try:
        time.sleep(4.0)
        assert proc.poll() is None, "the encoder ended by itself"
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    assert count_frames(video) >= 25  # a second or more of the 4 s written (gst-launch starts in about one)


def test_a_run_killed_outright_leaves_its_calibration(clip, tmp_path):
    """calibration.json is written as soon as the run has a calibration, not only at the end: a run killed with
    SIGKILL (a power cut, the OOM killer) left none, and a restart had to learn the camera again."""
    import signal
    import time

    out = tmp_path / "out"
    args = ["run", clip / "video.mp4", "--out", out, "--calibration", clip / "calibration.json", "--no-overlay",
            "--status-interval", "0.1"]  # (the position in status.json at once: killed a second in)
    proc = subprocess.Popen([sys.executable, "-m", "gst_trafficcal", *map(str, args)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            try:
                if (read_status(out / "status.json").position_s or 0) >= 1.0:
                    break
            except Exception:  # not written yet
                pass
            time.sleep(0.1)
        assert proc.poll() is None, "the run ended before it could be killed"
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    assert read_status(out / "status.json").state == "running"  # killed: no word of its end
    kept = load_calibration(out / "calibration.json")
    assert kept.camera.scale == pytest.approx(load_calibration(clip / "calibration.json").camera.scale)


def test_full_disk_keeps_every_vehicle_already_measured(clip, with_truth, tmp_path):
    """vehicles.jsonl on a full device (/dev/full): a clear error, and the CSV has every vehicle measured so far."""
    if not os.path.exists("/dev/full"):
        pytest.skip("needs /dev/full")
    out = tmp_path / "out"
    out.mkdir()
    (out / "vehicles.jsonl").symlink_to("/dev/full")
    # the calibration given lives in --out under the output's name: used, not cleared away as a stale output
    (out / "calibration.json").write_text((clip / "calibration.json").read_text())
    proc = trafficcal("run", clip / "video.mp4", "--out", out, "--calibration", out / "calibration.json",
                      "--no-overlay", "--start-time", START)
    line = one_line_error(proc)
    assert "vehicles.jsonl" in line and "No space left on device" in line
    kept = read_events_csv(out / "vehicles.csv")
    assert kept, "no vehicle kept"
    reference = {e.id: e for e in read_events(with_truth[0] / "vehicles.jsonl").events}
    # the vehicle whose line could not be written to vehicles.jsonl is in the CSV exactly as in a normal run
    same = lambda e: {k: v for k, v in e.to_dict().items() if k != "run"}  # noqa: E731 (each run has its own id)
    assert same(kept[0]) == same(reference[kept[0].id])
    assert len({e.id for e in kept}) == len(kept)
    assert load_calibration(out / "calibration.json").camera.scale is not None
    # status.json counts the vehicles written (also those written as the pipeline stopped, after the error), and
    # does not call the video truncated for ending where the run stopped (it said "the video ends at 3.6 s of the
    # 12.0 s its header states: the file is probably truncated", and 1 vehicle beside a CSV of 4)
    status = read_status(out / "status.json")
    assert status.state == "failed" and "vehicles.jsonl" in status.error
    assert status.vehicles == len(kept) and status.measured == sum(e.measured for e in kept)
    assert not [w for w in status.warnings if "truncated" in w] and "truncated" not in proc.stdout + proc.stderr


def test_every_vehicle_is_posted_to_the_events_url_whose_password_is_never_shown(clip, tmp_path):
    from .conftest import Receiver

    receiver = Receiver()
    try:
        url = receiver.url.replace("http://", "http://ops:s3cret@")
        proc = trafficcal("run", clip / "video.mp4", "--out", tmp_path / "out", "--no-overlay", "--calibration",
                          clip / "calibration.json", "--events-url", url)
    finally:
        receiver.close()
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    events = read_events(tmp_path / "out" / "vehicles.jsonl").events
    assert [b["id"] for b in receiver.bodies] == [e.id for e in events] and len(events) >= 5
    assert [b["speed_kmh"] for b in receiver.bodies] == [e.speed_kmh for e in events]
    assert "s3cret" not in proc.stdout + proc.stderr and "events-url=\"http://ops:***@127.0.0.1:" in proc.stdout
    line = one_line_error(trafficcal("run", clip / "video.mp4", "--out", tmp_path / "bad", "--events-url",
                                     "mqtt://broker/topic"))
    assert line == "trafficcal: error: --events-url: 'mqtt://broker/topic' is not an http:// or https:// URL"


def test_unreadable_scale_regression_is_refused_before_the_run(clip, tmp_path):
    reg = tmp_path / "reg.json"
    reg.write_text("[1, 2]")
    line = one_line_error(trafficcal("run", clip / "video.mp4", "--out", tmp_path / "out", "--scale-regression", reg))
    assert str(reg) in line
    assert not (tmp_path / "out").exists()


def test_scale_regression_reaches_bbscale(clip, tmp_path):
    """--scale-regression is bbscale's regression-file in the pipeline the run plays (and prints)."""
    from gst_trafficcal.scale.regression import ScaleRegression, save_regression

    reg = tmp_path / "reg.json"
    save_regression(ScaleRegression(1.05, 0.0), reg)
    proc = trafficcal("run", clip / "video.mp4", "--out", tmp_path / "out", "--no-overlay", "--scale-regression", reg)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    printed = " ".join(proc.stdout.split())
    assert "bbscale regression-file=" in printed and str(reg) in printed.split("bbscale regression-file=")[1][:400]


def test_body_shapes_reach_the_tracker(clip, tmp_path):
    """--body-shapes is the tracker's body-shapes property in the pipeline the run plays (and prints); a value
    that is none of auto, cars, box is refused before anything runs."""
    proc = trafficcal("run", clip / "video.mp4", "--out", tmp_path / "out", "--no-overlay", "--body-shapes", "box",
                      "--calibration", clip / "calibration.json")
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "tracker body-shapes=box" in " ".join(proc.stdout.split())
    assert read_events(tmp_path / "out" / "vehicles.jsonl")
    bad = trafficcal("run", clip / "video.mp4", "--out", tmp_path / "bad", "--body-shapes", "round")
    assert bad.returncode == 2 and "'round' is not one of" in bad.stderr and not (tmp_path / "bad").exists()


def test_a_zone_leaves_out_the_other_carriageway(clip, with_truth, tmp_path):
    """--zone around the near right carriageway (traffic towards VP1): the run plays it in vpdetect, vehicledetect
    and trafficoverlay, measures only that carriageway's vehicles (the whole frame: both directions) and outlines
    the zone on overlay.mp4; a zone that is not one is refused before anything runs."""
    zone = "340,50 380,50 400,270 190,270"
    proc = trafficcal("run", clip / "video.mp4", "--out", tmp_path / "out", "--zone", zone,
                      "--calibration", clip / "calibration.json")
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    shown = " ".join(proc.stdout.split())
    for element in ("vpdetect mode=fixed", "vehicledetect model=\"vehicleseg\"", "trafficoverlay"):
        assert re.search(re.escape(element) + r'[^!]* zone="' + zone + '"', shown), element
    inside = read_events(tmp_path / "out" / "vehicles.jsonl").events
    everywhere = read_events(with_truth[0] / "vehicles.jsonl").events
    assert {e.direction for e in everywhere} == {"towards_vp1", "away_from_vp1"}
    assert inside and {e.direction for e in inside} == {"towards_vp1"} and len(inside) < len(everywhere)
    cap = cv2.VideoCapture(str(tmp_path / "out" / "overlay.mp4"))
    cap.set(cv2.CAP_PROP_POS_FRAMES, 60)
    ok, frame = cap.read()
    assert ok
    violet = np.abs(frame.astype(int) - ZONE_BGR).max(axis=2) < 60
    ys = np.arange(120, 260, 10)  # down the zone's right edge, from (380, 50) to (400, 270)
    assert all(violet[y, x - 2:x + 3].any() for y, x in zip(ys, np.round(380 + (ys - 50) * 20 / 220).astype(int)))
    # calibration.json keeps the zone: a report made again outlines it, a run given the file measures in it
    assert json.loads((tmp_path / "out" / "calibration.json").read_text())["zone"] == zone
    again = trafficcal("report", "--events", tmp_path / "out" / "vehicles.jsonl", "--calibration",
                       tmp_path / "out" / "calibration.json", "--out", tmp_path / "again.html")
    assert again.returncode == 0, again.stderr[-2000:]
    page = " ".join(re.sub(r"<[^>]+>", " ", (tmp_path / "again.html").read_text()).split())
    assert f"detection zone [px] {zone}" in page
    for given, kept in (((), True), (("--zone", "all"), False)):
        rerun = trafficcal("run", clip / "video.mp4", "--out", tmp_path / "rerun", "--no-overlay", "--duration", "1",
                           "--calibration", tmp_path / "out" / "calibration.json", *given)
        assert rerun.returncode == 0, rerun.stdout[-2000:] + rerun.stderr[-2000:]
        printed = " ".join(rerun.stdout.split())
        assert bool(re.search(r'vehicledetect model="vehicleseg"[^!]* zone="' + zone + '"', printed)) is kept
        assert ("Zone kept in" in " ".join(rerun.stderr.split())) is kept and ("zone=" in printed) is kept
        assert "kept in" not in printed  # a note on stderr: `run ... > results.txt` keeps the results alone
    corner = trafficcal("run", clip / "video.mp4", "--out", tmp_path / "corner", "--no-overlay", "--zone",
                        "0,0 30,0 30,30 0,30", "--calibration", clip / "calibration.json")  # no road there
    assert corner.returncode == 0 and "no vehicle stood in the detection zone (0,0 30,0 30,30 0,30) in " in \
        " ".join(corner.stderr.split()), corner.stderr[-2000:]  # a warning: on stderr
    brief = trafficcal("run", clip / "video.mp4", "--out", tmp_path / "brief", "--no-overlay", "--zone",
                       "0,0 30,0 30,30 0,30", "--calibration", clip / "calibration.json", "--duration", "2")
    # 2 s of it: no vehicle yet is no news
    assert brief.returncode == 0 and "no vehicle stood" not in brief.stdout + brief.stderr
    line = one_line_error(trafficcal("run", clip / "video.mp4", "--out", tmp_path / "bad", "--zone", "10,10 20,20"))
    assert line == "trafficcal: error: --zone: zone '10,10 20,20': polygon 1 has 2 points; a zone needs at least 3"
    assert not (tmp_path / "bad").exists()


@pytest.fixture
def rtsp_clip(clip):
    """The clip served live over RTSP by a server in this process (needs gir1.2-gst-rtsp-server-1.0)."""
    yield from serve_rtsp(f"( filesrc location={clip / 'video.mp4'} ! qtdemux ! h264parse ! rtph264pay name=pay0 "
                          "pt=96 )", "clip")


def test_a_live_stream_runs_until_ctrl_c_and_every_output_is_complete(clip, rtsp_clip, tmp_path):
    """`trafficcal run rtsp://...` measures a live camera; Ctrl-C ends it as the end of the stream would."""
    import signal
    import time
    from datetime import datetime, timedelta

    out = tmp_path / "live"
    before = datetime.now().astimezone()
    proc = subprocess.Popen([sys.executable, "-m", "gst_trafficcal", "run", rtsp_clip, "--out", str(out),
                             "--calibration", str(clip / "calibration.json"), "--start-time", "now",
                             "--status-interval", "1"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            # Ctrl-C reaches it as in a terminal, even when the tests run as a background job
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 120
    status = None
    while time.monotonic() < deadline and proc.poll() is None:  # until the first vehicle has left
        if (out / "vehicles.jsonl").is_file() and (out / "vehicles.jsonl").read_text().strip():
            status = read_status(out / "status.json")
            if status.vehicles and status.speed_x is not None:
                break
        time.sleep(0.2)
    assert proc.poll() is None, proc.communicate()
    # status.json while it runs: a live stream is measured as fast as it comes, no faster
    assert status.state == "running" and status.source == rtsp_clip and status.pid == proc.pid
    assert 0 < status.position_s < 12 and 0.6 < status.speed_x < 1.5, status
    assert status.calibration["scale_m"] is not None and status.last_vehicle_at
    check = trafficcal("status", out, "--json")  # a health check while it runs: healthy
    assert check.returncode == 0 and json.loads(check.stdout)["healthy"] is True, check.stdout + check.stderr
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stdout[-2000:] + stderr[-2000:]
    assert "! uridecodebin uri=" not in stdout and f'uridecodebin uri="{rtsp_clip}"' in stdout
    assert "interrupted (Ctrl-C) at" in stderr and "Traceback" not in stderr
    events = read_events(out / "vehicles.jsonl").events
    assert len(events) >= 2 and any(e.measured for e in events)  # the first ones, and those in view at the stop
    # --start-time now: dated by the clock at the stream's first frame, the count per 15 min aligned to it
    start = datetime.fromisoformat(events[0].first_time) - timedelta(seconds=events[0].first_timestamp_s)
    assert before - timedelta(seconds=1) < start < datetime.now().astimezone()
    first = datetime.fromisoformat((out / "intervals.csv").read_text().splitlines()[1].split(",")[0])
    assert first.minute % 15 == 0 and first.second == 0 and start - timedelta(minutes=15) < first <= start + \
        timedelta(seconds=20)
    frames = count_frames(out / "overlay.mp4")  # finished by the end-of-stream: playable
    assert 12 < frames < 150  # some of the 12 s (150 frames) clip, not all of it
    status = read_status(out / "status.json")
    assert status.state == "interrupted" and status.vehicles == len(events)
    assert 12 < status.frames < 150 and 0 <= status.frames_dropped < status.frames  # a live stream's frames counted
    for name in ("calibration.json", "system.json", "vehicles.csv", "intervals.csv", "report.html"):
        assert (out / name).is_file(), name


def test_duration_stops_a_file_early(clip, tmp_path):
    proc = trafficcal("run", clip / "video.mp4", "--out", tmp_path, "--calibration", clip / "calibration.json",
                      "--duration", "5")
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "--duration reached at" in proc.stderr
    events = read_events(tmp_path / "vehicles.jsonl").events
    assert events and max(e.last_timestamp_s for e in events) < 5.0
    cap = cv2.VideoCapture(str(tmp_path / "overlay.mp4"))
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    cap.release()
    assert n == 63  # the frames at 0, 0.08, ... 4.96 s (12.5 fps): the stream ends exactly there, a finished MP4


def test_an_earlier_live_runs_outputs_are_kept_a_files_are_replaced(clip, tmp_path):
    """A service started again into the --out of a live stream's run (after a crash or a reboot): the measurements
    of a stream cannot be made again, so they move to --out/earlier-<start>/ — the calibration given inside --out
    copied, since this run reads it.  A file's run into the same folder is replaced, as before."""
    import shutil

    from gst_trafficcal.run_status import StatusFile

    out = tmp_path / "out"
    out.mkdir()
    StatusFile(out / "status.json", "rtsp://admin:***@cam/1").update(state="failed", error="the machine rebooted")
    (out / "vehicles.jsonl").write_text('{"id": 1}\n{"id": 2}\n')
    (out / "report.html").write_text("the earlier report")
    (tmp_path / "www").mkdir()  # an output linked elsewhere: its content is kept, the link stays for this run's
    (tmp_path / "www" / "system.json").write_text('{"the earlier": "results"}')
    (out / "system.json").symlink_to(tmp_path / "www" / "system.json")
    shutil.copy(clip / "calibration.json", out / "calibration.json")
    args = ("run", clip / "video.mp4", "--out", out, "--calibration", out / "calibration.json", "--duration", "3",
            "--no-overlay")
    proc = trafficcal(*args)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    kept = list(out.glob("earlier-*"))
    assert len(kept) == 1 and f"Kept the earlier run's outputs (2 vehicles of a live stream" in proc.stdout
    assert (kept[0] / "vehicles.jsonl").read_text() == '{"id": 1}\n{"id": 2}\n'
    assert (kept[0] / "report.html").read_text() == "the earlier report"
    assert (kept[0] / "system.json").read_text() == '{"the earlier": "results"}'
    assert not (kept[0] / "system.json").is_symlink() and (out / "system.json").is_symlink()
    assert "the earlier" not in (tmp_path / "www" / "system.json").read_text()  # this run's, through the link
    assert load_results(tmp_path / "www" / "system.json").cars
    assert read_status(kept[0] / "status.json").error == "the machine rebooted"
    assert (kept[0] / "calibration.json").read_bytes() == (out / "calibration.json").read_bytes()  # copied
    assert read_status(out / "status.json").source == str(clip / "video.mp4")  # this run's own outputs
    assert (out / "report.html").read_text() != "the earlier report" and read_events(out / "vehicles.jsonl").events
    again = trafficcal(*args)  # the file's run again: replaced, nothing more set aside
    assert again.returncode == 0 and "Kept" not in again.stdout and len(list(out.glob("earlier-*"))) == 1


def test_an_earlier_runs_outputs_that_are_symlinks_stay_links(clip, tmp_path):
    """Outputs linked elsewhere (a web server's folder) stay links when a run replaces the earlier run's outputs:
    the file a link leads to is removed before the run (nothing stale passes for this run's) and this run's file
    written through the link; a file this run does not write (evaluation.json without --gt, overlay.mp4 with
    --no-overlay) is then missing behind its link, not the earlier run's."""
    www, out = tmp_path / "www", tmp_path / "out"
    www.mkdir()
    out.mkdir()
    names = ("report.html", "system.json", "calibration.json", "intervals.csv", "evaluation.json", "overlay.mp4")
    for name in names:
        (www / name).write_text(f"the earlier run's {name}\n")
        (out / name).symlink_to(www / name)
    proc = trafficcal("run", clip / "video.mp4", "--out", out, "--calibration", clip / "calibration.json",
                      "--duration", "3", "--no-overlay")
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert all((out / name).is_symlink() and os.readlink(out / name) == str(www / name) for name in names)
    for name in ("report.html", "system.json", "calibration.json", "intervals.csv"):
        assert "the earlier run's" not in (www / name).read_text(), name
    assert load_calibration(out / "calibration.json").camera is not None
    assert not (www / "evaluation.json").exists() and not (www / "overlay.mp4").exists()
    wrote = " ".join(proc.stdout.split()).split("Wrote ")[1]
    assert "evaluation.json" not in wrote and "overlay.mp4" not in wrote and "report.html" in wrote


def test_an_out_folder_another_run_is_writing_into_is_refused(clip, tmp_path):
    """Two runs into one --out would overwrite each other's files: while the run whose status.json is there goes on
    (its process alive: here this test's), a second one is refused in one line; once it ended, it is not."""
    from datetime import datetime, timedelta

    from gst_trafficcal.run_status import StatusFile

    running = StatusFile(tmp_path / "status.json", "rtsp://cam/1")
    running.update(state="running")
    line = one_line_error(trafficcal("run", clip / "video.mp4", "--out", tmp_path))
    assert line.startswith(f"trafficcal: error: {tmp_path}: another run is writing there (process {os.getpid()} on ")
    assert line.endswith("reading rtsp://cam/1): give another --out, or stop that run first")
    # another machine's run whose clock is a day ahead: refused as before, but saying why it cannot be told and
    # what to do (it said "another run is writing there" until that machine's date came, with no word of the clock)
    data = json.loads((tmp_path / "status.json").read_text())
    ahead = (datetime.now().astimezone() + timedelta(days=1)).isoformat(timespec="milliseconds")
    (tmp_path / "status.json").write_text(json.dumps({**data, "host": "nvr-07", "updated_at": ahead}))
    line = one_line_error(trafficcal("run", clip / "video.mp4", "--out", tmp_path))
    assert re.search(r"another run may be writing there \(process \d+ on nvr-07, reading rtsp://cam/1\): its "
                     r"status.json is dated 86[34]\d\d s in the future, the clocks of nvr-07 and this one differ, so "
                     r"whether it still runs cannot be told: stop that run, or remove .*status.json if it is gone",
                     line), line
    running.update(state="interrupted")
    ended = trafficcal("run", clip / "video.mp4", "--out", tmp_path, "--duration", "1", "--no-overlay")
    assert ended.returncode == 0, ended.stdout[-2000:] + ended.stderr[-2000:]


def test_start_time_now_is_for_streams(clip, tmp_path):
    line = one_line_error(trafficcal("run", clip / "video.mp4", "--out", tmp_path, "--start-time", "now"))
    assert "live streams" in line


def test_a_picture_is_not_a_video(clip, tmp_path):
    """A still picture given as the video (a camera's snapshot): refused in one line before anything is made. It
    used to play as one frame, a run with no vehicle and a warning meant for gst-launch users (multifilesrc)."""
    import cv2

    cap = cv2.VideoCapture(str(clip / "video.mp4"))
    ok, frame = cap.read()
    cap.release()
    assert ok
    for name in ("snapshot.jpg", "snapshot.png"):
        cv2.imwrite(str(tmp_path / name), frame)
        out = tmp_path / f"out_{name}"
        line = one_line_error(trafficcal("run", tmp_path / name, "--out", out, "--no-overlay"))
        assert line.endswith(f"{tmp_path / name}: a picture, not a video: speeds are measured on video (pictures of "
                             "a camera taken at a fixed rate: make a video of them first, e.g. with ffmpeg)"), line
        assert not out.exists()


def test_a_directory_is_not_a_video(tmp_path):
    proc = trafficcal("run", tmp_path, "--out", tmp_path / "out")
    assert proc.returncode == 2 and "is a directory" in proc.stderr and "Traceback" not in proc.stderr


@pytest.mark.shared
def test_the_calibration_of_a_cameras_first_file_carries_over_to_the_next(tmp_path):
    """Recordings of one camera in parts: the first (kraten_cars.mp4, 47 s: enough to calibrate) is calibrated and
    scaled; the second (its first 6 s, too short to calibrate alone) is measured from its first vehicle with that
    calibration, checked against its view (vpdetect mode auto), bbscale passing the scale on as it is."""
    from .conftest import VIDEOS, require_shared

    whole = require_shared(VIDEOS / "kraten_cars.mp4")
    part = tmp_path / "part2.mp4"
    cap = cv2.VideoCapture(str(whole))
    writer = cv2.VideoWriter(str(part), cv2.VideoWriter_fourcc(*"mp4v"), 25, (640, 360))
    for _ in range(150):
        writer.write(cap.read()[1])
    writer.release()
    out = tmp_path / "out"
    proc = trafficcal("run", whole, part, "--out", out, "--no-overlay")
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    first = load_calibration(out / "kraten_cars" / "calibration.json")
    second = load_calibration(out / "part2" / "calibration.json")
    assert first.camera.scale is not None and first.source == "vpdetect+bbscale"
    assert second.source == "vpdetect+bbscale, carried over from kraten_cars.mp4"
    assert second.camera.scale == first.camera.scale and np.allclose(second.camera.vp2, first.camera.vp2)
    assert "vpdetect mode=auto calibration-file=" in proc.stdout
    events = read_events(out / "part2" / "vehicles.jsonl").events
    assert sum(e.measured for e in events) >= 3 and all(e.calibration_id == second.id for e in events if e.measured)
    assert "2 of 2 files" in proc.stdout and proc.stdout.count("│ ok ") == 2
    # tracks that were no vehicle passing (pieces of vehicles, on this real clip): said by the command and the
    # first file's report alike
    said = " ".join(proc.stdout.split())
    assert "Tracks not counted as vehicles: " in said
    line = "Tracks not counted as vehicles: " + said.split("Tracks not counted as vehicles: ")[1].split(").")[0] + ")"
    assert line in " ".join(html.unescape((out / "kraten_cars" / "report.html").read_text()).split())
    rows = (out / "parts.csv").read_text().splitlines()
    assert rows[0] == "part,folder,vehicles,measured,mean_kmh,v85_kmh,calibration,status,error"
    assert [r.split(",")[6] for r in rows[1:]] == [first.id, second.id]
    # the camera's view is kept, with its scale, for the parts (or connections) that show it again
    from gst_trafficcal.calibration import load_views

    views, skipped = load_views(out / "views", (640, 360))
    assert skipped == [] and [v.camera.scale for v in views] == [first.camera.scale]
    assert views[0].source.startswith("vpdetect+bbscale, ") and views[0].source.endswith(" from kraten_cars.mp4")
    assert "views-dir=" in proc.stdout


def test_several_files_one_failing_the_others_still_run(clip, tmp_path):
    """A file that is not a video fails (its error in the table and at the end, exit code 2); the files before and
    after it are measured, each into its own folder (the same names numbered)."""
    bad = tmp_path / "notes.mp4"
    bad.write_text("not a video")
    out = tmp_path / "out"
    proc = trafficcal("run", clip / "video.mp4", bad, clip / "video.mp4", "--out", out, "--no-overlay",
                      "--calibration", clip / "calibration.json")
    assert proc.returncode == 2, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert user_lines(proc.stderr)[-1].startswith("trafficcal: error: notes.mp4: ") and "Traceback" not in proc.stderr
    one = read_events(out / "video-1" / "vehicles.jsonl").events
    three = read_events(out / "video-3" / "vehicles.jsonl").events
    assert len(one) >= 5 and [(e.id, e.speed_kmh) for e in one] == [(e.id, e.speed_kmh) for e in three]
    assert "3 of 3 files" in proc.stdout and proc.stdout.count("│ ok ") == 2 and "│ failed: " in proc.stdout
    import csv

    with open(out / "parts.csv", newline="") as f:  # the same table, machine-readable
        parts = list(csv.DictReader(f))
    assert [(r["part"], r["folder"], r["status"]) for r in parts] == [
        ("video.mp4", "video-1", "ok"), ("notes.mp4", "notes", "failed"), ("video.mp4", "video-3", "ok")]
    assert parts[0]["vehicles"] == str(len(one)) and parts[0]["measured"] == str(sum(e.measured for e in one))
    assert parts[1]["error"].startswith(f"{bad}: ") and parts[1]["vehicles"] == ""


def test_several_files_all_refused_leave_no_new_out(tmp_path):
    """Every file refused (none is a video) into an --out the run makes: the errors in the table and at the end,
    and nothing new left behind, as for one file refused; before, status.json, parts.csv and two empty vehicle
    tables stayed in a new folder (and each error spoke of "the earlier outputs in out/notes", never made).  An
    --out that existed keeps the run's status.json and parts table (an operator's monitoring reads them)."""
    bad, worse = tmp_path / "notes.mp4", tmp_path / "list.mp4"
    bad.write_text("not a video")
    worse.write_text("nor this")
    out = tmp_path / "new" / "out"
    proc = trafficcal("run", bad, worse, "--out", out, "--no-overlay")
    assert proc.returncode == 2, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert user_lines(proc.stderr) == [f"trafficcal: error: notes.mp4: cannot be processed: no frame could be "
                                       f"decoded from it (not a video, empty, or damaged); list.mp4: cannot be "
                                       f"processed: no frame could be decoded from it (not a video, empty, or "
                                       f"damaged)"]
    assert "2 of 2 files" in proc.stdout and not (tmp_path / "new").exists()
    out.mkdir(parents=True)
    proc = trafficcal("run", bad, worse, "--out", out, "--no-overlay")
    assert proc.returncode == 2 and sorted(p.name for p in out.iterdir()) == [
        "parts.csv", "run.log", "status.json", "vehicles.csv", "vehicles.jsonl"]
    assert read_status(out / "status.json").state == "failed"
    log = (out / "run.log").read_text()  # each file's failure as it came, and the run's error at the end
    assert "notes.mp4: failed: " in log and "list.mp4: failed: " in log and "trafficcal: error: notes.mp4: " in log


def test_duration_counts_the_video_of_all_the_files(clip, tmp_path):
    """--duration with several files: seconds of video in all (as for a stream's connections): the 12 s clip three
    times with --duration 16 measures the first whole, the second up to its 4th second, and lists the third as not
    run (it was left out of the table and parts.csv, with exit code 0 and no word)."""
    import csv

    out = tmp_path / "out"
    proc = trafficcal("run", clip / "video.mp4", clip / "video.mp4", clip / "video.mp4", "--out", out,
                      "--no-overlay", "--calibration", clip / "calibration.json", "--duration", "16")
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    with open(out / "parts.csv", newline="") as f:
        parts = list(csv.DictReader(f))
    assert [(r["folder"], r["status"], r["error"]) for r in parts] == [
        ("video-1", "ok", ""), ("video-2", "ok", ""), ("video-3", "not run", "--duration reached")]
    last = max(e.last_timestamp_s for e in read_events(out / "video-2" / "vehicles.jsonl").events)
    assert 3.0 < last <= 4.05 and not (out / "video-3").exists()
    assert "of 3 files" in proc.stdout and "not run" in proc.stdout


def test_a_cameras_dated_files_are_counted_together(clip, tmp_path):
    """--start-time auto: each file dated from its name; --out/intervals.csv counts the vehicles of all of them
    on one clock (the 12 s clip as two recordings, 07:59:55 and 08:00:20: the 15-minute rows 07:45 and 08:00)."""
    import shutil

    a, b = tmp_path / "cam7_20261205_075955.mp4", tmp_path / "cam7_2026-12-05_08-00-20.mp4"
    shutil.copy(clip / "video.mp4", a)
    shutil.copy(clip / "video.mp4", b)
    out = tmp_path / "out"
    proc = trafficcal("run", a, b, "--out", out, "--no-overlay", "--calibration", clip / "calibration.json",
                      "--start-time", "auto")
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    first = read_events(out / a.stem / "vehicles.jsonl").events
    second = read_events(out / b.stem / "vehicles.jsonl").events
    assert first[0].first_time.startswith("2026-12-05T07:59:5") and second[0].first_time.startswith("2026-12-05T08:00:")
    import csv

    with open(out / "intervals.csv", newline="") as f:
        total = [r for r in csv.DictReader(f) if r["lane"] == "all"]
    assert [r["interval_start"][11:19] for r in total] == ["07:45:00", "08:00:00"]
    assert sum(int(r["vehicles"]) for r in total) == len(first) + len(second)
    # watched: 07:59:55-08:00:07 and 08:00:20-08:00:32 (12 s each), 5 s before 08:00 and 19 s after
    assert [float(r["observed_s"]) for r in total] == pytest.approx([5.0, 19.0], abs=0.2)
    # every vehicle of the day in one table, with its part, on the first file's clock (the second 25 s later)
    with open(out / "vehicles.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["part"] for r in rows] == [a.stem] * len(first) + [b.stem] * len(second)
    assert [float(r["first_timestamp_s"]) for r in rows] == pytest.approx(
        [e.first_timestamp_s for e in first] + [e.first_timestamp_s + 25.0 for e in second], abs=1e-3)
    assert [r["first_time"] for r in rows] == [e.first_time for e in first + second]
    assert len(read_events(out / "vehicles.jsonl").events) == len(rows)
    line = one_line_error(trafficcal("run", a, clip / "video.mp4", "--out", tmp_path / "x", "--start-time", "auto"))
    assert line == ("trafficcal: error: --start-time auto: no date and time in the name 'video.mp4' (e.g. "
                    "cam7_20261205_080000.mp4, 2026-12-05_08-00-00.mp4)")


@pytest.mark.parametrize("args, words", [
    (["rtsp://cam/1", "rtsp://cam/2"], "a stream (URI) runs alone"),
    (["{clip}", "{clip}", "--gt", "{gt}"], "--gt is the ground truth of one video"),
    (["{clip}", "{clip}", "--start-time", "2026-12-05T08:00:00"], "--start-time is the start of one recording"),
    (["rtsp://cam/1", "--start-time", "auto"], "--start-time auto reads each file's date and time from its name"),
])
def test_what_several_inputs_cannot_share_is_refused_first(clip, tmp_path, args, words):
    args = [a.format(clip=clip / "video.mp4", gt=clip / "gt_data.pkl") for a in args]
    assert words in one_line_error(trafficcal("run", *args, "--out", tmp_path / "out"))


def test_a_live_stream_that_ends_is_connected_again(clip, rtsp_clip, tmp_path):
    """--reconnect: the served clip ends after 12 s; the run connects again after a second and goes on until
    --duration (16 s of video in all), each connection in its own folder, a table of them at the end."""
    out = tmp_path / "live"
    proc = trafficcal("run", rtsp_clip, "--out", out, "--reconnect", "--duration", "16", "--no-overlay",
                      "--calibration", clip / "calibration.json")
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    parts = sorted(p for p in out.iterdir() if p.is_dir())
    assert len(parts) == 2 and all(re.fullmatch(r"\d{8}-\d{6}(-\d+)?", p.name) for p in parts)
    first = read_events(parts[0] / "vehicles.jsonl").events
    assert len(first) >= 5 and sum(e.measured for e in first) >= 5
    assert (parts[1] / "vehicles.jsonl").is_file() and (parts[1] / "report.html").is_file()
    assert "the stream ended: connecting again in 1 s (Ctrl-C stops)" in proc.stderr
    assert "2 connections" in proc.stdout and "│ ended " in proc.stdout and "│ ok " in proc.stdout
    index = [r.split(",") for r in (out / "parts.csv").read_text().splitlines()[1:]]
    assert [(r[1], r[7]) for r in index] == [(parts[0].name, "ended"), (parts[1].name, "ok")]
    assert index[0][2] == str(len(first))


def test_split_every_ends_each_connection_on_the_clock_and_connects_again_at_once(clip, rtsp_clip, tmp_path):
    """--split-every 4s (24h in service: a folder, outputs and report per day): each connection ends at the next
    multiple of 4 s on the clock and the next one starts at once — no wait, "split" in parts.csv — until --duration
    (9 s of video in all); each period's folder has its outputs."""
    out = tmp_path / "live"
    proc = trafficcal("run", rtsp_clip, "--out", out, "--reconnect", "--split-every", "4s", "--duration", "9",
                      "--no-overlay", "--calibration", clip / "calibration.json")
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    index = [r.split(",") for r in (out / "parts.csv").read_text().splitlines()[1:]]
    assert len(index) >= 3 and [r[7] for r in index] == ["split"] * (len(index) - 1) + ["ok"], index
    # said on stderr (and in run.log) as the run's other notes, not among its results on stdout
    assert proc.stderr.count("the next period's connection starts") == len(index) - 1
    assert "the next period's connection starts" not in proc.stdout
    assert "connecting again in" not in proc.stdout + proc.stderr  # a new period is no failure: no wait
    for row in index:
        assert (out / row[1] / "vehicles.jsonl").is_file() and (out / row[1] / "report.html").is_file(), row
    assert len(read_events(out / "vehicles.jsonl").events) == sum(int(r[2]) for r in index)  # every period's
    line = one_line_error(trafficcal("run", rtsp_clip, "--out", tmp_path / "x", "--split-every", "24h"))
    assert line == "trafficcal: error: --split-every is for a live stream with --reconnect (each period a " \
                   "connection of its own)"
    line = one_line_error(trafficcal("run", rtsp_clip, "--out", tmp_path / "x", "--reconnect", "--split-every", "1w"))
    assert "--split-every: '1w' is not a period" in line


@pytest.mark.parametrize("stop", ["SIGINT", "SIGTERM"])
def test_reconnecting_to_a_stream_that_is_not_there_goes_on_until_ctrl_c(clip, tmp_path, stop):
    """Nothing answers: each attempt fails, the wait doubles, Ctrl-C — or SIGTERM, a service stopped — ends it
    (130) with the table; a file is read once, so --reconnect with one is refused."""
    import signal
    import time

    from .conftest import closed_port

    # the camera's password is in its URI, as NVRs give them: never printed, never written
    uri = f"rtsp://admin:s3cr3t@127.0.0.1:{closed_port()}/none"
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "gst_trafficcal", "run", uri, "--out", str(out), "--reconnect",
                             "--no-overlay", "--status-interval", "0.5"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    waiting = None
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.2)
        if (out / "status.json").is_file() and (st := read_status(out / "status.json")).state == "reconnecting" \
                and st.parts_done >= 2:
            waiting = st  # two attempts failed: waiting 2 s for the third
            break
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(getattr(signal, stop))
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stdout[-2000:] + stderr[-2000:]
    assert "connecting again in 1 s" in stderr and "connecting again in 2 s" in stderr and "Traceback" not in stderr
    assert "│ failed: " in stdout and "connections (speeds in km/h)" in stdout
    # status.json said it was waiting to connect again, and why, and when
    assert waiting is not None and waiting.error and waiting.next_attempt_at and waiting.position_s is None
    assert waiting.source == uri.replace("s3cr3t", "***")
    assert read_status(out / "status.json").state == "interrupted"
    written = "".join(p.read_text(errors="replace") for p in out.rglob("*") if p.is_file())
    assert "s3cr3t" not in stdout + stderr + written and "admin:***@127.0.0.1" in stdout
    if stop == "SIGINT":
        line = one_line_error(trafficcal("run", clip / "video.mp4", "--out", tmp_path / "x", "--reconnect"))
        assert line == "trafficcal: error: --reconnect is for a live stream (a URI): a file is read to its end once"


def test_a_live_stream_stopped_by_sigterm_completes_every_output(clip, rtsp_clip, tmp_path):
    """`docker stop`, `systemctl stop` and Kubernetes send SIGTERM: the run ends as at Ctrl-C — the vehicles in view
    written, a playable overlay, the report, status "interrupted" — and says it was stopped."""
    import signal

    out = tmp_path / "live"
    proc = subprocess.Popen([sys.executable, "-m", "gst_trafficcal", "run", rtsp_clip, "--out", str(out),
                             "--calibration", str(clip / "calibration.json"), "--status-interval", "1"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _wait_for_a_vehicle(proc, out)
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stdout[-2000:] + stderr[-2000:]
    assert "stopped (SIGTERM) at" in stderr and "Traceback" not in stderr
    _assert_interrupted_with_every_output(out)


def test_a_run_whose_ssh_session_closes_completes_every_output(clip, rtsp_clip, tmp_path):
    """`trafficcal run` started from an SSH session that then closes: the terminal hangs up, and the kernel sends
    the session's process SIGHUP (the run's terminal here is a pseudo-terminal of the test, its controlling one,
    closed as sshd closes it).  The run ends as at Ctrl-C — the vehicles in view written, a playable overlay, the
    report — and status.json says "interrupted", though nothing can be printed any more.  Before, SIGHUP killed the
    process at once: the outputs up to there survived, but status.json said "running" for good."""
    import fcntl
    import signal
    import termios
    import threading

    out = tmp_path / "live"
    master, slave = os.openpty()

    def controlling_terminal() -> None:  # (after setsid: start_new_session) the pty becomes the session's terminal
        fcntl.ioctl(0, termios.TIOCSCTTY, 0)
        signal.signal(signal.SIGHUP, signal.SIG_DFL)  # as in a login session (tests run under nohup ignore it)

    proc = subprocess.Popen([sys.executable, "-m", "gst_trafficcal", "run", rtsp_clip, "--out", str(out),
                             "--calibration", str(clip / "calibration.json"), "--status-interval", "1"],
                            stdin=slave, stdout=slave, stderr=slave, start_new_session=True,
                            preexec_fn=controlling_terminal)
    os.close(slave)
    said = []

    def read_terminal() -> None:  # what the run prints, read as a terminal would (it must not block on a full pty)
        try:
            while chunk := os.read(master, 65536):
                said.append(chunk)
        except OSError:  # the terminal closed
            pass

    threading.Thread(target=read_terminal, daemon=True).start()
    _wait_for_a_vehicle(proc, out)
    assert proc.poll() is None, b"".join(said)[-3000:]
    os.close(master)  # the SSH session closes: SIGHUP, and the terminal is gone
    assert proc.wait(timeout=120) == 130, (proc.returncode, b"".join(said)[-3000:])
    _assert_interrupted_with_every_output(out)


def test_a_run_killed_outright_keeps_the_open_intervals_count(clip, rtsp_clip, tmp_path):
    """kill -9 (a power cut, the OOM killer) in the middle of a quarter hour: intervals.csv held only its header
    until the interval closed, so every vehicle counted in it was lost from the table.  Now the open interval's row
    is on disk as vehicles come: after the kill it counts the vehicles written before it, with the seconds of the
    interval watched so far."""
    import csv
    import signal
    import time

    out = tmp_path / "live"
    proc = subprocess.Popen([sys.executable, "-m", "gst_trafficcal", "run", rtsp_clip, "--out", str(out),
                             "--calibration", str(clip / "calibration.json"), "--no-overlay"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        _wait_for_a_vehicle(proc, out)
        assert proc.poll() is None
        time.sleep(1.0)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait(timeout=60)
    events = read_events(out / "vehicles.jsonl").events
    with open(out / "intervals.csv", newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["lane"] == "all"]
    assert len(rows) == 1 and 1 <= int(rows[0]["vehicles"]) <= len(events), rows
    assert 0 < float(rows[0]["observed_s"]) < 900


def test_a_camera_move_is_told_with_what_it_cost():
    """After a run in which the camera moved: a line per move (when, how many vehicles the old calibration
    measured, which one), and how many tracks of the time between the move and its notice were not counted."""
    from rich.console import Console

    from gst_trafficcal.calibration import Calibration
    from gst_trafficcal.cli.run import RunSummary, print_moves
    from gst_trafficcal.geometry import Camera
    from gst_trafficcal.gst.runner import Move
    from gst_trafficcal.outputs import VehicleEvent

    old = Calibration(Camera((900.0, -400.0), (-6000.0, -350.0), (640.0, 360.0), scale=7.5), (1280, 720))
    events = [VehicleEvent(i, "car", t, t + 2.0, 80.0) for i, t in enumerate([3.0, 10.0, 20.0, 40.0])]
    console = Console(record=True, width=400)
    print_moves(console, RunSummary(None, events, moves=[Move(34.8, old), Move(38.0, None, old)], discarded=26))
    text = console.export_text()
    assert f"The camera moved at 34.8 s: the 3 vehicles seen before were measured with calibration {old.id} " \
           "(scale 7.500 m), cut at the move; vpdetect learnt the new view from there" in text
    assert "The camera moved at 38.0 s: the 0 vehicles seen before were measured with the calibration then in " \
           f"force, cut at the move; it went back to a view calibrated before: calibration {old.id} (scale 7.500 " \
           "m) measured from there at once" in text
    assert "26 tracks seen only between the move and the moment it was noticed were not counted" in text
    console = Console(record=True, width=200)
    print_moves(console, RunSummary(None, events))
    assert console.export_text() == ""
    # a patrol: the moves before the latest ones kept are one line with their count, not a line each
    console = Console(record=True, width=400)
    print_moves(console, RunSummary(None, events, moves=[Move(34.8, old), Move(38.0, None, old)],
                                    moves_earlier=(300, 1.0, 15.0)))
    text = console.export_text()
    assert "The camera moved 302 times: 300 times from 1.0 s to 15.0 s (2 vehicles seen until then, each measured " \
           "with the calibration in force as it passed), then the latest 2:" in text
    assert "The camera moved at 34.8 s: the 1 vehicles seen before were measured with" in text
    assert len(text.splitlines()) == 3


def test_a_source_that_sends_nothing_ends_the_run_with_an_error(tmp_path):
    """A URI that never sends a frame (a UDP port nobody sends to; now and then an RTSP camera whose connection
    failed without the source saying so) ends the run after STALL_TIMEOUT seconds with one clear error, not a hang;
    a STALL_TIMEOUT that is not a number is an error at once."""
    from .conftest import closed_port

    uri = f"udp://127.0.0.1:{closed_port()}"
    env = dict(os.environ, STALL_TIMEOUT="2")
    proc = subprocess.run([sys.executable, "-m", "gst_trafficcal", "run", uri, "--out", str(tmp_path / "out"),
                           "--no-overlay"], capture_output=True, text=True, timeout=120, env=env)
    assert "! watchdog timeout=2000 !" in proc.stdout
    line = one_line_error(proc)
    assert f"{uri}: cannot be processed: no frame for 2 s: the source stopped sending or never connected" in line
    env["STALL_TIMEOUT"] = "soon"
    proc = subprocess.run([sys.executable, "-m", "gst_trafficcal", "run", uri, "--out", str(tmp_path / "out2"),
                           "--no-overlay"], capture_output=True, text=True, timeout=120, env=env)
    assert "STALL_TIMEOUT must be a number of seconds, got 'soon'" in one_line_error(proc)


def test_a_final_error_reaches_run_log_when_the_terminal_is_gone(tmp_path):
    """A run whose terminal is gone (its SSH session closed; here a pipe whose reader left before the first line)
    ended with its error in status.json only: nothing could print it.  Now --out/run.log holds what the terminal
    would have said that matters afterwards — the start, the error as the command line prints it, each line dated —
    and a later run into the same --out adds to it."""
    from .conftest import closed_port

    uri = f"udp://127.0.0.1:{closed_port()}"
    out = tmp_path / "out"
    env = dict(os.environ, STALL_TIMEOUT="1")
    for _ in range(2):
        read, write = os.pipe()
        os.close(read)  # the reader is gone: every write of the run fails (EPIPE)
        proc = subprocess.run([sys.executable, "-m", "gst_trafficcal", "run", uri, "--out", str(out), "--no-overlay"],
                              stdout=write, stderr=write, timeout=120, env=env)
        os.close(write)
        assert proc.returncode == 2
    status = json.loads((out / "status.json").read_text())
    assert status["state"] == "failed" and "no frame for 1 s" in status["error"]
    lines = (out / "run.log").read_text().splitlines()
    assert len(lines) == 4 and all(re.match(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}[+-]\d\d:\d\d ", ln) for ln in lines)
    assert f"trafficcal run started: {uri} into {out} (process " in lines[0]
    assert f"trafficcal: error: {uri}: cannot be processed: no frame for 1 s: the source stopped sending" in lines[1]
    assert "trafficcal run started" in lines[2] and "trafficcal: error:" in lines[3]


def test_run_log_is_appended_in_dated_lines_and_kept_small(tmp_path):
    """run.log: stderr's text in pieces becomes whole dated lines; past its size the file moves to run.log.1 (the
    one before that dropped), so a run of months keeps two small files; a log that cannot be written is said once
    and never stops the run."""
    from gst_trafficcal.cli.terminal import RunLog

    log = RunLog(tmp_path / "run.log", max_bytes=400)
    log.stream("trafficcal: warn")
    log.stream("ing: one\ntwo")
    log.flush()
    assert [ln.split(" ", 1)[1] for ln in (tmp_path / "run.log").read_text().splitlines()] == [
        "trafficcal: warning: one", "two"]
    for k in range(40):
        log.line(f"line {k}")
    kept = (tmp_path / "run.log.1").read_text() + (tmp_path / "run.log").read_text()
    assert (tmp_path / "run.log").stat().st_size <= 400 and (tmp_path / "run.log.1").stat().st_size <= 400
    assert kept.rstrip().endswith("line 39") and "line 30" in kept and not (tmp_path / "run.log.2").exists()
    broken = RunLog(tmp_path / "no" / "such" / "run.log")
    broken.line("x")  # said once on stderr, no exception
    broken.line("y")


def test_a_truncated_file_is_measured_up_to_where_it_ends_and_says_so(clip, tmp_path):
    """A recording cut off (a copy interrupted, a disk that filled up) plays to where its data ends and then ends
    like any file; the run measures what it holds and says the file is shorter than its header states, and the
    report does not claim the missing part was watched."""
    whole = tmp_path / "whole.mp4"  # the clip with its index first (as cameras and NVRs write them), then cut
    subprocess.run(["gst-launch-1.0", "-q", "filesrc", f"location={clip / 'video.mp4'}", "!", "qtdemux", "!",
                    "h264parse", "!", "mp4mux", "faststart=true", "!", "filesink", f"location={whole}"], check=True,
                   capture_output=True, timeout=120)
    data = whole.read_bytes()
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(data[:len(data) // 2])
    out = tmp_path / "out"
    run = trafficcal("run", cut, "--out", out, "--calibration", clip / "calibration.json", "--no-overlay")
    assert run.returncode == 0, run.stderr[-2000:]
    text = " ".join(run.stderr.split())  # a warning: on stderr (stdout, the results, may go to a file), not stdout
    found = re.search(r"the video ends at ([\d.]+) s of the ([\d.]+) s its header states: the file is probably "
                      r"truncated", text)
    assert found and "its header states" not in run.stdout, text[-3000:]
    logged = [ln for ln in (out / "run.log").read_text().splitlines() if "its header states" in ln]  # once, plain text
    assert len(logged) == 1 and logged[0].split(" ", 1)[1].startswith(f"warning: {cut}: {found.group(0)}"), logged
    end, length = map(float, found.groups())
    assert 3.0 < end < 0.8 * length and length == pytest.approx(12.0, abs=0.2)
    events = read_events(out / "vehicles.jsonl").events
    assert events and max(e.last_timestamp_s for e in events) <= end + 0.1
    status = read_status(out / "status.json")
    assert any("truncated" in w for w in status.warnings)
    assert status.position_s == pytest.approx(end, abs=0.06) and status.duration_s == pytest.approx(length, abs=0.06)
    report = (out / "report.html").read_text()
    assert f"({end:.0f} s watched)" in report, re.findall(r"\([^()]*watched\)", report)
    # its picture is the video's first frame (through GStreamer where OpenCV's FFmpeg refuses the cut file), not
    # the grey canvas of a report without a frame
    import base64

    png = base64.b64decode(re.search(r"data:image/png;base64,([A-Za-z0-9+/=]+)", report).group(1))
    picture = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert (picture == 90).all(axis=2).mean() < 0.2
    # the whole file: no such warning
    run = trafficcal("run", whole, "--out", tmp_path / "whole", "--calibration", clip / "calibration.json",
                     "--no-overlay")
    assert run.returncode == 0 and "its header states" not in run.stdout + run.stderr


def test_a_file_whose_audio_runs_on_past_its_video_is_not_called_truncated(tmp_path):
    """A file's header states its longest stream's duration: a recording with 4 s of video and 9 s of audio plays
    its video to 4 s. The run says the audio may run on, not that the file is truncated."""
    av = tmp_path / "av.mkv"
    subprocess.run(["gst-launch-1.0", "-q", "videotestsrc", "num-buffers=100", "!",
                    "video/x-raw,framerate=25/1,width=320,height=240", "!", "x264enc", "!", "h264parse", "!",
                    "matroskamux", "name=m", "!", "filesink", f"location={av}", "audiotestsrc", "num-buffers=400",
                    "samplesperbuffer=1024", "!", "audio/x-raw,rate=44100,channels=1", "!", "m."],
                   check=True, capture_output=True, timeout=120)
    run = trafficcal("run", av, "--out", tmp_path / "out", "--no-overlay", "--detector", "background")
    assert run.returncode == 0, run.stderr[-2000:]
    text = " ".join((run.stdout + run.stderr).split())
    assert re.search(r"the video ends at 4\.0 s of the 9\.\d s its file states: its audio may run on longer", text), \
        text[-3000:]
    assert "probably truncated" not in text


def test_the_remeasured_line_says_how_many_got_a_speed():
    """58 vehicles measured again of which 47 got a speed must not read as 58 speeds."""
    from rich.console import Console

    from gst_trafficcal.cli.run import print_remeasured

    console = Console(record=True, width=400)
    print_remeasured(console, 58, speeds=47)
    print_remeasured(console, 3, speeds=3)
    print_remeasured(console, 0, speeds=0)
    assert console.export_text().splitlines() == [
        "58 vehicles that left while the calibration was still settling were measured again with the final one (47 of "
        "them with a speed)",
        "3 vehicles that left while the calibration was still settling were measured again with the final one"]


def test_the_vehicle_table_fits_a_terminal_of_80_columns():
    """With a speed limit the table has seven columns: in 80 columns none is cut ("away_fr…")."""
    from rich.console import Console

    from gst_trafficcal.cli.run import print_vehicles
    from gst_trafficcal.outputs import VehicleEvent

    events = [VehicleEvent(i, "car", 1.0 * i, 1.0 * i + 2, 50.0 + i, lane=i % 3,
                           direction=("towards_vp1", "away_from_vp1")[i % 2]) for i in range(12)]
    events.append(VehicleEvent(99, "car", 20.0, 20.5, None, reason="track too short (3 reference points, needs 10)"))
    console = Console(record=True, width=80)
    print_vehicles(console, events, 55.0)
    text = console.export_text()
    assert "away_from_vp1" in text and "towards_vp1" in text and "…" not in text, text
    assert "13 vehicles, 12 measured (speeds in km/h)" in text and "over limit" in text


PORTRAIT = {"format": "gst-trafficcal-calibration", "version": 1, "state": "calibrated", "source": "test",
            "image_size": [360, 640], "vp1": [180.0, -400.0], "vp2": [3000.0, 400.0], "pp": [180.0, 320.0],
            "scale": 8.0}  # a calibration of upright frames of a phone's video (360 wide, 640 high)


def test_a_rotated_video_is_analysed_upright(tmp_path):
    """A phone's or a body camera's video: frames stored 640x360 and the MP4's display matrix turning them a
    quarter clockwise, as every player (and OpenCV, so trafficcal calibrate and the report's picture) shows them.
    The run turns them too (videoflip video-direction=auto), so a calibration of the upright 360x640 picture fits;
    before, the elements saw the stored frames, and the run refused that calibration (a calibration of 360x640
    images but the video is 640x360) while calibrate learnt one the run refused the other way round."""
    from .conftest import encoded, rotation_tagged

    video = rotation_tagged(encoded(tmp_path / "stored.mp4", "width=640,height=360", frames=25), tmp_path / "p.mp4")
    cal = tmp_path / "portrait.json"
    cal.write_text(json.dumps(PORTRAIT))
    proc = trafficcal("run", video, "--out", tmp_path / "out", "--calibration", cal)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "videoflip video-direction=90r ! videoscale" in proc.stdout
    _assert_upright_outputs(tmp_path / "out")


def _assert_upright_outputs(out: Path) -> None:
    """The run calibrated and drew the upright (portrait) picture of a rotation-tagged 640x360 video."""
    assert load_calibration(out / "calibration.json").image_size == (360, 640)
    cap = cv2.VideoCapture(str(out / "overlay.mp4"))
    assert cap.read()[1].shape == (640, 360, 3)
    cap.release()


def test_a_rotated_stream_takes_a_calibration_of_its_upright_picture(tmp_path):
    """A stream's rotation is not read before the run starts (videoflip video-direction=auto turns it by its tag):
    here an MP4 of a phone, read over HTTP.  The elements are first told the stored 640x360 and, once the tag has
    come (before any frame), the turned 360x640.  A --calibration of the upright picture was refused at those first
    caps (a calibration of 360x640 images but the video is 640x360); the size is now checked at the first frame."""
    import functools
    import threading
    from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer

    from .conftest import encoded, rotation_tagged

    rotation_tagged(encoded(tmp_path / "stored.mp4", "width=640,height=360", frames=25), tmp_path / "p.mp4")
    cal = tmp_path / "portrait.json"
    cal.write_text(json.dumps(PORTRAIT))

    class Quiet(SimpleHTTPRequestHandler):
        def log_message(self, *args):
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(Quiet, directory=str(tmp_path)))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        uri = f"http://127.0.0.1:{server.server_port}/p.mp4"
        proc = trafficcal("run", uri, "--out", tmp_path / "out", "--calibration", cal)
    finally:
        server.shutdown()
        server.server_close()
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "videoflip video-direction=auto ! videoscale" in proc.stdout
    _assert_upright_outputs(tmp_path / "out")


def _wait_for_a_vehicle(proc: subprocess.Popen, out: Path) -> None:
    """Until the live run ``proc`` has written its first vehicle (it left the view) to ``out``, or ended."""
    import time

    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if (out / "vehicles.jsonl").is_file() and (out / "vehicles.jsonl").read_text().strip():
            break
        time.sleep(0.2)


def _assert_interrupted_with_every_output(out: Path) -> None:
    """A live run stopped by a signal: status.json "interrupted" counting every vehicle written, an overlay
    completed by the end-of-stream (playable), and every other output."""
    events = read_events(out / "vehicles.jsonl").events
    status = read_status(out / "status.json")
    assert status.state == "interrupted" and status.vehicles == len(events) >= 2
    assert 12 < count_frames(out / "overlay.mp4") < 150
    for name in ("calibration.json", "system.json", "vehicles.csv", "intervals.csv", "report.html"):
        assert (out / name).is_file(), name
