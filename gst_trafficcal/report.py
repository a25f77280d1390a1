"""``report.html``: one self-contained page summarising a run (every image embedded as base64 PNG).

Sections: the calibration (numbers and a picture of a frame with the road grid and horizon), the vehicles
(speed histogram, statistics with V85 and the vehicles over a speed limit when one is given, counts per lane and direction, why some were not measured, the list), and,
when a ground truth was given, the evaluation (the tables of ``trafficcal eval`` and the cumulative
speed-error plot of :func:`gst_trafficcal.evaluation.plot_cumulative_errors`).
"""

from __future__ import annotations

import base64
import html
import io
import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import cv2
import numpy as np

from .calibration import Calibration
from .drawing import ZONE_BGR, draw_calibration, draw_lane_paths, draw_segments, zone_segments
from .errors import InputError
from .fileio import atomic_write_text
from .geometry import Camera
from .evaluation import ErrorStats, Evaluation, plot_cumulative_errors
from .outputs import AWAY_FROM_VP1, TOWARDS_VP1, VehicleEvent, unmeasured_by_kind
from .traffic_stats import SpeedLimit, as_limit, event_stats, interval_rows
from .zone import Zone

MAX_LISTED = 1000
"""At most this many vehicles are listed one per row (all are counted)."""

_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:2em auto;max-width:1100px;color:#222;
padding:0 1em}
h1{font-size:1.6em;margin-bottom:.2em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.8em}
table{border-collapse:collapse;margin:.6em 0}td,th{border:1px solid #ccc;padding:.25em .6em;text-align:right}
th{background:#f2f2f2}td.l,th.l{text-align:left}img{max-width:100%;border:1px solid #ddd}
.muted{color:#777}.grid{display:flex;flex-wrap:wrap;gap:2em;align-items:flex-start}
.warn{background:#fff4d6;border-left:4px solid #e0a800;padding:.4em .8em}
"""


def png_data_uri(image: np.ndarray) -> str:
    """A ``data:image/png;base64,...`` URI of a BGR (or grey) image."""
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise ValueError("cannot encode image as PNG")
    return "data:image/png;base64," + base64.b64encode(buf.tobytes()).decode("ascii")


def _figure_uri(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _esc(v: object) -> str:
    return html.escape(str(v), quote=True)


def _num(v: float | None, fmt: str = ".2f") -> str:
    return "–" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, fmt)


def _table(header: Sequence[str], rows: Sequence[Sequence[object]], left: int = 1) -> str:
    """An HTML table; the first ``left`` columns are left-aligned text."""
    cls = lambda k: ' class="l"' if k < left else ""  # noqa: E731
    head = "".join(f"<th{cls(k)}>{_esc(h)}</th>" for k, h in enumerate(header))
    body = "".join("<tr>" + "".join(f"<td{cls(k)}>{_esc(v)}</td>" for k, v in enumerate(r)) + "</tr>"
                   for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _img(uri: str, alt: str) -> str:
    return f'<img src="{uri}" alt="{_esc(alt)}">'


# --------------------------------------------------------------------------- pictures


def horizon_in_view(camera: Camera, image_size: tuple[int, int]) -> bool:
    """Whether the horizon line (through VP1 and VP2) crosses the image: the frame's corners on both sides of it."""
    w, h = image_size
    corners = np.array([[0.0, 0.0, 1.0], [w, 0.0, 1.0], [0.0, h, 1.0], [w, h, 1.0]])
    side = corners @ np.asarray(camera.horizon, float)
    return bool(side.min() <= 0.0 <= side.max())


def _picture_base(frame: np.ndarray | None, image_size: tuple[int, int] | None,
                  max_width: int) -> np.ndarray | None:
    """A BGR copy of ``frame`` (or a grey canvas of ``image_size``) at most ``max_width`` wide, to draw on:
    shrunk first, so that thin lines stay thin; None with neither."""
    if frame is None:
        if image_size is None:
            return None
        frame = np.full((image_size[1], image_size[0], 3), 90, np.uint8)
    elif image_size is not None and frame.shape[1::-1] != tuple(image_size):  # a picture of non-square pixels (its
        frame = cv2.resize(frame, tuple(image_size), interpolation=cv2.INTER_AREA)  # file's size; the run's is square)
    img = frame if frame.ndim == 3 else cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    scale = min(1.0, max_width / img.shape[1])
    if scale < 1.0:
        return cv2.resize(img, (max_width, int(round(img.shape[0] * scale))), interpolation=cv2.INTER_AREA)
    return img.copy()


def calibration_picture(calibration: Calibration | None, frame: np.ndarray | None,
                        grid_spacing_m: float = 3.0, max_width: int = 1100,
                        zone: Zone | None = None) -> np.ndarray | None:
    """The frame (or a grey canvas of the calibration's image size) with the road grid and horizon, and the
    detection ``zone`` outlined."""
    size = calibration.image_size if calibration is not None else None
    img = _picture_base(frame, size, max_width)
    if img is None:
        return None
    size = size or frame.shape[1::-1]
    s = img.shape[1] / size[0]  # video pixels -> picture pixels
    thickness = max(1, img.shape[0] // 700)
    if calibration is not None and calibration.camera is not None:
        c = calibration.camera
        cam = Camera(c.vp1 * s, c.vp2 * s, c.pp * s, c.scale)
        draw_calibration(img, cam, grid_spacing_m, thickness)
    if zone is not None:
        draw_segments(img, zone_segments(zone.pixels(size), size) * s, ZONE_BGR, thickness + 1)
    return img


def measured_paths(cars: Sequence, events: Sequence[VehicleEvent]) -> list[tuple[int | None, np.ndarray]]:
    """(lane, reference points in pixels) of every measured vehicle: the BrnoCompSpeed results' cars
    (``brnocompspeed.Track``) with the lanes of their events, for :func:`lanes_picture`.  Of an events file that
    several runs appended to (their track ids start again), the last run's: the results file is the last run's."""
    last_run = events[-1].run if events else None
    lanes = {e.id: e.lane for e in events if e.measured and e.run == last_run}
    return [(lanes[c.id], c.pos) for c in cars if c.id in lanes]


def lanes_picture(frame: np.ndarray | None, image_size: tuple[int, int] | None,
                  paths: Sequence[tuple[int | None, np.ndarray]], max_width: int = 1100) -> np.ndarray | None:
    """The frame, dimmed, with each measured vehicle's reference points coloured by its lane and the lanes named
    (:func:`~gst_trafficcal.drawing.draw_lane_paths`); None without paths or anything to draw them on."""
    img = _picture_base(frame, image_size, max_width) if paths else None
    if img is None:
        return None
    img //= 2  # dimmed
    # the paths are in the video's pixels: the calibration's image size, or the frame's
    s = img.shape[1] / (image_size[0] if image_size is not None else frame.shape[1])
    return draw_lane_paths(img, [(lane, np.asarray(p, np.float64) * s) for lane, p in paths],
                           max(1, img.shape[0] // 500))


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _limit_lines(ax, limit: "SpeedLimit | float | None", horizontal: bool, dashed: bool = False) -> None:
    """The speed limit on a plot: red, solid for everyone's (dashed too with ``dashed``, over other lines), dashed
    and thinner for each class with its own."""
    limit = as_limit(limit)
    line = ax.axhline if horizontal else ax.axvline
    if limit.kmh is not None:
        line(limit.kmh, color="#d62728", lw=1.5 if dashed else 2, ls="--" if dashed else "-",
             label=f"limit {limit.kmh:g} km/h")
    for name, kmh in limit.by_class:
        line(kmh, color="#d62728", lw=1.0 if dashed else 1.2, ls="--", label=f"{name} limit {kmh:g} km/h")


def speed_histogram_uri(speeds: np.ndarray, limit_kmh: "SpeedLimit | float | None" = None) -> str:
    """Histogram of measured speeds (km/h) as a PNG data URI; V85 (and the speed limit, when given) marked."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 3.6))
    try:
        lo, hi = float(np.floor(speeds.min() / 5) * 5), float(np.ceil(speeds.max() / 5) * 5)
        bins = np.arange(lo, max(hi, lo + 5) + 5, 5.0) if hi - lo <= 200 else 40
        ax.hist(speeds, bins=bins, color="#3c78d8", edgecolor="white")
        ax.axvline(float(np.percentile(speeds, 85)), color="#222", ls="--", lw=1.2, label="V85")
        _limit_lines(ax, limit_kmh, horizontal=False)
        ax.legend(loc="upper right", fontsize=8)
        ax.set_xlabel("speed [km/h]")
        ax.set_ylabel("vehicles")
        ax.set_title(f"Measured speeds (n={len(speeds)})")
        ax.grid(axis="y", alpha=0.3)
        fig.tight_layout()
        return _figure_uri(fig)
    finally:
        plt.close(fig)


DIRECTION_COLOURS = {TOWARDS_VP1: "#3c78d8", AWAY_FROM_VP1: "#e69138", None: "#888888"}


def speed_time_uri(events: Sequence[VehicleEvent], limit_kmh: "SpeedLimit | float | None" = None) -> str | None:
    """Each measured vehicle's speed against when it passed (the middle of its time in view; the clock when the
    events are dated, else stream seconds), coloured by direction, the limit marked: congestion, a quiet night
    or a faster direction show at a glance.  None with fewer than two measured vehicles that say when they passed
    (an events file written by another tool may leave the times out)."""
    def on_clock(e: VehicleEvent) -> bool:
        return bool(e.first_time and e.last_time)

    def in_stream(e: VehicleEvent) -> bool:
        return e.first_timestamp_s is not None and e.last_timestamp_s is not None

    measured = [e for e in events if e.measured and (on_clock(e) or in_stream(e))]
    dated = all(on_clock(e) for e in measured)
    if not dated:
        measured = [e for e in measured if in_stream(e)]
    if len(measured) < 2:
        return None
    if dated:
        first = [datetime.fromisoformat(e.first_time) for e in measured]
        when = [f + (datetime.fromisoformat(e.last_time) - f) / 2 for f, e in zip(first, measured)]
    else:
        when = [(e.first_timestamp_s + e.last_timestamp_s) / 2 for e in measured]
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 3.6))
    try:
        for d in (TOWARDS_VP1, AWAY_FROM_VP1, None):
            idx = [i for i, e in enumerate(measured) if e.direction == d]
            if idx:
                ax.scatter([when[i] for i in idx], [measured[i].speed_kmh for i in idx], s=14,
                           color=DIRECTION_COLOURS[d], label=_direction_label(d), linewidths=0)
        _limit_lines(ax, limit_kmh, horizontal=True)
        ax.legend(loc="best", fontsize=8)
        ax.set_xlabel("time of day" if dated else "time in the video [s]")
        if dated:
            fig.autofmt_xdate()
        ax.set_ylabel("speed [km/h]")
        ax.set_title("Speeds over time")
        ax.grid(alpha=0.3)
        fig.tight_layout()
        return _figure_uri(fig)
    finally:
        plt.close(fig)


def intervals_uri(names: Sequence[str], vehicles: Sequence[int], v85: Sequence[float | None],
                  limit_kmh: "SpeedLimit | float | None" = None) -> str:
    """Vehicles per interval (bars) and their V85 (line, right axis; the limit dashed) as a PNG data URI."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 3.6))
    try:
        x = np.arange(len(names))
        ax.bar(x, vehicles, color="#9fc5e8", label="vehicles")
        ax.set_ylabel("vehicles per interval")
        step = max(1, len(names) // 12)
        ax.set_xticks(x[::step], [names[i] for i in range(0, len(names), step)], rotation=30, ha="right",
                      fontsize=8)
        right = ax.twinx()
        right.plot(x, [np.nan if v is None else v for v in v85], "o-", color="#222", label="V85")
        _limit_lines(right, limit_kmh, horizontal=True, dashed=True)
        right.set_ylabel("V85 [km/h]")
        right.legend(loc="best", fontsize=8)
        ax.set_title("Traffic per interval")
        fig.tight_layout()
        return _figure_uri(fig)
    finally:
        plt.close(fig)


def cumulative_error_uri(errors_kmh: np.ndarray, label: str = "this run") -> str | None:
    """The evaluator's cumulative speed-error plot as a PNG data URI (None when no car was matched)."""
    buf = io.BytesIO()
    try:
        plot_cumulative_errors({label: np.asarray(errors_kmh, float)}, buf)
    except InputError:
        return None
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


# --------------------------------------------------------------------------- sections


#: what a calibration's ``confidence`` entries mean, for people (vpdetect's evidence, bbscale's confidence; the
#: calibration file keeps the keys): key -> (row label, format); other keys are shown as "confidence: key"
CONFIDENCE_LABELS: dict[str, tuple[str, str]] = {
    "vp1": ("VP1 support (share of the tracks' weight through it)", "{:.2f}"),
    "vp2": ("VP2 support (share of the edgelets' weight through it)", "{:.2f}"),
    "tracks": ("vehicle tracks voted for VP1", "{:.0f}"),
    "edgelets": ("vehicle edgelets voted for VP2", "{:.0f}"),
    "seconds": ("video watched until the vanishing points were found [s]", "{:.1f}"),
    "speed_tracks": ("tracks whose constant-speed motion placed VP1 along the lanes", "{:.0f}"),
    "vp1_along_px": ("VP1 moved along the lanes by the tracks' motion [px]", "{:+.1f}"),
    "vp1_along_refused_px": ("VP1 move along the lanes asked for but refused (too far) [px]", "{:+.1f}"),
    "vp1_across_px": ("VP1 moved across the lanes to where the tracks meet [px]", "{:+.1f}"),
    "scale": ("scale confidence (bbscale: share of matched vehicles that agree)", "{:.2f}"),
}


def _calibration_section(cal: Calibration | None, frame: np.ndarray | None, spacing: float,
                         zone: Zone | None = None) -> str:
    out = ["<h2>Calibration</h2>"]
    if cal is None:
        out.append('<p class="muted">No calibration was obtained.</p>')
    else:
        rows: list[tuple[str, str]] = [("state", cal.state), ("source", cal.source), ("id", cal.id),
                                       ("image size", f"{cal.image_size[0]} x {cal.image_size[1]}")]
        if cal.reason:
            rows.append(("reason", cal.reason))
        c = cal.camera
        if c is not None:
            rows += [("VP1 (traffic direction) [px]", f"{c.vp1[0]:.1f}, {c.vp1[1]:.1f}"),
                     ("VP2 (across the road) [px]", f"{c.vp2[0]:.1f}, {c.vp2[1]:.1f}"),
                     ("principal point [px]", f"{c.pp[0]:.1f}, {c.pp[1]:.1f}"),
                     ("focal length [px]", f"{c.focal:.1f}")]
            cond = cal.conditioning()
            rows.append((f"speeds change under a {cond.turn_deg:g}° error of VP2 [%]",
                         f"{cond.speed_pct:.2f}" + (" (poorly conditioned view)" if cond.poor else "")))
            if c.scale is not None:
                rows += [("scale λ = camera height [m]", f"{c.scale:.3f}"),
                         ("BrnoCompSpeed scale", f"{c.brno_scale():.6g}")]
            else:
                rows.append(("scale", "unknown (no speeds in km/h)"))
        for k, v in cal.confidence.items():
            label, fmt = CONFIDENCE_LABELS.get(k, (f"confidence: {k}", "{:.3g}"))
            rows.append((label, fmt.format(v)))
        if zone is not None:
            rows.append(("detection zone" + (" [fractions of the frame]" if zone.relative else " [px]"), str(zone)))
        out.append(_table(["", "value"], rows))
        if c is not None and cond.poor:
            out.append(f'<p class="warn">{_esc(cond.describe())}.</p>')
    pic = calibration_picture(cal, frame, spacing, zone=zone)
    if pic is not None:
        if cal is not None and cal.camera is not None:
            horizon = (" and the horizon (red)" if horizon_in_view(cal.camera, cal.image_size)
                       else "; the horizon, through both vanishing points, lies outside the picture")
            caption = (f"Road grid ({spacing:g} m cells; amber lines run towards VP1, blue towards VP2){horizon}.")
        else:
            caption = "A frame of the video."
        if zone is not None:
            caption += " Violet: the detection zone (vehicles standing outside it are neither counted nor measured)."
        out.append(f"<figure>{_img(png_data_uri(pic), 'calibration picture')}<figcaption>{_esc(caption)}"
                   "</figcaption></figure>")
    return "\n".join(out)


def _stats_header(limit: SpeedLimit) -> list[str]:
    head = ["speed [km/h]", "n", "mean", "median", "V85", "p95", "max"]
    return head + ([f"over {limit.describe()}"] if limit else [])


def _stats_row(name: str, events: Sequence[VehicleEvent], limit: SpeedLimit) -> list[str]:
    s = event_stats(events, limit)
    row = [name, str(s.n)] + [_num(x) for x in (s.mean, s.median, s.v85, s.p95, s.max)]
    if limit:
        row.append(f"{s.over_limit} ({100 * s.share_over:.0f} %)" if s.n else "0")
    return row


def _direction_label(d: str | None) -> str:
    return {TOWARDS_VP1: "towards VP1", AWAY_FROM_VP1: "away from VP1"}.get(d or "", "unknown")


def not_counted_text(brief: int, stationary: int) -> str:
    """The sentence on the tracks not counted as vehicles (``measurement.not_a_vehicle``); "" when none were."""
    from .measurement import MIN_PASSING_M, MIN_SEEN_S

    parts = []
    if brief:
        parts.append(f"{brief} seen for under {MIN_SEEN_S:g} s (pieces of vehicles counted once, or a detector's "
                     "flicker)")
    if stationary:
        parts.append(f"{stationary} that did not move {MIN_PASSING_M:g} m along the road (parked vehicles, or fixed "
                     "objects taken for one)")
    return f"Tracks not counted as vehicles: {' and '.join(parts)}." if parts else ""


def _vehicles_section(events: Sequence[VehicleEvent], limit_kmh: SpeedLimit = SpeedLimit(),
                      remeasured: tuple[int, int] = (0, 0), not_counted: tuple[int, int] = (0, 0),
                      lanes_fig: str = "") -> str:
    out = ["<h2>Vehicles</h2>"]
    measured = [e for e in events if e.measured]
    speeds = np.array([e.speed_kmh for e in measured], float)
    again = (f" {remeasured[0]} of them passed before the calibration settled and were measured again with the "
             f"final one at the end ({remeasured[1]} with a speed)." if remeasured[0] else "")
    out.append(f"<p>{len(events)} vehicles, {len(measured)} with a measured speed.{again}</p>")
    sure = [(e.speed_uncertainty_kmh, e.speed_kmh) for e in measured if e.speed_uncertainty_kmh is not None]
    if sure:
        u = np.array(sure, float)
        out.append(f"<p>Each speed comes with ± U, the half-width of an interval meant to hold the true speed for "
                   f"about 95 % of vehicles (the vehicle list's ± column): median U {np.median(u[:, 0]):.1f} km/h "
                   f"({np.median(100 * u[:, 0] / u[:, 1]):.1f} % of the speed), from the spread of the vehicle's "
                   f"own speed samples and the calibration's (how firmly the view pins the speeds down).</p>")
    if any(not_counted):
        out.append(f'<p class="muted">{_esc(not_counted_text(*not_counted))}</p>')
    if not events:
        return "\n".join(out)
    out.append('<p class="muted">Directions: <i>towards VP1</i> are the vehicles driving away from the camera, into '
               'the distance along the road; <i>away from VP1</i> those coming towards it. In overlay.mp4 their boxes '
               'are green and magenta, yellow while the direction is not known yet, and dark red over a speed '
               'limit; the counters there are those of the frame shown, the final ones are these (vehicles measured '
               'again at the end of a file included).</p>')
    blocks = []
    if len(speeds):
        blocks.append(_img(speed_histogram_uri(speeds, limit_kmh), "speed histogram"))
    over_time = speed_time_uri(events, limit_kmh)
    if over_time is not None:
        blocks.append(_img(over_time, "speeds over time"))
    tables = [_table(_stats_header(limit_kmh),
                     [_stats_row("all", measured, limit_kmh)]
                     + [_stats_row(_direction_label(d), [e for e in measured if e.direction == d], limit_kmh)
                        for d in (TOWARDS_VP1, AWAY_FROM_VP1) if any(e.direction == d for e in measured)])]
    # per lane and direction, as intervals.csv counts them: a lane that holds both directions shows both
    lanes = Counter((e.lane, e.direction) for e in events)
    lane_meas = Counter((e.lane, e.direction) for e in measured)
    order = {TOWARDS_VP1: 0, AWAY_FROM_VP1: 1}
    lane_rows = []
    for lane, d in sorted(lanes, key=lambda k: (k[0] is None, k[0] or 0, order.get(k[1] or "", 2))):
        st = event_stats([e for e in measured if e.lane == lane and e.direction == d], limit_kmh)
        row = ["unknown" if lane is None else f"lane {lane}", _direction_label(d), lanes[lane, d],
               lane_meas[lane, d], _num(st.mean), _num(st.v85)]
        lane_rows.append(row + ([st.over_limit] if limit_kmh else []))
    lane_header = ["lane", "direction", "vehicles", "measured", "mean speed [km/h]", "V85 [km/h]"]
    tables.append("<h3>Per lane</h3>" + _table(
        lane_header + ([f"over {limit_kmh.describe()}"] if limit_kmh else []), lane_rows))
    classes = Counter(e.label or "unknown" for e in events)
    class_rows = []
    for label, n in classes.most_common():
        v = np.array([e.speed_kmh for e in measured if (e.label or "unknown") == label], float)
        class_rows.append([label, n, len(v), _num(float(np.mean(v))) if len(v) else "–"])
    tables.append("<h3>Per class</h3>" + _table(["class", "vehicles", "measured", "mean speed [km/h]"], class_rows))
    dirs = Counter(e.direction for e in events)
    tables.append("<h3>Per direction</h3>" + _table(["direction", "vehicles"],
                                                    [[_direction_label(d), n] for d, n in dirs.most_common()]))
    runs = Counter(e.run for e in events)
    if len(runs) > 1:  # runs appended to one file (speedometer append): their track ids start again at 1
        run_rows = []
        for run, n in runs.items():
            mine = [e for e in events if e.run == run]
            v = np.array([e.speed_kmh for e in mine if e.measured], float)
            first = min((e.first_time for e in mine if e.first_time), default="–")
            run_rows.append([run or "unknown", n, len(v), first, _num(float(np.mean(v))) if len(v) else "–"])
        tables.append("<h3>Per run</h3>" + _table(["run", "vehicles", "measured", "first seen", "mean speed [km/h]"],
                                                  run_rows))
    reasons = unmeasured_by_kind(events)
    if reasons:  # by kind; each vehicle's own reason, with its figures, is in the list below
        tables.append("<h3>Not measured</h3>" + _table(["reason", "vehicles"], reasons))
    blocks.append("<div>" + "".join(tables) + "</div>")
    out.append('<div class="grid">' + "".join(blocks) + "</div>")
    if lanes_fig:
        out.append(lanes_fig)
    listed = events[:MAX_LISTED]
    dated = any(e.first_time for e in listed)
    several = len(runs) > 1
    rows = [[*([e.run or "–"] if several else []), e.id, e.label, *([e.first_time or "–"] if dated else []),
             _num(e.first_timestamp_s, ".2f"), _num(e.last_timestamp_s, ".2f"), _num(e.speed_kmh, ".1f"),
             _num(e.speed_uncertainty_kmh, ".1f"), "–" if e.lane is None else e.lane,
             _direction_label(e.direction), _size(e), e.reason] for e in listed]
    more = f" (the first {MAX_LISTED} of {len(events)})" if len(events) > MAX_LISTED else ""
    out.append(f"<details><summary>Vehicle list{more}</summary>"
               + _table([*(["run"] if several else []), "id", "label", *(["first seen"] if dated else []),
                         "first [s]", "last [s]", "speed [km/h]", "± [km/h], 95 %", "lane", "direction",
                         "size L × W × H [m]", "reason"],
                        rows, left=3 if several else 2) + "</details>")
    return "\n".join(out)


def _intervals_section(events: Sequence[VehicleEvent], interval_s: float, start: datetime | None,
                       limit_kmh: SpeedLimit, covered: Sequence[tuple[float, float]] | None = None) -> str:
    """Every vehicle of each interval (per lane and direction: intervals.csv); nothing without timestamps.  With
    ``covered`` (the stream time the video spans) every interval it reaches, and how much of it was watched."""
    rows = [r for r in interval_rows(events, interval_s, start, limit_kmh, covered) if r.total]
    if not rows:
        return ""
    head = ["interval", "vehicles", "measured", "mean [km/h]", "V85 [km/h]"]
    body = []
    for r in rows:
        s = r.speeds
        name = f"{r.start} – {r.end}"
        if r.observed_s is not None and r.observed_s < interval_s - 0.5:
            name += f" ({r.observed_s / 60:.1f} min watched)" if r.observed_s >= 60 else \
                f" ({r.observed_s:.0f} s watched)"
        body.append([name, r.vehicles, s.n, _num(s.mean), _num(s.v85)] + ([s.over_limit] if limit_kmh else []))
    what = f"{interval_s / 60:g} min" + ("" if start is not None else ", from the start of the video")
    table = _table(head + ([f"over {limit_kmh.describe()}"] if limit_kmh else []), body)
    if len(rows) < 2:
        return f"<h2>Per interval ({_esc(what)})</h2>" + table
    names = [r.start[11:16] if start is not None else r.start for r in rows]  # HH:MM of a date, else stream time
    plot = _img(intervals_uri(names, [r.vehicles for r in rows], [r.speeds.v85 for r in rows], limit_kmh),
                "traffic per interval")
    return f'<h2>Per interval ({_esc(what)})</h2><div class="grid">{plot}<div>{table}</div></div>'


def _size(e: VehicleEvent) -> str:
    dims = (e.length_m, e.width_m, e.height_m)
    return "–" if any(v is None for v in dims) else " × ".join(f"{v:.1f}" for v in dims)


def _stats_cells(s: ErrorStats | None) -> list[str]:
    if s is None:
        return ["–"] * 6
    return [str(s.n)] + [_num(v, ".3g") for v in (s.mean, s.median, s.p95, s.p99, s.max)]


def _evaluation_section(ev: Evaluation, gt_name: str) -> str:
    out = [f"<h2>Evaluation against the ground truth</h2><p>Ground truth: {_esc(gt_name or 'given')}; "
           "BrnoCompSpeed's official metrics (median speed mode, matching at the measurement line within "
           "0.2 s).</p>"]
    head = ["metric", "n", "mean", "median", "p95", "p99", "max"]
    s = ev.speed
    if s is not None:
        out.append("<h3>Speed errors (matched valid vehicles)</h3>"
                   + _table(head, [["speed [km/h]", *_stats_cells(s.abs_kmh)],
                                   ["speed [%]", *_stats_cells(s.rel_pct)]]))
        out.append(_table(["", "value"], [
            ["recall", _num(s.recall, ".4f")], ["false positives", s.false_positives],
            ["matched (valid / valid in ground truth)", f"{s.matched} ({s.matched_valid} / {s.n_gt_valid})"],
            ["vehicles in results / after prefilter", f"{s.n_cars} / {s.n_cars_after_prefilter}"]]))
        uri = cumulative_error_uri(s.errors_abs_kmh)
        if uri is not None:
            out.append(_img(uri, "cumulative speed error"))
        else:
            out.append('<p class="muted">No vehicle was matched with the ground truth: no error plot.</p>')
    c = ev.calibration
    if c is not None:
        rows = [["distance ratio", *_stats_cells(c.ratio_abs)], ["distance ratio [%]", *_stats_cells(c.ratio_rel_pct)]]
        if c.dist_all_abs_m is not None:
            rows += [["distance, all [m]", *_stats_cells(c.dist_all_abs_m)],
                     ["distance, all [%]", *_stats_cells(c.dist_all_rel_pct)],
                     ["distance, to VP1 [m]", *_stats_cells(c.dist_vp1_abs_m)],
                     ["distance, to VP1 [%]", *_stats_cells(c.dist_vp1_rel_pct)]]
        out.append("<h3>Calibration errors</h3>" + _table(head, rows))
    return "\n".join(out)


# --------------------------------------------------------------------------- the page


@dataclass(frozen=True)
class ReportInputs:
    """Everything the report shows; only ``events`` is required."""

    events: Sequence[VehicleEvent]
    calibration: Calibration | None = None
    frame: np.ndarray | None = None  # a BGR frame of the video for the calibration picture
    evaluation: Evaluation | None = None
    ground_truth_name: str = ""
    title: str = "gst-trafficcal report"
    source: str = ""  # the video
    grid_spacing_m: float = 3.0
    speed_limit_kmh: "SpeedLimit | float | None" = None  # marks the plots, counts the vehicles over it (per class)
    interval_s: float = 900.0  # the "Per interval" table's interval
    start_time: datetime | None = None  # date and time of stream time 0: intervals aligned to and named by the clock
    covered: Sequence[tuple[float, float]] | None = None  # stream time (s) the video spans: every interval it reaches
    remeasured: tuple[int, int] = (0, 0)  # vehicles measured again at the end with the final calibration (with speed)
    not_counted: tuple[int, int] = (0, 0)  # tracks that were no vehicle passing: (brief, stationary)
    paths: Sequence[tuple[int | None, np.ndarray]] = ()  # (lane, reference points in pixels) of measured vehicles
    zone: Zone | None = None  # the detection zone the run used (outlined in the calibration picture)
    warnings: Sequence[str] = ()  # what the run warned about (trafficcal run: as on its terminal and in run.log)


def render_report(inputs: ReportInputs) -> str:
    """The report as one HTML string (no external resources)."""
    parts = [f"<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>{_esc(inputs.title)}</title>"
             f"<style>{_CSS}</style></head><body><h1>{_esc(inputs.title)}</h1>"]
    if inputs.source:
        parts.append(f'<p class="muted">Video: {_esc(inputs.source)}</p>')
    parts.append(f'<p class="muted">{_esc(_run_line(inputs))}</p>')
    if inputs.warnings:  # read before the figures they qualify (frame times smoothed, a short video, a camera move)
        parts.append(_warnings_section(inputs.warnings))
    parts.append(_calibration_section(inputs.calibration, inputs.frame, inputs.grid_spacing_m, inputs.zone))
    limit = as_limit(inputs.speed_limit_kmh)
    size = inputs.calibration.image_size if inputs.calibration is not None else None
    lanes = lanes_picture(inputs.frame, size, inputs.paths)
    lanes_fig = ("" if lanes is None else
                 f"<figure>{_img(png_data_uri(lanes), 'where the lanes are')}<figcaption>Where the lanes are: each "
                 "measured vehicle's reference points (the middle of its box's bottom front edge), in the colour of "
                 "the lane it is counted in (grey: none), each lane named where its vehicles came nearest."
                 "</figcaption></figure>")
    parts.append(_vehicles_section(list(inputs.events), limit, inputs.remeasured, inputs.not_counted, lanes_fig))
    parts.append(_intervals_section(list(inputs.events), inputs.interval_s, inputs.start_time, limit,
                                    inputs.covered))
    if inputs.evaluation is not None:
        parts.append(_evaluation_section(inputs.evaluation, inputs.ground_truth_name))
    parts.append("</body></html>\n")
    return "\n".join(parts)


def _warnings_section(warnings: Sequence[str]) -> str:
    """What the run warned about, each once, in the order it came (also in run.log, dated)."""
    items = "".join(f'<p class="warn">{_esc(w)}</p>' for w in dict.fromkeys(warnings))
    return f"<h2>Warnings</h2><p class=\"muted\">What the run warned about (also in run.log, dated).</p>{items}"


def _run_line(inputs: ReportInputs) -> str:
    """What the report covers, in one line: the stream time watched (and its clock times), the vehicles and their
    flow per hour, the software and when the report was written."""
    from datetime import timezone

    from . import __version__

    parts = []
    watched = sum(max(0.0, b - a) for a, b in inputs.covered or ())
    if watched > 0:
        span = f"{_clock_span(inputs.start_time, inputs.covered)}" if inputs.start_time is not None else ""
        parts.append(f"{_duration(watched)} of video watched{span}")
    n, measured = len(inputs.events), sum(e.measured for e in inputs.events)
    flow = f", {3600.0 * n / watched:.0f} vehicles/h" if watched >= 60 else ""
    parts.append(f"{n} vehicles ({measured} with a speed){flow}")
    written = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    parts.append(f"gst-trafficcal {__version__}, report written {written}")
    return " · ".join(parts)


def _duration(seconds: float) -> str:
    m, s = divmod(int(round(seconds)), 60)
    h, m = divmod(m, 60)
    return f"{h} h {m:02d} min" if h else (f"{m} min {s:02d} s" if m else f"{seconds:.1f} s")


def _clock_span(start: datetime, covered: Sequence[tuple[float, float]]) -> str:
    from datetime import timedelta

    first, last = min(a for a, _ in covered), max(b for _, b in covered)
    a, b = start + timedelta(seconds=first), start + timedelta(seconds=last)
    return f" ({a:%Y-%m-%d %H:%M:%S} – {b:%H:%M:%S})"


def write_report(path: str | Path, inputs: ReportInputs) -> Path:
    """Write ``report.html`` atomically; InputError naming the file when it cannot be written."""
    return atomic_write_text(path, render_report(inputs), "report")
