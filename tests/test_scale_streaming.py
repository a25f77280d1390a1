"""The streaming scale stage (ScaleEstimator) on exact synthetic geometry, statuses, and the ONNX classifier."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gst_trafficcal.errors import InputError
from gst_trafficcal.geometry import Camera
from gst_trafficcal.scale.alignment import projected_boxes
from gst_trafficcal.scale.regression import ScaleRegression
from gst_trafficcal.scale.streaming import ScaleEstimator, Sighting, base_centre, load_align_models

TRUE_SCALE = 7.0
NAMES = ("skoda_octavia_mk1_liftback", "skoda_octavia_mk1_combi", "skoda_fabia_mk1_hatchback")


@pytest.fixture(scope="module")
def models():
    return load_align_models(",".join(NAMES))


@pytest.fixture(scope="module")
def cam() -> Camera:
    from gst_trafficcal.synth.camera import build_camera
    from gst_trafficcal.synth.scenario import CameraSpec

    spec = CameraSpec(height=TRUE_SCALE, offset=-6.0, pan=18.0, tilt=14.0, roll=2.0, hfov=60.0, resolution=[1280, 720])
    return build_camera(spec).calibration_camera()


def vehicle_sightings(cam: Camera, models, rng, n_vehicles: int, t0: float = 0.0) -> list[list[Sighting]]:
    """Per frame: vehicles of catalogue types driving towards the camera, detected box = the model's exact
    projected box ± 0.5 px, base = the true base centre (pixels)."""
    frames: dict[int, list[Sighting]] = {}
    names = list(models)
    for k in range(n_vehicles):
        m = models[names[k % len(names)]]
        y = rng.uniform(-1.5, 4.0)  # metres across the road in the calibration's world frame
        start = k * 6  # frames
        for j in range(8):
            x = 45.0 - 3.0 * j  # metres along the road, approaching (moving towards -x)
            base = cam.world_to_image(np.array([x, y, 0.0]))
            box = projected_boxes(cam, m.hull, base, -1.0, np.array([TRUE_SCALE]))[0]
            box = box + rng.uniform(-0.5, 0.5, 4)
            f = start + j
            frames.setdefault(f, []).append(Sighting(k + 1, t0 + f * 0.1, tuple(box), tuple(base), -1.0, "car"))
    n = max(frames) + 1
    return [frames.get(f, []) for f in range(n)]


def run(est: ScaleEstimator, frames, t0: float = 0.0) -> None:
    for f, ss in enumerate(frames):
        est.update(t0 + f * 0.1, ss)
    est.finish()


def test_scale_converges_to_the_true_scale(cam, models):
    est = ScaleEstimator(models, min_vehicles=4, refine_base=False)
    est.set_camera(cam)
    assert est.result().status.startswith("no fully visible vehicle")
    run(est, vehicle_sightings(cam, models, np.random.default_rng(0), 6))
    r = est.result()
    assert r.converged and r.status == "converged", r
    # measured: 0.1-0.3 % with the true base point and boxes within half a pixel
    assert r.scale == pytest.approx(TRUE_SCALE, rel=0.01)
    assert r.n_matched == 6 and r.n_agreeing >= 4 and 0.5 < r.confidence <= 1.0
    assert set(r.types) <= set(NAMES)


def test_too_few_vehicles_says_so_then_converges(cam, models):
    est = ScaleEstimator(models, min_vehicles=4, refine_base=False)
    est.set_camera(cam)
    frames = vehicle_sightings(cam, models, np.random.default_rng(1), 6)
    for f, ss in enumerate(frames[:12]):  # the first two vehicles only, then a long pause ends their tracks
        est.update(f * 0.1, ss)
    est.update(5.0, [])
    r = est.result()
    assert not r.converged and r.scale is None and r.status.startswith("too few matches"), r
    assert r.raw_scale == pytest.approx(TRUE_SCALE, rel=0.02) and r.confidence < 1.0


def test_regression_is_applied(cam, models):
    est = ScaleEstimator(models, min_vehicles=2, regression=ScaleRegression(2.0, 1.0), refine_base=False)
    est.set_camera(cam)
    run(est, vehicle_sightings(cam, models, np.random.default_rng(2), 3))
    r = est.result()
    assert r.converged and r.scale == pytest.approx(2.0 * r.raw_scale + 1.0)


def test_occluded_truncated_and_unknown_vehicles_give_no_scale(cam, models):
    est = ScaleEstimator(models, min_vehicles=1, refine_base=False)
    est.update(0.0, [Sighting(1, 0.0, (10, 10, 100, 80), (50, 80), 1.0)])
    assert est.result().status.startswith("waiting for the vanishing points")
    est.set_camera(cam)
    frames = vehicle_sightings(cam, models, np.random.default_rng(3), 2)
    from dataclasses import replace

    hidden = [[replace(s, occluded=True) if s.track_id == 1 else replace(s, truncated=True) for s in ss]
              for ss in frames]
    run(est, hidden)
    assert est.result().status.startswith("no fully visible vehicle")
    # a box far too wide for any catalogue car at its place: no match above the threshold
    wide = [[replace(s, box=(s.box[0] - 3 * (s.box[2] - s.box[0]), s.box[1], s.box[2], s.box[3])) for s in ss]
            for ss in frames]
    run(est, wide)
    r = est.result()
    assert r.scale is None and r.status.startswith("no vehicle of a known type"), r


def test_degenerate_viewpoint_status(cam, models):
    est = ScaleEstimator(models, min_vehicles=1, refine_base=False, min_box=1.0)
    est.set_camera(cam)
    above = float(cam.horizon @ [640, 0, 1])  # a base point far above the horizon
    y = 0.0 if above * float(cam.horizon @ [640, 700, 1]) < 0 else -2000.0
    for f in range(3):
        est.update(f * 0.1, [Sighting(1, f * 0.1, (600, y - 30, 680, y), (640, y), 1.0)])
    est.finish()
    assert est.result().status.startswith("degenerate viewpoint"), est.result()


def test_vanishing_point_change_drops_evidence(cam, models):
    est = ScaleEstimator(models, min_vehicles=2, refine_base=False)
    est.set_camera(cam)
    run(est, vehicle_sightings(cam, models, np.random.default_rng(4), 3))
    assert est.result().converged
    est.set_camera(cam.with_scale(3.0))  # same VPs: kept
    assert est.result().converged
    est.set_camera(Camera(cam.vp1 + [5.0, 0.0], cam.vp2, cam.pp))
    assert not est.result().converged


def test_a_moved_camera_drops_every_piece_of_evidence(cam, models):
    """After a move, even the same vanishing points start from nothing: what was seen is another view's."""
    from gst_trafficcal.calibration import Calibration
    from gst_trafficcal.scale.stage import ScaleStage

    stage = ScaleStage(ScaleEstimator(models, min_vehicles=2, refine_base=False))
    cal = Calibration(cam.with_scale(None), (1280, 720), state="vps", source="vpdetect")
    stage.on_calibration(cal)
    for f, ss in enumerate(vehicle_sightings(cam, models, np.random.default_rng(4), 3)):
        stage.update(f * 0.1, ss, cal)
    stage.finish(cal)
    assert stage.result().converged
    assert stage.on_calibration(cal) is not None  # the same VPs again: the scale is put back at once
    moved = Calibration(None, (1280, 720), state="learning", source="vpdetect", moved_at=3.0)
    assert stage.on_calibration(moved) is None and stage.estimator.camera is None
    assert stage.on_calibration(cal) is None and not stage.result().converged
    assert stage.result().n_vehicles == 0


def test_a_camera_back_at_a_view_it_had_gets_that_scale_at_once(cam, models):
    """vpdetect announces a known view again after a move (a PTZ preset): the scale found for those vanishing
    points is put on right away, with the move, while the evidence is gathered anew; a view never scaled gets
    none; a calibration that brings its own scale is left alone."""
    from dataclasses import replace

    from gst_trafficcal.calibration import Calibration
    from gst_trafficcal.scale.stage import ScaleStage

    stage = ScaleStage(ScaleEstimator(models, min_vehicles=2, refine_base=False))
    cal = Calibration(cam.with_scale(None), (1280, 720), state="vps", source="vpdetect")
    stage.on_calibration(cal)
    for f, ss in enumerate(vehicle_sightings(cam, models, np.random.default_rng(4), 3)):
        stage.update(f * 0.1, ss, cal)
    ours = stage.finish(cal)
    assert ours is not None and ours.camera.scale == stage.result().scale
    other = Calibration(Camera(cam.vp1 + [40.0, 0.0], cam.vp2, cam.pp), (1280, 720), state="vps", source="vpdetect")
    assert stage.on_calibration(replace(other, moved_at=5.0)) is None  # another view, never scaled
    back = stage.on_calibration(replace(cal, moved_at=9.0))
    assert back is not None and back.moved_at == 9.0 and back.camera.scale == ours.camera.scale
    assert back.source == "vpdetect+bbscale" and back.id == ours.id
    assert stage.result().n_vehicles == 0 and stage.estimator.camera is not None  # evidence anew, on these VPs
    given = Calibration(cam.with_scale(7.0), (1280, 720), source="file", moved_at=12.0)
    assert stage.on_calibration(given) is None


def test_base_centre_is_the_projective_centre(cam):
    X = np.array([[x, y, 0.0] for y in (0.0, 1.8) for x in (10.0, 14.5)])  # order ix + 2 iy
    corners = np.vstack([cam.world_to_image(X), cam.world_to_image(X + [0, 0, 1.5])])
    b = base_centre(corners)
    assert np.allclose(b, cam.world_to_image(np.array([12.25, 0.9, 0.0])), atol=1e-6)


def test_bad_model_names_and_parameters(models):
    with pytest.raises(InputError, match="unknown vehicle type 'no_such_car'"):
        load_align_models("skoda_octavia_mk1_combi,no_such_car")
    with pytest.raises(InputError, match="not found"):
        load_align_models("/nonexistent/catalogue.yaml")
    with pytest.raises(InputError, match="iou-threshold"):
        ScaleEstimator(models, iou_threshold=1.5)
    with pytest.raises(InputError, match="min-vehicles"):
        ScaleEstimator(models, min_vehicles=0)
    with pytest.raises(InputError, match="sighting selection must be one of largest, spread"):
        ScaleEstimator(models, select="smallest")
    with pytest.raises(InputError, match="type margin"):
        ScaleEstimator(models, type_margin=-0.01)


def test_sightings_chosen_largest_or_spread_over_the_size_range(models):
    """A track approaching the camera: its box grows frame by frame.  "largest" aligns the nearest sightings,
    "spread" sightings from the whole range of sizes (the largest, the smallest and between), each at least
    min_gap apart."""
    track = [Sighting(1, 0.25 * k, (0, 0, 40 + 4 * k, 30 + 3 * k), (20, 30), 1.0) for k in range(40)]
    largest = ScaleEstimator(models, per_track=4)._choose(track)
    spread = ScaleEstimator(models, per_track=4, select="spread")._choose(track)
    assert [s.t for s in largest] == pytest.approx([9.75, 9.5, 9.25, 9.0])
    assert sorted(s.t for s in spread) == pytest.approx([0.0, 3.25, 6.5, 9.75])
    # picks closer than min_gap give way to other sightings, largest first
    tight = ScaleEstimator(models, per_track=4, select="spread", min_gap=3.5)._choose(track)
    times = sorted(s.t for s in tight)
    assert 9.75 in times and len(times) <= 4 and min(np.diff(times)) >= 3.5


# ---------------------------------------------------------------------------------------------- classifier
def tiny_classifier(path, names, fixed_batch=False):
    """An ONNX graph: mean colour of the crop (GlobalAveragePool) -> 3 x C matrix -> softmax.  A red crop is
    class 0, a green one class 1, a blue one class 2."""
    import onnx
    from onnx import TensorProto, helper

    W = np.zeros((3, len(names)), np.float32)
    for c in range(min(3, len(names))):
        W[c, c] = 20.0
    batch = 1 if fixed_batch else "N"
    graph = helper.make_graph(
        [helper.make_node("GlobalAveragePool", ["x"], ["g"]), helper.make_node("Flatten", ["g"], ["f"]),
         helper.make_node("MatMul", ["f", "W"], ["z"]), helper.make_node("Softmax", ["z"], ["p"], axis=1)],
        "tiny", [helper.make_tensor_value_info("x", TensorProto.FLOAT, [batch, 3, 16, 16])],
        [helper.make_tensor_value_info("p", TensorProto.FLOAT, [batch, len(names)])],
        [helper.make_tensor("W", TensorProto.FLOAT, W.shape, W.ravel())])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    helper.set_model_props(model, {"labels": ",".join(names)})
    onnx.save(model, str(path))
    return path


@pytest.mark.parametrize("fixed_batch", [False, True])
def test_classifier_probabilities_from_an_onnx_graph(tmp_path, fixed_batch):
    pytest.importorskip("onnx")
    from gst_trafficcal.scale.classifier import TypeClassifier

    names = ["skoda_octavia_mk1_liftback", "skoda_octavia_mk1_combi", "other"]
    clf = TypeClassifier(tiny_classifier(tmp_path / "c.onnx", names, fixed_batch))
    img = np.zeros((100, 200, 3), np.uint8)
    img[:, :100] = (0, 0, 255)  # red (BGR) on the left, green on the right
    img[:, 100:] = (0, 255, 0)
    p = clf(img, [(10, 10, 60, 60), (120, 20, 190, 90)])
    assert max(p[0], key=p[0].get) == names[0] and p[0][names[0]] > 0.99
    assert max(p[1], key=p[1].get) == names[1] and p[1][names[1]] > 0.99
    assert sum(p[0].values()) == pytest.approx(1.0, abs=1e-5)


def test_types_that_fit_about_as_well_as_the_best_pool_their_matches(cam, models):
    """Without a classifier the best-fitting type names the track; the matches of every shortlisted type whose mean
    peak IoU is within ``type_margin`` of it enter the track's λ too (a car of unknown make fits several similar
    types about equally; taking one alone jumps between their lengths)."""
    frames = vehicle_sightings(cam, models, np.random.default_rng(2), 6)
    matches = {}
    for margin in (0.0, 1.0):
        est = ScaleEstimator(models, min_vehicles=4, refine_base=False, type_margin=margin)
        est.set_camera(cam)
        run(est, frames)
        assert est.result().converged
        matches[margin] = {m.track_id: m for m in est._matches}
    assert matches[0.0].keys() == matches[1.0].keys()
    for tid, alone in matches[0.0].items():
        pooled = matches[1.0][tid]
        assert pooled.model == alone.model  # the track's type is still the best-fitting one
        assert len(pooled.lambdas) >= len(alone.lambdas)
    # the three types are all shortlisted and all fit above the IoU threshold: every track pools more matches
    assert all(len(matches[1.0][t].lambdas) > len(m.lambdas) for t, m in matches[0.0].items())
    est = ScaleEstimator(models, min_vehicles=4, refine_base=False)  # the default margin keeps exact geometry exact
    est.set_camera(cam)
    run(est, frames)
    assert est.result().raw_scale == pytest.approx(TRUE_SCALE, rel=0.01)


def test_only_the_latest_matches_are_kept_whole_and_the_scale_uses_them_all(cam, models, monkeypatch):
    """A stream of weeks keeps a bounded number of matches whole (KEPT_MATCHES); λ*, the agreement and the counts
    come from every vehicle matched."""
    from gst_trafficcal.scale import streaming

    frames = vehicle_sightings(cam, models, np.random.default_rng(2), 6)
    results = {}
    for kept in (1000, 2):
        monkeypatch.setattr(streaming, "KEPT_MATCHES", kept)
        est = ScaleEstimator(models, min_vehicles=4, refine_base=False)
        est.set_camera(cam)
        run(est, frames)
        results[kept] = (est.result(), [m.track_id for m in est._matches])
    (everything, ids), (latest, last_two) = results[1000], results[2]
    assert len(ids) == 6 and last_two == ids[-2:]
    assert latest == everything and latest.n_matched == 6 and latest.converged


def test_classifier_probabilities_steer_the_types(cam, models):
    """Track-mean probabilities: only the named type is aligned, and its matches carry the weight."""
    est = ScaleEstimator(models, min_vehicles=2, refine_base=False)
    est.set_camera(cam)
    frames = vehicle_sightings(cam, models, np.random.default_rng(5), 3)
    from dataclasses import replace

    names = list(models)
    probs = [[replace(s, type_probs={names[(s.track_id - 1) % 3]: 0.9, "other": 0.1}) for s in ss] for ss in frames]
    run(est, probs)
    r = est.result()
    assert r.converged and r.scale == pytest.approx(TRUE_SCALE, rel=0.01)
    assert r.types == {n: 1 for n in names}


def test_bad_classifier_files(tmp_path):
    from gst_trafficcal.scale.classifier import TypeClassifier

    with pytest.raises(InputError, match="not found"):
        TypeClassifier(tmp_path / "missing.onnx")
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not a model")
    with pytest.raises(InputError, match="cannot be loaded"):
        TypeClassifier(bad)


def test_a_vehicle_that_stays_keeps_bounded_memory(cam, models):
    est = ScaleEstimator(models, min_vehicles=1, refine_base=False)
    est.set_camera(cam)
    (s,) = [ss for ss in vehicle_sightings(cam, models, np.random.default_rng(6), 1) if ss][0]
    from dataclasses import replace

    for f in range(1000):
        est.update(f * 0.1, [replace(s, t=f * 0.1)])
    assert len(est._tracks[s.track_id].sightings) <= 129
    est.finish()
    assert est.result().converged


def test_a_broken_mesh_in_the_models_catalogue_is_an_error_naming_it(tmp_path):
    """bbscale's ``models`` = a user catalogue whose mesh file is broken: the stage refuses to start with an
    InputError naming the file (not a trimesh traceback, not a silent procedural stand-in)."""
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "my_car.glb").write_bytes(b"glTF\x02\x00\x00\x00garbage" * 3)
    cat = tmp_path / "cat.yaml"
    cat.write_text("models:\n  my_car:\n    body_style: hatchback\n    length: 4.0\n    width: 1.7\n"
                   "    height: 1.45\n    wheelbase: 2.5\n    mesh: meshes/my_car.glb\n"
                   "    sources: {length: brochure}\n")
    with pytest.raises(InputError, match="my_car.glb"):
        load_align_models(str(cat))


def test_length_to_width_of_a_3d_box(cam):
    from gst_trafficcal.scale.streaming import length_to_width
    from gst_trafficcal.tracking.box3d import CORNER_BITS

    # a 4.5 x 1.8 x 1.5 m box on the road, 30 m ahead: the ratio on the road plane is scale-free
    lo, size = np.array([30.0, 1.0, 0.0]), np.array([4.5, 1.8, 1.5])
    px = cam.world_to_image(lo + CORNER_BITS * size)
    assert length_to_width(cam, px) == pytest.approx(2.5, rel=1e-6)


def test_vehicles_that_are_not_car_shaped_are_not_aligned(cam, models):
    """A truck-like 3D box (length 6x its width) is rejected before alignment even when its 2D box would match
    a car model; the status says how many were not car-shaped."""
    from gst_trafficcal.tracking.box3d import CORNER_BITS

    frames = vehicle_sightings(cam, models, np.random.default_rng(3), 1)

    def corners(s: Sighting, length: float) -> np.ndarray:
        x, y, _ = cam.to_world(np.asarray(s.base))
        lo = np.array([x - length / 2, y - 0.9, 0.0])
        return cam.world_to_image(lo + CORNER_BITS * np.array([length, 1.8, 1.5]))

    for length, aligned in ((4.5, True), (10.8, False)):
        est = ScaleEstimator(models, min_vehicles=1, refine_base=False)
        est.set_camera(cam)
        run(est, [[Sighting(s.track_id, s.t, s.box, s.base, s.heading, s.label, corners=corners(s, length))
                   for s in ss] for ss in frames])
        r = est.result()
        assert r.converged is aligned, r
        if not aligned:
            assert "1 not car-shaped" in r.status and r.n_vehicles == 0


def test_a_car_whose_plain_box_came_out_long_is_not_aligned(cam, models):
    """The tracker flags a car whose plain box came out long but who stands no taller than the scene's cars
    (``proportions`` "stretched": its outline is off); even with a car-shaped 3D box and a 2D box that matches a
    car model exactly, it gives no scale evidence, and the status counts it as not car-shaped."""
    frames = vehicle_sightings(cam, models, np.random.default_rng(3), 1)
    for stretched in (False, True):
        est = ScaleEstimator(models, min_vehicles=1, refine_base=False)
        est.set_camera(cam)
        run(est, [[replace(s, stretched=stretched) for s in ss] for ss in frames])
        r = est.result()
        assert r.converged is not stretched, r
        if stretched:
            assert "1 not car-shaped" in r.status and r.n_vehicles == 0


def test_vehicles_seen_before_the_vanishing_points_count_once_they_arrive(cam, models):
    """Before a calibration the tracker publishes only each vehicle's hull (no 3D box, no heading): those
    sightings are kept, and when the vanishing points arrive their 3D boxes are built from the hulls (the
    tracker's construction), so the vehicles that passed before count as well."""
    from dataclasses import replace

    from gst_trafficcal.scale.alignment import base_point, vehicle_to_camera

    names = list(models)
    frames = vehicle_sightings(cam, models, np.random.default_rng(3), 6)

    def early(s: Sighting) -> Sighting:  # what the tracker publishes before the calibration
        m = models[names[(s.track_id - 1) % len(names)]]
        X = base_point(cam, s.base) + (m.hull @ vehicle_to_camera(cam, s.heading).T) / TRUE_SCALE
        return replace(s, base=None, heading=0.0, hull=cam.from_road(X))

    half = len(frames) // 2
    est = ScaleEstimator(models, min_vehicles=5)
    for f, ss in enumerate(frames[:half]):  # no camera yet
        est.update(f * 0.1, [early(s) for s in ss])
    assert est.result().status.startswith("waiting for the vanishing points")
    est.set_camera(cam)
    for f, ss in enumerate(frames[half:], half):
        est.update(f * 0.1, ss)
    est.finish()
    r = est.result()
    assert r.n_matched >= 5, r  # those that passed before the calibration are matched too
    assert r.converged and r.scale == pytest.approx(TRUE_SCALE, rel=0.03), r
    without = ScaleEstimator(models, min_vehicles=5)  # the same stream without the early hulls
    for f, ss in enumerate(frames[:half]):
        without.update(f * 0.1, [replace(early(s), hull=None) for s in ss])
    without.set_camera(cam)
    for f, ss in enumerate(frames[half:], half):
        without.update(f * 0.1, ss)
    without.finish()
    assert without.result().n_matched <= 3 and not without.result().converged, without.result()
