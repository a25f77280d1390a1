"""A finished vehicle as a GStreamer event: what ``speedometer`` tells the elements downstream of it.

When a vehicle leaves, ``speedometer`` posts a ``trafficcal-speed`` bus message and also pushes the same structure
downstream as a *serialized custom downstream event* (before the buffer it left in, or before EOS)::

    trafficcal-speed, id=(int)17, label=(string)car, speed_kmh=(double)83.4, lane=(int)1,
        direction=(string)towards_vp1, calibration_id=(string)3f1a2b4c5d6e, ...

(every field of the vehicle's event, ``outputs.VehicleEvent``; absent where it is null), and
``merged_ids=(int)< 92 >`` when earlier tracks of the same vehicle (lost by the detector for a moment, given a new id
by the tracker) were measured with it: they are not vehicles of their own. A vehicle measured again with a later
calibration (the ``remeasure`` property) comes again with ``revised=(boolean)true``.

Tracks that speedometer found to be no vehicle passing (``measurement.not_a_vehicle``: seen for an instant, or
never moving) come as ``trafficcal-not-vehicles, ids=(int)< 12, 15 >``: a counter downstream takes them out.

Why an event: a vehicle that left before the calibration converged had no direction, lane or speed while it was in
view; it gets them only when speedometer measures it later. ``trafficoverlay`` counts such vehicles by their final
values instead of as "unknown", and a vehicle seen as two tracks once
(:meth:`gst_trafficcal.overlay.VehicleCounter.left`). Not sticky: each event is one
vehicle, and an element linked later has not seen it go by.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ._gi import Gst
from .meta import make_structure, structure_to_dict

STRUCTURE_NAME = "trafficcal-speed"
NOT_VEHICLES_NAME = "trafficcal-not-vehicles"


def vehicle_left_event(fields: Mapping[str, Any]) -> Gst.Event:
    """A serialized custom downstream event carrying one finished vehicle's fields (its event as a dict)."""
    return Gst.Event.new_custom(Gst.EventType.CUSTOM_DOWNSTREAM, make_structure(STRUCTURE_NAME, fields))


def parse_vehicle_left_event(event: Gst.Event) -> dict[str, Any] | None:
    """The fields of a finished vehicle's event, or None for any other event."""
    if event.type != Gst.EventType.CUSTOM_DOWNSTREAM or not event.has_name(STRUCTURE_NAME):
        return None
    return structure_to_dict(event.get_structure())


def not_vehicles_event(ids: list[int]) -> Gst.Event:
    """A serialized custom downstream event naming tracks that were no vehicle passing."""
    return Gst.Event.new_custom(Gst.EventType.CUSTOM_DOWNSTREAM,
                                make_structure(NOT_VEHICLES_NAME, {"ids": [int(i) for i in ids]}))


def parse_not_vehicles_event(event: Gst.Event) -> list[int] | None:
    """The track ids of a :func:`not_vehicles_event`, or None for any other event."""
    if event.type != Gst.EventType.CUSTOM_DOWNSTREAM or not event.has_name(NOT_VEHICLES_NAME):
        return None
    ids = structure_to_dict(event.get_structure()).get("ids") or []
    return [i for i in (ids if isinstance(ids, list) else [ids]) if isinstance(i, int)]
