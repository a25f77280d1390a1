"""run_status: the status file a long run keeps up to date for monitoring."""

from __future__ import annotations

import json
import os
import re

import pytest

from gst_trafficcal.errors import InputError
from gst_trafficcal.run_status import STATUS_FIELDS, StatusFile, read_status


class Clock:
    """A monotonic clock the test moves by hand."""

    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def on_disk(path) -> dict:
    return json.loads(path.read_text())


def test_written_at_once_then_at_most_every_interval_but_at_once_on_a_new_state(tmp_path):
    clock, path = Clock(), tmp_path / "status.json"
    status = StatusFile(path, "rtsp://cam/1", every_s=5.0, clock=clock)
    first = on_disk(path)
    assert tuple(first) == STATUS_FIELDS and first["state"] == "starting" and first["pid"] == os.getpid()
    assert first["source"] == "rtsp://cam/1" and first["vehicles"] == 0 and first["position_s"] is None
    status.position(1.0, None)  # a new state: written at once
    assert on_disk(path)["state"] == "running" and on_disk(path)["position_s"] == 1.0
    clock.t += 2.0
    status.position(3.0, None)
    assert on_disk(path)["position_s"] == 1.0  # 2 s later: not yet
    clock.t += 3.0
    status.position(6.0, None)
    assert on_disk(path)["position_s"] == 6.0  # 5 s after the last write
    status.update(state="reconnecting", error="the stream ended")
    assert on_disk(path)["state"] == "reconnecting" and on_disk(path)["error"] == "the stream ended"
    assert not list(tmp_path.glob(".*tmp"))  # written through a temporary file, nothing left behind


def test_speed_against_real_time_counts_and_warnings(tmp_path):
    clock, path = Clock(), tmp_path / "status.json"
    status = StatusFile(path, "v.mp4", every_s=1.0, clock=clock)
    status.position(0.0, 60.0)
    clock.t += 2.0
    status.position(5.0, 60.0)  # 5 s of video in 2 s
    assert on_disk(path)["speed_x"] == 2.5 and on_disk(path)["duration_s"] == 60.0
    clock.t += 4.0
    status.position(7.0, 60.0)  # slower than real time now
    assert on_disk(path)["speed_x"] == 0.5
    status.position(1.0, 60.0)  # back to the start (a new part): the rate starts again, the last one stays
    assert on_disk(path)["speed_x"] == 0.5
    status.vehicle(6.5, measured=True)
    status.vehicle(6.9, measured=False)
    for k in range(7):
        status.warning(f"w{k}")
    clock.t += 1.0
    status.update()
    got = read_status(path)
    assert (got.vehicles, got.measured, got.last_vehicle_s) == (2, 1, 6.9) and got.last_vehicle_at
    assert got.warnings == ["w2", "w3", "w4", "w5", "w6"]  # the last five


@pytest.mark.parametrize("final", ["failed", "interrupted", "finished"])
def test_the_final_speed_is_the_whole_runs(tmp_path, final):
    """In a final state, speed_x is the whole run's stream seconds per wall second — every part counted — not the
    last interval's: a pipeline that stalled before it failed left 0.008, which said nothing of the run."""
    clock, path = Clock(), tmp_path / "status.json"
    status = StatusFile(path, "v.mp4", every_s=1.0, clock=clock)
    for k in range(11):  # part 1: 50 s of video in 10 s
        status.position(5.0 * k, 50.0)
        clock.t += 1.0
    status.position(1.0, 30.0)  # part 2, from its start: 30 s of video in 10 s, the last 5 s of it stalled
    for k in range(1, 6):
        clock.t += 1.0
        status.position(1.0 + 5.792 * k, 30.0)  # to 29.96 s
    clock.t += 5.0
    status.position(30.0, 30.0)  # 0.04 s in the last 5 s: stalled
    assert on_disk(path)["speed_x"] == 0.008
    status.update(state=final, force=True)
    assert on_disk(path)["speed_x"] == pytest.approx(80.0 / 21.0, abs=1e-3)  # 80 s of video in 21 s of wall time


def test_bad_fields_and_states_are_programming_errors(tmp_path):
    status = StatusFile(tmp_path / "s.json", "v.mp4")
    with pytest.raises(TypeError, match="unknown status fields: colour"):
        status.update(colour="red")
    with pytest.raises(ValueError, match="state must be one of"):
        status.update(state="sleeping")
    with pytest.raises(InputError, match="must be positive"):
        StatusFile(tmp_path / "t.json", "v.mp4", every_s=0)


def test_a_status_file_that_cannot_be_written_is_told_once_and_the_run_goes_on(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")  # a file where the folder should be
    told: list[str] = []
    status = StatusFile(blocker / "status.json", "v.mp4", every_s=0.1, warn=told.append)
    status.update(state="running")
    status.update(state="finished")
    assert len(told) == 1 and "cannot write the run's status" in told[0] and "the run goes on" in told[0]
    assert status.status.state == "finished"


def test_read_status_names_a_broken_file(tmp_path):
    bad = tmp_path / "status.json"
    bad.write_text("[1, 2]")
    with pytest.raises(InputError, match="not a run's status"):
        read_status(bad)
    bad.write_text('{"state": "running", "updated_at": "2026-12-06T10:00:00+00:00", "from_a_newer_version": 1}')
    assert read_status(bad).state == "running"
    # another JSON file given by mistake (a calibration.json has a "state" too): no status, not a hung run
    for text in ('{"format": "gst-trafficcal-calibration", "state": "calibrated"}', '{"foo": 1}'):
        bad.write_text(text)
        with pytest.raises(InputError, match=r"status.json: not a run's status \(no (state or )?updated_at; "
                                             r"trafficcal run writes status.json in its --out\)"):
            read_status(bad)


def test_health_as_a_health_check_judges_it(tmp_path):
    import subprocess
    import sys
    from dataclasses import replace
    from datetime import datetime, timedelta

    from gst_trafficcal.run_status import health

    status = StatusFile(tmp_path / "s.json", "rtsp://cam/1")
    status.update(state="running")
    now = datetime.now().astimezone()
    fresh = status.status
    assert health(fresh, 60, now) == []
    assert "not updated for 120 s" in health(fresh, 60, now + timedelta(seconds=120))[0]
    assert health(replace(fresh, state="finished"), 60, now + timedelta(hours=5)) == []  # ended as it should
    assert health(replace(fresh, state="failed", error="disk full"), 60, now) == ["the run failed: disk full"]
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead = int(gone.stdout)
    assert health(replace(fresh, pid=dead), 60, now) == [f"process {dead} is not running any more"]
    assert health(replace(fresh, pid=int(gone.stdout), host="another-machine"), 60, now) == []  # not ours to check
    # a lost stream: since when is kept through the attempts (starting, reconnecting, ...) until it runs again
    status.update(state="reconnecting", error="the stream ended")
    lost = status.status.stream_lost_at
    status.update(state="starting")
    status.update(state="reconnecting")
    assert lost and status.status.stream_lost_at == lost
    later = datetime.fromisoformat(lost) + timedelta(seconds=90)
    assert health(replace(status.status, updated_at=later.isoformat()), 60, later) == \
        ["no stream for 90 s (the stream ended); still trying"]
    status.update(state="running")
    assert status.status.stream_lost_at is None


def test_trafficcal_status_exit_codes(tmp_path):
    """`trafficcal status`: 1 and the reason for a run that stopped updating, 2 without a status."""
    import subprocess
    import sys

    status = StatusFile(tmp_path / "status.json", "rtsp://cam/1")
    status.update(state="running")
    data = on_disk(tmp_path / "status.json")
    data["updated_at"] = "2026-01-01T00:00:00.000+00:00"
    (tmp_path / "status.json").write_text(json.dumps(data))
    run = subprocess.run([sys.executable, "-m", "gst_trafficcal", "status", str(tmp_path)], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 1 and "UNHEALTHY: status not updated for" in run.stdout, run.stdout + run.stderr
    missing = subprocess.run([sys.executable, "-m", "gst_trafficcal", "status", str(tmp_path / "nothing")],
                             capture_output=True, text=True, timeout=60)
    assert missing.returncode == 2 and "no such file (give the --out folder" in missing.stderr
    (tmp_path / "calibration.json").write_text('{"format": "gst-trafficcal-calibration", "state": "calibrated"}')
    wrong = subprocess.run([sys.executable, "-m", "gst_trafficcal", "status", str(tmp_path / "calibration.json")],
                           capture_output=True, text=True, timeout=60)
    assert wrong.returncode == 2 and "calibration.json: not a run's status" in wrong.stderr, wrong.stdout
    for source, duration, said in (("video.mp4", 60.0, "frames      250 of the file"),
                                   ("rtsp://cam/1", None, "frames      250 of the live stream, 3 dropped to keep up")):
        folder = tmp_path / source.replace("/", "_").replace(":", "")
        StatusFile(folder / "status.json", source).update(state="running", position_s=10.0, duration_s=duration,
                                                          frames=250, frames_dropped=3 if duration is None else 0)
        shown = subprocess.run([sys.executable, "-m", "gst_trafficcal", "status", str(folder)], capture_output=True,
                               text=True, timeout=60)
        assert said in shown.stdout and shown.stdout.count("frames") == 1, shown.stdout + shown.stderr


def test_a_corrupt_status_file_is_one_line_naming_it(tmp_path):
    (tmp_path / "status.json").write_text("{not json")
    with pytest.raises(InputError, match=r"status.json: not valid JSON, so not a run's status"):
        read_status(tmp_path / "status.json")


def test_trafficcal_status_of_a_folder_of_cameras_is_a_line_each(tmp_path):
    """An NVR's cameras, one --out folder each under one folder: `trafficcal status FOLDER` checks them all — a line
    each and a count, exit 1 when any is unhealthy or has no readable status (0 when every one is healthy)."""
    import subprocess
    import sys

    def status(*args: object) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "gst_trafficcal", "status", *map(str, args)],
                              capture_output=True, text=True, timeout=60)

    cameras = tmp_path / "cameras"
    for name, state in (("east", "running"), ("north", "finished"), ("west", "failed")):
        (cameras / name).mkdir(parents=True)
        StatusFile(cameras / name / "status.json", f"rtsp://nvr/{name}").update(
            state=state, vehicles=12, measured=10, error="disk full" if state == "failed" else "")
    (cameras / "south").mkdir()
    (cameras / "south" / "status.json").write_text("{not json")
    (cameras / "notes").mkdir()  # not a run: other files only, not listed
    (cameras / "notes" / "cabling.txt").write_text("east: port 3")
    run = status(cameras)
    lines = run.stdout.splitlines()
    assert run.returncode == 1 and len(lines) == 5, run.stdout + run.stderr
    assert lines[0].startswith(f"{cameras / 'east' / 'status.json'}: running;") and lines[0].endswith("healthy")
    assert "12 vehicles, 10 measured" in lines[0] and lines[1].endswith("finished; 12 vehicles, 10 measured; last –; "
                                                                        "healthy")
    assert lines[2].startswith(f"{cameras / 'south' / 'status.json'}: UNHEALTHY: no status: not valid JSON, so not a "
                               "run's status (")
    assert "west" in lines[3] and lines[3].endswith("UNHEALTHY: the run failed: disk full")
    assert lines[4] == "4 runs: 2 healthy, 2 not"
    fine = status(cameras / "east", cameras / "north" / "status.json", "--json")
    docs = json.loads(fine.stdout)
    assert fine.returncode == 0 and [d["healthy"] for d in docs] == [True, True], fine.stdout + fine.stderr
    assert [d["source"] for d in docs] == ["rtsp://nvr/east", "rtsp://nvr/north"] and docs[1]["path"].endswith(
        "north/status.json")
    listed = json.loads(status(cameras, "--json").stdout)
    assert [(d["path"].split("/")[-2], d["healthy"]) for d in listed] == [("east", True), ("north", True),
                                                                          ("south", False), ("west", False)]
    assert listed[2]["problems"][0].startswith("no status: not valid JSON") and "state" not in listed[2]
    gone = status(cameras / "east", tmp_path / "nowhere")
    assert gone.returncode == 1 and f"{tmp_path / 'nowhere'}: UNHEALTHY: no status: no such file\n" in gone.stdout
    one = status(cameras / "east")  # a single run: in full, as before
    assert one.returncode == 0 and "  vehicles    12, 10 measured" in one.stdout



def test_still_running_is_a_live_process_here_or_a_fresh_file_from_elsewhere(tmp_path):
    import subprocess
    import sys
    from dataclasses import replace
    from datetime import datetime, timedelta

    from gst_trafficcal.run_status import health, still_running

    status = StatusFile(tmp_path / "s.json", "rtsp://cam/1")
    status.update(state="running")
    mine = status.status
    assert not still_running(mine)  # this very process: not another run
    gone = int(subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                              text=True).stdout)
    assert not still_running(replace(mine, pid=gone))  # killed without a word: its state still says running
    parent = os.getppid()
    assert still_running(replace(mine, pid=parent)) and not still_running(replace(mine, pid=parent, state="failed"))
    # after a crash or a reboot its number went to a process started since: not the run (its restart was refused
    # for as long as that process lived)
    later = subprocess.Popen(["sleep", "30"])
    try:
        crashed = replace(mine, pid=later.pid, started_at=(datetime.now() - timedelta(minutes=5)).astimezone()
                          .isoformat())
        assert not still_running(crashed)
        assert f"process {later.pid} is not running any more" in " ".join(health(crashed))
        assert still_running(replace(mine, pid=later.pid, started_at=datetime.now().astimezone().isoformat()))
    finally:
        later.kill()
        later.wait()
    now = datetime.fromisoformat(mine.updated_at)
    away = replace(mine, host="another-machine")
    assert still_running(away, now + timedelta(seconds=30)) and not still_running(away, now + timedelta(minutes=5))


@pytest.mark.parametrize("field, value, words", [("pid", "x", 'pid is "x", not a whole number'),
                                                 ("vehicles", True, "vehicles is true, not a whole number"),
                                                 ("speed_x", "fast", 'speed_x is "fast", not a number or null'),
                                                 ("warnings", [1], "warnings is [1], not a list"),
                                                 ("calibration", [], "calibration is [], not an object or null")])
def test_a_status_with_a_field_of_the_wrong_type_is_one_line_naming_it(tmp_path, field, value, words):
    """Not a traceback later (a pid that is not a number reached os.kill): `trafficcal status` exits 2 with the
    line, and `trafficcal run` replaces such a file as an unreadable one."""
    import subprocess
    import sys

    StatusFile(tmp_path / "status.json", "rtsp://cam/1").update(state="running")
    data = on_disk(tmp_path / "status.json")
    data[field] = value
    (tmp_path / "status.json").write_text(json.dumps(data))
    with pytest.raises(InputError, match=re.escape(f"status.json: not a run's status ({words}")):
        read_status(tmp_path / "status.json")
    run = subprocess.run([sys.executable, "-m", "gst_trafficcal", "status", str(tmp_path)], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 2 and "Traceback" not in run.stderr and words in run.stderr, run.stderr


def test_a_status_with_an_unknown_state_is_not_a_runs_status(tmp_path):
    """"state": "dancing" was printed as "dancing since ..." and had no trafficcal_state series at 1: now it is an
    invalid status like a corrupt file — one line and exit 2 alone, "no status" (unhealthy) among several runs."""
    import subprocess
    import sys

    from prometheus_client.parser import text_string_to_metric_families

    run_dir = tmp_path / "cameras" / "east"
    StatusFile(run_dir / "status.json", "rtsp://cam/1").update(state="running")
    data = on_disk(run_dir / "status.json")
    data["state"] = "dancing"
    (run_dir / "status.json").write_text(json.dumps(data))
    words = 'not a run\'s status (state is "dancing", not one of starting, running, reconnecting, finished, ' \
            'interrupted, failed)'
    with pytest.raises(InputError, match=re.escape(f"status.json: {words}")):
        read_status(run_dir / "status.json")

    def status(*args: object) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "gst_trafficcal", "status", *map(str, args)],
                              capture_output=True, text=True, timeout=60)

    alone = status(run_dir)
    assert alone.returncode == 2 and alone.stderr == f"trafficcal: error: {run_dir / 'status.json'}: {words}\n"
    assert alone.stdout == ""
    StatusFile(tmp_path / "cameras" / "west" / "status.json", "rtsp://cam/2").update(state="running")
    both = status(tmp_path / "cameras")
    assert both.returncode == 1 and f"{run_dir / 'status.json'}: UNHEALTHY: no status: {words}" in both.stdout
    metrics = status(tmp_path / "cameras", "--prometheus")
    series = [(s.name, s.labels["run"]) for f in text_string_to_metric_families(metrics.stdout) for s in f.samples
              if s.labels["run"] == str(run_dir)]
    assert metrics.returncode == 1 and series == [("trafficcal_healthy", str(run_dir))]


def test_a_status_from_the_future_is_clock_skew_not_healthy(tmp_path):
    """updated_at in the future (the writer's clock years ahead) was healthy and printed "(-96831612 s ago)":
    now unhealthy with the reason, and the times say "in the future"; a skew of a second or two stays healthy."""
    import socket
    import subprocess
    import sys
    from dataclasses import replace
    from datetime import datetime, timedelta

    from prometheus_client.parser import text_string_to_metric_families

    from gst_trafficcal.run_status import CLOCK_SKEW_S, health

    status = StatusFile(tmp_path / "status.json", "rtsp://cam/1")
    status.update(state="running")
    now = datetime.fromisoformat(status.status.updated_at)
    away = replace(status.status, host="nvr-07")
    assert health(away, 60, now - timedelta(seconds=2)) == []  # this machine 2 s behind: fine
    assert health(away, 60, now - timedelta(seconds=3600)) == [
        "updated_at lies 3600 s in the future: the clocks of the writer (nvr-07) and this machine differ; whether "
        "the run hangs cannot be told"]
    here = health(replace(away, host=socket.gethostname()), 60, now - timedelta(seconds=CLOCK_SKEW_S + 1))
    assert here[0].startswith(f"updated_at lies {CLOCK_SKEW_S + 1:.0f} s in the future: this machine's clock was "
                              "set back since")
    # ended, but dated in the future (healthy before): suspicious, not healthy; a skew of a second or two is fine
    assert health(replace(away, state="finished"), 60, now - timedelta(seconds=3600)) == [
        "updated_at lies 3600 s in the future: the clocks of the writer (nvr-07) and this machine differ; its times "
        "cannot be trusted"]
    assert health(replace(away, state="finished"), 60, now - timedelta(seconds=2)) == []
    assert health(replace(away, state="failed", error="x"), 60, now - timedelta(seconds=3600))[1].startswith(
        "updated_at lies 3600 s in the future")

    data = on_disk(tmp_path / "status.json")
    ahead = (datetime.now().astimezone() + timedelta(days=1000)).isoformat(timespec="milliseconds")
    data.update(updated_at=ahead, host="nvr-07")
    (tmp_path / "status.json").write_text(json.dumps(data))
    run = subprocess.run([sys.executable, "-m", "gst_trafficcal", "status", str(tmp_path)], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 1 and "s ago)" not in run.stdout.splitlines()[-2], run.stdout
    assert re.search(rf"updated     {re.escape(ahead)} \(\d+ s in the future: clocks differ\) by process",
                     run.stdout), run.stdout
    assert re.search(r"UNHEALTHY: updated_at lies \d+ s in the future: the clocks of the writer \(nvr-07\) and this "
                     r"machine differ", run.stdout), run.stdout
    metrics = subprocess.run([sys.executable, "-m", "gst_trafficcal", "status", str(tmp_path), "--prometheus"],
                             capture_output=True, text=True, timeout=60)
    values = {s.name: s.value for f in text_string_to_metric_families(metrics.stdout) for s in f.samples}
    assert metrics.returncode == 1 and values["trafficcal_healthy"] == 0.0
    assert -1000 * 86400 <= values["trafficcal_status_age_seconds"] < -999 * 86400  # the skew, the run unhealthy
    data.update(state="finished")  # an ended run's status from the future was healthy (exit 0): now suspicious
    (tmp_path / "status.json").write_text(json.dumps(data))
    run = subprocess.run([sys.executable, "-m", "gst_trafficcal", "status", str(tmp_path)], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 1 and re.search(r"UNHEALTHY: updated_at lies \d+ s in the future: the clocks of the "
                                             r"writer \(nvr-07\) and this machine differ; its times cannot be "
                                             r"trusted", run.stdout), run.stdout


def test_a_camera_folder_without_a_status_is_reported_not_skipped(tmp_path):
    """`trafficcal status FOLDER` skipped a camera folder without status.json (healthy, exit 0, no Prometheus
    series): now a subfolder with any of a run's outputs, or an empty one, is a camera with no status (unhealthy,
    exit 1); hidden folders, lost+found and folders of other files are not cameras."""
    import subprocess
    import sys

    from prometheus_client.parser import text_string_to_metric_families

    def status(*args: object) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "gst_trafficcal", "status", *map(str, args)],
                              capture_output=True, text=True, timeout=60)

    cameras = tmp_path / "cameras"
    StatusFile(cameras / "cam1" / "status.json", "rtsp://nvr/1").update(state="running")
    (cameras / "cam2").mkdir()  # its run has not written anything yet
    (cameras / "cam3").mkdir()  # an earlier run's outputs, its status.json gone
    (cameras / "cam3" / "calibration.json").write_text("{}")
    for other in (".snapshots", "lost+found", "docs"):
        (cameras / other).mkdir()
    (cameras / "docs" / "README.txt").write_text("one folder per camera")
    run = status(cameras)
    assert run.returncode == 1, run.stdout + run.stderr
    assert run.stdout.splitlines()[1:] == [f"{cameras / name / 'status.json'}: UNHEALTHY: no status: no such file"
                                           for name in ("cam2", "cam3")] + ["3 runs: 1 healthy, 2 not"]
    metrics = status(cameras, "--prometheus")
    healthy = {s.labels["run"]: s.value for f in text_string_to_metric_families(metrics.stdout) for s in f.samples
               if s.name == "trafficcal_healthy"}
    assert metrics.returncode == 1 and healthy == {str(cameras / "cam1"): 1.0, str(cameras / "cam2"): 0.0,
                                                   str(cameras / "cam3"): 0.0}
    # a run's own --out without status.json is that run (no status, exit 2), not a folder of cameras: the
    # earlier-<start>/ folder of outputs set aside inside it is no camera
    StatusFile(cameras / "cam3" / "earlier-20261205-080000" / "status.json", "rtsp://nvr/3").update(state="finished")
    alone = status(cameras / "cam3")
    assert alone.returncode == 2 and alone.stderr.startswith(f"trafficcal: error: {cameras / 'cam3' / 'status.json'}: "
                                                             "no such file"), alone.stderr
    (tmp_path / "nothing-yet").mkdir()  # an empty --out: that run's, without a status (as before)
    empty = status(tmp_path / "nothing-yet")
    assert empty.returncode == 2 and "no such file" in empty.stderr
