"""A camera alone is a rig of one: a Localizer of one camera at the identity mounting
(LocalizerSettings.single_camera) given the camera's options solves every frame as the camera's own
SequenceLocalizer does, bit for bit: each estimate (pose, twist, model, inliers, failure,
covariances), its path and every fused twist, with tracking (the prediction's motion prior
too), without, across a new configuration, with a gyro, and on rendered images through a front
end (the same prediction searched with). A rig of two cameras keeps the rig estimator."""

import dataclasses

import numpy as np
import pytest

from rs_localizer.estimation.estimate import EstimateOptions, RansacOptions
from rs_localizer.estimation.result import camera_estimate
from rs_localizer.frames import Mounting
from rs_localizer.sim.trajectory import (
    R_IMU_CAMERA,
    SequenceConfig,
    Teleport,
    Trajectory,
    generate_sequence,
    imu_samples,
)
from rs_localizer.tracking.gyro_input import GyroSettings
from rs_localizer.tracking.localizer import CameraFrame
from rs_localizer.tracking.sequence import SequenceLocalizer, SequenceSettings
from rs_localizer.tracking.tracker import TrackerOptions
from rs_localizer.tracking.video import Localizer, LocalizerSettings

OPTS = EstimateOptions()  # (the camera's default options)
IDENTITY = Mounting(np.eye(3), np.zeros(3))
FRAMES = 24


@pytest.fixture(scope="module")
def video():
    config = SequenceConfig(num_frames=FRAMES, num_points=200, seed=5)
    frames, _, cam, traj = generate_sequence(config)
    t, w, _ = imu_samples(traj, -0.1, FRAMES / config.fps + 0.1, 200.0, seed=1)
    imu = [(config.t0_ns + int(round(s * 1e9)), r) for s, r in zip(t, w, strict=True)]
    return frames, cam, imu


def _same(a, b) -> bool:
    """Bit for bit (None only as None)."""
    if a is None or b is None:
        return a is None and b is None
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def _assert_same_pose(a, b):
    for f in ("orientation", "position", "angular_velocity", "linear_velocity"):
        assert _same(getattr(a, f), getattr(b, f)), f


def _assert_same_estimate(c, r, spr: float):
    """The camera's estimate ``c`` and the rig of one's ``r``: the rig's model has its
    velocities per second (the camera's over seconds_per_unit_r)."""
    for f in ("success", "failure", "initial_used", "initial_explained", "motion_prior_used",
              "gyro_used", "gyro_rejected", "planar", "num_valid", "ransac_iterations",
              "solver", "motion_model"):  # fmt: skip
        assert getattr(c, f) == getattr(r, f), f
    for f in ("inliers", "covariance", "pose_covariance", "twist_covariance",
              "acceleration_sensitivity"):  # fmt: skip
        assert _same(getattr(c, f), getattr(r, f)), f
    _assert_same_pose(c.pose, r.pose)
    assert _same(c.model.R, r.model.R) and _same(c.model.C, r.model.C)
    if c.success:
        k = spr if spr > 0 else 1.0  # (a global shutter's zeros kept)
        assert _same(c.model.w / k, r.model.w) and _same(c.model.t / k, r.model.t)
    assert r.num_valid_per_view == (c.num_valid,) and r.num_inliers_per_view == (c.num_inliers,)
    assert r.disagreeing == ()


def _assert_same_fused(a, b):
    assert [x.pose.stamp_ns for x in a] == [x.pose.stamp_ns for x in b]
    for x, y in zip(a, b, strict=True):
        _assert_same_pose(x.pose, y.pose)
        assert _same(x.pose_covariance, y.pose_covariance)
        assert _same(x.twist_covariance, y.twist_covariance)
        assert (x.own_twist, x.implausible) == (y.own_twist, y.implausible)


def _compare(video, tracking, imu=None, frames=None, configure=None):
    """Both localizers through the video (``configure``: (frame index, options) given to both
    from that frame on); returns the paths."""
    all_frames, cam, samples = video
    frames = all_frames if frames is None else frames
    seq = SequenceLocalizer(
        SequenceSettings(options=OPTS, tracking=tracking, imu=imu), imu_span=np.inf
    )
    rig = Localizer(LocalizerSettings({"cam": IDENTITY}, options=OPTS, tracking=tracking, imu=imu))
    assert rig.settings.single_camera
    if imu is not None:
        for t, w in samples:
            seq.add_imu(t, w)
            rig.add_imu(t, w)
    paths = []
    for k, f in enumerate(frames):
        if configure is not None and k == configure[0]:
            seq.configure(dataclasses.replace(seq.settings, options=configure[1]))
            rig.configure(dataclasses.replace(rig.settings, options=configure[1]))
        a = seq.process(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz, f.scores))
        (b,) = rig.add(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz, f.scores, camera_name="cam"))
        assert (a.stamp_ns, a.path) == (b.stamp_ns, b.path)
        assert (a.gyro is None) == (b.gyro is None)
        if a.gyro is not None:
            assert _same(a.gyro.angular_velocity, b.gyro.angular_velocity)
        _assert_same_estimate(a.estimate, b.estimate, cam.seconds_per_unit_r)
        _assert_same_fused(a.fused, b.fused)
        paths.append(a.path)
    _assert_same_fused(seq.flush(), rig.flush())
    return paths, seq, rig


def test_a_rig_of_one_camera_solves_its_frames_as_the_camera(video):
    """Tracked (cold, then tracked), the frames alone (tracking None), and tracked with the
    prediction's twist as the motion prior on every frame: the same estimates, paths and fused
    twists, bit for bit; the rig's own bookkeeping of its one camera (its share, no refusal,
    no disagreement) changes nothing."""
    paths, _, rig = _compare(video, TrackerOptions())
    assert paths[0] == "cold" and paths.count("tracked") >= FRAMES - 2
    assert rig.counts["rig.solved"] == FRAMES and rig.counts["cam.solved"] == FRAMES
    assert rig.camera_state("cam") == "running" and rig.last_share("cam").share == 1.0
    paths, _, _ = _compare(video, None)
    assert paths == [None] * FRAMES
    _compare(video, TrackerOptions(prior_from_prediction="always"))


def test_a_rig_of_one_relocalizes_resets_and_is_configured_as_the_camera(video):
    """A prediction that never explains enough (a 0.5 px gate): every frame relocalized, also
    solved again without the prediction's prior; a teleport (8 m, 40 deg) that the track
    contradicts is relocalized and posed, not refused (no other camera to confirm it); a gap
    of 12 frames (0.4 s, over a max_gap of 0.3 s) resets the track; new estimator options
    mid-video start a new track on both."""
    strict = TrackerOptions(gate_px=0.5, gate_sigmas=0.0, min_explained_ratio=1.0,
                            prior_from_prediction="always")  # fmt: skip
    paths, _, _ = _compare(video, strict)
    assert paths[1:] == ["relocalized"] * (FRAMES - 1)
    jump = Teleport(Trajectory(), time=0.3)
    config = SequenceConfig(num_frames=16, num_points=200, seed=5, num_landmarks=3000)
    jumped, _, _, _ = generate_sequence(config, trajectory=jump)
    paths, _, rig = _compare(video, TrackerOptions(), frames=jumped)
    k = paths.index("relocalized")
    assert 8 <= k <= 10 and paths[k + 1 :] == ["tracked"] * (15 - k)
    assert rig.counts["rig.solved"] == 16 and not any("rig.failed" in c for c in rig.counts)
    frames = [f for k, f in enumerate(video[0]) if not 6 <= k < 18]
    paths, _, _ = _compare(video, TrackerOptions(max_gap=0.3), frames=frames)
    assert paths[6] == "reset"
    other = EstimateOptions(ransac=RansacOptions(threshold_px=1.5))
    paths, _, _ = _compare(video, TrackerOptions(), configure=(10, other))
    assert paths[10] == "cold" and paths[11] == "tracked"


def test_a_rig_of_one_with_a_gyro_is_the_camera_with_it(video):
    """The gyro's measurement over the camera's readout, its bias estimated online: the same
    measurement and estimates as the camera's, tracked and not."""
    imu = GyroSettings(R_cam_imu=R_IMU_CAMERA.T, gyro_noise=0.003, gyro_bias_sigma=0.03,
                       estimate_bias=True, buffer=10.0)  # fmt: skip
    _, seq, rig = _compare(video, TrackerOptions(), imu)
    assert seq.counts["frames_with_gyro"] == FRAMES
    assert rig.gyro_counts()["frames_with_gyro"] == FRAMES
    _compare(video, None, imu)


def test_which_rigs_are_one_camera_and_a_rig_of_two_keeps_the_rig_estimator(video):
    """Only one camera at the identity mounting without a covariance is solved as the camera;
    its estimate is in the rig's terms (the camera's part of it is the camera's model). A rig
    of two cameras, even at the identity, runs the rig estimator."""
    frames, cam, _ = video
    turned = Mounting.from_pose(np.diag([1.0, -1.0, -1.0]), np.zeros(3))
    assert LocalizerSettings({"cam": IDENTITY}).single_camera
    assert not LocalizerSettings(
        {"cam": Mounting(np.eye(3), np.zeros(3), np.eye(6) * 1e-6)}
    ).single_camera
    assert not LocalizerSettings({"cam": turned}).single_camera
    assert not LocalizerSettings({"cam": Mounting(np.eye(3), np.array([0.1, 0, 0]))}).single_camera
    assert not LocalizerSettings({"a": IDENTITY, "b": IDENTITY}).single_camera
    one = Localizer(LocalizerSettings({"cam": IDENTITY}, options=OPTS))
    two = Localizer(LocalizerSettings({"a": IDENTITY, "b": IDENTITY}, options=OPTS))
    f = frames[0]
    (out,) = one.add(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz, camera_name="cam"))
    assert out.success and out.estimate.solver == "r6p_1lin"
    part = camera_estimate(out.estimate, 0, cam, IDENTITY, 0.0, f.uv)
    np.testing.assert_array_equal(part.model.R, out.estimate.model.R)
    np.testing.assert_allclose(
        part.model.w, out.estimate.model.w * cam.seconds_per_unit_r, rtol=1e-15, atol=0
    )
    assert not two.add(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz, camera_name="a"))
    (out2,) = two.add(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz, camera_name="b"))
    assert out2.success and out2.estimate.solver == "gr6p_1lin"


@pytest.mark.parametrize("tracking", [TrackerOptions(), None])
def test_a_rig_of_one_on_images_is_the_camera_on_them(tracking):
    """Rendered images of the marker room through a windowed ArUco front end each: the same
    prediction handed to the front end (the tracker's, or the last posed frame carried without
    tracking), the same rows found, estimates and fused twists, bit for bit."""
    from rs_localizer.frontends import make_frontend
    from rs_localizer.sim.render import render_rig_frames, vga_rig

    (c,) = vga_rig(1)
    frames, _ = render_rig_frames([c], 8, seed=3)

    def aruco():
        return make_frontend("aruco", "aruco_room", windowed=True, window_max_share=1.0)

    seq = SequenceLocalizer(SequenceSettings(options=OPTS, tracking=tracking), frontend=aruco())
    rig = Localizer(LocalizerSettings({c.name: IDENTITY}, options=OPTS, tracking=tracking))
    rig.set_frontend(c.name, aruco())
    spr = c.camera.seconds_per_unit_r
    predicted = 0
    for f in frames:
        p, q = seq.predict(f.stamp_ns, c.camera), rig.predict_camera(c.name, f.stamp_ns, c.camera)
        assert (p is None) == (q is None)
        if p is not None:
            predicted += 1
            assert all(_same(x, y) for x, y in zip(p, q, strict=True))
        a = seq.process_image(f.stamp_ns, f.image, c.camera, "rgb8")
        (b,) = rig.process_image(c.name, f.stamp_ns, f.image, c.camera, "rgb8")
        assert _same(a.points2d, b.frames[c.name].points2d) and a.path == b.path
        _assert_same_estimate(a.estimate, b.estimate, spr)
        assert a.estimate.success
        _assert_same_fused(a.fused, b.fused)
    assert predicted == len(frames) - 1
    _assert_same_fused(seq.flush(), rig.flush())


# ---------------------------------------------------------------------- the camera's policies
def _pair(**kw):
    """A camera's localizer and a rig of one (not its adapter: a Localizer of its own) with
    the same settings ``kw``."""
    seq = SequenceLocalizer(SequenceSettings(options=OPTS, **kw))
    rig = Localizer(LocalizerSettings({"cam": IDENTITY}, options=OPTS, **kw))
    return seq, rig


def _step(seq, rig, f, cam, stamp_ns=None):
    """One frame through both; asserts the same outcome, returns the camera's output."""
    t = f.stamp_ns if stamp_ns is None else stamp_ns
    a = seq.process(CameraFrame(t, cam, f.uv, f.xyz, f.scores))
    (b,) = rig.add(CameraFrame(t, cam, f.uv, f.xyz, f.scores, camera_name="cam"))
    assert (a.stamp_ns, a.path, a.twist_now) == (b.stamp_ns, b.path, b.twist_now)
    assert a.estimate is not None and b.camera_estimate is not None
    _assert_same_estimate(a.estimate, b.estimate, cam.seconds_per_unit_r)
    c = b.camera_estimate  # (the camera's own: its model per unit RS coordinate)
    assert all(_same(x, y) for x, y in zip(a.estimate.model, c.model, strict=True))
    assert _same(a.estimate.inliers, c.inliers) and a.estimate.failure == c.failure
    _assert_same_fused(a.fused, b.fused)
    assert seq.pending == rig.pending
    return a


def test_a_rig_of_one_takes_the_camera_s_solver_and_its_global_shutter_twists(video):
    """``LocalizerSettings.solver``: a rig of one solved with the global-shutter P3P as the camera
    is: the same estimates, each frame's own twist final at once (``twist_now``, nothing
    held); a camera without readout time (line delay 0) likewise on the default solver."""
    frames, cam, _ = video
    seq, rig = _pair(solver="p3p", tracking=TrackerOptions())
    for f in frames[:8]:
        a = _step(seq, rig, f, cam)
        assert a.twist_now and a.estimate.solver == "p3p" and rig.pending == 0
    gs = dataclasses.replace(cam, line_delay=0.0)
    seq, rig = _pair(tracking=TrackerOptions())
    for f in frames[:8]:
        a = _step(seq, rig, f, gs)
        assert a.twist_now and rig.pending == 0
    assert seq.tracking_values() == rig.tracking_values()


def test_a_rig_of_one_starts_a_track_for_a_new_camera_model_and_takes_frames_going_back(video):
    """A new camera model object ends the track (its twists out, counted a reset), as the
    camera's; a frame older than the previous one is no ``out_of_order`` skip: a time reset
    whose frame starts a new track (``reset``), and a stamp jump ahead likewise (over
    ``max_gap``); ``check_time`` names the same resets."""
    frames, cam, _ = video
    seq, rig = _pair(tracking=TrackerOptions())
    for f in frames[:6]:
        _step(seq, rig, f, cam)
    other = dataclasses.replace(cam)
    assert _step(seq, rig, frames[6], other).path == "cold"
    assert seq.tracking_values() == rig.tracking_values()
    assert rig.tracking_values()["resets"] == 1
    _step(seq, rig, frames[7], other)
    a = _step(seq, rig, frames[2], other)  # (going back)
    assert a.path == "reset" and a.estimate.success
    assert rig.counts["rig.time_resets"] == 1 and rig.counts["cam.skipped"] == 0
    t = frames[3].stamp_ns + 3 * 10**9
    assert seq.check_time(t) == rig.check_time(t) is not None
    assert _step(seq, rig, frames[3], other, t).path == "reset"
    assert rig.counts["rig.time_resets"] == 2 and rig.counts["cam.solved"] == 10
    assert seq.tracking_values() == rig.tracking_values()
    _assert_same_fused(seq.flush(), rig.flush())


def test_a_rig_of_one_configured_and_reset_as_the_camera(video):
    """Other tracking options at run time end the track at the next frame (the twists still
    pending go out with it); tracking switched off drops them; ``reset`` drops them too and
    forgets the last pose: the same outputs, counters and predictions as the camera's."""
    frames, cam, _ = video
    seq, rig = _pair(tracking=TrackerOptions())
    for f in frames[:5]:
        _step(seq, rig, f, cam)
    other = TrackerOptions(gate_px=25.0)
    seq.configure(dataclasses.replace(seq.settings, tracking=other))
    rig.configure(dataclasses.replace(rig.settings, tracking=other))
    assert seq.pending == rig.pending > 0  # (until the next frame)
    a = _step(seq, rig, frames[5], cam)
    assert a.path == "cold" and a.fused
    _step(seq, rig, frames[6], cam)
    seq.configure(dataclasses.replace(seq.settings, tracking=None))
    rig.configure(dataclasses.replace(rig.settings, tracking=None))
    a = _step(seq, rig, frames[7], cam)
    assert a.fused == [] and rig.pending == 0 and a.twist_now
    assert rig.tracking_values() == seq.tracking_values()
    assert rig.tracking_values()["track_state"] == "disabled"
    p, q = seq.predict(frames[8].stamp_ns, cam), rig.predict_camera("cam", frames[8].stamp_ns, cam)
    assert p is not None and all(_same(x, y) for x, y in zip(p, q, strict=True))
    seq.configure(dataclasses.replace(seq.settings, tracking=TrackerOptions()))
    rig.configure(dataclasses.replace(rig.settings, tracking=TrackerOptions()))
    for f in frames[8:12]:
        _step(seq, rig, f, cam)
    assert rig.pending > 0
    seq.reset()
    assert rig.reset() == [] and rig.pending == 0
    assert seq.predict(frames[12].stamp_ns, cam) is None
    assert rig.predict_camera("cam", frames[12].stamp_ns, cam) is None
    assert _step(seq, rig, frames[12], cam).path == "cold"
    assert seq.tracking_values() == rig.tracking_values()


def test_a_rig_of_one_s_frozen_image_starts_a_new_track(video):
    """The camera's image again (a frozen stream): the next new image is searched whole (no
    prediction) and starts a new track, as the camera's (``restart_track``); counted a
    reset."""
    from rs_localizer.frontends import make_frontend
    from rs_localizer.sim.render import render_rig_frames, vga_rig

    (c,) = vga_rig(1)
    frames, _ = render_rig_frames([c], 6, seed=3)

    def aruco():
        return make_frontend("aruco", "aruco_room", windowed=True, window_max_share=1.0)

    seq = SequenceLocalizer(SequenceSettings(options=OPTS), frontend=aruco())
    rig = Localizer(LocalizerSettings({c.name: IDENTITY}, options=OPTS))
    rig.set_frontend(c.name, aruco())
    paths = []
    for k, f in enumerate(frames):
        stamp = f.stamp_ns
        image = frames[2].image if k == 3 else f.image  # (frame 3: frame 2's image again)
        a = seq.process_image(stamp, image, c.camera, "rgb8")
        outs = rig.process_image(c.name, stamp, image, c.camera, "rgb8")
        if k == 3:
            assert a.failure == "frozen_image" and outs == []
            assert seq.predict(frames[4].stamp_ns, c.camera) is None
            assert rig.predict_camera(c.name, frames[4].stamp_ns, c.camera) is None
            continue
        (b,) = outs
        paths.append(a.path)
        assert a.path == b.path
        _assert_same_estimate(a.estimate, b.estimate, c.camera.seconds_per_unit_r)
        _assert_same_fused(a.fused, b.fused)
    assert paths == ["cold", "tracked", "tracked", "cold", "tracked"]
    assert seq.tracking_values() == rig.tracking_values()
    assert rig.tracking_values()["resets"] == 1


def test_a_frame_whose_estimator_raises_after_restart_track_ends_the_track_once(video, monkeypatch):
    """After :meth:`Localizer.restart_track` a camera's video ends its track at the next frame
    (one reset); when that frame's estimator raises (the frame failed, ``error`` set), the frame
    after it continues from there: still one reset, its path cold, as a camera's after one new
    track."""
    from rs_localizer.tracking import tracker

    frames, cam, _ = video
    rig = Localizer(LocalizerSettings({"": IDENTITY}, options=OPTS, tracking=TrackerOptions()))
    for f in frames[:3]:
        (o,) = rig.add(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz, f.scores))
        assert o.error is None
    assert rig.tracking_values()["resets"] == 0
    rig.restart_track()

    def raising(self, *a, **k):
        raise RuntimeError("estimator failed")

    monkeypatch.setattr(tracker.RSTracker, "track", raising)
    f = frames[3]
    (o,) = rig.add(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz, f.scores))
    assert o.error == "RuntimeError: estimator failed" and o.estimate is None
    assert rig.tracking_values()["resets"] == 1
    monkeypatch.undo()
    f = frames[4]
    (o,) = rig.add(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz, f.scores))
    assert o.error is None and o.estimate is not None and o.path == "cold"
    assert rig.tracking_values()["resets"] == 1


def test_a_rig_of_one_without_tracking_carries_its_last_pose_through_add(video):
    """Without tracking the last posed frame, carried at its own twist, predicts the next
    frame of :meth:`Localizer.add` as of :meth:`Localizer.process_image`, as the
    camera's."""
    frames, cam, _ = video
    seq, rig = _pair(tracking=None)
    for f in frames[:3]:
        _step(seq, rig, f, cam)
    t = frames[3].stamp_ns
    p, q = seq.predict(t, cam), rig.predict_camera("cam", t, cam)
    assert p is not None and all(_same(x, y) for x, y in zip(p, q, strict=True))


def test_only_a_rig_of_one_is_a_camera_s_video():
    """A camera's video is a rig of one camera named "" at the identity mounting
    (``LocalizerSettings.camera_video``); ``check_time`` notes a rig camera's stamp ahead of
    its frame as a camera's, by the camera's name (a rig's step back within ``time_reset_ns``
    is no reset, one beyond it and a jump ahead are, as the frames' own would be)."""
    assert LocalizerSettings({"": IDENTITY}).camera_video
    assert not LocalizerSettings({"cam": IDENTITY}).camera_video
    assert not LocalizerSettings({"": Mounting(np.eye(3), np.array([0.1, 0, 0]))}).camera_video
    rig = Localizer(LocalizerSettings({"a": IDENTITY, "b": IDENTITY}, time_reset_ns=10**9))
    with pytest.raises(ValueError, match="names the camera"):
        rig.check_time(0)
    with pytest.raises(ValueError, match="not in the rig"):
        rig.check_time(0, "c")
    t = 5 * 10**9
    assert rig.check_time(t, "a") is None and rig.check_time(t + 10**7, "b") is None
    assert rig.check_time(t - 10**8, "a") is None  # (within time_reset_ns: out of order)
    assert "older than the previous frame" in rig.check_time(t - 2 * 10**9, "b")
    assert "since the previous frame" in rig.check_time(t + 10**9, "a")
    assert rig.counts["rig.time_resets"] == 2 and rig.counts["a.stamp_jumped_ahead"] == 1


def test_a_rig_of_one_drops_an_image_with_too_few_correspondences_as_the_camera(video):
    """An image whose front end finds fewer correspondences than the solver needs is dropped
    before the estimator, as the camera's (``frontend_too_few_points``, counted skipped; the
    front end not told), and the video goes on as the camera's."""
    from rs_localizer.correspondences import Correspondences

    frames, cam, _ = video
    rng = np.random.default_rng(1)
    images = [rng.integers(0, 255, (48, 64), np.uint8) for _ in range(8)]

    class Rows:  # (each frame's own rows, frame 3 with 5 of them)
        def __init__(self):
            self.k, self.told = 0, []

        def process(self, image, camera, encoding="bgr8", prediction=None):
            f = frames[self.k]
            n = 5 if self.k == 3 else len(f.uv)
            return Correspondences(f.uv[:n], f.xyz[:n])

        def observe(self, stamp_ns, points2d, feedback):
            self.told.append(stamp_ns)

    a, b = Rows(), Rows()
    seq = SequenceLocalizer(SequenceSettings(options=OPTS), frontend=a)
    rig = Localizer(LocalizerSettings({"cam": IDENTITY}, options=OPTS))
    rig.set_frontend("cam", b)
    for k in range(8):
        a.k = b.k = k
        out = seq.process_image(frames[k].stamp_ns, images[k], cam, "mono8")
        outs = rig.process_image("cam", frames[k].stamp_ns, images[k], cam, "mono8")
        if k == 3:
            assert out.failure == "frontend_too_few_points" and outs == []
            continue
        (r,) = outs
        assert out.path == r.path
        _assert_same_estimate(out.estimate, r.estimate, cam.seconds_per_unit_r)
        _assert_same_fused(out.fused, r.fused)
    assert rig.counts["cam.skipped.frontend_too_few_points"] == 1
    assert a.told == b.told and frames[3].stamp_ns not in a.told


def test_a_rig_s_frozen_image_level_is_the_camera_s(video):
    """``LocalizerSettings.frozen_image_level`` (a camera's ``frozen_image_level``): the same image
    twice is skipped as ``frozen_image`` at the default level, taken with a negative one."""
    from rs_localizer.correspondences import Correspondences

    frames, cam, _ = video
    image = np.random.default_rng(2).integers(0, 255, (48, 64), np.uint8)

    class Rows:
        k = 0

        def process(self, image, camera, encoding="bgr8", prediction=None):
            return Correspondences(frames[self.k].uv, frames[self.k].xyz)

    for level, taken in ((SequenceSettings.frozen_image_level, 1), (-1.0, 2)):
        fe = Rows()
        rig = Localizer(
            LocalizerSettings({"cam": IDENTITY}, options=OPTS, frozen_image_level=level)
        )
        rig.set_frontend("cam", fe)
        outs = []
        for k in range(2):
            fe.k = k
            outs += rig.process_image("cam", frames[k].stamp_ns, image, cam, "mono8")
        assert len(outs) == taken
        assert rig.counts["cam.skipped.frozen_image"] == 2 - taken


def test_a_rig_of_one_worded_for_its_camera_leaves_a_time_reset_to_its_caller(video):
    """A frame going back (a time reset): a rig of one warns ``rig time reset: ...`` once;
    its camera named "" (its camera's video, worded for it) it warns nothing (its caller
    reports it), and both pose every frame the same."""
    from helpers.rig import Log

    frames, cam, _ = video
    order = [*frames[:6], frames[2], frames[3]]  # (back to the 3rd frame's stamp)
    logs, posed = [], []
    for name in ("cam", ""):
        log = Log()
        rig = Localizer(LocalizerSettings({name: IDENTITY}, options=OPTS), log)
        outs = [rig.add(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz, f.scores, camera_name=name))
                for f in order]  # fmt: skip
        assert rig.counts["rig.time_resets"] == 1
        logs.append([t for k, t in log.warnings if "time_reset" in k])
        posed.append([o.estimate.pose.position for (o,) in outs])
    assert len(logs[0]) == 1 and logs[0][0].startswith("rig time reset: ") and logs[1] == []
    assert all(_same(a, b) for a, b in zip(*posed, strict=True))
