"""benchmarks/view_monitor.py on a real clip: no false event on the clip as it is, each camera move (shift, zoom,
roll from the middle of the watched part) noticed, dated early rather than late, within two seconds."""

import subprocess
import sys

import numpy as np
import pytest

from .conftest import ROOT, VIDEOS, require_shared


@pytest.mark.shared
def test_moves_are_noticed_and_the_clip_as_it_is_gives_no_event(load_benchmark):
    clip = require_shared(VIDEOS / "kraten_cars.mp4")
    row = load_benchmark("view_monitor").measure(clip, learn_s=5.0)
    assert row["false_events"] == [] and row["watched_s"] > 40 and row["min_sim"] > 0.6
    for change in ("shift 2 %", "zoom 2 %", "roll 1°"):
        dated, noticed = row[change]
        assert -0.5 <= dated <= 0.0 and 0.0 < noticed <= 2.0, (change, row[change])


@pytest.mark.shared
def test_a_library_of_views_finds_a_view_as_itself_and_never_as_another(load_benchmark):
    """kraten's view and the same camera 5 % to the right (another preset) in a library: each stream's window
    medians are found as their own view, never as the other's; shifted by 2 % (a view the library lacks) as none."""
    bench = load_benchmark("view_monitor")
    s = bench.read(require_shared(VIDEOS / "kraten_cars.mp4"), 5.0, 640)
    preset2 = lambda img: np.roll(img, 32, axis=1)  # noqa: E731
    unknown = lambda img: np.roll(img, -26, axis=1)  # noqa: E731  (4 % the other way: neither view)
    views = {"home": (s.view, s.width), "preset2": (bench.window_views(s, preset2)[0], s.width)}
    streams = {"home": bench.window_views(s), "preset2": bench.window_views(s, preset2)}
    seen = bench.recognition(views, streams)
    assert seen["home"]["other"] == seen["preset2"]["other"] == 0
    assert seen["home"]["itself"] >= 0.95 * len(streams["home"]) and len(streams["home"]) >= 30
    assert seen["preset2"]["itself"] >= 0.95 * len(streams["preset2"])
    shifted = bench.recognition(views, {"home": bench.window_views(s, unknown)})
    assert shifted["home"]["none"] == len(streams["home"]), shifted


def test_a_file_that_is_not_a_video_is_said(tmp_path):
    bad = tmp_path / "notes.mp4"
    bad.write_text("not a video")
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "view_monitor.py"), str(bad)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0 and f"{bad}: cannot be read as a video" in proc.stderr
