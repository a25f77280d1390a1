"""The class a vehicle shows while in view against the one it is reported with, and how sure the motorcycles are
(docs/tracking.md "Vehicle classes", stop 57).

For a video this runs ``trafficcal run --no-overlay`` with the speedometer's ``frames-file`` (as count_breakdown
does) unless ``--run DIR`` holds such a run already, then counts the frames in which a vehicle's live ``"speed"``
class differs from its final label, lists those vehicles, the final classes, and each vehicle whose dimensions
some class explains best as a motorcycle with that class's likelihood margin (``vehicles.classify``; a
motorcycle is claimed at ``MOTORCYCLE_MARGIN``).  ``--draws N``: how many of N motorcycles drawn from the
catalogue's distribution with the measurement noise keep their class.

    .venv/bin/python benchmarks/live_classes.py ../shared/data/videos/kraten_cars.mp4 [--run DIR] [--draws 20000]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from count_breakdown import run_with_frames  # noqa: E402

from gst_trafficcal.outputs import read_events  # noqa: E402
from gst_trafficcal.vehicles.classify import (  # noqa: E402
    MEASUREMENT_NOISE, MOTORCYCLE_MARGIN, classify_dimensions, refined_label,
)


def live_classes(frames_jsonl: Path) -> dict[int, Counter]:
    """Per track id, the frames in which it carried each live class (its ``"speed"`` structure's label)."""
    live: dict[int, Counter] = defaultdict(Counter)
    with frames_jsonl.open() as f:
        for line in f:
            for o in json.loads(line)["objects"]:
                if o.get("speed"):
                    live[o["id"]][o["speed"].get("label", "")] += 1
    return live


def kept_share(draws: int, seed: int = 0) -> float:
    """Share of ``draws`` motorcycles from the catalogue's distribution, measured with the classifier's noise,
    that are reported as motorcycles."""
    from gst_trafficcal.vehicles.catalogue import style_distributions

    dist = style_distributions()["motorcycle"]
    rng = np.random.default_rng(seed)
    true = np.exp(np.log(dist.mean) + rng.normal(size=(draws, 3)) * np.asarray(dist.std) / np.asarray(dist.mean))
    measured = true * np.exp(rng.normal(size=true.shape) * np.asarray(MEASUREMENT_NOISE))
    return float(np.mean([refined_label("car", c) == "motorcycle" for c in classify_dimensions(measured)]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("video", type=Path)
    ap.add_argument("--run", type=Path, help="where the run goes, or a finished run with frames.jsonl")
    ap.add_argument("--draws", type=int, default=0, help="also the catalogue motorcycles' share kept (N draws)")
    a = ap.parse_args()
    run = a.run or Path(tempfile.mkdtemp(prefix="live_classes_"))
    run_with_frames(a.video, run)
    events = {e.id: e for e in read_events(run / "vehicles.jsonl").events}
    live = live_classes(run / "frames.jsonl")
    frames = other = 0
    for vid, seen in sorted(live.items()):
        if vid not in events:
            continue
        final = events[vid].label
        frames += sum(seen.values())
        wrong = sum(n for label, n in seen.items() if label != final)
        other += wrong
        if wrong:
            print(f"#{vid} reported {final}, shown {dict(seen)}")
    print(f"{len([v for v in live if v in events])} vehicles with a live class; frames showing another class than "
          f"the vehicle's final one: {other} of {frames}")
    print("final classes:", dict(Counter(e.label for e in events.values()).most_common()))
    for e in events.values():
        if e.length_m and e.width_m and e.height_m:
            (c,) = classify_dimensions([[e.length_m, e.width_m, e.height_m]])
            if c.label == "motorcycle":
                print(f"#{e.id} {e.length_m:.2f} x {e.width_m:.2f} x {e.height_m:.2f} m: motorcycle by a margin of "
                      f"{c.margin:.1f} (claimed at {MOTORCYCLE_MARGIN:g}), reported {e.label}")
    if a.draws:
        print(f"catalogue motorcycles reported as motorcycles: {kept_share(a.draws):.4f} of {a.draws}")


if __name__ == "__main__":
    main()
