"""How a frame's estimate moves under acceleration during its readout.

The refinement fits the constant-velocity model of eq. 4 (``R(tau) = expm(tau [w]x) R``,
``C(tau) = C + tau t``). A camera that accelerates during the readout follows, to second
order in ``tau``,

    R(tau) = expm([tau w + tau^2 beta / 2]x) R,   C(tau) = C + tau t + tau^2 b / 2,

with ``beta = -s^2 alpha`` and ``b = beta x C - s^2 a`` (``alpha``, ``a``: the camera's
angular and linear acceleration in its optical frame, rad/s^2 and m/s^2; ``s`` the seconds
per unit RS coordinate; terms that do not involve the accelerations are left out). The
least-squares estimate then moves by ``G (alpha, a)`` to first order, with
``G = (J^T W J)^-1 J^T W D``: J the Jacobian of the weighted residuals in (delta, C, w, t) at
the estimate, D that in (beta, b), which is ``tau / 2`` times the w and t columns. The
refinement's covariance does not contain this error; on a hand-held shake (angular
acceleration 20-30 rad/s^2) it dominates: the NEES of the 12 pose and twist errors is ~150
instead of 12 on the synthetic shake, and ~13 once ``G alpha`` is removed with the true
acceleration. :class:`~rs_localizer.tracking.fusion.TwistFilter` keeps the accelerations
in its state and uses G in its measurement model.
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel
from .._so3 import skew_matrix
from ..pose import model_twist_jacobian
from .refine import point_rows, pose_scalars

__all__ = ["acceleration_sensitivity", "output_jacobian", "physical_sensitivity"]


@kernel
def _normal_blocks(R, C, w, t, X, x, tau, k, cutoff, want_H):
    """``J^T W J`` (12, 12; only if ``want_H``) and ``J^T W D`` (12, 6) over the points in
    front of the camera within ``cutoff`` (Huber weights with threshold k, as the
    refinement), D the (beta, b) columns."""
    pose = pose_scalars(R, C, w, t)
    H = np.zeros((12, 12))
    B = np.zeros((12, 6))
    row = np.empty(12)
    for i in range(X.shape[0]):
        v = point_rows(pose, X, x, tau, i, k, cutoff, 0.0)
        if not v[0]:
            continue
        d, d02, d12, ti = v[16], v[17], v[18], v[19]
        for r in range(2):
            if r == 0:
                row[0], row[1], row[2] = v[4], v[5], v[6]
                row[3], row[4], row[5] = d, 0.0, d02
                row[6], row[7], row[8] = ti * v[10], ti * v[11], ti * v[12]
                row[9], row[10], row[11] = ti * d, 0.0, ti * d02
            else:
                row[0], row[1], row[2] = v[7], v[8], v[9]
                row[3], row[4], row[5] = 0.0, d, d12
                row[6], row[7], row[8] = ti * v[13], ti * v[14], ti * v[15]
                row[9], row[10], row[11] = 0.0, ti * d, ti * d12
            h = 0.5 * ti
            for a in range(12):
                ra = row[a]
                if want_H:
                    for b in range(a, 12):
                        H[a, b] += ra * row[b]
                rh = ra * h
                for b in range(6):
                    B[a, b] += rh * row[6 + b]
    for a in range(12):
        for b in range(a):
            H[a, b] = H[b, a]
    return H, B


@kernel
def _output_jacobian(R, C, w, s):
    J = np.zeros((12, 12))
    Rt = np.ascontiguousarray(R.T)
    RC = Rt @ skew_matrix(C)
    for i in range(3):
        for j in range(3):
            # camera orientation R^T = R0^T expm(-delta): world-axis rotation phi = -R^T delta
            J[i, j] = -Rt[i, j]
            # position c = -R^T C: dc/ddelta = -R^T [C]x, dc/dC = -R^T
            J[3 + i, j] = -RC[i, j]
            J[3 + i, 3 + j] = -Rt[i, j]
    if s > 0:  # (omega, v) rows: the twist's Jacobian (pose.model_twist_jacobian, (v, omega))
        Jz = model_twist_jacobian(C, w, s)
        for i in range(3):
            for j in range(12):
                J[6 + i, j] = Jz[3 + i, j]
                J[9 + i, j] = Jz[i, j]
    return J


@kernel
def _physical(G, R, C, w, s):
    """``J_out G M``: model sensitivities per (beta, b) to outputs per (alpha, a_cam), with
    ``beta = -s^2 alpha`` and ``b = beta x C - s^2 a``."""
    M = np.zeros((6, 6))
    SC = skew_matrix(C)
    for i in range(3):
        M[i, i] = -s * s
        M[3 + i, 3 + i] = -s * s
        for j in range(3):
            M[3 + i, j] = s * s * SC[i, j]
    return _output_jacobian(R, C, w, s) @ (G @ M)


def output_jacobian(
    R: np.ndarray, C: np.ndarray, w: np.ndarray, seconds_per_unit_r: float
) -> np.ndarray:
    """(12, 12) Jacobian of the estimate's outputs (camera rotation [rad, world axes],
    position [m, world], angular velocity [rad/s, camera], linear velocity [m/s, camera]) with
    respect to the model's (delta, C, w, t) (``R = expm([delta]x) R0``; velocities per unit
    RS coordinate), at R (3, 3), C (3,), w (3,); see
    :func:`~rs_localizer.estimation.estimate.physical_velocities`. The velocity rows are zero
    for a global shutter (``seconds_per_unit_r <= 0``)."""
    f64 = np.float64
    return _output_jacobian(
        np.ascontiguousarray(R, dtype=f64),
        np.ascontiguousarray(C, dtype=f64),
        np.ascontiguousarray(w, dtype=f64),
        float(seconds_per_unit_r),
    )


def physical_sensitivity(
    G: np.ndarray,
    R: np.ndarray,
    C: np.ndarray,
    w: np.ndarray,
    seconds_per_unit_r: float,
    compiled: bool = True,
) -> np.ndarray:
    """(12, 6) the estimate's outputs (rows as ``RSPoseEstimate.covariance``: rotation,
    position, angular and linear velocity; :func:`output_jacobian`) per (angular acceleration
    [rad/s^2], linear acceleration [m/s^2]) in the camera's (or rig's) frame, from the model's
    sensitivity ``G`` (12, 6) per ``(beta, b)`` at ``R`` (3, 3), ``C``, ``w`` (3,): ``beta =
    -s^2 alpha``, ``b = beta x C - s^2 a`` with ``s = seconds_per_unit_r`` (a rig's model: 1,
    its time in seconds). The conversion of :func:`acceleration_sensitivity`, of the NumPy
    implementation's and of a rig's. ``compiled=False``: in NumPy."""
    s = float(seconds_per_unit_r)
    if compiled:
        f64 = np.float64
        return _physical(
            np.ascontiguousarray(G, dtype=f64),
            np.ascontiguousarray(R, dtype=f64),
            np.ascontiguousarray(C, dtype=f64),
            np.ascontiguousarray(w, dtype=f64),
            s,
        )
    Rt, SC = R.T, _skew(C)
    J = np.zeros((12, 12))
    J[0:3, 0:3] = -Rt
    J[3:6, 0:3] = -Rt @ SC
    J[3:6, 3:6] = -Rt
    Jz = model_twist_jacobian.py_func(C, w, s)
    J[6:9], J[9:12] = Jz[3:6], Jz[0:3]
    M = np.zeros((6, 6))
    M[np.arange(6), np.arange(6)] = -s * s
    M[3:6, 0:3] = s * s * SC
    return J @ (G @ M)


def _skew(v: np.ndarray) -> np.ndarray:
    """``[v]x`` (3, 3) of ``v`` (3,)."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def acceleration_sensitivity(
    R: np.ndarray,
    C: np.ndarray,
    w: np.ndarray,
    t: np.ndarray,
    X: np.ndarray,
    x: np.ndarray,
    tau: np.ndarray,
    seconds_per_unit_r: float,
    loss_scale: float,
    cutoff: float = np.inf,
    normal_inverse: np.ndarray | None = None,
    max_points: int | None = None,
    acceleration_block: np.ndarray | None = None,
    compiled: bool = True,
) -> np.ndarray | None:
    """First-order change of a frame's estimate per unit of in-readout acceleration.

    Args:
        R (3, 3), C, w, t (3,): the refined model (world -> camera at the reference row,
            velocities per unit RS coordinate).
        X (N, 3), x (N, 2), tau (N,): the world points, normalized observations and
            ``r_i - r0`` given to :func:`~rs_localizer.estimation.refine.refine_rs_pose`.
        seconds_per_unit_r: the camera's RS time scale (s per unit r); > 0.
        loss_scale: the refinement's Huber threshold (normalized units).
        cutoff: points farther than this from the model are left out (normalized units; the
            final refinement's truncation).
        normal_inverse: optional (12, 12) ``(J^T W J)^-1`` at the estimate (the refinement's
            covariance divided by its sigma^2; with a motion prior the posterior one, which
            makes G that of the maximum a posteriori estimate), which saves computing it.
        max_points: with ``normal_inverse``, ``J^T W D`` is summed over the first
            ``max_points`` points only and scaled by ``N / max_points`` (points in random
            order). Faster but coarse: on the synthetic shake 150 of 500 points removed only
            half as much of the acceleration's effect as all of them; the estimator uses all.
        acceleration_block: optional (12, 6) ``J^T W D`` at the estimate over the same
            points (``RefineResult.acceleration_block`` of the refinement that produced it),
            used with ``normal_inverse`` instead of another pass over the points (then a
            camera's or a rig's, whose ``J^T W D`` is over its cameras' points).
        compiled: False: with ``normal_inverse`` and ``acceleration_block``, the conversion
            in NumPy (:func:`physical_sensitivity`; nothing compiles).
    Returns:
        (12, 6): rows as ``RSPoseEstimate.covariance`` (rotation, position, angular velocity,
        linear velocity), columns per (angular acceleration [rad/s^2], linear acceleration
        [m/s^2]), both in the camera frame at the reference row. ``None`` if the normal
        matrix is singular or ``seconds_per_unit_r <= 0``.
    """
    s = float(seconds_per_unit_r)
    if not s > 0:
        return None
    f64 = np.float64
    R, C, w, t = (np.ascontiguousarray(a, dtype=f64) for a in (R, C, w, t))
    Hinv = None
    if normal_inverse is not None:
        Hinv = np.asarray(normal_inverse, dtype=f64)
        if Hinv.shape != (12, 12) or not np.isfinite(Hinv).all():
            Hinv = None
    if Hinv is not None and acceleration_block is not None:
        B = np.asarray(acceleration_block, dtype=f64)
        if B.shape == (12, 6) and np.isfinite(B).all():
            out = physical_sensitivity(Hinv @ B, R, C, w, s, compiled)
            return out if np.isfinite(out).all() else None
    n = len(X)
    m = n if (Hinv is None or max_points is None) else min(n, max(int(max_points), 1))
    H, B = _normal_blocks(
        R,
        C,
        w,
        t,
        np.ascontiguousarray(X[:m], dtype=f64),
        np.ascontiguousarray(x[:m], dtype=f64),
        np.ascontiguousarray(tau[:m], dtype=f64),
        float(loss_scale),
        float(cutoff),
        Hinv is None,
    )
    if Hinv is not None:
        G = Hinv @ (B * (n / max(m, 1)))  # d(delta, C, w, t) / d(beta, b)
    else:
        try:
            G = np.linalg.solve(H, B)
        except np.linalg.LinAlgError:
            return None
    out = physical_sensitivity(G, R, C, w, s)
    return out if np.isfinite(out).all() else None
