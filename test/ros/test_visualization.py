"""The visualization topics: message content (markers against the pose, the debug image pixel
by pixel), built only when subscribed, published by the real node over DDS, and written by
``rs-localizer replay --debug-outputs``.

Pixel checks on estimator output use the synthetic sequence's ground-truth labels: a true
inlier (0.5 px noise, 2 px threshold) is an inlier of the estimate; a true outlier (a random
pixel) is almost never within 2 px of its prediction. Points can cover each other (500 discs of
radius 3 px on 1280x720), so the checks ask for >= 90 % (inliers) and >= 80 % (outliers) of the
labelled pixels, not all.
"""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("rosbags")

from helpers.debug_frames import K, known_frame
from helpers.ros import Probe, start_node, stop_node

from rs_localizer.camera import CameraModel
from rs_localizer.viz import COLORS

TEXT_BAND_PX = 100  # rows of the text band at 1280 px width (the labels under it are skipped)


def _colour_fractions(img, uv, labels):
    """Fraction of the labelled inliers drawn green and of the labelled outliers drawn red
    (points under the text band skipped)."""
    p = np.round(uv).astype(int)
    keep = p[:, 1] >= TEXT_BAND_PX
    px = img[p[keep, 1], p[keep, 0]]
    lab = labels[keep]
    green = (px == COLORS["inlier"]).all(axis=1)
    red = (px == COLORS["outlier"]).all(axis=1)
    return green[lab].mean(), red[~lab].mean()


def _far_corners_back_to_image(markers_points, orientation, position, camera):
    """Project the frustum's far corners (map) back into the image with the pose (OpenCV)."""
    import cv2

    R = np.asarray(orientation).T
    C = -R @ np.asarray(position)
    far = np.array([[p.x, p.y, p.z] for p in markers_points[1:8:2]])
    D = camera.D if camera.has_distortion else None
    back, _ = cv2.projectPoints(far, cv2.Rodrigues(R)[0], C, camera.K, D)
    return back.reshape(-1, 2)


def test_marker_array_against_the_pose():
    from visualization_msgs.msg import Marker

    from rs_localizer.ros.bags.bag_io import typestore
    from rs_localizer.ros.bags.replay_out import to_cdr
    from rs_localizer.ros.visualization import marker_array

    cam = CameraModel(K, [], 640, 480, line_delay=60e-6)
    _, X, est, _ = known_frame(cam)
    ma = marker_array(est, X, cam, 123_456_789, "world", frustum_depth=0.8, arrow_scale=0.5)
    m = {x.ns: x for x in ma.markers}
    assert set(m) == {"frustum", "angular_velocity", "linear_velocity", "inliers"}
    for x in ma.markers:  # map coordinates: identity pose, map frame, no TF needed
        assert x.header.frame_id == "world" and x.header.stamp.nanosec == 123_456_789
        assert (x.pose.orientation.w, x.pose.orientation.x, x.pose.position.z) == (1.0, 0, 0)
        assert x.color.a == 1.0 and x.action == Marker.ADD
    fr = m["frustum"]
    assert fr.type == Marker.LINE_LIST and len(fr.points) == 16 and fr.scale.x > 0
    P = np.array([[p.x, p.y, p.z] for p in fr.points])
    np.testing.assert_allclose(P[0:8:2], np.tile(est.pose.position, (4, 1)), atol=1e-12)
    # far corners: K^-1 of the pixel corners at 0.8 m along the optical axis, into the map
    px = np.array([[-0.5, -0.5], [639.5, -0.5], [639.5, 479.5], [-0.5, 479.5]])
    rays = np.c_[px, np.ones(4)] @ np.linalg.inv(K).T * 0.8
    np.testing.assert_allclose(
        P[1:8:2], rays @ est.pose.orientation.T + est.pose.position, atol=1e-9
    )
    np.testing.assert_allclose(P[9::2], np.roll(P[1:8:2], -1, axis=0), atol=1e-12)
    for ns, vel in (
        ("angular_velocity", est.pose.angular_velocity),
        ("linear_velocity", est.pose.linear_velocity),
    ):
        a = m[ns]
        assert a.type == Marker.ARROW and len(a.points) == 2 and a.scale.x > 0
        s, e = (np.array([p.x, p.y, p.z]) for p in a.points)
        np.testing.assert_allclose(s, est.pose.position, atol=1e-12)
        np.testing.assert_allclose(e - s, 0.5 * est.pose.orientation @ vel, atol=1e-9)
    pts = m["inliers"]
    assert pts.type == Marker.POINTS and pts.scale.x > 0
    np.testing.assert_allclose([[p.x, p.y, p.z] for p in pts.points], X[est.inliers])
    # global shutter (zero twist): the arrows are deleted, not drawn with zero length
    from dataclasses import replace

    gs = replace(est, pose=est.pose.with_twist(np.zeros(3), np.zeros(3)))
    m2 = {x.ns: x for x in marker_array(gs, X, cam, 0, "map").markers}
    assert m2["angular_velocity"].action == Marker.DELETE
    # the messages survive a bag round trip (rosbags typestore)
    ts = typestore()
    back = ts.deserialize_cdr(
        to_cdr(ma, "visualization_msgs/msg/MarkerArray", ts), "visualization_msgs/msg/MarkerArray"
    )
    assert len(back.markers[3].points) == est.num_inliers


def test_debug_image_message_roundtrip():
    from rs_localizer.ros.image_codec import decode_image
    from rs_localizer.ros.visualization import debug_image_msg

    img = np.random.default_rng(0).integers(0, 255, (48, 64, 3), dtype=np.uint8)
    msg = debug_image_msg(img, 5_000_000_001, "cam")
    assert (msg.encoding, msg.step, msg.header.frame_id) == ("bgr8", 192, "cam")
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (5, 1)
    back, enc = decode_image(msg)
    assert enc == "bgr8"
    np.testing.assert_array_equal(back, img)


def test_built_only_when_subscribed(ros_context):
    """No subscriber: nothing is drawn or built (the path still records the pose); a
    subscriber on one topic: only that message is built and it arrives."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    from rs_localizer.ros.visualization import NodeVisualization

    node = rclpy.create_node("viz_gate", namespace="/gate", context=ros_context)
    viz = NodeVisualization(node)
    built = {"debug_image": 0, "markers": 0, "path": 0}
    for name in built:
        fn = getattr(viz.builder, name)

        def counted(*a, name=name, fn=fn, **k):
            built[name] += 1
            return fn(*a, **k)

        setattr(viz.builder, name, counted)
    cam = CameraModel(K, [], 640, 480, line_delay=60e-6)
    uv, X, est, _ = known_frame(cam)
    viz.publish(est, uv, X, cam, 1000, 2000, "cam", "map")
    assert built == {"debug_image": 0, "markers": 0, "path": 0}
    assert len(viz.builder.poses) == 1

    listener = rclpy.create_node("viz_listener", context=ros_context)
    got = []
    listener.create_subscription(
        Image,
        "/gate/debug_image",
        got.append,
        QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE),
    )
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    ex.add_node(listener)
    try:
        end = time.monotonic() + 20
        while viz.pub_image.get_subscription_count() == 0 and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        assert viz.pub_image.get_subscription_count() == 1
        viz.set_image(np.full((480, 640), 100, np.uint8), "mono8", 3000)
        viz.publish(est, uv, X, cam, 3000, 4000, "cam", "map")
        assert viz.wait_drawn()
        assert built == {"debug_image": 1, "markers": 0, "path": 0}
        end = time.monotonic() + 10
        while not got and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        assert len(got) == 1 and got[0].header.stamp.nanosec == 3000
        from rs_localizer.ros.image_codec import decode_image

        img, _ = decode_image(got[0])
        assert tuple(img[455, 300]) == (70, 70, 70)  # 0.7 x the input image
        # an image of another stamp is not drawn under this frame
        viz.set_image(np.full((480, 640), 100, np.uint8), "mono8", 5000)
        viz.publish(est, uv, X, cam, 6000, 7000, "cam", "map")
        end = time.monotonic() + 10
        while len(got) < 2 and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        img, _ = decode_image(got[1])
        assert tuple(img[455, 300]) == (40, 40, 40)  # the blank canvas
        assert len(viz.builder.poses) == 3

        def broken(*a, **k):
            raise ValueError("drawing failed")

        viz.builder.debug_image = broken  # logged, not raised: the frame is not lost
        viz.publish(est, uv, X, cam, 8000, 9000, "cam", "map")
        assert viz.wait_drawn()
        assert len(viz.builder.poses) == 4
    finally:
        viz.close()
        ex.shutdown()
        listener.destroy_node()
        node.destroy_node()


def test_node_publishes_visualization(tmp_path, ros_context):
    """The real node over DDS (correspondence mode): debug_image on a canvas of the camera
    size with the labelled points in their colours, markers whose frustum sits at the published
    pose, and the path of every pose so far."""
    from nav_msgs.msg import Path
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image
    from visualization_msgs.msg import MarkerArray

    from rs_localizer.geometry import rotation_angle_deg
    from rs_localizer.ros import pointcloud as pc
    from rs_localizer.ros.conversions import camera_info_msg, pose_from_msg, stamp_to_ns
    from rs_localizer.ros.image_codec import decode_image
    from rs_localizer.sim.trajectory import SequenceConfig, generate_sequence

    frames, _, cam, _ = generate_sequence(SequenceConfig(num_frames=4, num_points=500, seed=7))
    node = start_node(
        tmp_path,
        {"viz.frustum_depth": 0.7, "diagnostics_period": 0.2},
        namespace="/viz",
        name="viz",
    )
    probe = Probe(ros_context, namespace="/viz")
    got = {"debug_image": [], "markers": [], "path": []}
    qos = QoSProfile(depth=20, reliability=ReliabilityPolicy.RELIABLE)
    for name, t in (("debug_image", Image), ("markers", MarkerArray), ("path", Path)):
        probe.node.create_subscription(t, f"/viz/{name}", got[name].append, qos)
    try:
        probe.wait_matched()
        assert probe.wait(lambda: all(probe.node.count_publishers(f"/viz/{n}") for n in got))
        probe.pub_info.publish(camera_info_msg(cam, "cam", frames[0].stamp_ns))
        probe.wait_diag(lambda v: v.get("camera") == "camera_info")
        for k, f in enumerate(frames):
            probe.pub_corr.publish(
                pc.correspondence_cloud(f.uv, f.xyz, frame_id="cam", stamp=f.stamp_ns)
            )
            assert probe.wait_pose(f.t_ref_ns, timeout=20) is not None, node.log
            assert probe.wait(lambda k=k: all(len(v) > k for v in got.values())), {
                n: len(v) for n, v in got.items()
            }
            pose = probe.pose_near(f.t_ref_ns)
            R, p = pose_from_msg(pose.pose)
            assert rotation_angle_deg(R, f.orientation) < 0.2
            im = got["debug_image"][k]
            assert (im.encoding, im.width, im.height) == ("bgr8", 1280, 720)
            assert stamp_to_ns(im.header.stamp) == f.stamp_ns and im.header.frame_id == "cam"
            img, _ = decode_image(im)
            green, red = _colour_fractions(img, f.uv, f.inlier)
            assert green >= 0.9 and red >= 0.8, (green, red)
            ma = got["markers"][k]
            fr = next(m for m in ma.markers if m.ns == "frustum")
            assert fr.header.frame_id == "map" and stamp_to_ns(fr.header.stamp) == f.t_ref_ns
            apex = fr.points[0]
            np.testing.assert_allclose([apex.x, apex.y, apex.z], p, atol=1e-9)
            back = _far_corners_back_to_image(fr.points, R, p, cam)
            np.testing.assert_allclose(
                back, [[-0.5, -0.5], [1279.5, -0.5], [1279.5, 719.5], [-0.5, 719.5]], atol=1e-3
            )
            far = np.array([[q.x, q.y, q.z] for q in fr.points[1:8:2]])
            np.testing.assert_allclose((far - p) @ R[:, 2], 0.7, atol=1e-9)  # viz.frustum_depth
            inl = next(m for m in ma.markers if m.ns == "inliers")
            assert abs(len(inl.points) - f.inlier.sum()) <= 0.05 * f.inlier.sum()
            path = got["path"][k]
            assert path.header.frame_id == "map" and len(path.poses) == k + 1
            assert stamp_to_ns(path.poses[-1].header.stamp) == f.t_ref_ns
            assert path.poses[-1].pose == pose.pose
    finally:
        alive, rc = stop_node(node, probe)
    assert alive and rc == 0, node.log


# ------------------------------------------------------------------------------ replay
@pytest.fixture(scope="module")
def labelled_bag(tmp_path_factory):
    """A 3-frame correspondence bag and its frames (ground-truth inlier labels)."""
    from rs_localizer.ros.bags.bag_io import write_sequence_bag
    from rs_localizer.sim.trajectory import SequenceConfig, generate_sequence

    frames, scene, cam, _ = generate_sequence(SequenceConfig(num_frames=3, num_points=500, seed=11))
    path = write_sequence_bag(
        tmp_path_factory.mktemp("viz_bag") / "bag", frames, scene, cam, keypoints=False
    )
    return path, frames, cam


def _topic_messages(bag, topic):
    from rs_localizer.ros.bags.bag_io import iter_messages, typestore

    ts = typestore()
    return [ts.deserialize_cdr(raw, mt) for _, mt, _, raw in iter_messages(bag, {topic})]


def test_replay_writes_the_visualization(labelled_bag, tmp_path, capsys):
    from rs_localizer.cli import main as cli
    from rs_localizer.ros.bags.bag_io import bag_topics
    from rs_localizer.ros.conversions import pose_from_msg, stamp_to_ns
    from rs_localizer.ros.image_codec import decode_image

    bag, frames, cam = labelled_bag
    out = tmp_path / "out"
    rc = cli(
        [
            "replay",
            str(bag),
            "--out",
            str(out),
            "--debug-outputs",
            "--path-length",
            "2",
            "--json",
            "--quiet",
        ]
    )
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    summary = json.loads(cap.out)  # --json: stdout is the JSON and nothing else
    assert summary["solved"] == summary["frames_total"] == 3
    assert "solved 3/3" in cap.err and "debug_image" in cap.err
    topics = bag_topics(out)
    assert topics["/rs_localizer/debug_image"] == "sensor_msgs/msg/Image"
    assert topics["/rs_localizer/markers"] == "visualization_msgs/msg/MarkerArray"
    assert topics["/rs_localizer/path"] == "nav_msgs/msg/Path"
    images = _topic_messages(out, "/rs_localizer/debug_image")
    markers = _topic_messages(out, "/rs_localizer/markers")
    paths = _topic_messages(out, "/rs_localizer/path")
    poses = _topic_messages(out, "/rs_localizer/pose")
    assert len(images) == len(markers) == len(paths) == len(poses) == 3
    for f, im, ma, path, pose in zip(frames, images, markers, paths, poses, strict=True):
        assert stamp_to_ns(im.header.stamp) == f.stamp_ns
        img, enc = decode_image(im)
        assert enc == "bgr8" and img.shape == (720, 1280, 3)
        green, red = _colour_fractions(img, f.uv, f.inlier)
        assert green >= 0.9 and red >= 0.8, (green, red)
        R, p = pose_from_msg(pose.pose)
        fr = next(m for m in ma.markers if m.ns == "frustum")
        back = _far_corners_back_to_image(fr.points, R, p, cam)
        np.testing.assert_allclose(
            back, [[-0.5, -0.5], [1279.5, -0.5], [1279.5, 719.5], [-0.5, 719.5]], atol=1e-3
        )
        assert stamp_to_ns(path.poses[-1].header.stamp) == stamp_to_ns(pose.header.stamp)
    assert [len(p.poses) for p in paths] == [1, 2, 2]  # --path-length 2
    # export-image writes the bag's image as PNG (full colour: the same pixels)
    import cv2

    assert cli(["export-image", str(out), str(tmp_path / "d.png"), "--index", "1"]) == 0
    np.testing.assert_array_equal(cv2.imread(str(tmp_path / "d.png")), decode_image(images[1])[0])
    assert cli(["export-image", str(out), str(tmp_path / "p.png"), "--colors", "16"]) == 0
    assert cv2.imread(str(tmp_path / "p.png")).shape == (720, 1280, 3)
    assert cli(["export-image", str(out), str(tmp_path / "x.png"), "--index", "3"]) == 2
    assert (
        cli(["export-image", str(out), str(tmp_path / "x.png"), "--topic", "/rs_localizer/pose"])
        == 2
    )
    # without --debug-outputs: no visualization topics
    rc = cli(["replay", str(bag), "--out", str(tmp_path / "plain"), "--quiet"])
    assert rc == 0 and "/rs_localizer/debug_image" not in bag_topics(tmp_path / "plain")
    # --debug-outputs without --out is an error
    assert cli(["replay", str(bag), "--debug-outputs", "--quiet"]) == 2


def test_replay_draws_on_the_bag_images(sample_images_bag, tmp_path):
    """An image bag (render-bag): the debug image is the bag's image of the same stamp,
    dimmed to 0.7, under the overlay."""
    import cv2

    from rs_localizer.ros.bags.replay import replay
    from rs_localizer.ros.image_codec import decode_image

    res = replay(sample_images_bag, out_bag=tmp_path / "out", debug_outputs=True, progress=None)
    assert res.solved == 20
    raw = {
        im.header.stamp.sec * 10**9 + im.header.stamp.nanosec: decode_image(im)[0]
        for im in _topic_messages(sample_images_bag, "/camera/image_raw")[::7]
    }
    debug = _topic_messages(tmp_path / "out", "/rs_localizer/debug_image")
    assert len(debug) == 20
    n = 0
    for im in debug:
        stamp = im.header.stamp.sec * 10**9 + im.header.stamp.nanosec
        if stamp not in raw:
            continue
        n += 1
        img, _ = decode_image(im)
        dimmed = cv2.cvtColor(cv2.convertScaleAbs(raw[stamp], alpha=0.7), cv2.COLOR_GRAY2BGR)
        same = (img == dimmed).all(axis=2)
        assert same.mean() > 0.8, same.mean()  # the rest: points, cube, text band
        assert same[:20].mean() < 0.5  # the text band is not the image
    assert n == 3


def test_viz_parameters_documented_in_the_config():
    """config/rs_localizer.yaml (every parameter with its default) lists the viz.* ones."""
    import yaml
    from helpers.paths import CONFIG

    from rs_localizer.ros.visualization import VIZ_PARAMETERS

    cfg = yaml.safe_load(CONFIG.read_text())["/**"]["ros__parameters"]["viz"]
    assert {f"viz.{k}": v for k, v in cfg.items()} == {k: d[0] for k, d in VIZ_PARAMETERS.items()}
    node_doc = (CONFIG.parents[1] / "docs" / "node.md").read_text()
    for k, (default, _, _) in VIZ_PARAMETERS.items():
        assert f"| `{k}` | `{default}` |" in node_doc, k


def test_the_input_image_is_held_only_for_a_debug_image_subscriber():
    """Decoded input images can be hundreds of MB: the visualization keeps one only while
    ``debug_image`` has a subscriber, and lets it go when its frame is not solved."""
    from types import SimpleNamespace

    from rs_localizer.ros.visualization import NodeVisualization

    subscribers = [0]
    viz = object.__new__(NodeVisualization)  # (the publishers alone, without a node)
    viz.pub_image = SimpleNamespace(get_subscription_count=lambda: subscribers[0])
    viz._image = None
    image = np.zeros((8, 8), np.uint8)
    viz.set_image(image, "mono8", 5)
    assert viz._image is None
    subscribers[0] = 1
    viz.set_image(image, "mono8", 5)
    assert viz._image[0] is image
    viz.clear_image()
    assert viz._image is None
