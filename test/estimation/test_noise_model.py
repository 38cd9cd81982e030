"""Correlated image error in the covariance (rs_localizer.estimation.noise_model):
the sandwich covariance against finite differences of the refinement, the REML fit
against the model it was drawn from, and the calibration of the new covariance on still
synthetic boards (not inflated where the correlated error is what the model says); the shift
shared by one marker's corners: its variances recovered, and the covariance with it covering the
true pose of a camera and of a rig where the independent points' does not."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import chi2

from rs_localizer.camera import CameraModel
from rs_localizer.estimation.estimate import CorrelatedNoise, EstimateOptions, estimate_rs_pose
from rs_localizer.estimation.noise_model import (
    MIN_SHIFT_DOF,
    correlated_noise_covariance,
    fit_correlated_noise,
    pixel_jacobians,
    shared_shift_variances,
)
from rs_localizer.estimation.prior import MotionPrior
from rs_localizer.estimation.refine import Mountings, RefineSettings, refine_rs_pose
from rs_localizer.estimation.rig import RIG_OPTIONS, estimate_rig_pose
from rs_localizer.estimation.view import View
from rs_localizer.frames import Mounting
from rs_localizer.geometry import matrix_to_rotvec, rotvec_to_matrix
from rs_localizer.sim.noise import correlated_field, shifted_tag_frame

# the OpenCV sample camera of test/data/photos/left_intrinsics.yml (strong barrel distortion)
K = np.array([[535.9157, 0.0, 342.2832], [0.0, 535.9157, 235.5708], [0.0, 0.0, 1.0]])
D = np.array([-0.26637, -0.038589, 0.0017832, -0.00028122, 0.23839])
CAM = CameraModel(K=K, D=D, width=640, height=480, line_delay=30e-6)
Q6 = chi2.ppf(0.9973, 6)
# a model of the size fitted on OpenCV's photos (python -m benchmarks.still_boards)
WHITE, CORR, LENGTH = 0.10, 0.21, 92.0


def board_views(n_views, seed):
    """Still views of a 9 x 6 board (25 mm squares) filling most of the image: (X (54, 3),
    R, C) per view, camera 0.3-0.45 m away, tilted up to ~35 deg."""
    g = np.stack(np.meshgrid(np.arange(9), np.arange(6)), -1).reshape(-1, 2) * 0.025
    X = np.c_[g - g.mean(0), np.zeros(len(g))]
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n_views:
        R = rotvec_to_matrix(np.r_[rng.uniform(-0.6, 0.6, 2), rng.uniform(-0.4, 0.4)])
        C = np.r_[rng.uniform(-0.03, 0.03, 2), rng.uniform(0.3, 0.45)]
        u = CAM.project_rs(X, R, C)
        if CAM.in_image(u, margin=-20).all():
            out.append((X, R, C, u))
    return out


@pytest.mark.parametrize("whitened", [False, True])
def test_sandwich_matches_finite_differences_of_the_refinement(whitened):
    """The increment ``s^2 B M B`` of :func:`correlated_noise_covariance` equals
    ``A Sigma A^T`` with A the finite-difference derivative of the (MAP, fixed noise weight)
    refinement w.r.t. the measured pixels (through OpenCV's undistortion) and Sigma the
    correlated error's dense pixel covariance; on a moving frame of 3D points through the
    distorted camera. ``whitened``: the refinement on the errors of the measured image (each
    point's whitening, held at the measured points, as the single camera's estimator does).
    (On a planar board the Gauss-Newton linearization that every covariance of the
    refinement uses is itself 5-25 % off the estimator's derivative: the flat valley; the 3D
    scene isolates the sandwich.)"""
    rng = np.random.default_rng(2)
    R0, C0 = rotvec_to_matrix(np.array([0.2, -0.3, 0.1])), np.array([0.02, -0.01, 1.0])
    while True:
        X = (R0.T @ (rng.uniform(-0.5, 0.5, (40, 3)) * [1, 1, 0.6]).T).T
        if CAM.in_image(CAM.project_rs(X, R0, C0), margin=-10).all():
            break
    s = CAM.seconds_per_unit_r
    w0 = np.array([0.3, -0.5, 0.2]) * s  # a moving camera (~0.6 rad/s, 0.3 m/s)
    t0 = np.array([0.1, 0.2, -0.15]) * s
    u = CAM.project_rs(X, R0, C0, w0, t0) + np.random.default_rng(1).normal(0, 0.1, (len(X), 2))
    x, r, _ = CAM.normalize(u)
    tau = r - CAM.r0
    prior = MotionPrior()
    kw = dict(seconds_per_unit_r=s, max_iterations=100, tol=1e-15)
    W = mnt = None
    if whitened:
        W = CAM.pixel_jacobian(x) / CAM.K[0, 0]
        mnt = Mountings(np.zeros(len(X), dtype=np.int64), np.eye(3)[None], np.zeros((1, 3)), W)
    ref0 = refine_rs_pose(
        (R0, C0, w0, t0), X, x, tau, 1.0, RefineSettings(**kw), prior=prior, mountings=mnt
    )
    sigma = ref0.sigma
    ref = refine_rs_pose(
        (ref0.R, ref0.C, ref0.w, ref0.t),
        X,
        x,
        tau,
        1.0,
        RefineSettings(noise=sigma, **kw),
        prior=prior,
        mountings=mnt,
    )
    cov = correlated_noise_covariance(
        ref.covariance,
        ref.sigma,
        ref.R,
        ref.C,
        ref.w,
        ref.t,
        X,
        x,
        tau,
        u,
        pixel_jacobians(CAM, x),
        CORR,
        LENGTH,
        W,
    )

    def theta(p):
        xp = CAM.normalize(p)[0]  # capture times kept (the covariance neglects their noise)
        o = refine_rs_pose(
            (ref.R, ref.C, ref.w, ref.t),
            X,
            xp,
            tau,
            1.0,
            RefineSettings(noise=sigma, covariance=False, **kw),
            prior=prior,
            mountings=mnt,
        )
        return np.r_[matrix_to_rotvec(o.R @ ref.R.T), o.C, o.w, o.t]

    h = 1e-2  # px (the undistortion is exact to ~1e-6 px)
    A = np.empty((12, 2 * len(X)))
    for j in range(2 * len(X)):
        d = np.zeros(2 * len(X))
        d[j] = h
        A[:, j] = (theta(u + d.reshape(-1, 2)) - theta(u - d.reshape(-1, 2))) / (2 * h)
    d2 = np.sum((u[:, None] - u[None]) ** 2, axis=-1)
    Sig = np.kron(CORR**2 * np.exp(-0.5 * d2 / LENGTH**2), np.eye(2))
    want = A @ Sig @ A.T
    got = cov - ref.covariance
    scale = np.sqrt(np.outer(np.diag(want), np.diag(want)))
    assert np.abs(got - want).max() / scale.max() < 1e-3
    np.testing.assert_allclose(got / scale, want / scale, atol=2e-3)
    assert np.all(np.linalg.eigvalsh(got) > -1e-9 * np.abs(got).max())


def test_no_correlated_error_leaves_the_covariance_alone():
    X, _R, _C, u = board_views(1, 4)[0]
    a = estimate_rs_pose(u + 0.1, X, CAM, "r6p_1lin")
    b = estimate_rs_pose(
        u + 0.1,
        X,
        CAM,
        "r6p_1lin",
        EstimateOptions(correlated_noise=CorrelatedNoise(sigma_px=0.0, length_px=50)),
    )
    np.testing.assert_array_equal(a.covariance, b.covariance)
    c = estimate_rs_pose(
        u + 0.1, X, CAM, "r6p_1lin", EstimateOptions(correlated_noise=CorrelatedNoise(sigma_px=0.2))
    )
    np.testing.assert_array_equal(
        a.model.R, c.model.R
    )  # the estimate is unchanged, only its covariance
    assert np.all(np.linalg.eigvalsh(c.covariance - a.covariance) > -1e-12)


@pytest.mark.parametrize(
    "kw",
    [
        dict(sigma_px=-0.1),
        dict(sigma_px=np.nan),
        dict(length_px=0.0),
        dict(length_px=np.inf),
    ],
)
def test_options_reject(kw):
    with pytest.raises(ValueError, match="correlated_noise"):
        CorrelatedNoise(**kw)


@pytest.fixture(scope="module")
def still_frames():
    """13 still views x 6 draws of white + correlated image error (the fitted model's size)."""
    views = board_views(13, 7)
    return [
        (X, R, C, u + correlated_field(u, WHITE, CORR, LENGTH, np.random.default_rng((k, seed))))
        for k, (X, R, C, u) in enumerate(views)
        for seed in range(6)
    ]


def test_fit_recovers_the_model(still_frames):
    """REML on 13 still views (one draw each) recovers the correlated error it was drawn from,
    and finds none in white noise."""
    views = [(u, X, R, C) for X, R, C, u in still_frames[::6]]
    fit = fit_correlated_noise(CAM, views)
    assert fit.views == 13 and fit.points == 13 * 54
    assert abs(fit.white_px - WHITE) < 0.02
    assert 0.6 * CORR < fit.correlated_px < 1.5 * CORR
    assert 0.5 * LENGTH < fit.length_px < 2.0 * LENGTH
    assert fit.log_likelihood_ratio > 50
    rng = np.random.default_rng(11)
    white = [(u + rng.normal(0, WHITE, u.shape), X, R, C) for X, R, C, u in board_views(13, 8)]
    wf = fit_correlated_noise(CAM, white)
    assert abs(wf.white_px - WHITE) < 0.01
    assert wf.log_likelihood_ratio < 6  # 2 LLR ~ chi2(2): 99.7 % at 11.6
    assert wf.correlated_px < 0.35 * WHITE


def test_covariance_is_calibrated_on_still_boards(still_frames):
    """Still boards with the correlated error: the twist's Mahalanobis distance from the true
    zero is close to chi2(6) with the option (median 6.0, mean 8.4, 92 % within the 99.73 %
    bound: not inflated; the tail is the refinement's own, see below) and far beyond it
    without (mean 86, 14 %). On these views white noise alone gives mean 13.9 and 79 % with
    the white-noise covariance: the Gauss-Newton covariance of a planar board's RS model is
    too tight in the flat valley whatever the noise model."""
    opts = EstimateOptions(correlated_noise=CorrelatedNoise(sigma_px=CORR, length_px=LENGTH))
    m_on, m_off = [], []
    for X, _R, _C, u in still_frames:
        for opt, out in ((opts, m_on), (EstimateOptions(), m_off)):
            e = estimate_rs_pose(u, X, CAM, "r6p_1lin", opt)
            assert e.success
            tw = np.r_[e.pose.linear_velocity, e.pose.angular_velocity]
            out.append(tw @ np.linalg.solve(e.twist_covariance, tw))
    m_on, m_off = np.asarray(m_on), np.asarray(m_off)
    assert 4.0 < np.median(m_on) < 7.5 and 4.0 < m_on.mean() < 10.0, m_on
    assert np.mean(m_on <= Q6) >= 0.88
    assert m_off.mean() > 25.0 and np.mean(m_off <= Q6) < 0.5


# --- a shift shared by each group's points (one marker's corners) ---------------------------


def _linear_residuals(rng, groups, shift, own, P=6):
    """Residuals of a least-squares fit of P parameters to 4 points per group (2 axes each):
    errors = each group's shift (std ``shift`` per axis) + each point's own (``own``)."""
    n = 4 * groups
    J = rng.normal(size=(2 * n, P))
    e = np.repeat(rng.normal(scale=shift, size=(groups, 1, 2)), 4, axis=1).reshape(-1)
    e = e + rng.normal(scale=own, size=2 * n)
    K = np.linalg.solve(J.T @ J, J.T)
    return e - J @ (K @ e), J, K, np.repeat(np.arange(groups), 4)


def test_shared_shift_variances_recover_known_variances():
    """2000 groups with a shift of 0.3 px and own noise of 0.2 px after a 6-parameter fit: both
    variances within 10 %; without a shift the shared variance is near 0; two groups (whose
    shifts 6 parameters absorb) cannot tell one: 0 and the degrees of freedom say why."""
    rng = np.random.default_rng(1)
    s_n2, s_g2, dof = shared_shift_variances(*_linear_residuals(rng, 2000, 0.3, 0.2))
    assert s_n2 == pytest.approx(0.04, rel=0.1) and s_g2 == pytest.approx(0.09, rel=0.1)
    assert 4000 - 6 <= dof < 4000  # (2 per group, less what 6 parameters absorb)
    s_n2, s_g2, _ = shared_shift_variances(*_linear_residuals(rng, 2000, 0.0, 0.2))
    assert s_n2 == pytest.approx(0.04, rel=0.1) and s_g2 < 0.004
    s_n2, s_g2, dof = shared_shift_variances(*_linear_residuals(rng, 2, 0.3, 0.2))
    assert s_g2 == 0.0 and dof < MIN_SHIFT_DOF and s_n2 > 0


def _pose_nees(est, R, C):
    d = np.r_[matrix_to_rotvec(est.model.R @ R.T), est.model.C - C]
    return float(d @ np.linalg.solve(np.asarray(est.covariance)[:6, :6], d))


@pytest.mark.parametrize("line_delay", [0.0, 30e-6])
def test_grouped_covariance_covers_the_truth(line_delay):
    """Still frames of 16 tags through the distorted camera, global shutter (P3P's model) and
    rolling shutter (R6P's 12 parameters): with each tag's corners shifted together (0.5 px)
    plus their own noise (0.15 px), the true pose within 3 sigma (NEES of 6 dof below its
    99.73 % quantile) in >= 80 % of frames with the corners grouped by tag, in under 60 %
    without; without a shift both >= 85 %. The estimate itself is the same with and without
    groups."""
    camera = CameraModel(K=K, D=D, width=640, height=480, line_delay=line_delay)
    rng = np.random.default_rng(7)
    for shift, grouped_min, plain_max in ((0.5, 0.8, 0.6), (0.0, 0.85, 1.0)):
        inside = {True: [], False: []}
        for _ in range(60):
            uv, X, g, R, C = shifted_tag_frame(rng, camera, 16, shift, 0.15)
            plain = estimate_rs_pose(uv, X, camera)
            grouped = estimate_rs_pose(uv, X, camera, groups=g)
            assert plain.success and grouped.success
            np.testing.assert_array_equal(grouped.model.R, plain.model.R)
            np.testing.assert_array_equal(grouped.inliers, plain.inliers)
            for k, est in ((True, grouped), (False, plain)):
                inside[k].append(_pose_nees(est, R, C) <= Q6)
        assert np.mean(inside[True]) >= grouped_min, (shift, np.mean(inside[True]))
        if shift > 0:
            assert np.mean(inside[False]) < plain_max, np.mean(inside[False])
        else:
            assert np.mean(inside[False]) >= 0.85


def test_grouped_rig_covariance_covers_the_truth():
    """A still two-camera rig (global shutter, the second camera turned 90 deg), 5 tags per
    camera shifted as above: the rig pose within 3 sigma in >= 85 % of frames with each view's
    corners grouped by tag (a tag's shift its own in each camera), under 60 % without."""
    camera = CameraModel(K=K, D=D, width=640, height=480, line_delay=0.0)
    turn = Mounting(rotvec_to_matrix(np.r_[0.0, np.pi / 2, 0.0]), np.r_[0.1, 0.0, 0.0])
    rng = np.random.default_rng(8)
    inside = {True: [], False: []}
    for _ in range(60):
        uv0, X0, g0, R, C = shifted_tag_frame(rng, camera, 5, 0.5, 0.15)
        uv1, Xa, g1, R1, C1 = shifted_tag_frame(rng, camera, 5, 0.5, 0.15)
        # (camera 1's points in its own frame, P1 = R1 Xa + C1, put in the world of the rig
        # pose (R, C) through the mounting: P1 = turn.R (R X + C) + turn.c)
        X1 = ((Xa @ R1.T + C1 - turn.c) @ turn.R - C) @ R
        views = [View(uv0, X0, camera, groups=g0), View(uv1, X1, camera, turn, groups=g1)]
        grouped = estimate_rig_pose(views, RIG_OPTIONS)
        plain = estimate_rig_pose([replace(v, groups=None) for v in views], RIG_OPTIONS)
        assert grouped.success and plain.success
        np.testing.assert_array_equal(grouped.model.C, plain.model.C)
        for k, est in ((True, grouped), (False, plain)):
            inside[k].append(_pose_nees(est, R, C) <= Q6)
    assert np.mean(inside[True]) >= 0.85 and np.mean(inside[False]) < 0.6, inside


def test_groups_are_checked_and_the_numpy_implementation_says_it_ignores_them():
    """Groups of the wrong length or not integers are refused (a rig's naming the camera);
    the NumPy implementation lists them in ``ignored_inputs``."""
    camera = CameraModel(K=K, D=D, width=640, height=480, line_delay=0.0)
    uv, X, g, _, _ = shifted_tag_frame(np.random.default_rng(9), camera, 6, 0.0, 0.2)
    with pytest.raises(ValueError, match="groups must be"):
        estimate_rs_pose(uv, X, camera, groups=g[:-1])
    with pytest.raises(ValueError, match="groups must be"):
        estimate_rs_pose(uv, X, camera, groups=g + 0.5)
    with pytest.raises(ValueError, match=r"'left'.*groups must be"):
        estimate_rig_pose([View(uv, X, camera, name="left", groups=g[:3])], RIG_OPTIONS)
    est = estimate_rs_pose(uv, X, camera, "p3p", groups=g, implementation="numpy")
    assert est.success and "groups" in est.ignored_inputs


@pytest.mark.parametrize("tags", [2, 4])
def test_shift_share_covers_frames_too_few_to_tell(tags):
    """Frames of 2 tags (posed from their 8 corners alone, :mod:`.single_tag`) and 4 tags
    (too few for their residuals to tell a shared shift from the pose), each tag shifted by
    0.5 px plus 0.15 px of own noise: grouped, the covariance stays the white noise's (the
    true pose within 3 sigma in under 20 % of frames); with the share configured
    (``correlated_noise.shift_share = 0.9``, the true one 0.92) in >= 60 %, >= 90 % for the
    two tags' few-points pose (whose white noise has a floor)."""
    camera = CameraModel(K=K, D=D, width=640, height=480, line_delay=0.0)
    shared = EstimateOptions(correlated_noise=CorrelatedNoise(shift_share=0.9))
    rng = np.random.default_rng(11)
    inside = {True: [], False: []}
    for _ in range(60):
        uv, X, g, R, C = shifted_tag_frame(rng, camera, tags, 0.5, 0.15)
        for k, opts in ((True, shared), (False, EstimateOptions())):
            est = estimate_rs_pose(uv, X, camera, options=opts, groups=g)
            assert est.success and est.few_points == (tags == 2)
            inside[k].append(_pose_nees(est, R, C) <= Q6)
    assert np.mean(inside[False]) < 0.2, np.mean(inside[False])
    assert np.mean(inside[True]) >= (0.9 if tags == 2 else 0.6), np.mean(inside[True])


@pytest.mark.parametrize("share", [-0.1, 1.0, float("nan")])
def test_shift_share_outside_0_1_is_refused(share):
    with pytest.raises(ValueError, match="shift_share"):
        CorrelatedNoise(shift_share=share)
