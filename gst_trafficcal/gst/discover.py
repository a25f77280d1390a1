"""What a media file holds, from GStreamer's discoverer: for telling a truncated video from one whose other
streams (audio) simply run on past its end, since a file's header states the longest stream's duration."""

from __future__ import annotations

from pathlib import Path

import gi

from ._gi import Gst

gi.require_version("GstPbutils", "1.0")
from gi.repository import GLib, GstPbutils  # noqa: E402


def has_audio(path: str | Path, timeout_s: float = 5.0) -> bool | None:
    """Whether the file holds an audio stream; None when the discoverer cannot tell (not a media file, no answer
    within ``timeout_s``)."""
    try:
        info = GstPbutils.Discoverer.new(int(timeout_s * Gst.SECOND)).discover_uri(Path(path).resolve().as_uri())
    except GLib.Error:
        return None
    if info.get_result() != GstPbutils.DiscovererResult.OK:
        return None
    return bool(info.get_audio_streams())
