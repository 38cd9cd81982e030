"""Our Levenberg-Marquardt refinement against SciPy's least_squares on the same problem."""

import numpy as np
import pytest

from rs_localizer._linalg import solve_symmetric as _solve_symmetric
from rs_localizer.estimation.prior import MotionPrior
from rs_localizer.estimation.refine import (
    Mountings,
    RefineSettings,
    _normal_equations,
    exact_errors,
    exact_jacobian,
    exact_residuals,
    exact_rows,
    posterior_step,
    refine_rs_pose,
    refine_rs_pose_scipy,
    untruncated_variance,
)
from rs_localizer.geometry import matrix_to_rotvec, rotation_angle_deg, rotvec_to_matrix
from rs_localizer.pose import model_twist, model_twist_jacobian
from rs_localizer.sim.synthetic import make_frame


def perturbed_start(f, rng):
    return (
        rotvec_to_matrix(rng.normal(size=3) * 0.01) @ f.R,
        f.C + rng.normal(size=3) * 0.02,
        f.w * 0.9,
        f.t * 1.1,
    )


@pytest.mark.parametrize("rolling", [True, False])
def test_matches_scipy_least_squares_without_outliers(rolling):
    rng = np.random.default_rng(1)
    f = make_frame(rng, 200, rs_speed=0.5 if rolling else 0.0, noise_px=1.0)
    start = perturbed_start(f, rng)
    tau = f.r - f.r0
    # huge loss scale: both are plain least squares, so their optimum must coincide
    a = refine_rs_pose(
        start,
        f.X,
        f.x,
        tau,
        1.0,
        RefineSettings(rolling_shutter=rolling, max_iterations=50, tol=1e-15),
    )
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
    Jn = np.stack(
        [
            (
                exact_residuals(theta + h * e, f.R, f.X, f.x, tau)
                - exact_residuals(theta - h * e, f.R, f.X, f.x, tau)
            )
            / (2 * h)
            for e in np.eye(12)
        ],
        axis=1,
    )
    np.testing.assert_allclose(J, Jn, atol=1e-6)


def test_recovers_ground_truth_with_outliers_and_reports_covariance():
    rng = np.random.default_rng(3)
    f = make_frame(rng, 400, rs_speed=0.5, noise_px=1.0, outlier_ratio=0.2)
    k = 2.0 / 1207.0
    ref = refine_rs_pose(
        perturbed_start(f, rng), f.X, f.x, f.r - f.r0, k, RefineSettings(cutoff=3 * k)
    )
    assert rotation_angle_deg(ref.R, f.R) < 0.05
    assert np.linalg.norm(ref.w - f.w) / np.linalg.norm(f.w) < 0.05
    sd = np.sqrt(np.diag(ref.covariance))
    assert np.all(sd > 0) and np.all(np.isfinite(sd))
    assert ref.sigma * 1207 == pytest.approx(1.0, rel=0.3)  # residual sigma ~ the 1 px noise
    e = exact_errors(ref.R, ref.C, ref.w, ref.t, f.X, f.x, f.r - f.r0)
    np.testing.assert_allclose(
        e,
        np.linalg.norm(
            exact_residuals(
                np.r_[np.zeros(3), ref.C, ref.w, ref.t], ref.R, f.X, f.x, f.r - f.r0
            ).reshape(-1, 2),
            axis=1,
        ),
    )


def reference_normal_equations(R, C, w, t, X, x, tau, k, cutoff, n_free):
    """H = J^T W J, g = J^T W r and the truncated Huber cost from exact_jacobian and
    exact_residuals in plain NumPy; also the mask of the points used and the errors."""
    n = len(X)
    theta = np.r_[np.zeros(3), C, w, t]
    r = exact_residuals(theta, R, X, x, tau).reshape(n, 2)
    J = exact_jacobian(theta, R, X, x, tau).reshape(n, 2, 12)[:, :, :n_free]
    z = (rotvec_to_matrix(tau[:, None] * w) @ (X @ R.T)[:, :, None])[:, 2, 0] + C[2] + tau * t[2]
    e = np.linalg.norm(r, axis=1)
    used = (z > 1e-12) & (e <= cutoff)
    wt = np.where(e <= k, 1.0, k / e)[used]
    H = np.einsum("n,nia,nib->ab", wt, J[used], J[used])
    g = np.einsum("n,nia,ni->a", wt, J[used], r[used])

    def rho(s):
        return np.where(s <= k, s * s, 2 * k * s - k * k)

    cost = rho(e[used]).sum() + (n - used.sum()) * rho(cutoff)
    return H, g, cost, used, e


@pytest.mark.parametrize("rolling", [True, False])
@pytest.mark.parametrize("w_scale", [1.0, 2.5])  # 2.5: some |tau w| beyond the series' range
def test_normal_equations_match_numpy_reference(rolling, w_scale):
    rng = np.random.default_rng(4)
    f = make_frame(rng, 61, rs_speed=1.0, noise_px=1.0, outlier_ratio=0.15)  # odd N
    R, C, w, t = perturbed_start(f, rng)
    w = w * w_scale
    if not rolling:
        w, t = np.zeros(3), np.zeros(3)
    tau = f.r - f.r0
    X = f.X.copy()
    X[0] = (np.array([0.1, 0.0, -1.0]) - C) @ R  # behind the camera
    n_free = 12 if rolling else 6
    e = exact_errors(R, C, w, t, X, f.x, tau)
    k, cutoff = np.quantile(e[np.isfinite(e)], [0.3, 0.8])
    H_ref, g_ref, cost_ref, used, e = reference_normal_equations(
        R, C, w, t, X, f.x, tau, k, cutoff, n_free
    )
    # all cases present: quadratic and linear Huber zone, beyond the cutoff, behind
    assert np.sum(used & (e <= k)) > 10 and np.sum(used & (e > k)) > 10
    assert np.sum(~used) > 10 and not used[0]
    if rolling:  # both branches of the rotation coefficients
        th = np.abs(tau) * np.linalg.norm(w)
        assert (th.max() > 0.2) == (w_scale > 1)
    H, g, cost = _normal_equations(R, C, w, t, X, f.x, tau, k, n_free, cutoff, None)
    assert H.shape == (n_free, n_free) and g.shape == (n_free,)
    np.testing.assert_allclose(H, H.T, rtol=0, atol=0)
    np.testing.assert_allclose(H, H_ref, rtol=1e-10, atol=1e-12 * np.abs(H_ref).max())
    np.testing.assert_allclose(g, g_ref, rtol=1e-10, atol=1e-12 * np.abs(g_ref).max())
    assert cost == pytest.approx(cost_ref, rel=1e-12)


@pytest.mark.parametrize("rolling", [True, False])
def test_covariance_is_sigma2_inverse_normal_matrix(rolling):
    rng = np.random.default_rng(5)
    f = make_frame(rng, 150, rs_speed=0.5, noise_px=1.0, outlier_ratio=0.1)
    k = 2.0 / 1207.0
    start = [
        rotvec_to_matrix(rng.normal(size=3) * 0.001) @ f.R,
        f.C + rng.normal(size=3) * 0.002,
        f.w * 0.98,
        f.t * 1.02,
    ]
    before = [a.copy() for a in start]
    tau = f.r - f.r0
    ref = refine_rs_pose(
        start, f.X, f.x, tau, k, RefineSettings(rolling_shutter=rolling, cutoff=3 * k)
    )
    for a, b in zip(start, before, strict=False):  # inputs untouched
        np.testing.assert_array_equal(a, b)
    n_free = 12 if rolling else 6
    e = exact_errors(ref.R, ref.C, ref.w, ref.t, f.X, f.x, tau)
    inside = np.isfinite(e) & (e <= k)
    # residual variance inside the threshold, corrected for the truncation (the correction is
    # checked against Monte Carlo in test_planar.py)
    sigma2 = untruncated_variance(np.sum(e[inside] ** 2) / (2 * inside.sum() - n_free), k)
    assert ref.sigma == pytest.approx(np.sqrt(sigma2), rel=1e-10)
    H = _normal_equations(ref.R, ref.C, ref.w, ref.t, f.X, f.x, tau, k, n_free, 3 * k, None)[0]
    cov = np.zeros((12, 12))
    cov[:n_free, :n_free] = sigma2 * np.linalg.inv(H)
    np.testing.assert_allclose(ref.covariance, cov, rtol=1e-8, atol=1e-8 * np.abs(cov).max())
    if not rolling:
        assert np.all(ref.w == 0) and np.all(ref.t == 0)
    # no covariance: None and NaN sigma, same pose
    fast = refine_rs_pose(
        start,
        f.X,
        f.x,
        tau,
        k,
        RefineSettings(rolling_shutter=rolling, cutoff=3 * k, covariance=False),
    )
    assert fast.covariance is None and np.isnan(fast.sigma) and fast.nfev == ref.nfev
    np.testing.assert_array_equal(fast.R, ref.R)


def test_all_points_beyond_cutoff():
    """Nothing to fit: H = 0, g = 0, so the model predicts no decrease and no step is taken;
    the covariance is NaN (singular H)."""
    rng = np.random.default_rng(5)
    f = make_frame(rng, 50, rs_speed=0.5)
    R, C, w, t = perturbed_start(f, rng)
    k = 0.1 / 1207.0
    ref = refine_rs_pose((R, C, w, t), f.X, f.x, f.r - f.r0, k, RefineSettings(cutoff=k))
    assert not ref.success and ref.nfev == 1 and ref.sigma == 0.0
    assert np.all(np.isnan(ref.covariance))
    np.testing.assert_array_equal(ref.R, R)
    assert ref.R is not R


@pytest.mark.parametrize("n", [12, 6])
def test_symmetric_solver_cholesky_lu_and_singular(n):
    rng = np.random.default_rng(6)
    L, M = np.empty((12, 12)), np.empty((12, 12))
    J = rng.normal(size=(30, 12))
    S = rng.normal(size=(12, 12))
    # positive definite (Cholesky), indefinite (LU fallback)
    for A, definite in ((J.T @ J, True), (S + S.T, False)):
        assert (np.linalg.eigvalsh(A[:n, :n]).min() > 0) == definite
        B = np.eye(12)
        assert _solve_symmetric(A, B, n, n, L, M)
        np.testing.assert_allclose(B[:n, :n], np.linalg.inv(A[:n, :n]), rtol=1e-9, atol=1e-12)
    assert not _solve_symmetric(np.zeros((12, 12)), np.eye(12), n, n, L, M)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("offset", [0.5, 2.0])
def test_posterior_step_matches_converged_map(seed, offset):
    """The closed-form MAP from the ML optimum against Levenberg-Marquardt run to convergence
    on the MAP cost from there, for a prior as informative as the data with its mean
    ``offset`` standard deviations off. The prior moves the estimate by several posterior
    standard deviations; the closed form lands within 6 % of that move (the rest is the
    truncated loss re-selecting points near its threshold at the new estimate, which one step
    on the ML normal equations cannot see), and its covariance is the posterior one to 2 %."""
    rng = np.random.default_rng(seed)
    f = make_frame(rng, 300, rs_speed=0.5, noise_px=1.0, outlier_ratio=0.2)
    k, s = 2.0 / 1207.0, 1e-3
    tau = f.r - f.r0
    ml = refine_rs_pose(
        (f.R, f.C, f.w, f.t),
        f.X,
        f.x,
        tau,
        k,
        RefineSettings(cutoff=2 * k, tol=1e-14, max_iterations=50),
    )
    Jz = model_twist_jacobian(ml.C, ml.w, s)
    S = Jz @ ml.covariance @ Jz.T  # the data's twist covariance
    mean = model_twist(ml.C, ml.w, ml.t, s) + offset * np.sqrt(np.diag(S))
    prior = MotionPrior(mean=mean, covariance=S, always=True)
    conv = refine_rs_pose(
        (ml.R, ml.C, ml.w, ml.t),
        f.X,
        f.x,
        tau,
        k,
        RefineSettings(cutoff=2 * k, tol=1e-14, max_iterations=50, seconds_per_unit_r=s),
        prior=prior,
    )
    step = posterior_step(ml, prior, s)
    sd = np.sqrt(np.diag(conv.covariance))

    def diff(a, b):
        return np.abs(np.r_[matrix_to_rotvec(a.R @ b.R.T), a.C - b.C, a.w - b.w, a.t - b.t]) / sd

    move = diff(ml, conv).max()
    assert move > 1.0  # the prior matters here
    assert diff(step, conv).max() < 0.06 * move
    # the posterior covariance with the ML estimate's noise sigma (the residuals at the MAP
    # point, which the prior pulls off the data, would inflate it), from the converged MAP's
    # data information and the prior's Jacobian there
    Jc = model_twist_jacobian(conv.C, conv.w, s)
    expected = ml.sigma**2 * np.linalg.inv(
        conv.data_information + ml.sigma**2 * Jc.T @ np.linalg.inv(S) @ Jc
    )
    np.testing.assert_allclose(
        np.sqrt(np.diag(step.covariance)), np.sqrt(np.diag(expected)), rtol=0.02
    )
    assert step.sigma == ml.sigma and step.data_information is ml.data_information
    # the data gradient at a converged ML optimum vanishes (relative to the normal matrix)
    assert np.all(np.abs(ml.data_gradient) < 1e-6 * np.sqrt(np.diag(ml.data_information)))


def test_posterior_step_refuses():
    rng = np.random.default_rng(4)
    f = make_frame(rng, 100, rs_speed=0.5, noise_px=1.0)
    ml = refine_rs_pose((f.R, f.C, f.w, f.t), f.X, f.x, f.r - f.r0, 2.0 / 1207.0)
    assert (
        posterior_step(ml, MotionPrior(angular_velocity_sigma=0.0, linear_velocity_sigma=0.0), 1e-3)
        is None
    )
    nocov = refine_rs_pose(
        (f.R, f.C, f.w, f.t), f.X, f.x, f.r - f.r0, 2.0 / 1207.0, RefineSettings(covariance=False)
    )
    assert posterior_step(nocov, MotionPrior(), 1e-3) is None
    with pytest.raises(ValueError):
        posterior_step(ml, MotionPrior(), 0.0)


@pytest.mark.parametrize("mounted", [False, True])
def test_exact_rows_are_the_exact_residuals_and_jacobian(mounted):
    """The refinement kernel's rows (exact_rows) equal the NumPy exact_residuals and
    exact_jacobian to rounding, at Huber-downweighted points too, one camera and mounted
    whitened points; None with a point behind the camera."""
    rng = np.random.default_rng(5)
    n = 40
    X = rng.normal(size=(n, 3)) + [0.0, 0.0, 5.0]
    x = rng.normal(scale=0.1, size=(n, 2))
    tau = rng.normal(scale=0.01, size=n)
    R0 = rotvec_to_matrix(np.r_[0.1, 0.2, -0.1])
    C, w, t = np.r_[0.1, 0.2, 0.3], np.r_[0.5, -0.3, 0.2], np.r_[0.1, 0.2, -0.1]
    m = None
    if mounted:
        scale = rng.normal(scale=0.1, size=(n, 2, 2)) + np.eye(2)
        m = Mountings(np.zeros(n, np.int64), np.eye(3)[None], np.zeros((1, 3)), scale)
    r, J = exact_rows((R0, C, w, t), X, x, tau, 0.02, m)
    theta = np.r_[0.0, 0.0, 0.0, C, w, t]
    r0, J0 = exact_residuals(theta, R0, X, x, tau, m), exact_jacobian(theta, R0, X, x, tau, m)
    assert np.abs(r0.reshape(-1, 2)).max() > 0.02  # (some points beyond the Huber scale)
    np.testing.assert_allclose(r, r0, rtol=0, atol=1e-12 * np.abs(r0).max())
    np.testing.assert_allclose(J, J0, rtol=0, atol=1e-12 * np.abs(J0).max())
    X[3, 2] = -5.0
    assert exact_rows((R0, C, w, t), X, x, tau, 0.02, m) is None
