"""Our calibration file: a versioned JSON record of a camera calibration, plus BrnoCompSpeed's block.

Example::

    {
      "format": "gst-trafficcal-calibration",
      "version": 1,
      "id": "c3f1a2b4c5d6",
      "state": "calibrated",
      "source": "vpdetect",
      "image_size": [1920, 1080],
      "vp1": [x, y], "vp2": [x, y], "pp": [x, y],
      "focal": 1234.5,
      "scale": 7.9,                    # λ: metres per road-plane unit = camera height in metres, or null
      "confidence": {"vp1": 0.98, ...},
      "camera": {"K": [[...]], "R": [[...]], "t": [...]},       # present when the scale is known
      "camera_calibration": {"vp1": [...], "vp2": [...], "pp": [...], "scale": s},  # BrnoCompSpeed convention
      "conditioning": {"vp2_image_widths": 3.1, "turn_deg": 0.1, "speed_pct": 0.7, "poor": false},
      "zone": "0.1,0.4 0.9,0.4 1,1 0,1"  # the detection zone it was learnt in (gst_trafficcal.zone), when one was
    }

``conditioning`` (derived, written for readers, ignored when loading): how much the speeds change when the lines
towards VP2 turn by ``turn_deg`` (:mod:`gst_trafficcal.vanishing.conditioning`); ``poor`` for a view along the road.

``zone`` (optional) is read by :func:`gst_trafficcal.zone.zone_of_file`, not by :func:`load_calibration`; likewise
``orientation`` (optional: the ``--orientation`` the picture was turned by) by
:func:`gst_trafficcal.imaging.orientation_of_file`.

``state`` is one of :data:`STATES`.  Loading validates everything and raises :class:`InputError` with a
one-line message naming the file for anything that is not our format or is corrupt.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .brnocompspeed import block_point, image_size_field
from .errors import GeometryError, InputError
from .fileio import atomic_write_text, is_json_number, read_json
from .geometry import Camera
from .road_homography import road_homography

if TYPE_CHECKING:
    from .vanishing.conditioning import Conditioning

FORMAT = "gst-trafficcal-calibration"
VERSION = 1
STATES = ("learning", "vps", "calibrated", "failed")
"""learning: evidence being gathered; vps: vanishing points known, no scale; calibrated: VPs and scale;
failed: could not converge (``reason`` says why)."""


@dataclass(frozen=True)
class Calibration:
    """A camera calibration with its provenance; ``camera`` is None until the vanishing points are known."""

    camera: Camera | None
    image_size: tuple[int, int]
    state: str = "calibrated"
    source: str = "unknown"
    confidence: dict[str, float] = field(default_factory=dict)
    reason: str = ""
    view: dict | None = None  # the static scene it was learnt on (vanishing/view.py), to tell a moved camera
    moved_at: float | None = None  # stream time (s) the camera moved, on the "learning" calibration vpdetect
    # announces then: what was seen before belongs to the calibration in force before, nothing after does

    def __post_init__(self) -> None:
        if self.state not in STATES:
            raise InputError(f"unknown calibration state {self.state!r} (expected one of {', '.join(STATES)})")
        if self.state in ("vps", "calibrated") and self.camera is None:
            raise InputError(f"calibration state {self.state!r} needs vanishing points")
        if self.state == "calibrated" and self.camera is not None and self.camera.scale is None:
            object.__setattr__(self, "state", "vps")

    @property
    def id(self) -> str:
        """Short content hash: equal calibrations have equal ids."""
        if self.camera is None:
            key = f"{self.state}:{self.image_size}" + ("" if self.moved_at is None else f":moved@{self.moved_at:.3f}")
        else:
            c = self.camera
            key = json.dumps([np.round(c.vp1, 6).tolist(), np.round(c.vp2, 6).tolist(), np.round(c.pp, 6).tolist(),
                              None if c.scale is None else round(c.scale, 9), list(self.image_size)])
        return hashlib.sha1(key.encode()).hexdigest()[:12]

    def with_scale(self, scale: float | None, **changes: Any) -> "Calibration":
        if self.camera is None:
            raise GeometryError("cannot set a scale before the vanishing points are known")
        state = "calibrated" if scale is not None else "vps"
        return replace(self, camera=self.camera.with_scale(scale), state=state, **changes)

    def conditioning(self) -> "Conditioning":
        """How firmly this view pins the speeds down (:mod:`gst_trafficcal.vanishing.conditioning`); needs the
        vanishing points."""
        from .vanishing.conditioning import view_conditioning

        if self.camera is None:
            raise GeometryError("no vanishing points yet: the view's conditioning is unknown")
        return view_conditioning(self.camera, self.image_size)

    # ------------------------------------------------------------------ JSON
    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"format": FORMAT, "version": VERSION, "id": self.id, "state": self.state,
                             "source": self.source, "image_size": list(self.image_size)}
        if self.reason:
            d["reason"] = self.reason
        if self.moved_at is not None:
            d["moved_at"] = float(self.moved_at)
        if self.camera is not None:
            c = self.camera
            d.update(vp1=c.vp1.tolist(), vp2=c.vp2.tolist(), pp=c.pp.tolist(), focal=c.focal, scale=c.scale)
            if c.scale is not None:
                K, R, t = c.to_KRt()
                d["camera"] = {"K": K.tolist(), "R": R.tolist(), "t": t.tolist()}
                try:  # for tools that take a homography or four points (derived, ignored when loading)
                    d["road_homography"] = road_homography(c, self.image_size).to_dict()
                except GeometryError:  # no road rows in the frame: the file stays valid without it
                    pass
            d["camera_calibration"] = {"vp1": c.vp1.tolist(), "vp2": c.vp2.tolist(), "pp": c.pp.tolist(),
                                       "scale": None if c.scale is None else c.brno_scale()}
            d["conditioning"] = self.conditioning().to_dict()
        d["confidence"] = dict(self.confidence)
        if self.view is not None:
            d["view"] = dict(self.view)
        return d

    @classmethod
    def from_dict(cls, d: Any, where: str = "calibration") -> "Calibration":
        if not isinstance(d, dict):
            raise InputError(f"{where}: not a calibration (expected a JSON object)")
        if d.get("format") != FORMAT:
            if d.get("camera_calibration") is not None and "format" not in d:
                return cls.from_brno_block(d["camera_calibration"], where=where, image_size=_size(d, where))
            if ("cars" in d or "camera_calibration" in d) and "format" not in d:
                raise InputError(f"{where}: a BrnoCompSpeed results file without a calibration (its "
                                 "camera_calibration is empty: the run found no scale)")
            raise InputError(f"{where}: not a gst-trafficcal calibration file (format {d.get('format')!r})")
        if d.get("version") != VERSION:
            raise InputError(f"{where}: unsupported calibration version {d.get('version')!r} (this is {VERSION})")
        state = d.get("state", "calibrated")
        if state not in STATES:
            raise InputError(f"{where}: unknown calibration state {state!r} (expected one of {', '.join(STATES)})")
        camera = None
        if "vp1" in d:
            scale = d.get("scale")
            if scale is not None and (not is_json_number(scale) or not math.isfinite(scale)):
                raise InputError(f"{where}: field 'scale' must be a number or null")
            try:
                camera = Camera(_point(d, "vp1", where), _point(d, "vp2", where), _point(d, "pp", where), scale)
            except GeometryError as exc:
                raise GeometryError(f"{where}: {exc}") from None
        if camera is None and state in ("vps", "calibrated"):  # else Calibration says so without the file's name
            raise InputError(f"{where}: state {state!r} needs the vanishing points (fields 'vp1', 'vp2' and 'pp'), "
                             "but the file has no 'vp1'")
        conf = d.get("confidence", {})
        if not (isinstance(conf, dict) and all(is_json_number(v) for v in conf.values())):
            raise InputError(f"{where}: field 'confidence' must be an object of numbers, got {conf!r}")
        view = d.get("view")
        if view is not None and not (isinstance(view, dict) and isinstance(view.get("png"), str)
                                     and is_json_number(view.get("frame_width"), whole=True)):
            raise InputError(f"{where}: field 'view' must be an object with 'png' and 'frame_width'")
        moved_at = d.get("moved_at")
        if moved_at is not None and not (is_json_number(moved_at) and math.isfinite(moved_at)):
            raise InputError(f"{where}: field 'moved_at' must be a number (seconds) or null")
        return cls(camera=camera, image_size=_size(d, where), state=state, source=str(d.get("source", "unknown")),
                   confidence={str(k): float(v) for k, v in conf.items()}, reason=str(d.get("reason", "")),
                   view=view, moved_at=None if moved_at is None else float(moved_at))

    @classmethod
    def from_brno_block(cls, block: Any, where: str = "calibration",
                        image_size: tuple[int, int] = (1920, 1080)) -> "Calibration":
        """From BrnoCompSpeed's ``camera_calibration`` {vp1, vp2, pp, scale} (its scale convention)."""
        if not isinstance(block, dict):
            raise InputError(f"{where}: 'camera_calibration' must be an object")
        scale = block.get("scale")
        if scale is not None and not is_json_number(scale):
            raise InputError(f"{where}: field 'camera_calibration.scale' must be a number or null, got {scale!r}")
        try:  # one reading of the block's points, [x, y] or [x, y, w], with BrnoCompSpeed's results
            vp1, vp2, pp = (np.array(block_point(block, key, f"{where}: camera_calibration"))
                            for key in ("vp1", "vp2", "pp"))
        except ValueError as exc:
            raise InputError(str(exc)) from None
        try:
            cam = Camera.from_brno(vp1, vp2, pp, None if scale is None else float(scale))
        except GeometryError as exc:
            raise GeometryError(f"{where}: {exc}") from None
        return cls(camera=cam, image_size=image_size, state="calibrated" if scale is not None else "vps",
                   source="brnocompspeed")


def same_vanishing_points(a: Calibration | None, b: Calibration | None) -> bool:
    """Whether two calibrations have the same vanishing points and principal point."""
    if a is None or b is None or a.camera is None or b.camera is None:
        return False
    return bool(np.allclose(a.camera.vp1, b.camera.vp1) and np.allclose(a.camera.vp2, b.camera.vp2)
                and np.allclose(a.camera.pp, b.camera.pp))


def latest_per_view(cals: list[Calibration], cal: Calibration) -> list[Calibration]:
    """``cals`` with ``cal`` in place of any calibration of the same vanishing points (one per view, the latest
    last)."""
    return [c for c in cals if not same_vanishing_points(c, cal)] + [cal]


def _point(d: dict, key: str, where: str) -> np.ndarray:
    v = d.get(key)
    if not (isinstance(v, (list, tuple)) and len(v) == 2 and all(is_json_number(x) for x in v)):
        raise InputError(f"{where}: field {key!r} must be a list of two numbers, got {v!r}")
    return np.asarray(v, dtype=np.float64)


def _size(d: dict, where: str) -> tuple[int, int]:
    try:  # one check for the field in both kinds of file
        return image_size_field(d.get("image_size", [1920, 1080]))
    except ValueError as exc:
        raise InputError(f"{where}: field {exc}") from None


def load_calibration(path: str | Path) -> Calibration:
    """Read our calibration JSON (or a BrnoCompSpeed results/calibration JSON with a camera_calibration block)."""
    return Calibration.from_dict(read_json(path, "calibration file"), where=str(path))


def save_calibration(cal: Calibration, path: str | Path, zone: object | None = None,
                     orientation: str = "auto") -> Path:
    """Write the calibration atomically (a crash never leaves half a file); with the detection ``zone``
    (:class:`gst_trafficcal.zone.Zone`) it was learnt and measured in as field ``zone``, so that a report made again
    from the file, or a run given it, keeps to the same road (:func:`gst_trafficcal.zone.zone_of_file`); with an
    ``orientation`` other than auto (``--orientation``: how the picture was turned) as field ``orientation``, so
    that they turn it the same way (:func:`gst_trafficcal.imaging.orientation_of_file`)."""
    d = cal.to_dict()
    if zone is not None:
        d["zone"] = str(zone)
    if orientation != "auto":
        d["orientation"] = orientation
    return atomic_write_text(path, json.dumps(d, indent=2) + "\n", "calibration")


# --------------------------------------------------------------------------- a camera's views (PTZ presets)

def view_key(cal: Calibration) -> str:
    """The file name stem of ``cal`` in a views folder: its vanishing points' id (with or without a scale, one
    file per view)."""
    return cal.with_scale(None).id if cal.camera is not None else cal.id


def load_views(folder: str | Path, image_size: tuple[int, int],
               orientation: str | None = None) -> tuple[list[Calibration], list[str]]:
    """The calibrations of a camera's views kept in ``folder`` (``*.json``, each with vanishing points and the
    ``view`` it was learnt on) for frames of ``image_size`` and, given an ``orientation``, of a picture turned that
    way (a view's field ``orientation``, auto when it keeps none: a camera re-mounted turned is another view); and a
    line per file that is not one (unreadable, another frame size or orientation, no view).  A missing folder holds
    none."""
    from .imaging import AUTO, orientation_of_file

    found, skipped = [], []
    root = Path(folder)
    for path in sorted(root.glob("*.json")) if root.is_dir() else []:
        try:
            cal = load_calibration(path)
            turned = orientation_of_file(path) or AUTO
        except InputError as exc:
            skipped.append(str(exc))
            continue
        if cal.camera is None or cal.view is None:
            skipped.append(f"{path}: no vanishing points or no view")
        elif tuple(cal.image_size) != tuple(image_size):
            skipped.append(f"{path}: a calibration of {cal.image_size[0]}x{cal.image_size[1]} frames")
        elif orientation is not None and turned != orientation:
            skipped.append(f"{path}: a view of the picture turned by orientation {turned}, not {orientation} "
                           "(a camera mounted another way is another view)")
        else:
            found.append(cal)
    return found, skipped


def save_view(cal: Calibration, folder: str | Path, orientation: str | None = None) -> Path | None:
    """Keep ``cal`` (with vanishing points and its view) in the views folder as ``<view_key>.json``, with the
    ``orientation`` its picture was turned by (None: the one the file there keeps, as when a scale is added to a
    view); a calibration of the same view with a scale already there is not replaced by one without.  Returns the
    path written, or None."""
    from .imaging import AUTO, orientation_of_file

    if cal.camera is None or cal.view is None:
        return None
    path = Path(folder) / f"{view_key(cal)}.json"
    if cal.camera.scale is None and path.is_file():
        try:
            if load_calibration(path).camera.scale is not None:
                return None
        except (InputError, AttributeError):
            pass  # broken: replaced
    if orientation is None and path.is_file():
        try:
            orientation = orientation_of_file(path)
        except InputError:
            pass  # broken: replaced
    try:
        Path(folder).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{folder}: cannot create the views folder ({exc.strerror or exc})") from None
    return save_calibration(replace(cal, moved_at=None), path, orientation=orientation or AUTO)
