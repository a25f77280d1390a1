"""Frames per second of `trafficcal synth` (render + imaging + H.264 encoding + ground truth).

Usage:  .venv/bin/python benchmarks/synth_fps.py [--duration 8] [--sizes 960x540,1920x1080] [--boxes]

Renders the ``highway_day`` preset with traffic dense enough for about ten vehicles in view (the script
prints the measured mean number of visible vehicles per frame) and reports the frame loop's speed (wall
clock, which other processes on the machine slow down), the CPU time of the frame loop and of the whole run
(setup included: the static scene, textures, noise bank), and the speeds these imply on otherwise idle
cores. Set LP_NUM_THREADS=1 (single-threaded llvmpipe) for stable CPU-time A/B comparisons.
Targets (2 cores, llvmpipe): >= 40 fps at 960x540 and >= 12 fps at 1920x1080.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import tempfile
from pathlib import Path

import numpy as np

from gst_trafficcal.synth.generate import FRAMES_JSONL, generate
from gst_trafficcal.synth.scenario import load_preset


def _cpu_seconds() -> float:
    """User + system CPU time of this process (llvmpipe's threads included) and of waited-for children (x264)."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=8.0)
    ap.add_argument("--sizes", default="960x540,1920x1080")
    ap.add_argument("--flow", type=float, default=1100.0, help="vehicles per hour per lane")
    ap.add_argument("--boxes", action="store_true", help="cuboid vehicles instead of the catalogue meshes")
    args = ap.parse_args()
    for size in args.sizes.split(","):
        w, h = (int(v) for v in size.lower().split("x"))
        scen = load_preset("highway_day")
        scen.camera.resolution = [w, h]
        scen.duration = args.duration
        scen.traffic.flow = args.flow
        scen.seed = 1
        with tempfile.TemporaryDirectory() as tmp:
            before = _cpu_seconds()
            res = generate(scen, tmp, box_vehicles=args.boxes)
            cpu = _cpu_seconds() - before
            per_frame: dict[int, int] = {}
            for line in (Path(tmp) / FRAMES_JSONL).read_text().splitlines():
                r = json.loads(line)
                if r["visible"] > 0.05:
                    per_frame[r["frame"]] = per_frame.get(r["frame"], 0) + 1
            in_view = np.mean([per_frame.get(i, 0) for i in range(res.frames)])
        cores = len(os.sched_getaffinity(0))
        loop_cpu = res.loop_cpu_seconds
        print(f"{w}x{h}: {res.frames / res.loop_seconds:.1f} fps ({res.frames} frames in {res.loop_seconds:.1f} s wall), "
              f"{in_view:.1f} vehicles in view on average; CPU {cpu:.1f} s (renderer + encoder) = "
              f"{res.frames / (cpu / cores):.1f} fps if the {cores} cores were ours alone; frame loop "
              f"{1000 * loop_cpu / res.frames:.1f} ms CPU per frame = {res.frames / (loop_cpu / cores):.1f} fps "
              f"(setup {cpu - loop_cpu:.1f} CPU-s; load average now {os.getloadavg()[0]:.1f})")


if __name__ == "__main__":
    main()
