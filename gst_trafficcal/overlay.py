"""Drawing the traffic overlay (grid, horizon, 3D boxes, ids, speeds, counters) onto video frames.

Everything is drawn through a :class:`Canvas`, which paints straight into the planes of a frame in any of
the supported raw formats: packed BGR/RGB/BGRx, GRAY8, and planar I420/NV12 -- for those the luma plane
gets the shape at full resolution and the chroma plane(s) the same shape at half resolution (cv2's
fixed-point ``shift`` does the halving without rounding), so an element can draw in place without
converting the frame. Text is drawn in luma only, on a filled neutral background box, so it stays sharp
and correctly coloured despite 4:2:0 chroma.

All drawing is cv2 calls over whole arrays of points (one ``polylines`` call per colour), no pixel loops.
"""

from __future__ import annotations

from collections import OrderedDict, deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from .drawing import (GRID_ACROSS_BGR, GRID_ALONG_BGR, HORIZON_BGR, ZONE_BGR, RoadGrid, clip_segments,
                      grid_min_cell_px, horizon_segment, road_grid_segments, world_camera, zone_segments)
from .geometry import Camera
from .lanes import DEFAULT_LANE_WIDTH_M, lane_centres
from .frame_rate import FrameSpacing, frames_needed
from .measurement import (DRIVE_OFF_FLOOR, direction_along_road, drive_off_points, drove_along_road, metres_between,
                          moved_along_road, not_a_vehicle)
from .outputs import AWAY_FROM_VP1, TOWARDS_VP1, direction_name
from .traffic_stats import SpeedLimit, as_limit, is_over_limit

_SHIFT = 4  # fixed-point bits of the coordinates given to cv2 (1/16 pixel)

#: the 12 edges of a 3D box as corner-index pairs, corners in the tracker's order (index = ix + 2 iy + 4 iz)
BOX_EDGES = np.array([(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1])


# --------------------------------------------------------------------------- colours


def bgr_to_yuv(color: Sequence[int], kr: float = 0.299, kb: float = 0.114,
               full_range: bool = False) -> tuple[int, int, int]:
    """8-bit (Y, U, V) of a BGR colour for the given matrix (BT.601 by default) and range."""
    b, g, r = (float(c) / 255.0 for c in color[:3])
    y = kr * r + (1 - kr - kb) * g + kb * b
    u = (b - y) / (2 * (1 - kb))
    v = (r - y) / (2 * (1 - kr))
    if full_range:
        vals = (255 * y, 128 + 255 * u, 128 + 255 * v)
    else:
        vals = (16 + 219 * y, 128 + 224 * u, 128 + 224 * v)
    return tuple(int(np.clip(round(x), 0, 255)) for x in vals)


# --------------------------------------------------------------------------- canvas


@dataclass
class _Target:
    array: np.ndarray  # a plane view (written in place)
    factor: int  # subsampling of this plane (1 or 2)
    channels: tuple[int, ...]  # indices into (B, G, R, 255) / (Y, U, V) giving this plane's channel values
    yuv: bool
    luma: bool  # receives text


class Canvas:
    """Paints shapes into the planes of one frame (see the module docstring)."""

    def __init__(self, targets: list[_Target], size: tuple[int, int], kr: float = 0.299, kb: float = 0.114,
                 full_range: bool = False) -> None:
        self.targets = targets
        self.size = size  # (width, height)
        self._yuv_args = (kr, kb, full_range)
        self._cache: dict[tuple[int, ...], tuple[int, int, int]] = {}

    # colour of a BGR colour on one target
    def _color(self, t: _Target, color: Sequence[int]) -> tuple[int, ...] | int:
        key = tuple(int(c) for c in color[:3])
        if t.yuv:
            if key not in self._cache:
                self._cache[key] = bgr_to_yuv(key, *self._yuv_args)
            src = self._cache[key]
        else:
            src = (*key, 255)
        vals = tuple(src[i] for i in t.channels)
        return vals[0] if len(vals) == 1 else vals

    @staticmethod
    def _thick(t: _Target, thickness: int) -> int:
        """Line thickness on a plane: subsampled chroma gets a slightly wider line so it covers the luma line."""
        return thickness if thickness < 0 or t.factor == 1 else thickness // t.factor + 1

    def segments(self, segments: np.ndarray, color: Sequence[int], thickness: int = 1) -> None:
        """Draw (N, 2, 2) pixel segments (clipped to the frame first, so far-away ends are harmless)."""
        segs = np.asarray(segments, np.float64).reshape(-1, 2, 2)
        if not len(segs):
            return
        segs, _ = clip_segments(segs, *self.size, margin=thickness + 2)
        if not len(segs):
            return
        for t in self.targets:
            pts = np.round(segs * ((1 << _SHIFT) / t.factor)).astype(np.int32)
            cv2.polylines(t.array, pts, False, self._color(t, color), self._thick(t, thickness),
                          cv2.LINE_AA if t.factor == 1 else cv2.LINE_8, _SHIFT)

    def rectangles(self, boxes: np.ndarray, color: Sequence[int], thickness: int = 1, alpha: float = 1.0) -> None:
        """Axis-aligned boxes (N, 4) = x0, y0, x1, y1 pixels; ``thickness < 0`` fills them, with ``alpha`` < 1
        blended over the picture (the video stays visible under a panel)."""
        boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
        if not len(boxes):
            return
        if thickness >= 0:
            x0, y0, x1, y1 = boxes.T
            corners = np.stack([np.stack([x0, y0], 1), np.stack([x1, y0], 1), np.stack([x1, y1], 1),
                                np.stack([x0, y1], 1)], axis=1)
            self.segments(np.stack([corners, np.roll(corners, -1, axis=1)], axis=2).reshape(-1, 2, 2), color,
                          thickness)
            return
        w, h = self.size
        b = np.clip(np.round(boxes), 0, [w, h, w, h]).astype(int)
        for t in self.targets:
            c = self._color(t, color)
            f = t.factor
            for x0, y0, x1, y1 in b:  # few boxes (labels): plain slicing is the fastest fill
                region = t.array[y0 // f:-(-y1 // f), x0 // f:-(-x1 // f)]
                if alpha >= 1.0:
                    region[...] = c
                else:
                    region[...] = region * (1.0 - alpha) + np.asarray(c, np.float64) * alpha + 0.5

    def text(self, org: tuple[float, float], text: str, color: Sequence[int], scale: float = 0.5,
             thickness: int = 1) -> None:
        """Text with its baseline starting at ``org`` (luma / colour channels only; see module docstring)."""
        for t in self.targets:
            if t.luma:
                cv2.putText(t.array, text, (int(round(org[0])), int(round(org[1]))), cv2.FONT_HERSHEY_SIMPLEX,
                            scale, self._color(t, color), thickness, cv2.LINE_AA)

    def label(self, anchor: tuple[float, float], lines: Sequence[str], scale: float = 0.5, thickness: int = 1,
              fg: Sequence[int] = (255, 255, 255), bg: Sequence[int] = (0, 0, 0), above: bool = True,
              alpha: float = 1.0) -> None:
        """Lines of text on a filled box (opacity ``alpha``) whose bottom-left (``above``) or top-left corner is
        ``anchor``, kept inside the frame."""
        if not lines:
            return
        sizes, line_h, width, height = _text_layout(lines, scale, thickness)
        w, h = self.size
        x0 = float(np.clip(anchor[0], 0, max(0, w - width)))
        y0 = anchor[1] - height if above else anchor[1]
        y0 = float(np.clip(y0, 0, max(0, h - height)))
        x0, y0 = 2 * int(x0 // 2), 2 * int(y0 // 2)  # even: the box covers whole chroma samples
        width, height = width + width % 2, height + height % 2
        self.rectangles(np.array([[x0, y0, x0 + width, y0 + height]]), bg, -1, alpha)
        for k, (s, sz) in enumerate(zip(lines, sizes)):
            self.text((x0 + 3, y0 + line_h * (k + 1) - sz[1]), s, fg, scale, thickness)


def _text_layout(lines: Sequence[str], scale: float, thickness: int) -> tuple[list, int, int, int]:
    """(each line's cv2.getTextSize, line height, box width, box height) of :meth:`Canvas.label`'s box."""
    sizes = [cv2.getTextSize(s, cv2.FONT_HERSHEY_SIMPLEX, scale, thickness) for s in lines]
    line_h = max(sz[0][1] + sz[1] for sz in sizes) + 3
    return sizes, line_h, max(sz[0][0] for sz in sizes) + 6, line_h * len(lines) + 3


def label_size(lines: Sequence[str], scale: float, thickness: int = 1) -> tuple[int, int]:
    """(width, height) in pixels of :meth:`Canvas.label`'s box for ``lines`` (before rounding to even)."""
    return _text_layout(lines, scale, thickness)[2:]


def place_labels(boxes: np.ndarray, size: tuple[int, int], taken: np.ndarray | None = None) -> np.ndarray:
    """Top-left corners for label boxes (N x 4: x0, y0, width, height, each wanted where its row says, in drawing
    order) kept inside the frame and off the ones placed before: each goes to the free height nearest above where it
    was wanted — just above a label already there — or, with no room above, the nearest below, so vehicles side by
    side keep readable labels.  Where no height is free (more labels than the column holds), the wanted one.
    ``taken``: boxes (x, y, width, height) already covered (the counters panel)."""
    w, h = size
    placed = np.zeros((0, 4)) if taken is None else np.asarray(taken, float).reshape(-1, 4)
    out = np.zeros((len(boxes), 2))
    for i, (x0, y0, bw, bh) in enumerate(np.asarray(boxes, float)):
        x = float(np.clip(x0, 0, max(0.0, w - bw)))
        want = float(np.clip(y0, 0, max(0.0, h - bh)))
        cols = placed[(placed[:, 0] < x + bw) & (x < placed[:, 0] + placed[:, 2])]  # labels this one could touch
        ys = np.concatenate([[want], cols[:, 1] - bh - 1, cols[:, 1] + cols[:, 3] + 1])
        ys = ys[(ys >= 0) & (ys <= h - bh)]
        free = [y for y in ys if not np.any((y < cols[:, 1] + cols[:, 3]) & (cols[:, 1] < y + bh))]
        y = min(free, key=lambda v: (v > want, abs(v - want))) if free else want  # above the vehicle first
        placed = np.vstack([placed, [x, y, bw, bh]])
        out[i] = (x, y)
    return out


def canvas_for_planes(planes: list[np.ndarray], fmt: str, kr: float = 0.299, kb: float = 0.114,
                      full_range: bool = False) -> Canvas:
    """A canvas over the plane views of a frame in ``fmt`` (GRAY8, I420, NV12, BGR, RGB, BGRx)."""
    h, w = planes[0].shape[:2]
    if fmt == "BGR":
        targets = [_Target(planes[0], 1, (0, 1, 2), False, True)]
    elif fmt == "RGB":
        targets = [_Target(planes[0], 1, (2, 1, 0), False, True)]
    elif fmt == "BGRx":
        targets = [_Target(planes[0], 1, (0, 1, 2, 3), False, True)]
    elif fmt == "GRAY8":
        targets = [_Target(planes[0], 1, (0,), True, True)]
    elif fmt == "I420":
        targets = [_Target(planes[0], 1, (0,), True, True), _Target(planes[1], 2, (1,), True, False),
                   _Target(planes[2], 2, (2,), True, False)]
    elif fmt == "NV12":
        targets = [_Target(planes[0], 1, (0,), True, True), _Target(planes[1], 2, (1, 2), True, False)]
    else:
        raise ValueError(f"cannot draw on {fmt!r} frames (supported: GRAY8, I420, NV12, BGR, RGB, BGRx)")
    if fmt == "GRAY8":
        full_range = True  # grey levels are full range
    return Canvas(targets, (w, h), kr, kb, full_range)


def canvas_for_bgr(image: np.ndarray) -> Canvas:
    """A canvas over a packed HxWx3 BGR image."""
    return canvas_for_planes([image], "BGR")


# --------------------------------------------------------------------------- what to draw


@dataclass(frozen=True)
class VehicleMark:
    """One vehicle in one frame, as the overlay draws it."""

    box: tuple[float, float, float, float]  # 2D box x0, y0, x1, y1 pixels
    track_id: int | None = None
    label: str = ""
    speed_kmh: float | None = None
    corners: np.ndarray | None = None  # (8, 2) pixels of the 3D box (corner index = ix + 2 iy + 4 iz)
    ref_point: tuple[float, float] | None = None  # reference point (bottom-front edge centre), pixels
    direction: str | None = None  # outputs.TOWARDS_VP1 / AWAY_FROM_VP1 / None
    lane: int | None = None
    tentative: bool = False  # a detection no track holds yet (a tracker runs upstream): drawn faint, without label


@dataclass(frozen=True)
class OverlayOptions:
    grid: bool = True
    horizon: bool = True
    boxes: bool = True
    labels: bool = True
    speeds: bool = True
    counters: bool = True
    grid_spacing_m: float = 3.0
    thickness: int = 2
    font_scale: float = 0.0  # 0: from the frame height (0.6 at 720 lines)
    speed_limit_kmh: "float | SpeedLimit" = 0.0  # vehicles faster than their limit are drawn in Style.speeding_bgr


@dataclass(frozen=True)
class Style:
    box_towards_bgr: tuple[int, int, int] = (0, 255, 0)  # green: moving towards VP1
    box_away_bgr: tuple[int, int, int] = (255, 0, 255)  # magenta: moving away from VP1
    box_unknown_bgr: tuple[int, int, int] = (0, 255, 255)  # yellow: direction unknown / plain detection
    tentative_bgr: tuple[int, int, int] = (170, 170, 170)  # light grey, 1 px: a detection no track holds yet
    ref_point_bgr: tuple[int, int, int] = (0, 0, 255)
    grid_along_bgr: tuple[int, int, int] = GRID_ALONG_BGR
    grid_across_bgr: tuple[int, int, int] = GRID_ACROSS_BGR
    horizon_bgr: tuple[int, int, int] = HORIZON_BGR
    text_bgr: tuple[int, int, int] = (255, 255, 255)
    text_bg_bgr: tuple[int, int, int] = (0, 0, 0)
    speeding_bgr: tuple[int, int, int] = (0, 0, 200)  # dark red (the reference point is bright red): box and label
    # background of a vehicle over the speed limit
    panel_alpha: float = 0.75  # opacity of the counters panel's background (the labels under it stay faint)
    zone_bgr: tuple[int, int, int] = ZONE_BGR  # the outline of the detection zone

    def box_color(self, direction: str | None) -> tuple[int, int, int]:
        if direction == TOWARDS_VP1:
            return self.box_towards_bgr
        if direction == AWAY_FROM_VP1:
            return self.box_away_bgr
        return self.box_unknown_bgr


@dataclass
class VehicleCounter:
    """Counts distinct tracked vehicles per direction and per lane (each id once, its latest known values).

    A vehicle's lane is the one its metadata gives; without one, and with a calibration with scale, the lane
    comes from the lateral road-plane offsets of the reference points of the vehicles seen
    (:func:`gst_trafficcal.lanes.lane_centres`) — until speedometer's lanes arrive through :meth:`left`.
    Vehicles not seen for ``FORGET_AFTER`` updates are folded into fixed totals, so memory and time per frame stay
    bounded on streams that run for days.

    A vehicle that left before it had a direction, lane or speed (the calibration came later) is counted as
    "unknown" until :meth:`left` gives its final values (speedometer measures it then, and says so downstream);
    :meth:`left` moves it to its direction, lane and, over the limit, the speeding count.

    With ``min_seen_s`` and ``min_passing_m`` (for a chain without speedometer, whose "no vehicle passing" events
    otherwise take them out) a track counts only once speedometer's rule,
    :func:`gst_trafficcal.measurement.not_a_vehicle`, says it is a vehicle passing, judged on what was seen of it so
    far: in view ``min_seen_s`` (stream seconds, the ``t`` of :meth:`update`; a detector's flicker or a fragment of a
    vehicle another track follows is not counted) and moved ``min_passing_m`` along the road
    (:func:`gst_trafficcal.measurement.moved_along_road` over its reference points; a parked vehicle is not counted, nor
    counted again each time it is occluded and found again; once older than its latest points, the move must hold
    all along them, which a point jumping by the car's length for a second or two does not) — or drove that far
    steadily over its latest points
    (:func:`gst_trafficcal.measurement.drove_along_road`: a vehicle that stood for most of its stay, then drove off).
    Without a scale the distance is taken with :data:`gst_trafficcal.drawing.ASSUMED_HEIGHT_M`, as the grid is; a track
    without reference points (before the vanishing points) is counted on the time in view alone, as speedometer reports
    one.
    """

    seen: dict[int, tuple[str | None, int | None]] = field(default_factory=dict)  # vehicles still around
    offsets: dict[int, list[float]] = field(default_factory=dict)  # world y (m) of their reference points
    lane_width_m: float = DEFAULT_LANE_WIDTH_M
    _last_seen: dict[int, int] = field(default_factory=dict, repr=False)
    _done_total: int = field(default=0, repr=False)
    _done_dir: dict[str | None, int] = field(default_factory=dict, repr=False)
    _done_lane: dict[int, int] = field(default_factory=dict, repr=False)
    _done_offsets: list[float] = field(default_factory=list, repr=False)  # medians of departed vehicles
    _centres: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    _centres_key: tuple[int, int] = field(default=(-1, -1), repr=False)
    _updates: int = field(default=0, repr=False)
    _lanes_key: tuple[int, int, int] = field(default=(-1, -1, -1), repr=False)
    _lanes: dict[int, int] = field(default_factory=dict, repr=False)
    speed_limit_kmh: "float | SpeedLimit" = 0.0  # also count the vehicles whose latest speed is over their limit
    _speed: dict[int, tuple[float, str]] = field(default_factory=dict, repr=False)  # latest known speed and class of
    # those still around
    _done_speeding: int = field(default=0, repr=False)
    _event_lanes: bool = field(default=False, repr=False)  # left() has given lanes: count only those
    # departed vehicles' counted values (direction, lane, over the limit), newest last, for left()
    _done_ids: OrderedDict[int, tuple[str | None, int | None, bool]] = field(default_factory=OrderedDict,
                                                                             repr=False)
    min_seen_s: float = 0.0  # a track counts once in view this long (0: at once)
    min_passing_m: float = 0.0  # ... and once it moved this far along the road (0: however little)
    _first_seen: dict[int, tuple[float, float, int, VehicleMark]] = field(default_factory=dict, repr=False)  # not
    # yet counted: (first t, last t, last update, last mark)
    _trails: dict[int, _Trail] = field(default_factory=dict, repr=False)  # their reference points
    _camera: Camera | None = field(default=None, repr=False)  # the latest update's
    _spacing: FrameSpacing = field(default_factory=FrameSpacing, repr=False)  # the trails' windows as durations
    own_directions: bool = False  # no speedometer: a vehicle's direction from its own points, as speedometer's
    _paths: dict[int, tuple[_Trail, _Trail]] = field(default_factory=dict, repr=False)  # own_directions: the
    # tracks' reference points and box centres since first seen, with their times

    MAX_OFFSETS = 64  # per vehicle (its median is all that is used)
    LANE_REFRESH = 25  # per-lane counts are recounted at most every this many updates (or on a new vehicle)
    FORGET_AFTER = 250  # updates (10 s at 25 fps) without a sighting: the vehicle has left
    MAX_LANE_SAMPLES = 2000  # departed vehicles' offsets kept for the lane model
    MAX_DONE_IDS = 20000  # departed vehicles left() can still correct (hours of traffic waiting for a calibration)

    def update(self, marks: Iterable[VehicleMark], camera: Camera | None = None, t: float | None = None) -> None:
        """Count the vehicles of one frame (``t``: its stream time in seconds, for ``min_seen_s``)."""
        metric = camera is not None and camera.scale is not None
        self._updates += 1
        self._camera = camera
        if t is not None:
            self._spacing.add(t)
        for m in marks:
            if m.track_id is None:
                continue
            followed = self._follow(m, camera, t)
            if not self._counts_now(m, t):
                continue
            counted_before = m.track_id in self.seen
            old_dir, old_lane = self.seen.get(m.track_id, (None, None))
            own = self._own_direction(m.track_id, camera, not counted_before) if followed and m.direction is None \
                else None
            self.seen[m.track_id] = (m.direction or own or old_dir, m.lane if m.lane is not None else old_lane)
            self._last_seen[m.track_id] = self._updates
            if m.speed_kmh is not None:
                self._speed[m.track_id] = (m.speed_kmh, m.label)
            if metric and m.lane is None and m.ref_point is not None:
                y = float(camera.to_world(np.asarray(m.ref_point, np.float64))[1])
                if np.isfinite(y):
                    ys = self.offsets.setdefault(m.track_id, [])
                    ys.append(y)
                    del ys[:-self.MAX_OFFSETS]
        if self._updates % 50 == 0:
            self._forget(self._updates - self.FORGET_AFTER)

    def _follow(self, m: VehicleMark, camera: Camera | None, t: float | None) -> bool:
        """With ``own_directions`` (no speedometer upstream), keep ``m``'s reference point and box centre (with
        ``t``) on its track's path, from its first sighting on, for :meth:`_own_direction`; False when not kept."""
        if not self.own_directions or camera is None or t is None:
            return False
        refs, centres = self._paths.setdefault(m.track_id, (_Trail(), _Trail()))
        if m.ref_point is not None:
            refs.add(m.ref_point, t)
        x0, y0, x1, y1 = m.box
        centres.add(((x0 + x1) / 2.0, (y0 + y1) / 2.0), t)
        return True

    def _own_direction(self, track_id: int, camera: Camera | None, now: bool = False) -> str | None:
        """The direction of a track along the road from what the counter saw of it (:meth:`_follow`;
        :func:`~gst_trafficcal.measurement.direction_along_road`, as speedometer decides it: its reference points,
        or its box centres while it has none); None when not known or not due: it is decided when the track
        counts (``now``: also at the end of the stream), then again at the 2nd, 4th, 8th... and every 32nd
        sighting."""
        path = self._paths.get(track_id)
        if camera is None or path is None:
            return None
        refs, centres = path
        path = refs if len(refs.points) >= 2 else centres
        n = path.seen
        if n < 2 or (not now and n & (n - 1) and n % 32):
            return None
        return direction_along_road(camera, np.array(path.points), np.array(path.times))

    def _counts_now(self, m: VehicleMark, t: float | None) -> bool:
        """Whether the track of ``m`` is counted now: it is already, or what was seen of it by ``t`` makes it a
        vehicle passing (see the class docstring)."""
        i = m.track_id
        if i in self.seen or (self.min_seen_s <= 0 and self.min_passing_m <= 0) or t is None:
            return True
        first = self._first_seen.get(i, (t,))[0]
        trail = self._trails.get(i) or self._trails.setdefault(i, _Trail.counting())
        if m.ref_point is not None:
            trail.add(m.ref_point)
        if not self._why_not(t - first, trail, cut=False):
            self._first_seen.pop(i, None)
            del self._trails[i]
            return True
        self._first_seen[i] = (first, t, self._updates, m)
        return False

    def _why_not(self, seen_s: float, trail: _Trail | None, cut: bool) -> str:
        """Why a track seen ``seen_s`` seconds along ``trail`` is no vehicle passing (yet), as speedometer judges the
        tracks it leaves unmeasured ("": it is one); ``cut``: the end of the stream cut it short."""
        moved = None
        if (self.min_passing_m > 0 and seen_s >= self.min_seen_s and trail is not None and len(trail.points) >= 2
                and self._camera is not None):
            cam = world_camera(self._camera)
            # the windows cover their 25 fps time at lower rates (at 5 fps 26 and 13 points, not 128 and 64)
            n_recent = frames_needed(_Trail.RECENT, self._spacing.seconds, 2 * DRIVE_OFF_FLOOR)
            n_steady = drive_off_points(self._spacing.seconds)
            pts, recent = np.array(trail.points), np.array(trail.recent)[-n_recent:]
            moved = moved_along_road(cam, pts)
            if len(recent) == n_recent:  # a track older than its latest points: the move held all along them,
                # not a parked car's point jumping by its length for a second or two (the younger ones move early)
                first = pts[:max(1, len(pts) // 4)]
                moved = min([moved] + [metres_between(cam, first, q) for q in np.array_split(recent, 4)])
            moved = max(moved, drove_along_road(cam, recent[-n_steady:]))
        return not_a_vehicle(np.inf if cut else seen_s, moved, self.min_seen_s, self.min_passing_m)

    def end(self, t: float | None, still_in_view_s: float) -> None:
        """End of the stream: the tracks not yet counted that were seen in its last ``still_in_view_s`` seconds (to
        ``t``) count unless they stood still — the end cut them short, as speedometer counts them."""
        for i, (first, last, u, m) in list(self._first_seen.items()):
            if t is not None and last >= t - still_in_view_s and not self._why_not(last - first, self._trails.get(i),
                                                                                   cut=True):
                own = self._own_direction(i, self._camera, now=True) if m.direction is None else None
                self.seen[i] = (m.direction or own, m.lane)
                self._last_seen[i] = u
                if m.speed_kmh is not None:
                    self._speed[i] = (m.speed_kmh, m.label)
        for i in self._first_seen:
            if i not in self.seen:
                self._paths.pop(i, None)
        self._first_seen.clear()
        self._trails.clear()

    def _forget(self, before: int) -> None:
        for i in [i for i, (_, _, u, _) in self._first_seen.items() if u < before]:  # never counted: gone for good
            del self._first_seen[i]
            self._trails.pop(i, None)
            self._paths.pop(i, None)
        gone = [i for i, t in self._last_seen.items() if t < before]
        for i in gone:
            direction, lane = self.seen[i]
            if lane is None and not self._event_lanes:
                lane = self._derived_lane(i)
            self._done_total += 1
            self._done_dir[direction] = self._done_dir.get(direction, 0) + 1
            if lane is not None:
                self._done_lane[lane] = self._done_lane.get(lane, 0) + 1
            speed, label = self._speed.pop(i, (None, ""))
            fast = is_over_limit(speed, self.speed_limit_kmh, label)
            self._done_speeding += fast
            self._done_ids[i] = (direction, lane, fast)
            ys = self.offsets.pop(i, None)
            if ys:
                self._done_offsets.append(float(np.median(ys)))
            del self.seen[i], self._last_seen[i]
            self._paths.pop(i, None)
        del self._done_offsets[:-self.MAX_LANE_SAMPLES]
        while len(self._done_ids) > self.MAX_DONE_IDS:
            self._done_ids.popitem(last=False)

    def left(self, track_id: int, direction: str | None = None, lane: int | None = None,
             speed_kmh: float | None = None, label: str = "", merged: Sequence[int] = ()) -> bool:
        """A vehicle's final values as speedometer gives them when it leaves (or measures it after it left, or again
        with a later calibration): they replace the direction, lane and speed it was counted with, so that the
        counts are the event files' (None: the files have none); ``merged``: earlier tracks of the same vehicle,
        measured with it, no longer counted as vehicles. False when the id was never counted here (or too long
        ago). Once lanes come this way, the per-lane counts hold only the vehicles that left with a lane (the
        files' lane numbers), not lanes derived here for the ones still in view."""
        self._event_lanes |= lane is not None
        self._lanes_key = (-1, -1, -1)  # recount the lanes
        for i in merged:
            if i != track_id:
                self._uncount(i)
        if track_id in self.seen:
            self.seen[track_id] = (direction, lane)
            self.offsets.pop(track_id, None)
            if speed_kmh is None:
                self._speed.pop(track_id, None)
            else:
                self._speed[track_id] = (speed_kmh, label)
            return True
        done = self._done_ids.get(track_id)
        if done is None:
            return False
        old_dir, old_lane, old_fast = done
        fast = is_over_limit(speed_kmh, self.speed_limit_kmh, label)
        _move(self._done_dir, old_dir, direction, count_none=True)
        _move(self._done_lane, old_lane, lane, count_none=False)
        self._done_speeding += int(fast) - int(old_fast)
        self._done_ids[track_id] = (direction, lane, fast)
        return True

    def not_vehicles(self, track_ids: Iterable[int]) -> None:
        """Take tracks speedometer found to be no vehicle passing (a fragment, a parked car) out of the counts."""
        for i in track_ids:
            self._uncount(i)

    def _uncount(self, track_id: int) -> None:
        """Take a track out of the counts (it was part of another vehicle, or none)."""
        if track_id in self.seen:
            del self.seen[track_id], self._last_seen[track_id]
            self._paths.pop(track_id, None)
            self._speed.pop(track_id, None)
            self.offsets.pop(track_id, None)
            return
        done = self._done_ids.pop(track_id, None)
        if done is None:
            return
        direction, lane, fast = done
        self._done_total -= 1
        _count(self._done_dir, direction, -1, count_none=True)
        _count(self._done_lane, lane, -1, count_none=False)
        self._done_speeding -= int(fast)

    def _derived_lane(self, track_id: int) -> int | None:
        ys = self.offsets.get(track_id)
        if not ys:
            return None
        key = (len(self.offsets), self._done_total)
        if key != self._centres_key:  # a new vehicle: refine the lanes
            medians = [np.median(v) for v in self.offsets.values()] + self._done_offsets
            self._centres = lane_centres(np.array(medians), self.lane_width_m)
            self._centres_key = key
        if not len(self._centres):
            return None
        y = float(np.median(ys))
        k = int(np.argmin(np.abs(self._centres - y)))
        return k if abs(self._centres[k] - y) <= self.lane_width_m else None

    @property
    def total(self) -> int:
        return self._done_total + len(self.seen)

    @property
    def speeding(self) -> int:
        """Distinct vehicles whose latest known speed was over ``speed_limit_kmh`` (0 without a limit)."""
        return self._done_speeding + sum(is_over_limit(v, self.speed_limit_kmh, label)
                                         for v, label in self._speed.values())

    def by_direction(self) -> dict[str | None, int]:
        out = dict(self._done_dir)
        for d, _ in self.seen.values():
            out[d] = out.get(d, 0) + 1
        return out

    def by_lane(self) -> dict[int, int]:
        key = (len(self.seen), self._done_total, self._updates // self.LANE_REFRESH)
        if key == self._lanes_key:
            return dict(self._lanes)
        out = dict(self._done_lane)
        for track_id, (_, lane) in self.seen.items():
            if lane is None and not self._event_lanes:
                lane = self._derived_lane(track_id)
            if lane is not None:
                out[lane] = out.get(lane, 0) + 1
        self._lanes, self._lanes_key = dict(sorted(out.items())), key
        return dict(self._lanes)

    def summary(self) -> dict[str, int]:
        """The counts as flat fields (trafficoverlay's end-of-stream message): total, towards_vp1, away_from_vp1,
        unknown_direction, lane_<k>, and with a limit over_limit."""
        d = self.by_direction()
        out = {"total": self.total, "towards_vp1": d.get(TOWARDS_VP1, 0), "away_from_vp1": d.get(AWAY_FROM_VP1, 0),
               "unknown_direction": d.get(None, 0)}
        out.update({f"lane_{k}": v for k, v in self.by_lane().items()})
        if as_limit(self.speed_limit_kmh or None):
            out["over_limit"] = self.speeding
        return out

    def lines(self) -> list[str]:
        """Text lines for the counter panel."""
        out = [f"vehicles: {self.total}"]
        d = self.by_direction()
        if d.get(TOWARDS_VP1) or d.get(AWAY_FROM_VP1):  # those tracked before the calibration have none
            unknown = f"  unknown: {d[None]}" if d.get(None) else ""
            out.append(f"towards VP1: {d.get(TOWARDS_VP1, 0)}  away: {d.get(AWAY_FROM_VP1, 0)}{unknown}")
        lanes = self.by_lane()
        if lanes:
            out.append("  ".join(f"lane {k}: {v}" for k, v in lanes.items()))
        limit = as_limit(self.speed_limit_kmh or None)
        if limit:
            out.append(f"over {limit.describe()}: {self.speeding}")
        return out


@dataclass
class _Trail:
    """A track's reference points (pixels, in time order) for :func:`~gst_trafficcal.measurement.moved_along_road`:
    every ``stride``-th one, at most ``MAX``, so that a parked car in view for hours keeps an even sample of its whole
    stay in bounded memory and time; and, given a ``recent`` deque (:meth:`counting`: the counter's trails, not
    own_directions' paths, which read the even sample only), its latest ``RECENT`` at full rate for
    :func:`~gst_trafficcal.measurement.drove_along_road` (a vehicle that stood, then drove off)."""

    points: list[tuple[float, float]] = field(default_factory=list)
    times: list[float] = field(default_factory=list)  # the points' stream times (seconds), where given
    stride: int = 1
    seen: int = 0
    recent: deque[tuple[float, float]] | None = None

    MAX = 128
    RECENT = 128  # 5.1 s at 25 fps (below 12.5 fps the latest points that cover that time: frames_needed)

    @classmethod
    def counting(cls) -> "_Trail":
        """A trail that also keeps its latest ``RECENT`` points (the counter's: :meth:`VehicleCounter._why_not`)."""
        return cls(recent=deque(maxlen=cls.RECENT))

    def add(self, point: tuple[float, float], t: float | None = None) -> None:
        if self.recent is not None:
            self.recent.append(point)
        if self.seen % self.stride == 0:
            self.points.append(point)
            if t is not None:
                self.times.append(t)
            if len(self.points) > self.MAX:
                del self.points[1::2]
                del self.times[1::2]
                self.stride *= 2
        self.seen += 1


def _count(counts: dict, key, delta: int, count_none: bool) -> None:
    """Add ``delta`` to ``counts[key]``; with ``count_none`` False a key None is no count (a vehicle without a lane
    is in no lane). Keys whose count falls to 0 are dropped."""
    if key is None and not count_none:
        return
    counts[key] = counts.get(key, 0) + delta
    if counts[key] <= 0:
        del counts[key]


def _move(counts: dict, old, new, count_none: bool) -> None:
    """One count moved from key ``old`` to ``new`` (see :func:`_count`)."""
    if old != new:
        _count(counts, old, -1, count_none)
        _count(counts, new, 1, count_none)


def mark_label(mark: VehicleMark, options: OverlayOptions) -> list[str]:
    """The text shown next to a vehicle: id and label, and its speed when known."""
    parts = []
    if options.labels:
        head = f"#{mark.track_id}" if mark.track_id is not None else ""
        parts.append(" ".join(s for s in (head, mark.label) if s))
    if options.speeds and mark.speed_kmh is not None:
        parts.append(f"{mark.speed_kmh:.1f} km/h")
    text = " ".join(p for p in parts if p)
    return [text] if text else []


# --------------------------------------------------------------------------- the overlay


def calibration_status(camera: Camera | None) -> str | None:
    """The overlay's status line while there is no speed to show yet, so that a recording does not look broken
    during the minute the calibration takes; None once speeds can be measured."""
    if camera is None:
        return "calibrating: no speeds yet"
    if camera.scale is None:
        return "finding the scale: no speeds yet"
    return None


class GridCache:
    """The road grid of the current calibration (recomputed only when the camera or frame size changes)."""

    def __init__(self) -> None:
        self._key: tuple | None = None
        self._grid: RoadGrid | None = None
        self._horizon: np.ndarray | None = None

    def get(self, camera: Camera, size: tuple[int, int], spacing_m: float,
            thickness: int = 1) -> tuple[RoadGrid, np.ndarray | None]:
        key = (tuple(camera.vp1), tuple(camera.vp2), tuple(camera.pp), camera.scale, tuple(size), spacing_m,
               thickness)
        if key != self._key:  # as dense as the report's picture (drawing.draw_calibration), no denser
            self._grid = road_grid_segments(camera, size, spacing_m,
                                            min_cell_px=grid_min_cell_px(size[1], thickness))
            self._horizon = horizon_segment(camera, size)
            self._key = key
        return self._grid, self._horizon


def wrap_lines(lines: Sequence[str], max_width: float, scale: float, thickness: int = 1,
               sep: str = "  ") -> list[str]:
    """``lines`` with each one wider than ``max_width`` pixels (in OpenCV's simplex font) broken at ``sep`` into
    as few lines as fit (a single item wider than that stays whole): the counters of many lanes on a small frame."""
    def width(text: str) -> int:
        return cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thickness)[0][0]

    out: list[str] = []
    for line in lines:
        items = line.split(sep)
        current = items[0]
        for item in items[1:]:
            joined = current + sep + item
            if width(joined) <= max_width:
                current = joined
            else:
                out.append(current)
                current = item
        out.append(current)
    return out


def mark_extent(mark: VehicleMark) -> tuple[float, float, float, float]:
    """The pixel box a vehicle covers: its 3D box's extent, or its 2D box."""
    if mark.corners is not None:
        c = np.asarray(mark.corners, np.float64).reshape(-1, 2)
        return float(c[:, 0].min()), float(c[:, 1].min()), float(c[:, 0].max()), float(c[:, 1].max())
    return tuple(float(v) for v in mark.box)


#: where the counters panel and the status line may go; "auto": the corner the traffic leaves freest
CORNERS = ("top-left", "top-right", "bottom-left", "bottom-right")
PANEL_POSITIONS = ("auto",) + CORNERS
_MARGIN = 8  # pixels between the panel and the frame's edges


def corner_origin(corner: str, box_size: tuple[float, float], size: tuple[int, int]) -> tuple[float, float]:
    """Top-left pixel of a ``box_size`` (width, height) box in ``corner`` of a frame of ``size``, 8 px in."""
    w, h = size
    x = w - _MARGIN - box_size[0] if corner.endswith("right") else _MARGIN
    y = h - _MARGIN - box_size[1] if corner.startswith("bottom") else _MARGIN
    return float(max(0, x)), float(max(0, y))


def _overlap(a: Sequence[float], b: Sequence[float]) -> bool:
    """Whether two boxes (x, y, width, height) share any area."""
    return a[0] < b[0] + b[2] and b[0] < a[0] + a[2] and a[1] < b[1] + b[3] and b[1] < a[1] + a[3]


def _other_row(corner: str) -> str:
    """The corner on the same side at the other edge (the status line's place beside a fixed panel)."""
    top, side = corner.split("-")
    return ("bottom" if top == "top" else "top") + "-" + side


@dataclass
class PanelPlacer:
    """Keeps the counters panel and the status line off the traffic: where the vehicles and their labels have been
    lately (a coarse grid of the frame, older frames fading out over ``memory_frames``) decides the corner each
    goes to. Far traffic enters at the horizon, often under the top-left corner, and a panel there hides it.

    A corner is left only when another carries less than ``move_ratio`` of its traffic, it has carried some
    (``min_cover``: the mean share of its cells covered), and ``min_dwell`` frames have passed since the last move:
    the panel settles instead of jumping after each vehicle. ``position`` other than "auto" fixes the panel's
    corner (the status line then takes the other one on the same side)."""

    position: str = "auto"
    cells: tuple[int, int] = (48, 27)  # columns, rows
    memory_frames: float = 750.0  # 30 s at 25 fps
    move_ratio: float = 0.5
    min_cover: float = 0.02
    min_dwell: int = 250
    panel: str = "top-left"
    status: str = "bottom-left"
    _heat: np.ndarray | None = field(default=None, repr=False)
    _weight: float = field(default=0.0, repr=False)  # the decayed number of frames seen (the heat's full scale)
    _since_move: list[int] = field(default_factory=lambda: [0, 0], repr=False)  # frames: panel, status line

    def __post_init__(self) -> None:
        if self.position not in PANEL_POSITIONS:
            raise ValueError(f"panel-position {self.position!r} is none of {', '.join(PANEL_POSITIONS)}")
        if self.position != "auto":
            self.panel, self.status = self.position, _other_row(self.position)

    def observe(self, regions: np.ndarray, size: tuple[int, int]) -> None:
        """Add one frame's vehicle regions (N x 4 pixel boxes x0, y0, x1, y1; a box counts the cells it touches)."""
        nx, ny = self.cells
        decay = 1.0 - 1.0 / self.memory_frames
        if self._heat is None:
            self._heat = np.zeros((ny, nx))
        self._heat *= decay
        self._weight = self._weight * decay + 1.0
        self._since_move = [n + 1 for n in self._since_move]
        r = np.asarray(regions, np.float64).reshape(-1, 4)
        r = r[np.isfinite(r).all(axis=1)] * np.array([nx / size[0], ny / size[1]] * 2)  # in cells
        lo = np.clip(np.floor(r[:, :2]), 0, [nx, ny]).astype(int)
        hi = np.clip(np.ceil(r[:, 2:]), 0, [nx, ny]).astype(int)
        frame = np.zeros((ny, nx))
        for (x0, y0), (x1, y1) in zip(lo, hi):  # a few boxes a frame
            frame[y0:y1, x0:x1] = 1.0
        self._heat += frame

    def _cover(self, corner: str, box_size: tuple[float, float], size: tuple[int, int]) -> float:
        """Mean share of the frames seen in which the cells under a ``box_size`` box in ``corner`` held traffic."""
        nx, ny = self.cells
        x, y = corner_origin(corner, box_size, size)
        i0, j0 = int(x * nx / size[0]), int(y * ny / size[1])
        i1 = max(i0 + 1, int(np.ceil((x + box_size[0]) * nx / size[0])))
        j1 = max(j0 + 1, int(np.ceil((y + box_size[1]) * ny / size[1])))
        return float(self._heat[j0:j1, i0:i1].mean()) / self._weight

    def _choose(self, current: str, choices: Sequence[str], box_size, size) -> str:
        cover = {k: self._cover(k, box_size, size) for k in choices}
        best = min(choices, key=lambda k: cover[k])  # ties: the order of CORNERS
        here = cover.get(current, np.inf)
        if current not in cover or (here >= self.min_cover and cover[best] < self.move_ratio * here):
            return best
        return current

    def place(self, panel_size: tuple[float, float] | None, status_size: tuple[float, float] | None,
              size: tuple[int, int]) -> tuple[str, str]:
        """(panel corner, status corner) for boxes of these sizes (None: not drawn) in a frame of ``size``."""
        if self.position == "auto" and self._heat is not None:
            settled = [n >= self.min_dwell for n in self._since_move]
            panel = self._choose(self.panel, CORNERS, panel_size, size) \
                if panel_size is not None and settled[0] else self.panel
            status = self.status
            if status_size is not None:
                free = [k for k in CORNERS if k != panel and not (panel_size is not None and _overlap(
                    (*corner_origin(k, status_size, size), *status_size),
                    (*corner_origin(panel, panel_size, size), *panel_size)))] or [_other_row(panel)]
                if settled[1] or status not in free:
                    status = self._choose(status, free, status_size, size)
            for k, (old, new) in enumerate(((self.panel, panel), (self.status, status))):
                if new != old:
                    self._since_move[k] = 0
            self.panel, self.status = panel, status
        return self.panel, self.status


def draw_overlay(canvas: Canvas, marks: Sequence[VehicleMark], camera: Camera | None = None,
                 options: OverlayOptions = OverlayOptions(), counter_lines: Sequence[str] = (),
                 style: Style = Style(), grid_cache: GridCache | None = None, status: str | None = None,
                 placer: PanelPlacer | None = None, zone: Sequence[np.ndarray] = ()) -> None:
    """Draw everything ``options`` asks for; vehicles with 3D corners get their 3D box, others their 2D box,
    tentative ones (a detection the tracker upstream has not confirmed as a vehicle yet) a thin grey 2D box only.
    ``status`` (:func:`calibration_status`): one line, at the bottom left unless ``placer`` (which sees this frame's
    vehicles and labels) puts it and the counters panel (top left) in corners the traffic leaves freer. ``zone``: the
    detection zone's polygons (pixels, :meth:`gst_trafficcal.zone.Zone.pixels`), outlined."""
    th = options.thickness
    fs = options.font_scale or max(0.35, 0.6 * canvas.size[1] / 720)
    ft = 1 if fs < 1.0 else 2
    if camera is not None and (options.grid or options.horizon):
        grid, horizon = (grid_cache or GridCache()).get(camera, canvas.size, options.grid_spacing_m)  # 1 px lines
        if options.grid:
            canvas.segments(grid.along, style.grid_along_bgr, 1)
            canvas.segments(grid.across, style.grid_across_bgr, 1)
        if options.horizon and horizon is not None:
            canvas.segments(horizon[None], style.horizon_bgr, th)

    if len(zone):
        canvas.segments(zone_segments(zone, canvas.size), style.zone_bgr, max(1, th // 2))

    def box_color(m: VehicleMark) -> tuple[int, int, int]:
        if is_over_limit(m.speed_kmh, options.speed_limit_kmh, m.label):
            return style.speeding_bgr
        return style.box_color(m.direction)

    tentative = [m.box for m in marks if m.tentative]
    marks = [m for m in marks if not m.tentative]
    if options.boxes and tentative:  # first: a vehicle's box drawn over it stays whole
        canvas.rectangles(np.array(tentative, np.float64), style.tentative_bgr, 1)
    if options.boxes:
        for color in {box_color(m) for m in marks}:
            group = [m for m in marks if box_color(m) == color]
            boxes3d = [np.asarray(m.corners, np.float64).reshape(8, 2) for m in group if m.corners is not None]
            if boxes3d:
                c = np.stack(boxes3d)  # (N, 8, 2)
                canvas.segments(c[:, BOX_EDGES].reshape(-1, 2, 2), color, th)
            flat = [m.box for m in group if m.corners is None]
            if flat:
                canvas.rectangles(np.array(flat, np.float64), color, th)
        refs = [m.ref_point for m in marks if m.ref_point is not None]
        if refs:
            r = np.asarray(refs, np.float64)
            d = 2.0 + th
            cross = np.concatenate([np.stack([r - [d, 0], r + [d, 0]], 1), np.stack([r - [0, d], r + [0, d]], 1)])
            canvas.segments(cross, style.ref_point_bgr, th)
    panel = wrap_lines(counter_lines, 0.5 * canvas.size[0], fs, ft) if options.counters and counter_lines else []
    panel_size = tuple(np.add(label_size(panel, fs, ft), 2)) if panel else None
    status_size = tuple(np.add(label_size([status], fs, ft), 2)) if status else None
    labelled = [(m, lines) for m in marks if (lines := mark_label(m, options))] \
        if options.labels or options.speeds else []
    extents = {id(m): mark_extent(m) for m in marks}
    traffic = list(extents.values()) + tentative  # where the panel should not be
    # nearest vehicles (lowest in the picture) first: theirs stay at their boxes, farther ones give way
    labelled.sort(key=lambda ml: -extents[id(ml[0])][3])
    wanted = []
    for m, lines in labelled:
        left, top = extents[id(m)][:2]
        bw, bh = label_size(lines, fs, ft)
        wanted.append((left, top - 2 - bh, bw + 1, bh + 1))  # + 1: the even rounding of Canvas.label
    corners = ("top-left", "bottom-left")
    if placer is not None:
        regions = traffic + [(x, y, x + w, y + h) for x, y, w, h in wanted]
        placer.observe(np.array(regions).reshape(-1, 4), canvas.size)
        corners = placer.place(panel_size, status_size, canvas.size)
    taken = []  # where the counters panel and the status line will be: labels keep off them
    for size, corner in ((panel_size, corners[0]), (status_size, corners[1])):
        if size is not None:
            taken.append((*corner_origin(corner, size, canvas.size), *size))
    if labelled:
        spots = place_labels(np.array(wanted).reshape(-1, 4), canvas.size, np.array(taken).reshape(-1, 4))
        for (m, lines), (x, y) in zip(labelled, spots):
            bg = style.speeding_bgr if is_over_limit(m.speed_kmh, options.speed_limit_kmh, m.label) \
                else style.text_bg_bgr
            canvas.label((x, y), lines, fs, ft, style.text_bgr, bg, above=False)
    # last, to stay readable; translucent: the traffic under it shows; the panel at most half the frame wide
    # (wrap_lines above), so a small frame's many lanes do not cover the road
    for lines, size, corner in ((panel, panel_size, corners[0]), ([status] if status else [], status_size, corners[1])):
        if lines:
            canvas.label(corner_origin(corner, size, canvas.size), lines, fs, ft, style.text_bgr, style.text_bg_bgr,
                         above=False, alpha=style.panel_alpha)


class GivenClasses:
    """The class the speedometer last gave each vehicle in view, kept for the frames in which it gives none (it
    withholds the live speed, with its class, while the speed samples disagree): without it the label would flip
    between its class and the detector's ("van", "car", "van") as the speed comes and goes."""

    LIMIT = 4096  # vehicles remembered (the oldest forgotten first)

    def __init__(self) -> None:
        self._given: OrderedDict[int, str] = OrderedDict()

    def label(self, track_id: int | None, given: object, detector_label: str) -> str:
        """The label to show: ``given`` (the "speed" structure's class) when there is one, else the class given
        earlier to ``track_id``, else the detector's."""
        if track_id is None:
            return str(given or detector_label)
        if given:
            self._given[track_id] = str(given)
            self._given.move_to_end(track_id)
            while len(self._given) > self.LIMIT:
                self._given.popitem(last=False)
            return str(given)
        return self._given.get(track_id, detector_label)


def marks_from_params(box: Sequence[float], label: str, object_id: int | None,
                      params: dict[str, dict], given: GivenClasses | None = None) -> VehicleMark:
    """A :class:`VehicleMark` from one ROI's parameter structures (see ``trafficoverlay``).

    Reads, all optional: ``"trafficcal-vehicle"`` as the tracker writes it (``box3d``: 8 corner pairs in pixels,
    ``ref_x``/``ref_y`` the reference point, ``direction`` +1/-1/0, see ``tracking.vehicle_meta``; also accepted:
    ``ref_point`` [x, y], ``lane``) and ``"speed"`` {``speed_kmh``, optional ``lane``, optional ``label``: the
    class the speedometer gives the vehicle, shown instead of the detector's ``label``, and with ``given`` also
    in the frames without one}.
    """
    tv = params.get("trafficcal-vehicle", {})
    sp = params.get("speed", {})
    # a silhouette cut by the top edge carries its box for the measurement, but its roof is the frame's edge
    corners = None if tv.get("cut_top") and not tv.get("has_3d") else tv.get("box3d")
    if corners is not None:
        corners = np.asarray(corners, np.float64).reshape(-1)
        corners = corners.reshape(8, 2) if corners.size == 16 and np.all(np.isfinite(corners)) else None
    ref = tv.get("ref_point")
    if ref is None and "ref_x" in tv and "ref_y" in tv:
        ref = (tv["ref_x"], tv["ref_y"])
    if ref is not None:
        ref = np.asarray(ref, np.float64).reshape(-1)
        ref = (float(ref[0]), float(ref[1])) if ref.size == 2 and np.all(np.isfinite(ref)) else None
    try:
        direction = direction_name(tv.get("direction"))
    except (ValueError, TypeError):
        direction = None
    lane = sp.get("lane", tv.get("lane"))
    speed = sp.get("speed_kmh")
    if speed is not None and not (isinstance(speed, (int, float)) and np.isfinite(speed)):
        speed = None
    label = given.label(object_id, sp.get("label"), label) if given is not None else sp.get("label") or label
    return VehicleMark(box=tuple(float(v) for v in box), track_id=object_id, label=str(label),
                       speed_kmh=None if speed is None else float(speed), corners=corners, ref_point=ref,
                       direction=direction,
                       lane=int(lane) if isinstance(lane, (int, float)) and lane >= 0 else None)
