"""fileio: free names beside what is already there, earlier files kept instead of replaced, and files written whole
(through a symlink; never over a named pipe, device or socket)."""

from __future__ import annotations

import os
import re
import socket
import stat
from pathlib import Path

import pytest

from gst_trafficcal.errors import InputError
from gst_trafficcal.fileio import (
    atomic_write, atomic_write_text, free_path, keep_aside, open_video, remove_earlier, replace_target, writable_dir,
    writable_file,
)


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


def test_a_symlink_is_written_through_and_stays_a_link(tmp_path: Path) -> None:
    """The file is renamed over the link's target, in the target's folder: the link stays, the target gets the new
    text, and no temporary file is left in either folder."""
    (tmp_path / "real").mkdir()
    (tmp_path / "links").mkdir()
    target = tmp_path / "real" / "r.json"
    target.write_text("old")
    link = tmp_path / "links" / "r.json"
    link.symlink_to("../real/r.json")
    assert atomic_write_text(link, "new", "results") == link
    assert link.is_symlink() and os.readlink(link) == "../real/r.json" and target.read_text() == "new"
    assert sorted(p.name for p in (tmp_path / "real").iterdir()) == ["r.json"]
    assert sorted(p.name for p in (tmp_path / "links").iterdir()) == ["r.json"]
    dangling = tmp_path / "links" / "new.json"  # a link to a file not made yet: the file is made there
    dangling.symlink_to("../real/new.json")
    atomic_write_text(dangling, "first", "results")
    assert dangling.is_symlink() and (tmp_path / "real" / "new.json").read_text() == "first"
    assert writable_file(link, "results") == link and target.read_text() == "new"  # checked, not touched


def test_a_named_pipe_device_or_socket_is_refused_not_replaced(tmp_path: Path) -> None:
    """Renaming over them would put a regular file in their place: refused in one line naming the path and what
    is there, by the check at start (writable_file) and by the writer itself."""
    fifo = tmp_path / "fifo.csv"
    os.mkfifo(fifo)
    sock_path = tmp_path / "s.json"
    sock = socket.socket(socket.AF_UNIX)
    sock.bind(str(sock_path))
    device = tmp_path / "null.json"
    device.symlink_to("/dev/null")  # through a link only: nothing here may write at /dev itself
    try:
        for path, kind in ((fifo, "a named pipe"), (sock_path, "a socket"), (device, "a character device")):
            shown = re.escape(f"{path} (a link to /dev/null)" if path == device else str(path))
            with pytest.raises(InputError, match=rf"^{shown}: {kind}, not a regular file: cannot write interval table "
                                                 r"there \(it is written whole, then renamed into place\)$"):
                atomic_write_text(path, "x", "interval table")
            with pytest.raises(InputError, match=rf"^{shown}: {kind}, not a regular file: cannot write the interval "
                                                 r"table there"):
                writable_file(path, "interval table")
        assert stat.S_ISFIFO(fifo.lstat().st_mode) and stat.S_ISSOCK(sock_path.lstat().st_mode)
        assert device.is_symlink() and stat.S_ISCHR(device.stat().st_mode)
        assert sorted(p.name for p in tmp_path.iterdir()) == ["fifo.csv", "null.json", "s.json"]  # no temp file
    finally:
        sock.close()
    loop = tmp_path / "loop.json"
    loop.symlink_to("loop.json")
    with pytest.raises(InputError, match=r"loop\.json: cannot write results there \(Too many levels"):
        replace_target(loop, "results")


def test_keep_aside_through_a_symlink_keeps_the_link(tmp_path: Path) -> None:
    """The link's target is set aside beside it; the link stays, so the next file is written through it."""
    (tmp_path / "real").mkdir()
    target = tmp_path / "real" / "system.json"
    target.write_text("earlier")
    link = tmp_path / "system.json"
    link.symlink_to(target)
    kept = keep_aside(link)
    assert kept is not None and kept.parent == tmp_path / "real" and kept.read_text() == "earlier"
    assert link.is_symlink() and not target.exists()
    atomic_write_text(link, "new", "results")
    assert link.is_symlink() and target.read_text() == "new"


def test_a_file_written_whole_keeps_the_permissions_of_the_one_it_replaces(tmp_path: Path) -> None:
    """A report made readable for a web server's group (or a calibration made read-only) keeps its mode when it is
    rewritten, also through a symlink; a new file gets a new file's mode (0666 less the umask) even when the writer
    made its temporary file 0600. A hard link cannot follow a rename: it keeps the earlier text (documented)."""
    report = tmp_path / "report.html"
    report.write_text("old")
    os.chmod(report, 0o640)
    atomic_write_text(report, "new", "report")
    assert report.read_text() == "new" and stat.S_IMODE(report.stat().st_mode) == 0o640
    os.chmod(report, 0o444)
    link = tmp_path / "served.html"
    link.symlink_to(report.name)
    atomic_write_text(link, "newer", "report")
    assert link.is_symlink() and report.read_text() == "newer" and stat.S_IMODE(report.stat().st_mode) == 0o444

    def private(tmp: Path) -> None:  # as tempfile.mkstemp would make it
        os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT, 0o600))
        os.chmod(tmp, 0o600)
        tmp.write_text("made 0600")

    umask = os.umask(0o027)
    try:
        atomic_write(tmp_path / "new.json", private, "results")
        atomic_write(report, private, "report")
    finally:
        os.umask(umask)
    assert stat.S_IMODE((tmp_path / "new.json").stat().st_mode) == 0o640  # 0666 less the umask 027
    assert stat.S_IMODE(report.stat().st_mode) == 0o444 and report.read_text() == "made 0600"
    hard = tmp_path / "hard.html"
    os.link(report, hard)
    atomic_write_text(report, "newest", "report")
    assert hard.read_text() == "made 0600" and report.read_text() == "newest"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["hard.html", "new.json", "report.html", "served.html"]


def test_writable_file_checks_new_folders_without_leaving_them(tmp_path: Path) -> None:
    """The check at start makes the missing folders to write a file there, then removes them: a run that writes
    nothing leaves no empty folders; the writer makes them when it writes. A folder that existed stays."""
    deep = tmp_path / "cams" / "cam1" / "cal.json"
    assert writable_file(deep, "calibration file") == deep
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "cams").mkdir()
    (tmp_path / "cams" / "notes.txt").write_text("kept")
    writable_file(deep, "calibration file")
    assert sorted(p.name for p in (tmp_path / "cams").iterdir()) == ["notes.txt"]
    link = tmp_path / "cal.json"  # a symlink into folders not made yet: checked at its target, nothing left either
    link.symlink_to("real/sub/cal.json")
    writable_file(link, "calibration file")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal.json", "cams"]
    atomic_write_text(link, "{}", "calibration")  # the writer makes them
    assert (tmp_path / "real" / "sub" / "cal.json").read_text() == "{}"
    (tmp_path / "plain").write_text("a file")
    with pytest.raises(InputError, match=r"plain/x/c\.json: cannot write the calibration file there \(Not a dir"):
        writable_file(tmp_path / "plain" / "x" / "c.json", "calibration file")
    assert (tmp_path / "plain").read_text() == "a file"


def test_remove_earlier_keeps_a_symlink_and_removes_its_target(tmp_path: Path) -> None:
    """An earlier run's output is removed before a new run; a symlink (to where the user wants the file, e.g. a web
    server's folder) stays, its target goes, and the next file is written through it."""
    (tmp_path / "www").mkdir()
    target = tmp_path / "www" / "report.html"
    target.write_text("the earlier run's")
    link = tmp_path / "report.html"
    link.symlink_to(target)
    plain = tmp_path / "system.json"
    plain.write_text("{}")
    for path in (link, plain, tmp_path / "missing.json"):
        remove_earlier(path)
    assert link.is_symlink() and not link.exists() and not target.exists() and not plain.exists()
    remove_earlier(link)  # dangling already: nothing to do
    atomic_write_text(link, "this run's", "report")
    assert link.is_symlink() and target.read_text() == "this run's"
    folder = tmp_path / "folder.json"  # a link to a folder: nothing removed (writing there is refused on its own)
    folder.symlink_to(tmp_path / "www")
    remove_earlier(folder)
    assert folder.is_symlink() and target.read_text() == "this run's"


def test_pictures_are_written_whole_in_their_names_format_or_refused(tmp_path: Path) -> None:
    """atomic_write_image encodes in the extension's format and renames into place (the mode of the earlier picture
    kept); an extension OpenCV has no encoder for, or a folder in the way, is an InputError naming the file —
    cv2.imwrite raised a cv2.error for the one and returned False, unread, for the other."""
    import cv2
    import numpy as np

    from gst_trafficcal.fileio import atomic_write_image, writable_image
    from gst_trafficcal.synth.groundtruth import contact_sheet

    image = np.zeros((20, 30, 3), np.uint8)
    image[5:15, 10:20] = (0, 0, 255)
    png = tmp_path / "grid.PNG"
    png.write_bytes(b"earlier")
    png.chmod(0o640)
    assert atomic_write_image(png, image, "grid picture") == png
    assert np.array_equal(cv2.imread(str(png)), image) and stat.S_IMODE(png.stat().st_mode) == 0o640
    jpg = atomic_write_image(tmp_path / "grid.jpg", image, "grid picture")
    assert jpg.read_bytes()[:2] == b"\xff\xd8"  # a JPEG
    for name in ("grid.xyz", "grid"):
        with pytest.raises(InputError, match=rf"{name}: cannot write the grid picture \(OpenCV writes no picture "
                                             r"named (\.xyz|without an extension): name it \.png or \.jpg\)"):
            writable_image(tmp_path / name, "grid picture")
        with pytest.raises(InputError, match=rf"{name}: cannot write grid picture \(OpenCV writes no picture"):
            atomic_write_image(tmp_path / name, image, "grid picture")
    (tmp_path / "preview.png").mkdir()  # synth's preview: an error said, no longer a False ignored
    with pytest.raises(InputError, match=r"preview\.png: a folder, not a regular file: cannot write preview picture"):
        contact_sheet([(0.0, image, [])], tmp_path / "preview.png")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["grid.PNG", "grid.jpg", "preview.png"]  # no temporary file
