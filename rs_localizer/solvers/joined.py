"""The "joined solver" of paper sec. 4.1 (translational motion).

R6P_{v,C,t}^{w} is best when the motion is (nearly) a pure translation, R6P_{v,C,w,t}^{[v]x}
otherwise; the joined solver runs both and keeps the one with the lower reprojection error.
On a minimal sample both usually fit the six points exactly, so the choice is only informative
with more than six points; the robust estimator therefore scores both hypotheses on all points.
"""

from __future__ import annotations

import numpy as np

from ..geometry import rs_project_linear
from ._common import DegenerateInputError, RSSolution, check_inputs
from .r6p_1lin import r6p_1lin
from .r6p_vCt_w import r6p_vCt_w

__all__ = ["r6p_joined", "rs_reprojection_rmse"]


def rs_reprojection_rmse(
    sol: RSSolution,
    x: np.ndarray,
    X: np.ndarray,
    r0: float = 0.0,
    readout: np.ndarray | None = None,
) -> float:
    """RMS reprojection error (normalized units) of a solution under eq. 5's closed-form
    projection (:func:`rs_localizer.geometry.rs_project_linear` with ``R = I + [v]x``)."""
    xp, _ = rs_project_linear(X, sol.R_linear, sol.C, sol.w, sol.t, r0, readout)
    e = np.sum((xp - x) ** 2, axis=1)
    return float(np.sqrt(np.mean(e))) if np.isfinite(e).all() else float("inf")


def r6p_joined(
    x: np.ndarray,
    X: np.ndarray,
    r: np.ndarray | None = None,
    r0: float = 0.0,
    iterations: int = 5,
    tol: float = 1e-12,
) -> RSSolution:
    """Joined solver: :func:`r6p_vCt_w` and :func:`r6p_1lin`, the lower reprojection error wins.

    Args:
        x: (N, 2) calibrated image points, N >= 6. X: (N, 3) world points.
        r: (N,) RS coordinates (default ``x[:, 1]``; the reprojection error assumes
            ``r = y``, i.e. top-to-bottom readout of undistorted points). r0: reference.
        iterations, tol: passed to both solvers.
    Returns:
        the winning :class:`RSSolution`.
    Raises:
        ValueError: wrong shapes, N < 6, NaN/inf.
        DegenerateInputError: neither solver found a solution.
    """
    x, X, r, r0 = check_inputs(x, X, r, r0, 6, "r6p_joined")
    best, best_err = None, np.inf
    for solver in (r6p_vCt_w, r6p_1lin):
        try:
            sol = solver(x, X, r, r0, iterations=iterations, tol=tol)
        except DegenerateInputError:
            continue
        err = rs_reprojection_rmse(sol, x, X, r0)
        if best is None or err < best_err:
            best, best_err = sol, err
    if best is None:
        raise DegenerateInputError("r6p_joined: both solvers failed on degenerate input")
    return best
