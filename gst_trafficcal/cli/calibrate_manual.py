"""``trafficcal calibrate-manual``: the paper's ManualCalib + ManualScale, from a BrnoCompSpeed ground truth or
from a person's road measurements (:mod:`gst_trafficcal.road_measurements`)."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np


@click.command(help="Calibration from road measurements (the paper's ManualCalib + ManualScale, §5): VP1 from the "
                    "lane dividers, VP2 by a grid search minimising the length error of the segments measured "
                    "across the traffic, the scale from those measured along it. Give either a BrnoCompSpeed "
                    "gt_data.pkl (--gt) or your own measurements (--measurements FILE, YAML or JSON: lane_dividers "
                    "as image points, segments with from/to pixels, metres and direction along|across; "
                    "docs/vpdetect.md \"Your own road measurements\"). For a camera the automatic calibration "
                    "calls poorly conditioned (looking along the road). Writes our calibration JSON (with the "
                    "BrnoCompSpeed camera_calibration block, and the road-plane homography for OpenCV or "
                    "supervision: docs/outputs.md); with --image, a picture of the grid and the "
                    "segments beside it.")
@click.option("--gt", "gt_path", type=click.Path(path_type=Path), default=None,
              help="Ground truth gt_data.pkl of a BrnoCompSpeed recording.")
@click.option("--measurements", "measurements_path", type=click.Path(path_type=Path), default=None,
              help="Your road measurements (YAML or JSON).")
@click.option("-o", "--output", "out_path", required=True, type=click.Path(path_type=Path),
              help="Calibration JSON to write.")
@click.option("--image-size", default=None,
              help="Frame size WxH; the principal point is its centre (960.5, 540.5 for 1920x1080). Default: the "
                   "measurements file's image_size, else the size of --image, else 1920x1080 (a BrnoCompSpeed "
                   "gt_data.pkl holds no size: give one of these for another resolution).")
@click.option("--image", "image_path", type=click.Path(path_type=Path), default=None,
              help="A picture or video of the camera (its first frame): writes OUTPUT.png with the road grid, the "
                   "lane dividers and each segment with its measured and calibrated length.")
def command(gt_path: Path | None, measurements_path: Path | None, out_path: Path, image_size: str | None,
            image_path: Path | None) -> None:
    from rich.console import Console
    from rich.table import Table

    from ..calibration import Calibration, save_calibration
    from ..errors import InputError
    from ..manual_calibration import RoadMarkings, calibrate_markings, size_doubt
    from .evaluate import parse_image_size

    if (gt_path is None) == (measurements_path is None):
        raise click.UsageError("give either --gt or --measurements")
    if image_path is not None and out_path.suffix.lower() == ".png":
        raise InputError(f"{out_path}: the calibration is a JSON file, and with --image its picture goes beside it "
                         f"as {out_path.with_suffix('.png').name}: name the calibration .json")
    size = parse_image_size(image_size) if image_size is not None else None
    if gt_path is not None:
        from ..brnocompspeed import load_gt_data

        markings = RoadMarkings.from_gt(load_gt_data(gt_path))
    else:
        from ..road_measurements import load_road_measurements

        markings, file_size = load_road_measurements(measurements_path)
        if size is not None and file_size is not None and size != file_size:
            raise InputError(f"{measurements_path}: its image_size {file_size[0]}x{file_size[1]} differs from "
                             f"--image-size {size[0]}x{size[1]}")
        size = size or file_size
    frame = _frame(image_path, size) if image_path is not None else None  # bad picture: an error before any work
    from ..fileio import atomic_write_image, writable_file, writable_image

    writable_file(out_path, "calibration file (-o)")  # a wrong path: one line now, not after the grid search
    if frame is not None:
        writable_image(out_path.with_suffix(".png"), "picture")
    size = size or ((frame.shape[1], frame.shape[0]) if frame is not None else (1920, 1080))
    doubt = size_doubt(np.concatenate([markings.p1, markings.p2]), size)
    if doubt:
        Console(stderr=True).print(f"[yellow]warning[/]: {doubt.text}: is the recording of another size? Give its size "
                                   "(--image-size) or a frame of it (--image), or the calibration is wrong",
                                   highlight=False)
    result = calibrate_markings(markings, image_size=size)
    cam = result.camera
    cal = Calibration(camera=cam, image_size=size, state="calibrated", source="manual-calibration")
    save_calibration(cal, out_path)
    out = Console()
    init = "none" if result.vp2_initial is None else f"({result.vp2_initial[0]:.1f}, {result.vp2_initial[1]:.1f})"
    out.print(
        f"VP1 ({cam.vp1[0]:.1f}, {cam.vp1[1]:.1f})  VP2 ({cam.vp2[0]:.1f}, {cam.vp2[1]:.1f}) [first guess {init}]  "
        f"f {cam.focal:.1f} px  scale {cam.scale:.4f} m (camera height)  "
        f"VP2-segment error {result.cost_m:.3f} m over {result.n_vp2_segments} segments -> {out_path}",
        markup=False)
    if measurements_path is not None:
        table = Table("segment", "direction", "measured [m]", "calibration [m]", "error [m]", title="Segments")
        got = cam.distance(markings.p1, markings.p2)
        for k, (d, g, t) in enumerate(zip(markings.metres, got, markings.to_vp1)):
            table.add_row(str(k), "along" if t else "across", f"{d:.2f}", f"{g:.2f}", f"{g - d:+.2f}")
        out.print(table)
    if frame is not None:
        png = out_path.with_suffix(".png")
        atomic_write_image(png, _picture(frame, cal, markings), "picture")  # whole or not at all (a full disk)
        out.print(f"Picture -> {png}", markup=False)


def _frame(path: Path, size: tuple[int, int] | None) -> np.ndarray:
    """The picture at ``path`` (or a video's first frame), BGR, which must be ``size`` when one is given."""
    import cv2

    from ..errors import InputError

    if not path.is_file():
        raise InputError(f"{path}: " + ("a folder, not a picture or video" if path.is_dir() else "no such file"))
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        from .run import first_frame

        img = first_frame(path)
        if img is None:
            raise InputError(f"{path}: neither a picture nor a video OpenCV can read")
    if size is not None and (img.shape[1], img.shape[0]) != size:
        raise InputError(f"{path}: it is {img.shape[1]}x{img.shape[0]}, the measurements are for {size[0]}x{size[1]}")
    return img


def _picture(frame: np.ndarray, cal, markings) -> np.ndarray:
    """The frame with the calibration's road grid, the lane dividers (magenta) and each segment (green along,
    orange across) labelled with its measured and calibrated length."""
    import cv2

    from ..drawing import draw_calibration, draw_segments, line_segment

    img = frame.copy()
    h, w = img.shape[:2]
    thick = 1 if w < 1280 else 2
    draw_calibration(img, cal.camera, thickness=thick, opacity=0.6)  # under the segments and their labels
    for line in markings.lane_lines:
        ends = line_segment(line, (w, h))
        if ends is not None:
            draw_segments(img, ends[None], (255, 0, 255), thick)
    got = cal.camera.distance(markings.p1, markings.p2)
    font = 0.4 * thick + 0.1
    for a, b, d, g, along in zip(markings.p1, markings.p2, markings.metres, got, markings.to_vp1):
        colour = (0, 200, 0) if along else (0, 140, 255)
        draw_segments(img, np.stack([a, b])[None], colour, thick + 1)
        for p in (a, b):
            cv2.circle(img, (int(round(p[0])), int(round(p[1]))), 2 + thick, colour, -1, cv2.LINE_AA)
        m = 0.5 * (a + b)
        cv2.putText(img, f"{d:.2f}/{g:.2f} m", (int(m[0]) + 4, int(m[1]) - 4), cv2.FONT_HERSHEY_SIMPLEX, font,
                    (0, 0, 0), thick + 2, cv2.LINE_AA)
        cv2.putText(img, f"{d:.2f}/{g:.2f} m", (int(m[0]) + 4, int(m[1]) - 4), cv2.FONT_HERSHEY_SIMPLEX, font,
                    colour, thick, cv2.LINE_AA)
    return img
