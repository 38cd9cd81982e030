"""The gyro as a measurement of the RS model's angular velocity: the readout mean from samples,
its combination with the motion prior, and gyro-aided estimates against the ground truth."""

import time
from dataclasses import replace

import numpy as np
import pytest

from rs_localizer.estimation import (
    EstimateOptions,
    GyroMeasurement,
    MotionPrior,
    RansacOptions,
    estimate_rs_pose,
)
from rs_localizer.estimation.frame import configure_frame, prepare_frame
from rs_localizer.estimation.gyro import GYRO_CHI2_THRESHOLD, gyro_consistency, gyro_prior
from rs_localizer.estimation.hypotheses import (
    KNOWN_W_SAMPLE,
    ColdSamples,
    SampleBySample,
    hypothesis_source,
)
from rs_localizer.geometry import rotation_angle_deg, rotvec_to_matrix
from rs_localizer.sim.gyro import R_WRONG, simulated_gyro
from rs_localizer.sim.planar import make_planar_frame
from rs_localizer.sim.trajectory import R_IMU_CAMERA
from rs_localizer.tracking.gyro import gyro_measurement, readout_window

OPTS = EstimateOptions(ransac=RansacOptions(seed=0, min_inliers=12))


def test_readout_window_spans_the_lines_around_the_stamp():
    f = make_planar_frame(0, "plane")
    cam = f.camera
    a, b = readout_window(cam, 10.0)
    assert b - a == pytest.approx(cam.line_delay * (cam.lines - 1))
    # the stamp is the reference line's time
    assert 10.0 - a == pytest.approx(float(cam.line_time(cam.reference_line)))
    a0, _ = readout_window(cam, 10.0, stamp_line=0.0)
    assert a0 == pytest.approx(10.0 - float(cam.line_time(0.0)))


def test_measurement_is_the_mean_rate_over_the_window_in_the_camera_frame():
    t = np.arange(0.0, 0.1, 0.005)
    # a rate linear in time: its mean over [a, b] is its value at (a + b) / 2, exactly, for
    # linear interpolation between samples
    slope, offset = np.array([1.0, -2.0, 0.5]), np.array([0.3, 0.1, -0.2])
    rates = offset + t[:, None] * slope
    bias = np.array([0.01, 0.02, -0.03])
    R = rotvec_to_matrix(np.array([0.3, -0.2, 1.0]))
    window = (0.0123, 0.0317)
    g = gyro_measurement(t, rates + bias, window, R, bias, noise=0.003, bias_sigma=0.001)
    expected = R @ (offset + slope * 0.5 * (window[0] + window[1]))
    np.testing.assert_allclose(g.angular_velocity, expected, atol=1e-12)
    # the covariance: the weights' sum of squares; a uniform weighting of 5 samples would
    # give 1/5, the parabola over 0.0194 s of 200 Hz samples a little more
    c2 = (g.covariance[0, 0] - 0.001**2) / 0.003**2
    assert 1 / 6 < c2 < 1 / 3, c2
    np.testing.assert_allclose(g.covariance, g.covariance[0, 0] * np.eye(3), atol=1e-18)
    # a jerk: the rate the RS model fits is the rotation angle's least-squares slope over the
    # window, omega(m) + j h^2 / 10 (the mean rate would be omega(m) + j h^2 / 6); sampled at
    # 10 kHz the interpolation error is negligible
    tt = np.arange(0.0, 0.1, 1e-4)
    j, m, h = 40.0, 0.05, 0.015
    quad = np.stack([0.5 * j * (tt - m) ** 2] * 3, 1)
    gq = gyro_measurement(tt, quad, (m - h, m + h), noise=0.003)
    np.testing.assert_allclose(gq.angular_velocity, [j * h * h / 10] * 3, rtol=1e-4)
    # independent: the slope of a least-squares line through the integrated angle
    grid = np.linspace(m - h, m + h, 200_001)
    theta = j * (grid - m) ** 3 / 6
    assert gq.angular_velocity[0] == pytest.approx(np.polyfit(grid, theta, 1)[0], rel=1e-4)
    # a zero-length window (global shutter): the interpolated rate at that instant
    gs = gyro_measurement(t, rates, (0.0123, 0.0123), noise=0.003)
    np.testing.assert_allclose(gs.angular_velocity, offset + slope * 0.0123, atol=1e-12)
    # the time offset moves the IMU stamps onto the camera clock
    shifted = gyro_measurement(t - 0.004, rates, window, noise=0.003, time_offset=0.004)
    np.testing.assert_allclose(
        shifted.angular_velocity, offset + slope * 0.5 * (window[0] + window[1]), atol=1e-12
    )


@pytest.mark.parametrize(
    "stamps, rates, window, match",
    [
        (np.arange(5) * 0.01, np.zeros((5, 3)), (0.0, 0.05), "cover"),
        (np.arange(5) * 0.01, np.zeros((5, 3)), (-0.001, 0.02), "cover"),
        (np.array([0.0, 0.01, 0.01, 0.02]), np.zeros((4, 3)), (0.0, 0.01), "increasing"),
        (np.arange(5) * 0.01, np.full((5, 3), np.nan), (0.0, 0.01), "finite"),
        (np.arange(5) * 0.01, np.zeros((5, 2)), (0.0, 0.01), r"\(M, 3\)"),
        (np.arange(5) * 0.01, np.zeros((5, 3)), (0.02, 0.01), "t_last >= t_first"),
    ],
)
def test_measurement_rejects_bad_samples(stamps, rates, window, match):
    with pytest.raises(ValueError, match=match):
        gyro_measurement(stamps, rates, window)


def test_gyro_prior_adds_the_information_to_the_motion_prior():
    S = np.diag([1e-4, 2e-4, 4e-4])
    g = GyroMeasurement(np.array([0.5, -1.0, 2.0]), S)
    base = MotionPrior(3.0, 1.5)
    p = gyro_prior(g, base)
    L = base.information()
    L[3:, 3:] += np.linalg.inv(S)
    np.testing.assert_allclose(p.information(), L, rtol=1e-12)
    # the posterior mean of two Gaussians on omega (the base's mean is zero)
    w = np.linalg.solve(L[3:, 3:], np.linalg.inv(S) @ g.angular_velocity)
    np.testing.assert_allclose(p.mean_vector(), np.r_[0, 0, 0, w], atol=1e-12)
    assert p.always and p.enabled
    # without a base prior the linear velocity stays unconstrained
    q = gyro_prior(g, None)
    assert np.all(q.information()[:3] == 0)
    np.testing.assert_allclose(q.mean_vector()[3:], g.angular_velocity, atol=1e-12)
    for bad in (np.eye(5), -np.eye(6), np.triu(np.ones((6, 6)))):
        with pytest.raises(ValueError):
            MotionPrior(information_matrix=bad)
    with pytest.raises(ValueError):
        GyroMeasurement(np.zeros(3), np.zeros((3, 3)))


@pytest.mark.slow
def test_consistency_is_chi_square_of_the_residual():
    g = GyroMeasurement(np.zeros(3), 1e-4 * np.eye(3))
    # weak image (posterior = the gyro): the floor of 1 % of the gyro's covariance applies
    assert gyro_consistency(g, [0.001, 0, 0], g.covariance) == pytest.approx(1e-6 / 1e-6)
    # strong image: posterior a quarter of the gyro's variance, residual covariance 3/4 of it
    c = gyro_consistency(g, [0.03, 0, 0], 0.25e-4 * np.eye(3))
    assert c == pytest.approx(0.03**2 / 0.75e-4)
    assert gyro_consistency(g, [np.nan, 0, 0], g.covariance) == np.inf


@pytest.mark.parametrize("scene", ["plane", "depth"])
def test_gyro_aided_estimate_has_the_gyros_angular_velocity(scene):
    """With a gyro the angular velocity error drops to the gyro's own (~0.004 rad/s) from
    0.04 (3D) to 0.15 rad/s (plane) without it; the rotation is no worse."""
    rng = np.random.default_rng(3)
    rows = []
    for _ in range(12):
        f = make_planar_frame(rng, scene)
        g = simulated_gyro(f, rng)
        a = estimate_rs_pose(f.points_px, f.X, f.camera, "r6p_1lin", OPTS, gyro=g)
        b = estimate_rs_pose(f.points_px, f.X, f.camera, "r6p_1lin", OPTS)
        assert a.success and b.success and a.gyro_used and not a.gyro_rejected
        assert not b.gyro_used and 0.0 <= a.gyro_chi2 <= GYRO_CHI2_THRESHOLD
        rows.append(
            (
                np.linalg.norm(a.pose.angular_velocity - f.angular_velocity),
                np.linalg.norm(b.pose.angular_velocity - f.angular_velocity),
                np.linalg.norm(g.angular_velocity - f.angular_velocity),
                rotation_angle_deg(a.pose.orientation, f.orientation),
                rotation_angle_deg(b.pose.orientation, f.orientation),
            )
        )
    m = np.median(np.array(rows), axis=0)
    assert m[0] < 2 * m[2] and m[0] < 0.01, m
    assert m[1] > 3 * m[0], m
    assert m[3] <= 1.1 * m[4], m


@pytest.mark.parametrize("scene, source", [("depth", ColdSamples), ("board", SampleBySample)])
def test_ransac_hypotheses_carry_the_gyros_angular_velocity(scene, source):
    """With a gyro RANSAC solves 5-point samples with its angular velocity (R5P_{v,C,t}^{w}):
    in the fused batch (3D scene) and step by step (planar scene); the best hypothesis is
    near the truth."""
    rng = np.random.default_rng(6)
    f = make_planar_frame(rng, scene)
    g = simulated_gyro(f, rng)
    opts = replace(OPTS, motion_prior=gyro_prior(g, OPTS.motion_prior))
    fr = prepare_frame(f.points_px, f.X, f.camera, np.inf, np.random.default_rng(0))
    configure_frame(fr, f.camera, "r6p_1lin", 12, 1.0, (np.inf, np.inf), opts.motion_prior)
    fr.known_w = -f.camera.seconds_per_unit_r * g.angular_velocity
    th2 = (opts.ransac.threshold_px / fr.f) ** 2
    src = hypothesis_source(fr, "r6p_1lin", opts, th2, False)
    assert isinstance(src, source)
    N = len(fr.x)
    out = src.best_of_batch(rng.random((32, KNOWN_W_SAMPLE)), N, np.arange(N), np.inf, 0, None)
    solved = np.any(out.w != 0, axis=1)  # (an invalid hypothesis is all zeros)
    assert solved.sum() >= 16
    np.testing.assert_array_equal(out.w[solved], np.broadcast_to(fr.known_w, out.w[solved].shape))
    assert np.isfinite(out.score)
    assert rotation_angle_deg(out.R[out.best].T, f.orientation) < 3.0


def test_gyro_on_a_board_is_better_and_not_slower():
    """Hand-held board frames (42 corners): with the gyro the rotation error drops (median
    0.75 against 1.06 deg over 200 frames, ``bench_gyro``; the best achievable from the
    truth is 0.73) and the angular velocity is the gyro's; a frame costs about the same
    (interleaved). At 50 % outliers RANSAC's 5-point samples need half the hypotheses."""
    rng = np.random.default_rng(8)
    rows, ms = [], []
    for _ in range(16):
        f = make_planar_frame(rng, "board")
        g = simulated_gyro(f, rng)
        # (this thread's CPU time: another process on the machine does not move it)
        t0 = time.thread_time()
        a = estimate_rs_pose(f.points_px, f.X, f.camera, "r6p_1lin", OPTS, gyro=g)
        t1 = time.thread_time()
        b = estimate_rs_pose(f.points_px, f.X, f.camera, "r6p_1lin", OPTS)
        ms.append((t1 - t0, time.thread_time() - t1))
        assert a.success and b.success and a.gyro_used
        rows.append(
            (
                rotation_angle_deg(a.pose.orientation, f.orientation),
                rotation_angle_deg(b.pose.orientation, f.orientation),
                np.linalg.norm(a.pose.angular_velocity - f.angular_velocity),
            )
        )
    m = np.median(np.array(rows), axis=0)
    assert m[0] < 0.85 * m[1], m
    assert m[2] < 0.02, m
    t = np.median(np.array(ms), axis=0)
    assert t[0] < 1.5 * t[1], t
    f = make_planar_frame(rng, "depth", outlier_ratio=0.5)
    g = simulated_gyro(f, rng)
    a = estimate_rs_pose(f.points_px, f.X, f.camera, "r6p_1lin", OPTS, gyro=g)
    b = estimate_rs_pose(f.points_px, f.X, f.camera, "r6p_1lin", OPTS)
    assert a.success and b.success and a.gyro_used
    # adaptive termination: 0.5^-5 against 0.5^-6 samples per all-inlier one
    assert a.ransac_iterations < 0.6 * b.ransac_iterations, (a.ransac_iterations, b)


def test_a_gyro_the_image_contradicts_is_dropped():
    """A camera-IMU rotation 90 deg off on a 3D scene: the estimator notices, falls back and
    returns exactly the unaided estimate."""
    rng = np.random.default_rng(4)
    rejected_by = []
    for _ in range(6):
        f = make_planar_frame(rng, "depth")
        bad = simulated_gyro(f, rng, R_WRONG @ R_IMU_CAMERA.T)
        a = estimate_rs_pose(f.points_px, f.X, f.camera, "r6p_1lin", OPTS, gyro=bad)
        b = estimate_rs_pose(f.points_px, f.X, f.camera, "r6p_1lin", OPTS)
        assert a.success and a.gyro_rejected and not a.gyro_used
        # (the gyro's chi-square against the image, recorded as a rig's estimate records it:
        # beyond the threshold where it contradicted the image, NaN where the aided failed)
        rejected_by.append(a.gyro_rejection)
        if a.gyro_rejection == "contradicted":
            assert a.gyro_chi2 > GYRO_CHI2_THRESHOLD
        else:
            assert a.gyro_rejection == "aided_failed" and np.isnan(a.gyro_chi2)
        assert np.isnan(b.gyro_chi2)
        np.testing.assert_array_equal(a.model.R, b.model.R)
        np.testing.assert_array_equal(a.pose.angular_velocity, b.pose.angular_velocity)
        chi2 = gyro_consistency(bad, b.pose.angular_velocity, b.twist_covariance[3:, 3:])
        assert chi2 > GYRO_CHI2_THRESHOLD
    assert "contradicted" in rejected_by, rejected_by


def test_global_shutter_solver_ignores_the_gyro():
    f = make_planar_frame(5, "depth")
    g = simulated_gyro(f, np.random.default_rng(5))
    a = estimate_rs_pose(f.points_px, f.X, f.camera, "p3p", OPTS, gyro=g)
    b = estimate_rs_pose(f.points_px, f.X, f.camera, "p3p", OPTS)
    assert a.success and not a.gyro_used and not a.gyro_rejected
    np.testing.assert_array_equal(a.model.R, b.model.R)


def test_imu_buffer_rejects_bad_samples_and_keeps_its_span():
    from rs_localizer.tracking.gyro import ImuBuffer

    buf = ImuBuffer(span=0.1, max_rate=10.0, max_gap=0.02)
    assert buf.add(1_000_000_000, [0.1, 0.2, 0.3]) is None
    assert buf.add(1_000_000_000, [0.1, 0.2, 0.3]) == "stamp_not_increasing"
    assert buf.add(999_000_000, [0.1, 0.2, 0.3]) == "stamp_not_increasing"
    assert buf.add(1_005_000_000, [np.nan, 0, 0]) == "non_finite"
    assert buf.add(1_005_000_000, [0, 0, -11.0]) == "saturated"
    for k in range(1, 60):  # 5 ms apart, 0.295 s: only the last 0.1 s stay
        assert buf.add(1_000_000_000 + 5_000_000 * k, [0.1, 0.2, 0.3]) is None
    t = [s for s, _ in buf.samples()]
    assert t[-1] - t[0] <= 100_000_000 and len(t) == 21
    assert buf.rate_hz() == pytest.approx(200.0)
    assert buf.received == 64


def test_imu_buffer_measurement_and_its_reasons():
    import threading
    import time

    from rs_localizer.tracking.gyro import ImuBuffer

    R = rotvec_to_matrix(np.array([0.2, 0.1, -0.4]))
    bias = np.array([0.01, 0.0, -0.02])
    buf = ImuBuffer(span=10.0, max_gap=0.02)
    g, why = buf.measurement((0, 1), np.eye(3), np.zeros(3), 0.003, 0.0)
    assert g is None and why == "no_samples"
    w = np.array([0.5, -1.0, 0.25])
    for k in range(21):  # 0 .. 0.1 s at 200 Hz
        buf.add(5_000_000 * k, w + bias)
    g, why = buf.measurement((20_000_000, 41_600_000), R, bias, 0.003, 0.001)
    assert why == "" and isinstance(g, GyroMeasurement)
    np.testing.assert_allclose(g.angular_velocity, R @ w, atol=1e-12)
    # the window goes into the IMU clock (t_imu = t_cam - time_offset): 0.09 s + 0.02 s is
    # beyond the samples
    assert buf.measurement((90_000_000, 95_000_000), R, bias, 0.003, 0.0, -0.02)[1] == (
        "not_covered"
    )
    assert buf.measurement((90_000_000, 95_000_000), R, bias, 0.003, 0.0, 0.02)[1] == ""
    sparse = ImuBuffer(span=10.0, max_gap=0.02)
    for k in range(5):  # an IMU at 10 Hz
        sparse.add(100_000_000 * k, w)
    assert sparse.measurement((120_000_000, 140_000_000), R, bias, 0.003, 0.0)[1] == "sparse"
    # a frame waits for the samples covering its readout, up to its timeout
    assert not buf.wait_until(200_000_000, 0.05)
    threading.Timer(0.05, lambda: buf.add(200_000_000, w)).start()
    t0 = time.monotonic()
    assert buf.wait_until(200_000_000, 5.0)
    assert time.monotonic() - t0 < 2.0
    assert not buf.wait_until(300_000_000, 5.0, stopped=lambda: True)
