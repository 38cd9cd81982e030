"""R6P_{v,C,t}^{w,t}: linear alternating 6-point RS solver (paper sec. 3.2).

Each iteration fixes w and estimates (v, C, t) by R6P_{v,C,t}, then keeps (v, C) and re-estimates
(w, t) together by R6P_{w,t}. Starts from w = 0.
"""

from __future__ import annotations

from .._jit import kernel
from ._linear import alternate, alternating_solver

__all__ = ["r6p_vCt_wt", "r6p_vCt_wt_batch"]


@kernel
def _kernel(x, X, r, r0, iterations, tol, v_init, out, ok, its, err):
    alternate(x, X, r, r0, iterations, tol, True, True, out, ok, its, err)


r6p_vCt_wt, r6p_vCt_wt_batch = alternating_solver(_kernel, "r6p_vCt_wt", "R6P_{v,C,t}^{w,t}", "3.2")
