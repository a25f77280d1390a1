"""Output files (and folders) claimed by the running elements of this process, so that none has two writers.

Two speedometers given one ``events-file`` (the branches of a ``tee``, two pipelines of one NVR process, or one
element given the same path as its ``events-file`` and its ``csv-file``) each wrote every vehicle into it: the file
held each vehicle twice, or two cameras' vehicles mixed, and the tables rewritten whole (results, intervals)
replaced each other — all without a word.  So did two vpdetects learning into one ``calibration-file`` or
``views-dir`` (each replaced the other's calibration, two cameras' views mixed in one folder).  An element claims its
output files when it starts and releases them when it stops; a file claimed already is refused at the start with
both users named.
"""

from __future__ import annotations

import os
import stat
import threading
import weakref
from collections.abc import Mapping
from typing import Any

from ..errors import InputError

_lock = threading.Lock()
_claims: dict[str, tuple[Any, str]] = {}  # real path -> (weak reference to the element, "who (which property)")


#: why a file claimed already is refused (speedometer's outputs; vpdetect gives its own)
VEHICLES_TWICE = ("two writers of one file write each vehicle twice, or mix two streams' vehicles, and replace each "
                  "other's tables; give each element files of its own")


def claim(element: Any, files: Mapping[str, str], why: str = VEHICLES_TWICE) -> list[str]:
    """Claim the non-empty paths of ``files`` (property name -> path) for ``element``; the keys to :func:`release`.
    InputError naming the other user (and ``why`` that is wrong) when a path is claimed already — by another running
    element, or by another of ``files`` — and nothing is claimed then.  A path that is neither a regular file nor a
    folder (``/dev/null``) is not claimed."""
    who = element.get_path_string() if hasattr(element, "get_path_string") else str(element)
    wanted: dict[str, str] = {}
    for prop, path in files.items():
        key = _key(path) if path else None
        if key is None:
            continue
        if key in wanted:
            raise InputError(f"{prop} {path} is also its {wanted[key]}: give each output a file of its own")
        wanted[key] = prop
    with _lock:
        for key, prop in wanted.items():
            ref, by = _claims.get(key, (None, ""))
            if ref is not None and ref() is not None and ref() is not element:
                raise InputError(f"{prop} {files[prop]} is written already by {by}: {why}")
        for key, prop in wanted.items():
            _claims[key] = (weakref.ref(element), f"{who} (its {prop})")
    return list(wanted)


def release(element: Any, keys: list[str]) -> None:
    """Give back what :func:`claim` returned for ``element``."""
    with _lock:
        for key in keys:
            ref, _ = _claims.get(key, (None, ""))
            if ref is not None and ref() in (element, None):
                del _claims[key]


def _key(path: str) -> str | None:
    """The file or folder ``path`` names, the same for every spelling of it (relative, through symlinks); None for a
    path that is something else (a device such as /dev/null, which any number of outputs may share)."""
    real = os.path.realpath(os.path.expanduser(path))
    try:
        mode = os.stat(real).st_mode
        if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
            return None
    except OSError:  # not there yet: it will be a regular file
        pass
    return real
