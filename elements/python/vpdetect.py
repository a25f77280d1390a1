"""GStreamer element ``vpdetect``: fully automatic camera calibration (two vanishing points, paper §4.1).

Frames pass through untouched.  The element learns VP1 from tracked vehicle motion (the lines of the tracks,
then how far along them from the tracks' perspective acceleration) and VP2 from edgelets
(``gst_trafficcal.vanishing.calibrator.VPCalibrator``, working on the Y plane of YUV input at a reduced
resolution and on a subset of frames), and announces every state change (learning -> vps, or failed with the
reason) downstream as the sticky ``trafficcal-calibration`` event and on the bus as an element message.
No scale here: λ comes from ``bbscale``.  With ``calibration-file`` it loads a stored calibration (mode
auto/fixed) or saves the one it learnt (mode auto/learn).
"""

from gst_trafficcal.gst._gi import GObject, Gst
from gst_trafficcal.gst.element import TrafficcalTransform

_RW = GObject.ParamFlags.READWRITE
MODES = ("auto", "learn", "fixed")


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
        "constant-speed": (bool, "Constant speed", "Move VP1 along the lanes to where the tracked points' "
                           "perspective acceleration puts it, taking vehicles to keep their speed for the second or "
                           "two a point is tracked (the lane lines alone place VP1 poorly along the lanes, which "
                           "stretches the road with distance); off where traffic keeps braking and accelerating",
                           True, _RW),
    }
    PASSTHROUGH = True

    def __init__(self):
        super().__init__()
        self._learner = None
        self._frames = 0
        self._fps = 25.0
        self._format = "I420"

    def on_caps(self, info):
        from gst_trafficcal.calibration import Calibration, load_calibration
        from gst_trafficcal.cli.calibrate import parse_focal_range
        from gst_trafficcal.vanishing.calibrator import CalibratorConfig, VPCalibrator

        from gst_trafficcal.gst.buffers import format_name

        if info.fps_n > 0 and info.fps_d > 0:
            self._fps = info.fps_n / info.fps_d
        self._format = format_name(info)
        if self.mode not in MODES:
            self.post_error(f"vpdetect: unknown mode {self.mode!r} (expected one of {', '.join(MODES)})")
            return
        path = self.calibration_file
        if self.mode == "fixed" and not path:
            self.post_error("vpdetect: mode=fixed needs calibration-file")
            return
        from pathlib import Path

        if path and self.mode != "learn" and (self.mode == "fixed" or Path(path).exists()):
            try:
                cal = load_calibration(path)
                if cal.camera is None:
                    raise ValueError(f"{path}: holds no vanishing points (state {cal.state})")
                if tuple(cal.image_size) != tuple(self.frame_size):
                    raise ValueError(f"{path}: calibration is for {cal.image_size[0]}x{cal.image_size[1]}, "
                                     f"the video is {self.frame_size[0]}x{self.frame_size[1]}")
            except Exception as exc:
                self.post_error(f"vpdetect: {exc}")
                return
            self._learner = None
            self.publish_calibration(cal)
            return
        if self._learner is not None and self._learner.image_size == tuple(self.frame_size):
            return
        try:
            width = self.frame_size[0]
            d = self.downscale
            config = CalibratorConfig(min_duration=self.min_duration, max_duration=self.max_duration,
                                      focal_range=parse_focal_range(self.focal_range), method=self.method,
                                      horizon_max_deg=self.horizon_max,
                                      vp1_constant_speed=self.constant_speed,
                                      track_width=round(width / d) if d else 960,
                                      edgelet_width=round(width / d) if d else 960)
            self._learner = VPCalibrator(self.frame_size, config)
        except Exception as exc:  # bad property values or frame size: readable error at negotiation
            self.post_error(f"vpdetect: {exc}")
            return
        self.publish_calibration(Calibration(None, self.frame_size, state="learning", source="vpdetect"))

    def on_calibration(self, cal):
        return self._learner is None  # while learning, our own calibration is the one downstream sees

    def transform_frame(self, buffer):
        from gst_trafficcal.gst.buffers import pts_seconds
        from gst_trafficcal.vanishing.frames import luma

        learner = self._learner
        if learner is None or learner.done:
            return Gst.FlowReturn.OK
        t = pts_seconds(buffer)
        if t is None:
            t = self._frames / self._fps
        self._frames += 1
        # the luma plane, computed by the same function as for files (trafficcal calibrate): the Y plane of
        # I420/NV12/GRAY8 as it is, colour formats converted to BT.601 limited-range luma
        with self.planes(buffer) as planes:
            changed = learner.add(luma(planes[0], self._format), t)
        if changed:
            self._publish(learner.calibration)
        return Gst.FlowReturn.OK

    def on_eos(self):
        learner = self._learner
        if learner is not None and not learner.done:
            self._publish(learner.finish())

    def _publish(self, cal):
        from gst_trafficcal.calibration import save_calibration

        self.publish_calibration(cal)
        if cal.state == "failed":
            self.post_warning(f"vpdetect: calibration failed: {cal.reason}")
        elif self.calibration_file:
            save_calibration(cal, self.calibration_file)


GObject.type_register(VpDetect)
__gstelementfactory__ = ("vpdetect", Gst.Rank.NONE, VpDetect)
