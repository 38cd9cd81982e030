"""SequenceLocalizer while its kernels compile (its ``implementation`` says ``"numpy"``): a
camera's video is tracked on the NumPy implementation as on the compiled one (the prediction
seeding RANSAC, the gyro, the twist filter), against the simulated truth, and the track goes
on across the switch to the compiled implementation."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.fresh_cache import run_on_empty_cache

from rs_localizer.estimation.estimate import EstimateOptions, RansacOptions
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.sim.trajectory import (
    R_IMU_CAMERA,
    SequenceConfig,
    generate_sequence,
    imu_samples,
    make_trajectory,
)
from rs_localizer.tracking.localizer import CameraFrame
from rs_localizer.tracking.sequence import GyroSettings, SequenceLocalizer, SequenceSettings

OPTS = EstimateOptions(ransac=RansacOptions(seed=0))
NOISE = 0.003  # rad/s per gyro sample
BIAS = np.array([0.01, -0.02, 0.005])  # rad/s, the simulated gyro's (known here)
T0 = SequenceConfig().t0_ns


@pytest.fixture(scope="module")
def video():
    """1 s of hand-held shake at 30 Hz, 300 correspondences (20 % outliers, 0.5 px), with a
    200 Hz gyro mounted as ``R_IMU_CAMERA``."""
    n = 30
    traj = make_trajectory("shake")
    frames, _, cam, _ = generate_sequence(
        SequenceConfig(num_frames=n, num_points=300, seed=2), trajectory=traj
    )
    t, om, _ = imu_samples(traj, -0.1, n / 30.0 + 0.1, 200.0, 1, NOISE, BIAS)
    return frames, cam, (T0 + np.round(t * 1e9).astype(np.int64), om)


def _run(video, implementation, gyro=True, switch=None):
    """The video through a SequenceLocalizer on ``implementation`` (from frame ``switch`` on:
    ``"compiled"``), with the gyro's samples all added first (offline). Returns (localizer,
    outputs, fused twists)."""
    frames, cam, (t, om) = video
    imu = None
    if gyro:
        imu = GyroSettings(
            R_cam_imu=R_IMU_CAMERA.T, gyro_noise=NOISE, gyro_bias=BIAS, gyro_bias_sigma=0.001
        )
    state = {"impl": implementation}
    seq = SequenceLocalizer(
        SequenceSettings(options=OPTS, stamp_row=0.0, imu=imu),
        implementation=lambda solver: state["impl"],
        imu_span=np.inf,
    )
    if gyro:
        for ti, wi in zip(t, om, strict=True):
            assert seq.add_imu(int(ti), wi) is None
    outs, fused = [], []
    for k, f in enumerate(frames):
        if k == switch:
            state["impl"] = "compiled"
        o = seq.process(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz))
        outs.append(o)
        fused += o.fused
    fused += seq.flush()
    return seq, outs, fused


def _errors(poses, frames):
    """(rotation deg, position m, angular velocity rad/s) of each ``(stamp_ns, RSPose)``
    against the frame of that reference time's truth."""
    by = {f.t_ref_ns: f for f in frames}
    e = []
    for stamp, pose in poses:
        f = by[stamp]
        e.append((rotation_angle_deg(pose.orientation, f.orientation),
                  np.linalg.norm(pose.position - f.position),
                  np.linalg.norm(pose.angular_velocity - f.angular_velocity)))  # fmt: skip
    return np.array(e)


def test_a_video_on_numpy_is_tracked_with_the_gyro_as_accurate_as_compiled(video):
    """The whole video on ``"numpy"`` and again on ``"compiled"``: on NumPy every frame
    after the first is tracked (the prediction seeded RANSAC: ``initial_used``), solved with
    the gyro, counted uncompiled (``compiled`` False), and its fused twist comes out; against
    the simulated truth the NumPy run's median rotation, position and angular velocity
    errors (own and fused) are within 1.5x the compiled run's (+ a floor of 0.005 deg,
    0.5 mm, 0.005 rad/s)."""
    frames = video[0]
    seq, outs, fused = _run(video, "numpy")
    _, ref, ref_fused = _run(video, "compiled")
    ests = [o.estimate for o in outs]
    assert all(e is not None and e.success for e in ests)
    assert all(not o.compiled for o in outs) and all(e.implementation == "numpy" for e in ests)
    assert all(r.compiled and r.estimate.implementation == "compiled" for r in ref)
    assert [o.path for o in outs] == ["cold"] + ["tracked"] * (len(outs) - 1)
    assert [r.path for r in ref] == [o.path for o in outs]
    assert all(e.initial_used for e in ests[1:]) and all(e.ignored_inputs == () for e in ests)
    assert all(o.gyro is not None and e.gyro_used for o, e in zip(outs, ests, strict=True))
    assert seq.counts["frames_with_gyro"] == len(outs)
    assert [f.pose.stamp_ns for f in fused] == [o.stamp_ns for o in outs]
    assert len(ref_fused) == len(fused)
    floor = np.array([0.005, 0.0005, 0.005])
    own = [[(o.stamp_ns, o.estimate.pose) for o in run] for run in (outs, ref)]
    twists = [[(f.pose.stamp_ns, f.pose) for f in run] for run in (fused, ref_fused)]
    for mine, theirs in (own, twists):
        m = np.median(_errors(mine, frames), axis=0)
        c = np.median(_errors(theirs, frames), axis=0)
        assert (m <= 1.5 * c + floor).all(), (m, c)


def test_the_track_goes_on_across_the_switch_to_compiled(video):
    """No gyro, the first 8 frames on ``"numpy"``, then ``"compiled"``: one track throughout
    (a cold frame, then tracked ones; no reset or cold frame at the switch), every frame's
    twist fused, each pose within 0.1 deg and 1 cm of the truth."""
    frames = video[0]
    seq, outs, fused = _run(video, "numpy", gyro=False, switch=8)
    n = len(outs)
    assert [o.compiled for o in outs] == [False] * 8 + [True] * (n - 8)
    assert [o.estimate.implementation for o in outs] == ["numpy"] * 8 + ["compiled"] * (n - 8)
    assert [o.path for o in outs] == ["cold"] + ["tracked"] * (n - 1)
    assert seq.tracking_values()["resets"] == 0
    assert [f.pose.stamp_ns for f in fused] == [o.stamp_ns for o in outs]
    e = _errors([(o.stamp_ns, o.estimate.pose) for o in outs], frames)
    assert (e[:, 0] < 0.1).all() and (e[:, 1] < 0.01).all(), e


def test_the_twist_filter_on_numpy_is_the_compiled_filter(video):
    """``TwistFilter.compiled`` False (the filter's steps as plain Python, what a frame on the
    NumPy implementation takes) gives the compiled filter's states: the same estimates fed to
    both, every prediction and update within 1e-9 (relative) of the other's."""
    from rs_localizer.tracking.fusion import TwistFilter
    from rs_localizer.tracking.tracker import RSTracker

    frames, cam, _ = video
    tracker = RSTracker()
    ests = [
        (f.t_ref_ns, tracker.process(f.t_ref_ns, f.uv, f.xyz, cam).estimate) for f in frames[:12]
    ]
    a, b = TwistFilter(tracker.filter.options), TwistFilter(tracker.filter.options)
    a.compiled, b.compiled = True, False
    for k, (stamp, est) in enumerate(ests):
        if k:
            pa, pb = a.predict(stamp), b.predict(stamp)
            np.testing.assert_allclose(pb.covariance, pa.covariance, rtol=1e-9, atol=1e-15)
            np.testing.assert_allclose(pb.pose.position, pa.pose.position, rtol=1e-9)
        a.update(stamp, est)
        b.update(stamp, est)
        np.testing.assert_allclose(b.X, a.X, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(b.P, a.P, rtol=1e-9, atol=1e-15)
    assert len(a.window) == len(b.window) > 1


_NO_COMPILE = """
import sys
sys.path[:0] = ARGS  # (this test's folder and the tests' helpers)
import test_sequence_uncompiled as T

video = T.video.__wrapped__()
seq, outs, fused = T._run(video, "numpy")
result = {"paths": [o.path for o in outs], "gyro": sum(o.estimate.gyro_used for o in outs),
          "fused": len(fused)}
"""


def test_a_tracked_video_on_numpy_compiles_nothing(tmp_path):
    """In a fresh process with an empty numba cache, the video on ``"numpy"`` with the gyro
    is tracked and fused (the tracker's prediction, the gyro's prior and checks, the twist
    filter as plain Python) and numba compiles no kernel nor loads one: a node's frames
    while its kernels compile in the background never wait for a compile."""
    from pathlib import Path

    here = Path(__file__).resolve().parent
    res = run_on_empty_cache(_NO_COMPILE, tmp_path, here, here.parent, timeout=120)
    paths = res["result"]["paths"]
    n = len(paths)
    assert paths == ["cold"] + ["tracked"] * (n - 1) and res["result"]["fused"] == n
    assert res["result"]["gyro"] == n
    assert res["kernels"] == []
    assert res["used"] == []
