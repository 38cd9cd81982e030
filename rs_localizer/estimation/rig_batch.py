"""The compiled kernels of the rig's RANSAC (:func:`~.rig.estimate_rig_pose`): each batch of
the search drawn (:func:`~.sampling.batch_samples`), solved (:func:`still_models`,
:func:`moving_models`: the rig's own hypotheses, :func:`~.rig._hypotheses`) and scored
(the camera's :func:`~.scoring.msac_scores` with the mountings: MSAC on each point's error in
pixels, with the pre-test) in one numba call (:func:`search_batch`), as :mod:`.batch` does for
one camera, termination checked after every batch. The rig's step-by-step search (with a gyro,
or another pre-rotation) calls the same kernels one by one.
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel
from .._so3 import compose_rotvec
from ..solvers.lambda_twist import MAX_SOLUTIONS
from ..solvers.r6p_1lin import solve_mounted
from .batch import checked_solutions
from .plausibility import motion_checked
from .sampling import batch_samples, gather_prerotated, p3p_mounted, p3p_mounted_into
from .scoring import best_mounted

__all__ = [
    "counted",
    "search_batch",
    "solve_rotated",
]


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
                 iterations, w2max, v2max, th2, k, pool_counts, best_cost, pretest_n,
                 pretest_min, out):  # fmt: skip
    """One batch of the compiled search: K samples of :meth:`~.view.StackedViews.samples` on
    the draws ``u`` (7, K) (among the pool indices ``subset`` unless empty), each sample's
    models (``still``: :func:`still_models` with ``missed``, ``rounds``; else
    :func:`moving_models` with ``anchor``, ``iterations``, those beyond ``w2max`` (rad/s)^2,
    ``v2max`` (m/s)^2 counted, not scored) scored as a camera's batch is
    (:func:`~.scoring.best_mounted`: MSAC on each point's error in px, ``th2`` px^2, the
    pre-test on the first ``pretest_n`` points of ``order`` needing ``pretest_min`` inliers
    there) against the best cost so far ``best_cost``, the batch's best's inliers below ``k``
    px counted (:func:`counted`). Returns ``(h, cost, inliers, models beyond the bounds)``:
    ``h`` -1 when no model beat the best, else the batch's best is written into ``out``
    ``(errors (N,) px, R, C, w, t, missed cameras (M,) bool)``."""
    samples = batch_samples(u, cam, pool_counts, subset)
    best_e, R_best, C_best, w_best, t_best, missed_best = out
    beyond = 0
    if still:
        R, C = still_batch(samples, x, X, cam, Rm, cm, missed, rounds)
        w = t = np.zeros((R.shape[0], 3))
        ok = np.ones(R.shape[0], dtype=np.bool_)
    else:
        R, C, w, t, ok, _ = moving_models(samples, x, X, tau, cam, Rm, cm, anchor, iterations)
        for g in range(len(ok)):
            if ok[g]:
                finite, within = motion_checked(C, w, t, g, w2max, v2max)
                ok[g] = finite and within  # (_hypotheses' finite models)
                if finite and not within:
                    beyond += 1
    h, cost, e = best_mounted(R, C, w, t, ok, X, x, A, (cam, Rm, cm, tau, still, order), th2,
                              best_cost, pretest_n, pretest_min)  # fmt: skip
    if not cost < best_cost:
        return -1, best_cost, 0, beyond
    best_e[:] = e
    R_best[:] = R[h]
    C_best[:] = C[h]
    if not still:  # (a still model's velocities: none written)
        w_best[:] = w[h]
        t_best[:] = t[h]
    n_best, m = counted(e, k, cam, pool_counts, subset)
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
    zero (:func:`solve_rotated` ``held``, each round pre-rotated by the last). Returns
    ``(R (H, 3, 3), C (H, 3))``."""
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
    for _ in range(rounds):
        sol, ok = solve_rotated(x, X, S, np.ascontiguousarray(Rc), np.zeros(X.shape[0]), cam, Rm,
                                cm, 1, True)  # fmt: skip
        if not ok.any():
            return Rg, Cg
        keep = np.flatnonzero(ok)
        S = S[keep]
        Cc = np.ascontiguousarray(sol[keep, 3:6])
        Rc = compose_rotvec(np.ascontiguousarray(sol[keep, 0:3]), Rc[keep])
    return np.concatenate((Rg, Rc)), np.concatenate((Cg, Cc))


@kernel
def moving_models(samples, x, X, tau, cam, Rm, cm, anchor, iterations):
    """The rolling-shutter models of K samples (K, 6) without a gyro
    (:func:`~.rig._hypotheses`): pre-rotated by each one's P3P pose
    (:func:`~.sampling.p3p_mounted`: one per sample) or by ``anchor`` (3, 3) unless empty,
    then ``iterations`` of :func:`solve_rotated`. Returns ``(R (H, 3, 3), C, w, t (H, 3),
    valid (H,), the sample of each (H,))``, H <= K."""
    K = samples.shape[0]
    if anchor.shape[0]:
        R0 = np.empty((K, 3, 3))
        for h in range(K):
            R0[h] = anchor
        S = samples
        own = np.arange(K)
    else:
        R0, _, own = p3p_mounted(x, X, samples, cam, Rm, cm)
        S = samples[own]
    sol, ok = solve_rotated(x, X, S, R0, tau, cam, Rm, cm, iterations)
    R = compose_rotvec(np.ascontiguousarray(sol[:, 0:3]), R0)
    C = np.ascontiguousarray(sol[:, 3:6])
    w = np.ascontiguousarray(sol[:, 6:9])
    t = np.ascontiguousarray(sol[:, 9:12])
    return R, C, w, t, ok, own


@kernel
def solve_rotated(x, X, S, R0, tau, cam, Rm, cm, iterations, held=False):
    """:func:`~rs_localizer.solvers.gr6p_1lin.gr6p_1lin_batch`'s kernel (``v_init`` zero, its
    default tolerance; no prior rows, or ``held`` the velocities held at zero by the prior
    rows ``(w, t) = 0``, the identity with right-hand side zero: with ``tau`` zero and one
    step, a global-shutter sample's correction, :func:`~.rig._held_solve`'s) on K problems
    whose world points ``X[S[k]]`` (``X`` (P, 3), ``S`` (K, N)) are pre-rotated by ``R0[k]``
    (K, 3, 3) here, at the times ``tau[S[k]]`` (``tau`` (P,) s) in the cameras ``cam[S[k]]``
    (gathered by :func:`~.sampling.gather_prerotated`); ``x`` (P, 2). Returns ``(out (K,
    12): v, C, w, t, zeros where not solved; ok (K,): solved, every entry finite)``, each
    rotation ``expm([v]x) R0[k]``."""
    K, N = S.shape[0], S.shape[1]
    xs, Xp, ts = gather_prerotated(S, R0, x, X, tau)
    cs = np.empty((K, N), dtype=np.int64)
    for k in range(K):
        for i in range(N):
            cs[k, i] = cam[S[k, i]]
    out = np.zeros((K, 12))
    ok = np.zeros(K, dtype=np.bool_)
    its = np.zeros(K, dtype=np.int64)
    err = np.zeros(K)
    P = np.zeros((K if held else 1, 6, 6))
    if held:
        for k in range(K):
            for a in range(6):
                P[k, a, a] = 1.0
    use = np.zeros(1, dtype=np.bool_)  # (a bool, as the batch's np.bool_, not a literal)
    use[0] = held
    solve_mounted(xs, Xp, ts, cs, Rm, cm, iterations, 1e-12, np.zeros((K, 3)), P,
                  np.zeros((P.shape[0], 6)), use[0], out, ok, its, err)  # fmt: skip
    checked_solutions(out, ok, 12)
    return out, ok
