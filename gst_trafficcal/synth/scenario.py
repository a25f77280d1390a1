"""Scenario records for the synthetic traffic generator, loaded from YAML/JSON with strict field checks.

A scenario file is a mapping with the sections ``camera``, ``road``, ``traffic``, ``lighting``, ``imaging``,
``measurement`` (every field optional, defaults below) plus ``name``, ``description``, ``duration``, ``seed`` and
``base`` (the name of a preset whose values this file overrides).  A mistyped field is an
:class:`InputError` that names it and suggests the closest valid name, so a typo never silently falls back
to a default.

World frame (metres): x along the road in the traffic direction of the first carriageway, y to the left,
z up, road plane z = 0, road centre line y = 0.  The camera stands at (0, ``camera.offset``, ``camera.height``).
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, get_args, get_origin, get_type_hints

import yaml

from ..errors import InputError

PRESET_DIR = Path(__file__).resolve().parent / "presets"
BODY_STYLES_DEFAULT = ("sedan", "estate", "hatchback", "suv", "van", "bus", "truck", "motorcycle")
LIGHTING_PRESETS = ("day", "overcast", "dusk", "night")
ROAD_SURFACE_DEFAULT = (0.30, 0.30, 0.31)  # dark asphalt (RGB albedo)


@dataclass
class CameraSpec:
    """Pinhole camera pose and intrinsics (principal point at the image centre, square pixels)."""

    height: float = 8.0  # metres above the road, 4..20
    offset: float = -6.0  # lateral position y of the camera (metres, + = left of the traffic direction)
    pan: float = 15.0  # degrees, + turns the view left of the road direction (world +x)
    tilt: float = 14.0  # degrees below the horizontal
    roll: float = 0.0  # degrees, + turns the image clockwise
    hfov: float = 60.0  # horizontal field of view in degrees, 30..90
    resolution: list[int] = field(default_factory=lambda: [960, 540])  # width, height; 320x240..1920x1080

    def validate(self, where: str) -> None:
        _check_range(where, "camera.height", self.height, 4.0, 20.0)
        _check_range(where, "camera.hfov", self.hfov, 30.0, 90.0)
        _check_range(where, "camera.tilt", self.tilt, 0.5, 80.0)
        _check_range(where, "camera.pan", self.pan, -80.0, 80.0)
        _check_range(where, "camera.roll", self.roll, -45.0, 45.0)
        _check_range(where, "camera.offset", self.offset, -60.0, 60.0)
        if len(self.resolution) != 2:
            raise InputError(f"{where}: field 'camera.resolution' must be [width, height]")
        w, h = self.resolution
        if not (320 <= w <= 1920 and 240 <= h <= 1080) or w % 2 or h % 2:
            raise InputError(f"{where}: field 'camera.resolution' must be even sizes from 320x240 to 1920x1080, "
                             f"got {w}x{h}")


@dataclass
class RoadSpec:
    """A straight road: one or two carriageways, markings, shoulders, verges and roadside furniture."""

    lanes: int = 2  # lanes per direction, 1..4
    directions: int = 2  # 1: one-way road, 2: two carriageways (traffic along +x on the right, -x on the left)
    lane_width: float = 3.5
    median: float = 1.0  # width between the two carriageways' inner edge lines (metres)
    median_barrier: bool = True  # concrete barrier in the median (two-way roads only)
    shoulder: float = 2.0  # paved shoulder outside the outer edge line
    verge: float = 8.0  # grass beyond the shoulder
    line_width: float = 0.15  # lane divider width
    edge_line_width: float = 0.25
    dash: float = 3.0  # dashed lane divider: dash length (metres)
    gap: float = 9.0  # and gap length
    guard_rails: bool = True
    pole_spacing: float = 50.0  # lamp posts along the outer edges; 0 = none
    signs: int = 3  # traffic signs along the verges
    trees: int = 40  # trees on the verges and beyond
    curve_radius: float = 0.0  # 0 = straight; else the road bends left (+) or right (-) with this radius (m)
    curve_start: float = 120.0  # where the bend starts (metres ahead of the camera); lines stay before it
    length: float = 600.0  # modelled road length ahead of the camera (metres)
    behind: float = 60.0  # modelled road length behind the camera (metres)
    # road-surface appearance (lanes and paved shoulders): albedo RGB 0..1 before lighting (the default is dark
    # asphalt; worn asphalt ~0.45-0.55, concrete ~0.6-0.8), contrast of its texture (grain, patches, wheel paths,
    # oil strips: 1 = asphalt's, 0 = flat) and transverse joints of a concrete pavement every ``joints`` metres
    surface: list[float] = field(default_factory=lambda: list(ROAD_SURFACE_DEFAULT))
    surface_texture: float = 1.0
    joints: float = 0.0  # 0 = none (asphalt); concrete slabs are typically 4-6 m long

    def validate(self, where: str) -> None:
        _check_range(where, "road.lanes", self.lanes, 1, 4)
        if self.directions not in (1, 2):
            raise InputError(f"{where}: field 'road.directions' must be 1 or 2, got {self.directions}")
        _check_range(where, "road.lane_width", self.lane_width, 2.5, 5.0)
        _check_range(where, "road.median", self.median, 0.0, 30.0)
        _check_range(where, "road.shoulder", self.shoulder, 0.0, 5.0)
        _check_range(where, "road.verge", self.verge, 0.0, 100.0)
        _check_range(where, "road.dash", self.dash, 0.5, 30.0)
        _check_range(where, "road.gap", self.gap, 0.0, 60.0)
        _check_range(where, "road.length", self.length, 100.0, 3000.0)
        _check_range(where, "road.behind", self.behind, 0.0, 500.0)
        _check_range(where, "road.pole_spacing", self.pole_spacing, 0.0, 500.0)
        if self.curve_radius != 0:
            _check_range(where, "road.curve_radius (absolute value)", abs(self.curve_radius), 150.0, 100000.0)
        _check_range(where, "road.curve_start", self.curve_start, 20.0, 3000.0)
        if len(self.surface) != 3:
            raise InputError(f"{where}: field 'road.surface' must be an RGB colour [r, g, b] (0.02..0.95 each), "
                             f"got {self.surface!r}")
        for i, v in enumerate(self.surface):
            _check_range(where, f"road.surface[{i}]", v, 0.02, 0.95)
        _check_range(where, "road.surface_texture", self.surface_texture, 0.0, 2.0)
        if self.joints != 0:
            _check_range(where, "road.joints (0 = none)", self.joints, 2.0, 50.0)

    @property
    def carriageway_width(self) -> float:
        return self.lanes * self.lane_width


@dataclass
class TrafficSpec:
    """Per-lane Poisson arrivals with normally distributed desired speeds and a vehicle-class mix."""

    flow: float = 600.0  # vehicles per hour per lane
    speed: float = 80.0  # mean speed km/h
    speed_std: float = 10.0
    min_speed: float = 20.0
    max_speed: float = 160.0
    headway: float = 1.0  # minimum time gap to the vehicle ahead (seconds)
    lateral_jitter: float = 0.25  # std of the lateral position within the lane (metres)
    mix: dict[str, float] = field(default_factory=lambda: {
        "sedan": 0.34, "estate": 0.2, "hatchback": 0.2, "suv": 0.1, "van": 0.08, "truck": 0.04, "bus": 0.02,
        "motorcycle": 0.02})
    models: dict[str, float] = field(default_factory=dict)  # named catalogue models (name -> share of traffic)
    # traffic directions: 0 = along +x (away from a camera looking along +x), 1 = along -x (towards it); a
    # one-way road carries only the first one listed
    directions: list[int] = field(default_factory=lambda: [0, 1])

    def validate(self, where: str) -> None:
        _check_range(where, "traffic.flow", self.flow, 0.0, 3000.0)
        _check_range(where, "traffic.speed", self.speed, 5.0, 250.0)
        _check_range(where, "traffic.speed_std", self.speed_std, 0.0, 60.0)
        _check_range(where, "traffic.headway", self.headway, 0.3, 10.0)
        if not self.min_speed < self.max_speed:
            raise InputError(f"{where}: field 'traffic.min_speed' must be below 'traffic.max_speed'")
        for name, share in {**self.mix, **self.models}.items():
            if not (isinstance(share, (int, float)) and share >= 0):
                raise InputError(f"{where}: share of {name!r} in the traffic mix must be a number >= 0")
        if sum(self.mix.values()) + sum(self.models.values()) <= 0:
            raise InputError(f"{where}: field 'traffic.mix' must give at least one class a positive share")
        bad = [d for d in self.directions if d not in (0, 1)]
        if bad or not self.directions:
            raise InputError(f"{where}: field 'traffic.directions' must list 0 and/or 1, got {self.directions}")


@dataclass
class LightingSpec:
    """Sun, ambient light and sky; ``preset`` sets the mood, the numbers refine it."""

    preset: str = "day"  # day | overcast | dusk | night
    sun_azimuth: float = 135.0  # degrees, direction the sunlight comes from, counter-clockwise from world +x
    sun_elevation: float = 40.0  # degrees above the horizon
    contrast: float = 1.0  # <1 washes the image out (haze, low-contrast sensors)
    haze: float = 0.15  # aerial perspective: fraction of sky colour mixed in at 500 m
    lamps: bool | None = None  # street lamps lit (default: at night)

    def validate(self, where: str) -> None:
        if self.preset not in LIGHTING_PRESETS:
            _unknown(where, "lighting.preset", self.preset, LIGHTING_PRESETS, what="value")
        _check_range(where, "lighting.sun_elevation", self.sun_elevation, 2.0, 90.0)
        _check_range(where, "lighting.contrast", self.contrast, 0.1, 1.5)
        _check_range(where, "lighting.haze", self.haze, 0.0, 1.0)


@dataclass
class ImagingSpec:
    """The sensor and transmission chain applied to rendered frames."""

    fps: float = 25.0  # 10..50
    noise: float = 2.0  # std of additive sensor noise (8-bit grey levels)
    blur: float = 0.6  # optics blur (Gaussian sigma in pixels, 0 = none)
    motion_blur: float = 0.0  # exposure time in seconds (vehicles smeared along their image motion)
    shake: float = 0.0  # std of small random camera rotations (degrees)
    shake_hz: float = 1.5  # how fast the shake wanders
    drop_rate: float = 0.0  # fraction of frames dropped (the video keeps real timestamps: a gap)
    bitrate: int = 4000  # H.264 kbit/s
    vignette: float = 0.15  # darkening at the corners (0 = none)

    def validate(self, where: str) -> None:
        _check_range(where, "imaging.fps", self.fps, 10.0, 50.0)
        _check_range(where, "imaging.noise", self.noise, 0.0, 50.0)
        _check_range(where, "imaging.blur", self.blur, 0.0, 5.0)
        _check_range(where, "imaging.motion_blur", self.motion_blur, 0.0, 0.1)
        _check_range(where, "imaging.shake", self.shake, 0.0, 2.0)
        _check_range(where, "imaging.drop_rate", self.drop_rate, 0.0, 0.5)
        _check_range(where, "imaging.bitrate", self.bitrate, 50, 100000)
        _check_range(where, "imaging.vignette", self.vignette, 0.0, 1.0)


@dataclass
class MeasurementSpec:
    """Where the ground truth's measurement lines go (``groundtruth.line_positions``): like BrnoCompSpeed's, in
    the well-resolved part of the road.  Line 0 is the nearest position where a car in every lane stays entirely
    in the frame around its crossing; line 2 the farthest where a typical 4.5 x 1.8 x 1.5 m car in every lane
    still has a 2D box diagonal of ``far_car_span`` x image width; line 1 half-way between."""

    far_car_span: float = 0.06  # smallest car size at the far line, fraction of the image width

    def validate(self, where: str) -> None:
        _check_range(where, "measurement.far_car_span", self.far_car_span, 0.01, 0.3)


@dataclass
class ReplaySpec:
    """Replay a BrnoCompSpeed recording: its cars over its background, under a given calibration."""

    gt_data: str = ""  # path of the recording's gt_data.pkl
    backdrop: str = ""  # its screen.png (default: next to gt_data.pkl)
    calibration: str = ""  # our calibration.json for the recording
    start: float = 0.0  # time window in the recording (seconds)


@dataclass
class Scenario:
    """Everything that defines one synthetic video."""

    name: str = "custom"
    description: str = ""
    duration: float = 30.0
    seed: int = 0
    camera: CameraSpec = field(default_factory=CameraSpec)
    road: RoadSpec = field(default_factory=RoadSpec)
    traffic: TrafficSpec = field(default_factory=TrafficSpec)
    lighting: LightingSpec = field(default_factory=LightingSpec)
    imaging: ImagingSpec = field(default_factory=ImagingSpec)
    measurement: MeasurementSpec = field(default_factory=MeasurementSpec)
    replay: ReplaySpec | None = None

    def validate(self, where: str = "scenario") -> "Scenario":
        _check_range(where, "duration", self.duration, 0.1, 7200.0)
        if not isinstance(self.seed, int) or isinstance(self.seed, bool) or self.seed < 0:  # numpy's seeds
            raise InputError(f"{where}: field 'seed' must be a whole number from 0, got {self.seed!r}")
        self.camera.validate(where)
        self.road.validate(where)
        self.traffic.validate(where)
        self.lighting.validate(where)
        self.imaging.validate(where)
        self.measurement.validate(where)
        if self.road.directions == 1:
            self.traffic.directions = self.traffic.directions[:1]
        if self.replay is not None and not self.replay.gt_data:
            raise InputError(f"{where}: field 'replay.gt_data' is required in replay mode")
        return self

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


# ---------------------------------------------------------------------------- loading


def _check_range(where: str, name: str, value: Any, lo: float, hi: float) -> None:
    if not (isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
            and lo <= value <= hi):
        raise InputError(f"{where}: field {name!r} must be a number from {lo:g} to {hi:g}, got {value!r}")


def _unknown(where: str, name: str, value: str, valid, what: str = "field") -> None:
    close = difflib.get_close_matches(str(value), list(valid), n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else f" (valid: {', '.join(sorted(valid))})"
    if what == "field":
        raise InputError(f"{where}: unknown field {name!r}{hint}")
    raise InputError(f"{where}: field {name!r} has unknown value {value!r}{hint}")


def _convert(where: str, name: str, value: Any, hint: Any) -> Any:
    """Check ``value`` against a type hint (dataclass, list, dict, scalar) and convert it."""
    origin = get_origin(hint)
    if dataclasses.is_dataclass(hint):
        return _build(hint, value, where, name + ".")
    if origin is list:
        if not isinstance(value, list):
            raise InputError(f"{where}: field {name!r} must be a list, got {value!r}")
        (item,) = get_args(hint)
        return [_convert(where, f"{name}[{i}]", v, item) for i, v in enumerate(value)]
    if origin is dict:
        if not isinstance(value, dict):
            raise InputError(f"{where}: field {name!r} must be a mapping, got {value!r}")
        _, vt = get_args(hint)
        return {str(k): _convert(where, f"{name}.{k}", v, vt) for k, v in value.items()}
    args = [a for a in get_args(hint) if a is not type(None)]
    if args:  # Optional[...] / unions
        if value is None:
            return None
        return _convert(where, name, value, args[0])
    if hint is bool:
        if not isinstance(value, bool):
            raise InputError(f"{where}: field {name!r} must be true or false, got {value!r}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or float(value) != int(value):
            raise InputError(f"{where}: field {name!r} must be an integer, got {value!r}")
        return int(value)
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InputError(f"{where}: field {name!r} must be a number, got {value!r}")
        return float(value)
    if hint is str:
        if not isinstance(value, str):
            raise InputError(f"{where}: field {name!r} must be a string, got {value!r}")
        return value
    return value


def _build(cls, data: Any, where: str, prefix: str = ""):
    if not isinstance(data, dict):
        raise InputError(f"{where}: section {prefix.rstrip('.') or 'scenario'!r} must be a mapping, got {data!r}")
    hints = get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    kwargs = {}
    for key, value in data.items():
        if key not in names:
            _unknown(where, prefix + str(key), str(key), names)
        kwargs[key] = _convert(where, prefix + key, value, hints[key])
    return cls(**kwargs)


def _merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict) and k not in ("mix", "models"):
            out[k] = _merge(out[k], v)
        else:
            out[k] = v
    return out


def _read_mapping(path: Path) -> dict:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: scenario file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read scenario file ({exc})") from None
    try:
        data = json.loads(text) if path.suffix.lower() == ".json" else yaml.safe_load(text)
    except (json.JSONDecodeError, yaml.YAMLError) as exc:
        raise InputError(f"{path}: corrupt scenario file ({str(exc).splitlines()[0]})") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: a scenario file must hold a mapping of fields")
    return data


def _resolve(data: dict, where: str, depth: int = 0) -> dict:
    """Expand ``base: <preset>`` inheritance."""
    if "base" not in data:
        return data
    if depth > 8:
        raise InputError(f"{where}: 'base' presets refer to each other in a loop")
    base_name = data["base"]
    if not isinstance(base_name, str):
        raise InputError(f"{where}: field 'base' must be a preset name")
    base_path = PRESET_DIR / f"{base_name}.yaml"
    if not base_path.exists():
        _unknown(where, "base", base_name, preset_names(), what="value")
    base = _resolve(_read_mapping(base_path), str(base_path), depth + 1)
    base.pop("description", None)
    over = {k: v for k, v in data.items() if k != "base"}
    return _merge(base, over)


def scenario_from_dict(data: dict, where: str = "scenario") -> Scenario:
    """Build and validate a scenario from a plain mapping (``base`` presets expanded)."""
    data = _resolve(data, where)
    scen = _build(Scenario, data, where)
    return scen.validate(where)


def load_scenario(path: str | Path) -> Scenario:
    """Read a YAML or JSON scenario file."""
    path = Path(path)
    data = _read_mapping(path)
    scen = scenario_from_dict(data, str(path))
    if scen.replay is not None:  # replay paths are relative to the scenario file
        base = path.resolve().parent
        r = scen.replay
        r.gt_data = str(base / r.gt_data) if r.gt_data else ""
        r.backdrop = str(base / r.backdrop) if r.backdrop else ""
        r.calibration = str(base / r.calibration) if r.calibration else ""
    if "name" not in data:
        scen.name = path.stem
    return scen


def preset_names() -> list[str]:
    return sorted(p.stem for p in PRESET_DIR.glob("*.yaml"))


def load_preset(name: str) -> Scenario:
    """A named preset from ``gst_trafficcal/synth/presets``."""
    path = PRESET_DIR / f"{name}.yaml"
    if not path.exists():
        close = difflib.get_close_matches(name, preset_names(), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise InputError(f"unknown preset {name!r}{hint}; `trafficcal synth --list-presets` lists them")
    scen = load_scenario(path)
    scen.name = name
    return scen


def list_presets() -> list[tuple[str, str]]:
    """(name, one-line description) of every preset."""
    out = []
    for name in preset_names():
        data = _read_mapping(PRESET_DIR / f"{name}.yaml")
        out.append((name, str(data.get("description", "")).strip().splitlines()[0] if data.get("description")
                    else ""))
    return out
