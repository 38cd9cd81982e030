"""The batched solver kernels behind one numba entry point, so that compiled callers (RANSAC's
fused batch in :mod:`rs_localizer.estimation.batch`) can run any of them by an integer id.

Every kernel has the signature of ``_linear.run_batch``'s kernels::

    kernel(x (K, N, 2), X (K, N, 3), r (K, N), r0, iterations, tol, v_init (K, 3),
           out (K, >= n_params), ok (K,), its (K,), err (K,))

and writes ``out[:, 0:12] = (v, C, w, t)`` (R9P also its ``R_rs`` to ``out[:, 12:21]``). numba
does not cache functions that take other compiled functions as arguments, so the dispatch is
an explicit branch on the id here (all kernels are compiled into :func:`run_kernel`, once,
and cached).
"""

from __future__ import annotations

import sys

from numba import njit

from .r5p_w import r5p_w_batch
from .r6p_1lin import r6p_1lin_batch
from .r6p_vC_wt import r6p_vC_wt_batch
from .r6p_vCt_w import r6p_vCt_w_batch
from .r6p_vCt_wt import r6p_vCt_wt_batch
from .registry import SOLVERS

__all__ = ["MAX_PARAMS", "R5P_W", "kernel_ids", "run_kernel"]


def _module(name):
    # ``rs_localizer.solvers`` re-exports functions under the module names (``r6p_1lin`` is a
    # function there), so take the modules themselves from sys.modules
    return sys.modules[f"{__package__}.{name}"]


_k_1lin = _module("r6p_1lin")._kernel
_k_vC_wt = _module("r6p_vC_wt")._kernel
_k_vCt_w = _module("r6p_vCt_w")._kernel
_k_vCt_wt = _module("r6p_vCt_wt")._kernel
_k_r9p = _module("r9p")._kernel
_k_r5p_w = _module("r5p_w")._kernel

#: kernel id of R5P_{v,C,t}^{w} (the angular velocity known, e.g. from a gyro: its ``v_init``
#: rows carry that ``w``); not a registry solver, RANSAC uses it when a gyro is given
R5P_W = 5

#: widest ``out`` row any kernel writes (R9P: v, C, w, t and the 3x3 R_rs)
MAX_PARAMS = 21

#: batched function (as listed in :attr:`SolverInfo.batch`) -> (kernel id, parameters written,
#: fewest points)
_IDS = {
    r6p_1lin_batch: (0, 12, 6),
    r6p_vC_wt_batch: (1, 12, 6),
    r6p_vCt_w_batch: (2, 12, 6),
    r6p_vCt_wt_batch: (3, 12, 6),
    SOLVERS["r9p"].batch[0]: (4, 21, 9),  # the registry's gauge-fixed r9p_batch wrapper
    r5p_w_batch: (R5P_W, 12, 5),
}


def kernel_ids(name: str) -> tuple[tuple[int, int, int], ...] | None:
    """``((id, n_params, min_points), ...)`` of the batched kernels of solver ``name`` (kernel
    id for :func:`run_kernel`, parameters it writes, fewest points it accepts) in the order of its
    registry entry's ``batch`` tuple (two for the joined solver), or ``None`` if the solver has
    no batched kernels (``p3p``, ``r6p``) or one that :func:`run_kernel` does not know.

    Raises ValueError for an unknown solver."""
    from .registry import solver_info

    batch = solver_info(name).batch
    if not batch or any(fn not in _IDS for fn in batch):
        return None
    return tuple(_IDS[fn] for fn in batch)


@njit(cache=True)
def run_kernel(kind, x, X, r, r0, iterations, tol, v_init, out, ok, its, err):
    """Run batched kernel ``kind`` (an id from :func:`kernel_ids`) on K problems; arguments as
    the kernels' (module docstring); N must be at least the kernel's ``min_points`` (not
    checked here: the kernels do not check it either). Unknown ids leave ``ok`` False."""
    if kind == 0:
        _k_1lin(x, X, r, r0, iterations, tol, v_init, out, ok, its, err)
    elif kind == 1:
        _k_vC_wt(x, X, r, r0, iterations, tol, v_init, out, ok, its, err)
    elif kind == 2:
        _k_vCt_w(x, X, r, r0, iterations, tol, v_init, out, ok, its, err)
    elif kind == 3:
        _k_vCt_wt(x, X, r, r0, iterations, tol, v_init, out, ok, its, err)
    elif kind == 4:
        _k_r9p(x, X, r, r0, iterations, tol, v_init, out, ok, its, err)
    elif kind == R5P_W:
        _k_r5p_w(x, X, r, r0, iterations, tol, v_init, out, ok, its, err)
    else:
        ok[:] = False
