"""The node's diagnostics values from its counters, without a node: one camera's and a rig's."""

from collections import Counter

from rs_localizer.ros.config import build_config
from rs_localizer.ros.diagnostics import diagnostic_status
from rs_localizer.ros.frame_queue import FrameCounts
from rs_localizer.ros.params import default_values
from rs_localizer.ros.pipeline import FramePipeline


def _values(stamp_ages):
    cfg = build_config(default_values())
    snap = FramePipeline(cfg).stats.snapshot()
    frames = FrameCounts(received=len(stamp_ages), solved=len(stamp_ages))
    args = (cfg, frames, snap, {}, "camera_info", 0, [0.01] * len(stamp_ages), stamp_ages)
    return diagnostic_status(*args, 0.0, None, False, 0.0)[2]


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
    medians and percentiles computed here; each camera's section has its own worker time
    (``<c>.camera_frame_ms_median``) beside the rig-wide one; per camera ``received = solved
    + failed + skipped + pending`` with the node's own counts folded in; a camera that sent
    nothing is named in an ERROR while no rig frame is posed; a time reset of the rig is
    counted under the camera's key."""
    import numpy as np
    from helpers.rig import mounts_of

    from rs_localizer.ros.diagnostics import ERROR, RigInputs, rig_diagnostics
    from rs_localizer.sim.rig_video import default_rig, generate_rig_video
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
    level, message, v = rig_diagnostics(rig, set(), RigInputs(counts, lat, age, times))
    cfg = build_config(default_values())
    snap = FramePipeline(cfg).stats.snapshot()
    args = (cfg, FrameCounts(received=4, solved=4), snap, {}, "camera_info", 0, lat, age)
    camera = diagnostic_status(*args, 0.0, None, False, 0.0)[2]
    keys = ("latency_ms_last", "latency_ms_median", "latency_ms_p99", "stamp_age_ms_last",
            "stamp_age_ms_median", "stamps_off_clock")  # fmt: skip
    assert {k: v[k] for k in keys} == {k: camera[k] for k in keys}
    assert v["latency_ms_median"] == f"{np.median(lat) * 1e3:.3f}" == "5.500"
    assert v["latency_ms_p99"] == f"{np.percentile(lat, 99) * 1e3:.3f}"
    assert v["stamp_age_ms_median"] == "20.000" and v["stamps_off_clock"] == 1
    assert v[f"{names[0]}.camera_frame_ms_median"] == "2.000"
    assert v[f"{names[1]}.camera_frame_ms_median"] == "10.000"
    assert v["camera_frame_ms_median"] == "2.500"  # (of all four)
    for n in names:
        parts = [v[f"{n}.{k}"] for k in ("solved", "failed", "skipped", "pending")]
        assert v[f"{n}.received"] == sum(parts), (n, v)
    assert v[f"{names[0]}.received"] == sent[names[0]] + 3
    assert v[f"{names[0]}.skipped.queue_full"] == 2 and v["rig_frames_solved"] > 0
    assert "busy: 2 camera frames dropped" in message, message
    assert v["time_resets"] == 0
    f = frames[0]  # (a camera frame 10 s after the video: a time reset, as for one camera)
    rig.add(CameraFrame(frames[-1].stamp_ns + 10**10, by[f.name], f.uv, f.xyz, camera_name=f.name))
    assert rig_diagnostics(rig, set(), RigInputs(counts, lat, age, times))[2]["time_resets"] == 1

    silent = Localizer(LocalizerSettings(mounts_of(cams)))
    only = Counter({f"{names[1]}.received": 1})
    level, message, v = rig_diagnostics(silent, set(), RigInputs(only, absent=[names[0]]))
    assert level == ERROR and message.startswith(
        f"no rig frame posed: no frame from camera {names[0]}"
    )
    assert v[f"{names[0]}.received"] == 0 and v["latency_ms_median"] == "nan"


def test_the_rig_status_counts_the_fused_twists_as_a_camera_does(monkeypatch):
    """A rig's fused twists go through the camera's plausibility check, and its status counts
    them under the camera's keys: a rig frame whose fused state the filter hands out at
    35 rad/s (above a 30 rad/s bound) is published with its own twist, counted in
    ``twists_implausible`` and ``twists_own_frame``; the counts equal the flags of the
    published rig frames."""
    import numpy as np
    from helpers.rig import mounts_of

    from rs_localizer.estimation.options import EstimateOptions, PlausibilityOptions
    from rs_localizer.ros.diagnostics import rig_diagnostics
    from rs_localizer.sim.rig_video import default_rig, generate_rig_video
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
    v = rig_diagnostics(rig, set())[2]
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

    from rs_localizer.ros.diagnostics import OK, WARN, rig_diagnostics
    from rs_localizer.sim.rig_video import default_rig, generate_rig_video
    from rs_localizer.tracking.localizer import CameraFrame
    from rs_localizer.tracking.video import Localizer, LocalizerSettings

    cfg = build_config(default_values())
    snap = FramePipeline(cfg).stats.snapshot()
    frames_in = FrameCounts(received=40, solved=40)
    for suspect, level in (("false", OK), ("true", WARN)):
        tracking = {"readout_contradicted": 12 if suspect == "true" else 0}
        tracking["readout_suspect"] = suspect
        args = (cfg, frames_in, snap, tracking, "camera_info", 0, [0.01], [0.01])
        got, message, v = diagnostic_status(*args, 0.0, None, False, 0.0)
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
        level, message, v = rig_diagnostics(rig, set())
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
    frames). Without a gyro, no gyro key."""
    import numpy as np
    from helpers.rig import mounts_of

    from rs_localizer.ros import diagnostics as D
    from rs_localizer.sim.rig_video import default_rig, generate_rig_video
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
    snap = FramePipeline(cfg).stats.snapshot()
    camera = D.diagnostic_status(cfg, FrameCounts(received=3, solved=3), snap, {}, "", 0, [],
                                 [], 0.0, None, False, 0.0)[2]  # fmt: skip
    camera_gyro = {k for k in camera if "gyro" in k or k.startswith("imu_")}
    level, message, v = D.rig_diagnostics(rigs[True], set(), Counter())
    rig_gyro = {k for k in v if "gyro" in k or k.startswith("imu_")}
    posed = v["rig_frames_solved"]
    assert posed > 0 and level == D.OK, message
    assert rig_gyro - {"gyro_missing.no_samples"} == camera_gyro, rig_gyro ^ camera_gyro
    assert v["frames_with_gyro"] == 0 and v["gyro_missing"] == v["gyro_missing.no_samples"]
    assert v["gyro_missing"] == posed and v["imu_rate_hz"] == "0.0"
    monkeypatch.setattr(D, "IMU_IDLE_WARN_S", 0.0)
    level, message, v = D.rig_diagnostics(rigs[True], set(), Counter())
    assert level == D.WARN and "no usable IMU sample for" in message, message
    assert "rig frames solved without the gyro; check the imu topic" in message, message
    level, message, v = D.rig_diagnostics(rigs[False], set(), Counter())
    assert level == D.OK and not {k for k in v if "gyro" in k or k.startswith("imu_")}, v


def test_a_rig_cameras_frames_are_the_same_in_its_diagnostics_and_a_replay():
    """A rig camera's frame accounting (``rig_camera_frames``) is the rig's counts of the camera
    with the node's own: received = solved + failed + skipped + pending, ``skipped`` and
    ``failed`` the sums of their reasons, the node's and the rig's reasons both kept; the rig
    node's diagnostics section and a rig bag replay's counts of the camera give the same
    values."""
    from helpers.rig import mounts_of

    from rs_localizer.ros.bags.rig_bag import camera_counts
    from rs_localizer.ros.diagnostics import RigInputs, rig_camera_frames, rig_diagnostics
    from rs_localizer.sim.rig_video import default_rig, generate_rig_video
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
    v = rig_diagnostics(rig, set(), RigInputs(counts))[2]
    for n in (a, b):
        replayed = camera_counts(rig, n, own[n])
        assert replayed == {k: v[f"{n}.{k}"] for k in replayed}, (n, replayed, v)
    assert list(camera_counts(rig, a, own[a]))[-2:] == ["skipped.bad_input", "skipped.queue_full"]
