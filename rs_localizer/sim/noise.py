"""Correlated image noise: pixel errors drawn from the models of
:mod:`rs_localizer.estimation.noise_model`: white plus a squared-exponential correlated part, as
fitted on photographs of still boards (``python -m benchmarks.still_boards``), and a shift
shared by each square tag's 4 corners (:func:`shifted_tag_frame`)."""

from __future__ import annotations

import numpy as np

from ..camera import CameraModel
from ..geometry import rotvec_to_matrix

__all__ = ["correlated_field", "shifted_tag_frame"]

#: a 0.16 m square tag's corners in its own frame (m)
_TAG = np.array([[-1, 1, 0], [1, 1, 0], [1, -1, 0], [-1, -1, 0]]) * 0.08


def shifted_tag_frame(
    rng: np.random.Generator, camera: CameraModel, tags: int, shift: float, own: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A still camera seeing ``tags`` 0.16 m square tags 1.5-3.5 m away, turned at random,
    every corner at least 20 px inside the image, each tag's 4 corners shifted together by
    ``shift`` px per axis plus each corner's own noise of ``own`` px.

    Returns:
        ``(uv (4 tags, 2) px, X (4 tags, 3) world points (m), each corner's tag (4 tags,),
        R (3, 3), C (3,))``, the camera's pose ``x_cam = R X + C``.
    """
    P = []
    while len(P) < tags:
        Rt = rotvec_to_matrix(rng.normal(scale=0.4, size=3))
        z = rng.uniform(1.5, 3.5)
        q = _TAG @ Rt.T + np.r_[rng.uniform(-0.6, 0.6) * z, rng.uniform(-0.45, 0.45) * z, z]
        u = camera.project(q)
        if np.all((u >= 20) & (u <= [camera.width - 20, camera.height - 20])):
            P.append(q)
    P = np.concatenate(P)
    R = rotvec_to_matrix(rng.normal(scale=0.2, size=3))
    C = rng.normal(scale=0.2, size=3)
    X = (P - C) @ R  # (R X + C = P)
    uv = camera.project(P) + np.repeat(rng.normal(scale=shift, size=(tags, 2)), 4, axis=0)
    return uv + rng.normal(scale=own, size=uv.shape), X, np.repeat(np.arange(tags), 4), R, C


def correlated_field(
    u_px: np.ndarray,
    white_px: float,
    correlated_px: float,
    length_px: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """(N, 2) image error (px) at the pixels ``u_px`` (N, 2): white noise of std ``white_px``
    (px) plus correlated noise of std ``correlated_px`` (px) whose correlation between two
    pixels falls as ``exp(-d^2 / (2 length_px^2))`` with their distance ``d`` (px); each axis
    independent. Raises ``numpy.linalg.LinAlgError`` when the covariance is not positive
    definite (e.g. a NaN pixel)."""
    d2 = np.sum((u_px[:, None] - u_px[None]) ** 2, axis=-1)
    K = correlated_px**2 * np.exp(-0.5 * d2 / length_px**2) + 1e-12 * np.eye(len(u_px))
    L = np.linalg.cholesky(K)
    return L @ rng.normal(size=(len(u_px), 2)) + rng.normal(0, white_px, (len(u_px), 2))
