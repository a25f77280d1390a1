"""Stride-aware access to raw video buffers as numpy arrays.

GStreamer pads rows (the default stride is rounded up to 4 bytes, decoders may add more and
describe it with a ``GstVideoMeta``), so a frame is never simply ``np.frombuffer(...).reshape``.
Every function here reads plane offsets and strides from the buffer's ``GstVideoMeta`` when it
has one, else from the ``GstVideo.VideoInfo`` of the negotiated caps.

The arrays yielded by the context managers below may be *views of the mapped memory*: use them
inside the ``with`` block only (``.copy()`` what you need to keep). The buffer is unmapped when
the block exits and a view kept past that point reads memory GStreamer may already have reused.

Supported formats: :data:`SUPPORTED_FORMATS` (GRAY8, I420, NV12, BGR, RGB, BGRx).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import cv2
import numpy as np

from ..imaging import fit
from . import _cgst
from ._gi import Gst, GstVideo

# Preference order: YUV first (the Y plane is the grey image for free), then packed RGB.
SUPPORTED_FORMATS: tuple[str, ...] = ("I420", "NV12", "GRAY8", "BGR", "BGRx", "RGB")

# (rows divisor, columns divisor, channels) of each plane, relative to the frame size.
_PLANES: dict[str, tuple[tuple[int, int, int], ...]] = {
    "GRAY8": ((1, 1, 1),),
    "I420": ((1, 1, 1), (2, 2, 1), (2, 2, 1)),
    "NV12": ((1, 1, 1), (2, 2, 2)),
    "BGR": ((1, 1, 3),),
    "RGB": ((1, 1, 3),),
    "BGRx": ((1, 1, 4),),
}


def video_caps_string(formats: tuple[str, ...] = SUPPORTED_FORMATS) -> str:
    """Caps string accepting raw system-memory video in ``formats`` at any size and rate."""
    return (
        f"video/x-raw, format=(string){{ {', '.join(formats)} }}, "
        "width=(int)[ 1, 2147483647 ], height=(int)[ 1, 2147483647 ], "
        "framerate=(fraction)[ 0/1, 2147483647/1 ]"
    )


def video_info_from_caps(caps: Gst.Caps | str) -> GstVideo.VideoInfo:
    """``GstVideo.VideoInfo`` for fixed raw-video caps in a supported format.

    Raises ValueError naming the caps when they are not raw video in one of
    :data:`SUPPORTED_FORMATS`.
    """
    if isinstance(caps, str):
        caps = Gst.Caps.from_string(caps)
    if caps is None or caps.is_empty() or not caps.is_fixed():
        raise ValueError(f"need fixed raw video caps, got {caps.to_string() if caps else None!r}")
    s = caps.get_structure(0)
    if s.get_name() != "video/x-raw" or not caps.get_features(0).is_equal(
        Gst.CapsFeatures.new_empty()
    ):
        raise ValueError(f"not raw system-memory video: {caps.to_string()}")
    fmt = s.get_string("format")
    if fmt not in SUPPORTED_FORMATS:
        raise ValueError(
            f"unsupported video format {fmt!r} (supported: {', '.join(SUPPORTED_FORMATS)}; "
            "put videoconvert in front)"
        )
    info = GstVideo.VideoInfo.new_from_caps(caps)
    if info is None:
        raise ValueError(f"cannot parse video caps {caps.to_string()}")
    return info


@dataclass(frozen=True)
class _InfoFacts:
    """What the frame accessors read from a VideoInfo: reading it through PyGObject costs tens of microseconds
    per field, which every element paid several times per frame (profiled: ~1 ms per 1080p frame in the chain)."""

    info: GstVideo.VideoInfo  # kept so that the id() key cannot be reused by another object
    format: str
    format_id: int
    size: tuple[int, int]
    offsets: tuple[int, ...]
    strides: tuple[int, ...]


_FACTS: dict[int, _InfoFacts] = {}


def _facts(info: GstVideo.VideoInfo) -> _InfoFacts:
    """The cached :class:`_InfoFacts` of ``info`` (VideoInfo objects are not changed after negotiation here)."""
    f = _FACTS.get(id(info))
    if f is not None and f.info is info:
        return f
    if len(_FACTS) > 64:  # one per negotiated caps and element; old ones are dropped
        _FACTS.clear()
    fid = info.finfo.format
    f = _FACTS[id(info)] = _InfoFacts(info, GstVideo.VideoFormat.to_string(fid), int(fid),
                                      (int(info.width), int(info.height)),
                                      tuple(int(v) for v in info.offset), tuple(int(v) for v in info.stride))
    return f


def format_name(info: GstVideo.VideoInfo) -> str:
    """Format name of ``info`` such as ``"I420"``."""
    return _facts(info).format


def frame_size(info: GstVideo.VideoInfo) -> tuple[int, int]:
    """(width, height) in pixels."""
    return _facts(info).size


@dataclass(frozen=True)
class PlaneLayout:
    """Where one plane lives in the mapped buffer."""

    offset: int
    stride: int
    rows: int
    cols: int
    channels: int


def plane_layouts(buffer: Gst.Buffer, info: GstVideo.VideoInfo) -> list[PlaneLayout]:
    """Plane layouts of ``buffer``: from its GstVideoMeta when present, else from ``info``."""
    facts = _facts(info)
    fmt = facts.format
    if fmt not in _PLANES:
        raise ValueError(f"unsupported video format {fmt!r} (supported: {', '.join(SUPPORTED_FORMATS)})")
    width, height = facts.size
    offsets, strides = facts.offsets, facts.strides
    vmeta = GstVideo.buffer_get_video_meta(buffer)
    if vmeta is not None:
        if (vmeta.width, vmeta.height) != (width, height) or int(vmeta.format) != facts.format_id:
            raise ValueError(
                f"buffer video meta {vmeta.width}x{vmeta.height} does not match caps {width}x{height} {fmt}"
            )
        offsets, strides = list(vmeta.offset), list(vmeta.stride)
    return [
        PlaneLayout(int(offsets[i]), int(strides[i]), -(-height // rdiv), -(-width // cdiv), ch)
        for i, (rdiv, cdiv, ch) in enumerate(_PLANES[fmt])
    ]


def _plane_view(data: memoryview, layout: PlaneLayout) -> np.ndarray:
    need = layout.offset + layout.stride * (layout.rows - 1) + layout.cols * layout.channels
    if layout.stride < layout.cols * layout.channels or len(data) < need:
        raise ValueError(
            f"buffer of {len(data)} bytes too small for a plane of {layout.rows}x{layout.cols}x"
            f"{layout.channels} at offset {layout.offset} with stride {layout.stride}"
        )
    shape: tuple[int, ...] = (layout.rows, layout.cols)
    strides: tuple[int, ...] = (layout.stride, layout.channels)
    if layout.channels > 1:
        shape += (layout.channels,)
        strides += (1,)
    return np.ndarray(shape, dtype=np.uint8, buffer=data, offset=layout.offset, strides=strides)


def _pygobject_maps_writable() -> bool:
    """Whether this gst-python's ``Buffer.map(WRITE)`` gives writable data (1.22: a writable memoryview)."""
    buf = Gst.Buffer.new_allocate(None, 1, None)
    mapinfo = buf.map(Gst.MapFlags.READ | Gst.MapFlags.WRITE)
    try:
        return isinstance(mapinfo.data, memoryview) and not mapinfo.data.readonly
    finally:
        buf.unmap(mapinfo)


_PYGOBJECT_WRITABLE_MAPS = _pygobject_maps_writable()


@contextmanager
def _mapped(buffer: Gst.Buffer, writable: bool) -> Iterator[memoryview]:
    if writable and not _PYGOBJECT_WRITABLE_MAPS:
        with _cgst.map_buffer(buffer, writable=True) as data:
            yield data
        return
    flags = Gst.MapFlags.READ | (Gst.MapFlags.WRITE if writable else 0)
    mapinfo = buffer.map(flags)
    ok, _ = mapinfo
    if not ok:
        raise RuntimeError(
            "cannot map buffer for writing (is it writable? in-place elements must not be in passthrough)"
            if writable
            else "cannot map buffer for reading"
        )
    try:
        yield mapinfo.data
    finally:
        buffer.unmap(mapinfo)


@contextmanager
def frame_planes(
    buffer: Gst.Buffer, info: GstVideo.VideoInfo, writable: bool = False
) -> Iterator[list[np.ndarray]]:
    """Yield numpy views of every plane of ``buffer`` (rows x cols[ x channels], uint8).

    Row padding is excluded through the array strides. With ``writable=True`` the views write
    straight into the buffer (draw in place); the buffer must then be writable, i.e. the element
    runs in place with passthrough off. Views are only valid inside the ``with`` block.
    """
    layouts = plane_layouts(buffer, info)
    with _mapped(buffer, writable) as data:
        planes = [_plane_view(data, lay) for lay in layouts]
        try:
            yield planes
        finally:
            del planes


@contextmanager
def frame_gray(buffer: Gst.Buffer, info: GstVideo.VideoInfo) -> Iterator[np.ndarray]:
    """Yield the frame as an HxW uint8 grey image.

    For GRAY8/I420/NV12 this is a read-only view of the Y plane (no copy: valid inside the
    ``with`` block only); for BGR/RGB/BGRx a converted copy: BT.601 luma in the 16-235 range of the Y plane a YUV
    stream of the same video carries (:func:`gst_trafficcal.vanishing.frames.luma`, as the CLI's frames), so that
    the detectors, trained and tuned on such planes, see the same image whichever format the pipeline negotiates
    (full-range luma of RGB made MOG2's boxes and the speeds worse on the same video).
    """
    fmt = format_name(info)
    if fmt in ("GRAY8", "I420", "NV12"):  # the luma plane only (no views of the chroma planes)
        layout = plane_layouts(buffer, info)[0]
        with _mapped(buffer, False) as data:
            gray = _plane_view(data, layout)
            try:
                yield gray
            finally:
                del gray
        return
    from ..vanishing.frames import luma

    with frame_planes(buffer, info) as planes:
        gray = luma(planes[0], fmt)
        try:
            yield gray
        finally:
            del gray


@contextmanager
def frame_bgr(buffer: Gst.Buffer, info: GstVideo.VideoInfo,
              size: tuple[int, int] | None = None) -> Iterator[np.ndarray]:
    """Yield the frame as an HxWx3 uint8 BGR image.

    A read-only view for BGR input, a converted copy otherwise. YUV input is converted with the
    colour matrix and range of the caps' colorimetry (BT.601/BT.709/..., limited or full range),
    chroma upsampled by pixel replication.

    With ``size`` (w, h) smaller than the frame, the frame reduced to that size (:func:`imaging.fit`) — for YUV
    input the planes are reduced first and only the small image is converted: what a detector working on a
    reduced image needs, at a fraction of the cost (1080p: no full-size BGR copy). Reduction and the colour
    matrix are both linear, so the two orders agree but for rounding and the clipping of out-of-gamut pixels.
    """
    fmt = format_name(info)
    reduced = tuple(size) if size is not None and tuple(size) != frame_size(info) else None
    with frame_planes(buffer, info) as planes:
        if fmt in ("I420", "NV12"):
            bgr = yuv420_to_bgr(planes, fmt, info, reduced)
        else:  # one plane (packed RGB or grey): converting maps each pixel alone, so reducing first changes nothing
            image = planes[0] if reduced is None else fit(planes[0], reduced)
            bgr = image if fmt == "BGR" else cv2.cvtColor(image, _TO_BGR[fmt])
        try:
            yield bgr
        finally:
            del bgr


_TO_BGR = {"RGB": cv2.COLOR_RGB2BGR, "BGRx": cv2.COLOR_BGRA2BGR, "GRAY8": cv2.COLOR_GRAY2BGR}


def _yuv_to_bgr_matrix(info: GstVideo.VideoInfo) -> np.ndarray:
    """3x4 affine matrix mapping (Y, U, V, 1) in 8-bit code values to (B, G, R)."""
    colorimetry = info.colorimetry
    ok, kr, kb = GstVideo.VideoColorMatrix.get_Kr_Kb(colorimetry.matrix)
    if not ok:  # unknown/RGB matrix on YUV data: GStreamer's own default for SD video
        kr, kb = 0.299, 0.114
    if colorimetry.range == getattr(GstVideo.VideoColorRange, "0_255"):
        y_off, y_scale, c_scale = 0.0, 255.0 / 255.0, 255.0 / 255.0
    else:  # 16-235 (and unknown, GStreamer's default for YUV)
        y_off, y_scale, c_scale = 16.0, 255.0 / 219.0, 255.0 / 224.0
    kg = 1.0 - kr - kb
    # R = Y + 2(1-kr) V ; B = Y + 2(1-kb) U ; G = (Y - kr R - kb B) / kg, with U,V centred.
    rows = {
        "R": (y_scale, 0.0, 2 * (1 - kr) * c_scale),
        "B": (y_scale, 2 * (1 - kb) * c_scale, 0.0),
    }
    g = (y_scale, -kb * 2 * (1 - kb) * c_scale / kg, -kr * 2 * (1 - kr) * c_scale / kg)
    m = np.zeros((3, 4), np.float64)
    for i, coef in enumerate((rows["B"], g, rows["R"])):
        m[i, :3] = coef
        m[i, 3] = -coef[0] * y_off - (coef[1] + coef[2]) * 128.0
    return m


def yuv420_to_bgr(planes: list[np.ndarray], fmt: str, info: GstVideo.VideoInfo,
                  size: tuple[int, int] | None = None) -> np.ndarray:
    """Convert I420/NV12 plane views to a packed HxWx3 BGR copy; with ``size`` (w, h), reduced to that size
    (each plane reduced with :func:`imaging.fit`, then converted)."""
    y = planes[0]
    h, w = y.shape
    if fmt == "I420":
        u, v = planes[1], planes[2]
    else:
        u, v = planes[1][:, :, 0], planes[1][:, :, 1]
    if size is not None:
        yuv = cv2.merge([fit(y, size), fit(u, size), fit(v, size)])
        return cv2.transform(yuv, _yuv_to_bgr_matrix(info))
    ch, cw = u.shape
    up = [cv2.resize(c, (2 * cw, 2 * ch), interpolation=cv2.INTER_NEAREST)[:h, :w] for c in (u, v)]
    yuv = cv2.merge([y, up[0], up[1]])
    return cv2.transform(yuv, _yuv_to_bgr_matrix(info))


def buffer_from_planes(planes: list[np.ndarray], info: GstVideo.VideoInfo) -> Gst.Buffer:
    """A new buffer holding ``planes`` laid out as ``info`` says (strides and offsets, padding zeroed).

    ``planes`` are packed arrays of each plane's shape (see :func:`frame_planes`); used to feed
    appsrc in tests and tools.
    """
    buf = Gst.Buffer.new_allocate(None, int(info.size), None)
    buf.memset(0, 0, int(info.size))
    with frame_planes(buf, info, writable=True) as views:
        if len(views) != len(planes):
            raise ValueError(f"{format_name(info)} has {len(views)} planes, got {len(planes)}")
        for view, plane in zip(views, planes):
            if view.shape != np.shape(plane):
                raise ValueError(f"plane shape {np.shape(plane)} != expected {view.shape}")
            view[...] = plane
    return buf


def buffer_from_bgr(bgr: np.ndarray, info: GstVideo.VideoInfo) -> Gst.Buffer:
    """A new buffer in ``info``'s format from a packed HxWx3 BGR image (cv2 conversions; BT.601)."""
    fmt = format_name(info)
    h, w = bgr.shape[:2]
    if (w, h) != frame_size(info):
        raise ValueError(f"image {w}x{h} does not match caps {frame_size(info)}")
    if fmt == "BGR":
        planes = [bgr]
    elif fmt == "RGB":
        planes = [cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)]
    elif fmt == "BGRx":
        planes = [cv2.cvtColor(bgr, cv2.COLOR_BGR2BGRA)]
    elif fmt == "GRAY8":
        planes = [cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)]
    else:
        if w % 2 or h % 2:
            raise ValueError(f"buffer_from_bgr needs even sizes for {fmt}, got {w}x{h}")
        flat = cv2.cvtColor(bgr, cv2.COLOR_BGR2YUV_I420).ravel()  # Y, then U and V of (h/2)x(w/2) each
        n, q = w * h, (w // 2) * (h // 2)
        y, u, v = flat[:n].reshape(h, w), flat[n : n + q].reshape(h // 2, w // 2), flat[n + q :].reshape(h // 2, w // 2)
        planes = [y, u, v] if fmt == "I420" else [y, np.dstack([u, v])]
    return buffer_from_planes(planes, info)


def pts_seconds(buffer: Gst.Buffer) -> float | None:
    """Presentation timestamp of ``buffer`` in seconds, None when unset (use this, not frame counts)."""
    pts = buffer.pts
    return None if pts == Gst.CLOCK_TIME_NONE else pts / Gst.SECOND


def stream_seconds(buffer: Gst.Buffer, segment: Gst.Segment | None) -> float | None:
    """Stream time of ``buffer`` in seconds — its timestamp as the position in the file, what a player shows —, None
    when it has no timestamp.  A file's timestamps need not start at 0 (a Matroska recording cut from a longer one,
    an NVR's file: its first frame at 3600 s with the segment saying so); the segment maps them to the file's own
    time, so vehicles are dated from its start and BrnoCompSpeed frame numbers count its frames.  Without a time
    segment (a plain live source's is the identity anyway) the timestamp itself."""
    pts = buffer.pts
    if pts == Gst.CLOCK_TIME_NONE:
        return None
    if segment is None or segment.format != Gst.Format.TIME:
        return pts / Gst.SECOND
    sign, value = segment.to_stream_time_full(Gst.Format.TIME, pts)
    if sign == 0:  # outside what the segment can map (no valid values): its timestamp
        return pts / Gst.SECOND
    return sign * value / Gst.SECOND


class StreamClock:
    """The elements' time of each buffer (seconds): its timestamp, but never going backwards.

    Timestamps that go back — recordings joined by ``concat`` (each part's start at 0 again), a seek back — would
    undo every speed and track; instead the time goes on one frame interval (the median of the last ones) after the
    last buffer, and stays that far ahead of the timestamps from then on.  One frame up to two frame intervals back
    whose follower goes forward again is a frame out of order (a camera's B-frames with wrong timestamps, UDP
    without a jitter buffer), not a new part: it is given the time of the frame before it and the timestamps keep
    their own time (each such frame used to move the time on by a frame for good: a second ahead after 25 of them,
    and every speed measured across one too low).  A second step back in a row is a jump after all (reverse
    playback).  Every element applies the same rule to the same buffers, so their times agree; after a flushing
    seek, whose flush dropped frames between the elements, those downstream take the offset of the first
    (:meth:`follow`).  A plain file or live stream is its timestamps exactly."""

    def __init__(self) -> None:
        self.offset = 0.0
        self.last: float | None = None
        self.jumps: list[tuple[float, float]] = []  # (timestamp gone back to, the time it was given instead)
        self.out_of_order = 0  # frames a little back between two going on, given the time before them
        self._steps: list[float] = []
        self._held: float | None = None  # the timestamp of the frame just held at the time before it
        self.switches: list[float] = []  # times given to the first frame of another stream that did not go on

    def __call__(self, pts_s: float | None, flushed: bool = False) -> float | None:
        """The time of a frame at stream time ``pts_s``; ``flushed``: the first timed frame after a flushing seek,
        another moment whichever way it went: not a frame out of order, and no frame interval measured across it."""
        if pts_s is None:
            return None
        t = pts_s + self.offset
        held, self._held = self._held, None
        if flushed:
            held = None
        if self.last is not None:
            if t < self.last or (flushed and t <= self.last):
                step = self.step
                if not flushed and held is None and self.last - t <= 2 * step + 1e-9:
                    self._held = pts_s
                    return self.last
                self.offset += self.last + step - t
                self.jumps.append((pts_s if held is None else held, self.last + step))  # from the frame held
                t = self.last + step
            else:
                if held is not None:  # the frame held is followed by one going on: it was out of order
                    self.out_of_order += 1
                if t > self.last and not flushed:
                    self._steps = (self._steps + [t - self.last])[-25:]
        self.last = t = round(t, 9)  # nanoseconds, as the timestamps (no float residue from the offset)
        return t

    def continues(self, pts_s: float) -> bool:
        """Whether a frame at stream time ``pts_s`` goes on from the last one: after it, by up to two frame intervals
        (a frame lost).  Asked of another stream's first frame (``input-selector`` switched to another source)."""
        if self.last is None:
            return True
        return self.last < pts_s + self.offset <= self.last + 2 * self.step + 1e-9

    @property
    def step(self) -> float:
        """The frame interval: the median of the last steps forward (0.04 s before any)."""
        return float(np.median(self._steps)) if self._steps else 0.04

    def catch_up(self, t: float | None) -> None:
        """Another element timing the same stream gave a frame the time ``t``: the next jump goes on after it too."""
        if t is not None and (self.last is None or t > self.last):
            self.last = t

    def follow(self, pts_s: float | None, offset: float) -> float | None:
        """The time of a frame at stream time ``pts_s`` by the ``offset`` an element upstream gave it
        (:mod:`.clock_event`): after a flushing seek the elements' clocks had seen different frames (those flushed
        on their way between them), and each going on from its own last frame would put them frames apart.  Should
        the offset take this clock back (it is not fed by that element alone), the frame is timed as a flushed one
        of its own."""
        if pts_s is None:
            return None
        t = round(pts_s + offset, 9)
        if self.last is not None and t < self.last:
            return self(pts_s, flushed=True)
        if offset > self.offset:
            self.jumps.append((pts_s, t))
        self.offset, self.last, self._held = offset, t, None
        return t
