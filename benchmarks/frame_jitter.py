"""Speeds of frames timed by a jittery arrival (a source with ``do-timestamp=true``), and with those times smoothed.

Renders the speedometer tests' cuboid clip (tests/conftest.py CUBOID_SCENE: 12 s, 480x270, 12.5 fps) and runs
``filesrc ! decodebin ! videoconvert ! tcgtdetect (the true boxes) ! tcjitter jitter=J seed=S [smooth=N] !
speedometer calibration-file=<true calibration>``: each frame's time delayed by a random 0..J s, kept increasing
(tests/gst_plugins/python/tcjitter.py), then optionally smoothed by a line fit over the last N frames.  Prints per
jitter and seed the vehicles measured and their speed error against the rendered truth, and whether the speedometer
warned of jittering frame times::

    .venv/bin/python benchmarks/frame_jitter.py [--jitter 0 0.02 0.04 0.08] [--seeds 3] [--smooth 0 50]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import tests.test_speedometer_element as T  # noqa: E402  (helpers and element registration of the tests)
from tests.conftest import CUBOID_SCENE  # noqa: E402

from gst_trafficcal.gst.pipeline import run_pipeline  # noqa: E402
from gst_trafficcal.outputs import read_events  # noqa: E402
from gst_trafficcal.brnocompspeed import load_results  # noqa: E402
from gst_trafficcal.synth.generate import generate  # noqa: E402
from gst_trafficcal.synth.scenario import scenario_from_dict  # noqa: E402
from gst_trafficcal.synth.traffic import cuboid_models  # noqa: E402


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jitter", type=float, nargs="+", default=[0.0, 0.02, 0.04, 0.08])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--smooth", type=int, nargs="+", default=[0, 50])
    args = ap.parse_args(argv)
    for name in ("speedometer.py", "tracker.py"):
        T.register_plugin_file(T.ELEMENTS / name)
    for name in ("tcgtdetect", "tcjitter"):
        T.register_plugin_file(T.TEST_PLUGINS / f"{name}.py")
    work = Path(tempfile.mkdtemp(prefix="frame-jitter-"))
    clip = work / "clip"
    generate(scenario_from_dict(CUBOID_SCENE), clip, box_vehicles=True, model_factory=cuboid_models())
    for smooth in args.smooth:
        for jitter in args.jitter:
            for seed in range(args.seeds):
                out = work / f"s{smooth}_j{jitter}_{seed}"
                out.mkdir()
                run = run_pipeline(f"{T.source(clip)} ! {T.detector(clip)} ! tcjitter jitter={jitter} seed={seed} "
                                   f"smooth={smooth} ! speedometer calibration-file={clip / 'calibration.json'} "
                                   f"events-file={out / 'events.jsonl'} results-file={out / 'results.json'} "
                                   "! appsink name=sink")
                events = read_events(out / "events.jsonl").events
                e = np.abs(T.gt_speed_errors(clip, events, load_results(out / "results.json")))
                warned = any("frame times jitter" in w for w in run.warnings)
                print(f"smooth {smooth:3d} jitter 0-{jitter * 1000:.0f} ms seed {seed}: {len(e)}/{len(events)} "
                      f"measured, |error| mean {e.mean():.2f} max {e.max():.2f} km/h; warned: {warned}", flush=True)


if __name__ == "__main__":
    main()
