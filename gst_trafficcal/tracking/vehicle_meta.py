"""The ``"trafficcal-vehicle"`` ROI parameter structure written by the ``tracker`` element, as a plain dict.

Fields (all present unless noted):

* ``t`` (double): time of the frame in seconds (buffer PTS);
* ``state`` (string): ``confirmed`` (tentative tracks get no structure);
* ``direction`` (int): +1 moving towards VP1, −1 away from it, 0 not known yet;
* ``occluded`` / ``truncated`` (boolean): partly covered by a nearer vehicle / touching the image border or a
  static occluder the tracker learned (a lamp pole in front of the road) — the vehicle is tracked but not
  measured (no 3D box) — except ``cut_top``;
* ``cut_top`` (boolean): truncated by the image's top edge alone (a tall vehicle near the camera): ``box3d`` is
  present, without a reference point, and the vehicle's measurement uses it only if it is seen whole too seldom
  (``tracker.MIN_WHOLE_BOXES``);
* ``hull_box`` (4 doubles): x0, y0, x1, y1 of the convex hull that was tracked, pixels;
* ``has_3d`` (boolean): whether the following are present;
* ``box3d`` (8 pairs of doubles): image corners of the 3D box, index = ix + 2·iy + 4·iz with ix/iy the
  low/high end along the road (VP1) / across it (VP2) and iz bottom/top;
* ``ref_x``, ``ref_y`` (doubles): the reference point (centre of the bottom-front edge) in pixels;
* ``body_shape`` (string): the body the 3D box holds — ``box`` (Dubská's plain box) or a catalogue car body
  (``tracking.shapes``), chosen per track for clean silhouettes;
* ``proportions`` (string): what the plain boxes that chose it say the vehicle is (``box3d.proportions_class``:
  ``car``, ``long`` — a truck or a bus —, ``stretched`` — a car whose box came out long, which bbscale does not
  use —, ``other``; empty before any silhouette fit);
* ``road_x``, ``road_y`` (doubles): the reference point on the road plane, world frame in plane units (x along
  VP1, camera foot at 0; multiply by the scale λ for metres);
* ``world_x``, ``world_y`` (doubles, only when the scale is known): the same in metres;
* ``hull`` (K pairs of doubles) and ``silhouette`` (boolean), only before a calibration with vanishing points:
  the tracked convex hull and whether it is a segmentation's outline, so that bbscale can build the 3D box of
  vehicles seen before the calibration once it arrives;
* ``derolled_box`` (4 doubles) and ``roll`` (double, radians), only with a 3D box from a segmentation's outline
  (``silhouette``) under a camera whose horizon is tilted by at least ``scale.roll.MIN_TILT_DEG``: the hull's box in
  the image turned by −roll about the principal point, where the vehicle stands upright (bbscale aligns these:
  ``scale/roll.py``; measured with vehicleseg's outlines, so other hulls keep the detector's box);
* ``calibration_id`` (string): id of the calibration used ("" before there is one).
"""

from __future__ import annotations

from typing import Any

from ..geometry import Camera
from ..scale.roll import derolled_fields
from .tracker import Observation, Track, body_shape_name

STRUCTURE = "trafficcal-vehicle"


def vehicle_fields(track: Track, obs: Observation, camera: Camera | None, calibration_id: str = "") -> dict[str, Any]:
    """The structure's fields for one observation of a track."""
    fields: dict[str, Any] = {
        "t": float(obs.t), "state": track.state.value, "direction": int(track.direction),
        "occluded": bool(obs.occluded), "truncated": bool(obs.truncated), "cut_top": bool(obs.cut_top),
        "hull_box": [float(v) for v in obs.box], "calibration_id": str(calibration_id),
    }
    has_3d = camera is not None and obs.corners_px is not None and obs.ref_px is not None
    fields["has_3d"] = bool(has_3d)
    if camera is None and obs.hull is not None:  # no vanishing points yet: bbscale builds the 3D box later
        fields["hull"] = [[float(x), float(y)] for x, y in obs.hull]
        fields["silhouette"] = bool(obs.silhouette)
    if camera is not None and obs.corners_px is not None and (has_3d or obs.cut_top):
        fields["box3d"] = [[float(x), float(y)] for x, y in obs.corners_px]
    if has_3d:
        fields["ref_x"], fields["ref_y"] = (float(v) for v in obs.ref_px)
        fields["body_shape"] = body_shape_name(track)
        fields["proportions"] = track.proportions
        fields["road_x"], fields["road_y"] = (float(v) for v in obs.ref_road)
        if camera.scale is not None:
            fields["world_x"], fields["world_y"] = (float(v) * camera.scale for v in obs.ref_road)
        for key, value in derolled_fields(camera, obs.hull, obs.silhouette).items():
            fields[key] = list(value) if key == "derolled_box" else float(value)  # lists: the structure's text path
    return fields
