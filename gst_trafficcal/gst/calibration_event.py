"""The per-stream calibration as a GStreamer event and bus message.

The calibration travels downstream as a *sticky custom downstream event* whose structure is::

    trafficcal-calibration, id=(string)3f1a2b4c5d6e, state=(string)calibrated, source=(string)vpdetect,
        width=(int)1920, height=(int)1080,
        vp1_x=(double)..., vp1_y=(double)..., vp2_x=(double)..., vp2_y=(double)...,
        pp_x=(double)..., pp_y=(double)..., focal=(double)..., scale=(double)...,
        confidence_vp1=(double)..., reason=(string)...

Flat doubles (not arrays) so ``gst-launch-1.0 -m`` prints it readably on one line and any
language reads it with ``gst_structure_get_double``. The point/focal/scale fields are absent
while the state is "learning" (or "failed"), ``scale`` is absent until it is known, ``reason``
only when set, and there is one ``confidence_<name>`` per entry of ``Calibration.confidence``; a calibration
learnt by ``vpdetect`` also carries ``view_png`` (a 160-px grey thumbnail of the scene it was learnt on, base64
PNG, ~14 kB) and ``view_width`` (``Calibration.view``; ``vanishing/view.py``); the "learning" calibration
vpdetect announces when it notices that the camera moved carries ``moved_at`` (stream seconds).
Being sticky, a new event replaces the previous one and reaches elements linked later.
The same structure is posted on the bus as an element message.
"""

from __future__ import annotations

from typing import Any

from ..calibration import FORMAT, VERSION, Calibration
from ._gi import Gst
from .meta import make_structure

STRUCTURE_NAME = "trafficcal-calibration"
_CONF_PREFIX = "confidence_"


def calibration_structure(cal: Calibration) -> Gst.Structure:
    """The ``trafficcal-calibration`` structure describing ``cal``."""
    fields: dict[str, Any] = {
        "id": cal.id, "state": cal.state, "source": cal.source,
        "width": int(cal.image_size[0]), "height": int(cal.image_size[1]),
    }
    if cal.camera is not None:
        c = cal.camera
        for name, point in (("vp1", c.vp1), ("vp2", c.vp2), ("pp", c.pp)):
            fields[f"{name}_x"], fields[f"{name}_y"] = float(point[0]), float(point[1])
        fields["focal"] = float(c.focal)
        fields["scale"] = None if c.scale is None else float(c.scale)
    for key, value in cal.confidence.items():
        fields[_CONF_PREFIX + key] = float(value)
    if cal.reason:
        fields["reason"] = cal.reason
    if cal.moved_at is not None:  # vpdetect noticed the camera move (then): what came before is another view
        fields["moved_at"] = float(cal.moved_at)
    if cal.view is not None:  # the scene it was learnt on, so that whoever saves it can check a moved camera later
        fields["view_png"], fields["view_width"] = str(cal.view["png"]), int(cal.view["frame_width"])
    return make_structure(STRUCTURE_NAME, fields)


def calibration_from_structure(s: Gst.Structure) -> Calibration:
    """Inverse of :func:`calibration_structure` (validated like a calibration file)."""
    if s.get_name() != STRUCTURE_NAME:
        raise ValueError(f"not a {STRUCTURE_NAME} structure: {s.get_name()}")
    values = {s.nth_field_name(i): s.get_value(s.nth_field_name(i)) for i in range(s.n_fields())}
    d: dict[str, Any] = {
        "format": FORMAT, "version": VERSION, "state": values.get("state", "calibrated"),
        "source": values.get("source", "unknown"),
        "image_size": [values.get("width"), values.get("height")],
        "confidence": {k[len(_CONF_PREFIX):]: v for k, v in values.items() if k.startswith(_CONF_PREFIX)},
    }
    if "vp1_x" in values:
        for name in ("vp1", "vp2", "pp"):
            d[name] = [values.get(f"{name}_x"), values.get(f"{name}_y")]
        d["scale"] = values.get("scale")
    for key in ("reason", "moved_at"):
        if key in values:
            d[key] = values[key]
    if "view_png" in values:
        d["view"] = {"png": values["view_png"], "frame_width": values.get("view_width")}
    return Calibration.from_dict(d, where=f"{STRUCTURE_NAME} event")


def calibration_event(cal: Calibration) -> Gst.Event:
    """A sticky custom downstream event carrying ``cal`` (push it on a src pad)."""
    return Gst.Event.new_custom(Gst.EventType.CUSTOM_DOWNSTREAM_STICKY, calibration_structure(cal))


def parse_calibration_event(event: Gst.Event) -> Calibration | None:
    """The calibration carried by ``event``, or None when it is any other event."""
    if event.type != Gst.EventType.CUSTOM_DOWNSTREAM_STICKY or not event.has_name(STRUCTURE_NAME):
        return None
    return calibration_from_structure(event.get_structure())


def calibration_message(element: Gst.Element, cal: Calibration) -> Gst.Message:
    """An element message (structure ``trafficcal-calibration``) for the bus, from ``element``."""
    return Gst.Message.new_element(element, calibration_structure(cal))


def parse_calibration_message(message: Gst.Message) -> Calibration | None:
    """The calibration carried by a bus message, or None for any other message."""
    if message.type != Gst.MessageType.ELEMENT:
        return None
    s = message.get_structure()
    if s is None or s.get_name() != STRUCTURE_NAME:
        return None
    return calibration_from_structure(s)
