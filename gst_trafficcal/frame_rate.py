"""Requirements counted in frames, kept at low frame rates as durations (NVR substreams at 5–12 fps).

The tracker's and the speedometer's counts (hits before a track is confirmed, reference points before a vehicle is
measured) were set on 25 fps video.  Where frames are more than :data:`REFERENCE_SPACING` apart a count asks for
the time it spans at 25 fps instead (``count`` × :data:`FRAME_S_25`), in as many frames as that takes — never more
than the count, never fewer than a floor.  At 0.08 s and closer (12.5 fps and up: the 25 fps cameras and the
12.5 fps synthetic scenes the defaults were measured on) the count is unchanged, as vpdetect's ``frame_spacing``.
"""

from __future__ import annotations

import math
from collections import deque

REFERENCE_SPACING = 0.08  # seconds between frames at and below which every count holds as set
FRAME_S_25 = 0.04  # the time one counted frame stands for: the counts were set at 25 fps
STEPS = 25  # frame steps the stream's spacing is the median of


def frames_needed(count: int, spacing: float | None, floor: int) -> int:
    """``count`` for frames ``spacing`` seconds apart or closer than :data:`REFERENCE_SPACING` (or not known yet);
    further apart, the frames that cover ``count`` 25 fps frames' time (``count`` × 0.04 s), between ``floor`` and
    ``count``."""
    if spacing is None or not spacing > REFERENCE_SPACING * (1 + 1e-3):  # 12.5 fps timestamps' rounding: as set
        return count
    return min(count, max(floor, math.ceil(count * FRAME_S_25 / spacing - 1e-9)))


class FrameSpacing:
    """The stream's time between frames: the median of its last :data:`STEPS` steps (a dropped frame or a jump
    moves it not; a stream's own rate, not a track's, whose detections may be missed)."""

    def __init__(self) -> None:
        self._steps: deque[float] = deque(maxlen=STEPS)
        self._t: float | None = None

    def add(self, t: float) -> None:
        """A frame at stream time ``t`` (seconds)."""
        if self._t is not None and t > self._t:
            self._steps.append(t - self._t)
        self._t = t

    @property
    def seconds(self) -> float | None:
        """Median step, None before two frames."""
        if not self._steps:
            return None
        s = sorted(self._steps)
        return s[len(s) // 2]
