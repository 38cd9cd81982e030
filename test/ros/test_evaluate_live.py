"""``rs-localizer evaluate --live``: the poses and the ground truth published while it listens
are captured (types from the publishers: PoseWithCovarianceStamped and PoseStamped) and
evaluated; the known offset and covariance of the published poses come back."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

pytest.importorskip("rclpy")


def test_live_capture_of_a_pose_topic_and_the_ground_truth(ros_context):
    import rclpy
    from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped

    from rs_localizer.pose import PoseWithCovariance, RSPose
    from rs_localizer.ros import conversions as cv
    from rs_localizer.ros.bags.evaluate import capture_live, evaluate_trajectory
    from rs_localizer.ros.qos import RELIABLE

    node = rclpy.create_node("fake_localizer", context=ros_context)
    est_pub = node.create_publisher(
        PoseWithCovarianceStamped, "/evt/pose_with_covariance", RELIABLE
    )
    gt_pub = node.create_publisher(PoseStamped, "/ground_truth/pose", RELIABLE)
    C = np.diag([1e-4] * 3 + [1e-6] * 3)  # (1 cm, 1 mrad)
    stop = threading.Event()

    def publish():
        k = 0
        while not stop.is_set():
            stamp = 1_000_000_000 + k * 20_000_000
            R = cv.matrix_from_quaternion([0.0, 0.0, np.sin(0.01 * k), np.cos(0.01 * k)])
            p = np.array([0.1 * k, 0.0, 1.0])
            zero = np.zeros(3)
            gt_pub.publish(cv.pose_stamped(RSPose(R, p, zero, zero), stamp, "map"))
            est = PoseWithCovariance(
                pose=RSPose(R, p + [0.0, 0.005, 0.0], zero, zero),  # (5 mm off: 0.5 sigma)
                pose_covariance=C,
                twist_covariance=None,
            )
            est_pub.publish(cv.pose_with_covariance_stamped(est, stamp, "map"))
            k += 1
            time.sleep(0.02)

    t = threading.Thread(target=publish, daemon=True)
    t.start()
    try:
        est, truth = capture_live(
            "/evt/pose_with_covariance", 1.5, "/ground_truth/pose", context=ros_context
        )
    finally:
        stop.set()
        t.join()
        node.destroy_node()
    assert len(est) >= 20 and truth is not None and len(truth) >= 20
    assert est.covariance is not None and np.allclose(est.covariance[0], C)
    res = evaluate_trajectory(est, truth)
    assert res["matched"] >= 20
    assert res["ape"]["pos_m"]["max"] == pytest.approx(0.005, abs=1e-9)
    assert res["ape"]["rot_deg"]["max"] < 1e-5
    assert res["covariance"]["within_3_sigma"] == res["matched"]
    with pytest.raises(TimeoutError, match="no publisher"):
        capture_live("/nobody/pose", 0.1, context=ros_context, wait=0.5)
