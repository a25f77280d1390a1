"""The learned vehicle segmenter (``vehicledetect model=vehicleseg``): boxes and convex hulls of vehicles.

A small ONNX network trained by this project on its own renderer (``training/vehicleseg``, card in
``weights/vehicleseg.json``) looks at the frame and a running-average background (:mod:`.seginput`) and gives

* ``mask``: a vehicle logit per work pixel (changed *and* a vehicle: cast shadows, headlight beams and background
  ghosts are not vehicles);
* ``centre``: an instance-centre heatmap logit at 1/4 of the work size;
* ``offset``: per 1/4 cell the (dx, dy) to its instance's centre.

Post-processing (vectorised): centres are the heatmap's local maxima above ``centre_threshold``; the mask's
connected components that hold exactly one centre are that vehicle; the pixels of components with several
centres go to the centre their offsets point nearest to (touching vehicles come out separate), and the pixels of
components without a centre go to the centre they point at when it is close, else form a vehicle of their own.
Each vehicle's convex hull is that of the 0.5 level line of its bilinearly interpolated probability (sub-pixel: a
hull of whole work-pixel squares lies up to 0.7 work pixel outside a slanted outline, i.e. 2.8 frame pixels at
1080p), its box that hull's extent, both in frame pixels.

The detector keeps the background itself, so call it once per frame in order, with the frame's timestamp.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy import ndimage

from ..errors import InputError
from .labels import COCO_VEHICLES
from .onnx_detector import open_session
from .records import Detections
from .seginput import RunningBackground, WorkGeometry, network_input, to_work

NAME = "vehicleseg"
WEIGHTS = Path(__file__).resolve().parent / "weights" / "vehicleseg.onnx"
CAR_ID = next(cid for cid, name in COCO_VEHICLES.items() if name == "car")
OUTPUTS = ("mask", "centre", "offset")
QUARTER = 4
SUBPIXEL = 4  # the outline is traced on the probability upsampled this many times (error <= 0.7 / SUBPIXEL px)
SQUARE = np.array([[0, 0], [1, 0], [0, 1], [1, 1]], np.float32)


@dataclass
class Segmentation:
    """What the network and the grouping found in one frame (work size), for overlays and tests."""

    probability: np.ndarray  # H x W vehicle probability
    instances: np.ndarray  # H x W int32, 0 = none, k = row k-1 of the detections
    centres: np.ndarray  # K x 2 centre peaks (work pixels)
    geometry: WorkGeometry


def is_vehicleseg(path: str | Path) -> bool:
    """Whether an ONNX file is a vehicle segmenter of this project (its ``gst_trafficcal_model`` metadata)."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.log_severity_level = 3
    try:
        meta = ort.InferenceSession(str(path), sess_options=opts,
                                    providers=["CPUExecutionProvider"]).get_modelmeta().custom_metadata_map
    except Exception:
        return False
    return meta.get("gst_trafficcal_model") == NAME


class VehicleSegDetector:
    """Vehicles (boxes + hulls) in BGR or grey frames; call in frame order with timestamps (seconds).

    ``path``: the ONNX file (default: the shipped model); ``threads``: onnxruntime intra-op threads (0 = its
    default); ``work_width``: width of the network's input (the frame is reduced to it); ``threshold``: minimum
    score (centre heatmap peak, or mean mask probability of a vehicle without a centre); ``min_area``: smallest
    vehicle as a fraction of the work image (0.15 %, the background detector's smallest blob: smaller, farther
    vehicles are too coarse to measure, and their flickering far-field tracks made the speed stage reject or
    mis-measure whole tracks: offline, the product's speed function measured 17 of the demo scene's 50 cars with a
    20-pixel minimum, 50 with 300 pixels);
    ``tau``: the background's time constant in seconds; ``mask_threshold``: vehicle probability at the outline.
    """

    timed = True  # __call__ takes the frame time: the element passes buffer timestamps

    def __init__(self, path: str | Path | None = None, threads: int = 1, work_width: int | None = None,
                 threshold: float = 0.3, centre_threshold: float = 0.3, min_area: float = 0.0015,
                 tau: float | None = None, mask_threshold: float = 0.5) -> None:
        self.path = Path(path) if path is not None else WEIGHTS
        if not self.path.is_file():
            raise InputError(f"vehicleseg model file not found: {self.path}")
        self.session = open_session(self.path, threads)
        meta = self.session.get_modelmeta().custom_metadata_map
        inputs, outputs = self.session.get_inputs(), [o.name for o in self.session.get_outputs()]
        if len(inputs) != 1 or len(inputs[0].shape) != 4 or inputs[0].shape[1] != 6 or \
                sorted(outputs) != sorted(OUTPUTS):
            raise InputError(f"{self.path}: not a vehicleseg model (needs one N x 6 x H x W input and outputs "
                             f"{', '.join(OUTPUTS)}; found inputs {[i.shape for i in inputs]}, outputs {outputs})")
        self.input_name = inputs[0].name
        self.work_width = int(work_width or int(meta.get("work_width", 480)))
        if not 64 <= self.work_width <= 1920:
            raise InputError(f"vehicleseg work width must be 64..1920 pixels, got {self.work_width}")
        self.tau = float(tau if tau is not None else float(meta.get("tau", 2.0)))
        self.threshold = float(threshold)
        self.centre_threshold = float(centre_threshold)
        if not 0 <= min_area < 1:
            raise InputError(f"vehicleseg min_area is a fraction of the image, 0..1, got {min_area}")
        self.min_area = float(min_area)
        if not 0 < mask_threshold < 1:
            raise InputError(f"vehicleseg mask_threshold is a probability, 0..1 exclusive, got {mask_threshold}")
        self.mask_threshold = float(mask_threshold)
        self.background = RunningBackground(tau=self.tau)
        self.geometry: WorkGeometry | None = None
        self.last: Segmentation | None = None
        try:  # one dry run proves the model runs (a truncated or wrong file fails here, at start-up)
            out = self.session.run(None, {self.input_name: np.zeros((1, 6, 32, 48), np.float32)})
        except Exception as exc:
            raise InputError(f"{self.path}: the model does not run ({str(exc).splitlines()[0][:200]})") from None
        if out[0].shape[-2:] != (32, 48):
            raise InputError(f"{self.path}: mask output {out[0].shape} does not match the 32 x 48 input")

    def reset(self) -> None:
        """Forget the background (a new video)."""
        self.background.reset()
        self.geometry = None

    def reduced_size(self, frame_size: tuple[int, int]) -> tuple[int, int]:
        """The (w, h) a frame of ``frame_size`` is reduced to first: callers that can reduce a frame more cheaply
        than from a full-size BGR copy (YUV planes) pass it reduced, with its ``frame_size``."""
        return WorkGeometry(tuple(frame_size), self.work_width).size

    def infer(self, image: np.ndarray, t: float | None = None,
              frame_size: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Update the background with ``image`` and run the network: (mask logits H x W, centre logits, offsets
        2 x H/4 x W/4), cropped to the work size.  ``frame_size``: the frame's (w, h) when ``image`` is that frame
        already reduced (to :meth:`reduced_size` or any size); default: ``image``'s own."""
        w, h = frame_size or image.shape[1::-1]
        if self.geometry is None or self.geometry.frame_size != (w, h):
            self.geometry = WorkGeometry((w, h), self.work_width)
            self.background.reset()
        work = to_work(image, self.geometry)
        background = self.background.update(work, t)
        mask, centre, offset = self.session.run(list(OUTPUTS), {self.input_name: network_input(work, background,
                                                                                           self.geometry)})
        ww, wh = self.geometry.size
        qh, qw = -(-wh // QUARTER), -(-ww // QUARTER)
        return mask[0, 0, :wh, :ww], centre[0, 0, :qh, :qw], offset[0, :, :qh, :qw]

    def __call__(self, image: np.ndarray, t: float | None = None, frame_size: tuple[int, int] | None = None
                 ) -> Detections:
        """Vehicles in a BGR (HxWx3) or grey (HxW) uint8 frame at time ``t`` (seconds; None: frames 1/25 s apart),
        boxes and hulls in that frame's pixels (``frame_size``: see :meth:`infer`)."""
        mask, centre, offset = self.infer(image, t, frame_size)
        detections, self.last = decode(mask, centre, offset, self.geometry, self.threshold, self.centre_threshold,
                                       max(1, round(self.min_area * mask.size)), self.mask_threshold)
        return detections


def centre_peaks(centre: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """Local maxima (3x3 cells) of the sigmoid heatmap above ``threshold``: (K x 2 quarter-cell x, y; K scores)."""
    heat = 1.0 / (1.0 + np.exp(-centre))
    peak = (heat >= cv2.dilate(heat, np.ones((3, 3), np.uint8))) & (heat > threshold)
    ys, xs = np.nonzero(peak)
    return np.stack([xs, ys], axis=1).astype(np.float64), heat[ys, xs]


def merge_split_peaks(label: np.ndarray, px: np.ndarray, py: np.ndarray, peak_comp: np.ndarray,
                      peak_score: np.ndarray, near: float = 1.5, relative: float = 0.4) -> tuple[np.ndarray, np.ndarray]:
    """Join the groups of two peaks of one component whose pixels point at the same place.

    A large vehicle can show two heatmap maxima; its pixels then still point at one centre (their mean predicted
    centres nearly coincide), while two touching vehicles' pixels point at two centres about their half-length
    apart.  Groups (pixels labelled 1..k by peak) whose mean predicted centres are closer than ``near`` cells or
    ``relative`` x the larger group's size (square root of its area, in cells) are merged into the stronger peak.
    Returns the relabelled pixels and the peaks' scores (a merged peak keeps the best score).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    k = len(peak_comp)
    is_peak = (label >= 1) & (label <= k)
    cnt = np.bincount(label[is_peak], minlength=k + 1)[1:].astype(np.float64)
    mx = np.bincount(label[is_peak], weights=px[is_peak], minlength=k + 1)[1:] / np.maximum(cnt, 1)
    my = np.bincount(label[is_peak], weights=py[is_peak], minlength=k + 1)[1:] / np.maximum(cnt, 1)
    size = np.sqrt(cnt) / QUARTER
    d = np.hypot(mx[:, None] - mx[None, :], my[:, None] - my[None, :])
    join = (d < np.maximum(near, relative * np.maximum(size[:, None], size[None, :]))) & \
        (peak_comp[:, None] == peak_comp[None, :]) & (peak_comp[:, None] > 0) & (cnt[:, None] > 0) & (cnt[None, :] > 0)
    if not join[~np.eye(k, dtype=bool)].any():
        return label, peak_score
    i, j = np.nonzero(join)
    _, group = connected_components(coo_matrix((np.ones(len(i)), (i, j)), shape=(k, k)), directed=False)
    best = np.full(group.max() + 1, -1)
    order = np.argsort(-peak_score)
    for p in order:  # the strongest peak of each group represents it (k is small)
        if best[group[p]] < 0:
            best[group[p]] = p
    rep = best[group]
    score = peak_score.copy()
    np.maximum.at(score, rep, peak_score)
    relabel = np.arange(max(int(label.max()), k) + 1)
    relabel[1:k + 1] = rep + 1
    return relabel[label], score


def outline_hull(prob: np.ndarray, inst: np.ndarray, label: int, sl: tuple[slice, slice],
                 factor: int = SUBPIXEL, level: float = 0.5) -> np.ndarray:
    """Convex hull (K x 2, work-pixel edge coordinates: pixel i spans [i, i+1]) of the ``level`` line of the
    probability of vehicle ``label``, interpolated bilinearly between pixel centres.

    Other vehicles' pixels count as probability 0 (touching vehicles part where their pixels meet) and the image
    outside as 0 (a vehicle cut by the border ends there).  The level line is traced on the probability upsampled
    ``factor`` times; the hull is that of the upsampled pixel squares above ``level``.
    """
    h, w = inst.shape
    y0, y1, x0, x1 = sl[0].start - 1, sl[0].stop + 1, sl[1].start - 1, sl[1].stop + 1
    a, b, c, d = max(y0, 0), min(y1, h), max(x0, 0), min(x1, w)
    own = inst[a:b, c:d]
    p = np.where((own == label) | (own == 0), prob[a:b, c:d], 0.0).astype(np.float32)
    p = np.pad(p, ((a - y0, y1 - b), (c - x0, x1 - d)))
    up = cv2.resize(p, (p.shape[1] * factor, p.shape[0] * factor), interpolation=cv2.INTER_LINEAR)
    contours, _ = cv2.findContours((up > level).view(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not contours:  # a one-pixel vehicle whose interpolated peak stays below the level: its pixel squares
        ys, xs = np.nonzero(inst[sl] == label)
        pts = np.stack([xs + sl[1].start, ys + sl[0].start], axis=1).astype(np.float32)
        return cv2.convexHull((pts[:, None] + SQUARE).reshape(-1, 2)).reshape(-1, 2).astype(np.float64)
    pts = np.concatenate([cv2.convexHull(cc).reshape(-1, 2) for cc in contours]).astype(np.float32)
    corners = ((pts[:, None, :] + SQUARE).reshape(-1, 2) / factor + np.float32([x0, y0])).astype(np.float32)
    return cv2.convexHull(corners).reshape(-1, 2).astype(np.float64)


def decode(mask: np.ndarray, centre: np.ndarray, offset: np.ndarray, geometry: WorkGeometry, threshold: float = 0.3,
           centre_threshold: float = 0.3, min_area: int = 20,
           mask_threshold: float = 0.5) -> tuple[Detections, Segmentation]:
    """Network outputs (work size) -> vehicles with boxes and hulls in frame pixels (see the module docstring);
    ``min_area`` in work pixels; ``mask_threshold``: the vehicle probability where a vehicle ends."""
    prob = 1.0 / (1.0 + np.exp(-mask))
    fg = (mask > np.log(mask_threshold / (1.0 - mask_threshold))).view(np.uint8)
    h, w = fg.shape
    peaks, peak_score = centre_peaks(centre, centre_threshold)
    n, comp = cv2.connectedComponents(fg, connectivity=8)
    inst = np.zeros((h, w), np.int32)
    if n > 1:
        ys, xs = np.nonzero(fg)
        lab = comp[ys, xs]
        k = len(peaks)
        # each foreground pixel's predicted centre: its quarter cell + the cell's offset, compared with every peak
        qy, qx = np.minimum(ys // QUARTER, offset.shape[1] - 1), np.minimum(xs // QUARTER, offset.shape[2] - 1)
        px = qx + offset[0, qy, qx]
        py = qy + offset[1, qy, qx]
        if k:
            d2 = (px[:, None] - peaks[None, :, 0]) ** 2 + (py[:, None] - peaks[None, :, 1]) ** 2
            nearest = d2.argmin(axis=1)
            near_ok = d2[np.arange(len(nearest)), nearest] <= 9.0  # within 3 cells (12 work pixels)
            # the component of each peak: where most of the pixels pointing at it lie
            votes = np.bincount(nearest[near_ok] * n + lab[near_ok], minlength=k * n).reshape(k, n)
            peak_comp = np.where(votes.max(axis=1) > 0, votes.argmax(axis=1), 0)
            has_peak = np.bincount(peak_comp, minlength=n)[lab] > 0
            has_peak &= lab > 0
            # in a component with peaks, the nearest of its own peaks; in one without, a peak the pixel points at
            # (a fragment of an occluded vehicle), else the component is a vehicle of its own
            own = np.where(peak_comp[None, :] == lab[:, None], d2, np.inf).argmin(axis=1)
            label = np.where(has_peak, own + 1, np.where(near_ok, nearest + 1, k + lab))
            if k > 1:
                label, peak_score = merge_split_peaks(label, px, py, peak_comp, peak_score)
        else:
            label = lab
        inst[ys, xs] = label
    objects = ndimage.find_objects(inst)
    sx, sy = geometry.scale
    boxes, scores, hulls, kept = [], [], [], []
    for i, sl in enumerate(objects):
        if sl is None:
            continue
        region = inst[sl] == i + 1
        area = int(region.sum())
        if area < min_area:
            continue
        score = float(peak_score[i]) if i < len(peaks) else float(prob[sl][region].mean()) * 0.5
        if score < threshold:
            continue
        # work pixel edges -> frame pixels (centres at integers, as the renderer's and the models' projected boxes);
        # the box is the hull's extent in the same coordinates
        hull = outline_hull(prob, inst, i + 1, sl, level=mask_threshold) * (sx, sy) - 0.5
        hulls.append(hull)
        boxes.append((*hull.min(axis=0), *hull.max(axis=0)))
        scores.append(score)
        kept.append(i + 1)
    remap = np.zeros(int(inst.max()) + 1, np.int32)
    remap[kept] = np.arange(1, len(kept) + 1)
    seg = Segmentation(prob, remap[inst], (peaks + 0.5) * QUARTER - 0.5, geometry)
    m = len(boxes)
    det = Detections(np.array(boxes, np.float64).reshape(-1, 4), np.array(scores), np.full(m, CAR_ID),
                     np.full(m, "car", dtype=object), hulls)
    return det, seg
