"""``trafficcal run`` over several inputs: a camera's recordings in parts, or a live stream's connections.

Each part is one :func:`.run.run_one` into a folder of its own; the latest calibration with a scale carries over to
the next part (vpdetect mode auto: checked against the part's view, so a camera moved in between is calibrated
anew, and bbscale passes the scale on as it is); a part that fails does not stop the others; a table of the parts
ends the run, and ``--out``/parts.csv (rewritten after each part, so a live session always has an up-to-date index)
holds the same rows.
"""

from __future__ import annotations

import contextlib
from pathlib import Path

from ..clock import next_boundary
from ..errors import InputError
from .run import RunOptions, run_one
from .terminal import log_line, say, stderr_console


def run_files(console, videos: list[Path], out_dir: Path, calibration_path: Path | None,
              options: RunOptions, starts: list | None = None) -> str:
    """Several files of one camera, each into ``out_dir``/NAME: the calibration with a scale found so far carries
    over (vpdetect mode auto: checked against each file's view); a table of them at the end.  Returns "" when
    every file ran, "interrupted" after Ctrl-C, or what failed.  ``starts``: each file's start (date and time, from
    its name): every vehicle dated, and ``out_dir``/intervals.csv counts the traffic of all the files."""
    parts = [(v, name, v.name) for v, name in zip(videos, _output_names(videos))]
    return run_parts(console, parts, len(videos), out_dir, calibration_path, options, starts=starts)


def run_stream(console, uri: str, out_dir: Path, calibration_path: Path | None, options: RunOptions) -> str:
    """A live stream that is connected again whenever it fails or ends (``--reconnect``): each connection into
    ``out_dir``/YYYYmmdd-HHMMSS (when it started), the calibration carried over like a camera's files; until
    Ctrl-C or ``--duration`` seconds of video in all."""
    from datetime import datetime

    from ..fileio import free_path

    def connections():
        while True:
            name = free_path(out_dir / f"{datetime.now():%Y%m%d-%H%M%S}").name
            yield uri, name, name

    return run_parts(console, connections(), None, out_dir, calibration_path, options, live=True)


PARTS_FIELDS = ("part", "folder", "vehicles", "measured", "mean_kmh", "v85_kmh", "calibration", "status", "error")
"""Columns of parts.csv: one row per file or connection."""
RECONNECT_MAX_WAIT = 60.0  # seconds between attempts to connect again, at most (doubling from 1 s)
HEALTHY_S = 10.0  # a connection that ran this long resets the wait to 1 s


def run_parts(console, parts, total: int | None, out_dir: Path, calibration_path: Path | None,
              options: RunOptions, live: bool = False, starts: list | None = None) -> str:
    """Each (input, folder name, label) of ``parts`` in turn into ``out_dir``/NAME, the latest calibration with a
    scale carried over to the next; a failure does not stop the others.  ``live``: the parts are connections to
    one stream, made again after a wait (1 s, doubling to a minute while they keep failing) until Ctrl-C or
    ``options.duration_s`` seconds of video in all.  Prints a table of the parts; returns "" when all ran,
    "interrupted" after Ctrl-C, or what failed (a live run: "", since it ran until it was stopped)."""
    import time
    from dataclasses import replace as dc_replace

    from rich.table import Table

    from ..calibration import load_calibration, save_calibration, save_view
    from ..traffic_stats import speed_stats
    from ..zone import parse_zone

    options = dc_replace(options, views_dir=out_dir / "views")  # the camera's views, kept from part to part
    combined = _AllVehicles(console, out_dir, min(starts) if starts else None)
    carried = None  # (calibration with a scale, the part it came from)
    rows, failures, records = [], [], []
    dated = []  # (start of the part, its events, seconds of it watched) for the intervals of all the parts
    used_s, wait = 0.0, 1.0
    interrupted = False
    for k, (video, name, label) in enumerate(parts, 1):
        sub = out_dir / name
        console.rule(f"[bold]{k}/{total}[/] {label} -> {sub}" if total else f"[bold]connection {k}[/] -> {sub}")
        if options.status is not None:
            options.status.update(part=name, parts_done=k - 1, next_attempt_at=None, force=True,
                                  **({"state": "starting"} if live else {}))
        given, mode = calibration_path, "fixed"
        if given is None and carried is not None:
            sub.mkdir(parents=True, exist_ok=True)
            given, mode = sub / "calibration.json", "auto"
            cal, origin = carried
            # not bbscale's own any more: a scale from a file, which bbscale passes on as it is
            save_calibration(dc_replace(cal, source=f"{cal.source}, carried over from {origin}"), given,
                             zone=parse_zone(options.zone), orientation=options.orientation)
        opts = options if starts is None else dc_replace(options, start=starts[k - 1])
        if options.duration_s is not None:  # seconds of video in all, over the files or connections
            opts = dc_replace(opts, duration_s=max(options.duration_s - used_s, 1e-3))
        split = False  # --split-every: this connection ends at the next period's start on the clock
        if live and options.split_every_s:
            from datetime import datetime

            now = datetime.now().astimezone()
            left = (next_boundary(now, options.split_every_s) - now).total_seconds()
            if opts.duration_s is None or left < opts.duration_s:
                opts, split = dc_replace(opts, duration_s=left), True
        summary, why = None, ""
        try:
            summary = run_one(console, video, sub, given, opts, calibration_mode=mode)
        except InputError as exc:
            text = str(exc)  # the part's label once: "notes.mp4: cannot be processed", not "notes.mp4: notes.mp4: ..."
            failures.append(f"{label}: {text.removeprefix(f'{video}: ')}")
            log_line(f"{label}: failed: {text}")
            rows.append([label, "–", "–", "–", "–", "", f"[red]failed[/]: {exc}"])
            records.append({"part": label, "folder": name, "status": "failed", "error": str(exc)})
            _write_parts(out_dir / "parts.csv", records)
            why = str(exc)
        if summary is not None:
            combined.add(name, summary.events, opts.start, options.live_clock)
            used_s += summary.position_s or 0.0
            for cal in summary.scaled:  # each view's scale, for when the camera shows that view again
                try:  # (a scale given with the view, as a carried calibration's: bbscale passes it on)
                    kept = cal if ", kept from " in cal.source or ", carried over from " in cal.source else \
                        dc_replace(cal, source=f"{cal.source}, kept from {label}")
                    save_view(kept, options.views_dir, options.orientation)
                except InputError as exc:
                    say(console, str(exc))
            if opts.start is not None and not live:
                dated.append((opts.start, summary.events, summary.watched_s))
            st = speed_stats([e.speed_kmh for e in summary.events if e.speed_kmh is not None])
            cal = summary.calibration
            if summary.has_scale:
                try:
                    carried = (load_calibration(sub / "calibration.json"), label)
                except InputError:
                    pass
            how = "" if cal is None else ("carried over" if "carried over" in cal.source else cal.state)
            split = split and summary.stopped == "duration"
            status = "split" if split else {"interrupted": "interrupted", "duration": "ok"}.get(
                summary.stopped, "ended" if live else "ok")
            rows.append([label, str(len(summary.events)), str(st.n), "–" if st.mean is None else f"{st.mean:.1f}",
                         "–" if st.v85 is None else f"{st.v85:.1f}", how, status])
            records.append({"part": label, "folder": name, "vehicles": len(summary.events), "measured": st.n,
                            "mean_kmh": None if st.mean is None else round(st.mean, 2),
                            "v85_kmh": None if st.v85 is None else round(st.v85, 2),
                            "calibration": "" if cal is None else cal.id, "status": status})
            _write_parts(out_dir / "parts.csv", records)
            if split:  # the next period's connection at once
                say(console, f"{name} ends here; the next period's connection starts", "bold", "--split-every")
                wait = 1.0
                continue
            if summary.stopped:
                interrupted = summary.stopped == "interrupted"
                if total:  # the files not reached are in the table and parts.csv, not silently left out
                    why_not = "interrupted" if interrupted else "--duration reached"
                    for _, later_name, later_label in list(parts)[k:]:
                        rows.append([later_label, "–", "–", "–", "–", "", f"[yellow]not run[/]: {why_not}"])
                        records.append({"part": later_label, "folder": later_name, "status": "not run",
                                        "error": why_not})
                    _write_parts(out_dir / "parts.csv", records)
                break
            why = "the stream ended"
            if (summary.position_s or 0.0) >= HEALTHY_S:
                wait = 1.0
        if not live:
            continue
        stderr_console().print(f"[yellow]{why}[/]: connecting again in {wait:g} s (Ctrl-C stops)", highlight=False,
                               soft_wrap=True)
        log_line(f"{name}: {why}: connecting again in {wait:g} s")
        if options.status is not None:
            from datetime import datetime, timedelta

            options.status.update(state="reconnecting", parts_done=k, error=why, next_attempt_at=(
                datetime.now().astimezone() + timedelta(seconds=wait)).isoformat(timespec="milliseconds"))
        try:
            time.sleep(wait)
        except KeyboardInterrupt:
            interrupted = True
            break
        wait = min(2 * wait, RECONNECT_MAX_WAIT)
    combined.close()
    if options.status is not None:
        options.status.update(parts_done=len(records))
    what = "connections" if live else f"of {total} files"
    table = Table(title=f"{len(rows)} {what} (speeds in km/h)")
    for col in ("connection" if live else "file", "vehicles", "measured", "mean", "V85", "calibration", "status"):
        table.add_column(col, justify="right" if col in ("vehicles", "measured", "mean", "V85") else "left",
                         overflow="fold", min_width=15 if col == "connection" else len(col))  # names wrap, not cut
    for row in rows:
        table.add_row(*row)
    console.print(table)
    if len(dated) > 1:
        _write_day_intervals(console, out_dir / "intervals.csv", dated, options)
    if interrupted:
        return "interrupted"
    return "" if live else "; ".join(failures)


class _AllVehicles:
    """``out_dir``/vehicles.jsonl and vehicles.csv: every part's vehicles in one table, each with its ``part``
    (folder), written after each part.  When the parts are dated (``--start-time auto``, a live clock) their
    timestamps are put on one clock — seconds since ``reference`` (the earliest file's start, or the first
    connection's) — as the day's intervals.csv counts them; otherwise each part's own."""

    def __init__(self, console, out_dir: Path, reference) -> None:
        from ..outputs import EventWriters

        self.console, self.reference, self.writers = console, reference, None
        from ..fileio import remove_earlier

        for name in ("vehicles.jsonl", "vehicles.csv"):
            remove_earlier(out_dir / name)  # a symlink stays: the table is written through it
        try:
            self.writers = EventWriters.open(out_dir / "vehicles.jsonl", out_dir / "vehicles.csv",
                                             extra_columns=("part",))
        except InputError as exc:
            say(console, f"{exc}: no table of every part's vehicles")

    def add(self, part: str, events: list, start, live_clock: bool) -> None:
        from ..outputs import stream_start

        if self.writers is None:
            return
        if start is None and live_clock:
            start = stream_start(events)
        if self.reference is None and start is not None and live_clock:
            self.reference = start
        shift = (start - self.reference).total_seconds() if start is not None and self.reference is not None else 0.0
        try:
            for e in _on_clock(events, shift, ndigits=3):
                self.writers.write(e, {"part": part})
        except InputError as exc:
            say(self.console, f"{exc}: the table of every part's vehicles is incomplete")

    def close(self) -> None:
        if self.writers is not None:
            try:
                self.writers.close()
            except InputError:
                pass


def _write_day_intervals(console, path: Path, dated: list, options: RunOptions) -> None:
    """One intervals.csv for the traffic of every dated part: each part's vehicles put on the clock of the earliest
    start, then counted per interval as one run's are; the stretches the files cover say how much of each interval
    was watched (a gap between recordings shows as less, an interval no file reaches has no row)."""
    from ..traffic_stats import interval_rows, write_intervals_csv

    first = min(start for start, _, _ in dated)
    events, covered = [], []
    for start, part, watched in dated:
        shift = (start - first).total_seconds()
        events += [e for e in _on_clock(part, shift)
                   if e.first_timestamp_s is not None and e.last_timestamp_s is not None]
        if watched:
            covered.append((shift, shift + watched))
    try:
        rows = interval_rows(events, 60 * options.interval_min, first, options.speed_limit,
                             covered=covered if len(covered) == len(dated) else None)
        write_intervals_csv(path, rows)
    except InputError as exc:
        say(console, str(exc))
        return
    console.print(f"[bold]Wrote[/] {path}: {len(events)} vehicles of {len(dated)} files in "
                  f"{len({r.start for r in rows})} intervals of {options.interval_min:g} min", highlight=False)


def _on_clock(events: list, shift: float, ndigits: int | None = None) -> list:
    """The vehicles of a part whose stream time 0 is ``shift`` seconds after the clock's: their timestamps moved by
    it (rounded to ``ndigits`` decimals if given); a vehicle without timestamps as it is."""
    return [e.moved(shift, ndigits) for e in events]


def _write_parts(path: Path, records: list[dict]) -> None:
    """parts.csv (PARTS_FIELDS, empty cell = unknown), atomically; a write error is said, not fatal (each part's
    own outputs are the record)."""
    import csv
    import io

    from ..fileio import atomic_write_text

    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=PARTS_FIELDS, lineterminator="\n")
    w.writeheader()
    for r in records:
        w.writerow({k: "" if r.get(k) is None else r[k] for k in PARTS_FIELDS})
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, buf.getvalue(), "parts table")
    except (InputError, OSError) as exc:
        import click

        click.echo(f"trafficcal: warning: {exc}", err=True)


def remove_a_refused_run(out_dir: Path, videos: list[Path], made: list[Path]) -> bool:
    """After a run of several ``videos`` into ``out_dir``, which it made (``made``: the folders it made, outermost
    first, as fileio.folder_made_for gives them), whose every file was refused before anything was made for it (no
    part's folder exists): remove what the run wrote there (status.json, the parts table, the empty vehicle tables)
    and the folders, so that it leaves nothing new, as a refused run of one file does.  False, with nothing removed,
    when a part's folder exists (a file that ran, however briefly)."""
    from ..fileio import remove_empty_folders

    if any((out_dir / name).exists() for name in _output_names(videos)):
        return False
    for name in ("status.json", "parts.csv", "vehicles.jsonl", "vehicles.csv", "intervals.csv", "run.log"):
        with contextlib.suppress(FileNotFoundError):
            (out_dir / name).unlink()
    remove_empty_folders([*made, out_dir / "views"])
    return True


def _output_names(videos: list[Path]) -> list[str]:
    """A folder name per file: its stem, numbered where two files share one."""
    stems = [v.stem or "video" for v in videos]
    return [s if stems.count(s) == 1 else f"{s}-{k}" for k, s in enumerate(stems, 1)]
