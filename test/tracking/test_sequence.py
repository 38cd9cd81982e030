"""The library's video entry point (rs_localizer.tracking.sequence.SequenceLocalizer) and the
typed domain objects (rs_localizer.pose, rs_localizer.correspondences): a synthetic video
against its ground truth and against the tracker driven directly, the gyro's timeline across a
time reset, and the pose conversions against the estimator's own."""

from typing import ClassVar

import numpy as np
import pytest

from rs_localizer.correspondences import (
    Correspondences,
    FrameFeedback,
    Frontend,
    TrackingFrontend,
)
from rs_localizer.estimation.estimate import EstimateOptions, InitialModel, RansacOptions
from rs_localizer.estimation.result import physical_velocities
from rs_localizer.frames import Mounting, camera_to_base
from rs_localizer.geometry import rotation_angle_deg, rotvec_to_matrix
from rs_localizer.pose import PoseWithCovariance, RSModel, RSPose
from rs_localizer.sim.trajectory import SequenceConfig, generate_sequence, make_trajectory
from rs_localizer.tracking.localizer import CameraFrame
from rs_localizer.tracking.sequence import GyroSettings, SequenceLocalizer, SequenceSettings
from rs_localizer.tracking.tracker import RSTracker, model_from_state

OPTS = EstimateOptions(ransac=RansacOptions(seed=0))


@pytest.fixture(scope="module")
def video():
    frames, _, cam, _ = generate_sequence(
        SequenceConfig(num_frames=12, seed=3), trajectory=make_trajectory("walk")
    )
    return frames, cam


def test_sequence_tracks_a_video_as_the_tracker_does(video):
    frames, cam = video
    seq = SequenceLocalizer(SequenceSettings(options=OPTS, stamp_row=0.0))
    tracker = RSTracker(options=OPTS)
    fused, direct = [], []
    for f in frames:
        out = seq.process(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz, tag=f.index))
        assert out.stamp_ns == f.t_ref_ns  # (the reference line's time, from the header stamp)
        r = tracker.process(f.t_ref_ns, f.uv, f.xyz, cam)
        direct += r.final
        e = out.estimate
        assert e.success and not out.twist_now
        assert rotation_angle_deg(e.pose.orientation, f.orientation) < 0.2
        assert np.linalg.norm(e.pose.position - f.position) < 0.05
        np.testing.assert_array_equal(e.pose.orientation, r.estimate.pose.orientation)
        fused += out.fused
    fused += seq.flush()
    direct += tracker.flush()
    # every frame's fused twist comes out once, in order, with the frame's own pose and tag
    assert [x.pose.stamp_ns for x in fused] == [f.t_ref_ns for f in frames]
    assert [x.tag for x in fused] == [f.index for f in frames]
    truth = {f.t_ref_ns: f for f in frames}
    for x, d in zip(fused, direct, strict=True):
        np.testing.assert_array_equal(x.pose.angular_velocity, d.pose.angular_velocity)
        assert (
            np.linalg.norm(x.pose.angular_velocity - truth[x.pose.stamp_ns].angular_velocity) < 0.3
        )
    assert seq.tracking_values()["frames_tracked"] == len(frames) - 1
    assert seq.pending == 0


def test_without_tracking_each_frame_is_final(video):
    frames, cam = video
    seq = SequenceLocalizer(SequenceSettings(options=OPTS, tracking=None))
    out = seq.process(CameraFrame(frames[0].stamp_ns, cam, frames[0].uv, frames[0].xyz))
    assert out.estimate.success and out.twist_now and out.fused == [] and out.path is None
    assert seq.tracking_values()["track_state"] == "disabled"


def test_a_switch_to_a_global_shutter_solver_releases_the_pending_twists(video):
    # the frames of a rolling-shutter track waiting for their fused twist go out with the
    # first frame of the new configuration, also when its own twist is final at once (a
    # global-shutter solver: nothing fused from then on)
    frames, cam = video
    seq = SequenceLocalizer(SequenceSettings(options=OPTS))
    fused = []
    for f in frames[:5]:
        fused += seq.process(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz, tag=f.index)).fused
    assert seq.pending > 0
    seq.configure(SequenceSettings(solver="p3p", options=OPTS))
    f = frames[5]
    out = seq.process(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz, tag=f.index))
    assert out.estimate.success and out.twist_now
    fused += out.fused
    assert [x.tag for x in fused] == [g.index for g in frames[:5]]
    assert seq.pending == 0
    for x in fused:  # (their fused twists, near the truth)
        truth = frames[x.tag]
        assert np.linalg.norm(x.pose.angular_velocity - truth.angular_velocity) < 0.3


def test_a_time_reset_starts_the_gyro_timeline_again(video):
    frames, _ = video
    seq = SequenceLocalizer(
        SequenceSettings(options=OPTS, imu=GyroSettings(estimate_bias=True)), imu_span=np.inf
    )
    t0 = frames[0].stamp_ns
    for k in range(40):
        assert seq.add_imu(t0 + k * 5_000_000, (0.0, 0.0, 0.0)) is None
    assert seq.check_time(t0) is None
    assert seq.check_time(t0) is None  # (the same stamp again: no reset)
    assert len(seq.imu) == 40
    # a stamp going back: the old timeline's samples are gone, the new timeline's accepted
    why = seq.check_time(t0 - 10**9)
    assert why is not None and "older" in why
    assert len(seq.imu) == 0
    assert seq.add_imu(t0 - 10**9, (0.0, 0.0, 0.0)) is None
    # a jump forward: the samples from the previous frame on are kept
    assert seq.add_imu(t0 - 10**9 + 5_000_000, (0.0, 0.0, 0.0)) is None
    assert seq.check_time(t0 - 10**9 + 5_000_000) is None
    why = seq.check_time(t0 + 10**10)
    assert why is not None and "time_reset_threshold" in why
    assert len(seq.imu) == 1


def test_reset_forgets_the_video(video):
    frames, cam = video
    seq = SequenceLocalizer(SequenceSettings(options=OPTS, imu=GyroSettings()))
    seq.add_imu(frames[0].stamp_ns, (0.0, 0.0, 0.0))
    for f in frames[:3]:
        seq.process(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz))
    assert seq.pending > 0
    seq.reset()
    assert seq.pending == 0 and len(seq.imu) == 0 and seq.flush() == []
    # (after a reset an older stamp is no time reset: the timeline was forgotten)
    assert seq.check_time(frames[0].stamp_ns) is None


def test_rs_pose_conversions_match_the_estimator():
    rng = np.random.default_rng(0)
    R = rotvec_to_matrix(rng.normal(size=3))
    model = RSModel(R, rng.normal(size=3), 0.01 * rng.normal(size=3), 0.02 * rng.normal(size=3))
    s = 2.1e-2
    pose = RSPose.from_model(model, s, stamp_ns=7)
    om, v, om_w, v_w = physical_velocities(*model, s)
    np.testing.assert_allclose(pose.orientation, R.T, atol=1e-15)
    np.testing.assert_allclose(pose.position, -R.T @ model.C, atol=1e-14)
    np.testing.assert_allclose(pose.angular_velocity, om, rtol=1e-12)
    np.testing.assert_allclose(pose.linear_velocity, v, rtol=1e-12)
    np.testing.assert_allclose(pose.angular_velocity_world, om_w, rtol=1e-12)
    np.testing.assert_allclose(pose.linear_velocity_world, v_w, rtol=1e-12)
    back = pose.model(s)
    for a, b in zip(back, model, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15)
    gs = RSPose.from_model(model, 0.0)
    assert not gs.angular_velocity.any() and not gs.linear_velocity.any()
    with pytest.raises(ValueError):
        RSPose.from_model(model, -1.0)
    R_, C_, w_, t_ = model  # (unpacks as the bare tuple the kernels take)
    assert R_ is model.R and C_ is model.C and w_ is model.w and t_ is model.t


def test_estimate_pose_and_model_views(video):
    frames, cam = video
    f = frames[0]
    seq = SequenceLocalizer(SequenceSettings(options=OPTS, tracking=None))
    e = seq.process(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz)).estimate
    p = RSPose.from_model(e.model, cam.seconds_per_unit_r)
    np.testing.assert_allclose(p.orientation, e.pose.orientation, atol=1e-12)
    np.testing.assert_allclose(p.position, e.pose.position, atol=1e-9)
    np.testing.assert_allclose(p.angular_velocity, e.pose.angular_velocity, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(p.linear_velocity, e.pose.linear_velocity, rtol=1e-9, atol=1e-12)


def test_estimates_and_states_store_their_pose_and_model(video):
    """The estimate, the fused states and frames, a base state and an initial model hold an
    RSPose / RSModel; the estimate, the fused frame and the base state are a
    PoseWithCovariance (the type the message conversions take)."""
    frames, cam = video
    s = cam.seconds_per_unit_r
    seq = SequenceLocalizer(SequenceSettings(options=OPTS))
    estimates, fused = {}, []
    for f in frames[:4]:
        out = seq.process(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz))
        estimates[out.stamp_ns] = e = out.estimate
        assert isinstance(e.pose, RSPose) and isinstance(e.model, RSModel)
        assert isinstance(e, PoseWithCovariance) and e.pose.stamp_ns is None
        np.testing.assert_array_equal(e.pose.orientation, e.model.R.T)
        np.testing.assert_allclose(
            e.pose.linear_velocity_world, e.pose.orientation @ e.pose.linear_velocity
        )
        fused += out.fused
    fused += seq.flush()
    assert len(fused) == 4
    ext = Mounting.from_pose(np.eye(3), np.array([0.1, 0.0, 0.2]))
    for x in fused:
        e, st = estimates[x.pose.stamp_ns], x.state
        # the frame's own pose as estimated, with the fused twist, at the frame's time
        assert isinstance(x, PoseWithCovariance) and x.pose.stamp_ns == st.pose.stamp_ns
        assert x.pose.orientation is e.pose.orientation and x.pose.position is e.pose.position
        assert x.pose.angular_velocity is st.pose.angular_velocity
        assert x.pose.linear_velocity is st.pose.linear_velocity
        base = camera_to_base(x, ext)
        assert isinstance(base, PoseWithCovariance) and base.pose.stamp_ns == x.pose.stamp_ns
        # the tracker's prediction model is the state's pose as a model, and back
        model = model_from_state(st, cam)
        for a, b in zip(model, st.pose.model(s), strict=True):
            np.testing.assert_array_equal(a, b)
        back = RSPose.from_model(model, s)
        np.testing.assert_allclose(back.position, st.pose.position, atol=1e-12)
        np.testing.assert_allclose(back.linear_velocity, st.pose.linear_velocity, atol=1e-9)
    init = InitialModel(tuple(estimates[fused[0].pose.stamp_ns].model), gate_px=5.0)
    assert isinstance(init.model, RSModel)
    np.testing.assert_array_equal(init.model.C, estimates[fused[0].pose.stamp_ns].model.C)
    gs = fused[0].pose.model(0.0)  # a global shutter: exact zeros, no -0.0
    assert not np.signbit(gs.w).any() and not gs.w.any() and not gs.t.any()


def test_correspondences_type():
    uv, xyz, ids = np.zeros((3, 2)), np.ones((3, 3)), np.arange(3)
    c = Correspondences(uv, xyz, ids, np.array([0.5, 0.2]))
    a, b, i = c  # (unpacks as the front ends' former 3-tuple)
    assert a is uv and b is xyz and i is ids and len(c) == 3
    assert c.valid_scores() is None  # (not one per row)
    assert Correspondences.of((uv, xyz, ids)).scores is None
    assert len(Correspondences.empty()) == 0

    class Markers:
        def process(self, image, camera=None, encoding="bgr8"):
            return c

    class Tracks(Markers):
        def observe(self, stamp_ns, points2d, feedback):
            pass

    assert isinstance(Markers(), Frontend) and not isinstance(Markers(), TrackingFrontend)
    assert isinstance(Tracks(), TrackingFrontend)


def test_rotation_log_inverts_the_exponential():
    from rs_localizer._so3 import rotation_log_into

    rng = np.random.default_rng(1)
    v = np.empty(3)
    for angle in (0.0, 1e-9, 1e-7, 1e-3, 1.0, 3.0, np.pi - 1e-5, np.pi):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        rotation_log_into(rotvec_to_matrix(angle * axis), v)
        atol = 1e-9
        if angle >= np.pi - 1e-4:  # (at pi, the axis and its opposite are the same rotation)
            v = v if v @ axis > 0 else -v
            atol = 1e-4  # (the axis from the symmetric part: off by ~ (pi - angle) there)
        np.testing.assert_allclose(v, angle * axis, atol=atol)


def test_a_frame_the_twist_filter_refuses_carries_its_own_twist():
    """On a hand-held shake (the make-bag simulator's ``shake``, seed 3) the fused-twist
    filter's gate refuses two frames of a sharp turn, where its prediction is off by over
    0.7 rad/s: the published twist of those frames is the frame's own (with its covariance),
    counted; every other frame carries the filter's state, and no published angular velocity
    is off by more than the frames' own worst."""
    frames, _, cam, _ = generate_sequence(
        SequenceConfig(num_frames=30, seed=3), trajectory=make_trajectory("shake")
    )
    seq = SequenceLocalizer(SequenceSettings(options=OPTS, stamp_row=0.0))
    fused, own = [], {}
    for f in frames:
        out = seq.process(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz))
        assert out.estimate.success
        own[out.stamp_ns] = out.estimate
        fused += out.fused
    fused += seq.flush()
    truth = {f.t_ref_ns: f.angular_velocity for f in frames}
    assert [x.pose.stamp_ns for x in fused] == [f.t_ref_ns for f in frames]

    def err(w, stamp):
        return float(np.linalg.norm(np.asarray(w) - truth[stamp]))

    refused = [x for x in fused if x.own_twist]
    assert len(refused) >= 1
    assert seq.tracking_values()["twists_own_frame"] == len(refused)
    for x in fused:
        e = own[x.pose.stamp_ns]
        assert x.own_twist == (not x.state.fused)
        if x.own_twist:
            np.testing.assert_array_equal(x.pose.angular_velocity, e.pose.angular_velocity)
            np.testing.assert_array_equal(x.pose.linear_velocity, e.pose.linear_velocity)
            np.testing.assert_array_equal(x.twist_covariance, e.twist_covariance)
        elif not x.own_twist:
            np.testing.assert_array_equal(x.pose.angular_velocity, x.state.pose.angular_velocity)
    # the refused frames are where the prediction went wrong: publishing it would be far off
    assert max(err(x.state.pose.angular_velocity, x.pose.stamp_ns) for x in refused) > 0.5
    worst_own = max(err(e.pose.angular_velocity, s) for s, e in own.items())
    assert max(err(x.pose.angular_velocity, x.pose.stamp_ns) for x in fused) <= worst_own


def test_stamps_beyond_int64_and_a_missing_camera_are_refused(video):
    """A frame stamp up to 2**63 - 1 ns is taken; one beyond (5e19 ns, 2**63) or an IMU stamp
    of 2**70 raises ValueError naming the int64 range, and a frame without a camera model a
    TypeError, before anything is solved or buffered. A frame may be made without a camera
    model (a rig's camera whose camera_info has not arrived); one camera's localizer refuses
    it."""
    frames, cam = video
    f = frames[0]
    assert CameraFrame(2**63 - 1, cam, f.uv, f.xyz).stamp_ns == 2**63 - 1
    for bad in (5e19, 2**63, float("inf"), float("nan")):
        with pytest.raises(ValueError, match="stamp"):
            CameraFrame(bad, cam, f.uv, f.xyz)
    with pytest.raises(TypeError, match="CameraModel"):
        CameraFrame(f.stamp_ns, object(), f.uv, f.xyz)
    seq = SequenceLocalizer(SequenceSettings(options=OPTS, imu=GyroSettings()))
    with pytest.raises(TypeError, match="CameraModel"):
        seq.process(CameraFrame(f.stamp_ns, None, f.uv, f.xyz))
    with pytest.raises(ValueError, match="int64"):
        seq.add_imu(2**70, (0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="int64"):
        seq.check_time(5 * 10**19)
    with pytest.raises(TypeError, match="CameraModel"):
        seq.process_image(f.stamp_ns, np.zeros((4, 4), np.uint8), None)
    assert len(seq.imu) == 0 and seq.counts == {}
    out = seq.process(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz))
    assert out.estimate.success  # (the refused inputs left no trace)


def test_process_image_gives_the_poses_of_its_front_ends_correspondences(video):
    """process_image runs the front end (the stamp passed to a VideoFrontend, not to a
    per-image Frontend), solves its rows as process does, tells the front end the estimate
    and logs its one-time warning; a front end that raises or finds too few points drops the
    frame with the reason."""
    frames, cam = video
    image = np.zeros((cam.height, cam.width), np.uint8)

    class PerImage:  # (the Frontend protocol only)
        def __init__(self):
            self.frame = None

        def process(self, image, camera=None, encoding="bgr8"):
            return Correspondences(self.frame.uv, self.frame.xyz)

    class Video(PerImage):
        seen: ClassVar[list] = []

        def process(self, image, camera=None, encoding="bgr8"):
            assert camera is cam
            return super().process(image, camera, encoding)

        def observe(self, stamp_ns, points2d, feedback):
            assert isinstance(feedback, FrameFeedback)
            assert feedback.inliers.shape == (len(points2d),)
            self.seen.append((stamp_ns, len(points2d), feedback.success))

        def pop_warning(self):
            return "once" if not self.seen else None

    warnings = []

    class Log:
        def info(self, text):
            pass

        def warning(self, key, text, count=0):
            warnings.append((key, text))

    for fe in (PerImage(), Video()):
        seq = SequenceLocalizer(SequenceSettings(options=OPTS), frontend=fe, log=Log())
        ref = SequenceLocalizer(SequenceSettings(options=OPTS))
        for f in frames[:4]:
            fe.frame = f
            out = seq.process_image(f.stamp_ns, image, cam, "mono8")
            want = ref.process(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz)).estimate
            assert out.failure is None and len(out.correspondences) == len(f.uv)
            np.testing.assert_array_equal(out.estimate.pose.orientation, want.pose.orientation)
            np.testing.assert_array_equal(out.estimate.pose.position, want.pose.position)
            assert rotation_angle_deg(out.estimate.pose.orientation, f.orientation) < 0.2
    assert [s[0] for s in Video.seen] == [f.stamp_ns for f in frames[:4]]
    assert all(ok for _, _, ok in Video.seen) and warnings == [("frontend.warning", "once")]
    fe = Video()
    fe.frame = frames[4]
    few = type(frames[4])(**{**vars(frames[4]), "uv": frames[4].uv[:5], "xyz": frames[4].xyz[:5]})
    fe.frame = few
    seq = SequenceLocalizer(SequenceSettings(options=OPTS), frontend=fe, frontend_name="aruco")
    out = seq.process_image(few.stamp_ns, image, cam)
    assert out.failure == "frontend_too_few_points" and out.estimate is None
    assert out.detail == "aruco front end found 1 markers: 5 correspondences, 12 needed"

    class Broken(PerImage):
        def process(self, image, camera=None, encoding="bgr8"):
            raise RuntimeError("no image")

    seq.set_frontend(Broken(), "board")
    out = seq.process_image(few.stamp_ns + 1, image, cam)
    assert out.failure == "frontend_error" and out.detail == "board: RuntimeError: no image"


NS = 1_000_000_000


def _state(w, v, fused=True):
    """A fused state at stamp 1 s with angular velocity w (rad/s), linear v (m/s)."""
    from rs_localizer.tracking.fusion import FusedState

    pose = RSPose(np.eye(3), np.zeros(3), np.asarray(w, float), np.asarray(v, float), NS)
    return FusedState(pose, np.zeros(3), np.zeros(3), np.eye(12), fused=fused)


def test_an_implausible_fused_twist_is_never_handed_out():
    """PendingTwists.release within the plausibility bounds (20 rad/s, 50 m/s): a fused twist
    beyond either is replaced by the frame's own (when plausible, with its covariance) or, for
    a frame without a twist of its own (global shutter) or with an implausible one, not
    released at all; every such frame is counted."""
    from rs_localizer.estimation.result import RSPoseEstimate
    from rs_localizer.tracking.localizer import PendingTwists

    def est(w, v, own=True):
        return RSPoseEstimate(
            success=True,
            pose=RSPose(np.eye(3), np.zeros(3), np.asarray(w, float), np.asarray(v, float)),
            covariance=np.eye(12),
            twist_covariance=np.eye(6) * 0.01 if own else None,
        )

    bounds = (20.0, 50.0)
    cases = [  # (estimate, fused state, released twist (w, v) or None, implausible)
        (est([1, 0, 0], [0, 0, 1]), _state([0, 3, 0], [0, 2, 0]), ([0, 3, 0], [0, 2, 0]), False),
        (est([1, 0, 0], [0, 0, 1]), _state([29, 8, 0], [0, 0, 11]), ([1, 0, 0], [0, 0, 1]), True),
        (est([1, 0, 0], [0, 0, 1]), _state([0, 1, 0], [60, 0, 0]), ([1, 0, 0], [0, 0, 1]), True),
        (
            est([1, 0, 0], [0, 0, 1]),
            _state([np.nan, 0, 0], [0, 0, 0]),
            ([1, 0, 0], [0, 0, 1]),
            True,
        ),
        (est([0, 0, 0], [0, 0, 0], own=False), _state([25, 0, 0], [0, 0, 0]), None, True),
        (est([21, 0, 0], [0, 0, 0]), _state([25, 0, 0], [0, 0, 0]), None, True),
    ]
    for e, f, want, implausible in cases:
        q = PendingTwists()
        q.hold(NS, e, "cam")
        out = q.release([f], bounds)
        assert q.implausible_twists == int(implausible) and len(q) == 0
        if want is None:
            assert out == []
            continue
        (fp,) = out
        np.testing.assert_array_equal(fp.pose.angular_velocity, want[0])
        np.testing.assert_array_equal(fp.pose.linear_velocity, want[1])
        assert fp.implausible == implausible and fp.own_twist == implausible
        assert q.own_twists == int(implausible) and fp.tag == "cam" and fp.state is f
        if implausible:
            np.testing.assert_array_equal(fp.twist_covariance, e.twist_covariance)
    # without bounds (as before) the fused twist is handed out as it is
    q = PendingTwists()
    q.hold(NS, cases[1][0])
    (fp,) = q.release([cases[1][1]])
    np.testing.assert_array_equal(fp.pose.angular_velocity, [29, 8, 0])


def test_sequence_publishes_no_fused_twist_beyond_the_plausibility_bounds(video, monkeypatch):
    """Whatever the twist filter hands out, SequenceLocalizer's fused twists stay within the
    estimator's plausibility bounds (its options'): a final state made implausible (one frame
    given 35 rad/s) comes out with the frame's own twist, counted ``twists_implausible``; the
    other frames carry the filter's twist."""
    from dataclasses import replace

    from rs_localizer.estimation.options import PlausibilityOptions
    from rs_localizer.tracking import fusion

    frames, cam = video
    bad = frames[5].t_ref_ns
    update = fusion.TwistFilter.update

    def corrupting(self, *a, **k):
        step = update(self, *a, **k)
        for f in step.final:
            if f.pose.stamp_ns == bad:
                f.pose.angular_velocity[0] += 35.0  # (a view of the filter's row)
        return step

    monkeypatch.setattr(fusion.TwistFilter, "update", corrupting)
    opts = replace(OPTS, plausibility=PlausibilityOptions(max_angular_velocity=30.0))
    seq = SequenceLocalizer(SequenceSettings(options=opts, stamp_row=0.0))
    fused, own = [], {}
    for f in frames:
        out = seq.process(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz))
        own[out.stamp_ns] = out.estimate
        fused += out.fused
    fused += seq.flush()
    assert [x.pose.stamp_ns for x in fused] == [f.t_ref_ns for f in frames]
    assert seq.tracking_values()["twists_implausible"] == 1
    for x in fused:
        assert np.linalg.norm(x.pose.angular_velocity) <= 30.0
        assert x.implausible == (x.pose.stamp_ns == bad)
        if x.implausible:
            e = own[bad].pose
            np.testing.assert_array_equal(x.pose.angular_velocity, e.angular_velocity)
            np.testing.assert_array_equal(x.pose.linear_velocity, e.linear_velocity)
        elif not x.own_twist:
            np.testing.assert_array_equal(x.pose.angular_velocity, x.state.pose.angular_velocity)


@pytest.mark.parametrize("timing", ["true", "line delay x2", "readout reversed"])
def test_the_video_flags_a_wrong_rolling_shutter_timing(timing):
    """A 36-frame walk given to the localizer with its true timing: none of the last 30
    frames was relocalized or had its twist refused, ``readout_suspect`` false, nothing
    logged. The same frames with the line delay doubled or the readout direction reversed
    (the twist fitted over a readout of the wrong timing is not the camera's: the next
    frames contradict it): suspect, the count of frames as the tracker's own counters say
    (each contradicted frame was relocalized or its twist its own), warned once."""
    from dataclasses import replace

    from helpers.rig import Log

    from rs_localizer.tracking.localizer import READOUT_CHECK_FRAMES

    frames, _, cam, _ = generate_sequence(
        SequenceConfig(num_frames=36, seed=3), trajectory=make_trajectory("walk")
    )
    given = {
        "true": cam,
        "line delay x2": replace(cam, line_delay=2 * cam.line_delay),
        "readout reversed": replace(cam, readout="bottom_to_top"),
    }[timing]
    log = Log()
    seq = SequenceLocalizer(SequenceSettings(options=OPTS, stamp_row=0.0), log=log)
    fused, paths = [], {}
    for f in frames:
        out = seq.process(CameraFrame(f.stamp_ns, given, f.uv, f.xyz))
        paths[out.stamp_ns] = out.path
        fused += out.fused
    fused += seq.flush()
    v = seq.tracking_values()
    last = fused[-READOUT_CHECK_FRAMES:]
    expected = sum(paths[x.pose.stamp_ns] == "relocalized" or x.own_twist for x in last)
    assert v["readout_contradicted"] == expected
    warned = [k for k, _ in log.warnings if k == "readout.suspect"]
    if timing == "true":
        assert expected == 0 and v["readout_suspect"] == "false" and not warned
    else:
        assert expected >= 10 and v["readout_suspect"] == "true" and len(warned) == 1


def test_a_fast_readout_camera_s_fused_twist_comes_from_the_video():
    """A camera reading a line in 1 ns walks at ~1.4 rad/s and ~1.3 m/s: no frame shows its
    motion, each is posed on the global-shutter model with the rolling-shutter fit's (huge)
    velocity covariance, and the fused twist comes from the poses along the video (it was
    published as exactly zero with a zero covariance). Against the truth: within 0.1 rad/s
    and 0.1 m/s, and its covariance covers the error (NEES median below the 6-dof chi-square's
    0.99 quantile)."""
    from dataclasses import replace

    _, _, cam, _ = generate_sequence(SequenceConfig(num_frames=1, seed=3))
    frames, _, cam, _ = generate_sequence(
        SequenceConfig(num_frames=16, seed=3),
        camera=replace(cam, line_delay=1e-9),
        trajectory=make_trajectory("walk"),
    )
    seq = SequenceLocalizer(SequenceSettings(options=OPTS, stamp_row=0.0))
    fused = []
    for f in frames:
        out = seq.process(CameraFrame(f.stamp_ns, cam, f.uv, f.xyz))
        assert out.estimate.success and out.estimate.motion_model == "global_shutter"
        fused += out.fused
    fused += seq.flush()
    assert len(fused) == len(frames)
    nees = []
    for x, f in zip(fused[1:], frames[1:], strict=True):
        dw, dv = (
            x.pose.angular_velocity - f.angular_velocity,
            x.pose.linear_velocity - f.linear_velocity,
        )
        assert np.linalg.norm(f.angular_velocity) > 0.5
        assert np.linalg.norm(dw) < 0.1 and np.linalg.norm(dv) < 0.1, (dw, dv)
        d = np.concatenate([dv, dw])  # (ROS twist order)
        nees.append(d @ np.linalg.solve(x.twist_covariance, d))
    assert np.median(nees) < 16.81
