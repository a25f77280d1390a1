"""What a long run's BrnoCompSpeed results file (``system.json``) costs: memory per vehicle, file size, the time
to rewrite it and the memory the rewrite takes on top; and what the interval table (``intervals.csv``) holds per
vehicle.

Usage:
  .venv/bin/python benchmarks/results_file.py [--vehicles 25000] [--points 80] [--out /tmp/system.json]

``--vehicles`` vehicles of ``--points`` reference points each (a vehicle seen for about 3 s at 25 fps; 25 000 is
a busy camera's day) are collected by ``outputs.BrnoResultsWriter`` as speedometer collects them, then written
once as its checkpoints do (atomically, synced).  Memory is the process's peak resident size (``ru_maxrss``)
before and after the write, so the rewrite's extra memory is their difference.  The interval table's memory is
``tracemalloc``'s count of what ``traffic_stats.IntervalTable`` holds after as many vehicles' events.
"""

from __future__ import annotations

import argparse
import resource
import time
import tracemalloc
from pathlib import Path

import numpy as np

from gst_trafficcal.outputs import BrnoResultsWriter, VehicleEvent
from gst_trafficcal.traffic_stats import IntervalTable


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--vehicles", type=int, default=25000)
    parser.add_argument("--points", type=int, default=80)
    parser.add_argument("--out", type=Path, default=Path("/tmp/system.json"))
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    start = peak_mb()
    writer = BrnoResultsWriter(args.out, 25.0)
    for i in range(args.vehicles):
        t = 3.2 * i + np.arange(args.points) / 25.0
        writer.add(i + 1, t, rng.uniform(0, 1920, (args.points, 2)))
    held = peak_mb()
    t0 = time.perf_counter()
    writer.write(None)
    took = time.perf_counter() - t0
    after = peak_mb()
    size = args.out.stat().st_size
    print(f"{args.vehicles} vehicles of {args.points} points: held in memory {held - start:.0f} MB "
          f"({(held - start) * 1024 / args.vehicles:.1f} kB a vehicle); file {size / 1e6:.0f} MB written in "
          f"{took:.1f} s; the write's extra memory {after - held:.0f} MB")
    tracemalloc.start()
    table = IntervalTable(args.out.with_name("intervals.csv"))
    for i in range(args.vehicles):
        t = 3.2 * i
        table.vehicle(VehicleEvent(i + 1, "car", t, t + 3.0, 80.0 + i % 20, lane=i % 3, direction="towards_vp1",
                                   calibration_id="0123456789ab", n_samples=60, length_m=4.5, width_m=1.8,
                                   height_m=1.5, first_time=f"2026-12-05T08:00:00.{i % 1000:03d}+01:00",
                                   last_time=f"2026-12-05T08:00:03.{i % 1000:03d}+01:00"))  # a string each
    table_bytes = tracemalloc.get_traced_memory()[0]
    tracemalloc.stop()
    print(f"the interval table holds {table_bytes / 2**20:.0f} MB for them ({table_bytes / 1024 / args.vehicles:.2f} "
          "kB a vehicle)")


if __name__ == "__main__":
    main()
