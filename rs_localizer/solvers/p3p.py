"""P3P: the global-shutter minimal absolute pose baseline (three correspondences).

Our own numba implementation of Lambda Twist (Persson and Nordberg, "Lambda Twist: An Accurate
Fast Robust Perspective Three Point (P3P) Solver", ECCV 2018), written from the paper in
:mod:`.lambda_twist`, is the default backend. PoseLib's P3P (``poselib.p3p``, the library
reference the tests compare against) and OpenCV's ``cv2.solveP3P`` remain selectable with
``backend=`` or the ``RS_LOCALIZER_P3P`` environment variable (read at import, an unknown
value raises ValueError there; used to time the estimator with either backend).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ._common import check_inputs
from .lambda_twist import lambda_twist, lambda_twist_batch

try:  # PoseLib (the bench extra) is optional: the "poselib" backend falls back to OpenCV
    import poselib as _poselib
except ImportError:  # pragma: no cover - exercised by test_p3p_opencv_backend
    _poselib = None

__all__ = ["BACKENDS", "DEFAULT_BACKEND", "P3PSolution", "p3p", "p3p_batch", "p3p_opencv"]

#: selectable P3P implementations
BACKENDS = ("lambda_twist", "poselib", "opencv")
#: backend used when ``backend=None``; from ``RS_LOCALIZER_P3P`` (default ``"lambda_twist"``)
DEFAULT_BACKEND = os.environ.get("RS_LOCALIZER_P3P", "lambda_twist")
if DEFAULT_BACKEND not in BACKENDS:
    raise ValueError(f"RS_LOCALIZER_P3P must be one of {BACKENDS}, got {DEFAULT_BACKEND!r}")


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


def _backend(backend):
    """The backend to run: ``backend`` or :data:`DEFAULT_BACKEND`; ``poselib`` falls back to
    ``opencv`` when PoseLib is not installed."""
    b = DEFAULT_BACKEND if backend is None else backend
    if b not in BACKENDS:
        raise ValueError(f"p3p: backend must be one of {BACKENDS}, got {b!r}")
    if b == "poselib" and _poselib is None:
        return "opencv"
    return b


def p3p(x: np.ndarray, X: np.ndarray, backend: str | None = None) -> list[P3PSolution]:
    """All (up to 4) global-shutter poses from 3 correspondences (P3P).

    Args:
        x: (3, 2) calibrated (undistorted, normalized) image points.
        X: (3, 3) world points.
        backend: ``"lambda_twist"`` (ours, Persson and Nordberg ECCV 2018), ``"poselib"``,
            ``"opencv"``, or ``None`` for :data:`DEFAULT_BACKEND`.
    Returns:
        list of :class:`P3PSolution` ``X_cam = R X + C`` (possibly empty for degenerate input,
        e.g. collinear points).
    Raises:
        ValueError: wrong shapes, N != 3, NaN/inf, unknown backend.
    """
    b = _backend(backend)
    x, X = _check(x, X)
    if b == "opencv":
        return p3p_opencv(x, X)
    xh = np.concatenate([x, np.ones((3, 1))], axis=1)
    xh /= np.linalg.norm(xh, axis=1, keepdims=True)
    if b == "lambda_twist":
        R, C = lambda_twist(xh, X)
        return [P3PSolution(R[i], C[i]) for i in range(len(R))]
    out = []
    for pose in _poselib.p3p(xh, X):
        R, C = np.asarray(pose.R), np.asarray(pose.t)
        if np.isfinite(R).all() and np.isfinite(C).all():
            out.append(P3PSolution(R, C))
    return out


def p3p_opencv(x: np.ndarray, X: np.ndarray) -> list[P3PSolution]:
    """:func:`p3p` through OpenCV's ``cv2.solveP3P`` (SOLVEPNP_P3P) with K = I."""
    import cv2

    x, X = _check(x, X)
    try:
        n, rvecs, tvecs = cv2.solveP3P(X, x, np.eye(3), None, flags=cv2.SOLVEPNP_P3P)
    except cv2.error:
        return []
    out = []
    for rv, tv in zip(rvecs[:n], tvecs[:n], strict=False):
        R, _ = cv2.Rodrigues(rv)
        C = np.asarray(tv, dtype=float).ravel()
        if np.isfinite(R).all() and np.isfinite(C).all():
            out.append(P3PSolution(R, C))
    return out


def p3p_batch(
    bearings: np.ndarray, X: np.ndarray, backend: str | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """P3P on K triplets at once (RANSAC): bearings (K, 3, 3) unit rays, X (K, 3, 3).

    Args:
        bearings: (K, 3, 3) camera rays (camera frame). X: (K, 3, 3) world points.
        backend: as in :func:`p3p` (default :data:`DEFAULT_BACKEND`, Lambda Twist).
    Returns:
        (R (M, 3, 3), C (M, 3), owner (M,) int64): all M finite solutions ``X_cam = R X + C``
        and the triplet each came from (non-decreasing). No validation of the arrays (hot
        path): callers pass finite, well-shaped arrays.
    Raises:
        ValueError: unknown backend.
    """
    b = _backend(backend)
    if b == "lambda_twist":
        return lambda_twist_batch(
            np.ascontiguousarray(bearings, dtype=np.float64),
            np.ascontiguousarray(X, dtype=np.float64),
        )
    K = len(bearings)
    if b == "poselib":
        poses = [_poselib.p3p(bk, Xk) for bk, Xk in zip(bearings, X, strict=False)]
        Rts = [p.Rt for ps in poses for p in ps]
        counts = [len(ps) for ps in poses]
    else:
        sols = [p3p_opencv(bk[:, :2] / bk[:, 2:3], Xk) for bk, Xk in zip(bearings, X, strict=False)]
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
