"""3D boxes from convex hulls on synthetic geometry: a known box seen by a known camera is recovered."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from gst_trafficcal.geometry import Camera, rotation_matrix
from gst_trafficcal.tracking.box3d import CORNER_BITS, boxes_from_hulls, corners_fit_hulls, pixels_to_road

W, H = 1920, 1080


def make_camera(pan: float, tilt: float, roll: float, height: float, f: float = 1400.0):
    K = np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1.0]])
    R = rotation_matrix(pan, tilt, roll)
    t = -R @ np.array([0.0, 0.0, height])
    return Camera.from_KRt(K, R, t), K, R, t


def project(K, R, t, X):
    p = (K @ (R @ np.asarray(X).T + t[:, None])).T
    return p[:, :2] / p[:, 2:]


def vehicle_corners(x, y, length=4.5, width=1.8, height=1.5):
    lo = np.array([x - length / 2, y - width / 2, 0.0])
    hi = np.array([x + length / 2, y + width / 2, height])
    return np.where(CORNER_BITS == 1, hi, lo)


def hull_of(px):
    return cv2.convexHull(px.astype(np.float32)).reshape(-1, 2).astype(np.float64)


# (pan, tilt, roll, height, lateral offsets of the vehicles): cameras centred, left and right of the road,
# strong roll, VP2 almost at infinity (camera looking along the road), camera looking across the road.
CASES = [
    (0.5, 15, 0, 8, [-6, -2, 3, 7]),
    (20, 20, 2, 10, [-5, 0, 5]),
    (-25, 25, -3, 12, [-4, 1, 6]),
    (10, 12, 12, 6, [-3, 3]),
    (-55, 30, 0, 15, [-6, -2, 2, 6]),
    (50, 25, 5, 6, [-6, -2, 3, 7]),
]


@pytest.mark.parametrize("pan,tilt,roll,height,lanes", CASES)
def test_recovers_projected_box_exactly(pan, tilt, roll, height, lanes):
    cam, K, R, t = make_camera(pan, tilt, roll, height)
    d = np.array([np.cos(np.radians(pan)), np.sin(np.radians(pan))])
    rng = np.random.default_rng(abs(int(pan * 10 + tilt)))
    truth, hulls = [], []
    for lane in lanes:
        for dist in (12.0, 25.0, 45.0):
            centre = dist * d + lane * np.array([-d[1], d[0]])
            X = vehicle_corners(*centre, length=rng.uniform(3.5, 9), width=rng.uniform(1.6, 2.5),
                                height=rng.uniform(1.2, 3.5))
            px = project(K, R, t, X)
            if np.all((px > 0) & (px < [W, H])):
                truth.append(px)
                hulls.append(hull_of(px))
    assert len(hulls) >= 4
    boxes = boxes_from_hulls(cam, hulls)
    assert boxes.valid.all()
    err = np.abs(boxes.corners_px - np.array(truth)).max(axis=(1, 2))
    assert err.max() < 1.0, err
    assert np.all(boxes.residual < 1e-4)


@pytest.mark.parametrize("direction", [1, -1])
def test_reference_point_is_bottom_front_centre_on_the_road(direction):
    cam, K, R, t = make_camera(15, 20, 1, 9)
    d = np.array([np.cos(np.radians(15)), np.sin(np.radians(15))])
    centres = [20 * d + 3 * np.array([-d[1], d[0]]), 35 * d - 4 * np.array([-d[1], d[0]])]
    L = 4.6
    hulls = [hull_of(project(K, R, t, vehicle_corners(*c, length=L))) for c in centres]
    boxes = boxes_from_hulls(cam, hulls)
    road, px = boxes.reference_points(cam, direction)
    front = np.array([np.append(c + direction * L / 2 * np.array([1.0, 0.0]), 0.0) for c in centres])
    # world x is the road direction (VP1): the front is half a length along it
    assert np.abs(px - project(K, R, t, front)).max() < 1.0
    # road-plane coordinates in plane units times λ (camera height) are world metres
    assert np.abs(road * cam.scale - front[:, :2]).max() < 0.02
    assert np.allclose(cam.to_world(px)[:, :2], front[:, :2], atol=0.02)
    assert np.allclose(pixels_to_road(cam, px), road, atol=1e-6)


def test_plain_box_of_a_body_with_a_cabin_keeps_the_body():
    """Dubská's plain construction (no body shapes): a silhouette of a narrower cabin on a body gives a box close
    to the body's box (the ground and vertical tangents touch the body, the roof tangent is slack)."""
    cam, K, R, t = make_camera(-10, 18, 0, 8)
    d = np.array([np.cos(np.radians(-10)), np.sin(np.radians(-10))])
    c = 22 * d + 2.5 * np.array([-d[1], d[0]])
    body = vehicle_corners(*c, length=4.6, width=1.8, height=0.9)
    cabin = vehicle_corners(*(c - 0.2 * d), length=2.4, width=1.5, height=1.45)
    cabin[:4, 2] = 0.9
    px = project(K, R, t, np.vstack([body, cabin]))
    boxes = boxes_from_hulls(cam, [hull_of(px)], shapes=())
    assert boxes.valid[0]
    x0, x1, y0, y1, h = boxes.params[0] * cam.scale
    assert abs((x1 - x0) - 4.6) < 0.05 and abs((y1 - y0) - 1.8) < 0.05 and 0.9 <= h <= 1.46
    road, _ = boxes.reference_points(cam, 1)
    assert np.linalg.norm(road[0] * cam.scale - (c + 2.3 * np.array([1.0, 0.0]))) < 0.3


def test_points_above_horizon_are_invalid_and_empty_input():
    cam, *_ = make_camera(5, 15, 0, 8)
    above = np.array([[900.0, 10.0], [1000.0, 10.0], [950.0, -50.0]])
    boxes = boxes_from_hulls(cam, [above])
    assert not boxes.valid[0]
    assert len(boxes_from_hulls(cam, [])) == 0


def test_no_degenerate_box_at_the_cameras_foot():
    """The zero-size box at the camera's foot reaching up to the camera is tangent to every hull and has the
    smallest volume; it must never be chosen.  Seen on a BrnoCompSpeed replay (session0_right: camera looking
    along the road, VP2 far away) for about a quarter of the hulls, whose reference points landed 26000 px below
    the image (speeds of 100-600 km/h); also for exact cuboids seen by the scale tests' random cameras."""
    cam = Camera(vp1=[823.68, -92.69], vp2=[122348.0, 64.95], pp=[960.5, 540.5], scale=8.15)
    x0, y0, x1, y1 = 783.5, 299.5, 895.5, 359.5  # a car's hull box, far down the road
    rect = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    boxes = boxes_from_hulls(cam, [rect])
    assert boxes.valid[0] and boxes.params[0, 4] < 1  # below the camera
    c = boxes.corners_px[0]
    assert np.all((c >= [x0 - 1, y0 - 1]) & (c <= [x1 + 1, y1 + 1]))  # a box whose silhouette is the rectangle
    _, ref = boxes.reference_points(cam, -1)
    assert abs(ref[0, 1] - y1) < 1.0 and x0 < ref[0, 0] < x1  # bottom edge of the hull


def test_boxes_far_outside_their_hull_are_invalid():
    lo, hi = np.array([[100.0, 100.0]]), np.array([[200.0, 150.0]])
    inside = np.array([[[150.0, 120.0]] * 8])
    assert corners_fit_hulls(inside, lo, hi).tolist() == [True]
    near = inside.copy()
    near[0, 0] = [290.0, 190.0]  # within the hull box's own size of it: a box is fuller than a rounded car
    assert corners_fit_hulls(near, lo, hi).tolist() == [True]
    far = inside.copy()
    far[0, 3] = [150.0, 26000.0]
    assert corners_fit_hulls(far, lo, hi).tolist() == [False]
    assert corners_fit_hulls(np.full((1, 8, 2), np.nan), lo, hi).tolist() == [False]


SHARED_KENNEY = Path(__file__).resolve().parents[1].parent / "shared" / "models" / "vehicles" / "kenney_car_kit"


def _front_errors(vertices: np.ndarray, length: float, shapes) -> np.ndarray:
    """Reference-point errors (m) of a car mesh (vehicle frame, base centre at the origin) driven both ways in
    two lanes at 18-45 m, seen by two cameras: the box from its exact silhouette against its true front."""
    V = vertices - [(vertices[:, 0].min() + vertices[:, 0].max()) / 2,
                    (vertices[:, 1].min() + vertices[:, 1].max()) / 2, vertices[:, 2].min()]
    errs = []
    for pan, tilt, height in ((-10, 18, 8), (5, 12, 6)):
        cam, K, R, t = make_camera(pan, tilt, 0, height)
        for direction in (1, -1):
            flip = np.diag([direction, direction, 1.0])  # heading along world x (towards VP1) or against it
            for x in (18.0, 30.0, 45.0):
                for y in (-3.0, 2.5):
                    boxes = boxes_from_hulls(cam, [hull_of(project(K, R, t, V @ flip + [x, y, 0]))], shapes=shapes)
                    assert boxes.valid[0]
                    road, _ = boxes.reference_points(cam, direction)
                    errs.append(np.linalg.norm(road[0] * cam.scale - [x + direction * length / 2, y]))
    return np.array(errs)


def test_car_body_shapes_put_the_box_on_a_real_cars_silhouette():
    """A car is not a box: rounded bumpers above the road, wheels set in, a narrower cabin.  With the plain
    construction the reference point of an exact car silhouette lands ~0.3 m off (up to 0.9 m); with the
    catalogue's body shapes within centimetres (named models, whose proportions differ from the shapes'
    mean-dimension bodies)."""
    from gst_trafficcal.vehicles.catalogue import load_catalogue
    from gst_trafficcal.vehicles.mesh import mesh_for

    cat = load_catalogue()
    for name in ("skoda_octavia_mk1_combi", "vw_golf_mk4_hatchback", "skoda_superb_mk2_liftback"):
        V = np.unique(np.asarray(mesh_for(cat[name], np.random.default_rng(0)).vertices), axis=0)
        plain, shaped = _front_errors(V, cat[name].length, ()), _front_errors(V, cat[name].length, None)
        assert np.median(plain) > 0.25, name
        assert np.median(shaped) < 0.1 and shaped.max() < 0.35, (name, np.round(shaped, 3))


def test_car_body_shapes_help_on_a_mesh_from_elsewhere():
    """Kenney's CC0 toy car (not one of our procedural bodies), rescaled to an Octavia's dimensions: the body
    shapes still halve the reference-point error of its exact silhouette."""
    path = SHARED_KENNEY / "sedan.glb"
    if not path.is_file():
        pytest.skip("../shared/models/vehicles/kenney_car_kit is not available")
    from gst_trafficcal.vehicles.mesh import load_mesh_file

    V = np.unique(np.asarray(load_mesh_file(path, 4.51, 1.73, 1.46).vertices), axis=0)
    plain, shaped = _front_errors(V, 4.51, ()), _front_errors(V, 4.51, None)
    assert np.median(shaped) < 0.5 * np.median(plain), (np.median(shaped), np.median(plain))


def test_long_vehicles_hold_truck_and_bus_bodies():
    """A semitrailer's rear stands a metre above the road and a bus's wheels are set in under its overhangs: the
    plain box misplaces their fronts by 0.4-0.6 m (median over the views), and a car's sloped ends, which explain
    a truck's silhouette best of all, must not be offered to them.  With the long-vehicle bodies, which only
    long boxes may hold, the fronts of their exact silhouettes land within 0.2 m."""
    from gst_trafficcal.vehicles.catalogue import load_catalogue
    from gst_trafficcal.vehicles.mesh import mesh_for

    cat = load_catalogue()
    for name in ("eu_tractor_semitrailer_16_5m", "mercedes_citaro_o530_12m_bus"):
        V = np.unique(np.asarray(mesh_for(cat[name], np.random.default_rng(0)).vertices), axis=0)
        plain, shaped = _front_errors(V, cat[name].length, ()), _front_errors(V, cat[name].length, None)
        assert np.median(plain) > 0.3, name
        assert np.median(shaped) < 0.2 and np.median(shaped) < 0.5 * np.median(plain), (name, np.round(shaped, 2))


def test_proportions_decide_which_bodies_a_vehicle_may_hold():
    from gst_trafficcal.tracking.box3d import allowed_shapes, proportions_class

    # x0, x1, y0, y1, h in any unit: a car, a semitrailer, a motorcycle with its rider, and no box at all
    boxes = np.array([[0, 4.6, 0, 1.8, 1.46], [0, 16.5, 0, 2.55, 4.0], [0, 2.1, 0, 0.8, 1.5], [np.nan] * 5])
    assert proportions_class(boxes).tolist() == ["car", "long", "other", "other"]
    # the median over a track's boxes decides: one distorted box does not make a car long
    track = np.array([[0, 4.6, 0, 1.8, 1.46], [0, 9.0, 0, 1.8, 1.46], [0, 4.4, 0, 1.7, 1.4]])[:, None, :]
    assert proportions_class(track).tolist() == ["car"]
    ok = allowed_shapes(["box", "car", "long"], np.array(["car", "long", "other", "stretched"]))
    assert ok.tolist() == [[True, True, True, True], [True, False, False, True], [False, True, False, False]]
    # with the scene's typical height a long box must also stand tall: a car whose box came out long stays a car
    long_car, truck = np.array([[0, 9.0, 0, 1.8, 1.5]]), np.array([[0, 16.5, 0, 2.55, 4.0]])
    assert proportions_class(long_car).tolist() == ["long"]
    assert proportions_class(long_car, typical_height=1.5).tolist() == ["stretched"]
    narrow = np.array([[0, 9.0, 0, 1.2, 1.5]])  # its width short too: height / width 1.25 is no van's here
    assert proportions_class(narrow, typical_height=1.5).tolist() == ["stretched"]
    assert proportions_class(truck, typical_height=1.5).tolist() == ["long"]


def test_typical_height_is_the_median_of_the_last_vehicles():
    from gst_trafficcal.tracking.box3d import TypicalHeight

    typical = TypicalHeight(size=4, least=3)
    typical.add(0.3)
    typical.add(None)
    typical.add(float("nan"))
    assert typical.value is None  # one height is not a scene's
    assert typical.value_with([0.32, 0.9]) == pytest.approx(0.32)  # the vehicles in view stand in
    for h in (0.31, 0.9, 0.33, 0.34):
        typical.add(h)
    assert len(typical.heights) == 4 and typical.value == pytest.approx(0.335)  # the first (0.3) has left
    typical.clear()
    assert typical.value is None


def test_a_long_box_of_a_cars_height_holds_a_cars_body():
    """A car's plain box can come out far too long (a low camera, its far lane: 1.5-3x, from the segmenter's
    outline), and a car's silhouette must then not take a truck's body, which would move its front by metres.
    Exact silhouettes seen by two cameras: a car stretched to a semitrailer's proportions but of a car's height
    takes a car body once the scene's typical height is known, the semitrailer keeps a long body."""
    from gst_trafficcal.tracking.box3d import TypicalHeight, fit_shapes, track_choice, track_class
    from gst_trafficcal.vehicles.catalogue import load_catalogue
    from gst_trafficcal.vehicles.mesh import mesh_for

    cat = load_catalogue()

    def mesh(name: str, stretch: float = 1.0) -> np.ndarray:
        V = np.unique(np.asarray(mesh_for(cat[name], np.random.default_rng(0)).vertices), axis=0) * [stretch, 1, 1]
        return V - [(V[:, 0].min() + V[:, 0].max()) / 2, (V[:, 1].min() + V[:, 1].max()) / 2, V[:, 2].min()]

    for pan, tilt, height in ((-10, 18, 8), (5, 12, 6)):
        cam, K, R, t = make_camera(pan, tilt, 0, height)

        def choice(V: np.ndarray, typical: float | None) -> tuple[str, float, str]:
            """(kind of the body chosen, the plain boxes' median height, the class they give)"""
            hulls = [hull_of(project(K, R, t, V + [x, y, 0])) for x in (20.0, 24.0, 28.0) for y in (-3.0, 2.5)]
            fits = fit_shapes(cam, hulls)
            cls = track_class(fits.params[0], typical)
            k = track_choice(fits.fit.T, fits.kinds, cls)
            return fits.kinds[k], float(np.median(fits.params[0, :, 4])), cls

        typical = TypicalHeight()
        for name in ("skoda_octavia_mk1_combi", "vw_golf_mk4_hatchback", "skoda_superb_mk2_liftback",
                     "skoda_fabia_mk1_hatchback", "vw_passat_b6_variant"):
            kind, h, _ = choice(mesh(name), typical.value)
            assert kind in ("car", "box"), name
            typical.add(h)
        stretched = mesh("skoda_octavia_mk1_combi", stretch=2.2)  # 10 m long, 1.5 m tall
        assert choice(stretched, None)[2] == "long"  # proportions alone: a long vehicle's bodies
        kind, _, cls = choice(stretched, typical.value)
        assert cls == "stretched" and kind in ("car", "box")
        for name in ("eu_tractor_semitrailer_16_5m", "mercedes_citaro_o530_12m_bus"):
            kind, _, cls = choice(mesh(name), typical.value)
            assert cls == "long" and kind in ("long", "box"), name
