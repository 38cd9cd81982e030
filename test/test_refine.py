"""Our Levenberg-Marquardt refinement against SciPy's least_squares on the same problem."""

import numpy as np
import pytest

from rs_localizer.geometry import rotation_angle_deg, rotvec_to_matrix
from rs_localizer.refine import (exact_errors, exact_jacobian, exact_residuals, refine_rs_pose,
                                 refine_rs_pose_scipy)
from rs_localizer.synthetic import make_frame


def perturbed_start(f, rng):
    return (rotvec_to_matrix(rng.normal(size=3) * 0.01) @ f.R, f.C + rng.normal(size=3) * 0.02,
            f.w * 0.9, f.t * 1.1)


@pytest.mark.parametrize("rolling", [True, False])
def test_matches_scipy_least_squares_without_outliers(rolling):
    rng = np.random.default_rng(1)
    f = make_frame(rng, 200, rs_speed=0.5 if rolling else 0.0, noise_px=1.0)
    start = perturbed_start(f, rng)
    tau = f.r - f.r0
    # huge loss scale: both are plain least squares, so their optimum must coincide
    a = refine_rs_pose(*start, f.X, f.x, tau, 1.0, rolling_shutter=rolling, max_iterations=50,
                       tol=1e-15)
    b = refine_rs_pose_scipy(*start, f.X, f.x, tau, 1.0, rolling_shutter=rolling)
    np.testing.assert_allclose(a.R, b.R, atol=1e-10)
    for p, q in ((a.C, b.C), (a.w, b.w), (a.t, b.t)):
        np.testing.assert_allclose(p, q, atol=1e-9)
    if not rolling:
        assert np.all(a.w == 0) and np.all(a.t == 0)


def test_jacobian_matches_finite_differences():
    rng = np.random.default_rng(2)
    f = make_frame(rng, 20, rs_speed=0.8)
    theta = np.r_[rng.normal(size=3) * 0.01, f.C, f.w, f.t]
    tau = f.r - f.r0
    J = exact_jacobian(theta, f.R, f.X, f.x, tau)
    h = 1e-7
    Jn = np.stack([(exact_residuals(theta + h * e, f.R, f.X, f.x, tau)
                    - exact_residuals(theta - h * e, f.R, f.X, f.x, tau)) / (2 * h)
                   for e in np.eye(12)], axis=1)
    np.testing.assert_allclose(J, Jn, atol=1e-6)


def test_recovers_ground_truth_with_outliers_and_reports_covariance():
    rng = np.random.default_rng(3)
    f = make_frame(rng, 400, rs_speed=0.5, noise_px=1.0, outlier_ratio=0.2)
    k = 2.0 / 1207.0
    ref = refine_rs_pose(*perturbed_start(f, rng), f.X, f.x, f.r - f.r0, k, cutoff=3 * k)
    assert rotation_angle_deg(ref.R, f.R) < 0.05
    assert np.linalg.norm(ref.w - f.w) / np.linalg.norm(f.w) < 0.05
    sd = np.sqrt(np.diag(ref.covariance))
    assert np.all(sd > 0) and np.all(np.isfinite(sd))
    assert ref.sigma * 1207 == pytest.approx(1.0, rel=0.3)  # residual sigma ~ the 1 px noise
    e = exact_errors(ref.R, ref.C, ref.w, ref.t, f.X, f.x, f.r - f.r0)
    np.testing.assert_allclose(e, np.linalg.norm(exact_residuals(
        np.r_[np.zeros(3), ref.C, ref.w, ref.t], ref.R, f.X, f.x, f.r - f.r0).reshape(-1, 2),
        axis=1))
