"""Pipeline pieces that ``trafficcal run``, the snapshot of a file's first frame and the pipelines/ scripts share
(no ``gi`` import: strings only).  The scripts take them from here (``python -m gst_trafficcal.gst.chains``, via
pipelines/lib.sh), so each is written once.

The elements take the decoded video upright and of square pixels: ``videoflip`` applies the rotation a phone or a
body camera writes into its file (the MP4's display matrix: GStreamer passes it on as a tag and leaves the frames
as stored, where OpenCV — trafficcal calibrate, the report's picture — turns them upright), and ``videoscale`` to
square pixels makes a DVR's 704x576 D1 or a 480x360 stored for a 640x360 picture measurable (speeds were 35 % off
in silence).  Both pass a video that is upright and of square pixels through untouched.

A file's rotation or mirroring is read before the pipeline starts and given to videoflip: with
``video-direction=auto`` the elements are first told the stored size (caps come before the tag) and only then the
turned one, and a calibration file of the upright picture was refused at the first (GStreamer 1.22 does not tag an
``ur-ll`` mirroring at all).  A stream's is not known up front: ``auto`` there, and the
elements check a calibration's (and a zone's) size at the first frame, by when the tag has turned the caps
(``TrafficcalTransform.refuse_size``).
"""

from __future__ import annotations

import sys

SQUARE_I420 = "video/x-raw,format=I420,pixel-aspect-ratio=1/1"
# an encoder's input: I420 of an even size, which x264 needs (an odd-sized video is scaled by a pixel, 1281x721 to
# 1282x722; videoscale passes an even one through untouched)
EVEN_I420 = "video/x-raw,format=I420,width=[2,32768,2],height=[2,32768,2]"


def upright(direction: str | None) -> str:
    """The videoflip that shows frames as their file's display matrix says (``direction``: a video-direction, as
    :func:`gst_trafficcal.imaging.video_direction` reads it; None: not known before the stream plays)."""
    return f"videoflip video-direction={direction or 'auto'}"


def analysed_video(direction: str | None) -> list[str]:
    """The elements between the decoder's ``videoconvert`` and the analysis: the video turned upright (``direction``
    as :func:`upright` takes it) and scaled to square pixels, in I420."""
    return [upright(direction), "videoscale", SQUARE_I420]


def main(argv: list[str]) -> int:
    """``analysed VIDEO [ORIENTATION]``: :func:`analysed_video`'s elements for ``VIDEO`` (a file or a URI, its
    rotation read as trafficcal run reads it, or turned by ``ORIENTATION`` as its ``--orientation``) joined by
    ``!``, one word per line (for bash's mapfile); a bad ORIENTATION: the error on one line and exit code 3;
    ``kept-orientation CALIBRATION``: the orientation the calibration file keeps (its field ``orientation``, as
    ``trafficcal run --calibration`` takes it), nothing when it keeps none, a bad one: one line and exit code 3;
    ``even-i420``: :data:`EVEN_I420`."""
    if len(argv) in (2, 3) and argv[0] == "analysed":
        from ..cli.run import direction_of
        from ..errors import InputError
        from ..imaging import check_orientation

        try:
            orientation = check_orientation(argv[2] if len(argv) == 3 else None, "ORIENTATION")
        except InputError as exc:
            print(exc)
            return 3
        words = " ! ".join(analysed_video(direction_of(argv[1], orientation))).split(" ")
    elif len(argv) == 2 and argv[0] == "kept-orientation":
        from ..errors import InputError
        from ..imaging import orientation_of_file

        try:
            kept = orientation_of_file(argv[1])
        except InputError as exc:
            print(exc)
            return 3
        words = [] if kept is None else [kept]
    elif argv == ["even-i420"]:
        words = [EVEN_I420]
    else:
        print("usage: python -m gst_trafficcal.gst.chains analysed VIDEO|URI [ORIENTATION] | kept-orientation "
              "CALIBRATION | even-i420", file=sys.stderr)
        return 2
    print("\n".join(words))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
