"""``trafficcal fit-scale --train DIR... -o FILE``: fit the scale-correcting regression λ_reg = αλ* + β.

Each training directory is a ``trafficcal synth`` output folder (``video.mp4`` + ``calibration.json``).  BBScale
runs on its video with the calibration's vanishing points (λ*), against the true scale: the calibration's own
scale — for a synthetic scene and for a BrnoCompSpeed replay alike (a replay is rendered with the camera of the
recording's ManualCalib+ManualScale calibration, so its scale is the ManualScale of the recording); a replay
folder whose calibration.json has no scale falls back to the ManualScale of ``gt_data.pkl``'s measured
distances towards VP1 with the calibration's VPs.  ``--orientation`` turns the videos as ``trafficcal run``'s
does (recordings of a camera mounted turned: stored sideways, untagged); without it each folder's calibration.json
says how its frames were turned (its field ``orientation``), as for ``trafficcal run --calibration``.
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from .run import check_detector, detector_option, given_orientation, orientation_option


def true_scale(folder: Path, calibration) -> tuple[float, str]:
    """(true λ, where it comes from) for a training folder."""
    from ..errors import InputError

    scen = folder / "scenario.json"
    replay = False
    if scen.is_file():
        try:
            replay = bool(json.loads(scen.read_text(encoding="utf-8")).get("replay"))
        except (json.JSONDecodeError, UnicodeDecodeError, AttributeError):
            raise InputError(f"{scen}: not valid JSON") from None
    if calibration.camera is not None and calibration.camera.scale is not None:
        return float(calibration.camera.scale), "replay camera" if replay else "synth"
    if replay and (folder / "gt_data.pkl").is_file():
        from ..brnocompspeed import load_gt_data
        from ..manual_calibration import manual_scale

        gt = load_gt_data(folder / "gt_data.pkl")
        sel = gt.distances_to_vp1
        if sel.any():
            return manual_scale(calibration.camera, gt.distances_p1[sel], gt.distances_p2[sel],
                                gt.distances_m[sel]), "ManualScale"
    raise InputError(f"{folder}: calibration.json has no scale and there is no replay ground truth")


@click.command(help="Fit the scale-correction regression λ_reg = α·λ* + β (paper §4.3) on training scenes "
                    "(trafficcal synth output folders; BrnoCompSpeed replays use ManualScale as ground truth) "
                    "and write it as JSON for bbscale's regression-file property.")
@click.option("--train", "train", multiple=True, required=True, type=click.Path(path_type=Path),
              help="Training folder (video.mp4 + calibration.json); repeat, or give a folder of folders.")
@click.option("-o", "--output", "out_path", required=True, type=click.Path(path_type=Path),
              help="Regression JSON to write.")
@click.option("--models", default="", help="Vehicle types (as bbscale's models property).")
@click.option("--iou-threshold", default=0.85, show_default=True, help="Minimum IoU of a match.")
@click.option("--min-vehicles", default=3, show_default=True, help="Agreeing vehicles needed per scene.")
@click.option("--max-duration", default=None, type=click.FloatRange(min=0, min_open=True),
              help="Seconds of each video to use [default: all].")
@detector_option(" for the scale chain (fit with the detector `trafficcal run` will use)")
@click.option("--form", type=click.Choice(["ratio", "affine"]), default="ratio", show_default=True,
              help="ratio: λ_reg = α·λ* (β = 0; predicted held-out scenes better on every set measured); "
                   "affine: least-squares α and β, the paper's form (needs scenes of clearly different λ).")
@orientation_option(" (every training video's; not given: the one each folder's calibration.json keeps, as "
                    "trafficcal run --calibration takes it, else auto) — recordings of a camera mounted turned")
def command(train: tuple[Path, ...], out_path: Path, models: str, iou_threshold: float, min_vehicles: int,
            max_duration: float | None, detector: str, form: str, orientation: str | None = None) -> None:
    from rich.console import Console
    from rich.table import Table

    from ..calibration import load_calibration
    from ..errors import InputError
    from ..imaging import check_orientation
    from ..scale.regression import fit_regression, save_regression
    from ..scale.streaming import load_align_models
    from ..scale.video import scale_from_video

    if orientation is not None:
        check_orientation(orientation)  # a bad one: one line, before any work
    folders: list[Path] = []
    for d in train:
        if d.exists() and not d.is_dir():
            raise InputError(f"{d}: a file, not a training folder (a folder with video.mp4 and calibration.json, "
                             "or a folder of such folders)")
        if not d.is_dir():
            raise InputError(f"training folder {d} not found")
        if (d / "calibration.json").is_file():
            folders.append(d)
        else:
            sub = sorted(p for p in d.iterdir() if (p / "calibration.json").is_file())
            if not sub:
                raise InputError(f"{d}: no calibration.json in it or in its subfolders (a trafficcal synth output?)")
            folders.extend(sub)
    unique = list({f.resolve(): f for f in reversed(folders)}.values())[::-1]  # a scene given twice counts once
    console = Console(stderr=True)
    if len(unique) < len(folders):
        console.print(f"[yellow]warning[/]: {len(folders) - len(unique)} training folder(s) given more than once "
                      "(the same scene, by another path): each scene is fitted once", highlight=False)
    folders = unique
    align_models = load_align_models(models)
    model = check_detector(detector)
    from ..fileio import writable_file

    writable_file(out_path, "regression file (-o)")  # a wrong path: one line now, not after the whole fit
    table = Table("scene", "truth", "true λ", "λ*", "error %", "status")
    names, raw, true = [], [], []
    for k, f in enumerate(folders, 1):
        console.print(f"[{k}/{len(folders)}] {f.name}: measuring its scale", highlight=False)
        cal = load_calibration(f / "calibration.json")
        lam_true, source = true_scale(f, cal)
        # its frames turned as the calibration's were: a camera mounted turned stores them sideways, untagged
        turned, _ = given_orientation(orientation, f / "calibration.json")
        res = scale_from_video(f / "video.mp4", cal.with_scale(None), models=align_models,
                               iou_threshold=iou_threshold, min_vehicles=min_vehicles, max_duration=max_duration,
                               detector=model, orientation=turned)
        r = res.result
        lam = r.raw_scale if r.converged else None
        names.append(f.name)
        raw.append(float("nan") if lam is None else lam)
        true.append(lam_true)
        err = "" if lam is None else f"{100 * (lam / lam_true - 1):+.2f}"
        table.add_row(f.name, source, f"{lam_true:.3f}", "" if lam is None else f"{lam:.3f}", err, r.status)
    console.print(table)
    reg = fit_regression(raw, true, names, form=form)
    save_regression(reg, out_path)
    click.echo(f"λ_reg = {reg.alpha:.5f} · λ* {reg.beta:+.5f}  ({len(reg.scenes)} of {len(folders)} scenes) "
               f"-> {out_path}")
