"""Relative scale error per scene: BBScale, BBScale+reg (leave-one-out), BMVC14, ManualScale.

Each preset is rendered once (``trafficcal synth``, cached in --work), then the whole chain runs on its video
(background detector, tracker, BBScale; :func:`gst_trafficcal.scale.video.scale_from_video`) with the scene's
true vanishing points.  BBScale+reg: the regression λ_reg = αλ* (+ β with ``--regression-form affine``) fitted
on all *other* converged scenes (leave-one-out cross-validation).  BMVC14: median 3D-box dimensions of the same tracks against a mean car.  ManualScale: the
scene's measured distances towards VP1 (gt_data.pkl) with the true VPs.  Prints a markdown table and writes
docs/results/scale.md (with ``--write``).

BrnoCompSpeed replays (``--replays session0_center,...``, folders in --replay-work): each recording of
sessions 0-3 replayed by ``trafficcal synth`` (docs/synth.md "Replay mode") with the camera of its
ManualCalib+ManualScale calibration (``trafficcal calibrate-manual``), overcast light, 1920x1080, 60 s (120 s
for the sparse session 3) from the busiest window (:data:`REPLAY_STARTS`), or ``--replay-duration`` seconds from
its start; the true λ is that rendering camera's.  Folders already in --replay-work are reused (the lead's
/tmp/replays; one rendered with another duration is an error), missing ones rendered.
Per-scene results are kept in --work under a name holding the detector's weights and the chain's code
(:func:`detector_key`, :func:`code_key`): a second run of the same code only re-prints (e.g. to ``--write``).

    .venv/bin/python benchmarks/scale.py --work /tmp/scale_bench --duration 40 --jobs 2 \
        --replay-work /tmp/replays --replays all
    .venv/bin/python benchmarks/scale.py --presets '' --replays all --replay-work /tmp/replays_long \
        --replay-duration 240,360 --traffic catalogue --detector vehicleseg --work /tmp/scale_long
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PRESETS = ("octavia_reference", "highway_day", "right_side_oneway", "left_side", "low_camera", "high_camera",
           "zoom", "wide", "country_two_way", "sparse")


#: start (s) of the busiest 60 s window of each recording (120 s for session 3), as rendered in /tmp/replays
REPLAY_STARTS = {"session0_center": 20.0, "session0_left": 75.0, "session0_right": 20.0,
                 "session1_center": 1060.1, "session1_left": 1013.9, "session1_right": 1060.6,
                 "session2_center": 3029.5, "session2_left": 3013.4, "session2_right": 3020.2,
                 "session3_center": 356.3, "session3_left": 389.4, "session3_right": 422.3}
BRNO = ROOT.parent / "shared" / "data" / "brnocompspeed"

#: ``--traffic catalogue``: the scenes' traffic with half of the passenger cars named catalogue types (3 % of
#: the traffic each, the Škoda/VW types common on Czech roads), the other half generic cars of random
#: dimensions, and the presets' vans, trucks, buses and motorcycles — real traffic consists of real models, some
#: of them in the catalogue; the presets' traffic has only generic cars, none of a catalogue type
CATALOGUE_TRAFFIC = (
    "traffic:\n"
    "  mix: {sedan: 0.15, estate: 0.10, hatchback: 0.12, suv: 0.06, van: 0.08, truck: 0.04, bus: 0.02, "
    "motorcycle: 0.02}\n"
    "  models: {" + ", ".join(f"{m}: 0.03" for m in (
        "skoda_octavia_mk1_liftback", "skoda_octavia_mk1_combi", "skoda_octavia_mk2_liftback",
        "skoda_octavia_mk2_combi", "skoda_octavia_mk3_combi", "skoda_superb_mk2_liftback",
        "skoda_fabia_mk1_hatchback", "skoda_fabia_mk2_hatchback", "vw_golf_mk4_hatchback", "vw_golf_mk6_hatchback",
        "vw_passat_b6_variant", "skoda_yeti_suv", "vw_tiguan_mk1_suv")) + "}\n")


def replay_duration(name: str, duration: str | float | None = None) -> float:
    """Seconds of recording ``name`` a replay holds.  ``duration``: None for 60 (120 for the sparse session 3), a
    number for every recording, or "SECONDS,SESSION3_SECONDS"."""
    if duration is None or duration == "":
        return 120.0 if name.startswith("session3") else 60.0
    parts = duration_arg(str(duration))
    return parts[-1] if name.startswith("session3") else parts[0]


def duration_arg(text: str) -> list[float]:
    """``--replay-duration``'s "S" or "S,S3": positive seconds (argparse reports a bad one at start-up)."""
    try:
        parts = [float(v) for v in text.split(",")]
    except ValueError:
        parts = []
    if not 1 <= len(parts) <= 2 or not all(0 < v < float("inf") for v in parts):
        raise argparse.ArgumentTypeError(f"expected SECONDS or SECONDS,SESSION3_SECONDS (positive), got {text!r}")
    return parts


def _duration_option(text: str) -> str:
    """``--replay-duration`` checked at start-up, kept as given (:func:`replay_duration` reads it per recording)."""
    duration_arg(text)
    return text


def render_replay(name: str, work: Path, traffic: str = "preset", duration: str | float | None = None) -> Path:
    """The replay folder of recording ``name`` in ``work`` (rendered when missing; ``traffic`` "catalogue" adds
    :data:`CATALOGUE_TRAFFIC`; ``duration`` see :func:`replay_duration`).  A folder rendered with another duration
    is an error, not reused."""
    out = work / name
    dur = replay_duration(name, duration)
    if (out / "video.mp4").is_file():
        scenario = out / "scenario.json"  # renders older than the scenario file are taken as they are
        held = json.loads(scenario.read_text()).get("duration") if scenario.is_file() else None
        if held is not None and abs(float(held) - dur) > 1e-6:
            raise SystemExit(f"{out} holds {held:g} s of replay, not {dur:g} s: use another --replay-work")
        return out
    gt = BRNO / name / "gt_data.pkl"
    if not gt.is_file():
        raise SystemExit(f"{gt} not found (../shared with BrnoCompSpeed is needed to render replays)")
    cfg = work / "cfg"
    cfg.mkdir(parents=True, exist_ok=True)
    tc = str(ROOT / ".venv/bin/trafficcal")
    subprocess.run([tc, "calibrate-manual", "--gt", str(gt), "-o", str(cfg / f"cal_{name}.json")], check=True,
                   capture_output=True)
    (cfg / f"{name}.yaml").write_text(
        f"duration: {dur:g}\nimaging: {{fps: 25}}\nlighting: {{preset: overcast}}\nreplay:\n  gt_data: {gt}\n"
        f"  calibration: cal_{name}.json\n  start: {REPLAY_STARTS[name]}\n"
        + (CATALOGUE_TRAFFIC if traffic == "catalogue" else ""))
    subprocess.run([tc, "synth", "--scenario", str(cfg / f"{name}.yaml"), "--out", str(out), "--no-progress"],
                   check=True, capture_output=True)
    return out


def render(preset: str, work: Path, duration: float, seed: int, traffic: str = "preset") -> Path:
    tc = str(ROOT / ".venv/bin/trafficcal")
    if traffic == "catalogue":
        out = work / f"{preset}_s{seed}_{duration:g}_cat"
        if not (out / "video.mp4").is_file():
            cfg = work / "cfg" / f"{preset}_cat.yaml"
            cfg.parent.mkdir(parents=True, exist_ok=True)
            cfg.write_text(f"base: {preset}\nduration: {duration:g}\n{CATALOGUE_TRAFFIC}")
            subprocess.run([tc, "synth", "--scenario", str(cfg), "--seed", str(seed), "--out", str(out),
                            "--no-progress"], check=True, capture_output=True)
        return out
    out = work / f"{preset}_s{seed}_{duration:g}"
    if not (out / "video.mp4").is_file():
        subprocess.run([tc, "synth", "--preset", preset, "--duration", str(duration),
                        "--seed", str(seed), "--out", str(out), "--no-progress"], check=True, capture_output=True)
    return out


class SideEstimators:
    """Two more scale stages fed from the same tracking pass: the tracker's hull box instead of the detector's
    rectangle, and the renderer's exact 2D box (frames.jsonl, the vehicle the detection overlaps most) with the
    same tracks, 3D-box bases and selection — the error left when the 2D box is exact."""

    def __init__(self, folder: Path, camera, models, min_vehicles: int):
        from gst_trafficcal.scale.streaming import ScaleEstimator

        self.camera = camera
        self.hull = ScaleEstimator(models, min_vehicles=min_vehicles)
        self.exact = ScaleEstimator(models, min_vehicles=min_vehicles)
        for e in (self.hull, self.exact):
            e.set_camera(camera)
        from gst_trafficcal.synth.groundtruth import records_by_frame

        self.truth = {n: np.asarray([r["box"] for r in recs], np.float64).reshape(-1, 4)
                      for n, recs in records_by_frame(folder / "frames.jsonl").items()}

    def __call__(self, n: int, t: float, result, detections) -> None:
        from dataclasses import replace

        from gst_trafficcal.scale.alignment import box_iou
        from gst_trafficcal.scale.video import frame_sightings

        self.hull.update(t, frame_sightings(result, detections, self.camera, "hull"))
        truth = self.truth.get(n)
        exact = []
        for s in frame_sightings(result, detections, self.camera, "detector"):
            if truth is None or not len(truth):
                continue
            iou = box_iou(truth, s.box)
            if iou.max() > 0.5:
                exact.append(replace(s, box=tuple(float(v) for v in truth[int(np.argmax(iou))])))
        self.exact.update(t, exact)

    def results(self):
        for e in (self.hull, self.exact):
            e.finish()
        return self.hull.result(), self.exact.result()


def measure(folder: Path, min_vehicles: int, cache_dir: Path, background: str = "mog2",
            duration: float | None = None, detector: str = "") -> dict:
    from gst_trafficcal.brnocompspeed import load_gt_data
    from gst_trafficcal.calibration import load_calibration
    from gst_trafficcal.manual_calibration import manual_scale
    from gst_trafficcal.scale.baseline import bmvc14_scale
    from gst_trafficcal.scale.streaming import load_align_models
    from gst_trafficcal.scale.video import scale_from_video

    cache = cache_dir / f"{folder.name}.json"
    if cache.is_file():
        return json.loads(cache.read_text())
    cal = load_calibration(folder / "calibration.json")
    true = float(cal.camera.scale)
    models = load_align_models(None)
    side = SideEstimators(folder, cal.camera.with_scale(None), models, min_vehicles)
    res = scale_from_video(folder / "video.mp4", cal.with_scale(None), models=models, min_vehicles=min_vehicles,
                           on_frame=side, background=background, max_duration=duration, detector=detector)
    r = res.result
    hull, exact = side.results()
    base = bmvc14_scale(res.box_params) if len(res.box_params) else None
    gt = load_gt_data(folder / "gt_data.pkl")
    sel = gt.distances_to_vp1
    manual = manual_scale(cal.camera, gt.distances_p1[sel], gt.distances_p2[sel], gt.distances_m[sel]) \
        if sel.any() else None
    row = {"scene": folder.name, "true": true, "bbscale": r.raw_scale, "converged": bool(r.converged),
           "status": r.status, "matched": r.n_matched, "agreeing": r.n_agreeing, "types": r.types,
           "hull": hull.raw_scale, "exact": exact.raw_scale, "exact_matched": exact.n_matched,
           "bmvc14": None if base is None or base.scale is None else base.scale, "manual": manual}
    cache.write_text(json.dumps(row))
    return row


def is_replay(scene: str) -> bool:
    """Whether a scene (folder name) is a BrnoCompSpeed replay (``session<k>_<view>``) rather than a synth preset."""
    return scene.startswith("session")


def loo_regression(rows: list[dict], form: str = "ratio") -> list[float | None]:
    """Per scene, λ_reg from the regression (``trafficcal fit-scale --form``) fitted on the other converged scenes."""
    from gst_trafficcal.scale.regression import leave_one_out

    # trained as trafficcal fit-scale does: only scenes where the stage converged
    regs = leave_one_out([r["bbscale"] for r in rows], [r["true"] for r in rows], [r["scene"] for r in rows],
                         train=[r["converged"] for r in rows], form=form, min_others=2)
    return [None if reg is None or row["bbscale"] is None else reg.apply(row["bbscale"])
            for reg, row in zip(regs, rows)]


def fmt(v, true) -> str:
    return "–" if v is None else f"{100 * (v / true - 1):+.2f}"


def summary(errors: list[float]) -> str:
    e = np.abs(np.array([x for x in errors if x is not None]))
    return "–" if not len(e) else f"{np.median(e):.2f} / {np.mean(e):.2f} / {e.max():.2f} (n={len(e)})"


def detector_key(detector: str) -> str:
    """The per-scene results cache's name for a detector: its name and the first digits of its weights' sha256, so
    results of an earlier version of a model (a re-trained vehicleseg) are never taken for this one's."""
    from gst_trafficcal.detection import vehicleseg
    from gst_trafficcal.detection.models import resolve_model, sha256_of

    path = vehicleseg.WEIGHTS if detector == vehicleseg.NAME else resolve_model(detector)
    return f"{Path(detector).stem}-{sha256_of(path)[:8]}"


CHAIN_PACKAGES = ("detection", "tracking", "scale", "vehicles")  # what a scene's row depends on besides the inputs


def code_key(root: Path = ROOT / "gst_trafficcal", packages: tuple[str, ...] = CHAIN_PACKAGES) -> str:
    """First digits of a sha256 over the chain's source files (``root/<package>/**/*.py``), so a results cache
    written by other code (e.g. another λ* kernel) is never taken for this code's."""
    import hashlib

    h = hashlib.sha256()
    for pkg in packages:
        for f in sorted((root / pkg).rglob("*.py")):
            h.update(str(f.relative_to(root)).encode() + b"\0" + f.read_bytes())
    return h.hexdigest()[:8]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=Path("/tmp/scale_bench"))
    ap.add_argument("--presets", default=",".join(PRESETS))
    ap.add_argument("--duration", type=float, default=40.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--min-vehicles", type=int, default=3)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--replays", default="", help="BrnoCompSpeed replays: comma-separated names or 'all'")
    ap.add_argument("--replay-work", type=Path, default=Path("/tmp/replays"))
    ap.add_argument("--replay-duration", default=None, metavar="S[,S3]", type=_duration_option,
                    help="seconds of each recording to replay, optionally another figure for session 3 (default 60,120);"
                         " a longer stretch shows the scale more vehicles")
    ap.add_argument("--renders", type=Path, default=None,
                    help="use the synth scenes already rendered in RENDERS/<preset> (e.g. /tmp/aa_syn, 60 s) instead of "
                         "rendering; the first --duration seconds are analysed")
    ap.add_argument("--traffic", choices=("preset", "catalogue"), default="preset",
                    help="the presets' traffic (generic cars only) or CATALOGUE_TRAFFIC (half the cars catalogue types)")
    ap.add_argument("--background", choices=("mog2", "average"), default="mog2", help="background detector method")
    ap.add_argument("--detector", default="", help="vehicledetect's model instead of the background detector, e.g. "
                    "vehicleseg (boxes + hulls)")
    ap.add_argument("--regression-form", choices=("ratio", "affine"), default="ratio",
                    help="form of the leave-one-out BBScale+reg (trafficcal fit-scale --form)")
    ap.add_argument("--write", type=Path, default=None,
                    help="also write the table as markdown here, e.g. docs/results/scale.md")
    a = ap.parse_args()
    a.work.mkdir(parents=True, exist_ok=True)
    presets = [p for p in a.presets.split(",") if p]
    replays = list(REPLAY_STARTS) if a.replays == "all" else [r for r in a.replays.split(",") if r]
    with ProcessPoolExecutor(a.jobs) as pool:
        if a.renders is not None:
            folders = [a.renders / p for p in presets]
            missing = [str(f) for f in folders if not (f / "video.mp4").is_file()]
            if missing:
                raise SystemExit(f"not rendered: {', '.join(missing)}")
        else:
            folders = list(pool.map(render, presets, [a.work] * len(presets), [a.duration] * len(presets),
                                    [a.seed] * len(presets), [a.traffic] * len(presets)))
        n_synth = len(folders)
        folders += [render_replay(r, a.replay_work, a.traffic, a.replay_duration) for r in replays]
        cache = a.work / ((f"results_{detector_key(a.detector)}_{a.traffic}" if a.detector
                           else f"results_{a.background}_{a.traffic}") + f"_code-{code_key()}")
        cache.mkdir(exist_ok=True)
        durations = [a.duration] * n_synth + [None] * (len(folders) - n_synth)
        rows = list(pool.map(measure, folders, [a.min_vehicles] * len(folders), [cache] * len(folders),
                             [a.background] * len(folders), durations, [a.detector] * len(folders)))
    reg = loo_regression(rows, a.regression_form)
    lines = ["| scene | true λ (m) | BBScale % | BBScale+reg (LOO) % | BMVC14 % | ManualScale % | matched / agreeing "
             "| BBScale, hull box % | BBScale, exact box % |",
             "|---|---|---|---|---|---|---|---|---|"]
    keys = ("bbscale", "reg", "bmvc14", "manual", "hull", "exact")
    errs = {k: [] for k in keys}
    for row, rg in zip(rows, reg):
        t = row["true"]
        lines.append(f"| {row['scene']} | {t:.2f} | {fmt(row['bbscale'], t)} | {fmt(rg, t)} | "
                     f"{fmt(row['bmvc14'], t)} | {fmt(row['manual'], t)} | {row['matched']} / {row['agreeing']}"
                     f"{'' if row['converged'] else ' (not converged)'} | {fmt(row['hull'], t)} | "
                     f"{fmt(row['exact'], t)} |")
        for k in keys:
            v = rg if k == "reg" else row[k]
            errs[k].append(None if v is None else 100 * (v / t - 1))
    groups = [("all", [True] * len(rows))]
    replay = [is_replay(r["scene"]) for r in rows]
    if any(replay) and not all(replay):
        groups = [("synth", [not x for x in replay]), ("replays", replay)] + groups
    for name, mask in groups:
        def pick(k):
            return [e for e, m in zip(errs[k], mask) if m]
        lines.append(f"| **{name}: median / mean / max abs %** | | " + " | ".join(summary(pick(k)) for k in keys[:4])
                     + " | | " + " | ".join(summary(pick(k)) for k in keys[4:]) + " |")
    table = "\n".join(lines)
    print(table)
    cmd = shlex.join(["benchmarks/scale.py", *sys.argv[1:]])
    if a.write is None:
        return
    a.write.parent.mkdir(parents=True, exist_ok=True)
    a.write.write_text(
        "# Scene scale λ on synthetic scenes and BrnoCompSpeed replays\n\n"
        f"Command: `.venv/bin/python {cmd}` ("
        + (f"the first {a.duration:g} s of each preset's render in {a.renders}" if a.renders is not None else
           f"each preset rendered for {a.duration:g} s, seed {a.seed}") + "; the "
        f"chain: vehicledetect ({f'model={a.detector}' if a.detector else 'background detector'}), the tracker, "
        "BBScale with every passenger-car type of the "
        "catalogue, no classifier, the scene's true vanishing points). Relative error λ/λ_true − 1 in %; "
        f"BBScale+reg is leave-one-out (the regression, form {a.regression_form}, fitted on the other converged scenes). λ* is reported even when "
        "the stage did not converge (fewer than --min-vehicles agreeing vehicles; marked). A dash: no estimate. "
        f"Traffic: {a.traffic} ({'half of the passenger cars named catalogue types, benchmarks/scale.py CATALOGUE_TRAFFIC' if a.traffic == 'catalogue' else 'the presets own: generic cars of random dimensions, none of a catalogue type'}); "
        + (f"detector: vehicledetect model={a.detector}. " if a.detector else
           f"background detector method: {a.background}. ") +
        "Replays (session*): true λ = the rendering camera's (our ManualCalib+ManualScale of the recording); "
        "ManualScale recomputed from the recording's measured distances with the true VPs. Diagnostic columns "
        "from the same tracking pass: BBScale aligned with the tracker's hull box instead of the detector's "
        "rectangle, and with the renderer's exact 2D box of each tracked vehicle (same tracks, bases, "
        "selection; no regression).\n\n" + table + "\n")


if __name__ == "__main__":
    main()
