"""Robust estimation of the rolling-shutter pose (the layer above the minimal solvers).

* :mod:`.estimate`: the entry point :func:`estimate_rs_pose` (LO-RANSAC: sampling, P3P
  pre-rotation, the RS minimal solver, preemptive MSAC scoring, local optimization, the final
  exact-model refinement) with :class:`EstimateOptions` and :class:`RSPoseEstimate`;
* :mod:`.sampling`: sample drawing, pre-rotation and gathering kernels;
* :mod:`.scoring`: MSAC scoring kernels on the RS model;
* :mod:`.refine`: Levenberg-Marquardt on the exact constant-velocity model (eq. 4) and its
  covariance;
* :mod:`.prior`: the motion prior (:class:`MotionPrior`) of the MAP estimate.
* :mod:`.noise_model`: spatially correlated image error in the covariance (its fit on still
  calibration views).
"""

from .estimate import EstimateOptions, RSPoseEstimate, estimate_rs_pose, physical_velocities
from .points import cap_points
from .prior import MotionPrior
from .refine import exact_errors, refine_rs_pose

__all__ = [
    "EstimateOptions",
    "MotionPrior",
    "RSPoseEstimate",
    "cap_points",
    "estimate_rs_pose",
    "exact_errors",
    "physical_velocities",
    "refine_rs_pose",
]
