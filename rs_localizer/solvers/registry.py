"""The one registry of solvers: name -> what the estimator, the node, the benchmarks and the
experiments need to know about it.

Every place that dispatches on a solver name reads :data:`SOLVERS` (no if-chains elsewhere).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from .joined import r6p_joined
from .p3p import p3p
from .r6p import r6p
from .r6p_1lin import r6p_1lin, r6p_1lin_batch
from .r6p_vC_wt import r6p_vC_wt, r6p_vC_wt_batch
from .r6p_vCt_w import r6p_vCt_w, r6p_vCt_w_batch
from .r6p_vCt_wt import r6p_vCt_wt, r6p_vCt_wt_batch
from .r9p import r9p, r9p_batch

__all__ = ["DEFAULT_SOLVER", "SOLVERS", "SOLVER_NAMES", "SolverInfo", "sample_size", "solver_info"]

#: how RANSAC makes hypotheses with a solver
GLOBAL_SHUTTER = "global_shutter"  # the P3P pre-rotation itself is the hypothesis (w = t = 0)
BATCHED = "batched"  # one solution per sample from batched numba kernels
ROOTS = "roots"  # every real root of a per-sample polynomial solver (R6P)


def _r9p_batch(x, X, r=None, r0: float = 0.0, iterations: int | None = None):
    """:func:`r9p_batch` with the batched-kernel signature (R9P is not iterative)."""
    return r9p_batch(x, X, r, r0)


@dataclass(frozen=True)
class SolverInfo:
    """What is known about one solver.

    Attributes:
        name: registry key (the ``solver`` option and node parameter).
        paper_name: the paper's name, plain text (``R6P_{v,C,w,t}^{[v]x}``).
        section: where it is derived (paper section / equation).
        sample_size: points of a minimal sample.
        max_solutions: most solutions per minimal sample.
        rolling: estimates the RS velocities (``w``, ``t``); False for the global-shutter P3P.
        iterative: a linear solver iterated on its own linearization (``iterations``).
        hypotheses: ``global_shutter``, ``batched`` or ``roots`` (see module constants).
        single: the public one-problem function ``(x, X, r, r0, ...)``.
        batch: batched kernels ``(xs (K, N, 2), Xs (K, N, 3), rs (K, N), r0, iterations)
            -> RSBatch`` run on every RANSAC sample (two for the joined solver).
        lo_solvers: solvers of the nonminimal local-optimization step (a solver needing more
            inliers than there are falls back to ``r6p_1lin``).
        default_iterations: linear iterations per RANSAC sample (None: not iterative).
        paper_us: the paper's Table 1 time per iteration (C++ on a 2.5 GHz i7, us), if given.
        coplanar: works on coplanar 3D points (False for R9P: its 18 unknowns lose 3
            dimensions there, ``R_rs + u n^T`` and ``t - u d`` fit a plane ``n.X = d``
            equally).
    """

    name: str
    paper_name: str
    section: str
    sample_size: int
    max_solutions: int
    rolling: bool
    iterative: bool
    hypotheses: str
    single: Callable
    batch: tuple = ()
    lo_solvers: tuple = ()
    default_iterations: int | None = None
    paper_us: float | None = None
    coplanar: bool = True


SOLVERS: dict[str, SolverInfo] = {
    s.name: s
    for s in (
        SolverInfo(
            "p3p",
            "P3P",
            "global shutter baseline",
            3,
            4,
            False,
            False,
            GLOBAL_SHUTTER,
            p3p,
            paper_us=3,
        ),
        # R6P is not iterative: its 5 iterations are those of its local optimization's r6p_1lin
        SolverInfo(
            "r6p",
            "R6P",
            "Albl et al. CVPR 2015",
            6,
            20,
            True,
            False,
            ROOTS,
            r6p,
            lo_solvers=("r6p_1lin",),
            default_iterations=5,
            paper_us=1700,
        ),
        # after the P3P pre-rotation one iteration is as good as R6P (paper Fig. 6)
        SolverInfo(
            "r6p_1lin",
            "R6P_{v,C,w,t}^{[v]x}",
            "sec. 3.3",
            6,
            1,
            True,
            True,
            BATCHED,
            r6p_1lin,
            (r6p_1lin_batch,),
            ("r6p_1lin",),
            1,
            paper_us=10,
        ),
        SolverInfo(
            "r6p_vC_wt",
            "R6P_{v,C}^{w,t}",
            "sec. 3.1",
            6,
            1,
            True,
            True,
            BATCHED,
            r6p_vC_wt,
            (r6p_vC_wt_batch,),
            ("r6p_vC_wt",),
            5,
            paper_us=27,
        ),
        SolverInfo(
            "r6p_vCt_w",
            "R6P_{v,C,t}^{w}",
            "sec. 3.2",
            6,
            1,
            True,
            True,
            BATCHED,
            r6p_vCt_w,
            (r6p_vCt_w_batch,),
            ("r6p_vCt_w",),
            5,
            paper_us=24,
        ),
        SolverInfo(
            "r6p_vCt_wt",
            "R6P_{v,C,t}^{w,t}",
            "sec. 3.2",
            6,
            1,
            True,
            True,
            BATCHED,
            r6p_vCt_wt,
            (r6p_vCt_wt_batch,),
            ("r6p_vCt_wt",),
            5,
            paper_us=30,
        ),
        SolverInfo(
            "r9p",
            "R9P",
            "sec. 3.4, eq. 8",
            9,
            1,
            True,
            False,
            BATCHED,
            r9p,
            (_r9p_batch,),
            ("r9p",),
            5,
            paper_us=20,
            coplanar=False,
        ),
        SolverInfo(
            "r6p_joined",
            "joined",
            "sec. 4.1",
            6,
            1,
            True,
            True,
            BATCHED,
            r6p_joined,
            (r6p_vCt_w_batch, r6p_1lin_batch),
            ("r6p_vCt_w", "r6p_1lin"),
            5,
        ),
    )
}

#: solver names in a stable order (parameter descriptions, CLI choices, benchmarks)
SOLVER_NAMES = tuple(SOLVERS)

#: the solver of a camera's frames unless its settings name another: the paper's linear
#: rolling-shutter solver R6P_{v,C,w,t}^{[v]x} (sec. 3.3)
DEFAULT_SOLVER = "r6p_1lin"


def solver_info(name: str) -> SolverInfo:
    """The registry entry of ``name``. Raises ValueError for an unknown solver."""
    try:
        return SOLVERS[name]
    except KeyError:
        raise ValueError(f"unknown solver {name!r}; expected one of {SOLVER_NAMES}") from None


def sample_size(name: str) -> int:
    """Minimal sample size of a solver by name (3 for P3P, 9 for R9P, 6 otherwise).

    Raises ValueError for an unknown solver."""
    return solver_info(name).sample_size
