"""The shipped Fast DDS profile: when it is applied, and that a best-effort reader in another
process receives every 640x480 RGB frame at 30 Hz with it (without it most are lost)."""

import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from rs_localizer.ros.dds_profile import (
    PROFILE_ENV,
    PROFILE_PATH,
    apply_default_profile,
    profile_in_effect,
)

ROOT = Path(__file__).resolve().parents[2]


def test_profile_applied_only_when_the_user_chose_nothing(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    env = {}
    assert apply_default_profile(env) == str(PROFILE_PATH)
    assert env["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(PROFILE_PATH)
    for chosen in (
        {"FASTRTPS_DEFAULT_PROFILES_FILE": "/mine.xml"},
        {"FASTDDS_DEFAULT_PROFILES_FILE": "/mine.xml"},
        {"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"},
        {"RS_LOCALIZER_DDS_PROFILE": "0"},
    ):
        env = dict(chosen)
        assert apply_default_profile(env) is None and env == chosen
    assert apply_default_profile({"RMW_IMPLEMENTATION": "rmw_fastrtps_cpp"}) is not None
    (tmp_path / "DEFAULT_FASTRTPS_PROFILES.xml").write_text("<profiles/>")
    assert apply_default_profile({}) is None  # Fast DDS loads that file itself


def test_profile_segment_holds_large_frames():
    ns = {"f": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}
    root = ET.parse(PROFILE_PATH).getroot()
    shm = [
        d
        for d in root.iterfind("f:transport_descriptors/f:transport_descriptor", ns)
        if d.findtext("f:type", namespaces=ns) == "SHM"
    ]
    assert len(shm) == 1
    # several 1280x720 rgb8 frames in flight
    assert int(shm[0].findtext("f:segment_size", namespaces=ns)) >= 4 * 1280 * 720 * 3
    part = root.find("f:participant", ns)
    assert part.get("is_default_profile") == "true"


_SUB = """
import sys, time, rclpy
from sensor_msgs.msg import Image
from rs_localizer.ros.qos import IMAGE_QOS
rclpy.init()
n = rclpy.create_node("profile_sub")
got = set()
n.create_subscription(Image, "/profile_test/image", lambda m: got.add(m.header.frame_id), IMAGE_QOS)
print("ready", flush=True)
end = time.time() + float(sys.argv[1])
while time.time() < end and len(got) < 30:
    rclpy.spin_once(n, timeout_sec=0.05)
print("GOT", len(got), flush=True)
"""

_PUB = """
import time, numpy as np, rclpy
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image
rclpy.init()
n = rclpy.create_node("profile_pub")
pub = n.create_publisher(Image, "/profile_test/image", qos_profile_sensor_data)
end = time.time() + 30
while pub.get_subscription_count() == 0 and time.time() < end:
    rclpy.spin_once(n, timeout_sec=0.05)
time.sleep(1.0)  # (a best-effort reader misses samples sent right after matching)
data = np.random.default_rng(0).integers(0, 255, 480 * 640 * 3, dtype=np.uint8).tobytes()
t0 = time.perf_counter()
for i in range(30):
    m = Image(height=480, width=640, encoding="rgb8", step=640 * 3, data=data)
    m.header.frame_id = str(i)
    pub.publish(m)
    while time.perf_counter() < t0 + (i + 1) / 30:
        time.sleep(0.001)
time.sleep(1.0)
"""


@pytest.mark.slow
def test_best_effort_640x480_rgb_at_30hz_with_the_profile(ros_domain):
    """Driver and reader (the node's image QoS) in two processes, both with the profile, as
    the launch file runs them: all 30 frames of 921,600 bytes arrive."""
    env = {
        **os.environ,
        "PYTHONPATH": str(ROOT),
        "ROS_DOMAIN_ID": str(ros_domain),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        "FASTRTPS_DEFAULT_PROFILES_FILE": str(PROFILE_PATH),
    }
    env.pop("FASTDDS_DEFAULT_PROFILES_FILE", None)
    sub = subprocess.Popen(
        [sys.executable, "-c", _SUB, "40"], env=env, stdout=subprocess.PIPE, text=True
    )
    try:
        assert sub.stdout.readline().strip() == "ready"
        subprocess.run([sys.executable, "-c", _PUB], env=env, check=True, timeout=60)
        out, _ = sub.communicate(timeout=60)
    finally:
        sub.kill()
    assert out.strip().splitlines()[-1] == "GOT 30"


def test_the_profile_in_effect_is_named_with_why(tmp_path, monkeypatch):
    """What the node logs at start: which profile is in effect (the package's, the user's,
    none) and why; a profile variable naming a missing or malformed file leaves neither that
    profile nor the package's in effect, and says so."""
    monkeypatch.chdir(tmp_path)
    env = {}
    apply_default_profile(env)
    st = profile_in_effect(env, tmp_path)
    assert (st.source, st.path, st.ok) == ("package", str(PROFILE_PATH), True)
    assert "the package's" in st.message()
    # the launch file's installed copy of it
    copy = tmp_path / "share" / "fastdds_profile.xml"
    copy.parent.mkdir()
    copy.write_bytes(PROFILE_PATH.read_bytes())
    st = profile_in_effect({"FASTRTPS_DEFAULT_PROFILES_FILE": str(copy)}, tmp_path)
    assert (st.source, st.ok) == ("package", True)
    mine = tmp_path / "mine.xml"
    mine.write_text('<?xml version="1.0"?><dds><profiles/></dds>')
    for var in PROFILE_ENV:
        st = profile_in_effect({var: str(mine)}, tmp_path)
        assert (st.source, st.path, st.ok) == ("user", str(mine), True) and var in st.reason
    broken = {
        "missing.xml": (None, "no such file"),
        "malformed.xml": ("<profiles><participant>", "not well-formed XML"),
        "other.xml": ("<launch/>", "not a Fast DDS profile"),
    }
    for name, (text, why) in broken.items():
        f = tmp_path / name
        if text is not None:
            f.write_text(text)
        env = {"FASTRTPS_DEFAULT_PROFILES_FILE": str(f)}
        assert apply_default_profile(env) is None  # (the user's choice is kept)
        st = profile_in_effect(env, tmp_path)
        assert (st.source, st.ok) == ("none", False)
        msg = st.message()
        assert why in msg and str(f) in msg and "FASTRTPS_DEFAULT_PROFILES_FILE" in msg, msg
        assert "neither that profile nor the package's" in msg, msg
    st = profile_in_effect({"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}, tmp_path)
    assert (st.source, st.ok) == ("other middleware", True) and "cyclonedds" in st.message()
    st = profile_in_effect({"RS_LOCALIZER_DDS_PROFILE": "0"}, tmp_path)
    assert (st.source, st.ok) == ("none", True) and "turned off" in st.reason
    st = profile_in_effect({}, tmp_path)  # (nothing applied it)
    assert (st.source, st.ok) == ("none", False)
    # Fast DDS's file in the working directory: the user's, or broken
    (tmp_path / "DEFAULT_FASTRTPS_PROFILES.xml").write_text("<profiles/>")
    assert profile_in_effect({}, tmp_path).source == "user"
    (tmp_path / "DEFAULT_FASTRTPS_PROFILES.xml").write_text("<profiles>")
    st = profile_in_effect({}, tmp_path)
    assert (st.source, st.ok) == ("none", False) and "not well-formed" in st.message()
