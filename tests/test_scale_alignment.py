"""BBScale alignment core: synthetic cameras and vehicles with a known scale λ, recovered from boxes alone.

The base points here are the models' true base centres, so the 3D-box correction of b is off (the paper's
method, ``refine_base=False``); test_scale_baseline.py covers b from the tracker's 3D box."""

from pathlib import Path

import numpy as np
import pytest

from gst_trafficcal.errors import InputError
from gst_trafficcal.geometry import Camera, rotation_matrix
from gst_trafficcal.scale import (Observation, align, align_model, box_iou, estimate_scale, kde_mode,
                                  projected_boxes)
from gst_trafficcal.scale.alignment import vehicle_to_camera
from gst_trafficcal.vehicles import load_catalogue
from gst_trafficcal.vehicles.mesh import load_mesh_file

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
KENNEY = SHARED / "models" / "vehicles" / "kenney_car_kit"
OCTAVIAS = ("skoda_octavia_mk1_liftback", "skoda_octavia_mk1_combi")


@pytest.fixture(scope="module")
def models():
    cat = load_catalogue()
    return {n: align_model(cat[n]) for n in OCTAVIAS}


def random_camera(rng, size=(1920, 1080)):
    f = rng.uniform(700, 2200)
    W, H = size
    K = np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1]])
    R = rotation_matrix(rng.uniform(-35, 35), rng.uniform(8, 40), rng.uniform(-10, 10))
    C = np.array([0.0, rng.uniform(-10, 10), rng.uniform(4, 18)])
    return Camera.from_KRt(K, R, -R @ C)


def observe(cam, mesh_vertices, pos, heading, track_id=0):
    """The exact image box and base centre of a vehicle mesh (metres) standing at world ``pos`` (metres)."""
    Xc = (pos @ cam.rotation.T - cam.scale * cam.normal) + mesh_vertices @ vehicle_to_camera(cam, heading).T
    if (Xc[:, 2] <= 0.5).any():
        return None
    px = cam.from_road(Xc)
    return Observation(box=(*px.min(0), *px.max(0)), base=tuple(cam.world_to_image(pos)), heading=heading,
                       track_id=track_id)


def in_view(obs, size=(1920, 1080)):
    return obs is not None and obs.box[0] > 0 and obs.box[1] > 0 and obs.box[2] < size[0] and obs.box[3] < size[1]


def scene(rng, models, n=6):
    cam = random_camera(rng)
    names = list(models)
    obs, truth = [], []
    while len(obs) < n:
        name = names[len(obs) % len(names)]
        o = observe(cam, models[name].mesh.vertices, np.array([rng.uniform(8, 60), rng.uniform(-10, 10), 0.0]),
                    float(rng.choice([-1.0, 1.0])), track_id=len(obs))
        if in_view(o) and o.box[2] - o.box[0] > 30:
            obs.append(o)
            truth.append(name)
    return cam, obs, truth


def test_scale_recovered_within_half_a_percent_and_types_identified(models):
    rng = np.random.default_rng(11)
    errs = []
    for _ in range(8):
        cam, obs, truth = scene(rng, models)
        est = estimate_scale(cam.with_scale(None), obs, models, refine_base=False)
        assert est.ok, est.status
        errs.append(abs(est.scale / cam.scale - 1))
        assert est.n_matched == len(obs)
        assert est.models_used == {n: truth.count(n) for n in set(truth)}
    assert max(errs) < 0.005, errs


def test_iou_peaks_at_the_true_scale_and_lambda_ij_is_the_candidate(models):
    rng = np.random.default_rng(2)
    cam, obs, truth = scene(rng, models, n=2)
    m = models[truth[0]]
    a = align(cam.with_scale(None), m, obs[0])
    assert a.iou.max() > 0.99
    assert abs(a.lambdas[a.best] / cam.scale - 1) < 0.01
    # the front and rear base points of the placed model, back on the road plane, are l/λ apart
    np.testing.assert_allclose(a.lambda_ij, a.lambdas, rtol=1e-9)
    # IoU decreases away from the peak on both sides (unimodal)
    i = a.best
    assert np.all(np.diff(a.iou[: i + 1]) >= -1e-9) and np.all(np.diff(a.iou[i:]) <= 1e-9)
    # the viewpoint points from the vehicle up towards the camera
    assert a.viewpoint[2] > 0 and abs(np.linalg.norm(a.viewpoint) - 1) < 1e-12


def test_projected_boxes_match_direct_projection(models):
    rng = np.random.default_rng(5)
    cam = random_camera(rng)
    m = models[OCTAVIAS[1]]
    pos = np.array([30.0, 2.0, 0.0])
    obs = observe(cam, m.mesh.vertices, pos, -1.0)
    boxes = projected_boxes(cam, m.hull, obs.base, -1.0, np.array([cam.scale]))
    np.testing.assert_allclose(boxes[0], obs.box, atol=1e-6)  # the hull's box is the mesh's box


def test_noisy_boxes_from_many_vehicles(models):
    """±1 px detector jitter on every box edge and ±1 px on the base point: λ* still within 1 %."""
    rng = np.random.default_rng(4)
    errs = []
    for _ in range(4):
        cam, obs, _ = scene(rng, models, n=20)
        noisy = [Observation(box=tuple(np.add(o.box, rng.uniform(-1, 1, 4))),
                             base=tuple(np.add(o.base, rng.uniform(-1, 1, 2))), heading=o.heading,
                             track_id=o.track_id) for o in obs]
        est = estimate_scale(cam.with_scale(None), noisy, models, refine_base=False)
        assert est.ok, est.status
        errs.append(abs(est.scale / cam.scale - 1))
    assert max(errs) < 0.01, errs


def test_classifier_probabilities_select_the_model(models):
    rng = np.random.default_rng(8)
    cam, obs, truth = scene(rng, models, n=4)
    # a confident (correct) classifier: only the named type is aligned
    labelled = [Observation(o.box, o.base, o.heading, o.track_id, {t: 0.9, "unknown_type": 0.1})
                for o, t in zip(obs, truth)]
    est = estimate_scale(cam.with_scale(None), labelled, models, refine_base=False)
    assert est.ok and abs(est.scale / cam.scale - 1) < 0.005
    assert est.models_used == {n: truth.count(n) for n in set(truth)}


def test_statuses_when_no_scale_can_be_had(models):
    rng = np.random.default_rng(9)
    cam, obs, _ = scene(rng, models, n=3)
    cam0 = cam.with_scale(None)
    est = estimate_scale(cam0, [], models, refine_base=False)
    assert not est.ok and est.status == "no vehicle observations"
    # boxes of another shape (a bus-like box at the same base): no match above the threshold
    wrong = [Observation((o.box[0], o.box[1] - 3 * (o.box[3] - o.box[1]), o.box[2], o.box[3]), o.base, o.heading)
             for o in obs]
    est = estimate_scale(cam0, wrong, models, refine_base=False)
    assert not est.ok and "no vehicle matched" in est.status
    est = estimate_scale(cam0, obs, models, min_vehicles=10, refine_base=False)
    assert not est.ok and "too few matched vehicles: 3 < 10" in est.status
    # a base point above the horizon is no observation to align (skipped, not an exception)
    above = Observation(obs[0].box, (cam.vp1[0], cam.vp1[1] - 50.0), 1.0)
    est = estimate_scale(cam0, [above], models, refine_base=False)
    assert not est.ok and "no vehicle matched" in est.status
    with pytest.raises(InputError, match="empty"):
        align(cam0, models[OCTAVIAS[0]], Observation((10, 10, 5, 20), obs[0].base))


def test_kde_mode_weighted_and_on_the_log_scale():
    rng = np.random.default_rng(0)
    v = np.exp(rng.normal(np.log(10.0), 0.01, 400))
    assert abs(kde_mode(v, np.ones_like(v)) / 10.0 - 1) < 0.005
    # two clusters: the heavier-weighted one wins
    v2 = np.concatenate([v, v * 1.2])
    w2 = np.concatenate([np.full(400, 0.9), np.full(400, 0.3)])
    assert abs(kde_mode(v2, w2) / 10.0 - 1) < 0.005
    assert abs(kde_mode(v2, w2[::-1]) / 12.0 - 1) < 0.005
    # a symmetric (in log λ) IoU profile has its mode at the centre
    lam = 7.0 * np.geomspace(1 / 1.08, 1.08, 61)
    iou = 1 - np.abs(np.log(lam / 7.0))
    assert abs(kde_mode(lam, iou) / 7.0 - 1) < 1e-3


def test_the_binned_density_has_the_kde_mode_and_does_not_grow():
    """LogDensity, fed vehicle by vehicle, has the mode of kde_mode with the same kernel over every value to within
    a step (0.05 %); degenerate input as kde_mode's; its bins stay as many however many values come."""
    from gst_trafficcal.scale.estimate import LogDensity

    rng = np.random.default_rng(1)
    for _ in range(5):
        density, lams, weights = LogDensity(), [], []
        for _ in range(int(rng.integers(3, 40))):
            lam = 8.0 * np.exp(rng.normal(0.0, 0.04, int(rng.integers(1, 30))) + (0.3 if rng.random() < 0.1 else 0))
            w = rng.uniform(0.85, 1.0, len(lam))
            density.add(lam, w / w.sum())
            lams.append(lam), weights.append(w / w.sum())
        lam, w = np.concatenate(lams), np.concatenate(weights)
        v = np.log(lam)
        sd = np.sqrt(np.average((v - np.average(v, weights=w)) ** 2, weights=w))
        assert density.mode(0.05) == pytest.approx(kde_mode(lam, w, bw_method=0.05 / sd), rel=6e-4)
        assert len(density) == len(lam)
    one = LogDensity()
    with pytest.raises(ValueError, match="no values"):
        one.mode(0.05)
    one.add(np.array([7.5, 7.5, np.nan, -1.0]), np.array([0.5, 0.5, 1.0, 1.0]))  # the bad values left out
    assert one.mode(0.05) == pytest.approx(7.5, rel=1e-12) and len(one) == 2
    many = LogDensity()
    for _ in range(20):
        many.add(8.0 * np.exp(rng.normal(0.0, 0.05, 1000)), np.full(1000, 1e-3))
    bins = len(many._bins)
    for _ in range(200):
        many.add(8.0 * np.exp(rng.normal(0.0, 0.05, 1000)), np.full(1000, 1e-3))
    assert len(many._bins) < 1.5 * bins and len(many) == 220_000
    assert many.mode(0.05) == pytest.approx(8.0, rel=0.01)


def test_box_iou():
    boxes = np.array([[0, 0, 10, 10], [5, 0, 15, 10], [20, 20, 30, 30], [np.nan] * 4])
    np.testing.assert_allclose(box_iou(boxes, (0, 0, 10, 10)), [1.0, 50 / 150, 0.0, 0.0])


@pytest.mark.skipif(not KENNEY.is_dir(), reason=f"{KENNEY} (shared test data) is absent")
def test_scale_from_a_user_mesh_file():
    """A type given as a mesh file (Kenney's sedan rescaled to Octavia liftback dimensions)."""
    cat = load_catalogue()
    spec = cat["skoda_octavia_mk1_liftback"]
    mesh = load_mesh_file(KENNEY / "sedan.glb", spec.length, spec.width, spec.height)
    m = align_model(spec, mesh)
    rng = np.random.default_rng(3)
    cam, obs, _ = scene(rng, {m.name: m}, n=5)
    est = estimate_scale(cam.with_scale(None), obs, {m.name: m}, refine_base=False)
    assert est.ok and abs(est.scale / cam.scale - 1) < 0.005


def test_track_mean_type_probabilities():
    from gst_trafficcal.scale.estimate import with_track_mean_types

    obs = [Observation((0, 0, 1, 1), (0, 0), 1.0, 1, {"a": 0.8, "b": 0.2}),
           Observation((0, 0, 1, 1), (0, 0), 1.0, 1, {"a": 0.4, "b": 0.6}),
           Observation((0, 0, 1, 1), (0, 0), 1.0, 2, None)]
    out = with_track_mean_types(obs)
    assert out[0].type_probs == pytest.approx({"a": 0.6, "b": 0.4}) and out[1].type_probs == out[0].type_probs
    assert out[2].type_probs is None


def test_heading_from_track():
    from gst_trafficcal.scale.alignment import heading_from_track

    cam = random_camera(np.random.default_rng(0))
    towards = cam.world_to_image(np.array([[10.0, 1.0, 0.0], [14.0, 1.0, 0.0], [18.0, 1.2, 0.0]]))
    assert heading_from_track(cam.with_scale(None), towards) == 1.0
    assert heading_from_track(cam.with_scale(None), towards[::-1]) == -1.0
    with pytest.raises(InputError):
        heading_from_track(cam, towards[:1])


def test_fitted_base_recovers_a_displaced_base_point(models):
    """``refine_base="fit"``: b fitted jointly with λ to the exact box brings back the true base centre and λ
    from a b displaced by a tenth of the box height (as the tracker's 3D-box base can be); with the displaced b
    as is, λ is further off."""
    from dataclasses import replace

    from gst_trafficcal.scale.alignment import fitted_base

    rng = np.random.default_rng(5)
    cam, obs, truth = scene(rng, models, n=4)
    c0 = cam.with_scale(None)
    for o, name in zip(obs, truth):
        m = models[name]
        h = o.box[3] - o.box[1]
        moved = replace(o, base=(o.base[0] + 0.1 * h, o.base[1] + 0.05 * h))
        b = fitted_base(c0, m, moved, float(cam.scale) * 1.05)
        assert np.hypot(b[0] - o.base[0], b[1] - o.base[1]) < 0.01 * h + 0.5
        fit, raw = align(c0, m, moved, refine_base="fit"), align(c0, m, moved)
        lam_fit, lam_raw = fit.lambda_ij[fit.best], raw.lambda_ij[raw.best]
        assert fit.iou.max() > 0.98 and fit.iou.max() >= raw.iou.max()
        assert abs(lam_fit / cam.scale - 1) < 0.01 and abs(lam_fit / cam.scale - 1) <= abs(lam_raw / cam.scale - 1)


def test_loose_edges_count_only_one_way():
    """A shadow-extended edge (+1) is free outward, a lost part (-1) free inward; 0 is the plain IoU."""
    from gst_trafficcal.scale.alignment import box_iou, loose_iou

    model = np.array([[0.0, 0.0, 10.0, 10.0]])
    wide = [0.0, 0.0, 12.0, 10.0]  # the detected box reaches 2 px further right (a cast shadow)
    short = [0.0, 3.0, 10.0, 10.0]  # the detected box lost the top 3 px
    assert loose_iou(model, wide, (0, 0, 1, 0))[0] == pytest.approx(1.0)
    assert loose_iou(model, wide, (0, 0, -1, 0))[0] == pytest.approx(box_iou(model, wide)[0])
    assert loose_iou(model, short, (0, -1, 0, 0))[0] == pytest.approx(1.0)
    assert loose_iou(model, short, (0, 1, 0, 0))[0] == pytest.approx(0.7)
    assert loose_iou(model, short, None)[0] == pytest.approx(0.7)
