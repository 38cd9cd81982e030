"""Rolling-shutter absolute pose solvers (Kukelova et al. ACCV 2018) and their baselines.

==================  ==============================  ===========  ====================
function            paper name                      points       solutions
==================  ==============================  ===========  ====================
``p3p``             P3P (global shutter)            3            up to 4
``r6p``             R6P (Albl et al. CVPR 2015)     6            up to 20
``r6p_1lin``        R6P_{v,C,w,t}^{[v]x} (3.3)      >= 6         1, iterative
``r6p_vC_wt``       R6P_{v,C}^{w,t} (3.1)           >= 6         1, iterative
``r6p_vCt_w``       R6P_{v,C,t}^{w} (3.2)           >= 6         1, iterative
``r6p_vCt_wt``      R6P_{v,C,t}^{w,t} (3.2)         >= 6         1, iterative
``r9p``             R9P (3.4, eq. 8)                >= 9         1
``r6p_joined``      joined solver (4.1)             >= 6         1
``r5p_w``           R5P_{v,C,t}^{w} (w known, 3.2)  >= 5         1, iterative
==================  ==============================  ===========  ====================

The ``*_batch`` variants solve K problems at once ((K, N, 2), (K, N, 3) -> :class:`RSBatch`).
:data:`SOLVERS` (``registry.py``) is the one table of what is known about each solver.
"""

from ._common import DegenerateInputError, RSBatch, RSSolution
from .joined import r6p_joined
from .p3p import P3PSolution, p3p, p3p_batch, p3p_opencv
from .r5p_w import r5p_w, r5p_w_batch
from .r6p import r6p
from .r6p_1lin import r6p_1lin, r6p_1lin_batch
from .r6p_vC_wt import r6p_vC_wt, r6p_vC_wt_batch
from .r6p_vCt_w import r6p_vCt_w, r6p_vCt_w_batch
from .r6p_vCt_wt import r6p_vCt_wt, r6p_vCt_wt_batch
from .r9p import r9p, r9p_batch
from .registry import SOLVER_NAMES, SOLVERS, SolverInfo, sample_size, solver_info

__all__ = [
    "SOLVERS",
    "SOLVER_NAMES",
    "DegenerateInputError",
    "P3PSolution",
    "RSBatch",
    "RSSolution",
    "SolverInfo",
    "p3p",
    "p3p_batch",
    "p3p_opencv",
    "r5p_w",
    "r5p_w_batch",
    "r6p",
    "r6p_1lin",
    "r6p_1lin_batch",
    "r6p_joined",
    "r6p_vC_wt",
    "r6p_vC_wt_batch",
    "r6p_vCt_w",
    "r6p_vCt_w_batch",
    "r6p_vCt_wt",
    "r6p_vCt_wt_batch",
    "r9p",
    "r9p_batch",
    "sample_size",
    "solver_info",
]
