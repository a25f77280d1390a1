"""Where the files shipped beside the library are: the GStreamer element files and the vehicle catalogue.

In a checkout (and its editable install) they are the repository's ``elements/`` and ``models3d/``, the product's
layout. A built wheel carries them inside the package, as ``gst_trafficcal/elements/python/*.py`` and
``gst_trafficcal/models3d/`` (setup.py maps the repository's directories there: one copy of each file), found here
through importlib.resources. No other import: gst/env.py and the catalogue use it before anything heavy."""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

REPOSITORY = Path(__file__).resolve().parents[1]
"""The checkout this package is imported from, when it is one (else the directory holding the package)."""


def shipped(name: str) -> Path:
    """The directory ``name`` (``elements`` or ``models3d``): the installed package's copy when it has one, else the
    repository's ``<checkout>/<name>`` (which need not exist: the callers say what is missing)."""
    packaged = files("gst_trafficcal") / name
    if isinstance(packaged, Path) and packaged.is_dir():
        return packaged.resolve()
    return REPOSITORY / name
