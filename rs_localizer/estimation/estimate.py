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

A frame of too few points for its solver but four or more coplanar ones (one square marker's
corners) or six or more on more than one plane (a few markers' corners), or of exactly four
coplanar ones, skips RANSAC: :mod:`.single_tag` poses it from them alone.

The stages run in :func:`~.driver.staged_estimate`, the one staged estimator of a camera's
frame and of a rig frame's cameras (:func:`~.rig.estimate_rig_pose`), here on the camera's
stages (:class:`_CameraStages`). A stage that finds the frame gives no pose raises
:class:`~.result.EstimationFailed`; the driver turns it into a failed :class:`RSPoseEstimate`
in one place.

The same stages run with their compiled steps in NumPy and SciPy (:mod:`.numpy_impl`) when
the ``implementation`` argument selects it (:mod:`.implementation`); every estimate records
which ran.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from ..camera import CameraModel
from ..pose import RSModel
from ..solvers.registry import SOLVER_NAMES, sample_size, solver_info
from .degeneracy import PLANAR_TOLERANCE
from .driver import checked_inputs, gyro_checked_estimate, staged_estimate
from .finalize import (
    STILL_FALLBACK,
    FinalModel,
    ImageAlone,
    final_estimate,
    image_alone,
    prior_at_rest,
    refine_final_model,
    still_fallback,
    still_final,
    unobserved_twist,
)
from .frame import Model, configure_frame, prepare_frame
from .gyro import GyroMeasurement, gyro_prior
from .implementation import COMPILED, NUMPY, NUMPY_UNUSED, resolve_implementation
from .map_weights import check_point_sigma, weighted_final_model
from .numpy_impl import NumpyRansac, final_model
from .options import (
    CorrelatedNoise,
    EstimateOptions,
    InitialModel,
    LocalOptimizationOptions,
    PlausibilityOptions,
    RansacOptions,
    RefineOptions,
    points_needed,
)
from .plausibility import motion_bounds
from .prior import MotionPrior
from .ransac import Ransac, SeededShuffle, prosac_order
from .result import (
    DEGENERATE_GEOMETRY,
    EstimationFailed,
    RSPoseEstimate,
    body_estimate,
    physical_velocities,
)
from .single_tag import (
    MIN_PLANAR_POINTS,
    few_points_estimate,
    few_points_planarity,
)

if TYPE_CHECKING:
    from .view import View

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

#: the solver of the global-shutter model (``w = t = 0``), which a rolling-shutter solver's
#: frames take where they cannot observe motion (``RSPoseEstimate.motion_model``)
GS_SOLVER = "p3p"


def estimate_rs_pose(
    points2d: np.ndarray,
    points3d: np.ndarray,
    camera: CameraModel,
    solver: str = "r6p_1lin",
    options: EstimateOptions | None = None,
    scores: np.ndarray | None = None,
    *,
    initial_model: InitialModel | RSModel | tuple | None = None,
    gyro: GyroMeasurement | None = None,
    point_sigma: np.ndarray | None = None,
    implementation: str | None = None,
    view: View | None = None,
    groups: np.ndarray | None = None,
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
        points2d: (N, 2) px, the measured (distorted) pixel coordinates.
        points3d: (N, 3) world (map) points in metres.
        camera: :class:`~rs_localizer.camera.CameraModel` (intrinsics, distortion, RS timing).
        solver: one of :data:`SOLVERS`; ``p3p`` is the global-shutter baseline (w = t = 0).
        options: :class:`EstimateOptions` (default ``EstimateOptions()``).
        scores: optional (N,) match quality, higher is better (PROSAC-style sample ordering).
        initial_model: optional :class:`InitialModel` (a prediction, e.g. from the previous
            frames of a video): tested first; if it explains enough points it seeds RANSAC and
            its rotation replaces P3P as the samples' pre-rotation (a bare model ``(R, C, w,
            t)``: one with the default gate). Without it the estimator is unchanged.
        gyro: optional :class:`~rs_localizer.estimation.gyro.GyroMeasurement` of this
            frame's readout (camera optical frame): RANSAC solves its minimal samples with
            the angular velocity known (R5P_{v,C,t}^{w}, 5 points,
            :func:`~rs_localizer.solvers.r5p_w.r5p_w_batch`), so every hypothesis carries
            the gyro's angular velocity; it is added to the motion prior
            (:func:`~rs_localizer.estimation.gyro.gyro_prior`), so local optimization and the
            final refinement are maximum a posteriori with it on every frame, and on planar
            frames the hypotheses' damped solves use it too; the covariance includes it. The
            gyro is then judged by the image alone (never by an estimate solved with it):
            the aided model is refined once more without any prior
            (:func:`~rs_localizer.estimation.finalize.image_alone`); if the gyro disagrees
            with that angular velocity (:func:`~rs_localizer.estimation.gyro.gyro_image_chi2`
            above :data:`~rs_localizer.estimation.gyro.GYRO_CHI2_THRESHOLD`), if the aided
            estimate fails, or if it explains fewer than ``1 -``
            :data:`~rs_localizer.estimation.gyro.GYRO_INLIER_MARGIN` of the inliers of the
            unaided estimate (run when the aided one explains fewer than
            :data:`~rs_localizer.estimation.gyro.GYRO_RECHECK_FRACTION` of the valid points,
            or the image-alone refinement explains more than it: a gyro that led RANSAC to a
            wrong consensus), the frame is solved again without it, ``gyro_rejected`` is set
            and ``gyro_rejection`` says why. Ignored by the global-shutter ``p3p``.
        point_sigma: optional (N,) standard deviation (m, per axis) of each 3D point, e.g. a
            built map's stated precision: the final model is then refined once more with each
            point weighted by its total image noise, detection and map
            (:func:`~rs_localizer.estimation.map_weights.weighted_final_model`; RANSAC and its
            inlier test are unchanged; frames refined with a motion prior keep the unweighted
            fit; the covariance is the weighted fit's, without acceleration sensitivity or
            correlated noise). Without it the estimator is unchanged.

        implementation: ``"compiled"`` (the numba kernels), ``"numpy"`` (NumPy, SciPy and
            OpenCV only, nothing compiles: the solvers of
            :data:`~rs_localizer.estimation.implementation.NUMPY_SOLVERS`, the same model and
            outputs, ``initial_model``, ``gyro`` (its prior and its check; the minimal samples
            stay the linear R6P's) and the acceleration sensitivity as above; it cannot use
            ``scores``, ``point_sigma`` and the correlated noise, and lists those it was given
            in the estimate's ``ignored_inputs``), or ``None``:
            :func:`~rs_localizer.estimation.implementation.default_implementation` (compiled,
            unless numba is unusable here or ``RS_LOCALIZER_COMPILED=0``). A process whose
            kernels compile in the background asks
            :func:`rs_localizer.runtime.warmup.ready_implementation` which one is ready.
        view: the :class:`~rs_localizer.estimation.view.View` whose points these are
            (``points2d``, ``points3d`` and ``camera`` its own) when its camera is mounted
            on a body, e.g. a rig frame of one camera with points: the estimate is then the
            body's (:func:`~.result.body_estimate` at the view's mounting and stamp offset:
            ``model`` per second in the body's frame, the pose and covariances of it, the
            view's inliers and per-view fields), and ``initial_model`` (its model the
            body's) and ``gyro`` (the body's angular velocity in its frame) are given in the
            body's terms (:meth:`~rs_localizer.estimation.view.View.camera_model`, the gyro
            turned by the mounting's rotation). None: the camera's own estimate.
        groups: optional (N,) int, each correspondence's group (one marker's corners: the
            marker's id; default: the ``view``'s :attr:`~.view.View.groups`): points of one
            group share a part of their image error, which the covariance then includes,
            its size estimated from the frame's residuals where they tell it
            (:func:`~.noise_model.shared_shift_covariance`; the compiled implementation's
            refined frames). The estimate itself is unchanged.

    A frame with fewer valid points than :func:`points_needed` but four or more coplanar ones
    or :data:`~.single_tag.MIN_SPREAD_POINTS` or more on more than one plane, or exactly four
    coplanar ones (one square marker's corners), is posed from them alone
    (:func:`~.single_tag.few_points_estimate`: IPPE's two poses of a plane or SQPnP's pose,
    refined with the velocities held at ``initial_model``'s or ``gyro``'s, a plane's
    ambiguity resolved by the image or ``initial_model``, else ``ambiguous_tag``;
    ``RSPoseEstimate.few_points``, and ``single_tag`` for coplanar points); compiled
    implementation only.

    Returns:
        :class:`RSPoseEstimate`. Data problems (NaN rows, too few points, all outliers,
        degenerate geometry) give ``success=False`` with a ``failure`` reason
        (:data:`~.result.FAILURE_REASONS`), never an exception or a NaN pose. Rows that fail
        validation are counted in ``num_dropped``.
    Raises:
        ValueError: unknown solver name, unknown implementation, ``"numpy"`` for a solver
            without it, arrays that are not (N, 2) / (N, 3) / (N,), ``options`` that are not
            :class:`EstimateOptions`, a ``gyro`` that is not a
            :class:`~rs_localizer.estimation.gyro.GyroMeasurement`, a ``view`` whose camera
            is not ``camera`` or without a mounting, or ``groups`` that are not (N,)
            integers.
    """
    options, initial_model = checked_inputs(
        "estimate_rs_pose", options, EstimateOptions(), initial_model, gyro
    )
    if view is not None:
        if view.camera is not camera or view.mounting is None:
            raise ValueError("estimate_rs_pose: a view must have the camera given and a mounting")
        if initial_model is not None:
            initial_model = replace(initial_model, model=view.camera_model(initial_model.model))
        if gyro is not None:
            gyro = gyro.rotated(view.mounting.R)
        if groups is None:
            groups = view.groups
    est = _estimate_rs_pose(
        points2d,
        points3d,
        camera,
        solver,
        options,
        scores,
        initial_model,
        gyro,
        point_sigma,
        implementation,
        solver,
        groups,
    )
    if view is None:
        return est
    return body_estimate(est, view.mounting, view.stamp_offset, camera.seconds_per_unit_r)


def _estimate_rs_pose(
    points2d: np.ndarray,
    points3d: np.ndarray,
    camera: CameraModel,
    solver: str,
    opts: EstimateOptions,
    scores: np.ndarray | None,
    initial_model: InitialModel | None,
    gyro: GyroMeasurement | None,
    point_sigma: np.ndarray | None,
    implementation: str | None,
    name: str,
    groups: np.ndarray | None = None,
) -> RSPoseEstimate:
    """:func:`estimate_rs_pose` with ``solver``, its estimate recorded as ``name``'s (a
    global shutter's frame of a rolling-shutter solver runs the global-shutter one)."""
    if solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}; expected one of {SOLVERS}")
    if camera.line_delay <= 0 and solver_info(solver).rolling:
        # a global shutter: every row at one time, nothing to fit the velocities to
        est = _estimate_rs_pose(
            points2d, points3d, camera, GS_SOLVER, opts, scores, initial_model, gyro,
            point_sigma, implementation, name, groups,
        )  # fmt: skip
        return est if est.solver == name else replace(est, solver=name)
    compiled = resolve_implementation(implementation, solver) == COMPILED
    unused: tuple[str, ...] = ()
    if not compiled:
        unused = _unused_by_numpy(opts, scores, point_sigma, groups)
        scores = point_sigma = groups = None
    if point_sigma is not None:
        point_sigma = check_point_sigma(point_sigma, len(np.asarray(points3d)))
    args = (points2d, points3d, camera, solver)
    if gyro is None or camera.line_delay <= 0 or not solver_info(solver).rolling:
        ignored = unused if gyro is None else ("gyro", *unused)
        return _estimate(
            *args, opts, scores, initial_model, point_sigma=point_sigma, ignored=ignored,
            compiled=compiled, name=name, groups=groups,
        )  # fmt: skip
    aided = replace(opts, motion_prior=gyro_prior(gyro, opts.motion_prior, compiled))
    return gyro_checked_estimate(
        _CameraStages(
            *args, aided, scores, initial_model, gyro, opts.motion_prior,
            point_sigma=point_sigma, ignored=unused, compiled=compiled, name=name,
            groups=groups,
        ),
        gyro,
        lambda: _estimate(
            *args, opts, scores, initial_model, point_sigma=point_sigma, ignored=unused,
            compiled=compiled, groups=groups,
        ),
        compiled,
    )  # fmt: skip


def _unused_by_numpy(
    opts: EstimateOptions,
    scores: np.ndarray | None,
    point_sigma: np.ndarray | None,
    groups: np.ndarray | None = None,
) -> tuple[str, ...]:
    """The inputs given that the NumPy implementation does not use (its estimate's
    ``ignored_inputs``; :data:`~.implementation.NUMPY_UNUSED`)."""
    given = (
        scores is not None,
        point_sigma is not None,
        opts.correlated_noise.sigma_px > 0,
        groups is not None,
    )
    return tuple(name for name, g in zip(NUMPY_UNUSED, given, strict=True) if g)


def _estimate(*args, **kwargs) -> RSPoseEstimate:
    """:func:`estimate_rs_pose` with one set of options and no gyro: the staged estimator
    (:func:`~.driver.staged_estimate`) on the camera's :class:`_CameraStages` (arguments as
    there)."""
    return staged_estimate(_CameraStages(*args, **kwargs))


class _CameraStages:
    """One camera's frame as the staged estimator's :class:`~.driver.Stages`
    (:func:`estimate_rs_pose` with one set of options, the motion prior possibly including a
    gyro): with ``gyro`` RANSAC solves its samples with the gyro's angular velocity (and a
    success has ``gyro_used`` set) and a success records what the image alone (with
    ``image_prior``, the motion prior without the gyro) says near the final model
    (:func:`~.finalize.image_alone`, :meth:`gyro_evidence`). ``point_sigma``: (num_rows,) the
    3D points' standard deviations (m), or None (:func:`~.map_weights.weighted_final_model`).
    ``ignored``: the estimate's ``ignored_inputs``. ``compiled=False``: the NumPy
    implementation (:mod:`.numpy_impl`: the same stages with their compiled steps in NumPy and
    SciPy; the gyro only through the motion prior and the image-alone check, not in the
    minimal samples; without ``scores``, ``point_sigma``, single-tag frames and the
    global-shutter model of still frames). ``name``: the solver a few-points frame's estimate
    records (None: ``solver``). ``groups``: (num_rows,) each point's group, or None
    (:attr:`~.frame.Frame.groups`).

    Its stages: :func:`~.frame.prepare_frame`, :func:`~.frame.configure_frame` (or
    :func:`_few_points`); LO-RANSAC (:class:`~.ransac.Ransac`); the final refinement
    (:func:`~.finalize.refine_final_model`, :func:`~.finalize.still_final`, the map points'
    weights); :func:`~.finalize.final_estimate`; after ``implausible_motion`` or
    ``too_few_inliers`` the global-shutter estimator (:func:`~.finalize.still_fallback`)."""

    def __init__(
        self,
        points2d: np.ndarray,
        points3d: np.ndarray,
        camera: CameraModel,
        solver: str,
        opts: EstimateOptions,
        scores: np.ndarray | None,
        initial_model: InitialModel | None,
        gyro: GyroMeasurement | None = None,
        image_prior: MotionPrior | None = None,
        *,
        point_sigma: np.ndarray | None = None,
        ignored: tuple[str, ...] = (),
        compiled: bool = True,
        name: str | None = None,
        groups: np.ndarray | None = None,
    ):
        self.inputs = (points2d, points3d, camera)
        self.groups = groups
        self.solver, self.opts, self.scores = solver, opts, scores
        self.initial_model, self.gyro, self.image_prior = initial_model, gyro, image_prior
        self.point_sigma, self.ignored, self.compiled = point_sigma, ignored, compiled
        self.name = name or solver
        self.t_start = time.perf_counter()
        self.timings: dict[str, float] = {}
        self.image: ImageAlone | None = None
        self.search: Ransac | None = None

    def prepared(self) -> RSPoseEstimate | None:
        (points2d, points3d, camera), opts, compiled = self.inputs, self.opts, self.compiled
        shuffle = SeededShuffle(opts.ransac.seed)  # (the generator built when RANSAC runs)
        self.fr = fr = prepare_frame(
            points2d, points3d, camera, opts.plausibility.max_point_norm, shuffle,
            compiled=compiled, groups=self.groups,
        )  # fmt: skip
        fr.shift_share = opts.correlated_noise.shift_share
        if self.gyro is not None and compiled:  # (the model's w per unit r: omega = -w / s)
            fr.known_w = -camera.seconds_per_unit_r * self.gyro.angular_velocity
        order = prosac_order(fr, self.scores)
        self.min_inliers = min_inliers = points_needed(self.solver, opts)
        flat = few_points_planarity(fr, min_inliers) if compiled else None
        if flat is not None:
            return _few_points(
                fr, camera, self.solver, opts, self.initial_model, self.gyro, self.timings,
                self.ignored, flat, self.name,
            )  # fmt: skip
        rng = shuffle.generator()
        self.search = (Ransac if compiled else NumpyRansac)(
            fr, self.solver, opts, rng, order, self.scores is not None
        )
        try:
            configure_frame(
                fr,
                camera,
                self.solver,
                opts.ransac.min_inliers,
                opts.ransac.threshold_px,
                (opts.plausibility.max_angular_velocity, opts.plausibility.max_linear_velocity),
                opts.motion_prior,
                compiled=compiled,
            )
        finally:
            self.timings["prepare"] = time.perf_counter() - self.t_start
        return None

    def searched(self) -> Model:
        search = self.search
        search.run(self.initial_model)
        self.timings.update(search.timings)
        return search.result(self.min_inliers, self.opts.ransac.threshold_px)

    def polished(self, model: Model) -> Model:
        return model  # (local optimization ran on every new best inside the search)

    def final(self, model: Model) -> FinalModel:
        fr, solver, opts, min_inliers = self.fr, self.solver, self.opts, self.min_inliers
        t0 = time.perf_counter()
        if self.compiled:
            camera = self.inputs[2]
            final = refine_final_model(
                fr, camera, solver, opts, model, self.search.inliers, min_inliers
            )
        else:
            final = final_model(fr, solver, opts, model, min_inliers)
        self.model_solver = solver
        if (
            self.compiled
            and self.gyro is None
            and solver_info(solver).rolling
            and (not final.prior_used or prior_at_rest(fr.final_prior))
        ):
            still = still_final(fr, final, min_inliers)
            if still is not None:
                final, self.model_solver = still, GS_SOLVER
        if self.point_sigma is not None:
            sigma = self.point_sigma[fr.rows]
            final = weighted_final_model(fr, self.model_solver, final, sigma, min_inliers)
        self.timings["refine"] = time.perf_counter() - t0
        return final

    def finished(self, final: FinalModel) -> RSPoseEstimate:
        fr, opts, search, timings = self.fr, self.opts, self.search, self.timings
        initial = (search.explained, search.anchor is not None)
        est = final_estimate(
            fr,
            self.model_solver,
            final,
            search.iterations,
            initial,
            timings,
            opts.plausibility.consistent_fit,
            self.gyro is not None,
            opts.ransac.threshold_px / fr.f,
            self.ignored,
            self.compiled,
        )
        if self.gyro is not None:
            t0 = time.perf_counter()
            th = opts.ransac.threshold_px / fr.f
            self.image = image_alone(fr, final.model, th, self.image_prior)
            timings["gyro_check"] = time.perf_counter() - t0
        timings["total"] = time.perf_counter() - self.t_start
        solver = self.solver
        if self.model_solver == solver:
            return est
        # (a rolling-shutter solver's frame on the global-shutter model: the twist covariance
        # is the rolling-shutter fit's, what the frame says of its motion; its (12, 12)
        # covariance, the fit's, already carries it)
        if final.covariance is None:
            return replace(est, solver=solver, twist_covariance=None)
        fields = unobserved_twist(None, final.covariance, *final.model[:2], fr.spr)
        return replace(est, solver=solver, **fields)

    def retried(self, failure: EstimationFailed) -> RSPoseEstimate | None:
        solver, fr = self.solver, self.fr
        if not (
            self.compiled
            and self.gyro is None
            and solver_info(solver).rolling
            and failure.reason in STILL_FALLBACK  # (the frame configured: its threshold set)
        ):
            return None
        # (a frame that shows no motion, on the global-shutter model; its twist covariance
        # from the rolling-shutter fit, with the motion prior where the final refinement uses
        # it from the start: planar frames)
        still = still_fallback(
            failure.reason,
            lambda: _estimate(
                *self.inputs, GS_SOLVER, self.opts, self.scores, self.initial_model,
                point_sigma=self.point_sigma, ignored=self.ignored,
            ),
            fr,
            fr.threshold,
            fr.prior if fr.planar else None,
        )  # fmt: skip
        return None if still is None else replace(still, solver=solver)

    def failed(self, failure: EstimationFailed) -> RSPoseEstimate:
        impl = COMPILED if self.compiled else NUMPY
        timings = self.timings | {"total": time.perf_counter() - self.t_start}
        return _failed(
            failure, self.solver, self.fr, self.search.iterations, timings, self.ignored, impl
        )  # fmt: skip

    def gyro_evidence(self, est: RSPoseEstimate) -> tuple:
        return self.image, lambda: est.planar, est.num_valid


def _few_points(
    fr,
    camera: CameraModel,
    solver: str,
    opts: EstimateOptions,
    initial_model: InitialModel | None,
    gyro: GyroMeasurement | None,
    timings: dict[str, float],
    ignored: tuple[str, ...],
    flat: float,
    name: str,
) -> RSPoseEstimate:
    """A frame of too few points for ``solver`` but at least four coplanar ones or
    :data:`~.single_tag.MIN_SPREAD_POINTS` on more than one plane, or exactly four coplanar
    ones whatever the solver (one square marker's corners: a minimal sample and one point to
    check it cannot pose a tag whose corners fit a square only to a pixel) posed from them
    alone (:func:`~.single_tag.few_points_estimate`), or its failure; ``flat``: the points'
    planarity (:func:`~.single_tag.few_points_planarity`), ``name``: the solver the estimate
    records."""
    t_start = time.perf_counter()
    try:
        _configure_few_points(fr, camera, opts, flat)
        est = few_points_estimate(
            fr, solver, opts, initial_model, gyro is not None, timings, ignored,
            flat=flat, name=name,
        )  # fmt: skip
    except EstimationFailed as failure:
        return _failed(failure, name, fr, 0, timings, ignored)
    timings["few_points"] = time.perf_counter() - t_start
    return est


def _failed(
    failure: EstimationFailed,
    solver: str,
    fr,
    iterations: int,
    timings: dict[str, float],
    ignored: tuple[str, ...],
    implementation: str = COMPILED,
) -> RSPoseEstimate:
    """The failed estimate of ``failure`` on the prepared frame ``fr`` after ``iterations``
    RANSAC hypotheses, by ``implementation`` (which could not use ``ignored``):
    :meth:`~.result.EstimationFailed.estimate`, no inlier among its ``fr.num_rows`` rows (its
    one view's too)."""
    return failure.estimate(
        (np.zeros(fr.num_rows, dtype=bool),), (len(fr.x),), fr.num_rows, solver=solver,
        ransac_iterations=iterations, timings=timings, implementation=implementation,
        ignored_inputs=ignored,
    )  # fmt: skip


def _configure_few_points(fr, camera: CameraModel, opts: EstimateOptions, flat: float) -> None:
    """Check that the few points of ``fr`` fix a pose and set its threshold, timing, velocity
    bounds and ``planar`` (:func:`_few_points`; ``flat``: their planarity).

    Raises:
        EstimationFailed: ``degenerate_geometry`` (:meth:`~.frame.Frame.degenerate`).
    """
    th_px = opts.ransac.threshold_px
    if fr.degenerate(np.ones(len(fr.x), dtype=bool), th_px):
        raise EstimationFailed(DEGENERATE_GEOMETRY)
    fr.threshold = th_px / fr.f
    fr.spr = spr = camera.seconds_per_unit_r
    fr.motion_bounds = motion_bounds(
        opts.plausibility.max_angular_velocity, opts.plausibility.max_linear_velocity, spr
    )
    fr.planar = bool(len(fr.x) >= MIN_PLANAR_POINTS and flat < PLANAR_TOLERANCE)
