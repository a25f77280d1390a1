"""Look at what the segmenter finds in a video: PNGs of chosen frames with its mask, boxes and hulls drawn.

    .venv/bin/python -m training.vehicleseg.overlay VIDEO --frames 100,200 --out /tmp/vseg_look [--model FILE]

Each PNG shows the frame with the vehicle mask tinted red, every vehicle's box (green) and convex hull (blue),
the centre peaks (yellow) and, on the right, the detector's running-average background.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

from gst_trafficcal.detection.vehicleseg import VehicleSegDetector


def draw(frame: np.ndarray, det, seg) -> np.ndarray:
    """The frame (BGR) with the segmentation drawn on it."""
    out = frame.copy()
    h, w = frame.shape[:2]
    prob = cv2.resize(seg.probability, (w, h), interpolation=cv2.INTER_LINEAR)
    m = prob > 0.5
    out[m] = (0.55 * out[m] + np.array([0, 0, 115])).astype(np.uint8)
    sx, sy = seg.geometry.scale
    for box, hull in zip(det.boxes, det.hulls):
        x0, y0, x1, y1 = np.round(box).astype(int)
        cv2.rectangle(out, (x0, y0), (x1 - 1, y1 - 1), (0, 255, 0), 1)
        cv2.polylines(out, [np.round(hull).astype(np.int32)], True, (255, 80, 0), 1)
    for cx, cy in seg.centres:
        cv2.circle(out, (int((cx + 0.5) * sx), int((cy + 0.5) * sy)), 3, (0, 255, 255), -1)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("video", type=Path)
    ap.add_argument("--frames", default="100", help="comma-separated frame numbers to save")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--model", type=Path, default=None)
    args = ap.parse_args(argv)
    wanted = sorted(int(v) for v in args.frames.split(","))
    args.out.mkdir(parents=True, exist_ok=True)
    det = VehicleSegDetector(args.model)
    cap = cv2.VideoCapture(str(args.video))
    i = 0
    while i <= wanted[-1]:
        ok, frame = cap.read()
        if not ok:
            break
        t = cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
        d = det(frame, t)
        if i in wanted:
            bg = cv2.resize(det.background.image(), frame.shape[1::-1])
            png = args.out / f"{args.video.stem}_{i:05d}.png"
            cv2.imwrite(str(png), np.hstack([draw(frame, d, det.last), bg]))
            print(f"{png}: {len(d)} vehicles")
        i += 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
