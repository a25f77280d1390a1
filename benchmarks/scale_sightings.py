"""Where BBScale's error comes from: the chain's sightings of each scene, dumped once, replayed into variants.

``dump`` runs the scale chain of :func:`gst_trafficcal.scale.video.scale_from_video` (detector, tracker, the
scene's true vanishing points) over rendered scenes (synth presets or BrnoCompSpeed replays, folders with
``frames.jsonl``) and stores every sighting the ``bbscale`` stage would see — detector box, hull, 3D-box corners,
heading, body shape — next to the renderer's truth for the same vehicle (exact 2D box, exact 3D box, catalogue
model, real length).  ``replay`` feeds those sightings into :class:`~gst_trafficcal.scale.streaming.ScaleEstimator`
variants without re-running detection and tracking (seconds per scene instead of minutes), e.g. with the exact
box or the exact base swapped in, to separate the error of the boxes, of the base points and of the types:

    .venv/bin/python benchmarks/scale_sightings.py dump /tmp/replays_cat/session* --out /tmp/sightings [--detector vehicleseg]
    .venv/bin/python benchmarks/scale_sightings.py replay /tmp/sightings/*.pkl --variant chain,exact_box,exact_base,exact
    .venv/bin/python benchmarks/scale_sightings.py replay /tmp/sightings/*.pkl --variant chain --estimator iou_threshold=0.9
    .venv/bin/python benchmarks/scale_sightings.py replay /tmp/sightings/*.pkl --variant chain --until 60,120
    .venv/bin/python benchmarks/scale_sightings.py replay /tmp/sightings/*.pkl --variant chain,shifted_box --halves
    .venv/bin/python benchmarks/scale_sightings.py replay /tmp/sightings/*.pkl --variant exact_sides,exact_box_true_type
"""

from __future__ import annotations

import argparse
import pickle
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


@dataclass
class Record:
    """One sighting as the scale stage saw it, with the renderer's truth of the vehicle it is (when matched)."""

    frame: int
    sighting: object  # gst_trafficcal.scale.streaming.Sighting (box = detector box)
    hull_box: tuple | None
    true_id: int | None = None
    true_box: tuple | None = None
    true_corners: np.ndarray | None = None  # 8x2 px, order box3d.CORNER_BITS
    true_model: str | None = None
    true_size: tuple | None = None  # length, width, height (m)
    true_visible: float = 0.0


def _corner_order(c: np.ndarray) -> np.ndarray:
    """The renderer's box corners (frames.jsonl ``box3d``: bottom then top, each front-left, front-right,
    rear-right, rear-left) in the tracker's order (box3d.CORNER_BITS: bit 0 along the vehicle, bit 1 across,
    bit 2 up)."""
    return np.asarray(c, np.float64).reshape(8, 2)[[2, 1, 3, 0, 6, 5, 7, 4]]


def dump(folder: Path, out: Path, detector: str, duration: float | None) -> Path:
    from gst_trafficcal.calibration import load_calibration
    from gst_trafficcal.scale.alignment import box_iou
    from gst_trafficcal.scale.streaming import load_align_models
    from gst_trafficcal.scale.video import frame_sightings, scale_from_video
    from gst_trafficcal.synth.groundtruth import records_by_frame

    dest = out / f"{folder.name}{'_' + Path(detector).stem if detector else ''}.pkl"
    if dest.is_file():
        return dest
    cal = load_calibration(folder / "calibration.json")
    cam = cal.camera.with_scale(None)
    truth = records_by_frame(folder / "frames.jsonl")
    records: list[Record] = []

    def on_frame(n, t, result, detections):
        hull = {s.track_id: s.box for s in frame_sightings(result, detections, cam, "hull")}
        recs = truth.get(n, [])
        boxes = np.array([r["box"] for r in recs], np.float64).reshape(-1, 4)
        for s in frame_sightings(result, detections, cam, "detector"):
            rec = Record(n, s, hull.get(s.track_id))
            if len(boxes):
                iou = box_iou(boxes, s.box)
                k = int(np.argmax(iou))
                if iou[k] > 0.3:
                    r = recs[k]
                    rec = replace(rec, true_id=int(r["id"]), true_box=tuple(r["box"]),
                                  true_corners=_corner_order(r["box3d"]), true_model=str(r["model"]),
                                  true_size=tuple(r["size"]), true_visible=float(r["visible"]))
            records.append(rec)

    res = scale_from_video(folder / "video.mp4", cal.with_scale(None), models=load_align_models(None),
                           on_frame=on_frame, detector=detector, max_duration=duration)
    out.mkdir(parents=True, exist_ok=True)
    with open(dest, "wb") as fh:
        pickle.dump({"scene": folder.name, "true": float(cal.camera.scale), "camera": cam, "detector": detector,
                     "chain": res.result.raw_scale, "records": [vars(r) for r in records]}, fh)
    return dest


# ---------------------------------------------------------------------------------------------------- variants
def _exact_base(rec: Record):
    from gst_trafficcal.scale.streaming import base_centre

    return base_centre(rec.true_corners) if rec.true_corners is not None else None


#: the box edges ``shifted_box`` moves (left, top, right: stop 20 found the bottom is not what λ lacks)
SHIFTED_EDGES = (0, 1, 2)


def scene_edge_shift(records: list[Record], edges: tuple[int, ...] = SHIFTED_EDGES) -> np.ndarray:
    """The scene's median renderer − detector offset of each box edge (x0, y0, x1, y1; px) over its fully visible
    matched sightings, zero for the edges not in ``edges`` (and all zero without such sightings)."""
    d = [np.subtract(r.true_box, r.sighting.box) for r in records if r.true_box is not None and r.true_visible > 0.99]
    shift = np.zeros(4)
    if d:
        idx = list(edges)
        shift[idx] = np.median(np.reshape(d, (-1, 4)), axis=0)[idx]
    return shift


def variant_sightings(records: list[Record], variant: str) -> list[tuple[int, float, object]]:
    """(frame, t, sighting) with what ``variant`` swaps in: chain (as seen), exact_box (renderer's 2D box),
    exact_base (renderer's 3D-box base centre), exact (both), hull (the tracker's hull box), shifted_box (every
    detector box moved by the scene's median renderer − detector offset of its left, top and right edges: an
    oracle per-scene correction, the best any one correction per scene can do), true_type and exact_box_true_type
    (a perfect classifier: each sighting's type probabilities one-hot on the renderer's model, so only vehicles of a
    catalogue type are aligned, each with its own model — what a fine-grained classifier could give at best),
    exact_sides / exact_ends (the renderer's left and right edges / top and bottom edges only, the detector's
    other two: which pair of edges the error comes from), axis_box (the image's own boxes also under a rolled
    camera, as before stop 39: no de-rolled boxes).  Every variant that swaps a box in aligns it in the image's own
    axes (the renderer's boxes are axis-aligned)."""
    shift = scene_edge_shift(records) if variant == "shifted_box" else None
    own_axes = variant not in ("chain", "true_type", "exact_base")
    out = []
    for r in records:
        s = r.sighting
        if own_axes and getattr(s, "derolled_box", None) is not None:
            s = replace(s, derolled_box=None, roll=0.0)
        if shift is not None:
            s = replace(s, box=tuple(float(v) for v in np.add(s.box, shift)))
        if variant.endswith("true_type"):
            s = replace(s, type_probs={r.true_model or "?": 1.0})
        if variant in ("exact_box", "exact", "exact_box_true_type"):
            if r.true_box is None:
                continue
            s = replace(s, box=tuple(float(v) for v in r.true_box))
        if variant in ("exact_base", "exact"):
            if r.true_corners is None or s.base is None:
                continue
            s = replace(s, base=_exact_base(r), corners=r.true_corners)
        if variant in ("exact_sides", "exact_ends"):
            if r.true_box is None:
                continue
            keep = (0, 2) if variant == "exact_sides" else (1, 3)
            box = list(s.box)
            for k in keep:
                box[k] = float(r.true_box[k])
            s = replace(s, box=tuple(box))
        if variant == "hull" and r.hull_box is not None:
            s = replace(s, box=tuple(float(v) for v in r.hull_box))
        out.append((r.frame, float(s.t), s))
    return out


def load(path: Path) -> dict:
    """A dump with its records as :class:`Record` (stored as plain dicts, so any script can read them)."""
    with open(path, "rb") as fh:
        data = pickle.load(fh)
    data["records"] = [r if isinstance(r, Record) else Record(**r) for r in data["records"]]
    return data


def replay(data: dict, variant: str, until: float | None = None, parity: int | None = None, **options) -> dict:
    """λ* of ``variant``'s sightings; ``until``: only those of the first seconds, as if the video ended there;
    ``parity`` 0 / 1: only the tracks with even / odd ids (two disjoint halves of the scene's vehicles)."""
    from gst_trafficcal.scale.streaming import ScaleEstimator, load_align_models

    est = ScaleEstimator(load_align_models(None), **options)
    est.set_camera(data["camera"])
    frames: dict[int, list] = {}
    times: dict[int, float] = {}
    for n, t, s in variant_sightings(data["records"], variant):
        if until is not None and t > until:
            continue
        if parity is not None and s.track_id % 2 != parity:
            continue
        frames.setdefault(n, []).append(s)
        times[n] = t
    for n in sorted(frames):
        est.update(times[n], frames[n])
    est.finish()
    r = est.result()
    return {"scene": data["scene"], "variant": variant, "true": data["true"], "raw": r.raw_scale,
            "converged": r.converged, "matched": r.n_matched, "agreeing": r.n_agreeing,
            "error": None if r.raw_scale is None else 100 * (r.raw_scale / data["true"] - 1),
            "matches": est._matches}


def vehicle_table(data: dict, variants: list[str], min_vehicles: int = 5, **options) -> str:
    """Per variant, each matched vehicle's own λ error, the catalogue type it was matched with and what it is."""
    from collections import Counter

    truth: dict[int, Counter] = {}
    for r in data["records"]:
        truth.setdefault(r.sighting.track_id, Counter())[r.true_model] += 1
    lines = []
    for v in variants:
        res = replay(data, v, min_vehicles=min_vehicles, **options)
        lines.append(f"  {data['scene']} {v}: λ* {res['error']:+.2f} %" if res["error"] is not None else
                     f"  {data['scene']} {v}: no λ*")
        for m in res["matches"]:
            true = truth.get(m.track_id, Counter()).most_common(1)
            lines.append(f"    track {m.track_id:4d}  own {100 * (m.own / data['true'] - 1):+7.2f} %  "
                         f"{m.model:28s} is {true[0][0] if true else '?'}")
    return "\n".join(lines)


def halves_rows(data: dict, variant: str, min_vehicles: int, **options) -> tuple[float | None, float | None]:
    """λ* error (%) of the scene's even-id and odd-id tracks apart (each half needs ``min_vehicles``): where the
    two agree while the whole is far off, the scene's error is a bias its boxes share, not sampling."""
    out = []
    for parity in (0, 1):
        res = replay(data, variant, parity=parity, min_vehicles=min_vehicles, **options)
        out.append(res["error"])
    return out[0], out[1]


def halves_summary(pairs: list[tuple[float | None, float | None]]) -> str:
    """Median and RMS |even − odd| (%) over the scenes where both halves gave a λ*."""
    d = np.array([a - b for a, b in pairs if a is not None and b is not None])
    return "–" if not len(d) else f"{np.median(np.abs(d)):.2f} / {np.sqrt(np.mean(d ** 2)):.2f} ({len(d)} scenes)"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("dump", help="run the chain once per scene folder and store its sightings")
    d.add_argument("folders", nargs="+", type=Path)
    d.add_argument("--out", type=Path, default=Path("/tmp/sightings"))
    d.add_argument("--detector", default="", help="vehicledetect model (empty: the background detector)")
    d.add_argument("--duration", type=float, default=None, help="analyse only the first seconds")
    r = sub.add_parser("replay", help="replay stored sightings into ScaleEstimator variants")
    r.add_argument("files", nargs="+", type=Path)
    r.add_argument("--variant", default="chain,exact_box,exact_base,exact")
    r.add_argument("--min-vehicles", type=int, default=5)
    r.add_argument("--vehicles", action="store_true",
                   help="also list each matched vehicle: its own λ error, the type chosen and the true model")
    r.add_argument("--estimator", action="append", default=[], metavar="FIELD=VALUE",
                   help="a ScaleEstimator keyword for every variant (repeatable), e.g. --estimator iou_threshold=0.9 "
                        "or --estimator select=spread --estimator per_track=6")
    r.add_argument("--halves", action="store_true",
                   help="also λ* from the even-id and the odd-id tracks of each scene apart (min-vehicles halved): "
                        "do two disjoint halves of the vehicles agree (a bias of the scene's boxes) or not (sampling)")
    r.add_argument("--until", default=[], metavar="S[,S...]", type=_seconds_list,
                   help="also λ* from only the first S seconds of each scene, as if its video ended there (how long "
                        "the scale needs to watch), e.g. 60,120,240")
    a = ap.parse_args()
    if a.cmd == "dump":
        for f in a.folders:
            print(dump(f, a.out, a.detector, a.duration), flush=True)
        return
    missing = [str(f) for f in a.files if not f.is_file()]
    if missing:
        raise SystemExit(f"scale_sightings.py replay: no such dump: {', '.join(missing)}")
    from gst_trafficcal.scale.streaming import ScaleEstimator
    from options import field_overrides, parameter_defaults

    options = field_overrides(parameter_defaults(ScaleEstimator), a.estimator, "ScaleEstimator")
    names = a.variant.split(",")
    columns = {(f"{v} ≤ {u:g} s" if u is not None else v): (v, u) for u in [*a.until, None] for v in names}
    variants = list(columns)
    results: dict[str, list[dict]] = {v: [] for v in variants}  # per column, replay()'s result of each scene
    halves: list[tuple[str, dict]] = []  # --halves: per scene, each variant's (even, odd) λ* errors
    print("| scene | " + " | ".join(variants) + " |")
    print("|---|" + "---|" * len(variants))
    for f in a.files:
        data = load(f)
        cells = []
        for v in variants:
            res = replay(data, *columns[v], min_vehicles=a.min_vehicles, **options)
            results[v].append(res)
            cells.append("–" if res["error"] is None else
                         f"{res['error']:+.2f}{'' if res['converged'] else '*'} ({res['matched']}/{res['agreeing']})")
        print(f"| {data['scene']} | " + " | ".join(cells) + " |", flush=True)
        if a.vehicles:
            print(vehicle_table(data, names, a.min_vehicles, **options), flush=True)
        if a.halves:  # while the dump is loaded; printed after the summaries
            halves.append((data["scene"], {v: halves_rows(data, v, (a.min_vehicles + 1) // 2, **options)
                                           for v in names}))
    print("| median / mean abs % | " + " | ".join(_summary([r["error"] for r in results[v]]) for v in variants) + " |")
    # per set (replays: the BrnoCompSpeed recordings; synth: the rest), λ* and λ_reg = α·λ* left one out within the
    # set, as benchmarks/scale.py's BBScale and BBScale+reg (LOO) columns
    from scale import is_replay, loo_regression

    for name, replays in (("synth", False), ("replays", True)):
        sets = {v: [r for r in results[v] if is_replay(r["scene"]) == replays] for v in variants}
        if not sets[variants[0]]:
            continue
        reg = []
        for v in variants:
            lam = loo_regression([{**r, "bbscale": r["raw"]} for r in sets[v]])
            reg.append(_summary([None if x is None else 100 * (x / r["true"] - 1) for x, r in zip(lam, sets[v])]))
        print(f"| {name}: median / mean abs % | " + " | ".join(_summary([r["error"] for r in sets[v]])
                                                                for v in variants) + " |")
        print(f"| {name}, +reg (leave-one-out α·λ*) | " + " | ".join(reg) + " |")
    if a.halves:
        print("\n| scene | " + " | ".join(f"{v} even ids | {v} odd ids" for v in names) + " |")
        print("|---|" + "---|---|" * len(names))
        for scene, pairs in halves:
            print(f"| {scene} | " + " | ".join("–" if e is None else f"{e:+.2f}" for v in names for e in pairs[v])
                  + " |")
        cells = [c for v in names for c in (halves_summary([p[v] for _, p in halves]), "")]
        print("| median / RMS abs(even − odd) % | " + " | ".join(cells) + " |")


def _seconds_list(text: str) -> list[float]:
    """``--until``'s "S[,S...]": positive seconds (argparse reports a bad one at start-up)."""
    try:
        out = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        out = []
    if not out or not all(0 < v < float("inf") for v in out):
        raise argparse.ArgumentTypeError(f"expected positive seconds, comma-separated, got {text!r}")
    return out


def _summary(errors: list[float | None]) -> str:
    e = np.abs([x for x in errors if x is not None])
    return "–" if not len(e) else f"{np.median(e):.2f} / {np.mean(e):.2f}"


if __name__ == "__main__":
    main()
