"""One entry point for every detector, shared by the vehicledetect element, the CLI and benchmarks."""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..errors import InputError
from .records import Detections

Detector = Callable[[np.ndarray], Detections]


def create_detector(
    model: str = "",
    model_format: str = "auto",
    labels: str | None = None,
    threshold: float = 0.4,
    threads: int = 1,
    tiles: str | tuple[int, int] = (1, 1),
    background: str = "mog2",
) -> Detector:
    """An ONNX detector for ``model`` (a path or an installed model's name), or the background
    detector when ``model`` is empty (``background``: its model, "mog2" or "average" — the moving average with
    shadow peeling, tighter boxes).  ``model="vehicleseg"`` (or ``model_format="vehicleseg"``, or a file whose
    metadata names it) is the project's learned vehicle segmenter, which also gives each vehicle's convex hull.
    Bad files or names raise InputError here, at start-up."""
    if not model:
        from .background import BackgroundDetector

        if background not in ("mog2", "average"):
            raise InputError(f"background method must be mog2 or average, got {background!r}")
        return BackgroundDetector(method=background)
    from . import vehicleseg
    from .models import resolve_model
    from .onnx_detector import OnnxDetector

    if model == vehicleseg.NAME:
        return vehicleseg.VehicleSegDetector(threads=threads)
    path = resolve_model(model)
    if model_format == vehicleseg.NAME or (model_format == "auto" and vehicleseg.is_vehicleseg(path)):
        return vehicleseg.VehicleSegDetector(path, threads=threads)
    return OnnxDetector(path, model_format=model_format, labels=labels, threshold=threshold,
                        threads=threads, tiles=parse_tiles(tiles) if isinstance(tiles, str) else tiles)


def ignored_options(detector: Detector, model_format: str = "auto", labels: str | None = None,
                    threshold: float = 0.4, tiles: str | tuple[int, int] = (1, 1),
                    background: str = "mog2") -> list[str]:
    """The options given (not at their defaults) that ``detector`` does not use — ``labels``, ``tiles``,
    ``threshold`` and ``model-format`` are an ONNX model's, ``background`` the built-in detector's — named as the
    element's properties, so that a user learns at start why setting them changes nothing."""
    from .background import BackgroundDetector
    from .onnx_detector import OnnxDetector

    given = {"model-format": model_format not in ("auto", ""), "labels": bool(labels), "threshold": threshold != 0.4,
             "tiles": (parse_tiles(tiles) if isinstance(tiles, str) else tuple(tiles)) != (1, 1),
             "background": background != "mog2"}
    if isinstance(detector, BackgroundDetector):
        used = {"background"}
    elif isinstance(detector, OnnxDetector):
        used = {"model-format", "labels", "threshold", "tiles"}
    else:  # vehicleseg: its own outputs, classes and threshold
        used = {"model-format"}
    return [name for name, set_ in given.items() if set_ and name not in used]


def detect(detector: Detector, image: np.ndarray, t: float | None = None,
           frame_size: tuple[int, int] | None = None) -> Detections:
    """Run any detector on one frame; detectors that keep a background over time (``timed``, e.g. vehicleseg) get
    the frame time ``t`` in seconds.  ``frame_size``: the frame's (w, h) when ``image`` is it reduced to
    :func:`reduced_size` (boxes still come in frame pixels)."""
    args = (image, t) if getattr(detector, "timed", False) else (image,)
    if frame_size is not None and tuple(frame_size) != image.shape[1::-1]:
        return detector(*args, frame_size=tuple(frame_size))
    return detector(*args)


def reduced_size(detector: Detector, frame_size: tuple[int, int]) -> tuple[int, int] | None:
    """The size a detector reduces every frame of ``frame_size`` to before anything else, when it says so
    (vehicleseg's work image, an ONNX detector's network image without tiles) and the frame is at least twice that
    size each way: the caller may then hand it the frame already reduced (1080p: a quarter of the conversion's cost
    and no full-size copy).  None: pass full frames (smaller frames cost little, and they keep the full
    conversion's chroma resampling)."""
    size = getattr(detector, "reduced_size", None)
    size = size(frame_size) if size is not None else None
    if size is None:
        return None
    w, h = size
    return (w, h) if frame_size[0] >= 2 * w and frame_size[1] >= 2 * h else None


def parse_tiles(text: str) -> tuple[int, int]:
    """``"3x2"`` -> (3, 2) (columns, rows); InputError otherwise."""
    cols, sep, rows = text.strip().lower().partition("x")
    try:
        value = (int(cols), int(rows))
    except ValueError:
        value = None
    if not sep or value is None or min(value) < 1 or max(value) > 8:
        raise InputError(f"tiles must look like COLUMNSxROWS with 1..8 each (e.g. 3x2), got {text!r}")
    return value
