"""The rig mode with images over DDS: three 640x480 RGB cameras of the marker room (each view
rendered at the rig's motion composed with its mounting, rs_localizer.sim.render.render_rig_frames)
published per camera on ``<camera>/image_raw``, each camera's ArUco front end, one pose for the rig
against the truth, every image counted (undecodable and wrong-size images under the single-camera
node's reasons); the managed rig node through a transition cycle; the diagnostics converter shared
with the single-camera node; the status naming two cameras that disagree."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.rig_node import T0, RigHarness, rig_parameters

from rs_localizer.geometry import rotation_angle_deg, rotvec_to_matrix

pytest.importorskip("rclpy")

OK, WARN = b"\x00", b"\x01"  # (diagnostic_msgs/DiagnosticStatus levels)


def image_msg(img: np.ndarray, stamp_ns: int, frame_id: str, encoding: str = "rgb8"):
    from sensor_msgs.msg import Image

    from rs_localizer.ros.conversions import ns_to_stamp

    m = Image()
    m.header.stamp = ns_to_stamp(stamp_ns)
    m.header.frame_id = frame_id
    m.height, m.width = int(img.shape[0]), int(img.shape[1])
    m.encoding = encoding
    img = np.ascontiguousarray(img)
    m.step = int(img.strides[0])
    m.data = img.tobytes()
    return m


@pytest.fixture(scope="module")
def rendered():
    from rs_localizer.sim.render import render_rig_frames, vga_rig

    cams = vga_rig(3)
    frames, motion = render_rig_frames(cams, 6, seed=5)
    return cams, frames, motion


def test_three_cameras_images_over_dds_one_pose_every_image_counted(ros_context, rendered):
    """18 RGB images (3 cameras x 6, unsynchronized) on each camera's image_raw, lock-step:
    6 rig poses within 0.1 deg and 3 mm of the truth, each from the three cameras' markers;
    then an image of another size and one of an unknown encoding, counted
    ``skipped.image_size_mismatch`` and ``skipped.bad_image``; received = solved + failed +
    skipped + pending per camera and per rig frame in the diagnostics, with the stage times
    (the front end's too). With
    ``republish_correspondences``, each camera's ``correspondences_out`` holds what its front
    end found in each image it searched, stamped like the image (the first image of each
    camera, searched whole, gives the correspondences of the same front end run on it alone),
    and nothing for the two images not searched. With the node's
    warm-up: on a numba cache without the rig's kernels they compile in the background and
    the rig frames are posed on the NumPy implementation meanwhile (the diagnostics say
    which)."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2

    from rs_localizer.ros.config import build_config, load_maps
    from rs_localizer.ros.conversions import pose_from_msg
    from rs_localizer.ros.node import RSLocalizerNode
    from rs_localizer.ros.params import default_values
    from rs_localizer.ros.pointcloud import read_correspondences
    from rs_localizer.sim.trajectory import rig_truth

    cams, frames, motion = rendered
    params = rig_parameters(cams, frontend="aruco", frontend_map="aruco_room", warmup=True,
                            republish_correspondences=True)  # fmt: skip
    node = RSLocalizerNode("rs_localizer", context=ros_context, namespace="/rig",
                            parameter_overrides=params)  # fmt: skip
    h = RigHarness(ros_context, cams, node)
    clouds = {c.name: [] for c in cams}
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    for c in cams:
        topic = f"/rig/{c.name}/correspondences_out"
        h.probe.create_subscription(PointCloud2, topic, clouds[c.name].append, qos)
    try:
        assert h.matched(), "the rig node and the probe did not match"
        topics = [f"/rig/{c.name}/correspondences_out" for c in cams]
        assert h.wait(lambda: all(h.probe.count_publishers(t) == 1 for t in topics))
        h.send_info(cams)
        for f in frames:
            h.send(f.name, "image", image_msg(f.image, f.stamp_ns, f.name))
        last = frames[-1].stamp_ns
        h.send("front", "image", image_msg(frames[0].image[:240, :320], last + 40_000_000, "front"))
        bad = image_msg(frames[0].image, last + 50_000_000, "left", encoding="yuv422")
        h.send("left", "image", bad)
        assert h.wait(lambda: len(h.poses) >= 5)
        _, v = h.last_diag()
        assert len(h.poses) == int(v["rig_frames_solved"]) >= 5, v
        assert v["compiled"] in ("true", "false") and "compile_state" in v, v
        for m in h.poses:
            stamp = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
            R, p, _, _ = rig_truth(motion, (stamp - T0) * 1e-9)
            Re, pe = pose_from_msg(m.pose)
            assert rotation_angle_deg(Re, R) < 0.1 and np.linalg.norm(pe - p) < 0.003
        assert h.wait(lambda: all(len(clouds[c.name]) == 6 for c in cams)), {
            n: len(m) for n, m in clouds.items()
        }
        values = {**default_values(), "frontend": "aruco", "frontend_map": "aruco_room"}
        alone = load_maps(build_config(values).camera, owner=clouds).frontend
        for c in cams:
            mine = [f for f in frames if f.name == c.name]
            got = clouds[c.name]
            assert [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in got] == [
                f.stamp_ns for f in mine
            ]
            assert all(m.header.frame_id == c.name for m in got)
            first = read_correspondences(got[0])
            want = alone.process(mine[0].image, c.camera, encoding="rgb8")
            assert len(first.points2d) == len(want.points2d) > 0
            assert np.allclose(first.points2d, want.points2d, atol=1e-3)
            assert np.allclose(first.points, want.points, atol=1e-5)
        assert v["front.skipped.image_size_mismatch"] == "1", v
        assert v["left.skipped.bad_image"] == "1", v
        rig_sum = sum(int(v[f"rig_frames_{k}"]) for k in ("solved", "failed", "skipped", "pending"))
        assert int(v["rig_frames"]) == rig_sum
        for c in cams:
            n = c.name
            got = sum(int(v[f"{n}.{k}"]) for k in ("solved", "failed", "skipped", "pending"))
            assert int(v[f"{n}.received"]) == got == 6 + (n != "right"), (n, v)
            assert int(v[f"{n}.inliers"]) > 60, v
        # (the camera's stage times, the front end's of the images searched)
        stages = [float(v[f"{k}_ms_median"]) for k in ("decode", "frontend", "estimate", "publish")]
        assert all(0.0 < t < 10_000.0 for t in stages), v
    finally:
        h.close()


def test_the_managed_rig_node_through_a_transition_cycle(ros_context):
    """configure (a camera without mounting: the transition fails naming it; with it: the
    publishers and camera_info subscriptions, no frame input; an estimator parameter taken,
    ``rs.line_delay`` refused), activate (frames posed),
    deactivate (frames not taken, the open rig frames published), cleanup (unconfigured),
    configure + activate again (posed again, a new track)."""
    from rclpy.lifecycle import TransitionCallbackReturn
    from rclpy.parameter import Parameter

    from rs_localizer.ros.lifecycle import RSLocalizerLifecycleNode
    from rs_localizer.sim.trajectory import default_rig, generate_rig_video

    SUCCESS, FAILURE = TransitionCallbackReturn.SUCCESS, TransitionCallbackReturn.FAILURE
    cams = default_rig(3)
    frames, _, _ = generate_rig_video(cams, duration=0.3, num_points=120, seed=21)
    full = rig_parameters(cams)
    params = [p for p in full if p.name != "rig.left.mounting"]
    broken = RSLocalizerLifecycleNode("rs_localizer", context=ros_context, namespace="/broken",
                                       parameter_overrides=params)  # fmt: skip
    assert broken.trigger_configure() == FAILURE and broken.mode.rig is None
    broken.destroy_node()
    node = RSLocalizerLifecycleNode("rs_localizer", context=ros_context, namespace="/rig",
                                     parameter_overrides=full)  # fmt: skip
    (r,) = node.set_parameters([Parameter("ransac.threshold_px", value=2.5)])
    assert r.successful  # (unconfigured: read at configure)
    assert node.trigger_configure() == SUCCESS
    h = RigHarness(ros_context, cams, node)

    def clouds(fs, taken=True):
        from rs_localizer.ros.conversions import ns_to_stamp
        from rs_localizer.ros.pointcloud import correspondence_cloud

        for f in fs:
            cloud = correspondence_cloud(
                f.uv, f.xyz, frame_id=f.name, stamp=ns_to_stamp(f.stamp_ns)
            )
            h.send(f.name, "cloud", cloud, taken)

    try:
        assert h.wait(lambda: h.pub["front"]["info"].get_subscription_count() > 0)
        assert h.pub["front"]["cloud"].get_subscription_count() == 0  # (inactive)
        (r,) = node.set_parameters([Parameter("ransac.threshold_px", value=3.0)])
        assert r.successful and node.mode.rig.settings.options.ransac.threshold_px == 3.0
        (r,) = node.set_parameters([Parameter("rs.line_delay", value=2e-5)])
        assert not r.successful and "restart the node to change rs.line_delay" in r.reason
        h.send_info(cams)
        assert node.trigger_activate() == SUCCESS
        assert h.matched(("cloud",))
        clouds(frames[:15])
        assert h.wait(lambda: len(h.poses) >= 4)
        assert node.trigger_deactivate() == SUCCESS
        assert len(h.poses) == 5 or h.wait(lambda: len(h.poses) == 5)  # (the open one too)
        assert node.mode.rig.rig_counts()["pending"] == 0
        received = node.mode.rig.counts["front.received"]
        clouds(frames[15:18], taken=False)
        h.wait(lambda: False, timeout=0.5)
        assert node.mode.rig.counts["front.received"] == received  # (not subscribed)
        assert node.trigger_cleanup() == SUCCESS and node.mode.rig is None
        assert node.trigger_configure() == SUCCESS and node.trigger_activate() == SUCCESS
        assert h.matched(("cloud", "info"))
        h.send_info(cams)
        n0 = len(h.poses)
        clouds(frames[15:])
        assert h.wait(lambda: len(h.poses) >= n0 + 3)
        assert (
            node.mode.rig.counts["rig.path.cold"] == 1
            and node.mode.rig.counts["front.received"] == 4
        )  # (counters anew)
    finally:
        h.close()


def test_one_diagnostics_converter_for_both_nodes():
    """status_message: the levels of .diagnostics and their names give the same message; the
    values keep their order as strings; an unknown level is refused. Both nodes build their
    status with it (through their shared core, :mod:`rs_localizer.ros.core`)."""
    import inspect

    from diagnostic_msgs.msg import DiagnosticStatus

    from rs_localizer.ros import core, mode, rig_node
    from rs_localizer.ros.diagnostics import ERROR, OK, WARN
    from rs_localizer.ros.status_msg import status_message

    for lv, name, byte in ((OK, "OK", DiagnosticStatus.OK), (WARN, "WARN", DiagnosticStatus.WARN),
                           (ERROR, "ERROR", DiagnosticStatus.ERROR)):  # fmt: skip
        a = status_message("n", "hw", lv, "m", {"b": 2, "a": 1.5})
        b = status_message("n", "hw", name, "m", {"b": 2, "a": 1.5})
        assert a.level == b.level == byte
        assert [(kv.key, kv.value) for kv in a.values] == [("b", "2"), ("a", "1.5")]
    with pytest.raises(ValueError, match="unknown diagnostic level"):
        status_message("n", "hw", "FINE", "m", {})
    # (the one node builds a camera's and a rig's status with the one builder and converts
    # them; its mode builds no status or message itself, it hands its status as data)
    assert "status_message(" in inspect.getsource(core)
    assert "status(parts, self._timing_snapshot())" in inspect.getsource(core.NodeCore)
    assert "def diagnostics(" in inspect.getsource(mode.LocalizerMode)
    for mod in (mode, rig_node):
        assert not hasattr(mod, "status")
        assert "status_message(" not in inspect.getsource(mod)
        assert "DiagnosticStatus()" not in inspect.getsource(mod)


def test_the_status_names_both_of_two_cameras_that_disagree():
    """Two cameras, the left mounting 3 deg off: nothing tells which mounting is wrong, so every
    rig frame is refused (``cameras_disagree``: the status is ERROR, no rig frame posed) and
    both cameras' state is ``disagrees``, the ERROR message going on with the cameras'
    warning and the failures by reason; with a third camera the status warns and names left
    alone, outvoted by the others (``left.outvoted``)."""
    from helpers.ros import rig_status

    from rs_localizer.frames import Mounting
    from rs_localizer.ros.diagnostics import ERROR
    from rs_localizer.ros.diagnostics import WARN as W
    from rs_localizer.sim.trajectory import default_rig, generate_rig_video
    from rs_localizer.tracking.localizer import CameraFrame
    from rs_localizer.tracking.video import Localizer, LocalizerSettings

    for k in (2, 3):
        cams = default_rig(k)
        frames, _, _ = generate_rig_video(cams, duration=0.3, num_points=120, seed=7)
        mounts = {c.name: Mounting.from_pose(c.R_rig_cam, c.p_rig_cam) for c in cams}
        bad = rotvec_to_matrix(np.radians([0.0, 3.0, 0.0]))
        mounts["left"] = Mounting(bad @ mounts["left"].R, mounts["left"].c)
        rig = Localizer(LocalizerSettings(mounts))
        by = {c.name: c.camera for c in cams}
        for f in frames:
            rig.add(CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name))
        level, message, values = rig_status(rig)
        if k == 2:
            assert level == ERROR and rig.counts["rig.failed.cameras_disagree"] > 0, message
            n = rig.counts["rig.failed.cameras_disagree"]
            assert message.startswith("no rig frame posed: cameras front and left disagree")
            assert f"rig frames failed (cameras_disagree {n})" in message, message
            assert values["rig_frames_failed.cameras_disagree"] == n
            assert values["front.state"] == values["left.state"] == "disagrees"
            assert rig.camera_partner("front") == "left"
            continue
        assert level == W, message
        assert "camera left disagrees with the rig" in message, message
        assert "front" not in message and values["front.state"] == "running"
        assert "outvoted by the others" in message and values["front.outvoted"] == 0
        assert values["left.outvoted"] == rig.counts["rig.solved"] > 0, values


def test_the_lifecycle_process_runs_the_rig_mode(tmp_path, ros_domain):
    """rs_localizer_lifecycle_node with rig.cameras runs the managed rig node (the process
    runner): it starts unconfigured in the rig mode and stops cleanly on SIGINT."""
    from rs_localizer.ros.process import NodeProcess, ros_env

    p = tmp_path / "rig.yaml"
    p.write_text(
        "/**/rs_localizer:\n  ros__parameters:\n    warmup: false\n    rig:\n"
        "      cameras: [front, left]\n"
        "      front: {mounting: [0.15, 0.0, 0.1, -0.5, 0.5, -0.5, 0.5]}\n"
        "      left: {mounting: [0.0, 0.12, 0.12, -0.7071068, 0.0, 0.0, 0.7071068]}\n"
    )
    n = NodeProcess([p], namespace="/rig", env=ros_env(), log=tmp_path / "lc.log",
                    executable="rs_localizer_lifecycle_node")  # fmt: skip
    try:
        assert n.wait_ready(60.0, marker="unconfigured (lifecycle node, rig mode"), n.log
    finally:
        rc = n.stop()
    assert rc == 0, n.log
