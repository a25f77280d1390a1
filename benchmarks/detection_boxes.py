"""Box quality of the background detector (or the learned vehicleseg) on rendered scenes with per-frame truth (synth presets, replays).

For each scene folder (video.mp4 + frames.jsonl, e.g. /tmp/aa_syn/<preset> or /tmp/replays/<session>_<view>)
the detector runs on every frame in order (it learns the road); from frame ``--first`` on, its boxes are scored
against the moving vehicles at least 90 % visible whose box diagonal is at least 5 % of the image width:

* recall: fraction of those vehicles with a box at IoU ≥ 0.5, and their median best IoU;
* precision: fraction of boxes at IoU ≥ 0.5 with any vehicle more than 20 % visible;
* box edges: median offset of the matched box's left/right edge from the vehicle's (in vehicle widths) and of its
  top/bottom edge (in vehicle heights) — positive right/bottom: a cast shadow to the right shows as +right;
* CPU-time fps of the detector (grey frames as vehicledetect gets them, BGR for vehicleseg; decoding excluded).

    .venv/bin/python benchmarks/detection_boxes.py --method average /tmp/aa_syn/highway_day /tmp/replays/session0_left

Vehicles without a speed (a few BrnoCompSpeed cars in the replays stand still for the whole clip) are not
counted: no background model can see them.
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

from gst_trafficcal.detection.background import BackgroundDetector  # noqa: E402
from gst_trafficcal.detection.factory import detect  # noqa: E402
from gst_trafficcal.detection.records import box_iou  # noqa: E402
from gst_trafficcal.synth.groundtruth import records_by_frame  # noqa: E402


def score_scene(scene: Path, detector, frames: int, first: int) -> dict:
    truth = records_by_frame(scene / "frames.jsonl")
    cap = cv2.VideoCapture(str(scene / "video.mp4"))
    n_gt = n_tp = n_det = n_good = 0
    ious, dx, dy = [], [], []
    busy, count = 0.0, 0
    for i in range(frames):
        ok, bgr = cap.read()
        if not ok:
            break
        t = cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
        c0 = time.process_time()
        det = detect(detector, bgr if getattr(detector, "timed", False) else cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY), t)
        busy += time.process_time() - c0
        count += 1
        if i < first:
            continue
        recs = truth.get(i, [])
        width = bgr.shape[1]
        anyg = np.array([r["box"] for r in recs if r["visible"] > 0.2], float).reshape(-1, 4)
        g = np.array([r["box"] for r in recs if r["visible"] >= 0.9 and r.get("speed_kmh", 99) >= 5],
                     float).reshape(-1, 4)
        g = g[np.hypot(g[:, 2] - g[:, 0], g[:, 3] - g[:, 1]) >= 0.05 * width]
        b = det.boxes.reshape(-1, 4).astype(float)
        n_gt += len(g)
        n_det += len(b)
        if len(anyg) and len(b):
            n_good += int((box_iou(b, anyg).max(axis=1) >= 0.5).sum())
        if len(g) and len(b):
            iou = box_iou(g, b)
            best, j = iou.max(axis=1), iou.argmax(axis=1)
            ious += list(best)
            m = best >= 0.5
            n_tp += int(m.sum())
            gg, bb = g[m], b[j[m]]
            w, h = gg[:, 2] - gg[:, 0], gg[:, 3] - gg[:, 1]
            dx += list(np.stack([(bb[:, 0] - gg[:, 0]) / w, (bb[:, 2] - gg[:, 2]) / w], axis=1))
            dy += list(np.stack([(bb[:, 1] - gg[:, 1]) / h, (bb[:, 3] - gg[:, 3]) / h], axis=1))
        elif len(g):
            ious += [0.0] * len(g)
    cap.release()
    return dict(scene=scene.name, vehicles=n_gt, tp=n_tp, detections=n_det, good=n_good, ious=ious,
                dx=dx, dy=dy, fps=count / max(busy, 1e-9))


def summary(name: str, rows: list[dict]) -> str:
    """One table row; a scene with no scored vehicle (e.g. a sparse scene's window) shows dashes, not NaN."""
    gt, tp = sum(r["vehicles"] for r in rows), sum(r["tp"] for r in rows)
    det, good = sum(r["detections"] for r in rows), sum(r["good"] for r in rows)
    ious = sum((r["ious"] for r in rows), [])
    if not gt:
        return f"| {name} | 0 | — | {good / det if det else 0:.3f} | — | — | — |"
    dx = np.median(np.array(sum((r["dx"] for r in rows), [])).reshape(-1, 2), axis=0)
    dy = np.median(np.array(sum((r["dy"] for r in rows), [])).reshape(-1, 2), axis=0)
    return (f"| {name} | {gt} | {tp / gt:.3f} | {good / max(det, 1):.3f} | "
            f"{np.median(ious) if ious else 0:.2f} | {dx[0]:+.2f} / {dx[1]:+.2f} | {dy[0]:+.2f} / {dy[1]:+.2f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="+", type=Path)
    ap.add_argument("--method", default="mog2", choices=("mog2", "average", "vehicleseg"))
    ap.add_argument("--model", default="", help="vehicleseg: another ONNX file than the shipped one")
    ap.add_argument("--no-peel", action="store_true", help="average: keep the cast shadows in the boxes")
    ap.add_argument("--frames", type=int, default=400, help="frames read per scene")
    ap.add_argument("--first", type=int, default=60, help="first scored frame (after the warm-up)")
    args = ap.parse_args()
    rows = []
    print("| scene | vehicles | recall | precision | median IoU | left / right edge | top / bottom edge |")
    print("|---|---|---|---|---|---|---|")
    for scene in args.scenes:
        if args.method == "vehicleseg":
            from gst_trafficcal.detection.vehicleseg import VehicleSegDetector
            det = VehicleSegDetector(args.model or None)
        else:
            det = BackgroundDetector(method=args.method, peel=not args.no_peel)
        r = score_scene(scene, det, args.frames, args.first)
        rows.append(r)
        print(summary(scene.name, [r]), flush=True)
    print(summary("all", rows))
    print(f"\ndetector CPU-time fps (mean over scenes): {np.mean([r['fps'] for r in rows]):.0f} "
          f"[method {args.method}{', no peel' if args.no_peel else ''}]")


if __name__ == "__main__":
    main()
