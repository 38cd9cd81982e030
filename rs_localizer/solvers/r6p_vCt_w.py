"""R6P_{v,C,t}^{w}: linear alternating 6-point RS solver (paper sec. 3.2).

Each iteration fixes w and estimates (v, C, t) by R6P_{v,C,t} (12 equations, 9 unknowns), then
fixes (v, C, t) and estimates w by R6P_{w} (3 unknowns). Starts from w = 0. Best for (near) pure
translational motion.
"""

from __future__ import annotations

from .._jit import kernel
from ._linear import alternate, alternating_solver

__all__ = ["r6p_vCt_w", "r6p_vCt_w_batch"]


@kernel
def _kernel(x, X, r, r0, iterations, tol, v_init, out, ok, its, err):
    alternate(x, X, r, r0, iterations, tol, True, False, out, ok, its, err)


r6p_vCt_w, r6p_vCt_w_batch = alternating_solver(_kernel, "r6p_vCt_w", "R6P_{v,C,t}^{w}", "3.2")
