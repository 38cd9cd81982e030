"""Numba kernels that prepare RANSAC's data and turn its minimal samples into RS solver input
(paper sec. 4).

Row validation, sampling without replacement (a camera's, and over views stacked by view: a
rig frame's, :func:`batch_samples`), each sample's P3P poses through its first point's
mounting (:func:`p3p_mounted`: a camera alone, or a rig's camera), the choice of each
sample's P3P pre-rotation, and the gather of the pre-rotated sample points, each one call per
frame or per batch of samples, so that the estimator's cost is the solvers themselves and not
array glue (a NumPy call costs 5-10 us here).
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel
from .._so3 import INLINE, copy_matrix3
from ..solvers.lambda_twist import MAX_SOLUTIONS, lambda_twist_into


@kernel
def valid_rows(u, X, max_norm):
    """(N,) bool: row i has finite pixels ``u[i]`` (N, 2) and a finite world point ``X[i]``
    (N, 3) with every coordinate within ``max_norm`` of the origin (points at infinity fail)."""
    N = u.shape[0]
    out = np.empty(N, dtype=np.bool_)
    for i in range(N):
        ok = np.isfinite(u[i, 0]) and np.isfinite(u[i, 1])
        for a in range(3):
            ok = ok and abs(X[i, a]) <= max_norm  # False for NaN
        out[i] = ok
    return out


@kernel
def draw_samples(u, pool):
    """K samples of s distinct indices from ``range(pool)``, uniformly without replacement.

    Args:
        u: (K, s) uniform numbers in [0, 1) (from the caller's seeded generator, so sampling
            is reproducible); s <= pool.
        pool: size of the index range.
    Returns:
        (K, s) int64; the j-th draw picks uniformly among the ``pool - j`` indices not yet in
        the sample (the rank of the pick among them is ``floor(u * (pool - j))``).
    """
    K, s = u.shape
    out = np.empty((K, s), dtype=np.int64)
    chosen = np.empty(s, dtype=np.int64)  # sorted ascending
    for k in range(K):
        draw_sample(u, k, 0, 0, s, pool, 0, chosen, out)
    return out


@kernel(inline=INLINE)
def draw_sample(u, k, j0, a, b, pool, offset, chosen, out):
    """Draws ``a`` to ``b - 1`` of sample ``k`` of :func:`draw_samples` (or of
    :func:`draw_samples_numpy`, with one range for these draws): the j-th into ``out[k, j]``,
    the ``floor(u[k, j0 + j] * (pool - j))``-th index of ``offset + range(pool)`` not in the
    sample yet (``u`` uniform numbers in [0, 1); ``b <= pool``, and the sample's first ``a``
    indices must lie in that range). ``chosen`` (at least b int64) holds those first ``a``
    sorted ascending and ends holding the first ``b`` so."""
    for j in range(a, b):
        c = min(int(u[k, j0 + j] * (pool - j)), pool - j - 1) + offset
        # the pick among the indices not chosen yet: step over the chosen ones at or below it
        pos = 0
        while pos < j and chosen[pos] <= c:
            c += 1
            pos += 1
        for m in range(j, pos, -1):
            chosen[m] = chosen[m - 1]
        chosen[pos] = c
        out[k, j] = c


def draw_samples_numpy(
    u: np.ndarray, pool: int | np.ndarray, offset: int | np.ndarray = 0
) -> np.ndarray:
    """:func:`draw_samples` in NumPy, all K samples at once (the NumPy implementation): the
    same (K, s) indices from the same ``u``. ``pool`` may also be (K,) int64, each sample's
    own range, or (K, s), each draw's: the j-th draw of sample k picks among the
    ``pool[k, j] - j`` indices of ``offset[k, j] + range(pool[k, j])`` (``offset`` 0, (K,) or
    (K, s) int64) not chosen yet. A rig's samples spread over its cameras so: their first
    draws within one camera's points (its range of the stacked pool), the others among every
    camera's (offset 0, the whole pool). (The chosen indices are distinct and sorted, so the
    kernel's walk over them, which stops at the first one above the pick, steps over exactly
    those at or below it: one comparison per chosen index.)"""
    K, s = u.shape
    pool, offset = np.asarray(pool), np.asarray(offset)
    out = np.empty((K, s), dtype=np.int64)
    for j in range(s):
        p = pool[:, j] if pool.ndim == 2 else pool
        c = np.minimum((u[:, j] * (p - j)).astype(np.int64), p - j - 1)
        c += offset[:, j] if offset.ndim == 2 else offset
        if j:
            chosen = np.sort(out[:, :j], axis=1)
            for m in range(j):
                c += chosen[:, m] <= c
        out[:, j] = c
    return out


@kernel
def p3p_mounted_into(x, X, sample, cam, Rm, cm, b, P, R_cam, C_cam, R, C, off):
    """Lambda Twist's solutions (Persson and Nordberg, ECCV 2018) on the first 3 points of one
    ``sample`` (indices into the normalized points ``x`` (N, 2) and world points ``X`` (N,
    3)) into ``R[off:off + n]`` (3, 3), ``C[off:off + n]`` (3,); returns n (<= 4 for a
    camera, <= 1 for a rig).

    A camera alone: ``Rm`` None (``cam``, ``cm`` None too), the poses ``x_cam = R X + C``. A
    rig: the poses mapped to the rig through the first point's camera ``c = cam[sample[0]]``
    (``cam`` (N,) int64, mountings ``x_cam = Rm[c] x_rig + cm[c]``, ``Rm`` (M, 3, 3), ``cm``
    (M, 3)): ``R = Rm[c]^T R_cam``, ``C = Rm[c]^T (C_cam - cm[c])``, and only the pose of
    least global-shutter error on the sample's other points through their mountings kept
    (:func:`_sample_error`; n = 0 when every pose puts one behind its camera), as a camera's
    pre-rotation is chosen (:func:`select_prerotations`). The bearings handed to Lambda
    Twist: the unit rays ``(x, 1) / |(x, 1)|`` of each point in its own camera. ``b``, ``P`` (3,
    3), ``R_cam`` (4, 3, 3), ``C_cam`` (4, 3): the caller's buffers; ``off`` an int64."""
    for j in range(3):
        i = sample[j]
        nrm = np.sqrt(x[i, 0] * x[i, 0] + x[i, 1] * x[i, 1] + 1.0)
        b[j, 0], b[j, 1], b[j, 2] = x[i, 0] / nrm, x[i, 1] / nrm, 1.0 / nrm
        for a in range(3):
            P[j, a] = X[i, a]
    if Rm is None:  # (a camera: numba prunes the mapping at compile time)
        return lambda_twist_into(b, P, R, C, off)
    else:
        n = lambda_twist_into(b, P, R_cam, C_cam, np.int64(0))
        c = cam[sample[0]]
        best, e_best = -1, np.inf
        for h in range(n):
            for i in range(3):
                for j in range(3):
                    R[off + h, i, j] = (
                        Rm[c, 0, i] * R_cam[h, 0, j]
                        + Rm[c, 1, i] * R_cam[h, 1, j]
                        + (Rm[c, 2, i] * R_cam[h, 2, j])
                    )
                C[off + h, i] = (
                    Rm[c, 0, i] * (C_cam[h, 0] - cm[c, 0])
                    + Rm[c, 1, i] * (C_cam[h, 1] - cm[c, 1])
                    + Rm[c, 2, i] * (C_cam[h, 2] - cm[c, 2])
                )
            e = _sample_error(R, C, off + h, sample, X, x, cam, Rm, cm)
            if e < e_best:
                best, e_best = h, e
        if best < 0:
            return 0
        if best > 0:
            copy_matrix3(R[off + best], R[off])
            for a in range(3):
                C[off, a] = C[off + best, a]
        return 1


def least_error_roots(
    R: np.ndarray,
    C: np.ndarray,
    own: np.ndarray,
    samples: np.ndarray,
    X: np.ndarray,
    x: np.ndarray,
    cam: np.ndarray | None = None,
    Rm: np.ndarray | None = None,
    cm: np.ndarray | None = None,
) -> np.ndarray:
    """The NumPy twin of the compiled choice of each sample's P3P pose (a camera's,
    :func:`select_prerotations`; a rig's, :func:`p3p_mounted_into`): among the poses ``R``
    (H, 3, 3), ``C`` (H, 3) of the samples ``own`` (H,) int64 (non-decreasing; rows of
    ``samples`` (K, s) int64), the index of each sample's pose of least :func:`_sample_error`
    (squared normalized units summed over the sample's points beyond the first three, all of
    them for 3-point samples; the first of equal ones), none where every pose puts one of
    those points behind its camera (or gives no finite error).

    A camera alone: ``cam``, ``Rm``, ``cm`` None, the poses world -> camera
    (``x_cam = R X + C``). A rig: the poses world -> rig, each point seen through its
    camera's mounting ``x_cam = Rm[c] x_rig + cm[c]``, ``c = cam[i]`` (``cam`` (N,) int64,
    ``Rm`` (M, 3, 3), ``cm`` (M, 3)). ``X`` (N, 3) world points, ``x`` (N, 2) normalized
    image points.

    Returns:
        (K',) int64 indices into the H poses, K' <= K, in increasing order of their sample.
    """
    S = samples[own, 3:] if samples.shape[1] > 3 else samples[own]
    P = np.einsum("hab,hnb->hna", R, X[S]) + C[:, None]
    if Rm is not None:
        c = cam[S]
        P = np.einsum("hnab,hnb->hna", Rm[c], P) + cm[c]
    with np.errstate(divide="ignore", invalid="ignore"):
        d = P[..., :2] / P[..., 2:3] - x[S]
        e = (d * d).sum(axis=(1, 2))
    e = np.where((P[..., 2] > 0).all(axis=1) & np.isfinite(e), e, np.inf)
    order = np.lexsort((e, own))  # (stable: the first of equal errors)
    first = order[np.unique(own[order], return_index=True)[1]]
    return first[np.isfinite(e[first])]


@kernel
def p3p_mounted(x, X, samples, cam, Rm, cm):
    """:func:`p3p_mounted_into` on each of the samples (K, >= 3) (``cam``, ``Rm``, ``cm``
    None for a camera alone): ``(R (H, 3, 3), C (H, 3), the sample of each (H,) int64)``, a
    camera's every finite solution, a rig's chosen one, grouped by sample in increasing
    order."""
    K = samples.shape[0]
    R = np.empty((MAX_SOLUTIONS * K, 3, 3))
    C = np.empty((MAX_SOLUTIONS * K, 3))
    own = np.empty(MAX_SOLUTIONS * K, dtype=np.int64)
    b, P = np.empty((3, 3)), np.empty((3, 3))
    R_cam, C_cam = np.empty((MAX_SOLUTIONS, 3, 3)), np.empty((MAX_SOLUTIONS, 3))
    m = np.int64(0)  # (an int64 from the start: one compiled p3p_mounted_into)
    for k in range(K):
        n = p3p_mounted_into(x, X, samples[k], cam, Rm, cm, b, P, R_cam, C_cam, R, C, m)
        for j in range(n):
            own[m + j] = k
        m += n
    return R[:m].copy(), C[:m].copy(), own[:m].copy()


@kernel
def gather_prerotated(samples, R_pre, x, X, r):
    """The solver input of K samples: ``x[samples]``, ``R_pre[k] X[samples[k]]``, ``r[samples]``.

    Args:
        samples: (K, s) indices; R_pre (K, 3, 3); x (N, 2); X (N, 3); r (N,).
    Returns:
        (xs (K, s, 2), Xs (K, s, 3), rs (K, s)).
    """
    K, s = samples.shape
    xs = np.empty((K, s, 2))
    Xs = np.empty((K, s, 3))
    rs = np.empty((K, s))
    for k in range(K):
        for j in range(s):
            i = samples[k, j]
            xs[k, j, 0] = x[i, 0]
            xs[k, j, 1] = x[i, 1]
            rs[k, j] = r[i]
            for a in range(3):
                Xs[k, j, a] = (
                    R_pre[k, a, 0] * X[i, 0] + R_pre[k, a, 1] * X[i, 1] + R_pre[k, a, 2] * X[i, 2]
                )
    return xs, Xs, rs


@kernel(inline=INLINE)
def _sample_error(R, C, m, sample, X, x, cam, Rm, cm):
    """Global-shutter reprojection error of the pose ``R[m], C[m]`` (``p = R[m] X + C[m]``)
    on ``sample``'s points (s,) beyond the first three (all of them for 3-point samples): the
    sum of squared distances in the normalized image plane, ``inf`` when one of them is not in
    front of its camera. A camera alone: ``Rm`` None (``cam``, ``cm`` None too), ``p`` the
    point in the camera. A rig: ``p`` in the rig, each point seen through its camera's mounting
    ``q = Rm[c] p + cm[c]``, ``c = cam[i]`` (as :func:`p3p_mounted_into`'s)."""
    s = sample.shape[0]
    first = 3 if s > 3 else 0
    e = 0.0
    for j in range(first, s):
        i = sample[j]
        p0 = R[m, 0, 0] * X[i, 0] + R[m, 0, 1] * X[i, 1] + R[m, 0, 2] * X[i, 2] + C[m, 0]
        p1 = R[m, 1, 0] * X[i, 0] + R[m, 1, 1] * X[i, 1] + R[m, 1, 2] * X[i, 2] + C[m, 1]
        p2 = R[m, 2, 0] * X[i, 0] + R[m, 2, 1] * X[i, 1] + R[m, 2, 2] * X[i, 2] + C[m, 2]
        if Rm is not None:  # (a rig: numba prunes the mapping for a camera at compile time)
            c = cam[i]
            q0 = Rm[c, 0, 0] * p0 + Rm[c, 0, 1] * p1 + Rm[c, 0, 2] * p2 + cm[c, 0]
            q1 = Rm[c, 1, 0] * p0 + Rm[c, 1, 1] * p1 + Rm[c, 1, 2] * p2 + cm[c, 1]
            q2 = Rm[c, 2, 0] * p0 + Rm[c, 2, 1] * p1 + Rm[c, 2, 2] * p2 + cm[c, 2]
            p0, p1, p2 = q0, q1, q2
        if not p2 > 0.0:
            return np.inf
        dx = p0 / p2 - x[i, 0]
        dy = p1 / p2 - x[i, 1]
        e += dx * dx + dy * dy
    return e


@kernel(inline=INLINE)
def _copy_pose(R, C, m, Rout, Cout, k):
    """``Rout[k], Cout[k] = R[m], C[m]`` element by element (see
    :func:`rs_localizer._so3.copy_matrix3`)."""
    copy_matrix3(R[m], Rout[k])
    for a in range(3):
        Cout[k, a] = C[m, a]


@kernel
def select_prerotations(R, C, owner, samples, X, x, K):
    """For each of K samples pick, among its P3P solutions (R (M,3,3), C (M,3), owner (M,)),
    the one with the lowest global-shutter reprojection error on the sample's points beyond
    the first three (all of them for 3-point samples), ignoring solutions with a point behind
    the camera. Returns (R (K,3,3), C (K,3), ok (K,))."""
    Rout = np.zeros((K, 3, 3))
    Cout = np.zeros((K, 3))
    ok = np.zeros(K, dtype=np.bool_)
    best = np.full(K, np.inf)
    for m in range(R.shape[0]):
        k = owner[m]
        e = _sample_error(R, C, m, samples[k], X, x, None, None, None)
        if e < best[k]:
            best[k] = e
            _copy_pose(R, C, m, Rout, Cout, k)
            ok[k] = True
    for k in range(K):
        if not ok[k]:
            for a in range(3):
                Rout[k, a, a] = 1.0
    return Rout, Cout, ok


@kernel
def second_prerotations(R, C, owner, samples, X, x, K, ratio, slack):
    """The runner-up pre-rotation of each sample on planar scenes: P3P on coplanar
    points is two-fold ambiguous (the two poses of a plane seen under near-affine projection,
    as in IPPE), and with rolling-shutter distortion the wrong one can score best on the
    sample's other points. Among each sample's P3P solutions (as in
    :func:`select_prerotations`), the second-lowest error ``e2`` is kept when
    ``e2 <= ratio * e1 + slack`` (``e1`` the lowest; squared normalized units summed over the
    sample's points beyond the first three).

    Returns (R (K,3,3), C (K,3), kept (K,)): the runner-up per sample where kept."""
    Rout = np.zeros((K, 3, 3))
    Cout = np.zeros((K, 3))
    e1 = np.full(K, np.inf)
    e2 = np.full(K, np.inf)
    m1 = np.full(K, -1)
    m2 = np.full(K, -1)
    for m in range(R.shape[0]):
        k = owner[m]
        e = _sample_error(R, C, m, samples[k], X, x, None, None, None)
        if e < e1[k]:
            e2[k], m2[k] = e1[k], m1[k]
            e1[k], m1[k] = e, m
        elif e < e2[k]:
            e2[k], m2[k] = e, m
    kept = np.zeros(K, dtype=np.bool_)
    for k in range(K):
        if m2[k] >= 0 and e2[k] <= ratio * e1[k] + slack:
            kept[k] = True
            _copy_pose(R, C, m2[k], Rout, Cout, k)
        else:
            for a in range(3):
                Rout[k, a, a] = 1.0
    return Rout, Cout, kept


@kernel
def sample_kernel(u, cdf, eligible, counts, starts, n):
    """:meth:`~.view.StackedViews.samples`' (S, 6) samples from its uniform draws ``u`` (7, S)
    in the order the NumPy form takes them: the view (inverse of ``cdf``), then six draws as
    a camera's sample draws them (:func:`draw_sample`), the first three among the view's
    points (its range of the stack), the other three among all ``n``."""
    S = u.shape[1]
    out = np.empty((S, 6), dtype=np.int64)
    chosen = np.empty(6, dtype=np.int64)
    v = u.T  # (the draws of sample k in row k)
    for k in range(S):
        j = 0
        while j < len(cdf) and cdf[j] <= u[0, k]:  # (searchsorted, side="right")
            j += 1
        cam = eligible[min(j, len(cdf) - 1)]
        draw_sample(v, k, 1, 0, 3, counts[cam], starts[cam], chosen, out)
        draw_sample(v, k, 1, 3, 6, n, 0, chosen, out)
    return out


@kernel
def batch_sampling(cam, pool_counts, subset):
    """:func:`view_sampling` compiled: :meth:`~.view.StackedViews.samples`' distribution over a pool
    stacked by camera (``cam`` (N,) each point's camera, ``pool_counts`` (M,) each camera's
    points), among the pool indices ``subset`` when it is not empty: ``(counts (M,), starts
    (M,), eligible cameras (at least 3 points), cdf over them, n)``, the same numbers (the
    cdf's quotients summed in order, then divided by the last)."""
    M = len(pool_counts)
    counts = np.zeros(M, dtype=np.int64)
    if len(subset):
        for i in subset:
            counts[cam[i]] += 1
        n = len(subset)
    else:
        counts[:] = pool_counts
        n = len(cam)
    starts = np.empty(M, dtype=np.int64)
    a, m, total = 0, 0, 0
    for c in range(M):
        starts[c] = a
        a += counts[c]
        if counts[c] >= 3:
            m += 1
            total += counts[c]
    eligible = np.empty(m, dtype=np.int64)
    cdf = np.empty(m)
    acc, j = 0.0, 0
    for c in range(M):
        if counts[c] >= 3:
            eligible[j] = c
            acc += counts[c] / total
            cdf[j] = acc
            j += 1
    if m:
        last = cdf[m - 1]
        for j in range(m):
            cdf[j] = cdf[j] / last
    return counts, starts, eligible, cdf, n


@kernel
def batch_samples(u, cam, pool_counts, subset):
    """:func:`sample_kernel`'s samples (K, 6) from the draws ``u`` (7, K) on
    :func:`batch_sampling`'s distribution, mapped through ``subset`` when it is not empty."""
    counts, starts, eligible, cdf, n = batch_sampling(cam, pool_counts, subset)
    samples = sample_kernel(u, cdf, eligible, counts, starts, n)
    if len(subset):
        for a in range(samples.shape[0]):
            for b in range(6):
                samples[a, b] = subset[samples[a, b]]
    return samples


def view_sampling(cam: np.ndarray, M: int) -> tuple:
    """The distribution of :meth:`~.view.StackedViews.samples` over points stacked by view
    (``cam`` (N,) each point's view among M): ``(counts (M,), starts (M,), eligible views (at
    least 3 points), cdf over them, n)`` (int64 arrays; the cdf the quotients' running sums
    divided by the last): the NumPy twin of :func:`batch_sampling`, the same numbers."""
    counts = np.bincount(cam, minlength=M).astype(np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)  # (stacked by view)
    eligible = np.flatnonzero(counts >= 3).astype(np.int64)
    cdf = np.cumsum(counts[eligible] / counts[eligible].sum())
    cdf /= cdf[-1]
    return counts, starts, eligible, cdf, len(cam)
