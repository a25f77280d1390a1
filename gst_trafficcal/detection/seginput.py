"""The input of the learned vehicle segmenter: the frame and a running-average background at the work size.

Shared by the run-time detector (:mod:`.vehicleseg`) and the training-data generator (``training/vehicleseg``) so
the network is trained on exactly the images it sees at run time: the same reduction to the work size and the
same background, ghosts of passing vehicles included.

The background is a plain exponential running average (``cv2.accumulateWeighted``) with a time constant in
seconds (frame timestamps, so 12.5, 25 and 50 fps videos get the same background), started as the mean of the
first frames.  It has no selective update: a model-driven update would make the training background depend on
the model.  The network learns "changed and not a shadow or a ghost" from the pair.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..imaging import fit

STRIDE = 16  # the network's total stride: its input sides are padded to multiples of it


@dataclass(frozen=True)
class WorkGeometry:
    """Frame <-> work-image mapping: the frame reduced to ``width`` pixels wide (aspect kept), then its bottom and
    right padded to multiples of :data:`STRIDE` for the network."""

    frame_size: tuple[int, int]  # frame width, height
    width: int = 480

    @property
    def size(self) -> tuple[int, int]:
        """Work image (width, height) before padding."""
        w, h = self.frame_size
        return self.width, max(1, round(h * self.width / w))

    @property
    def padded(self) -> tuple[int, int]:
        """Network input (width, height)."""
        w, h = self.size
        return -(-w // STRIDE) * STRIDE, -(-h // STRIDE) * STRIDE

    @property
    def scale(self) -> tuple[float, float]:
        """Frame pixels per work pixel along x and y."""
        return self.frame_size[0] / self.size[0], self.frame_size[1] / self.size[1]


def to_work(image: np.ndarray, geometry: WorkGeometry) -> np.ndarray:
    """A BGR (or grey, converted) uint8 frame reduced to the work size (the ONNX detectors' resize: bilinear to
    twice the size, then area averaging)."""
    if image.ndim == 2:
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    if (image.shape[1], image.shape[0]) == geometry.size:
        return np.ascontiguousarray(image)
    return fit(image, geometry.size)


@dataclass
class RunningBackground:
    """Exponential running average of work images with time constant ``tau`` seconds.

    :meth:`update` returns the background *before* the frame is added (the past only; the first frame is its own
    background) and then adds the frame.  The first frames are averaged with weight 1/n until that is below the
    time constant's weight, so the start-up background is the mean of the first frames.  A timestamp that goes
    back or jumps by more than ``reset_gap`` seconds (a seek, a new clip) restarts the average.
    """

    tau: float = 2.0
    fps: float = 25.0  # assumed frame rate when no timestamps are given
    reset_gap: float = 10.0
    _acc: np.ndarray | None = field(default=None, repr=False)
    _t: float | None = field(default=None, repr=False)
    frames: int = 0

    def reset(self) -> None:
        self._acc, self._t, self.frames = None, None, 0

    def update(self, work: np.ndarray, t: float | None = None) -> np.ndarray:
        """The uint8 background for ``work`` (HxWx3 uint8) at time ``t`` seconds, then ``work`` is learned."""
        if t is None:
            t = self.frames / self.fps
        dt = None if self._t is None else t - self._t
        if self._acc is None or self._acc.shape != work.shape or dt is None or dt < 0 or dt > self.reset_gap:
            self._acc = work.astype(np.float32)
            self._t, self.frames = t, 1
            return work.copy()
        background = cv2.convertScaleAbs(self._acc)  # rounded and saturated to uint8
        self.frames += 1
        alpha = max(1.0 - math.exp(-max(dt, 1e-3) / self.tau), 1.0 / self.frames)
        cv2.accumulateWeighted(work, self._acc, alpha)
        self._t = t
        return background

    def image(self) -> np.ndarray | None:
        """The current background (uint8, work size), None before the first frame."""
        return None if self._acc is None else cv2.convertScaleAbs(self._acc)


def network_input(frame: np.ndarray, background: np.ndarray, geometry: WorkGeometry) -> np.ndarray:
    """1 x 6 x H x W float32 network input: frame BGR then background BGR, scaled to [-0.5, 0.5], padded at the
    bottom and right by edge replication to the network's stride.  Written channel-first straight into the
    output (a third of the time of concatenating, padding and converting the pair: 0.7 against 2.2 ms at
    480x272)."""
    w, h = geometry.size
    pw, ph = geometry.padded
    x = np.empty((1, 6, ph, pw), np.float32)
    for k, image in enumerate((frame, background)):
        np.multiply(image.transpose(2, 0, 1), np.float32(1.0 / 255.0), out=x[0, 3 * k:3 * k + 3, :h, :w])
    if ph > h:
        x[0, :, h:, :w] = x[0, :, h - 1:h, :w]
    if pw > w:
        x[0, :, :, w:] = x[0, :, :, w - 1:w]
    x -= 0.5
    return x
