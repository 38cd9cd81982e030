"""A bare subscriber in its own process, the reference of a load test: it subscribes one
``sensor_msgs/PointCloud2`` topic with the QoS a node under test is given (reliable, keep
last ``depth``) and does nothing in its callback but note the message's stamp, so what it
misses is what the machine's load and the middleware lose, not what a callback holding the
executor does.

Run as ``python count_messages.py TOPIC DEPTH OUT``: prints ``ready`` once subscribed, and on
SIGTERM or SIGINT writes the stamps received (ns, one per line) to ``OUT`` and exits.
:func:`count_in` counts the stamps of a range."""

from __future__ import annotations

import signal
import sys
from pathlib import Path


def count_in(path: str | Path, first_ns: int, last_ns: int) -> int:
    """The stamps in ``path`` (written by this script) within ``[first_ns, last_ns]``."""
    stamps = [int(s) for s in Path(path).read_text().split()]
    return sum(first_ns <= s <= last_ns for s in stamps)


def main(topic: str, depth: int, out: str) -> None:
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2

    stamps: list[int] = []
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = rclpy.create_node("rs_localizer_test_count_messages")
    qos = QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE)
    node.create_subscription(
        PointCloud2,
        topic,
        lambda m: stamps.append(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec),
        qos,
    )
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    print("ready", flush=True)
    try:
        while not stop:
            ex.spin_once(timeout_sec=0.05)
    except ExternalShutdownException:
        pass
    Path(out).write_text("".join(f"{s}\n" for s in stamps))
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), sys.argv[3])
