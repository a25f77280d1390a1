"""One time for a frame in elements on different branches of a ``tee``: what the elements have decided per segment.

The clock event (:mod:`.clock_event`) reaches the elements after the one that timed a frame after a jump, not those on
another branch of a ``tee`` before them: each first element of a branch would decide the time after a flushing seek
from the last frame *it* had seen — the branches' queues held different frames when the flush dropped them — and the
branches would give the same frame times seconds apart.  So the elements of a process share, per segment (its
seqnum, which a flushing seek gives every branch alike), the latest time any of them gave a frame in it and the
offset decided at the jump into it: the first element to time a frame after the seek goes on after the latest time
of the segment before, and every other one takes the offset it decided.  A source may perform one seek twice (asked
of a pipeline, it reaches the source from both sinks of a tee): two flushes with one seqnum, and a branch may have timed
frames between them; the offset is decided anew for each flush (keyed by the seqnum and the flushes of it seen), going
on after the latest time of the segment before and of this one.
"""

from __future__ import annotations

import threading
from collections import OrderedDict

KEEP = 256
"""Segments remembered (a seek makes one; only the last two of a stream are ever asked)."""


class SegmentClocks:
    """Per segment seqnum: the latest time given to a frame in it and the clock offset decided at the jump into it.
    Use it under :attr:`lock` (a decision and its record are one step for the elements of all branches)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self._reached: OrderedDict[int, float] = OrderedDict()
        self._decided: OrderedDict[tuple[int, int], float] = OrderedDict()

    def reached(self, seqnum: int | None) -> float | None:
        """The latest time any element gave a frame of segment ``seqnum``."""
        return None if seqnum is None else self._reached.get(seqnum)

    def reach(self, seqnum: int | None, t: float) -> None:
        """An element gave a frame of segment ``seqnum`` the time ``t``."""
        if seqnum is not None and t > self._reached.get(seqnum, float("-inf")):
            _put(self._reached, seqnum, t)

    def decided(self, key: tuple[int, int] | None) -> float | None:
        """The offset decided at the jump ``key`` = (segment seqnum, its flushes seen: a source may perform one seek
        twice, flushing twice with one seqnum) (None: not decided yet)."""
        return None if key is None else self._decided.get(key)

    def decide(self, key: tuple[int, int] | None, offset: float) -> None:
        if key is not None:
            _put(self._decided, key, offset)


def _put(table: OrderedDict, key, value: float) -> None:
    table[key] = value
    table.move_to_end(key)
    while len(table) > KEEP:
        table.popitem(last=False)


SEGMENTS = SegmentClocks()
"""The process's: every element's (Python elements of one pipeline run in one process)."""
