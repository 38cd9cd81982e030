"""The node on a robot: outputs in the robot's base frame, compressed images,
lifecycle management and several cameras in one process, each over DDS against a real node
process."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("rosbags")

from helpers.ros import start_node, stop_node
from helpers.transforms import transform, twist_hat

OUTPUTS = ("/camera/pose", "/camera/twist", "/camera/odom", "/camera/pose_with_covariance")


def _base_ground_truth(gt, T_bc):
    """Camera ground truth -> base ground truth with 4x4 matrices: ``T_mb = T_mc T_bc^-1`` and
    the body twist by conjugation ``xi_b^ = T_bc xi_c^ T_bc^-1`` (the camera and the base are
    one rigid body)."""
    from rs_localizer.accuracy import GroundTruth

    out = GroundTruth(stamps=gt.stamps.copy())
    T_cb = np.linalg.inv(T_bc)
    for s in gt.stamps:
        T = transform(gt.orientation[s], gt.position[s]) @ T_cb
        out.orientation[s], out.position[s] = T[:3, :3], T[:3, 3]
        if s in gt.angular_velocity:
            X = T_bc @ twist_hat(gt.angular_velocity[s], gt.linear_velocity[s]) @ T_cb
            out.angular_velocity[s] = np.array([X[2, 1], X[0, 2], X[1, 0]])
            out.linear_velocity[s] = X[:3, 3]
    return out


def test_base_frame_outputs(tmp_path, ros_context, sample_bag):
    """With base_frame and camera_to_base.* every output describes the base: checked against
    the bag's ground truth moved to the base with 4x4 transforms."""
    from scipy.spatial.transform import Rotation

    from rs_localizer.accuracy import summarize_errors
    from rs_localizer.ros.bags.accuracy import evaluate_outputs
    from rs_localizer.ros.bags.bag_io import load_ground_truth
    from rs_localizer.ros.bags.play import play

    q_bc = Rotation.from_euler("xyz", [-95, 3, -88], degrees=True).as_quat()  # a tilted camera
    t_bc = np.array([0.35, -0.12, 0.6])
    node = start_node(
        tmp_path,
        {
            "base_frame": "base_link",
            "camera_to_base.translation": t_bc.tolist(),
            "camera_to_base.rotation": q_bc.tolist(),
        },
    )
    try:
        res = play(
            sample_bag,
            lockstep=True,
            output_topics=OUTPUTS,
            context=ros_context,
            timeout=5.0,
            topics=["/camera/correspondences", "/camera/camera_info"],
            limit=12,
            log=print,
            late_topics=("/camera/twist", "/camera/odom"),
        )
        assert res.answered == len(res.frames) == 12, node.log
        gt = _base_ground_truth(
            load_ground_truth(sample_bag), transform(Rotation.from_quat(q_bc).as_matrix(), t_bc)
        )
        s = summarize_errors(evaluate_outputs(res.frames, gt, ["/camera"])["/camera"])
        # the camera-frame limits of test_node.py; a missing or wrong transform is off by the
        # mounting itself (~90 deg, 0.7 m, ~0.5 m/s)
        assert s["rot_deg"]["median"] < 0.03 and s["pos_m"]["median"] < 0.01, s
        assert s["angvel"]["median"] < 0.15 and s["linvel"]["median"] < 0.8, s
        for f in res.frames:
            twist = f["outputs"]["/camera/twist"][1]
            odom = f["outputs"]["/camera/odom"][1]
            pwc = f["outputs"]["/camera/pose_with_covariance"][1]
            assert twist.header.frame_id == "base_link" and odom.child_frame_id == "base_link"
            assert odom.header.frame_id == "map" and pwc.header.frame_id == "map"
            np.testing.assert_allclose(
                [odom.pose.pose.position.x, odom.pose.pose.position.y],
                [pwc.pose.pose.position.x, pwc.pose.pose.position.y],
            )
            for cov in (
                np.reshape(pwc.pose.covariance, (6, 6)),
                np.reshape(odom.twist.covariance, (6, 6)),
            ):
                assert np.isfinite(cov).all() and (np.diag(cov) > 0).all()
    finally:
        alive, rc = stop_node(node)
    assert alive and rc == 0, node.log


def test_bad_extrinsic_is_a_clear_error(tmp_path, ros_domain):
    from helpers.paths import CONFIG
    from helpers.ros import refused_start

    from rs_localizer.ros.process import write_params_yaml

    overlay = write_params_yaml(
        tmp_path / "p.yaml", {"base_frame": "base_link", "camera_to_base.rotation": [0.0, 0.0, 0.0]}
    )
    exited, rc, log = refused_start(tmp_path, [CONFIG, overlay], "/bad_ext", 120)
    assert exited and rc != 0
    assert "invalid camera_to_base" in log and "quaternion" in log, log


def test_compressed_images(tmp_path, ros_context, sample_images_bag):
    """``image_transport: compressed``: JPEG and PNG versions of the rendered frames on
    ``<image remapped>/compressed`` are solved (accurate against ground truth); bad payloads
    are dropped and counted as ``bad_image``; the node stays up."""
    from helpers.paths import CONFIG, IMAGES_CONFIG
    from helpers.ros import Probe
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import CameraInfo, CompressedImage, Image

    from rs_localizer.accuracy import frame_errors
    from rs_localizer.ros.bags.bag_io import iter_messages, load_ground_truth
    from rs_localizer.ros.conversions import ns_to_stamp, pose_from_msg, stamp_to_ns
    from rs_localizer.ros.image_codec import compressed_fields, decode_image
    from rs_localizer.ros.process import NodeProcess, ros_env, write_params_yaml

    ns = "/cimg"
    topic = f"{ns}/image_raw/compressed"
    overlay = write_params_yaml(
        tmp_path / "p.yaml",
        {
            "image_transport": "compressed",
            "republish_correspondences": False,
            "diagnostics_period": 0.2,
        },
        reliable_topics=[f"{ns}/camera_info", topic],
    )
    node = NodeProcess(
        [CONFIG, IMAGES_CONFIG, overlay],
        namespace=ns,
        env=ros_env(),
        remaps={"image": "image_raw"},
        log=tmp_path / "node.log",
    )
    msgs = {"/camera/image_raw": [], "/camera/camera_info": []}
    types = {"/camera/image_raw": Image, "/camera/camera_info": CameraInfo}
    for t, _, _, raw in iter_messages(sample_images_bag, set(types)):
        msgs[t].append(deserialize_message(raw, types[t]))
    gt = load_ground_truth(sample_images_bag)
    ref_offset = round(239.5 * 62.5e-6 * 1e9)
    probe = Probe(ros_context, namespace=ns)
    pub = probe.node.create_publisher(
        CompressedImage, topic, QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    )
    try:
        assert node.wait_ready(120), node.log
        assert f"aruco front end on {topic}" in node.log, node.log
        assert probe.wait(lambda: pub.get_subscription_count() > 0, 30), node.log
        probe.wait_matched()
        probe.pub_info.publish(msgs["/camera/camera_info"][0])
        probe.wait_camera_info()
        n_bad = n_good = 0
        errs = []
        for k, im in enumerate(msgs["/camera/image_raw"][:6]):
            arr, _ = decode_image(im)
            kind = "jpeg" if k % 2 == 0 else "png"
            f = compressed_fields(arr, kind, quality=95, encoding=im.encoding)
            stamp = stamp_to_ns(im.header.stamp)
            if k in (1, 4):  # a bad payload just before the frame (counted, not solved)
                bad = CompressedImage(
                    format=f["format"], data=f["data"][: len(f["data"]) // 3].tobytes()
                )
                bad.header.stamp = ns_to_stamp(stamp - 1000)
                bad.header.frame_id = im.header.frame_id
                pub.publish(bad)
                n_bad += 1
            msg = CompressedImage(format=f["format"], data=f["data"].tobytes())
            msg.header = im.header
            pub.publish(msg)
            pose = probe.wait_pose(stamp + ref_offset, timeout=30)
            assert pose is not None, f"no pose for the {kind} frame {k}:\n{node.log}"
            n_good += 1
            R, p = pose_from_msg(pose.pose)
            errs.append(frame_errors(R, p, None, None, gt, stamp + ref_offset))
        # JPEG at quality 95: still far better than the global-shutter p3p (0.38 deg, 2.3 cm)
        assert max(e["rot_deg"] for e in errs) < 0.1, errs
        assert max(e["pos_m"] for e in errs) < 0.01, errs
        # counters count frames on arrival: wait until none is pending (the pose of the last
        # frame can be out before its counters are)
        _st, v = probe.wait_diag(
            lambda v: (
                int(v.get("image_frames", 0)) == n_good + n_bad
                and int(v.get("frames_pending", 1)) == 0
                and int(v.get("frames_solved", 0)) >= n_good
            )
        )
        assert int(v["frames_solved"]) == n_good and int(v["failed.bad_image"]) == n_bad, v
        assert "truncated JPEG" in node.log or "does not decode" in node.log, node.log
    finally:
        alive, rc = stop_node(node, probe)
    assert alive and rc == 0, node.log


class LifecycleClient:
    """Drives a managed node through its lifecycle services (lifecycle_msgs ChangeState and
    GetState) from a test-side node."""

    def __init__(self, node, node_name):
        from lifecycle_msgs.srv import ChangeState, GetState

        self.node = node
        self.change = node.create_client(ChangeState, f"{node_name}/change_state")
        self.get = node.create_client(GetState, f"{node_name}/get_state")

    def _call(self, executor, cli, req, timeout=120.0, attempts=1):
        assert cli.wait_for_service(timeout_sec=30.0), cli.srv_name
        for _ in range(attempts):
            fut = cli.call_async(req)
            executor.spin_until_future_complete(fut, timeout_sec=timeout / attempts)
            if fut.done():
                return fut.result()
            cli.remove_pending_request(fut)
        raise AssertionError(f"{cli.srv_name} did not answer")

    def state(self, executor) -> str:
        """The node's state label. The request is sent again when no answer comes within 30 s:
        a service can take a request before it has matched the client's reply reader (Fast
        DDS then drops the reply, "failed to send response"), and asking again changes
        nothing."""
        from lifecycle_msgs.srv import GetState

        return self._call(executor, self.get, GetState.Request(), attempts=4).current_state.label

    def transition(self, executor, transition_id) -> bool:
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState

        return self._call(
            executor, self.change, ChangeState.Request(transition=Transition(id=transition_id))
        ).success


def _frames(sample_bag, n):
    """The first ``n`` correspondence clouds and the camera_info of the sample bag (rclpy)."""
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import CameraInfo, PointCloud2

    from rs_localizer.ros.bags.bag_io import iter_messages

    clouds, info = [], None
    for topic, _, _, raw in iter_messages(
        sample_bag, {"/camera/correspondences", "/camera/camera_info"}
    ):
        if topic.endswith("camera_info") and info is None:
            info = deserialize_message(raw, CameraInfo)
        elif topic.endswith("correspondences") and len(clouds) < n:
            clouds.append(deserialize_message(raw, PointCloud2))
    return clouds, info


def test_lifecycle(tmp_path, ros_context, sample_bag):
    """configure loads and compiles (publishers exist, inactive; frames ignored), activate
    subscribes and publishes (poses match ground truth), deactivate stops, cleanup releases;
    a configure with an invalid parameter fails and leaves the node unconfigured."""
    from helpers.paths import CONFIG
    from helpers.ros import ParamClient, Probe
    from lifecycle_msgs.msg import Transition

    from rs_localizer.accuracy import frame_errors
    from rs_localizer.ros.bags.bag_io import load_ground_truth
    from rs_localizer.ros.conversions import pose_from_msg, stamp_to_ns
    from rs_localizer.ros.process import NodeProcess, ros_env, write_params_yaml

    ns = "/lc"
    overlay = write_params_yaml(
        tmp_path / "p.yaml",
        {"diagnostics_period": 0.2},
        reliable_topics=[f"{ns}/correspondences", f"{ns}/camera_info"],
    )
    node = NodeProcess(
        [CONFIG, overlay],
        namespace=ns,
        env=ros_env(),
        executable="rs_localizer_lifecycle_node",
        log=tmp_path / "lc.log",
    )
    clouds, info = _frames(sample_bag, 8)
    gt = load_ground_truth(sample_bag)
    ref = round(359.5 * 30e-6 * 1e9)
    probe = Probe(ros_context, namespace=ns)
    ex = probe.executor
    lc = LifecycleClient(probe.node, f"{ns}/rs_localizer")
    params = None
    count = probe.node.count_publishers
    subs = probe.node.count_subscribers

    def send(k):
        probe.pub_info.publish(info)
        probe.pub_corr.publish(clouds[k])
        return stamp_to_ns(clouds[k].header.stamp) + ref

    try:
        assert node.wait_ready(120, marker="unconfigured"), node.log
        assert lc.state(ex) == "unconfigured"
        probe.spin(0.5)
        assert count(f"{ns}/pose") == 0 and subs(f"{ns}/correspondences") == 0

        # an invalid parameter is accepted while unconfigured, and configure then fails
        params = ParamClient(ros_context, f"{ns}/rs_localizer")
        assert params.set(solver="nonexistent")[0].successful
        assert not lc.transition(ex, Transition.TRANSITION_CONFIGURE)
        assert lc.state(ex) == "unconfigured"
        assert "configure failed: invalid parameters: unknown solver 'nonexistent'" in node.log
        assert params.set(solver="r6p_1lin")[0].successful

        assert lc.transition(ex, Transition.TRANSITION_CONFIGURE), node.log
        assert lc.state(ex) == "inactive"
        assert "warm-up (r6p_1lin)" in node.log
        assert probe.wait(lambda: count(f"{ns}/pose") == 1 and subs(f"{ns}/camera_info") == 1, 10)
        assert subs(f"{ns}/correspondences") == 0
        s = send(0)
        probe.spin(1.0)
        assert probe.pose_near(s) is None and not probe.outputs["pose"]  # inactive: nothing

        assert lc.transition(ex, Transition.TRANSITION_ACTIVATE)
        assert lc.state(ex) == "active"
        assert probe.wait(lambda: probe.pub_corr.get_subscription_count() == 1, 10)
        for k in range(1, 5):
            s = send(k)
            pose = probe.wait_pose(s, timeout=20)
            assert pose is not None, f"active: no pose for frame {k}:\n{node.log}"
            e = frame_errors(*pose_from_msg(pose.pose), None, None, gt, s)
            assert e["rot_deg"] < 0.2 and e["pos_m"] < 0.03, e
        _, v = probe.wait_diag(lambda v: int(v.get("frames_solved", 0)) == 4)
        assert int(v["frames_solved"]) == 4 and int(v["frames_received"]) == 4, v

        assert lc.transition(ex, Transition.TRANSITION_DEACTIVATE)
        assert lc.state(ex) == "inactive"
        assert probe.wait(lambda: subs(f"{ns}/correspondences") == 0, 10)
        n_poses, probe.diag = len(probe.outputs["pose"]), {}
        send(5)
        probe.spin(1.5)
        assert len(probe.outputs["pose"]) == n_poses and probe.node_diag()[0] is None

        assert lc.transition(ex, Transition.TRANSITION_ACTIVATE)  # again
        assert probe.wait(lambda: probe.pub_corr.get_subscription_count() == 1, 10)
        s = send(6)
        assert probe.wait_pose(s, timeout=20) is not None, node.log

        assert lc.transition(ex, Transition.TRANSITION_DEACTIVATE)
        assert lc.transition(ex, Transition.TRANSITION_CLEANUP)
        assert lc.state(ex) == "unconfigured"
        assert probe.wait(lambda: count(f"{ns}/pose") == 0 and subs(f"{ns}/camera_info") == 0, 10)
        # configure again after cleanup: counters start from zero
        assert lc.transition(ex, Transition.TRANSITION_CONFIGURE)
        assert lc.transition(ex, Transition.TRANSITION_ACTIVATE)
        assert probe.wait(
            lambda: (
                probe.pub_corr.get_subscription_count() == 1
                and probe.pub_info.get_subscription_count() == 1
            ),
            10,
        )
        probe.diag = {}
        s = send(7)
        assert probe.wait_pose(s, timeout=20) is not None, node.log
        _st, v = probe.wait_diag(lambda v: int(v.get("frames_solved", 0)) >= 1)
        assert int(v["frames_received"]) == 1, v
        assert lc.transition(ex, Transition.TRANSITION_ACTIVE_SHUTDOWN)
        assert lc.state(ex) == "finalized"
    finally:
        if params is not None:
            params.close()
        alive, rc = stop_node(node, probe)
    assert alive and rc == 0, node.log


def test_cameras_in_one_process(tmp_path, ros_context, sample_bag, keypoints_bag):
    """``cameras``: one localizer per namespace in one process, each with its own section of
    the parameter file; a landmark file named by every camera is loaded once."""
    from helpers.paths import CONFIG
    from helpers.ros import Probe
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import PointCloud2

    from rs_localizer.ros.bags.bag_io import iter_messages
    from rs_localizer.ros.conversions import stamp_to_ns
    from rs_localizer.ros.process import NodeProcess, ros_env, write_params_yaml

    names = {"front": "/multi/front", "rear": "/multi/rear", "/abs/cam3": "/abs/cam3"}
    topics = [
        f"{ns}/{t}"
        for ns in names.values()
        for t in ("correspondences", "keypoints", "camera_info")
    ]
    overlay = write_params_yaml(
        tmp_path / "p.yaml",
        {
            "cameras": list(names),
            "landmarks_file": str(keypoints_bag / "landmarks.csv"),
            "diagnostics_period": 0.2,
        },
        reliable_topics=topics,
    )
    rear = tmp_path / "rear.yaml"  # the rear camera's own section: its frames
    rear.write_text(
        "/multi/rear/rs_localizer:\n  ros__parameters:\n"
        "    camera_frame: rear_optical\n    base_frame: base_link\n"
    )
    node = NodeProcess(
        [CONFIG, overlay, rear], namespace="/multi", env=ros_env(), log=tmp_path / "multi.log"
    )
    clouds, info = _frames(sample_bag, 2)
    kps = [
        deserialize_message(raw, PointCloud2)
        for topic, _, _, raw in iter_messages(keypoints_bag, {"/camera/keypoints"})
    ][:1]
    ref = round(359.5 * 30e-6 * 1e9)
    probes = {}
    try:
        assert node.wait_ready(240, count=3), node.log
        # the process logs its summary after the last camera's ``ready`` line: wait for it too
        assert node.wait_ready(30, marker="3 cameras in this process:"), node.log
        assert (
            "3 cameras in this process: /multi/front, /multi/rear, /abs/cam3; "
            "1 map files loaded (1 in use)" in node.log
        ), node.log
        probes = {ns: Probe(ros_context, namespace=ns) for ns in names.values()}
        for pr in probes.values():
            pr.wait_matched()
        for k, (ns, pr) in enumerate(probes.items()):
            pr.pub_info.publish(info)
            msg = clouds[k % 2]
            pr.pub_corr.publish(msg)
            s = stamp_to_ns(msg.header.stamp) + ref
            assert pr.wait_pose(s, timeout=30) is not None, f"{ns}: no pose\n{node.log}"
            pr.pub_kp.publish(kps[0])
            s = stamp_to_ns(kps[0].header.stamp) + ref
            assert pr.wait_pose(s, timeout=30) is not None, f"{ns}: no keypoints pose\n{node.log}"
            assert pr.wait(lambda pr=pr: len(pr.outputs["twist"]) == 2, 10), (
                ns,
                len(pr.outputs["twist"]),
                node.log,
            )
            frame = pr.outputs["twist"][-1].header.frame_id
            assert frame == ("base_link" if ns == "/multi/rear" else "camera_optical_frame"), (
                ns,
                frame,
            )
        for ns, pr in probes.items():  # each camera counts its own frames
            st, v = pr.wait_diag(lambda v: int(v.get("frames_solved", 0)) == 2)
            assert st is not None and st.name.endswith(f"{ns}/rs_localizer"), (ns, st, node.log)
            assert int(v["frames_received"]) == 2, (ns, v, node.log)
        assert node.log.count("] ready:") == 3 or node.log.count("]: ready:") == 3
    finally:
        alive, rc = stop_node(node, *probes.values())
    assert alive and rc == 0, node.log


@pytest.mark.parametrize(
    "cams, error", [(["a", "a"], "listed twice"), (["", "b"], "empty camera namespace")]
)
def test_bad_camera_lists_are_clear_errors(tmp_path, ros_domain, cams, error):
    from helpers.paths import CONFIG
    from helpers.ros import refused_start

    from rs_localizer.ros.process import write_params_yaml

    overlay = write_params_yaml(tmp_path / "p.yaml", {"cameras": cams})
    exited, rc, log = refused_start(tmp_path, [CONFIG, overlay], "/badcams", 120)
    assert exited and rc == 1 and error in log, log


def test_runner_helpers():
    from rs_localizer.ros.runner import camera_namespaces, node_cli_args

    assert camera_namespaces(["front", "/abs/x", "rear/"], "/robot") == [
        "/robot/front",
        "/abs/x",
        "/robot/rear",
    ]
    assert camera_namespaces(["a"], "/") == ["/a"]
    with pytest.raises(ValueError):
        camera_namespaces(["a", "/a"], "/")
    argv = [
        "prog",
        "--ros-args",
        "-r",
        "__ns:=/robot",
        "--params-file",
        "p.yaml",
        "-r",
        "image:=image_raw",
        "--remap",
        "rs_localizer:__node:=x",
        "-p",
        "a:=1",
        "--",
        "other",
        "--ros-args",
        "--log-level",
        "info",
    ]
    assert node_cli_args(argv) == [
        "--ros-args",
        "--params-file",
        "p.yaml",
        "-r",
        "image:=image_raw",
        "-p",
        "a:=1",
        "--log-level",
        "info",
    ]
    assert node_cli_args(["prog"]) == []
