"""vpdetect's background warm-up at several input frame rates (docs/vpdetect.md, "Background warm-up").

Usage:
  .venv/bin/python benchmarks/vpdetect_warmup.py [--video ../shared/data/videos/kraten_cars.mp4] [--seconds 6]
         [--warmup N] [FPS ...]   (default rates: 5 10 25 50)

The clip is re-timed with ``videorate`` to each rate and its grey frames fed to the element's calibrator
(``VPCalibrator``) with their buffer times.  Reported per rate: the analysed frames, when the running-average
background (``vanishing.foreground.RunningForeground``) is ready, and the share of its pixels called moving once
ready (the first five analysed frames, and the median to ``--seconds``): a background averaged over too few
frames keeps the first vehicles as ghosts, which the slow adaptation (1 % per analysed frame) clears only after
tens of seconds at low rates.  ``--warmup N``: try another warm-up frame count.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gst_trafficcal.gst._gi import Gst  # noqa: E402
from gst_trafficcal.vanishing.calibrator import VPCalibrator  # noqa: E402


def measure(video: Path, fps: int, seconds: float, warmup: int | None) -> str:
    """One rate's line."""
    pipeline = Gst.parse_launch(f"filesrc location={video} ! decodebin ! videoconvert ! videorate ! "
                                f"video/x-raw,format=GRAY8,framerate={fps}/1 ! appsink name=s sync=false")
    sink = pipeline.get_by_name("s")
    pipeline.set_state(Gst.State.PLAYING)
    cal, ready_t, fractions = None, None, []
    try:
        while (sample := sink.emit("try-pull-sample", 5 * Gst.SECOND)) is not None:
            buf, st = sample.get_buffer(), sample.get_caps().get_structure(0)
            w, h = st.get_value("width"), st.get_value("height")
            ok, info = buf.map(Gst.MapFlags.READ)
            data = np.frombuffer(info.data, np.uint8)
            grey = data.reshape(h, len(data) // h)[:, :w].copy()
            buf.unmap(info)
            t = buf.pts / Gst.SECOND
            if cal is None:
                cal = VPCalibrator((w, h))
                if warmup is not None:
                    cal.fg_model.warmup = warmup
            before = cal.analysed
            cal.add(grey, t)
            if cal.analysed > before and cal.fg_model.ready:
                ready_t = t if ready_t is None else ready_t
                fractions.append(cal.fg_model.fraction)
            if t > seconds:
                break
    finally:
        pipeline.set_state(Gst.State.NULL)
    if cal is None or ready_t is None:
        return f"{fps} fps: background not ready within {seconds:g} s"
    return (f"{fps} fps: {cal.analysed} analysed frames in {seconds:g} s; background ready at {ready_t:.2f} s; "
            f"moving share of the first 5 ready frames {np.round(fractions[:5], 3).tolist()}, "
            f"median to {seconds:g} s {np.median(fractions):.3f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("fps", nargs="*", type=int, default=[5, 10, 25, 50])
    ap.add_argument("--video", type=Path, default=ROOT.parent / "shared" / "data" / "videos" / "kraten_cars.mp4")
    ap.add_argument("--seconds", type=float, default=6.0)
    ap.add_argument("--warmup", type=int, default=None)
    args = ap.parse_args()
    Gst.init(None)
    for fps in args.fps:
        print(measure(args.video, fps, args.seconds, args.warmup), flush=True)


if __name__ == "__main__":
    main()
