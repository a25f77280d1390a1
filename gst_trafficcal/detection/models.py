"""Detector model provisioning: verified copies of user-chosen ONNX files in a per-user cache.

The project ships no weights. ``install`` copies a local file or downloads a URL into
``$XDG_CACHE_HOME/gst-trafficcal/models`` (``~/.cache/...`` by default) after checking its SHA-256 and
that onnxruntime can open it; elements and commands then accept the bare file name as ``model``.
"""

from __future__ import annotations

import contextlib
import hashlib
import http.client
import os
import secrets
import urllib.parse
import urllib.request
from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError

CHUNK = 1 << 20


@dataclass(frozen=True)
class ModelEntry:
    """One installed model file."""

    name: str
    path: Path
    size: int | None
    sha256: str | None  # None when the file cannot be read
    problem: str = ""  # why it cannot be read ("" for a readable file)


@dataclass(frozen=True)
class Installed:
    """What ``install`` did: ``action`` is "installed", "unchanged" (the same file was there) or "replaced"."""

    path: Path
    action: str


def cache_dir() -> Path:
    """The per-user model cache directory (not created)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "gst-trafficcal" / "models"


def sha256_of(path: str | Path) -> str:
    """Hex SHA-256 of a file, read in chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(CHUNK):
            h.update(chunk)
    return h.hexdigest()


def _is_url(source: str) -> bool:
    return urllib.parse.urlparse(source).scheme in ("http", "https", "ftp", "file")


def _os_error(exc: OSError, about: Path | None = None) -> str:
    """An OSError in a few words, with the file it is about unless that is ``about`` or a file in it (a temporary
    name says nothing to the user): 'No such file or directory: /proc/foo'."""
    words = exc.strerror or str(exc) or type(exc).__name__
    if not exc.filename or (about is not None and about in (Path(exc.filename), Path(exc.filename).parent)):
        return words
    return f"{words}: {exc.filename}"


def _check_onnx(path: Path, shown: str) -> None:
    """InputError unless onnxruntime opens ``path``; the message names ``shown`` (the user's source), not ``path``."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.log_severity_level = 3
    try:
        ort.InferenceSession(str(path), sess_options=opts, providers=["CPUExecutionProvider"])
    except Exception as exc:
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0].replace(str(path), shown)
        raise InputError(f"{shown}: not a usable ONNX model ({first[:200]})") from None


def _create_part(folder: Path) -> tuple[int, Path]:
    """A new temporary file in ``folder``, open for writing, with mode 0666 less the umask like any new file
    (mkstemp's 0600 would hide the model from the other users of a shared cache)."""
    for _ in range(10):
        tmp = folder / f".part-{secrets.token_hex(8)}"
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666), tmp
        except FileExistsError:
            continue
    raise FileExistsError(f"no free temporary name in {folder}")


def _installed_already(dest: Path, expected: str, force: bool) -> bool:
    """Whether ``dest`` holds the file with SHA-256 ``expected`` already; InputError when it holds another one
    (or one that cannot be read) and ``force`` is false."""
    if not (dest.exists() or dest.is_symlink()):
        return False
    if dest.is_dir():
        raise InputError(f"{dest}: a folder is in the way in the model cache (remove it, or pass another --name)")
    try:
        got = sha256_of(dest)
    except OSError as exc:
        if force:
            return False
        raise InputError(f"{dest}: cannot read the model installed under this name ({_os_error(exc, dest)}); "
                         "pass --force to replace it") from None
    if got == expected:
        return True
    if not force:
        raise InputError(f"{dest}: a different model is installed under this name (SHA-256 {got}); pass --force "
                         "to replace it, or --name to install under another name")
    return False


def _copy(source: str, is_url: bool, fd: int) -> str:
    """Copy ``source`` into the open file ``fd`` (closed after); its hex SHA-256.  Errors reading the source are
    InputError naming it; errors writing stay OSError (the cache's)."""
    h = hashlib.sha256()
    with os.fdopen(fd, "wb") as out:
        try:
            src = urllib.request.urlopen(source, timeout=60) if is_url else open(source, "rb")
        except OSError as exc:
            raise InputError(f"cannot fetch {source} ({_os_error(exc)})") from None
        with src:
            while True:
                try:
                    chunk = src.read(CHUNK)
                except (OSError, http.client.HTTPException) as exc:
                    raise InputError(f"cannot read {source} ({exc})") from None
                if not chunk:
                    break
                h.update(chunk)
                out.write(chunk)
    return h.hexdigest()


def install(source: str | Path, sha256: str, name: str | None = None, force: bool = False) -> Installed:
    """Copy/download ``source`` into the cache as ``name`` (default: its file name).

    The file must have the given SHA-256 (hex, case-insensitive) and open in onnxruntime; nothing
    is left in the cache otherwise. Installing the same file again does nothing ("unchanged"); a different
    file under a name already installed is refused unless ``force``. The new file gets the usual permissions
    (0666 less the umask). Every failure, the cache's included (not writable, not creatable), is an InputError.
    """
    expected = sha256.strip().lower()
    if len(expected) != 64 or any(c not in "0123456789abcdef" for c in expected):
        raise InputError(f"--sha256 must be 64 hexadecimal digits, got {sha256!r}")
    source = str(source)
    is_url = _is_url(source)
    filename = name or Path(urllib.parse.urlparse(source).path if is_url else source).name
    if name is not None and (not name or name in (".", "..") or "/" in name or "\\" in name):
        raise InputError(f"--name {name!r}: a file name in the model cache, without folders (e.g. mymodel.onnx)")
    if not filename or filename in (".", "..") or "/" in filename:
        raise InputError(f"cannot derive a model file name from {source!r}; pass a name")
    if not is_url and Path(source).is_dir():
        raise InputError(f"{source}: a directory, not a model file")
    if not is_url and not Path(source).is_file():
        raise InputError(f"model file not found: {source}")
    dest_dir = cache_dir()
    dest = dest_dir / filename
    try:
        if _installed_already(dest, expected, force):
            return Installed(dest, "unchanged")
        existed = dest.exists() or dest.is_symlink()
        dest_dir.mkdir(parents=True, exist_ok=True)
        fd, tmp = _create_part(dest_dir)
    except OSError as exc:
        raise InputError(f"cannot write to the model cache {dest_dir} ({_os_error(exc, dest_dir)})") from None
    try:
        got = _copy(source, is_url, fd)
        if got != expected:
            raise InputError(f"{source}: SHA-256 mismatch (expected {expected}, got {got})")
        _check_onnx(tmp, source)
        os.replace(tmp, dest)
    except OSError as exc:
        raise InputError(f"cannot write to the model cache {dest_dir} ({_os_error(exc, dest_dir)})") from None
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
    return Installed(dest, "replaced" if existed else "installed")


def list_models() -> list[ModelEntry]:
    """Installed models, sorted by name; one that cannot be read is listed with its ``problem`` (no SHA-256).
    InputError when the cache folder itself cannot be read."""
    d = cache_dir()
    try:
        if not d.is_dir():
            return []
        files = sorted(p for p in d.iterdir() if p.is_file() and not p.name.startswith(".part-"))
    except OSError as exc:
        raise InputError(f"cannot read the model cache {d} ({_os_error(exc, d)})") from None
    entries = []
    for p in files:
        size: int | None = None
        try:
            size = p.stat().st_size
            entries.append(ModelEntry(p.name, p, size, sha256_of(p)))
        except OSError as exc:
            entries.append(ModelEntry(p.name, p, size, None, f"cannot read it ({exc.strerror or exc})"))
    return entries


def resolve_model(model: str | Path) -> Path:
    """A model given as a path, or as the name of an installed model; InputError when neither exists."""
    p = Path(model).expanduser()
    places = [p] if p.is_absolute() or "/" in str(model) else [p, cache_dir() / str(model)]
    for path in places:
        try:
            if path.is_file():
                return path
        except OSError as exc:  # a folder on the way that this user may not search (Python 3.11 raises it)
            raise InputError(f"{path}: cannot look for model {model} there ({_os_error(exc, path)})") from None
    raise InputError(f"model file not found: {model} (neither a file nor a model installed in {cache_dir()})")
