"""benchmarks/box_edges.py: the detector box's left, top and right edges move to the body's image edges."""

import numpy as np


def _vehicle() -> np.ndarray:
    """A light body (x 40..119, y 30..89) on a grey road, with a soft dark shadow beside and below it."""
    img = np.full((140, 180), 90, np.uint8)
    img[34:100, 32:128] = 60  # soft shadow, darker road around the body
    img[30:90, 40:120] = 200
    return img


def test_edges_move_to_the_body_and_the_bottom_stays(load_benchmark):
    be = load_benchmark("box_edges")
    img = _vehicle()
    # a detector box 5 px wider on the left (into the shadow), 3 px inside on the right, 4 px high at the top
    box = (34.0, 26.0, 116.0, 93.0)
    x0, y0, x1, y1 = be.refine_box(img, box, work_px=4.0)
    assert abs(x0 - 40) <= 1 and abs(x1 - 119) <= 1 and abs(y0 - 30) <= 1
    assert y1 == 93.0  # the bottom is the detector's


def test_an_edge_without_image_support_stays(load_benchmark):
    be = load_benchmark("box_edges")
    flat = np.full((140, 180), 90, np.uint8)
    box = (34.0, 26.0, 116.0, 93.0)
    assert be.refine_box(flat, box, work_px=4.0) == box


def test_a_video_shorter_than_the_dump_is_refused(load_benchmark, tmp_path):
    import pickle

    import cv2
    import pytest

    from gst_trafficcal.errors import InputError

    be = load_benchmark("box_edges")
    video = tmp_path / "video.mp4"
    out = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 25, (180, 140))
    for _ in range(3):
        out.write(cv2.cvtColor(_vehicle(), cv2.COLOR_GRAY2BGR))
    out.release()
    from scale_sightings import Record  # the benchmarks folder is on the path once box_edges is loaded

    from gst_trafficcal.scale.streaming import Sighting

    rec = Record(10, Sighting(1, 0.4, (34.0, 26.0, 116.0, 93.0), None, 1.0), None)
    dump = tmp_path / "scene_vehicleseg.pkl"
    dump.write_bytes(pickle.dumps({"scene": "scene", "records": [vars(rec)]}))
    with pytest.raises(InputError, match="ends at frame 3, before the dump's last sighting"):
        be.refine_dump(dump, video, tmp_path / "out")
    with pytest.raises(InputError, match="no such file"):
        be.refine_dump(dump, tmp_path / "missing.mp4", tmp_path / "out")
