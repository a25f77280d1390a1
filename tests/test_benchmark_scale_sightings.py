"""benchmarks/scale_sightings.py replay: the oracle per-scene edge shift and the even/odd halves of a scene."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from gst_trafficcal.scale.streaming import load_align_models

from .test_scale_streaming import TRUE_SCALE, cam, vehicle_sightings  # noqa: F401  (cam: the same camera fixture)

ROOT = Path(__file__).resolve().parents[1]
#: every detector box this much outside the exact one on the left, top and right (a soft-shadow halo), px
HALO = (-4.0, -3.0, 4.0, 0.0)


@pytest.fixture(scope="module")
def scene(cam, load_benchmark):
    """A dump of 12 catalogue vehicles whose detector boxes all carry the same halo, with the exact boxes as truth."""
    mod = load_benchmark("scale_sightings")
    models = load_align_models("skoda_octavia_mk1_liftback,skoda_octavia_mk1_combi,skoda_fabia_mk1_hatchback")
    names = list(models)
    frames = vehicle_sightings(cam, models, np.random.default_rng(3), 12)
    records = []
    for n, sightings in enumerate(frames):
        for s in sightings:  # vehicle_sightings gives track k + 1 the type names[k % 3]
            records.append(mod.Record(n, replace(s, box=tuple(np.add(s.box, HALO))), None, true_id=s.track_id,
                                      true_box=s.box, true_model=names[(s.track_id - 1) % len(names)],
                                      true_visible=1.0))
    return mod, {"scene": "halo", "camera": cam, "true": TRUE_SCALE, "records": records}


def test_the_scene_edge_shift_is_the_halo_undone_and_the_bottom_stays(scene):
    mod, data = scene
    shift = mod.scene_edge_shift(data["records"])
    assert shift == pytest.approx([4.0, 3.0, -4.0, 0.0], abs=1e-9)
    for rec, (_, _, s) in zip(data["records"], mod.variant_sightings(data["records"], "shifted_box")):
        assert s.box == pytest.approx(rec.true_box, abs=1e-9)


def test_the_oracle_shift_removes_a_halo_the_chain_scales_by(scene):
    mod, data = scene
    chain = mod.replay(data, "chain", min_vehicles=4)
    shifted = mod.replay(data, "shifted_box", min_vehicles=4)
    assert chain["error"] is not None and abs(chain["error"]) > 2.0  # the halo biases λ*
    assert abs(shifted["error"]) < 1.0


def test_exact_sides_and_exact_ends_swap_in_one_pair_of_edges(scene):
    mod, data = scene
    sides = [s.box for _, _, s in mod.variant_sightings(data["records"], "exact_sides")]
    ends = [s.box for _, _, s in mod.variant_sightings(data["records"], "exact_ends")]
    for rec, a, b in zip(data["records"], sides, ends):
        true, det = np.asarray(rec.true_box), np.asarray(rec.sighting.box)
        assert np.allclose(np.asarray(a)[[0, 2]], true[[0, 2]]) and np.allclose(np.asarray(a)[[1, 3]], det[[1, 3]])
        assert np.allclose(np.asarray(b)[[1, 3]], true[[1, 3]]) and np.allclose(np.asarray(b)[[0, 2]], det[[0, 2]])
    # the halo's sides (4 px each) are most of its bias: the true sides alone bring λ* close
    chain = mod.replay(data, "chain", min_vehicles=4)["error"]
    assert abs(mod.replay(data, "exact_sides", min_vehicles=4)["error"]) < abs(chain) / 2


def test_true_type_aligns_each_vehicle_with_its_own_model_only(scene):
    mod, data = scene
    res = mod.replay(data, "true_type", min_vehicles=4)
    truth = {r.true_id: r.true_model for r in data["records"]}
    assert res["matches"] and all(m.model == truth[m.track_id] for m in res["matches"])
    # a vehicle of no catalogue type (true model unknown) is not aligned at all
    unknown = [replace(r, true_model="generic_sedan") if r.true_id == 1 else r for r in data["records"]]
    res = mod.replay({**data, "records": unknown}, "true_type", min_vehicles=4)
    assert 1 not in {m.track_id for m in res["matches"]} and len(res["matches"]) >= 4
    exact = mod.replay(data, "exact_box_true_type", min_vehicles=4)
    assert abs(exact["error"]) < 0.5  # exact boxes and the true types: the estimator's own error only


def test_both_halves_of_a_biased_scene_share_its_bias(scene):
    mod, data = scene
    even, odd = mod.halves_rows(data, "chain", 3)
    whole = mod.replay(data, "chain", min_vehicles=4)["error"]
    assert even is not None and odd is not None
    assert abs(even - whole) < 1.5 and abs(odd - whole) < 1.5
    assert mod.halves_summary([(even, odd), (None, 1.0)]).endswith("(1 scenes)")


def test_a_missing_dump_is_one_line(tmp_path):
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "scale_sightings.py"), "replay",
                        str(tmp_path / "nothing.pkl")], capture_output=True, text=True)
    assert r.returncode != 0 and "no such dump" in r.stderr and "Traceback" not in r.stderr
