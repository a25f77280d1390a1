"""Streaming per-vehicle speed measurement: tracked vehicles in, one :class:`~gst_trafficcal.outputs.VehicleEvent` out
per vehicle that leaves (paper §4.4).

Shared by the ``speedometer`` element and ``trafficcal run`` so that both give the same numbers.  Per frame the
caller hands over the tracked vehicles as :class:`Sighting` records (what the ``tracker`` element writes in its
``"trafficcal-vehicle"`` ROI structure: time, hull box, 3D box corners and reference point when a calibration with
vanishing points was in force) and, whenever it changes, the current calibration.

* **Reference points**: when a vehicle leaves, its reference points are rebuilt from its per-frame 3D boxes the
  way the tracker finishes a track (front face from the final direction of travel, far faces placed at the
  track's median length and width from the well-conditioned near faces), which is steadier than the points the
  tracker could give frame by frame.  Vehicles seen before the vanishing points were known carry only their hull
  (or hull box); their 3D boxes are built from it once a calibration with vanishing points exists.
* **Speed**: ``v = median_i λ‖P(i+τ) − P(i)‖ / (t(i+τ) − t(i))`` over the reference points that are the
  vehicle's own, times from buffer timestamps (:func:`gst_trafficcal.speed.vehicle_speed`) — or, with
  :attr:`SpeedMeter.smooth_times`, the frames' smoothed times given to :meth:`SpeedMeter.update` (times of arrival
  that jitter: :class:`~gst_trafficcal.frame_jitter.FrameRetimer`; the events keep the buffers' times): a 3D box
  far outside its hull gives no point; points that do not continue the vehicle's motion (an ID switch, a merge, a
  degenerate box) are dropped, the longest consistent run is the vehicle; a vehicle whose τ-pair speeds disagree
  or whose points span too little road is reported unmeasured with the reason instead of with a wrong speed.  Only
  measured vehicles carry points for the BrnoCompSpeed results (the ones their speed came from), so the official
  evaluation measures what was published.
* **Calibration not there yet**: vehicles that leave before a calibration with scale exists are kept (points and
  timestamps) and measured as soon as one arrives, so one pass over a file measures every vehicle; at the end of
  the stream the ones still waiting are reported unmeasured, with the reason.
* **A moved camera** (a calibration with ``moved_at``, from vpdetect): what was seen before belongs to the
  calibration in force then.  Every vehicle in view is cut at the move and measured now with that calibration
  (or reported unmeasured when it had no scale), as are the vehicles waiting for a scale; the lanes are learnt
  again; a track id seen before the move is not taken up again after it.  A track that began after the move and
  was not seen again once the move was noticed is no vehicle of either view and is not reported
  (:attr:`SpeedMeter.discarded` counts them): between a move and its notice (1–3 s) a background-model detector
  compares the new picture with the old view's background and finds "vehicles" along every edge of the scene,
  and a tracker that starts again at the notice takes the real ones up anew.
* **A jump in the stream** (a player's seek, recordings joined: :meth:`SpeedMeter.cut`): every vehicle in view
  ends there, measured from what was seen before it; no track is measured across the jump.
* A vehicle has left when it has not been seen for ``end_after`` seconds (stream time), so the result does not
  depend on whether the tracker ran upstream or inside the caller.
* **Direction**: sign of the reference points' motion along the road (world x, towards VP1); **lane**: the
  online :class:`~gst_trafficcal.lanes.LaneModel` over the vehicles' lateral offsets.
* **Not every track is a vehicle** (:func:`not_a_vehicle`): a track left unmeasured that was seen for under
  ``min_seen_s`` (a fragment of a vehicle the tracker also follows, a flicker of the detector; not when the end of
  the stream or a camera move cut it short) or that moved under ``min_passing_m`` along the road (a parked
  vehicle, a fixed object taken for one) is not reported —
  the traffic counts are of vehicles passing; :attr:`SpeedMeter.not_counted` counts them by reason.  A vehicle with
  a speed is always reported.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .calibration import Calibration
from .detection.records import box_iou
from .frame_rate import FrameSpacing, frames_needed
from .geometry import Camera
from .lanes import LaneModel, lateral_offset
from .outputs import AWAY_FROM_VP1, TOWARDS_VP1, VehicleEvent
from .speed import DEFAULT_TAU, SpeedChecks, VehicleSpeed, _median_velocity, metres_per_pixel, vehicle_speed
from .tracking.box3d import TypicalHeight, box_heights, corners_fit_hulls, pixels_to_road
from .tracking.tracker import Observation, Track, TrackerConfig, TrackState, measured_boxes, rebuild_boxes
from .tracking.tracker import shape_min_px, track_dimensions
from .tracking.tracker import _set_references, _update_direction  # the tracker's own finishing step
from .uncertainty import calibration_pct, speed_uncertainty
from .vehicles.classify import MAX_Z, classify_dimensions, refined_label

DEFAULT_MIN_TRACK_LENGTH = 10
MIN_SEEN_S = 0.5  # an unmeasured track seen for less is no vehicle of its own (a fragment, a detector's flicker)
MIN_PASSING_M = 3.0  # an unmeasured track that moved less along the road did not pass (parked, fixed)
DRIVE_OFF_POINTS = 64  # a track's latest reference points drove_along_road judges (2.6 s at 25 fps; below 12.5 fps
# the points that cover that time, at least DRIVE_OFF_FLOOR: drive_off_points)
DRIVE_OFF_FLOOR = 8  # the fewest points drove_along_road judges
BRIEF = "brief"  # SpeedMeter.not_counted's reasons
STATIONARY = "stationary"
END_AFTER_MARGIN = 0.4  # seconds beyond the tracker's coasting time (max_lost) before a vehicle counts as gone
DEFAULT_END_AFTER = TrackerConfig.max_lost + END_AFTER_MARGIN  # a vehicle the tracker still coasts is not cut
MIN_DIRECTION_SPAN = 0.05  # plane units the reference point must travel along the road to give a direction
DEFAULT_STITCH_GAP = 1.0  # seconds: a track starting this soon after a vehicle was lost may continue it
DEFAULT_MAX_WAITING = 2000  # vehicles held for a calibration with a scale (a few tens of MB; a busy road's hour
# or two): a live camera that never calibrates must neither grow without end nor keep its counts from the files
STITCH_LATERAL_M = 1.5  # metres across the road a continuing track may start from where the lost one was heading
LIVE_WINDOW = 250  # observations behind the per-frame estimate of a vehicle still in view
LIVE_LABEL_EVERY = 25  # observations between two classifications of a vehicle in view (its final one: when it leaves)
LIVE_EVERY = 5  # observations between two estimates of a vehicle in view (5 a second at 25 fps; the ROI structure
# repeats the last one in between: a median over up to LIVE_WINDOW points barely moves in a frame, and computing
# it every frame was a tenth of the chain's time in dense traffic); below 12.5 fps as often in time (frames_needed)


@dataclass(frozen=True)
class Sighting:
    """One tracked vehicle in one frame (pixels, seconds)."""

    id: int
    label: str
    t: float
    box: tuple[float, float, float, float]  # x0, y0, x1, y1 of the tracked hull (or detection box)
    confidence: float = 0.0
    truncated: bool = False  # touching the image border: not measured
    occluded: bool = False  # partly covered by a nearer vehicle: not measured
    corners_px: np.ndarray | None = None  # 8x2 corners of the 3D box (tracking.box3d.CORNER_BITS order)
    ref_px: np.ndarray | None = None  # the tracker's reference point of this frame
    hull: np.ndarray | None = None  # Kx2 convex hull when known (builds the 3D box later if VPs come late)
    silhouette: bool = False  # the hull is a segmentation's clean outline (car body shapes apply, tracker.py)
    cut_top: bool = False  # truncated by the image's top edge alone: its 3D box may still measure (tracker.py)

    @classmethod
    def from_fields(cls, object_id: int, label: str, confidence: float, fields: Mapping[str, Any],
                    t: float | None = None) -> "Sighting":
        """From the ``"trafficcal-vehicle"`` structure (``tracking.vehicle_meta``); ``t`` overrides its time."""
        time = float(fields["t"]) if t is None else float(t)
        box = tuple(float(v) for v in fields.get("hull_box", (np.nan,) * 4))
        corners = ref = None
        cut_top = bool(fields.get("cut_top", False))
        if (fields.get("has_3d") or cut_top) and "box3d" in fields:
            corners = np.asarray(fields["box3d"], np.float64).reshape(8, 2)
            if "ref_x" in fields and "ref_y" in fields:
                ref = np.array([float(fields["ref_x"]), float(fields["ref_y"])])
        hull = fields.get("hull")
        hull = None if hull is None else np.asarray(hull, np.float64).reshape(-1, 2)
        return cls(int(object_id), str(label), time, box, float(confidence), bool(fields.get("truncated", False)),
                   bool(fields.get("occluded", False)), corners, ref, hull, bool(fields.get("silhouette", False)),
                   cut_top)


@dataclass(frozen=True)
class LiveSpeed:
    """Current estimate for a vehicle still in view (for the per-frame ``"speed"`` ROI structure)."""

    speed_kmh: float
    confidence: float  # share of τ-pair speeds within 10 % of the vehicle's own motion (speed.vehicle_speed)
    n_samples: int
    label: str = ""  # the class its 3D boxes give so far (vehicles.classify.refined_label of the detector's)
    uncertainty_kmh: float | None = None  # half-width of the ~95 % interval (gst_trafficcal.uncertainty)


def steady_label(shown: str, next_: str, new: str) -> tuple[str, str]:
    """The class to show for a vehicle in view, and the one waiting, after its size gave ``new``: a change is shown
    only when two refreshes in a row give it, so a vehicle whose size lies between two classes (half hidden, or
    far) does not flip its label on the video every second; the first class is shown at once."""
    if not shown or new == shown:
        return new, ""
    return (new, "") if new and new == next_ else (shown, new)


@dataclass(frozen=True)
class MeasuredVehicle:
    """A vehicle that left: its event and the reference points behind it (for the BrnoCompSpeed results)."""

    event: VehicleEvent
    times_s: np.ndarray  # (M,) timestamps of the reference points its speed was measured from (none: unmeasured)
    points_px: np.ndarray  # (M, 2) those reference points, pixels
    merged_ids: tuple[int, ...] = ()  # earlier tracks of the same vehicle, measured with it (SpeedMeter._stitch)


@dataclass
class _Kept:
    """What :meth:`SpeedMeter.remeasure` needs of a measured vehicle — its reference points, not its observations
    (a few kB instead of some hundred: a long file's vehicles stay small)."""

    rec: "_Record"  # id, and its first and last observation only (the event's timestamps)
    times: np.ndarray
    fit_times: np.ndarray  # the same frames' smoothed times where given (SpeedMeter.update's fit_t), else times
    px: np.ndarray  # the reference points found with the vanishing points of the time
    label: str  # the detector's label
    dims_plane: np.ndarray | None  # length, width, height in road-plane units (metres / λ)
    calibration_id: str | None


@dataclass
class _Record:
    id: int
    observations: list[Observation] = field(default_factory=list)
    last_t: float = 0.0
    unboxed: list[int] = field(default_factory=list)  # observations that came without a 3D box but could have one
    live_label: str = ""  # the class given to the vehicle in view (refreshed every LIVE_LABEL_EVERY observations)
    live_label_next: str = ""  # another class its size gave at the last refresh, shown if the next one agrees
    live_label_at: int = -1  # how many observations it had then
    live: LiveSpeed | None = None  # the current estimate of the vehicle in view (refreshed every LIVE_EVERY)
    live_at: int = -1  # how many observations it had then
    merged: list[int] = field(default_factory=list)  # ids of the earlier tracks stitched in front of this one
    cut: bool = False  # its view was cut short (end of stream, camera move): a brief track may still be a vehicle

    def track(self) -> Track:
        return Track(id=self.id, state=TrackState.FINISHED, observations=self.observations)


@dataclass
class FrameOutput:
    """What :meth:`SpeedMeter.update` found: current speeds of the vehicles in view and vehicles that left."""

    speeds: dict[int, LiveSpeed]
    finished: list[MeasuredVehicle]


@dataclass(frozen=True)
class _PctKey:
    """What :func:`~gst_trafficcal.uncertainty.calibration_pct` reads of a calibration, as the key of the one it
    was computed for: whether it has a scale (not its value: bbscale refining it leaves the part as it is), its
    source (manual or vpdetect's) and its view (image size, vanishing points, principal point).  Not an
    ``lru_cache`` on the calibration: it holds numpy arrays (unhashable), and a new scale makes a new one."""

    scaled: bool
    source: str
    image_size: tuple[int, int]
    points: tuple[float, ...]  # VP1, VP2, pp

    @classmethod
    def of(cls, cal: Calibration) -> "_PctKey | None":
        cam = cal.camera
        if cam is None:
            return None
        return cls(cam.scale is not None, cal.source, tuple(cal.image_size),
                   tuple(np.concatenate([cam.vp1, cam.vp2, cam.pp]).tolist()))


class SpeedMeter:
    """Online speed measurement (see the module doc).  Feed :meth:`update` once per frame, in time order."""

    def __init__(self, tau: int = DEFAULT_TAU, min_track_length: int = DEFAULT_MIN_TRACK_LENGTH,
                 end_after: float = DEFAULT_END_AFTER, calibration: Calibration | None = None,
                 checks: SpeedChecks = SpeedChecks(), stitch_gap: float = DEFAULT_STITCH_GAP,
                 max_waiting: int = DEFAULT_MAX_WAITING, keep_measured: bool = False,
                 min_seen_s: float = MIN_SEEN_S, min_passing_m: float = MIN_PASSING_M) -> None:
        if tau < 1:
            raise ValueError(f"tau must be at least 1, got {tau}")
        if min_track_length < tau + 1:
            raise ValueError(f"min_track_length must be at least tau + 1 = {tau + 1}, got {min_track_length}")
        if not end_after > 0:
            raise ValueError(f"end_after must be positive, got {end_after}")
        if max_waiting < 1:
            raise ValueError(f"max_waiting must be at least 1, got {max_waiting}")
        self.max_waiting = int(max_waiting)
        self.tau = int(tau)
        self.min_track_length = int(min_track_length)
        self.end_after = float(end_after)
        self.checks = checks
        self.stitch_gap = float(stitch_gap)
        self.calibration: Calibration | None = None
        self.lanes = LaneModel()
        self._live: dict[int, _Record] = {}
        self._pending: list[_Record] = []  # left before a calibration with scale existed
        # the typical vehicle height among the vehicles whose 3D boxes are built here late (tracker.TrackerConfig's
        # body-shape choice), with the camera it is in plane units of
        self._late_heights, self._late_camera = TypicalHeight(), None
        self._retired: set[int] = set()  # ids of the vehicles cut by a camera move or a jump (their tracks end there)
        self._blind: dict[int, float] = {}  # tracks begun between a move and its notice -> when it was noticed
        self.discarded = 0  # such tracks never seen after the notice: not reported
        self.min_seen_s, self.min_passing_m = float(min_seen_s), float(min_passing_m)
        self.not_counted: Counter[str] = Counter()  # unmeasured tracks that were no vehicle passing (BRIEF, STATIONARY)
        # their track ids (and of the tracks stitched into them), and of the discarded ones, until the caller takes
        # them (take_not_counted_ids; the element does at every frame)
        self.not_counted_ids: list[int] = []
        # keep_measured: every vehicle measured (its reference points and size, _Kept: about 4 kB), with the calibration
        # it was measured with, for remeasure() (a file's early vehicles measured again with the one it ends with)
        self.keep_measured = bool(keep_measured)
        self._measured: dict[int, _Kept] = {}
        # sightings dropped because their track id was given to another sighting of the same frame (a tracker's
        # fault: _one_per_id), and the first such id and time, for the caller to say
        self.duplicates = 0
        self.first_duplicate: tuple[int, float] | None = None
        # sightings left out of their track because it already has one at that time (a frame stamped with the time
        # of the one before it): a vehicle a frame further on at no later time would make every τ-pair across it
        # too fast, and its points disagree with the vehicle's own motion (every 4th frame so: no vehicle measured)
        self.same_time = 0
        self.t: float | None = None
        # speeds from the frames' smoothed times (update's fit_t) where they were given, not their own: set by the
        # caller once it knows the times jitter (speedometer retime); read when a speed is computed, so a vehicle in
        # view then is measured wholly from smoothed times
        self.smooth_times = False
        self.spacing = FrameSpacing()  # the stream's time between frames: min_track_length as a duration below 12.5 fps
        # the calibration part of speed uncertainties, for the view it was computed for (its VPs: a new scale alone
        # does not change it, and the view's conditioning costs ~20 ms)
        self._calibration_pct: tuple[_PctKey | None, float | None] = (None, None)
        if calibration is not None:
            self.set_calibration(calibration)

    # ------------------------------------------------------------------ inputs
    @property
    def camera(self) -> Camera | None:
        return self.calibration.camera if self.calibration is not None else None

    @property
    def can_measure(self) -> bool:
        return self.camera is not None and self.camera.scale is not None

    @property
    def waiting(self) -> int:
        """Vehicles that left and wait for a calibration with scale."""
        return len(self._pending)

    def set_calibration(self, cal: Calibration | None) -> list[MeasuredVehicle]:
        """Use ``cal`` from now on; returns the vehicles waiting for a scale, measured now if it has one, and, when
        ``cal`` says the camera moved, every vehicle seen before the move."""
        out = []
        if cal is not None and cal.moved_at is not None and (self.calibration is None
                                                              or self.calibration.id != cal.id):
            out = self._camera_moved(float(cal.moved_at))
        if cal is not self.calibration:
            for rec in self._live.values():  # the estimates of the vehicles in view are made again with it
                rec.live_at = -1
        self.calibration = cal
        if not self.can_measure or not self._pending:
            return out
        pending, self._pending = self._pending, []
        return out + _vehicles(self._measure(r) for r in self._stitch_waiting(pending))

    def _camera_moved(self, t_move: float) -> list[MeasuredVehicle]:
        """End what the previous calibration saw: the vehicles in view, cut at ``t_move``, and the ones waiting for a
        scale; measured with the calibration in force until now, or unmeasured with the reason."""
        for rec in list(self._live.values()):
            n = sum(o.t < t_move for o in rec.observations)  # observations are in time order
            if n == 0:  # first seen after the move: a vehicle of the new view if it is still seen after the notice
                self._blind[rec.id] = self.t if self.t is not None else t_move
                continue
            rec.unboxed = [k for k in rec.unboxed if k < n]
            rec.observations = rec.observations[:n]
            del self._live[rec.id]
            self._retired.add(rec.id)
            rec.last_t = rec.observations[-1].t
            rec.cut = True
            self._pending.append(rec)
        pending, self._pending = self._pending, []
        pending.sort(key=lambda r: (r.last_t, r.id))
        if self.can_measure:
            out = _vehicles(self._measure(r) for r in pending)
        else:
            why = (f"the camera moved at {t_move:.1f} s, before the calibration of the view it was seen in "
                   + ("had vanishing points" if self.camera is None else "had a scale"))
            out = _vehicles(self._unmeasured(r, why, self.calibration) for r in pending)
        self.lanes = LaneModel()  # the lanes lie elsewhere in the new view
        self._measured.clear()  # measured in the old view: never again with another view's calibration
        return out

    def update(self, t: float, sightings: Iterable[Sighting], fit_t: float | None = None) -> FrameOutput:
        """Add one frame (time ``t``, seconds) of tracked vehicles; vehicles unseen for ``end_after`` s leave.
        ``fit_t``: the frame's smoothed time, for the speeds' durations while :attr:`smooth_times` is set.
        ValueError for a time that is no finite number (a frame without a timestamp: the caller passes it by, as the
        speedometer does) or goes backwards; one sighting per track id is used (:meth:`_one_per_id`)."""
        if not math.isfinite(t):
            raise ValueError(f"a frame's time must be a finite number of seconds, got {t}")
        if self.t is not None and t < self.t:
            raise ValueError(f"timestamps must not go backwards ({t:.6f} s after {self.t:.6f} s)")
        sightings = self._one_per_id(t, sightings)
        self.t = t
        self.spacing.add(t)
        seen = []
        for s in sightings:
            if s.id in self._retired:  # a track that went on across a camera move: not this vehicle any more
                continue
            rec = self._live.get(s.id)
            if rec is None:
                rec = self._live[s.id] = _Record(s.id)
            if rec.observations and s.t <= rec.observations[-1].t:
                self.same_time += 1
                rec.last_t = s.t
                continue
            obs = _observation(s, self.camera)
            obs.fit_t = None if fit_t is None else float(fit_t)
            if obs.box3d is None and obs.hull is not None and (not obs.truncated or obs.cut_top) and not obs.occluded:
                rec.unboxed.append(len(rec.observations))
            rec.observations.append(obs)
            rec.last_t = s.t
            seen.append(rec)
        finished = self._end([r for r in self._live.values() if t - r.last_t > self.end_after])
        speeds = {}
        if self.can_measure:
            every = frames_needed(LIVE_EVERY, self.spacing.seconds, 1)  # 0.2 s: at 5 fps every frame, not 1 s
            for rec in seen:
                n = len(rec.observations)
                if rec.live_at < 0 or n - rec.live_at >= every or rec.unboxed:
                    rec.live, rec.live_at = self._live_speed(rec), n
                if rec.live is not None:
                    speeds[rec.id] = rec.live
        return FrameOutput(speeds, finished)

    def _one_per_id(self, t: float, sightings: Iterable[Sighting]) -> list[Sighting]:
        """The frame's sightings with one per track id.  Two with one id (a tracker that gave two vehicles, or one
        vehicle twice, the same id) would both go into that vehicle's points, and its speed would be neither's:
        the one nearest to where the track's motion so far puts it is kept (for a track not seen before: the first
        that is not a copy of another id's sighting of the frame), the others are dropped and counted in
        :attr:`duplicates`.  ValueError for a sighting without a finite time."""
        sightings = list(sightings)
        by_id: dict[int, list[Sighting]] = {}
        for s in sightings:
            if not math.isfinite(s.t):
                raise ValueError(f"vehicle {s.id}: its time must be a finite number of seconds, got {s.t}")
            by_id.setdefault(s.id, []).append(s)
        out = []
        for vid, group in by_id.items():
            if len(group) > 1:
                self.duplicates += len(group) - 1
                self.first_duplicate = self.first_duplicate or (vid, t)
                rec = self._live.get(vid)
                if rec is not None and rec.observations:
                    there = _expected_centre(rec.observations, t)
                    gaps = [float(np.hypot(*(np.reshape(s.box, (2, 2)).mean(axis=0) - there))) for s in group]
                    gaps = [g if math.isfinite(g) else math.inf for g in gaps]
                    group = [group[gaps.index(min(gaps))]]
                else:  # a new track: not the copy of another track's sighting (the same box under two ids)
                    others = [o.box for o in sightings if o.id != vid]
                    claimed = (box_iou([c.box for c in group], others).max(axis=1) >= 0.5 if others
                               else np.zeros(len(group), bool))
                    group = [c for c, taken in zip(group, claimed) if not taken] or group
            out.append(group[0])
        return out

    def cut(self) -> list[MeasuredVehicle]:
        """The stream jumped (a seek, parts joined): every vehicle in view leaves now, cut short (a brief one may still
        be a vehicle), measured with what was seen before the jump; a track id that goes on after it (a tracker that
        did not end its tracks there) is not taken up again: its next sightings are of another moment."""
        for rec in self._live.values():
            rec.cut = True
            self._retired.add(rec.id)
        return self._end(list(self._live.values()))

    def flush(self) -> list[MeasuredVehicle]:
        """End of stream: every vehicle in view leaves; those still waiting for a scale are reported unmeasured."""
        for rec in self._live.values():
            rec.cut = True
        out = self._end(list(self._live.values()))
        pending, self._pending = self._pending, []
        out += _vehicles(self._unmeasured(r, self._no_calibration_reason()) for r in pending)
        return out

    # ------------------------------------------------------------------ measurement
    def _end(self, records: list[_Record]) -> list[MeasuredVehicle]:
        out = []
        for rec in sorted(records, key=lambda r: (r.last_t, r.id)):
            del self._live[rec.id]
            noticed = self._blind.pop(rec.id, None)
            if noticed is not None and rec.last_t <= noticed:  # seen only between a camera move and its notice
                self.discarded += 1
                self.not_counted_ids += rec.merged + [rec.id]
                continue
            if self.can_measure and self.stitch_gap > 0 and self._stitch(rec):
                continue  # continued by a later track of the same vehicle: measured with it
            if self.can_measure:
                out += _vehicles([self._measure(rec)])
            else:
                self._pending.append(rec)
        excess = len(self._pending) - self.max_waiting
        if excess > 0:  # held long enough: memory stays bounded and the counts reach the files
            old, self._pending = self._pending[:excess], self._pending[excess:]
            why = (f"no calibration with a scale while {self.max_waiting} later vehicles left (at most that many "
                   "wait for one; the oldest is then written unmeasured)")
            out += _vehicles(self._unmeasured(r, why) for r in old)
        return out

    def _stitch_waiting(self, waiting: list[_Record]) -> list[_Record]:
        """The vehicles that left before a calibration with scale, less those a later track continues: each is
        stitched now, as :meth:`_end` does once a scale exists, into the track that continues it — one that left
        after it and waited too, or one still in view.  Before stop 54 these were never stitched, and a vehicle the
        detector lost for a moment while vpdetect was still learning (the first 25 s of a file) was counted twice."""
        if self.stitch_gap <= 0:
            return waiting
        waiting = sorted(waiting, key=lambda r: (r.last_t, r.id))
        kept = []
        for k, rec in enumerate(waiting):
            if not self._stitch(rec, [*waiting[k + 1:], *self._live.values()]):
                kept.append(rec)
        return kept

    def _stitch(self, rec: _Record, candidates: Iterable[_Record] | None = None) -> bool:
        """Hand a vehicle that left over to the live track that continues it, if one does (or to one of
        ``candidates``: :meth:`_stitch_waiting`): a track that started
        within ``stitch_gap`` seconds after it was last seen, whose first reference point lies where this one's
        motion (its median road velocity) predicts, within the jump tolerance of :class:`SpeedChecks` plus 15 % of
        the distance predicted along the road and ``STITCH_LATERAL_M`` across it (the same lane).  The detector lost the vehicle for a moment and the tracker gave it a new id; the
        two pieces together are measured as one vehicle (under the later id), often the only way it is seen
        across the whole measured stretch of road."""
        cam = self.camera
        times, px, _, _ = self._reference_points(rec, cam)
        if len(px) < 2:
            return False
        world = cam.to_world(px)[:, :2]
        v = _median_velocity(world, times, self.tau)
        best, best_d = None, np.inf
        for other in self._live.values() if candidates is None else candidates:
            first = other.observations[0].t
            gap = first - rec.last_t
            if not 0 < gap <= self.stitch_gap:
                continue
            t2, px2, _, _ = self._reference_points(other, cam)
            if len(px2) == 0:
                continue
            miss = cam.to_world(px2[:1])[0, :2] - world[-1] - v * (t2[0] - times[-1])
            if abs(miss[1]) > STITCH_LATERAL_M:  # not in the same lane (world y is across the road)
                continue
            d = float(np.linalg.norm(miss))
            tolerance = max(self.checks.jump_m, self.checks.jump_px * float(metres_per_pixel(cam, px2[:1])[0]))
            if d <= tolerance + 0.15 * float(np.linalg.norm(v)) * (t2[0] - times[-1]) and d < best_d:
                best, best_d = other, d
        if best is None:
            return False
        best.unboxed = rec.unboxed + [k + len(rec.observations) for k in best.unboxed]
        best.observations[:0] = rec.observations
        best.merged[:0] = rec.merged + [rec.id]
        return True

    def _no_calibration_reason(self) -> str:
        if self.camera is None:
            return "no calibration (the stream ended before the vanishing points were known)"
        return "the calibration has no scale (the stream ended before the scale was known)"

    def _reference_points(self, rec: _Record, camera: Camera, last: int | None = None
                          ) -> tuple[np.ndarray, np.ndarray, Track, np.ndarray]:
        """(times (M,), pixels (M, 2), track, the times for the speeds' durations (M,)) of the finished-track
        reference points available with ``camera``, from every observation or from the ``last`` ones."""
        obs = rec.observations
        if rec.unboxed:  # seen without a 3D box (no vanishing points at the time): build it from the hull now
            idx, rec.unboxed = rec.unboxed, []
            late = Track(id=rec.id, state=TrackState.FINISHED, observations=[obs[k] for k in idx])
            if camera is not self._late_camera:
                self._late_heights.clear()
                self._late_camera = camera
            rebuild_boxes(camera, late, TrackerConfig.shape_fits, self._late_heights.value,
                          shape_min_px(self.calibration.image_size if self.calibration is not None else None))
            self._late_heights.add(late.height)
        if last is not None:
            obs = obs[-last:]
        track = Track(id=rec.id, state=TrackState.FINISHED, observations=obs)
        _update_direction(track)
        _set_references(camera, track, obs)
        px, _ = track.reference_points()
        times = track.timestamps
        ok = np.all(np.isfinite(px), axis=1)
        fit = times
        if self.smooth_times:
            fit = np.array([o.t if o.fit_t is None else o.fit_t for o in obs], np.float64)
        return times[ok], px[ok], track, fit[ok]

    def _live_speed(self, rec: _Record) -> LiveSpeed | None:
        """The current estimate, from the last LIVE_WINDOW observations (bounded cost, also for a vehicle standing
        in a queue for minutes; equal to the final speed for shorter tracks): none while the vehicle would be
        reported unmeasured.  Made every LIVE_EVERY observations, and at each one that came without a 3D box (its
        box is built at the first call after the calibration, so the order in which the vehicles' late boxes are
        built stays that of their sightings)."""
        _, px, track, fit = self._reference_points(rec, self.camera, last=LIVE_WINDOW)
        m = self._speed(px, fit)
        if not m.measured:
            return None
        n = len(rec.observations)
        if rec.live_label_at < 0 or n - rec.live_label_at >= LIVE_LABEL_EVERY:  # the size settles slowly: not
            rec.live_label, rec.live_label_next = steady_label(  # every frame (0.5 ms per vehicle)
                rec.live_label, rec.live_label_next, self._label(track)[0])
            rec.live_label_at = n
        return LiveSpeed(m.speed_kmh, m.agreement, m.n_pairs, rec.live_label,
                         self.uncertainty(m.speed_kmh, m.spread_kmh, self.calibration))

    @property
    def points_needed(self) -> int:
        """Reference points a vehicle needs: ``min_track_length``, or where the stream's frames are more than
        0.08 s apart the ones that cover its time at 25 fps (10: 0.4 s), at least τ + 1
        (:func:`~gst_trafficcal.frame_rate.frames_needed`: at 10 and 5 fps 6 points, not 1 and 2 s of track)."""
        return frames_needed(self.min_track_length, self.spacing.seconds, self.tau + 1)

    def _speed(self, px: np.ndarray, times: np.ndarray) -> VehicleSpeed:
        """:func:`~gst_trafficcal.speed.vehicle_speed` with the meter's minimum track length (reference points
        before and after dropping the ones that are not the vehicle's own)."""
        none = np.zeros(len(px), bool)
        needed = self.points_needed
        if len(px) < needed:
            return VehicleSpeed(None, 0, f"track too short ({len(px)} reference points, needs {needed})", none)
        m = vehicle_speed(self.camera, px, times, self.tau, self.checks)
        if m.measured and m.kept.sum() < needed:
            return VehicleSpeed(None, 0, f"track too short ({int(m.kept.sum())} consistent reference points of "
                                f"{len(px)}, needs {needed})", m.kept)
        return m

    def remeasure(self) -> list[MeasuredVehicle]:
        """With ``keep_measured``: the vehicles measured (or left unmeasured for their own track) under another
        calibration than the one in force now, measured again with it — same id, the new calibration's id — in the
        order they left.  For the end of a file, whose later calibration saw more: a scale that moved 9 % after
        it first converged (high_camera, stop 40) had left the first vehicles' speeds 9 % off.  Not across a
        camera move (those vehicles belong to the earlier view).  From the reference points found then (the
        vanishing points move little after the first scale; λ most) and the size rescaled.  The kept vehicles are
        then forgotten."""
        kept, self._measured = self._measured, {}
        cal = self.calibration
        if not self.can_measure:
            return []
        out = []
        for k in sorted((k for k in kept.values() if k.calibration_id != cal.id),
                        key=lambda k: (k.rec.last_t, k.rec.id)):
            m = self._speed(k.px, k.fit_times)
            dims = None if k.dims_plane is None else k.dims_plane * self.camera.scale
            label, dims = self._label_of(k.label, dims)
            out.append(self._finish(k.rec, label, m.speed_kmh, m.reason, k.times, k.px, cal, m.n_pairs, m.kept, dims,
                                    m.spread_kmh))
        return out

    def _measure(self, rec: _Record) -> MeasuredVehicle | None:
        """The vehicle's event, measured with the calibration in force; None when the track was no vehicle
        passing (:func:`not_a_vehicle`)."""
        cal = self.calibration
        times, px, track, fit = self._reference_points(rec, self.camera)
        if len(px) == 0:
            return self._unmeasured(rec, "no reference point (no 3D box: never fully visible, nor cut by the top edge alone)", cal)
        m = self._speed(px, fit)
        # the road it covered: its own points (the longest consistent run) when there are enough of them — a parked
        # car's points jump to each vehicle that passes it, merging with it for a moment; whether it drove off: its
        # latest points, all of them, as trafficoverlay judges it (a vehicle that stood, then drove off and was missed
        # for a moment has two runs: the standing one is the longest)
        if not m.measured and self._not_counted(rec, px[m.kept] if m.kept.sum() > self.tau else px, px):
            return None
        label, dims = self._label(track)
        if self.keep_measured:
            ends = _Record(rec.id, observations=[rec.observations[0], rec.observations[-1]], last_t=rec.last_t)
            self._measured[rec.id] = _Kept(ends, times, fit, px, track.label,
                                           None if dims is None else dims / self.camera.scale, cal.id)
        return self._finish(rec, label, m.speed_kmh, m.reason, times, px, cal, m.n_pairs, m.kept, dims, m.spread_kmh)

    def _label(self, track: Track) -> tuple[str, np.ndarray | None]:
        """(label, dimensions in metres or None): the detector's label, refined by the vehicle's measured size
        when the detector gave no class of its own (:mod:`gst_trafficcal.vehicles.classify`); dimensions no class
        explains (a flat or broken 3D box: a car 12 m long and half a metre tall) are not reported."""
        return self._label_of(track.label, self._dimensions(track))

    @staticmethod
    def _label_of(label: str, dims: np.ndarray | None) -> tuple[str, np.ndarray | None]:
        """:meth:`_label` from the detector's label and the dimensions (metres) already measured."""
        size = None if dims is None else classify_dimensions(dims)[0]
        if size is not None and size.worst_z > MAX_Z:  # no vehicle is that shape: a degenerate 3D box, not reported
            return label, None
        return refined_label(label, size), dims

    def _dimensions(self, track: Track) -> np.ndarray | None:
        """Length, width and height (metres) of a vehicle whose reference points were just set: length and width
        from the views where each is well conditioned (:func:`~gst_trafficcal.tracking.tracker.track_dimensions`),
        height the median over its measured 3D boxes; None without a scale or a 3D box."""
        cam = self.camera
        if cam is None or cam.scale is None:
            return None
        lw = track_dimensions(track)
        corners = [o.corners_px for o in measured_boxes(track) if o.corners_px is not None]
        if lw is None or not corners:
            return None
        dims = np.array([lw[0], lw[1], float(np.median(box_heights(cam, np.array(corners))))]) * cam.scale
        return dims if bool(np.all(np.isfinite(dims) & (dims > 0))) else None

    def _finish(self, rec: _Record, label: str, speed: float | None, reason: str, times: np.ndarray,
                px: np.ndarray, cal: Calibration | None, n_pairs: int,
                kept: np.ndarray | None = None, dims: np.ndarray | None = None,
                spread_kmh: float = 0.0) -> MeasuredVehicle:
        """The vehicle's event; its reference points (for the BrnoCompSpeed results) only when it was measured,
        and then the ones its speed came from.  ``spread_kmh``: the 1σ its speed samples give
        (:attr:`~gst_trafficcal.speed.VehicleSpeed.spread_kmh`), for its uncertainty."""
        cam = cal.camera if cal is not None else None
        direction = lane = None
        if cam is not None and len(px) < 2 and len(rec.observations) >= 2:
            # not measured (no reference points): the direction its boxes moved in, for the counts per direction
            seen_t = np.array([o.t for o in rec.observations])
            direction = direction_along_road(cam, _box_centres(rec.observations), seen_t)
        elif cam is not None:
            direction = direction_along_road(cam, px, times)
            if cam.scale is not None:
                offset = lateral_offset(cam.to_world(px)[:, 1])
                lane = self.lanes.assign(offset) if speed is not None else self.lanes.lane_of(offset)
        ts = [o.t for o in rec.observations]
        event = VehicleEvent(id=rec.id, label=label, first_timestamp_s=min(ts), last_timestamp_s=max(ts),
                             speed_kmh=speed, reason=reason, lane=lane, direction=direction,
                             calibration_id=cal.id if cal is not None else None, n_samples=n_pairs,
                             speed_uncertainty_kmh=self.uncertainty(speed, spread_kmh, cal),
                             **({} if dims is None else dict(zip(("length_m", "width_m", "height_m"),
                                                                 np.round(dims, 2).tolist()))))
        if speed is None:
            return MeasuredVehicle(event, np.zeros(0), np.zeros((0, 2)), tuple(rec.merged))
        if kept is not None:
            times, px = times[kept], px[kept]
        return MeasuredVehicle(event, times, px, tuple(rec.merged))

    def uncertainty(self, speed: float | None, spread_kmh: float, cal: Calibration | None) -> float | None:
        """Half-width (km/h) of the ~95 % interval around a speed measured with ``cal``
        (:mod:`gst_trafficcal.uncertainty`; the calibration's part computed once per view: its vanishing points)."""
        if speed is None or cal is None:
            return None
        view = _PctKey.of(cal)
        if view is None or self._calibration_pct[0] != view:
            self._calibration_pct = (view, calibration_pct(cal))
        pct = self._calibration_pct[1]
        return None if pct is None else round(speed_uncertainty(speed, spread_kmh, pct), 2)

    def _unmeasured(self, rec: _Record, reason: str, cal: Calibration | None = None) -> MeasuredVehicle | None:
        """The event of a vehicle left unmeasured for ``reason``; None when the track was no vehicle passing."""
        if self._not_counted(rec, np.zeros((0, 2))):
            return None
        return self._finish(rec, rec.track().label, None, reason, np.zeros(0), np.zeros((0, 2)), cal, 0)

    def _not_counted(self, rec: _Record, px: np.ndarray, latest: np.ndarray | None = None) -> bool:
        """Whether the unmeasured track ``rec`` (its own reference points ``px``, pixels, in time order; ``latest``:
        all its points, for whether it drove off, else ``px``) was no vehicle passing; counted in
        :attr:`not_counted` by reason."""
        moved = None
        cam = self.camera
        seen_s = rec.observations[-1].t - rec.observations[0].t
        if len(px) >= 2 and cam is not None and cam.scale is not None and seen_s >= self.min_seen_s:
            # only for a track seen long enough to tell (a vehicle the end of the stream cut after a moment has not
            # gone far yet)
            # or drove off after standing for most of its stay (a queue at lights), as trafficoverlay counts it
            latest = (px if latest is None else latest)[-drive_off_points(self.spacing.seconds):]
            moved = max(moved_along_road(cam, px), drove_along_road(cam, latest))
        why = not_a_vehicle(np.inf if rec.cut else seen_s, moved, self.min_seen_s, self.min_passing_m)
        if why:
            self.not_counted[why] += 1
            self.not_counted_ids += rec.merged + [rec.id]
        return bool(why)

    def take_not_counted_ids(self) -> list[int]:
        """The track ids found to be no vehicle since the last call (not counted, discarded after a camera move):
        a counter downstream takes them out."""
        ids, self.not_counted_ids = self.not_counted_ids, []
        return ids


def moved_along_road(camera: Camera, px: np.ndarray) -> float:
    """Metres along the road (world x; ``camera`` has a scale) between where a track was in its first and in its last
    quarter: the medians of its reference points ``px`` (N x 2 pixels in time order, N >= 1) in each.  The medians
    ride out a parked car's point, which jumps by the car's length when its front is not known, and back.  The
    measure of :func:`not_a_vehicle`'s ``moved_m``, for speedometer and for trafficoverlay's own counter."""
    px = np.asarray(px, np.float64).reshape(-1, 2)
    q = max(1, len(px) // 4)
    return metres_between(camera, px[:q], px[-q:])


def metres_between(camera: Camera, a: np.ndarray, b: np.ndarray) -> float:
    """Metres along the road (world x) between the medians of two sets of reference points (pixels)."""
    along = [np.median(camera.to_world(np.asarray(p, np.float64).reshape(-1, 2))[:, 0]) for p in (a, b)]
    return float(abs(along[1] - along[0]))


def drive_off_points(spacing_s: float | None) -> int:
    """How many of a track's latest reference points :func:`drove_along_road` judges, for frames ``spacing_s`` apart:
    :data:`DRIVE_OFF_POINTS`, or below 12.5 fps those covering its time (:func:`~gst_trafficcal.frame_rate.
    frames_needed`, at least :data:`DRIVE_OFF_FLOOR`)."""
    return frames_needed(DRIVE_OFF_POINTS, spacing_s, DRIVE_OFF_FLOOR)


def drove_along_road(camera: Camera, px: np.ndarray) -> float:
    """Metres a track drove steadily along the road (world x; ``camera`` has a scale) over its latest reference points
    ``px`` (N x 2 pixels at full rate, in time order): from the median of their first quarter to that of their last
    when each quarter's median is further in one direction than the one before by at least a sixth of that; 0
    otherwise, or with under :data:`DRIVE_OFF_FLOOR` points.  A vehicle that stood for most of its stay and then
    drove off shows it here while :func:`moved_along_road` over an even sample of its whole stay does not yet; a
    parked car's point jumping by the car's length (and back) is one step among still ones, which at most two of
    the three advances show."""
    along = camera.to_world(np.asarray(px, np.float64).reshape(-1, 2))[:, 0]
    if len(along) < DRIVE_OFF_FLOOR or not np.all(np.isfinite(along)):
        return 0.0
    m = np.array([np.median(q) for q in np.array_split(along, 4)])
    total = float(m[-1] - m[0])
    return abs(total) if total and np.all(np.diff(m) * np.sign(total) >= abs(total) / 6) else 0.0


def not_a_vehicle(seen_s: float, moved_m: float | None, min_seen_s: float = MIN_SEEN_S,
                  min_passing_m: float = MIN_PASSING_M) -> str:
    """Why a track left unmeasured is no vehicle passing ("" when it may be one): :data:`BRIEF` when it was seen
    for under ``min_seen_s`` seconds — vehicles take seconds to cross a traffic camera's view; such tracks are a
    piece of a vehicle followed by another track, or a detector's flicker —, :data:`STATIONARY` when it moved under
    ``min_passing_m`` metres along the road (``moved_m``; None: not known) — a parked vehicle, or a fixed object
    taken for one, which the traffic counts must not count once per time it is occluded."""
    if seen_s < min_seen_s:
        return BRIEF
    if moved_m is not None and moved_m < min_passing_m:
        return STATIONARY
    return ""


def _vehicles(found: Iterable[MeasuredVehicle | None]) -> list[MeasuredVehicle]:
    """The vehicles among ``found`` (None: a track that was no vehicle passing)."""
    return [m for m in found if m is not None]


def _observation(s: Sighting, camera: Camera | None) -> Observation:
    """The tracker's observation record for a sighting (3D box extents recovered from the corners)."""
    box = np.asarray(s.box, np.float64)
    hull = s.hull
    if hull is None and np.all(np.isfinite(box)):
        hull = np.array([[box[0], box[1]], [box[2], box[1]], [box[2], box[3]], [box[0], box[3]]])
    obs = Observation(t=float(s.t), box=box, det_box=box, score=float(s.confidence), label=s.label, hull=hull,
                      truncated=s.truncated, occluded=s.occluded, silhouette=s.silhouette and s.hull is not None,
                      cut_top=s.cut_top)
    # a 3D box far outside the tracked hull (a degenerate solve upstream) gives no reference point
    if (s.corners_px is not None and camera is not None
            and corners_fit_hulls(s.corners_px[None], box[None, :2], box[None, 2:])[0]):
        road = pixels_to_road(camera, s.corners_px[:4])  # bottom corners: (x0,y0), (x1,y0), (x0,y1), (x1,y1)
        if np.all(np.isfinite(road)):
            obs.box3d = np.array([road[0, 0], road[1, 0], road[0, 1], road[2, 1], 0.0])
            obs.corners_px = np.asarray(s.corners_px, np.float64)
            obs.ref_px = s.ref_px
    return obs


def _box_centres(observations: list[Observation]) -> np.ndarray:
    """Centres of the observations' 2D boxes (N x 2 pixels): they move with the vehicle along the road even where
    the box is cut by the frame's edge (growing as it enters, shrinking as it leaves)."""
    boxes = np.array([o.box for o in observations], np.float64).reshape(-1, 4)
    return (boxes[:, :2] + boxes[:, 2:]) / 2.0


def _expected_centre(observations: list[Observation], t: float) -> np.ndarray:
    """Where the box centre of a track seen in ``observations`` should be at time ``t``: its last one moved on at the
    pace of its last two (the last one itself for a track seen once, or twice at one time)."""
    centres = _box_centres(observations[-2:])
    if len(centres) < 2 or not observations[-1].t > observations[-2].t:
        return centres[-1]
    pace = (centres[1] - centres[0]) / (observations[-1].t - observations[-2].t)
    return centres[1] + pace * (t - observations[-1].t)


def direction_along_road(camera: Camera, px: np.ndarray, times: np.ndarray) -> str | None:
    """Towards/away from VP1 from the reference points' motion along the road (None when it barely moves); also
    trafficoverlay's, from its own trail of a track, without speedometer."""
    x = pixels_to_road(camera, px)[:, 0]
    ok = np.isfinite(x)
    if ok.sum() < 2:
        return None
    x, t = x[ok], np.asarray(times, np.float64)[ok]
    tc = t - t.mean()
    denom = float(tc @ tc)
    if denom <= 0:
        return None
    slope = float(tc @ (x - x.mean())) / denom
    if abs(slope * np.ptp(t)) < MIN_DIRECTION_SPAN:
        return None
    return TOWARDS_VP1 if slope > 0 else AWAY_FROM_VP1


def speed_params(live: LiveSpeed, label: str, model_name: str = "") -> dict[str, Any]:
    """The ``"speed"`` ROI structure {speed_kmh, label, model_name, confidence, speed_uncertainty_kmh} of a vehicle
    in view (the last when known: the ~95 % interval's half-width)."""
    params = {"speed_kmh": float(live.speed_kmh), "label": str(label), "model_name": str(model_name),
              "confidence": float(live.confidence)}
    if live.uncertainty_kmh is not None:
        params["speed_uncertainty_kmh"] = float(live.uncertainty_kmh)
    return params

