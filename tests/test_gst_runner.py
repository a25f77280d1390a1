"""``gst_trafficcal.gst.runner``: a whole pipeline in-process, with progress, bus messages and clear errors."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.gst

from gst_trafficcal.gst.runner import PipelineError, RunFailed, missing_elements, run_pipeline_file  # noqa: E402


def test_progress_follows_the_stream_position_to_the_end():
    seen = []
    out = run_pipeline_file("videotestsrc num-buffers=50 ! video/x-raw,width=64,height=48,framerate=25/1 ! "
                            "identity sleep-time=4000 ! fakesink sync=false",
                            progress=lambda pos, dur: seen.append((pos, dur)), poll_s=0.05)
    positions = [p for p, _ in seen]
    assert len(seen) >= 3 and positions == sorted(positions)
    assert positions[-1] == pytest.approx(2.0, abs=0.05)  # 50 frames at 25 fps
    assert out.position_s is not None and out.calibration is None


def test_a_sink_that_cannot_write_names_its_file_and_why(tmp_path):
    """A full disk under the overlay video: the error names the file and the cause (it said "filesink0: Could not
    write to resource." for a file too large, without the file)."""
    import os

    if not os.path.exists("/dev/full"):
        pytest.skip("needs /dev/full")
    with pytest.raises(RunFailed) as failed:
        run_pipeline_file("videotestsrc num-buffers=50 ! video/x-raw,width=64,height=48 ! "
                          "filesink name=out location=/dev/full")
    assert str(failed.value) == "out: /dev/full: cannot write (No space left on the resource)"


def test_our_elements_are_registered_in_process():
    assert missing_elements(["vpdetect", "vehicledetect", "tracker", "speedometer", "trafficoverlay"]) == []
    assert missing_elements(["no-such-element-here"]) == ["no-such-element-here"]


def test_calibration_messages_are_collected():
    from gst_trafficcal.calibration import Calibration

    out = run_pipeline_file("videotestsrc num-buffers=5 ! video/x-raw,format=I420,width=160,height=120 ! "
                            "vpdetect min-duration=1 ! fakesink")
    states = [c.state for _, c in out.calibrations]
    assert states[0] == "learning" and states[-1] == "failed"  # a test pattern has no traffic
    assert isinstance(out.calibration, Calibration) and out.calibration.reason
    assert out.warnings and "calibration failed" in out.warnings[-1]


def test_a_long_run_keeps_only_the_latest_messages_and_the_callback_sees_every_one():
    """A run of weeks posts several messages per vehicle: the outcome kept every one (about 3 kB a vehicle, without
    end, in ``trafficcal run``'s process); now the latest MESSAGES_KEPT, while ``on_message`` gets them all."""
    from pathlib import Path

    from gst_trafficcal.gst.element import register_plugin_file
    from gst_trafficcal.gst.runner import MESSAGES_KEPT

    register_plugin_file(Path(__file__).resolve().parent / "gst_plugins" / "python" / "tccheck.py")
    frames = MESSAGES_KEPT + 500
    seen = []
    out = run_pipeline_file(f"videotestsrc num-buffers={frames} ! video/x-raw,format=I420,width=16,height=16 ! "
                            "tccheck ! fakesink", on_message=seen.append)
    assert len([m for m in seen if m.name == "tccheck"]) == frames
    assert len(out.messages) == MESSAGES_KEPT and out.messages[-1] is seen[-1]
    assert len(out.named("tccheck")) == MESSAGES_KEPT


def test_warnings_like_one_before_are_said_once_with_a_count_every_kind_kept():
    """A PTZ camera on patrol warns at every move: the run kept each warning, and printed one line per move at the
    end (hundreds a day).  Now a warning like one before (the same words, other numbers and ids) is counted into the
    first one's line, which says how many more there were and the last; every other kind keeps its own line."""
    from gst_trafficcal.gst.runner import RunOutcome

    out = RunOutcome()
    out.warn("vpdetect0: the video's pixels are not square")
    for k in range(500):
        out.warn(f"vpdetect0: the camera moved at {60.0 * k + 12.5:.1f} s (shifted by ({k % 7:+.0f}, -3) px, zoom "
                 f"+{k % 3}.0 %): learning a new calibration")
        out.warn(f"vpdetect0: the camera moved at {60.0 * k + 40.0:.1f} s to a view it was calibrated on before: "
                 f"using calibration {'c0ffee' if k % 2 else 'b4dcafe1'} again")
    out.warn("bbscale0: no scale: too few vehicles")
    out.warn("vpdetect0: the video's pixels are not square")  # exactly the same: counted too
    assert out.warnings == [
        "vpdetect0: the video's pixels are not square (and 1 more like it, the last: vpdetect0: the video's pixels "
        "are not square)",
        "vpdetect0: the camera moved at 12.5 s (shifted by (+0, -3) px, zoom +0.0 %): learning a new calibration "
        "(and 499 more like it, the last: vpdetect0: the camera moved at 29952.5 s (shifted by (+2, -3) px, zoom "
        "+1.0 %): learning a new calibration)",
        "vpdetect0: the camera moved at 40.0 s to a view it was calibrated on before: using calibration b4dcafe1 "
        "again (and 499 more like it, the last: vpdetect0: the camera moved at 29980.0 s to a view it was "
        "calibrated on before: using calibration c0ffee again)",
        "bbscale0: no scale: too few vehicles"]


def test_warnings_of_two_elements_are_not_counted_as_one_kind():
    """Grouping by words merged vpdetect1's warnings into vpdetect0's line (the digits of the name were taken for a
    number): two cameras' elements in one pipeline now keep a line each; a number inside the text still groups."""
    from gst_trafficcal.gst.runner import RunOutcome

    out = RunOutcome()
    for k in range(3):
        out.warn(f"vpdetect0: the camera moved at {10.0 * k:.1f} s: learning a new calibration")
        out.warn(f"vpdetect1: the camera moved at {10.0 * k + 5:.1f} s: learning a new calibration")
    out.warn("pipeline: 2 frames late")
    out.warn("the clock jumped by 3 s")
    out.warn("the clock jumped by 4 s")
    assert out.warnings == [
        "vpdetect0: the camera moved at 0.0 s: learning a new calibration (and 2 more like it, the last: vpdetect0: "
        "the camera moved at 20.0 s: learning a new calibration)",
        "vpdetect1: the camera moved at 5.0 s: learning a new calibration (and 2 more like it, the last: vpdetect1: "
        "the camera moved at 25.0 s: learning a new calibration)",
        "pipeline: 2 frames late",
        "the clock jumped by 3 s (and 1 more like it, the last: the clock jumped by 4 s)"]


def test_after_a_camera_move_the_run_ends_with_the_new_views_calibration():
    """The calibration a run ended with is the new view's (here: still learning), never the old view's scale that
    an element further down posted a moment after the move; each move says what measured the vehicles before."""
    from dataclasses import replace

    from gst_trafficcal.calibration import Calibration
    from gst_trafficcal.geometry import Camera
    from gst_trafficcal.gst.runner import RunOutcome

    vps = Calibration(Camera((300.0, -60.0), (7000.0, 340.0), (320.0, 180.0)), (640, 360), state="vps")
    old = vps.with_scale(9.0)
    moved = Calibration(None, (640, 360), state="learning", reason="the camera moved at 35.0 s", moved_at=35.0)
    out = RunOutcome(calibrations=[("vpdetect0", vps), ("bbscale0", old), ("vpdetect0", moved),
                                   ("bbscale0", old.with_scale(9.1))])
    assert out.calibration is moved and out.moves == [(35.0, old, None)]
    new = Calibration(Camera((310.0, -50.0), (6000.0, 330.0), (320.0, 180.0)), (640, 360), state="vps")
    out.calibrations += [("vpdetect0", new), ("bbscale0", new.with_scale(8.0))]
    assert out.calibration.id == new.with_scale(8.0).id
    assert RunOutcome(calibrations=[("vpdetect0", vps), ("bbscale0", old)]).moves == []
    # back at the first view (a PTZ preset): vpdetect announces its calibration again with the move, bbscale puts
    # the scale it found for it back on: the run ends with that, although the old view had the same one
    back = replace(vps, moved_at=60.0)
    out.calibrations += [("vpdetect0", back), ("bbscale0", replace(old, moved_at=60.0))]
    assert out.calibration.id == old.id and out.calibration.moved_at == 60.0
    t, before, known = out.moves[-1]
    assert (t, before.id, known.id, known.moved_at) == (60.0, new.with_scale(8.0).id, old.id, 60.0)


def _ptz_patrol(moves: int):
    """The calibrations a run posts while a PTZ camera patrols four presets, each move a few of them with a view
    picture of 12 kB: the first visit of a preset learnt (learning with the move, the vanishing points, bbscale's
    scale, a republished one), each return taken up again (vpdetect's known calibration with the move, bbscale's
    scale put back on)."""
    from dataclasses import replace

    from gst_trafficcal.calibration import Calibration
    from gst_trafficcal.geometry import Camera

    def picture(k: int) -> dict:
        return {"png": f"{k:08d}" + "v" * 12000, "frame_width": 640}

    posted, scaled, k = [], {}, 0
    for m in range(moves):
        t, p = 30.0 * m + 10.0, m % 4
        vps = Calibration(Camera((300.0 - 40 * p, -60.0), (7000.0 - 500 * p, 340.0), (320.0, 180.0)), (640, 360),
                          state="vps", view=picture(k))
        k += 1
        if m == 0:
            posted.append(("vpdetect0", vps))
        elif p not in scaled:
            posted += [("vpdetect0", Calibration(None, (640, 360), state="learning", moved_at=t)), ("vpdetect0", vps)]
        else:
            posted += [("vpdetect0", replace(scaled[p].with_scale(None), moved_at=t, view=picture(k))),
                       ("bbscale0", replace(scaled[p], moved_at=t, view=picture(k + 1)))]
            k += 2
            continue
        scaled[p] = vps.with_scale(8.0 + p, view=picture(k))
        posted += [("bbscale0", scaled[p]), ("bbscale0", vps.with_scale(8.1 + p, view=picture(k + 1)))]
        scaled[p] = posted[-1][1]
        k += 2
    return posted


def test_a_run_of_many_posted_calibrations_keeps_the_views_and_moves_not_every_picture():
    """A PTZ camera on patrol without --split-every: the run kept every calibration posted, 12 kB each with its view
    picture — 9 MB a day.  Posted through add, those before the last move are folded: the calibration the run ends
    with, the moves and each view's last scaled calibration (its picture, saved for the next part) are those of
    every calibration posted, while the pictures held stay as many as the views, however long the patrol."""
    from gst_trafficcal.gst.runner import RunOutcome

    def said(out):
        def key(c):
            return None if c is None else (c.id, c.state, c.moved_at)
        final = out.calibration
        return (key(final), final.view, [(m.t, key(m.before), key(m.known)) for m in out.moves],
                out.moves_earlier, [(key(c), c.view) for c in out.scaled_views])

    def pictures(out) -> int:
        cals = [c for _, c in out.calibrations] + out.scaled_views
        cals += [c for m in out.moves for c in (m.before, m.known) if c is not None]
        return len({c.view["png"] for c in cals if c.view is not None})

    posted = _ptz_patrol(400)
    assert len(posted) > 800
    out = RunOutcome()
    for n, (element, cal) in enumerate(posted, 1):
        out.add(element, cal)
        if n % 97 == 0 or n == len(posted):
            assert said(out) == said(RunOutcome(calibrations=posted[:n])), n  # the same as with every one kept
            assert len(out.calibrations) <= 4 and pictures(out) <= 4 + 4, n
    assert len(out.moves) + out.moves_earlier[0] == 399 and len(out.scaled_views) == 4
    assert pictures(RunOutcome(calibrations=posted)) > 800  # what was kept before


def test_a_patrol_keeps_the_latest_moves_in_full_and_counts_the_others():
    """The list of camera moves grew by 1-2 kB a move (the calibrations around each) and the run printed a line per
    move: a PTZ patrol of a day, hundreds.  Now the latest MOVES_KEPT are kept in full, the earlier ones counted
    (how many, the first's and the last's time), however long the patrol; what is kept is what every calibration
    posted says."""
    import pickle

    from gst_trafficcal.gst.runner import MOVES_KEPT, RunOutcome

    posted = _ptz_patrol(400)
    out = RunOutcome()
    sizes = []
    for n, (element, cal) in enumerate(posted, 1):
        out.add(element, cal)
        if n in (len(posted) // 2, len(posted)):
            sizes.append(len(pickle.dumps(out._folded.moves)))
    whole = RunOutcome(calibrations=posted)
    def said(moves):
        return [(m.t, *[None if c is None else (c.id, c.state, c.moved_at) for c in (m.before, m.known)])
                for m in moves]

    assert len(out.moves) == MOVES_KEPT and said(out.moves) == said(whole.moves)
    assert out.moves_earlier == whole.moves_earlier == (399 - MOVES_KEPT, 40.0, 30.0 * (399 - MOVES_KEPT) + 10.0)
    assert out.moves[0].t == 30.0 * (400 - MOVES_KEPT) + 10.0 and out.moves[-1].t == 30.0 * 399 + 10.0
    assert sizes[1] <= sizes[0] * 1.1  # bounded: twice the moves, no more memory


def test_errors_name_the_element_and_the_cause(tmp_path):
    text = tmp_path / "notes.mp4"
    text.write_text("hello\n" * 100)
    with pytest.raises(RunFailed, match="not a video"):
        run_pipeline_file(f"filesrc location={text} ! decodebin ! fakesink")
    with pytest.raises(RunFailed, match="filesrc"):
        run_pipeline_file(f"filesrc location={tmp_path / 'absent.mp4'} ! decodebin ! fakesink")
    with pytest.raises(PipelineError, match="cannot build the pipeline"):
        run_pipeline_file("videotestsrc ! no-such-element-here ! fakesink")


def test_in_process_python_elements_log_no_floating_reference_critical():
    """PyGObject's floating-reference bug message is dropped in process; other GStreamer criticals still print."""
    import os
    import subprocess
    import sys

    code = (
        "import ctypes\n"
        "from gst_trafficcal.gst.runner import run_pipeline_file\n"
        "run_pipeline_file('videotestsrc num-buffers=3 ! video/x-raw,format=I420,width=64,height=48 ! "
        "vpdetect ! vehicledetect ! tracker ! fakesink')\n"
        "glib = ctypes.CDLL('libglib-2.0.so.0')\n"
        "glib.g_log(b'GStreamer', 1 << 3, b'%s', b'another critical')\n"  # G_LOG_LEVEL_CRITICAL
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=os.environ)
    assert res.returncode == 0, res.stderr
    assert "should be floating" not in res.stderr
    assert "GStreamer-CRITICAL" in res.stderr and "another critical" in res.stderr


def _frames(path) -> int:
    from .conftest import count_frames

    return count_frames(path)


ENDLESS = ("videotestsrc is-live=true ! video/x-raw,width=64,height=48,framerate=25/1 ! "
           "x264enc tune=zerolatency speed-preset=ultrafast ! mp4mux ! filesink location={}")


def test_stop_after_ends_an_endless_stream_with_a_playable_file(tmp_path):
    """A live source that never ends: stopped at 1 s by an end-of-stream, so mp4mux completes the file."""
    out = run_pipeline_file(ENDLESS.format(tmp_path / "a.mp4"), stop_after_s=1.0, poll_s=0.05)
    assert out.stopped == "duration" and out.position_s == pytest.approx(1.0, abs=0.2)
    assert 20 <= _frames(tmp_path / "a.mp4") <= 35  # 25 fps for about a second: a finished MP4


def test_stop_after_at_a_named_element_is_exact(tmp_path):
    """With the element on the decoded video named, the stream ends at the first frame that late, however far
    ahead the source runs (a file decodes faster than real time)."""
    desc = ("videotestsrc num-buffers=100 ! video/x-raw,width=64,height=48,framerate=25/1 ! videoconvert name=head ! "
            f"queue ! x264enc tune=zerolatency speed-preset=ultrafast ! mp4mux ! filesink location={tmp_path / 'c.mp4'}")
    out = run_pipeline_file(desc, stop_after_s=1.0, stop_element="head", poll_s=0.05)
    assert out.stopped == "duration" and _frames(tmp_path / "c.mp4") == 25
    out = run_pipeline_file(desc, stop_after_s=10.0, stop_element="head")  # longer than the stream: to its end
    assert out.stopped == "" and _frames(tmp_path / "c.mp4") == 100


@pytest.fixture
def ctrl_c():
    """Ctrl-C as in a terminal (a test run in the background may have SIGINT ignored)."""
    import signal

    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)


def test_ctrl_c_finishes_the_stream_and_a_second_one_stops_at_once(tmp_path, ctrl_c):
    import os
    import signal

    def interrupt(pos, dur):
        if pos >= 0.5:
            os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C, while the bus loop runs

    out = run_pipeline_file(ENDLESS.format(tmp_path / "b.mp4"), progress=interrupt, poll_s=0.05)
    assert out.stopped == "interrupted" and _frames(tmp_path / "b.mp4") >= 10  # a playable file up to there
    assert out.stopped_by == "SIGINT"

    calls = []

    def stubborn(pos, dur):  # keeps pressing Ctrl-C: the second one is not waited out
        calls.append(pos)
        os.kill(os.getpid(), signal.SIGINT)

    with pytest.raises(KeyboardInterrupt):
        # the end-of-stream waits behind slow buffers: the second Ctrl-C comes before it arrives
        run_pipeline_file("videotestsrc is-live=true ! video/x-raw,width=64,height=48 ! queue ! "
                          "identity sleep-time=300000 ! fakesink", progress=stubborn, poll_s=0.05)
    assert len(calls) == 2
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # the handler is put back


@pytest.mark.parametrize("name", ["SIGTERM", "SIGHUP"])
def test_sigterm_finishes_the_stream_as_ctrl_c_does(tmp_path, name):
    """SIGTERM — what systemctl stop, docker stop and Kubernetes send — and SIGHUP — the terminal that started the
    run closed (an SSH session ended) — end the stream like Ctrl-C (a playable file), say which signal it was, and
    the process's own handling of the signal is put back afterwards.  (SIGHUP killed the process at once.)"""
    import os
    import signal

    sig = signal.Signals[name]

    def terminate(pos, dur):
        if pos >= 0.5:
            os.kill(os.getpid(), sig)  # while the bus loop runs

    # as in a login session: a test run under nohup ignores SIGHUP, and the runner leaves an ignored signal alone
    # (the stream would never end)
    inherited = signal.signal(sig, signal.SIG_DFL) if sig == signal.SIGHUP else None
    try:
        before = signal.getsignal(sig)
        out = run_pipeline_file(ENDLESS.format(tmp_path / "t.mp4"), progress=terminate, poll_s=0.05)
        assert out.stopped == "interrupted" and out.stopped_by == name
        assert _frames(tmp_path / "t.mp4") >= 10  # completed by the end-of-stream: playable up to there
        assert signal.getsignal(sig) is before
    finally:
        if inherited is not None:
            signal.signal(sig, inherited)


def test_a_live_stream_too_fast_for_the_machine_drops_its_oldest_frames_a_file_never_does(tmp_path):
    """A camera served over RTSP (4 s at 25 fps) into an analysis that manages about 6 frames a second (identity
    sleeping 160 ms a frame): the live queue keeps a second of frames and drops the oldest beyond that — about half
    of them here (4 s: some 25 analysed, 25 queued at the end) — instead of falling further and further behind.
    The same analysis on a file drops nothing: a file waits for it."""
    from .conftest import serve_rtsp

    launch = ("( videotestsrc is-live=true num-buffers=100 pattern=ball ! video/x-raw,width=320,height=240,"
              "framerate=25/1 ! x264enc tune=zerolatency speed-preset=ultrafast key-int-max=25 ! "
              "rtph264pay name=pay0 pt=96 )")
    slow = ("videoconvert ! queue name=tcqueue max-size-buffers=4 max-size-bytes=0 max-size-time=0 ! "
            "identity sleep-time=160000 ! fakesink")
    told: list[tuple[int, int]] = []
    for uri in serve_rtsp(launch, "cam"):
        live = run_pipeline_file(f"uridecodebin uri={uri} ! {slow}", live_queue="tcqueue",
                                 on_frames=lambda dropped, frames: told.append((dropped, frames)))
    assert live.live and live.frames_in >= 90, (live.frames_in, live.frames_dropped)
    assert 0.3 < live.frames_dropped / live.frames_in < 0.8, (live.frames_in, live.frames_dropped)
    assert told and told[-1] == (live.frames_dropped, live.frames_in)  # told as they changed, to the end
    assert all(a[0] <= b[0] and a[1] <= b[1] for a, b in zip(told, told[1:]))
    clip = tmp_path / "clip.mp4"
    run_pipeline_file("videotestsrc num-buffers=20 pattern=ball ! video/x-raw,width=320,height=240,framerate=25/1 ! "
                      f"x264enc ! mp4mux ! filesink location={clip}")
    played = run_pipeline_file(f"filesrc location={clip} ! decodebin ! {slow}", live_queue="tcqueue")
    assert not played.live and played.frames_dropped == 0 and played.frames_in == 20  # every frame, none dropped
