"""The check of a gyro against the rotation between solved frames
(rs_localizer.tracking.gyro_check) on simulated hand-held motion with a known mount: a
90 deg wrong mount is detected, a right one with noisy and occasionally wrong poses is not,
and a mount that becomes right again recovers."""

import warnings

import numpy as np
import pytest

from rs_localizer.geometry import rotation_angle_deg, rotvec_to_matrix
from rs_localizer.sim.trajectory import R_IMU_CAMERA, imu_samples, make_trajectory
from rs_localizer.tracking.gyro import ImuBuffer
from rs_localizer.tracking.gyro_check import GyroMountCheck, MountCheckOptions

T0 = 1_000_000_000_000  # ns, the video's start on the camera clock
NOISE = 0.003
BIAS = np.array([0.01, -0.02, 0.005])
#: a camera-IMU rotation wrong by 90 deg about the optical axis
R_WRONG = rotvec_to_matrix(np.array([0.0, 0.0, np.pi / 2])) @ R_IMU_CAMERA.T


def _imu(traj, seconds, switch=None, R_after=None):
    """A 200 Hz gyro mounted as R_IMU_CAMERA over [-0.1, seconds + 0.1] s; from ``switch``
    s on, its samples are those of an IMU mounted as ``R_after`` (camera -> IMU)."""
    t, om, _ = imu_samples(traj, -0.1, seconds + 0.1, 200.0, 0, NOISE, BIAS)
    if switch is not None:
        _, om2, _ = imu_samples(
            traj, -0.1, seconds + 0.1, 200.0, 0, NOISE, BIAS, R_imu_camera=R_after
        )
        om = np.where((t >= switch)[:, None], om2, om)
    buf = ImuBuffer(span=np.inf)
    for ti, wi in zip(t, om, strict=True):
        buf.add(T0 + int(round(ti * 1e9)), wi)
    return buf


def _run(check, traj, buf, n, pose_sigma=3e-4, bad_every=0, seed=0):
    """Frames at 30 fps with the true orientation perturbed by ``pose_sigma`` rad (the
    covariance says so); every ``bad_every``-th frame is 5 deg off (a wrong pose). Returns
    ``inconsistent`` after each frame."""
    rng = np.random.default_rng(seed)
    P = pose_sigma**2 * np.eye(3)
    out = []
    for k in range(n):
        t = k / 30.0
        err = rng.normal(0, pose_sigma, 3)
        if bad_every and k % bad_every == bad_every // 2:
            err = err + np.deg2rad(5.0) * rng.normal(size=3) / np.sqrt(3)
        Ori = rotvec_to_matrix(err) @ traj.orientation(t)
        check.update(T0 + int(round(t * 1e9)), Ori, P, buf, BIAS, 1e-6 * np.eye(3))
        out.append(check.inconsistent)
    return np.array(out)


def test_wrong_mount_detected_and_recovers():
    """A mount 90 deg off is declared inconsistent within 12 frames of hand-held shake; once
    the samples agree with the assumed mount (from 4 s on), it is consistent again within
    a window and a half."""
    traj = make_trajectory("shake")
    buf = _imu(traj, 8.0, switch=4.0, R_after=R_WRONG.T)
    check = GyroMountCheck(R_WRONG, NOISE)
    inc = _run(check, traj, buf, 240)
    first = int(np.argmax(inc))
    assert inc.any() and first <= 12, first
    assert inc[first:120].all()  # (stays declared while the mount is wrong)
    assert check.detections == 1
    assert check.mount_error_deg == pytest.approx(90.0, abs=10.0)  # (found at the detection)
    back = 120 + int(np.argmin(inc[120:]))
    assert not inc[-1] and back <= 120 + 15, back
    assert check.counts["failed"] >= 100


@pytest.mark.parametrize(
    "rotvec",
    [
        [0.0, 0.0, np.pi / 2],  # 90 deg about the optical axis
        np.full(3, 2 * np.pi / 3 / np.sqrt(3)),  # the axes permuted (x -> y -> z -> x)
        [np.pi, 0.0, 0.0],  # two axes' signs flipped
        [0.0, -0.6, 0.0],  # 34 deg off
    ],
)
def test_mount_error_is_the_mounts_error(rotvec):
    """A mount wrong by a known rotation ``E`` (``E R_true`` assumed) is detected, and the
    mount the check's window suggests, ``mount_error`` times the assumed one, is the true
    mount within 1.5 deg (the poses' noise, 0.02 deg per frame, against pairs' rotations of
    0.5-3 deg); the mount error's angle is ``E``'s."""
    E = rotvec_to_matrix(np.asarray(rotvec, dtype=float))
    traj = make_trajectory("shake")
    check = GyroMountCheck(E @ R_IMU_CAMERA.T, NOISE)
    inc = _run(check, traj, _imu(traj, 3.0), 60)
    assert inc.any() and int(np.argmax(inc)) <= 12
    assert rotation_angle_deg(check.mount_error @ check.R_cam_imu, R_IMU_CAMERA.T) < 1.5
    angle = np.rad2deg(np.linalg.norm(rotvec))
    assert check.mount_error_deg == pytest.approx(angle, abs=1.5)


def test_a_window_of_rotations_about_one_axis_is_explained_without_a_warning():
    """A window of pairs turning about one axis only (a pan without noise: the mount error
    about that axis is not observable) whose image rotations are the gyro's turned 90 deg
    about x: explained by a mount error that turns the gyro's axis onto the image's, and no
    warning reaches the caller's log."""
    check = GyroMountCheck(R_IMU_CAMERA.T, NOISE)
    Q0 = rotvec_to_matrix(np.array([np.pi / 2, 0.0, 0.0]))
    for k in np.linspace(0.01, 0.03, check.options.window):
        phi = np.array([0.0, 0.0, k])
        check._window.append((True, phi, Q0 @ phi))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert check._explained_by_mount()
    assert np.allclose(check.mount_error @ [0.0, 0.0, 1.0], Q0 @ [0.0, 0.0, 1.0])


def test_right_mount_not_flagged_despite_wrong_poses():
    """The right mount over 40 s of shake with noisy poses and one pose in 15 wrong by
    5 deg (each fails two pairs): never declared inconsistent."""
    traj = make_trajectory("shake")
    buf = _imu(traj, 40.0)
    check = GyroMountCheck(R_IMU_CAMERA.T, NOISE)
    inc = _run(check, traj, buf, 1200, bad_every=15)
    assert check.counts["failed"] >= 100  # (the wrong poses do fail their pairs)
    assert not inc.any() and check.detections == 0


def test_bad_options():
    with pytest.raises(ValueError):
        MountCheckOptions(window=5, failures=6)
    with pytest.raises(ValueError):
        MountCheckOptions(recover_failures=6)
    with pytest.raises(ValueError):
        GyroMountCheck(np.ones((3, 3)), NOISE)
