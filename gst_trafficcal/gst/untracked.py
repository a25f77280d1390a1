"""Saying once, and why, when an element that needs tracked vehicles keeps getting none.

bbscale and an upstream-tracked speedometer read the tracker's parameter structures (``object_id``,
``trafficcal-vehicle``) on each vehicle's ROI meta.  A pipeline can deliver the ROIs without them and run on
silently with nothing measured: the tracker missing or placed before the detector, or an element between the tracker
and the reader that rebuilds the ROI metas without their parameters (GStreamer's videoconvert or videoscale changing
the format keeps the rectangles and labels only).  :class:`UntrackedWatch` tells those cases apart from an empty road.
"""

from __future__ import annotations

from dataclasses import dataclass

UNTRACKED_AFTER_S = 5.0
"""Stream seconds of vehicles without a tracker's id before the element says so (a tracker confirms a vehicle
within a second)."""


@dataclass
class UntrackedWatch:
    """Feed :meth:`check` every frame; it returns the warning to post, once, or None."""

    element: str
    after_s: float = UNTRACKED_AFTER_S
    said: bool = False  # the warning was given
    _since: float | None = None
    _done: bool = False

    def check(self, t: float, n_rois: int, n_tracked: int, tracker_upstream: bool) -> str | None:
        """``n_rois`` vehicles on this frame, ``n_tracked`` of them with a tracker's id and 3D box structure: the
        warning once vehicles have come for ``after_s`` seconds and none was tracked; never after a tracked one."""
        if self._done or n_rois == 0:
            return None
        if n_tracked:
            self._done = True
            return None
        if self._since is None:
            self._since = t
        if t - self._since < self.after_s:
            return None
        self._done = self.said = True
        what = f"{self.element}: vehicles have arrived for {t - self._since:.0f} s without a tracker's data " \
               f"(object_id, trafficcal-vehicle)"
        if tracker_upstream:
            return (f"{what} although a tracker runs upstream: the tracker must come after vehicledetect, and an "
                    f"element between the tracker and {self.element} that changes the video format (videoconvert, "
                    f"videoscale) keeps the vehicles' rectangles but drops that data; convert the format before "
                    f"vehicledetect or after {self.element}")
        return (f"{what}: nothing is measured from them; put a tracker before {self.element} "
                f"(... ! vehicledetect ! tracker ! {self.element} ! ...)")
