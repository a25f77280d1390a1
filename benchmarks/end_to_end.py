"""End-to-end benchmark of the product: ``trafficcal run`` on synthetic scenes and BrnoCompSpeed replays, scored
with the BrnoCompSpeed evaluator (the same code as ``trafficcal eval``).

Modes (``--modes``):

* ``auto`` — fully automatic, nothing from the ground truth: ``trafficcal run VIDEO --no-overlay``, i.e.
  ``vpdetect ! vehicledetect ! tracker ! bbscale ! speedometer``.  A scene whose vanishing points or scale did not
  converge is reported as such; its vehicles are unmeasured and count as missed in the pooled recall.
* ``auto-reg`` — fully automatic with the paper's scale-correcting regression (BBScaleReg): for each scene,
  λ_reg = αλ* (+ β with ``--regression-form affine``) fitted (``trafficcal fit-scale``'s fit) on the *other* scenes of its group (synth / replays):
  their ``auto`` runs' λ* against their scene camera's λ (leave-one-out; the paper trains it on other videos),
  then ``trafficcal run --scale-regression``.  Needs ``auto`` in the same run.
* ``manual`` — the same chain with the paper's ManualCalib + ManualScale calibration (``trafficcal
  calibrate-manual`` from the ground-truth markings, given as ``--calibration``): separates the tracking/speed
  error from the calibration error.  On replays this is the rendering camera itself.

Per scene and mode: mean / median / 95th / 99th percentile absolute speed error of matched valid cars
(BrnoCompSpeed median mode), recall, false positives, the calibration's distance-ratio error (mean relative, as
``benchmarks/calibration.py``), its scale error against the scene's camera (true camera for synth, rendering
camera for replays), wall-clock and CPU-time frames per second.  Prints a markdown table against the paper's
numbers and writes JSON.

Scenes: synth presets rendered into ``--syn-work/<preset>`` (``trafficcal synth --preset P --duration D``; the
calibration benchmark's /tmp/syn renders are reused); replays of sessions 0–3 from ``--replays/<session>_<view>``
(the lead's /tmp/replays), rendered into ``--work/replays`` by the same recipe when absent (``trafficcal
calibrate-manual`` then ``trafficcal synth --scenario`` with a ``replay:`` block, docs/synth.md).

``--throughput VIDEO``: only the throughput measurement on one 1920x1080 H.264 video (also the chain with
trafficoverlay and the x264 encoding of overlay.mp4, as ``trafficcal run`` does by default): decode-only pipelines
(``filesrc ! decodebin ! fakesink``, and with ``videoconvert`` to I420) and the product chain, each run by
``gst-launch-1.0`` in the same invocation; prints wall and CPU-time fps and the chain/decode ratio.

    nice -n 10 .venv/bin/python benchmarks/end_to_end.py --json /tmp/e2e_bench/end_to_end.json
    nice -n 10 .venv/bin/python benchmarks/end_to_end.py --throughput /tmp/replays/session0_center/video.mp4
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from gst_trafficcal.synth.truth_match import vehicle_key

ROOT = Path(__file__).resolve().parents[1]
TRAFFICCAL = [sys.executable, "-m", "gst_trafficcal"]
BRNO = ROOT.parent / "shared" / "data" / "brnocompspeed"
SYNTH_PRESETS = "highway_day,right_side_oneway,high_camera,vp2_far"
# busiest window of each recording (start in seconds, vehicles in it), as chosen for /tmp/replays/starts.txt
REPLAY_STARTS = {
    "session0_center": 20.0, "session0_left": 75.0, "session0_right": 20.0,
    "session1_center": 1060.1, "session1_left": 1013.9, "session1_right": 1060.6,
    "session2_center": 3029.5, "session2_left": 3013.4, "session2_right": 3020.2,
    "session3_center": 356.3, "session3_left": 389.4, "session3_right": 422.3,
}
# the paper (Sochor et al. 2017, Tables 4 and 6) on the real BrnoCompSpeed videos; it reports the 99th percentile
PAPER = {"auto": {"mean": 1.10, "median": 0.97, "p99": 3.05, "recall": 0.863, "ratio": 0.09},
         "manual": {"mean": 1.35, "median": 0.95, "p99": 4.84}}


@dataclass
class Scene:
    name: str
    kind: str  # "synth" | "replay"
    folder: Path  # video.mp4, gt_data.pkl, calibration.json (true / rendering camera)


@dataclass
class Row:
    scene: str
    kind: str
    mode: str
    frames: int = 0
    seconds: float = 0.0  # of video
    wall_s: float = 0.0
    cpu_s: float = 0.0
    state: str = ""  # the calibration the run ended with: state (source)
    has_vps: bool = False
    has_scale: bool = False
    ratio_err: float | None = None  # mean relative distance-ratio error of the run's calibration (gt segments)
    ratio_err_scene: float | None = None  # same, the segments' lengths as the scene's camera measures them
    reference_ratio_err: float | None = None  # same for the scene's true / rendering camera
    scale_err_pct: float | None = None  # λ / λ_scene − 1
    road_err_pct: float | None = None  # the VPs alone: road distances at λ_scene (vp1_constant_speed.vp_road_error)
    vehicles: int = 0
    measured: int = 0
    rendered: int | None = None  # vehicles that passed, from the scene's frames.jsonl (passing_vehicles)
    unmeasured: dict[str, int] = field(default_factory=dict)
    errors_kmh: list[float] = field(default_factory=list)  # matched valid cars
    truth_errors_kmh: list[float] = field(default_factory=list)  # signed, every measured vehicle vs the rendering
    classes: list[tuple[str, str]] = field(default_factory=list)  # (rendered class, reported label) of the same
    dims_log_ratio: list[list[float]] = field(default_factory=list)  # log(reported / rendered length, width, height)
    recall: float | None = None
    false_positives: int | None = None
    matched_valid: int = 0
    gt_valid: int = 0
    failure: str = ""
    warnings: list[str] = field(default_factory=list)  # the run's warnings (e.g. why bbscale found no scale)

    def stat(self, what: str) -> float | None:
        return _stat(np.asarray(self.errors_kmh), what)


def _stat(e: np.ndarray, what: str) -> float | None:
    if not e.size:
        return None
    return float({"mean": np.mean, "median": np.median}.get(what, lambda x: np.percentile(x, float(what[1:])))(e))


# --------------------------------------------------------------------------- scenes


def _run(cmd: list, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([str(c) for c in cmd], capture_output=True, text=True, **kw)


def synth_scene(preset: str, syn_work: Path, duration: float) -> Scene:
    out = syn_work / preset
    if not (out / "video.mp4").is_file() or not (out / "gt_data.pkl").is_file():
        proc = _run([*TRAFFICCAL, "synth", "--preset", preset, "--duration", duration, "--out", out,
                     "--no-progress"])
        if proc.returncode:
            raise SystemExit(f"rendering {preset} failed: {proc.stderr[-800:]}")
    return Scene(preset, "synth", out)


def replay_scene(name: str, replays: Path, work: Path) -> Scene | None:
    """The lead's render in ``replays`` when complete, else rendered into ``work/replays`` (same recipe)."""
    for folder in (replays / name, work / "replays" / name):
        if (folder / "video.mp4").is_file() and (folder / "gt_data.pkl").is_file():
            return Scene(name, "replay", folder)
    gt = BRNO / name / "gt_data.pkl"
    if not gt.is_file():
        print(f"skipping {name}: {gt} is absent", file=sys.stderr)
        return None
    out = work / "replays" / name
    cfg = work / "replays" / "cfg"
    cfg.mkdir(parents=True, exist_ok=True)
    proc = _run([*TRAFFICCAL, "calibrate-manual", "--gt", gt, "-o", cfg / f"cal_{name}.json"])
    if proc.returncode:
        raise SystemExit(f"calibrate-manual {name} failed: {proc.stderr[-800:]}")
    duration = 120 if name.startswith("session3") else 60  # session 3 is sparse
    (cfg / f"{name}.yaml").write_text(
        f"duration: {duration}\nimaging: {{fps: 25}}\nlighting: {{preset: overcast}}\nreplay:\n"
        f"  gt_data: {gt}\n  calibration: cal_{name}.json\n  start: {REPLAY_STARTS[name]}\n")
    tmp = out.with_name(name + ".tmp")
    proc = _run([*TRAFFICCAL, "synth", "--scenario", cfg / f"{name}.yaml", "--out", tmp, "--no-progress"])
    if proc.returncode:
        raise SystemExit(f"rendering replay {name} failed: {proc.stderr[-800:]}")
    tmp.rename(out)
    return Scene(name, "replay", out)


# --------------------------------------------------------------------------- one run


def timed(cmd: list, env: dict | None = None) -> tuple[int, str, float, float]:
    """(return code, output (stdout and stderr), wall seconds, CPU seconds user+system of the process and its
    children)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([str(c) for c in cmd], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env)
    out = proc.stdout.read().decode("utf-8", "replace")
    _, status, usage = os.wait4(proc.pid, 0)
    proc.stdout.close()
    return os.waitstatus_to_exitcode(status), out, time.perf_counter() - t0, usage.ru_utime + usage.ru_stime


def frame_count(video: Path) -> int:
    import cv2

    cap = cv2.VideoCapture(str(video))
    try:
        return int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    finally:
        cap.release()


MODES = ("auto", "auto-reg", "manual")


def loo_regressions(rows: list[Row], scenes: list[Scene], work: Path, form: str = "ratio") -> dict[str, Path]:
    """Per scene, the regression λ_reg = αλ* + β fitted on the other scenes of its group whose ``auto`` run found
    a scale (their λ* against the scene camera's λ), written to ``work/<scene>/auto-reg/regression.json``."""
    from gst_trafficcal.calibration import load_calibration
    from gst_trafficcal.scale.regression import leave_one_out, save_regression

    pairs = {}
    for r in rows:
        cal_file = work / r.scene / "auto" / "calibration.json"
        if r.mode == "auto" and r.has_scale and cal_file.is_file():
            pairs[r.scene] = load_calibration(cal_file).camera.scale
    true = [load_calibration(sc.folder / "calibration.json").camera.scale for sc in scenes]
    regs = leave_one_out([pairs.get(sc.name) for sc in scenes], true, [sc.name for sc in scenes],
                         groups=[sc.kind for sc in scenes], form=form)
    out = {}
    for sc, reg in zip(scenes, regs):
        if reg is None:
            continue
        path = work / sc.name / "auto-reg" / "regression.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        save_regression(reg, path)
        out[sc.name] = path
    return out


def run_scene(scene: Scene, mode: str, work: Path, fresh: bool = False, detector: str = "",
              regression: Path | None = None) -> Row:
    """``trafficcal run`` on one scene in one mode (unless an earlier run's outputs are there and not ``fresh``:
    its ``run.json`` keeps the timing), scored against the scene's gt_data.pkl; ``detector``: ``--detector`` of
    ``trafficcal run`` (vehicleseg, background, an ONNX file; empty: run's default, vehicleseg)."""
    from gst_trafficcal.brnocompspeed import load_gt_data, load_results
    from gst_trafficcal.calibration import load_calibration
    from gst_trafficcal.errors import InputError
    from gst_trafficcal.evaluation import evaluate_calibration, evaluate_speeds, prepare_tracks
    from gst_trafficcal.outputs import read_events

    out = work / scene.name / mode
    out.mkdir(parents=True, exist_ok=True)
    row = Row(scene.name, scene.kind, mode, frames=frame_count(scene.folder / "video.mp4"))
    reference = load_calibration(scene.folder / "calibration.json")
    size = reference.image_size
    done = out / "run.json"
    if fresh or not done.is_file():
        done.unlink(missing_ok=True)
        cmd = [*TRAFFICCAL, "run", scene.folder / "video.mp4", "--out", out, "--no-overlay",
               *(["--detector", detector] if detector else [])]
        if mode == "manual":
            cal_path = out.parent / "manual_calibration.json"
            proc = _run([*TRAFFICCAL, "calibrate-manual", "--gt", scene.folder / "gt_data.pkl", "--image-size",
                         f"{size[0]}x{size[1]}", "-o", cal_path])
            if proc.returncode:
                row.failure = f"calibrate-manual: {proc.stderr.strip().splitlines()[-1:]}"
                return row
            cmd += ["--calibration", cal_path]
        if regression is not None:
            cmd += ["--scale-regression", regression]
        rc, err, wall, cpu = timed(cmd, env=dict(os.environ, COLUMNS="1000"))  # warnings on one line each
        failure = "" if not rc else (" ".join(ln for ln in err.splitlines() if ln.startswith("trafficcal:"))[-400:]
                                     or err[-400:])
        warnings = [ln.strip() for ln in err.splitlines() if "warning" in ln.lower() and "floating" not in ln]
        done.write_text(json.dumps({"wall_s": wall, "cpu_s": cpu, "failure": failure, "warnings": warnings}) + "\n")
    timing = json.loads(done.read_text())
    row.wall_s, row.cpu_s, row.failure = timing["wall_s"], timing["cpu_s"], timing["failure"]
    row.warnings = timing.get("warnings", [])
    gt = load_gt_data(scene.folder / "gt_data.pkl")
    row.gt_valid = sum(c.valid for c in gt.cars)
    row.seconds = row.frames / gt.fps
    row.reference_ratio_err = evaluate_calibration(gt, reference.camera).ratio_rel_pct.mean / 100
    try:
        events = read_events(out / "vehicles.jsonl").events
    except InputError:
        events = []
    row.vehicles, row.measured = len(events), sum(e.measured for e in events)
    row.rendered = passing_vehicles(scene.folder / "frames.jsonl", size)
    row.unmeasured = dict(Counter(e.reason for e in events if not e.measured).most_common())
    cal_file = out / "calibration.json"
    cal = load_calibration(cal_file) if cal_file.is_file() else None
    if cal is None:
        row.state = "none"
        return row
    row.state = f"{cal.state} ({cal.source})"
    cam = cal.camera
    row.has_vps = cam is not None
    row.has_scale = cam is not None and cam.scale is not None
    if cam is None:
        return row
    row.ratio_err = evaluate_calibration(gt, cam).ratio_rel_pct.mean / 100
    row.ratio_err_scene = evaluate_calibration(as_measured_by(gt, reference.camera), cam).ratio_rel_pct.mean / 100
    from vp1_constant_speed import vp_road_error

    row.road_err_pct = vp_road_error(scene.folder, cam, reference.camera.scale)
    if not row.has_scale or not (out / "system.json").is_file():
        return row
    if reference.camera.scale:
        row.scale_err_pct = 100 * (cam.scale / reference.camera.scale - 1)
    prepared = prepare_tracks(load_results(out / "system.json"), gt, width=size[0], height=size[1])
    matches = truth_matches(scene.folder / "frames.jsonl", events, out / "system.json", size)
    row.truth_errors_kmh = [m.speed_error_kmh for m in matches]
    row.classes = [(m.rendered_class, m.label) for m in matches]
    row.dims_log_ratio = [np.log(np.divide(m.size, m.rendered_size)).tolist() for m in matches if m.size is not None]
    sp = evaluate_speeds(gt, prepared, cam)
    row.errors_kmh = [float(v) for v in sp.errors_abs_kmh]
    row.recall, row.false_positives, row.matched_valid = sp.recall, sp.false_positives, sp.matched_valid
    return row


def scene_fps(scene: Path) -> float:
    """The scene's frame rate: its gt_data.pkl's (as the scores here take it), else its scenario.json's
    imaging.fps, else 25 (the renderer's default; said on stderr, since frame numbers then rest on it)."""
    from gst_trafficcal.brnocompspeed import load_gt_data

    if (scene / "gt_data.pkl").is_file():
        return float(load_gt_data(scene / "gt_data.pkl").fps)
    try:
        return float(json.loads((scene / "scenario.json").read_text())["imaging"]["fps"])
    except (OSError, ValueError, KeyError, TypeError):
        print(f"{scene}: no gt_data.pkl and no imaging.fps in scenario.json: taking 25 fps", file=sys.stderr)
        return 25.0


def rule_frames(frames_jsonl: Path, size: tuple[int, int], min_area: float = 0.0015) -> Counter | None:
    """Per rendered vehicle (:func:`vehicle_key`), the frames it is seen at least half visible and at least as large
    as the detectors' smallest vehicle (``min_area`` of the image); None without a frames.jsonl."""
    if not frames_jsonl.is_file():
        return None
    frames: Counter = Counter()
    least = min_area * size[0] * size[1]
    with frames_jsonl.open() as f:
        for line in f:
            r = json.loads(line)
            x0, y0, x1, y1 = r["box"]
            if r.get("visible", 1.0) >= 0.5 and (x1 - x0) * (y1 - y0) >= least:
                frames[vehicle_key(r)] += 1
    return frames


def passing_vehicles(frames_jsonl: Path, size: tuple[int, int], min_frames: int = 10,
                     min_area: float = 0.0015) -> int | None:
    """How many rendered vehicles a traffic count of the video should hold: those seen as :func:`rule_frames` says
    in ``min_frames`` frames or more (session0_center's reused ids make 23 vehicles there, not 20); None without a
    frames.jsonl."""
    frames = rule_frames(frames_jsonl, size, min_area)
    return None if frames is None else sum(n >= min_frames for n in frames.values())


def as_measured_by(gt, camera):
    """``gt`` with each segment's length as ``camera`` measures it: on replays the segments are the recording's
    real measurements, which even the rendering camera misses by ~0.025 in distance ratio; against these the
    error is the one towards the camera that rendered the video."""
    from dataclasses import replace

    plane = camera.plane_distance(gt.distances_p1, gt.distances_p2)
    return replace(gt, distances=tuple(replace(d, distance=float(v)) for d, v in zip(gt.distances, plane)))


def truth_matches(frames_jsonl: Path, events: list, results_json: Path, size: tuple[int, int]) -> list:
    """Every measured vehicle against the rendered vehicle its reference points follow
    (:func:`gst_trafficcal.synth.truth_match.match_measured`'s ``TruthMatch`` records: speed error, class, size),
    not only those BrnoCompSpeed's matching keeps — a car must be tracked between its measurement lines, which on
    the synth presets lie far down the road; the results file is not read without a frames.jsonl."""
    from gst_trafficcal.brnocompspeed import load_results
    from gst_trafficcal.synth.truth_match import match_measured

    if not frames_jsonl.is_file():
        return []
    return match_measured(frames_jsonl, events, load_results(results_json), size)


# --------------------------------------------------------------------------- tables


def _f(v, fmt: str = ".2f") -> str:
    return "–" if v is None or v != v else format(v, fmt)


def _why(warnings: list[str], element: str) -> str:
    """``; element: <its last warning>`` (why a stage did not converge), or nothing."""
    said = [w.split(f"{element}: ", 1)[1] for w in warnings if f"{element}0: {element}: " in w]
    return f"; {element}: {said[-1][:200]}" if said else ""


def scene_table(rows: list[Row]) -> str:
    lines = ["| scene | mode | calibration | ratio err vs segments / vs scene camera (scene camera's) | λ err % | "
             "road err % at true λ | vehicles (measured) / rendered | mean / median / p95 km/h | recall | FP | "
             "every measured vehicle: n, mean / p95 km/h (signed mean) | fps wall / CPU |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if r.failure and not r.vehicles:
            cal = f"run failed: {r.failure}"
        elif not r.has_vps:
            cal = "no VPs: " + r.state + _why(r.warnings, "vpdetect")
        elif not r.has_scale:
            cal = "no scale: " + r.state + _why(r.warnings, "bbscale")
        else:
            cal = r.state
        lines.append(
            f"| {r.scene} | {r.mode} | {cal} | {_f(r.ratio_err, '.3f')} / {_f(r.ratio_err_scene, '.3f')} "
            f"({_f(r.reference_ratio_err, '.3f')}) | "
            f"{_f(r.scale_err_pct, '+.1f')} | {_f(r.road_err_pct, '+.1f')} | {r.vehicles} ({r.measured}) / "
            f"{_f(r.rendered, 'd')} | "
            f"{_f(r.stat('mean'))} / "
            f"{_f(r.stat('median'))} / {_f(r.stat('p95'))} | {_f(r.recall, '.3f')} "
            f"({r.matched_valid}/{r.gt_valid}) | {_f(r.false_positives, 'd')} | {len(r.truth_errors_kmh)}, "
            f"{_f(_stat(np.abs(r.truth_errors_kmh), 'mean'))} / {_f(_stat(np.abs(r.truth_errors_kmh), 'p95'))} "
            f"({_f(_stat(np.asarray(r.truth_errors_kmh), 'mean'), '+.2f')}) | "
            f"{_f(r.frames / r.wall_s if r.wall_s else None, '.1f')} / {_f(r.frames / r.cpu_s if r.cpu_s else None, '.1f')} |")
    return "\n".join(lines)


def pooled(rows: list[Row]) -> dict:
    """Over all scenes of a group: errors pooled over matched cars; recall counts scenes without a scale as
    missing every car; fps over all frames."""
    e = np.concatenate([np.asarray(r.errors_kmh) for r in rows]) if rows else np.zeros(0)
    te = np.abs(np.concatenate([np.asarray(r.truth_errors_kmh) for r in rows])) if rows else np.zeros(0)
    gt_valid = sum(r.gt_valid for r in rows)
    conv = [r for r in rows if r.has_scale]
    frames = sum(r.frames for r in rows)
    ratios = [r.ratio_err for r in rows if r.ratio_err is not None]
    return {"scenes": len(rows), "with_scale": len(conv), "with_vps": sum(r.has_vps for r in rows),
            "cars": int(e.size), **{k: _stat(e, k) for k in ("mean", "median", "p95", "p99")},
            "truth": {"vehicles": int(te.size), **{k: _stat(te, k) for k in ("mean", "median", "p95")}},
            "class_accuracy": _class_accuracy([p for r in rows for p in r.classes]),
            "dimensions": _dimension_errors([d for r in rows for d in r.dims_log_ratio]),
            "recall": sum(r.matched_valid for r in rows) / gt_valid if gt_valid else None,
            "recall_converged": (sum(r.matched_valid for r in conv) / max(1, sum(r.gt_valid for r in conv))
                                 if conv else None),
            "false_positives": sum(r.false_positives or 0 for r in rows),
            "fp_per_min": (sum(r.false_positives or 0 for r in conv) / (sum(r.seconds for r in conv) / 60)
                           if conv and sum(r.seconds for r in conv) else None),
            "ratio_err_mean": float(np.mean(ratios)) if ratios else None,
            "scale_err_mean_abs_pct": _mean_abs([r.scale_err_pct for r in rows]),
            "road_err_mean_abs_pct": _mean_abs([r.road_err_pct for r in rows]),
            "fps_wall": frames / sum(r.wall_s for r in rows) if rows and sum(r.wall_s for r in rows) else None,
            "fps_cpu": frames / sum(r.cpu_s for r in rows) if rows and sum(r.cpu_s for r in rows) else None}


def _class_accuracy(pairs: list[tuple[str, str]]) -> float | None:
    return sum(t == label for t, label in pairs) / len(pairs) if pairs else None


def _dimension_errors(log_ratios: list[list[float]]) -> dict | None:
    """Median and robust spread (1.4826 MAD) of log(reported / rendered) length, width and height."""
    if not log_ratios:
        return None
    d = np.asarray(log_ratios, np.float64)
    med = np.median(d, axis=0)
    return {"vehicles": len(d), "median": med.round(3).tolist(),
            "robust_std": (1.4826 * np.median(np.abs(d - med), axis=0)).round(3).tolist()}


def _mean_abs(values: list) -> float | None:
    v = [abs(x) for x in values if x is not None]
    return float(np.mean(v)) if v else None


CLASSES = ("car", "van", "bus", "truck", "motorcycle")


def class_table(rows: list[Row]) -> str:
    """Per group (synth/replay, mode): the labels of the measured vehicles against the rendered vehicles' classes
    (right / rendered per class, the wrong labels in brackets)."""
    notes = []
    lines = ["| scenes | mode | vehicles | labelled right | " + " | ".join(CLASSES) + " |",
             "|---|---|---|---|" + "---|" * len(CLASSES)]
    for kind in ("synth", "replay"):
        for mode in MODES:
            pairs = [p for r in rows if r.kind == kind and r.mode == mode for p in r.classes]
            if not pairs:
                continue
            cells = []
            for c in CLASSES:
                got = Counter(label for true, label in pairs if true == c)
                wrong = ", ".join(f"{k} {n}" for k, n in got.most_common() if k != c)
                cells.append(f"{got[c]}/{sum(got.values())}" + (f" ({wrong})" if wrong else "") if got else "–")
            lines.append(f"| {kind} ({sum(r.kind == kind and r.mode == mode for r in rows)}) | {mode} | {len(pairs)} | "
                         f"{_class_accuracy(pairs):.3f} | " + " | ".join(cells) + " |")
            dims = _dimension_errors([d for r in rows if r.kind == kind and r.mode == mode for d in r.dims_log_ratio])
            if dims:
                notes.append(f"{kind}, {mode}: {dims['vehicles']} vehicles, log(reported / rendered) length, width, "
                             f"height median {dims['median']}, robust spread {dims['robust_std']}")
    return "\n".join(lines) + ("\n\nMeasured dimensions: " + "; ".join(notes) + "." if notes else "")


def unmeasured_table(rows: list[Row]) -> str:
    """Per group (synth/replay, mode): the vehicles reported without a speed, by reason."""
    from gst_trafficcal.outputs import reason_kind

    lines = ["| scenes | mode | vehicles | measured | unmeasured, by reason |", "|---|---|---|---|---|"]
    for kind in ("synth", "replay"):
        for mode in MODES:
            sel = [r for r in rows if r.kind == kind and r.mode == mode]
            if not sel:
                continue
            reasons = Counter()
            for r in sel:
                for reason, n in r.unmeasured.items():
                    reasons[reason_kind(reason)] += n
            lines.append(f"| {kind} ({len(sel)}) | {mode} | {sum(r.vehicles for r in sel)} | "
                         f"{sum(r.measured for r in sel)} | "
                         + "; ".join(f"{k}: {n}" for k, n in reasons.most_common()) + " |")
    return "\n".join(lines)


def count_table(rows: list[Row]) -> str:
    """Per group: the traffic count (every vehicle reported, what intervals.csv and the report count) against the
    rendered vehicles that passed (:func:`passing_vehicles`): in total, and the scenes' count errors."""
    lines = ["| scenes | mode | reported | rendered | total error | per scene: mean \\|error\\| (worst) |",
             "|---|---|---|---|---|---|"]
    for kind in ("synth", "replay"):
        for mode in MODES:
            sel = [r for r in rows if r.kind == kind and r.mode == mode and r.rendered]
            if not sel:
                continue
            reported, rendered = sum(r.vehicles for r in sel), sum(r.rendered for r in sel)
            rel = [(r.vehicles - r.rendered) / r.rendered for r in sel]
            worst = max(zip(rel, sel), key=lambda x: abs(x[0]))
            lines.append(f"| {kind} ({len(sel)}) | {mode} | {reported} | {rendered} | "
                         f"{100 * (reported - rendered) / rendered:+.1f} % | {100 * np.mean(np.abs(rel)):.1f} % "
                         f"({worst[1].scene} {100 * worst[0]:+.0f} %) |")
    return "\n".join(lines)


def summary_table(rows: list[Row]) -> tuple[str, dict]:
    lines = ["| scenes | mode | with VPs / scale | cars | mean | median | p95 | p99 km/h | recall (converged) | FP | "
             "ratio err | every measured vehicle: n, mean / p95 km/h | fps wall / CPU |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    out = {}
    for kind in ("synth", "replay"):
        for mode in MODES:
            sel = [r for r in rows if r.kind == kind and r.mode == mode]
            if not sel:
                continue
            p = out[f"{kind}/{mode}"] = pooled(sel)
            lines.append(f"| {kind} ({p['scenes']}) | {mode} | {p['with_vps']} / {p['with_scale']} | {p['cars']} | "
                         f"{_f(p['mean'])} | {_f(p['median'])} | {_f(p['p95'])} | {_f(p['p99'])} | "
                         f"{_f(p['recall'], '.3f')} ({_f(p['recall_converged'], '.3f')}) | {p['false_positives']} "
                         f"({_f(p['fp_per_min'], '.2f')}/min) | "
                         f"{_f(p['ratio_err_mean'], '.3f')} | {p['truth']['vehicles']}, {_f(p['truth']['mean'])} / "
                         f"{_f(p['truth']['p95'])} | {_f(p['fps_wall'], '.1f')} / {_f(p['fps_cpu'], '.1f')} |")
    a, m = PAPER["auto"], PAPER["manual"]
    lines.append(f"| paper, real BrnoCompSpeed | auto (EdgeLetsCalib + BBScaleReg) | | | {a['mean']:.2f} | "
                 f"{a['median']:.2f} | – | {a['p99']:.2f} | {a['recall']:.3f} | 1.91/min | {a['ratio']:.2f} | | |")
    lines.append(f"| paper, real BrnoCompSpeed | manual (ManualCalib + ManualScale) | | | {m['mean']:.2f} | "
                 f"{m['median']:.2f} | – | {m['p99']:.2f} | | | | | |")
    return "\n".join(lines), out


# --------------------------------------------------------------------------- throughput


def throughput(video: Path, work: Path, detector: str = "") -> dict:
    """Decode-only and product-chain fps on ``video``, each a gst-launch-1.0 process in this invocation
    (``detector``: ``trafficcal run --detector``; empty: its default, vehicleseg)."""
    from gst_trafficcal.cli.run import DEFAULT_DETECTOR, RunPaths, pipeline_description, quote
    from gst_trafficcal.gst.env import elements_dir, gst_environment

    env = dict(os.environ, **gst_environment())
    frames = frame_count(video)
    out = work / "throughput"
    out.mkdir(parents=True, exist_ok=True)
    src = f"filesrc location={quote(video)} ! decodebin"
    bbscale = (elements_dir() / "python" / "bbscale.py").exists()
    detector = detector or DEFAULT_DETECTOR
    pipelines = {
        "decode": f"{src} ! fakesink",
        "decode+videoconvert": f"{src} ! videoconvert ! video/x-raw,format=I420 ! fakesink",
        "chain, one thread": pipeline_description(video, RunPaths(out), detector=detector, overlay=False,
                                                  bbscale=bbscale, queues=False),
        "chain": pipeline_description(video, RunPaths(out), detector=detector, overlay=False,
                                      bbscale=bbscale),
        # what `trafficcal run` does by default: the chain plus trafficoverlay and H.264 encoding of overlay.mp4
        "chain + overlay": pipeline_description(video, RunPaths(out), detector=detector, overlay=True,
                                                bbscale=bbscale),
    }
    res = {"video": str(video), "frames": frames, "pipelines": {}}
    for name, desc in pipelines.items():
        rc, err, wall, cpu = timed(["gst-launch-1.0", "-q", *_split(desc)], env=env)
        if rc:
            raise SystemExit(f"{name} failed: {err[-1500:]}")
        res["pipelines"][name] = {"description": desc, "wall_s": wall, "cpu_s": cpu, "fps_wall": frames / wall,
                                  "fps_cpu": frames / cpu}
        print(f"{name:20s} {frames / wall:7.1f} fps wall ({wall:.1f} s)  {frames / cpu:7.1f} fps per CPU-second "
              f"({cpu:.1f} s CPU)", flush=True)
    p = res["pipelines"]
    res["ratio_wall"] = p["chain"]["fps_wall"] / p["decode+videoconvert"]["fps_wall"]
    res["ratio_cpu"] = p["chain"]["fps_cpu"] / p["decode+videoconvert"]["fps_cpu"]
    print(f"chain / decode+videoconvert: {res['ratio_wall']:.3f} wall, {res['ratio_cpu']:.3f} CPU; "
          f"target: >= 25 fps end to end ({'met' if p['chain']['fps_wall'] >= 25 else 'not met'} "
          f"at {p['chain']['fps_wall']:.1f} fps wall)")
    return res


def _git_head() -> str:
    proc = _run(["git", "-C", ROOT, "rev-parse", "--short", "HEAD"])
    dirty = _run(["git", "-C", ROOT, "status", "--porcelain", "--untracked-files=no"]).stdout.strip()
    return proc.stdout.strip() + (" with uncommitted changes in the tree" if dirty else "")


def _split(desc: str) -> list[str]:
    return shlex.split(desc)


# --------------------------------------------------------------------------- main


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=Path("/tmp/e2e_bench"), help="run outputs (and replays rendered here)")
    ap.add_argument("--syn-work", type=Path, default=Path("/tmp/syn"), help="synth renders, one folder per preset")
    ap.add_argument("--replays", type=Path, default=Path("/tmp/replays"), help="pre-rendered replays, if any")
    ap.add_argument("--synth", default=SYNTH_PRESETS, help="comma-separated presets ('' for none)")
    ap.add_argument("--scene", type=Path, action="append", default=[],
                    help="an extra rendered synth folder (video.mp4, gt_data.pkl, calibration.json), e.g. the "
                         "demo's out/demo/scene; repeatable")
    ap.add_argument("--duration", type=float, default=60.0, help="seconds of a synth render made here")
    ap.add_argument("--replay", default="all", help="comma-separated session<S>_<view> names, 'all' or ''")
    ap.add_argument("--modes", default="auto,manual")
    ap.add_argument("--jobs", type=int, default=1, help="scenes run at the same time")
    ap.add_argument("--fresh", action="store_true", help="re-run scenes already run into --work (default: re-score their outputs)")
    ap.add_argument("--json", type=Path, default=None, help="write every row and the pooled figures here")
    ap.add_argument("--write", type=Path, default=None, help="also write the tables as markdown here, e.g. "
                    "docs/results/end_to_end.md")
    ap.add_argument("--regression-form", choices=("ratio", "affine"), default="ratio",
                    help="auto-reg's regression form (trafficcal fit-scale --form)")
    ap.add_argument("--detector", default="", help="trafficcal run --detector: vehicleseg (run's default, also when "
                    "empty), background (the built-in background subtraction, MOG2), an ONNX file; use a --work of "
                    "its own per detector")
    ap.add_argument("--throughput", type=Path, default=None, metavar="VIDEO",
                    help="only measure decode-only vs chain fps on this video")
    a = ap.parse_args()
    a.work.mkdir(parents=True, exist_ok=True)
    if a.throughput is not None:
        res = throughput(a.throughput, a.work, a.detector)
        if a.json:
            a.json.write_text(json.dumps(res, indent=2) + "\n")
        return
    scenes = [synth_scene(p, a.syn_work, a.duration) for p in a.synth.split(",") if p]
    scenes += [Scene(f"{d.parent.name}/{d.name}", "synth", d) for d in a.scene]
    names = list(REPLAY_STARTS) if a.replay == "all" else [n for n in a.replay.split(",") if n]
    scenes += [s for s in (replay_scene(n, a.replays, a.work) for n in names) if s is not None]
    modes = [m for m in a.modes.split(",") if m]
    bad = [m for m in modes if m not in MODES]
    if bad or ("auto-reg" in modes and "auto" not in modes):
        raise SystemExit(f"--modes: {', '.join(MODES)} (auto-reg needs auto), got {a.modes!r}")
    rows = []

    def run_all(jobs, regressions=None):
        with ProcessPoolExecutor(a.jobs) as pool:
            regs = [None if regressions is None else regressions.get(scene.name) for scene, _ in jobs]
            for row in pool.map(run_scene, *zip(*jobs), [a.work] * len(jobs), [a.fresh] * len(jobs),
                                [a.detector] * len(jobs), regs):
                rows.append(row)
                print(f"{row.scene} {row.mode}: {row.vehicles} vehicles, {row.measured} measured, mean error "
                      f"{_f(row.stat('mean'))} km/h, recall {_f(row.recall, '.3f')}, calibration {row.state}"
                      f"{', ' + row.failure if row.failure else ''}", flush=True)
                if a.json:  # partial results survive an interrupted run
                    a.json.write_text(json.dumps({"rows": [asdict(r) for r in rows]}, indent=2, default=str) + "\n")

    run_all([(scene, mode) for scene in scenes for mode in modes if mode != "auto-reg"])
    if "auto-reg" in modes:  # leave-one-out regressions from the automatic runs, then the runs with them
        regressions = loo_regressions(rows, scenes, a.work, a.regression_form)
        jobs = [(scene, "auto-reg") for scene in scenes if scene.name in regressions]
        if jobs:
            run_all(jobs, regressions)
    per_scene = scene_table(rows)
    table, pooled_figs = summary_table(rows)
    reasons = unmeasured_table(rows)
    classes = class_table(rows)
    counts = count_table(rows)
    print(per_scene + "\n\n" + table + "\n\n" + counts + "\n\n" + reasons + "\n\n" + classes)
    if a.write:
        cmd = shlex.join(["benchmarks/end_to_end.py", *sys.argv[1:]])
        a.write.parent.mkdir(parents=True, exist_ok=True)
        a.write.write_text(
            "# End to end: `trafficcal run` on synthetic scenes and BrnoCompSpeed replays\n\n"
            f"Command: `nice -n 10 .venv/bin/python {cmd}` (git {_git_head()}). Per scene and mode the product ran "
            "once (`trafficcal run VIDEO --no-overlay`; manual: `--calibration` from `trafficcal calibrate-manual`); "
            "speed errors are BrnoCompSpeed's (matched valid cars, median mode, `gst_trafficcal.evaluation` as "
            "`trafficcal eval`); 'every measured vehicle' scores each measured vehicle against the rendered vehicle "
            "its reference points follow (frames.jsonl). Distance-ratio error: mean relative, against the "
            "ground-truth segments / against the same segments as the scene's camera measures them (in brackets: "
            "the scene camera's own error against the segments; on replays the recording's real measurements). "
            "λ err: scale against the scene camera's. road err at true λ: how much the run's vanishing points alone "
            "stretch the road — the distances the rendered vehicles' reference points travel in five frames, measured "
            "with the run's VPs and the scene camera's λ, against the renderer's (median); the speeds are off by "
            "about (1 + λ err)(1 + road err) − 1. fps: wall clock on the shared machine / per CPU-second. "
            "Recall in the pooled table counts the cars of scenes without a scale as missed (in brackets: over "
            "scenes with a scale only); the paper reports the 99th percentile, not the 95th.\n\n"
            "## Per scene\n\n" + per_scene + "\n\n## Pooled\n\n" + table + "\n\n## Traffic counts\n\n"
            "The vehicles the product reported (`vehicles.jsonl`: what intervals.csv, the report and the overlay "
            "count) against the rendered vehicles that passed: those seen at least half visible and as large as "
            "the detectors' smallest vehicle (0.15 % of the image) in 10 frames or more (the scene's frames.jsonl; "
            "`passing_vehicles`).\n\n" + counts + "\n\n## Vehicles without a speed\n\n"
            "Every vehicle the product counted is reported; these got no speed, with the reason it gives (a "
            "vehicle whose reference points do not follow one vehicle, whose speed samples disagree or that was "
            "seen too briefly is not published with a guessed speed, and is not in the BrnoCompSpeed results "
            "file).\n\n"
            + reasons + "\n\n## Vehicle classes\n\nThe label each measured vehicle is reported with (with the default "
            "detector, which calls every vehicle a car: the class its measured 3D boxes give, `vehicles.classify`) "
            "against the class of the rendered vehicle its reference points follow (as 'every measured vehicle'); "
            "per rendered class: labelled right / measured, the other labels given in brackets.\n\n" + classes + "\n")
    if a.json:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps({"command": shlex.join(sys.argv), "rows": [asdict(r) for r in rows],
                                      "git": _git_head(), "pooled": pooled_figs, "paper": PAPER}, indent=2, default=str) + "\n")


if __name__ == "__main__":
    main()
