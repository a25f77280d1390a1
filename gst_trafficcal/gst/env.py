"""The environment gst-launch-1.0 / gst-inspect-1.0 need to run our Python elements.

The gst-python plugin loader (``libgstpython.so``) embeds Debian's ``/usr/bin/python3`` and finds
Python elements in ``<entry>/python/*.py`` for every entry of ``GST_PLUGIN_PATH``. The embedded
interpreter looks for ``python3`` on ``PATH`` to find its prefix: with the venv's ``bin`` first on
``PATH`` it picks up the venv's ``pyvenv.cfg`` and hence its site-packages (numpy, cv2, ...);
``PYTHONPATH`` (repository root + venv site-packages) makes the same work even when ``PATH`` is
not in our favour. ``scripts/env.sh`` sets exactly the same variables. No ``gi`` import here.
"""

from __future__ import annotations

import os
import shlex
import sys
import sysconfig
from collections.abc import Iterable, Mapping
from pathlib import Path

from ..errors import InputError

VARIABLES = ("VIRTUAL_ENV", "PATH", "GST_PLUGIN_PATH", "PYTHONPATH")


def project_root() -> Path:
    """The repository checkout this package runs from (holds ``elements/`` and ``.venv``)."""
    return Path(__file__).resolve().parents[2]


def elements_dir(root: Path | None = None) -> Path:
    """``<root>/elements``: the GST_PLUGIN_PATH entry whose ``python/`` holds our elements."""
    d = (root or project_root()) / "elements"
    if not (d / "python").is_dir():
        raise InputError(
            f"{d / 'python'}: element directory not found (run from a gst-trafficcal checkout installed in editable mode)"
        )
    return d


def venv_dir(root: Path | None = None) -> Path:
    """The virtual environment: the running one when inside a venv, else ``<root>/.venv``."""
    if sys.prefix != sys.base_prefix:
        return Path(sys.prefix)
    return (root or project_root()) / ".venv"


def _site_packages(venv: Path) -> Path:
    if Path(sys.prefix).resolve() == venv.resolve():
        return Path(sysconfig.get_paths()["purelib"])
    ver = f"python{sys.version_info.major}.{sys.version_info.minor}"
    return venv / "lib" / ver / "site-packages"


def _prepend(new: Iterable[str], old: str | None) -> str:
    first = [str(p) for p in new]
    rest = [p for p in (old or "").split(os.pathsep) if p and p not in first]
    return os.pathsep.join(first + rest)


def gst_environment(
    base: Mapping[str, str] | None = None, plugin_dirs: Iterable[str | Path] = ()
) -> dict[str, str]:
    """The values of :data:`VARIABLES` to run our elements, prepended to those of ``base`` (default: os.environ).

    ``plugin_dirs`` are extra GST_PLUGIN_PATH entries (each with a ``python/`` subdirectory), put right after our
    elements: a Python element of another make that imports OpenCV first (its bootstrap rewrites the embedded
    interpreter's import path) left the loader unable to import ours after it — all six elements were gone.
    """
    base = os.environ if base is None else base
    root = project_root()
    venv = venv_dir(root)
    plugins = [elements_dir(root)] + [Path(p).resolve() for p in plugin_dirs]
    return {
        "VIRTUAL_ENV": str(venv),
        "PATH": _prepend([venv / "bin"], base.get("PATH", os.defpath)),
        "GST_PLUGIN_PATH": _prepend(plugins, base.get("GST_PLUGIN_PATH")),
        "PYTHONPATH": _prepend([root, _site_packages(venv)], base.get("PYTHONPATH")),
    }


def shell_exports(env: Mapping[str, str]) -> str:
    """POSIX-shell ``export`` lines for ``env`` (for ``eval "$(trafficcal gst-env)"``)."""
    return "".join(f"export {k}={shlex.quote(env[k])}\n" for k in VARIABLES if k in env)
