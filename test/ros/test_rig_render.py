"""Rendered rig bags: ``render-bag --rig`` renders unsynchronized rolling-shutter cameras in the
closed AprilTag room, writes their images, camera_info and the front end's correspondences;
``replay`` poses the rig against the truth; one reader serves replay and calibrate-rig; the
rig-frame grouping play waits on is the rig mode's own; ``play --lockstep`` runs the bag through
the rig node over DDS."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
from helpers.ros import spinning

pytest.importorskip("rosbags")

FRAMES = 10


@pytest.fixture(scope="module")
def rendered_rig_bag(tmp_path_factory):
    from rs_localizer.cli import main

    bag = tmp_path_factory.mktemp("rigrender") / "rig"
    args = ["render-bag", str(bag), "--rig", "3", "--frames", str(FRAMES), "--quiet"]
    assert main(args) == 0
    return bag


@pytest.mark.slow  # (renders the rig bag)
def test_render_bag_rig_writes_every_camera_and_replays(rendered_rig_bag, capsys):
    from rs_localizer.cli import main
    from rs_localizer.maps.markers import load_marker_map
    from rs_localizer.ros.bags.bag_io import bag_topics, iter_messages, typestore
    from rs_localizer.ros.param_files import read_params_file
    from rs_localizer.ros.pointcloud import read_correspondences

    bag = rendered_rig_bag
    topics = bag_topics(bag)
    names = ("front", "left", "right")
    for n in names:
        assert topics[f"/rig/{n}/image_raw"] == "sensor_msgs/msg/Image"
        assert topics[f"/rig/{n}/correspondences"] == "sensor_msgs/msg/PointCloud2"
        assert topics[f"/rig/{n}/camera_info"] == "sensor_msgs/msg/CameraInfo"
    meta = json.loads((bag / "sequence.json").read_text())
    cams = meta["rig"]["cameras"]
    assert [c["name"] for c in cams] == list(names)
    # different line delays and readout directions, first frames at most 10 ms apart
    assert len({c["line_delay"] for c in cams}) == 3 and len({c["direction"] for c in cams}) == 3
    offsets = [c["offset_s"] for c in cams]
    assert 0 < max(offsets) - min(offsets) <= 0.010
    p = read_params_file(bag / "rig_params.yaml")
    assert p["rig.cameras"] == list(names)
    # images 640x480 rgb8; every correspondence is the map's corner of its id
    _, corners = load_marker_map(bag / "markers.yaml")
    ts = typestore()
    n_img = {n: 0 for n in names}
    wanted = {f"/rig/{n}/{t}" for n in names for t in ("image_raw", "correspondences")}
    for topic, mt, _, raw in iter_messages(bag, wanted):
        msg = ts.deserialize_cdr(raw, mt)
        cam = topic.split("/")[2]
        if topic.endswith("image_raw"):
            assert (msg.width, msg.height, msg.encoding) == (640, 480, "rgb8")
            n_img[cam] += 1
            continue
        c = read_correspondences(msg)
        assert len(c.ids) >= 4
        X = np.array([corners[int(i) // 4][int(i) % 4] for i in c.ids])
        assert np.allclose(X, c.points, atol=1e-5)
    assert n_img == {n: FRAMES for n in names}
    capsys.readouterr()
    assert main(["replay", str(bag), "--quiet", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["frames_total"] == s["solved"] == FRAMES
    assert s["rot_deg"]["median"] < 0.2 and s["pos_m"]["median"] < 0.01


@pytest.mark.slow  # (renders the rig bag)
def test_one_reader_for_replay_and_calibrate_rig(rendered_rig_bag):
    """``read_rig_frames`` (calibrate-rig) and ``replay`` read a rig's frames through
    ``iter_rig_frames``: every correspondences message once, with its camera's model."""
    from rs_localizer.ros.bags.bag_frames import (
        QuietLog,
        iter_rig_frames,
        read_rig_frames,
        rig_bag_config,
    )
    from rs_localizer.ros.bags.bag_io import iter_messages, typestore
    from rs_localizer.ros.bags.replay import replay
    from rs_localizer.ros.camera_input import rig_camera_inputs

    bag = rendered_rig_bag
    frames = read_rig_frames(bag).frames
    meta = json.loads((bag / "sequence.json").read_text())
    by = {c["name"]: c for c in meta["rig"]["cameras"]}
    ts = typestore()
    expected = [
        (t.split("/")[2], ts.deserialize_cdr(raw, mt).header.stamp)
        for t, mt, _, raw in iter_messages(bag, {f"/rig/{n}/correspondences" for n in by})
    ]
    assert [(f.camera_name, f.stamp_ns) for f in frames] == [
        (n, s.sec * 1_000_000_000 + s.nanosec) for n, s in expected
    ]
    for f in frames:
        c = by[f.camera_name]
        assert f.camera.line_delay == pytest.approx(c["line_delay"])
        assert f.camera.readout == c["direction"]
    cfg = rig_bag_config(bag)[2]
    again = list(iter_rig_frames(bag, rig_camera_inputs(cfg, QuietLog(), lambda *a: None)))
    assert len(again) == len(frames) == 3 * FRAMES
    res = replay(bag, progress=None)
    for n in by:
        assert res.camera_counts[n]["received"] == FRAMES


def test_rig_frame_ends_follow_the_rig_mode(tmp_path):
    """The frames after which ``play --lockstep`` waits are those whose arrival makes the rig
    mode (Localizer) solve rig frames: with a dropped frame and a camera that stops."""
    from rs_localizer.ros.bags.bag_frames import read_rig_frames, rig_parameter_values
    from rs_localizer.ros.bags.bag_io import write_rig_bag
    from rs_localizer.ros.bags.play import rig_frame_grouping
    from rs_localizer.ros.config import build_config
    from rs_localizer.sim.trajectory import default_rig, generate_rig_video
    from rs_localizer.tracking.video import Localizer

    cams = default_rig(3)
    cams[1] = type(cams[1])(**{**cams[1].__dict__, "drop": (3, 4)})
    cams[2] = type(cams[2])(**{**cams[2].__dict__, "stop": 0.25})
    frames, _, traj = generate_rig_video(cams, duration=0.5, num_points=60, seed=2)
    bag = write_rig_bag(tmp_path / "rig", frames, cams, traj)
    ends = rig_frame_grouping(bag)[0]
    values, cam_values = rig_parameter_values(bag)
    rig = Localizer(build_config(values, cam_values).settings)
    truth = {}
    for f in read_rig_frames(bag).frames:
        k = len(rig.add(f))
        if k:
            truth[(f.camera_name, f.stamp_ns)] = k
    assert ends == truth
    # (the dropped frames: one frame completes several rig frames; after the stop, the rig
    # frames close only once stop_after passed, or at the end)
    assert sum(ends.values()) >= 6 and max(ends.values()) >= 2


@pytest.mark.slow  # (renders the rig bag)
def test_play_lockstep_rig_bag_over_dds(rendered_rig_bag, ros_context):
    """``play --lockstep`` of a rendered 3-camera rig bag into the rig node: each rig frame
    answered on /rig/pose (the node's correspondences path; the images are not played to a
    node that does not take them), the poses near the truth."""
    import rclpy
    from geometry_msgs.msg import PoseStamped
    from rclpy.parameter import Parameter
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from rs_localizer.accuracy import frame_errors
    from rs_localizer.ros.bags.bag_io import load_ground_truth
    from rs_localizer.ros.bags.play import play
    from rs_localizer.ros.conversions import pose_from_msg
    from rs_localizer.ros.node import RSLocalizerNode
    from rs_localizer.ros.param_files import read_params_file

    bag = rendered_rig_bag
    params = read_params_file(bag / "rig_params.yaml")
    params.update(publish_tf=False, warmup=False)
    node = RSLocalizerNode(
        "rs_localizer",
        context=ros_context,
        namespace="/rig",
        parameter_overrides=[Parameter(k, value=v) for k, v in params.items()],
    )
    probe = rclpy.create_node("rig_play_probe", context=ros_context)
    poses = []
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    probe.create_subscription(PoseStamped, "/rig/pose", poses.append, qos)
    with spinning(ros_context, node, probe):
        res = play(bag, lockstep=True, context=ros_context, wait_subscribers=20.0,
                   timeout=5.0, log=print)  # fmt: skip
        time.sleep(0.3)
        node_rig_frames = node.mode.rig.counts["rig_frames"]  # (the node's own count)
    assert res.rig_frames == FRAMES and res.answered == FRAMES and res.timeouts == 0
    assert not res.gave_up
    assert res.rig_frames_in_bag == FRAMES == node_rig_frames
    assert len(res.frames) == 3 * FRAMES and all("image" not in f["topic"] for f in res.frames)
    assert len(poses) == FRAMES
    gt = load_ground_truth(bag)
    for m in poses:
        s = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
        R, p = pose_from_msg(m.pose)
        e = frame_errors(R, p, None, None, gt, s)
        assert e["rot_deg"] < 0.2 and e["pos_m"] < 0.01


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--rig", "5"], "--rig takes 1 to 4 cameras"),
        (["--rig", "3", "--frontend", "features"], "no --frontend"),
        (["--rig", "3", "--mono"], "no --mono"),
        (["--rig", "2", "--scene", "checkerboard"], "has no markers"),
    ],
)
def test_render_bag_rig_refuses_what_it_cannot_render(tmp_path, capsys, extra, message):
    from rs_localizer.cli import main

    out = tmp_path / "rig"
    assert main(["render-bag", str(out), "--frames", "1", "--quiet", *extra]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()
