"""GStreamer element ``speedometer``: per-vehicle speeds (paper §4.4) into ROI metadata, bus messages and files.

Input: vehicle ROI metas (``vehicledetect``), and optionally the ``tracker`` element's ``object_id`` and
``"trafficcal-vehicle"`` structures.  When no ``tracker`` runs upstream, speedometer runs the library's tracking
stage itself on the ROIs (grey frame and, as the tracker's ``colour`` default says, U/V planes for its background
model), with the tracker element's defaults, and writes the same ``object_id``/``"trafficcal-vehicle"`` structures, so ``vehicledetect ! speedometer``
and ``vehicledetect ! tracker ! speedometer`` give the same numbers.

Calibration: the upstream ``trafficcal-calibration`` event when it has a scale; else ``calibration-file``; else the
upstream vanishing points with the ``scale`` property; else, when no ``bbscale`` runs upstream, speedometer runs
bbscale's stage itself (:class:`gst_trafficcal.scale.stage.ScaleStage`: BBScale on the tracked vehicles, the
same publishing rule, properties ``scale-models``, ``scale-min-vehicles``, ``scale-regression-file``) and measures
with the upstream vanishing points and the λ it finds, so ``vpdetect ! vehicledetect ! speedometer`` measures
speeds with nothing given and gives the numbers of ``... ! tracker ! bbscale ! speedometer``.  Vehicles that
leave before a calibration with scale exists are measured as soon as one arrives; at end of stream the ones still
waiting are written unmeasured, with the reason.  When vpdetect says the camera moved (a calibration with
``moved_at``), the vehicles seen before are measured with the calibration they were seen under (cut at the move),
and the scale is found anew for the new view; tracks seen only between the move and its notice are no vehicles
(a ``trafficcal-discarded`` message counts them).  At a jump in the stream (a player's flushing seek, either way;
recordings joined by ``concat``) the vehicles in view end, measured from what was seen before it: none is measured
across the jump.  Nor is a track left unmeasured that was seen for under half a
second or never moved 3 m along the road (``min-seen``, ``min-moved``; a fragment of a vehicle, a parked car:
``measurement.not_a_vehicle``; a ``trafficcal-not-counted`` message, fields ``brief`` and ``stationary`` and the
two thresholds, counts them): the files and counts hold the vehicles that passed.

Output per frame: a ``"speed"`` {speed_kmh, label, model_name, confidence, speed_uncertainty_kmh} structure on the
ROI of every vehicle with a current estimate (the last: the ~95 % interval's half-width,
``gst_trafficcal.uncertainty``).  Per vehicle that leaves: a ``trafficcal-speed`` element message (the event's
fields, and with ``speed-limit`` or ``class-limits`` a boolean ``over_limit``: faster than its class's limit; none
without a speed), the same as a JSON POST to ``events-url`` (a webhook;
``gst_trafficcal.publish``: background thread, retries, a warning when it fails — never an error), and
the same structure pushed downstream as a custom event (``gst_trafficcal.gst.vehicle_event``: trafficoverlay
counts a vehicle measured after it left by its final direction, lane and speed), a line in ``events-file`` (JSON
lines) / ``csv-file``; per frame with tracked vehicles, a line in ``frames-file``
(gvametaconvert's shape: box, track id, ``"trafficcal-vehicle"`` with the reference point and 3D box, ``"speed"``);
``results-file`` gets the BrnoCompSpeed results JSON
(rewritten atomically now and then and at end of stream); ``intervals-file`` the traffic count per ``interval``
minutes, lane and direction (:class:`gst_trafficcal.traffic_stats.IntervalTable`: rewritten as each interval
closes, the open one's rows after them, at most once a minute of stream, as vehicles come — so a live stream's
counts are on disk as they come, also after a kill -9 — and at the end; every watched interval has a row,
zero when no vehicle passed, and says how many seconds of it were watched).  A failed write (full disk) stops
the pipeline with an error naming the file; every vehicle written before stays in the files.  With ``remeasure``,
each vehicle measured again at the end is sent once more — a ``trafficcal-speed-revised`` message and an
``events-url`` POST, its new fields with ``revised: true`` — so a receiver replaces what it got for that run and id.
"""

from gst_trafficcal.frame_jitter import RETIME_MODES, FrameJitter, FrameRetimer
from gst_trafficcal.gst._gi import GObject, Gst
from gst_trafficcal.gst.element import READY_ONLY, TrafficcalTransform, upstream_element
from gst_trafficcal.gst.untracked import UNTRACKED_AFTER_S, UntrackedWatch

_RW = READY_ONLY  # read at start (gst-inspect-1.0: changeable only in NULL or READY state)
_RESULTS_EVERY = 10.0  # seconds of stream time between rewrites of the BrnoCompSpeed results file, at least


class Speedometer(TrafficcalTransform):
    __gtype_name__ = "GstSpeedometer"
    __gstmetadata__ = ("speedometer", "Filter/Analyzer/Video",
                       "Measures each tracked vehicle's speed from its road-plane reference points (median over "
                       "tau-spaced pairs, buffer timestamps); adds a 'speed' ROI structure, posts a trafficcal-speed "
                       "message per vehicle and writes JSON-lines/CSV events and BrnoCompSpeed results",
                       "gst-trafficcal")
    __gproperties__ = {
        "events-file": (str, "Events file", "JSON-lines file, one object per vehicle that left (empty: none)", "",
                        _RW),
        "csv-file": (str, "CSV file", "CSV file, one row per vehicle that left (empty: none)", "", _RW),
        "frames-file": (str, "Frames file", "JSON-lines file, one line per frame with vehicles: each vehicle's "
                        "box, track id, reference point and 3D box ('trafficcal-vehicle') and current speed "
                        "('speed'), in gvametaconvert's shape (empty: none)", "", _RW),
        "results-file": (str, "Results file", "BrnoCompSpeed results JSON (camera_calibration + cars with "
                         "frames/posX/posY), rewritten atomically (empty: none)", "", _RW),
        "intervals-file": (str, "Intervals file", "CSV traffic count per interval, lane and direction (counts, "
                           "speeds, V85, over the limit, classes, seconds watched), rewritten as each interval "
                           "closes, with the open one's rows so far at most once a minute as vehicles come, and at "
                           "the end of the stream (empty: none)", "", _RW),
        "append": (bool, "Append", "Add to an existing events-file, csv-file and frames-file instead of replacing "
                   "them, so a pipeline started again into the same files (a service restarted after a crash or a "
                   "reboot) keeps what it measured before; results-file and intervals-file, tables of one run, are "
                   "then not replaced either but kept beside as NAME.earlier-<time>.EXT (trafficcal report counts "
                   "the intervals of the whole events file)", False, _RW),
        "remeasure": (bool, "Measure again at the end", "At end of stream, measure the vehicles measured under an "
                      "earlier calibration again with the final one (a file: its later calibration saw more) and "
                      "rewrite their lines in events-file, csv-file and results-file and their counts in "
                      "intervals-file; each is posted again as a trafficcal-speed-revised message and to events-url, "
                      "with revised=true (same run and id), and a trafficcal-remeasured message says how many. "
                      "Keeps every measured vehicle's reference points (about 4 kB each) until the end: for files, "
                      "not for endless live streams", False, _RW),
        "interval": (float, "Interval", "Minutes per row of intervals-file (aligned to the clock with "
                     "start-datetime)", 0.01, 10080.0, 15.0, _RW),
        "calibration-file": (str, "Calibration file", "Calibration JSON used when no calibration with scale "
                             "comes from upstream (empty: none)", "", _RW),
        "scale": (float, "Scale", "Scene scale (metres per road-plane unit = camera height in metres) applied "
                  "to an upstream calibration that has vanishing points but no scale (0: none)", 0.0, 1e6, 0.0,
                  _RW),
        "scale-models": (str, "Scale models", "With no bbscale upstream and no scale given: the vehicle types its "
                         "own scale stage aligns (as bbscale's models)", "", _RW),
        "scale-min-vehicles": (int, "Scale minimum vehicles", "With no bbscale upstream and no scale given: "
                               "matched vehicles that must agree before its own scale is used (as bbscale's "
                               "min-vehicles)", 1, 100000, 5, _RW),
        "scale-regression-file": (str, "Scale regression file", "With no bbscale upstream and no scale given: "
                                  "scale-correction regression JSON for its own scale stage (as bbscale's)", "",
                                  _RW),
        "start-datetime": (str, "Start date and time", "Date and time of stream time 0, ISO 8601 "
                           "(2026-12-05T08:00:00+01:00; without an offset: local time): the events then carry "
                           "first_time and last_time; 'now': the clock at the first frame less its timestamp (live "
                           "sources); empty: none", "", _RW),
        "events-url": (str, "Events URL", "http(s):// URL that receives each vehicle event as it leaves, one JSON "
                       "POST per vehicle (a webhook; http://user:password@host/... for basic authentication; signed "
                       "with the environment's TRAFFICCAL_EVENTS_SECRET when set: X-Trafficcal-Signature-256); sent "
                       "from a background thread, retried, never holding the video up; empty: none", "", _RW),
        "speed-limit": (float, "Speed limit", "km/h: each trafficcal-speed message also says whether the vehicle "
                        "was faster (over_limit; 0: no limit, no field)", 0.0, 1000.0, 0.0, _RW),
        "class-limits": (str, "Class limits", "Classes with speed limits of their own, CLASS=KMH,... (e.g. "
                         "truck=60,bus=60): over_limit holds their vehicles to these instead of speed-limit", "",
                         _RW),
        "tau": (int, "Tau", "Observations between the two points of each speed sample (more for a vehicle that "
                "covers less than 4 m of road in tau observations)", 1, 1000, 5, _RW),
        "min-track-length": (int, "Minimum track length", "Reference points a vehicle needs to be measured "
                             "(at least tau + 1); frames more than 0.08 s apart: as many as cover this many 25 fps "
                             "frames' time (10: 0.4 s), at least tau + 1", 2, 100000, 10, _RW),
        "views-dir": (str, "Views folder", "The camera's views folder (vpdetect views-dir): a scale this element "
                      "finds itself (no bbscale upstream) is kept there with its view, so that after a restart "
                      "vpdetect gives the view with its scale at once; empty = none", "", _RW),
        "max-waiting": (int, "Most vehicles waiting", "Vehicles that left before a calibration with a scale are "
                        "held to be measured once it comes, at most this many: beyond, the oldest is written "
                        "unmeasured with the reason (a live camera that never calibrates stays bounded in memory and "
                        "its vehicles reach the files)", 1, 1000000, 2000, _RW),
        "min-seen": (float, "Minimum time seen", "Seconds a track left without a speed must have been seen to be "
                     "reported and counted as a vehicle (shorter: a piece of a vehicle, a detector's flicker; not "
                     "for a track the end of the stream or a camera move cut short; 0: no such rule)", 0.0, 3600.0,
                     0.5, _RW),
        "min-moved": (float, "Minimum distance moved", "Metres along the road a track left without a speed and "
                      "seen for min-seen or longer must have moved to be reported and counted as a vehicle (less: "
                      "a parked vehicle, a fixed object taken for one; 0: no such rule; both 0: every track is "
                      "reported)", 0.0, 1000.0, 3.0, _RW),
        "vehicle-timeout": (float, "Vehicle timeout", "Seconds without a sighting after which a vehicle has "
                            "left and is reported (0: the tracker's max-lost + 0.4 s; never less than that)", 0.0,
                            3600.0, 0.0, _RW),
        "retime": (str, "Retime", "Frame times for the speeds' durations: auto = smoothed by a line fit over the "
                   "last 50 frames once the times are found to jitter (times of arrival: do-timestamp=true), off = "
                   "the buffers' own, always = smoothed from the start; needs caps with a frame rate; buffer times "
                   "and the events' timestamps stay the buffers'", "auto", _RW),
    }

    def __init__(self):
        super().__init__()
        self._reset()

    def _reset(self):
        self._meter = None
        self._outputs = None
        self._frames = None
        self._poster = None  # EventPoster for events-url
        self._intervals = None  # traffic_stats.IntervalTable for intervals-file
        self._limit = None  # traffic_stats.SpeedLimit from speed-limit and class-limits
        self._posted = 0
        self._discarded = 0  # the meter's tracks seen only between a camera move and its notice, as last posted
        self._not_counted: dict[str, int] = {}  # the meter's tracks that were no vehicle passing, as last posted
        self._results_t = None
        self._results_every = _RESULTS_EVERY  # grows with the file (outputs.checkpoint_interval)
        self._fps_fixed = False
        self._caps_fps = None  # the caps' frame rate (an MP4 with frames dropped states their average)
        self._file_cal = None
        self._upstream = None
        self._in_force_id = None
        self._tracking = None  # None: not decided; False: a tracker runs upstream; else the internal pipeline
        self._colour = True  # internal tracking uses the frame's colour (the tracker element's default)
        self._flushed = False
        self._failed = False
        self._last_pts = None
        self._jumps = 0  # timestamp jumps back already said
        self._last_jump = None  # the time given at the latest jump back
        self._said_reverse = False  # _say_jumps: said that the timestamps keep going back
        self._said_out_of_order = False  # said that frames come out of order (StreamClock.out_of_order)
        self._dts = []
        self._jitter = FrameJitter()  # frame times of arrival, not of capture (do-timestamp=true): said once
        self._retimer = None  # FrameRetimer: smoothed frame times for the speeds (retime; caps with a frame rate)
        self._own_stage = None  # bbscale's stage, built at start
        self._stage = None  # ... in use: no bbscale upstream, no scale given (decided at the first frame)
        self._scaled = None  # the upstream calibration with the λ that stage found
        self._start = None  # datetime of stream time 0 (start-datetime), None while unknown
        self._run = None  # this run's id (outputs.new_run_id), set at start
        self._begun = False  # the video arrived and the files were started (_begin)
        self._untracked = UntrackedWatch("speedometer")  # a tracker upstream whose data does not arrive
        self._detector = None  # whether a vehicledetect runs upstream (decided at the first frame)
        self._empty_since = None  # stream time since which no vehicle arrived, while no detector is seen upstream

    # ------------------------------------------------------------------ life cycle
    def do_start(self):
        from gst_trafficcal.calibration import load_calibration
        from gst_trafficcal.measurement import SpeedMeter
        from gst_trafficcal.outputs import VehicleOutputs, new_run_id

        self._reset()
        self._run = new_run_id()  # on every event: appended runs reuse track ids
        try:
            from gst_trafficcal.clock import NOW, parse_start_time

            # one writer per file: two speedometers given one file (a tee's branches, two pipelines) each wrote
            # every vehicle into it, without a word
            self.claim_files({name: self.get_property(name) for name in (
                "events-file", "csv-file", "frames-file", "results-file", "intervals-file")})

            if self.retime not in RETIME_MODES:
                raise ValueError(f"retime must be one of {', '.join(RETIME_MODES)}, got {self.retime!r}")
            if self.min_track_length < self.tau + 1:  # the library says the same with its own argument names
                raise ValueError(f"min-track-length must be at least tau + 1 = {self.tau + 1}, got "
                                 f"{self.min_track_length}")
            self._meter = SpeedMeter(tau=self.tau, min_track_length=self.min_track_length, max_waiting=self.max_waiting,
                                     keep_measured=self.remeasure, min_seen_s=self.min_seen,
                                     min_passing_m=self.min_moved)
            if self.start_datetime.strip().lower() != NOW:
                self._start = parse_start_time(self.start_datetime, "start-datetime")
            if self.calibration_file:
                self._file_cal = load_calibration(self.calibration_file)
            # opened now so that an unwritable path fails at start, but emptied only when the video arrives
            # (_begin): a pipeline whose source fails keeps the files of the run before; fps is set from the caps
            self._outputs = VehicleOutputs(self.events_file or None, self.csv_file or None,
                                           self.results_file or None, fps=25.0, append=self.append, lazy=True)
            from gst_trafficcal.traffic_stats import element_limit

            self._limit = element_limit(self.speed_limit, self.class_limits)
            if self.intervals_file:
                from gst_trafficcal.fileio import writable_file
                from gst_trafficcal.traffic_stats import IntervalTable

                writable_file(self.intervals_file, "interval table")  # an unwritable path fails now, not in an hour
                self._intervals = IntervalTable(self.intervals_file, 60.0 * self.interval, self._start, self._limit)
            if self.events_url:
                from gst_trafficcal.publish import EventPoster

                self._poster = EventPoster(self.events_url)
            if self.frames_file:
                from gst_trafficcal.outputs import FrameJsonlWriter

                self._frames = FrameJsonlWriter(self.frames_file, append=self.append, skip_empty=True, lazy=True)
            if not self._scale_given():  # built now, so bad scale-* properties are an error at start
                self._own_stage = self._new_scale_stage()
        except Exception as exc:  # bad properties / unreadable calibration / unwritable file: readable error
            self.release_files()
            self.post_error(f"speedometer: {exc}")
            return False
        self._apply_calibration()
        return True

    def do_stop(self):
        if not self._flushed and self._meter is not None:  # stopped without EOS: keep what was measured
            self._finish(post=False)
        self._close()
        self.release_files()
        self._reset()
        return super().do_stop()

    def on_eos(self):
        if self._stage is not None and not self._failed:  # bbscale's final estimate, then every vehicle leaves
            self._scale_changed(True, self._stage.finish(self._upstream))
        self._finish(post=True)

    def _begin(self):
        """The video arrives (first caps): now the run's files replace the earlier run's — with ``append`` its
        tables are kept aside and its event files go on — and the interval table's header is on disk."""
        from gst_trafficcal.errors import InputError

        self._begun = True
        try:
            if self.append:
                from gst_trafficcal.fileio import keep_aside

                for path in (self.results_file, self.intervals_file):
                    kept = keep_aside(path) if path else None
                    if kept is not None:
                        self.post_info(f"speedometer: the earlier {path} is kept as {kept}")
                for path, kept in self._outputs.events.kept_aside:  # moved when opened (do_start): said now
                    self.post_warning(f"speedometer: {path} had other columns (an earlier version's); it is kept "
                                      f"as {kept} and a new one begun")
            self._outputs.begin()
            if self._frames is not None:
                self._frames.begin()
            if self._intervals is not None:
                from gst_trafficcal.traffic_stats import write_intervals_csv

                write_intervals_csv(self.intervals_file, [])
        except InputError as exc:
            self.post_error(f"speedometer: {exc}")
            self._failed = True

    def on_caps(self, info):
        self.warn_non_square(info, "speedometer")
        if not self._begun and self._outputs is not None:
            self._begin()
        wrong = self.file_calibration_mismatch(self._file_cal, self.calibration_file)
        if wrong:
            self.refuse_size(f"speedometer: {wrong}")  # at the first frame: a stream's rotation may turn it
        # frames dropped on the way (a leaky queue) leave whole multiples of the caps' interval: no jitter
        self._jitter.interval = info.fps_d / info.fps_n if info.fps_n > 0 and info.fps_d > 0 else None
        # smoothed against the caps' frame interval (dropped frames stay gaps); a new rate: smoothed anew
        interval = self._jitter.interval if self.retime != "off" else None
        if interval is None:
            self._retimer = None
        elif self._retimer is None or self._retimer.interval != interval:
            self._retimer = FrameRetimer(interval)
        self._jitter.smoothed = self._retimer is not None
        if info.fps_n > 0 and info.fps_d > 0 and self._outputs is not None and self._outputs.brno is not None:
            self._caps_fps = info.fps_n / info.fps_d
            self._outputs.brno.fps = self._caps_fps  # BrnoCompSpeed frame numbers = t * fps (checked: _fix_fps)

    def on_calibration(self, cal):
        self._upstream = cal
        if cal.moved_at is not None:  # vpdetect: the camera moved; nothing found for the old view applies now
            self._scaled = None
            if self._tracking:  # our own tracking: no track continues across the move
                self._tracking.camera_moved()
        if self._tracking is not None:  # decided at the first frame; a scale from upstream makes ours needless
            self._stage = None if self._scale_given() else (self._own_stage or self._stage)
        if self._stage is not None:
            ours = self._stage.on_calibration(cal)
            if ours is not None:
                self._scaled = ours
        return self._apply_calibration(from_upstream=True)

    def on_jump(self, t):
        """A seek (or parts joined): the vehicles in view end here, measured from what was seen before; our own
        tracking starts its tracks again, so no vehicle is measured across the jump."""
        if self._meter is None or self._failed:
            return
        if self._tracking:
            self._tracking.flush()
        if self._retimer is not None:  # the times after the jump are on a line of their own
            self._retimer = FrameRetimer(self._retimer.interval)
        self._emit(self._meter.cut())

    # ------------------------------------------------------------------ calibration
    def _effective(self):
        up = self._upstream
        if up is not None and up.camera is not None and up.camera.scale is not None:
            return up
        if self._file_cal is not None:
            return self._file_cal
        if up is not None and up.camera is not None and self.scale > 0:
            return up.with_scale(self.scale, source=f"{up.source}+speedometer-scale")
        if self._scaled is not None:
            from gst_trafficcal.calibration import same_vanishing_points

            if same_vanishing_points(self._scaled, up):
                return self._scaled
        return up

    def _apply_calibration(self, from_upstream=False):
        """Give the meter the calibration in force; returns whether an upstream event is forwarded as is."""
        cal = self._effective()
        if cal is not None and cal.id != self._in_force_id:
            self._in_force_id = cal.id
            self._emit(self._meter.set_calibration(cal))
            if cal is not self._upstream:
                self.publish_calibration(cal)  # downstream sees what the speeds were measured with
        return cal is self._upstream or not from_upstream

    # ------------------------------------------------------------------ frames
    def _say_jumps(self, jumps) -> None:
        """Say each time the timestamps went back (parts joined, a seek back) — but a stream whose timestamps keep
        going back (reverse playback, frames out of order: another jump within a second of stream time) once,
        not on every frame."""
        for back, given in jumps:
            if self._last_jump is not None and given - self._last_jump < 1.0:
                if not self._said_reverse:
                    self._said_reverse = True
                    self.post_warning("speedometer: the timestamps keep going back (reverse playback, or frames out "
                                      "of order): the vehicles' times go on forwards and their speeds are not "
                                      "those of the road; said once")
            elif any(abs(given - t) < 1e-6 for t in self.stream_clock.switches[-4:]):  # at another stream's start
                self.post_warning(f"speedometer: another stream began (parts joined, a source switched: "
                                  f"input-selector) and its timestamps went back to {back:.3f} s; the vehicles in "
                                  f"view end there and the times go on from {given:.3f} s")
            else:
                self.post_warning(f"speedometer: the timestamps went back to {back:.3f} s (parts joined, a seek "
                                  f"back); the vehicles' times go on from {given:.3f} s")
            self._last_jump = given

    def transform_frame(self, buffer):
        from gst_trafficcal.gst.meta import read_vehicle_rois, update_roi_params
        from gst_trafficcal.measurement import END_AFTER_MARGIN, Sighting, speed_params
        from gst_trafficcal.tracking.vehicle_meta import STRUCTURE as VEHICLE

        if self._failed:
            return Gst.FlowReturn.ERROR
        t = self.buffer_t
        if t is None:  # no time, no speed: passed through
            self.warn_untimed("speedometer", "are passed through unmeasured")
            return Gst.FlowReturn.OK
        if len(self.stream_clock.jumps) > self._jumps:  # timestamps went back (joined parts, a seek): said once each
            self._say_jumps(self.stream_clock.jumps[self._jumps:])
            self._jumps = len(self.stream_clock.jumps)
        if self.stream_clock.out_of_order and not self._said_out_of_order:
            self._said_out_of_order = True
            self.post_warning("speedometer: a frame came out of order (its timestamp a frame or two before the one "
                              "ahead of it: a camera's B-frames with wrong timestamps, or UDP without a jitter "
                              "buffer); such frames are given the time of the frame before them; said once")
        if self._last_pts is not None and t > self._last_pts and len(self._dts) < 50:
            self._dts.append(t - self._last_pts)  # the frame rate of variable-rate caps, for BrnoCompSpeed
        self._last_pts = t
        jitter = self._jitter.add(t)
        if jitter:
            self.post_warning(f"speedometer: {jitter}")
        fit_t = self._retimer.add(t) if self._retimer is not None else None
        # auto: the vehicles measured from now on, those in view too, are measured from the smoothed times
        self._meter.smooth_times = self._retimer is not None and (self.retime == "always" or self._jitter.said)
        if self._start is None and self.start_datetime:
            from gst_trafficcal.clock import NOW, start_from_now

            if self.start_datetime.strip().lower() == NOW:
                self._start = start_from_now(t)
                if self._intervals is not None:
                    self._intervals.set_start(self._start)
        if self._tracking is None:
            upstream = upstream_element(self, "tracker")
            self._tracking = False if upstream is not None else self._tracking_pipeline()
            # a vehicle the tracker still coasts must not be reported as gone
            max_lost = (float(upstream.get_property("max-lost")) if upstream is not None
                        else self._tracking.config.max_lost)
            self._meter.end_after = max(self.vehicle_timeout, max_lost + END_AFTER_MARGIN)
            try:
                self._stage = self._scale_stage()
            except Exception as exc:  # bad scale-* properties, seen only now
                self.post_error(f"speedometer: {exc}")
                return Gst.FlowReturn.ERROR
            self.post_element_message("trafficcal-speedometer",
                                      {"tracking": "upstream" if self._tracking is False else "internal",
                                       "scale": "internal" if self._stage is not None else "upstream"})
            if self._stage is not None and self._upstream is not None:
                self._stage.on_calibration(self._upstream)
        rois = read_vehicle_rois(buffer, self.frame_size,  # the tracker here needs the hulls too
                                 only=(VEHICLE,) if self._tracking is False else None)
        self._check_detector(t, len(rois))
        if self._tracking is False:
            tracked = [r for r in rois if r.object_id is not None and VEHICLE in r.params]
            warning = self._untracked.check(t, len(rois), len(tracked), tracker_upstream=True)
            if warning:
                self.post_warning(warning)
            labelled = [(r, Sighting.from_fields(r.object_id, r.label, r.confidence, r.params[VEHICLE], t=t))
                        for r in tracked]
        else:
            labelled = self._track(buffer, rois, t)
            tracked = None  # written into the buffer by the tracking just now: read them there
        if self._stage is not None:  # bbscale's stage, on what bbscale would read here: the tracked ROIs
            self._scale_frame(buffer, t, tracked)
        said, said_same_time = self._meter.duplicates, self._meter.same_time
        out = self._meter.update(t, [s for _, s in labelled], fit_t)
        if self._meter.same_time and not said_same_time:  # the stream's fault, said once
            self.post_warning(f"speedometer: a frame has the time of the frame before it (at {t:.2f} s: a repeated "
                              "timestamp, or a frame out of order): the vehicles' sightings in such frames are left "
                              "out of their speeds, which would come out too fast; said once")
        if self._meter.duplicates and not said:  # a tracker's fault, said once; the meter keeps one sighting per id
            vid, at = self._meter.first_duplicate
            self.post_warning(f"speedometer: two vehicles in one frame carry the same track id ({vid} at {at:.2f} s; "
                              "a tracker upstream that gives one id twice?): each track is measured from the "
                              "sighting that continues its motion, the others are left out; said once")
        for roi, s in labelled:
            live = out.speeds.get(s.id)
            if live is not None:
                update_roi_params(buffer, roi.index, "speed", speed_params(live, live.label or s.label))
        if not self._emit(out.finished):
            return Gst.FlowReturn.ERROR
        if self._frames is not None and labelled and not self._write_frame(buffer, t):
            return Gst.FlowReturn.ERROR
        if self._intervals is not None and not self._guarded_write(self._intervals.frame, t):
            return Gst.FlowReturn.ERROR
        due = self._results_t is None or t - self._results_t >= self._results_every
        if out.finished and self.results_file and due:
            import time

            from gst_trafficcal.outputs import checkpoint_interval

            self._results_t, began = t, time.monotonic()
            if not self._write_results():
                return Gst.FlowReturn.ERROR
            self._results_every = checkpoint_interval(time.monotonic() - began, _RESULTS_EVERY)
        return Gst.FlowReturn.OK

    def _check_detector(self, t, n_rois):
        """Say once when no vehicle has come for a while and nothing upstream marks vehicles: speedometer measures
        the ROIs a detector (vehicledetect, or another that writes ROI metas) puts on the frames."""
        if self._detector is None:
            self._detector = upstream_element(self, "vehicledetect") is not None
        if self._detector or self._empty_since is False:
            return
        if n_rois:
            self._empty_since = False  # another detector marks them
            return
        if self._empty_since is None:
            self._empty_since = t
        elif t - self._empty_since >= UNTRACKED_AFTER_S:
            waited, self._empty_since = t - self._empty_since, False
            self.post_warning(f"speedometer: no vehicle has arrived in {waited:.0f} s and no detector runs upstream: "
                              "speedometer measures the vehicles a detector marks (... ! vehicledetect ! speedometer "
                              "! ...)")

    def _new_scale_stage(self):
        """bbscale's stage with our scale-* properties (built at start, so bad models or a bad regression file
        are an error there)."""
        from gst_trafficcal.scale.stage import build_stage

        return build_stage(self.scale_models, self.scale_min_vehicles, self.scale_regression_file)

    def _scale_given(self) -> bool:
        """Something else gives the scale: bbscale upstream with a tracker before it (without one it sees no tracked
        vehicle, and our own stage must find the scale), the ``scale`` property, a calibration file with a scale,
        or an upstream calibration that has one (vpdetect ``mode=fixed`` with a scaled file)."""
        bbscale = upstream_element(self, "bbscale")
        return (bbscale is not None and upstream_element(bbscale, "tracker") is not None) or self.scale > 0 or \
            _has_scale(self._file_cal) or _has_scale(self._upstream)

    def _scale_stage(self):
        """Our own scale stage when nothing else can give the scale (built at start, or here when bbscale seemed
        upstream at start but is not linked now)."""
        if self._scale_given():
            return None
        if self._own_stage is None:
            self._own_stage = self._new_scale_stage()
        return self._own_stage

    def _scale_frame(self, buffer, t, tracked=None):
        """Feed this frame's tracked vehicles (``tracked``: the ROIs with a vehicle structure, already read; None:
        read them from ``buffer``) to our scale stage; use the calibration it publishes."""
        from gst_trafficcal.gst.meta import read_vehicle_rois
        from gst_trafficcal.scale.stage import sighting_from_fields
        from gst_trafficcal.tracking.vehicle_meta import STRUCTURE as VEHICLE

        if tracked is None:
            tracked = [r for r in read_vehicle_rois(buffer, self.frame_size, only=(VEHICLE,))
                       if r.object_id is not None and VEHICLE in r.params]
        sightings = [sighting_from_fields(r.object_id, r.label, tuple(r.box), r.params[VEHICLE], t) for r in tracked]
        changed, ours = self._stage.update(t, sightings, self._upstream)
        self._scale_changed(changed, ours)

    def _scale_changed(self, changed, ours):
        if changed:
            self.post_element_message("trafficcal-scale", self._stage.report())
        if ours is not None:
            self._scaled = ours
            self._apply_calibration()
            self.keep_scale_view(ours, self.views_dir)

    def _tracking_pipeline(self):
        """The tracker element's stage with its default properties (no tracker upstream)."""
        from gst_trafficcal.tracking.background import BackgroundModel
        from gst_trafficcal.tracking.pipeline import TrackingPipeline
        from gst_trafficcal.tracking.tracker import TrackerConfig

        self._colour = bool(_tracker_default("colour", True))
        return TrackingPipeline(config=TrackerConfig(), background=BackgroundModel(work_width=480))

    def _track(self, buffer, rois, t):
        """Run the library tracker on this frame's ROIs; label them like the tracker element; return sightings."""
        from gst_trafficcal.gst.meta import OBJECT_ID, detections_from_rois, update_roi_params
        from gst_trafficcal.measurement import Sighting
        from gst_trafficcal.tracking.vehicle_meta import STRUCTURE, vehicle_fields

        pipe = self._tracking
        cal = self._meter.calibration
        camera = cal.camera if cal is not None else None
        if camera is not pipe.camera:
            pipe.set_camera(camera)
        detections = detections_from_rois(rois)
        # as the tracker element's default 'colour' says: its background model also gets the U/V planes
        with self.gray_and_chroma(buffer, self._colour and pipe.background is not None) as (gray, chroma):
            result, detections = pipe.process(gray, t, detections, chroma=chroma)
        out = []
        for i, roi in enumerate(rois):
            track = result.track_of(i)
            if track is None:
                continue
            fields = vehicle_fields(track, track.last, camera, cal.id if cal is not None else "")
            update_roi_params(buffer, roi.index, OBJECT_ID, {"id": int(track.id)})
            update_roi_params(buffer, roi.index, STRUCTURE, fields)
            hull = track.last.hull
            if hull is not None:
                fields["hull"] = hull  # builds the 3D box later when the vanishing points come late
                fields["silhouette"] = bool(track.last.silhouette)  # ... with the tracker's body-shape rule
            out.append((roi, Sighting.from_fields(track.id, track.label, roi.confidence, fields, t=t)))
        pipe.pop_finished()  # the meter decides when a vehicle has left (same rule with or without tracker)
        return out

    # ------------------------------------------------------------------ outputs
    def _stamped(self, measured):
        """A finished vehicle's event with its date and time (start-datetime) and this run's id."""
        from dataclasses import replace

        return replace(measured.event.with_clock(self._start), run=self._run)

    def _fields(self, event):
        """A vehicle's event as messages and events-url carry it: its fields and, with a limit, ``over_limit`` —
        null (absent from the message) for a vehicle without a speed: not known, rather than "not over"."""
        from gst_trafficcal.traffic_stats import is_over_limit

        fields = event.to_dict()
        if self._limit:
            fields["over_limit"] = (None if event.speed_kmh is None
                                    else is_over_limit(event.speed_kmh, self._limit, event.label))
        return fields

    def _emit(self, finished):
        """Post and write each finished vehicle; False (after posting an error) when a file could not be written."""
        from gst_trafficcal.errors import InputError

        if self._meter is not None and self._meter.discarded != self._discarded:
            self._discarded = self._meter.discarded
            self.post_element_message("trafficcal-discarded", {
                "tracks": self._discarded, "why": "seen only between a camera move and its notice"})
        if self._meter is not None and self._meter.not_counted_ids:  # the overlay's counters drop them
            from gst_trafficcal.gst.vehicle_event import not_vehicles_event

            self.srcpad.push_event(not_vehicles_event(self._meter.take_not_counted_ids()))
        if self._meter is not None and dict(self._meter.not_counted) != self._not_counted:
            from gst_trafficcal.measurement import BRIEF, STATIONARY

            self._not_counted = dict(self._meter.not_counted)
            self.post_element_message("trafficcal-not-counted", {
                "brief": self._not_counted.get(BRIEF, 0), "stationary": self._not_counted.get(STATIONARY, 0),
                "min_seen_s": self.min_seen, "min_moved_m": self.min_moved})
        ok = True
        for m in finished:
            event = self._stamped(m)
            fields = self._fields(event)
            self.post_element_message("trafficcal-speed", fields)
            self._tell_downstream(fields, m.merged_ids)
            self._deliver(event, fields)
            try:
                self._write_vehicle(event, m)
            except InputError as exc:  # every other output got the vehicle; the files keep what they have
                if ok and not self._failed:
                    self.post_error(f"speedometer: {exc}")
                ok = False
        if not ok:
            self._failed = True
        return ok

    def _write_vehicle(self, event, m):
        """One finished vehicle's line in the events, CSV and results files (InputError when one cannot be
        written)."""
        if self._outputs is None:
            return
        self._fix_fps()
        self._outputs.vehicle(event, m.times_s if len(m.points_px) else None, m.points_px)

    def _tell_downstream(self, fields, merged_ids=()):
        """The vehicle's fields as a custom downstream event (gst.vehicle_event), so that trafficoverlay counts a
        vehicle measured after it left (the calibration came later) by its direction, lane and speed, and the
        earlier tracks measured with it (``merged_ids``) not as vehicles of their own."""
        from gst_trafficcal.gst.vehicle_event import vehicle_left_event

        self.srcpad.push_event(vehicle_left_event({**fields, "merged_ids": list(merged_ids)} if merged_ids
                                                  else fields))

    def _fix_fps(self):
        """BrnoCompSpeed frame numbers from the median frame interval seen so far, where the caps state no rate
        (variable) or one 1 % off it: an MP4 whose recorder dropped frames states their average (65/3 for 25 fps
        with 2 s missing), and its frame numbers were t·21.67 — fractions, not the frames'."""
        if not self._fps_fixed and self._dts and self._outputs.brno is not None:
            import statistics
            from fractions import Fraction

            seen = 1.0 / statistics.median(self._dts)
            if self._caps_fps is None or abs(seen / self._caps_fps - 1.0) > 0.01:
                self._outputs.brno.fps = float(Fraction(seen).limit_denominator(1001))  # 25, 30000/1001: exact
            self._fps_fixed = True

    def _write_frame(self, buffer, t):
        """One line of ``frames-file``: this frame's vehicle ROIs as they leave (with 'speed' when known)."""
        from gst_trafficcal.gst.meta import read_vehicle_rois

        rois = [r for r in read_vehicle_rois(buffer, self.frame_size) if r.object_id is not None]
        return self._guarded_write(self._frames.write, rois, self.frame_size, t)

    def _write_results(self):
        return self._guarded_write(self._outputs.checkpoint, self._meter.calibration)

    def _guarded_write(self, write, *args):
        """Run one output write; on a file error post it once (the element keeps flowing) and return False."""
        from gst_trafficcal.errors import InputError

        try:
            write(*args)
        except InputError as exc:
            if not self._failed:
                self.post_error(f"speedometer: {exc}")
            self._failed = True
            return False
        return True

    def _finish(self, post):
        """End of stream (or stop): every vehicle leaves, the waiting ones unmeasured; files written and closed."""
        from gst_trafficcal.errors import InputError

        if self._flushed or self._meter is None:
            return
        self._flushed = True
        finished = self._meter.flush()
        if post:
            self._emit(finished)
            if self.remeasure and not self._failed:
                self._revise()
        else:  # stopping without EOS (or after an error): keep what can be kept, quietly
            for m in finished:
                event = self._stamped(m)
                try:
                    self._write_vehicle(event, m)
                except InputError:
                    pass
                self._deliver(event, self._fields(event))
        self._close(report=post)

    def _revise(self):
        """remeasure: the vehicles measured under an earlier calibration, measured again with the final one; their
        lines in the files replaced (outputs.VehicleOutputs.revise) and their interval counts."""
        from gst_trafficcal.errors import InputError

        again = self._meter.remeasure()
        if not again:
            return
        events = [self._stamped(m) for m in again]
        if self._intervals is not None:
            for event in events:
                self._intervals.revise(event)
        cal = self._meter.calibration
        for event in events:  # what was sent when they left is corrected the same way: by (run, id)
            fields = self._fields(event)
            fields["revised"] = True
            self.post_element_message("trafficcal-speed-revised", fields)
            self._tell_downstream(fields)
            self._post(fields)
        self.post_element_message("trafficcal-remeasured", {
            "vehicles": len(events), "measured": sum(e.measured for e in events), "calibration_id": cal.id})
        if self._outputs is None:
            return
        try:
            self._outputs.revise([(e, m.times_s, m.points_px) for e, m in zip(events, again)])
        except InputError as exc:  # the file keeps the first measurement of its vehicles
            self.post_error(f"speedometer: {exc}")
            self._failed = True

    def _deliver(self, event, fields):
        """A vehicle that left, to the outputs that do not fail the stream: the interval table, and events-url's
        poster (a warning, once per new problem, when posting fails)."""
        if self._intervals is not None:
            self._intervals.vehicle(event)
        self._post(fields)

    def _post(self, fields):
        """One event to events-url's poster, if any (a warning, once per new problem, when posting fails)."""
        if self._poster is None:
            return
        self._poster.post(fields)
        self._posted += 1
        problem = self._poster.new_problem()
        if problem:
            self.post_warning(f"speedometer: cannot post vehicle events: {problem}; retrying with each vehicle, and "
                              "every vehicle is still written to the files")

    def _close(self, report=True):
        from gst_trafficcal.errors import InputError

        if self._poster is not None:
            poster, self._poster = self._poster, None
            stats = poster.close(timeout=10.0)
            self.post_element_message("trafficcal-events-url", {
                "url": poster.shown_url, "events": self._posted, "sent": stats.sent, "failed": stats.failed,
                "dropped": stats.dropped})
            if not stats.complete and report:
                why = stats.last_error or "not answered in time"
                self.post_warning(f"speedometer: {stats.failed + stats.dropped} of {self._posted} vehicle events "
                                  f"could not be posted to {poster.shown_url} ({why}); every vehicle is in the files")

        intervals, self._intervals = self._intervals if self._begun else None, None  # never started: untouched
        frames, self._frames = self._frames, None
        outputs, self._outputs = self._outputs, None
        calibration = self._meter.calibration if self._meter is not None else None
        for close in (intervals and intervals.close, frames and frames.close,
                      outputs and (lambda: outputs.close(calibration))):
            if not close:
                continue
            try:
                close()
            except InputError as exc:  # each output is closed, whatever the others did
                if report and not self._failed:
                    self.post_error(f"speedometer: {exc}")
                self._failed = True


def _tracker_default(name, fallback):
    """The default of the ``tracker`` element's property ``name`` (internal tracking follows it), or ``fallback``
    when that element is not installed."""
    factory = Gst.ElementFactory.find("tracker")
    element = factory.create(None) if factory is not None else None
    if element is None:
        return fallback
    try:
        return element.get_property(name)
    except TypeError:  # an older tracker without the property
        return fallback


def _has_scale(cal) -> bool:
    return cal is not None and cal.camera is not None and cal.camera.scale is not None


GObject.type_register(Speedometer)
__gstelementfactory__ = ("speedometer", Gst.Rank.NONE, Speedometer)
