"""benchmarks.bench_shared_shift: its frames' truth, and a short run's report."""

from types import SimpleNamespace

import numpy as np

from benchmarks.bench_shared_shift import D, K, main, pose_errors, rig_frames
from rs_localizer.camera import CameraModel
from rs_localizer.geometry import rotvec_to_matrix
from rs_localizer.sim.noise import shifted_tag_frame


def test_frames_project_to_their_pixels_at_the_truth():
    """Without noise or shift every corner is where the true pose projects it, in the image;
    a rig view's points through its mounting too."""
    camera = CameraModel(K=K, D=D, width=640, height=480, line_delay=0.0)
    rng = np.random.default_rng(0)
    uv, X, g, R, C = shifted_tag_frame(rng, camera, 5, 0.0, 0.0)
    np.testing.assert_allclose(camera.project(X @ R.T + C), uv, atol=1e-9)
    assert np.array_equal(g, np.repeat(np.arange(5), 4)) and (uv >= 20).all()
    for views, R, C in rig_frames(rng, camera, 2, 0.0, 0.0):
        for v in views:
            P = (v.X @ R.T + C) @ v.mounting.R.T + v.mounting.c
            np.testing.assert_allclose(camera.project(P), v.uv, atol=1e-9)


def test_pose_errors_are_the_rotation_angle_and_the_centre_distance():
    """An estimate turned 0.2 deg about its own axis and its camera centre moved 3 mm from the
    truth ``x = R X + C`` (centre ``-R^T C``): 0.2 deg and 3 mm."""
    R, C = rotvec_to_matrix(np.r_[0.3, -0.2, 0.1]), np.r_[0.1, -0.4, 2.0]
    Re = rotvec_to_matrix(np.radians(0.2) * np.r_[0.0, 0.6, 0.8]) @ R
    centre = -R.T @ C + np.r_[0.003, 0.0, 0.0]
    est = SimpleNamespace(model=SimpleNamespace(R=Re, C=-Re @ centre))
    rot, pos = pose_errors(est, R, C)
    assert np.isclose(rot, 0.2, rtol=1e-9) and np.isclose(pos, 3.0, rtol=1e-9)


def test_a_short_run_reports_every_case(capsys):
    main(["--frames", "2"])
    out = capsys.readouterr().out
    assert out.count("grouped / plain time") == 7 and "rig of 3" in out
    assert out.count("median error rotation") == 7
