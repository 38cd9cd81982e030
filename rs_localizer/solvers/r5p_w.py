"""R5P_{v,C,t}^{w}: the rolling-shutter absolute pose with the angular velocity known (a gyro).

With ``w`` given, eq. 5 of the paper is linear in the other unknowns (v, C, t) only: it is
the pose half-step of R6P_{v,C,t}^{w} (sec. 3.2) with ``w`` fixed, not alternated. Since
``w`` is known, its rotation during the readout need not be linearized either: the solver uses
the exact ``expm(tau [w]x)`` of eq. 4 where eq. 5 has ``I + tau [w]x`` (the same cost), and
keeps the product with ``[v]x``, so it is exact to first order in ``v`` alone::

    lambda_i x_hat_i = M_i (I + [v]x) X_i + C + tau_i t,   M_i = expm(tau_i [w]x)

with ``tau_i = r_i - r0``. For each elimination row E of point i (see ``_linear``),
``E . M (v x X) = (M^T E) . (v x X) = (X x M^T E) . v``, so the coefficient row is::

    [X x (M^T E) | E | tau E] . [v; C; t] = -E . (M X)

9 unknowns, two equations per point: 5 points (10 equations, least squares) instead of the 6
of the solvers that estimate ``w`` too. Each further iteration rotates the points by the
rotation found (``expm([v]x)``) and solves again for the remaining small rotation, so the
iteration converges to the exact solution of eq. 4 with the given ``w``.

``w`` is the model's angular velocity per unit r (docs/architecture.md "Conventions"): a
gyro's ``omega`` (rad/s, camera optical frame) is ``w = -omega * s`` with ``s`` the camera's
seconds per unit r (:attr:`rs_localizer.camera.CameraModel.seconds_per_unit_r`).
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel
from .._so3 import (
    copy_matrix3,
    rotate_left_into,
    rotate_small,
    rotation_log_into,
    so3_coefficients,
)
from ._common import RSBatch, RSSolution
from ._linear import lstsq, rows_E, run_batch_with_prior, run_single

__all__ = ["r5p_w", "r5p_w_batch"]


@kernel
def _solve(x, X, r, r0, iterations, tol, w_in, P, q, use_prior, out, ok, its, err):
    """The iteration of the module docstring for K problems with ``w_in[k]`` (K, 3) the known
    ``w``; with ``use_prior`` each solve also takes the 6 rows ``P[k] (w, t) = q[k]`` with
    ``w`` fixed, i.e. ``P[k][:, 3:] t = q[k] - P[k][:, :3] w`` (damped least squares on t)."""
    K, N = x.shape[0], x.shape[1]
    n_rows = 2 * N + 6 if use_prior else 2 * N
    A = np.empty((n_rows, 9))
    b = np.empty(n_rows)
    u = np.zeros(9)
    E = np.empty((2, 3))
    Rc = np.empty((3, 3))
    Rn = np.empty((3, 3))
    v = np.zeros(3)
    for k in range(K):
        w0, w1, w2 = w_in[k, 0], w_in[k, 1], w_in[k, 2]
        ok[k] = False
        its[k] = 0
        err[k] = np.inf
        for a in range(3):
            for c in range(3):
                Rc[a, c] = 1.0 if a == c else 0.0
        for it in range(iterations):
            for i in range(N):
                tau = r[k, i] - r0
                # Y = Rc X (the rotation found so far), MY = M Y
                Y0 = Rc[0, 0] * X[k, i, 0] + Rc[0, 1] * X[k, i, 1] + Rc[0, 2] * X[k, i, 2]
                Y1 = Rc[1, 0] * X[k, i, 0] + Rc[1, 1] * X[k, i, 1] + Rc[1, 2] * X[k, i, 2]
                Y2 = Rc[2, 0] * X[k, i, 0] + Rc[2, 1] * X[k, i, 1] + Rc[2, 2] * X[k, i, 2]
                a0, a1, a2 = tau * w0, tau * w1, tau * w2
                c1, c2, _ = so3_coefficients(a0 * a0 + a1 * a1 + a2 * a2)
                # M Y = Y + c1 a x Y + c2 a x (a x Y) (Rodrigues)
                h0, h1, h2 = a1 * Y2 - a2 * Y1, a2 * Y0 - a0 * Y2, a0 * Y1 - a1 * Y0
                M0 = Y0 + c1 * h0 + c2 * (a1 * h2 - a2 * h1)
                M1 = Y1 + c1 * h1 + c2 * (a2 * h0 - a0 * h2)
                M2 = Y2 + c1 * h2 + c2 * (a0 * h1 - a1 * h0)
                rows_E(x[k], i, E)
                for qq in range(2):
                    row = A[2 * i + qq]
                    e0, e1, e2 = E[qq, 0], E[qq, 1], E[qq, 2]
                    # m = M^T e = expm(-[a]x) e = e - c1 a x e + c2 a x (a x e)
                    g0, g1, g2 = a1 * e2 - a2 * e1, a2 * e0 - a0 * e2, a0 * e1 - a1 * e0
                    m0 = e0 - c1 * g0 + c2 * (a1 * g2 - a2 * g1)
                    m1 = e1 - c1 * g1 + c2 * (a2 * g0 - a0 * g2)
                    m2 = e2 - c1 * g2 + c2 * (a0 * g1 - a1 * g0)
                    row[0] = Y1 * m2 - Y2 * m1
                    row[1] = Y2 * m0 - Y0 * m2
                    row[2] = Y0 * m1 - Y1 * m0
                    row[3] = e0
                    row[4] = e1
                    row[5] = e2
                    row[6] = tau * e0
                    row[7] = tau * e1
                    row[8] = tau * e2
                    b[2 * i + qq] = -(e0 * M0 + e1 * M1 + e2 * M2)
            if use_prior:
                for a in range(6):
                    row = A[2 * N + a]
                    for j in range(6):
                        row[j] = 0.0
                    row[6] = P[k, a, 3]
                    row[7] = P[k, a, 4]
                    row[8] = P[k, a, 5]
                    b[2 * N + a] = q[k, a] - (P[k, a, 0] * w0 + P[k, a, 1] * w1 + P[k, a, 2] * w2)
            if not lstsq(A, b, u):
                break
            rotate_left_into(u[0], u[1], u[2], Rc, Rn)
            copy_matrix3(Rn, Rc)
            its[k] = it + 1
            ok[k] = True
            if u[0] * u[0] + u[1] * u[1] + u[2] * u[2] <= tol * tol:
                break
        if not ok[k]:
            continue
        rotation_log_into(Rc, v)
        for a in range(3):
            out[k, a] = v[a]
            out[k, 3 + a] = u[3 + a]
            out[k, 9 + a] = u[6 + a]
        out[k, 6] = w0
        out[k, 7] = w1
        out[k, 8] = w2
        # RMS algebraic error of eq. 4 with the exact rotations
        acc = 0.0
        for i in range(N):
            tau = r[k, i] - r0
            Y0 = Rc[0, 0] * X[k, i, 0] + Rc[0, 1] * X[k, i, 1] + Rc[0, 2] * X[k, i, 2]
            Y1 = Rc[1, 0] * X[k, i, 0] + Rc[1, 1] * X[k, i, 1] + Rc[1, 2] * X[k, i, 2]
            Y2 = Rc[2, 0] * X[k, i, 0] + Rc[2, 1] * X[k, i, 1] + Rc[2, 2] * X[k, i, 2]
            p0, p1, p2, _, _, _ = rotate_small(tau * w0, tau * w1, tau * w2, Y0, Y1, Y2)
            p0 += u[3] + tau * u[6]
            p1 += u[4] + tau * u[7]
            p2 += u[5] + tau * u[8]
            e1 = -p1 + x[k, i, 1] * p2
            e2 = p0 - x[k, i, 0] * p2
            acc += e1 * e1 + e2 * e2
        err[k] = np.sqrt(acc / N)


@kernel
def _kernel(x, X, r, r0, iterations, tol, v_init, out, ok, its, err):
    """The batched-kernel signature of ``_linear.run_batch``; ``v_init`` (K, 3) carries the
    known ``w`` of each problem (this solver has no other use for an initial ``v``)."""
    # (no prior rows: the arguments of the same types as the prior path's, writable arrays
    # and a non-literal flag, so that both share one compiled _solve)
    no_P, no_q = np.zeros((1, 6, 6)), np.zeros((1, 6))
    _solve(x, X, r, r0, iterations, tol, v_init, no_P, no_q, np.bool_(False), out, ok, its, err)


def _known_w(w, K: int) -> np.ndarray:
    a = np.asarray(w, dtype=float)
    if a.shape not in ((3,), (K, 3)) or not np.isfinite(a).all():
        raise ValueError(f"r5p_w: w must be 3 or ({K}, 3) finite numbers, got shape {a.shape}")
    return np.ascontiguousarray(np.broadcast_to(a, (K, 3)))


def r5p_w(
    x: np.ndarray,
    X: np.ndarray,
    w: np.ndarray,
    r: np.ndarray | None = None,
    r0: float = 0.0,
    iterations: int = 3,
    tol: float = 1e-12,
) -> RSSolution:
    """R5P_{v,C,t}^{w}: rolling-shutter absolute pose with a known angular velocity ``w``
    (paper eq. 5, linear in v, C, t once ``w`` is fixed; module docstring).

    Args:
        x: (N, 2) calibrated (undistorted, normalized) image points, N >= 5 (5 give 10
            equations for 9 unknowns: least squares).
        X: (N, 3) world points (any unit; C and t come out in it), best pre-rotated so that
            the remaining rotation ``v`` is small.
        w: (3,) the known angular velocity in rad per unit r (camera frame;
            ``w = -omega * seconds_per_unit_r`` for a gyro's ``omega`` in rad/s).
        r: (N,) RS coordinate of each observation (default ``x[:, 1]``). r0: reference.
        iterations: linear solves; each next one re-linearizes ``v`` at the previous
            rotation (the first alone is exact to first order in ``v``).
        tol: stop when the rotation update is at most ``tol`` (rad).
    Returns:
        :class:`RSSolution` with v (rad; the rotation is ``expm([v]x)`` on top of the
        points' frame), C, the given w, t (per unit r), the iterations that ran and the RMS
        algebraic error of eq. 4 (exact rotations).
    Raises:
        ValueError: wrong shapes, N < 5, NaN/inf input or ``w``, iterations < 1.
        DegenerateInputError (a ValueError): rank-deficient system (collinear, duplicated
            points).
    """
    return run_single(_kernel, "r5p_w", 12, 5, x, X, r, r0, iterations, tol, _known_w(w, 1))


def r5p_w_batch(
    x: np.ndarray,
    X: np.ndarray,
    w: np.ndarray,
    r: np.ndarray | None = None,
    r0: float = 0.0,
    iterations: int = 1,
    tol: float = 1e-12,
    prior_rows: tuple[np.ndarray, np.ndarray] | None = None,
) -> RSBatch:
    """Batched :func:`r5p_w` for K problems (RANSAC hypotheses).

    Args:
        x: (K, N, 2), X: (K, N, 3), r: (K, N) or None; w: (3,) or (K, 3) rad per unit r.
        iterations: linear solves per problem (default 1: one 10 x 9 solve on a minimal
            sample pre-rotated by P3P).
        prior_rows: ``None``, or ``(P (K, 6, 6), q (K, 6))`` rows of a linearized motion
            prior on ``(w, t)`` (as for :func:`rs_localizer.solvers.r6p_1lin_batch`); with
            ``w`` fixed they constrain ``t``: ``P[k][:, 3:] t = q[k] - P[k][:, :3] w`` is
            added to every solve (damped least squares).
    Returns:
        :class:`RSBatch` with (K, 3) v, C, w (the given one), t and a (K,) ``valid`` mask
        (False for rank loss or non-finite input, never raises for those).
    Raises:
        ValueError: wrong shapes or N < 5, a non-finite ``w``, or ``prior_rows`` not of
            shapes (K, 6, 6), (K, 6).
    """
    K = np.shape(x)[0]
    wk = _known_w(w, K)
    return run_batch_with_prior(
        _kernel, _solve, "r5p_w", 5, x, X, r, r0, iterations, tol, wk, prior_rows
    )
