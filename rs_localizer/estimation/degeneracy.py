"""Planar and near-degenerate configurations of the RS pose problem.

Two measures, both reported in :class:`~rs_localizer.estimation.estimate.RSPoseEstimate`:

- :func:`planarity`: thickness of the 3D points relative to their extent, the ratio of the
  smallest to the largest singular value of the centred points. 0 on a board, a marker or a
  wall; ~0.3-0.6 for points spread through a room or a corridor. Below
  :data:`PLANAR_TOLERANCE` the scene counts as planar: R9P cannot be used (its 18 unknowns
  lose 3 dimensions on coplanar points) and hypothesis generation uses the motion prior
  (damped linear solves).
- :func:`far_side_fraction`: where the other points lie relative to the plane of a planar
  inlier set, seen from the camera. A camera that really sees a wall of a room sees it from the
  room's side; a fit that explains one wall of a 3D scene from outside the scene (the wall seen
  from behind: what mirrored or reflected correspondences give, since a plane seen from behind
  is its mirror image) has the rest of the scene beyond that wall.
- :func:`condition_number`: of the data's information matrix of the 12 parameters (pose and
  velocities) after Jacobi scaling (each parameter divided by its own information, so the
  number does not depend on units). Large values mean some combination of rotation and
  velocity is barely determined by the image: on planar scenes the maximum-likelihood estimate
  is then near-degenerate and the motion prior carries that combination.
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel
from .plausibility import masked_scatter

__all__ = ["PLANAR_TOLERANCE", "condition_number", "far_side_fraction", "planarity"]

#: scenes thinner than this fraction of their extent count as planar (a facade with 20 cm of
#: relief over 10 m: 0.02; a desk with objects is well above)
PLANAR_TOLERANCE = 0.05


@kernel
def _planarity(X, mask):
    for i in range(X.shape[0]):
        if mask[i] and not (np.isfinite(X[i, 0]) and np.isfinite(X[i, 1]) and np.isfinite(X[i, 2])):
            return np.nan
    S, c = masked_scatter(X, mask, 1.0)
    if c < 3:
        return 0.0
    ev = np.linalg.eigvalsh(S)
    if not ev[2] > 0.0:
        return 0.0
    return np.sqrt(max(ev[0], 0.0) / ev[2])


def planarity(X: np.ndarray, mask: np.ndarray | None = None, compiled: bool = True) -> float:
    """Smallest over largest singular value of the centred points ``X`` (N, 3) (m), or of
    the rows ``mask`` (N,) bool selects (without copying them).

    0 for coplanar points (and for fewer than 3 points or a single repeated point: no extent,
    nothing to measure), up to 1 for an isotropic cloud; NaN if a selected point is not
    finite. ``compiled=False``: in NumPy (the estimator's NumPy implementation; fewer than 3
    points give 0 before the finiteness test). Raises ValueError for a wrong shape of ``X``
    or ``mask``.
    """
    X = np.ascontiguousarray(X, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 3:
        raise ValueError(f"X must have shape (N, 3), got {X.shape}")
    if mask is None:
        mask = np.ones(len(X), dtype=np.bool_)
    else:
        mask = np.asarray(mask, dtype=np.bool_)
        if mask.shape != (len(X),):
            raise ValueError(f"mask must have shape ({len(X)},), got {mask.shape}")
    if not compiled:
        return _planarity_numpy(X[mask])
    return float(_planarity(X, mask))


def coplanar(X: np.ndarray, compiled: bool = True) -> bool:
    """Whether the points ``X`` (N, 3) (m) are coplanar: :func:`planarity` below
    :data:`PLANAR_TOLERANCE` (a camera's frame, a rig's views, a few points' tag)."""
    return bool(planarity(X, compiled=compiled) < PLANAR_TOLERANCE)


def _planarity_numpy(X: np.ndarray) -> float:
    if len(X) < 3:
        return 0.0
    if not np.isfinite(X).all():
        return float("nan")
    ev = np.linalg.eigvalsh(np.cov(X.T, bias=True) * len(X))
    return 0.0 if not ev[2] > 0 else float(np.sqrt(max(ev[0], 0.0) / ev[2]))


def far_side_fraction(X: np.ndarray, inliers: np.ndarray, centre: np.ndarray) -> float:
    """Of the points ``X`` (N, 3) (m) that are not ``inliers`` (N,) bool and lie off the
    inliers' best-fit plane (farther from it than 3 times the inliers' RMS distance to it, and
    than 1e-3 of their extent), the fraction on the other side of that plane than the camera
    centre ``centre`` (3,) (m, same frame as ``X``).

    Meaningful when the inliers are coplanar (:func:`planarity` below
    :data:`PLANAR_TOLERANCE`). 0.0 when no point is off the plane or fewer than 3 inliers.

    Raises:
        ValueError: ``X`` not (N, 3), ``inliers`` not (N,), ``centre`` not (3,).
    """
    X = np.asarray(X, dtype=np.float64)
    inliers = np.asarray(inliers, dtype=bool)
    centre = np.asarray(centre, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 3 or inliers.shape != (len(X),) or centre.shape != (3,):
        raise ValueError(
            f"need X (N, 3), inliers (N,), centre (3,); got {X.shape}, {inliers.shape}, "
            f"{centre.shape}"
        )
    P = X[inliers]
    if len(P) < 3:
        return 0.0
    c = P.mean(axis=0)
    _, s, vt = np.linalg.svd(P - c, full_matrices=False)
    n = vt[2]
    rms = s[2] / np.sqrt(len(P))
    margin = max(3.0 * rms, 1e-3 * s[0] / np.sqrt(len(P)))
    d = (X[~inliers] - c) @ n
    off = d[np.abs(d) > margin]
    if not len(off):
        return 0.0
    camera_side = np.sign(n @ (centre - c))
    return float(np.mean(np.sign(off) == -camera_side))


@kernel
def _condition_number(H):
    n = H.shape[0]
    s = np.empty(n)
    for i in range(n):
        if not (H[i, i] > 0.0 and np.isfinite(H[i, i])):
            return np.inf
        s[i] = 1.0 / np.sqrt(H[i, i])
    A = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            A[i, j] = s[i] * H[i, j] * s[j]
            if not np.isfinite(A[i, j]):
                return np.inf
    ev = np.linalg.eigvalsh(A)
    if not ev[0] > 0.0:
        return np.inf
    return ev[n - 1] / ev[0]


def condition_number(information: np.ndarray, compiled: bool = True) -> float:
    """Condition number of a symmetric information matrix (n, n) after Jacobi scaling
    ``D^-1/2 H D^-1/2`` with ``D = diag(H)`` (unit-free); ``inf`` if it is singular, has a
    zero diagonal entry (an undetermined parameter) or a non-finite entry.
    ``compiled=False``: in NumPy (the estimator's NumPy implementation)."""
    H = np.ascontiguousarray(information, dtype=np.float64)
    if H.ndim != 2 or H.shape[0] != H.shape[1]:
        raise ValueError(f"information must be square, got shape {H.shape}")
    if not compiled:
        d = np.diag(H)
        if not (np.all(d > 0) and np.isfinite(H).all()):
            return float("inf")
        s = 1.0 / np.sqrt(d)
        ev = np.linalg.eigvalsh(s[:, None] * H * s[None, :])
        return float(ev[-1] / ev[0]) if ev[0] > 0 else float("inf")
    return float(_condition_number(H))
