"""One frame of a video file through GStreamer, for pictures (the report's calibration grid, calibrate-manual's).

OpenCV's FFmpeg reads most files, but refuses some that GStreamer plays: a recording cut off after its index (an
MP4 written with its header first, then truncated), which qtdemux plays up to where its data ends — the run
measured it, so its report should show it too.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ._gi import Gst
from .chains import analysed_video
from .buffers import frame_bgr, video_info_from_caps


def first_frame_bgr(path: str | Path, timeout_s: float = 10.0, orientation: str = "auto") -> np.ndarray | None:
    """The first decodable frame of a local video file as an HxWx3 BGR copy, upright and of square pixels as the
    elements see it (turned by ``orientation`` when it is not auto: imaging.check_orientation), or None (not a
    video, no frame within ``timeout_s``)."""
    # upright (by the file's display matrix when its header can be read, else by the tag GStreamer reads: OpenCV
    # could not open it) and of square pixels
    from ..imaging import mp4_direction

    pipeline = Gst.parse_launch(" ! ".join(["filesrc name=src", "decodebin", "videoconvert",
                                            *analysed_video(orientation if orientation != "auto" else
                                                            mp4_direction(path)),
                                            "videoconvert", "video/x-raw,format=BGR",
                                            "appsink name=sink max-buffers=1 sync=false"]))
    pipeline.get_by_name("src").set_property("location", str(path))
    try:
        pipeline.set_state(Gst.State.PAUSED)
        done, _, _ = pipeline.get_state(int(timeout_s * Gst.SECOND))  # prerolled, or FAILURE on a decoding error
        if done != Gst.StateChangeReturn.SUCCESS:
            return None
        sample = pipeline.get_by_name("sink").emit("try-pull-preroll", 0)
        if sample is None:
            return None
        with frame_bgr(sample.get_buffer(), video_info_from_caps(sample.get_caps())) as bgr:
            return np.array(bgr, copy=True)
    finally:
        pipeline.set_state(Gst.State.NULL)
