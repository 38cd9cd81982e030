"""3D geometry of the ``markers`` topic, in the map frame (no ROS here).

The pose is the estimate's reference-line pose: ``orientation`` (camera -> map rotation) and
``position`` (camera centre in the map, m); camera optical frame as in REP 103 (z forward, x
right, y down).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from ..camera import CameraModel
from ..pose import RSPose

__all__ = ["frustum_corners", "frustum_segments", "velocity_arrows"]


def frustum_corners(
    camera: CameraModel, orientation: ArrayLike, position: ArrayLike, depth: float
) -> np.ndarray:
    """(4, 3) map points where the rays through the image corners reach ``depth`` (m, along
    the optical axis): pixel corners ``(-0.5, -0.5)``, ``(W - 0.5, -0.5)``,
    ``(W - 0.5, H - 0.5)``, ``(-0.5, H - 0.5)`` (top-left, top-right, bottom-right,
    bottom-left), undistorted with the camera's lens model.

    Raises:
        ValueError: ``depth`` not positive and finite.
    """
    if not (np.isfinite(depth) and depth > 0):
        raise ValueError(f"depth must be positive, got {depth}")
    w, h = camera.width, camera.height
    px = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
    xn = camera.undistort(px)
    rays = np.concatenate([xn, np.ones((4, 1))], axis=1) * float(depth)
    return rays @ np.asarray(orientation, dtype=float).T + np.asarray(position, dtype=float)


def frustum_segments(
    camera: CameraModel, orientation: ArrayLike, position: ArrayLike, depth: float
) -> np.ndarray:
    """(16, 3) map points, consecutive pairs are the 8 segments of the camera frustum: centre
    to each of the 4 :func:`frustum_corners`, then the far rectangle (for a ``LINE_LIST``)."""
    c = np.asarray(position, dtype=float)
    k = frustum_corners(camera, orientation, position, depth)
    segs = [(c, k[i]) for i in range(4)] + [(k[i], k[(i + 1) % 4]) for i in range(4)]
    return np.array([p for s in segs for p in s])


def velocity_arrows(pose: RSPose, scale: float = 1.0) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Start and end (3,) map points of the angular- and linear-velocity arrows at the camera
    centre of ``pose``: ``end = position + scale * velocity_world`` (``scale`` m per rad/s
    and per m/s).

    Returns:
        ``{"angular_velocity": (start, end), "linear_velocity": (start, end)}``.
    """
    p = np.asarray(pose.position, dtype=float)
    return {
        "angular_velocity": (p, p + scale * np.asarray(pose.angular_velocity_world)),
        "linear_velocity": (p, p + scale * np.asarray(pose.linear_velocity_world)),
    }
