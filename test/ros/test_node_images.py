"""Image mode: the real node (``frontend: aruco``) on the rendered sample ``data/sample_images``.

The bag: 20 mono8 640x480 frames of the ``aruco_room`` scene under handheld shake (angular
speed 0.2-1.1 rad/s, linear speed ~0.3 m/s), 30 ms readout (62.5 us/line), markers 1-5 m away,
~279 ArUco corners per frame with ~0.2-0.3 px corner error (subpixel refinement on rendered,
noisy images). Offline, the same front end + estimator give r6p_1lin median/max errors of
0.009/0.043 deg, 0.7/2.0 mm, 0.064/0.17 rad/s and 0.23/0.55 m/s; p3p on the same corners has
0.42 deg / 2.6 cm median (the rolling-shutter distortion it cannot model).

Thresholds are ~3x the typical values: a wrong time scale, sign or frame (or falling back to a
global-shutter solution) gives errors of the size of the motion itself (p3p: >0.1 deg on every
frame, >0.5 cm, |w| error = |w| ~0.45 rad/s median), far beyond them. The linear velocity is
weakly observable here (9 mm of motion during the readout, seen from metres away: error ~0.23
m/s against a true speed of ~0.3 m/s), so its bound only catches gross errors.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("rosbags")

from helpers.paths import CONFIG, IMAGES_CONFIG
from helpers.ros import Probe, assert_dropped, start_node, stop_node

NS = "/img"
LIMITS = {  # key: (median, max); typical 0.009/0.043 deg, 0.7/2.0 mm, 0.064/0.17 rad/s,
    "rot_deg": (0.03, 0.15),  # 0.23/0.55 m/s
    "pos_m": (0.003, 0.008),
    "angvel": (0.2, 0.5),
    "linvel": (0.6, 1.2),
}
REF_OFFSET_NS = round(239.5 * 62.5e-6 * 1e9)  # stamp row 0 -> reference (centre) row 239.5
IMAGE_TOPIC, INFO_TOPIC = "/camera/image_raw", "/camera/camera_info"


def _node(tmp, ns, name, params=None):
    return start_node(
        tmp,
        {"diagnostics_period": 0.2, **(params or {})},
        namespace=ns,
        name=name,
        config=(CONFIG, IMAGES_CONFIG),
    )


@pytest.fixture(scope="module")
def node(tmp_path_factory, sample_images_bag):
    n = _node(tmp_path_factory.mktemp("img_node"), NS, "img")
    yield n
    alive = n.alive()
    rc = n.stop()
    assert alive, f"node died:\n{n.log}"
    assert rc == 0, f"node exit code {rc}:\n{n.log}"


def _bag_messages(bag):
    """rclpy Image and CameraInfo messages of the bag, and its correspondence clouds."""
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import CameraInfo, Image, PointCloud2

    from rs_localizer.ros.bags.bag_io import iter_messages

    types = {IMAGE_TOPIC: Image, INFO_TOPIC: CameraInfo, "/camera/correspondences": PointCloud2}
    out = {t: [] for t in types}
    for topic, _, _, raw in iter_messages(bag, set(types)):
        out[topic].append(deserialize_message(raw, types[topic]))
    return out


def test_sample_images_accuracy(node, ros_context, sample_images_bag):
    """Lock-step replay of the rendered bag's images: every frame solved, accurate, stamped at
    the reference row; the republished correspondences are the front end's output."""
    from rs_localizer.accuracy import summarize_errors
    from rs_localizer.ros.bags.accuracy import evaluate_outputs
    from rs_localizer.ros.bags.bag_io import load_ground_truth
    from rs_localizer.ros.bags.play import play
    from rs_localizer.ros.conversions import stamp_to_ns
    from rs_localizer.ros.pointcloud import read_correspondences

    outs = (f"{NS}/pose", f"{NS}/twist", f"{NS}/correspondences_out")
    res = play(
        sample_images_bag,
        lockstep=True,
        topics=[IMAGE_TOPIC, INFO_TOPIC],
        remap={IMAGE_TOPIC: f"{NS}/image", INFO_TOPIC: f"{NS}/camera_info"},
        output_topics=outs,
        context=ros_context,
        timeout=10.0,
        log=print,
        late_topics=(f"{NS}/twist",),
    )  # (the fused twist: a frame late)
    assert len(res.frames) == 20 and res.answered == 20, node.log
    gt = load_ground_truth(sample_images_bag)
    errs = evaluate_outputs(res.frames, gt, [NS])[NS]
    s = summarize_errors(errs)
    print("image-mode accuracy:", s)
    assert s["frames"] == 20
    for key, (med, mx) in LIMITS.items():
        assert s[key]["median"] < med, f"{key} median {s[key]['median']:.4g} >= {med}"
        assert s[key]["max"] < mx, f"{key} max {s[key]['max']:.4g} >= {mx}"

    from rs_localizer.frontends import make_frontend
    from rs_localizer.ros.image_codec import decode_image

    msgs = _bag_messages(sample_images_bag)
    images = {stamp_to_ns(m.header.stamp): m for m in msgs[IMAGE_TOPIC]}
    clouds = {
        stamp_to_ns(c.header.stamp): read_correspondences(c)
        for c in msgs["/camera/correspondences"]
    }
    fe = make_frontend("aruco", "aruco_room")  # IMAGES_CONFIG's front end, here
    n_bag = n_bag_found = 0
    uv_dev = []
    for f in res.frames:
        pose = f["outputs"][f"{NS}/pose"][1]
        twist = f["outputs"][f"{NS}/twist"][1]
        stamp = stamp_to_ns(pose.header.stamp)
        assert stamp - f["stamp"] == REF_OFFSET_NS  # image stamp = row 0, pose at row 239.5
        assert stamp in gt.orientation
        assert pose.header.frame_id == "map"
        assert twist.header.frame_id == "camera_optical_frame"
        cout = f["outputs"][f"{NS}/correspondences_out"][1]
        assert stamp_to_ns(cout.header.stamp) == f["stamp"]
        assert cout.header.frame_id == "camera_optical_frame"
        mine = read_correspondences(cout)
        # the node republishes its front end's output: the same front end on the same image
        img, encoding = decode_image(images[f["stamp"]])
        uv, xyz, ids = fe.process(img, encoding=encoding)
        assert len(mine.uv) == len(uv) > 200
        np.testing.assert_allclose(mine.uv, uv, atol=1e-3)
        np.testing.assert_allclose(mine.xyz, xyz, atol=1e-6)
        assert mine.ids is not None and np.array_equal(mine.ids, ids)
        assert len(np.unique(mine.ids)) == len(mine.ids)
        # and it is the bag's front-end output up to the OpenCV version (4.6 finds a few more
        # markers here than 5.0, which recorded the bag; 99% of common corners within 1e-4 px)
        ref = clouds[f["stamp"]]
        at = {int(i): k for k, i in enumerate(mine.ids)}
        found = [k for k, i in enumerate(ref.ids) if int(i) in at]
        n_bag += len(ref.ids)
        n_bag_found += len(found)
        uv_dev += [np.abs(mine.uv[at[int(ref.ids[k])]] - ref.uv[k]).max() for k in found]
    assert n_bag_found >= 0.98 * n_bag, (n_bag_found, n_bag)
    assert np.median(uv_dev) < 1e-3 and np.quantile(uv_dev, 0.99) < 0.05, np.quantile(
        uv_dev, [0.5, 0.99, 1]
    )

    probe = Probe(ros_context, namespace=NS)
    try:
        _st, v = probe.wait_diag(lambda v: int(v.get("frames_solved", 0)) >= 20)
        assert v.get("frontend") == "aruco" and int(v["image_frames"]) >= 20, v
        assert 200 < float(v["frontend_correspondences_mean"]) < 320, v
        assert 0 < float(v["frontend_ms_median"]) < 2000, v
        assert 0 < float(v["frontend_ms_last"]) < 2000, v
    finally:
        probe.close()


def test_frontend_map_parameter(node, ros_context, sample_images_bag):
    """frontend is read-only; frontend_map reloads, a bad map is rejected and changes nothing."""
    from helpers.ros import ParamClient

    params = ParamClient(ros_context, f"{NS}/rs_localizer")
    try:
        (r,) = params.set(frontend="features")
        assert not r.successful  # read-only
        (r,) = params.set(frontend_map="/nonexistent/markers.yaml")
        assert not r.successful and "cannot load frontend_map" in r.reason, r.reason
        (r,) = params.set(frontend_map=str(sample_images_bag / "markers.yaml"))
        assert r.successful, r.reason
    finally:
        params.close()
    assert "reloaded the aruco front end" in node.log
    assert "marker detector: OpenCV ArUco, DICT_4X4_250" in node.log  # which detector runs


def test_bad_images(tmp_path, ros_context, sample_images_bag):
    """Bad images are dropped and counted with their reason; the next valid image is solved."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image
    from std_msgs.msg import Header

    from rs_localizer.ros.conversions import ns_to_stamp, stamp_to_ns

    msgs = _bag_messages(sample_images_bag)
    images, info = msgs[IMAGE_TOPIC], msgs[INFO_TOPIC][0]
    ns = "/img_bad"
    node = _node(tmp_path, ns, "img_bad", {"republish_correspondences": False})
    probe = Probe(ros_context, namespace=ns)
    pub = probe.node.create_publisher(
        Image, f"{ns}/image", QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    )
    try:
        probe.wait_matched()
        assert probe.wait(lambda: pub.get_subscription_count() > 0, 30)
        probe.pub_info.publish(info)
        probe.wait_camera_info()
        sent = {"images": 0}
        expected = {}
        frames = iter(images)

        def copy(m, **changes):
            header = Header(
                stamp=ns_to_stamp(stamp_to_ns(m.header.stamp)), frame_id=m.header.frame_id
            )
            out = Image(
                header=header,
                height=m.height,
                width=m.width,
                encoding=m.encoding,
                is_bigendian=m.is_bigendian,
                step=m.step,
                data=m.data,
            )
            for k, v in changes.items():
                setattr(out, k, v)
            return out

        def restamp(m, stamp_ns):
            out = copy(m)
            out.header.stamp = ns_to_stamp(stamp_ns)
            return out

        def bad(m, reason):
            pub.publish(m)
            sent["images"] += 1
            expected[reason] = expected.get(reason, 0) + 1

        def good(m):
            pub.publish(m)
            sent["images"] += 1
            stamp = stamp_to_ns(m.header.stamp)
            pose = probe.wait_pose(stamp + REF_OFFSET_NS, timeout=20)
            assert pose is not None, f"no pose for a valid image after {expected}:\n{node.log}"

        good(next(frames))
        f = next(frames)
        s = stamp_to_ns(f.header.stamp)
        bad(copy(restamp(f, s - 1), encoding="mono16"), "bad_image")  # wrong encoding
        good(f)
        f = next(frames)
        s = stamp_to_ns(f.header.stamp)
        bad(copy(restamp(f, s - 1), data=bytes(f.data)[:-1000]), "bad_image")  # truncated
        good(f)
        f = next(frames)
        s = stamp_to_ns(f.header.stamp)
        bad(copy(restamp(f, s - 1), height=0, width=0, step=0, data=b""), "bad_image")  # empty
        img = np.frombuffer(bytes(f.data), np.uint8).reshape(f.height, f.step)[:, : f.width]
        half = np.ascontiguousarray(img[::2, ::2])
        bad(
            copy(
                restamp(f, s - 1),
                height=half.shape[0],
                width=half.shape[1],
                step=half.shape[1],
                data=half.tobytes(),
            ),
            "image_size_mismatch",
        )
        blank = np.full_like(img, 128)
        bad(copy(restamp(f, s - 1), data=blank.tobytes()), "frontend_too_few_points")
        good(f)
        # other valid layouts: rgb8, bgr8 and a mono8 image with row padding
        f = next(frames)
        img = np.frombuffer(bytes(f.data), np.uint8).reshape(f.height, f.step)[:, : f.width]
        rgb = np.repeat(img[:, :, None], 3, axis=2)
        good(copy(f, encoding="rgb8", step=3 * f.width, data=rgb.tobytes()))
        f = next(frames)
        img = np.frombuffer(bytes(f.data), np.uint8).reshape(f.height, f.step)[:, : f.width]
        good(
            copy(
                f,
                encoding="bgr8",
                step=3 * f.width,
                data=np.repeat(img[:, :, None], 3, axis=2).tobytes(),
            )
        )
        f = next(frames)
        img = np.frombuffer(bytes(f.data), np.uint8).reshape(f.height, f.step)[:, : f.width]
        padded = np.zeros((f.height, f.width + 16), np.uint8)
        padded[:, : f.width] = img
        good(copy(f, step=f.width + 16, data=padded.tobytes()))
        n_good = 7

        st, v = probe.wait_diag(
            lambda v: (
                int(v.get("image_frames", 0)) == sent["images"] and v.get("frames_pending") == "0"
            )
        )  # (all solved or failed)
        assert int(v["image_frames"]) == int(v["frames_received"]) == sent["images"], v
        log = assert_dropped(node, st, v, expected)
        assert int(v["frames_failed"]) == sum(expected.values()), v
        assert int(v["frames_solved"]) == n_good == len(probe.outputs["pose"]), v
        assert "unsupported image encoding 'mono16'" in log
    finally:
        alive, rc = stop_node(node, probe)
    assert alive and rc == 0, node.log


@pytest.mark.slow
@pytest.mark.parametrize(
    "params, message",
    [
        ({"frontend_map": "/nonexistent/markers.yaml"}, "cannot load frontend_map"),
        ({"frontend": "apriltag"}, "unknown frontend 'apriltag'"),
        ({"frontend_map": ""}, "frontend aruco needs frontend_map"),
    ],
)
def test_bad_frontend_parameters_are_clear_errors(tmp_path, ros_domain, params, message):
    from helpers.ros import refused_start

    from rs_localizer.ros.process import write_params_yaml

    overlay = write_params_yaml(tmp_path / "p.yaml", params)
    exited, rc, log = refused_start(tmp_path, [CONFIG, IMAGES_CONFIG, overlay], "/img_err", 60)
    assert exited and rc != 0
    assert message in log, log


def test_debug_image_on_the_input_image(node, ros_context, sample_images_bag):
    """Image mode: ``debug_image`` is the input image (dimmed to 0.7) under the overlay, with
    the marker corners the front end found drawn as inliers, stamped like the image."""
    import cv2
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    from rs_localizer.ros.conversions import ns_to_stamp, stamp_to_ns
    from rs_localizer.ros.image_codec import decode_image
    from rs_localizer.ros.pointcloud import read_correspondences
    from rs_localizer.viz import COLORS

    msgs = _bag_messages(sample_images_bag)
    frame, info = msgs[IMAGE_TOPIC][6], msgs[INFO_TOPIC][0]
    corners = read_correspondences(msgs["/camera/correspondences"][6]).uv
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    probe = Probe(ros_context, namespace=NS)
    pub = probe.node.create_publisher(Image, f"{NS}/image", qos)
    got = []
    probe.node.create_subscription(Image, f"{NS}/debug_image", got.append, qos)
    try:
        probe.wait_matched()
        assert probe.wait(
            lambda: (
                pub.get_subscription_count() > 0
                and probe.node.count_publishers(f"{NS}/debug_image") > 0
            ),
            30,
        )
        probe.pub_info.publish(info)
        probe.spin(0.3)
        stamp = stamp_to_ns(frame.header.stamp) + 2000 * 10**9  # after every earlier frame
        frame.header.stamp = ns_to_stamp(stamp)
        pub.publish(frame)
        assert probe.wait_pose(stamp + REF_OFFSET_NS, timeout=20) is not None, node.log
        assert probe.wait(lambda: len(got) > 0, 10)
        im = got[0]
        assert stamp_to_ns(im.header.stamp) == stamp
        assert (im.encoding, im.width, im.height) == ("bgr8", 640, 480)
        img, _ = decode_image(im)
        raw, _ = decode_image(frame)
        dimmed = cv2.cvtColor(cv2.convertScaleAbs(raw, alpha=0.7), cv2.COLOR_GRAY2BGR)
        assert (img == dimmed).all(axis=2).mean() > 0.8
        p = np.round(corners).astype(int)
        p = p[p[:, 1] >= 50]  # below the text band
        green = (img[p[:, 1], p[:, 0]] == COLORS["inlier"]).all(axis=1)
        assert len(p) > 200 and green.mean() > 0.9, green.mean()
    finally:
        probe.close()


@pytest.mark.slow  # (a node of its own in the bag's namespace)
def test_play_sends_a_frontend_node_its_images(tmp_path, ros_context, sample_images_bag):
    """``play`` of the rendered bag (``/camera/image_raw``, ``camera_info`` and the
    correspondences the renderer computed from the true map) into a node running the ArUco
    front end on ``/camera/image``: the images go out, on the node's image topic, and the
    correspondences stay in the bag; played with ``--source correspondences`` instead, the
    node counts them (``frames_beside_frontend``) and says so once, naming both topics."""
    from rs_localizer.ros.bags.play import play

    node = _node(tmp_path, "/camera", "cam")
    probe = Probe(ros_context, namespace="/camera")
    try:
        notes = []
        res = play(sample_images_bag, lockstep=True, limit=4, timeout=10.0,
                   context=ros_context, log=notes.append)  # fmt: skip
        assert res.answered == len(res.frames) == 4, (notes, node.log)
        assert {f["topic"] for f in res.frames} == {IMAGE_TOPIC}
        assert res.skipped_topics == ["/camera/correspondences"], notes
        assert f"note: playing {IMAGE_TOPIC} as /camera/image" in "\n".join(notes)
        _st, v = probe.wait_diag(lambda v: int(v.get("frames_solved", 0)) >= 4)
        assert int(v["image_frames"]) == 4 and int(v["frames_beside_frontend"]) == 0, v

        res = play(sample_images_bag, lockstep=True, limit=3, timeout=10.0,
                   context=ros_context, log=notes.append, source="correspondences")  # fmt: skip
        assert {f["topic"] for f in res.frames} == {"/camera/correspondences"}
        _st, v = probe.wait_diag(lambda v: int(v.get("frames_beside_frontend", 0)) >= 3)
        assert int(v["frames_beside_frontend"]) == 3 and int(v["image_frames"]) == 4, v
        warning = (
            "received correspondences on /camera/correspondences while the aruco front end "
            "runs on /camera/image"
        )
        assert node.log.count(warning) == 1, node.log
    finally:
        alive, rc = stop_node(node, probe)
    assert alive and rc == 0, node.log
