"""rs_localizer: rolling-shutter absolute pose estimation for ROS 2.

The solvers follow Kukelova, Albl, Sugimoto, Pajdla, "Linear solution to the minimal absolute
pose rolling shutter problem", ACCV 2018 (arXiv:1812.11532), and Albl, Kukelova, Pajdla,
"R6P - Rolling shutter absolute pose problem", CVPR 2015.

Only ``rs_localizer.ros`` imports rclpy; everything else is plain NumPy/SciPy/OpenCV.

    from rs_localizer import CameraModel, EstimateOptions, estimate_rs_pose

A video (tracking, gyro, gyro bias): :class:`~rs_localizer.tracking.sequence.SequenceLocalizer`.

Layers (imports point down only): the model (:mod:`.geometry`, :mod:`.camera`, :mod:`.maps`,
:mod:`.accuracy`, :mod:`.pose`, :mod:`.correspondences`) <- :mod:`.solvers` <-
:mod:`.estimation` <- :mod:`.runtime` <- :mod:`.tracking` <- :mod:`.frontends` <- :mod:`.ros`;
:mod:`.sim` produces data; :mod:`.experiments` (the paper's synthetic experiments) and
:mod:`.cli` compose everything. The benchmarks are outside the package (``benchmarks/`` of a
checkout).
"""

# numba's cache directory must be chosen before anything imports numba (jit_cache docstring)
from .runtime import jit_cache as _jit_cache

_jit_cache.configure()

from .camera import CameraModel
from .correspondences import Correspondences, Frontend
from .estimation import (
    CorrelatedNoise,
    EstimateOptions,
    InitialModel,
    LocalOptimizationOptions,
    MotionPrior,
    PlausibilityOptions,
    RansacOptions,
    RefineOptions,
    RSPoseEstimate,
    estimate_rs_pose,
)
from .pose import PoseWithCovariance, RSModel, RSPose
from .tracking import CameraFrame, GyroSettings, SequenceLocalizer, SequenceSettings

__version__ = "0.1.0"

__all__ = [
    "CameraFrame",
    "CameraModel",
    "CorrelatedNoise",
    "Correspondences",
    "EstimateOptions",
    "Frontend",
    "GyroSettings",
    "InitialModel",
    "LocalOptimizationOptions",
    "MotionPrior",
    "PlausibilityOptions",
    "PoseWithCovariance",
    "RSModel",
    "RSPose",
    "RSPoseEstimate",
    "RansacOptions",
    "RefineOptions",
    "SequenceLocalizer",
    "SequenceSettings",
    "__version__",
    "estimate_rs_pose",
]
