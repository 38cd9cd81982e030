"""``rs_localizer_node``: rolling-shutter camera localization from 2D-3D correspondences.

A thin layer over :func:`rs_localizer.estimate_rs_pose` (no solver logic here):
decode the input, pick the camera model, call the estimator, publish, count. Images go through
an image front end (:mod:`rs_localizer.frontends`: ArUco markers or natural features against a
map) first, then down the same path as a correspondence cloud.

Threads: the subscription callbacks only count frames and put them into a bounded queue
(``queue_size``; a full queue drops its oldest frame, counted as skipped); one worker thread
solves and publishes, so the executor stays free for camera_info, parameters and diagnostics
however slow a frame is (the accounting: :mod:`rs_localizer.ros.frame_queue`).

Subscriptions (best effort, history 100 clouds / 10 images / 5 camera_info; overridable with
``qos_overrides.<topic>.subscription.*``):
    correspondences  sensor_msgs/PointCloud2  u, v [px, distorted], x, y, z [m, map frame]
                                              (+ id uint32, + score float32)
    keypoints        sensor_msgs/PointCloud2  u, v, id; 3D points from ``landmarks_file``
    camera_info      sensor_msgs/CameraInfo
    imu              sensor_msgs/Imu (sensor-data QoS), only with ``imu.enabled``: its gyro
    image            sensor_msgs/Image (mono8/rgb8/bgr8/rgba8/bgra8), only when ``frontend`` is
                     ``aruco`` or ``features``; header.stamp = capture time of ``rs.stamp_row``
    image/compressed sensor_msgs/CompressedImage (JPEG, PNG) instead, with
                     ``image_transport: compressed`` (topic: the resolved ``image`` + /compressed)
Publications (reliable, depth 10):
    pose                  geometry_msgs/PoseStamped              map_frame, reference-row time
    twist                 geometry_msgs/TwistStamped             camera frame, rad/s and m/s; with
                          tracking (default) the fused twist of the frame ``tracking.lag``
                          frames back, stamped with that frame's time
    twist_single_frame    geometry_msgs/TwistStamped             the frame's own twist
    pose_with_covariance  geometry_msgs/PoseWithCovarianceStamped
    odom                  nav_msgs/Odometry                      pose + (fused) twist, with the
                          twist's stamp
    /tf                   tf2_msgs/TFMessage (if importable and publish_tf)
    /diagnostics          diagnostic_msgs/DiagnosticArray
    correspondences_out   sensor_msgs/PointCloud2 (image mode, ``republish_correspondences``):
                          the front end's u, v, x, y, z, id (+ score), stamped like the image
    debug_image, markers, path  visualization, built only when subscribed
                          (:mod:`rs_localizer.ros.visualization`, parameters ``viz.*``)
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np
from rclpy.node import Node

from ..correspondences import FrontendHooks
from ..frontends.shared import LoadedMaps
from .config import LocalizerConfig, build_config, default_timing_note, load_maps
from .core import NodeCore, QueuedFrame, TakenFrame
from .diagnostics import CameraPart, GyroState, StatusParts, frontend_values
from .frame_queue import frame_accounting
from .outputs import FrameOutcome, camera_outcome, publish_frame
from .params import PARAMETERS, ConfigError
from .pipeline import FramePipeline, StatsSnapshot, log_warm_up
from .rig_node import RigMode

__all__ = ["PARAMETERS", "CameraMode", "RSLocalizerNode", "camera_status_parts"]


class CameraMode:
    """The single camera's part of :class:`RSLocalizerNode` (``rig.cameras`` empty): the
    camera's topics without prefix, its frames through a
    :class:`~rs_localizer.ros.pipeline.FramePipeline` on the node's worker thread, what the
    pipeline returns published, the camera's diagnostics. The node
    (:class:`~rs_localizer.ros.core.NodeCore`, ``node``) holds the plumbing; this object what
    the camera's mode does at each phase (the interface :class:`~.core.NodeCore` names; the
    rig's is :class:`~rs_localizer.ros.rig_node.RigMode`). Made with the node's state
    (``_init_state``): the pipeline without configuration, the camera's input stage and
    counts (named ""), the frame queue."""

    #: the single camera counts its image frames (``image_frames``)
    count_image_frames = True
    #: the single camera's topics and texts (:class:`~rs_localizer.ros.core.NodeCore`)
    cloud_kind = "correspondences"
    image_topic = "image"
    keypoints_always = True
    images_text = None
    info_qos_overridable = True
    busy_key = "skipped"
    busy_text = (
        "busy: frame queue full (queue_size {size}), dropped the oldest waiting frame "
        "[{dropped} skipped so far]"
    )
    #: the mode in the managed node's start line (``unconfigured (lifecycle node...)``)
    mode_note = ""

    def __init__(self, node: NodeCore):
        self.node = node
        self.pipeline = FramePipeline(log=node.get_logger(), stopped=node.stopping)
        # (the one camera, named "")
        node.set_cameras({"": self.pipeline.camera_input}, {"": self.pipeline.stats},
                         self.pipeline.log)  # fmt: skip

    @property
    def cfg(self) -> LocalizerConfig | None:
        """The configuration built from the parameters (None: not configured)."""
        return self.pipeline.config

    def configured_as(self) -> str:
        """What the managed node's ``configured: ... (inactive)`` line names."""
        return f"solver {self.cfg.solver}"

    def camera_of(self, item: QueuedFrame) -> None:
        """None: :meth:`take_frame` finds the camera model (the pipeline's)."""
        return None

    def configure(self) -> None:
        """Parameters -> configuration (camera model, landmarks, front end and its map), then
        the JIT warm-up. Raises RuntimeError for invalid parameters."""
        try:
            cfg, maps = self.changed_configuration({})
        except ConfigError as e:
            raise RuntimeError(f"invalid parameters: {e}") from None
        self._apply_config(cfg, maps)
        self._warm_up(cfg, background=True)

    def _warm_up(self, cfg: LocalizerConfig, background: bool = False) -> None:
        """With ``warmup``, the kernels of ``cfg``'s solver, tracking and gyro compiled or
        loaded (:func:`.pipeline.log_warm_up`; ``background``: its)."""
        if self.node.get_parameter("warmup").value:
            log_warm_up(cfg.solver, cfg.options, cfg.tracking, self.node.get_logger(),
                        cfg.imu is not None, background)  # fmt: skip

    def imu_input(self) -> Callable[[Any], str | None] | None:
        """With ``imu.enabled`` (read-only), what takes an ``imu`` message: the pipeline's
        gyro (:meth:`.pipeline.FramePipeline.add_imu`); else None
        (:meth:`.core.NodeCore._subscribe_imu`)."""
        return None if self.cfg.imu is None else self.pipeline.add_imu

    def frame_inputs_destroyed(self) -> None:
        """After the frame inputs' end (the frames still queued dropped): the track is
        dropped too (nothing is left for :meth:`.core.NodeCore._end_video` to publish)."""
        self.pipeline.drop_tracker()  # (a reactivated node starts a new track)

    def close_track(self) -> list[FrameOutcome]:
        """None left: the single camera's track is dropped with its frame inputs."""
        return []

    def log_ready(self) -> None:
        cfg = self.cfg
        if cfg.line_delay == 0 and cfg.readout_time == 0:
            self.node.get_logger().warning(
                "rs.line_delay and rs.readout_time are 0: global-shutter "
                "timing, the published twist will be zero"
            )
        text = f"ready: solver {cfg.solver}, line delay {cfg.line_delay * 1e6:.2f} us/line"
        if cfg.readout_time > 0:
            text += f", readout {cfg.readout_time * 1e3:.2f} ms"
        text += f", intrinsics from {'parameters' if cfg.fallback else 'camera_info'}"
        landmarks = self._maps().landmarks
        if landmarks:
            text += f", {len(landmarks[0])} landmarks from {cfg.landmarks_file}"
        if "" in self.node.images_of:
            text += f", {cfg.frontend_kind} front end on {self.node.images_of['']} (map "
            text += f"{cfg.frontend_map})"
        self.node.get_logger().info(text)

    # ------------------------------------------------------------------ parameters
    def _maps(self) -> LoadedMaps:
        """The landmarks and the front end loaded for the configuration in use."""
        return self.pipeline.maps

    def _apply_config(self, cfg: LocalizerConfig, maps: LoadedMaps):
        old = self.cfg
        old_fe = self._maps().frontend
        # (the RS timing may have changed: camera models rebuilt)
        self.pipeline.configure(cfg, maps)
        self.node.queue_size, self.node.frontend_kind = cfg.queue_size, cfg.frontend_kind
        self.node.image_transport, self.node.landmarks = cfg.image_transport, maps.landmarks
        self.node.republish, self.node.map_frame = (
            bool(cfg.republish_correspondences),
            cfg.map_frame,
        )
        if old is not None and old_fe is not None and maps.frontend is not old_fe:
            self.node.get_logger().info(
                f"reloaded the {cfg.frontend_kind} front end from {cfg.frontend_map}"
            )
        detector = None if maps.frontend is None else maps.frontend.marker_detector_note()
        if detector is not None and maps.frontend is not old_fe:
            # which marker detector runs (a missing AprilTag library: a warning with the
            # install line)
            line, fallback = detector
            log = self.node.get_logger().warning if fallback else self.node.get_logger().info
            log(f"marker detector: {line}")
        if cfg.republish_correspondences and maps.frontend is not None:
            self.node.open_found_output()
        note = default_timing_note(cfg) if maps.frontend is not None else None  # (images)
        if note is not None:
            self.node.warn_once("default_timing", note)

    def changed_configuration(self, overrides: dict) -> tuple[LocalizerConfig, LoadedMaps]:
        """The configuration of the parameters with ``overrides`` and the maps it names
        (a changed ``landmarks_file`` or ``frontend_map`` loaded; ConfigError: not loadable)."""
        cfg = build_config(self.node.param_values(overrides))
        return cfg, load_maps(cfg, owner=self, current=self._maps())

    def apply_change(self, built: tuple[LocalizerConfig, LoadedMaps], overrides: dict) -> None:
        """The pipeline reconfigured (:meth:`_apply_config`); a solver change logged (and its
        kernels warmed up with ``warmup``: loaded from numba's cache, or, not cached and the
        solver has a NumPy implementation, compiled in another process while its frames are
        solved uncompiled, as at start: the parameter service answers at once), reloaded
        landmarks logged."""
        cfg, maps = built
        if "solver" in overrides and overrides["solver"] != self.cfg.solver:
            self.node.get_logger().info(f"solver: {self.cfg.solver} -> {overrides['solver']}")
            self._warm_up(cfg, background=True)
        self._apply_config(cfg, maps)
        if overrides.get("landmarks_file") and maps.landmarks is not None:
            self.node.get_logger().info(
                f"reloaded {len(maps.landmarks[0])} landmarks from {cfg.landmarks_file}"
            )

    # ------------------------------------------------------------------ frames
    def take_frame(self, item: QueuedFrame, camera: Any = None) -> TakenFrame:
        """The worker: one frame through the pipeline (its stamp checked as it arrived),
        counted ``solved`` or ``failed.<reason>``; with ``republish_correspondences`` what the
        front end found in the image, as a ``correspondences_out`` cloud."""
        res = self.pipeline.process(item.msg, item.kind, item.stamp)
        found = [] if res.correspondences is None else [("", res.correspondences, res.stamp_ns)]
        outcome = "solved" if res.failure is None else f"failed.{res.failure}"
        return TakenFrame((outcome,), res.failure, res, found=found)

    def publish_taken(self, item: QueuedFrame, taken: TakenFrame) -> None:
        """The worker, after the frame is counted: publish what the pipeline returned
        (:func:`.outputs.publish_frame` of its :func:`.outputs.camera_outcome`: a failed
        frame, the fused twists it made final and its log line)."""
        tic = time.perf_counter()
        res = taken.result
        failed = 0 if res.solved else self.pipeline.stats.get(f"failed.{res.failure}")
        publish_frame(self.node, camera_outcome(res, failed))
        if res.solved:
            self.pipeline.stats.stage_time("publish", time.perf_counter() - tic)
            self.node.record_timing(item.arrived, res.stamp_ns)

    def idle_twists(self) -> list:
        return self.pipeline.flush_idle()  # (none unconfigured)

    # ------------------------------------------------------------------ diagnostics
    def diagnostics(self) -> tuple[str, StatusParts]:
        """The camera's hardware id and status (:func:`camera_status_parts` of its
        pipeline's counters)."""
        p, cfg = self.pipeline, self.cfg
        stats = p.stats.snapshot()
        gyro = None
        if cfg.imu is not None:
            gyro = GyroState.of(cfg.imu, stats.counts, p.imu, p.gyro_bias_values(),
                                p.gyro_inconsistent)  # fmt: skip
        parts = camera_status_parts(cfg, stats, p.tracking_values(), p.camera_source(),
                                    p.stats.messages_lost, gyro, self._maps().frontend)  # fmt: skip
        return cfg.camera_frame or "camera", parts


def camera_status_parts(
    cfg: LocalizerConfig,
    stats: StatsSnapshot,
    tracking: dict[str, Any],
    camera_source: str,
    messages_lost: int,
    gyro: GyroState | None = None,
    frontend: FrontendHooks | None = None,
) -> StatusParts:
    """The single camera's status as data (:func:`.diagnostics.status` lays it out): its
    frames (:func:`~.frame_queue.frame_accounting` of its counts ``stats.counts``), its one
    section named "" (its counts and ``messages_lost``); ``solver``, ``camera``
    (``camera_source``); after the estimator's path ``frames_compiled`` /
    ``frames_uncompiled`` (frames solved on each path), ``queue_size``, ``time_resets``,
    then ``frames_few_points``, ``frames_single_tag``; the map-fit check of its counts;
    ``inliers_last``, ``inliers_mean``, ``planar``, ``tracking``
    (:meth:`.pipeline.FramePipeline.tracking_values`), ``condition_number_last``; its stage
    times; with an image front end (``frontend``, :attr:`.pipeline.FramePipeline.maps`) its
    values (:func:`.diagnostics.frontend_values`); the ``gyro`` with ``imu.enabled``; its
    counts by reason."""
    c, inliers = stats.counts, stats.inliers
    frames = frame_accounting(c)
    return StatusParts(
        frames=frames,
        cameras=[CameraPart("", frames, {**c, "messages_lost": messages_lost},
                            frontend=frontend is not None)],
        head={"solver": cfg.solver, "camera": camera_source},
        path={"frames_compiled": c.get("frames_compiled", 0),
              "frames_uncompiled": c.get("frames_uncompiled", 0),
              "queue_size": cfg.queue_size, "time_resets": c.get("time_resets", 0)},
        path_after={"frames_few_points": c.get("frames_few_points", 0),
                    "frames_single_tag": c.get("frames_single_tag", 0)},
        map_fit=c,
        tracking={
            "inliers_last": inliers[-1] if inliers else 0,
            "inliers_mean": f"{np.mean(inliers):.1f}" if inliers else "0",
            "planar": str(stats.planar).lower(),
            **tracking,
            "condition_number_last": f"{stats.condition_number:.3g}",
        },
        stage_times=stats.stage_times,
        with_frontend=frontend is not None,
        frontend={} if frontend is None else frontend_values(cfg.frontend_kind, frontend, stats),
        gyro=gyro,
        counts=c,
    )  # fmt: skip


class RSLocalizerNode(NodeCore, Node):
    """The localizer node, for one camera (``rig.cameras`` empty: :class:`CameraMode`) or a
    rig (:class:`~rs_localizer.ros.rig_node.RigMode`): configured (JIT warm-up included),
    subscribed and publishing from construction. ``node_name`` and ``kwargs`` go to
    :class:`rclpy.node.Node`. The managed node is
    :class:`~rs_localizer.ros.lifecycle.RSLocalizerLifecycleNode`.

    Raises:
        RuntimeError: invalid parameters (the message names the parameter).
    """

    _modes = (CameraMode, RigMode)
