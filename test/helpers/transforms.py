"""4x4 homogeneous transforms, written out independently of the package: a pose's matrix and a
body twist's (its hat), to move a camera's poses and twists to the robot's base."""

from __future__ import annotations

import numpy as np


def transform(R, p) -> np.ndarray:
    """(4, 4) of rotation ``R`` (3, 3) and translation ``p`` (3,)."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


def twist_hat(w, v) -> np.ndarray:
    """(4, 4) of the body twist: angular ``w`` (3,) rad/s, linear ``v`` (3,) m/s."""
    X = np.zeros((4, 4))
    X[:3, :3] = [[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]
    X[:3, 3] = v
    return X
