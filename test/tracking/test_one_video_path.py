"""Localizer: a camera alone and a rig solve their frames the one way (one implementation
rule, one gyro window, one time-reset policy, one tracker path, one carried prediction); what a
rig does as a camera does, each against an independent expectation (simulated rig videos,
rs_localizer.sim.trajectory.generate_rig_video)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from helpers.rig import T0, assert_balanced, mounts_of

from rs_localizer.correspondences import Correspondences
from rs_localizer.estimation import implementation
from rs_localizer.frames import Mounting
from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.sim.trajectory import default_rig, generate_rig_video, rig_truth
from rs_localizer.tracking.localizer import CameraFrame
from rs_localizer.tracking.sequence import GyroSettings
from rs_localizer.tracking.tracker import TrackerOptions
from rs_localizer.tracking.video import Localizer, LocalizerSettings


@pytest.fixture(scope="module")
def video():
    cams = default_rig(2)
    frames, _, traj = generate_rig_video(cams, duration=0.3, num_points=80, seed=3)
    return cams, frames, traj


def _add_all(rig, frames, cams, stamp=None, rows=None):
    by = {c.name: c.camera for c in cams}
    outs = []
    for f in sorted(frames, key=lambda f: f.stamp_ns):
        uv, xyz = (f.uv, f.xyz) if rows is None else rows(f)
        s = f.stamp_ns if stamp is None else stamp(f)
        outs += rig.add(CameraFrame(s, by[f.name], uv, xyz, tag=f.index, camera_name=f.name))
    return outs + rig.close()


def test_a_rig_without_an_implementation_runs_the_estimators_default_and_says_which(
    video, monkeypatch
):
    """In a process that does not compile by default (no usable numba) a rig given no
    implementation runs the rig estimator's default, NumPy, and says so as a camera does: each
    rig frame's ``compiled`` is what its estimate records it ran on, and the frames are
    counted ``rig.uncompiled``, never ``compiled`` True for a frame the NumPy path solved."""
    cams, frames, _ = video
    monkeypatch.setattr(implementation, "_BY_DEFAULT", False)
    rig = Localizer(LocalizerSettings(mounts_of(cams)))
    outs = _add_all(rig, frames[:8], cams)
    solved = [o for o in outs if o.estimate is not None]
    assert solved
    for o in solved:
        assert o.estimate.implementation == "numpy"
        assert o.compiled is False
    assert rig.counts["rig.uncompiled"] == len(outs)
    assert_balanced(rig)


def _windows(rig):
    """The gyro windows (ns) the rig asks its gyro input for, in order."""
    asked = []
    real = rig.gyro_input.measurement

    def measurement(window):
        asked.append(window)
        return real(window)

    rig.gyro_input.measurement = measurement
    return asked


def test_a_rig_frames_gyro_window_runs_from_each_cameras_stamp_row(video):
    """The gyro window of a rig frame is a camera's: each camera's readout from its frame's
    stamp, the capture time of row ``stamp_row`` (here row 200), its first line read
    ``200 line_delay`` before (top to bottom; bottom to top: ``(lines - 201) line_delay``), its
    last ``(lines - 1) line_delay`` after its first; the window spans the earliest first line
    to the latest last line (each end within 1 ns: integer ns)."""
    cams, frames, _ = video
    imu = GyroSettings(R_cam_imu=np.eye(3), wait=0.0)
    rig = Localizer(LocalizerSettings(mounts_of(cams), imu=imu, stamp_row=200.0))
    asked = _windows(rig)
    outs = _add_all(rig, frames[:10], cams)
    by = {c.name: c.camera for c in cams}
    assert len(asked) == len(outs) > 0
    for o, (lo, hi) in zip(outs, asked, strict=True):
        first, last = [], []
        for n, f in o.frames.items():
            cam = by[n]
            rows_before = 200.0 if cam.readout == "top_to_bottom" else cam.lines - 201.0
            a = f.stamp_ns - round(rows_before * cam.line_delay * 1e9)  # (int ns)
            first.append(a)
            last.append(a + round((cam.lines - 1) * cam.line_delay * 1e9))
        assert abs(lo - min(first)) <= 1 and abs(hi - max(last)) <= 1, (lo, hi, first, last)


def test_a_rig_frame_taken_at_one_instant_asks_no_gyro_as_a_global_shutter_camera(video):
    """Global-shutter cameras (no readout time): a rig frame of frames at one stamp has no
    motion within it to measure, so no gyro measurement is asked for (as a global-shutter
    camera's frame: none over an empty window); frames 4 ms apart are measured over
    exactly their two stamps."""
    cams, frames, _ = video
    gs = [replace(c, camera=replace(c.camera, line_delay=0.0)) for c in cams]
    imu = GyroSettings(R_cam_imu=np.eye(3), wait=0.0)
    first = [f for f in frames if f.index == 0]
    for apart in (0, 4_000_000):
        rig = Localizer(LocalizerSettings(mounts_of(gs), imu=imu, tracking=None))
        asked = _windows(rig)
        outs = _add_all(rig, first, gs, stamp=lambda f, d=apart: T0 + d * (f.name == "left"))
        assert len(outs) == 1 and set(outs[0].cameras) == {c.name for c in gs}
        if apart == 0:
            assert asked == [] and outs[0].gyro is None
            assert not any(k.startswith("rig.gyro_missing") for k in rig.counts)
        else:
            assert asked == [(T0, T0 + apart)]


def test_a_camera_counts_its_stamp_jump_ahead_as_a_rig_camera_does(video):
    """A camera alone (a rig of one named ``""``) whose stamps jump 2 s ahead: a time reset,
    counted ``.stamp_jumped_ahead`` under its name as a rig's camera counts it, once per jump
    (``rig.time_resets`` the same)."""
    cams, frames, _ = video
    cam = cams[0]
    mine = [f for f in frames if f.name == cam.name]
    rig = Localizer(LocalizerSettings({"": Mounting(np.eye(3), np.zeros(3))}))
    for k, f in enumerate(mine[:6]):
        jump = 2_000_000_000 if k >= 3 else 0
        rig.add(CameraFrame(f.stamp_ns + jump, cam.camera, f.uv, f.xyz))
    assert rig.counts[".stamp_jumped_ahead"] == 1 == rig.counts["rig.time_resets"]


class _Rows:
    """A video front end giving the frame's own correspondences (``current``)."""

    def __init__(self, current):
        self.current = current

    def process(self, image, camera, encoding="bgr8", prediction=None):
        f = self.current["frame"]
        return Correspondences(f.uv, f.xyz)

    def observe(self, stamp_ns, points2d, feedback):
        pass

    def pop_warning(self):
        return None


def _rig_of_row_images(cams, frames, seed):
    """A rig video whose cameras' front ends give each frame's simulated rows
    (:class:`_Rows`) for random mono images, the frames of indices 0 and 1 sent in stamp
    order: the rig, ``send(frame, dt=0, image=None)`` (a frame's image, random unless given,
    at its stamp plus ``dt`` ns; what ``process_image`` returned) and each camera's last
    image sent."""
    current = {}
    rig = Localizer(LocalizerSettings(mounts_of(cams)))
    for c in cams:
        rig.set_frontend(c.name, _Rows(current), "rows")
    by = {c.name: c.camera for c in cams}
    rng = np.random.default_rng(seed)
    images = {}

    def send(f, dt=0, image=None):
        current["frame"] = f
        images[f.name] = rng.integers(0, 255, (48, 64), np.uint8) if image is None else image
        return rig.process_image(f.name, f.stamp_ns + dt, images[f.name], by[f.name], "mono8")

    for f in sorted((f for f in frames if f.index < 2), key=lambda f: f.stamp_ns):
        send(f)
    return rig, send, images


def test_a_rig_cameras_image_after_a_time_reset_is_not_compared_with_the_old_timelines(video):
    """After a time reset (one camera's stamps 2 s ahead: the clock jumped) another camera's
    image that is the same picture as its last one of the old timeline is a new timeline's
    first image, taken, not skipped as ``frozen_image``, as a camera's video takes it;
    the same image again within the new timeline still is."""
    cams, frames, _ = video
    rig, send, images = _rig_of_row_images(cams, frames, seed=2)
    a, b = (next(f for f in frames if f.index == 2 and f.name == c.name) for c in cams)
    jump = 2_000_000_000
    send(a, jump)  # (a new picture, 2 s on: the time reset)
    assert rig.counts["rig.time_resets"] == 1
    send(b, jump, images[b.name])  # (camera b's last picture again, in the new timeline)
    assert rig.counts[f"{b.name}.skipped.frozen_image"] == 0
    send(b, jump + 33_000_000, images[b.name])
    assert rig.counts[f"{b.name}.skipped.frozen_image"] == 1
    rig.close()
    assert_balanced(rig)


def test_a_rig_keeps_as_its_gate_the_inliers_over_the_rows_it_was_given(video):
    """The track's inlier ratio of a posed rig frame (the next frame's gate) is a camera's:
    its inliers over every row given, also rows it could not use (here 10 rows per camera
    with a NaN world point), as the camera's tracker keeps it, not over the usable rows alone."""
    cams, frames, _ = video

    def rows(f):
        xyz = f.xyz.copy()
        xyz[:10] = np.nan
        return f.uv, xyz

    rig = Localizer(LocalizerSettings(mounts_of(cams)))
    by = {c.name: c.camera for c in cams}
    for f in sorted(frames[:12], key=lambda f: f.stamp_ns):
        uv, xyz = rows(f)
        for o in rig.add(CameraFrame(f.stamp_ns, by[f.name], uv, xyz, camera_name=f.name)):
            if o.success:
                given = sum(len(fr.points2d) for fr in o.frames.values())
                assert given > int(np.sum(o.estimate.num_valid_per_view))
                assert rig._track.inlier_ratio == o.estimate.num_inliers / given


def test_a_rig_without_tracking_carries_its_last_pose_for_frames_added(video):
    """Without tracking a rig's frames given to ``add`` (no images) are carried as a
    camera's: the next frame of a camera is predicted from the last rig frame posed, carried at
    its own twist through the camera's mounting, within 2 deg of the truth, as
    after rig frames of images."""
    cams, frames, traj = video
    rig = Localizer(LocalizerSettings(mounts_of(cams), tracking=None))
    head = [f for f in frames if f.index < 4]
    outs = _add_all(rig, head, cams)
    assert any(o.success for o in outs)
    nxt = next(f for f in frames if f.index == 4 and f.name == cams[0].name)
    model = rig.predict_camera(nxt.name, nxt.stamp_ns, cams[0].camera)
    assert model is not None
    R_rig, _, _, _ = rig_truth(traj, (nxt.stamp_ns - T0) * 1e-9)
    R_world_cam = R_rig @ cams[0].R_rig_cam  # (rig -> world after camera -> rig)
    assert rotation_angle_deg(model[0].T, R_world_cam) < 2.0  # (the model's R: world -> camera)


@pytest.mark.parametrize("alone", [True, False])
def test_a_frame_whose_estimator_raises_after_a_gap_releases_the_ended_tracks_twists(
    video, monkeypatch, alone
):
    """A frame 0.7 s after the last (beyond ``max_gap``, within ``time_reset_ns``: the track
    resets at it) whose estimator raises: the frame fails (``error``) and the twists the
    ended track still held go out with it, final as they are: every frame posed before it
    has had its fused twist handed out exactly once, a camera's video as a rig: none
    stays pending."""
    from rs_localizer.tracking import tracker

    cams, frames, _ = video
    if alone:
        cams = cams[:1]
        frames = [f for f in frames if f.name == cams[0].name]
        mounts = {"": Mounting(np.eye(3), np.zeros(3))}
    else:
        mounts = mounts_of(cams)
    name = {c.name: "" if alone else c.name for c in cams}
    by = {c.name: c.camera for c in cams}
    rig = Localizer(LocalizerSettings(mounts))
    head = sorted((f for f in frames if f.index < 5), key=lambda f: f.stamp_ns)
    outs = []
    for f in head:
        outs += rig.add(CameraFrame(f.stamp_ns, by[f.name], f.uv, f.xyz, camera_name=name[f.name]))
    if not alone:
        outs += rig.close()
    posed = {o.stamp_ns for o in outs if o.success}
    fused = [p.pose.stamp_ns for o in outs for p in o.fused]
    assert len(posed) >= 4 and rig.pending > 0

    def raising(*a, **k):
        raise RuntimeError("estimator failed")

    monkeypatch.setattr(tracker, "estimate_rs_pose" if alone else "estimate_rig_pose", raising)
    late = [f for f in frames if f.index == 5]
    for f in late:
        s = f.stamp_ns + 700_000_000
        got = rig.add(CameraFrame(s, by[f.name], f.uv, f.xyz, camera_name=name[f.name]))
        got += [] if alone else rig.close()
        fused += [p.pose.stamp_ns for o in got for p in o.fused]
        assert all(o.error == "RuntimeError: estimator failed" for o in got)
    assert sorted(fused) == sorted(posed) and rig.pending == 0


def test_a_rig_cameras_image_that_resets_the_time_is_not_compared_with_its_last(video):
    """A rig camera's frame time is noted before its image is searched, as a camera's: its
    image 2 s after the rig's newest frame (a time reset) that is the same picture as its
    last one is the new timeline's first image, taken, not skipped as ``frozen_image``, and
    the reset is counted."""
    cams, frames, _ = video
    rig, send, images = _rig_of_row_images(cams, frames, seed=5)
    a = next(f for f in frames if f.index == 2 and f.name == cams[0].name)
    send(a, 2_000_000_000, images[a.name])  # (camera a's last picture, 2 s on)
    assert rig.counts["rig.time_resets"] == 1
    assert rig.counts[f"{a.name}.stamp_jumped_ahead"] == 1
    assert rig.counts[f"{a.name}.skipped.frozen_image"] == 0
    assert rig.camera_counts(a.name)["pending"] == 1  # (its frame in the new rig frame)
    rig.close()
    assert_balanced(rig)


def test_a_rig_notes_its_cameras_stamps_on_the_clock_as_a_camera_does(video):
    """The time-reset policy reads each camera's stamp on the rig's clock, as a camera's video
    reads its stamps, not its reference line's capture time: a global-shutter camera's frame
    stamped 1.005 s after a rolling-shutter camera's frame is a jump ahead of more than
    ``time_reset_ns`` (1 s), a time reset, although the rolling
    shutter's reference line, read 10.8 ms after its stamp's row, puts the two 0.994 s apart."""
    cams, frames, _ = video
    rs, gs = cams[0], replace(cams[1], camera=replace(cams[1].camera, line_delay=0.0))
    assert rs.camera.readout == "top_to_bottom"
    # (the reference line: the middle row, 359.5 rows of 30 us after row 0)
    ref_after = LocalizerSettings(mounts_of(cams)).reference_ns(rs.name, T0, rs.camera) - T0
    assert ref_after == round(359.5 * 30e-6 * 1e9)
    rig = Localizer(LocalizerSettings(mounts_of([rs, gs]), tracking=None))
    f_rs = next(f for f in frames if f.index == 0 and f.name == rs.name)
    f_gs = next(f for f in frames if f.index == 0 and f.name == gs.name)
    rig.add(CameraFrame(T0, rs.camera, f_rs.uv, f_rs.xyz, camera_name=rs.name))
    rig.add(CameraFrame(T0 + 1_005_000_000, gs.camera, f_gs.uv, f_gs.xyz, camera_name=gs.name))
    assert rig.counts["rig.time_resets"] == 1
    assert rig.counts[f"{gs.name}.stamp_jumped_ahead"] == 1
    rig.close()
    assert_balanced(rig)


def test_a_rig_whose_track_has_no_state_predicts_from_its_last_posed_frame(video):
    """With no state in the rig's track (a new track, other tracking options given to
    ``configure``) the next frame of a camera is predicted, as a camera's video predicts it,
    from the last rig frame posed carried at its own twist through the camera's mounting:
    within 2 deg of the truth, without waiting for the new track to have a state."""
    cams, frames, traj = video
    rig = Localizer(LocalizerSettings(mounts_of(cams)))
    outs = _add_all(rig, [f for f in frames if f.index < 4], cams)
    assert outs[-1].success and rig.track_state == "tracking"
    rig.configure(replace(rig.settings, tracking=TrackerOptions(gate_px=12.0)))
    assert rig.track_state == "lost"
    nxt = next(f for f in frames if f.index == 4 and f.name == cams[0].name)
    model = rig.predict_camera(nxt.name, nxt.stamp_ns, cams[0].camera)
    assert model is not None
    R_rig, _, _, _ = rig_truth(traj, (nxt.stamp_ns - T0) * 1e-9)
    R_world_cam = R_rig @ cams[0].R_rig_cam  # (rig -> world after camera -> rig)
    assert rotation_angle_deg(model[0].T, R_world_cam) < 2.0  # (the model's R: world -> camera)


def test_a_frames_own_twist_is_final_by_one_rule_for_a_camera_and_a_rig(video):
    """One rule for ``twist_now``, a camera's frame's and a rig frame's: its own twist is final
    when nothing fuses it (no tracking) or its estimator measures no twist
    (``FrameViews.measures_twist``). A rolling-shutter camera alone and a rig hold their frames
    for the fused twist (a rig frame of global-shutter cameras at one instant too: its pose is
    fused into the rig's twist); a camera alone on P3P, or without readout time, measures
    none: each frame's own twist final at once; without tracking every frame's is."""
    cams, frames, _ = video
    cam = cams[0]
    mine = [f for f in frames if f.name == cam.name][:4]
    alone = {"": Mounting(np.eye(3), np.zeros(3))}
    gs_cam = replace(cam.camera, line_delay=0.0)
    gs = [replace(c, camera=replace(c.camera, line_delay=0.0)) for c in cams]
    first = [f for f in frames if f.index < 4]
    cases = [
        (LocalizerSettings(alone), cam.camera, False),
        (LocalizerSettings(alone, solver="p3p"), cam.camera, True),
        (LocalizerSettings(alone), gs_cam, True),
        (LocalizerSettings(alone, tracking=None), cam.camera, True),
    ]
    for settings, camera, now in cases:
        rig = Localizer(settings)
        outs = [o for f in mine for o in rig.add(CameraFrame(f.stamp_ns, camera, f.uv, f.xyz))]
        assert len(outs) == 4 and all(o.success for o in outs)
        assert all(o.twist_now is now for o in outs), (settings.solver, camera.line_delay)
        assert rig.pending == (0 if now else len(outs)) - sum(len(o.fused) for o in outs)
    for rig_cams, stamp in ((cams, None), (gs, lambda f: T0 + 33_000_000 * f.index)):
        rig = Localizer(LocalizerSettings(mounts_of(rig_cams)))
        outs = [o for o in _add_all(rig, first, rig_cams, stamp=stamp) if o.success]
        assert len(outs) >= 3 and not any(o.twist_now for o in outs)
        if stamp is not None:
            assert {o.estimate.motion_model for o in outs} == {"global_shutter"}
    rig = Localizer(LocalizerSettings(mounts_of(cams), tracking=None))
    outs = [o for o in _add_all(rig, first, cams) if o.success]
    assert outs and all(o.twist_now for o in outs)
