"""Run a scenario end to end: traffic -> frames -> imaging -> video.mp4, plus every ground-truth file."""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..calibration import Calibration, save_calibration
from ..errors import InputError
from .camera import SynthCamera, build_camera, check_view
from .encode import VideoWriter
from .groundtruth import (SilhouetteAreas, build_gt_data, contact_sheet, lane_index, save_ground_truth,
                          scene_lines, vehicle_record)
from .imaging import Imaging, Shake
from .render import BoxMesh, Renderer, proxy_mesh, resolve_lighting, simplified_mesh
from .scenario import Scenario
from .scene import RoadLayout, build_scene
from .traffic import Traffic, Vehicle, draw_model, generate_traffic

VIDEO, GT_DATA, CALIBRATION, FRAMES_JSONL, PREVIEW, SCENARIO = (
    "video.mp4", "gt_data.pkl", "calibration.json", "frames.jsonl", "preview.png", "scenario.json")
#: the video while it is being written (renamed to VIDEO when complete)
PARTIAL_VIDEO = "video.partial.mp4"


@dataclass
class SynthResult:
    out_dir: Path
    frames: int  # frames written to the video
    dropped: int
    vehicles: int  # vehicles with at least one measurement-line crossing
    calibration: Calibration
    loop_seconds: float = 0.0  # wall time of the frame loop including the encoder finishing
    loop_cpu_seconds: float = 0.0  # CPU time of the frame loop: this process (all threads) + the encoder process


def _cpu_seconds() -> float:
    """User + system CPU time of this process (all its threads) and of its waited-for children (the encoder)."""
    import resource

    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def _mesh_for(v: Vehicle, box_vehicles: bool):
    if box_vehicles or v.model is None:
        return BoxMesh.make(v.length, v.width, v.height, colour=tuple(np.random.default_rng(v.colour_seed).uniform(
            0.1, 0.8, 3)))
    from ..vehicles.mesh import mesh_for
    return mesh_for(v.model, np.random.default_rng(v.colour_seed))


def generate(scen: Scenario, out_dir: str | Path, progress: Callable[[int, int], None] | None = None,
             box_vehicles: bool = False, traffic: Traffic | None = None, write_video: bool = True,
             keep_masks: list | None = None, model_factory=None) -> SynthResult:
    """Render ``scen`` into ``out_dir``.  ``box_vehicles`` draws cuboids (exact silhouettes, for tests);
    ``keep_masks`` (a list) receives (time, rgb, ids, records, items, shake homography or None) of every frame, for tests;
    ``model_factory(kind, name, rng)`` replaces the vehicle catalogue (tests use fixed-size cuboids)."""
    factory = model_factory or draw_model
    if scen.duration * scen.imaging.fps < 1 - 1e-9:
        raise InputError(f"duration {scen.duration:g} s is shorter than one frame at {scen.imaging.fps:g} fps")
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{out}: cannot create output folder ({exc.strerror or exc})") from None
    rng = np.random.default_rng(scen.seed)
    replay = None
    if scen.replay is not None:
        from .replay import prepare_replay
        replay = prepare_replay(scen, rng, factory)
        cam, layout, lines, traffic, backdrop = (replay.cam, replay.layout, replay.lines, replay.traffic,
                                                 replay.backdrop)
        true_cam = replay.calibration
        W, H = cam.size
        scen.camera.resolution = [W, H]
        ground = objects = np.zeros((0, 10), np.float32)
        lamps: list = []
    else:
        cam = build_camera(scen.camera)
        layout = RoadLayout(scen.road)
        true_cam = check_view(cam, scen.road, layout.half_width + scen.road.shoulder)
        if traffic is None:
            traffic = generate_traffic(scen, np.random.default_rng(rng.integers(2**63)), model_factory=factory)
        ground, objects, lamps = build_scene(scen.road, np.random.default_rng(rng.integers(2**63)), False)
        dirs = [d for d in scen.traffic.directions if d < scen.road.directions or scen.road.directions == 1]
        lines = scene_lines(cam, layout, dirs, scen.measurement.far_car_span)
        backdrop = None
    light = resolve_lighting(scen.lighting)
    W, H = cam.size
    cal = Calibration(camera=true_cam, image_size=(W, H), state="calibrated", source="synth",
                      confidence={"vp1": 1.0, "vp2": 1.0, "scale": 1.0})
    save_calibration(cal, out / CALIBRATION)
    (out / SCENARIO).write_text(json.dumps(scen.to_dict(), indent=2) + "\n", encoding="utf-8")
    fps = scen.imaging.fps
    n = int(np.floor(scen.duration * fps + 1e-9))
    if replay is not None:
        gt = replay.gt
        lane_of = {v.id: v.lane for v in traffic.vehicles}.__getitem__
    else:
        gt = build_gt_data(cam, layout, lines, traffic.vehicles, fps, n / fps)
        lane_of = lambda vid: lane_index(lines, by_id[vid].y)  # noqa: E731
        by_id = {v.id: v for v in traffic.vehicles}
    save_ground_truth(gt, out / GT_DATA)

    renderer = Renderer(cam, light, ground, objects, lamps, scen.road.pole_spacing if replay is None else 0.0,
                        backdrop=backdrop, seed=int(rng.integers(2**31)), road=_road_pattern(scen),
                        surface_texture=scen.road.surface_texture, joints=scen.road.joints)
    imaging = Imaging(scen.imaging, scen.lighting, (W, H), night=scen.lighting.preset == "night",
                      rng=np.random.default_rng(rng.integers(2**63)))
    shake = Shake(cam.K, scen.imaging.shake, scen.imaging.shake_hz, np.random.default_rng(rng.integers(2**63)))
    drop_rng = np.random.default_rng(rng.integers(2**63))
    dropped = drop_rng.random(n) < scen.imaging.drop_rate
    dropped[0] = False
    vfr = bool(dropped.any())
    sheet_at = set(np.linspace(0, n - 1, min(6, n)).round().astype(int).tolist())
    sheet: list = []
    meshes: dict[int, object] = {}
    proxies: dict[int, object] = {}
    written = 0
    # the video is written under a partial name and renamed when the last frame is in: an interrupted render (an
    # exception, Ctrl-C, a killed process whose encoder still closes the file) never leaves a playable but short
    # video.mp4 that a later run would take for a finished scene
    partial = out / PARTIAL_VIDEO
    if write_video:
        (out / VIDEO).unlink(missing_ok=True)
    writer = VideoWriter(partial, (W, H), fps, scen.imaging.bitrate, variable_timestamps=vfr) \
        if write_video else None
    complete = False
    exposure = scen.imaging.motion_blur
    areas = SilhouetteAreas()
    t_loop, cpu_loop = time.perf_counter(), _cpu_seconds()
    try:
        with open(out / FRAMES_JSONL, "w", encoding="utf-8") as jf:
            for i in range(n):
                if progress is not None:
                    progress(i, n)
                if dropped[i]:
                    continue
                t = i / fps
                active = traffic.active(t)
                items = []
                for v in active:
                    size = _projected_size(cam, v, t)
                    if size <= 0:
                        continue
                    m = meshes.get(v.id)
                    if m is None:
                        m = meshes[v.id] = _mesh_for(v, box_vehicles)
                    if not box_vehicles and size < LOD_PIXELS[1]:  # levels of detail by projected size
                        lod = 0 if size < LOD_PIXELS[0] else 1
                        key = (v.id, lod)
                        if key not in proxies:
                            proxies[key] = proxy_mesh(v, m) if lod == 0 else simplified_mesh(m, v.length / 16)
                        m = proxies[key]
                    items.append((v, m, v.centre(t).astype(np.float32), v.turn(t)))
                rgb, ids = renderer.render(items)
                counts = cv2.calcHist([ids], [0], None, [256], [0, 256]).ravel().astype(int)
                Hs = shake.homography(t) if scen.imaging.shake > 0 else None
                motions = {}
                if exposure > 0:
                    for k, (v, *_) in enumerate(items):
                        if k + 1 < 255 and counts[k + 1]:
                            a = cam.project(v.centre(t - exposure) + [0, 0, v.height / 2])
                            b = cam.project(v.centre(t) + [0, 0, v.height / 2])
                            motions[k + 1] = b - a
                frame = imaging.process(rgb, ids, motions, Hs)
                if writer is not None:
                    writer.write(frame, t)
                recs = []
                for k, (v, _, off, turn) in enumerate(items):
                    verts = renderer.frame_points[k]
                    seen = int(counts[k + 1]) if k + 1 < 255 else 0  # slots >= 255 share one mask value
                    r = vehicle_record(written, t, v, cam, verts, seen, lane_of(v.id), Hs, renderer.frame_triangles[k],
                                       areas)
                    if r is not None:
                        recs.append(r)
                        jf.write(json.dumps(r) + "\n")
                if keep_masks is not None:
                    keep_masks.append((t, frame, ids, recs, items, Hs))
                if i in sheet_at:
                    sheet.append((t, frame, recs))
                written += 1
                if i % 50 == 0:
                    keep = {v.id for v in active}
                    renderer.forget(keep)
                    areas.forget(keep)
                    for vid in [k for k in meshes if k not in keep]:
                        del meshes[vid]
                    for key in [k for k in proxies if k[0] not in keep]:
                        del proxies[key]
        if progress is not None:
            progress(n, n)
        complete = True
    finally:
        if writer is not None:
            writer.close()
            if complete:
                partial.replace(out / VIDEO)
        renderer.release()
    loop_seconds, loop_cpu = time.perf_counter() - t_loop, _cpu_seconds() - cpu_loop
    contact_sheet(sheet, out / PREVIEW)
    return SynthResult(out_dir=out, frames=written, dropped=int(dropped.sum()), vehicles=len(gt.cars),
                       calibration=cal, loop_seconds=loop_seconds, loop_cpu_seconds=loop_cpu)


# projected 3D-box extents (pixels) below which vehicles are drawn as a few boxes / as a simplified mesh
LOD_PIXELS = (40.0, 150.0)


def _projected_size(cam: SynthCamera, v: Vehicle, t: float, margin: float = 0.3) -> float:
    """Largest extent in pixels of the vehicle's projected 3D box, or 0 when neither it nor its shadow can show
    in the image (behind the camera, or outside the image widened by ``margin`` on every side)."""
    X = v.box_corners(t)
    d = cam.depth(X)
    if not np.any(d > 0.5):
        return 0.0
    if not np.all(d > 0.5):
        return float("inf")  # partly behind the camera: very close
    p = cam.project(X)
    W, H = cam.size
    if not (p[:, 0].max() > -margin * W and p[:, 0].min() < (1 + margin) * W and
            p[:, 1].max() > -margin * H and p[:, 1].min() < (1 + margin) * H):
        return 0.0
    return float(np.max(p.max(axis=0) - p.min(axis=0)))


def _road_pattern(scen: Scenario) -> tuple[float, ...]:
    r = scen.road
    bend = (r.curve_start, r.curve_radius)
    if r.directions == 1:  # one carriageway centred on y = 0: the pattern starts at its edge
        if r.lanes % 2:  # a lane is centred on y = 0
            return (r.lane_width, -r.lane_width / 2, (r.carriageway_width + r.lane_width) / 2, *bend)
        return (r.lane_width, 0.0, r.carriageway_width / 2, *bend)
    return (r.lane_width, r.median / 2, r.carriageway_width, *bend)
