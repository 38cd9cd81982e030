"""estimate_rig_pose with a gyro on the rig: a right gyro improves the angular velocity against
the truth, a wrong one (biased, or mounted at the wrong rotation) is rejected by the image and
leaves the unaided estimate."""

import numpy as np
import pytest

from rs_localizer.estimation.gyro import GyroMeasurement
from rs_localizer.estimation.rig import estimate_rig_pose
from rs_localizer.geometry import rotation_angle_deg, rotvec_to_matrix
from rs_localizer.sim import synthetic as sim_rig

SIGMA = 0.005  # rad/s, the gyro's noise over one rig frame


def _frames(seed, n, points=40, cameras=3, speed=(1.0, 2.0)):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        rig = sim_rig.make_rig(cameras, rng)
        truth = sim_rig.rig_motion(rng, rng.uniform(*speed), 1.5)
        out.append((sim_rig.rig_frame(rig, truth, [points] * cameras, rng), truth, rng))
    return out


def _gyro(omega, rng=None):
    noise = np.zeros(3) if rng is None else rng.normal(size=3) * SIGMA
    return GyroMeasurement(np.asarray(omega) + noise, SIGMA**2 * np.eye(3))


def _omega_error(est, truth):
    # (the rig's angular velocity is -w of its model, rig frame)
    return float(np.linalg.norm(est.pose.angular_velocity + truth.w))


def test_a_right_gyro_improves_the_angular_velocity_and_keeps_the_pose():
    """3 cameras x 40 points, 20 % outliers, turning 1-2 rad/s: with a gyro of 0.005 rad/s
    noise the angular velocity error is a fraction of the image alone's; the rotation and
    position are not worse; the gyro is used on every frame, its final refinement maximum a
    posteriori with the gyro's rate (``motion_prior_used``, as a camera's with a gyro; the
    image alone's maximum likelihood) and the posterior covariance of the angular velocity
    covers the error and is below the gyro's own."""
    plain, aided = [], []
    for f, truth, rng in _frames(5, 8):
        base = estimate_rig_pose(f.views)
        est = estimate_rig_pose(f.views, gyro=_gyro(-truth.w, rng))
        assert base.success and est.success
        assert est.gyro_used and not est.gyro_rejected and est.gyro_rejection == ""
        assert not base.gyro_used and not base.gyro_rejected
        assert est.motion_prior_used and not base.motion_prior_used
        assert np.isfinite(est.gyro_chi2) and est.gyro_chi2 < 16.27
        plain.append(
            (
                _omega_error(base, truth),
                rotation_angle_deg(base.model.R, truth.R),
                base.pose.position,
            )
        )
        aided.append(
            (_omega_error(est, truth), rotation_angle_deg(est.model.R, truth.R), est.pose.position)
        )
        S = est.twist_covariance[3:, 3:]
        assert np.trace(S) < 3 * SIGMA**2
        d = est.pose.angular_velocity + truth.w
        assert d @ np.linalg.solve(S, d) < 25.0
    p = np.array([a[:2] for a in plain])
    a = np.array([a[:2] for a in aided])
    assert np.median(a[:, 0]) < 0.5 * np.median(p[:, 0])
    assert a[:, 0].max() < 4 * SIGMA
    assert np.median(a[:, 1]) < 1.2 * np.median(p[:, 1])


@pytest.mark.parametrize(
    "wrong",
    [
        lambda om: om + np.array([0.15, -0.1, 0.1]),  # a bias of 0.2 rad/s
        lambda om: rotvec_to_matrix(np.radians([0.0, 12.0, 0.0])) @ om,  # mounted 12 deg off
    ],
    ids=["biased", "wrong_mounting"],
)
def test_a_wrong_gyro_is_rejected_and_the_estimate_is_the_unaided_one(wrong):
    """A gyro biased by 0.2 rad/s, or mounted 12 degrees off, on a rig turning at 1.5-2 rad/s
    with 3 x 80 points: the image contradicts it, the estimate is exactly the one without the
    gyro (rotation, position, velocities) with ``gyro_rejected`` and the reason set."""
    for f, truth, _ in _frames(11, 4, points=80, speed=(1.5, 2.0)):
        base = estimate_rig_pose(f.views)
        est = estimate_rig_pose(f.views, gyro=_gyro(wrong(-truth.w)))
        assert base.success and est.success
        assert est.gyro_rejected and not est.gyro_used and not est.motion_prior_used
        assert est.gyro_rejection == "contradicted" and est.gyro_chi2 > 16.27
        for a, b in zip(est.model, base.model, strict=True):
            np.testing.assert_array_equal(a, b)
        assert est.num_inliers == base.num_inliers


def test_a_gyro_on_a_global_shutter_rig_is_ignored_and_a_wrong_type_raises():
    """A global-shutter rig frame (no time spread) does not determine the angular velocity:
    the gyro is not used and the estimate is the one without it; a gyro that is not a
    GyroMeasurement raises ValueError."""
    rng = np.random.default_rng(3)
    rig = sim_rig.make_rig(2, rng, readout_time=(0.0, 0.0), stamp_spread=0.0)
    truth = sim_rig.rig_motion(rng, 1.0, 1.0)
    f = sim_rig.rig_frame(rig, truth, [40, 40], rng)
    base = estimate_rig_pose(f.views)
    est = estimate_rig_pose(f.views, gyro=_gyro(np.array([1.0, 0.0, 0.0])))
    assert (
        est.success
        and est.motion_model == "global_shutter"
        and not est.gyro_used
        and not est.gyro_rejected
        and not est.motion_prior_used
    )
    np.testing.assert_array_equal(est.model.R, base.model.R)
    with pytest.raises(ValueError, match="GyroMeasurement"):
        estimate_rig_pose(f.views, gyro=np.zeros(3))
