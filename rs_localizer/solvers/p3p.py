"""P3P: the global-shutter minimal absolute pose baseline (three correspondences).

Wraps PoseLib's P3P (``poselib.p3p``, ~3 us per call here) and falls back to OpenCV's
``cv2.solveP3P`` (~40 us) when PoseLib is not installed. Both are well-kept libraries; we do
not write our own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._common import check_inputs

try:  # PoseLib is a hard dependency of the package, but keep OpenCV as a working fallback
    import poselib as _poselib
except ImportError:  # pragma: no cover - exercised by test_p3p_opencv_backend
    _poselib = None

__all__ = ["P3PSolution", "p3p", "p3p_opencv", "p3p_batch"]


@dataclass(frozen=True)
class P3PSolution:
    """A global-shutter pose ``X_cam = R X + C``: R (3, 3) rotation, C (3,) translation."""

    R: np.ndarray
    C: np.ndarray


def _check(x, X):
    x, X, _, _ = check_inputs(x, X, None, 0.0, 3, "p3p")
    if len(x) != 3:
        raise ValueError(f"p3p: needs exactly 3 correspondences, got {len(x)}")
    return x, X


def p3p(x, X) -> list[P3PSolution]:
    """All (up to 4) global-shutter poses from 3 correspondences (P3P).

    Args:
        x: (3, 2) calibrated (undistorted, normalized) image points.
        X: (3, 3) world points.
    Returns:
        list of :class:`P3PSolution` (possibly empty for degenerate input, e.g. collinear points).
    Raises:
        ValueError: wrong shapes, N != 3, NaN/inf.
    """
    x, X = _check(x, X)
    if _poselib is None:
        return p3p_opencv(x, X)
    xh = np.concatenate([x, np.ones((3, 1))], axis=1)
    xh /= np.linalg.norm(xh, axis=1, keepdims=True)
    out = []
    for pose in _poselib.p3p(xh, X):
        R, C = np.asarray(pose.R), np.asarray(pose.t)
        if np.isfinite(R).all() and np.isfinite(C).all():
            out.append(P3PSolution(R, C))
    return out


def p3p_opencv(x, X) -> list[P3PSolution]:
    """:func:`p3p` through OpenCV's ``cv2.solveP3P`` (SOLVEPNP_P3P) with K = I."""
    import cv2

    x, X = _check(x, X)
    try:
        n, rvecs, tvecs = cv2.solveP3P(X, x, np.eye(3), None, flags=cv2.SOLVEPNP_P3P)
    except cv2.error:
        return []
    out = []
    for rv, tv in zip(rvecs[:n], tvecs[:n]):
        R, _ = cv2.Rodrigues(rv)
        C = np.asarray(tv, dtype=float).ravel()
        if np.isfinite(R).all() and np.isfinite(C).all():
            out.append(P3PSolution(R, C))
    return out


def p3p_batch(bearings, X):
    """P3P on K triplets at once (RANSAC): bearings (K, 3, 3) unit rays, X (K, 3, 3).

    Returns:
        (R (M, 3, 3), C (M, 3), owner (M,)): all M finite solutions and the triplet each came
        from. No validation (hot path): callers pass finite, well-shaped arrays.
    """
    K = len(bearings)
    if _poselib is not None:
        poses = [_poselib.p3p(b, Xk) for b, Xk in zip(bearings, X)]
        Rts = [p.Rt for ps in poses for p in ps]
        counts = [len(ps) for ps in poses]
    else:
        sols = [p3p_opencv(b[:, :2] / b[:, 2:3], Xk) for b, Xk in zip(bearings, X)]
        Rts = [np.c_[s.R, s.C] for ss in sols for s in ss]
        counts = [len(ss) for ss in sols]
    if not Rts:
        return np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    Rt = np.array(Rts)
    own = np.repeat(np.arange(K, dtype=np.int64), counts)
    if not np.isfinite(Rt).all():  # rare: drop non-finite solutions
        ok = np.isfinite(Rt).all(axis=(1, 2))
        Rt, own = Rt[ok], own[ok]
    return np.ascontiguousarray(Rt[:, :, :3]), np.ascontiguousarray(Rt[:, :, 3]), own
