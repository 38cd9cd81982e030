"""The estimator's two implementations and how a call chooses one.

:func:`~.estimate.estimate_rs_pose` runs the same stages (prepare, LO-RANSAC, finalize; the
same model, outputs and failure reasons) in one of two implementations, named by its
``implementation`` argument:

- ``"compiled"``: the numba kernels (:mod:`.frame`, :mod:`.ransac`, :mod:`.finalize` and
  the kernels they call). numba compiles them on first use (one to two minutes of CPU on a
  cold cache) or loads them from its cache; every solver, every input.
- ``"numpy"``: NumPy, SciPy and OpenCV only (:mod:`.numpy_impl`), for the solvers of
  :data:`NUMPY_SOLVERS`: nothing compiles, at a lower rate. It cannot use the inputs and
  options of :data:`NUMPY_UNUSED`; an estimate records those it was given
  (``RSPoseEstimate.ignored_inputs``).

``None`` (the default) is :func:`default_implementation`: the compiled kernels, unless this
process cannot or must not compile them (numba unavailable, or :data:`COMPILED_ENV` ``=0`` in
the environment). Which implementation is *ready* in a running process (a node whose kernels
compile in the background) is the runtime's to say
(:func:`rs_localizer.runtime.warmup.ready_implementation`); its callers pass that explicitly.
Every estimate records the implementation that ran (``RSPoseEstimate.implementation``).
"""

from __future__ import annotations

import os
import sys

from ..solvers.registry import SOLVER_NAMES

__all__ = [
    "COMPILED",
    "COMPILED_ENV",
    "IMPLEMENTATIONS",
    "NUMPY",
    "NUMPY_SOLVERS",
    "NUMPY_UNUSED",
    "compiled_by_default",
    "default_implementation",
    "numba_usable",
    "resolve_implementation",
]

#: the numba kernels
COMPILED = "compiled"
#: NumPy, SciPy and OpenCV only (:mod:`.numpy_impl`)
NUMPY = "numpy"
#: the implementations, by name
IMPLEMENTATIONS = (COMPILED, NUMPY)
#: the solvers the NumPy implementation runs (the paper's linear R6P, the node's default,
#: and the global-shutter P3P baseline); the others are compiled only
NUMPY_SOLVERS = ("r6p_1lin", "p3p")
#: what the NumPy implementation cannot use, as ``RSPoseEstimate.ignored_inputs`` names it:
#: the arguments ``scores`` (PROSAC ordering: it samples uniformly), ``point_sigma``,
#: ``groups`` (a camera's; a rig frame's views' groups it uses), and the option
#: ``correlated_noise`` (with ``sigma_px > 0``). It does use ``initial_model`` (the
#: seed and the anchored samples), ``gyro`` (its motion prior and the image-alone check; the
#: minimal samples stay the linear R6P's, without the gyro's angular velocity) and
#: ``refine.acceleration_sensitivity``
NUMPY_UNUSED = (
    "scores",
    "point_sigma",
    "correlated_noise",
    "groups",
)
#: environment variable: ``0`` makes :func:`default_implementation` ``"numpy"`` for the
#: solvers that have it (numba unusable on this machine, or to measure that implementation)
COMPILED_ENV = "RS_LOCALIZER_COMPILED"


def numba_usable() -> bool:
    """False when numba could not be imported in this process: the package then runs on the
    stand-in that :mod:`rs_localizer.runtime.jit_cache` puts in its place (its kernels raise
    when called; :func:`rs_localizer.runtime.jit_cache.numba_error` says why)."""
    numba = sys.modules.get("numba")
    return numba is not None and not getattr(numba, "__rs_localizer_standin__", False)


def compiled_by_default() -> bool:
    """True unless this process cannot or must not compile the kernels: numba is not usable
    (:func:`numba_usable`) or :data:`COMPILED_ENV` is ``0`` in the environment (both as they
    were when this module was imported: the package imports numba, or its stand-in, first)."""
    return _BY_DEFAULT


_BY_DEFAULT = os.environ.get(COMPILED_ENV, "1").strip() != "0" and numba_usable()


def default_implementation(solver: str | None) -> str:
    """The implementation of ``estimate_rs_pose(..., implementation=None)``: ``"numpy"`` for a
    solver of :data:`NUMPY_SOLVERS` (None: the rig's estimator, which has both) unless
    :func:`compiled_by_default`; else ``"compiled"``."""
    if (solver is None or solver in NUMPY_SOLVERS) and not compiled_by_default():
        return NUMPY
    return COMPILED


def resolve_implementation(implementation: str | None, solver: str | None) -> str:
    """``implementation`` checked (``None``: :func:`default_implementation`) for ``solver``
    (None: the rig's estimator, which has both implementations).

    Raises:
        ValueError: an implementation not in :data:`IMPLEMENTATIONS`, or ``"numpy"`` for a
            solver not in :data:`NUMPY_SOLVERS`.
    """
    if implementation is None:
        return default_implementation(solver)
    if implementation == COMPILED:
        return COMPILED
    if implementation != NUMPY:
        raise ValueError(
            f"unknown implementation {implementation!r}; expected one of {IMPLEMENTATIONS}"
        )
    if solver not in NUMPY_SOLVERS and solver in SOLVER_NAMES:
        raise ValueError(f"solver {solver!r} needs the compiled kernels; {NUMPY_SOLVERS} do not")
    return NUMPY
