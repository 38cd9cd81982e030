"""R9P: the linear non-iterative 9-point RS solver (paper sec. 3.4, eq. 8).

Eq. 5 rewritten as eq. 8 and with ``[w]x (I + [v]x)`` replaced by a general 3x3 ``R_rs``::

    lambda_i x_hat_i = (I + [v]x) X_i + C + tau_i (R_rs X_i + t)

is linear in 18 unknowns (v, C, t and the 9 entries of R_rs); two independent equations per
point need N >= 9. Coefficient rows for each elimination row E (see ``_linear``)::

    [X x E | E | tau E | tau (E (x) X)] . [v; C; t; vec(R_rs)] = -E . X

(``vec`` row-major). The paper stops at R_rs; we also recover the angular velocity: since
``R_rs = [w]x (I + [v]x)``, ``[w]x ~ R_rs (I + [v]x)^-1`` and ``w`` is the vector of the
projection of that matrix onto the skew-symmetric matrices, ``(M - M^T) / 2``.

Degeneracy (not in the paper): on global-shutter data (no motion) every
``R_rs = b (I + [v]x), t = b C`` explains the observations for any scalar ``b`` (the RS term is
then parallel to the point itself and only rescales lambda), so the system loses rank. v, C
and the recovered w (the skew part of ``b I`` is zero) are still determined; t is not. Exact
global-shutter input raises :class:`DegenerateInputError`. Near it the least-squares solution
drifts along that line with the noise, so by default we return the member of the line
``(R_rs + b (I + [v]x), t + b C)`` with ``trace(R_rs (I + [v]x)^-1) = 0``, which the model
``R_rs = [w]x (I + [v]x)`` satisfies exactly (a gauge choice: on moving cameras the shift is at
the noise level; near a global shutter it removes the noise-driven t).
``gauge_fix=False`` returns the raw least-squares solution of eq. 8.
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel
from ._common import RSBatch, RSSolution
from ._linear import cross_into, lstsq, rows_E, run_batch, run_single

__all__ = ["r9p", "r9p_batch"]


@kernel
def _eq8_error(x, X, r, r0, u):
    n = x.shape[0]
    acc = 0.0
    p = np.empty(3)
    for i in range(n):
        tau = r[i] - r0
        X0, X1, X2 = X[i, 0], X[i, 1], X[i, 2]
        p[0] = (
            X0 + u[1] * X2 - u[2] * X1 + u[3] + tau * (u[12] * X0 + u[13] * X1 + u[14] * X2 + u[6])
        )
        p[1] = (
            X1 + u[2] * X0 - u[0] * X2 + u[4] + tau * (u[15] * X0 + u[16] * X1 + u[17] * X2 + u[7])
        )
        p[2] = (
            X2 + u[0] * X1 - u[1] * X0 + u[5] + tau * (u[18] * X0 + u[19] * X1 + u[20] * X2 + u[8])
        )
        e1 = -p[1] + x[i, 1] * p[2]
        e2 = p[0] - x[i, 0] * p[2]
        acc += e1 * e1 + e2 * e2
    return np.sqrt(acc / n)


@kernel
def _kernel(x, X, r, r0, iterations, tol, v_init, out, ok, its, err):
    _solve(x, X, r, r0, True, out, ok, its, err)


@kernel
def _kernel_raw(x, X, r, r0, iterations, tol, v_init, out, ok, its, err):
    _solve(x, X, r, r0, False, out, ok, its, err)


@kernel
def _solve(x, X, r, r0, gauge_fix, out, ok, its, err):
    K, N = x.shape[0], x.shape[1]
    A = np.empty((2 * N, 18))
    b = np.empty(2 * N)
    s = np.zeros(18)
    u = np.zeros(21)  # v, C, t, R_rs (solver order) -> out order v, C, w, t, R_rs
    E = np.empty((2, 3))
    Vi = np.empty((3, 3))
    M = np.empty((3, 3))
    for k in range(K):
        ok[k] = False
        its[k] = 0
        for i in range(N):
            tau = r[k, i] - r0
            X0, X1, X2 = X[k, i, 0], X[k, i, 1], X[k, i, 2]
            rows_E(x[k], i, E)
            for q in range(2):
                row = A[2 * i + q]
                e0, e1, e2 = E[q, 0], E[q, 1], E[q, 2]
                cross_into(X0, X1, X2, e0, e1, e2, row, 0)
                row[3] = e0
                row[4] = e1
                row[5] = e2
                row[6] = tau * e0
                row[7] = tau * e1
                row[8] = tau * e2
                for j in range(3):
                    ej = tau * E[q, j]
                    row[9 + 3 * j] = ej * X0
                    row[10 + 3 * j] = ej * X1
                    row[11 + 3 * j] = ej * X2
                b[2 * i + q] = -(e0 * X0 + e1 * X1 + e2 * X2)
        if not lstsq(A, b, s):
            err[k] = np.inf
            continue
        # reorder: u = [v, C, t, (unused 3), R_rs] for _eq8_error
        u[0:9] = s[0:9]
        u[12:21] = s[9:18]
        err[k] = _eq8_error(x[k], X[k], r[k], r0, u)
        # M = R_rs (I + [v]x)^-1, with the closed-form inverse of V = I + [v]x:
        # V^-1 = (I - [v]x + v v^T) / (1 + |v|^2)
        v0, v1, v2 = s[0], s[1], s[2]
        den = 1.0 + v0 * v0 + v1 * v1 + v2 * v2
        Vi[0, 0] = (1.0 + v0 * v0) / den
        Vi[0, 1] = (v2 + v0 * v1) / den
        Vi[0, 2] = (-v1 + v0 * v2) / den
        Vi[1, 0] = (-v2 + v1 * v0) / den
        Vi[1, 1] = (1.0 + v1 * v1) / den
        Vi[1, 2] = (v0 + v1 * v2) / den
        Vi[2, 0] = (v1 + v2 * v0) / den
        Vi[2, 1] = (-v0 + v2 * v1) / den
        Vi[2, 2] = (1.0 + v2 * v2) / den
        for i in range(3):
            for j in range(3):
                M[i, j] = (
                    s[9 + 3 * i] * Vi[0, j] + s[10 + 3 * i] * Vi[1, j] + s[11 + 3 * i] * Vi[2, j]
                )
        out[k, 0:3] = s[0:3]
        out[k, 3:6] = s[3:6]
        out[k, 6] = 0.5 * (M[2, 1] - M[1, 2])
        out[k, 7] = 0.5 * (M[0, 2] - M[2, 0])
        out[k, 8] = 0.5 * (M[1, 0] - M[0, 1])
        out[k, 9:12] = s[6:9]
        out[k, 12:21] = s[9:18]
        if gauge_fix:
            # move along (R_rs + b V, t + b C) to trace(R_rs V^-1) = 0 (module docstring)
            beta = -(M[0, 0] + M[1, 1] + M[2, 2]) / 3.0
            out[k, 9:12] += beta * s[3:6]
            out[k, 12] += beta
            out[k, 13] += beta * v2 * -1.0
            out[k, 14] += beta * v1
            out[k, 15] += beta * v2
            out[k, 16] += beta
            out[k, 17] += beta * -v0
            out[k, 18] += beta * -v1
            out[k, 19] += beta * v0
            out[k, 20] += beta
        ok[k] = True


def r9p(
    x: np.ndarray,
    X: np.ndarray,
    r: np.ndarray | None = None,
    r0: float = 0.0,
    gauge_fix: bool = True,
) -> RSSolution:
    """R9P (paper sec. 3.4, eq. 8): linear, non-iterative, 9 or more correspondences.

    Args:
        x: (N, 2) calibrated image points, N >= 9 (least squares for N > 9).
        X: (N, 3) world points. r: (N,) RS coordinates (default ``x[:, 1]``). r0: reference.
        gauge_fix: return the trace-free member of the near-degenerate line (module
            docstring); False gives the raw least-squares solution of eq. 8.
    Returns:
        :class:`RSSolution` with v, C, t, the general (3, 3) ``R_rs`` of eq. 8, and ``w``
        recovered as the skew-symmetric part of ``R_rs (I + [v]x)^-1``; ``algebraic_error`` is
        the RMS residual of eq. 8.
    Raises:
        ValueError: wrong shapes, N < 9, NaN/inf.
        DegenerateInputError (a ValueError): rank-deficient 2N x 18 system.
    """
    return run_single(
        _kernel if gauge_fix else _kernel_raw,
        "r9p",
        21,
        9,
        x,
        X,
        r,
        r0,
        1,
        0.0,
        None,
        with_R_rs=True,
    )


def r9p_batch(
    x: np.ndarray,
    X: np.ndarray,
    r: np.ndarray | None = None,
    r0: float = 0.0,
    gauge_fix: bool = True,
) -> RSBatch:
    """Batched :func:`r9p`: x (K, N, 2), X (K, N, 3), r (K, N) -> :class:`RSBatch` with
    ``R_rs`` (K, 3, 3); invalid problems flagged in ``valid``. Raises ValueError on bad shapes."""
    return run_batch(
        _kernel if gauge_fix else _kernel_raw,
        "r9p",
        21,
        9,
        x,
        X,
        r,
        r0,
        1,
        0.0,
        None,
        with_R_rs=True,
    )
