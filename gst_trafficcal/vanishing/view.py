"""Has the camera moved since it was calibrated?  A small fingerprint of the static scene, stored with the
calibration and compared with the scene a stream shows.

A stored calibration is only right for the view it was learnt on: a camera knocked, re-aimed or zoomed keeps
its image size, and its speeds would be silently wrong.  ``vpdetect`` keeps a median background thumbnail
(:class:`ViewAccumulator`) of the video it calibrates on and saves it in the calibration file (``view``); when
it loads a calibration it compares the stream's thumbnail with it (:func:`compare_views`: the shift between the
two images' gradients by phase correlation, and their normalised correlation once aligned).  The gradients, not
the grey levels, so that daylight, exposure and weather changes are not taken for a move.  While a stream runs,
:class:`ViewMonitor` keeps comparing a rolling median of the latest thumbnails with the calibration's view, so a
camera knocked or re-aimed mid-stream is noticed within two seconds or so.
"""

from __future__ import annotations

import base64
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import InputError

VIEW_WIDTH = 160
"""Width in pixels of the thumbnail (the height keeps the frame's aspect)."""
MAX_SHIFT = 1.5
"""Thumbnail pixels (1.5 / 160 ≈ 1 % of the frame width) the view may shift before it counts as moved."""
MAX_ZOOM = 0.01
"""Relative change of scale (a zoom: the focal length, hence every speed, changes by as much) that counts as moved."""
MAX_ROTATION_DEG = 0.5
"""Rotation of the image (the camera's roll) that counts as moved."""
MIN_SIMILARITY = 0.5
"""Normalised correlation of the aligned gradient images below which the view counts as another one."""
MIN_ALIGN_GAIN = 0.03
"""How much better the aligned images must correlate than the images as they are for a measured shift, zoom or roll
to be believed (:attr:`ViewMatch.displaced`): a real move is explained by the alignment; vehicles standing in the
median thumbnail of heavy traffic are not, and ECC then fits a small transform to them that explains nothing.
On a scene that correlates almost perfectly either way (a 1° roll of a sparse view: 0.96 -> 0.99) the gain is
small but the alignment removes most of what differed: halving the mismatch (1 - correlation) also counts."""


@dataclass(frozen=True)
class ViewMatch:
    """How the current view compares with the calibration's."""

    shift: tuple[float, float]  # (dx, dy) of the current view against the stored one, in frame pixels
    zoom: float  # relative scale of the current view against the stored one, minus 1
    rotation_deg: float
    similarity: float  # normalised correlation of the aligned gradient images, -1..1
    moved: bool
    unaligned: float = 0.0  # normalised correlation of the gradient images as they are

    @property
    def recognised(self) -> bool:
        """The same scene (once aligned): whatever moved, the shift, zoom and roll were measured on it."""
        return self.similarity >= MIN_SIMILARITY

    @property
    def displaced(self) -> bool:
        """Moved by a measured shift, zoom or roll of a recognised scene (not merely unrecognisable), which the
        alignment explains (it raises the correlation by MIN_ALIGN_GAIN at least, or halves the mismatch)."""
        explained = (self.similarity - self.unaligned >= MIN_ALIGN_GAIN
                     or 1.0 - self.unaligned >= 2.0 * (1.0 - self.similarity) > 0.0)
        return self.moved and self.recognised and explained

    def describe(self) -> str:
        return (f"shifted by ({self.shift[0]:+.0f}, {self.shift[1]:+.0f}) px, zoom {100 * self.zoom:+.1f} %, "
                f"rotated {self.rotation_deg:+.1f}°, similarity {self.similarity:.2f} (the same view: within "
                f"{MAX_SHIFT / VIEW_WIDTH * 100:.0f} % of the width, {100 * MAX_ZOOM:g} % zoom, {MAX_ROTATION_DEG:g}°, "
                f"similarity at least {MIN_SIMILARITY:g})")


def thumbnail(luma: np.ndarray) -> np.ndarray:
    """A VIEW_WIDTH-wide grey thumbnail of a luma frame (area averaging)."""
    h, w = luma.shape[:2]
    size = (VIEW_WIDTH, max(1, round(VIEW_WIDTH * h / w)))
    return cv2.resize(luma, size, interpolation=cv2.INTER_AREA)


class ViewAccumulator:
    """Median of the thumbnails of every ``every``-th frame (up to ``keep`` of them): the static scene without
    the traffic passing through it."""

    def __init__(self, every: int = 5, keep: int = 25) -> None:
        self.every, self.keep = every, keep
        self._n = 0
        self._thumbs: list[np.ndarray] = []

    def wants(self) -> bool:
        """Whether the next frame is one that is sampled (the caller may skip reading the others)."""
        return self._n % self.every == 0

    def skip(self) -> None:
        """Count a frame that is not sampled (:meth:`wants` said no) without reading it."""
        self._n += 1

    def add(self, luma: np.ndarray) -> None:
        if self.wants():
            self._thumbs.append(thumbnail(luma))
            del self._thumbs[:-self.keep]
        self._n += 1

    @property
    def count(self) -> int:
        return len(self._thumbs)

    def view(self) -> np.ndarray | None:
        """The median thumbnail (None before the first frame)."""
        if not self._thumbs:
            return None
        return np.median(np.stack(self._thumbs), axis=0).astype(np.uint8)


def encode_view(view: np.ndarray, frame_width: int) -> dict:
    """The calibration file's ``view`` field: the thumbnail as base64 PNG and the frame width it came from."""
    ok, png = cv2.imencode(".png", view)
    if not ok:
        raise ValueError("cannot encode the view thumbnail")
    return {"png": base64.b64encode(png.tobytes()).decode("ascii"), "frame_width": int(frame_width)}


def decode_view(field: dict, where: str = "calibration") -> tuple[np.ndarray, int]:
    """(thumbnail, frame width) from a calibration file's ``view``; InputError naming ``where`` if it is broken."""
    try:
        img = cv2.imdecode(np.frombuffer(base64.b64decode(field["png"], validate=True), np.uint8),
                           cv2.IMREAD_GRAYSCALE)
        width = int(field["frame_width"])
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{where}: field 'view' is broken ({exc})") from None
    if img is None or width <= 0:
        raise InputError(f"{where}: field 'view' is broken (not a PNG thumbnail)")
    return img, width


def _gradient(img: np.ndarray) -> np.ndarray:
    f = cv2.GaussianBlur(img.astype(np.float32), (0, 0), 0.8)
    return cv2.magnitude(cv2.Sobel(f, cv2.CV_32F, 1, 0), cv2.Sobel(f, cv2.CV_32F, 0, 1))


def _blurred_gradient(img: np.ndarray) -> np.ndarray:
    return cv2.GaussianBlur(_gradient(img), (0, 0), 1.5)


def _correlation(a: np.ndarray, b: np.ndarray, margin: int = 4) -> float:
    x, y = a[margin:-margin, margin:-margin].ravel(), b[margin:-margin, margin:-margin].ravel()
    x, y = x - x.mean(), y - y.mean()
    denom = float(np.sqrt((x * x).sum() * (y * y).sum()))
    return float((x * y).sum() / denom) if denom > 0 else 0.0


def compare_views(stored: np.ndarray, current: np.ndarray, frame_width: int) -> ViewMatch:
    """How the current thumbnail maps onto the stored one (same size): the shift by phase correlation of their
    gradient images, refined to a similarity transform (zoom, rotation) by ECC; their normalised correlation once
    aligned.  Moved when any of them is out of bounds (MAX_SHIFT, MAX_ZOOM, MAX_ROTATION_DEG, MIN_SIMILARITY)."""
    if stored.shape != current.shape:
        return ViewMatch((0.0, 0.0), 0.0, 0.0, 0.0, True)
    a, b = _gradient(stored), _gradient(current)
    window = cv2.createHanningWindow(a.shape[::-1], cv2.CV_32F)
    (dx, dy), _ = cv2.phaseCorrelate(a, b, window)
    warp = np.float32([[1, 0, dx], [0, 1, dy]])  # stored -> current coordinates
    try:
        _, warp = cv2.findTransformECC(a, b, warp, cv2.MOTION_AFFINE,
                                       (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-5), None, 3)
    except cv2.error:  # no convergence (e.g. another scene): the shift alone
        pass
    A = warp[:, :2].astype(np.float64)
    zoom = float(np.sqrt(abs(np.linalg.det(A)))) - 1.0
    rotation = float(np.degrees(np.arctan2(A[1, 0] - A[0, 1], A[0, 0] + A[1, 1])))
    # the translation of the thumbnail's centre (where a camera's re-aim shows)
    c = np.array([a.shape[1] / 2, a.shape[0] / 2])
    tx, ty = A @ c + warp[:, 2] - c
    back = cv2.warpAffine(b, warp, b.shape[::-1], flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REPLICATE)
    sim = _correlation(a, back)
    scale = frame_width / stored.shape[1]
    moved = bool(np.hypot(tx, ty) > MAX_SHIFT or abs(zoom) > MAX_ZOOM or abs(rotation) > MAX_ROTATION_DEG
                 or sim < MIN_SIMILARITY)
    return ViewMatch((float(tx * scale), float(ty * scale)), zoom, rotation, sim, moved, _correlation(a, b))


class RollingView:
    """Every ``every``-th frame's thumbnail in a rolling window of ``window``, with when each was taken: the
    window's median (the traffic passing through left out) and when it turned to what it shows."""

    def __init__(self, every: int = 5, window: int = 9) -> None:
        self.window = int(window)
        self._views = ViewAccumulator(every, keep=self.window)
        self._times: list[float] = []

    def wants(self) -> bool:
        return self._views.wants()

    def skip(self) -> None:
        self._views.skip()

    def sample(self, luma: np.ndarray, t: float) -> np.ndarray | None:
        """Add a frame (luma plane, stream time ``t``) if it is one to sample; the window's median once it holds
        three thumbnails (None before, and for a frame not sampled)."""
        if not self.wants():
            self.skip()
            return None
        self._views.add(luma)
        self._times.append(float(t))
        del self._times[:-self.window]
        return self._views.view() if self._views.count >= min(3, self.window) else None

    def median(self) -> np.ndarray | None:
        return self._views.view()

    def turned(self) -> float:
        """When the median turned: the window's later half began (more than half of it shows what it shows)."""
        n = len(self._times)
        return self._times[max(0, n - n // 2 - 2)]


@dataclass(frozen=True)
class ViewEvent:
    """A change :class:`ViewMonitor` noticed: ``moved`` (``t`` = when the camera moved, stream seconds),
    ``unrecognised`` (the scene no longer matches the view, ``t`` = since when) or ``recognised`` (it matches
    again)."""

    kind: str
    t: float
    match: ViewMatch


class ViewMonitor:
    """Watches a stream for a camera that moves away from a calibration's view (``stored``, a thumbnail of frames
    ``frame_width`` wide).

    Every ``every``-th frame's thumbnail joins a rolling window of ``window``; their median (the traffic passing
    through is not in it) is compared with the stored view.  A move is ``confirm`` comparisons in a row that
    measure a shift, zoom or roll beyond the bounds on a scene still recognised (:attr:`ViewMatch.displaced`); it is
    dated to when the window's median turned (more than half of it after the move), which is usually a little early
    (benchmarks/view_monitor.py: 0.2 s early on 67 of 69 moves, up to 0.6 s late on the others).  A scene that is no
    longer recognised at all (darkness, fog, a covered lens, another scene) is reported as such but not taken for a
    move: the gradients cannot tell those apart, and recalibrating at dusk would throw a good calibration away for
    one that fails; that, and seeing the scene again, take five times as many comparisons in a row.  Cost: one
    :func:`compare_views` (a few ms) per ``every`` frames.
    """

    def __init__(self, stored: np.ndarray, frame_width: int, every: int = 5, window: int = 9, confirm: int = 5) -> None:
        if every < 1 or window < 1 or confirm < 1:
            raise ValueError("every, window and confirm must be at least 1")
        self.stored, self.frame_width = stored, int(frame_width)
        self.confirm = int(confirm)
        self._window = RollingView(every, window)
        self._run_kind, self._run_start, self._run_len = "", 0.0, 0  # the current run of comparisons of one kind
        self.state = "recognised"  # or "unrecognised", "moved" (then the monitor is done)
        self.last: ViewMatch | None = None

    def wants(self) -> bool:
        """Whether the next frame is one the monitor samples (the caller may skip reading the others)."""
        return self.state != "moved" and self._window.wants()

    def skip(self) -> None:
        """Count a frame that is not sampled (:meth:`wants` said no) without reading it."""
        self._window.skip()

    def current(self) -> np.ndarray | None:
        """The median of the rolling window: the scene as the stream shows it now (traffic removed)."""
        return self._window.median()

    def add(self, luma: np.ndarray, t: float) -> ViewEvent | None:
        """Add a frame (its luma plane, at stream time ``t``); returns what changed, if anything."""
        if self.state == "moved":
            self._window.skip()
            return None
        median = self._window.sample(luma, t)
        if median is None:
            return None
        match = compare_views(self.stored, median, self.frame_width)
        self.last = match
        kind = "moved" if match.displaced else "recognised" if match.recognised else "unrecognised"
        if kind != self._run_kind:  # a new run, dated when the median turned
            self._run_kind, self._run_start, self._run_len = kind, self._window.turned(), 0
        self._run_len += 1
        needed = self.confirm if kind == "moved" else 5 * self.confirm  # losing sight of the scene is slower news
        if kind == self.state or self._run_len < needed:
            return None
        self.state = kind
        return ViewEvent(kind, self._run_start, match)


class ViewLibrary:
    """The views a stream has been calibrated on, by key (a calibration's id): a PTZ camera's presets, a camera
    knocked and put back.  :meth:`find` tells which of them, if any, a thumbnail shows — the same view within the
    bounds of :func:`compare_views` (not moved), the most similar one if several.

    Another scene's view costs :func:`compare_views` up to 25 ms (ECC fails slowly), so a library of presets
    would cost a watcher comparing five times a second a good part of a core.  Views whose gradient images, blurred
    (σ 1.5 thumbnail px) and compared as they are, correlate less than ``PREFILTER`` with the thumbnail's are passed
    over first (0.1 ms): on the benchmark scenes (throw-away /tmp/s34/prefilter.py) the same view correlates
    0.84 or more, even shifted to the move bound (1.5 px) 0.80 or more, another scene's 0.27 at the 95th percentile
    and 0.51 at most."""

    PREFILTER = 0.4

    def __init__(self) -> None:
        self.views: dict[str, tuple[np.ndarray, int]] = {}
        self._blurred: dict[str, np.ndarray] = {}

    def __len__(self) -> int:
        return len(self.views)

    def add(self, key: str, view: np.ndarray, frame_width: int) -> None:
        self.views[key] = (view, int(frame_width))
        self._blurred[key] = _blurred_gradient(view)

    def remove(self, key: str) -> None:
        self.views.pop(key, None)
        self._blurred.pop(key, None)

    def find(self, current: np.ndarray | None, exclude: str | None = None) -> tuple[str, ViewMatch] | None:
        best = None
        if current is None:
            return None
        blurred = _blurred_gradient(current)
        for key, (view, width) in self.views.items():
            if key == exclude or view.shape != current.shape:
                continue
            if _correlation(self._blurred[key], blurred) < self.PREFILTER:  # plainly another scene
                continue
            match = compare_views(view, current, width)
            if not match.moved and (best is None or match.similarity > best[1].similarity):
                best = (key, match)
        return best


class ReturnWatcher:
    """While a new view is being learnt: watches for the stream to show one of the ``library``'s views again
    (the PTZ camera went back to a preset before the new one was learnt).  Sampled and dated like
    :class:`ViewMonitor`: every ``every``-th frame into a rolling window of ``window``, whose median must be the
    same known view in ``confirm`` comparisons in a row."""

    def __init__(self, library: ViewLibrary, every: int = 5, window: int = 9, confirm: int = 5) -> None:
        self.library, self.confirm = library, int(confirm)
        self._window = RollingView(every, window)
        self._key, self._start, self._run = None, 0.0, 0

    def add(self, luma: np.ndarray, t: float) -> tuple[str, float, ViewMatch] | None:
        """Add a frame (luma plane, stream time ``t``); returns (key, when the camera got there, the match) once a
        known view is confirmed."""
        median = self._window.sample(luma, t)
        if median is None:
            return None
        found = self.library.find(median)
        key = found[0] if found is not None else None
        if key != self._key:
            self._key, self._start, self._run = key, self._window.turned(), 0
        self._run += 1
        if key is None or self._run < self.confirm:
            return None
        return key, self._start, found[1]
