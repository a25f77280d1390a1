"""The detection zone (gst_trafficcal.zone): parsing, masks, which vehicles stand in it, errors."""

from __future__ import annotations

import re

import numpy as np
import pytest

from gst_trafficcal.errors import InputError
from gst_trafficcal.zone import parse_zone


def test_a_zone_in_pixels_and_in_fractions() -> None:
    px = parse_zone(" 10,20 110,20 110,70 10,70 ")
    assert not px.relative and str(px) == "10,20 110,20 110,70 10,70"
    assert str(parse_zone("10, 20  110 ,20 110 , 70 10,70")) == str(px)  # spaces around the commas are no matter
    assert str(parse_zone("10,20 110,20 110,20 110,70 10,70 10,20")) == str(px)  # a ring closed, a point twice
    m = px.mask((160, 90))
    assert m.shape == (90, 160) and m.dtype == np.uint8 and set(np.unique(m)) == {0, 255}
    # pixels 10..109 x 20..69, and those the outline passes through (one more row and column at most)
    assert 100 * 50 <= (m > 0).sum() <= 101 * 51 and m[20, 10] and m[69, 109] and not m[71:].any()
    rel = parse_zone("0,0.5 1,0.5 1,1 0,1")  # the bottom half, at any resolution
    assert rel.relative
    for size in ((64, 36), (1920, 1080)):
        inside = rel.mask(size) > 0
        assert inside[size[1] // 2 + 1:].all() and not inside[:size[1] // 2].any()
    assert np.allclose(rel.pixels((1920, 1080))[0], [[0, 540], [1920, 540], [1920, 1080], [0, 1080]])
    assert parse_zone("") is None and parse_zone("   ") is None


def test_which_points_and_vehicles_lie_inside() -> None:
    from gst_trafficcal.detection.records import Detections

    zone = parse_zone("0,0 100,0 100,100 0,100; 200,0 300,0 250,100")  # a square and a triangle
    pts = np.array([[50, 50], [150, 50], [250, 20], [210, 90], [-5, 50], [50, 500], [np.nan, 3]])
    assert zone.contains(pts, (320, 240)).tolist() == [True, False, True, False, False, False, False]
    # a vehicle stands where its box's bottom centre is: one reaching out of the square but standing in it, one
    # whose roof is in it but not its wheels
    found = Detections(np.array([[60, 20, 140, 90], [20, 60, 80, 130], [210, 10, 290, 40]], np.float32),
                       np.array([0.9, 0.8, 0.7]), np.array([2, 2, 7]))
    kept = zone.keep(found, (320, 240))
    assert kept.boxes.tolist() == [[60, 20, 140, 90], [210, 10, 290, 40]] and kept.class_ids.tolist() == [2, 7]
    assert len(zone.keep(Detections.empty(), (320, 240))) == 0


def test_vehicles_on_the_frames_bottom_edge_stand_in_a_zone_reaching_it() -> None:
    """Boxes end at the frame's edge (y1 = height): the nearest vehicles, entering or leaving at the bottom, are
    in a zone that reaches the bottom — the whole frame in fractions, or in pixels — and not in one that stops
    short of it."""
    size = (640, 360)
    bottoms = np.array([[320, 360], [320, 359.6], [320, 359.4], [320, 300], [640, 200], [320, 360.5]])
    for text in ("0,0 1,0 1,1 0,1", "0,0 640,0 640,360 0,360"):
        assert parse_zone(text).contains(bottoms, size).tolist() == [True] * 5 + [False], text
    assert parse_zone("0,0 640,0 640,350 0,350").contains(bottoms, size).tolist() == [False] * 3 + [True, True,
                                                                                                    False]


def test_a_zone_that_does_not_fit_the_frame() -> None:
    zone = parse_zone("100,100 700,100 700,500 100,500")
    assert zone.check((1920, 1080)) is None and zone.doubt((1920, 1080)) is None
    assert zone.check((640, 360)) is None  # part of it covers the frame
    assert zone.doubt((640, 360)) == ("zone 100,100 700,100 700,500 100,500 reaches to 700,500, beyond the 640x360 "
                                      "frame: written for another resolution? Fractions 0..1 of the width and "
                                      "height fit any")
    assert parse_zone("900,500 1000,500 1000,600").check((640, 360)) == \
        "zone 900,500 1000,500 1000,600: it covers no pixel of the 640x360 frame"
    assert parse_zone("10,10 30,10 30,20").doubt((640, 360)) == (  # a triangle of 100 px and its outline: 122 px
        "zone 10,10 30,10 30,20 covers only 0.053 % of the 640x360 frame: written for another resolution? "
        "Fractions 0..1 of the width and height fit any")
    assert parse_zone("0,0 1,0 1,0.001").doubt((640, 360)) is None  # fractions fit any frame


@pytest.mark.parametrize("text,message", [
    ("1,2 3,4", "polygon 1 has 2 points; a zone needs at least 3"),
    ("0,0 10,0 10,10; 5,5 6,6", "polygon 2 has 2 points"),
    ("a,b c,d e,f", "polygon 1 is not a list of x,y numbers; expected 'x,y x,y x,y ...'"),
    ("1,2,3 4,5,6 7,8,9", "polygon 1 has a point without exactly two coordinates"),
    ("0,0 10,0 10", "polygon 1 has a point without exactly two coordinates"),
    ("0,0 10,0 10,10; ; 5,5 6,6 x,7", "polygon 3 is not a list of x,y numbers"),
    ("0.3,0.2 0.6,0.2 1.0,1 0.1,10", "mixes fractions of the frame (between 0 and 1) with pixels (above 1)"),
    ("0,0 inf,0 5,5", "polygon 1 has a coordinate that is not a finite number"),
    ("0,0 10,10 20,20", "polygon 1 encloses no area"),
    ("0,0 100,100 100,0 0,100", "polygon 1 crosses itself: give its corners in order around it"),
    ("0,0 10,0 10,10; 20,20 40,20 40,40 30,10 20,40", "polygon 2 crosses itself"),
    ("-1,0 5,0 5,5", "negative coordinates"),
    (";;", "no polygon"),
])
def test_a_zone_that_is_not_one_names_what_is_wrong(text: str, message: str) -> None:
    with pytest.raises(InputError, match=re.escape(f"zone '{text}': {message}")):
        parse_zone(text)
