"""The background detector's peeled foreground as the tracker's background model (``tracker background=peeled``).

The tracker builds each vehicle's convex hull from a foreground mask.  Its own moving-average model removes cast
shadows pixel by pixel, which also removes grey vehicle faces; the background detector's shadow peeling
(:mod:`gst_trafficcal.detection.background`) removes only dark, smooth regions that reach a blob's outline.
:class:`PeeledBackground` gives the tracking pipeline that mask through :class:`BackgroundModel`'s interface
(``apply``, ``ready``, ``scale``, ``mask``).  It runs its own detector instance (the elements stay usable
separately); a caller that already runs ``BackgroundDetector(method="average")`` on the same frames can pass it
as ``detector`` and call :meth:`PeeledBackground.use` instead of ``apply``, so one model serves both.
"""

from __future__ import annotations

import numpy as np

from ..detection.background import BackgroundDetector
from ..errors import InputError


class PeeledBackground:
    """Foreground = the vehicles' pixels of a moving-average background detector with shadow peeling."""

    def __init__(self, detector: BackgroundDetector | None = None, work_width: int = 480) -> None:
        self.detector = detector or BackgroundDetector(method="average", work_width=work_width)
        if self.detector.method != "average" or not self.detector.peel:
            raise InputError("the peeled background needs BackgroundDetector(method='average', peel=True)")
        self.scale = 1.0  # full-resolution pixels per work pixel
        self.mask: np.ndarray | None = None

    def apply(self, gray: np.ndarray, chroma: np.ndarray | None = None) -> np.ndarray:
        """Feed one grey frame; the vehicles' mask (uint8 0/255) at the work size.  ``chroma`` is not used."""
        if gray.ndim != 2:
            raise InputError(f"background model needs a grey image (H x W), got shape {gray.shape}")
        self.detector(gray)
        return self.use()

    def use(self) -> np.ndarray:
        """The mask of the frame the detector processed last (when the caller ran the detector itself)."""
        self.scale = 1.0 / self.detector.scale
        self.mask = self.detector.last_core.view(np.uint8) * np.uint8(255)
        return self.mask

    @property
    def ready(self) -> bool:
        return self.detector.ready

    def reset(self) -> None:
        self.detector.reset()
