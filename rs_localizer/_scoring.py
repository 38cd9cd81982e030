"""Numba kernels for RANSAC scoring: the closed-form RS projection of eq. 4/5, many hypotheses.

Kept apart from :mod:`rs_localizer.estimate` so the estimator reads as the pipeline it is.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ._so3 import so3_coefficients


@njit(cache=True, inline="always")
def project_error2(x0, x1, d0, d1, r0, q0, q1, q2, C0, C1, C2, w0, w1, w2, t0, t1, t2, exact):
    """Squared reprojection error of one point whose rotated world point is ``q = R X``.

    The capture row comes from the first-order model ``p(r) = P0 + (r - r0) P1`` with
    ``P0 = q + C``, ``P1 = w x q + t`` (paper eq. 4/5): the row constraint
    ``r = d . (p_xy / p_z)`` is a quadratic in r, solved in closed form, taking the root
    nearest the global-shutter projection (see
    :func:`rs_localizer.geometry.rs_project_first_order`). With ``exact=False`` the point is
    that first-order projection (eq. 5 exactly); with ``exact=True`` it is placed at that row
    with the exact constant-velocity rotation ``expm(tau [w]x)``, which removes the
    several-pixel second-order error of the linearized rotation at fast motion (30 deg per
    frame). Returns ``inf`` if there is no valid root or the point is behind the camera.
    """
    P00, P01, P02 = q0 + C0, q1 + C1, q2 + C2
    P10 = w1 * q2 - w2 * q1 + t0
    P11 = w2 * q0 - w0 * q2 + t1
    P12 = w0 * q1 - w1 * q0 + t2
    a = d0 * P00 + d1 * P01
    b = d0 * P10 + d1 * P11
    A = P12
    B = P02 - r0 * A - b
    Cq = -(a - r0 * b)
    if P02 == 0.0:
        return np.inf
    r_gs = a / P02
    if abs(A) < 1e-14 * max(abs(B), 1e-300):
        if B == 0.0:
            return np.inf
        r = -Cq / B
    else:
        disc = B * B - 4.0 * A * Cq
        if disc < 0.0:
            return np.inf
        sq = np.sqrt(disc)
        q = -0.5 * (B + sq) if B >= 0 else -0.5 * (B - sq)
        r1 = q / A
        r2 = Cq / q if q != 0.0 else np.inf
        r = r1 if abs(r1 - r_gs) <= abs(r2 - r_gs) else r2
    tau = r - r0
    if exact:
        a0, a1, a2 = tau * w0, tau * w1, tau * w2
        sa, ca, _ = so3_coefficients(a0 * a0 + a1 * a1 + a2 * a2)
        c0 = a1 * q2 - a2 * q1
        c1 = a2 * q0 - a0 * q2
        c2 = a0 * q1 - a1 * q0
        px = q0 + sa * c0 + ca * (a1 * c2 - a2 * c1) + C0 + tau * t0
        py = q1 + sa * c1 + ca * (a2 * c0 - a0 * c2) + C1 + tau * t1
        pz = q2 + sa * c2 + ca * (a0 * c1 - a1 * c0) + C2 + tau * t2
    else:
        px = P00 + tau * P10
        py = P01 + tau * P11
        pz = P02 + tau * P12
    if not pz > 0.0:
        return np.inf
    ex = px / pz - x0
    ey = py / pz - x1
    return ex * ex + ey * ey


@njit(cache=True)
def msac_scores(x, X, r0e, d, Rs, Cs, ws, ts, th2, valid, bail, exact=True, pretest_n=0,
                pretest_min=0):
    """MSAC scores of H hypotheses on N points.

    Args:
        x (N, 2), X (N, 3), r0e (N,) per-point reference coordinate, d (2,) readout direction,
        Rs (H, 3, 3), Cs, ws, ts (H, 3), th2 squared threshold (normalized units), valid (H,),
        bail: stop scoring a hypothesis once its partial score exceeds this (best so far).
        exact: see :func:`project_error2`.
        pretest_n, pretest_min: T(d,d)-style pre-test (Matas and Chum): a hypothesis with fewer
            than ``pretest_min`` inliers among the first ``pretest_n`` points (callers shuffle
            the points) is rejected without scoring the rest.
    Returns:
        (scores (H,), inlier counts (H,)); invalid, pre-test-rejected or bailed hypotheses
        score ``inf``.
    """
    H, N = Rs.shape[0], x.shape[0]
    scores = np.full(H, np.inf)
    counts = np.zeros(H, dtype=np.int64)
    d0, d1 = d[0], d[1]
    for h in range(H):
        if not valid[h]:
            continue
        R00, R01, R02 = Rs[h, 0, 0], Rs[h, 0, 1], Rs[h, 0, 2]
        R10, R11, R12 = Rs[h, 1, 0], Rs[h, 1, 1], Rs[h, 1, 2]
        R20, R21, R22 = Rs[h, 2, 0], Rs[h, 2, 1], Rs[h, 2, 2]
        C0, C1, C2 = Cs[h, 0], Cs[h, 1], Cs[h, 2]
        w0, w1, w2 = ws[h, 0], ws[h, 1], ws[h, 2]
        t0, t1, t2 = ts[h, 0], ts[h, 1], ts[h, 2]
        s = 0.0
        c = 0
        for i in range(N):
            X0, X1, X2 = X[i, 0], X[i, 1], X[i, 2]
            e2 = project_error2(x[i, 0], x[i, 1], d0, d1, r0e[i],
                                R00 * X0 + R01 * X1 + R02 * X2,
                                R10 * X0 + R11 * X1 + R12 * X2,
                                R20 * X0 + R21 * X1 + R22 * X2,
                                C0, C1, C2, w0, w1, w2, t0, t1, t2, exact)
            if e2 < th2:
                s += e2
                c += 1
            else:
                s += th2
            if s > bail or (i + 1 == pretest_n and c < pretest_min):
                s = np.inf
                break
        if s <= bail:
            scores[h] = s
            counts[h] = c
    return scores, counts


@njit(cache=True)
def errors2(x, X, r0e, d, R, C, w, t, exact=True):
    """(N,) squared reprojection errors of one hypothesis (``inf`` where invalid); see
    :func:`project_error2`."""
    N = x.shape[0]
    out = np.empty(N)
    for i in range(N):
        X0, X1, X2 = X[i, 0], X[i, 1], X[i, 2]
        out[i] = project_error2(x[i, 0], x[i, 1], d[0], d[1], r0e[i],
                                R[0, 0] * X0 + R[0, 1] * X1 + R[0, 2] * X2,
                                R[1, 0] * X0 + R[1, 1] * X1 + R[1, 2] * X2,
                                R[2, 0] * X0 + R[2, 1] * X1 + R[2, 2] * X2,
                                C[0], C[1], C[2], w[0], w[1], w[2], t[0], t[1], t[2], exact)
    return out


@njit(cache=True)
def select_prerotations(R, C, owner, samples, X, x, K):
    """For each of K samples pick, among its P3P solutions (R (M,3,3), C (M,3), owner (M,)),
    the one with the lowest global-shutter reprojection error on the sample's points beyond
    the first three (all of them for 3-point samples), ignoring solutions with a point behind
    the camera. Returns (R (K,3,3), C (K,3), ok (K,))."""
    Rout = np.zeros((K, 3, 3))
    Cout = np.zeros((K, 3))
    ok = np.zeros(K, dtype=np.bool_)
    best = np.full(K, np.inf)
    s = samples.shape[1]
    first = 3 if s > 3 else 0
    for m in range(R.shape[0]):
        k = owner[m]
        e = 0.0
        for j in range(first, s):
            i = samples[k, j]
            p0 = R[m, 0, 0] * X[i, 0] + R[m, 0, 1] * X[i, 1] + R[m, 0, 2] * X[i, 2] + C[m, 0]
            p1 = R[m, 1, 0] * X[i, 0] + R[m, 1, 1] * X[i, 1] + R[m, 1, 2] * X[i, 2] + C[m, 1]
            p2 = R[m, 2, 0] * X[i, 0] + R[m, 2, 1] * X[i, 1] + R[m, 2, 2] * X[i, 2] + C[m, 2]
            if not p2 > 0.0:
                e = np.inf
                break
            dx = p0 / p2 - x[i, 0]
            dy = p1 / p2 - x[i, 1]
            e += dx * dx + dy * dy
        if e < best[k]:
            best[k] = e
            Rout[k] = R[m]
            Cout[k] = C[m]
            ok[k] = True
    for k in range(K):
        if not ok[k]:
            for a in range(3):
                Rout[k, a, a] = 1.0
    return Rout, Cout, ok
