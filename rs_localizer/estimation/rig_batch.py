"""The compiled kernels of the rig's RANSAC (:func:`~.rig.estimate_rig_pose`): each batch of
the search drawn (:func:`~.sampling.batch_samples`), solved (:func:`still_models`,
:func:`moving_models`: the rig's own hypotheses, :func:`~.rig._hypotheses`) and scored
(:func:`~.scoring.model_cost`, MSAC on each point's error in pixels) in one numba call
(:func:`search_batch`), as :mod:`.batch` does for one camera, termination checked after every
sample as PoseLib's loop does. The rig's step-by-step search (with a gyro, or another
pre-rotation) calls the same kernels one by one.
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel
from .._so3 import compose_rotvec
from ..solvers.lambda_twist import MAX_SOLUTIONS
from ..solvers.r6p_1lin import solve_mounted
from .batch import checked_solutions
from .plausibility import motion_checked
from .ransac import required_samples_kernel
from .sampling import batch_samples, gather_prerotated, p3p_mounted, p3p_mounted_into
from .scoring import model_cost

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
def search_batch(draws, o, K, subset, X, x, tau, cam, Rm, cm, A, still, missed, rounds, anchor,
                 iterations, w2max, v2max, th2, k, pool_counts, best_cost, it0, min_it, needed,
                 log_miss, out):  # fmt: skip
    """One batch of the compiled search: K samples of :meth:`~.view.StackedViews.samples` on
    the draws ``draws[o:o + 7 K]`` (among the pool indices ``subset`` unless empty), each
    sample's models (``still``: :func:`still_models` with ``missed``, ``rounds``; else
    :func:`moving_models` with ``anchor``, ``iterations``, those beyond ``w2max`` (rad/s)^2,
    ``v2max`` (m/s)^2 counted, not scored) scored in turn (``th2`` px^2) against the search's
    state (``best_cost``, ``it0`` samples drawn, ``min_it``, ``needed``, ``log_miss`` =
    log(1 - confidence)), a new best's inliers below ``k`` px counted (:func:`counted`); the
    batch stops after the first sample at which termination is reached
    (:func:`~.ransac.required_samples`). Returns ``(samples drawn, h, cost, inliers, models
    beyond the bounds)``: ``h`` -1 when no model beat the best, else the batch's best is
    written into ``out`` ``(errors (N,) px, R, C, w, t, missed cameras (M,) bool)``: the same
    model as :mod:`.rig`'s steps one by one, bit for bit."""
    samples = batch_samples(draws[o : o + 7 * K].reshape((7, K)), cam, pool_counts, subset)
    N = X.shape[0]
    e = np.empty(N)
    best_e, R_best, C_best, w_best, t_best, missed_best = out
    among = len(subset) if len(subset) else N
    s = 3 if still else 6
    found, n_best, beyond, drawn = -1, 0, 0, K
    # (one sample's global-shutter models' buffers; a moving frame's models of every sample)
    b, P = np.empty((3, 3)), np.empty((3, 3))
    R_cam, C_cam = np.empty((MAX_SOLUTIONS, 3, 3)), np.empty((MAX_SOLUTIONS, 3))
    Rp, Cp = np.empty((MAX_SOLUTIONS, 3, 3)), np.empty((MAX_SOLUTIONS, 3))
    z = np.zeros((2 * MAX_SOLUTIONS, 3))
    if still:
        R, C, w, t = np.empty((0, 3, 3)), np.empty((0, 3)), z, z
        ok, own = np.empty(0, dtype=np.bool_), np.empty(0, dtype=np.int64)
    else:
        R, C, w, t, ok, own = moving_models(samples, x, X, tau, cam, Rm, cm, anchor, iterations)
    H, h = len(ok), 0
    for j in range(K):
        lo = h
        if still:
            R, C = still_models(samples[j], x, X, cam, Rm, cm, missed, rounds, b, P, R_cam,
                                C_cam, Rp, Cp)  # fmt: skip
            lo, h = 0, R.shape[0]
        else:
            while h < H and own[h] == j:
                h += 1
        for g in range(lo, h):
            if not still:
                if not ok[g]:
                    continue
                finite, within = motion_checked(C, w, t, g, w2max, v2max)
                if not finite:  # (_hypotheses' finite models)
                    continue
                if not within:
                    beyond += 1
                    continue
            if still:  # (the flag a constant in each call, as in the kernels' own code)
                c = model_cost(R, C, w, t, X, tau, cam, Rm, cm, x, A, th2, True, g, best_cost, e)
            else:
                c = model_cost(R, C, w, t, X, tau, cam, Rm, cm, x, A, th2, False, g, best_cost, e)
            if c >= 0 and c < best_cost:
                best_cost, found = c, g
                best_e[:] = e
                R_best[:] = R[g]
                C_best[:] = C[g]
                if not still:
                    w_best[:] = w[g]
                    t_best[:] = t[g]
                n_best, m = counted(e, k, cam, pool_counts, subset)
                missed_best[:] = m
                needed = required_samples_kernel(n_best / among, s, log_miss)
        if it0 + j + 1 >= min_it and it0 + j + 1 >= needed:
            drawn = j + 1
            break
    return drawn, found, best_cost, n_best, beyond


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
