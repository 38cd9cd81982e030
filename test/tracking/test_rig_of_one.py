"""A camera alone is a rig of one: a RigLocalizer of one camera at the identity mounting
(RigSettings.single_camera) given the camera's options solves every frame as the camera's own
SequenceLocalizer does, bit for bit: each estimate (pose, twist, model, inliers, failure,
covariances), its path and every fused twist, with tracking (the prediction's motion prior
too), without, across a new configuration, with a gyro, and on rendered images through a front
end (the same prediction searched with). A rig of two cameras keeps the rig estimator."""

import dataclasses

import numpy as np
import pytest

from rs_localizer.estimation.estimate import EstimateOptions, RansacOptions
from rs_localizer.estimation.rig import camera_estimate
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
from rs_localizer.tracking.rig import RigLocalizer, RigSettings
from rs_localizer.tracking.sequence import SequenceLocalizer, SequenceSettings
from rs_localizer.tracking.tracker import TrackerOptions

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
        assert _same(c.model.w / spr, r.model.w) and _same(c.model.t / spr, r.model.t)
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
    rig = RigLocalizer(RigSettings({"cam": IDENTITY}, options=OPTS, tracking=tracking, imu=imu))
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
    assert RigSettings({"cam": IDENTITY}).single_camera
    assert not RigSettings(
        {"cam": Mounting(np.eye(3), np.zeros(3), np.eye(6) * 1e-6)}
    ).single_camera
    assert not RigSettings({"cam": turned}).single_camera
    assert not RigSettings({"cam": Mounting(np.eye(3), np.array([0.1, 0, 0]))}).single_camera
    assert not RigSettings({"a": IDENTITY, "b": IDENTITY}).single_camera
    one = RigLocalizer(RigSettings({"cam": IDENTITY}, options=OPTS))
    two = RigLocalizer(RigSettings({"a": IDENTITY, "b": IDENTITY}, options=OPTS))
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
    from rs_localizer.sim.render.rig import render_rig_frames, vga_rig

    (c,) = vga_rig(1)
    frames, _ = render_rig_frames([c], 8, seed=3)

    def aruco():
        return make_frontend("aruco", "aruco_room", windowed=True, window_max_share=1.0)

    seq = SequenceLocalizer(SequenceSettings(options=OPTS, tracking=tracking), frontend=aruco())
    rig = RigLocalizer(RigSettings({c.name: IDENTITY}, options=OPTS, tracking=tracking))
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
