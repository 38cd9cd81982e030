"""tools/build_tf2_msgs.py builds tf2_msgs for the PyPI wheels: into a temporary prefix, then
in a fresh interpreter that sees it, a TFMessage serializes to the layout and values that
rosbags' own definition of tf2_msgs/msg/TFMessage gives (an independent CDR writer; CDR's
padding bytes are unspecified, so values are compared, both ways), and a localizer node offers
/tf with that type."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("rosidl_generator_py")
pytest.importorskip("rosbags")

ROOT = Path(__file__).resolve().parents[2]

CHECK = """
import numpy as np
from geometry_msgs.msg import TransformStamped
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.typesys import Stores, get_typestore
from tf2_msgs.msg import TFMessage

t = TransformStamped()
t.header.stamp.sec, t.header.stamp.nanosec = 17, 250
t.header.frame_id, t.child_frame_id = "map", "camera"
t.transform.translation.x, t.transform.rotation.w = 1.5, 1.0
ours = bytes(serialize_message(TFMessage(transforms=[t, t])))
ts = get_typestore(Stores.ROS2_JAZZY)
M = ts.types
tr = M["geometry_msgs/msg/TransformStamped"](
    M["std_msgs/msg/Header"](M["builtin_interfaces/msg/Time"](17, 250), "map"),
    "camera",
    M["geometry_msgs/msg/Transform"](
        M["geometry_msgs/msg/Vector3"](1.5, 0.0, 0.0),
        M["geometry_msgs/msg/Quaternion"](0.0, 0.0, 0.0, 1.0),
    ),
)
ref = bytes(ts.serialize_cdr(M["tf2_msgs/msg/TFMessage"]([tr, tr]), "tf2_msgs/msg/TFMessage"))
# the same CDR layout (CDR's alignment padding bytes are unspecified: compare the values)
assert len(ours) == len(ref), (ours.hex(), ref.hex())
dec = ts.deserialize_cdr(ours, "tf2_msgs/msg/TFMessage")
assert dec == M["tf2_msgs/msg/TFMessage"]([tr, tr]), dec
assert deserialize_message(ref, TFMessage) == TFMessage(transforms=[t, t])

import rclpy
from rclpy.parameter import Parameter
from rs_localizer.ros.node import RSLocalizerNode

rclpy.init(domain_id=int(__import__("os").environ["ROS_DOMAIN_ID"]))
node = RSLocalizerNode("tf_check", parameter_overrides=[Parameter("warmup", value=False)])
pubs = dict(node.get_publisher_names_and_types_by_node("tf_check", "/"))
assert pubs.get("/tf") == ["tf2_msgs/msg/TFMessage"], pubs
# shut down before the interpreter exits (a live node's threads at exit can crash it)
node.destroy_node()
rclpy.shutdown()
print("ok", flush=True)
"""


@pytest.mark.slow
@pytest.mark.skipif(not (shutil.which("cc") and shutil.which("c++")), reason="no C compiler")
def test_build_tf2_msgs_into_a_prefix(tmp_path, ros_domain):
    prefix = tmp_path / "prefix"
    build = subprocess.run(
        [
            sys.executable,
            str(ROOT / "tools" / "build_tf2_msgs.py"),
            "--prefix",
            str(prefix),
            "--site",
            str(prefix / "site"),
            "--force",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert build.returncode == 0, build.stdout + build.stderr
    env = dict(os.environ)
    env["LD_LIBRARY_PATH"] = os.pathsep.join(
        [str(prefix / "lib"), *filter(None, [env.get("LD_LIBRARY_PATH")])]
    )
    env["PYTHONPATH"] = os.pathsep.join([str(prefix / "site"), str(ROOT)])
    env.pop("_ROS_WHEELS_BOOTSTRAP_COMPLETE", None)
    res = subprocess.run(
        [sys.executable, "-c", CHECK], env=env, capture_output=True, text=True, timeout=120
    )
    assert res.returncode == 0 and "ok" in res.stdout, res.stdout + res.stderr
