"""``rs-localizer play``: which frame topic it plays, and each IMU message sent once.

A responder node stands in for the localizer: it answers every frame with a pose of the same
stamp and records what arrived."""

import threading
import time

import pytest
from helpers.ros import spinning

from rs_localizer.cli import main as cli
from rs_localizer.ros.bags.bag_io import CAMERA_INFO, COMPRESSED_IMAGE, IMAGE, PC2
from rs_localizer.ros.bags.play import choice_is_final, choose_frame_topics, is_frame_topic


def test_choose_frame_topics():
    """One frame topic per camera namespace: an image the node subscribes, else the
    correspondences, else an image, else the keypoints."""
    bag = {
        "/cam/correspondences": PC2,
        "/cam/keypoints": PC2,
        "/cam/image_raw": IMAGE,
        "/other/keypoints": PC2,
        "/other/image/compressed": COMPRESSED_IMAGE,
    }
    kept, skipped = choose_frame_topics(bag, subscribed=set())
    assert sorted(kept) == ["/cam/correspondences", "/other/image/compressed"]
    assert sorted(skipped) == ["/cam/image_raw", "/cam/keypoints", "/other/keypoints"]
    kept, _ = choose_frame_topics(bag, subscribed={"/cam/image_raw", "/cam/correspondences"})
    assert "/cam/image_raw" in kept
    kept, skipped = choose_frame_topics({"/cam/keypoints": PC2}, set())
    assert kept == ["/cam/keypoints"] and skipped == []
    # source: images even when none is subscribed yet, or the correspondences even when the
    # node subscribes an image
    kept, _ = choose_frame_topics(bag, subscribed=set(), source="image")
    assert sorted(kept) == ["/cam/image_raw", "/other/image/compressed"]
    kept, _ = choose_frame_topics(bag, subscribed={"/cam/image_raw"}, source="correspondences")
    assert sorted(kept) == ["/cam/correspondences", "/other/keypoints"]
    assert is_frame_topic("/c/image/compressed", COMPRESSED_IMAGE)
    assert not is_frame_topic("/c/camera_info", CAMERA_INFO)


def test_choice_is_final_when_no_later_subscription_can_change_it():
    """``choice_is_final`` against every set of topics that could be found subscribed later:
    final exactly when none of them changes the choice (e.g. ``auto`` and a subscribed image
    in each namespace that has one; not with the correspondences subscribed and an image
    not yet)."""
    from itertools import chain, combinations

    bag = {
        "/cam/correspondences": PC2,
        "/cam/keypoints": PC2,
        "/cam/image_raw": IMAGE,
        "/cam/image": IMAGE,
        "/other/keypoints": PC2,
        "/other/image/compressed": COMPRESSED_IMAGE,
    }

    def subsets(ts):
        ts = sorted(ts)
        return (
            set(c) for c in chain.from_iterable(combinations(ts, k) for k in range(len(ts) + 1))
        )

    finals = 0
    for source in ("auto", "image", "correspondences"):
        for heard in subsets(bag):
            kept = set(choose_frame_topics(bag, heard, source)[0])
            later = (
                set(choose_frame_topics(bag, heard | more, source)[0])
                for more in subsets(set(bag) - heard)
            )
            expected = all(k == kept for k in later)
            assert choice_is_final(bag, heard, source) == expected, (source, heard)
            finals += expected
    assert 0 < finals < 3 * 2 ** len(bag)
    assert not choice_is_final(bag, {"/cam/correspondences", "/other/keypoints"})
    assert choice_is_final(bag, {"/cam/image", "/cam/correspondences", "/other/image/compressed"})
    assert choice_is_final({"/cam/correspondences": PC2, "/cam/keypoints": PC2}, set())


@pytest.fixture(scope="module")
def imu_bag(tmp_path_factory):
    path = tmp_path_factory.mktemp("play") / "bag"
    args = ["make-bag", str(path), "--frames", "5", "--points", "150", "--imu-rate", "200"]
    assert cli(args + ["--seed", "3"]) == 0
    return path


def test_lockstep_plays_one_frame_topic_and_each_imu_sample_once(imu_bag, ros_context):
    import rclpy
    from geometry_msgs.msg import PoseStamped
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Imu, PointCloud2

    from rs_localizer.ros.bags.bag_io import iter_messages

    node = rclpy.create_node("play_test_responder", context=ros_context)
    qos = QoSProfile(depth=500, reliability=ReliabilityPolicy.RELIABLE)
    pose = node.create_publisher(PoseStamped, "/camera/pose", qos)
    got = {"correspondences": [], "keypoints": [], "imu": []}

    def on_frame(kind):
        def cb(msg):
            got[kind].append(msg.header.stamp)
            pose.publish(PoseStamped(header=msg.header))

        return cb

    for kind in ("correspondences", "keypoints"):
        node.create_subscription(PointCloud2, f"/camera/{kind}", on_frame(kind), qos)
    node.create_subscription(
        Imu,
        "/imu/data",
        lambda m: got["imu"].append((m.header.stamp.sec, m.header.stamp.nanosec)),
        qos,
    )
    notes = []
    with spinning(ros_context, node):
        from rs_localizer.ros.bags.play import play

        res = play(
            imu_bag, lockstep=True, context=ros_context, wait_subscribers=20.0, log=notes.append
        )
        time.sleep(0.3)
    assert res.answered == len(res.frames) == 5 and res.timeouts == 0
    assert res.skipped_topics == ["/camera/keypoints"]
    assert got["keypoints"] == [] and len(got["correspondences"]) == 5
    assert any("--topics" in n and "/camera/keypoints" in n for n in notes)
    n_imu = sum(1 for m in iter_messages(imu_bag, None) if m[0] == "/imu/data")
    assert len(got["imu"]) == n_imu > 0  # each sample once, none primed or republished
    assert len(set(got["imu"])) == n_imu


def test_auto_source_waits_for_an_image_subscription_found_after_the_correspondences(
    sample_images_bag, ros_context
):
    """A node's subscriptions are discovered one by one (seconds apart on a loaded machine):
    here a node takes ``/camera/correspondences`` at once and its image topic
    ``/camera/image`` only 0.5 s after the player's publishers appear. ``--source auto``
    still plays the rendered bag's images (``/camera/image_raw``, on the node's
    ``/camera/image``), not its correspondences: the choice waits until the subscriptions
    settle."""
    import rclpy
    from geometry_msgs.msg import PoseStamped
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image, PointCloud2

    from rs_localizer.ros.bags.play import SETTLE_S, play

    delay = 0.5  # (found well within SETTLE_S of the correspondences: room for a late timer)
    assert delay <= SETTLE_S - 0.4
    node = rclpy.create_node("play_test_late_images", context=ros_context)
    qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    pose = node.create_publisher(PoseStamped, "/camera/pose", qos)
    got = {"correspondences": 0, "image": 0}
    late = {}

    def answer(kind):
        def cb(msg):
            got[kind] += 1
            pose.publish(PoseStamped(header=msg.header))

        return cb

    node.create_subscription(PointCloud2, "/camera/correspondences", answer("correspondences"), qos)

    def subscribe_images_later():
        now = time.monotonic()
        if "at" not in late and node.count_publishers("/camera/correspondences"):
            late["at"] = now + delay  # (the player is there)
        if "at" in late and "images" not in late and now >= late["at"]:
            late["images"] = node.create_subscription(Image, "/camera/image", answer("image"), qos)

    node.create_timer(0.02, subscribe_images_later)
    notes = []
    with spinning(ros_context, node):
        res = play(sample_images_bag, lockstep=True, limit=2, timeout=5.0, context=ros_context,
                   log=notes.append)  # fmt: skip
    assert "images" in late
    assert {f["topic"] for f in res.frames} == {"/camera/image_raw"}, notes
    assert res.skipped_topics == ["/camera/correspondences"], notes
    assert res.answered == 2 and got == {"correspondences": 0, "image": 2}, (got, notes)


def test_live_and_pose_topics_follow_remaps_and_namespace():
    """A frame's live topic and the node's pose topic that answers it: an explicit remap
    wins, ``__ns`` moves every other topic into a namespace."""
    from rs_localizer.ros.bags.play import live_topic, pose_topic_of

    assert live_topic("/camera/image", {}) == "/camera/image"
    assert pose_topic_of("/camera/image", {}) == "/camera/pose"
    assert pose_topic_of("/camera/image/compressed", {}) == "/camera/pose"
    remap = {"/camera/image": "/robot/cam/image", "__ns": "/r2/"}
    assert pose_topic_of("/camera/image", remap) == "/robot/cam/pose"
    assert live_topic("/camera/camera_info", remap) == "/r2/camera/camera_info"
    assert pose_topic_of("/cam1/correspondences", remap) == "/r2/cam1/pose"


class _Responder:
    """A node taking ``/<ns>/correspondences`` and answering each on ``answer_topic``."""

    def __init__(self, ros_context, ns, answer_topic):
        import rclpy
        from geometry_msgs.msg import PoseStamped
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import PointCloud2

        self.node = rclpy.create_node("play_test_ns_responder", context=ros_context)
        qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
        pose = self.node.create_publisher(PoseStamped, answer_topic, qos)
        self.frames = 0

        def cb(msg):
            self.frames += 1
            pose.publish(PoseStamped(header=msg.header))

        self.node.create_subscription(PointCloud2, f"{ns}/correspondences", cb, qos)
        self.ex = SingleThreadedExecutor(context=ros_context)
        self.ex.add_node(self.node)
        self.stop = threading.Event()
        self.th = threading.Thread(
            target=lambda: [
                self.ex.spin_once(timeout_sec=0.02) for _ in iter(self.stop.is_set, True)
            ]
        )
        self.th.start()

    def close(self):
        self.stop.set()
        self.th.join()
        self.ex.remove_node(self.node)
        self.node.destroy_node()
        self.ex.shutdown()


def test_lockstep_waits_on_the_pose_of_the_namespace_played_into(imu_bag, ros_context):
    """``__ns`` (and a remap) move the frames into another namespace: lock-step waits for the
    pose topic there, not for ``/camera/pose``."""
    from rs_localizer.ros.bags.play import play

    r = _Responder(ros_context, "/robot/camera", "/robot/camera/pose")
    try:
        t0 = time.monotonic()
        res = play(
            imu_bag,
            lockstep=True,
            topics=["/camera/correspondences", "/camera/camera_info"],
            remap={"__ns": "/robot"},
            context=ros_context,
            wait_subscribers=20.0,
            log=print,
        )
        took = time.monotonic() - t0
    finally:
        r.close()
    assert res.answered == len(res.frames) == 5 and res.timeouts == 0 and not res.gave_up
    assert r.frames == 5 and took < 15.0


def test_lockstep_gives_up_naming_the_pose_topics_that_exist(imu_bag, ros_context):
    """A node takes the frames but answers in another namespace: lock-step stops before the
    first frame and names the pose topic that has a publisher; with nobody taking the frames
    it stops after ``give_up`` unanswered frames instead of waiting through the bag."""
    from rs_localizer.ros.bags.play import play

    r = _Responder(ros_context, "/camera", "/elsewhere/pose")
    notes = []
    try:
        res = play(
            imu_bag,
            lockstep=True,
            topics=["/camera/correspondences", "/camera/camera_info"],
            context=ros_context,
            wait_subscribers=20.0,
            timeout=0.3,
            log=notes.append,
        )
    finally:
        r.close()
    assert res.frames == [] and r.frames == 0
    asked, have = res.gave_up.split("with a publisher:")
    assert "/camera/pose" in asked and "/elsewhere/pose" in have
    assert "/camera/pose" not in have  # (the player's own subscription is no publisher)
    assert any(n.startswith("error:") and "/elsewhere/pose" in n for n in notes)

    res = play(
        imu_bag,
        lockstep=True,
        topics=["/camera/correspondences", "/camera/camera_info"],
        remap={"__ns": "/nobody"},
        context=ros_context,
        wait_subscribers=0.5,
        timeout=0.2,
        retries=0,
        give_up=2,
        log=print,
    )
    assert len(res.frames) == 2 and res.answered == 0 and res.timeouts == 2
    # (two frames sent of the bag's more: it stopped, whatever the machine's load)
    assert "/nobody/camera/pose" in res.gave_up and "to the first 2 frames" in res.gave_up


def test_lockstep_gives_up_naming_the_frame_topics_a_running_node_does_not_take(
    imu_bag, ros_context
):
    """The node publishes the pose topic lock-step waits on but takes none of the frames (a
    rig node waiting for a camera whose topic it does not receive): the player stops saying
    so, names the frame topic nobody subscribes and the diagnostics command, instead of
    pointing at the pose topic it waits on as if the node ran elsewhere."""
    from rs_localizer.ros.bags.play import play

    r = _Responder(ros_context, "/mute/elsewhere", "/mute/camera/pose")
    try:
        res = play(
            imu_bag,
            lockstep=True,
            topics=["/camera/correspondences", "/camera/camera_info"],
            remap={"__ns": "/mute"},
            context=ros_context,
            wait_subscribers=0.5,
            timeout=0.2,
            retries=0,
            give_up=2,
            log=print,
        )
    finally:
        r.close()
    assert len(res.frames) == 2 and res.answered == 0 and r.frames == 0
    assert "though a node publishes it" in res.gave_up
    assert "no node subscribes /mute/camera/correspondences" in res.gave_up
    assert "rs-localizer diagnostics --ns /mute/camera --once" in res.gave_up
    assert "with a publisher:" not in res.gave_up


class _CompilingResponder(_Responder):
    """A responder that answers no frame during its first ``busy`` seconds (a node compiling
    its kernels); with ``say``, it logs as the node's warm-up does (``/rosout``) when it
    starts and when it is done."""

    def __init__(self, ros_context, busy, say):
        super().__init__(ros_context, "/cam_busy", "/unused/pose")
        from geometry_msgs.msg import PoseStamped
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
        pose = self.node.create_publisher(PoseStamped, "/cam_busy/pose", qos)
        self.ready_at = time.monotonic() + busy
        self.pending = []
        log = self.node.get_logger()
        if say:  # (log_warm_up's first and last lines)
            log.info("warm-up (r6p_1lin): numba cache /tmp/x (writable)")

        def cb(msg):
            self.frames += 1
            self.pending.append(msg.header)

        def tick():
            if time.monotonic() < self.ready_at:
                return
            if say and self.pending is not None:
                log.info(f"warm-up (r6p_1lin): {busy:.2f} s, ok, compiled 3 kernels")
            for h in self.pending:
                pose.publish(PoseStamped(header=h))
            self.pending.clear()

        from sensor_msgs.msg import PointCloud2

        self.node.create_subscription(PointCloud2, "/cam_busy/frames", cb, qos)
        self.node.create_timer(0.05, tick)


@pytest.mark.parametrize("say", [True, False])
def test_lockstep_waits_for_a_node_that_says_it_compiles(imu_bag, ros_context, say):
    """A node that logs that it compiles (as the warm-up does) answers its first frame only
    after 2.5 s: lock-step waits on beyond its 0.5 s timeout, without a timeout or a resend;
    the same node silent about it times the first frame out (the control)."""
    from rs_localizer.ros.bags.play import play

    r = _CompilingResponder(ros_context, busy=2.5, say=say)
    notes = []
    try:
        res = play(
            imu_bag,
            lockstep=True,
            topics=["/camera/correspondences", "/camera/camera_info"],
            remap={"/camera/correspondences": "/cam_busy/frames", "__ns": "/cam_busy"},
            output_topics=["/cam_busy/pose"],
            context=ros_context,
            wait_subscribers=10.0,
            timeout=0.5,
            retries=0,
            limit=2,
            log=notes.append,
        )
    finally:
        r.close()
    if say:
        assert res.answered == 2 and res.timeouts == 0 and res.republished == 0, notes
        assert res.compile_waited >= 1.5
        assert any("is compiling its kernels: waiting" in n for n in notes), notes
    else:
        assert res.timeouts >= 1 and res.compile_waited == 0, notes


def test_play_counts_rig_frames_as_the_rig_node(tmp_path, ros_domain, capsys):
    """``play`` of a rig bag prints its camera frames and the rig frames they form, the count
    of the rig node's own grouping (``Localizer`` through ``replay``: its ``rig_frames``)."""
    from rs_localizer.ros.bags.replay import replay

    bag = tmp_path / "rig"
    assert cli(["make-bag", str(bag), "--rig", "3", "--frames", "5", "--quiet"]) == 0
    capsys.readouterr()
    assert cli(["play", str(bag), "--rate", "0", "--wait", "0"]) == 0
    out = capsys.readouterr().out
    n_rig = replay(bag, progress=None).camera_counts["rig"]["rig_frames"]
    assert n_rig == 5
    assert "15 camera frames" in out and f"({n_rig} rig frames: the camera frames grouped" in out


def test_plays_preloaded_messages_without_a_bag(imu_bag, ros_context):
    """``messages`` without a bag directory (``path`` None, as the benchmarks pass them): every
    message is published, the frames reach a subscriber."""
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2

    from rs_localizer.ros.bags.bag_io import iter_messages
    from rs_localizer.ros.bags.play import play

    topics = ["/camera/camera_info", "/camera/correspondences"]
    msgs = list(iter_messages(imu_bag, topics))
    node = rclpy.create_node("play_test_listener", context=ros_context)
    qos = QoSProfile(depth=500, reliability=ReliabilityPolicy.RELIABLE)
    got = []
    node.create_subscription(PointCloud2, topics[1], got.append, qos)
    with spinning(ros_context, node):
        res = play(
            None, messages=msgs, rate=100.0, context=ros_context, wait_subscribers=20.0, log=print
        )
        deadline = time.monotonic() + 5.0
        while len(got) < 5 and time.monotonic() < deadline:
            time.sleep(0.05)
    assert res.published == len(msgs) > 5 and res.rig_frames == 0
    assert len(got) == 5


def test_play_a_recording_of_a_rigs_cameras_with_the_rig_nodes_parameters(
    tmp_path, ros_domain, capsys
):
    """A recording of a rig's cameras (no sequence.json, topics ``/<camera>/...``) plays as a
    rig bag with the rig node's parameter file: lock-step into the rig node (root namespace)
    waits for ``/pose`` after each camera frame completing a rig frame, and every rig frame is
    answered; without the file it is a camera's bag, and parameters naming no rig are
    refused."""
    from helpers.rig_bags import recording_of

    from rs_localizer.ros.process import NodeProcess, ros_env, write_params_yaml

    bag = tmp_path / "rig"
    assert cli(["make-bag", str(bag), "--rig", "2", "--frames", "8", "--quiet"]) == 0
    rec, params = recording_of(bag, tmp_path / "recording", tmp_path / "rig.yaml")
    capsys.readouterr()
    assert cli(["play", str(rec), "--rate", "0", "--wait", "0"]) == 0
    out = capsys.readouterr().out
    assert "16 frames" in out and "rig frames" not in out
    assert cli(["play", str(rec), "--rate", "0", "--wait", "0", "-p", "publish_tf:=false"]) == 2
    assert "name none" in capsys.readouterr().err
    overlay = write_params_yaml(tmp_path / "overlay.yaml", {"publish_tf": False})
    node = NodeProcess([params, overlay], namespace="", env=ros_env(), log=tmp_path / "n.log")
    try:
        assert node.wait_ready(120.0), node.log
        code = cli(["play", str(rec), "--lockstep", "--params-file", str(params),
                    "--timeout", "10"])  # fmt: skip
        out = capsys.readouterr().out
    finally:
        alive, rc = node.alive(), node.stop()
    assert alive and rc == 0, node.log
    assert code == 0, out
    assert "16 camera frames" in out and "(8 rig frames: the camera frames grouped" in out
    assert "8 rig frames completed in 8 waits answered, 0 timed out" in out
