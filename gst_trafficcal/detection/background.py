"""Weight-free vehicle detector: foreground blobs of a background model (the built-in default).

The frame is reduced to a small working size and compared with a background model:

* ``mog2`` (default, 320 px): OpenCV's MOG2 with its shadow label discarded (the label also swallows grey
  vehicles on a grey road);
* ``average`` (480 px): the tracker's moving-average model (:class:`~gst_trafficcal.tracking.background.
  BackgroundModel`: temporal-median start, selective update, |frame - background| threshold) without its
  per-pixel shadow test, followed by **shadow peeling** (below). Better boxes (recall 0.58 -> 0.74 at IoU 0.5
  on held-out synth and replay scenes, cast shadows off the box) but not yet the default: on the demo scene the
  speeds it leads to are worse (docs/detectors.md).

Shadow peeling.  A per-pixel shadow test ("darker by a locally constant factor") cannot tell a cast shadow
from a grey or dark vehicle face on a grey road (both are uniformly darker than the road), and it removes
whole grey vehicles.  So every blob of the change mask is kept as one vehicle (the grouping), and only its
box is tightened: shadow candidates (frame/background ratio in ``shadow_ratio`` and smooth: the ratio within
``shadow_dev`` of its local mean) that form a region reaching the blob's outline (within ``shadow_ring``
work pixels of the unchanged road) are peeled off — a cast shadow or the dark contact shadow under a vehicle
lies at the blob's edge, a vehicle's uniform faces are mostly enclosed by its outline, windows and lights.
The thin penumbra left between a peeled shadow and the road is cut too.  When peeling would leave less than
``core_min`` of the blob (a dark vehicle: it is dark and smooth everywhere), the whole blob's box is kept.

Each blob's box becomes a detection labelled "car" with the fill ratio of its kept pixels as confidence.
Pixel sizes say little about vehicle class without a calibration, so no size-based class is guessed here.
The model needs a warm-up (``warmup`` frames for the moving average, about ``history`` for MOG2) before the
background is clean; nothing is reported during the moving average's warm-up.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

from ..tracking.background import BackgroundModel
from .labels import COCO_VEHICLES
from .records import Detections

CAR_ID = next(cid for cid, name in COCO_VEHICLES.items() if name == "car")


class BackgroundDetector:
    """Moving blobs -> boxes. Call once per frame, in order (the model learns from every frame).

    ``work_width``: processing width in pixels (height keeps the aspect ratio; default 320 for MOG2, 480 for the
    moving average); ``method``: "mog2" or "average"; ``min_area``: smallest blob as a fraction of the frame area; ``threshold``: minimum confidence
    (fill ratio of the box); ``mask``: optional HxW uint8 image, zero where vehicles must be ignored (any size,
    it is resized); ``peel``: peel cast shadows off the blobs' boxes (see the module docstring).
    """

    def __init__(
        self,
        work_width: int | None = None,
        method: str = "mog2",
        history: int = 300,
        alpha: float = 0.02,
        diff_threshold: float = 22.0,
        min_area: float = 0.0015,
        threshold: float = 0.0,
        mask: np.ndarray | None = None,
        peel: bool = True,
        shadow_ratio: tuple[float, float] = (0.15, 0.95),
        shadow_dev: float = 0.03,
        shadow_ring: int = 3,
        core_min: float = 0.4,
    ) -> None:
        if method not in ("mog2", "average"):
            raise ValueError(f"unknown background method {method!r} (average or mog2)")
        self.work_width = int(work_width if work_width is not None else (320 if method == "mog2" else 480))
        self.method = method
        self.history = history
        self.alpha = float(alpha)
        self.diff_threshold = float(diff_threshold)
        self.min_area = float(min_area)
        self.threshold = float(threshold)
        self.user_mask = mask
        self.peel = bool(peel) and method == "average"
        self.shadow_ratio = shadow_ratio
        self.shadow_dev = float(shadow_dev)
        self.shadow_ring = int(shadow_ring)
        self.core_min = float(core_min)
        self.last_core: np.ndarray | None = None  # the vehicles' pixels of the last frame (peeled blobs), work size
        self._reset(None)

    def reset(self) -> None:
        """Forget the background (a new video, or the camera moved): learnt again from the next frame."""
        self._reset(None)

    def _reset(self, shape: tuple[int, int] | None) -> None:
        self.shape = shape
        self.frames = 0
        self._mog = None
        self._model = None
        self._mask = None
        if shape is None:
            return
        h, w = shape
        self.scale = self.work_width / w if w > self.work_width else 1.0
        self.size = (max(1, round(w * self.scale)), max(1, round(h * self.scale)))
        k = max(3, int(round(self.size[0] / 160)) | 1)
        self._open = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
        self._close = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3 * k, 3 * k))
        if self.method == "mog2":
            self._mog = cv2.createBackgroundSubtractorMOG2(history=self.history, varThreshold=16, detectShadows=True)
        else:
            self._model = BackgroundModel(work_width=self.work_width, alpha=self.alpha,
                                          threshold=self.diff_threshold, shadows=False, close_px=3,
                                          keep_ratio=self.peel)
        r = self.shadow_ring
        self._ring = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        self._cut = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
        self._small_open = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
        if self.user_mask is not None:
            self._mask = cv2.resize(self.user_mask, self.size, interpolation=cv2.INTER_NEAREST) > 0

    @property
    def ready(self) -> bool:
        """True once the background model has finished its warm-up."""
        return self._model.ready if self._model is not None else self.frames > 0

    def foreground(self, image: np.ndarray) -> np.ndarray:
        """Update the model with a grey or BGR frame; return its foreground (change) mask at working size,
        cast shadows included (they are peeled off the boxes, not the mask)."""
        if image.ndim == 3:
            image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        if self.shape != image.shape[:2]:
            self._reset(image.shape[:2])
        self.frames += 1
        if self._model is not None:
            fg = self._model.apply(image)
            size = (fg.shape[1], fg.shape[0])
            if size != self.size:  # the model rounds its working size its own way
                self.size, self.scale = size, fg.shape[1] / image.shape[1]
                if self.user_mask is not None:
                    self._mask = cv2.resize(self.user_mask, self.size, interpolation=cv2.INTER_NEAREST) > 0
        else:
            small = cv2.resize(image, self.size, interpolation=cv2.INTER_AREA) if self.scale != 1.0 else image
            small = cv2.GaussianBlur(small, (3, 3), 0)
            fg = self._mog.apply(small)
            fg = np.where(fg == 255, np.uint8(255), np.uint8(0))  # 127 = shadow
            fg = cv2.morphologyEx(fg, cv2.MORPH_OPEN, self._open)
            fg = cv2.morphologyEx(fg, cv2.MORPH_CLOSE, self._close)
        if self._mask is not None:
            fg[~self._mask] = 0
        return fg

    def shadows(self, fg: np.ndarray, ratio: np.ndarray) -> np.ndarray:
        """Boolean mask of the cast-shadow pixels of ``fg`` (work size) to peel off: dark, smooth ratio regions
        that reach the blob's outline."""
        lo, hi = self.shadow_ratio
        fgb = fg > 0
        dev = np.abs(ratio - cv2.blur(ratio, (5, 5)))
        cand = (ratio > lo) & (ratio < hi) & (dev < self.shadow_dev) & fgb
        near = cv2.dilate((~fgb).view(np.uint8), self._ring) > 0
        n, lab = cv2.connectedComponents(cand.view(np.uint8), connectivity=8)
        hit = np.zeros(n, bool)
        hit[lab[cand & near]] = True
        hit[0] = False
        shadow = hit[lab]
        # the penumbra between a peeled shadow and the road (a thin ring the smoothness test rejects)
        ring = near & (cv2.dilate(shadow.view(np.uint8), self._cut) > 0)
        return shadow | (ring & fgb)

    def __call__(self, image: np.ndarray) -> Detections:
        """Vehicles (moving blobs) in a grey or BGR frame, boxes in that frame's pixels."""
        fg = self.foreground(image)
        self.last_core = np.zeros(fg.shape, bool)
        if not self.ready:
            return Detections.empty()
        n, lab, stats, _ = cv2.connectedComponentsWithStats(fg, connectivity=8)
        if n <= 1:
            return Detections.empty()
        area = stats[1:, cv2.CC_STAT_AREA].astype(np.float64)
        x, y, w, h = (stats[1:, i].astype(np.float64) for i in range(4))
        boxes = np.stack([x, y, x + w, y + h], axis=1)
        kept = area.copy()
        if self.peel and self._model is not None and self._model.ratio is not None:
            core = (fg > 0) & ~self.shadows(fg, self._model.ratio)
            core = cv2.morphologyEx(core.view(np.uint8), cv2.MORPH_OPEN, self._small_open) > 0
            core_lab = np.where(core, lab, 0)
            sl = ndimage.find_objects(core_lab, max_label=n - 1)
            core_area = np.bincount(core_lab.ravel(), minlength=n)[1:].astype(np.float64)
            whole = np.ones(n, bool)  # blobs kept whole (peeling would leave too little)
            whole[0] = False
            for j, s in enumerate(sl):
                if s is not None and core_area[j] >= self.core_min * area[j]:
                    boxes[j] = (s[1].start, s[0].start, s[1].stop, s[0].stop)
                    kept[j] = core_area[j]
                    whole[j + 1] = False
            self.last_core = core | whole[lab]
        else:
            self.last_core = fg > 0
        fill = np.minimum(kept / np.maximum((boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1]), 1.0), 1.0)
        keep = (area >= self.min_area * fg.size) & (fill >= self.threshold)
        boxes = boxes[keep] / self.scale
        k = int(keep.sum())
        return Detections(boxes, fill[keep], np.full(k, CAR_ID), np.full(k, "car", dtype=object))
