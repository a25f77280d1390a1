"""``trafficcal demo``: the main job end to end on a built-in synthetic scene, with the error against the truth.

1. renders a short scene with exact ground truth (``trafficcal synth``, preset ``highway_day`` by default);
2. measures every vehicle through the real GStreamer elements, in-process with the same runner and pipeline as
   ``trafficcal run`` (``filesrc ! decodebin ! videoconvert ! vpdetect ! vehicledetect model=vehicleseg ! tracker
   ! bbscale ! speedometer ! trafficoverlay ! x264enc ! mp4mux``; ``--detector`` as ``trafficcal run``'s). By
   default (``--calibration auto``) fully automatically, as on a user's camera: vpdetect learns the vanishing points
   and bbscale the scale from the video in the same pass, and the vehicles that left before are measured again
   with the final calibration. ``--calibration manual`` gives vpdetect the paper's manual baseline instead
   (ManualCalib + ManualScale from the scene's road markings), so the speed errors are those of detection,
   tracking and measurement alone; the automatic vanishing points are then found in a separate pass and reported;
3. reports the calibration against the truth (and the other calibration for comparison), and scores the speeds
   with the BrnoCompSpeed evaluator; writes ``report.html``.
"""

from __future__ import annotations

import time
from collections import Counter
from pathlib import Path

import click

from .run import check_detector, detector_option


@click.command(name="demo")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=Path("out/demo"),
              show_default=True, help="Folder for everything the demo writes.")
@click.option("--preset", default="highway_day", show_default=True,
              help="Synthetic scene to render (see `trafficcal synth --list-presets`).")
@click.option("--duration", type=float, default=60.0, show_default=True, help="Seconds of video to render.")
@click.option("--seed", type=int, default=7, show_default=True, help="Random seed of the scene.")
@click.option("--calibration", "calibration_mode", type=click.Choice(["auto", "manual"]), default="auto",
              show_default=True,
              help="auto: fully automatic, as on your cameras (vpdetect's vanishing points and bbscale's scale, learnt "
                   "from the video in the same pass). manual: the paper's manual baseline from the scene's road "
                   "markings for the speeds, so their errors are those of detection, tracking and measurement alone.")
@detector_option("")
def command(out_dir: Path, preset: str, duration: float, seed: int, calibration_mode: str, detector: str) -> None:
    """Render a built-in synthetic traffic scene, calibrate, measure speeds, and compare with the truth.

    Leaves in --out: scene/ (video.mp4 and its exact ground truth), calibration.json (the one the speeds were
    measured with), calibration_manual.json or calibration_auto.json (the other, for comparison), vehicles.jsonl,
    vehicles.csv, system.json (BrnoCompSpeed results), evaluation.json, speed_errors.png, overlay.mp4 and
    report.html.
    """
    import numpy as np
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeRemainingColumn
    from rich.table import Table

    from ..brnocompspeed import load_gt_data, load_results
    from ..calibration import Calibration, save_calibration
    from ..evaluation import evaluate, evaluate_calibration, plot_cumulative_errors, prepare_tracks
    from ..gst.env import elements_dir
    from ..manual_calibration import calibrate_manual
    from ..report import ReportInputs, write_report
    from ..synth import scenario as sc
    from ..synth.generate import generate
    from ..synth.truth_match import match_measured
    from ..vanishing.calibrator import CalibratorConfig, calibrate_video
    from .run import (RunPaths, first_frame, lane_paths, measure_video, pipeline_description, print_not_counted,
                      print_remeasured)
    from .terminal import stderr_console

    console = Console()
    check_detector(detector)  # before the render
    out_dir.mkdir(parents=True, exist_ok=True)
    scene_dir = out_dir / "scene"

    # 1. the scene --------------------------------------------------------------------------------------------
    scen = sc.load_preset(preset)
    scen.duration, scen.seed = duration, seed
    scen.validate(preset)
    t0 = time.monotonic()
    with Progress("[progress.description]{task.description}", BarColumn(), MofNCompleteColumn(),
                  TimeRemainingColumn(), console=stderr_console()) as bar:  # progress: stderr
        task = bar.add_task(f"rendering {preset}", total=None)
        scene = generate(scen, scene_dir, progress=lambda i, n: bar.update(task, completed=i, total=n))
    truth = scene.calibration
    W, H = truth.image_size
    console.print(f"[bold]Scene[/] {preset}: {W}x{H}, {duration:g} s, {scene.frames} frames, {scene.vehicles} "
                  f"vehicles crossing the measurement lines (rendered in {time.monotonic() - t0:.0f} s) -> {scene_dir}")

    # 2. calibration and measurement through the GStreamer elements -------------------------------------------
    gt = load_gt_data(scene_dir / "gt_data.pkl")
    true_cam = truth.camera
    manual = Calibration(calibrate_manual(gt, image_size=(W, H)).camera, (W, H), source="manual-calibration")
    paths = RunPaths(out_dir)
    video = scene_dir / "video.mp4"
    bbscale = (elements_dir() / "python" / "bbscale.py").exists()
    if calibration_mode == "manual":
        with stderr_console().status("automatic calibration (vpdetect: VP1 from vehicle tracks, VP2 from edgelets)"):
            auto = calibrate_video(video, CalibratorConfig(), stop_when_done=True).calibration
        save_calibration(auto, out_dir / "calibration_auto.json")
        print_automatic_vps(console, auto, gt, true_cam, "-> calibration_auto.json")
        cal_path = save_calibration(manual, out_dir / "calibration.json")
        cam = manual.camera
        console.print(f"[bold]Calibration used for speeds[/] (ManualCalib + ManualScale from the scene's road "
                      f"markings, the paper's baseline; bbscale passes a calibration with scale through unchanged): "
                      f"f = {cam.focal:.0f} px (true {true_cam.focal:.0f}), scale = {cam.scale:.3f} m (true "
                      f"{true_cam.scale:.3f}) -> calibration.json")
        keep: tuple[Path, ...] = (cal_path,)
    else:
        cal_path, keep = None, ()
    pipeline = pipeline_description(video, paths, calibration=cal_path, detector=detector, bbscale=bbscale)
    console.print("[bold]Measuring[/] gst-launch-1.0 " + pipeline.replace(str(out_dir) + "/", ""), highlight=False,
                  soft_wrap=True)
    t0 = time.monotonic()
    measured = measure_video(video, out_dir, pipeline, console, label="running the pipeline", keep=keep)
    elapsed = time.monotonic() - t0
    console.print(f"  {scene.frames} frames in {elapsed:.1f} s ({scene.frames / elapsed:.1f} fps incl. overlay "
                  f"encoding)")
    if calibration_mode == "manual":
        calibration = manual
    else:
        calibration = measured.calibration
        print_automatic(console, calibration, gt, true_cam)
        save_calibration(manual, out_dir / "calibration_manual.json")
        m = manual.camera
        console.print(f"  for comparison, the paper's manual baseline from the scene's road markings: f = "
                      f"{m.focal:.0f} px, scale = {m.scale:.3f} m ({100 * (m.scale / true_cam.scale - 1):+.1f} %), "
                      f"distance-ratio error {evaluate_calibration(gt, m).ratio_abs.mean:.3f} mean "
                      "-> calibration_manual.json (trafficcal demo --calibration manual measures with it)",
                      highlight=False)
        print_remeasured(console, measured.remeasured, indent="  ", speeds=measured.remeasured_speeds)
    print_not_counted(console, measured.not_counted, indent="  ")

    # 4. evaluation -------------------------------------------------------------------------------------------
    events = measured.events
    results = load_results(paths.results)
    ev = None
    if calibration is not None and calibration.camera is not None and calibration.camera.scale is not None:
        ev = evaluate(gt, calibration.camera, prepared=prepare_tracks(results, gt, width=W, height=H))
        (out_dir / "evaluation.json").write_text(__import__("json").dumps(ev.to_dict(per_item=False), indent=2))
    errors = ev.speed.errors_abs_kmh if ev is not None and ev.speed is not None else np.empty(0)
    if errors.size:
        plot_cumulative_errors({"demo": errors}, out_dir / "speed_errors.png")

    if any(e.measured for e in events):
        table = Table(title="Vehicles (first 15; ± U holds the true speed for about 95 % of vehicles)")
        for col in ("id", "label", "direction", "lane", "speed km/h", "± km/h", "note"):
            table.add_column(col)
        for e in events[:15]:
            u = getattr(e, "speed_uncertainty_kmh", None)
            table.add_row(str(e.id), e.label, str(e.direction or ""), "" if e.lane is None else str(e.lane),
                          "" if e.speed_kmh is None else f"{e.speed_kmh:.1f}", "" if u is None else f"{u:.1f}",
                          e.reason or "")
        console.print(table)
    else:  # nothing measured: one line per reason, not the same note fifteen times
        for reason, n in Counter(e.reason for e in events).most_common():
            console.print(f"  {n} vehicles tracked, not measured: {reason}", highlight=False)
    summary = Table(title="Against the ground truth (BrnoCompSpeed metrics)")
    summary.add_column("metric")
    summary.add_column("value", justify="right")
    if ev is not None:
        cr = ev.calibration
        summary.add_row("distance-ratio error (mean / median)",
                        f"{cr.ratio_abs.mean:.3f} / {cr.ratio_abs.median:.3f}")
    if ev is not None and ev.speed is not None:
        if ev.speed.abs_kmh.n:
            s = ev.speed.abs_kmh
            summary.add_row("speed error km/h (mean / median / 95 %)",
                            f"{s.mean:.2f} / {s.median:.2f} / {s.p95:.2f}")
        summary.add_row("recall", f"{ev.speed.recall:.3f}")
        summary.add_row("false positives", str(ev.speed.false_positives))
        summary.add_row("matched vehicles", str(ev.speed.matched))
    # the render's per-frame truth also names each vehicle's class: the labels the speedometer gave by size
    matches = match_measured(scene_dir / "frames.jsonl", events, results, (W, H))
    if matches:
        wrong = Counter(f"{m.rendered_class} as {m.label}" for m in matches if m.label != m.rendered_class)
        summary.add_row("vehicle classes right (against the render)",
                        f"{sum(m.label == m.rendered_class for m in matches)} / {len(matches)}"
                        + (f" ({', '.join(f'{n} {k}' for k, n in wrong.most_common())})" if wrong else ""))
    if summary.row_count:
        console.print(summary)

    write_report(out_dir / "report.html", ReportInputs(
        events=events, calibration=calibration, frame=first_frame(video), evaluation=ev,
        ground_truth_name=str(scene_dir / "gt_data.pkl"), title=f"gst-trafficcal demo: {preset}",
        source=str(video), covered=[(0.0, measured.watched_s)] if measured.watched_s else None,
        remeasured=(measured.remeasured, measured.remeasured_speeds), not_counted=measured.not_counted,
        paths=lane_paths(out_dir / "system.json", events)))
    wrote = ["overlay.mp4", "report.html", "vehicles.jsonl", "vehicles.csv", "system.json"]
    wrote += ["evaluation.json"] if ev is not None else []
    wrote += ["speed_errors.png"] if errors.size else []
    console.print(f"[bold]Wrote[/] {out_dir}: {', '.join(wrote)}")


def print_automatic_vps(console, auto, gt, true_cam, where: str) -> None:
    """vpdetect's vanishing points against the truth: the focal length, the distance-ratio error and how firmly
    the view pins the speeds down (or why they were not found)."""
    from ..evaluation import evaluate_calibration
    from .calibrate import print_conditioning

    if auto is None or auto.camera is None:
        console.print(f"[bold]Automatic VPs[/] (vpdetect): not converged: {auto.reason if auto else 'no calibration'}")
        return
    ratio = evaluate_calibration(gt, auto.camera).ratio_abs
    console.print(f"[bold]Automatic VPs[/] (vpdetect): f = {auto.camera.focal:.0f} px (true {true_cam.focal:.0f}), "
                  f"distance-ratio error {ratio.mean:.3f} mean / {ratio.median:.3f} median {where}")
    print_conditioning(console, auto)


def print_automatic(console, calibration, gt, true_cam) -> None:
    """The fully automatic calibration the run ended with, against the truth: vpdetect's vanishing points and
    bbscale's scale (or why there is none, and so no speeds)."""
    from .terminal import say

    print_automatic_vps(console, calibration, gt, true_cam, "-> calibration.json")
    cam = calibration.camera if calibration is not None else None
    if cam is not None and cam.scale is not None:
        console.print(f"[bold]Automatic scale[/] (bbscale): {cam.scale:.3f} m (true {true_cam.scale:.3f}, "
                      f"{100 * (cam.scale / true_cam.scale - 1):+.1f} %)", highlight=False)
    else:
        why = calibration.reason if calibration is not None and calibration.reason else "not converged"
        say(console, f"no speeds: the automatic calibration has no scale after this video ({why}); a longer "
                     "--duration gives it more vehicles, or --calibration manual measures with the scene's road "
                     "markings")
