"""The scale of a video file without GStreamer: decode (OpenCV), detect (the ``vehicledetect`` detectors), track
(the ``tracker`` element's library stage) and align (:class:`.streaming.ScaleEstimator`, as ``bbscale``).

``estimate_scale(video, calibration)`` is what ``trafficcal calibrate`` / ``trafficcal fit-scale`` call: the
calibration's vanishing points are used, its scale (if any) ignored, and the calibration comes back with λ
(state "calibrated", ``confidence["scale"]``) or, without convergence, unchanged with ``reason`` saying why.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np

from ..calibration import Calibration
from ..errors import InputError
from ..tracking.tracker import body_shape_name
from ..vanishing.frames import luma
from .roll import derolled_fields
from .streaming import ScaleEstimator, ScaleResult, Sighting, base_centre
from ..zone import Zone


#: which 2D box of a tracked vehicle is aligned: "hull" = the box of its foreground convex hull (the tracker's
#: ``hull_box``), "detector" = the detector's rectangle
BOX_SOURCES = ("hull", "detector")


def frame_sightings(result, detections, camera, box: str = "detector") -> list[Sighting]:
    """The sightings of one frame from the tracker's association, as the ``tracker`` element publishes them
    (confirmed tracks only; base from the 3D box, ``box`` = "hull" (the convex hull's box) or "detector",
    direction as heading)."""
    if box not in BOX_SOURCES:
        raise InputError(f"box must be one of {', '.join(BOX_SOURCES)}, got {box!r}")
    out = []
    for i in range(len(detections)):
        track = result.track_of(i)
        if track is None:
            continue
        o = track.last
        base = base_centre(o.corners_px) if camera is not None and o.corners_px is not None else None
        b = o.box if box == "hull" else detections.boxes[i]
        rolled = derolled_fields(camera, o.hull, o.silhouette) if base is not None else {}
        out.append(Sighting(int(track.id), float(o.t), tuple(float(v) for v in b), base,
                            float(track.direction), str(detections.labels[i]), bool(o.occluded),
                            bool(o.truncated), corners=o.corners_px if base is not None else None,
                            body_shape=body_shape_name(track), stretched=track.proportions == "stretched", **rolled))
    return out


@dataclass
class VideoScale:
    """The outcome of :func:`scale_from_video`: the calibration (with λ when converged) and the stage's result."""

    calibration: Calibration
    result: ScaleResult
    frames: int
    seconds: float
    box_params: np.ndarray  # (V, 5) per vehicle: median 3D box x0, x1, y0, y1, h (plane units), for BMVC14


def _check_size(video: Path, calibration: Calibration, size: tuple[int, int]) -> None:
    """An InputError when ``calibration`` was made for another frame size than ``video``'s frames as analysed
    (squared and turned): its vanishing points are pixels of that size, and every vehicle would miss the models."""
    (w, h), (vw, vh) = calibration.image_size, size
    if (w, h) != (vw, vh):
        raise InputError(f"{video}: the calibration is of {w}x{h} images but the video's frames are {vw}x{vh} "
                         "(a camera mounted turned: give its --orientation, or calibrate this video)")


def scale_from_video(video: str | Path, calibration: Calibration, *, models=None, iou_threshold: float = 0.85,
                     min_vehicles: int = 5, regression=None, detector: str = "", max_duration: float | None = None,
                     progress: Callable[[float], None] | None = None, box: str = "detector",
                     on_frame: Callable | None = None, colour: bool = False, background: str = "mog2",
                     zone: Zone | None = None, orientation: str = "auto") -> VideoScale:
    """Run detection, tracking and the scale stage over ``video`` with ``calibration``'s vanishing points
    (``box``: which 2D box is aligned, see :data:`BOX_SOURCES`; ``colour``: the background model also uses the
    frame's U/V, as the ``tracker`` element does by default — off here: measured on six synth presets, the
    colour hulls move the 3D-box base points so that even exact 2D boxes give λ 1-9 % off (median 3.0 %, vs
    1.1 % with brightness-only hulls), so run ``tracker colour=false`` upstream of ``bbscale``;
    ``on_frame(index, t, result, detections)`` is called after each frame is tracked, e.g. for a benchmark's
    side estimators; ``background``: the background detector's method when ``detector`` is empty, "mog2" or
    "average", see :func:`~gst_trafficcal.detection.factory.create_detector`); ``zone``: only the vehicles standing
    in it, as vehicledetect's ``zone``; ``orientation``: how the frames are turned, as the calibration's were)."""
    import cv2

    from ..detection.factory import create_detector, detect
    from ..tracking.background import BackgroundModel, chroma_from_bgr
    from ..tracking.pipeline import TrackingPipeline
    from .streaming import load_align_models

    if calibration.camera is None:
        raise InputError("the scale needs the vanishing points: the calibration has none (state "
                         f"{calibration.state!r})")
    from ..fileio import open_video
    from ..imaging import capture_par, opencv_picture

    path = Path(video)
    cap = open_video(path)
    par = capture_par(cap)  # frames of non-square pixels scaled to square ones, as the calibration's (frames.py)
    picture = opencv_picture(path, orientation)  # turned (a mirrored file's flip) as they are shown (frames.py)
    camera = calibration.camera.with_scale(None)
    est = ScaleEstimator(models if isinstance(models, dict) else load_align_models(models),
                         iou_threshold=iou_threshold, min_vehicles=min_vehicles, regression=regression)
    est.set_camera(camera)
    det = create_detector(detector, background=background)
    pipe = TrackingPipeline(background=BackgroundModel(work_width=480))
    pipe.set_camera(camera)
    n, t = 0, 0.0
    boxes: dict[int, list[np.ndarray]] = {}
    try:
        while True:
            ok, bgr = cap.read()
            if not ok:
                break
            bgr = picture.frame(bgr, par)
            if n == 0:
                _check_size(path, calibration, bgr.shape[1::-1])
            t = float(cap.get(cv2.CAP_PROP_POS_MSEC)) / 1000.0
            if max_duration is not None and t > max_duration:
                break
            # the elements see the decoder's Y plane (video range 16-235); OpenCV expands it to full range
            gray = luma(bgr)
            detections = detect(det, bgr if detector else gray, t)
            if zone is not None:
                detections = zone.keep(detections, gray.shape[::-1])
            result, detections = pipe.process(gray, t, detections, chroma=chroma_from_bgr(bgr) if colour else None)
            sightings = frame_sightings(result, detections, camera, box)
            est.update(t, sightings)
            if on_frame is not None:
                on_frame(n, t, result, detections)
            for i in range(len(detections)):
                track = result.track_of(i)
                if track is not None and track.last.box3d is not None and not track.last.occluded \
                        and not track.last.truncated:
                    boxes.setdefault(track.id, []).append(np.asarray(track.last.box3d, np.float64))
            n += 1
            if progress is not None:
                progress(t)
    finally:
        cap.release()
    if n == 0:
        raise InputError(f"video {path}: no frames could be decoded")
    est.finish()
    r = est.result()
    if r.converged:
        conf = dict(calibration.confidence, scale=float(r.confidence))
        source = calibration.source if calibration.source.endswith("bbscale") else f"{calibration.source}+bbscale"
        cal = calibration.with_scale(float(r.scale), confidence=conf, source=source)
    else:
        cal = replace(calibration.with_scale(None), reason=f"no scale: {r.status}")
    params = np.array([np.median(np.array(b), axis=0) for b in boxes.values()]).reshape(-1, 5)
    return VideoScale(cal, r, n, t, params)


def estimate_scale(video: str | Path, calibration: Calibration, **options) -> Calibration:
    """``calibration`` with the scale λ estimated from ``video`` by BBScale (see :func:`scale_from_video`)."""
    return scale_from_video(video, calibration, **options).calibration
