"""R6P_{v,C,w,t}^{[v]x}: the linear iterative 6-point solver of paper sec. 3.3 (eq. 6).

Each iteration fixes ``v_hat`` only inside the nonlinear term ``[w]x [v]x`` of eq. 5 and
solves the remaining equations, linear in all 12 unknowns (v, C, w, t)::

    lambda_i x_hat_i = (I + tau_i [w]x) X_i + [v]x X_i + tau_i [w]x [v_hat]x X_i + C + tau_i t

with ``tau_i = r_i - r0``. The first iteration uses ``v_hat = v_init`` (default 0); each next one
takes ``v_hat`` from the previous estimate. A fixed point satisfies eq. 5 exactly.

Coefficient rows, for each elimination row E of point i (see ``_linear``), with
``Z = X + v_hat x X``:  ``[X x E | E | tau (Z x E) | tau E] . [v; C; w; t] = -E . X``.
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel
from ._common import RSBatch, RSSolution
from ._linear import (
    PATIENCE,
    cross_into,
    eq5_error,
    lstsq,
    rows_E,
    run_batch_with_prior,
    run_single,
)

__all__ = ["r6p_1lin", "r6p_1lin_batch"]


@kernel
def _solve(x, X, r, r0, iterations, tol, v_init, P, q, use_prior, out, ok, its, err):
    """The iteration of the module docstring for K problems; with ``use_prior`` each linear
    solve also takes the 6 rows ``P[k] (w, t) = q[k]`` (damped least squares, see
    :func:`r6p_1lin_batch`), so the system is (2N + 6) x 12."""
    K, N = x.shape[0], x.shape[1]
    n_rows = 2 * N + 6 if use_prior else 2 * N
    A = np.empty((n_rows, 12))
    b = np.empty(n_rows)
    u = np.zeros(12)
    E = np.empty((2, 3))
    vhat = np.empty(3)
    for k in range(K):
        for a in range(3):  # (element by element: see _so3.copy_matrix3)
            vhat[a] = v_init[k, a]
        best = np.inf
        stale = 0
        ok[k] = False
        its[k] = 0
        for it in range(iterations):
            for i in range(N):
                tau = r[k, i] - r0
                X0, X1, X2 = X[k, i, 0], X[k, i, 1], X[k, i, 2]
                Z0 = X0 + vhat[1] * X2 - vhat[2] * X1
                Z1 = X1 + vhat[2] * X0 - vhat[0] * X2
                Z2 = X2 + vhat[0] * X1 - vhat[1] * X0
                rows_E(x[k], i, E)
                for qq in range(2):
                    row = A[2 * i + qq]
                    e0, e1, e2 = E[qq, 0], E[qq, 1], E[qq, 2]
                    cross_into(X0, X1, X2, e0, e1, e2, row, 0)
                    row[3] = e0
                    row[4] = e1
                    row[5] = e2
                    cross_into(Z0, Z1, Z2, e0, e1, e2, row, 6)
                    row[6] *= tau
                    row[7] *= tau
                    row[8] *= tau
                    row[9] = tau * e0
                    row[10] = tau * e1
                    row[11] = tau * e2
                    b[2 * i + qq] = -(e0 * X0 + e1 * X1 + e2 * X2)
            if use_prior:
                for a in range(6):
                    row = A[2 * N + a]
                    for j in range(6):
                        row[j] = 0.0
                        row[6 + j] = P[k, a, j]
                    b[2 * N + a] = q[k, a]
            if not lstsq(A, b, u):
                break
            e = eq5_error(x[k], X[k], r[k], r0, u[0:3], u[3:6], u[6:9], u[9:12])
            its[k] = it + 1
            # stop when converged, or when the error has not improved on the best by more than
            # tol for PATIENCE iterations (the fixed-point error is not always monotone)
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
    # (no prior rows: the arguments of the same types as the prior path's, writable arrays
    # and a non-literal flag, so that both share one compiled _solve)
    no_P, no_q = np.zeros((1, 6, 6)), np.zeros((1, 6))
    _solve(x, X, r, r0, iterations, tol, v_init, no_P, no_q, np.bool_(False), out, ok, its, err)


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
    return run_single(_kernel, "r6p_1lin", 12, 6, x, X, r, r0, iterations, tol, v_init)


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
    return run_batch_with_prior(
        _kernel, _solve, "r6p_1lin", 6, x, X, r, r0, iterations, tol, v_init, prior_rows
    )
