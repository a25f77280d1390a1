"""GStreamer element ``vehicledetect``: finds vehicles and attaches them as ROI metadata.

Each vehicle becomes a ``GstVideoRegionOfInterestMeta`` (roi_type = label, e.g. "car") with DL
Streamer's ``"detection"`` structure (normalised box, confidence, label_id, label). With ``model``
empty, the built-in background-subtraction detector (no weights) finds moving vehicles; otherwise
``model`` names an ONNX detector file (a path, or a model installed with ``trafficcal models
install``) whose output layout is recognised or given by ``model-format``; ``model=vehicleseg`` is the project's
learned vehicle segmenter (shipped), whose ROIs also carry each vehicle's convex hull (``"trafficcal-hull"``),
which the tracker then uses for its 3D boxes. A bad model file stops
the pipeline at start-up with an error naming it. With ``interval`` N > 1 only every N-th frame is
analysed; the frames in between carry no vehicle metadata (stale boxes of moving vehicles would
mislead the tracker, which predicts across the gap itself). When vpdetect says the camera moved (a calibration
with ``moved_at``) a detector with a background of its own (the built-in one, vehicleseg) learns it again.
"""

from gst_trafficcal.gst._gi import GObject, Gst
from gst_trafficcal.gst.element import LIVE, READY_ONLY, TrafficcalTransform

_RW = READY_ONLY  # read at start (gst-inspect-1.0: changeable only in NULL or READY state)


class VehicleDetect(TrafficcalTransform):
    __gtype_name__ = "GstVehicledetect"  # instances vehicledetect0, ...
    __gstmetadata__ = ("vehicledetect", "Filter/Analyzer/Video",
                       "Detects vehicles (ONNX detector or background subtraction) and attaches ROI metas with "
                       "DL Streamer 'detection' params", "gst-trafficcal")
    __gproperties__ = {
        "model": (str, "Model", "ONNX detector file or installed model name; vehicleseg = the shipped learned "
                  "vehicle segmenter (boxes + convex hulls, keeps its own background); empty = built-in background-"
                  "subtraction detector (moving vehicles, no weights)", "", _RW),
        "model-format": (str, "Model format", "Output layout of the model: auto (recognised from the output "
                         "shapes or metadata), fastestdet, nanodet, yolox, yolov5, yolov8, ssd or vehicleseg", "auto",
                         _RW),
        "labels": (str, "Labels", "Class ids kept and their vehicle labels, e.g. '2:car,3:motorcycle,5:bus,7:truck' "
                   "(COCO, the default when empty); a list of names such as 'car,truck' keeps those COCO "
                   "vehicles", "", _RW),
        "threshold": (float, "Threshold", "Minimum detection confidence of the ONNX model (the background "
                      "detector keeps every blob large enough)", 0.0, 1.0, 0.4, _RW),
        "interval": (int, "Interval", "Detect on every N-th frame; frames in between carry no vehicle metadata",
                     1, 1000, 1, LIVE),
        "tiles": (str, "Tiles", "Run the ONNX model on COLUMNSxROWS overlapping tiles of the frame (e.g. 3x2): finds "
                  "distant vehicles in full-HD frames at one inference per tile", "1x1", _RW),
        "background": (str, "Background method", "Model of the built-in detector (no model given): mog2 (default) or "
                       "average (moving average with shadow peeling: boxes without the cast shadow)", "mog2", _RW),
        "threads": (int, "Threads", "onnxruntime intra-op threads (0 = onnxruntime's default)", 0, 64, 1, _RW),
        "zone": (str, "Zone", "Where vehicles are looked for: polygons 'x,y x,y x,y ...' separated by ';', in pixels "
                 "or fractions 0..1 of the frame; a vehicle whose box's bottom centre lies outside is dropped (empty: "
                 "the whole frame)", "", _RW),
    }

    def __init__(self):
        super().__init__()
        self._detector = None
        self._zone = None
        self._said_upstream = False  # the warning that the frames came with detections already: once
        self._frame = 0

    def do_start(self):
        from gst_trafficcal.detection.factory import create_detector, ignored_options
        from gst_trafficcal.errors import TrafficcalError
        from gst_trafficcal.zone import parse_zone

        self._said_upstream = False
        try:
            self._detector = create_detector(self.model, self.model_format, self.labels, self.threshold, self.threads,
                                             self.tiles, background=self.background)
            ignored = ignored_options(self._detector, self.model_format, self.labels, self.threshold, self.tiles,
                                      self.background)
            self._zone = parse_zone(self.zone)
        except TrafficcalError as exc:
            self.post_error(f"vehicledetect: {exc}", code=Gst.CoreError.FAILED)
            return False
        missing = getattr(self._detector, "missing_labels", None)
        if missing:  # some of the classes asked for are not the model's: those are never found
            self.post_warning(f"vehicledetect: model {self.model} has {self._detector.decoder.num_classes} classes; "
                              f"labels' class id(s) {', '.join(map(str, missing))} are not among them and are never "
                              "found")
        if ignored:
            which = "the built-in background detector" if not self.model else f"model {self.model}"
            self.post_warning(f"vehicledetect: {', '.join(ignored)} {'is' if len(ignored) == 1 else 'are'} not used "
                              f"by {which}; ignored")
        self._frame = 0
        return True

    def on_caps(self, info):
        if self._zone is not None:
            self.zone_fits(self._zone, tuple(self.frame_size), "vehicledetect")

    def on_calibration(self, cal):
        reset = getattr(self._detector, "reset", None)  # detectors with a background of their own
        if cal.moved_at is not None and reset is not None:  # the camera moved: that background is another view's
            reset()
        return True

    def do_stop(self):
        self._detector = None
        return super().do_stop()

    def transform_frame(self, buffer):
        from gst_trafficcal.detection.factory import detect, reduced_size
        from gst_trafficcal.gst.meta import add_vehicle_roi, has_rois, hull_params

        frame, self._frame = self._frame, self._frame + 1
        if frame % self.interval:
            return Gst.FlowReturn.OK
        # a detector that starts by reducing the frame (vehicleseg) gets it reduced from the YUV planes
        size = reduced_size(self._detector, self.frame_size) if self.model else None
        with (self.bgr(buffer, size) if self.model else self.gray(buffer)) as image:
            detections = detect(self._detector, image, self.buffer_t, self.frame_size if size else None)
        if self._zone is not None:
            detections = self._zone.keep(detections, self.frame_size)
        if not self._said_upstream and has_rois(buffer):  # two detectors: each vehicle would be tracked twice
            self._said_upstream = True
            self.post_warning("vehicledetect: the frames already carry detections (another detector upstream?); "
                              "this one's are added to them, and a vehicle both find may be counted twice")
        for d in detections:
            add_vehicle_roi(buffer, self.frame_size, d.box, d.label, d.score, d.class_id, params=hull_params(d.hull))
        return Gst.FlowReturn.OK


GObject.type_register(VehicleDetect)
__gstelementfactory__ = ("vehicledetect", Gst.Rank.NONE, VehicleDetect)
