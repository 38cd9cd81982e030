"""A live view of a localizer without a ROS install: the node's outputs served to the Foxglove
app over the Foxglove SDK's WebSocket server (``rs-localizer view``).

The ROS 2 messages are forwarded as they arrive, serialized (CDR) with their ``ros2msg``
schema (the message definitions of rosbags' Jazzy type store, as in a rosbag2 MCAP file), so
Foxglove decodes them as from ``foxglove_bridge``. A ROS topic is subscribed only while a
Foxglove client subscribes its channel: the node draws ``debug_image``, ``markers`` and
``path`` only while someone watches.

Channel names: the outputs ``NS/<name>`` (:data:`OUTPUT_TOPICS`) are served as
``CHANNEL_NS/<name>``, by default :data:`LAYOUT_NS` (``/camera``, the namespace the shipped
layout ``foxglove/rs_localizer.json`` names), so one layout serves a node in any namespace and
the bag of ``rs-localizer replay --out BAG --debug-outputs`` (``/rs_localizer/<name>``, played
with ``rs-localizer play``) alike; ``/diagnostics``, ``/tf`` and ``/tf_static`` keep their names.
"""

from __future__ import annotations

import functools
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

__all__ = [
    "GLOBAL_TOPICS",
    "LAYOUT_NS",
    "OUTPUT_TOPICS",
    "ServedTopic",
    "ViewServer",
    "foxglove_available",
    "localizer_namespaces",
    "ros2msg_schema",
    "serve",
    "served_topics",
]

#: the namespace the shipped Foxglove layout names (the launch file's default)
LAYOUT_NS = "/camera"

#: the localizer's outputs the view serves: name (relative to the node's namespace) -> type
OUTPUT_TOPICS = {
    "pose": "geometry_msgs/msg/PoseStamped",
    "path": "nav_msgs/msg/Path",
    "markers": "visualization_msgs/msg/MarkerArray",
    "debug_image": "sensor_msgs/msg/Image",
    "odom": "nav_msgs/msg/Odometry",
    "twist": "geometry_msgs/msg/TwistStamped",
    "twist_single_frame": "geometry_msgs/msg/TwistStamped",
    "pose_with_covariance": "geometry_msgs/msg/PoseWithCovarianceStamped",
}

#: absolute topics the view serves under their own names (``/tf*`` when ``tf2_msgs`` imports)
GLOBAL_TOPICS = {
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/tf_static": "tf2_msgs/msg/TFMessage",
}

#: history of a forwarding subscription (images: 2, as the node's publisher)
_DEPTH = {"debug_image": 2}


def foxglove_available() -> bool:
    """Whether the Foxglove SDK (``pip install foxglove-sdk``, the ``view`` extra) imports.
    (A checkout's ``foxglove/`` layout directory on ``sys.path`` imports as an empty namespace
    package: that is not the SDK.)"""
    try:
        import foxglove
    except ImportError:
        return False
    return hasattr(foxglove, "start_server")


def _join(ns: str, name: str) -> str:
    return f"{ns.rstrip('/')}/{name}"


def _normalize_ns(ns: str) -> str:
    """``camera`` / ``/camera/`` -> ``/camera``; ``/`` and ``""`` -> ``""`` (the root)."""
    ns = ns.strip().strip("/")
    return f"/{ns}" if ns else ""


def _msg_class(type_name: str) -> Any:
    """``pkg/msg/Type`` -> the rclpy message class. Raises ImportError when not installed."""
    import importlib

    pkg, _, typ = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), typ)


@dataclass
class ServedTopic:
    """One ROS topic the view forwards: its name, the Foxglove channel's name, its type, and
    the ROS subscription's history and durability."""

    ros_topic: str
    channel_topic: str
    type_name: str
    depth: int = 10
    transient_local: bool = False
    received: int = field(default=0, compare=False)


def served_topics(
    ns: str = LAYOUT_NS, channel_ns: str | None = LAYOUT_NS, with_tf: bool = True
) -> list[ServedTopic]:
    """The topics :class:`ViewServer` serves for a node in namespace ``ns``: the outputs
    ``ns/<name>`` as channels ``channel_ns/<name>`` (``channel_ns`` None: their ROS names),
    then ``/diagnostics`` and, with ``with_tf``, ``/tf`` and ``/tf_static``."""
    ns = _normalize_ns(ns)
    chan = ns if channel_ns is None else _normalize_ns(channel_ns)
    out = [
        ServedTopic(_join(ns, name), _join(chan, name), t, depth=_DEPTH.get(name, 10))
        for name, t in OUTPUT_TOPICS.items()
    ]
    for topic, t in GLOBAL_TOPICS.items():
        if topic.startswith("/tf") and not with_tf:
            continue
        out.append(ServedTopic(topic, topic, t, transient_local=topic == "/tf_static"))
    return out


@functools.lru_cache(maxsize=1)
def _typestore() -> Any:
    from .bags.bag_io import typestore

    return typestore()


def ros2msg_schema(type_name: str) -> bytes:
    """The ``ros2msg`` schema of ``type_name`` (``pkg/msg/Type``): its definition followed by
    those of the messages it uses, as rosbag2 writes them into MCAP files and Foxglove reads
    them. Raises KeyError for a type rosbags' Jazzy type store does not know."""
    text, _ = _typestore().generate_msgdef(type_name, ros_version=2)
    return text.encode()


def localizer_namespaces(topics_and_types: list[tuple[str, list[str]]]) -> list[str]:
    """The namespaces with a ``pose`` topic of type PoseStamped in a graph's
    ``get_topic_names_and_types()``: where localizer outputs are (``/`` for the root)."""
    out = []
    for topic, types in topics_and_types:
        if topic.endswith("/pose") and OUTPUT_TOPICS["pose"] in types:
            out.append(topic[: -len("/pose")] or "/")
    return sorted(out)


class _Listener:
    """The WebSocket server's listener: hands (channel id, +1/-1) to the ROS thread."""

    def __init__(self, on_change: Callable[[int, int], None]):
        self.on_change = on_change

    def on_subscribe(self, client: Any, channel: Any) -> None:
        self.on_change(channel.id, +1)

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        self.on_change(channel.id, -1)


class ViewServer:
    """The Foxglove WebSocket server forwarding a localizer's outputs (see the module doc).

    Args:
        context: the rclpy Context (initialized) of the forwarding node.
        ns: the localizer's namespace (``/camera``; ``/rs_localizer`` for a replay bag played
            with ``rs-localizer play``).
        port: the TCP port (0: a free one, :attr:`port` tells which).
        host: the address to bind (``127.0.0.1``: this machine only; ``0.0.0.0``: every
            interface).
        channel_ns: the namespace of the outputs' channels (default :data:`LAYOUT_NS`, the
            layout's; None: their ROS names).
        log: where a line about the clients' subscriptions and the first message of each
            topic goes (None: nowhere).

    Raises:
        ImportError: the Foxglove SDK is not installed.
        RuntimeError: the server could not start (e.g. the port is in use).

    ``start()`` starts the server and the ROS thread, ``close()`` stops both; a context
    manager does both.
    """

    def __init__(
        self,
        context: Any,
        ns: str = LAYOUT_NS,
        port: int = 8765,
        host: str = "127.0.0.1",
        channel_ns: str | None = LAYOUT_NS,
        log: Callable[[str], None] | None = None,
    ):
        import foxglove

        self.context, self.ns, self.host, self._port = context, _normalize_ns(ns), host, port
        self.log = log or (lambda _line: None)
        try:
            _msg_class(GLOBAL_TOPICS["/tf"])
            with_tf = True
        except ImportError:  # (tf2_msgs is not among the PyPI wheels: make tf2-msgs)
            with_tf = False
        self.topics = served_topics(self.ns, channel_ns, with_tf)
        self.fox_context = foxglove.Context()
        self.channels: dict[int, tuple[Any, ServedTopic]] = {}
        for t in self.topics:
            schema = foxglove.Schema(
                name=t.type_name, encoding="ros2msg", data=ros2msg_schema(t.type_name)
            )
            ch = foxglove.Channel(
                t.channel_topic, schema=schema, message_encoding="cdr", context=self.fox_context
            )
            self.channels[ch.id()] = (ch, t)
        self._changes: queue.SimpleQueue[tuple[int, int]] = queue.SimpleQueue()
        self._subscribers: dict[int, int] = {}  # channel id -> clients subscribed
        self._subs: dict[int, Any] = {}  # channel id -> rclpy subscription
        self._best_effort: set[int] = set()  # channels received best effort
        self.server = None
        self.node = None
        self._wake = None  # the guard condition waking the ROS thread
        self._thread = None
        self._stop = threading.Event()

    @property
    def port(self) -> int:
        """The port the server listens on (after :meth:`start`)."""
        return self.server.port if self.server is not None else self._port

    @property
    def url(self) -> str:
        """``ws://HOST:PORT``, what the Foxglove app opens."""
        host = "localhost" if self.host in ("127.0.0.1", "0.0.0.0") else self.host
        return f"ws://{host}:{self.port}"

    def start(self) -> ViewServer:
        """Create the forwarding node, start its thread and the WebSocket server."""
        import foxglove
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.node = rclpy.create_node("rs_localizer_view", context=self.context)
        self._wake = self.node.create_guard_condition(self._apply_changes)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, name="rs_localizer_view", daemon=True)
        self._thread.start()
        try:
            self.server = foxglove.start_server(
                name="rs_localizer",
                host=self.host,
                port=self._port,
                server_listener=_Listener(self._request),
                context=self.fox_context,
            )
        except Exception as e:
            self.close()
            raise RuntimeError(f"cannot serve on {self.host}:{self._port}: {e}") from e
        return self

    def __enter__(self) -> ViewServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _spin(self) -> None:
        while not self._stop.is_set() and self.context.ok():
            self.executor.spin_once(timeout_sec=0.1)

    def _request(self, channel_id: int, delta: int) -> None:
        """(a server thread) a client (un)subscribed a channel: the ROS thread applies it."""
        self._changes.put((channel_id, delta))
        wake = self._wake
        if wake is not None:
            wake.trigger()

    def _apply_changes(self) -> None:
        """(the ROS thread) create the ROS subscription of a channel a first client
        subscribed, destroy that of a channel the last client left."""
        while True:
            try:
                cid, delta = self._changes.get_nowait()
            except queue.Empty:
                return
            if cid not in self.channels:
                continue
            ch, t = self.channels[cid]
            if delta == 0:  # a best-effort publisher appeared: resubscribe best effort
                if cid in self._subs and cid not in self._best_effort:
                    self._best_effort.add(cid)
                    self.node.destroy_subscription(self._subs.pop(cid))
                    self._subs[cid] = self._subscribe(ch, t)
                    self.log(f"{t.ros_topic}: a best-effort publisher, received best effort")
                continue
            n = max(self._subscribers.get(cid, 0) + delta, 0)
            self._subscribers[cid] = n
            if n > 0 and cid not in self._subs:
                self._subs[cid] = self._subscribe(ch, t)
                self.log(f"serving {t.channel_topic} (ROS topic {t.ros_topic})")
            elif n <= 0 and cid in self._subs:
                self.node.destroy_subscription(self._subs.pop(cid))
                self.log(f"stopped {t.channel_topic} (no client)")

    def _subscribe(self, ch: Any, t: ServedTopic) -> Any:
        from rclpy.event_handler import SubscriptionEventCallbacks
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

        # reliable unless a publisher is best effort (a reliable reader misses those); one
        # appearing later is reported as incompatible: then resubscribe best effort
        cid = ch.id()
        infos = self.node.get_publishers_info_by_topic(t.ros_topic)
        best_effort = cid in self._best_effort or any(
            i.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for i in infos
        )
        if best_effort:
            self._best_effort.add(cid)
        events = SubscriptionEventCallbacks(incompatible_qos=lambda _event: self._request(cid, 0))
        qos = QoSProfile(
            depth=t.depth,
            reliability=ReliabilityPolicy.BEST_EFFORT
            if best_effort
            else ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL
            if t.transient_local
            else DurabilityPolicy.VOLATILE,
        )

        def forward(data: bytes) -> None:
            if t.received == 0:
                self.log(f"first message on {t.ros_topic}")
            t.received += 1
            ch.log(data)

        return self.node.create_subscription(
            _msg_class(t.type_name), t.ros_topic, forward, qos, event_callbacks=events, raw=True
        )

    def missing_outputs(self) -> str | None:
        """A line when no output arrived and nothing publishes the localizer's pose in
        :attr:`ns` (naming the namespaces where a pose is published: the ``--ns`` to pass);
        None otherwise."""
        pose = _join(self.ns, "pose")
        if self.node is None or any(t.received for t in self.topics[: len(OUTPUT_TOPICS)]):
            return None
        found = localizer_namespaces(self.node.get_topic_names_and_types())
        if self.node.count_publishers(pose) or (self.ns or "/") in found:
            return None
        if not found:
            return f"nothing publishes {pose} yet (is the node running, in this ROS_DOMAIN_ID?)"
        return (
            f"nothing publishes {pose} yet; a localizer's pose is published in "
            + ", ".join(found)
            + f" (rs-localizer view --ns {found[0]})"
        )

    def close(self) -> None:
        """Stop the server and the ROS thread, destroy the node (idempotent)."""
        if self.server is not None:
            self.server.stop()
            self.server = None
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        if self.node is not None:
            self._wake = None
            self.executor.remove_node(self.node)
            self.executor.shutdown()
            self.node.destroy_node()
            self.node = None
        for ch, _ in self.channels.values():
            ch.close()


def serve(
    ns: str = LAYOUT_NS,
    port: int = 8765,
    host: str = "127.0.0.1",
    channel_ns: str | None = LAYOUT_NS,
    duration: float | None = None,
    log: Callable[[str], None] = print,
) -> None:
    """``rs-localizer view``: a :class:`ViewServer` in a new rclpy context (``ROS_DOMAIN_ID``
    from the environment) until Ctrl-C or ``duration`` s; ``log`` gets where to connect, the
    clients' subscriptions, and after 3 s :meth:`ViewServer.missing_outputs` if any.

    Raises:
        ImportError: the Foxglove SDK is not installed.
        RuntimeError: the server could not start (e.g. the port is in use).
    """
    import rclpy

    context = rclpy.Context()
    rclpy.init(args=[], context=context)
    try:
        server = ViewServer(context, ns, port, host, channel_ns, log).start()
        try:
            first = server.topics[0]
            names = (
                f"layout foxglove/rs_localizer.json ({first.ros_topic} as "
                f"{first.channel_topic}, ...)"
                if first.channel_topic == _join(LAYOUT_NS, "pose")
                else f"channels under their ROS names ({first.channel_topic}, ...; the layout "
                f"foxglove/rs_localizer.json shows {LAYOUT_NS}/...)"
            )
            log(
                f"serving {server.ns or '/'} on {server.url}: in Foxglove, Open connection, "
                f"Foxglove WebSocket, {server.url}; {names}. Ctrl-C stops."
            )
            start, hinted = time.monotonic(), False
            while duration is None or time.monotonic() - start < duration:
                time.sleep(0.2)
                if not hinted and time.monotonic() - start > 3.0:
                    hinted = True
                    hint = server.missing_outputs()
                    if hint:
                        log(hint)
        except KeyboardInterrupt:
            pass
        finally:
            server.close()
    finally:
        rclpy.try_shutdown(context=context)
