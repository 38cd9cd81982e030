"""Correlated image noise: pixel errors drawn from the model of
:mod:`rs_localizer.estimation.noise_model` (white plus a squared-exponential correlated part), as
fitted on photographs of still boards (``python -m benchmarks.still_boards``)."""

from __future__ import annotations

import numpy as np

__all__ = ["correlated_field"]


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
