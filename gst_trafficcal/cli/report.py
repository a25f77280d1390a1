"""``trafficcal report``: build ``report.html`` from the files of a run (events, calibration, optional ground truth)."""

from __future__ import annotations

from pathlib import Path

import click

from ..errors import InputError
from .run import given_orientation, orientation_option


def _frame(image: Path | None, video: str | None, at_s: float, orientation: str = "auto"):
    """A BGR frame: the image file, or the video's frame at ``at_s`` seconds, or a stream's (a URI) frame now
    (None when neither is given); a video's turned by ``orientation`` (trafficcal run's --orientation)."""
    import cv2

    from .run import first_frame, frame_picture, is_stream, local_file, shown_source

    from ..fileio import cannot_open_video, open_video, video_file
    from ..imaging import capture_par

    if image is not None:
        if not image.is_file():
            raise InputError(f"{image}: " + ("a folder, not an image" if image.is_dir() else "no such image"))
        frame = cv2.imread(str(image), cv2.IMREAD_COLOR)
        if frame is None:
            raise InputError(f"{image}: not an image OpenCV can read")
        return frame
    if video is None:
        return None
    if is_stream(video):
        if at_s > 0:
            raise InputError("--frame-time is for a video file: a stream gives the frame it is at")
        frame = first_frame(video, orientation)
        if frame is None:
            raise InputError(f"{shown_source(video)}: no frame could be read from the stream")
        return frame
    video = Path(local_file(video) or video)
    if at_s <= 0:  # the first frame, as trafficcal run's report shows it (GStreamer where OpenCV refuses the file)
        frame = first_frame(video_file(video), orientation)
        if frame is None:
            raise cannot_open_video(video)
        return frame
    cap = open_video(video)
    try:
        cap.set(cv2.CAP_PROP_POS_MSEC, at_s * 1000.0)
        ok, frame = cap.read()
        par = capture_par(cap)
    finally:
        cap.release()
    if not ok or frame is None:
        raise InputError(f"{video}: cannot read a frame (not a video, or shorter than {at_s:g} s)")
    # turned (a mirrored file shown mirrored) and of square pixels, as trafficcal run's frames
    return frame_picture(video, orientation).frame(frame, par)


@click.command(help="Write a self-contained report.html (calibration picture, speed histogram and statistics with "
                    "V85, counts per lane, class and interval; "
                    "with --gt and --results also the BrnoCompSpeed error tables and cumulative error plot).")
@click.option("--events", "events_path", required=True, type=click.Path(path_type=Path),
              help="Vehicle events, JSON lines (vehicles.jsonl).")
@click.option("--calibration", "calibration_path", type=click.Path(path_type=Path),
              help="Calibration JSON (ours, or a BrnoCompSpeed results file with camera_calibration).")
@click.option("--frame", "frame_path", type=click.Path(path_type=Path), help="An image of the scene.")
@click.option("--video", "video_path", metavar="VIDEO|URI",
              help="The video (a file, or a stream's URI); a frame of it is used when --frame is not given.")
@click.option("--frame-time", type=click.FloatRange(min=0), default=0.0, show_default=True,
              help="Seconds into --video of that frame (a file's; a stream gives the frame it is at).")
@click.option("--gt", "gt_path", type=click.Path(path_type=Path), help="Ground truth gt_data.pkl.")
@click.option("--results", "results_path", type=click.Path(path_type=Path),
              help="BrnoCompSpeed results JSON of the run (system.json): the picture of the lanes; needed with "
                   "--gt for speed errors.")
@click.option("--title", default="gst-trafficcal report", show_default=True, help="Page title.")
@click.option("--speed-limit", default="", metavar="KMH[,CLASS=KMH...]",
              help="Posted speed limit in km/h, and classes with limits of their own (e.g. 80,truck=60,bus=60): "
                   "marked on the plots; the tables count the vehicles over their limit.")
@click.option("--interval", "interval_min", type=click.FloatRange(min=0.01, max=10080), default=15.0,
              show_default=True, help="Minutes per interval of the traffic count (aligned to the clock when the "
                                      "events carry dates: speedometer start-datetime=, trafficcal run --start-time).")
@click.option("--intervals-csv", "intervals_path", type=click.Path(path_type=Path),
              help="Also write the traffic count per interval, lane and direction as CSV.")
@click.option("--zone", default="", metavar="'x,y x,y x,y ...'",
              help="The detection zone the run used (trafficcal run --zone): outlined in the calibration picture. "
                   "Default: the zone the --calibration file keeps (a run's calibration.json does); 'all': none.")
@orientation_option(" for the picture (the run's --orientation; default: the one the --calibration file keeps, "
                    "else auto)")
@click.option("--out", "out_path", required=True, type=click.Path(path_type=Path), help="The report.html to write.")
def command(events_path: Path, calibration_path: Path | None, frame_path: Path | None, video_path: str | None,
            frame_time: float, gt_path: Path | None, results_path: Path | None, title: str, speed_limit: str,
            interval_min: float, intervals_path: Path | None, out_path: Path, zone: str = "",
            orientation: str | None = None) -> None:
    from ..brnocompspeed import load_gt_data, load_results
    from ..calibration import load_calibration
    from ..outputs import on_one_clock, read_events
    from ..report import ReportInputs, measured_paths, write_report
    from ..traffic_stats import interval_rows, parse_speed_limit, write_intervals_csv
    from ..zone import given_or_kept

    limit = parse_speed_limit(speed_limit, "--speed-limit")
    where = given_or_kept(zone, "--zone", calibration_path)  # a run's calibration.json keeps the zone it measured in
    orientation, _ = given_orientation(orientation, calibration_path)  # and the orientation it turned the video by
    log = read_events(events_path)
    cal = load_calibration(calibration_path) if calibration_path is not None else None
    results = load_results(results_path) if results_path is not None else None
    if cal is None and results is not None and results.calibration is not None:
        cal = load_calibration(results_path)  # its camera_calibration, in pixels of its image_size (ours write it)
    frame = _frame(frame_path, video_path, frame_time, orientation)
    if cal is not None and frame is not None and tuple(cal.image_size) != tuple(frame.shape[1::-1]):
        (w, h), (fw, fh) = cal.image_size, frame.shape[1::-1]
        other = "" if abs(w / h - fw / fh) < 0.01 * w / h else "; not even the same shape: another camera's?"
        click.echo(f"warning: {calibration_path or results_path}: a calibration of {w}x{h} frames, the picture is "
                   f"{fw}x{fh}: the grid is drawn scaled to it{other}", err=True)
    evaluation = None
    if gt_path is not None:
        from ..evaluation import evaluate

        gt = load_gt_data(gt_path)
        if cal is None or cal.camera is None:
            raise InputError("--gt needs a calibration with vanishing points (--calibration or --results)")
        if results is not None and cal.camera.scale is None:
            raise InputError(f"{calibration_path or results_path}: calibration has no scale, speeds cannot be "
                             "evaluated")
        evaluation = evaluate(gt, cal.camera, results)
    start, events = on_one_clock(log.events)  # an appended file's runs, each from its own stream start
    path = write_report(out_path, ReportInputs(
        events, cal, frame, evaluation, ground_truth_name=str(gt_path or ""), title=title,
        source=str(video_path or ""), speed_limit_kmh=limit, interval_s=60 * interval_min,
        start_time=start, paths=measured_paths(results.cars, events) if results is not None else (), zone=where))
    skipped = f" ({log.skipped} broken line(s) skipped)" if log.skipped else ""
    click.echo(f"{path}: {len(log.events)} vehicles{skipped}")
    if intervals_path is not None:
        rows = interval_rows(events, 60 * interval_min, start, limit)
        click.echo(f"{write_intervals_csv(intervals_path, rows)}: {sum(r.total for r in rows)} intervals")
