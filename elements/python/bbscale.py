"""GStreamer element ``bbscale``: the scene scale λ from 3D vehicle model bounding-box alignment (paper §4.3).

Reads the tracked vehicles of each frame (ROI metas with ``object_id`` and the ``trafficcal-vehicle``
structure written by ``tracker``) and the calibration (sticky "trafficcal-calibration" event with the vanishing
points).  Fully visible vehicles are aligned with the catalogue's 3D models when their track ends
(:class:`gst_trafficcal.scale.streaming.ScaleEstimator`).  When ``min-vehicles`` vehicles agree, the
calibration is sent downstream again with λ (state ``calibrated``, ``confidence_scale``) and posted on the bus;
it is re-sent when λ moves by more than 0.5 %, and at the end of the stream with the final estimate.  Every change of the estimate posts a ``trafficcal-scale``
element message (status, λ*, counts) saying why there is no scale yet.  A calibration that already carries a
scale (e.g. from a calibration file) is passed through untouched.  With ``views-dir`` (vpdetect's views folder) each
scale found is kept there with its view, so that a restarted pipeline measures from its first vehicle.
"""

from gst_trafficcal.gst._gi import GObject, Gst
from gst_trafficcal.gst.element import READY_ONLY, TrafficcalTransform

_RW = READY_ONLY  # read at start (gst-inspect-1.0: changeable only in NULL or READY state)


class BBScale(TrafficcalTransform):
    __gtype_name__ = "GstBbscale"
    __gstmetadata__ = ("bbscale", "Filter/Analyzer/Video",
                       "Scene scale from aligning 3D vehicle models with the tracked vehicles' boxes (BBScale); "
                       "re-sends the calibration with the scale", "gst-trafficcal")
    __gproperties__ = {
        "models": (str, "Models", "Vehicle types to align: empty = every named type of the repository catalogue; "
                   "a catalogue YAML file; or comma-separated type names", "", _RW),
        "iou-threshold": (float, "IoU threshold", "Minimum IoU between a rendered model box and the detected box "
                          "for a match to count", 0.01, 0.99, 0.85, _RW),
        "min-vehicles": (int, "Minimum vehicles", "Matched vehicles that must agree on the scale (their own "
                         "scale within 8 % of the estimate) before it is published; trucks, buses and merged blobs "
                         "(3D-box length/width outside 0.8-3.5) are not aligned", 1, 100000, 5, _RW),
        "regression-file": (str, "Regression file", "Scale-correction regression JSON (trafficcal fit-scale); "
                            "empty = none", "", _RW),
        "classifier": (str, "Classifier", "Optional ONNX fine-grained classifier (crop -> catalogue type "
                       "probabilities); empty = every type is tried and the match quality decides", "", _RW),
        "box": (str, "Box", "Which 2D box of a tracked vehicle is aligned: 'hull' (the box of its foreground convex "
                "hull, the tracker's hull_box) or 'detector' (the detector's rectangle)", "detector", _RW),
        "renderer": (str, "Renderer", "Model boxes by 'projection' (exact bounding box of the projected mesh, "
                     "fast) or 'gl' (moderngl silhouettes, slow)", "projection", _RW),
        "views-dir": (str, "Views folder", "The camera's views folder (vpdetect views-dir): each scale found is kept "
                      "there with its view, so that after a restart vpdetect gives the view with its scale at once; "
                      "empty = none", "", _RW),
    }

    def __init__(self):
        super().__init__()
        self._stage = None
        self._classifier = None

    def do_start(self):
        from gst_trafficcal.errors import TrafficcalError
        from gst_trafficcal.gst.untracked import UntrackedWatch
        from gst_trafficcal.scale.stage import build_stage

        self._untracked = UntrackedWatch("bbscale")
        self._tracker_upstream = None  # decided at the first frame, when the pipeline is linked

        try:
            if self.renderer not in ("projection", "gl"):
                raise TrafficcalError(f"renderer must be 'projection' or 'gl', got {self.renderer!r}")
            if self.box not in ("hull", "detector"):
                raise TrafficcalError(f"box must be 'hull' or 'detector', got {self.box!r}")
            self._classifier = None
            if self.classifier:
                from gst_trafficcal.scale.classifier import TypeClassifier
                self._classifier = TypeClassifier(self.classifier)
            self._stage = build_stage(self.models, self.min_vehicles, self.regression_file, self.iou_threshold,
                                      self.renderer)
        except TrafficcalError as exc:
            self.post_error(f"bbscale: {exc}")
            return False
        return True

    def do_stop(self):
        if self._stage is not None and getattr(self._stage.estimator.renderer, "release", None):
            self._stage.estimator.renderer.release()
        self._stage = None
        self._classifier = None
        return super().do_stop()

    def on_calibration(self, cal):
        if self._stage is None:
            return True
        ours = self._stage.on_calibration(cal)
        if ours is not None:  # same vanishing points again: keep our scale on what goes downstream
            self.publish_calibration(ours)
            return False
        return True

    def _report(self, ours):
        self.post_element_message("trafficcal-scale", self._stage.report())
        if ours is not None:
            self.publish_calibration(ours)
            self.keep_scale_view(ours, self.views_dir)

    def transform_frame(self, buffer):
        from gst_trafficcal.gst.meta import read_vehicle_rois
        from gst_trafficcal.scale.stage import sighting_from_fields, upstream_has_scale
        from gst_trafficcal.tracking.vehicle_meta import STRUCTURE as VEHICLE

        cal = self.calibration
        if upstream_has_scale(cal):
            return Gst.FlowReturn.OK
        t = self.buffer_t
        if t is None:
            self.warn_untimed("bbscale", "are ignored")
            return Gst.FlowReturn.OK
        every = read_vehicle_rois(buffer, self.frame_size, only=(VEHICLE,))
        rois = [r for r in every if r.object_id is not None and VEHICLE in r.params]
        self._check_tracked(t, len(every), len(rois))
        probs = [None] * len(rois)
        if self._classifier is not None and rois:
            with self.bgr(buffer) as bgr:
                probs = self._classifier(bgr, [r.box for r in rois])
        sightings = [sighting_from_fields(r.object_id, r.label, tuple(r.box), r.params["trafficcal-vehicle"], t, p,
                                          use_hull_box=self.box == "hull") for r, p in zip(rois, probs)]
        changed, ours = self._stage.update(t, sightings, cal)
        if changed:
            self._report(ours)
        return Gst.FlowReturn.OK

    def _check_tracked(self, t, n_rois, n_tracked):
        """Say once when vehicles keep coming untracked (no tracker before bbscale, or its data dropped on the way)."""
        from gst_trafficcal.gst.element import upstream_element

        if self._tracker_upstream is None:
            self._tracker_upstream = upstream_element(self, "tracker") is not None
        warning = self._untracked.check(t, n_rois, n_tracked, self._tracker_upstream)
        if warning:
            self.post_warning(warning)

    def on_eos(self):
        from gst_trafficcal.scale.stage import upstream_has_scale

        if self._stage is None or upstream_has_scale(self.calibration):
            return
        self._report(self._stage.finish(self.calibration))
        if not self._stage.result().converged and not self._untracked.said:  # else said why already
            self.post_warning(f"bbscale: no scale: {self._stage.result().status}")


GObject.type_register(BBScale)
__gstelementfactory__ = ("bbscale", Gst.Rank.NONE, BBScale)
