"""Capping a frame's correspondences to a fixed budget before estimation.

The estimator's cost grows with the number of points while the accuracy stops improving long
before thousands of points; a node bounds the work per frame by keeping at most ``max_points``
rows of each frame.
"""

from __future__ import annotations

import numpy as np

__all__ = ["cap_points", "capped_rows"]


def capped_rows(n: int, max_points: int, scores: np.ndarray | None = None) -> np.ndarray:
    """Indices (increasing) of the rows kept when ``n`` rows are capped to ``max_points``.

    With ``scores`` (N,) holding at least one finite value: the ``max_points`` highest scores
    (NaN ranks lowest; ties keep the earlier row). Otherwise ``max_points`` rows evenly spaced
    over the frame (first and last included), so that the kept points still cover the image
    when the rows are ordered by position. ``n <= max_points``: every row.

    Raises:
        ValueError: ``max_points < 1``, or ``scores`` not of length ``n``.
    """
    n, max_points = int(n), int(max_points)
    if max_points < 1:
        raise ValueError(f"max_points must be >= 1, got {max_points}")
    if scores is not None and len(scores) != n:
        raise ValueError(f"scores has {len(scores)} entries for {n} rows")
    if n <= max_points:
        return np.arange(n)
    if scores is not None and np.isfinite(scores).any():
        keep = np.argsort(-np.nan_to_num(scores, nan=-np.inf), kind="stable")[:max_points]
        keep.sort()
        return keep
    return np.linspace(0, n - 1, max_points).astype(int)


def cap_points(
    points2d: np.ndarray,
    points3d: np.ndarray,
    scores: np.ndarray | None,
    max_points: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """At most ``max_points`` rows of a frame's correspondences (see :func:`capped_rows`).

    Args:
        points2d: (N, 2) image points (px). points3d: (N, 3) map points (m).
        scores: (N,) match quality, higher is better, or None.
        max_points: the budget (>= 1).
    Returns:
        ``(points2d, points3d, scores)`` of the kept rows, in their original order (the inputs
        themselves when ``N <= max_points``).
    Raises:
        ValueError: as :func:`capped_rows`; ``points3d`` not of length N.
    """
    n = len(points2d)
    if len(points3d) != n:
        raise ValueError(f"{n} image points but {len(points3d)} map points")
    if n <= max_points:
        capped_rows(n, max_points, scores)  # (the checks)
        return points2d, points3d, scores
    keep = capped_rows(n, max_points, scores)
    return points2d[keep], points3d[keep], None if scores is None else scores[keep]
