"""Runs' status as Prometheus metrics (``trafficcal status --prometheus``).

Monitoring that already scrapes Prometheus — node_exporter's textfile collector fed by a cron job, or any scraper
of a text file — gets every camera's run as series labelled ``run`` (the status file's folder) and ``source``:
whether it is healthy, its state, vehicles and measured vehicles, frames and a live stream's dropped frames,
camera moves (counters), speed against real time, the stream position, how old the status and the last
vehicle are, and how firmly the view pins the speeds down (gauges).  A run without a readable status is
``trafficcal_healthy 0`` with nothing else.  The text is made by ``prometheus_client``, which also escapes the
labels.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

from .run_status import STATES, RunStatus, age_s


@dataclass(frozen=True)
class RunHealth:
    """One run as ``trafficcal status`` judged it: where its status file is, the status (None when there is no
    readable one) and why it is unhealthy (empty: healthy)."""

    path: str
    status: RunStatus | None
    problems: list[str] = field(default_factory=list)


LABELS = ["run", "source"]


class _RunsCollector:
    def __init__(self, runs: Sequence[RunHealth], now: datetime) -> None:
        self.runs, self.now = runs, now

    def collect(self):
        healthy = GaugeMetricFamily("trafficcal_healthy", "1 when the run is healthy (trafficcal status exit code 0)",
                                    labels=LABELS)
        state = GaugeMetricFamily("trafficcal_state", "1 for the state the run is in", labels=LABELS + ["state"])
        counters = {name: CounterMetricFamily(f"trafficcal_{name}", text, labels=LABELS) for name, text in (
            ("vehicles", "Vehicles that left the view, the whole run"),
            ("vehicles_measured", "Of those, vehicles with a speed"),
            ("frames", "Frames that reached the analysis, of a file or a live stream"),
            ("frames_dropped", "Of those, frames a live stream dropped because the machine could not keep up "
             "(0 for a file)"),
            ("camera_moves", "Times the camera was seen to move"))}
        gauges = {name: GaugeMetricFamily(f"trafficcal_{name}", text, labels=LABELS) for name, text in (
            ("speed_ratio", "Stream seconds measured per wall-clock second"),
            ("position_seconds", "Stream position of the part being measured"),
            ("calibrated", "1 when the calibration in force has a scale (speeds are measured)"),
            ("view_speed_sensitivity_percent", "How much the speeds change (%) under a 0.1 degree error of VP2: "
             "2 or more for a view along the road"),
            ("status_age_seconds", "Seconds since the status file was last written (negative: the writer's clock "
             "is ahead of this machine's)"),
            ("last_vehicle_age_seconds", "Seconds since the last vehicle left the view (negative: the writer's clock "
             "is ahead)"))}
        for run in self.runs:
            s = run.status
            labels = [str(Path(run.path).parent), "" if s is None else s.source]
            healthy.add_metric(labels, float(not run.problems))
            if s is None:
                continue
            for name in STATES:
                state.add_metric(labels + [name], float(s.state == name))
            for name, value in (("vehicles", s.vehicles), ("vehicles_measured", s.measured), ("frames", s.frames),
                                ("frames_dropped", s.frames_dropped), ("camera_moves", s.camera_moves)):
                counters[name].add_metric(labels, float(value))
            scaled = bool(s.calibration) and s.calibration.get("scale_m") is not None
            for name, value in (("speed_ratio", s.speed_x), ("position_seconds", s.position_s),
                                ("calibrated", float(scaled)), ("status_age_seconds", age_s(s.updated_at, self.now)),
                                ("view_speed_sensitivity_percent", _number((s.calibration or {}).get(
                                    "speed_sensitivity_pct"))),
                                ("last_vehicle_age_seconds", age_s(s.last_vehicle_at or "", self.now))):
                if value is not None:
                    gauges[name].add_metric(labels, float(value))
        yield healthy
        yield state
        yield from counters.values()
        yield from gauges.values()


def _number(value) -> float | None:
    """A status field's number, or None for anything else (a hand-edited file, an unbounded sensitivity)."""
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None


def prometheus_text(runs: Sequence[RunHealth], now: datetime) -> str:
    """The Prometheus text exposition of ``runs`` at ``now`` (ages are counted to it)."""
    registry = CollectorRegistry(auto_describe=False)
    registry.register(_RunsCollector(runs, now))
    return generate_latest(registry).decode("utf-8")
