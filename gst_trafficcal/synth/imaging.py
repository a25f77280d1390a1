"""The camera's imaging chain applied to rendered frames: motion blur, bloom, shake, optics blur, contrast,
vignetting and sensor noise (OpenCV on uint8 images: a few milliseconds per frame).

Camera shake is a small rotation about the camera centre, so it is exactly the homography K R K⁻¹ of the
image: the ground-truth points are mapped with the same matrix and stay exact.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..geometry import rotation_matrix
from .scenario import ImagingSpec, LightingSpec


@dataclass
class Shake:
    """Smooth random camera rotations: sums of sinusoids per axis with std ``std_deg``."""

    K: np.ndarray
    std_deg: float
    hz: float
    rng: np.random.Generator

    def __post_init__(self) -> None:
        n = 4
        self.freq = self.hz * self.rng.uniform(0.3, 1.7, (3, n))
        self.phase = self.rng.uniform(0, 2 * np.pi, (3, n))
        self.amp = np.full((3, n), self.std_deg * np.sqrt(2.0 / n))
        self.amp[2] *= 0.5  # roll shakes less than pan/tilt

    def homography(self, t: float) -> np.ndarray:
        """Image homography of the shaken camera relative to the nominal one at time t."""
        if self.std_deg <= 0:
            return np.eye(3)
        a = (self.amp * np.sin(2 * np.pi * self.freq * t + self.phase)).sum(axis=1)
        # relative rotation in camera coordinates: yaw about camera y, pitch about camera x, roll about z
        base = rotation_matrix(0.0, 0.0, 0.0)
        Rd = rotation_matrix(a[0], a[1], a[2]) @ base.T
        return self.K @ Rd @ np.linalg.inv(self.K)


def apply_homography(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    p = np.asarray(pts, float)
    q = p @ H[:, :2].T + H[:, 2]
    return q[..., :2] / q[..., 2:3]


def _noise_bank(rng: np.random.Generator, size: tuple[int, int], sigma: float, n: int) -> list[np.ndarray]:
    """``n`` sensor-noise images (H, W, 3) int16: per-pixel luma noise of std ``sigma`` plus smooth chroma noise
    (half as strong, at a quarter of the resolution, upsampled).  Summed and rounded in one reused float64
    buffer (fresh 50 MB temporaries per image made this a second at 1080p)."""
    W, H = size
    total = np.empty((H, W, 3), np.float64)
    bank = []
    for _ in range(n):
        luma = rng.standard_normal((H, W, 1))
        luma *= sigma
        chroma = cv2.resize((rng.standard_normal((H // 4 + 1, W // 4 + 1, 3)) * sigma * 0.5).astype(np.float32),
                            (W, H), interpolation=cv2.INTER_LINEAR)
        np.add(luma, chroma, out=total)
        np.rint(total, out=total)
        bank.append(total.astype(np.int16))
    return bank


class Imaging:
    """Stateful per-video imaging chain (keeps noise banks and the vignette map); uint8 OpenCV operations only,
    so a 1080p frame costs a few milliseconds."""

    def __init__(self, spec: ImagingSpec, lighting: LightingSpec, size: tuple[int, int], night: bool,
                 rng: np.random.Generator):
        self.spec, self.night = spec, night
        W, H = size
        self.size = size
        self.rng = rng
        self.contrast = lighting.contrast
        yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
        r2 = ((xx - W / 2) ** 2 + (yy - H / 2) ** 2) / ((W / 2) ** 2 + (H / 2) ** 2)
        gain = (1.0 - spec.vignette * r2) * 255.0
        self.gain = np.repeat(np.clip(gain, 0, 255).round().astype(np.uint8)[..., None], 3, axis=2) \
            if spec.vignette > 0 else None
        sigma = spec.noise * (1.6 if night else 1.0)
        self.noise_bank = _noise_bank(rng, (W, H), sigma, 6 if sigma > 0 else 0)

    def motion_blur(self, img: np.ndarray, ids: np.ndarray, motions: dict[int, np.ndarray]) -> np.ndarray:
        """Smear each vehicle (ID mask slot -> image displacement during the exposure, pixels)."""
        if self.spec.motion_blur <= 0 or not motions:
            return img
        H, W = ids.shape
        out = img
        for slot, d in motions.items():
            length = float(np.hypot(*d))
            if length < 1.0:
                continue
            ys, xs = np.nonzero(ids == slot)
            if len(xs) == 0:
                continue
            pad = int(np.ceil(length)) + 2
            x0, x1 = max(xs.min() - pad, 0), min(xs.max() + pad + 1, W)
            y0, y1 = max(ys.min() - pad, 0), min(ys.max() + pad + 1, H)
            k = int(np.ceil(length)) | 1
            ker = np.zeros((k, k), np.float32)
            c = k // 2
            n = max(int(length * 2), 2)
            for s in np.linspace(-0.5, 0.5, n):
                ker[int(round(c + s * d[1])), int(round(c + s * d[0]))] += 1
            ker /= ker.sum()
            crop = out[y0:y1, x0:x1].astype(np.float32)
            m = (ids[y0:y1, x0:x1] == slot).astype(np.float32)[..., None]
            bm = cv2.filter2D(m[..., 0], -1, ker)[..., None]
            bo = cv2.filter2D(crop * m, -1, ker)
            res = bo + crop * (1 - bm)
            if out is img:
                out = img.copy()
            out[y0:y1, x0:x1] = np.clip(res, 0, 255).astype(np.uint8)
        return out

    def process(self, img: np.ndarray, ids: np.ndarray, motions: dict[int, np.ndarray],
                H: np.ndarray | None) -> np.ndarray:
        """Motion blur, bloom around lights, shake warp, optics blur, contrast, vignette, sensor noise."""
        W, Hh = self.size
        img = self.motion_blur(img, ids, motions)
        if self.night:  # bloom around lights, computed at quarter resolution
            small = cv2.resize(img, (W // 4, Hh // 4), interpolation=cv2.INTER_AREA)
            bright = cv2.subtract(small, np.full_like(small, 190))
            glow = cv2.GaussianBlur(bright, (0, 0), max(W / 480.0, 1.0))
            glow = cv2.resize(glow, (W, Hh), interpolation=cv2.INTER_LINEAR)
            img = cv2.addWeighted(img, 1.0, glow, 2.5, 0.0)
        if H is not None and not np.allclose(H, np.eye(3)):
            img = cv2.warpPerspective(img, H, (W, Hh), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        if self.spec.blur > 0:
            img = cv2.GaussianBlur(img, (0, 0), self.spec.blur)
        if self.gain is not None:
            img = cv2.multiply(img, self.gain, scale=1.0 / 255.0)
        if self.contrast != 1.0:
            img = cv2.convertScaleAbs(img, alpha=self.contrast, beta=128.0 * (1.0 - self.contrast))
        if self.noise_bank:
            img = cv2.add(img, self.noise_bank[int(self.rng.integers(len(self.noise_bank)))], dtype=cv2.CV_8U)
        return img
