"""Offline replay: the localizer node over every frame of a bag, without middleware.

The frames go through the node's own per-frame pipeline
(:class:`~rs_localizer.ros.pipeline.FramePipeline`) configured from the node's parameters
(:mod:`..params`; :mod:`..param_files`: defaults, then ROS 2 parameter files, then
overrides), so a replay publishes what the node would: the pose, the frame's own twist
(``twist_single_frame``) and, with tracking (the default), the fused twist on ``twist`` and
``odom`` when it is final. The outputs are written as a bag (``/rs_localizer/<topic>``) and a
CSV (one line per frame), and compared with the bag's ground truth (``/ground_truth/*``) when
it has one. With ``debug_outputs`` the output bag also gets the node's visualization topics
(``debug_image``, ``markers``, ``path``: :mod:`rs_localizer.ros.visualization`), to open in
Foxglove or RViz.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import os
import shutil
import sys
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np

from ...accuracy import GroundTruth, frame_errors, frame_fit_summary, summarize_errors
from ...frontends.shared import SHARED_MAPS, LoadedMaps
from ...tracking.localizer import readout_warning
from .. import conversions as cv
from ..config import LocalizerConfig, build_config, default_timing_note, load_maps
from ..outputs import frame_messages, fused_messages
from ..param_files import parameter_values, read_params_file
from ..pipeline import FramePipeline, FrameResult, FusedOutput
from .bag_io import (
    CAMERA_INFO,
    COMPRESSED_IMAGE,
    GT_POSE,
    IMAGE,
    IMU,
    OUT_TYPES,
    bag_topics,
    iter_messages,
    load_ground_truth,
    progress_bar,
    read_bag_info,
    storage_plugin,
    typestore,
)

if TYPE_CHECKING:
    from ...camera import CameraModel
    from ...estimation.result import RSPoseEstimate
    from ...pose import PoseWithCovariance
    from ...tracking.video import LocalizerOutput

__all__ = [
    "BAG_TIMING",
    "CSV_COLUMNS",
    "DebugWriter",
    "ReplayResult",
    "ReplayRows",
    "open_out_bag",
    "replay",
    "replay_parameters",
    "to_cdr",
    "write_csv",
    "write_messages",
]

#: RS timing parameters a replay takes from the bag's ``sequence.json`` (``rs`` section, written
#: by make-bag and render-bag) when neither a parameter file nor an override sets them
#: (``rs.readout_time`` is not among them: with 0 the line delay is used, as recorded)
BAG_TIMING = ("rs.line_delay", "rs.direction", "rs.reference_row", "rs.stamp_row")


def to_cdr(msg: Any, msgtype: str, ts: Any) -> bytes:
    """rclpy message -> CDR bytes with zeroed padding (rclpy leaves the alignment padding
    uninitialized, which makes bags non-reproducible): serialize, then let rosbags re-encode."""
    from rclpy.serialization import serialize_message

    return bytes(ts.serialize_cdr(ts.deserialize_cdr(serialize_message(msg), msgtype), msgtype))


@dataclass
class ReplayResult:
    """Outcome of :func:`replay`: ``rows`` (one dict per frame, the CSV's columns),
    ``summary`` (accuracy against ground truth, :func:`~rs_localizer.accuracy.summarize_errors`
    of the published pose and twist), ``failures`` (reason -> frames), the files written, the
    configuration and parameter values used, the maps loaded for it (``maps``: the landmarks
    and the front end, :class:`~rs_localizer.frontends.shared.LoadedMaps`), and the pipeline's
    counters (``counts``: e.g. ``frames_with_gyro``, ``gyro_rejected``,
    ``gyro_disabled_inconsistent``, ``gyro_missing.<reason>``, as in the node's diagnostics),
    ``gyro_bias`` and ``gyro_bias_std`` ((3,) rad/s, IMU frame: the bias the last frame used,
    the online estimate with ``imu.estimate_bias``; None without ``imu.enabled``)."""

    rows: list = field(default_factory=list)
    summary: dict = field(default_factory=dict)
    failures: dict = field(default_factory=dict)
    out_bag: Path | None = None
    out_csv: Path | None = None
    config: LocalizerConfig | None = None
    maps: LoadedMaps | None = None
    parameters: dict = field(default_factory=dict)
    counts: dict = field(default_factory=dict)
    gyro_bias: np.ndarray | None = None
    gyro_bias_std: np.ndarray | None = None
    #: warnings about the replay's set-up for the user (e.g. a default line delay on images)
    notes: list = field(default_factory=list)

    @property
    def solved(self) -> int:
        """Frames with a pose."""
        return sum(1 for r in self.rows if r["success"])


def replay_parameters(
    path: str | os.PathLike,
    params_files: Iterable[str | os.PathLike] = (),
    params: Mapping[str, Any] | None = None,
    source: str | None = None,
) -> tuple[dict[str, Any], list[str]]:
    """The node parameter values of a replay of the bag ``path``: the defaults, then
    ``params_files`` in order (ROS 2 parameter files, as ``--params-file`` gives them to the
    node), then ``params`` (overrides by parameter name). Then, for what none of them sets: the
    :data:`BAG_TIMING` values of the bag's ``sequence.json``, and with ``source`` keypoints the
    bag's ``landmarks.csv`` as ``landmarks_file``. Returns ``(values, ignored file entries)``.

    Raises:
        ConfigError (a ValueError): see :func:`..param_files.parameter_values`.
    """
    params_files = list(params_files)
    values, ignored = parameter_values(params_files, params)
    given = set(params or {}).union(*(read_params_file(f) for f in params_files))
    rs = read_bag_info(Path(path)).get("rs", {})
    for name in BAG_TIMING:
        key = name.split(".", 1)[1]
        if name not in given and rs.get(key) is not None:
            values[name] = str(rs[key]) if name == "rs.direction" else float(rs[key])
    if source == "keypoints" and not values["landmarks_file"]:
        values["landmarks_file"] = str(Path(path) / "landmarks.csv")
    return values, ignored


def _timing_given(path: Path, params_files: list, params: Mapping[str, Any] | None) -> bool:
    """Whether the parameters (files or overrides) or the bag's ``sequence.json`` set the RS
    timing (``rs.line_delay`` or ``rs.readout_time``)."""
    given = set(params or {}).union(*(read_params_file(f) for f in params_files))
    rs = read_bag_info(Path(path)).get("rs", {})
    from_bag = rs.get("line_delay") is not None or rs.get("readout_time") is not None
    return bool(given & {"rs.line_delay", "rs.readout_time"}) or from_bag


def _imu_mount_note(cfg: LocalizerConfig, info: dict) -> str | None:
    """A note when the bag's ``sequence.json`` (make-bag, render-bag) gives the IMU's mount
    (``imu.rotation_imu_from_camera``) and ``imu.rotation`` differs from it by over 1 deg:
    the gyro would contradict the image (a wrong mount), and the frames be solved without it."""
    R_imu_cam = info.get("imu", {}).get("rotation_imu_from_camera")
    if cfg.imu is None or R_imu_cam is None:
        return None
    from ...geometry import rotation_angle_deg
    from ..conversions import quaternion_from_matrix

    R = np.asarray(R_imu_cam, float).T  # (IMU -> camera optical frame, as imu.rotation)
    if rotation_angle_deg(R, np.asarray(cfg.imu.R_cam_imu, float)) <= 1.0:
        return None
    q = ", ".join(f"{v:.6g}" for v in quaternion_from_matrix(R, orthonormal=True))
    return (
        f"the bag's sequence.json gives the IMU's mount, imu.rotation:=[{q}], and imu.rotation "
        "differs from it: the gyro will contradict the image and frames be solved without it "
        f'(pass -p "imu.rotation:=[{q}]")'
    )


def _frame_topic(topics: dict, source: str, cfg: LocalizerConfig, info: dict, image_topic):
    """The bag topic of the frames for ``source``."""
    if source != "image":
        return next((t for t in topics if t.rstrip("/").endswith("/" + source)), None)
    want = COMPRESSED_IMAGE if cfg.image_transport == "compressed" else IMAGE
    images = [t for t, mt in topics.items() if mt == want]
    for t in (image_topic, info.get("topics", {}).get("image")):
        if t in images:
            return t
    return images[0] if images else None


def replay(
    path: str | os.PathLike,
    *,
    params_files: Iterable[str | os.PathLike] = (),
    params: Mapping[str, Any] | None = None,
    source: str | None = None,
    out_bag: str | os.PathLike | None = None,
    out_csv: str | os.PathLike | None = None,
    storage: str = "mcap",
    progress: TextIO | None = sys.stderr,
    overwrite: bool = False,
    debug_outputs: bool = False,
    path_length: int = 1000,
    image_topic: str | None = None,
    imu_topic: str | None = None,
    log: Any = None,
) -> ReplayResult:
    """Run the localizer node's per-frame pipeline over every frame of a bag, offline.

    Args:
        path: bag directory (make-bag or render-bag output, or a recording), or its storage
            file (then its directory is read, with its sequence.json).
        params_files: the node's ROS 2 parameter files (later ones win; see
            :func:`..param_files.read_params_file` for the sections read).
        params: overrides by parameter name (``{"solver": "p3p", "tracking.enabled": False}``).
            RS timing and the keypoints' landmarks that nothing sets come from the bag
            (:func:`replay_parameters`).
        source: the frames: ``correspondences`` (``*/correspondences``), ``keypoints``
            (``*/keypoints`` + ``landmarks_file``) or ``image`` (an image topic through the
            front end of the ``frontend`` parameter); None: ``image`` when ``frontend`` is not
            ``none``, else ``correspondences``.
        out_bag: write the outputs here (``/rs_localizer/pose``, ``twist``,
            ``twist_single_frame``, ``pose_with_covariance``, ``odom``: the node's messages,
            each logged at the bag time of the frame that made it final). out_csv: one line
            per frame (:data:`CSV_COLUMNS`: the pose, the twist on ``twist`` and the frame's own
            twist, errors against ground truth). storage: ``mcap`` or ``sqlite3``.
        debug_outputs: (needs ``out_bag``) add, for every solved frame,
            ``/rs_localizer/debug_image`` (stamped like the input frame, drawn on the input
            image in image mode, else on the bag's image of the same stamp on ``image_topic``
            -- default: its ``sensor_msgs/Image`` topic in the frame topic's namespace, else
            the first one -- or on a blank canvas), ``/rs_localizer/markers`` and
            ``/rs_localizer/path`` (the last ``path_length`` poses), as the node publishes them.
        image_topic: with ``source`` image the frames' topic (default: the bag's image topic,
            as ``sequence.json`` names it).
        imu_topic: with ``imu.enabled`` the ``sensor_msgs/Imu`` topic whose gyro the frames
            use (default: the bag's only IMU topic); all its samples are buffered first.
        progress: stream for the progress bar (None: none). log: logger for the pipeline's
            warnings (None: silent).

    Raises:
        ValueError: no frame topic for ``source``; ``debug_outputs`` without ``out_bag``;
            ``imu.enabled`` without one IMU topic (or ``imu_topic`` not one); invalid
            parameters (a :class:`~rs_localizer.ros.params.ConfigError`).
        FileExistsError: ``out_bag`` exists and not ``overwrite``.
    """
    path = Path(path)
    if path.is_file() and (path.parent / "metadata.yaml").is_file():
        path = path.parent  # BAG/BAG.mcap: the bag directory, with its sequence.json
    params_files = list(params_files)
    values, cfg, maps, source = _replay_config(path, params_files, params, source)
    ts = typestore()
    topics = bag_topics(path)
    frame_topic, info_topic, viz_topic, imu_topic = _replay_topics(
        path, topics, cfg, source, image_topic, imu_topic, debug_outputs, out_bag
    )
    if cfg.imu is not None:
        # (offline every sample is buffered before the frames: no waiting)
        cfg = dataclasses.replace(cfg, imu=dataclasses.replace(cfg.imu, wait=0.0))
    gt = load_ground_truth(path) if GT_POSE in topics else GroundTruth()
    n_frames = _count(path, frame_topic)
    result = ReplayResult(config=cfg, maps=maps, parameters=values)
    note = None if _timing_given(path, params_files, params) else default_timing_note(cfg)
    if note is not None:
        result.notes.append(note)
    note = _imu_mount_note(cfg, read_bag_info(path))
    if note is not None:
        result.notes.append(note)
    writer, conns = None, {}
    if out_bag is not None:
        writer, conns = open_out_bag(Path(out_bag), storage, overwrite, ts)
        result.out_bag = Path(out_bag)
    viz = DebugWriter(writer, conns, ts, path_length, cfg.map_frame) if debug_outputs else None
    rows = ReplayRows(gt)
    pipeline = FramePipeline(cfg, log=log, imu_span=math.inf, maps=maps)
    _run_frames(
        path,
        ts,
        pipeline,
        cfg,
        source,
        (frame_topic, info_topic, viz_topic, imu_topic),
        rows,
        writer,
        conns,
        viz,
        n_frames,
        progress,
    )
    _summarize(result, rows, pipeline, out_csv)
    tracking = pipeline.tracking_values()
    if tracking.get("readout_suspect") == "true":
        result.notes.append(readout_warning(tracking["readout_contradicted"]))
    return result


def _replay_config(
    path: Path, params_files, params, source: str | None
) -> tuple[dict[str, Any], LocalizerConfig, LoadedMaps, str]:
    """Stage 1 of :func:`replay`: ``(parameter values, configuration, its maps loaded,
    source)``; ``source`` None becomes ``image`` with a front end, else ``correspondences``.

    Raises:
        ValueError: invalid parameters; ``source`` image without a front end.
    """
    values, _ = replay_parameters(path, params_files, params, source)
    token = object()
    try:
        cfg = build_config(values)
        maps = load_maps(cfg, owner=token)
    finally:
        SHARED_MAPS.release(token)  # (maps keeps what it loaded)
    if source is None:
        source = "image" if maps.frontend is not None else "correspondences"
    if source == "image" and maps.frontend is None:
        raise ValueError("--source image needs a front end (the frontend parameter is none)")
    # (offline every camera_info before a frame has been read: no waiting)
    cfg = dataclasses.replace(cfg, camera_info_wait=0.0)
    return values, cfg, maps, source


def _replay_topics(
    path: Path,
    topics: dict[str, str],
    cfg: LocalizerConfig,
    source: str,
    image_topic: str | None,
    imu_topic: str | None,
    debug_outputs: bool,
    out_bag: Any,
) -> tuple[str, str | None, str | None, str | None]:
    """Stage 2 of :func:`replay`: the bag topics ``(frames, camera_info, images to draw the
    debug image on or None, IMU or None)``.

    Raises:
        ValueError: no frame topic; ``debug_outputs`` without ``out_bag``; ``imu.enabled``
            without one IMU topic (or ``imu_topic`` not one).
    """
    info = read_bag_info(path)
    frame_topic = _frame_topic(topics, source, cfg, info, image_topic)
    info_topic = next((t for t, mt in topics.items() if mt == CAMERA_INFO), None)
    if frame_topic is None:
        what = f"*/{source}" if source != "image" else f"{cfg.image_transport} image"
        raise ValueError(f"{path}: no {what} topic (topics: {sorted(topics)})")
    if debug_outputs and out_bag is None:
        raise ValueError("debug outputs need an output bag (--out)")
    if debug_outputs and source != "image" and image_topic is None:
        images = [t for t, mt in topics.items() if mt == IMAGE]
        ns = frame_topic.rsplit("/", 1)[0] + "/"
        image_topic = next((t for t in images if t.startswith(ns)), images[0] if images else None)
    viz_topic = image_topic if debug_outputs and source != "image" else None
    if cfg.imu is not None:
        imus = [t for t, mt in topics.items() if mt == IMU]
        if imu_topic is None and len(imus) == 1:
            imu_topic = imus[0]
        if imu_topic not in imus:
            raise ValueError(
                f"{path}: imu.enabled needs a sensor_msgs/Imu topic (--imu-topic; IMU topics: "
                f"{imus})"
            )
    return frame_topic, info_topic, viz_topic, imu_topic


def open_out_bag(out_bag: Path, storage: str, overwrite: bool, ts: Any) -> tuple[Any, dict]:
    """The output bag of a replay (of a camera or a rig): its open writer and its connections
    by output name (:data:`OUT_TYPES`, as ``/rs_localizer/<name>``).

    Raises:
        FileExistsError: ``out_bag`` exists and not ``overwrite``.
    """
    from rosbags.rosbag2 import Writer

    if out_bag.exists():
        if not overwrite:
            raise FileExistsError(f"{out_bag} exists (use --overwrite)")
        shutil.rmtree(out_bag)
    writer = Writer(out_bag, version=9, storage_plugin=storage_plugin(storage))
    writer.open()
    conns = {}
    for name, mt in OUT_TYPES.items():
        conns[name] = writer.add_connection(f"/rs_localizer/{name}", mt, typestore=ts)
    return writer, conns


def _run_frames(
    path: Path,
    ts: Any,
    pipeline: FramePipeline,
    cfg: LocalizerConfig,
    source: str,
    topics: tuple[str, str | None, str | None, str | None],
    rows: ReplayRows,
    writer: Any,
    conns: dict,
    viz: DebugWriter | None,
    n_frames: int,
    progress: TextIO | None,
) -> None:
    """Stage 4 of :func:`replay`: the IMU samples buffered (with ``cfg.imu``), then every frame
    (and camera_info, and image to draw on) of the bag, in log-time order, through
    ``pipeline``; the rows and the outputs recorded, then the twists still pending at the end
    of the video. The debug outputs and the output bag are closed in any case."""
    frame_topic, info_topic, viz_topic, imu_topic = topics
    if cfg.imu is not None:
        for _, msgtype, _, raw in iter_messages(path, {imu_topic}):
            pipeline.add_imu(ts.deserialize_cdr(raw, msgtype))
    bar = progress_bar(progress, n_frames)
    try:
        i = 0
        t_log = 0
        wanted = OUT_TYPES.__contains__
        for topic, msgtype, t_log, raw in iter_messages(
            path, {frame_topic, info_topic} | ({viz_topic} if viz_topic else set())
        ):
            msg = ts.deserialize_cdr(raw, msgtype)
            if topic == viz_topic:
                viz.add_image(msg)
                continue
            if topic == info_topic:
                pipeline.add_camera_info(msg)
                continue
            i += 1
            res = pipeline.process(msg, source)
            rows.add(i - 1, res, cfg.solver)
            msgs = frame_messages(res, cfg.map_frame, wanted)
            rows.fused(res.fused)
            write_messages(writer, conns, ts, t_log, msgs)
            if viz is not None and res.solved:
                if res.image is not None:
                    viz.add_decoded(*res.image)
                viz.frame(res, t_log)
            bar.update()
        last = pipeline.flush()  # (the end of the video: the twists still pending)
        rows.fused(last)
        write_messages(writer, conns, ts, t_log, fused_messages(last, cfg.map_frame))
    finally:
        bar.close()
        if viz is not None:
            viz.flush()
        if writer is not None:
            writer.close()


def _summarize(
    result: ReplayResult, rows: ReplayRows, pipeline: FramePipeline, out_csv: Any
) -> None:
    """Stage 5 of :func:`replay`: the rows, counts, gyro bias, failures and error summary
    into ``result``; the CSV written to ``out_csv`` (None: none)."""
    result.rows, result.failures, result.summary = rows.summary()
    result.counts = pipeline.stats.snapshot().counts
    if result.counts.get("map_fit_doubtful"):  # (the map-fit check, as the node warns)
        result.notes.append(pipeline.map_fit_text())
    bias = pipeline.gyro_bias_values()
    if bias is not None:
        result.gyro_bias, result.gyro_bias_std = bias
    if out_csv is not None:
        result.out_csv = Path(out_csv)
        write_csv(result.out_csv, result.rows)


def write_messages(
    writer: Any, conns: dict, ts: Any, t_log: int, messages: Iterable[tuple[str, Any]]
) -> None:
    """Write ``(topic, message)`` pairs (:mod:`rs_localizer.ros.outputs`) into an output bag of
    :func:`open_out_bag` at log time ``t_log`` (ns); topics it does not hold (``tf``) are left
    out by the caller's ``wanted``; ``writer`` None: nothing."""
    if writer is None:
        return
    for topic, m in messages:
        writer.write(conns[topic], t_log, to_cdr(m, OUT_TYPES[topic], ts))


def _xyz(prefix: str, v) -> dict:
    return {f"{prefix}{a}": float(v[k]) for k, a in enumerate("xyz")}


class ReplayRows:
    """The rows of a replay's CSV and summary, one per frame (a camera's frame, or a rig
    frame of :func:`~rs_localizer.ros.bags.rig_bag.replay_rig`): the pose when solved, the
    published twist (the frame's own, or the fused one when it comes) and the errors against
    ground truth (``gt``). Columns: :data:`CSV_COLUMNS`."""

    def __init__(self, gt: GroundTruth):
        self.gt = gt
        self.rows: list[dict] = []
        self.waiting: dict[int, tuple] = {}  # out stamp -> (row, orientation, position)

    def add(self, index: int, res: FrameResult, solver: str) -> None:
        """A camera's frame (the node's pipeline's result ``res``, solved by ``solver``)."""
        row = {
            "frame": index,
            "stamp_ns": res.stamp_ns,
            "success": res.solved,
            "failure": res.failure or "",
            "solver": solver,
        }
        if res.out_stamp_ns is not None:
            row["out_stamp_ns"] = res.out_stamp_ns
        est = res.estimate
        if est is not None:
            row["time_ms"] = res.times.get("estimate", float("nan")) * 1e3
            row["num_points"] = len(res.points2d)
            row["num_inliers"] = est.num_inliers
            row["rmse_px"] = est.rmse_px
        self.rows.append(row)
        if res.solved:
            self._posed(row, res.output, res.out_stamp_ns, res.twist_now)

    def add_rig(self, index: int, out: LocalizerOutput, twist_now: bool) -> None:
        """A rig frame (``out``, solved or failed; ``twist_now``: its own twist is the one
        published, without tracking): its stamp is the rig frame's time, ``num_points`` the
        rows of all its cameras, ``failure`` the estimator's or the rig's reason (``error``:
        the estimator raised)."""
        est = out.estimate
        row = {
            "frame": index,
            "stamp_ns": out.stamp_ns,
            "out_stamp_ns": out.stamp_ns,
            "success": out.success,
            "failure": "" if out.success else (est.failure if est is not None else "error"),
            "solver": est.solver if est is not None else "",
        }
        if est is not None:
            row["num_points"] = out.num_points
            row["num_inliers"] = est.num_inliers
            row["rmse_px"] = est.rmse_px
        self.rows.append(row)
        if out.success:
            self._posed(row, est, out.stamp_ns, twist_now)

    def _posed(self, row: dict, out: PoseWithCovariance, stamp: int, twist_now: bool) -> None:
        q = cv.quaternion_from_matrix(out.pose.orientation)
        row.update({f"q{a}": q[k] for k, a in enumerate("xyzw")})
        row.update(_xyz("p", out.pose.position))
        row.update(_xyz("single_w", out.pose.angular_velocity))
        row.update(_xyz("single_v", out.pose.linear_velocity))
        self.waiting[stamp] = (row, out.pose.orientation, out.pose.position)
        if twist_now:
            self._twist(stamp, out.pose.angular_velocity, out.pose.linear_velocity)

    def fused(self, fused: Iterable[FusedOutput]) -> None:
        """The fused twists now final (of frames added before)."""
        for f in fused:
            self._twist(f.stamp_ns, f.source.pose.angular_velocity, f.source.pose.linear_velocity)

    def _twist(self, stamp: int, w, v) -> None:
        item = self.waiting.pop(stamp, None)
        if item is None:
            return
        row, R, p = item
        row.update(_xyz("w", w))
        row.update(_xyz("v", v))
        self._errors(row, R, p, w, v, stamp)

    def _errors(self, row, R, p, w, v, stamp) -> None:
        err = frame_errors(R, p, w, v, self.gt, stamp)
        if err:
            row.update({f"err_{k}": val for k, val in err.items()})

    def pose_pairs(self) -> tuple[list, list]:
        """The solved frames' poses ``(R, p)`` and their ground truth's, for the rigid fit of
        the frames."""
        est, gt = [], []
        for r in self.rows:
            s = self.gt.nearest(r.get("out_stamp_ns", r["stamp_ns"])) if "qw" in r else None
            if s is not None:
                q = [r[f"q{a}"] for a in "xyzw"]
                est.append((cv.matrix_from_quaternion(q), np.array([r[f"p{a}"] for a in "xyz"])))
                gt.append((self.gt.orientation[s], np.asarray(self.gt.position[s])))
        return est, gt

    def finish(self) -> list[dict]:
        """The rows; solved frames whose twist never came get their pose errors alone."""
        for stamp, (row, R, p) in self.waiting.items():
            self._errors(row, R, p, None, None, stamp)
        self.waiting.clear()
        return self.rows

    def summary(self) -> tuple[list[dict], dict[str, int], dict]:
        """``(rows, failures, summary)`` at the end of the video (:meth:`finish`):
        ``failures`` reason -> frames, ``summary`` the errors of the published pose and twist
        against ground truth (:func:`~rs_localizer.accuracy.summarize_errors`) and, with
        errors, ``frame_fit`` (the errors after a rigid fit of the frames,
        :func:`~rs_localizer.accuracy.frame_fit_summary`)."""
        rows = self.finish()
        failures: dict[str, int] = {}
        for r in rows:
            if not r["success"]:
                failures[r["failure"]] = failures.get(r["failure"], 0) + 1
        summary = summarize_errors(
            [{k[4:]: v for k, v in r.items() if k.startswith("err_")} for r in rows]
        )
        fit = frame_fit_summary(*self.pose_pairs())
        if fit is not None and summary.get("frames"):
            summary["frame_fit"] = fit
        return rows, failures, summary


class DebugWriter:
    """Writes the visualization topics of solved frames into the replay's output bag,
    ``/rs_localizer/<prefix><topic>`` for each of ``topics`` (of
    :data:`~rs_localizer.ros.visualization.VIZ_TOPICS`; None: all), drawn by the node's
    :class:`~rs_localizer.ros.visualization.VisualizationBuilder`. A camera's replay gives it
    each solved frame (:meth:`frame`): that frame's debug image waits until the next frame (or
    the end), so that the bag's image with the same stamp has been read whatever the order of
    equal log times. A rig's replay writes each topic itself (:meth:`debug_image`,
    :meth:`markers`, :meth:`path`)."""

    def __init__(
        self,
        writer: Any,
        conns: dict,
        ts: Any,
        path_length: int,
        map_frame: str,
        prefix: str = "",
        topics: Iterable[str] | None = None,
    ):
        from ..visualization import VIZ_TOPICS, VisualizationBuilder

        self.writer, self.conns, self.ts, self.map_frame = writer, conns, ts, map_frame
        self.types, self.prefix = VIZ_TOPICS, prefix
        for name in VIZ_TOPICS if topics is None else topics:
            conns[prefix + name] = writer.add_connection(
                f"/rs_localizer/{prefix}{name}", VIZ_TOPICS[name], typestore=ts
            )
        self.builder = VisualizationBuilder(path_length)
        self.images = {}  # header stamp (ns) -> (image, encoding), the last few
        self.pending = None

    def add_image(self, msg: Any) -> None:
        from ..image_codec import ImageRejected, decode_image

        try:
            self.add_decoded(*decode_image(msg), cv.stamp_to_ns(msg.header.stamp))
        except ImageRejected:
            return

    def add_decoded(self, image: np.ndarray, encoding: str, stamp_ns: int) -> None:
        self.images[int(stamp_ns)] = (image, encoding)
        while len(self.images) > 8:
            self.images.pop(next(iter(self.images)))

    def _write(self, name: str, t_log: int, msg: Any) -> None:
        self.writer.write(
            self.conns[self.prefix + name], t_log, to_cdr(msg, self.types[name], self.ts)
        )

    def markers(
        self,
        est: RSPoseEstimate,
        X: np.ndarray,
        camera: CameraModel,
        out_stamp_ns: int,
        t_log: int,
    ) -> None:
        """``markers`` of a frame posed at ``out_stamp_ns``, logged at ``t_log``."""
        self._write(
            "markers", t_log, self.builder.markers(est, X, camera, out_stamp_ns, self.map_frame)
        )

    def path(self, est: RSPoseEstimate, out_stamp_ns: int, t_log: int) -> None:
        """The pose of ``est`` at ``out_stamp_ns`` added to the path, and ``path`` written."""
        self.builder.add_pose(est, out_stamp_ns, self.map_frame)
        self._write("path", t_log, self.builder.path(out_stamp_ns, self.map_frame))

    def debug_image(
        self,
        est: RSPoseEstimate,
        uv: np.ndarray,
        X: np.ndarray,
        camera: CameraModel,
        stamp_ns: int,
        frame_id: str,
        t_log: int,
        image: tuple | None = None,
    ) -> None:
        """``debug_image`` of a frame stamped ``stamp_ns``, drawn on ``image`` ((image,
        encoding) of the same stamp; None, or not of the camera's size: a blank canvas)."""
        img, enc = (None, None) if image is None else image
        if img is not None and img.shape[:2] != (camera.height, camera.width):
            img, enc = None, None
        self._write(
            "debug_image",
            t_log,
            self.builder.debug_image(est, uv, X, camera, stamp_ns, frame_id, img, enc),
        )

    def frame(self, res: FrameResult, t_log: int) -> None:
        self.flush()
        self.markers(res.estimate, res.points3d, res.camera, res.out_stamp_ns, t_log)
        self.path(res.estimate, res.out_stamp_ns, t_log)
        self.pending = (res, t_log)

    def flush(self) -> None:
        """Write the debug image of the frame still waiting (if any)."""
        if self.pending is None:
            return
        res, t_log = self.pending
        self.pending = None
        self.debug_image(res.estimate, res.points2d, res.points3d, res.camera, res.stamp_ns,
                         res.frame_id, t_log, self.images.get(res.stamp_ns))  # fmt: skip


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
    "single_wx",
    "single_wy",
    "single_wz",
    "single_vx",
    "single_vy",
    "single_vz",
]


def write_csv(path: str | os.PathLike, rows: list[dict]) -> None:
    """Write a replay's ``rows`` (:class:`ReplayRows`) as CSV, :data:`CSV_COLUMNS`."""
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
