"""Multi-vehicle tracker of the paper (§4.2): detections -> convex hulls -> Kalman-filtered tracks.

* Association: Hungarian assignment (``scipy.optimize.linear_sum_assignment``) of detections to the Kalman
  predictions of the tracks' detection boxes, cost 1 − IoU with a centre-distance fallback for small, fast
  boxes, gated by IoU/distance and size ratio.  (The detector's box is steadier from frame to frame than the
  hull's, which changes when blobs merge or split; the hull feeds the 3D box.)
* States: tentative until ``n_init`` hits (frames more than 0.08 s apart: the hits covering ``n_init`` 25 fps
  frames' time, at least 2, :func:`~gst_trafficcal.frame_rate.frames_needed`), confirmed, lost while unmatched
  (predicted), finished after ``max_lost`` seconds without a match.  Time comes from the caller's timestamps
  (buffer PTS), never frame counts, so dropped frames only widen the prediction step.
* The paper's heuristic: a detection partly covered by a nearer one is not measured, so only fully visible
  vehicles give 3D boxes and reference points.  It still keeps its track alive (association and the 2D Kalman
  filter), so a vehicle that passes behind another one keeps its id; it never starts a track.
* Static occluders (:mod:`.occluders`): the tracker learns where a pole or post in front of the road hides
  vehicles; a vehicle cut by one is tracked but not measured, its track coasts through it (with a calibration on
  the road: the last 3D box moved at the vehicle's road velocity, since image motion accelerates under
  perspective), and its fragments start no tracks of their own.
* 3D boxes (:mod:`.box3d`): from clean vehicle silhouettes (a segmentation model's hulls) the box holds the
  car body shape that explains the track's tangents best, one shape per track so the reference point does not
  jump between bodies; from background-model hulls (which keep part of the cast shadow) the plain box
  (``TrackerConfig.body_shapes``).
* Works in 2D without a calibration; :meth:`Tracker.set_camera` switches to 3D boxes at any time without losing
  tracks: every observation keeps its convex hull and timestamp, and the boxes and reference points of the
  observations already made are rebuilt, so a vehicle seen before calibration is still measured.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from enum import Enum

import numpy as np
from scipy.optimize import linear_sum_assignment

from ..detection.records import Detections, box_iou, clip_boxes
from ..errors import InputError
from ..frame_rate import FrameSpacing, frames_needed
from ..geometry import Camera
from .box3d import (CORNER_BITS, TypicalHeight, _boxes, _pad_hulls, fit_shapes, pixels_to_road, track_choice,
                    track_class, world_rays, world_to_pixels)
from .kalman import BoxKF, ConstantVelocityKF
from .occluders import OccluderMap, complete_boxes


class TrackState(str, Enum):
    TENTATIVE = "tentative"
    CONFIRMED = "confirmed"
    LOST = "lost"
    FINISHED = "finished"


@dataclass
class Observation:
    """One frame of a track: what was measured (box, hull) and what was derived from it (3D box, reference)."""

    t: float  # seconds (from the buffer PTS)
    box: np.ndarray  # 2D box of the convex hull (detection box when there is no hull), xyxy pixels
    det_box: np.ndarray  # the detector's box
    score: float
    label: str
    hull: np.ndarray | None = None  # convex hull, Kx2 pixels
    truncated: bool = False  # touches the image border: not fully visible, no 3D box (but see cut_top)
    occluded: bool = False  # partly covered by a nearer vehicle: not measured, no 3D box
    cut_top: bool = False  # truncated by the image's top edge alone: 3D box, measured only as MIN_WHOLE_BOXES says
    box3d: np.ndarray | None = None  # x0, x1, y0, y1, h in world plane units
    corners_px: np.ndarray | None = None  # 8x2 pixels, order box3d.CORNER_BITS
    ref_px: np.ndarray | None = None  # reference point (centre of the bottom-front edge), pixels
    ref_road: np.ndarray | None = None  # the same on the road plane, world plane units (x along VP1, y across)
    ref_road_filtered: np.ndarray | None = None  # Kalman-filtered reference point on the road
    silhouette: bool = False  # the hull is a clean vehicle silhouette (segmentation), so car body shapes apply
    shape_params: np.ndarray | None = field(default=None, repr=False)  # (S, 5) box of each body shape
    shape_fit: np.ndarray | None = field(default=None, repr=False)  # (S,) misfit of each shape (radians)
    shape_ok: bool = field(default=False, repr=False)  # the hull's tangents were valid
    length_px: float = field(default=0.0, repr=False)  # pixels a car's length would span along the road here
    # the frame's smoothed time (frame_jitter.FrameRetimer: speedometer retime) for speed durations; None: t
    fit_t: float | None = field(default=None, repr=False)


@dataclass
class Track:
    """A tracked vehicle: id (≥ 1), state and the list of its observations (one per matched frame)."""

    id: int
    state: TrackState
    observations: list[Observation] = field(default_factory=list)
    direction: int = 0  # +1 moving towards VP1, -1 away from it, 0 unknown (no calibration yet)
    hits: int = 0
    last_t: float = 0.0
    kf_t: float = 0.0  # time of the last detection that updated the 2D filter (not one cut by a static occluder)
    kf: BoxKF | None = field(default=None, repr=False)
    road_kf: ConstantVelocityKF | None = field(default=None, repr=False)
    road_kf_t: float = field(default=0.0, repr=False)
    ever_confirmed: bool = False
    shape: int = 0  # index of the body shape its 3D boxes hold (0 = the plain box; see box3d.fit_shapes)
    height: float | None = None  # plain-box height over the fits that chose the shape (plane units), once chosen
    proportions: str = ""  # what those fits' plain boxes say it is (box3d.proportions_class; "" before any fit)

    @property
    def label(self) -> str:
        labels = [o.label for o in self.observations if o.label]
        return max(set(labels), key=labels.count) if labels else ""

    @property
    def timestamps(self) -> np.ndarray:
        return np.array([o.t for o in self.observations], np.float64)

    @property
    def boxes(self) -> np.ndarray:
        return np.array([o.box for o in self.observations], np.float64).reshape(-1, 4)

    @property
    def last(self) -> Observation:
        return self.observations[-1]

    def reference_points(self) -> tuple[np.ndarray, np.ndarray]:
        """(pixels (M, 2), road plane (M, 2)) per observation; NaN where no 3D box was available."""
        px = np.array([o.ref_px if o.ref_px is not None else (np.nan, np.nan) for o in self.observations])
        road = np.array([o.ref_road if o.ref_road is not None else (np.nan, np.nan) for o in self.observations])
        return px.reshape(-1, 2), road.reshape(-1, 2)

    def recompute(self, camera: Camera, shape_fits: int | None = None, typical_height: float | None = None,
                  shape_min_px: float = 0.0) -> None:
        """(Re)build the 3D boxes and reference points of every observation with ``camera`` (the body shape
        chosen over the first ``shape_fits`` silhouette fits where a car's length spans ``shape_min_px``, as the
        tracker does live; ``typical_height``: the scene's, box3d.TypicalHeight)."""
        rebuild_boxes(camera, self, shape_fits, typical_height, shape_min_px)
        _update_direction(self)
        _set_references(camera, self, self.observations)
        self.road_kf = None
        for o in self.observations:
            _filter_road(self, o)


@dataclass
class TrackerConfig:
    """Tracker tuning; times in seconds."""

    n_init: int = 3  # hits before a track is confirmed (below 12.5 fps fewer: the same time, at least 2)
    max_lost: float = 1.5  # seconds a confirmed track survives without a match (long occlusions)
    tentative_lost: float = 0.25  # seconds a tentative track survives without a match (detectors run every
    # N-th frame leave gaps; a false positive rarely recurs at the predicted place)
    iou_gate: float = 0.2  # minimum IoU to associate (below it only the centre-distance fallback applies)
    dist_gate: float = 0.4  # centre distance fallback, in units of the predicted box diagonal
    size_gate: float = 1.8  # maximum ratio between the areas of the predicted and the detected box
    drop_occluded: bool = True  # the paper's heuristic
    occlusion_overlap: float = 0.02  # fraction of a detection's area covered by a nearer one that drops it
    border: float = 2.0  # pixels: boxes this close to the image edge are truncated (not fully visible)
    duplicate_iou: float = 0.5  # an unmatched detection overlapping a matched one this much starts no track
    min_direction_span: float = 0.02  # plane units the box centre must move along the road to fix the direction
    # 3D boxes: "auto" = car body shapes for clean silhouettes (hulls that come with the detections, e.g. from
    # vehicleseg), the plain box for the background model's hulls (their cast-shadow part misleads a body fit:
    # measured, speeds got worse); "cars" = body shapes always; "box" = Dubská's plain box always
    body_shapes: str = "auto"
    # the body shape is chosen over a track's first `shape_fits` silhouette fits and then kept: every box the
    # tracker publishes holds it, so the reference points a speed is measured from come from one construction
    # (re-choosing it along the track moved them by up to the shapes' difference at every switch: measured on
    # the vehicleseg replays, 22 of 55 tracks switched 142 times, and their speed samples disagreed)
    shape_fits: int = 10
    # ... counting only the fits where a car's length spans at least this fraction of the frame's width along the
    # road (Observation.length_px): an oncoming vehicle is first seen far down the road, where its length is a few
    # pixels; there its plain box came out 15-20 m long and no car body fitted (a view along the road, the
    # replays), or the box fitted a small blob as well as any body (exact silhouettes), and the box, held for the
    # whole track, put the fronts on the front tyres, 0.5-0.9 m behind the bumper where speeds are measured
    # (docs/tracking.md "Oncoming fronts"); until such a fit comes, the choice over the others stands in; 0: every
    # fit counts
    shape_min_length: float = 0.01
    # static occluders (a lamp pole, a sign post in front of the road) learned from where vehicles are seen
    # (occluders.OccluderMap): a vehicle touching one is not measured, its cut box edges are completed with the
    # track's predicted size, and its fragments start no tracks, so a vehicle keeps one track behind a pole
    occluders: bool = True
    fragment_margin: float = 0.2  # a cut detection must lie mostly inside a track's predicted box grown by this
    # a big vehicle whose own detection is missing this frame still occludes (the paper's heuristic) what lies
    # behind its last detected box, for `lost_occludes` seconds, if that box is at least `big_occluder` times the
    # other detection's area: near the camera a bus's uniform roof can break up into a few small boxes, which must
    # not start tracks, and a car emerging from behind it must not be measured from its visible top
    lost_occludes: float = 0.5
    big_occluder: float = 4.0
    # with a calibration, a track without a measured box this frame (lost, or cut by an occluder) is predicted on the
    # road (its last 3D box moved at its road velocity) instead of at constant image velocity (_coast_on_road)
    coast_on_road: bool = True
    # ... once its measured 3D boxes of the last second are at least 5 and span at least this (seconds: a track that
    # began as a blob of two vehicles driving apart had 5 boxes over 0.16 s and coasted along one of them)
    coast_min_span: float = 0.25

    def __post_init__(self) -> None:
        if self.n_init < 1:
            raise InputError(f"n_init must be at least 1, got {self.n_init}")
        if self.max_lost < 0:
            raise InputError(f"max_lost must be non-negative, got {self.max_lost}")
        if self.body_shapes not in ("auto", "cars", "box"):
            raise InputError(f"body_shapes must be auto, cars or box, got {self.body_shapes!r}")
        if self.shape_fits < 1:
            raise InputError(f"shape_fits must be at least 1, got {self.shape_fits}")
        if not 0.0 <= self.shape_min_length < 1.0:
            raise InputError(f"shape_min_length must be in [0, 1) of the frame width, got {self.shape_min_length}")


@dataclass
class FrameResult:
    """Output of one :meth:`Tracker.update`: the track id of each input detection (0 = none) and the tracks."""

    t: float
    track_ids: np.ndarray  # (N,) per input detection; 0 when unmatched or not yet confirmed
    occluded: np.ndarray  # (N,) bool: partly covered by a nearer detection (tracked, not measured)
    tracks: list[Track]  # confirmed tracks observed in this frame, in detection order

    def track_of(self, i: int) -> Track | None:
        tid = int(self.track_ids[i])
        return next((tr for tr in self.tracks if tr.id == tid), None)


class Tracker:
    """Online tracker; feed it one frame of detections (and their convex hulls) at a time."""

    def __init__(self, config: TrackerConfig | None = None, camera: Camera | None = None,
                 image_size: tuple[int, int] | None = None) -> None:
        self.config = config or TrackerConfig()
        self.camera: Camera | None = None
        self.image_size = image_size
        self.tracks: list[Track] = []
        self.finished: list[Track] = []
        self._ids = itertools.count(1)
        self.t: float | None = None
        self.spacing = FrameSpacing()  # the stream's time between frames: n_init as a duration below 12.5 fps
        self._silhouettes = False  # this frame's hulls get the car body shapes (set by update)
        self.occluders: OccluderMap | None = OccluderMap() if self.config.occluders else None
        self.typical_height = TypicalHeight()  # of the vehicles whose body shape is chosen (plane units)
        if camera is not None:
            self.set_camera(camera)

    # ----------------------------------------------------------------- calibration
    def set_camera(self, camera: Camera | None) -> None:
        """Use ``camera`` from now on (None: back to 2D); rebuilds the 3D data of live and finished tracks (those
        not yet taken with :meth:`pop_finished`; call :meth:`Track.recompute` on the ones taken earlier)."""
        same = (camera is not None and self.camera is not None and np.allclose(camera.vp1, self.camera.vp1)
                and np.allclose(camera.vp2, self.camera.vp2) and np.allclose(camera.pp, self.camera.pp))
        self.camera = camera
        if self.occluders is not None:
            self.occluders.vp1 = None if camera is None else np.asarray(camera.vp1, np.float64)
        if same or camera is None:
            return
        self.typical_height.clear()  # plane units change with the camera
        for tr in sorted(self.tracks + self.finished, key=lambda tr: tr.id):  # in the order they were chosen
            tr.recompute(camera, self.config.shape_fits, self.typical_height.value, self.shape_min_px)
            self.typical_height.add(tr.height)

    @property
    def shape_min_px(self) -> float:
        """:func:`shape_min_px` of this tracker's frames and config."""
        return shape_min_px(self.image_size, self.config.shape_min_length)

    # ----------------------------------------------------------------- main step
    def update(self, t: float, detections: Detections, hulls: list[np.ndarray | None] | None = None,
               image_size: tuple[int, int] | None = None, silhouettes: bool = False) -> FrameResult:
        """Advance to time ``t`` (seconds) with this frame's detections; returns the association.  ``silhouettes``:
        the hulls are clean vehicle outlines (a segmentation model's), not a background model's."""
        cfg = self.config
        self._silhouettes = cfg.body_shapes == "cars" or (cfg.body_shapes == "auto" and silhouettes)
        if image_size is not None:
            self.image_size = image_size
        if self.t is not None and t < self.t:
            raise InputError(f"timestamps must not go backwards ({t:.6f} s after {self.t:.6f} s)")
        dt = 0.0 if self.t is None else t - self.t
        self.t = t
        self.spacing.add(t)
        # hits that confirm a track: n_init, or below 12.5 fps those covering its time at 25 fps (at least 2)
        n_init = frames_needed(cfg.n_init, self.spacing.seconds, min(2, cfg.n_init))
        n = len(detections)
        hulls = list(hulls) if hulls is not None else [None] * n
        if len(hulls) != n:
            raise InputError(f"{len(hulls)} hulls for {n} detections")
        det_boxes = detections.boxes.astype(np.float64)
        meas = det_boxes.copy()
        for i, h in enumerate(hulls):
            if h is not None and len(h) >= 3:
                meas[i] = [h[:, 0].min(), h[:, 1].min(), h[:, 0].max(), h[:, 1].max()]
            else:
                hulls[i] = None

        occluded = self._occluded(det_boxes) if cfg.drop_occluded else np.zeros(n, bool)
        # edges of the visible outline that touch a static occluder: the vehicle may go on behind it
        occ_map = self.occluders if self.image_size is not None else None
        cut = occ_map.cut_sides(meas) if occ_map is not None else np.zeros((n, 4), bool)

        prev_t = t - dt
        for tr in self.tracks:
            tr.kf.predict(dt)
            if tr.kf_t < prev_t and self.camera is not None and cfg.coast_on_road:  # coasting: follow it on the road
                _coast_on_road(self.camera, tr, t, min_span=cfg.coast_min_span)
        pred = np.array([tr.kf.box for tr in self.tracks]).reshape(-1, 4)
        completed = complete_boxes(det_boxes, cut, pred)  # (T, N, 4): det_boxes where nothing is cut
        pairs = self._associate(self._visible(pred), completed, det_boxes, cut.any(axis=1))
        if cfg.drop_occluded:
            occluded |= self._behind_lost(det_boxes, {ti for ti, _ in pairs}, t)

        track_ids = np.zeros(n, np.int64)
        matched_tracks: set[int] = set()
        new_obs: list[tuple[Track, Observation, int]] = []
        matched_det = set()
        for ti, i in pairs:
            tr = self.tracks[ti]
            obs = self._observation(t, detections, i, meas[i], hulls[i], occluded[i], cut[i].any())
            if not cut[i].any():  # a vehicle cut by a static occluder coasts on its prediction
                tr.kf.update(det_boxes[i])
                tr.kf_t = t
            tr.observations.append(obs)
            tr.hits += 1
            tr.last_t = t
            if tr.state is TrackState.LOST or (tr.state is TrackState.TENTATIVE and tr.hits >= n_init):
                tr.state = TrackState.CONFIRMED
                tr.ever_confirmed = True
            matched_tracks.add(ti)
            matched_det.add(i)
            new_obs.append((tr, obs, i))

        # unmatched tracks: tentative ones survive tentative_lost seconds, confirmed ones coast for max_lost
        survivors = []
        for ti, tr in enumerate(self.tracks):
            if ti not in matched_tracks:
                if tr.state is TrackState.TENTATIVE:
                    if t - tr.last_t > cfg.tentative_lost:
                        continue
                    survivors.append(tr)
                    continue
                tr.state = TrackState.LOST
                if t - tr.last_t > cfg.max_lost:
                    self._finish(tr)
                    continue
            survivors.append(tr)
        self.tracks = survivors

        # unmatched detections start tentative tracks (unless they duplicate a matched vehicle, or are a fragment
        # of one: cut by a static occluder and inside the box it was matched with, completed across the occluder)
        taken = det_boxes[sorted(matched_det)] if matched_det else np.zeros((0, 4))
        hosts = completed[tuple(np.array(pairs).T)] if pairs else np.zeros((0, 4))
        for i in range(n):
            if i in matched_det or occluded[i]:
                continue
            if len(taken) and box_iou(det_boxes[i:i + 1], taken).max() > cfg.duplicate_iou:
                continue
            if cut[i].any() and len(hosts) and _inside(det_boxes[i:i + 1], hosts).max() >= 0.5:
                continue
            tr = Track(id=next(self._ids), state=TrackState.TENTATIVE, hits=1, last_t=t, kf_t=t,
                       kf=BoxKF(det_boxes[i]))
            if cfg.n_init <= 1:
                tr.state, tr.ever_confirmed = TrackState.CONFIRMED, True
            obs = self._observation(t, detections, i, meas[i], hulls[i], False, cut[i].any())
            tr.observations.append(obs)
            self.tracks.append(tr)
            new_obs.append((tr, obs, i))
            taken = np.vstack([taken, det_boxes[i:i + 1]])

        if self.camera is not None and new_obs:
            self._attach_3d([o for _, o, _ in new_obs], [tr for tr, _, _ in new_obs])
        if occ_map is not None:  # learn where vehicles are seen, and which way they move there
            vel = np.full((n, 2), np.nan)
            for tr, o, i in new_obs:  # boxes cut by the image border or covered move oddly: no vote
                if tr.state is TrackState.CONFIRMED and not (o.truncated or o.occluded):
                    vel[i] = tr.kf.velocity
            occ_map.add(self.image_size, [h if h is not None else _rect(b) for h, b in zip(hulls, det_boxes)], vel)

        out_tracks = []
        for tr, obs, i in new_obs:
            if tr.state is TrackState.CONFIRMED:
                track_ids[i] = tr.id
                out_tracks.append(tr)
        return FrameResult(t, track_ids, occluded, out_tracks)

    def flush(self) -> list[Track]:
        """End of stream: finish every live track that was ever confirmed; returns all finished tracks."""
        for tr in self.tracks:
            if tr.ever_confirmed:
                self._finish(tr)
        self.tracks = []
        return self.pop_finished()

    def camera_moved(self) -> list[Track]:
        """The camera moved (another view from now on): every track ends, none continues across the move; back to
        2D until the next calibration; the static occluders are learnt again.  Returns the finished tracks."""
        self.set_camera(None)
        if self.occluders is not None:
            self.occluders = OccluderMap()
        return self.flush()

    def pop_finished(self) -> list[Track]:
        """Tracks that ended since the last call (only ones that were confirmed at some point)."""
        out = [tr for tr in self.finished if tr.ever_confirmed]
        self.finished = []
        return out

    def outputs(self, coast: float = 0.2) -> tuple[np.ndarray, np.ndarray]:
        """(ids (M,), detection boxes (M, 4)) of the vehicles tracked now: confirmed tracks matched in the last
        update, plus lost ones whose prediction is younger than ``coast`` seconds and still inside the image (for
        MOT scoring and drawing; measurements only ever use matched observations)."""
        ids, boxes = [], []
        for tr in self.tracks:
            if tr.state is TrackState.CONFIRMED and tr.last_t == self.t:
                ids.append(tr.id)
                boxes.append(tr.last.det_box)
            elif tr.state in (TrackState.CONFIRMED, TrackState.LOST) and self.t - tr.last_t <= coast:
                b = tr.kf.box
                if self.image_size is None or (b[0] >= 0 and b[1] >= 0 and b[2] <= self.image_size[0]
                                               and b[3] <= self.image_size[1]):
                    ids.append(tr.id)
                    boxes.append(b)
        return np.array(ids, np.int64), np.array(boxes, np.float64).reshape(-1, 4)

    @property
    def confirmed(self) -> list[Track]:
        return [tr for tr in self.tracks if tr.state in (TrackState.CONFIRMED, TrackState.LOST)]

    # ----------------------------------------------------------------- helpers
    def _finish(self, tr: Track) -> None:
        """End a track; its reference points are rebuilt with its final direction and dimensions."""
        tr.state = TrackState.FINISHED
        if self.camera is not None and tr.ever_confirmed:
            _update_direction(tr, self.config.min_direction_span)
            _set_references(self.camera, tr, tr.observations)
        self.finished.append(tr)

    def _observation(self, t: float, det: Detections, i: int, box: np.ndarray, hull, occluded: bool,
                     cut: bool = False) -> Observation:
        trunc = bool(cut)  # cut by a static occluder: not fully visible either
        cut_top = False
        if self.image_size is not None and not trunc:
            w, h = self.image_size
            b = self.config.border
            # the hull's box or the detector's: a hull whose lower part the background model missed (a dark
            # bumper taken for shadow) can stop short of the edge the vehicle is cut by
            both = np.stack([np.asarray(box, np.float64), det.boxes[i].astype(np.float64)])
            edges = np.concatenate([both[:, :2] <= b, both[:, 2:] >= np.array([w - 1 - b, h - 1 - b])], axis=1)
            trunc = bool(edges.any())
            # only the top edge cuts it (a truck's roof above the frame of a near camera): the ground-touching
            # tangents, which give the near faces and the reference point, are whole
            cut_top = trunc and bool(edges[:, 1].any()) and not bool(edges[:, [0, 2, 3]].any())
        return Observation(t=t, box=np.asarray(box, np.float64).copy(), det_box=det.boxes[i].astype(np.float64),
                           score=float(det.scores[i]), label=str(det.labels[i]), hull=hull, truncated=trunc,
                           occluded=bool(occluded), silhouette=self._silhouettes, cut_top=cut_top)

    def _occluded(self, boxes: np.ndarray) -> np.ndarray:
        """Detections partly covered by a nearer detection (the paper's heuristic)."""
        n = len(boxes)
        if n < 2:
            return np.zeros(n, bool)
        lt = np.maximum(boxes[:, None, :2], boxes[None, :, :2])
        rb = np.minimum(boxes[:, None, 2:], boxes[None, :, 2:])
        inter = np.prod((rb - lt).clip(min=0), axis=2)
        area = np.prod(boxes[:, 2:] - boxes[:, :2], axis=1)
        covered = inter / np.maximum(area[:, None], 1e-9)  # fraction of i covered by j
        nearness = self._nearness(boxes)
        nearer = nearness[None, :] > nearness[:, None]  # j nearer than i
        np.fill_diagonal(covered, 0.0)
        return np.any((covered > self.config.occlusion_overlap) & nearer, axis=1)

    def _nearness(self, boxes: np.ndarray) -> np.ndarray:
        """Larger = nearer to the camera: minus road distance of the bottom centre, or its image y without one."""
        bottom = np.stack([(boxes[:, 0] + boxes[:, 2]) / 2, boxes[:, 3]], axis=1)
        if self.camera is not None:
            road = pixels_to_road(self.camera, bottom)
            d = np.linalg.norm(road, axis=1)
            below = world_rays(self.camera, bottom)[:, 2] < 0
            if np.all(below & np.isfinite(d)):
                return -d
        return bottom[:, 1]

    def _visible(self, pred: np.ndarray) -> np.ndarray:
        """The predicted boxes cut to the image: a vehicle leaving the frame is detected by its part still in view,
        so a box that runs past the border is compared with that part (its size and overlap), not with the whole
        vehicle the filter predicts; otherwise the size gate refuses the shrinking part and it starts a new track
        — the same vehicle counted again as a 1-3 frame fragment."""
        return pred if self.image_size is None else clip_boxes(pred, *self.image_size)

    def _behind_lost(self, boxes: np.ndarray, matched: set[int], t: float) -> np.ndarray:
        """(N,) detections occluded by a big vehicle not detected this frame: the last detected box of a confirmed
        track lost for at most ``lost_occludes`` seconds, not farther from the camera, at least ``big_occluder``
        times the detection's area, covering more than ``occlusion_overlap`` of it.

        Near the camera a bus or truck can drop out of the detector for a few frames (its uniform roof filling the
        view as it drives out of the image), leaving a few small boxes on it and, behind it, the top of a car
        emerging: the pieces started tracks (the same vehicle reported again, without a reference point) and the
        car was measured from its visible top, whose bottom edge is the bus's roof (119 km/h instead of 74 on the
        session2_center replay).  The vehicle is still there, so it still occludes.  A track's *predicted* box is
        not used: for a vehicle leaving the image it can cover the whole frame and the far vehicles in it."""
        cfg = self.config
        lost = [tr.observations[-1].det_box for ti, tr in enumerate(self.tracks)
                if ti not in matched and tr.ever_confirmed and t - tr.last_t <= cfg.lost_occludes]
        n = len(boxes)
        if not lost or n == 0:
            return np.zeros(n, bool)
        hosts = np.array(lost, np.float64).reshape(-1, 4)
        covered = _inside(boxes, hosts)  # (H, N)
        area = np.prod(boxes[:, 2:] - boxes[:, :2], axis=1)
        big = np.prod(hosts[:, 2:] - hosts[:, :2], axis=1)[:, None] >= cfg.big_occluder * area[None, :]
        near = self._nearness(np.vstack([hosts, boxes]))
        nearer = near[:len(hosts), None] >= near[None, len(hosts):]  # a piece of it ends where it ends
        return np.any((covered > cfg.occlusion_overlap) & big & nearer, axis=0)

    def _associate(self, pred: np.ndarray, meas: np.ndarray, det: np.ndarray | None = None,
                   cut: np.ndarray | None = None) -> list[tuple[int, int]]:
        """Hungarian assignment of the T predicted boxes to the detections: ``meas`` (T, N, 4), each detection's
        box as seen from each track (completed across static occluders with that track's size).  A detection
        ``cut`` by an occluder is a part of the vehicle: its own box ``det`` must lie mostly inside the track's
        predicted box (grown by ``fragment_margin``), else a fragment could be completed to any track's size."""
        if len(pred) == 0 or meas.shape[1] == 0:
            return []
        cfg = self.config
        lt = np.maximum(pred[:, None, :2], meas[..., :2])
        rb = np.minimum(pred[:, None, 2:], meas[..., 2:])
        inter = np.prod((rb - lt).clip(min=0), axis=2)
        area_p = np.prod(pred[:, 2:] - pred[:, :2], axis=1).clip(min=1.0)[:, None]
        area_m = np.prod(meas[..., 2:] - meas[..., :2], axis=2).clip(min=1.0)
        iou = inter / np.maximum(area_p + area_m - inter, 1e-9)
        pc = (pred[:, :2] + pred[:, 2:]) / 2
        mc = (meas[..., :2] + meas[..., 2:]) / 2
        diag = np.hypot(pred[:, 2] - pred[:, 0], pred[:, 3] - pred[:, 1])
        dist = np.linalg.norm(pc[:, None] - mc, axis=2) / np.maximum(diag[:, None], 1.0)
        log_ratio = np.abs(np.log(area_p / area_m))
        cost = 1.0 - iou + 0.5 * dist + 0.5 * log_ratio
        feasible = ((iou >= cfg.iou_gate) | (dist <= cfg.dist_gate)) & (log_ratio <= np.log(cfg.size_gate))
        if cut is not None and cut.any():
            grow = cfg.fragment_margin * (pred[:, 2:] - pred[:, :2])
            host = np.concatenate([pred[:, :2] - grow, pred[:, 2:] + grow], axis=1)
            feasible[:, cut] &= _inside(det[cut], host) >= 0.5
        big = 1e6
        cost = np.where(feasible, cost, big)
        rows, cols = linear_sum_assignment(cost)
        return [(int(r), int(c)) for r, c in zip(rows, cols) if cost[r, c] < big]

    def _choose_shape(self, track: Track) -> int:
        """The track's body shape while its first fits come in (:func:`track_shape`); once they are all in, its
        height joins the scene's typical one."""
        if track.height is not None:  # chosen
            return track.shape
        typical = self.typical_height.value
        if typical is None:  # the scene's first vehicles: the ones in view so far stand in
            typical = self.typical_height.value_with([_fit_height(tr, self.config.shape_fits, self.shape_min_px)
                                                      for tr in self.tracks
                                                      if tr.height is None])
        shape = track_shape(track, self.config.shape_fits, typical, self.shape_min_px)
        self.typical_height.add(track.height)
        return shape

    def _attach_3d(self, observations: list[Observation], tracks: list[Track]) -> None:
        cam = self.camera
        fit_boxes(cam, observations)
        for tr, obs in zip(tracks, observations):
            new_fit = obs.shape_fit is not None and len(obs.shape_fit) > 1  # else the fits are as before
            shape = self._choose_shape(tr) if new_fit else tr.shape
            if shape != tr.shape:  # the track's body shape changed: every box of the track holds the new one
                tr.shape = shape
                apply_shape(cam, tr, tr.observations)
                reshaped = True
            else:
                apply_shape(cam, tr, [obs])
                reshaped = False
            old = tr.direction
            _update_direction(tr, self.config.min_direction_span)
            if reshaped:
                _set_references(cam, tr, tr.observations, cut_top=False)
                if tr.direction != old and old != 0:
                    tr.road_kf = None
            elif tr.direction != old and old != 0:
                _set_references(cam, tr, tr.observations, cut_top=False)
                tr.road_kf = None
            elif tr.direction != old:
                _set_references(cam, tr, tr.observations, cut_top=False)
            else:
                _set_references(cam, tr, [obs], cut_top=False)
            _filter_road(tr, obs)


def _coast_on_road(camera: Camera, track: Track, t: float, min_points: int = 5, span: float = 1.0,
                   min_span: float = 0.25) -> None:
    """Set the 2D filter of a track that has no measured box this frame (lost, or cut by a static occluder) to
    where its vehicle is on the road: the last 3D box moved at the vehicle's road velocity and projected.

    Image motion accelerates under perspective (a vehicle nearing the camera doubled its image speed within a
    second on ``left_side``), so the constant image velocity of the 2D filter falls behind a vehicle hidden for half a
    second; on the road plane constant velocity is physically right.  The velocity is the least-squares slope of
    the 3D box centres measured in the last ``span`` seconds before the last one (the road filter of the reference
    point has seen points from before the track's direction was known, and the box's near face moves a little
    faster than the vehicle as the fitted box lengthens on approach; the centre least).  Needs at least
    ``min_points`` of them over at least ``min_span`` seconds; the 2D filter is left as it is otherwise."""
    recent = []  # measured observations within ``span`` of the last one, newest first
    for m in reversed(track.observations):
        if m.box3d is None:
            continue
        if recent and m.t < recent[0].t - span:
            break
        recent.append(m)
    if len(recent) < min_points:
        return
    o = recent[0]
    if o.t - recent[-1].t < min_span:
        return
    ts = np.array([m.t for m in recent]) - o.t
    ref = np.array([[(m.box3d[0] + m.box3d[1]) / 2, (m.box3d[2] + m.box3d[3]) / 2] for m in recent], np.float64)
    tc = ts - ts.mean()
    denom = float(np.sum(tc * tc))
    if denom <= 0:
        return
    v = (tc @ (ref - ref.mean(axis=0))) / denom
    if not np.all(np.isfinite(v)):
        return
    x0, x1, y0, y1, h = o.box3d
    corners = np.stack([np.where(CORNER_BITS[:, 0] == 1, x1, x0), np.where(CORNER_BITS[:, 1] == 1, y1, y0),
                        CORNER_BITS[:, 2] * h], axis=1)
    step = 0.04
    shifts = np.array([0.0, t - o.t, t - o.t + step])[:, None, None] * np.array([v[0], v[1], 0.0])
    with np.errstate(divide="ignore", invalid="ignore"):
        px = world_to_pixels(camera, corners[None] + shifts)  # (3, 8, 2): then, now, a moment later
    if not np.all(np.isfinite(px)):
        return
    lo, hi = px.min(axis=1), px.max(axis=1)
    size = hi - lo
    if np.any(size <= 1.0):
        return
    # the detector's box relative to the projected 3D box when it was measured, carried to the moved one
    d = o.det_box
    rel_lo, rel_hi = (d[:2] - lo[0]) / size[0], (d[2:] - lo[0]) / size[0]
    boxes = np.concatenate([lo[1:] + rel_lo * size[1:], lo[1:] + rel_hi * size[1:]], axis=1)  # (2, 4)
    z = np.stack([(boxes[:, 0] + boxes[:, 2]) / 2, (boxes[:, 1] + boxes[:, 3]) / 2,
                  boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1]], axis=1)
    track.kf.kf.x = np.concatenate([z[0], (z[1] - z[0]) / step])


def _rect(box: np.ndarray) -> np.ndarray:
    x0, y0, x1, y1 = np.asarray(box, np.float64)
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])


def _inside(boxes: np.ndarray, hosts: np.ndarray) -> np.ndarray:
    """(M, N): the fraction of each of ``boxes``' (N, 4) area inside each of ``hosts`` (M, 4) — whether a fragment
    cut by a static occluder belongs to a vehicle's box, and how much of a detection a lost big vehicle covers."""
    lt = np.maximum(hosts[:, None, :2], boxes[None, :, :2])
    rb = np.minimum(hosts[:, None, 2:], boxes[None, :, 2:])
    inter = np.prod((rb - lt).clip(min=0), axis=2)
    return inter / np.prod(boxes[:, 2:] - boxes[:, :2], axis=1).clip(min=1.0)


def fit_boxes(camera: Camera, observations: list[Observation]) -> None:
    """Fit the 3D box (the plain box, and the car body shapes for silhouettes) to every observation that has a
    hull and is fully visible or cut by the top edge alone, in two vectorised solves; the box itself is set by
    :func:`apply_shape`."""
    for o in observations:
        o.box3d = o.corners_px = o.shape_params = o.shape_fit = None
        o.shape_ok = False
    for cars in (False, True):
        idx = [k for k, o in enumerate(observations)
               if o.hull is not None and (not o.truncated or o.cut_top) and not o.occluded and o.silhouette == cars]
        if not idx:
            continue
        fits = fit_shapes(camera, [observations[k].hull for k in idx], None if cars else ())
        span = car_length_px(camera, fits.params[0])
        for j, k in enumerate(idx):
            o = observations[k]
            o.shape_params, o.shape_fit, o.shape_ok = fits.params[:, j], fits.fit[:, j], bool(fits.valid[j])
            o.length_px = float(span[j])


CAR_LENGTH_WIDTHS = 2.5  # a car is about two and a half times as long as it is wide


def shape_min_px(image_size: tuple[int, int] | None,
                 shape_min_length: float = TrackerConfig.shape_min_length) -> float:
    """Least span (pixels) of a car's length along the road where a silhouette has a say in its track's body shape
    (TrackerConfig.shape_min_length of the frame width; 0 while the frame size is unknown)."""
    return shape_min_length * image_size[0] if image_size is not None else 0.0


def car_length_px(camera: Camera, boxes: np.ndarray) -> np.ndarray:
    """(N,) pixels a car's length (:data:`CAR_LENGTH_WIDTHS` times the width of each plain box (N, 5), which the
    tangents measure well) spans along the road at the box: how well the silhouette can show a length, and so a
    body.  0 where the box is not finite."""
    b = np.asarray(boxes, np.float64).reshape(-1, 5)
    xc, yc = (b[:, 0] + b[:, 1]) / 2, (b[:, 2] + b[:, 3]) / 2
    step = CAR_LENGTH_WIDTHS * np.abs(b[:, 3] - b[:, 2])
    z = np.zeros(len(b))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        a = world_to_pixels(camera, np.stack([xc, yc, z], axis=1))
        e = world_to_pixels(camera, np.stack([xc + step, yc, z], axis=1))
        span = np.linalg.norm(e - a, axis=1)
    return np.where(np.isfinite(span), span, 0.0)


def rebuild_boxes(camera: Camera, track: Track, shape_fits: int | None = None,
                  typical_height: float | None = None, shape_min_px: float = 0.0) -> None:
    """Fit and set the 3D boxes of all the track's observations, with the body shape chosen over its first
    ``shape_fits`` silhouette fits where a car's length spans ``shape_min_px`` (as the tracker chooses live; None:
    over all; ``typical_height``: the scene's, box3d.TypicalHeight)."""
    fit_boxes(camera, track.observations)
    track.height = None
    track.shape = track_shape(track, shape_fits, typical_height, shape_min_px)
    apply_shape(camera, track, track.observations)


def body_shape_name(track: Track) -> str:
    """Name of the body shape the track's 3D boxes hold ("box" = Dubská's plain box; see box3d.fit_shapes)."""
    if track.shape == 0:
        return "box"
    from .shapes import default_shapes

    names = [s.name for s in default_shapes()]
    return names[track.shape] if track.shape < len(names) else "box"


def _valid_fit(o: Observation, min_px: float = 0.0) -> bool:
    """Whether the observation's silhouette has a say in its track's body shape and height: fitted with every
    shape, its tangents gave a plain box, and a car's length spans at least ``min_px`` along the road there
    (:func:`car_length_px`).  Not a silhouette cut by the top edge; nor one far down the road, where a few pixels of
    outline are all a length shows (TrackerConfig.shape_min_length)."""
    return (not o.cut_top and o.shape_fit is not None and len(o.shape_fit) > 1
            and bool(np.isfinite(o.shape_fit[0])) and (min_px <= 0 or o.length_px >= min_px))


def _first_fits(track: Track, first: int | None, min_px: float = 0.0) -> list[Observation]:
    """The track's observations with a valid fit (:func:`_valid_fit`), the first ``first`` of them (all: None)."""
    out = []
    for o in track.observations:
        if first is not None and len(out) >= first:
            break
        if _valid_fit(o, min_px):
            out.append(o)
    return out


def _fit_height(track: Track, first: int, min_px: float = 0.0) -> float:
    """Median plain-box height of the track's first ``first`` valid fits so far (NaN: none)."""
    h = [o.shape_params[0][4] for o in _first_fits(track, first, min_px)]
    return float(np.median(h)) if h else np.nan


def track_shape(track: Track, first: int | None = None, typical_height: float | None = None,
                min_px: float = 0.0) -> int:
    """The body shape that explains the tangents of the track's silhouettes best (summed misfit; 0 = box), over
    its ``first`` valid fits (all: None; a silhouette whose tangents give no box, or where a car's length spans
    less than ``min_px``, does not count), of the shapes
    its proportions allow (a car's bodies for a car and for a "stretched" one — long, but no taller than the
    scene's ``typical_height`` —, a truck's or a bus's for a long vehicle taller than that, else the box:
    box3d.track_choice).  Sets ``track.proportions`` (that class) and, once those fits are all in (or with
    ``first`` None), ``track.height``: their plain boxes' median height."""
    rows = _first_fits(track, first, min_px)  # the choice is made over these: later fits cannot change it
    final = bool(rows) and (first is None or len(rows) >= first)
    if not rows:  # none that shows a length yet (a vehicle far down the road): the others stand in meanwhile
        rows = _first_fits(track, first)
    if not rows:
        track.proportions = ""
        return 0
    boxes = np.array([o.shape_params[0] for o in rows])
    if final:
        track.height = float(np.median(boxes[:, 4]))
    track.proportions = track_class(boxes, typical_height)
    from .shapes import default_shapes

    return track_choice(np.array([o.shape_fit for o in rows]), [s.kind for s in default_shapes()], track.proportions)


def apply_shape(camera: Camera, track: Track, observations: list[Observation]) -> None:
    """3D box and image corners of ``observations`` (of ``track``) from the track's body shape."""
    sel = [o for o in observations if o.shape_params is not None]
    for o in observations:
        o.box3d = o.corners_px = None
    if not sel:
        return
    theta = np.array([o.shape_params[track.shape if len(o.shape_params) > track.shape else 0] for o in sel])
    boxes = _boxes(camera, theta, np.array([o.shape_ok for o in sel]), _pad_hulls([o.hull for o in sel]),
                   np.zeros(len(sel)))
    for j, o in enumerate(sel):
        if boxes.valid[j]:
            o.box3d, o.corners_px = boxes.params[j], boxes.corners_px[j]


def _update_direction(track: Track, min_span: float = 0.02) -> None:
    """Direction of travel along the road from the 3D box centres (keeps the old one while ambiguous).

    The median displacement between observations half the track apart: the whole track votes, so the end of a
    track far away (a pixel is metres there, and a receding vehicle barely moves in the image) cannot flip it.
    """
    x = np.array([0.5 * (o.box3d[0] + o.box3d[1]) for o in measured_boxes(track)])
    if len(x) < 2:
        return
    h = max(1, len(x) // 2)
    step = float(np.median(x[h:] - x[:-h]))
    if abs(step) >= min_span:
        track.direction = 1 if step > 0 else -1


#: a track with at least this many 3D boxes of whole silhouettes is measured from those alone; one with fewer (a
#: truck or a bus whose roof leaves a near camera's frame at the top before its front has come in: never seen
#: whole) also from its boxes of silhouettes cut by the top edge alone (Observation.cut_top), whose
#: ground-touching tangents — the near faces the reference point is built from — are whole.  Their far faces
#: and height are not: they are never a whole vehicle's measurement when whole ones exist.  10 is the speed
#: meter's default minimum track length (measurement.DEFAULT_MIN_TRACK_LENGTH): fewer whole boxes could not give
#: a speed on their own
MIN_WHOLE_BOXES = 10


def measured_boxes(track: Track) -> list[Observation]:
    """The track's observations whose 3D boxes give reference points and dimensions (:data:`MIN_WHOLE_BOXES`)."""
    boxed = [o for o in track.observations if o.box3d is not None]
    whole = [o for o in boxed if not o.cut_top]
    return whole if len(whole) >= MIN_WHOLE_BOXES else boxed


def track_dimensions(track: Track, cut_top: bool = True) -> tuple[float, float] | None:
    """Length (along the road) and width of the vehicle, plane units (None without 3D boxes).

    Far away and seen along the road, a vehicle's length spans a pixel or two and is not measurable; so each
    dimension is the median over the observations where its box edge is longest in the image (at least half
    of the longest), which are the well-conditioned ones.  Over :func:`measured_boxes`, or with ``cut_top``
    False over the whole silhouettes' boxes alone.
    """
    obs = measured_boxes(track) if cut_top else [o for o in track.observations if o.box3d is not None and not o.cut_top]
    if not obs:
        return None
    p = np.array([o.box3d for o in obs])
    with_px = np.array([o.corners_px is not None for o in obs])
    out = []
    for lo, hi, (a, b) in ((0, 1, (0, 1)), (2, 3, (0, 2))):  # x0->x1 edge, y0->y1 edge (bottom)
        size = p[:, hi] - p[:, lo]
        good = np.ones(len(obs), bool)
        if with_px.any():  # corners known: keep the views where this edge is long in the image
            c = np.array([o.corners_px for o, w in zip(obs, with_px) if w])
            span = np.zeros(len(obs))
            span[with_px] = np.linalg.norm(c[:, b] - c[:, a], axis=1)
            good = span >= 0.5 * span.max()
        out.append(float(np.median(size[good])))
    return out[0], out[1]


def _anchored(lo: np.ndarray, hi: np.ndarray, size: float) -> tuple[np.ndarray, np.ndarray]:
    """Box extents rebuilt from the end nearer to the camera (coordinate 0) and the track's median size."""
    near_lo = lo > 0  # the whole box on the positive side: its low end faces the camera
    near_hi = hi < 0
    new_lo = np.where(near_lo, lo, np.where(near_hi, hi - size, lo))
    new_hi = np.where(near_lo, lo + size, np.where(near_hi, hi, hi))
    return new_lo, new_hi


def _set_references(camera: Camera, track: Track, observations: list[Observation], cut_top: bool = True) -> None:
    """Reference point = centre of the bottom edge at the front (direction of travel; +x when unknown).

    The box's faces nearer to the camera come from the ground-touching tangents and are well conditioned; the
    far faces (often hidden) are noisy.  A vehicle's length and width do not change, so the far faces are placed
    at the track's median length and width from the near ones: exact for exact hulls, and far steadier on
    real foreground masks.  Observations cut by the top edge get points as :func:`measured_boxes` says, and only
    with ``cut_top`` (the tracker's live frames have none: whether a track will be seen whole is known when it
    ends).
    """
    front = 1 if track.direction >= 0 else 0
    allowed = {id(o) for o in measured_boxes(track)} if cut_top else None
    sel = [o for o in observations if o.box3d is not None
           and (id(o) in allowed if cut_top else not o.cut_top)]
    chosen = {id(o) for o in sel}
    for o in observations:
        if id(o) not in chosen:
            o.ref_px = o.ref_road = o.ref_road_filtered = None
    if not sel:
        return
    p = np.array([o.box3d for o in sel])
    length, width = track_dimensions(track, cut_top)
    x0, x1 = _anchored(p[:, 0], p[:, 1], length)
    y0, y1 = _anchored(p[:, 2], p[:, 3], width)
    road = np.stack([x1 if front else x0, 0.5 * (y0 + y1)], axis=1)
    px = world_to_pixels(camera, np.concatenate([road, np.zeros((len(sel), 1))], axis=1))
    for o, r, q in zip(sel, road, px):
        o.ref_road, o.ref_px = r, q


def _filter_road(track: Track, obs: Observation) -> None:
    """Kalman-smooth the road-plane reference point (constant velocity along the road)."""
    if obs.ref_road is None:
        return
    if track.road_kf is None:
        track.road_kf = ConstantVelocityKF(obs.ref_road, meas_std=0.01, accel_std=0.5, vel_std0=5.0)
        track.road_kf_t = obs.t
    else:
        track.road_kf.predict(obs.t - track.road_kf_t)
        track.road_kf.update(obs.ref_road)
        track.road_kf_t = obs.t
    obs.ref_road_filtered = track.road_kf.position
