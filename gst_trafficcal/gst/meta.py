"""Per-vehicle metadata on buffers, in Intel DL Streamer's layout (read and written only here).

Each vehicle is one ``GstVideoRegionOfInterestMeta``: ``roi_type`` = label, ``id`` = index of the
ROI within the frame (so ``GstVideo.buffer_get_video_region_of_interest_meta_id`` finds it), integer
``x, y, w, h`` = the box clipped to the frame, and parameter structures:

- ``"detection"``: ``x_min, y_min, x_max, y_max`` (doubles normalised by the frame size),
  ``confidence`` (double), ``label_id`` (int), ``label`` (string) -- exactly as DL Streamer's gvadetect;
- ``"object_id"``: ``id`` (int >= 1), written by the tracker, as DL Streamer's gvatrack;
- ``"trafficcal-hull"``: ``points`` (K x [x, y] doubles, frame pixels with pixel centres at integers), the
  vehicle's convex outline from a segmentation detector (``vehicledetect model=vehicleseg``); the tracker builds
  its 3D boxes from it instead of its own background model;
- any extra named structures (``"trafficcal-vehicle"``, ``"speed"``, ...) given as ``{name: {field: value}}``.

Field values may be bool, int, float, str, or (nested) sequences of numbers (stored as
``GstValueArray``). PyGObject hands out *copies* of structures, so every structure is built
completely before it is attached; never edit what :func:`read_vehicle_rois` returns and expect the
buffer to change -- call :func:`update_roi_params`.
"""

from __future__ import annotations

import math
import re
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from . import _cgst
from ._gi import GObject, Gst, GstVideo

if TYPE_CHECKING:
    from ..detection.records import Detections

DETECTION = "detection"
OBJECT_ID = "object_id"
HULL = "trafficcal-hull"

_INT32 = (-(2**31), 2**31 - 1)


@dataclass
class RoiRecord:
    """One vehicle ROI read back from a buffer.

    ``box`` is (x0, y0, x1, y1) in pixels (from the normalised "detection" doubles when present,
    else the meta's integer rectangle); ``params`` holds every parameter structure by name,
    including "detection" and "object_id".  ``index`` is its place among the buffer's ROI metas (attachment order),
    which :func:`update_roi_params` takes: ``meta_id`` is whatever the detector set (ours number them, GStreamer's
    default and other detectors leave 0 on every ROI).
    """

    meta_id: int
    label: str
    box: tuple[float, float, float, float]
    confidence: float
    label_id: int
    object_id: int | None
    params: dict[str, dict[str, Any]] = field(default_factory=dict)
    index: int = -1


def _gvalue(value: Any) -> Any:
    """A Python value as something ``Gst.Structure.set_value`` stores with the right GType."""
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, bool):
        return value
    if isinstance(value, int):
        if _INT32[0] <= value <= _INT32[1]:
            return value
        v = GObject.Value(GObject.TYPE_INT64)
        v.set_int64(value)
        return v
    if isinstance(value, float):
        return value
    if isinstance(value, str):
        return value
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, Sequence):
        return Gst.ValueArray([_gvalue(x) for x in _promote(value)])
    raise TypeError(f"cannot store {type(value).__name__} {value!r} in a metadata structure")


def _promote(value: Sequence) -> list:
    """Array items with every number a float when any leaf is a float (GstValueArray needs one type)."""

    def leaves(v: Any) -> list:
        if isinstance(v, (str, bytes)) or not isinstance(v, (Sequence, np.ndarray)):
            return [v]
        return [leaf for x in v for leaf in leaves(x)]

    def to_float(v: Any) -> Any:
        if isinstance(v, np.generic):
            v = v.item()
        if isinstance(v, (Sequence, np.ndarray)) and not isinstance(v, str):
            return [to_float(x) for x in v]
        return float(v) if isinstance(v, int) and not isinstance(v, bool) else v

    items = [x.item() if isinstance(x, np.generic) else x for x in value]
    if any(isinstance(leaf, (float, np.floating)) for leaf in leaves(items)):
        items = [to_float(x) for x in items]
    return items


def _pyvalue(value: Any) -> Any:
    if isinstance(value, Gst.ValueArray):
        return [_pyvalue(v) for v in value]
    return value


_PLAIN = "A-Za-z0-9_+/:.-"  # the characters GStreamer writes unquoted (a regex character class)
_PLAIN_TEXT = re.compile(f"[{_PLAIN}]+\\Z")
_PLAIN_CHAR = re.compile(f"[{_PLAIN}]")
_FIELD_NAME = re.compile(f"[A-Za-z][{_PLAIN}]*\\Z")


def _text_string(value: str) -> str:
    """A string as GStreamer's serialisation writes it: bare when plain, else quoted with ``\\`` escapes and
    octal bytes (gst_string_wrap), so that ``Gst.Structure.from_string`` reads back exactly ``value``."""
    if value != "NULL" and _PLAIN_TEXT.match(value):
        return value
    out = []
    for c in value.encode():
        ch = chr(c)
        if c < 0x20 or c >= 0x7F:
            out.append(f"\\{c:03o}")
        elif _PLAIN_CHAR.match(ch):
            out.append(ch)
        else:
            out.append("\\" + ch)
    return '"' + "".join(out) + '"'


def _text_value(value: Any) -> str | None:
    """``(type)value`` of one field in GStreamer's serialisation, for the values the elements write nearly every
    frame (bool, int, float, str, lists and lists of lists of floats); None for anything else."""
    kind = type(value)
    if kind is bool:
        return "(boolean)true" if value else "(boolean)false"
    if kind is float:
        return f"(double){value:.17g}"  # as g_ascii_dtostr: the same double is read back
    if kind is int:
        return f"(int){value}" if _INT32[0] <= value <= _INT32[1] else f"(gint64){value}"
    if kind is str:
        return "(string)" + _text_string(value)
    if kind is list and value:
        if all(type(x) is float for x in value):
            return "(double)< " + ", ".join([f"{x:.17g}" for x in value]) + " >"
        if all(type(x) is list and x and all(type(y) is float for y in x) for x in value):
            inner = ", ".join(["< " + ", ".join([f"(double){y:.17g}" for y in x]) + " >" for x in value])
            return f"(double)< {inner} >"
    return None


def _structure_text(name: str, fields: Mapping[str, Any]) -> str | None:
    """The serialisation of the structure :func:`make_structure` builds, or None when some field is not of the
    plain kinds :func:`_text_value` writes (then the structure is built field by field)."""
    parts = [name]
    for key, value in fields.items():
        if value is None:
            continue
        text = _text_value(value)
        if text is None or not _FIELD_NAME.match(key):
            return None
        parts.append(f"{key}={text}")
    return ", ".join(parts) + ";"


def make_structure(name: str, fields: Mapping[str, Any]) -> Gst.Structure:
    """A complete ``Gst.Structure`` called ``name`` holding ``fields``.  The plain fields of the per-vehicle
    structures are written as text and parsed by GStreamer in one call (a quarter of the time of setting them
    one by one through GObject values: the elements write several per vehicle and frame); other values go
    through :func:`_gvalue`."""
    text = _structure_text(name, fields) if _FIELD_NAME.match(name) else None
    if text is not None:
        parsed = Gst.Structure.from_string(text)
        s = parsed[0] if isinstance(parsed, tuple) else parsed
        if s is not None:
            return s
    s = Gst.Structure.new_empty(name)
    for key, value in fields.items():
        if value is None:
            continue
        s.set_value(key, _gvalue(value))
    return s


def structure_to_dict(s: Gst.Structure) -> dict[str, Any]:
    """Fields of ``s`` as plain Python values (arrays become lists)."""
    return {s.nth_field_name(i): _pyvalue(s.get_value(s.nth_field_name(i))) for i in range(s.n_fields())}


def _require_writable(buffer: Gst.Buffer) -> None:
    if not _cgst.is_writable(buffer):
        raise RuntimeError(
            "buffer is not writable: metadata can only be added in an in-place element with passthrough off"
        )


def add_vehicle_roi(
    buffer: Gst.Buffer,
    frame_size: tuple[int, int],
    box: Sequence[float],
    label: str,
    confidence: float,
    label_id: int,
    object_id: int | None = None,
    params: Mapping[str, Mapping[str, Any]] | None = None,
) -> int:
    """Attach one vehicle ROI to ``buffer`` and return its meta id (its index within the frame).

    ``frame_size`` = (width, height); ``box`` = (x0, y0, x1, y1) in pixels, clipped to the frame.
    """
    _require_writable(buffer)
    width, height = int(frame_size[0]), int(frame_size[1])
    x0, y0, x1, y1 = (float(v) for v in box)
    if not all(math.isfinite(v) for v in (x0, y0, x1, y1)) or x1 < x0 or y1 < y0:
        raise ValueError(f"invalid box {tuple(box)} (need finite x0 <= x1, y0 <= y1)")
    x0, x1 = min(max(x0, 0.0), width), min(max(x1, 0.0), width)
    y0, y1 = min(max(y0, 0.0), height), min(max(y1, 0.0), height)
    if object_id is not None and int(object_id) < 1:
        raise ValueError(f"object_id must be >= 1, got {object_id}")
    meta_id = sum(1 for _ in _cgst.iter_roi_metas(buffer))
    ix, iy = int(round(x0)), int(round(y0))
    iw, ih = int(round(x1)) - ix, int(round(y1)) - iy
    meta = GstVideo.buffer_add_video_region_of_interest_meta(buffer, label, ix, iy, iw, ih)
    if meta is None:
        raise RuntimeError("gst_buffer_add_video_region_of_interest_meta failed")
    meta.id = meta_id
    structures = [
        make_structure(
            DETECTION,
            {"x_min": x0 / width, "y_min": y0 / height, "x_max": x1 / width, "y_max": y1 / height,
             "confidence": float(confidence), "label_id": int(label_id), "label": str(label)},
        )
    ]
    if object_id is not None:
        structures.append(make_structure(OBJECT_ID, {"id": int(object_id)}))
    for name, fields in (params or {}).items():
        if name in (DETECTION, OBJECT_ID):
            raise ValueError(f"parameter structure {name!r} is written from the arguments, not params")
        structures.append(make_structure(name, fields))
    for s in structures:  # each complete before add_param (which stores a copy)
        meta.add_param(s)
    return meta_id


def read_vehicle_rois(buffer: Gst.Buffer, frame_size: tuple[int, int],
                      only: Collection[str] | None = None) -> list[RoiRecord]:
    """Every ROI meta on ``buffer`` as :class:`RoiRecord`, in attachment order.  With ``only``, ``params`` holds
    just the structures of those names besides "detection" and "object_id" (the others are not read: reading a
    structure costs more than anything else an element does with a vehicle that it only passes on)."""
    width, height = float(frame_size[0]), float(frame_size[1])
    names = None if only is None else {DETECTION, OBJECT_ID, *only}
    out: list[RoiRecord] = []
    for index, (_addr, m) in enumerate(_cgst.iter_roi_metas(buffer)):
        params: dict[str, dict[str, Any]] = {}
        for s in _cgst.roi_param_structures(m, names):  # the first structure of a name wins, as get_param
            params.setdefault(s.get_name(), structure_to_dict(s))
        det = params.get(DETECTION, {})
        label = _cgst.quark_string(m.roi_type) or str(det.get("label", ""))
        if all(k in det for k in ("x_min", "y_min", "x_max", "y_max")):
            box = (det["x_min"] * width, det["y_min"] * height, det["x_max"] * width, det["y_max"] * height)
        else:
            box = (float(m.x), float(m.y), float(m.x + m.w), float(m.y + m.h))
        oid = params.get(OBJECT_ID, {}).get("id")
        out.append(
            RoiRecord(
                meta_id=int(m.id), label=label, box=tuple(round(float(v), 6) for v in box),  # hide 1-ulp normalisation noise
                confidence=float(det.get("confidence", 0.0)), label_id=int(det.get("label_id", -1)),
                object_id=None if oid is None else int(oid), params=params, index=index,
            )
        )
    return out


def has_rois(buffer: Gst.Buffer) -> bool:
    """Whether ``buffer`` carries any ROI meta (read nothing of it)."""
    return next(iter(_cgst.iter_roi_metas(buffer)), None) is not None


def hull_params(hull: np.ndarray | None) -> dict[str, dict[str, Any]] | None:
    """The ``"trafficcal-hull"`` parameter structure for a Kx2 hull (None for no hull)."""
    if hull is None:
        return None
    return {HULL: {"points": np.asarray(hull, np.float64).reshape(-1, 2).tolist()}}


def roi_hull(roi: RoiRecord) -> np.ndarray | None:
    """The ROI's convex hull (Kx2 frame pixels) from its ``"trafficcal-hull"`` structure, or None."""
    points = roi.params.get(HULL, {}).get("points")
    if not points:
        return None
    return np.asarray(points, np.float64).reshape(-1, 2)


def detections_from_rois(rois: Sequence[RoiRecord]) -> Detections:
    """The ROIs' boxes, confidences, labels and (when any ROI carries one) hulls as the library's
    :class:`Detections` (empty for no ROIs)."""
    from ..detection.records import Detections

    hulls = [roi_hull(r) for r in rois]
    return Detections(np.array([r.box for r in rois], np.float64).reshape(-1, 4),
                      np.array([r.confidence for r in rois], np.float64),
                      np.array([r.label_id for r in rois], np.int64),
                      np.array([r.label for r in rois], dtype=object),
                      hulls if any(h is not None for h in hulls) else None)


def update_roi_params(buffer: Gst.Buffer, index: int, name: str, fields: Mapping[str, Any]) -> None:
    """Replace (or add) parameter structure ``name`` of the ``index``-th ROI meta of ``buffer`` (attachment order:
    :attr:`RoiRecord.index`, what :func:`add_vehicle_roi` returns) — by place, not by the meta's id, which other
    detectors leave 0 on every ROI (every vehicle's data then went onto the first box).

    Updating "object_id" is how the tracker labels an existing detection.
    """
    _require_writable(buffer)
    for k, (addr, m) in enumerate(_cgst.iter_roi_metas(buffer)):
        if k == index:
            structure = make_structure(name, fields)
            _cgst.roi_remove_params(m, name)
            _cgst.roi_add_param(addr, structure)
            return
    raise KeyError(f"no region-of-interest meta number {index} on this buffer")
