"""The streaming scale stage: λ from tracked vehicles as they pass, for the ``bbscale`` element and the CLI.

Fed once per frame with the tracked vehicles (:class:`Sighting`: track id, the 2D box, the base centre of
its 3D box, heading, label, occlusion flags) and the camera (vanishing points).  Per track it keeps the fully
visible, unoccluded sightings with a 3D box; when the track ends (not seen for ``track_timeout`` seconds, or
:meth:`ScaleEstimator.finish`) it aligns the catalogue models (:func:`.alignment.align`) with the track's
``per_track`` largest sightings (spread in time):

* without classifier probabilities every type is tried (a cheap single pass over all of them on the largest
  sighting, then the ``shortlist`` best in full on every chosen sighting) and the type with the best mean peak
  IoU over the track's sightings is the track's type — the match quality decides; the matches of every type
  within ``type_margin`` (0.02) of that mean peak IoU are pooled into the track's λ (a car of unknown make fits
  several similar types about equally, and one of them alone jumps between their lengths; measured at stop 29,
  docs/bbscale_streaming.md);
* with them (:mod:`.classifier`, track-mean probabilities) each type with probability > 0 contributes its
  matches weighted by IoU x probability, as the paper does.

Only passenger-car-shaped vehicles are aligned: the median length/width of the track's 3D boxes on the road
must lie in ``shape_range`` (trucks, buses, vehicles merged into one blob and broken 3D boxes do not; on the
BrnoCompSpeed replays those gave the matches 50-60 % off that kept λ* there).  Matches with IoU above
``iou_threshold`` give λ_ij (weights = IoU); λ* is the mode of the weighted kernel density
(:class:`.estimate.LogDensity`, binned: neither its memory nor its cost grows with the vehicles).  It converges
when ``min_vehicles`` vehicles agree with λ* (their own λ within ``agreement`` = 8 % of it: even with exact boxes
one vehicle's λ scatters by ~5 % median, because a car of unknown make is matched with the catalogue type of most
similar shape, whose length differs from its own); the optional regression (:mod:`.regression`) maps λ* to λ_reg.
Alignment work is bounded: ``per_track`` sightings per vehicle, each aligned once.  When the vanishing points
change, what was accumulated is dropped (the alignments depend on them).

Vehicles seen before the vanishing points are known are not lost: a sighting without a 3D box but with its convex
hull (the tracker publishes the hull until a calibration arrives) is kept, and once the vanishing points are known
its 3D box is built from the hull with the tracker's construction (:func:`..tracking.box3d.fit_shapes`, one body
shape per track), so in a clip whose calibration converges half-way the first half's vehicles still count.
"""

from __future__ import annotations

from array import array
from collections import deque
from dataclasses import dataclass, field
from typing import Iterable, Mapping, Sequence

import numpy as np

from ..errors import GeometryError, InputError, TrafficcalError
from ..geometry import Camera
from ..tracking.box3d import TypicalHeight
from .alignment import AlignModel, Observation, align, align_model
from .estimate import DEFAULT_IOU_THRESHOLD, LogDensity, kde_mode
from .roll import derolled_camera, derolled_fields, derolled_points

#: matched vehicles kept whole (their λ_ij, for diagnostics and benchmarks); the density and the agreement count use
#: every vehicle matched, in a form that does not grow with them
KEPT_MATCHES = 1000

#: body styles aligned by default (passenger cars: common, and their boxes fit tightly); vans, buses, trucks and
#: motorcycles are only aligned when named in ``models``
DEFAULT_STYLES = ("sedan", "estate", "hatchback", "suv")

#: how a track's sightings are chosen for alignment (:meth:`ScaleEstimator._choose`)
SELECTIONS = ("largest", "spread")

#: labels never aligned with car models (detectors' non-vehicle or two-wheeler classes)
SKIPPED_LABELS = frozenset({"person", "bicycle", "motorcycle", "motorbike", "pedestrian"})


@dataclass(frozen=True)
class Sighting:
    """One tracked vehicle in one frame.  ``box`` = detected 2D box (x0, y0, x1, y1) pixels; ``base`` = centre
    of the base of its 3D box in pixels (None without a 3D box); ``heading`` +1 towards VP1, -1 away, 0 not
    known; ``type_probs`` = a classifier's probabilities for this sighting (None without classifier)."""

    track_id: int
    t: float
    box: tuple[float, float, float, float]
    base: tuple[float, float] | None
    heading: float
    label: str = "car"
    occluded: bool = False
    truncated: bool = False
    type_probs: Mapping[str, float] | None = None
    corners: Sequence[Sequence[float]] | None = None  # the 3D box's 8 image corners (order box3d.CORNER_BITS)
    body_shape: str = "box"  # the body the tracker's 3D box holds (box or a catalogue car body, tracking.shapes)
    hull: np.ndarray | None = None  # Kx2 convex hull, pixels: a sighting before the vanishing points were known
    silhouette: bool = False  # the hull is a segmentation's outline (car body shapes apply, tracking.tracker)
    stretched: bool = False  # a car whose plain box came out long (box3d.proportions_class): its outline is off
    derolled_box: tuple[float, float, float, float] | None = None  # the hull's box in the image turned by −roll
    roll: float = 0.0  # radians, the horizon's tilt that derolled_box was taken at (scale.roll)


def length_to_width(camera: Camera, corners_px) -> float | None:
    """Length / width of a 3D box's base on the road (scale-free) from its 8 image corners (order
    ``box3d.CORNER_BITS``: corner 1 = corner 0 moved along the road, corner 2 = moved across); None when the
    base is not on the visible road."""
    from ..tracking.box3d import pixels_to_road

    c = np.asarray(corners_px, np.float64).reshape(8, 2)[:3]
    with np.errstate(divide="ignore", invalid="ignore"):
        road = pixels_to_road(camera, c)
    L, W = np.linalg.norm(road[1] - road[0]), np.linalg.norm(road[2] - road[0])
    return float(L / W) if np.isfinite(L) and np.isfinite(W) and W > 0 else None


def base_centre(corners_px: Sequence[Sequence[float]]) -> tuple[float, float] | None:
    """Centre of the bottom face of a 3D box from its 8 image corners (order ``box3d.CORNER_BITS``: bottom face
    = corners 0..3): the intersection of the face's diagonals 0–3 and 1–2, exact under perspective."""
    c = np.asarray(corners_px, np.float64).reshape(8, 2)
    h = np.hstack([c[:4], np.ones((4, 1))])
    p = np.cross(np.cross(h[0], h[3]), np.cross(h[1], h[2]))
    if not np.all(np.isfinite(p)) or abs(p[2]) < 1e-12:
        return None
    return float(p[0] / p[2]), float(p[1] / p[2])


@dataclass
class ScaleResult:
    """The stage's state: ``scale`` (λ_reg when a regression is set, else λ*; None until converged),
    ``raw_scale`` = λ*, ``confidence`` in [0, 1], ``status`` saying why there is no scale yet (or "converged"),
    counts, and the type chosen per matched vehicle."""

    scale: float | None
    raw_scale: float | None
    confidence: float
    status: str
    converged: bool
    n_vehicles: int = 0  # tracks with usable sightings that were aligned
    n_matched: int = 0  # of them, tracks with a match above the IoU threshold
    n_agreeing: int = 0  # of them, tracks whose own λ agrees with λ*
    n_matches: int = 0  # λ_ij entering the density
    types: dict = field(default_factory=dict)  # type name -> matched vehicles


@dataclass
class _TrackBuffer:
    sightings: list[Sighting] = field(default_factory=list)
    last_t: float = 0.0
    probs_sum: dict = field(default_factory=dict)
    probs_n: int = 0
    early: list[Sighting] = field(default_factory=list)  # hull sightings from before the vanishing points
    heading: float = 0.0  # the tracker's direction once known


@dataclass
class _TrackMatch:
    track_id: int
    model: str
    lambdas: np.ndarray
    weights: np.ndarray
    own: float  # the track's own λ (mode of its matches)
    spread: float = 0.0  # relative range of the best-IoU λ over the track's sightings


def load_align_models(spec: str | Sequence[str] | None = None) -> dict[str, AlignModel]:
    """Alignment models from a catalogue: ``spec`` empty/None = the named passenger-car types
    (:data:`DEFAULT_STYLES`) of the repository catalogue; a path to a catalogue YAML = every named type in it; otherwise comma-separated type names (optionally
    ``path.yaml:name1,name2``).  InputError naming the unknown type or the bad file."""
    from pathlib import Path

    from ..vehicles.catalogue import load_catalogue

    if spec is None or spec == "" or (not isinstance(spec, str) and len(spec) == 0):
        cat = load_catalogue()
        names = [n for n, m in cat.items() if m.body_style in DEFAULT_STYLES]
    elif isinstance(spec, str) and (spec.endswith((".yaml", ".yml")) or Path(spec).is_file()):
        cat, names = load_catalogue(spec), None
    elif isinstance(spec, str) and ":" in spec and spec.split(":", 1)[0].endswith((".yaml", ".yml")):
        path, rest = spec.split(":", 1)
        cat, names = load_catalogue(path), [n.strip() for n in rest.split(",") if n.strip()]
    else:
        cat = load_catalogue()
        names = [n.strip() for n in (spec.split(",") if isinstance(spec, str) else spec) if n.strip()]
    if names is not None:
        unknown = [n for n in names if n not in cat]
        if unknown:
            raise InputError(f"unknown vehicle type {unknown[0]!r} (catalogue types: {', '.join(sorted(cat))})")
        cat = {n: cat[n] for n in names}
    if not cat:
        raise InputError("no vehicle types to align (the catalogue has no named models)")
    return {n: align_model(m) for n, m in cat.items()}


class ScaleEstimator:
    """Accumulates BBScale evidence over a stream; see the module documentation."""

    def __init__(self, models: Mapping[str, AlignModel] | None = None, iou_threshold: float = DEFAULT_IOU_THRESHOLD,
                 min_vehicles: int = 5, regression=None, renderer=None, per_track: int = 3, min_gap: float = 0.2,
                 track_timeout: float = 1.0, min_box: float = 24.0, shortlist: int = 3, agreement: float = 0.08,
                 refine_base: bool = True, bandwidth: float = 0.05,
                 shape_range: tuple[float, float] | None = (0.8, 3.5), shape_tolerance: float | None = None,
                 min_peak: float = 0.0, loose=None, select: str = "largest", type_margin: float = 0.02):
        if not 0.0 < iou_threshold < 1.0:
            raise InputError(f"iou-threshold must be between 0 and 1, got {iou_threshold:g}")
        if min_vehicles < 1:
            raise InputError(f"min-vehicles must be at least 1, got {min_vehicles}")
        self.models = dict(models) if models is not None else load_align_models()
        if not self.models:
            raise InputError("no vehicle types to align")
        self.iou_threshold = float(iou_threshold)
        self.min_vehicles = int(min_vehicles)
        self.regression = regression
        self.renderer = renderer
        self.per_track, self.min_gap, self.track_timeout = int(per_track), float(min_gap), float(track_timeout)
        self.min_box, self.shortlist, self.agreement = float(min_box), int(shortlist), float(agreement)
        self.refine_base = refine_base
        self.bandwidth = float(bandwidth)
        self.shape_range, self.shape_tolerance = shape_range, shape_tolerance
        self.min_peak = float(min_peak)
        if not type_margin >= 0.0:
            raise InputError(f"type margin is an IoU difference, 0 or more, got {type_margin:g}")
        self.type_margin = float(type_margin)
        self.loose = tuple(int(np.sign(v)) for v in loose) if loose is not None else None
        if select not in SELECTIONS:
            raise InputError(f"sighting selection must be one of {', '.join(SELECTIONS)}, got {select!r}")
        self.select = select
        self.camera: Camera | None = None
        self._derolled: tuple | None = None  # (camera, roll, de-rolled camera) of the last rolled sighting
        self._tracks: dict[int, _TrackBuffer] = {}
        self._waiting: list[tuple[int, _TrackBuffer]] = []  # tracks that ended before any vanishing points
        self._reset()

    # ------------------------------------------------------------------ state
    def _reset(self) -> None:
        """Drop the evidence of the previous vanishing points; open tracks keep only their hull sightings (they
        hold under any VPs)."""
        for buf in self._tracks.values():
            buf.sightings = []
        self._tracks = {tid: b for tid, b in self._tracks.items() if b.early}
        self._density = LogDensity()  # every match's λ_ij, each vehicle's weights summing to 1
        self._own = array("d")  # each matched vehicle's own λ
        self._types: dict[str, int] = {}  # type name -> matched vehicles
        self._matches: deque[_TrackMatch] = deque(maxlen=KEPT_MATCHES)  # the latest, as they were matched
        self._n_aligned = 0
        self._n_geometry_failures = 0
        self._geometry_reason = ""
        self._n_selected = 0
        self._n_not_car = 0
        self._result: ScaleResult | None = None
        self._early_heights = TypicalHeight()  # as the tracker's, for the early sightings' body shapes (_boxed)

    def restart(self) -> None:
        """The camera moved: every piece of evidence so far, open tracks and early sightings included, belongs to
        another view; start from nothing (no vanishing points until the next :meth:`set_camera`)."""
        self.camera = None
        self._tracks, self._waiting = {}, []
        self._reset()

    def set_camera(self, camera: Camera | None) -> None:
        """Use ``camera`` (its vanishing points; any scale is ignored).  A change of VPs drops the evidence."""
        if camera is None:
            self.camera = None
            return
        if self.camera is not None and np.allclose(self.camera.vp1, camera.vp1) and \
                np.allclose(self.camera.vp2, camera.vp2) and np.allclose(self.camera.pp, camera.pp):
            return
        self.camera = camera.with_scale(None)
        self._reset()

    # ------------------------------------------------------------------ input
    def usable(self, s: Sighting) -> bool:
        """Fully visible, unoccluded, with a 3D box base and a known heading, of a vehicle label, large enough."""
        return self._visible(s) and s.base is not None and s.heading != 0 and bool(np.all(np.isfinite(s.base)))

    def _visible(self, s: Sighting) -> bool:
        x0, y0, x1, y1 = s.box
        return (not s.occluded and not s.truncated and s.label not in SKIPPED_LABELS
                and min(x1 - x0, y1 - y0) >= self.min_box)

    def update(self, t: float, sightings: Iterable[Sighting], camera: Camera | None = None) -> bool:
        """Add one frame's sightings (time ``t`` seconds).  Tracks not seen for ``track_timeout`` are aligned.
        Returns True when the result changed (call :meth:`result`)."""
        if camera is not None:
            self.set_camera(camera)
        for s in sightings:
            buf = self._tracks.setdefault(int(s.track_id), _TrackBuffer())
            buf.last_t = float(t)
            if s.type_probs:
                buf.probs_n += 1
                for k, p in s.type_probs.items():
                    buf.probs_sum[k] = buf.probs_sum.get(k, 0.0) + float(p)
            if s.heading != 0:
                buf.heading = float(s.heading)
            if self.camera is not None and self.usable(s):
                buf.sightings.append(s)
                if len(buf.sightings) > 128:  # a vehicle that stays (queue, parked): bounded memory
                    buf.sightings = self._choose(buf.sightings)
            elif s.base is None and s.hull is not None and self._visible(s):  # before the vanishing points
                buf.early.append(s)
                if len(buf.early) > 128:
                    buf.early = sorted(buf.early, key=lambda e: e.t)[::2]
        ended = [tid for tid, b in self._tracks.items() if t - b.last_t > self.track_timeout]
        changed = self._close(ended)
        if self.camera is not None and self._waiting:  # tracks that ended before the first vanishing points
            waiting, self._waiting = self._waiting, []
            for tid, buf in waiting:
                changed |= self._align_track(tid, buf)
            if changed:
                self._result = None
        return changed

    def finish(self) -> bool:
        """Align every open track (end of stream).  Returns True when the result changed."""
        return self._close(list(self._tracks))

    def _close(self, track_ids: list[int]) -> bool:
        changed = False
        for tid in track_ids:
            buf = self._tracks.pop(tid)
            if self.camera is not None and (buf.sightings or buf.early):
                changed |= self._align_track(tid, buf)
            elif self.camera is None and buf.early:
                self._waiting.append((tid, buf))
                del self._waiting[:-500]  # bounded: the last 500 vehicles before any calibration
        if changed:
            self._result = None
        return changed

    def _boxed(self, buf: _TrackBuffer) -> list[Sighting]:
        """The track's early hull sightings with the 3D boxes the tracker would have built (its construction,
        one body shape per track) and the track's heading (the tracker's, or from the boxes' motion)."""
        from dataclasses import replace

        from ..tracking.box3d import boxes_from_fits, fit_shapes, track_choice, track_class
        from ..tracking.tracker import TrackerConfig
        from .alignment import heading_from_track

        early = sorted(buf.early, key=lambda e: e.t)
        silhouette = any(e.silhouette for e in early)
        fits = fit_shapes(self.camera, [np.asarray(e.hull, np.float64).reshape(-1, 2) for e in early],
                          None if silhouette else ())
        first = np.flatnonzero(np.isfinite(fits.fit[0]))[:TrackerConfig.shape_fits]  # as the tracker chooses
        cls = track_class(fits.params[0, first], self._early_heights.value) if silhouette and len(first) else ""
        k = track_choice(fits.fit[:, first].T, fits.kinds, cls) if silhouette else 0
        stretched = cls == "stretched"
        if silhouette and len(first) >= TrackerConfig.shape_fits:
            self._early_heights.add(float(np.median(fits.params[0, first, 4])))
        boxes = boxes_from_fits(self.camera, fits, np.full(len(early), k))
        out = []
        for j, e in enumerate(early):
            base = base_centre(boxes.corners_px[j]) if boxes.valid[j] else None
            if base is not None:
                out.append(replace(e, base=base, corners=boxes.corners_px[j], body_shape=fits.names[k], hull=None,
                                   stretched=stretched, **derolled_fields(self.camera, e.hull, silhouette)))
        heading = buf.heading
        if heading == 0 and len(out) >= 2:
            try:
                heading = heading_from_track(self.camera, np.array([s.base for s in out]))
            except InputError:  # no two of its points on the visible road
                heading = 0.0
        return [replace(s, heading=heading) for s in out] if heading != 0 else []

    # ------------------------------------------------------------------ alignment
    def _choose(self, sightings: list[Sighting]) -> list[Sighting]:
        """``per_track`` sightings at least ``min_gap`` seconds apart: the largest (``select`` "largest"), or
        spread evenly over the track's range of box sizes ("spread")."""
        order = sorted(sightings, key=lambda s: -(s.box[2] - s.box[0]) * (s.box[3] - s.box[1]))
        if self.select == "spread" and len(order) > self.per_track:
            picks = np.linspace(0, len(order) - 1, self.per_track).round().astype(int)
            rest = np.setdiff1d(np.arange(len(order)), picks)  # fall back on the others, largest first
            order = [order[i] for i in np.concatenate([picks, rest])]
        chosen: list[Sighting] = []
        for s in order:
            if all(abs(s.t - c.t) >= self.min_gap for c in chosen):
                chosen.append(s)
                if len(chosen) == self.per_track:
                    break
        return chosen

    def _observation(self, s: Sighting, probs: dict | None) -> Observation:
        """The sighting as aligned: under a rolled camera, its hull's box and base in the de-rolled image."""
        box, base, roll = s.box, (float(s.base[0]), float(s.base[1])), 0.0
        if s.derolled_box is not None and s.roll:
            box, roll = s.derolled_box, float(s.roll)
            base = tuple(float(v) for v in derolled_points(base, self.camera.pp, roll)[0])
        return Observation(box=tuple(float(v) for v in box), base=base, heading=1.0 if s.heading > 0 else -1.0,
                           track_id=int(s.track_id), type_probs=probs, body_shape=s.body_shape, roll=roll)

    def _camera_for(self, roll: float) -> Camera:
        """The camera the boxes of ``roll`` are in (the de-rolled camera of the last tilt is kept)."""
        if not roll:
            return self.camera
        if self._derolled is None or self._derolled[0] is not self.camera or self._derolled[1] != roll:
            self._derolled = (self.camera, roll, derolled_camera(self.camera, roll))
        return self._derolled[2]

    def _align(self, model: AlignModel, obs: Observation, refine: bool):
        try:
            return align(self._camera_for(obs.roll), model, obs, renderer=self.renderer, refine_base=refine,
                         loose=self.loose)
        except GeometryError as exc:
            self._n_geometry_failures += 1
            self._geometry_reason = str(exc)
        except TrafficcalError:
            pass
        return None

    def _car_shaped(self, sightings: list[Sighting]) -> list[Sighting]:
        """The sightings of a passenger-car-shaped vehicle: the median length/width of the track's 3D boxes on the
        road must lie in ``shape_range`` (a truck, bus, two vehicles merged into one blob or a broken box lie
        outside; measured on the replays these are the matches 50-60 % off), and with ``shape_tolerance`` only
        sightings whose own ratio is within that relative distance of the median are kept.  Empty when the
        vehicle is not car-shaped; unchanged without 3D-box corners.  Also empty for a car whose plain box the
        tracker found stretched (long, but of a car's height: its outline is off, e.g. a far lane seen past the
        median barrier; admitted, six such cars moved session2_center's λ from −2.1 to −3.2 %)."""
        if any(s.stretched for s in sightings):
            return []
        if self.shape_range is None:
            return sightings
        ratios = [length_to_width(self.camera, s.corners) if s.corners is not None else None for s in sightings]
        known = [r for r in ratios if r is not None]
        if not known:
            return sightings
        med = float(np.median(known))
        if not self.shape_range[0] <= med <= self.shape_range[1]:
            return []
        if self.shape_tolerance is None:
            return sightings
        return [s for s, r in zip(sightings, ratios) if r is None or abs(r / med - 1) <= self.shape_tolerance]

    def _align_track(self, tid: int, buf: _TrackBuffer) -> bool:
        if buf.early:
            buf.sightings = buf.sightings + [s for s in self._boxed(buf) if self.usable(s)]
            buf.early = []
        if not buf.sightings:
            return False
        self._n_selected += 1
        sightings = self._car_shaped(buf.sightings)
        if not sightings:
            self._n_not_car += 1
            return False
        chosen = self._choose(sightings)
        probs = {k: v / buf.probs_n for k, v in buf.probs_sum.items()} if buf.probs_n else None
        obs = [self._observation(s, probs) for s in chosen]
        if probs:  # classifier: every named type with its track-mean probability
            names = [n for n, p in probs.items() if n in self.models and p > 0]
        else:  # match quality decides: quick pass over all types on the largest sighting, then a shortlist
            quick = [(a.iou.max(), n) for n in self.models
                     if (a := self._align(self.models[n], obs[0], False)) is not None]
            names = [n for _, n in sorted(quick, reverse=True)[: self.shortlist]]
        if not names:
            return False
        self._n_aligned += 1
        per_type = {}
        for n in names:
            aligned = [a for o in obs if (a := self._align(self.models[n], o, self.refine_base)) is not None]
            if aligned:
                per_type[n] = aligned
        if not per_type:
            return False
        quality = {n: float(np.mean([a.iou.max() for a in aligned])) for n, aligned in per_type.items()}
        if probs:  # every named type, its matches weighted by the track-mean probability (the paper)
            model = max(per_type, key=lambda n: probs[n])
            weight = {n: probs[n] for n in per_type}
        else:  # the best-fitting type names the track; the types within type_margin of it are pooled
            model = max(quality, key=quality.get)
            weight = {n: 1.0 for n in per_type if quality[n] >= quality[model] - self.type_margin}
        lams, wts = [], []
        for n, p in weight.items():
            for a in per_type[n]:
                k = a.kept(self.iou_threshold)
                lams.append(a.lambda_ij[k])
                wts.append(a.iou[k] * p)
        lam, w = np.concatenate(lams), np.concatenate(wts)
        ok = np.isfinite(lam) & (lam > 0) & (w > 0)
        if not ok.any() or quality[model] < self.min_peak:
            return True  # aligned but unmatched: the status counts it
        lam, w = lam[ok], w[ok]
        peaks = np.array([a.lambda_ij[a.best] for a in per_type[model] if a.iou.max() > self.iou_threshold])
        spread = float(np.ptp(peaks) / np.median(peaks)) if len(peaks) > 1 else 0.0
        match = _TrackMatch(tid, model, lam, w, kde_mode(lam, w), spread)
        # each vehicle votes once (its IoU weights normalised): a vehicle with many matches cannot outvote others
        self._density.add(lam, w / w.sum())
        self._own.append(match.own)
        self._types[model] = self._types.get(model, 0) + 1
        self._matches.append(match)
        return True

    # ------------------------------------------------------------------ output
    def result(self) -> ScaleResult:
        """λ (with regression), confidence and status from everything aligned so far."""
        if self._result is None:
            self._result = self._compute()
        return self._result

    def _compute(self) -> ScaleResult:
        if self.camera is None:
            return ScaleResult(None, None, 0.0, "waiting for the vanishing points (no calibration yet)", False)
        counts = dict(n_vehicles=self._n_aligned, n_matched=len(self._own), types=dict(self._types))
        if not self._own:
            if self._n_selected and self._n_geometry_failures and not self._n_aligned:
                return ScaleResult(None, None, 0.0, f"degenerate viewpoint: {self._geometry_reason}", False,
                                   **counts)
            if not self._n_selected:
                return ScaleResult(None, None, 0.0, "no fully visible vehicle with a 3D box seen yet", False,
                                   **counts)
            shape = f" ({self._n_not_car} not car-shaped)" if self._n_not_car else ""
            return ScaleResult(None, None, 0.0, f"no vehicle of a known type: none of {self._n_selected} fully "
                               f"visible vehicles{shape} matched a catalogue model with IoU > "
                               f"{self.iou_threshold:g}", False, **counts)
        # a kernel of fixed width in log λ: Scott's rule on pooled matches of different vehicles grows with the
        # outliers and drags the mode. The default 5 % is about one vehicle's own scatter (a car of unknown make
        # matched with the catalogue type of most similar shape): a narrower kernel (2 % before stop 14) picks a
        # noisy local peak of 10-40 votes (docs/bbscale_streaming.md)
        raw = self._density.mode(self.bandwidth)
        own = np.frombuffer(self._own, dtype=np.float64)
        agree = int(np.sum(np.abs(own / raw - 1.0) <= self.agreement))
        converged = agree >= self.min_vehicles
        # share of the matched vehicles that agree, discounted until min_vehicles of them do
        confidence = float(agree / len(own) * min(1.0, agree / self.min_vehicles))
        scale = raw if self.regression is None else float(self.regression.apply(raw))
        status = "converged" if converged else \
            f"too few matches: {agree} of {len(own)} matched vehicles agree, min-vehicles is {self.min_vehicles}"
        return ScaleResult(scale if converged else None, raw, confidence, status, converged, n_agreeing=agree,
                           n_matches=len(self._density), **counts)

    def current_scale(self) -> float | None:
        """λ* (with regression) from the evidence so far even before convergence, None without any match."""
        r = self.result()
        if r.raw_scale is None:
            return None
        return r.raw_scale if self.regression is None else float(self.regression.apply(r.raw_scale))
