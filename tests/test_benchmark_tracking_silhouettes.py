"""benchmarks/tracking.py --detector oracle-silhouette: the renderer's exact vehicle silhouettes as hulls."""

import json
import pickle

import numpy as np
import pytest


@pytest.fixture(scope="module")
def tracking(load_benchmark):
    return load_benchmark("tracking")


def test_hulls_from_an_id_image(tracking):
    ids = np.zeros((60, 80), np.uint8)
    ids[10:20, 5:30] = 1  # slot 1: vehicle 7, pixels x 5..29, y 10..19
    ids[30:50, 40:45] = 2  # slot 2: vehicle 9
    ids[0:3, 0:3] = 255  # the shared overflow slot: skipped
    hulls = tracking.silhouette_hulls(ids, [7, 9])
    assert set(hulls) == {7, 9}
    assert np.allclose([*hulls[7].min(axis=0), *hulls[7].max(axis=0)], [4.5, 9.5, 29.5, 19.5])
    assert np.allclose([*hulls[9].min(axis=0), *hulls[9].max(axis=0)], [39.5, 29.5, 44.5, 49.5])
    shifted = tracking.silhouette_hulls(ids, [7, 9], np.array([[1.0, 0, 3.0], [0, 1.0, -2.0], [0, 0, 1.0]]))
    assert np.allclose(shifted[7].min(axis=0), [7.5, 7.5])  # the shake homography moves them


def test_a_render_keeps_each_vehicles_silhouette(tracking, tmp_path):
    from gst_trafficcal.synth.scenario import load_preset

    scen = load_preset("highway_day")
    scen.duration, scen.seed = 2.0, 3
    out = tracking.render_silhouettes(scen, tmp_path / "scene")
    with open(out / "silhouettes.pkl", "rb") as fh:
        sil = pickle.load(fh)
    assert len(sil) == 50  # every frame of 2 s at 25 fps
    checked = 0
    with open(out / "frames.jsonl", encoding="utf-8") as fh:
        for line in fh:
            r = json.loads(line)
            hull = sil[int(round(r["time"] * 1000))].get(r["id"])
            x0, y0, x1, y1 = r["box"]
            if r["visible"] < 1.0 or hull is None or min(x0, y0) < 1 or x1 > 958 or y1 > 538:
                continue  # occluded or cut by the frame: its mask is not the whole vehicle
            box = np.array([*hull.min(axis=0), *hull.max(axis=0)])
            # the renderer's own box (measured: within 0.92 px)
            assert np.abs(box - r["box"]).max() <= 1.5, (r["id"], box, r["box"])
            checked += 1
    assert checked > 50
