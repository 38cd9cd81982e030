"""Localizer: unsynchronized RS cameras on one rig through a video (simulated with
rs_localizer.sim.trajectory.generate_rig_video), against the rig's true trajectory."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from helpers.rig import T0, Log, assert_balanced, mounts_of

from rs_localizer.frames import Mounting
from rs_localizer.geometry import rotation_angle_deg, rotvec_to_matrix
from rs_localizer.sim.trajectory import default_rig, generate_rig_video, rig_truth
from rs_localizer.tracking.localizer import CameraFrame
from rs_localizer.tracking.sequence import SequenceLocalizer
from rs_localizer.tracking.video import MISSED_REASONS, SKIP_REASONS, Localizer, LocalizerSettings


def run(frames, cams, settings=None, log=None, camera_of=None):
    """Every frame through a Localizer in the given order; returns (rig, outputs, fused)."""
    by = {c.name: c.camera for c in cams}
    rig = Localizer(settings or LocalizerSettings(mounts_of(cams)), log=log)
    outs, fused = [], []
    for f in frames:
        cam = by[f.name] if camera_of is None else camera_of(f)
        for o in rig.add(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz, camera_name=f.name)):
            outs.append(o)
            fused += o.fused
    for o in rig.close():
        outs.append(o)
        fused += o.fused
    fused += rig.flush()
    return rig, outs, fused


def errors(o, traj):
    R, p, w, v = rig_truth(traj, (o.stamp_ns - T0) * 1e-9)
    pose = o.estimate.pose
    return (
        rotation_angle_deg(pose.orientation, R),
        np.linalg.norm(pose.position - p),
        np.linalg.norm(pose.angular_velocity - w),
        np.linalg.norm(pose.linear_velocity - v),
    )


@pytest.fixture(scope="module")
def video():
    cams = default_rig(3)
    frames, _, traj = generate_rig_video(cams, duration=0.6, num_points=150, seed=3)
    return cams, frames, traj


def test_three_unsynchronized_cameras_one_pose_per_rig_frame_and_a_fused_twist(video):
    """3 cameras, first frames 0, 4 and 8 ms apart, 20 % outliers, turning at ~1 rad/s: one
    rig frame per trio of frames, each posed within 0.03 deg and 3 mm; tracked after the
    first; the fused twist (fixed lag) at least 2x closer to the truth than each rig frame's
    own."""
    cams, frames, traj = video
    rig, outs, fused = run(frames, cams)
    assert len(outs) == 18 and all(o.success for o in outs)
    assert all(o.cameras == ("front", "left", "right") and not o.missing for o in outs)
    assert [o.path for o in outs] == ["cold"] + ["tracked"] * 17
    e = np.array([errors(o, traj) for o in outs])
    assert np.median(e[:, 0]) < 0.03 and np.median(e[:, 1]) < 0.003, np.median(e, axis=0)
    assert len(fused) == 18 and [f.pose.stamp_ns for f in fused] == [o.stamp_ns for o in outs]
    fw, fv = [], []
    for f in fused:
        _, _, w, v = rig_truth(traj, (f.pose.stamp_ns - T0) * 1e-9)
        fw.append(np.linalg.norm(f.pose.angular_velocity - w))
        fv.append(np.linalg.norm(f.pose.linear_velocity - v))
    assert np.median(fw) < 0.5 * np.median(e[:, 2]), (np.median(fw), np.median(e[:, 2]))
    assert np.median(fv) < 0.5 * np.median(e[:, 3]), (np.median(fv), np.median(e[:, 3]))
    # every camera's share of the rig's inliers, and the counts balance
    o = outs[5]
    assert abs(sum(s.share for s in o.shares.values()) - 1.0) < 1e-9
    assert all(0.6 < s.ratio < 0.95 for s in o.shares.values())
    assert_balanced(rig)
    assert rig.camera_counts("left") == dict(received=18, solved=18, failed=0, skipped=0, pending=0)
    # the stamp offsets: each camera's reference time after the rig frame's
    by = {c.name: c for c in cams}
    o = outs[3]
    for n, off in o.stamp_offsets.items():
        cam = by[n].camera
        t_ref = by[n].offset + 3 / 30 + cam.line_time(cam.reference_line)
        assert abs(round(t_ref * 1e9) - (o.stamp_ns - T0 + round(off * 1e9))) <= 2


def test_arrival_order_does_not_matter(video):
    """Frames arriving in another interleaving (a camera's frames in order, the cameras
    delayed by up to 30 ms each) give the same rig frames and poses."""
    cams, frames, _ = video
    rng = np.random.default_rng(0)
    key = [f.stamp_ns + rng.uniform(0, 30e6) for f in frames]
    shuffled = [frames[i] for i in np.argsort(key, kind="stable")]
    for n in ("front", "left", "right"):  # (each camera's own frames stay in order)
        own = [f.stamp_ns for f in shuffled if f.name == n]
        assert own == sorted(own)
    _, a, _ = run(frames, cams)
    _, b, _ = run(shuffled, cams)
    assert [o.stamp_ns for o in a] == [o.stamp_ns for o in b]
    for x, y in zip(a, b, strict=True):
        assert rotation_angle_deg(x.estimate.pose.orientation, y.estimate.pose.orientation) < 0.01


def test_a_camera_whose_frames_stop_the_rig_runs_on_the_others():
    """The right camera stops at 0.3 s: the rig frames after it have two cameras, counted as
    missed (``stopped``) after ``stop_after``, still posed within 0.05 deg and 5 mm; a camera
    whose frames come back joins again."""
    cams = default_rig(3)
    cams[2] = type(cams[2])(**{**cams[2].__dict__, "stop": 0.3})
    frames, _, traj = generate_rig_video(cams, duration=0.9, num_points=150, seed=4)
    log = Log()
    settings = LocalizerSettings(mounts_of(cams), stop_after=0.2)
    rig, outs, _ = run(frames, cams, settings, log)
    assert all(o.success for o in outs)
    late = [o for o in outs if (o.stamp_ns - T0) * 1e-9 > 0.55]
    assert late and all(o.cameras == ("front", "left") for o in late)
    assert all(o.missing == {"right": "stopped"} for o in late)
    assert rig.counts["right.stopped"] == 1 and rig.camera_state("right") == "stopped"
    assert any("'right'" in t and "stop_after" in t for _, t in log.warnings)
    e = np.array([errors(o, traj) for o in late])
    assert e[:, 0].max() < 0.05 and e[:, 1].max() < 0.005
    assert_balanced(rig)
    assert set(MISSED_REASONS) >= {k.split(".")[-1] for k in rig.counts if ".missed." in k}


def test_a_camera_that_never_sent_is_stopped_from_when_the_clock_began_however_noted(video):
    """After a time reset a camera that has not sent since counts as stopped ``stop_after``
    after the new timeline's first frame time on the video's clock (its stamp,
    ``VideoClock.first``), the same whether the frames' times were noted ahead
    (``check_time``, as the node and the replay do) or by ``add`` alone."""
    from rs_localizer.tracking.video import GroupingOnly

    cams, frames, _ = video
    settings = LocalizerSettings(mounts_of(cams[:2]), stop_after=0.2)
    f0 = next(f for f in frames if f.name == "front")
    cam = cams[0].camera
    d = settings.reference_ns("front", T0, cam) - T0  # (reference line after the stamp's)
    assert d > 2_000_000
    # (a timeline, then a stamp going back; the last frame 0.2 s after the first by its
    # stamp, not by its reference time)
    stamps = [T0 + 5 * 10**9, T0, T0 + 100_000_000, T0 + 200_000_000 - d // 2]
    stopped = []
    for ahead in (False, True):
        rig = GroupingOnly(settings)
        for t in stamps:
            if ahead:
                rig.check_time(t, "front")
            rig.add(CameraFrame(t, cam, f0.uv, f0.xyz, camera_name="front"))
        stopped.append(rig.counts["left.stopped"])
        assert rig.camera_state("left") == "stopped" and rig.counts["rig.time_resets"] == 1
    assert stopped == [1, 1]


def test_cameras_slower_than_stop_after_are_not_taken_as_stopped_between_their_frames():
    """Three 2 Hz cameras (a frame every 0.5 s, the default ``stop_after``): each rig frame
    holds all three cameras' frames, none counted stopped or missed; with the frame interval
    not taken into account the first camera's frame of each stamp was solved alone."""
    cams = [replace(c, fps=2.0) for c in default_rig(3)]
    frames, _, traj = generate_rig_video(cams, duration=4.0, num_points=120, seed=6)
    assert np.median(np.diff(sorted(f.stamp_ns for f in frames if f.name == "front"))) >= 5e8
    rig, outs, _ = run(frames, cams)
    assert len(outs) == 8 and all(o.success for o in outs)
    assert all(o.cameras == ("front", "left", "right") for o in outs)
    assert not [k for k in rig.counts if k.endswith(".stopped") or ".missed." in k]
    e = np.array([errors(o, traj) for o in outs])
    assert e[:, 0].max() < 0.05 and e[:, 1].max() < 0.005
    assert_balanced(rig)


def test_frames_too_far_apart_are_separate_rig_frames_counted():
    """The left camera's frames 16 ms after the front's with a 10 ms window: never one rig
    frame; each posed alone from its camera, the other counted missing as ``apart``."""
    cams = default_rig(2, offsets_s=(0.0, 0.0161))
    frames, _, traj = generate_rig_video(cams, duration=0.4, num_points=150, seed=5)
    rig, outs, _ = run(frames, cams, LocalizerSettings(mounts_of(cams), window=0.010))
    assert all(len(o.cameras) == 1 for o in outs)
    assert rig.counts["front.missed.apart"] >= 10 and rig.counts["left.missed.apart"] >= 10
    assert rig.counts["rig.incomplete"] == len(outs)
    ok = [o for o in outs if o.success]
    assert len(ok) >= 0.9 * len(outs)
    assert np.median([errors(o, traj)[0] for o in ok]) < 0.1
    assert_balanced(rig)
    # with a 20 ms window the same frames pair up
    _, outs2, _ = run(frames, cams, LocalizerSettings(mounts_of(cams), window=0.020))
    assert sum(len(o.cameras) == 2 for o in outs2) >= 10


def test_dropped_frames_and_a_camera_waiting_for_its_camera_info(video):
    """The left camera's first 5 frames come without a camera model (its camera_info has not
    arrived: skipped as ``no_camera_info``, the rig runs on the others, missing from those rig
    frames as ``no_camera_info``) and its frame 9 is dropped (``dropped``); the counts
    balance."""
    cams, frames, _ = video
    frames = [f for f in frames if not (f.name == "left" and f.index == 9)]
    by = {c.name: c.camera for c in cams}

    def camera_of(f):
        return None if f.name == "left" and f.index < 5 else by[f.name]

    rig, outs, _ = run(frames, cams, camera_of=camera_of)
    assert rig.counts["left.skipped.no_camera_info"] == 5
    assert sum(o.missing.get("left") == "no_camera_info" for o in outs) == 5
    assert sum(o.missing.get("left") == "dropped" for o in outs) == 1
    assert all(o.success for o in outs)
    assert_balanced(rig)
    assert "no_camera_info" in SKIP_REASONS


def test_a_mounting_off_by_degrees_is_named():
    """The left camera's mounting given 3 degrees off: its points become outliers of the rig's
    pose, the rig is named ``disagreeing`` with a warning naming the camera and the offset
    measured from the camera alone; the rig's pose stays accurate (the other two)."""
    cams = default_rig(3)
    frames, _, traj = generate_rig_video(cams, duration=0.4, num_points=150, seed=6)
    mounts = mounts_of(cams)
    bad = rotvec_to_matrix(np.radians([0.0, 3.0, 0.0]))
    mounts["left"] = Mounting(bad @ mounts["left"].R, mounts["left"].c)
    log = Log()
    rig, outs, _ = run(frames, cams, LocalizerSettings(mounts), log)
    assert outs[-1].disagreeing == ("left",)
    assert rig.camera_state("left") == "disagrees" and rig.counts["left.disagreements"] == 1
    text = [t for k, t in log.warnings if k == "rig.disagrees.left"]
    assert len(text) == 1 and "'left'" in text[0] and "mounting" in text[0]
    deg = float(text[0].split("alone it is ")[1].split(" deg")[0])
    assert 2.0 < deg < 4.0, text[0]
    assert outs[-1].shares["left"].ratio < 0.2 < outs[-1].shares["front"].ratio
    e = np.array([errors(o, traj) for o in outs if o.success])
    assert np.median(e[:, 0]) < 0.05 and np.median(e[:, 1]) < 0.005
    # the right mountings: nobody disagrees
    _, good, _ = run(frames, cams)
    assert all(o.disagreeing == () for o in good)


def test_a_camera_of_a_few_points_whose_mounting_is_off_is_named():
    """The left camera cut to 8-11 points per frame (one or two tags' corners: it votes in
    each rig frame's consensus) and its mounting given 3 degrees off: outvoted in every rig
    frame and, judged from as many points as it votes with, named ``disagreeing`` with a
    warning; with the right mountings nobody is named."""
    cams = default_rig(3)
    frames, _, _ = generate_rig_video(cams, duration=0.4, num_points=150, seed=6)
    rng = np.random.default_rng(6)
    small = []
    for f in frames:
        if f.name == "left":
            keep = np.flatnonzero(f.inlier)[: rng.integers(8, 12)]
            f = replace(f, uv=f.uv[keep], xyz=f.xyz[keep], inlier=f.inlier[keep])
        small.append(f)
    assert {len(f.uv) for f in small if f.name == "left"} <= set(range(8, 12))
    mounts = mounts_of(cams)
    bad = rotvec_to_matrix(np.radians([0.0, 3.0, 0.0]))
    mounts["left"] = Mounting(bad @ mounts["left"].R, mounts["left"].c)
    log = Log()
    rig, outs, _ = run(small, cams, LocalizerSettings(mounts), log)
    assert all(o.success and o.outvoted == ("left",) for o in outs)
    assert outs[-1].disagreeing == ("left",) and rig.camera_state("left") == "disagrees"
    assert [k for k, _ in log.warnings] == ["rig.disagrees.left"]
    _, good, _ = run(small, cams)
    assert all(o.success and o.disagreeing == () == o.outvoted for o in good)


def test_stamps_going_back_start_the_rig_again(video):
    """The video played twice (stamps going back by more than ``time_reset_ns``): the rig
    starts again, the track cold; a camera's frame older than its previous one (by less) is
    skipped as ``out_of_order``."""
    cams, frames, _ = video
    settings = LocalizerSettings(mounts_of(cams), time_reset_ns=200_000_000)
    rig, outs, _ = run(frames + frames, cams, settings)
    assert [o.path for o in outs].count("cold") == 2
    assert sum(o.success for o in outs) >= 34
    assert rig.counts["rig.time_resets"] == 1
    assert_balanced(rig)
    rig2, _, _ = run([frames[0], frames[3], frames[0]], cams)
    assert rig2.counts["front.skipped.out_of_order"] == 1
    assert_balanced(rig2)


def test_a_jump_ahead_at_a_dropped_frame_is_the_time_reset_no_camera_stopped(video):
    """A gap in the bag whose first frame after it is one a camera could not use (an image that
    did not decode, ``Localizer.drop``; a frame without camera model): its stamp is noted on
    the clock as every frame's, so the jump is the time reset there: the rig frame still open
    is solved as the clock's jump solves it, no camera counts as stopped for the gap (the
    skipped camera's time 3 s ahead of the other's would otherwise make that one ``stopped``,
    warned, and the reset a frame late)."""
    cams, frames, _ = video
    by = {c.name: c.camera for c in cams}
    jump, mid = 3 * 10**9, T0 + 290_000_000
    for dropped in ("drop", "no_camera_info"):
        log = Log()
        rig = Localizer(LocalizerSettings(mounts_of(cams)), log=log)
        outs, first_after = [], None
        for f in sorted(frames, key=lambda f: f.stamp_ns):
            stamp = f.stamp_ns if f.stamp_ns < mid else f.stamp_ns + jump
            if stamp > mid and first_after is None:  # (the first frame after the gap)
                first_after = f.name
                if dropped == "drop":
                    outs += rig.drop(f.name, stamp, by[f.name], "bad_input")
                else:
                    outs += rig.add(CameraFrame(stamp, None, f.uv, f.xyz, camera_name=f.name))
                continue
            outs += rig.add(CameraFrame(stamp, by[f.name], f.uv, f.xyz, camera_name=f.name))
        outs += rig.close()
        assert rig.counts["rig.time_resets"] == 1, dict(rig.counts)
        assert not [k for k in rig.counts if k.endswith(".stopped")], dict(rig.counts)
        assert not [k for k, _ in log.warnings if k == "rig.stopped"]
        assert [o.path for o in outs].count("cold") == 2 and all(o.success for o in outs)
        reason = "skipped" if dropped == "drop" else "no_camera_info"
        assert [o.missing for o in outs if o.missing] == [{first_after: reason}]
        assert_balanced(rig)


def test_a_stamp_jump_ahead_starts_the_rig_again_as_for_one_camera(video):
    """The video's second half stamped 3 s later (a gap in a bag, a clock that jumped ahead:
    more than ``time_reset_ns`` after the rig's newest frame) is a time reset, as for one
    camera (``SequenceLocalizer.check_time`` on the front camera's stamps finds the same one):
    counted ``rig.time_resets`` once and warned about with the camera's reason; the rig frame
    still open at the jump (the right camera's last frame before it lost) is solved, none
    is skipped, no camera counts as stopped for the gap, the track starts again (``cold``)
    and the rig frames after the jump are posed as well as before it against the truth (the
    jump taken off)."""
    cams, frames, traj = video
    jump, mid = 3 * 10**9, T0 + 290_000_000
    shifted = [f if f.stamp_ns < mid else replace(f, stamp_ns=f.stamp_ns + jump) for f in frames]
    last_right = max(f.index for f in frames if f.name == "right" and f.stamp_ns < mid)
    shifted = [f for f in shifted if not (f.name == "right" and f.index == last_right)]
    log = Log()
    rig, outs, _ = run(shifted, cams, log=log)
    assert rig.counts["rig.time_resets"] == 1, dict(rig.counts)
    seq = SequenceLocalizer()
    why = [seq.check_time(f.stamp_ns) for f in shifted if f.name == "front"]
    assert sum(w is not None for w in why) == 1
    camera_reason = next(w for w in why if w is not None).split(" s ")[-1]
    warned = [t for k, t in log.warnings if k == "rig.time_reset"]
    assert len(warned) == 1 and warned[0].endswith(camera_reason), (warned, camera_reason)
    assert not [k for k in rig.counts if "skipped" in k or k.endswith(".stopped")]
    assert len(outs) == 18 and all(o.success for o in outs)
    incomplete = [o for o in outs if o.missing]
    assert len(incomplete) == 1 and set(incomplete[0].missing) == {"right"}
    assert incomplete[0].stamp_ns < mid
    assert [o.path for o in outs].count("cold") == 2 and "reset" not in [o.path for o in outs]
    after = [o for o in outs if o.stamp_ns > mid + jump]
    assert len(after) == 9 and after[0].path == "cold"
    e = np.array([errors(replace(o, stamp_ns=o.stamp_ns - jump), traj) for o in after])
    assert np.median(e[:, 0]) < 0.03 and np.median(e[:, 1]) < 0.003, np.median(e, axis=0)
    assert_balanced(rig)
    # a jump within time_reset_ns is no time reset: the track resets on the gap alone
    rig2, outs2, _ = run(shifted, cams, LocalizerSettings(mounts_of(cams), time_reset_ns=5 * 10**9))
    assert rig2.counts["rig.time_resets"] == 0 and "reset" in [o.path for o in outs2]


def test_bad_settings():
    cams = default_rig(2)
    m = mounts_of(cams)
    with pytest.raises(ValueError, match="'left' has no mounting"):
        LocalizerSettings({"front": m["front"], "left": None})
    with pytest.raises(ValueError, match="at least one camera"):
        LocalizerSettings({})
    with pytest.raises(ValueError, match="rotation"):
        Mounting(np.diag([1.0, 1.0, -1.0]), np.zeros(3))
    rig = Localizer(LocalizerSettings(m))
    with pytest.raises(ValueError, match="'back' is not in the rig"):
        rig.add(
            CameraFrame(T0, cams[0].camera, np.zeros((0, 2)), np.zeros((0, 3)), camera_name="back")
        )
    mount = Mounting.from_pose(cams[1].R_rig_cam, cams[1].p_rig_cam)
    assert np.allclose(mount.position, cams[1].p_rig_cam)
    R = np.asarray(cams[1].R_rig_cam).T  # (x_cam = R x_rig + c)
    assert np.allclose(mount.R, R) and np.allclose(mount.c, -R @ cams[1].p_rig_cam)


def test_configure_takes_new_options_from_the_next_rig_frame(video):
    """``configure`` as a camera's: the estimator's options of the next rig frames (a velocity
    bound below the rig's turn refuses them ``implausible_motion``), tracking off ending the
    track (its twists still pending go out with the next rig frame), the counts and the rig
    frames open kept; settings of another rig (window, mountings) are refused."""
    from rs_localizer.estimation.options import EstimateOptions

    cams, frames, _ = video
    by = {c.name: c.camera for c in cams}
    settings = LocalizerSettings(mounts_of(cams))
    rig = Localizer(settings)
    outs = []
    half = len(frames) // 2
    for f in frames[:half]:
        outs += rig.add(CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name))
    assert outs and all(o.success for o in outs) and rig.pending > 0
    pending, received, open_ = rig.pending, rig.counts["front.received"], rig.rig_counts()
    slow = EstimateOptions()
    slow = replace(slow, plausibility=replace(slow.plausibility, max_angular_velocity=0.01))
    rig.configure(replace(settings, options=slow, tracking=None))
    assert rig.track_state == "disabled" and rig.pending == 0
    assert rig.counts["front.received"] == received and rig.rig_counts() == open_
    later = []
    for f in frames[half:]:
        later += rig.add(CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name))
    later += rig.close()
    assert len(later[0].fused) == pending
    assert later and not any(o.success for o in later)
    assert {o.estimate.failure for o in later} == {"implausible_motion"}
    assert len(outs) + len(later) == 18
    assert_balanced(rig)
    with pytest.raises(ValueError, match="keeps its window"):
        rig.configure(replace(settings, window=0.03))
    moved = dict(mounts_of(cams), front=Mounting.from_pose(np.eye(3), np.zeros(3)))
    with pytest.raises(ValueError, match="keeps its mounts"):
        rig.configure(replace(settings, mounts=moved))


def test_the_filter_measures_with_the_estimators_covariance(video):
    """Each rig frame's measurement carries the rig estimator's covariance and acceleration
    sensitivity, and that covariance covers the pose's error against the truth (median NEES
    of the 6 pose errors below 3 x 6)."""
    from rs_localizer.geometry import matrix_to_rotvec

    cams, frames, traj = video
    _, outs, _ = run(frames, cams)
    nees = []
    for o in outs:
        m = o.estimate
        assert m.acceleration_sensitivity.shape == (12, 6)
        R, p, _, _ = rig_truth(traj, (o.stamp_ns - T0) * 1e-9)
        e = np.concatenate([matrix_to_rotvec(m.pose.orientation @ R.T), m.pose.position - p])
        nees.append(e @ np.linalg.solve(m.covariance[:6, :6], e))
    assert np.median(nees) < 18.0, np.median(nees)


def test_calibrate_mountings_from_the_video(video):
    """Each camera's mounting from the 0.6 s video (18 rig frames, 150 points, 20 % outliers)
    relative to the front camera's true one: within 0.05 deg and 3 mm of the truth and 3 of its
    stated standard deviations; no frame of the reference camera is an error."""
    from rs_localizer.calibration import calibrate_mountings

    cams, frames, _ = video
    by = {c.name: c.camera for c in cams}
    truth = mounts_of(cams)
    fr = [CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name) for f in frames]
    out = calibrate_mountings(fr, "front", reference_mount=truth["front"])
    assert sorted(out) == ["front", "left", "right"]
    assert out["front"].mount is truth["front"] and out["front"].std_deg == 0.0
    for n in ("left", "right"):
        e = out[n]
        deg = rotation_angle_deg(e.mount.R, truth[n].R)
        mm = 1e3 * np.linalg.norm(e.mount.position - truth[n].position)
        assert e.frames >= 15 and deg < 0.05 and mm < 3.0, (n, deg, mm)
        assert deg < 3 * e.std_deg and mm < 3 * e.std_mm, (n, deg, mm, e)
    with pytest.raises(ValueError, match="nope"):
        calibrate_mountings(fr, "nope")


def test_a_mountings_stated_std_covers_its_error_over_a_longer_video():
    """5 s of the rig walk (150 rig frames, 300 points, 0.5 px noise, 20 % outliers): the
    single-camera poses share a bias that averaging 150 frames does not remove (here the
    position errors are 2.1-2.5 times the batch-means std of the mean alone); each mounting's
    error against the truth is within 2 of its stated std, which is never below the
    independent frames' std of the mean nor 10 times the errors' size (not inflated)."""
    from rs_localizer.calibration import calibrate_mountings

    cams = default_rig(3)
    frames, _, _ = generate_rig_video(cams, duration=5.0, num_points=300, seed=2)
    by = {c.name: c.camera for c in cams}
    truth = mounts_of(cams)
    fr = [CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name) for f in frames]
    out = calibrate_mountings(fr, "front", reference_mount=truth["front"])
    err = {}
    for n in ("left", "right"):
        e = out[n]
        assert e.frames >= 140, (n, e.frames)
        err[n] = (
            rotation_angle_deg(e.mount.R, truth[n].R),
            1e3 * np.linalg.norm(e.mount.position - truth[n].position),
        )
    scale_deg = max(d for d, _ in err.values())
    scale_mm = max(m for _, m in err.values())
    for n, (deg, mm) in err.items():
        e = out[n]
        assert deg <= 2 * e.std_deg and mm <= 2 * e.std_mm, (n, deg, mm, e)
        # not below the std of the mean of independent frames
        assert e.std_deg >= e.scatter_deg / np.sqrt(e.frames)
        assert e.std_mm >= e.scatter_mm / np.sqrt(e.frames)
        assert e.std_deg < 10 * scale_deg and e.std_mm < 10 * scale_mm, (n, deg, mm, e)


#: the ring of four cameras, in order round the rig
RING = ("front", "left", "back", "right")


def ring_frames(duration, seed, phases=(0, 1, 2, 3)):
    """A 4-camera ring (front, left, back, right) where only neighbours see the map at the
    same time: in quarter q of the video, cameras RING[q] and RING[q + 1] send frames (the
    quarters not in ``phases``: none). Front and back never share a rig frame."""
    cams = default_rig(4)
    frames, _, _ = generate_rig_video(cams, duration=duration, num_points=150, seed=seed)
    by = {c.name: c.camera for c in cams}
    out = []
    for f in frames:
        q = min(int(4 * (f.stamp_ns - T0) * 1e-9 / duration), 3)
        if q in phases and f.name in (RING[q], RING[(q + 1) % 4]):
            out.append(CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name))
    return cams, out


def test_calibrate_mountings_of_a_ring_of_cameras():
    """A ring of four cameras, only neighbours sharing rig frames (2 s, 150 points, 20 %
    outliers): every mounting within 0.3 deg and 5 mm of the truth and 3 of its stated
    standard deviations (the back camera only through the left and right ones), with a
    positive-definite covariance whose trace gives the stated std."""
    from rs_localizer.calibration import calibrate_mountings

    cams, fr = ring_frames(2.0, 1)
    times = {n: {f.stamp_ns // 10**7 for f in fr if f.camera_name == n} for n in RING}
    assert not times["front"] & times["back"]  # (never within 10 ms of each other)
    truth = mounts_of(cams)
    out = calibrate_mountings(fr, "front", reference_mount=truth["front"])
    assert sorted(out) == sorted(RING)
    assert out["front"].mount is truth["front"]
    for n in ("left", "back", "right"):
        e = out[n]
        deg = rotation_angle_deg(e.mount.R, truth[n].R)
        mm = 1e3 * np.linalg.norm(e.mount.position - truth[n].position)
        assert e.frames >= 25 and deg < 0.3 and mm < 5.0, (n, deg, mm)
        assert deg < 3 * e.std_deg and mm < 3 * e.std_mm, (n, deg, mm, e)
        assert np.linalg.eigvalsh(e.mount.covariance).min() > 0
        assert e.std_deg == pytest.approx(np.degrees(np.sqrt(np.trace(e.mount.covariance[:3, :3]))))


def test_calibrate_mountings_of_a_chain_of_cameras():
    """An open chain: front sees the map with left, left with back, back with right (each
    pair a quarter of a 2 s video, 150 points, 20 % outliers); right reaches the reference
    through two cameras and front never shares a rig frame with back or right. Every
    mounting is within 3 of its stated standard deviations of the truth (0.2-0.75 std
    here), and the stated std grows along the chain (each link adds its error)."""
    from rs_localizer.calibration import calibrate_mountings

    cams, fr = ring_frames(2.0, 3, phases=(0, 1, 2))
    shared = {n: {f.stamp_ns // 10**7 for f in fr if f.camera_name == n} for n in RING}
    assert not shared["front"] & (shared["back"] | shared["right"])
    truth = mounts_of(cams)
    out = calibrate_mountings(fr, "front", reference_mount=truth["front"])
    assert sorted(out) == sorted(RING)
    for n in ("left", "back", "right"):
        e = out[n]
        deg = rotation_angle_deg(e.mount.R, truth[n].R)
        mm = 1e3 * np.linalg.norm(e.mount.position - truth[n].position)
        assert deg < 3 * e.std_deg and mm < 3 * e.std_mm, (n, deg, mm, e)
        assert deg < 0.1 and mm < 5.0, (n, deg, mm)
    assert out["left"].std_mm < out["back"].std_mm < out["right"].std_mm


def test_cameras_not_connected_to_the_reference_are_missing():
    """The ring's quarters where left sees with back and back with right, and the front
    camera's frames of the first quarter alone: with left as the reference back and right
    are calibrated (right through back) and front, which shares no rig frame, is missing;
    with front as the reference only front is returned."""
    from rs_localizer.calibration import calibrate_mountings

    _, part = ring_frames(0.8, 2, phases=(0, 1, 2))
    part = [f for f in part if not (f.camera_name == "left" and f.stamp_ns < T0 + 2 * 10**8)]
    assert sorted(calibrate_mountings(part, "left")) == ["back", "left", "right"]
    assert sorted(calibrate_mountings(part, "front")) == ["front"]


def test_the_rig_and_one_camera_share_the_pending_twists_and_end_track(video):
    # the rig's pending twists are the single camera's (tracking/localizer.py): pending, flush
    # and end_track; after end_track the rig has no prediction for a camera's next frame
    cams, frames, _ = video
    by = {c.name: c.camera for c in cams}
    rig = Localizer(LocalizerSettings(mounts_of(cams)))
    cut = len(frames) // 2
    for f in frames[:cut]:
        rig.add(CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name))
    assert rig.pending > 0
    nxt = frames[cut]
    assert rig.predict_camera(nxt.name, nxt.stamp_ns, by[nxt.name]) is not None
    rig.end_track()
    assert rig.pending == 0 and rig.flush() == [] and rig.track_state == "lost"
    assert rig.predict_camera(nxt.name, nxt.stamp_ns, by[nxt.name]) is None
    fused = []
    for f in frames[cut:]:  # (a new track: its rig frames fused again)
        for o in rig.add(CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name)):
            fused += o.fused
    fused += rig.flush()
    assert len(fused) > 0 and rig.pending == 0


def test_a_rig_and_a_camera_take_one_tracking_options_type(video, monkeypatch):
    """A rig's tracking options are a camera's ``TrackerOptions``: its tracked rig frames are
    verified with at most ``tracked_max_iterations`` RANSAC samples (default
    ``RIG_TRACKED_MAX_ITERATIONS``), cold ones with the estimator options' own maximum; a
    camera's tracked frames take the same field (default: the options' own maximum)."""
    import rs_localizer.tracking.tracker as tracker_module
    from rs_localizer.estimation.options import EstimateOptions
    from rs_localizer.estimation.rig import RIG_OPTIONS
    from rs_localizer.tracking.tracker import RSTracker, TrackerOptions
    from rs_localizer.tracking.video import RIG_TRACKED_MAX_ITERATIONS

    cams, frames, _ = video
    seen = []
    real = tracker_module.estimate_rig_pose

    def spy(views, options, **kw):
        seen.append((kw.get("initial_model") is not None, options.ransac.max_iterations))
        return real(views, options, **kw)

    monkeypatch.setattr(tracker_module, "estimate_rig_pose", spy)
    cold = RIG_OPTIONS.ransac.max_iterations
    for tracking, tracked in ((TrackerOptions(), RIG_TRACKED_MAX_ITERATIONS),
                              (TrackerOptions(tracked_max_iterations=7), 7)):  # fmt: skip
        seen.clear()
        _, outs, _ = run(frames, cams, LocalizerSettings(mounts_of(cams), tracking=tracking))
        assert any(o.path == "tracked" for o in outs)
        assert {n for t, n in seen if t} == {tracked}
        assert {n for t, n in seen if not t} == {cold}
    options = EstimateOptions()
    assert RSTracker(options=options).tracked_options.ransac.max_iterations == (
        options.ransac.max_iterations
    )
    tracker = RSTracker(options=options, tracker_options=TrackerOptions(tracked_max_iterations=9))
    assert tracker.tracked_options.ransac.max_iterations == 9
    with pytest.raises(ValueError, match="tracked_max_iterations"):
        TrackerOptions(tracked_max_iterations=0)


def test_a_camera_stamped_late_is_put_on_the_rig_clock_by_its_time_offset(video):
    """A camera whose driver stamps its frames 25 ms late: its frames join the wrong rig
    frames, where it disagrees with the others; with ``time_offsets`` of -25 ms the rig is
    the one of the correct stamps, estimate for estimate, and so are the mountings
    calibrated from the video."""
    from dataclasses import replace as dc_replace

    from rs_localizer.calibration import calibrate_mountings

    cams, frames, _ = video
    late = [dc_replace(f, stamp_ns=f.stamp_ns + 25_000_000) if f.name == "left" else f
            for f in frames]  # fmt: skip
    rig, _, _ = run(late, cams)
    assert rig.counts["left.disagreements"] == 1 and rig.camera_state("left") == "disagrees"
    truth_rig, want, _ = run(frames, cams)
    settings = LocalizerSettings(mounts_of(cams), time_offsets={"left": -0.025})
    fixed, got, _ = run(late, cams, settings)
    assert fixed.counts == truth_rig.counts
    assert [o.cameras for o in got] == [o.cameras for o in want]
    assert [o.stamp_ns for o in got] == [o.stamp_ns for o in want]
    for a, b in zip(got, want, strict=True):
        assert a.success == b.success
        if a.success:
            np.testing.assert_array_equal(a.estimate.model.R, b.estimate.model.R)
            np.testing.assert_array_equal(a.estimate.model.C, b.estimate.model.C)
    by = {c.name: c.camera for c in cams}

    def frames_of(video):
        return [CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=f.name) for f in video]

    truth = calibrate_mountings(frames_of(frames), "front", min_inliers=20)
    shifted = calibrate_mountings(
        frames_of(late), "front", min_inliers=20, time_offsets={"left": -0.025}
    )
    np.testing.assert_array_equal(shifted["left"].mount.R, truth["left"].mount.R)
    # the offset estimated from the video's rotation: -25 ms, each mounting within 3 of its
    # stated std of the truth
    mounts = mounts_of(cams)
    found = calibrate_mountings(
        frames_of(late), "front", reference_mount=mounts["front"], estimate_time_offsets=True
    )
    for n, want in (("left", -0.025), ("right", 0.0)):
        dt, std = found[n].time_offset, found[n].time_offset_std
        assert abs(dt - want) < min(4 * std + 1e-5, 1e-3), (n, dt, std)
    assert np.isnan(found["front"].time_offset_std)
    for n in ("left", "right"):
        e = found[n]
        deg = rotation_angle_deg(e.mount.R, mounts[n].R)
        mm = 1e3 * np.linalg.norm(e.mount.position - mounts[n].position)
        assert deg < 3 * e.std_deg and mm < 3 * e.std_mm, (n, deg, mm, e.std_deg, e.std_mm)
    with pytest.raises(ValueError, match="time_offsets"):
        LocalizerSettings(mounts_of(cams), time_offsets={"back": 0.01})
    with pytest.raises(ValueError, match="at most 1 s"):
        LocalizerSettings(mounts_of(cams), time_offsets={"left": 2.0})
    with pytest.raises(ValueError, match="keeps its time_offsets"):
        Localizer(LocalizerSettings(mounts_of(cams))).configure(settings)
