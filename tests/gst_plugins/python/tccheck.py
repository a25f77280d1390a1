"""Test element ``tccheck``: a downstream consumer of gst_trafficcal.gst metadata.

Passthrough (it never writes). Per frame it reads the ROIs (read_vehicle_rois) and posts an
element message ``tccheck`` with their count, the first ROI's box and mean, and the id of the
calibration it received from upstream through the base class (empty when none), and the frame's time in the
element (``t``: its ``buffer_t``, -1 when untimed) with its stream time (``stream``), the jumps seen so far
(``jumps``: on_jump calls) and the frames its clock took for out of order (``out-of-order``).
"""

from gst_trafficcal.gst.element import TrafficcalTransform
from gst_trafficcal.gst._gi import GObject, Gst
from gst_trafficcal.gst.buffers import stream_seconds
from gst_trafficcal.gst.meta import read_vehicle_rois


class TcCheck(TrafficcalTransform):
    __gtype_name__ = "GstTcCheck"
    __gstmetadata__ = ("tccheck", "Filter/Analyzer/Video", "gst-trafficcal plumbing test: ROI/calibration reader",
                       "gst-trafficcal tests")
    PASSTHROUGH = True
    __gproperties__ = {
        "drop-calibration": (bool, "Drop calibration", "Keep calibration events (on_calibration returns False) "
                             "instead of forwarding them", False, GObject.ParamFlags.READWRITE),
    }

    def do_start(self):
        self.jumps = 0  # on_jump calls this run
        return True

    def on_jump(self, t):
        self.jumps += 1

    def on_calibration(self, cal):
        return not self.drop_calibration

    def transform_frame(self, buffer):
        rois = read_vehicle_rois(buffer, self.frame_size)
        fields = {"rois": len(rois), "calibration": self.calibration.id if self.calibration else "",
                  "t": -1.0 if self.buffer_t is None else self.buffer_t,
                  "stream": stream_seconds(buffer, self._segment) or 0.0, "jumps": self.jumps,
                  "out-of-order": self.stream_clock.out_of_order}
        if rois:
            fields["box"] = list(rois[0].box)
            fields["mean"] = rois[0].params.get("tc-test", {}).get("mean", -1.0)
        self.post_element_message("tccheck", fields)
        return Gst.FlowReturn.OK


GObject.type_register(TcCheck)
__gstelementfactory__ = ("tccheck", Gst.Rank.NONE, TcCheck)
