"""``trafficcal eval``: score a results file and/or a calibration against BrnoCompSpeed ground truth."""

from __future__ import annotations

import json
from pathlib import Path

import click

from ..errors import GeometryError, InputError


def parse_image_size(value: str) -> tuple[int, int]:
    """'1920x1080' -> (1920, 1080), InputError otherwise."""
    try:
        w, h = (int(v) for v in value.lower().split("x"))
    except ValueError:
        raise InputError(f"--image-size must look like 1920x1080, got {value!r}") from None
    if w <= 0 or h <= 0:
        raise InputError(f"--image-size must be positive, got {value!r}")
    return w, h


def frame_size(given: tuple[int, int] | None, results, cal, cal_path: Path | None) -> tuple[tuple[int, int], str]:
    """(frame size, where it came from): --image-size (``given``), else the results file's image_size (ours write
    it), else the --calibration's (``cal``), else BrnoCompSpeed's 1920x1080 (its ground truth holds no size)."""
    if given is not None:
        return given, "--image-size"
    if results is not None and results.image_size is not None:
        return results.image_size, f"{results.source}'s image_size"
    if cal is not None:
        return tuple(cal.image_size), f"{cal_path}'s image_size"
    return (1920, 1080), "BrnoCompSpeed's, assumed: --image-size for another"


def _camera(results, results_path: Path | None, calibration_path: Path | None, cal, size: tuple[int, int],
            size_from: str):
    """The camera to evaluate: --calibration's (``cal``, for frames of ``size``) if given, else the results file's
    camera_calibration."""
    from ..geometry import Camera

    if cal is not None:
        if cal.camera is None:
            raise InputError(f"{calibration_path}: calibration has no vanishing points yet (state {cal.state!r})")
        if tuple(cal.image_size) != tuple(size):  # another camera's, or a scaled-down copy: meaningless errors
            raise InputError(f"{calibration_path}: calibration is for {cal.image_size[0]}x{cal.image_size[1]} frames, "
                             f"the recording's are {size[0]}x{size[1]} ({size_from})")
        return cal.camera
    if results is None or results.calibration is None:
        raise InputError(f"{results_path}: has no camera_calibration block; pass --calibration")
    c = results.calibration
    try:
        return Camera.from_brno(c.vp1, c.vp2, c.pp, c.scale)
    except GeometryError as exc:
        raise GeometryError(f"{results_path}: camera_calibration: {exc}") from None


def _table(title: str, rows: list[tuple[str, object]]):
    from rich.markup import escape
    from rich.table import Table

    table = Table(title=f"{title} errors", title_justify="left")
    for col in ("metric", "n", "mean", "median", "p95", "p99", "max"):
        table.add_column(col, justify="left" if col == "metric" else "right")
    for label, stats in rows:
        if stats is None:
            continue
        cells = [f"{v:.4g}" if v == v else "-" for v in (stats.mean, stats.median, stats.p95, stats.p99, stats.max)]
        table.add_row(escape(label), str(stats.n), *cells)
    return table


def print_report(ev, console, mode: str = "median") -> None:
    """Human-readable tables of an Evaluation."""
    c = ev.calibration
    if c is not None:
        console.print(f"focal length: {c.focal:.1f} px")
        console.print(_table("Calibration", [
            ("distance ratio", c.ratio_abs), ("distance ratio [%]", c.ratio_rel_pct),
            ("distance, all [m]", c.dist_all_abs_m), ("distance, all [%]", c.dist_all_rel_pct),
            ("distance, to VP1 [m]", c.dist_vp1_abs_m), ("distance, to VP1 [%]", c.dist_vp1_rel_pct),
        ]))
    s = ev.speed
    if s is not None:
        console.print(_table(f"Speed ({mode} mode, matched valid cars)", [
            ("speed [km/h]", s.abs_kmh), ("speed [%]", s.rel_pct)]))
        console.print(f"recall: {s.recall:.4f}   false positives: {s.false_positives}   "
                      f"matched: {s.matched} ({s.matched_valid} valid of {s.n_gt_valid})   "
                      f"cars: {s.n_cars} -> {s.n_cars_after_prefilter} after prefilter, "
                      f"{s.n_intersection_errors} intersection errors")


@click.command(help="Score a BrnoCompSpeed results file and/or a calibration against ground truth "
                    "(the dataset's official metrics: distance-ratio error, distance errors, speed errors in "
                    "median mode, recall, false positives).")
@click.option("--gt", "gt_path", required=True, type=click.Path(path_type=Path),
              help="Ground truth gt_data.pkl of the recording.")
@click.option("--results", "results_path", type=click.Path(path_type=Path),
              help="System results JSON (BrnoCompSpeed format: camera_calibration + cars).")
@click.option("--calibration", "calibration_path", type=click.Path(path_type=Path),
              help="Calibration JSON (ours, or any JSON with a camera_calibration block); overrides the "
                   "results file's calibration.")
@click.option("--json", "json_path", type=click.Path(path_type=Path), help="Write all metrics to this JSON file.")
@click.option("--plot", "plot_path", type=click.Path(path_type=Path),
              help="Write a PNG cumulative histogram of absolute speed errors.")
@click.option("--mode", type=click.Choice(["median", "full"]), default="median", show_default=True,
              help="Speed measurement mode of the official evaluation.")
@click.option("--image-size", default=None,
              help="Frame size WxH of the recording (for the 10 px border filter). Default: the results file's "
                   "image_size (trafficcal run writes it), else the --calibration's, else 1920x1080 (BrnoCompSpeed).")
def command(gt_path: Path, results_path: Path | None, calibration_path: Path | None, json_path: Path | None,
            plot_path: Path | None, mode: str, image_size: str) -> None:
    import numpy as np
    from rich.console import Console

    from ..brnocompspeed import load_gt_data, load_results
    from ..calibration import load_calibration
    from ..evaluation import evaluate, plot_cumulative_errors, plot_format, prepare_tracks
    from ..manual_calibration import size_doubt

    if results_path is None and calibration_path is None:
        raise click.UsageError("give --results and/or --calibration")
    given = parse_image_size(image_size) if image_size is not None else None  # a bad one: one line before reading
    if plot_path is not None:
        plot_format(plot_path)  # a folder or no image format: one line now, not after the tables
    gt = load_gt_data(gt_path)
    results = load_results(results_path, cars_required=True) if results_path is not None else None
    cal = load_calibration(calibration_path) if calibration_path is not None else None
    size, size_from = frame_size(given, results, cal, calibration_path)
    camera = _camera(results, results_path, calibration_path, cal, size, size_from)
    doubt = size_doubt(np.concatenate([gt.distances_p1, gt.distances_p2]), size)
    if doubt and doubt.outside:  # the ground truth of another recording, or results of a scaled copy: meaningless
        raise InputError(f"{gt_path}: {doubt.text} ({size_from}): the ground truth and what is scored are of "
                         "different frame sizes")
    if doubt:
        Console(stderr=True).print(f"[yellow]warning[/]: {gt_path}: {doubt.text} ({size_from}): is the recording "
                                   "smaller? (--image-size)", highlight=False)
    prepared = None
    if results is not None:
        if camera.scale is None:
            raise InputError(f"{calibration_path or results_path}: calibration has no scale, speeds cannot be "
                             "measured")
        prepared = prepare_tracks(results, gt, *size)
    ev = evaluate(gt, camera, mode=mode, prepared=prepared)
    print_report(ev, Console(), mode)
    if json_path is not None:
        doc = {"gt": str(gt_path), "results": None if results_path is None else str(results_path),
               "calibration_file": None if calibration_path is None else str(calibration_path),
               "mode": mode, **ev.to_dict()}
        try:
            json_path.parent.mkdir(parents=True, exist_ok=True)
            json_path.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
        except OSError as exc:
            raise InputError(f"{json_path}: cannot write ({exc.strerror or exc})") from None
    if plot_path is not None:
        if ev.speed is None:
            raise InputError("--plot needs --results (it plots speed errors)")
        label = results_path.parent.name if results_path is not None else "system"
        plot_cumulative_errors({label: ev.speed.errors_abs_kmh}, plot_path)
