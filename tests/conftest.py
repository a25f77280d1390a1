"""Shared test fixtures: where the shared data lives, and skipping when it is absent."""

from __future__ import annotations

import json
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
BRNO = SHARED / "data" / "brnocompspeed"
VIDEOS = SHARED / "data" / "videos"
DETECTORS = SHARED / "models" / "detectors"
RECORDINGS = [f"session{s}_{p}" for s in range(4) for p in ("center", "left", "right")]


@pytest.fixture(scope="session")
def load_benchmark():
    """``load_benchmark("scale")`` imports benchmarks/scale.py (the benchmarks are scripts, not a package), with
    benchmarks/ on the path as when it runs (the scripts import their siblings, e.g. options.py)."""
    import importlib.util

    if str(ROOT / "benchmarks") not in sys.path:
        sys.path.insert(0, str(ROOT / "benchmarks"))

    def load(name: str):
        spec = importlib.util.spec_from_file_location(f"{name}_benchmark", ROOT / "benchmarks" / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module  # a dataclass's string annotations are resolved through sys.modules
        spec.loader.exec_module(module)
        return module

    return load


def serve_rtsp(launch: str, mount: str, drop_on_stop: bool = False):
    """Serve ``launch`` (a gst-rtsp-server media description, payloader ``pay0``) over RTSP from a server running
    in this process; yields its ``rtsp://127.0.0.1:PORT/mount`` URL.  For generator fixtures: skips the test
    without Debian's gir1.2-gst-rtsp-server-1.0.  ``drop_on_stop``: the server closes a client's connection when
    it asks PAUSE or TEARDOWN (as a camera may), so rtspsrc fails while it is stopped, whichever it sends."""
    import threading

    import gi

    try:
        gi.require_version("GstRtspServer", "1.0")
        gi.require_version("GstRtsp", "1.0")
        from gi.repository import GstRtsp, GstRtspServer
    except (ValueError, ImportError):
        pytest.skip("needs the GstRtspServer introspection data (Debian: gir1.2-gst-rtsp-server-1.0)")
    from gst_trafficcal.gst._gi import GLib

    ctx = GLib.MainContext.new()
    loop = GLib.MainLoop.new(ctx, False)
    server = GstRtspServer.RTSPServer.new()
    server.set_service("0")
    factory = GstRtspServer.RTSPMediaFactory.new()
    factory.set_launch(launch)
    server.get_mount_points().add_factory(f"/{mount}", factory)
    if drop_on_stop:
        def drop(client, _context):
            client.close()
            return GstRtsp.RTSPStatusCode.OK

        def watch(_server, client):
            client.connect("pre-pause-request", drop)
            client.connect("pre-teardown-request", drop)

        server.connect("client-connected", watch)
    server.attach(ctx)
    thread = threading.Thread(target=loop.run, daemon=True)
    thread.start()
    try:
        yield f"rtsp://127.0.0.1:{server.get_bound_port()}/{mount}"
    finally:
        loop.quit()
        thread.join(10)


def require_shared(path: Path) -> Path:
    """Skip the calling test with a reason when a file of ../shared is not there."""
    if not path.exists():
        pytest.skip(f"needs the shared test data: {path} is absent")
    return path


@pytest.fixture
def brno_dir() -> Path:
    return require_shared(BRNO)


# A small two-way motorway rendered with cuboid vehicles (exact silhouettes): 12 s at 12.5 fps, 480x270 (a few
# seconds to render). Shared by the run, pipelines and speedometer tests; rendered once per session and flow.
CUBOID_SCENE = {"base": "highway_day", "duration": 12, "seed": 4, "camera": {"resolution": [480, 270]},
                "traffic": {"flow": 600, "speed_std": 15}, "imaging": {"fps": 12.5, "noise": 1.0}}


def _render_cuboid_clip(tmp_path_factory, flow: int) -> Path:
    from gst_trafficcal.synth.generate import generate
    from gst_trafficcal.synth.scenario import scenario_from_dict
    from gst_trafficcal.synth.traffic import cuboid_models

    scene = {**CUBOID_SCENE, "traffic": {**CUBOID_SCENE["traffic"], "flow": flow}}
    out = tmp_path_factory.mktemp(f"cuboid_clip_{flow}")
    generate(scenario_from_dict(scene), out, box_vehicles=True, model_factory=cuboid_models())
    return out


@pytest.fixture(scope="session")
def cuboid_clip(tmp_path_factory) -> Path:
    """Folder of the cuboid clip (video.mp4, calibration.json, gt_data.pkl, ...) at 600 vehicles/h."""
    return _render_cuboid_clip(tmp_path_factory, 600)


@pytest.fixture(scope="session")
def cuboid_clip_dense(tmp_path_factory) -> Path:
    """The same clip at 1500 vehicles/h: enough edges on vehicles for VP2 within 8 s."""
    return _render_cuboid_clip(tmp_path_factory, 1500)


def track_spans(frames) -> dict[int, list[float]]:
    """[first, last] PTS of each track id in the frames of a :func:`gst_trafficcal.gst.pipeline.run_pipeline` run."""
    spans: dict[int, list[float]] = {}
    for f in frames:
        for r in f.rois:
            if r.object_id is not None:
                spans.setdefault(r.object_id, [f.pts, f.pts])[1] = f.pts
    return spans


def count_frames(path: Path) -> int:
    """How many frames OpenCV decodes from a video file (0 for one it cannot read, e.g. an MP4 without its index)."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    n = 0
    while cap.read()[0]:
        n += 1
    cap.release()
    return n


def encoded(dst: Path, caps: str, frames: int = 100, src: Path | None = None) -> Path:
    """An H.264 MP4 ``dst`` of exactly ``frames`` frames of raw video ``caps`` (e.g. ``width=480,height=360,
    pixel-aspect-ratio=4/3``: stored squeezed, as a DVR's D1): the first frames of the video ``src`` (cut by
    :func:`cut_after`: ``identity eos-after`` behind a decoder lets more through, varying with the load), or of
    videotestsrc's still colour bars (``num-buffers``: its one thread makes no more).  x264enc on one thread: with
    two its frames differ from run to run (as trafficcal synth's encoder says), and what is measured on them too."""
    from gst_trafficcal.gst.pipeline import run_pipeline

    tail = (f"videoconvert ! videoscale ! video/x-raw,{caps} ! x264enc speed-preset=ultrafast threads=1 ! mp4mux ! "
            f"filesink location=\"{dst}\"")
    if src is None:
        run_pipeline(f"videotestsrc pattern=smpte num-buffers={frames} ! {tail}", timeout=120)
    else:
        run_pipeline(cut_after(f"filesrc location=\"{src}\" ! decodebin ! identity name=cut ! {tail}", frames),
                     timeout=120)
    return dst


def rotation_tagged(src: Path, dst: Path, degrees: int | str = 90) -> Path:
    """``src`` (an MP4 of one video track) with the display matrix a phone writes for a picture taken turned by
    ``degrees`` clockwise (the track header's matrix; the frames stay as stored): players, OpenCV and GStreamer's
    ``videoflip video-direction=auto`` show it turned upright.  ``degrees`` may also name a mirroring as videoflip's
    video-direction does: "horiz", "vert", "ul-lr" (the picture transposed), "ur-ll" (across the other diagonal)."""
    import struct

    data = bytearray(src.read_bytes())
    i = data.find(b"tkhd")
    assert i > 0 and data.count(b"tkhd") == 1, "one video track expected"
    # after the box's type: version and flags, 3 times and the track id and a reserved word (of 4 or 8 bytes),
    # the duration, 8 reserved bytes, then layer, alternate group, volume and 2 reserved bytes
    start = i + 4 + 4 + (8 + 8 + 4 + 4 + 8 if data[i + 4] == 1 else 4 + 4 + 4 + 4 + 4) + 8 + 8
    # (a, b, c, d): a stored pixel (x, y) is shown at (a x + c y, b x + d y) (ISO/IEC 14496-12's matrix)
    a, b, c, d = {90: (0, 1, -1, 0), 180: (-1, 0, 0, -1), 270: (0, -1, 1, 0), "horiz": (-1, 0, 0, 1),
                  "vert": (1, 0, 0, -1), "ul-lr": (0, 1, 1, 0), "ur-ll": (0, -1, -1, 0)}[degrees]
    struct.pack_into(">9i", data, start, a << 16, b << 16, 0, c << 16, d << 16, 0, 0, 0, 1 << 30)
    dst.write_bytes(bytes(data))
    return dst


def closed_port() -> int:
    """A local TCP port nobody listens on (bound for a moment, then released): connections to it are refused."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Receiver:
    """A webhook receiver (an in-process HTTP server on localhost): keeps the JSON it is sent; answers with
    ``statuses`` in turn (then 200) after ``delay`` seconds."""

    def __init__(self, statuses=(), delay=0.0):
        self.bodies: list[dict] = []
        self.raw: list[bytes] = []  # each accepted body as sent (signatures are over these bytes)
        self.headers: list[dict] = []
        self.statuses = list(statuses)
        self.delay = delay
        receiver = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self):
                body = self.rfile.read(int(self.headers["Content-Length"]))
                time.sleep(receiver.delay)
                status = receiver.statuses.pop(0) if receiver.statuses else 200
                if status == 200:
                    receiver.bodies.append(json.loads(body))
                    receiver.raw.append(body)
                    receiver.headers.append(dict(self.headers))
                self.send_response(status)
                self.end_headers()

            def log_message(self, *args):
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_port}/events"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def close(self):
        self.server.shutdown()
        self.server.server_close()


def switch_after(pipeline, selector_name: str, buffers: int, to_pad: str = "sink_1") -> None:
    """Switch the ``input-selector`` ``selector_name`` of ``pipeline`` to its pad ``to_pad`` once ``buffers`` buffers
    have gone through it (asked from the application's side, as a user's camera switch is).  The active pad's next
    buffer waits before the selector until the switch is done, and is then dropped there as an inactive pad's: the
    switch comes after exactly ``buffers`` frames, and no frame of the old source is on its way downstream when the
    new one starts (asked as the buffer left, on a loaded machine the old source's last frames went through before
    the switch came, or one was still on its way and reached the elements among the new source's first)."""
    import threading

    from gst_trafficcal.gst._gi import Gst

    sel, entered, switched = pipeline.get_by_name(selector_name), [], threading.Event()

    def ask(_pipeline):
        sel.set_property("active-pad", sel.get_static_pad(to_pad))
        switched.set()

    def hold(_pad, _info):
        entered.append(True)
        if len(entered) == buffers + 1:
            pipeline.call_async(ask)
            switched.wait(30)
        return Gst.PadProbeReturn.OK

    for pad in sel.sinkpads:  # (the active one: the selector chooses it as data comes)
        if pad.get_name() != to_pad:
            pad.add_probe(Gst.PadProbeType.BUFFER, hold)


def first_frames(pad, frames: int) -> list[float]:
    """Let exactly ``frames`` frames through ``pad`` (a sink pad), then an end-of-stream and no more, whatever is on
    its way (``identity eos-after`` refuses one frame and then lets through those on their way: one of them seconds
    later, varying with the load); the frames' times in seconds, as they pass."""
    from gst_trafficcal.gst._gi import Gst

    passed: list[float] = []
    ended = []

    def probe(_pad, info):
        if len(passed) < frames:
            passed.append(info.get_buffer().pts / Gst.SECOND)
            return Gst.PadProbeReturn.OK
        if not ended:  # the frame after the last: an end-of-stream in its place (as gst.runner cuts a run)
            ended.append(True)
            _pad.send_event(Gst.Event.new_eos())
        return Gst.PadProbeReturn.DROP

    pad.add_probe(Gst.PadProbeType.BUFFER, probe)
    return passed


def cut_after(description: str, frames: int):
    """``description`` parsed, with exactly ``frames`` frames let through its ``identity name=cut`` and then an
    end-of-stream (:func:`first_frames`; ``identity eos-after`` is not an exact cut behind a decoder)."""
    from gst_trafficcal.gst._gi import Gst

    pipeline = Gst.parse_launch(description)
    first_frames(pipeline.get_by_name("cut").get_static_pad("sink"), frames)
    return pipeline


def seek_once(pipeline, pad, target_s: float, at_s: float = 6.0) -> list[bool]:
    """A flushing, accurate seek of ``pipeline`` to ``target_s`` when the first buffer at or after ``at_s`` passes
    ``pad`` (asked from the pipeline's thread, as a player does); the list returned holds True once it was asked.
    That buffer waits at ``pad`` until the seek's flush passes it: on a loaded machine the asking thread may come
    late, and the stream could end first."""
    import threading

    from gst_trafficcal.gst._gi import Gst

    sought: list[bool] = []
    flushing = threading.Event()

    def probe(_pad, info):
        if not sought and info.get_buffer().pts >= at_s * Gst.SECOND:
            sought.append(True)
            pipeline.call_async(lambda p: p.seek_simple(Gst.Format.TIME, Gst.SeekFlags.FLUSH | Gst.SeekFlags.ACCURATE,
                                                        int(target_s * Gst.SECOND)))
            flushing.wait(20)
        return Gst.PadProbeReturn.OK

    def flush(_pad, info):
        if info.get_event().type == Gst.EventType.FLUSH_START:
            flushing.set()
        return Gst.PadProbeReturn.OK

    pad.add_probe(Gst.PadProbeType.BUFFER, probe)
    pad.add_probe(Gst.PadProbeType.EVENT_FLUSH, flush)
    return sought
