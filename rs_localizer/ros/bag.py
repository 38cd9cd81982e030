"""ROS 2 bags with ``rosbags`` (no rosbag2 needed): make-bag, play, replay.

* :func:`write_sequence_bag` writes a synthetic sequence (:mod:`rs_localizer.trajectory`) as a
  bag (mcap or sqlite3) with ``<ns>/correspondences``, ``<ns>/keypoints``, ``<ns>/camera_info``,
  ``/ground_truth/pose`` and ``/ground_truth/twist``, plus ``landmarks.csv`` (the map for the
  keypoints topic) and ``sequence.json`` (RS timing and generation settings) in the bag directory.
* :func:`play` publishes a bag into the live ROS graph (original timing scaled by ``rate``, or
  lock-step: wait for each frame's output before sending the next).
* :func:`replay` runs the estimator over every frame offline (no middleware) and writes the
  estimates as a bag and a CSV.

Messages are built with the rclpy message classes and serialized with
``rclpy.serialization`` (plain CDR, what rosbag2 stores); reading uses the rosbags typestore.
"""

from __future__ import annotations

import csv
import importlib
import json
import math
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..camera import CameraModel
from ..geometry import rotation_angle_deg
from . import conversions as cv
from .pointcloud import correspondence_cloud, keypoint_cloud

__all__ = ["write_sequence_bag", "read_bag_info", "load_ground_truth", "iter_messages",
           "play", "replay", "PlayResult", "ReplayResult", "GroundTruth", "frame_errors",
           "summarize_errors", "format_summary"]

PC2 = "sensor_msgs/msg/PointCloud2"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
IMAGE = "sensor_msgs/msg/Image"
POSE = "geometry_msgs/msg/PoseStamped"
TWIST = "geometry_msgs/msg/TwistStamped"
GT_POSE = "/ground_truth/pose"
GT_TWIST = "/ground_truth/twist"
FRAME_TOPIC_SUFFIXES = ("correspondences", "keypoints")  # + every sensor_msgs/Image topic
OUT_TYPES = {"pose": POSE, "twist": TWIST,
             "pose_with_covariance": "geometry_msgs/msg/PoseWithCovarianceStamped",
             "odom": "nav_msgs/msg/Odometry"}


def _typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def _cdr(msg, msgtype: str, ts) -> bytes:
    """rclpy message -> CDR bytes with zeroed padding (rclpy leaves the alignment padding
    uninitialized, which makes bags non-reproducible): serialize, then let rosbags re-encode."""
    from rclpy.serialization import serialize_message

    return bytes(ts.serialize_cdr(ts.deserialize_cdr(serialize_message(msg), msgtype), msgtype))


def _storage_plugin(storage: str):
    from rosbags.rosbag2 import StoragePlugin

    try:
        return {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
    except KeyError:
        raise ValueError(f"unknown storage {storage!r}; use mcap or sqlite3") from None


# ---------------------------------------------------------------- make-bag
def write_sequence_bag(path, frames, scene, camera: CameraModel, *, storage: str = "mcap",
                       namespace: str = "/camera", camera_frame: str = "camera_optical_frame",
                       map_frame: str = "map", with_ids: bool = True, with_scores: bool = False,
                       keypoints: bool = True, correspondences: bool = True,
                       stamp_row: float = 0.0, settings: dict | None = None,
                       overwrite: bool = False) -> Path:
    """Write a synthetic sequence as a ROS 2 bag directory; returns its path.

    Log times: camera_info at stamp + 1 ms, clouds and ground truth at stamp + 2 ms (so that
    camera_info always comes first). Ground truth is stamped with the reference row's time.
    """
    from rosbags.rosbag2 import Writer

    from ..trajectory import save_landmarks_csv

    path = Path(path)
    if path.exists():
        if not overwrite:
            raise FileExistsError(f"{path} exists (use --overwrite)")
        shutil.rmtree(path)
    ts = _typestore()
    ns = namespace.rstrip("/")
    topics = {"camera_info": f"{ns}/camera_info", "gt_pose": GT_POSE, "gt_twist": GT_TWIST}
    if correspondences:
        topics["correspondences"] = f"{ns}/correspondences"
    if keypoints:
        topics["keypoints"] = f"{ns}/keypoints"
    used = np.unique(np.concatenate([f.ids for f in frames])) if frames else np.zeros(0, int)
    with Writer(path, version=9, storage_plugin=_storage_plugin(storage)) as w:
        c_info = w.add_connection(topics["camera_info"], CAMERA_INFO, typestore=ts)
        c_corr = (w.add_connection(topics["correspondences"], PC2, typestore=ts)
                  if correspondences else None)
        c_kp = w.add_connection(topics["keypoints"], PC2, typestore=ts) if keypoints else None
        c_gtp = w.add_connection(GT_POSE, POSE, typestore=ts)
        c_gtt = w.add_connection(GT_TWIST, TWIST, typestore=ts)
        for f in frames:
            t_log = f.stamp_ns + 1_000_000
            w.write(c_info, t_log, _cdr(cv.camera_info_msg(camera, camera_frame, f.stamp_ns),
                                        CAMERA_INFO, ts))
            t_log += 1_000_000
            if c_corr is not None:
                w.write(c_corr, t_log, _cdr(correspondence_cloud(
                    f.uv, f.xyz, f.ids if with_ids else None,
                    f.scores if with_scores else None, frame_id=camera_frame,
                    stamp=f.stamp_ns), PC2, ts))
            if c_kp is not None:
                w.write(c_kp, t_log, _cdr(keypoint_cloud(
                    f.uv, f.ids, f.scores if with_scores else None, frame_id=camera_frame,
                    stamp=f.stamp_ns), PC2, ts))
            est_like = _GT(f.orientation, f.position, f.angular_velocity, f.linear_velocity)
            w.write(c_gtp, t_log, _cdr(cv.pose_stamped(est_like, f.t_ref_ns, map_frame),
                                       POSE, ts))
            w.write(c_gtt, t_log, _cdr(cv.twist_stamped(est_like, f.t_ref_ns, camera_frame),
                                       TWIST, ts))
    if keypoints and len(used):
        save_landmarks_csv(path / "landmarks.csv", used, scene.lookup(used))
    write_sequence_json(path, "rs-localizer make-bag", topics, len(frames), camera,
                        camera_frame, map_frame, stamp_row, settings=settings or {})
    return path


def write_sequence_json(path, generator: str, topics, frames: int, camera: CameraModel,
                        camera_frame: str, map_frame: str, stamp_row: float,
                        rolling_shutter: bool = True, **extra) -> None:
    """Write a bag's ``sequence.json`` (the schema :func:`load_sequence_info` and the demo read):
    topics, frame count, frames, camera (K, D, size, distortion model) and RS timing, plus
    ``extra`` top-level entries (``settings``, ``frontend``, ...). ``rolling_shutter=False``
    records a global-shutter sequence (zero line delay and readout time)."""
    meta = {
        "generator": generator,
        "topics": topics,
        "frames": int(frames),
        "camera_frame": camera_frame,
        "map_frame": map_frame,
        "camera": {"K": camera.K.tolist(), "D": camera.D.tolist(), "width": camera.width,
                   "height": camera.height, "distortion_model": camera.distortion_model},
        "rs": {"line_delay": camera.line_delay if rolling_shutter else 0.0,
               "readout_time": camera.readout_time if rolling_shutter else 0.0,
               "direction": camera.readout, "reference_row": camera.reference_line,
               "stamp_row": float(stamp_row)},
        **extra,
    }
    (Path(path) / "sequence.json").write_text(json.dumps(meta, indent=2) + "\n")


@dataclass
class _GT:
    orientation: np.ndarray
    position: np.ndarray
    angular_velocity: np.ndarray
    linear_velocity: np.ndarray


# ---------------------------------------------------------------- reading
def read_bag_info(path) -> dict:
    """``sequence.json`` of a bag written by make-bag, or ``{}``."""
    p = Path(path) / "sequence.json"
    return json.loads(p.read_text()) if p.is_file() else {}


def iter_messages(path, topics=None):
    """Yield ``(topic, msgtype, log_time_ns, raw_cdr)`` in log-time order."""
    from rosbags.rosbag2 import Reader

    with Reader(path) as r:
        conns = [c for c in r.connections if topics is None or c.topic in topics]
        for conn, t_ns, raw in r.messages(connections=conns):
            yield conn.topic, conn.msgtype, t_ns, bytes(raw)


def bag_topics(path) -> dict:
    """topic -> msgtype."""
    from rosbags.rosbag2 import Reader

    with Reader(path) as r:
        return {c.topic: c.msgtype for c in r.connections}


@dataclass
class GroundTruth:
    """Ground truth per reference-row stamp (ns): camera -> map pose and camera-frame twist."""

    stamps: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    orientation: dict = field(default_factory=dict)
    position: dict = field(default_factory=dict)
    angular_velocity: dict = field(default_factory=dict)
    linear_velocity: dict = field(default_factory=dict)

    def __len__(self):
        return len(self.stamps)

    def nearest(self, stamp_ns: int, tol_ns: int = 2_000_000):
        """Ground-truth stamp nearest ``stamp_ns`` within ``tol_ns``, else None."""
        if not len(self.stamps):
            return None
        i = int(np.searchsorted(self.stamps, stamp_ns))
        best = None
        for j in (i - 1, i):
            if 0 <= j < len(self.stamps):
                d = abs(int(self.stamps[j]) - int(stamp_ns))
                if d <= tol_ns and (best is None or d < best[0]):
                    best = (d, int(self.stamps[j]))
        return None if best is None else best[1]


def load_ground_truth(path, pose_topic=GT_POSE, twist_topic=GT_TWIST) -> GroundTruth:
    ts = _typestore()
    gt = GroundTruth()
    for topic, msgtype, _, raw in iter_messages(path, {pose_topic, twist_topic}):
        msg = ts.deserialize_cdr(raw, msgtype)
        stamp = cv.stamp_to_ns(msg.header.stamp)
        if topic == pose_topic:
            gt.orientation[stamp], gt.position[stamp] = cv.pose_from_msg(msg.pose)
        else:
            gt.angular_velocity[stamp], gt.linear_velocity[stamp] = cv.twist_from_msg(msg.twist)
    gt.stamps = np.array(sorted(gt.orientation), dtype=np.int64)
    return gt


# ---------------------------------------------------------------- accuracy
def frame_errors(orientation, position, angular_velocity, linear_velocity, gt: GroundTruth,
                 stamp_ns: int) -> dict | None:
    """Errors of one estimate against ground truth: rotation (deg), position (m), angular
    velocity (rad/s, norm of the difference), linear velocity (m/s). None if no ground truth."""
    s = gt.nearest(stamp_ns)
    if s is None:
        return None
    out = {"rot_deg": rotation_angle_deg(orientation, gt.orientation[s]),
           "pos_m": float(np.linalg.norm(np.asarray(position) - gt.position[s]))}
    if s in gt.angular_velocity and angular_velocity is not None:
        out["angvel"] = float(np.linalg.norm(np.asarray(angular_velocity)
                                             - gt.angular_velocity[s]))
        out["linvel"] = float(np.linalg.norm(np.asarray(linear_velocity)
                                             - gt.linear_velocity[s]))
        out["angvel_gt"] = float(np.linalg.norm(gt.angular_velocity[s]))
    return out


def summarize_errors(errors: list) -> dict:
    """Median / mean / max of each error over frames (None entries skipped)."""
    errors = [e for e in errors if e]
    out = {"frames": len(errors)}
    for key in ("rot_deg", "pos_m", "angvel", "linvel"):
        vals = np.array([e[key] for e in errors if key in e])
        if len(vals):
            out[key] = {"median": float(np.median(vals)), "mean": float(np.mean(vals)),
                        "p90": float(np.percentile(vals, 90)), "max": float(np.max(vals))}
    return out


def format_summary(name: str, summary: dict, total: int | None = None) -> str:
    parts = [f"{name}: {summary['frames']}" + (f"/{total}" if total is not None else "")
             + " frames"]
    units = {"rot_deg": ("rotation", "deg", 1), "pos_m": ("position", "cm", 100),
             "angvel": ("ang.vel", "rad/s", 1), "linvel": ("lin.vel", "m/s", 1)}
    for key, (label, unit, scale) in units.items():
        if key in summary:
            s = summary[key]
            parts.append(f"{label} median {s['median'] * scale:.3g} mean {s['mean'] * scale:.3g} "
                         f"max {s['max'] * scale:.3g} {unit}")
    return "; ".join(parts)


# ---------------------------------------------------------------- play
def output_type(topic: str):
    """Message class of a node output topic, by its name."""
    from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, TwistStamped
    from nav_msgs.msg import Odometry

    from sensor_msgs.msg import PointCloud2

    last = topic.rstrip("/").rsplit("/", 1)[-1]
    return {"twist": TwistStamped, "odom": Odometry,
            "pose_with_covariance": PoseWithCovarianceStamped,
            "correspondences_out": PointCloud2}.get(last, PoseStamped)


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
    image (``sensor_msgs/msg/Image``)."""
    return topic.rstrip("/").rsplit("/", 1)[-1] in FRAME_TOPIC_SUFFIXES or msgtype == IMAGE


def play(path, *, rate: float = 1.0, lockstep: bool = False, topics=None, remap=None,
         output_topics=("/camera/pose",), timeout: float = 2.0, retries: int = 1,
         wait_subscribers: float = 30.0, reliable: bool = True, context=None, domain_id=None,
         limit: int | None = None, loop: int = 1, stamp_offset_ns: int = 0, messages=None,
         on_frame=None, log=print) -> PlayResult:
    """Publish a bag into the ROS graph.

    Args:
        path: bag directory.
        rate: time scale of the original timing (ignored in lock-step).
        lockstep: after each frame (a ``*/correspondences``, ``*/keypoints`` or image message) wait
            until every ``output_topics`` topic delivered a message stamped within 1 s of the
            frame, or ``timeout``; then republish it up to ``retries`` times (a best-effort
            subscription may drop a sample) before moving on.
        topics: only these bag topics (default: all). remap: ``{bag_topic: live_topic}``.
        wait_subscribers: seconds to wait until every frame topic has a subscriber.
        reliable: publish with reliable QoS (depth 10); else best effort.
        context: an ``rclpy.Context`` (initialized here if needed and shut down at the end if
            it was created here). domain_id: ROS domain for a context created here.
        limit: stop after this many frames. loop: play the bag this many times (frame stamps
            are shifted forward by the bag duration so they keep increasing).
        stamp_offset_ns: added to every header stamp (replaying a bag into a running node).
        messages: preloaded ``iter_messages`` list (benchmarks). on_frame: callback(frame dict).
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    remap = dict(remap or {})
    own_context = context is None
    if own_context:
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=domain_id)
    node = rclpy.create_node("rs_localizer_player", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    result = PlayResult()
    try:
        msgs = messages if messages is not None else list(iter_messages(path, topics))
        if topics is not None:
            msgs = [m for m in msgs if m[0] in topics]
        types = {}
        for topic, msgtype, _, _ in msgs:
            types.setdefault(topic, msgtype)
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE if reliable
                         else ReliabilityPolicy.BEST_EFFORT)
        pubs = {t: node.create_publisher(_msg_class(mt), remap.get(t, t), qos)
                for t, mt in types.items()}
        outputs = {}
        pending = {"frame": None}

        def make_cb(topic):
            def cb(msg):
                fr = pending["frame"]
                if fr is None:
                    return
                s = cv.stamp_to_ns(msg.header.stamp)
                if abs(s - fr["stamp"]) < 1_000_000_000 and topic not in fr["outputs"]:
                    fr["outputs"][topic] = (time.perf_counter(), msg)
            return cb

        if lockstep:
            for t in output_topics:
                outputs[t] = node.create_subscription(output_type(t), t, make_cb(t), qos)
        frame_topics = [t for t in pubs if is_frame_topic(t, types[t])]
        deadline = time.monotonic() + wait_subscribers
        while any(pubs[t].get_subscription_count() == 0 for t in frame_topics) or (
                lockstep and any(node.count_publishers(t) == 0 for t in output_topics)):
            if time.monotonic() > deadline:
                missing = [remap.get(t, t) for t in frame_topics
                           if pubs[t].get_subscription_count() == 0]
                log(f"warning: no subscriber on {missing} after {wait_subscribers:.0f} s; "
                    "playing anyway")
                break
            executor.spin_once(timeout_sec=0.05)
        if not msgs:
            return result
        t_first = msgs[0][2]
        duration = msgs[-1][2] - t_first + 1
        wall0 = time.perf_counter()
        n_frames = 0
        last_pub = {}
        if lockstep:  # best-effort subscribers drop early samples: prime the camera_info
            first = next((k for k, m in enumerate(msgs) if is_frame_topic(m[0], m[1])),
                         len(msgs))
            for _ in range(3):
                for topic, msgtype, _, raw in msgs[:first]:
                    pubs[topic].publish(_shift_stamp(raw, msgtype, stamp_offset_ns))
                end = time.perf_counter() + 0.05
                while time.perf_counter() < end:
                    executor.spin_once(timeout_sec=0.01)
        for rep in range(max(int(loop), 1)):
            shift = rep * (duration + 33_000_000) + stamp_offset_ns
            for topic, msgtype, t_ns, raw in msgs:
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
                last_pub[topic] = raw
                result.published += 1
                if not is_frame_topic(topic, msgtype):
                    continue
                n_frames += 1
                frame = {"index": n_frames - 1, "topic": topic, "stamp": _header_stamp(raw),
                         "t_pub": time.perf_counter(), "outputs": {},
                         "expected": len(output_topics) if lockstep else 0}
                result.frames.append(frame)
                if lockstep:
                    pending["frame"] = frame
                    attempt = 0
                    t_end = time.perf_counter() + timeout
                    while len(frame["outputs"]) < len(output_topics):
                        now = time.perf_counter()
                        if now >= t_end:
                            if attempt >= retries:
                                result.timeouts += 1
                                break
                            attempt += 1
                            for t, r in last_pub.items():  # camera_info and the frame again
                                pubs[t].publish(r)
                            t_end = time.perf_counter() + timeout
                        executor.spin_once(timeout_sec=min(0.01, max(t_end - now, 0)))
                    if len(frame["outputs"]) == len(output_topics):
                        result.answered += 1
                    pending["frame"] = None
                if on_frame is not None:
                    on_frame(frame)
                if limit is not None and n_frames >= limit:
                    break
            if limit is not None and n_frames >= limit:
                break
        result.wall_time = time.perf_counter() - wall0
        # let reliable writers flush the tail
        end = time.perf_counter() + 0.2
        while time.perf_counter() < end:
            executor.spin_once(timeout_sec=0.02)
    finally:
        executor.remove_node(node)
        node.destroy_node()
        executor.shutdown()
        if own_context:
            rclpy.try_shutdown(context=context)
    return result


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
    if not shift_ns or msgtype not in (PC2, CAMERA_INFO, POSE, TWIST, IMAGE):
        return raw
    order = "<" if raw[1] == 1 else ">"
    s = _header_stamp(raw) + shift_ns
    head = np.array([(s // 1_000_000_000, s % 1_000_000_000)],
                    dtype=order + "i4, " + order + "u4").tobytes()
    return raw[:4] + head + raw[12:]


# ---------------------------------------------------------------- replay
@dataclass
class ReplayResult:
    rows: list = field(default_factory=list)
    summary: dict = field(default_factory=dict)
    failures: dict = field(default_factory=dict)
    out_bag: Path | None = None
    out_csv: Path | None = None

    @property
    def solved(self) -> int:
        return sum(1 for r in self.rows if r["success"])


def _progress(i, n, t0, stream):
    if stream is None:
        return
    width = 30
    done = int(width * i / max(n, 1))
    rate = i / max(time.perf_counter() - t0, 1e-9)
    stream.write(f"\r[{'#' * done}{'.' * (width - done)}] {i}/{n} frames {rate:6.1f} Hz")
    if i == n:
        stream.write("\n")
    stream.flush()


def replay(path, *, solver: str = "r6p_1lin", options=None, source: str = "correspondences",
           line_delay: float | None = None, readout_time: float | None = None,
           direction: str | None = None, reference_row: float | None = None,
           stamp_row: float | None = None, landmarks_file=None, out_bag=None, out_csv=None,
           storage: str = "mcap", map_frame: str = "map", camera_frame: str | None = None,
           progress=sys.stderr, overwrite: bool = False) -> ReplayResult:
    """Run :func:`estimate_rs_pose` over every frame of a bag, offline.

    RS timing defaults come from the bag's ``sequence.json`` (make-bag) and can be overridden.
    Writes the estimates (``/rs_localizer/pose``, ``twist``, ``pose_with_covariance``,
    ``odom``) to ``out_bag`` and one line per frame to ``out_csv`` when given, and compares
    with ``/ground_truth/*`` when the bag has them.
    """
    from ..estimate import EstimateOptions, estimate_rs_pose
    from ..trajectory import load_landmarks_csv
    from .pointcloud import read_correspondences, read_keypoints

    path = Path(path)
    info = read_bag_info(path)
    rs = info.get("rs", {})
    line_delay = rs.get("line_delay", 0.0) if line_delay is None else line_delay
    readout_time = 0.0 if readout_time is None else readout_time
    direction = rs.get("direction", "top_to_bottom") if direction is None else direction
    reference_row = rs.get("reference_row", -1.0) if reference_row is None else reference_row
    stamp_row = rs.get("stamp_row", 0.0) if stamp_row is None else stamp_row
    options = options or EstimateOptions()
    ts = _typestore()
    topics = bag_topics(path)
    frame_topic = next((t for t in topics if t.rstrip("/").endswith("/" + source)), None)
    info_topic = next((t for t, mt in topics.items() if mt == CAMERA_INFO), None)
    if frame_topic is None:
        raise ValueError(f"{path}: no */{source} topic (topics: {sorted(topics)})")
    lm_index = None
    if source == "keypoints":
        lm = Path(landmarks_file) if landmarks_file else path / "landmarks.csv"
        ids, pts = load_landmarks_csv(lm)
        order = np.argsort(ids)
        lm_index = (ids[order], pts[order])
    gt = load_ground_truth(path) if GT_POSE in topics else GroundTruth()
    n_frames = _count(path, frame_topic)
    result = ReplayResult()
    writer = None
    conns = {}
    if out_bag is not None:
        from rosbags.rosbag2 import Writer

        out_bag = Path(out_bag)
        if out_bag.exists():
            if not overwrite:
                raise FileExistsError(f"{out_bag} exists (use --overwrite)")
            shutil.rmtree(out_bag)
        writer = Writer(out_bag, version=9, storage_plugin=_storage_plugin(storage))
        writer.open()
        for name, mt in OUT_TYPES.items():
            conns[name] = writer.add_connection(f"/rs_localizer/{name}", mt, typestore=ts)
        result.out_bag = out_bag
    camera = None
    cam_key = None
    t0 = time.perf_counter()
    i = 0
    try:
        for topic, msgtype, t_log, raw in iter_messages(path, {frame_topic, info_topic}):
            msg = ts.deserialize_cdr(raw, msgtype)
            if topic == info_topic:
                key = (tuple(msg.k), tuple(msg.d), msg.distortion_model, msg.width, msg.height)
                if key != cam_key:
                    camera = cv.camera_model_from_camera_info(
                        msg, line_delay, readout_time, direction, reference_row)
                    cam_key = key
                continue
            i += 1
            stamp = cv.stamp_to_ns(msg.header.stamp)
            row = {"frame": i - 1, "stamp_ns": stamp, "success": False, "failure": "",
                   "solver": solver}
            if camera is None:
                row["failure"] = "no_camera_info"
            else:
                try:
                    if source == "keypoints":
                        kp = read_keypoints(msg)
                        j = np.clip(np.searchsorted(lm_index[0], kp.ids), 0,
                                    len(lm_index[0]) - 1)
                        known = lm_index[0][j] == kp.ids
                        uv, xyz, scores = kp.uv[known], lm_index[1][j[known]], (
                            None if kp.scores is None else kp.scores[known])
                    else:
                        c = read_correspondences(msg)
                        uv, xyz, scores = c.uv, c.xyz, c.scores
                except ValueError as e:
                    row["failure"] = getattr(e, "reason", "bad_cloud")
                else:
                    tic = time.perf_counter()
                    est = estimate_rs_pose(uv, xyz, camera, solver=solver, options=options,
                                           scores=scores)
                    row["time_ms"] = (time.perf_counter() - tic) * 1e3
                    out_stamp = stamp + int(round(
                        camera.time_offset(stamp_row, camera.reference_line) * 1e9))
                    row["out_stamp_ns"] = out_stamp
                    row["num_points"] = len(uv)
                    row["num_inliers"] = est.num_inliers
                    row["rmse_px"] = est.rmse_px
                    if est.success:
                        row["success"] = True
                        q = cv.quaternion_from_matrix(est.orientation)
                        row.update({f"q{a}": q[k] for k, a in enumerate("xyzw")})
                        row.update({f"p{a}": est.position[k] for k, a in enumerate("xyz")})
                        row.update({f"w{a}": est.angular_velocity[k]
                                    for k, a in enumerate("xyz")})
                        row.update({f"v{a}": est.linear_velocity[k]
                                    for k, a in enumerate("xyz")})
                        err = frame_errors(est.orientation, est.position,
                                           est.angular_velocity, est.linear_velocity, gt,
                                           out_stamp)
                        if err:
                            row.update({f"err_{k}": v for k, v in err.items()})
                        if writer is not None:
                            cf = camera_frame or msg.header.frame_id or "camera"
                            for name, m in (
                                    ("pose", cv.pose_stamped(est, out_stamp, map_frame)),
                                    ("twist", cv.twist_stamped(est, out_stamp, cf)),
                                    ("pose_with_covariance", cv.pose_with_covariance_stamped(
                                        est, out_stamp, map_frame)),
                                    ("odom", cv.odometry(est, out_stamp, map_frame, cf))):
                                writer.write(conns[name], t_log, _cdr(m, OUT_TYPES[name], ts))
                    else:
                        row["failure"] = est.failure or "unknown"
            if not row["success"]:
                result.failures[row["failure"]] = result.failures.get(row["failure"], 0) + 1
            result.rows.append(row)
            _progress(i, n_frames, t0, progress)
    finally:
        if writer is not None:
            writer.close()
    errors = [{k[4:]: v for k, v in r.items() if k.startswith("err_")} for r in result.rows]
    result.summary = summarize_errors(errors)
    if out_csv is not None:
        result.out_csv = Path(out_csv)
        _write_csv(result.out_csv, result.rows)
    return result


def _count(path, topic) -> int:
    from rosbags.rosbag2 import Reader

    with Reader(path) as r:
        return sum(c.msgcount for c in r.connections if c.topic == topic)


CSV_COLUMNS = ["frame", "stamp_ns", "out_stamp_ns", "solver", "success", "failure", "num_points",
               "num_inliers", "rmse_px", "time_ms", "qx", "qy", "qz", "qw", "px", "py", "pz",
               "wx", "wy", "wz", "vx", "vy", "vz", "err_rot_deg", "err_pos_m", "err_angvel",
               "err_linvel"]


def _write_csv(path, rows):
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=CSV_COLUMNS, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.9g}" if isinstance(v, float) and math.isfinite(v) else v)
                        for k, v in r.items()})
