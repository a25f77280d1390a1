"""Training data for the vehicle segmenter: randomised synthetic scenes rendered by ``gst_trafficcal.synth``.

Every scene is a random variation of the renderer's presets (camera height, side, pan, tilt, roll and focal length;
lanes and directions; traffic density up to jams with occlusions; day, overcast, dusk, night, low contrast; noise,
blur, motion blur, shake, JPEG compression; catalogue models, generic cars of every body style and, when
../shared has them, Kenney's low-poly meshes; road surfaces from dark asphalt to light concrete).  Seeds start at
1000: the benchmarks use seeds 1, 2 and the demo 7, and no BrnoCompSpeed background (replay mode) is ever rendered here.

Each frame of a scene goes through the run-time path (:mod:`gst_trafficcal.detection.seginput`: reduction to the
work size, running-average background), so the stored background carries the same ghosts as at run time.  A
sample (one npz per kept frame, uint8) holds ``frame`` and ``background`` (work size, BGR), ``fg`` (fraction of
each work pixel covered by vehicles, 0..255, from the renderer's exact id mask) and ``inst`` (vehicle instance per
work pixel, 0 = none, 255 = unknown).

    .venv/bin/python -m training.vehicleseg.data --out /tmp/vseg_data --scenes 0:120
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from gst_trafficcal.detection.seginput import RunningBackground, WorkGeometry, to_work
from gst_trafficcal.errors import TrafficcalError
from gst_trafficcal.synth.scenario import load_preset

SEED_BASE = 1000  # held-out discipline: benchmark scenes use seeds 1, 2 and 7
KENNEY = Path(__file__).resolve().parents[2] / ".." / "shared" / "models" / "vehicles" / "kenney_car_kit"
BASES = ("highway_day", "country_two_way", "right_side_oneway", "curve", "centre_overpass", "left_side")
RESOLUTIONS = ((960, 540), (960, 540), (960, 540), (640, 360), (800, 600), (1280, 720))
KENNEY_FOR = {"sedan": ("sedan.glb", "sedan-sports.glb", "taxi.glb", "police.glb"),
              "hatchback": ("hatchback-sports.glb",), "suv": ("suv.glb", "suv-luxury.glb"),
              "van": ("van.glb", "delivery.glb")}


@dataclasses.dataclass
class SceneRecipe:
    """How one training scene is made and sampled (stored next to its samples)."""

    index: int
    seed: int
    base: str
    scenario: dict
    jpeg_quality: int  # 0 = no compression
    kenney_share: float
    work_width: int
    every: int  # keep every n-th frame after ``start`` seconds
    start: float
    surface: str = "asphalt"  # road-surface kind (:func:`road_surface`)
    road_grey: float | None = None  # measured after rendering (:func:`road_grey`)


PROFILES = ("base", "outline", "overhead")
SURFACES = ("mixed", "asphalt")
OUTLINE_RESOLUTIONS = ((960, 540), (1280, 720), (1920, 1080))


def road_surface(road, rng: np.random.Generator) -> str:
    """Draw the road surface (``RoadSpec.surface``, ``surface_texture``, ``joints``) from dark asphalt to light
    concrete: the first model saw only the renderer's dark asphalt (~65 grey levels) and made the boxes of cars on
    BrnoCompSpeed's light roads (140-190 grey levels) too tall; about a third of the scenes keep the dark asphalt
    unchanged.  Returns the kind drawn."""
    kind = str(rng.choice(["asphalt", "worn", "concrete"], p=[0.35, 0.30, 0.35]))
    if kind == "asphalt":
        return kind
    tint = rng.normal(0.0, 0.012, 3)
    if kind == "worn":  # light, worn asphalt: lighter aggregate, less contrast
        albedo, road.surface_texture = rng.uniform(0.40, 0.62), float(rng.uniform(0.4, 1.2))
    else:  # concrete slabs, warm grey, faint texture, joints in most
        albedo, road.surface_texture = rng.uniform(0.55, 0.82), float(rng.uniform(0.15, 0.8))
        tint += np.array([0.01, 0.0, -0.03])
        road.joints = float(rng.uniform(3.5, 6.5)) if rng.random() < 0.7 else 0.0
    road.surface = [round(float(np.clip(albedo + t, 0.05, 0.95)), 4) for t in tint]
    return kind


def outline_lighting(scen, rng: np.random.Generator) -> None:
    """The ``outline`` profile's light and picture, drawn over a base recipe: the scenes where the first model's
    outlines were too large — low sun with long hard shadows, overcast light whose soft contact shadow is the only
    shadow, dusk — at up to 1080p (the replays' size, where a work pixel is 4 frame pixels), busier traffic."""
    light = scen.lighting
    kind = str(rng.choice(["low_sun", "overcast", "day", "dusk", "night"], p=[0.32, 0.36, 0.12, 0.12, 0.08]))
    light.preset = "day" if kind == "low_sun" else kind
    light.sun_elevation = float(rng.uniform(8, 25) if kind in ("low_sun", "dusk") else rng.uniform(25, 70))
    light.contrast = float(rng.choice([rng.uniform(0.5, 0.8), rng.uniform(0.8, 1.2)], p=[0.3, 0.7]))
    scen.camera.resolution = list(OUTLINE_RESOLUTIONS[int(rng.integers(len(OUTLINE_RESOLUTIONS)))])
    tr = scen.traffic
    tr.flow = float(min(2500.0, tr.flow * rng.uniform(1.0, 1.6)))


def overhead_view(scen, rng: np.random.Generator) -> None:
    """The ``overhead`` profile's camera, light and picture, drawn over a base recipe: a camera above the lanes
    looking down the road, as in every BrnoCompSpeed view, where the first models outlined approaching vehicles a
    work pixel behind where they are and took soft shadows beside light cars into them (docs/tracking.md "The
    replays' boxes trail their vehicles") -- large, near vehicles seen head-on and from behind, at up to 1080p,
    under overcast light and sun from any side."""
    from gst_trafficcal.synth.scene import RoadLayout

    scen.road.curve_radius = 0.0 if rng.random() < 0.8 else scen.road.curve_radius
    scen.road.lanes = int(rng.integers(1, 4))
    lane = RoadLayout(scen.road).lane_centre(int(rng.choice(scen.traffic.directions)),
                                             int(rng.integers(scen.road.lanes)))
    cam = scen.camera
    cam.height = float(rng.uniform(6.0, 14.0))
    cam.offset = float(lane + rng.uniform(-2.0, 2.0))
    cam.pan = float(rng.normal(0.0, 4.0))
    cam.tilt = float(np.clip(rng.normal(10.0 + cam.height * 1.2, 4.0), 8.0, 40.0))
    cam.roll = float(np.clip(rng.normal(0.0, 3.0), -8.0, 8.0))
    cam.hfov = float(max(30.0, rng.uniform(28.0, 60.0)))  # the scenario allows 30-90
    cam.resolution = list(OUTLINE_RESOLUTIONS[int(rng.integers(len(OUTLINE_RESOLUTIONS)))])
    light = scen.lighting
    kind = str(rng.choice(["overcast", "day", "low_sun", "dusk"], p=[0.4, 0.35, 0.15, 0.1]))
    light.preset = "day" if kind == "low_sun" else kind
    light.sun_elevation = float(rng.uniform(8, 25) if kind in ("low_sun", "dusk") else rng.uniform(25, 70))


def random_recipe(index: int, duration: float = 14.0, work_width: int = 480, profile: str = "base",
                  surfaces: str = "mixed") -> SceneRecipe:
    """A random scene for training index ``index`` (seed ``SEED_BASE + index``), reproducible; ``profile``
    ``outline`` redraws light and picture size (:func:`outline_lighting`) from a separate random stream, so the
    base recipes stay as they were; ``surfaces`` ``mixed`` draws the road surface (:func:`road_surface`) from
    another one (``asphalt``: the renderer's dark asphalt, the first model's data)."""
    seed = SEED_BASE + index
    rng = np.random.default_rng([seed, 7])
    base = str(rng.choice(BASES))
    scen = load_preset(base)
    cam = scen.camera
    side = rng.choice([-1.0, 1.0], p=[0.7, 0.3])
    cam.height = float(rng.uniform(4.5, 18.0))
    cam.offset = float(side * rng.uniform(0.0, 14.0)) if base != "centre_overpass" else float(rng.uniform(-2, 2))
    cam.pan = float(-side * rng.uniform(0.0, 32.0))
    cam.tilt = float(np.clip(rng.normal(8.0 + cam.height * 0.8, 4.0), 4.0, 35.0))
    cam.roll = float(np.clip(rng.normal(0.0, 5.0), -15.0, 15.0))
    cam.hfov = float(rng.uniform(30.0, 85.0))
    cam.resolution = list(RESOLUTIONS[int(rng.integers(len(RESOLUTIONS)))])
    road = scen.road
    if base not in ("country_two_way", "right_side_oneway"):
        road.lanes = int(rng.integers(1, 5))
        road.directions = int(rng.choice([1, 2], p=[0.25, 0.75]))
    road.curve_radius = float(rng.choice([0.0, 0.0, 1.0]) * rng.choice([-1, 1]) * rng.uniform(300, 2000))
    road.trees = int(rng.integers(0, 80))
    tr = scen.traffic
    density = rng.choice(["sparse", "normal", "dense", "jam"], p=[0.15, 0.45, 0.25, 0.15])
    tr.flow = float({"sparse": rng.uniform(150, 400), "normal": rng.uniform(400, 1000),
                     "dense": rng.uniform(1000, 1800), "jam": rng.uniform(1600, 2500)}[density])
    tr.speed = float({"jam": rng.uniform(20, 45), "dense": rng.uniform(40, 80)}.get(density, rng.uniform(60, 130)))
    tr.speed_std = float(rng.uniform(3, 15))
    tr.min_speed = min(tr.min_speed, tr.speed * 0.5)
    tr.headway = float(rng.uniform(0.5, 1.2) if density in ("dense", "jam") else rng.uniform(0.8, 2.0))
    tr.directions = [0, 1] if road.directions == 2 else [int(rng.integers(0, 2))]
    tr.mix = {"sedan": 0.3, "estate": 0.18, "hatchback": 0.2, "suv": 0.12, "van": 0.09,
              "truck": float(rng.uniform(0.02, 0.1)), "bus": float(rng.uniform(0.0, 0.04)),
              "motorcycle": float(rng.uniform(0.0, 0.04))}
    if rng.random() < 0.4:  # named catalogue models as well as generic cars
        tr.models = {"skoda_octavia_mk1_liftback": 0.1, "skoda_octavia_mk2_combi": 0.08, "vw_golf_mk6_hatchback": 0.08,
                     "skoda_superb_mk2_liftback": 0.05, "skoda_fabia_mk2_hatchback": 0.06, "vw_tiguan_mk1_suv": 0.05,
                     "ford_transit_mk7_van_swb_low_roof": 0.03}
    light = scen.lighting
    light.preset = str(rng.choice(["day", "overcast", "dusk", "night"], p=[0.45, 0.25, 0.15, 0.15]))
    light.sun_azimuth = float(rng.uniform(0, 360))
    light.sun_elevation = float(rng.uniform(5, 25) if light.preset == "dusk" else rng.uniform(15, 75))
    light.contrast = float(rng.choice([rng.uniform(0.45, 0.75), rng.uniform(0.8, 1.25)], p=[0.25, 0.75]))
    light.haze = float(rng.uniform(0.0, 0.5))
    im = scen.imaging
    im.fps = 12.5
    im.noise = float(rng.uniform(0.5, 6.0))
    im.blur = float(rng.uniform(0.0, 1.4))
    im.motion_blur = float(rng.choice([0.0, rng.uniform(0.002, 0.015)], p=[0.7, 0.3]))
    im.shake = float(rng.choice([0.0, rng.uniform(0.02, 0.12)], p=[0.8, 0.2]))
    im.vignette = float(rng.uniform(0.0, 0.35))
    if profile == "outline":
        outline_lighting(scen, np.random.default_rng([seed, 17]))
    elif profile == "overhead":
        overhead_view(scen, np.random.default_rng([seed, 23]))
    elif profile != "base":
        raise ValueError(f"unknown data profile {profile!r} (one of {', '.join(PROFILES)})")
    if surfaces == "mixed":
        surface = road_surface(scen.road, np.random.default_rng([seed, 19]))
    elif surfaces == "asphalt":
        surface = "asphalt"
    else:
        raise ValueError(f"unknown surfaces {surfaces!r} (one of {', '.join(SURFACES)})")
    scen.duration = float(duration)
    scen.seed = seed
    scen.name = f"vseg_{index}"
    scen.validate(f"training scene {index}")
    quality = int(rng.choice([0, int(rng.integers(25, 90))], p=[0.4, 0.6]))
    return SceneRecipe(index=index, seed=seed, base=base, scenario=scen.to_dict(), jpeg_quality=quality,
                       kenney_share=float(rng.uniform(0.1, 0.35)) if KENNEY.is_dir() else 0.0,
                       work_width=work_width, every=3, start=2.0, surface=surface)


def kenney_factory(share: float, seed: int):
    """A traffic ``model_factory``: the catalogue's models and body styles, a ``share`` of the passenger cars and
    vans drawn with one of Kenney's meshes instead of the procedural one (other shapes for the same class)."""
    from gst_trafficcal.synth.traffic import draw_model

    rng = np.random.default_rng([seed, 11])

    def factory(kind, name, r):
        model = draw_model(kind, name, r)
        files = KENNEY_FOR.get(model.body_style)
        if files and model.mesh is None and rng.random() < share:
            model = dataclasses.replace(model, mesh=(KENNEY / files[int(rng.integers(len(files)))]).resolve())
        return model

    return factory


class SampleWriter:
    """Receives the renderer's frames (``generate(keep_masks=...)`` calls ``append``), runs the run-time input
    path on every frame and writes the kept ones."""

    def __init__(self, recipe: SceneRecipe, out: Path, frame_size: tuple[int, int]) -> None:
        self.recipe, self.out = recipe, out
        self.geometry = WorkGeometry(frame_size, recipe.work_width)
        self.background = RunningBackground()
        self.rng = np.random.default_rng([recipe.seed, 13])
        self.count = 0
        self.frames = 0
        self.first: tuple[np.ndarray, np.ndarray] | None = None  # first kept frame (BGR as delivered) and its ids

    def append(self, item) -> None:
        t, rgb, ids, _recs, _items, shake = item
        bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
        q = self.recipe.jpeg_quality
        if q:
            ok, enc = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, q])
            bgr = cv2.imdecode(enc, cv2.IMREAD_COLOR)
        work = to_work(bgr, self.geometry)
        background = self.background.update(work, t)
        i = self.frames
        self.frames += 1
        early = i in (2, 6, 12)  # a few samples while the background is still forming
        if not early and (t < self.recipe.start or i % self.recipe.every):
            return
        if shake is not None:  # the id mask is drawn unshaken; the delivered frame is warped
            h, w = ids.shape
            ids = cv2.warpPerspective(ids, shake, (w, h), flags=cv2.INTER_NEAREST, borderValue=0)
        if self.first is None and not early:
            self.first = (bgr, ids)
        size = self.geometry.size
        fg = cv2.resize((ids > 0).astype(np.float32), size, interpolation=cv2.INTER_AREA)
        inst = cv2.resize(ids, size, interpolation=cv2.INTER_NEAREST)
        np.savez_compressed(self.out / f"s{self.recipe.index:05d}_{i:04d}.npz", frame=work, background=background,
                            fg=np.round(fg * 255).astype(np.uint8), inst=inst, t=np.float32(t))
        self.count += 1


def road_grey(scen, bgr: np.ndarray, ids: np.ndarray) -> float | None:
    """Median grey level of the road in a delivered frame: lane centres +- 1 m, 12-50 m ahead of the camera, where
    no vehicle is (None when too little of it is in view)."""
    from gst_trafficcal.synth.camera import build_camera
    from gst_trafficcal.synth.scene import RoadLayout

    cam, lay = build_camera(scen.camera), RoadLayout(scen.road)
    pts = []
    for d in range(scen.road.directions):
        for lane in range(scen.road.lanes):
            c = lay.lane_centre(d, lane)
            xs, ys = np.meshgrid(np.linspace(12.0, 50.0, 40), np.linspace(c - 1.0, c + 1.0, 5))
            pts.append(np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], 1))
    X = np.concatenate(pts)
    X = X[cam.depth(X) > 1.0]
    uv = np.round(cam.project(X)).astype(int)
    h, w = ids.shape
    ok = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    uv = uv[ok]
    uv = uv[ids[uv[:, 1], uv[:, 0]] == 0]
    if len(uv) < 20:
        return None
    grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    return float(np.median(grey[uv[:, 1], uv[:, 0]]))


def render_scene(recipe: SceneRecipe, out: Path) -> int:
    """Render one recipe, writing its samples into ``out``; the number of samples (and the road's grey level in
    the first kept frame, :func:`road_grey`, as ``recipe.road_grey`` in the scene record)."""
    from gst_trafficcal.synth.generate import generate
    from gst_trafficcal.synth.scenario import scenario_from_dict

    scen = scenario_from_dict(recipe.scenario, f"training scene {recipe.index}")
    writer = SampleWriter(recipe, out, tuple(scen.camera.resolution))
    tmp = Path(tempfile.mkdtemp(prefix="vseg_scene_"))
    try:
        factory = kenney_factory(recipe.kenney_share, recipe.seed) if recipe.kenney_share > 0 else None
        generate(scen, tmp, write_video=False, keep_masks=writer, model_factory=factory)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    recipe.road_grey = road_grey(scen, *writer.first) if writer.first is not None else None
    return writer.count


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--scenes", default="0:100", help="training scene indices START:STOP (seeds 1000+index)")
    ap.add_argument("--duration", type=float, default=14.0)
    ap.add_argument("--work-width", type=int, default=480)
    ap.add_argument("--profile", choices=PROFILES, default="base",
                    help="outline: low sun, overcast, dusk, up to 1080p, busier (see outline_lighting); overhead: a "
                         "camera above the lanes looking down the road, up to 1080p (see overhead_view)")
    ap.add_argument("--surfaces", choices=SURFACES, default="mixed",
                    help="mixed: dark asphalt to light concrete (road_surface); asphalt: the first model's data")
    args = ap.parse_args(argv)
    a, b = (int(v) for v in args.scenes.split(":"))
    args.out.mkdir(parents=True, exist_ok=True)
    for index in range(a, b):
        marker = args.out / f"scene_{index:05d}.json"
        if marker.exists():
            continue
        t0 = time.perf_counter()
        for attempt in range(5):  # a random camera may not see the road: draw the next variation
            recipe = random_recipe(index + 100000 * attempt, args.duration, args.work_width, args.profile,
                                   args.surfaces)
            try:
                n = render_scene(recipe, args.out)
                break
            except TrafficcalError as exc:
                print(f"scene {index}: {exc}; redrawing", file=sys.stderr)
        else:
            continue
        info = dataclasses.asdict(recipe) | {"samples": n, "seconds": round(time.perf_counter() - t0, 1),
                                             "profile": args.profile, "surfaces": args.surfaces}
        marker.write_text(json.dumps(info, indent=1) + "\n", encoding="utf-8")
        print(f"scene {index} ({recipe.base}, {recipe.scenario['lighting']['preset']}, {recipe.surface} road "
              f"{recipe.road_grey if recipe.road_grey is None else round(recipe.road_grey)}, "
              f"{recipe.scenario['traffic']['flow']:.0f} veh/h/lane): {n} samples in {info['seconds']} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
