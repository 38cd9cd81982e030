"""The batched solver kernels behind one numba entry point, so that compiled callers (RANSAC's
fused batch in :mod:`rs_localizer.estimation.batch`) can run any of them.

Every kernel has the signature of ``_linear.run_batch``'s kernels::

    kernel(x (K, N, 2), X (K, N, 3), r (K, N), r0, iterations, tol, v_init (K, 3),
           out (K, >= n_params), ok (K,), its (K,), err (K,))

and writes ``out[:, 0:12] = (v, C, w, t)`` (R9P also its ``R_rs`` to ``out[:, 12:21]``).

A solver's kernels travel into compiled code as a :class:`KernelSet`, whose numba type
carries the kernel ids. A caller is compiled once per kernel set, and each compiled version
contains only the kernels of its set: the default node compiles R6P_{v,C,w,t}^{[v]x} alone,
not every solver of the package (compiling them all into one branch on a runtime id took
about three times as long). numba does not cache functions that take other compiled
functions as arguments; a type that names the kernels is cached like any other argument type.
"""

from __future__ import annotations

import functools
import sys

import numpy as np
from numba import types
from numba.core.imputils import lower_constant
from numba.extending import NativeValue, models, overload, register_model, unbox

from .._jit import kernel
from .r5p_w import r5p_w_batch
from .r6p_1lin import r6p_1lin_batch
from .r6p_vC_wt import r6p_vC_wt_batch
from .r6p_vCt_w import r6p_vCt_w_batch
from .r6p_vCt_wt import r6p_vCt_wt_batch
from .registry import SOLVERS

__all__ = [
    "KNOWN_W",
    "MAX_PARAMS",
    "R5P_W",
    "KernelSet",
    "compile_kernel_set",
    "kernel_count",
    "kernel_ids",
    "kernel_set",
    "run_kernels",
]


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

#: the kernel index of :func:`run_kernels` that runs a set's known-angular-velocity kernel
KNOWN_W = -1

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


#: kernel id -> kernel
_KERNELS = {0: _k_1lin, 1: _k_vC_wt, 2: _k_vCt_w, 3: _k_vCt_wt, 4: _k_r9p, R5P_W: _k_r5p_w}


class KernelSetType(types.Type):
    """The numba type of a :class:`KernelSet`: its kernel ids are part of the type, so a
    compiled caller is specialized (and cached) per set."""

    def __init__(self, ids: tuple[int, ...], known_w: int | None = None):
        self.ids = tuple(int(i) for i in ids)
        self.known_w = None if known_w is None else int(known_w)
        extra = "" if self.known_w is None else f"+{self.known_w}"
        super().__init__(name=f"KernelSet{self.ids}{extra}")


register_model(KernelSetType)(models.OpaqueModel)


@unbox(KernelSetType)
def _unbox_kernel_set(typ, obj, c):
    # everything is in the type; the value itself carries nothing
    return NativeValue(c.context.get_dummy_value())


@lower_constant(KernelSetType)
def _constant_kernel_set(context, builder, ty, pyval):
    # (a set as a global constant of compiled code: nothing to carry either)
    return context.get_dummy_value()


class KernelSet:
    """Batched kernels to run, by id (:func:`kernel_ids`), as an argument of compiled code
    (:func:`run_kernels`, :func:`kernel_count`), and optionally the kernel that solves the
    same samples with the angular velocity known (``known_w``: :data:`R5P_W`, run as index
    :data:`KNOWN_W`: a frame with a gyro uses the same compiled batch). Immutable; use
    :func:`kernel_set` to share one instance per set.

    Raises ValueError for an id that has no kernel.
    """

    __slots__ = ("_numba_type_", "ids", "known_w")

    def __init__(self, ids: tuple[int, ...], known_w: int | None = None):
        ids = tuple(int(i) for i in ids)
        unknown = [i for i in (*ids, *(() if known_w is None else (known_w,))) if i not in _KERNELS]
        if unknown:
            raise ValueError(f"no batched kernel with id {unknown}; known: {sorted(_KERNELS)}")
        self.ids = ids
        self.known_w = None if known_w is None else int(known_w)
        self._numba_type_ = KernelSetType(ids, self.known_w)

    def __len__(self) -> int:
        return len(self.ids)

    def __repr__(self) -> str:
        return f"KernelSet({self.ids}, known_w={self.known_w})"


@functools.cache
def kernel_set(ids: tuple[int, ...], known_w: int | None = None) -> KernelSet:
    """The shared :class:`KernelSet` of ``ids`` (a tuple of kernel ids, possibly empty) and
    ``known_w``. Raises ValueError for an unknown id."""
    return KernelSet(ids, known_w)


def compile_kernel_set(kernels: KernelSet, iterations: int = 1) -> None:
    """Compile (or load from numba's cache) every kernel of ``kernels``, with the argument
    types :func:`run_kernels` passes them in the fused RANSAC batch, by running each on two
    problems of 9 points at the origin (which it rejects as degenerate; ``ok`` stays False).
    Lets a warm-up compile the kernels ahead of, or beside, the batch that calls them."""
    K, N = 2, 9
    ids = (*kernels.ids, *(() if kernels.known_w is None else (kernels.known_w,)))
    for i in ids:
        _KERNELS[i](
            np.zeros((K, N, 2)),
            np.zeros((K, N, 3)),
            np.zeros((K, N)),
            0.0,
            int(iterations),
            1e-12,
            np.zeros((K, 3)),
            np.zeros((K, MAX_PARAMS)),
            np.zeros(K, dtype=np.bool_),
            np.zeros(K, dtype=np.int64),
            np.zeros(K),
        )


def kernel_count(kernels: KernelSet) -> int:
    """Number of kernels in a :class:`KernelSet`, a compile-time constant (compiled code
    only)."""
    raise NotImplementedError("kernel_count is called from compiled code only")


def run_kernels(
    kernels: KernelSet,
    j: int,
    x: np.ndarray,
    X: np.ndarray,
    r: np.ndarray,
    r0: float,
    iterations: int,
    tol: float,
    v_init: np.ndarray,
    out: np.ndarray,
    ok: np.ndarray,
    its: np.ndarray,
    err: np.ndarray,
) -> None:
    """Run the ``j``-th kernel of the :class:`KernelSet` ``kernels`` on K problems (compiled
    code only; ``j`` = :data:`KNOWN_W`: the set's known-angular-velocity kernel, which reads
    the known w from ``v_init``); arguments as the kernels' (module docstring). N must be at
    least the kernel's ``min_points`` (not checked here: the kernels do not check it either).
    ``j`` outside the set leaves ``ok`` False."""
    raise NotImplementedError("run_kernels is called from compiled code only")


@overload(kernel_count)
def _kernel_count(kernels):
    if not isinstance(kernels, KernelSetType):
        return None
    n = len(kernels.ids)
    return lambda kernels: n


@overload(run_kernels)
def _run_kernels(kernels, j, x, X, r, r0, iterations, tol, v_init, out, ok, its, err):
    if not isinstance(kernels, KernelSetType):
        return None
    if len(kernels.ids) > 2:
        raise ValueError(f"a kernel set holds at most two kernels, not {len(kernels.ids)}")
    # (a kernel the set does not have is a stand-in that solves nothing)
    ks = [_KERNELS[i] for i in kernels.ids]
    kw = _KERNELS[kernels.known_w] if kernels.known_w is not None else _no_kernel
    k0 = ks[0] if len(ks) > 0 else _no_kernel
    k1 = ks[1] if len(ks) > 1 else _no_kernel

    def impl(kernels, j, x, X, r, r0, iterations, tol, v_init, out, ok, its, err):
        if j == 0:
            k0(x, X, r, r0, iterations, tol, v_init, out, ok, its, err)
        elif j == 1:
            k1(x, X, r, r0, iterations, tol, v_init, out, ok, its, err)
        elif j == KNOWN_W:
            kw(x, X, r, r0, iterations, tol, v_init, out, ok, its, err)
        else:
            ok[:] = False

    return impl


@kernel
def _no_kernel(x, X, r, r0, iterations, tol, v_init, out, ok, its, err):
    """Stands in for a kernel a set does not have: solves nothing."""
    ok[:] = False
