"""One pose for a rig of rolling-shutter cameras from one rig frame (RANSAC over all cameras).

A rig frame is one image of each of M cameras rigidly mounted on the rig, each with its own
intrinsics, lens distortion, line delay, readout direction and stamp. Camera ``c`` is mounted at
``x_cam = R_c x_rig + c_c``. The rig moves with constant angular velocity ``w`` and linear
velocity ``t`` through the frame (the exact constant-velocity model, paper eq. 4, in time)::

    x_rig(tau) = expm(tau [w]x) R X + C + tau t

with ``tau`` (s) the capture time of an observation minus the rig's reference time: for a point
on measured line ``r`` (RS coordinate, :class:`~rs_localizer.camera.CameraModel`) of camera c,
``tau = stamp_offset_c + (r - r0_c) * seconds_per_unit_r_c`` (``stamp_offset_c``: the capture
time of the camera's reference line minus the rig's reference time). ``(R, C, w, t)`` is the
single-camera :class:`~rs_localizer.pose.RSModel` with one second as the unit of ``tau``: the
rig's :class:`~rs_localizer.pose.RSPose` is ``RSPose.from_model((R, C, w, t), 1.0)``
(orientation rig -> world, position, angular velocity ``-w`` rad/s and linear velocity
``w x C - t`` m/s in the rig frame; :func:`~rs_localizer.pose.model_twist` with ``s = 1``).
Camera c's own model at its reference line is :func:`camera_model_of_rig`.

:func:`estimate_rig_pose` runs the single camera's staged estimator
(:func:`~rs_localizer.estimation.driver.staged_estimate`, whose docstring lists the stages) on
the rig's stages (:class:`_RigStages`) over the rig frame's views stacked
(:class:`~.view.StackedViews`: each camera's rows checked and normalized as a camera's frame's,
their degeneracy, scoring and samples). What is the rig's own:

- a sample is 3 points of one camera (drawn with probability proportional to its number of
  points, among cameras with at least 3) and 3 more points drawn uniformly from every camera's
  remaining points (:meth:`~.view.StackedViews.samples`); the camera's 3 points give P3P poses
  (Lambda Twist, global shutter) mapped to the rig (``R_rig = R_c^T R_cam``), each
  pre-rotating the sample's world points for the batched
  :func:`~rs_localizer.solvers.gr6p_1lin.gr6p_1lin_batch` on the 6 points;
- the scoring is MSAC on the reprojection error in pixels of the measured, distorted image
  with each camera's exact model at the observation's own capture time
  (:meth:`~.view.StackedViews.best_scored`); the search is the single camera's
  (:class:`~rs_localizer.estimation.ransac.RansacLoop`, :class:`_RigSearch`), compiled one
  call per batch (:mod:`.rig_batch`) that checks termination after every sample, as
  PoseLib's loop does;
- local optimization is the single camera's rounds
  (:func:`~rs_localizer.estimation.local_optimization.polish`) with the rig's steps: the rig
  solver on the best model's inliers (:func:`_refit`), then the final refinement's first, at
  most :data:`LO_ROUNDS` rounds;
- the final stage is a single camera's (:mod:`~rs_localizer.estimation.finalize`) on the
  stacked views as one :class:`~rs_localizer.estimation.frame.RefinementView` (each point
  seen through its camera's mounting at its own time, errors in its camera's pixels, one
  second per unit of ``tau``; the covariance with the mountings' uncertainty), with the
  choice between refinements of :func:`~.finalize.chosen_refinement`
  (:data:`CONTRADICTION_GATE`: cameras whose mountings disagree) and the consistent fit view
  by view (:data:`AGREE_SHARE`); the rig's own part of the result is its per-camera fields
  (:func:`_rig_estimate`);
- the cameras' consensus: every camera with enough points must agree with the pose, cameras
  that contradict each other decided by their number, never by their numbers of points
  (:func:`_consensus`); an initial model, a prediction and a gyro on the rig are used as a
  single camera's estimator uses its own (:func:`estimate_rig_pose`).

The estimator runs in one of the single camera's two implementations (``implementation``,
:mod:`~rs_localizer.estimation.implementation`), its stages the camera's on either; on
``"numpy"`` the rig's own parts are OpenCV's P3P (:func:`~.numpy_impl.p3p_roots`, every root)
and the rig solver's NumPy form (:func:`~rs_localizer.solvers.gr6p_1lin.gr6p_1lin_batch` with
``numpy``). A rig node takes it while its kernels compile in the background
(:mod:`rs_localizer.runtime.background`): on a cold cache its first rig frame compiles nothing.

A rig frame whose observations were all taken at one time (global-shutter cameras with equal
stamps) does not determine ``w`` and ``t``: the estimate is then the rig's generalized absolute
pose (the P3P samples mapped to the rig, the refinement and covariance of the 6 pose
parameters) with ``w = t = 0`` and ``motion_model`` ``"global_shutter"``. While RANSAC's best
model explains no point of a camera that has some (one camera's P3P pose from three corners
of a small tag is a degree or so off, pixels off in a camera looking elsewhere), each P3P
model of a sample with points in such a camera is also corrected on the sample's six points
by the rig solver with the velocities held at zero, as a generalized P3P would pose it. A
search whose final model has fewer than ``ransac.min_inliers`` inliers runs again with every
sample's P3P models corrected so, each in :data:`SPREAD_CORRECTION_ROUNDS` rounds (a rig frame
of one small tag per camera, whose P3P poses are tens of degrees off).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from ..geometry import matrix_to_rotvec
from ..pose import RSModel, RSPose
from ..solvers.gr6p_1lin import (
    gr6p_1lin_batch,
    still_solve_rotated,
)
from .degeneracy import coplanar
from .driver import checked_inputs, gyro_checked_estimate, staged_estimate
from .estimate import estimate_rs_pose
from .finalize import (
    FINAL_CUTOFF,
    GLOBAL_SHUTTER,
    ROLLING_SHUTTER,
    FinalModel,
    checked_outputs,
    chosen_refinement,
    frame_refinement,
    image_alone,
    information_condition,
    refined_model,
    selected_final,
    still_fallback,
    with_covariance,
)
from .frame import (
    Model,
)
from .gyro import (
    GyroMeasurement,
    gyro_prior,
)
from .hypotheses import (
    anchor_prerotations,
    composed,
    linear_refit,
    prerotated_models,
    still_models,
)
from .implementation import COMPILED, NUMPY, resolve_implementation
from .local_optimization import initial_model_seed, polish, view_seed_steps
from .numpy_impl import p3p_roots
from .options import EstimateOptions, InitialModel, RansacOptions
from .plausibility import (
    collinear_3d,
    plausible_motion,
)
from .prior import MotionPrior, sample_prior_rows
from .ransac import RansacLoop, required_iterations, seeded_rng, seeded_stream
from .result import (
    CAMERAS_DISAGREE,
    DEGENERATE_GEOMETRY,
    RIG_FAILURE_REASONS,
    TOO_FEW_INLIERS,
    TOO_FEW_POINTS,
    EstimationFailed,
    RSPoseEstimate,
    built_estimate,
    output_covariance,
)
from .rig_batch import (
    counted,
    lambda_twist_on_rig,
    search_batch,
)
from .single_tag import posed_planarity
from .view import StackedViews, View

__all__ = [
    "AGREE_SHARE",
    "CONTRADICTION_GATE",
    "FINAL_CUTOFF",
    "LO_ROUNDS",
    "PREDICTION_GATE",
    "PREDICTION_MARGIN",
    "PRE_ROTATIONS",
    "RIG_FAILURE_REASONS",
    "RIG_OPTIONS",
    "RIG_SOLVER",
    "RIG_SOLVER_ITERATIONS",
    "SPREAD_CORRECTION_ROUNDS",
    "STILL_SPREAD",
    "VERIFY_ALL_EXPLAINED",
    "VERIFY_MIN_POINTS",
    "VERIFY_SHARE",
    "VOTE_MIN_POINTS",
    "estimate_rig_pose",
]

#: ``RSPoseEstimate.solver`` of a rig's estimate: the rig solver that poses it (on the
#: global-shutter model too, where it corrects the P3P samples with the velocities held at 0;
#: a rig frame of one camera's few points records that camera's, :func:`_one_camera_alone`)
RIG_SOLVER = "gr6p_1lin"

#: a camera votes in the cameras' consensus (:func:`estimate_rig_pose`) with at least this
#: many valid points; cameras with fewer are fitted with every group, never outvoted
VOTE_MIN_POINTS = 8

#: the rig estimator's default options: a camera's (``EstimateOptions()``: threshold,
#: iterations, confidence 0.9999, seed, refinement, velocity bounds) with ``min_inliers``
#: :data:`VOTE_MIN_POINTS` over all cameras, so that the cameras' consensus can pose a
#: voting camera of a few points alone
RIG_OPTIONS = EstimateOptions(ransac=RansacOptions(min_inliers=VOTE_MIN_POINTS))

#: the rig solver's iterations per sample after the pre-rotation when
#: ``EstimateOptions.ransac.solver_iterations`` is None (the single camera's choice per solver)
RIG_SOLVER_ITERATIONS = 3

#: the rig solver's iterations (velocities held at zero) that correct a global-shutter
#: sample's P3P pose on its points in other cameras (:func:`_hypotheses_still`)
STILL_SOLVER_ITERATIONS = 1

#: the rounds of that correction in a global-shutter search run again because its model had
#: too few inliers (:class:`_RigStages`): each round pre-rotated by the previous round's
#: rotation (the rig solver's rotation is linear about its pre-rotation: one round from a P3P
#: pose 10-30 degrees off, as three noisy corners of a small tag give, stays degrees off;
#: a second one converges on the sample's six points)
SPREAD_CORRECTION_ROUNDS = 2

#: local optimization's rounds (:func:`~.local_optimization.polish`; a camera's are at most
#: ``local_optimization.steps``): the rig's refinement is the final refinement's first, on
#: every point until converged, so further rounds seldom move the model. Up to 4 rounds
#: changed none of the rig's medians or posed counts in ``python -m benchmarks.bench_rig``
#: (also ``--points 36``, ``--gyro``) and ``python -m benchmarks.bench_rig_rendered``, and
#: made every TagSLAM recording's rig frames slower
LO_ROUNDS = 1

#: the pre-rotations of RANSAC's samples (``estimate_rig_pose(..., pre_rotation=)``)
PRE_ROTATIONS = ("p3p", "gp3p")

#: s: observation times spread by at most this are one time (a global-shutter rig frame)
STILL_SPREAD = 1e-9

#: a voting camera agrees with a model when its inlier ratio is at least this share of the
#: best-fitting voting camera's under that model (a camera whose mounting or stamp is wrong
#: has almost no inliers: 0-5 % of its points at a mounting 2 deg off or a clock 5 ms off)
AGREE_SHARE = 0.3

#: two groups of cameras that disagree at the inlier threshold but whose poses each explain
#: the other group's points within this many inlier thresholds, or one pose explains both
#: groups' points within them, do not contradict each other (a tie of such groups is posed
#: by the joint fit, not refused): on TagSLAM's real 4-camera ring (``python -m
#: benchmarks.bench_real_rig --folder test_7``), two cameras seeing tags disagreed at 2 px in
#: 30 of 265 rig frames without this gate (their poses alone a few tenths of a degree apart),
#: in 4 with it: there the two cameras' poses alone are 2.6 to 5.9 degrees apart and the
#: recording's reference pose misses both cameras' corners by 9 to 29 px (median), a real
#: contradiction; a mounting 2 degrees off misses by 15 px and more at focal lengths of 450
#: px and more
CONTRADICTION_GATE = 3.0

#: with a prediction, a voting camera is explained by it when its share of points within
#: this many inlier thresholds of the prediction is at least :data:`AGREE_SHARE` times the
#: best voting camera's
PREDICTION_GATE = 3.0

#: ``verify_cameras``: camera d agrees with camera c's own pose when that pose explains at
#: least this share of the inliers d's own pose has
VERIFY_SHARE = 0.5

#: ``verify_cameras``: a camera is posed alone to check the others only with at least this
#: many valid points. Posed alone from a tag or two (8-12 corners for the twelve parameters
#: of a rolling-shutter pose) its velocities fit its noise and its pose misses cameras that
#: agree with the rig: a correct first rig frame was refused as ``cameras_disagree``
VERIFY_MIN_POINTS = 20

#: ``verify_cameras``: a joint estimate that explains at least this share of every voting
#: camera's points is not checked camera by camera (a camera posed alone extrapolates its
#: velocities to cameras looking elsewhere: a front and a back camera each explaining all of
#: their 32 and 48 corners under the joint pose were refused as disagreeing)
VERIFY_ALL_EXPLAINED = 0.95

#: with a prediction, the group of cameras whose pose is nearer to it is chosen when the
#: other group's is at least this many times farther (rotation in rad plus position over
#: the points' median depth)
PREDICTION_MARGIN = 2.0


def _rig_solver(pool: StackedViews, iterations: int, prior: MotionPrior | None = None,
                threshold_px: float = 2.0, held: bool = False):  # fmt: skip
    """The rig's :data:`~.hypotheses.SampleSolver`: the rig solver
    (:func:`~rs_localizer.solvers.gr6p_1lin.gr6p_1lin_batch`, each point seen through its
    camera's mounting, ``iterations`` linear steps) with the gyro ``prior``'s rows
    (:func:`~.prior.sample_prior_rows`: one second per unit of tau, half the inlier
    threshold in the sample's first camera's normalized units times the points' mean distance
    from the rig) or, ``held``, the velocities held at zero (prior rows ``(w, t) = 0``)."""

    def solve(S, xs, Xs, rs, C0) -> list:
        if held:
            rows = (np.broadcast_to(np.eye(6), (len(S), 6, 6)), np.zeros((len(S), 6)))
        elif prior is None:
            rows = None
        else:
            noise = 0.5 * threshold_px / pool.focal[S[:, 0]]
            rows = sample_prior_rows(prior, Xs, C0, 1.0, noise, True, pool.compiled)
        return [gr6p_1lin_batch(xs, Xs, rs, pool.cam[S], pool.R_mount, pool.c_mount, iterations,
                                prior_rows=rows, numpy=not pool.compiled)]  # fmt: skip

    return solve


def _hypotheses(
    pool: StackedViews,
    samples: np.ndarray,
    iterations: int,
    anchor=None,
    prior: MotionPrior | None = None,
    threshold_px: float = 2.0,
    p3p=None,
):
    """Models (R, C, w, t) of the samples: P3P in the sample's first camera, mapped to the
    rig (``p3p``: :func:`_p3p_on_rig` by default, or :func:`_gp3p_on_rig`), pre-rotates the
    rig solver (``anchor``: this model's (3, 3) rotation pre-rotates
    every sample instead, an initial model's or the best model's; ``(R, C)``), as a camera's
    samples pre-rotate its solver (:func:`~.hypotheses.prerotated_models` with
    :func:`_rig_solver`); ``prior``: a gyro's motion prior, whose rows (at the pre-rotation,
    P3P's or the anchor's translation) join every linear solve. Returns arrays of the H finite
    models (the search drops those beyond its velocity bounds), or None."""
    if anchor is not None:
        (R0, C0), S = anchor_prerotations(anchor, len(samples)), samples
    else:
        pre = (p3p or _p3p_on_rig)(pool, samples)
        if pre is None:
            return None
        R0, C0, own = pre
        S = samples[own]
    solve = _rig_solver(pool, iterations, prior, threshold_px)
    R, C, w, t, ok = prerotated_models(S, R0, C0, pool.x, pool.X, pool.tau, solve, pool.compiled)
    ok &= plausible_motion(None, C, w, t, None, pool.compiled)
    if not ok.any():
        return None
    return R[ok], C[ok], w[ok], t[ok]


def _hypotheses_still(pool: StackedViews, samples: np.ndarray, p3p=None, missed=None, rounds=1):
    """Global-shutter models (R, C, 0, 0) of the samples: P3P on the sample's first 3 points
    (one camera), mapped to the rig: ``R = R_c^T R_cam``, ``C = R_c^T (C_cam - c_c)``
    (``p3p``: :func:`_p3p_on_rig` by default, or :func:`_gp3p_on_rig`). ``missed``: (M,)
    bool, cameras whose points the best model so far does not explain, or None: each P3P
    model of a sample with points in one of them (and in the P3P's camera) is also corrected
    on the sample's 6 points by the rig solver with the velocities held at zero
    (:data:`STILL_SOLVER_ITERATIONS`; prior rows ``(w, t) = 0``), ``rounds`` times, each
    pre-rotated by the previous round's rotation. Returns arrays of H models, or None."""
    p3p = (p3p or _p3p_on_rig)(pool, samples)
    if p3p is None:
        return None
    R, C, own = p3p
    if missed is None:
        return still_models(R, C)
    spread = np.flatnonzero(missed[pool.cam[samples[own]]].any(axis=1))
    if len(spread) == 0:
        return still_models(R, C)
    # (one camera's P3P pose misses another camera's points by the lever arm times its
    # rotation error: a small tag's three corners leave a pose a degree off, pixels off in
    # a camera looking elsewhere; the rig solver with the velocities held at zero corrects
    # it on the sample's six points, from every camera it spans, as a generalized P3P would)
    S, Rg = samples[own[spread]], R[spread]
    for _ in range(rounds):
        Rg, Cg, valid = _held_solve(pool, S, Rg)
        if not valid.any():
            return still_models(R, C)
        S, Rg, Cg = S[valid], Rg[valid], Cg[valid]
    return still_models(np.concatenate([R, Rg]), np.concatenate([C, Cg]))


def _held_solve(pool: StackedViews, S: np.ndarray, Rg: np.ndarray) -> tuple:
    """The rig solver with the velocities held at zero on the samples ``S`` (H, 6) at one
    time, pre-rotated by ``Rg`` (H, 3, 3) (:data:`STILL_SOLVER_ITERATIONS`; prior rows
    ``(w, t) = 0``): ``(R (H, 3, 3), C (H, 3), valid (H,))``, each rotation ``expm([v]x)
    Rg`` (:func:`~.hypotheses.composed`). Compiled:
    :func:`~rs_localizer.solvers.gr6p_1lin.still_solve_rotated` (the same solution from the
    pose's six unknowns alone)."""
    if not pool.compiled:
        solve = _rig_solver(pool, STILL_SOLVER_ITERATIONS, held=True)
        R, C, _, _, ok = prerotated_models(S, Rg, None, pool.x, pool.X, np.zeros(len(pool.X)),
                                           solve, False)  # fmt: skip
        return R, C, ok
    X, x = pool.kernel_arrays[:2]
    cam, Rm, cm, _ = pool.compiled_mountings.views
    S = np.ascontiguousarray(S, dtype=np.int64)
    Rg = np.ascontiguousarray(Rg, dtype=np.float64)
    out, ok = still_solve_rotated(x, X, S, Rg, cam, Rm, cm)
    return composed(out[:, 0:3], Rg), out[:, 3:6], ok


def _gp3p_on_rig(pool: StackedViews, samples: np.ndarray):
    """Generalized P3P (PoseLib's ``gp3p``) on each sample's first 3 points, in whatever
    cameras they lie: the rays ``R_c^T x`` from the camera centres ``-R_c^T c_c`` in the rig
    frame give the rig's ``R`` (H, 3, 3) and ``C`` (H, 3) directly (``x_rig = R X + C``); and
    the indices (H,) of the samples that gave them (up to 8 per sample); None when none did.
    A global-shutter solver, as :func:`_p3p_on_rig`."""
    import poselib  # (an optional comparison: imported on use)

    centres = -np.einsum("cji,cj->ci", pool.R_mount, pool.c_mount)
    first = samples[:, :3]
    rays = np.concatenate([pool.x[first], np.ones(first.shape + (1,))], axis=2)
    rays = np.einsum("hnji,hnj->hni", pool.R_mount[pool.cam[first]], rays)
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    Rs, Cs, own = [], [], []
    for h in range(len(samples)):
        for sol in poselib.gp3p(centres[pool.cam[first[h]]], rays[h], pool.X[first[h]]):
            Rs.append(sol.R)
            Cs.append(sol.t)
            own.append(h)
    if not own:
        return None
    R, C = np.array(Rs), np.array(Cs)
    ok = np.isfinite(R).all(axis=(1, 2)) & np.isfinite(C).all(axis=1)
    if not ok.any():
        return None
    return R[ok], C[ok], np.array(own, dtype=np.int64)[ok]


def _p3p_on_rig(pool: StackedViews, samples: np.ndarray):
    """P3P (Lambda Twist) on each sample's first 3 points, all of one camera, mapped to the
    rig: ``R = R_c^T R_cam`` (H, 3, 3), ``C = R_c^T (C_cam - c_c)`` (H, 3) and the indices
    (H,) of the samples that gave a solution; None when none did. The NumPy implementation's
    pool: OpenCV's P3P (:func:`~.numpy_impl.p3p_roots`, every root) instead."""
    if pool.compiled:  # (solved and mapped to the rig in one compiled call)
        X, x, _, (cam, Rm, cm, _) = pool.kernel_arrays
        R, C, own = lambda_twist_on_rig(x, X, samples, cam, Rm, cm)
        return (R, C, own) if len(own) else None
    cam0 = pool.cam[samples[:, 0]]
    R_cam, C_cam, own = p3p_roots(pool.X[samples[:, :3]], pool.x[samples[:, :3]])
    if len(own) == 0:
        return None
    RcT = pool.R_mount[cam0[own]].transpose(0, 2, 1)
    R = RcT @ R_cam
    C = (RcT @ (C_cam - pool.c_mount[cam0[own]])[..., None])[..., 0]
    return R, C, own


def _refit(
    pool: StackedViews,
    inl: np.ndarray,
    model,
    threshold_px: float,
    rounds: int = 2,
    prior: MotionPrior | None = None,
):
    """The rig solver on the inliers, pre-rotated by the current model, ``rounds`` times;
    ``prior``: a gyro's motion prior, whose rows (:func:`_rig_solver`'s at ``threshold_px``)
    join the solve: a camera's non-minimal step (:func:`~.hypotheses.linear_refit`) with the
    rig solver."""
    R, C, w, t = model
    idx = np.flatnonzero(inl)
    if len(idx) < 6:
        return model
    solve = _rig_solver(pool, 10, prior, threshold_px)
    for _ in range(rounds):
        m = linear_refit(idx, R, C, pool.x, pool.X, pool.tau, solve)
        if m is None:
            return model
        R, C, w, t = m
    return R, C, w, t


def estimate_rig_pose(
    views: Sequence[View],
    options: EstimateOptions | None = None,
    *,
    initial_model: InitialModel | RSModel | tuple | None = None,
    gyro: GyroMeasurement | None = None,
    gyro_time: float | None = None,
    pre_rotation: str = "p3p",
    prediction: RSModel | tuple | None = None,
    consensus: bool = True,
    verify_cameras: bool = False,
    implementation: str | None = None,
    twist: tuple | None = None,
) -> RSPoseEstimate:
    """The pose and velocities of a rig of RS cameras from one rig frame (module docstring):
    the many-view call of the staged estimator whose one-view call is
    :func:`~.estimate.estimate_rs_pose`; its arguments are used as that one's.

    Args:
        views: one :class:`View` per camera (pixels, world points, camera, mounting, stamp
            offset); a camera may have no points.
        options: :class:`~rs_localizer.estimation.options.EstimateOptions` (default
            :data:`RIG_OPTIONS`), of which the rig uses ``ransac`` (``min_inliers`` over all
            cameras; ``solver_iterations`` None: :data:`RIG_SOLVER_ITERATIONS`),
            ``refine.enabled`` (without it the estimate is the rig solver's refit of
            RANSAC's model) and ``plausibility`` (velocity bounds in rad/s and m/s, rows
            beyond ``max_point_norm`` dropped, ``consistent_fit``); its other fields are a
            single camera's alone.
        initial_model: an :class:`~rs_localizer.estimation.InitialModel` (a bare model: the
            default gate) of the rig's predicted ``(R, C, w, t)`` (per second, at the rig's
            reference time), used as a camera's: tested on every point, pulled onto those
            it explains, seeding RANSAC and pre-rotating its samples, verified with samples
            among its inliers when it has ``min_explained``.
        gyro: a :class:`~rs_localizer.estimation.gyro.GyroMeasurement` of the rig's angular
            velocity (rad/s, **rig frame**), used as a camera's: its rows in every sample's
            rig solve, the refinements maximum a posteriori with it, then judged by the image
            alone (:func:`~.driver.gyro_checked_estimate`: ``gyro_rejected`` and the frame
            solved again without it on disagreement). Ignored on a global-shutter rig frame
            and without ``refine``.
        gyro_time: s from the rig's reference time: the middle of the gyro's window (for the
            ``acceleration_sensitivity``); None: the middle of the observation times.
        pre_rotation: ``"p3p"`` (3 points of one camera, Lambda Twist, mapped to the rig) or
            ``"gp3p"`` (PoseLib's generalized P3P on 3 points drawn from all cameras, samples
            drawn uniformly; needs ``poselib``; ``python -m benchmarks.bench_rig
            --pre-rotation``, docs/rig.md).
        prediction: the rig's predicted model that decides between cameras that contradict
            each other (:func:`_consensus`); None: ``initial_model``'s model, if any.
        consensus: check that the cameras with points agree (:func:`_consensus`); False: the
            joint estimate as it is.
        verify_cameras: also pose every voting camera alone and compare (:func:`_verified`):
            for a rig frame nothing else checks (a track's first).
        implementation: ``"compiled"``, ``"numpy"`` or None, as ``estimate_rs_pose``'s
            (:func:`~.implementation.resolve_implementation`); the estimate records it.
        twist: the rig's ``(w (3,) rad/s, t (3,) m/s)`` in the model's convention (a
            tracker's); None: ``prediction``'s or ``initial_model``'s, if any. Used only for
            the share of the cameras' time offset std
            (:attr:`~rs_localizer.frames.Mounting.time_offset_std`) in the covariance of a
            global-shutter rig frame, whose model has no twist of its own.
    Returns:
        :class:`RSPoseEstimate`: the rig's world -> rig pose at the reference time, its
        velocities (``.pose``: an :class:`~rs_localizer.pose.RSPose`), their covariances, the
        inliers per camera; ``success=False`` with one of :data:`RIG_FAILURE_REASONS` when the
        frame gives no pose.
    Raises:
        ValueError: unknown ``pre_rotation`` or ``implementation``, ``options`` that are not
            :class:`~rs_localizer.estimation.options.EstimateOptions` (whose own constructors
            refuse a setting out of its range, naming it), a gyro that is not a
            :class:`~rs_localizer.estimation.gyro.GyroMeasurement`, no views, a view that is
            not a :class:`View`, a camera without a mounting (``mounting`` None; the
            message names it) or with a mounting that is not a
            :class:`~rs_localizer.frames.Mounting`, mismatched pixel and point counts or
            shapes.
    """
    who = "estimate_rig_pose"
    if len(views) == 0:
        raise ValueError(f"{who}: needs at least one camera")
    options, initial_model = checked_inputs(who, options, RIG_OPTIONS, initial_model, gyro)
    if pre_rotation not in PRE_ROTATIONS:
        raise ValueError(f"{who}: pre_rotation must be one of {PRE_ROTATIONS}: {pre_rotation!r}")
    compiled = resolve_implementation(implementation, None) == COMPILED
    cache: dict = {}  # (each view checked and undistorted once: the consensus solves again)
    max_norm = float(options.plausibility.max_point_norm)
    settings = (options, initial_model, pre_rotation == "gp3p")
    if twist is None:
        known = prediction if prediction is not None else initial_model
        known = getattr(known, "model", known)
        twist = None if known is None else tuple(known)[2:4]

    def stacked(vs: Sequence[View]) -> StackedViews:
        pool = StackedViews(vs, compiled, cache, max_norm)
        pool.twist = twist
        return pool

    def solve(vs: Sequence[View]) -> RSPoseEstimate:
        return _estimate_pool(stacked(vs), settings, gyro, gyro_time)

    pool = stacked(views)
    alone = _one_camera_alone(views, pool, options, initial_model, gyro)
    if alone is not None:
        return alone
    est = _estimate_pool(pool, settings, gyro, gyro_time)
    if not consensus or not est.success:
        return est
    if prediction is None and initial_model is not None:
        prediction = initial_model.model
    threshold_px = options.ransac.threshold_px
    return _consensus(views, pool, est, threshold_px, solve, prediction, verify_cameras)


def _one_camera_alone(
    views: Sequence[View], pool: StackedViews, options: EstimateOptions, initial_model, gyro
) -> RSPoseEstimate | None:
    """A rig frame whose points are all one camera's and too few for the rig's search (fewer
    than ``ransac.min_inliers`` or 7, e.g. one tag's four corners) posed by that camera's
    estimator given its view (:func:`~.estimate.estimate_rs_pose` with ``view``: its
    few-points path, :func:`~.single_tag.few_points_estimate`, one marker's corners or a few
    on more than one plane, the velocities held at the rig's prediction or gyro; the estimate
    the rig's, :func:`~.result.body_estimate`), as one of the rig frame's views
    (:func:`_restored`); None for any other rig frame (or on the NumPy implementation, which
    has no few-points path) or a camera whose points that path does not take."""
    counts = pool.counts()
    with_points = [c for c, n in enumerate(counts) if n]
    # (fewer than the rig solver's sample and one more, or the options' min_inliers)
    need = max(options.ransac.min_inliers, 7)
    if not pool.compiled or len(with_points) != 1 or len(pool.cam) >= need:
        return None
    c = with_points[0]
    if posed_planarity(pool.X[pool.slices[c]]) is None:  # (single_tag.few_points's rule)
        return None
    v = views[c]
    est = estimate_rs_pose(
        v.uv, v.X, v.camera, options=options, initial_model=initial_model, gyro=gyro,
        implementation=COMPILED, view=v,
    )  # fmt: skip
    return _restored(est, pool, c)


def _estimate_pool(pool: StackedViews, settings: tuple, gyro, gyro_time) -> RSPoseEstimate:
    """:func:`estimate_rig_pose` on the stacked views ``pool`` before the cameras' consensus
    (``settings``: its arguments in :class:`_RigStages`' order), the gyro checked
    (:func:`~.driver.gyro_checked_estimate`)."""
    still = len(pool.cam) > 0 and pool.tau_spread <= STILL_SPREAD
    if gyro is None or still or not settings[0].refine.enabled:
        return _estimate(pool, *settings)
    if gyro_time is None:
        gyro_time = 0.5 * (float(pool.tau.min()) + float(pool.tau.max()))
    prior = gyro_prior(gyro, compiled=pool.compiled)
    aided = _RigStages(pool, *settings, prior=prior, gyro_time=gyro_time)
    return gyro_checked_estimate(
        aided, gyro, lambda: _estimate(pool, *settings), pool.compiled
    )  # fmt: skip


def _agreeing(est: RSPoseEstimate, voters: list[int]) -> set[int]:
    """The voting cameras that agree with a solved estimate: inlier ratio at least
    :data:`AGREE_SHARE` times the best voting camera's."""
    return _sharing(est.num_inliers_per_view, est.num_valid_per_view, voters)


def _sharing(hits, valid, voters: list[int]) -> set[int]:
    """The voting cameras c whose share ``hits[c] / valid[c]`` of their valid points is at
    least :data:`AGREE_SHARE` times the best voting camera's, and not 0."""
    ratio = {c: int(hits[c]) / int(valid[c]) for c in voters}  # (float64 quotients, to the bit)
    best = max(ratio.values())
    return {c for c in voters if ratio[c] >= AGREE_SHARE * best and ratio[c] > 0}


def _only(views: Sequence[View], drop: set[int]) -> list[View]:
    """The views with the points of cameras ``drop`` removed (the cameras keep their place)."""
    return [
        View(np.zeros((0, 2)), np.zeros((0, 3)), v.camera, v.mounting, v.stamp_offset, v.name)
        if c in drop
        else v
        for c, v in enumerate(views)
    ]


def _consensus(
    views: Sequence[View],
    pool: StackedViews,
    est: RSPoseEstimate,
    threshold_px: float,
    solve,
    prediction,
    verify: bool = False,
) -> RSPoseEstimate:
    """The cameras' consensus on a solved joint estimate (:func:`estimate_rig_pose`).

    Every camera with at least :data:`VOTE_MIN_POINTS` valid points votes. When all agree with
    the joint estimate (:func:`_agreeing`: the common case, no extra work) it is returned as
    is. Cameras that disagree and are fewer than those that agree are outvoted at once (no
    pose of their own can gather more cameras). Otherwise the rig is solved again
    (``solve``) on the cameras that disagree alone (and the cameras too small to vote): if
    that pose explains none of the agreeing cameras, the two groups contradict each other
    (e.g. a wrong mounting or stamp on one side), and the group of more cameras, on a tie
    the group whose pose is nearer the ``prediction`` (by :data:`PREDICTION_MARGIN`), poses
    the rig; the other group's cameras are
    ``disagreeing``. A tie without a prediction that decides fails as ``cameras_disagree``,
    unless the two groups are near (:func:`_near`): then the joint estimate is returned, its
    covariance widened by the groups' disagreement (:func:`_near_spread`). A tie without a
    prediction is first checked with the joint estimate alone: when one pose fitted from it
    explains every voting camera within the gate (:func:`_one_pose`), the joint estimate is
    returned so, the others solved alone only when it leaves one of them out (for
    :func:`_near_spread`).
    The joint estimate's point count never decides: a camera with most of the points is
    outvoted by two that agree with each other. With a prediction, the cameras whose points
    it explains are checked first (:func:`_by_track`: a track never outvotes more cameras
    than it keeps); with ``verify``, every voting camera is posed alone (:func:`_verified`:
    a wrong stamp on one of two cameras can leave both with a fair share of inliers under a
    joint pose that is wrong, the velocities absorbing part of the time error)."""
    voters = [c for c, n in enumerate(est.num_valid_per_view) if n >= VOTE_MIN_POINTS]
    if len(voters) < 2:
        return est
    if prediction is not None:
        tracked = _by_track(views, pool, est, threshold_px, voters, solve, prediction)
        if tracked is not None:
            return tracked
    if verify:
        checked = _verified(views, pool, est, threshold_px, voters, solve, prediction)
        if checked is not None:
            return checked
    a = _agreeing(est, voters)
    rest = set(voters) - a
    if not rest:
        return est
    if len(a) > len(rest):
        # (the second pose's cameras are among the others, fewer than the agreeing ones,
        # whatever it is: outvoted without solving it)
        return _outvoted(est, pool, rest)
    # as many cameras on each side and no prediction: when one pose fitted from the joint
    # estimate explains every voting camera within the gate (as :func:`_near` accepts), the
    # two groups are near, whatever the others' own pose
    tried = len(a) == len(rest) and prediction is None
    if tried and _one_pose(pool, est, voters, set(voters), threshold_px):
        if set(voters) <= _agreeing(est, voters):
            return est
        other = solve(_only(views, a))
        return _near_spread(est, _restored(other, pool) if other.success else other, voters)
    sub = solve(_only(views, a))
    sub = _restored(sub, pool) if sub.success else sub
    b = _agreeing(sub, voters) if sub.success else set()
    if not b or b & a:
        # the others explain no consistent pose of their own, or one the agreeing cameras
        # share (cameras with many outliers, not a contradiction): outvoted by the joint fit
        return est if b & a else _outvoted(est, pool, rest)
    if len(b) < len(a):  # (outvoted whatever the pose of the second pose's cameras alone)
        return _outvoted(est, pool, rest)
    if b != rest:  # (solved on the cameras that agree with the second pose only)
        sub = solve(_only(views, set(voters) - b))
        if not sub.success:
            return _outvoted(est, pool, rest)
        sub = _restored(sub, pool)
    choice = 0 if len(a) > len(b) else 1 if len(b) > len(a) else None
    if choice is None:
        choice = _by_prediction(pool, est, sub, prediction)
    if choice is None and _near(pool, est, sub, a, b, voters, threshold_px, tried):
        # (a small inconsistency, e.g. a mounting a few tenths of a degree off)
        return _near_spread(est, sub, voters)
    if choice == 0:
        return _outvoted(est, pool, rest)
    if choice == 1:
        return _outvoted(sub, pool, set(voters) - b)
    return _disagree(est, pool, a | b)


def _near_spread(est: RSPoseEstimate, other: RSPoseEstimate, voters) -> RSPoseEstimate:
    """``est``, the joint estimate of two groups of cameras that are near (:func:`_near`),
    with the covariance of their disagreement: when a voting camera does not agree with it
    (:func:`_agreeing`: the fit at the inlier threshold kept one group's points), its model
    covariance plus ``other``'s (the other group's own estimate) plus ``d d^T``, ``d`` the
    step between the two estimates' models (over (delta, C) of the global-shutter model,
    (delta, C, w, t) of the rolling-shutter one), its outputs' covariances derived again.
    Cameras that disagree beyond their noise but within the gate carry an error none of
    them models (a lens model, a tag map or an exposure time a little off), and nothing in
    the rig frame says which group is right, while the pose of one group alone has a
    covariance of that group's points only (docs/rig.md, "Real 4-camera rigs"). ``est``
    unchanged when every voting camera agrees, or either estimate has no covariance."""
    if set(voters) <= _agreeing(est, voters) or not other.success:
        return est
    if est.model_covariance is None or other.model_covariance is None:
        return est
    rolling = est.motion_model != GLOBAL_SHUTTER
    free = 12 if rolling else 6
    R, C, w, t = est.model
    Ro, Co, wo, to = other.model
    d = np.concatenate([matrix_to_rotvec(Ro @ R.T), Co - C, wo - w, to - t])[:free]
    if not np.isfinite(d).all():
        return est
    cov = np.array(est.model_covariance, dtype=float)
    cov[:free, :free] += np.asarray(other.model_covariance)[:free, :free] + np.outer(d, d)
    spr = 1.0 if rolling else 0.0  # (a rig's times are in seconds: StackedViews.spr)
    out = output_covariance(cov, R, C, w, spr, est.implementation != NUMPY)
    return est._replaced(
        model_covariance=cov, covariance=out[0], pose_covariance=out[1],
        twist_covariance=out[2] if est.twist_covariance is not None else None,
    )  # fmt: skip


def _gated(pool: StackedViews, est, voters, gate_px: float, model=None) -> set[int]:
    """The voting cameras whose share of points within ``gate_px`` of ``est``'s pose (or of
    ``model`` ``(R, C, w, t)``) is at least :data:`AGREE_SHARE` times the best voting
    camera's."""
    ok = pool.errors(est.model if model is None else model) < gate_px
    return _sharing(np.bincount(pool.cam[ok], minlength=len(pool.sizes)),
                    est.num_valid_per_view, voters)  # fmt: skip


def _one_pose(pool: StackedViews, est, voters, cams: set, threshold_px: float, start=None) -> bool:
    """Whether one pose fitted from ``start``'s (default ``est``'s) with
    :data:`CONTRADICTION_GATE` inlier thresholds as its threshold, every voting camera weighed
    alike (:func:`_evened`), explains the cameras ``cams`` within that gate (:func:`_gated`,
    ``est`` giving the valid point counts; ``est``'s motion model)."""
    gate = CONTRADICTION_GATE * threshold_px
    free = 6 if est.motion_model == GLOBAL_SHUTTER else 12
    model = (est if start is None else start).model
    fit = refined_model(_evened(pool, voters), model, gate, free == 12)
    return cams <= _gated(pool, est, voters, gate, fit)


def _near(
    pool: StackedViews, first, second, a: set, b: set, voters, threshold_px: float, tried=False
) -> bool:
    """Two groups of cameras ``a`` and ``b`` whose poses (``first``, ``second``) each
    explain the other group's points within :data:`CONTRADICTION_GATE` inlier thresholds, or
    that one pose explains within them (:func:`_refine` from either pose with the gate as
    its threshold, every voting camera weighed alike, :func:`_evened`; a camera of either
    group explained as :func:`_gated` at the gate): a small inconsistency (a mounting or
    lens model a few tenths of a degree or pixels off), not a contradiction (a mounting
    degrees off, a wrong stamp)."""
    gate = CONTRADICTION_GATE * threshold_px
    if b <= _gated(pool, first, voters, gate) and a <= _gated(pool, second, voters, gate):
        return True
    # one pose for both groups, fitted with the gate as its threshold from either group's
    # pose: a group posed alone extrapolates its own uncertainty to the other group's
    # cameras (a camera seeing a few tags), so the other group's points can miss its pose by
    # more than the gate although one pose explains both groups within it; a mounting or
    # stamp that is wrong leaves no such pose. Every voting camera weighs alike in the fit:
    # weighed by its points, a camera of 140 corners holds the fit to its own pose and one
    # of 12 stays beyond the gate where a pose between them explains both within it
    # (``tried``: the fit from ``first`` already failed, :func:`_one_pose`)
    return any(
        _one_pose(pool, first, voters, a | b, threshold_px, start)
        for start in ((second,) if tried else (first, second))
    )


def _evened(pool: StackedViews, voters) -> StackedViews:
    """``pool`` with each voting camera's points repeated so that every voting camera counts
    about as many points as the one with most (``round(most / own)`` copies; the other
    cameras' points once): a least-squares fit on it weighs the voting cameras alike, as
    the cameras' consensus counts cameras, not points. Only for fitting: its rows no longer
    map to the views'."""
    n = pool.counts()
    most = max(n[c] for c in voters)
    copies = [max(1, round(most / n[c])) if c in voters and n[c] else 1 for c in range(len(n))]
    if all(k == 1 for k in copies):
        return pool
    return pool.repeated(copies)


def _by_track(views, pool, est, threshold_px, voters, solve, prediction):
    """The cameras the prediction explains (:data:`PREDICTION_GATE`) against those it does
    not: the estimate of the explained cameras alone with the others ``disagreeing`` when
    those disagree with it too, are no more than the explained ones and, on the
    global-shutter model, are not near them (:func:`_near`), else None (the prediction
    explains every camera, or fewer cameras than it does not, or the cameras it does not
    explain agree with the others or are only a little apart from them: the prediction was
    off for them, and a small inconsistency between cameras is the consensus's to settle,
    not the prediction's)."""
    model = tuple(np.asarray(a, dtype=float) for a in prediction)
    explained = _gated(pool, est, voters, PREDICTION_GATE * threshold_px, model)
    suspect = set(voters) - explained
    if not explained or not suspect or len(explained) < len(suspect):
        return None  # (a track never outvotes more cameras than it keeps)
    kept = est
    if _agreeing(est, voters) != explained:
        sub = solve(_only(views, suspect))
        if not sub.success:
            return None
        kept = _restored(sub, pool)
        agree = _agreeing(kept, voters)
        if not (explained <= agree and not suspect & agree):
            return None
    # (a prediction a degree off explains one fisheye camera's points within its gate and
    # not another's whose own pose is a few tenths of a degree from the first's: not a
    # contradiction it may decide. Only on the global-shutter model: a rolling-shutter
    # pose's twist absorbs a wrong stamp, so that the groups can be near although one's
    # stamp is tens of milliseconds off, which the prediction's twist does tell)
    if kept.motion_model == GLOBAL_SHUTTER:
        own = solve(_only(views, explained))
        if own.success and own.motion_model == GLOBAL_SHUTTER:
            own = _restored(own, pool)
            if _near(pool, kept, own, explained, suspect, voters, threshold_px):
                return None
    return _outvoted(kept, pool, suspect)


def _verified(views, pool, est, threshold_px, voters, solve, prediction):
    """``verify_cameras`` (:func:`estimate_rig_pose`): the estimate of the largest group of
    voting cameras that agree posed alone (two cameras agree when either's own pose explains
    at least :data:`VERIFY_SHARE` of the other's own inliers); on a tie the prediction does
    not break, the joint estimate when the two groups are near (:func:`_near`, as in
    :func:`_consensus`), else ``cameras_disagree``; or None when every camera posed alone
    agrees with the others."""
    M = len(pool.sizes)
    valid = np.asarray(est.num_valid_per_view)
    voting = voters
    voters = [c for c in voters if valid[c] >= VERIFY_MIN_POINTS]
    if len(voters) < 2:
        return None
    inliers = np.asarray(est.num_inliers_per_view, dtype=float)
    if all(inliers[c] >= VERIFY_ALL_EXPLAINED * valid[c] for c in voters):
        return None  # (one pose explains every camera's points: nothing contradicts)
    inl = {}
    for c in voters:
        e = solve(_only(views, set(voters) - {c}))
        if e.success:
            ok = pool.errors(e.model) < threshold_px
            inl[c] = np.bincount(pool.cam[ok], minlength=M)
    cams = list(inl)

    def agree(c, d):
        return inl[c][d] >= VERIFY_SHARE * inl[d][d] or inl[d][c] >= VERIFY_SHARE * inl[c][c]

    groups, seen = [], set()
    for c in cams:  # (connected components of the agreement)
        if c in seen:
            continue
        group, todo = {c}, [c]
        while todo:
            x = todo.pop()
            for d in cams:
                if d not in group and agree(x, d):
                    group.add(d)
                    todo.append(d)
        seen |= group
        groups.append(group)
    if len(groups) < 2:
        return None
    groups.sort(key=len, reverse=True)
    fits = [solve(_only(views, set(voters) - g)) for g in groups[:2]]
    fits = [_restored(f, pool) if f.success else f for f in fits]
    if len(groups[0]) > len(groups[1]):
        choice = 0
    else:
        ok = all(f.success for f in fits)
        choice = _by_prediction(pool, fits[0], fits[1], prediction) if ok else None
        a, b = groups[0], groups[1]
        if choice is None and ok and _near(pool, *fits, a, b, voting, threshold_px):
            return est  # (a small inconsistency, e.g. a mounting a few tenths of a degree off)
    if choice is None or not fits[choice].success:
        return _disagree(est, pool, groups[0] | groups[1])
    return _outvoted(fits[choice], pool, set(voters) - groups[choice])


def _disagree(est: RSPoseEstimate, pool: StackedViews, cams: set[int]) -> RSPoseEstimate:
    """The failure ``cameras_disagree`` of cameras ``cams``, with the joint estimate's per
    camera counts."""
    none, identity = np.zeros(len(pool.cam), dtype=bool), RSModel.identity()
    return replace(
        est, success=False, failure=CAMERAS_DISAGREE, model=identity,
        inliers=np.zeros(len(est.inliers), dtype=bool), inliers_per_view=pool.per_camera(none),
        rmse_px=np.nan, num_behind=0, num_dropped=est.num_dropped - est.num_behind,
        covariance=None, model_covariance=None, acceleration_sensitivity=None,
        disagreeing=tuple(sorted(cams)), pose=RSPose.from_model(identity, 1.0),
        pose_covariance=None, twist_covariance=None,
    )  # fmt: skip


def _restored(est: RSPoseEstimate, pool: StackedViews, view: int | None = None) -> RSPoseEstimate:
    """An estimate on views some of whose points were removed (:func:`_only`), or of the one
    view ``view`` of them (a camera's own estimate, its one view's per-view fields), as one of
    the full views ``pool``: their valid point counts, and no inlier among the removed points
    or in the other views."""
    own = est.inliers_per_view
    if view is not None:
        own = tuple(
            own[0] if c == view else np.zeros(0, dtype=bool) for c in range(len(pool.sizes))
        )
    per = tuple(
        m if len(m) == n else np.zeros(n, dtype=bool) for m, n in zip(own, pool.sizes, strict=True)
    )
    counts = est.num_inliers_per_view
    if view is not None:
        counts = tuple(int(np.count_nonzero(m)) for m in per)
    return est._replaced(
        inliers=_joined(per), inliers_per_view=per, num_valid_per_view=pool.counts(),
        num_inliers_per_view=counts, num_valid=len(pool.cam),
        num_dropped=sum(pool.sizes) - len(pool.cam) + est.num_behind,
    )  # fmt: skip


def _outvoted(est: RSPoseEstimate, pool: StackedViews, cams: set[int]) -> RSPoseEstimate:
    """``est`` with the voting cameras ``cams`` left out: none of their points an inlier."""
    inliers = tuple(
        np.zeros(pool.sizes[c], dtype=bool) if c in cams else np.asarray(m, dtype=bool)
        for c, m in enumerate(est.inliers_per_view)
    )
    per = tuple(0 if c in cams else int(n) for c, n in enumerate(est.num_inliers_per_view))
    return replace(
        est, inliers=_joined(inliers), inliers_per_view=inliers, num_inliers_per_view=per,
        disagreeing=tuple(sorted(cams)),
    )  # fmt: skip


def _joined(per_view: tuple) -> np.ndarray:
    """The views' (N_c,) bool masks as one over the rig frame's rows in order."""
    return np.concatenate(per_view) if per_view else np.zeros(0, dtype=bool)


def _by_prediction(pool: StackedViews, first, second, prediction) -> int | None:
    """0 or 1: the estimate whose pose is nearer the predicted model ``(R, C, ...)`` by
    :data:`PREDICTION_MARGIN` (rotation angle in rad plus the positions' distance over the
    points' median depth), None without a prediction or when neither is."""
    if prediction is None:
        return None
    Rp = np.asarray(prediction[0], dtype=float)
    pp = -Rp.T @ np.asarray(prediction[1], dtype=float)
    depth = float(np.median(np.linalg.norm(pool.X @ first.model.R.T + first.model.C, axis=1)))
    d = []
    for e in (first, second):
        R, C = e.model.R, e.model.C
        ang = np.linalg.norm(matrix_to_rotvec(R @ Rp.T))
        d.append(float(ang + np.linalg.norm(-R.T @ C - pp) / max(depth, 0.1)))
    if d[0] * PREDICTION_MARGIN <= d[1]:
        return 0
    if d[1] * PREDICTION_MARGIN <= d[0]:
        return 1
    return None


#: :func:`~.rig_batch.search_batch`'s subset of no subset (every pool point sampled)
_NO_SUBSET = np.zeros(0, dtype=np.int64)
#: :func:`~.rig_batch.search_batch`'s anchor of none (P3P pre-rotates the samples)
_NO_ANCHOR = np.zeros((0, 3))

#: the models whose errors a search keeps (:meth:`_RigSearch.errors`): the final refinement's
#: candidates and the one it returns
_ERRORS_KEPT = 6


class _RigSearch(RansacLoop):
    """The rig's RANSAC: a :class:`~.ransac.RansacLoop` (the single camera's termination and
    batches) over the rig's minimal samples, its own :class:`~.ransac.RansacEstimator`:
    ``generate_models`` draws 6 points (:meth:`~.view.StackedViews.samples`, or
    :meth:`~.view.StackedViews.uniform_samples` for the generalized P3P) and solves them
    (:func:`_hypotheses`, :func:`_hypotheses_still`), dropping models beyond the velocity
    bounds (``implausible``; a compiled search draws, solves and scores each batch in one
    call, :meth:`_batch`); ``score_models`` is MSAC on every point's reprojection error in
    pixels; ``refine_model`` keeps the model as it is (the rig's local optimization runs
    once, after the search) and gives termination its inlier
    ratio (among the seed's inliers ``subset`` when RANSAC verifies a seed)."""

    #: a compiled batch checks termination after every sample (:mod:`.rig_batch`); the
    #: step-by-step search's batches are the same
    per_sample = True

    def __init__(self, pool, options, still, generalized, prior, anchored, subset, spread=False):
        r = options.ransac
        super().__init__(3 if still else 6, r)
        self.pool, self.still, self.generalized, self.prior = pool, still, generalized, prior
        self.anchored, self.subset = anchored, subset
        self._seed, self._rng = r.seed, None
        self.threshold_px = float(r.threshold_px)
        self.th2 = self.threshold_px**2
        self.solver_iterations = r.solver_iterations or RIG_SOLVER_ITERATIONS
        p = options.plausibility
        self.bounds = (float(p.max_angular_velocity), float(p.max_linear_velocity))
        self._e, self._cost = np.zeros(0), 0.0
        self._costed: list = []
        #: the search's batches: its options (:func:`~.ransac.batch_sizes`, the first no
        #: larger than ``min_iterations``: :attr:`per_sample`)
        self.batches = r
        #: (M,) bool, the cameras of 3 or more points of which the best model explains none
        #: (None: none such): the global-shutter samples with points in them are then also
        #: corrected on them (:func:`_hypotheses_still`); ``spread``: every camera of 3 or
        #: more points, whatever the best model (every sample corrected)
        self.spread = spread
        # (each camera's points in the pool: np.bincount of its cameras)
        counts = pool.counts()
        self._counts = np.array(counts, dtype=np.int64)
        #: the number of cameras with points in the pool
        self.cameras = sum(1 for n in counts if n)
        self.missed = self._counts >= 3 if spread and still else None
        #: each batch drawn, solved and scored in one compiled call (:meth:`_batch`)
        self.fused = not generalized and pool.compiled and (still or prior is None)
        self._w2max, self._v2max = self.bounds[0] ** 2, self.bounds[1] ** 2
        self._no_missed = np.zeros(len(pool.sizes), dtype=bool)
        self._min_it, self._max_it = r.min_iterations, r.max_iterations
        self._args: tuple | None = None  # (:meth:`_batch`'s kernels' arguments)
        self._drawn = 0  # (the seed's random draws the batches took)
        self._out: tuple | None = None  # (:meth:`_batch`'s output buffers)
        self._n, self._missed = 0, self._no_missed

    @property
    def rng(self) -> np.random.Generator:
        """The search's random generator (:func:`~.ransac.seeded_rng`; the compiled search
        reads the same stream from :func:`~.ransac.seeded_stream` instead)."""
        if self._rng is None:
            self._rng = seeded_rng(self._seed)
        return self._rng

    def cost(self, model) -> float:
        """MSAC cost (px^2) of one model on every point (its errors kept for
        :meth:`errors`)."""
        for m, _, cost in self._costed:
            if m is model:  # (the same object, measured again: local optimization's)
                return cost
        e, cost = self.pool.scored(model, self.th2)
        self._kept(model, e, cost)
        return cost

    def _kept(self, model, e: np.ndarray, cost: float) -> None:
        """Keep ``model``'s errors and cost for :meth:`cost` and :meth:`errors`."""
        self._costed = [*self._costed[1 - _ERRORS_KEPT :], (model, e, cost)]

    def errors(self, model) -> np.ndarray:
        """(N,) the reprojection errors (px) of ``model`` on every point: those of one of the
        last :data:`_ERRORS_KEPT` models :meth:`cost` measured when it is one of them (the
        same object: the final refinement compares several)."""
        for m, e, _ in self._costed:
            if m is model:
                return e
        return self.pool.errors(model)

    def generate_models(self, loop: RansacLoop, K: int) -> tuple:
        if self.fused:
            return self._batch(K)
        pool = self.pool
        draw = pool.uniform_samples if self.generalized else pool.samples
        samples = draw(self.rng, K, self.subset)
        p3p = _gp3p_on_rig if self.generalized else None
        if self.still:
            rounds = SPREAD_CORRECTION_ROUNDS if self.spread else 1
            return _hypotheses_still(pool, samples, p3p, self.missed, rounds), K
        anchor = self.best[:2] if self.anchored and self.best is not None else None
        hyp = _hypotheses(
            pool, samples, self.solver_iterations, anchor, self.prior, self.threshold_px, p3p
        )  # fmt: skip
        if hyp is None:
            return None, K
        ok = plausible_motion(None, hyp[1], hyp[2], hyp[3], self.bounds, pool.compiled)
        self.implausible += int(np.count_nonzero(~ok))
        return (tuple(a[ok] for a in hyp) if ok.any() else None), K

    def _batch(self, K: int) -> tuple:
        """``generate_models`` in one compiled call (:func:`~.rig_batch.search_batch`): K
        samples on the seed's next ``7 K`` random draws (:func:`~.ransac.seeded_stream`: those
        :meth:`~.view.StackedViews.samples` takes), solved and scored in turn, the batch
        stopping after the first sample at which termination is reached (a new best's inlier
        ratio counted at once, as PoseLib's loop does after every sample). Returns ``((cost,
        model, errors, inliers, missed cameras) of the batch's best model, or None when none
        beat the best, samples drawn)``."""
        if self._args is None:
            pool, subset = self.pool, self.subset
            X, x, tau, (cam, Rm, cm, A) = pool.kernel_arrays
            self._args = (_NO_SUBSET if subset is None else subset, X, x, tau, cam, Rm, cm, A)
            self._draws = seeded_stream(self._seed, "random", 7 * int(self._max_it))
        # (the kernel reads the batch's draws at their offset in the stream and the search's
        # state as scalars, and returns Python ints and floats)
        o = self._drawn
        self._drawn = o + 7 * K
        # (the batch's best errors, model and missed cameras are written into buffers, new
        # ones after each batch that found a best model: the search keeps that model)
        if self._out is None:
            N, M = len(self.pool.cam), len(self._counts)
            self._out = (np.empty(N), np.empty((3, 3)), np.empty(3), np.zeros(3), np.zeros(3),
                         np.empty(M, dtype=bool))  # fmt: skip
        anchor = _NO_ANCHOR
        if self.anchored and self.best is not None and not self.still:
            anchor = np.ascontiguousarray(self.best[0], dtype=np.float64)
        drawn, h, cost, n, beyond = search_batch(
            self._draws, o, K, *self._args, self.still,
            self._no_missed if self.missed is None else self.missed,
            SPREAD_CORRECTION_ROUNDS if self.spread else 1, anchor, self.solver_iterations,
            self._w2max, self._v2max, self.th2, self.threshold_px, self._counts, self.score,
            self.iterations, self._min_it, self.needed, self._log_miss, self._out,
        )  # fmt: skip
        self.implausible += beyond
        if h < 0:
            return None, drawn
        e, R, C, w, t, missed = self._out
        self._out = None
        return (cost, (R, C, w, t), e, n, missed), drawn

    def score_models(self, hyp: tuple) -> tuple[float, tuple]:
        if self.fused:  # (:meth:`_batch`'s best, scored)
            self._cost, model, self._e, self._n, self._missed = hyp
            return self._cost, model
        h, self._cost, self._e = self.pool.best_scored(*hyp, self.th2)
        return self._cost, tuple(a[h] for a in hyp)

    def refine_model(self, loop: RansacLoop, model: tuple) -> tuple[float, tuple, float]:
        """The model as it is (the rig's local optimization runs after the search), its
        errors and cost kept (:meth:`cost`), and the inlier ratio termination counts on
        (among the seed's inliers ``subset`` when RANSAC verifies a seed); the cameras it
        misses (:func:`~.rig_batch.counted`) correct the next global-shutter samples."""
        pool = self.pool
        if pool.compiled:  # (the compiled errors and cost of :meth:`cost`, to the bit)
            self._kept(model, self._e, self._cost)
        if self.fused:
            n, missed = self._n, self._missed
        elif pool.compiled:
            subset = _NO_SUBSET if self.subset is None else self.subset
            n, missed = counted(self._e, self.threshold_px, pool.cam, self._counts, subset)
        else:  # (the same numbers in NumPy)
            inl = self._e < self.threshold_px
            hit = np.bincount(pool.cam[inl], minlength=len(pool.sizes))
            missed = (self._counts >= 3) & (hit == 0)
            n = np.count_nonzero(inl if self.subset is None else inl[self.subset])
        if self.still and not self.spread:
            self.missed = missed if missed.any() else None
        among = len(self._e) if self.subset is None else len(self.subset)
        return self._cost, model, float(n / among)


def _rig_estimate(
    pool: StackedViews,
    model=None,
    inliers: np.ndarray | None = None,
    outputs=(None, None, None),
    **record,
) -> RSPoseEstimate:
    """The :class:`~.result.RSPoseEstimate` of the stacked views ``pool``
    (:func:`~.result.built_estimate`, the rig's views): of ``model`` ``(R, C, w, t)`` (float64
    arrays, taken, not copied) with the (N_pool,) ``inliers`` and ``outputs`` (the covariance
    (12, 12), the ROS pose and twist blocks), or with ``failure=`` one of
    :data:`RIG_FAILURE_REASONS` (the identity and zeros, no inliers); ``record``: the other
    fields by name."""
    R, C, w, t = RSModel.identity() if model is None else model
    inl = np.zeros(len(pool.cam), dtype=bool) if inliers is None else inliers
    per = pool.per_camera(inl)
    record.setdefault("implementation", COMPILED if pool.compiled else NUMPY)
    return built_estimate(
        record.pop("failure", None),
        RSModel(R, C, w, t),
        RSPose.from_model((R, C, w, t), 1.0, compiled=pool.compiled),
        np.array(inl, dtype=bool) if pool.all_valid else _joined(per),
        len(pool.cam),
        sum(pool.sizes),
        outputs,
        (per, tuple(int(np.count_nonzero(m)) for m in per), pool.counts()),
        solver=RIG_SOLVER,
        **record,
    )


def _estimate(pool: StackedViews, *settings, **kwargs) -> RSPoseEstimate:
    """:func:`estimate_rig_pose` on the stacked views ``pool``: the staged estimator
    (:func:`~.driver.staged_estimate`) on the rig's :class:`_RigStages` (arguments as
    there)."""
    return staged_estimate(_RigStages(pool, *settings, **kwargs))


class _RigStages:
    """A rig frame's stacked views ``pool`` as the staged estimator's
    :class:`~.driver.Stages` (:func:`estimate_rig_pose`'s arguments), with the gyro ``prior``
    (on a rig frame that is not still; :func:`~.gyro.gyro_prior`, the rig's twist with one
    second per unit of tau; ``gyro_time``: s from the rig's reference time when the rig turned
    at the measured rate, for the sensitivity to acceleration) or without one; ``still``: on
    the global-shutter model (True) or not (False) whatever the observations' time spread
    (None: global shutter when they are within :data:`STILL_SPREAD`).

    Its stages: at least 6 points, 3 in one camera, that fix a pose; the initial model's seed
    and :class:`_RigSearch`; :func:`~.local_optimization.polish` with the rig's steps; the
    final refinement of the lowest MSAC cost (:func:`~.finalize.chosen_refinement`,
    :data:`CONTRADICTION_GATE`), its inliers, not on one 3D line, its covariance; the last
    checks and the consistent fit of the cameras that support it (:data:`AGREE_SHARE`).

    A global-shutter search whose final model has fewer than ``ransac.min_inliers`` inliers
    searches again (``spread``) with every sample's P3P models corrected on the sample's six
    points by the rig solver (:func:`_hypotheses_still`, :data:`SPREAD_CORRECTION_ROUNDS`
    rounds), not only those with points in a camera the best model explains none of, and
    with one round: three noisy corners of one small tag give P3P poses 10-30 degrees off,
    one round of the correction leaves them degrees off, and a pose that explains one
    camera's corners alone (or a few of every camera's) then has the lowest cost although a
    pose between the cameras' own explains every corner. A rolling-shutter rig frame without
    a gyro whose estimate fails (``implausible_motion``, ``too_few_inliers``) is posed on the
    global-shutter model when it shows no motion, as a single camera's
    (:func:`~.finalize.still_fallback`): the rig's generalized absolute pose if the
    rolling-shutter model refined from it (:func:`~.finalize.rolling_shutter_check`) finds
    velocities its noise explains, with that refinement's twist covariance (not without the
    refinement, ``options.refine``)."""

    def __init__(
        self,
        pool: StackedViews,
        options: EstimateOptions,
        initial_model,
        generalized: bool,
        prior: MotionPrior | None = None,
        still: bool | None = None,
        spread: bool = False,
        gyro_time: float = 0.0,
    ):
        self.pool, self.options, self.initial_model = pool, options, initial_model
        self.generalized, self.prior, self.still, self.spread = generalized, prior, still, spread
        self.gyro_time = gyro_time
        self.threshold_px = float(options.ransac.threshold_px)
        self.refine = options.refine.enabled
        self.search: _RigSearch | None = None
        self.last = None

    def prepared(self) -> None:
        pool = self.pool
        if len(pool.cam) < 6 or max(pool.counts()) < 3:
            raise EstimationFailed(TOO_FEW_POINTS)
        if pool.degenerate(self.threshold_px):
            raise EstimationFailed(DEGENERATE_GEOMETRY)
        # every observation at one time: the pose alone (generalized P3P samples, w = t = 0)
        if self.still is None:
            self.still = pool.tau_spread <= STILL_SPREAD
        return None

    def searched(self) -> Model:
        pool, still, prior, threshold_px = self.pool, self.still, self.prior, self.threshold_px
        r = self.options.ransac
        free, size = (6, 3) if still else (12, 6)
        explained, anchored, subset, seeded = -1, False, None, None
        if self.initial_model is not None:
            # (tested on every point, pulled onto the explained ones, as a single camera's)
            im = self.initial_model
            # (copies in the prediction's own memory order, which the kernels and BLAS see)
            gate, model = float(im.gate_px), tuple(np.array(a, dtype=float) for a in im.model)
            explained, seeded, anchored = initial_model_seed(
                model, im.min_explained, not still, size, gate,
                *view_seed_steps(pool, threshold_px, gate, free == 12, prior),
            )  # fmt: skip
            n_in = 0 if seeded is None else int(np.count_nonzero(seeded[2]))
            # (its inliers explain the frame, 3 of them in one camera: RANSAC only verifies
            # it, sampling among them)
            need = max(int(im.min_explained), size + 1, 6)
            if n_in >= need and np.bincount(pool.cam[seeded[2]]).max() >= 3:
                subset = np.flatnonzero(seeded[2])
        self.explained, self.seeded = explained, seeded
        self.search = search = _RigSearch(
            pool, self.options, still, self.generalized, prior, anchored, subset, self.spread
        )
        if seeded is not None:
            search.best, search.score = seeded[1], search.cost(seeded[1])
            # (verifying a seed that explains the frame: RANSAC samples among its inliers,
            # whose all-inlier probability is 1, as the single camera's verification)
            search.needed = (
                0.0
                if subset is not None
                else required_iterations(float(np.mean(seeded[2])), size, r.confidence)
            )
        search.search(search, search.batches)
        return search.found()

    def polished(self, model: Model) -> Model:
        # local optimization: the single camera's rounds (polish) with the rig's steps, the
        # rig solver on the inliers and the final refinement's first; on a frame taken at one
        # time (no linear re-solve) its one round is that refinement alone, kept where it
        # lowers the cost
        pool, search, prior, threshold_px = self.pool, self.search, self.prior, self.threshold_px
        best_cost, refine = search.score, self.refine

        def refit(m, inl):
            return [_refit(pool, inl, m, threshold_px, prior=prior)]

        def evaluate(m):
            return search.cost(m), search.errors(m) < threshold_px

        exact = functools.partial(
            refined_model, pool, th=threshold_px, rolling=not self.still, prior=prior
        )
        if self.still:
            last = (model, exact(model)) if refine else None
            if last is not None and search.cost(last[1]) < best_cost:
                model = last[1]
        else:
            best = (best_cost, model, search.errors(model) < threshold_px)
            steps = (refit, exact if refine else None)
            (_, model, _), last = polish(best, evaluate, *steps, LO_ROUNDS, min_inliers=0)
        self.last = last
        return model

    def final(self, model: Model) -> FinalModel:
        pool, search, prior, threshold_px = self.pool, self.search, self.prior, self.threshold_px
        still, refine, last = self.still, self.refine, self.last
        if refine:  # the final refinement, the model of the lowest MSAC cost (chosen_refinement)
            # (local optimization's last refinement is the final one's first, whether it took
            # it, or did not and the model is still the one it started from)
            first = None
            if last is not None and (last[0] is model or last[1] is model):
                first = last[1]
            model = chosen_refinement(
                pool, model, threshold_px, not still, prior, search.cost, search.errors,
                search.cameras, CONTRADICTION_GATE, first,
            )  # fmt: skip
        self.e = e = search.errors(model)
        compiled, rolling = pool.compiled, not still
        # (a camera's final stages with the rig's steps: the inliers and their RMS error, not
        # on one 3D line, the final refinement's Jacobian at the model (no step, as a camera's
        # final refinement gives it: its information, covariance and J^T W D), the last checks
        # on every camera's model, the consistent fit, the outputs)
        copies = RSModel(*(np.array(a, dtype=float) for a in model))
        final = selected_final(pool, copies, threshold_px, self.options.ransac.min_inliers,
                               errors=e)  # fmt: skip
        # (every point an inlier: the pool's points, not collinear, pool.degenerate above)
        inl = final.inliers
        if not inl.all() and collinear_3d(pool.X[inl], compiled=compiled):
            raise EstimationFailed(DEGENERATE_GEOMETRY)
        ref = rate = None
        if refine and np.count_nonzero(inl) > 6:
            ref = frame_refinement(pool, final.model, threshold_px, rolling,
                                   prior if rolling else None, rolling,
                                   max_iterations=0)  # fmt: skip
        if prior is not None:
            rate = (self.gyro_time, prior.information()[3:, 3:])
        return with_covariance(pool, final, ref, threshold_px, rolling, sensitivity=rolling,
                               alone=False, rate_prior=rate, errors=e)  # fmt: skip

    def finished(self, final: FinalModel) -> RSPoseEstimate:
        pool, search, e, threshold_px = self.pool, self.search, self.e, self.threshold_px
        compiled, still = pool.compiled, self.still
        rolling = not still
        behind, out = checked_outputs(
            pool, final, rolling, pool.spr if rolling else 0.0,
            self.options.plausibility.consistent_fit, threshold_px, lambda: e,
            lambda: information_condition(final.information, rolling, compiled),
            pool.view_planar, compiled,
            bounds2=(search._w2max, search._v2max), support_share=AGREE_SHARE,
        )  # fmt: skip
        return _rig_estimate(
            pool,
            final.model,
            final.inliers,
            (None, None, None) if out is None else out,  # (final.model: selected_final's copies)
            failure=None,
            ransac_iterations=search.iterations,
            rmse_px=final.rmse_px,
            num_behind=behind,
            model_covariance=final.covariance,
            motion_model=GLOBAL_SHUTTER if still else ROLLING_SHUTTER,
            acceleration_sensitivity=final.sensitivity,
            initial_explained=self.explained,
            initial_used=self.seeded is not None,
            gyro_used=self.prior is not None,
        )

    def retried(self, failure: EstimationFailed) -> RSPoseEstimate | None:
        pool, still = self.pool, self.still
        if still is None:  # (refused before the time spread was looked at)
            return None
        if still:
            if failure.reason != TOO_FEW_INLIERS or self.spread:
                return None
            # (every sample corrected across the cameras: the class docstring)
            return _estimate(
                pool, self.options, self.initial_model, self.generalized, self.prior, True,
                True, self.gyro_time,
            )  # fmt: skip
        if self.prior is not None or not self.refine:
            return None
        # (a rolling-shutter rig frame that shows no motion: the global-shutter model)
        return still_fallback(
            failure.reason,
            lambda: _estimate(pool, self.options, self.initial_model, self.generalized,
                              still=True),
            pool,
            self.threshold_px,
        )  # fmt: skip

    def failed(self, failure: EstimationFailed) -> RSPoseEstimate:
        iterations = 0 if self.search is None else self.search.iterations
        return _rig_estimate(pool=self.pool, failure=failure.reason,
                             ransac_iterations=iterations, num_behind=failure.behind)  # fmt: skip

    def gyro_evidence(self, est: RSPoseEstimate) -> tuple:
        pool, threshold_px, compiled = self.pool, self.threshold_px, self.pool.compiled
        image = image_alone(pool, est.model, threshold_px, None) if est.success else None

        def planar() -> bool:
            return coplanar(pool.X[pool.errors(est.model) < threshold_px], compiled)

        return image, planar, len(pool.cam)
