"""One numba call per RANSAC batch: sampling, P3P pre-rotation, the batched RS solver and the
preemptive MSAC scoring (paper sec. 4).

:func:`ransac_batch` runs the same kernels as the step-by-step path of
:mod:`rs_localizer.estimation.estimate` (:func:`~.sampling.draw_samples`, Lambda Twist P3P
on unit bearings (:func:`~.sampling.p3p_mounted`),
:func:`~.sampling.select_prerotations`, :func:`~.sampling.gather_prerotated`, the solver's
batched kernel, :func:`~rs_localizer._so3.compose_rotvec`'s rotation,
:func:`~.scoring.msac_scores`) on the same numbers, so its hypotheses and scores are the same,
bit for bit; it only removes the ~15 NumPy/Python calls per batch between them (a NumPy call
costs 1-10 us, a batch of 64 hypotheses ~150 us of kernels).
"""

from __future__ import annotations

import functools

import numpy as np

from .._jit import kernel
from .._so3 import compose_rotvec, copy_matrix3
from ..solvers.kernels import (
    KNOWN_W,
    MAX_PARAMS,
    R5P_W,
    KernelSet,
    kernel_count,
    kernel_ids,
    kernel_set,
    run_kernels,
)
from ..solvers.p3p import DEFAULT_BACKEND
from ..solvers.r6p_1lin import solve_mounted
from ..solvers.registry import BATCHED, GLOBAL_SHUTTER, solver_info
from .plausibility import motion_checked
from .sampling import draw_samples, gather_prerotated, p3p_mounted, select_prerotations
from .scoring import msac_scores

__all__ = [
    "checked_solutions",
    "fused_kernels",
    "prerotated_batch",
    "prerotated_solutions",
    "ransac_batch",
    "solve_and_score",
]

#: stopping tolerance of the iterative solvers on RANSAC samples (their default)
_SOLVER_TOL = 1e-12


@functools.cache  # (the registry and the backend are fixed at import)
def fused_kernels(solver: str) -> tuple[KernelSet, np.ndarray] | None:
    """``(kernels, n_params)`` for :func:`ransac_batch` with ``solver``: its batched kernels
    as a :class:`~rs_localizer.solvers.kernels.KernelSet` (empty for the global-shutter P3P;
    an RS solver's set also holds R5P_{v,C,t}^{w} for frames with a gyro)
    and the (J,) int64 parameters each writes; ``None`` when the solver has no fused path: R6P
    (a variable number of roots per sample), a batched solver without a kernel id, or a P3P
    backend other than our Lambda Twist (``RS_LOCALIZER_P3P``, for comparisons). The result
    is shared between calls: do not modify the array (it stays writable: numba compiles a
    read-only array as another type). Raises ValueError for an unknown solver."""
    info = solver_info(solver)
    if DEFAULT_BACKEND != "lambda_twist":
        return None
    if info.hypotheses == GLOBAL_SHUTTER:
        return kernel_set(()), np.zeros(0, dtype=np.int64)
    ids = kernel_ids(solver) if info.hypotheses == BATCHED else None
    if ids is None:
        return None
    return (
        kernel_set(tuple(k[0] for k in ids), R5P_W),
        np.array([k[1] for k in ids], dtype=np.int64),
    )


@kernel
def ransac_batch(
    u,
    pool,
    order,
    x,
    X,
    r,
    r0e,
    d,
    r0,
    kernels,
    n_params,
    iterations,
    th2,
    bail,
    pretest_n,
    pretest_min,
    measured=False,
    w_max=np.inf,
    v_max=np.inf,
    w_known=None,
    W=None,
):
    """Draw, solve and score one batch of K RANSAC samples.

    Args:
        u: (K, s) uniform numbers in [0, 1) (the caller's seeded generator); s is the sample
            size (3 for P3P, 6, or 9 for R9P).
        pool: sample from ``order[:pool]`` (PROSAC-style growing pool; ``len(x)`` for plain
            sampling). order: (N,) int64 point indices, best-scored first.
        x (N, 2) normalized points, X (N, 3) world points, r (N,) RS coordinates, r0e (N,)
            per-point reference coordinate, d (2,) readout direction, r0 the reference
            coordinate (see :meth:`rs_localizer.camera.CameraModel.normalize`).
        kernels: the :class:`~rs_localizer.solvers.kernels.KernelSet` of J batched kernels
            (:func:`fused_kernels`), each run on every sample, pre-rotated by the sample's P3P
            solution; J = 0: the P3P pre-rotations are the (global-shutter) hypotheses. The
            function is compiled once per kernel set. n_params: (J,) parameters each kernel
            writes (checked for finiteness).
        iterations: linear iterations of the iterative solvers.
        th2: squared inlier threshold (normalized units). bail, pretest_n, pretest_min: as in
            :func:`~.scoring.msac_scores` (best score so far, pre-test size and bound);
            measured: score at the measured capture times (see ``msac_scores``).
        w_max, v_max: motion bounds per unit r (:func:`~.plausibility.motion_bounds`): a
            hypothesis with ``|w| > w_max`` or ``|w x C - t| > v_max`` is not scored.
        w_known: (3,) the known angular velocity (rad per unit r, a gyro's): every sample is
            then solved by the kernel set's known-angular-velocity kernel instead of its own
            (R5P_{v,C,t}^{w}, :data:`rs_localizer.solvers.kernels.R5P_W`; the known w goes to
            it as every sample's ``v_init``; one hypothesis per sample); a (0,) array or
            None: no gyro. (Callers pass an array either way: one compiled version for both.)
        W: (N, 4) each point's whitening of its image error (:attr:`~.frame.Frame.W`; with
            ``measured``), a (0, 4) array or None: none.
    Returns:
        (h, score, Rs (H, 3, 3), Cs (H, 3), ws (H, 3), ts (H, 3), n_implausible: valid
        hypotheses rejected for their motion alone) with H = max(J, 1) K
        hypotheses (kernel j's in rows ``j K .. j K + K - 1``), h the index of the batch's best
        and ``score`` its MSAC score (``inf`` if no hypothesis was valid or none beat
        ``bail``). Invalid hypotheses (no P3P solution, solver rank loss, non-finite values)
        are never scored.
    """
    K, s = u.shape
    local = draw_samples(u, pool)
    samples = np.empty((K, s), dtype=np.int64)
    for k in range(K):
        for j in range(s):
            samples[k, j] = order[local[k, j]]
    R, C, own = p3p_mounted(x, X, samples, None, None, None)  # (a camera: unit bearings)
    R_p, C_p, ok_p = select_prerotations(R, C, own, samples, X, x, K)
    return solve_and_score(
        samples,
        R_p,
        C_p,
        ok_p,
        x,
        X,
        r,
        r0e,
        d,
        r0,
        kernels,
        n_params,
        iterations,
        th2,
        bail,
        pretest_n,
        pretest_min,
        measured,
        w_max,
        v_max,
        w_known,
        W,
    )


@kernel
def prerotated_batch(
    u,
    pool,
    order,
    R_pre,
    x,
    X,
    r,
    r0e,
    d,
    r0,
    kernels,
    n_params,
    iterations,
    th2,
    bail,
    pretest_n,
    pretest_min,
    measured=False,
    w_max=np.inf,
    v_max=np.inf,
    w_known=None,
    W=None,
):
    """:func:`ransac_batch` with one given pre-rotation ``R_pre`` (3, 3) for every sample
    instead of each sample's P3P pose (a video tracker's predicted rotation,
    :class:`rs_localizer.estimation.estimate.InitialModel`); the same kernels otherwise (the
    step-by-step path: :func:`~rs_localizer.estimation.estimate._generate` with ``R_pre``).
    ``kernels`` must not be empty (an RS solver). Arguments and returns as
    :func:`ransac_batch`."""
    K, s = u.shape
    local = draw_samples(u, pool)
    samples = np.empty((K, s), dtype=np.int64)
    R_p = np.empty((K, 3, 3))
    for k in range(K):
        for j in range(s):
            samples[k, j] = order[local[k, j]]
        R_p[k] = R_pre
    return solve_and_score(
        samples,
        R_p,
        np.zeros((K, 3)),
        np.ones(K, dtype=np.bool_),
        x,
        X,
        r,
        r0e,
        d,
        r0,
        kernels,
        n_params,
        iterations,
        th2,
        bail,
        pretest_n,
        pretest_min,
        measured,
        w_max,
        v_max,
        w_known,
        W,
    )


@kernel
def solve_and_score(
    samples,
    R_p,
    C_p,
    ok_p,
    x,
    X,
    r,
    r0e,
    d,
    r0,
    kernels,
    n_params,
    iterations,
    th2,
    bail,
    pretest_n,
    pretest_min,
    measured,
    w_max,
    v_max,
    w_known,
    W,
    mount=None,
):
    """The part of :func:`ransac_batch` after the pre-rotations: solve every pre-rotated
    sample with each kernel (:func:`prerotated_solutions`), drop implausible hypotheses,
    score, the batch's best the first minimum of the scores. ``mount``: None (a camera) or a
    rig's stacked views, as :func:`~.scoring.msac_scores` takes them
    (:func:`~.rig_batch.search_batch`; ``w_known`` None, ``r`` the capture times s): each
    sample solved by the rig solver, or on a still rig frame the still models ``R_p``,
    ``C_p`` (``w = t = 0``) scored. Returns as :func:`ransac_batch` (``h`` -1 and the score
    ``inf`` for a batch of no hypothesis, a rig's whose samples P3P posed none)."""
    K = R_p.shape[0]
    # (an "is None" test on the argument itself: the branch that cannot be typed is pruned)
    if w_known is None:  # noqa: SIM108 (numba prunes this branch on a None argument)
        wk = np.zeros(0)
    else:
        wk = w_known
    known = wk.shape[0] == 3
    J = 1 if known else kernel_count(kernels)
    if mount is not None and mount[4]:  # (a still rig frame: its models are R_p, C_p)
        J = 0
    if J == 0:
        Rs, Cs, ok = R_p, C_p, ok_p
        ws = np.zeros((K, 3))
        ts = np.zeros((K, 3))
    else:
        v0 = np.zeros((K, 3))
        if known:  # (the known-w kernel reads its w from v_init)
            for k in range(K):
                v0[k, 0], v0[k, 1], v0[k, 2] = wk[0], wk[1], wk[2]
        Rs, Cs, ws, ts, ok = prerotated_solutions(
            samples, R_p, ok_p, x, X, r, r0, kernels, n_params, iterations, v0, known, mount
        )
    n_implausible = 0
    w2max, v2max = w_max * w_max, v_max * v_max
    for q in range(ok.shape[0]):  # an implausibly moving hypothesis has no inliers
        if ok[q] and not motion_checked(Cs, ws, ts, q, w2max, v2max):
            ok[q] = False
            n_implausible += 1
    if mount is None:
        scores, _ = msac_scores(x, X, r0e, d, Rs, Cs, ws, ts, th2, ok, bail, True, pretest_n,
                                pretest_min, 0.5, measured, W)  # fmt: skip
    else:  # (a rig's: ``measured`` a constant, the camera's error forms compiled out)
        scores, _ = msac_scores(x, X, r0e, d, Rs, Cs, ws, ts, th2, ok, bail, True, pretest_n,
                                pretest_min, 0.5, True, W, mount)  # fmt: skip
    if scores.shape[0] == 0:  # (a rig's batch of no model: no sample posed)
        return -1, np.inf, Rs, Cs, ws, ts, n_implausible
    h = np.argmin(scores)
    return h, scores[h], Rs, Cs, ws, ts, n_implausible


@kernel
def prerotated_solutions(samples, R_p, ok_p, x, X, r, r0, kernels, n_params, iterations, v0,
                         known, mount=None, min_points=None):  # fmt: skip
    """K samples (K, s) pre-rotated by ``R_p`` (K, 3, 3) (:func:`~.sampling.gather_prerotated`
    on ``x`` (N, 2), ``X`` (N, 3), ``r`` (N,)) solved by each of the J batched kernels of
    ``kernels`` (``n_params`` (J,) the parameters each writes, checked for finiteness;
    ``known``: the set's known-angular-velocity kernel alone, J = 1, its w in every row of
    ``v0`` (K, 3), the kernels' ``v_init``; ``min_points`` (J,): a kernel given fewer points
    per sample is not run, its solutions not ok). ``mount``: None (a camera) or a rig's
    stacked views as :func:`~.scoring.msac_scores` takes them (its first five are read):
    ``kernels`` R6P_{v,C,w,t}^{[v]x}
    alone, run through each point's camera's mounting
    (:func:`~rs_localizer.solvers.r6p_1lin.solve_mounted`, the rig solver; ``r`` the capture
    times s), on a still frame (``mount[4]``) with the velocities held at zero by the prior
    rows ``(w, t) = 0`` (with ``r`` zero and one step, a global-shutter sample's correction).
    Returns ``(Rs (H, 3, 3), Cs, ws, ts (H, 3), ok (H,))``, H = J K, kernel j's in rows
    ``j K .. j K + K - 1``, each rotation ``expm([v]x) R_p[k]``; ``ok`` the solution's and
    ``ok_p`` (K,)'s; a solution not ok zero (its rotation ``R_p[k]``)."""
    K, s = samples.shape
    J = 1 if known else kernel_count(kernels)
    xs, Xs, rs = gather_prerotated(samples, R_p, x, X, r)
    H = J * K
    Rs = np.empty((H, 3, 3))
    Cs = np.empty((H, 3))
    ws = np.empty((H, 3))
    ts = np.empty((H, 3))
    ok = np.empty(H, dtype=np.bool_)
    out = np.empty((K, MAX_PARAMS))
    ok_k = np.zeros(K, dtype=np.bool_)
    its = np.zeros(K, dtype=np.int64)
    err = np.zeros(K)
    v = np.empty((K, 3))
    if mount is not None:  # (each point's camera; the prior rows of held velocities)
        cam, Rm, cm, held = mount[0], mount[1], mount[2], mount[4]
        cs = np.empty((K, s), dtype=np.int64)
        for k in range(K):
            for i in range(s):
                cs[k, i] = cam[samples[k, i]]
        P = np.zeros((K if held else 1, 6, 6))
        if held:
            for k in range(K):
                for a in range(6):
                    P[k, a, a] = 1.0
    for j in range(J):
        out[:] = 0.0
        if mount is not None:
            solve_mounted(xs, Xs, rs, cs, Rm, cm, iterations, _SOLVER_TOL, v0, P,
                          np.zeros((P.shape[0], 6)), held, out, ok_k, its, err)  # fmt: skip
        elif min_points is None or s >= min_points[j]:
            run_kernels(kernels, KNOWN_W if known else j, xs, Xs, rs, r0, iterations,
                        _SOLVER_TOL, v0, out, ok_k, its, err)  # fmt: skip
        else:
            ok_k[:] = False
        checked_solutions(out, ok_k, 12 if known else n_params[j])
        for k in range(K):
            h = j * K + k
            for a in range(3):
                v[k, a] = out[k, a]
                Cs[h, a] = out[k, 3 + a]
                ws[h, a] = out[k, 6 + a]
                ts[h, a] = out[k, 9 + a]
            ok[h] = ok_k[k] and ok_p[k]
        # (a call, not inlined: the same floating-point contraction as the step-by-step path)
        Rj = compose_rotvec(v, R_p)
        for k in range(K):
            copy_matrix3(Rj[k], Rs[j * K + k])
    return Rs, Cs, ws, ts, ok


@kernel
def checked_solutions(out, ok, n_params):
    """A batched solver's K solutions ``out`` (K, >= 12) ``(v, C, w, t)`` and their ``ok``
    (K,) bool checked in place: ``ok[k]`` False where one of the first ``n_params``
    parameters is not finite, and the 12 parameters of a row not ok zeroed (as
    :class:`~rs_localizer.solvers.RSBatch`'s invalid problems): those of
    :func:`prerotated_solutions`."""
    for k in range(out.shape[0]):
        for a in range(n_params):
            if not np.isfinite(out[k, a]):
                ok[k] = False
        if not ok[k]:
            for a in range(12):
                out[k, a] = 0.0


@kernel
def nonminimal_solve(kernels, n_params, min_points, inl, R, x, X, r, r0, iterations):
    """Local optimization's nonminimal step in one call: each batched kernel of ``kernels`` on
    all points of ``inl``, pre-rotated by R.

    Args:
        kernels, n_params: a :class:`~rs_localizer.solvers.kernels.KernelSet` of J kernels
            and their (J,) parameter counts (as for :func:`ransac_batch`); min_points: (J,)
            the fewest points each kernel accepts (fewer inliers: that kernel is skipped,
            ``ok`` False); inl: (N,) bool; R: (3, 3)
            the current rotation;
            x (N, 2), X (N, 3), r (N,), r0 as there; iterations: linear iterations.
    Returns:
        (ok (J,), Rs (J, 3, 3), Cs, ws, ts (J, 3)): kernel j's solution composed with R,
        ``Rs[j] = expm([v]x) R``; ``ok[j]`` False for rank loss or non-finite values.
    """
    idx = np.flatnonzero(inl)
    R1 = np.empty((1, 3, 3))
    copy_matrix3(R, R1[0])
    Rs, Cs, ws, ts, ok = prerotated_solutions(
        idx.reshape((1, idx.shape[0])), R1, np.ones(1, dtype=np.bool_), x, X, r, r0, kernels,
        n_params, iterations, np.zeros((1, 3)), False, None, min_points,
    )  # fmt: skip
    return ok, Rs, Cs, ws, ts
