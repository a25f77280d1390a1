"""benchmarks/scale.py keeps per-scene results in --work; their cache is named for the detector's weights and the
chain's code, so a re-trained model or a changed estimator never reuses earlier results."""

from __future__ import annotations

import argparse

import pytest

from gst_trafficcal.detection import vehicleseg
from gst_trafficcal.detection.models import sha256_of
from gst_trafficcal.errors import InputError


def test_cache_key_follows_the_weights(tmp_path, load_benchmark):
    key = load_benchmark("scale").detector_key
    assert key("vehicleseg") == f"vehicleseg-{sha256_of(vehicleseg.WEIGHTS)[:8]}"
    same = tmp_path / "vehicleseg.onnx"
    same.write_bytes(vehicleseg.WEIGHTS.read_bytes())
    assert key(str(same)) == key("vehicleseg")  # the same weights elsewhere share the results
    retrained = tmp_path / "retrained.onnx"
    retrained.write_bytes(vehicleseg.WEIGHTS.read_bytes() + b"\0")
    assert key(str(retrained)).startswith("retrained-") and key(str(retrained))[-8:] != key("vehicleseg")[-8:]
    with pytest.raises(InputError, match="model file not found"):
        key(str(tmp_path / "missing.onnx"))


def test_cache_key_follows_the_chains_code(tmp_path, load_benchmark):
    """The cache is also named for the chain's source (detection, tracking, scale, vehicles): a change of the
    estimator (e.g. its kernel) must not reuse results written by the old code."""
    code_key = load_benchmark("scale").code_key
    for pkg in ("scale", "tracking"):
        (tmp_path / pkg / "sub").mkdir(parents=True)
        (tmp_path / pkg / "__init__.py").write_text("")
        (tmp_path / pkg / "sub" / "estimate.py").write_text("BANDWIDTH = 0.02\n")
    (tmp_path / "scale" / "notes.txt").write_text("not code")
    before = code_key(tmp_path, ("scale", "tracking"))
    assert code_key(tmp_path, ("scale", "tracking")) == before and len(before) == 8
    (tmp_path / "scale" / "notes.txt").write_text("still not code")
    assert code_key(tmp_path, ("scale", "tracking")) == before
    (tmp_path / "scale" / "sub" / "estimate.py").write_text("BANDWIDTH = 0.05\n")
    assert code_key(tmp_path, ("scale", "tracking")) != before
    assert code_key(tmp_path, ("tracking",)) != code_key(tmp_path, ("scale", "tracking"))
    assert len(code_key()) == 8  # the repository's own chain


def test_replay_length_and_a_folder_of_another_length(tmp_path, load_benchmark):
    """--replay-duration: 60 s (120 s for the sparse session 3) by default, one figure for all or "S,S3"; a replay
    folder rendered with another length is refused, not silently measured as if it were the asked one."""
    bench = load_benchmark("scale")
    assert bench.replay_duration("session0_left") == 60 and bench.replay_duration("session3_right") == 120
    assert bench.replay_duration("session1_center", "240") == 240 == bench.replay_duration("session3_left", 240)
    assert bench.replay_duration("session2_left", "240,360") == 240
    assert bench.replay_duration("session3_center", "240,360") == 360
    folder = tmp_path / "session0_left"
    folder.mkdir()
    (folder / "video.mp4").write_bytes(b"\0")
    (folder / "scenario.json").write_text('{"duration": 60.0}')
    assert bench.render_replay("session0_left", tmp_path, "catalogue") == folder  # the default length: reused
    with pytest.raises(SystemExit, match="holds 60 s of replay, not 240 s"):
        bench.render_replay("session0_left", tmp_path, "catalogue", "240,360")


def test_a_replay_folder_without_its_scenario_file_is_reused_as_it_is(tmp_path, load_benchmark):
    """Renders older than the scenario file (no scenario.json) keep working: their length is not known, so they are
    taken as they are; a malformed --replay-duration is refused with the option's own message."""
    bench = load_benchmark("scale")
    folder = tmp_path / "session1_left"
    folder.mkdir()
    (folder / "video.mp4").write_bytes(b"\0")
    assert bench.render_replay("session1_left", tmp_path, "catalogue", "240") == folder
    for bad in ("abc", "0", "60,-1", "60,120,240"):
        with pytest.raises(argparse.ArgumentTypeError, match="SECONDS or SECONDS,SESSION3_SECONDS"):
            bench.duration_arg(bad)
