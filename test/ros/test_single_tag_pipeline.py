"""The node's frame pipeline (without ROS) on frames that see one marker: a tag's four corners
posed and counted in ``frames_single_tag``, an ambiguous one refused as ``ambiguous_tag``."""

import numpy as np

from rs_localizer.camera import CameraModel
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.ros import config as C
from rs_localizer.ros import params as P
from rs_localizer.ros.pipeline import FramePipeline

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
    pipe = FramePipeline(cfg)
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
    # a 10 cm tag 4 m away, 20 degrees off its axis: both plane poses fit its corners
    X = _tag(0.1)
    R, Cc = _view(20, 4.0)
    uv = cam.project_rs(X, R, Cc) + rng.normal(0, 0.5, (4, 2))
    res = pipe.process(msgs.cloud(uv, X, ids, 2_000_000_000, "cam"), "correspondences")
    assert res.failure == "ambiguous_tag", (res.failure, res.detail)
    assert pipe.stats.snapshot().counts["frames_single_tag"] == 1
