"""The node's building blocks without ROS: parameters and configuration, the camera_info
history, the frame queue's accounting, point capping and the per-frame pipeline (fed rosbags
messages, which have the fields of the rclpy ones)."""

from __future__ import annotations

import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from rs_localizer.estimation.points import cap_points, capped_rows
from rs_localizer.ros import config as C
from rs_localizer.ros import param_files as F
from rs_localizer.ros import params as P
from rs_localizer.ros.camera_info_history import CameraInfoHistory, calibration_key
from rs_localizer.ros.camera_input import CameraCounts
from rs_localizer.ros.config import load_maps
from rs_localizer.ros.frame_queue import FrameQueue, frame_accounting

ROS_FREE = (
    "rs_localizer.ros.params",
    "rs_localizer.ros.pipeline",
    "rs_localizer.ros.frame_queue",
    "rs_localizer.ros.camera_info_history",
    "rs_localizer.ros.diagnostics",
    "rs_localizer.ros.outputs",
)


def test_modules_import_no_ros():
    code = (
        f"import sys, {', '.join(ROS_FREE)}; "
        "bad = [m for m in sys.modules if m.split('.')[0] in "
        "('rclpy', 'rcl_interfaces', 'sensor_msgs', 'geometry_msgs', 'builtin_interfaces')]; "
        "assert not bad, bad"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


# ---------------------------------------------------------------------------- point capping
def test_cap_points_keeps_the_best_scores_else_evenly_spaced():
    uv, xyz = np.arange(20.0).reshape(10, 2), np.arange(30.0).reshape(10, 3)
    scores = np.array([0.1, 0.9, np.nan, 0.5, 0.9, 0.2, 0.8, 0.0, 0.3, 0.7])
    u, x, s = cap_points(uv, xyz, scores, 4)
    assert capped_rows(10, 4, scores).tolist() == [1, 4, 6, 9]
    np.testing.assert_array_equal(u, uv[[1, 4, 6, 9]])
    np.testing.assert_array_equal(x, xyz[[1, 4, 6, 9]])
    np.testing.assert_array_equal(s, scores[[1, 4, 6, 9]])
    assert capped_rows(4, 2, np.array([0.5, 0.7, 0.5, 0.5])).tolist() == [0, 1]  # ties: earlier
    assert capped_rows(10, 4).tolist() == [0, 3, 6, 9]  # no scores: evenly spaced
    assert capped_rows(10, 4, np.full(10, np.nan)).tolist() == [0, 3, 6, 9]
    u, x, s = cap_points(uv, xyz, None, 10)
    assert u is uv and x is xyz and s is None
    with pytest.raises(ValueError):
        cap_points(uv, xyz[:5], None, 4)
    with pytest.raises(ValueError):
        capped_rows(10, 0)


# ---------------------------------------------------------------------------- parameters
def test_the_config_file_holds_every_default():
    from helpers.paths import CONFIG

    values, ignored = F.parameter_values([CONFIG])
    assert values == P.default_values() and ignored == []


def test_params_file_sections_and_overrides(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text(
        "/**:\n  ros__parameters:\n    ransac: {seed: 3}\n    viz: {path_length: 5}\n"
        "    typo_name: 1\n"
        "rs_localizer:\n  ros__parameters:\n    solver: p3p\n"
        "/camera/rs_localizer:\n  ros__parameters:\n    solver: r9p\n"
    )
    assert F.read_params_file(f) == {
        "ransac.seed": 3,
        "viz.path_length": 5,
        "typo_name": 1,
        "solver": "p3p",
    }
    values, ignored = F.parameter_values([f], {"tracking.lag": 2})
    assert values["ransac.seed"] == 3 and values["solver"] == "p3p" and values["tracking.lag"] == 2
    assert ignored == ["typo_name"]
    bad = tmp_path / "bad.yaml"
    bad.write_text("solver: p3p\n")
    with pytest.raises(P.ConfigError, match="ros__parameters"):
        F.read_params_file(bad)


@pytest.mark.parametrize(
    "name, value, message",
    [
        ("rs.line_delay", 0, "must be of type float (write e.g. 0.0"),
        ("rs.line_delay", -1.0, "outside"),
        ("ransac.min_inliers", 2, "outside"),
        ("ransac.seed", 1.5, "must be of type int"),
        ("refine", 1, "must be of type bool"),
        ("camera.d", [0, 0, 0, 0, 0], "list of float"),
        ("nonexistent", 1, "unknown parameter"),
    ],
)
def test_values_are_checked_as_ros_does(name, value, message):
    with pytest.raises(P.ConfigError, match=message.replace("(", r"\(")):
        P.check_parameter(name, value)


@pytest.mark.parametrize(
    "changes, message",
    [
        ({"solver": "r7p"}, "unknown solver 'r7p'"),
        ({"rs.direction": "diagonal"}, "unknown rs.direction"),
        ({"max_points": 11}, "max_points 11 is below the 12 points"),
        ({"max_angular_velocity": 0.0}, "invalid RANSAC options: max_angular_velocity"),
        ({"camera.fx": float("nan")}, "camera.fx/fy/cx/cy must be finite"),
        ({"camera.d": [float("inf"), 0.0]}, "camera.d must be finite"),
        ({"base_frame": "base", "camera_to_base.rotation": [0.0] * 4}, "invalid camera_to_base"),
        ({"landmarks_file": "/nonexistent.csv"}, "cannot load landmarks_file"),
        ({"frontend": "sift"}, "unknown frontend 'sift'"),
        ({"frontend": "aruco"}, "frontend aruco needs frontend_map"),
        ({"image_transport": "h264"}, "unknown image_transport"),
        ({"tracking.lag": -1}, "invalid tracking parameters"),
    ],
)
def test_invalid_configurations_raise_with_the_parameter_named(changes, message):
    """The configuration (or, for the map files, loading its maps) names the parameter."""
    with pytest.raises(P.ConfigError, match=message):
        load_maps(C.build_config({**P.default_values(), **changes}).camera)


def test_config_from_the_defaults():
    cfg = C.build_config(P.default_values())
    assert cfg.solver == "r6p_1lin" and cfg.tracking.fusion.lag == 1
    assert cfg.options == C.estimate_options(P.default_values())
    cam = cfg.camera
    assert cam.reference_row is None and cam.fallback is None and cam.frontend_kind == "none"
    assert load_maps(cfg.camera).frontend is None and load_maps(cfg.camera).landmarks is None
    assert cfg.time_reset_ns == 1_000_000_000 and cfg.min_points == 12
    off = C.build_config({**P.default_values(), "tracking.enabled": False})
    assert off.tracking is None


# ---------------------------------------------------------------------------- camera_info
@pytest.fixture(scope="module")
def msgs():
    from rs_localizer.ros.bags.bag_io import RosbagsMessages

    return RosbagsMessages()


@pytest.fixture(scope="module")
def sequence():
    from rs_localizer.sim.trajectory import SequenceConfig, generate_sequence

    frames, scene, cam, _ = generate_sequence(SequenceConfig(num_frames=8, num_points=300, seed=4))
    return frames, scene, cam


def test_camera_info_history_selects_by_stamp(msgs, sequence):
    _, _, cam = sequence
    h = CameraInfoHistory(size=3)
    info = msgs.camera_info(cam, 100, "cam")
    key = calibration_key(info)
    assert h.camera_for(50) is None and h.camera_for(50, fallback="fb") == "fb"
    assert h.add(100, key, info, "A") is True
    assert h.add(200, key, info, "A") is False  # the same calibration: one entry
    assert len(h) == 1 and h.entries()[0].seq == 2
    h.add(300, ("other",), info, "B")
    assert [h.camera_for(s) for s in (50, 100, 299, 300, 10**9)] == ["A", "A", "A", "B", "B"]
    assert h.camera_with_key(("other",)) == "B"
    h.forget_after(150)  # a time reset: calibrations stamped later go
    assert [e.camera for e in h.entries()] == ["A"]
    h.forget_after(10)  # nothing older: the newest stays
    assert [e.camera for e in h.entries()] == ["A"]
    for k in range(5):
        h.add(1000 + k, (k,), info, k)
    assert [e.camera for e in h.entries()] == [2, 3, 4]  # size 3: the oldest go
    assert h.rebuild(lambda m: "C") == [] and {e.camera for e in h.entries()} == {"C"}


def test_camera_info_history_waits_for_the_frames_own_camera_info(msgs, sequence):
    """camera_info with every frame (same stamps): a frame waits for its own."""
    _, _, cam = sequence
    h = CameraInfoHistory()
    info = msgs.camera_info(cam, 0, "cam")
    for s in (1, 2):
        h.add(s, (s,), info, s)
        assert h.camera_for(s, wait=1.0) == s
    threading.Timer(0.1, lambda: h.add(3, (3,), info, 3)).start()
    t0 = time.monotonic()
    assert h.camera_for(3, wait=5.0) == 3  # woken by its camera_info
    assert 0.05 < time.monotonic() - t0 < 4.0
    t0 = time.monotonic()
    assert h.camera_for(4, wait=0.2) == 3  # it never comes: the previous one after the wait
    assert time.monotonic() - t0 >= 0.15
    assert h.camera_for(5, wait=5.0, stopped=lambda: True) == 3  # stopping: no wait


def test_a_camera_without_camera_info_holds_one_frame_only(msgs, sequence):
    """No camera_info yet: the first frame waits the whole ``wait`` in vain, the next ones
    return at once (a rig's worker, or a camera's queue, is not held by a camera that sends
    none) until a camera_info arrives, which the frames after it then take."""
    _, _, cam = sequence
    h = CameraInfoHistory()
    t0 = time.monotonic()
    assert h.camera_for(1, wait=0.3) is None
    assert time.monotonic() - t0 >= 0.25
    t0 = time.monotonic()
    for s in range(2, 12):
        assert h.camera_for(s, wait=0.3) is None
    assert time.monotonic() - t0 < 0.25  # (ten frames, not one of them held)
    info = msgs.camera_info(cam, 20, "cam")
    threading.Timer(0.05, lambda: h.add(20, (1,), info, "A")).start()
    assert h.camera_for(21, wait=0.3) is None  # (still none: not held)
    time.sleep(0.1)
    assert h.camera_for(22, wait=0.3) == "A"


# ---------------------------------------------------------------------------- frame queue
class _Outcome:
    def __init__(self, failure=None):
        self.failure = failure


def test_frame_accounting_holds_in_every_snapshot():
    """received = solved + failed + skipped + pending in every snapshot of the camera's counts
    (the queue's received and skipped, the worker's outcome: a raising ``process`` counted
    ``failed.internal_error``), sampled from another thread while frames stream in faster than
    they are processed."""
    counts = CameraCounts()

    def process(k):
        time.sleep(0.0005 * (k % 3))
        if k % 7 == 0:
            raise RuntimeError("boom")
        out = _Outcome(None if k % 5 else "no_camera_info")
        counts.frame_done(0.0, "solved" if out.failure is None else f"failed.{out.failure}")
        return out

    delivered = []
    q = FrameQueue(process, lambda k, o: delivered.append((k, o.failure)),
                   counts_of=lambda k: counts)  # fmt: skip
    q.start()
    samples, stop = [], threading.Event()

    def sample():
        while not stop.is_set():
            samples.append(frame_accounting(counts.counts()))

    reader = threading.Thread(target=sample)
    reader.start()
    try:
        for k in range(1500):
            q.put(k, 3)
            if k % 50 == 0:
                time.sleep(0.002)
        end = time.monotonic() + 20
        while q.pending and time.monotonic() < end:
            time.sleep(0.01)
    finally:
        stop.set()
        reader.join()
        q.stop()
    final = frame_accounting(counts.counts())
    assert len(samples) > 100
    for c in samples + [final]:
        assert c.received == c.solved + c.failed + c.skipped + c.pending, c
        assert c.pending >= 0 and c.failed == sum(c.failures.values()), c
    assert final.received == 1500 and final.pending == 0
    assert final.skipped > 0 and final.solved > 0
    assert final.failed > 0 and set(final.failures) <= {"internal_error", "no_camera_info"}
    assert final.skipped == q.dropped == counts.get("skipped.queue_full")
    assert len(delivered) == final.solved + final.failed
    assert [k for k, _ in delivered] == sorted(k for k, _ in delivered)  # in order
    assert all(f == "internal_error" for k, f in delivered if k % 7 == 0)


def test_frame_queue_drops_the_oldest_and_stops():
    gate = threading.Event()
    done = []
    counts = CameraCounts()

    def process(k):
        gate.wait(5)
        counts.frame_done(0.0, "solved")
        return _Outcome()

    q = FrameQueue(process, lambda k, o: done.append(k), counts_of=lambda k: counts)
    q.start()
    q.put(0, 2)
    while q.pending != 1 or counts.get("received") != 1:
        time.sleep(0.001)
    time.sleep(0.05)  # (the worker is on frame 0)
    assert [q.put(k, 2) for k in (1, 2, 3, 4)] == [0, 0, 1, 1]  # 1 and 2 dropped
    c = frame_accounting(counts.counts())
    assert (c.received, c.skipped, c.pending, q.pending) == (5, 2, 3, 3)
    gate.set()
    end = time.monotonic() + 5
    while q.pending and time.monotonic() < end:
        time.sleep(0.01)
    assert done == [0, 3, 4]
    q.stop(drop_queued=True)
    q.put(5, 2)
    q.request_stop(drop_queued=True)  # (stopped: the frame waiting is dropped)
    c = frame_accounting(counts.counts())
    assert (c.received, c.solved, c.skipped, c.pending) == (6, 3, 3, 0)
    assert counts.counts() == {"received": 6, "solved": 3, "skipped.queue_full": 2,
                               "skipped.stopped": 1}  # fmt: skip


# ---------------------------------------------------------------------------- pipeline
def _pipeline(**changes):
    from helpers.camera_node import CameraNode

    cfg = C.build_config({**P.default_values(), "camera_info_wait": 0.0, **changes})
    return CameraNode(cfg)


def test_pipeline_tracks_a_sequence(msgs, sequence):
    """Every frame solved and stamped at its reference line; with tracking (lag 1) each frame's
    fused twist comes with the next frame, the last one with flush()."""
    import importlib.util

    from rs_localizer.ros.outputs import fused_messages, outcome_messages

    with_messages = importlib.util.find_spec("geometry_msgs") is not None
    frames, _, cam = sequence
    pipe = _pipeline()
    f0 = frames[0]
    res = pipe.process(msgs.cloud(f0.uv, f0.xyz, f0.ids, f0.stamp_ns, "cam"), "correspondences")
    assert res.failure == "no_camera_info" and pipe.camera_source() == "missing"
    pipe.add_camera_info(msgs.camera_info(cam, f0.stamp_ns, "cam"))
    assert pipe.camera_source() == "camera_info"
    fused = []
    for f in frames:
        res = pipe.process(
            msgs.cloud(f.uv, f.xyz, f.ids, f.stamp_ns, "cam", scores=f.scores), "correspondences"
        )
        assert res.solved, (res.failure, res.detail)
        assert res.out_stamp_ns == f.t_ref_ns and res.frame_id == "cam" and not res.twist_now
        assert np.degrees(np.linalg.norm(res.estimate.pose.orientation - f.orientation)) < 0.5
        fused += [o.stamp_ns for o in res.fused]
        if with_messages:  # the node's publishing order
            out = pipe.outcome(res)
            topics = [t for t, _ in outcome_messages(out, "map", lambda t: t != "tf")]
            assert topics == ["pose", "twist_single_frame"] + ["twist", "odom"] * len(res.fused) + [
                "pose_with_covariance"
            ]
            # only what has a subscriber is built (the pose always)
            only = [t for t, _ in outcome_messages(out, "map", lambda t: t == "odom")]
            assert only == ["pose"] + ["odom"] * len(res.fused)
    assert fused == [f.t_ref_ns for f in frames[:-1]]  # one frame late
    last = pipe.flush()
    assert [o.stamp_ns for o in last] == [frames[-1].t_ref_ns] and pipe.flush() == []
    if with_messages:
        assert [t for t, _ in fused_messages(last, "map")] == ["twist", "odom"]
    values = pipe.tracking_values()
    assert values["track_state"] == "tracking" and values["frames_tracked"] >= len(frames) - 2


def test_pipeline_drops_and_counts(msgs, sequence):
    frames, _, cam = sequence
    pipe = _pipeline(max_points=100, **{"tracking.enabled": False})
    pipe.add_camera_info(msgs.camera_info(cam, 0, "cam"))
    f = frames[0]
    uv = f.uv.copy()
    uv[:3] = np.nan
    res = pipe.process(msgs.cloud(uv, f.xyz, f.ids, f.stamp_ns, "cam"), "correspondences")
    assert res.solved and res.twist_now and len(res.points2d) == 100
    st = pipe.stats.snapshot()
    assert st.counts["points_dropped"] >= 3 and st.counts["capped_clouds"] == 1
    res = pipe.process(msgs.cloud(f.uv, f.xyz, f.ids, f.stamp_ns - 10**9, "cam"), "correspondences")
    assert res.solved and pipe.stats.snapshot().counts["time_resets"] == 1  # never dropped
    empty = msgs.cloud(f.uv[:0], f.xyz[:0], f.ids[:0], f.stamp_ns, "cam")
    assert pipe.process(empty, "correspondences").failure == "empty_cloud"
    kp = msgs.keypoints(f.uv, f.ids, f.stamp_ns, "cam")
    assert pipe.process(kp, "keypoints").failure == "no_landmarks"
    img = msgs.image(np.zeros((4, 4), np.uint8), f.stamp_ns, "cam")
    assert pipe.process(img, "image").failure == "no_frontend"
    info = msgs.camera_info(cam, 5, "cam")
    info.k[0] = 0.0
    assert pipe.add_camera_info(info) is None
    assert pipe.stats.snapshot().counts["camera_info_rejected.bad_intrinsics"] == 1


def test_pipeline_warns_once_of_a_feature_map_that_matches_nothing(msgs, sequence, tmp_path):
    """A feature map whose descriptors match none of an image's many keypoints: each such
    image counted (frontend_few_match_frames), one warning over several images."""
    import cv2
    from helpers.camera_node import CameraNode

    from rs_localizer.frontends.shared import SHARED_MAPS
    from rs_localizer.maps.features import FeatureMap

    _, _, cam = sequence
    rng = np.random.default_rng(0)
    fmap = FeatureMap(
        rng.normal(size=(20, 3)), rng.random((20, 128), np.float32), np.arange(20), "sift"
    ).save(tmp_path / "features.npz")
    owner = object()
    cfg = C.build_config(
        {
            **P.default_values(),
            "camera_info_wait": 0.0,
            "frontend": "features",
            "frontend_map": str(fmap),
        }
    )
    maps = load_maps(cfg.camera, owner=owner)
    warned = []

    class Log:
        def info(self, text):
            pass

        def warning(self, text):
            warned.append(text)

        def error(self, text):
            pass

    pipe = CameraNode(cfg, log=Log(), maps=maps)
    pipe.add_camera_info(msgs.camera_info(cam, 0, "cam"))
    texture = rng.integers(0, 256, (cam.height // 4, cam.width // 4), np.uint8)
    img = cv2.resize(texture, (cam.width, cam.height), interpolation=cv2.INTER_CUBIC)
    for k in range(3):  # (three different images: the same one again would be frozen_image)
        res = pipe.process(msgs.image(np.roll(img, 3 * k, axis=1), (k + 1) * 10**8, "cam"), "image")
        assert res.failure == "frontend_too_few_points"
    assert maps.frontend.few_match_frames == 3
    assert len([w for w in warned if "frontend_few_match_frames" in w]) == 1
    SHARED_MAPS.release(owner)


def test_pipeline_uncompiled_then_compiled(msgs, sequence):
    """While the kernels compile (the runtime's ready implementation is NumPy), frames are
    solved on the NumPy implementation and tracked as on the compiled kernels (their twists
    pending for the twist filter, the frames after the first tracked), counted per path;
    once the kernels are ready the track goes on across the switch (the next frame tracked,
    no reset)."""
    from rs_localizer.runtime import background

    frames, _, cam = sequence
    pipe = _pipeline()
    pipe.add_camera_info(msgs.camera_info(cam, frames[0].stamp_ns, "cam"))
    background._hold(True)
    try:
        for f in frames[:3]:
            res = pipe.process(msgs.cloud(f.uv, f.xyz, f.ids, f.stamp_ns, "cam"), "correspondences")
            assert res.solved, (res.failure, res.detail)
            assert not res.compiled and not res.twist_now
            assert res.estimate.implementation == "numpy"
            assert np.degrees(np.linalg.norm(res.estimate.pose.orientation - f.orientation)) < 0.5
        track = pipe.tracking_values()
        assert track["track_state"] == "tracking" and track["frames_tracked"] == 2
    finally:
        background._hold(False)
    f = frames[3]
    res = pipe.process(msgs.cloud(f.uv, f.xyz, f.ids, f.stamp_ns, "cam"), "correspondences")
    assert res.solved and res.compiled and not res.twist_now
    assert res.estimate.initial_used
    track = pipe.tracking_values()
    assert track["frames_tracked"] == 3 and track["resets"] == 0
    counts = pipe.stats.snapshot().counts
    assert (counts["frames_uncompiled"], counts["frames_compiled"]) == (3, 1)


def test_a_frames_stamp_is_checked_once_and_its_reference_time_made_once(
    msgs, sequence, monkeypatch
):
    """Along the camera node's route (message -> its mode's frame step -> its rig of one -> front
    end -> estimator), for a correspondence frame and an image frame alike, the stamp is
    validated once (at the message, where a bad one is ``bad_stamp``) and the reference time
    computed once; the output stamp is the reference row's capture time of the simulation
    (``t_ref_ns``, from the trajectory, not from the formula)."""
    from helpers.camera_node import CameraNode

    import rs_localizer.camera as camera_mod
    import rs_localizer.ros.conversions as conversions_mod
    import rs_localizer.tracking.sequence as sequence_mod
    import rs_localizer.tracking.video as rig_mod
    from rs_localizer.correspondences import Correspondences
    from rs_localizer.frontends.shared import LoadedMaps
    from rs_localizer.ros.image_codec import image_fields

    frames, _, cam = sequence
    checks, refs = [], []
    original = camera_mod.checked_stamp

    def counted(stamp_ns, what="frame"):
        if type(stamp_ns) is not camera_mod.Stamp:  # (one already checked is taken as is)
            checks.append(stamp_ns)
        return original(stamp_ns, what)

    for mod in (camera_mod, conversions_mod, sequence_mod, rig_mod):
        monkeypatch.setattr(mod, "checked_stamp", counted)
    time_offset = camera_mod.CameraModel.time_offset

    def counted_offset(self, a, b):
        refs.append((a, b))
        return time_offset(self, a, b)

    monkeypatch.setattr(camera_mod.CameraModel, "time_offset", counted_offset)

    current = {}

    class Frontend:  # (the frame's own correspondences, whatever the image)
        def process(self, image, camera, encoding="bgr8", prediction=None):
            f = current["frame"]
            return Correspondences(f.uv, f.xyz)

    cfg = C.build_config({**P.default_values(), "camera_info_wait": 0.0})
    pipe = CameraNode(cfg, maps=LoadedMaps(frontend=Frontend()))
    pipe.add_camera_info(msgs.camera_info(cam, frames[0].stamp_ns, "cam"))
    rng = np.random.default_rng(0)
    for k, f in enumerate(frames[:4]):
        checks.clear()
        refs.clear()
        if k % 2:
            img = rng.integers(0, 255, (cam.height, cam.width), np.uint8)
            msg = msgs.T["sensor_msgs/msg/Image"](
                header=msgs.header(f.stamp_ns, "cam"), **image_fields(img, "mono8")
            )
            current["frame"] = f
            res = pipe.process(msg, "image")
        else:
            res = pipe.process(msgs.cloud(f.uv, f.xyz, f.ids, f.stamp_ns, "cam"), "correspondences")
        assert res.solved, (k, res.failure, res.detail)
        assert res.out_stamp_ns == f.t_ref_ns and res.estimate is not None
        assert checks == [f.stamp_ns], k
        assert len(refs) == 1, (k, refs)


def test_an_image_after_a_time_reset_is_not_compared_with_the_last_one(msgs, sequence):
    """The pipeline notes a frame's time before its image is searched (a time reset acted on
    first); the image after a reset is then taken as the library takes it from
    ``SequenceLocalizer.process_image`` alone: not compared with the image before the reset
    (a new timeline), so the same picture again is searched, not refused ``frozen_image``;
    without a reset it is refused."""
    from helpers.camera_node import CameraNode

    from rs_localizer.tracking.sequence import SequenceLocalizer

    _, _, cam = sequence
    cfg = C.build_config(
        {**P.default_values(), "camera_info_wait": 0.0, "time_reset_threshold": 1.0}
    )
    image = np.random.default_rng(1).integers(0, 256, (cam.height, cam.width), np.uint8)
    stamps = [2 * 10**9, 2 * 10**9 + 10**8, 10**9, 10**9 + 10**8]  # (a step back: a reset)

    class Finds:
        """A front end finding 3 points (too few for a pose) in any image."""

        def process(self, image, camera, encoding, prediction=None):
            from rs_localizer.correspondences import Correspondences

            return Correspondences(np.zeros((3, 2)), np.zeros((3, 3)), np.arange(3))

    pipe = CameraNode(cfg)
    pipe.set_frontend(Finds(), "test")
    pipe.add_camera_info(msgs.camera_info(cam, 0, "cam"))
    node = [pipe.process(msgs.image(image, t, "cam"), "image").failure for t in stamps]
    lib = SequenceLocalizer(frontend=Finds(), frontend_name="test")
    alone = [lib.process_image(t, image, cam, "mono8").failure for t in stamps]
    few, frozen = "frontend_too_few_points", "frozen_image"
    assert alone == [few, frozen, few, frozen]
    assert node == alone
    assert pipe.stats.snapshot().counts["time_resets"] == 1


def test_camera_input_notes_a_time_reset_and_names_its_intrinsics():
    """CameraInput.note_time: a stamp the video's clock calls a time reset is counted
    ``time_resets`` and warned about once (key ``time_reset``, the camera's label before it),
    and the camera_infos stamped after it are forgotten (a frame after the reset no longer
    picks them); a stamp the clock accepts changes nothing. CameraInput.source: ``missing``,
    ``parameters`` with a fallback, ``camera_info`` once one is kept."""
    from rs_localizer.ros.camera_input import CameraInput

    warned, counts = [], CameraCounts()
    log = type("L", (), {"warning": lambda self, key, text: warned.append((key, text))})()
    inp = CameraInput(log, counts.add, label="rig camera 'a': ")
    assert inp.source() == "missing"
    inp.fallback = object()
    assert inp.source() == "parameters"
    cams = {s: object() for s in (1, 2, 3)}  # (a model per camera_info, told apart by identity)
    for s, cam in cams.items():
        inp.history.add(s * 10**9, (s,), None, cam)
    assert inp.source() == "camera_info" and inp.camera_for(5 * 10**9) is cams[3]
    inp.note_time(4 * 10**9, lambda stamp: None)
    assert counts.get("time_resets") == 0 and not warned and inp.camera_for(5 * 10**9) is cams[3]
    seen = []
    inp.note_time(int(1.5e9), lambda stamp: seen.append(stamp) or "went back")
    assert seen == [int(1.5e9)] and counts.get("time_resets") == 1
    assert warned == [("rig camera 'a': time_reset", "rig camera 'a': time reset: went back")]
    assert inp.camera_for(5 * 10**9) is cams[1] and len(inp.history) == 1


def test_a_frame_step_that_raises_raises_to_the_worker(msgs, sequence, monkeypatch):
    """A defect in the camera alone's frame step (its rig of one raising) is raised to the
    node's worker, as a rig camera's is (the worker counts the frame ``failed.internal_error``
    and logs it: ``test_node.py``), not turned into a dropped frame's outcome; the next frame
    is solved."""
    frames, _, cam = sequence
    pipe = _pipeline(**{"tracking.enabled": False})
    pipe.add_camera_info(msgs.camera_info(cam, 0, "cam"))

    def broken(*args, **kwargs):
        raise RuntimeError("boom")

    monkeypatch.setattr(pipe.rig, "add", broken)
    f0, f1 = frames[:2]
    with pytest.raises(RuntimeError, match="boom"):
        pipe.process(msgs.cloud(f0.uv, f0.xyz, f0.ids, f0.stamp_ns, "cam"), "correspondences")
    monkeypatch.undo()
    res = pipe.process(msgs.cloud(f1.uv, f1.xyz, f1.ids, f1.stamp_ns, "cam"), "correspondences")
    assert res.solved and res.out_stamp_ns == f1.t_ref_ns


def test_a_frame_step_that_raised_publishes_nothing(monkeypatch):
    """A frame whose frame step raised (the worker counted it ``failed.internal_error`` and
    logged it) reaches the publishing step without a result: nothing is published and no
    second warning ("publishing failed") follows."""
    from types import SimpleNamespace

    import rs_localizer.ros.mode as N
    from rs_localizer.ros.core import QueuedFrame, TakenFrame

    published = []
    monkeypatch.setattr(N, "publish_frame", lambda node, outcome: published.append(outcome))
    mode = N.LocalizerMode.__new__(N.LocalizerMode)
    mode.node, mode.alone = SimpleNamespace(), False
    taken = TakenFrame(("failed.internal_error",), "internal_error")
    mode.publish_taken(QueuedFrame("a", "correspondences", None, 0.0, 0), taken)
    assert published == []


def test_a_parameter_change_waits_for_the_frame_the_worker_is_on():
    """The camera alone takes a run-time change between two frames of the worker, as a rig
    does: while a frame is taken the change is handed to the worker (the parameter callback
    returns at once, the frame keeps the old settings), then the next frame is solved with
    the new settings."""
    import time

    from helpers.camera_node import CameraNode

    from rs_localizer.frontends.shared import LoadedMaps

    values = P.default_values()
    cfg = C.build_config(values)
    new = C.build_config({**values, "ransac.threshold_px": 3.0})
    assert new.options.ransac.threshold_px != cfg.options.ransac.threshold_px
    pipe = CameraNode(cfg)
    change = ((new, {"": LoadedMaps()}), {"ransac.threshold_px": 3.0})
    with pipe.node._between.frame():  # (the worker on a frame)
        t = threading.Thread(target=pipe.mode._change_to, args=change)
        tic = time.perf_counter()
        t.start()
        t.join(5.0)
        assert not t.is_alive() and time.perf_counter() - tic < 1.0
        assert pipe.mode.cfg is cfg  # (not during the frame)
    assert pipe.mode.cfg is new  # (after it, before the next)
    assert pipe.rig.settings.options.ransac.threshold_px == 3.0


def test_a_publishing_failure_does_not_silence_a_frames_internal_error_line():
    """Warnings are throttled per kind: a publishing failure's line and, within the throttle
    period, a frame's ``internal_error`` line are both logged (neither hides the other)."""
    from types import SimpleNamespace

    from rs_localizer.ros.core import NodeCore
    from rs_localizer.ros.pipeline import ThrottledLog

    lines = []
    logger = SimpleNamespace(warning=lines.append, info=lines.append, error=lines.append)
    core = SimpleNamespace(_log=ThrottledLog(logger, period=60.0))
    NodeCore._delivery_failed(core, RuntimeError("no tf2_msgs"))
    core._log.warning("internal_error", "frame failed (internal_error): RuntimeError: boom")
    assert len(lines) == 2 and "publishing failed" in lines[0] and "boom" in lines[1], lines


def test_between_frames_runs_a_step_at_once_or_after_the_frame_being_taken():
    """:class:`BetweenFrames`: a step runs at once when no frame is being taken; while one
    is, the caller returns at once and the steps run at the frame's end, in the order they
    were handed, before the next frame; a step that raises goes to ``on_error`` and the
    others still run; steps handed while a worker takes frames back to back all run, in
    order."""
    from rs_localizer.ros.frame_queue import BetweenFrames

    errors, ran = [], []
    between = BetweenFrames(errors.append)
    assert between.run(lambda: ran.append("idle")) and ran == ["idle"]
    with between.frame():
        ran.append("frame")
        tic = time.perf_counter()
        t = threading.Thread(target=lambda: [between.run(lambda: ran.append("a")),
                                             between.run(lambda: 1 / 0),
                                             between.run(lambda: ran.append("b"))])  # fmt: skip
        t.start()
        t.join(5.0)
        assert not t.is_alive() and time.perf_counter() - tic < 1.0
        assert ran == ["idle", "frame"]
        assert not between.hold_if_free()
    assert ran == ["idle", "frame", "a", "b"]
    assert len(errors) == 1 and isinstance(errors[0], ZeroDivisionError)
    # (stress: steps handed while a worker takes frames back to back all run)
    done, stop = [], threading.Event()

    def worker():
        while not stop.is_set():
            with between.frame():
                pass

    w = threading.Thread(target=worker)
    w.start()
    for k in range(2000):
        between.run(lambda k=k: done.append(k))
    stop.set()
    w.join(5.0)
    assert done == list(range(2000))
