"""A training checkpoint from a shipped ONNX export, to fine-tune a model whose PyTorch checkpoint is gone.

    .venv/bin/python -m training.vehicleseg.from_onnx --onnx gst_trafficcal/detection/weights/vehicleseg.onnx \
        --data /tmp/vseg_data --out /tmp/vseg_shipped.pt

The export folds every BatchNorm into the convolution before it (weight and bias), so the BatchNorm's own
parameters are lost.  They are rebuilt so that the network computes exactly the export's function in eval mode
*and* about the same in training mode: each folded convolution keeps the folded weight (no bias), and its
BatchNorm gets the per-channel mean m and variance v of that convolution's output over sample batches as its
running statistics, weight sqrt(v + eps) and bias (folded bias + m).  In eval mode the BatchNorm is then
z - m + m + bias = z + bias, the export's output; in training mode it normalises with batch statistics close to
m and v, i.e. nearly the same.  ``--check`` compares the result with onnxruntime on a sample.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import onnx
import torch
from onnx import numpy_helper
from torch import nn

from .model import VehicleSegNet


def _module_name(node_name: str) -> str:
    """The module a node belongs to, from the scopes torch's exporter names it with: ``/enc2/enc2.1/dw/dw.0/Conv``
    -> ``enc2.1.dw.0`` (a scope extends the previous one when it starts with it and a dot, as Sequential children
    do; else it is an attribute of the module so far)."""
    parts = node_name.strip("/").split("/")[:-1]
    full, prev = "", ""
    for c in parts:
        if prev and c.startswith(prev + "."):
            full += c[len(prev):]
        else:
            full = f"{full}.{c}" if full else c
        prev = c
    return full


def _conv_weights(path: Path) -> dict[str, tuple[np.ndarray, np.ndarray | None]]:
    """Module name of each Conv in the export (:func:`_module_name`) -> (weight, bias)."""
    m = onnx.load(str(path))
    init = {i.name: numpy_helper.to_array(i) for i in m.graph.initializer}
    out = {}
    for node in m.graph.node:
        if node.op_type != "Conv":
            continue
        if not node.name.endswith("/Conv"):
            raise ValueError(f"{path}: cannot tell which module Conv node {node.name!r} is")
        name = _module_name(node.name)
        w = init[node.input[1]]
        b = init[node.input[2]] if len(node.input) > 2 else None
        out[name] = (w, b)
    return out


def import_onnx(path: Path, calibration: list[torch.Tensor]) -> VehicleSegNet:
    """The network with the export's weights and BatchNorms rebuilt on ``calibration`` inputs (N x 6 x H x W)."""
    model = VehicleSegNet()
    modules = dict(model.named_modules())
    convs = _conv_weights(path)
    names = {n for n, m in modules.items() if isinstance(m, nn.Conv2d)}
    if set(convs) != names:
        raise ValueError(f"{path}: its convolutions do not match the network: "
                         f"missing {sorted(names - set(convs))[:5]}, unknown {sorted(set(convs) - names)[:5]}")
    folded: dict[str, tuple[nn.BatchNorm2d, torch.Tensor]] = {}
    with torch.no_grad():
        for name, (w, b) in convs.items():
            conv = modules[name]
            conv.weight.copy_(torch.from_numpy(w))
            head, _, idx = name.rpartition(".")
            bn = modules.get(f"{head}.{int(idx) + 1}") if idx.isdigit() else None
            if isinstance(bn, nn.BatchNorm2d):  # folded: identity BatchNorm carrying the bias for now
                bias = torch.from_numpy(b) if b is not None else torch.zeros(w.shape[0])
                bn.running_mean.zero_()
                bn.running_var.fill_(1.0 - bn.eps)
                bn.weight.fill_(1.0)
                bn.bias.copy_(bias)
                folded[name] = (bn, bias)
            elif b is not None:
                conv.bias.copy_(torch.from_numpy(b))
    # statistics of each folded convolution's output (eval mode: the export's function, so every layer sees the
    # inputs it will see)
    stats: dict[str, list[torch.Tensor]] = {n: [torch.zeros(()), None, None] for n in folded}
    hooks = []
    for name in folded:
        def hook(_m, _inp, out, name=name):
            s = stats[name]
            x = out.detach().double()
            s[0] = s[0] + x.shape[0] * x.shape[2] * x.shape[3]
            s1, s2 = x.sum((0, 2, 3)), (x * x).sum((0, 2, 3))
            s[1] = s1 if s[1] is None else s[1] + s1
            s[2] = s2 if s[2] is None else s[2] + s2
        hooks.append(modules[name].register_forward_hook(hook))
    model.eval()
    with torch.no_grad():
        for x in calibration:
            model(x)
    for h in hooks:
        h.remove()
    with torch.no_grad():
        for name, (bn, bias) in folded.items():
            n, s1, s2 = stats[name]
            mean = s1 / n
            var = (s2 / n - mean * mean).clamp(min=1e-8)
            bn.running_mean.copy_(mean.float())
            bn.running_var.copy_(var.float())
            bn.weight.copy_(torch.sqrt(var + bn.eps).float())
            bn.bias.copy_((bias.double() + mean).float())
    return model


def main(argv: list[str] | None = None) -> int:
    from .train import batch, split_files

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--onnx", type=Path, required=True)
    ap.add_argument("--data", type=Path, nargs="+", required=True, help="sample folders (for the BatchNorm statistics)")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--batches", type=int, default=20, help="batches of 6 random crops for the statistics")
    ap.add_argument("--crop", default="192x320")
    ap.add_argument("--check", action="store_true", help="compare with onnxruntime on whole samples")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    rng = np.random.default_rng(0)
    crop = tuple(int(v) for v in args.crop.lower().split("x"))
    files, _ = split_files(args.data)
    xs = [batch([files[i] for i in rng.choice(len(files), 6)], crop, rng)["x"] for _ in range(args.batches)]
    model = import_onnx(args.onnx, xs)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"model": model.state_dict(), "step": 0, "from_onnx": str(args.onnx)}, args.out)
    print(f"{args.out}: weights of {args.onnx}, BatchNorms rebuilt on {args.batches} batches")
    if args.check:
        import onnxruntime as ort
        sess = ort.InferenceSession(str(args.onnx), providers=["CPUExecutionProvider"])
        x = batch(files[:4], (256, 448), rng, augment=False)["x"].contiguous()
        model.eval()
        with torch.no_grad():
            ours = [t.numpy() for t in model(x)]
        ref = [np.concatenate(r) for r in zip(*(sess.run(None, {"input": x[i:i + 1].numpy()}) for i in range(len(x))))]
        for name, a, b in zip(("mask", "centre", "offset"), ours, ref):
            print(f"eval {name}: max |torch - onnx| = {np.abs(a - b).max():.2e} (range {np.ptp(b):.1f})")
        model.train()
        with torch.no_grad():
            train = model(x)[0].numpy()
        model.eval()
        iou = ((train > 0) & (ref[0] > 0)).sum() / max(((train > 0) | (ref[0] > 0)).sum(), 1)
        print(f"training mode (batch statistics of these 4): mask agreement IoU with the export {iou:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
