"""Speed statistics for traffic engineers: V85 and the vehicles over a speed limit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gst_trafficcal.errors import InputError
from gst_trafficcal.traffic_stats import check_limit, is_over_limit, speed_stats


def test_v85_and_the_other_figures_of_known_speeds() -> None:
    speeds = np.arange(1.0, 101.0)  # 1 .. 100 km/h
    s = speed_stats(speeds)
    assert s.n == 100 and s.mean == pytest.approx(50.5) and s.median == pytest.approx(50.5)
    assert s.v85 == pytest.approx(85.15) and s.p95 == pytest.approx(95.05) and s.max == 100.0
    assert s.limit_kmh is None and s.over_limit is None and s.share_over is None


def test_over_the_limit_is_strictly_faster() -> None:
    s = speed_stats([49.9, 50.0, 50.1, 80.0, None, float("nan")], limit_kmh=50)
    assert s.n == 4  # None and NaN are not measured speeds
    assert s.over_limit == 2 and s.share_over == pytest.approx(0.5) and s.limit_kmh == 50.0
    assert s.v85 == pytest.approx(np.percentile([49.9, 50.0, 50.1, 80.0], 85))


def test_no_speeds() -> None:
    s = speed_stats([], limit_kmh=80)
    assert s.n == 0 and s.mean is None and s.v85 is None and s.over_limit == 0 and s.share_over is None


def test_limits() -> None:
    assert check_limit(None) is None and check_limit(0) is None and check_limit(80) == 80.0
    for bad in (-5, math.inf, math.nan):
        with pytest.raises(InputError, match="speed limit"):
            check_limit(bad)
    assert is_over_limit(81.0, 80.0) and not is_over_limit(80.0, 80.0)
    assert not is_over_limit(None, 80.0) and not is_over_limit(float("nan"), 80.0)
    assert not is_over_limit(200.0, 0.0) and not is_over_limit(200.0, None)


def test_a_limit_with_classes_of_their_own() -> None:
    from gst_trafficcal.traffic_stats import VEHICLE_CLASSES, SpeedLimit, parse_speed_limit

    lim = parse_speed_limit("80, Truck=60,bus=70")
    assert lim == SpeedLimit(80.0, (("truck", 60.0), ("bus", 70.0))) and lim.describe() == "80 km/h (truck 60, bus 70)"
    assert lim.properties() == "speed-limit=80 class-limits=truck=60,bus=70"
    assert (lim.for_label("truck"), lim.for_label("car"), lim.for_label(None)) == (60.0, 80.0, 80.0)
    assert parse_speed_limit("truck=60").describe() == "truck 60 km/h" and parse_speed_limit("truck=60").kmh is None
    assert not parse_speed_limit("") and not parse_speed_limit("0") and not parse_speed_limit(None)
    assert parse_speed_limit(90) == SpeedLimit(90.0)
    for bad in ("fast", "80,truck", "80,truck=-5", "=60", "80,truck=x", "80,lorry=60"):
        with pytest.raises(InputError, match="--speed-limit"):
            parse_speed_limit(bad, "--speed-limit")
    # a class name that is no class (a typo would leave the trucks unchecked): said, with the classes
    with pytest.raises(InputError, match=r"--speed-limit: 'lorry' is no vehicle class \(classes: car, van, bus, "
                                         r"truck, motorcycle\)"):
        parse_speed_limit("80,lorry=60", "--speed-limit")
    with pytest.raises(InputError, match=r"--speed-limit: '-50': a limit is a positive number of km/h \(0: none\)"):
        parse_speed_limit("-50", "--speed-limit")
    # a limit given twice was taken silently: 80,90 held everyone to 90; truck=60,truck=50 said both, applied 50
    with pytest.raises(InputError, match="--speed-limit: '80,90' gives the limit for every vehicle twice"):
        parse_speed_limit("80,90", "--speed-limit")
    with pytest.raises(InputError, match="class-limits: 'truck=60,Truck=50' gives the limit for truck twice"):
        parse_speed_limit("truck=60,Truck=50", "class-limits", classes_only=True)
    from gst_trafficcal.vehicles.classify import LABEL_OF_STYLE

    assert set(VEHICLE_CLASSES) == set(LABEL_OF_STYLE.values())  # every class the vehicles are reported as
    # each vehicle held to its class's limit: the truck at 65 is over, the car at 75 is not
    speeds, labels = [75.0, 65.0, 85.0, 55.0, None], ["car", "truck", "car", "truck", "bus"]
    assert speed_stats(speeds, lim, labels).over_limit == 2 and speed_stats(speeds, 80).over_limit == 1
    assert speed_stats(speeds, parse_speed_limit("truck=60"), labels).over_limit == 1  # cars: no limit
    assert is_over_limit(65.0, lim, "truck") and not is_over_limit(65.0, lim, "car")
    with pytest.raises(ValueError, match="2 labels for 3 speeds"):
        speed_stats([1.0, 2.0, 3.0], lim, ["car", "car"])
    # the elements' speed-limit and class-limits properties
    from gst_trafficcal.traffic_stats import element_limit

    assert element_limit(80.0, "truck=60,bus=70") == parse_speed_limit("80,truck=60,bus=70")
    assert not element_limit(0.0, "")
    with pytest.raises(InputError, match="class-limits '80': CLASS=KMH pairs only"):
        element_limit(0.0, "80")


def _event(i: int, t: float, speed: float | None, lane: int | None = 0, direction: str | None = "towards_vp1",
           label: str = "car"):
    from gst_trafficcal.outputs import VehicleEvent

    return VehicleEvent(i, label, t - 1.0, t + 1.0, speed, "" if speed is not None else "track too short",
                        lane=lane, direction=direction)


def test_counts_per_interval_lane_and_direction() -> None:
    from gst_trafficcal.traffic_stats import interval_rows

    events = [_event(1, 10, 50.0), _event(2, 100, 70.0), _event(3, 200, 90.0, label="van"),
              _event(4, 890, None, lane=1),  # middle at 890 s: still the first 15 minutes
              _event(5, 950, 60.0, direction="away_from_vp1", label="bus"), _event(6, 1000, 80.0),
              _event(7, 3600 * 2 + 5, 55.0)]  # an empty hour in between: no rows for it
    rows = interval_rows(events, 900, limit_kmh=75)
    assert [(r.start, r.end, r.lane, r.direction, r.vehicles, r.total) for r in rows] == [
        ("0:00:00", "0:15:00", 0, "towards_vp1", 3, False), ("0:00:00", "0:15:00", 1, "towards_vp1", 1, False),
        ("0:00:00", "0:15:00", None, None, 4, True),
        ("0:15:00", "0:30:00", 0, "away_from_vp1", 1, False), ("0:15:00", "0:30:00", 0, "towards_vp1", 1, False),
        ("0:15:00", "0:30:00", None, None, 2, True),
        ("2:00:00", "2:15:00", 0, "towards_vp1", 1, False), ("2:00:00", "2:15:00", None, None, 1, True)]
    first = rows[0].to_dict()
    assert first["measured"] == 3 and first["mean_kmh"] == 70.0 and first["over_limit"] == 1
    assert first["v85_kmh"] == round(float(np.percentile([50, 70, 90], 85)), 2)
    assert (first["car"], first["van"], first["bus"], first["other"]) == (2, 1, 0, 0)
    total = rows[2].to_dict()
    assert total["lane"] == total["direction"] == "all" and total["vehicles"] == 4 and total["measured"] == 3
    assert rows[1].to_dict()["mean_kmh"] is None  # lane 1's only vehicle was not measured
    assert rows[3].to_dict()["bus"] == 1
    from gst_trafficcal.traffic_stats import parse_speed_limit

    by_class = interval_rows(events, 900, limit_kmh=parse_speed_limit("75,van=85"))  # the van at 90 still over
    assert by_class[0].to_dict()["over_limit"] == 1 and by_class[3].to_dict()["over_limit"] == 0
    assert interval_rows(events, 900, limit_kmh=parse_speed_limit("75,van=95"))[0].to_dict()["over_limit"] == 0


def test_an_interval_that_is_no_number_of_seconds_and_nan_times_are_clear() -> None:
    """An infinite or NaN interval is one clear InputError (an infinite one gave numpy's "cannot convert float NaN to
    integer", the interval's start being inf * 0); a vehicle whose timestamps are NaN or infinite is left out as one
    without timestamps (the same numpy error before), and a covered span that is not finite is refused by name."""
    from dataclasses import replace

    import pytest

    from gst_trafficcal.errors import InputError
    from gst_trafficcal.traffic_stats import IntervalTable, interval_rows, last_boundary

    events = [_event(1, 10, 50.0), replace(_event(2, 20, 60.0), first_timestamp_s=float("nan")),
              replace(_event(3, 30, 70.0), last_timestamp_s=float("inf"))]
    for bad in (float("inf"), float("nan"), 0.0, -5.0):
        for call in (lambda: interval_rows(events, bad), lambda: last_boundary(10.0, bad),
                     lambda: IntervalTable("unused.csv", bad)):
            with pytest.raises(InputError, match="interval must be a positive, finite number of seconds, got "):
                call()
    rows = interval_rows(events, 900)
    assert [(r.start, r.vehicles, r.total) for r in rows] == [("0:00:00", 1, False), ("0:00:00", 1, True)]
    with pytest.raises(InputError, match="a covered span of stream time must be two finite numbers of seconds"):
        interval_rows(events, 900, covered=[(0.0, float("nan"))])


def test_the_packed_vehicles_count_as_the_events_do() -> None:
    """CountedVehicles keeps what the table needs of each event, packed: the same rows; an event without
    timestamps is left out, as interval_rows leaves it out."""
    from dataclasses import replace

    from gst_trafficcal.traffic_stats import CountedVehicles, interval_rows, parse_speed_limit

    events = [_event(1, 10, 50.0), _event(2, 100, 70.25), _event(3, 200, 90.0, label="van"),
              _event(4, 890, None, lane=1), _event(5, 950, 60.0, direction="away_from_vp1", label="bus"),
              replace(_event(6, 1000, 80.0), lane=None, direction=None, label=""), _event(7, 3600 * 2 + 5, 55.0),
              replace(_event(8, 50, 99.0), first_timestamp_s=None)]
    packed = CountedVehicles()
    for e in events:
        packed.append(e)
    assert len(packed) == 7
    back = list(packed)
    assert [(v.first_timestamp_s, v.last_timestamp_s, v.lane, v.direction, v.speed_kmh, v.label) for v in back] == [
        (e.first_timestamp_s, e.last_timestamp_s, e.lane, e.direction, e.speed_kmh, e.label) for e in events[:7]]
    limit = parse_speed_limit("75,van=85")
    assert interval_rows(back, 900, limit_kmh=limit) == interval_rows(events, 900, limit_kmh=limit)


def test_a_revised_vehicle_replaces_the_last_one_with_its_id() -> None:
    """speedometer remeasure: the vehicle measured again replaces its counted fields — the last vehicle with that id
    (ids start again in a new run appended to the same table), nothing else."""
    from dataclasses import replace

    from gst_trafficcal.traffic_stats import CountedVehicles

    packed = CountedVehicles()
    for e in (_event(1, 10, 50.0), _event(2, 20, 60.0), _event(1, 30, 70.0), _event(3, 40, None)):
        packed.append(e)
    assert packed.revise(replace(_event(1, 30, 88.0), lane=2, label="van"))
    assert packed.revise(_event(3, 40, 66.0)) and not packed.revise(_event(9, 50, 1.0))
    assert [(v.speed_kmh, v.lane, v.label) for v in packed] == [(50.0, 0, "car"), (60.0, 0, "car"), (88.0, 2, "van"),
                                                                (66.0, 0, "car")]


def test_intervals_are_aligned_to_the_clock_when_the_start_time_is_known(tmp_path) -> None:
    import csv
    from datetime import datetime

    from gst_trafficcal.clock import parse_start_time
    from gst_trafficcal.traffic_stats import INTERVAL_FIELDS, interval_rows, write_intervals_csv

    start = parse_start_time("2026-12-05T07:58:30+01:00")
    assert start == datetime.fromisoformat("2026-12-05T07:58:30+01:00")
    # stream second 60 is 07:59:30, second 120 is 08:00:30: two intervals, named by the clock
    rows = interval_rows([_event(1, 60, 50.0), _event(2, 120, 60.0)], 900, start)
    assert [(r.start, r.end) for r in rows if r.total] == [
        ("2026-12-05T07:45:00+01:00", "2026-12-05T08:00:00+01:00"),
        ("2026-12-05T08:00:00+01:00", "2026-12-05T08:15:00+01:00")]
    path = write_intervals_csv(tmp_path / "intervals.csv", rows)
    with open(path, newline="") as f:
        back = list(csv.DictReader(f))
    assert tuple(back[0]) == INTERVAL_FIELDS and len(back) == 4
    assert back[1]["lane"] == "all" and back[1]["over_limit"] == "" and back[3]["mean_kmh"] == "60.0"
    with pytest.raises(InputError, match="interval"):
        interval_rows([], 0)



def test_every_watched_interval_has_a_row_and_says_how_much_of_it_was_watched() -> None:
    """A recording of 0–25 min and another of 50–61:40: the quarter hours they reach each have a row of all
    vehicles, zero when none passed; the 25–45 min nobody watched have none; observed_s says how much of each
    quarter was watched (the ends are partial)."""
    from datetime import datetime

    from gst_trafficcal.traffic_stats import interval_rows, last_boundary

    events = [_event(1, 10, 50.0), _event(2, 100, 70.0), _event(3, 3010, 60.0)]
    rows = [r for r in interval_rows(events, 900, covered=[(0, 1500), (3000, 3700)]) if r.total]
    assert [(r.start, r.vehicles, r.observed_s) for r in rows] == [
        ("0:00:00", 2, 900.0), ("0:15:00", 0, 600.0), ("0:45:00", 1, 600.0), ("1:00:00", 0, 100.0)]
    assert rows[1].to_dict()["mean_kmh"] is None and rows[1].to_dict()["observed_s"] == 600.0
    assert [r.observed_s for r in interval_rows(events, 900)] == [None] * 4  # not known: no empty rows either
    start = datetime.fromisoformat("2026-12-05T07:58:30+01:00")  # on the clock: 07:45, 08:00 and 08:15
    rows = [r for r in interval_rows([], 900, start, covered=[(0.0, 1200.0)]) if r.total]
    assert [(r.start[11:16], r.vehicles, r.observed_s) for r in rows] == [
        ("07:45", 0, 90.0), ("08:00", 0, 900.0), ("08:15", 0, 210.0)]
    assert last_boundary(1000.0, 900, start) == 990.0 and last_boundary(80.0, 900, start) == -810.0
    assert last_boundary(1000.0, 900) == 900.0


def test_the_interval_table_is_on_disk_as_the_intervals_close(tmp_path) -> None:
    """A stream of 2000 s at 1 frame/s, a vehicle every 100 s: the closed quarter hours are on disk once each has
    ended and 30 s more have passed (9 vehicles, 900 s watched); at the end all three, the last one 200 s watched."""
    import csv

    from gst_trafficcal.traffic_stats import IntervalTable

    path = tmp_path / "intervals.csv"
    table = IntervalTable(path, 900, grace_s=30)
    closed = []
    for t in range(2000):
        if t % 100 == 50:
            table.vehicle(_event(t, t - 5, 60.0))
        if table.frame(float(t)) and t in (930, 1830):
            with open(path, newline="") as f:
                rows = [r for r in csv.DictReader(f) if r["lane"] == "all"]
            closed.append([(r["interval_start"], r["vehicles"], r["observed_s"]) for r in rows][:-1])
    assert closed == [[("0:00:00", "9", "900.0")], [("0:00:00", "9", "900.0"), ("0:15:00", "9", "900.0")]]
    table.close()
    with open(path, newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["lane"] == "all"]
    assert [(r["interval_start"], r["vehicles"], r["observed_s"]) for r in rows] == [
        ("0:00:00", "9", "900.0"), ("0:15:00", "9", "900.0"), ("0:30:00", "2", "200.0")]
    empty = IntervalTable(tmp_path / "none.csv", 900)
    empty.close()
    assert (tmp_path / "none.csv").read_text().startswith("interval_start,interval_end,observed_s,")


def test_the_open_interval_is_on_disk_as_it_grows(tmp_path) -> None:
    """The interval still open had no row until it closed: a run killed outright (kill -9, a power cut) lost what
    was counted in it.  Now, whenever a vehicle was counted and a minute of stream has passed, the file holds what a
    clean stop at that moment would have written (the open interval with the seconds of it watched so far); between
    vehicles it is not rewritten; the table at the end is the same as before."""
    import csv

    from gst_trafficcal.traffic_stats import IntervalTable, interval_rows, intervals_csv_text

    path = tmp_path / "intervals.csv"
    table = IntervalTable(path, 900, grace_s=30)
    events, writes = [], []
    for t in range(2000):
        if t % 100 == 50:
            events.append(_event(t, t - 5, 60.0, lane=t % 200 // 100))
            table.vehicle(events[-1])
        if table.frame(float(t)):
            writes.append(t)
            # what the file holds now, if the process died here: the table of a stop at this frame
            assert path.read_text() == intervals_csv_text(interval_rows(events, 900, covered=[(0.0, t + 1.0)]))
    assert writes == [50, 150, 250, 350, 450, 550, 650, 750, 850, 930, 990, 1050, 1150, 1250, 1350, 1450, 1550,
                      1650, 1750, 1830, 1890, 1950]  # a vehicle each (at most one a minute), and each close
    with open(path, newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["lane"] == "all"]
    assert [(r["interval_start"], r["vehicles"], r["observed_s"]) for r in rows] == [
        ("0:00:00", "9", "900.0"), ("0:15:00", "9", "900.0"), ("0:30:00", "2", "151.0")]  # killed at 1999 s
    table.close()
    assert path.read_text() == intervals_csv_text(interval_rows(events, 900, covered=[(0.0, 2000.0)]))
