"""Planar and near-degenerate configurations of the RS pose problem (issue 16).

Two measures, both reported in :class:`~rs_localizer.estimation.estimate.RSPoseEstimate`:

- :func:`planarity`: thickness of the 3D points relative to their extent, the ratio of the
  smallest to the largest singular value of the centred points. 0 on a board, a marker or a
  wall; ~0.3-0.6 for points spread through a room or a corridor. Below
  :data:`PLANAR_TOLERANCE` the scene counts as planar: R9P cannot be used (its 18 unknowns
  lose 3 dimensions on coplanar points) and hypothesis generation uses the motion prior
  (damped linear solves).
- :func:`condition_number`: of the data's information matrix of the 12 parameters (pose and
  velocities) after Jacobi scaling (each parameter divided by its own information, so the
  number does not depend on units). Large values mean some combination of rotation and
  velocity is barely determined by the image: on planar scenes the maximum-likelihood estimate
  is then near-degenerate and the motion prior carries that combination.
"""

from __future__ import annotations

import numpy as np

__all__ = ["PLANAR_TOLERANCE", "planarity", "condition_number"]

#: scenes thinner than this fraction of their extent count as planar (a facade with 20 cm of
#: relief over 10 m: 0.02; a desk with objects is well above)
PLANAR_TOLERANCE = 0.05


def planarity(X) -> float:
    """Smallest over largest singular value of the centred points ``X`` (N, 3) (m).

    0 for coplanar points (and for fewer than 3 points or a single repeated point: no extent,
    nothing to measure), up to 1 for an isotropic cloud. Raises ValueError for a wrong shape.
    """
    X = np.asarray(X, dtype=float)
    if X.ndim != 2 or X.shape[1] != 3:
        raise ValueError(f"X must have shape (N, 3), got {X.shape}")
    if len(X) < 3:
        return 0.0
    S = np.cov(X.T, bias=True)  # 3x3 scatter: its eigenvalues are the squared singular values / N
    ev = np.linalg.eigvalsh(S)
    if not ev[2] > 0:
        return 0.0
    return float(np.sqrt(max(ev[0], 0.0) / ev[2]))


def condition_number(information) -> float:
    """Condition number of a symmetric information matrix (n, n) after Jacobi scaling
    ``D^-1/2 H D^-1/2`` with ``D = diag(H)`` (unit-free); ``inf`` if it is singular, has a
    zero diagonal entry (an undetermined parameter) or a non-finite entry."""
    H = np.asarray(information, dtype=float)
    d = np.diag(H)
    if not (np.isfinite(H).all() and (d > 0).all()):
        return float("inf")
    s = 1.0 / np.sqrt(d)
    ev = np.linalg.eigvalsh(s[:, None] * H * s[None, :])
    if not ev[0] > 0:
        return float("inf")
    return float(ev[-1] / ev[0])
