"""Augmentation and training targets for the vehicle segmenter (numpy/OpenCV, one sample at a time).

Coordinates: work pixels; the network's 1/4-resolution cell j covers work pixels 4j..4j+3.  Instance centres are
the centroids of each vehicle's visible pixels in the whole (uncropped) work image, so a vehicle cut by the crop
keeps the centre it has at run time (its offsets may point outside the crop).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

QUARTER = 4
UNKNOWN = 255  # the renderer's id mask saturates at 255 vehicles in view
HARD_WEIGHT = 3.0  # loss weight of pixels that changed against the background but are no vehicle (shadows, beams)
CHANGED = 18  # grey levels: what counts as changed
SHADOW_WEIGHT = 6.0  # loss weight of the faint changes next to a vehicle that are no vehicle: cast, contact shadows
SHADOW_NEAR = 6  # work pixels around a vehicle where they are looked for
SHADOW_CHANGED = 6  # grey levels: a soft overcast shadow changes the road by less than CHANGED
BOUNDARY_WEIGHT = 2.0  # loss weight of the pixels on a vehicle's outline (either side), where the box edges come from


@dataclass
class Sample:
    """Network input and targets of one crop (float32 / uint8 arrays, channels first for the input)."""

    x: np.ndarray  # 6 x H x W, in [-0.5, 0.5]
    fg: np.ndarray  # H x W vehicle fraction 0..1
    fg_w: np.ndarray  # H x W loss weight (0 = padding / unknown; HARD_WEIGHT on changed pixels that are no vehicle)
    heat: np.ndarray  # H/4 x W/4 centre heatmap 0..1 (1 exactly at each centre)
    offset: np.ndarray  # 2 x H/4 x W/4 (dx, dy) to the instance centre, 1/4-resolution pixels
    off_w: np.ndarray  # H/4 x W/4


def instance_centres(inst: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per label 0..255: centroid x, y (work pixels) and pixel count."""
    h, w = inst.shape
    flat = inst.ravel()
    count = np.bincount(flat, minlength=256).astype(np.float64)
    xs = np.tile(np.arange(w, dtype=np.float64), h)
    ys = np.repeat(np.arange(h, dtype=np.float64), w)
    sx = np.bincount(flat, weights=xs, minlength=256)
    sy = np.bincount(flat, weights=ys, minlength=256)
    n = np.maximum(count, 1)
    return sx / n, sy / n, count


def photometric(frame: np.ndarray, background: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Colour changes shared by frame and background (camera colour response, gamma, greyscale sensors) and a few of
    the frame's own (exposure drift, sensor noise, a pixel of jitter of the background)."""
    pair = np.concatenate([frame, background], axis=1).astype(np.float32) / 255.0
    if rng.random() < 0.8:
        pair *= rng.uniform(0.8, 1.2, 3).astype(np.float32) * np.float32(rng.uniform(0.75, 1.25))
    if rng.random() < 0.5:
        pair = np.clip(pair, 0, 1) ** np.float32(rng.uniform(0.7, 1.4))
    if rng.random() < 0.12:
        g = pair @ np.array([0.114, 0.587, 0.299], np.float32)
        pair = np.repeat(g[..., None], 3, axis=2)
    w = frame.shape[1]
    f, b = pair[:, :w], pair[:, w:]
    if rng.random() < 0.3:
        f = f * np.float32(rng.normal(1.0, 0.04))
    if rng.random() < 0.4:
        f = f + rng.normal(0, rng.uniform(0.002, 0.015), f.shape).astype(np.float32)
    if rng.random() < 0.1:
        b = np.roll(b, (int(rng.integers(-1, 2)), int(rng.integers(-1, 2))), axis=(0, 1))
    return np.clip(f, 0, 1), np.clip(b, 0, 1)


def mask_weights(fg: np.ndarray, known: np.ndarray, diff: np.ndarray, shadow_weight: float = SHADOW_WEIGHT,
                 boundary_weight: float = BOUNDARY_WEIGHT) -> np.ndarray:
    """Per-pixel weight of the mask loss: 0 where the truth is unknown or padding; ``HARD_WEIGHT`` where the frame
    changed by more than ``CHANGED`` against the background and no vehicle is (shadows, beams, ghosts);
    ``shadow_weight`` where it changed by more than ``SHADOW_CHANGED`` within ``SHADOW_NEAR`` pixels of a vehicle
    and no vehicle is (the shadow strips and halos that made the first model's boxes too large);
    ``boundary_weight`` on the outline (pixels whose 3x3 neighbourhood holds vehicle and no vehicle).
    ``diff``: the largest absolute frame - background difference over the channels, grey levels."""
    w = known.astype(np.float32)
    empty = fg < 0.05
    w[(diff > CHANGED) & empty] *= HARD_WEIGHT
    body = (fg >= 0.5).astype(np.uint8)
    if shadow_weight > 0:
        k = 2 * SHADOW_NEAR + 1
        near = cv2.dilate((~empty).astype(np.uint8), np.ones((k, k), np.uint8)) > 0
        shadow = near & empty & (diff > SHADOW_CHANGED)
        w[shadow] = np.maximum(w[shadow], shadow_weight * known[shadow])
    if boundary_weight != 1:
        square = np.ones((3, 3), np.uint8)
        edge = cv2.dilate(body, square) != cv2.erode(body, square)
        w[edge] *= boundary_weight
    return w


def make_sample(data: dict, crop: tuple[int, int], rng: np.random.Generator, augment: bool = True,
                shadow_weight: float = SHADOW_WEIGHT, boundary_weight: float = BOUNDARY_WEIGHT) -> Sample:
    """A random crop (``crop`` = height, width, multiples of 16) of one stored sample with its targets
    (mask-loss weights: :func:`mask_weights`)."""
    frame, background, fg, inst = data["frame"], data["background"], data["fg"], data["inst"]
    if augment and rng.random() < 0.6:  # vehicles nearer / farther than in the render
        s = float(rng.uniform(0.6, 1.3))
        size = (max(crop[1] // 2, round(frame.shape[1] * s)), max(crop[0] // 2, round(frame.shape[0] * s)))
        interp = cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR
        frame, background = (cv2.resize(a, size, interpolation=interp) for a in (frame, background))
        fg = cv2.resize(fg, size, interpolation=interp)
        inst = cv2.resize(inst, size, interpolation=cv2.INTER_NEAREST)
    cx, cy, count = instance_centres(inst)
    h, w = inst.shape
    ch, cw = crop
    y0 = int(rng.integers(0, max(h - ch, 0) + 1))
    x0 = int(rng.integers(0, max(w - cw, 0) + 1))
    pad = ((0, max(ch - (h - y0), 0)), (0, max(cw - (w - x0), 0)))
    sl = np.s_[y0:y0 + ch, x0:x0 + cw]
    frame = np.pad(frame[sl], pad + ((0, 0),), mode="edge")
    background = np.pad(background[sl], pad + ((0, 0),), mode="edge")
    fg = np.pad(fg[sl], pad).astype(np.float32) / 255.0
    inst = np.pad(inst[sl], pad)
    valid = np.pad(np.ones((min(ch, h - y0), min(cw, w - x0)), bool), pad)
    cx, cy = cx - x0, cy - y0
    if augment and rng.random() < 0.5:
        frame, background, fg, inst, valid = (a[:, ::-1] for a in (frame, background, fg, inst, valid))
        cx = cw - 1 - cx
    diff = np.abs(frame.astype(np.int16) - background.astype(np.int16)).max(axis=2)
    if augment:
        f, b = photometric(frame, background, rng)
    else:
        f, b = frame.astype(np.float32) / 255.0, background.astype(np.float32) / 255.0
    x = np.concatenate([f, b], axis=2).transpose(2, 0, 1) - np.float32(0.5)
    fg_w = mask_weights(fg, valid & (inst != UNKNOWN), diff, shadow_weight, boundary_weight)

    qh, qw = ch // QUARTER, cw // QUARTER
    qi = inst[QUARTER // 2::QUARTER, QUARTER // 2::QUARTER][:qh, :qw]
    gx = (cx - (QUARTER - 1) / 2) / QUARTER  # centres in 1/4-resolution pixel coordinates
    gy = (cy - (QUARTER - 1) / 2) / QUARTER
    jj, ii = np.meshgrid(np.arange(qw, dtype=np.float32), np.arange(qh, dtype=np.float32))
    known = (qi > 0) & (qi != UNKNOWN)
    offset = np.stack([np.where(known, gx[qi] - jj, 0), np.where(known, gy[qi] - ii, 0)]).astype(np.float32)
    off_w = known.astype(np.float32)
    heat = np.zeros((qh, qw), np.float32)
    for label in np.nonzero(count[1:UNKNOWN] >= 12)[0] + 1:
        px, py = gx[label], gy[label]
        if not (-0.5 <= px < qw - 0.5 and -0.5 <= py < qh - 0.5):
            continue
        sigma = float(np.clip(0.2 * np.sqrt(count[label]) / QUARTER, 0.7, 4.0))
        r = int(np.ceil(3 * sigma))
        ix, iy = int(round(px)), int(round(py))
        xa, xb, ya, yb = max(ix - r, 0), min(ix + r + 1, qw), max(iy - r, 0), min(iy + r + 1, qh)
        g = np.exp(-((jj[ya:yb, xa:xb] - ix) ** 2 + (ii[ya:yb, xa:xb] - iy) ** 2) / (2 * sigma ** 2))
        heat[ya:yb, xa:xb] = np.maximum(heat[ya:yb, xa:xb], g)
    return Sample(np.ascontiguousarray(x, np.float32), np.ascontiguousarray(fg), np.ascontiguousarray(fg_w),
                  heat, offset, off_w)
