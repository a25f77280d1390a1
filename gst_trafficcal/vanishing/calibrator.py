"""Streaming, fully automatic calibration of the two vanishing points (paper §4.1).

:class:`VPCalibrator` is fed grey frames with their timestamps (seconds).  It analyses a subset of them at a
reduced resolution: every frame whose time is at least ``1 / track_fps`` after the previous analysed one goes
through the background model and the KLT tracker (VP1 evidence), and some of those are searched for edgelets
(VP2 evidence, inside the bounding box of the moving regions) under a budget of searched pixels per second
(about three 960x540 frames a second), so small videos and sparse traffic are searched on more frames, at most
every tracked frame (or every ``1 / edgelet_fps`` seconds when that is set).  Finished straight tracks are voted into a Diamond Space; every
``check_interval`` seconds the peak is located and VP1 is declared when it moved less than ``vp1_stable_deg``
between two consecutive checks with at least ``min_tracks`` tracks; then (``vp1_constant_speed``) it is moved along
the lanes to where the tracks' perspective acceleration puts it (``constant_speed.py``: the lines fix VP1 across
the lanes, the speeds along them), again with all tracks when VP2 is declared; a move of more than ``max_along`` of
VP1's distance from the tracks is refused (traffic braking or pulling away as a whole, e.g. before a junction).  Edgelets gathered before that are kept
in a bounded buffer (only those inside a vehicle, ``interior_edges``: not on its outline against the road);
once VP1 is known, those not pointing at it are voted into a second Diamond Space masked
to VP2 candidates giving a real focal length in ``focal_range``; VP2 is declared the same way.  The result
is a :class:`~gst_trafficcal.calibration.Calibration` with state ``vps`` (no scale: that is bbscale's job),
or, when it cannot converge, state ``failed`` with the reason (no traffic, no dominant direction, too short...).
The frame counts in the requirements (``min_edgelets``, the tracks' ``TrackParams``) are for analysed frames
``frame_spacing`` (0.08 s) apart; a low-fps input's frames count for more and its tracks need fewer of them.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from ..calibration import Calibration
from ..diamond import DiamondSpace, Peak, all_of, focal_mask, horizon_mask, rasterise
from ..errors import GeometryError, InputError
from ..geometry import Camera
from .edgelets import Edgelets, detect_edgelets, detect_gradient_edgels, interior, towards
from .foreground import RunningForeground
from .constant_speed import AlongLanes, LaneMotion, vp1_across_lines, vp1_along_lanes
from .tracks import MotionLines, TrackParams
from ..zone import Zone

MAX_MOTION_CHUNKS = 20_000  # analysed frames whose finished tracks' motion fits are kept (bounded memory)


@dataclass
class CalibratorConfig:
    """Parameters of :class:`VPCalibrator` (durations in seconds of video, sizes in pixels)."""

    track_width: int = 960          # frames downscaled to at most this width for tracking (480: VP1 off by 0.3-0.6°)
    edgelet_width: int = 960        # ... and to at most this width for edgelets
    foreground_width: int = 240     # ... and this for the background model
    track_fps: float = 15.0         # analysed frames per second for tracking (subset of the input)
    edgelet_fps: float | None = None  # frames per second searched for edgelets (None: pixel budget below)
    edgelet_pixels: float = 3.0 * 960 * 540  # edgelet budget: searched pixels (moving bounding box) per second
    method: str = "edgelets"        # VP2 evidence: "edgelets" (paper) or "gradient" (ITS15 baseline)
    edgelet_blur: float = 1.0        # Gaussian sigma before Sobel for edgelets (0: 3x3 kernel; VP2 3.6° -> 2.8°)
    orientation: str = "subpixel"   # edgelet orientation: "subpixel" (default), "svd" (paper) or "tensor"
    edgelet_along: int = 8          # half length (px) along the edge of the sub-pixel orientation window (see docs)
    min_duration: float = 20.0      # never declare before this much video
    max_duration: float = 180.0     # give up (state failed) when not converged after this much video
    check_interval: float = 5.0     # peaks are re-estimated this often
    min_tracks: int = 60
    min_edgelets: int = 2000        # voted edgelets for VP2 (interior ones, about half of all; 3000 before)
    # min_edgelets and the track's frame counts and per-step speed (TrackParams) are set for analysed frames this far
    # apart (s; 25 fps input at track_fps 15); frames further apart (low-fps input) count each edgelet dt / spacing
    # times and ask the same time and speed of a track (TrackParams.spaced), up to max_spacing (docs/vpdetect.md)
    frame_spacing: float = 0.08
    max_spacing: float = 4.0
    min_vp1_support: float = 0.15   # share of the track weight through VP1
    vp1_stable_deg: float = 0.5     # movement of VP1 between checks (viewing-sphere degrees)
    vp2_stable_deg: float = 1.0
    vp1_exclusion_deg: float = 12.0  # edgelets whose line passes this close to VP1 are dropped
    vp1_near_fraction: float = 0.3  # edgelets closer to VP1 than this x width get proportionally less weight
    min_quality: float = 2.5        # edgelet quality (singular value ratio) to keep
    interior_edges: float = 15.0    # VP2 only from edgelets inside vehicles: both sides of the edge differ from the
                                    # background by more than this (grey levels); outline edges of rounded bodies
                                    # tilt with the view (vp2_far focal error -12.4 -> -6.9 %); 0: every edgelet
    focal_range: tuple[float, float] | None = None  # px; default (0.3, 6) x image width
    horizon_max_deg: float = 30.0   # VP2 only where the horizon VP1-VP2 is within this of horizontal (90: off)
    accumulator_size: int = 128
    edgelet_buffer: int = 400_000   # edgelets kept while VP1 is unknown
    vp1_constant_speed: bool = True  # move VP1 along the lanes to where the tracks' perspective acceleration says
    min_speed_tracks: int = 30      # ... when at least this many tracks have a motion fit
    max_along: float = 0.15         # ... and the move is at most this share of VP1's distance from the tracks
                                    # (larger: the traffic brakes or accelerates as a whole; VP1 is left as is)
    vp1_across_lines: bool = True   # ... and then across the lanes to where the tracks' lines meet (docs, stop 39)
    track: TrackParams = field(default_factory=TrackParams)
    zone: Zone | None = None        # learn only from the motion and edges inside it (gst_trafficcal.zone)

    def __post_init__(self) -> None:
        if self.min_duration > self.max_duration:  # it would only ever fail, at max_duration, "too short"
            raise InputError(f"the minimum duration ({self.min_duration:g} s) is longer than the maximum "
                             f"({self.max_duration:g} s)")


@dataclass
class Status:
    """Progress of the calibration (for progress bars and messages)."""

    state: str
    time: float
    frames: int
    tracks: int
    edgelets: int
    vp1: np.ndarray | None
    vp2: np.ndarray | None
    reason: str = ""


class VPCalibrator:
    """Fully automatic VP1/VP2 calibration from a stream of grey frames (see the module doc)."""

    def __init__(self, image_size: tuple[int, int], config: CalibratorConfig | None = None) -> None:
        w, h = int(image_size[0]), int(image_size[1])
        if w < 32 or h < 32:
            raise InputError(f"frame size {w}x{h} is too small to calibrate (need at least 32x32)")
        self.cfg = config or CalibratorConfig()
        if self.cfg.method not in ("edgelets", "gradient"):
            raise InputError(f"unknown VP2 method {self.cfg.method!r} (edgelets or gradient)")
        self.image_size = (w, h)
        self.pp = np.array([w / 2.0, h / 2.0])
        self.focal_range = self.cfg.focal_range or (0.3 * w, 6.0 * w)
        if not (0 < self.focal_range[0] < self.focal_range[1]):
            raise InputError(f"focal range must be 0 < min < max, got {self.focal_range}")
        self.track_scale = min(1.0, self.cfg.track_width / w)
        self.edge_scale = min(1.0, self.cfg.edgelet_width / w)
        self.fg_scale = min(1.0, self.cfg.foreground_width / w)
        if self.cfg.zone is not None and (wrong := self.cfg.zone.check(self.image_size)):
            raise InputError(wrong)
        self._zone_fg: np.ndarray | None = None  # the zone at the foreground model's size (made at the first frame)
        self.fg_model = RunningForeground()
        self.tracker = MotionLines(self.cfg.track)
        self.ds1 = DiamondSpace.for_image(w, h, self.cfg.accumulator_size)
        self.ds2 = DiamondSpace.for_image(w, h, self.cfg.accumulator_size)
        self.buffer: deque[tuple[Edgelets, float]] = deque()  # with each chunk's evidence weight
        self.buffered = 0
        self.n_tracks = 0
        self.n_edgelets = 0
        self.edge_evidence = 0.0  # voted edgelets, each weighted by its frame's spacing (what min_edgelets asks for)
        self._track_dt = math.inf  # seconds between this analysed frame and the one before
        self.frames = 0
        self.analysed = 0
        self.t0: float | None = None
        self.t = 0.0
        self._last_track_t = -math.inf
        self._last_edge_t = -math.inf
        self._credit = 0.0     # edgelet search budget (pixels) available now
        self._credit_t = 0.0   # video time up to which the budget was credited
        self._next_check = 0.0
        self.vp1: Peak | None = None
        self.vp2: Peak | None = None
        self.vp1_fixed = False
        self.vp1_diamond: Peak | None = None  # the Diamond Space's VP1 before the move along the lanes
        self.along: AlongLanes | None = None  # the move along the lanes the tracks asked for (made if ≤ max_along)
        self.across_px: float | None = None  # the move across the lanes that followed it (vp1_across_lines)
        self._motion: list[LaneMotion] = []  # motion fits of the finished tracks, image pixels
        self._prev1: Peak | None = None
        self._prev2: Peak | None = None
        self.state = "learning"
        self.reason = ""
        self.calibration = Calibration(None, self.image_size, state="learning", source="vpdetect")
        self._fg: np.ndarray | None = None
        self.moving_fraction = 0.0

    # ------------------------------------------------------------------ feeding
    @property
    def duration(self) -> float:
        return self.t

    @property
    def done(self) -> bool:
        return self.state in ("vps", "failed")

    def status(self) -> Status:
        return Status(self.state, self.t, self.frames, self.n_tracks, self.n_edgelets,
                      None if self.vp1 is None else self.vp1.xy, None if self.vp2 is None else self.vp2.xy,
                      self.reason)

    def add(self, gray: np.ndarray, timestamp: float) -> bool:
        """Feed one grey frame (HxW uint8, image size) at ``timestamp`` seconds; True when the state changed."""
        if self.done:
            return False
        if gray.ndim != 2 or gray.shape[1] != self.image_size[0] or gray.shape[0] != self.image_size[1]:
            raise InputError(f"frame of shape {gray.shape} does not match the image size {self.image_size}")
        if self.t0 is None:
            self.t0 = float(timestamp)
        self.t = float(timestamp) - self.t0
        self.frames += 1
        if self.t - self._last_track_t >= 1.0 / self.cfg.track_fps - 1e-6:
            self._track_dt = self.t - self._last_track_t
            self._last_track_t = self.t
            self._track(gray)
        if self._edge_due():
            self._last_edge_t = self.t
            self._edges(gray)
        if self.t >= self._next_check:
            self._next_check = self.t + self.cfg.check_interval
            return self._check(final=False)
        return False

    def _track(self, gray: np.ndarray) -> None:
        small = _resize(gray, self.track_scale)
        tiny = _resize(small, self.fg_scale / self.track_scale)
        self._fg = self.fg_model.apply(tiny)
        if self.cfg.zone is not None:  # tracks and edgelets are searched on the foreground: the zone's only
            if self._zone_fg is None or self._zone_fg.shape != self._fg.shape:
                zone = cv2.resize(self.cfg.zone.mask(self.image_size), self._fg.shape[::-1],
                                  interpolation=cv2.INTER_AREA)
                self._zone_fg = np.where(zone > 0, 255, 0).astype(np.uint8)
            self._fg &= self._zone_fg
        self.analysed += 1
        if math.isfinite(self._track_dt):  # a track asks for the same time and speed at any frame spacing
            self.tracker.p = self.cfg.track.spaced(self._spacing_ratio())
        self.moving_fraction += (self.fg_model.fraction - self.moving_fraction) * 0.05
        lines, lengths, motion = self.tracker.update(small, self._fg, self.t)
        if len(motion) and self.cfg.vp1_constant_speed and len(self._motion) < MAX_MOTION_CHUNKS:
            self._motion.append(motion.scaled(1.0 / self.track_scale))
        if len(lines) and not self.vp1_fixed:
            # to image pixels: x_img = x / s, so a line l becomes (a, b, c / ... ) = (a s, b s, c) up to scale
            lines = lines * np.array([self.track_scale, self.track_scale, 1.0])
            self.ds1.insert(lines, np.minimum(lengths / self.track_scale, 4.0 * self.image_size[0]))
            self.n_tracks += len(lines)

    def _edge_due(self) -> bool:
        """Whether this frame is searched for edgelets.

        With ``edgelet_fps`` set: every 1/edgelet_fps s.  By default a budget of ``edgelet_pixels`` searched pixels
        per second of video, counted over the part actually searched (the bounding box of the moving regions):
        sparse traffic is searched on more frames (up to ``track_fps``), dense traffic on about three 960x540
        frames a second, at about the same cost."""
        if self._fg is None:
            return False
        dt = self.t - self._last_edge_t
        if self.cfg.edgelet_fps:
            return dt >= 1.0 / self.cfg.edgelet_fps - 1e-6
        budget = self.cfg.edgelet_pixels
        self._credit = min(self._credit + budget * (self.t - self._credit_t), budget)  # at most 1 s saved up
        self._credit_t = self.t
        if dt < 1.0 / self.cfg.track_fps - 1e-6 or self._credit <= 0:
            return False
        x, y, bw, bh = cv2.boundingRect(self._fg)
        s = self.edge_scale / self.fg_scale
        self._credit -= max(bw * bh * s * s, 0.05 * budget)
        return True

    def _edges(self, gray: np.ndarray) -> None:
        if not self.fg_model.ready or not self._fg.any():
            return
        small = _resize(gray, self.edge_scale)
        if self.cfg.method == "edgelets":
            e = detect_edgelets(small, self._fg, orientation=self.cfg.orientation, blur=self.cfg.edgelet_blur,
                                along=self.cfg.edgelet_along)
        else:
            e = detect_gradient_edgels(small, self._fg)
        if self.cfg.method == "edgelets":
            e = e.subset(e.quality >= self.cfg.min_quality)
            if self.cfg.interior_edges > 0:  # the foreground model is ready here, so its background exists
                e = e.subset(interior(e, small, self.fg_model.bg, self.fg_scale / self.edge_scale,
                                      self.cfg.interior_edges))
        e = e.scaled(1.0 / self.edge_scale)
        if not len(e):
            return
        weight = self._spacing_ratio()  # what each edgelet counts for towards min_edgelets
        if self.vp1_fixed:
            self._vote_edges(e, weight)
        else:
            self.buffer.append((e, weight))
            self.buffered += len(e)
            while self.buffered > self.cfg.edgelet_buffer and len(self.buffer) > 1:
                self.buffered -= len(self.buffer.popleft()[0])

    def _spacing_ratio(self) -> float:
        """This analysed frame's distance from the one before, in ``frame_spacing`` units: 1 at or below it (exactly,
        so 25 fps and faster inputs are analysed as they always were), at most ``max_spacing``.  Each of its
        edgelets counts that many times towards ``min_edgelets``: between two such frames every vehicle moved
        further, so the frame adds the new evidence of that many frames at the reference rate (a 5 fps stream gives
        fewer than half the edgelets of a 25 fps one, about 5 a frame at either rate on kraten_cars)."""
        ratio = self._track_dt / self.cfg.frame_spacing
        return 1.0 if ratio <= 1.0 + 1e-3 else min(ratio, self.cfg.max_spacing)

    def _vote_edges(self, e: Edgelets, evidence: float = 1.0) -> None:
        keep = ~towards(e, self.vp1.point, self.cfg.vp1_exclusion_deg)
        e = e.subset(keep)
        if len(e):
            weight = np.ones(len(e)) if self.cfg.method == "edgelets" else e.magnitude / max(e.magnitude.mean(), 1e-9)
            # vehicles near VP1 are far away and tiny: their edge orientations are poor and their lines all
            # cross in a small region, which makes a false peak; weight grows with the distance from VP1
            near = self.cfg.vp1_near_fraction * self.image_size[0]
            if near > 0 and abs(self.vp1.point[2]) > 1e-12:
                dist = np.linalg.norm(e.points - self.vp1.xy, axis=1)
                weight = weight * np.clip(dist / near, 0.0, 1.0)
            self.ds2.insert(e.lines(), weight, points=e.points)
            self.n_edgelets += len(e)
            self.edge_evidence += len(e) * evidence

    # ------------------------------------------------------------------ decisions
    def _fix_vp1(self, peak: Peak) -> None:
        self.vp1_diamond = peak
        self.vp1 = self._along_lanes(peak)
        self.vp1_fixed = True
        for e, evidence in self.buffer:
            self._vote_edges(e, evidence)
        self.buffer.clear()
        self.buffered = 0

    def _along_lanes(self, peak: Peak) -> Peak:
        """``peak`` moved along the lanes by the tracks' constant-speed motion (``constant_speed.py``), when
        enabled and the evidence says where; else ``peak``."""
        if not (self.cfg.vp1_constant_speed and peak.finite):
            return peak
        motion = LaneMotion.concatenate(self._motion)
        fit = vp1_along_lanes(peak.xy, motion, self.image_size[0], min_tracks=self.cfg.min_speed_tracks)
        self.along = fit
        self.across_px = None
        if not self._along_accepted():
            return peak
        vp1 = fit.vp1
        if self.cfg.vp1_across_lines:
            vp1, self.across_px = vp1_across_lines(fit.vp1, motion.points.mean(axis=0), self.ds1.lines @ self.ds1.T,
                                                   self.ds1.weights, self.image_size[0])
        point = np.append(vp1, 1.0)
        return replace(peak, point=point / np.linalg.norm(point))

    def _along_accepted(self) -> bool:
        """Whether the move along the lanes the tracks asked for is made (at most ``max_along``)."""
        return self.along is not None and abs(self.along.relative) <= self.cfg.max_along

    def _check(self, final: bool) -> bool:
        """Re-estimate the peaks; declare or fail when the evidence allows.  True when the state changed."""
        cfg = self.cfg
        if not self.vp1_fixed:
            peak = self.ds1.find_peak() if self.n_tracks else None
            prev, self._prev1 = self._prev1, peak
            self.vp1 = peak
            enough = peak is not None and self.n_tracks >= cfg.min_tracks and peak.support >= cfg.min_vp1_support
            stable = enough and prev is not None and _angle(prev.point, peak.point, self.ds1) < cfg.vp1_stable_deg
            if final and enough:
                stable = self._halves_agree(self.ds1, None, cfg.vp1_stable_deg * 4)
            if enough and stable and (self.t >= cfg.min_duration or final):
                self._fix_vp1(peak)
        if self.vp1_fixed and self.n_edgelets:
            vp1 = self.vp1.point[:2] / _w(self.vp1.point)
            mask = all_of(focal_mask(vp1, self.pp, self.focal_range),
                          horizon_mask(vp1, cfg.horizon_max_deg) if cfg.horizon_max_deg < 90 else None)
            peak = self.ds2.find_peak(mask)
            prev, self._prev2 = self._prev2, peak
            self.vp2 = peak
            enough = peak is not None and self.edge_evidence >= cfg.min_edgelets
            stable = enough and prev is not None and _angle(prev.point, peak.point, self.ds2) < cfg.vp2_stable_deg
            if final and enough:
                stable = self._halves_agree(self.ds2, mask, cfg.vp2_stable_deg * 4)
            if enough and stable and (self.t >= cfg.min_duration or final):
                return self._declare()
        if final or self.t >= cfg.max_duration:
            return self._fail(self._why())
        return False

    def _halves_agree(self, ds: DiamondSpace, mask, max_deg: float) -> bool:
        """Stability for a last decision: the peaks of the odd and the even half of the votes agree."""
        lines, w = ds.lines, ds.weights
        peaks = []
        for half in (slice(0, None, 2), slice(1, None, 2)):
            sub = DiamondSpace(ds.size, tuple(ds.centre), ds.norm)
            sub._lines, sub._weights = [lines[half]], [w[half]]
            sub.acc = rasterise(lines[half], w[half], ds.size)
            peaks.append(sub.find_peak(mask))
        return None not in peaks and _angle(peaks[0].point, peaks[1].point, ds) < max_deg

    def _declare(self) -> bool:
        if self.vp1_diamond is not None:  # the tracks finished since VP1 was fixed count too
            self.vp1 = self._along_lanes(self.vp1_diamond)
        vp1, vp2 = _finite(self.vp1.point), _finite(self.vp2.point)
        try:
            cam = Camera(vp1, vp2, self.pp)
        except GeometryError as exc:
            return self._fail(f"the vanishing points found give no valid camera ({exc})")
        self.state = "vps"
        conf = {"vp1": round(self.vp1.support, 4), "vp2": round(self.vp2.support, 4),
                "tracks": float(self.n_tracks), "edgelets": float(self.n_edgelets), "seconds": round(self.t, 3)}
        if self.along is not None:
            key = "vp1_along_px" if self._along_accepted() else "vp1_along_refused_px"
            conf[key] = round(self.along.shift_px, 2)
            if self.across_px is not None:
                conf["vp1_across_px"] = round(self.across_px, 2)
            conf["speed_tracks"] = float(self.along.tracks)
        self.calibration = Calibration(cam, self.image_size, state="vps", source="vpdetect", confidence=conf)
        return True

    def _fail(self, reason: str) -> bool:
        self.state = "failed"
        self.reason = reason
        self.calibration = Calibration(None, self.image_size, state="failed", source="vpdetect", reason=reason)
        return True

    def _why(self) -> str:
        """Why no calibration was declared; a video shorter than ``min_duration`` says so first (its lack of tracks
        or edges is then no sign of a bad view)."""
        why = self._lacking()
        if self.frames >= 2 and self.t < self.cfg.min_duration and not why.startswith(("too short", "no traffic: "
                                                                                       "nothing moved")):
            return f"too short: {self.t:.1f} s of video, need at least {self.cfg.min_duration:g} s; {why}"
        return why

    def _lacking(self) -> str:
        cfg = self.cfg
        t = f"{self.t:.1f} s"
        if self.frames < 2:
            return "too short: a single frame, motion needs a video"
        if self.n_tracks < cfg.min_tracks:
            if self.moving_fraction < 1e-3:
                return f"no traffic: nothing moved in {t} of video"
            inside = " inside the zone" if cfg.zone is not None else ""
            return f"no traffic: only {self.n_tracks} straight vehicle tracks{inside} in {t} (need {cfg.min_tracks})"
        if self.vp1 is None or self.vp1.support < cfg.min_vp1_support:
            sup = 0.0 if self.vp1 is None else self.vp1.support
            return (f"no dominant direction of motion (curved road or intersection?): only {sup:.0%} of "
                    f"{self.n_tracks} tracks meet at one point (need {cfg.min_vp1_support:.0%})")
        if not self.vp1_fixed:
            if self.t < cfg.min_duration:
                return f"too short: {t} of video, need at least {cfg.min_duration:g} s"
            return f"the direction of motion (VP1) did not stabilise in {t} (curved road?)"
        x, y = self.vp1.xy
        vp1 = f"VP1 found at ({x:.1f}, {y:.1f}), but "
        if self.edge_evidence < cfg.min_edgelets:
            worth = ("" if round(self.edge_evidence) == self.n_edgelets else  # a low-fps input (_spacing_ratio)
                     f"worth {self.edge_evidence:.0f} at {1 / cfg.frame_spacing:g} analysed frames/s; ")
            return (vp1 + f"too few edges on vehicles for VP2: {self.n_edgelets} in {t} ({worth}need "
                    f"{cfg.min_edgelets}; a longer video helps)")
        if self.vp2 is None:
            lo, hi = self.focal_range
            return vp1 + f"no second vanishing point giving a focal length in [{lo:.0f}, {hi:.0f}] px"
        if self.t < cfg.min_duration:
            return vp1 + f"too short: {t} of video, need at least {cfg.min_duration:g} s"
        return vp1 + f"the second vanishing point (VP2) did not stabilise in {t}"

    def finish(self) -> Calibration:
        """End of the stream: a last decision on the evidence gathered so far; returns the calibration."""
        if not self.done:
            if self.frames == 0:
                self._fail("no frames: the video is empty")
            else:
                self._check(final=True)
        return self.calibration


def _resize(img: np.ndarray, scale: float) -> np.ndarray:
    """Downscale by ``scale`` (area averaging): exact halvings first, OpenCV's fast path for factor 2."""
    if scale >= 0.999:
        return np.ascontiguousarray(img)
    size = (max(1, round(img.shape[1] * scale)), max(1, round(img.shape[0] * scale)))
    while img.shape[1] >= 2 * size[0] and img.shape[0] >= 2 * size[1]:
        img = cv2.resize(img, (img.shape[1] // 2, img.shape[0] // 2), interpolation=cv2.INTER_AREA)
    if img.shape[1] == size[0] and img.shape[0] == size[1]:
        return img
    return cv2.resize(img, size, interpolation=cv2.INTER_AREA)


def _w(p: np.ndarray) -> float:
    return p[2] if abs(p[2]) > 1e-12 else math.copysign(1e-12, p[2] if p[2] else 1.0)


def _finite(p: np.ndarray) -> np.ndarray:
    """Pixel coordinates of a homogeneous point; points at infinity are moved to a very far finite point."""
    return p[:2] / _w(p)


def _angle(p: np.ndarray, q: np.ndarray, ds: DiamondSpace) -> float:
    """Angle (degrees) between two homogeneous pixel points on the Diamond Space's normalised sphere."""
    a, b = ds.points_to_normalised(p), ds.points_to_normalised(q)
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    return float(np.degrees(np.arccos(np.clip(abs(a @ b), 0, 1))))


@dataclass
class VideoCalibration:
    """Result of :func:`calibrate_video`: the calibration, the calibrator (evidence, status) and the first frame
    in colour (BGR, for the grid picture)."""

    calibration: Calibration
    calibrator: VPCalibrator
    frame: np.ndarray | None
    frames_read: int
    seconds_processing: float


def calibrate_video(path, config: CalibratorConfig | None = None, progress=None,
                    stop_when_done: bool = True, orientation: str = "auto") -> VideoCalibration:
    """Calibrate a video file (OpenCV decoding, times from the container's timestamps).

    Frames are analysed as their luma plane (:mod:`.frames`), exactly what the element sees on YUV caps.
    ``progress(frame_index, frame_count, status)`` is called for every frame.  Raises InputError for a missing
    or undecodable file; an empty or static video gives state ``failed`` with the reason.  A calibration with
    vanishing points carries the view it was learnt on (:mod:`.view`), as ``vpdetect``'s does.  ``orientation``:
    how the frames are turned (``--orientation``, :func:`.frames.luma_frames`).
    """
    import time
    from dataclasses import replace

    from .frames import luma_frames
    from .view import ViewAccumulator, encode_view

    frames = luma_frames(path, orientation)
    cal = VPCalibrator(frames.size, config)
    views = ViewAccumulator(keep=60)
    n = 0
    busy = 0.0
    for t, gray in frames:
        start = time.perf_counter()
        cal.add(gray, t)
        views.add(gray)
        busy += time.perf_counter() - start
        n += 1
        if progress is not None:
            progress(n, frames.count, cal.status())
        if stop_when_done and cal.done:
            break
    result = cal.finish()
    if result.camera is not None and views.count:
        result = replace(result, view=encode_view(views.view(), frames.size[0]))
    return VideoCalibration(result, cal, frames.first_bgr, n, busy)
