"""Offline replay: the estimator over every frame of a bag (no middleware), the estimates
written as a bag and a CSV, and their accuracy against the bag's ground truth. With
``debug_outputs`` the output bag also gets the node's visualization topics (``debug_image``,
``markers``, ``path``: :mod:`rs_localizer.ros.visualization`), to open in Foxglove or RViz."""

from __future__ import annotations

import csv
import math
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..accuracy import GroundTruth, frame_errors, summarize_errors
from . import conversions as cv
from .bag_io import (
    CAMERA_INFO,
    GT_POSE,
    IMAGE,
    OUT_TYPES,
    _storage_plugin,
    _typestore,
    bag_topics,
    iter_messages,
    load_ground_truth,
    read_bag_info,
)

__all__ = ["CSV_COLUMNS", "ReplayResult", "replay"]


def _cdr(msg, msgtype: str, ts) -> bytes:
    """rclpy message -> CDR bytes with zeroed padding (rclpy leaves the alignment padding
    uninitialized, which makes bags non-reproducible): serialize, then let rosbags re-encode."""
    from rclpy.serialization import serialize_message

    return bytes(ts.serialize_cdr(ts.deserialize_cdr(serialize_message(msg), msgtype), msgtype))


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


def replay(
    path,
    *,
    solver: str = "r6p_1lin",
    options=None,
    source: str = "correspondences",
    line_delay: float | None = None,
    readout_time: float | None = None,
    direction: str | None = None,
    reference_row: float | None = None,
    stamp_row: float | None = None,
    landmarks_file=None,
    out_bag=None,
    out_csv=None,
    storage: str = "mcap",
    map_frame: str = "map",
    camera_frame: str | None = None,
    progress=sys.stderr,
    overwrite: bool = False,
    debug_outputs: bool = False,
    path_length: int = 1000,
    image_topic: str | None = None,
) -> ReplayResult:
    """Run :func:`estimate_rs_pose` over every frame of a bag, offline.

    RS timing defaults come from the bag's ``sequence.json`` (make-bag) and can be overridden.
    Writes the estimates (``/rs_localizer/pose``, ``twist``, ``pose_with_covariance``,
    ``odom``) to ``out_bag`` and one line per frame to ``out_csv`` when given, and compares
    with ``/ground_truth/*`` when the bag has them.

    ``debug_outputs`` (needs ``out_bag``) adds, for every solved frame,
    ``/rs_localizer/debug_image`` (stamped like the input frame, drawn on the bag's image of
    the same stamp when it has one on ``image_topic`` -- default: its ``sensor_msgs/Image``
    topic in the frame topic's namespace, else the first one -- or on a blank canvas),
    ``/rs_localizer/markers`` and ``/rs_localizer/path`` (the last ``path_length`` poses),
    as the node publishes them.

    Raises:
        ValueError: no frame topic for ``source``; ``debug_outputs`` without ``out_bag``.
        FileExistsError: ``out_bag`` exists and not ``overwrite``.
    """
    from ..estimation.estimate import EstimateOptions, estimate_rs_pose
    from ..maps import load_landmarks_csv
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
    if debug_outputs and out_bag is None:
        raise ValueError("debug outputs need an output bag (--out)")
    if debug_outputs and image_topic is None:
        images = [t for t, mt in topics.items() if mt == IMAGE]
        ns = frame_topic.rsplit("/", 1)[0] + "/"
        image_topic = next((t for t in images if t.startswith(ns)), images[0] if images else None)
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
    viz = _DebugWriter(writer, conns, ts, path_length, map_frame) if debug_outputs else None
    camera = None
    cam_key = None
    t0 = time.perf_counter()
    i = 0
    try:
        for topic, msgtype, t_log, raw in iter_messages(
            path, {frame_topic, info_topic} | ({image_topic} if viz and image_topic else set())
        ):
            msg = ts.deserialize_cdr(raw, msgtype)
            if viz is not None and topic == image_topic:
                viz.add_image(msg)
                continue
            if topic == info_topic:
                key = (tuple(msg.k), tuple(msg.d), msg.distortion_model, msg.width, msg.height)
                if key != cam_key:
                    camera = cv.camera_model_from_camera_info(
                        msg, line_delay, readout_time, direction, reference_row
                    )
                    cam_key = key
                continue
            i += 1
            stamp = cv.stamp_to_ns(msg.header.stamp)
            row = {
                "frame": i - 1,
                "stamp_ns": stamp,
                "success": False,
                "failure": "",
                "solver": solver,
            }
            if camera is None:
                row["failure"] = "no_camera_info"
            else:
                try:
                    if source == "keypoints":
                        kp = read_keypoints(msg)
                        j = np.clip(np.searchsorted(lm_index[0], kp.ids), 0, len(lm_index[0]) - 1)
                        known = lm_index[0][j] == kp.ids
                        uv, xyz, scores = (
                            kp.uv[known],
                            lm_index[1][j[known]],
                            (None if kp.scores is None else kp.scores[known]),
                        )
                    else:
                        c = read_correspondences(msg)
                        uv, xyz, scores = c.uv, c.xyz, c.scores
                except ValueError as e:
                    row["failure"] = getattr(e, "reason", "bad_cloud")
                else:
                    tic = time.perf_counter()
                    est = estimate_rs_pose(
                        uv, xyz, camera, solver=solver, options=options, scores=scores
                    )
                    row["time_ms"] = (time.perf_counter() - tic) * 1e3
                    out_stamp = stamp + int(
                        round(camera.time_offset(stamp_row, camera.reference_line) * 1e9)
                    )
                    row["out_stamp_ns"] = out_stamp
                    row["num_points"] = len(uv)
                    row["num_inliers"] = est.num_inliers
                    row["rmse_px"] = est.rmse_px
                    if est.success:
                        row["success"] = True
                        q = cv.quaternion_from_matrix(est.orientation)
                        row.update({f"q{a}": q[k] for k, a in enumerate("xyzw")})
                        row.update({f"p{a}": est.position[k] for k, a in enumerate("xyz")})
                        row.update({f"w{a}": est.angular_velocity[k] for k, a in enumerate("xyz")})
                        row.update({f"v{a}": est.linear_velocity[k] for k, a in enumerate("xyz")})
                        err = frame_errors(
                            est.orientation,
                            est.position,
                            est.angular_velocity,
                            est.linear_velocity,
                            gt,
                            out_stamp,
                        )
                        if err:
                            row.update({f"err_{k}": v for k, v in err.items()})
                        if writer is not None:
                            cf = camera_frame or msg.header.frame_id or "camera"
                            for name, m in (
                                ("pose", cv.pose_stamped(est, out_stamp, map_frame)),
                                ("twist", cv.twist_stamped(est, out_stamp, cf)),
                                (
                                    "pose_with_covariance",
                                    cv.pose_with_covariance_stamped(est, out_stamp, map_frame),
                                ),
                                ("odom", cv.odometry(est, out_stamp, map_frame, cf)),
                            ):
                                writer.write(conns[name], t_log, _cdr(m, OUT_TYPES[name], ts))
                            if viz is not None:
                                viz.frame(est, uv, xyz, camera, stamp, out_stamp, cf, t_log)
                    else:
                        row["failure"] = est.failure or "unknown"
            if not row["success"]:
                result.failures[row["failure"]] = result.failures.get(row["failure"], 0) + 1
            result.rows.append(row)
            _progress(i, n_frames, t0, progress)
    finally:
        if viz is not None:
            viz.flush()
        if writer is not None:
            writer.close()
    errors = [{k[4:]: v for k, v in r.items() if k.startswith("err_")} for r in result.rows]
    result.summary = summarize_errors(errors)
    if out_csv is not None:
        result.out_csv = Path(out_csv)
        _write_csv(result.out_csv, result.rows)
    return result


class _DebugWriter:
    """Writes the visualization topics of solved frames into the replay's output bag. A frame's
    debug image waits until the next frame (or the end), so that the bag's image with the same
    stamp has been read whatever the order of equal log times."""

    def __init__(self, writer, conns, ts, path_length, map_frame):
        from .visualization import VIZ_TOPICS, VisualizationBuilder

        self.writer, self.conns, self.ts, self.map_frame = writer, conns, ts, map_frame
        self.types = VIZ_TOPICS
        for name, mt in VIZ_TOPICS.items():
            conns[name] = writer.add_connection(f"/rs_localizer/{name}", mt, typestore=ts)
        self.builder = VisualizationBuilder(path_length)
        self.images = {}  # header stamp (ns) -> (image, encoding), the last few
        self.pending = None

    def add_image(self, msg):
        from ..frontends.image import image_from_msg

        try:
            self.images[cv.stamp_to_ns(msg.header.stamp)] = image_from_msg(msg)
        except ValueError:
            return
        while len(self.images) > 8:
            self.images.pop(next(iter(self.images)))

    def _write(self, name, t_log, msg):
        self.writer.write(self.conns[name], t_log, _cdr(msg, self.types[name], self.ts))

    def frame(self, est, uv, xyz, camera, stamp, out_stamp, camera_frame, t_log):
        self.flush()
        b = self.builder
        b.add_pose(est, out_stamp, self.map_frame)
        self._write("markers", t_log, b.markers(est, xyz, camera, out_stamp, self.map_frame))
        self._write("path", t_log, b.path(out_stamp, self.map_frame))
        self.pending = (est, uv, xyz, camera, stamp, camera_frame, t_log)

    def flush(self):
        if self.pending is None:
            return
        est, uv, xyz, camera, stamp, camera_frame, t_log = self.pending
        self.pending = None
        img, enc = self.images.get(stamp, (None, None))
        if img is not None and img.shape[:2] != (camera.height, camera.width):
            img, enc = None, None
        self._write(
            "debug_image",
            t_log,
            self.builder.debug_image(est, uv, xyz, camera, stamp, camera_frame, img, enc),
        )


def _count(path, topic) -> int:
    from rosbags.rosbag2 import Reader

    with Reader(path) as r:
        return sum(c.msgcount for c in r.connections if c.topic == topic)


CSV_COLUMNS = [
    "frame",
    "stamp_ns",
    "out_stamp_ns",
    "solver",
    "success",
    "failure",
    "num_points",
    "num_inliers",
    "rmse_px",
    "time_ms",
    "qx",
    "qy",
    "qz",
    "qw",
    "px",
    "py",
    "pz",
    "wx",
    "wy",
    "wz",
    "vx",
    "vy",
    "vz",
    "err_rot_deg",
    "err_pos_m",
    "err_angvel",
    "err_linvel",
]


def _write_csv(path, rows):
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=CSV_COLUMNS, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow(
                {
                    k: (f"{v:.9g}" if isinstance(v, float) and math.isfinite(v) else v)
                    for k, v in r.items()
                }
            )
