"""BrnoCompSpeed file formats: the ground-truth ``gt_data.pkl`` and the system results JSON.

The dataset's ground truth is a Python-2 pickle of plain dicts holding numpy arrays. It is read
here with a restricted unpickler (only numpy arrays/scalars and ``set`` may be rebuilt, so a
hostile pickle cannot run code) and turned into typed records. ``save_gt_data`` writes the same
structure back, so generated scenes can be scored by the official evaluation code as well.

The results format is ``{"camera_calibration": {"vp1", "vp2", "pp", "scale"}, "cars": [{"id",
"frames", "posX", "posY"}]}``; positions are road-plane reference points in image pixels and
``scale`` follows BrnoCompSpeed's own convention (see ``geometry.Camera.from_brno``).
"""

from __future__ import annotations

import io
import json
import math
import pickle
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from .errors import InputError
from .fileio import atomic_write, is_json_number, read_json

__all__ = [
    "BrnoCalibration",
    "DistanceMeasurement",
    "GroundTruth",
    "GtCar",
    "LineCrossing",
    "Results",
    "Track",
    "load_gt_data",
    "load_results",
    "save_gt_data",
    "save_results",
]


# --------------------------------------------------------------------------- ground truth


@dataclass(frozen=True, eq=False)
class DistanceMeasurement:
    """A segment between two road markers with its measured length."""

    p1: np.ndarray  # (2,) image pixels
    p2: np.ndarray  # (2,) image pixels
    distance: float  # metres
    to_vp1: bool  # True: along the traffic (towards VP1); False: across it (towards VP2)


@dataclass(frozen=True)
class LineCrossing:
    """Time at which a ground-truth car crossed one measurement line."""

    line: int  # index into GroundTruth.measurement_lines
    video_time: float  # seconds


@dataclass(frozen=True)
class GtCar:
    """One ground-truth vehicle passage (speed from the dataset's lidar gates)."""

    car_id: int
    lanes: frozenset[int]
    valid: bool
    speed: float  # km/h
    intersections: tuple[LineCrossing, ...]
    time_intersection_last_shifted: float | None = None
    acceleration: float | None = None

    @property
    def match_time(self) -> float:
        """The time the official evaluation matches on: the last entry of ``intersections``."""
        return self.intersections[-1].video_time


@dataclass(frozen=True, eq=False)
class GroundTruth:
    """Contents of one recording's ``gt_data.pkl``."""

    fps: float
    measurement_lines: np.ndarray  # (M, 3) homogeneous image lines
    lane_div_lines: np.ndarray  # (L, 3) homogeneous image lines, lane k between rows k and k+1
    invalid_lanes: frozenset[int]
    distances: tuple[DistanceMeasurement, ...]
    cars: tuple[GtCar, ...]
    source: Path | None = field(default=None, compare=False)

    @property
    def distances_p1(self) -> np.ndarray:
        return np.array([d.p1 for d in self.distances], dtype=float).reshape(-1, 2)

    @property
    def distances_p2(self) -> np.ndarray:
        return np.array([d.p2 for d in self.distances], dtype=float).reshape(-1, 2)

    @property
    def distances_m(self) -> np.ndarray:
        return np.array([d.distance for d in self.distances], dtype=float)

    @property
    def distances_to_vp1(self) -> np.ndarray:
        return np.array([d.to_vp1 for d in self.distances], dtype=bool)


_ALLOWED_GLOBALS = {
    ("numpy", "ndarray"),
    ("numpy", "dtype"),
    ("numpy.core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"),
    ("numpy._core.multiarray", "_reconstruct"),
    ("numpy._core.multiarray", "scalar"),
    ("__builtin__", "set"),
    ("builtins", "set"),
    ("__builtin__", "frozenset"),
    ("builtins", "frozenset"),
    ("_codecs", "encode"),  # how Python 3 writes bytes (numpy array data) at protocol 2; only encodes text
}


class _SafeUnpickler(pickle.Unpickler):
    """Unpickler that rebuilds only numpy arrays/scalars and sets (no arbitrary code)."""

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) not in _ALLOWED_GLOBALS:
            raise pickle.UnpicklingError(f"refusing to load {module}.{name}")
        return super().find_class(module, name)


def _line_array(value: Any, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] < 2 or not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} must be at least two finite homogeneous lines (3 numbers each)")
    return arr


def _point(value: Any, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float).ravel()
    if arr.size == 3:
        arr = arr[:2] / arr[2]
    if arr.size != 2 or not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} is not an image point")
    return arr


def _finite(value: Any, what: str, positive: bool = False) -> float:
    """``value`` as a float; ValueError naming ``what`` when it is NaN or infinite (or not positive): one such car
    made every speed statistic NaN, one such crossing time dropped every system car as seen too late."""
    v = float(value)
    if not math.isfinite(v) or (positive and not v > 0):
        raise ValueError(f"{what} must be a {'positive' if positive else 'finite'} number, got {v}")
    return v


def _parse_gt(raw: Any) -> GroundTruth:
    if not isinstance(raw, dict):
        raise ValueError("top level is not a dict")
    missing = [k for k in ("fps", "measurementLines", "laneDivLines", "distanceMeasurement", "cars")
               if k not in raw]
    if missing:
        raise ValueError(f"missing key(s) {', '.join(missing)}")
    fps = float(raw["fps"])
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    distances = []
    for i, d in enumerate(raw["distanceMeasurement"]):
        distances.append(DistanceMeasurement(
            p1=_point(d["p1"], f"distanceMeasurement[{i}].p1"),
            p2=_point(d["p2"], f"distanceMeasurement[{i}].p2"),
            distance=_finite(d["distance"], f"distanceMeasurement[{i}].distance", positive=True),
            to_vp1=bool(d["toVP1"])))
    cars = []
    for i, c in enumerate(raw["cars"]):
        crossings = tuple(LineCrossing(int(x["measurementLineId"]), _finite(x["videoTime"], f"cars[{i}] videoTime"))
                          for x in c["intersections"])
        if not crossings:
            raise ValueError(f"cars[{i}] has no line intersections")
        shifted = c.get("timeIntersectionLastShifted")
        accel = c.get("acceleration")
        cars.append(GtCar(
            car_id=int(c["carId"]), lanes=frozenset(int(v) for v in c["laneIndex"]),
            valid=bool(c["valid"]), speed=_finite(c["speed"], f"cars[{i}].speed"), intersections=crossings,
            time_intersection_last_shifted=None if shifted is None else float(shifted),
            acceleration=None if accel is None else float(accel)))
    return GroundTruth(
        fps=fps,
        measurement_lines=_line_array(raw["measurementLines"], "measurementLines"),
        lane_div_lines=_line_array(raw["laneDivLines"], "laneDivLines"),
        invalid_lanes=frozenset(int(v) for v in raw.get("invalidLanes", ())),
        distances=tuple(distances), cars=tuple(cars))


def load_gt_data(path: str | Path) -> GroundTruth:
    """Read a BrnoCompSpeed ``gt_data.pkl``; raise InputError naming the file if it is unusable."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    try:
        raw = _SafeUnpickler(io.BytesIO(data), encoding="latin1").load()
    except Exception as exc:  # pickle raises many types on garbage input
        raise InputError(f"{path}: not a readable gt_data pickle ({type(exc).__name__}: {exc})") from None
    try:
        gt = _parse_gt(raw)
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        detail = f"missing key {exc}" if isinstance(exc, KeyError) else str(exc)
        raise InputError(f"{path}: not a BrnoCompSpeed gt_data.pkl ({detail})") from None
    return replace(gt, source=path)


def gt_to_raw(gt: GroundTruth) -> dict[str, Any]:
    """The plain-dict structure of ``gt_data.pkl`` (same keys and types as the dataset's files)."""
    cars = []
    for c in gt.cars:
        car: dict[str, Any] = {
            "laneIndex": set(c.lanes), "carId": int(c.car_id), "valid": bool(c.valid),
            "speed": np.float64(c.speed),
            "intersections": [{"measurementLineId": np.int64(x.line), "videoTime": np.float64(x.video_time)}
                              for x in c.intersections],
            "timeIntersectionLastShifted": np.float64(
                c.time_intersection_last_shifted if c.time_intersection_last_shifted is not None
                else c.match_time),
        }
        if c.acceleration is not None:
            car["acceleration"] = np.float64(c.acceleration)
        cars.append(car)
    return {
        "distanceMeasurement": [{"p1": np.array([*d.p1, 1.0]), "p2": np.array([*d.p2, 1.0]),
                                 "distance": float(d.distance), "toVP1": bool(d.to_vp1)}
                                for d in gt.distances],
        "measurementLines": [np.asarray(l, dtype=float).copy() for l in gt.measurement_lines],
        "laneDivLines": [np.asarray(l, dtype=float).copy() for l in gt.lane_div_lines],
        "invalidLanes": set(gt.invalid_lanes),
        "fps": float(gt.fps),
        "cars": cars,
    }


def save_gt_data(gt: GroundTruth, path: str | Path) -> None:
    """Write ``gt`` as a ``gt_data.pkl`` in the dataset's structure (pickle protocol 2), atomically
    (:func:`gst_trafficcal.fileio.atomic_write`: InputError naming the file when it cannot be written)."""
    raw = gt_to_raw(gt)

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            pickle.dump(raw, f, protocol=2)

    atomic_write(path, write, "ground truth")


# --------------------------------------------------------------------------- results JSON


def block_point(d: dict, key: str, where: str = "camera_calibration") -> tuple[float, float]:
    """Point ``key`` of a ``camera_calibration`` block: [x, y] or homogeneous [x, y, w] (both are found in
    BrnoCompSpeed's files); ValueError naming ``where.key`` when it is missing, not numbers, at infinity or not
    finite."""
    if key not in d:
        raise ValueError(f"{where} has no '{key}'")
    v = d[key]
    if not (isinstance(v, (list, tuple)) and len(v) in (2, 3)
            and all(is_json_number(x) for x in v)):
        raise ValueError(f"{where}.{key} must be a list of 2 numbers")
    v = [float(x) for x in v]
    if len(v) == 3:
        if v[2] == 0:
            raise ValueError(f"{where}.{key} is a point at infinity")
        v = [v[0] / v[2], v[1] / v[2]]
    if not all(math.isfinite(x) for x in v):
        raise ValueError(f"{where}.{key} is not finite")
    return v[0], v[1]


@dataclass(frozen=True)
class BrnoCalibration:
    """The ``camera_calibration`` block: vanishing points, principal point, BrnoCompSpeed scale."""

    vp1: tuple[float, float]
    vp2: tuple[float, float]
    pp: tuple[float, float]
    scale: float

    def to_dict(self) -> dict[str, Any]:
        return {"vp1": list(self.vp1), "vp2": list(self.vp2), "pp": list(self.pp), "scale": self.scale}

    @classmethod
    def from_dict(cls, d: Any, where: str = "camera_calibration") -> "BrnoCalibration":
        if not isinstance(d, dict):
            raise ValueError(f"{where} is not an object")
        pts = {key: block_point(d, key, where) for key in ("vp1", "vp2", "pp")}
        if "scale" not in d:
            raise ValueError(f"{where} has no 'scale'")
        scale = d["scale"]
        if not is_json_number(scale) or not math.isfinite(scale) or scale <= 0:
            raise ValueError(f"{where}.scale must be a positive number, got {scale!r}")
        return cls(pts["vp1"], pts["vp2"], pts["pp"], float(scale))


@dataclass(frozen=True, eq=False)
class Track:
    """One system car: image positions of its road-plane reference point per frame."""

    id: int
    frames: np.ndarray  # (n,) frame numbers, in the file's order
    pos: np.ndarray  # (n, 2) pixels
    scalar_positions: bool = False  # posX/posY were plain numbers (the official code drops such cars)


@dataclass(frozen=True, eq=False)
class Results:
    """A BrnoCompSpeed results file."""

    calibration: BrnoCalibration | None
    cars: tuple[Track, ...]
    source: Path | None = field(default=None, compare=False)
    image_size: tuple[int, int] | None = None  # (width, height) of the positions' frames, where the file says
    # (ours write it beside the format's fields; the official files are of 1920x1080 recordings and do not)


def _numbers(value: Any, what: str) -> tuple[np.ndarray, bool]:
    if is_json_number(value):
        return np.array([float(value)]), True
    if not isinstance(value, list):
        raise ValueError(f"{what} must be a list of numbers")
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a list of numbers") from None
    if arr.ndim != 1:
        raise ValueError(f"{what} must be a flat list of numbers")
    return arr, False


def _parse_results(raw: Any) -> Results:
    if not isinstance(raw, dict):
        raise ValueError("top level is not a JSON object")
    if "cars" not in raw and "camera_calibration" not in raw:
        raise ValueError("neither 'cars' nor 'camera_calibration' present")
    calib = None
    if raw.get("camera_calibration") is not None:
        calib = BrnoCalibration.from_dict(raw["camera_calibration"])
    cars_raw = raw.get("cars", [])
    if not isinstance(cars_raw, list):
        raise ValueError("'cars' must be a list")
    cars = []
    for i, c in enumerate(cars_raw):
        if not isinstance(c, dict):
            raise ValueError(f"cars[{i}] is not an object")
        for key in ("id", "frames", "posX", "posY"):
            if key not in c:
                raise ValueError(f"cars[{i}] has no '{key}'")
        frames, s1 = _numbers(c["frames"], f"cars[{i}].frames")
        x, s2 = _numbers(c["posX"], f"cars[{i}].posX")
        y, s3 = _numbers(c["posY"], f"cars[{i}].posY")
        if not (len(frames) == len(x) == len(y)):
            raise ValueError(f"cars[{i}] (id {c['id']}) has lists of different lengths: "
                             f"frames {len(frames)}, posX {len(x)}, posY {len(y)}")
        if len(frames) == 0:
            raise ValueError(f"cars[{i}] (id {c['id']}) has no positions")
        cars.append(Track(id=c["id"], frames=frames, pos=np.column_stack([x, y]),
                          scalar_positions=s2 or s3 or s1))
    size = raw.get("image_size")
    return Results(calib, tuple(cars), image_size=None if size is None else image_size_field(size))


def image_size_field(value: Any) -> tuple[int, int]:
    """An ``image_size`` field (of results or calibration files) as (width, height); ValueError unless it is two
    positive whole numbers (true/false are not numbers here)."""
    if not (isinstance(value, (list, tuple)) and len(value) == 2 and
            all(is_json_number(v, whole=True) and v > 0 for v in value)):
        raise ValueError(f"'image_size' must be [width, height], got {value!r}")
    return int(value[0]), int(value[1])


def load_results(path: str | Path, cars_required: bool = False) -> Results:
    """Read a BrnoCompSpeed results JSON; raise InputError naming the file if it is unusable (with
    ``cars_required``, also when it has no ``cars`` list: a calibration file given as results)."""
    raw = read_json(path, "BrnoCompSpeed results file")
    if cars_required and isinstance(raw, dict) and "cars" not in raw:
        raise InputError(f"{path}: no 'cars' list, so no vehicles to score (a calibration file? give it as "
                         "--calibration)")
    try:
        res = _parse_results(raw)
    except ValueError as exc:
        raise InputError(f"{path}: not a BrnoCompSpeed results file ({exc})") from None
    return replace(res, source=Path(path))


def _plain(v: float) -> int | float:
    f = float(v)
    return int(f) if f.is_integer() and abs(f) < 2**53 else f


def _car_dict(t: Track) -> dict[str, Any]:
    """One car of the results file (frame numbers as integers where they are whole)."""
    f = np.asarray(t.frames, dtype=np.float64)
    whole = bool(np.all((f == np.round(f)) & (np.abs(f) < 2**53)))
    frames = f.astype(np.int64).tolist() if whole else [_plain(v) for v in f]
    return {"id": t.id, "frames": frames, "posX": t.pos[:, 0].tolist(), "posY": t.pos[:, 1].tolist()}


def results_to_dict(res: Results) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if res.calibration is not None:
        out["camera_calibration"] = res.calibration.to_dict()
    out["cars"] = [_car_dict(t) for t in res.cars]
    return out


def save_results(res: Results, path: str | Path) -> None:
    """Write ``res`` as a BrnoCompSpeed results JSON — the text of ``json.dumps(results_to_dict(res))`` — a car at
    a time: a long run's file is never whole in memory (at once it took 4.5 times the file's size, 430 MB for a
    busy camera's day), atomically (:func:`gst_trafficcal.fileio.atomic_write`: an interrupted write leaves the
    earlier file, and one that cannot be written is an InputError naming it)."""
    def write(tmp: Path) -> None:
        with tmp.open("w", encoding="utf-8") as out:
            write_results_text(out, res.calibration, (car_json(t) for t in res.cars))

    atomic_write(path, write, "BrnoCompSpeed results")


def car_json(track: Track) -> str:
    """One car of the results file as its JSON text (what :func:`save_results` writes for it)."""
    return json.dumps(_car_dict(track))


def write_results_text(out, calibration: BrnoCalibration | None, cars: Iterable[str],
                       image_size: tuple[int, int] | None = None) -> None:
    """The results file's text into the open text file ``out``, the cars given as their JSON (:func:`car_json`);
    with ``image_size`` (width, height) also that field, beside the format's own (its calibration block holds
    pixels of frames of that size: the file then serves as a calibration of any resolution, not only 1920x1080)."""
    out.write("{")
    if calibration is not None:
        out.write(f'"camera_calibration": {json.dumps(calibration.to_dict())}, ')
        if image_size is not None:
            out.write(f'"image_size": [{int(image_size[0])}, {int(image_size[1])}], ')
    out.write('"cars": [')
    for i, car in enumerate(cars):
        out.write((", " if i else "") + car)
    out.write("]}")
