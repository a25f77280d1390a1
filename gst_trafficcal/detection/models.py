"""Detector model provisioning: verified copies of user-chosen ONNX files in a per-user cache.

The project ships no weights. ``install`` copies a local file or downloads a URL into
``$XDG_CACHE_HOME/gst-trafficcal/models`` (``~/.cache/...`` by default) after checking its SHA-256 and
that onnxruntime can open it; elements and commands then accept the bare file name as ``model``.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
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
    size: int
    sha256: str


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


def _check_onnx(path: Path, shown: str) -> None:
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.log_severity_level = 3
    try:
        ort.InferenceSession(str(path), sess_options=opts, providers=["CPUExecutionProvider"])
    except Exception as exc:
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise InputError(f"{shown}: not a usable ONNX model ({first[:200]})") from None


def install(source: str | Path, sha256: str, name: str | None = None) -> Path:
    """Copy/download ``source`` into the cache as ``name`` (default: its file name); return the path.

    The file must have the given SHA-256 (hex, case-insensitive) and open in onnxruntime; nothing
    is left in the cache otherwise. Installing the same file again is a no-op.
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
    if not is_url and not Path(source).is_file():
        raise InputError(f"model file not found: {source}")
    dest_dir = cache_dir()
    dest = dest_dir / filename
    if dest.is_file() and sha256_of(dest) == expected:
        return dest
    dest_dir.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=".part-", dir=dest_dir)
    tmp = Path(tmp_name)
    try:
        h = hashlib.sha256()
        with os.fdopen(fd, "wb") as out:
            try:
                src = urllib.request.urlopen(source, timeout=60) if is_url else open(source, "rb")
            except OSError as exc:
                raise InputError(f"cannot fetch {source}: {exc}") from None
            with src:
                while chunk := src.read(CHUNK):
                    h.update(chunk)
                    out.write(chunk)
        got = h.hexdigest()
        if got != expected:
            raise InputError(f"{source}: SHA-256 mismatch (expected {expected}, got {got})")
        _check_onnx(tmp, source)
        os.replace(tmp, dest)
    finally:
        tmp.unlink(missing_ok=True)
    return dest


def list_models() -> list[ModelEntry]:
    """Installed models, sorted by name."""
    d = cache_dir()
    if not d.is_dir():
        return []
    return [
        ModelEntry(p.name, p, p.stat().st_size, sha256_of(p))
        for p in sorted(d.iterdir())
        if p.is_file() and not p.name.startswith(".part-")
    ]


def resolve_model(model: str | Path) -> Path:
    """A model given as a path, or as the name of an installed model; InputError when neither exists."""
    p = Path(model).expanduser()
    if p.is_file():
        return p
    cached = cache_dir() / str(model)
    if not p.is_absolute() and "/" not in str(model) and cached.is_file():
        return cached
    raise InputError(f"model file not found: {model} (neither a file nor a model installed in {cache_dir()})")
