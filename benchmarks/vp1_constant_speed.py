"""VP1 moved along the lanes by the tracks' constant-speed motion: the calibrator with and without that step.

For each rendered scene (a synth preset or a BrnoCompSpeed replay: a folder with video.mp4, calibration.json and
the renderer's per-frame truth frames.jsonl), ``calibrate_video`` runs twice, with ``vp1_constant_speed`` off (VP1
where the tracks' lines meet, the Diamond Space peak) and on (the default: then moved along the lanes,
:mod:`gst_trafficcal.vanishing.constant_speed`).  Reported per scene: VP1's error in pixels and in degrees on the
viewing sphere, and the **road distance error at the true scale**: the median relative error of the distances the
vehicles' reference points travel in five frames, measured with the calibration's vanishing points and the scene's
true λ (camera height), against the renderer's — the speed error a perfect scale would leave, i.e. how much the
vanishing points alone stretch the road.

    .venv/bin/python benchmarks/vp1_constant_speed.py /tmp/replays_cat/session* [--jobs 2] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gst_trafficcal.calibration import load_calibration  # noqa: E402
from gst_trafficcal.diamond import angle_between  # noqa: E402
from gst_trafficcal.geometry import Camera, homogeneous  # noqa: E402
from gst_trafficcal.vanishing.calibrator import CalibratorConfig, calibrate_video  # noqa: E402

from comparison import before_after, dash  # noqa: E402  (benchmarks/comparison.py)

STEP = 5  # frames between the two points of a travelled distance (the speedometer's τ)


@dataclass
class Row:
    scene: str
    group: str = ""  # the scene folder's parent (e.g. the replays' and the synth renders' folders)
    speed_tracks: int = 0
    shift_px: float | None = None  # how far the step moved VP1 along the lanes
    shift_rel: float | None = None  # ... as a share of VP1's distance from the tracks (refused above max_along)
    vp1_px_off: float | None = None
    vp1_px_on: float | None = None
    vp1_deg_off: float | None = None
    vp1_deg_on: float | None = None
    dist_off: float | None = None  # road distance error at the true scale, %, signed median
    dist_on: float | None = None
    note: str = ""


def reference_pairs(scene: Path, step: int = STEP) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(first points (M, 2), second points (M, 2) in pixels, true distances (M,) in metres) of every fully visible
    vehicle's reference point ``step`` frames apart that moved at least half a metre (frames.jsonl)."""
    by_id: dict[int, dict[int, tuple]] = {}
    with open(scene / "frames.jsonl") as fh:
        for line in fh:
            r = json.loads(line)
            if r.get("visible", 1.0) < 1.0:
                continue
            by_id.setdefault(r["id"], {})[r["frame"]] = (r["ref"], r["ref_world"])
    a, b, d = [], [], []
    for frames in by_id.values():
        for k, (p, w) in frames.items():
            if k + step in frames:
                q, w2 = frames[k + step]
                dist = float(np.linalg.norm(np.subtract(w2[:2], w[:2])))
                if dist >= 0.5:
                    a.append(p)
                    b.append(q)
                    d.append(dist)
    return np.array(a, float).reshape(-1, 2), np.array(b, float).reshape(-1, 2), np.array(d)


def road_distance_error(pairs, camera: Camera, scale: float) -> float:
    """Median relative error (%) of the distances of :func:`reference_pairs` measured with ``camera``'s vanishing
    points and the scale ``scale``."""
    a, b, d = pairs
    measured = np.asarray(camera.with_scale(scale).plane_distance(a, b)) * scale
    return float(100 * np.median(measured / d - 1))


def vp_road_error(folder: Path, camera: Camera, true_scale: float | None) -> float | None:
    """How much ``camera``'s vanishing points alone stretch the road (%): :func:`road_distance_error` of the scene's
    :func:`reference_pairs` at its true λ. With the λ error beside it, it splits a fully automatic run's speed
    error into its two parts (the end-to-end benchmark's "road err % at true λ"; the calibration benchmark prints it
    too): the speeds are off by about (1 + λ err)(1 + road err) − 1.  None without per-frame truth (frames.jsonl),
    a true scale or a vehicle's reference points."""
    if not true_scale or not (folder / "frames.jsonl").is_file():
        return None
    pairs = reference_pairs(folder)
    return road_distance_error(pairs, camera, true_scale) if len(pairs[2]) else None


def evaluate(scene: Path) -> Row:
    row = Row(scene.name, scene.resolve().parent.name)
    truth = load_calibration(scene / "calibration.json").camera
    pairs = reference_pairs(scene)
    if not len(pairs[2]):
        row.note = "no vehicle reference points in frames.jsonl"
        return row
    for on in (False, True):
        res = calibrate_video(scene / "video.mp4", CalibratorConfig(vp1_constant_speed=on))
        cam = res.calibration.camera
        if cam is None:
            row.note = f"no vanishing points ({res.calibration.reason})"
            return row
        px = float(np.linalg.norm(cam.vp1 - truth.vp1))
        deg = angle_between(homogeneous(cam.vp1), homogeneous(truth.vp1), truth.pp, truth.focal)
        dist = road_distance_error(pairs, cam, truth.scale)
        if on:
            row.vp1_px_on, row.vp1_deg_on, row.dist_on = px, deg, dist
            along = res.calibrator.along
            row.speed_tracks = along.tracks if along is not None else 0
            row.shift_px = along.shift_px if along is not None else None
            row.shift_rel = along.relative if along is not None else None
            if along is None:
                row.note = "the tracks did not place VP1 along the lanes (kept where the lines meet)"
            elif "vp1_along_refused_px" in res.calibration.confidence:
                row.note = f"move refused ({100 * along.relative:+.0f} % of VP1's distance; kept where the lines meet)"
        else:
            row.vp1_px_off, row.vp1_deg_off, row.dist_off = px, deg, dist
    return row


def _f(v, fmt: str = ".2f") -> str:
    return dash(v, fmt)


def table(rows: list[Row]) -> str:
    out = ["| scene | tracks | VP1 moved px (share of its distance) | VP1 err px, off → on | VP1 err °, off → on | road distance err at true "
           "scale %, off → on |", "|---|---|---|---|---|---|"]
    for r in rows:
        moved = _f(r.shift_px, '+.1f') + ("" if r.shift_rel is None else f" ({100 * r.shift_rel:+.1f} %)")
        out.append(f"| {r.scene} | {r.speed_tracks} | {moved} | {_f(r.vp1_px_off, '.1f')} → "
                   f"{_f(r.vp1_px_on, '.1f')} | {_f(r.vp1_deg_off, '.3f')} → {_f(r.vp1_deg_on, '.3f')} | "
                   f"{_f(r.dist_off, '+.2f')} → {_f(r.dist_on, '+.2f')} |" + (f" {r.note}" if r.note else ""))
    done = [r for r in rows if r.dist_on is not None and r.dist_off is not None]
    groups = sorted({r.group for r in done})
    for label, sel in ([(f"{g}/", [r for r in done if r.group == g]) for g in groups] if len(groups) > 1 else []) \
            + ([("", done)] if done else []):
        def summary(a: str, b: str, fmt: str, absolute: bool = False) -> str:
            x = np.array([getattr(r, a) for r in sel], float)
            y = np.array([getattr(r, b) for r in sel], float)
            return before_after(np.abs(x), np.abs(y), fmt) if absolute else before_after(x, y, fmt)
        out.append(f"| **{label}{len(sel)} scenes** | | | {summary('vp1_px_off', 'vp1_px_on', '.1f')} | "
                   f"{summary('vp1_deg_off', 'vp1_deg_on', '.3f')} | {summary('dist_off', 'dist_on', '.2f', True)}"
                   " (absolute) |")
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="+", type=Path, help="rendered scene folders (video.mp4, calibration.json, "
                                                         "frames.jsonl)")
    ap.add_argument("--jobs", type=int, default=1, help="scenes calibrated at the same time")
    ap.add_argument("--json", type=Path, help="write the rows as JSON")
    args = ap.parse_args()
    missing = [s for s in args.scenes if not all((s / f).is_file() for f in ("video.mp4", "calibration.json",
                                                                             "frames.jsonl"))]
    if missing:
        raise SystemExit(f"not a rendered scene (video.mp4, calibration.json and frames.jsonl needed): "
                         f"{', '.join(map(str, missing))}")
    with ProcessPoolExecutor(max(1, args.jobs)) as pool:
        rows = []
        for r in pool.map(evaluate, args.scenes):
            rows.append(r)
            print(f"{r.scene}: VP1 {_f(r.vp1_px_off, '.1f')} -> {_f(r.vp1_px_on, '.1f')} px, road distances "
                  f"{_f(r.dist_off, '+.2f')} -> {_f(r.dist_on, '+.2f')} % {r.note}", flush=True)
    print()
    print(table(rows))
    if args.json:
        args.json.write_text(json.dumps([asdict(r) for r in rows], indent=1) + "\n")


if __name__ == "__main__":
    main()
