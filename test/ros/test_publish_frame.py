"""One frame's outcome published by :func:`rs_localizer.ros.outputs.publish_frame`, a rig
frame's and the single camera's alike: its messages in order (each built as
:mod:`rs_localizer.ros.conversions` builds it), the path given the pose it draws, each camera's
view to its own visualization with its image, the log lines to the node's throttled log."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("geometry_msgs")


class _Viz:
    """A visualization recording what it was handed."""

    def __init__(self):
        self.calls = []

    def hold_image(self, image):
        self.calls.append(("image", image))

    def publish(self, est, uv, X, camera, stamp_ns, out_stamp_ns, frame, map_frame, pose=None):
        self.calls.append(("publish", est, uv, camera, stamp_ns, out_stamp_ns, frame, pose))


class _Node:
    """The node's side of publish_frame: its outputs (every one subscribed but ``tf``),
    visualizations and log."""

    map_frame = "world"

    def __init__(self, viz, camera_viz):
        self.viz, self.camera_viz = viz, camera_viz
        self.sent, self.warned = [], []

    def wanted(self, topic: str) -> bool:
        return topic != "tf"

    def publish_messages(self, messages):
        self.sent += messages

    def warn(self, key: str, text: str, count: int = 0):
        self.warned.append((key, text, count))


def _state(seed: int, stamp_ns: int):
    from rs_localizer.geometry import rotvec_to_matrix
    from rs_localizer.pose import PoseWithCovariance, RSPose

    rng = np.random.default_rng(seed)
    pose = RSPose(rotvec_to_matrix(rng.normal(size=3)), rng.normal(size=3), rng.normal(size=3),
                  rng.normal(size=3), stamp_ns)  # fmt: skip
    return PoseWithCovariance(pose=pose, pose_covariance=np.diag(rng.uniform(1, 2, 6)))


def _stamp(m) -> int:
    return m.header.stamp.sec * 10**9 + m.header.stamp.nanosec


def test_a_posed_rig_frame_its_own_twist_then_the_fused_its_path_and_cameras():
    """A rig frame posed with its own twist final and an earlier frame's fused twist: pose,
    twist_single_frame, the fused twist and odom, its own twist and odom (each topic's
    stamps in order), pose_with_covariance
    (tf not subscribed), each as conversions builds it; the path (the node's viz) gets the
    rig's pose and the very pose message sent; the camera's view goes to the camera's viz
    with its image (no pose message: its pose is not the rig's); the log line is warned."""
    from rs_localizer.ros import conversions as cv
    from rs_localizer.ros.outputs import (
        CameraView,
        FrameOutcome,
        LogLine,
        PosedFrame,
        publish_frame,
    )
    from rs_localizer.ros.pipeline import FusedOutput

    rig, earlier, cam = _state(1, 2_000), _state(2, 1_000), _state(3, 2_005)
    image = (np.zeros((4, 4), np.uint8), "mono8", 2_010)
    uv, X = np.zeros((5, 2)), np.zeros((5, 3))
    view = CameraView("left", cam, uv, X, "model", 2_010, 2_005, "left_optical", image)
    fused = [FusedOutput(1_000, earlier, "base")]
    line = LogLine("rig.outvoted.right", "right outvoted")
    outcome = FrameOutcome(PosedFrame(rig, 2_000, "base", True, (view,)), fused, (line,))
    path, left = _Viz(), _Viz()
    node = _Node(path, {"left": left, "right": _Viz()})
    publish_frame(node, outcome)
    topics = [t for t, _ in node.sent]
    assert topics == ["pose", "twist_single_frame", "twist", "odom", "twist", "odom",
                      "pose_with_covariance"]  # fmt: skip
    msgs = [m for _, m in node.sent]
    expected = [
        cv.pose_stamped(rig.pose, 2_000, "world"),
        cv.twist_stamped(rig.pose, 2_000, "base"),
        cv.twist_stamped(earlier.pose, 1_000, "base"),
        cv.odometry(earlier, 1_000, "world", "base"),
        cv.twist_stamped(rig.pose, 2_000, "base"),
        cv.odometry(rig, 2_000, "world", "base"),
        cv.pose_with_covariance_stamped(rig, 2_000, "world"),
    ]
    assert msgs == expected
    assert [_stamp(m) for m in msgs] == [2_000] * 2 + [1_000] * 2 + [2_000] * 3
    ((kind, est, *_, pose_msg),) = path.calls
    assert kind == "publish" and est is rig and pose_msg is msgs[0]
    drawn = ("publish", cam, uv, "model", 2_010, 2_005, "left_optical", None)
    assert left.calls == [("image", image), drawn]
    assert node.camera_viz["right"].calls == []  # (not in the outcome: not watched)
    assert node.warned == [("rig.outvoted.right", "right outvoted", 0)]


def test_the_single_camera_s_outcome_its_view_draws_the_path(monkeypatch):
    """The single camera (its viz the node's, with the path): solved, its view drawn once with
    the camera's estimate and the sent pose message when that pose is the camera's, none
    (the path makes the camera's own) when the output is the robot base's; the fused twists
    go out also when the frame's own twist is final (an earlier track's), before it; failed,
    the fused twists alone and
    the line ``frame dropped (<reason>): <detail>`` with its count."""
    from types import SimpleNamespace

    import rs_localizer.ros.mode as M
    import rs_localizer.ros.outputs as O
    from rs_localizer.ros.outputs import fused_messages, publish_frame
    from rs_localizer.ros.pipeline import FusedOutput

    est, base, earlier = _state(4, 5_000), _state(5, 5_000), _state(6, 4_000)
    fused = [FusedOutput(4_000, earlier, "cam")]
    pending = object()  # (the rig of one's fused states final now, as the localizer gives them)

    def outcome(mount, twist_now=False, failure=None, failed=0):
        """The camera alone's outcome (its mode's) of a frame posed at ``est``, its output moved
        to the robot base (``base``) by ``mount`` when given."""
        mode = M.LocalizerMode.__new__(M.LocalizerMode)  # (the camera alone's, its node a stand-in)
        mode.alone, mode.rig = True, None
        mode._fused_in = (None, None) if mount is None else ("base_link", mount)
        mode.node = SimpleNamespace(camera_counts={"": SimpleNamespace(get=lambda key: failed)},
                                    inputs={"": SimpleNamespace(label="")})  # fmt: skip
        res = M.CameraFrameResult("cam")
        res.stamp_ns, res.out_stamp_ns, res.camera = 5_100, 5_000, "model"
        res.points2d, res.points3d, res.fused = "uv", "X", fused
        res.failure, res.detail = failure, "9 points"
        res.outs = [SimpleNamespace(camera_estimate=est, estimate=est, twist_now=twist_now,
                                    success=True, fused=[pending], error=None, outvoted=(),
                                    stamp_ns=5_000, cameras=("",), tags={"": "cam"})]  # fmt: skip
        (out,) = mode.outcomes("", res)
        return out

    def fused_outputs(given, frame, mount):  # (pipeline.fused_outputs: tested on its own)
        assert given == [pending] and (frame, mount) in ((None, None), ("base_link", "mount"))
        return fused

    monkeypatch.setattr(O, "fused_outputs", fused_outputs)
    monkeypatch.setattr(O, "camera_to_base", lambda e, mount: base if e is est else None)
    for mount, frame in ((None, "cam"), ("mount", "base_link")):
        viz = _Viz()
        node = _Node(viz, {"": viz})
        publish_frame(node, outcome(mount))
        assert [t for t, _ in node.sent] == ["pose", "twist_single_frame", "twist", "odom",
                                             "pose_with_covariance"]  # fmt: skip
        assert node.sent[2:4] == fused_messages(fused, "world")
        assert node.sent[1][1].header.frame_id == frame
        pose_msg = node.sent[0][1] if mount is None else None
        drawn = ("publish", est, "uv", "model", 5_100, 5_000, "cam", pose_msg)
        assert viz.calls == [("image", None), drawn]
        assert node.warned == []
    # (its own twist final at once, an earlier track's fused twist final with it: both out,
    # the earlier stamp first)
    node = _Node(_Viz(), {"": _Viz()})
    publish_frame(node, outcome(None, twist_now=True))
    twists = [m for t, m in node.sent if t == "twist"]
    assert [t for t, _ in node.sent][2:6] == ["twist", "odom", "twist", "odom"]
    assert node.sent[2:4] == fused_messages(fused, "world")
    assert [_stamp(m) for m in twists] == [4_000, 5_000]
    viz = _Viz()
    node = _Node(viz, {"": viz})
    publish_frame(node, outcome(None, failure="too_few_inliers", failed=3))
    assert node.sent == fused_messages(fused, "world") and viz.calls == []
    assert node.warned == [("too_few_inliers", "frame dropped (too_few_inliers): 9 points", 3)]
