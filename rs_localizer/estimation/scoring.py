"""Numba kernels for RANSAC scoring: the closed-form RS projection of eq. 4/5, many hypotheses.

A camera mounted on a rig is scored by the same exact-model error on the rig's model seen from
that camera (:func:`mounted_pose`, :func:`pose_error2`), and the MSAC scores of models on a
frame's views stacked (:class:`~.view.StackedViews`) are the camera's (:func:`msac_scores`
with the mountings; :func:`best_mounted`).

Kept apart from :mod:`rs_localizer.estimation.estimate` so the estimator reads as the pipeline it
is.
The entry points release the GIL (``nogil``): the node's subscription callbacks keep taking
frames while a frame is scored.
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel
from .._so3 import FMA, INLINE, rotate_small
from ..geometry import exact_camera_points


@kernel(inline=INLINE, fastmath=FMA)
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
        return exact_error2(x0, x1, tau, q0, q1, q2, C0, C1, C2, w0, w1, w2, t0, t1, t2)
    return _image_error2(x0, x1, P00 + tau * P10, P01 + tau * P11, P02 + tau * P12)


@kernel(inline=INLINE, fastmath=FMA)
def _image_error2(x0, x1, px, py, pz):
    """Squared distance of the projection of the camera point p from x (``inf`` behind the
    camera)."""
    if not pz > 0.0:
        return np.inf
    ex = px / pz - x0
    ey = py / pz - x1
    return ex * ex + ey * ey


def exact_errors2_numpy(
    R: np.ndarray,
    C: np.ndarray,
    w: np.ndarray,
    t: np.ndarray,
    X: np.ndarray,
    x: np.ndarray,
    tau: np.ndarray,
    W: np.ndarray | None = None,
) -> np.ndarray:
    """(H, n) squared reprojection errors (normalized units) of H models (R (H, 3, 3); C, w,
    t (H, 3)) at the points ``X`` (n, 3), ``x`` (n, 2) captured at ``tau`` (n,) (``r - r0``),
    exact model (paper eq. 4); ``inf`` behind the camera. :func:`exact_error2` in NumPy (the
    estimator's NumPy implementation); with ``W`` (n, 4), each point's error whitened by its
    row-major 2x2 (:func:`exact_error2_whitened`)."""
    p = exact_camera_points(R, C, w, t, X, tau)
    z = p[..., 2]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        iz = 1.0 / z
        if W is None:
            e = (p[..., 0] * iz - x[:, 0]) ** 2 + (p[..., 1] * iz - x[:, 1]) ** 2
        else:
            ex, ey = p[..., 0] * iz - x[:, 0], p[..., 1] * iz - x[:, 1]
            e = (W[:, 0] * ex + W[:, 1] * ey) ** 2 + (W[:, 2] * ex + W[:, 3] * ey) ** 2
    return np.where(z > 0, e, np.inf)


@kernel(inline=INLINE, fastmath=FMA)
def exact_error2(x0, x1, tau, q0, q1, q2, C0, C1, C2, w0, w1, w2, t0, t1, t2):
    """Squared reprojection error of one point (``q = R X``) captured at ``tau = r - r0``,
    placed with the exact constant-velocity model ``expm(tau [w]x) q + C + tau t`` (paper
    eq. 4); ``inf`` behind the camera. The one compiled form of the exact-model error: the
    scoring kernels and :func:`rs_localizer.estimation.refine.exact_errors` inline it (with
    their own fast-math flags); the NumPy implementation's is :func:`exact_errors2_numpy`."""
    Aq0, Aq1, Aq2, _, _, _ = rotate_small(tau * w0, tau * w1, tau * w2, q0, q1, q2)
    return _image_error2(x0, x1, Aq0 + C0 + tau * t0, Aq1 + C1 + tau * t1, Aq2 + C2 + tau * t2)


@kernel(inline=INLINE, fastmath=FMA)
def measured_error2(x0, x1, d0, d1, r0e, q0, q1, q2, C0, C1, C2, w0, w1, w2, t0, t1, t2):
    """Squared reprojection error of one point (``q = R X``) at its measured capture time.

    The point's RS coordinate is its measured line, ``r - r0 = d . x - r0e`` (the per-point
    reference of :meth:`rs_localizer.camera.CameraModel.normalize`), and the point is
    placed there with the exact constant-velocity model ``expm(tau [w]x) q + C + tau t``:
    the residual :func:`rs_localizer.estimation.refine.exact_errors` and the refinement
    minimize (paper eq. 2-4 without linearization). Unlike :func:`project_error2` it needs no
    capture-row solve, and it does not undercount inliers at fast motion, where the
    first-order row misplaces points by pixels (at RS speed 1, 30 deg per frame, the true
    model had 277 of 301 inliers under :func:`project_error2`). ``inf`` behind the camera.
    """
    return exact_error2(
        x0, x1, d0 * x0 + d1 * x1 - r0e, q0, q1, q2, C0, C1, C2, w0, w1, w2, t0, t1, t2
    )


@kernel(inline=INLINE, fastmath=FMA)
def image_error2_whitened(x0, x1, px, py, pz, a00, a01, a10, a11):
    """:func:`_image_error2` with the error ``e`` whitened by the 2x2 ``a = (a00 a01; a10
    a11)``: ``|a e|^2`` (``inf`` behind the camera)."""
    if not pz > 0.0:
        return np.inf
    ex = px / pz - x0
    ey = py / pz - x1
    e0 = a00 * ex + a01 * ey
    e1 = a10 * ex + a11 * ey
    return e0 * e0 + e1 * e1


@kernel(inline=INLINE, fastmath=FMA)
def measured_error2_whitened(
    x0, x1, d0, d1, r0e, q0, q1, q2, C0, C1, C2, w0, w1, w2, t0, t1, t2, a00, a01, a10, a11
):
    """:func:`measured_error2` with the image error whitened by the point's 2x2 ``a`` (a row
    of :attr:`~.frame.Frame.W`): the error in the measured (distorted) image to first
    order, in normalized units of the mean focal length."""
    tau = d0 * x0 + d1 * x1 - r0e
    return exact_error2_whitened(
        x0, x1, tau, q0, q1, q2, C0, C1, C2, w0, w1, w2, t0, t1, t2, a00, a01, a10, a11
    )


@kernel(inline=INLINE, fastmath=FMA)
def exact_error2_whitened(
    x0, x1, tau, q0, q1, q2, C0, C1, C2, w0, w1, w2, t0, t1, t2, a00, a01, a10, a11
):
    """:func:`exact_error2` with the image error whitened by the 2x2 ``a`` (row-major)."""
    Aq0, Aq1, Aq2, _, _, _ = rotate_small(tau * w0, tau * w1, tau * w2, q0, q1, q2)
    return image_error2_whitened(
        x0,
        x1,
        Aq0 + C0 + tau * t0,
        Aq1 + C1 + tau * t1,
        Aq2 + C2 + tau * t2,
        a00,
        a01,
        a10,
        a11,
    )


@kernel(inline=INLINE, fastmath=FMA)
def _turned(Rm, c, v0, v1, v2):
    """``Rm[c] v`` for a vector ``v``: three scalars."""
    return (
        Rm[c, 0, 0] * v0 + Rm[c, 0, 1] * v1 + Rm[c, 0, 2] * v2,
        Rm[c, 1, 0] * v0 + Rm[c, 1, 1] * v1 + Rm[c, 1, 2] * v2,
        Rm[c, 2, 0] * v0 + Rm[c, 2, 1] * v1 + Rm[c, 2, 2] * v2,
    )


@kernel(inline=INLINE, fastmath=FMA)
def mounted_pose(R, C, w, t, h, Rm, cm, c, out):
    """Model ``h`` of the rig (``R`` (H, 3, 3), ``C``, ``w``, ``t`` (H, 3)) as camera ``c``'s
    own exact model, the camera mounted at ``x_cam = Rm[c] x_rig + cm[c]``, written into
    ``out`` (18,): ``(Rm[c] R[h]`` (row-major), ``Rm[c] C[h] + cm[c], Rm[c] w[h], Rm[c]
    t[h])``. Since ``Rm expm(tau [w]x) = expm(tau [Rm w]x) Rm``, the point ``Rm (expm(tau
    [w]x) R X + C + tau t) + cm`` is that model's ``expm(tau [w_c]x) R_c X + C_c + tau t_c``,
    which the camera's kernels evaluate (:func:`pose_error2`)."""
    out[0], out[3], out[6] = _turned(Rm, c, R[h, 0, 0], R[h, 1, 0], R[h, 2, 0])
    out[1], out[4], out[7] = _turned(Rm, c, R[h, 0, 1], R[h, 1, 1], R[h, 2, 1])
    out[2], out[5], out[8] = _turned(Rm, c, R[h, 0, 2], R[h, 1, 2], R[h, 2, 2])
    C0, C1, C2 = _turned(Rm, c, C[h, 0], C[h, 1], C[h, 2])
    out[9], out[10], out[11] = C0 + cm[c, 0], C1 + cm[c, 1], C2 + cm[c, 2]
    out[12], out[13], out[14] = _turned(Rm, c, w[h, 0], w[h, 1], w[h, 2])
    out[15], out[16], out[17] = _turned(Rm, c, t[h, 0], t[h, 1], t[h, 2])


@kernel(inline=INLINE, fastmath=FMA)
def pose_error2(pose, X, x, tau, A, i, still):
    """The squared image error of point ``i`` (``X`` (N, 3), ``x`` (N, 2)) under a camera's
    ``pose`` (18,: ``R`` row-major, ``C``, ``w``, ``t``; :func:`mounted_pose`) at its capture
    time ``tau[i]``: :func:`exact_error2_whitened` with the point's row-major 2x2 ``A[i]`` (a
    camera's pixel Jacobian: to first order the error in px of the measured image); ``inf``
    behind the camera. ``still``: ``w = t = 0`` (the rotation at every capture time the
    identity: the same error without the terms that add zeros)."""
    X0, X1, X2 = X[i, 0], X[i, 1], X[i, 2]
    q0 = pose[0] * X0 + pose[1] * X1 + pose[2] * X2
    q1 = pose[3] * X0 + pose[4] * X1 + pose[5] * X2
    q2 = pose[6] * X0 + pose[7] * X1 + pose[8] * X2
    if still:
        return image_error2_whitened(
            x[i, 0], x[i, 1], q0 + pose[9], q1 + pose[10], q2 + pose[11],
            A[i, 0], A[i, 1], A[i, 2], A[i, 3],
        )  # fmt: skip
    return exact_error2_whitened(
        x[i, 0], x[i, 1], tau[i], q0, q1, q2, pose[9], pose[10], pose[11],
        pose[12], pose[13], pose[14], pose[15], pose[16], pose[17],
        A[i, 0], A[i, 1], A[i, 2], A[i, 3],
    )  # fmt: skip


@kernel(fastmath=FMA)
def mounted_poses(Rs, Cs, ws, ts, valid, Rm, cm):
    """(H, M, 18) every valid hypothesis (``Rs`` (H, 3, 3), ``Cs``, ``ws``, ``ts`` (H, 3),
    ``valid`` (H,)) as each camera's own model (:func:`mounted_pose`; zeros where not
    valid): computed once per hypothesis and camera, not per point."""
    poses = np.zeros((Rs.shape[0], Rm.shape[0], 18))
    for h in range(Rs.shape[0]):
        if valid[h]:
            for c in range(Rm.shape[0]):
                mounted_pose(Rs, Cs, ws, ts, h, Rm, cm, c, poses[h, c])
    return poses


@kernel(fastmath=FMA)
def mounted_errors(R, C, w, t, h, X, x, A, mount):
    """(N,) the errors (px) of hypothesis ``h`` on every point of a rig's stacked views
    (``mount`` as :func:`msac_scores`' , ``A`` its ``W``): each point's camera's
    :func:`pose_error2`, the square root of what :func:`msac_scores` sums."""
    cam, Rm, cm, tau, still, _ = mount
    one = slice(h, h + 1)
    pose = mounted_poses(R[one], C[one], w[one], t[one], np.ones(1, dtype=np.bool_), Rm, cm)[0]
    e = np.empty(X.shape[0])
    for i in range(X.shape[0]):
        e[i] = np.sqrt(pose_error2(pose[cam[i]], X, x, tau, A, i, still))
    return e


@kernel(inline=INLINE, fastmath=FMA)
def _error2_h(x, X, r0e, d0, d1, Rs, Cs, ws, ts, h, i, exact, measured, W):
    """Squared reprojection error of point i under hypothesis h (see :func:`project_error2`,
    :func:`measured_error2` if ``measured``; :func:`measured_error2_whitened` if ``W`` (N, 4)
    has rows and ``measured``)."""
    X0, X1, X2 = X[i, 0], X[i, 1], X[i, 2]
    q0 = Rs[h, 0, 0] * X0 + Rs[h, 0, 1] * X1 + Rs[h, 0, 2] * X2
    q1 = Rs[h, 1, 0] * X0 + Rs[h, 1, 1] * X1 + Rs[h, 1, 2] * X2
    q2 = Rs[h, 2, 0] * X0 + Rs[h, 2, 1] * X1 + Rs[h, 2, 2] * X2
    if measured and W.shape[0] > 0:
        return measured_error2_whitened(
            x[i, 0], x[i, 1], d0, d1, r0e[i], q0, q1, q2,
            Cs[h, 0], Cs[h, 1], Cs[h, 2], ws[h, 0], ws[h, 1], ws[h, 2],
            ts[h, 0], ts[h, 1], ts[h, 2],
            W[i, 0], W[i, 1], W[i, 2], W[i, 3],
        )  # fmt: skip
    if measured:
        return measured_error2(
            x[i, 0], x[i, 1], d0, d1, r0e[i], q0, q1, q2,
            Cs[h, 0], Cs[h, 1], Cs[h, 2], ws[h, 0], ws[h, 1], ws[h, 2],
            ts[h, 0], ts[h, 1], ts[h, 2],
        )  # fmt: skip
    return project_error2(
        x[i, 0], x[i, 1], d0, d1, r0e[i], q0, q1, q2,
        Cs[h, 0], Cs[h, 1], Cs[h, 2], ws[h, 0], ws[h, 1], ws[h, 2],
        ts[h, 0], ts[h, 1], ts[h, 2], exact,
    )  # fmt: skip


@kernel(fastmath=FMA)
def _msac_points(
    x, X, r0e, d0, d1, Rs, Cs, ws, ts, h, start, stop, s, c, th2, bail, need, exact, measured, W,
    at,
):  # fmt: skip
    """Add points ``start <= i < stop`` to hypothesis h's running MSAC score s and inlier
    count c, stopping early once s exceeds ``bail`` or fewer than ``need`` inliers remain
    reachable. Returns (s, c, True if every point was added). The one place
    :func:`msac_scores` evaluates errors: one inlined copy of the error model to compile.
    ``at``: None (a camera's points, :func:`_error2_h`) or a rig's ``(cam, poses (H, M, 18),
    tau, still, order)`` (the i-th point ``order[i]``, its camera's :func:`pose_error2`)."""
    for i in range(start, stop):
        if at is None:  # (a camera: numba prunes the rig's branch at compile time)
            e2 = _error2_h(x, X, r0e, d0, d1, Rs, Cs, ws, ts, h, i, exact, measured, W)
        else:
            cam, poses, tau, still, order = at
            p = order[i]
            e2 = pose_error2(poses[h, cam[p]], X, x, tau, W, p, still)
        if e2 < th2:
            s += e2
            c += 1
        else:
            s += th2
        if s > bail or c + (stop - 1 - i) < need:
            return s, c, False
    return s, c, True


@kernel(fastmath=FMA)
def msac_scores(
    x,
    X,
    r0e,
    d,
    Rs,
    Cs,
    ws,
    ts,
    th2,
    valid,
    bail,
    exact=True,
    pretest_n=0,
    pretest_min=0,
    pretest_fraction=0.5,
    measured=False,
    W=None,
    mount=None,
):
    """MSAC scores of H hypotheses on N points, evaluated preemptively.

    Every valid hypothesis is first scored on the first ``pretest_n`` points (callers shuffle
    the points, so they are a random subset); the survivors are then completed in order of
    decreasing pre-test inlier count. Each completed score becomes the bail-out bound of the
    following hypotheses and raises the T(d,d)-style pre-test bound (Matas and Chum) to
    ``pretest_fraction`` of the inliers it predicts among the pre-test points, so a batch
    costs about one full evaluation plus ``pretest_n`` points per other hypothesis, and the
    best hypothesis of the batch gets its exact score.

    Args:
        x (N, 2), X (N, 3), r0e (N,) per-point reference coordinate, d (2,) readout direction,
        Rs (H, 3, 3), Cs, ws, ts (H, 3), th2 squared threshold (normalized units), valid (H,),
        bail: the best score so far (hypotheses that cannot beat it are dropped).
        exact: see :func:`project_error2`.
        measured: score with :func:`measured_error2` instead (``exact`` is then ignored).
        W: (N, 4) each point's row-major 2x2 whitening of its image error (``measured``
            only, :func:`measured_error2_whitened`; :attr:`~.frame.Frame.W`); (0, 4) or
            ``None``: none.
        pretest_n, pretest_min: pre-test size and the smallest inlier count among those points
            for a hypothesis to be completed (raised by every completed hypothesis).
        mount: None (a camera) or a rig's stacked views ``(cam (N,) int64, Rm (M, 3, 3), cm
            (M, 3), tau (N,) s, still, order (N,) int64)``: Rs ... ts are the rig's models,
            each point's error its camera's (:func:`pose_error2` of :func:`mounted_pose`, the
            mounting ``x_cam = Rm[c] x_rig + cm[c]``; ``still``: w = t = 0) with ``W`` its
            (N, 4) pixel Jacobian (errors in px, ``th2`` px^2), the points visited in
            ``order`` (a rig's views are stacked by camera: a random order makes the pre-test
            points a random subset); ``r0e``, ``d``, ``exact`` and ``measured`` unused.
    Returns:
        (scores (H,), inlier counts (H,)): the MSAC score of every hypothesis that beat all
        hypotheses completed before it, ``inf`` for invalid, pre-test-rejected or bailed ones;
        ``argmin(scores)`` is the batch's best hypothesis.
    """
    # (an "is None" test on the argument itself: the branch that cannot be typed is pruned)
    if W is None:  # noqa: SIM108 (numba prunes this branch on a None argument)
        Wa = np.zeros((0, 4))
    else:
        Wa = W
    if mount is None:
        at = None
    else:  # (each valid hypothesis's pose in each camera, once)
        cam, Rm, cm, tau, still, order = mount
        at = (cam, mounted_poses(Rs, Cs, ws, ts, valid, Rm, cm), tau, still, order)
    H, N = Rs.shape[0], x.shape[0]
    scores = np.full(H, np.inf)
    counts = np.zeros(H, dtype=np.int64)
    d0, d1 = d[0], d[1]
    n_pre = min(pretest_n, N)
    part = np.zeros(H)
    pre_cnt = np.full(H, -1, dtype=np.int64)
    zero = np.int64(0)  # (not a literal: one compiled _msac_points for both loops)
    for h in range(H):
        if not valid[h]:
            continue
        # stop once the hypothesis can no longer pass the pre-test or beat the bound
        s, c, done = _msac_points(
            x, X, r0e, d0, d1, Rs, Cs, ws, ts, h,
            zero, n_pre, 0.0, zero, th2, bail, pretest_min, exact, measured, Wa, at,
        )  # fmt: skip
        if done:
            part[h] = s
            pre_cnt[h] = c
    order = np.argsort(-pre_cnt, kind="mergesort")
    for j in range(H):
        h = order[j]
        if pre_cnt[h] < 0:
            break
        if pre_cnt[h] < pretest_min or part[h] > bail:
            continue
        s, c, _ = _msac_points(
            x, X, r0e, d0, d1, Rs, Cs, ws, ts, h,
            n_pre, N, part[h], pre_cnt[h], th2, bail, -N, exact, measured, Wa, at,
        )  # fmt: skip
        if s <= bail:
            scores[h] = s
            counts[h] = c
            bail = s
            if N > 0:
                pretest_min = max(pretest_min, int(pretest_fraction * n_pre * c / N))
    return scores, counts


@kernel
def best_mounted(R, C, w, t, valid, X, x, A, mount, th2, bail, pretest_n, pretest_min):
    """The best of H rig models (``R`` (H, 3, 3), ``C``, ``w``, ``t`` (H, 3), ``valid``
    (H,)) on a rig's stacked views (:func:`msac_scores` with ``mount``, ``A`` as its ``W``;
    the pre-test on ``pretest_n`` points, ``bail`` the best cost so far): ``(h, its cost
    (px^2), its (N,) errors px)``, ``h`` the first minimum; ``(h, inf, no errors)`` when no
    model reached ``bail``."""
    scores, _ = msac_scores(x, X, mount[3], np.zeros(2), R, C, w, t, th2, valid, bail, True,
                            pretest_n, pretest_min, 0.5, True, A, mount)  # fmt: skip
    h = np.argmin(scores)
    if not (valid[h] and scores[h] <= bail):
        return h, np.inf, np.empty(0)
    return h, scores[h], mounted_errors(R, C, w, t, h, X, x, A, mount)


@kernel(fastmath=FMA)
def errors2(x, X, r0e, d, R, C, w, t, exact=True, measured=False, W=None):
    """(N,) squared reprojection errors of one hypothesis (``inf`` where invalid); see
    :func:`project_error2` (:func:`measured_error2` if ``measured``, whitened by ``W`` (N, 4)
    if it has rows: :func:`measured_error2_whitened`)."""
    # (an "is None" test on the argument itself: the branch that cannot be typed is pruned)
    if W is None:  # noqa: SIM108 (numba prunes this branch on a None argument)
        Wa = np.zeros((0, 4))
    else:
        Wa = W
    N = x.shape[0]
    out = np.empty(N)
    for i in range(N):
        X0, X1, X2 = X[i, 0], X[i, 1], X[i, 2]
        q0 = R[0, 0] * X0 + R[0, 1] * X1 + R[0, 2] * X2
        q1 = R[1, 0] * X0 + R[1, 1] * X1 + R[1, 2] * X2
        q2 = R[2, 0] * X0 + R[2, 1] * X1 + R[2, 2] * X2
        if measured and Wa.shape[0] > 0:
            out[i] = measured_error2_whitened(
                x[i, 0], x[i, 1], d[0], d[1], r0e[i], q0, q1, q2,
                C[0], C[1], C[2], w[0], w[1], w[2], t[0], t[1], t[2],
                Wa[i, 0], Wa[i, 1], Wa[i, 2], Wa[i, 3],
            )  # fmt: skip
        elif measured:
            out[i] = measured_error2(
                x[i, 0], x[i, 1], d[0], d[1], r0e[i], q0, q1, q2,
                C[0], C[1], C[2], w[0], w[1], w[2], t[0], t[1], t[2],
            )  # fmt: skip
        else:
            out[i] = project_error2(
                x[i, 0], x[i, 1], d[0], d[1], r0e[i], q0, q1, q2,
                C[0], C[1], C[2], w[0], w[1], w[2], t[0], t[1], t[2], exact,
            )  # fmt: skip
    return out


@kernel
def exact_errors2(x, X, r0e, d, R, C, w, t, measured, W):
    """:func:`errors2` with ``exact=True`` (the estimator's errors), for callers in Python.

    ``exact`` goes in as a compile-time constant, as in :func:`msac_evaluate` and the fused
    RANSAC batch, so all of them share one compiled :func:`errors2` (numba compiles a
    constant flag and a run-time flag separately). ``W``: as :func:`msac_scores`'."""
    return errors2(x, X, r0e, d, R, C, w, t, True, measured, W)


@kernel
def exact_msac_scores(
    x, X, r0e, d, Rs, Cs, ws, ts, th2, valid, bail, pretest_n, pretest_min, pretest_fraction,
    measured, W,
):  # fmt: skip
    """:func:`msac_scores` with ``exact=True`` (the estimator's scoring), for callers in Python;
    one compiled :func:`msac_scores` with the fused RANSAC batch's (see :func:`exact_errors2`).
    """
    return msac_scores(
        x, X, r0e, d, Rs, Cs, ws, ts, th2, valid, bail, True, pretest_n, pretest_min,
        pretest_fraction, measured, W,
    )  # fmt: skip


@kernel(fastmath=FMA)
def msac_evaluate(x, X, r0e, d, R, C, w, t, th2, measured=False, W=None):
    """MSAC score, inlier mask and inlier count of one model on all N points.

    Args as :func:`errors2` (R (3, 3); C, w, t (3,)) plus th2, the squared threshold;
    ``measured``: errors at the measured capture times (:func:`measured_error2`); ``W``:
    as :func:`msac_scores`.
    Returns:
        (score, inliers (N,) bool, count); ``(inf, all False, 0)`` if a model parameter is not
        finite.
    """
    N = x.shape[0]
    inl = np.zeros(N, dtype=np.bool_)
    for a in range(3):
        if not (
            np.isfinite(C[a])
            and np.isfinite(w[a])
            and np.isfinite(t[a])
            and np.isfinite(R[a, 0])
            and np.isfinite(R[a, 1])
            and np.isfinite(R[a, 2])
        ):
            return np.inf, inl, 0
    e2 = errors2(x, X, r0e, d, R, C, w, t, True, measured, W)
    s = 0.0
    c = 0
    for i in range(N):
        if e2[i] < th2:
            s += e2[i]
            inl[i] = True
            c += 1
        else:
            s += th2
    return s, inl, c
