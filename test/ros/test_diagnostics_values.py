"""The node's diagnostics values from its counters, without a node: one camera's and a rig's."""

from collections import Counter
from dataclasses import replace

from helpers.ros import camera_status, rig_status

from rs_localizer.ros.config import build_config
from rs_localizer.ros.frame_queue import FrameCounts
from rs_localizer.ros.params import default_values
from rs_localizer.ros.pipeline import PipelineStats


def _values(stamp_ages):
    cfg = build_config(default_values())
    snap = PipelineStats().snapshot()
    n = len(stamp_ages)
    snap = replace(snap, counts={"received": n, "solved": n})
    return camera_status(cfg, snap, {}, "camera_info", 0, [0.01] * n, stamp_ages)[2]


def test_stage_times_of_a_cameras_frame():
    """A camera's frame through the worker, the camera alone's and a rig camera's one way: its
    input stage and the wait for its gyro samples (``decode``) from the start to its taking,
    and the rest of the localizer's time less its front end's search and the gyro wait
    (``estimate``) only when it completed a posed rig frame; publishing apart."""
    from rs_localizer.ros.camera_input import CameraCounts

    st = CameraCounts(kept=2)
    st.frame_stage_times(10.0, 10.25, 10.5, 0.0, 0.0, False)  # (a cloud, no rig frame posed)
    st.stage_time("frontend", 0.125)  # (an image completing a posed one, 1/16 s gyro wait)
    st.frame_stage_times(20.0, 20.5, 21.0, 0.125, 0.0625, True)
    st.stage_time("publish", 0.0625)
    assert st.stage_times() == {"decode": [0.25, 0.5625], "frontend": [0.125],
                                "estimate": [0.3125], "publish": [0.0625]}  # fmt: skip
    st.frame_stage_times(30.0, 30.75, 31.0, 0.0, 0.0, True)  # (kept: the last two of each)
    assert st.stage_times()["decode"] == [0.5625, 0.75]
    assert st.stage_times()["estimate"] == [0.3125, 0.25]


def test_stamp_age_leaves_out_stamps_of_another_clock():
    """A recorded bag played without use_sim_time: its stamps are days older than the node's
    clock. Their age is no delay of the node: counted apart, not averaged in."""
    live = _values([0.010, 0.012, 0.014])
    assert live["stamp_age_ms_median"] == "12.000" and live["stamps_off_clock"] == 0
    recorded = _values([95.6e6, 95.6e6 + 0.033])
    assert recorded["stamp_age_ms_median"] == "nan" and recorded["stamps_off_clock"] == 2
    mixed = _values([0.010, 95.6e6, -3600.0, 0.020])
    assert mixed["stamp_age_ms_last"] == "20.000" and mixed["stamp_age_ms_median"] == "15.000"
    assert mixed["stamps_off_clock"] == 2


def test_the_rig_status_has_the_cameras_timing_keys_and_a_section_per_camera():
    """The rig's status comes from the same builder: given the same latencies and stamp ages
    as a camera's, its timing keys are the camera's, character for character, and equal the
    medians and percentiles computed here, and the keys both statuses have come in the same
    order; the worker's stage times give the camera's stage keys (``<stage>_ms_median``, the
    front end's only with a front end) before the rig-wide ``camera_frame_ms_median``; each
    camera's section has its own worker time
    (``<c>.camera_frame_ms_median``) beside the rig-wide one; per camera ``received = solved
    + failed + skipped + pending`` with the node's own counts folded in; a camera that sent
    nothing is named in an ERROR while no rig frame is posed; a time reset of the rig is
    counted under the camera's key."""
    import numpy as np
    from helpers.rig import mounts_of

    from rs_localizer.ros.diagnostics import ERROR, RigInputs
    from rs_localizer.sim.trajectory import default_rig, generate_rig_video
    from rs_localizer.tracking.localizer import CameraFrame
    from rs_localizer.tracking.video import Localizer, LocalizerSettings

    cams = default_rig(2)
    frames, _, _ = generate_rig_video(cams, duration=0.2, num_points=80, seed=5)
    by = {c.name: c.camera for c in cams}
    rig = Localizer(LocalizerSettings(mounts_of(cams)))
    names = [c.name for c in cams]
    for f in frames:
        rig.add(CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name))
    sent = {n: sum(f.name == n for f in frames) for n in names}
    # (the node's counts: every frame received and handed on, 2 more of the first camera
    # dropped from a full queue, 1 more still queued)
    counts = Counter({f"{n}.received": k for n, k in sent.items()})
    counts[f"{names[0]}.received"] += 3
    counts[f"{names[0]}.skipped.queue_full"] += 2
    lat, age = [0.004, 0.006, 0.020, 0.005], [0.010, 0.030, 95.6e6]
    times = {names[0]: [0.001, 0.003, 0.002], names[1]: [0.010]}
    stages = {"decode": [0.001, 0.002], "frontend": [0.03], "estimate": [0.004, 0.008, 0.005],
              "publish": []}  # fmt: skip
    inputs = RigInputs(counts, times, stage_times=stages)
    level, message, v = rig_status(rig, (), inputs, (lat, age))
    cfg = build_config(default_values())
    snap = replace(PipelineStats().snapshot(), counts={"received": 4, "solved": 4})
    camera = camera_status(cfg, snap, {}, "camera_info", 0, lat, age)[2]
    keys = ("latency_ms_last", "latency_ms_median", "latency_ms_p99", "stamp_age_ms_last",
            "stamp_age_ms_median", "stamps_off_clock")  # fmt: skip
    assert {k: v[k] for k in keys} == {k: camera[k] for k in keys}
    shared = [k for k in v if k in camera]  # (one layout: the keys of both in one order)
    assert shared == [k for k in camera if k in v] and "map_fit_doubtful" in shared, shared
    assert v["latency_ms_median"] == f"{np.median(lat) * 1e3:.3f}" == "5.500"
    assert v["latency_ms_p99"] == f"{np.percentile(lat, 99) * 1e3:.3f}"
    assert v["stamp_age_ms_median"] == "20.000" and v["stamps_off_clock"] == 1
    assert v[f"{names[0]}.camera_frame_ms_median"] == "2.000"
    assert v[f"{names[1]}.camera_frame_ms_median"] == "10.000"
    assert v["camera_frame_ms_median"] == "2.500"  # (of all four)
    assert v["decode_ms_median"] == "1.500" and v["estimate_ms_median"] == "5.000"
    assert v["publish_ms_median"] == "nan" and "frontend_ms_median" not in v
    timing = [k for k in v if k.endswith("_ms_median") and "." not in k]
    assert timing == ["latency_ms_median", "stamp_age_ms_median", "decode_ms_median",
                      "estimate_ms_median", "publish_ms_median",
                      "camera_frame_ms_median"]  # fmt: skip
    inputs.frontend = True
    assert rig_status(rig, (), inputs, (lat, age))[2]["frontend_ms_median"] == "30.000"
    for n in names:
        parts = [v[f"{n}.{k}"] for k in ("solved", "failed", "skipped", "pending")]
        assert v[f"{n}.received"] == sum(parts), (n, v)
    assert v[f"{names[0]}.received"] == sent[names[0]] + 3
    assert v[f"{names[0]}.skipped.queue_full"] == 2 and v["rig_frames_solved"] > 0
    assert "busy: 2 camera frames dropped" in message, message
    assert v["time_resets"] == 0
    f = frames[0]  # (a camera frame 10 s after the video: a time reset, as for one camera)
    rig.add(CameraFrame(frames[-1].stamp_ns + 10**10, by[f.name], f.uv, f.xyz, camera_name=f.name))
    assert rig_status(rig, (), RigInputs(counts, times), (lat, age))[2]["time_resets"] == 1

    silent = Localizer(LocalizerSettings(mounts_of(cams)))
    only = Counter({f"{names[1]}.received": 1})
    level, message, v = rig_status(silent, (), RigInputs(only, absent=[names[0]]), ([], []))
    assert level == ERROR and message.startswith(
        f"no rig frame posed: no frame from camera {names[0]}"
    )
    assert v[f"{names[0]}.received"] == 0 and v["latency_ms_median"] == "nan"


def test_a_camera_that_never_sent_a_frame_is_named_with_its_topic():
    """A camera of ``rig.cameras`` from which the node received nothing while the others run
    (its topic not published, or not remapped into the node's namespace): once the rig runs
    on the others it is ``stopped`` and the status says that no frame came from it and which
    topic to check, not only that it stopped."""
    from helpers.rig import mounts_of

    from rs_localizer.ros.diagnostics import WARN, RigInputs
    from rs_localizer.sim.trajectory import default_rig, generate_rig_video
    from rs_localizer.tracking.localizer import CameraFrame
    from rs_localizer.tracking.video import Localizer, LocalizerSettings

    cams = default_rig(3)
    frames, _, _ = generate_rig_video(cams, duration=0.8, num_points=60, seed=2)
    by = {c.name: c.camera for c in cams}
    silent = cams[2].name
    rig = Localizer(LocalizerSettings(mounts_of(cams)))
    sent = Counter()
    for f in frames:
        if f.name != silent:
            rig.add(CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name))
            sent[f"{f.name}.received"] += 1
    level, message, v = rig_status(rig, (), RigInputs(sent), ([], []))
    assert v[f"{silent}.state"] == "stopped" and v[f"{silent}.received"] == 0, v
    assert level == WARN and v["rig_frames_solved"] > 0
    assert f"camera {silent} stopped: no frame received from it" in message, message
    assert f"{silent}/correspondences" in message
    level, message, _ = rig_status(rig, (), RigInputs(sent, frontend=True), ([], []))
    assert f"{silent}/image_raw" in message, message


def test_the_rig_status_has_the_tracks_values_of_a_camera():
    """A rig's status reports its track as a camera's does, the keys in the camera's order:
    ``track_state``, ``frames_tracked``, ``relocalizations``, ``resets`` (gained by the rig:
    its track's counts over its tracks), then the fused twists' and the readout check's."""
    from helpers.rig import mounts_of

    from rs_localizer.sim.trajectory import default_rig, generate_rig_video
    from rs_localizer.tracking.localizer import CameraFrame
    from rs_localizer.tracking.video import Localizer, LocalizerSettings

    cams = default_rig(2)
    frames, _, _ = generate_rig_video(cams, duration=0.3, num_points=80, seed=5)
    by = {c.name: c.camera for c in cams}
    rig = Localizer(LocalizerSettings(mounts_of(cams)))
    for f in frames:
        rig.add(CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name))
    v = rig_status(rig)[2]
    track = rig.tracking_values()
    cfg = build_config(default_values())
    snap = replace(PipelineStats().snapshot(), counts={"received": 1, "solved": 1})
    camera = camera_status(cfg, snap, track, "camera_info", 0)[2]
    assert [k for k in v if k in track] == [k for k in camera if k in track] == list(track)
    assert list(track)[:4] == ["track_state", "frames_tracked", "relocalizations", "resets"]
    assert {k: v[k] for k in track} == track
    assert v["track_state"] == "tracking" and 0 < v["frames_tracked"] <= v["rig_frames"]
    assert v["resets"] == 0


def test_the_rig_status_counts_the_fused_twists_as_a_camera_does(monkeypatch):
    """A rig's fused twists go through the camera's plausibility check, and its status counts
    them under the camera's keys: a rig frame whose fused state the filter hands out at
    35 rad/s (above a 30 rad/s bound) is published with its own twist, counted in
    ``twists_implausible`` and ``twists_own_frame``; the counts equal the flags of the
    published rig frames."""
    import numpy as np
    from helpers.rig import mounts_of

    from rs_localizer.estimation.options import EstimateOptions, PlausibilityOptions
    from rs_localizer.sim.trajectory import default_rig, generate_rig_video
    from rs_localizer.tracking import fusion
    from rs_localizer.tracking.localizer import CameraFrame
    from rs_localizer.tracking.video import Localizer, LocalizerSettings

    cams = default_rig(2)
    frames, _, _ = generate_rig_video(cams, duration=0.3, num_points=80, seed=5)
    by = {c.name: c.camera for c in cams}
    update, corrupted = fusion.TwistFilter.update, []

    def corrupting(self, *a, **k):
        step = update(self, *a, **k)
        for f in step.final:
            if not corrupted:
                corrupted.append(f.pose.stamp_ns)
                f.pose.angular_velocity[0] += 35.0  # (a view of the filter's row)
        return step

    monkeypatch.setattr(fusion.TwistFilter, "update", corrupting)
    bounds = PlausibilityOptions(max_angular_velocity=30.0)
    rig = Localizer(
        LocalizerSettings(mounts_of(cams), options=EstimateOptions(plausibility=bounds))
    )
    fused = []
    for f in frames:
        for out in rig.add(CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name)):
            fused += out.fused
    for out in rig.close():
        fused += out.fused
    fused += rig.flush()
    v = rig_status(rig)[2]
    assert len(corrupted) == 1 and len(fused) > 3
    assert v["twists_implausible"] == 1 == sum(x.implausible for x in fused)
    assert v["twists_own_frame"] == sum(x.own_twist for x in fused) >= 1
    (bad,) = [x for x in fused if x.implausible]
    assert bad.pose.stamp_ns == corrupted[0] and bad.own_twist
    assert all(np.linalg.norm(x.pose.angular_velocity) <= 30.0 for x in fused)


def test_a_suspect_readout_timing_warns():
    """The camera's status goes to WARN with the advice while the video flags the
    rolling-shutter timing (``readout_suspect``, a tracking value), OK otherwise; a rig whose
    cameras are given twice their line delay is flagged on its own video, its status WARN
    and its log naming the cameras' timing parameters, and the same rig with the true line
    delays is not."""
    from dataclasses import replace

    from helpers.rig import Log, mounts_of

    from rs_localizer.ros.diagnostics import OK, WARN
    from rs_localizer.sim.trajectory import default_rig, generate_rig_video
    from rs_localizer.tracking.localizer import CameraFrame
    from rs_localizer.tracking.video import Localizer, LocalizerSettings

    cfg = build_config(default_values())
    snap = replace(PipelineStats().snapshot(), counts={"received": 40, "solved": 40})
    for suspect, level in (("false", OK), ("true", WARN)):
        tracking = {"readout_contradicted": 12 if suspect == "true" else 0}
        tracking["readout_suspect"] = suspect
        got, message, v = camera_status(cfg, snap, tracking, "camera_info", 0, [0.01], [0.01])
        assert got == level and v["readout_suspect"] == suspect
        assert ("12 of the last 30 frames" in message and "rs.line_delay" in message) == (
            suspect == "true"
        ), message

    cams = default_rig(2)
    frames, _, _ = generate_rig_video(cams, duration=1.4, num_points=60, seed=5)
    for scale in (1.0, 2.0):
        by = {c.name: replace(c.camera, line_delay=scale * c.camera.line_delay) for c in cams}
        log = Log()
        rig = Localizer(LocalizerSettings(mounts_of(cams)), log=log)
        for f in frames:
            rig.add(CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name))
        rig.close()
        rig.flush()
        level, message, v = rig_status(rig)
        logged = [t for k, t in log.warnings if k == "readout.suspect"]
        assert len(logged) == (scale == 2.0) and all("rig.<camera>" in t for t in logged)
        assert v["readout_contradicted"] >= 0, v  # (30 rig frames and more)
        flagged = "rig frames' rolling-shutter motion does not predict the video" in message
        assert flagged == (scale == 2.0) == (v["readout_suspect"] == "true"), (scale, message)
        if scale == 2.0:
            assert level == WARN and v["readout_contradicted"] >= 10


def test_a_rig_with_a_gyro_reports_it_as_a_camera_does(monkeypatch):
    """A rig with a gyro whose samples never come: its status carries the single-camera
    node's gyro keys (the same set as a camera's with a gyro, the rig frames for its frames),
    every rig frame counted without samples, and the camera's WARN once no usable IMU sample
    has come for ``IMU_IDLE_WARN_S`` while rig frames arrive (its text, rig frames for
    frames), the keys it shares with the camera's in the camera's order. Without a gyro, no
    gyro key."""
    import numpy as np
    from helpers.rig import mounts_of

    from rs_localizer.ros import diagnostics as D
    from rs_localizer.sim.trajectory import default_rig, generate_rig_video
    from rs_localizer.tracking.gyro_input import GyroSettings
    from rs_localizer.tracking.localizer import CameraFrame
    from rs_localizer.tracking.video import Localizer, LocalizerSettings

    cams = default_rig(2)
    frames, _, _ = generate_rig_video(cams, duration=0.2, num_points=80, seed=5)
    by = {c.name: c.camera for c in cams}
    rigs = {}
    for gyro in (None, GyroSettings(R_cam_imu=np.eye(3), wait=0.0)):
        rig = rigs[gyro is not None] = Localizer(LocalizerSettings(mounts_of(cams), imu=gyro))
        for f in frames:
            rig.add(CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name))
    cfg = build_config({**default_values(), "imu.enabled": True})
    snap = replace(PipelineStats().snapshot(), counts={"received": 3, "solved": 3})
    camera = camera_status(cfg, snap, {}, "", 0, rate_hz=0.0, idle_s=0.0)[2]
    camera_gyro = {k for k in camera if "gyro" in k or k.startswith("imu_")}
    level, message, v = rig_status(rigs[True], (), D.RigInputs())
    rig_gyro = {k for k in v if "gyro" in k or k.startswith("imu_")}
    assert [k for k in v if k in camera] == [k for k in camera if k in v]  # (one layout)
    posed = v["rig_frames_solved"]
    assert posed > 0 and level == D.OK, message
    assert rig_gyro - {"gyro_missing.no_samples"} == camera_gyro, rig_gyro ^ camera_gyro
    assert v["frames_with_gyro"] == 0 and v["gyro_missing"] == v["gyro_missing.no_samples"]
    assert v["gyro_missing"] == posed and v["imu_rate_hz"] == "0.0"
    monkeypatch.setattr(D, "IMU_IDLE_WARN_S", 0.0)
    level, message, v = rig_status(rigs[True], (), D.RigInputs())
    assert level == D.WARN and "no usable IMU sample for" in message, message
    assert "rig frames solved without the gyro; check the imu topic" in message, message
    level, message, v = rig_status(rigs[False], (), D.RigInputs())
    assert level == D.OK and not {k for k in v if "gyro" in k or k.startswith("imu_")}, v


def test_a_rig_cameras_frames_are_the_same_in_its_diagnostics_and_a_replay():
    """A rig camera's frame accounting (``rig_camera_frames``) is the rig's counts of the camera
    with the node's own: received = solved + failed + skipped + pending, ``skipped`` and
    ``failed`` the sums of their reasons, the node's and the rig's reasons both kept; the rig
    node's diagnostics section and a rig bag replay's counts of the camera give the same
    values."""
    from helpers.rig import mounts_of

    from rs_localizer.ros.bags.replay import camera_counts
    from rs_localizer.ros.diagnostics import RigInputs, rig_camera_frames
    from rs_localizer.sim.trajectory import default_rig, generate_rig_video
    from rs_localizer.tracking.localizer import CameraFrame
    from rs_localizer.tracking.video import Localizer, LocalizerSettings

    cams = default_rig(2)
    frames, _, _ = generate_rig_video(cams, duration=0.2, num_points=80, seed=5)
    by = {c.name: c.camera for c in cams}
    a, b = (c.name for c in cams)
    rig = Localizer(LocalizerSettings(mounts_of(cams)))
    sent = Counter()
    for i, f in enumerate(frames):
        sent[f.name] += 1
        if f.name == b and i == 5:  # (an image the node could not decode, dropped by the rig)
            rig.drop(b, f.stamp_ns, by[b], "bad_image")
        else:
            rig.add(CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name))
    # (the node's counts: camera a's frames and 4 more: 1 of a stamp out of range, 1 whose
    # handling raised, 1 dropped from a full queue, 1 still queued)
    own = {a: Counter({"received": sent[a] + 4, "skipped.bad_input": 1,
                       "failed.internal_error": 1, "skipped.queue_full": 1}),
           b: Counter({"received": sent[b]})}  # fmt: skip
    fa, fb = rig_camera_frames(rig, a, own[a]), rig_camera_frames(rig, b, own[b])
    for fc in (fa, fb):
        assert fc.received == fc.solved + fc.failed + fc.skipped + fc.pending, fc
        assert sum(fc.skips.values()) == fc.skipped and sum(fc.failures.values()) == fc.failed
    assert fa.received == sent[a] + 4 and fa.failures == {"internal_error": 1}
    assert fa.skips == {"bad_input": 1, "queue_full": 1}
    assert fa.pending == rig.camera_counts(a)["pending"] + 1
    assert fb.skips == {"bad_image": 1} and fb.received == sent[b]
    counts = Counter()
    for n, c in own.items():
        counts.update({f"{n}.{k}": v for k, v in c.items()})
    v = rig_status(rig, (), RigInputs(counts))[2]
    for n in (a, b):
        replayed = camera_counts(rig, n, own[n])
        assert replayed == {k: v[f"{n}.{k}"] for k in replayed}, (n, replayed, v)
    assert list(camera_counts(rig, a, own[a]))[-2:] == ["skipped.bad_input", "skipped.queue_full"]


# fmt: off
#: the keys of the single camera's status in publishing order (each state of
#: ``_pinned_states`` has some of them)
_ORDER = (
    "solver", "camera", "frames_received", "frames_solved", "frames_failed", "frames_skipped",
    "frames_pending", "compiled", "compile_state", "compile_failures", "compile_error",
    "frames_compiled", "frames_uncompiled", "queue_size", "time_resets", "messages_lost",
    "points_dropped", "clouds_capped", "unknown_landmark_ids", "camera_info_rejected",
    "frames_few_points", "frames_single_tag", "frames_failed_with_matches", "map_fit_doubtful",
    "inliers_last", "inliers_mean", "planar", "track_state", "readout_suspect",
    "condition_number_last", "latency_ms_last", "latency_ms_median", "latency_ms_p99",
    "stamp_age_ms_last", "stamp_age_ms_median", "stamps_off_clock", "decode_ms_median",
    "frontend_ms_median", "estimate_ms_median", "publish_ms_median", "frontend", "image_frames",
    "frames_beside_frontend", "frontend_ms_last", "frontend_correspondences_last",
    "frontend_correspondences_mean", "frontend_ms_p99", "frontend_frames_global",
    "frontend_few_match_frames", "imu_rate_hz", "frames_with_gyro", "gyro_rejected",
    "gyro_missing", "imu_rejected", "imu_idle_s", "gyro_bias", "gyro_bias_std",
    "gyro_bias_rejected", "gyro_inconsistent", "gyro_disabled_inconsistent", "gyro_pairs_failed",
    "gyro_inconsistent_detections", "failed.too_few_points", "camera_info_rejected.distortion",
    "gyro_rejected.too_far", "imu_rejected.stamp_back",
)
#: the fresh state's values (the others': these with their own)
_FRESH = {
    "solver": "r6p_1lin", "camera": "camera_info", "frames_received": 0, "frames_solved": 0,
    "frames_failed": 0, "frames_skipped": 0, "frames_pending": 0, "compiled": "false",
    "compile_state": "compiling", "compile_failures": 0, "compile_error": "",
    "frames_compiled": 0, "frames_uncompiled": 0, "queue_size": 5, "time_resets": 0,
    "messages_lost": 0, "points_dropped": 0, "clouds_capped": 0, "unknown_landmark_ids": 0,
    "camera_info_rejected": 0, "frames_few_points": 0, "frames_single_tag": 0,
    "frames_failed_with_matches": 0, "map_fit_doubtful": "false", "inliers_last": 0,
    "inliers_mean": "0", "planar": "false", "track_state": "lost", "condition_number_last": "nan",
    "latency_ms_last": "nan", "latency_ms_median": "nan", "latency_ms_p99": "nan",
    "stamp_age_ms_last": "nan", "stamp_age_ms_median": "nan", "stamps_off_clock": 0,
    "decode_ms_median": "nan", "estimate_ms_median": "nan", "publish_ms_median": "nan",
}
#: the single camera's status on three states (``_pinned_states``): level, message and
#: every key's value (the latencies' p99 of 10 and 30 ms is 29.8 ms; a stamp age of
#: 95.6e6 s is another clock's; 90 front-end points over 4 runs: 22.5)
_PINNED = {
    "fresh": (0, (
        "waiting for frames; kernels compiling in the background: frames on the uncompiled "
        "path"
    ), _FRESH),
    "mixed": (1, (
        "3/6 frames solved, 1 skipped (busy); most frames with many matches refused: does "
        "the map fit this place? mirrored or another room?; kernels compiling in the "
        "background: frames on the uncompiled path"
    ), {**_FRESH, **{
        "camera": "parameters", "frames_received": 6, "frames_solved": 3, "frames_failed": 1,
        "frames_skipped": 1, "frames_pending": 1, "time_resets": 1, "messages_lost": 2,
        "points_dropped": 4, "camera_info_rejected": 1, "frames_few_points": 1,
        "frames_failed_with_matches": 1, "map_fit_doubtful": "true", "inliers_last": 31,
        "inliers_mean": "25.5", "planar": "true", "track_state": "tracking",
        "readout_suspect": "false", "condition_number_last": "1.23e+03",
        "latency_ms_last": "30.000", "latency_ms_median": "20.000", "latency_ms_p99": "29.800",
        "stamp_age_ms_last": "20.000", "stamp_age_ms_median": "20.000", "stamps_off_clock": 1,
        "decode_ms_median": "1.000", "estimate_ms_median": "3.000", "publish_ms_median": "0.500",
        "failed.too_few_points": 1, "camera_info_rejected.distortion": 1,
    }}),
    "gyro": (1, (
        "4/4 frames solved; the gyro contradicts the image (check imu.rotation, "
        "imu.time_offset): frames solved without it; kernels compiling in the background: "
        "frames on the uncompiled path"
    ), {**_FRESH, **{
        "frames_received": 4, "frames_solved": 4, "inliers_last": 25, "inliers_mean": "25.0",
        "track_state": "tracking", "condition_number_last": "50", "latency_ms_last": "5.000",
        "latency_ms_median": "5.000", "latency_ms_p99": "5.000", "stamp_age_ms_last": "6.000",
        "stamp_age_ms_median": "6.000", "decode_ms_median": "1.000",
        "frontend_ms_median": "15.000", "estimate_ms_median": "2.000",
        "publish_ms_median": "0.500", "frontend": "aruco", "image_frames": 4,
        "frames_beside_frontend": 0, "frontend_ms_last": "20.000",
        "frontend_correspondences_last": 22, "frontend_correspondences_mean": "22.5",
        "frontend_ms_p99": "19.900", "frontend_frames_global": 4, "frontend_few_match_frames": 2,
        "imu_rate_hz": "200.0", "frames_with_gyro": 2, "gyro_rejected": 1, "gyro_missing": 0,
        "imu_rejected": 2, "imu_idle_s": "0.0", "gyro_bias": "0.00100 -0.00200 0.00000",
        "gyro_bias_std": "0.01000 0.01000 0.01000", "gyro_bias_rejected": 0,
        "gyro_inconsistent": "true", "gyro_disabled_inconsistent": 1, "gyro_pairs_failed": 0,
        "gyro_inconsistent_detections": 0, "gyro_rejected.too_far": 1,
        "imu_rejected.stamp_back": 2,
    }}),
}
# fmt: on


def _pinned_states():
    """Three states of one camera: fresh (no frame yet); frames solved, failed, skipped and
    pending with messages lost, a camera_info rejected and the map-fit check doubting the map;
    a gyro the image contradicts, beside an ArUco front end."""
    from dataclasses import replace

    from rs_localizer.ros.pipeline import StatsSnapshot

    class Frontend:
        few_match_frames = 2

        def summary(self):
            return None

    cfg = build_config(default_values())
    gyro_cfg = build_config({**default_values(), "imu.enabled": True})
    gyro_cfg = replace(gyro_cfg, cameras=(replace(gyro_cfg.camera, frontend_kind="aruco"),))
    none = {"decode": [], "frontend": [], "estimate": [], "publish": []}
    fresh = StatsSnapshot({}, [], False, float("nan"), 0, none)
    yield "fresh", (cfg, fresh, {"track_state": "lost"}, "camera_info", 0, [], [])
    c = {"received": 6, "solved": 3, "failed.too_few_points": 1, "skipped.queue_full": 1,
         "camera_info_rejected": 1, "camera_info_rejected.distortion": 1, "points_dropped": 4,
         "frames_failed_with_matches": 1, "map_fit_doubtful": 1, "frames_few_points": 1,
         "time_resets": 1}  # fmt: skip
    times = {"decode": [0.001], "frontend": [], "estimate": [0.002, 0.004], "publish": [5e-4]}
    snap = StatsSnapshot(c, [20, 31], True, 1234.5, 0, times)
    tracking = {"track_state": "tracking", "readout_suspect": "false"}
    yield "mixed", (cfg, snap, tracking, "parameters", 2, [0.01, 0.03],
                    [0.02, 95.6e6])  # fmt: skip
    g = {"received": 4, "solved": 4, "image_frames": 4, "frontend_runs": 4, "frontend_points": 90,
         "frames_with_gyro": 2, "gyro_rejected": 1, "gyro_rejected.too_far": 1, "imu_rejected": 2,
         "imu_rejected.stamp_back": 2, "gyro_disabled_inconsistent": 1}  # fmt: skip
    times = {"decode": [0.001], "frontend": [0.01, 0.02], "estimate": [0.002], "publish": [5e-4]}
    snap = StatsSnapshot(g, [25], False, 50.0, 22, times)
    bias = ((0.001, -0.002, 0.0), (0.01, 0.01, 0.01))
    yield "gyro", (gyro_cfg, snap, {"track_state": "tracking"}, "camera_info",
                   0, [0.005], [0.006], 200.0, bias, True, 0.01, Frontend())  # fmt: skip


def test_the_single_cameras_status_keeps_its_keys_order_values_and_message(monkeypatch):
    """One camera's published status on three states (:func:`_pinned_states`), while the
    kernels compile in the background: its level, message and every key with its value are
    those of :data:`_PINNED`, its keys in the order of :data:`_ORDER`."""
    from rs_localizer.ros import diagnostics as D

    monkeypatch.setattr(D, "compiled_ready", lambda: False)
    monkeypatch.setattr(D, "background_state",
                        lambda: {"state": "compiling", "failures": 0, "reason": None})  # fmt: skip
    for name, args in _pinned_states():
        level, message, values = camera_status(*args)
        assert (level, message) == _PINNED[name][:2], (name, message)
        assert list(values) == [k for k in _ORDER if k in values], name
        assert values == _PINNED[name][2], name


def test_one_builder_takes_level_and_message_from_what_is_solved(monkeypatch):
    """One builder for both modes: the same accounting (4 received, 2 failed for
    ``too_few_points``, 2 pending) is a camera alone's frames or, with a named camera, a rig's
    rig frames; the keys, level and message follow from it by one rule (a camera alone: frames
    arrived and none solved is an ERROR naming its failures; a rig: rig frames tried and none
    posed, the message with the failures by reason; a lost message a WARN in both, its count
    first for the camera, a rig's trailing warning)."""
    from rs_localizer.ros import diagnostics as D

    monkeypatch.setattr(D, "compiled_ready", lambda: True)
    monkeypatch.setattr(D, "background_state", lambda: {"state": "done", "failures": 0,
                                                         "reason": None})  # fmt: skip
    frames = FrameCounts(4, 0, 2, 0, 2, failures={"too_few_points": 2})
    camera = D.CameraPart("", frames, {"messages_lost": 0})
    level, message, v = D.status(D.StatusParts(frames=frames, cameras=[camera]))
    assert (level, message) == (D.ERROR, "no frame solved ({'too_few_points': 2})")
    assert [v[k] for k in ("frames_received", "frames_failed", "frames_pending")] == [4, 2, 2]
    assert v["failed.too_few_points"] == 2 and "rig_frames" not in v
    named = D.CameraPart("a", FrameCounts(6, 0, 0, 0, 6), {"messages_lost": 0})
    level, message, v = D.status(D.StatusParts(frames=frames, cameras=[named]))
    assert level == D.ERROR
    assert message == "no rig frame posed: 2 rig frames failed (too_few_points 2)"
    assert [v[k] for k in ("rig_frames", "rig_frames_failed", "rig_frames_pending")] == [4, 2, 2]
    assert v["rig_frames_failed.too_few_points"] == 2 and v["a.received"] == 6
    assert "frames_received" not in v and "failed.too_few_points" not in v
    solved = FrameCounts(4, 3, 0, 0, 1)
    camera = D.CameraPart("", solved, {"messages_lost": 1})
    assert D.status(D.StatusParts(frames=solved, cameras=[camera]))[:2] == (
        D.WARN, "3/4 frames solved")  # fmt: skip
    named = D.CameraPart("a", solved, {"messages_lost": 1})
    assert D.status(D.StatusParts(frames=solved, cameras=[named]))[:2] == (
        D.WARN, "1 camera messages lost by the middleware (QoS message_lost)")  # fmt: skip
    named = D.CameraPart("a", solved, {"messages_lost": 0})
    assert D.status(D.StatusParts(frames=solved, cameras=[named]))[:2] == (
        D.OK, "3 rig frames posed")  # fmt: skip


def test_a_camera_lists_every_warning_as_a_rig_does(monkeypatch):
    """Three warnings at once (the gyro contradicts the image, the rolling-shutter timing is
    suspect, no usable IMU sample for 10 s while frames arrive): a camera alone's message is
    its count then all three (not only the first), a rig's the same three for its rig
    frames, in the same order."""
    from rs_localizer.ros import diagnostics as D
    from rs_localizer.tracking.localizer import readout_warning

    monkeypatch.setattr(D, "compiled_ready", lambda: True)
    monkeypatch.setattr(D, "background_state", lambda: {"state": "done", "failures": 0,
                                                         "reason": None})  # fmt: skip
    cfg = build_config({**default_values(), "imu.enabled": True})
    tracking = {"readout_contradicted": 12, "readout_suspect": "true"}

    def expected(unit, rig):
        return [
            "the gyro contradicts the image (check imu.rotation, imu.time_offset): "
            f"{unit} solved without it",
            readout_warning(12, rig=rig),
            f"no usable IMU sample for 10.0 s (3 IMU messages rejected): {unit} solved "
            "without the gyro; check the imu topic and its stamps",
        ]

    snap = replace(PipelineStats().snapshot(),
                   counts={"received": 4, "solved": 4, "imu_rejected": 3})  # fmt: skip
    level, message, _ = camera_status(cfg, snap, tracking, "camera_info", 0, [0.01], [0.01],
                                      200.0, None, True, 10.0)  # fmt: skip
    assert (level, message) == (D.WARN, "; ".join(["4/4 frames solved", *expected("frames", 0)]))
    frames = FrameCounts(4, 4)
    gyro = D.GyroState(cfg.imu, {"imu_rejected": 3}, 200.0, None, True, 10.0)
    rig = D.StatusParts(frames, [D.CameraPart("a", frames, {})], tracking=tracking, gyro=gyro)
    assert D.status(rig)[:2] == (D.WARN, "; ".join(expected("rig frames", True)))
