"""The elements' clock after a jump, as a GStreamer event: one time for a frame in every element.

Each element times its frames with a :class:`~gst_trafficcal.gst.buffers.StreamClock` that never goes back: after
a seek back it goes on one frame interval after the last frame it saw.  After a flushing seek the elements have not
seen the same last frame — the frames on their way between them (many with a ``queue`` between) were flushed — so
each going on from its own would put a downstream element's time frames behind an upstream one's, and with it a
track's times in the tracker behind speedometer's.  Instead the first element that times a frame after a jump (a
flushing seek, or timestamps gone back) pushes, before that frame, the offset it gave the stream time::

    trafficcal-clock, offset=(double)3.04, seqnum=(uint)1234, time=(double)9.04

(``seqnum``: that of the segment the offset applies to, the seek's; ``time``: the time it gave the frame that
follows), and the elements downstream time the frames that follow by it (:meth:`StreamClock.follow`) and forward it.
Not sticky: it goes with the frame that follows it.  An element between that makes a segment of its own (another
seqnum: its stream times may be others, e.g. ``identity single-segment=true``) does not lose it: an element whose
segment is not the event's gives the frame that follows the event's ``time`` and goes on from there.
"""

from __future__ import annotations

from dataclasses import dataclass

from ._gi import GObject, Gst

STRUCTURE_NAME = "trafficcal-clock"


@dataclass(frozen=True)
class GivenClock:
    """What a :func:`clock_event` says: the offset of the stream time from the next frame on in the segment
    ``seqnum``, and ``time``, the time of that next frame (None from an event without it)."""

    offset: float
    seqnum: int
    time: float | None = None


def clock_event(offset: float, seqnum: int, time: float | None = None) -> Gst.Event:
    """A serialized custom downstream event: the stream time's offset from the next frame on, in the segment
    ``seqnum``; ``time``: the time given to that frame."""
    s = Gst.Structure.new_empty(STRUCTURE_NAME)
    s.set_value("offset", float(offset))  # a double: the very offset, so that every element rounds alike
    s.set_value("seqnum", _uint(seqnum))
    if time is not None:
        s.set_value("time", float(time))
    return Gst.Event.new_custom(Gst.EventType.CUSTOM_DOWNSTREAM, s)


def parse_clock_event(event: Gst.Event) -> GivenClock | None:
    """What a :func:`clock_event` says, or None for any other event."""
    if event.type != Gst.EventType.CUSTOM_DOWNSTREAM or not event.has_name(STRUCTURE_NAME):
        return None
    s = event.get_structure()
    ok, offset = s.get_double("offset")
    ok_seq, seqnum = s.get_uint("seqnum")
    ok_time, time = s.get_double("time")
    return GivenClock(offset, seqnum, time if ok_time else None) if ok and ok_seq else None


def _uint(value: int) -> GObject.Value:
    v = GObject.Value()
    v.init(GObject.TYPE_UINT)
    v.set_uint(int(value) & 0xFFFFFFFF)
    return v
