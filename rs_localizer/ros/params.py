"""The node's parameters: each declared once, with its default, description, range and
read-only flag, and the checks of their values (no ROS needed).

:data:`PARAMETERS` declares every parameter of ``rs_localizer_node`` (``config/rs_localizer.yaml``
lists them with their defaults; ``make params`` writes the docs' tables from it), and
:data:`RIG_PARAMETERS` and :data:`RIG_CAMERA_PARAMETERS` the rig mode's. :func:`default_values`
gives every parameter's default, :func:`check_parameter` checks a value as ROS does, and
:func:`option_fields` groups the values by the settings field each sets
(:attr:`Parameter.field`). Elsewhere: the ROS 2 parameter files are read by
:mod:`.param_files`, the node's configuration is built from the values by :mod:`.config`
(the library's settings by :mod:`rs_localizer.tracking.settings` and
:func:`rs_localizer.frontends.registry.frontend_options`), and the maps it names are loaded by
:func:`.config.load_maps`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

from ..camera import DISTORTION_MODELS, READOUT_DIRECTIONS
from ..frames import OPTICAL_TO_BODY_QUATERNION
from ..frontends.registry import FRONTENDS
from ..solvers.registry import SOLVER_NAMES as SOLVERS

__all__ = [
    "FRONTEND_CHOICES",
    "IMAGE_TRANSPORTS",
    "OPTION_GROUPS",
    "OTHER_NODE_PARAMETERS",
    "PARAMETERS",
    "RIG_CAMERA_PARAMETERS",
    "RIG_PARAMETERS",
    "ConfigError",
    "FloatRange",
    "IntRange",
    "Parameter",
    "check_parameter",
    "default_values",
    "option_fields",
]


@dataclass(frozen=True)
class FloatRange:
    """Allowed values of a floating-point parameter: ``from_value <= x <= to_value`` (the
    node declares it as ``rcl_interfaces/FloatingPointRange``, step 0: any value)."""

    from_value: float
    to_value: float
    step: float = 0.0


@dataclass(frozen=True)
class IntRange:
    """Allowed values of an integer parameter: ``from_value <= x <= to_value`` (declared as
    ``rcl_interfaces/IntegerRange``)."""

    from_value: int
    to_value: int
    step: int = 1


class Parameter(NamedTuple):
    """One node parameter: the single place its name (the :data:`PARAMETERS` key), default,
    description, range and read-only flag are written, and where its value goes.

    Attributes:
        default: the value when no parameter file or override sets it; its type is the
            parameter's type (``float`` parameters need ``0.0`` in YAML, not ``0``).
        description: the ROS parameter descriptor's text (``ros2 param describe``).
        range: :class:`FloatRange`, :class:`IntRange` or None (any value).
        read_only: the node refuses changes at run time.
        field: the options field it sets, ``"<group>"`` or ``"<group>:<path>"`` with
            ``<group>`` one of :data:`OPTION_GROUPS` (``estimate``: ``EstimateOptions``,
            ``tracking``: ``TrackerOptions``, ``imu``: ``GyroSettings``). Without a path
            the field has the parameter's name less the group's prefix (``ransac.seed`` ->
            ``EstimateOptions.ransac.seed``, ``tracking.gate_px`` -> ``TrackerOptions.gate_px``);
            a path says where the names differ (``refine`` -> ``refine.enabled``). None: read
            by :func:`rs_localizer.ros.config.build_config` itself (frames, camera, queue,
            front end).
    """

    default: Any
    description: str
    range: FloatRange | IntRange | None = None
    read_only: bool = False
    field: str | None = None


#: the lens models of ``camera.distortion_model`` (:data:`~rs_localizer.camera.DISTORTION_MODELS`)
_MODELS = tuple(DISTORTION_MODELS)

#: name -> :class:`Parameter`: every parameter of the node, in the order of
#: config/rs_localizer.yaml and docs/node.md (``python -m rs_localizer.ros.param_docs --write``
#: rewrites their defaults from this table; test/test_docs_sync.py checks them)
PARAMETERS = {
    "solver": Parameter(
        "r6p_1lin", f"minimal solver: one of {', '.join(SOLVERS)} (p3p = global shutter)"
    ),
    "ransac.threshold_px": Parameter(
        2.0,
        "RANSAC inlier threshold on the reprojection error (px)",
        FloatRange(from_value=0.05, to_value=100.0),
        field="estimate",
    ),
    "ransac.max_iterations": Parameter(
        1000, "RANSAC iteration cap", IntRange(from_value=1, to_value=1_000_000), field="estimate"
    ),
    "ransac.confidence": Parameter(
        0.9999,
        "RANSAC adaptive-termination confidence",
        FloatRange(from_value=0.5, to_value=0.999999999),
        field="estimate",
    ),
    "ransac.min_inliers": Parameter(
        12, "fewest inliers for a pose", IntRange(from_value=3, to_value=100_000), field="estimate"
    ),
    "ransac.seed": Parameter(
        0,
        "RANSAC random seed (deterministic)",
        IntRange(from_value=0, to_value=2_147_483_647),
        field="estimate",
    ),
    "refine": Parameter(
        True,
        "nonlinear refinement on the exact constant-velocity model",
        field="estimate:refine.enabled",
    ),
    "motion_prior.angular_velocity_sigma": Parameter(
        3.0,
        "motion prior: sigma of each angular velocity component (rad/s, camera frame); "
        "0 = no prior on it",
        FloatRange(from_value=0.0, to_value=1e4),
        field="estimate",
    ),
    "motion_prior.linear_velocity_sigma": Parameter(
        1.5,
        "motion prior: sigma of each linear velocity component (m/s, camera frame); "
        "0 = no prior on it (both 0: maximum likelihood, near-degenerate on planar scenes)",
        FloatRange(from_value=0.0, to_value=1e4),
        field="estimate",
    ),
    "correlated_noise.sigma_px": Parameter(
        0.0,
        "std (px per axis) of a spatially correlated image error (lens-model residue, "
        "corner bias) in the covariance; 0 = white noise only. Fit it on still calibration "
        "views (estimation.noise_model.fit_correlated_noise)",
        FloatRange(from_value=0.0, to_value=100.0),
        field="estimate",
    ),
    "correlated_noise.length_px": Parameter(
        100.0,
        "correlation length (px) of that error",
        FloatRange(from_value=0.1, to_value=1e5),
        field="estimate",
    ),
    "correlated_noise.shift_share": Parameter(
        0.0,
        "share of a marker corner's error variance that the marker's 4 corners share (its "
        "image shifted as a whole), in the covariance of frames with too few markers to "
        "estimate it themselves (frames with more estimate their own); 0 = none there. "
        "Measure it with python -m benchmarks.reference_fit",
        FloatRange(from_value=0.0, to_value=0.99),
        field="estimate",
    ),
    "rs.line_delay": Parameter(
        3.0e-5,
        "time between consecutive image lines (s/line); 0 = global shutter",
        FloatRange(from_value=0.0, to_value=0.01),
    ),
    "rs.readout_time": Parameter(
        0.0,
        "time to read the whole frame (s); if > 0 it wins over "
        "rs.line_delay (line_delay = readout_time / lines)",
        FloatRange(from_value=0.0, to_value=1.0),
    ),
    "rs.direction": Parameter(
        "top_to_bottom", "readout direction: " + ", ".join(READOUT_DIRECTIONS)
    ),
    "rs.reference_row": Parameter(
        -1.0,
        "line (px) at which the pose is estimated; -1 = image centre",
        FloatRange(from_value=-1.0, to_value=100_000.0),
    ),
    "rs.stamp_row": Parameter(
        0.0,
        "line (px) whose capture time is the input header.stamp",
        FloatRange(from_value=0.0, to_value=100_000.0),
    ),
    "map_frame": Parameter("map", "frame of the published pose", read_only=True),
    "camera_frame": Parameter(
        "", "camera optical frame of the outputs; empty = input header.frame_id"
    ),
    "publish_tf": Parameter(
        True, "publish map -> camera (or base_frame) on /tf (needs tf2_msgs)", read_only=True
    ),
    "base_frame": Parameter(
        "",
        "robot body frame (REP 103, e.g. base_link); set: pose, "
        "pose_with_covariance, odom, twist and /tf describe it instead of the camera "
        "(camera_to_base.* is the mounting); empty = the camera optical frame",
    ),
    "camera_to_base.translation": Parameter(
        [0.0, 0.0, 0.0],
        "camera optical frame origin in base_frame (m, x y z): the base_frame -> camera transform",
    ),
    "camera_to_base.rotation": Parameter(
        list(OPTICAL_TO_BODY_QUATERNION),
        "rotation camera optical "
        "frame -> base_frame, quaternion x y z w (default: a camera "
        "looking along the base's x axis)",
    ),
    "landmarks_file": Parameter("", "CSV id,x,y,z for the keypoints topic (reloaded on change)"),
    "max_points": Parameter(
        5000,
        "clouds with more points are capped (highest scores, else evenly spaced), with a warning",
        IntRange(from_value=10, to_value=10_000_000),
    ),
    "time_reset_threshold": Parameter(
        1.0,
        "a frame stamped later than the previous one by more than "
        "this (s) resets the time-dependent state (a gap); any step back "
        "does too. Frames are never dropped for their stamp",
        FloatRange(from_value=0.0, to_value=1e6),
    ),
    "queue_size": Parameter(
        5,
        "frames waiting to be solved; when full, the oldest waiting frame is "
        "dropped (counted in frames_skipped) so that the newest are solved",
        IntRange(from_value=1, to_value=10_000),
    ),
    "camera_info_wait": Parameter(
        0.05,
        "s a frame may wait for its camera_info: when none has arrived "
        "yet, or when camera_info comes with every frame (same stamps) and "
        "the frame's own has not arrived yet",
        FloatRange(from_value=0.0, to_value=5.0),
    ),
    "max_angular_velocity": Parameter(
        20.0,
        "rad/s; a model turning faster is implausible (never published: implausible_motion)",
        FloatRange(from_value=0.01, to_value=1e6),
        field="estimate:plausibility.max_angular_velocity",
    ),
    "max_linear_velocity": Parameter(
        50.0,
        "m/s; a model moving faster is implausible",
        FloatRange(from_value=0.01, to_value=1e9),
        field="estimate:plausibility.max_linear_velocity",
    ),
    "tracking.enabled": Parameter(
        True,
        "track the camera through the video: predicted RANSAC, "
        "relocalization, and twist / odom carry the fused twist; "
        "false: every frame alone",
    ),
    "tracking.lag": Parameter(
        1,
        "frames of smoothing delay of the fused twist: twist / odom of a frame "
        "are published when this many later frames have been fused (0: at once, "
        "causal filter)",
        IntRange(from_value=0, to_value=10),
        field="tracking:fusion.lag",
    ),
    "tracking.max_gap": Parameter(
        0.5,
        "s; a longer gap between frames (or a stamp going back) resets "
        "the track; after this long without frames the pending twists are "
        "published",
        FloatRange(from_value=0.01, to_value=60.0),
        field="tracking",
    ),
    "tracking.gate_px": Parameter(
        20.0,
        "a point is explained by the prediction within this distance "
        "(px); too few explained points: relocalize",
        FloatRange(from_value=0.5, to_value=1000.0),
        field="tracking",
    ),
    "tracking.angular_noise": Parameter(
        30.0,
        "filter process noise: angular jerk density (rad/s^3/sqrt(Hz))",
        FloatRange(from_value=1e-3, to_value=1e6),
        field="tracking:fusion.angular_noise",
    ),
    "tracking.linear_noise": Parameter(
        5.0,
        "filter process noise: linear jerk density (m/s^3/sqrt(Hz))",
        FloatRange(from_value=1e-3, to_value=1e6),
        field="tracking:fusion.linear_noise",
    ),
    "tracking.prior_from_prediction": Parameter(
        "planar",
        "the estimator's motion prior is the predicted "
        "twist: planar (when the last frame was planar), always "
        "or never",
        field="tracking",
    ),
    "imu.enabled": Parameter(
        False,
        "subscribe to imu (sensor_msgs/Imu) and use its gyro in the estimate: the mean "
        "angular velocity over each frame's readout, as a measurement with its covariance",
        read_only=True,
    ),
    "imu.rotation": Parameter(
        [0.0, 0.0, 0.0, 1.0],
        "rotation IMU frame -> camera optical frame (rig mode: -> base_frame), quaternion "
        "x y z w (rs-localizer calibrate-readout --imu-topic prints it)",
    ),
    "imu.time_offset": Parameter(
        0.0,
        "s added to the IMU stamps to put them on the camera's clock",
        FloatRange(from_value=-1.0, to_value=1.0),
        field="imu",
    ),
    "imu.gyro_noise": Parameter(
        0.003,
        "standard deviation of one gyro sample (rad/s); averaged over the samples of a readout",
        FloatRange(from_value=1e-6, to_value=10.0),
        field="imu",
    ),
    "imu.gyro_bias": Parameter(
        [0.0, 0.0, 0.0],
        "gyro bias subtracted from the rates (rad/s, IMU frame; calibrate-readout "
        "--imu-topic prints it)",
    ),
    "imu.gyro_bias_sigma": Parameter(
        0.005,
        "uncertainty of imu.gyro_bias per axis (rad/s); with imu.estimate_bias the initial "
        "uncertainty of the estimate, else fixed (it does not average down)",
        FloatRange(from_value=0.0, to_value=10.0),
        field="imu",
    ),
    "imu.estimate_bias": Parameter(
        True,
        "estimate the gyro bias online from the rotation between consecutive solved frames, "
        "starting from imu.gyro_bias with imu.gyro_bias_sigma; the frames' gyro uses the "
        "estimate and its uncertainty",
        read_only=True,
        field="imu",
    ),
    "imu.bias_random_walk": Parameter(
        1e-4,
        "rad/s per sqrt(s): how fast the estimated gyro bias may drift (imu.estimate_bias)",
        FloatRange(from_value=0.0, to_value=1.0),
        field="imu",
    ),
    "imu.wait": Parameter(
        0.03,
        "s a frame may wait for the gyro samples covering its readout; then it is solved "
        "without the gyro (gyro_missing.not_covered)",
        FloatRange(from_value=0.0, to_value=1.0),
        field="imu",
    ),
    "imu.buffer": Parameter(
        2.0,
        "s of gyro samples kept for frames that arrive late",
        FloatRange(from_value=0.1, to_value=60.0),
        read_only=True,
        field="imu",
    ),
    "imu.max_rate": Parameter(
        35.0,
        "rad/s; a sample with a larger component is the gyro's saturation and rejected",
        FloatRange(from_value=0.1, to_value=1000.0),
        field="imu",
    ),
    "imu.max_gap": Parameter(
        0.02,
        "s; a readout whose gyro samples are further apart is solved without the gyro "
        "(gyro_missing.sparse: an IMU topic too slow to describe one readout)",
        FloatRange(from_value=0.001, to_value=1.0),
        field="imu",
    ),
    "diagnostics_period": Parameter(
        1.0,
        "period of /diagnostics (s)",
        FloatRange(from_value=0.05, to_value=60.0),
        read_only=True,
    ),
    "warmup": Parameter(
        True, "solve a synthetic problem at start (JIT compilation)", read_only=True
    ),
    "camera.fx": Parameter(
        0.0,
        "fallback intrinsics until camera_info arrives; fx <= 0 = wait for camera_info",
        FloatRange(from_value=0.0, to_value=1e6),
    ),
    "camera.fy": Parameter(0.0, "fallback fy (px)", FloatRange(from_value=0.0, to_value=1e6)),
    "camera.cx": Parameter(0.0, "fallback cx (px)", FloatRange(from_value=-1e6, to_value=1e6)),
    "camera.cy": Parameter(0.0, "fallback cy (px)", FloatRange(from_value=-1e6, to_value=1e6)),
    "camera.width": Parameter(
        0, "fallback image width (px)", IntRange(from_value=0, to_value=100_000)
    ),
    "camera.height": Parameter(
        0, "fallback image height (px)", IntRange(from_value=0, to_value=100_000)
    ),
    "camera.distortion_model": Parameter(
        "plumb_bob",
        f"fallback distortion model: {', '.join(_MODELS[:-1])} or {_MODELS[-1]}",
    ),
    "camera.d": Parameter(
        [0.0, 0.0, 0.0, 0.0, 0.0], "fallback distortion coefficients (OpenCV order)"
    ),
    "frontend": Parameter(
        "none",
        "image front end: none (no image subscription), aruco, features or board "
        "(checkerboard, ChArUco or AprilTag/ArUco tag board from a board YAML)",
        read_only=True,
    ),
    "frontend_map": Parameter(
        "",
        "map of the front end: aruco: marker map YAML, scene YAML or a "
        "built-in scene name (aruco_room); features: feature map .npz; board: "
        "board YAML (reloaded on change)",
    ),
    "image_transport": Parameter(
        "raw",
        "image input with a front end: raw (sensor_msgs/Image on image) "
        "or compressed (sensor_msgs/CompressedImage, JPEG or PNG, on "
        "image/compressed, decoded with OpenCV)",
        read_only=True,
    ),
    "republish_correspondences": Parameter(
        False,
        "publish the front end's correspondences on "
        "correspondences_out (PointCloud2) for inspection",
    ),
    "features.tracking": Parameter(
        True,
        "features front end on video: track the last frame's inliers (optical flow) and match "
        "map points near their predicted pixels; full detection + global matching only to "
        "(re)localize. false: full detection and global matching on every image",
        read_only=True,
    ),
    "features.matcher": Parameter(
        "auto",
        "global matching of the features front end: auto (flann for SIFT maps, bf for ORB "
        "maps), bf (exact brute force) or flann (approximate; SIFT maps only)",
        read_only=True,
    ),
    "features.flann_checks": Parameter(
        32,
        "leaves FLANN visits per query (more: closer to brute force, slower)",
        IntRange(from_value=1, to_value=4096),
        read_only=True,
    ),
    "features.max_features": Parameter(
        2000,
        "features detected per image on global and refresh frames",
        IntRange(from_value=10, to_value=100_000),
        read_only=True,
    ),
    "features.refresh_frames": Parameter(
        10,
        "with tracking: a background detection refreshes the tracks every this many frames "
        "(0: only when they run low)",
        IntRange(from_value=0, to_value=10_000),
        read_only=True,
    ),
    "features.search_radius_px": Parameter(
        8.0,
        "px; guided matching window around each map point's predicted pixel",
        FloatRange(from_value=1.0, to_value=200.0),
        read_only=True,
    ),
    "aruco.windowed": Parameter(
        True,
        "aruco front end, on images of at least aruco.windowed_min_pixels: detect markers only "
        "in windows around the pixels the tracker predicts for every map marker in view (or "
        "the last solved frame carried at its twist when tracking is off), the full frame on "
        "start, after a failed frame, when a marker found in the last frame is missing and "
        "those found lie off their predicted corners, and every aruco.full_frame_every frames",
        read_only=True,
    ),
    "aruco.windowed_min_pixels": Parameter(
        640 * 480 + 1,
        "with aruco.windowed: the windowed search on images of at least this many pixels "
        "(default: above 640x480, where it halves the detection and finds the same markers; "
        "at 640x480 the windows cover half the frame and cost more than it); 0: every size",
        IntRange(from_value=0, to_value=100_000_000),
        read_only=True,
    ),
    "aruco.window_margin_px": Parameter(
        16.0,
        "px; with aruco.windowed: padding of each predicted marker's bounding box",
        FloatRange(from_value=2.0, to_value=500.0),
        read_only=True,
    ),
    "aruco.full_frame_every": Parameter(
        10,
        "with aruco.windowed: a full-frame detection at least every this many frames (markers "
        "the prediction misplaced; 0: only on the fallbacks)",
        IntRange(from_value=0, to_value=10_000),
        read_only=True,
    ),
    "aruco.detector": Parameter(
        "auto",
        "marker detector: auto (AprilTag families with the AprilTag 3 library when it is "
        "installed, else OpenCV, said at start; ArUco dictionaries with OpenCV), apriltag "
        "(require the library) or opencv (OpenCV's ArUco detector for every dictionary)",
        read_only=True,
    ),
    "aruco.quad_decimate": Parameter(
        0.0,
        "AprilTag: find quads on the image decimated by this factor (1: full resolution, "
        "finds smaller tags, slower; 1.5 or an integer); corners refined and tags decoded at "
        "full resolution; 0: by image size (1.5 up to 640x480, 2 above)",
        FloatRange(from_value=0.0, to_value=8.0),
        read_only=True,
    ),
    "aruco.nthreads": Parameter(
        1,
        "AprilTag: detector threads (more cut the latency; the library before 3.4.3, "
        "pupil_apriltags' and Debian 12's among them, may crash at its first detection with "
        "more than one)",
        IntRange(from_value=1, to_value=64),
        read_only=True,
    ),
    "aruco.quad_sigma": Parameter(
        0.0,
        "AprilTag: px; Gaussian blur (std) before finding quads (0: none; noisy images: 0.8)",
        FloatRange(from_value=0.0, to_value=10.0),
        read_only=True,
    ),
    "aruco.refine_edges": Parameter(
        True, "AprilTag: snap the quad edges to the image gradients", read_only=True
    ),
    "aruco.decode_sharpening": Parameter(
        0.25,
        "AprilTag: sharpening of the decoded samples",
        FloatRange(from_value=0.0, to_value=10.0),
        read_only=True,
    ),
    "aruco.max_hamming": Parameter(
        0,
        "AprilTag: most corrected bits of a kept tag",
        IntRange(from_value=0, to_value=2),
        read_only=True,
    ),
    "aruco.min_decision_margin": Parameter(
        -1.0,
        "AprilTag: smallest decision margin of a kept tag (the library's units; negative: the "
        "binding's default)",
        FloatRange(from_value=-1.0, to_value=10_000.0),
        read_only=True,
    ),
    "aruco.edge_refinement": Parameter(
        False,
        "AprilTag 36h11, 36h10, 25h9, 16h5: refine the library's corners from their edges' "
        "grey-level profiles (closer on clean renders; on real photos the library's corners "
        "fit the tags better: python -m benchmarks.bench_real_markers)",
        read_only=True,
    ),
    "aruco.small_tags": Parameter(
        False,
        "AprilTag, with quad_decimate above 1: detect whole frames by a coarse pass "
        "(quad_decimate 8) and a look at full resolution in windows around the tag-sized dark "
        "blobs it found no tag on (finds tags of 10-160 px the decimation loses: python -m "
        "benchmarks.bench_real_markers --small)",
        read_only=True,
    ),
    "aruco.adaptive_thresh_constant": Parameter(
        20.0,
        "OpenCV: grey levels below the neighbourhood mean that make a marker candidate's dark "
        "(OpenCV's adaptiveThreshConstant; its default 7 makes textured walls candidates)",
        FloatRange(from_value=0.0, to_value=255.0),
        read_only=True,
    ),
    "aruco.adaptive_thresh_win_size_step": Parameter(
        20,
        "OpenCV: px; step of the thresholding windows from 3 to 23 px (OpenCV's "
        "adaptiveThreshWinSizeStep; 20: two passes, 10: three)",
        IntRange(from_value=1, to_value=100),
        read_only=True,
    ),
    "aruco.error_correction_rate": Parameter(
        0.6,
        "OpenCV: share of the dictionary's correctable bits a kept marker may have wrong "
        "(OpenCV's errorCorrectionRate)",
        FloatRange(from_value=0.0, to_value=1.0),
        read_only=True,
    ),
    "features.min_tracked_inliers": Parameter(
        150,
        "with tracking: fewer tracked inliers than this start a refresh detection",
        IntRange(from_value=0, to_value=100_000),
        read_only=True,
    ),
}


#: values of the ``frontend`` parameter
FRONTEND_CHOICES = ("none",) + FRONTENDS
#: values of the ``image_transport`` parameter
IMAGE_TRANSPORTS = ("raw", "compressed")
#: options groups a :attr:`Parameter.field` names -> the prefix its parameter names drop
#: (``estimate``: ``EstimateOptions``, ``tracking``: ``TrackerOptions``, ``imu``:
#: ``GyroSettings``)
OPTION_GROUPS = {"estimate": "", "tracking": "tracking.", "imu": "imu."}


#: parameter-file entries that belong to the node but are not localizer parameters: the
#: visualization (``viz.*``, declared by :mod:`.visualization`), QoS overrides and the
#: process-level ``cameras`` list
OTHER_NODE_PARAMETERS = ("viz.", "qos_overrides.", "cameras", "use_sim_time")

_RANGE_TOL = 1e-6  # relative tolerance at a float range's ends (rclpy's PARAM_REL_TOL)


class ConfigError(ValueError):
    """Parameter values that cannot be used; the message names the parameter."""


def default_values() -> dict[str, Any]:
    """Every parameter at its default value (lists copied)."""
    return {
        k: (list(p.default) if isinstance(p.default, list) else p.default)
        for k, p in PARAMETERS.items()
    }


def check_parameter(name: str, value: Any) -> None:
    """Check one value against its parameter's type and range as ROS does when the node
    declares or sets it (a double parameter does not take an integer; a double-array one
    takes only doubles).

    Raises:
        ConfigError: unknown parameter, wrong type, or outside the declared range.
    """
    if name not in PARAMETERS:
        raise ConfigError(f"unknown parameter {name!r}")
    default, desc, rng = PARAMETERS[name][:3]
    kind = type(default).__name__

    if isinstance(default, list):
        ok = isinstance(value, (list, tuple)) and all(isinstance(x, float) for x in value)
        kind = "list of float"
    elif isinstance(default, (bool, str, float)):
        ok = isinstance(value, type(default))
    else:  # int (a bool is not one here)
        ok = isinstance(value, int) and not isinstance(value, bool)
    if not ok:
        hint = " (write e.g. 0.0, not 0, in YAML)" if "float" in kind else ""
        raise ConfigError(f"parameter {name!r} must be of type {kind}{hint}, got {value!r}")
    if rng is None:
        return
    lo, hi = min(rng.from_value, rng.to_value), max(rng.from_value, rng.to_value)
    if isinstance(rng, FloatRange):
        inside = (
            math.isclose(value, lo, rel_tol=_RANGE_TOL)
            or math.isclose(value, hi, rel_tol=_RANGE_TOL)
            or lo < value < hi
        )
    else:
        inside = lo <= value <= hi and (value in (lo, hi) or (value - lo) % rng.step == 0)
    if not inside:
        raise ConfigError(f"parameter {name!r}: {value!r} is outside [{lo}, {hi}] ({desc})")


def _typed(default: Any, value: Any) -> Any:
    """``value`` as its parameter's type (ROS gives the declared type; a parameter file read by
    :func:`.param_files.read_params_file` is checked by :func:`check_parameter` first)."""
    if isinstance(default, bool):
        return bool(value)
    if isinstance(default, (int, float, str)):
        return type(default)(value)
    return list(value)


def option_fields(group: str, values: Mapping[str, Any]) -> dict[str, Any]:
    """The fields of options group ``group`` that parameters set (:attr:`Parameter.field`),
    as a tree ``{field: value or {subfield: ...}}`` of the values in ``values`` (what
    :func:`rs_localizer.tracking.settings.with_fields` takes).

    Raises:
        KeyError: ``values`` lacks one of the group's parameters.
    """
    tree: dict[str, Any] = {}
    for name, par in PARAMETERS.items():
        if par.field is None or par.field.split(":")[0] != group:
            continue
        _, _, path = par.field.partition(":")
        if not path:
            prefix = OPTION_GROUPS[group]
            path = name[len(prefix) :] if prefix and name.startswith(prefix) else name
        *parents, leaf = path.split(".")
        node = tree
        for k in parents:
            node = node.setdefault(k, {})
        node[leaf] = _typed(par.default, values[name])
    return tree


#: the rig mode's parameters (docs/rig_node.md), declared by every node: with ``rig.cameras``
#: set the node runs a rig (:class:`~rs_localizer.ros.mode.LocalizerMode`) instead of one
#: localizer per camera; every parameter of :data:`PARAMETERS` applies to it too
#: (``ransac.*``, ``tracking.*``, ``rs.*`` as every camera's default timing, ``map_frame``,
#: ``base_frame``, ``publish_tf``, ``time_reset_threshold``, ``diagnostics_period``).
#: ``rig.cameras`` is a string array (its empty default is declared with that type).
RIG_PARAMETERS = {
    "rig.cameras": Parameter(
        [],
        "the rig's camera names: one pose for all of them (topics <camera>/correspondences, "
        "<camera>/image_raw with a frontend, and <camera>/camera_info; each needs "
        "rig.<camera>.mounting); empty: no rig",
        read_only=True,
    ),
    "rig.window": Parameter(
        0.015,
        "s; the frames of one rig frame lie within this of its earliest (reference-row "
        "capture times); stamps further apart are different rig frames",
        FloatRange(from_value=0.0, to_value=1.0),
        read_only=True,
    ),
    "rig.stop_after": Parameter(
        0.5,
        "s of stamp time without a frame of a camera (while the others send) after which the "
        "rig stops waiting for it and runs on the others; at least two of the camera's own "
        "frame intervals",
        FloatRange(from_value=0.001, to_value=3600.0),
        read_only=True,
    ),
}
#: each rig camera's parameters, declared as ``rig.<camera>.<name>`` for every camera of
#: ``rig.cameras`` (``mounting`` has no default: a camera without one stops the node at start)
RIG_CAMERA_PARAMETERS = {
    "mounting": Parameter(
        [],
        "x, y, z (m), qx, qy, qz, qw: the camera optical frame's pose in base_frame (required)",
        read_only=True,
    ),
    "mounting_covariance": Parameter(
        [0.0] * 36,
        "the mounting's uncertainty: 36 numbers, the 6 x 6 covariance row by row over x, y, "
        "z (m) and rotations about base_frame's x, y, z axes (rad) of the camera's pose "
        "(calibrate-rig writes it); added to the rig pose's covariance; all zero: the "
        "mounting is taken as exact",
        read_only=True,
    ),
    "line_delay": Parameter(
        -1.0,
        "s per line of the camera's rolling shutter; negative: rs.line_delay",
        FloatRange(from_value=-1.0, to_value=0.01),
        read_only=True,
    ),
    "readout_time": Parameter(
        -1.0,
        "s per frame (wins over line_delay when > 0); negative: rs.readout_time",
        FloatRange(from_value=-1.0, to_value=1.0),
        read_only=True,
    ),
    "direction": Parameter(
        "", "the camera's readout direction; empty: rs.direction", read_only=True
    ),
    "time_offset": Parameter(
        0.0,
        "s added to the camera's stamps to put its frames on the rig's clock: a driver that "
        "stamps late or early by a constant amount (e.g. the apparent offset the node warns "
        "of for a camera whose frames never join the others')",
        FloatRange(from_value=-1.0, to_value=1.0),
        read_only=True,
    ),
    "time_offset_std": Parameter(
        0.0,
        "s, the standard deviation of the camera's time_offset (calibrate-rig writes it): "
        "each rig frame's pose covariance adds the uncertainty of moving the camera's "
        "observations along that frame's motion by it; 0: the camera's stamps are exact",
        FloatRange(from_value=0.0, to_value=1.0),
        read_only=True,
    ),
}
