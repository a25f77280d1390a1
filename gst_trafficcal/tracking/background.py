"""Moving-average background model and the grouping of foreground blobs by detections (paper §4.2).

The model runs at a reduced resolution (cheap, and it smooths noise): a float background image updated with
``cv2.accumulateWeighted``, foreground = |frame − background| above a threshold, cleaned by morphology.
The detector's boxes then say which blobs belong to one vehicle; the convex hull of each group is what the
3D box is built from.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import InputError


@dataclass
class BackgroundModel:
    """Running-average background of a grey video at ``work_width`` pixels wide.

    ``alpha`` is the learning rate per frame of background pixels; foreground pixels learn at ``foreground_rate``
    times that rate, so a passing vehicle leaves no trail while a parked one (or a ghost of a vehicle present in the
    first frame) fades into the background within seconds; ``threshold`` is the grey-level difference that makes
    a pixel foreground; cast shadows (darker by a locally constant factor) are not foreground (``shadows``);
    the background starts as the temporal median of the first ``warmup`` frames (so
    vehicles present at the start leave no ghosts).
    """

    work_width: int = 480
    alpha: float = 0.02
    threshold: float = 22.0
    warmup: int = 25
    open_px: int = 3
    close_px: int = 7
    foreground_rate: float = 0.25  # learning rate of foreground pixels relative to alpha
    shadows: bool = True  # remove cast shadows from the foreground
    shadow_ratio: tuple[float, float] = (0.3, 0.92)  # frame/background brightness of a shadow
    shadow_std: float = 0.04  # maximum local spread of that ratio (window ``shadow_window`` work pixels)
    shadow_window: int = 5
    chroma_threshold: float = 14.0  # colour difference (U/V levels) that makes a pixel foreground
    chroma_rel_threshold: float = 0.12  # ... or colour difference relative to the brightness (dark faces)
    chroma_tolerance: float = 5.0  # colour deviation (U/V levels) a cast shadow may have from the darkened road
    chroma_rel_tolerance: float = 0.06  # ... and relative to the pixel's brightness
    colour_shadow_std: float | None = None  # spread test in the colour mode too (over the window's candidates)
    colour_shadow_ratio: tuple[float, float] = (0.1, 0.92)  # shadow_ratio of the colour test
    shadow_min_support: float = 0.3  # fraction of the ratio window that must be shadow candidates
    keep_ratio: bool = False  # keep frame/background of the last frame in ``ratio`` (the detector's shadow peeling)

    def __post_init__(self) -> None:
        if self.work_width < 16:
            raise InputError(f"background work width must be at least 16 pixels, got {self.work_width}")
        if not 0 < self.alpha < 1:
            raise InputError(f"background learning rate must be in (0, 1), got {self.alpha}")
        self._bg: np.ndarray | None = None
        self._frames = 0
        self._size: tuple[int, int] | None = None
        self.scale = 1.0  # full-resolution pixels per work pixel
        self._open = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (self.open_px, self.open_px))
        self._close = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (self.close_px, self.close_px))
        self._grow = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (self.shadow_window, self.shadow_window))
        self.mask: np.ndarray | None = None
        self._first: list[np.ndarray] = []
        self._bg_uv: np.ndarray | None = None
        self._first_uv: list[np.ndarray] = []
        self.ratio: np.ndarray | None = None

    def reset(self) -> None:
        self._bg = None
        self._bg_uv = None
        self._frames = 0
        self._first = []
        self._first_uv = []

    def _small(self, gray: np.ndarray) -> np.ndarray:
        if gray.ndim != 2:
            raise InputError(f"background model needs a grey image (H x W), got shape {gray.shape}")
        h, w = gray.shape
        if self._size != (w, h):
            self._size = (w, h)
            self.scale = max(1.0, w / self.work_width)
            self.reset()
        if self.scale == 1.0:
            return gray.astype(np.float32)
        size = (int(round(w / self.scale)), int(round(h / self.scale)))
        return cv2.resize(gray, size, interpolation=cv2.INTER_AREA).astype(np.float32)

    def _small_uv(self, chroma: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """Colour-difference planes (U, V, any resolution) at the work size, centred on 0."""
        chroma = np.asarray(chroma)
        if chroma.ndim != 3 or chroma.shape[2] != 2:
            raise InputError(f"background model needs chroma as H x W x 2 (U, V), got shape {chroma.shape}")
        h, w = shape
        uv = cv2.resize(chroma, (w, h), interpolation=cv2.INTER_AREA).astype(np.float32) - 128.0
        return cv2.GaussianBlur(uv, (3, 3), 0)

    def apply(self, gray: np.ndarray, chroma: np.ndarray | None = None) -> np.ndarray:
        """Feed one grey frame (the Y plane); returns the foreground mask (uint8 0/255) at the work resolution.

        ``chroma`` (optional, H' x W' x 2 uint8: the frame's U and V planes at any resolution, e.g. I420's
        half-size planes) enables the colour tests: a pixel whose colour changed is foreground even at the road's
        brightness, and a cast shadow must keep the road's chromaticity (darkened, not recoloured), which tells
        it from a dark vehicle face without a window that straddles the vehicle's edge.
        """
        small = cv2.GaussianBlur(self._small(gray), (3, 3), 0)
        uv = self._small_uv(chroma, small.shape) if chroma is not None else None
        if self._bg is None:
            self._bg = small.copy()
        if uv is not None and self._bg_uv is None:
            self._bg_uv = uv.copy()
        diff = cv2.absdiff(small, self._bg)
        changed = diff > self.threshold
        if self.keep_ratio:
            self.ratio = small / cv2.max(self._bg, 1.0)
        if uv is not None:
            cdiff = _max_channel(cv2.absdiff(uv, self._bg_uv))
            changed |= cdiff > np.maximum(self.chroma_threshold,
                                          self.chroma_rel_threshold * cv2.max(cv2.max(small, self._bg), 16.0))
        if self.shadows:
            changed &= ~self._shadow(small, uv)
        fg = changed.astype(np.uint8) * 255
        fg = cv2.morphologyEx(fg, cv2.MORPH_OPEN, self._open)
        fg = cv2.morphologyEx(fg, cv2.MORPH_CLOSE, self._close)
        self._frames += 1
        if self._frames <= self.warmup:
            # the first frames: the background is their temporal median (vehicles passing are not in it)
            self._first.append(small)
            if uv is not None:
                self._first_uv.append(uv)
            if self._frames == self.warmup or self._frames % 5 == 0:
                self._bg = np.median(np.stack(self._first), axis=0).astype(np.float32)
                if uv is not None and len(self._first_uv) == len(self._first):
                    self._bg_uv = np.median(np.stack(self._first_uv), axis=0).astype(np.float32)
            if self._frames == self.warmup:
                self._first = []
                self._first_uv = []
        else:
            back = cv2.bitwise_not(fg)
            cv2.accumulateWeighted(small, self._bg, self.alpha, mask=back)
            cv2.accumulateWeighted(small, self._bg, self.alpha * self.foreground_rate, mask=fg)
            if uv is not None:
                cv2.accumulateWeighted(uv, self._bg_uv, self.alpha, mask=back)
                cv2.accumulateWeighted(uv, self._bg_uv, self.alpha * self.foreground_rate, mask=fg)
        self.mask = fg
        return fg

    def _shadow(self, small: np.ndarray, uv: np.ndarray | None = None) -> np.ndarray:
        """Cast shadows: darker than the background by a locally constant factor (the road's texture shows
        through), unlike a vehicle, whose ratio to the road behind it varies from pixel to pixel.

        With colour (``uv``) a shadow candidate must also keep the road's chromaticity (U, V scaled by the same
        factor as Y), and the ratio's spread is taken over the candidates of the window only, so a shadow pixel
        next to a (coloured) vehicle is not kept because its window reaches into the vehicle.
        """
        ratio = small / np.maximum(self._bg, 1.0)
        k = (self.shadow_window, self.shadow_window)
        colour = uv is not None and self._bg_uv is not None
        lo, hi = self.colour_shadow_ratio if colour else self.shadow_ratio
        dark = (ratio > lo) & (ratio < hi)
        if not colour:
            mean = cv2.blur(ratio, k)
            var = cv2.blur(ratio * ratio, k) - mean * mean
            core = (dark & (var < self.shadow_std ** 2)).astype(np.uint8)
        else:
            # chromaticity kept: only at the darkened pixels (a small part of the frame), for speed
            idx = np.flatnonzero(dark)
            r = ratio.reshape(-1)[idx]
            dev = np.abs(uv.reshape(-1, 2)[idx] - r[:, None] * self._bg_uv.reshape(-1, 2)[idx]).max(axis=1)
            tol = np.minimum(self.chroma_tolerance, self.chroma_rel_tolerance * np.maximum(small.reshape(-1)[idx], 16.0))
            dark = np.zeros(dark.shape, bool)
            dark.reshape(-1)[idx[dev < tol]] = True
            m = dark.astype(np.float32)
            support = cv2.blur(m, k)
            core = dark & (support >= self.shadow_min_support)
            if self.colour_shadow_std is not None:
                r = ratio * m
                sm = np.maximum(support, 1e-6)
                mean = cv2.blur(r, k) / sm
                var = cv2.blur(r * ratio, k) / sm - mean * mean
                core &= var < self.colour_shadow_std ** 2
            core = core.astype(np.uint8)
        # the penumbra around a shadow's core varies too much for the test: grow the core over darkened pixels
        grown = cv2.dilate(core, self._grow) > 0
        return dark & grown

    @property
    def ready(self) -> bool:
        """True once the background has seen enough frames to be trusted."""
        return self._frames > self.warmup

    def background(self) -> np.ndarray | None:
        """The current background image (uint8, work resolution)."""
        return None if self._bg is None else np.clip(self._bg, 0, 255).astype(np.uint8)


def _max_channel(a: np.ndarray) -> np.ndarray:
    """Per-pixel maximum over the two channels of an H x W x 2 image."""
    u, v = cv2.split(a)
    return cv2.max(u, v)


def blob_boxes(mask: np.ndarray, scale: float = 1.0, min_area: float = 150.0) -> np.ndarray:
    """Bounding boxes (Nx4 xyxy, full-resolution pixels) of the connected foreground blobs of ``mask``.

    ``min_area`` is in full-resolution pixels.  This is the detector-free fallback: one blob = one vehicle.
    """
    n, _, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    stats = stats[1:]
    keep = stats[:, cv2.CC_STAT_AREA] * scale * scale >= min_area
    s = stats[keep].astype(np.float64)
    boxes = np.stack([s[:, 0], s[:, 1], s[:, 0] + s[:, 2], s[:, 1] + s[:, 3]], axis=1) if len(s) else np.zeros((0, 4))
    return boxes * scale


def group_hulls(mask: np.ndarray, boxes: np.ndarray, scale: float = 1.0, margin: float = 0.08,
                min_fill: float = 0.05) -> list[np.ndarray | None]:
    """Convex hull (full-resolution pixels, Kx2) of the foreground blobs that belong to each box.

    A blob belongs to a box when at least half of its pixels lie in the box, or when it fills at least a fifth
    of the box (a vehicle merged with a neighbour or a shadow).  Only the blob pixels inside the box grown by
    ``margin`` of its size enter the hull, so a merged neighbour does not spill over.  Boxes whose grouped
    pixels cover less than ``min_fill`` of the box get None (no foreground evidence).
    """
    boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
    out: list[np.ndarray | None] = [None] * len(boxes)
    if len(boxes) == 0:
        return out
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return out
    h, w = mask.shape
    sizes = stats[:, cv2.CC_STAT_AREA].astype(np.float64)
    sb = boxes / scale
    for j in range(len(boxes)):
        bw, bh = sb[j, 2] - sb[j, 0], sb[j, 3] - sb[j, 1]
        x0, y0 = int(max(np.floor(sb[j, 0]), 0)), int(max(np.floor(sb[j, 1]), 0))
        x1, y1 = int(min(np.ceil(sb[j, 2]), w)), int(min(np.ceil(sb[j, 3]), h))
        if x1 <= x0 or y1 <= y0:
            continue
        counts = np.bincount(labels[y0:y1, x0:x1].ravel(), minlength=n).astype(np.float64)
        counts[0] = 0
        member = (counts >= 0.5 * sizes) | (counts >= 0.2 * bw * bh)
        member[0] = False
        if counts[member].sum() < min_fill * bw * bh:
            continue
        gx0, gy0 = int(max(np.floor(sb[j, 0] - margin * bw), 0)), int(max(np.floor(sb[j, 1] - margin * bh), 0))
        gx1, gy1 = int(min(np.ceil(sb[j, 2] + margin * bw), w)), int(min(np.ceil(sb[j, 3] + margin * bh), h))
        ys, xs = np.nonzero(member[labels[gy0:gy1, gx0:gx1]])
        if len(xs) < 3:
            continue
        pts = np.stack([xs + gx0, ys + gy0], axis=1).astype(np.float32)
        hull = cv2.convexHull(pts).reshape(-1, 2).astype(np.float64)
        # work-pixel centres -> outer pixel edges, in full-resolution pixel coordinates (centres at integers)
        c = hull.mean(axis=0)
        hull = (hull + 0.5 + 0.5 * np.sign(hull - c)) * scale - 0.5
        out[j] = hull
    return out


def chroma_from_bgr(bgr: np.ndarray) -> np.ndarray:
    """The U and V planes (half size, as in I420) of a BGR frame, H/2 x W/2 x 2 uint8: the ``chroma`` input of
    :meth:`BackgroundModel.apply` for callers that decode to BGR."""
    if bgr.ndim != 3 or bgr.shape[2] != 3:
        raise InputError(f"need a BGR image (H x W x 3), got shape {bgr.shape}")
    h, w = (bgr.shape[0] // 2) * 2, (bgr.shape[1] // 2) * 2
    yuv = cv2.cvtColor(np.ascontiguousarray(bgr[:h, :w]), cv2.COLOR_BGR2YUV_I420)
    n = (h // 2) * (w // 2)
    flat = yuv[h:].reshape(-1)
    return np.dstack([flat[:n].reshape(h // 2, w // 2), flat[n:2 * n].reshape(h // 2, w // 2)])


def chroma_from_planes(planes: list[np.ndarray], fmt: str) -> np.ndarray | None:
    """The U and V planes of a raw video frame given as its planes (GStreamer formats I420, NV12, BGR, RGB,
    BGRx); None for GRAY8 (no colour)."""
    if fmt == "I420":
        return np.dstack([planes[1], planes[2]])
    if fmt == "NV12":
        return planes[1]
    code = {"BGR": None, "RGB": cv2.COLOR_RGB2BGR, "BGRx": cv2.COLOR_BGRA2BGR}
    if fmt not in code:
        return None
    bgr = planes[0] if code[fmt] is None else cv2.cvtColor(planes[0], code[fmt])
    return chroma_from_bgr(bgr)
