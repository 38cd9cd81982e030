"""gR6P_{v,C,w,t}^{[v]x} (the rig generalization of paper sec. 3.3) against ground truth, the
single-camera r6p_1lin and PoseLib's generalized absolute pose."""

import numpy as np
import pytest

from rs_localizer.geometry import (
    rotation_angle_deg,
    rotvec_to_matrix,
    rs_project_exact,
    rs_project_first_order,
    skew,
)
from rs_localizer.solvers import DegenerateInputError, r6p_1lin, r6p_1lin_batch
from rs_localizer.solvers.gr6p_1lin import gr6p_1lin, gr6p_1lin_batch
from rs_localizer.solvers.r6p_1lin import mounted_error

#: readout directions d (r = d . x): top to bottom, left to right, bottom to top
READOUTS = ([0.0, 1.0], [1.0, 0.0], [0.0, -1.0])


def make_rig(rng, m):
    """M cameras looking outward around the rig's z axis (front, side, back...), 5-20 cm off
    the rig's origin, each with its own line delay (s per normalized unit), stamp offset (s,
    up to 10 ms) and readout direction."""
    R, c, cams = [], [], []
    for k in range(m):
        yaw = 2 * np.pi * k / max(m, 1) + rng.normal() * 0.1
        Rc = rotvec_to_matrix([0.0, yaw, 0.0]) @ rotvec_to_matrix(rng.normal(size=3) * 0.05)
        pos = rng.uniform(-0.2, 0.2, 3)  # camera centre in the rig frame
        R.append(Rc)
        c.append(-Rc @ pos)
        cams.append(
            dict(
                delay=rng.uniform(0.015, 0.04),
                stamp=rng.uniform(-0.01, 0.01),
                r0=rng.uniform(-0.2, 0.2),
                readout=np.array(READOUTS[k % 3]),
            )
        )
    return np.array(R), np.array(c), cams


def observe(rng, Rm, cm, cams, counts, v, C, w, t, exact=False):
    """Noise-free observations of random points in front of each camera: the linearized rig
    model of the module docstring (R = I + [v]x, I + tau [w]x), or the exact constant-velocity
    model (expm) with ``exact``. Returns x, X, tau, cam (stacked over cameras)."""
    Rrig_lin = np.eye(3) + skew(v)
    xs, Xs, taus, ids = [], [], [], []
    for c, n in enumerate(counts):
        k = cams[c]
        # world points in front of camera c at the reference time (rig pose ~ (I, C))
        pc = rng.uniform([-1.5, -1.5, 2.0], [1.5, 1.5, 6.0], (3 * n, 3))
        Xw = (Rm[c].T @ (pc - cm[c]).T).T - C
        if exact:
            # camera c in the single-camera exact model (geometry.rs_project_exact), its own r:
            # R' = R_c expm(s W) R, C' = R_c (C + s t) + c_c, w' = d R_c w, t' = d R_c t
            s, d = k["stamp"], k["delay"]
            Rv = rotvec_to_matrix(v)
            Rp = Rm[c] @ rotvec_to_matrix(s * w) @ Rv
            x, r = rs_project_exact(
                Xw, Rp, Rm[c] @ (C + s * t) + cm[c], d * Rm[c] @ w, d * Rm[c] @ t, k["r0"],
                k["readout"],
            )  # fmt: skip
        else:
            # linearized: x_cam = P0 + (r - r0) P1 with tau = s + d (r - r0)
            s, d = k["stamp"], k["delay"]
            RX = Xw @ Rrig_lin.T
            P0 = (RX + s * np.cross(w, RX) + C + s * t) @ Rm[c].T + cm[c]
            P1 = d * ((np.cross(w, RX) + t) @ Rm[c].T)
            x, r = rs_project_first_order(P0, P1, k["r0"], k["readout"])
        good = np.isfinite(x).all(axis=1) & (np.abs(x) < 1.0).all(axis=1)
        sel = np.flatnonzero(good)[:n]
        assert len(sel) == n
        xs.append(x[sel])
        Xs.append(Xw[sel])
        # each observation's time relative to the rig's reference time (the solver's module
        # docstring): the camera's stamp offset plus its line delay times (r - r0)
        taus.append(k["stamp"] + k["delay"] * (r[sel] - k["r0"]))
        ids.append(np.full(n, c))
    return np.vstack(xs), np.vstack(Xs), np.concatenate(taus), np.concatenate(ids)


def truth(rng, w_mag=1.0, t_mag=0.5, v_mag=0.05):
    """A rig motion: v as after a pre-rotation (rad), C (m), w (rad/s), t (m/s)."""
    w = rng.normal(size=3)
    return (
        rng.normal(size=3) * v_mag,
        rng.normal(size=3) * 0.2,
        w * w_mag / np.linalg.norm(w),
        rng.normal(size=3) * t_mag,
    )


def errors(sol, v, C, w, t):
    return (
        np.linalg.norm(sol.v - v),
        np.linalg.norm(sol.C - C),
        np.linalg.norm(sol.w - w),
        np.linalg.norm(sol.t - t),
    )


@pytest.mark.parametrize("r0", [0.0, 0.2])
def test_one_camera_at_identity_equals_r6p_1lin(r0):
    """A rig of one camera mounted at the identity, tau = r - r0: the rows are r6p_1lin's, so
    the solution is the same (bit for bit here; asserted to 1e-9), single and batched, with and
    without the prior rows."""
    rng = np.random.default_rng(3)
    eye, z = np.eye(3)[None], np.zeros((1, 3))
    for n in (6, 7, 20):
        X = rng.uniform(-1, 1, (n, 3)) + [0, 0, 3]
        x = X[:, :2] / X[:, 2:] + rng.normal(size=(n, 2)) * 0.01
        r = x[:, 1]
        a = r6p_1lin(x, X, r, r0, iterations=8)
        b = gr6p_1lin(x, X, r - r0, np.zeros(n, int), eye, z, iterations=8)
        for f in ("v", "C", "w", "t"):
            np.testing.assert_allclose(getattr(b, f), getattr(a, f), rtol=0, atol=1e-9)
        assert b.iterations == a.iterations
        assert abs(b.algebraic_error - a.algebraic_error) < 1e-12
    K, n = 5, 8
    X = rng.uniform(-1, 1, (K, n, 3)) + [0, 0, 3]
    x = X[..., :2] / X[..., 2:] + rng.normal(size=(K, n, 2)) * 0.01
    P = rng.normal(size=(K, 6, 6))
    q = rng.normal(size=(K, 6))
    for prior in (None, (P, q)):
        a = r6p_1lin_batch(x, X, x[..., 1], r0, iterations=6, prior_rows=prior)
        b = gr6p_1lin_batch(x, X, x[..., 1] - r0, 0, eye, z, iterations=6, prior_rows=prior)
        assert np.array_equal(a.valid, b.valid)
        for f in ("v", "C", "w", "t"):
            np.testing.assert_allclose(getattr(b, f), getattr(a, f), rtol=0, atol=1e-9)


@pytest.mark.parametrize("m", [2, 3, 4])
def test_recovers_rig_motion_on_linearized_model_data(m):
    """Noise-free data of the rig eq. 5 (unsynchronized cameras, own line delays and readout
    directions, 1 rad/s, 0.5 m/s): the fixed point is exact; the iteration reaches the truth
    on minimal (6 points, spread over the cameras) and larger samples."""
    rng = np.random.default_rng(10 + m)
    hits = total = 0
    for _ in range(30):
        Rm, cm, cams = make_rig(rng, m)
        v, C, w, t = truth(rng)
        for counts in (np.bincount(rng.integers(0, m, 6), minlength=m), [5] * m):
            x, X, tau, cam = observe(rng, Rm, cm, cams, counts, v, C, w, t)
            sol = gr6p_1lin(x, X, tau, cam, Rm, cm, iterations=50)
            total += 1
            e = errors(sol, v, C, w, t)
            hits += max(e) < 1e-7
            if sum(counts) > 6:  # overdetermined: one root, always reached
                assert max(e) < 1e-7, e
                assert sol.algebraic_error < 1e-10
    assert hits >= 0.9 * total


def test_numpy_form_agrees_with_the_compiled_solver_and_the_truth():
    """gr6p_1lin_batch(..., numpy=True) (NumPy's stacked QR, nothing compiled) on 3-camera rigs: on
    noise-free data of the rig eq. 5 (20 minimal samples of 6 points, 5 samples of 15) it
    reaches the truth as the compiled batch does (1e-7); on data with 1e-3 noise, with and
    without prior rows, it gives the compiled batch's valid flags, iteration counts and
    solutions (1e-9)."""
    rng = np.random.default_rng(31)
    Rm, cm, cams = make_rig(rng, 3)
    for n, K in ((6, 20), (15, 5)):
        v, C, w, t = truth(rng)
        obs = [observe(rng, Rm, cm, cams, [n // 3] * 3, v, C, w, t) for _ in range(K)]
        x, X, tau, cam = (np.array([o[i] for o in obs]) for i in range(4))
        exact = gr6p_1lin_batch(x, X, tau, cam, Rm, cm, iterations=50, numpy=True)
        ref = gr6p_1lin_batch(x, X, tau, cam, Rm, cm, iterations=50)
        hit = np.array([max(errors(_row(exact, k), v, C, w, t)) < 1e-7 for k in range(K)])
        hit_ref = np.array([max(errors(_row(ref, k), v, C, w, t)) < 1e-7 for k in range(K)])
        assert hit.mean() >= 0.9 and np.array_equal(hit, hit_ref)
        x = x + rng.normal(size=x.shape) * 1e-3
        P, q = rng.normal(size=(K, 6, 6)), rng.normal(size=(K, 6))
        for prior in (None, (P, q)):
            a = gr6p_1lin_batch(x, X, tau, cam, Rm, cm, iterations=10, prior_rows=prior)
            b = gr6p_1lin_batch(x, X, tau, cam, Rm, cm, iterations=10, prior_rows=prior, numpy=True)
            assert np.array_equal(a.valid, b.valid) and np.array_equal(a.iterations, b.iterations)
            for f in ("v", "C", "w", "t"):
                np.testing.assert_allclose(getattr(b, f), getattr(a, f), rtol=0, atol=1e-9)


def _row(batch, k):
    """Problem ``k`` of an RSBatch as an object with v, C, w, t."""
    from types import SimpleNamespace

    return SimpleNamespace(v=batch.v[k], C=batch.C[k], w=batch.w[k], t=batch.t[k])


def test_exact_model_error_shrinks_with_motion():
    """Data of the exact constant-velocity model (expm), 3 cameras, v = 0 (a perfect
    pre-rotation): the linearization error of R(tau) ~ I + tau [w]x falls with the motion,
    about quadratically, as for r6p_1lin."""
    rng = np.random.default_rng(5)
    Rm, cm, cams = make_rig(rng, 3)
    med = []
    for scale in (2.0, 1.0, 0.5):
        errs = []
        for _ in range(15):
            _, C, w, t = truth(rng, w_mag=scale, t_mag=0.5 * scale)
            v = np.zeros(3)
            x, X, tau, cam = observe(rng, Rm, cm, cams, [10, 10, 10], v, C, w, t, exact=True)
            sol = gr6p_1lin(x, X, tau, cam, Rm, cm, iterations=20)
            errs.append(np.linalg.norm(sol.w - w) / scale)
            assert rotation_angle_deg(rotvec_to_matrix(sol.v), np.eye(3)) < 0.05
            assert np.linalg.norm(sol.C - C) < 1e-3
        med.append(np.median(errs))
    assert med[0] > med[1] > med[2]
    assert med[2] < 0.3 * med[0]
    assert med[2] < 0.01  # relative error of w at 0.5 rad/s


def _poselib_pose(x, X, cam, Rm, cm):
    """PoseLib's generalized absolute pose (all points inliers, bundle-refined): rig pose
    (R, C) with x_rig = R X + C."""
    poselib = pytest.importorskip("poselib")
    pts2, pts3, ext, cams = [], [], [], []
    for c in range(len(Rm)):
        s = cam == c
        pts2.append(x[s])
        pts3.append(X[s])
        e = poselib.CameraPose()
        e.R, e.t = Rm[c], cm[c]
        ext.append(e)
        cams.append({"model": "PINHOLE", "width": 2, "height": 2, "params": [1, 1, 0, 0]})
    pose, info = poselib.estimate_generalized_absolute_pose(
        pts2, pts3, ext, cams, {"max_reproj_error": 1e-6}, {}
    )
    return pose.R, pose.t, info


def test_global_shutter_rig_matches_poselib():
    """A still rig (w = t = 0) of 3 cameras, exact rotation: pre-rotating the world points
    by PoseLib's minimal gP3P solution (the closest of its roots) and solving three times (each
    pass re-pre-rotates with the last rotation, as the estimator does), the rig pose equals
    PoseLib's generalized absolute pose on the same inputs, and w, t come out zero."""
    poselib = pytest.importorskip("poselib")
    rng = np.random.default_rng(8)
    for _ in range(5):
        Rm, cm, cams = make_rig(rng, 3)
        R_true = rotvec_to_matrix(rng.normal(size=3))
        C = rng.normal(size=3) * 0.2
        z = np.zeros(3)
        # points observed with the rotation included: X = R_true^T Xp, Xp seen at v = 0
        x, Xp, tau, cam = observe(rng, Rm, cm, cams, [4, 4, 4], z, C, z, z)
        X = Xp @ R_true  # R_true X = Xp
        # PoseLib's gP3P on 3 points (one per camera): rays in the rig frame
        idx = [np.flatnonzero(cam == c)[0] for c in range(3)]
        xh = np.c_[x[idx], np.ones(3)]
        origins = np.array([-Rm[c].T @ cm[c] for c in cam[idx]])
        dirs = np.array([Rm[c].T @ xh[j] for j, c in enumerate(cam[idx])])
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        poses = poselib.gp3p(origins, dirs, X[idx])
        R0 = min((p.R for p in poses), key=lambda R: rotation_angle_deg(R, R_true))
        R_ref, C_ref, _ = _poselib_pose(x, X, cam, Rm, cm)
        for _ in range(3):
            sol = gr6p_1lin(x, X @ R0.T, tau, cam, Rm, cm, iterations=10)
            R0 = rotvec_to_matrix(sol.v) @ R0
        # (matrix difference: the arccos of rotation_angle_deg has a ~1e-6 deg floor)
        assert np.abs(R0 - R_ref).max() < 1e-9
        np.testing.assert_allclose(sol.C, C_ref, atol=1e-8)
        np.testing.assert_allclose(sol.w, 0, atol=1e-6)
        np.testing.assert_allclose(sol.t, 0, atol=1e-6)
        assert np.abs(R_ref - R_true).max() < 1e-9


def test_mounted_error_is_zero_on_model_data():
    """The RMS algebraic error of the rig eq. 5 (r6p_1lin.mounted_error, the error the
    solver's iterations stop on), on noise-free data of 2 cameras: zero at the true motion,
    not with the rig's position 0.1 off."""
    rng = np.random.default_rng(2)
    Rm, cm, cams = make_rig(rng, 2)
    v, C, w, t = truth(rng)
    x, X, tau, cam = observe(rng, Rm, cm, cams, [4, 4], v, C, w, t)
    assert mounted_error(x, X, tau, cam, Rm, cm, v, C, w, t) < 1e-12
    assert mounted_error(x, X, tau, cam, Rm, cm, v, C + 0.1, w, t) > 1e-3


def test_degenerate_and_bad_input():
    """Too few points, bad shapes, NaN, bad camera indices raise ValueError; all points on
    one ray, collinear points, one tau for all raise DegenerateInputError; the batch flags
    them instead."""
    rng = np.random.default_rng(4)
    Rm, cm, cams = make_rig(rng, 2)
    v, C, w, t = truth(rng)
    x, X, tau, cam = observe(rng, Rm, cm, cams, [4, 4], v, C, w, t)
    with pytest.raises(ValueError, match="at least 6"):
        gr6p_1lin(x[:5], X[:5], tau[:5], cam[:5], Rm, cm)
    with pytest.raises(ValueError):
        gr6p_1lin(x, X[:7], tau, cam, Rm, cm)
    with pytest.raises(ValueError):
        gr6p_1lin(x, X, tau[:7], cam, Rm, cm)
    with pytest.raises(ValueError, match="cam"):
        gr6p_1lin(x, X, tau, cam + 1, Rm, cm)
    with pytest.raises(ValueError, match="c_mount"):
        gr6p_1lin(x, X, tau, cam, Rm, cm[:1])
    xn = x.copy()
    xn[1, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        gr6p_1lin(xn, X, tau, cam, Rm, cm)
    with pytest.raises(ValueError, match="iterations"):
        gr6p_1lin(x, X, tau, cam, Rm, cm, iterations=0)
    # every point on one ray of camera 0 (the same image point, world points along the ray)
    n = 8
    ray = Rm[0].T @ np.array([0.1, -0.2, 1.0])
    origin = -Rm[0].T @ cm[0]
    Xr = origin + np.outer(np.linspace(2, 6, n), ray)
    xr = np.repeat([[0.1, -0.2]], n, axis=0)
    one = np.zeros(n, int)
    with pytest.raises(DegenerateInputError):
        gr6p_1lin(xr, Xr, rng.uniform(-0.01, 0.01, n), one, Rm, cm)
    # one point repeated
    with pytest.raises(DegenerateInputError):
        gr6p_1lin(np.repeat(x[:1], n, 0), np.repeat(X[:1], n, 0), tau[:n], cam[:n], Rm, cm)
    # every observation at the same time: w and t are not determined
    with pytest.raises(DegenerateInputError):
        gr6p_1lin(x, X, np.full(len(x), 0.003), cam, Rm, cm)
    b = gr6p_1lin_batch(
        np.array([x, np.repeat(x[:1], 8, 0), x]),
        np.array([X, np.repeat(X[:1], 8, 0), X]),
        np.array([tau, tau, tau * np.nan]),
        np.array([cam, cam, cam]),
        Rm,
        cm,
        iterations=30,
    )
    assert list(b.valid) == [True, False, False]
    assert np.isfinite(b.v).all() and np.isfinite(b.t).all()
    assert max(errors(b.solution(0), v, C, w, t)) < 1e-7
