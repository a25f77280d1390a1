"""The trafficcal-calibration sticky event and bus message: builder/parser and a trip through pipelines."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.gst

from gst_trafficcal.calibration import Calibration, save_calibration  # noqa: E402
from gst_trafficcal.geometry import Camera  # noqa: E402
from gst_trafficcal.gst._gi import Gst  # noqa: E402
from gst_trafficcal.gst.calibration_event import (  # noqa: E402
    STRUCTURE_NAME,
    calibration_event,
    calibration_message,
    calibration_structure,
    parse_calibration_event,
    parse_calibration_message,
)
from gst_trafficcal.gst.element import register_plugin_file  # noqa: E402
from gst_trafficcal.gst.env import gst_environment  # noqa: E402
from gst_trafficcal.gst.pipeline import PipelineError, run_pipeline  # noqa: E402

TESTS = Path(__file__).resolve().parent
PLUGINS = TESTS / "gst_plugins"


def _cal(scale: float | None = 6.5, **kw) -> Calibration:
    cam = Camera((260.25, -480.5), (-2840.0, -280.125), (161.0, 121.0), scale)
    return Calibration(cam, (322, 242), source="test", confidence={"vp1": 0.9, "vp2": 0.75}, **kw)


@pytest.mark.parametrize(
    "cal",
    [_cal(), _cal(scale=None), _cal(reason="retrying"), Calibration(None, (640, 480), state="learning"),
     Calibration(None, (640, 480), state="failed", reason="too few tracks"),
     _cal(view={"png": "iVBORw0KGgo=", "frame_width": 322}),
     Calibration(None, (640, 480), state="learning", reason="the camera moved at 7.2 s", moved_at=7.25)],
    ids=["calibrated", "vps", "reason", "learning", "failed", "view", "moved"],
)
def test_event_round_trip(cal: Calibration) -> None:
    event = calibration_event(cal)
    assert event.type == Gst.EventType.CUSTOM_DOWNSTREAM_STICKY and event.has_name(STRUCTURE_NAME)
    back = parse_calibration_event(event)
    assert back is not None and back.id == cal.id and back.state == cal.state
    assert (back.image_size, back.source, back.confidence, back.reason, back.view, back.moved_at) == (
        cal.image_size, cal.source, cal.confidence, cal.reason, cal.view, cal.moved_at)
    if cal.camera is None:
        assert back.camera is None
    else:
        for name in ("vp1", "vp2", "pp"):
            np.testing.assert_array_equal(getattr(back.camera, name), getattr(cal.camera, name))
        assert back.camera.scale == cal.camera.scale and back.camera.focal == cal.camera.focal


def test_structure_is_flat_and_readable() -> None:
    text = calibration_structure(_cal()).to_string()
    for part in ("trafficcal-calibration, ", "vp1_x=(double)260.25", "vp1_y=(double)-480.5", "pp_x=(double)161",
                 "scale=(double)6.5", "state=(string)calibrated", "width=(int)322", "confidence_vp2=(double)0.75",
                 "focal=(double)"):
        assert part in text, part
    assert "scale=" not in calibration_structure(_cal(scale=None)).to_string()


def test_other_events_and_messages_are_not_calibrations() -> None:
    assert parse_calibration_event(Gst.Event.new_eos()) is None
    other = Gst.Event.new_custom(Gst.EventType.CUSTOM_DOWNSTREAM_STICKY, Gst.Structure.new_empty("something-else"))
    assert parse_calibration_event(other) is None
    pipeline = Gst.Pipeline.new("p")
    msg = calibration_message(pipeline, _cal())
    assert msg.type == Gst.MessageType.ELEMENT and parse_calibration_message(msg).id == _cal().id
    assert parse_calibration_message(Gst.Message.new_eos(pipeline)) is None


def test_corrupt_event_gives_a_clear_error() -> None:
    s = calibration_structure(_cal())
    s.set_value("vp2_x", 161.0)  # VP2 on top of the principal point: degenerate camera
    s.set_value("vp2_y", 121.0)
    with pytest.raises(Exception, match="trafficcal-calibration event"):
        parse_calibration_event(Gst.Event.new_custom(Gst.EventType.CUSTOM_DOWNSTREAM_STICKY, s))


def test_event_reaches_appsink_and_downstream_element(tmp_path: Path) -> None:
    """tcmarker publishes the file's calibration: a pad probe at appsink and tccheck both receive it."""
    register_plugin_file(PLUGINS / "python" / "tcmarker.py")
    register_plugin_file(PLUGINS / "python" / "tccheck.py")
    cal = _cal()
    path = save_calibration(cal, tmp_path / "cal.json")
    frames = [np.full((242, 322, 3), 90, np.uint8) for _ in range(3)]
    run = run_pipeline(f"appsrc name=src ! tcmarker calibration-file={path} ! tccheck ! queue ! appsink name=sink",
                       frames, "video/x-raw,format=I420,width=322,height=242,framerate=25/1")
    assert [c.id for c in run.calibrations] == [cal.id]  # sticky, sent once
    assert all(f.calibration is not None and f.calibration.id == cal.id for f in run.frames)
    np.testing.assert_array_equal(run.frames[0].calibration.camera.vp2, cal.camera.vp2)
    assert [m.fields["calibration"] for m in run.messages if m.name == "tccheck"] == [cal.id] * 3
    posted = [m for m in run.messages if m.name == STRUCTURE_NAME]
    assert len(posted) == 1 and posted[0].source.startswith("tcmarker") and posted[0].fields["scale"] == 6.5


def test_missing_calibration_file_is_a_readable_pipeline_error(tmp_path: Path) -> None:
    register_plugin_file(PLUGINS / "python" / "tcmarker.py")
    with pytest.raises(PipelineError, match="nope.json: no such file"):
        run_pipeline(f"appsrc name=src ! tcmarker calibration-file={tmp_path / 'nope.json'} ! appsink name=sink",
                     [np.zeros((24, 32, 3), np.uint8)], "video/x-raw,format=BGR,width=32,height=24,framerate=25/1")


def test_gst_launch_prints_the_calibration_message(tmp_path: Path) -> None:
    """gst-launch-1.0 -m with our test elements loaded by the Python plugin loader from GST_PLUGIN_PATH."""
    cal = _cal()
    path = save_calibration(cal, tmp_path / "cal.json")
    env = dict(os.environ, **gst_environment(plugin_dirs=[PLUGINS]), GST_REGISTRY=str(tmp_path / "registry.bin"))
    cmd = ["gst-launch-1.0", "-m", "videotestsrc", "num-buffers=3", "!", "video/x-raw,width=322,height=242", "!",
           "tcmarker", f"calibration-file={path}", "!", "tccheck", "!", "fakesink"]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr + out.stdout
    assert f"trafficcal-calibration, id=(string){cal.id}, state=(string)calibrated" in out.stdout
    assert out.stdout.count(f"tccheck, rois=(int)") == 3
    assert out.stdout.count(f"calibration=(string){cal.id}") == 3


def test_calibration_published_at_eos_still_reaches_downstream(tmp_path: Path) -> None:
    """An element that only converges at end of stream (on_eos) still delivers its calibration."""
    register_plugin_file(PLUGINS / "python" / "tcmarker.py")
    register_plugin_file(PLUGINS / "python" / "tccheck.py")
    cal = _cal()
    path = save_calibration(cal, tmp_path / "cal.json")
    frames = [np.full((242, 322, 3), 90, np.uint8) for _ in range(2)]
    run = run_pipeline(f"appsrc name=src ! tcmarker calibration-file={path} calibration-at-eos=true ! tccheck ! "
                       "appsink name=sink", frames, "video/x-raw,format=NV12,width=322,height=242,framerate=25/1")
    assert [f.calibration for f in run.frames] == [None, None]  # not there while frames flowed
    assert [c.id for c in run.calibrations] == [cal.id]  # arrived before EOS
    assert [m.fields["calibration"] for m in run.messages if m.name == "tccheck"] == ["", ""]
    assert [m.fields["id"] for m in run.messages if m.name == STRUCTURE_NAME] == [cal.id]
