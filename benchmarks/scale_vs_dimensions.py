"""Does a scene's scale error show in the sizes it measures?  Per scene of an end-to-end run: the λ error against the
median length, width and height of its measured cars (what a scene could estimate itself) and against the rendered
ones; and the λ error left after a linear correction by each median, fitted on the other scenes (leave-one-out).

    .venv/bin/python benchmarks/end_to_end.py ... --modes auto --work W --json W.json
    .venv/bin/python benchmarks/scale_vs_dimensions.py W.json W

Stop 57's answer: docs/bbscale_streaming.md "Stop 57".
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from scipy.stats import pearsonr, spearmanr

from gst_trafficcal.outputs import read_events


def scene_rows(rows: list[dict], work: Path) -> list[tuple[str, float, float, np.ndarray, np.ndarray]]:
    """(scene, λ err %, road err %, median log measured L W H of its measured cars, median log(measured / rendered))
    of every fully automatic run with a scale error."""
    out = []
    for r in rows:
        if r["mode"] != "auto" or r["scale_err_pct"] is None:
            continue
        events = read_events(work / r["scene"] / "auto" / "vehicles.jsonl").events
        cars = np.array([(e.length_m, e.width_m, e.height_m) for e in events
                         if e.label == "car" and e.length_m and e.measured])
        own = np.median(np.log(cars), axis=0) if len(cars) else np.full(3, np.nan)
        rel = np.median(np.array(r["dims_log_ratio"]), axis=0) if r["dims_log_ratio"] else np.full(3, np.nan)
        out.append((r["scene"], float(r["scale_err_pct"]), float(r["road_err_pct"]), own, rel))
    return out


def leave_one_out(err: np.ndarray, x: np.ndarray) -> np.ndarray:
    """λ errors (%) after subtracting a line in ``x`` fitted on the other scenes (its mean kept: only the part that
    varies with ``x`` is taken out)."""
    left = []
    for i in range(len(err)):
        m = np.arange(len(err)) != i
        line = np.polyfit(x[m], err[m], 1)
        left.append(err[i] - np.polyval(line, x[i]) + np.mean(err[m] - np.polyval(line, x[m])))
    return np.array(left)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("json", type=Path, help="end_to_end.py --json")
    ap.add_argument("work", type=Path, help="end_to_end.py --work (the runs' vehicles.jsonl)")
    a = ap.parse_args()
    rows = scene_rows(json.loads(a.json.read_text())["rows"], a.work)
    for scene, lam, road, own, rel in rows:
        print(f"{scene:40s} λ {lam:+5.2f} % road {road:+5.2f} %  median car L W H {np.exp(own).round(2)} m, "
              f"log(measured / rendered) {rel.round(3)}")
    lam = np.array([r[1] for r in rows])
    for k, name in enumerate(("length", "width", "height")):
        own = np.array([r[3][k] for r in rows])
        rel = np.array([r[4][k] for r in rows])
        ok = np.isfinite(own)
        left = np.abs(leave_one_out(lam[ok], own[ok] * 100))
        print(f"{name}: λ err against the scene's median, Pearson {pearsonr(lam[ok], own[ok])[0]:+.2f} Spearman "
              f"{spearmanr(lam[ok], own[ok])[0]:+.2f}; against the rendered, Pearson "
              f"{pearsonr(lam[ok], rel[ok])[0]:+.2f}; corrected by it (leave-one-out) |λ err| median / mean "
              f"{np.median(left):.2f} / {np.mean(left):.2f} % (as measured {np.median(np.abs(lam[ok])):.2f} / "
              f"{np.mean(np.abs(lam[ok])):.2f} %)")


if __name__ == "__main__":
    main()
