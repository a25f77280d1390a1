"""The scale stage of a stream: BBScale evidence from the tracked vehicles and the rule for publishing λ.

Shared by the ``bbscale`` element and ``speedometer``'s own scale stage (when no ``bbscale`` runs upstream), so
``vpdetect ! vehicledetect ! speedometer`` and ``... ! tracker ! bbscale ! speedometer`` publish the same
calibration at the same frame:

* an upstream calibration that already has a scale (a calibration file) is left alone;
* new vanishing points restart the evidence (:meth:`.streaming.ScaleEstimator.set_camera`); the same ones again
  keep it, and a scale found for them is put back on the calibration at once; a moved camera (``moved_at``) drops
  everything seen before — and when it moved to a view whose vanishing points this stage has given a scale before
  (vpdetect announces a known view again: a PTZ preset), that scale is put on at once, the evidence gathered anew;
* when the estimate converges the calibration is published with λ, and again whenever λ moves by more than
  ``republish`` (0.5 %); at the end of the stream the final estimate, however small the change.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable, Mapping

import numpy as np

from ..calibration import Calibration, latest_per_view, same_vanishing_points
from .estimate import DEFAULT_IOU_THRESHOLD
from .streaming import ScaleEstimator, ScaleResult, Sighting, base_centre, load_align_models

#: relative change of λ after which the calibration is published again
REPUBLISH = 0.005

#: the ``source`` suffix of calibrations whose scale this stage (or the bbscale element) found
SOURCE_SUFFIX = "bbscale"


def sighting_from_fields(object_id: int, label: str, box: tuple[float, float, float, float],
                         fields: Mapping[str, Any], t: float, probs: Mapping[str, float] | None = None,
                         use_hull_box: bool = False) -> Sighting:
    """The scale stage's view of one tracked vehicle from the tracker's ``"trafficcal-vehicle"`` ROI structure
    (:mod:`gst_trafficcal.tracking.vehicle_meta`); ``box`` is the ROI's (the detector's) rectangle, replaced by the
    tracked hull's box with ``use_hull_box``."""
    base = base_centre(fields["box3d"]) if fields.get("has_3d") and "box3d" in fields else None
    if use_hull_box:
        box = tuple(fields.get("hull_box", box))
    hull = fields.get("hull") if base is None else None  # before the vanishing points: the 3D box comes later
    return Sighting(int(object_id), float(fields.get("t", t)), tuple(float(v) for v in box), base,
                    float(fields.get("direction", 0)), str(label), bool(fields.get("occluded", False)),
                    bool(fields.get("truncated", False)), probs,
                    corners=fields["box3d"] if base is not None else None,
                    body_shape=str(fields.get("body_shape", "box")),
                    stretched=fields.get("proportions") == "stretched",
                    hull=None if hull is None else np.asarray(hull, np.float64).reshape(-1, 2),
                    silhouette=bool(fields.get("silhouette", False)),
                    derolled_box=tuple(fields["derolled_box"]) if base is not None and "derolled_box" in fields
                    else None, roll=float(fields.get("roll", 0.0)) if base is not None else 0.0)


def upstream_has_scale(cal: Calibration | None) -> bool:
    """Whether a calibration arriving from upstream already carries a scale of its own (not one of ours)."""
    return (cal is not None and cal.camera is not None and cal.camera.scale is not None
            and not cal.source.endswith(SOURCE_SUFFIX))


@dataclass
class ScaleStage:
    """:class:`ScaleEstimator` plus the publishing rule.  Each method returns the calibration to publish now
    (the upstream one with λ), or None."""

    estimator: ScaleEstimator
    republish: float = REPUBLISH

    def __post_init__(self) -> None:
        self.published: float | None = None
        self.known: list[Calibration] = []  # every calibration this stage gave a scale, the latest per view

    def on_calibration(self, cal: Calibration) -> Calibration | None:
        """An upstream calibration (with vanishing points): restart or keep the evidence.  Returns our scaled
        calibration when the same vanishing points come again after the scale was found."""
        if cal.moved_at is not None:  # another view from here: nothing seen so far measures it
            self.estimator.restart()
            self.published = None
            if cal.camera is None or upstream_has_scale(cal):
                return None
            self.estimator.set_camera(cal.camera)
            before = next((k for k in reversed(self.known) if same_vanishing_points(k, cal)), None)
            if before is None:
                return None
            self.published = float(before.camera.scale)  # a view seen before: its scale again, right away
            return self._ours(cal, self.published, {**cal.confidence, **before.confidence})
        if cal.camera is None or upstream_has_scale(cal):
            return None
        self.estimator.set_camera(cal.camera)
        r = self.estimator.result()
        if r.converged:
            return self._publish(cal, r, force=True)
        self.published = None  # new vanishing points: the next convergence is published whatever its value
        return None

    def update(self, t: float, sightings: Iterable[Sighting], cal: Calibration | None) -> tuple[bool, Calibration | None]:
        """One frame's sightings.  Returns (whether the estimate changed, the calibration to publish or None)."""
        if upstream_has_scale(cal):
            return False, None
        changed = self.estimator.update(t, sightings, cal.camera if cal is not None else None)
        return changed, (self._maybe(cal) if changed else None)

    def finish(self, cal: Calibration | None) -> Calibration | None:
        """End of stream: align what is still open; the final estimate is published if it differs at all."""
        if upstream_has_scale(cal):
            return None
        self.estimator.finish()
        r = self.estimator.result()
        if r.converged and r.scale != self.published and cal is not None and cal.camera is not None:
            return self._publish(cal, r, force=True)
        return None

    def result(self) -> ScaleResult:
        return self.estimator.result()

    def report(self) -> dict[str, Any]:
        """The fields of the ``trafficcal-scale`` bus message: status, counts, λ* and λ when known."""
        r = self.estimator.result()
        fields: dict[str, Any] = {
            "status": r.status, "converged": bool(r.converged), "confidence": float(r.confidence),
            "vehicles": int(r.n_vehicles), "matched": int(r.n_matched), "agreeing": int(r.n_agreeing),
            "matches": int(r.n_matches), "types": ",".join(f"{k}:{v}" for k, v in sorted(r.types.items()))}
        if r.raw_scale is not None:
            fields["raw_scale"] = float(r.raw_scale)
        if r.scale is not None:
            fields["scale"] = float(r.scale)
        return fields

    def _maybe(self, cal: Calibration | None) -> Calibration | None:
        r = self.estimator.result()
        if r.converged and cal is not None and cal.camera is not None:
            return self._publish(cal, r)
        return None

    def _publish(self, cal: Calibration, r: ScaleResult, force: bool = False) -> Calibration | None:
        if self.published is not None and not force and abs(r.scale / self.published - 1) <= self.republish:
            return None
        self.published = float(r.scale)
        return self._ours(cal, float(r.scale), {**cal.confidence, "scale": float(r.confidence)})

    def _ours(self, cal: Calibration, scale: float, confidence: dict[str, float]) -> Calibration:
        """``cal`` with the scale this stage gives it (remembered for its view)."""
        source = cal.source if cal.source.endswith(SOURCE_SUFFIX) else f"{cal.source}+{SOURCE_SUFFIX}"
        ours = cal.with_scale(scale, confidence=confidence, source=source)
        self.known = latest_per_view(self.known, ours)
        return ours


def build_stage(models: str = "", min_vehicles: int = 5, regression_file: str = "",
                iou_threshold: float = DEFAULT_IOU_THRESHOLD, renderer: str = "projection") -> ScaleStage:
    """The stage from element settings (bbscale's, and speedometer's scale-* properties): ``models`` as bbscale's
    property (empty: every catalogue passenger-car type), a regression JSON path (empty: none), ``renderer``
    projection or gl (the OpenGL context is made last, once everything else has loaded).  Unknown types, a broken
    mesh or an unreadable regression file raise the library's one-line errors naming them."""
    from .regression import load_regression

    regression = load_regression(regression_file) if regression_file else None
    align_models = load_align_models(models)
    gl = None
    if renderer == "gl":
        from .silhouette import SilhouetteRenderer

        gl = SilhouetteRenderer()
    return ScaleStage(ScaleEstimator(align_models, iou_threshold=iou_threshold, min_vehicles=min_vehicles,
                                     regression=regression, renderer=gl))
