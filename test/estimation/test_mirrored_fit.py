"""Correspondences reflected through the camera centre (a mirror image of a 3D scene: no rigid
pose explains them) give no pose, while true frames with as few inliers are still solved."""

from __future__ import annotations

from dataclasses import replace

import pytest

from rs_localizer.estimation import estimate_rs_pose
from rs_localizer.estimation.result import INCONSISTENT_FIT
from rs_localizer.sim.attacks import TestFrame, attack, corridor_frames
from rs_localizer.sim.synthetic import make_frame, paper_camera, protocol_options

OPTS = protocol_options()
UNCHECKED = replace(OPTS, plausibility=replace(OPTS.plausibility, consistent_fit=False))


@pytest.mark.parametrize(
    "seed, rs_speed", [(1, 1.0), (28, 1.0), (4, 0.5), (16, 0.5), (17, 0.5), (29, 0.5)]
)
def test_a_partial_fit_of_reflected_correspondences_is_refused(seed, rs_speed):
    """The paper protocol's frames (300 points in a box in front of the camera, 1 px noise),
    every 3D point reflected through the camera centre: without the consistency check these
    frames give a confident pose from 14-97 of the 300 points, badly conditioned."""
    f = make_frame(seed, n_points=300, rs_speed=rs_speed, noise_px=1.0)
    a = attack(TestFrame(f.points_px, f.X, paper_camera(), f.position, OPTS), "reflected")
    e = estimate_rs_pose(a.points_px, a.points3d, a.camera, "r6p_1lin", UNCHECKED)
    assert e.success and e.num_inliers < 0.5 * e.num_valid  # (the garbage the check is for)
    e = estimate_rs_pose(a.points_px, a.points3d, a.camera, "r6p_1lin", OPTS)
    assert not e.success and e.failure == INCONSISTENT_FIT


def test_true_frames_with_most_points_outliers_are_still_solved():
    """The corridor with 70 % outliers: 3D inlier sets of about 30 % of the points."""
    for f in corridor_frames(6, 7, outlier_ratio=0.7):
        e = estimate_rs_pose(f.points_px, f.points3d, f.camera, "r6p_1lin", f.options)
        assert e.failure != INCONSISTENT_FIT


def test_near_misses_make_a_partial_fit_inconsistent():
    """The near-miss rule of :func:`fit_is_inconsistent` (shared by the compiled and the
    uncompiled path) on a 3D cloud: 100 inliers of 300, the other 200 points either just
    missing (1-5 thresholds) or anywhere (far beyond)."""
    import numpy as np

    from rs_localizer.estimation.finalize import NEAR_MISS_WINDOW, fit_is_inconsistent

    rng = np.random.default_rng(0)
    X = rng.uniform(-1, 1, (300, 3)) + [0, 0, 5]
    inl = np.zeros(300, bool)
    inl[:100] = True
    th = 1e-3
    e = np.where(inl, 0.5 * th, rng.uniform(1.5 * th, 0.9 * NEAR_MISS_WINDOW * th, 300))
    far = np.where(inl, 0.5 * th, rng.uniform(20 * th, 100 * th, 300))
    args = (X, inl, np.zeros(3), 1.0, 10.0, True)
    assert fit_is_inconsistent(*args, th, lambda: e)
    assert not fit_is_inconsistent(*args, th, lambda: far)
    assert not fit_is_inconsistent(*args, 0.0, lambda: e)  # threshold 0: the test is off
    assert not fit_is_inconsistent(X, inl, np.zeros(3), 1.0, 10.0, False, th, lambda: e)  # P3P
