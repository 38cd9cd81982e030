"""Localizer while its kernels compile (its ``implementation`` says ``"numpy"``): the rig
frames are tracked on the NumPy implementation as on the compiled one (the prediction, the
gyro, the twist filter), against the rig's true trajectory, and the track goes on across
the switch to the compiled implementation."""

from __future__ import annotations

import numpy as np
from helpers.rig import T0, assert_balanced, mounts_of

from rs_localizer.geometry import rotation_angle_deg, rotvec_to_matrix
from rs_localizer.sim.trajectory import default_rig, generate_rig_video, rig_gyro, rig_truth
from rs_localizer.tracking.localizer import CameraFrame
from rs_localizer.tracking.sequence import GyroSettings
from rs_localizer.tracking.video import Localizer, LocalizerSettings

NOISE = 0.003  # rad/s per gyro sample
R_RIG_IMU = rotvec_to_matrix(np.array([0.3, -0.2, 1.0]))  # an IMU mounted turned on the rig


def test_rig_frames_tracked_on_numpy_and_the_track_goes_on_once_compiled():
    """3 cameras, 20 % outliers: the first 6 rig frames on ``"numpy"`` (``compiled`` False,
    counted ``rig.uncompiled``), then ``"compiled"``: one track throughout (a cold frame, then
    tracked ones, no second cold frame at the switch), every rig frame's twist fused, each
    pose within 0.05 deg and 5 mm of the truth; the counts balance."""
    cams = default_rig(3)
    frames, _, traj = generate_rig_video(cams, duration=0.4, num_points=120, seed=7)
    by = {c.name: c.camera for c in cams}
    state = {"impl": "numpy"}
    rig = Localizer(LocalizerSettings(mounts_of(cams)), implementation=lambda: state["impl"])
    outs, fused = [], []
    for f in frames:
        for o in rig.add(CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name)):
            outs.append(o)
            fused += o.fused
            if len(outs) == 6:
                state["impl"] = "compiled"
    for o in rig.close():
        outs.append(o)
        fused += o.fused
    fused += rig.flush()
    assert len(outs) == 12 and all(o.success for o in outs)
    assert [o.compiled for o in outs] == [False] * 6 + [True] * 6
    assert [o.estimate.implementation for o in outs] == ["numpy"] * 6 + ["compiled"] * 6
    assert [o.path for o in outs] == ["cold"] + ["tracked"] * 11
    assert [f.pose.stamp_ns for f in fused] == [o.stamp_ns for o in outs]
    assert rig.counts["rig.uncompiled"] == 6
    for o in outs:
        R, p, _, _ = rig_truth(traj, (o.stamp_ns - T0) * 1e-9)
        pose = o.estimate.pose
        assert rotation_angle_deg(pose.orientation, R) < 0.05
        assert np.linalg.norm(pose.position - p) < 0.005
    assert_balanced(rig)


def _video_run(cams, frames, gyro, impl):
    """The rig video with its gyro samples, in arrival order (a frame 30 ms after its
    stamp), through a Localizer on ``impl``. Returns (rig, outputs, fused twists)."""
    imu = GyroSettings(R_cam_imu=R_RIG_IMU, gyro_noise=NOISE, gyro_bias_sigma=0.001)
    rig = Localizer(LocalizerSettings(mounts_of(cams), imu=imu), implementation=lambda: impl)
    by = {c.name: c.camera for c in cams}
    events = [(f.stamp_ns + 30_000_000, 1, f) for f in frames]
    events += [(int(t), 0, w) for t, w in zip(*gyro, strict=True)]
    outs = []
    for t, kind, item in sorted(events, key=lambda e: (e[0], e[1])):
        if kind == 0:
            assert rig.add_imu(t, item) is None
        else:
            outs += rig.add(
                CameraFrame(item.stamp_ns, by[item.name], item.uv, item.xyz, camera_name=item.name)
            )
    outs += rig.close()
    fused = [f for o in outs for f in o.fused] + rig.flush()
    return rig, outs, fused


def _errors(poses, traj):
    """(rotation deg, position m, angular velocity rad/s) of each ``(stamp_ns, RSPose)``
    against the truth."""
    e = []
    for stamp, pose in poses:
        R, p, w, _ = rig_truth(traj, (stamp - T0) * 1e-9)
        e.append((rotation_angle_deg(pose.orientation, R), np.linalg.norm(pose.position - p),
                  np.linalg.norm(pose.angular_velocity - w)))  # fmt: skip
    return np.array(e)


def test_a_rig_video_on_numpy_keeps_its_track_with_the_gyro_as_accurate_as_compiled():
    """2 cameras x 60 points over 0.8 s with a gyro at 400 Hz, the whole video on
    ``"numpy"`` and again on ``"compiled"``: on NumPy every rig frame after the first is
    tracked (the prediction seeded it), solved with the gyro, and its fused twist comes out;
    against the true trajectory the NumPy run's median rotation, position and angular
    velocity errors (own and fused) are within 1.5x the compiled run's (+ a floor of
    0.005 deg, 0.5 mm, 0.005 rad/s)."""
    cams = default_rig(2)
    frames, _, traj = generate_rig_video(cams, duration=0.8, num_points=60, seed=5)
    gyro = rig_gyro(traj, 0.8, R_rig_imu=R_RIG_IMU, noise=NOISE, seed=1)
    rig, outs, fused = _video_run(cams, frames, gyro, "numpy")
    _, ref, ref_fused = _video_run(cams, frames, gyro, "compiled")
    assert len(outs) == len(ref) > 20 and all(o.success for o in outs)
    assert all(not o.compiled and o.estimate.implementation == "numpy" for o in outs)
    assert [o.path for o in outs] == ["cold"] + ["tracked"] * (len(outs) - 1)
    assert all(o.estimate.initial_used for o in outs[1:])
    assert all(o.gyro is not None and o.estimate.gyro_used for o in outs)
    assert rig.counts["rig.gyro_used"] == rig.counts["rig.uncompiled"] == len(outs)
    assert sorted(f.pose.stamp_ns for f in fused) == [o.stamp_ns for o in outs]
    assert len(ref_fused) == len(fused)
    floor = np.array([0.005, 0.0005, 0.005])
    own = [[(o.stamp_ns, o.estimate.pose) for o in run] for run in (outs, ref)]
    twists = [[(f.pose.stamp_ns, f.pose) for f in run] for run in (fused, ref_fused)]
    for mine, theirs in (own, twists):
        m, t = np.median(_errors(mine, traj), axis=0), np.median(_errors(theirs, traj), axis=0)
        assert (m <= 1.5 * t + floor).all(), (m, t)
    assert_balanced(rig)
