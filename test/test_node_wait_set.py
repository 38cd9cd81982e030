"""What the node adds to the executor's wait set, which rclpy rebuilds in Python twice for every
message it takes: the outputs' publishers add no QoS event handlers (a subscriber with
incompatible QoS reports it on its own side), the subscriptions keep rclpy's default ones."""

from __future__ import annotations

import time

import pytest

pytest.importorskip("rclpy")


def _params(**extra):
    from rclpy.parameter import Parameter

    values = {"warmup": False, "publish_tf": False, **extra}
    return [Parameter(k, value=v) for k, v in values.items()]


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
    from rs_localizer.ros.lifecycle import RSLocalizerLifecycleNode
    from rs_localizer.ros.node import RSLocalizerNode

    if lifecycle:
        node = RSLocalizerLifecycleNode(
            "wait_set_lc", context=ros_context, namespace="/ws", parameter_overrides=_params()
        )
        node.trigger_configure()
        node.trigger_activate()  # (the frame subscriptions)
    else:
        node = RSLocalizerNode(
            "wait_set", context=ros_context, namespace="/ws", parameter_overrides=_params()
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
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor

    from rs_localizer.ros.node import RSLocalizerNode

    node = RSLocalizerNode(
        "wait_set_out",
        context=ros_context,
        namespace="/ws_out",
        parameter_overrides=_params(diagnostics_period=0.1),
    )
    probe = rclpy.create_node("wait_set_probe", context=ros_context)
    got = []
    probe.create_subscription(
        DiagnosticArray,
        "/diagnostics",
        lambda m: got.extend(s for s in m.status if "ws_out" in s.name),
        10,
    )
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    ex.add_node(probe)
    try:
        deadline = time.monotonic() + 20
        while not got and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.1)
    finally:
        ex.shutdown()
        probe.destroy_node()
        node.destroy_node()
    assert got, "no /diagnostics from the node"
