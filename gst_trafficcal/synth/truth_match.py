"""Measured vehicles against a render's per-frame truth: which rendered vehicle each one is, its speed error,
and its class and size against the rendered vehicle's.

BrnoCompSpeed's matching (:mod:`gst_trafficcal.evaluation`) keeps only cars tracked between its measurement lines;
a render's ``frames.jsonl`` (reference point, speed, class and size of every vehicle in every frame) scores every
measured vehicle.  Used by ``trafficcal demo`` and ``benchmarks/end_to_end.py``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..brnocompspeed import Results
from ..outputs import VehicleEvent
from ..vehicles.classify import LABEL_OF_STYLE
from .groundtruth import read_jsonl


@dataclass(frozen=True)
class TruthMatch:
    """One measured vehicle and the rendered vehicle its reference points follow."""

    vehicle_id: int
    rendered_id: int
    speed_error_kmh: float  # measured − rendered (median over the frames they share)
    rendered_class: str  # the rendered body style as a label (vehicles.classify.LABEL_OF_STYLE)
    label: str  # the label the vehicle was reported with
    rendered_size: tuple[float, float, float]  # length, width, height (m)
    size: tuple[float, float, float] | None  # the reported ones, None when none was reported


def vehicle_key(r: dict) -> tuple:
    """A rendered vehicle of a frames.jsonl record: its id with its model, lane and direction (a replay's ids are the
    recording's car ids, and BrnoCompSpeed's session0_center gives one id to two or three cars: ids 11 and 25)."""
    return r["id"], r.get("model"), r.get("lane"), r.get("direction")


def match_measured(frames_jsonl: str | Path, events: Sequence[VehicleEvent], results: Results,
                   image_size: tuple[int, int], max_distance: float = 0.05) -> list[TruthMatch]:
    """Every measured vehicle whose BrnoCompSpeed track (``results``: its reference points and frames) follows a
    rendered vehicle: the median distance between their reference points over the frames they share below
    ``max_distance`` of the image width, and at least half of the track's frames shared.  Unmatched vehicles are
    left out (the evaluator counts them as false positives).  Empty without a ``frames.jsonl``."""
    path = Path(frames_jsonl)
    if not path.is_file():
        return []
    truth: dict[tuple, dict[int, tuple[float, float, float]]] = {}  # by vehicle_key: ids may repeat
    about: dict[tuple, tuple[str, tuple[float, float, float]]] = {}
    for r in read_jsonl(path):
        key = vehicle_key(r)
        truth.setdefault(key, {})[int(r["frame"])] = (*r["ref"], float(r["speed_kmh"]))
        style = str(r.get("class", ""))
        about[key] = (LABEL_OF_STYLE.get(style, style), tuple(float(v) for v in r.get("size", (np.nan,) * 3)))
    tracks = {t.id: t for t in results.cars}
    out = []
    for e in events:
        tr = tracks.get(e.id)
        if not e.measured or tr is None:
            continue
        frames = np.round(tr.frames).astype(int)
        best, best_key, best_speed = max_distance * image_size[0], None, 0.0
        for key, recs in truth.items():
            common = [(k, f) for k, f in enumerate(frames) if f in recs]
            if len(common) < max(2, len(frames) // 2):
                continue
            ref = np.array([recs[f] for _, f in common])
            d = float(np.median(np.hypot(*(ref[:, :2] - tr.pos[[k for k, _ in common]]).T)))
            if d < best:
                best, best_key, best_speed = d, key, float(np.median(ref[:, 2]))
        if best_key is not None:
            size = (e.length_m, e.width_m, e.height_m)
            out.append(TruthMatch(e.id, int(best_key[0]), e.speed_kmh - best_speed, about[best_key][0], e.label,
                                  about[best_key][1], None if any(v is None for v in size) else size))
    return out


def label_accuracy(matches: Sequence[TruthMatch]) -> float | None:
    """Share of the matched vehicles reported with their rendered class (None without any)."""
    return sum(m.label == m.rendered_class for m in matches) / len(matches) if matches else None
