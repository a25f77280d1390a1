"""Where a traffic count's extra or missing vehicles come from (docs/speedometer.md "Stop 54").

For a rendered scene (synth or replay: video.mp4 + frames.jsonl) this runs ``trafficcal run --no-overlay`` with the
speedometer's ``frames-file`` (every track's box per frame) unless ``--run DIR`` holds such a run already, then
follows each reported vehicle (vehicles.jsonl) frame by frame to the rendered vehicle whose box overlaps its box
most (IoU ≥ 0.2, the one of most of its frames) and sorts the count's error:

* split: one rendered vehicle reported two or more times (a track lost and taken up under a new id, or a second
  track on a piece of a large vehicle);
* follows no rendered vehicle: a false detection (on these scenes the shadow of a truck or van in the next lane);
* a rendered vehicle the benchmark's rule (``end_to_end.passing_vehicles``) leaves out;
* passing, not reported: missed (or merged into another).

    .venv/bin/python benchmarks/count_breakdown.py /tmp/aa_syn/left_side [--run DIR] [--verbose]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from collections import Counter, defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import numpy as np  # noqa: E402
from end_to_end import rule_frames, scene_fps  # noqa: E402

from gst_trafficcal.detection.records import box_iou, clip_boxes  # noqa: E402
from gst_trafficcal.synth.truth_match import vehicle_key  # noqa: E402

RUN_WITH_FRAMES = """
import sys
from gst_trafficcal.cli import main, run as R
_d = R.pipeline_description
def _with_frames(video, paths, *a, **k):
    return _d(video, paths, *a, **k).replace(
        "speedometer ", f"speedometer frames-file={paths.events.parent / 'frames.jsonl'} ", 1)
R.pipeline_description = _with_frames
sys.exit(main(sys.argv[1:]))
"""


def breakdown(scene: Path, run: Path) -> tuple[Counter, list[str], int, int]:
    fps = scene_fps(scene)
    truth: dict[int, dict[tuple, dict]] = defaultdict(dict)
    for line in open(scene / "frames.jsonl"):
        r = json.loads(line)
        truth[r["frame"]][vehicle_key(r)] = r
    tracks: dict[int, dict[int, tuple]] = defaultdict(dict)
    size = (0, 0)
    for line in open(run / "frames.jsonl"):
        fr = json.loads(line)
        size = fr["resolution"]["width"], fr["resolution"]["height"]
        f = int(round(fr["timestamp"] / 1e9 * fps))
        for o in fr["objects"]:
            if "id" in o:
                tracks[o["id"]][f] = (o["x"], o["y"], o["x"] + o["w"], o["y"] + o["h"])
    W, H = size
    events = [json.loads(line) for line in open(run / "vehicles.jsonl")]
    frames_seen = rule_frames(scene / "frames.jsonl", size)  # the benchmark's rule (passing_vehicles)
    passing = {k for k, n in frames_seen.items() if n >= 10}
    follows = {}
    for e in events:
        votes: Counter = Counter()
        for f, box in tracks.get(e["id"], {}).items():
            keys = list(truth.get(f, {}))
            ious = box_iou([box], clip_boxes(np.array([truth[f][k]["box"] for k in keys], np.float64).reshape(-1, 4),
                                             W, H))[0]
            best = int(np.argmax(ious)) if len(keys) else -1
            votes[keys[best] if best >= 0 and ious[best] > 0.2 else None] += 1
        top = votes.most_common(1)
        follows[e["id"]] = top[0][0] if top and top[0][1] >= 0.5 * sum(votes.values()) else None
    by_vehicle = defaultdict(list)
    for eid, k in follows.items():
        by_vehicle[k].append(eid)
    ev = {e["id"]: e for e in events}
    rows: Counter = Counter()
    notes = []

    def said(eid: int) -> str:
        e = ev[eid]
        what = f"{e['speed_kmh']:.0f} km/h" if e["speed_kmh"] is not None else e["reason"][:45]
        return f"#{eid} {e['first_timestamp_s']:.2f}-{e['last_timestamp_s']:.2f} s ({what})"

    for k in sorted(passing, key=str):
        n = len(by_vehicle.get(k, []))
        if n == 0:
            rows["missed"] -= 1
            notes.append(f"missed: rendered {k[0]} ({frames_seen[k]} frames by the rule)")
        elif n > 1:
            rows["split"] += n - 1
            notes.append(f"split: rendered {k[0]} ({k[1]}) as " + "; ".join(said(i) for i in by_vehicle[k]))
    for eid, k in follows.items():
        if k is None:
            rows["no rendered vehicle"] += 1
            notes.append(f"no rendered vehicle: {said(eid)}")
        elif k not in passing:
            rows["left out by the rule"] += 1
            notes.append(f"left out by the rule: {said(eid)} follows rendered {k[0]} ({frames_seen[k]} frames)")
    return rows, notes, len(events), len(passing)


def run_with_frames(video: Path, run: Path) -> None:
    """``trafficcal run VIDEO --out RUN --no-overlay`` with the speedometer's frames-file (RUN/frames.jsonl), unless
    RUN holds one already."""
    if not (run / "frames.jsonl").is_file():
        subprocess.run([sys.executable, "-c", RUN_WITH_FRAMES, "run", str(video), "--out", str(run), "--no-overlay"],
                       check=True, stdout=subprocess.DEVNULL)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="+", type=Path, help="rendered scene folders (video.mp4, frames.jsonl)")
    ap.add_argument("--run", type=Path, help="a finished run with frames.jsonl (one scene only)")
    ap.add_argument("--work", type=Path, help="where the runs go (default: a temporary folder)")
    ap.add_argument("--verbose", action="store_true", help="each split, false detection and missed vehicle")
    a = ap.parse_args()
    work = a.work or Path(tempfile.mkdtemp(prefix="count_breakdown_"))
    print("| scene | reported / passed | split | no rendered vehicle | left out by the rule | missed |")
    print("|---|---|---|---|---|---|")
    for scene in a.scenes:
        run = a.run or work / scene.name
        run_with_frames(scene / "video.mp4", run)
        rows, notes, reported, passed = breakdown(scene, run)
        print(f"| {scene.name} | {reported} / {passed} ({reported - passed:+d}) | {rows['split']} | "
              f"{rows['no rendered vehicle']} | {rows['left out by the rule']} | {rows['missed']} |")
        if a.verbose:
            for n in notes:
                print(f"|   {n} | | | | | |")


if __name__ == "__main__":
    main()
