"""Train the vehicle segmenter on samples from ``training.vehicleseg.data`` (CPU, PyTorch).

    nice -n 5 .venv/bin/python -m training.vehicleseg.train --data /tmp/vseg_data --out /tmp/vseg_run

Losses: mask — binary cross-entropy against the vehicle fraction of each work pixel (pixels that changed against the
background but are no vehicle — cast shadows, headlight beams, ghosts — weigh 3x, faint changes next to a vehicle
that are no vehicle — soft and contact shadows — 6x, the outline 2x: ``targets.mask_weights``) plus a soft Dice term;
centre — CenterNet's penalty-reduced focal loss on the 1/4-resolution heatmap; offset — smooth L1 to the
instance centre on vehicle cells.  Scenes whose index ends in 9 (every tenth) are the validation set.  The folder
is re-scanned every ``--rescan`` steps so training can start while the data is still being rendered.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from .model import VehicleSegNet
from .targets import BOUNDARY_WEIGHT, SHADOW_WEIGHT, make_sample

SCENE = re.compile(r"s(\d{5,})_\d{4}\.npz$")  # redrawn scenes have index + 100000 (six digits)


def split_files(folders: Path | list[Path]) -> tuple[list[Path], list[Path]]:
    """(training, validation) sample files of one or several folders; validation = scenes whose index ends in 9."""
    train, val = [], []
    for folder in [folders] if isinstance(folders, Path) else folders:
        for p in sorted(folder.glob("s*_*.npz")):
            m = SCENE.search(p.name)
            if m:
                (val if int(m.group(1)) % 10 == 9 else train).append(p)
    return train, val


def load(path: Path) -> dict:
    with np.load(path) as d:
        return {k: d[k] for k in ("frame", "background", "fg", "inst")}


def batch(files: list[Path], crop: tuple[int, int], rng: np.random.Generator, augment: bool = True,
          **weights: float) -> dict:
    """A training batch of random crops (``weights``: :func:`targets.make_sample`'s loss weights)."""
    samples = [make_sample(load(f), crop, rng, augment, **weights) for f in files]
    out = {k: torch.from_numpy(np.stack([getattr(s, k) for s in samples])) for k in
           ("x", "fg", "fg_w", "heat", "offset", "off_w")}
    out["x"] = out["x"].contiguous(memory_format=torch.channels_last)
    return out


def losses(model: torch.nn.Module, b: dict) -> dict[str, torch.Tensor]:
    mask, centre, offset = model(b["x"])
    mask, centre = mask[:, 0], centre[:, 0]
    w = b["fg_w"]
    bce = (F.binary_cross_entropy_with_logits(mask, b["fg"], reduction="none") * w).sum() / w.sum().clamp(min=1)
    valid = (w > 0).float()
    p = torch.sigmoid(mask) * valid
    dice = 1 - (2 * (p * b["fg"]).sum((1, 2)) + 1) / (p.sum((1, 2)) + (b["fg"] * valid).sum((1, 2)) + 1)
    hp = torch.sigmoid(centre).clamp(1e-4, 1 - 1e-4)
    pos = (b["heat"] >= 1.0).float()
    focal = -(pos * (1 - hp) ** 2 * torch.log(hp) +
              (1 - pos) * (1 - b["heat"]) ** 4 * hp ** 2 * torch.log(1 - hp)).sum() / pos.sum().clamp(min=1)
    ow = b["off_w"]
    off = (F.smooth_l1_loss(offset, b["offset"], reduction="none").sum(1) * ow).sum() / ow.sum().clamp(min=1)
    return {"bce": bce, "dice": dice.mean(), "centre": focal, "offset": off}


def total(parts: dict[str, torch.Tensor]) -> torch.Tensor:
    return parts["bce"] + parts["dice"] + parts["centre"] + 0.2 * parts["offset"]


def train_mode(model: torch.nn.Module, freeze_bn: bool = False) -> None:
    """Training mode; ``freeze_bn`` keeps the BatchNorms on their running statistics (eval mode), as for
    fine-tuning with small batches a model whose statistics are settled (e.g. imported by ``from_onnx``)."""
    model.train()
    if freeze_bn:
        for m in model.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.eval()


@torch.no_grad()
def validate(model: torch.nn.Module, files: list[Path], crop: tuple[int, int], freeze_bn: bool = False,
             **weights: float) -> dict[str, float]:
    """Loss parts and mask IoU (threshold 0.5) over the validation files, one fixed crop each."""
    model.eval()
    rng = np.random.default_rng(0)
    acc: dict[str, float] = {}
    inter = union = 0.0
    for i in range(0, len(files), 8):
        b = batch(files[i:i + 8], crop, rng, augment=False, **weights)
        for k, v in losses(model, b).items():
            acc[k] = acc.get(k, 0.0) + float(v) * len(files[i:i + 8])
        pred = model(b["x"])[0][:, 0] > 0
        true = b["fg"] > 0.5
        valid = b["fg_w"] > 0
        inter += float((pred & true & valid).sum())
        union += float(((pred | true) & valid).sum())
    train_mode(model, freeze_bn)
    out = {k: v / max(len(files), 1) for k, v in acc.items()}
    out["mask_iou"] = inter / max(union, 1.0)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, nargs="+", required=True, help="sample folders")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--batch", type=int, default=6)
    ap.add_argument("--crop", default="192x320", help="HEIGHTxWIDTH of the training crops (multiples of 16)")
    ap.add_argument("--lr", type=float, default=3e-3)
    ap.add_argument("--threads", type=int, default=1, help="torch threads (1 is the most work per CPU second here)")
    ap.add_argument("--rescan", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--resume", type=Path, default=None, help="checkpoint to continue from (weights, optimiser, step)")
    ap.add_argument("--init", type=Path, default=None, help="start from these weights with a fresh schedule")
    ap.add_argument("--shadow-weight", type=float, default=SHADOW_WEIGHT,
                    help="mask-loss weight of faint changes next to vehicles (0: off, the first model's loss)")
    ap.add_argument("--boundary-weight", type=float, default=BOUNDARY_WEIGHT,
                    help="mask-loss weight of outline pixels (1: off, the first model's loss)")
    ap.add_argument("--freeze-bn", action="store_true",
                    help="keep the BatchNorms' running statistics (fine-tuning an imported export, train_mode)")
    args = ap.parse_args(argv)
    weights = {"shadow_weight": args.shadow_weight, "boundary_weight": args.boundary_weight}
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    crop = tuple(int(v) for v in args.crop.lower().split("x"))
    args.out.mkdir(parents=True, exist_ok=True)
    model = VehicleSegNet().to(memory_format=torch.channels_last)
    opt = torch.optim.AdamW(model.parameters(), lr=args.lr, weight_decay=1e-4)
    start = 0
    if args.init is not None:
        model.load_state_dict(torch.load(args.init, map_location="cpu")["model"])
    if args.resume is not None:
        state = torch.load(args.resume, map_location="cpu")
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["opt"])
        start = int(state["step"])
    train_mode(model, args.freeze_bn)
    log = open(args.out / "log.jsonl", "a", encoding="utf-8")
    train_files, val_files = split_files(args.data)
    t0, c0 = time.perf_counter(), time.process_time()
    running: dict[str, float] = {}
    for step in range(start, args.steps):
        if step % args.rescan == 0:
            train_files, val_files = split_files(args.data)
        warm = min(1.0, (step + 1) / 50)
        lr = args.lr * warm * 0.5 * (1 + math.cos(math.pi * step / args.steps))
        for g in opt.param_groups:
            g["lr"] = lr
        pick = rng.choice(len(train_files), size=args.batch, replace=len(train_files) < args.batch)
        parts = losses(model, batch([train_files[i] for i in pick], crop, rng, **weights))
        loss = total(parts)
        opt.zero_grad()
        loss.backward()
        opt.step()
        for k, v in parts.items():
            v = float(v.detach())
            running[k] = 0.95 * running.get(k, v) + 0.05 * v
        if (step + 1) % 25 == 0 or step + 1 == args.steps:
            rec = {"step": step + 1, "lr": lr, "train": {k: round(v, 4) for k, v in running.items()},
                   "files": len(train_files), "wall": round(time.perf_counter() - t0), "cpu": round(time.process_time() - c0)}
            if (step + 1) % 250 == 0 or step + 1 == args.steps:
                val = validate(model, val_files[::4], crop, args.freeze_bn, **weights)
                rec["val"] = {k: round(v, 4) for k, v in val.items()}
                torch.save({"model": model.state_dict(), "opt": opt.state_dict(), "step": step + 1},
                           args.out / "checkpoint.pt")
            log.write(json.dumps(rec) + "\n")
            log.flush()
            print(json.dumps(rec), flush=True)
    torch.save({"model": model.state_dict(), "step": args.steps}, args.out / "final.pt")
    return 0


if __name__ == "__main__":
    sys.exit(main())
