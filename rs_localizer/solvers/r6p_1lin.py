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
from numba import njit

from ._linear import PATIENCE, cross_into, eq5_error, lstsq, rows_E, run_batch, run_single

__all__ = ["r6p_1lin", "r6p_1lin_batch"]


@njit(cache=True)
def _kernel(x, X, r, r0, iterations, tol, v_init, out, ok, its, err):
    K, N = x.shape[0], x.shape[1]
    A = np.empty((2 * N, 12))
    b = np.empty(2 * N)
    u = np.zeros(12)
    E = np.empty((2, 3))
    vhat = np.empty(3)
    for k in range(K):
        vhat[:] = v_init[k]
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
                for q in range(2):
                    row = A[2 * i + q]
                    e0, e1, e2 = E[q, 0], E[q, 1], E[q, 2]
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
                    b[2 * i + q] = -(e0 * X0 + e1 * X1 + e2 * X2)
            if not lstsq(A, b, u):
                break
            e = eq5_error(x[k], X[k], r[k], r0, u[0:3], u[3:6], u[6:9], u[9:12])
            its[k] = it + 1
            # stop when converged, or when the error has not improved on the best by more than
            # tol for PATIENCE iterations (the fixed-point error is not always monotone)
            stale = 0 if e < best - tol else stale + 1
            if e < best:
                best = e
                out[k, :12] = u
                ok[k] = True
            vhat[:] = u[0:3]
            if e <= tol or stale >= PATIENCE:
                break
        err[k] = best


def r6p_1lin(x, X, r=None, r0: float = 0.0, iterations: int = 5, v_init=None, tol: float = 1e-12):
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


def r6p_1lin_batch(x, X, r=None, r0: float = 0.0, iterations: int = 5, v_init=None,
                   tol: float = 1e-12):
    """Batched :func:`r6p_1lin` for K problems (RANSAC hypotheses).

    Args:
        x: (K, N, 2), X: (K, N, 3), r: (K, N) or None, v_init: (3,) or (K, 3) or None.
    Returns:
        :class:`RSBatch` with (K, 3) v, C, w, t and a (K,) ``valid`` mask (False for rank loss
        or non-finite input, never raises for those).
    Raises:
        ValueError: wrong shapes or N < 6.
    """
    return run_batch(_kernel, "r6p_1lin", 12, 6, x, X, r, r0, iterations, tol, v_init)
