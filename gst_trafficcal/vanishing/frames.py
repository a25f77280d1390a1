"""The grey image the calibrator analyses, one definition for the `vpdetect` element and for video files.

Both take the luma plane Y' of the decoded video: the element straight from I420/NV12 buffers, files through
OpenCV's FFmpeg backend with the colour conversion turned off (the decoder's Y plane, the same bytes a
GStreamer H.264 decoder gives).  Colour frames (BGR/RGB/BGRx caps, or files whose decoder does not give planar
YUV) are converted by :func:`luma` to what that Y plane would hold: BT.601 limited-range luma.  Without this
the CLI (BGR -> ``COLOR_BGR2GRAY``, full range) and the element (Y plane, 16-235) saw different contrasts and
rounding, and their calibrations of one clip differed.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np

from ..errors import InputError
from ..imaging import OpenCVPicture, capture_par, opencv_picture

# Y' = 16 + 219/255 (0.299 R + 0.587 G + 0.114 B), ITU-R BT.601 limited range (what decoders output)
_K = 219.0 / 255.0
_TO_VIDEO_RANGE = np.rint(16.0 + _K * np.arange(256)).astype(np.uint8)  # full-range luma -> 16-235


def luma(image: np.ndarray, order: str = "BGR") -> np.ndarray:
    """HxW uint8 luma of a frame: a 2-D image (a Y plane, GRAY8) as it is; a colour image (``order`` BGR, RGB,
    BGRx, RGBx, BGRA, RGBA) as BT.601 limited-range Y': OpenCV's luma (0-255) mapped into 16-235 by a table, within
    one grey level of the exact value and about as fast as cvtColor alone (a float transform took 9x as long)."""
    if image.ndim == 2:
        return image
    if image.ndim != 3 or image.shape[2] not in (3, 4):
        raise InputError(f"cannot take the luma of an image of shape {image.shape}")
    rgb = order[:3].upper() == "RGB"
    code = {(3, False): cv2.COLOR_BGR2GRAY, (3, True): cv2.COLOR_RGB2GRAY,
            (4, False): cv2.COLOR_BGRA2GRAY, (4, True): cv2.COLOR_RGBA2GRAY}[(image.shape[2], rgb)]
    return cv2.LUT(cv2.cvtColor(image, code), _TO_VIDEO_RANGE)


@dataclass
class LumaFrames:
    """Frames of a video file as luma planes, with their timestamps (seconds).

    ``planar`` tells whether the decoder's Y plane is read directly (planar YUV streams: H.264, HEVC, MPEG-4...)
    or the frames are decoded to BGR and converted by :func:`luma` (anything else, e.g. RGB or packed YUV).
    ``first_bgr`` is the first frame in colour (for pictures).  Frames of non-square pixels (``par``, e.g. 480x360
    stored for a 640x360 picture) are scaled to square ones, as ``trafficcal run`` and the scripts' videoscale does:
    ``size`` is the square-pixel size, so a calibration learnt here fits their frames."""

    path: Path
    fps: float
    count: int
    size: tuple[int, int]
    planar: bool
    first_bgr: np.ndarray | None
    par: Fraction = Fraction(1)
    # how the frames are turned (a mirrored file's flip, --orientation) and, for a quarter turn, the stored pixels'
    # ``par`` inverted, as videoflip does (imaging.OpenCVPicture)
    picture: OpenCVPicture = field(default_factory=OpenCVPicture)

    def __iter__(self) -> Iterator[tuple[float, np.ndarray]]:
        with _quiet():
            cap = _open(self.path, planar=self.planar)
        n = 0
        try:
            while True:
                if self.planar:
                    with _quiet():  # one warning per frame otherwise
                        ok, img = cap.read()
                else:
                    ok, img = cap.read()
                if not ok:
                    break
                msec = cap.get(cv2.CAP_PROP_POS_MSEC)
                t = msec / 1000.0 if n and msec > 0 else n / self.fps
                img = img if self.planar else luma(img)
                yield t, self.picture.frame(img, self.par)
                n += 1
        finally:
            cap.release()


def luma_frames(path: str | Path, orientation: str = "auto") -> LumaFrames:
    """Open a video for calibration (InputError for a missing or undecodable file).

    The Y plane is used when the FFmpeg backend returns it (a HxW frame when the colour conversion is off) and
    it matches the colour decode of the first frame (mean |Y - luma(BGR)| < 3 grey levels; measured 0.7-1.0 on the clips of
    ../shared, a misread packed format gives tens); otherwise BGR frames
    are converted with :func:`luma`.  ``orientation``: how the frames are turned (imaging.opencv_picture: auto, as the
    file says; else trafficcal's --orientation, whatever it says), as trafficcal run's videoflip turns them."""
    from ..fileio import open_video

    path = Path(path)
    cap = open_video(path)
    try:
        fps = cap.get(cv2.CAP_PROP_FPS) or 25.0
        fps = fps if 1.0 <= fps <= 1000.0 else 25.0
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        if w <= 0 or h <= 0:
            raise InputError(f"{path}: cannot read the frame size (corrupt or not a video)")
        par = capture_par(cap)
        ok, first = cap.read()
    finally:
        cap.release()
    first_bgr = first if ok else None
    planar = False
    if ok and first.ndim == 3:
        with _quiet():
            ycap = _open(path, planar=True)
            try:
                yok, y = ycap.read() if ycap.isOpened() else (False, None)
            finally:
                ycap.release()
        planar = bool(yok and y.ndim == 2 and y.shape == (h, w)
                      and float(np.mean(np.abs(y.astype(np.int16) - luma(first).astype(np.int16)))) < 3.0)
    picture = opencv_picture(path, orientation)
    return LumaFrames(path, fps, count, picture.size((w, h), par), planar,
                      None if first_bgr is None else picture.frame(first_bgr, par), par, picture)


def _open(path: Path, planar: bool) -> cv2.VideoCapture:
    if not planar:
        return cv2.VideoCapture(str(path))
    return cv2.VideoCapture(str(path), cv2.CAP_FFMPEG, [cv2.CAP_PROP_CONVERT_RGB, 0])


@contextmanager
def _quiet() -> Iterator[None]:
    """OpenCV logs a warning when the colour conversion is off ("decoded frame will be returned in its
    original format"): that is what we want here, so only errors are logged meanwhile."""
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    try:
        yield
    finally:
        cv2.utils.logging.setLogLevel(level)
