"""GStreamer element ``vpdetect``: fully automatic camera calibration (two vanishing points, paper §4.1).

Frames pass through untouched.  The element learns VP1 from tracked vehicle motion (the lines of the tracks,
then how far along them from the tracks' perspective acceleration) and VP2 from edgelets
(``gst_trafficcal.vanishing.calibrator.VPCalibrator``, working on the Y plane of YUV input at a reduced
resolution and on a subset of frames), and announces every state change (learning -> vps, or failed with the
reason) downstream as the sticky ``trafficcal-calibration`` event and on the bus as an element message.
No scale here: λ comes from ``bbscale``.  With ``calibration-file`` it loads a stored calibration (mode
auto/fixed) or saves the one it learnt (mode auto/learn), with a thumbnail of the static scene it was learnt on
(``view``, ``gst_trafficcal.vanishing.view``).  A loaded calibration with a view is checked against the stream's
first seconds: if the camera has moved (shifted, zoomed, rotated, or another scene), mode auto warns and learns
anew (and saves the new calibration); mode fixed warns and keeps the file's.  Then, all along the stream, the
calibration in force is watched (``ViewMonitor``): a camera knocked or re-aimed mid-stream is noticed a second or
two later; modes auto and learn then announce a "learning" calibration with ``moved_at`` (when it moved), which
tells the elements downstream that what they saw before belongs to the previous calibration, and learn anew; mode
fixed warns.  Each change is also a ``trafficcal-view`` bus message.

Every view the element has had a calibration for in this stream (the file's, each one learnt) is remembered
(``ViewLibrary``): when the camera moves to one of them — a PTZ camera back at a preset, a knocked camera put
back — that calibration is announced again at once (with ``moved_at``; bbscale gives it back the scale it found
for it), also while a new view is being learnt, instead of learning it anew for minutes.  With ``views-dir`` the
views outlive the pipeline: every calibration in the folder (one JSON per view, ``calibration.save_view``) is
known from the start — the stream's first seconds pick the one it shows — and each one learnt is added to it,
with the element's ``orientation``: a view kept with another one is not used (a camera mounted another way is
another view).

Started again (NULL or READY, then PLAYING: an NVR reconnecting, or re-pointed at another camera) the element
begins as a new one: what it keeps from a run is in ``calibration-file`` and ``views-dir``, read again at the start.
"""

from gst_trafficcal.gst._gi import GObject, Gst
from gst_trafficcal.gst.element import READY_ONLY, TrafficcalTransform

_RW = READY_ONLY  # read at start (gst-inspect-1.0: changeable only in NULL or READY state)
MODES = ("auto", "learn", "fixed")
#: why a calibration-file or views-dir another vpdetect of the process writes is refused (gst.file_claims)
ONE_WRITER = ("two vpdetects learning into one calibration file or views folder replace each other's calibrations "
              "(two cameras' in one file, their views mixed in one folder); give each vpdetect its own")
VIEW_CHECK_SAMPLES = 15  # thumbnails (every 5th frame: 3 s at 25 fps) before a loaded calibration's view is checked


class VpDetect(TrafficcalTransform):
    __gtype_name__ = "GstVpdetect"
    __gstmetadata__ = ("vpdetect", "Filter/Analyzer/Video",
                       "Fully automatic traffic-camera calibration: VP1 from vehicle motion (KLT tracks), VP2 from "
                       "edgelets, both through a Diamond Space; sends the trafficcal-calibration event",
                       "gst-trafficcal")
    __gproperties__ = {
        "calibration-file": (str, "Calibration file", "Calibration JSON: loaded when it exists (modes auto, fixed), "
                             "otherwise written when the calibration converges (modes auto, learn)", "", _RW),
        "mode": (str, "Mode", "auto: load calibration-file if it exists, else learn and save it; learn: always "
                 "learn (and overwrite calibration-file); fixed: only load calibration-file (error if missing)",
                 "auto", _RW),
        "min-duration": (float, "Minimum duration", "Seconds of video before a calibration can be declared",
                         0.0, 1e6, 20.0, _RW),
        "max-duration": (float, "Maximum duration", "Seconds of video after which an unconverged calibration is "
                         "declared failed (with the reason)", 1.0, 1e7, 180.0, _RW),
        "downscale": (float, "Downscale", "Analysis resolution: tracking and edgelets run at 1/downscale of the frame "
                      "size (0 = automatic: at most 960 px wide)",
                      0.0, 64.0, 0.0, _RW),
        "focal-range": (str, "Focal range", "MIN,MAX plausible focal length in pixels for VP2 (empty: 0.3 to 6 "
                        "times the frame width)", "", _RW),
        "horizon-max": (float, "Maximum horizon inclination", "VP2 only where the horizon (line VP1-VP2) is within "
                        "this many degrees of horizontal (90: no limit); excludes the vertical vanishing point",
                        1.0, 90.0, 30.0, _RW),
        "method": (str, "VP2 method", "edgelets (the paper) or gradient (orientation of image gradients, ITS15 "
                   "baseline)", "edgelets", _RW),
        "view-check": (bool, "View check", "Compare the stream with the scene the calibration in force was learnt "
                       "on: a loaded calibration in the first seconds, and any calibration all along the stream; if "
                       "the camera has moved, warn, and (mode fixed excepted) learn anew", True, _RW),
        "views-dir": (str, "Views folder", "Folder of calibrations of this camera's views (PTZ presets; one JSON "
                      "per view, with the view it was learnt on): known from the start, so the view the stream "
                      "shows — at the start or after a move — gets its calibration at once; each calibration "
                      "learnt is added (mode learn: only added to; empty: views are remembered for this stream "
                      "only)",
                      "", _RW),
        "constant-speed": (bool, "Constant speed", "Move VP1 along the lanes to where the tracked points' "
                           "perspective acceleration puts it, taking vehicles to keep their speed for the second or "
                           "two a point is tracked (the lane lines alone place VP1 poorly along the lanes, which "
                           "stretches the road with distance); off where traffic keeps braking and accelerating",
                           True, _RW),
        "zone": (str, "Zone", "Learn only from the traffic inside: polygons 'x,y x,y x,y ...' separated by ';', in "
                 "pixels or fractions 0..1 of the frame — the measured road, without a side road or a parking lot "
                 "(empty: the whole frame); kept in calibration-file", "", _RW),
        "orientation": (str, "Orientation", "How the picture was turned before vpdetect (the videoflip "
                        "video-direction given, as trafficcal run --orientation: 90r, 180, 90l, horiz, ...): kept in "
                        "calibration-file's field orientation, so a run given the file turns the picture the same "
                        "way, and in views-dir's views, used only by a vpdetect of the same orientation (empty or "
                        "auto: none kept)", "", _RW),
    }
    PASSTHROUGH = True

    def __init__(self):
        super().__init__()
        self._reset()

    def _reset(self):
        """The state of one run, as a new element has it (at creation, start and stop): a pipeline started again
        (NULL or READY, then PLAYING: an NVR reconnecting, or pointed at another camera) learns, loads and checks
        its views as a new one would, instead of taking the last run's learner, views and calibration in force for
        the new stream's (views-dir and calibration-file are read again: what outlives a run is in files)."""
        self._learner = None
        self._warned_view_of = None  # the learner whose view was said to pin the speeds down poorly
        self._frames = 0
        self._fps = 25.0
        self._format = "I420"
        self._views = None  # ViewAccumulator: the stream's static scene (learning, or checking a loaded calibration)
        self._loaded = None  # a loaded calibration whose view is being checked
        self._held = False  # ... and not published yet (mode auto: held until the check is done)
        self._monitor = None  # ViewMonitor watching the calibration in force for a moved camera
        self._moved_at = None  # when the camera moved, while the new view is being learnt
        self._library = None  # ViewLibrary: every view calibrated in this stream, by calibration id
        self._known = {}  # ... and those calibrations
        self._in_force = None  # id of the calibration whose view is watched
        self._return = None  # ReturnWatcher: while learning, a known view seen again
        self._views_loaded = False  # views-dir read
        self._size = None  # the frame size of the caps so far
        self._zone = None  # gst_trafficcal.zone.Zone: where the traffic to learn from is
        self._orientation = "auto"  # how the picture was turned upstream: kept in the calibration file
        self._said_upstream = False  # the warning that a calibration from upstream is replaced: once

    def do_start(self):
        """A calibration file to be written (modes learn and auto) whose folder cannot be written is an error now,
        not after the minutes of video the calibration takes to learn."""
        from gst_trafficcal.errors import InputError
        from gst_trafficcal.fileio import writable_file
        from gst_trafficcal.imaging import check_orientation
        from gst_trafficcal.vanishing.calibrator import CalibratorConfig
        from gst_trafficcal.zone import parse_zone

        self._reset()
        try:
            self._zone = parse_zone(self.zone)
            self._orientation = check_orientation(self.orientation, "orientation")
            # durations that can only fail: now, not when learning starts (with a loaded file: after a camera move)
            CalibratorConfig(min_duration=self.min_duration, max_duration=self.max_duration)
        except InputError as exc:
            self.post_error(f"vpdetect: {exc}")
            return False
        if self.mode in ("learn", "auto"):  # (mode fixed reads them only)
            try:
                # one writer each: two vpdetects learning into one calibration file or views folder replaced each
                # other's calibrations (two cameras' in one file, their views mixed), without a word
                self.claim_files({"calibration-file": self.calibration_file, "views-dir": self.views_dir},
                                 why=ONE_WRITER)
                if self.calibration_file:
                    writable_file(self.calibration_file, "calibration file")
            except InputError as exc:
                self.release_files()
                self.post_error(f"vpdetect: {exc}")
                return False
        return True

    def do_stop(self):
        self.release_files()
        self._reset()  # the learner's frames and the views go now, not at the next start
        return super().do_stop()

    def on_caps(self, info):
        from gst_trafficcal.calibration import Calibration, load_calibration
        from gst_trafficcal.gst.buffers import format_name

        self.warn_non_square(info, "vpdetect")
        if info.fps_n > 0 and info.fps_d > 0:
            self._fps = info.fps_n / info.fps_d
        self._format = format_name(info)
        if self.mode not in MODES:
            self.post_error(f"vpdetect: unknown mode {self.mode!r} (expected one of {', '.join(MODES)})")
            return
        size, before = tuple(self.frame_size), self._size
        self._size = size
        # checked here in every mode, also with a loaded calibration
        if self._zone is not None and size != before and not self.zone_fits(self._zone, size, "vpdetect"):
            return
        if before is not None and size != before and self._frames > 0:
            self._resized(before)
            return
        path = self.calibration_file
        if self.mode == "fixed" and not path:
            self.post_error("vpdetect: mode=fixed needs calibration-file")
            return
        self._load_views()
        from pathlib import Path

        if path and self.mode != "learn" and (self.mode == "fixed" or Path(path).exists()):
            try:
                cal = load_calibration(path)
                if cal.camera is None:
                    raise ValueError(f"{path}: holds no vanishing points (state {cal.state})")
                wrong = self.file_calibration_mismatch(cal, path)
                if wrong:  # said at the first frame (a stream's rotation may turn it before), published at none
                    self.refuse_size(f"vpdetect: {wrong}")
                    return
            except Exception as exc:
                self.post_error(f"vpdetect: {exc}")
                return
            self._learner = None
            if cal.view is not None and self.view_check:
                from gst_trafficcal.vanishing.view import ViewAccumulator

                self._views, self._loaded = ViewAccumulator(), cal
                self._held = self.mode == "auto"  # a moved camera must not measure with the file's calibration
                if self._held:
                    self.publish_calibration(Calibration(None, self.frame_size, state="learning", source="vpdetect"))
                    return
            self.publish_calibration(cal)
            return
        if self._learner is not None and self._learner.image_size == tuple(self.frame_size):
            return
        self._start_learning()

    def _resized(self, before):
        """The frame size changed mid-stream (another stream, the camera's settings): another view — announced
        as a move, so that nothing seen at the old size is measured with what comes; learnt anew (mode fixed: an
        error, the file is for the old size)."""
        t = self.buffer_t if self.buffer_t is not None else self._frames / self._fps
        what = f"the frame size changed from {before[0]}x{before[1]} to {self._size[0]}x{self._size[1]} at {t:.1f} s"
        if self.mode == "fixed":
            self.post_error(f"vpdetect: {what}; {self.calibration_file} is a calibration of {before[0]}x{before[1]} "
                            "frames")
            return
        self._loaded, self._held, self._monitor, self._in_force, self._return = None, False, None, None, None
        self._library, self._known, self._views_loaded = None, {}, False
        self._load_views()  # views-dir: the views of the new size
        self.post_warning(f"vpdetect: {what}: another view; learning a new calibration")
        self._learn_after_move(t, f"the camera moved at {t:.1f} s ({what})")

    def _learn_after_move(self, t, reason):
        """The camera moved at ``t`` to a view without a calibration: announce it (``moved_at``) and learn it."""
        from gst_trafficcal.calibration import Calibration

        self._moved_at = float(t)
        self._start_learning(Calibration(None, tuple(self.frame_size), state="learning", source="vpdetect",
                                         reason=reason, moved_at=float(t)))

    def _start_learning(self, announce=None):
        """Learn a calibration from here on; ``announce``: the "learning" calibration to send (default: a plain
        one)."""
        from gst_trafficcal.calibration import Calibration
        from gst_trafficcal.cli.calibrate import parse_focal_range
        from gst_trafficcal.vanishing.calibrator import CalibratorConfig, VPCalibrator
        from gst_trafficcal.vanishing.view import ViewAccumulator

        self._views = ViewAccumulator(keep=60)
        if self._library:
            from gst_trafficcal.vanishing.view import ReturnWatcher

            self._return = ReturnWatcher(self._library)
        try:
            width = self.frame_size[0]
            d = self.downscale
            config = CalibratorConfig(min_duration=self.min_duration, max_duration=self.max_duration,
                                      focal_range=parse_focal_range(self.focal_range), method=self.method,
                                      horizon_max_deg=self.horizon_max,
                                      vp1_constant_speed=self.constant_speed,
                                      track_width=round(width / d) if d else 960,
                                      edgelet_width=round(width / d) if d else 960, zone=self._zone)
            self._learner = VPCalibrator(self.frame_size, config)
        except Exception as exc:  # bad property values or frame size: readable error at negotiation
            self.post_error(f"vpdetect: {exc}")
            return
        self.publish_calibration(announce or Calibration(None, self.frame_size, state="learning", source="vpdetect"))

    def on_calibration(self, cal):
        # while learning or holding a loaded calibration back, our own calibration is the one downstream sees
        forward = self._learner is None and not self._held
        if not forward and not self._said_upstream:  # two vpdetects, or a calibration source before this one
            self._said_upstream = True
            self.post_warning(f"vpdetect: a calibration also comes from upstream ({cal.source}, {cal.state}; another "
                              "vpdetect?) and this vpdetect's own replaces it downstream: keep one of them")
        return forward

    def transform_frame(self, buffer):
        from gst_trafficcal.vanishing.frames import luma

        learner = self._learner
        checking = self._loaded is not None
        t = self.buffer_t
        if t is None:
            t = self._frames / self._fps
        self._frames += 1
        if not checking and (learner is None or learner.done):
            if self._monitor is not None:
                self._monitor_frame(buffer, t)
            return Gst.FlowReturn.OK
        # the luma plane, computed by the same function as for files (trafficcal calibrate): the Y plane of
        # I420/NV12/GRAY8 as it is, colour formats converted to BT.601 limited-range luma
        with self.planes(buffer) as planes:
            y = luma(planes[0], self._format)
            self._views.add(y)
            if checking:
                if self._views.count >= VIEW_CHECK_SAMPLES:
                    self._check_view()
                return Gst.FlowReturn.OK
            back = None
            if self._return is not None:  # a view calibrated before, seen again: no need to learn it
                back = self._return.add(y, t)
            if back is not None:
                self._switch_to(*back)
                return Gst.FlowReturn.OK
            changed = learner.add(y, t)
        if changed:
            self._publish(learner.calibration)
        return Gst.FlowReturn.OK

    def _check_view(self):
        """Compare the stream's scene with the loaded calibration's; publish it, or (moved) warn and in mode auto
        learn anew."""
        from gst_trafficcal.vanishing.view import compare_views, decode_view, thumbnail

        cal, self._loaded = self._loaded, None
        try:
            stored, width = decode_view(cal.view, self.calibration_file)
        except Exception as exc:  # a broken view: the calibration itself is readable, so say so and use it
            self.post_warning(f"vpdetect: {exc}; the camera view is not checked")
            stored = None
        current = self._views.view()
        match = compare_views(stored, current, width) if stored is not None and current is not None else None
        if match is not None and stored.shape != current.shape:  # another aspect ratio than the file's
            match = None
        if match is not None:
            self._remember(cal, stored, width)
        if match is None or not match.moved:
            if self._held:
                self.publish_calibration(cal)
            self._held = False
            if match is not None:  # (a view of another aspect ratio is not watched: it would never match)
                self._watch(stored, width, cal.id)
            return
        found = self._library.find(current, exclude=cal.id) if self._library and self._held else None
        if found is not None:  # the camera shows another view it has a calibration for
            self._held = False
            self._switch_to(*found[:1], None, found[1])
            return
        if not self._held:  # mode fixed: the file's calibration stays, the user is told
            self.post_warning(f"vpdetect: the camera view differs from the one {self.calibration_file} was "
                              f"calibrated on ({match.describe()}): the camera may have moved and speeds may be "
                              "wrong; recalibrate (mode=auto or learn)")
            return
        self._held = False
        self.post_warning(f"vpdetect: the camera view differs from the one {self.calibration_file} was calibrated "
                          f"on ({match.describe()}): the camera has moved; learning a new calibration (it will "
                          "replace the file)")
        self._start_learning()

    def _watch(self, stored, width, key):
        """Watch the calibration in force (id ``key``; its view: thumbnail ``stored`` of ``width``-px frames) from
        now on."""
        from gst_trafficcal.vanishing.view import ViewMonitor

        self._monitor = ViewMonitor(stored, width, every=max(1, round(self._fps / 5)))  # 5 comparisons a second
        self._in_force = key

    def _load_views(self):
        """views-dir's calibrations for this frame size, once per stream (unusable files: a warning each)."""
        from gst_trafficcal.calibration import load_views
        from gst_trafficcal.vanishing.view import decode_view

        if self._views_loaded or not self.views_dir or not self.view_check or self.mode == "learn":
            return  # (mode learn learns whatever the folder holds, and adds to it)
        self._views_loaded = True
        found, skipped = load_views(self.views_dir, tuple(self.frame_size), self._orientation)
        for why in skipped:
            self.post_warning(f"vpdetect: views-dir: {why}: not used")
        for cal in found:
            try:
                self._remember(cal, *decode_view(cal.view, str(self.views_dir)))
            except Exception as exc:  # a broken thumbnail: that view is not known
                self.post_warning(f"vpdetect: views-dir: {exc}: not used")

    def _remember(self, cal, stored, width):
        """A calibration with its view: used again whenever the stream shows that view after a move."""
        from gst_trafficcal.calibration import same_vanishing_points
        from gst_trafficcal.vanishing.view import ViewLibrary

        if self._library is None:
            self._library = ViewLibrary()
        for key, old in list(self._known.items()):  # one entry per view: the one with a scale if either has one
            if key != cal.id and same_vanishing_points(old, cal):
                if old.camera.scale is not None and cal.camera.scale is None:
                    return
                del self._known[key]
                self._library.remove(key)
        self._library.add(cal.id, stored, width)
        self._known[cal.id] = cal

    def _switch_to(self, key, t, match):
        """The stream shows the view of known calibration ``key``: announce it (with ``moved_at`` = ``t`` when the
        camera moved there from a view in force or being learnt after a move; ``t`` None: found at the start, nothing
        seen before belongs to another view), and watch it."""
        from dataclasses import replace

        cal = self._known[key]
        moved = t is not None and (self._in_force is not None or self._moved_at is not None)
        self._learner, self._return, self._moved_at, self._views = None, None, None, None
        if moved:
            self.post_warning(f"vpdetect: the camera moved at {t:.1f} s to a view it was calibrated on before "
                              f"({match.describe()} against it): using calibration {cal.id} again")
        else:
            self.post_info(f"vpdetect: the stream shows a view calibrated before ({match.describe()} against "
                           f"it): using calibration {cal.id}")  # good news: an INFO, not a warning
        self.post_element_message("trafficcal-view", {
            "state": "returned", "t": float(t or 0.0), "calibration_id": cal.id, "shift_x": match.shift[0],
            "shift_y": match.shift[1], "zoom": float(match.zoom), "rotation_deg": float(match.rotation_deg),
            "similarity": float(match.similarity)})
        self.publish_calibration(replace(cal, moved_at=float(t)) if moved else cal)
        if self.calibration_file and self.mode != "fixed":
            self._save(cal)  # the file holds the calibration in force
        self._watch(*self._library.views[key], key)

    def _monitor_frame(self, buffer, t):
        from gst_trafficcal.vanishing.frames import luma

        monitor = self._monitor
        if not monitor.wants():
            monitor.skip()
            return
        with self.planes(buffer) as planes:
            event = monitor.add(luma(planes[0], self._format), t)
        if event is None:
            return
        m = event.match
        self.post_element_message("trafficcal-view", {
            "state": event.kind, "t": float(event.t), "shift_x": m.shift[0], "shift_y": m.shift[1],
            "zoom": float(m.zoom), "rotation_deg": float(m.rotation_deg), "similarity": float(m.similarity)})
        if event.kind == "unrecognised":
            self.post_warning(f"vpdetect: since {event.t:.1f} s the scene no longer matches the view the calibration "
                              f"was learnt on (similarity {m.similarity:.2f}): too dark, obscured, or another scene; "
                              "the calibration is kept (speeds are wrong if the camera was moved)")
        elif event.kind == "moved":
            self._camera_moved(event)

    def _camera_moved(self, event):
        current = self._monitor.current()
        self._monitor = None
        what = f"the camera moved at {event.t:.1f} s ({event.match.describe()})"
        if self._zone is not None:  # polygons of the frame: they do not follow the view
            self.post_warning(f"vpdetect: the detection zone ({self._zone}) was drawn for the view before the move at "
                              f"{event.t:.1f} s and stays where it was in the frame: check it against the new view "
                              "(vehicles and calibration are still taken from inside it only)")
        if self.mode == "fixed":
            self.post_warning(f"vpdetect: {what}: speeds from here on are wrong; recalibrate (mode=auto or learn)")
            return
        found = self._library.find(current, exclude=self._in_force) if self._library else None
        if found is not None:
            self._switch_to(found[0], event.t, found[1])
            return
        self.post_warning(f"vpdetect: {what}: learning a new calibration"
                          + (f" (it will replace {self.calibration_file})" if self.calibration_file else ""))
        self._learn_after_move(event.t, f"the camera moved at {event.t:.1f} s")

    def on_eos(self):
        if self._loaded is not None:  # the stream ended while its view was being checked
            if self._views.count >= 3:
                self._check_view()
            elif self._held:
                self._held = False
                cal, self._loaded = self._loaded, None
                self.publish_calibration(cal)
        learner = self._learner
        if learner is not None and not learner.done:
            self._publish(learner.finish())

    def _publish(self, cal):
        from dataclasses import replace

        if cal.state == "failed" and self._moved_at is not None:  # say why there was something to learn
            cal = replace(cal, reason=f"the camera moved at {self._moved_at:.1f} s and the new view could not be "
                                      f"calibrated: {cal.reason}")
        elif cal.camera is not None:
            self._moved_at = None

        if cal.camera is not None and cal.view is None and self._views is not None and self._views.count:
            from gst_trafficcal.vanishing.view import encode_view

            cal = replace(cal, view=encode_view(self._views.view(), self.frame_size[0]))
        self.publish_calibration(cal)
        if cal.camera is not None and self._learner is not None and self._warned_view_of is not self._learner:
            cond = cal.conditioning()
            if cond.poor:  # once per view learnt
                self._warned_view_of = self._learner
                self.post_warning(f"vpdetect: {cond.describe()}")
        if cal.camera is not None and cal.view is not None and self.view_check and self._learner.done:
            from gst_trafficcal.vanishing.view import decode_view

            stored, width = decode_view(cal.view)
            self._remember(cal, stored, width)
            self._return = None
            self._watch(stored, width, cal.id)
            if self.views_dir:
                from gst_trafficcal.calibration import save_view

                try:
                    save_view(cal, self.views_dir, self._orientation)
                except Exception as exc:  # the calibration itself is fine: say why the folder did not get it
                    self.post_warning(f"vpdetect: views-dir: {exc}")
        if cal.state == "failed":
            self.post_warning(f"vpdetect: calibration failed: {cal.reason}")
        elif self.calibration_file:
            self._save(cal)

    def _save(self, cal):
        """Write ``cal`` to ``calibration-file``; a file that cannot be written (a full disk) is a warning: the
        calibration is in force downstream and on the bus all the same, and the measurement goes on."""
        from gst_trafficcal.calibration import save_calibration
        from gst_trafficcal.errors import InputError

        try:
            save_calibration(cal, self.calibration_file, zone=self._zone, orientation=self._orientation)
        except InputError as exc:
            self.post_warning(f"vpdetect: the calibration is in force but not saved: {exc}")


GObject.type_register(VpDetect)
__gstelementfactory__ = ("vpdetect", Gst.Rank.NONE, VpDetect)
