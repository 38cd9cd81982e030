"""Plausibility checks of the estimator: motion bounds, cheirality, degenerate point sets.

A model that explains the correspondences is not necessarily a camera pose: with the six extra
degrees of freedom of the rolling-shutter model (``w``, ``t``), RANSAC can fit hundreds of
"inliers" of a degenerate cloud (all pixels on one image line, 3D points reflected through the
camera centre) with angular velocities of thousands of rad/s and a camera kilometres away. The
checks here keep such models out:

* :func:`plausible_motion`: the physical angular and linear velocities (paper eq. 5 with
  ``tau = time / seconds_per_unit_r``, see :func:`rs_localizer.estimation.estimate.physical_velocities`)
  within the bounds of :class:`~rs_localizer.estimation.estimate.EstimateOptions`. Applied to
  every RANSAC hypothesis and local-optimization candidate (an implausible model scores like
  "no inliers") and to the final model.
* :func:`depths_at_capture`: the depth of every point at its own capture time under the exact
  constant-velocity model (``expm(tau [w]x) R X + C + tau t``, the model of the refinement);
  inliers must be in front of the camera (cheirality).
* :func:`image_degenerate`, :func:`collinear_3d`: point sets that fix no pose (identical points,
  3D points on a line, image points within the inlier threshold of one image line).
* :func:`check_final_model`: the last check before ``success=True``; returns a failure reason
  (``implausible_motion``, ``cheirality``) or ``None``.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["motion_bounds", "plausible_motion", "depths_at_capture", "collinear_3d",
           "image_degenerate", "check_final_model", "IMPLAUSIBLE_MOTION", "CHEIRALITY"]

#: failure reasons of :func:`check_final_model`
IMPLAUSIBLE_MOTION = "implausible_motion"
CHEIRALITY = "cheirality"


def motion_bounds(max_angular_velocity: float, max_linear_velocity: float,
                  seconds_per_unit_r: float):
    """Bounds on the model velocities per unit RS coordinate ``r``.

    Args:
        max_angular_velocity: rad/s (``inf`` = no bound).
        max_linear_velocity: m/s (``inf`` = no bound).
        seconds_per_unit_r: the camera's capture-time difference per unit of ``r`` (s).
    Returns:
        ``(w_max, v_max)`` in rad and m per unit ``r``, or ``None`` when the timing is global
        shutter (``seconds_per_unit_r <= 0``: the model velocities have no physical scale and
        are not bounded).
    """
    s = float(seconds_per_unit_r)
    if not s > 0:
        return None
    return float(max_angular_velocity) * s, float(max_linear_velocity) * s


def plausible_motion(Rs, Cs, ws, ts, bounds) -> np.ndarray:
    """Which models move plausibly.

    The camera's angular velocity is ``-w`` and its linear velocity ``w x C - t`` (per unit r,
    in the camera frame; see ``physical_velocities``), so a model is plausible when
    ``|w| <= w_max`` and ``|w x C - t| <= v_max``.

    Args:
        Rs (K, 3, 3) rotations (unused, for a uniform signature), Cs, ws, ts (K, 3) or (3,).
        bounds: ``(w_max, v_max)`` from :func:`motion_bounds`, or ``None`` (everything passes).
    Returns:
        (K,) bool (a 0-d bool for single (3,) vectors); ``False`` for non-finite parameters.
    """
    Cs, ws, ts = (np.asarray(a, dtype=float) for a in (Cs, ws, ts))
    finite = (np.isfinite(Cs).all(axis=-1) & np.isfinite(ws).all(axis=-1)
              & np.isfinite(ts).all(axis=-1))
    if bounds is None:
        return finite
    w_max, v_max = bounds
    with np.errstate(invalid="ignore", over="ignore"):
        wn = np.sqrt(np.sum(ws * ws, axis=-1))
        v = np.cross(ws, Cs) - ts
        vn = np.sqrt(np.sum(v * v, axis=-1))
        return finite & (wn <= w_max) & (vn <= v_max)


def depths_at_capture(R, C, w, t, X, tau) -> np.ndarray:
    """(N,) depth (camera z, m) of each world point at its own capture time.

    Exact constant-velocity model (the refinement's, eq. 4 with the rotation
    ``expm(tau [w]x) R``): ``p_i = expm(tau_i [w]x) R X_i + C + tau_i t``, computed with
    SciPy's rotation vectors (independent of the numba kernels).

    Args:
        R (3, 3), C, w, t (3,): the model (world -> camera at the reference row; velocities per
            unit r). X (N, 3) world points (m). tau (N,) ``r_i - r0`` of each observation.
    """
    X = np.asarray(X, dtype=float).reshape(-1, 3)
    tau = np.asarray(tau, dtype=float).reshape(-1)
    if len(X) == 0:
        return np.zeros(0)
    q = X @ np.asarray(R, dtype=float).T
    rot = Rotation.from_rotvec(tau[:, None] * np.asarray(w, dtype=float)[None, :])
    p = rot.apply(q) + np.asarray(C, dtype=float) + tau[:, None] * np.asarray(t, dtype=float)
    return p[:, 2]


def collinear_3d(X, tol: float = 1e-3) -> bool:
    """True if the 3D points (N, 3) lie (nearly) on a line or are identical (the rotation about
    that line is free): second singular value of the centred points below ``tol`` times the
    first."""
    X = np.asarray(X, dtype=float).reshape(-1, 3)
    if len(X) < 3:
        return True
    s = np.linalg.svd(X - X.mean(axis=0), compute_uv=False)
    return bool(s[0] == 0 or s[1] < tol * s[0])


def line_rms(points) -> float:
    """RMS distance of 2D points (N, 2) from their total-least-squares line (0 for N < 3)."""
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(p) < 3:
        return 0.0
    s = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
    return float(s[-1] / math.sqrt(len(p)))


def image_degenerate(points_px, points_normalized, focal: float, threshold_px: float) -> bool:
    """True if the image points lie within the inlier threshold of one image line (identical
    points included): the rays then span a plane through the camera centre and the pose is not
    determined (with the RS model's velocities, RANSAC still "fits" them).

    Tested in the measured pixels and in the undistorted normalized coordinates scaled by
    ``focal`` (a straight image line stays degenerate whichever of the two it is straight in).

    Args:
        points_px (N, 2) measured pixels; points_normalized (N, 2) undistorted normalized
        coordinates; focal (px); threshold_px: RMS distance from the line (px) below which
        the set is degenerate.
    """
    return (line_rms(points_px) < threshold_px
            or line_rms(np.asarray(points_normalized, dtype=float) * focal) < threshold_px)


def check_final_model(R, C, w, t, X, tau, bounds):
    """The last check before a model is reported as a pose.

    Args:
        R (3, 3), C, w, t (3,): the final model; X (N, 3) its inliers' world points, tau (N,)
        their ``r - r0``; bounds: :func:`motion_bounds` (or ``None``).
    Returns:
        ``"implausible_motion"`` (non-finite parameters or a velocity beyond the bounds),
        ``"cheirality"`` (an inlier not in front of the camera at its capture time), or
        ``None`` when the model is plausible.
    """
    if not (np.isfinite(R).all() and plausible_motion(None, C, w, t, bounds)):
        return IMPLAUSIBLE_MOTION
    z = depths_at_capture(R, C, w, t, X, tau)
    if not (np.isfinite(z).all() and (z > 0).all()):
        return CHEIRALITY
    return None
