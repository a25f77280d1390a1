"""Reading and writing the project's files with errors a user can act on.

Every reader raises :class:`InputError` naming the file (missing, unreadable, not JSON); every writer is atomic
(temporary file, fsync, rename) so a crash or a full disk never leaves half a file where a good one was.  A symlink
is written through (the rename happens on its target, the link stays); a named pipe, device or socket at the path
is refused, since renaming over it would replace it by a regular file.
"""

from __future__ import annotations

import contextlib
import json
import os
import stat
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from .errors import InputError


def read_text(path: str | Path, what: str) -> str:
    """The text of ``path``; InputError "<path>: no such file" / "cannot read <what>" otherwise."""
    path = Path(path)
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read {what} ({exc})") from None


def read_json(path: str | Path, what: str) -> Any:
    """Parsed JSON of ``path``; InputError naming the file and the position of a syntax error."""
    try:
        return json.loads(read_text(path, what))
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON, so not a {what} ({exc.msg} at line {exc.lineno})") from None


def json_text_field(path: str | Path, field: str, what: str, must: str) -> str | None:
    """The text field ``field`` of the JSON object in ``path`` (a ``what``), None when it has none; InputError
    "PATH: field 'FIELD' must be MUST" when it is there but no text."""
    d = read_json(path, what)
    text = d.get(field) if isinstance(d, dict) else None
    if text is not None and not isinstance(text, str):
        raise InputError(f"{path}: field '{field}' must be {must}")
    return text


def is_json_number(x: Any, whole: bool = False) -> bool:
    """Whether a value read from JSON is a number (a whole one with ``whole``); true and false are not, though Python
    counts them as ints: ``[true, 0]`` is no image point, ``true`` no scale."""
    return isinstance(x, int if whole else (int, float)) and not isinstance(x, bool)


_KINDS: tuple[tuple[Callable[[int], bool], str], ...] = (
    (stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a named pipe"), (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"),
)


def link_target(path: str | Path) -> Path:
    """The file a symlink at ``path`` leads to (resolved whole), else ``path`` itself."""
    path = Path(path)
    return Path(os.path.realpath(path)) if path.is_symlink() else path


def replace_target(path: str | Path, what: str) -> Path:
    """Where a file written whole and renamed into place (:func:`atomic_write`) must go for ``path``: the file a
    symlink leads to (so the link stays a link and its target gets the new text), else ``path`` itself.
    InputError naming ``path`` when something other than a regular file is there (a named pipe, a device, a
    socket, a folder): renaming over it would replace it instead of writing to it."""
    path = Path(path)
    target = link_target(path)
    try:
        mode = target.stat().st_mode
    except (FileNotFoundError, NotADirectoryError):  # nothing there yet (a folder that is a file: said by the caller)
        return target
    except OSError as exc:  # a symlink loop, a folder that cannot be searched
        raise InputError(f"{path}: cannot write {what} there ({exc.strerror or exc})") from None
    if stat.S_ISREG(mode):
        return target
    kind = next((name for test, name in _KINDS if test(mode)), "an unknown kind of file")
    via = f" (a link to {target})" if target != path else ""
    raise InputError(f"{path}{via}: {kind}, not a regular file: cannot write {what} there "
                     "(it is written whole, then renamed into place)")


def atomic_write(path: str | Path, write: Callable[[Path], None], what: str) -> Path:
    """Call ``write(tmp)`` then move ``tmp`` over ``path``; InputError "<path>: cannot write <what> (...)".

    A symlink at ``path`` is followed: the temporary file is made beside its target and renamed over the target
    (atomic on the target's file system), the link is kept.  Anything else that is not a regular file is refused
    (:func:`replace_target`).  The new file keeps the permission bits (rwx of owner, group and others) of the file
    it replaces — a report made readable for a web server stays readable — and a new one gets those of any new
    file (0666 less the umask), whatever mode ``write`` gave ``tmp``.  What a rename cannot keep is not kept: a
    hard link to the earlier file goes on holding the earlier text, and the new file belongs to whoever wrote it.
    Returns ``path``."""
    path = Path(path)
    target = replace_target(path, what)
    tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        mode = _mode_for(target, tmp)
        write(tmp)
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, mode)  # after the fsync, which must open it: an earlier file may have been unreadable
        os.replace(tmp, target)
    except BaseException as exc:  # no temporary file left, whatever failed (also a value write() cannot encode, Ctrl-C)
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise InputError(f"{path}: cannot write {what} ({exc.strerror or exc})") from None
        raise
    return path


def _mode_for(target: Path, tmp: Path) -> int:
    """The permission bits the file replacing ``target`` gets: the earlier file's, else a new file's (``tmp`` is
    created empty with 0666, which the kernel reduces by the umask: no process-wide umask call, which another
    thread creating a file meanwhile would see)."""
    with contextlib.suppress(FileNotFoundError):
        tmp.unlink()  # a leftover of a crashed writer of the same pid: its mode would be taken for a new file's
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o666)
    try:
        new = stat.S_IMODE(os.fstat(fd).st_mode)
    finally:
        os.close(fd)
    try:
        return stat.S_IMODE(target.stat().st_mode) & 0o777
    except FileNotFoundError:
        return new & 0o777


def atomic_write_text(path: str | Path, text: str, what: str) -> Path:
    """Write ``text`` (UTF-8) atomically."""
    return atomic_write(path, lambda tmp: tmp.write_text(text, encoding="utf-8"), what)


def atomic_write_image(path: str | Path, image: Any, what: str) -> Path:
    """Write the BGR picture ``image`` whole, then rename it into place (:func:`atomic_write`): a crash or a full
    disk leaves the earlier picture, never half of one.  The format is the name's extension (.png, .jpg, ...);
    InputError "<path>: cannot write <what> (...)" when OpenCV cannot encode it so."""
    import cv2

    path = Path(path)
    try:
        ok, data = cv2.imencode(path.suffix, image)
    except cv2.error:  # no encoder for that extension
        ok = False
    if not ok:
        raise _no_picture_format(path, f"cannot write {what}")
    return atomic_write(path, lambda tmp: tmp.write_bytes(data.tobytes()), what)


def _no_picture_format(path: Path, cannot: str) -> InputError:
    """The error for a picture named with an extension OpenCV has no encoder for (``cannot``: "cannot write ...")."""
    return InputError(f"{path}: {cannot} (OpenCV writes no picture named "
                      f"{path.suffix or 'without an extension'}: name it .png or .jpg)")


def writable_image(path: str | Path, what: str) -> Path:
    """``path`` checked before any work as a picture :func:`atomic_write_image` can write: an extension OpenCV has
    an encoder for, and a place :func:`writable_file` accepts; InputError naming ``what`` otherwise."""
    import cv2

    path = Path(path)
    if not path.is_dir() and not cv2.haveImageWriter(str(path)):
        raise _no_picture_format(path, f"cannot write the {what}")
    return writable_file(path, what)


def writable_dir(path: str | Path, what: str) -> Path:
    """The folder ``path``, created if missing and checked writable before any work is done; InputError
    "<path>: cannot create <what> (...)" / "cannot write in <what> (...)" otherwise."""
    import tempfile

    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"{path}: not a folder, so it cannot be the {what}")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{path}: cannot create the {what} ({exc.strerror or exc})") from None
    try:
        with tempfile.NamedTemporaryFile(dir=path, prefix=".write-check-"):
            pass
    except OSError as exc:
        raise InputError(f"{path}: cannot write in the {what} ({exc.strerror or exc})") from None
    return path


def writable_file(path: str | Path, what: str) -> Path:
    """``path``, checked before any work that a file written whole and renamed into place (:func:`atomic_write`)
    can go there: its folder (a symlink's: its target's) writable — a file is made and removed there — and nothing
    but a regular file already there (no folder, named pipe, device: :func:`replace_target`), which is not touched;
    InputError naming ``what`` otherwise.  Folders missing on the way are made for the check and removed again:
    a run that then writes nothing (it failed, or it found nothing to write) leaves no empty folders behind, and
    the writer makes them when it writes."""
    import tempfile

    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: a folder, so it cannot be the {what}")
    folder = replace_target(path, f"the {what}").parent
    made: list[Path] = []  # the folders this check made, deepest last
    try:
        for f in missing_folders(folder):
            f.mkdir()
            made.append(f)
        if not folder.is_dir():
            raise NotADirectoryError(20, f"{folder} is not a folder")
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".write-check-"):
            pass
    except OSError as exc:
        raise InputError(f"{path}: cannot write the {what} there ({exc.strerror or exc})") from None
    finally:
        remove_empty_folders(made)
    return path


def missing_folders(path: str | Path) -> list[Path]:
    """The folders that must be made for the folder ``path`` to exist (itself included), outermost first; none
    when it exists (or something else is in its place: said by whoever makes it)."""
    path = Path(path)
    missing = [path, *path.parents]
    missing = missing[:next((k for k, f in enumerate(missing) if f.exists() or f.is_symlink()), len(missing))]
    return missing[::-1]


@contextlib.contextmanager
def folder_made_for(path: str | Path) -> Iterator[list[Path]]:
    """Around making the folder ``path`` and the checks of the work that goes in it: when the block raises (the work
    was refused), the folders it made are removed again if still empty, so a refused run leaves nothing behind.
    Yields the folders missing when it started (empty: ``path`` existed), outermost first."""
    made = missing_folders(path)
    try:
        yield made
    except BaseException:
        remove_empty_folders(made)
        raise


def remove_empty_folders(folders: list[Path]) -> None:
    """Remove ``folders`` (outermost first, as :func:`missing_folders` gives them), deepest first, each only if it is
    there and empty: what was put in one meanwhile (another writer) stays, with the folders on the way to it."""
    for f in reversed(folders):
        with contextlib.suppress(OSError):
            f.rmdir()


def free_path(path: str | Path) -> Path:
    """``path`` if nothing is there, else the first of ``name-2.ext``, ``name-3.ext``, ... that is free (a folder's
    ``name-2``): where something is set aside or started without replacing what is already there."""
    path = Path(path)
    k = 2
    free = path
    while free.exists():
        free = path.with_name(f"{path.stem}-{k}{path.suffix}")
        k += 1
    return free


def remove_earlier(path: str | Path) -> None:
    """Remove an earlier run's file at ``path`` before a new run writes it, so that it is not taken for the new
    run's (a file the new run does not write is then missing, not stale).  A symlink stays — it is where the user
    wants the file, as for every file written whole (:func:`atomic_write`) — and the file it leads to is removed,
    so the link dangles until the new file is written through it.  A link to something else than a regular file
    (a folder, a named pipe) is left alone: writing there is refused with its own error."""
    path = Path(path)
    if path.is_symlink():
        target = link_target(path)
        with contextlib.suppress(OSError):
            if not stat.S_ISREG(target.lstat().st_mode):
                return
        path = target
    path.unlink(missing_ok=True)


def keep_aside(path: str | Path) -> Path | None:
    """Move a non-empty file at ``path`` to ``name.earlier-<its last change>.ext`` beside it (numbered when taken)
    instead of letting a new run replace it; returns where it went, or None when there was nothing to keep.  A
    symlink's target is moved (beside the target), so the link stays and the new file is written through it.
    InputError naming the file when it cannot be moved."""
    from datetime import datetime

    path = link_target(path)
    try:
        st = path.stat()
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if st.st_size == 0 or not path.is_file():
        return None
    stem, ext = (path.name.split(".", 1) + [""])[:2]
    when = f"{datetime.fromtimestamp(st.st_mtime):%Y%m%d-%H%M%S}"
    kept = path.with_name(f"{stem}.earlier-{when}" + (f".{ext}" if ext else ""))
    try:
        kept = free_path(kept)
        path.rename(kept)
    except OSError as exc:
        raise InputError(f"{path}: cannot keep the earlier file as {kept.name} ({exc.strerror or exc})") from None
    return kept


@contextlib.contextmanager
def quiet_ffmpeg():
    """OpenCV's FFmpeg keeps its complaints ("moov atom not found") off the console meanwhile, unless the user set
    OPENCV_FFMPEG_LOGLEVEL: where a refusal is handled with an error of our own, they are noise before it."""
    user_level = os.environ.get("OPENCV_FFMPEG_LOGLEVEL")
    os.environ["OPENCV_FFMPEG_LOGLEVEL"] = user_level or "-8"
    try:
        yield
    finally:
        if user_level is None:
            os.environ.pop("OPENCV_FFMPEG_LOGLEVEL", None)


def video_file(path: str | Path) -> Path:
    """``path`` when a file is there; InputError "<path>: a folder, not a video file" / "no such file" otherwise."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: a folder, not a video file")
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    return path


def cannot_open_video(path: str | Path) -> InputError:
    """The error for a file no decoder opens."""
    return InputError(f"{path}: cannot open video (not a video file, or no decoder for it)")


def open_video(path: str | Path):
    """An opened ``cv2.VideoCapture``; InputError (:func:`video_file`, :func:`cannot_open_video`) otherwise."""
    import cv2

    path = video_file(path)
    with quiet_ffmpeg():  # a file it cannot open is said in one line below
        cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise cannot_open_video(path)
    return cap
