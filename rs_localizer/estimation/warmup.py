"""JIT warm-up: solve a small synthetic problem so numba compiles (or loads from its cache)
every kernel a real frame needs, before the first real frame.

Used by the node at start (and on a solver change) and by ``rs-localizer compile``, the
install-time compilation step (see :mod:`rs_localizer.jit_cache` for where the kernels go).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable

import numpy as np

from ..camera import CameraModel
from ..jit_cache import cache_state, compile_progress
from ..solvers.registry import SOLVER_NAMES
from .estimate import EstimateOptions, RSPoseEstimate, estimate_rs_pose

__all__ = ["DEFAULT_SOLVERS", "compile_kernels", "warm_up"]

#: what ``rs-localizer compile`` compiles by default: the node's default solver and the
#: global-shutter baseline of ``rs-localizer demo``
DEFAULT_SOLVERS = ("r6p_1lin", "p3p")


def _problem(n: int = 60, seed: int = 1):
    """A 640x480 distorted RS camera and ``n`` exact correspondences (3-8 m deep) with
    scores: pixels (n, 2), world points (n, 3), scores (n,)."""
    rng = np.random.default_rng(seed)
    cam = CameraModel(
        K=np.array([[800.0, 0, 320], [0, 800.0, 240], [0, 0, 1]]),
        D=np.array([0.05, -0.05, 0.0, 0.0, 0.0]),
        width=640,
        height=480,
        line_delay=5e-5,
        distortion_model="plumb_bob",
    )
    uv = rng.uniform([0, 0], [639, 479], (n, 2))
    depth = rng.uniform(3, 8, n)
    xn = cam.undistort(uv)
    X = np.concatenate([xn, np.ones((n, 1))], axis=1) * depth[:, None]
    return cam, uv, X, rng.uniform(0, 1, n)


def warm_up(
    solver: str = "r6p_1lin", options: EstimateOptions | None = None
) -> tuple[float, RSPoseEstimate]:
    """Run :func:`~rs_localizer.estimation.estimate_rs_pose` with ``solver`` and ``options`` on
    a synthetic 60-point problem, with and without scores (the two input paths of the node).

    Returns:
        (seconds, the estimate of the run without scores).
    Raises:
        ValueError: unknown solver.
    """
    if solver not in SOLVER_NAMES:
        raise ValueError(f"unknown solver {solver!r}; expected one of {list(SOLVER_NAMES)}")
    tic = time.perf_counter()
    cam, uv, X, scores = _problem()
    est = estimate_rs_pose(uv, X, cam, solver=solver, options=options)
    estimate_rs_pose(uv, X, cam, solver=solver, options=options, scores=scores)
    return time.perf_counter() - tic, est


def compile_kernels(
    solvers: Iterable[str] = DEFAULT_SOLVERS, log: Callable[[str], object] = print
) -> dict:
    """Compile (or load) every kernel the estimator needs for ``solvers``, reporting each
    kernel numba compiles through ``log`` (see :func:`rs_localizer.jit_cache.compile_progress`).

    Returns:
        ``{"seconds": total, "kernels": [(name, seconds)], "cache": cache_state(),
        "solvers": {solver: seconds}}``.
    Raises:
        ValueError: an unknown solver name.
    """
    solvers = list(solvers)
    for s in solvers:
        if s not in SOLVER_NAMES:
            raise ValueError(f"unknown solver {s!r}; expected one of {list(SOLVER_NAMES)}")
    tic = time.perf_counter()
    per = {}
    with compile_progress(log) as prog:
        for s in solvers:
            per[s], _ = warm_up(s)
    return {
        "seconds": time.perf_counter() - tic,
        "kernels": prog.kernels,
        "cache": cache_state(),
        "solvers": per,
    }
