"""A camera frame with a known pose and velocity, for the debug-image and visualization tests:
the expected pixel of every drawn element follows from it independently of the estimator."""

from __future__ import annotations

import numpy as np

from rs_localizer.estimation.estimate import RSPoseEstimate, physical_velocities
from rs_localizer.geometry import rotvec_to_matrix, rs_project_exact
from rs_localizer.pose import RSModel, RSPose

#: intrinsics (px) of the test camera, 640 x 480
K = np.array([[500.0, 0, 320.0], [0, 520.0, 240.0], [0, 0, 1]])


def known_pose():
    """The reference pose ``(R, C)``: world-to-camera rotation, camera centre (m, world)."""
    R = rotvec_to_matrix([0.1, -0.25, 0.05])
    C = np.array([0.3, -0.2, 1.0])
    return R, C


def world_points(R, C, xn, depth):
    """World points seen at normalized (N, 2) ``xn`` and ``depth`` from the reference pose."""
    Xc = np.c_[xn, np.ones(len(xn))] * np.asarray(depth, dtype=float).reshape(-1, 1)
    return (Xc - C) @ R  # R^T (Xc - C)


def known_frame(cam, w=(0.02, -0.05, 0.01), t=(0.05, 0.0, 0.02), seed=0):
    """A grid of inliers (0.3 px noise) and four outliers displaced by +25 px in u, with the
    estimate equal to the true pose. Returns (uv, X, est, truth_uv)."""
    R, C = known_pose()
    w, t = np.asarray(w, float), np.asarray(t, float)
    gx, gy = np.meshgrid(np.arange(60, 600, 80.0), np.arange(110, 460, 70.0))
    grid = np.c_[gx.ravel(), gy.ravel()]
    X = world_points(
        R,
        C,
        (grid - K[:2, 2]) / np.diag(K)[:2],
        np.random.default_rng(seed).uniform(3, 6, len(grid)),
    )
    x, _ = rs_project_exact(X, R, C, w, t, r0=cam.r0, readout=cam.readout_vector)
    truth = x @ K[:2, :2].T + K[:2, 2]
    uv = truth + np.random.default_rng(seed + 1).normal(0, 0.3, truth.shape)
    inl = np.ones(len(uv), dtype=bool)
    out = np.array([3, 10, 17, 30])
    inl[out] = False
    uv[out] = truth[out] + [25.0, 0.0]
    om, vc, _, _ = physical_velocities(R, C, w, t, cam.seconds_per_unit_r)
    est = RSPoseEstimate(
        success=True,
        solver="r6p_1lin",
        model=RSModel(R, C, w, t),
        pose=RSPose(R.T, -R.T @ C, om, vc),
        inliers=inl,
        rmse_px=0.42,
    )
    return uv, X, est, truth
