"""The gyro is judged by the image alone: a wrong but plausible gyro gives the unaided estimate,
a right one is used; the image-alone refinement and the chi-square it feeds."""

from __future__ import annotations

import numpy as np
import pytest

from rs_localizer.estimation import EstimateOptions, RansacOptions, estimate_rs_pose
from rs_localizer.estimation.gyro import GyroMeasurement, gyro_image_chi2
from rs_localizer.estimation.result import GYRO_REJECTIONS
from rs_localizer.sim.gyro import simulated_gyro
from rs_localizer.sim.planar import make_planar_frame
from rs_localizer.tracking.gyro import gyro_measurement

OPTS = EstimateOptions(ransac=RansacOptions(seed=0, min_inliers=12))


@pytest.mark.parametrize("scene", ["depth", "plane"])
def test_a_gyro_off_by_rad_per_second_stated_precise_is_refused(scene):
    """The true rate plus a 2-30 rad/s offset, stated with 0.005 rad/s: the estimate is exactly
    the unaided one, with the reason."""
    rng = np.random.default_rng(11)
    for _ in range(4):
        f = make_planar_frame(rng, scene, outlier_ratio=0.2)
        off = rng.uniform(2, 30) * rng.choice([-1, 1]) * np.eye(3)[rng.integers(3)]
        bad = GyroMeasurement(f.angular_velocity + off, 0.005**2 * np.eye(3))
        a = estimate_rs_pose(f.points_px, f.X, f.camera, "r6p_1lin", OPTS, gyro=bad)
        b = estimate_rs_pose(f.points_px, f.X, f.camera, "r6p_1lin", OPTS)
        assert a.gyro_rejected and not a.gyro_used and a.gyro_rejection in GYRO_REJECTIONS
        assert a.success == b.success
        np.testing.assert_array_equal(a.model.R, b.model.R)
        np.testing.assert_array_equal(a.pose.angular_velocity, b.pose.angular_velocity)


def test_a_right_gyro_is_used_and_carries_no_reason():
    rng = np.random.default_rng(12)
    for scene in ("depth", "plane", "board"):
        f = make_planar_frame(rng, scene, outlier_ratio=0.3)
        e = estimate_rs_pose(
            f.points_px, f.X, f.camera, "r6p_1lin", OPTS, gyro=simulated_gyro(f, rng)
        )
        assert e.success and e.gyro_used and not e.gyro_rejected and e.gyro_rejection == ""
        assert "gyro_check" in e.timings


def test_image_chi2_allows_for_the_rate_change_in_the_readout():
    """``r^T (S_gyro + S_image + (k |d|)^2 I)^-1 r`` against NumPy; a planar frame allows more."""
    S, P = 1e-4 * np.eye(3), np.diag([4e-4, 1e-4, 9e-4])
    d = np.array([0.3, -0.4, 0.0])  # |d| = 0.5 rad/s
    g = GyroMeasurement(np.zeros(3), S, d)
    r = np.array([0.05, -0.02, 0.1])
    for planar, scale, k in ((False, 1.0, 0.1), (True, 2.0, 0.2)):
        ref = r @ np.linalg.solve(S + scale * P + (k * 0.5) ** 2 * np.eye(3), r)
        assert gyro_image_chi2(g, r, P, planar) == pytest.approx(ref, rel=1e-12)
    assert gyro_image_chi2(g, r, P, True) < gyro_image_chi2(g, r, P, False)
    assert gyro_image_chi2(g, [np.nan, 0, 0], P) == np.inf
    assert gyro_image_chi2(g, r, -np.eye(3)) == np.inf


def test_the_measurement_reports_the_rate_change_over_the_readout():
    """A rate growing linearly at 20 rad/s^2 about x: over a 20 ms readout it changes by
    0.4 rad/s; the mean is the rate at the window's middle."""
    t = np.arange(-0.02, 0.05, 0.005)
    rates = np.stack([1.0 + 20.0 * t, np.zeros_like(t), np.zeros_like(t)], axis=1)
    g = gyro_measurement(t, rates, (0.0, 0.02))
    np.testing.assert_allclose(g.rate_change, [0.4, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(g.angular_velocity, [1.2, 0.0, 0.0], atol=1e-12)
    assert np.all(gyro_measurement(t, rates, (0.01, 0.01)).rate_change == 0.0)
