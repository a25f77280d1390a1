"""GStreamer element ``trafficoverlay``: draws the traffic analysis onto the video (for NVR output).

Draws, in place and straight into the frame's planes (I420/NV12 luma and chroma, or packed RGB, no
conversion of the whole frame): the road-plane grid towards VP1/VP2 and the horizon of the calibration (the
sticky "trafficcal-calibration" event from upstream, or ``calibration-file``), each vehicle's 3D box (from
the tracker's "trafficcal-vehicle" structure) or its 2D box (plain "detection" ROIs), its track id, label
and speed (the "speed" structure) — with a tracker upstream, a detection no track holds yet only as a thin grey box
without label —, and counters of distinct vehicles per direction and lane; with
``speed-limit``, vehicles over it in red and their count. A vehicle that left before the calibration (so without
direction or lane while in view) is counted by the values speedometer gives it when it measures it later (its
``trafficcal-speed`` custom event, ``gst_trafficcal.gst.vehicle_event``). At end of stream a
``trafficcal-overlay-counts`` message gives the final counts (total, towards_vp1, away_from_vp1,
unknown_direction, lane_<k>, over_limit).

The element is never in passthrough, so GstBaseTransform hands it a writable buffer: a buffer shared
with another branch (e.g. after a ``tee``) is copied first and the other branch never sees the drawing.
"""

from gst_trafficcal.gst._gi import GObject, Gst
from gst_trafficcal.gst.element import LIVE, READY_ONLY, TrafficcalTransform
from gst_trafficcal.gst.untracked import UntrackedWatch

_RW = READY_ONLY  # read at start (gst-inspect-1.0: changeable only in NULL or READY state)


class TrafficOverlay(TrafficcalTransform):
    __gtype_name__ = "GstTrafficOverlay"
    __gstmetadata__ = ("trafficoverlay", "Filter/Effect/Video",
                       "Draws the road grid, horizon, 3D vehicle boxes, track ids, speeds and vehicle counters "
                       "onto the video, in place", "gst-trafficcal")
    __gproperties__ = {
        "draw-grid": (bool, "Draw grid", "Draw the road-plane grid (lines towards VP1 and VP2) of the calibration",
                      True, LIVE),
        "draw-horizon": (bool, "Draw horizon", "Draw the horizon (the line through VP1 and VP2)", True, LIVE),
        "draw-boxes": (bool, "Draw boxes", "Draw each vehicle's 3D box (2D box when it has none) and reference "
                       "point", True, LIVE),
        "draw-labels": (bool, "Draw labels", "Write each vehicle's track id and label", True, LIVE),
        "draw-speeds": (bool, "Draw speeds", "Write each vehicle's speed in km/h when it is known", True, LIVE),
        "draw-counters": (bool, "Draw counters", "Show counts of distinct tracked vehicles per direction and lane",
                          True, LIVE),
        "grid-spacing": (float, "Grid spacing", "Cell size of the road grid in metres (while the calibration has "
                         "no scale, the grid assumes a camera 7 m above the road)", 0.1, 1000.0, 3.0, LIVE),
        "line-thickness": (int, "Line thickness", "Thickness of boxes and the horizon in pixels", 1, 16, 2, LIVE),
        "font-scale": (float, "Font scale", "Text size (OpenCV font scale); 0 = from the frame height", 0.0, 10.0,
                       0.0, LIVE),
        "speed-limit": (float, "Speed limit", "km/h; vehicles faster than this are drawn in red and counted in the "
                        "counters panel (0: none)", 0.0, 1000.0, 0.0, _RW),
        "class-limits": (str, "Class limits", "Classes with speed limits of their own, CLASS=KMH,... (e.g. "
                         "truck=60,bus=60): their vehicles are held to these instead of speed-limit", "", _RW),
        "panel-position": (str, "Panel position", "Corner of the counters panel: auto (the corner the traffic "
                           "leaves freest; the status line takes the next freest), top-left, top-right, bottom-left "
                           "or bottom-right", "auto", _RW),
        "zone": (str, "Zone", "Detection zone to outline (as given to vpdetect and vehicledetect): polygons "
                 "'x,y x,y x,y ...' separated by ';', in pixels or fractions 0..1 of the frame; empty: none", "",
                 _RW),
        "calibration-file": (str, "Calibration file", "Calibration JSON used for the grid until (or unless) a "
                             "calibration event arrives from upstream; empty: none", "", _RW),
    }

    def __init__(self):
        super().__init__()
        self._counter = None
        self._zone = None
        self._grid_cache = None
        self._yuv = (0.299, 0.114, False)
        self._said_grey = False  # on_caps: said once that GRAY8 frames get a grey overlay

    def do_start(self):
        from gst_trafficcal.overlay import GivenClasses, GridCache, PanelPlacer, VehicleCounter

        from gst_trafficcal.errors import InputError
        from gst_trafficcal.traffic_stats import element_limit
        from gst_trafficcal.zone import parse_zone

        try:
            self._limit = element_limit(self.speed_limit, self.class_limits)
            self._zone = parse_zone(self.zone)
        except InputError as exc:
            self.post_error(f"trafficoverlay: {exc}")
            return False
        try:
            self._placer = PanelPlacer(self.panel_position)
        except ValueError as exc:
            self.post_error(f"trafficoverlay: {exc}")
            return False
        self._counter = VehicleCounter(speed_limit_kmh=self._limit)
        self._said_grey = False
        self._grid_cache = GridCache()
        self._given = GivenClasses()  # the speedometer's class of each vehicle, also while it gives no live speed
        self._untracked = UntrackedWatch("trafficoverlay")
        self._tracked_upstream = None  # a tracker or speedometer upstream (decided at the first frame)
        self._file_cal = None
        if self.calibration_file:
            from gst_trafficcal.calibration import load_calibration

            try:
                self.calibration = self._file_cal = load_calibration(self.calibration_file)
            except Exception as exc:  # a bad file is a readable pipeline error
                self.post_error(f"trafficoverlay: {exc}")
                return False
        return True

    def on_custom_event(self, event):
        """speedometer's finished vehicles: one measured after it left (the calibration came later) is counted by
        its final direction, lane and speed, not as "unknown"; earlier tracks measured with it, and tracks speedometer
        found to be no vehicle passing, are not counted."""
        from gst_trafficcal.gst.vehicle_event import parse_not_vehicles_event, parse_vehicle_left_event
        from gst_trafficcal.outputs import DIRECTIONS

        ids = parse_not_vehicles_event(event)
        if ids is not None and self._counter is not None:
            self._counter.not_vehicles(ids)
        fields = parse_vehicle_left_event(event)
        if fields is not None and self._counter is not None and isinstance(fields.get("id"), int):
            direction, lane, speed = fields.get("direction"), fields.get("lane"), fields.get("speed_kmh")
            merged = fields.get("merged_ids") or []
            self._counter.left(fields["id"], direction if direction in DIRECTIONS else None,
                               lane if isinstance(lane, int) and lane >= 0 else None,
                               float(speed) if isinstance(speed, (int, float)) else None, str(fields.get("label", "")),
                               merged=[i for i in merged if isinstance(i, int)])
        return True

    def on_eos(self):
        if self._counter is not None:  # counted whether or not the panel is drawn
            from gst_trafficcal.measurement import DEFAULT_END_AFTER

            self._counter.end(self.buffer_t, DEFAULT_END_AFTER)  # the tracks in view at the end count, however brief
            self.post_element_message("trafficcal-overlay-counts", self._counter.summary())

    def on_caps(self, info):
        from gst_trafficcal.gst._gi import GstVideo

        c = info.colorimetry
        ok, kr, kb = GstVideo.VideoColorMatrix.get_Kr_Kb(c.matrix)
        full = c.range == getattr(GstVideo.VideoColorRange, "0_255")
        self._yuv = (kr, kb, full) if ok else (0.299, 0.114, full)
        wrong = self.file_calibration_mismatch(self._file_cal, self.calibration_file)
        if wrong:
            self.refuse_size(f"trafficoverlay: {wrong}")  # at the first frame: a stream's rotation may turn it
        from gst_trafficcal.gst.buffers import format_name

        if format_name(info) == "GRAY8" and not self._said_grey:  # a thermal or monochrome camera, as it came
            self._said_grey = True
            self.post_info("trafficoverlay: the frames are grey (GRAY8), so the overlay is drawn in grey: speeding "
                           "vehicles, the zone and the grid's directions differ by colour only in colour frames. "
                           "For colour, convert before the first trafficcal element (videoconvert ! "
                           "video/x-raw,format=I420 ! vpdetect ...): a videoconvert between the tracker and this "
                           "element drops the vehicles' ids and speeds")

    def transform_frame(self, buffer):
        from dataclasses import replace

        from gst_trafficcal.gst.buffers import format_name
        from gst_trafficcal.gst.meta import read_vehicle_rois
        from gst_trafficcal.overlay import (OverlayOptions, calibration_status, canvas_for_planes, draw_overlay,
                                            marks_from_params)
        from gst_trafficcal.tracking.vehicle_meta import STRUCTURE as VEHICLE

        marks = [marks_from_params(r.box, r.label, r.object_id, r.params, self._given)
                 for r in read_vehicle_rois(buffer, self.frame_size, only=(VEHICLE, "speed"))]
        self._check_tracked(marks)
        if self._tracked_upstream:  # a detection no track holds yet is no vehicle yet: faint, no label, not in view
            marks = [replace(m, tentative=True) if m.track_id is None else m for m in marks]
        cal = self.calibration
        camera = cal.camera if cal is not None else None
        self._counter.update(marks, camera, self.buffer_t)
        options = OverlayOptions(grid=self.draw_grid, horizon=self.draw_horizon, boxes=self.draw_boxes,
                                 labels=self.draw_labels, speeds=self.draw_speeds, counters=self.draw_counters,
                                 grid_spacing_m=self.grid_spacing, thickness=self.line_thickness,
                                 font_scale=self.font_scale, speed_limit_kmh=self._limit)
        counter_lines = self._counter.lines() + [f"in view: {sum(not m.tentative for m in marks)}"]
        with self.planes(buffer, writable=True) as planes:
            canvas = canvas_for_planes(planes, format_name(self.video_info), *self._yuv)
            draw_overlay(canvas, marks, camera, options, counter_lines, grid_cache=self._grid_cache,
                         status=calibration_status(camera) if self.draw_counters else None, placer=self._placer,
                         zone=self._zone.pixels(self.frame_size) if self._zone is not None else ())
            del canvas
        return Gst.FlowReturn.OK

    def _check_tracked(self, marks):
        """Say once when a tracker (or speedometer) runs upstream but its ids do not arrive: an element between
        dropped them, and the overlay would draw bare boxes without ids, speeds or counts."""
        from gst_trafficcal.gst.element import upstream_element

        if self._tracked_upstream is None:
            self._tracked_upstream = any(upstream_element(self, name) is not None
                                         for name in ("tracker", "speedometer"))
            if upstream_element(self, "speedometer") is None:  # nobody says which tracks were no vehicle passing:
                from gst_trafficcal.measurement import MIN_PASSING_M, MIN_SEEN_S  # count by speedometer's rule

                self._counter.min_seen_s, self._counter.min_passing_m = MIN_SEEN_S, MIN_PASSING_M
                self._counter.own_directions = True  # and which way they went: each track's own points
        t = self.buffer_t
        if self._tracked_upstream and t is not None:
            warning = self._untracked.check(t, len(marks), sum(m.track_id is not None for m in marks), True)
            if warning:
                self.post_warning(warning)


GObject.type_register(TrafficOverlay)
__gstelementfactory__ = ("trafficoverlay", Gst.Rank.NONE, TrafficOverlay)
