"""``trafficcal calibrate VIDEO -o CALIB_JSON``: fully automatic VP1/VP2 calibration of a traffic video."""

from __future__ import annotations

from pathlib import Path

import click

from .run import check_detector, detector_option, orientation_option


def parse_focal_range(text: str | None) -> tuple[float, float] | None:
    """"MIN,MAX" in pixels (None/empty: the calibrator's default)."""
    from ..errors import InputError

    if not text:
        return None
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"focal range must be MIN,MAX in pixels, got {text!r}") from None
    if not 0 < lo < hi:
        raise InputError(f"focal range must satisfy 0 < MIN < MAX, got {text!r}")
    return lo, hi


@click.command(help="Fully automatic calibration (paper §4.1): VP1 from tracked vehicle motion, VP2 from "
                    "edgelets, both through a Diamond Space. Writes our calibration JSON (state 'vps': no "
                    "scale) and a PNG of a frame with the grid towards VP1/VP2 and the horizon. Exit code 1 "
                    "when it cannot converge (the JSON then has state 'failed' and the reason). With --scale, "
                    "BBScale (paper §4.3) then runs on the same video with these VPs and adds the scene scale λ "
                    "(state 'calibrated', confidence 'scale') or, when it cannot, keeps state 'vps' with the "
                    "reason. A calibration with a scale also holds the road-plane homography (image pixels to "
                    "metres) and four road points with their metres, for OpenCV or supervision "
                    "(docs/outputs.md).")
@click.argument("video", type=click.Path(path_type=Path))
@click.option("-o", "--output", "out_path", required=True, type=click.Path(path_type=Path),
              help="Calibration JSON to write.")
@click.option("--png", "png_path", type=click.Path(path_type=Path), default=None,
              help="Grid image to write [default: the output path with .png].")
@click.option("--method", type=click.Choice(["edgelets", "gradient"]), default="edgelets", show_default=True,
              help="VP2 evidence: edgelets (the paper) or gradient orientations (ITS15 baseline).")
@click.option("--min-duration", default=20.0, show_default=True, help="Seconds of video before declaring.")
@click.option("--max-duration", default=180.0, show_default=True, help="Give up after this many seconds.")
@click.option("--focal-range", default="", help="MIN,MAX focal length in pixels [default: 0.3..6 x width].")
@click.option("--horizon-max", default=30.0, show_default=True,
              help="Degrees: VP2 only where the horizon VP1-VP2 is this close to horizontal (90: no limit).")
@click.option("--constant-speed/--no-constant-speed", default=True, show_default=True,
              help="Move VP1 along the lanes to where the tracked points' perspective acceleration puts it "
                   "(vehicles keep their speed for a second or two); off where traffic keeps braking.")
@click.option("--whole/--stop-early", default=False, show_default=True,
              help="Read the whole video even after convergence.")
@click.option("--progress/--no-progress", default=True, show_default=True, help="Show a progress bar.")
@click.option("--scale/--no-scale", "with_scale", default=False, show_default=True,
              help="After the VPs, estimate the scale λ by BBScale on the same video.")
@click.option("--scale-models", default="", help="BBScale vehicle types (as bbscale's models property) "
              "[default: the catalogue's passenger cars].")
@click.option("--iou-threshold", default=0.85, show_default=True, help="BBScale: minimum IoU of a match.")
@click.option("--min-vehicles", default=5, show_default=True, help="BBScale: agreeing vehicles needed.")
@click.option("--regression-file", default=None, type=click.Path(path_type=Path),
              help="BBScale: scale-correction regression from trafficcal fit-scale.")
@detector_option(" for BBScale")
@click.option("--zone", default="", metavar="'x,y x,y x,y ...'",
              help="Learn only from the traffic inside this polygon of the frame (pixels, or fractions 0..1 of its "
                   "width and height; several: separated by ';'), e.g. the measured road without a side road or a "
                   "parking lot; as trafficcal run --zone. Kept in the calibration file, so that trafficcal run "
                   "--calibration measures in it too. Default: the whole frame.")
@orientation_option(" (the same as trafficcal run's, so that the calibration fits its frames; kept in the "
                    "calibration file, which trafficcal run --calibration then turns the picture by)")
def command(video: Path, out_path: Path, png_path: Path | None, method: str, min_duration: float,
            max_duration: float, focal_range: str, horizon_max: float, whole: bool, progress: bool,
            with_scale: bool, scale_models: str, iou_threshold: float, min_vehicles: int,
            regression_file: Path | None, detector: str, constant_speed: bool = True, zone: str = "",
            orientation: str | None = None) -> None:
    import cv2
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from ..calibration import save_calibration
    from ..drawing import ZONE_BGR, draw_calibration, draw_segments, zone_segments
    from ..errors import InputError
    from ..imaging import check_orientation
    from ..vanishing.calibrator import CalibratorConfig, calibrate_video
    from ..zone import parse_zone

    if min_duration < 0 or max_duration <= 0:
        raise InputError("durations must be positive")
    orientation = check_orientation(orientation)  # a bad one: one line, before any work
    where = parse_zone(zone, "--zone")
    if with_scale:  # bad scale inputs are one-line errors now, not after the vanishing points were found
        from ..scale.regression import load_regression
        from ..scale.streaming import load_align_models

        align_models = load_align_models(scale_models)
        regression = load_regression(regression_file) if regression_file is not None else None
        model = check_detector(detector)
    cfg = CalibratorConfig(method=method, min_duration=min_duration, max_duration=max_duration,
                           focal_range=parse_focal_range(focal_range), horizon_max_deg=horizon_max,
                           vp1_constant_speed=constant_speed, zone=where)
    from ..fileio import atomic_write_image, open_video, writable_file, writable_image
    from ..imaging import capture_par, opencv_picture

    cap = open_video(video)  # a missing or unreadable video: its one line before anything is created
    # the frames as calibrated: of square pixels (vanishing.frames), as trafficcal run and the scripts analyse them
    # turned as the file or --orientation says (a quarter turn swaps the sides, and a non-square pixel's aspect)
    size = opencv_picture(video, orientation).size(
        (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))), capture_par(cap))
    cap.release()
    wrong = where.check(size) if where is not None and min(size) > 0 else None
    if wrong:
        raise InputError(f"{video}: the --{wrong}")
    # now (after the inputs were checked), not after the whole video
    writable_file(out_path, "calibration file (-o)")
    writable_image(png_path or out_path.with_suffix(".png"), "grid picture")  # a format OpenCV writes, too
    console = Console(stderr=True)
    doubt = where.doubt(size) if where is not None and min(size) > 0 else None
    if doubt:  # a zone in pixels of another resolution, perhaps: said before the long pass, as trafficcal run does
        console.print(f"[yellow]warning[/]: --zone: {doubt}", highlight=False)
    with Progress(TextColumn("[bold]calibrate"), BarColumn(), TextColumn("{task.completed}/{task.total} frames"),
                  TextColumn("{task.fields[info]}"), TimeElapsedColumn(), console=console,
                  disable=not progress) as bar:
        task = bar.add_task("calibrate", total=None, info="")

        def update(i: int, total: int, status) -> None:
            if i % 10 == 0 or status.state != "learning":
                info = f"{status.time:6.1f} s  {status.tracks} tracks  {status.edgelets} edgelets  {status.state}"
                bar.update(task, completed=i, total=total or None, info=info)

        result = calibrate_video(video, cfg, progress=update, stop_when_done=not whole, orientation=orientation)
    cal = result.calibration
    out = Console()
    if with_scale and cal.camera is not None:
        cal = _add_scale(video, cal, align_models, iou_threshold, min_vehicles, regression, out, model, where,
                         orientation)
    # trafficcal run --calibration keeps to the same road, turned the same way
    save_calibration(cal, out_path, zone=where, orientation=orientation)
    fps = result.frames_read / max(result.seconds_processing, 1e-9)
    if cal.camera is None:
        out.print(f"{video}: not calibrated after {result.calibrator.t:.1f} s of video: {cal.reason} -> {out_path}",
                  markup=False)
        raise SystemExit(1)
    png = png_path or out_path.with_suffix(".png")
    if result.frame is not None:
        image = result.frame.copy() if result.frame.ndim == 3 else cv2.cvtColor(result.frame, cv2.COLOR_GRAY2BGR)
        draw_calibration(image, cal.camera, thickness=1 if image.shape[1] < 1280 else 2)
        if where is not None:
            draw_segments(image, zone_segments(where.pixels(image.shape[1::-1]), image.shape[1::-1]), ZONE_BGR,
                          2 if image.shape[1] < 1280 else 3)
        atomic_write_image(png, image, "grid picture")  # whole or not at all (a full disk, a crash)
    c = cal.camera
    out.print(f"VP1 ({c.vp1[0]:.1f}, {c.vp1[1]:.1f})  VP2 ({c.vp2[0]:.1f}, {c.vp2[1]:.1f})  f {c.focal:.1f} px  "
              f"after {cal.confidence.get('seconds', 0):.1f} s of video ({result.frames_read} frames, "
              f"{fps:.0f} fps analysis)  confidence vp1 {cal.confidence.get('vp1', 0):.2f} "
              f"vp2 {cal.confidence.get('vp2', 0):.2f} -> {out_path}, {png}", markup=False)
    print_conditioning(out, cal)
    if "vp1_along_px" in cal.confidence:
        out.print(f"VP1 moved {cal.confidence['vp1_along_px']:+.1f} px along the lanes (away from the traffic: +) by "
                  f"the constant-speed motion of {cal.confidence.get('speed_tracks', 0):.0f} tracks"
                  + (f", then {cal.confidence['vp1_across_px']:+.1f} px across them to where the tracks' lines meet"
                     if "vp1_across_px" in cal.confidence else ""), markup=False)
    elif "vp1_along_refused_px" in cal.confidence:
        out.print(f"VP1 left where the tracks' lines meet: their speeds would move it "
                  f"{cal.confidence['vp1_along_refused_px']:+.1f} px along the lanes, too far for traffic at constant "
                  f"speed (braking or pulling away, e.g. before a junction?)", markup=False)


def print_conditioning(console, cal, warned: bool = False) -> None:
    """One line on how firmly ``cal``'s view pins the speeds down: a warning with what to do for a poorly
    conditioned view, unless ``warned`` (vpdetect's own warning says it), then a plain line without the advice."""
    cond = cal.conditioning()
    if cond.poor and not warned:
        from .terminal import say

        say(console, cond.describe(True))  # (on stderr, as every warning)
    else:
        console.print("View: " + cond.describe(not warned), highlight=False)


def _add_scale(video: Path, cal, models, iou_threshold: float, min_vehicles: int, regression, out, model: str = "",
               zone=None, orientation: str = "auto"):
    """The calibration with BBScale's λ from ``video`` (gst_trafficcal.scale.video), or with the reason
    (``models``: loaded align models; ``regression``: a loaded ScaleRegression or None; ``model``: vehicledetect's,
    "" for the background detector; ``zone``: only the vehicles standing in it; ``orientation``: how its frames are
    turned, as they were for the vanishing points)."""
    from ..scale.video import scale_from_video

    res = scale_from_video(video, cal, models=models, iou_threshold=iou_threshold, min_vehicles=min_vehicles,
                           regression=regression, detector=model, zone=zone, orientation=orientation)
    r = res.result
    if r.converged:
        out.print(f"scale λ {r.scale:.3f} m (λ* {r.raw_scale:.3f}, confidence {r.confidence:.2f}, "
                  f"{r.n_agreeing} of {r.n_matched} matched vehicles agree)", markup=False)
    else:
        out.print(f"no scale: {r.status}", markup=False)
    return res.calibration
