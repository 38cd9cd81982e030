"""Correspondences whose 3D points carry a stated precision (a built map's): the final fit
weighs each by its total image noise, and nothing changes without it."""

import numpy as np
import pytest

from rs_localizer.estimation import estimate_rs_pose
from rs_localizer.estimation.map_weights import point_weights
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.sim.synthetic import FOCAL_PX, make_frame, paper_camera

CAM = paper_camera()


def _noisy_map(f, rng, sigma_px=3.0):
    """Half the 3D points moved by Gaussian errors of ``sigma_px`` (as seen at their depth,
    per axis), half exact: returns the map points and their true per-point std (m)."""
    depth = np.linalg.norm(f.X - f.position, axis=1)
    sigma = np.where(np.arange(len(f.X)) % 2 == 1, sigma_px * depth / FOCAL_PX, 0.0)
    return f.X + rng.normal(size=f.X.shape) * sigma[:, None], sigma


def test_weighting_by_the_map_precision_beats_weighing_all_points_alike():
    rng = np.random.default_rng(11)
    plain, weighted = [], []
    for k in range(20):
        f = make_frame(2000 + k, 200, rs_speed=0.5, noise_px=0.5)
        X, sigma = _noisy_map(f, rng)
        a = estimate_rs_pose(f.points_px, X, CAM, "r6p_1lin")
        b = estimate_rs_pose(f.points_px, X, CAM, "r6p_1lin", point_sigma=sigma)
        assert a.success and b.success
        plain.append(
            (rotation_angle_deg(a.model.R, f.R), np.linalg.norm(a.pose.position - f.position))
        )
        weighted.append(
            (rotation_angle_deg(b.model.R, f.R), np.linalg.norm(b.pose.position - f.position))
        )
    plain, weighted = np.median(plain, axis=0), np.median(weighted, axis=0)
    assert weighted[0] < 0.8 * plain[0]
    assert weighted[1] < 0.8 * plain[1]


def test_exact_points_leave_the_estimate_unchanged():
    f = make_frame(7, 150, rs_speed=0.5, noise_px=1.0, outlier_ratio=0.2)
    a = estimate_rs_pose(f.points_px, f.X, CAM, "r6p_1lin")
    b = estimate_rs_pose(f.points_px, f.X, CAM, "r6p_1lin", point_sigma=np.zeros(len(f.X)))
    assert np.array_equal(a.model.R, b.model.R) and np.array_equal(a.pose.position, b.pose.position)
    assert np.array_equal(a.inliers, b.inliers)
    assert np.array_equal(a.covariance, b.covariance)


def test_point_weights_follow_the_stated_noise():
    # a point known to 2 mm at 1 m: 2e-3 in normalized units, against 1e-3 detection noise
    w = point_weights(np.array([0.0, 2e-3]), np.array([1.0, 1.0]), 1e-3)
    assert np.allclose(w, [1.0, 1.0 / np.sqrt(5.0)])


def test_point_sigma_of_another_shape_or_negative_is_refused():
    f = make_frame(8, 50, rs_speed=0.5, noise_px=0.5)
    with pytest.raises(ValueError, match="shape"):
        estimate_rs_pose(f.points_px, f.X, CAM, point_sigma=np.zeros(3))
    with pytest.raises(ValueError, match=">= 0"):
        estimate_rs_pose(f.points_px, f.X, CAM, point_sigma=-np.ones(len(f.X)))
