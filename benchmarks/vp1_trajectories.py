"""VP1 from whole vehicle trajectories against the calibrator's VP1 from KLT corner tracks.

For each rendered scene (a synth preset or a BrnoCompSpeed replay: a folder with video.mp4, calibration.json,
gt_data.pkl): the calibrator's vanishing points (vpdetect's, from ``calibrate_video``, or an earlier
``benchmarks/end_to_end.py`` run's ``<scene>/auto/calibration.json`` with ``--e2e``), then vehicleseg and the
tracker over the whole clip with that camera, and VP1 as the intersection of the vehicles' reference-point
trajectories (:mod:`gst_trafficcal.vanishing.trajectories`), alone and — when the calibrator runs here — as extra votes in its
own VP1 accumulator (``--share`` of its weight).  Reported per scene: VP1's error (degrees on the viewing sphere)
and the distance-ratio error of the calibration (against the segments as the scene's own camera measures them: the
error towards the rendering camera), with the calibrator's VP1 and with the trajectories' (VP2 and the principal
point kept).  ``--speeds WORK`` also runs ``trafficcal run --calibration`` with each (bbscale
finds λ; the votes' VP1 too when the calibrator runs here) and reports the mean absolute speed error from its
evaluation.

    .venv/bin/python benchmarks/vp1_trajectories.py /tmp/replays_cat/session* --e2e /tmp/e2e [--speeds /tmp/vp1spd]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gst_trafficcal.brnocompspeed import load_gt_data  # noqa: E402
from gst_trafficcal.calibration import Calibration, load_calibration, save_calibration  # noqa: E402
from gst_trafficcal.diamond import angle_between  # noqa: E402
from gst_trafficcal.errors import GeometryError  # noqa: E402
from gst_trafficcal.evaluation import evaluate_calibration  # noqa: E402
from gst_trafficcal.geometry import Camera, homogeneous  # noqa: E402
from gst_trafficcal.vanishing.trajectories import vp1_from_trajectories, vp1_with_trajectory_votes  # noqa: E402

from comparison import before_after, dash  # noqa: E402  (benchmarks/comparison.py)

TRAFFICCAL = [sys.executable, "-m", "gst_trafficcal"]


@dataclass
class Row:
    scene: str
    lines: int = 0  # straight trajectories that voted
    inliers: int = 0
    vp1_klt_deg: float | None = None  # the calibrator's VP1 error
    vp1_traj_deg: float | None = None  # the trajectories' VP1 error
    ratio_klt: float | None = None  # distance-ratio error (mean) with the calibrator's VP1
    ratio_traj: float | None = None  # ... with the trajectories' VP1
    speed_klt: float | None = None  # mean absolute speed error (km/h), trafficcal run with the calibrator's VP1
    speed_traj: float | None = None
    vp1_votes_deg: float | None = None  # the calibrator's accumulator with the trajectories voted in
    ratio_votes: float | None = None
    speed_votes: float | None = None
    note: str = ""


def calibrator_camera(scene: Path, e2e: Path | None):
    """The fully automatic run's vanishing points: an end_to_end.py run's, else vpdetect's calibrator now; with
    the calibrator's VP1 accumulator in the second case (None in the first)."""
    if e2e is not None and (e2e / scene.name / "auto" / "calibration.json").is_file():
        return load_calibration(e2e / scene.name / "auto" / "calibration.json").camera, None
    from gst_trafficcal.vanishing.calibrator import calibrate_video

    res = calibrate_video(scene / "video.mp4")
    return res.calibration.camera, res.calibrator.ds1


def reference_trajectories(scene: Path, camera: Camera, detector: str = "vehicleseg") -> list[np.ndarray]:
    """Every track's reference points (pixels, NaN where a frame gave none) over the whole clip, tracked with
    ``camera``'s 3D boxes on ``detector``'s outlines."""
    from gst_trafficcal.detection.factory import create_detector, detect
    from gst_trafficcal.tracking.background import BackgroundModel
    from gst_trafficcal.tracking.pipeline import TrackingPipeline

    det = create_detector(detector)
    pipe = TrackingPipeline(background=BackgroundModel())
    pipe.set_camera(camera.with_scale(None))
    cap = cv2.VideoCapture(str(scene / "video.mp4"))
    if not cap.isOpened():
        raise SystemExit(f"{scene / 'video.mp4'}: cannot open")
    tracks = []
    while True:
        ok, bgr = cap.read()
        if not ok:
            break
        t = cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
        pipe.process(cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY), t, detect(det, bgr, t))
        tracks += pipe.tracker.pop_finished()
    cap.release()
    tracks += pipe.flush()
    return [tr.reference_points()[0] for tr in tracks]


def scene_segments(scene: Path):
    """The scene's gt_data.pkl with its segments as the scene's own camera measures them (the ratio errors are
    then those towards the rendering camera)."""
    from end_to_end import as_measured_by  # benchmarks/end_to_end.py

    return as_measured_by(load_gt_data(scene / "gt_data.pkl"), load_calibration(scene / "calibration.json").camera)


def ratio_error(segments, camera: Camera) -> float:
    """Mean distance-ratio error of ``camera`` over :func:`scene_segments`."""
    return evaluate_calibration(segments, camera).ratio_rel_pct.mean / 100


def mean_speed_error(scene: Path, camera: Camera, out: Path) -> float | None:
    """``trafficcal run`` with ``camera``'s vanishing points (no scale: bbscale finds it), scored on gt_data.pkl."""
    out.mkdir(parents=True, exist_ok=True)
    size = load_calibration(scene / "calibration.json").image_size
    cal = out / "vps.json"
    save_calibration(Calibration(camera.with_scale(None), size, state="vps", source="vpdetect"), cal)
    proc = subprocess.run([*TRAFFICCAL, "run", scene / "video.mp4", "--out", out / "run", "--calibration", cal,
                           "--gt", scene / "gt_data.pkl", "--no-overlay"], capture_output=True, text=True)
    report = out / "run" / "evaluation.json"
    if proc.returncode or not report.is_file():
        print(f"{scene.name}: trafficcal run failed: {proc.stderr.strip()[-300:]}", file=sys.stderr)
        return None
    speed = json.loads(report.read_text())["speed"]["abs_kmh"]
    return speed["mean"] if speed.get("n") else None


def evaluate(scene: Path, e2e: Path | None, speeds: Path | None, share: float = 0.25) -> Row:
    row = Row(scene.name)
    truth = load_calibration(scene / "calibration.json").camera
    auto, accumulator = calibrator_camera(scene, e2e)
    if auto is None:
        row.note = "the calibrator found no vanishing points"
        return row

    def vp_err(cam: Camera) -> float:
        return angle_between(homogeneous(cam.vp1), homogeneous(truth.vp1), truth.pp, truth.focal)

    segments = scene_segments(scene)
    row.vp1_klt_deg, row.ratio_klt = vp_err(auto), ratio_error(segments, auto)
    trajectories = reference_trajectories(scene, auto)
    peak = vp1_with_trajectory_votes(accumulator, trajectories, share) if accumulator is not None else None
    votes = None
    if peak is not None and peak.finite:
        try:
            votes = Camera(peak.xy, auto.vp2, auto.pp)
            row.vp1_votes_deg, row.ratio_votes = vp_err(votes), ratio_error(segments, votes)
        except GeometryError:
            pass
    if speeds is not None:
        row.speed_klt = mean_speed_error(scene, auto, speeds / scene.name / "klt")
        if votes is not None:
            row.speed_votes = mean_speed_error(scene, votes, speeds / scene.name / "votes")
    vp = vp1_from_trajectories(trajectories)
    if vp is None:
        row.note = "too few straight trajectories"
        return row
    row.lines, row.inliers = len(vp.lines), int(vp.inliers.sum())
    try:
        traj = Camera(vp.point, auto.vp2, auto.pp)
    except GeometryError as exc:
        row.note = f"no camera with the trajectories' VP1 ({exc})"
        return row
    row.vp1_traj_deg, row.ratio_traj = vp_err(traj), ratio_error(segments, traj)
    if speeds is not None:
        row.speed_traj = mean_speed_error(scene, traj, speeds / scene.name / "trajectories")
    return row


def _f(v, fmt: str = ".3f") -> str:
    return dash(v, fmt)


def table(rows: list[Row]) -> str:
    out = ["| scene | trajectories (inliers) | VP1 err, calibrator → trajectories | ratio err | mean speed err km/h "
           "| calibrator + trajectory votes: VP1 err, ratio err, speed err |", "|---|---|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r.scene} | {r.lines} ({r.inliers}) | {_f(r.vp1_klt_deg)}° → {_f(r.vp1_traj_deg)}° | "
                   f"{_f(r.ratio_klt)} → {_f(r.ratio_traj)} | {_f(r.speed_klt, '.2f')} → {_f(r.speed_traj, '.2f')} | "
                   f"{_f(r.vp1_votes_deg)}°, {_f(r.ratio_votes)}, {_f(r.speed_votes, '.2f')} |"
                   + (f" {r.note}" if r.note else ""))
    both = [r for r in rows if r.vp1_traj_deg is not None]
    if both:
        def summary(a: str, b: str, fmt: str) -> str:
            pairs = [(getattr(r, a), getattr(r, b)) for r in both if getattr(r, a) is not None
                     and getattr(r, b) is not None]
            if not pairs:
                return "–"
            x, y = np.array(pairs).T
            return before_after(x, y, fmt)
        out.append(f"| **{len(both)} scenes** | | {summary('vp1_klt_deg', 'vp1_traj_deg', '.3f')} | "
                   f"{summary('ratio_klt', 'ratio_traj', '.3f')} | {summary('speed_klt', 'speed_traj', '.2f')} | "
                   f"{summary('vp1_klt_deg', 'vp1_votes_deg', '.3f')}; {summary('ratio_klt', 'ratio_votes', '.3f')}; "
                   f"{summary('speed_klt', 'speed_votes', '.2f')} |")
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="+", type=Path, help="rendered scene folders (video.mp4, calibration.json, "
                                                         "gt_data.pkl)")
    ap.add_argument("--e2e", type=Path, help="an end_to_end.py --work folder: take each scene's fully automatic "
                                             "vanishing points from its auto/calibration.json")
    ap.add_argument("--speeds", type=Path, help="also run trafficcal run with each VP1 (the calibrator's, the "
                                                "trajectories', the votes') into this folder and report the mean "
                                                "absolute speed error (about a minute per scene and VP1)")
    ap.add_argument("--share", type=float, default=0.25, help="weight of the trajectory votes in the calibrator's "
                                                                  "accumulator, as a share of its own (default 0.25)")
    ap.add_argument("--json", type=Path, help="write the rows as JSON")
    args = ap.parse_args()
    missing = [s for s in args.scenes if not (s / "video.mp4").is_file() or not (s / "gt_data.pkl").is_file()]
    if missing:
        raise SystemExit(f"not a rendered scene (video.mp4 and gt_data.pkl needed): {', '.join(map(str, missing))}")
    rows = []
    for scene in args.scenes:
        rows.append(evaluate(scene, args.e2e, args.speeds, args.share))
        r = rows[-1]
        print(f"{r.scene}: VP1 {_f(r.vp1_klt_deg)}° -> {_f(r.vp1_traj_deg)}°, ratio {_f(r.ratio_klt)} -> "
              f"{_f(r.ratio_traj)}, speed {_f(r.speed_klt, '.2f')} -> {_f(r.speed_traj, '.2f')} km/h; votes: VP1 "
              f"{_f(r.vp1_votes_deg)}°, ratio {_f(r.ratio_votes)}, speed {_f(r.speed_votes, '.2f')} km/h {r.note}",
              flush=True)
    print()
    print(table(rows))
    if args.json:
        from dataclasses import asdict

        args.json.write_text(json.dumps([asdict(r) for r in rows], indent=1) + "\n")


if __name__ == "__main__":
    main()
