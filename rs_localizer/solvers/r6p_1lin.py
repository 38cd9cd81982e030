"""R6P_{v,C,w,t}^{[v]x}: the linear iterative 6-point solver of paper sec. 3.3 (eq. 6).

Each iteration fixes ``v_hat`` only inside the nonlinear term ``[w]x [v]x`` of eq. 5 and
solves the remaining equations, linear in all 12 unknowns (v, C, w, t)::

    lambda_i x_hat_i = (I + tau_i [w]x) X_i + [v]x X_i + tau_i [w]x [v_hat]x X_i + C + tau_i t

with ``tau_i = r_i - r0``. The first iteration uses ``v_hat = v_init`` (default 0); each next one
takes ``v_hat`` from the previous estimate. A fixed point satisfies eq. 5 exactly.

Coefficient rows, for each elimination row E of point i (see ``_linear``), with
``Z = X + v_hat x X``:  ``[X x E | E | tau (Z x E) | tau E] . [v; C; w; t] = -E . X``.

One kernel (:func:`solve_mounted`, run by :func:`run_mounted`) solves it for a camera alone
and for a rig's cameras: each point seen through its camera's mounting ``x_cam = R_c x + c_c``
at its own time ``tau``, the rows ``F = R_c^T E`` and right-hand side ``-F . X - E . c_c``; a
camera alone is one mounting at the identity with ``tau = r - r0``, its rows the ones above to
the bit (a rig: :mod:`~.gr6p_1lin`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .._jit import kernel
from ._common import RSBatch, RSSolution, check_batch, check_inputs
from ._linear import (
    PATIENCE,
    cross_into,
    lstsq,
    run_batch_with_prior,
    run_single,
)

__all__ = ["mounted_error", "r6p_1lin", "r6p_1lin_batch", "run_mounted", "solve_mounted"]


@kernel
def mounted_error(x, X, tau, cam, Rm, cm, v, C, w, t):
    """RMS algebraic residual of eq. 5 for one problem whose points ``x`` (N, 2), ``X`` (N, 3)
    are seen at the times ``tau`` (N,) through the mountings ``Rm[cam]``, ``cm[cam]`` (the
    module docstring; a camera alone: one mounting at the identity, ``tau = r - r0``)."""
    n = x.shape[0]
    acc = 0.0
    for i in range(n):
        ti = tau[i]
        c = cam[i]
        y0 = X[i, 0] + v[1] * X[i, 2] - v[2] * X[i, 1]
        y1 = X[i, 1] + v[2] * X[i, 0] - v[0] * X[i, 2]
        y2 = X[i, 2] + v[0] * X[i, 1] - v[1] * X[i, 0]
        p0 = y0 + ti * (w[1] * y2 - w[2] * y1) + C[0] + ti * t[0]
        p1 = y1 + ti * (w[2] * y0 - w[0] * y2) + C[1] + ti * t[1]
        p2 = y2 + ti * (w[0] * y1 - w[1] * y0) + C[2] + ti * t[2]
        q0 = Rm[c, 0, 0] * p0 + Rm[c, 0, 1] * p1 + Rm[c, 0, 2] * p2 + cm[c, 0]
        q1 = Rm[c, 1, 0] * p0 + Rm[c, 1, 1] * p1 + Rm[c, 1, 2] * p2 + cm[c, 1]
        q2 = Rm[c, 2, 0] * p0 + Rm[c, 2, 1] * p1 + Rm[c, 2, 2] * p2 + cm[c, 2]
        e1 = -q1 + x[i, 1] * q2
        e2 = q0 - x[i, 0] * q2
        acc += e1 * e1 + e2 * e2
    return np.sqrt(acc / n)


@kernel
def solve_mounted(x, X, tau, cam, Rm, cm, iterations, tol, v_init, P, q, use_prior, out, ok, its,
                  err):  # fmt: skip
    """The iteration of the module docstring for K problems (x (K, N, 2), X (K, N, 3),
    tau (K, N), cam (K, N) indices into the mountings Rm (M, 3, 3), cm (M, 3)); with
    ``use_prior`` each linear solve also takes the 6 rows ``P[k] (w, t) = q[k]`` (damped least
    squares, see :func:`r6p_1lin_batch`), so the system is (2N + 6) x 12. The rows of a point
    seen at the identity mounting are those of the module docstring to the bit (``F = E``: the
    sums below in its order, ``1 * e + 0 * ...`` exact); a rig's cameras:
    :mod:`~.gr6p_1lin`."""
    K, N = x.shape[0], x.shape[1]
    n_rows = 2 * N + 6 if use_prior else 2 * N
    A = np.empty((n_rows, 12))
    b = np.empty(n_rows)
    u = np.zeros(12)
    F = np.empty((N, 2, 3))  # the elimination rows in the rig frame, R_c^T E
    d = np.empty((N, 2))  # -F . X - E . c_c (the part of the right-hand side without v_hat)
    vhat = np.empty(3)
    for k in range(K):
        for i in range(N):
            c = cam[k, i]
            xi, yi = x[k, i, 0], x[k, i, 1]
            X0, X1, X2 = X[k, i, 0], X[k, i, 1], X[k, i, 2]
            # E1 = [0, -1, y], E2 = [1, 0, -x]; F = R_c^T E (R_c = I: E itself, to the bit)
            for j in range(3):
                F[i, 0, j] = Rm[c, 0, j] * 0.0 + Rm[c, 1, j] * -1.0 + Rm[c, 2, j] * yi
                F[i, 1, j] = Rm[c, 0, j] * 1.0 + Rm[c, 1, j] * 0.0 + Rm[c, 2, j] * -xi
            ec0 = -cm[c, 1] + yi * cm[c, 2]
            ec1 = cm[c, 0] - xi * cm[c, 2]
            d[i, 0] = -(F[i, 0, 0] * X0 + F[i, 0, 1] * X1 + F[i, 0, 2] * X2) - ec0
            d[i, 1] = -(F[i, 1, 0] * X0 + F[i, 1, 1] * X1 + F[i, 1, 2] * X2) - ec1
        for a in range(3):
            vhat[a] = v_init[k, a]
        best = np.inf
        stale = 0
        ok[k] = False
        its[k] = 0
        for it in range(iterations):
            for i in range(N):
                ti = tau[k, i]
                X0, X1, X2 = X[k, i, 0], X[k, i, 1], X[k, i, 2]
                Z0 = X0 + vhat[1] * X2 - vhat[2] * X1
                Z1 = X1 + vhat[2] * X0 - vhat[0] * X2
                Z2 = X2 + vhat[0] * X1 - vhat[1] * X0
                for qq in range(2):
                    row = A[2 * i + qq]
                    f0, f1, f2 = F[i, qq, 0], F[i, qq, 1], F[i, qq, 2]
                    cross_into(X0, X1, X2, f0, f1, f2, row, 0)
                    row[3] = f0
                    row[4] = f1
                    row[5] = f2
                    cross_into(Z0, Z1, Z2, f0, f1, f2, row, 6)
                    row[6] *= ti
                    row[7] *= ti
                    row[8] *= ti
                    row[9] = ti * f0
                    row[10] = ti * f1
                    row[11] = ti * f2
                    b[2 * i + qq] = d[i, qq]
            if use_prior:
                for a in range(6):
                    row = A[2 * N + a]
                    for j in range(6):
                        row[j] = 0.0
                        row[6 + j] = P[k, a, j]
                    b[2 * N + a] = q[k, a]
            if not lstsq(A, b, u):
                break
            e = mounted_error(x[k], X[k], tau[k], cam[k], Rm, cm, u[0:3], u[3:6], u[6:9], u[9:12])
            its[k] = it + 1
            # stop when converged, or when the error has not improved on the best by more
            # than tol for PATIENCE iterations (the fixed-point error is not always monotone)
            stale = 0 if e < best - tol else stale + 1
            if e < best:
                best = e
                for a in range(12):
                    out[k, a] = u[a]
                ok[k] = True
            for a in range(3):
                vhat[a] = u[a]
            if e <= tol or stale >= PATIENCE:
                break
        err[k] = best


@kernel
def _kernel(x, X, r, r0, iterations, tol, v_init, out, ok, its, err):
    """:func:`solve_mounted` of one camera (K problems at ``r``, ``r0``; the kernel of the fused
    RANSAC batch, :mod:`.kernels`): ``tau = r - r0``, one mounting at the identity, no prior
    rows."""
    K, N = x.shape[0], x.shape[1]
    tau = np.empty((K, N))
    for k in range(K):
        for i in range(N):
            tau[k, i] = r[k, i] - r0
    cam = np.zeros((K, N), dtype=np.int64)
    Rm, cm = np.eye(3).reshape(1, 3, 3), np.zeros((1, 3))
    # (no prior rows: the arguments of the same types as the prior path's, writable arrays
    # and a non-literal flag, so that both share one compiled solve)
    no_P, no_q = np.zeros((1, 6, 6)), np.zeros((1, 6))
    solve_mounted(x, X, tau, cam, Rm, cm, iterations, tol, v_init, no_P, no_q, np.bool_(False),
                  out, ok, its, err)  # fmt: skip


#: :func:`solve_mounted`'s prior arguments without prior rows (as ``_kernel``'s)
_NO_PRIOR = (np.zeros((1, 6, 6)), np.zeros((1, 6)), np.bool_(False))


def run_mounted(name: str, batched: bool, solve: Callable, x: np.ndarray, X: np.ndarray,
                tau: np.ndarray, cam: np.ndarray, Rm: np.ndarray, cm: np.ndarray, iterations: int,
                tol: float, v_init: np.ndarray | None,
                prior_rows: tuple[np.ndarray, np.ndarray] | None = None,
                **single: str) -> RSSolution | RSBatch:  # fmt: skip
    """One problem (``batched`` False: :func:`~._linear.run_single` on it as a batch of one,
    with its keywords ``single``) or K (:func:`~._linear.run_batch_with_prior`) by ``solve``
    (:func:`solve_mounted`, or a function of its arguments) on points seen at the times
    ``tau`` (N,) or (K, N) through the mountings ``Rm[cam]``, ``cm[cam]`` (``cam`` int64 as
    ``tau``): a camera alone (:func:`r6p_1lin`, :func:`r6p_1lin_batch`) and a rig's cameras
    (:mod:`~.gr6p_1lin`). ``x``, ``X``, ``tau`` already checked by the caller."""
    cams = cam if batched else cam[None]

    def with_prior(x, X, tau, r0, iterations, tol, v_init, P, q, use, out, ok, its, err):
        solve(x, X, tau, cams, Rm, cm, iterations, tol, v_init, P, q, use, out, ok, its, err)

    def kernel(x, X, tau, r0, iterations, tol, v_init, out, ok, its, err):
        solve(x, X, tau, cams, Rm, cm, iterations, tol, v_init, *_NO_PRIOR, out, ok, its, err)

    if batched:
        return run_batch_with_prior(kernel, with_prior, name, 6, x, X, tau, 0.0, iterations, tol,
                                    v_init, prior_rows, checked=True)  # fmt: skip
    return run_single(kernel, name, 12, 6, x, X, tau, 0.0, iterations, tol, v_init, checked=True,
                      **single)  # fmt: skip


def _one_camera(batched, x, X, r, r0, iterations, tol, v_init, prior_rows=None):
    """:func:`run_mounted` of a camera alone: ``tau = r - r0``, one mounting at the identity."""
    x, X, r, r0 = (check_batch if batched else check_inputs)(x, X, r, r0, 6, "r6p_1lin")
    return run_mounted("r6p_1lin", batched, solve_mounted, x, X, r - r0,
                       np.zeros(r.shape, dtype=np.int64), np.eye(3).reshape(1, 3, 3),
                       np.zeros((1, 3)), iterations, tol, v_init, prior_rows)  # fmt: skip


def r6p_1lin(
    x: np.ndarray,
    X: np.ndarray,
    r: np.ndarray | None = None,
    r0: float = 0.0,
    iterations: int = 5,
    v_init: np.ndarray | None = None,
    tol: float = 1e-12,
) -> RSSolution:
    """R6P_{v,C,w,t}^{[v]x} (paper sec. 3.3): linear iterative RS absolute pose.

    Args:
        x: (N, 2) calibrated (undistorted, normalized) image points, N >= 6; N > 6 solves each
            iteration in the least-squares sense.
        X: (N, 3) world points (any unit; C and t come out in it).
        r: (N,) RS coordinate of each observation (default ``x[:, 1]``, top-to-bottom rows).
        r0: reference RS coordinate; all equations use ``r - r0``.
        iterations: maximum linear iterations (each one 2N x 12 system).
        v_init: (3,) initial ``v_hat`` for the nonlinear term (default zeros, as in the paper).
        tol: stop when the RMS algebraic error of eq. 5 is <= tol, or when it has not
            decreased by more than tol for 3 iterations (it need not fall monotonically).
    Returns:
        :class:`RSSolution` with v (rad), C, w (rad per unit r), t (per unit r), the iterations
        that ran and the algebraic error of eq. 5; the iterate with the lowest error is kept.

    Convergence: on noise-free minimal data the fixed point is the exact solution of eq. 5.
    The iteration converges in about 10 steps for moderate motion; for fast motion
    (|w| ~ 0.5 rad per unit r) a few percent of minimal instances converge slowly or not at
    all (measured in ``test_solvers.py``); RANSAC absorbs those.
    Raises:
        ValueError: wrong shapes, N < 6, NaN/inf input, iterations < 1.
        DegenerateInputError (a ValueError): rank-deficient system (collinear, duplicated points).
    """
    return _one_camera(False, x, X, r, r0, iterations, tol, v_init)


def r6p_1lin_batch(
    x: np.ndarray,
    X: np.ndarray,
    r: np.ndarray | None = None,
    r0: float = 0.0,
    iterations: int = 5,
    v_init: np.ndarray | None = None,
    tol: float = 1e-12,
    prior_rows: tuple[np.ndarray, np.ndarray] | None = None,
) -> RSBatch:
    """Batched :func:`r6p_1lin` for K problems (RANSAC hypotheses).

    Args:
        x: (K, N, 2), X: (K, N, 3), r: (K, N) or None, v_init: (3,) or (K, 3) or None.
        prior_rows: ``None``, or ``(P (K, 6, 6), q (K, 6))``: every linear solve then minimizes
            ``|A u - b|^2 + |P[k] (w, t) - q[k]|^2`` (damped / regularized least squares on the
            velocities; a linearized motion prior) instead of solving ``A u = b``.
            On near-degenerate samples (coplanar points, a small image extent) the plain
            solve lets (w, t) absorb noise without bound; the extra rows keep them near the
            prior. ``None`` runs the plain kernel (results bit-identical to before).
    Returns:
        :class:`RSBatch` with (K, 3) v, C, w, t and a (K,) ``valid`` mask (False for rank loss
        or non-finite input, never raises for those).
    Raises:
        ValueError: wrong shapes or N < 6, or ``prior_rows`` not of shapes (K, 6, 6), (K, 6).
    """
    return _one_camera(True, x, X, r, r0, iterations, tol, v_init, prior_rows)
