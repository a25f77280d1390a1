"""Stop 21 experiment: move the detector box's left, top and right edges to the strongest image edge nearby.

vehicleseg traces its outlines at the work width (480 px: 4 frame pixels per work pixel at 1080p), and its box
edges lie 2-9 frame pixels from the renderer's on the replays (soft shadows beside the body count as vehicle).
This refines each of those three edges at full resolution: in a band of ``band`` work pixels around the edge, each
row (left/right) or column (top) gives the position of its strongest gradient across the edge when that exceeds
``tau`` grey levels per pixel; the edge goes to a low percentile of those positions (``q``, ``q_top``: the
outermost body point, robust to a few spurious edges). The bottom stays the detector's (it lies in the body's
own shadow, where no image edge marks it).  Offline, on stored sightings (``scale_sightings.py dump``) and the
scenes' videos; writes refined dumps that ``scale_sightings.py replay`` reads:

    .venv/bin/python benchmarks/box_edges.py /tmp/sight19/*.pkl --out /tmp/sight_edges \
        --scenes /tmp/replays_cat,/tmp/scl_cat
    .venv/bin/python benchmarks/scale_sightings.py replay /tmp/sight_edges/*.pkl --variant chain

Not part of the product: it helped the scenes it was tuned on and hurt fresh ones (docs/bbscale_streaming.md
"Stop 21").
"""

from __future__ import annotations

import argparse
import math
import pickle
import sys
from collections import defaultdict
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def _edge_position(grad: np.ndarray, lo: int, hi: int, tau: float, q: float, outward_low: bool) -> float | None:
    """``grad``: lines x positions of |gradient| across the edge; the ``q``-th outermost percentile of each line's
    strongest position in [lo, hi) over the lines whose strongest gradient exceeds ``tau`` (None: < 3 such)."""
    band = grad[:, max(lo, 0):max(hi, 0)]
    if band.shape[1] < 2 or band.shape[0] < 3:
        return None
    arg = band.argmax(axis=1)
    keep = band[np.arange(len(arg)), arg] > tau
    if keep.sum() < 3:
        return None
    return float(np.percentile(max(lo, 0) + arg[keep], q if outward_low else 100 - q))


def refine_box(grey: np.ndarray, box, work_px: float, band: float = 2.5, tau: float = 8.0, q: float = 20.0,
               q_top: float = 40.0) -> tuple[float, float, float, float]:
    """``box`` (x0, y0, x1, y1, pixel-centre coordinates) with its left, top and right edges moved to the image's
    strongest edges within ``band`` work pixels (``work_px`` frame pixels each); an edge without a clear image
    edge stays where it was."""
    h, w = grey.shape
    x0, y0, x1, y1 = (float(v) for v in box)
    b = band * work_px
    X0, X1 = max(int(math.floor(x0 - b)) - 2, 0), min(int(math.ceil(x1 + b)) + 3, w)
    Y0, Y1 = max(int(math.floor(y0 - b)) - 2, 0), min(int(math.ceil(y1 + b)) + 3, h)
    if X1 - X0 < 8 or Y1 - Y0 < 8:
        return x0, y0, x1, y1
    crop = cv2.GaussianBlur(grey[Y0:Y1, X0:X1].astype(np.float32), (0, 0), 0.8)
    gx = np.abs(cv2.Sobel(crop, cv2.CV_32F, 1, 0, ksize=3)) / 8
    gy = np.abs(cv2.Sobel(crop, cv2.CV_32F, 0, 1, ksize=3)) / 8
    rows = slice(max(round(y0) - Y0, 0), round(y1) - Y0 + 1)
    cols = slice(max(round(x0) - X0, 0), round(x1) - X0 + 1)
    out = [x0, y0, x1, y1]
    p = _edge_position(gx[rows], round(x0 - b) - X0, round(x0 + b) - X0 + 1, tau, q, True)
    if p is not None:
        out[0] = X0 + p
    p = _edge_position(gx[rows], round(x1 - b) - X0, round(x1 + b) - X0 + 1, tau, q, False)
    if p is not None:
        out[2] = X0 + p
    p = _edge_position(gy[:, cols].T, round(y0 - b) - Y0, round(y0 + b) - Y0 + 1, tau, q_top, True)
    if p is not None:
        out[1] = Y0 + p
    return tuple(out)


def refine_dump(pkl: Path, video: Path, out: Path, **params) -> tuple[np.ndarray, np.ndarray]:
    """Write ``pkl``'s sightings with refined boxes to ``out``/name; returns the edge errors (detector minus
    renderer, N x 4 frame px) before and after, over the fully visible matched sightings."""
    import scale_sightings as ss

    from gst_trafficcal.detection.seginput import WorkGeometry
    from gst_trafficcal.errors import InputError
    from gst_trafficcal.fileio import open_video

    data = ss.load(pkl)
    by_frame: dict[int, list[int]] = defaultdict(list)
    for i, r in enumerate(data["records"]):
        by_frame[r.frame].append(i)
    boxes: dict[int, tuple] = {}
    cap = open_video(video)
    try:
        n, last = 0, max(by_frame, default=-1)
        while n <= last:
            ok, frame = cap.read()
            if not ok:
                raise InputError(f"{video}: ends at frame {n}, before the dump's last sighting (frame {last})")
            if n in by_frame:
                grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
                work_px = WorkGeometry((grey.shape[1], grey.shape[0])).scale[0]  # vehicleseg's default work width
                for i in by_frame[n]:
                    boxes[i] = refine_box(grey, data["records"][i].sighting.box, work_px, **params)
            n += 1
    finally:
        cap.release()
    before, after, records = [], [], []
    for i, r in enumerate(data["records"]):
        if i in boxes:
            if r.true_box is not None and r.true_visible > 0.99:
                before.append(np.subtract(r.sighting.box, r.true_box))
                after.append(np.subtract(boxes[i], r.true_box))
            r = replace(r, sighting=replace(r.sighting, box=boxes[i]))
        records.append(vars(r))
    out.mkdir(parents=True, exist_ok=True)
    with open(out / pkl.name, "wb") as fh:
        pickle.dump({**data, "records": records}, fh)
    return np.reshape(before, (-1, 4)), np.reshape(after, (-1, 4))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dumps", nargs="+", type=Path, help="scale_sightings.py dump files")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--scenes", default="/tmp/replays_cat,/tmp/scl_cat",
                    help="comma-separated folders holding the dumps' scene folders (with video.mp4)")
    ap.add_argument("--band", type=float, default=2.5, help="search band around each edge, work pixels")
    ap.add_argument("--tau", type=float, default=8.0, help="smallest gradient that counts, grey levels / px")
    ap.add_argument("--q", type=float, default=20.0, help="outermost percentile of the side edges' positions")
    ap.add_argument("--q-top", type=float, default=40.0, help="the same for the top edge")
    a = ap.parse_args()
    from gst_trafficcal.errors import InputError

    roots = [Path(p) for p in a.scenes.split(",") if p]
    print("| scene | n | detector − renderer, median left / top / right / bottom px | |median| | refined median | "
          "refined |median| |")
    print("|---|---|---|---|---|---|")
    for pkl in a.dumps:
        scene = pkl.stem.rsplit("_vehicleseg", 1)[0]
        video = next((r / scene / "video.mp4" for r in roots if (r / scene / "video.mp4").is_file()), None)
        if video is None:
            sys.exit(f"{pkl}: no {scene}/video.mp4 under {a.scenes}")
        try:
            d, r = refine_dump(pkl, video, a.out, band=a.band, tau=a.tau, q=a.q, q_top=a.q_top)
        except InputError as exc:
            sys.exit(str(exc))
        f = lambda v: " / ".join(f"{x:+.1f}" for x in v)  # noqa: E731
        print(f"| {scene} | {len(d)} | {f(np.median(d, 0))} | {f(np.median(np.abs(d), 0))} | {f(np.median(r, 0))} | "
              f"{f(np.median(np.abs(r), 0))} |", flush=True)


if __name__ == "__main__":
    main()
