"""R6P_{v,C}^{w,t}: linear alternating 6-point RS solver (paper sec. 3.1).

Each iteration fixes (w, t) and estimates (v, C) by R6P_{v,C}, then fixes (v, C) and estimates
(w, t) by R6P_{w,t}. Starts from w = t = 0. The paper finds it unstable because pose and motion are
never estimated together.
"""

from __future__ import annotations

from .._jit import kernel
from ._linear import alternate, alternating_solver

__all__ = ["r6p_vC_wt", "r6p_vC_wt_batch"]


@kernel
def _kernel(x, X, r, r0, iterations, tol, v_init, out, ok, its, err):
    alternate(x, X, r, r0, iterations, tol, False, True, out, ok, its, err)


r6p_vC_wt, r6p_vC_wt_batch = alternating_solver(_kernel, "r6p_vC_wt", "R6P_{v,C}^{w,t}", "3.1")
