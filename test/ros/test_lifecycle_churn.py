"""The lifecycle node taken through configure / activate / deactivate / cleanup 20 times in
this process while correspondence frames stream: the frame accounting adds up in every cycle
(received = solved + failed + skipped + pending, nothing pending after deactivate), frames are
solved while active, and the process's threads and memory do not grow with the cycles."""

from __future__ import annotations

import threading
import time

import pytest

pytest.importorskip("rclpy")

pytestmark = pytest.mark.slow  # (20 cycles, frames solved in each)


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096 / 2**20


def test_lifecycle_churn_while_frames_stream(ros_context, sample_bag):
    import rclpy
    from helpers.ros import in_process_parameters
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.lifecycle import TransitionCallbackReturn
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import CameraInfo, PointCloud2

    from rs_localizer.ros.bags.bag_io import iter_messages
    from rs_localizer.ros.frame_queue import frame_accounting
    from rs_localizer.ros.lifecycle import RSLocalizerLifecycleNode

    OK = TransitionCallbackReturn.SUCCESS
    clouds, info = [], None
    for topic, _, _, raw in iter_messages(
        sample_bag, {"/camera/correspondences", "/camera/camera_info"}
    ):
        if topic.endswith("camera_info") and info is None:
            info = deserialize_message(raw, CameraInfo)
        elif topic.endswith("correspondences") and len(clouds) < 40:
            clouds.append(deserialize_message(raw, PointCloud2))
    node = RSLocalizerLifecycleNode(
        "rs_localizer",
        context=ros_context,
        namespace="/churn",
        parameter_overrides=in_process_parameters({"diagnostics_period": 0.2}),
    )
    src = rclpy.create_node("churn_source", context=ros_context)
    pub_info = src.create_publisher(CameraInfo, "/churn/camera_info", 10)
    pub_corr = src.create_publisher(PointCloud2, "/churn/correspondences", 10)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    ex.add_node(src)
    threads, rss, solved = [], [], []
    k = 0
    try:
        for cycle in range(20):
            assert node.trigger_configure() == OK
            assert node.trigger_activate() == OK
            t_end = time.monotonic() + 1.0
            while time.monotonic() < t_end:  # (frames stream: ~30 Hz)
                pub_info.publish(info)
                pub_corr.publish(clouds[k % len(clouds)])
                k += 1
                ex.spin_once(timeout_sec=0.03)
            assert node.trigger_deactivate() == OK
            c = frame_accounting(node.camera_counts[""].counts())
            assert c.received == c.solved + c.failed + c.skipped + c.pending, (cycle, c)
            assert c.pending == 0, (cycle, c)
            solved.append(c.solved)
            assert node.trigger_cleanup() == OK
            for _ in range(5):
                ex.spin_once(timeout_sec=0.01)
            threads.append(threading.active_count())
            rss.append(_rss_mb())
    finally:
        ex.shutdown()
        node.destroy_node()
        src.destroy_node()
    assert min(solved) > 0, solved  # (every active phase solved frames)
    assert max(threads[5:]) <= threads[4], threads  # (no thread left behind per cycle)
    assert rss[-1] - rss[4] < 40.0, rss  # MB over 15 cycles (no map or pipeline kept)
