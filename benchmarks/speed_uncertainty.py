"""How often a vehicle's true speed lies within speed ± speed_uncertainty_kmh, from end-to-end output folders.

For each scene: the run's folder (``vehicles.jsonl``, ``system.json``, ``calibration.json``, as
``benchmarks/end_to_end.py`` leaves them under ``WORK/<scene>/<mode>``) and the scene's folder with the renderer's
truth (``frames.jsonl``, ``scenario.json``).  Each measured vehicle is matched to the rendered vehicle its reference
points follow (``end_to_end.truth_matches``); its U is the one in vehicles.jsonl, or — for runs written before the
field — recomputed from its reference points in system.json and the run's calibration with
:mod:`gst_trafficcal.uncertainty` (``--recompute`` forces that, e.g. to try other constants).

    .venv/bin/python benchmarks/speed_uncertainty.py --runs /tmp/e2e --scenes /tmp/replays_cat --mode auto

Prints per scene and pooled: vehicles, coverage (share with |error| <= U), median U (km/h and % of the speed),
the calibration's own error (median error in % of the true speed), and the track part alone (the share of
vehicles whose error about their scene's median error lies within the track part's ±1.96 σ).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gst_trafficcal.brnocompspeed import load_results  # noqa: E402
from gst_trafficcal.calibration import load_calibration  # noqa: E402
from gst_trafficcal.outputs import read_events  # noqa: E402
from gst_trafficcal.speed import vehicle_speed  # noqa: E402
from gst_trafficcal.uncertainty import (  # noqa: E402
    DEFAULT_MODEL, UncertaintyModel, calibration_pct, speed_uncertainty,
)


@dataclass
class Vehicle:
    speed_kmh: float
    true_kmh: float
    u_kmh: float
    track_kmh: float  # the track part's 1σ (with its floor)
    spread_kmh: float  # the samples' own 1σ (uncertainty.sample_spread, no floor)
    track_inside: bool = False  # its error about its scene's median error within ±1.96 × the track part


@dataclass
class Scene:
    name: str
    calibration_pct: float | None  # the model's 1σ of the calibration
    speed_pct: float | None  # the view's sensitivity
    vehicles: list[Vehicle]


def score_scene(run: Path, truth: Path, model: UncertaintyModel = DEFAULT_MODEL, recompute: bool = False
                ) -> Scene | None:
    """The scene's matched vehicles with their U; None when the run left no calibration or no vehicles."""
    from end_to_end import scene_fps, truth_matches

    if not all((run / f).is_file() for f in ("vehicles.jsonl", "system.json", "calibration.json")):
        return None
    cal = load_calibration(run / "calibration.json")
    if cal.camera is None or cal.camera.scale is None:
        return None
    speed_pct = (json.loads((run / "calibration.json").read_text()).get("conditioning") or {}).get("speed_pct")
    cal_pct = calibration_pct(cal, speed_pct, model)
    events = read_events(run / "vehicles.jsonl").events
    results = load_results(run / "system.json")
    tracks = {t.id: t for t in results.cars}
    fps = scene_fps(truth)
    by_id = {e.id: e for e in events}
    out = []
    for m in truth_matches(truth / "frames.jsonl", events, run / "system.json", cal.image_size):
        e, tr = by_id[m.vehicle_id], tracks.get(m.vehicle_id)
        if tr is None:
            continue
        times = (tr.frames - tr.frames[0]) / fps
        vs = vehicle_speed(cal.camera, tr.pos, times)
        spread = vs.spread_kmh if vs.measured else 0.0
        track = max(model.track_factor * spread, model.track_floor_pct / 100 * e.speed_kmh)
        u = getattr(e, "speed_uncertainty_kmh", None)
        if recompute or u is None:
            u = speed_uncertainty(e.speed_kmh, spread, cal_pct, model)
        out.append(Vehicle(e.speed_kmh, e.speed_kmh - m.speed_error_kmh, float(u), track, spread))
    if out:
        med = np.median([v.speed_kmh / v.true_kmh - 1 for v in out])
        for v in out:
            v.track_inside = bool(abs(v.speed_kmh - v.true_kmh * (1 + med)) <= 1.96 * v.track_kmh)
    return Scene(truth.name, cal_pct, speed_pct, out)


def fit(scenes: list[Scene]) -> str:
    """The model's constants fitted on ``scenes`` (automatic calibrations): the calibration's 1σ² = scale² +
    vp² × sensitivity by maximum likelihood on the scenes' median relative errors (normal), and the track part's
    factor on the samples' spread as the one that holds 95 % of the vehicles' errors about their scene's median error
    (without a floor)."""
    e = np.array([np.median([100 * (v.speed_kmh / v.true_kmh - 1) for v in s.vehicles]) for s in scenes])
    sens = np.array([s.speed_pct if s.speed_pct is not None else DEFAULT_MODEL.unknown_speed_pct for s in scenes])
    best = (np.inf, 0.0, 0.0)
    for a in np.arange(0.05, 5.0, 0.05):
        for b in np.arange(0.0, 5.0, 0.05):
            var = a * a + b * b * sens
            nll = float(np.sum(np.log(var) + e * e / var))
            best = min(best, (nll, a, b))
    z = [abs(v.speed_kmh - v.true_kmh * (1 + m / 100)) / v.spread_kmh
         for s, m in zip(scenes, e) for v in s.vehicles if v.spread_kmh > 0]
    return (f"fit on {len(scenes)} scenes, {sum(len(s.vehicles) for s in scenes)} vehicles: scale_pct "
            f"{best[1]:.2f}, vp_pct_per_root {best[2]:.2f}, track_factor {np.percentile(z, 95) / 1.96:.2f} "
            f"(scene errors % @ sensitivity: "
            f"{', '.join(f'{x:+.1f}@{y:.1f}' for x, y in zip(e, sens))})")


def summary(vehicles: list[Vehicle]) -> str:
    """n | coverage | median U km/h (% of speed) | calibration error % (median) | track-part coverage."""
    if not vehicles:
        return "0 | – | – | – | –"
    err = np.array([v.speed_kmh - v.true_kmh for v in vehicles])
    true = np.array([v.true_kmh for v in vehicles])
    u = np.array([v.u_kmh for v in vehicles])
    rel = 100 * err / true
    inside_track = [v.track_inside for v in vehicles]
    return (f"{len(vehicles)} | {np.mean(np.abs(err) <= u):.3f} | {np.median(u):.2f} "
            f"({np.median(100 * u / np.array([v.speed_kmh for v in vehicles])):.1f} %) | {np.median(rel):+.2f} | "
            f"{np.mean(inside_track):.3f}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=Path, required=True, help="end_to_end.py's work folder: RUNS/<scene>/<mode>")
    ap.add_argument("--scenes", type=Path, required=True, help="the scenes' folders: SCENES/<scene>/frames.jsonl")
    ap.add_argument("--mode", default="auto")
    ap.add_argument("--label", default="", help="the set's name in the pooled row")
    ap.add_argument("--recompute", action="store_true", help="U from the model even where vehicles.jsonl has it")
    ap.add_argument("--fit", action="store_true", help="also print the model's constants fitted on these scenes")
    for f in ("track_factor", "track_floor_pct", "scale_pct", "vp_pct_per_root", "manual_pct"):
        ap.add_argument("--" + f.replace("_", "-"), type=float, default=getattr(DEFAULT_MODEL, f))
    a = ap.parse_args(argv)
    model = replace(DEFAULT_MODEL, track_factor=a.track_factor, track_floor_pct=a.track_floor_pct,
                    scale_pct=a.scale_pct, vp_pct_per_root=a.vp_pct_per_root, manual_pct=a.manual_pct)
    print("| scene | sensitivity % | calibration 1σ % | vehicles | coverage | median U km/h (% of speed) | "
          "median error % | track part alone: coverage |")
    print("|---|---|---|---|---|---|---|---|")
    pooled: list[Vehicle] = []
    scored: list[Scene] = []
    for folder in sorted(p for p in a.scenes.iterdir() if (p / "frames.jsonl").is_file()):
        s = score_scene(a.runs / folder.name / a.mode, folder, model, a.recompute)
        if s is None:
            print(f"| {folder.name} | – | – | no calibrated run | | | | |")
            continue
        pooled += s.vehicles
        scored += [s] if s.vehicles else []
        sens = "–" if s.speed_pct is None else f"{s.speed_pct:.1f}"
        print(f"| {s.name} | {sens} | {s.calibration_pct:.2f} | {summary(s.vehicles)} |")
    print(f"| **{f'pooled {a.label}'.strip()}** | | | {summary(pooled)} |")
    if a.fit:
        print(fit(scored))
    return 0


if __name__ == "__main__":
    sys.exit(main())
