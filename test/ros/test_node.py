"""Integration tests: the real node in a subprocess, committed bags replayed over DDS in lock-step.

Accuracy thresholds (sample bag: 1280x720, fx ~1000, 30 us/row, angular speed 0.4-1.7 rad/s,
walking at 1.3 m/s, 0.5 px noise, 20 % outliers, 500 correspondences, depths 3-25 m, median
~14 m). With 400 inliers at 0.5 px the pose is determined to ~0.01 deg and ~2 mm; the
velocities come from how the image changes during one 21.6 ms readout: the rotation during the
readout (~2 deg) is seen across all points and gives the angular velocity to ~0.05 rad/s, but the
translation during the readout is only ~3 cm seen from ~14 m (~2 px of parallax), so the linear
velocity is weakly observable (typically 0.3 m/s error, up to ~0.6). The limits below are ~3x
the typical values so that they catch real regressions (a wrong sign, frame or time scale
gives errors of the size of the motion itself: >1 rad/s, >0.5 deg or >5 cm) without
flakiness. The global-shutter p3p baseline has ~50x larger pose errors on this motion.
"""

from __future__ import annotations

import contextlib
import os
import time

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("rosbags")

from helpers.ros import ParamClient, Probe, assert_dropped, start_node, stop_node

LIMITS = {  # key: (median, max); typical on the sample bag: 0.010/0.06 deg, 1.8/4 mm,
    "rot_deg": (0.03, 0.2),  # 0.04/0.12 rad/s, 0.28/0.58 m/s
    "pos_m": (0.01, 0.03),
    "angvel": (0.15, 0.4),
    "linvel": (0.8, 1.5),
}
OUTPUTS = ("/camera/pose", "/camera/twist", "/camera/odom", "/camera/pose_with_covariance")


def _check_accuracy(errs, limits=LIMITS, label=""):
    from rs_localizer.accuracy import summarize_errors

    s = summarize_errors(errs)
    for key, (med, mx) in limits.items():
        assert s[key]["median"] < med, f"{label} {key} median {s[key]['median']:.4g} >= {med}"
        assert s[key]["max"] < mx, f"{label} {key} max {s[key]['max']:.4g} >= {mx}"
    return s


@pytest.fixture(scope="module")
def node(tmp_path_factory, keypoints_bag):
    tmp = tmp_path_factory.mktemp("node")
    n = start_node(
        tmp, {"diagnostics_period": 0.2, "landmarks_file": str(keypoints_bag / "landmarks.csv")}
    )
    yield n
    alive = n.alive()
    rc = n.stop()
    assert alive, f"node died:\n{n.log}"
    assert rc == 0, f"node exit code {rc}:\n{n.log}"


#: the solvers the tests switch the node to at runtime
SWITCHED_SOLVERS = ("p3p", "r6p_vC_wt")


@pytest.fixture(scope="module")
def switched_solver_kernels():
    """The kernels of :data:`SWITCHED_SOLVERS` compiled (or loaded from numba's cache, which
    the node shares) in this process, with the node's estimator and tracking options: the node
    warms a new solver up before its set_parameters service answers, so a solver change on a
    cache without its kernels (a new checkout, a busy machine: over the parameter client's
    30 s) would time the numba compile, not the node's answer."""
    from helpers.paths import CONFIG

    from rs_localizer.ros.config import build_config
    from rs_localizer.ros.param_files import parameter_values
    from rs_localizer.runtime.warmup import warm_up

    for solver in SWITCHED_SOLVERS:
        cfg = build_config(parameter_values([CONFIG], {"solver": solver})[0])
        warm_up(solver, cfg.options, cfg.tracking, gyro=cfg.imu is not None)


def _restore(params, **values):
    """In a test's ``finally``: set the module's node back to ``values`` (the later tests on it
    expect its defaults), without hiding the test's own failure (a restore that fails leaves
    the node as it is: the later tests see it)."""
    with contextlib.suppress(AssertionError):
        params.set(**values)


def _play(ros_context, bag, offset_s=0.0, limit=None, outputs=OUTPUTS, topics=None):
    from rs_localizer.ros.bags.accuracy import evaluate_outputs
    from rs_localizer.ros.bags.bag_io import load_ground_truth
    from rs_localizer.ros.bags.play import play

    res = play(
        bag,
        lockstep=True,
        output_topics=outputs,
        context=ros_context,
        timeout=5.0,
        topics=topics,
        stamp_offset_ns=int(offset_s * 1e9),
        limit=limit,
        log=print,
        late_topics=("/camera/twist", "/camera/odom"),
    )  # (the fused twist: lag 1)
    gt = load_ground_truth(bag)
    if offset_s:  # shift ground truth like the inputs
        shift = int(offset_s * 1e9)
        for d in (gt.orientation, gt.position, gt.angular_velocity, gt.linear_velocity):
            for k in list(d):
                d[k + shift] = d.pop(k)
        gt.stamps = gt.stamps + shift
    return res, gt, evaluate_outputs(res.frames, gt, ["/camera"])["/camera"]


def test_sample_bag_accuracy(node, ros_context, sample_bag):
    from rs_localizer.ros.conversions import stamp_to_ns

    res, gt, errs = _play(
        ros_context, sample_bag, topics=["/camera/correspondences", "/camera/camera_info"]
    )
    assert len(res.frames) == 30 and res.answered == 30, node.log
    s = _check_accuracy(errs)
    print("sample bag accuracy:", s)
    for f in res.frames:
        pose = f["outputs"]["/camera/pose"][1]
        twist = f["outputs"]["/camera/twist"][1]
        odom = f["outputs"]["/camera/odom"][1]
        pwc = f["outputs"]["/camera/pose_with_covariance"][1]
        # stamped at the reference (centre) row: exactly the ground-truth stamp
        stamp = stamp_to_ns(pose.header.stamp)
        assert stamp in gt.orientation
        assert stamp - f["stamp"] == round(359.5 * 30e-6 * 1e9)
        assert pose.header.frame_id == "map" and odom.header.frame_id == "map"
        assert twist.header.frame_id == "camera_optical_frame"
        assert odom.child_frame_id == "camera_optical_frame"
        for cov in (
            np.reshape(pwc.pose.covariance, (6, 6)),
            np.reshape(odom.pose.covariance, (6, 6)),
            np.reshape(odom.twist.covariance, (6, 6)),
        ):
            assert np.isfinite(cov).all() and (np.diag(cov) > 0).all()
            np.testing.assert_allclose(cov, cov.T, atol=1e-12 + 1e-9 * np.abs(cov).max())
    # position covariance is consistent with the actual error (within a factor ~10)
    sig = [
        np.sqrt(
            np.trace(
                np.reshape(f["outputs"]["/camera/pose_with_covariance"][1].pose.covariance, (6, 6))[
                    :3, :3
                ]
            )
        )
        for f in res.frames
    ]
    ratio = s["pos_m"]["median"] / np.median(sig)
    assert 0.1 < ratio < 10, f"position error / predicted sigma = {ratio:.3g}"


def test_keypoints_with_landmark_map(node, ros_context, keypoints_bag):
    res, _gt, errs = _play(ros_context, keypoints_bag, outputs=OUTPUTS[:2])
    assert res.answered == len(res.frames) == 10, node.log
    _check_accuracy(errs, label="keypoints")


def test_solver_switch_at_runtime(
    node, ros_context, sample_bag, keypoints_bag, switched_solver_kernels
):
    topics = ["/camera/correspondences", "/camera/camera_info"]
    params = ParamClient(ros_context, "/camera/rs_localizer")
    try:
        (r,) = params.set(solver="p3p")
        assert r.successful, r.reason
        res, _gt, errs = _play(ros_context, sample_bag, offset_s=300.0, limit=10, topics=topics)
        assert res.answered == 10, node.log
        for f in res.frames:  # global shutter: no velocity
            tw = f["outputs"]["/camera/twist"][1].twist
            assert tw.angular.x == tw.angular.y == tw.angular.z == 0.0
        p3p_rot = np.median([e["rot_deg"] for e in errs])

        # rejected changes leave the node as it was
        (r,) = params.set(solver="r7p_magic")
        assert not r.successful and "unknown solver" in r.reason
        (r,) = params.set(map_frame="world")
        assert not r.successful  # read-only
        (r,) = params.set(**{"rs.line_delay": -1.0})
        assert not r.successful  # out of range
        (r,) = params.set(**{"rs.direction": "diagonal"})
        assert not r.successful
        (r,) = params.set(landmarks_file="/nonexistent/landmarks.csv")
        assert not r.successful and "cannot load landmarks_file" in r.reason
        (r,) = params.set(landmarks_file=str(keypoints_bag / "landmarks.csv"))  # reload
        assert r.successful

        (r,) = params.set(solver="r6p_1lin")
        assert r.successful
    finally:
        _restore(params, solver="r6p_1lin")
        params.close()
    res, _gt, errs = _play(ros_context, sample_bag, offset_s=400.0, limit=10, topics=topics)
    assert res.answered == 10
    _check_accuracy(errs, label="after switching back")
    rs_rot = np.median([e["rot_deg"] for e in errs])
    assert p3p_rot > 3 * rs_rot, (p3p_rot, rs_rot)
    assert node.alive()


def test_diagnostics(node, ros_context, sample_bag):
    res, _, _ = _play(
        ros_context,
        sample_bag,
        offset_s=500.0,
        limit=5,
        topics=["/camera/correspondences", "/camera/camera_info"],
    )
    assert res.answered == 5
    probe = Probe(ros_context)
    try:
        st, v = probe.wait_diag(lambda v: int(v.get("frames_solved", 0)) >= 5, timeout=10)
        assert st is not None, "no diagnostics from the node"
        for key in (
            "frames_received",
            "frames_solved",
            "frames_failed",
            "messages_lost",
            "inliers_last",
            "inliers_mean",
            "latency_ms_median",
            "latency_ms_p99",
            "solver",
            "camera",
            "planar",
            "condition_number_last",
        ):
            assert key in v, key
        assert v["solver"] == "r6p_1lin" and v["camera"] == "camera_info"
        assert v["planar"] == "false"  # a corridor: points in depth
        assert 1.0 <= float(v["condition_number_last"]) < 1e4
        assert int(v["frames_received"]) >= int(v["frames_solved"]) >= 5
        # (the last frame is this test's; the mean is over every frame the module's node
        # solved, the earlier tests' too: test_solver_switch_at_runtime's p3p ones with fewer)
        assert 300 < int(v["inliers_last"]) <= 500
        assert 0 < float(v["inliers_mean"]) <= 500
        assert 0 < float(v["latency_ms_median"]) <= float(v["latency_ms_p99"]) < 5000
    finally:
        probe.close()


def test_tracking_fused_twist_and_resets(node, ros_context, sample_bag, switched_solver_kernels):
    """With tracking (default) twist / odom carry the fused twist, a frame late and
    stamped with their frame's time, better than the per-frame twist on twist_single_frame;
    diagnostics count tracked frames; a solver change resets the track; tracking.enabled false
    gives the per-frame twist on twist again."""
    from rs_localizer.ros.conversions import stamp_to_ns

    topics = ["/camera/correspondences", "/camera/camera_info"]
    outs = OUTPUTS + ("/camera/twist_single_frame",)
    res, gt, errs = _play(ros_context, sample_bag, offset_s=700.0, topics=topics, outputs=outs)
    assert res.answered == len(res.frames) == 30, node.log
    single = []
    for f in res.frames:
        pose = f["outputs"]["/camera/pose"][1]
        sf = f["outputs"]["/camera/twist_single_frame"][1]
        tw = f["outputs"]["/camera/twist"][1]
        odom = f["outputs"]["/camera/odom"][1]
        stamp = stamp_to_ns(pose.header.stamp)
        assert stamp_to_ns(sf.header.stamp) == stamp == stamp_to_ns(tw.header.stamp)
        assert stamp_to_ns(odom.header.stamp) == stamp
        assert np.isfinite(np.reshape(odom.twist.covariance, (6, 6))).all()
        w = np.array([sf.twist.angular.x, sf.twist.angular.y, sf.twist.angular.z])
        v = np.array([sf.twist.linear.x, sf.twist.linear.y, sf.twist.linear.z])
        single.append(
            (
                np.linalg.norm(w - gt.angular_velocity[stamp]),
                np.linalg.norm(v - gt.linear_velocity[stamp]),
            )
        )
    single = np.array(single)
    fused_w = np.median([e["angvel"] for e in errs])
    fused_v = np.median([e["linvel"] for e in errs])
    # (bench_video: 0.009 vs 0.043 rad/s, 0.025 vs 0.29 m/s)
    assert fused_v < 0.4 * np.median(single[:, 1]), (fused_v, np.median(single[:, 1]))
    assert fused_w < 0.7 * np.median(single[:, 0]), (fused_w, np.median(single[:, 0]))
    probe = Probe(ros_context)
    params = ParamClient(ros_context, "/camera/rs_localizer")
    try:
        st, v = probe.wait_diag(lambda v: int(v.get("frames_tracked", 0)) >= 29, timeout=10)
        assert st is not None and v["track_state"] == "tracking", v
        resets0 = int(v["resets"])
        (r,) = params.set(solver="r6p_vC_wt")  # a solver change resets the track
        assert r.successful, r.reason
        res, _, _ = _play(
            ros_context, sample_bag, offset_s=701.0, limit=4, topics=topics, outputs=outs
        )
        assert res.answered == 4, node.log
        st, v = probe.wait_diag(lambda v: int(v.get("resets", 0)) > resets0, timeout=10)
        assert st is not None, "no reset after the solver change"
        for r in params.set(solver="r6p_1lin", **{"tracking.enabled": False}):
            assert r.successful, r.reason
        res, _, _ = _play(
            ros_context, sample_bag, offset_s=702.0, limit=3, topics=topics, outputs=outs
        )
        assert res.answered == 3, node.log
        for f in res.frames:  # the per-frame twist again, with the frame
            tw = f["outputs"]["/camera/twist"][1].twist
            sf = f["outputs"]["/camera/twist_single_frame"][1].twist
            assert (tw.linear.x, tw.angular.y) == (sf.linear.x, sf.angular.y)
        st, v = probe.wait_diag(lambda v: v.get("track_state") == "disabled", timeout=10)
        assert st is not None
    finally:
        _restore(params, solver="r6p_1lin", **{"tracking.enabled": True})
        params.close()
        probe.close()


# ---------------------------------------------------------------------------- bad input
@pytest.fixture(scope="module")
def frames():
    from rs_localizer.sim.trajectory import SequenceConfig, generate_sequence

    fr, scene, cam, _ = generate_sequence(
        SequenceConfig(num_frames=16, num_points=300, seed=5, t0_ns=1_800_000_000_000_000_000)
    )
    return fr, scene, cam


def test_bad_inputs(tmp_path, ros_context, frames):
    """Every bad input is dropped with its reason counted; valid frames after it still solve."""
    from sensor_msgs.msg import PointField

    from rs_localizer.maps import save_landmarks_csv
    from rs_localizer.ros import pointcloud as pc
    from rs_localizer.ros.conversions import camera_info_msg

    fr, scene, cam = frames
    lm = tmp_path / "landmarks.csv"
    save_landmarks_csv(lm, scene.ids, scene.points)
    node = start_node(
        tmp_path,
        {"diagnostics_period": 0.2, "max_points": 2000, "landmarks_file": str(lm)},
        namespace="/bad",
        name="bad",
    )
    probe = Probe(ros_context, namespace="/bad")
    try:
        probe.wait_matched()
        it = iter(fr)
        expected = {}
        received = 0

        def cloud(f, stamp=None, **kw):
            return pc.correspondence_cloud(
                f.uv, f.xyz, frame_id="cam", stamp=f.stamp_ns if stamp is None else stamp, **kw
            )

        def bad(msg, reason, topic="corr"):
            nonlocal received
            (probe.pub_corr if topic == "corr" else probe.pub_kp).publish(msg)
            received += 1
            if reason:
                expected[reason] = expected.get(reason, 0) + 1

        def good(f=None, msg=None, topic="corr"):
            nonlocal received
            f = f or next(it)
            (probe.pub_corr if topic == "corr" else probe.pub_kp).publish(msg or cloud(f))
            received += 1
            pose = probe.wait_pose(f.t_ref_ns, timeout=20)
            assert pose is not None, f"no pose for a valid frame after {expected}:\n{node.log}"
            return f

        # no camera_info yet (and no fallback intrinsics)
        f0 = next(it)
        bad(cloud(f0), "no_camera_info")
        st, v = probe.wait_diag(lambda v: v.get("failed.no_camera_info") == "1")
        assert v.get("failed.no_camera_info") == "1" and v["camera"] == "missing", v
        probe.pub_info.publish(camera_info_msg(cam, "cam", f0.stamp_ns))
        probe.wait_diag(lambda v: v.get("camera") == "camera_info")
        last = good(f0)

        # missing fields
        f = next(it)
        arr = pc.correspondence_array(f.uv, f.xyz)
        no_z = arr[["u", "v", "x", "y"]]
        bad(pc.array_to_cloud(np.ascontiguousarray(no_z), "cam", f.stamp_ns - 1), "missing_fields")
        last = good(f)
        # wrong field types
        f = next(it)
        m = cloud(f, stamp=f.stamp_ns - 1)
        m.fields[0] = PointField(name="u", offset=0, datatype=PointField.UINT32, count=1)
        bad(m, "wrong_field_type")
        last = good(f)
        # truncated data
        f = next(it)
        m = cloud(f, stamp=f.stamp_ns - 1)
        m.data = bytes(m.data)[:-7]
        bad(m, "truncated")
        last = good(f)
        # empty cloud
        bad(
            pc.correspondence_cloud(np.zeros((0, 2)), np.zeros((0, 3)), stamp=last.stamp_ns + 1),
            "empty_cloud",
        )
        # NaN/inf rows: dropped by the estimator, frame still solved
        f = next(it)
        uv = f.uv.copy()
        uv[:20, 0] = np.nan
        uv[20:30, 1] = np.inf
        xyz = f.xyz.copy()
        xyz[30:40, 2] = -np.inf
        last = good(f, pc.correspondence_cloud(uv, xyz, frame_id="cam", stamp=f.stamp_ns))
        probe.wait_diag(lambda v: int(v.get("points_dropped", 0)) >= 40)
        assert int(probe.node_diag()[1]["points_dropped"]) >= 40
        # only NaN rows
        f = next(it)
        bad(
            pc.correspondence_cloud(np.full((50, 2), np.nan), f.xyz[:50], stamp=f.stamp_ns - 1),
            None,
        )
        last = good(f)
        # fewer than the minimum
        f = next(it)
        bad(pc.correspondence_cloud(f.uv[:4], f.xyz[:4], stamp=f.stamp_ns - 1), None)
        last = good(f)
        # all outliers
        f = next(it)
        rng = np.random.default_rng(0)
        bad(
            pc.correspondence_cloud(
                rng.uniform([0, 0], [1279, 719], (300, 2)), f.xyz, stamp=f.stamp_ns - 1
            ),
            None,
        )
        last = good(f)
        # a stamp older than the last frame: solved all the same (a time reset, counted)
        f = next(it)
        old = last.stamp_ns - 10_000_000
        probe.pub_corr.publish(cloud(f, stamp=old))
        received += 1
        assert probe.wait_pose(old + f.t_ref_ns - f.stamp_ns, timeout=20) is not None, node.log
        probe.wait_diag(lambda v: v.get("time_resets") == "1")
        assert probe.node_diag()[1]["time_resets"] == "1"
        last = good(f)
        # unknown landmark ids: some (dropped, counted, solved) and all (failure)
        f = next(it)
        ids = f.ids.copy()
        ids[:50] = 999_999_999
        last = good(f, pc.keypoint_cloud(f.uv, ids, frame_id="cam", stamp=f.stamp_ns), "kp")
        probe.wait_diag(lambda v: int(v.get("unknown_landmark_ids", 0)) >= 50)
        f = next(it)
        bad(
            pc.keypoint_cloud(f.uv, np.arange(300) + 3_000_000_000, stamp=f.stamp_ns - 1),
            "unknown_landmarks",
            "kp",
        )
        # (another topic: wait until it is processed before the next frame)
        probe.wait_diag(lambda v: v.get("failed.unknown_landmarks") == "1")
        last = good(f)
        # huge cloud: capped to max_points, still solved
        f = next(it)
        reps = 40
        uv = np.tile(f.uv, (reps, 1)) + rng.normal(0, 0.05, (reps * len(f.uv), 2))
        last = good(
            f,
            pc.correspondence_cloud(
                uv, np.tile(f.xyz, (reps, 1)), frame_id="cam", stamp=f.stamp_ns
            ),
        )
        expected_capped = 1

        st, v = probe.wait_diag(
            lambda v: (
                int(v.get("frames_received", 0)) == received and v.get("frames_pending") == "0"
            )
        )
        assert int(v["frames_received"]) == received, v
        log = assert_dropped(node, st, v, expected)
        # the estimator's own reasons for the three data-limited frames
        est_reasons = {
            k: int(x)
            for k, x in v.items()
            if k.startswith("failed.")
            and k[7:]
            in (
                "degenerate_geometry",
                "too_few_points",
                "no_hypothesis",
                "too_few_inliers",
                "implausible_motion",
                "cheirality",
                # (4 points near one plane: the one-tag path, whose two poses they cannot
                # tell apart)
                "ambiguous_tag",
            )
        }
        assert sum(est_reasons.values()) == 3, v
        assert int(v["frames_failed"]) == sum(expected.values()) + 3
        assert int(v["clouds_capped"]) == expected_capped
        assert int(v["frames_solved"]) == len(probe.outputs["pose"])
        assert "capped to max_points 2000" in log
    finally:
        alive, rc = stop_node(node, probe)
    assert alive and rc == 0, node.log


def test_fallback_intrinsics_without_camera_info(tmp_path, ros_context, frames):
    from rs_localizer.ros import pointcloud as pc

    fr, _, cam = frames
    K, D = cam.K, cam.D
    node = start_node(
        tmp_path,
        {
            "camera.fx": K[0, 0],
            "camera.fy": K[1, 1],
            "camera.cx": K[0, 2],
            "camera.cy": K[1, 2],
            "camera.width": cam.width,
            "camera.height": cam.height,
            "camera.distortion_model": "plumb_bob",
            "camera.d": [float(x) for x in D],
            "rs.readout_time": cam.readout_time,
            "rs.line_delay": 0.0,
        },
        namespace="/fallback",
        name="fallback",
    )
    probe = Probe(ros_context, namespace="/fallback")
    try:
        probe.wait_matched()
        for f in fr[:3]:
            probe.pub_corr.publish(pc.correspondence_cloud(f.uv, f.xyz, stamp=f.stamp_ns))
            assert probe.wait_pose(f.t_ref_ns) is not None, node.log
        from rs_localizer.geometry import rotation_angle_deg
        from rs_localizer.ros.conversions import pose_from_msg

        R, p = pose_from_msg(probe.pose_near(fr[2].t_ref_ns).pose)
        assert rotation_angle_deg(R, fr[2].orientation) < LIMITS["rot_deg"][1]
        assert np.linalg.norm(p - fr[2].position) < LIMITS["pos_m"][1]
        _st, v = probe.wait_diag(lambda v: v.get("camera") == "parameters")
        assert v["camera"] == "parameters"
    finally:
        probe.close()
        node.stop()


def test_yaml_integer_for_double_is_a_clear_error(tmp_path, ros_domain):
    from helpers.ros import refused_start

    bad = tmp_path / "bad.yaml"
    bad.write_text("/**:\n  ros__parameters:\n    ransac:\n      threshold_px: 2\n")
    exited, _, log = refused_start(tmp_path, [bad], "/yaml", 60)
    assert exited
    assert "ransac.threshold_px" in log and "0.0" in log


def test_demo_command(ros_domain, tmp_path):
    """`make demo`'s command: two nodes (RS solver and p3p) on the sample bag, then two nodes
    in image mode (ArUco front end) on the rendered sample, each with a summary."""
    import subprocess
    import sys

    from helpers.paths import ROOT

    pytest.importorskip("rosbags")
    if not (ROOT / "data" / "sample" / "metadata.yaml").exists():
        pytest.skip("no sample bag")
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    out = subprocess.run(
        [sys.executable, "-m", "rs_localizer", "demo", "--summary-only"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "TMPDIR": str(tmp)},
    )
    assert out.returncode == 0, out.stdout + out.stderr
    # a successful demo removes its working directory (node logs, QoS file)
    assert not list(tmp.glob("rs_localizer_demo_*"))
    corr, _, images = out.stdout.partition("rs_localizer demo (image mode)")
    assert "r6p_1lin: 30/30 frames" in corr and "p3p: 30/30 frames" in corr
    assert "smaller" in corr
    assert images, out.stdout
    assert "aruco front end" in images and "marker corners per image" in images
    assert "r6p_1lin: 20/20 frames" in images and "p3p: 20/20 frames" in images
    assert "smaller" in images


# ------------------------------------------------------------------ never a wrong pose
def _settle(probe, timeout=30.0):
    """Wait until the node has nothing pending and its counters stopped changing; returns
    the diagnostics values."""
    prev = None
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        probe.spin(0.5)
        v = probe.node_diag()[1]
        key = (
            v.get("frames_received"),
            v.get("frames_solved"),
            v.get("frames_failed"),
            v.get("frames_skipped"),
            v.get("frames_pending"),
        )
        if key == prev and v.get("frames_pending", "0") == "0":
            return v
        prev = key
    return probe.node_diag()[1]


def _n(v, key):
    return int(v.get(key, 0))


def _received(v) -> bool:
    """The node's diagnostics values count a frame received."""
    return _n(v, "frames_received") >= 1


@pytest.fixture(scope="module")
def rel_node(tmp_path_factory, frames):
    """One node for the issue-11 checks: namespace /rel, reliable inputs, a landmark map."""
    from rs_localizer.maps import save_landmarks_csv

    _fr, scene, _cam = frames
    tmp = tmp_path_factory.mktemp("rel")
    lm = tmp / "landmarks.csv"
    save_landmarks_csv(lm, scene.ids, scene.points)
    n = start_node(
        tmp,
        {"diagnostics_period": 0.2, "max_points": 2000, "landmarks_file": str(lm)},
        namespace="/rel",
        name="rel",
    )
    n.landmarks = lm
    yield n
    alive = n.alive()
    rc = n.stop()
    assert alive, f"node died:\n{n.log}"
    assert rc == 0, f"node exit code {rc}:\n{n.log}"


@pytest.fixture
def rel(rel_node, ros_context, frames):
    """A probe on /rel with the camera_info of ``frames`` published and the counters settled."""
    from rs_localizer.ros.conversions import camera_info_msg

    _fr, _, cam = frames
    probe = Probe(ros_context, namespace="/rel")
    probe.wait_matched()
    probe.pub_info.publish(camera_info_msg(cam, "cam", 0))
    probe.wait_diag(lambda v: v.get("camera") == "camera_info", timeout=10)
    yield probe
    probe.close()
    assert rel_node.alive(), rel_node.log


def _shifted(f, k, dt_ns):
    """Frame ``f`` restamped ``dt_ns`` later (``k``: a label): the same pixels and points."""
    from dataclasses import replace

    return replace(f, index=k, stamp_ns=f.stamp_ns + dt_ns, t_ref_ns=f.t_ref_ns + dt_ns)


def test_implausible_frames_are_never_published(rel_node, rel, frames):
    """A v field at u's offset, pixels with v == u, points reflected through the
    camera centre: each fails with its reason and publishes nothing; rows behind the camera
    count in points_dropped."""
    from sensor_msgs.msg import PointField

    from rs_localizer.ros import pointcloud as pc

    fr, _, _cam = frames
    probe = rel
    base = _settle(probe)
    t0 = 50_000_000_000
    f = _shifted(fr[1], 0, t0)
    m = pc.correspondence_cloud(f.uv, f.xyz, frame_id="cam", stamp=f.stamp_ns)
    m.fields[1] = PointField(name="v", offset=0, datatype=PointField.FLOAT32, count=1)
    probe.pub_corr.publish(m)
    f = _shifted(fr[2], 1, t0 + 1_000_000)
    uv = f.uv.copy()
    uv[:, 1] = uv[:, 0]
    probe.pub_corr.publish(pc.correspondence_cloud(uv, f.xyz, stamp=f.stamp_ns))
    f = _shifted(fr[3], 2, t0 + 2_000_000)
    probe.pub_corr.publish(pc.correspondence_cloud(f.uv, 2 * f.position - f.xyz, stamp=f.stamp_ns))
    # 30 % of the rows behind the camera: solved, those rows counted as dropped
    f = _shifted(fr[4], 3, t0 + 3_000_000)
    n = int(0.3 * len(f.xyz))
    X = f.xyz.copy()
    X[:n] = 2 * f.position - X[:n]
    probe.pub_corr.publish(pc.correspondence_cloud(f.uv, X, stamp=f.stamp_ns))
    assert probe.wait_pose(f.t_ref_ns, timeout=20) is not None, rel_node.log
    v = _settle(probe)
    assert _n(v, "frames_received") - _n(base, "frames_received") == 4
    assert _n(v, "failed.bad_layout") - _n(base, "failed.bad_layout") == 1
    assert _n(v, "failed.degenerate_geometry") - _n(base, "failed.degenerate_geometry") == 1
    implausible = sum(
        _n(v, f"failed.{r}") - _n(base, f"failed.{r}")
        for r in ("implausible_motion", "cheirality", "no_hypothesis", "too_few_inliers")
    )
    assert implausible == 1, v
    assert _n(v, "frames_solved") - _n(base, "frames_solved") == 1
    assert _n(v, "points_dropped") - _n(base, "points_dropped") == n
    for k in range(3):  # nothing published for the three bad frames
        assert probe.pose_near(_shifted(fr[k + 1], k, t0 + k * 1_000_000).t_ref_ns) is None


def test_camera_info_is_chosen_by_stamp(tmp_path, ros_context, frames):
    """A camera_info published just before its frame is the one that frame uses (two
    cameras alternate: principal points 40 px apart, ~2.3 deg of rotation if mixed up), also
    for the very first frame, and with the frame published before its camera_info (the order
    of image_transport's CameraPublisher; ``camera_info_wait`` 1 s: on a loaded machine the
    camera_info sent right after its frame reached the node more than the default 50 ms
    later, and the frame took the previous camera's)."""
    from dataclasses import replace as dc_replace

    from rs_localizer.geometry import rotation_angle_deg
    from rs_localizer.ros import pointcloud as pc
    from rs_localizer.ros.conversions import camera_info_msg, pose_from_msg

    fr, _, cam = frames
    K2 = cam.K.copy()
    K2[0, 2] += 40.0
    cam2 = dc_replace(cam, K=K2)
    node = start_node(
        tmp_path,
        {"diagnostics_period": 0.2, "camera_info_wait": 1.0},
        namespace="/cinfo",
        name="cinfo",
    )
    probe = Probe(ros_context, namespace="/cinfo")
    try:
        probe.wait_matched()
        errs = []
        for k, f in enumerate(fr[:12]):
            c, shift = (cam2, 40.0) if k % 2 else (cam, 0.0)
            info = camera_info_msg(c, "cam", f.stamp_ns)
            cloud = pc.correspondence_cloud(
                f.uv + [shift, 0.0], f.xyz, frame_id="cam", stamp=f.stamp_ns
            )
            if k < 8:  # camera_info first, then the frame, at once
                probe.pub_info.publish(info)
                probe.pub_corr.publish(cloud)
            else:  # the frame first
                probe.pub_corr.publish(cloud)
                probe.pub_info.publish(info)
            # (the frame subscription is best effort: a first frame sent while discovery
            # finishes on the node's side is lost, received by nobody; the pair is sent again
            # while the node's diagnostics count no frame received)
            for _ in range(4 if k == 0 else 0):
                if _received(probe.wait_diag(_received, timeout=5.0)[1]):
                    break
                probe.pub_info.publish(info)
                probe.pub_corr.publish(cloud)
            pose = probe.wait_pose(f.t_ref_ns, timeout=20)
            assert pose is not None, f"frame {k} not solved:\n{node.log}"
            R, _ = pose_from_msg(pose.pose)
            errs.append(rotation_angle_deg(R, f.orientation))
        assert max(errs) < LIMITS["rot_deg"][1], np.round(errs, 3)
        v = _settle(probe)
        assert _n(v, "frames_solved") == 12 and _n(v, "frames_failed") == 0, v
    finally:
        alive, rc = stop_node(node, probe)
    assert alive and rc == 0, node.log


def test_camera_info_validation_keeps_the_previous_camera(rel_node, rel, frames):
    """A ROI outside the image, a plumb_bob D with 3 or 6
    coefficients, a NaN cx are rejected with their reason; frames keep using the previous
    camera and stay accurate."""
    from rs_localizer.geometry import rotation_angle_deg
    from rs_localizer.ros import pointcloud as pc
    from rs_localizer.ros.conversions import camera_info_msg, pose_from_msg

    fr, _, cam = frames
    probe = rel
    base = _settle(probe)
    t0 = 60_000_000_000
    bad = []
    m = camera_info_msg(cam, "cam", 0)
    m.roi.x_offset, m.roi.y_offset, m.roi.width, m.roi.height = 900, 0, 640, 480
    bad.append(("bad_roi", m))
    m = camera_info_msg(cam, "cam", 0)
    m.roi.width, m.roi.height = 5000, 5000
    bad.append(("bad_roi", m))
    for d in ([0.1, -0.05, 0.01], [0.1, -0.05, 0.001, 0.001, 0.01, 0.2]):
        m = camera_info_msg(cam, "cam", 0)
        m.d = d
        bad.append(("bad_distortion", m))
    m = camera_info_msg(cam, "cam", 0)
    k = list(m.k)
    k[2] = float("nan")
    m.k = k
    bad.append(("bad_intrinsics", m))
    for k, (_, m) in enumerate(bad):
        probe.pub_info.publish(m)
        f = _shifted(fr[5 + k], k, t0 + k * 100_000_000)
        probe.pub_corr.publish(pc.correspondence_cloud(f.uv, f.xyz, stamp=f.stamp_ns))
        pose = probe.wait_pose(f.t_ref_ns, timeout=20)
        assert pose is not None, rel_node.log
        R, p = pose_from_msg(pose.pose)
        assert rotation_angle_deg(R, f.orientation) < LIMITS["rot_deg"][1]
        assert np.linalg.norm(p - f.position) < LIMITS["pos_m"][1]
    v = _settle(probe)
    for reason in ("bad_roi", "bad_distortion", "bad_intrinsics"):
        n = sum(r == reason for r, _ in bad)
        key = f"camera_info_rejected.{reason}"
        assert _n(v, key) - _n(base, key) == n, (reason, v)
    assert "non-finite" in rel_node.log and "fx or fy <= 0" not in rel_node.log


def test_invalid_stamps_are_rejected_never_wrapped(rel_node, rel, frames):
    """A stamp with nanosec >= 1e9 or a negative sec, and one whose output (+ the reference row's
    10.8 ms) does not fit int32 seconds: each fails with bad_stamp; nothing wraps."""
    from rs_localizer.ros import pointcloud as pc
    from rs_localizer.ros.conversions import stamp_to_ns

    fr, _, _cam = frames
    probe = rel
    base = _settle(probe)
    f = fr[6]
    n_poses = len(probe.outputs["pose"])
    for sec, nsec in ((70, 4_000_000_000), (70, 1_000_000_000), (-5, 0), (2**31 - 1, 999_999_999)):
        m = pc.correspondence_cloud(f.uv, f.xyz, frame_id="cam")
        m.header.stamp.sec, m.header.stamp.nanosec = sec, nsec
        probe.pub_corr.publish(m)
    g = _shifted(fr[7], 0, 75_000_000_000)
    probe.pub_corr.publish(pc.correspondence_cloud(g.uv, g.xyz, stamp=g.stamp_ns))
    assert probe.wait_pose(g.t_ref_ns, timeout=20) is not None, rel_node.log
    v = _settle(probe)
    assert _n(v, "failed.bad_stamp") - _n(base, "failed.bad_stamp") == 4, v
    new = probe.outputs["pose"][n_poses:]
    assert len(new) == 1 and stamp_to_ns(new[0].header.stamp) == g.t_ref_ns
    assert all(m.header.stamp.sec >= 0 for m in probe.outputs["pose"])


def test_time_jumps_never_drop_valid_frames(rel_node, rel, ros_context, sample_bag, frames):
    """The sample bag played twice into one node (a jump back of 0.967 s) is
    answered in full both times; a frame stamped 0.9 s ahead does not drop the frames after
    it. Each jump back is a counted time reset."""
    from rs_localizer.ros import pointcloud as pc
    from rs_localizer.ros.bags.play import play

    probe = rel
    base = _settle(probe)
    remap = {
        "/camera/correspondences": "/rel/correspondences",
        "/camera/camera_info": "/rel/camera_info",
    }
    resets = []
    for _ in range(2):
        res = play(
            sample_bag,
            lockstep=True,
            output_topics=("/rel/pose",),
            context=ros_context,
            timeout=5.0,
            topics=list(remap),
            remap=remap,
            stamp_offset_ns=900_000_000_000,
            log=print,
        )
        assert len(res.frames) == 30 and res.answered == 30, rel_node.log
        resets.append(_n(_settle(probe), "time_resets"))
    assert resets[1] - resets[0] == 1  # the second playback starts 0.967 s back
    fr, _, _cam = frames
    t0 = 950_000_000_000
    seq = [_shifted(fr[k], k, t0) for k in range(8)]
    spike = _shifted(fr[3], 99, t0 + 900_000_000)  # 0.9 s ahead of the frame before it
    for k, f in enumerate(seq):
        probe.pub_corr.publish(pc.correspondence_cloud(f.uv, f.xyz, stamp=f.stamp_ns))
        if k == 3:
            probe.pub_corr.publish(
                pc.correspondence_cloud(spike.uv, spike.xyz, stamp=spike.stamp_ns)
            )
        assert probe.wait_pose(f.t_ref_ns, timeout=20) is not None, (k, rel_node.log)
    assert probe.pose_near(spike.t_ref_ns) is not None
    v = _settle(probe)
    # the gap from the bag's stamps to these frames, and the step back after the spike
    assert _n(v, "time_resets") - resets[1] == 2, v
    assert _n(v, "frames_solved") - _n(base, "frames_solved") == 69
    assert "time reset" in rel_node.log


def test_landmarks_file_fifo_does_not_hang_the_node(rel_node, rel, ros_context, tmp_path, frames):
    """landmarks_file set to a FIFO (a read would hang SetParameters and stop the frames) is
    refused at once: only regular files are read."""
    import os

    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    from rs_localizer.ros import pointcloud as pc

    fifo = tmp_path / "landmarks.fifo"
    os.mkfifo(fifo)
    params = ParamClient(ros_context, "/rel/rs_localizer")
    try:
        for path in (str(fifo), str(tmp_path)):
            req = SetParameters.Request()
            req.parameters = [Parameter("landmarks_file", value=path).to_parameter_msg()]
            t0 = time.monotonic()
            fut = params.cli.call_async(req)
            params.ex.spin_until_future_complete(fut, timeout_sec=5.0)
            assert fut.done(), "SetParameters did not return within 5 s"
            (r,) = fut.result().results
            assert not r.successful and "not a regular file" in r.reason, r.reason
            assert time.monotonic() - t0 < 5.0
        (r,) = params.set(landmarks_file=str(rel_node.landmarks))
        assert r.successful
    finally:
        # (on failure: release a reader blocked on the FIFO)
        with contextlib.suppress(OSError):
            os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        params.close()
    fr, _, _ = frames
    f = _shifted(fr[9], 0, 1_000_000_000_000)
    rel.pub_corr.publish(pc.correspondence_cloud(f.uv, f.xyz, stamp=f.stamp_ns))
    assert rel.wait_pose(f.t_ref_ns, timeout=20) is not None, rel_node.log


def test_smaller_defects(rel_node, rel, ros_context, frames):
    """The cap applies after NaN rows are dropped; an extra field of unknown datatype
    is ignored; identical points are degenerate_geometry; camera.d = NaN and max_points below
    the inliers a pose needs are rejected parameter values."""
    from sensor_msgs.msg import PointField

    from rs_localizer.ros import pointcloud as pc

    fr, _, _ = frames
    probe = rel
    base = _settle(probe)
    t0 = 1_100_000_000_000
    # 300 valid rows among 20000 (max_points 2000): all 300 are kept, nothing is capped
    f = _shifted(fr[10], 0, t0)
    n_rows = 20_000
    rows = np.sort(np.random.default_rng(0).choice(n_rows, len(f.uv), replace=False))
    uv = np.full((n_rows, 2), np.nan)
    xyz = np.full((n_rows, 3), np.nan)
    uv[rows], xyz[rows] = f.uv, f.xyz
    probe.pub_corr.publish(pc.correspondence_cloud(uv, xyz, stamp=f.stamp_ns))
    assert probe.wait_pose(f.t_ref_ns, timeout=20) is not None, rel_node.log
    v = probe.wait_diag(lambda v: _n(v, "frames_solved") > _n(base, "frames_solved"))[1]
    assert _n(v, "clouds_capped") == _n(base, "clouds_capped"), v
    assert _n(v, "inliers_last") > 0.7 * len(f.uv), v
    assert _n(v, "points_dropped") - _n(base, "points_dropped") >= n_rows - len(f.uv)
    # an extra field of unknown datatype
    f = _shifted(fr[11], 1, t0 + 100_000_000)
    m = pc.correspondence_cloud(f.uv, f.xyz, stamp=f.stamp_ns)
    m.fields = list(m.fields) + [PointField(name="rgb", offset=0, datatype=42, count=1)]
    probe.pub_corr.publish(m)
    assert probe.wait_pose(f.t_ref_ns, timeout=20) is not None, rel_node.log
    # identical points
    f = _shifted(fr[12], 2, t0 + 200_000_000)
    probe.pub_corr.publish(
        pc.correspondence_cloud(
            np.tile(f.uv[:1], (100, 1)), np.tile(f.xyz[:1], (100, 1)), stamp=f.stamp_ns
        )
    )
    v = probe.wait_diag(
        lambda v: _n(v, "failed.degenerate_geometry") > _n(base, "failed.degenerate_geometry")
    )[1]
    assert _n(v, "failed.degenerate_geometry") == _n(base, "failed.degenerate_geometry") + 1
    params = ParamClient(ros_context, "/rel/rs_localizer")
    try:
        (r,) = params.set(**{"camera.d": [float("nan"), 0.0, 0.0, 0.0, 0.0]})
        assert not r.successful and "camera.d" in r.reason
        (r,) = params.set(max_points=11)
        assert not r.successful and "max_points" in r.reason
        (r,) = params.set(**{"ransac.min_inliers": 3000})
        assert not r.successful and "max_points" in r.reason
    finally:
        params.close()


def _flood(probe, pub, msgs, rate_hz):
    """Publish ``msgs`` at ``rate_hz`` (busy-waiting between messages, taking the probe's own
    messages when more than 1 ms ahead); returns the achieved rate."""
    t0 = time.perf_counter()
    for k, m in enumerate(msgs):
        while time.perf_counter() < t0 + k / rate_hz:
            if time.perf_counter() < t0 + k / rate_hz - 1e-3:
                probe.executor.spin_once(timeout_sec=0)
        pub.publish(m)
    return len(msgs) / (time.perf_counter() - t0)


class _Messages:
    """``n`` messages built on demand by ``make(k)`` (a long flood without holding them all)."""

    def __init__(self, n, make):
        self.n, self.make = n, make

    def __len__(self):
        return self.n

    def __getitem__(self, k):
        if not 0 <= k < self.n:
            raise IndexError(k)
        return self.make(k)


def test_flood_accounting(tmp_path, ros_context, frames):
    """Under a flood the node knows what it received and what it skipped:
    received = solved + failed + skipped, skipped > 0, diagnostics WARN, latency measured
    from arrival. Best effort at ~2 kHz on correspondences (300 points; a loaded machine's
    middleware may drop most of them before the node, which then keeps up with the rest and
    skips none), then reliable at
    ~300 Hz on keypoints (4500 points, ~3 ms to solve: more than the node can keep up with at
    that rate; 1500 points no longer were once tracked frames got faster), 2 s each;
    reliable frames reach the node: at least 80 % of those that
    reach a bare subscriber of the node's QoS in another process (``helpers/count_messages.py``,
    under the same load; on an idle machine both take all of them). ``RS_FLOOD_SECONDS=60``: each
    stream 60 s instead of 2; ``RS_FLOOD_COLD=1``: the node starts on an empty numba cache
    (its frames solved uncompiled while the kernels compile in the background). The node is stopped
    (SIGSTOP) for 0.7 s during a third, reliable stream. Every diagnostics message (20 Hz) keeps
    received = solved + failed + skipped + pending."""
    import os
    import signal
    import subprocess
    import sys
    import threading
    from pathlib import Path

    from helpers import count_messages
    from helpers.paths import CONFIG

    from rs_localizer.maps import save_landmarks_csv
    from rs_localizer.ros import pointcloud as pc
    from rs_localizer.ros.conversions import camera_info_msg
    from rs_localizer.ros.process import NodeProcess, ros_env, write_params_yaml

    fr, scene, cam = frames
    lm = tmp_path / "landmarks.csv"
    save_landmarks_csv(lm, scene.ids, scene.points)
    ns = "/flood"
    overlay = write_params_yaml(
        tmp_path / "flood.yaml",
        {"diagnostics_period": 0.05, "landmarks_file": str(lm)},
        reliable_topics=[f"{ns}/keypoints", f"{ns}/camera_info"],
    )  # correspondences: best effort
    env = ros_env()
    if os.environ.get("RS_FLOOD_COLD") == "1":  # (a cold start: solved uncompiled meanwhile)
        env["NUMBA_CACHE_DIR"] = str(tmp_path / "empty_numba_cache")
    node = NodeProcess([CONFIG, overlay], namespace=ns, env=env, log=tmp_path / "flood.log")
    assert node.wait_ready(120), node.log
    probe = Probe(ros_context, namespace=ns)
    # the reference: a bare subscriber of the keypoints with the node's QoS in its own process
    # (helpers/count_messages.py), under the same load as the node
    ref_out = tmp_path / "reference_stamps.txt"
    ref = subprocess.Popen(
        [sys.executable, str(Path(count_messages.__file__)), f"{ns}/keypoints", "100", ref_out],
        env=ros_env(), stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert ref.stdout.readline().strip() == "ready"
        probe.wait_matched()
        assert probe.wait(lambda: probe.pub_kp.get_subscription_count() >= 2, 30)
        probe.pub_info.publish(camera_info_msg(cam, "cam", 0))
        probe.wait_diag(lambda v: v.get("camera") == "camera_info", timeout=10)
        t0 = 2_000_000_000_000
        results = {}
        phases = (("best_effort", 2000.0, 2.0), ("reliable", 300.0, 2.0), ("stopped", 300.0, 2.0))
        for kind, rate, secs in phases:
            base = _settle(probe)
            n = int(rate * secs * float(os.environ.get("RS_FLOOD_SECONDS", 2.0)) / 2.0)
            dt = int(1e9 / rate)
            if kind == "best_effort":
                msgs = _Messages(
                    n,
                    lambda k, t0=t0, dt=dt: pc.correspondence_cloud(
                        fr[k % len(fr)].uv, fr[k % len(fr)].xyz, stamp=t0 + k * dt
                    ),
                )
                pub = probe.pub_corr
            else:
                rng = np.random.default_rng(1)
                big = [
                    (
                        np.tile(f.uv, (15, 1)) + rng.normal(0, 0.3, (15 * len(f.uv), 2)),
                        np.tile(f.ids, 15),
                    )
                    for f in fr
                ]
                msgs = _Messages(
                    n,
                    lambda k, t0=t0, dt=dt, big=big: pc.keypoint_cloud(
                        *big[k % len(fr)], stamp=t0 + k * dt
                    ),
                )
                pub = probe.pub_kp
            timers = []
            if kind == "stopped":
                pid = node.proc.pid
                timers = [
                    threading.Timer(0.5, os.kill, (pid, signal.SIGSTOP)),
                    threading.Timer(1.2, os.kill, (pid, signal.SIGCONT)),
                ]
            for t in timers:
                t.start()
            achieved = _flood(probe, pub, msgs, rate)
            for t in timers:
                t.join()
            v = _settle(probe, timeout=60)
            st, v = probe.node_diag()
            d = {
                k: _n(v, f"frames_{k}") - _n(base, f"frames_{k}")
                for k in ("received", "solved", "failed", "skipped")
            }
            results[kind] = dict(
                sent=n,
                stamps=(t0, t0 + (n - 1) * dt),
                rate=round(achieved),
                **d,
                latency_ms_median=v["latency_ms_median"],
                latency_ms_p99=v["latency_ms_p99"],
                estimate_ms_median=v["estimate_ms_median"],
                stamp_age_ms_median=v["stamp_age_ms_median"],
                messages_lost=v.get("messages_lost"),  # (so far: lost by the middleware)
            )
            print(kind, results[kind])
            t0 += n * dt + 1_000_000_000
            assert d["received"] == d["solved"] + d["failed"] + d["skipped"], (kind, d, v)
            assert v["frames_pending"] == "0"
            assert d["received"] <= n
            assert d["solved"] > 0 and d["failed"] == 0, (kind, d, v)
            # latency from arrival includes the wait in the queue
            assert float(v["latency_ms_median"]) >= float(v["estimate_ms_median"])
            if kind == "best_effort" and d["skipped"] == 0:
                # (the middleware dropped the flood before the node, which kept up with what
                # reached it: what it never saw it cannot count)
                assert d["received"] < n, (kind, d)
                continue
            assert d["skipped"] > 0, (kind, d)
            assert st.level == st.WARN and "skipped" in st.message, st.message
        # the accounting holds in every message, not only once the node is idle
        history = [v for name, v in probe.diag_history if name.endswith(f"{ns}/rs_localizer")]
        assert len(history) >= 40, len(history)
        for v in history:
            parts = [_n(v, f"frames_{k}") for k in ("solved", "failed", "skipped", "pending")]
            assert _n(v, "frames_received") == sum(parts), v
        assert "frame queue full" in node.log
        # the reliable frames reach the node as they reach a bare subscriber under the same
        # load (on an idle machine all of them; a loaded one's middleware loses what a
        # subscriber falls more than its depth of 100 behind): a node whose callbacks held the
        # executor while frames are solved (~3 ms each at 300 Hz) took about half of them
        ref.send_signal(signal.SIGTERM)
        assert ref.wait(30) == 0
        for kind in ("reliable", "stopped"):
            results[kind]["reference"] = count_messages.count_in(ref_out, *results[kind]["stamps"])
        print("reference", {k: results[k]["reference"] for k in ("reliable", "stopped")})
        r = results["reliable"]
        assert r["reference"] >= 0.5 * r["sent"], results  # (the reference itself kept up)
        assert r["received"] >= 0.8 * r["reference"], results
    finally:
        if ref.poll() is None:
            ref.kill()
            ref.wait()
        alive, rc = stop_node(node, probe)
    assert alive and rc == 0, node.log


def test_a_solver_change_does_not_hold_the_parameter_service_for_a_compile(monkeypatch):
    """A solver changed at run time warms up its kernels as the node's start does: kernels
    not in numba's cache compile in another process (``background``) while the frames go on
    uncompiled, instead of in the parameter callback, which would hold the node's executor
    (no diagnostics, camera_info or parameter answers) for the whole compile."""
    from types import SimpleNamespace

    import rs_localizer.ros.mode as N
    import rs_localizer.ros.pipeline as W

    calls = []
    monkeypatch.setattr(W, "log_warm_up", lambda *a, **k: calls.append((a[0], a[-1], k)))
    old = _config_of({})
    new = _config_of({"solver": "p3p"})
    logs = []
    node = SimpleNamespace(
        get_logger=lambda: SimpleNamespace(info=logs.append, warning=logs.append),
        get_parameter=lambda name: SimpleNamespace(value=True),
    )
    mode = N.LocalizerMode.__new__(N.LocalizerMode)  # (the camera alone's, unconfigured)
    mode.node, mode.cfg, mode.alone = node, old, True
    mode._change_to = lambda built, overrides: None
    mode.apply_change((new, None), {"solver": "p3p"})
    assert calls == [("p3p", True, {})]
    assert logs == [f"solver: {old.solver} -> p3p"]


def _config_of(overrides):
    """The node's configuration of its default parameters with ``overrides``."""
    from rs_localizer.ros import config as C
    from rs_localizer.ros import params as P

    values = {k: p.default for k, p in P.PARAMETERS.items()}
    values.update(overrides)
    return C.build_config(values)


def _direct_camera_node(ctx, cam, logged: list, published: list, queue: int, **params):
    """The camera node without DDS (frames handed to its callback, its worker taking them),
    with the camera's true camera_info; ``logged`` takes the texts it logs, ``published``
    the ``(topic, message)`` pairs it publishes (``pose``, ``twist``, ``odom`` wanted)."""
    from rclpy.parameter import Parameter

    from rs_localizer.ros.conversions import camera_info_msg
    from rs_localizer.ros.node import RSLocalizerNode

    values = {"warmup": False, "publish_tf": False, "queue_size": queue, **params}
    overrides = [Parameter(k, value=v) for k, v in values.items()]
    node = RSLocalizerNode("rs_localizer", context=ctx, namespace="/direct",
                           parameter_overrides=overrides)  # fmt: skip
    node._log.logger = type("L", (), {"warning": logged.append, "info": logged.append,
                                      "error": logged.append})()  # fmt: skip
    node.wanted = lambda topic: topic in ("pose", "twist", "odom")
    node.publish_messages = published.extend
    node.inputs[""].add_camera_info(camera_info_msg(cam, "cam", 0))
    return node


def _send_and_drain(node, frames) -> None:
    from rs_localizer.ros import pointcloud as pc
    from rs_localizer.ros.frame_queue import frame_accounting

    for f in frames:
        node._on_frame("", "cloud", pc.correspondence_cloud(f.uv, f.xyz, frame_id="cam",
                                                            stamp=f.stamp_ns))  # fmt: skip
    deadline = time.monotonic() + 300.0  # (a cold numba cache: the first frame compiles)
    while time.monotonic() < deadline:
        c = frame_accounting(node.camera_counts[""].counts())
        if c.pending == 0 and c.received == len(frames):
            return
        time.sleep(0.01)
    raise AssertionError(f"frames not taken: {c}")


def _stamps(published, topic) -> list[int]:
    return [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
            for t, m in published if t == topic]  # fmt: skip


def test_the_end_of_the_video_publishes_every_posed_frame_s_fused_twist(ros_context, frames):
    """The camera node's video ends (``deactivate``, the end of its inputs) mid-track: the last
    ``tracking.lag`` frames, posed with their fused twist still pending, get it then (``odom``
    and ``twist`` for every ``pose``, at its stamp), as a rig node's and ``replay`` at a bag's
    end; before the end they wait."""
    fr, _, cam = frames
    logged, published = [], []
    node = _direct_camera_node(ros_context, cam, logged, published, len(fr),
                               **{"tracking.lag": 2})  # fmt: skip
    try:
        _send_and_drain(node, fr[:8])
        poses = _stamps(published, "pose")
        assert poses == [f.t_ref_ns for f in fr[:8]], logged
        assert _stamps(published, "odom") == poses[:-2]  # (tracking.lag 2: two wait)
        node._end_video()
        assert _stamps(published, "odom") == _stamps(published, "twist") == poses
        assert _stamps(published, "pose") == poses  # (nothing else published)
    finally:
        node.destroy_node()


def test_a_frame_step_that_raises_is_a_failed_frame_worded_as_replay_and_the_rig(
    ros_context, frames, monkeypatch
):
    """A defect in the camera node's frame step (its localizer raising on the 4th frame) is
    the frame failed ``internal_error``: counted once ``failed.internal_error`` (received =
    solved + failed + skipped + pending), logged ``frame failed (internal_error): <type>:
    <text>`` as ``replay`` and a rig node log it, nothing published for it; the next frames
    are solved."""
    from rs_localizer.ros.frame_queue import frame_accounting

    fr, _, cam = frames
    logged, published = [], []
    node = _direct_camera_node(ros_context, cam, logged, published, len(fr))
    try:
        rig, calls = node.mode.rig, []
        add = rig.add

        def faulty(*args, **kwargs):
            calls.append(1)
            if len(calls) == 4:
                raise RuntimeError("injected fault")
            return add(*args, **kwargs)

        monkeypatch.setattr(rig, "add", faulty)
        _send_and_drain(node, fr[:8])
        counts = node.camera_counts[""]
        c = frame_accounting(counts.counts())
        assert (c.received, c.solved, c.failed, c.skipped, c.pending) == (8, 7, 1, 0, 0), c
        assert c.failures == {"internal_error": 1}, c
        line = "frame failed (internal_error): RuntimeError: injected fault"
        assert [t for t in logged if "internal_error" in str(t)] == [line], logged
        assert _stamps(published, "pose") == [f.t_ref_ns for k, f in enumerate(fr[:8]) if k != 3]
    finally:
        node.destroy_node()


def test_a_parameter_change_and_the_diagnostics_do_not_wait_for_the_frame_being_solved(
    ros_context, frames
):
    """While the worker is on a slow frame (its localizer held 1 s), a run-time parameter
    change (``ros2 param set``) and the diagnostics timer return at once, the frames that
    arrive meanwhile counted ``received``; the change is taken after the slow frame (the
    frames after it solved with it) and the status published then balances (received =
    solved + failed + skipped + pending)."""
    import threading

    from rclpy.parameter import Parameter

    from rs_localizer.ros import pointcloud as pc
    from rs_localizer.ros.frame_queue import frame_accounting

    fr, _, cam = frames
    logged, published, diag = [], [], []
    node = _direct_camera_node(ros_context, cam, logged, published, len(fr))
    node.pub_diag = type("Pub", (), {"publish": lambda self, msg: diag.append(msg)})()
    try:
        rig, entered, calls = node.mode.rig, threading.Event(), []
        add = rig.add

        def slow(*args, **kwargs):
            calls.append(rig.settings.options.ransac.threshold_px)
            if len(calls) == 1:
                entered.set()
                time.sleep(1.0)
            return add(*args, **kwargs)

        rig.add = slow
        old = rig.settings.options.ransac.threshold_px

        def cloud(f):
            return pc.correspondence_cloud(f.uv, f.xyz, frame_id="cam", stamp=f.stamp_ns)

        node._on_frame("", "cloud", cloud(fr[0]))
        assert entered.wait(10.0)
        tic = time.perf_counter()
        result = node.set_parameters([Parameter("ransac.threshold_px", value=old + 1.0)])
        node.publish_diagnostics()
        for f in fr[1:4]:
            node._on_frame("", "cloud", cloud(f))
        assert time.perf_counter() - tic < 0.3  # (the slow frame takes 1 s)
        assert result[0].successful
        assert frame_accounting(node.camera_counts[""].counts()).received == 4
        assert diag == []  # (handed to the worker)
        for _ in range(1000):
            if frame_accounting(node.camera_counts[""].counts()).pending == 0:
                break
            time.sleep(0.01)
        assert calls == [old] + [old + 1.0] * 3  # (the change between the frames)
        (msg,) = diag
        v = {kv.key: kv.value for kv in msg.status[0].values}
        n = {k: int(v[f"frames_{k}"]) for k in ("received", "solved", "failed", "skipped",
                                                 "pending")}  # fmt: skip
        assert n["received"] == n["solved"] + n["failed"] + n["skipped"] + n["pending"], n
        assert n["received"] == 4 and n["solved"] == 1, n
    finally:
        node.destroy_node()
