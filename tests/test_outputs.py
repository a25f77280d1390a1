"""Per-vehicle result files: JSONL/CSV events (line at a time, full disk), BrnoCompSpeed results (atomic)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from gst_trafficcal.brnocompspeed import load_results
from gst_trafficcal.calibration import Calibration
from gst_trafficcal.errors import InputError
from gst_trafficcal.evaluation import median_speeds
from gst_trafficcal.geometry import Camera
from gst_trafficcal.outputs import (
    EVENT_FIELDS, BrnoResultsWriter, CsvEventWriter, EventWriters, JsonlEventWriter, VehicleEvent, VehicleOutputs,
    frames_from_times, on_one_clock, read_events, read_events_csv, reason_kind, unmeasured_by_kind,
)
from gst_trafficcal.speed import track_speed

ROOT = Path(__file__).resolve().parents[1]


def _events(n: int = 5) -> list[VehicleEvent]:
    out = []
    for i in range(n):
        measured = i % 3 != 2
        out.append(VehicleEvent(id=i + 1, label="car" if i % 2 else "truck", first_timestamp_s=1.5 * i,
                                last_timestamp_s=1.5 * i + 2.25, speed_kmh=60.0 + i if measured else None,
                                reason="" if measured else "stream ended before the calibration converged",
                                lane=i % 2, direction=1 if i % 2 else -1, calibration_id="c0ffee123456",
                                n_samples=10 + i))
    return out


def test_event_record_normalises_values() -> None:
    e = VehicleEvent(np.int64(7), "car", np.float32(1.5), 2.0, float("nan"), lane=np.int32(2), direction=0)
    d = e.to_dict()
    assert list(d) == list(EVENT_FIELDS)
    assert d["speed_kmh"] is None and d["reason"] == "not measured" and d["direction"] is None
    assert isinstance(d["id"], int) and isinstance(d["lane"], int) and d["first_timestamp_s"] == 1.5
    json.dumps(d)  # plain JSON types only
    assert VehicleEvent(1, "car", 0, 1, 50.0, reason="stale").reason == ""  # a measured vehicle has no reason
    with pytest.raises(ValueError, match="unknown direction"):
        VehicleEvent(1, "car", 0, 1, 50.0, direction="north")


def test_jsonl_and_csv_round_trip(tmp_path: Path) -> None:
    events = _events()
    with EventWriters.open(tmp_path / "v.jsonl", tmp_path / "sub" / "v.csv") as w:
        for e in events:
            w.write(e)
    log = read_events(tmp_path / "v.jsonl")
    assert log.events == events and log.skipped == 0
    lines = (tmp_path / "v.jsonl").read_text().splitlines()
    assert len(lines) == len(events) and json.loads(lines[2])["speed_kmh"] is None
    assert json.loads(lines[2])["reason"] == "stream ended before the calibration converged"
    assert read_events_csv(tmp_path / "sub" / "v.csv") == events
    header = (tmp_path / "sub" / "v.csv").read_text().splitlines()[0]
    assert header == ",".join(EVENT_FIELDS)


def test_events_with_the_clock_round_trip(tmp_path: Path) -> None:
    from gst_trafficcal.clock import parse_start_time

    start = parse_start_time("2026-12-05T08:00:00+01:00")
    events = [e.with_clock(start) for e in _events()]
    assert events[1].first_time == "2026-12-05T08:00:01.500+01:00"
    assert events[1].last_time == "2026-12-05T08:00:03.750+01:00"
    assert _events()[0].with_clock(None).first_time is None
    with EventWriters.open(tmp_path / "v.jsonl", tmp_path / "v.csv") as w:
        for e in events:
            w.write(e)
    assert read_events(tmp_path / "v.jsonl").events == events and read_events_csv(tmp_path / "v.csv") == events
    # a file from before the clock fields still loads (no times)
    old = {k: v for k, v in events[0].to_dict().items() if k not in ("first_time", "last_time", "run")}
    assert VehicleEvent.from_dict(old).first_time is None and VehicleEvent.from_dict(old).run is None


def test_a_run_id_tells_appended_runs_apart(tmp_path: Path) -> None:
    """Each run's id (its UTC start and four random hex digits) goes with every event into both files; two runs
    appended to one file reuse track ids, (run, id) does not."""
    from dataclasses import replace
    from datetime import datetime, timezone

    from gst_trafficcal.outputs import new_run_id

    at = datetime(2026, 12, 6, 6, 30, 5, tzinfo=timezone.utc)
    ids = {new_run_id(at) for _ in range(20)}
    assert all(len(i) == 21 and i.startswith("20261206T063005Z-") for i in ids) and len(ids) > 15
    runs = [new_run_id(), new_run_id()]
    for run in runs:
        with EventWriters.open(tmp_path / "v.jsonl", tmp_path / "v.csv", append=True) as w:
            for e in _events(3):
                w.write(replace(e, run=run))
    for read in (read_events(tmp_path / "v.jsonl").events, read_events_csv(tmp_path / "v.csv")):
        assert [e.run for e in read] == [runs[0]] * 3 + [runs[1]] * 3
        assert len({e.id for e in read}) == 3 and len({(e.run, e.id) for e in read}) == 6


def test_appending_to_a_csv_of_other_columns_keeps_it_aside_and_begins_anew(tmp_path: Path) -> None:
    """A CSV written with other columns (an earlier version's, without ``run``) is not appended to — every row after
    would sit under the wrong column — nor refused (a service upgraded with append=true would not start): it is
    kept aside whole (``v.earlier-<its last change>.csv``) and a new file with today's columns begun.  Before, the
    writer refused to open.  A file with our columns is appended to, as before; a pipe is never read."""
    path = tmp_path / "v.csv"
    old = ",".join(f for f in EVENT_FIELDS if f != "run") + "\n1,car,0.0,1.0,50.0,,,,,0,,,,,\n"
    path.write_text(old)
    with CsvEventWriter(path, append=True) as w:
        w.write(_events(1)[0])
    (kept,) = tmp_path.glob("v.earlier-*.csv")
    assert w.kept_aside == kept and kept.read_text() == old
    assert path.read_text().splitlines()[0] == ",".join(EVENT_FIELDS) and len(read_events_csv(path)) == 1
    with CsvEventWriter(path, append=True) as w:  # our own columns: appended to
        w.write(_events(2)[1])
    assert w.kept_aside is None and len(read_events_csv(path)) == 2 and len(list(tmp_path.glob("v.earlier-*"))) == 1
    with EventWriters.open(csv_path=path, append=True) as both:
        assert both.kept_aside == []


def test_runs_appended_to_one_file_go_on_one_clock() -> None:
    """Two dated runs in one file (each from its own stream time 0) are put on the earliest run's clock; a single
    run, its millisecond-rounded dates included, and undated events come back unchanged."""
    from gst_trafficcal.clock import parse_start_time

    first = [e.with_clock(parse_start_time("2026-12-05T08:00:00.0004+01:00")) for e in _events()]
    second = [e.with_clock(parse_start_time("2026-12-05T08:10:00+01:00")) for e in _events(3)]
    start, one = on_one_clock(first)
    assert one == first and start == parse_start_time("2026-12-05T08:00:00+01:00")
    start, both = on_one_clock(second + first)  # the later run first: the clock is still the earlier one's
    assert start == parse_start_time("2026-12-05T08:00:00+01:00")
    assert both[3:] == first
    assert [e.first_timestamp_s for e in both[:3]] == pytest.approx([600.0 + e.first_timestamp_s for e in _events(3)])
    assert [e.last_timestamp_s - e.first_timestamp_s for e in both] == pytest.approx(
        [e.last_timestamp_s - e.first_timestamp_s for e in second + first])
    assert on_one_clock(_events()) == (None, _events())


def test_unmeasured_vehicles_count_by_the_kind_of_reason() -> None:
    """Reasons that differ only in their figures count together; measured vehicles are not counted."""
    reasons = ["track too short (4 reference points, needs 10)", "speed samples disagree (only 21 % within 10 % "
               "of the vehicle's own motion, median 9.0 km/h, needs 60 %)", "track too short (9 reference points, "
               "needs 10)", "no reference point (no 3D box: never fully visible, nor cut by the top edge alone)",
               "track too short (1 reference points, needs 10)", "", "no calibration: VP2 not found"]
    events = [VehicleEvent(i, "car", 0.0, 1.0, None if r else 80.0, reason=r) for i, r in enumerate(reasons)]
    assert reason_kind(reasons[3]) == "no reference point" and reason_kind("stale") == "stale"
    assert unmeasured_by_kind(events) == [("track too short", 3), ("speed samples disagree", 1),
                                          ("no reference point", 1), ("no calibration", 1)]
    assert unmeasured_by_kind(events[5:6]) == []


def test_each_event_is_on_disk_before_the_next_is_written(tmp_path: Path) -> None:
    """No buffering: another reader sees every line as soon as write() returns (what survives a crash)."""
    path = tmp_path / "v.jsonl"
    w = JsonlEventWriter(path)
    for k, e in enumerate(_events(), 1):
        w.write(e)
        assert len(read_events(path).events) == k
    c = CsvEventWriter(tmp_path / "v.csv")
    c.write(_events()[0])
    assert len(read_events_csv(tmp_path / "v.csv")) == 1
    w.close()
    c.close()


def test_append_mode_keeps_earlier_events_and_single_csv_header(tmp_path: Path) -> None:
    ev = _events(4)
    for chunk in (ev[:2], ev[2:]):
        with EventWriters.open(tmp_path / "v.jsonl", tmp_path / "v.csv", append=True) as w:
            for e in chunk:
                w.write(e)
    assert read_events(tmp_path / "v.jsonl").events == ev
    assert read_events_csv(tmp_path / "v.csv") == ev
    assert (tmp_path / "v.csv").read_text().count("first_timestamp_s") == 1


def test_full_device_raises_input_error_naming_the_file() -> None:
    if not os.path.exists("/dev/full"):
        pytest.skip("/dev/full is not available")
    w = JsonlEventWriter("/dev/full")
    with pytest.raises(InputError, match=r"^/dev/full: cannot write \(No space left on device\)"):
        w.write(_events(1)[0])
    with pytest.raises(InputError, match="/dev/full"):
        CsvEventWriter("/dev/full")  # the header line already fails


def test_a_full_disk_under_one_file_does_not_cost_the_others_their_line(tmp_path: Path) -> None:
    if not os.path.exists("/dev/full"):
        pytest.skip("/dev/full is not available")
    w = EventWriters([JsonlEventWriter("/dev/full"), JsonlEventWriter(tmp_path / "ok.jsonl")])
    ev = _events(3)
    for e in ev:
        with pytest.raises(InputError, match="/dev/full"):
            w.write(e)
    w.close()
    assert read_events(tmp_path / "ok.jsonl").events == ev


_FILL_SCRIPT = textwrap.dedent("""
    import resource, signal, sys
    from gst_trafficcal.errors import InputError
    from gst_trafficcal.outputs import CsvEventWriter, JsonlEventWriter, VehicleEvent
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)           # the kernel then fails write() with EFBIG
    limit = int(sys.argv[2])
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))  # the disk is "full" at `limit` bytes
    w = (CsvEventWriter if sys.argv[1].endswith(".csv") else JsonlEventWriter)(sys.argv[1])
    written = 0
    try:
        for i in range(1, 10000):
            w.write(VehicleEvent(i, "car", i * 0.5, i * 0.5 + 1.0, 50.0 + i, lane=1, direction=1))
            written = i
    except InputError as exc:
        print(written)
        print(exc)
        sys.exit(0)
    sys.exit("never filled up")
""")


def _fill_up(path: Path, limit: int) -> tuple[int, str]:
    """Vehicles written to ``path`` (JSON lines, or CSV by its suffix) by a process whose files cannot grow beyond
    ``limit`` bytes (a real short write, then EFBIG) until a write fails: how many were written, and the error."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, "-c", _FILL_SCRIPT, str(path), str(limit)], capture_output=True, text=True,
                         env=env, timeout=60)
    assert out.returncode == 0, out.stderr
    written, message = out.stdout.splitlines()
    return int(written), message


def test_earlier_lines_survive_when_the_disk_fills_up(tmp_path: Path) -> None:
    """A real short write on a real file (file-size limit), then the file is read back: it ends with the last
    complete line, the one that did not fit is cut off again (no invalid JSON line is left)."""
    path = tmp_path / "v.jsonl"
    written, message = _fill_up(path, 2000)
    assert written >= 5 and message == f"{path}: cannot write (File too large); every earlier line is kept"
    text = path.read_text()
    assert 0 < len(text) < 2000 and text.endswith("\n")  # cut back to the last whole line
    assert [json.loads(line)["id"] for line in text.splitlines()] == list(range(1, written + 1))
    log = read_events(path)
    assert [e.id for e in log.events] == list(range(1, written + 1)) and log.skipped == 0
    assert log.events[-1].speed_kmh == 50.0 + written


def test_csv_rows_survive_when_the_disk_fills_up(tmp_path: Path) -> None:
    """The CSV events too: the row that did not fit is cut off again, every earlier row is whole."""
    path = tmp_path / "v.csv"
    written, message = _fill_up(path, 1500)
    assert written >= 5 and message == f"{path}: cannot write (File too large); every earlier line is kept"
    text = path.read_text()
    assert 0 < len(text) < 1500 and text.endswith("\n") and len(text.splitlines()) == written + 1  # + the header
    assert [e.id for e in read_events_csv(path)] == list(range(1, written + 1))


def test_a_line_that_does_not_fit_is_not_left_for_a_later_run(tmp_path: Path) -> None:
    """A later run appending to the file (after the disk got room again) continues right after the last whole
    line: every line of the file is a vehicle, none is a fragment."""
    path = tmp_path / "v.jsonl"
    written, _ = _fill_up(path, 1000)
    later = _events(2)
    with JsonlEventWriter(path, append=True) as w:
        for e in later:
            w.write(e)
    lines = path.read_text().splitlines()
    assert len(lines) == written + 2 and all(isinstance(json.loads(line), dict) for line in lines)
    assert read_events(path).skipped == 0


def test_a_writer_recovers_after_a_failed_write(tmp_path: Path) -> None:
    """After a cut line, the next successful write starts on a new line: only the fragment is lost."""
    path = tmp_path / "v.jsonl"
    w = JsonlEventWriter(path)
    ev = _events(3)
    w.write(ev[0])
    w._file._f.write(b'{"id": 99, "label": "ca')  # what a short write leaves behind
    w._file._broken = True
    w.write(ev[1])
    w.write(ev[2])
    w.close()
    log = read_events(path)
    assert log.events == ev and log.skipped == 1


def test_unwritable_location_is_a_clear_error(tmp_path: Path) -> None:
    (tmp_path / "f").write_text("x")
    with pytest.raises(InputError, match=r"f/v\.jsonl: cannot open for writing"):
        JsonlEventWriter(tmp_path / "f" / "v.jsonl")
    with pytest.raises(InputError, match=r"f/system\.json: cannot write BrnoCompSpeed results there"):
        BrnoResultsWriter(tmp_path / "f" / "system.json", 25.0)  # at once, not when the first car comes


def test_reading_bad_event_files(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no such event file"):
        read_events(tmp_path / "none.jsonl")
    (tmp_path / "bin.jsonl").write_bytes(b"\x00\x01garbage\nmore garbage\n")
    with pytest.raises(InputError, match="not a JSON-lines event file"):
        read_events(tmp_path / "bin.jsonl")
    (tmp_path / "list.jsonl").write_text("[1, 2]\n")
    with pytest.raises(InputError, match=r"list\.jsonl:1: not a vehicle event"):
        read_events(tmp_path / "list.jsonl")
    (tmp_path / "other.jsonl").write_text('{"foo": 1}\n')
    with pytest.raises(InputError, match="missing id, speed_kmh"):
        read_events(tmp_path / "other.jsonl")


@pytest.mark.parametrize("field", ["first_time", "last_time"])
def test_an_events_file_with_a_bad_date_is_named(tmp_path: Path, field: str) -> None:
    """A date that is no ISO 8601 time is refused where the file is read, with the file and its line: it used to
    pass, and the report then failed with "start time: 'yesterday' is not ..." naming no file."""
    from datetime import datetime, timezone

    good = {"id": 1, "label": "car", "first_timestamp_s": 1.0, "last_timestamp_s": 2.0, "speed_kmh": 50.0,
            "first_time": "2026-12-05T08:00:01.000+00:00", "last_time": "2026-12-05T08:00:02.000+00:00"}
    path = tmp_path / "vehicles.jsonl"
    path.write_text(json.dumps(good) + "\n" + json.dumps({**good, "id": 2, field: "yesterday"}) + "\n")
    with pytest.raises(InputError, match=rf"vehicles\.jsonl:2: bad vehicle event \({field} 'yesterday' is not an "
                                         r"ISO 8601 date and time"):
        on_one_clock(read_events(path).events)
    path.write_text(json.dumps(good) + "\n")
    assert on_one_clock(read_events(path).events)[0] == datetime(2026, 12, 5, 8, 0, tzinfo=timezone.utc)


# --------------------------------------------------------------------------- BrnoCompSpeed results


def _camera() -> Camera:
    return Camera.from_brno([967.0, -271.0], [-3911.0, 570.0], [960.5, 540.5], 0.0056)


def _track(rng: np.random.Generator, n: int, camera: Camera, v_kmh: float, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """Reference points of a vehicle driving towards VP1 at v_kmh on the road below the camera."""
    t = (np.arange(n) + rng.integers(0, 500)) / fps
    x = 15.0 + v_kmh / 3.6 * (t - t[0])
    world = np.stack([x, np.full(n, rng.uniform(-3, 3)), np.zeros(n)], axis=1)
    return t, camera.world_to_image(world)


def test_brno_results_round_trip_and_official_speeds(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    cam = _camera()
    cal = Calibration(cam, (1920, 1080), source="test")
    fps = 50.0
    w = BrnoResultsWriter(tmp_path / "system.json", fps)
    tracks = [_track(rng, 20 + 5 * k, cam, 60.0 + 10 * k, fps) for k in range(4)]
    for k, (t, p) in enumerate(tracks, 1):
        assert w.add(k, t, p)
    nan_track = np.full((3, 2), np.nan)
    assert not w.add(99, [0.0, 0.02, 0.04], nan_track)  # nothing measurable: not written
    w.write(cal)
    res = load_results(tmp_path / "system.json")
    assert [c.id for c in res.cars] == [1, 2, 3, 4]
    assert res.calibration.vp1 == tuple(cam.vp1) and res.calibration.scale == pytest.approx(0.0056, rel=1e-12)
    raw = json.loads((tmp_path / "system.json").read_text())
    assert all(isinstance(f, int) for f in raw["cars"][0]["frames"])  # exact frame numbers stay integers
    back = Camera.from_brno(res.calibration.vp1, res.calibration.vp2, res.calibration.pp, res.calibration.scale)
    official = median_speeds(res.cars, back, fps)  # what BrnoCompSpeed's evaluation will measure
    ours = [track_speed(cam, p, t).speed_kmh for t, p in tracks]
    np.testing.assert_allclose(official, ours, rtol=1e-9)
    np.testing.assert_allclose(official, [60, 70, 80, 90], rtol=1e-6)


def test_brno_results_drop_nan_points_and_keep_fractional_frames(tmp_path: Path) -> None:
    w = BrnoResultsWriter(tmp_path / "s.json", 25.0)
    t = np.array([0.0, 0.04, 0.0813, 0.12])
    p = np.array([[10.0, 20.0], [np.nan, np.nan], [12.0, 22.0], [13.0, 23.0]])
    w.add(5, t, p)
    w.write(None)  # no calibration yet: results without camera_calibration
    raw = json.loads((tmp_path / "s.json").read_text())
    assert "camera_calibration" not in raw
    car = raw["cars"][0]
    assert car["frames"][0] == 0 and car["frames"][1] == pytest.approx(2.0325) and car["frames"][2] == 3
    assert car["posX"] == [10.0, 12.0, 13.0]
    np.testing.assert_allclose(frames_from_times([1.0, 1.00001, 1.02], 50.0), [50, 50, 51])
    with pytest.raises(InputError, match="positive frame rate"):
        BrnoResultsWriter(tmp_path / "x.json", 0.0)


def test_brno_results_writer_closed_keeps_its_file(tmp_path: Path) -> None:
    """Closing lets go of the held cars (their anonymous file); the results file stays as last written, and a
    writer closed too early cannot replace it with one without its cars."""
    path = tmp_path / "system.json"
    w = BrnoResultsWriter(path, 25.0)
    w.add(1, [0.0, 0.04], [[10.0, 20.0], [11.0, 21.0]])
    w.write(None)
    before = path.read_text()
    w.close()
    w.close()  # twice: nothing more
    with pytest.raises(ValueError, match="closed"):
        w.write(None)
    with pytest.raises(InputError, match="cannot hold vehicle 2"):
        w.add(2, [0.0], [[1.0, 2.0]])
    assert path.read_text() == before and sorted(p.name for p in tmp_path.iterdir()) == ["system.json"]


def test_brno_results_are_written_atomically(tmp_path: Path) -> None:
    cam = _camera()
    cal = Calibration(cam, (1920, 1080))
    path = tmp_path / "system.json"
    w = BrnoResultsWriter(path, 50.0)
    w.add(1, [0.0, 0.02], [[900.0, 800.0], [901.0, 790.0]])
    w.write(cal)
    before = path.read_text()
    # a failing rewrite (here: the file-size limit, a real short write) leaves the previous file intact
    script = textwrap.dedent(f"""
        import resource, signal, sys
        import numpy as np
        from gst_trafficcal.calibration import load_calibration
        from gst_trafficcal.errors import InputError
        from gst_trafficcal.outputs import BrnoResultsWriter
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        hard = resource.getrlimit(resource.RLIMIT_FSIZE)[1]
        w = BrnoResultsWriter({str(path)!r}, 50.0)
        car = np.arange(30) * 0.02, np.column_stack([np.arange(30.0) + 500, np.arange(30.0) + 600])
        for k in range(1, 50):
            w.add(k, *car)
        resource.setrlimit(resource.RLIMIT_FSIZE, ({len(before) + 100}, hard))
        try:
            w.write(None)
        except InputError as exc:
            print(exc)
        # the cars held beside the file on a disk that fills up: the car that does not fit is an error, no half
        # car is left, and every car before it is written once there is room again
        resource.setrlimit(resource.RLIMIT_FSIZE, (4000, hard))  # room for a few cars
        w2 = BrnoResultsWriter({str(path.with_name("other.json"))!r}, 50.0)
        held = 0
        try:
            for k in range(1, 50):
                w2.add(k, *car)
                held += 1
        except InputError as exc:
            print(held, exc)
        resource.setrlimit(resource.RLIMIT_FSIZE, (hard, hard))
        w2.write(None)
        w2.close()
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60,
                         env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert out.returncode == 0, out.stderr
    first, second = out.stdout.splitlines()
    assert first.startswith(f"{path}: cannot write BrnoCompSpeed results (File too large)")
    assert path.read_text() == before
    held, message = second.split(" ", 1)
    assert 0 < int(held) < 49
    assert message.startswith(f"{tmp_path / 'other.json'}: cannot hold vehicle {int(held) + 1} for the BrnoCompSpeed "
                              "results (File too large); the vehicles before it are kept")
    assert [c.id for c in load_results(tmp_path / "other.json").cars] == list(range(1, int(held) + 1))
    # no temporary file left behind (the cars' own file is anonymous)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["other.json", "system.json"]
    (tmp_path / "dir.json").mkdir()
    with pytest.raises(InputError, match=r"dir\.json: a folder, not a regular file: cannot write BrnoCompSpeed "):
        BrnoResultsWriter(tmp_path / "dir.json", 50.0)  # at once, not at the end


def test_vehicle_outputs_write_everything_and_survive_a_failing_file(tmp_path: Path) -> None:
    from gst_trafficcal.outputs import VehicleOutputs

    cam = _camera()
    cal = Calibration(cam, (1920, 1080))
    rng = np.random.default_rng(0)
    out = VehicleOutputs(tmp_path / "v.jsonl", tmp_path / "v.csv", tmp_path / "system.json", fps=50.0)
    ev = _events(3)
    for e in ev:
        t, p = _track(rng, 12, cam, 70.0, 50.0)
        out.vehicle(e, t, p)
    out.close(cal)
    assert read_events(tmp_path / "v.jsonl").events == ev and read_events_csv(tmp_path / "v.csv") == ev
    assert [c.id for c in load_results(tmp_path / "system.json").cars] == [e.id for e in ev]
    with pytest.raises(InputError, match="frame rate"):
        VehicleOutputs(brno_json=tmp_path / "s.json")
    if not os.path.exists("/dev/full"):
        return
    # the event file is on a full disk: the BrnoCompSpeed file still gets every vehicle at close
    out = VehicleOutputs("/dev/full", None, tmp_path / "system2.json", fps=50.0)
    for e in ev:
        with pytest.raises(InputError, match="/dev/full"):
            out.vehicle(e, *_track(rng, 12, cam, 70.0, 50.0))
    out.close(cal)
    assert len(load_results(tmp_path / "system2.json").cars) == 3


def test_frame_records_in_gvametaconvert_shape(tmp_path: Path) -> None:
    from dataclasses import dataclass as _dc, field as _field

    from gst_trafficcal.outputs import FrameJsonlWriter, frame_record

    @_dc
    class Roi:  # the fields of gst.meta.RoiRecord
        meta_id: int
        label: str
        box: tuple
        confidence: float
        label_id: int
        object_id: int | None
        params: dict = _field(default_factory=dict)

    rois = [Roi(0, "car", (100.0, 50.0, 300.0, 150.0), 0.9, 2, 7,
                {"detection": {"x_min": 0.1}, "object_id": {"id": 7},
                 "speed": {"speed_kmh": 88.5, "label": "car", "confidence": np.float64(0.8)},
                 "trafficcal-vehicle": {"box3d": np.arange(16.0).reshape(8, 2), "world_x": float("nan")}}),
            Roi(1, "truck", (-10.0, 900.0, 50.0, 1200.0), 0.5, 7, None)]
    rec = frame_record(rois, (1000, 1000), 1.5, "file:///v.mp4")
    assert rec["resolution"] == {"height": 1000, "width": 1000} and rec["timestamp"] == 1_500_000_000
    a, b = rec["objects"]
    assert a["detection"] == {"bounding_box": {"x_min": 0.1, "y_min": 0.05, "x_max": 0.3, "y_max": 0.15},
                              "confidence": 0.9, "label": "car", "label_id": 2}
    assert (a["x"], a["y"], a["w"], a["h"], a["id"], a["region_id"], a["roi_type"]) == (100, 50, 200, 100, 7, 0, "car")
    assert a["speed"]["speed_kmh"] == 88.5 and a["trafficcal-vehicle"]["box3d"][7] == [14.0, 15.0]
    assert a["trafficcal-vehicle"]["world_x"] is None and "object_id" not in a
    assert "id" not in b and (b["x"], b["y"], b["w"], b["h"]) == (0, 900, 50, 100)  # clipped to the frame
    with FrameJsonlWriter(tmp_path / "frames.jsonl", skip_empty=True) as w:
        w.write(rois, (1000, 1000), 0.0)
        w.write([], (1000, 1000), 0.04)
        w.write(rois[:1], (1000, 1000), 0.08)
    lines = [json.loads(x) for x in (tmp_path / "frames.jsonl").read_text().splitlines()]
    assert [len(x["objects"]) for x in lines] == [2, 1] and lines[1]["timestamp"] == 80_000_000


@pytest.fixture
def tiny_disk(tmp_path: Path):
    """A real 64 KiB filesystem (tmpfs); skipped where mounting is not allowed (not root, no CAP_SYS_ADMIN)."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a tiny tmpfs needs root")
    out = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)], capture_output=True,
                         text=True, timeout=30)
    if out.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {out.stderr.strip()}")
    try:
        yield mnt
    finally:
        # lazily: files a failed test left open must not keep it mounted under pytest's old folders
        subprocess.run(["umount", "--lazy", str(mnt)], capture_output=True, timeout=30)


def test_a_really_full_disk(tiny_disk: Path, tmp_path: Path) -> None:
    """ENOSPC from a real filesystem: every earlier vehicle stays readable, other files keep getting events,
    and the BrnoCompSpeed file written before the disk filled up is not replaced by a partial one."""
    from gst_trafficcal.outputs import VehicleOutputs

    cam = _camera()
    cal = Calibration(cam, (1920, 1080))
    rng = np.random.default_rng(1)
    brno = tiny_disk / "system.json"
    out = VehicleOutputs(tiny_disk / "v.jsonl", tmp_path / "v.csv", brno, fps=50.0)
    first_error = None
    n = 0
    while first_error is None and n < 5000:
        n += 1
        e = VehicleEvent(n, "car", n * 0.5, n * 0.5 + 2.0, 60.0 + n % 40, lane=n % 3, direction=1,
                         calibration_id=cal.id, n_samples=20)
        try:
            out.vehicle(e, *_track(rng, 40, cam, 60.0, 50.0))
            if n == 3:
                out.checkpoint(cal)  # a BrnoCompSpeed file with 3 vehicles, before the disk is full
        except InputError as exc:
            first_error = str(exc)
    # the first file to find the disk full: the events, or the cars held for the BrnoCompSpeed file beside them
    assert first_error is not None
    assert first_error.startswith((f"{tiny_disk / 'v.jsonl'}: cannot write (No space left",
                                   f"{brno}: cannot hold vehicle {n} for the BrnoCompSpeed results (No space left"))
    for k in range(3):  # the disk stays full: later vehicles still reach the CSV on the other disk
        with pytest.raises(InputError, match="No space left on device"):
            out.vehicle(VehicleEvent(n + 1 + k, "car", 0, 1, 50.0), *_track(rng, 40, cam, 60.0, 50.0))
    with pytest.raises(InputError, match=r"system\.json: cannot write BrnoCompSpeed results \(No space left"):
        out.close(cal)
    log = read_events(tiny_disk / "v.jsonl")
    assert [e.id for e in log.events] == list(range(1, len(log.events) + 1)) and len(log.events) >= n - 1
    assert log.skipped <= 1
    assert [e.id for e in read_events_csv(tmp_path / "v.csv")] == list(range(1, n + 4))
    assert [c.id for c in load_results(brno).cars] == [1, 2, 3]  # the checkpoint, intact
    assert sorted(p.name for p in tiny_disk.iterdir()) == ["system.json", "v.jsonl"]  # no temporary file left


def test_a_growing_results_file_is_rewritten_less_often_as_it_grows():
    """At least every 10 s of stream, but never spending more than 1 % of the time on rewriting it."""
    from gst_trafficcal.outputs import checkpoint_interval

    assert checkpoint_interval(0.01) == 10.0  # a small file: every 10 s
    assert checkpoint_interval(0.5) == pytest.approx(50.0)  # a day's file taking half a second: every 50 s
    assert checkpoint_interval(3.0, minimum_s=10.0, share=0.05) == pytest.approx(60.0)


def test_vehicles_measured_again_replace_their_lines_in_every_file(tmp_path: Path) -> None:
    """VehicleOutputs.revise (speedometer remeasure): each revised vehicle's line replaced in place in the JSON
    lines and the CSV — only the line of its own run, lines of an earlier run with the same id and a torn line
    left as they were — and its car in the BrnoCompSpeed results replaced, or left out when no longer measured."""
    from dataclasses import replace

    events = _events(4)
    earlier = [replace(e, run="20261206T060000Z-aaaa") for e in events]
    with EventWriters.open(tmp_path / "v.jsonl", tmp_path / "v.csv") as w:
        for e in earlier:
            w.write(e)
    with open(tmp_path / "v.jsonl", "a") as fh:
        fh.write('{"id": 9, "speed_k')  # torn by a crash
    run = [replace(e, run="20261206T070000Z-bbbb") for e in events]
    out = VehicleOutputs(tmp_path / "v.jsonl", tmp_path / "v.csv", tmp_path / "system.json", fps=25.0, append=True)
    pts = np.array([[100.0, 200.0], [110.0, 210.0], [120.0, 220.0]])
    for e in run:
        out.vehicle(e, [0.0, 0.04, 0.08], pts)
    faster = replace(run[0], speed_kmh=run[0].speed_kmh * 1.1, calibration_id="f1a1")
    gone = replace(run[1], speed_kmh=None, reason="speed samples disagree")
    out.revise([(faster, np.array([0.0, 0.04]), pts[:2]), (gone, None, None)])
    out.close(None)
    log = read_events(tmp_path / "v.jsonl")
    assert log.skipped == 1
    assert log.events == earlier + [faster, gone] + run[2:]
    assert read_events_csv(tmp_path / "v.csv") == earlier + [faster, gone] + run[2:]
    cars = {c.id: c for c in load_results(tmp_path / "system.json").cars}
    assert sorted(cars) == sorted(e.id for e in run if e.id != gone.id)
    assert len(cars[faster.id].frames) == 2 and len(cars[run[2].id].frames) == 3


def test_symlinked_files_stay_links_when_written_whole(tmp_path: Path) -> None:
    """The BrnoCompSpeed results and event files revised at the end (remeasure) are renamed into place: through a
    symlink that is its target (the link stays a link), where before the link was replaced by a regular file and
    its target kept the old content."""
    from dataclasses import replace

    real, links = tmp_path / "real", tmp_path / "links"
    real.mkdir()
    links.mkdir()
    for name in ("system.json", "v.jsonl", "v.csv"):
        (real / name).write_text("")
        (links / name).symlink_to(f"../real/{name}")
    run = [replace(e, run="20261206T070000Z-bbbb") for e in _events(3)]
    out = VehicleOutputs(links / "v.jsonl", links / "v.csv", links / "system.json", fps=25.0)
    pts = np.array([[100.0, 200.0], [110.0, 210.0]])
    for e in run:
        out.vehicle(e, [0.0, 0.04], pts)
    faster = replace(run[0], speed_kmh=run[0].speed_kmh * 1.1)
    out.revise([(faster, np.array([0.0, 0.04]), pts)])
    out.close(None)
    assert all((links / name).is_symlink() for name in ("system.json", "v.jsonl", "v.csv"))
    assert read_events(real / "v.jsonl").events == [faster] + run[1:]
    assert read_events_csv(real / "v.csv") == [faster] + run[1:]
    assert [c.id for c in load_results(real / "system.json").cars] == [e.id for e in run]
    assert sorted(p.name for p in real.iterdir()) == ["system.json", "v.csv", "v.jsonl"]  # no temporary file


def test_a_named_pipe_is_no_results_file_and_events_sent_down_one_are_not_revised(tmp_path: Path) -> None:
    """A results file renamed into place cannot go to a named pipe (it would be replaced by a regular file): an
    error when the writer is made, not at the end. Events written down a pipe are gone: revising them reads
    nothing (it once waited for another writer of the pipe) and leaves the pipe as it is."""
    import stat
    import threading

    from gst_trafficcal.outputs import revise_event_file

    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match=rf"^{fifo}: a named pipe, not a regular file: cannot write BrnoCompSpeed "
                                         "results there"):
        BrnoResultsWriter(fifo, 25.0)
    done: list[int] = []
    revising = threading.Thread(target=lambda: done.append(revise_event_file(fifo, {(None, 1): _events(1)[0]},
                                                                              False)), daemon=True)
    revising.start()
    revising.join(10)
    blocked = revising.is_alive()
    if blocked:  # waiting for a writer to the pipe it opened to read: let it go before failing
        os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        revising.join(10)
    assert not blocked and done == [0]
    assert stat.S_ISFIFO(fifo.lstat().st_mode)
