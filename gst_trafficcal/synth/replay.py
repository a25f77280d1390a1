"""Replay mode: a BrnoCompSpeed recording's cars rendered over its own background.

Given the recording's ``gt_data.pkl``, its ``screen.png`` and a calibration of its camera, every ground-truth
car whose crossing of measurement line 0 (the crossing the evaluation matches on) falls in the time window
becomes a vehicle that drives down the middle of its real lane at its real speed and crosses line 0 at the
real time.  The world frame is the calibration's (origin on the road below the camera, x towards VP1), so
the renderer's camera is exactly ``calibration.camera.to_KRt()``; gt_data.pkl keeps the recording's own
lines and distance segments, with the cars' times shifted to the window.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..brnocompspeed import GroundTruth, GtCar, LineCrossing, load_gt_data
from ..calibration import load_calibration
from ..errors import InputError
from ..geometry import Camera
from .camera import SynthCamera
from .scenario import Scenario
from .traffic import Traffic, Vehicle, _shares, draw_model


@dataclass
class Replay:
    cam: SynthCamera
    calibration: Camera
    traffic: Traffic
    backdrop: np.ndarray  # RGB, camera size
    gt: GroundTruth  # the recording's ground truth, cars in the window, times shifted
    layout: None = None
    lines: None = None


def _line_points(line: np.ndarray, W: int) -> np.ndarray:
    """Two image points on a homogeneous line (at x = 0 and x = W, or y = 0 / H for near-vertical lines)."""
    a, b, c = line
    if abs(b) > abs(a):
        xs = np.array([0.0, float(W)])
        return np.column_stack([xs, -(a * xs + c) / b])
    ys = np.array([0.0, 1000.0])
    return np.column_stack([-(b * ys + c) / a, ys])


def _world_line(cam: Camera, line: np.ndarray, W: int) -> tuple[np.ndarray, np.ndarray]:
    p = cam.to_world(_line_points(line, W))[:, :2]
    return p[0], p[1] - p[0]


def _intersect_y(p: np.ndarray, d: np.ndarray, y: float) -> float:
    """x where the world line p + s d meets y = const."""
    if abs(d[1]) < 1e-12:
        return float(p[0])
    s = (y - p[1]) / d[1]
    return float(p[0] + s * d[0])


def _lane_centre_y(cam: Camera, gt: GroundTruth, lane: int, W: int) -> float:
    """World y of the middle of lane ``lane`` (between lane dividing lines lane and lane + 1) at line 0."""
    m0 = gt.measurement_lines[0]
    ys = []
    for k in (lane, lane + 1):
        x = np.cross(m0, gt.lane_div_lines[k])
        ys.append(cam.to_world(x[:2] / x[2])[1])
    return float(np.mean(ys))


def _fallback_speeds(gt: GroundTruth) -> dict[int, float]:
    """Median measured speed (km/h) of the recording's cars per lane, and over all lanes under key -1."""
    speeds: dict[int, list[float]] = {}
    for c in gt.cars:
        if c.speed > 0 and np.isfinite(c.speed):
            for lane in c.lanes:
                speeds.setdefault(int(lane), []).append(float(c.speed))
    every = [v for vs in speeds.values() for v in vs]
    out = {lane: float(np.median(vs)) for lane, vs in speeds.items()}
    out[-1] = float(np.median(every)) if every else 60.0
    return out


def prepare_replay(scen: Scenario, rng: np.random.Generator, model_factory=draw_model) -> Replay:
    r = scen.replay
    assert r is not None
    gt = load_gt_data(r.gt_data)
    if not r.calibration:
        raise InputError("replay.calibration is required: a calibration of the recording's camera "
                         "(e.g. from `trafficcal calibrate-manual`)")
    cal = load_calibration(r.calibration)
    if cal.camera is None or cal.camera.scale is None:
        raise InputError(f"{r.calibration}: replay needs a calibration with a scale")
    true = cal.camera
    backdrop_path = Path(r.backdrop) if r.backdrop else Path(r.gt_data).with_name("screen.png")
    img = cv2.imread(str(backdrop_path), cv2.IMREAD_COLOR)
    if img is None:
        raise InputError(f"{backdrop_path}: backdrop image missing or unreadable")
    W, H = cal.image_size
    if (img.shape[1], img.shape[0]) != (W, H):
        raise InputError(f"{backdrop_path}: backdrop is {img.shape[1]}x{img.shape[0]} but the calibration is for "
                         f"{W}x{H}")
    K, R, t = true.to_KRt()
    cam = SynthCamera(K=K, R=R, t=t, size=(W, H))
    backdrop = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)

    # direction of travel along world x: from cars crossing several lines (the same for the whole recording)
    lines_x = []
    centre = _lane_centre_y(true, gt, 0, W)
    for m in gt.measurement_lines:
        p, d = _world_line(true, m, W)
        lines_x.append(_intersect_y(p, d, centre))
    signs = []
    for c in gt.cars:
        if len(c.intersections) >= 2:
            a, b = c.intersections[0], c.intersections[-1]
            dx = lines_x[b.line] - lines_x[a.line]
            signs.append(np.sign(dx) * np.sign(b.video_time - a.video_time))
    sign = 1.0 if not signs or np.mean(signs) >= 0 else -1.0

    t0, t1 = r.start, r.start + scen.duration
    items, probs = _shares(scen.traffic)
    fallback = _fallback_speeds(gt)
    vehicles, cars = [], []
    for c in gt.cars:
        match = c.intersections[-1]
        if not (t0 <= match.video_time < t1) or match.line != 0:
            continue
        (lane,) = sorted(c.lanes)[:1]
        y = _lane_centre_y(true, gt, lane, W)
        p, d = _world_line(true, gt.measurement_lines[0], W)
        x_line = _intersect_y(p, d, y)
        kind, name = items[int(rng.choice(len(items), p=probs))]
        model = model_factory(kind, name, rng)
        # a car without a measured speed (invalid in the dataset, speed 0) still drove past: it gets its lane's
        # median speed instead of standing across line 0 for the whole clip, where it hid the cars behind it
        v = (c.speed if c.speed > 0 else fallback.get(int(lane), fallback[-1])) / 3.6
        L = float(model.length)
        tm = match.video_time - t0
        x_at_zero = x_line - sign * v * tm - sign * L / 2
        vehicles.append(Vehicle(
            id=int(c.car_id), direction=0 if sign > 0 else 1, lane=int(lane), y=y, speed=v, x_at_zero=x_at_zero,
            body_style=getattr(model, "body_style", name), model_name=str(getattr(model, "name", name)), length=L,
            width=float(model.width), height=float(model.height), model=model,
            colour_seed=int(rng.integers(0, 2**31))))
        cars.append(GtCar(car_id=c.car_id, lanes=c.lanes, valid=c.valid, speed=c.speed,
                          intersections=tuple(LineCrossing(x.line, x.video_time - t0) for x in c.intersections),
                          time_intersection_last_shifted=match.video_time - t0, acceleration=c.acceleration))
    if not vehicles:
        raise InputError(f"{r.gt_data}: no car crosses measurement line 0 between {t0:g} s and {t1:g} s")
    new_gt = GroundTruth(fps=scen.imaging.fps, measurement_lines=gt.measurement_lines,
                         lane_div_lines=gt.lane_div_lines, invalid_lanes=gt.invalid_lanes, distances=gt.distances,
                         cars=tuple(cars))
    x_near = -20.0
    x_far = max(lines_x) + 400.0
    return Replay(cam=cam, calibration=true, traffic=Traffic(vehicles, x_near, x_far),
                  backdrop=backdrop, gt=new_gt)
