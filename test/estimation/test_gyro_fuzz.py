"""A wrong IMU never makes a pose worse: a seeded fuzz of the gyro path.

A synthetic hand-held video of the corridor (``generate_sequence`` with the ``shake``
trajectory: 1280x720, 30 us/line, 500 correspondences with 20 % outliers) with a simulated
200 Hz gyro, attacked in the ways a
real IMU stream goes wrong: spikes of +-30 rad/s on a few samples (under ``imu.max_rate``),
garbage rates under that bound, a bias offset far beyond the stated uncertainty, samples
stamped far in the future or the past, dropouts, a wrong mount, a wrong time offset, a time
reset of the IMU clock. Each frame is solved with the gyro measurement the
:class:`~rs_localizer.tracking.gyro.ImuBuffer` gives for its readout and without any gyro;
per frame, the aided pose's rotation and position errors against the ground truth must not
exceed the unaided one's by more than 1.2x (plus the noise floor :data:`ROT_FLOOR_DEG`,
:data:`POS_FLOOR_M`: on a clean frame both are a few hundredths of a degree, and a right gyro
changes them by about that much either way), and every frame is accounted for (solved with
the gyro, rejected by the image, or without samples: never lost).
"""

from __future__ import annotations

import numpy as np
import pytest

from rs_localizer.estimation import EstimateOptions, RansacOptions, estimate_rs_pose
from rs_localizer.geometry import rotation_angle_deg, rotvec_to_matrix
from rs_localizer.sim.gyro import NOISE, RATE_HZ
from rs_localizer.sim.trajectory import (
    R_IMU_CAMERA,
    SequenceConfig,
    generate_sequence,
    imu_samples,
    make_trajectory,
)
from rs_localizer.tracking.gyro import (
    GYRO_MISSING_REASONS,
    IMU_SAMPLE_REJECTIONS,
    ImuBuffer,
)

OPTS = EstimateOptions(ransac=RansacOptions(seed=0))
#: absolute slack on top of 1.2x (deg, m): the per-frame noise of the unaided pose on this video
ROT_FLOOR_DEG = 0.03
POS_FLOOR_M = 0.003
FRAMES = 24

ATTACKS = (
    "clean",
    "spikes",
    "garbage",
    "bias_offset",
    "future_stamp",
    "past_stamp",
    "dropout",
    "wrong_mount",
    "time_offset",
    "clock_reset",
)


@pytest.fixture(scope="module")
def video():
    config = SequenceConfig(num_frames=FRAMES, seed=3, num_landmarks=2000)
    frames, _, cam, traj = generate_sequence(config, trajectory=make_trajectory("shake"))
    t0_ns = config.t0_ns
    t_end = (frames[-1].t_ref_ns - t0_ns) * 1e-9 + 0.1
    t, om, _ = imu_samples(
        traj, -0.1, t_end, RATE_HZ, 3, NOISE, np.zeros(3), R_imu_camera=R_IMU_CAMERA
    )
    stamps = t0_ns + np.round(t * 1e9).astype(np.int64)
    unaided = [estimate_rs_pose(f.uv, f.xyz, cam, "r6p_1lin", OPTS) for f in frames]
    return frames, cam, stamps, om, unaided


def _attacked(kind: str, stamps: np.ndarray, om: np.ndarray, rng: np.random.Generator):
    """The IMU stream ``[(arrival_ns, stamp_ns, rate (3,))]`` in arrival order under attack
    ``kind`` (``arrival_ns``: when the sample arrives, the true time of the sample before it),
    and the mount the node is told (``R_cam_imu``)."""
    s, w = stamps.copy(), om.copy()
    R = R_IMU_CAMERA.T
    n = len(s)
    if kind == "spikes":  # a few samples at +-30 rad/s on one axis
        for k in rng.choice(n, size=max(3, n // 40), replace=False):
            w[k, rng.integers(3)] = rng.choice([-30.0, 30.0])
    elif kind == "garbage":  # a run of random rates under max_rate
        k0 = int(rng.integers(n // 4, n // 2))
        w[k0 : k0 + n // 4] = rng.uniform(-30, 30, (len(w[k0 : k0 + n // 4]), 3))
    elif kind == "bias_offset":  # 2-30 rad/s off, the bias stated to 0.005 rad/s
        w = w + rng.uniform(2, 30) * rng.choice([-1, 1]) * np.eye(3)[rng.integers(3)]
    elif kind == "wrong_mount":
        R = rotvec_to_matrix(np.array([0.0, 0.0, np.pi / 2])) @ R
    elif kind == "time_offset":  # the IMU clock 15 ms behind the stated offset
        s = s + 15_000_000
    stream = [(int(a), int(a), b) for a, b in zip(stamps, w, strict=True)]
    stream = [(a, int(t), b) for (a, _, b), t in zip(stream, s, strict=True)]

    def bad(k: int, stamp: int) -> tuple:
        return (stream[k][0], stamp, stream[k][2])

    if kind == "future_stamp":  # one sample 5 s ahead, another a year ahead
        k = int(rng.integers(10, n // 2))
        stream.insert(k, bad(k, stream[k][1] + 5_000_000_000))
        stream.insert(k + 30, bad(k + 30, stream[k + 30][1] + 365 * 86400 * 10**9))
    elif kind == "past_stamp":  # samples stamped 10 s and at 0 in the past
        k = int(rng.integers(10, n // 2))
        stream.insert(k, bad(k, stream[k][1] - 10_000_000_000))
        stream.insert(k + 5, bad(k + 5, 1))
    elif kind == "dropout":  # 0.2 s without samples
        k = int(rng.integers(n // 4, n // 2))
        del stream[k : k + 40]
    elif kind == "clock_reset":  # the IMU stream restarts 1 s earlier for a moment, resumes
        k = int(rng.integers(n // 4, n // 2))
        replay = [(stream[k][0], a - 1_000_000_000, b) for _, a, b in stream[k - 20 : k]]
        stream = stream[:k] + replay + stream[k:]
    return stream, R


def _run(video, kind: str, seed: int):
    frames, cam, stamps, om, unaided = video
    rng = np.random.default_rng(seed)
    stream, R = _attacked(kind, stamps, om, rng)
    buf = ImuBuffer(span=2.0)
    lead = int(round(cam.line_time(cam.reference_line) * 1e9))
    span = int(round(cam.line_delay * (cam.lines - 1) * 1e9))
    k = 0
    counts = {"used": 0, "rejected": 0, "missing": 0}
    rejected_samples = 0
    worse = []
    for f, u in zip(frames, unaided, strict=True):
        first = f.t_ref_ns - lead
        while k < len(stream) and stream[k][0] <= first + span + 30_000_000:
            why = buf.add(*stream[k][1:])  # (samples arrive up to 30 ms ahead of the frames)
            assert why is None or why in IMU_SAMPLE_REJECTIONS
            rejected_samples += why is not None
            k += 1
        g, why = buf.measurement((first, first + span), R, np.zeros(3), NOISE, 0.005)
        if g is None:
            assert why in GYRO_MISSING_REASONS
            counts["missing"] += 1
            continue
        e = estimate_rs_pose(f.uv, f.xyz, cam, "r6p_1lin", OPTS, gyro=g)
        assert e.success == u.success or (e.success and e.gyro_used), (kind, e.failure)
        assert e.gyro_used != e.gyro_rejected
        counts["used" if e.gyro_used else "rejected"] += 1
        if not (e.success and u.success):
            continue
        rot = rotation_angle_deg(e.pose.orientation, f.orientation)
        rot_u = rotation_angle_deg(u.pose.orientation, f.orientation)
        pos = float(np.linalg.norm(e.pose.position - f.position))
        pos_u = float(np.linalg.norm(u.pose.position - f.position))
        if rot > 1.2 * rot_u + ROT_FLOOR_DEG or pos > 1.2 * pos_u + POS_FLOOR_M:
            worse.append((f.t_ref_ns, rot, rot_u, pos, pos_u, e.gyro_used))
    assert sum(counts.values()) == len(frames)
    return counts, worse, rejected_samples, buf


@pytest.mark.parametrize("kind", ATTACKS)
def test_a_wrong_imu_never_makes_a_pose_worse(video, kind):
    for seed in (0, 1):
        counts, worse, rejected, buf = _run(video, kind, seed)
        assert not worse, (kind, seed, counts, worse)
        if kind == "clean":
            assert counts["used"] == FRAMES and rejected == 0, counts
            assert buf.accepted == buf.received and buf.dropped == 0 and buf.resets == 0
        if kind in ("future_stamp", "past_stamp"):
            # the bad stamps cost at most a few samples: the gyro is back for every frame
            assert counts["missing"] == 0 and counts["used"] >= FRAMES - 1, (kind, counts)
            assert rejected <= 25, (kind, rejected)
        if kind in ("spikes", "garbage", "bias_offset", "wrong_mount"):
            assert counts["rejected"] >= 1, (kind, counts)
