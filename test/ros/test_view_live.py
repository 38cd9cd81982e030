"""The live view end to end, as a user watches a localizer from the Foxglove app: a real node
localizing the sample images bag (played to it in lock-step over DDS), and the bag that
``rs-localizer replay --out --debug-outputs`` writes (played with ``play``), each served by
``rs-localizer view``'s Foxglove WebSocket server to a client that speaks the Foxglove WebSocket
protocol (``helpers.foxglove_ws``; the Foxglove SDK's server names it ``foxglove.sdk.v1``
and refuses a client that offers only the older name ``foxglove.websocket.v1``), and
``rs-localizer diagnostics`` following the node's ``/diagnostics`` live.

Checked against an independent computation: the poses (and the path's poses) that arrive over
the WebSocket, decoded from CDR with their advertised type, are those ``replay`` computes
offline on the same bag with the same parameters (to 1e-12 relative, as
``test_node_replay.py``); the debug image is the replay's drawing of the same frame; the
layout ``foxglove/rs_localizer.json`` names only channels the server advertises, for the node
and the replay bag alike."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("rosbags")

from helpers.foxglove_ws import FoxgloveClient, layout_topics
from helpers.paths import CONFIG, IMAGES_CONFIG, ROOT
from helpers.ros import start_node

#: slow: a node, a replay and two plays of 20 images
pytestmark = pytest.mark.slow

NS = "/live"
FRAME_TOPIC = "/camera/image_raw"
#: the Foxglove WebSocket protocol v1: the names a client offers, the one the SDK's server takes
OFFERED = ("foxglove.websocket.v1", "foxglove.sdk.v1")
PROTOCOL = "foxglove.sdk.v1"
#: the channels the Foxglove app shows (the layout's names) -> their ROS 2 types
CHANNELS = {
    "/camera/pose": "geometry_msgs/msg/PoseStamped",
    "/camera/path": "nav_msgs/msg/Path",
    "/camera/markers": "visualization_msgs/msg/MarkerArray",
    "/camera/debug_image": "sensor_msgs/msg/Image",
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
}
REPLAY_OUTPUTS = ("pose", "path", "markers", "debug_image")


def _ctrl_c_stops() -> None:
    """(In the child before it runs:) SIGINT at its default, so that Ctrl-C stops the command as
    in a terminal even when the tests run with SIGINT ignored (a background job of a
    non-interactive shell passes that on to every process it starts)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _need_foxglove():
    from rs_localizer.ros.view import foxglove_available

    if not foxglove_available():
        pytest.skip("foxglove-sdk not installed (the 'view' extra)")


def _setup(bag):
    """The node's parameter files and overrides on the images bag (as the demo runs it)."""
    from rs_localizer.ros.bags.bag_io import read_bag_info

    rs = read_bag_info(bag)["rs"]
    params = {
        "frontend": "aruco",
        "frontend_map": str((bag / "markers.yaml").resolve()),
        "rs.line_delay": float(rs["line_delay"]),
        "rs.readout_time": 0.0,
        "rs.stamp_row": float(rs["stamp_row"]),
    }
    return [CONFIG, IMAGES_CONFIG], params


def _stamp(msg) -> int:
    """A message's header stamp (ns); a MarkerArray's: its first marker's."""
    h = msg.header if hasattr(msg, "header") else msg.markers[0].header
    return int(h.stamp.sec) * 1_000_000_000 + int(h.stamp.nanosec)


def _pose_values(p) -> np.ndarray:
    a, q = p.position, p.orientation
    return np.array([a.x, a.y, a.z, q.x, q.y, q.z, q.w])


def _same_pose(a, b) -> bool:
    """The same pose to 1e-12 relative to the values' magnitude (at least 1)."""
    x, y = _pose_values(a), _pose_values(b)
    return bool(np.all(np.abs(x - y) <= 1e-12 * np.maximum(np.abs(x), 1.0)))


def _msg_class(type_name: str):
    pkg, _, typ = type_name.split("/")
    return getattr(__import__(f"{pkg}.msg", fromlist=[typ]), typ)


def _decode(payload: bytes, type_name: str):
    from rclpy.serialization import deserialize_message

    return deserialize_message(payload, _msg_class(type_name))


@pytest.fixture(scope="module")
def offline(tmp_path_factory, sample_images_bag):
    """``replay --out --debug-outputs`` on the images bag: the out bag, and its messages by
    output name and stamp (rosbags' classes)."""
    from rs_localizer.ros.bags.bag_io import iter_messages, typestore
    from rs_localizer.ros.bags.replay import replay

    files, params = _setup(sample_images_bag)
    out = tmp_path_factory.mktemp("replay") / "out"
    res = replay(
        sample_images_bag,
        params_files=files,
        params=params,
        out_bag=out,
        progress=None,
        debug_outputs=True,
    )
    ts = typestore()
    msgs: dict = {n: {} for n in REPLAY_OUTPUTS}
    topics = {f"/rs_localizer/{n}" for n in REPLAY_OUTPUTS}
    for topic, mt, _, raw in iter_messages(out, topics):
        m = ts.deserialize_cdr(raw, mt)
        msgs[topic.rsplit("/", 1)[1]].setdefault(_stamp(m), m)
    assert res.solved == len(res.rows) == len(msgs["pose"]) > 10
    return out, msgs, len(res.rows)


class _Poller:
    """Read a client's WebSocket on a thread (messages do not wait in the socket)."""

    def __init__(self, client: FoxgloveClient):
        self.client, self.stop, self.error = client, threading.Event(), None
        self.th = threading.Thread(target=self._run, daemon=True)
        self.th.start()

    def _run(self):
        try:
            while not self.stop.is_set():
                self.client.poll(0.1)
        except Exception as e:  # (reported by the test)
            self.error = e

    def join(self):
        self.stop.set()
        self.th.join(10.0)


def _connect(view) -> tuple[FoxgloveClient, dict]:
    """A client offering both names of the protocol (:data:`OFFERED`), after the server's
    advertisement of every channel of :data:`CHANNELS`; returns it and what it saw (protocol,
    server info, channels)."""
    client = FoxgloveClient(view.port, protocols=OFFERED)
    client.wait_channels(list(CHANNELS), timeout=20.0)
    deadline = time.monotonic() + 5.0
    while client.server_info is None and time.monotonic() < deadline:
        client.poll(0.1)
    seen = {
        "protocol": client.protocol,
        "server_info": client.server_info,
        "channels": dict(client.channels),
    }
    return client, seen


def _wait(pred, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while not pred() and time.monotonic() < deadline:
        time.sleep(0.1)
    return pred()


@pytest.fixture(scope="module")
def node_live(tmp_path_factory, ros_domain, sample_images_bag):
    """A node in /live localizing the images bag played in lock-step, ``rs-localizer view --ns
    /live`` serving it to a Foxglove client subscribed to every channel of :data:`CHANNELS`,
    and ``rs-localizer diagnostics --ns /live`` running meanwhile (stopped by Ctrl-C)."""
    _need_foxglove()
    import rclpy

    from rs_localizer.ros.bags.play import play
    from rs_localizer.ros.process import ros_env
    from rs_localizer.ros.view import ViewServer

    files, params = _setup(sample_images_bag)
    tmp = tmp_path_factory.mktemp("live")
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=ros_domain)
    node = start_node(
        tmp, {**params, "diagnostics_period": 0.5}, namespace=NS, name="live", config=files
    )
    lines: list = []
    diag_lines: list = []
    diag = None
    try:
        with ViewServer(ctx, ns=NS, port=0, log=lines.append) as view:
            client, seen = _connect(view)
            try:
                client.subscribe(list(CHANNELS))
                # the view's ROS subscriptions exist and see the node's publishers
                assert _wait(
                    lambda: all(
                        view.node.count_publishers(f"{NS}/{n}") >= 1
                        and view.node.count_subscribers(f"{NS}/{n}") >= 1
                        for n in ("pose", "path", "markers", "debug_image")
                    ),
                    30.0,
                ), (lines, node.log)
                poller = _Poller(client)
                diag = subprocess.Popen(
                    [sys.executable, "-m", "rs_localizer", "diagnostics", "--ns", NS],
                    cwd=ROOT,
                    env=ros_env(),
                    stdout=subprocess.PIPE,
                    stderr=subprocess.STDOUT,
                    text=True,
                    preexec_fn=_ctrl_c_stops,
                )
                reader = threading.Thread(
                    target=lambda: diag_lines.extend(iter(diag.stdout.readline, "")), daemon=True
                )
                reader.start()
                assert _wait(lambda: diag_lines, 60.0), "rs-localizer diagnostics printed nothing"
                res = play(
                    sample_images_bag,
                    lockstep=True,
                    topics=[FRAME_TOPIC, "/camera/camera_info"],
                    remap={FRAME_TOPIC: f"{NS}/image", "/camera/camera_info": f"{NS}/camera_info"},
                    output_topics=(f"{NS}/pose",),
                    context=ctx,
                    timeout=10.0,
                    retries=0,
                    log=lambda *_: None,
                )
                time.sleep(2.0)  # (the last drawings, and statuses after the last frame)
                poller.join()
                diag.send_signal(signal.SIGINT)
                diag_rc = diag.wait(30)
                reader.join(10.0)
            finally:
                client.close()
    finally:
        if diag is not None and diag.poll() is None:
            diag.kill()
        alive, rc = node.alive(), node.stop()
        rclpy.try_shutdown(context=ctx)
    assert alive and rc == 0, node.log
    assert poller.error is None, poller.error
    return {
        **seen,
        "messages": list(client.messages),
        "played": res,
        "view_log": lines,
        "diagnostics": "".join(diag_lines),
        "diagnostics_rc": diag_rc,
    }


@pytest.fixture(scope="module")
def bag_live(offline, ros_domain):
    """The replay's out bag played with ``play`` and served by ``rs-localizer view --ns
    /rs_localizer``, a Foxglove client subscribed to its outputs."""
    _need_foxglove()
    import rclpy

    from rs_localizer.ros.bags.play import play
    from rs_localizer.ros.view import ViewServer

    out, _, _ = offline
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=ros_domain)
    lines: list = []
    try:
        with ViewServer(ctx, ns="/rs_localizer", port=0, log=lines.append) as view:
            client, seen = _connect(view)
            try:
                wanted = [f"/camera/{n}" for n in REPLAY_OUTPUTS]
                client.subscribe(wanted)
                assert _wait(
                    lambda: all(
                        view.node.count_subscribers(f"/rs_localizer/{n}") >= 1
                        for n in REPLAY_OUTPUTS
                    ),
                    30.0,
                ), lines
                poller = _Poller(client)
                # (slowed down: what goes out before DDS matched the view is lost)
                play(
                    out,
                    topics=[f"/rs_localizer/{n}" for n in REPLAY_OUTPUTS],
                    rate=0.25,
                    context=ctx,
                    log=lambda *_: None,
                )
                time.sleep(1.0)
                poller.join()
            finally:
                client.close()
    finally:
        rclpy.try_shutdown(context=ctx)
    assert poller.error is None, poller.error
    return {**seen, "messages": list(client.messages), "view_log": lines}


def _received(live: dict, topic: str) -> list:
    return [_decode(p, CHANNELS[topic]) for t, _, p in live["messages"] if t == topic]


def test_the_foxglove_app_connects_and_sees_every_channel(node_live):
    """The server takes the protocol as foxglove.sdk.v1, names itself, and advertises pose,
    path, markers, debug image and diagnostics with their ROS 2 schemas (CDR, ros2msg)."""
    assert node_live["protocol"] == PROTOCOL
    assert node_live["server_info"]["name"] == "rs_localizer"
    for topic, type_name in CHANNELS.items():
        ch = node_live["channels"][topic]
        assert (ch["encoding"], ch["schemaEncoding"], ch["schemaName"]) == (
            "cdr",
            "ros2msg",
            type_name,
        )
        # the schema's first definition is the message's: every field of the rclpy class
        main = ch["schema"].split("\n===")[0]
        fields = _msg_class(type_name).get_fields_and_field_types()
        for name in fields:
            assert re.search(rf"^\S+ {name}\b", main, re.M), (topic, name, main)


def test_the_nodes_pose_arrives_as_replay_computes_it(node_live, offline):
    """Every frame's pose arrives over the WebSocket and decodes to the pose ``replay``
    computes for that stamp, and so does every pose of every path that arrives; the played
    frames were all answered."""
    _, expected, n = offline
    played = node_live["played"]
    assert played.timeouts == 0 and played.answered == len(played.frames) == n
    poses = _received(node_live, "/camera/pose")
    # (subscribed and matched before the first frame, reliable: every frame's pose arrives)
    assert sorted(_stamp(m) for m in poses) == sorted(expected["pose"]), node_live["view_log"]
    for m in poses:
        want = expected["pose"][_stamp(m)]
        assert m.header.frame_id == want.header.frame_id
        assert _same_pose(m.pose, want.pose), (_stamp(m), m.pose, want.pose)
    paths = _received(node_live, "/camera/path")
    assert paths, node_live["view_log"]
    for path in paths:
        assert path.poses
        for p in path.poses:
            assert _same_pose(p.pose, expected["pose"][_stamp(p)].pose)
    # the last path holds the last frames, as the replay's last path
    last = max(paths, key=_stamp)
    assert [_stamp(p) for p in last.poses] == [
        _stamp(p) for p in expected["path"][max(expected["path"])].poses
    ]


def test_the_nodes_drawings_and_status_arrive(node_live, offline):
    """The markers, the debug image (the replay's drawing of the same frame, byte for byte)
    and the node's diagnostics arrive and decode."""
    _, expected, n = offline
    arrays = _received(node_live, "/camera/markers")
    assert arrays and all(a.markers for a in arrays)
    images = _received(node_live, "/camera/debug_image")
    assert images, node_live["view_log"]
    for img in images:
        want = expected["debug_image"][_stamp(img)]
        assert (img.width, img.height, img.encoding) == (want.width, want.height, want.encoding)
        assert bytes(img.data) == bytes(want.data)
    statuses = [
        s
        for a in _received(node_live, "/diagnostics")
        for s in a.status
        if s.name == f"rs_localizer: {NS}/rs_localizer"
    ]
    assert statuses
    last = {kv.key: kv.value for kv in statuses[-1].values}
    assert int(last["frames_received"]) == n


def test_the_layout_shows_what_the_view_advertises(node_live, bag_live):
    """Every topic the shipped layout reads is a channel the server advertises, for a node and
    for a played replay bag alike."""
    layout = layout_topics(json.loads((ROOT / "foxglove" / "rs_localizer.json").read_text()))
    assert set(CHANNELS) <= set(layout)
    for live in (node_live, bag_live):
        missing = set(layout) - set(live["channels"])
        assert not missing, (sorted(missing), sorted(live["channels"]))


def test_the_replay_bag_is_served_as_the_node(bag_live, offline):
    """The replay bag's /rs_localizer/<name> played arrive as the layout's /camera/<name>:
    each pose is the bag's pose of that stamp, the drawings arrive too."""
    _, expected, _ = offline
    assert bag_live["protocol"] == PROTOCOL
    poses = _received(bag_live, "/camera/pose")
    assert poses, bag_live["view_log"]
    for m in poses:
        assert _same_pose(m.pose, expected["pose"][_stamp(m)].pose)
    for topic in ("/camera/path", "/camera/markers", "/camera/debug_image"):
        assert _received(bag_live, topic), (topic, bag_live["view_log"])


def test_diagnostics_command_follows_the_running_node(node_live, offline):
    """``rs-localizer diagnostics --ns /live`` prints the node's status as it changes: a block
    per status, the frame counters rising to the frames played, received = solved + failed +
    skipped + pending, and Ctrl-C ends it with code 0."""
    _, _, n = offline
    out = node_live["diagnostics"]
    assert node_live["diagnostics_rc"] == 0, out
    heads = [ln for ln in out.splitlines() if re.match(r"\d\d:\d\d:\d\d\.\d \[", ln)]
    assert len(heads) >= 2, out
    assert all(f"rs_localizer: {NS}/rs_localizer" in h for h in heads), out
    blocks = re.split(r"(?m)^\d\d:\d\d:\d\d\.\d \[.*$", out)[1:]
    counts = []
    for b in blocks:
        kv = dict(re.findall(r"(\w+)=(\S+)", b))
        counts.append({k: int(kv[k]) for k in kv if k.startswith("frames_") and kv[k].isdigit()})
    received = [c["frames_received"] for c in counts]
    assert received == sorted(received) and received[-1] == n, received
    assert received[0] < n  # (it printed while the frames came in)
    c = counts[-1]
    assert c["frames_received"] == (
        c["frames_solved"] + c["frames_failed"] + c["frames_skipped"] + c["frames_pending"]
    ), c


def test_a_client_offering_only_the_old_protocol_name_is_refused(ros_context):
    """The Foxglove SDK's server takes the protocol only as ``foxglove.sdk.v1``: a client
    offering only ``foxglove.websocket.v1`` (the same protocol under its older name) gets HTTP
    400, as docs/node.md says."""
    _need_foxglove()
    from rs_localizer.ros.view import ViewServer

    with ViewServer(ros_context, ns="/old", port=0) as view:
        with pytest.raises(OSError, match="400"):
            FoxgloveClient(view.port, protocols=("foxglove.websocket.v1",))
        client = FoxgloveClient(view.port, protocols=("foxglove.sdk.v1",))
        try:
            assert client.protocol == PROTOCOL
        finally:
            client.close()
