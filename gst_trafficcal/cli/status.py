"""``trafficcal status``: what a run is doing, from its status.json — for people and for health checks."""

from __future__ import annotations

import json
import sys
from dataclasses import asdict
from datetime import datetime
from pathlib import Path

import click


def _ago(iso: str | None, now: datetime) -> str:
    """A status's time with how long ago it was — or how far in the future, when the writer's clock is ahead."""
    from ..run_status import age_s

    if not iso:
        return "–"
    s = age_s(iso, now)
    if s is None:
        return iso
    if s > -0.5:
        return f"{iso} ({max(s, 0.0):.0f} s ago)"
    return f"{iso} ({-s:.0f} s in the future: clocks differ)"


def _document(status, problems: list[str]) -> dict:
    """What --json prints of a run: its status file's fields (none without a status), with whether it is healthy
    and why not."""
    return {**(asdict(status) if status is not None else {}), "healthy": not problems, "problems": problems}


NOT_CAMERAS = ("lost+found",)  # folders a volume of camera folders may hold that are never a camera's


def _run_outputs() -> tuple[str, ...]:
    """What a run leaves in its --out (any one of them makes a folder a run's)."""
    from .run import OUTPUTS

    return ("status.json", "parts.csv", "views") + OUTPUTS


def _holds_a_run(folder: Path) -> bool:
    """Whether ``folder`` holds any of a run's outputs: it is a run's --out, with its status.json or without."""
    return any((folder / name).exists() for name in _run_outputs())


def _camera_folders(folder: Path) -> list[Path]:
    """The subfolders of ``folder`` that are a camera's --out: one with any of a run's outputs, an empty one (a
    camera whose run has not written yet) or one that cannot be looked into; not hidden ones, lost+found, or ones
    of other things only (notes)."""
    cameras = []
    for child in sorted(folder.iterdir()):
        if child.name.startswith(".") or child.name in NOT_CAMERAS or not child.is_dir():
            continue
        try:
            if _holds_a_run(child) or next(child.iterdir(), None) is None:
                cameras.append(child)
        except OSError:  # unreadable: its status cannot be told, which is reported, not hidden
            cameras.append(child)
    return cameras


def status_files(paths: tuple[Path, ...]) -> list[Path]:
    """The status files ``paths`` name: a status.json itself; a run's --out folder (its status.json); or a folder of
    such folders, one per camera (``_camera_folders``; each one's status.json, there or not, so a camera without a
    status is reported, not skipped) when the folder holds no run's outputs of its own."""
    files = []
    for path in paths:
        try:
            cameras = _camera_folders(path) if path.is_dir() and not _holds_a_run(path) else []
        except OSError:  # a folder that cannot be read: its status.json cannot be either, which is said
            cameras = []
        if cameras:
            files += [camera / "status.json" for camera in cameras]
        else:
            files.append(path / "status.json" if path.is_dir() else path)
    return files


@click.command(name="status")
@click.argument("paths", nargs=-1, required=True, metavar="OUT_DIR|STATUS.json...", type=click.Path(path_type=Path))
@click.option("--max-age", "max_age_s", type=click.FloatRange(min=0, min_open=True), default=60.0, show_default=True,
              metavar="SECONDS",
              help="A run not ended whose status is older than this, or whose stream has been lost this long, is "
                   "unhealthy.")
@click.option("--json", "as_json", is_flag=True, help="Print the status file's JSON (plus 'healthy' and 'problems'); "
                                                      "for several runs, a list of them (plus 'path').")
@click.option("--prometheus", is_flag=True,
              help="Print the runs as Prometheus metrics (text format), e.g. for node_exporter's textfile collector: "
                   "trafficcal status /srv/cameras --prometheus > /var/lib/node_exporter/textfile/trafficcal.prom")
def command(paths: tuple[Path, ...], max_age_s: float, as_json: bool, prometheus: bool) -> None:
    """Print what the `trafficcal run` writing into OUT_DIR is doing (its status.json): state, stream position and
    speed against real time, calibration, vehicles, the last vehicle, dropped frames, warnings.

    Exit code 0 when the run is healthy (running and updated within --max-age, or ended as it should), 1 when not
    (failed; no update for --max-age seconds; its process gone; the stream lost for --max-age seconds; its last
    update in the future, also an ended run's: the clocks differ), 2 when there is no readable status: usable as a
    container or service health check, e.g. HEALTHCHECK CMD trafficcal status /out --max-age 60.

    Several runs — several OUT_DIRs, or a folder holding one OUT_DIR per camera (trafficcal status /srv/cameras)
    — are a line each and a count; exit code 0 when every one is healthy, 1 when any is not or has no readable
    status. A camera's folder is any subfolder with a run's outputs (status.json, calibration.json,
    vehicles.jsonl, ...) or an empty one, reported without a status when it has no status.json; hidden folders,
    lost+found and folders of other files are not cameras.
    """
    if as_json and prometheus:
        raise click.UsageError("--json or --prometheus, not both")
    files = status_files(paths)
    if prometheus:
        _prometheus(files, max_age_s)
    if len(files) > 1:
        _several(files, max_age_s, as_json)
    _one(files[0], max_age_s, as_json)


def judged(files: list[Path], max_age_s: float, now: datetime) -> list:
    """Each run's status read and judged (``status_metrics.RunHealth``); a missing or unreadable one is unhealthy
    with the reason."""
    from ..errors import InputError
    from ..run_status import health, read_status
    from ..status_metrics import RunHealth

    runs = []
    for file in files:
        try:
            status = read_status(file)  # "FILE: no such file" when there is none
        except InputError as exc:
            runs.append(RunHealth(str(file), None, [f"no status: {str(exc).removeprefix(f'{file}: ')}"]))
            continue
        runs.append(RunHealth(str(file), status, health(status, max_age_s, now)))
    return runs


def _several(files: list[Path], max_age_s: float, as_json: bool) -> None:
    """A line per run (or a JSON list), then how many are healthy; exits 0 when all are, 1 otherwise."""
    now = datetime.now().astimezone()
    runs = judged(files, max_age_s, now)
    if as_json:
        click.echo(json.dumps([{"path": r.path, **_document(r.status, r.problems)} for r in runs], indent=1))
    else:
        lines = []
        for r in runs:
            verdict = "; ".join(f"UNHEALTHY: {p}" for p in r.problems) or "healthy"
            s = r.status
            if s is None:
                lines.append(f"{r.path}: {verdict}")
                continue
            speed = "" if s.speed_x is None else f", {s.speed_x:.2f} x real time"
            lines.append(f"{r.path}: {s.state}{speed}; {s.vehicles} vehicles, {s.measured} measured; last "
                         f"{_ago(s.last_vehicle_at, now)}; {verdict}")
        bad = sum(bool(r.problems) for r in runs)
        click.echo("\n".join(lines + [f"{len(runs)} runs: {len(runs) - bad} healthy, {bad} not"]))
    sys.exit(1 if any(r.problems for r in runs) else 0)


def _prometheus(files: list[Path], max_age_s: float) -> None:
    """The runs as Prometheus metrics; exits 0 when every run is healthy, 1 otherwise."""
    from ..status_metrics import prometheus_text

    now = datetime.now().astimezone()
    runs = judged(files, max_age_s, now)
    click.echo(prometheus_text(runs, now), nl=False)
    sys.exit(1 if any(r.problems for r in runs) else 0)


def _one(file: Path, max_age_s: float, as_json: bool) -> None:
    """One run's status in full (or its JSON); exits 0 healthy, 1 not (InputError, exit 2, without a status)."""
    from ..errors import InputError
    from ..run_status import health, read_status

    if not file.exists():
        raise InputError(f"{file}: no such file (give the --out folder of a trafficcal run, or its status.json)")
    status = read_status(file)
    now = datetime.now().astimezone()
    problems = health(status, max_age_s, now)
    if as_json:
        click.echo(json.dumps(_document(status, problems), indent=1))
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
                            + _sensitivity(cal.get("speed_sensitivity_pct"))
                            if cal else "none yet"),
        f"  vehicles    {status.vehicles}, {status.measured} measured; last {_ago(status.last_vehicle_at, now)}",
    ]
    live = "://" in status.source and not status.source.startswith("file://")
    if status.frames and live:  # a stream (a file waits for us: no frame of it is dropped)
        lines.append(f"  frames      {status.frames} of the live stream, {status.frames_dropped} dropped to keep up")
    elif status.frames:
        lines.append(f"  frames      {status.frames} of the file")
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


def _sensitivity(pct) -> str:
    """The view's sensitivity to VP2 as the status line says it ("" when the status has none)."""
    from ..vanishing.conditioning import POOR_PCT, TURN_DEG

    if not isinstance(pct, (int, float)):
        return ""
    return f"; speeds {pct:.1f} % per {TURN_DEG:g}° of VP2" + (" (a view along the road)" if pct >= POOR_PCT else "")
