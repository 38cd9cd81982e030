"""The node's frame pipeline (without ROS) on frames that see one marker or two: a tag's four
corners posed and counted in ``frames_single_tag`` and ``frames_few_points``, an ambiguous one
refused as ``ambiguous_tag``, two tags on different walls posed and counted in
``frames_few_points`` alone."""

import numpy as np
from helpers.camera_node import CameraNode

from rs_localizer.camera import CameraModel
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.ros import config as C
from rs_localizer.ros import params as P

K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])


def _tag(side):
    s = side / 2
    return np.array([[-s, -s, 0.0], [s, -s, 0.0], [s, s, 0.0], [-s, s, 0.0]])


def _view(deg, distance):
    a = np.radians(deg)
    R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    return R @ np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, distance])


def test_one_tag_is_posed_and_counted_and_an_ambiguous_one_refused():
    from rs_localizer.ros.bags.bag_io import RosbagsMessages

    msgs = RosbagsMessages()
    cam = CameraModel(K=K, width=640, height=480, line_delay=30e-6)
    cfg = C.build_config({**P.default_values(), "camera_info_wait": 0.0, "tracking.enabled": False})
    pipe = CameraNode(cfg)
    pipe.add_camera_info(msgs.camera_info(cam, 0, "cam"))
    rng = np.random.default_rng(1)
    X = _tag(0.2)
    R, Cc = _view(35, 0.8)
    uv = cam.project_rs(X, R, Cc) + rng.normal(0, 0.3, (4, 2))
    ids = np.arange(4)
    res = pipe.process(msgs.cloud(uv, X, ids, 1_000_000_000, "cam"), "correspondences")
    assert res.solved, (res.failure, res.detail)
    assert res.estimate.single_tag and rotation_angle_deg(res.estimate.model.R, R) < 2.0
    assert pipe.stats.snapshot().counts["frames_single_tag"] == 1
    assert pipe.stats.snapshot().counts["frames_few_points"] == 1
    # a 10 cm tag 4 m away, 20 degrees off its axis: both plane poses fit its corners
    X = _tag(0.1)
    R, Cc = _view(20, 4.0)
    uv = cam.project_rs(X, R, Cc) + rng.normal(0, 0.5, (4, 2))
    res = pipe.process(msgs.cloud(uv, X, ids, 2_000_000_000, "cam"), "correspondences")
    assert res.failure == "ambiguous_tag", (res.failure, res.detail)
    assert pipe.stats.snapshot().counts["frames_single_tag"] == 1


def test_two_tags_on_different_walls_are_posed_and_counted():
    from rs_localizer.ros.bags.bag_io import RosbagsMessages

    msgs = RosbagsMessages()
    cam = CameraModel(K=K, width=640, height=480, line_delay=30e-6)
    cfg = C.build_config({**P.default_values(), "camera_info_wait": 0.0, "tracking.enabled": False})
    pipe = CameraNode(cfg)
    pipe.add_camera_info(msgs.camera_info(cam, 0, "cam"))
    # (one tag on the floor, one on a wall: 8 corners on two planes, fewer than min_inliers)
    quarter = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    X = np.concatenate([_tag(0.2), _tag(0.2) @ quarter.T + [0.0, 0.3, 0.15]])
    R, Cc = _view(35, 1.2)
    uv = cam.project_rs(X, R, Cc) + np.random.default_rng(2).normal(0, 0.3, (8, 2))
    res = pipe.process(msgs.cloud(uv, X, np.arange(8), 1_000_000_000, "cam"), "correspondences")
    assert res.solved, (res.failure, res.detail)
    est = res.estimate
    assert est.few_points and not est.single_tag and est.num_inliers == 8
    assert rotation_angle_deg(est.model.R, R) < 1.0
    counts = pipe.stats.snapshot().counts
    assert counts["frames_few_points"] == 1 and counts.get("frames_single_tag", 0) == 0
