"""Frames of a bag as 2D-3D correspondences (offline, rosbags; no middleware), and its gyro.

:func:`read_bag_frames` turns every frame of a bag into ``(stamp_ns, points2d, points3d,
scores)``: from a correspondence cloud, from keypoints with the bag's landmark map, or from
images through an image front end (ArUco or feature map). :func:`read_gyro` reads the angular
velocity of ``sensor_msgs/Imu`` messages. Used by ``rs-localizer calibrate-readout``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...camera import CameraModel
from .. import conversions as cv
from .bag_io import CAMERA_INFO, IMAGE, IMU, bag_topics, iter_messages, read_bag_info, typestore

__all__ = ["SOURCES", "BagFrames", "read_bag_frames", "read_gyro"]

#: where the correspondences of a frame come from
SOURCES = ("correspondences", "keypoints", "image")


@dataclass
class BagFrames:
    """Frames of a bag. ``camera``: from the first ``camera_info`` (line delay 0, the bag's
    readout direction, reference line at the image centre); ``frames``: list of ``(stamp_ns,
    points2d (N, 2), points3d (N, 3), scores (N,) or None)``; ``skipped``: reason ->
    count of frames without usable correspondences; ``stamp_row``: the line whose capture time
    the stamps are (from ``sequence.json``, default 0)."""

    camera: CameraModel | None = None
    frames: list = field(default_factory=list)
    skipped: dict = field(default_factory=dict)
    stamp_row: float = 0.0
    direction: str = "top_to_bottom"


def _frame_topic(topics: dict, source: str):
    if source == "image":
        cand = [t for t, mt in topics.items() if mt == IMAGE]
    else:
        cand = [t for t in topics if t.rstrip("/").endswith("/" + source)]
    return cand[0] if cand else None


def read_bag_frames(
    path: str | Path,
    source: str = "correspondences",
    landmarks_file: str | Path | None = None,
    frontend: str | None = None,
    frontend_map: str | Path | None = None,
    direction: str | None = None,
) -> BagFrames:
    """Read every frame of a bag as correspondences.

    Args:
        path: bag directory.
        source: ``correspondences`` (``*/correspondences`` clouds), ``keypoints``
            (``*/keypoints`` clouds + the landmark CSV ``landmarks_file``, default the bag's
            ``landmarks.csv``) or ``image`` (``sensor_msgs/Image`` + a front end: ``frontend``
            and ``frontend_map``, default the ``frontend`` entry of ``sequence.json``, whose
            map path is relative to the bag).
        direction: readout direction (default: the bag's ``sequence.json``, else top to
            bottom).
    Returns:
        :class:`BagFrames`.
    Raises:
        ValueError: unknown source, no such topic in the bag, no camera_info, no front end.
        FileNotFoundError: missing bag, landmark file or front-end map.
    """
    from ...maps import load_landmarks_csv
    from ..pointcloud import read_correspondences, read_keypoints

    if source not in SOURCES:
        raise ValueError(f"unknown source {source!r}; expected one of {SOURCES}")
    path = Path(path)
    if not (path / "metadata.yaml").exists():
        raise FileNotFoundError(f"{path}: not a bag directory (no metadata.yaml)")
    info = read_bag_info(path)
    rs = info.get("rs", {})
    direction = direction or rs.get("direction", "top_to_bottom")
    out = BagFrames(stamp_row=float(rs.get("stamp_row", 0.0)), direction=direction)
    topics = bag_topics(path)
    frame_topic = _frame_topic(topics, source)
    info_topic = next((t for t, mt in topics.items() if mt == CAMERA_INFO), None)
    if frame_topic is None:
        raise ValueError(f"{path}: no {source} topic (topics: {sorted(topics)})")
    lm_index = None
    fe = None
    if source == "keypoints":
        ids, pts = load_landmarks_csv(
            Path(landmarks_file) if landmarks_file else path / "landmarks.csv"
        )
        order = np.argsort(ids)
        lm_index = (ids[order], pts[order])
    elif source == "image":
        from ...frontends import make_frontend
        from ..image_codec import decode_image

        spec = info.get("frontend", {})
        kind = frontend or spec.get("kind")
        fmap = frontend_map or (path / spec["map"] if "map" in spec else None)
        if kind is None:
            raise ValueError(
                f"{path}: no front end given and none in sequence.json "
                "(use --frontend and --frontend-map)"
            )
        if fmap is None:
            hint = (
                "; without a marker map, `rs-localizer map-markers BAG -o map.yaml "
                "--marker-size M --calibrate-readout` builds one and estimates the readout "
                "time from the same video"
                if kind == "aruco"
                else ""
            )
            raise ValueError(
                f"{path}: the {kind} front end needs its map: --frontend-map MAP "
                f"(sequence.json names none){hint}"
            )
        fe = make_frontend(kind, fmap)
    ts = typestore()
    for topic, msgtype, _, raw in iter_messages(path, {frame_topic, info_topic}):
        msg = ts.deserialize_cdr(raw, msgtype)
        if topic == info_topic:
            if out.camera is None:
                out.camera = cv.camera_model_from_camera_info(msg, 0.0, 0.0, direction, None)
            continue
        stamp = cv.stamp_to_ns(msg.header.stamp)
        try:
            if source == "keypoints":
                kp = read_keypoints(msg)
                j = np.clip(np.searchsorted(lm_index[0], kp.ids), 0, len(lm_index[0]) - 1)
                known = lm_index[0][j] == kp.ids
                uv, xyz = kp.uv[known], lm_index[1][j[known]]
                scores = None if kp.scores is None else kp.scores[known]
            elif source == "image":
                img, enc = decode_image(msg)
                uv, xyz, _ = fe.process(img, out.camera, encoding=enc)
                scores = None
            else:
                c = read_correspondences(msg)
                uv, xyz, scores = c.points2d, c.points, c.scores
        except ValueError as e:
            reason = getattr(e, "reason", "bad_frame")
            out.skipped[reason] = out.skipped.get(reason, 0) + 1
            continue
        out.frames.append((stamp, uv, xyz, scores))
    if out.camera is None:
        raise ValueError(f"{path}: no camera_info message")
    out.frames.sort(key=lambda f: f[0])
    return out


def read_gyro(path: str | Path, topic: str) -> tuple[np.ndarray, np.ndarray]:
    """Angular velocities of the ``sensor_msgs/Imu`` messages on ``topic``: ``(t_ns (M,),
    omega (M, 3) rad/s)`` in the IMU frame, by header stamp.

    Raises:
        ValueError: no such topic, or it is not ``sensor_msgs/Imu``, or it is empty.
    """
    topics = bag_topics(path)
    if topics.get(topic) != IMU:
        raise ValueError(f"{path}: no sensor_msgs/Imu topic {topic!r} (topics: {sorted(topics)})")
    ts = typestore()
    t, om = [], []
    for _, msgtype, _, raw in iter_messages(path, {topic}):
        msg = ts.deserialize_cdr(raw, msgtype)
        t.append(cv.stamp_to_ns(msg.header.stamp))
        a = msg.angular_velocity
        om.append((a.x, a.y, a.z))
    if not t:
        raise ValueError(f"{path}: {topic} has no messages")
    order = np.argsort(t)
    return np.asarray(t, dtype=np.int64)[order], np.asarray(om, dtype=float)[order]
