"""ROS 2 bag I/O with ``rosbags`` (no rosbag2, no rclpy): the typestore, writing sequences
and reading them back.

* :func:`write_sequence_bag` writes a synthetic sequence (frames from
  :func:`rs_localizer.sim.trajectory.generate_sequence`) as a bag (mcap or sqlite3) with
  ``<ns>/correspondences``, ``<ns>/keypoints``, ``<ns>/camera_info``, ``/ground_truth/pose`` and
  ``/ground_truth/twist``, plus ``landmarks.csv`` (the map for the keypoints topic) and
  ``sequence.json`` (RS timing and generation settings) in the bag directory.
* :func:`write_rig_bag` writes a simulated rig video (several cameras, each its own timing) as
  a rig bag: per camera ``<ns>/<camera>/camera_info``, ``.../correspondences`` and, rendered,
  ``.../image_raw``, the rig's ground truth, ``sequence.json`` with a ``rig`` entry and
  ``rig_params.yaml`` (the rig node's parameter file); :class:`RigTopics` and
  :func:`rig_namespace` name a rig bag's topics.
* :class:`RosbagsMessages` builds messages of the Jazzy typestore (rendered sequences).
* :func:`read_bag_info`, :func:`iter_messages`, :func:`bag_topics`, :func:`bag_connections`,
  :func:`load_ground_truth` read bags.
"""

from __future__ import annotations

import json
import os
import shutil
from collections import Counter
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from ...accuracy import GroundTruth
from ...camera import CameraModel
from ...maps import save_landmarks_csv
from .. import conversions as cv
from ..image_codec import image_fields
from ..pointcloud import correspondence_array, is_dense, keypoint_array, pack_cloud

__all__ = [
    "GT_POSE",
    "GT_TWIST",
    "RigTopics",
    "RosbagsMessages",
    "bag_connections",
    "bag_topics",
    "first_message",
    "iter_messages",
    "load_ground_truth",
    "read_bag_info",
    "rig_namespace",
    "storage_plugin",
    "typestore",
    "write_rig_bag",
    "write_sequence_bag",
    "write_sequence_json",
]

PC2 = "sensor_msgs/msg/PointCloud2"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
IMAGE = "sensor_msgs/msg/Image"
POSE = "geometry_msgs/msg/PoseStamped"
TWIST = "geometry_msgs/msg/TwistStamped"
IMU = "sensor_msgs/msg/Imu"
GT_POSE = "/ground_truth/pose"
GT_TWIST = "/ground_truth/twist"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
#: message types of the localizer's outputs in a replay's bag (``/rs_localizer/<name>``)
OUT_TYPES = {
    "pose": POSE,
    "twist": TWIST,
    "twist_single_frame": TWIST,
    "pose_with_covariance": "geometry_msgs/msg/PoseWithCovarianceStamped",
    "odom": "nav_msgs/msg/Odometry",
}
_NS = 1_000_000_000


def typestore() -> Any:
    """The rosbags typestore of ROS 2 Jazzy (message definitions for (de)serializing CDR)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def storage_plugin(storage: str) -> type:
    """The rosbags ``StoragePlugin`` of ``mcap`` or ``sqlite3``.

    Raises:
        ValueError: another name.
    """
    from rosbags.rosbag2 import StoragePlugin

    try:
        return {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
    except KeyError:
        raise ValueError(f"unknown storage {storage!r}; use mcap or sqlite3") from None


def write_sequence_bag(
    path: str | os.PathLike,
    frames: Sequence[Any],
    scene: Any,
    camera: CameraModel,
    *,
    storage: str = "mcap",
    namespace: str = "/camera",
    camera_frame: str = "camera_optical_frame",
    map_frame: str = "map",
    with_ids: bool = True,
    with_scores: bool = False,
    keypoints: bool = True,
    correspondences: bool = True,
    stamp_row: float = 0.0,
    settings: dict | None = None,
    overwrite: bool = False,
    gt_twist: bool = True,
    imu: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    imu_topic: str = "/imu/data",
    imu_frame: str = "imu_link",
    extra: dict | None = None,
) -> Path:
    """Write a synthetic sequence as a ROS 2 bag directory; returns its path.

    Log times: camera_info at stamp + 1 ms, clouds and ground truth at stamp + 2 ms (so that
    camera_info always comes first). Ground truth is stamped with the reference row's time.
    ``gt_twist=False`` leaves out ``/ground_truth/twist`` (a bag without ground-truth
    velocities). ``imu``: optional ``(t_ns (M,), omega (M, 3), specific_force (M, 3))`` written
    as ``sensor_msgs/Imu`` on ``imu_topic`` (orientation unknown: covariance[0] = -1).
    ``extra``: more top-level entries of ``sequence.json``.
    """
    from rosbags.rosbag2 import Writer

    path = Path(path)
    if path.exists():
        if not overwrite:
            raise FileExistsError(f"{path} exists (use --overwrite)")
        shutil.rmtree(path)
    M = RosbagsMessages()
    ts = M.ts
    topics = _sequence_topics(namespace, gt_twist, correspondences, keypoints, imu, imu_topic)
    used = np.unique(np.concatenate([f.ids for f in frames])) if frames else np.zeros(0, int)
    with Writer(path, version=9, storage_plugin=storage_plugin(storage)) as w:
        conns = {
            name: w.add_connection(topics[name], mt, typestore=ts)
            for name, mt in _SEQUENCE_TYPES.items()
            if name in topics
        }
        if imu is not None:
            for t_ns, om, fo in zip(*imu, strict=True):
                w.write(conns["imu"], int(t_ns), M.cdr(M.imu(om, fo, int(t_ns), imu_frame), IMU))
        for f in frames:
            _write_sequence_frame(
                w, M, conns, f, camera, camera_frame, map_frame, with_ids, with_scores
            )
    if keypoints and len(used):
        save_landmarks_csv(path / "landmarks.csv", used, scene.lookup(used))
    write_sequence_json(
        path,
        "rs-localizer make-bag",
        topics,
        len(frames),
        camera,
        camera_frame,
        map_frame,
        stamp_row,
        settings=settings or {},
        **(extra or {}),
    )
    return path


#: the topics of :func:`write_sequence_bag` by name, with their message types, in the order
#: their connections are added
_SEQUENCE_TYPES = {
    "camera_info": CAMERA_INFO,
    "correspondences": PC2,
    "keypoints": PC2,
    "gt_pose": POSE,
    "gt_twist": TWIST,
    "imu": IMU,
}


def _sequence_topics(
    namespace: str,
    gt_twist: bool,
    correspondences: bool,
    keypoints: bool,
    imu: Any,
    imu_topic: str,
) -> dict[str, str]:
    """Stage 1 of :func:`write_sequence_bag`: the topic names by name (as ``sequence.json``
    lists them)."""
    ns = namespace.rstrip("/")
    topics = {"camera_info": f"{ns}/camera_info", "gt_pose": GT_POSE}
    if gt_twist:
        topics["gt_twist"] = GT_TWIST
    if correspondences:
        topics["correspondences"] = f"{ns}/correspondences"
    if keypoints:
        topics["keypoints"] = f"{ns}/keypoints"
    if imu is not None:
        topics["imu"] = imu_topic
    return topics


def _write_sequence_frame(
    w: Any,
    M: RosbagsMessages,
    conns: dict[str, Any],
    f: Any,
    camera: CameraModel,
    camera_frame: str,
    map_frame: str,
    with_ids: bool,
    with_scores: bool,
) -> None:
    """Stage 2 of :func:`write_sequence_bag`: one frame's messages: camera_info logged at
    stamp + 1 ms, the clouds and the ground truth at stamp + 2 ms."""
    t_log = f.stamp_ns + 1_000_000
    w.write(
        conns["camera_info"],
        t_log,
        M.cdr(M.camera_info(camera, f.stamp_ns, camera_frame), CAMERA_INFO),
    )
    t_log += 1_000_000
    scores = f.scores if with_scores else None
    if "correspondences" in conns:
        cloud = M.cloud(f.uv, f.xyz, f.ids if with_ids else None, f.stamp_ns, camera_frame, scores)
        w.write(conns["correspondences"], t_log, M.cdr(cloud, PC2))
    if "keypoints" in conns:
        kp = M.keypoints(f.uv, f.ids, f.stamp_ns, camera_frame, scores)
        w.write(conns["keypoints"], t_log, M.cdr(kp, PC2))
    pose = M.pose(f.orientation, f.position, f.t_ref_ns, map_frame)
    w.write(conns["gt_pose"], t_log, M.cdr(pose, POSE))
    if "gt_twist" in conns:
        twist = M.twist(f.angular_velocity, f.linear_velocity, f.t_ref_ns, camera_frame)
        w.write(conns["gt_twist"], t_log, M.cdr(twist, TWIST))


def write_sequence_json(
    path: str | os.PathLike,
    generator: str,
    topics: Mapping[str, str],
    frames: int,
    camera: CameraModel,
    camera_frame: str,
    map_frame: str,
    stamp_row: float,
    rolling_shutter: bool = True,
    **extra: Any,
) -> None:
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
        "camera": {
            "K": camera.K.tolist(),
            "D": camera.D.tolist(),
            "width": camera.width,
            "height": camera.height,
            "distortion_model": camera.distortion_model,
        },
        "rs": {
            "line_delay": camera.line_delay if rolling_shutter else 0.0,
            "readout_time": camera.readout_time if rolling_shutter else 0.0,
            "direction": camera.readout,
            "reference_row": camera.reference_line,
            "stamp_row": float(stamp_row),
        },
        **extra,
    }
    (Path(path) / "sequence.json").write_text(json.dumps(meta, indent=2) + "\n")


# ---------------------------------------------------------------- reading
def read_bag_info(path: str | os.PathLike) -> dict:
    """``sequence.json`` of a bag written by make-bag, or ``{}``."""
    p = Path(path) / "sequence.json"
    return json.loads(p.read_text()) if p.is_file() else {}


def iter_messages(
    path: str | os.PathLike, topics: Iterable[str] | None = None
) -> Iterator[tuple[str, str, int, bytes]]:
    """Yield ``(topic, msgtype, log_time_ns, raw_cdr)`` in log-time order: of every topic, or
    of those of ``topics`` the bag has (none when it has none of them)."""
    from rosbags.rosbag2 import Reader

    with Reader(path) as r:
        conns = [c for c in r.connections if topics is None or c.topic in topics]
        if not conns:  # (rosbags reads every connection when given none)
            return
        for conn, t_ns, raw in r.messages(connections=conns):
            yield conn.topic, conn.msgtype, t_ns, bytes(raw)


def first_message(path: str | os.PathLike, topics: Iterable[str]) -> Any | None:
    """The first message (in log-time order) of those of ``topics`` in the bag at ``path``,
    deserialized (e.g. a camera's first ``sensor_msgs/CameraInfo``); None when they have
    none or the bag has none of them."""
    for _, msgtype, _, raw in iter_messages(path, topics):
        return typestore().deserialize_cdr(raw, msgtype)
    return None


def bag_topics(path: str | os.PathLike) -> dict[str, str]:
    """topic -> msgtype of every connection of the bag at ``path``."""
    return {t: mt for t, (mt, _) in bag_connections(path).items()}


def bag_connections(path: str | os.PathLike) -> dict[str, tuple[str, int]]:
    """topic -> ``(msgtype, messages)`` of the bag at ``path``, from its index (no message
    read): a topic on several connections has the last one's msgtype and all their messages."""
    from rosbags.rosbag2 import Reader

    out: dict[str, tuple[str, int]] = {}
    with Reader(path) as r:
        for c in r.connections:
            out[c.topic] = (c.msgtype, out.get(c.topic, ("", 0))[1] + c.msgcount)
    return out


def load_ground_truth(
    path: str | os.PathLike, pose_topic: str = GT_POSE, twist_topic: str = GT_TWIST
) -> GroundTruth:
    ts = typestore()
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


# ---------------------------------------------------------------- rosbags messages
class RosbagsMessages:
    """Message builders of the rosbags ROS 2 Jazzy typestore (no rclpy): header, image,
    camera_info, correspondence cloud, pose, twist, and ``cdr`` to serialize them."""

    def __init__(self):
        from rosbags.typesys import Stores, get_typestore

        self.ts = get_typestore(Stores.ROS2_JAZZY)
        self.T = self.ts.types

    def header(self, stamp_ns: int, frame_id: str) -> Any:
        sec, nsec = divmod(max(int(stamp_ns), 0), _NS)
        return self.T["std_msgs/msg/Header"](
            stamp=self.T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=frame_id
        )

    def image(self, img: np.ndarray, stamp_ns: int, frame_id: str) -> Any:
        return self.T[IMAGE](header=self.header(stamp_ns, frame_id), **image_fields(img))

    def camera_info(self, cam: CameraModel, stamp_ns: int, frame_id: str) -> Any:
        D = np.asarray(cam.D, dtype=float)
        model = cam.distortion_model if cam.has_distortion else "plumb_bob"
        if model == "plumb_bob" and len(D) < 5:
            D = np.concatenate([D, np.zeros(5 - len(D))])
        P = np.zeros((3, 4))
        P[:, :3] = cam.K
        roi = self.T["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        return self.T[CAMERA_INFO](
            header=self.header(stamp_ns, frame_id),
            height=cam.height,
            width=cam.width,
            distortion_model=model,
            d=D,
            k=cam.K.ravel().copy(),
            r=np.eye(3).ravel(),
            p=P.ravel(),
            binning_x=0,
            binning_y=0,
            roi=roi,
        )

    def cloud(
        self,
        uv: np.ndarray,
        xyz: np.ndarray,
        ids: np.ndarray | None,
        stamp_ns: int,
        frame_id: str,
        scores: np.ndarray | None = None,
    ) -> Any:
        return self.cloud_from_array(correspondence_array(uv, xyz, ids, scores), stamp_ns, frame_id)

    def keypoints(
        self,
        uv: np.ndarray,
        ids: np.ndarray,
        stamp_ns: int,
        frame_id: str,
        scores: np.ndarray | None = None,
    ) -> Any:
        return self.cloud_from_array(keypoint_array(uv, ids, scores), stamp_ns, frame_id)

    def cloud_from_array(self, arr: np.ndarray, stamp_ns: int, frame_id: str) -> Any:
        """A structured array (:mod:`rs_localizer.ros.pointcloud`) as a PointCloud2 (height 1,
        little endian, dense only if every float is finite)."""
        packed = pack_cloud(arr)
        PF = self.T["sensor_msgs/msg/PointField"]
        return self.T[PC2](
            header=self.header(stamp_ns, frame_id),
            height=1,
            width=packed.width,
            fields=[PF(name=n, offset=o, datatype=d, count=c) for n, o, d, c in packed.fields],
            is_bigendian=False,
            point_step=packed.point_step,
            row_step=packed.row_step,
            data=np.frombuffer(packed.data, dtype=np.uint8),
            is_dense=is_dense(arr),
        )

    def pose(self, R: np.ndarray, p: np.ndarray, stamp_ns: int, frame_id: str) -> Any:
        q = cv.quaternion_from_matrix(R)
        T = self.T
        return T[POSE](
            header=self.header(stamp_ns, frame_id),
            pose=T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=float(p[0]), y=float(p[1]), z=float(p[2])),
                orientation=T["geometry_msgs/msg/Quaternion"](
                    x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])
                ),
            ),
        )

    def twist(self, w: np.ndarray, v: np.ndarray, stamp_ns: int, frame_id: str) -> Any:
        T = self.T
        V = T["geometry_msgs/msg/Vector3"]
        return T[TWIST](
            header=self.header(stamp_ns, frame_id),
            twist=T["geometry_msgs/msg/Twist"](
                linear=V(x=float(v[0]), y=float(v[1]), z=float(v[2])),
                angular=V(x=float(w[0]), y=float(w[1]), z=float(w[2])),
            ),
        )

    def imu(
        self, omega: np.ndarray, specific_force: np.ndarray, stamp_ns: int, frame_id: str
    ) -> Any:
        """``sensor_msgs/Imu`` with angular velocity (rad/s) and linear acceleration (specific
        force, m/s^2); orientation unknown (``orientation_covariance[0] = -1``)."""
        T = self.T
        V = T["geometry_msgs/msg/Vector3"]
        unknown = np.zeros(9)
        unknown[0] = -1.0
        return T[IMU](
            header=self.header(stamp_ns, frame_id),
            orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=unknown,
            angular_velocity=V(x=float(omega[0]), y=float(omega[1]), z=float(omega[2])),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=V(
                x=float(specific_force[0]), y=float(specific_force[1]), z=float(specific_force[2])
            ),
            linear_acceleration_covariance=np.zeros(9),
        )

    def cdr(self, msg: Any, msgtype: str) -> bytes:
        return self.ts.serialize_cdr(msg, msgtype)


def _mounting(cam) -> list[float]:
    q = cv.quaternion_from_matrix(cam.R_rig_cam)
    return [float(x) for x in (*cam.p_rig_cam, *q)]


def write_rig_bag(
    path: str | os.PathLike,
    frames: Iterable[Any],
    cameras: list,
    trajectory: Any,
    *,
    t0_ns: int = 1_700_000_000_000_000_000,
    namespace: str = "/rig",
    base_frame: str = "base_link",
    map_frame: str = "map",
    stamp_row: float = 0.0,
    storage: str = "mcap",
    overwrite: bool = False,
    settings: dict | None = None,
    generator: str = "rs-localizer make-bag --rig",
    compress: bool = False,
    extra: dict | None = None,
    imu: tuple | None = None,
) -> Path:
    """Write a simulated rig video as a rig bag (module docstring); returns its path.

    Args:
        frames: camera frames in stamp order, each with ``name``, ``stamp_ns``, ``t_ref_ns``,
            ``uv`` (N, 2) px, ``xyz`` (N, 3) m, optionally ``ids`` (N,) (default 0..N-1) and
            ``image`` ((H, W, 3) uint8 RGB: then ``<ns>/<c>/image_raw`` is written too):
            :func:`rs_localizer.sim.trajectory.generate_rig_video`,
            :func:`rs_localizer.sim.render.renderer.render_rig_video`; an iterator is consumed
            as it is written.
        cameras: the rig's cameras (``name``, ``camera``, ``R_rig_cam``, ``p_rig_cam``,
            ``offset``, ``fps``). trajectory: the rig's motion (``pose(t)``,
            ``velocity_body(t)``; rig time 0 at ``t0_ns``).
        generator, settings, extra: recorded in ``sequence.json`` (``extra``: further
            top-level entries, e.g. the front end). compress: zstd (mcap chunks, sqlite3
            messages).
        imu: optional ``(t_ns (M,), omega (M, 3) rad/s, R_rig_imu (3, 3))``, a gyro on the
            rig (:func:`rs_localizer.sim.trajectory.rig_gyro`) written on ``<namespace>/imu``
            at its stamps.

    Log times: camera_info at stamp + 1 ms, the image, the cloud and the ground truth at
    stamp + 2 ms.

    Raises:
        FileExistsError: ``path`` exists and not ``overwrite``.
    """
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, Writer

    path = Path(path)
    if path.exists():
        if not overwrite:
            raise FileExistsError(f"{path} exists (use --overwrite)")
        shutil.rmtree(path)
    ns = namespace.rstrip("/")
    M = RosbagsMessages()
    topics = {}
    for c in cameras:
        topics[f"{c.name}/camera_info"] = f"{ns}/{c.name}/camera_info"
        topics[f"{c.name}/correspondences"] = f"{ns}/{c.name}/correspondences"
    by = {c.name: c for c in cameras}
    writer = Writer(path, version=9, storage_plugin=storage_plugin(storage))
    if compress:
        writer.set_compression(
            CompressionMode.STORAGE if storage == "mcap" else CompressionMode.MESSAGE,
            CompressionFormat.ZSTD,
        )
    n_frames = 0
    with writer as w:
        conns = {}
        for c in cameras:
            conns[f"{c.name}/camera_info"] = w.add_connection(
                topics[f"{c.name}/camera_info"], CAMERA_INFO, typestore=M.ts
            )
            conns[f"{c.name}/correspondences"] = w.add_connection(
                topics[f"{c.name}/correspondences"], PC2, typestore=M.ts
            )
        gt_pose = w.add_connection(GT_POSE, POSE, typestore=M.ts)
        gt_twist = w.add_connection(GT_TWIST, TWIST, typestore=M.ts)
        if imu is not None:  # (a gyro on the rig)
            c_imu = w.add_connection(f"{ns}/imu", IMU, typestore=M.ts)
            for t_ns, om in zip(imu[0], imu[1], strict=True):
                w.write(c_imu, int(t_ns), M.cdr(M.imu(om, np.zeros(3), int(t_ns), "imu_link"), IMU))
        written = set()
        for f in frames:
            n_frames += 1
            cam = by[f.name]
            frame_id = f"{f.name}_optical_frame"
            info = M.camera_info(cam.camera, f.stamp_ns, frame_id)
            w.write(
                conns[f"{f.name}/camera_info"], f.stamp_ns + 1_000_000, M.cdr(info, CAMERA_INFO)
            )
            t_log = f.stamp_ns + 2_000_000
            image = getattr(f, "image", None)
            if image is not None:
                key = f"{f.name}/image_raw"
                if key not in conns:
                    topics[key] = f"{ns}/{f.name}/image_raw"
                    conns[key] = w.add_connection(topics[key], IMAGE, typestore=M.ts)
                w.write(conns[key], t_log, M.cdr(M.image(image, f.stamp_ns, frame_id), IMAGE))
            ids = getattr(f, "ids", None)
            ids = np.arange(len(f.uv), dtype=np.uint32) if ids is None else ids.astype(np.uint32)
            cloud = M.cloud(f.uv, f.xyz, ids, f.stamp_ns, frame_id)
            w.write(conns[f"{f.name}/correspondences"], t_log, M.cdr(cloud, PC2))
            if f.t_ref_ns in written:
                continue
            written.add(f.t_ref_ns)
            t = (f.t_ref_ns - t0_ns) * 1e-9
            R, p = trajectory.pose(t)
            om, v = trajectory.velocity_body(t)
            w.write(gt_pose, t_log, M.cdr(M.pose(R, p, f.t_ref_ns, map_frame), POSE))
            w.write(gt_twist, t_log, M.cdr(M.twist(om, v, f.t_ref_ns, base_frame), TWIST))
    rig = {
        "namespace": ns,
        "base_frame": base_frame,
        "cameras": [
            {
                "name": c.name,
                "mounting": _mounting(c),
                "line_delay": c.camera.line_delay,
                "direction": c.camera.readout,
                "offset_s": c.offset,
                "fps": c.fps,
            }
            for c in cameras
        ],
    }
    if imu is not None:
        q = cv.quaternion_from_matrix(np.asarray(imu[2], dtype=float))
        rig["imu"] = {"topic": f"{ns}/imu", "rotation": [float(x) for x in q]}
    meta = {
        "generator": generator,
        "topics": {**topics, "gt_pose": GT_POSE, "gt_twist": GT_TWIST},
        "frames": n_frames,
        "map_frame": map_frame,
        "rs": {"stamp_row": float(stamp_row)},
        "rig": rig,
        "settings": settings or {},
        **(extra or {}),
    }
    (path / "sequence.json").write_text(json.dumps(meta, indent=2) + "\n")
    (path / "rig_params.yaml").write_text(_params_yaml(rig, stamp_row, cameras))
    return path


def _params_yaml(rig: dict, stamp_row: float, cameras: list) -> str:
    """The node's parameter file of a rig bag's ``rig`` entry and ``cameras`` (each one's
    mounting written as ``calibrate-rig`` writes it:
    :func:`~rs_localizer.ros.config.mounting_values`)."""
    from ...frames import Mounting
    from ..config import mounting_values, rig_parameter_file

    cams = {
        c.name: {
            "mounting": mounting_values(Mounting.from_pose(c.R_rig_cam, c.p_rig_cam)),
            "line_delay": float(c.camera.line_delay),
            "direction": c.camera.readout,
        }
        for c in cameras
    }
    extra = {}
    if "imu" in rig:
        extra["imu"] = {"enabled": True, "rotation": [round(x, 12) for x in rig["imu"]["rotation"]]}
    return rig_parameter_file(rig["base_frame"], stamp_row, cams, extra)


def rig_namespace(bag: str | os.PathLike, cameras: Iterable[str] = ()) -> str:
    """The namespace of a rig bag's camera topics, without a trailing slash:
    ``sequence.json``'s ``rig.namespace`` (``make-bag --rig``, ``render-bag --rig``); else,
    for a recording of the ``cameras``, the namespace ``<ns>`` under which the bag holds the
    most of their ``<ns>/<camera>/camera_info`` topics (``""`` for ``/front/camera_info``,
    ``/robot`` for ``/robot/front/camera_info``: the rig node's topics, which are relative to
    its namespace); else ``/rig``."""
    info = read_bag_info(bag).get("rig")
    if info is not None:
        return str(info.get("namespace", "/rig")).rstrip("/")
    found: Counter = Counter()
    for topic in bag_topics(bag) if cameras else ():
        for n in cameras:
            leaf = f"/{n}/camera_info"
            if topic.endswith(leaf):
                found[topic[: -len(leaf)]] += 1
    return found.most_common(1)[0][0] if found else "/rig"


@dataclass(frozen=True)
class RigTopics:
    """A rig bag's topics of the cameras ``names``: ``<namespace>/<camera>/camera_info``,
    ``.../correspondences``, ``.../keypoints`` and ``.../image_raw`` (:meth:`of`: topic ->
    ``(kind, camera)``, kind ``info``, ``cloud``, ``keypoints`` or ``image``)."""

    namespace: str
    names: tuple

    def topic(self, name: str, kind: str) -> str:
        """The topic of camera ``name``'s ``kind`` (``info``, ``cloud``, ``keypoints``,
        ``image``)."""
        leaf = {"info": "camera_info", "cloud": "correspondences", "keypoints": "keypoints",
                "image": "image_raw"}[kind]  # fmt: skip
        return f"{self.namespace}/{name}/{leaf}"

    def of(self, kinds: Iterable[str] = ("info", "cloud")) -> dict[str, tuple[str, str]]:
        return {self.topic(n, k): (k, n) for n in self.names for k in kinds}


def progress_bar(
    stream: TextIO | None, total: int | None, desc: str = "replaying", unit: str = "frame"
) -> Any:
    """A ``tqdm`` bar of replayed frames written to ``stream``, disabled when ``stream`` is
    None; ``total``: the frames to come (None: counted as they come)."""
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, file=stream, disable=stream is None)
