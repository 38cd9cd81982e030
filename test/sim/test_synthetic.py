"""The paper-protocol generator: geometry, determinism, ground-truth velocities."""

import numpy as np
import pytest

from rs_localizer.geometry import rotation_angle_deg, rs_project_exact
from rs_localizer.sim.synthetic import FOCAL_PX, HALF_TAN, make_frame, paper_camera


def test_frame_follows_the_protocol():
    f = make_frame(0, 200, rs_speed=1.0, angle_from_identity=10.0)
    assert f.x.shape == (200, 2) and f.X.shape == (200, 3)
    assert np.all(np.abs(f.x) <= HALF_TAN + 1e-12) and np.all(np.abs(f.X) <= 1)
    assert 2 <= np.linalg.norm(f.position) <= 3
    assert rotation_angle_deg(f.R, np.eye(3)) == pytest.approx(10.0)
    # 30 deg and 0.3 units over the frame height 2 tan(22.5 deg)
    assert np.degrees(np.linalg.norm(f.w)) * 2 * HALF_TAN == pytest.approx(30.0)
    assert np.linalg.norm(f.t) * 2 * HALF_TAN == pytest.approx(0.3)
    x, _r = rs_project_exact(f.X, f.R, f.C, f.w, f.t, f.r0)
    np.testing.assert_allclose(x, f.x, atol=1e-12)  # noise-free: exact model, r = y
    np.testing.assert_allclose(f.r, f.x[:, 1])
    np.testing.assert_allclose(f.points_px, f.x * FOCAL_PX + (1000 - 1) / 2)


def test_noise_outliers_and_determinism():
    a = make_frame(5, 300, noise_px=1.0, outlier_ratio=0.3)
    b = make_frame(5, 300, noise_px=1.0, outlier_ratio=0.3)
    np.testing.assert_array_equal(a.x, b.x)
    assert (~a.inlier).sum() == 90
    clean = make_frame(5, 300)
    err = np.linalg.norm(a.x - clean.x, axis=1)[a.inlier] * FOCAL_PX
    assert np.sqrt(np.mean(err**2) / 2) == pytest.approx(1.0, rel=0.15)


def test_motion_options_and_velocities():
    f = make_frame(1, 50, translation_only=True)
    assert np.all(f.w == 0) and np.all(f.angular_velocity == 0)
    g = make_frame(1, 50, rotation_only=True)
    assert np.all(g.t == 0)
    # angular velocity of the camera = -w / seconds_per_unit_r (finite differences agree)
    np.testing.assert_allclose(g.angular_velocity, -g.w / g.seconds_per_unit_r, rtol=1e-6)
    assert g.seconds_per_unit_r == pytest.approx(paper_camera(0.03).seconds_per_unit_r)
    e = make_frame(2, 50, model="eq5")
    assert np.isfinite(e.x).all()
    with pytest.raises(ValueError):
        make_frame(0, 10, model="spline")
