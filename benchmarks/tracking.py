"""Tracking benchmark on ``trafficcal synth`` scenes with exact per-frame ground truth (issue 5, point 5).

For each preset: render a scene (cached in --work), decode it, run detection + the tracking pipeline with the
scene's true calibration, and score:

* MOTA / IDF1 (py-motmetrics, IoU ≥ 0.5 against ground-truth boxes of vehicles at least half visible);
* recall and false positives per minute under BrnoCompSpeed's counting rule (the tracks' reference points as
  a results file, matched by crossing of the measurement line within 0.2 s, lane-checked — the project's
  evaluator), plus the speed error these tracks give with the true calibration (tracking alone);
* reference-point error (centre of the bottom-front edge) in pixels and metres on the road plane, between the
  measurement lines (where speeds are measured) and for every measured observation within 40 m of the camera;
* tracker throughput (background model + blob grouping + 3D boxes + Kalman tracking, no decoding or
  detection) and the mean number of vehicles per frame; and the tracker core alone with 10 vehicles.

Detectors: ``oracle`` (ground-truth boxes, hulls from the background model: isolates the tracker from the
detector), ``oracle-hull`` (ground-truth boxes and exact silhouettes: isolates it from segmentation too),
``blobs`` (foreground blobs, no weights), ``nanodet`` (the shared NanoDet ONNX model through the detection
library; needs realistic vehicle meshes).

    .venv/bin/python benchmarks/tracking.py --presets highway_day,left_side --duration 30 --detector oracle
    .venv/bin/python benchmarks/tracking.py --all --json results.json

Targets (issue 5): recall ≥ 0.95, ≤ 1 false positive per minute, median reference-point error ≤ 0.15 m,
tracker ≥ 100 fps with 10 vehicles.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
import zlib
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gst_trafficcal.brnocompspeed import BrnoCalibration, Results, Track as BrnoTrack, load_gt_data  # noqa: E402
from gst_trafficcal.calibration import load_calibration  # noqa: E402
from gst_trafficcal.detection.factory import detect  # noqa: E402
from gst_trafficcal.detection.records import Detections, box_iou  # noqa: E402
from gst_trafficcal.evaluation import lanes_of_points, points_between_lines  # noqa: E402
from gst_trafficcal.tracking.background import BackgroundModel, chroma_from_bgr  # noqa: E402
from gst_trafficcal.tracking.pipeline import TrackingPipeline  # noqa: E402
from gst_trafficcal.tracking.tracker import TrackerConfig  # noqa: E402
from options import field_overrides  # noqa: E402  (benchmarks/options.py)

SHARED = ROOT.parent / "shared"
NANODET = SHARED / "models" / "detectors" / "nanodet_hpc203.onnx"
DEBUG = False
MIN_SIZE = 0.01
NEAR = 40.0  # metres from the camera foot: the near-range reference-point error
DEFAULT_PRESETS = ("highway_day", "left_side", "right_side_oneway", "high_camera", "low_camera", "vp2_far",
                   "strong_roll", "dense", "sparse", "zoom", "wide", "country_two_way")


@dataclass
class SceneScore:
    preset: str
    detector: str
    frames: int
    minutes: float
    ap50: float  # detection average precision at IoU 0.5 (detector boxes against moving vehicles at least half visible)
    ap50_zone: float  # the same inside the measurement zone (between the first and last measurement lines)
    mota: float
    idf1: float
    id_switches: int
    mostly_tracked: float  # fraction of vehicles tracked over at least 80 % of their visible life
    gt_cars: int
    recall: float
    false_positives: int
    fp_per_min: float
    speed_mae_kmh: float
    ref_err_px_median: float
    ref_err_m_median: float
    ref_err_m_p95: float
    ref_points: int
    ref_err_m_median_near: float  # all measured observations within NEAR metres of the camera
    # the in-zone reference points split by which face the front is (oncoming: the face nearer the camera, seen;
    # receding: the far one, placed at the track's length): count and median signed error along the direction
    # of travel (m, + = ahead of the true front), and the median absolute error across the road (m)
    ref_oncoming: int
    ref_along_oncoming_m: float
    ref_receding: int
    ref_along_receding_m: float
    ref_lateral_m: float
    vehicles_per_frame: float
    tracker_fps: float


def match_detections(det_boxes: np.ndarray, scores: np.ndarray, gt_boxes: np.ndarray, seen: np.ndarray,
                     iou_min: float = 0.5, count_fp: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One frame of detection scoring (PASCAL VOC rule): detections in descending score take the unmatched
    ground-truth box of highest IoU ≥ ``iou_min``.  Returns (scores, 1 = true positive / 0 = false positive)
    of the detections that count; a detection matching only a vehicle not ``seen`` (less than half visible or
    tiny) is ignored, neither true nor false; so is an unmatched detection where ``count_fp`` (per detection) is
    False."""
    order = np.argsort(-scores, kind="stable")
    iou = box_iou(det_boxes[order], gt_boxes)
    used = np.zeros(len(gt_boxes), bool)
    keep, tp = [], []
    for r, i in enumerate(order):
        cand = np.where(~used & (iou[r] >= iou_min))[0]
        if len(cand):
            j = cand[np.argmax(iou[r, cand])]
            used[j] = True
            if not seen[j]:
                continue
            keep.append(i)
            tp.append(1)
        elif count_fp is None or count_fp[i]:
            keep.append(i)
            tp.append(0)
    return scores[np.array(keep, int)], np.array(tp, int)


def average_precision(scores: np.ndarray, tp: np.ndarray, n_gt: int) -> float:
    """Area under the precision/recall curve (all-point interpolation, as PASCAL VOC 2010+ and COCO per IoU)."""
    if n_gt == 0:
        return float("nan")
    if len(scores) == 0:
        return 0.0
    order = np.argsort(-scores, kind="stable")
    tp = tp[order]
    ctp = np.cumsum(tp)
    recall = ctp / n_gt
    precision = ctp / np.arange(1, len(tp) + 1)
    mrec = np.concatenate([[0.0], recall, [recall[-1]]])
    mpre = np.concatenate([[1.0], precision, [0.0]])
    mpre = np.maximum.accumulate(mpre[::-1])[::-1]
    return float(np.sum((mrec[1:] - mrec[:-1]) * mpre[1:]))


def _box_model(kind, name, rng):
    """Cuboid vehicles of plausible sizes (silhouette = the 3D box), when the mesh catalogue is not wanted."""
    import types

    big = name in ("bus", "truck", "van") or rng.random() < 0.12
    size = (rng.uniform(6.0, 12.0), rng.uniform(2.3, 2.55), rng.uniform(2.5, 3.5)) if big else \
        (rng.uniform(3.8, 5.0), rng.uniform(1.65, 1.95), rng.uniform(1.35, 1.8))
    return types.SimpleNamespace(name=f"box_{name}", body_style=name, length=float(size[0]), width=float(size[1]),
                                 height=float(size[2]))


def render(preset: str, duration: float, seed: int, work: Path, vehicles: str = "catalogue") -> Path:
    """The scene folder, rendered unless already there: ``trafficcal synth`` (catalogue meshes) or the synth
    library with cuboid vehicles (``vehicles="boxes"``)."""
    out = work / f"{preset}-{seed}-{duration:g}s-{vehicles}"
    if (out / "frames.jsonl").exists() and (out / "video.mp4").exists():
        return out
    if vehicles == "boxes":
        from gst_trafficcal.synth.generate import generate
        from gst_trafficcal.synth.scenario import load_preset

        scen = load_preset(preset)
        scen.duration, scen.seed = duration, seed
        generate(scen, out, model_factory=_box_model, box_vehicles=True)
    else:
        cmd = [sys.executable, "-m", "gst_trafficcal", "synth", "--preset", preset, "--duration", str(duration),
               "--seed", str(seed), "--out", str(out), "--no-progress"]
        subprocess.run(cmd, check=True, cwd=ROOT)
    return out


class SilhouetteHulls(list):
    """``generate(keep_masks=...)`` sink keeping, per frame, only each visible vehicle's exact silhouette as a
    convex hull (pixel centres at integers; the rendered id image itself is dropped): {time ms: {vehicle id: hull}}."""

    def __init__(self) -> None:
        super().__init__()
        self.hulls: dict[int, dict[int, np.ndarray]] = {}

    def append(self, item) -> None:
        t, _, ids, _, items, H = item
        self.hulls[int(round(t * 1000))] = silhouette_hulls(ids, [v.id for v, *_ in items], H)


def silhouette_hulls(ids: np.ndarray, vehicle_ids: list[int], H: np.ndarray | None = None) -> dict[int, np.ndarray]:
    """Each vehicle's convex hull (K x 2 pixels) from the renderer's id image (slot k + 1 = ``vehicle_ids[k]``;
    slots from 255 share one value and are skipped), moved by the camera-shake homography ``H`` when there is one."""
    from gst_trafficcal.synth.imaging import apply_homography

    from scipy import ndimage

    out: dict[int, np.ndarray] = {}
    for k, sl in enumerate(ndimage.find_objects(ids, max_label=min(len(vehicle_ids), 254)), start=1):
        if sl is None:
            continue
        ys, xs = np.nonzero(ids[sl] == k)
        # the pixel squares' corners (pixel i spans [i - 0.5, i + 0.5])
        pts = np.stack([xs + sl[1].start, ys + sl[0].start], axis=1).astype(np.float32)
        hull = cv2.convexHull(pts).reshape(-1, 2).astype(np.float64)
        corners = (hull[:, None, :] + np.array([[-0.5, -0.5], [0.5, -0.5], [-0.5, 0.5], [0.5, 0.5]])).reshape(-1, 2)
        hull = cv2.convexHull(corners.astype(np.float32)).reshape(-1, 2).astype(np.float64)
        out[int(vehicle_ids[k - 1])] = apply_homography(H, hull) if H is not None else hull
    return out


def render_silhouettes(scen, out: Path) -> Path:
    """Render the scenario ``scen`` into ``out`` with every frame's exact vehicle silhouettes in
    ``out/silhouettes.pkl`` (skipped when already there): what a perfect segmenter would give the tracker."""
    import pickle

    from gst_trafficcal.synth.generate import generate

    if (out / "silhouettes.pkl").exists() and (out / "video.mp4").exists() and (out / "frames.jsonl").exists():
        return out
    sink = SilhouetteHulls()
    generate(scen, out, keep_masks=sink)
    with open(out / "silhouettes.pkl", "wb") as fh:
        pickle.dump(sink.hulls, fh)
    return out


def silhouette_scene(preset: str, given: Path | None, duration: float, seed: int, work: Path) -> Path:
    """The preset (or the given scene folder's scenario.json) rendered again with its exact silhouettes."""
    from gst_trafficcal.synth.scenario import load_preset, load_scenario

    if given is not None:
        if not (given / "scenario.json").exists():
            raise SystemExit(f"{given}: no scenario.json to render it again with silhouettes")
        return render_silhouettes(load_scenario(given / "scenario.json"), work / f"{given.name}-silhouettes")
    scen = load_preset(preset)
    scen.duration, scen.seed = duration, seed
    return render_silhouettes(scen, work / f"{preset}-{seed}-{duration:g}s-silhouettes")


def load_truth(scene: Path) -> dict[int, list[dict]]:
    """Per-vehicle ground-truth records grouped by time in milliseconds."""
    by_time: dict[int, list[dict]] = {}
    with open(scene / "frames.jsonl", encoding="utf-8") as f:
        for line in f:
            if line.strip():
                r = json.loads(line)
                by_time.setdefault(int(round(r["time"] * 1000)), []).append(r)
    return by_time


def make_detector(name: str, model: str | None = None):
    """The detector ``name`` stands for; ``model``: vehicleseg's ONNX file instead of the shipped one."""
    if name == "nanodet":
        from gst_trafficcal.detection.onnx_detector import OnnxDetector
        return OnnxDetector(NANODET, threshold=0.35)
    if name == "background":  # what vehicledetect runs with no model (the product's default)
        from gst_trafficcal.detection.factory import create_detector
        return create_detector("")
    if name == "background-average":  # vehicledetect background=average (moving average + shadow peeling)
        from gst_trafficcal.detection.factory import create_detector
        return create_detector("", background="average")
    if name in ("vehicleseg", "vehicleseg-boxes"):  # vehicledetect model=vehicleseg (learned segmenter: boxes + hulls)
        from gst_trafficcal.detection.factory import create_detector
        return create_detector(model or "vehicleseg")
    return None


def evaluate_scene(preset: str, scene: Path, detector_name: str, background: dict | None = None,
                   colour: bool = False, peeled: bool = False, tracker: dict | None = None,
                   model: str | None = None, cache: Path | None = None) -> SceneScore:
    """Score one rendered scene; ``background`` overrides BackgroundModel fields, ``colour`` passes the frames'
    U and V planes to it (as the element does with I420/NV12 input) instead of the grey frame alone; ``tracker``
    overrides TrackerConfig fields; ``model``: vehicleseg's ONNX file (default: the shipped one); ``cache``: a
    folder keeping the detector's output per scene, so variants of the tracker are compared on the same
    detections without running the detector again."""
    import motmetrics as mm
    import pickle

    cal = load_calibration(scene / "calibration.json")
    cam = cal.camera
    W, H = cal.image_size
    gt = load_gt_data(scene / "gt_data.pkl")
    lines = gt.measurement_lines
    truth = load_truth(scene)
    silhouettes = {}
    if detector_name == "oracle-silhouette":
        import pickle

        if not (scene / "silhouettes.pkl").exists():
            raise SystemExit(f"{scene}: no silhouettes.pkl (render it with render_silhouettes)")
        with open(scene / "silhouettes.pkl", "rb") as fh:
            silhouettes = pickle.load(fh)
    cached: dict[int, Detections] | None = None
    cache_file = None
    if cache is not None and detector_name not in ("oracle", "oracle-hull", "oracle-silhouette", "blobs"):
        key = f"{scene.resolve()}|{detector_name}|{model or ''}|{(scene / 'video.mp4').stat().st_mtime_ns}"
        cache_file = cache / f"{scene.name}-{detector_name}-{zlib.crc32(key.encode()):08x}.pkl"
        if cache_file.is_file():
            try:
                with open(cache_file, "rb") as fh:
                    cached = pickle.load(fh)
            except (OSError, EOFError, pickle.UnpicklingError) as exc:  # a run cut short while writing it
                print(f"{cache_file}: unreadable ({exc}); detecting again", file=sys.stderr)
                cached = None
    fresh: dict[int, Detections] = {}
    detector = make_detector(detector_name, model) if cached is None else None
    config = TrackerConfig(**(tracker or {}))
    if peeled:  # tracker peel=true: hulls from the background detector's peeled foreground
        from gst_trafficcal.tracking.peeled import PeeledBackground
        pipe = TrackingPipeline(config=config, background=PeeledBackground())
    else:
        pipe = TrackingPipeline(config=config, background=BackgroundModel(**(background or {})))
    pipe.set_camera(cam)
    cap = cv2.VideoCapture(str(scene / "video.mp4"))
    if not cap.isOpened():
        raise SystemExit(f"{scene / 'video.mp4'}: cannot open")
    acc = mm.MOTAccumulator(auto_id=True)
    busy = 0.0
    frames = 0
    n_vehicles = 0
    ref_px_err, ref_m_err, near_m_err = [], [], []
    faces: list[tuple[bool, float, float]] = []  # in-zone points: (receding, along the travel (m), across (m))
    gt_boxes_by_frame = []
    ap_scores, ap_tp, ap_gt = [], [], 0
    apz_scores, apz_tp, apz_gt = [], [], 0
    while True:
        ok, bgr = cap.read()
        if not ok:
            break
        t = cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
        recs = truth.get(int(round(t * 1000)), [])
        gboxes = np.array([r["box"] for r in recs], np.float64).reshape(-1, 4)
        visible = np.array([r["visible"] for r in recs])
        # vehicles a detector could see: at least half visible, box diagonal at least MIN_SIZE of the image width,
        # moving (the replays hold a few BrnoCompSpeed cars without a speed, standing still for the whole clip:
        # a background model cannot see them; detections of them are ignored, neither true nor false)
        speed = np.array([r.get("speed_kmh", 99.0) for r in recs])
        seen = (visible >= 0.5) & (np.hypot(*(gboxes[:, 2:] - gboxes[:, :2]).T) >= MIN_SIZE * W) & (speed >= 5.0)
        gref = np.array([r["ref"] for r in recs], np.float64).reshape(-1, 2)
        in_zone = points_between_lines(gref, lines[0], lines[-1]) if len(recs) else np.zeros(0, bool)
        hulls = None
        if detector_name == "oracle-silhouette":  # the renderer's exact silhouettes: the tracker's geometry alone
            sil = silhouettes.get(int(round(t * 1000)), {})
            keep = seen & np.array([r["id"] in sil for r in recs], bool)
            hl = [sil[r["id"]] for r, k in zip(recs, keep) if k]
            bx = np.array([(*h.min(axis=0), *h.max(axis=0)) for h in hl], np.float64).reshape(-1, 4)
            det = Detections(bx, np.ones(len(hl)), np.full(len(hl), 2), np.full(len(hl), "car", dtype=object), hl)
        elif detector_name in ("oracle", "oracle-hull"):
            keep = seen
            if detector_name == "oracle-hull":  # exact silhouettes: isolates the tracker from segmentation
                hulls = [cv2.convexHull(np.array(r["box3d"], np.float32)).reshape(-1, 2).astype(np.float64)
                         for r, k in zip(recs, keep) if k]
            det = Detections(gboxes[keep], np.ones(int(keep.sum())), np.full(int(keep.sum()), 2),
                             np.full(int(keep.sum()), "car", dtype=object))
        elif detector_name == "blobs":
            det = None
        else:
            det = cached[frames] if cached is not None else detect(detector, bgr, t)
            fresh[frames] = det
            if detector_name == "vehicleseg-boxes":  # its boxes only: hulls from the tracker's background model
                det = Detections(det.boxes, det.scores, det.class_ids, det.labels)
        gray = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
        chroma = chroma_from_bgr(bgr) if colour else None  # what an I420 buffer holds: not timed
        t0 = time.process_time()
        res, used = pipe.process(gray, t, det, hulls=hulls, chroma=chroma)
        busy += time.process_time() - t0
        frames += 1
        # detection AP: the boxes the tracker got (for blobs, the blobs it made)
        sc, tp = match_detections(used.boxes, np.asarray(used.scores, np.float64), gboxes, seen)
        ap_scores.append(sc)
        ap_tp.append(tp)
        ap_gt += int(seen.sum())
        # ... and inside the measurement zone: vehicles whose reference point is in it; a detection of a vehicle
        # outside it is ignored, an unmatched one is false only if its bottom centre is in the zone
        ub = used.boxes.reshape(-1, 4).astype(np.float64)
        dz = points_between_lines(np.stack([(ub[:, 0] + ub[:, 2]) / 2, ub[:, 3]], axis=1), lines[0], lines[-1]) \
            if len(ub) else np.zeros(0, bool)
        sc, tp = match_detections(ub, np.asarray(used.scores, np.float64), gboxes, seen & in_zone, count_fp=dz)
        apz_scores.append(sc)
        apz_tp.append(tp)
        apz_gt += int((seen & in_zone).sum())
        n_vehicles += len(used)
        # MOT scoring against vehicles at least half visible
        ids, boxes = pipe.tracker.outputs(0.0)
        g = seen
        iou = box_iou(gboxes[g], boxes)
        acc.update([r["id"] for r, k in zip(recs, g) if k], list(ids), np.where(iou >= 0.5, 1 - iou, np.nan))
        # reference points of this frame's measured observations against the matched ground truth
        for i in range(len(used)):
            tr = res.track_of(i)
            if tr is None or tr.last.ref_px is None or not len(gboxes):
                continue
            ov = box_iou(tr.last.det_box[None], gboxes)[0]
            k = int(np.argmax(ov))
            gref = np.array(recs[k]["ref"], np.float64)
            if ov[k] < 0.5:
                continue
            err_px = float(np.linalg.norm(tr.last.ref_px - gref))
            err_m = float(cam.distance(tr.last.ref_px, gref))
            if np.linalg.norm(cam.to_world(gref)[:2]) <= NEAR:
                near_m_err.append(err_m)
            if points_between_lines(gref[None], lines[0], lines[-1])[0]:  # where speeds are measured
                ref_px_err.append(err_px)
                ref_m_err.append(err_m)
                faces.append(face_error(cam, tr.last.ref_px, gref, tr.direction))
        gt_boxes_by_frame.append(len(recs))
    cap.release()
    if cache_file is not None and cached is None:
        cache.mkdir(parents=True, exist_ok=True)
        part = cache_file.with_suffix(".part")
        with open(part, "wb") as fh:
            pickle.dump(fresh, fh)
        part.replace(cache_file)  # whole or absent: a run stopped while writing leaves no half file behind
    tracks = pipe.flush()
    # BrnoCompSpeed counting rule through the project's evaluator
    from gst_trafficcal.evaluation import evaluate_speeds, prepare_tracks

    cars = []
    for tr in tracks:
        px, _ = tr.reference_points()
        ok = np.all(np.isfinite(px), axis=1)
        # export the points on valid lanes (the official rule drops a car with any point off the lane dividers
        # or in an invalid lane)
        lanes = lanes_of_points(px[ok], gt.lane_div_lines)
        ok[ok] &= (lanes >= 0) & ~np.isin(lanes, list(gt.invalid_lanes))
        if ok.sum() < 2:
            continue
        frames_idx = np.round(tr.timestamps[ok] * gt.fps).astype(np.int64)
        cars.append(BrnoTrack(tr.id, frames_idx, px[ok]))
        if DEBUG:
            allpx = np.all(np.isfinite(px), axis=1)
            print(f"   track {tr.id}: t {tr.timestamps[0]:.2f}-{tr.timestamps[-1]:.2f} obs {len(px)} measured "
                  f"{allpx.sum()} in lanes {ok.sum()} dir {tr.direction} y {np.nanmin(px[:, 1]):.0f}-"
                  f"{np.nanmax(px[:, 1]):.0f}", file=sys.stderr)
    brno = BrnoCalibration(tuple(cam.vp1), tuple(cam.vp2), tuple(cam.pp), cam.brno_scale())
    prepared = prepare_tracks(Results(brno, tuple(cars)), gt, W, H)
    report = evaluate_speeds(gt, prepared, cam)
    if DEBUG:
        print(f"  cars {len(cars)}, after prefilter {len(prepared.tracks)}, intersection errors {prepared.n_errors}, "
              f"matched {report.matched}/{report.n_gt_cars}", file=sys.stderr)
        for k in range(len(prepared.tracks)):
            tr = prepared.tracks[k]
            print("   ", tr.id, len(tr.frames), bool(prepared.ok[k]), np.round(prepared.point_last[k], 1),
                  np.round(prepared.point_first[k], 1), round(float(prepared.time_last[k]), 2),
                  np.round(tr.pos[[0, -1]]).tolist(), file=sys.stderr)
        print("    gt", [(c.car_id, sorted(c.lanes), round(c.match_time, 2)) for c in gt.cars], file=sys.stderr)
        print("    speed errors", [(c["gt_id"], c["id"], round(c["error_kmh"], 2)) for c in report.cars], file=sys.stderr)
    summary = mm.metrics.create().compute(acc, metrics=["mota", "idf1", "num_switches", "mostly_tracked",
                                                         "num_unique_objects"], name=preset).iloc[0]
    minutes = frames / gt.fps / 60.0
    return SceneScore(
        preset=preset, detector=detector_name, frames=frames, minutes=round(minutes, 3),
        ap50=round(average_precision(np.concatenate(ap_scores), np.concatenate(ap_tp), ap_gt), 4),
        ap50_zone=round(average_precision(np.concatenate(apz_scores), np.concatenate(apz_tp), apz_gt), 4),
        mota=round(float(summary["mota"]), 4), idf1=round(float(summary["idf1"]), 4),
        id_switches=int(summary["num_switches"]),
        mostly_tracked=round(float(summary["mostly_tracked"]) / max(float(summary["num_unique_objects"]), 1), 4),
        gt_cars=report.n_gt_cars, recall=round(report.recall, 4),
        false_positives=report.false_positives, fp_per_min=round(report.false_positives / max(minutes, 1e-9), 3),
        speed_mae_kmh=round(report.abs_kmh.mean, 3) if report.matched_valid else float("nan"),
        ref_err_px_median=round(float(np.median(ref_px_err)), 3) if ref_px_err else float("nan"),
        ref_err_m_median=round(float(np.median(ref_m_err)), 4) if ref_m_err else float("nan"),
        ref_err_m_p95=round(float(np.percentile(ref_m_err, 95)), 4) if ref_m_err else float("nan"),
        ref_points=len(ref_m_err),
        ref_err_m_median_near=round(float(np.median(near_m_err)), 4) if near_m_err else float("nan"),
        **face_summary(faces),
        vehicles_per_frame=round(n_vehicles / max(frames, 1), 2),
        tracker_fps=round(frames / max(busy, 1e-9), 1))


def face_error(cam, ref_px: np.ndarray, true_px: np.ndarray, direction: int) -> tuple[bool, float, float]:
    """A reference point's error split by face: (receding — its front is the box face away from the camera —,
    signed error along the direction of travel in metres (+ = ahead), error across the road in metres)."""
    ours, true = cam.to_world(np.asarray(ref_px, np.float64))[:2], cam.to_world(np.asarray(true_px, np.float64))[:2]
    d = 1 if direction >= 0 else -1
    return bool(d * ours[0] > 0), float(d * (ours[0] - true[0])), float(ours[1] - true[1])


def face_summary(faces: list[tuple[bool, float, float]]) -> dict:
    """SceneScore's ref_oncoming … ref_lateral_m from :func:`face_error`'s tuples."""
    a = np.array(faces, np.float64).reshape(-1, 3)
    rec = a[:, 0] > 0

    def med(x: np.ndarray) -> float:
        return round(float(np.median(x)), 4) if len(x) else float("nan")

    return dict(ref_oncoming=int((~rec).sum()), ref_along_oncoming_m=med(a[~rec, 1]), ref_receding=int(rec.sum()),
                ref_along_receding_m=med(a[rec, 1]), ref_lateral_m=med(np.abs(a[:, 2])))


def print_table(scores: list[SceneScore], cols: list[str]) -> None:
    """The ``cols`` fields of each scene's score as a Markdown table."""
    print("\n| " + " | ".join(cols) + " |\n|" + "---|" * len(cols))
    for s in scores:
        d = asdict(s)
        print("| " + " | ".join(str(d[c]) for c in cols) + " |")


def core_fps(n_vehicles: int = 10, size: tuple[int, int] = (960, 540),
             seconds: float = 20.0) -> tuple[float, float, float]:
    """Tracker core (association, Kalman, 3D boxes) on simulated hulls with about ``n_vehicles`` in view:
    (wall-clock fps, CPU-time fps, vehicles per frame)."""
    from gst_trafficcal.tracking.simulate import default_camera, detect, simulate
    from gst_trafficcal.tracking.tracker import Tracker

    cam = default_camera(size)
    best = None
    for rate in (0.3, 0.45, 0.6, 0.8, 1.0, 1.3):
        scene = simulate(cam, size, duration=seconds, rate=rate, seed=5)
        mean = float(np.mean([len(f.ids) for f in scene.frames[100:]]))
        best = (scene, mean)
        if mean >= n_vehicles:
            break
    scene, mean = best
    rng = np.random.default_rng(0)
    inputs = [detect(f, rng, size) for f in scene.frames]
    tracker = Tracker(camera=cam, image_size=size)
    t0, c0 = time.perf_counter(), time.process_time()
    for f, (det, hulls, _) in zip(scene.frames, inputs):
        tracker.update(f.t, det, hulls)
    n = len(scene.frames)
    return n / (time.perf_counter() - t0), n / (time.process_time() - c0), mean


def pipeline_fps(size: tuple[int, int], n_vehicles: int = 10, seconds: float = 12.0,
                 colour: bool = False) -> tuple[float, float, float]:
    """The whole tracking stage (background model — with the colour tests if ``colour`` —, grouping, 3D boxes,
    tracker: what the ``tracker`` element runs per I420 frame) on frames with about ``n_vehicles`` painted silhouettes:
    (wall-clock fps, CPU-time fps, vehicles per frame)."""
    from gst_trafficcal.tracking.simulate import default_camera, simulate

    cam = default_camera(size)
    for rate in (0.3, 0.45, 0.6, 0.8, 1.0, 1.3):
        scene = simulate(cam, size, duration=seconds, rate=rate, seed=5)
        frames = scene.frames[100:]
        if np.mean([len(f.ids) for f in frames]) >= n_vehicles:
            break
    rng = np.random.default_rng(0)
    bg = cv2.resize(rng.integers(70, 120, (size[1] // 6, size[0] // 6)).astype(np.uint8), size)
    images = []
    for k, f in enumerate(frames):
        img = cv2.cvtColor(bg, cv2.COLOR_GRAY2BGR)
        for j, h in enumerate(f.hulls):
            cv2.fillPoly(img, [np.round(h).astype(np.int32)], (60 + 40 * (j % 4), 200, 90 + 30 * (j % 5)))
        # as an I420 buffer gives them: the Y plane and the half-size U, V planes
        images.append((cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), chroma_from_bgr(img) if colour else None))
    pipe = TrackingPipeline()
    pipe.set_camera(cam)
    wall = busy = 0.0
    for f, (img, chroma) in zip(frames, images):
        det = Detections(f.boxes, np.ones(len(f.ids)), np.full(len(f.ids), 2), np.full(len(f.ids), "car", dtype=object))
        t0, c0 = time.perf_counter(), time.process_time()
        pipe.process(img, f.t, det, chroma=chroma)
        wall += time.perf_counter() - t0
        busy += time.process_time() - c0
    return len(frames) / wall, len(frames) / busy, float(np.mean([len(f.ids) for f in frames]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", default=",".join(DEFAULT_PRESETS[:4]),
                    help="comma-separated synth presets (empty: only the fps measurements)")
    ap.add_argument("--all", action="store_true", help=f"all of: {', '.join(DEFAULT_PRESETS)}")
    ap.add_argument("--scenes", default="",
                    help="comma-separated scene folders scored as they are (video.mp4, frames.jsonl, gt_data.pkl, "
                         "calibration.json), e.g. the replays /tmp/replays/session0_left (real road backgrounds)")
    ap.add_argument("--duration", type=float, default=30.0, help="seconds of video per preset")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--detector", default="oracle", choices=("oracle", "oracle-hull", "oracle-silhouette", "blobs",
                                                              "background", "background-average", "vehicleseg",
                                                              "vehicleseg-boxes", "nanodet"),
                    help="ground-truth boxes (oracle: hulls from the background model; oracle-hull: the true 3D "
                         "box's outline; oracle-silhouette: the rendered vehicles' exact silhouettes, the scene "
                         "rendered again with them — the tracker's geometry alone), "
                         "foreground blobs inside the tracker (blobs), vehicledetect's default background "
                         "detector (background: the product's default chain; background-average: its "
                         "background=average), the learned segmenter (vehicleseg: its boxes and hulls; vehicleseg-boxes: its boxes, hulls from the "
                         "tracker's background model) or NanoDet")
    ap.add_argument("--model", default="", help="vehicleseg, vehicleseg-boxes: another ONNX file than the shipped one "
                                                "(e.g. one exported with --meta work_width=960)")
    ap.add_argument("--vehicles", default="catalogue", choices=("catalogue", "boxes"),
                    help="vehicle meshes from the synth catalogue, or cuboids (exact silhouettes)")
    ap.add_argument("--work", type=Path, default=Path("/tmp/trafficcal-bench-tracking"),
                    help="where rendered scenes are cached")
    ap.add_argument("--json", type=Path, help="write the scores here")
    ap.add_argument("--verbose", action="store_true", help="print the counting-rule details per track")
    ap.add_argument("--min-size", type=float, default=0.01,
                    help="smallest vehicle a detector is credited to see: box diagonal / image width")
    ap.add_argument("--shadow-std", type=float, default=None,
                    help="BackgroundModel.shadow_std (spread of the frame/background ratio a cast shadow may have)")
    ap.add_argument("--bg", action="append", default=[], metavar="FIELD=VALUE",
                    help="override a BackgroundModel field (repeatable), e.g. --bg chroma_tolerance=6")
    ap.add_argument("--tracker", action="append", default=[], metavar="FIELD=VALUE",
                    help="override a TrackerConfig field (repeatable), e.g. --tracker occluders=false")
    ap.add_argument("--colour", action="store_true",
                    help="also pass the U, V planes to the background model (tracker colour=true); default: "
                         "the Y plane only, as the tracker element by default")
    ap.add_argument("--peeled", action="store_true",
                    help="hulls from the background detector's peeled foreground (tracker peel=true) instead of the "
                         "tracker's own background model")
    ap.add_argument("--no-fps", action="store_true", help="skip the throughput measurements")
    ap.add_argument("--cache", type=Path, default=None,
                    help="keep each scene's detections in this folder and use them in later runs (tracker variants "
                         "compared on the same detections, without running the detector again)")
    args = ap.parse_args()
    if args.model and args.detector not in ("vehicleseg", "vehicleseg-boxes"):
        ap.error(f"--model is for --detector vehicleseg or vehicleseg-boxes, not {args.detector}")
    if args.model:  # a missing or foreign file: one line at start-up, not a traceback in the first scene
        from gst_trafficcal.errors import InputError
        try:
            make_detector(args.detector, args.model)
        except InputError as exc:
            ap.error(str(exc))
    global DEBUG, MIN_SIZE
    DEBUG, MIN_SIZE = args.verbose, args.min_size
    presets = DEFAULT_PRESETS if args.all else tuple(p for p in args.presets.split(",") if p)
    args.work.mkdir(parents=True, exist_ok=True)
    bg_opts = field_overrides(BackgroundModel(), args.bg)
    if args.shadow_std is not None:
        bg_opts["shadow_std"] = args.shadow_std
    tr_opts = field_overrides(TrackerConfig(), args.tracker)
    scores = []
    jobs = [(p, None) for p in presets] + [(Path(d).name, Path(d)) for d in args.scenes.split(",") if d]
    for preset, given in jobs:
        if args.detector == "oracle-silhouette":
            scene = silhouette_scene(preset, given, args.duration, args.seed, args.work)
        else:
            scene = given or render(preset, args.duration, args.seed, args.work, args.vehicles)
        s = evaluate_scene(preset, scene, args.detector, bg_opts, colour=args.colour, peeled=args.peeled,
                           tracker=tr_opts, model=args.model or None, cache=args.cache)
        scores.append(s)
        print(json.dumps(asdict(s)), flush=True)
    cols = ["preset", "ap50", "ap50_zone", "mota", "idf1", "id_switches", "mostly_tracked", "recall", "fp_per_min", "speed_mae_kmh", "ref_err_px_median",
            "ref_err_m_median", "ref_err_m_median_near", "vehicles_per_frame", "tracker_fps"]
    print_table(scores, cols)
    # where the reference error is: which face, along or across the road
    print_table(scores, ["preset", "ref_err_m_median", "ref_oncoming", "ref_along_oncoming_m", "ref_receding",
                         "ref_along_receding_m", "ref_lateral_m"])
    if scores:
        rec = np.mean([s.recall for s in scores])
        fpm = sum(s.false_positives for s in scores) / sum(s.minutes for s in scores)
        ref = np.median([s.ref_err_m_median for s in scores])
        print(f"\nmean recall {rec:.3f} (target ≥ 0.95), FP/min {fpm:.2f} (≤ 1), median ref error {ref:.3f} m "
              f"(≤ 0.15) [{args.detector}]")
    if args.no_fps:
        if args.json:
            args.json.write_text(json.dumps({"scores": [asdict(s) for s in scores]}, indent=2) + "\n")
        return
    wall, fps, mean = core_fps()
    print(f"tracker core: {fps:.0f} fps CPU time ({wall:.0f} wall) with {mean:.1f} vehicles per frame "
          f"(target ≥ 100 fps with 10)")
    stage = {}
    for size in ((960, 540), (1920, 1080)):
        key = f"{size[0]}x{size[1]}"
        stage[key] = pipeline_fps(size, colour=args.colour)
        print(f"tracking stage at {key} (background + hulls + 3D + tracker): {stage[key][1]:.0f} fps CPU time "
              f"({stage[key][0]:.0f} wall) with {stage[key][2]:.1f} vehicles")
    if args.json:
        args.json.write_text(json.dumps({"scores": [asdict(s) for s in scores], "core_fps": fps,
                                         "core_vehicles": mean, "stage_fps": stage}, indent=2) + "\n")


if __name__ == "__main__":
    main()
