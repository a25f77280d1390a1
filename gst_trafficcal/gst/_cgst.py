"""The few libgstreamer/libgstvideo calls PyGObject cannot make, through ctypes.

PyGObject 3.42 cannot iterate a buffer's metas (``gst_buffer_iterate_meta*`` take a gpointer
state, ``foreach_meta`` passes the wrong arguments to its callback) nor remove a parameter
structure from a ``GstVideoRegionOfInterestMeta``. Intel DL Streamer's ``gstgva`` solves the
same problem the same way. ``hash()`` of a PyGObject boxed/mini-object wrapper is its C pointer.
"""

from __future__ import annotations

import ctypes
from collections.abc import Container, Iterator
from contextlib import contextmanager

from ._gi import Gst, GstVideo

_gst = ctypes.CDLL("libgstreamer-1.0.so.0")
_gstvideo = ctypes.CDLL("libgstvideo-1.0.so.0")
_glib = ctypes.CDLL("libglib-2.0.so.0")


class _GList(ctypes.Structure):
    pass


_GList._fields_ = [
    ("data", ctypes.c_void_p),
    ("next", ctypes.POINTER(_GList)),
    ("prev", ctypes.POINTER(_GList)),
]


class RoiMetaStruct(ctypes.Structure):
    """C layout of GstVideoRegionOfInterestMeta (GstMeta header + fields)."""

    _fields_ = [
        ("meta_flags", ctypes.c_uint),
        ("meta_info", ctypes.c_void_p),
        ("roi_type", ctypes.c_uint32),  # GQuark
        ("id", ctypes.c_int),
        ("parent_id", ctypes.c_int),
        ("x", ctypes.c_uint),
        ("y", ctypes.c_uint),
        ("w", ctypes.c_uint),
        ("h", ctypes.c_uint),
        ("params", ctypes.POINTER(_GList)),
    ]


_gst.gst_buffer_iterate_meta_filtered.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_void_p), ctypes.c_size_t]
_gst.gst_buffer_iterate_meta_filtered.restype = ctypes.c_void_p
_gst.gst_mini_object_is_writable.argtypes = [ctypes.c_void_p]
_gst.gst_mini_object_is_writable.restype = ctypes.c_int
_gst.gst_structure_to_string.argtypes = [ctypes.c_void_p]
_gst.gst_structure_to_string.restype = ctypes.c_void_p
_gst.gst_structure_get_name.argtypes = [ctypes.c_void_p]
_gst.gst_structure_get_name.restype = ctypes.c_char_p
_gst.gst_structure_copy.argtypes = [ctypes.c_void_p]
_gst.gst_structure_copy.restype = ctypes.c_void_p
_gst.gst_structure_free.argtypes = [ctypes.c_void_p]
_gst.gst_structure_free.restype = None
_glib.g_free.argtypes = [ctypes.c_void_p]
_glib.g_free.restype = None
_glib.g_quark_to_string.argtypes = [ctypes.c_uint32]
_glib.g_quark_to_string.restype = ctypes.c_char_p
_glib.g_list_delete_link.argtypes = [ctypes.POINTER(_GList), ctypes.POINTER(_GList)]
_glib.g_list_delete_link.restype = ctypes.POINTER(_GList)
_gstvideo.gst_video_region_of_interest_meta_add_param.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
_gstvideo.gst_video_region_of_interest_meta_add_param.restype = None

# GType value of the ROI meta API (hash() of a GObject.GType is its numeric value).
_ROI_API = hash(GstVideo.VideoRegionOfInterestMeta.get_info().api)


def is_writable(buffer: Gst.Buffer) -> bool:
    """``gst_buffer_is_writable`` (a C macro, absent from the Python bindings)."""
    return bool(_gst.gst_mini_object_is_writable(hash(buffer)))


def iter_roi_metas(buffer: Gst.Buffer) -> Iterator[tuple[int, RoiMetaStruct]]:
    """(address, struct view) of every GstVideoRegionOfInterestMeta on ``buffer``, in order."""
    state = ctypes.c_void_p()
    while True:
        addr = _gst.gst_buffer_iterate_meta_filtered(hash(buffer), ctypes.byref(state), _ROI_API)
        if not addr:
            return
        yield addr, RoiMetaStruct.from_address(addr)


def quark_string(quark: int) -> str:
    raw = _glib.g_quark_to_string(quark)
    return raw.decode() if raw else ""


def roi_param_structures(meta: RoiMetaStruct, names: Container[str] | None = None) -> list[Gst.Structure]:
    """Python copies of the parameter structures of a ROI meta, in list order; with ``names``, only those called
    one of them (the others are not copied: a reader that needs two of five saves most of the work)."""
    out: list[Gst.Structure] = []
    node = meta.params
    while node:
        if names is not None and (_gst.gst_structure_get_name(node.contents.data) or b"").decode() not in names:
            node = node.contents.next
            continue
        text_ptr = _gst.gst_structure_to_string(node.contents.data)
        try:
            text = ctypes.string_at(text_ptr).decode()
        finally:
            _glib.g_free(text_ptr)
        parsed = Gst.Structure.from_string(text)
        structure = parsed[0] if isinstance(parsed, tuple) else parsed
        if structure is None:
            raise RuntimeError(f"cannot re-parse ROI parameter structure {text!r}")
        out.append(structure)
        node = node.contents.next
    return out


def roi_remove_params(meta: RoiMetaStruct, name: str) -> int:
    """Remove (and free) every parameter structure called ``name``; returns how many."""
    removed = 0
    node = meta.params
    while node:
        nxt = node.contents.next
        data = node.contents.data
        if _gst.gst_structure_get_name(data).decode() == name:
            meta.params = _glib.g_list_delete_link(meta.params, node)
            _gst.gst_structure_free(data)
            removed += 1
        node = nxt
    return removed


def roi_add_param(meta_addr: int, structure: Gst.Structure) -> None:
    """Append a copy of ``structure`` to the ROI meta at ``meta_addr`` (the meta owns the copy)."""
    _gstvideo.gst_video_region_of_interest_meta_add_param(meta_addr, _gst.gst_structure_copy(hash(structure)))


class _GstMapInfo(ctypes.Structure):
    _fields_ = [
        ("memory", ctypes.c_void_p),
        ("flags", ctypes.c_int),
        ("data", ctypes.c_void_p),
        ("size", ctypes.c_size_t),
        ("maxsize", ctypes.c_size_t),
        ("user_data", ctypes.c_void_p * 4),
        ("_gst_reserved", ctypes.c_void_p * 4),
    ]


_gst.gst_buffer_map.argtypes = [ctypes.c_void_p, ctypes.POINTER(_GstMapInfo), ctypes.c_int]
_gst.gst_buffer_map.restype = ctypes.c_int
_gst.gst_buffer_unmap.argtypes = [ctypes.c_void_p, ctypes.POINTER(_GstMapInfo)]
_gst.gst_buffer_unmap.restype = None


@contextmanager
def map_buffer(buffer: Gst.Buffer, writable: bool) -> Iterator[memoryview]:
    """``gst_buffer_map`` through ctypes, yielding a (writable) memoryview of the mapped bytes.

    Fallback for gst-python versions whose ``Buffer.map(WRITE)`` hands out read-only data
    (1.22's gives a writable memoryview, which :mod:`.buffers` uses first).
    """
    info = _GstMapInfo()
    flags = int(Gst.MapFlags.READ) | (int(Gst.MapFlags.WRITE) if writable else 0)
    if not _gst.gst_buffer_map(hash(buffer), ctypes.byref(info), flags):
        raise RuntimeError("cannot map buffer" + (" for writing (is it writable?)" if writable else ""))
    try:
        raw = (ctypes.c_ubyte * info.size).from_address(info.data) if info.size else bytearray()
        view = memoryview(raw).cast("B")
        yield view if writable else view.toreadonly()
    finally:
        _gst.gst_buffer_unmap(hash(buffer), ctypes.byref(info))
