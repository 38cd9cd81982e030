"""Plausibility checks of the estimator: motion bounds, cheirality, degenerate point sets.

A model that explains the correspondences is not necessarily a camera pose: with the six extra
degrees of freedom of the rolling-shutter model (``w``, ``t``), RANSAC can fit hundreds of
"inliers" of a degenerate cloud (all pixels on one image line, 3D points reflected through the
camera centre) with angular velocities of thousands of rad/s and a camera kilometres away. The
checks here keep such models out:

* :func:`plausible_motion`: the physical angular and linear velocities (paper eq. 5 with
  ``tau = time / seconds_per_unit_r``, see
  :func:`rs_localizer.estimation.estimate.physical_velocities`)
  within the bounds of :class:`~rs_localizer.estimation.estimate.EstimateOptions`. Applied to
  every RANSAC hypothesis and local-optimization candidate (an implausible model scores like
  "no inliers") and to the final model.
* :func:`depths_at_capture`: the depth of every point at its own capture time under the exact
  constant-velocity model (``expm(tau [w]x) R X + C + tau t``, the model of the refinement);
  inliers must be in front of the camera (cheirality).
* :func:`degenerate_points`, :func:`collinear_points`: point sets that fix no pose (identical
  points, 3D points on a line, image points within the inlier threshold of one image line), of
  one camera or of each camera of a rig.
* :func:`check_final_model`: the last check before ``success=True``; returns a failure reason
  (``implausible_motion``, ``cheirality``) or ``None``.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import kernel
from ..geometry import exact_camera_points

__all__ = [
    "CHEIRALITY",
    "IMPLAUSIBLE_MOTION",
    "all_finite",
    "check_final_model",
    "collinear_points",
    "collinear_points_numpy",
    "degenerate_points",
    "degenerate_points_numpy",
    "depths_at_capture",
    "final_check",
    "final_model_check",
    "final_model_check_numpy",
    "finite_model",
    "motion_bounds",
    "motion_norms2",
    "plausible_models",
    "plausible_motion",
]

#: failure reasons of :func:`check_final_model`
IMPLAUSIBLE_MOTION = "implausible_motion"
CHEIRALITY = "cheirality"


def motion_bounds(
    max_angular_velocity: float, max_linear_velocity: float, seconds_per_unit_r: float
) -> tuple[float, float] | None:
    """Bounds on the model velocities per unit RS coordinate ``r``.

    Args:
        max_angular_velocity: rad/s (``inf`` = no bound).
        max_linear_velocity: m/s (``inf`` = no bound).
        seconds_per_unit_r: the camera's capture-time difference per unit of ``r`` (s).
    Returns:
        ``(w_max, v_max)`` in rad and m per unit ``r``, or ``None`` when the timing is global
        shutter (``seconds_per_unit_r <= 0``: the model velocities have no physical scale and
        are not bounded).
    """
    s = float(seconds_per_unit_r)
    if not s > 0:
        return None
    return float(max_angular_velocity) * s, float(max_linear_velocity) * s


def plausible_motion(
    Rs: np.ndarray,
    Cs: np.ndarray,
    ws: np.ndarray,
    ts: np.ndarray,
    bounds: tuple[float, float] | None,
    compiled: bool = True,
) -> bool | np.ndarray:
    """Which models move plausibly.

    The camera's angular velocity is ``-w`` and its linear velocity ``w x C - t`` (per unit r,
    in the camera frame; see ``physical_velocities``), so a model is plausible when
    ``|w| <= w_max`` and ``|w x C - t| <= v_max``.

    Args:
        Rs (K, 3, 3) rotations (unused, for a uniform signature), Cs, ws, ts (K, 3) or (3,).
        bounds: ``(w_max, v_max)`` from :func:`motion_bounds`, or ``None`` (only finiteness
            is checked).
        compiled: False: in NumPy (:func:`plausible_models`; nothing compiles).
    Returns:
        (K,) bool, or a bool for single (3,) vectors; ``False`` for non-finite parameters.
    """
    if not compiled:
        one = np.ndim(ws) == 1
        Cs, ws, ts = (np.asarray(a, dtype=float).reshape(-1, 3) for a in (Cs, ws, ts))
        ok = plausible_models(Cs, ws, ts, bounds)
        return bool(ok[0]) if one else ok
    if np.ndim(ws) == 1:  # one model (every LO candidate): one compiled call
        f64 = np.float64
        w2max, v2max = (
            (np.inf, np.inf) if bounds is None else (float(bounds[0]) ** 2, float(bounds[1]) ** 2)
        )
        return bool(
            _plausible1(
                np.asarray(Cs, dtype=f64),
                np.asarray(ws, dtype=f64),
                np.asarray(ts, dtype=f64),
                w2max,
                v2max,
            )
        )
    Cs, ws, ts = (np.ascontiguousarray(a, dtype=np.float64).reshape(-1, 3) for a in (Cs, ws, ts))
    if bounds is None:
        return _plausible(Cs, ws, ts, np.inf, np.inf)
    return _plausible(Cs, ws, ts, float(bounds[0]) ** 2, float(bounds[1]) ** 2)


def plausible_models(
    C: np.ndarray, w: np.ndarray, t: np.ndarray, bounds: tuple[float, float] | None
) -> np.ndarray:
    """(H,) finite models moving within ``bounds`` (w_max, v_max per unit r): ``|w| <= w_max``
    and ``|w x C - t| <= v_max`` (:func:`plausible_motion` in NumPy, nothing compiled; the
    squared norms by :func:`motion_norms2`'s own code, on the (H,) columns)."""
    ok = np.isfinite(C).all(axis=1) & np.isfinite(w).all(axis=1) & np.isfinite(t).all(axis=1)
    if bounds is None:
        return ok
    with np.errstate(invalid="ignore", over="ignore"):
        wn2, vn2 = motion_norms2.py_func(*C.T, *w.T, *t.T)
        return ok & (wn2 <= bounds[0] ** 2) & (vn2 <= bounds[1] ** 2)


@kernel
def motion_norms2(C0, C1, C2, w0, w1, w2, t0, t1, t2):
    """``(|w|^2, |w x C - t|^2)`` of a model's ``C`` (m), ``w`` (rad) and ``t`` (m per unit r),
    given as their nine components: the squared angular and linear speeds per unit RS
    coordinate (:func:`rs_localizer.pose.model_twist` before its division by ``s``), which
    :func:`plausible_motion`, :func:`check_final_model` and RANSAC's hypothesis filter
    (:func:`motion_checked`) compare with the squared bounds of
    :func:`motion_bounds`. A numba kernel (scalars in and out: no array per hypothesis)."""
    v0 = w1 * C2 - w2 * C1 - t0
    v1 = w2 * C0 - w0 * C2 - t1
    v2 = w0 * C1 - w1 * C0 - t2
    return w0 * w0 + w1 * w1 + w2 * w2, v0 * v0 + v1 * v1 + v2 * v2


@kernel
def motion_checked(C, w, t, q, w2max, v2max):
    """RANSAC's hypothesis filter on model ``q`` of ``C``, ``w``, ``t`` (H, 3) (a camera's or a
    rig's fused batch, :func:`~.batch.solve_and_score`): its squared speeds
    (:func:`motion_norms2`) within the squared bounds ``w2max``, ``v2max`` (False for NaN)."""
    wn2, vn2 = motion_norms2(C[q, 0], C[q, 1], C[q, 2], w[q, 0], w[q, 1], w[q, 2], t[q, 0],
                             t[q, 1], t[q, 2])  # fmt: skip
    return wn2 <= w2max and vn2 <= v2max


@kernel
def _plausible1(C, w, t, w_max2, v_max2):
    """:func:`plausible_motion` of one model (C, w, t (3,))."""
    C0, C1, C2, w0, w1, w2, t0, t1, t2 = C[0], C[1], C[2], w[0], w[1], w[2], t[0], t[1], t[2]
    if not (
        np.isfinite(C0)
        and np.isfinite(C1)
        and np.isfinite(C2)
        and np.isfinite(w0)
        and np.isfinite(w1)
        and np.isfinite(w2)
        and np.isfinite(t0)
        and np.isfinite(t1)
        and np.isfinite(t2)
    ):
        return False
    wn2, vn2 = motion_norms2(C0, C1, C2, w0, w1, w2, t0, t1, t2)
    return wn2 <= w_max2 and vn2 <= v_max2


def all_finite(*arrays: np.ndarray) -> bool:
    """Whether every entry of the arrays is finite, in NumPy (nothing compiles): a model's
    ``(R, C, w, t)`` as :func:`finite_model` tests it compiled, or any arrays."""
    return all(np.isfinite(a).all() for a in arrays)


@kernel
def finite_model(R, C, w, t):
    """True if every entry of the model R (3, 3), C, w, t (3,) is finite (one compiled call
    instead of four NumPy reductions)."""
    for i in range(3):
        for j in range(3):
            if not np.isfinite(R[i, j]):
                return False
    return _plausible1(C, w, t, np.inf, np.inf)


@kernel
def _plausible(Cs, ws, ts, w_max2, v_max2):
    out = np.empty(Cs.shape[0], dtype=np.bool_)
    for k in range(Cs.shape[0]):
        C0, C1, C2 = Cs[k, 0], Cs[k, 1], Cs[k, 2]
        wn2, vn2 = motion_norms2(
            C0, C1, C2, ws[k, 0], ws[k, 1], ws[k, 2], ts[k, 0], ts[k, 1], ts[k, 2]
        )
        finite = (
            np.isfinite(C0)
            and np.isfinite(C1)
            and np.isfinite(C2)
            and np.isfinite(wn2)
            and np.isfinite(ts[k, 0])
            and np.isfinite(ts[k, 1])
            and np.isfinite(ts[k, 2])
        )
        out[k] = finite and wn2 <= w_max2 and vn2 <= v_max2
    return out


def depths_at_capture(
    R: np.ndarray, C: np.ndarray, w: np.ndarray, t: np.ndarray, X: np.ndarray, tau: np.ndarray
) -> np.ndarray:
    """(N,) depth (camera z, m) of each world point at its own capture time.

    Exact constant-velocity model (the refinement's, eq. 4 with the rotation
    ``expm(tau [w]x) R``): ``p_i = expm(tau_i [w]x) R X_i + C + tau_i t``; the z row of
    Rodrigues' formula (written apart from the scoring and refinement kernels).

    Args:
        R (3, 3), C, w, t (3,): the model (world -> camera at the reference row; velocities per
            unit r). X (N, 3) world points (m). tau (N,) ``r_i - r0`` of each observation.
    """
    X = np.ascontiguousarray(X, dtype=np.float64).reshape(-1, 3)
    tau = np.ascontiguousarray(tau, dtype=np.float64).reshape(-1)
    return _depths(
        np.ascontiguousarray(R, dtype=np.float64),
        *(np.ascontiguousarray(a, dtype=np.float64) for a in (C, w, t)),
        X,
        tau,
    )


@kernel
def _depths(R, C, w, t, X, tau):
    n = X.shape[0]
    out = np.empty(n)
    wn = np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    k0, k1, k2 = (w[0] / wn, w[1] / wn, w[2] / wn) if wn > 0 else (0.0, 0.0, 0.0)
    for i in range(n):
        q0 = R[0, 0] * X[i, 0] + R[0, 1] * X[i, 1] + R[0, 2] * X[i, 2]
        q1 = R[1, 0] * X[i, 0] + R[1, 1] * X[i, 1] + R[1, 2] * X[i, 2]
        q2 = R[2, 0] * X[i, 0] + R[2, 1] * X[i, 1] + R[2, 2] * X[i, 2]
        th = tau[i] * wn
        c, s = np.cos(th), np.sin(th)
        # z of q cos th + (k x q) sin th + k (k . q)(1 - cos th)
        out[i] = (
            q2 * c
            + (k0 * q1 - k1 * q0) * s
            + k2 * (k0 * q0 + k1 * q1 + k2 * q2) * (1 - c)
            + C[2]
            + tau[i] * t[2]
        )
    return out


@kernel
def masked_scatter(P, mask, scale):
    """(scatter matrix (d, d) of the centred rows ``scale * P[mask]``, their number) for
    d = 2 or 3 columns, in one pass: sums and products of the rows relative to the first
    selected one (the shift keeps the moments as accurate as a centred two-pass sum for
    points near each other and far from the origin)."""
    n, d = P.shape
    o0 = o1 = o2 = 0.0
    s0 = s1 = s2 = s00 = s01 = s02 = s11 = s12 = s22 = 0.0
    c = 0
    for i in range(n):
        if mask[i]:
            if c == 0:
                o0, o1 = scale * P[i, 0], scale * P[i, 1]
                if d == 3:
                    o2 = scale * P[i, 2]
            c += 1
            a0 = scale * P[i, 0] - o0
            a1 = scale * P[i, 1] - o1
            a2 = scale * P[i, 2] - o2 if d == 3 else 0.0
            s0 += a0
            s1 += a1
            s2 += a2
            s00 += a0 * a0
            s01 += a0 * a1
            s02 += a0 * a2
            s11 += a1 * a1
            s12 += a1 * a2
            s22 += a2 * a2
    k = 1.0 / max(c, 1)
    S = np.empty((d, d))
    S[0, 0] = s00 - s0 * s0 * k
    S[0, 1] = S[1, 0] = s01 - s0 * s1 * k
    S[1, 1] = s11 - s1 * s1 * k
    if d == 3:
        S[0, 2] = S[2, 0] = s02 - s0 * s2 * k
        S[1, 2] = S[2, 1] = s12 - s1 * s2 * k
        S[2, 2] = s22 - s2 * s2 * k
    return S, c


@kernel
def _line_rms_masked(P, mask, scale):
    """RMS distance of the 2D points ``scale * P[mask]`` (P (N, 2)) from their
    total-least-squares line (0 for fewer than 3): the square root of the smaller eigenvalue
    of their 2x2 scatter matrix over their number."""
    S, c = masked_scatter(P, mask, scale)
    if c < 3:
        return 0.0
    a, b, cc = S[0, 0], S[0, 1], S[1, 1]
    lam = 0.5 * (a + cc) - math.sqrt(max(0.25 * (a - cc) ** 2 + b * b, 0.0))
    return math.sqrt(max(lam, 0.0) / c)


@kernel
def collinear_points(X, mask, tol=1e-3):
    """Whether the 3D points ``X[mask]`` (X (N, 3), mask (N,) bool) are fewer than 3,
    identical or (nearly) on one line (the rotation about that line is free): the second
    singular value of the centred points below ``tol`` times the first (the eigenvalues of
    their scatter matrix, :func:`masked_scatter`, are the squared singular values)."""
    S, c = masked_scatter(X, mask, 1.0)
    if c < 3:
        return True
    ev = np.linalg.eigvalsh(S)  # ascending
    return not ev[2] > 0 or ev[1] < tol * tol * ev[2]


def collinear_points_numpy(X: np.ndarray, mask: np.ndarray, tol: float = 1e-3) -> bool:
    """:func:`collinear_points` in NumPy (the estimator's NumPy implementation; nothing
    compiles)."""
    P = X[mask]
    if len(P) < 3:
        return True
    ev = np.linalg.eigvalsh(np.cov(P.T, bias=True) * len(P))
    return bool(not ev[2] > 0 or ev[1] < tol**2 * ev[2])


@kernel
def degenerate_points(X, points_px, points_normalized, mask, focal, rows, threshold_px, tol=1e-3):
    """Whether the points ``mask`` selects fix no pose, of one camera or of a rig's cameras,
    in one compiled call without the fancy indexing (the estimator runs it on every frame):
    the world points :func:`collinear_points`, or every view's image points within
    ``threshold_px`` of one image line (the view's rays then span a plane through its
    camera's centre and its pose is not determined; with the RS model's velocities, RANSAC
    still "fits" them). A view's points are tested in the measured pixels and in the
    undistorted normalized coordinates times its focal length (a straight image line stays
    degenerate whichever of the two it is straight in): the RMS distance from their
    total-least-squares line below ``threshold_px``; a view of fewer than 3 selected points
    is on a line (one or two rays always lie in a plane through the camera's centre).

    Args:
        X (N, 3) world points (m); points_px (N, 2) measured pixels; points_normalized (N, 2)
        undistorted normalized coordinates; mask (N,) bool; focal (M,) each view's focal
        length (px per normalized unit); rows (M, 2) int64: view v's points are the rows
        ``rows[v, 0]:rows[v, 1]`` (a camera alone: one view, ``[[0, N]]``); threshold_px
        (px) > 0; tol: of :func:`collinear_points`.
    """
    if collinear_points(X, mask, tol):
        return True
    for v in range(rows.shape[0]):
        a, b = rows[v, 0], rows[v, 1]
        m = mask[a:b]
        if not (
            _line_rms_masked(points_px[a:b], m, 1.0) < threshold_px
            or _line_rms_masked(points_normalized[a:b], m, focal[v]) < threshold_px
        ):
            return False
    return True


def degenerate_points_numpy(
    X: np.ndarray,
    points_px: np.ndarray,
    points_normalized: np.ndarray,
    mask: np.ndarray,
    focal: np.ndarray,
    rows: np.ndarray,
    threshold_px: float,
    tol: float = 1e-3,
) -> bool:
    """:func:`degenerate_points` in NumPy, for the estimator's NumPy implementation (nothing
    compiles): the same tests on the same arrays."""
    if collinear_points_numpy(X, mask, tol):
        return True
    return all(
        _line_rms_numpy(points_px[a:b][mask[a:b]]) < threshold_px
        or _line_rms_numpy(points_normalized[a:b][mask[a:b]] * f) < threshold_px
        for (a, b), f in zip(np.asarray(rows).tolist(), np.asarray(focal).tolist(), strict=True)
    )


def _line_rms_numpy(P: np.ndarray) -> float:
    """:func:`_line_rms_masked` in NumPy."""
    if len(P) < 3:
        return 0.0
    S = np.cov(P.T, bias=True) * len(P)
    return math.sqrt(max(np.linalg.eigvalsh(S)[0], 0.0) / len(P))


@kernel
def final_model_check(R, C, w, t, X, tau, mask, w_max2, v_max2):
    """:func:`check_final_model` on :func:`depths_at_capture` of the points ``mask`` selects,
    in one compiled call: returns (0 plausible, 1 implausible motion, 2 cheirality; the number
    of all points not in front of the camera at their capture times)."""
    for i in range(3):
        for j in range(3):
            if not np.isfinite(R[i, j]):
                return 1, 0
    if not _plausible1(C, w, t, w_max2, v_max2):
        return 1, 0
    z = _depths(R, C, w, t, X, tau)
    behind = 0
    code = 0
    for i in range(z.shape[0]):
        if not z[i] > 0.0:
            behind += 1
            if mask[i]:
                code = 2
    return code, behind


def final_model_check_numpy(
    R: np.ndarray,
    C: np.ndarray,
    w: np.ndarray,
    t: np.ndarray,
    X: np.ndarray,
    tau: np.ndarray,
    mask: np.ndarray,
    w_max2: float,
    v_max2: float,
) -> tuple[int, int]:
    """:func:`final_model_check` in NumPy (the estimator's NumPy implementation)."""
    if not all_finite(R, C, w, t):
        return 1, 0
    wn2, vn2 = motion_norms2.py_func(*C, *w, *t)
    if not (wn2 <= w_max2 and vn2 <= v_max2):
        return 1, 0
    behind = ~(exact_camera_points(R, C, w, t, X, tau)[:, 2] > 0.0)
    return (2 if (behind & mask).any() else 0), int(np.count_nonzero(behind))


def final_check(
    R: np.ndarray,
    C: np.ndarray,
    w: np.ndarray,
    t: np.ndarray,
    X: np.ndarray,
    tau: np.ndarray,
    mask: np.ndarray,
    w_max2: float = np.inf,
    v_max2: float = np.inf,
    *,
    compiled: bool = True,
    views: tuple | None = None,
) -> tuple[int, int]:
    """The last check of a final model, of one camera or of a rig of cameras (``views``): a
    finite model moving within the bounds, and each point's depth at its own capture time
    under the exact constant-velocity model (paper eq. 4, Kukelova, Albl, Sugimoto, Pajdla,
    ACCV 2018) in front of its camera (:func:`final_model_check`).

    Args:
        R (3, 3), C, w, t (3,): the model (world -> camera, or world -> rig with ``views``),
            velocities per unit of ``tau``; X (N, 3) world points (m); tau (N,) their capture
            times minus the reference time; mask (N,) bool: the inliers (one not in front of
            its camera is a cheirality failure); w_max2, v_max2: the squared bounds on ``|w|``
            and ``|w x C - t|`` of the model per unit of ``tau`` (:func:`motion_bounds`;
            infinite: not checked).
        compiled: False: in NumPy (:func:`final_model_check_numpy`).
        views: ``None``: one camera at the identity mounting. A rig's views ``(R_mount (M, 3,
            3), c_mount (M, 3), rows (M, 2) int64)``: camera m (``x_cam = R_mount[m] x_rig +
            c_mount[m]``) sees the points ``rows[m, 0]:rows[m, 1]`` (the points stacked by
            camera) and checks them with its own model ``(R_m R, R_m C + c_m, R_m w, R_m t)``
            (``expm(tau [R_m w]x) R_m = R_m expm(tau [w]x)``); the bounds apply to the rig's
            model.
    Returns:
        (0 plausible, 1 not finite or implausible motion, 2 cheirality; the number of all
        points not in front of their camera at their capture times, 0 with code 1).
    """
    check = final_model_check if compiled else final_model_check_numpy
    if views is None:
        return check(R, C, w, t, X, tau, mask, w_max2, v_max2)
    if compiled:
        ok = finite_model(R, C, w, t) and _plausible1(C, w, t, w_max2, v_max2)
    else:
        ok = all_finite(R, C, w, t)
        wn2, vn2 = motion_norms2.py_func(*C, *w, *t)
        ok = ok and wn2 <= w_max2 and vn2 <= v_max2
    if not ok:
        return 1, 0
    Rm, cm, rows = views
    # (every camera's products at once: the same values as camera by camera, to the bit)
    RcR, RcC, Rcw, Rct = Rm @ R, Rm @ C + cm, Rm @ w, Rm @ t
    if compiled and mask.dtype == np.bool_ and mask.flags.c_contiguous:
        code, behind = _views_final_check(RcR, RcC, Rcw, Rct, X, tau, mask, rows)
        return int(code), int(behind)
    code, behind = 0, 0
    for m in range(len(rows)):
        a, b = int(rows[m, 0]), int(rows[m, 1])
        if b == a:
            continue
        k, n = check(RcR[m], RcC[m], Rcw[m], Rct[m], X[a:b], tau[a:b], mask[a:b], np.inf, np.inf)
        code, behind = max(code, int(k)), behind + int(n)
    return code, behind


@kernel
def _views_final_check(RcR, RcC, Rcw, Rct, X, tau, mask, rows):
    """:func:`final_model_check` of each camera m's model ``(RcR[m], RcC[m], Rcw[m],
    Rct[m])`` on its points ``rows[m, 0]:rows[m, 1]`` (without motion bounds): (the largest
    code, the number of points behind their cameras); :func:`final_check`'s ``views``."""
    code, behind = 0, 0
    for m in range(rows.shape[0]):
        a, b = rows[m, 0], rows[m, 1]
        if b == a:
            continue
        k, n = final_model_check(RcR[m], RcC[m], Rcw[m], Rct[m], X[a:b], tau[a:b], mask[a:b],
                                 np.inf, np.inf)  # fmt: skip
        code = max(code, k)
        behind += n
    return code, behind


def check_final_model(
    R: np.ndarray,
    C: np.ndarray,
    w: np.ndarray,
    t: np.ndarray,
    inlier_depths: np.ndarray,
    bounds: tuple[float, float] | None,
) -> str | None:
    """The last check before a model is reported as a pose.

    Args:
        R (3, 3), C, w, t (3,): the final model; inlier_depths (N,): its inliers' depths at
        their capture times (:func:`depths_at_capture`); bounds: :func:`motion_bounds` (or
        ``None``).
    Returns:
        ``"implausible_motion"`` (non-finite parameters or a velocity beyond the bounds),
        ``"cheirality"`` (an inlier not in front of the camera at its capture time), or
        ``None`` when the model is plausible.
    """
    if not (np.isfinite(R).all() and plausible_motion(None, C, w, t, bounds)):
        return IMPLAUSIBLE_MOTION
    z = np.asarray(inlier_depths, dtype=float)
    if not (z > 0).all():  # (False for NaN)
        return CHEIRALITY
    return None
