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
from .core import ModeBase, NodeCore, QueuedFrame, TakenFrame
from .diagnostics import CameraPart, GyroState, StatusParts, frontend_values
from .frame_queue import frame_accounting
from .outputs import camera_outcome, publish_frame
from .params import PARAMETERS
from .pipeline import FramePipeline, StatsSnapshot, log_warm_up
from .rig_node import RigMode

__all__ = ["PARAMETERS", "CameraMode", "RSLocalizerNode", "camera_status_parts"]


class CameraMode(ModeBase):
    """The single camera's part of :class:`RSLocalizerNode` (``rig.cameras`` empty): the
    camera's topics without prefix, its frames through a
    :class:`~rs_localizer.ros.pipeline.FramePipeline` on the node's worker thread, what the
    pipeline returns published, the camera's diagnostics. The node
    (:class:`~rs_localizer.ros.core.NodeCore`, ``node``) holds the plumbing, the modes' shared
    base (:class:`~rs_localizer.ros.core.ModeBase`) what both modes do alike; this object
    what only the camera's does (the rig's is :class:`~rs_localizer.ros.rig_node.RigMode`).
    Made with the node's state (``_init_state``): the pipeline without configuration, the
    camera's input stage and counts (named ""), the frame queue."""

    def __init__(self, node: NodeCore):
        super().__init__(node)
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

    def _configuration(self) -> tuple[LocalizerConfig, LoadedMaps]:
        return self.changed_configuration({})

    def _warm_kernels(self, built: tuple[LocalizerConfig, LoadedMaps]) -> None:
        """The kernels of the configuration's solver, tracking and gyro, compiled or loaded
        (:func:`.pipeline.log_warm_up`, in the background)."""
        cfg = built[0]
        log_warm_up(cfg.solver, cfg.options, cfg.tracking, self.node.get_logger(),
                    cfg.imu is not None, True)  # fmt: skip

    @property
    def _take_imu(self) -> Callable[[Any], str | None]:
        """The pipeline's gyro (:meth:`.pipeline.FramePipeline.add_imu`)."""
        return self.pipeline.add_imu

    def frame_inputs_destroyed(self) -> None:
        """After the frame inputs' end (the frames still queued dropped): the track is
        dropped too (nothing is left for :meth:`.core.NodeCore._end_video` to publish)."""
        self.pipeline.drop_tracker()  # (a reactivated node starts a new track)

    def _ready_warnings(self) -> list[str]:
        """A global-shutter timing (the twist is then zero)."""
        if self.cfg.camera.line_delay == 0 and self.cfg.camera.readout_time == 0:
            return [
                "rs.line_delay and rs.readout_time are 0: global-shutter "
                "timing, the published twist will be zero"
            ]
        return []

    def _ready_subject(self) -> str:
        cfg, cam = self.cfg, self.cfg.camera
        text = f"solver {cfg.solver}, line delay {cam.line_delay * 1e6:.2f} us/line"
        if cam.readout_time > 0:
            text += f", readout {cam.readout_time * 1e3:.2f} ms"
        return text + f", intrinsics from {'parameters' if cam.fallback else 'camera_info'}"

    # ------------------------------------------------------------------ parameters
    def _maps(self) -> LoadedMaps:
        """The landmarks and the front end loaded for the configuration in use."""
        return self.pipeline.maps

    def _start_with(self, built: tuple[LocalizerConfig, LoadedMaps]) -> None:
        """The pipeline configured (camera models rebuilt: the RS timing may have changed),
        the node's settings (:meth:`~.core.ModeBase._settle`); a reloaded front end, the
        marker detector that runs and a default RS timing with images logged."""
        cfg, maps = built
        old = self.cfg
        old_fe = self._maps().frontend
        self.pipeline.configure(cfg, maps)
        self._settle(cfg, maps.landmarks)
        if old is not None and old_fe is not None and maps.frontend is not old_fe:
            self.node.get_logger().info(
                f"reloaded the {cfg.camera.frontend_kind} front end from {cfg.camera.frontend_map}"
            )
        detector = None if maps.frontend is None else maps.frontend.marker_detector_note()
        if detector is not None and maps.frontend is not old_fe:
            # which marker detector runs (a missing AprilTag library: a warning with the
            # install line)
            line, fallback = detector
            log = self.node.get_logger().warning if fallback else self.node.get_logger().info
            log(f"marker detector: {line}")
        note = default_timing_note(cfg) if maps.frontend is not None else None  # (images)
        if note is not None:
            self.node.warn_once("default_timing", note)

    def changed_configuration(self, overrides: dict) -> tuple[LocalizerConfig, LoadedMaps]:
        """The configuration of the parameters with ``overrides`` and the maps it names
        (a changed ``landmarks_file`` or ``frontend_map`` loaded; ConfigError: not loadable)."""
        cfg = build_config(self.node.param_values(overrides))
        return cfg, load_maps(cfg.camera, owner=self, current=self._maps())

    def _change_to(self, built: tuple[LocalizerConfig, LoadedMaps], overrides: dict) -> None:
        """The pipeline reconfigured (:meth:`_start_with`), reloaded landmarks logged."""
        self._start_with(built)
        cfg, maps = built
        if overrides.get("landmarks_file") and maps.landmarks is not None:
            self.node.get_logger().info(
                f"reloaded {len(maps.landmarks[0])} landmarks from {cfg.camera.landmarks_file}"
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
        return cfg.camera.frame or "camera", parts


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
        frontend={} if frontend is None else frontend_values(cfg.camera.frontend_kind, frontend,
                                                             stats),
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
