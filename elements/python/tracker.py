"""GStreamer element ``tracker``: Kalman tracking of the vehicles found by ``vehicledetect`` (paper §4.2).

Reads the vehicle ROI metas of each frame, groups the foreground blobs of a moving-average background model by
them, and tracks the convex hulls.  Each ROI of a confirmed track gets an ``"object_id"`` {id} structure (as DL
Streamer's gvatrack) and a ``"trafficcal-vehicle"`` structure; with a calibration (the sticky
"trafficcal-calibration" event from ``vpdetect``) the latter carries the 3D box and the road-plane reference
point.  Without one it tracks in 2D, and switches to 3D when the calibration arrives without losing tracks.  When vpdetect
says the camera moved (a calibration with ``moved_at``) every track ends and tracking starts again in 2D; at a jump
in the stream (a flushing seek, recordings joined by ``concat``) every track ends too, none continues across it.
Time comes from buffer PTS.  A bus message ``trafficcal-track`` is posted when a track ends.
"""

from gst_trafficcal.gst._gi import GObject, Gst
from gst_trafficcal.gst.element import READY_ONLY, TrafficcalTransform

_RW = READY_ONLY  # read at start (gst-inspect-1.0: changeable only in NULL or READY state)


class Tracker(TrafficcalTransform):
    __gtype_name__ = "GstTracker"  # instances tracker0, ...
    __gstmetadata__ = ("tracker", "Filter/Analyzer/Video",
                       "Tracks vehicle ROIs with a Kalman filter over convex hulls of foreground blobs; adds "
                       "object_id and a trafficcal-vehicle structure (3D box, road-plane reference point)",
                       "gst-trafficcal")
    __gproperties__ = {
        "min-hits": (int, "Minimum hits", "Detections needed before a track is confirmed and gets an object_id "
                     "(frames more than 0.08 s apart: as many as cover this many 25 fps frames' time, at least 2)",
                     1, 1000, 3, _RW),
        "max-lost": (float, "Maximum lost time", "Seconds a confirmed track survives without a detection",
                     0.0, 60.0, 1.5, _RW),
        "iou-threshold": (float, "IoU threshold", "Minimum IoU between a track's prediction and a detection to "
                          "associate them (a centre-distance fallback also applies)", 0.0, 1.0, 0.2, _RW),
        "drop-occluded": (bool, "Drop occluded", "Do not measure detections partly covered by a nearer one (the "
                          "paper's heuristic; their tracks keep their ids)", True, _RW),
        "background": (bool, "Background model", "Use a moving-average background model to take the vehicle's "
                       "convex hull inside each box (off: the box itself is the hull, coarser 3D boxes)", True, _RW),
        "background-width": (int, "Background width", "Width in pixels at which the background model runs",
                             16, 8192, 480, _RW),
        "colour": (bool, "Colour", "Use the frame's colour (U and V planes; BGR/RGB are converted) in the background "
                   "model: colour changes count as foreground and cast shadows must keep the road's colour. Closer "
                   "reference points on synthetic cuboids, but less consistent along a track (speeds worse with the "
                   "background detector), so off by default (GRAY8 input always uses brightness)",
                   False, _RW),
        "peel": (bool, "Peel", "Take the hulls from the background detector's foreground (moving average, cast shadows "
                 "peeled off each blob's outline: keeps grey vehicle faces) instead of the per-pixel shadow test; "
                 "ignores colour", False, _RW),
        "body-shapes": (str, "Body shapes", "3D boxes: auto = a catalogue car body fitted to clean silhouettes (hulls "
                        "that come with the ROIs, e.g. vehicledetect model=vehicleseg) and the plain box for the "
                        "background model's hulls (their cast shadow misleads a body fit); cars = body shapes "
                        "always; box = Dubska's plain box always", "auto", _RW),
        "blob-detection": (bool, "Blob detection", "When a frame carries no vehicle ROI, use the foreground blobs "
                           "as vehicles and add ROIs for them (detector-free mode)", False, _RW),
        "min-blob-area": (float, "Minimum blob area", "Smallest blob (pixels) taken as a vehicle in blob-detection "
                          "mode", 1.0, 1e7, 400.0, _RW),
    }

    def __init__(self):
        super().__init__()
        self._pipe = None

    def do_start(self):
        from gst_trafficcal.tracking.background import BackgroundModel
        from gst_trafficcal.tracking.pipeline import TrackingPipeline
        from gst_trafficcal.tracking.tracker import TrackerConfig

        try:
            if self.body_shapes not in ("auto", "cars", "box"):
                raise ValueError(f"body-shapes must be auto, cars or box, got {self.body_shapes!r}")
            config = TrackerConfig(n_init=self.min_hits, max_lost=self.max_lost, iou_gate=self.iou_threshold,
                                   drop_occluded=self.drop_occluded, body_shapes=self.body_shapes)
            if not self.background:
                background = None
            elif self.peel:
                from gst_trafficcal.tracking.peeled import PeeledBackground

                background = PeeledBackground(work_width=self.background_width)
            else:
                background = BackgroundModel(work_width=self.background_width)
        except Exception as exc:  # bad property values: a readable error at start-up
            self.post_error(f"tracker: {exc}")
            return False
        self._pipe = TrackingPipeline(config=config, background=background, min_blob_area=self.min_blob_area)
        return True

    def on_calibration(self, cal):
        if cal.moved_at is not None and self._pipe is not None:  # the camera moved: no track goes on across it
            for track in self._pipe.camera_moved():
                self._post_track(track)
        return True

    def on_jump(self, t):
        """A seek (or parts joined): the vehicles after it are seen at another moment; no track goes on across it."""
        if self._pipe is not None:
            for track in self._pipe.flush():
                self._post_track(track)

    def do_sink_event(self, event):
        if event.type == Gst.EventType.EOS and self._pipe is not None:  # report the tracks still open
            for track in self._pipe.flush():
                self._post_track(track)
        return super().do_sink_event(event)

    def do_stop(self):
        if self._pipe is not None:
            for track in self._pipe.flush():
                self._post_track(track)
        self._pipe = None
        return super().do_stop()

    def transform_frame(self, buffer):
        from gst_trafficcal.detection.records import Detections
        from gst_trafficcal.gst.meta import (OBJECT_ID, add_vehicle_roi, detections_from_rois, read_vehicle_rois,
                                             update_roi_params)
        from gst_trafficcal.tracking.vehicle_meta import vehicle_fields

        t = self.buffer_t
        if t is None:
            self.warn_untimed("tracker", "are passed through untracked")
            return Gst.FlowReturn.OK
        rois = read_vehicle_rois(buffer, self.frame_size)
        if rois:
            detections = detections_from_rois(rois)
        elif self.blob_detection:
            detections = None
        else:
            detections = Detections.empty()
        cal = self.calibration
        camera = cal.camera if cal is not None else None
        if camera is not self._pipe.camera:
            self._pipe.set_camera(camera)
        with self.gray_and_chroma(buffer, self.colour and self._pipe.background is not None) as (gray, chroma):
            result, detections = self._pipe.process(gray, t, detections, chroma=chroma)
        if not rois and len(detections):  # blob-detection mode: the blobs become the frame's ROIs
            meta_ids = [add_vehicle_roi(buffer, self.frame_size, b, str(lab), float(s), int(c))
                        for b, lab, s, c in zip(detections.boxes, detections.labels, detections.scores,
                                                detections.class_ids)]
        else:
            meta_ids = [r.index for r in rois]
        for i in range(len(detections)):
            track = result.track_of(i)
            if track is None:
                continue
            update_roi_params(buffer, meta_ids[i], OBJECT_ID, {"id": int(track.id)})
            update_roi_params(buffer, meta_ids[i], "trafficcal-vehicle",
                              vehicle_fields(track, track.last, camera, cal.id if cal is not None else ""))
        for track in self._pipe.pop_finished():
            self._post_track(track)
        return Gst.FlowReturn.OK

    def _post_track(self, track):
        ts = track.timestamps
        self.post_element_message("trafficcal-track", {
            "id": int(track.id), "label": track.label, "first": float(ts[0]), "last": float(ts[-1]),
            "observations": int(len(ts)), "direction": int(track.direction)})


GObject.type_register(Tracker)
__gstelementfactory__ = ("tracker", Gst.Rank.NONE, Tracker)
