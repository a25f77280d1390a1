"""fileio: free names beside what is already there, and earlier files kept instead of replaced."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from gst_trafficcal.errors import InputError
from gst_trafficcal.fileio import free_path, keep_aside, open_video, writable_dir


def test_free_path_numbers_files_and_folders(tmp_path: Path) -> None:
    assert free_path(tmp_path / "a.csv") == tmp_path / "a.csv"
    (tmp_path / "a.csv").write_text("x")
    (tmp_path / "a-2.csv").write_text("x")
    assert free_path(tmp_path / "a.csv") == tmp_path / "a-3.csv"
    (tmp_path / "20261205-080000").mkdir()
    assert free_path(tmp_path / "20261205-080000") == tmp_path / "20261205-080000-2"


def test_keep_aside_moves_an_earlier_file_under_its_time(tmp_path: Path) -> None:
    table = tmp_path / "intervals.csv"
    assert keep_aside(table) is None  # nothing there
    table.write_text("")
    assert keep_aside(table) is None and table.exists()  # nothing to keep
    for text in ("first\n", "second\n"):
        table.write_text(text)
        os.utime(table, (1764921600, 1764921600))  # 2025-12-05T08:00:00 UTC
    kept = keep_aside(table)
    assert kept is not None and not table.exists() and kept.read_text() == "second\n"
    assert kept.parent == tmp_path and kept.name.startswith("intervals.earlier-20251205-") and kept.suffix == ".csv"
    table.write_text("third\n")
    os.utime(table, (1764921600, 1764921600))
    again = keep_aside(table)
    assert again == kept.with_name(kept.name.replace(".csv", "-2.csv")) and again.read_text() == "third\n"
    assert kept.read_text() == "second\n"
    results = tmp_path / "system.json"
    results.write_text("{}")
    assert keep_aside(results).name.endswith(".json")


def test_keep_aside_that_cannot_rename_is_a_clear_error(tmp_path: Path) -> None:
    """A name with no room for ".earlier-<time>" (the file system's 255 bytes): an error naming the file."""
    long = tmp_path / ("r" * 240 + ".json")
    long.write_text("{}")
    with pytest.raises(InputError, match=r"r\.json: cannot keep the earlier file as .*File name too long"):
        keep_aside(long)
    assert long.read_text() == "{}"


def test_writable_dir_creates_the_folder_or_says_why_it_cannot(tmp_path: Path) -> None:
    """An output folder is checked before any work: created when missing, refused with the reason otherwise."""
    assert writable_dir(tmp_path / "a" / "b", "output folder").is_dir()
    assert not [p for p in (tmp_path / "a" / "b").iterdir()]  # the write check leaves nothing behind
    (tmp_path / "f").write_text("x")
    with pytest.raises(InputError, match=r"/f: not a folder, so it cannot be the output folder"):
        writable_dir(tmp_path / "f", "output folder")
    with pytest.raises(InputError, match=r"/f/x: cannot create the output folder \(Not a directory\)"):
        writable_dir(tmp_path / "f" / "x", "output folder")
    with pytest.raises(InputError, match=r"^/proc: cannot write in the output folder"):  # exists, not writable
        writable_dir("/proc", "output folder")


def test_open_video_names_what_is_wrong(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r": a folder, not a video file$"):
        open_video(tmp_path)
    with pytest.raises(InputError, match=r"none.mp4: no such file$"):
        open_video(tmp_path / "none.mp4")
    (tmp_path / "text.mp4").write_text("not a video")
    with pytest.raises(InputError, match=r"text.mp4: cannot open video"):
        open_video(tmp_path / "text.mp4")
