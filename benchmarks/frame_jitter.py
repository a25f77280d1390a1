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

``--series N`` instead (no rendering; about a minute for 50): N simulated time series of each kind — times of
arrival (capture times on a steady rate, each delayed by a random 0..J s, some frames dropped) and variable frame
rates timed at capture — and per kind in how many FrameJitter says the times jitter (so that retime=auto smooths
them), and how far the 5-frame durations a speed divides by are from the capture times', as they come and smoothed
(FrameRetimer)::

    .venv/bin/python benchmarks/frame_jitter.py --series 50
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

from gst_trafficcal.frame_jitter import FrameJitter, retimed  # noqa: E402
from gst_trafficcal.gst.pipeline import run_pipeline  # noqa: E402
from gst_trafficcal.outputs import read_events  # noqa: E402
from gst_trafficcal.brnocompspeed import load_results  # noqa: E402
from gst_trafficcal.synth.generate import generate  # noqa: E402
from gst_trafficcal.synth.scenario import scenario_from_dict  # noqa: E402
from gst_trafficcal.synth.traffic import cuboid_models  # noqa: E402


FRAMES = 1500  # frames of each simulated series


def _arrival(fps: float, delay: float, drop: float):
    """Capture times at ``fps``, a fraction ``drop`` of the frames dropped, and their times of arrival (each delayed
    by a random 0..``delay`` s, kept increasing)."""
    def make(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, float]:
        kept = rng.random(FRAMES) >= drop
        kept[0] = True
        capture = np.arange(FRAMES)[kept] / fps
        return capture, np.maximum.accumulate(capture + rng.uniform(0, delay, len(capture))), 1 / fps
    return make


def _variable_rate(drifting: bool):
    """Capture times of a rate that varies itself (caps 30 fps): 30-45 ms intervals at random, or drifting between
    33 and 40 ms; timed at capture (arrival = capture)."""
    def make(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, float]:
        k = np.arange(FRAMES)
        dts = (0.0365 + 0.0035 * np.sin(k / 80 + rng.uniform(0, 6.3)) + rng.normal(0, 0.001, FRAMES) if drifting
               else rng.uniform(0.030, 0.045, FRAMES))
        capture = np.concatenate([[0.0], np.cumsum(dts)])
        return capture, capture, 1 / 30
    return make


SERIES = {  # name: maker of (capture times, times as the speedometer gets them, the caps' frame interval)
    "arrival 25 fps, 0-40 ms": _arrival(25, 0.04, 0.0),
    "arrival 25 fps, 0-40 ms, 2 % dropped": _arrival(25, 0.04, 0.02),
    "arrival 25 fps, 0-40 ms, 10 % dropped": _arrival(25, 0.04, 0.10),
    "arrival 12.5 fps, 0-20 ms": _arrival(12.5, 0.02, 0.0),
    "arrival 12.5 fps, 0-40 ms": _arrival(12.5, 0.04, 0.0),
    "arrival 12.5 fps, 0-40 ms, 5 % dropped": _arrival(12.5, 0.04, 0.05),
    "arrival 12.5 fps, 0-80 ms": _arrival(12.5, 0.08, 0.0),
    "variable rate 30-45 ms at random": _variable_rate(False),
    "variable rate drifting 33-40 ms": _variable_rate(True),
}


def series_table(n: int) -> list[tuple[str, int, float, float]]:
    """Per kind of :data:`SERIES`: (name, series of ``n`` said to jitter, median |relative error| of the 5-frame
    durations as they come, the same smoothed), the errors against the capture times over all ``n`` series."""
    rows = []
    for name, make in SERIES.items():
        said, raw, smooth = 0, [], []
        for seed in range(n):
            capture, times, interval = make(np.random.default_rng(seed))
            jitter = FrameJitter(interval)
            said += any(jitter.add(float(t)) for t in times)
            true = capture[5:] - capture[:-5]
            for got, out in ((times, raw), (retimed(times, interval), smooth)):
                out.append(np.abs((got[5:] - got[:-5]) / true - 1)[100:])  # once the smoothing line is fitted
        rows.append((name, said, float(np.median(np.concatenate(raw))), float(np.median(np.concatenate(smooth)))))
    return rows


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jitter", type=float, nargs="+", default=[0.0, 0.02, 0.04, 0.08])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--smooth", type=int, nargs="+", default=[0])
    ap.add_argument("--retime", nargs="+", default=["off", "auto", "always"], choices=["off", "auto", "always"])
    ap.add_argument("--series", type=int, default=0, metavar="N",
                    help="simulated time series instead of the rendered clip: N of each kind (see above)")
    args = ap.parse_args(argv)
    if args.series < 0:
        ap.error(f"--series must be a number of series (1 or more), got {args.series}")
    if args.series:
        print(f"{'series':40s} said  5-frame durations off (median): as they come / smoothed")
        for name, said, raw, smooth in series_table(args.series):
            print(f"{name:40s} {said:3d}/{args.series}  {raw * 100:5.1f} % / {smooth * 100:5.1f} %")
        return
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
