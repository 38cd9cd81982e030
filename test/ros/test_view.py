"""``rs-localizer view`` (the Foxglove WebSocket server forwarding a node's outputs) and
``rs-localizer diagnostics`` (``/diagnostics`` printed live).

A publisher stands in for the node; a minimal Foxglove WebSocket client (the protocol the
Foxglove app speaks, ``helpers.foxglove_ws``) subscribes the server's channels and decodes what
arrives with rclpy, compared with what was published."""

from __future__ import annotations

import threading
import time

import pytest

from rs_localizer.cli import main as cli
from rs_localizer.ros.echo import format_status, status_in_ns


def _need_foxglove():
    from rs_localizer.ros.view import foxglove_available

    if not foxglove_available():
        pytest.skip("foxglove-sdk not installed (the 'view' extra)")


class _Publisher:
    """A node publishing ``msgs`` ({topic: message}) every 50 ms on its own thread."""

    def __init__(self, ros_context, msgs, qos=10):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.node = rclpy.create_node("view_test_publisher", context=ros_context)
        self.pubs = [
            (self.node.create_publisher(type(m), topic, qos), m) for topic, m in msgs.items()
        ]
        self.ex = SingleThreadedExecutor(context=ros_context)
        self.ex.add_node(self.node)
        self.stop = threading.Event()
        self.th = threading.Thread(target=self._run)
        self.th.start()

    def _run(self):
        while not self.stop.is_set():
            for pub, m in self.pubs:
                pub.publish(m)
            self.ex.spin_once(timeout_sec=0.05)

    def close(self):
        self.stop.set()
        self.th.join()
        self.ex.remove_node(self.node)
        self.ex.shutdown()
        self.node.destroy_node()


def _diagnostics(name, level=1, values=(("frames_received", "12"), ("latency_ms_median", "3.5"))):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    st = DiagnosticStatus(name=name, message="1 frame failed", hardware_id="camera")
    st.level = bytes([level])
    st.values = [KeyValue(key=k, value=v) for k, v in values]
    return DiagnosticArray(status=[st])


def _wait(pred, timeout, poll):
    deadline = time.monotonic() + timeout
    while not pred() and time.monotonic() < deadline:
        poll()
    return pred()


def test_view_forwards_pose_and_diagnostics(ros_context):
    """The outputs of a node in /vt are served as the layout's /camera/<name> with their ROS 2
    schemas; a ROS topic is subscribed only while a client subscribes its channel; the pose
    and the diagnostics arrive byte for byte as published."""
    _need_foxglove()
    from geometry_msgs.msg import PoseStamped
    from helpers.foxglove_ws import FoxgloveClient
    from rclpy.serialization import deserialize_message, serialize_message

    from rs_localizer.ros.view import ViewServer

    pose = PoseStamped()
    pose.header.frame_id = "map"
    pose.header.stamp.sec, pose.header.stamp.nanosec = 12, 345
    pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = 1.5, -2.25, 0.125
    pose.pose.orientation.z, pose.pose.orientation.w = 0.6, 0.8
    diag = _diagnostics("rs_localizer: /vt/rs_localizer")
    lines = []
    pub = None
    with ViewServer(ros_context, ns="/vt", port=0, log=lines.append) as view:
        assert view.port > 0 and view.url == f"ws://localhost:{view.port}"
        client = FoxgloveClient(view.port)
        try:
            client.wait_channels(["/camera/pose", "/camera/debug_image", "/diagnostics"])
            ch = client.channels["/camera/pose"]
            assert (ch["encoding"], ch["schemaEncoding"], ch["schemaName"]) == (
                "cdr",
                "ros2msg",
                "geometry_msgs/msg/PoseStamped",
            )
            assert "MSG: geometry_msgs/Quaternion" in ch["schema"]
            node = view.node
            assert node.count_subscribers("/vt/pose") == 0  # nobody watches yet
            pub = _Publisher(ros_context, {"/vt/pose": pose, "/diagnostics": diag})
            client.subscribe(["/camera/pose", "/diagnostics"])
            got = _wait(
                lambda: client.received("/camera/pose") and client.received("/diagnostics"),
                20.0,
                lambda: client.poll(0.1),
            )
            assert got, (lines, client.messages[:3])
            assert node.count_subscribers("/vt/pose") == 1
            assert node.count_subscribers("/vt/debug_image") == 0  # not subscribed: not drawn
            assert client.received("/camera/pose")[-1] == serialize_message(pose)
            back = deserialize_message(client.received("/diagnostics")[-1], type(diag))
            assert back.status[0].name == "rs_localizer: /vt/rs_localizer"
            assert [(kv.key, kv.value) for kv in back.status[0].values] == [
                ("frames_received", "12"),
                ("latency_ms_median", "3.5"),
            ]
            assert "serving /camera/pose (ROS topic /vt/pose)" in lines
        finally:
            client.close()
            if pub is not None:
                pub.close()
        # the last client left: the ROS subscription goes
        assert _wait(lambda: node.count_subscribers("/vt/pose") == 0, 10.0, lambda: time.sleep(0.1))


def test_view_takes_a_best_effort_publisher_appearing_later(ros_context):
    """A channel subscribed before any publisher exists is read reliably; a best-effort
    publisher appearing then (as ``rs-localizer play`` publishes images) is still received."""
    _need_foxglove()
    from helpers.foxglove_ws import FoxgloveClient
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Image

    from rs_localizer.ros.view import ViewServer

    img = Image(height=2, width=3, encoding="mono8", step=3, data=bytes(range(6)))
    lines = []
    with ViewServer(ros_context, ns="/be", port=0, log=lines.append) as view:
        client = FoxgloveClient(view.port)
        pub = None
        try:
            client.wait_channels(["/camera/debug_image"])
            client.subscribe(["/camera/debug_image"])
            subscribed = lambda: view.node.count_subscribers("/be/debug_image") == 1  # noqa: E731
            assert _wait(subscribed, 10.0, lambda: client.poll(0.1))
            pub = _Publisher(ros_context, {"/be/debug_image": img}, qos=qos_profile_sensor_data)
            got = _wait(
                lambda: client.received("/camera/debug_image"), 20.0, lambda: client.poll(0.1)
            )
            assert got, lines
            assert any("best effort" in ln for ln in lines), lines
        finally:
            client.close()
            if pub is not None:
                pub.close()


def test_view_names_where_the_outputs_are(ros_context):
    """No pose in the namespace asked for, one elsewhere: the hint names the --ns to pass."""
    _need_foxglove()
    from geometry_msgs.msg import PoseStamped

    from rs_localizer.ros.view import ViewServer

    pub = _Publisher(ros_context, {"/rs_localizer/pose": PoseStamped()})
    try:
        with ViewServer(ros_context, ns="/camera", port=0) as view:
            hint = _wait(view.missing_outputs, 10.0, lambda: time.sleep(0.2))
            assert hint and "rs-localizer view --ns /rs_localizer" in hint, hint
    finally:
        pub.close()


def test_view_command_serves_and_stops(ros_context, capsys):
    _need_foxglove()
    assert cli(["view", "--port", "0", "--ns", "/nobody", "--duration", "1"]) == 0
    out = capsys.readouterr().out
    assert "serving /nobody on ws://localhost:" in out and "Foxglove WebSocket" in out


def test_view_command_without_the_sdk(monkeypatch, capsys):
    from rs_localizer.ros import view

    monkeypatch.setattr(view, "foxglove_available", lambda: False)
    assert cli(["view"]) == 2
    err = capsys.readouterr().err
    assert "rs-localizer view: error:" in err and "foxglove-sdk" in err


def test_format_status():
    text = format_status(
        "rs_localizer: /camera/rs_localizer",
        b"\x01",
        "2 frames failed",
        [("frames_received", "60"), ("gyro_bias", "[0.1, 0.2,\n 0.3]")]
        + [(f"k{i}", "x" * 10) for i in range(12)],
        width=60,
        stamp=0.25,
    )
    lines = text.splitlines()
    assert lines[0].endswith(".2 [WARN] rs_localizer: /camera/rs_localizer: 2 frames failed")
    assert lines[1].startswith("  frames_received=60  gyro_bias=[0.1, 0.2, 0.3]")
    assert all(len(ln) <= 60 for ln in lines[1:])
    pairs = " ".join(lines[1:]).split()
    assert "k11=xxxxxxxxxx" in pairs  # nothing lost, no pair split
    only = format_status(
        "n", 2, "m", [("latency_ms_median", "3"), ("frames_failed", "1")], ["lat*"]
    )
    assert "[ERROR]" in only and "latency_ms_median=3" in only and "frames_failed" not in only


def test_status_in_ns():
    assert status_in_ns("rs_localizer: /camera/rs_localizer", "/camera")
    assert status_in_ns("rs_localizer: /camera/rs_localizer", "camera/")
    assert not status_in_ns("rs_localizer: /robot/camera/rs_localizer", "/camera")
    assert status_in_ns("rs_localizer: /rs_localizer", "/")
    assert status_in_ns("rs_localizer: /a/b", None) and not status_in_ns("other: /a/b", None)


def test_diagnostics_command_prints_a_status(ros_context, capsys):
    """--once prints the localizer's status in the namespace asked for, not the others."""
    from diagnostic_msgs.msg import DiagnosticArray

    ours = _diagnostics("rs_localizer: /dt/rs_localizer")
    other = _diagnostics("rs_localizer: /elsewhere/rs_localizer", level=0)
    both = DiagnosticArray(status=[*other.status, *ours.status])
    pub = _Publisher(ros_context, {"/diagnostics": both})
    try:
        rc = cli(["diagnostics", "--ns", "/dt", "--once", "--timeout", "30"])
    finally:
        pub.close()
    out = capsys.readouterr().out
    assert rc == 0, out
    head, body = out.strip().splitlines()
    assert head.endswith("[WARN] rs_localizer: /dt/rs_localizer: 1 frame failed")
    assert body == "  frames_received=12  latency_ms_median=3.5"
    assert "elsewhere" not in out


def test_diagnostics_command_times_out(ros_context, capsys):
    assert cli(["diagnostics", "--ns", "/nobody_here", "--timeout", "1"]) == 2
    err = capsys.readouterr().err
    assert "no /diagnostics status from a localizer in /nobody_here within 1 s" in err
