"""Robust estimation of the rolling-shutter pose (the layer above the minimal solvers).

* :mod:`.estimate`: the entry point :func:`estimate_rs_pose`, three stages: :mod:`.frame`
  (prepare), :mod:`.ransac` with :mod:`.hypotheses` and :mod:`.local_optimization`
  (LO-RANSAC: P3P pre-rotation, the RS minimal solver, preemptive MSAC scoring, local
  optimization), :mod:`.finalize` (the exact-model refinement, checks, outputs);
* :mod:`.options`: :class:`EstimateOptions` grouped by concern, :class:`InitialModel`;
  :mod:`.result`: :class:`RSPoseEstimate` and its failure reasons;
* :mod:`.sampling`: sample drawing, pre-rotation and gathering kernels;
* :mod:`.scoring`: MSAC scoring kernels on the RS model;
* :mod:`.refine`: Levenberg-Marquardt on the exact constant-velocity model (eq. 4) and its
  covariance;
* :mod:`.prior`: the motion prior (:class:`MotionPrior`) of the MAP estimate;
  :mod:`.gyro`: a gyro's angular velocity over the readout as a measurement
  (:class:`GyroMeasurement`; made from a video's samples by
  :func:`rs_localizer.tracking.gyro.gyro_measurement`).
* :mod:`.noise_model`: spatially correlated image error in the covariance (its fit on still
  calibration views).
"""

from .estimate import estimate_rs_pose
from .gyro import GyroMeasurement
from .options import (
    CorrelatedNoise,
    EstimateOptions,
    InitialModel,
    LocalOptimizationOptions,
    PlausibilityOptions,
    RansacOptions,
    RefineOptions,
)
from .points import cap_points
from .prior import MotionPrior
from .refine import RefineSettings, exact_errors, refine_rs_pose
from .result import FAILURE_REASONS, RSPoseEstimate, physical_velocities

__all__ = [
    "FAILURE_REASONS",
    "CorrelatedNoise",
    "EstimateOptions",
    "GyroMeasurement",
    "InitialModel",
    "LocalOptimizationOptions",
    "MotionPrior",
    "PlausibilityOptions",
    "RSPoseEstimate",
    "RansacOptions",
    "RefineOptions",
    "RefineSettings",
    "cap_points",
    "estimate_rs_pose",
    "exact_errors",
    "physical_velocities",
    "refine_rs_pose",
]
