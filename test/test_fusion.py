"""The fused twist (rs_localizer.estimation.fusion.TwistFilter).

* On a problem where the error-state filter is exactly linear (rotation about one fixed axis,
  pose measurements), its fixed-lag output equals an independent linear Kalman filter + RTS
  smoother written here with SciPy's matrix exponential (Van Loan discretization).
* On synthetic videos (the real estimator through the tracker): the fused velocities beat the
  per-frame ones, the covariance is consistent (NEES), gating and restarts.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.linalg import expm

from rs_localizer.estimation.fusion import FusionOptions, TwistFilter
from rs_localizer.estimation.estimate import EstimateOptions, estimate_rs_pose
from rs_localizer.estimation.tracker import RSTracker, TrackerOptions
from rs_localizer.geometry import matrix_to_rotvec, rotvec_to_matrix
from rs_localizer.sim.trajectory import SequenceConfig, generate_sequence, make_trajectory

NS = 1_000_000_000


def _van_loan(A, Qc, dt):
    """Discrete (F, Q) of dx = A x dt + noise (spectral density Qc) over dt (Van Loan 1978)."""
    n = len(A)
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = -A
    M[:n, n:] = Qc
    M[n:, n:] = A.T
    E = expm(M * dt)
    F = E[n:, n:].T
    return F, F @ E[:n, n:]


def _linear_smoother(z, r, dt, q, p0, lag):
    """Per-frame estimates of a 3-state integrator chain (x, x', x'') measured in x with
    variance r, white jerk of density q, prior (z[0], 0, 0) with variances p0; the estimate of
    frame k uses measurements up to k + lag (Kalman filter, then RTS back to k)."""
    A = np.diag([1.0, 1.0], 1)
    F, Q = _van_loan(A, np.diag([0.0, 0.0, q]), dt)
    H = np.array([[1.0, 0.0, 0.0]])
    n = len(z)
    xf, Pf, xp, Pp = [], [], [None], [None]
    x = np.array([z[0], 0.0, 0.0])
    P = np.diag([r, p0[1], p0[2]])
    xf.append(x), Pf.append(P)
    for k in range(1, n):
        x, P = F @ x, F @ P @ F.T + Q
        xp.append(x), Pp.append(P)
        S = H @ P @ H.T + r
        K = P @ H.T / S
        x = x + (K * (z[k] - H @ x)).ravel()
        P = (np.eye(3) - K @ H) @ P
        xf.append(x), Pf.append(P)
    out = []
    for k in range(n):
        end = min(n - 1, k + lag)
        xs = xf[end]
        for j in range(end - 1, k - 1, -1):
            G = Pf[j] @ F.T @ np.linalg.inv(Pp[j + 1])
            xs = xf[j] + G @ (xs - xp[j + 1])
        out.append(xs)
    return np.array(out)


@pytest.mark.parametrize("lag", [0, 1, 3])
def test_linear_case_equals_kalman_rts_smoother(lag):
    rng = np.random.default_rng(0)
    n, dt = 25, 1 / 30
    t = np.arange(n) * dt
    yaw = 0.3 + 1.2 * np.sin(2.0 * t)
    pos = np.stack([1.5 * t, 0.2 * np.sin(3 * t), 1.0 + 0.05 * np.cos(5 * t)], 1)
    sr, sp = 2e-3, 3e-3  # rad, m
    yaw_m = yaw + rng.normal(0, sr, n)
    pos_m = pos + rng.normal(0, sp, (n, 3))
    opts = FusionOptions(lag=lag, angular_noise=20.0, linear_noise=4.0, gate=1.0)
    filt = TwistFilter(opts)
    cov = np.zeros((12, 12))
    cov[:3, :3] = np.eye(3) * sr**2
    cov[3:6, 3:6] = np.eye(3) * sp**2
    final = []
    for k in range(n):
        est = SimpleNamespace(success=True, orientation=rotvec_to_matrix([0, 0, yaw_m[k]]),
                              position=pos_m[k], angular_velocity=np.zeros(3),
                              linear_velocity=np.zeros(3), covariance=cov,
                              twist_covariance=None)  # pose-only measurement
        final += filt.update(int(round(t[k] * NS)), est).final
    final += filt.flush()
    assert [f.stamp_ns for f in final] == [int(round(x * NS)) for x in t]
    p0 = (None, opts.initial_velocity**2, opts.angular_acceleration_std**2)
    ref_yaw = _linear_smoother(yaw_m, sr**2, dt, opts.angular_noise**2, p0, lag)
    p0l = (None, opts.initial_velocity**2, opts.linear_acceleration_std**2)
    for k, f in enumerate(final[:n - lag]):  # frames the smoother finished
        assert matrix_to_rotvec(f.orientation)[2] == pytest.approx(ref_yaw[k, 0], abs=1e-9)
        assert f.angular_velocity[2] == pytest.approx(ref_yaw[k, 1], abs=1e-7)
        assert f.angular_acceleration[2] == pytest.approx(ref_yaw[k, 2], abs=1e-5)
        for a in range(3):
            ref = _linear_smoother(pos_m[:, a], sp**2, dt, opts.linear_noise**2, p0l, lag)
            assert f.position[a] == pytest.approx(ref[k, 0], abs=1e-9)
            assert f.linear_velocity_world[a] == pytest.approx(ref[k, 1], abs=1e-7)


def test_options_are_validated():
    with pytest.raises(ValueError):
        FusionOptions(model="jerk")
    with pytest.raises(ValueError):
        FusionOptions(lag=-1)
    with pytest.raises(ValueError):
        FusionOptions(angular_noise=0.0)
    with pytest.raises(ValueError):
        FusionOptions(measurement_scale=0.5)
    with pytest.raises(ValueError):
        FusionOptions(gate=0.0)
    with pytest.raises(RuntimeError):
        TwistFilter().predict(0)


def _track(name, n, seed, fusion=None, **cfg):
    frames, _, cam, _ = generate_sequence(SequenceConfig(num_frames=n, seed=seed, **cfg),
                                          trajectory=make_trajectory(name))
    tr = RSTracker(options=EstimateOptions(seed=0),
                   tracker_options=TrackerOptions(fusion=fusion or FusionOptions()))
    single, final = {}, []
    for f in frames:  # single frame: the estimator alone (as without tracking)
        single[f.t_ref_ns] = estimate_rs_pose(f.uv, f.xyz, cam, options=EstimateOptions(seed=0))
        final += tr.process(f.t_ref_ns, f.uv, f.xyz, cam).final
    final += tr.flush()
    return frames, single, final


def _errors(frames, single, final):
    by = {f.t_ref_ns: f for f in frames}
    out = {}
    for key in ("angular_velocity", "linear_velocity"):
        out["single_" + key] = np.median([np.linalg.norm(getattr(e, key) - getattr(by[s], key))
                                          for s, e in single.items()])
        out["fused_" + key] = np.median([np.linalg.norm(getattr(x, key)
                                                        - getattr(by[x.stamp_ns], key))
                                         for x in final])
    nees = []
    for x in final:
        f = by[x.stamp_ns]
        e = np.concatenate([matrix_to_rotvec(x.orientation @ f.orientation.T),
                            x.position - f.position, x.angular_velocity - f.angular_velocity,
                            x.linear_velocity - f.linear_velocity])
        nees.append(e @ np.linalg.solve(x.covariance, e))
    out["nees"] = float(np.mean(nees[2:]))
    return out


@pytest.fixture(scope="module")
def sample_like():
    """The frames of data/sample (make-bag --frames 30 --seed 0) through the tracker."""
    return _errors(*_track("walk", 30, 0))


def test_fused_twist_beats_single_frame_on_the_sample(sample_like):
    e = sample_like
    # targets (bench_video): linear <= 1/4, angular <= 1/2 of the single-frame error
    assert e["fused_linear_velocity"] < 0.4 * e["single_linear_velocity"]
    assert e["fused_angular_velocity"] < 0.7 * e["single_angular_velocity"]
    assert e["single_linear_velocity"] > 0.15  # the per-frame figure (0.28 m/s in README)


@pytest.mark.parametrize("name", ["shake", "car"])
def test_fused_twist_no_worse_on_shake_and_car(name):
    e = _errors(*_track(name, 30, 1))
    assert e["fused_linear_velocity"] <= e["single_linear_velocity"]
    assert e["fused_angular_velocity"] <= e["single_angular_velocity"]


@pytest.mark.parametrize("name", ["walk", "shake", "pan"])
def test_covariance_is_consistent(name, sample_like):
    """Mean NEES of the 12 fused pose and twist errors against ground truth: 12 for a
    consistent covariance; the per-frame estimates alone give ~30 (walk) and ~150 (shake)."""
    e = sample_like if name == "walk" else _errors(*_track(name, 30, 2))
    assert 5.0 < e["nees"] < 20.0


def test_gate_restarts_on_a_jump_and_flush_returns_pending_frames():
    cov = np.eye(12) * 1e-6
    filt = TwistFilter(FusionOptions(lag=2))

    def est(p, v=(0.0, 0.0, 0.0)):
        return SimpleNamespace(success=True, orientation=np.eye(3), position=np.asarray(p),
                               angular_velocity=np.zeros(3), linear_velocity=np.asarray(v),
                               covariance=cov, twist_covariance=np.eye(6))

    out = []
    for k in range(4):  # 0.3 m/s along x
        step = filt.update(k * NS // 30, est([0.01 * k, 0, 0], [0.3, 0, 0]))
        assert step.current.fused and (k == 0) == step.current.restarted
        out += step.final
    assert [f.stamp_ns for f in out] == [0, NS // 30]  # lag 2: frames 0, 1 final
    # 5 m away: gated twice, restarts on the third (max_rejections = 2)
    steps = [filt.update(k * NS // 30, est([5.0, 0, 0])) for k in (4, 5, 6)]
    assert [s.current.fused for s in steps] == [False, False, True]
    assert steps[2].current.restarted and not steps[1].current.restarted
    assert np.allclose(steps[2].current.position, [5, 0, 0])
    # the restart returned the frames still pending (2, 3, 4, 5), all once
    stamps = [f.stamp_ns for s in steps for f in s.final]
    assert stamps == [k * NS // 30 for k in (2, 3, 4, 5)]
    # relocalized: restart at once; a failed estimate is not fused; a stamp going back resets
    s = filt.update(7 * NS // 30, est([9.0, 0, 0]), relocalized=True)
    assert s.current.restarted
    assert filt.update(8 * NS // 30, SimpleNamespace(success=False)).current.fused is False
    s = filt.update(NS // 30, est([0, 0, 0]))
    assert s.current.restarted and s.current.stamp_ns == NS // 30
    assert [f.stamp_ns for f in s.final] == [7 * NS // 30, 8 * NS // 30]


def test_prior_information_is_taken_out():
    """An estimate that is the posterior of a data measurement and a twist prior gives back
    the data measurement (posterior by the covariance-form Kalman update here)."""
    from rs_localizer.estimation.prior import MotionPrior

    rng = np.random.default_rng(3)
    A = rng.normal(size=(12, 12))
    R_d = A @ A.T * 1e-4 + np.eye(12) * 1e-5  # data covariance (rot, pos, omega, v)
    z_d = rng.normal(size=12) * 0.1
    z_d[:3] = 0.0  # rotation relative to the data's orientation
    O_d = rotvec_to_matrix([0.1, 0.2, -0.3])
    B = rng.normal(size=(6, 6))
    P = B @ B.T * 1e-3 + np.eye(6) * 1e-3  # prior covariance, ROS order (v, omega)
    m = rng.normal(size=6) * 0.1
    prior = MotionPrior(mean=m, covariance=P, always=True)
    # the prior observes the twist: H picks (v, omega) out of (rot, pos, omega, v)
    H = np.zeros((6, 12))
    for row, col in enumerate([9, 10, 11, 6, 7, 8]):
        H[row, col] = 1.0
    K = R_d @ H.T @ np.linalg.inv(H @ R_d @ H.T + P)
    z_post = z_d + K @ (m - H @ z_d)
    R_post = (np.eye(12) - K @ H) @ R_d
    G_d = rng.normal(size=(12, 6)) * 1e-3
    est = SimpleNamespace(success=True, orientation=rotvec_to_matrix(z_post[:3]) @ O_d,
                          position=z_post[3:6], angular_velocity=z_post[6:9],
                          linear_velocity=z_post[9:12], covariance=0.5 * (R_post + R_post.T),
                          twist_covariance=np.eye(6),
                          acceleration_sensitivity=(np.eye(12) - K @ H) @ G_d)
    z = TwistFilter()._measurement(est, prior)
    assert z.deprior
    np.testing.assert_allclose(z.R, R_d, rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(z.p, z_d[3:6], atol=1e-9)
    np.testing.assert_allclose(z.omega, z_d[6:9], atol=1e-9)
    np.testing.assert_allclose(z.v, z_d[9:12], atol=1e-9)
    np.testing.assert_allclose(z.O, O_d, atol=1e-9)
    np.testing.assert_allclose(z.G, G_d, rtol=1e-6, atol=1e-12)
    # without the prior the posterior is taken as it is
    plain = TwistFilter()._measurement(est)
    assert not plain.deprior and np.allclose(plain.R, est.covariance)
