"""How tight a vehicle segmenter's outlines are, on stored samples (``training.vehicleseg.data`` npz files).

    .venv/bin/python -m training.vehicleseg.evaluate --data /tmp/vseg_data --model gst_trafficcal/detection/weights/vehicleseg.onnx

For every sample the ONNX model runs on the whole work image (frame + stored run-time background) and the
detector's own post-processing (:func:`gst_trafficcal.detection.vehicleseg.decode`) makes the vehicles; they are
matched to the true instances (IoU >= 0.5 of the boxes, work pixels) and reported per lighting preset:

* median box-edge offset (left / right in box widths, top / bottom in box heights; positive = right / down) and
  median box IoU of the matched vehicles wider than ``--min-width`` work pixels;
* mask IoU over the image (threshold 0.5) and the share of *shadow* pixels called vehicle: pixels within 8 work
  pixels of a vehicle that changed against the background (> 6 grey levels) but hold no vehicle (< 5 % covered) —
  cast and contact shadows, the outline error this measures.

Validation scenes only by default (index ending in 9, never trained on).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from scipy import ndimage

from gst_trafficcal.detection.records import box_iou
from gst_trafficcal.detection.seginput import WorkGeometry, network_input
from gst_trafficcal.detection.vehicleseg import QUARTER, VehicleSegDetector, decode

from .targets import UNKNOWN
from .train import SCENE

NEAR = 8  # work pixels around a vehicle where shadow pixels are counted
SHADOW_CHANGE = 6  # grey levels


@dataclass
class Tally:
    """Accumulated figures of one group of samples."""

    edges: list = field(default_factory=list)  # rows: left, right, top, bottom offsets (box fractions), IoU
    inter: float = 0.0
    union: float = 0.0
    shadow: int = 0
    shadow_fg: int = 0
    vehicles: int = 0
    matched: int = 0

    def row(self, name: str) -> str:
        e = np.array(self.edges).reshape(-1, 5)
        med = np.median(e, axis=0) if len(e) else np.full(5, np.nan)
        return (f"| {name} | {self.vehicles} | {self.matched / max(self.vehicles, 1):.3f} | {med[4]:.3f} | "
                f"{med[0]:+.3f} / {med[1]:+.3f} | {med[2]:+.3f} / {med[3]:+.3f} | "
                f"{self.inter / max(self.union, 1):.3f} | {self.shadow_fg / max(self.shadow, 1):.3f} |")


def true_boxes(inst: np.ndarray, min_px: int) -> np.ndarray:
    """Boxes (x0, y0, x1, y1 pixel edges) of the instances with at least ``min_px`` pixels, not touching the
    image border (a cut vehicle's box is not its outline)."""
    h, w = inst.shape
    out = []
    for i, sl in enumerate(ndimage.find_objects(inst)):
        if sl is None or i + 1 == UNKNOWN:
            continue
        if int((inst[sl] == i + 1).sum()) < min_px:
            continue
        y0, y1, x0, x1 = sl[0].start, sl[0].stop, sl[1].start, sl[1].stop
        if x0 == 0 or y0 == 0 or x1 == w or y1 == h:
            continue
        out.append((x0, y0, x1, y1))
    return np.array(out, np.float64).reshape(-1, 4)


def evaluate_sample(det: VehicleSegDetector, d: dict, tallies: list[Tally], min_width: float) -> None:
    """Run the model on one sample and add its figures to each of ``tallies``."""
    one = Tally()
    score_sample(det, d, one, min_width)
    for t in tallies:
        t.edges += one.edges
        t.inter += one.inter
        t.union += one.union
        t.shadow += one.shadow
        t.shadow_fg += one.shadow_fg
        t.vehicles += one.vehicles
        t.matched += one.matched


def score_sample(det: VehicleSegDetector, d: dict, tally: Tally, min_width: float) -> None:
    """The figures of one sample, into an empty ``tally``."""
    frame, background, fg, inst = d["frame"], d["background"], d["fg"].astype(np.float32) / 255, d["inst"]
    h, w = inst.shape
    geom = WorkGeometry((w, h), w)
    mask, centre, offset = det.session.run(None, {det.input_name: network_input(frame, background, geom)})
    qh, qw = -(-h // QUARTER), -(-w // QUARTER)
    mask, centre, offset = mask[0, 0, :h, :w], centre[0, 0, :qh, :qw], offset[0, :, :qh, :qw]
    found, _ = decode(mask, centre, offset, geom, det.threshold, det.centre_threshold,
                      max(1, round(det.min_area * mask.size)), det.mask_threshold)
    known = inst != UNKNOWN
    pred, true = (1 / (1 + np.exp(-mask)) > det.mask_threshold) & known, (fg >= 0.5) & known
    tally.inter += float((pred & true).sum())
    tally.union += float((pred | true).sum())
    near = cv2.dilate((fg > 0.05).astype(np.uint8), np.ones((2 * NEAR + 1, 2 * NEAR + 1), np.uint8)) > 0
    changed = np.abs(frame.astype(np.int16) - background.astype(np.int16)).max(axis=2) > SHADOW_CHANGE
    shadow = near & changed & (fg < 0.05) & known
    tally.shadow += int(shadow.sum())
    tally.shadow_fg += int((shadow & pred).sum())
    g = true_boxes(inst, 12)
    g = g[(g[:, 2] - g[:, 0]) >= min_width]
    b = found.boxes.reshape(-1, 4) + 0.5  # pixel-centre coordinates -> pixel edges, as true_boxes
    tally.vehicles += len(g)
    if not len(g) or not len(b):
        return
    iou = box_iou(g, b)
    best, j = iou.max(axis=1), iou.argmax(axis=1)
    m = best >= 0.5
    tally.matched += int(m.sum())
    gg, bb = g[m], b[j[m]]
    gw, gh = gg[:, 2] - gg[:, 0], gg[:, 3] - gg[:, 1]
    tally.edges += list(np.stack([(bb[:, 0] - gg[:, 0]) / gw, (bb[:, 2] - gg[:, 2]) / gw,
                                  (bb[:, 1] - gg[:, 1]) / gh, (bb[:, 3] - gg[:, 3]) / gh, best[m]], axis=1))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--model", type=Path, default=None, help="ONNX file (default: the shipped model)")
    ap.add_argument("--all", action="store_true", help="every scene, not only the validation scenes (index % 10 == 9)")
    ap.add_argument("--every", type=int, default=2, help="use every n-th sample of a scene")
    ap.add_argument("--min-width", type=float, default=24.0, help="smallest scored vehicle width, work pixels")
    ap.add_argument("--mask-threshold", type=float, default=0.5, help="the detector's mask_threshold")
    args = ap.parse_args(argv)
    det = VehicleSegDetector(args.model, mask_threshold=args.mask_threshold)
    light: dict[int, str] = {}
    for p in args.data.glob("scene_*.json"):
        r = json.loads(p.read_text())
        light[int(p.stem.split("_")[1])] = r["scenario"]["lighting"]["preset"]
    tallies: dict[str, Tally] = defaultdict(Tally)
    files = [p for p in sorted(args.data.glob("s*_*.npz")) if SCENE.search(p.name)]
    for k, p in enumerate(files):
        idx = int(SCENE.search(p.name).group(1))
        if (not args.all and idx % 10 != 9) or idx not in light or k % args.every:
            continue
        with np.load(p) as d:
            sample = {n: d[n] for n in ("frame", "background", "fg", "inst")}
        evaluate_sample(det, sample, [tallies[light[idx]], tallies["all"]], args.min_width)
    print(f"model {det.path}, mask threshold {det.mask_threshold}")
    print("| lighting | vehicles | recall | median IoU | left / right edge | top / bottom edge | mask IoU | "
          "shadow px called vehicle |")
    print("|---|---|---|---|---|---|---|---|")
    for name in sorted(tallies, key=lambda n: (n == "all", n)):
        print(tallies[name].row(name))
    return 0


if __name__ == "__main__":
    sys.exit(main())
