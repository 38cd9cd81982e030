"""``rs_localizer_node``: rolling-shutter camera localization from 2D-3D correspondences.

A thin layer over :func:`rs_localizer.estimate_rs_pose` (no solver logic here):
decode the input, pick the camera model, call the estimator, publish, count. Images go through
an image front end (:mod:`rs_localizer.frontends`: ArUco markers or natural features against a
map) first, then down the same path as a correspondence cloud.

Threads: the subscription callbacks (executor thread) only put frames into a bounded queue
(``queue_size``; when it is full the oldest waiting frame is dropped and counted as skipped,
so the newest frames are solved); one worker thread takes them out, solves and publishes. So
``frames_received = frames_solved + frames_failed + frames_skipped (+ frames_pending)``, and the
executor stays free for camera_info, parameters and diagnostics however slow a frame is.

Subscriptions (best effort, history 100 clouds / 10 images / 5 camera_info; overridable with
``qos_overrides.<topic>.subscription.*``):
    correspondences  sensor_msgs/PointCloud2  u, v [px, distorted], x, y, z [m, map frame]
                                              (+ id uint32, + score float32)
    keypoints        sensor_msgs/PointCloud2  u, v, id; 3D points from ``landmarks_file``
    camera_info      sensor_msgs/CameraInfo
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

import bisect
import math
import os
import sys
import threading
import time
from collections import Counter, deque

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, TwistStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, PointCloud2

from ..camera import READOUT_DIRECTIONS, CameraModel
from ..estimation import EstimateOptions, MotionPrior, estimate_rs_pose
from ..estimation.fusion import FusionOptions
from ..estimation.tracker import RSTracker, TrackerOptions
from ..frames import OPTICAL_TO_BODY_QUATERNION, Extrinsic, camera_to_base
from ..frontends import FRONTENDS
from ..frontends.shared import SHARED_MAPS
from ..maps import check_regular_file
from ..solvers.registry import SOLVER_NAMES as SOLVERS
from ..solvers.registry import sample_size, solver_info
from . import conversions as cv
from .pointcloud import CloudError, correspondence_cloud, read_correspondences, read_keypoints
from .visualization import NodeVisualization

__all__ = ["PARAMETERS", "RSLocalizerNode", "main"]

_D = ParameterDescriptor
_F = FloatingPointRange
_I = IntegerRange

#: name -> (default, description, range or None, read_only). Mirrors config/rs_localizer.yaml.
PARAMETERS = {
    "solver": (
        "r6p_1lin",
        f"minimal solver: one of {', '.join(SOLVERS)} (p3p = global shutter)",
        None,
        False,
    ),
    "ransac.threshold_px": (
        2.0,
        "RANSAC inlier threshold on the reprojection error (px)",
        _F(from_value=0.05, to_value=100.0, step=0.0),
        False,
    ),
    "ransac.max_iterations": (
        1000,
        "RANSAC iteration cap",
        _I(from_value=1, to_value=1_000_000, step=1),
        False,
    ),
    "ransac.confidence": (
        0.9999,
        "RANSAC adaptive-termination confidence",
        _F(from_value=0.5, to_value=0.999999999, step=0.0),
        False,
    ),
    "ransac.min_inliers": (
        12,
        "fewest inliers for a pose",
        _I(from_value=3, to_value=100_000, step=1),
        False,
    ),
    "ransac.seed": (
        0,
        "RANSAC random seed (deterministic)",
        _I(from_value=0, to_value=2_147_483_647, step=1),
        False,
    ),
    "refine": (True, "nonlinear refinement on the exact constant-velocity model", None, False),
    "motion_prior.angular_velocity_sigma": (
        3.0,
        "motion prior: sigma of each angular velocity component (rad/s, camera frame); "
        "0 = no prior on it",
        _F(from_value=0.0, to_value=1e4, step=0.0),
        False,
    ),
    "motion_prior.linear_velocity_sigma": (
        1.5,
        "motion prior: sigma of each linear velocity component (m/s, camera frame); "
        "0 = no prior on it (both 0: maximum likelihood, near-degenerate on planar scenes)",
        _F(from_value=0.0, to_value=1e4, step=0.0),
        False,
    ),
    "correlated_noise.sigma_px": (
        0.0,
        "std (px per axis) of a spatially correlated image error (lens-model residue, "
        "corner bias) in the covariance; 0 = white noise only. Fit it on still calibration "
        "views (estimation.noise_model.fit_correlated_noise)",
        _F(from_value=0.0, to_value=100.0, step=0.0),
        False,
    ),
    "correlated_noise.length_px": (
        100.0,
        "correlation length (px) of that error",
        _F(from_value=0.1, to_value=1e5, step=0.0),
        False,
    ),
    "rs.line_delay": (
        3.0e-5,
        "time between consecutive image lines (s/line); 0 = global shutter",
        _F(from_value=0.0, to_value=0.01, step=0.0),
        False,
    ),
    "rs.readout_time": (
        0.0,
        "time to read the whole frame (s); if > 0 it wins over "
        "rs.line_delay (line_delay = readout_time / lines)",
        _F(from_value=0.0, to_value=1.0, step=0.0),
        False,
    ),
    "rs.direction": (
        "top_to_bottom",
        "readout direction: " + ", ".join(READOUT_DIRECTIONS),
        None,
        False,
    ),
    "rs.reference_row": (
        -1.0,
        "line (px) at which the pose is estimated; -1 = image centre",
        _F(from_value=-1.0, to_value=100_000.0, step=0.0),
        False,
    ),
    "rs.stamp_row": (
        0.0,
        "line (px) whose capture time is the input header.stamp",
        _F(from_value=0.0, to_value=100_000.0, step=0.0),
        False,
    ),
    "map_frame": ("map", "frame of the published pose", None, True),
    "camera_frame": (
        "",
        "camera optical frame of the outputs; empty = input header.frame_id",
        None,
        False,
    ),
    "publish_tf": (
        True,
        "publish map -> camera (or base_frame) on /tf (needs tf2_msgs)",
        None,
        True,
    ),
    "base_frame": (
        "",
        "robot body frame (REP 103, e.g. base_link); set: pose, "
        "pose_with_covariance, odom, twist and /tf describe it instead of the camera "
        "(camera_to_base.* is the mounting); empty = the camera optical frame",
        None,
        False,
    ),
    "camera_to_base.translation": (
        [0.0, 0.0, 0.0],
        "camera optical frame origin in base_frame (m, x y z): the base_frame -> camera transform",
        None,
        False,
    ),
    "camera_to_base.rotation": (
        list(OPTICAL_TO_BODY_QUATERNION),
        "rotation camera optical "
        "frame -> base_frame, quaternion x y z w (default: a camera "
        "looking along the base's x axis)",
        None,
        False,
    ),
    "landmarks_file": (
        "",
        "CSV id,x,y,z for the keypoints topic (reloaded on change)",
        None,
        False,
    ),
    "max_points": (
        5000,
        "clouds with more points are capped (highest scores, else evenly spaced), with a warning",
        _I(from_value=10, to_value=10_000_000, step=1),
        False,
    ),
    "time_reset_threshold": (
        1.0,
        "a frame stamped later than the previous one by more than "
        "this (s) resets the time-dependent state (a gap); any step back "
        "does too. Frames are never dropped for their stamp",
        _F(from_value=0.0, to_value=1e6, step=0.0),
        False,
    ),
    "queue_size": (
        5,
        "frames waiting to be solved; when full, the oldest waiting frame is "
        "dropped (counted in frames_skipped) so that the newest are solved",
        _I(from_value=1, to_value=10_000, step=1),
        False,
    ),
    "camera_info_wait": (
        0.05,
        "s a frame may wait for its camera_info: when none has arrived "
        "yet, or when camera_info comes with every frame (same stamps) and "
        "the frame's own has not arrived yet",
        _F(from_value=0.0, to_value=5.0, step=0.0),
        False,
    ),
    "max_angular_velocity": (
        20.0,
        "rad/s; a model turning faster is implausible (never published: implausible_motion)",
        _F(from_value=0.01, to_value=1e6, step=0.0),
        False,
    ),
    "max_linear_velocity": (
        50.0,
        "m/s; a model moving faster is implausible",
        _F(from_value=0.01, to_value=1e9, step=0.0),
        False,
    ),
    "tracking.enabled": (
        True,
        "track the camera through the video: predicted RANSAC, "
        "relocalization, and twist / odom carry the fused twist; "
        "false: every frame alone",
        None,
        False,
    ),
    "tracking.lag": (
        1,
        "frames of smoothing delay of the fused twist: twist / odom of a frame "
        "are published when this many later frames have been fused (0: at once, "
        "causal filter)",
        _I(from_value=0, to_value=10, step=1),
        False,
    ),
    "tracking.max_gap": (
        0.5,
        "s; a longer gap between frames (or a stamp going back) resets "
        "the track; after this long without frames the pending twists are "
        "published",
        _F(from_value=0.01, to_value=60.0, step=0.0),
        False,
    ),
    "tracking.gate_px": (
        20.0,
        "a point is explained by the prediction within this distance "
        "(px); too few explained points: relocalize",
        _F(from_value=0.5, to_value=1000.0, step=0.0),
        False,
    ),
    "tracking.angular_noise": (
        30.0,
        "filter process noise: angular jerk density (rad/s^3/sqrt(Hz))",
        _F(from_value=1e-3, to_value=1e6, step=0.0),
        False,
    ),
    "tracking.linear_noise": (
        5.0,
        "filter process noise: linear jerk density (m/s^3/sqrt(Hz))",
        _F(from_value=1e-3, to_value=1e6, step=0.0),
        False,
    ),
    "tracking.prior_from_prediction": (
        "planar",
        "the estimator's motion prior is the predicted "
        "twist: planar (when the last frame was planar), always "
        "or never",
        None,
        False,
    ),
    "diagnostics_period": (
        1.0,
        "period of /diagnostics (s)",
        _F(from_value=0.05, to_value=60.0, step=0.0),
        True,
    ),
    "warmup": (True, "solve a synthetic problem at start (JIT compilation)", None, True),
    "camera.fx": (
        0.0,
        "fallback intrinsics until camera_info arrives; fx <= 0 = wait for camera_info",
        _F(from_value=0.0, to_value=1e6, step=0.0),
        False,
    ),
    "camera.fy": (0.0, "fallback fy (px)", _F(from_value=0.0, to_value=1e6, step=0.0), False),
    "camera.cx": (0.0, "fallback cx (px)", _F(from_value=-1e6, to_value=1e6, step=0.0), False),
    "camera.cy": (0.0, "fallback cy (px)", _F(from_value=-1e6, to_value=1e6, step=0.0), False),
    "camera.width": (
        0,
        "fallback image width (px)",
        _I(from_value=0, to_value=100_000, step=1),
        False,
    ),
    "camera.height": (
        0,
        "fallback image height (px)",
        _I(from_value=0, to_value=100_000, step=1),
        False,
    ),
    "camera.distortion_model": (
        "plumb_bob",
        "fallback distortion model: plumb_bob, rational_polynomial, equidistant or none",
        None,
        False,
    ),
    "camera.d": (
        [0.0, 0.0, 0.0, 0.0, 0.0],
        "fallback distortion coefficients (OpenCV order)",
        None,
        False,
    ),
    "frontend": (
        "none",
        "image front end: none (no image subscription), aruco, features or board "
        "(checkerboard, ChArUco or AprilTag/ArUco tag board from a board YAML)",
        None,
        True,
    ),
    "frontend_map": (
        "",
        "map of the front end: aruco: marker map YAML, scene YAML or a "
        "built-in scene name (aruco_room); features: feature map .npz; board: "
        "board YAML (reloaded on change)",
        None,
        False,
    ),
    "image_transport": (
        "raw",
        "image input with a front end: raw (sensor_msgs/Image on image) "
        "or compressed (sensor_msgs/CompressedImage, JPEG or PNG, on "
        "image/compressed, decoded with OpenCV)",
        None,
        True,
    ),
    "republish_correspondences": (
        False,
        "publish the front end's correspondences on "
        "correspondences_out (PointCloud2) for inspection",
        None,
        False,
    ),
}

#: values of the ``frontend`` parameter
FRONTEND_KINDS = ("none",) + FRONTENDS
#: values of the ``image_transport`` parameter
IMAGE_TRANSPORTS = ("raw", "compressed")

_LOG_PERIOD = 2.0  # s, per failure reason
# Frame subscriptions: sensor-data QoS (best effort) with a deeper history than its 5, so that
# frames arriving while the worker holds the GIL wait in the middleware until the callbacks
# move them to the node's queue, where a drop is counted (frames_skipped), instead of being
# overwritten unseen (images: 10, they are big)
_CLOUD_QOS = QoSProfile(
    depth=100,
    reliability=qos_profile_sensor_data.reliability,
    durability=qos_profile_sensor_data.durability,
    history=qos_profile_sensor_data.history,
)
_IMAGE_QOS = QoSProfile(
    depth=10,
    reliability=qos_profile_sensor_data.reliability,
    durability=qos_profile_sensor_data.durability,
    history=qos_profile_sensor_data.history,
)
_CAMERA_HISTORY = 32  # camera_info entries kept (distinct calibrations, by stamp)


class _Fused:
    """A frame's published pose (from its estimate) with its fused twist (a
    :class:`~rs_localizer.estimation.fusion.FusedState`): what twist / odom carry."""

    def __init__(self, est, fused):
        self.orientation, self.position = est.orientation, est.position
        self.pose_covariance = est.pose_covariance
        self.angular_velocity, self.linear_velocity = (
            fused.angular_velocity,
            fused.linear_velocity,
        )
        self.twist_covariance = fused.twist_covariance


class _Drop(ValueError):
    """A frame dropped by an input stage: ``reason`` is counted as ``failed.<reason>``."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


class LocalizerCore:
    """Everything of the localizer node but the order of its construction, shared by
    :class:`RSLocalizerNode` (all at once) and the managed
    :class:`~rs_localizer.ros.lifecycle.RSLocalizerLifecycleNode` (by lifecycle transition).
    Mixed into an rclpy ``Node``; the phases: :meth:`_declare_parameters`, :meth:`_init_state`,
    :meth:`_configure` (parameters -> configuration, maps, JIT warm-up), :meth:`_create_outputs`,
    :meth:`_create_camera_info_input`, :meth:`_create_frame_inputs`, :meth:`_log_ready`."""

    cfg = None  # the configuration built from the parameters (None: not configured)

    def _make_publisher(self, msg_type, topic, qos):
        """Publishers of the outputs (the managed node makes lifecycle publishers)."""
        return self.create_publisher(msg_type, topic, qos)

    def _declare_parameters(self):
        for name, (default, desc, rng, ro) in PARAMETERS.items():
            d = _D(description=desc, read_only=ro)
            if isinstance(rng, FloatingPointRange):
                d.floating_point_range = [rng]
            elif isinstance(rng, IntegerRange):
                d.integer_range = [rng]
            try:
                self.declare_parameter(name, default, d)
            except InvalidParameterValueException as e:
                raise RuntimeError(f"parameter {name!r}: {e} ({desc})") from None
            except InvalidParameterTypeException as e:
                kind = type(default).__name__
                raise RuntimeError(
                    f"parameter {name!r} must be of type {kind}"
                    + (" (write e.g. 0.0, not 0, in YAML)" if kind == "float" else "")
                    + f": {e}"
                ) from None

    def _init_state(self):
        self.counts = Counter()  # frames received / solved / failed.<reason> / ...
        self.latencies = deque(maxlen=1000)  # s, arrival (subscription callback) -> published
        self.stamp_ages = deque(maxlen=1000)  # s, input header.stamp -> published (ROS clock)
        self.stage_times = {
            k: deque(maxlen=1000) for k in ("decode", "frontend", "estimate", "publish")
        }
        self.inliers = deque(maxlen=1000)
        self._planar_last = (False, float("nan"))  # (planar, condition number) of the last pose
        self.messages_lost = 0  # QoS message_lost events over the frame subscriptions
        self._lost = {}
        self._last_log = {}
        self._last_stamp = None  # stamp of the last frame the worker took (time resets)
        # the queue between the subscription callbacks and the worker, the camera_info history
        # and the counters they share are guarded by this condition
        self._lock = threading.Condition()
        self._queue = deque()  # (msg, extract, arrival perf_counter)
        self._busy = False  # the worker is on a frame
        self._stop = False
        self._cam_hist = []  # [stamp_ns, key, msg, CameraModel, seq], sorted by stamp
        self._cam_seq = 0  # arrival counter of camera_info entries
        self._info_stamps = deque(maxlen=64)  # stamps of the last camera_infos received
        self._frame_stamps = deque(maxlen=64)  # stamps of the last frames taken by the worker
        self._camera = None  # CameraModel of the newest camera_info (with RS timing)
        self._landmarks = None  # (sorted ids, points)
        self._frontend = None  # image front end (frontend != none)
        self._frontend_key = None  # (kind, map path) it was built from
        self._frontend_last = 0  # correspondences the front end made of the last image
        self._t_frontend = 0.0  # s in the front end for the current frame
        self._tf_pub = None
        self.pub_corr_out = None  # correspondences_out, created when first needed
        self.sub_info = self.sub_corr = self.sub_kp = self.sub_image = None
        self._diag_timer = None
        # video tracking: the tracker, what it was made for, the per-frame outputs
        # waiting for their fused twist (out stamp -> (pose source, frame id)), the worker's
        # and the idle-flush timer's lock around them, and counters over trackers
        self._tracker = None
        self._tracker_key = None
        self._pending_out = {}
        self._track_lock = threading.RLock()
        self._last_frame_wall = None
        self._track_counts = Counter()
        self._flush_timer = None

    def _configure(self):
        """Parameters -> configuration (camera model, landmarks, front end and its map), then
        the JIT warm-up. Raises RuntimeError for invalid parameters."""
        cfg = self._build_config({})
        if isinstance(cfg, str):
            raise RuntimeError(f"invalid parameters: {cfg}")
        self._apply_config(cfg)
        if self.get_parameter("warmup").value:
            self._warmup(self.cfg["solver"])

    def _create_outputs(self):
        rel = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.pub_pose = self._make_publisher(PoseStamped, "pose", rel)
        self.pub_twist = self._make_publisher(TwistStamped, "twist", rel)
        self.pub_pwc = self._make_publisher(PoseWithCovarianceStamped, "pose_with_covariance", rel)
        self.pub_odom = self._make_publisher(Odometry, "odom", rel)
        self.pub_twist_single = self._make_publisher(TwistStamped, "twist_single_frame", rel)
        self.pub_diag = self._make_publisher(DiagnosticArray, "/diagnostics", rel)
        if getattr(self, "viz", None) is None:  # (declares the viz.* parameters: once)
            self.viz = NodeVisualization(self)  # debug_image, markers, path (viz.* parameters)
        if self.get_parameter("publish_tf").value:
            if cv.have_tf2_msgs():
                from tf2_msgs.msg import TFMessage

                self._tf_pub = self._make_publisher(TFMessage, "/tf", rel)
            else:
                self.get_logger().warning(
                    "publish_tf is true but tf2_msgs is not importable (not in the PyPI "
                    "wheels): not publishing /tf"
                )
        if self.cfg["republish"] and self._frontend is not None:
            self._corr_out_publisher()

    def _create_camera_info_input(self):
        # (created before the frame inputs: a camera_info ready together with a frame is
        # taken first)
        self.sub_info = self.create_subscription(
            CameraInfo,
            "camera_info",
            self._on_camera_info,
            qos_profile_sensor_data,
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
        )

    def _create_frame_inputs(self):
        """The frame subscriptions, the diagnostics timer and the worker thread."""
        self.sub_corr = self.create_subscription(
            PointCloud2,
            "correspondences",
            self._on_correspondences,
            _CLOUD_QOS,
            event_callbacks=self._lost_events("correspondences"),
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
        )
        self.sub_kp = self.create_subscription(
            PointCloud2,
            "keypoints",
            self._on_keypoints,
            _CLOUD_QOS,
            event_callbacks=self._lost_events("keypoints"),
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
        )
        self.sub_image = None
        if self._frontend is not None:
            if self.cfg["image_transport"] == "compressed":  # image_transport's topic name
                self.sub_image = self.create_subscription(
                    CompressedImage,
                    self.resolve_topic_name("image") + "/compressed",
                    self._on_image,
                    _IMAGE_QOS,
                    event_callbacks=self._lost_events("image"),
                    qos_overriding_options=QoSOverridingOptions.with_default_policies(),
                )
            else:
                self.sub_image = self.create_subscription(
                    Image,
                    "image",
                    self._on_image,
                    _IMAGE_QOS,
                    event_callbacks=self._lost_events("image"),
                    qos_overriding_options=QoSOverridingOptions.with_default_policies(),
                )
        self._diag_timer = self.create_timer(
            float(self.get_parameter("diagnostics_period").value), self.publish_diagnostics
        )
        self._flush_timer = self.create_timer(0.05, self._flush_idle_track)
        self._start_worker()

    def _start_worker(self):
        with self._lock:
            self._stop = False
        # the worker holds the GIL while it solves; hand it to the subscription callbacks
        # often, so that frames leave the middleware's queue quickly (0.5 ms, CPython: 5 ms)
        sys.setswitchinterval(min(sys.getswitchinterval(), 5e-4))
        self._worker = threading.Thread(target=self._work, name="rs_localizer_worker", daemon=True)
        self._worker.start()

    def _stop_worker(self, drop_queued: bool = False):
        """Stop the worker thread (the frame it is on is finished); ``drop_queued``: forget
        the frames still waiting (counted as skipped)."""
        with self._lock:
            self._stop = True
            if drop_queued:
                self.counts["skipped"] += len(self._queue)
                self._queue.clear()
            self._lock.notify_all()
        worker = getattr(self, "_worker", None)
        if worker is not None and worker.is_alive() and threading.current_thread() is not worker:
            worker.join(timeout=10.0)
        self._worker = None

    def _destroy_frame_inputs(self):
        """Undo :meth:`_create_frame_inputs`; frames still queued are dropped."""
        for sub in (self.sub_corr, self.sub_kp, self.sub_image):
            if sub is not None:
                self.destroy_subscription(sub)
        self.sub_corr = self.sub_kp = self.sub_image = None
        if self._diag_timer is not None:
            self.destroy_timer(self._diag_timer)
            self._diag_timer = None
        if self._flush_timer is not None:
            self.destroy_timer(self._flush_timer)
            self._flush_timer = None
        self._stop_worker(drop_queued=True)
        with self._track_lock:  # (a reactivated node starts a new track)
            self._drop_tracker()

    def _log_ready(self):
        if self.cfg["line_delay"] == 0 and self.cfg["readout_time"] == 0:
            self.get_logger().warning(
                "rs.line_delay and rs.readout_time are 0: global-shutter "
                "timing, the published twist will be zero"
            )
        self.get_logger().info(
            f"ready: solver {self.cfg['solver']}, line delay "
            f"{self.cfg['line_delay'] * 1e6:.2f} us/line"
            + (
                f", readout {self.cfg['readout_time'] * 1e3:.2f} ms"
                if self.cfg["readout_time"] > 0
                else ""
            )
            + f", intrinsics from {'parameters' if self.cfg['fallback'] else 'camera_info'}"
            + (
                f", {len(self._landmarks[0])} landmarks from {self.cfg['landmarks_file']}"
                if self._landmarks
                else ""
            )
            + (
                f", {self.cfg['frontend']} front end on {self.sub_image.topic_name} (map "
                f"{self.cfg['frontend_map']})"
                if self.sub_image is not None
                else ""
            )
        )

    # ------------------------------------------------------------------ parameters
    def _param_values(self, overrides: dict) -> dict:
        vals = {}
        for name in PARAMETERS:
            if name in overrides:
                vals[name] = overrides[name]
            else:
                vals[name] = self.get_parameter(name).value
        return vals

    def _build_config(self, overrides: dict):
        """Everything derived from the parameters, or an error string."""
        p = self._param_values(overrides)
        if p["solver"] not in SOLVERS:
            return f"unknown solver {p['solver']!r}; expected one of {list(SOLVERS)}"
        if p["rs.direction"] not in READOUT_DIRECTIONS:
            return (
                f"unknown rs.direction {p['rs.direction']!r}; expected one of "
                f"{list(READOUT_DIRECTIONS)}"
            )
        try:
            opts = EstimateOptions(
                threshold_px=float(p["ransac.threshold_px"]),
                max_iterations=int(p["ransac.max_iterations"]),
                confidence=float(p["ransac.confidence"]),
                min_inliers=int(p["ransac.min_inliers"]),
                seed=int(p["ransac.seed"]),
                refine=bool(p["refine"]),
                motion_prior=MotionPrior(
                    float(p["motion_prior.angular_velocity_sigma"]),
                    float(p["motion_prior.linear_velocity_sigma"]),
                ),
                max_angular_velocity=float(p["max_angular_velocity"]),
                max_linear_velocity=float(p["max_linear_velocity"]),
                correlated_noise_px=float(p["correlated_noise.sigma_px"]),
                correlated_noise_length_px=float(p["correlated_noise.length_px"]),
            )
        except (TypeError, ValueError) as e:
            return f"invalid RANSAC options: {e}"
        need = max(opts.min_inliers, sample_size(p["solver"]) + 1)
        if int(p["max_points"]) < need:
            return (
                f"max_points {p['max_points']} is below the {need} points a pose needs "
                f"(ransac.min_inliers {opts.min_inliers}, solver {p['solver']}): every "
                "frame would fail"
            )
        ref = float(p["rs.reference_row"])
        tracking = None
        if bool(p["tracking.enabled"]):
            try:
                tracking = TrackerOptions(
                    gate_px=float(p["tracking.gate_px"]),
                    max_gap=float(p["tracking.max_gap"]),
                    prior_from_prediction=str(p["tracking.prior_from_prediction"]),
                    fusion=FusionOptions(
                        lag=int(p["tracking.lag"]),
                        angular_noise=float(p["tracking.angular_noise"]),
                        linear_noise=float(p["tracking.linear_noise"]),
                    ),
                )
            except (TypeError, ValueError) as e:
                return f"invalid tracking parameters: {e}"
        cfg = {
            "solver": p["solver"],
            "options": opts,
            "line_delay": float(p["rs.line_delay"]),
            "tracking": tracking,
            "readout_time": float(p["rs.readout_time"]),
            "direction": p["rs.direction"],
            "reference_row": None if ref < 0 else ref,
            "stamp_row": float(p["rs.stamp_row"]),
            "map_frame": p["map_frame"],
            "camera_frame": p["camera_frame"],
            "max_points": int(p["max_points"]),
            "time_reset_ns": int(float(p["time_reset_threshold"]) * 1e9),
            "queue_size": int(p["queue_size"]),
            "camera_info_wait": float(p["camera_info_wait"]),
            "landmarks_file": p["landmarks_file"],
            "fallback": None,
        }
        if not all(
            math.isfinite(float(p[k])) for k in ("camera.fx", "camera.fy", "camera.cx", "camera.cy")
        ):
            return "invalid fallback camera parameters: camera.fx/fy/cx/cy must be finite"
        d = p["camera.d"] if p["camera.d"] is not None else []
        if not all(math.isfinite(float(x)) for x in d):
            return f"invalid fallback camera parameters: camera.d must be finite, got {list(d)}"
        if float(p["camera.fx"]) > 0:
            K = np.array(
                [
                    [p["camera.fx"], 0.0, p["camera.cx"]],
                    [0.0, p["camera.fy"] or p["camera.fx"], p["camera.cy"]],
                    [0.0, 0.0, 1.0],
                ],
                dtype=float,
            )
            try:
                cfg["fallback"] = cv.camera_model(
                    K,
                    list(d),
                    p["camera.width"],
                    p["camera.height"],
                    p["camera.distortion_model"],
                    cfg["line_delay"],
                    cfg["readout_time"],
                    cfg["direction"],
                    cfg["reference_row"],
                )
            except ValueError as e:
                return f"invalid fallback camera parameters: {e}"
        try:
            self._with_timing(CameraModel(K=np.eye(3), width=10, height=10), cfg)
        except ValueError as e:
            return f"invalid rolling-shutter parameters: {e}"
        cfg["base_frame"], cfg["extrinsic"] = str(p["base_frame"]).strip(), None
        if cfg["base_frame"]:
            try:
                cfg["extrinsic"] = Extrinsic.from_translation_quaternion(
                    p["camera_to_base.translation"], p["camera_to_base.rotation"]
                )
            except ValueError as e:
                return f"invalid camera_to_base: {e}"
        path = p["landmarks_file"]
        cfg["landmarks"] = None
        if path:
            try:  # (loaded once per process: cameras naming the same file share it)
                cfg["landmarks"] = SHARED_MAPS.landmarks(path, owner=self)
            except (OSError, ValueError) as e:
                return f"cannot load landmarks_file {path!r}: {e}"
        kind, fmap = str(p["frontend"]).strip().lower(), str(p["frontend_map"])
        if kind not in FRONTEND_KINDS:
            return f"unknown frontend {p['frontend']!r}; expected one of {list(FRONTEND_KINDS)}"
        transport = str(p["image_transport"]).strip().lower()
        if transport not in IMAGE_TRANSPORTS:
            return (
                f"unknown image_transport {p['image_transport']!r}; expected one of "
                f"{list(IMAGE_TRANSPORTS)}"
            )
        cfg.update(
            frontend=kind,
            frontend_map=fmap,
            republish=bool(p["republish_correspondences"]),
            frontend_obj=None,
            image_transport=transport,
        )
        if kind != "none":
            if not fmap:
                return f"frontend {kind} needs frontend_map (" + (
                    "marker map YAML, scene YAML or aruco_room)"
                    if kind == "aruco"
                    else "board YAML)"
                    if kind == "board"
                    else "feature map .npz)"
                )
            if (kind, fmap) == self._frontend_key:
                cfg["frontend_obj"] = self._frontend
            else:
                try:
                    if os.path.lexists(os.path.expanduser(fmap)):  # (not a built-in name)
                        check_regular_file(os.path.expanduser(fmap))  # a FIFO would block
                    # (the map is loaded once per process and shared by cameras naming it)
                    cfg["frontend_obj"] = SHARED_MAPS.frontend(
                        kind, os.path.expanduser(fmap), owner=self
                    )
                except Exception as e:
                    return f"cannot load frontend_map {fmap!r} ({kind}): {type(e).__name__}: {e}"
        return cfg

    @staticmethod
    def _with_timing(camera: CameraModel, cfg) -> CameraModel:
        return cv.camera_model(
            camera.K,
            camera.D,
            camera.width,
            camera.height,
            camera.distortion_model,
            cfg["line_delay"],
            cfg["readout_time"],
            cfg["direction"],
            cfg["reference_row"],
        )

    def _apply_config(self, cfg):
        self.cfg = cfg
        self._landmarks = cfg["landmarks"]
        if cfg["frontend_obj"] is not self._frontend:
            if self._frontend is not None:
                self.get_logger().info(
                    f"reloaded the {cfg['frontend']} front end from {cfg['frontend_map']}"
                )
            self._frontend = cfg["frontend_obj"]
            self._frontend_key = (cfg["frontend"], cfg["frontend_map"])
        if (
            cfg["republish"]
            and self._frontend is not None
            and getattr(self, "pub_pose", None) is not None
        ):
            self._corr_out_publisher()
        with self._lock:  # the RS timing may have changed: rebuild the camera models
            hist = []
            for entry in self._cam_hist:
                try:
                    hist.append([*entry[:3], self._camera_from_info(entry[2]), entry[4]])
                except ValueError as e:
                    self.get_logger().error(f"camera_info unusable with the new parameters: {e}")
            self._cam_hist = hist
            self._camera = max(hist, key=lambda e: e[4])[3] if hist else None

    def _on_set_parameters(self, params) -> SetParametersResult:
        overrides = {p.name: p.value for p in params if p.name in PARAMETERS}
        if not overrides or self.cfg is None:  # (not configured yet: checked at configure)
            return SetParametersResult(successful=True)
        cfg = self._build_config(overrides)
        if isinstance(cfg, str):
            self.get_logger().warning(f"rejected parameter change: {cfg}")
            return SetParametersResult(successful=False, reason=cfg)
        if "solver" in overrides and overrides["solver"] != self.cfg["solver"]:
            self.get_logger().info(f"solver: {self.cfg['solver']} -> {overrides['solver']}")
            if self.get_parameter("warmup").value:
                self._warmup(overrides["solver"], cfg)
        self._apply_config(cfg)
        if overrides.get("landmarks_file") and cfg["landmarks"] is not None:
            self.get_logger().info(
                f"reloaded {len(cfg['landmarks'][0])} landmarks from {cfg['landmarks_file']}"
            )
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ warm-up
    def _warmup(self, solver, cfg=None):
        """Run the estimator on a small synthetic RS problem so that the numba JIT compiles
        (or loads from its cache) before the first real frame, logging each kernel compiled."""
        from ..estimation.warmup import warm_up
        from ..jit_cache import cache_state, compile_progress

        cfg = cfg or self.cfg
        log = self.get_logger()
        st = cache_state()
        log.info(
            f"warm-up ({solver}): numba cache {st['dir']} ({st['mode']}"
            + (f", {st['seeded']} files copied from the package" if st["seeded"] else "")
            + ")"
        )
        try:
            with compile_progress(log.info) as prog:
                dt, est = warm_up(solver, cfg["options"])
            log.info(
                f"warm-up ({solver}): {dt:.2f} s, {'ok' if est.success else est.failure}"
                + (
                    f", compiled {len(prog.kernels)} kernels (`rs-localizer compile` after "
                    "installing avoids this)"
                    if prog.kernels
                    else ", kernels from the cache"
                )
            )
        except Exception as e:
            log.warning(f"warm-up ({solver}) failed: {type(e).__name__}: {e}")

    # ------------------------------------------------------------------ callbacks
    def _lost_events(self, topic):
        def on_lost(status):
            self._lost[topic] = int(status.total_count)
            self.messages_lost = sum(self._lost.values())

        return SubscriptionEventCallbacks(message_lost=on_lost)

    def _camera_from_info(self, msg) -> CameraModel:
        cam = cv.camera_model_from_camera_info(
            msg,
            self.cfg["line_delay"],
            self.cfg["readout_time"],
            self.cfg["direction"],
            self.cfg["reference_row"],
        )
        return cam

    def _on_camera_info(self, msg: CameraInfo):
        """Validate a camera_info and add it to the history the frames pick from by stamp (a
        rejected one is counted and logged, and the previous cameras stay)."""
        try:
            stamp = cv.checked_stamp_ns(msg.header.stamp)
        except cv.StampError as e:
            return self._reject_camera_info("bad_stamp", str(e))
        key = (
            tuple(msg.k),
            tuple(msg.d),
            msg.distortion_model,
            msg.width,
            msg.height,
            msg.binning_x,
            msg.binning_y,
            msg.roi.x_offset,
            msg.roi.y_offset,
            msg.roi.width,
            msg.roi.height,
        )
        with self._lock:
            cam = next((e[3] for e in self._cam_hist if e[1] == key), None)
        if cam is None:
            try:
                cam = self._camera_from_info(msg)
            except cv.CameraInfoError as e:
                return self._reject_camera_info(e.reason, str(e))
            except ValueError as e:  # (RS timing of the parameters: cannot happen, see cfg)
                return self._reject_camera_info("bad_intrinsics", str(e))
        first = False
        with self._lock:
            first = not self._cam_hist
            hist = self._cam_hist
            i = bisect.bisect_right([e[0] for e in hist], stamp)
            self._cam_seq += 1
            if i > 0 and hist[i - 1][1] == key:
                hist[i - 1][4] = self._cam_seq  # the entry before already covers this stamp
            else:
                hist.insert(i, [stamp, key, msg, cam, self._cam_seq])
                if i + 1 < len(hist) and hist[i + 1][1] == key:
                    del hist[i + 1]  # now covered from an earlier stamp
                if len(hist) > _CAMERA_HISTORY:
                    del hist[0]
            self._camera = cam
            self._info_stamps.append(stamp)
            self._lock.notify_all()
        if first:
            self.get_logger().info(
                f"camera_info: {cam.width}x{cam.height}, fx {cam.K[0, 0]:.1f}, "
                f"{cam.distortion_model if cam.has_distortion else 'no distortion'}"
            )

    def _reject_camera_info(self, reason, detail):
        with self._lock:
            self.counts["camera_info_rejected"] += 1
            self.counts[f"camera_info_rejected.{reason}"] += 1
        self._log_throttled(
            f"camera_info.{reason}",
            f"camera_info rejected ({reason}), the previous camera stays: {detail}",
        )

    def _camera_for(self, stamp: int):
        """The camera model of a frame stamped ``stamp`` (ns): from the newest camera_info
        stamped at or before it (the oldest one if the frame is older than all), else the
        fallback intrinsics, else ``None``. Waits up to ``camera_info_wait`` when no
        camera_info has arrived yet (and there is no fallback), or when camera_info comes
        with every frame and this frame's has not arrived yet."""
        cfg = self.cfg
        deadline = time.monotonic() + cfg["camera_info_wait"]
        with self._lock:
            # camera_info comes with every frame when the last two frames each got one with
            # their stamp (before or after them)
            infos = set(self._info_stamps)
            synced = len(self._frame_stamps) >= 2 and all(
                self._frame_stamps[-k] in infos for k in (1, 2)
            )
            self._frame_stamps.append(stamp)
            while not self._stop:
                if self._cam_hist:
                    if not synced or stamp in self._info_stamps or self._cam_hist[-1][0] >= stamp:
                        break
                elif cfg["fallback"] is not None:
                    return cfg["fallback"]
                if time.monotonic() >= deadline:
                    break
                self._lock.wait(deadline - time.monotonic())
            hist = self._cam_hist
            if not hist:
                return cfg["fallback"]
            i = bisect.bisect_right([e[0] for e in hist], stamp)
            return hist[max(i - 1, 0)][3]

    def _on_correspondences(self, msg: PointCloud2):
        self._enqueue(msg, self._from_correspondences)

    def _on_keypoints(self, msg: PointCloud2):
        self._enqueue(msg, self._from_keypoints)

    def _on_image(self, msg):  # sensor_msgs/Image or CompressedImage
        self.counts["image_frames"] += 1
        self._enqueue(msg, self._from_image)

    def _enqueue(self, msg, extract):
        """Subscription callbacks: count the frame and queue it for the worker. A full queue
        drops its oldest frame (``frames_skipped``): the newest frames are the ones solved."""
        arrival = time.perf_counter()
        with self._lock:
            self.counts["received"] += 1
            skipped = 0
            while len(self._queue) >= self.cfg["queue_size"]:
                self._queue.popleft()
                skipped += 1
            self.counts["skipped"] += skipped
            self._queue.append((msg, extract, arrival))
            self._lock.notify_all()
        if skipped:
            self._log_throttled(
                "skipped",
                "busy: frame queue full (queue_size "
                f"{self.cfg['queue_size']}), dropped the oldest waiting frame "
                f"[{self.counts['skipped']} skipped so far]",
            )

    def _work(self):
        """The worker thread: frames out of the queue, through :meth:`_handle`, in order."""
        while True:
            with self._lock:
                while not self._queue and not self._stop:
                    self._lock.wait()
                if self._stop:
                    return
                msg, extract, arrival = self._queue.popleft()
                self._busy = True
            try:
                self._safe_handle(msg, extract, arrival)
            finally:
                with self._lock:
                    self._busy = False

    def destroy_node(self):
        """Stop the worker thread (the frame it is on is finished), release the shared maps,
        then destroy the node."""
        if getattr(self, "_lock", None) is not None:
            self._stop_worker()
        SHARED_MAPS.release(self)  # (maps no other camera of the process uses are freed)
        return super().destroy_node()

    def _safe_handle(self, msg, extract, arrival=None):
        try:
            self._handle(msg, extract, arrival)
        except Exception as e:
            self._fail("internal_error", f"{type(e).__name__}: {e}")

    def _corr_out_publisher(self):
        if self.pub_corr_out is None:
            self.pub_corr_out = self._make_publisher(
                PointCloud2,
                "correspondences_out",
                QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE),
            )
        return self.pub_corr_out

    def _fail(self, reason: str, detail: str):
        self.counts["failed"] += 1
        self.counts[f"failed.{reason}"] += 1
        self._log_throttled(reason, f"frame dropped ({reason}): {detail}")

    def _log_throttled(self, key, text):
        now = time.monotonic()
        if now - self._last_log.get(key, -1e9) >= _LOG_PERIOD:
            self._last_log[key] = now
            n = self.counts.get(f"failed.{key}", 0)
            self.get_logger().warning(text + (f" [{n} so far]" if n > 1 else ""))

    def _reset_time_state(self, stamp: int, why: str):
        """Time went back (or jumped ahead by more than ``time_reset_threshold``): forget what
        depends on time (camera_infos stamped after ``stamp``, kept when nothing else is
        left), count and log it. Frames are never dropped for their stamp."""
        self.counts["time_resets"] += 1
        self._log_throttled("time_reset", f"time reset: {why}")
        with self._lock:
            keep = [e for e in self._cam_hist if e[0] <= stamp]
            if not keep and self._cam_hist:
                keep = [max(self._cam_hist, key=lambda e: e[4])]
            self._cam_hist = keep
            self._frame_stamps.clear()

    def _handle(self, msg, extract, arrival=None):
        """The pipeline of every frame: checks, ``extract(msg, camera, stamp) -> (uv, xyz,
        scores)`` (raises :class:`_Drop` or :class:`CloudError` for a bad frame), cap,
        estimate, publish, count. ``arrival``: ``perf_counter`` when the frame arrived (the
        latency is measured from it)."""
        tic = time.perf_counter()
        arrival = tic if arrival is None else arrival
        self._t_frontend = 0.0
        cfg = self.cfg
        try:
            stamp = cv.checked_stamp_ns(msg.header.stamp)
        except cv.StampError as e:
            return self._fail("bad_stamp", str(e))
        if isinstance(msg, PointCloud2) and int(msg.width) * int(msg.height) == 0:
            return self._fail("empty_cloud", "cloud has no points")
        last = self._last_stamp
        self._last_stamp = stamp
        if last is not None and stamp < last:
            self._reset_time_state(
                stamp,
                f"stamp {stamp * 1e-9:.6f} s is {(last - stamp) * 1e-9:.3f}"
                " s older than the previous frame",
            )
        elif last is not None and stamp - last > cfg["time_reset_ns"]:
            self._reset_time_state(
                stamp,
                f"{(stamp - last) * 1e-9:.3f} s since the previous frame (> time_reset_threshold)",
            )
        camera = self._camera_for(stamp)
        if camera is None:
            return self._fail(
                "no_camera_info",
                "no camera_info received (waited "
                f"{cfg['camera_info_wait']:.3f} s) and no fallback intrinsics "
                "(camera.fx <= 0)",
            )
        out_stamp = stamp + int(
            round(camera.time_offset(cfg["stamp_row"], camera.reference_line) * 1e9)
        )
        if not 0 <= out_stamp <= cv.STAMP_MAX_NS:
            return self._fail(
                "bad_stamp",
                f"output stamp {out_stamp} ns (input {stamp} ns + "
                "the reference row's offset) is outside [0, 2^31 s)",
            )
        try:
            uv, xyz, scores = extract(msg, camera, stamp)
        except (_Drop, CloudError) as e:
            return self._fail(e.reason, str(e))
        # rows with NaN/inf go before the cap, so that the cap keeps valid rows
        good = np.isfinite(uv).all(axis=1) & np.isfinite(xyz).all(axis=1)
        n_bad = len(uv) - int(np.count_nonzero(good))
        if n_bad:
            self.counts["points_dropped"] += n_bad
            uv, xyz = uv[good], xyz[good]
            scores = None if scores is None else scores[good]
        if len(uv) > cfg["max_points"]:
            self.counts["capped_clouds"] += 1
            self.counts["capped_points"] += len(uv) - cfg["max_points"]
            if scores is not None and np.isfinite(scores).any():
                keep = np.argsort(-np.nan_to_num(scores, nan=-np.inf), kind="stable")[
                    : cfg["max_points"]
                ]
                keep.sort()
            else:
                keep = np.linspace(0, len(uv) - 1, cfg["max_points"]).astype(int)
            self._log_throttled(
                "capped", f"cloud of {len(uv)} points capped to max_points {cfg['max_points']}"
            )
            uv, xyz = uv[keep], xyz[keep]
            scores = None if scores is None else scores[keep]
        t_decoded = time.perf_counter()
        frame = cfg["camera_frame"] or msg.header.frame_id or "camera"
        mf = cfg["map_frame"]
        with self._track_lock:
            final = []
            try:
                if cfg["tracking"] is not None:
                    tracker, final = self._tracker_for(camera, cfg)
                    r = tracker.process(out_stamp, uv, xyz, camera, scores)
                    est = r.estimate
                    final = final + r.final
                    self._last_frame_wall = time.monotonic()
                else:
                    self._drop_tracker()
                    est = estimate_rs_pose(
                        uv, xyz, camera, solver=cfg["solver"], options=cfg["options"], scores=scores
                    )
            except Exception as e:
                self._publish_fused(final)
                return self._fail("estimator_error", f"{type(e).__name__}: {e}")
            t_estimated = time.perf_counter()
            self.counts["points_dropped"] += int(est.num_dropped)
            if not est.success:  # (twists of earlier frames a reset made final still go out)
                self._publish_fused(final)
                return self._fail(
                    est.failure or "estimator_error",
                    f"{len(uv)} points, {est.num_inliers} inliers, solver {cfg['solver']}",
                )
            self._handle_solved(
                est,
                uv,
                xyz,
                camera,
                stamp,
                out_stamp,
                frame,
                mf,
                final,
                arrival,
                tic,
                t_decoded,
                t_estimated,
            )

    def _handle_solved(
        self,
        est,
        uv,
        xyz,
        camera,
        stamp,
        out_stamp,
        frame,
        mf,
        final,
        arrival,
        tic,
        t_decoded,
        t_estimated,
    ):
        """Publish a solved frame (and the fused twists now final), count, time."""
        cfg = self.cfg
        self.counts["solved"] += 1  # (before publishing: whoever has the pose sees the count)
        self.inliers.append(est.num_inliers)
        self._planar_last = (est.planar, est.condition_number)
        out, out_frame = est, frame  # the camera's pose and twist, or the robot base's
        if cfg["extrinsic"] is not None:
            out, out_frame = camera_to_base(est, cfg["extrinsic"]), cfg["base_frame"]
        # (messages nobody subscribes to are not even built: ~0.1 ms each)
        self.pub_pose.publish(cv.pose_stamped(out, out_stamp, mf))
        if self.pub_twist_single.get_subscription_count():
            self.pub_twist_single.publish(cv.twist_stamped(out, out_stamp, out_frame))
        # (global-shutter solver or timing: no twist to fuse; twist / odom stay the per-frame,
        # zero, twist)
        if (
            cfg["tracking"] is None
            or not solver_info(cfg["solver"]).rolling
            or camera.seconds_per_unit_r <= 0
        ):
            if self.pub_twist.get_subscription_count():
                self.pub_twist.publish(cv.twist_stamped(out, out_stamp, out_frame))
            if self.pub_odom.get_subscription_count():
                self.pub_odom.publish(cv.odometry(out, out_stamp, mf, out_frame))
        else:  # twist / odom when the frame's fused twist is final (tracking.lag frames on)
            self._pending_out[out_stamp] = (est, frame)
            self._publish_fused(final)
        if self.pub_pwc.get_subscription_count():
            self.pub_pwc.publish(cv.pose_with_covariance_stamped(out, out_stamp, mf))
        if self._tf_pub is not None and self._tf_pub.get_subscription_count():
            self._tf_pub.publish(cv.tf_message(out, out_stamp, mf, out_frame))
        self.viz.publish(est, uv, xyz, camera, stamp, out_stamp, frame, mf)  # (camera frame)
        toc = time.perf_counter()
        self.latencies.append(toc - arrival)
        self.stamp_ages.append((self.get_clock().now().nanoseconds - stamp) * 1e-9)
        self.stage_times["decode"].append(t_decoded - tic - self._t_frontend)
        self.stage_times["estimate"].append(t_estimated - t_decoded)
        self.stage_times["publish"].append(toc - t_estimated)

    # ------------------------------------------------------------------ tracking
    def _tracker_for(self, camera, cfg):
        """The tracker for this camera and configuration: a new one when the solver, the
        estimator or tracking options or the camera model changed (the old track's pending
        twists are returned to be published). Returns (tracker, final states)."""
        key = (cfg["solver"], cfg["options"], cfg["tracking"], id(camera))
        final = []
        if self._tracker is None or key != self._tracker_key:
            if self._tracker is not None:
                final = self._drop_tracker(flush=True)
                self._track_counts["resets"] += 1
            self._tracker = RSTracker(cfg["solver"], cfg["options"], cfg["tracking"])
            self._tracker_key = key
            self._tracker_camera = camera  # (keeps id(camera) unique while in use)
        return self._tracker, final

    def _drop_tracker(self, flush: bool = False):
        """Forget the tracker (its counters are kept); returns its pending fused states when
        ``flush``, else drops them with the outputs waiting for them."""
        final = []
        t = self._tracker
        if t is not None:
            for k in ("frames_tracked", "relocalizations", "resets"):
                self._track_counts[k] += getattr(t, k)
            final = t.reset() if flush else []
        self._tracker = self._tracker_key = None
        if not flush:
            self._pending_out.clear()
        return final

    def _publish_fused(self, final):
        """twist and odom of frames whose fused state is final: the frame's own pose (as
        published) with the fused twist and its covariance, stamped with the frame's time."""
        for f in final:
            item = self._pending_out.pop(f.stamp_ns, None)
            if item is None:
                continue
            est, frame = item
            src = _Fused(est, f)
            out, out_frame = src, frame
            if self.cfg["extrinsic"] is not None:
                out, out_frame = camera_to_base(src, self.cfg["extrinsic"]), self.cfg["base_frame"]
            self.pub_twist.publish(cv.twist_stamped(out, f.stamp_ns, out_frame))
            self.pub_odom.publish(cv.odometry(out, f.stamp_ns, self.cfg["map_frame"], out_frame))
        if len(self._pending_out) > 64:  # (never left behind for long: drop the oldest)
            for k in sorted(self._pending_out)[:-64]:
                del self._pending_out[k]

    def _flush_idle_track(self):
        """Timer: after ``tracking.max_gap`` without frames the track is over (the next frame
        resets it): publish the twists still pending."""
        if self._tracker is None or self.cfg is None or self.cfg["tracking"] is None:
            return
        with self._track_lock:
            last = self._last_frame_wall
            if (
                self._tracker is None
                or last is None
                or not self._pending_out
                or time.monotonic() - last < self.cfg["tracking"].max_gap
            ):
                return
            self._publish_fused(self._tracker.flush())

    def _from_correspondences(self, msg, camera, stamp):
        c = read_correspondences(msg)
        return c.uv, c.xyz, c.scores

    def _from_keypoints(self, msg, camera, stamp):
        if self._landmarks is None:
            raise _Drop("no_landmarks", "keypoints received but no landmarks_file is loaded")
        kp = read_keypoints(msg)
        ids, pts = self._landmarks
        j = np.clip(np.searchsorted(ids, kp.ids), 0, len(ids) - 1)
        known = ids[j] == kp.ids
        n_unknown = int(np.count_nonzero(~known))
        if n_unknown:
            self.counts["unknown_landmark_ids"] += n_unknown
        if not known.any():
            raise _Drop("unknown_landmarks", f"none of the {len(kp)} keypoint ids is in the map")
        scores = None if kp.scores is None else kp.scores[known]
        return kp.uv[known], pts[j[known]], scores

    def _from_image(self, msg, camera, stamp):
        """Decode, run the front end, optionally republish its correspondences."""
        from ..frontends.image import image_from_compressed, image_from_msg

        fe = self._frontend
        if fe is None:  # (the subscription exists only with a front end)
            raise _Drop("no_frontend", "image received but frontend is none")
        if isinstance(msg, CompressedImage):
            try:
                img, enc = image_from_compressed(msg)
            except ValueError as e:
                raise _Drop("bad_image", str(e)) from None
            h, w = img.shape[:2]
        else:
            h, w = int(msg.height), int(msg.width)
            if h * w == 0:
                raise _Drop("bad_image", f"empty image ({w}x{h})")
            try:
                img, enc = image_from_msg(msg)
            except ValueError as e:
                raise _Drop("bad_image", str(e)) from None
        if camera.width > 0 and camera.height > 0 and (w, h) != (camera.width, camera.height):
            raise _Drop(
                "image_size_mismatch",
                f"image is {w}x{h}, the camera model {camera.width}x{camera.height}",
            )
        self.viz.set_image(img, enc, stamp)
        t0 = time.perf_counter()
        try:
            uv, xyz, ids = fe.process(img, camera, encoding=enc)
        except Exception as e:
            raise _Drop(
                "frontend_error", f"{self.cfg['frontend']}: {type(e).__name__}: {e}"
            ) from None
        self._t_frontend = time.perf_counter() - t0
        self.stage_times["frontend"].append(self._t_frontend)
        scores = getattr(fe, "last_scores", None)
        if scores is not None and len(scores) != len(uv):
            scores = None
        self.counts["frontend_runs"] += 1
        self.counts["frontend_points"] += len(uv)
        self._frontend_last = len(uv)
        if self.cfg["republish"]:
            frame = self.cfg["camera_frame"] or msg.header.frame_id or "camera"
            self._corr_out_publisher().publish(
                correspondence_cloud(uv, xyz, ids, scores, frame_id=frame, stamp=stamp)
            )
        need = max(self.cfg["options"].min_inliers, sample_size(self.cfg["solver"]) + 1)
        if len(uv) < need:
            what = (
                f"{len(uv) // 4} markers"
                if self.cfg["frontend"] == "aruco"
                else f"{len(uv)} matches"
            )
            raise _Drop(
                "frontend_too_few_points",
                f"{self.cfg['frontend']} front end found "
                f"{what}: {len(uv)} correspondences, {need} needed",
            )
        return uv, xyz, scores

    # ------------------------------------------------------------------ diagnostics
    def diagnostics_status(self) -> DiagnosticStatus:
        with self._lock:  # (a consistent snapshot of the counters the two threads write)
            c = Counter(self.counts)
            pending = len(self._queue) + int(self._busy)
            camera_source = (
                "camera_info"
                if self._cam_hist
                else "parameters"
                if self.cfg["fallback"] is not None
                else "missing"
            )
        lat = np.array(list(self.latencies)) * 1e3
        age = np.array(list(self.stamp_ages)) * 1e3
        st = DiagnosticStatus()
        st.name = f"rs_localizer: {self.get_fully_qualified_name()}"
        st.hardware_id = self.cfg["camera_frame"] or "camera"
        failed = {k[7:]: v for k, v in sorted(c.items()) if k.startswith("failed.")}
        if c["received"] and not c["solved"]:
            st.level = DiagnosticStatus.ERROR
            st.message = "no frame solved" + (f" ({failed})" if failed else "")
        elif c["failed"] or self.messages_lost or c["skipped"]:
            st.level = DiagnosticStatus.WARN
            st.message = f"{c['solved']}/{c['received']} frames solved" + (
                f", {c['skipped']} skipped (busy)" if c["skipped"] else ""
            )
        else:
            st.level = DiagnosticStatus.OK
            st.message = (
                f"{c['solved']}/{c['received']} frames solved"
                if c["received"]
                else "waiting for frames"
            )
        values = {
            "solver": self.cfg["solver"],
            "camera": camera_source,
            "frames_received": c["received"],
            "frames_solved": c["solved"],
            "frames_failed": c["failed"],
            "frames_skipped": c["skipped"],
            "frames_pending": pending,
            "queue_size": self.cfg["queue_size"],
            "time_resets": c["time_resets"],
            "messages_lost": self.messages_lost,
            "points_dropped": c["points_dropped"],
            "clouds_capped": c["capped_clouds"],
            "unknown_landmark_ids": c["unknown_landmark_ids"],
            "camera_info_rejected": c["camera_info_rejected"],
            "inliers_last": self.inliers[-1] if self.inliers else 0,
            "inliers_mean": f"{np.mean(self.inliers):.1f}" if self.inliers else "0",
            "planar": str(self._planar_last[0]).lower(),
            **self._tracking_values(),
            "condition_number_last": f"{self._planar_last[1]:.3g}",
            "latency_ms_last": f"{lat[-1]:.3f}" if len(lat) else "nan",
            "latency_ms_median": f"{np.median(lat):.3f}" if len(lat) else "nan",
            "latency_ms_p99": f"{np.percentile(lat, 99):.3f}" if len(lat) else "nan",
            "stamp_age_ms_last": f"{age[-1]:.3f}" if len(age) else "nan",
            "stamp_age_ms_median": f"{np.median(age):.3f}" if len(age) else "nan",
        }
        for k, d in self.stage_times.items():
            if k == "frontend" and self._frontend is None:
                continue
            d = list(d)
            values[f"{k}_ms_median"] = f"{np.median(d) * 1e3:.3f}" if d else "nan"
        if self._frontend is not None:
            fe_ms = self.stage_times["frontend"]
            values.update(
                {
                    "frontend": self.cfg["frontend"],
                    "image_frames": c["image_frames"],
                    "frontend_ms_last": f"{fe_ms[-1] * 1e3:.3f}" if fe_ms else "nan",
                    "frontend_correspondences_last": self._frontend_last,
                    "frontend_correspondences_mean": (
                        f"{c['frontend_points'] / c['frontend_runs']:.1f}"
                        if c["frontend_runs"]
                        else "0"
                    ),
                }
            )
        values.update({f"failed.{k}": v for k, v in failed.items()})
        values.update({k: v for k, v in sorted(c.items()) if k.startswith("camera_info_rejected.")})
        st.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        return st

    def _tracking_values(self) -> dict:
        """Diagnostics of video tracking: track_state (tracking, lost or disabled),
        frames_tracked, relocalizations, resets (over the node's life)."""
        t = self._tracker
        tc = self._track_counts
        on = self.cfg is not None and self.cfg["tracking"] is not None
        state = "disabled" if not on else t.track_state if t is not None else "lost"
        return {
            "track_state": state,
            "frames_tracked": tc["frames_tracked"] + (t.frames_tracked if t else 0),
            "relocalizations": tc["relocalizations"] + (t.relocalizations if t else 0),
            "resets": tc["resets"] + (t.resets if t else 0),
        }

    def publish_diagnostics(self):
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [self.diagnostics_status()]
        self.pub_diag.publish(msg)


class RSLocalizerNode(LocalizerCore, Node):
    """The localizer node: configured (JIT warm-up included), subscribed and publishing from
    construction. ``node_name`` and ``kwargs`` go to :class:`rclpy.node.Node`.

    Raises:
        RuntimeError: invalid parameters (the message names the parameter).
    """

    def __init__(self, node_name: str = "rs_localizer", **kwargs):
        Node.__init__(self, node_name, **kwargs)
        self._declare_parameters()
        self._init_state()
        self._configure()
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._create_outputs()
        self._create_camera_info_input()
        self._create_frame_inputs()
        self._log_ready()


def main(args=None):
    """Entry point of ``rs_localizer_node`` (``ros2 run rs_localizer rs_localizer_node``): one
    node, or one per camera namespace in the ``cameras`` parameter (:mod:`.runner`)."""
    from .runner import run

    return run(RSLocalizerNode, args, "rs_localizer_node")


if __name__ == "__main__":
    sys.exit(main())
