"""The estimator's output kernels against the NumPy formulas they replace (covariance
propagation by an explicit Jacobian, RMS of the inliers, velocities by cross products), and the
one builder of a camera's and a rig's estimate."""

import numpy as np
import pytest

from rs_localizer.estimation.outputs import final_inliers
from rs_localizer.estimation.result import (
    built_estimate,
    output_covariance,
    physical_velocities,
)
from rs_localizer.geometry import rotvec_to_matrix, skew


def test_final_inliers_and_rms():
    e = np.array([0.5, np.inf, 3.0, np.nan, 1.0, 2.0])
    mask, n, rms = final_inliers(e, 2.0)
    assert mask.tolist() == [True, False, False, False, True, False] and n == 2
    assert rms == pytest.approx(np.sqrt((0.25 + 1.0) / 2))
    assert np.isnan(final_inliers(np.full(3, np.inf), 1.0)[2])


@pytest.mark.parametrize("s", [0.0, 3e-2 / 0.83])
def test_output_covariance_matches_the_explicit_jacobian(s):
    rng = np.random.default_rng(1)
    R = rotvec_to_matrix(rng.normal(size=3))
    C, w = rng.normal(size=3), rng.normal(size=3)
    A = rng.normal(size=(12, 12))
    cov12 = A @ A.T
    J = np.zeros((12, 12))
    J[0:3, 0:3] = -R.T
    J[3:6, 0:3] = -R.T @ skew(C)
    J[3:6, 3:6] = -R.T
    if s > 0:
        J[6:9, 6:9] = -np.eye(3) / s
        J[9:12, 6:9] = -skew(C) / s
        J[9:12, 3:6] = skew(w) / s
        J[9:12, 9:12] = -np.eye(3) / s
    ref = J @ cov12 @ J.T
    out, pose, twist = output_covariance(cov12, R, C, w, s)
    np.testing.assert_allclose(out, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
    order = [3, 4, 5, 0, 1, 2]
    np.testing.assert_allclose(
        pose, ref[np.ix_(order, order)], rtol=1e-12, atol=1e-12 * np.abs(ref).max()
    )
    if s > 0:
        tw = [9, 10, 11, 6, 7, 8]
        np.testing.assert_allclose(
            twist, ref[np.ix_(tw, tw)], rtol=1e-12, atol=1e-12 * np.abs(ref).max()
        )
    else:
        assert twist is None


def test_physical_velocities_match_the_cross_product_formula():
    rng = np.random.default_rng(2)
    R = rotvec_to_matrix(rng.normal(size=3))
    C, w, t = rng.normal(size=3), rng.normal(size=3), rng.normal(size=3)
    om, vc, om_w, vc_w = physical_velocities(R, C, w, t, 0.02)
    np.testing.assert_allclose(om, -w / 0.02, rtol=1e-14)
    np.testing.assert_allclose(vc, (np.cross(w, C) - t) / 0.02, rtol=1e-12)
    np.testing.assert_allclose(om_w, R.T @ om, rtol=1e-12)
    np.testing.assert_allclose(vc_w, R.T @ vc, rtol=1e-12)
    assert all((a == 0).all() for a in physical_velocities(R, C, w, t, 0.0))


def test_one_builder_counts_the_rows_of_a_camera_and_of_a_rig_and_refuses_unknown_reasons():
    # one camera: 5 input rows, 3 valid; a failure is the identity, no inlier, its one view's
    none = np.zeros(5, dtype=bool)
    cam = built_estimate("too_few_points", None, None, (none,), (3,), 5, solver="p3p")
    assert not cam.success and cam.failure == "too_few_points" and cam.solver == "p3p"
    assert cam.num_valid == 3 and cam.num_dropped == 2 and cam.num_inliers == 0
    assert np.array_equal(cam.model.R, np.eye(3)) and not np.any(cam.pose.position)
    assert cam.inliers is none and cam.inliers_per_view == (none,)
    assert cam.num_valid_per_view == (3,) and cam.num_inliers_per_view == (0,)
    # a rig of two views (2 and 3 rows, all valid), posed, one valid row behind its camera
    per = (np.array([True, False]), np.array([True, True, False]))
    model = (np.eye(3), np.array([0.0, 0.0, 1.0]), np.zeros(3), np.zeros(3))
    rig = built_estimate(None, model, None, per, (2, 3), 5, (None, None, None), num_behind=1)
    assert rig.success and rig.failure is None and rig.num_inliers == 3
    assert rig.num_dropped == 1 and rig.num_inliers_per_view == (1, 2)
    assert rig.num_valid_per_view == (2, 3) and rig.inliers_per_view[1].tolist() == per[1].tolist()
    assert rig.inliers.tolist() == [True, False, True, True, False]
    assert rig.model is model and rig.covariance is None
    # a rig's own reason is known to the one builder, a made-up one is not
    assert built_estimate("cameras_disagree", None, None, (), (), 0).failure
    with pytest.raises(ValueError, match="unknown failure reason"):
        built_estimate("tired", None, None, (), (), 0)
