"""One call per frame: background model -> blobs grouped by detections -> convex hulls -> tracker.

This is the library stage that the ``tracker`` element wraps and that ``speedometer`` runs itself when no
tracker ran upstream, so both give the same tracks.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..detection.records import Detections
from ..geometry import Camera
from .background import BackgroundModel, blob_boxes, group_hulls
from .tracker import FrameResult, Track, Tracker, TrackerConfig


@dataclass
class TrackingPipeline:
    """Background model + tracker.  Without detections the foreground blobs themselves are the vehicles."""

    config: TrackerConfig = field(default_factory=TrackerConfig)
    background: BackgroundModel | None = field(default_factory=BackgroundModel)
    min_blob_area: float = 400.0  # full-resolution pixels, for the detector-free mode

    def __post_init__(self) -> None:
        self.tracker = Tracker(self.config)

    @property
    def camera(self) -> Camera | None:
        return self.tracker.camera

    def set_camera(self, camera: Camera | None) -> None:
        self.tracker.set_camera(camera)

    def process(self, gray: np.ndarray | None, t: float, detections: Detections | None = None,
                camera: Camera | None = None,
                hulls: list[np.ndarray | None] | None = None,
                chroma: np.ndarray | None = None) -> tuple[FrameResult, Detections]:
        """Track one frame at time ``t`` (seconds).  Returns the association and the detections used.

        ``gray`` may be None when only boxes are available (no hulls: the 3D boxes then come from the boxes'
        rectangles, which is coarser).  ``hulls`` (one per detection, e.g. from an instance-segmentation model;
        by default the detections' own ``hulls`` when they carry them) replace the background model's, which is then
        not run on this frame (rows without a hull get their box as hull).  A ``camera`` different from the current one switches the tracker to it.
        ``chroma`` (the frame's U and V planes, H' x W' x 2, see ``background.chroma_from_bgr``) turns on the background model's
        colour tests (cleaner vehicle outlines: cast shadows are told from dark vehicle faces by their colour).
        """
        if camera is not None and camera is not self.tracker.camera:
            self.tracker.set_camera(camera)
        mask = None
        scale = 1.0
        size = None
        if hulls is None and detections is not None and detections.hulls is not None:
            hulls = list(detections.hulls)
        silhouettes = hulls is not None  # a segmentation's outlines, not the background model's (cast shadows)
        if gray is not None:
            size = (gray.shape[1], gray.shape[0])
            if self.background is not None and hulls is None:
                mask = self.background.apply(gray, chroma)
                scale = self.background.scale
                if not self.background.ready:
                    mask = None
        if detections is None:
            if mask is None:
                detections = Detections.empty()
            else:
                boxes = blob_boxes(mask, scale, self.min_blob_area)
                detections = Detections(boxes, np.ones(len(boxes)), np.full(len(boxes), 2),
                                        np.full(len(boxes), "car", dtype=object))
        if hulls is not None:
            if detections is None or len(hulls) != len(detections):
                raise ValueError("hulls need detections, one hull per detection")
        elif mask is not None:
            hulls = group_hulls(mask, detections.boxes, scale)
        else:
            hulls = [None] * len(detections)
        hulls = [h if h is not None else _box_hull(b) for h, b in zip(hulls, detections.boxes)]
        return self.tracker.update(t, detections, hulls, image_size=size, silhouettes=silhouettes), detections

    def flush(self) -> list[Track]:
        return self.tracker.flush()

    def pop_finished(self) -> list[Track]:
        return self.tracker.pop_finished()

    def camera_moved(self) -> list[Track]:
        """The camera moved: every track ends (:meth:`Tracker.camera_moved`) and the background model starts
        again from the next frame (the old view's background would be foreground everywhere for seconds)."""
        if self.background is not None:
            self.background.reset()
        return self.tracker.camera_moved()


def _box_hull(box: np.ndarray) -> np.ndarray:
    x0, y0, x1, y1 = np.asarray(box, np.float64)
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
