"""Does vpdetect's mid-stream camera check (``vanishing.view.ViewMonitor``) notice moves, and only moves?

Usage:
  .venv/bin/python benchmarks/view_monitor.py VIDEO... [--learn 20] [--width 640]

Per video: the calibration's view is taken as vpdetect keeps it (the median thumbnail of every 5th frame of the
first ``--learn`` seconds, at most the last 60), then the monitor watches the rest, sampling five frames a second
as the element does:

* unchanged — every event is a false alarm (and the lowest and median correlation of its window say how close
  the video came to one);
* changed from the middle of the watched part on — shifted by 2 % of the width, zoomed by 2 %, rolled by 1°
  (the camera knocked or re-aimed): when the move was dated against when it happened (negative = early, as
  intended) and how long after it was noticed.

Then the views seen before (``ViewLibrary``, what vpdetect uses to take a PTZ preset's calibration up again): a
library of every video's learnt view; once a second, the median of the latest nine samples of each video is looked
up in it — found as itself (right), as another video's view (a wrong calibration: must never happen), or as none —
and the same for the video shifted by 2 % from the start (a view the library does not have: must be none).

Frames are read once, reduced to ``--width`` pixels (the monitor's thumbnail is 160 px wide, so this changes
nothing it sees) and the changes applied to them.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from gst_trafficcal.vanishing.view import ViewAccumulator, ViewLibrary, ViewMonitor

CHANGES = {
    "shift 2 %": lambda img: cv2.warpAffine(img, np.float32([[1, 0, 0.02 * img.shape[1]], [0, 1, 0]]),
                                            img.shape[::-1], borderMode=cv2.BORDER_REFLECT),
    "zoom 2 %": lambda img: cv2.warpAffine(img, cv2.getRotationMatrix2D((img.shape[1] / 2, img.shape[0] / 2), 0,
                                                                        1.02), img.shape[::-1]),
    "roll 1°": lambda img: cv2.warpAffine(img, cv2.getRotationMatrix2D((img.shape[1] / 2, img.shape[0] / 2), 1.0,
                                                                       1.0), img.shape[::-1]),
}


@dataclass
class Samples:
    """The frames the monitor would read (every ``every``-th), reduced, with their times; the learnt view."""

    view: np.ndarray
    width: int
    every: int
    times: list[float]
    frames: list[np.ndarray]


def read(video: Path, learn_s: float, width: int) -> Samples:
    cap = cv2.VideoCapture(str(video))
    if not cap.isOpened():
        raise SystemExit(f"{video}: cannot be read as a video")
    fps = cap.get(cv2.CAP_PROP_FPS) or 25.0
    every = max(1, round(fps / 5))  # as vpdetect: five comparisons a second
    learnt = ViewAccumulator(keep=60)
    times, frames, i = [], [], 0
    while cap.grab():
        t = i / fps
        learning = t < learn_s
        if (learning and learnt.wants()) or (not learning and i % every == 0):
            ok, bgr = cap.retrieve()
            if not ok:
                break
            grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
            grey = cv2.resize(grey, (width, round(width * grey.shape[0] / grey.shape[1])), interpolation=cv2.INTER_AREA)
            if learning:
                learnt.add(grey)
            else:
                times.append(t)
                frames.append(grey)
        elif learning:
            learnt.skip()
        i += 1
    cap.release()
    if learnt.view() is None or not frames:
        raise SystemExit(f"{video}: shorter than --learn {learn_s:g} s plus a few seconds to watch")
    return Samples(learnt.view(), width, every, times, frames)


def watch(s: Samples, change=None, at: float | None = None) -> tuple[list, list[float]]:
    """[(event, time noticed)], and the window correlations, over the samples (changed from ``at`` on)."""
    monitor = ViewMonitor(s.view, s.width, every=1)  # the samples are already every ``s.every``-th frame
    events, sims = [], []
    for t, img in zip(s.times, s.frames):
        e = monitor.add(change(img) if change is not None and t >= at else img, t)
        if monitor.last is not None:
            sims.append(monitor.last.similarity)
        if e is not None:
            events.append((e, t))
    return events, sims


def window_views(s: Samples, change=None, step: int = 5, window: int = 9) -> list[np.ndarray]:
    """The monitor's window median (``window`` samples) every ``step`` samples (once a second), ``change`` applied
    to every frame."""
    acc, out = ViewAccumulator(every=1, keep=window), []
    for k, img in enumerate(s.frames):
        acc.add(change(img) if change is not None else img)
        if acc.count >= window and k % step == 0:
            out.append(acc.view())
    return out


def recognition(views: dict[str, tuple[np.ndarray, int]], streams: dict[str, list[np.ndarray]]) -> dict[str, dict]:
    """Per stream: how many of its window medians the library of ``views`` finds as ``itself``, as ``other`` (another
    video's view) or as ``none``."""
    library = ViewLibrary()
    for name, (view, width) in views.items():
        library.add(name, view, width)
    out = {}
    for name, medians in streams.items():
        counts = {"itself": 0, "other": 0, "none": 0}
        for m in medians:
            found = library.find(m)
            counts["none" if found is None else "itself" if found[0] == name else "other"] += 1
        out[name] = counts
    return out


def measure(video: Path, learn_s: float = 20.0, width: int = 640, samples: Samples | None = None) -> dict:
    """The figures of one video (see the module doc)."""
    s = samples or read(video, learn_s, width)
    events, sims = watch(s)
    at = s.times[len(s.times) // 2]
    row = {"video": video.parent.name if video.name == "video.mp4" else video.name,
           "watched_s": s.times[-1] - s.times[0], "false_events": [e.kind for e, _ in events],
           "min_sim": min(sims) if sims else None, "median_sim": float(np.median(sims)) if sims else None}
    for name, change in CHANGES.items():
        found, _ = watch(s, change, at)
        moved = [(e, t) for e, t in found if e.kind == "moved"]
        row[name] = (moved[0][0].t - at, moved[0][1] - at) if moved else None
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("videos", nargs="+", type=Path)
    ap.add_argument("--learn", type=float, default=20.0, help="seconds the view is learnt from (vpdetect: until it "
                                                              "converges, 20 s at the least)")
    ap.add_argument("--width", type=int, default=640, help="frames reduced to this width first")
    args = ap.parse_args()
    views, plain, shifted = {}, {}, {}
    print(f"{'video':34s} {'watched':>8s} {'false':>6s} {'min/med sim':>12s}  " +
          "  ".join(f"{n + ' dated/noticed s':>26s}" for n in CHANGES))
    false, delays = 0, []
    for video in args.videos:
        s = read(video, args.learn, args.width)
        r = measure(video, args.learn, args.width, samples=s)
        key = f"{len(views)}:{r['video']}"
        views[key] = (s.view, s.width)
        plain[key], shifted[key] = window_views(s), window_views(s, CHANGES["shift 2 %"])
        false += len(r["false_events"])
        cells = []
        for name in CHANGES:
            if r[name] is None:
                cells.append(f"{'not noticed':>26s}")
            else:
                cells.append(f"{r[name][0]:+13.2f} / {r[name][1]:10.2f}")
                delays.append(r[name][1])
        sim = "–" if r["min_sim"] is None else f"{r['min_sim']:.2f}/{r['median_sim']:.2f}"
        print(f"{r['video'][:34]:34s} {r['watched_s']:7.0f}s {len(r['false_events']):6d} {sim:>12s}  " +
              "  ".join(cells), flush=True)
    noticed = f"{min(delays):.2f}–{max(delays):.2f} s" if delays else "none"
    print(f"\n{len(args.videos)} videos: {false} false events; moves noticed {noticed} after they happened "
          f"({len(delays)} of {len(args.videos) * len(CHANGES)})")
    seen, moved = recognition(views, plain), recognition(views, shifted)
    print(f"\nviews seen before (a library of the {len(views)} videos' views; a window median once a second):")
    print(f"{'video':34s} {'as is: itself / other / none':>30s} {'shifted 2 %: itself / other / none':>36s}")
    for key in views:
        a, b = seen[key], moved[key]
        print(f"{key.split(':', 1)[1][:34]:34s} {a['itself']:>16d} / {a['other']:5d} / {a['none']:4d} "
              f"{b['itself']:>22d} / {b['other']:5d} / {b['none']:4d}")
    total = {k: sum(c[k] for c in seen.values()) for k in ("itself", "other", "none")}
    wrong = sum(c["other"] + c["itself"] for c in moved.values())
    print(f"as is: {total['itself']} of {sum(total.values())} medians found as their own view, {total['other']} as "
          f"another's; shifted: {wrong} of {sum(sum(c.values()) for c in moved.values())} taken for a known view")


if __name__ == "__main__":
    main()
