"""R6P_{v,C}^{w,t}: linear alternating 6-point RS solver (paper sec. 3.1).

Each iteration fixes (w, t) and estimates (v, C) by R6P_{v,C}, then fixes (v, C) and estimates (w, t) by R6P_{w,t}. Starts from w = t = 0. The paper finds it unstable because pose and motion are never estimated together.
"""

from __future__ import annotations

from numba import njit

from ._linear import alternate, run_batch, run_single

__all__ = ["r6p_vC_wt", "r6p_vC_wt_batch"]


@njit(cache=True)
def _kernel(x, X, r, r0, iterations, tol, v_init, out, ok, its, err):
    alternate(x, X, r, r0, iterations, tol, False, True, out, ok, its, err)


def r6p_vC_wt(x, X, r=None, r0: float = 0.0, iterations: int = 5, tol: float = 1e-12):
    """R6P_{v,C}^{w,t} (paper sec. 3.1): alternating linear RS absolute pose.

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
    return run_single(_kernel, "r6p_vC_wt", 12, 6, x, X, r, r0, iterations, tol, None)


def r6p_vC_wt_batch(x, X, r=None, r0: float = 0.0, iterations: int = 5, tol: float = 1e-12):
    """Batched :func:`r6p_vC_wt`: x (K, N, 2), X (K, N, 3), r (K, N) -> :class:`RSBatch`
    (invalid problems flagged in valid, never raised). Raises ValueError on bad shapes."""
    return run_batch(_kernel, "r6p_vC_wt", 12, 6, x, X, r, r0, iterations, tol, None)
