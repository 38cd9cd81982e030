"""R5P_{v,C,t}^{w}: the RS absolute pose with the angular velocity known, against noise-free
data of the exact model (eq. 4) and against a generic least-squares solve of its equations."""

import numpy as np
import pytest
from numba import njit
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from rs_localizer.solvers import DegenerateInputError, r5p_w, r5p_w_batch
from rs_localizer.solvers.kernels import KNOWN_W, MAX_PARAMS, R5P_W, kernel_set, run_kernels


def _skew(a):
    return np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])


def _exact_frame(rng, n=5, planar=False, r0=0.05):
    """Noise-free correspondences of the exact constant-velocity model (eq. 4,
    ``X_cam = expm(tau [w]x) R X + C + tau t``), each observed at its own image row; a
    fast hand-held camera (``w`` ~0.1 rad per unit r: ~5 rad/s at 0.02 s per unit r)."""
    R = Rotation.from_rotvec(rng.normal(0, 0.3, 3)).as_matrix()
    C = np.array([0.1, -0.2, 0.3]) + rng.normal(0, 0.3, 3)
    w, t = rng.normal(0, 0.1, 3), rng.normal(0, 0.05, 3)
    depth = np.zeros(n) if planar else rng.uniform(-1, 1, n)
    Xc = np.c_[rng.uniform(-1.2, 1.2, (n, 2)), 4.0 + depth]
    X = (Xc - C) @ R  # (R X + C = Xc)
    r = rng.uniform(-0.3, 0.3, n)
    for _ in range(30):  # the row each point is seen at (a fixed point)
        tau = r - r0
        P = Rotation.from_rotvec(tau[:, None] * w).apply(X @ R.T) + C + tau[:, None] * t
        x = P[:, :2] / P[:, 2:]
        r = x[:, 1]
    return x, X, r, r0, R, C, w, t


def _numpy_rows(x, X, r, r0, w):
    """The solver's equations built independently: ``E (expm(tau [w]x) (I + [v]x) X + C +
    tau t) = 0`` with ``E`` the first two rows of ``[x_hat]x``, linear in (v, C, t)."""
    A, b = [], []
    for i in range(len(x)):
        tau = r[i] - r0
        M = expm(tau * _skew(w))
        for E in (np.array([0.0, -1.0, x[i, 1]]), np.array([1.0, 0.0, -x[i, 0]])):
            A.append(np.r_[-(E @ M @ _skew(X[i])), E, tau * E])
            b.append(-E @ M @ X[i])
    return np.array(A), np.array(b)


@pytest.mark.parametrize("planar", [False, True])
def test_recovers_the_exact_model_from_noise_free_data(planar):
    rng = np.random.default_rng(7)
    errs = []
    for _ in range(40):
        x, X, r, r0, R, C, w, t = _exact_frame(rng, planar=planar)
        R_pre = Rotation.from_rotvec(rng.normal(0, 0.02, 3)).as_matrix() @ R
        s = r5p_w(x, X @ R_pre.T, w, r, r0, iterations=6)
        R_est = expm(_skew(s.v)) @ R_pre
        np.testing.assert_array_equal(s.w, w)
        errs.append(max(np.abs(R_est - R).max(), np.abs(s.C - C).max(), np.abs(s.t - t).max()))
    errs = np.array(errs)
    assert errs.max() < 1e-9, np.sort(errs)[-4:]


@pytest.mark.parametrize("n", [5, 12])
def test_one_solve_is_the_least_squares_solution_of_its_equations(n):
    rng = np.random.default_rng(n)
    x, X, r, r0, R, *_ = _exact_frame(rng, n=n)
    x = x + rng.normal(0, 1e-3, x.shape)  # (noisy: a least-squares problem for n > 5)
    w = rng.normal(0, 0.3, 3)
    Xp = X @ (Rotation.from_rotvec([0.01, -0.02, 0.015]).as_matrix() @ R).T
    A, b = _numpy_rows(x, Xp, r, r0, w)
    u = np.linalg.lstsq(A, b, rcond=None)[0]
    s = r5p_w(x, Xp, w, r, r0, iterations=1)
    # (v is returned as the rotation vector of expm([v]x): the same for one solve)
    np.testing.assert_allclose(s.v, u[:3], atol=1e-12)
    np.testing.assert_allclose(s.C, u[3:6], atol=1e-12)
    np.testing.assert_allclose(s.t, u[6:9], atol=1e-11)
    # the damped solve: with the prior rows P (w, t) = q and w fixed, P[:, 3:] t = q - P[:, :3] w
    P, q = rng.normal(size=(1, 6, 6)), rng.normal(size=(1, 6))
    Ap = np.vstack([A, np.c_[np.zeros((6, 6)), P[0][:, 3:]]])
    bp = np.r_[b, q[0] - P[0][:, :3] @ w]
    up = np.linalg.lstsq(Ap, bp, rcond=None)[0]
    sb = r5p_w_batch(x[None], Xp[None], w, r[None], r0, prior_rows=(P, q))
    assert sb.valid[0]
    np.testing.assert_allclose(np.r_[sb.v[0], sb.C[0], sb.t[0]], up, atol=1e-11)


def test_batch_and_the_fused_kernel_id_give_the_single_solutions():
    rng = np.random.default_rng(3)
    frames = [_exact_frame(rng) for _ in range(4)]
    x = np.stack([f[0] for f in frames])
    X = np.stack([f[1] @ f[4].T for f in frames])
    r = np.stack([f[2] for f in frames])
    w = np.stack([f[6] for f in frames])
    b = r5p_w_batch(x, X, w, r, 0.05, iterations=2)
    assert b.valid.all()
    for k in range(4):
        s = r5p_w(x[k], X[k], w[k], r[k], 0.05, iterations=2)
        np.testing.assert_allclose(np.r_[b.v[k], b.C[k], b.w[k], b.t[k]], np.r_[s.v, s.C, s.w, s.t])
    # the kernel RANSAC's fused batch runs for a frame with a gyro (w through v_init), as
    # r6p_1lin's kernel set holds it: same numbers
    out = np.zeros((4, MAX_PARAMS))
    ok, its, err = np.zeros(4, dtype=bool), np.zeros(4, dtype=np.int64), np.zeros(4)
    _run(kernel_set((0,), R5P_W), KNOWN_W, x, X, r, 0.05, 2, 1e-12, w, out, ok, its, err)
    assert ok.all()
    np.testing.assert_array_equal(out[:, :12], np.c_[b.v, b.C, b.w, b.t])


@njit
def _run(kernels, j, x, X, r, r0, iterations, tol, v_init, out, ok, its, err):
    run_kernels(kernels, j, x, X, r, r0, iterations, tol, v_init, out, ok, its, err)


def test_bad_input_is_rejected():
    rng = np.random.default_rng(4)
    x, X, r, r0, *_ = _exact_frame(rng, n=6)
    with pytest.raises(ValueError, match="r5p_w"):
        r5p_w(x[:4], X[:4], np.zeros(3), r[:4], r0)
    with pytest.raises(ValueError, match="w must be"):
        r5p_w(x, X, [0.0, np.nan, 0.0], r, r0)
    with pytest.raises(DegenerateInputError):  # all points on one 3D line
        line = np.outer(np.linspace(0, 1, 6), [1.0, 2.0, 0.5]) + [0, 0, 4]
        r5p_w(x, line, np.zeros(3), r, r0)
    b = r5p_w_batch(np.stack([x, x]), np.stack([X, np.zeros_like(X)]), np.zeros(3), None, r0)
    assert b.valid.tolist() == [True, False]
