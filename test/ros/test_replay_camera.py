"""A camera alone is a rig of one: a rig camera's frame keeps its scores and a rig of one
weighs them as the camera's estimator does, its debug views draw the camera's own estimate;
``rs-localizer replay`` of a camera's bag runs the rig mode's rig of one, with the camera's
output transform (``camera_to_base.*``) and one row per frame message."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

pytest.importorskip("rclpy")

from helpers.ros import LineLog
from helpers.transforms import transform, twist_hat

from rs_localizer.estimation.estimate import EstimateOptions, estimate_rs_pose
from rs_localizer.frames import Mounting
from rs_localizer.sim.trajectory import SequenceConfig, generate_sequence
from rs_localizer.tracking.video import Localizer, LocalizerSettings

IDENTITY = Mounting(np.eye(3), np.zeros(3))


def _same(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.tobytes() == b.tobytes()


def test_a_rig_of_one_weighs_its_cloud_s_scores_and_draws_its_camera_s_estimate():
    """Clouds with scores (20 % outliers, scored lower) through a rig camera's input into a
    rig of one without tracking: each frame keeps the cloud's scores, its estimate is the
    camera estimator's on the same rows and scores (``estimate_rs_pose``), bit for bit, and
    its debug view draws that estimate at the frame's time; without the scores the estimates
    differ (the scores order RANSAC's samples)."""
    from rs_localizer.ros.camera_input import CameraInput
    from rs_localizer.ros.conversions import ns_to_stamp
    from rs_localizer.ros.pointcloud import correspondence_cloud, read_correspondences
    from rs_localizer.ros.visualization import rig_camera_views

    frames, _, cam, _ = generate_sequence(SequenceConfig(num_frames=6, num_points=120, seed=5))
    opts = EstimateOptions()
    rig = Localizer(LocalizerSettings({"c": IDENTITY}, options=opts, tracking=None))
    inp = CameraInput(None, lambda key, n: None, name="c", rig=True)
    inp.history.add(0, (), None, cam)  # (the camera model of every stamp)
    differs = 0
    for f in frames:
        msg = correspondence_cloud(f.uv, f.xyz, scores=f.scores, stamp=ns_to_stamp(f.stamp_ns))
        frame = inp.take(msg, "correspondences", f.stamp_ns, cam)
        c = read_correspondences(msg)  # (the cloud's rows and scores, as stored)
        assert _same(frame.scores, c.scores) and np.allclose(c.scores, f.scores, rtol=1e-6)
        (out,) = rig.add(frame)
        want = estimate_rs_pose(c.uv, c.xyz, cam, options=opts, scores=c.scores)
        got = out.camera_estimate
        assert got.success and want.success
        for name in ("orientation", "position", "angular_velocity", "linear_velocity"):
            assert _same(getattr(got.pose, name), getattr(want.pose, name)), name
        assert _same(got.inliers, want.inliers) and _same(got.covariance, want.covariance)
        ((n, drawn_frame, view, ref),) = rig_camera_views(out, {"c": IDENTITY})
        assert n == "c" and drawn_frame is frame and view is got and ref == out.stamp_ns
        alone = estimate_rs_pose(c.uv, c.xyz, cam, options=opts)
        differs += not _same(alone.pose.orientation, want.pose.orientation)
    assert differs >= 1


def _frame_ids(out_bag) -> set:
    from rs_localizer.ros.bags.bag_io import iter_messages, typestore

    ts = typestore()
    return {
        ts.deserialize_cdr(raw, mt).header.frame_id
        for _, mt, _, raw in iter_messages(out_bag, {"/rs_localizer/twist_single_frame"})
    }


def test_a_camera_s_replay_moves_its_outputs_to_the_base(sample_bag, tmp_path):
    """``camera_to_base.*`` and ``base_frame`` move every pose and twist of a camera's replay
    to the robot's base (checked with 4x4 transforms against the replay without them:
    ``T_mb = T_mc T_bc^-1``, body twists by conjugation ``xi_b^ = T_bc xi_c^ T_bc^-1``), the
    twists stamped in ``base_frame``; without them in the camera's frame id."""
    from scipy.spatial.transform import Rotation

    from rs_localizer.ros.bags.bag_io import iter_messages, typestore
    from rs_localizer.ros.bags.replay import replay

    q_bc = Rotation.from_euler("xyz", [-95, 3, -88], degrees=True).as_quat()
    t_bc = np.array([0.35, -0.12, 0.6])
    T_bc = transform(Rotation.from_quat(q_bc).as_matrix(), t_bc)
    T_cb = np.linalg.inv(T_bc)
    params = {"base_frame": "base_link", "camera_to_base.translation": t_bc.tolist(),
              "camera_to_base.rotation": q_bc.tolist()}  # fmt: skip
    cam = replay(sample_bag, out_bag=tmp_path / "cam", progress=None)
    base = replay(sample_bag, params=params, out_bag=tmp_path / "base", progress=None)
    assert cam.solved == base.solved == len(base.rows) == len(cam.rows)
    for a, b in zip(cam.rows, base.rows, strict=True):
        assert (a["stamp_ns"], a["out_stamp_ns"]) == (b["stamp_ns"], b["out_stamp_ns"])
        R = Rotation.from_quat([a[f"q{k}"] for k in "xyzw"]).as_matrix()
        T = transform(R, [a[f"p{k}"] for k in "xyz"]) @ T_cb
        Rb = Rotation.from_quat([b[f"q{k}"] for k in "xyzw"]).as_matrix()
        np.testing.assert_allclose(Rb, T[:3, :3], atol=1e-9)
        np.testing.assert_allclose([b[f"p{k}"] for k in "xyz"], T[:3, 3], atol=1e-9)
        for w in ("", "single_"):
            if f"{w}wx" not in a:
                continue
            xi = twist_hat([a[f"{w}w{k}"] for k in "xyz"], [a[f"{w}v{k}"] for k in "xyz"])
            X = T_bc @ xi @ T_cb
            np.testing.assert_allclose([b[f"{w}w{k}"] for k in "xyz"], [X[2, 1], X[0, 2], X[1, 0]],
                                       atol=1e-9)  # fmt: skip
            np.testing.assert_allclose([b[f"{w}v{k}"] for k in "xyz"], X[:3, 3], atol=1e-9)
    assert _frame_ids(tmp_path / "base") == {"base_link"}
    ts = typestore()
    bag_ids = {
        ts.deserialize_cdr(raw, mt).header.frame_id
        for _, mt, _, raw in iter_messages(sample_bag, {"/camera/correspondences"})
    }
    assert _frame_ids(tmp_path / "cam") == bag_ids and "base_link" not in bag_ids


def test_a_camera_s_replay_has_a_row_for_each_frame_its_input_drops(keypoints_bag, tmp_path):
    """Keypoints none of whose ids is in the landmark map: every frame message is a failed row
    (``unknown_landmarks``, with its header stamp and its output stamp)."""
    from rs_localizer.ros.bags.bag_io import iter_messages, typestore
    from rs_localizer.ros.bags.replay import replay

    table = tmp_path / "landmarks.csv"
    table.write_text("id,x,y,z\n999999,0,0,1\n")
    res = replay(keypoints_bag, source="keypoints", params={"landmarks_file": str(table)},
                 progress=None)  # fmt: skip
    ts = typestore()
    stamps = [
        ts.deserialize_cdr(raw, mt).header.stamp
        for _, mt, _, raw in iter_messages(keypoints_bag, {"/camera/keypoints"})
    ]
    assert len(res.rows) == len(stamps) > 0 and res.solved == 0
    assert res.failures == {"unknown_landmarks": len(stamps)}
    for r, s in zip(res.rows, stamps, strict=True):
        assert r["stamp_ns"] == s.sec * 10**9 + s.nanosec and r["out_stamp_ns"] >= 0
    assert res.counts["unknown_landmark_ids"] >= len(stamps)


def _raise_on(monkeypatch, n: int) -> None:
    """The rig's frame step (``Localizer.add``) raises at its ``n``-th call (from 0)."""
    calls = iter(range(10**6))
    add = Localizer.add

    def failing(self, frame, *args, **kwargs):
        if next(calls) == n:
            raise RuntimeError("injected fault")
        return add(self, frame, *args, **kwargs)

    monkeypatch.setattr(Localizer, "add", failing)


def test_a_camera_s_replay_fails_a_frame_whose_step_raises_and_goes_on(sample_bag, monkeypatch):
    """A frame whose step raises is a failed row ``internal_error``, logged with the
    exception as the node logs it, and every later frame is solved (the bag's 30 frames)."""
    from rs_localizer.ros.bags.replay import replay

    _raise_on(monkeypatch, 4)
    log = LineLog()
    res = replay(sample_bag, progress=None, log=log)
    assert len(res.rows) == 30 and res.failures == {"internal_error": 1}
    assert res.rows[4]["failure"] == "internal_error" and not res.rows[4]["success"]
    assert all(r["success"] for r in res.rows[5:]) and res.solved == 29
    assert log.warnings() == ["frame failed (internal_error): RuntimeError: injected fault"]


def test_a_camera_s_replay_logs_a_time_reset_once_as_the_camera(sample_bag, tmp_path):
    """A camera's bag whose stamps go back 2 s after its 15th frame: one time reset, counted
    ``time_resets`` and logged once in the camera's words (``time reset: ...``, no rig's
    warning), every frame solved."""
    from dataclasses import replace

    from helpers.rig_bags import rewrite_bag

    from rs_localizer.ros.bags.replay import replay

    seen = iter(range(10**6))

    def edit(topic, msg, t):
        if topic.endswith("/correspondences") and next(seen) >= 15:
            s = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec - 2 * 10**9
            stamp = replace(msg.header.stamp, sec=s // 10**9, nanosec=s % 10**9)
            msg = replace(msg, header=replace(msg.header, stamp=stamp))
        return [(t, msg)]

    bag = rewrite_bag(sample_bag, tmp_path / "back", edit)
    log = LineLog()
    res = replay(bag, progress=None, log=log)
    assert res.solved == len(res.rows) == 30 and res.counts["time_resets"] == 1
    warned = log.warnings()
    assert len(warned) == 1 and warned[0].startswith("time reset: stamp ")
    assert "older than the previous frame" in warned[0]
    assert not any("rig" in t for _, t in log.lines)


def test_a_camera_s_replay_counts_its_estimator_and_front_end_as_its_node(sample_images_bag):
    """A camera's replay of images through its front end counts what its node counts: each
    image searched (``frontend_runs``) and the correspondences found (``frontend_points``:
    the rows given to the estimator, none dropped nor capped), each frame's estimator path
    (``frames_compiled`` + ``frames_uncompiled``: every frame) and the rows its estimator
    left out (``points_dropped``)."""
    from helpers.paths import CONFIG, IMAGES_CONFIG

    from rs_localizer.ros.bags.replay import replay

    res = replay(sample_images_bag, params_files=[CONFIG, IMAGES_CONFIG], progress=None)
    c = res.counts
    n = len(res.rows)
    assert n > 0 and res.solved == n and "capped_clouds" not in c
    assert c["frontend_runs"] == n
    assert c["frontend_points"] == sum(r["num_points"] for r in res.rows)
    assert c.get("frames_compiled", 0) + c.get("frames_uncompiled", 0) == n
    assert c["points_dropped"] == 0


def test_a_camera_s_video_speaks_as_the_camera_and_publishes_as_the_node():
    """A rig of one camera named "" is the camera's video (``LocalizerSettings.camera_video``):
    its outputs' estimate is the camera estimator's own (velocities per unit RS coordinate)
    with the rig's pose, its fused twists carry the frame's tag; its frame is counted as the
    camera's node counts it (``LocalizerOutput.camera_counts``: compiled, the estimator's
    dropped rows) and published as the node publishes it (``frame_outcome``: its pose at its
    time in its frame id, or moved to ``base_frame`` by its mounting as
    ``camera_to_base`` moves it; a failed frame only its fused twists)."""
    from rs_localizer.frames import camera_to_base
    from rs_localizer.ros.bags.replay import frame_outcome
    from rs_localizer.tracking.localizer import CameraFrame

    frames, _, cam, _ = generate_sequence(SequenceConfig(num_frames=8, num_points=120, seed=5))
    video = Localizer(LocalizerSettings({"": IDENTITY}, options=EstimateOptions()))
    rig = Localizer(LocalizerSettings({"c": IDENTITY}, options=EstimateOptions()))
    assert video.settings.camera_video and not rig.settings.camera_video
    mount = Mounting(np.array([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]]), np.array([0.1, 0, 0.3]))
    fused = []
    for f in frames:
        (out,) = video.add(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz, f.scores, tag="cam_optical"))
        (other,) = rig.add(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz, f.scores, camera_name="c"))
        est = out.estimate
        assert est is out.camera_estimate and est.success
        assert _same(est.model.w, other.camera_estimate.model.w)
        assert _same(est.pose.angular_velocity, other.estimate.pose.angular_velocity)
        assert out.camera_counts() == [("frames_compiled", 1), ("points_dropped", 0)]
        plain = frame_outcome(out, None)
        assert plain.posed.pose is est and plain.posed.frame_id == "cam_optical"
        assert plain.posed.stamp_ns == out.stamp_ns and plain.posed.twist_now == out.twist_now
        moved = frame_outcome(out, "robot", mount)
        want = camera_to_base(est, mount)
        assert moved.posed.frame_id == "robot"
        assert np.allclose(moved.posed.pose.pose.position, want.pose.position, atol=0)
        assert np.allclose(moved.posed.pose.pose.angular_velocity, want.pose.angular_velocity)
        fused += out.fused
        assert [x.frame_id for x in plain.fused] == ["cam_optical"] * len(out.fused)
    assert fused and all(f.tag == "cam_optical" for f in fused)
    failed = dataclasses.replace(out, estimate=dataclasses.replace(est, success=False))
    assert frame_outcome(failed, "robot", mount).posed is None


def test_a_camera_s_replay_of_marker_images_gives_the_estimator_each_corner_s_marker(
    sample_images_bag, monkeypatch
):
    """The node's path of an image (``replay``: the camera's input, its rig of one's front
    end, the tracker path's solves): every solve of every frame is given the groups of the
    rows it is given, each row's marker, as the front end's ids tell it (``4 * marker_id +
    corner``): the marker corners' shared error reaches the estimator's covariance."""
    from helpers.paths import CONFIG, IMAGES_CONFIG

    from rs_localizer.frontends.aruco import ArucoFrontend
    from rs_localizer.ros.bags.replay import replay
    from rs_localizer.tracking import tracker

    found, given = [], []
    process = ArucoFrontend.process

    def searched(self, *args, **kw):
        c = process(self, *args, **kw)
        found.append(c)
        return c

    def solved(uv, *args, **kw):
        given.append((len(found), np.asarray(uv).copy(), kw.get("groups")))
        return estimate_rs_pose(uv, *args, **kw)

    monkeypatch.setattr(ArucoFrontend, "process", searched)
    monkeypatch.setattr(tracker, "estimate_rs_pose", solved)
    res = replay(sample_images_bag, params_files=[CONFIG, IMAGES_CONFIG], progress=None)
    assert res.solved == len(res.rows) > 0 and len(given) >= len(res.rows)
    for k, uv, groups in given:
        c = found[k - 1]  # (the image the solve is of: the last searched)
        assert np.array_equal(uv, c.points2d)  # (every row given: none dropped nor capped)
        assert groups is not None and np.array_equal(groups, np.asarray(c.ids) // 4)
