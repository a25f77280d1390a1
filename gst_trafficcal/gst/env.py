"""The environment gst-launch-1.0 / gst-inspect-1.0 need to run our Python elements.

The gst-python plugin loader (``libgstpython.so``) embeds Debian's ``/usr/bin/python3`` and finds
Python elements in ``<entry>/python/*.py`` for every entry of ``GST_PLUGIN_PATH``. The embedded
interpreter looks for ``python3`` on ``PATH`` to find its prefix: with the venv's ``bin`` first on
``PATH`` it picks up the venv's ``pyvenv.cfg`` and hence its site-packages (numpy, cv2, ...);
``PYTHONPATH`` (repository root + venv site-packages) makes the same work even when ``PATH`` is
not in our favour. ``scripts/env.sh`` sets exactly the same variables. No ``gi`` import here.

Installed from a wheel (``pip install .``), the elements are the package's copy (``gst_trafficcal/elements``,
gst_trafficcal.resources) and PYTHONPATH starts with the directory the package was installed into; outside a venv,
VIRTUAL_ENV and PATH are left alone (the system's ``python3`` is the one the loader embeds).
"""

from __future__ import annotations

import os
import shlex
import sys
import sysconfig
from collections.abc import Iterable, Mapping
from pathlib import Path

from ..errors import InputError
from ..resources import shipped

VARIABLES = ("VIRTUAL_ENV", "PATH", "GST_PLUGIN_PATH", "PYTHONPATH")
LOADER = "libgstpython.so"
"""gst-python's plugin loader: without it GStreamer loads no Python element ("No such element or plugin")."""
LOADER_PACKAGE = "gstreamer1.0-python3-plugin-loader"


def project_root() -> Path:
    """The directory this package is imported from: the repository checkout (holds ``elements/`` and ``.venv``), or
    the site-packages / ``pip install --target`` directory of an installed wheel."""
    return Path(__file__).resolve().parents[2]


def elements_dir(root: Path | None = None) -> Path:
    """The GST_PLUGIN_PATH entry whose ``python/`` holds our elements: ``<root>/elements`` when ``root`` is given,
    else the installed package's copy or the checkout's ``elements/``."""
    d = root / "elements" if root is not None else shipped("elements")
    if not (d / "python").is_dir():
        raise InputError(f"{d / 'python'}: element directory not found (reinstall gst-trafficcal: `pip install .` "
                         "from a checkout, or run from a checkout installed in editable mode)")
    return d


def venv_dir(root: Path | None = None) -> Path | None:
    """The virtual environment: the running one when inside a venv, else ``<root>/.venv`` when it exists (None:
    the package runs from the system's Python)."""
    if sys.prefix != sys.base_prefix:
        return Path(sys.prefix)
    venv = (root or project_root()) / ".venv"
    return venv if venv.is_dir() else None


def _site_packages(venv: Path | None) -> Path:
    if venv is None or Path(sys.prefix).resolve() == venv.resolve():
        return Path(sysconfig.get_paths()["purelib"])
    ver = f"python{sys.version_info.major}.{sys.version_info.minor}"
    return venv / "lib" / ver / "site-packages"


def _prepend(new: Iterable[str | Path], old: str | None) -> str:
    first = list(dict.fromkeys(str(p) for p in new))  # an installed package's root may be the site-packages
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
    plugins = [elements_dir()] + [Path(p).resolve() for p in plugin_dirs]
    env = {
        "GST_PLUGIN_PATH": _prepend(plugins, base.get("GST_PLUGIN_PATH")),
        "PYTHONPATH": _prepend([root, _site_packages(venv)], base.get("PYTHONPATH")),
    }
    if venv is not None:
        env.update(VIRTUAL_ENV=str(venv), PATH=_prepend([venv / "bin"], base.get("PATH", os.defpath)))
    return dict(sorted(env.items(), key=lambda kv: VARIABLES.index(kv[0])))


def _dirs(value: str | None) -> list[Path]:
    return [Path(p) for p in (value or "").split(os.pathsep) if p]


def plugin_loader(base: Mapping[str, str] | None = None) -> Path | None:
    """The plugin loader (:data:`LOADER`) in a directory GStreamer scans for plugins, None when there is none.

    The directories as GStreamer 1.22 chooses them: GST_PLUGIN_PATH(_1_0), then GST_PLUGIN_SYSTEM_PATH(_1_0) when
    set (even empty), else the user's plugin directory and the system's (``<libdir>/gstreamer-1.0``)."""
    base = os.environ if base is None else base
    user = base.get("GST_PLUGIN_PATH_1_0", base.get("GST_PLUGIN_PATH"))
    system = base.get("GST_PLUGIN_SYSTEM_PATH_1_0", base.get("GST_PLUGIN_SYSTEM_PATH"))
    if system is None:
        libdirs = {sysconfig.get_config_var("LIBDIR") or "/usr/lib", "/usr/lib", "/usr/local/lib"}
        if sysconfig.get_config_var("MULTIARCH"):
            libdirs.add(f"/usr/lib/{sysconfig.get_config_var('MULTIARCH')}")
        defaults = [Path(base.get("HOME", "~")).expanduser() / ".local/share/gstreamer-1.0/plugins"]
        system = os.pathsep.join(str(p) for p in defaults + [Path(d) / "gstreamer-1.0" for d in sorted(libdirs)])
    for d in _dirs(user) + _dirs(system):
        if (d / LOADER).is_file():
            return d / LOADER
    return None


def require_plugin_loader(base: Mapping[str, str] | None = None) -> Path:
    """:func:`plugin_loader`, or an InputError naming the Debian package that installs it."""
    found = plugin_loader(base)
    if found is None:
        raise InputError(f"GStreamer's Python plugin loader ({LOADER}) is not where GStreamer looks for plugins, "
                         "so gst-launch-1.0 and gst-inspect-1.0 cannot load our elements: install the Debian package "
                         f"{LOADER_PACKAGE} (apt-get install {LOADER_PACKAGE} python3-gst-1.0)")
    return found


def shell_exports(env: Mapping[str, str]) -> str:
    """POSIX-shell ``export`` lines for ``env`` (for ``eval "$(trafficcal gst-env)"``)."""
    return "".join(f"export {k}={shlex.quote(env[k])}\n" for k in VARIABLES if k in env)
