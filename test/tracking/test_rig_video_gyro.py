"""Localizer with a gyro on the rig (simulated with rs_localizer.sim.trajectory.generate_rig_video):
a right gyro improves each rig frame's angular velocity against the true trajectory, a wrongly
mounted one is rejected and counted, a biased one's bias is estimated online."""

from __future__ import annotations

import dataclasses
from dataclasses import replace

import numpy as np
import pytest
from helpers.rig import T0

from rs_localizer.frames import Mounting
from rs_localizer.geometry import rotvec_to_matrix
from rs_localizer.sim.trajectory import default_rig, generate_rig_video, rig_gyro, rig_truth
from rs_localizer.tracking.localizer import CameraFrame
from rs_localizer.tracking.sequence import GyroSettings
from rs_localizer.tracking.video import Localizer, LocalizerSettings

NOISE = 0.003  # rad/s per sample
R_RIG_IMU = rotvec_to_matrix(np.array([0.3, -0.2, 1.0]))  # an IMU mounted turned on the rig


@pytest.fixture(scope="module")
def video():
    cams = default_rig(2)
    frames, _, traj = generate_rig_video(cams, duration=0.8, num_points=60, seed=5)
    return cams, frames, traj


def _run(video, imu=None, gyro=None, log=None):
    """The frames and gyro samples (``(stamps, rates)``) through a Localizer in the order
    they would arrive (a frame once its readout is over: 30 ms after its stamp). Returns
    (rig, outputs)."""
    cams, frames, _ = video
    mounts = {c.name: Mounting.from_pose(c.R_rig_cam, c.p_rig_cam) for c in cams}
    rig = Localizer(LocalizerSettings(mounts, imu=imu), log=log)
    by = {c.name: c.camera for c in cams}
    events = [(f.stamp_ns + 30_000_000, 1, f) for f in frames]
    if gyro is not None:
        events += [(int(t), 0, w) for t, w in zip(*gyro, strict=True)]
    outs = []
    for t, kind, item in sorted(events, key=lambda e: (e[0], e[1])):
        if kind == 0:
            assert rig.add_imu(t, item) is None
            continue
        outs += rig.add(
            CameraFrame(item.stamp_ns, by[item.name], item.uv, item.xyz, camera_name=item.name)
        )
    outs += rig.close()
    return rig, outs


def _omega_errors(outs, traj):
    e = []
    for o in outs:
        _, _, w, _ = rig_truth(traj, (o.stamp_ns - T0) * 1e-9)
        e.append(np.linalg.norm(o.estimate.pose.angular_velocity - w))
    return np.array(e)


def test_a_right_gyro_improves_each_rig_frames_angular_velocity(video):
    """2 cameras x 60 points, an IMU at 400 Hz turned on the rig (its R_rig_imu given): every
    rig frame posed with the gyro used; the median angular velocity error of the rig frames'
    own estimates below 0.3x those without the gyro; the rig frame's gyro measurement is
    the true rate within 5 sigma."""
    _, _, traj = video
    gyro = rig_gyro(traj, 0.8, R_rig_imu=R_RIG_IMU, noise=NOISE, seed=1)
    imu = GyroSettings(R_cam_imu=R_RIG_IMU, gyro_noise=NOISE, gyro_bias_sigma=0.001)
    rig, outs = _run(video, imu, gyro)
    _, plain = _run(video)
    assert all(o.success for o in outs) and len(outs) == len(plain) > 20
    assert rig.counts["rig.gyro_used"] == len(outs)
    assert rig.counts["rig.gyro_rejected"] == rig.counts["rig.gyro_missing"] == 0
    for o in outs:
        assert o.estimate.gyro_used and o.gyro is not None
        _, _, w, _ = rig_truth(traj, (o.stamp_ns - T0) * 1e-9)
        d = o.gyro.angular_velocity - w
        assert d @ np.linalg.solve(o.gyro.covariance, d) < 25.0
    e_gyro, e_plain = _omega_errors(outs, traj), _omega_errors(plain, traj)
    assert np.median(e_gyro) < 0.3 * np.median(e_plain), (np.median(e_gyro), np.median(e_plain))


def test_a_wrongly_mounted_gyro_is_rejected_and_changes_nothing(video):
    """The IMU's rotation on the rig given 15 degrees off: the image contradicts the gyro on
    the rig frames that turn enough to show it (counted, with the reason); the rejected
    frames' poses are the ones without a gyro, and the median angular velocity error is not
    worse than without it."""
    _, _, traj = video
    gyro = rig_gyro(traj, 0.8, R_rig_imu=R_RIG_IMU, noise=NOISE, seed=2)
    wrong = rotvec_to_matrix(np.radians([15.0, 0.0, 0.0])) @ R_RIG_IMU
    imu = GyroSettings(R_cam_imu=wrong, gyro_noise=NOISE, gyro_bias_sigma=0.001)
    rig, outs = _run(video, imu, gyro)
    _, plain = _run(video)
    assert all(o.success for o in outs)
    n_rej = rig.counts["rig.gyro_rejected"]
    assert n_rej >= 0.7 * len(outs)
    assert (
        rig.counts["rig.gyro_rejected.contradicted"] + rig.counts["rig.gyro_rejected.fewer_inliers"]
        == n_rej
    )
    assert rig.counts["rig.gyro_used"] + n_rej == len(outs)
    e_gyro, e_plain = _omega_errors(outs, traj), _omega_errors(plain, traj)
    assert np.median(e_gyro) <= 1.05 * np.median(e_plain)
    # the first rig frame (solved without a prediction) rejected: exactly the unaided pose
    if outs[0].estimate.gyro_rejected:
        np.testing.assert_array_equal(
            outs[0].estimate.pose.orientation, plain[0].estimate.pose.orientation
        )


def test_the_gyro_bias_is_estimated_online_and_missing_samples_are_counted(video):
    """A gyro biased by (0.03, -0.02, 0.025) rad/s with a prior of 0 +- 0.05 rad/s: after the
    video the online estimate is within 0.01 rad/s of the true bias per axis and its stated
    std shrank below the prior's; without samples every rig frame is counted as
    ``gyro_missing.no_samples`` and solved without the gyro; a sample without an IMU is
    ``disabled``."""
    _, _, traj = video
    bias = np.array([0.03, -0.02, 0.025])
    gyro = rig_gyro(traj, 0.8, R_rig_imu=R_RIG_IMU, bias=bias, noise=NOISE, seed=3)
    imu = GyroSettings(
        R_cam_imu=R_RIG_IMU, gyro_noise=NOISE, gyro_bias_sigma=0.05, estimate_bias=True
    )
    rig, outs = _run(video, imu, gyro)
    assert all(o.success for o in outs)
    b, std = rig.gyro_bias_values()
    assert np.abs(b - bias).max() < 0.01, b
    assert (std < 0.05).all()
    rig2, outs2 = _run(video, replace(imu, estimate_bias=False))
    assert all(o.success and o.gyro is None for o in outs2)
    assert rig2.counts["rig.gyro_missing.no_samples"] == len(outs2)
    rig3, _ = _run(video)
    assert rig3.add_imu(T0, np.zeros(3)) == "disabled" and rig3.gyro_bias_values() is None


def test_the_gyro_aided_sensitivity_predicts_the_shift_of_an_accelerating_rig():
    """The walk accelerates (several rad/s^2): a rig frame's angular velocity, held to the
    gyro's mean rate over the rig frame's capture times (3 cameras, 0, 4 and 8 ms apart), is
    off the rate at the rig frame's time by about the angular acceleration times the window's
    middle. The estimate's ``acceleration_sensitivity`` (with the gyro's own term) predicts
    that shift from the true accelerations: the median of what is left is below 0.5x the
    median shift."""
    cams = default_rig(3)
    frames, _, traj = generate_rig_video(cams, duration=0.6, num_points=60, seed=6)
    gyro = rig_gyro(traj, 0.6, R_rig_imu=R_RIG_IMU, noise=NOISE, seed=4)
    imu = GyroSettings(R_cam_imu=R_RIG_IMU, gyro_noise=NOISE, gyro_bias_sigma=0.001)
    _, outs = _run((cams, frames, traj), imu, gyro)
    assert len(outs) == 18 and all(o.success and o.estimate.gyro_used for o in outs)
    shift, left = [], []
    h = 1e-4
    for o in outs:
        t = (o.stamp_ns - T0) * 1e-9
        _, _, w, v = rig_truth(traj, t)
        (_, _, wa, va), (_, _, wb, vb) = rig_truth(traj, t - h), rig_truth(traj, t + h)
        alpha = (wb - wa) / (2 * h)
        a = (vb - va) / (2 * h) + np.cross(w, v)  # (rig frame: R^T p'')
        err = o.estimate.pose.angular_velocity - w
        pred = o.estimate.acceleration_sensitivity[6:9] @ np.r_[alpha, a]
        shift.append(np.linalg.norm(err))
        left.append(np.linalg.norm(err - pred))
    assert np.median(shift) > 0.01  # (rad/s: the shift is there)
    assert np.median(left) < 0.5 * np.median(shift), (np.median(left), np.median(shift))


def test_a_gyro_mounted_90_degrees_off_is_found_and_left_out_as_for_one_camera(video):
    """The IMU's rotation on the rig given 90 degrees off: the rotation between posed rig
    frames contradicts the gyro (the single camera's
    :class:`~rs_localizer.tracking.gyro_check.GyroMountCheck`), it is declared inconsistent
    once (``rig.gyro_inconsistent_detections``, a warning naming ``imu.rotation``) and the
    rig frames after it are solved without it (``rig.gyro_disabled_inconsistent``, no gyro
    measurement); the rig's diagnostics say so (WARN, ``gyro_inconsistent: true``). The same
    wrong mount on the front camera alone (``SequenceLocalizer``) is found too; the right
    mount is never declared inconsistent."""
    from helpers.rig import Log

    from rs_localizer.ros.diagnostics import WARN
    from rs_localizer.tracking.localizer import CameraFrame
    from rs_localizer.tracking.sequence import SequenceLocalizer, SequenceSettings

    pytest.importorskip("rclpy")
    from helpers.ros import rig_status

    cams, frames, traj = video
    gyro = rig_gyro(traj, 0.8, R_rig_imu=R_RIG_IMU, noise=NOISE, seed=4)
    wrong = rotvec_to_matrix(np.radians([90.0, 0.0, 0.0])) @ R_RIG_IMU
    imu = GyroSettings(R_cam_imu=wrong, gyro_noise=NOISE, gyro_bias_sigma=0.001)
    log = Log()
    rig, outs = _run(video, imu, gyro, log)
    c = rig.counts
    assert rig.gyro_inconsistent and c["rig.gyro_inconsistent_detections"] == 1, dict(c)
    assert c["rig.gyro_pairs_failed"] >= 6, dict(c)
    first = next(k for k, o in enumerate(outs) if o.success and o.gyro is None)
    assert first <= 12 and all(o.gyro is None for o in outs[first:])
    assert c["rig.gyro_disabled_inconsistent"] == len(outs) - first > 5, dict(c)
    assert all(o.success for o in outs)
    warned = [t for k, t in log.warnings if k == "gyro.inconsistent"]
    assert len(warned) == 1 and "rig frames" in warned[0] and "imu.rotation" in warned[0]
    level, message, v = rig_status(rig)
    assert level == WARN and "the gyro contradicts the image" in message, message
    assert v["gyro_inconsistent"] == "true" and v["gyro_disabled_inconsistent"] > 5, v
    # the front camera alone, its gyro as wrong (IMU -> camera: the mounting's rotation)
    front = cams[0]
    R_front = front.R_rig_cam.T  # (rig -> camera optical frame)
    alone = GyroSettings(R_cam_imu=R_front @ wrong, gyro_noise=NOISE, gyro_bias_sigma=0.001)
    seq = SequenceLocalizer(SequenceSettings(imu=dataclasses.replace(alone, wait=0.0)))
    for t, w in zip(*gyro, strict=True):
        seq.add_imu(int(t), w)
    for f in frames:
        if f.name == front.name:
            seq.process(CameraFrame(f.stamp_ns, front.camera, f.uv, f.xyz))
    assert seq.gyro_inconsistent and seq.counts["gyro_inconsistent_detections"] == 1
    # the right mount: never inconsistent
    right = GyroSettings(R_cam_imu=R_RIG_IMU, gyro_noise=NOISE, gyro_bias_sigma=0.001)
    rig2, outs2 = _run(video, right, gyro)
    assert not rig2.gyro_inconsistent and rig2.counts["rig.gyro_inconsistent_detections"] == 0
    assert rig2.counts["rig.gyro_used"] == len(outs2)
    assert rig_status(rig2)[2]["gyro_inconsistent"] == "false"


def test_a_time_reset_starts_the_rigs_gyro_timeline_again_as_a_cameras(video):
    """The rig's gyro follows the single camera's time-reset policy: a frame more than
    ``time_reset_ns`` after the rig's newest keeps the samples from that newest frame's stamp
    on (its first line's capture time here, ``stamp_row`` 0: its whole readout, not from
    its reference line's, mid-readout), the older ones dropped; a frame going back by more
    drops them all; both counted ``rig.time_resets``; the bias estimate is kept (the same
    IMU), its pairing restarted."""
    cams, frames, _ = video
    mounts = {c.name: Mounting.from_pose(c.R_rig_cam, c.p_rig_cam) for c in cams}
    imu = GyroSettings(R_cam_imu=R_RIG_IMU, buffer=100.0, estimate_bias=True)
    rig = Localizer(LocalizerSettings(mounts, imu=imu, tracking=None))
    by = {c.name: c.camera for c in cams}
    stamps = [T0 + k * 5_000_000 for k in range(100)]  # (0.5 s at 200 Hz)
    for t in stamps:
        assert rig.add_imu(t, np.zeros(3)) is None
    first = [f for f in frames if f.stamp_ns < T0 + 200_000_000]
    for f in first:
        rig.add(CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name))
    newest = max(f.stamp_ns for f in first)
    bias = rig.gyro_bias
    assert rig.counts["rig.time_resets"] == 0 and len(rig.imu) == 100
    f = frames[len(first)]
    rig.add(CameraFrame(f.stamp_ns + 3 * 10**9, by[f.name], f.uv, f.xyz, camera_name=f.name))
    assert rig.counts["rig.time_resets"] == 1
    assert len(rig.imu) == sum(t >= newest for t in stamps) > 0
    assert rig.gyro_bias is bias and rig.gyro_bias._prev is None
    rig.add(CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name))  # (3 s back)
    assert rig.counts["rig.time_resets"] == 2 and len(rig.imu) == 0
    assert rig.rig_counts()["skipped"] > 0  # (the rig frame open at the step back: dropped)


def test_the_rigs_gap_is_passed_to_the_gyro_check_and_bias_estimator():
    """The rig's gyro forms no pair of rig frames across its one gap, ``tracking.max_gap``
    (0.5 s without tracking), as a camera's across ``SequenceSettings.max_gap``, whatever
    ``stop_after``."""
    from rs_localizer.tracking.tracker import TrackerOptions

    cams = default_rig(2)
    mounts = {c.name: Mounting.from_pose(c.R_rig_cam, c.p_rig_cam) for c in cams}
    imu = GyroSettings(estimate_bias=True)
    to = TrackerOptions(max_gap=0.3)
    rig = Localizer(LocalizerSettings(mounts, imu=imu, tracking=to, stop_after=0.8))
    assert rig.gyro_check.options.max_interval == rig.gyro_bias.options.max_interval == 0.3
    rig = Localizer(LocalizerSettings(mounts, imu=imu, tracking=None, stop_after=0.8))
    assert rig.gyro_check.options.max_interval == rig.gyro_bias.options.max_interval == 0.5


def test_the_filter_takes_out_only_the_prior_a_frames_refinement_holds():
    """A rig frame posed with a right gyro is refined with the gyro's rate alone
    (``motion_prior_used``; the rig estimator takes no motion prior): its solve gives the twist
    filter no prior to take out, though its options carry one; one camera's frame with the same
    gyro holds the options' motion prior with it, which the filter takes out."""
    from rs_localizer.estimation.gyro import GyroMeasurement
    from rs_localizer.estimation.rig import RIG_OPTIONS
    from rs_localizer.estimation.view import View
    from rs_localizer.sim import synthetic as sim_rig
    from rs_localizer.tracking.tracker import FrameViews

    rng = np.random.default_rng(5)
    rig = sim_rig.make_rig(3, rng)
    truth = sim_rig.rig_motion(rng, 1.5, 1.5)
    f = sim_rig.rig_frame(rig, truth, [60] * 3, rng)
    gyro = GyroMeasurement(-truth.w, 0.005**2 * np.eye(3))
    assert RIG_OPTIONS.motion_prior is not None
    solve = FrameViews(f.views, RIG_OPTIONS, RIG_OPTIONS, gyro=gyro).cold()
    est = solve.estimate
    assert est.success and est.gyro_used and est.motion_prior_used
    assert solve.prior is None
    v = f.views[0]
    R_m = v.mounting.R  # (the gyro in the camera's optical frame: R_cam_rig omega)
    own = View(v.uv, v.X, v.camera, Mounting(np.eye(3), np.zeros(3)))
    one = GyroMeasurement(R_m @ -truth.w, 0.005**2 * np.eye(3))
    solve = FrameViews((own,), RIG_OPTIONS, RIG_OPTIONS, solver="r6p_1lin", gyro=one).cold()
    assert solve.estimate.success and solve.estimate.motion_prior_used
    assert solve.prior is RIG_OPTIONS.motion_prior
