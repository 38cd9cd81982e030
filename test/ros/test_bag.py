"""Bag tools: make-bag (mcap and sqlite3), reading back, play over DDS, offline replay."""

from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("rosbags")

from helpers.ros import spinning

from rs_localizer.cli import main as cli
from rs_localizer.ros.bags import bag_io
from rs_localizer.ros.bags import play as rs_play
from rs_localizer.ros.bags import replay as rs_replay


@pytest.fixture(scope="module")
def small_bags(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("bags")
    out = {}
    for storage in ("mcap", "sqlite3"):
        path = tmp / f"seq_{storage}"
        assert (
            cli(
                [
                    "make-bag",
                    str(path),
                    "--frames",
                    "4",
                    "--points",
                    "200",
                    "--storage",
                    storage,
                    "--scores",
                    "--seed",
                    "7",
                ]
            )
            == 0
        )
        out[storage] = path
    return out


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_make_bag_contents(small_bags, storage):
    from rosbags.rosbag2 import Reader

    from rs_localizer.maps import load_landmarks_csv
    from rs_localizer.ros.pointcloud import read_correspondences, read_keypoints

    path = small_bags[storage]
    with Reader(path) as r:
        counts = {c.topic: c.msgcount for c in r.connections}
        assert r.storage_plugin_name if hasattr(r, "storage_plugin_name") else True
    assert counts == {
        "/camera/camera_info": 4,
        "/camera/correspondences": 4,
        "/camera/keypoints": 4,
        "/ground_truth/pose": 4,
        "/ground_truth/twist": 4,
    }
    # (the bag's index, as replay reads it: each topic's type and count of the messages read)
    read = Counter((t, mt) for t, mt, _, _ in bag_io.iter_messages(path))
    assert bag_io.bag_connections(path) == {t: (mt, n) for (t, mt), n in read.items()}
    info = bag_io.read_bag_info(path)
    assert info["rs"]["line_delay"] == pytest.approx(30e-6)
    assert info["rs"]["reference_row"] == pytest.approx(359.5)
    assert info["settings"]["num_points"] == 200
    ids, pts = load_landmarks_csv(path / "landmarks.csv")
    lm = dict(zip(ids.tolist(), pts, strict=True))
    ts = bag_io.typestore()
    order = []
    for topic, msgtype, _t, raw in bag_io.iter_messages(path):
        order.append(topic)
        msg = ts.deserialize_cdr(raw, msgtype)
        if topic.endswith("correspondences"):
            c = read_correspondences(msg)
            assert c.uv.shape == (200, 2) and c.ids is not None and c.scores is not None
            assert msg.header.frame_id == "camera_optical_frame"
            np.testing.assert_allclose(c.xyz, [lm[i] for i in c.ids], atol=1e-5)
        elif topic.endswith("keypoints"):
            k = read_keypoints(msg)
            assert set(k.ids) <= set(lm)
    assert order[0] == "/camera/camera_info"  # camera_info comes before its frame
    gt = bag_io.load_ground_truth(path)
    assert len(gt) == 4
    s0 = int(gt.stamps[0])
    assert gt.nearest(s0 + 1000) == s0 and gt.nearest(s0 + 10_000_000) is None
    R = gt.orientation[s0]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
    assert 0.2 < np.linalg.norm(gt.angular_velocity[s0]) < 3


def test_same_content_in_both_storages(small_bags):
    # (compare decoded content: CDR padding bytes are not deterministic)
    ts = bag_io.typestore()
    a = list(bag_io.iter_messages(small_bags["mcap"]))
    b = list(bag_io.iter_messages(small_bags["sqlite3"]))
    assert [(m[0], m[2], len(m[3])) for m in a] == [(m[0], m[2], len(m[3])) for m in b]
    for x, y in zip(a, b, strict=True):
        mx, my = ts.deserialize_cdr(x[3], x[1]), ts.deserialize_cdr(y[3], y[1])
        if x[1] == bag_io.PC2:
            assert bytes(mx.data) == bytes(my.data)
        assert mx.header.stamp == my.header.stamp


def test_make_bag_refuses_to_overwrite(small_bags, capsys):
    assert cli(["make-bag", str(small_bags["mcap"]), "--frames", "1"]) == 2
    assert "exists" in capsys.readouterr().err


def test_replay_offline_with_outputs(small_bags, tmp_path, capsys):
    path = small_bags["mcap"]
    out, csv = tmp_path / "est", tmp_path / "est.csv"
    rc = cli(["replay", str(path), "--out", str(out), "--csv", str(csv), "--quiet", "--json"])
    cap = capsys.readouterr()
    assert rc == 0, cap.out + cap.err
    assert "solved 4/4" in cap.err  # --json: the summary lines go to stderr
    summary = json.loads(cap.out)  # and stdout is only the JSON
    assert summary["frames"] == 4 and summary["solved"] == 4 and summary["failures"] == {}
    assert summary["rot_deg"]["max"] < 0.25 and summary["pos_m"]["max"] < 0.06
    assert summary["angvel"]["max"] < 0.5
    lines = csv.read_text().splitlines()
    assert lines[0].startswith("frame,stamp_ns,out_stamp_ns,solver,success")
    assert len(lines) == 5
    topics = bag_io.bag_topics(out)
    assert topics["/rs_localizer/pose"] == "geometry_msgs/msg/PoseStamped"
    assert topics["/rs_localizer/odom"] == "nav_msgs/msg/Odometry"
    gt = bag_io.load_ground_truth(path)
    est = bag_io.load_ground_truth(out, "/rs_localizer/pose", "/rs_localizer/twist")
    assert list(est.stamps) == list(gt.stamps)  # stamped at the reference row


def test_replay_keypoints_source(small_bags, capsys):
    res = rs_replay.replay(small_bags["sqlite3"], source="keypoints", progress=None)
    assert res.solved == 4 and res.summary["rot_deg"]["max"] < 0.25


def test_replay_with_the_node_parameters(small_bags, tmp_path, capsys):
    """--params-file gives replay the node's parameters (options override them); tracking
    as in the node: twist carries the fused twist, twist_single_frame each frame's own."""
    import csv as csv_module

    from helpers.paths import CONFIG

    path = small_bags["mcap"]
    out, table = tmp_path / "est", tmp_path / "est.csv"
    args = ["replay", str(path), "--params-file", str(CONFIG), "--quiet"]
    assert cli([*args, "--out", str(out), "--csv", str(table)]) == 0
    assert "solved 4/4" in capsys.readouterr().out
    topics = bag_io.bag_topics(out)
    assert topics["/rs_localizer/twist_single_frame"] == "geometry_msgs/msg/TwistStamped"
    rows = list(csv_module.DictReader(table.open()))
    assert len(rows) == 4 and all(r["wx"] and r["single_wx"] for r in rows)
    assert any(r["wx"] != r["single_wx"] for r in rows)  # fused
    assert cli([*args, "--no-tracking", "--csv", str(table), "--seed", "3"]) == 0
    rows = list(csv_module.DictReader(table.open()))
    assert all(r["wx"] == r["single_wx"] for r in rows)  # every frame alone
    # the parameter files decide; the bag's sequence.json fills in the RS timing they leave
    values, _ = rs_replay.replay_parameters(path, [CONFIG], {"solver": "p3p"})
    assert values["solver"] == "p3p" and values["rs.reference_row"] == -1.0
    values, _ = rs_replay.replay_parameters(path)
    assert values["rs.reference_row"] == pytest.approx(359.5)
    assert values["rs.line_delay"] == pytest.approx(30e-6)
    # invalid values are refused as the node refuses them
    capsys.readouterr()
    assert cli([*args, "-p", "ransac.seed:=1.5"]) == 2
    assert "must be of type int" in capsys.readouterr().err
    assert cli([*args, "--param", "solver:=r7p"]) == 2
    assert "unknown solver 'r7p'" in capsys.readouterr().err


def test_play_reaches_a_subscriber(small_bags, ros_context):
    """play publishes every message with original timing (rate 4) into the live graph."""

    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo, PointCloud2

    node = rclpy.create_node("bag_test_listener", context=ros_context)
    got = {"corr": [], "info": []}
    qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    node.create_subscription(
        PointCloud2, "/replayed/correspondences", lambda m: got["corr"].append(m), qos
    )
    node.create_subscription(
        CameraInfo, "/camera/camera_info", lambda m: got["info"].append(m), qos
    )
    with spinning(ros_context, node):
        res = rs_play.play(
            small_bags["mcap"],
            rate=4.0,
            context=ros_context,
            topics=["/camera/correspondences", "/camera/camera_info"],
            remap={"/camera/correspondences": "/replayed/correspondences"},
            wait_subscribers=20.0,
        )
        end = __import__("time").monotonic() + 5
        while len(got["corr"]) < 4 and __import__("time").monotonic() < end:
            __import__("time").sleep(0.02)
    assert res.published == 8 and len(res.frames) == 4
    assert 3 * 33e-3 / 4 * 0.8 < res.wall_time < 2.0  # 4 frames at 30 Hz, 4x faster
    assert len(got["corr"]) == 4 and len(got["info"]) >= 1
    stamps = [m.header.stamp.nanosec for m in got["corr"]]
    assert stamps == sorted(stamps)


def test_header_stamp_shift_roundtrip():
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import PointCloud2

    from rs_localizer.ros.conversions import stamp_to_ns
    from rs_localizer.ros.pointcloud import correspondence_cloud

    raw = serialize_message(
        correspondence_cloud(np.ones((3, 2)), np.ones((3, 3)), stamp=1_700_000_000_999_999_999)
    )
    assert rs_play._header_stamp(raw) == 1_700_000_000_999_999_999
    shifted = rs_play._shift_stamp(raw, bag_io.PC2, 2)
    assert (
        stamp_to_ns(deserialize_message(shifted, PointCloud2).header.stamp)
        == 1_700_000_001_000_000_001
    )


def test_replay_warns_when_the_video_contradicts_the_rolling_shutter_timing(capsys):
    """``data/sample`` (30 frames) replayed with its own line delay: no warning; with twice
    that line delay the frames' twists do not predict the video, and replay says what to
    check."""
    from helpers.paths import SAMPLE_BAG as SAMPLE

    assert cli(["replay", str(SAMPLE), "--quiet"]) == 0
    assert "does not predict the video" not in capsys.readouterr().err
    assert cli(["replay", str(SAMPLE), "--quiet", "--line-delay", "6e-5"]) == 0
    err = capsys.readouterr().err
    assert "warning: the frames' rolling-shutter motion does not predict the video" in err
    assert "check rs.line_delay" in err
