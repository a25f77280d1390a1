"""Vehicle detection with any supported single-stage ONNX detector through onnxruntime.

The model is opened, checked and its output layout recognised once, at construction, so a missing,
corrupt or unsupported file fails at start-up with a one-line :class:`~gst_trafficcal.errors.InputError`
naming it, never per frame.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from ..errors import InputError
from ..imaging import fit
from .decoders import DEFAULT_INPUT_SIZE, FORMATS, Decoder, LayoutError, Preprocess, make_decoder
from .labels import LabelMap
from .records import Detections


def open_session(path: Path, threads: int):
    """An onnxruntime CPU session for ``path`` with ``threads`` intra-op threads (0: onnxruntime's choice), one
    inter-op thread and no spinning; InputError naming the file when onnxruntime cannot load it."""
    import onnxruntime as ort  # heavy: imported only when a model is actually used

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = max(0, int(threads))
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    opts.log_severity_level = 3
    # idle worker threads sleep instead of spinning: measured on the loaded 2-core machine, NanoDet with
    # 2 threads ran at 13 fps spinning and 35 fps not (1 thread: 26 fps); a pipeline shares its cores
    opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
    try:
        return ort.InferenceSession(str(path), sess_options=opts, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own Fail/InvalidProtobuf/... types
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"{path}: not a usable ONNX model ({first[:200]})") from None


@dataclass(frozen=True)
class Letterbox:
    """Network-input pixel = image pixel * scale + pad; kept to map boxes back to the image."""

    sx: float
    sy: float
    px: float
    py: float

    def to_image(self, boxes: np.ndarray) -> np.ndarray:
        return (boxes - np.array([self.px, self.py, self.px, self.py], np.float32)) / np.array(
            [self.sx, self.sy, self.sx, self.sy], np.float32
        )


def resized_size(frame_size: tuple[int, int], pre: Preprocess) -> tuple[int, int]:
    """The (w, h) a frame of ``frame_size`` is resized to: the network's size when stretched, else the largest size
    of the frame's shape that fits inside it (the letterbox pads the rest)."""
    (w, h), (nw, nh) = frame_size, pre.size
    if pre.letterbox == "none":
        return nw, nh
    r = min(nw / w, nh / h)
    return max(1, round(w * r)), max(1, round(h * r))


def prepare(image: np.ndarray, pre: Preprocess) -> tuple[np.ndarray, Letterbox]:
    """Resize/letterbox a BGR (or grey) image into an HxWx3 float32 network image, normalised."""
    if image.ndim == 2:
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    h, w = image.shape[:2]
    nw, nh = pre.size
    rw, rh = resized_size((w, h), pre)
    if pre.letterbox == "none":
        canvas = fit(image, (nw, nh))
        lb = Letterbox(nw / w, nh / h, 0.0, 0.0)
    else:
        px, py = ((nw - rw) // 2, (nh - rh) // 2) if pre.letterbox == "center" else (0, 0)
        canvas = np.full((nh, nw, 3), pre.pad_value, np.uint8)
        canvas[py : py + rh, px : px + rw] = fit(image, (rw, rh))
        lb = Letterbox(rw / w, rh / h, float(px), float(py))
    if pre.rgb:
        canvas = cv2.cvtColor(canvas, cv2.COLOR_BGR2RGB)
    net = canvas.astype(np.float32)
    if any(pre.mean):
        net -= np.array(pre.mean, np.float32)
    if any(s != 1.0 for s in pre.std):
        net *= np.array([1.0 / s for s in pre.std], np.float32)
    return net, lb


def nms(boxes: np.ndarray, scores: np.ndarray, iou: float, class_ids: np.ndarray | None = None) -> np.ndarray:
    """Indices kept by non-maximum suppression (per class when ``class_ids`` is given), best first."""
    if len(boxes) == 0:
        return np.zeros(0, np.int64)
    b = boxes.astype(np.float32)
    if class_ids is not None:  # offset each class far apart so boxes of different classes never overlap
        b = b + (class_ids.astype(np.float32) * (float(b.max()) + 1.0))[:, None]
    xywh = np.concatenate([b[:, :2], b[:, 2:] - b[:, :2]], axis=1)
    keep = cv2.dnn.NMSBoxes(xywh.tolist(), scores.astype(float).tolist(), 0.0, iou)
    return np.asarray(keep, np.int64).reshape(-1)


class OnnxDetector:
    """A COCO (or custom) detector that returns :class:`Detections` of vehicles for BGR frames.

    ``model_format`` is "auto" (recognise from output shapes) or one of :data:`~.decoders.FORMATS`;
    ``labels`` selects and names the vehicle classes; ``threshold`` is the minimum score;
    ``nms_iou`` the suppression overlap; ``agnostic_nms`` suppresses across classes (one box per
    vehicle even when the model hesitates between car and truck); ``threads`` sets onnxruntime's
    intra-op threads (0 = onnxruntime's default); ``input_size`` (w, h) overrides dynamic inputs;
    ``preprocess`` overrides fields of the family's default :class:`~.decoders.Preprocess`;
    ``tiles`` (columns, rows) runs the model on overlapping tiles of the frame (cost: one inference
    per tile) so that distant vehicles in full-HD frames keep enough pixels for a 320 px network.
    """

    def __init__(
        self,
        path: str | Path,
        model_format: str = "auto",
        labels: LabelMap | str | None = None,
        threshold: float = 0.4,
        nms_iou: float = 0.5,
        agnostic_nms: bool = True,
        threads: int = 1,
        input_size: tuple[int, int] | None = None,
        preprocess: dict | None = None,
        tiles: tuple[int, int] = (1, 1),
    ) -> None:
        self.path = Path(path)
        if model_format != "auto" and model_format not in FORMATS:
            raise InputError(f"unknown model format {model_format!r} (use auto or one of {', '.join(FORMATS)})")
        if not self.path.is_file():
            raise InputError(f"model file not found: {self.path}")
        self.labels = labels if isinstance(labels, LabelMap) else LabelMap.parse(labels)
        self.threshold = float(threshold)
        self.nms_iou = float(nms_iou)
        self.agnostic_nms = agnostic_nms
        if len(tiles) != 2 or min(tiles) < 1 or max(tiles) > 8:
            raise InputError(f"tiles must be columns x rows between 1 and 8, got {tiles}")
        self.tiles = (int(tiles[0]), int(tiles[1]))
        self.session = open_session(self.path, threads)
        inputs = self.session.get_inputs()
        if len(inputs) != 1 or len(inputs[0].shape) != 4:
            raise InputError(f"{self.path}: expected one 4-D image input, found {[i.shape for i in inputs]}")
        inp = inputs[0]
        self.input_name = inp.name
        self.nhwc = inp.shape[3] == 3 and inp.shape[1] != 3
        self.input_uint8 = inp.type == "tensor(uint8)"
        dims = inp.shape[1:3] if self.nhwc else inp.shape[2:4]
        if input_size is not None:
            size = (int(input_size[0]), int(input_size[1]))
        elif all(isinstance(d, int) and d > 0 for d in dims):
            size = (int(dims[1]), int(dims[0]))
        else:
            d = DEFAULT_INPUT_SIZE.get(model_format, 640)
            size = (d, d)
        # one dry run gives the real output shapes (symbolic dims resolved) and proves the model runs
        try:
            outputs = self._run(np.zeros((size[1], size[0], 3), np.float32))
        except Exception as exc:
            raise InputError(f"{self.path}: the model does not run on a {size[0]}x{size[1]} image ({str(exc).splitlines()[0][:200]})") from None
        try:
            self.decoder: Decoder = make_decoder(model_format, size, [o.shape for o in outputs])
        except LayoutError as exc:
            raise InputError(f"{self.path}: {exc}") from None
        self.preprocess = replace(self.decoder.preprocess, **(preprocess or {}))
        self.input_size = size
        n = self.decoder.num_classes
        missing = sorted(c for c in self.labels.names if n > 0 and c >= n)
        if missing and len(missing) == len(self.labels.names):  # nothing would ever be found, in silence
            raise InputError(f"{self.path}: the model has {n} classes (ids 0 to {n - 1}); labels names only "
                             f"class id(s) {', '.join(map(str, missing))}")
        self.missing_labels = missing  # ids the model does not have (the others still give vehicles)

    @property
    def model_format(self) -> str:
        return self.decoder.name

    def _run(self, net: np.ndarray) -> list[np.ndarray]:
        blob = net[None] if self.nhwc else net.transpose(2, 0, 1)[None]
        blob = np.ascontiguousarray(blob.clip(0, 255).astype(np.uint8) if self.input_uint8 else blob)
        return self.session.run(None, {self.input_name: blob})

    def _candidates(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        net, lb = prepare(image, self.preprocess)
        boxes, scores, class_ids = self.decoder(self._run(net), self.threshold, self.labels.ids)
        return lb.to_image(boxes), scores, class_ids

    def reduced_size(self, frame_size: tuple[int, int]) -> tuple[int, int] | None:
        """The (w, h) a whole frame of ``frame_size`` is resized to before the network (inside the letterbox, or
        the network's size when stretched); None with tiles, which need the full frame."""
        return resized_size(frame_size, self.preprocess) if self.tiles == (1, 1) else None

    def __call__(self, image: np.ndarray, frame_size: tuple[int, int] | None = None) -> Detections:
        """Vehicles in a BGR (HxWx3) or grey (HxW) uint8 frame, boxes in that frame's pixels; ``frame_size``: the
        frame's (w, h) when ``image`` is it already reduced (to :meth:`reduced_size`)."""
        h, w = image.shape[:2]
        if frame_size is not None and tuple(frame_size) != (w, h):
            return self(image).scaled(frame_size[0] / w, frame_size[1] / h).clipped(*frame_size)
        if self.tiles == (1, 1):
            boxes, scores, class_ids = self._candidates(image)
        else:
            parts = []
            for x0, y0, x1, y1 in tile_grid(w, h, *self.tiles):
                b, s, c = self._candidates(image[y0:y1, x0:x1])
                b = b + np.array([x0, y0, x0, y0], np.float32)
                # a box touching an inner tile edge is a cut-off vehicle, seen whole by the neighbour
                # tile (the overlap is wider than the vehicles this mode is for)
                cut = ((x0 > 0) & (b[:, 0] <= x0 + 2)) | ((x1 < w) & (b[:, 2] >= x1 - 2)) | \
                      ((y0 > 0) & (b[:, 1] <= y0 + 2)) | ((y1 < h) & (b[:, 3] >= y1 - 2))
                parts.append((b[~cut], s[~cut], c[~cut]))
            boxes, scores, class_ids = (np.concatenate([p[i] for p in parts]) for i in range(3))
        keep = nms(boxes, scores, self.nms_iou, None if self.agnostic_nms else class_ids)
        boxes, scores, class_ids = boxes[keep], scores[keep], class_ids[keep]
        det = Detections(boxes, scores, class_ids, self.labels.lookup(class_ids))
        return det.clipped(w, h)


def tile_grid(width: int, height: int, cols: int, rows: int, overlap: float = 0.15) -> list[tuple[int, int, int, int]]:
    """(x0, y0, x1, y1) of cols x rows tiles covering the image, neighbours overlapping by
    ``overlap`` of a tile."""
    tw = width if cols == 1 else int(np.ceil(width / (cols - (cols - 1) * overlap)))
    th = height if rows == 1 else int(np.ceil(height / (rows - (rows - 1) * overlap)))
    out = []
    for r in range(rows):
        for c in range(cols):
            x0 = 0 if cols == 1 else round(c * (width - tw) / (cols - 1))
            y0 = 0 if rows == 1 else round(r * (height - th) / (rows - 1))
            out.append((x0, y0, x0 + tw, y0 + th))
    return out
