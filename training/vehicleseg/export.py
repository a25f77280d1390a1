"""Export a trained checkpoint to the ONNX file the product ships (opset 17, dynamic height and width).

    .venv/bin/python -m training.vehicleseg.export --checkpoint /tmp/vseg_run/final.pt \
        --out gst_trafficcal/detection/weights/vehicleseg.onnx

The file's metadata names it (``gst_trafficcal_model`` = vehicleseg, so ``vehicledetect model=PATH`` recognises
it) and carries the run-time input settings it was trained with (work width, background time constant).
"""

from __future__ import annotations

import argparse
import collections
import hashlib
import json
import subprocess
import sys
from pathlib import Path

import onnx
import torch

from .model import VehicleSegNet

WORK_WIDTH = 480
TAU = 2.0


def export(checkpoint: Path, out: Path, meta: dict[str, str] | None = None) -> None:
    state = torch.load(checkpoint, map_location="cpu")
    model = VehicleSegNet()
    model.load_state_dict(state["model"])
    model.eval()
    x = torch.zeros(1, 6, 272, WORK_WIDTH)
    out.parent.mkdir(parents=True, exist_ok=True)
    torch.onnx.export(model, x, str(out), opset_version=17, input_names=["input"],
                      output_names=["mask", "centre", "offset"],
                      dynamic_axes={"input": {2: "height", 3: "width"}, "mask": {2: "height", 3: "width"},
                                    "centre": {2: "h4", 3: "w4"}, "offset": {2: "h4", 3: "w4"}}, dynamo=False)
    m = onnx.load(str(out))
    props = {"gst_trafficcal_model": "vehicleseg", "work_width": str(WORK_WIDTH), "tau": str(TAU),
             "inputs": "frame BGR + running-average background BGR, /255 - 0.5, sides multiples of 16",
             **(meta or {})}
    del m.metadata_props[:]
    for k, v in props.items():
        m.metadata_props.add(key=k, value=v)
    m.producer_name = "gst-trafficcal training/vehicleseg"
    onnx.checker.check_model(m)
    onnx.save(m, str(out))


def card(out: Path, data: Path | list[Path], logs: list[Path], commands: list[str]) -> dict:
    """The model card's measured facts: file, code version, data recipe (from the data folders' scene records) and
    the training logs' last validation figures."""
    folders = [data] if isinstance(data, Path) else data
    scenes = [json.loads(p.read_text()) for f in folders for p in sorted(f.glob("scene_*.json"))]
    seeds = [s["seed"] for s in scenes]
    count = collections.Counter
    meta = {p.key: p.value for p in onnx.load(str(out)).metadata_props}  # --meta work_width=N overrides the default
    commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                            cwd=Path(__file__).resolve().parent).stdout.strip()
    stages = []
    for log in logs:
        recs = [json.loads(line) for line in log.read_text().splitlines() if line.strip()]
        last_val = next((r for r in reversed(recs) if "val" in r), {})
        stages.append({"log": str(log), "steps": recs[-1]["step"] if recs else 0,
                       "cpu_seconds": recs[-1].get("cpu") if recs else None,
                       "validation": last_val.get("val", {})})
    return {
        "model": out.name, "bytes": out.stat().st_size, "sha256": hashlib.sha256(out.read_bytes()).hexdigest(),
        "git_commit_at_export": commit, "torch": torch.__version__, "opset": 17,
        "input": {"work_width": int(meta.get("work_width", WORK_WIDTH)),
                  "background_tau_s": float(meta.get("tau", TAU)),
                  "channels": "frame BGR + running-average background BGR, x/255 - 0.5"},
        "outputs": {"mask": "vehicle logit per work pixel", "centre": "instance-centre logit at 1/4",
                    "offset": "(dx, dy) to the instance centre at 1/4, in 1/4 cells"},
        "commands": commands,
        "data": {"scenes": len(scenes), "samples": sum(s["samples"] for s in scenes),
                 "seeds": [min(seeds), max(seeds)] if seeds else [],
                 "bases": dict(count(s["base"] for s in scenes)),
                 "lighting": dict(count(s["scenario"]["lighting"]["preset"] for s in scenes)),
                 "resolutions": dict(count("x".join(map(str, s["scenario"]["camera"]["resolution"])) for s in scenes)),
                 "jpeg": sum(1 for s in scenes if s["jpeg_quality"]),
                 "profiles": dict(count(s.get("profile", "base") for s in scenes)),
                 "surfaces": dict(count(s.get("surface", "asphalt") for s in scenes)),
                 "road_grey_110_190": sum(1 for s in scenes if 110 <= (s.get("road_grey") or 0) <= 190),
                 "validation": "scenes whose index ends in 9",
                 "never used": "benchmark seeds 1, 2, 7; BrnoCompSpeed replays (screen.png backgrounds)"},
        "training": stages,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--checkpoint", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--meta", action="append", default=[], help="KEY=VALUE metadata to add (repeatable)")
    ap.add_argument("--card", type=Path, default=None, help="also write the model card (JSON) here")
    ap.add_argument("--data", type=Path, nargs="+", default=None, help="the training data folders (for the card)")
    ap.add_argument("--log", type=Path, action="append", default=[], help="training log.jsonl (for the card)")
    ap.add_argument("--command", action="append", default=[], help="a command that made the model (for the card)")
    args = ap.parse_args(argv)
    export(args.checkpoint, args.out, dict(kv.split("=", 1) for kv in args.meta))
    print(f"{args.out}: {args.out.stat().st_size} bytes")
    if args.card is not None:
        info = card(args.out, args.data or [Path(".")], args.log, args.command)
        if args.card.exists():  # keep what was measured with the model (held-out figures) when re-exporting
            old = json.loads(args.card.read_text())
            if old.get("sha256") == info["sha256"]:
                info = {**old, **info}
        args.card.write_text(json.dumps(info, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
