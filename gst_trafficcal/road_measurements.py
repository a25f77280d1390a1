"""A person's road measurements for one camera: the manual calibration's input without BrnoCompSpeed files.

Where the automatic calibration cannot pin the speeds down (a camera looking along the road:
:mod:`gst_trafficcal.vanishing.conditioning`), a traffic engineer measures a few distances on the road — a dash
and its gap, a lane's width — and reads their ends' pixel positions off a frame. ``trafficcal calibrate-manual
--measurements FILE`` turns them into a calibration by the paper's ManualCalib + ManualScale
(:func:`gst_trafficcal.manual_calibration.calibrate_markings`). The file, JSON or YAML::

    image_size: [1920, 1080]            # the frame the pixels were read from (optional: --image-size)
    lane_dividers:                      # at least two lines that run with the traffic (lane markings, kerbs),
      - [[812, 1079], [905, 402]]       #   each given by two or more image points along it
      - [[1203, 1079], [1010, 402]]
    segments:                           # measured on the road: at least one along the traffic, one across it
      - {from: [880, 700], to: [902, 560], metres: 6.0, direction: along}
      - {from: [880, 700], to: [1120, 700], metres: 3.5, direction: across}

Every problem is an :class:`InputError` naming the file and the entry (``segments[2].metres``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .errors import InputError
from .fileio import read_text
from .manual_calibration import RoadMarkings

DIRECTIONS = {"along": True, "across": False}


def fit_line(points: np.ndarray) -> np.ndarray:
    """Homogeneous line (a, b, c), ‖(a, b)‖ = 1, through image points (N ≥ 2, 2) by total least squares (the
    vehicle tracks' fit, :func:`gst_trafficcal.vanishing.tracks.fit_lines`, from the points' sums)."""
    from .vanishing.tracks import fit_lines

    x, y = points[:, 0], points[:, 1]
    sums = np.array([[len(points), x.sum(), y.sum(), x @ x, x @ y, y @ y]], dtype=np.float64)
    return fit_lines(sums)[0][0]


def _point(value: Any, where: str) -> np.ndarray:
    if (not isinstance(value, (list, tuple)) or len(value) != 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)):
        raise InputError(f"{where} must be an image point [x, y] of two numbers, got {value!r}")
    return np.array(value, dtype=float)


def parse_road_measurements(data: Any, where: str) -> tuple[RoadMarkings, tuple[int, int] | None]:
    """The markings (and the image size, when given) of a measurements mapping; ``where`` names it in errors."""
    if not isinstance(data, dict):
        raise InputError(f"{where}: road measurements must be a mapping with lane_dividers and segments")
    unknown = set(data) - {"image_size", "lane_dividers", "segments"}
    if unknown:
        raise InputError(f"{where}: unknown field(s) {', '.join(sorted(map(str, unknown)))} (expected image_size, "
                         "lane_dividers, segments)")
    size = data.get("image_size")
    if size is not None:
        if (not isinstance(size, (list, tuple)) or len(size) != 2
                or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size)):
            raise InputError(f"{where}: image_size must be [width, height] in pixels, got {size!r}")
        size = (int(size[0]), int(size[1]))
    dividers = data.get("lane_dividers")
    if not isinstance(dividers, list) or len(dividers) < 2:
        raise InputError(f"{where}: lane_dividers must list at least two lines that run with the traffic "
                         "(each two or more image points)")
    lines = []
    for k, line in enumerate(dividers):
        at = f"{where}: lane_dividers[{k}]"
        if not isinstance(line, list) or len(line) < 2:
            raise InputError(f"{at} must be a list of two or more image points")
        pts = np.array([_point(p, f"{at}[{j}]") for j, p in enumerate(line)])
        if np.ptp(pts, axis=0).max() < 1.0:
            raise InputError(f"{at}: its points are less than a pixel apart, they give no direction")
        lines.append(fit_line(pts))
    segments = data.get("segments")
    if not isinstance(segments, list) or not segments:
        raise InputError(f"{where}: segments must list the measured road segments (from, to, metres, direction)")
    p1, p2, metres, along = [], [], [], []
    for k, seg in enumerate(segments):
        at = f"{where}: segments[{k}]"
        if not isinstance(seg, dict):
            raise InputError(f"{at} must be a mapping with from, to, metres and direction")
        missing = [key for key in ("from", "to", "metres", "direction") if key not in seg]
        if missing:
            raise InputError(f"{at} lacks {', '.join(missing)}")
        a, b = _point(seg["from"], f"{at}.from"), _point(seg["to"], f"{at}.to")
        m = seg["metres"]
        if not isinstance(m, (int, float)) or isinstance(m, bool) or not (math.isfinite(m) and m > 0):
            raise InputError(f"{at}.metres must be a positive number of metres, got {m!r}")
        if seg["direction"] not in DIRECTIONS:
            raise InputError(f"{at}.direction must be 'along' (the traffic) or 'across' (it), got "
                             f"{seg['direction']!r}")
        if np.linalg.norm(b - a) < 1.0:
            raise InputError(f"{at}: its ends are less than a pixel apart")
        p1.append(a), p2.append(b), metres.append(float(m)), along.append(DIRECTIONS[seg["direction"]])
    markings = RoadMarkings(np.array(lines), np.array(p1), np.array(p2), np.array(metres), np.array(along),
                            source=where)
    return markings, size


def load_road_measurements(path: str | Path) -> tuple[RoadMarkings, tuple[int, int] | None]:
    """Read a measurements file (YAML, or JSON by its ``.json`` suffix): see the module doc."""
    path = Path(path)
    text = read_text(path, "road measurements file")
    try:
        data = json.loads(text) if path.suffix.lower() == ".json" else yaml.safe_load(text)
    except (json.JSONDecodeError, yaml.YAMLError) as exc:
        raise InputError(f"{path}: not a readable road measurements file ({str(exc).splitlines()[0]})") from None
    return parse_road_measurements(data, str(path))


def road_measurements_dict(m: RoadMarkings, image_size: tuple[int, int]) -> dict:
    """``m`` as a measurements mapping (each lane divider by its two image-border points): e.g. a BrnoCompSpeed
    recording's markings written as a file a person can read and edit."""
    from .drawing import line_segment

    dividers = []
    for k, line in enumerate(m.lane_lines):
        ends = line_segment(line, image_size)
        if ends is None:
            raise InputError(f"{m.source}: lane divider {k} does not cross the {image_size[0]}x{image_size[1]} image")
        dividers.append(np.round(ends, 3).tolist())
    segments = [{"from": np.round(a, 3).tolist(), "to": np.round(b, 3).tolist(), "metres": float(d),
                 "direction": "along" if t else "across"} for a, b, d, t in zip(m.p1, m.p2, m.metres, m.to_vp1)]
    return {"image_size": list(image_size), "lane_dividers": dividers, "segments": segments}
