"""Image reduction shared by the detectors and the buffer access layer; OpenCV's frames of non-square pixels
scaled to the square ones the elements see (:func:`squared`)."""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from .errors import InputError


def fit(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Resize to ``size`` (w, h). Large reductions go bilinear to twice the size, then area-averaged:
    nearly the quality of a direct INTER_AREA (about 1 grey level apart) at a fraction of its cost
    (1080p -> 320x320: ~3 ms instead of ~20 ms on one core, measured while profiling)."""
    h, w = image.shape[:2]
    if w > 2 * size[0] and h > 2 * size[1]:
        image = cv2.resize(image, (2 * size[0], 2 * size[1]), interpolation=cv2.INTER_LINEAR)
        return cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA if w > size[0] else cv2.INTER_LINEAR)


def square_size(width: int, height: int, par: Fraction) -> tuple[int, int]:
    """The frame size (w, h) of square pixels that GStreamer's ``videoscale ! video/x-raw,pixel-aspect-ratio=1/1``
    gives for ``width``x``height`` pixels of aspect ratio ``par`` (as ``trafficcal run`` and the pipelines/ scripts
    scale them): the height kept, the width of the picture's display aspect, rounded half up (480x360 of 4/3 ->
    640x360, a DVR's 704x576 D1 of 12/11 -> 768x576)."""
    if par <= 0 or par == 1:
        return width, height
    return max(1, int(Fraction(width) * par + Fraction(1, 2))), height


def capture_par(cap) -> Fraction:
    """The pixel aspect ratio an opened ``cv2.VideoCapture`` states (its sample aspect ratio; 1 when it states none).
    OpenCV's FFmpeg backend gives the stored pixels (480x360 of a 640x360 picture) where GStreamer's caps say
    pixel-aspect-ratio=4/3; it does turn a phone's rotated video upright, as ``videoflip video-direction=auto``."""
    num, den = int(cap.get(cv2.CAP_PROP_SAR_NUM) or 0), int(cap.get(cv2.CAP_PROP_SAR_DEN) or 0)
    return Fraction(num, den) if num > 0 and den > 0 else Fraction(1)


def squared(frame: np.ndarray, par: Fraction) -> np.ndarray:
    """A frame of ``par`` pixels scaled to square ones (:func:`square_size`, bilinear as videoscale's default), so
    that a picture or an analysis of OpenCV's frames has the size and geometry of the elements' (as it is when
    its pixels are square already)."""
    size = square_size(frame.shape[1], frame.shape[0], par)
    if size == (frame.shape[1], frame.shape[0]):
        return frame
    return cv2.resize(frame, size, interpolation=cv2.INTER_LINEAR)


# videoflip's video-direction for each display matrix that turns or mirrors a picture, as the 2x2 matrix taking a
# stored pixel's (x, y) about the centre (y down) to where it is shown; a display matrix's a, b, c, d give [[a, c],
# [b, d]].  horiz, vert, ul-lr and ur-ll are a mirrored picture (a selfie camera's, a mirror-image recording), as
# GStreamer's qtdemux tags it flip-rotate-0, flip-rotate-180, flip-rotate-270 (and flip-rotate-90: 1.22 does not
# tag ur-ll) and ``videoflip video-direction=auto`` shows it.
DIRECTIONS: dict[str, tuple[tuple[int, int], tuple[int, int]]] = {
    "identity": ((1, 0), (0, 1)), "90r": ((0, -1), (1, 0)), "180": ((-1, 0), (0, -1)), "90l": ((0, 1), (-1, 0)),
    "horiz": ((-1, 0), (0, 1)), "vert": ((1, 0), (0, -1)), "ul-lr": ((0, 1), (1, 0)), "ur-ll": ((0, -1), (-1, 0))}
_ROTATIONS = {0: "identity", 90: "90r", 180: "180", 270: "90l"}  # degrees clockwise
AUTO = "auto"  # --orientation's default: as the file's display matrix or the stream's tag says
ORIENTATIONS = (AUTO, *DIRECTIONS)  # --orientation's values: auto, or a videoflip video-direction that overrides it


def check_orientation(text: str | None, option: str = "--orientation") -> str:
    """``text`` as an orientation: ``auto`` (the file's display matrix or the stream's tag turns the picture), or
    the videoflip ``video-direction`` the stored frames are turned by whatever they say — a camera mounted on its
    side or upside down, or one imaging a mirror, sends no tag over RTP (90r: a quarter turn clockwise, 180,
    90l, horiz/vert: mirrored left-right/top-bottom, ul-lr/ur-ll: mirrored about a diagonal); InputError
    naming ``option`` otherwise.  Empty or None: auto."""
    value = (text or AUTO).strip().lower()
    if value not in ORIENTATIONS:
        raise InputError(f"{option} must be one of {', '.join(ORIENTATIONS)}, got {text!r}")
    return value


def orientation_of_file(path: str | Path) -> str | None:
    """The orientation a calibration file keeps (its field ``orientation``, written by ``trafficcal calibrate`` and
    ``run`` given an ``--orientation``), None when it keeps none; InputError naming the file otherwise."""
    from .fileio import json_text_field

    text = json_text_field(path, "orientation", "calibration file", f"one of {', '.join(ORIENTATIONS)}")
    return None if text is None else check_orientation(text, f"{path}: field 'orientation'")


def turned_size(size: tuple[int, int], fixup) -> tuple[int, int]:
    """The size (w, h) of OpenCV's ``size`` frames once ``fixup`` (:attr:`OpenCVPicture.fixup`, or None) turned
    them."""
    if fixup is None:
        return size
    h, w = fixup(np.zeros((size[1], size[0]), np.uint8)).shape
    return w, h


def video_direction(path: str | Path) -> str | None:
    """The videoflip ``video-direction`` that shows a video file's frames as its display matrix says (a phone's or
    a body camera's turned picture, a mirrored one): read from the MP4/MOV video track's header, else OpenCV's
    rotation (what its FFmpeg reads and applies); None when neither can tell (GStreamer may still play the file:
    it then turns it by the tag it reads, ``video-direction=auto``)."""
    direction = mp4_direction(path)
    if direction is not None:
        return direction
    degrees = opencv_rotation(path)
    return None if degrees is None else _ROTATIONS[degrees]


def opencv_rotation(path: str | Path) -> int | None:
    """Degrees (0, 90, 180 or 270) OpenCV's FFmpeg turns a video file's frames clockwise (its display matrix's
    rotation; a mirrored one is read as a rotation, without the mirroring); None when OpenCV cannot open it."""
    from .fileio import quiet_ffmpeg

    with quiet_ffmpeg():
        cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            return None
        return int(round(cap.get(cv2.CAP_PROP_ORIENTATION_META) / 90.0)) % 4 * 90
    finally:
        cap.release()


def mp4_direction(path: str | Path) -> str | None:
    """The :data:`DIRECTIONS` name of the display matrix of an MP4/MOV file's first video track ("identity" when it
    neither turns nor mirrors, or does something else: a scaling or an odd angle); None when the file is not one
    whose boxes can be read (another container, cut off before its header)."""
    import struct

    try:
        moov = _top_level_box(Path(path), b"moov")
    except OSError:
        return None
    if moov is None:
        return None
    for kind, a, b in _boxes(moov):
        if kind != b"trak":
            continue
        inner = {k: (x, y) for k, x, y in _boxes(moov, a, b)}
        if b"tkhd" not in inner or not _is_video(moov, inner.get(b"mdia")):
            continue
        x = inner[b"tkhd"][0]
        start = x + (4 + 8 + 8 + 4 + 4 + 8 if moov[x] == 1 else 4 + 4 + 4 + 4 + 4 + 4) + 8 + 8
        if start + 36 > inner[b"tkhd"][1]:
            return None
        ma, mb, _, mc, md = struct.unpack_from(">5i", moov, start)
        m = tuple(tuple(round(v / 65536) for v in row) for row in ((ma, mc), (mb, md)))
        return next((name for name, known in DIRECTIONS.items() if known == m), "identity")
    return None


def _top_level_box(path: Path, kind: bytes, limit: int = 64 << 20) -> bytes | None:
    """The contents of the file's first top-level box ``kind`` (skipping the others by seeking: a recording's
    media data may come first), None when there is none or it is larger than ``limit``."""
    import struct

    with path.open("rb") as f:
        size_total = path.stat().st_size
        pos = 0
        while pos + 8 <= size_total:
            f.seek(pos)
            size, found = struct.unpack(">I4s", f.read(8))
            head = 8
            if size == 1:
                size, head = struct.unpack(">Q", f.read(8))[0], 16
            elif size == 0:
                size = size_total - pos
            if size < head:
                return None
            if found == kind:
                return f.read(size - head) if size - head <= limit else None
            pos += size
    return None


def _boxes(data: bytes, start: int = 0, end: int | None = None):
    """(type, contents' start, end) of each ISO-BMFF box in ``data[start:end]``, up to one that does not fit."""
    import struct

    end = len(data) if end is None else end
    while start + 8 <= end:
        size, kind = struct.unpack_from(">I4s", data, start)
        head = 8
        if size == 1 and start + 16 <= end:
            size, head = struct.unpack_from(">Q", data, start + 8)[0], 16
        elif size == 0:
            size = end - start
        if size < head or start + size > end:
            return
        yield kind, start + head, start + size
        start += size


def _is_video(moov: bytes, mdia: tuple[int, int] | None) -> bool:
    """Whether a track's ``mdia`` box (its span in ``moov``) has the video handler."""
    if mdia is None:
        return False
    for kind, a, _ in _boxes(moov, *mdia):
        if kind == b"hdlr":
            return moov[a + 8:a + 12] == b"vide"
    return False


def apply_direction(frame: np.ndarray, matrix: tuple[tuple[int, int], tuple[int, int]]) -> np.ndarray:
    """``frame`` (H x W [x C]) shown by ``matrix`` (a :data:`DIRECTIONS` value, or a product of them)."""
    (m00, m01), (m10, m11) = matrix
    if m00 == 0:  # the axes swap: shown x is ±stored y, shown y is ±stored x
        frame, sx, sy = frame.swapaxes(0, 1), m01, m10
    else:
        sx, sy = m00, m11
    return np.ascontiguousarray(frame[::sy, ::sx])


@dataclass(frozen=True)
class OpenCVPicture:
    """How OpenCV's frames of a video become the picture trafficcal run's ``videoflip ! videoscale`` analyses:
    ``fixup`` still turns them (None: nothing to do; :func:`opencv_picture`), ``quarter`` tells that the picture is
    the stored one turned a quarter (or mirrored about a diagonal).  Its pixels' aspect ratio is then the stored
    one's inverse, as videoflip swaps the caps' pixel-aspect-ratio: 480x360 stored at 4/3 turned 90r is 360x480 at
    3/4, which videoscale makes 270x480 (its height kept), not 480x480."""

    fixup: Callable[[np.ndarray], np.ndarray] | None = None
    quarter: bool = False

    def par(self, par: Fraction) -> Fraction:
        """The aspect ratio of the turned picture's pixels, of stored pixels of ``par`` (OpenCV's capture_par)."""
        return 1 / par if self.quarter and par > 0 else par

    def size(self, size: tuple[int, int], par: Fraction) -> tuple[int, int]:
        """The analysed size (w, h) of OpenCV's frames of ``size`` (CAP_PROP_FRAME_WIDTH/HEIGHT) and ``par``: the
        one size trafficcal run, the scripts and trafficcal calibrate work at."""
        return square_size(*turned_size(size, self.fixup), self.par(par))

    def frame(self, frame: np.ndarray, par: Fraction) -> np.ndarray:
        """OpenCV's ``frame`` (of stored pixels of ``par``) as the analysed picture: turned, then squared."""
        return squared(self.fixup(frame) if self.fixup else frame, self.par(par))


def swaps_axes(direction: str) -> bool:
    """Whether the :data:`DIRECTIONS` ``direction`` swaps a picture's width and height (a quarter turn)."""
    return DIRECTIONS[direction][0][0] == 0


def opencv_picture(path: str | Path, orientation: str = AUTO) -> OpenCVPicture:
    """:class:`OpenCVPicture` of a video file (OpenCV turns its frames by the rotation it reads: :func:`
    opencv_rotation`): with ``orientation`` auto what still turns them into the picture its display matrix shows
    (:func:`video_direction`: a flip for a mirrored file, nothing for all others); with a :data:`DIRECTIONS` name the
    stored frames turned that way whatever the file says (a camera mounted on its side or upside down:
    :func:`check_orientation`); and whether the picture is the stored one turned a quarter."""
    direction, degrees = mp4_direction(path), opencv_rotation(path)
    if orientation != AUTO:
        direction, degrees = orientation, 0 if degrees is None else degrees
    shown = direction if direction is not None else None if degrees is None else _ROTATIONS[degrees]
    quarter = shown is not None and swaps_axes(shown)
    if direction is None or degrees is None or DIRECTIONS[direction] == DIRECTIONS[_ROTATIONS[degrees]]:
        return OpenCVPicture(None, quarter)
    want, done = np.array(DIRECTIONS[direction]), np.array(DIRECTIONS[_ROTATIONS[degrees]])
    rest = tuple(tuple(int(v) for v in row) for row in want @ done.T)  # want = rest @ done (done's inverse: .T)
    return OpenCVPicture(lambda frame: apply_direction(frame, rest), quarter)
