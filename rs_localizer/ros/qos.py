"""Quality of service of the node: the profiles of its subscriptions and publications, and the
QoS events its publishers watch (none).

Frame subscriptions use the sensor-data QoS (best effort) with a deeper history than its 5:
frames that arrive while the executor waits for the CPU or the GIL (the worker's Python
between its compiled kernels) wait in the middleware until the callbacks move them to the
node's queue (each callback takes every frame waiting on the frame subscriptions:
:meth:`~rs_localizer.ros.core.NodeCore._take_frames`), where a drop is counted
(``frames_skipped``), instead of being overwritten unseen. Images keep 10 (they are big), IMU
samples 200 (about 1 s at 200 Hz). The outputs are reliable with a history of 10;
``debug_image`` keeps 2.
"""

from __future__ import annotations

from rclpy.event_handler import PublisherEventCallbacks
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

__all__ = ["CLOUD_QOS", "DEBUG_IMAGE_QOS", "IMAGE_QOS", "IMU_QOS", "RELIABLE", "output_events"]

CLOUD_QOS, IMAGE_QOS, IMU_QOS = (
    QoSProfile(
        depth=depth,
        reliability=qos_profile_sensor_data.reliability,
        durability=qos_profile_sensor_data.durability,
        history=qos_profile_sensor_data.history,
    )
    for depth in (100, 10, 200)
)
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
DEBUG_IMAGE_QOS = QoSProfile(depth=2, reliability=ReliabilityPolicy.RELIABLE)


def output_events() -> PublisherEventCallbacks:
    """The QoS event callbacks of an output publisher: none.

    rclpy gives every publisher two default event handlers (a new subscriber with incompatible
    QoS, or with an incompatible type: a warning in the log). Each is a waitable that rclpy's
    executor adds to its wait set in Python, and it rebuilds the wait set at least twice for
    every message it takes, over the waitables of every camera node in the process. The
    node's ten publishers had 20 of its 28 waitables; the executor thread runs on the core that
    solves. A subscriber whose QoS does not match an output is reported on its own side: rclpy
    and rclcpp subscriptions log "offering incompatible QoS" by default. The node's
    subscriptions keep their default handlers.
    """
    return PublisherEventCallbacks(use_default_callbacks=False)
