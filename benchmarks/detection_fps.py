"""Frames per second of each element's work (vehicledetect's detectors, tracker) at 960x540 and 1920x1080.

    .venv/bin/python benchmarks/detection_fps.py [--frames 60] [--threads 1]

Prints one markdown table (the README's): wall-clock and CPU-time fps per element and size, and the target.
The tracker rows come from ``benchmarks/tracking.py``: the tracking stage the ``tracker`` element runs per
frame (background model — grey, and with the colour tests —, hulls, 3D boxes, Kalman tracking) on frames with about 10
painted vehicles, and the tracker core alone (association, Kalman, 3D boxes; 10 simulated vehicles).

Frames are the first N of ../shared/data/videos/abhishek_highway.mp4 scaled to each size beforehand
(decoding and scaling are not timed). The background detector gets the grey image (what the element
takes from the Y plane of I420/NV12); ONNX detectors get BGR. Targets (issue 5): background >= 100 fps
at 960x540, NanoDet >= 25 fps. Wall-clock figures depend on the machine's load; the CPU-time figures
(frames per second of process CPU time) estimate what one idle core gives when --threads is 1.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
SHARED = ROOT.parent / "shared"
CLIP = SHARED / "data" / "videos" / "abhishek_highway.mp4"
DETECTORS = SHARED / "models" / "detectors"
SIZES = [(960, 540), (1920, 1080)]


def read_frames(n: int) -> list:
    cap = cv2.VideoCapture(str(CLIP))
    frames = []
    while len(frames) < n:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame)
    if not frames:
        sys.exit(f"cannot read {CLIP} (needs ../shared)")
    return frames


def fps(detector, images: list, warmup: int = 5) -> tuple[float, float]:
    """(wall-clock fps, fps from this process's CPU time). On a loaded machine the wall clock also
    counts time spent waiting for a core; CPU time does not (with 1 thread it is what an idle core gives)."""
    for img in images[:warmup]:
        detector(img)
    t0, c0 = time.perf_counter(), time.process_time()
    for img in images:
        detector(img)
    return len(images) / (time.perf_counter() - t0), len(images) / (time.process_time() - c0)


def main() -> None:
    from gst_trafficcal.detection.background import BackgroundDetector
    from gst_trafficcal.detection.onnx_detector import OnnxDetector
    from gst_trafficcal.detection.vehicleseg import VehicleSegDetector

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from tracking import core_fps, pipeline_fps

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--threads", type=int, default=1, help="onnxruntime intra-op threads")
    ap.add_argument("--only", default="", help="only the rows whose name contains this text (e.g. vehicleseg)")
    args = ap.parse_args()
    frames = read_frames(args.frames)
    detectors = {
        "vehicledetect: background (MOG2, default)": (lambda: BackgroundDetector(method="mog2"), True, "≥ 100 at 960x540"),
        "vehicledetect: background=average (moving average, shadow peeling)": (
            lambda: BackgroundDetector(method="average"), True, "≥ 100 at 960x540"),
        "vehicledetect: NanoDet-m 320": (lambda: OnnxDetector(DETECTORS / "nanodet_hpc203.onnx", threads=args.threads),
                                         False, "≥ 25"),
        "vehicledetect: FastestDet 352": (lambda: OnnxDetector(DETECTORS / "FastestDet.onnx", threads=args.threads),
                                          False, ""),
        "vehicledetect: vehicleseg (learned segmenter, 480 px, boxes + hulls)": (
            lambda: VehicleSegDetector(threads=args.threads), False, "≤ 15 ms per frame per core"),
    }
    detectors = {k: v for k, v in detectors.items() if args.only.lower() in k.lower()}
    head = "| element | " + " | ".join(f"{w}x{h} wall / CPU fps" for w, h in SIZES) + " | target |"
    print(head + "\n|---|" + "---|" * len(SIZES) + "---|", flush=True)
    for name, (make, grey, target) in detectors.items():
        cells = []
        for w, h in SIZES:
            images = [cv2.resize(f, (w, h)) for f in frames]
            if grey:
                images = [cv2.cvtColor(i, cv2.COLOR_BGR2GRAY) for i in images]
            wall, cpu = fps(make(), images)
            cells.append(f"{wall:.0f} / {cpu:.0f}")
        print(f"| {name} | " + " | ".join(cells) + f" | {target} |", flush=True)
    for colour in (False, True):
        if args.only and "tracker" not in args.only:
            break
        cells, mean = [], []
        for w, h in SIZES:
            wall, cpu, n = pipeline_fps((w, h), colour=colour)
            cells.append(f"{wall:.0f} / {cpu:.0f}")
            mean.append(n)
        name = "tracker colour=true" if colour else "tracker (default)"
        print(f"| {name} ({np.mean(mean):.1f} vehicles per frame) | " + " | ".join(cells)
              + " | ≥ 100 with 10 vehicles |", flush=True)
    if args.only and "tracker" not in args.only:
        return
    wall, cpu, n = core_fps()
    print(f"| tracker core only ({n:.1f} vehicles; no image work, size-independent) | {wall:.0f} / {cpu:.0f} | "
          f"{wall:.0f} / {cpu:.0f} | |")
    print(f"\n{args.frames} frames of {CLIP.name} per detector and size, {args.threads} onnxruntime thread(s); "
          "CPU time = this process's CPU seconds (all its threads)")


if __name__ == "__main__":
    main()
