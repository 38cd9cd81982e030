"""Numba building blocks shared by the linear RS solvers (paper sec. 3).

Each correspondence gives two equations from eq. 5 after eliminating lambda with the first two
rows of ``[x_hat]x`` (``x_hat = [x, y, 1]``)::

    E1 = [0, -1, y],  E2 = [1, 0, -x],   E . p(X) = 0

where ``p`` is the right-hand side of eq. 5. Fixing some unknowns makes ``E . p`` linear in the
rest; with the triple-product identity ``E . (a x b) = a . (b x E)`` every coefficient row is
written with cross products. Every kernel solves its K problems in a loop with a Householder
least-squares (square for minimal samples, overdetermined otherwise) and reports rank loss.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .._jit import kernel
from .._linalg import solve_square
from .._so3 import INLINE
from ._common import DegenerateInputError, RSBatch, RSSolution, check_batch, check_inputs

RANK_TOL = 1e-10
#: iterations without a new lowest algebraic error before an iterative solver stops
PATIENCE = 3


@kernel(inline=INLINE)
def cross_into(a0, a1, a2, b0, b1, b2, out, j):
    out[j] = a1 * b2 - a2 * b1
    out[j + 1] = a2 * b0 - a0 * b2
    out[j + 2] = a0 * b1 - a1 * b0


@kernel
def lstsq(A, b, u):
    """Least squares ``min |A u - b|`` for A (m, n), m >= n (A, b overwritten): Gaussian
    elimination when square (minimal samples), Householder QR otherwise.

    Returns False (u untouched) if the numerical rank is below n.
    """
    m, n = A.shape
    if m == n:
        return solve_square(A, b, u, RANK_TOL)
    return householder_lstsq(A, b, u, 0.0)


@kernel
def householder_lstsq(A, b, u, unit):
    """:func:`lstsq`'s Householder QR of A (m, n), m > n (A, b overwritten; False, u
    untouched, if the numerical rank is below n).

    ``unit``: 0.0, or 1.0 for a system that also has unknowns held at zero by rows of their
    own (the identity on them, zero on A's columns, right-hand side zero: the rig solver's
    velocities on a rig frame taken at one time), which are left out of A: their pivots, of
    magnitude 1, join the rank test, and A's unknowns come out as the whole system's to the
    bit (QR of the whole system leaves those rows and columns apart: their products with
    A's entries are zeros)."""
    m, n = A.shape
    # Householder on the transpose so that every inner loop runs over contiguous memory
    At = np.ascontiguousarray(A.T)
    rmax = unit
    for k in range(n):
        col = At[k]
        s = 0.0
        for i in range(k, m):
            s += col[i] * col[i]
        nrm = np.sqrt(s)
        if nrm == 0.0:
            return False
        alpha = -nrm if col[k] > 0 else nrm
        v0 = col[k] - alpha
        vnorm2 = s - col[k] * col[k] + v0 * v0
        col[k] = v0
        if vnorm2 > 0.0:
            for j in range(k + 1, n):
                cj = At[j]
                d = 0.0
                for i in range(k, m):
                    d += col[i] * cj[i]
                f = 2.0 * d / vnorm2
                for i in range(k, m):
                    cj[i] -= f * col[i]
            d = 0.0
            for i in range(k, m):
                d += col[i] * b[i]
            f = 2.0 * d / vnorm2
            for i in range(k, m):
                b[i] -= f * col[i]
        col[k] = alpha
        if abs(alpha) > rmax:
            rmax = abs(alpha)
    if unit > 0.0 and unit <= RANK_TOL * rmax:
        return False
    for k in range(n):
        if abs(At[k, k]) <= RANK_TOL * rmax:
            return False
    for k in range(n - 1, -1, -1):
        s = b[k]
        for j in range(k + 1, n):
            s -= At[j, k] * u[j]
        u[k] = s / At[k, k]
    return True


@kernel
def eq5_error(x, X, r, r0, v, C, w, t):
    """RMS algebraic residual of eq. 5 for one problem (x (N,2), X (N,3), r (N,))."""
    n = x.shape[0]
    acc = 0.0
    for i in range(n):
        tau = r[i] - r0
        # Y = (I + [v]x) X
        y0 = X[i, 0] + v[1] * X[i, 2] - v[2] * X[i, 1]
        y1 = X[i, 1] + v[2] * X[i, 0] - v[0] * X[i, 2]
        y2 = X[i, 2] + v[0] * X[i, 1] - v[1] * X[i, 0]
        p0 = y0 + tau * (w[1] * y2 - w[2] * y1) + C[0] + tau * t[0]
        p1 = y1 + tau * (w[2] * y0 - w[0] * y2) + C[1] + tau * t[1]
        p2 = y2 + tau * (w[0] * y1 - w[1] * y0) + C[2] + tau * t[2]
        e1 = -p1 + x[i, 1] * p2
        e2 = p0 - x[i, 0] * p2
        acc += e1 * e1 + e2 * e2
    return np.sqrt(acc / n)


@kernel
def rows_E(x, i, E):
    """The two elimination rows for point i into E (2, 3)."""
    E[0, 0] = 0.0
    E[0, 1] = -1.0
    E[0, 2] = x[i, 1]
    E[1, 0] = 1.0
    E[1, 1] = 0.0
    E[1, 2] = -x[i, 0]


def lstsq_stack(
    A: np.ndarray, b: np.ndarray, normal_equations: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Least squares ``min |A[k] u - b[k]|`` of K systems A (K, m, 12), m >= 12, b (K, m) in
    NumPy (the NumPy implementations' linear solves): square systems (minimal samples) by
    NumPy's stacked LU solve (singular ones one by one, ``ok`` False); others by their normal
    equations solved so (``normal_equations``), else by NumPy's stacked Householder QR, ``ok``
    False where the triangular factor's smallest pivot is at most ``RANK_TOL`` times its
    largest (rank loss); ``ok`` False too where a value is not finite.
    Returns (u (K, 12), NaN where not ok; ok (K,))."""
    if normal_equations and A.shape[1] != A.shape[2]:
        A, b = np.einsum("kmi,kmj->kij", A, A), np.einsum("kmi,km->ki", A, b)
    u = np.full(b.shape[:1] + (12,), np.nan)
    ok = np.isfinite(A).all(axis=(1, 2)) & np.isfinite(b).all(axis=1)
    if not ok.any():
        return u, ok
    idx = np.flatnonzero(ok)
    if A.shape[1] == A.shape[2]:
        try:
            u[idx] = np.linalg.solve(A[idx], b[idx][..., None])[..., 0]
        except np.linalg.LinAlgError:  # (a singular system: solve them one by one)
            for k in idx:
                try:
                    u[k] = np.linalg.solve(A[k], b[k])
                except np.linalg.LinAlgError:
                    ok[k] = False
    else:
        Q, R = np.linalg.qr(A[idx])
        d = np.abs(np.diagonal(R, axis1=1, axis2=2))
        full = d.min(axis=1) > RANK_TOL * d.max(axis=1)
        rhs = np.einsum("kmi,km->ki", Q, b[idx])
        if full.any():
            u[idx[full]] = np.linalg.solve(R[full], rhs[full][..., None])[..., 0]
        ok[idx[~full]] = False
    ok &= np.isfinite(u).all(axis=1)
    return u, ok


def run_single(
    kernel: Callable,
    name: str,
    n_params: int,
    min_points: int,
    x: np.ndarray,
    X: np.ndarray,
    r: np.ndarray | None,
    r0: float,
    iterations: int,
    tol: float,
    v_init: np.ndarray | None,
    with_R_rs: bool = False,
    degenerate: str = "collinear, coplanar-degenerate or duplicated points?",
    checked: bool = False,
) -> RSSolution:
    """Validate one problem, run ``kernel`` on it as a batch of one, build an RSSolution
    (``degenerate``: the likely causes of rank loss, for the error message; ``checked``: x,
    X, r already checked as :func:`check_inputs` does, by the caller).

    Raises:
        ValueError: bad shapes, too few points, NaN/inf (from :func:`check_inputs`), or a
            non-positive iteration count.
        DegenerateInputError: the linear system lost rank (collinear/duplicated points...).
    """
    if not checked:
        x, X, r, r0 = check_inputs(x, X, r, r0, min_points, name)
    if iterations < 1:
        raise ValueError(f"{name}: iterations must be >= 1, got {iterations}")
    v0 = np.zeros((1, 3)) if v_init is None else np.asarray(v_init, dtype=float).reshape(1, 3)
    if not np.isfinite(v0).all():
        raise ValueError(f"{name}: v_init contains NaN or inf")
    out = np.zeros((1, n_params))
    ok = np.zeros(1, dtype=np.bool_)
    its = np.zeros(1, dtype=np.int64)
    err = np.zeros(1)
    kernel(x[None], X[None], r[None], r0, int(iterations), float(tol), v0, out, ok, its, err)
    if not ok[0] or not np.isfinite(out[0]).all():
        raise DegenerateInputError(
            f"{name}: the correspondences do not determine a solution (rank-deficient system; "
            f"{degenerate})"
        )
    u = out[0]
    return RSSolution(
        u[0:3],
        u[3:6],
        u[6:9],
        u[9:12],
        u[12:21].reshape(3, 3) if with_R_rs else None,
        int(its[0]),
        float(err[0]),
    )


def run_batch(
    kernel: Callable,
    name: str,
    n_params: int,
    min_points: int,
    x: np.ndarray,
    X: np.ndarray,
    r: np.ndarray | None,
    r0: float,
    iterations: int,
    tol: float,
    v_init: np.ndarray | None,
    with_R_rs: bool = False,
    checked: bool = False,
) -> RSBatch:
    """Batched counterpart of :func:`run_single`: x (K, N, 2), X (K, N, 3), r (K, N)
    (``checked``: already checked as :func:`check_batch` does, by the caller)."""
    if not checked:
        x, X, r, r0 = check_batch(x, X, r, r0, min_points, name)
    K = x.shape[0]
    if iterations < 1:
        raise ValueError(f"{name}: iterations must be >= 1, got {iterations}")
    v0 = (
        np.zeros((K, 3))
        if v_init is None
        # (a writable copy, as the fused batch passes: one compiled kernel for both)
        else np.array(np.broadcast_to(np.asarray(v_init, dtype=float), (K, 3)), order="C")
    )
    out = np.zeros((K, n_params))
    ok = np.zeros(K, dtype=np.bool_)
    its = np.zeros(K, dtype=np.int64)
    err = np.zeros(K)
    kernel(x, X, r, r0, int(iterations), float(tol), v0, out, ok, its, err)
    ok &= np.isfinite(out).all(axis=1)
    out[~ok] = 0.0
    return RSBatch(
        out[:, 0:3],
        out[:, 3:6],
        out[:, 6:9],
        out[:, 9:12],
        ok,
        its,
        err,
        out[:, 12:21].reshape(K, 3, 3) if with_R_rs else None,
    )


def run_batch_with_prior(
    kernel: Callable,
    solve: Callable,
    name: str,
    min_points: int,
    x: np.ndarray,
    X: np.ndarray,
    r: np.ndarray | None,
    r0: float,
    iterations: int,
    tol: float,
    v_init: np.ndarray | None,
    prior_rows: tuple[np.ndarray, np.ndarray] | None,
    checked: bool = False,
) -> RSBatch:
    """:func:`run_batch` of a 12-parameter solver whose linear solves can take the rows of a
    linearized motion prior on (w, t): ``kernel`` without them (``prior_rows`` None), else
    ``solve(x, X, r, r0, iterations, tol, v_init, P, q, True, out, ok, its, err)`` with
    ``P`` (K, 6, 6), ``q`` (K, 6) from ``prior_rows``.

    Raises:
        ValueError: as :func:`run_batch`, or ``prior_rows`` not of shapes (K, 6, 6), (K, 6).
    """
    if prior_rows is None:
        return run_batch(
            kernel, name, 12, min_points, x, X, r, r0, iterations, tol, v_init, checked=checked
        )
    P = np.ascontiguousarray(prior_rows[0], dtype=np.float64)
    q = np.ascontiguousarray(prior_rows[1], dtype=np.float64)
    K = np.shape(x)[0]
    if P.shape != (K, 6, 6) or q.shape != (K, 6):
        raise ValueError(
            f"{name}: prior_rows must have shapes ({K}, 6, 6) and ({K}, 6), "
            f"got {P.shape} and {q.shape}"
        )

    def with_prior(x, X, r, r0, iterations, tol, v_init, out, ok, its, err):
        solve(x, X, r, r0, iterations, tol, v_init, P, q, True, out, ok, its, err)

    return run_batch(
        with_prior, name, 12, min_points, x, X, r, r0, iterations, tol, v_init, checked=checked
    )


def alternating_solver(
    kernel: Callable, name: str, label: str, section: str
) -> tuple[Callable[..., RSSolution], Callable[..., RSBatch]]:
    """The public pair ``(solve, solve_batch)`` of an alternating solver (paper sec. 3.1/3.2):
    R6P_{v,C}^{w,t}, R6P_{v,C,t}^{w} and R6P_{v,C,t}^{w,t} differ only in the flags their
    ``kernel`` passes to :func:`alternate` (each paper solver's module defines its kernel and
    names the pair ``name`` and ``name + "_batch"``, defined in that module; ``label`` and
    ``section``: the paper's name and section, for the docstrings)."""

    def solve(x, X, r=None, r0: float = 0.0, iterations: int = 5, tol: float = 1e-12):
        return run_single(kernel, name, 12, 6, x, X, r, r0, iterations, tol, None)

    def solve_batch(x, X, r=None, r0: float = 0.0, iterations: int = 5, tol: float = 1e-12):
        return run_batch(kernel, name, 12, 6, x, X, r, r0, iterations, tol, None)

    solve.__doc__ = f"""{label} (paper sec. {section}): alternating linear RS absolute pose.

    Args:
        x: (N, 2) calibrated image points, N >= 6 (each half-step is a least-squares solve).
        X: (N, 3) world points. r: (N,) RS coordinates (default x[:, 1]). r0: reference.
        iterations: maximum alternations (one = both half-steps).
        tol: stop when the RMS algebraic error of eq. 5 is <= tol or decreased by <= tol.
    Returns:
        :class:`RSSolution` (v, C, w, t per unit r), iterations run, algebraic error of eq. 5;
        the iterate with the lowest error is kept.
    Raises:
        ValueError: wrong shapes, N < 6, NaN/inf, iterations < 1.
        DegenerateInputError (a ValueError): a half-step system lost rank.
    """
    solve_batch.__doc__ = f"""Batched :func:`{name}`: x (K, N, 2), X (K, N, 3), r (K, N) ->
    :class:`RSBatch` (invalid problems flagged in valid, never raised). Raises ValueError on bad
    shapes."""
    for fn, fn_name in ((solve, name), (solve_batch, name + "_batch")):
        fn.__name__ = fn.__qualname__ = fn_name
        fn.__module__ = kernel.__module__
    return solve, solve_batch


@kernel
def build_pose_step(x, X, r, r0, w, t, estimate_t, A, b):
    """Rows of the R6P_{v,C} / R6P_{v,C,t} half-steps (paper sec. 3.1, 3.2): w (and t) fixed.

    With ``M_i = I + tau_i [w]x``: ``E . p = E . M X + (M^T E) . (v x X) + E . C + tau E . t``,
    and ``M^T E = E - tau (w x E)``. Unknowns [v, C] or [v, C, t]; A has 6 or 9 columns.
    """
    N = x.shape[0]
    E = np.empty((2, 3))
    for i in range(N):
        tau = r[i] - r0
        X0, X1, X2 = X[i, 0], X[i, 1], X[i, 2]
        wx0 = w[1] * X2 - w[2] * X1
        wx1 = w[2] * X0 - w[0] * X2
        wx2 = w[0] * X1 - w[1] * X0
        rows_E(x, i, E)
        for q in range(2):
            row = A[2 * i + q]
            e0, e1, e2 = E[q, 0], E[q, 1], E[q, 2]
            m0 = e0 - tau * (w[1] * e2 - w[2] * e1)
            m1 = e1 - tau * (w[2] * e0 - w[0] * e2)
            m2 = e2 - tau * (w[0] * e1 - w[1] * e0)
            cross_into(X0, X1, X2, m0, m1, m2, row, 0)
            row[3] = e0
            row[4] = e1
            row[5] = e2
            rhs = e0 * (X0 + tau * wx0) + e1 * (X1 + tau * wx1) + e2 * (X2 + tau * wx2)
            if estimate_t:
                row[6] = tau * e0
                row[7] = tau * e1
                row[8] = tau * e2
            else:
                rhs += tau * (e0 * t[0] + e1 * t[1] + e2 * t[2])
            b[2 * i + q] = -rhs


@kernel
def build_motion_step(x, X, r, r0, v, C, t, estimate_t, A, b):
    """Rows of the R6P_{w,t} / R6P_{w} half-steps (paper sec. 3.1, 3.2): v, C (and t) fixed.

    With ``Y = (I + [v]x) X``: ``E . p = E . (Y + C) + tau (Y x E) . w + tau E . t``.
    Unknowns [w, t] or [w]; A has 6 or 3 columns.
    """
    N = x.shape[0]
    E = np.empty((2, 3))
    for i in range(N):
        tau = r[i] - r0
        X0, X1, X2 = X[i, 0], X[i, 1], X[i, 2]
        Y0 = X0 + v[1] * X2 - v[2] * X1 + C[0]
        Y1 = X1 + v[2] * X0 - v[0] * X2 + C[1]
        Y2 = X2 + v[0] * X1 - v[1] * X0 + C[2]
        y0, y1, y2 = Y0 - C[0], Y1 - C[1], Y2 - C[2]
        rows_E(x, i, E)
        for q in range(2):
            row = A[2 * i + q]
            e0, e1, e2 = E[q, 0], E[q, 1], E[q, 2]
            cross_into(y0, y1, y2, e0, e1, e2, row, 0)
            row[0] *= tau
            row[1] *= tau
            row[2] *= tau
            rhs = e0 * Y0 + e1 * Y1 + e2 * Y2
            if estimate_t:
                row[3] = tau * e0
                row[4] = tau * e1
                row[5] = tau * e2
            else:
                rhs += tau * (e0 * t[0] + e1 * t[1] + e2 * t[2])
            b[2 * i + q] = -rhs


@kernel
def alternate(x, X, r, r0, iterations, tol, pose_t, motion_t, out, ok, its, err):
    """Alternation of paper sec. 3.1/3.2 for K problems, starting from w = t = 0.

    ``pose_t``: the pose half-step estimates t too (R6P_{v,C,t}); ``motion_t``: the motion
    half-step estimates t too (R6P_{w,t}). The three solvers are
    R6P_{v,C}^{w,t} (False, True), R6P_{v,C,t}^{w} (True, False), R6P_{v,C,t}^{w,t} (True, True).
    """
    K, N = x.shape[0], x.shape[1]
    n1 = 9 if pose_t else 6
    n2 = 6 if motion_t else 3
    A1 = np.empty((2 * N, n1))
    b1 = np.empty(2 * N)
    u1 = np.zeros(n1)
    A2 = np.empty((2 * N, n2))
    b2 = np.empty(2 * N)
    u2 = np.zeros(n2)
    v = np.zeros(3)
    C = np.zeros(3)
    w = np.zeros(3)
    t = np.zeros(3)
    for k in range(K):
        w[:] = 0.0
        t[:] = 0.0
        best = np.inf
        stale = 0
        ok[k] = False
        its[k] = 0
        for it in range(iterations):
            build_pose_step(x[k], X[k], r[k], r0, w, t, pose_t, A1, b1)
            if not lstsq(A1, b1, u1):
                break
            v[:] = u1[0:3]
            C[:] = u1[3:6]
            if pose_t:
                t[:] = u1[6:9]
            build_motion_step(x[k], X[k], r[k], r0, v, C, t, motion_t, A2, b2)
            if not lstsq(A2, b2, u2):
                break
            w[:] = u2[0:3]
            if motion_t:
                t[:] = u2[3:6]
            e = eq5_error(x[k], X[k], r[k], r0, v, C, w, t)
            its[k] = it + 1
            # stop when converged, or when the error has not improved on the best by more than
            # tol for PATIENCE iterations (the fixed-point error is not always monotone)
            stale = 0 if e < best - tol else stale + 1
            if e < best:
                best = e
                out[k, 0:3] = v
                out[k, 3:6] = C
                out[k, 6:9] = w
                out[k, 9:12] = t
                ok[k] = True
            if e <= tol or stale >= PATIENCE:
                break
        err[k] = best
