"""Buffer -> numpy through real pipelines, for every supported format at sizes that force row padding.

Reference images are built independently of gst_trafficcal.gst.buffers: the test lays out (or
unpacks) bytes itself with GStreamer's default stride rule (rows rounded up to 4 bytes) and
converts with cv2.cvtColor on packed data.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

pytestmark = pytest.mark.gst

from gst_trafficcal.gst._gi import Gst, GstVideo  # noqa: E402
from gst_trafficcal.gst.buffers import (  # noqa: E402
    SUPPORTED_FORMATS,
    buffer_from_bgr,
    buffer_from_planes,
    frame_bgr,
    frame_gray,
    frame_planes,
    plane_layouts,
    video_caps_string,
    video_info_from_caps,
)
from gst_trafficcal.gst.element import register_plugin_file  # noqa: E402
from gst_trafficcal.gst.pipeline import run_pipeline  # noqa: E402

PLUGINS = Path(__file__).resolve().parent / "gst_plugins" / "python"
SIZES = [(322, 242), (641, 361)]


def _ru4(n: int) -> int:
    return (n + 3) // 4 * 4


def _test_image(w: int, h: int, seed: int = 0) -> np.ndarray:
    """A BGR image with smooth gradients and some noise (chroma subsampling stays well-behaved)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    img = np.dstack([40 + 170 * xx / w, 30 + 180 * yy / h, 128 + 90 * np.sin(xx / 23.0 + yy / 17.0)])
    img += rng.normal(0, 6, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def _packed_planes(fmt: str, bgr: np.ndarray) -> list[np.ndarray]:
    """The packed planes of ``bgr`` in ``fmt`` by cv2 alone (4:2:0 needs even sizes)."""
    h, w = bgr.shape[:2]
    if fmt == "GRAY8":
        return [cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)]
    if fmt == "BGR":
        return [bgr]
    if fmt == "RGB":
        return [cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)]
    if fmt == "BGRx":
        return [cv2.cvtColor(bgr, cv2.COLOR_BGR2BGRA)]
    flat = cv2.cvtColor(bgr, cv2.COLOR_BGR2YUV_I420).ravel()
    n, q = w * h, w * h // 4
    y, u, v = flat[:n].reshape(h, w), flat[n:n + q].reshape(h // 2, w // 2), flat[n + q:].reshape(h // 2, w // 2)
    return [y, u, v] if fmt == "I420" else [y, np.dstack([u, v])]


def _default_layout(fmt: str, w: int, h: int) -> list[tuple[int, int, tuple[int, ...]]]:
    """(offset, stride, packed shape) per plane with GStreamer's default strides, computed here."""
    cw, ch = (w + 1) // 2, (h + 1) // 2
    if fmt == "GRAY8":
        return [(0, _ru4(w), (h, w))]
    if fmt in ("BGR", "RGB"):
        return [(0, _ru4(3 * w), (h, w, 3))]
    if fmt == "BGRx":
        return [(0, 4 * w, (h, w, 4))]
    ys, yrows = _ru4(w), 2 * ch  # 4:2:0: the luma plane reserves an even number of rows
    if fmt == "I420":
        cs = _ru4(cw)
        return [(0, ys, (h, w)), (ys * yrows, cs, (ch, cw)), (ys * yrows + cs * ch, cs, (ch, cw))]
    return [(0, ys, (h, w)), (ys * yrows, _ru4(2 * cw), (ch, cw, 2))]


def _pack(fmt: str, planes: list[np.ndarray], w: int, h: int) -> bytes:
    layout = _default_layout(fmt, w, h)
    end = max(off + stride * (shape[0] + (shape[0] % 2 if i == 0 and len(layout) > 1 else 0))
              for i, (off, stride, shape) in enumerate(layout))
    raw = np.full(end, 0xAB, np.uint8)  # padding filled with a value that must never show up
    for (off, stride, shape), plane in zip(layout, planes):
        rowbytes = int(np.prod(shape[1:]))
        rows = raw[off:off + stride * shape[0]].reshape(shape[0], stride)
        rows[:, :rowbytes] = plane.reshape(shape[0], rowbytes)
    return raw.tobytes()


def _unpack(fmt: str, data: bytes, w: int, h: int) -> list[np.ndarray]:
    raw = np.frombuffer(data, np.uint8)
    out = []
    for off, stride, shape in _default_layout(fmt, w, h):
        rowbytes = int(np.prod(shape[1:]))
        out.append(raw[off:off + stride * shape[0]].reshape(shape[0], stride)[:, :rowbytes].reshape(shape).copy())
    return out


def _reference_bgr(fmt: str, planes: list[np.ndarray]) -> np.ndarray:
    """cv2's conversion of packed planes to BGR (4:2:0 formats cropped to even sizes)."""
    if fmt == "GRAY8":
        return cv2.cvtColor(planes[0], cv2.COLOR_GRAY2BGR)
    if fmt == "BGR":
        return planes[0]
    if fmt == "RGB":
        return cv2.cvtColor(planes[0], cv2.COLOR_RGB2BGR)
    if fmt == "BGRx":
        return cv2.cvtColor(planes[0], cv2.COLOR_BGRA2BGR)
    y = planes[0]
    h, w = y.shape[0] // 2 * 2, y.shape[1] // 2 * 2
    if fmt == "I420":
        u, v = planes[1][:h // 2, :w // 2], planes[2][:h // 2, :w // 2]
    else:
        u, v = planes[1][:h // 2, :w // 2, 0], planes[1][:h // 2, :w // 2, 1]
    packed = np.concatenate([y[:h, :w].ravel(), u.ravel(), v.ravel()]).reshape(h * 3 // 2, w)
    return cv2.cvtColor(packed, cv2.COLOR_YUV2BGR_I420)


def _reference_gray(fmt: str, planes: list[np.ndarray]) -> np.ndarray:
    if fmt in ("GRAY8", "I420", "NV12"):
        return planes[0]
    b, g, r = (planes[0][..., i].astype(np.float64) for i in ((0, 1, 2) if fmt in ("BGR", "BGRx") else (2, 1, 0)))
    return np.rint(16.0 + 219.0 / 255.0 * (0.299 * r + 0.587 * g + 0.114 * b)).astype(np.uint8)  # BT.601, 16-235


def _assert_gray(fmt: str, got: np.ndarray, ref: np.ndarray) -> None:
    """A luma plane as it is; a colour format's luma computed in float32 (cv2.transform) rounds a value lying on a
    half the other way now and then."""
    if fmt in ("GRAY8", "I420", "NV12"):
        np.testing.assert_array_equal(got, ref)
    else:
        assert got.shape == ref.shape and np.abs(got.astype(int) - ref).max() <= 1


def _assert_bgr_close(fmt: str, got: np.ndarray, ref: np.ndarray, luma: np.ndarray | None = None) -> None:
    got = got[: ref.shape[0], : ref.shape[1]]
    if fmt in ("I420", "NV12"):  # our exact BT.601 matrix vs cv2's fixed-point one
        diff = np.abs(got.astype(int) - ref.astype(int)).max(axis=2)
        if luma is not None:  # cv2 clamps super-black luma (Y < 16) before converting; we do not
            diff = diff[luma[: ref.shape[0], : ref.shape[1]] >= 16]
        assert diff.max() <= 2, f"max difference {diff.max()}"
        assert diff.mean() < 0.6
    else:
        np.testing.assert_array_equal(got, ref)


def _caps(fmt: str, w: int, h: int) -> str:
    return f"video/x-raw,format={fmt},width={w},height={h},framerate=25/1"


@pytest.mark.parametrize("w,h", SIZES)
@pytest.mark.parametrize("fmt", SUPPORTED_FORMATS)
def test_appsrc_to_appsink_padded_layout(fmt: str, w: int, h: int) -> None:
    """Bytes laid out by the test with padded rows come back as the right images."""
    bgr = _test_image(w, h)
    if fmt in ("I420", "NV12") and (w % 2 or h % 2):  # odd sizes: chroma planes of ceil(h/2) x ceil(w/2)
        big = _packed_planes(fmt, _test_image(w + w % 2, h + h % 2))
        planes = [big[0][:h, :w]] + big[1:]
    else:
        planes = _packed_planes(fmt, bgr)
    data = _pack(fmt, planes, w, h)
    info = video_info_from_caps(_caps(fmt, w, h))
    assert len(data) == info.size, "test layout disagrees with GStreamer's default strides"
    got: dict[str, np.ndarray] = {}

    def check(buffer: Gst.Buffer, vinfo: GstVideo.VideoInfo) -> None:
        with frame_gray(buffer, vinfo) as gray:
            got["gray"] = gray.copy()
        with frame_bgr(buffer, vinfo) as img:
            got["bgr"] = img.copy()

    run = run_pipeline("appsrc name=src ! queue ! appsink name=sink", [Gst.Buffer.new_wrapped(data)],
                       _caps(fmt, w, h), on_buffer=check)
    assert len(run.frames) == 1 and run.frames[0].frame_size == (w, h) and run.frames[0].format == fmt
    assert got["gray"].shape == (h, w) and got["bgr"].shape == (h, w, 3)
    _assert_gray(fmt, got["gray"], _reference_gray(fmt, planes))
    _assert_bgr_close(fmt, got["bgr"], _reference_bgr(fmt, planes))


@pytest.mark.parametrize("fmt", SUPPORTED_FORMATS)
def test_videotestsrc_videoconvert_matches_independent_unpacking(fmt: str) -> None:
    """Frames produced by videoconvert at 641x361: frame_gray/frame_bgr equal cv2 on the test's own unpacking."""
    w, h = 641, 361
    got: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def check(buffer: Gst.Buffer, vinfo: GstVideo.VideoInfo) -> None:
        ok, mapinfo = buffer.map(Gst.MapFlags.READ)
        assert ok
        try:
            data = bytes(mapinfo.data)
        finally:
            buffer.unmap(mapinfo)
        with frame_gray(buffer, vinfo) as gray, frame_bgr(buffer, vinfo) as img:
            got.append((data, gray.copy(), img.copy()))

    desc = (f"videotestsrc num-buffers=2 pattern=smpte ! video/x-raw,format=I420,width={w},height={h} ! "
            f"videoconvert ! video/x-raw,format={fmt},colorimetry=bt601 ! appsink name=sink")
    run = run_pipeline(desc, on_buffer=check)
    assert len(run.frames) == 2
    for data, gray, img in got:
        planes = _unpack(fmt, data, w, h)
        _assert_gray(fmt, gray, _reference_gray(fmt, planes))
        _assert_bgr_close(fmt, img, _reference_bgr(fmt, planes), luma=planes[0])
        assert gray.std() > 20  # a real picture, not a blank buffer


def test_grey_images_agree_across_formats() -> None:
    """The same picture delivered in every format gives consistent grey images.

    YUV and GRAY8 give the (limited-range) luma plane itself, identical across them; packed RGB
    formats give cv2's luma in the same 16-235 range, which matches the Y plane except where
    videotestsrc's out-of-gamut bars were clipped: the detectors see the same image in any format.
    """
    w, h = 322, 242
    grays = {}
    for fmt in SUPPORTED_FORMATS:
        desc = (f"videotestsrc num-buffers=1 pattern=smpte ! video/x-raw,format=I420,width={w},height={h} ! "
                f"videoconvert ! video/x-raw,format={fmt} ! appsink name=sink")
        grays[fmt] = run_pipeline(desc, keep_gray=True).frames[0].gray.astype(float)
    for fmt in ("NV12", "GRAY8"):
        np.testing.assert_array_equal(grays[fmt], grays["I420"])
    for fmt in ("RGB", "BGRx"):
        np.testing.assert_array_equal(grays[fmt], grays["BGR"])
    diff = np.abs(grays["BGR"] - grays["I420"])
    assert np.median(diff) <= 2 and diff.mean() < 7


def test_buffer_with_video_meta_uses_its_strides() -> None:
    """A buffer whose GstVideoMeta declares wide custom strides (like a decoder's) is read through them."""
    w, h = 322, 242
    bgr = _test_image(w, h, seed=3)
    y, u, v = _packed_planes("I420", bgr)
    strides, rows = [512, 256, 256], [h + 8, h // 2 + 4, h // 2 + 4]  # extra rows too, as hardware decoders do
    offsets = [0, strides[0] * rows[0], strides[0] * rows[0] + strides[1] * rows[1]]
    raw = np.full(offsets[2] + strides[2] * rows[2], 0x11, np.uint8)
    for off, stride, plane in zip(offsets, strides, (y, u, v)):
        raw[off:off + stride * plane.shape[0]].reshape(plane.shape[0], stride)[:, :plane.shape[1]] = plane
    buf = Gst.Buffer.new_wrapped(raw.tobytes())
    GstVideo.buffer_add_video_meta_full(buf, GstVideo.VideoFrameFlags.NONE, GstVideo.VideoFormat.I420, w, h, 3,
                                        offsets + [0], strides + [0])
    got = {}

    def check(buffer: Gst.Buffer, vinfo: GstVideo.VideoInfo) -> None:
        assert [p.stride for p in plane_layouts(buffer, vinfo)] == strides
        with frame_gray(buffer, vinfo) as gray, frame_bgr(buffer, vinfo) as img:
            got["gray"], got["bgr"] = gray.copy(), img.copy()

    run_pipeline("appsrc name=src ! appsink name=sink", [buf], _caps("I420", w, h), on_buffer=check)
    np.testing.assert_array_equal(got["gray"], y)
    _assert_bgr_close("I420", got["bgr"], _reference_bgr("I420", [y, u, v]))


@pytest.mark.parametrize("fmt", SUPPORTED_FORMATS)
def test_writable_planes_draw_in_place_through_an_element(fmt: str) -> None:
    """tcmarker draw-border=true writes into the buffer via frame_planes(writable=True)."""
    register_plugin_file(PLUGINS / "tcmarker.py")
    w, h = 322, 242
    bgr = np.full((h, w, 3), 200, np.uint8)
    run = run_pipeline("appsrc name=src ! tcmarker draw-border=true threshold=255 ! appsink name=sink",
                       [bgr], _caps(fmt, w, h), keep_gray=True)
    gray = run.frames[0].gray
    black = 16 if fmt in ("BGR", "RGB", "BGRx") else 0  # a black RGB pixel is a Y plane's black, 16
    for edge in (gray[0], gray[-1], gray[:, 0], gray[:, -1]):
        assert (edge == black).all()
    inner = gray[2:-2, 2:-2]
    assert inner.min() == inner.max() and inner.min() > 150  # untouched interior
    assert run.frames[0].rois == []  # nothing above threshold 255


def test_writable_mapping_of_shared_buffer_does_not_touch_the_original() -> None:
    """Drawing in place on one tee branch leaves the other branch's picture intact (copy-on-write)."""
    register_plugin_file(PLUGINS / "tcmarker.py")
    w, h = 64, 48
    frame = np.full((h, w), 180, np.uint8)
    desc = ("appsrc name=src ! tee name=t t. ! queue ! tcmarker draw-border=true ! fakesink "
            "t. ! queue ! appsink name=sink")
    run = run_pipeline(desc, [frame], _caps("GRAY8", w, h), keep_gray=True)
    assert (run.frames[0].gray == 180).all()


def test_frame_planes_views_are_read_only_unless_writable() -> None:
    info = video_info_from_caps(_caps("NV12", 322, 242))
    buf = buffer_from_bgr(_test_image(322, 242), info)
    with frame_planes(buf, info) as planes:
        assert [p.shape for p in planes] == [(242, 322), (121, 161, 2)]
        assert not planes[0].flags.writeable
        with pytest.raises(ValueError):
            planes[0][0, 0] = 1
    with frame_planes(buf, info, writable=True) as planes:
        planes[0][5, 7] = 99
    with frame_gray(buf, info) as gray:
        assert gray[5, 7] == 99


def test_short_buffer_and_bad_caps_give_clear_errors() -> None:
    info = video_info_from_caps(_caps("BGR", 322, 242))
    short = Gst.Buffer.new_wrapped(bytes(1000))
    with pytest.raises(ValueError, match="too small"):
        with frame_gray(short, info):
            pass
    with pytest.raises(ValueError, match="unsupported video format 'YUY2'"):
        video_info_from_caps(_caps("YUY2", 64, 48))
    with pytest.raises(ValueError, match="not raw"):
        video_info_from_caps("video/x-h264,stream-format=byte-stream,alignment=au")
    assert Gst.Caps.from_string(video_caps_string()).is_subset(Gst.Caps.from_string("video/x-raw"))


def test_ctypes_mapping_fallback_writes_in_place(monkeypatch: pytest.MonkeyPatch) -> None:
    """The ctypes gst_buffer_map path (for gst-python versions with read-only WRITE maps) works the same."""
    import gst_trafficcal.gst.buffers as buffers

    assert buffers._PYGOBJECT_WRITABLE_MAPS  # Debian bookworm's gst-python 1.22
    monkeypatch.setattr(buffers, "_PYGOBJECT_WRITABLE_MAPS", False)
    info = video_info_from_caps(_caps("I420", 322, 242))
    buf = buffer_from_bgr(_test_image(322, 242), info)
    with frame_planes(buf, info, writable=True) as planes:
        assert planes[0].flags.writeable and [p.shape for p in planes] == [(242, 322), (121, 161), (121, 161)]
        planes[0][3, 4] = 7
        planes[2][10, 11] = 201
    ok, mapinfo = buf.map(Gst.MapFlags.READ)
    try:
        raw = bytes(mapinfo.data)
    finally:
        buf.unmap(mapinfo)
    assert raw[3 * info.stride[0] + 4] == 7 and raw[info.offset[2] + 10 * info.stride[2] + 11] == 201
    test_writable_planes_draw_in_place_through_an_element("NV12")  # and through a real pipeline


@pytest.mark.parametrize("colorimetry", ["bt601", "bt709"])
def test_yuv_to_bgr_follows_the_caps_colorimetry(colorimetry: str) -> None:
    """frame_bgr on I420 agrees with videoconvert's own YUV->BGR for the colour matrix in the caps.

    On 100 % colour bars BT.601 and BT.709 differ by tens of levels: decoding the same planes with
    the other matrix must disagree with videoconvert.
    """
    caps = f"video/x-raw,format=I420,width=640,height=360,colorimetry={colorimetry}"
    src = f"videotestsrc num-buffers=1 pattern=smpte100 ! {caps}"
    out: dict[str, np.ndarray] = {}
    planes: list[np.ndarray] = []

    def grab(name: str):
        def cb(buffer: Gst.Buffer, vinfo: GstVideo.VideoInfo) -> None:
            with frame_bgr(buffer, vinfo) as img:
                out[name] = img.astype(int)
            if name == "ours":
                with frame_planes(buffer, vinfo) as views:
                    planes.extend(v.copy() for v in views)
        return cb

    run_pipeline(f"{src} ! appsink name=sink", on_buffer=grab("ours"))
    run_pipeline(f"{src} ! videoconvert ! video/x-raw,format=BGR ! appsink name=sink", on_buffer=grab("videoconvert"))
    diff = np.abs(out["ours"] - out["videoconvert"])
    assert np.median(diff) <= 2 and np.percentile(diff, 99) <= 6
    other = "bt709" if colorimetry == "bt601" else "bt601"
    info = video_info_from_caps(caps.replace(colorimetry, other))
    with frame_bgr(buffer_from_planes(planes, info), info) as wrong:
        assert np.percentile(np.abs(wrong.astype(int) - out["videoconvert"]), 99) > 10


def test_the_stream_clock_never_goes_back():
    """Timestamps as they come: a plain stream is its timestamps; parts joined (each from 0 again) and a seek back
    go on one frame interval after the last buffer; unset timestamps stay unset."""
    from gst_trafficcal.gst.buffers import StreamClock

    clock = StreamClock()
    times = [clock(0.04 * k) for k in range(100)]
    assert times == [round(0.04 * k, 9) for k in range(100)] and clock.jumps == []
    again = [clock(0.04 * k) for k in range(50)]  # a second part from 0
    assert again[0] == pytest.approx(4.0) and np.allclose(np.diff(again), 0.04) and clock.jumps == [(0.0, 4.0)]
    assert clock(1.0) == pytest.approx(5.96 + 0.04)  # a seek back to 1 s
    assert clock(1.04) == pytest.approx(6.04) and len(clock.jumps) == 2
    assert clock(None) is None
    assert clock(1.04) == pytest.approx(6.04)  # the same timestamp twice is not a jump


def test_a_frame_out_of_order_keeps_the_stream_clock_on_its_timestamps():
    """A frame a frame interval back between two going on (a camera's B-frames with wrong timestamps): it gets the
    time of the frame before it, and the clock stays on the timestamps — each such frame moved the time on by a frame
    for good (40 of them in 48 s of stream: 1.6 s ahead, every speed across one too low).  Two steps back in a row
    are a jump after all (reverse playback), said from the first of them."""
    from gst_trafficcal.gst.buffers import StreamClock

    clock = StreamClock()
    order = list(range(1200))
    for k in range(10, 1190, 30):  # frames k and k + 1 swapped, 40 times
        order[k], order[k + 1] = order[k + 1], order[k]
    times = [clock(0.04 * k) for k in order]
    assert clock.jumps == [] and clock.out_of_order == 40
    assert times[-1] == pytest.approx(0.04 * 1199)
    assert times[11] == times[10] == pytest.approx(0.44) and times[12] == pytest.approx(0.48)

    reverse = StreamClock()
    times = [reverse(0.04 * (60 - k)) for k in range(6)]
    assert reverse.jumps[0] == (pytest.approx(2.36), pytest.approx(2.44)) and reverse.out_of_order == 0
    assert all(b >= a for a, b in zip(times, times[1:]))


@pytest.mark.shared
@pytest.mark.parametrize("fmt", SUPPORTED_FORMATS)
def test_frame_bgr_reduced_equals_the_full_conversion_reduced(fmt: str) -> None:
    """``frame_bgr(..., size)`` of a real 1080p frame (BrnoCompSpeed's screen.png through videoconvert) is
    ``imaging.fit`` of the full conversion: exactly for packed formats, within rounding and the clipping of
    out-of-gamut pixels for YUV, whose planes are reduced before the colour matrix."""
    from gst_trafficcal.imaging import fit

    from .conftest import BRNO, require_shared

    image = cv2.imread(str(require_shared(BRNO / "session0_center" / "screen.png")))
    assert image.shape == (1080, 1920, 3)
    caps = "video/x-raw,format=BGR,width=1920,height=1080,framerate=25/1"
    got: dict[str, np.ndarray] = {}

    def check(buffer: Gst.Buffer, vinfo: GstVideo.VideoInfo) -> None:
        with frame_bgr(buffer, vinfo) as full:
            got["full"] = fit(full, (480, 270)).astype(int)
        with frame_bgr(buffer, vinfo, (480, 270)) as small:
            got["small"] = small.astype(int)
        with frame_bgr(buffer, vinfo, (1920, 1080)) as same:  # the frame's own size: no reduction
            got["same"] = same.copy()

    run_pipeline(f"appsrc name=src ! videoconvert ! video/x-raw,format={fmt} ! appsink name=sink",
                 [buffer_from_bgr(image, video_info_from_caps(Gst.Caps.from_string(caps)))], caps, on_buffer=check)
    assert got["small"].shape == (270, 480, 3) and got["same"].shape == (1080, 1920, 3)
    diff = np.abs(got["small"] - got["full"])
    if fmt in ("I420", "NV12"):
        assert diff.mean() < 0.5 and np.percentile(diff, 99.9) <= 2 and diff.max() <= 12, (diff.mean(), diff.max())
    else:
        assert diff.max() == 0
    assert got["full"].std() > 30  # a real picture


def test_the_stream_clock_after_a_flush_and_by_an_offset_given():
    """The first frame after a flushing seek is another moment: a frame back goes on one interval after the last
    (not a frame out of order, given the last time again), no interval is measured across a seek forward; a clock
    that saw fewer frames (flushed on their way to it) follows the offset given from upstream to the same times,
    and never goes back for one."""
    from gst_trafficcal.gst.buffers import StreamClock

    up, down = StreamClock(), StreamClock()
    for k in range(150):  # up saw 6 s, down 3 s: the rest was in a queue when the seek came
        up(0.04 * k)
        if k <= 75:
            down(0.04 * k)
    assert up(5.92, flushed=True) == pytest.approx(6.0) and up.jumps == [(5.92, pytest.approx(6.0))]
    assert down.follow(5.92, up.offset) == up.last and down.jumps == [(5.92, up.last)]
    assert [up(5.96), up(6.0)] == [down(5.96), down(6.0)] == [pytest.approx(6.04), pytest.approx(6.08)]
    assert up(20.0, flushed=True) == 20.08 and up(20.04) == pytest.approx(20.12) and max(up._steps) < 0.05
    assert down.follow(1.0, 0.0) == pytest.approx(6.12) and len(down.jumps) == 2  # an offset that would go back
