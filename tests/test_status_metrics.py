"""status_metrics: runs' status as Prometheus metrics (trafficcal status --prometheus)."""

from __future__ import annotations

from gst_trafficcal.run_status import StatusFile


def test_trafficcal_status_as_prometheus_metrics(tmp_path):
    """--prometheus: the runs as Prometheus text, read back with prometheus_client's own parser — a series per run
    labelled with its folder and source: healthy, state, the counters, the ages; a run without a readable status is
    unhealthy and nothing more."""
    import subprocess
    import sys
    from datetime import datetime, timedelta

    from prometheus_client.parser import text_string_to_metric_families

    cameras = tmp_path / "cameras"
    (cameras / "east").mkdir(parents=True)
    (cameras / "west").mkdir()
    east = StatusFile(cameras / "east" / "status.json", 'rtsp://nvr/"east"')
    east.update(state="running", vehicles=12, measured=10, frames=3000, frames_dropped=7, camera_moves=1,
                speed_x=1.0, position_s=120.0, calibration={"state": "calibrated", "id": "a", "scale_m": 9.2,
                                                     "speed_sensitivity_pct": 12.5},
                last_vehicle_at=(datetime.now().astimezone() - timedelta(seconds=30)).isoformat())
    (cameras / "west" / "status.json").write_text("{not json")
    run = subprocess.run([sys.executable, "-m", "gst_trafficcal", "status", str(cameras), "--prometheus"],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 1, run.stdout + run.stderr  # west has no status
    series = {(s.name, s.labels.get("run"), s.labels.get("state")): s.value
              for family in text_string_to_metric_families(run.stdout) for s in family.samples}
    e, w = str(cameras / "east"), str(cameras / "west")
    assert series[("trafficcal_healthy", e, None)] == 1.0 and series[("trafficcal_healthy", w, None)] == 0.0
    assert series[("trafficcal_state", e, "running")] == 1.0 and series[("trafficcal_state", e, "failed")] == 0.0
    assert [series[(f"trafficcal_{n}_total", e, None)] for n in
            ("vehicles", "vehicles_measured", "frames", "frames_dropped", "camera_moves")] == [12, 10, 3000, 7, 1]
    assert series[("trafficcal_speed_ratio", e, None)] == 1.0 and series[("trafficcal_calibrated", e, None)] == 1.0
    assert 29 < series[("trafficcal_last_vehicle_age_seconds", e, None)] < 90
    assert series[("trafficcal_view_speed_sensitivity_percent", e, None)] == 12.5
    shown = subprocess.run([sys.executable, "-m", "gst_trafficcal", "status", str(cameras / "east")],
                           capture_output=True, text=True, timeout=60)
    assert "scale 9.2); speeds 12.5 % per 0.1° of VP2 (a view along the road)" in shown.stdout, shown.stdout
    assert 0 <= series[("trafficcal_status_age_seconds", e, None)] < 60
    assert [k for k in series if k[1] == w] == [("trafficcal_healthy", w, None)]
    sources = {s.labels["source"] for f in text_string_to_metric_families(run.stdout) for s in f.samples}
    assert sources == {'rtsp://nvr/"east"', ""}  # the quotes escaped and read back
    both = subprocess.run([sys.executable, "-m", "gst_trafficcal", "status", str(cameras), "--prometheus", "--json"],
                          capture_output=True, text=True, timeout=60)
    assert both.returncode == 2 and "--json or --prometheus, not both" in both.stderr


def test_frames_help_text_covers_a_file(tmp_path):
    """trafficcal_frames_total counts a file's frames too (run.md, since stop 47): its help text said "A live
    stream's frames"; the dropped frames are a live stream's alone."""
    from datetime import datetime

    from prometheus_client.parser import text_string_to_metric_families

    from gst_trafficcal.run_status import read_status
    from gst_trafficcal.status_metrics import RunHealth, prometheus_text

    StatusFile(tmp_path / "status.json", "video.mp4").update(state="running", frames=250)
    run = RunHealth(str(tmp_path / "status.json"), read_status(tmp_path / "status.json"))
    families = {f.name: f for f in text_string_to_metric_families(prometheus_text([run], datetime.now().astimezone()))}
    assert families["trafficcal_frames"].documentation == "Frames that reached the analysis, of a file or a live stream"
    assert [s.value for s in families["trafficcal_frames"].samples if s.name == "trafficcal_frames_total"] == [250]
    assert families["trafficcal_frames_dropped"].documentation.endswith("could not keep up (0 for a file)")
