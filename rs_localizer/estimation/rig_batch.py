"""The compiled kernels of the rig's RANSAC (:func:`~.rig.estimate_rig_pose`): each batch of
the search drawn (:func:`~.sampling.batch_samples`), its samples' pre-rotations or still models
(:func:`still_models`: the rig's own hypotheses, :func:`~.rig._hypotheses`) solved and scored
by the camera's batch (:func:`~.batch.solve_and_score` with the mountings: the rig solver,
MSAC on each point's error in pixels with the pre-test) in one numba call
(:func:`search_batch`), termination checked after every batch. The rig's step-by-step search
(with a gyro, or another pre-rotation) calls the same kernels one by one.
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel
from ..solvers.kernels import kernel_ids, kernel_set
from ..solvers.lambda_twist import MAX_SOLUTIONS
from .batch import prerotated_solutions, solve_and_score
from .sampling import batch_samples, p3p_mounted, p3p_mounted_into
from .scoring import mounted_errors

__all__ = ["RIG_KERNELS", "counted", "search_batch"]

#: ``(kernels, n_params)`` of the rig's samples in the camera's batch: R6P_{v,C,w,t}^{[v]x}
#: alone, which :func:`~.batch.prerotated_solutions` runs through each point's camera's
#: mounting (the rig solver, :func:`~rs_localizer.solvers.r6p_1lin.solve_mounted`)
RIG_KERNELS = (
    kernel_set((kernel_ids("r6p_1lin")[0][0],)),
    np.array([kernel_ids("r6p_1lin")[0][1]], dtype=np.int64),
)


@kernel
def counted(e, k, cam, pool_counts, subset):
    """The inliers of errors ``e`` (N,) px (below ``k``; among ``subset`` when it is not
    empty) and the cameras of 3 or more points (``pool_counts``) with none: ``(inliers,
    those cameras (M,) bool)``."""
    hit = np.zeros(len(pool_counts), dtype=np.int64)
    n_in = 0
    for i in range(len(e)):
        if e[i] < k:
            n_in += 1
            hit[cam[i]] += 1
    if len(subset):
        n_in = 0
        for i in subset:
            if e[i] < k:
                n_in += 1
    missed = np.empty(len(pool_counts), dtype=np.bool_)
    for c in range(len(pool_counts)):
        missed[c] = pool_counts[c] >= 3 and hit[c] == 0
    return n_in, missed


@kernel
def search_batch(u, subset, X, x, tau, cam, Rm, cm, A, order, still, missed, rounds, anchor,
                 iterations, w_max, v_max, th2, k, pool_counts, best_cost, pretest_n,
                 pretest_min, out):  # fmt: skip
    """One batch of the compiled search: K samples of :meth:`~.view.StackedViews.samples` on
    the draws ``u`` (7, K) (among the pool indices ``subset`` unless empty), solved and scored
    as a camera's batch is (:func:`~.batch.solve_and_score` with the mountings: ``still``,
    each sample's :func:`still_models` with ``missed``, ``rounds``; else each pre-rotated by
    its P3P pose (:func:`~.sampling.p3p_mounted`: one per sample) or by ``anchor`` (3, 3)
    unless empty, then ``iterations`` of the rig solver, those beyond ``w_max`` (rad/s),
    ``v_max`` (m/s) counted, not scored; MSAC on each point's error in px, ``th2`` px^2, the
    pre-test on the first ``pretest_n`` points of ``order`` needing ``pretest_min`` inliers
    there) against the best cost so far ``best_cost``, the batch's best's inliers below ``k``
    px counted (:func:`counted`). Returns ``(h, cost, inliers, models beyond the bounds)``:
    ``h`` -1 when no model beat the best, else the batch's best is written into ``out``
    ``(errors (N,) px, R, C, w, t, missed cameras (M,) bool)``."""
    samples = batch_samples(u, cam, pool_counts, subset)
    best_e, R_best, C_best, w_best, t_best, missed_best = out
    K = samples.shape[0]
    mount = (cam, Rm, cm, tau, still, order)
    if still:
        R0, C0 = still_batch(samples, x, X, cam, Rm, cm, missed, rounds)
    elif anchor.shape[0]:
        R0, C0 = np.empty((K, 3, 3)), np.zeros((K, 3))
        for h in range(K):
            R0[h] = anchor
    else:
        R0, C0, own = p3p_mounted(x, X, samples, cam, Rm, cm)
        samples = samples[own]
    h, cost, R, C, w, t, beyond = solve_and_score(
        samples, R0, C0, np.ones(R0.shape[0], dtype=np.bool_), x, X, tau, tau, np.zeros(2),
        0.0, *RIG_KERNELS, iterations, th2, best_cost, pretest_n, pretest_min, True, w_max, v_max,
        None, A, mount,
    )  # fmt: skip
    if not cost < best_cost:
        return -1, best_cost, 0, beyond
    best_e[:] = mounted_errors(R, C, w, t, h, X, x, A, mount)
    R_best[:] = R[h]
    C_best[:] = C[h]
    if not still:  # (a still model's velocities: none written)
        w_best[:] = w[h]
        t_best[:] = t[h]
    n_best, m = counted(best_e, k, cam, pool_counts, subset)
    missed_best[:] = m
    return h, cost, n_best, beyond


@kernel
def still_batch(samples, x, X, cam, Rm, cm, missed, rounds):
    """:func:`still_models` of each of the samples (K, 6), in their order: ``(R (H, 3, 3), C
    (H, 3))``."""
    K = samples.shape[0]
    R, C = np.empty((2 * MAX_SOLUTIONS * K, 3, 3)), np.empty((2 * MAX_SOLUTIONS * K, 3))
    b, P = np.empty((3, 3)), np.empty((3, 3))
    R_cam, C_cam = np.empty((MAX_SOLUTIONS, 3, 3)), np.empty((MAX_SOLUTIONS, 3))
    Rp, Cp = np.empty((MAX_SOLUTIONS, 3, 3)), np.empty((MAX_SOLUTIONS, 3))
    H = 0
    for j in range(K):
        Rj, Cj = still_models(samples[j], x, X, cam, Rm, cm, missed, rounds, b, P, R_cam, C_cam,
                              Rp, Cp)  # fmt: skip
        n = Rj.shape[0]
        R[H : H + n] = Rj
        C[H : H + n] = Cj
        H += n
    return R[:H], C[:H]


@kernel
def still_models(sample, x, X, cam, Rm, cm, missed, rounds, b, P, R_cam, C_cam, R, C):
    """One sample's global-shutter models (:func:`~.rig._hypotheses` with 0 iterations), in
    the order they are scored: its P3P pose (:func:`~.sampling.p3p_mounted_into`, into the
    buffers ``R``, ``C``), then, when a point of the sample lies in a camera ``missed`` ((M,)
    bool), that pose corrected ``rounds`` times by the rig solver with the velocities held at
    zero (:func:`~.batch.prerotated_solutions` on the views at one time, each round
    pre-rotated by the last). Returns ``(R (H, 3, 3), C (H, 3))``."""
    q = p3p_mounted_into(x, X, sample, cam, Rm, cm, b, P, R_cam, C_cam, R, C, 0)
    Rg, Cg = R[:q], C[:q]
    hit = False
    if q > 0 and rounds > 0:
        for i in range(6):
            if missed[cam[sample[i]]]:
                hit = True
    if not hit:
        return Rg, Cg
    S = np.empty((q, 6), dtype=np.int64)
    for h in range(q):
        S[h] = sample
    Rc, Cc = Rg, Cg
    still = (cam, Rm, cm, np.zeros(X.shape[0]), True)  # (the frame's views at one time)
    for _ in range(rounds):
        Rs, Cs, _, _, ok = prerotated_solutions(S, np.ascontiguousarray(Rc), np.ones(len(S),
                                                dtype=np.bool_), x, X, still[3], 0.0,
                                                *RIG_KERNELS, 1, np.zeros((len(S), 3)), False,
                                                still)  # fmt: skip
        if not ok.any():
            return Rg, Cg
        keep = np.flatnonzero(ok)
        S, Rc, Cc = S[keep], Rs[keep], Cs[keep]
    return np.concatenate((Rg, Rc)), np.concatenate((Cg, Cc))
