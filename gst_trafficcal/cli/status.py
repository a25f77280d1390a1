"""``trafficcal status``: what a run is doing, from its status.json — for people and for health checks."""

from __future__ import annotations

import sys
from datetime import datetime
from pathlib import Path

import click


def _ago(iso: str | None, now: datetime) -> str:
    if not iso:
        return "–"
    try:
        s = (now - datetime.fromisoformat(iso)).total_seconds()
    except ValueError:
        return iso
    return f"{iso} ({s:.0f} s ago)"


@click.command(name="status")
@click.argument("path", metavar="OUT_DIR|STATUS.json", type=click.Path(path_type=Path))
@click.option("--max-age", "max_age_s", type=click.FloatRange(min=0, min_open=True), default=60.0, show_default=True,
              metavar="SECONDS",
              help="A run not ended whose status is older than this, or whose stream has been lost this long, is "
                   "unhealthy.")
@click.option("--json", "as_json", is_flag=True, help="Print the status file's JSON (plus 'healthy' and 'problems').")
def command(path: Path, max_age_s: float, as_json: bool) -> None:
    """Print what the `trafficcal run` writing into OUT_DIR is doing (its status.json): state, stream position and
    speed against real time, calibration, vehicles, the last vehicle, dropped frames, warnings.

    Exit code 0 when the run is healthy (running and updated within --max-age, or ended as it should), 1 when not
    (failed; no update for --max-age seconds; its process gone; the stream lost for --max-age seconds), 2 when
    there is no readable status: usable as a container or service health check, e.g.
    HEALTHCHECK CMD trafficcal status /out --max-age 60.
    """
    import json
    from dataclasses import asdict

    from ..errors import InputError
    from ..run_status import health, read_status

    file = path / "status.json" if path.is_dir() else path
    if not file.exists():
        raise InputError(f"{file}: no such file (give the --out folder of a trafficcal run, or its status.json)")
    status = read_status(file)
    now = datetime.now().astimezone()
    problems = health(status, max_age_s, now)
    if as_json:
        click.echo(json.dumps({**asdict(status), "healthy": not problems, "problems": problems}, indent=1))
        sys.exit(1 if problems else 0)
    cal = status.calibration or {}
    position = "–" if status.position_s is None else (
        f"{status.position_s:.1f} s" + (f" of {status.duration_s:.1f} s" if status.duration_s else ""))
    lines = [
        f"{file}: {status.state} since {_ago(status.state_since, now)}",
        f"  source      {status.source}" + (f"  (part {status.part}, {status.parts_done} done)" if status.part else ""),
        f"  position    {position}" + ("" if status.speed_x is None else f", {status.speed_x:.2f} x real time"),
        "  calibration " + (f"{cal.get('state')} ({cal.get('source')}, id {cal.get('id')}, "
                            + ("no scale" if cal.get("scale_m") is None else f"scale {cal['scale_m']:g}") + ")"
                            if cal else "none yet"),
        f"  vehicles    {status.vehicles}, {status.measured} measured; last {_ago(status.last_vehicle_at, now)}",
    ]
    if status.frames:
        lines.append(f"  frames      {status.frames} of the live stream, {status.frames_dropped} dropped to keep up")
    if status.camera_moves:
        lines.append(f"  camera      moved {status.camera_moves} time(s)")
    if status.state == "reconnecting":
        lines.append(f"  next try    {status.next_attempt_at}; stream lost {_ago(status.stream_lost_at, now)}")
    if status.error:
        lines.append(f"  last error  {status.error}")
    lines += [f"  warning     {w}" for w in status.warnings]
    lines.append(f"  updated     {_ago(status.updated_at, now)} by process {status.pid} on {status.host}")
    lines += [f"UNHEALTHY: {p}" for p in problems] or ["healthy"]
    click.echo("\n".join(lines))
    sys.exit(1 if problems else 0)
