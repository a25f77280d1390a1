"""H.264 MP4 writing through GStreamer's x264enc.

Constant frame rate: ``gst-launch-1.0`` runs as a subprocess reading raw I420 frames from its stdin
(``fdsrc ! rawvideoparse ! x264enc ! mp4mux ! filesink``), so the library needs no ``gi`` and encoding runs in
parallel with rendering.  Frames are converted RGB -> I420 with OpenCV (cheaper than videoconvert).
Videos with dropped frames need real timestamps with gaps, which raw stdin cannot carry; they go through
:mod:`gst_trafficcal.gst.encode` (appsrc with explicit PTS) instead.
"""

from __future__ import annotations

import shutil
import subprocess
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np

from ..errors import InputError


def _fps_fraction(fps: float) -> Fraction:
    return Fraction(fps).limit_denominator(1001)


def encoder_chain(bitrate: int, fps: float) -> str:
    """x264 settings shared by both writers: fast preset, keyframe every 2 s, no B-frames (low latency like
    IP cameras). One encoder thread: with two, x264enc's output differs from run to run, and a scene must
    give the same video every time (reproducible tests and benchmarks); rendering is the bottleneck anyway.
    It ends in a ``filesink`` whose location each writer sets outside the description's text (a path may hold
    spaces, quotes or "!")."""
    gop = max(int(round(2 * fps)), 1)
    return (f"x264enc bitrate={int(bitrate)} speed-preset=superfast key-int-max={gop} bframes=0 threads=1 "
            f"! video/x-h264,profile=high ! h264parse ! mp4mux ! filesink")


def _grow_pipe(pipe, size: int) -> None:
    """Let ``pipe`` hold ``size`` bytes (a whole frame, at most the system's limit, 1 MiB by default) so that
    writing a frame does not wait for the encoder to read it 64 KiB at a time (Linux only; else unchanged)."""
    try:
        import fcntl

        limit = int(Path("/proc/sys/fs/pipe-max-size").read_text())
        fcntl.fcntl(pipe.fileno(), fcntl.F_SETPIPE_SZ, min(size, limit))
    except (ImportError, AttributeError, OSError, ValueError):
        pass


class VideoWriter:
    """Write RGB frames to an H.264 MP4 file; use as a context manager."""

    def __init__(self, path: str | Path, size: tuple[int, int], fps: float, bitrate: int,
                 variable_timestamps: bool = False):
        self.path = Path(path)
        self.size = size
        self.fps = fps
        self._vfr = variable_timestamps
        self._proc: subprocess.Popen | None = None
        self._gst = None
        W, H = size
        if W % 2 or H % 2:
            raise InputError(f"video size must be even, got {W}x{H}")
        if variable_timestamps:
            from ..gst.encode import AppsrcH264Writer
            self._gst = AppsrcH264Writer(self.path, size, fps, encoder_chain(bitrate, fps))
            return
        exe = shutil.which("gst-launch-1.0")
        if exe is None:
            raise InputError("gst-launch-1.0 not found: install gstreamer1.0-tools to write videos")
        fr = _fps_fraction(fps)
        frame_bytes = W * H * 3 // 2
        pipeline = (f"fdsrc fd=0 blocksize={frame_bytes} ! rawvideoparse use-sink-caps=false width={W} height={H} "
                    f"format=i420 framerate={fr.numerator}/{fr.denominator} ! "
                    + encoder_chain(bitrate, fps))
        # the location as an argument of its own: gst-launch-1.0 escapes each argument (a path with spaces)
        self._proc = subprocess.Popen([exe, "-q", *pipeline.split(), f"location={self.path}"],
                                      stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        _grow_pipe(self._proc.stdin, frame_bytes)

    def write(self, rgb: np.ndarray, pts: float | None = None) -> None:
        """Append a frame (H, W, 3) uint8 RGB; ``pts`` (seconds) is used by variable-timestamp videos."""
        yuv = cv2.cvtColor(rgb, cv2.COLOR_RGB2YUV_I420)
        if self._gst is not None:
            self._gst.push(yuv, pts)
            return
        assert self._proc is not None and self._proc.stdin is not None
        try:
            self._proc.stdin.write(yuv.tobytes())
        except BrokenPipeError:
            err = self._proc.stderr.read().decode(errors="replace") if self._proc.stderr else ""
            raise InputError(f"{self.path}: video encoder stopped ({err.strip().splitlines()[-1:] or '?'})") from None

    def close(self) -> None:
        if self._gst is not None:
            self._gst.close()
            self._gst = None
            return
        if self._proc is not None:
            self._proc.stdin.close()
            rc = self._proc.wait()
            err = self._proc.stderr.read().decode(errors="replace") if self._proc.stderr else ""
            self._proc = None
            if rc != 0:
                raise InputError(f"{self.path}: video encoding failed: {err.strip()[-300:]}")

    def __enter__(self) -> "VideoWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
