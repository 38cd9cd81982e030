"""The compiled kernels of the rig's RANSAC (:func:`~.rig.estimate_rig_pose`): a batch of
minimal samples drawn, solved and scored in one numba call, as :mod:`.batch` does for one camera.

:func:`still_batch` (a global-shutter rig frame: Lambda Twist P3P of one camera's 3 points
mapped to the rig, corrected on the sample's 6 points by the rig solver with the velocities
held at zero where the best model misses a camera) and :func:`moving_batch` (a rolling-shutter
one without a gyro: the P3P or a prediction's rotation pre-rotating the rig solver
(:func:`~rs_localizer.solvers.gr6p_1lin.solve_rotated`), the motion bounds) end in
:func:`best_msac`: the MSAC cost of every model on every point's reprojection error in pixels
through its camera's mounting (:func:`point_residual`), summed as ``np.sum`` sums, the lowest
kept. The rig's step-by-step search (:mod:`.rig`: with a gyro, the generalized P3P, the NumPy
implementation) calls the same kernels one by one.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._so3 import INLINE, compose_rotvec
from ..solvers.gr6p_1lin import solve_rotated, still_solve_rotated
from ..solvers.lambda_twist import lambda_twist_batch
from .plausibility import motion_norms2

__all__ = [
    "batch_samples",
    "best_counted",
    "best_msac",
    "block_sum",
    "camera_error",
    "inliers_missed",
    "lambda_twist_on_rig",
    "moving_batch",
    "pairwise_sum",
    "point_residual",
    "sample_kernel",
    "still_batch",
    "still_residual",
]


@njit(cache=True, inline=INLINE)
def camera_error(z0, z1, z2, c_, Rm, cm, x, A, i):
    """The (2,) image error (px) of point ``i`` at ``z`` in the rig frame, seen by camera
    ``c_`` through its mounting: :func:`point_residual`'s last steps."""
    q0 = Rm[c_, 0, 0] * z0 + Rm[c_, 0, 1] * z1 + Rm[c_, 0, 2] * z2 + cm[c_, 0]
    q1 = Rm[c_, 1, 0] * z0 + Rm[c_, 1, 1] * z1 + Rm[c_, 1, 2] * z2 + cm[c_, 1]
    q2 = Rm[c_, 2, 0] * z0 + Rm[c_, 2, 1] * z1 + Rm[c_, 2, 2] * z2 + cm[c_, 2]
    if q2 <= 1e-9:
        return np.inf, np.inf
    ex = q0 / q2 - x[i, 0]
    ey = q1 / q2 - x[i, 1]
    return A[i, 0] * ex + A[i, 1] * ey, A[i, 2] * ex + A[i, 3] * ey


@njit(cache=True, inline=INLINE)
def point_residual(R, C, w, t, X, tau, cam, Rm, cm, x, A, h, i):
    """The (2,) image error (px) of point ``i`` under model ``h``: predicted minus measured,
    the normalized difference times the point's 2x2 pixel Jacobian ``A[i]`` (row-major,
    :class:`~.rig._Pool`), to first order the error in the measured image; ``(inf, inf)`` behind the
    camera. Inlined (numba permitting: ``INLINE``) into each kernel that needs it: the same
    operations in each."""
    # y = R X, then the exact rotation expm(tau [w]x) y (Rodrigues)
    y0 = R[h, 0, 0] * X[i, 0] + R[h, 0, 1] * X[i, 1] + R[h, 0, 2] * X[i, 2]
    y1 = R[h, 1, 0] * X[i, 0] + R[h, 1, 1] * X[i, 1] + R[h, 1, 2] * X[i, 2]
    y2 = R[h, 2, 0] * X[i, 0] + R[h, 2, 1] * X[i, 1] + R[h, 2, 2] * X[i, 2]
    ti = tau[i]
    p0, p1, p2 = ti * w[h, 0], ti * w[h, 1], ti * w[h, 2]
    th = np.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
    if th < 1e-12:
        z0 = y0 + p1 * y2 - p2 * y1
        z1 = y1 + p2 * y0 - p0 * y2
        z2 = y2 + p0 * y1 - p1 * y0
    else:
        k0, k1, k2 = p0 / th, p1 / th, p2 / th
        c, s = np.cos(th), np.sin(th)
        kd = (k0 * y0 + k1 * y1 + k2 * y2) * (1.0 - c)
        z0 = y0 * c + (k1 * y2 - k2 * y1) * s + k0 * kd
        z1 = y1 * c + (k2 * y0 - k0 * y2) * s + k1 * kd
        z2 = y2 * c + (k0 * y1 - k1 * y0) * s + k2 * kd
    z0 += C[h, 0] + ti * t[h, 0]
    z1 += C[h, 1] + ti * t[h, 1]
    z2 += C[h, 2] + ti * t[h, 2]
    return camera_error(z0, z1, z2, cam[i], Rm, cm, x, A, i)


@njit(cache=True, inline=INLINE)
def still_residual(R, C, X, cam, Rm, cm, x, A, h, i):
    """:func:`point_residual` of a model with ``w = t = 0`` (the rotation at every capture
    time the identity): the same (2,) error, without the terms that add zeros."""
    y0 = R[h, 0, 0] * X[i, 0] + R[h, 0, 1] * X[i, 1] + R[h, 0, 2] * X[i, 2]
    y1 = R[h, 1, 0] * X[i, 0] + R[h, 1, 1] * X[i, 1] + R[h, 1, 2] * X[i, 2]
    y2 = R[h, 2, 0] * X[i, 0] + R[h, 2, 1] * X[i, 1] + R[h, 2, 2] * X[i, 2]
    z0, z1, z2 = y0 + C[h, 0], y1 + C[h, 1], y2 + C[h, 2]
    return camera_error(z0, z1, z2, cam[i], Rm, cm, x, A, i)


@njit(cache=True)
def block_sum(a, lo, n):
    """The sum of ``a[lo:lo + n]``, ``n <= 128``, as NumPy's pairwise summation sums one
    block: sequentially below 8, else in 8 interleaved partial sums."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[lo + i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    m = n - n % 8
    while i < m:
        j = lo + i
        r0 += a[j]
        r1 += a[j + 1]
        r2 += a[j + 2]
        r3 += a[j + 3]
        r4 += a[j + 4]
        r5 += a[j + 5]
        r6 += a[j + 6]
        r7 += a[j + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@njit(cache=True)
def pairwise_sum(a, lo, n):
    """The sum of ``a[lo:lo + n]`` in NumPy's pairwise order (``np.sum`` of a contiguous
    float64 row, to the bit): blocks of at most 128 (:func:`block_sum`), larger ranges
    halved at a multiple of 8 and their halves' sums added (without recursion: an explicit
    stack)."""
    if n <= 128:
        return block_sum(a, lo, n)
    st = np.empty((128, 3), dtype=np.int64)  # (start, length, halves summed)
    vals = np.empty(128)
    sp, vp = 1, 0
    st[0, 0], st[0, 1], st[0, 2] = lo, n, 0
    while sp > 0:
        sp -= 1
        a0, m, done = st[sp, 0], st[sp, 1], st[sp, 2]
        if m <= 128:
            vals[vp] = block_sum(a, a0, m)
            vp += 1
        elif done:
            vals[vp - 2] = vals[vp - 2] + vals[vp - 1]
            vp -= 1
        else:
            n2 = m // 2
            n2 -= n2 % 8
            st[sp, 0], st[sp, 1], st[sp, 2] = a0, m, 1
            st[sp + 1, 0], st[sp + 1, 1], st[sp + 1, 2] = a0 + n2, m - n2, 0
            st[sp + 2, 0], st[sp + 2, 1], st[sp + 2, 2] = a0, n2, 0
            sp += 3
    return vals[0]


@njit(cache=True)
def best_msac(R, C, w, t, X, tau, cam, Rm, cm, x, A, th2, still=False):
    """The model of the lowest MSAC cost among H models (:func:`~.rig._errors_kernel`'s errors,
    each squared error capped at ``th2`` px^2, summed as ``np.sum`` sums): ``(h, its cost,
    its (N,) errors)``, ``h`` as ``np.argmin`` of the H costs picks it (the first minimum,
    or the first NaN). A model whose running cost already exceeds the best one's is left
    before its last points: the hypotheses' models and the points are finite, so that no
    later point makes its cost NaN. ``still``: every ``w`` and ``t`` zero (the errors of
    :func:`still_residual`, the same)."""
    H, N = R.shape[0], X.shape[0]
    e = np.empty(N)
    v = np.empty(N)
    best_e = np.zeros(N)
    best, best_cost = -1, 0.0
    # a model is left once the plain running sum of its first capped squares exceeds the
    # best cost by this factor: its pairwise sum over every point is then larger (each sum of
    # N non-negative terms is within N * 2^-52 of the exact one), so it is not the argmin
    stop = 1.0 + 1e-9
    for h in range(H):
        bound = best_cost * stop if best >= 0 and np.isfinite(best_cost) else np.inf
        run = 0.0
        left = False
        for i in range(N):
            if still:
                d0, d1 = still_residual(R, C, X, cam, Rm, cm, x, A, h, i)
            else:
                d0, d1 = point_residual(R, C, w, t, X, tau, cam, Rm, cm, x, A, h, i)
            e[i] = np.sqrt(d0**2 + d1**2)
            q = e[i] * e[i]
            v[i] = th2 if q > th2 else q
            run += v[i]
            if run > bound:
                left = True
                break
        if left:
            continue
        c = pairwise_sum(v, 0, N)
        if best < 0 or (best_cost == best_cost and (c < best_cost or c != c)):
            best, best_cost = h, c
            best_e[:] = e
    return best, best_cost, best_e


@njit(cache=True)
def sample_kernel(u, cdf, eligible, counts, starts, n):
    """:func:`~.rig._sample`'s (S, 6) samples from its uniform draws ``u`` (7, S) in the order the
    NumPy form takes them: the camera (inverse of ``cdf``), three distinct points of it
    (:func:`~.rig._distinct3`), three distinct points of the ``n - 3`` others."""
    S = u.shape[1]
    out = np.empty((S, 6), dtype=np.int64)
    for k in range(S):
        j = 0
        while j < len(cdf) and cdf[j] <= u[0, k]:  # (searchsorted, side="right")
            j += 1
        cam = eligible[min(j, len(cdf) - 1)]
        for part in range(2):
            N = counts[cam] if part == 0 else n - 3
            a = np.int64(u[1 + 3 * part, k] * N)
            b = np.int64(u[2 + 3 * part, k] * (N - 1))
            if b >= a:
                b += 1
            c = np.int64(u[3 + 3 * part, k] * (N - 2))
            lo, hi = min(a, b), max(a, b)
            if c >= lo:
                c += 1
            if c >= hi:
                c += 1
            if part == 0:
                out[k, 0], out[k, 1], out[k, 2] = starts[cam] + a, starts[cam] + b, starts[cam] + c
            else:
                out[k, 3], out[k, 4], out[k, 5] = a, b, c
        t0, t1, t2 = out[k, 0], out[k, 1], out[k, 2]  # (sorted: map onto the pool without them)
        if t0 > t1:
            t0, t1 = t1, t0
        if t1 > t2:
            t1, t2 = t2, t1
        if t0 > t1:
            t0, t1 = t1, t0
        for i in range(3, 6):
            r = out[k, i]
            if r >= t0:
                r += 1
            if r >= t1:
                r += 1
            if r >= t2:
                r += 1
            out[k, i] = r
    return out


@njit(cache=True)
def lambda_twist_on_rig(bearings, X, samples, cam, Rm, cm):
    """:func:`~rs_localizer.solvers.lambda_twist.lambda_twist_batch` on the first 3 points
    of each sample (K, >= 3) of the pool's bearings (N, 3) and world points (N, 3), mapped
    to the rig through the first point's camera (``cam`` (N,), mountings ``Rm`` (M, 3, 3),
    ``cm`` (M, 3)): ``(R (H, 3, 3), C (H, 3), own (H,))`` as :func:`~.rig._p3p_on_rig`'s."""
    K = samples.shape[0]
    b = np.empty((K, 3, 3))
    P = np.empty((K, 3, 3))
    for k in range(K):
        for j in range(3):
            i = samples[k, j]
            for a in range(3):
                b[k, j, a] = bearings[i, a]
                P[k, j, a] = X[i, a]
    R_cam, C_cam, own = lambda_twist_batch(b, P)
    H = len(own)
    R = np.empty((H, 3, 3))
    C = np.empty((H, 3))
    for h in range(H):
        c = cam[samples[own[h], 0]]
        for i in range(3):
            for j in range(3):
                R[h, i, j] = (
                    Rm[c, 0, i] * R_cam[h, 0, j]
                    + Rm[c, 1, i] * R_cam[h, 1, j]
                    + (Rm[c, 2, i] * R_cam[h, 2, j])
                )
            C[h, i] = (
                Rm[c, 0, i] * (C_cam[h, 0] - cm[c, 0])
                + Rm[c, 1, i] * (C_cam[h, 1] - cm[c, 1])
                + Rm[c, 2, i] * (C_cam[h, 2] - cm[c, 2])
            )
    return R, C, own


@njit(cache=True)
def still_batch(u, sampling, subset, bearings, X, x, tau, cam, Rm, cm, A, missed, rounds, th2,
                 k, pool_counts):  # fmt: skip
    """One global-shutter batch of the compiled search in one call: :func:`~.rig._sample` from its
    uniform draws ``u`` (7, K) (``sampling``: :func:`~.rig._sampling_of`'s ``(counts, starts,
    eligible, cdf, n)``; ``subset`` (S,) the sorted pool indices sampled among, or empty: the
    whole pool), :func:`~.rig._hypotheses_still` (Lambda Twist mapped to the rig; with ``missed``
    (M,) bool any True, the samples with points in those cameras corrected ``rounds`` times
    by the rig solver with the velocities held at zero), the lowest MSAC cost among them
    (:func:`best_msac`, ``th2`` px^2) and its inliers (errors below ``k`` px;
    ``pool_counts`` (M,): every camera's points in the pool). Returns ``(h, cost, errors (N,)
    px, R (3, 3), C (3,), inliers (among ``subset`` when given), the cameras of 3 or more
    points with no inlier (M,) bool)``; ``h`` -1 when no sample gave a model. The same
    numbers as those steps called one by one, bit for bit."""
    counts = sampling[0]
    samples = batch_samples(u, sampling, subset)
    R, C, own = lambda_twist_on_rig(bearings, X, samples, cam, Rm, cm)
    if len(own) == 0:
        return -1, 0.0, np.zeros(0), np.eye(3), np.zeros(3), 0, np.zeros(len(counts), np.bool_)
    spread = np.empty(len(own), dtype=np.int64)
    m = 0
    if missed.any():
        for h in range(len(own)):
            for j in range(6):
                if missed[cam[samples[own[h], j]]]:
                    spread[m] = h
                    m += 1
                    break
    if m:
        S = np.empty((m, 6), dtype=np.int64)
        Rg = np.empty((m, 3, 3))
        for i in range(m):
            S[i] = samples[own[spread[i]]]
            Rg[i] = R[spread[i]]
        Cg = np.empty((0, 3))
        for _ in range(rounds):
            out, ok = still_solve_rotated(x, X, S, Rg, cam, Rm, cm)
            if not ok.any():
                Rg, Cg = np.empty((0, 3, 3)), np.empty((0, 3))
                break
            keep = np.flatnonzero(ok)
            S = S[keep]
            Cg = np.ascontiguousarray(out[keep, 3:6])
            Rg = compose_rotvec(np.ascontiguousarray(out[keep, 0:3]), Rg[keep])
        R, C = np.concatenate((R, Rg)), np.concatenate((C, Cg))
    z = np.zeros((len(R), 3))
    h, cost, e, n_in, missed_now = best_counted(R, C, z, z, X, tau, cam, Rm, cm, x, A, th2,
                                                 True, k, pool_counts, subset)  # fmt: skip
    return h, cost, e, R[h].copy(), C[h].copy(), n_in, missed_now


@njit(cache=True)
def batch_samples(u, sampling, subset):
    """:func:`sample_kernel`'s samples (K, 6) from the draws ``u`` (7, K) and
    :func:`~.rig._sampling_of`'s ``sampling``, mapped through ``subset`` when it is not empty."""
    counts, starts, eligible, cdf, n = sampling
    samples = sample_kernel(u, cdf, eligible, counts, starts, n)
    if len(subset):
        for a in range(samples.shape[0]):
            for b in range(6):
                samples[a, b] = subset[samples[a, b]]
    return samples


@njit(cache=True)
def best_counted(R, C, w, t, X, tau, cam, Rm, cm, x, A, th2, still, k, pool_counts, subset):
    """:func:`best_msac` of the models, then its best model's inliers (errors below
    ``k`` px; among ``subset`` when it is not empty) and the cameras of 3 or more points
    (``pool_counts``) with none: ``(h, cost, errors, inliers, those cameras (M,) bool)``."""
    h, cost, e = best_msac(R, C, w, t, X, tau, cam, Rm, cm, x, A, th2, still)
    n_in, missed = inliers_missed(e, k, cam, pool_counts)
    if len(subset):
        n_in = 0
        for i in subset:
            if e[i] < k:
                n_in += 1
    return h, cost, e, n_in, missed


@njit(cache=True)
def moving_batch(u, sampling, subset, bearings, X, x, tau, cam, Rm, cm, A, anchor, iterations,
                  w2max, v2max, th2, k, pool_counts):  # fmt: skip
    """One rolling-shutter batch of the compiled search without a gyro in one call, as
    :func:`still_batch` (its arguments, without ``missed`` and ``rounds``): the samples'
    pre-rotations (Lambda Twist mapped to the rig, or ``anchor`` (3, 3) for every sample when
    it is not empty), the rig solver on the pre-rotated samples (``iterations``,
    :func:`~rs_localizer.solvers.gr6p_1lin.solve_rotated`), its valid solutions within the
    motion bounds (``w2max`` (rad/s)^2, ``v2max`` (m/s)^2; :func:`~.rig._hypotheses`, then
    ``generate_models``' bounds), the lowest MSAC cost among them. Returns :func:`still_batch`'s
    outputs with the best model's ``w`` and ``t`` (3,) after its ``C``, and the number of
    valid solutions beyond the bounds; the rotations by the compiled Rodrigues
    (:func:`~rs_localizer._so3.compose_rotvec`: NumPy's to rounding)."""
    counts = sampling[0]
    samples = batch_samples(u, sampling, subset)
    if anchor.shape[0]:
        R0 = np.empty((samples.shape[0], 3, 3))
        for h in range(samples.shape[0]):
            R0[h] = anchor
        S = samples
    else:
        R0, _, own = lambda_twist_on_rig(bearings, X, samples, cam, Rm, cm)
        S = np.empty((len(own), 6), dtype=np.int64)
        for h in range(len(own)):
            S[h] = samples[own[h]]
    out, ok = solve_rotated(x, X, S, R0, tau, cam, Rm, cm, iterations)
    keep = np.empty(len(ok), dtype=np.int64)
    m, beyond = 0, 0
    for h in range(len(ok)):
        if not ok[h]:
            continue
        wn2, vn2 = motion_norms2(out[h, 3], out[h, 4], out[h, 5], out[h, 6], out[h, 7],
                                 out[h, 8], out[h, 9], out[h, 10], out[h, 11])  # fmt: skip
        if not (np.isfinite(wn2) and vn2 <= np.inf):  # (_hypotheses' finite models)
            continue
        if wn2 <= w2max and vn2 <= v2max:
            keep[m] = h
            m += 1
        else:
            beyond += 1
    if m == 0:
        z = np.zeros(3)
        return (-1, 0.0, np.zeros(0), np.eye(3), z, z, z, 0, np.zeros(len(counts), np.bool_),
                beyond)  # fmt: skip
    keep = keep[:m]
    v = np.ascontiguousarray(out[keep, 0:3])
    R = compose_rotvec(v, R0[keep])
    C = np.ascontiguousarray(out[keep, 3:6])
    w = np.ascontiguousarray(out[keep, 6:9])
    t = np.ascontiguousarray(out[keep, 9:12])
    h, cost, e, n_in, missed = best_counted(R, C, w, t, X, tau, cam, Rm, cm, x, A, th2, False,
                                             k, pool_counts, subset)  # fmt: skip
    return h, cost, e, R[h].copy(), C[h].copy(), w[h].copy(), t[h].copy(), n_in, missed, beyond


@njit(cache=True)
def inliers_missed(e, k, cam, counts):
    """``(the number of errors e (N,) below k, (M,) bool: the cameras of at least 3 points
    (``counts``) with none of them)``."""
    hit = np.zeros(len(counts), dtype=np.int64)
    n = 0
    for i in range(len(e)):
        if e[i] < k:
            n += 1
            hit[cam[i]] += 1
    missed = np.empty(len(counts), dtype=np.bool_)
    for c in range(len(counts)):
        missed[c] = counts[c] >= 3 and hit[c] == 0
    return n, missed
