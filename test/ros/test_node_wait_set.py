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
