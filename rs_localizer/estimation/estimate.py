"""Robust rolling-shutter pose estimation: the entry point :func:`estimate_rs_pose` (in the
spirit of PoseLib's ``estimate_absolute_pose``).

It runs three stages, one module each:

1. prepare (:mod:`.frame`): validate, undistort and normalize the correspondences; check that
   they can fix a pose; planarity, timing, velocity bounds, motion prior;
2. RANSAC (:mod:`.ransac`, :mod:`.hypotheses`, :mod:`.local_optimization`): LO-RANSAC over
   P3P-pre-rotated minimal samples (or samples pre-rotated by an initial model), the batched
   RS solver, preemptive MSAC scoring, local optimization of every new best;
3. finalize (:mod:`.finalize`): the refinement on the exact constant-velocity model with its
   covariance, the last checks, the outputs (:mod:`.result`).

A stage that finds the frame gives no pose raises :class:`~.result.EstimationFailed`; the
estimator turns it into a failed :class:`RSPoseEstimate` in one place.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from ..camera import CameraModel
from ..solvers.registry import SOLVER_NAMES, sample_size, solver_info
from .finalize import final_estimate, refine_final_model
from .frame import configure_frame, prepare_frame
from .gyro import GYRO_CHI2_THRESHOLD, GyroMeasurement, gyro_consistency, gyro_prior
from .options import (
    CorrelatedNoise,
    EstimateOptions,
    InitialModel,
    LocalOptimizationOptions,
    PlausibilityOptions,
    RansacOptions,
    RefineOptions,
)
from .prior import MotionPrior
from .ransac import Ransac, prosac_order, seeded_rng
from .result import EstimationFailed, RSPoseEstimate, failed_estimate, physical_velocities

__all__ = [
    "SOLVERS",
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
    "estimate_rs_pose",
    "physical_velocities",
    "points_needed",
    "sample_size",
]

#: solver names (:data:`rs_localizer.solvers.registry.SOLVERS` holds what is known of each)
SOLVERS = SOLVER_NAMES


def estimate_rs_pose(
    points2d_px: np.ndarray,
    points3d: np.ndarray,
    camera: CameraModel,
    solver: str = "r6p_1lin",
    options: EstimateOptions | None = None,
    scores: np.ndarray | None = None,
    *,
    initial_model: InitialModel | None = None,
    gyro: GyroMeasurement | None = None,
) -> RSPoseEstimate:
    """Robust rolling-shutter absolute pose from 2D-3D correspondences.

    Pipeline: validate and normalize (OpenCV undistortion; RS time from the measured, distorted
    line) -> RANSAC over minimal samples (P3P pre-rotation per sample, batched RS solver,
    preemptive MSAC score on the reprojection error of the exact constant-velocity model at
    each point's measured capture time, adaptive termination, PROSAC-style ordering when
    ``scores`` are given; one numba call per batch, :mod:`.batch`) -> local optimization (the
    RS solver on all inliers) -> robust refinement on the exact model (paper eq. 4; truncated
    Huber loss on all points within ``FINAL_CUTOFF`` thresholds) with covariance.

    Args:
        points2d_px: (N, 2) measured (distorted) pixel coordinates.
        points3d: (N, 3) world (map) points in metres.
        camera: :class:`~rs_localizer.camera.CameraModel` (intrinsics, distortion, RS timing).
        solver: one of :data:`SOLVERS`; ``p3p`` is the global-shutter baseline (w = t = 0).
        options: :class:`EstimateOptions` (default ``EstimateOptions()``).
        scores: optional (N,) match quality, higher is better (PROSAC-style sample ordering).
        initial_model: optional :class:`InitialModel` (a prediction, e.g. from the previous
            frames of a video): tested first; if it explains enough points it seeds RANSAC and
            its rotation replaces P3P as the samples' pre-rotation. Without it the estimator is
            unchanged.
        gyro: optional :class:`~rs_localizer.estimation.gyro.GyroMeasurement` of this
            frame's readout (camera optical frame): RANSAC solves its minimal samples with
            the angular velocity known (R5P_{v,C,t}^{w}, 5 points,
            :func:`~rs_localizer.solvers.r5p_w.r5p_w_batch`), so every hypothesis carries
            the gyro's angular velocity; it is added to the motion prior
            (:func:`~rs_localizer.estimation.gyro.gyro_prior`), so local optimization and the
            final refinement are maximum a posteriori with it on every frame, and on planar
            frames the hypotheses' damped solves use it too; the covariance includes it. If
            the image disagrees with it (:func:`~rs_localizer.estimation.gyro.gyro_consistency`
            above :data:`~rs_localizer.estimation.gyro.GYRO_CHI2_THRESHOLD`) or the aided
            estimate fails where an unaided one succeeds, the frame is solved again without
            it and ``gyro_rejected`` is set. Ignored by the global-shutter ``p3p``.
    Returns:
        :class:`RSPoseEstimate`. Data problems (NaN rows, too few points, all outliers,
        degenerate geometry) give ``success=False`` with a ``failure`` reason
        (:data:`~.result.FAILURE_REASONS`), never an exception or a NaN pose. Rows that fail
        validation are counted in ``num_dropped``.
    Raises:
        ValueError: unknown solver name, or arrays that are not (N, 2) / (N, 3) / (N,).
    """
    if solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}; expected one of {SOLVERS}")
    opts = options or EstimateOptions()
    args = (points2d_px, points3d, camera, solver)
    if gyro is None or camera.line_delay <= 0 or not solver_info(solver).rolling:
        return _estimate(*args, opts, scores, initial_model)
    aided = replace(opts, motion_prior=gyro_prior(gyro, opts.motion_prior))
    est = _estimate(*args, aided, scores, initial_model, gyro)
    if est.success and est.twist_covariance is not None:
        chi2 = gyro_consistency(gyro, est.angular_velocity, est.twist_covariance[3:, 3:])
        if chi2 <= GYRO_CHI2_THRESHOLD:
            return replace(est, gyro_used=True)
    unaided = _estimate(*args, opts, scores, initial_model)
    if est.success or unaided.success:
        return replace(unaided, gyro_rejected=True)
    return unaided


def points_needed(solver: str, options: EstimateOptions) -> int:
    """Fewest correspondences (and inliers) a pose of ``solver`` needs: the options'
    ``ransac.min_inliers``, and at least one more than the solver's minimal sample (a model
    fitted to exactly its sample has no redundancy to check it). The node refuses a
    ``max_points`` below this."""
    return max(options.ransac.min_inliers, sample_size(solver) + 1)


def _estimate(
    points2d_px: np.ndarray,
    points3d: np.ndarray,
    camera: CameraModel,
    solver: str,
    opts: EstimateOptions,
    scores: np.ndarray | None,
    initial_model: InitialModel | None,
    gyro: GyroMeasurement | None = None,
) -> RSPoseEstimate:
    """:func:`estimate_rs_pose` with one set of options (the motion prior possibly including
    a gyro); with ``gyro`` RANSAC solves its samples with the gyro's angular velocity."""
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    rng = seeded_rng(opts.ransac.seed)
    fr = prepare_frame(points2d_px, points3d, camera, opts.plausibility.max_point_norm, rng)
    if gyro is not None:  # (the model's w per unit r: omega = -w / s)
        fr.known_w = -camera.seconds_per_unit_r * gyro.angular_velocity
    search = Ransac(fr, solver, opts, rng, prosac_order(fr, scores), scores is not None)
    min_inliers = points_needed(solver, opts)
    try:
        try:
            configure_frame(
                fr,
                camera,
                solver,
                opts.ransac.min_inliers,
                opts.ransac.threshold_px,
                (opts.plausibility.max_angular_velocity, opts.plausibility.max_linear_velocity),
                opts.motion_prior,
            )
        finally:
            timings["prepare"] = time.perf_counter() - t_start
        search.run(initial_model)
        timings.update(search.timings)
        model = search.result(min_inliers, opts.ransac.threshold_px)
        t0 = time.perf_counter()
        final = refine_final_model(fr, camera, solver, opts, model, search.inliers, min_inliers)
        timings["refine"] = time.perf_counter() - t0
        initial = (search.explained, search.anchor is not None)
        est = final_estimate(
            fr,
            solver,
            final,
            search.iterations,
            initial,
            timings,
            opts.plausibility.consistent_fit,
        )
    except EstimationFailed as failure:
        return failed_estimate(
            failure.reason, solver, fr.num_rows, len(fr.x), search.iterations, timings
        )
    timings["total"] = time.perf_counter() - t_start
    return est
