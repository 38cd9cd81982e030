"""Rotations and the rolling-shutter (RS) camera model.

Conventions (paper sec. 2):

* World points ``X`` (N, 3) map to the camera (optical frame, z forward, x right, y down) as
  ``X_cam = R(tau) X + C(tau)`` where ``tau = r - r0`` is the rolling-shutter coordinate of the
  observation minus the reference coordinate. ``C`` is the translation of the world origin in the
  camera frame (the paper calls it C; the camera *position* in the world is ``-R^T C``).
* Linearized model (paper eq. 4/5): ``R(tau) = (I + tau [w]x) R``, ``C(tau) = C + tau t``, with
  ``R = I + [v]x`` in eq. 5. Exact constant-velocity model (data generation, refinement):
  ``R(tau) = expm(tau [w]x) R``.
* Image coordinates ``x`` (N, 2) are calibrated (normalized, undistorted): ``[X/Z, Y/Z]``.
* The RS coordinate of an image point is ``r = d . x`` with the readout direction ``d`` (2,):
  ``(0, 1)`` rows read top to bottom (the default: ``r = y``), ``(0, -1)`` bottom to top,
  ``(1, 0)`` left to right, ``(-1, 0)`` right to left. Time is proportional to ``r - r0``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = [
    "READOUT_TOP_TO_BOTTOM",
    "camera_position",
    "compose",
    "cross",
    "exact_camera_points",
    "invert",
    "matrix_to_rotvec",
    "moved",
    "nearest_rotation",
    "reprojection_errors",
    "rotation_angle_deg",
    "rotvec_to_matrix",
    "rs_project_exact",
    "rs_project_first_order",
    "rs_project_linear",
    "skew",
    "vee",
]

READOUT_TOP_TO_BOTTOM = np.array([0.0, 1.0])


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix ``[v]x`` with ``[v]x u = v x u``.

    Args:
        v: (3,) or (..., 3) vector(s).
    Returns:
        (3, 3) or (..., 3, 3) skew-symmetric matrices.
    Raises:
        ValueError: if the last dimension is not 3.
    """
    v = np.asarray(v, dtype=float)
    if v.shape[-1] != 3:
        raise ValueError(f"skew expects vectors of length 3, got shape {v.shape}")
    S = np.zeros(v.shape + (3,))
    S[..., 0, 1] = -v[..., 2]
    S[..., 0, 2] = v[..., 1]
    S[..., 1, 0] = v[..., 2]
    S[..., 1, 2] = -v[..., 0]
    S[..., 2, 0] = -v[..., 1]
    S[..., 2, 1] = v[..., 0]
    return S


def vee(S: np.ndarray) -> np.ndarray:
    """Inverse of :func:`skew` applied to the skew-symmetric part of ``S`` (..., 3, 3) -> (..., 3).

    For a general matrix this is the orthogonal projection onto skew-symmetric matrices
    (``(S - S^T) / 2``) followed by extraction of the vector.
    """
    S = np.asarray(S, dtype=float)
    A = 0.5 * (S - np.swapaxes(S, -1, -2))
    return np.stack([A[..., 2, 1], A[..., 0, 2], A[..., 1, 0]], axis=-1)


def rotvec_to_matrix(v: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation vector (..., 3) [rad] -> rotation matrix (..., 3, 3). Vectorized."""
    v = np.asarray(v, dtype=float)
    theta = np.linalg.norm(v, axis=-1)[..., None, None]
    K = skew(v)
    small = theta < 1e-8
    th = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(th) / th)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(th)) / th**2)
    return np.eye(3) + a * K + b * (K @ K)


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products over the last axis (..., 3), broadcast, without ``np.cross``'s axis
    handling (a third of the NumPy estimator's time otherwise)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _rotate_small(a: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``expm([a]x) q`` for stacked rotation vectors ``a`` and points ``q`` (..., 3)."""
    th2 = np.einsum("...i,...i->...", a, a)
    th = np.sqrt(th2)
    small = th2 < 1e-12
    ths = np.where(small, 1.0, th)
    sa = np.where(small, 1.0 - th2 / 6.0, np.sin(ths) / ths)
    ca = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(ths)) / (ths * ths))
    aq = cross(a, q)
    return q + sa[..., None] * aq + ca[..., None] * cross(a, aq)


def exact_camera_points(
    R: np.ndarray, C: np.ndarray, w: np.ndarray, t: np.ndarray, X: np.ndarray, tau: np.ndarray
) -> np.ndarray:
    """Camera-frame points of the exact constant-velocity RS model at given capture times,
    ``p_i = expm(tau_i [w]x) R X_i + C + tau_i t`` (paper eq. 2-4 with the exact rotation): the
    NumPy form of the model whose image error the estimator scores and refines (the compiled
    one: :func:`rs_localizer.estimation.scoring.exact_error2`).

    Args:
        R: (..., 3, 3) rotation at ``tau = 0``; C, w, t: (..., 3) translation, angular and
            linear velocity per unit RS coordinate (one model, or a stack of H models).
        X: (N, 3) world points (m). tau: (N,) RS coordinate of each point's capture minus the
            reference coordinate.
    Returns:
        (..., N, 3) camera-frame points (m): one row per point, per model.
    """
    q = X @ np.swapaxes(R, -1, -2)
    p = _rotate_small(tau[:, None] * w[..., None, :], q)
    p += C[..., None, :] + tau[:, None] * t[..., None, :]
    return p


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation matrix (..., 3, 3) -> rotation vector (..., 3) in radians (SciPy)."""
    R = np.asarray(R, dtype=float)
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(R.shape[:-2] + (3,))


def nearest_rotation(M: np.ndarray) -> np.ndarray:
    """Closest rotation matrix (Frobenius norm) to a 3x3 matrix ``M`` via SVD (det = +1)."""
    U, _, Vt = np.linalg.svd(np.asarray(M, dtype=float))
    D = np.eye(3)
    D[2, 2] = np.sign(np.linalg.det(U @ Vt))
    return U @ D @ Vt


def compose(R1: np.ndarray, C1: np.ndarray, R2: np.ndarray, C2: np.ndarray):
    """Pose composition ``(R1, C1) o (R2, C2)``: ``X -> R1 (R2 X + C2) + C1``. Returns (R, C)."""
    return R1 @ R2, R1 @ C2 + C1


def moved(R: np.ndarray, p: np.ndarray, d: np.ndarray, sel: Any = slice(None)) -> tuple:
    """Copies of the poses ``R`` (K, 3, 3), ``p`` (K, 3) with the poses ``sel`` (all) moved by
    the increments ``d`` (k, 6): a rotation vector (rad) composed on the left, a translation added
    (the parameters of the rig's mountings' adjustments,
    :class:`~rs_localizer.calibration.corners.RigCorners`; the marker map's output frame's
    propagation, :mod:`~rs_localizer.mapping.marker_frame`)."""
    R, p = R.copy(), p.copy()
    if len(d):
        R[sel], p[sel] = rotvec_to_matrix(d[:, :3]) @ R[sel], p[sel] + d[:, 3:]
    return R, p


def invert(R: np.ndarray, C: np.ndarray):
    """Inverse of the map ``X -> R X + C``. Returns ``(R^T, -R^T C)``."""
    return R.T, -R.T @ C


def camera_position(R: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Camera centre in world coordinates for ``X_cam = R X + C``: ``-R^T C`` (3,)."""
    return -np.asarray(R).T @ np.asarray(C)


def rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle in degrees of the relative rotation ``R_a^T R_b`` (geodesic distance on SO(3))."""
    c = (np.trace(np.asarray(R_a).T @ np.asarray(R_b)) - 1.0) / 2.0
    return float(np.degrees(np.arccos(min(max(c, -1.0), 1.0))))  # (np.clip's, cheaper)


def _readout(readout) -> np.ndarray:
    d = READOUT_TOP_TO_BOTTOM if readout is None else np.asarray(readout, dtype=float)
    if d.shape != (2,):
        raise ValueError(f"readout direction must have shape (2,), got {d.shape}")
    return d


def rs_project_first_order(P0: np.ndarray, P1: np.ndarray, r0: float = 0.0, readout=None):
    """Project points whose camera coordinates move linearly with the RS coordinate.

    ``p(r) = P0 + (r - r0) P1`` and the observation must satisfy ``r = d . (p_xy / p_z)``. This is
    a quadratic in ``r`` per point (paper eq. 5 with lambda eliminated):
    ``P1z r^2 + (P0z - r0 P1z - d.P1xy) r - (d.P0xy - r0 d.P1xy) = 0``, solved in closed form,
    vectorized; of the two roots the one nearest the global-shutter projection ``d.P0xy/P0z`` is
    taken.

    Args:
        P0, P1: (N, 3) camera coordinates at the reference row and their rate per unit ``r``.
        r0: reference RS coordinate. readout: direction ``d`` (2,), default ``(0, 1)``.
    Returns:
        (x, r): (N, 2) normalized image points and (N,) their RS coordinates. Points with no real
        root or behind the camera (``p_z <= 0``) get ``nan`` (callers treat them as outliers).
    """
    d = _readout(readout)
    P0 = np.asarray(P0, dtype=float)
    P1 = np.asarray(P1, dtype=float)
    a = P0[:, :2] @ d
    b = P1[:, :2] @ d
    A = P1[:, 2]
    B = P0[:, 2] - r0 * A - b
    Cq = -(a - r0 * b)
    with np.errstate(divide="ignore", invalid="ignore"):
        r_gs = a / P0[:, 2]
        disc = B * B - 4.0 * A * Cq
        sq = np.sqrt(np.where(disc >= 0, disc, np.nan))
        # numerically stable roots: q = -(B + sign(B) sq)/2, roots q/A and Cq/q
        q = -0.5 * (B + np.copysign(sq, B))
        r1 = q / A
        r2 = Cq / q
        linear = np.abs(A) < 1e-14 * np.maximum(np.abs(B), 1e-300)
        r_lin = -Cq / B
        pick = np.where(np.abs(r1 - r_gs) <= np.abs(r2 - r_gs), r1, r2)
        pick = np.where(np.isnan(r1), r2, np.where(np.isnan(r2), r1, pick))
        r = np.where(linear, r_lin, pick)
        p = P0 + (r - r0)[:, None] * P1
        x = p[:, :2] / p[:, 2:3]
    bad = ~np.isfinite(r) | ~(p[:, 2] > 0)
    x[bad] = np.nan
    r = np.where(bad, np.nan, r)
    return x, r


def rs_project_linear(X, R, C, w, t, r0: float = 0.0, readout=None):
    """Projection through the linearized RS model (paper eq. 4; eq. 5 with ``R = I + [v]x``).

    ``lambda [x; 1] = (I + (r - r0)[w]x) R X + C + (r - r0) t`` with ``r = d . x``.

    Args:
        X: (N, 3) world points. R: (3, 3) matrix (a rotation, or ``I + [v]x``). C, w, t: (3,).
        r0: reference RS coordinate. readout: readout direction ``d`` (2,).
    Returns:
        (x, r): (N, 2) normalized image points, (N,) RS coordinates; ``nan`` where no valid
        projection exists (see :func:`rs_project_first_order`).
    """
    X = np.asarray(X, dtype=float)
    RX = X @ np.asarray(R, dtype=float).T
    P0 = RX + np.asarray(C, dtype=float)
    P1 = np.cross(np.asarray(w, dtype=float), RX) + np.asarray(t, dtype=float)
    return rs_project_first_order(P0, P1, r0, readout)


def rs_project_exact(
    X, R, C, w, t, r0: float = 0.0, readout=None, iterations: int = 50, tol: float = 1e-13
):
    """Projection through the exact constant-velocity RS model (for data generation).

    ``lambda [x; 1] = expm((r - r0)[w]x) R X + C + (r - r0) t`` with ``r = d . x``. The row
    constraint is solved per point by Newton's method starting from the global-shutter row.

    Args:
        X: (N, 3) world points. R: (3, 3) rotation at the reference coordinate ``r0``.
        C: (3,) translation at ``r0``. w: (3,) angular velocity per unit ``r`` (rad).
        t: (3,) linear velocity per unit ``r``. readout: direction ``d`` (2,).
    Returns:
        (x, r) as in :func:`rs_project_linear`; ``nan`` for points that do not converge or lie
        behind the camera.
    """
    d = _readout(readout)
    X = np.asarray(X, dtype=float)
    R = np.asarray(R, dtype=float)
    C = np.asarray(C, dtype=float)
    w = np.asarray(w, dtype=float)
    t = np.asarray(t, dtype=float)
    RX = X @ R.T
    P = RX + C
    with np.errstate(divide="ignore", invalid="ignore"):
        r = (P[:, :2] @ d) / P[:, 2]
        W = skew(w)
        converged = np.zeros(len(X), dtype=bool)
        for _ in range(iterations):
            tau = r - r0
            Rt = rotvec_to_matrix(tau[:, None] * w)
            p = np.einsum("nij,nj->ni", Rt, RX) + C + tau[:, None] * t
            dp = np.einsum("ij,nj->ni", W, p - C - tau[:, None] * t) + t
            f = r - (p[:, :2] @ d) / p[:, 2]
            df = 1.0 - ((dp[:, :2] @ d) * p[:, 2] - (p[:, :2] @ d) * dp[:, 2]) / p[:, 2] ** 2
            step = f / df
            r = r - step
            converged = np.abs(step) < tol
            if np.all(converged | ~np.isfinite(step)):
                break
        tau = r - r0
        Rt = rotvec_to_matrix(tau[:, None] * w)
        p = np.einsum("nij,nj->ni", Rt, RX) + C + tau[:, None] * t
        x = p[:, :2] / p[:, 2:3]
        resid = np.abs(r - x @ d)
    bad = ~np.isfinite(r) | ~(p[:, 2] > 0) | ~(resid < 1e-9)
    x[bad] = np.nan
    r = np.where(bad, np.nan, r)
    return x, r


def reprojection_errors(x, X, R, C, w, t, r0: float = 0.0, readout=None):
    """Euclidean reprojection errors of observations under the linearized RS model.

    Args:
        x: (N, 2) observed normalized image points. X: (N, 3) world points.
        R, C, w, t, r0, readout: as in :func:`rs_project_linear`.
    Returns:
        (N,) errors in normalized units (multiply by the focal length for pixels); ``inf`` where
        the point has no valid projection.
    """
    xp, _ = rs_project_linear(X, R, C, w, t, r0, readout)
    e = np.linalg.norm(xp - np.asarray(x, dtype=float), axis=1)
    return np.where(np.isfinite(e), e, np.inf)
