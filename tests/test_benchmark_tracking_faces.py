"""benchmarks/tracking.py: the reference-point error split by face (oncoming fronts seen, receding fronts hidden)."""


def test_reference_errors_split_by_face(load_benchmark):
    """face_error: which face the front is and the signed error along / across the road, in metres."""
    import numpy as np
    import pytest

    from gst_trafficcal.synth.camera import build_camera
    from gst_trafficcal.synth.scenario import CameraSpec

    tr = load_benchmark("tracking")
    cam = build_camera(CameraSpec(height=8.0, offset=-4.0, pan=15.0, tilt=12.0, roll=1.0, hfov=60.0,
                                  resolution=[960, 540])).calibration_camera()
    px = lambda x, y: cam.world_to_image(np.array([x, y, 0.0]))  # noqa: E731
    # driving towards +x at x = 40 m: moving away from the camera, its front is the far face
    receding, along, across = tr.face_error(cam, px(40.5, 2.3), px(40.0, 2.0), +1)
    assert receding and along == pytest.approx(0.5, abs=1e-6) and across == pytest.approx(0.3, abs=1e-6)
    # driving towards −x at the same place: oncoming; 0.4 m nearer the camera is ahead of its front
    receding, along, across = tr.face_error(cam, px(39.6, 2.0), px(40.0, 2.0), -1)
    assert not receding and along == pytest.approx(0.4, abs=1e-6) and across == pytest.approx(0.0, abs=1e-6)
    summary = tr.face_summary([(True, 0.5, 0.3), (True, 0.7, -0.1), (False, 0.4, 0.0)])
    assert summary == dict(ref_oncoming=1, ref_along_oncoming_m=0.4, ref_receding=2, ref_along_receding_m=0.6,
                           ref_lateral_m=0.1)
    assert tr.face_summary([])["ref_oncoming"] == 0 and np.isnan(tr.face_summary([])["ref_lateral_m"])
