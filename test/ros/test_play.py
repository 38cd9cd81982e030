"""``rs-localizer play``: which frame topic it plays, and each IMU message sent once.

A responder node stands in for the localizer: it answers every frame with a pose of the same
stamp and records what arrived."""

import threading
import time

import pytest

from rs_localizer.cli import main as cli
from rs_localizer.ros.bags.bag_io import CAMERA_INFO, COMPRESSED_IMAGE, IMAGE, PC2
from rs_localizer.ros.bags.play import choose_frame_topics, is_frame_topic


def test_choose_frame_topics():
    """One frame topic per camera namespace: an image the node subscribes, else the
    correspondences, else an image, else the keypoints."""
    bag = {
        "/cam/correspondences": PC2,
        "/cam/keypoints": PC2,
        "/cam/image_raw": IMAGE,
        "/other/keypoints": PC2,
        "/other/image/compressed": COMPRESSED_IMAGE,
    }
    kept, skipped = choose_frame_topics(bag, subscribed=set())
    assert sorted(kept) == ["/cam/correspondences", "/other/image/compressed"]
    assert sorted(skipped) == ["/cam/image_raw", "/cam/keypoints", "/other/keypoints"]
    kept, _ = choose_frame_topics(bag, subscribed={"/cam/image_raw", "/cam/correspondences"})
    assert "/cam/image_raw" in kept
    kept, skipped = choose_frame_topics({"/cam/keypoints": PC2}, set())
    assert kept == ["/cam/keypoints"] and skipped == []
    assert is_frame_topic("/c/image/compressed", COMPRESSED_IMAGE)
    assert not is_frame_topic("/c/camera_info", CAMERA_INFO)


@pytest.fixture(scope="module")
def imu_bag(tmp_path_factory):
    path = tmp_path_factory.mktemp("play") / "bag"
    args = ["make-bag", str(path), "--frames", "5", "--points", "150", "--imu-rate", "200"]
    assert cli(args + ["--seed", "3"]) == 0
    return path


def test_lockstep_plays_one_frame_topic_and_each_imu_sample_once(imu_bag, ros_context):
    import rclpy
    from geometry_msgs.msg import PoseStamped
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Imu, PointCloud2

    from rs_localizer.ros.bags.bag_io import iter_messages

    node = rclpy.create_node("play_test_responder", context=ros_context)
    qos = QoSProfile(depth=500, reliability=ReliabilityPolicy.RELIABLE)
    pose = node.create_publisher(PoseStamped, "/camera/pose", qos)
    got = {"correspondences": [], "keypoints": [], "imu": []}

    def on_frame(kind):
        def cb(msg):
            got[kind].append(msg.header.stamp)
            pose.publish(PoseStamped(header=msg.header))

        return cb

    for kind in ("correspondences", "keypoints"):
        node.create_subscription(PointCloud2, f"/camera/{kind}", on_frame(kind), qos)
    node.create_subscription(
        Imu,
        "/imu/data",
        lambda m: got["imu"].append((m.header.stamp.sec, m.header.stamp.nanosec)),
        qos,
    )
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    stop = threading.Event()
    th = threading.Thread(
        target=lambda: [ex.spin_once(timeout_sec=0.02) for _ in iter(stop.is_set, True)]
    )
    th.start()
    notes = []
    try:
        from rs_localizer.ros.bags.play import play

        res = play(
            imu_bag, lockstep=True, context=ros_context, wait_subscribers=20.0, log=notes.append
        )
        time.sleep(0.3)
    finally:
        stop.set()
        th.join()
        ex.remove_node(node)
        node.destroy_node()
        ex.shutdown()
    assert res.answered == len(res.frames) == 5 and res.timeouts == 0
    assert res.skipped_topics == ["/camera/keypoints"]
    assert got["keypoints"] == [] and len(got["correspondences"]) == 5
    assert any("--topics" in n and "/camera/keypoints" in n for n in notes)
    n_imu = sum(1 for m in iter_messages(imu_bag, None) if m[0] == "/imu/data")
    assert len(got["imu"]) == n_imu > 0  # each sample once, none primed or republished
    assert len(set(got["imu"])) == n_imu
