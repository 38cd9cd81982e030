"""The rig mode does what the single-camera node does, on a simulated 3-camera rig sent over DDS:
the velocity bounds refuse motion beyond them as ``implausible_motion``, the RANSAC parameters
reach the rig's estimator, a forward stamp jump starts the rig's track again, a camera_info
applies from its own stamp, the pending twists go out when the input stops, each camera's
``debug_image`` and ``markers`` and the rig's ``path`` are published, and while the kernels
compile the rig frames are tracked and fused on the NumPy implementation."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from helpers.rig_node import T0, RigHarness, rig_parameters

from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.sim.trajectory import default_rig, generate_rig_video, rig_truth

pytest.importorskip("rclpy")


def _harness(ctx, cams, params, kinds=("cloud", "info"), outputs=("pose", "odom")) -> RigHarness:
    from rs_localizer.ros.node import RSLocalizerNode

    node = RSLocalizerNode("rs_localizer", context=ctx, namespace="/rig",
                            parameter_overrides=params)  # fmt: skip
    h = RigHarness(ctx, cams, node, timeout=20.0)
    assert h.matched(kinds, outputs), "the rig node and the probe did not match"
    return h


def _stamp(m) -> int:
    return m.header.stamp.sec * 10**9 + m.header.stamp.nanosec


def _settled(v) -> int:
    """Rig frames formed and no longer pending."""
    return int(v["rig_frames"]) - int(v["rig_frames_pending"])


def test_an_angular_velocity_bound_below_the_motion_refuses_every_rig_frame_as_implausible(
    ros_context,
):
    """``max_angular_velocity`` at 0.8x the slowest turn of the rig (1.3-1.7 rad/s): every rig
    frame is refused ``implausible_motion`` (the status counts them, no pose goes out), as
    the single-camera estimator refuses each camera's frame alone with that bound."""
    from rs_localizer.estimation import estimate_rs_pose
    from rs_localizer.estimation.options import EstimateOptions

    cams = default_rig(3)
    frames, _, traj = generate_rig_video(cams, duration=0.3, num_points=120, seed=16)
    t = np.linspace(0.0, 0.3, 31)
    R = traj.orientation(t)
    rate = np.radians([rotation_angle_deg(R[k + 1], R[k]) for k in range(30)]) / 0.01
    bound = 0.8 * float(rate.min())
    o = EstimateOptions()
    o = dataclasses.replace(
        o, plausibility=dataclasses.replace(o.plausibility, max_angular_velocity=bound)
    )
    by = {c.name: c.camera for c in cams}
    alone = {estimate_rs_pose(f.uv, f.xyz, by[f.name], options=o).failure for f in frames[:6]}
    assert alone == {"implausible_motion"}, alone
    h = _harness(ros_context, cams, rig_parameters(cams, max_angular_velocity=bound))
    try:
        assert h.node.mode.rig.settings.options.plausibility.max_angular_velocity == bound
        h.send_info(cams)
        h.send_clouds(frames)
        _, v = h.last_diag()
        n = _settled(v)
        assert n >= 8 and v["rig_frames_failed.implausible_motion"] == str(n), v
        assert v["rig_frames_solved"] == "0" and not h.poses, v
    finally:
        h.close()


def test_the_ransac_parameters_reach_the_rig_estimator(ros_context, monkeypatch):
    """``ransac.threshold_px``, ``.confidence``, ``.min_inliers``, ``.max_iterations``,
    ``.seed``, ``refine`` and the velocity bounds are the rig estimator's arguments on every
    rig frame; and they act: a threshold of 0.05 px on points with 0.5 px noise leaves too
    few inliers in every rig frame (refused ``too_few_inliers``), where 2 px poses them all."""
    import rs_localizer.tracking.tracker as tracker_module

    calls = []
    real = tracker_module.estimate_rig_pose

    def spy(views, options, **kw):
        r, p = options.ransac, options.plausibility
        calls.append(
            {
                "threshold_px": r.threshold_px,
                "confidence": r.confidence,
                "min_inliers": r.min_inliers,
                "max_iterations": r.max_iterations,
                "seed": r.seed,
                "refine": options.refine.enabled,
                "max_angular_velocity": p.max_angular_velocity,
                "max_linear_velocity": p.max_linear_velocity,
            }
        )
        return real(views, options, **kw)

    monkeypatch.setattr(tracker_module, "estimate_rig_pose", spy)
    cams = default_rig(3)
    frames, _, _ = generate_rig_video(cams, duration=0.2, num_points=120, seed=23)
    given = {
        "ransac.threshold_px": 0.05,
        "ransac.confidence": 0.95,
        "ransac.min_inliers": 20,
        "ransac.max_iterations": 700,
        "ransac.seed": 5,
        "refine": True,
        "max_angular_velocity": 9.0,
        "max_linear_velocity": 4.0,
    }
    for threshold in (0.05, 2.0):
        calls.clear()
        params = rig_parameters(cams, **{**given, "ransac.threshold_px": threshold})
        h = _harness(ros_context, cams, params)
        try:
            h.send_info(cams)
            h.send_clouds(frames)
            _, v = h.last_diag()
            n = _settled(v)
            assert n >= 5 and len(calls) >= n, (n, len(calls))
            for kw in calls:
                assert kw["threshold_px"] == threshold and kw["confidence"] == 0.95, kw
                assert (kw["min_inliers"], kw["seed"], kw["refine"]) == (20, 5, True), kw
                assert kw["max_iterations"] <= 700, kw  # (a tracked rig frame: fewer)
                assert (kw["max_angular_velocity"], kw["max_linear_velocity"]) == (9.0, 4.0)
            assert any(kw["max_iterations"] == 700 for kw in calls)
            if threshold == 2.0:
                assert v["rig_frames_solved"] == str(n), v
            else:
                assert v["rig_frames_solved"] == "0", v
                assert v["rig_frames_failed.too_few_inliers"] == str(n), v
        finally:
            h.close()


def test_a_forward_stamp_jump_ends_the_rig_s_track_as_a_camera_s(ros_context):
    """The video sent again 5 s later (``time_reset_threshold`` 1 s): the first rig frame
    after the jump starts a new track (``cold``, not tracked: as a camera's tracker, which
    starts again after a gap), the first track's pending twists are published when the jump
    arrives (before the second video ends), and every rig frame of both is posed."""
    cams = default_rig(3)
    frames, _, _ = generate_rig_video(cams, duration=0.2, num_points=120, seed=24)
    later = [dataclasses.replace(f, stamp_ns=f.stamp_ns + 5 * 10**9) for f in frames]
    h = _harness(ros_context, cams, rig_parameters(cams))
    try:
        h.send_info(cams)
        h.send_clouds(frames)
        n = len(frames) // 3
        assert h.wait(lambda: len(h.poses) == n)
        first = {_stamp(m) for m in h.poses}
        assert len(h.odom) < n  # (the last rig frames' fused twists wait for later ones)
        h.send_clouds(later[:3])  # (the second video's first rig frame)
        assert h.wait(lambda: {_stamp(m) for m in h.odom} >= first), "twists not published"
        h.send_clouds(later[3:])
        c = h.node.mode.rig.counts
        assert c["rig.path.cold"] == 2 and c["rig.path.reset"] == 0, dict(c)
        _, v = h.last_diag()
        assert sum(int(v[f"{x.name}.stamp_jumped_ahead"]) for x in cams) == 1, v
        assert len(h.poses) == 2 * n and v["rig_frames_solved"] == str(2 * n), v
        for c in cams:
            assert h.node.mode.rig.counts[f"{c.name}.stopped"] == 0 and v[f"{c.name}.missed"] == "0"
    finally:
        h.close()


def test_a_camera_info_change_mid_stream_applies_from_its_own_stamp(ros_context):
    """Every camera's principal point moves 20 px right halfway through the video (its
    second half rendered so: pixels + 20 px in u). Both camera_infos, the old one stamped at
    the start and the new one at the camera's first frame of the second half, arrive before
    any frame: each frame uses the one of its stamp (neither the newest nor the first for
    all), so every rig frame is posed within 0.05 deg and 5 mm of the truth (20 px of the
    wrong one: about 2 deg)."""
    from rs_localizer.ros.conversions import camera_info_msg, pose_from_msg

    cams = default_rig(3)
    frames, _, traj = generate_rig_video(cams, duration=0.4, num_points=120, seed=25)
    half = 6
    for f in frames:
        if f.index >= half:
            f.uv = f.uv + np.array([20.0, 0.0])
    h = _harness(ros_context, cams, rig_parameters(cams))
    try:
        h.send_info(cams)
        for c in cams:
            at = min(f.stamp_ns for f in frames if f.name == c.name and f.index == half)
            moved = camera_info_msg(c.camera, c.name, at)
            moved.k[2] += 20.0
            moved.p[2] += 20.0
            h.pub[c.name]["info"].publish(moved)
        assert h.wait(lambda: all(len(h.node.inputs[c.name].history) == 2 for c in cams))
        h.send_clouds(frames)
        _, v = h.last_diag()
        n = _settled(v)
        assert n >= 11 and v["rig_frames_solved"] == str(n) == str(len(h.poses)), v
        for m in h.poses:
            R, p, _, _ = rig_truth(traj, (_stamp(m) - T0) * 1e-9)
            Re, pe = pose_from_msg(m.pose)
            assert rotation_angle_deg(Re, R) < 0.05 and np.linalg.norm(pe - p) < 0.005
    finally:
        h.close()


def test_the_pending_twists_go_out_when_the_input_stops(ros_context):
    """15 rig frames, then nothing: the last ``tracking.lag`` rig frames' fused twists wait
    for later rig frames; after ``tracking.max_gap`` (3 s here: time to see them wait)
    without camera frames they are published (``odom`` for every posed rig frame), as the
    single-camera node does, without the video's end (deactivate) being signalled. (The
    twists still pending are read when the 14th pose arrives, before ``max_gap`` has passed;
    on a loaded machine the last rig frame may be closed too by then: 15 poses.)"""
    cams = default_rig(3)
    frames, _, _ = generate_rig_video(cams, duration=0.5, num_points=120, seed=26)
    h = _harness(ros_context, cams, rig_parameters(cams, **{"tracking.max_gap": 3.0}))
    try:
        h.send_info(cams)
        h.send_clouds(frames)
        at_14 = {}

        def fourteen() -> bool:
            if len(h.poses) >= 14 and not at_14:
                at_14.update(poses=len(h.poses), odom=len(h.odom))
            return bool(at_14)

        assert h.wait(fourteen)
        assert at_14["poses"] - at_14["odom"] >= 1, f"no twist pending: {at_14}"
        assert h.wait(lambda: len(h.odom) == len(h.poses) >= 14, timeout=10.0)
        assert [_stamp(m) for m in h.odom] == [_stamp(m) for m in h.poses]
    finally:
        h.close()


def test_each_camera_s_debug_image_and_markers_and_the_rig_s_path(ros_context):
    """With ``viz.max_rate`` 0 (every posed rig frame drawn): ``<camera>/debug_image`` is the
    camera's canvas (its size, ``bgr8``, its frame id) with the simulator's inliers drawn as
    inliers under the rig's pose; ``<camera>/markers`` has the camera's frustum with its
    apex at the camera's true position (the rig's truth through its mounting) at the
    camera's reference time; ``path`` is the rig's poses. ``viz.*`` may change at run time
    (read when drawing, as by the single-camera node); other parameters are refused."""
    from nav_msgs.msg import Path
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image
    from visualization_msgs.msg import MarkerArray

    from rs_localizer.viz.debug_image import COLORS

    cams = default_rig(3)
    frames, _, _ = generate_rig_video(cams, duration=0.2, num_points=120, seed=27)
    h = _harness(ros_context, cams, rig_parameters(cams, **{"viz.max_rate": 0.0}))
    got = {"image": [], "markers": [], "path": []}
    qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    for kind, t, topic in (
        ("image", Image, "/rig/left/debug_image"),
        ("markers", MarkerArray, "/rig/left/markers"),
        ("path", Path, "/rig/path"),
    ):
        h.probe.create_subscription(t, topic, got[kind].append, qos)
    try:
        viz = h.node.camera_viz["left"]
        assert h.wait(lambda: viz.wants("debug_image") and viz.wants("markers"))
        assert h.wait(lambda: h.node.viz.wants("path"))
        left = next(c for c in cams if c.name == "left")
        h.send_info(cams)
        rig = h.node.mode.rig
        for k in range(len(frames) // 3):  # (one rig frame at a time: each one drawn)
            h.send_clouds(frames[3 * k : 3 * k + 3])
            # the worker done with the three camera frames (none left waiting: frames sent
            # faster than a loaded machine solves them would fill the queue, which drops the
            # oldest), then the outputs of every rig frame posed so far
            assert h.wait(lambda: h.node._frames.pending == 0), rig.rig_counts()
            n = rig.rig_counts()["solved"]
            assert h.wait(lambda n=n: min(len(h.poses), *(len(v) for v in got.values())) >= n), (
                {k: len(v) for k, v in got.items()},
                len(h.poses),
                rig.rig_counts(),
            )
        c = rig.rig_counts()
        assert c["skipped"] == c["failed"] == 0 and c["solved"] >= 5, c
        # every posed rig frame drawn: each camera frame's image and markers, the rig's path
        assert h.wait(
            lambda: len(got["markers"]) == len(got["image"]) == len(h.poses) == c["solved"]
        )
        by_stamp = {f.stamp_ns: f for f in frames if f.name == "left"}
        for img in got["image"]:
            f = by_stamp[_stamp(img)]
            size = (left.camera.width, left.camera.height, "bgr8")
            assert (img.width, img.height, img.encoding) == size
            assert img.header.frame_id == "left"
            px = np.frombuffer(bytes(img.data), np.uint8).reshape(img.height, img.width, 3)
            uv = np.round(f.uv).astype(int)
            seen = (uv[:, 0] >= 0) & (uv[:, 0] < img.width) & (uv[:, 1] >= 0)
            seen &= (uv[:, 1] < img.height) & (uv[:, 1] > 120)  # (below the caption)
            green = np.all(px[uv[seen, 1], uv[seen, 0]] == COLORS["inlier"], axis=1)
            assert green[f.inlier[seen]].mean() > 0.9 and green[~f.inlier[seen]].mean() < 0.2
        refs = {f.t_ref_ns: f for f in frames if f.name == "left"}
        for ma in got["markers"]:
            (fr,) = [m for m in ma.markers if m.ns == "frustum"]
            f = refs[_stamp(fr)]
            apex = np.array([fr.points[0].x, fr.points[0].y, fr.points[0].z])
            true = f.position + f.orientation @ left.p_rig_cam
            assert np.linalg.norm(apex - true) < 0.005 and fr.header.frame_id == "map"
        last = got["path"][-1]
        assert [_stamp(p) for p in last.poses] == [_stamp(m) for m in h.poses]
        # viz.* change at run time (read when drawing); an invalid value is rejected
        from rclpy.parameter import Parameter

        ok, refused = h.node.set_parameters(
            [Parameter("viz.frustum_depth", value=0.2), Parameter("max_points", value=10)]
        )
        assert ok.successful and not refused.successful
        assert "max_points 10 is below the 12 points a pose needs" in refused.reason
    finally:
        h.close()


def test_warmup_runs_the_rig_s_kernels_before_the_first_frame(ros_context, monkeypatch):
    """``warmup`` true: at start the node runs the rig's synthetic rig frames
    (:func:`~rs_localizer.runtime.warmup.warm_rig`) with its settings and every camera's RS
    timing, as the single-camera node warms its own kernels up, and all of them are posed;
    ``warmup`` false: not."""
    from rclpy.parameter import Parameter

    import rs_localizer.runtime.warmup as warmup
    from rs_localizer.ros.node import RSLocalizerNode

    calls = []
    real = warmup.warm_rig

    def spy(settings, timing=None, frames=8):
        calls.append((settings, timing, real(settings, timing, frames)))
        return calls[-1][2]

    monkeypatch.setattr(warmup, "warm_rig", spy)
    cams = default_rig(3)
    for on in (False, True):
        params = [p for p in rig_parameters(cams) if p.name != "warmup"]
        params.append(Parameter("warmup", value=on))
        node = RSLocalizerNode("rs_localizer", context=ros_context, parameter_overrides=params)
        try:
            if not on:
                assert calls == []
                continue
            ((settings, timing, posed),) = calls
            assert settings is node.mode.rig.settings and posed == 8
            assert timing == {c.name: (c.camera.line_delay, 0.0, c.camera.readout) for c in cams}
        finally:
            node.destroy_node()


def test_while_the_kernels_compile_the_rig_frames_are_tracked_and_fused(ros_context):
    """The node's rig frames on the NumPy implementation (the runtime holding them there as
    a background compile does): every rig frame posed within 0.05 deg and 5 mm of the truth,
    tracked after the first, ``odom`` carrying the fused twists (the last rig frames' wait for
    later ones, then go out after ``tracking.max_gap``), the diagnostics say ``compiled``
    false and count every rig frame in ``rig_frames_uncompiled``."""
    from rs_localizer.ros.conversions import pose_from_msg
    from rs_localizer.runtime import background

    cams = default_rig(3)
    frames, _, traj = generate_rig_video(cams, duration=0.4, num_points=120, seed=27)
    background._hold(True)
    h = _harness(ros_context, cams, rig_parameters(cams, **{"tracking.max_gap": 3.0}))
    try:
        h.send_info(cams)
        h.send_clouds(frames)
        n = len(frames) // 3
        assert h.wait(lambda: len(h.poses) == n)
        assert len(h.odom) < n  # (the last rig frames' fused twists wait for later ones)
        c = h.node.mode.rig.counts
        assert c["rig.uncompiled"] == n and c["rig.path.tracked"] == n - 1, dict(c)
        _, v = h.last_diag()
        assert v["compiled"] == "false" and v["rig_frames_uncompiled"] == str(n), v
        for m in h.poses:
            R, p, _, _ = rig_truth(traj, (_stamp(m) - T0) * 1e-9)
            Re, pe = pose_from_msg(m.pose)
            assert rotation_angle_deg(Re, R) < 0.05 and np.linalg.norm(pe - p) < 0.005
        assert h.wait(lambda: len(h.odom) == n, timeout=10.0)
        assert [_stamp(m) for m in h.odom] == [_stamp(m) for m in h.poses]
    finally:
        background._hold(False)
        h.close()


def test_a_rig_of_one_is_solved_with_the_solver_parameter_and_publishes_its_twist(ros_context):
    """A rig of one camera at the identity mounting is its camera's video: the node's
    ``solver`` (here P3P, a global-shutter solver) is what its frames are solved with, and a
    global shutter's own twist (zero) is final at once: published on ``odom`` with every pose,
    tracking on, as the camera node publishes it. ``solver`` is not named as unused, and a
    change of it at run time is taken."""
    from rclpy.parameter import Parameter

    cams = default_rig(1)
    frames, _, _ = generate_rig_video(cams, duration=0.2, num_points=80, seed=3)
    params = rig_parameters(cams, solver="p3p")
    params = [p for p in params if p.name != "rig.front.mounting"]
    params.append(Parameter("rig.front.mounting", value=[0.0] * 6 + [1.0]))
    h = _harness(ros_context, cams, params)
    try:
        rig = h.node.mode.rig
        assert rig.settings.single_camera and rig.settings.solver == "p3p"
        assert h.node.mode.cfg.unused == ()
        h.send_info(cams)
        h.send_clouds(frames)
        _, v = h.last_diag()
        n = int(v["rig_frames_solved"])
        assert n == len(frames) == len(h.poses), v
        assert h.wait(lambda: len(h.odom) == n), (len(h.odom), n)
        for m in h.odom:
            t = m.twist.twist
            assert [t.angular.x, t.angular.y, t.angular.z, t.linear.x] == [0.0] * 4
        res = h.node.set_parameters([Parameter("solver", value="r6p_1lin")])
        assert res[0].successful, res[0].reason
        assert h.node.mode.rig.settings.solver == "r6p_1lin"
    finally:
        h.close()
