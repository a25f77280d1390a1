"""report.html: parsed with html.parser, embedded images decoded, tables checked against the inputs."""

from __future__ import annotations

import base64
import csv
import json
from collections import Counter
from html.parser import HTMLParser
from pathlib import Path

import cv2
import numpy as np
import pytest

from .conftest import BRNO, require_shared
from gst_trafficcal.brnocompspeed import load_gt_data, load_results
from gst_trafficcal.calibration import Calibration
from gst_trafficcal.errors import InputError
from gst_trafficcal.evaluation import evaluate, median_speeds
from gst_trafficcal.geometry import Camera, rotation_matrix
from gst_trafficcal.outputs import VehicleEvent
from gst_trafficcal.report import ReportInputs, calibration_picture, render_report, write_report

W, H = 640, 360


class _Page(HTMLParser):
    """Tags, images, headings and tables (rows of cell texts) of an HTML page."""

    def __init__(self) -> None:
        super().__init__()
        self.tags: Counter[str] = Counter()
        self.attrs: list[tuple[str, dict[str, str | None]]] = []
        self.images: list[str] = []
        self.headings: list[str] = []
        self.tables: list[list[list[str]]] = []
        self._cell: list[str] | None = None
        self._heading: list[str] | None = None
        self.text: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.tags[tag] += 1
        d = dict(attrs)
        self.attrs.append((tag, d))
        if tag == "img":
            self.images.append(d.get("src") or "")
        elif tag == "table":
            self.tables.append([])
        elif tag == "tr":
            self.tables[-1].append([])
        elif tag in ("td", "th"):
            self._cell = []
        elif tag in ("h1", "h2", "h3"):
            self._heading = []

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None:
            self.tables[-1][-1].append("".join(self._cell).strip())
            self._cell = None
        elif tag in ("h1", "h2", "h3") and self._heading is not None:
            self.headings.append("".join(self._heading).strip())
            self._heading = None

    def handle_data(self, data):
        self.text.append(data)
        if self._cell is not None:
            self._cell.append(data)
        if self._heading is not None:
            self._heading.append(data)


def _parse(text: str) -> _Page:
    p = _Page()
    p.feed(text)
    p.close()
    return p


def _decode(uri: str) -> np.ndarray:
    prefix = "data:image/png;base64,"
    assert uri.startswith(prefix)
    img = cv2.imdecode(np.frombuffer(base64.b64decode(uri[len(prefix):], validate=True), np.uint8),
                       cv2.IMREAD_COLOR)
    assert img is not None and img.size > 0
    return img


def _table_after(page: _Page, first_header: str) -> list[list[str]]:
    for t in page.tables:
        if t and t[0] and t[0][0] == first_header:
            return t
    raise AssertionError(f"no table starting with {first_header!r}")


def _calibration() -> Calibration:
    K = np.array([[600.0, 0, W / 2], [0, 600.0, H / 2], [0, 0, 1]])
    R = rotation_matrix(20.0, 12.0, 0.0)
    return Calibration(Camera.from_KRt(K, R, -R @ np.array([0.0, 0.0, 7.0])), (W, H), source="vpdetect",
                       confidence={"vp1": 0.93, "edgelets": 2163.0, "vp1_along_refused_px": -43.27, "new_key": 1.5})


def _events() -> list[VehicleEvent]:
    rng = np.random.default_rng(1)
    out = []
    for i in range(40):
        measured = i % 7 != 3
        out.append(VehicleEvent(i + 1, "car" if i % 4 else "truck", i * 1.0, i * 1.0 + 2.0,
                                float(rng.normal(80, 10)) if measured else None,
                                "" if measured else ("track too short" if i % 2 else "no calibration with scale"),
                                lane=[0, 1, 1, None][i % 4], direction=1 if i % 3 else -1, calibration_id="abc",
                                speed_uncertainty_kmh=2.0 + i / 10 if measured else None,
                                **({"length_m": 4.52, "width_m": 1.79, "height_m": 1.46} if i % 2 else {})))
    return out


def test_report_without_ground_truth() -> None:
    frame = np.full((H, W, 3), 100, np.uint8)
    events = _events()
    page = _parse(render_report(ReportInputs(events, _calibration(), frame, source="cam1.mp4")))
    assert page.headings[:3] == ["gst-trafficcal report", "Calibration", "Vehicles"]
    assert "Evaluation against the ground truth" not in page.headings
    pics = [_decode(u) for u in page.images]
    assert len(pics) == 3  # calibration picture, speed histogram, speeds over time
    assert pics[0].shape == (H, W, 3)
    # speeds over time: a point per measured vehicle in its direction's colour (BGR of #3c78d8 and #e69138)
    colour = lambda img, bgr: int(np.sum(np.all(np.abs(img.astype(int) - bgr) <= 12, axis=2)))  # noqa: E731
    assert colour(pics[2], (216, 120, 60)) > 100 and colour(pics[2], (56, 145, 230)) > 100
    one_way = [e for e in events if e.direction != "away_from_vp1"]
    alone = _decode(_parse(render_report(ReportInputs(one_way, _calibration()))).images[-1])
    assert colour(alone, (216, 120, 60)) > 100 and colour(alone, (56, 145, 230)) == 0
    drawn = np.any(pics[0] != 100, axis=2)
    assert 0.02 < drawn.mean() < 0.6  # the grid and the horizon on the frame
    # numbers of the page = numbers of the inputs
    measured = [e for e in events if e.measured]
    text = "".join(page.text)
    assert f"{len(events)} vehicles, {len(measured)} with a measured speed." in text
    lanes = _table_after(page, "lane")  # per lane and direction
    names = {"towards_vp1": "towards VP1", "away_from_vp1": "away from VP1"}
    want = Counter((f"lane {e.lane}" if e.lane is not None else "unknown", names[e.direction]) for e in events)
    got = {(r[0], r[1]): int(r[2]) for r in lanes[1:]}
    assert got == dict(want) and len(got) > 3
    got_measured = Counter()
    for r in lanes[1:]:
        got_measured[r[0]] += int(r[3])
    assert got_measured == Counter(f"lane {e.lane}" if e.lane is not None else "unknown" for e in measured)
    stats = _table_after(page, "speed [km/h]")
    speeds = [e.speed_kmh for e in measured]
    assert stats[1][:3] == ["all", str(len(measured)), f"{np.mean(speeds):.2f}"]
    assert stats[0][4] == "V85" and stats[1][4] == f"{np.percentile(speeds, 85):.2f}" and len(stats[0]) == 7
    lane0 = [e.speed_kmh for e in measured if e.lane == 0 and e.direction == "towards_vp1"]
    assert lanes[1][:2] == ["lane 0", "towards VP1"]
    assert lanes[0][5] == "V85 [km/h]" and lanes[1][5] == f"{np.percentile(lane0, 85):.2f}"
    reasons = {r[0]: int(r[1]) for r in _table_after(page, "reason")[1:]}
    assert reasons == dict(Counter(e.reason for e in events if not e.measured))
    classes = {r[0]: (int(r[1]), int(r[2])) for r in _table_after(page, "class")[1:]}
    assert classes == {c: (sum(e.label == c for e in events), sum(e.label == c for e in measured))
                       for c in ("car", "truck")}
    directions = {r[0]: int(r[1]) for r in _table_after(page, "direction")[1:]}
    assert directions == {"towards VP1": sum(e.direction == "towards_vp1" for e in events),
                          "away from VP1": sum(e.direction == "away_from_vp1" for e in events)}
    listing = _table_after(page, "id")
    assert len(listing) == len(events) + 1 and listing[4][4] == "–"  # vehicle 4 was not measured
    size = listing[0].index("size L × W × H [m]")
    assert listing[2][size] == "4.5 × 1.8 × 1.5" and listing[1][size] == "–"  # vehicle 2 has a size, 1 none
    sure = listing[0].index("± [km/h], 95 %")  # each speed's uncertainty beside it, none without a speed
    assert sure == listing[0].index("speed [km/h]") + 1 and listing[2][sure] == "2.1" and listing[4][sure] == "–"
    u = [e.speed_uncertainty_kmh for e in events if e.measured]
    assert any(f"median U {np.median(u):.1f} km/h" in t for t in page.text)
    calib = {r[0]: r[1] for r in _table_after(page, "")[1:]}
    assert calib["state"] == "calibrated" and calib["scale λ = camera height [m]"] == "7.000"
    # the calibration's evidence in words, its figures as the file has them; a key the report does not know as it is
    assert calib["VP1 support (share of the tracks' weight through it)"] == "0.93"
    assert calib["vehicle edgelets voted for VP2"] == "2163"
    assert calib["VP1 move along the lanes asked for but refused (too far) [px]"] == "-43.3"
    assert calib["confidence: new_key"] == "1.5"
    sensitivity = _calibration().conditioning().speed_pct
    assert calib["speeds change under a 0.1° error of VP2 [%]"] == f"{sensitivity:.2f}" and sensitivity < 2
    assert not [a for tag, a in page.attrs if a.get("class") == "warn"]


def test_report_shows_where_the_lanes_are() -> None:
    """With the measured vehicles' reference points: a picture of the frame, dimmed, with each vehicle's points in
    its lane's colour and the lanes named — placed after the per-lane counts it explains; none without points."""
    from gst_trafficcal.drawing import NO_LANE_BGR, lane_bgr

    frame = np.full((H, W, 3), 100, np.uint8)
    events = _events()
    x0 = {0: 100.0, 1: 160.0, None: 400.0}
    paths = [(e.lane, np.array([[x0[e.lane], 80.0], [x0[e.lane] + 20, 300.0]])) for e in events if e.measured]
    page = _parse(render_report(ReportInputs(events, _calibration(), frame, paths=paths)))
    alts = [a.get("alt") for tag, a in page.attrs if tag == "img"]
    pic = _decode(page.images[alts.index("where the lanes are")])
    assert pic.shape == (H, W, 3) and pic[5, 5].tolist() == [50, 50, 50]  # the frame, dimmed
    for lane, x in ((0, 110), (1, 170)):  # the middle of each lane's line: its brightest pixel is of its colour
        window = pic[190, x - 3:x + 4].astype(int)
        px = window[np.argmax(window.sum(axis=1))]
        others = [lane_bgr(1 - lane), NO_LANE_BGR]  # the other colours in the picture
        assert all(np.linalg.norm(px - lane_bgr(lane)) < np.linalg.norm(px - c) for c in others), (lane, px)
    text = "".join(page.text)
    assert "Where the lanes are: each measured vehicle's reference points" in text
    assert text.index("Per lane") < text.index("Where the lanes are")
    bare = _parse(render_report(ReportInputs(events, _calibration(), frame)))
    assert "where the lanes are" not in [a.get("alt") for tag, a in bare.attrs if tag == "img"]


def test_report_warns_about_a_view_along_the_road() -> None:
    """A camera looking along the road (pan 4°): VP2 far away, the speeds poorly pinned down — said in the table
    and in a paragraph that says what to do."""
    K = np.array([[900.0, 0, W / 2], [0, 900.0, H / 2], [0, 0, 1]])
    R = rotation_matrix(4.0, 8.0, 0.0)
    cal = Calibration(Camera.from_KRt(K, R, -R @ np.array([0.0, 0.0, 7.0])), (W, H), source="vpdetect")
    cond = cal.conditioning()
    assert cond.poor
    page = _parse(render_report(ReportInputs(_events(), cal)))
    calib = {r[0]: r[1] for r in _table_after(page, "")[1:]}
    assert calib["speeds change under a 0.1° error of VP2 [%]"] == f"{cond.speed_pct:.2f} (poorly conditioned view)"
    assert [a for tag, a in page.attrs if tag == "p" and a.get("class") == "warn"]
    assert "calibrate-manual" in "".join(page.text) and "looks along the road" in "".join(page.text)


def test_report_with_a_speed_limit() -> None:
    events = _events()
    speeds = np.array([e.speed_kmh for e in events if e.measured])
    page = _parse(render_report(ReportInputs(events, _calibration(), speed_limit_kmh=85)))
    stats = _table_after(page, "speed [km/h]")
    assert stats[0][-1] == "over 85 km/h"
    n = int(np.sum(speeds > 85))
    assert 0 < n < len(speeds) and stats[1][-1] == f"{n} ({100 * n / len(speeds):.0f} %)"
    lanes = _table_after(page, "lane")
    assert lanes[0][-1] == "over 85 km/h" and sum(int(r[-1]) for r in lanes[1:]) == n
    towards = [e.speed_kmh for e in events if e.measured and e.direction == "towards_vp1"]
    assert stats[2][0] == "towards VP1" and stats[2][-1].startswith(f"{sum(v > 85 for v in towards)} (")
    # the histogram and the speeds over time mark the limit: a red line (matplotlib's C3 red) the plain ones lack
    plain = _parse(render_report(ReportInputs(events, _calibration())))
    red = lambda img: int(np.sum((img[:, :, 2] > 180) & (img[:, :, 1] < 80) & (img[:, :, 0] < 80)))  # noqa: E731
    for k in (1, 2):  # (after the calibration picture)
        assert red(_decode(page.images[k])) > 100 and red(_decode(plain.images[k])) == 0
    with pytest.raises(InputError, match="speed limit"):
        render_report(ReportInputs(events, speed_limit_kmh=-1))


def test_report_per_interval_with_dates() -> None:
    from gst_trafficcal.clock import parse_start_time
    from gst_trafficcal.outputs import stream_start

    start = parse_start_time("2026-12-05T07:59:50+01:00")
    events = [e.with_clock(start) for e in _events()]  # vehicles every second from 07:59:50
    assert stream_start(events) == start and stream_start(_events()) is None
    page = _parse(render_report(ReportInputs(events, interval_s=60, start_time=start, speed_limit_kmh=80)))
    assert "Per interval (1 min)" in page.headings
    table = _table_after(page, "interval")
    assert table[0][-1] == "over 80 km/h"
    mids = [0.5 * (e.first_timestamp_s + e.last_timestamp_s) for e in events]
    want = [sum(m < 10 for m in mids), sum(10 <= m < 70 for m in mids)]  # 07:59 and 08:00
    assert [r[0] for r in table[1:]] == ["2026-12-05T07:59:00+01:00 – 2026-12-05T08:00:00+01:00",
                                         "2026-12-05T08:00:00+01:00 – 2026-12-05T08:01:00+01:00"]
    assert [int(r[1]) for r in table[1:]] == want
    # two intervals: a plot of vehicles (blue bars) and V85 per interval, the limit as a red dashed line
    alts = [a.get("alt") for tag, a in page.attrs if tag == "img"]
    plot = _decode(page.images[alts.index("traffic per interval")])
    red = int(np.sum((plot[:, :, 2] > 180) & (plot[:, :, 1] < 80) & (plot[:, :, 0] < 80)))
    bars = int(np.sum((np.abs(plot.astype(int) - (232, 197, 159)).max(axis=2) < 8)))  # #9fc5e8 in BGR
    assert red > 50 and bars > 500
    listing = _table_after(page, "id")
    assert listing[0][2] == "first seen" and listing[1][2] == events[0].first_time
    # without dates: intervals from the start of the video, no date column
    page = _parse(render_report(ReportInputs(_events(), interval_s=60)))
    assert "Per interval (1 min, from the start of the video)" in page.headings
    assert _table_after(page, "interval")[1][0] == "0:00:00 – 0:01:00"
    assert "traffic per interval" not in [a.get("alt") for tag, a in page.attrs if tag == "img"]  # one interval
    assert "first seen" not in _table_after(page, "id")[0]


def test_report_is_self_contained_and_escaped() -> None:
    events = [VehicleEvent(1, "<script>alert(1)</script>", 0.0, 1.0, 50.0)]
    text = render_report(ReportInputs(events, _calibration(), None, title="a & b"))
    page = _parse(text)
    assert page.tags["script"] == 0 and page.tags["link"] == 0 and page.tags["iframe"] == 0
    for tag, attrs in page.attrs:
        for key in ("src", "href"):
            if attrs.get(key) is not None:
                assert attrs[key].startswith("data:image/png;base64,"), (tag, key)
    assert "<script>alert" not in text and "&lt;script&gt;" in text
    assert page.headings[0] == "a & b"
    assert _decode(page.images[0]).shape == (H, W, 3)  # no frame: the grid on a plain canvas


def test_report_lists_the_runs_warnings_once_each_before_the_figures() -> None:
    """trafficcal run's warnings (as on its terminal): a section of their own, before the calibration and the
    vehicles they qualify, each once, escaped; none, no section."""
    jitter = "speedometer0: speedometer: the frame times jitter: intervals of 40 ms vary by 12 ms <...>"
    short = "clip.mp4: the video ended after 12.0 s"
    text = render_report(ReportInputs([], _calibration(), warnings=[jitter, short, jitter]))
    page = _parse(text)
    assert page.headings[1] == "Warnings" and page.headings[2] == "Calibration"
    shown = [t.strip() for t in page.text if "frame times jitter" in t or "ended after" in t]
    assert shown == [jitter, short]
    assert "&lt;...&gt;" in text
    assert "Warnings" not in _parse(render_report(ReportInputs([], _calibration()))).headings


def test_report_with_nothing_measured() -> None:
    page = _parse(render_report(ReportInputs([], None)))
    assert page.images == []
    text = "".join(page.text)
    assert "No calibration was obtained." in text and "0 vehicles, 0 with a measured speed." in text
    events = [VehicleEvent(1, "car", 0.0, 1.0, None, "stream ended before the calibration converged")]
    page = _parse(render_report(ReportInputs(events, Calibration(None, (W, H), state="learning"))))
    assert {r[0]: r[1] for r in _table_after(page, "reason")[1:]} == {
        "stream ended before the calibration converged": "1"}
    assert len(page.images) == 1  # a plain canvas of the image size, no histogram without speeds


def test_report_of_events_without_times() -> None:
    """An events file of another tool may leave the times out (they are optional): the speeds over time are drawn
    for the vehicles that have them, left out with fewer than two, and nothing else breaks."""
    timed = [VehicleEvent(i, "car", float(i), i + 2.0, 80.0 + i, "") for i in range(1, 4)]
    untimed = [VehicleEvent(i, "car", None, None, 60.0 + i, "") for i in range(4, 9)]
    for events, pictures in ((untimed, 1), (untimed + timed[:1], 1), (untimed + timed, 2)):
        page = _parse(render_report(ReportInputs(events, None)))
        text = "".join(page.text)
        assert f"{len(events)} vehicles, {len(events)} with a measured speed." in text
        assert len(page.images) == pictures, (len(events), len(page.images))  # histogram (+ speeds over time)


def test_calibration_picture_shrinks_large_frames_and_keeps_geometry() -> None:
    cal = _calibration()
    big = np.full((2 * H, 2 * W, 3), 60, np.uint8)  # a frame at twice the calibrated size
    pic = calibration_picture(cal, big, max_width=W)
    assert pic.shape == (H, W, 3)
    same = calibration_picture(cal, np.full((H, W, 3), 60, np.uint8))
    overlap = (np.any(pic != 60, axis=2) & np.any(same != 60, axis=2)).sum() / np.any(same != 60, axis=2).sum()
    assert overlap > 0.8


def test_report_outlines_the_detection_zone() -> None:
    """A run's zone: a row in the calibration table and a violet outline in its picture, at the picture's scale
    (a frame twice the calibrated size shrunk to it); a zone in fractions fits any frame."""
    from gst_trafficcal.drawing import ZONE_BGR
    from gst_trafficcal.zone import parse_zone

    zone = parse_zone("40,60 200,60 200,200 40,200")
    page = _parse(render_report(ReportInputs(_events(), _calibration(), np.full((H, W, 3), 60, np.uint8),
                                             zone=zone)))
    text = " ".join("".join(page.text).split())
    assert "detection zone [px]40,60 200,60 200,200 40,200" in text and "Violet: the detection zone" in text
    for pic in (calibration_picture(_calibration(), np.full((2 * H, 2 * W, 3), 60, np.uint8), max_width=W, zone=zone),
                calibration_picture(_calibration(), np.full((H, W, 3), 60, np.uint8),
                                    zone=parse_zone(f"{40 / W},{60 / H} {200 / W},{60 / H} {200 / W},{200 / H} "
                                                    f"{40 / W},{200 / H}"))):
        violet = np.abs(pic.astype(int) - ZONE_BGR).max(axis=2) < 40
        assert violet[100:160, 38:43].any(axis=1).all() and violet[100:160, 198:203].any(axis=1).all()  # its sides
        assert not violet[100:160, 60:180].any()  # inside it, nothing
    bare = _parse(render_report(ReportInputs(_events(), _calibration(), np.full((H, W, 3), 60, np.uint8))))
    assert "detection zone" not in "".join(bare.text)


def test_report_with_brnocompspeed_ground_truth(tmp_path: Path) -> None:
    rec = require_shared(BRNO / "session0_left")
    gt = load_gt_data(rec / "gt_data.pkl")
    res = load_results(rec / "system_dubska_bmvc14.json")
    cal = Calibration.from_brno_block(res.calibration.to_dict())
    speeds = median_speeds(res.cars, cal.camera, gt.fps)
    events = [VehicleEvent(t.id, "car", t.frames[0] / gt.fps, t.frames[-1] / gt.fps,
                           s if np.isfinite(s) else None, "track too short", calibration_id=cal.id)
              for t, s in zip(res.cars, speeds)]
    ev = evaluate(gt, cal.camera, res)
    frame = cv2.imread(str(rec / "screen.png"))
    path = write_report(tmp_path / "out" / "report.html",
                        ReportInputs(events, cal, frame, ev, ground_truth_name="session0_left/gt_data.pkl"))
    page = _parse(path.read_text(encoding="utf-8"))
    assert "Evaluation against the ground truth" in page.headings
    pics = [_decode(u) for u in page.images]
    # calibration picture, speed histogram, speeds over time, traffic per 15 min (the recording's hour), cumulative
    # error plot
    assert len(pics) == 5
    assert pics[0].shape[1] == 1100  # 1920 frames are shrunk
    assert pics[4].shape == (500, 800, 3)  # the evaluator's plot (8x5 in at 100 dpi)
    errors = _table_after(page, "metric")
    assert errors[1][0] == "speed [km/h]" and errors[1][1] == str(ev.speed.abs_kmh.n)
    assert errors[1][2] == f"{ev.speed.abs_kmh.mean:.3g}" and errors[1][4] == f"{ev.speed.abs_kmh.p95:.3g}"
    summary = {r[0]: r[1] for r in page.tables[[t[1][0] if len(t) > 1 else "" for t in page.tables].index("recall")][1:]}
    assert summary["recall"] == f"{ev.speed.recall:.4f}"
    assert summary["false positives"] == str(ev.speed.false_positives)
    calib_errors = [t for t in page.tables if len(t) > 1 and t[1][0] == "distance ratio"][0]
    assert calib_errors[1][2] == f"{ev.calibration.ratio_abs.mean:.3g}"


def test_write_report_errors_name_the_file(tmp_path: Path) -> None:
    (tmp_path / "f").write_text("x")
    with pytest.raises(InputError, match=r"f/report\.html: cannot write report"):
        write_report(tmp_path / "f" / "report.html", ReportInputs([]))
    (tmp_path / "d.html").mkdir()
    with pytest.raises(InputError, match=r"d\.html: a folder, not a regular file: cannot write report"):
        write_report(tmp_path / "d.html", ReportInputs([]))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.html", "f"]  # no temporary file left


# --------------------------------------------------------------------------- trafficcal report


def _cli(*args: str) -> "subprocess.CompletedProcess":
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "gst_trafficcal", "report", *args], capture_output=True, text=True,
                          timeout=300, cwd=Path(__file__).resolve().parents[1])


def test_cli_report_from_run_files(tmp_path: Path) -> None:
    from gst_trafficcal.calibration import save_calibration
    from gst_trafficcal.outputs import EventWriters

    events = _events()
    with EventWriters.open(tmp_path / "vehicles.jsonl") as w:
        for e in events:
            w.write(e)
    with open(tmp_path / "vehicles.jsonl", "a") as f:
        f.write('{"id": 99, "lab')  # a line cut short by a crash
    save_calibration(_calibration(), tmp_path / "calibration.json")
    cv2.imwrite(str(tmp_path / "frame.png"), np.full((H, W, 3), 100, np.uint8))
    out = _cli("--events", str(tmp_path / "vehicles.jsonl"), "--calibration", str(tmp_path / "calibration.json"),
               "--frame", str(tmp_path / "frame.png"), "--speed-limit", "85,truck=75", "--interval", "0.5",
               "--intervals-csv", str(tmp_path / "intervals.csv"), "--out", str(tmp_path / "report.html"))
    assert out.returncode == 0 and "warning" not in out.stderr, out.stderr
    n_intervals = len({int(0.5 * (e.first_timestamp_s + e.last_timestamp_s) // 30) for e in events})
    assert out.stdout.strip().splitlines() == [
        f"{tmp_path / 'report.html'}: {len(events)} vehicles (1 broken line(s) skipped)",
        f"{tmp_path / 'intervals.csv'}: {n_intervals} intervals"]
    with open(tmp_path / "intervals.csv", newline="") as f:
        counts = list(csv.DictReader(f))
    assert sum(int(r["vehicles"]) for r in counts if r["lane"] == "all") == len(events)
    assert {r["observed_s"] for r in counts} == {""}  # the events alone do not say what the video covered
    page = _parse((tmp_path / "report.html").read_text(encoding="utf-8"))
    # calibration picture, histogram, speeds over time, traffic per half minute
    assert len(page.images) == 4 and _decode(page.images[0]).shape == (H, W, 3)
    over = sum(e.speed_kmh > (75 if e.label == "truck" else 85) for e in events if e.measured)
    stats = _table_after(page, "speed [km/h]")
    assert stats[0][-1] == "over 85 km/h (truck 75)" and stats[1][-1].startswith(f"{over} (")
    assert over != sum(e.speed_kmh > 85 for e in events if e.measured)  # the trucks' own limit counted
    bad = _cli("--events", str(tmp_path / "vehicles.jsonl"), "--speed-limit", "85,lorry", "--out",
               str(tmp_path / "r2.html"))
    assert bad.returncode == 2 and "--speed-limit: '85,lorry' is not KMH or KMH,CLASS=KMH" in bad.stderr
    zoned = _cli("--events", str(tmp_path / "vehicles.jsonl"), "--calibration", str(tmp_path / "calibration.json"),
                 "--frame", str(tmp_path / "frame.png"), "--zone", "0,0 0.5,0 0.5,1", "--out", str(tmp_path / "z.html"))
    assert zoned.returncode == 0, zoned.stderr
    text = " ".join("".join(_parse((tmp_path / "z.html").read_text(encoding="utf-8")).text).split())
    assert "detection zone [fractions of the frame]0,0 0.5,0 0.5,1" in text
    bad = _cli("--events", str(tmp_path / "vehicles.jsonl"), "--zone", "0,0 1,1", "--out", str(tmp_path / "r3.html"))
    assert bad.returncode == 2 and "--zone: zone '0,0 1,1': polygon 1 has 2 points" in bad.stderr
    # the calibration from a run's system.json, in pixels of its image_size: no size warning, the same grid
    import json

    from gst_trafficcal.outputs import brno_calibration

    (tmp_path / "system.json").write_text(json.dumps({"camera_calibration": brno_calibration(_calibration()).to_dict(),
                                                      "image_size": [W, H], "cars": []}))
    sysrep = _cli("--events", str(tmp_path / "vehicles.jsonl"), "--results", str(tmp_path / "system.json"),
                  "--frame", str(tmp_path / "frame.png"), "--out", str(tmp_path / "sys.html"))
    assert sysrep.returncode == 0 and "warning" not in sysrep.stderr, sysrep.stderr
    a = _decode(_parse((tmp_path / "sys.html").read_text(encoding="utf-8")).images[0])
    b = _decode(_parse((tmp_path / "report.html").read_text(encoding="utf-8")).images[0])
    assert np.abs(a.astype(int) - b).max() <= 2  # the same grid on the same picture
    # a picture of another size: drawn scaled, with a warning (and another shape: perhaps another camera's)
    for size, shape in (((W // 2, H // 2), False), ((H, H), True)):
        cv2.imwrite(str(tmp_path / "other.png"), np.full((size[1], size[0], 3), 100, np.uint8))
        other = _cli("--events", str(tmp_path / "vehicles.jsonl"), "--calibration", str(tmp_path / "calibration.json"),
                     "--frame", str(tmp_path / "other.png"), "--out", str(tmp_path / "other.html"))
        assert other.returncode == 0 and f"a calibration of {W}x{H} frames, the picture is {size[0]}x{size[1]}: the " \
            "grid is drawn scaled to it" in other.stderr and ("another camera's?" in other.stderr) is shape


def test_cli_report_with_ground_truth(tmp_path: Path) -> None:
    rec = require_shared(BRNO / "session0_center")
    res = load_results(rec / "system_dubska_bmvc14.json")
    (tmp_path / "vehicles.jsonl").write_text(
        "".join(json.dumps(VehicleEvent(t.id, "car", t.frames[0] / 50, t.frames[-1] / 50, 90.0).to_dict()) + "\n"
                for t in res.cars[:50]))
    out = _cli("--events", str(tmp_path / "vehicles.jsonl"), "--results", str(rec / "system_dubska_bmvc14.json"),
               "--gt", str(rec / "gt_data.pkl"), "--frame", str(rec / "screen.png"), "--out",
               str(tmp_path / "r.html"))
    assert out.returncode == 0, out.stderr
    page = _parse((tmp_path / "r.html").read_text(encoding="utf-8"))
    assert "Evaluation against the ground truth" in page.headings and len(page.images) == 5
    alts = [a.get("alt") for tag, a in page.attrs if tag == "img"]
    assert "where the lanes are" in alts  # the results' reference points (these events name no lanes: grey)
    gt = load_gt_data(rec / "gt_data.pkl")
    cal = Calibration.from_brno_block(res.calibration.to_dict())
    ev = evaluate(gt, cal.camera, res)
    assert _table_after(page, "metric")[1][2] == f"{ev.speed.abs_kmh.mean:.3g}"


def test_cli_report_errors_are_one_line(tmp_path: Path) -> None:
    out = _cli("--events", str(tmp_path / "none.jsonl"), "--out", str(tmp_path / "r.html"))
    assert out.returncode == 2 and out.stderr.strip() == f"trafficcal: error: {tmp_path / 'none.jsonl'}: no such event file"
    (tmp_path / "v.jsonl").write_text(json.dumps(VehicleEvent(1, "car", 0, 1, 50.0).to_dict()) + "\n")
    (tmp_path / "fake.mp4").write_text("not a video")
    out = _cli("--events", str(tmp_path / "v.jsonl"), "--video", str(tmp_path / "fake.mp4"), "--out",
               str(tmp_path / "r.html"))
    assert out.returncode == 2 and "fake.mp4: cannot open video" in out.stderr and "Traceback" not in out.stderr
    out = _cli("--events", str(tmp_path / "v.jsonl"), "--gt", str(tmp_path / "gt.pkl"), "--out",
               str(tmp_path / "r.html"))
    assert out.returncode == 2 and "gt.pkl: no such file" in out.stderr
    from .conftest import closed_port

    (tmp_path / "results.json").write_text(json.dumps({"camera_calibration": None, "cars": []}))
    for args, said in [(["--frame", str(tmp_path)], f"{tmp_path}: a folder, not an image"),
                       (["--video", f"rtsp://127.0.0.1:{closed_port()}/cam"], "/cam: no frame could be read from"),
                       (["--video", "rtsp://127.0.0.1/cam", "--frame-time", "3"], "--frame-time is for a video file"),
                       (["--video", str(tmp_path / "fake.mp4"), "--frame-time", "-1"], "--frame-time"),
                       (["--interval", "0.0001"], "--interval"),
                       (["--calibration", str(tmp_path / "results.json")],
                        "results.json: a BrnoCompSpeed results file without a calibration")]:
        out = _cli("--events", str(tmp_path / "v.jsonl"), *args, "--out", str(tmp_path / "r.html"))
        assert out.returncode == 2 and said in out.stderr and "Traceback" not in out.stderr, (args, out.stderr)
    assert not (tmp_path / "r.html").exists()


def test_report_of_appended_runs_counts_each_run() -> None:
    """Events of two runs in one file (speedometer append; each run's track ids from 1): a per-run table with
    each run's vehicles and measured ones, and the run beside each id in the list; one run: neither."""
    from dataclasses import replace

    events = _events()
    second = [replace(e, run="20261206T070000Z-beef") for e in events[:3]]
    both = [replace(e, run="20261206T063000Z-0a1b") for e in events] + second
    page = _parse(render_report(ReportInputs(both, _calibration())))
    runs = _table_after(page, "run")
    assert runs[0] == ["run", "vehicles", "measured", "first seen", "mean speed [km/h]"]
    assert {r[0]: (int(r[1]), int(r[2])) for r in runs[1:]} == {
        "20261206T063000Z-0a1b": (len(events), sum(e.measured for e in events)),
        "20261206T070000Z-beef": (3, sum(e.measured for e in second))}
    (listing,) = [t for t in page.tables if t and t[0][:2] == ["run", "id"]]
    assert len(listing) == len(both) + 1 and [r[0] for r in listing[1:]][-3:] == ["20261206T070000Z-beef"] * 3
    single = _parse(render_report(ReportInputs(both[:len(events)], _calibration())))
    assert not any(t[0][0] == "run" for t in single.tables if t)


def test_report_says_what_it_covers_and_where_the_horizon_is() -> None:
    """The header line: the video time watched (with its clock times when dated), vehicles and flow per hour, the
    software; the caption names the red horizon only when the picture shows it."""
    from datetime import datetime, timezone

    from gst_trafficcal import __version__
    from gst_trafficcal.report import horizon_in_view

    events = _events()
    measured = sum(e.measured for e in events)
    start = datetime(2026, 12, 6, 8, 0, 0, tzinfo=timezone.utc)
    text = "".join(_parse(render_report(ReportInputs(events, _calibration(), covered=[(0.0, 120.0)],
                                                     start_time=start))).text)
    assert (f"2 min 00 s of video watched (2026-12-06 08:00:00 – 08:02:00) · {len(events)} vehicles ({measured} "
            f"with a speed), {30 * len(events)} vehicles/h · gst-trafficcal {__version__}, report written ") in text
    assert "were measured again" not in text
    assert "not counted" not in text
    short = "".join(_parse(render_report(ReportInputs(events, covered=[(0.0, 42.0)], remeasured=(9, 7),
                                                      not_counted=(5, 2)))).text)
    assert (f"{len(events)} vehicles, {measured} with a measured speed. 9 of them passed before the calibration "
            "settled and were measured again with the final one at the end (7 with a speed).") in short
    assert ("Tracks not counted as vehicles: 5 seen for under 0.5 s (pieces of vehicles counted once, or a "
            "detector's flicker) and 2 that did not move 3 m along the road (parked vehicles, or fixed objects "
            "taken for one).") in short
    assert "42.0 s of video watched · 40 vehicles" in short and "vehicles/h" not in short  # no rate from 42 s
    cal = _calibration()
    assert horizon_in_view(cal.camera, cal.image_size)
    assert "and the horizon (red)." in text
    R = rotation_matrix(20.0, 70.0, 0.0)
    level = Calibration(Camera.from_KRt(np.array([[600.0, 0, W / 2], [0, 600.0, H / 2], [0, 0, 1]]), R,
                                        -R @ np.array([0.0, 0.0, 7.0])), (W, H), source="test")
    assert not horizon_in_view(level.camera, level.image_size)  # looking down steeply: the horizon above the frame
    steep = "".join(_parse(render_report(ReportInputs(events, level))).text)
    assert "the horizon, through both vanishing points, lies outside the picture" in steep
    assert "horizon (red)" not in steep
