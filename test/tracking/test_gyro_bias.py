"""Online gyro-bias estimation (rs_localizer.tracking.gyro_bias) against simulated
trajectories with a known bias: the integrated rotation, convergence, outlier pairs, gaps."""

import numpy as np
import pytest

from rs_localizer.geometry import matrix_to_rotvec, rotvec_to_matrix
from rs_localizer.sim.trajectory import R_IMU_CAMERA, imu_samples, make_trajectory
from rs_localizer.tracking.gyro import ImuBuffer, gyro_measurement
from rs_localizer.tracking.gyro_bias import GyroBiasEstimator, GyroBiasOptions, integrate_gyro

T0 = 1_000_000_000_000  # ns, the video's start on the camera clock
NOISE = 0.003
BIAS = np.array([0.05, -0.05, 0.05])


def _imu(traj, seconds, bias=BIAS, seed=0, drop=None):
    """A 200 Hz gyro over [-0.1, seconds + 0.1] s in an ImuBuffer (stamps T0 + t);
    ``drop`` (a, b) s leaves out the samples in that interval."""
    t, om, _ = imu_samples(traj, -0.1, seconds + 0.1, 200.0, seed, NOISE, bias)
    buf = ImuBuffer(span=np.inf)
    for ti, wi in zip(t, om, strict=True):
        if drop is None or not drop[0] < ti < drop[1]:
            buf.add(T0 + int(round(ti * 1e9)), wi)
    return buf


def _estimator(sigma=0.05, **opts):
    return GyroBiasEstimator(
        np.zeros(3), sigma, R_IMU_CAMERA.T, NOISE, options=GyroBiasOptions(**opts)
    )


def _feed(est, traj, buf, times, rng, pose_sigma=2e-4, bad=()):
    """Frames at ``times`` (s) with the true orientation perturbed by ``pose_sigma`` rad
    (the covariance says so); frames whose index is in ``bad`` are 1 deg off. Returns the
    outcomes."""
    out = []
    P = pose_sigma**2 * np.eye(3)
    for k, t in enumerate(times):
        err = rng.normal(0, pose_sigma, 3)
        if k in bad:
            err = err + np.deg2rad(1.0) * np.array([0.0, 1.0, 0.0])
        Ori = rotvec_to_matrix(err) @ traj.orientation(t)
        out.append(est.update(T0 + int(round(t * 1e9)), Ori, P, buf))
    return out


def test_integrated_rotation_and_its_bias_derivative():
    """The gyro's integral matches the trajectory's rotation between two instants (shake:
    the fastest preset), and J is the derivative with respect to the bias (finite
    differences)."""
    traj = make_trajectory("shake")
    t = np.arange(0.0, 1.0, 0.005)
    w, _ = traj.velocity_body(t)
    for t0 in (0.2013, 0.5171, 0.7702):
        t1 = t0 + 1 / 30
        sel = (t >= t0 - 0.005) & (t <= t1 + 0.005)
        dR, J, c = integrate_gyro(t[sel] - t0, w[sel], t1 - t0, np.zeros(3))
        true = traj.orientation(t0).T @ traj.orientation(t1)
        assert np.linalg.norm(matrix_to_rotvec(dR.T @ true)) < 1e-4
        assert c.sum() == pytest.approx(t1 - t0) and (c >= 0).all()
    rng = np.random.default_rng(1)
    ts = np.arange(-0.004, 0.04, 0.005)
    om = rng.normal(0, 2.0, (len(ts), 3))
    b = np.array([0.1, -0.2, 0.3])
    dR, J, _ = integrate_gyro(ts, om, 0.033, b)
    for i in range(3):
        d = np.zeros(3)
        d[i] = 1e-6
        dR2, _, _ = integrate_gyro(ts, om, 0.033, b + d)
        np.testing.assert_allclose(matrix_to_rotvec(dR.T @ dR2) / 1e-6, -J[:, i], atol=1e-6)
    with pytest.raises(ValueError, match="cover"):
        integrate_gyro(ts, om, 0.05, b)


def test_converges_to_the_simulated_bias():
    """A bias of 0.05 rad/s per axis, unknown (prior 0 +- 0.05), is estimated to <= 0.005
    rad/s within 5 s of hand-held motion at 30 fps from poses good to 0.01 deg, and the
    reported std covers the error."""
    traj = make_trajectory("walk")
    buf = _imu(traj, 5.0)
    est = _estimator()
    rng = np.random.default_rng(0)
    out = _feed(est, traj, buf, np.arange(150) / 30.0, rng)
    assert out[0] == "first" and out.count("used") >= 145, out
    err = np.abs(est.bias - BIAS)
    assert err.max() <= 0.005, est.bias
    assert (err <= 4 * est.std).all(), (err, est.std)
    assert est.std.max() < 0.005


def test_rejects_an_outlier_pair_and_keeps_the_bias():
    """A pose 1 deg off makes the pairs before and after it fail the chi-square test: both
    are counted and do not move the estimate."""
    traj = make_trajectory("walk")
    buf = _imu(traj, 3.0)
    est = _estimator()
    rng = np.random.default_rng(2)
    times = np.arange(90) / 30.0
    out = _feed(est, traj, buf, times[:60], rng)
    before = est.bias.copy()
    out2 = _feed(est, traj, buf, times[60:63], rng, bad=(1,))
    assert out2 == ["used", "rejected", "rejected"], out2
    assert est.counts["rejected"] == out.count("rejected") + 2
    assert np.abs(est.bias - before).max() < 0.003
    _feed(est, traj, buf, times[63:], rng)
    assert np.abs(est.bias - BIAS).max() <= 0.005


def test_gaps_restart_the_pairing():
    """A frame too long after the previous one, a missing IMU interval, a restart (tracker
    reset) and a non-finite pose each start a new pair without touching the estimate."""
    traj = make_trajectory("walk")
    buf = _imu(traj, 3.0, drop=(1.0, 1.2))
    est = _estimator(max_interval=0.5)
    rng = np.random.default_rng(3)
    assert _feed(est, traj, buf, [0.0, 1 / 30], rng) == ["first", "used"]
    b = est.bias.copy()
    assert _feed(est, traj, buf, [0.9], rng) == ["gap"]  # 0.87 s later
    assert _feed(est, traj, buf, [1.1, 1.25, 1.3], rng) == ["no_gyro", "no_gyro", "used"]
    est.restart()
    assert _feed(est, traj, buf, [1.4, 1.45], rng) == ["first", "used"]
    assert est.update(T0 + int(1.5e9), np.full((3, 3), np.nan), np.eye(3), buf) == "bad_pose"
    assert _feed(est, traj, buf, [1.55, 1.6], rng) == ["first", "used"]
    # a stamp going back is a gap, too
    assert _feed(est, traj, buf, [1.0], rng) == ["gap"]
    assert est.counts["gap"] == 2 and est.counts["no_gyro"] == 2 and est.counts["bad_pose"] == 1
    assert np.abs(est.bias - b).max() < 0.05  # (only used pairs moved it)


def test_measurement_uses_the_estimate_and_its_covariance():
    """A readout's gyro measurement subtracts the current estimate and adds its covariance
    (rotated into the camera frame) to the sample noise."""
    traj = make_trajectory("walk")
    buf = _imu(traj, 2.0)
    est = _estimator()
    _feed(est, traj, buf, np.arange(40) / 30.0, np.random.default_rng(4))
    window = (T0 + int(0.5e9), T0 + int(0.5216e9))
    g, reason = est.measurement(buf, window)
    assert reason == ""
    t, om, span, _ = buf.interval(window)
    ref = gyro_measurement(t, om, (0.0, span), R_IMU_CAMERA.T, est.bias, NOISE)
    np.testing.assert_allclose(g.angular_velocity, ref.angular_velocity, atol=1e-12)
    R = R_IMU_CAMERA.T
    np.testing.assert_allclose(g.covariance, ref.covariance + R @ est.covariance @ R.T, atol=1e-15)
    w, _ = traj.velocity_body(0.5108)
    assert np.linalg.norm(g.angular_velocity - w) < 0.02


def test_bad_arguments():
    with pytest.raises(ValueError, match="bias"):
        GyroBiasEstimator([0.0, 0.0], 0.05, np.eye(3), NOISE)
    with pytest.raises(ValueError, match="sigma"):
        GyroBiasEstimator(np.zeros(3), -1.0, np.eye(3), NOISE)
    with pytest.raises(ValueError, match="rotation"):
        GyroBiasEstimator(np.zeros(3), 0.05, 2 * np.eye(3), NOISE)
    with pytest.raises(ValueError, match="max_interval"):
        GyroBiasOptions(max_interval=0.0)
    with pytest.raises(ValueError, match="random_walk"):
        GyroBiasOptions(random_walk=-1.0)
