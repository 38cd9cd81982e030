"""Play a bag into the live ROS 2 graph (rclpy): original timing scaled by ``rate``, or
lock-step (wait for each frame's output before sending the next).

Images (``sensor_msgs/Image``, ``CompressedImage``) go out with the sensor-data QoS camera
drivers use (best effort), the other topics reliable by default. When a camera namespace has
frames on several topics (``make-bag`` writes ``correspondences`` and ``keypoints`` of the same
frames; a rendered bag may add the image), only one of them is played, the one the node can use
(:func:`choose_frame_topics`), unless ``topics`` names them.

A rig bag (``make-bag --rig``, ``render-bag --rig``: cameras ``<ns>/<camera>/...``) is played
the same way, every camera's topics in log-time order; in lock-step the player waits for the
rig's ``<ns>/pose`` after each camera frame that completes a rig frame in the rig mode
(:func:`rig_frame_grouping`), and sends the other cameras' frames without waiting."""

from __future__ import annotations

import heapq
import importlib
import itertools
import os
import re
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .. import conversions as cv
from .bag_io import (
    CAMERA_INFO,
    COMPRESSED_IMAGE,
    IMAGE,
    IMU,
    PC2,
    POSE,
    TWIST,
    bag_topics,
    iter_messages,
)

__all__ = [
    "SOURCES",
    "PlayResult",
    "choice_is_final",
    "choose_frame_topics",
    "is_frame_topic",
    "output_type",
    "play",
    "rig_frame_grouping",
]

FRAME_TOPIC_SUFFIXES = ("correspondences", "keypoints")  # + every sensor_msgs/Image topic
#: ``play(source=...)``: what a camera namespace with several frame topics sends
SOURCES = ("auto", "image", "correspondences")
#: choosing the frames (:func:`choose_frame_topics`): a node's subscriptions are discovered one
#: by one (seconds apart on a loaded machine); the choice waits until the subscribed frame
#: topics stayed the same this long (s), unless no subscription found later could change it
#: (:func:`choice_is_final`)
SETTLE_S = 1.0
#: ... and at most this long (s) after every camera namespace has a subscriber
SETTLE_CAP_S = 5.0
#: the node's log lines (``/rosout``) that say it starts and ends compiling its kernels
#: (:func:`~rs_localizer.ros.pipeline.log_warm_up`, :mod:`rs_localizer.runtime.jit_cache`)
_COMPILING = re.compile(r"^(warm-up \(.*\): numba cache|compiling )")
_COMPILED = re.compile(
    r"^(warm-up \(.*\): ([\d.]+ s|failed)|kernels compiled and loaded|kernels not compiled)"
)


def output_type(topic: str) -> type:
    """Message class of a node output topic, by its name."""
    from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, TwistStamped
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import PointCloud2

    last = topic.rstrip("/").rsplit("/", 1)[-1]
    return {
        "twist": TwistStamped,
        "twist_single_frame": TwistStamped,
        "odom": Odometry,
        "pose_with_covariance": PoseWithCovarianceStamped,
        "correspondences_out": PointCloud2,
    }.get(last, PoseStamped)


def _msg_class(msgtype: str):
    pkg, kind, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{pkg}.{kind}"), name)


@dataclass
class PlayResult:
    """Outcome of :func:`play`: per frame the input stamp, publish time (monotonic s), outputs
    received (``{pose_topic: (recv_time, msg)}``) and the summary counters."""

    frames: list = field(default_factory=list)
    published: int = 0
    answered: int = 0
    timeouts: int = 0
    wall_time: float = 0.0
    #: lock-step: frames sent again because no output came within the timeout
    republished: int = 0
    #: frame topics of the bag left out (another topic carries the same frames)
    skipped_topics: list = field(default_factory=list)
    #: lock-step: why playing stopped before the end (no node answered), else ""
    gave_up: str = ""
    #: a rig bag in lock-step: the rig frames the frames sent completed, grouped as the rig
    #: node groups them (:func:`rig_frame_grouping`), else 0
    rig_frames: int = 0
    #: a rig bag: the rig frames its camera frames form in all (the node's ``rig_frames``
    #: after the whole bag), else 0
    rig_frames_in_bag: int = 0
    #: lock-step: seconds waited beyond the timeouts for a node compiling its kernels
    compile_waited: float = 0.0

    @property
    def latencies(self) -> np.ndarray:
        """Publish -> first output (s) per answered frame (the slowest pose topic)."""
        out = []
        for f in self.frames:
            if f["outputs"] and len(f["outputs"]) == f["expected"]:
                out.append(max(t for t, _ in f["outputs"].values()) - f["t_pub"])
        return np.array(out)


def is_frame_topic(topic: str, msgtype: str | None = None) -> bool:
    """A topic carrying one frame per message: ``*/correspondences``, ``*/keypoints`` or an
    image (``sensor_msgs/msg/Image`` or ``CompressedImage``)."""
    last = topic.rstrip("/").rsplit("/", 1)[-1]
    return last in FRAME_TOPIC_SUFFIXES or msgtype in (IMAGE, COMPRESSED_IMAGE)


def _parent(topic: str) -> str:
    """Camera namespace of a frame topic (``/cam/image/compressed`` -> ``/cam``)."""
    t = topic.rstrip("/")
    if t.endswith("/compressed"):
        t = t[: -len("/compressed")]
    return t.rsplit("/", 1)[0]


def live_topic(topic: str, remap: Mapping[str, str]) -> str:
    """The topic a bag topic is published on: ``remap[topic]`` when given, else the topic
    moved into the namespace ``remap["__ns"]`` when given (``/camera/image`` with
    ``__ns:=/robot`` -> ``/robot/camera/image``), else the topic itself."""
    if topic in remap:
        return remap[topic]
    ns = remap.get("__ns", "").rstrip("/")
    return f"{ns}{topic}" if ns else topic


def pose_topic_of(frame_topic: str, remap: Mapping[str, str], rig: bool = False) -> str:
    """The node's pose topic answering a bag frame topic: ``pose`` in the namespace the frame
    is published into (``/camera/image_raw`` remapped to ``/robot/cam/image_raw`` ->
    ``/robot/cam/pose``); ``rig``: in the namespace above the camera's (the rig node's:
    ``/rig/front/correspondences`` -> ``/rig/pose``)."""
    parent = _parent(live_topic(frame_topic, remap))
    return f"{_parent(parent) if rig else parent}/pose"


def choose_frame_topics(
    frame_topics: dict, subscribed: set, source: str = "auto"
) -> tuple[list, list]:
    """The frame topic to play in each camera namespace, and the ones left out.

    ``frame_topics``: ``{topic: msgtype}`` of the bag's frame topics; ``subscribed``: those with
    a live subscriber. Per namespace (the topic's parent) one topic is kept, the first of
    (``source`` ``auto``): an image with a subscriber (the node runs an image front end),
    ``correspondences`` (needs nothing else), a compressed or raw image, ``keypoints`` (needs
    the node's ``landmarks_file``); ``image``: an image with a subscriber, any image, then as
    ``auto``; ``correspondences``: ``correspondences``, ``keypoints``, then the images.
    Returns ``(kept, skipped)`` topic lists.
    """

    def rank(t):
        mt = frame_topics[t]
        image = mt in (IMAGE, COMPRESSED_IMAGE)
        last = t.rstrip("/").rsplit("/", 1)[-1]
        if source == "correspondences":
            return {"correspondences": 0, "keypoints": 1}.get(last, 2 if t in subscribed else 3)
        if image and t in subscribed:
            return 0
        if image and source == "image":
            return 1
        if last == "correspondences":
            return 2
        if image:
            return 3
        return 4

    groups = {}
    for t in frame_topics:
        groups.setdefault(_parent(t), []).append(t)
    kept, skipped = [], []
    for ts in groups.values():
        best = min(ts, key=lambda t: (rank(t), t))
        kept.append(best)
        skipped += [t for t in ts if t != best]
    return kept, skipped


def choice_is_final(frame_topics: dict, subscribed: set, source: str = "auto") -> bool:
    """Whether :func:`choose_frame_topics` keeps the same topics whichever other frame topics
    are found subscribed later (``auto``: e.g. an image with a subscriber in every namespace
    that has an image, or a bag without images; ``frame_topics``, ``subscribed``, ``source``
    as there). A topic's rank depends only on whether it is subscribed itself, so trying the
    other topics one at a time is enough: topics that together changed a namespace's choice
    would change it with the one that wins alone."""
    kept = set(choose_frame_topics(frame_topics, subscribed, source)[0])
    return all(
        set(choose_frame_topics(frame_topics, subscribed | {t}, source)[0]) == kept
        for t in set(frame_topics) - subscribed
    )


def _bag_stream(
    path: str | os.PathLike,
    wanted: set[str],
    types: Mapping[str, str],
    imu_lead_ns: int,
) -> Iterator[tuple[str, str, int, bytes]]:
    """The bag's messages on the ``wanted`` topics, read as they are sent (never the whole bag
    in memory), in log-time order; ``imu_lead_ns`` > 0: the ``sensor_msgs/Imu`` topics that
    far ahead (two readers merged)."""
    imu = {t for t in wanted if types[t] == IMU}
    if imu_lead_ns <= 0 or not imu:
        yield from iter_messages(path, wanted)
        return
    rest = iter_messages(path, wanted - imu) if wanted - imu else iter(())
    yield from heapq.merge(
        rest,
        iter_messages(path, imu),
        key=lambda m: m[2] - imu_lead_ns if m[1] == IMU else m[2],
    )


def rig_frame_grouping(bag: str | os.PathLike, params_files: Iterable[str | os.PathLike] = (),
                       params: Mapping[str, Any] | None = None) -> tuple[dict, int]:  # fmt: skip
    """Which camera frames of a rig bag complete a rig frame when played in log-time order
    into the rig mode (what ``play --lockstep`` waits after): the frames read as the rig node
    reads them (:func:`~rs_localizer.ros.bags.bag_frames.read_rig_frames`), handed on as it
    hands them (:func:`~rs_localizer.ros.camera_input.to_rig`) to the rig's own grouping,
    without solving (:class:`~rs_localizer.tracking.video.GroupingOnly`: by reference-line
    time within ``rig.window``; a frame before its camera's first camera_info, out of order
    or late joins no rig frame; a cloud not read but stamped counts as the camera's frame
    at that time).

    Returns:
        ``({(camera name, header stamp ns): number of rig frames its arrival completes}``
        (frames completing none left out, and the rig frames still open at the end), the
        number of rig frames formed in all, the open ones included (the rig node's
        ``rig_frames`` once it closes them)).
    Raises:
        ValueError: no ``rig.cameras`` or parameters the rig node refuses (as
        :func:`~rs_localizer.ros.bags.bag_frames.read_rig_frames`).
    """
    from ...tracking.video import GroupingOnly
    from ..camera_input import to_rig
    from .bag_frames import read_rig_frames

    read = read_rig_frames(bag, params_files, params)
    rig = GroupingOnly(read.settings)
    out: dict[tuple[str, int], int] = {}
    for f in read.items:
        done = len(to_rig(rig, f))
        if done:
            out[(f.camera_name, f.stamp_ns)] = out.get((f.camera_name, f.stamp_ns), 0) + done
    return out, int(rig.counts["rig_frames"])


def _rig_grouping(path, params_files: list, params: Mapping[str, Any] | None) -> tuple:
    """A rig bag's ``(namespace of its cameras' topics, future of its rig frame grouping)``
    (:func:`rig_frame_grouping`, with the rig node's parameter files and parameters): the
    grouping is read on another thread, beside the first messages
    sent, since it reads the whole bag."""
    from concurrent.futures import ThreadPoolExecutor

    from .bag_frames import rig_parameter_values
    from .bag_io import rig_namespace

    cameras = rig_parameter_values(path, params_files, params)[0]["rig.cameras"]
    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="rig_grouping")
    ns = rig_namespace(path, [str(n) for n in cameras or ()])
    grouping = (ns, pool.submit(rig_frame_grouping, path, params_files, params))
    pool.shutdown(wait=False)
    return grouping


def play(
    path: str | os.PathLike | None,
    *,
    rate: float = 1.0,
    lockstep: bool = False,
    topics: Iterable[str] | None = None,
    remap: Mapping[str, str] | None = None,
    output_topics: Sequence[str] | None = None,
    timeout: float = 2.0,
    retries: int = 1,
    wait_subscribers: float = 30.0,
    reliable: bool = True,
    context: Any = None,
    domain_id: int | None = None,
    limit: int | None = None,
    loop: int = 1,
    stamp_offset_ns: int = 0,
    messages: list[tuple[str, str, int, bytes]] | None = None,
    on_frame: Callable[[dict], None] | None = None,
    log: Callable[[str], Any] = print,
    late_topics: Iterable[str] = (),
    imu_lead: float = 0.1,
    give_up: int = 3,
    source: str = "auto",
    compile_wait: float = 600.0,
    params_files: Iterable[str | os.PathLike] = (),
    params: Mapping[str, Any] | None = None,
) -> PlayResult:
    """Publish a bag into the ROS graph.

    Args:
        path: bag directory. Its messages are read while they are sent (the first one goes out
            as soon as the node is found, whatever the bag's size). None with ``messages``.
        rate: time scale of the original timing (ignored in lock-step).
        lockstep: after each frame (a ``*/correspondences``, ``*/keypoints`` or image message) wait
            until every ``output_topics`` topic delivered a message stamped within 1 s of the
            frame, or ``timeout``; then republish it up to ``retries`` times (a best-effort
            subscription may drop a sample) before moving on, counted in
            ``PlayResult.timeouts`` and reported through ``log``. While the node says it
            compiles its kernels (its log on ``/rosout``, ``compile_state`` on
            ``/diagnostics``) the wait goes on, up to ``compile_wait`` s in all.
            A rig bag (:func:`~rs_localizer.ros.bags.bag_frames.is_rig_bag`) waits only after the
            camera frames that complete a rig frame (:func:`rig_frame_grouping`), for the
            rig's pose (``<ns>/pose``; ``PlayResult.rig_frames`` counts them).
        topics: only these bag topics (default: all). remap: ``{bag_topic: live_topic}``;
            the key ``__ns`` moves every other bag topic into that namespace
            (:func:`live_topic`).
        source: which frames a camera namespace with several frame topics sends: ``auto``
            (what the node listens to: the images when it subscribes an image topic in that
            namespace, i.e. runs a front end; else the correspondences), ``image`` or
            ``correspondences`` (:func:`choose_frame_topics`), chosen once the node's
            subscriptions have settled (at once when no subscription found later could change
            the choice, :func:`choice_is_final`; else after :data:`SETTLE_S` s without a
            change, at most :data:`SETTLE_CAP_S` s). In every mode a bag image topic
            nobody subscribes is published on the node's image topic of the same namespace and
            type (``/camera/image_raw`` as ``/camera/image``), unless ``remap`` names it.
        output_topics: the node's outputs to wait for in lock-step. Default: each frame waits
            for the ``pose`` topic of the namespace it is published into
            (:func:`pose_topic_of`: remaps and ``__ns`` followed).
        wait_subscribers: seconds to wait until every frame topic has a subscriber (longer
            while the node compiles). A managed node found not active meanwhile is named
            through ``log``, with the command that activates it.
        reliable: publish with reliable QoS (depth 10); else best effort. Images go out with
            the sensor-data QoS (best effort, depth 5) of camera drivers, or as ``reliable``
            says when a subscriber asks for reliable images (which a best-effort publisher
            does not match).
        context: an ``rclpy.Context`` (initialized here if needed and shut down at the end if
            it was created here). domain_id: ROS domain for a context created here.
        limit: stop after this many frames. loop: play the bag this many times (frame stamps
            are shifted forward by the bag duration so they keep increasing).
        stamp_offset_ns: added to every header stamp (replaying a bag into a running node).
        messages: preloaded ``iter_messages`` list (benchmarks). on_frame: callback(frame dict).
        late_topics: output topics (among ``output_topics``) that may be published after later
            frames (the node's fused twist and odom with ``tracking.lag`` > 0): lock-step does
            not wait for them; each message goes to the frame with the nearest header stamp
            (within 1 s), and at the end the player waits up to ``timeout`` for the missing
            ones. Other outputs go to the frame being waited for, as before.
        imu_lead: lock-step: ``sensor_msgs/Imu`` messages go out this many seconds of bag time
            ahead of the frames (a node using the gyro waits for the samples covering a
            frame's readout, which would otherwise come only after the frame was answered).
            Each IMU message is sent once (never primed nor republished: a repeated sample
            would be rejected by the node as not increasing).
        give_up: lock-step: stop after this many frames in a row without any answer while no
            frame has been answered yet (the node is not running, not active, or answers on
            another topic); ``PlayResult.gave_up`` and ``log`` say why: a managed node that is
            not active by name, else the pose topics that do have a publisher. Also stop
            before the first frame when, after ``wait_subscribers``, a node takes the frames
            but none publishes a waited topic. 0: never give up.
        compile_wait: lock-step: the longest wait (s) for a node that compiles.
        params_files, params: the rig node's parameter files and parameters (``rig.cameras``,
            ``rig.window``, ...), over a rig bag's ``rig_params.yaml``: a recording of a rig's
            cameras (no ``sequence.json``) is played as a rig bag when they name
            ``rig.cameras``, and lock-step groups its frames with them.

    When ``topics`` is None and a camera namespace has several frame topics, only the one
    :func:`choose_frame_topics` picks is played (a note through ``log`` names the others and
    the ``--topics`` to pass instead).

    Raises:
        ValueError: an unknown ``source``.
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from .bag_frames import is_rig_bag

    if source not in SOURCES:
        raise ValueError(f"unknown source {source!r}; one of {', '.join(SOURCES)}")
    params_files = list(params_files)
    rig = path is not None and is_rig_bag(path, params_files, params)
    grouping = _rig_grouping(path, params_files, params) if rig else None
    own_context = context is None
    if own_context:
        context = rclpy.Context()
        # (args=[]: the player's own command line, e.g. a `__ns:=NS` remap, is no ROS argument)
        rclpy.init(args=[], context=context, domain_id=domain_id)
    node = rclpy.create_node("rs_localizer_player", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    result = PlayResult()
    try:
        lead = int(imu_lead * 1e9) if lockstep else 0
        if messages is not None:
            msgs = [m for m in messages if topics is None or m[0] in topics]
            if lead > 0:  # (stable: the rest keeps its order)
                msgs = sorted(msgs, key=lambda m: m[2] - lead if m[1] == IMU else m[2])
            types = {}
            for topic, msgtype, _, _ in msgs:
                types.setdefault(topic, msgtype)
        else:
            types = {t: mt for t, mt in bag_topics(path).items() if topics is None or t in topics}
        remap = dict(remap or {})
        user_remapped = set(remap)
        s = _Session(node, executor, remap, types, reliable, result, log)
        late = set(late_topics or ())
        frame_topics = [t for t in s.pubs if is_frame_topic(t, types[t])]
        s.rig, s.grouping = rig, grouping
        s.compile_wait = compile_wait if lockstep else 0.0
        if lockstep:
            s.watch_compiling()
        choose = topics is None and len({_parent(t) for t in frame_topics}) < len(frame_topics)
        s.wait_for_subscribers(frame_topics, choose, (), wait_subscribers, source=source)
        s.publish_images_on_node_topics(frame_topics, user_remapped)
        if choose:
            s.choose_frames(frame_topics, source)
        frame_topics = [t for t in frame_topics if t not in result.skipped_topics]
        if output_topics is None:  # each frame waits for its own namespace's (or rig's) pose
            waited = {t: [pose_topic_of(t, remap, rig and lockstep)] for t in frame_topics}
            output_topics = sorted({p for ps in waited.values() for p in ps})
        else:
            waited = {t: [o for o in output_topics if o not in late] for t in frame_topics}
        if lockstep:
            s.subscribe_outputs(output_topics, late)
            s.wait_for_subscribers(frame_topics, False, output_topics, 2.0, quiet=True)
        if lockstep and give_up > 0:  # the frames are taken, but nobody answers on these
            taken = any(s.pubs[t].get_subscription_count() for t in frame_topics)
            unpublished = [t for t in output_topics if not _published_by_others(node, t)]
            if taken and unpublished:
                result.gave_up = _no_answer_message(
                    node, executor, unpublished, "before the first frame"
                )
                log(f"error: {result.gave_up}")
                return result
        skipped = set(result.skipped_topics)
        if messages is not None:
            msgs = [m for m in msgs if m[0] not in skipped]

            def stream():
                return iter(msgs)

        else:
            wanted = set(types) - skipped

            def stream():
                return _bag_stream(path, wanted, types, lead)

        s.publish_all(
            stream,
            rate=rate,
            lockstep=lockstep,
            waited=waited,
            timeout=timeout,
            retries=retries,
            limit=limit,
            loop=loop,
            stamp_offset_ns=stamp_offset_ns,
            on_frame=on_frame,
            give_up=give_up,
        )
        # let reliable writers flush the tail (and the late outputs of the last frames come)
        s.flush_tail(timeout if lockstep and late else 0.0, late)
        if grouping is not None and (lockstep or grouping[1].exception() is None):
            result.rig_frames_in_bag = grouping[1].result()[1]
    finally:
        executor.remove_node(node)
        node.destroy_node()
        executor.shutdown()
        if own_context:
            rclpy.try_shutdown(context=context)
    return result


def _published_by_others(node: Any, topic: str) -> bool:
    """Whether a node other than the player ``node`` (which publishes the bag's own topics)
    publishes ``topic``."""
    me = (node.get_namespace(), node.get_name())
    infos = node.get_publishers_info_by_topic(topic)
    return any((i.node_namespace, i.node_name) != me for i in infos)


def _not_active(node: Any, executor: Any, live_topics: Iterable[str]) -> dict[str, str]:
    """The managed nodes that are not active (``{full name: state}``), those whose namespace
    holds one of ``live_topics`` if any does, else all of them."""
    from ..lifecycle_client import inactive_nodes

    found = inactive_nodes(node, executor)
    topics = list(live_topics)
    mine = {
        n: st
        for n, st in found.items()
        if any(t.startswith(n.rsplit("/", 1)[0] + "/") for t in topics)
    }
    return mine or found


def _activate_hint(not_active: Mapping[str, str]) -> str:
    """``the managed node /camera/rs_localizer is inactive: activate it with ...``."""
    parts = []
    for name, state in not_active.items():
        steps = ["activate"] if state == "inactive" else ["configure", "activate"]
        cmds = " and ".join(f"rs-localizer lifecycle {name} {st}" for st in steps)
        parts.append(f"the managed node {name} is {state}: {cmds}")
    return "; ".join(parts)


def _subscribed_by_others(node: Any, topic: str) -> bool:
    """Whether a node other than the player ``node`` subscribes ``topic``."""
    me = (node.get_namespace(), node.get_name())
    infos = node.get_subscriptions_info_by_topic(topic)
    return any((i.node_namespace, i.node_name) != me for i in infos)


def _no_answer_message(
    node: Any, executor: Any, topics: Sequence[str], when: str, frame_topics: Iterable[str] = ()
) -> str:
    """Why lock-step stops: no answer on ``topics``; the cause: a managed node that is not
    active (by name, with the commands that activate it); else, when ``topics`` have a
    publisher (the node runs but poses nothing: a rig waiting for a camera), the
    ``frame_topics`` no node subscribes and the diagnostics command; else the pose topics that
    have a publisher in the graph (the namespace the node may run in)."""
    frame_topics = list(frame_topics)
    not_active = _not_active(node, executor, [*topics, *frame_topics])
    if not_active:
        return f"no node answered on {', '.join(topics)} {when}; {_activate_hint(not_active)}"
    if topics and all(_published_by_others(node, t) for t in topics):
        unheard = [t for t in frame_topics if not _subscribed_by_others(node, t)]
        ns = topics[0].rsplit("/", 1)[0] or "/"
        return (
            f"no node answered on {', '.join(topics)} {when}, though a node publishes it: "
            "it takes no frame or poses none"
            + (
                f"; no node subscribes {', '.join(unheard)} (a rig waits for each camera of "
                "rig.cameras until the others' stamps are rig.stop_after ahead)"
                if unheard
                else ""
            )
            + f"; its diagnostics say why: rs-localizer diagnostics --ns {ns} --once"
        )
    poses = sorted(
        name
        for name, kinds in node.get_topic_names_and_types()
        if name.rstrip("/").endswith("/pose")
        and "geometry_msgs/msg/PoseStamped" in kinds
        and _published_by_others(node, name)
    )
    where = (
        f"pose topics with a publisher: {', '.join(poses)} (wait for one with --output-topic, "
        "or play into the node's namespace with --remap FROM:=TO or __ns:=NS)"
        if poses
        else "no pose topic has a publisher: is the node running, and on this ROS_DOMAIN_ID?"
    )
    return f"no node answered on {', '.join(topics)} {when}; {where}"


class _Session:
    """The stages of :func:`play` on one player node: its publishers (one per bag topic), the
    subscriptions to the node's outputs (lock-step), the wait for subscribers, the choice of
    frame topics, publishing and the final flush."""

    def __init__(
        self,
        node: Any,
        executor: Any,
        remap: dict[str, str],
        types: dict[str, str],
        reliable: bool,
        result: PlayResult,
        log: Callable[[str], Any],
    ) -> None:
        from rclpy.event_handler import PublisherEventCallbacks
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        self.node, self.executor, self.remap, self.types = node, executor, remap, types
        self.result, self.log = result, log
        self.qos = QoSProfile(
            depth=10,
            reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        )
        # a reader asking for reliable images does not match the sensor-data publisher: play
        # answers it with a reliable one (match_reliable_image_readers below), so rclpy's
        # "incompatible QoS" warning on the first publisher would be noise
        quiet = PublisherEventCallbacks(incompatible_qos=lambda event: None)
        self._quiet = quiet
        self.pubs = {
            t: (
                self._image_publisher(t)
                if mt in (IMAGE, COMPRESSED_IMAGE)
                else node.create_publisher(_msg_class(mt), live_topic(t, remap), self.qos)
            )
            for t, mt in types.items()
        }
        self.outputs: dict[str, Any] = {}
        self.pending: dict[str, dict | None] = {"frame": None}
        self.reliable_images: set[str] = set()
        #: a rig bag in lock-step: {(camera namespace, header stamp): rig frames completed}
        self.rig_waits: dict | None = None
        #: a rig bag: whether it is one, and ``(namespace, future of its grouping)``
        self.rig = False
        self.grouping: tuple | None = None
        #: lock-step: the longest wait (s) for a node compiling its kernels (0: none)
        self.compile_wait = 0.0
        #: nodes (logger or status name) that said they compile, and the time they said so
        self.compiling: dict[str, float] = {}
        self._told: set[str] = set()

    def watch_compiling(self) -> None:
        """Follow the nodes' log (``/rosout``: the warm-up's and the compile's lines, the
        history a node keeps for late subscribers included) and ``/diagnostics``
        (``compile_state`` ``compiling`` or ``loading``) for a node compiling its kernels."""
        from diagnostic_msgs.msg import DiagnosticArray
        from rcl_interfaces.msg import Log
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

        me = self.node.get_logger().name

        def on_log(msg):
            if msg.name == me:
                return
            if _COMPILED.match(msg.msg):
                self.compiling.pop(msg.name, None)
            elif _COMPILING.match(msg.msg):
                self.compiling[msg.name] = time.monotonic()

        def on_diag(msg):
            for st in msg.status:
                v = {kv.key: kv.value for kv in st.values}
                if "compile_state" not in v:
                    continue
                if v["compile_state"] in ("compiling", "loading"):
                    self.compiling.setdefault(st.name, time.monotonic())
                else:
                    self.compiling.pop(st.name, None)

        rosout = QoSProfile(
            depth=1000,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
        )
        self.node.create_subscription(Log, "/rosout", on_log, rosout)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10)

    def busy_compiling(self) -> bool:
        """Whether a node said it compiles its kernels (and has not said it is done)."""
        return bool(self.compiling)

    def _tell_compiling(self) -> None:
        if "compiling" not in self._told:
            self._told.add("compiling")
            self.log(
                f"note: {', '.join(sorted(self.compiling))} is compiling its kernels: waiting "
                f"(up to {self.compile_wait:.0f} s; `rs-localizer compile` after installing "
                "saves this wait)"
            )

    def _image_publisher(self, topic: str) -> Any:
        """The sensor-data (best effort) publisher of a bag image topic on its live topic."""
        from rclpy.qos import qos_profile_sensor_data

        return self.node.create_publisher(
            _msg_class(self.types[topic]),
            live_topic(topic, self.remap),
            qos_profile_sensor_data,
            event_callbacks=self._quiet,
        )

    def subscribe_outputs(self, output_topics: Sequence[str], late: set[str]) -> None:
        """Lock-step: subscribe to every output topic; a message goes to the frame being
        waited for, or (``late`` topics) to the frame with the nearest stamp (within 1 s)."""
        result, pending = self.result, self.pending

        def make_cb(topic):
            def cb(msg):
                s = cv.stamp_to_ns(msg.header.stamp)
                if topic in late:  # the frame with the nearest stamp
                    fr = min(result.frames[-64:], key=lambda f: abs(f["stamp"] - s), default=None)
                else:
                    fr = pending["frame"]
                if fr is None:
                    return
                if abs(s - fr["stamp"]) < 1_000_000_000 and topic not in fr["outputs"]:
                    fr["outputs"][topic] = (time.perf_counter(), msg)

            return cb

        for t in output_topics:
            self.outputs[t] = self.node.create_subscription(output_type(t), t, make_cb(t), self.qos)

    def _match_reliable_image_readers(self, frame_topics: Sequence[str]) -> None:
        # a subscriber asking for reliable images (a QoS override) does not match the
        # sensor-data publisher: publish that topic reliable (it matches both kinds)
        from rclpy.qos import ReliabilityPolicy

        pubs, types, remap = self.pubs, self.types, self.remap
        for t in frame_topics:
            if types[t] not in (IMAGE, COMPRESSED_IMAGE) or t in self.reliable_images:
                continue
            if pubs[t].get_subscription_count():
                continue
            infos = self.node.get_subscriptions_info_by_topic(live_topic(t, remap))
            if any(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in infos):
                self.node.destroy_publisher(pubs[t])
                pubs[t] = self.node.create_publisher(
                    _msg_class(types[t]), live_topic(t, remap), self.qos
                )
                self.reliable_images.add(t)

    def _node_image_topic(self, topic: str) -> str | None:
        """The image topic a node (not the player) subscribes in the live namespace of the bag
        image topic ``topic``, of the same message type (None: none, or several)."""
        live = live_topic(topic, self.remap)
        ns, mt = _parent(live), self.types[topic]
        found = [
            name
            for name, kinds in self.node.get_topic_names_and_types()
            if mt in kinds and _parent(name) == ns and _subscribed_by_others(self.node, name)
        ]
        return found[0] if len(found) == 1 else None

    def wait_for_subscribers(
        self,
        frame_topics: Sequence[str],
        choose: bool,
        output_topics: Sequence[str],
        wait_subscribers: float,
        quiet: bool = False,
        source: str = "auto",
    ) -> None:
        """Spin until the frame topics have subscribers and every ``output_topics`` topic a
        publisher, or ``wait_subscribers`` s passed (then a warning through ``log`` unless
        ``quiet``; longer while a node compiles). A bag image topic counts as subscribed when
        a node subscribes an image topic of its type in its namespace
        (:meth:`publish_images_on_node_topics` plays it there). After 2 s without subscribers
        a managed node that is not active is named through ``log``, once.

        ``choose`` (one frame topic per camera namespace is played, chosen by ``source`` from
        the subscribed ones: :meth:`choose_frames`): a subscriber in each namespace is enough,
        and then the wait goes on until the node's subscriptions are settled, as the frame
        topics the ROS graph shows subscribed tell: either no subscription found later could
        change the choice (:func:`choice_is_final`: e.g. the node's image topic is found) and
        the topics it keeps have a subscriber as above (our publisher matched it), or the
        subscribed frame topics stayed the same for :data:`SETTLE_S` s and every one has a
        subscriber as above. After :data:`SETTLE_CAP_S` s the frames are chosen from the
        subscribers matched then (a note through ``log`` says so)."""
        node, pubs, types = self.node, self.pubs, self.types
        t0 = time.monotonic()
        deadline = t0 + wait_subscribers
        asked_lifecycle = False
        settling = {"heard": None, "changed": t0, "since": None}

        def has_reader(t):
            if pubs[t].get_subscription_count():
                return True
            if types[t] not in (IMAGE, COMPRESSED_IMAGE):
                return False
            target = self._node_image_topic(t)  # (its own topic: a reader of another QoS)
            return target is not None and target != live_topic(t, self.remap)

        def unmatched():
            # choosing: one subscribed frame topic per namespace is enough (then the wait for
            # the subscriptions to settle); else every frame topic needs its subscriber
            if choose:
                ns = {_parent(t) for t in frame_topics}
                ok = {_parent(t) for t in frame_topics if has_reader(t)}
                return bool(ns - ok)
            return not all(has_reader(t) for t in frame_topics)

        def unsettled(now):
            heard = {
                t
                for t in frame_topics
                if has_reader(t) or _subscribed_by_others(node, live_topic(t, self.remap))
            }
            if heard != settling["heard"]:
                settling.update(heard=heard, changed=now)
            if settling["since"] is None:  # (every namespace has a subscriber from now on)
                settling["since"] = now
            frames = {t: types[t] for t in frame_topics}
            final = choice_is_final(frames, heard, source)
            # final: only the topics kept need their subscriber matched (the choice is made
            # from the matched ones)
            waited = set(choose_frame_topics(frames, heard, source)[0]) & heard if final else heard
            unmatched_heard = [live_topic(t, self.remap) for t in waited if not has_reader(t)]
            if now - settling["since"] >= SETTLE_CAP_S:
                self.log(
                    f"note: the subscriptions to the frame topics did not settle within "
                    f"{SETTLE_CAP_S:g} s"
                    + (f" ({', '.join(unmatched_heard)} not matched)" if unmatched_heard else "")
                    + "; choosing from the subscribers matched now"
                )
                return False
            return bool(unmatched_heard) or (now - settling["changed"] < SETTLE_S and not final)

        while True:
            self._match_reliable_image_readers(frame_topics)
            now = time.monotonic()
            if not (unmatched() or any(node.count_publishers(t) == 0 for t in output_topics)):
                if not (choose and unsettled(now)):
                    break
                self.executor.spin_once(timeout_sec=0.05)
                continue
            if not asked_lifecycle and not quiet and now - t0 > 2.0:
                asked_lifecycle = True
                live = [live_topic(t, self.remap) for t in frame_topics]
                not_active = _not_active(node, self.executor, live)
                if not_active:
                    self.log(f"waiting: {_activate_hint(not_active)}")
            if now > deadline and self.busy_compiling() and now < t0 + self.compile_wait:
                self._tell_compiling()
                deadline = now + 1.0
            if now > deadline:
                missing = [
                    live_topic(t, self.remap)
                    for t in frame_topics
                    if pubs[t].get_subscription_count() == 0
                ]
                if not quiet:
                    self.log(
                        f"warning: no subscriber on {missing} after {wait_subscribers:.0f} s; "
                        "playing anyway"
                    )
                break
            self.executor.spin_once(timeout_sec=0.05)

    def publish_images_on_node_topics(
        self, frame_topics: Sequence[str], user_remapped: set[str]
    ) -> None:
        """A bag image topic nobody subscribes (and ``remap`` does not name), while a node
        subscribes one image topic of its type in its namespace (``/camera/image_raw`` and
        the node's ``/camera/image``): published there instead (a note through ``log``);
        then up to 2 s for the new publisher to match."""
        moved = []
        for t in frame_topics:
            if self.types[t] not in (IMAGE, COMPRESSED_IMAGE) or t in user_remapped:
                continue
            if self.pubs[t].get_subscription_count():
                continue
            target = self._node_image_topic(t)
            if target is None or target == live_topic(t, self.remap):
                continue
            self.remap[t] = target
            self.node.destroy_publisher(self.pubs[t])
            self.pubs[t] = self._image_publisher(t)
            moved.append(t)
            self.log(f"note: playing {t} as {target} (the image topic the node subscribes)")
        end = time.monotonic() + 2.0
        while moved and time.monotonic() < end:
            self._match_reliable_image_readers(moved)
            if all(self.pubs[t].get_subscription_count() for t in moved):
                break
            self.executor.spin_once(timeout_sec=0.05)

    def choose_frames(self, frame_topics: Sequence[str], source: str = "auto") -> None:
        """The frame topics :func:`choose_frame_topics` leaves out, in
        ``result.skipped_topics`` (named through ``log``), from the subscribers matched now
        (after :meth:`wait_for_subscribers` with ``choose``)."""
        pubs, types = self.pubs, self.types
        subscribed = {t for t in frame_topics if pubs[t].get_subscription_count()}
        kept, skipped = choose_frame_topics({t: types[t] for t in frame_topics}, subscribed, source)
        if skipped:
            self.result.skipped_topics = skipped
            others = [t for t in types if t not in skipped and t not in kept]
            self.log(
                f"note: frames on several topics; playing {', '.join(kept)} and not "
                f"{', '.join(skipped)} (choose with --source, or --topics "
                f"{' '.join(kept + others)})"
            )
        for t in kept:  # (the node runs a front end but cannot take the bag's images)
            ns = _parent(live_topic(t, self.remap))
            if types[t] in (IMAGE, COMPRESSED_IMAGE):
                continue
            node_images = [
                name
                for name, kinds in self.node.get_topic_names_and_types()
                if _parent(name) == ns
                and set(kinds) & {IMAGE, COMPRESSED_IMAGE}
                and _subscribed_by_others(self.node, name)
            ]
            if node_images and source != "correspondences":
                self.log(
                    f"warning: the node subscribes {', '.join(node_images)} (a front end) but "
                    f"the bag has no image of that type beside {t}: playing {t}, which the "
                    "node solves as given, without its front end and map"
                )

    def _prime(self, stream: Iterator, stamp_offset_ns: int) -> Iterator:
        """Lock-step: best-effort subscribers drop early samples: publish the messages
        before the first frame three times (not the IMU: a sample sent twice is rejected as
        not increasing). Reads ahead of ``stream`` only that far (a rig: until every camera's
        first camera_info, at most 1000 messages); returns the stream from its start."""
        head: list = []
        early: list = []
        for m in stream:
            head.append(m)
            if is_frame_topic(m[0], m[1]):
                break
            early.append(m)
        if self.rig:  # (a rig: every camera's first camera_info too)
            infos = {t for t, mt in self.types.items() if mt == CAMERA_INFO}
            seen = {m[0] for m in early}
            for m in itertools.islice(stream, 1000):
                head.append(m)
                if m[1] == CAMERA_INFO and m[0] not in seen:
                    seen.add(m[0])
                    early.append(m)
                if infos <= seen:
                    break
        for _ in range(3):
            for topic, msgtype, _, raw in early:
                if msgtype == IMU:
                    continue
                self.pubs[topic].publish(_shift_stamp(raw, msgtype, stamp_offset_ns))
            end = time.perf_counter() + 0.05
            while time.perf_counter() < end:
                self.executor.spin_once(timeout_sec=0.01)
        return itertools.chain(head, stream)

    def _await_outputs(
        self, frame: dict, waited: Sequence[str], last_pub: dict, timeout: float, retries: int
    ) -> None:
        """Lock-step: spin until ``frame`` has every ``waited`` output, republishing the last
        messages of each topic up to ``retries`` times after ``timeout`` s without them. While
        a node says it compiles, a timeout only waits on (up to ``compile_wait`` s in all)."""
        result = self.result
        self.pending["frame"] = frame
        attempt = 0
        t_end = time.perf_counter() + timeout
        while any(t not in frame["outputs"] for t in waited):
            now = time.perf_counter()
            if now >= t_end:
                if self.busy_compiling() and result.compile_waited < self.compile_wait:
                    self._tell_compiling()
                    result.compile_waited += timeout
                    t_end = now + timeout
                    continue
                if attempt >= retries:
                    result.timeouts += 1
                    missing = [t for t in waited if t not in frame["outputs"]]
                    self.log(
                        f"warning: frame {frame['index']}: no {', '.join(missing)} "
                        f"within {timeout:g} s ({retries} retries); moving on"
                    )
                    break
                attempt += 1
                result.republished += 1
                for t, r in last_pub.items():  # camera_info and the frame again
                    self.pubs[t].publish(r)
                t_end = time.perf_counter() + timeout
            self.executor.spin_once(timeout_sec=min(0.01, max(t_end - now, 0)))
        if all(t in frame["outputs"] for t in waited):
            result.answered += 1
        self.pending["frame"] = None

    def publish_all(
        self,
        stream: Callable[[], Iterator],
        *,
        rate: float,
        lockstep: bool,
        waited: Mapping[str, Sequence[str]],
        timeout: float,
        retries: int,
        limit: int | None,
        loop: int,
        stamp_offset_ns: int,
        on_frame: Callable[[dict], None] | None,
        give_up: int = 0,
    ) -> None:
        """Publish the messages of ``stream()`` (each call: the bag from its start) ``loop``
        times (stamps shifted by the bag duration each time), at ``rate`` times the original
        timing or in lock-step (each frame waiting for the outputs ``waited[frame_topic]``),
        recording each frame in ``result``; sets ``result.wall_time``. Lock-step stops after
        ``give_up`` (> 0) frames in a row without an answer while none was answered
        (``result.gave_up``)."""
        result, executor, pubs = self.result, self.executor, self.pubs
        wall0 = time.perf_counter()
        n_frames = n_waited = 0
        last_pub = {}
        played: dict[str, None] = {}  # the frame topics played, in order (as the node's names)
        t_first = t_last = None
        shift = stamp_offset_ns
        for rep in range(max(int(loop), 1)):
            msgs = stream()
            if rep == 0 and lockstep:
                msgs = self._prime(msgs, stamp_offset_ns)
                if self.grouping is not None:  # (raises what grouping the bag raised)
                    ns, fut = self.grouping
                    ends = fut.result()[0]
                    self.rig_waits = {(f"{ns}/{n}", st): k for (n, st), k in ends.items()}
            if rep > 0:
                if t_first is None:
                    break
                shift = rep * (t_last - t_first + 1 + 33_000_000) + stamp_offset_ns
            for topic, msgtype, t_ns, raw in msgs:
                if rep == 0:
                    t_first = t_ns if t_first is None else t_first
                    t_last = t_ns if t_last is None else max(t_last, t_ns)
                wait = lockstep
                completes = 1
                if lockstep and self.rig_waits is not None and is_frame_topic(topic, msgtype):
                    completes = self.rig_waits.get((_parent(topic), _header_stamp(raw)), 0)
                    wait = completes > 0
                if shift:
                    raw = _shift_stamp(raw, msgtype, shift)
                if not lockstep and rate > 0:
                    target = wall0 + (t_ns + shift - stamp_offset_ns - t_first) * 1e-9 / rate
                    while True:
                        now = time.perf_counter()
                        if now >= target:
                            break
                        executor.spin_once(timeout_sec=min(target - now, 0.05))
                pubs[topic].publish(raw)
                if msgtype != IMU:  # (republished with a frame without answer)
                    last_pub[topic] = raw
                result.published += 1
                if not is_frame_topic(topic, msgtype):
                    continue
                played.setdefault(live_topic(topic, self.remap))
                n_frames += 1
                frame = {
                    "index": n_frames - 1,
                    "topic": topic,
                    "stamp": _header_stamp(raw),
                    "t_pub": time.perf_counter(),
                    "outputs": {},
                    "expected": len(waited[topic]) if wait else 0,
                }
                result.frames.append(frame)
                if wait:
                    n_waited += 1
                    if self.rig_waits is not None:
                        result.rig_frames += completes
                    self._await_outputs(frame, waited[topic], last_pub, timeout, retries)
                if on_frame is not None:
                    on_frame(frame)
                if wait and give_up > 0 and result.answered == 0 and n_waited >= give_up:
                    result.gave_up = _no_answer_message(
                        self.node,
                        self.executor,
                        waited[topic],
                        f"to the first {n_waited} frames",
                        list(played),
                    )
                    self.log(f"error: {result.gave_up}")
                if result.gave_up or (limit is not None and n_frames >= limit):
                    break
            if result.gave_up or (limit is not None and n_frames >= limit):
                break
        result.wall_time = time.perf_counter() - wall0

    def flush_tail(self, late_wait: float, late: set[str]) -> None:
        """Spin 0.2 s, and up to ``late_wait`` s while a frame misses a ``late`` output."""
        end = time.perf_counter() + 0.2
        end_late = time.perf_counter() + late_wait
        while time.perf_counter() < max(end, end_late):
            if time.perf_counter() >= end and not any(
                t not in f["outputs"] for f in self.result.frames for t in late
            ):
                break
            self.executor.spin_once(timeout_sec=0.02)


def _header_stamp(raw: bytes) -> int:
    """Header stamp of a CDR message that starts with std_msgs/Header (4-byte encapsulation
    header, then int32 sec, uint32 nanosec, little endian)."""
    if raw[1] not in (0, 1):
        return 0
    order = "<" if raw[1] == 1 else ">"
    sec, nsec = np.frombuffer(raw[4:12], dtype=order + "i4, " + order + "u4")[0]
    return int(sec) * 1_000_000_000 + int(nsec)


def _shift_stamp(raw: bytes, msgtype: str, shift_ns: int) -> bytes:
    """Shift the header stamp of a CDR message that starts with a Header (all our types)."""
    if not shift_ns or msgtype not in (PC2, CAMERA_INFO, POSE, TWIST, IMAGE, COMPRESSED_IMAGE, IMU):
        return raw
    order = "<" if raw[1] == 1 else ">"
    s = _header_stamp(raw) + shift_ns
    head = np.array(
        [(s // 1_000_000_000, s % 1_000_000_000)], dtype=order + "i4, " + order + "u4"
    ).tobytes()
    return raw[:4] + head + raw[12:]
