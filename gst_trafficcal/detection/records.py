"""The vehicle-observation record that flows from the detectors to the tracker, elements and sinks.

One :class:`Detections` holds every vehicle found in one frame as parallel arrays (in the spirit of
roboflow supervision's ``Detections``), so later stages filter, index and concatenate whole frames
with numpy instead of looping over Python objects.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterator

import numpy as np


@dataclass(frozen=True)
class Detection:
    """One vehicle: a convenience view of one row of :class:`Detections`."""

    box: tuple[float, float, float, float]  # x0, y0, x1, y1 in image pixels
    score: float
    class_id: int
    label: str
    hull: np.ndarray | None = field(default=None, compare=False)  # Kx2 convex hull (pixel centres at integers)


@dataclass
class Detections:
    """Vehicles found in one frame.

    ``boxes`` is an Nx4 float32 array of (x0, y0, x1, y1) image pixels, ``scores`` N confidences in
    0..1, ``class_ids`` N integer ids of the source model (COCO ids for the COCO detectors: car 2,
    motorcycle 3, bus 5, truck 7) and ``labels`` N vehicle labels ("car", "bus", ...).

    ``hulls`` is None (the detector gives boxes only) or N convex hulls, one per row: a Kx2 float64 array of
    image points (pixel centres at integers, as the tracker's hulls) or None for a row without an outline.  A
    segmentation detector fills it; the tracker then builds its 3D boxes from these outlines instead of its
    background model's.
    """

    boxes: np.ndarray
    scores: np.ndarray
    class_ids: np.ndarray
    labels: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=object))
    hulls: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.boxes = np.asarray(self.boxes, dtype=np.float32).reshape(-1, 4)
        n = len(self.boxes)
        self.scores = np.asarray(self.scores, dtype=np.float32).reshape(n)
        self.class_ids = np.asarray(self.class_ids, dtype=np.int64).reshape(n)
        labels = np.asarray(self.labels, dtype=object).reshape(-1)
        if len(labels) == 0 and n:
            labels = np.full(n, "", dtype=object)
        if len(labels) != n:
            raise ValueError(f"{len(labels)} labels for {n} boxes")
        self.labels = labels
        if self.hulls is not None:
            hulls = np.empty(n, dtype=object)
            given = list(self.hulls)
            if len(given) != n:
                raise ValueError(f"{len(given)} hulls for {n} boxes")
            for i, h in enumerate(given):
                if h is not None:
                    h = np.asarray(h, np.float64)
                    if h.ndim != 2 or h.shape[1] != 2 or len(h) < 1:
                        raise ValueError(f"hull {i} must be a Kx2 array of points, got shape {h.shape}")
                hulls[i] = h
            self.hulls = hulls

    @classmethod
    def empty(cls) -> "Detections":
        """A frame without vehicles."""
        return cls(np.zeros((0, 4), np.float32), np.zeros(0, np.float32), np.zeros(0, np.int64))

    @classmethod
    def merge(cls, parts: list["Detections"]) -> "Detections":
        """Concatenate several records (e.g. detections of image tiles) into one."""
        parts = [p for p in parts if len(p)]
        if not parts:
            return cls.empty()
        hulls = None
        if any(p.hulls is not None for p in parts):  # rows of parts without outlines get None
            hulls = [h for p in parts for h in (p.hulls if p.hulls is not None else [None] * len(p))]
        return cls(
            np.concatenate([p.boxes for p in parts]),
            np.concatenate([p.scores for p in parts]),
            np.concatenate([p.class_ids for p in parts]),
            np.concatenate([p.labels for p in parts]),
            hulls,
        )

    def __len__(self) -> int:
        return len(self.boxes)

    def __getitem__(self, index: int | slice | np.ndarray | list) -> "Detections":
        """Rows selected by an index, slice, integer array or boolean mask (always a record)."""
        if isinstance(index, (int, np.integer)):
            index = [int(index)]
        return Detections(self.boxes[index], self.scores[index], self.class_ids[index], self.labels[index],
                          None if self.hulls is None else self.hulls[index])

    def __iter__(self) -> Iterator[Detection]:
        hulls = self.hulls if self.hulls is not None else [None] * len(self)
        for box, score, cid, label, hull in zip(self.boxes, self.scores, self.class_ids, self.labels, hulls):
            yield Detection(tuple(float(v) for v in box), float(score), int(cid), str(label), hull)

    @property
    def centers(self) -> np.ndarray:
        """Nx2 box centres in pixels."""
        return (self.boxes[:, :2] + self.boxes[:, 2:]) / 2

    @property
    def bottom_centers(self) -> np.ndarray:
        """Nx2 centres of the bottom box edges (closest to the road) in pixels."""
        return np.stack([(self.boxes[:, 0] + self.boxes[:, 2]) / 2, self.boxes[:, 3]], axis=1)

    @property
    def widths(self) -> np.ndarray:
        return self.boxes[:, 2] - self.boxes[:, 0]

    @property
    def heights(self) -> np.ndarray:
        return self.boxes[:, 3] - self.boxes[:, 1]

    @property
    def areas(self) -> np.ndarray:
        return self.widths * self.heights

    def with_label(self, *labels: str) -> "Detections":
        """Only the vehicles carrying one of the given labels."""
        return self[np.isin(self.labels, list(labels))]

    def above(self, threshold: float) -> "Detections":
        """Only the vehicles scored at least ``threshold``."""
        return self[self.scores >= threshold]

    def scaled(self, sx: float, sy: float | None = None) -> "Detections":
        """The same detections with boxes multiplied by (sx, sy), e.g. to another frame size."""
        sy = sx if sy is None else sy
        hulls = None
        if self.hulls is not None:  # pixel centres at integers: the pixel edges scale, the centres follow
            s = np.array([sx, sy])
            hulls = [None if h is None else (h + 0.5) * s - 0.5 for h in self.hulls]
        return Detections(self.boxes * np.array([sx, sy, sx, sy], np.float32), self.scores, self.class_ids, self.labels,
                          hulls)

    def clipped(self, width: int, height: int) -> "Detections":
        """Boxes clipped to a width x height image; boxes left empty are dropped."""
        boxes = clip_boxes(self.boxes, width, height)
        keep = (boxes[:, 2] > boxes[:, 0]) & (boxes[:, 3] > boxes[:, 1])
        hulls = None
        if self.hulls is not None:
            lo, hi = np.array([-0.5, -0.5]), np.array([width - 0.5, height - 0.5])
            hulls = [None if h is None else h.clip(lo, hi) for h in self.hulls[keep]]
        return Detections(boxes[keep], self.scores[keep], self.class_ids[keep], self.labels[keep], hulls)


def clip_boxes(boxes: np.ndarray, width: float, height: float) -> np.ndarray:
    """Nx4 xyxy boxes cut to a width x height image (a copy, same dtype; a box wholly outside becomes empty)."""
    out = np.array(boxes, copy=True)
    out[:, [0, 2]] = out[:, [0, 2]].clip(0, width)
    out[:, [1, 3]] = out[:, [1, 3]].clip(0, height)
    return out


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Intersection over union of every box in ``a`` (Nx4 xyxy) with every box in ``b`` (Mx4): NxM."""
    a = np.asarray(a, np.float64).reshape(-1, 4)
    b = np.asarray(b, np.float64).reshape(-1, 4)
    lt = np.maximum(a[:, None, :2], b[None, :, :2])
    rb = np.minimum(a[:, None, 2:], b[None, :, 2:])
    inter = np.prod((rb - lt).clip(min=0), axis=2)
    area_a = np.prod(a[:, 2:] - a[:, :2], axis=1)
    area_b = np.prod(b[:, 2:] - b[:, :2], axis=1)
    union = area_a[:, None] + area_b[None, :] - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1), 0.0)
