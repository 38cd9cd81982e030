"""A wrong IMU never makes a published pose worse: a seeded fuzz of the gyro through the
node's offline path (:func:`rs_localizer.ros.bags.replay.replay`) on a recorded bag.

A small ``make-bag --motion shake --imu-rate 200`` bag (24 frames of 300 correspondences with
20 % outliers, a 200 Hz gyro) is copied with its ``sensor_msgs/Imu`` messages attacked the ways
a real IMU stream goes wrong: spikes of +-30 rad/s on a few samples (under ``imu.max_rate``),
a run of garbage rates under that bound, one sample stamped 5 s ahead, samples stamped in the
past, a 0.2 s dropout; and the clean bag is replayed with a wrong mount (``imu.rotation``).
Each is replayed with the IMU on (``imu.enabled`` and the bag's true mount from its
``sequence.json``) and compared, frame by frame, with the clean bag replayed with the IMU off:
every published pose's rotation and position errors against the bag's ground truth must not
exceed the IMU-off ones by more than 1.2x (plus the noise floor :data:`ROT_FLOOR_DEG`,
:data:`POS_FLOOR_M`), every frame is accounted for, and after a bad stamp the later frames
use the gyro again.
"""

from __future__ import annotations

import dataclasses
import json
import shutil

import numpy as np
import pytest

pytest.importorskip("rosbags")

FRAMES = 24
#: absolute slack on top of 1.2x (deg, m): the per-frame noise of the IMU-off pose
ROT_FLOOR_DEG = 0.03
POS_FLOOR_M = 0.003
RATIO = 1.2
ATTACKS = ("spikes", "garbage", "future_stamp", "past_stamp", "dropout", "wrong_mount")
#: attacks after which the gyro must come back for the later frames
STAMP_ATTACKS = ("future_stamp", "past_stamp")
#: IMU messages each attack adds to the bag (the dropout removes 40)
ADDED = {"future_stamp": 1, "past_stamp": 2, "dropout": -40}
#: attacks the image must contradict on some frame (the gyro then left out)
CONTRADICTED = ("spikes", "garbage", "wrong_mount")


@pytest.fixture(scope="session")
def gyro_bag(tmp_path_factory):
    """The clean bag, its IMU-on parameters (true mount) and its IMU-off replay."""
    from scipy.spatial.transform import Rotation

    from rs_localizer.cli import main
    from rs_localizer.ros.bags.replay import replay

    out = tmp_path_factory.mktemp("imu_fuzz") / "bag"
    args = ["make-bag", str(out), "--motion", "shake", "--imu-rate", "200"]
    args += ["--frames", str(FRAMES), "--points", "300", "--quiet"]
    assert main(args) == 0
    info = json.loads((out / "sequence.json").read_text())
    R_imu_camera = np.array(info["imu"]["rotation_imu_from_camera"])
    # imu.rotation: IMU -> camera optical frame, x y z w
    quat = Rotation.from_matrix(R_imu_camera.T).as_quat()
    params = {"imu.enabled": True, "imu.rotation": [float(q) for q in quat]}
    base = replay(out, params={}, progress=None)
    assert base.solved == FRAMES, base.failures
    return out, info["topics"]["imu"], params, base


def _attacked_copy(src, dst, imu_topic: str, kind: str, seed: int) -> None:
    """Copy the bag at ``src`` to ``dst`` with its IMU messages under attack ``kind``
    (inserted samples are logged at the time of the sample they follow)."""
    from rosbags.rosbag2 import Reader, Writer

    from rs_localizer.ros.bags.bag_io import storage_plugin, typestore

    ts = typestore()
    rng = np.random.default_rng(seed)
    with Reader(src) as r:
        msgs = [(c, t, bytes(raw)) for c, t, raw in r.messages()]
        connections = list(r.connections)
    imu = [k for k, (c, _, _) in enumerate(msgs) if c.topic == imu_topic]
    n = len(imu)
    decoded = {k: ts.deserialize_cdr(msgs[k][2], msgs[k][0].msgtype) for k in imu}

    def with_rate(m, w):
        V = type(m.angular_velocity)
        return dataclasses.replace(m, angular_velocity=V(x=w[0], y=w[1], z=w[2]))

    def with_stamp(m, stamp_ns: int):
        T = type(m.header.stamp)
        stamp = T(sec=int(stamp_ns // 10**9), nanosec=int(stamp_ns % 10**9))
        return dataclasses.replace(m, header=dataclasses.replace(m.header, stamp=stamp))

    def stamp_of(m) -> int:
        return m.header.stamp.sec * 10**9 + m.header.stamp.nanosec

    extra = {}  # message index -> messages logged right after it
    drop = set()
    if kind == "spikes":  # a few samples at +-30 rad/s on one axis
        for j in rng.choice(n, size=max(3, n // 40), replace=False):
            m = decoded[imu[j]]
            w = [m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z]
            w[int(rng.integers(3))] = float(rng.choice([-30.0, 30.0]))
            decoded[imu[j]] = with_rate(m, w)
    elif kind == "garbage":  # a run of random rates under imu.max_rate
        j0 = int(rng.integers(n // 4, n // 2))
        for j in range(j0, min(n, j0 + n // 4)):
            decoded[imu[j]] = with_rate(
                decoded[imu[j]], [float(v) for v in rng.uniform(-30, 30, 3)]
            )
    elif kind == "future_stamp":  # one sample stamped 5 s ahead, early in the video
        j = int(rng.integers(10, n // 4))
        m = decoded[imu[j]]
        extra[imu[j]] = [with_stamp(m, stamp_of(m) + 5_000_000_000)]
    elif kind == "past_stamp":  # a sample stamped 10 s in the past, another at 1 ns
        j = int(rng.integers(10, n // 4))
        m = decoded[imu[j]]
        extra[imu[j]] = [with_stamp(m, stamp_of(m) - 10_000_000_000)]
        m5 = decoded[imu[j + 5]]
        extra[imu[j + 5]] = [with_stamp(m5, 1)]
    elif kind == "dropout":  # 0.2 s without samples
        j0 = int(rng.integers(n // 4, n // 2))
        drop = set(imu[j0 : j0 + 40])
    with Writer(dst, version=9, storage_plugin=storage_plugin("mcap")) as w:
        conns = {
            c.id: w.add_connection(c.topic, c.msgtype, typestore=ts, serialization_format="cdr")
            for c in connections
        }
        for k, (c, t, raw) in enumerate(msgs):
            if k in drop:
                continue
            if k in decoded:
                raw = bytes(ts.serialize_cdr(decoded[k], c.msgtype))
            w.write(conns[c.id], t, raw)
            for m in extra.get(k, []):
                w.write(conns[c.id], t, bytes(ts.serialize_cdr(m, c.msgtype)))
    shutil.copy(src / "sequence.json", dst / "sequence.json")
    if (src / "landmarks.csv").is_file():
        shutil.copy(src / "landmarks.csv", dst / "landmarks.csv")


def _imu_messages(bag, imu_topic: str) -> int:
    from rs_localizer.ros.bags.bag_io import iter_messages

    return sum(1 for _ in iter_messages(bag, {imu_topic}))


def _max_ratios(attacked, base) -> tuple[float, float, list]:
    """The largest per-frame error ratios (rotation, position) of ``attacked`` over ``base``
    and the frames beyond ``RATIO`` x base + floor: ``(frame, rot, rot_base, pos, pos_base)``."""
    worst_rot = worst_pos = 0.0
    worse = []
    for a, b in zip(attacked.rows, base.rows, strict=True):
        assert a["stamp_ns"] == b["stamp_ns"]
        if not (a["success"] and b["success"]):
            continue
        rot, rot_b = a["err_rot_deg"], b["err_rot_deg"]
        pos, pos_b = a["err_pos_m"], b["err_pos_m"]
        worst_rot = max(worst_rot, rot / max(rot_b, 1e-9))
        worst_pos = max(worst_pos, pos / max(pos_b, 1e-9))
        if rot > RATIO * rot_b + ROT_FLOOR_DEG or pos > RATIO * pos_b + POS_FLOOR_M:
            worse.append((a["frame"], rot, rot_b, pos, pos_b))
    return worst_rot, worst_pos, worse


@pytest.mark.parametrize("kind", ATTACKS)
def test_a_wrong_imu_never_makes_a_replayed_pose_worse(gyro_bag, tmp_path, kind):
    from rs_localizer.ros.bags.replay import replay

    src, imu_topic, params, base = gyro_bag
    if kind == "wrong_mount":  # the clean bag, the node told a mount 90 deg off
        from scipy.spatial.transform import Rotation

        R = Rotation.from_quat(params["imu.rotation"]) * Rotation.from_rotvec([0, 0, np.pi / 2])
        bag, params = src, {**params, "imu.rotation": [float(q) for q in R.as_quat()]}
    else:
        bag = tmp_path / "attacked"
        _attacked_copy(src, bag, imu_topic, kind, seed=ATTACKS.index(kind))
        count = _imu_messages(bag, imu_topic)
        assert count == _imu_messages(src, imu_topic) + ADDED.get(kind, 0)
    res = replay(bag, params=params, progress=None)
    # frame accounting: every frame of the bag is solved or failed with a reason (offline
    # nothing is skipped or left pending)
    assert len(res.rows) == FRAMES
    failed = sum(res.failures.values())
    assert res.solved + failed == FRAMES, (res.solved, res.failures)
    assert all(r["failure"] for r in res.rows if not r["success"])
    assert res.solved >= base.solved - 1, res.failures
    c = res.counts
    rot, pos, worse = _max_ratios(res, base)
    print(f"{kind}: max error ratio rot {rot:.2f} pos {pos:.2f}; counts {c}")
    assert not worse, (kind, worse, c)
    if kind in STAMP_ATTACKS:
        # the bad stamps cost at most a few samples: the later frames use the gyro again
        assert c.get("frames_with_gyro", 0) >= FRAMES - 2, c
        assert not any(k.startswith("gyro_missing") for k in c), c
    if kind in CONTRADICTED:
        assert c.get("gyro_rejected", 0) + c.get("gyro_disabled_inconsistent", 0) >= 1, c
    if kind == "dropout":  # (the frames in the gap are solved without the gyro, counted)
        assert c.get("gyro_missing", 0) >= 1, c
    if kind == "past_stamp":  # (a sample going back is refused, and counted)
        assert c.get("imu_rejected.stamp_not_increasing", 0) >= 1, c
    if kind == "future_stamp":  # (the lone sample ahead is dropped, and counted)
        assert c.get("imu_rejected.stamp_jumped_ahead", 0) >= 1, c
