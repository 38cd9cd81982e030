"""The shipped RViz configuration and Foxglove layout name the node's topics, message fields and
frames: parsed from the files, compared with the publishers of a node built in namespace
/camera (the launch file's default) and with the map_frame parameter's default."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import yaml
from helpers.foxglove_ws import layout_topics

ROOT = Path(__file__).resolve().parents[2]
RVIZ = ROOT / "rviz" / "rs_localizer.rviz"
FOXGLOVE = ROOT / "foxglove" / "rs_localizer.json"
NAMESPACE = "/camera"

#: RViz display class -> the message type it shows
RVIZ_TYPES = {
    "rviz_default_plugins/Pose": "geometry_msgs/msg/PoseStamped",
    "rviz_default_plugins/Path": "nav_msgs/msg/Path",
    "rviz_default_plugins/MarkerArray": "visualization_msgs/msg/MarkerArray",
    "rviz_default_plugins/Image": "sensor_msgs/msg/Image",
}


def _rviz_displays() -> list[dict]:
    cfg = yaml.safe_load(RVIZ.read_text())
    return cfg["Visualization Manager"]["Displays"]


def _foxglove() -> dict:
    return json.loads(FOXGLOVE.read_text())


def _panels(node) -> list[str]:
    """The panel ids of a mosaic layout tree."""
    if isinstance(node, str):
        return [node]
    return _panels(node["first"]) + _panels(node["second"])


def _has_field(msg_cls, path: str) -> bool:
    for name in path.split("."):
        if msg_cls is None:  # a field of a number
            return False
        fields = msg_cls.get_fields_and_field_types()
        if name not in fields:
            return False
        ftype = fields[name]
        if "/" in ftype:  # a nested message: pkg/Type
            pkg, typ = ftype.split("/")
            msg_cls = getattr(__import__(f"{pkg}.msg", fromlist=[typ]), typ)
        else:
            msg_cls = None
    return True


def test_files_are_installed_and_launched():
    setup = (ROOT / "setup.py").read_text()
    assert '"rviz/*.rviz"' in setup and '"foxglove/*.json"' in setup
    launch = (ROOT / "launch" / "rs_localizer.launch.py").read_text()
    assert re.search(r'"rviz", "rs_localizer.rviz"', launch)
    layout = _foxglove()
    assert sorted(_panels(layout["layout"])) == sorted(layout["configById"])


def test_topics_and_frames_are_the_nodes(ros_context):
    from rclpy.parameter import Parameter

    from rs_localizer.ros.node import RSLocalizerNode
    from rs_localizer.ros.params import PARAMETERS

    map_frame = PARAMETERS["map_frame"][0]
    node = RSLocalizerNode(
        "rs_localizer",
        context=ros_context,
        namespace=NAMESPACE,
        parameter_overrides=[Parameter("warmup", value=False)],
    )
    try:
        published = dict(node.get_publisher_names_and_types_by_node("rs_localizer", NAMESPACE))
        status = node.diagnostics_status()
    finally:
        node.destroy_node()
    # RViz: every topic a display names is published by the node with the display's type
    displays = _rviz_displays()
    named = {d["Topic"]["Value"]: d["Class"] for d in displays if "Topic" in d}
    assert set(named) == {f"{NAMESPACE}/{t}" for t in ("pose", "path", "markers", "debug_image")}
    for topic, cls in named.items():
        assert RVIZ_TYPES[cls] in published.get(topic, []), (topic, published.get(topic))
    cfg = yaml.safe_load(RVIZ.read_text())["Visualization Manager"]
    assert cfg["Global Options"]["Fixed Frame"] == map_frame
    # Foxglove: every topic is the node's, every plotted field exists in its message
    layout = _foxglove()
    topics = layout_topics(layout)
    assert f"{NAMESPACE}/twist" in topics and f"{NAMESPACE}/debug_image" in topics
    for topic, fields in topics.items():
        assert topic in published, (topic, sorted(published))
        (msg_type,) = published[topic]
        pkg, _, typ = msg_type.split("/")
        msg_cls = getattr(__import__(f"{pkg}.msg", fromlist=[typ]), typ)
        for f in fields:
            assert not f or _has_field(msg_cls, f), (topic, f)
    scene = layout["configById"]["3D!rs_localizer_scene"]
    assert scene["followTf"] == map_frame == scene["layers"]["grid"]["frameId"]
    # the diagnostics detail panel opens on this node's status
    detail = layout["configById"]["DiagnosticStatusPanel!rs_localizer_status"]
    assert "/diagnostics" in topics
    assert (detail["selectedName"], detail["selectedHardwareId"]) == (
        status.name,
        status.hardware_id,
    )


@pytest.mark.parametrize("ns", [NAMESPACE, "/rs_localizer", "/robot/front"])
def test_view_serves_every_layout_topic(ns):
    """``rs-localizer view --ns NS`` serves the outputs of a node in NS (and those of a replay
    bag, ``/rs_localizer/<name>``, with their types) under the names the layout shows."""
    pytest.importorskip("rclpy")
    from rs_localizer.ros.bags.bag_io import OUT_TYPES
    from rs_localizer.ros.view import OUTPUT_TOPICS, served_topics
    from rs_localizer.ros.visualization import VIZ_TOPICS

    served = served_topics(ns)
    channels = {t.channel_topic: t for t in served}
    assert set(layout_topics(_foxglove())) <= set(channels)
    assert {t.ros_topic for t in served} >= {f"{ns}/{n}" for n in ("pose", "path", "markers")}
    for t in served:
        if t.ros_topic.startswith(f"{ns}/"):
            assert t.channel_topic == f"{NAMESPACE}/{t.ros_topic[len(ns) + 1 :]}"
        else:
            assert t.channel_topic == t.ros_topic
    # every output of the node and of a replay bag, with its type
    assert OUTPUT_TOPICS == {**OUT_TYPES, **VIZ_TOPICS}
    by_ros = {t.ros_topic: t.type_name for t in served}
    for name, type_name in OUTPUT_TOPICS.items():
        assert by_ros[f"{ns}/{name}"] == type_name, name


@pytest.mark.parametrize("path", ["twist.angular.x", "twist.nope"])
def test_field_check_can_fail(path):
    pytest.importorskip("rclpy")
    from geometry_msgs.msg import TwistStamped

    assert _has_field(TwistStamped, path) == (path == "twist.angular.x")
