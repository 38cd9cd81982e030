"""What the node adds to the executor's wait set, which rclpy rebuilds in Python twice for every
message it takes: the outputs' publishers add no QoS event handlers (a subscriber with
incompatible QoS reports it on its own side), the subscriptions keep rclpy's default ones."""

from __future__ import annotations

import pytest

pytest.importorskip("rclpy")


def _event_owners(node) -> list[str]:
    """``subscription`` or ``publisher`` for each QoS event handler among the node's
    waitables (the only waitables the node creates)."""
    from rclpy.event_handler import EventHandler

    owners = []
    for w in node.waitables:
        assert isinstance(w, EventHandler), type(w)
        owners.append(type(w.event_type).__name__.split("_")[1])  # rcl_<owner>_event_type_t
    return owners


@pytest.mark.parametrize("lifecycle", [False, True])
def test_publishers_add_no_event_handlers(ros_context, lifecycle):
    from helpers.ros import in_process_parameters

    from rs_localizer.ros.lifecycle import RSLocalizerLifecycleNode
    from rs_localizer.ros.node import RSLocalizerNode

    if lifecycle:
        node = RSLocalizerLifecycleNode(
            "wait_set_lc",
            context=ros_context,
            namespace="/ws",
            parameter_overrides=in_process_parameters({}),
        )
        node.trigger_configure()
        node.trigger_activate()  # (the frame subscriptions)
    else:
        node = RSLocalizerNode(
            "wait_set",
            context=ros_context,
            namespace="/ws",
            parameter_overrides=in_process_parameters({}),
        )
    try:
        topics = {p.topic_name for p in node.publishers}
        outputs = {"pose", "twist", "odom", "pose_with_covariance", "twist_single_frame"}
        viz = {"debug_image", "markers", "path"}
        assert {f"/ws/{t}" for t in outputs | viz} | {"/diagnostics"} <= topics, topics
        owners = _event_owners(node)
        # (rclpy's own /parameter_events publisher keeps its two handlers)
        assert "/parameter_events" in topics
        assert owners.count("publisher") == 2, owners
        # the frame and camera_info subscriptions keep rclpy's defaults (+ message_lost)
        assert owners.count("subscription") >= 2 * 3, owners
    finally:
        node.destroy_node()


def test_outputs_reach_a_default_subscriber(ros_context):
    """Without the publishers' event handlers the outputs still go out: a subscriber with
    rclpy's default QoS (reliable, volatile) receives ``/diagnostics``."""
    from helpers.ros import diagnostics_in_process

    assert diagnostics_in_process(ros_context, "wait_set_out", {}), "no /diagnostics from the node"


def test_one_executor_turn_takes_every_waiting_frame(ros_context):
    """A frame subscription's callback takes every message already waiting in the readers of
    the node's frame subscriptions (correspondences and keypoints here), so that a few
    executor turns count a whole burst ``received`` (the frame queue then drops and
    counts what it cannot hold): an executor taking one message per turn, each turn rebuilding
    its wait set in Python and waiting for the GIL while the worker runs Python, falls behind a
    stream and the reader's history overwrites frames the node never counts."""
    import time

    import numpy as np
    import rclpy
    from helpers.ros import in_process_parameters
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2

    from rs_localizer.ros.node import RSLocalizerNode
    from rs_localizer.ros.pointcloud import correspondence_cloud, keypoint_cloud

    node = RSLocalizerNode(
        "take_all",
        context=ros_context,
        namespace="/take_all",
        parameter_overrides=in_process_parameters({"queue_size": 3}),
    )
    source = rclpy.create_node("take_all_source", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    try:
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        pub = source.create_publisher(PointCloud2, "/take_all/correspondences", qos)
        pub_kp = source.create_publisher(PointCloud2, "/take_all/keypoints", qos)
        deadline = time.monotonic() + 20
        while min(p.get_subscription_count() for p in (pub, pub_kp)) < 1:
            assert time.monotonic() < deadline, "the node's frame subscriptions not matched"
            time.sleep(0.05)
        rng = np.random.default_rng(0)
        n = 40  # (3 points each: failed at once, too few to solve; keypoints without landmarks)
        for k in range(n // 2):
            stamp = 1_000_000_000 + k * 10_000_000
            pub.publish(correspondence_cloud(rng.random((3, 2)), rng.random((3, 3)), stamp=stamp))
            pub_kp.publish(keypoint_cloud(rng.random((3, 2)), np.arange(3), stamp=stamp + 1))
        time.sleep(1.0)  # (delivered to the reader before the executor's first turn)
        counts = node.camera_counts[""]
        for _ in range(4):  # (the timers may take a turn or two)
            ex.spin_once(timeout_sec=1.0)
        taken = counts.counts()
        assert taken["received"] == n, taken
        deadline = time.monotonic() + 20
        while node._frames.pending and time.monotonic() < deadline:
            time.sleep(0.05)
        done = counts.counts()
        outcomes = sum(v for k, v in done.items() if k == "solved" or "." in k)
        assert done["received"] == outcomes == n, done
    finally:
        ex.shutdown()
        source.destroy_node()
        node.destroy_node()
