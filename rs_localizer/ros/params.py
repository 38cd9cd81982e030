"""The node's parameters and the configuration built from them (no ROS needed).

:data:`PARAMETERS` declares every parameter of ``rs_localizer_node`` (default, description,
range, read-only; ``config/rs_localizer.yaml`` lists them with their defaults). The node, the
managed node and ``rs-localizer replay`` turn a full set of parameter values into a
:class:`LocalizerConfig` with :func:`build_config`, which raises :class:`ConfigError` naming
the parameter when a value cannot be used. Parameter files in the ROS 2 format are read by
:func:`read_params_file` (for replay; the node gets them from ROS).
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..camera import READOUT_DIRECTIONS, CameraModel
from ..estimation import (
    CorrelatedNoise,
    EstimateOptions,
    MotionPrior,
    PlausibilityOptions,
    RansacOptions,
    RefineOptions,
)
from ..estimation.fusion import FusionOptions
from ..estimation.tracker import TrackerOptions
from ..frames import OPTICAL_TO_BODY_QUATERNION, Extrinsic
from ..frontends import FRONTENDS
from ..frontends.shared import SHARED_MAPS
from ..maps import check_regular_file
from ..solvers.registry import SOLVER_NAMES as SOLVERS
from ..solvers.registry import sample_size
from . import conversions as cv

__all__ = [
    "FRONTEND_KINDS",
    "IMAGE_TRANSPORTS",
    "PARAMETERS",
    "ConfigError",
    "FloatRange",
    "ImuConfig",
    "IntRange",
    "LocalizerConfig",
    "build_config",
    "check_parameter",
    "default_values",
    "estimate_options",
    "imu_config",
    "parameter_values",
    "points_needed",
    "read_params_file",
    "tracker_options",
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
        FloatRange(from_value=0.05, to_value=100.0),
        False,
    ),
    "ransac.max_iterations": (
        1000,
        "RANSAC iteration cap",
        IntRange(from_value=1, to_value=1_000_000),
        False,
    ),
    "ransac.confidence": (
        0.9999,
        "RANSAC adaptive-termination confidence",
        FloatRange(from_value=0.5, to_value=0.999999999),
        False,
    ),
    "ransac.min_inliers": (
        12,
        "fewest inliers for a pose",
        IntRange(from_value=3, to_value=100_000),
        False,
    ),
    "ransac.seed": (
        0,
        "RANSAC random seed (deterministic)",
        IntRange(from_value=0, to_value=2_147_483_647),
        False,
    ),
    "refine": (True, "nonlinear refinement on the exact constant-velocity model", None, False),
    "motion_prior.angular_velocity_sigma": (
        3.0,
        "motion prior: sigma of each angular velocity component (rad/s, camera frame); "
        "0 = no prior on it",
        FloatRange(from_value=0.0, to_value=1e4),
        False,
    ),
    "motion_prior.linear_velocity_sigma": (
        1.5,
        "motion prior: sigma of each linear velocity component (m/s, camera frame); "
        "0 = no prior on it (both 0: maximum likelihood, near-degenerate on planar scenes)",
        FloatRange(from_value=0.0, to_value=1e4),
        False,
    ),
    "correlated_noise.sigma_px": (
        0.0,
        "std (px per axis) of a spatially correlated image error (lens-model residue, "
        "corner bias) in the covariance; 0 = white noise only. Fit it on still calibration "
        "views (estimation.noise_model.fit_correlated_noise)",
        FloatRange(from_value=0.0, to_value=100.0),
        False,
    ),
    "correlated_noise.length_px": (
        100.0,
        "correlation length (px) of that error",
        FloatRange(from_value=0.1, to_value=1e5),
        False,
    ),
    "rs.line_delay": (
        3.0e-5,
        "time between consecutive image lines (s/line); 0 = global shutter",
        FloatRange(from_value=0.0, to_value=0.01),
        False,
    ),
    "rs.readout_time": (
        0.0,
        "time to read the whole frame (s); if > 0 it wins over "
        "rs.line_delay (line_delay = readout_time / lines)",
        FloatRange(from_value=0.0, to_value=1.0),
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
        FloatRange(from_value=-1.0, to_value=100_000.0),
        False,
    ),
    "rs.stamp_row": (
        0.0,
        "line (px) whose capture time is the input header.stamp",
        FloatRange(from_value=0.0, to_value=100_000.0),
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
        IntRange(from_value=10, to_value=10_000_000),
        False,
    ),
    "time_reset_threshold": (
        1.0,
        "a frame stamped later than the previous one by more than "
        "this (s) resets the time-dependent state (a gap); any step back "
        "does too. Frames are never dropped for their stamp",
        FloatRange(from_value=0.0, to_value=1e6),
        False,
    ),
    "queue_size": (
        5,
        "frames waiting to be solved; when full, the oldest waiting frame is "
        "dropped (counted in frames_skipped) so that the newest are solved",
        IntRange(from_value=1, to_value=10_000),
        False,
    ),
    "camera_info_wait": (
        0.05,
        "s a frame may wait for its camera_info: when none has arrived "
        "yet, or when camera_info comes with every frame (same stamps) and "
        "the frame's own has not arrived yet",
        FloatRange(from_value=0.0, to_value=5.0),
        False,
    ),
    "max_angular_velocity": (
        20.0,
        "rad/s; a model turning faster is implausible (never published: implausible_motion)",
        FloatRange(from_value=0.01, to_value=1e6),
        False,
    ),
    "max_linear_velocity": (
        50.0,
        "m/s; a model moving faster is implausible",
        FloatRange(from_value=0.01, to_value=1e9),
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
        IntRange(from_value=0, to_value=10),
        False,
    ),
    "tracking.max_gap": (
        0.5,
        "s; a longer gap between frames (or a stamp going back) resets "
        "the track; after this long without frames the pending twists are "
        "published",
        FloatRange(from_value=0.01, to_value=60.0),
        False,
    ),
    "tracking.gate_px": (
        20.0,
        "a point is explained by the prediction within this distance "
        "(px); too few explained points: relocalize",
        FloatRange(from_value=0.5, to_value=1000.0),
        False,
    ),
    "tracking.angular_noise": (
        30.0,
        "filter process noise: angular jerk density (rad/s^3/sqrt(Hz))",
        FloatRange(from_value=1e-3, to_value=1e6),
        False,
    ),
    "tracking.linear_noise": (
        5.0,
        "filter process noise: linear jerk density (m/s^3/sqrt(Hz))",
        FloatRange(from_value=1e-3, to_value=1e6),
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
    "imu.enabled": (
        False,
        "subscribe to imu (sensor_msgs/Imu) and use its gyro in the estimate: the mean "
        "angular velocity over each frame's readout, as a measurement with its covariance",
        None,
        True,
    ),
    "imu.rotation": (
        [0.0, 0.0, 0.0, 1.0],
        "rotation IMU frame -> camera optical frame, quaternion x y z w "
        "(rs-localizer calibrate-readout --imu-topic prints it)",
        None,
        False,
    ),
    "imu.time_offset": (
        0.0,
        "s added to the IMU stamps to put them on the camera's clock",
        FloatRange(from_value=-1.0, to_value=1.0),
        False,
    ),
    "imu.gyro_noise": (
        0.003,
        "standard deviation of one gyro sample (rad/s); averaged over the samples of a readout",
        FloatRange(from_value=1e-6, to_value=10.0),
        False,
    ),
    "imu.gyro_bias": (
        [0.0, 0.0, 0.0],
        "gyro bias subtracted from the rates (rad/s, IMU frame; calibrate-readout "
        "--imu-topic prints it)",
        None,
        False,
    ),
    "imu.gyro_bias_sigma": (
        0.005,
        "uncertainty of imu.gyro_bias per axis (rad/s); with imu.estimate_bias the initial "
        "uncertainty of the estimate, else fixed (it does not average down)",
        FloatRange(from_value=0.0, to_value=10.0),
        False,
    ),
    "imu.estimate_bias": (
        True,
        "estimate the gyro bias online from the rotation between consecutive solved frames, "
        "starting from imu.gyro_bias with imu.gyro_bias_sigma; the frames' gyro uses the "
        "estimate and its uncertainty",
        None,
        True,
    ),
    "imu.bias_random_walk": (
        1e-4,
        "rad/s per sqrt(s): how fast the estimated gyro bias may drift (imu.estimate_bias)",
        FloatRange(from_value=0.0, to_value=1.0),
        False,
    ),
    "imu.wait": (
        0.03,
        "s a frame may wait for the gyro samples covering its readout; then it is solved "
        "without the gyro (gyro_missing.not_covered)",
        FloatRange(from_value=0.0, to_value=1.0),
        False,
    ),
    "imu.buffer": (
        2.0,
        "s of gyro samples kept for frames that arrive late",
        FloatRange(from_value=0.1, to_value=60.0),
        True,
    ),
    "imu.max_rate": (
        35.0,
        "rad/s; a sample with a larger component is the gyro's saturation and rejected",
        FloatRange(from_value=0.1, to_value=1000.0),
        False,
    ),
    "imu.max_gap": (
        0.02,
        "s; a readout whose gyro samples are further apart is solved without the gyro "
        "(gyro_missing.sparse: an IMU topic too slow to describe one readout)",
        FloatRange(from_value=0.001, to_value=1.0),
        False,
    ),
    "diagnostics_period": (
        1.0,
        "period of /diagnostics (s)",
        FloatRange(from_value=0.05, to_value=60.0),
        True,
    ),
    "warmup": (True, "solve a synthetic problem at start (JIT compilation)", None, True),
    "camera.fx": (
        0.0,
        "fallback intrinsics until camera_info arrives; fx <= 0 = wait for camera_info",
        FloatRange(from_value=0.0, to_value=1e6),
        False,
    ),
    "camera.fy": (
        0.0,
        "fallback fy (px)",
        FloatRange(from_value=0.0, to_value=1e6),
        False,
    ),
    "camera.cx": (
        0.0,
        "fallback cx (px)",
        FloatRange(from_value=-1e6, to_value=1e6),
        False,
    ),
    "camera.cy": (
        0.0,
        "fallback cy (px)",
        FloatRange(from_value=-1e6, to_value=1e6),
        False,
    ),
    "camera.width": (
        0,
        "fallback image width (px)",
        IntRange(from_value=0, to_value=100_000),
        False,
    ),
    "camera.height": (
        0,
        "fallback image height (px)",
        IntRange(from_value=0, to_value=100_000),
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
    "features.tracking": (
        True,
        "features front end on video: track the last frame's inliers (optical flow) and match "
        "map points near their predicted pixels; full detection + global matching only to "
        "(re)localize. false: full detection and global matching on every image",
        None,
        True,
    ),
    "features.matcher": (
        "auto",
        "global matching of the features front end: auto (flann for SIFT maps, bf for ORB "
        "maps), bf (exact brute force) or flann (approximate; SIFT maps only)",
        None,
        True,
    ),
    "features.flann_checks": (
        32,
        "leaves FLANN visits per query (more: closer to brute force, slower)",
        IntRange(from_value=1, to_value=4096),
        True,
    ),
    "features.max_features": (
        2000,
        "features detected per image on global and refresh frames",
        IntRange(from_value=10, to_value=100_000),
        True,
    ),
    "features.refresh_frames": (
        10,
        "with tracking: a background detection refreshes the tracks every this many frames "
        "(0: only when they run low)",
        IntRange(from_value=0, to_value=10_000),
        True,
    ),
    "features.search_radius_px": (
        8.0,
        "px; guided matching window around each map point's predicted pixel",
        FloatRange(from_value=1.0, to_value=200.0),
        True,
    ),
    "features.min_tracked_inliers": (
        150,
        "with tracking: fewer tracked inliers than this start a refresh detection",
        IntRange(from_value=0, to_value=100_000),
        True,
    ),
}

#: values of the ``frontend`` parameter
FRONTEND_KINDS = ("none",) + FRONTENDS
#: values of the ``image_transport`` parameter
IMAGE_TRANSPORTS = ("raw", "compressed")


#: parameter-file entries that belong to the node but are not localizer parameters: the
#: visualization (``viz.*``, declared by :mod:`.visualization`), QoS overrides and the
#: process-level ``cameras`` list
OTHER_NODE_PARAMETERS = ("viz.", "qos_overrides.", "cameras", "use_sim_time")

_RANGE_TOL = 1e-6  # relative tolerance at a float range's ends (rclpy's PARAM_REL_TOL)


class ConfigError(ValueError):
    """Parameter values that cannot be used; the message names the parameter."""


def default_values() -> dict[str, Any]:
    """Every parameter at its default value (lists copied)."""
    return {k: (list(v[0]) if isinstance(v[0], list) else v[0]) for k, v in PARAMETERS.items()}


def check_parameter(name: str, value: Any) -> None:
    """Check one value against its parameter's type and range as ROS does when the node
    declares or sets it (a double parameter does not take an integer; a double-array one
    takes only doubles).

    Raises:
        ConfigError: unknown parameter, wrong type, or outside the declared range.
    """
    if name not in PARAMETERS:
        raise ConfigError(f"unknown parameter {name!r}")
    default, desc, rng, _ = PARAMETERS[name]
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


def _flatten(tree: Mapping, prefix: str = "") -> dict[str, Any]:
    out = {}
    for k, v in tree.items():
        name = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(_flatten(v, name + "."))
        else:
            out[name] = v
    return out


def _section_applies(section: str, node_name: str) -> bool:
    """Whether a parameter-file section applies to a node named ``node_name`` outside any
    namespace: the wildcards (``/**``, ``/*``) and the node's own name (``rs_localizer``,
    ``/rs_localizer``, ``/**/rs_localizer``)."""
    s = str(section).strip()
    return s in ("/**", "**", "/*", "*") or s.lstrip("/") in (node_name, f"**/{node_name}")


def read_params_file(path: str | os.PathLike, node_name: str = "rs_localizer") -> dict[str, Any]:
    """The parameters a ROS 2 parameter file gives a node named ``node_name`` (no namespace):
    its sections ``/**`` and ``rs_localizer`` (also ``/rs_localizer``, ``/**/rs_localizer``) in
    file order, each ``ros__parameters`` tree flattened to dotted names (``ransac:
    {seed: 3}`` -> ``ransac.seed``). Sections of other nodes or namespaces
    (``/camera/rs_localizer``) are not read. Values are as YAML parses them (checked later,
    against :data:`PARAMETERS`, by :func:`check_parameter`).

    Raises:
        ConfigError: the file is not a ROS 2 parameter file (YAML mapping of node name ->
            ``ros__parameters`` mapping). OSError: the file cannot be read.
    """
    import yaml

    try:
        tree = yaml.safe_load(Path(path).read_text())
    except yaml.YAMLError as e:
        raise ConfigError(f"{path}: not YAML: {e}") from None
    if not isinstance(tree, Mapping):
        raise ConfigError(f"{path}: not a ROS 2 parameter file (node name: ros__parameters: ...)")
    out: dict[str, Any] = {}
    for section, body in tree.items():
        if not isinstance(body, Mapping) or not isinstance(body.get("ros__parameters"), Mapping):
            raise ConfigError(f"{path}: section {section!r} has no ros__parameters mapping")
        if _section_applies(section, node_name):
            out.update(_flatten(body["ros__parameters"]))
    return out


def estimate_options(values: Mapping[str, Any]) -> EstimateOptions:
    """The estimator options of the parameters ``ransac.*``, ``refine``, ``motion_prior.*``,
    ``max_angular_velocity``, ``max_linear_velocity`` and ``correlated_noise.*`` (every other
    option at its default).

    Raises:
        TypeError, ValueError: from :class:`EstimateOptions` (e.g. a confidence outside (0, 1)).
    """
    return EstimateOptions(
        ransac=RansacOptions(
            threshold_px=float(values["ransac.threshold_px"]),
            max_iterations=int(values["ransac.max_iterations"]),
            confidence=float(values["ransac.confidence"]),
            min_inliers=int(values["ransac.min_inliers"]),
            seed=int(values["ransac.seed"]),
        ),
        refine=RefineOptions(enabled=bool(values["refine"])),
        motion_prior=MotionPrior(
            float(values["motion_prior.angular_velocity_sigma"]),
            float(values["motion_prior.linear_velocity_sigma"]),
        ),
        plausibility=PlausibilityOptions(
            max_angular_velocity=float(values["max_angular_velocity"]),
            max_linear_velocity=float(values["max_linear_velocity"]),
        ),
        correlated_noise=CorrelatedNoise(
            sigma_px=float(values["correlated_noise.sigma_px"]),
            length_px=float(values["correlated_noise.length_px"]),
        ),
    )


def points_needed(solver: str, options: EstimateOptions) -> int:
    """Fewest correspondences a pose needs: the estimator's ``min_inliers`` and one more than
    the solver's minimal sample."""
    return max(options.ransac.min_inliers, sample_size(solver) + 1)


def tracker_options(values: Mapping[str, Any]) -> TrackerOptions | None:
    """The video tracker's options of the ``tracking.*`` parameters; None when
    ``tracking.enabled`` is false (every frame alone).

    Raises:
        TypeError, ValueError: from :class:`TrackerOptions` / :class:`FusionOptions`.
    """
    if not bool(values["tracking.enabled"]):
        return None
    return TrackerOptions(
        gate_px=float(values["tracking.gate_px"]),
        max_gap=float(values["tracking.max_gap"]),
        prior_from_prediction=str(values["tracking.prior_from_prediction"]),
        fusion=FusionOptions(
            lag=int(values["tracking.lag"]),
            angular_noise=float(values["tracking.angular_noise"]),
            linear_noise=float(values["tracking.linear_noise"]),
        ),
    )


@dataclass(frozen=True)
class ImuConfig:
    """The gyro's use in the estimate (the ``imu.*`` parameters).

    Attributes:
        R_cam_imu: (3, 3) rotation IMU -> camera optical frame. time_offset: s added to the
            IMU stamps. gyro_noise, gyro_bias_sigma: rad/s. gyro_bias: (3,) rad/s, IMU frame.
        estimate_bias: estimate the bias online (initial value ``gyro_bias``, standard
            deviation ``gyro_bias_sigma``). bias_random_walk: rad/s per sqrt(s).
        wait: s a frame waits for its samples. buffer: s kept. max_rate: rad/s saturation.
        max_gap: s between samples beyond which a readout is ``sparse``.
    """

    R_cam_imu: np.ndarray
    time_offset: float
    gyro_noise: float
    gyro_bias: np.ndarray
    gyro_bias_sigma: float
    wait: float
    buffer: float
    max_rate: float
    max_gap: float
    estimate_bias: bool = False
    bias_random_walk: float = 1e-4


def imu_config(values: Mapping[str, Any]) -> ImuConfig | None:
    """The :class:`ImuConfig` of the ``imu.*`` parameters; None when ``imu.enabled`` is false.

    Raises:
        ValueError: ``imu.rotation`` not a quaternion (4 finite numbers of norm near 1),
            ``imu.gyro_bias`` not 3 finite numbers.
    """
    if not bool(values["imu.enabled"]):
        return None
    R = Extrinsic.from_translation_quaternion([0.0, 0.0, 0.0], values["imu.rotation"]).rotation
    bias = np.asarray(values["imu.gyro_bias"], dtype=float).reshape(-1)
    if bias.shape != (3,) or not np.isfinite(bias).all():
        raise ValueError(f"imu.gyro_bias must be 3 finite numbers (rad/s), got {bias.tolist()}")
    return ImuConfig(
        R_cam_imu=R,
        time_offset=float(values["imu.time_offset"]),
        gyro_noise=float(values["imu.gyro_noise"]),
        gyro_bias=bias,
        gyro_bias_sigma=float(values["imu.gyro_bias_sigma"]),
        wait=float(values["imu.wait"]),
        buffer=float(values["imu.buffer"]),
        max_rate=float(values["imu.max_rate"]),
        max_gap=float(values["imu.max_gap"]),
        estimate_bias=bool(values["imu.estimate_bias"]),
        bias_random_walk=float(values["imu.bias_random_walk"]),
    )


@dataclass(frozen=True, eq=False)
class LocalizerConfig:
    """Everything the localizer derives from its parameters (see :data:`PARAMETERS` for the
    meaning of each; built by :func:`build_config`).

    Attributes:
        solver: minimal solver name. options: the estimator's options.
        tracking: the video tracker's options, None = every frame alone.
        imu: the gyro's use (:class:`ImuConfig`), None = no gyro.
        line_delay (s/line), readout_time (s, > 0 wins), direction, reference_row (px, None =
            image centre), stamp_row (px): the rolling-shutter timing of every camera model.
        map_frame, camera_frame ("" = the input's frame id), base_frame ("" = none) and
            extrinsic (the base_frame -> camera mounting, None without base_frame).
        max_points: the cap on a frame's rows. time_reset_ns: a forward stamp jump larger
            than this (ns) resets the time-dependent state. queue_size: frames waiting.
        camera_info_wait: s a frame may wait for its camera_info.
        fallback: the camera model of the ``camera.*`` parameters (None: camera.fx <= 0).
        landmarks_file and landmarks: ``(sorted ids (N,), points (N, 3) m)`` or None.
        frontend_kind (``none``, ``aruco``, ...), frontend_map, frontend: the image front end
            object (None for ``none``), image_transport (``raw``/``compressed``),
            republish_correspondences.
    """

    solver: str
    options: EstimateOptions
    tracking: TrackerOptions | None
    line_delay: float
    readout_time: float
    direction: str
    reference_row: float | None
    stamp_row: float
    map_frame: str
    camera_frame: str
    base_frame: str
    extrinsic: Extrinsic | None
    max_points: int
    time_reset_ns: int
    queue_size: int
    camera_info_wait: float
    fallback: CameraModel | None
    landmarks_file: str
    landmarks: tuple[np.ndarray, np.ndarray] | None
    frontend_kind: str
    frontend_map: str
    frontend: Any
    image_transport: str
    republish_correspondences: bool
    imu: ImuConfig | None = None

    @property
    def min_points(self) -> int:
        """Fewest correspondences a pose needs (:func:`points_needed`)."""
        return points_needed(self.solver, self.options)

    def camera_with_timing(self, camera: CameraModel) -> CameraModel:
        """``camera``'s intrinsics with this configuration's rolling-shutter timing.

        Raises:
            ValueError: timing the camera model rejects.
        """
        return cv.camera_model(
            camera.K,
            camera.D,
            camera.width,
            camera.height,
            camera.distortion_model,
            self.line_delay,
            self.readout_time,
            self.direction,
            self.reference_row,
        )

    def camera_from_info(self, msg: Any) -> CameraModel:
        """The camera model of a ``sensor_msgs/CameraInfo`` (rclpy or rosbags) with this
        configuration's timing.

        Raises:
            CameraInfoError (a ValueError): see :func:`.conversions.camera_model_from_camera_info`.
        """
        return cv.camera_model_from_camera_info(
            msg, self.line_delay, self.readout_time, self.direction, self.reference_row
        )


def _frontend_options(kind: str, p) -> dict:
    """Keyword arguments of the front end ``kind`` from the ``features.*`` parameters."""
    if kind != "features":
        return {}
    matcher = str(p["features.matcher"]).strip().lower()
    if matcher not in ("auto", "bf", "flann"):
        raise ConfigError(
            f"unknown features.matcher {p['features.matcher']!r}; expected auto, bf or flann"
        )
    return {
        "tracking": bool(p["features.tracking"]),
        "matcher": None if matcher == "auto" else matcher,
        "flann_checks": int(p["features.flann_checks"]),
        "n_features": int(p["features.max_features"]),
        "refresh_frames": int(p["features.refresh_frames"]),
        "search_radius_px": float(p["features.search_radius_px"]),
        "min_tracked_inliers": int(p["features.min_tracked_inliers"]),
    }


def _frontend_needs(kind: str) -> str:
    if kind == "aruco":
        return "marker map YAML, scene YAML or aruco_room)"
    if kind == "board":
        return "board YAML)"
    return "feature map .npz)"


def build_config(
    values: Mapping[str, Any],
    *,
    owner: object | None = None,
    current: LocalizerConfig | None = None,
) -> LocalizerConfig:
    """The configuration of a full set of parameter values (one per :data:`PARAMETERS` name).

    Loads the landmark table (``landmarks_file``) and the front end's map (``frontend_map``)
    through :data:`~rs_localizer.frontends.shared.SHARED_MAPS` on behalf of ``owner`` (one
    copy per process, released with ``SHARED_MAPS.release(owner)``); the front end of
    ``current`` is reused when its kind and map are unchanged. Types and ranges are not checked
    here (ROS does it for the node, :func:`check_parameter` for replay).

    Raises:
        ConfigError: the first unusable value, with a message naming the parameter (unknown
            solver, direction, front end or transport; estimator or tracking options their
            classes reject; ``max_points`` below what a pose needs; non-finite or invalid
            fallback intrinsics; rolling-shutter timing; ``camera_to_base``; a landmark or
            front-end map that does not load).
    """
    p = values
    if p["solver"] not in SOLVERS:
        raise ConfigError(f"unknown solver {p['solver']!r}; expected one of {list(SOLVERS)}")
    if p["rs.direction"] not in READOUT_DIRECTIONS:
        raise ConfigError(
            f"unknown rs.direction {p['rs.direction']!r}; expected one of "
            f"{list(READOUT_DIRECTIONS)}"
        )
    try:
        opts = estimate_options(p)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"invalid RANSAC options: {e}") from None
    need = points_needed(p["solver"], opts)
    if int(p["max_points"]) < need:
        raise ConfigError(
            f"max_points {p['max_points']} is below the {need} points a pose needs "
            f"(ransac.min_inliers {int(p['ransac.min_inliers'])}, solver {p['solver']}): every "
            "frame would fail"
        )
    ref = float(p["rs.reference_row"])
    try:
        tracking = tracker_options(p)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"invalid tracking parameters: {e}") from None
    try:
        imu = imu_config(p)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"invalid imu parameters: {e}") from None
    line_delay, readout_time = float(p["rs.line_delay"]), float(p["rs.readout_time"])
    direction, reference_row = p["rs.direction"], (None if ref < 0 else ref)
    if not all(
        math.isfinite(float(p[k])) for k in ("camera.fx", "camera.fy", "camera.cx", "camera.cy")
    ):
        raise ConfigError("invalid fallback camera parameters: camera.fx/fy/cx/cy must be finite")
    d = p["camera.d"] if p["camera.d"] is not None else []
    if not all(math.isfinite(float(x)) for x in d):
        raise ConfigError(
            f"invalid fallback camera parameters: camera.d must be finite, got {list(d)}"
        )
    fallback = None
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
            fallback = cv.camera_model(
                K,
                list(d),
                p["camera.width"],
                p["camera.height"],
                p["camera.distortion_model"],
                line_delay,
                readout_time,
                direction,
                reference_row,
            )
        except ValueError as e:
            raise ConfigError(f"invalid fallback camera parameters: {e}") from None
    try:
        cv.camera_model(
            np.eye(3), [], 10, 10, "plumb_bob", line_delay, readout_time, direction, reference_row
        )
    except ValueError as e:
        raise ConfigError(f"invalid rolling-shutter parameters: {e}") from None
    base_frame, extrinsic = str(p["base_frame"]).strip(), None
    if base_frame:
        try:
            extrinsic = Extrinsic.from_translation_quaternion(
                p["camera_to_base.translation"], p["camera_to_base.rotation"]
            )
        except ValueError as e:
            raise ConfigError(f"invalid camera_to_base: {e}") from None
    path = p["landmarks_file"]
    landmarks = None
    if path:
        try:  # (loaded once per process: cameras naming the same file share it)
            landmarks = SHARED_MAPS.landmarks(path, owner=owner)
        except (OSError, ValueError) as e:
            raise ConfigError(f"cannot load landmarks_file {path!r}: {e}") from None
    kind, fmap = str(p["frontend"]).strip().lower(), str(p["frontend_map"])
    if kind not in FRONTEND_KINDS:
        raise ConfigError(
            f"unknown frontend {p['frontend']!r}; expected one of {list(FRONTEND_KINDS)}"
        )
    transport = str(p["image_transport"]).strip().lower()
    if transport not in IMAGE_TRANSPORTS:
        raise ConfigError(
            f"unknown image_transport {p['image_transport']!r}; expected one of "
            f"{list(IMAGE_TRANSPORTS)}"
        )
    frontend = None
    if kind != "none":
        if not fmap:
            raise ConfigError(f"frontend {kind} needs frontend_map (" + _frontend_needs(kind))
        if current is not None and (kind, fmap) == (current.frontend_kind, current.frontend_map):
            frontend = current.frontend
        else:
            try:
                if os.path.lexists(os.path.expanduser(fmap)):  # (not a built-in name)
                    check_regular_file(os.path.expanduser(fmap))  # a FIFO would block
                # (the map is loaded once per process and shared by cameras naming it)
                frontend = SHARED_MAPS.frontend(
                    kind, os.path.expanduser(fmap), owner=owner, **_frontend_options(kind, p)
                )
            except Exception as e:
                raise ConfigError(
                    f"cannot load frontend_map {fmap!r} ({kind}): {type(e).__name__}: {e}"
                ) from None
    return LocalizerConfig(
        solver=p["solver"],
        options=opts,
        tracking=tracking,
        line_delay=line_delay,
        readout_time=readout_time,
        direction=direction,
        reference_row=reference_row,
        stamp_row=float(p["rs.stamp_row"]),
        map_frame=p["map_frame"],
        camera_frame=p["camera_frame"],
        base_frame=base_frame,
        extrinsic=extrinsic,
        max_points=int(p["max_points"]),
        time_reset_ns=int(float(p["time_reset_threshold"]) * 1e9),
        queue_size=int(p["queue_size"]),
        camera_info_wait=float(p["camera_info_wait"]),
        fallback=fallback,
        landmarks_file=p["landmarks_file"],
        landmarks=landmarks,
        frontend_kind=kind,
        frontend_map=fmap,
        frontend=frontend,
        image_transport=transport,
        republish_correspondences=bool(p["republish_correspondences"]),
        imu=imu,
    )


def parameter_values(
    files: Iterable[str | os.PathLike] = (), overrides: Mapping[str, Any] | None = None
) -> tuple[dict[str, Any], list[str]]:
    """Every parameter's value from its default, then each parameter file in order
    (:func:`read_params_file`), then ``overrides``, each value checked
    (:func:`check_parameter`). Returns ``(values, ignored)``: ``ignored`` lists file entries
    that are not localizer parameters (``viz.*``, ``qos_overrides.*`` and ``cameras`` belong
    to the node but not to the estimation; other names are unknown to the node, which ignores
    them too).

    Raises:
        ConfigError: a file that is not a parameter file, an unknown override, or a value of
            the wrong type or outside its range. OSError: a file cannot be read.
    """
    values = default_values()
    ignored = []
    for f in files:
        for name, value in read_params_file(f).items():
            if name not in PARAMETERS:
                if not name.startswith(OTHER_NODE_PARAMETERS):
                    ignored.append(name)
                continue
            check_parameter(name, value)
            values[name] = value
    for name, value in (overrides or {}).items():
        check_parameter(name, value)
        values[name] = value
    return values, ignored
