"""A camera measured for hours in one pipeline: does the process's memory stay flat?

Usage:
  .venv/bin/python benchmarks/soak.py [--video ../shared/data/videos/kraten_cars.mp4] [--loops 40]
      [--work /tmp/soak] [--every 5] [--detector vehicleseg|background|MODEL] [--objects]

Plays ``--video`` ``--loops`` times back to back in one pipeline (a segment seek back to the start at each end,
gapless, as a looping player does: the timestamps start again, as when recordings are joined) through the chain
``trafficcal run`` uses, with every per-vehicle output written (events, CSV, BrnoCompSpeed results, the interval
table), all in this process as ``trafficcal run`` runs it.  Every ``--every`` seconds it samples the process's
resident memory (``VmRSS``) with the video played so far and the vehicles written; it prints the samples, the
memory after the first loop (everything loaded, the calibration found) and at the end, and the growth after the
first loop and in the run's second half (the allocator's warm-up over: what keeps growing) per hour of video and per
thousand vehicles (least-squares lines through the samples); and the speed
against real time in the second loop and in the last (a cost that grows with the vehicles slows it down).
"""

from __future__ import annotations

import argparse
import shutil
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def rss_mb() -> float:
    """This process's resident memory (MB) from /proc."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise RuntimeError("no VmRSS in /proc/self/status")


def lines(path: Path) -> int:
    try:
        with path.open("rb") as f:
            return sum(1 for _ in f)
    except FileNotFoundError:
        return 0


def object_counts() -> dict[str, int]:
    """Live Python objects (those the garbage collector tracks) by type, qualified by module."""
    import gc
    from collections import Counter

    gc.collect()
    return Counter(f"{type(o).__module__}.{type(o).__qualname__}" for o in gc.get_objects())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--video", type=Path, default=ROOT.parent / "shared/data/videos/kraten_cars.mp4")
    ap.add_argument("--loops", type=int, default=40)
    ap.add_argument("--work", type=Path, default=Path("/tmp/soak"))
    ap.add_argument("--every", type=float, default=5.0, help="Seconds between memory samples.")
    ap.add_argument("--detector", default="vehicleseg", help="As trafficcal run's --detector (background: MOG2).")
    ap.add_argument("--objects", action="store_true",
                    help="Also count Python objects by type after the first loop and at the end, and print the types "
                         "that grew most (what holds the memory that grows).")
    args = ap.parse_args()
    if not args.video.is_file():
        raise SystemExit(f"{args.video}: no such file")

    from gst_trafficcal.cli.run import model_of, quote
    from gst_trafficcal.gst._gi import Gst
    from gst_trafficcal.gst.runner import ensure_elements

    import gst_trafficcal

    ensure_elements()
    print(f"gst_trafficcal from {Path(gst_trafficcal.__file__).parent}", flush=True)
    shutil.rmtree(args.work, ignore_errors=True)
    args.work.mkdir(parents=True)
    events = args.work / "vehicles.jsonl"
    model = model_of(args.detector)
    det = f"vehicledetect model={quote(model)}" if model else "vehicledetect"
    desc = (f"filesrc location={quote(args.video)} ! decodebin ! videoconvert ! vpdetect ! {det} ! tracker ! bbscale ! "
            f"speedometer events-file={quote(events)} csv-file={quote(args.work / 'vehicles.csv')} "
            f"results-file={quote(args.work / 'system.json')} intervals-file={quote(args.work / 'intervals.csv')} "
            "! fakesink sync=false")
    pipeline = Gst.parse_launch(desc)
    bus = pipeline.get_bus()
    pipeline.set_state(Gst.State.PAUSED)
    if pipeline.get_state(120 * Gst.SECOND)[0] != Gst.StateChangeReturn.SUCCESS:
        raise SystemExit("the pipeline did not preroll")
    duration = pipeline.query_duration(Gst.Format.TIME)[1] / Gst.SECOND
    def loop(flags: Gst.SeekFlags, loops_after: int) -> None:
        """Play the video from its start again; a segment seek (its end a SEGMENT_DONE, not an end-of-stream)
        while more loops follow, a plain one for the last (its end the stream's)."""
        if loops_after > 0:
            flags |= Gst.SeekFlags.SEGMENT
        pipeline.seek(1.0, Gst.Format.TIME, flags, Gst.SeekType.SET, 0, Gst.SeekType.NONE, -1)

    loop(Gst.SeekFlags.FLUSH, args.loops - 1)
    loops_done = 0
    objects_before = None
    samples: list[tuple[float, float, int, float]] = []  # (video s, RSS MB, vehicles, wall s)
    stop = threading.Event()
    t0 = time.perf_counter()

    def position() -> float:
        ok, pos = pipeline.query_position(Gst.Format.TIME)
        return loops_done * duration + (pos / Gst.SECOND if ok and pos >= 0 else 0.0)

    def take(video_s: float) -> None:
        samples.append((video_s, rss_mb(), lines(events), time.perf_counter() - t0))
        v, m, n, w = samples[-1]
        print(f"{w:7.0f} s  video {v / 60:6.1f} min  RSS {m:7.1f} MB  {n:6d} vehicles", flush=True)

    def sample() -> None:
        while not stop.wait(args.every):
            take(position())

    pipeline.set_state(Gst.State.PLAYING)
    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    first_loop = None
    loop_ends = [0.0]  # wall seconds at which each loop's last frame was sent (and the start)
    try:
        while True:
            msg = bus.timed_pop_filtered(Gst.SECOND, Gst.MessageType.ERROR | Gst.MessageType.EOS
                                         | Gst.MessageType.SEGMENT_DONE)
            if msg is None:
                continue
            if msg.type == Gst.MessageType.ERROR:
                err, debug = msg.parse_error()
                raise SystemExit(f"{msg.src.get_name()}: {err.message} {debug or ''}")
            if msg.type == Gst.MessageType.EOS:
                loop_ends.append(time.perf_counter() - t0)
                take(args.loops * duration)
                break
            loops_done += 1
            loop_ends.append(time.perf_counter() - t0)
            take(loops_done * duration)  # a sample at each loop's end, however fast the loops go
            if first_loop is None:
                first_loop = (rss_mb(), lines(events))
                objects_before = object_counts() if args.objects else None
            loop(Gst.SeekFlags.NONE, args.loops - 1 - loops_done)  # gapless: queued before this one drains
    finally:
        stop.set()
        objects_after = object_counts() if args.objects else None
        pipeline.set_state(Gst.State.NULL)
    wall = time.perf_counter() - t0
    end = (rss_mb(), lines(events))
    after = np.array([(v, m, n) for v, m, n, _ in samples if v >= duration])
    print(f"{args.loops} loops of {args.video.name} ({duration:.1f} s): {args.loops * duration / 3600:.2f} h of "
          f"video in {wall / 60:.1f} min, {end[1]} vehicles")
    if first_loop is not None:
        print(f"RSS after the first loop {first_loop[0]:.0f} MB ({first_loop[1]} vehicles), at the end {end[0]:.0f} MB")
    if objects_before is not None and objects_after is not None:
        grown = sorted(((objects_after[k] - objects_before.get(k, 0), k) for k in objects_after), reverse=True)[:15]
        print("Python objects grown since the first loop: " + ", ".join(f"{k} +{n}" for n, k in grown if n > 0))
    speeds = duration / np.diff(loop_ends)  # per loop, against real time
    if args.loops >= 3 and len(speeds) == args.loops:  # the second loop (warmed up) against the last: slower?
        print(f"speed against real time: second loop {speeds[1]:.2f}, last loop {speeds[-1]:.2f}")
    for name, part in (("after the first loop", after), ("in the second half", after[len(after) // 2:])):
        if len(part) < 3:
            continue
        per_h = np.polyfit(part[:, 0] / 3600.0, part[:, 1], 1)[0]
        per_k = np.polyfit(part[:, 2] / 1000.0, part[:, 1], 1)[0] if np.ptp(part[:, 2]) > 0 else float("nan")
        print(f"growth {name}: {per_h:+.1f} MB per hour of video, {per_k:+.2f} MB per 1000 vehicles (least "
              f"squares over {len(part)} samples, {part[0, 1]:.0f} to {part[-1, 1]:.0f} MB)")


if __name__ == "__main__":
    main()
