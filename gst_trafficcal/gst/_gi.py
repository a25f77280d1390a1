"""Single place that pins the GI versions and initialises GStreamer for ``gst_trafficcal.gst``."""

from __future__ import annotations

import ctypes

# libgstreamer links libunwind, whose _Unwind_* symbols then take precedence (in this process's global symbol
# scope) over libgcc_s's for extension modules loaded later, e.g. when cv2 was imported before gi. Any C++
# exception thrown there (onnxruntime errors on a corrupt model, matplotlib's ft2font) then kills the process
# (SIGSEGV/SIGABRT) instead of becoming a Python exception. Making libgcc_s global first keeps the right unwinder.
try:
    ctypes.CDLL("libgcc_s.so.1", mode=ctypes.RTLD_GLOBAL)
except OSError:  # not glibc/libgcc (nothing to fix there)
    pass

import sys  # noqa: E402

# OpenCV's loader (cv2/__init__.py) rebinds ``sys.path`` to a copy of the list. gst-python's plugin loader holds
# the original list and inserts each GST_PLUGIN_PATH/python directory into it before importing that directory's
# elements, so once any element had imported cv2, the elements of later plugin directories failed with
# "No module named ...". Import cv2 once here (every element imports this module first) and keep the list object.
_sys_path = sys.path
import cv2  # noqa: E402,F401

if sys.path is not _sys_path:
    _sys_path[:] = sys.path
    sys.path = _sys_path
del _sys_path

import gi  # noqa: E402

gi.require_version("Gst", "1.0")
gi.require_version("GstBase", "1.0")
gi.require_version("GstVideo", "1.0")
from gi.repository import GLib, GObject, Gst, GstBase, GstVideo  # noqa: E402

if not Gst.is_initialized():
    Gst.init(None)

# PyGObject before 3.50 creates Python-defined elements already ref-sunk, so every in-process
# Gst.parse_launch/ElementFactory.make of one of our elements logs "GStreamer-CRITICAL: The created element
# should be floating, this is probably caused by faulty bindings" (pygobject merge request 129; harmless: the
# pipeline then holds the only reference). Drop exactly that message; every other critical is still printed.
_FLOATING_BUG = "The created element should be floating"


def _gst_log_filter(domain: str, level: GLib.LogLevelFlags, message: str, *user_data: object) -> None:
    if not message.startswith(_FLOATING_BUG):
        GLib.log_default_handler(domain, level, message, None)


GLib.log_set_handler("GStreamer", GLib.LogLevelFlags.LEVEL_CRITICAL, _gst_log_filter, None)

__all__ = ["GLib", "GObject", "Gst", "GstBase", "GstVideo"]
