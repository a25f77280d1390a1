"""Speeds of frames timed by a jittery arrival (a source with ``do-timestamp=true``), and with those times smoothed.

Renders the speedometer tests' cuboid clip (tests/conftest.py CUBOID_SCENE: 12 s, 480x270, 12.5 fps) and runs
``filesrc ! decodebin ! videoconvert ! tcgtdetect (the true boxes) ! tcjitter jitter=J seed=S [smooth=N] !
speedometer calibration-file=<true calibration> retime=R``: each frame's time delayed by a random 0..J s, kept
increasing (tests/gst_plugins/python/tcjitter.py), then optionally smoothed by tcjitter's plain line fit over the
last N frames, and measured with the speedometer's own smoothing (retime: off, auto, always).  Prints per setting,
jitter and seed the vehicles measured and their speed error against the rendered truth, whether the speedometer
warned of jittering frame times, and per setting and jitter the means over the seeds::

    .venv/bin/python benchmarks/frame_jitter.py [--jitter 0 0.02 0.04 0.08] [--seeds 3] [--smooth 0]
        [--retime off auto always]
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
    ap.add_argument("--smooth", type=int, nargs="+", default=[0])
    ap.add_argument("--retime", nargs="+", default=["off", "auto", "always"], choices=["off", "auto", "always"])
    args = ap.parse_args(argv)
    for name in ("speedometer.py", "tracker.py"):
        T.register_plugin_file(T.ELEMENTS / name)
    for name in ("tcgtdetect", "tcjitter"):
        T.register_plugin_file(T.TEST_PLUGINS / f"{name}.py")
    work = Path(tempfile.mkdtemp(prefix="frame-jitter-"))
    clip = work / "clip"
    generate(scenario_from_dict(CUBOID_SCENE), clip, box_vehicles=True, model_factory=cuboid_models())
    summary = []
    for smooth in args.smooth:
        for retime in args.retime:
            for jitter in args.jitter:
                measured, means = [], []
                for seed in range(args.seeds):
                    out = work / f"s{smooth}_{retime}_j{jitter}_{seed}"
                    out.mkdir()
                    run = run_pipeline(f"{T.source(clip)} ! {T.detector(clip)} ! tcjitter jitter={jitter} "
                                       f"seed={seed} smooth={smooth} ! speedometer retime={retime} "
                                       f"calibration-file={clip / 'calibration.json'} "
                                       f"events-file={out / 'events.jsonl'} results-file={out / 'results.json'} "
                                       "! appsink name=sink")
                    events = read_events(out / "events.jsonl").events
                    e = np.abs(T.gt_speed_errors(clip, events, load_results(out / "results.json")))
                    warned = any("frame times jitter" in w for w in run.warnings)
                    measured.append(len(e))
                    means.append(e.mean())
                    print(f"smooth {smooth:3d} retime {retime:6s} jitter 0-{jitter * 1000:.0f} ms seed {seed}: "
                          f"{len(e)}/{len(events)} measured, |error| mean {e.mean():.2f} max {e.max():.2f} km/h; "
                          f"warned: {warned}", flush=True)
                summary.append(f"smooth {smooth:3d} retime {retime:6s} jitter 0-{jitter * 1000:2.0f} ms: measured "
                               f"{np.mean(measured):.1f} ({min(measured)}-{max(measured)}), |error| mean "
                               f"{np.mean(means):.2f} ({min(means):.2f}-{max(means):.2f}) km/h")
    print("\nmeans over the seeds:\n" + "\n".join(summary))


if __name__ == "__main__":
    main()
