"""benchmarks/speed_uncertainty.py on a real speedometer run: it reads the product's U, recomputes the same U from
system.json's reference points, and counts the vehicles within ± U against the rendered truth."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from gst_trafficcal.gst.element import register_plugin_file
from gst_trafficcal.gst.pipeline import run_pipeline
from gst_trafficcal.outputs import read_events

from .conftest import ROOT


@pytest.fixture(scope="module")
def layout(cuboid_clip, tmp_path_factory) -> tuple[Path, Path]:
    """(runs, scenes) as end_to_end.py leaves them: RUNS/<scene>/auto holds the speedometer's files and the
    calibration, SCENES/<scene> the clip with its truth."""
    register_plugin_file(ROOT / "elements" / "python" / "speedometer.py")
    register_plugin_file(ROOT / "tests" / "gst_plugins" / "python" / "tcgtdetect.py")
    root = tmp_path_factory.mktemp("uncertainty")
    scenes, run = root / "scenes", root / "runs" / "clip" / "auto"
    scenes.mkdir()
    run.mkdir(parents=True)
    os.symlink(cuboid_clip, scenes / "clip")
    shutil.copy(cuboid_clip / "calibration.json", run / "calibration.json")
    run_pipeline(f"filesrc location={cuboid_clip / 'video.mp4'} ! decodebin ! videoconvert ! "
                 f"tcgtdetect frames-file={cuboid_clip / 'frames.jsonl'} ! speedometer "
                 f"calibration-file={run / 'calibration.json'} events-file={run / 'vehicles.jsonl'} "
                 f"results-file={run / 'system.json'} ! fakesink")
    return root / "runs", scenes


def test_the_recomputed_uncertainty_is_the_products_and_coverage_is_counted(layout, load_benchmark, capsys):
    bench = load_benchmark("speed_uncertainty")
    runs, scenes = layout
    given = bench.score_scene(runs / "clip" / "auto", scenes / "clip")
    again = bench.score_scene(runs / "clip" / "auto", scenes / "clip", recompute=True)
    events = [e for e in read_events(runs / "clip" / "auto" / "vehicles.jsonl").events if e.measured]
    assert len(given.vehicles) >= 12 and len(given.vehicles) <= len(events)
    assert {v.u_kmh for v in given.vehicles} <= {e.speed_uncertainty_kmh for e in events}
    for a, b in zip(given.vehicles, again.vehicles):  # the benchmark's U for runs before the field: the product's
        assert b.u_kmh == pytest.approx(a.u_kmh, abs=0.02)
    inside = sum(abs(v.speed_kmh - v.true_kmh) <= v.u_kmh for v in given.vehicles) / len(given.vehicles)
    assert inside >= 0.8
    assert bench.main(["--runs", str(runs), "--scenes", str(scenes), "--label", "clip"]) == 0
    row = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("| clip |"))
    assert row.split(" | ")[3:5] == [str(len(given.vehicles)), f"{inside:.3f}"]
