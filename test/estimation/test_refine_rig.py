"""The exact-model refinement of a rig (each observation through its camera's mounting, at its
own time, in its camera's pixels) against finite differences, SciPy's least_squares on the same
problem, and the single camera's refinement (a rig of one camera at the identity mounting)."""

import numpy as np
import pytest

from rs_localizer.estimation.prior import MotionPrior
from rs_localizer.estimation.refine import (
    KernelMountings,
    Mountings,
    RefineSettings,
    _checked_mountings,
    _normal_equations,
    exact_jacobian,
    exact_mounting_jacobian,
    exact_residuals,
    kernel_mountings,
    least_squares_exact_model,
    refine_rs_pose,
)
from rs_localizer.geometry import matrix_to_rotvec, rotvec_to_matrix
from rs_localizer.sim.synthetic import make_frame


def rig_problem(rng, m=3, n=40, noise_px=0.5):
    """A rig of m cameras at random (non-identity) mountings, each seeing n points at its own
    capture times (stamps 10 ms apart, 30 ms readout), turning at ~1.5 rad/s: the rig's
    model (R, C, w, t per s), X, normalized x, tau (s), Mountings (focal lengths as scale)."""
    Rm = np.array([rotvec_to_matrix(rng.normal(size=3)) for _ in range(m)])
    cm = rng.normal(size=(m, 3)) * 0.15
    R = rotvec_to_matrix(rng.normal(size=3))
    C = rng.normal(size=3)
    w = rng.normal(size=3)
    w *= 1.5 / np.linalg.norm(w)
    t = rng.normal(size=3)
    focal = rng.uniform(450, 600, size=m)
    Xs, xs, taus, cams = [], [], [], []
    for c in range(m):
        z = rng.uniform(2, 8, size=n)
        pc = np.c_[rng.uniform(-0.5, 0.5, (n, 2)) * z[:, None], z]  # camera frame
        tau = 0.01 * c + rng.uniform(-0.015, 0.015, size=n)
        y = (pc - cm[c]) @ Rm[c]  # rig frame: Rm^T (pc - cm)
        y = y - C - tau[:, None] * t
        X = np.einsum("nij,nj->ni", rotvec_to_matrix(-tau[:, None] * w), y) @ R
        Xs.append(X)
        xs.append(pc[:, :2] / pc[:, 2:] + rng.normal(size=(n, 2)) * noise_px / focal[c])
        taus.append(tau)
        cams.append(np.full(n, c))
    cam = np.concatenate(cams)
    mountings = Mountings(cam, Rm, cm, focal[cam])
    return (R, C, w, t), np.vstack(Xs), np.vstack(xs), np.concatenate(taus), mountings


def numeric(f, p, h=1e-7):
    return np.stack([(f(p + h * e) - f(p - h * e)) / (2 * h) for e in np.eye(len(p))], axis=1)


def test_rig_jacobians_match_finite_differences_and_the_kernel():
    rng = np.random.default_rng(4)
    (R, C, w, t), X, x, tau, mnt = rig_problem(rng, m=3, n=15)
    theta = np.r_[rng.normal(size=3) * 0.01, C, w, t]
    J = exact_jacobian(theta, R, X, x, tau, mnt)
    Jn = numeric(lambda th: exact_residuals(th, R, X, x, tau, mnt), theta)
    np.testing.assert_allclose(J, Jn, rtol=1e-5, atol=1e-4 * np.abs(J).max())
    # the mounting of each observation's own camera: rotation on the rig axes, centre
    for c in range(3):

        def moved(u, c=c):
            Rm, cm = mnt.R_mount.copy(), mnt.c_mount.copy()
            centre = -Rm[c].T @ cm[c]
            Rm[c] = Rm[c] @ rotvec_to_matrix(-u[:3])
            cm[c] = -Rm[c] @ (centre + u[3:])
            return exact_residuals(theta, R, X, x, tau, mnt._replace(R_mount=Rm, c_mount=cm))

        Jm = numeric(moved, np.zeros(6))
        on = np.repeat(mnt.cam == c, 2)
        Jm_a = exact_mounting_jacobian(theta, R, X, x, tau, mnt)
        np.testing.assert_allclose(Jm_a[on], Jm[on], rtol=1e-5, atol=1e-4 * np.abs(Jm).max())
    # the compiled kernel's normal equations (every point inside the Huber threshold)
    Rth = rotvec_to_matrix(theta[:3]) @ R
    H, g, cost = _normal_equations(
        Rth, C, w, t, X, x, tau, 1e6, 12, np.inf,
        _checked_mountings(mnt, len(X)),
    )  # fmt: skip
    J0 = exact_jacobian(np.r_[np.zeros(3), theta[3:]], Rth, X, x, tau, mnt)
    r0 = exact_residuals(np.r_[np.zeros(3), theta[3:]], Rth, X, x, tau, mnt)
    np.testing.assert_allclose(H, J0.T @ J0, rtol=1e-9, atol=1e-9 * np.abs(H).max())
    np.testing.assert_allclose(g, J0.T @ r0, rtol=1e-9, atol=1e-9 * np.abs(g).max())
    assert cost == pytest.approx(r0 @ r0, rel=1e-12)


def test_rig_refinement_matches_scipy_least_squares():
    rng = np.random.default_rng(5)
    (R, C, w, t), X, x, tau, mnt = rig_problem(rng, m=3, n=40)
    start = (rotvec_to_matrix(rng.normal(size=3) * 0.01) @ R, C + 0.02, w * 0.9, t * 1.1)
    a = refine_rs_pose(
        start, X, x, tau, 1e6,
        RefineSettings(max_iterations=50, tol=1e-15, seconds_per_unit_r=1.0),
        mountings=mnt,
    )  # fmt: skip
    theta0 = np.r_[np.zeros(3), start[1], start[2], start[3]]
    fit = least_squares_exact_model(
        start[0], theta0, 12, X, x, tau, None, 1.0, 0.0, mountings=mnt,
        xtol=1e-14, ftol=1e-14, gtol=1e-14,
    )  # fmt: skip
    th = fit.theta
    np.testing.assert_allclose(a.R, rotvec_to_matrix(th[:3]) @ start[0], atol=1e-9)
    np.testing.assert_allclose(a.C, th[3:6], atol=1e-8)
    np.testing.assert_allclose(a.w, th[6:9], atol=1e-7)
    np.testing.assert_allclose(a.t, th[9:12], atol=1e-7)
    # near the truth; the residual sigma (px) near the noise's 0.5 px
    assert np.linalg.norm(a.w - w) < 0.05
    assert 0.35 < a.sigma < 0.65


@pytest.mark.parametrize("with_prior", [False, True])
def test_one_camera_at_the_identity_mounting_is_the_single_camera_refinement(with_prior):
    rng = np.random.default_rng(6)
    f = make_frame(rng, 300, rs_speed=0.5, noise_px=1.0, outlier_ratio=0.2)
    tau = f.r - f.r0
    start = (rotvec_to_matrix(rng.normal(size=3) * 0.005) @ f.R, f.C + 0.01, f.w * 0.9, f.t)
    settings = RefineSettings(
        cutoff=3 * 2.0 / 1207.0, seconds_per_unit_r=3e-5, acceleration_block=True
    )
    prior = MotionPrior(0.5, 0.5) if with_prior else None
    one = Mountings(
        np.zeros(len(f.X), np.int64), np.eye(3)[None], np.zeros((1, 3)), np.ones(len(f.X))
    )
    a = refine_rs_pose(start, f.X, f.x, tau, 2.0 / 1207.0, settings, prior)
    b = refine_rs_pose(start, f.X, f.x, tau, 2.0 / 1207.0, settings, prior, mountings=one)
    assert a.nfev == b.nfev and a.success and b.success
    for p, q in (
        (a.R, b.R), (a.C, b.C), (a.w, b.w), (a.t, b.t), (a.covariance, b.covariance),
        (a.data_information, b.data_information), (a.acceleration_block, b.acceleration_block),
    ):  # fmt: skip
        np.testing.assert_allclose(q, p, rtol=1e-9, atol=1e-12 * np.abs(p).max())
    assert b.sigma == pytest.approx(a.sigma, rel=1e-9)


def test_mountings_that_do_not_match_are_refused():
    rng = np.random.default_rng(7)
    model, X, x, tau, mnt = rig_problem(rng, m=2, n=10)
    with pytest.raises(ValueError, match="camera index"):
        refine_rs_pose(model, X, x, tau, 2.0, mountings=mnt._replace(cam=mnt.cam + 1))
    with pytest.raises(ValueError, match="must be"):
        refine_rs_pose(model, X, x, tau, 2.0, mountings=mnt._replace(scale=mnt.scale[:-1]))


def test_mountings_checked_once_refine_as_the_mountings():
    """:func:`kernel_mountings` (checked once, for many refinements of one rig frame) gives
    the refinement and covariance of the :class:`Mountings` themselves, to the bit; checked
    for other observations, or not matching, it is refused."""
    rng = np.random.default_rng(8)
    (R, C, w, t), X, x, tau, mnt = rig_problem(rng, m=3, n=30)
    start = (rotvec_to_matrix(rng.normal(size=3) * 0.01) @ R, C + 0.02, w * 0.9, t * 1.1)
    settings = RefineSettings(seconds_per_unit_r=1.0, acceleration_block=True)
    once = kernel_mountings(mnt, len(X))
    assert isinstance(once, KernelMountings)
    a = refine_rs_pose(start, X, x, tau, 2.0 / 500, settings, mountings=mnt)
    b = refine_rs_pose(start, X, x, tau, 2.0 / 500, settings, mountings=once)
    assert a.nfev == b.nfev and a.sigma == b.sigma
    for p, q in ((a.R, b.R), (a.C, b.C), (a.w, b.w), (a.t, b.t), (a.covariance, b.covariance),
                 (a.acceleration_block, b.acceleration_block)):  # fmt: skip
        assert np.array_equal(p, q)
    with pytest.raises(ValueError, match="checked for 90 observations, got 89"):
        refine_rs_pose(start, X[1:], x[1:], tau[1:], 2.0 / 500, settings, mountings=once)
    with pytest.raises(ValueError, match="camera index"):
        kernel_mountings(mnt._replace(cam=mnt.cam + 1), len(X))


@pytest.mark.parametrize("with_prior", [False, True])
def test_the_numpy_refinement_reaches_the_compiled_one_and_gives_its_covariance(with_prior):
    """``refine_rs_pose_numpy`` (SciPy's least_squares, nothing compiled) on a rig with 10 %
    outliers: the compiled refinement's optimum, and at one model (no step) its sigma,
    information, acceleration block and (posterior) covariance."""
    from dataclasses import replace

    from rs_localizer.estimation.refine import refine_rs_pose_numpy

    rng = np.random.default_rng(7)
    (R, C, w, t), X, x, tau, mnt = rig_problem(rng, m=3, n=40)
    bad = rng.choice(len(X), 12, replace=False)
    x[bad] += rng.normal(size=(12, 2)) * 0.05  # (~25 px off: beyond the cutoff)
    start = (rotvec_to_matrix(rng.normal(size=3) * 0.003) @ R, C + 0.005, w * 0.95, t)
    prior = MotionPrior(1.0, 1.0) if with_prior else None
    settings = RefineSettings(
        max_iterations=50, tol=1e-15, cutoff=3.0, seconds_per_unit_r=1.0, acceleration_block=True
    )
    a = refine_rs_pose(start, X, x, tau, 1.0, settings, prior, mnt)
    b = refine_rs_pose_numpy(start, X, x, tau, 1.0, settings, prior, mnt)
    assert a.success and b.success
    # the same optimum within a tenth of its standard deviation (SciPy's Huber loss acts on
    # each residual component, the compiled one on each point's distance)
    d = np.r_[matrix_to_rotvec(b.R @ a.R.T), b.C - a.C, b.w - a.w, b.t - a.t]
    assert np.all(np.abs(d) < 0.1 * np.sqrt(np.diag(a.covariance)))
    # (both moved from the start to the truth, 1.5 rad/s, within the noise)
    assert np.linalg.norm(b.w - w) < 0.05 < np.linalg.norm(np.asarray(start[2]) - w)
    at = (a.R, a.C, a.w, a.t)
    still = replace(settings, max_iterations=0)
    a0 = refine_rs_pose(at, X, x, tau, 1.0, still, prior, mnt)
    b0 = refine_rs_pose_numpy(at, X, x, tau, 1.0, still, prior, mnt)
    np.testing.assert_allclose(b0.R, a.R, rtol=0, atol=0)  # (no step)
    assert b0.sigma == pytest.approx(a0.sigma, rel=1e-9)
    for p, q in (
        (a0.data_information, b0.data_information),
        (a0.acceleration_block, b0.acceleration_block),
        (a0.covariance, b0.covariance),
    ):
        np.testing.assert_allclose(q, p, rtol=1e-7, atol=1e-9 * np.abs(p).max())


def test_polish_hands_back_its_last_refinement_taken_or_not():
    """Local optimization's rounds (``polish``, a camera's and a rig's) on scalar models
    scored by their squared distance to 3: the linear step's 1.0 beats the start 0.0, the
    refinement from 1.0 is handed back with its start whether its lower score makes it the
    polished model (2.0) or not (-4.0); without a refinement, none."""
    from rs_localizer.estimation.local_optimization import polish

    def evaluate(m):
        return (m - 3.0) ** 2, np.arange(10) < 10 - abs(m - 3.0)

    best = (9.0, 0.0, np.arange(10) < 7)
    for step, want in ((lambda m: m + 1.0, 2.0), (lambda m: m - 5.0, 1.0)):
        (score, model, inl), last = polish(best, evaluate, lambda m, i: [1.0], step, 1)
        assert model == want and score == (want - 3.0) ** 2
        assert np.array_equal(inl, evaluate(want)[1])
        assert last == (1.0, step(1.0))
    (score, model, _), last = polish(best, evaluate, lambda m, i: [1.0], None, 1)
    assert (score, model, last) == (4.0, 1.0, None)


def test_pulled_in_keeps_a_finite_pull_that_lowers_the_score():
    """An initial model's pull (``pulled_in``, a camera's and a rig's) on models scored by
    their squared distance to 3: the refinement asked with the frame, the threshold, the gate
    as its cutoff, the motion model, the prior and the iterations; its model is kept only
    where it is finite and lowers the seed's score."""
    from rs_localizer.estimation.local_optimization import pulled_in

    def evaluate(m):
        return float((m[0] - 3.0) ** 2), np.arange(4) < 2

    seed = (4.0, (np.array(1.0),), np.zeros(4, dtype=bool))
    calls = []

    def pull(step):
        def refine(fr, model, th, rolling, prior, *, cutoff, max_iterations):
            calls.append((fr, th, cutoff, rolling, prior, max_iterations))
            return (model[0] + step,)

        return pulled_in(seed, "frame", 0.5, 7.0, True, None, 10, evaluate, refine)

    for step, kept in ((1.5, True), (5.0, False), (np.nan, False)):
        out = pull(step)
        assert (out is not seed) == kept
        if kept:
            assert out[1][0] == 2.5 and out[0] == 0.25 and out[2].tolist() == [1, 1, 0, 0]
    assert calls == [("frame", 0.5, 7.0, True, None, 10)] * 3
