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
``w x C - t`` m/s in the rig frame). Camera c's own model is
:func:`~.result.camera_model_of_rig`.

:func:`estimate_rig_pose` runs the single camera's staged estimator
(:func:`~.driver.staged_estimate`) on the rig's stages (:class:`_RigStages`) over the stacked
views (:class:`~.view.StackedViews`), compiled or in NumPy. The rig's own parts: a sample is 3
points of one camera and 3 of any, its P3P poses mapped to the rig pre-rotating the rig solver
(:func:`_hypotheses`; compiled: :mod:`.rig_batch`); MSAC on each point's pixel error in its
camera's distorted image at its own capture time; the final refinement's choice between
cameras whose mountings disagree (:data:`CONTRADICTION_GATE`); the cameras' consensus
(:func:`_consensus`; docs/rig.md, "The cameras' consensus").

A rig frame whose observations were all taken at one time (global-shutter cameras with equal
stamps) does not determine ``w`` and ``t``: the estimate is then the rig's generalized
absolute pose with ``w = t = 0`` and ``motion_model`` ``"global_shutter"``, its P3P poses
corrected across the cameras by the rig solver with the velocities held at zero where the
best model misses a camera (three corners of a small tag leave a pose degrees off).
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
from scipy.sparse.csgraph import connected_components

from ..accuracy import absolute_pose_errors
from ..geometry import matrix_to_rotvec
from ..pose import RSModel, RSPose
from ..solvers.gr6p_1lin import gr6p_1lin_batch
from .degeneracy import coplanar
from .driver import checked_inputs, gyro_checked_estimate, staged_estimate
from .estimate import estimate_rs_pose
from .finalize import (
    GLOBAL_SHUTTER,
    FinalModel,
    checked_outputs,
    chosen_refinement,
    frame_refinement,
    image_alone,
    information_condition,
    posed_estimate,
    refined_model,
    selected_final,
    still_fallback,
    with_covariance,
)
from .frame import Model
from .gyro import GyroMeasurement, gyro_prior
from .hypotheses import (
    anchor_prerotations,
    linear_refit,
    prerotated_models,
    still_models,
)
from .implementation import COMPILED, NUMPY, resolve_implementation
from .local_optimization import initial_model_seed, polish, view_seed_steps
from .numpy_impl import p3p_prerotations
from .options import EstimateOptions, InitialModel, RansacOptions
from .plausibility import collinear_points, collinear_points_numpy, plausible_motion
from .prior import MotionPrior, sample_prior_rows
from .ransac import RansacLoop, SeededShuffle, seeded_stream
from .result import (
    CAMERAS_DISAGREE,
    DEGENERATE_GEOMETRY,
    TOO_FEW_INLIERS,
    TOO_FEW_POINTS,
    EstimationFailed,
    RSPoseEstimate,
    built_estimate,
    per_view_fields,
)
from .rig_batch import search_batch
from .sampling import p3p_mounted
from .single_tag import posed_planarity
from .view import StackedViews, View

__all__ = [
    "AGREE_SHARE",
    "CONTRADICTION_GATE",
    "LO_ROUNDS",
    "PREDICTION_GATE",
    "PREDICTION_MARGIN",
    "RIG_OPTIONS",
    "RIG_SOLVER",
    "SPREAD_CORRECTION_ROUNDS",
    "STILL_SPREAD",
    "VERIFY_MIN_POINTS",
    "VERIFY_SHARE",
    "VOTE_MIN_POINTS",
    "estimate_rig_pose",
]

#: ``RSPoseEstimate.solver`` of a rig's estimate (a rig frame of one camera's few points
#: records that camera's, :func:`_one_camera_alone`)
RIG_SOLVER = "gr6p_1lin"

#: a camera votes in the cameras' consensus with at least this many valid points; cameras
#: with fewer are fitted with every group, never outvoted
VOTE_MIN_POINTS = 8

#: the rig estimator's default options: a camera's (``EstimateOptions()``) with
#: ``min_inliers`` :data:`VOTE_MIN_POINTS` over all cameras, so that the consensus can pose a
#: voting camera of a few points alone
RIG_OPTIONS = EstimateOptions(ransac=RansacOptions(min_inliers=VOTE_MIN_POINTS))

#: the rounds of the held rig solver's correction of a global-shutter sample's P3P pose when
#: a global-shutter search runs again because its model had too few inliers (docs/rig.md)
SPREAD_CORRECTION_ROUNDS = 2

#: local optimization's rounds: the rig's refinement runs on every point until converged, so
#: further rounds seldom move the model (up to 4 changed none of the medians or posed counts
#: of ``python -m benchmarks.bench_rig``, also ``--points 36``, ``--gyro``, and
#: ``benchmarks.bench_rig_rendered``, and made every TagSLAM recording slower)
LO_ROUNDS = 1

#: s: observation times spread by at most this are one time (a global-shutter rig frame)
STILL_SPREAD = 1e-9

#: a voting camera agrees with a model when its inlier ratio is at least this share of the
#: best-fitting voting camera's (docs/rig.md, "The cameras' consensus")
AGREE_SHARE = 0.3

#: inlier thresholds within which two groups of cameras that disagree at the threshold are
#: only a small inconsistency apart, not a contradiction (docs/rig.md; on TagSLAM's test_7
#: two cameras disagreed at 2 px in 30 of 265 rig frames without it, in 4 with it)
CONTRADICTION_GATE = 3.0

#: with a prediction, a voting camera is explained by it when its share of points within
#: this many inlier thresholds of it is at least :data:`AGREE_SHARE` times the best's
PREDICTION_GATE = 3.0

#: ``verify_cameras``: camera d agrees with camera c's own pose when that pose explains at
#: least this share of the inliers d's own pose has
VERIFY_SHARE = 0.5

#: ``verify_cameras``: a camera is posed alone only with at least this many valid points
#: (from 8-12 corners a rolling-shutter pose's velocities fit its noise and miss cameras that
#: agree with the rig: a correct first rig frame was refused)
VERIFY_MIN_POINTS = 20

#: with a prediction, the group of cameras whose pose is nearer to it is chosen when the
#: other group's is at least this many times farther (rotation in rad plus position over
#: the points' median depth)
PREDICTION_MARGIN = 2.0


def _rig_solver(pool: StackedViews, iterations: int, prior: MotionPrior | None = None,
                threshold_px: float = 2.0, held: bool = False):  # fmt: skip
    """The rig's :data:`~.hypotheses.SampleSolver`: the rig solver (each point seen through
    its camera's mounting, ``iterations`` linear steps) with the gyro ``prior``'s rows
    (:func:`~.prior.sample_prior_rows`, one second per unit of tau, the noise half the inlier
    threshold in the sample's first camera's normalized units) or, ``held``, the velocities
    held at zero (prior rows ``(w, t) = 0``)."""

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


def _hypotheses(pool: StackedViews, samples: np.ndarray, iterations: int, anchor=None,
                prior: MotionPrior | None = None, threshold_px: float = 2.0, poses=None,
                missed: np.ndarray | None = None, rounds: int = 1):  # fmt: skip
    """Models (R, C, w, t) of the samples (K, 6), as a camera's samples are solved
    (:func:`~.hypotheses.prerotated_models`): each pre-rotated by its P3P poses mapped to the
    rig (:func:`_p3p_on_rig`; ``poses``: another pre-rotation's, :func:`estimate_rig_pose`'s
    ``pre_rotation``) or by ``anchor`` ``(R, C)`` (an initial model's or the best model's),
    then the rig solver (:func:`_rig_solver`, ``iterations``, the gyro ``prior``'s rows at
    ``threshold_px``), the models not finite dropped. ``iterations`` 0: a
    global-shutter rig frame's P3P poses with ``w = t = 0``, those of samples with points in
    a camera ``missed`` ((M,) bool: the best model explains none of its points) also
    corrected on their 6 points ``rounds`` times by the rig solver with the velocities held
    at zero (:func:`_held_solve`, each round pre-rotated by the previous one's rotation), as a
    generalized P3P would pose them. Returns the H models' arrays, or None."""
    if anchor is not None:
        (R0, C0), S = anchor_prerotations(anchor, len(samples)), samples
    else:
        pre = (_p3p_on_rig if poses is None else poses)(pool, samples)
        if pre is None:
            return None
        R0, C0, own = pre
        S = samples[own]
    if iterations == 0:
        spread = [] if missed is None else np.flatnonzero(missed[pool.cam[S]].any(axis=1))
        if len(spread) == 0:
            return still_models(R0, C0)
        S, Rg = S[spread], R0[spread]
        for _ in range(rounds):
            Rg, Cg, valid = _held_solve(pool, S, Rg)
            if not valid.any():
                return still_models(R0, C0)
            S, Rg, Cg = S[valid], Rg[valid], Cg[valid]
        return still_models(np.concatenate([R0, Rg]), np.concatenate([C0, Cg]))
    solve = _rig_solver(pool, iterations, prior, threshold_px)
    R, C, w, t, ok = prerotated_models(S, R0, C0, pool.x, pool.X, pool.tau, solve, pool.compiled)
    ok &= plausible_motion(None, C, w, t, None, pool.compiled)
    if not ok.any():
        return None
    return R[ok], C[ok], w[ok], t[ok]


def _held_solve(pool: StackedViews, S: np.ndarray, Rg: np.ndarray) -> tuple:
    """The rig solver with the velocities held at zero (one linear step) on the samples ``S``
    (H, 6), pre-rotated by ``Rg`` (H, 3, 3): ``(R (H, 3, 3), C (H, 3), valid (H,))``, as the
    compiled batches correct theirs (:func:`~.batch.prerotated_solutions` ``held``)."""
    solve = _rig_solver(pool, 1, held=True)
    R, C, _, _, ok = prerotated_models(S, Rg, None, pool.x, pool.X, np.zeros(len(pool.X)),
                                       solve, pool.compiled)  # fmt: skip
    return R, C, ok


def _p3p_on_rig(pool: StackedViews, samples: np.ndarray):
    """P3P on each sample's first 3 points, all of one camera, mapped to the rig: ``R = R_c^T
    R_cam`` (H, 3, 3), ``C = R_c^T (C_cam - c_c)`` (H, 3), and the sample of each (H,); None
    when none solved. A sample keeps one pose, as a camera's does: the one of least error on
    its other points through their mountings (:func:`~.sampling.least_error_roots`).
    Compiled: Lambda Twist (:func:`~.sampling.p3p_mounted`); NumPy: OpenCV's, mapped and
    chosen by the function that chooses a camera's (:func:`~.numpy_impl.p3p_prerotations`)."""
    if pool.compiled:  # (solved, mapped and chosen in one compiled call)
        X, x, _, (cam, Rm, cm, _) = pool.kernel_arrays
        R, C, own = p3p_mounted(x, X, samples, cam, Rm, cm)
    else:
        R, C, own = p3p_prerotations(pool.X, pool.x, samples, pool.cam, pool.R_mount,
                                     pool.c_mount)  # fmt: skip
    return (R, C, own) if len(own) else None


def estimate_rig_pose(
    views: Sequence[View],
    options: EstimateOptions | None = None,
    *,
    initial_model: InitialModel | RSModel | tuple | None = None,
    gyro: GyroMeasurement | None = None,
    gyro_time: float | None = None,
    pre_rotation: object = None,
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
            cameras; ``solver_iterations`` None: 3 rig solver steps per sample),
            ``refine.enabled`` (without it the estimate is the rig solver's refit of
            RANSAC's model) and ``plausibility`` (velocity bounds in rad/s and m/s, rows
            beyond ``max_point_norm`` dropped, ``consistent_fit``); its other fields are a
            single camera's alone.
        initial_model: an :class:`~rs_localizer.estimation.InitialModel` (a bare model: the
            default gate) of the rig's predicted ``(R, C, w, t)`` (per second, at the rig's
            reference time), used as a camera's.
        gyro: a :class:`~rs_localizer.estimation.gyro.GyroMeasurement` of the rig's angular
            velocity (rad/s, **rig frame**), used as a camera's (its rows also in every
            sample's rig solve); ignored on a global-shutter rig frame and without ``refine``.
        gyro_time: s from the rig's reference time: the middle of the gyro's window (for the
            ``acceleration_sensitivity``); None: the middle of the observation times.
        pre_rotation: None: RANSAC's samples pre-rotated by P3P on 3 points of one camera
            (Lambda Twist, mapped to the rig); or another pre-rotation for a comparison, an
            object with ``samples(pool, rng, K, subset)`` (K, 6) int64 indices of the stacked
            views (:class:`~.view.StackedViews`; ``subset``: sorted indices to draw among, or
            None) and ``poses(pool, samples)`` as :func:`_p3p_on_rig`'s, each sample's pose
            on its first 3 points (the search then runs step by step:
            ``benchmarks.bench_rig.GeneralizedP3P``, PoseLib's generalized P3P, docs/rig.md).
        prediction: the rig's predicted model that decides between cameras that contradict
            each other (:func:`_consensus`); None: ``initial_model``'s model, if any.
        consensus: check that the cameras with points agree (:func:`_consensus`); False: the
            joint estimate as it is. ``verify_cameras``: also pose every voting camera alone
            and compare (:func:`_verified`), for a rig frame nothing else checks (a track's
            first).
        implementation: ``"compiled"``, ``"numpy"`` or None, as ``estimate_rs_pose``'s.
        twist: the rig's ``(w (3,) rad/s, t (3,) m/s)`` in the model's convention (a
            tracker's); None: ``prediction``'s or ``initial_model``'s, if any. Used only for
            the share of the cameras' time offset std
            (:attr:`~rs_localizer.frames.Mounting.time_offset_std`) in the covariance of a
            global-shutter rig frame, whose model has no twist of its own.
    Returns:
        :class:`RSPoseEstimate`: the rig's world -> rig pose at the reference time, its
        velocities (``.pose``: an :class:`~rs_localizer.pose.RSPose`), their covariances, the
        inliers per camera; ``success=False`` with one of
        :data:`~.result.RIG_FAILURE_REASONS` when the frame gives no pose.
    Raises:
        ValueError: the inputs :func:`~.driver.checked_inputs` refuses, a ``pre_rotation``
            without ``samples`` and ``poses``, an unknown ``implementation``, no views, a view
            that is not a :class:`View`, a camera without a mounting (named) or with a
            mounting that is not a :class:`~rs_localizer.frames.Mounting`, mismatched pixel
            and point counts or shapes.
    """
    who = "estimate_rig_pose"
    if len(views) == 0:
        raise ValueError(f"{who}: needs at least one camera")
    options, initial_model = checked_inputs(who, options, RIG_OPTIONS, initial_model, gyro)
    if pre_rotation is not None and not all(
        callable(getattr(pre_rotation, n, None)) for n in ("samples", "poses")
    ):
        raise ValueError(f"{who}: pre_rotation needs samples and poses: {pre_rotation!r}")
    compiled = resolve_implementation(implementation, None) == COMPILED
    cache: dict = {}  # (each view checked and undistorted once: the consensus solves again)
    max_norm = float(options.plausibility.max_point_norm)
    if prediction is None and initial_model is not None:
        prediction = initial_model.model
    if twist is None and prediction is not None:
        twist = tuple(prediction)[2:4]

    def stacked(vs: Sequence[View]) -> StackedViews:
        pool = StackedViews(vs, compiled, cache, max_norm)
        pool.twist = twist
        pool.shift_share = options.correlated_noise.shift_share
        return pool

    def estimated(pool: StackedViews) -> RSPoseEstimate:
        """The rig frame of ``pool`` before the consensus, the gyro checked as a camera's
        (:func:`~.driver.gyro_checked_estimate`)."""
        stages = _RigStages(pool, options, initial_model, pre_rotation)
        if gyro is None or stages.still or not stages.refine:
            return staged_estimate(stages)
        at = gyro_time
        if at is None:  # (the middle of the observation times)
            at = 0.5 * (float(pool.tau.min()) + float(pool.tau.max()))
        aided = replace(stages, prior=gyro_prior(gyro, compiled=pool.compiled), gyro_time=at)
        return gyro_checked_estimate(aided, gyro, lambda: staged_estimate(stages), pool.compiled)

    def solve(drop: set[int]) -> RSPoseEstimate:
        """The rig frame without the points of cameras ``drop`` (each keeps its place),
        restored to every view (:func:`_restored`) when it is posed."""
        none = {"uv": np.zeros((0, 2)), "X": np.zeros((0, 3)), "groups": None}
        est = estimated(stacked([replace(v, **none) if c in drop else v
                                 for c, v in enumerate(views)]))  # fmt: skip
        return _restored(est, pool) if est.success else est

    pool = stacked(views)
    alone = _one_camera_alone(views, pool, options, initial_model, gyro)
    if alone is not None:
        return alone
    est = estimated(pool)
    if not consensus or not est.success:
        return est
    return _consensus(pool, est, options.ransac.threshold_px, solve, prediction, verify_cameras)


def _one_camera_alone(views: Sequence[View], pool: StackedViews, options: EstimateOptions,
                      initial_model, gyro) -> RSPoseEstimate | None:  # fmt: skip
    """A rig frame whose points are all one camera's and too few for the rig's search (fewer
    than ``ransac.min_inliers`` or 7, e.g. one tag's corners) posed by that camera's
    estimator's few-points path (:func:`~.estimate.estimate_rs_pose` with ``view``,
    :func:`~.single_tag.few_points_estimate`) as one of the rig frame's views; None for any
    other rig frame, on the NumPy implementation or when that path does not take them."""
    with_points = [c for c, n in enumerate(pool.counts()) if n]
    need = max(options.ransac.min_inliers, 7)  # (the rig solver's sample and one more)
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
    return _restored(est, pool, view=c)


class _Vote(NamedTuple):
    """What the cameras' consensus decides on (:func:`_consensus`'s arguments)."""

    pool: StackedViews
    threshold_px: float
    voters: list
    solve: Callable[[set[int]], RSPoseEstimate]
    prediction: tuple | None

    def solved(self, drop: set[int]) -> tuple[RSPoseEstimate, set[int]]:
        """The rig solved without the cameras ``drop`` (``solve``) and the voting cameras
        that agree with it (:func:`_agreeing`; none when it failed)."""
        est = self.solve(drop)
        return est, _agreeing(est, self.voters) if est.success else set()


def _consensus(pool: StackedViews, est: RSPoseEstimate, threshold_px: float, solve, prediction,
               verify: bool = False) -> RSPoseEstimate:  # fmt: skip
    """The cameras' consensus on the solved joint estimate ``est`` (docs/rig.md, "The cameras'
    consensus"): every camera of at least :data:`VOTE_MIN_POINTS` valid points votes. All
    agree (:func:`_agreeing`): ``est``. Fewer disagree than agree: they are outvoted
    (:func:`_restored`). Otherwise the rig is solved (``solve``) without the agreeing cameras
    and the two groups are decided (:func:`_decided`): by their number of cameras (never of
    points), on a tie by the ``prediction``, else the joint estimate when they are near
    (:func:`_near`; first tried from ``est`` alone, :func:`_one_pose`), its covariance widened
    by the groups' disagreement (:func:`_near_spread`), or ``cameras_disagree``. With a
    prediction the cameras it explains are checked first (:func:`_by_track`); with
    ``verify`` every voting camera is posed alone (:func:`_verified`: a wrong stamp can leave
    two cameras a fair share of inliers under a joint pose that is wrong)."""
    voters = [c for c, n in enumerate(est.num_valid_per_view) if n >= VOTE_MIN_POINTS]
    if len(voters) < 2:
        return est
    v = _Vote(pool, threshold_px, voters, solve, prediction)
    if prediction is not None:
        tracked = _by_track(v, est)
        if tracked is not None:
            return tracked
    if verify:
        checked = _verified(v, est)
        if checked is not None:
            return checked
    a = _agreeing(est, voters)
    rest = set(voters) - a
    if not rest:
        return est
    if len(a) > len(rest):  # (outvoted whatever the others' own pose: not solved)
        return _restored(est, pool, rest)
    tried = len(a) == len(rest) and prediction is None
    sub, b = v.solved(a)
    if tried and _one_pose(v, est, set(voters)):  # (a tie one pose from ``est`` explains)
        return _near_spread(est, sub)
    if b & a:  # (a pose the agreeing cameras share: cameras with outliers, no contradiction)
        return est
    if not b or len(b) < len(a):  # (no consistent pose of their own, or fewer cameras)
        return _restored(est, pool, rest)
    if b != rest:  # (solved on the cameras that agree with the second pose only)
        sub = solve(set(voters) - b)
        if not sub.success:
            return _restored(est, pool, rest)
    out = _decided(v, est, (est, sub), (a, b), set(voters), tried)
    return _near_spread(est, sub) if out is est else out


def _near_spread(est: RSPoseEstimate, other: RSPoseEstimate) -> RSPoseEstimate:
    """``est``, the joint estimate of two groups of cameras that are near (:func:`_near`) and
    that leaves a voting camera out (the fit at the inlier threshold kept one group's points),
    with the covariance of their disagreement: its model covariance plus ``other``'s (the
    other group's own estimate) plus ``d d^T``, ``d`` the step between the two estimates'
    models (over (delta, C) of the global-shutter model, (delta, C, w, t) of the
    rolling-shutter one), its outputs' covariances derived again
    (:meth:`~.result.RSPoseEstimate._with_model_covariance`). Cameras that disagree beyond
    their noise but within the gate carry an error none of them models (a lens model, a tag
    map or an exposure time a little off), and nothing in the rig frame says which group is
    right, while the pose of one group alone has a covariance of that group's points only
    (docs/rig.md, "Real 4-camera rigs"). ``est`` unchanged when ``other`` failed or either
    estimate has no covariance."""
    if not other.success or est.model_covariance is None or other.model_covariance is None:
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
    # (a rig's times are in seconds: StackedViews.spr)
    return est._with_model_covariance(cov, 1.0 if rolling else 0.0)


def _decided(v: _Vote, est, fits, groups, cams: set, tried=False) -> RSPoseEstimate:
    """Two groups of cameras ``groups`` that contradict each other, each posed by its
    estimate in ``fits`` (:func:`_consensus`, :func:`_verified`): the fit of the group of
    more cameras, on a tie the one nearer the ``prediction`` (:func:`_by_prediction`), the
    other cameras of ``cams`` outvoted; else ``est`` when the groups are near (:func:`_near`,
    ``tried`` as there), or ``cameras_disagree`` (also when the chosen fit failed)."""
    a, b = groups
    ok = all(f.success for f in fits)
    choice = 0 if len(a) > len(b) else 1 if len(b) > len(a) else None
    if choice is None and ok:
        choice = _by_prediction(v.pool, *fits, v.prediction)
        if choice is None and _near(v, *fits, a, b, tried):
            return est  # (a small inconsistency, e.g. a mounting a few tenths of a degree off)
    if choice is None or not fits[choice].success:
        return _disagree(est, v.pool, a | b)
    return _restored(fits[choice], v.pool, cams - groups[choice])


def _agreeing(est: RSPoseEstimate, voters, pool=None, gate_px=0.0, model=None) -> set[int]:
    """The voting cameras whose share of their valid points among ``est``'s inliers (with
    ``pool``: within ``gate_px`` of ``est``'s pose, or of ``model`` ``(R, C, w, t)``) is at
    least :data:`AGREE_SHARE` times the best voting camera's, and not 0."""
    hits = est.num_inliers_per_view
    if pool is not None:
        hits = pool.counts(pool.errors(est.model if model is None else model) < gate_px)
    valid = est.num_valid_per_view
    ratio = {c: int(hits[c]) / int(valid[c]) for c in voters}  # (float64 quotients, to the bit)
    best = max(ratio.values())
    return {c for c in voters if ratio[c] >= AGREE_SHARE * best and ratio[c] > 0}


def _one_pose(v: _Vote, est, cams: set, start=None) -> bool:
    """Whether one pose fitted from ``start``'s (default ``est``'s) with
    :data:`CONTRADICTION_GATE` inlier thresholds as its threshold, every voting camera weighed
    alike (:func:`_evened`; ``est``'s motion model), explains the cameras ``cams`` within that
    gate (:func:`_agreeing`)."""
    gate, start = CONTRADICTION_GATE * v.threshold_px, est if start is None else start
    fit = refined_model(_evened(v.pool, v.voters), start.model, gate,
                        est.motion_model != GLOBAL_SHUTTER)  # fmt: skip
    return cams <= _agreeing(est, v.voters, v.pool, gate, fit)


def _near(v: _Vote, first, second, a: set, b: set, tried=False) -> bool:
    """Two groups of cameras ``a`` and ``b`` whose poses (``first``, ``second``) each explain
    the other group's points within :data:`CONTRADICTION_GATE` inlier thresholds, or that one
    pose fitted from either explains within them (:func:`_one_pose`; ``tried``: the fit from
    ``first`` already failed): a small inconsistency (a mounting or lens model a few tenths
    of a degree or pixels off), not a contradiction (a mounting degrees off, a wrong stamp)."""
    gate, pool, voters = CONTRADICTION_GATE * v.threshold_px, v.pool, v.voters
    if b <= _agreeing(first, voters, pool, gate) and a <= _agreeing(second, voters, pool, gate):
        return True
    # (a group posed alone extrapolates its own uncertainty to the other group's cameras, so
    # their points can miss its pose by more than the gate although one pose explains both
    # groups within it; a wrong mounting or stamp leaves no such pose)
    return any(
        _one_pose(v, first, a | b, start) for start in ((second,) if tried else (first, second))
    )


def _evened(pool: StackedViews, voters) -> StackedViews:
    """``pool`` with each voting camera's points repeated ``round(most / own)`` times, so that
    a least-squares fit weighs the voting cameras alike, as the consensus counts cameras, not
    points (a camera of 140 corners would hold the fit to its own pose against one of 12)."""
    n = pool.counts()
    most = max(n[c] for c in voters)
    copies = [max(1, round(most / n[c])) if c in voters and n[c] else 1 for c in range(len(n))]
    return pool if all(k == 1 for k in copies) else pool.repeated(copies)


def _by_track(v: _Vote, est) -> RSPoseEstimate | None:
    """The cameras the prediction explains (:data:`PREDICTION_GATE`) against those it does
    not: the estimate of the explained cameras alone with the others outvoted when those
    disagree with it too, are no more than the explained ones and, on the global-shutter
    model, are not near them (:func:`_near`: a prediction a degree off can miss one fisheye
    camera and not another a few tenths of a degree from it; a rolling-shutter pose's twist
    can absorb a wrong stamp, which the prediction's twist tells); else None."""
    pool, voters, solve = v.pool, v.voters, v.solve
    model = tuple(np.asarray(a, dtype=float) for a in v.prediction)
    explained = _agreeing(est, voters, pool, PREDICTION_GATE * v.threshold_px, model)
    suspect = set(voters) - explained
    if not explained or not suspect or len(explained) < len(suspect):
        return None  # (a track never outvotes more cameras than it keeps)
    kept = est
    if _agreeing(est, voters) != explained:
        kept, agree = v.solved(suspect)  # (none agree with a failed solve)
        if not (explained <= agree and not suspect & agree):
            return None
    if kept.motion_model == GLOBAL_SHUTTER:
        own = solve(explained)
        near = own.success and own.motion_model == GLOBAL_SHUTTER
        if near and _near(v, kept, own, explained, suspect):
            return None
    return _restored(kept, pool, suspect)


def _verified(v: _Vote, est) -> RSPoseEstimate | None:
    """``verify_cameras``: every voting camera of :data:`VERIFY_MIN_POINTS` points posed
    alone; two agree when either's own pose explains at least :data:`VERIFY_SHARE` of the
    other's own inliers; the largest group that agrees poses the rig, a tie decided as the
    consensus decides one (:func:`_decided`); None when they all agree."""
    valid = np.asarray(est.num_valid_per_view)
    checked = [c for c in v.voters if valid[c] >= VERIFY_MIN_POINTS]
    if len(checked) < 2:
        return None
    inliers = np.asarray(est.num_inliers_per_view, dtype=float)
    if all(inliers[c] >= 0.95 * valid[c] for c in checked):
        # (one pose explains every camera's points: nothing contradicts, and a camera posed
        # alone extrapolates its velocities to cameras looking elsewhere)
        return None
    inl = {}
    for c in checked:
        e = v.solve(set(checked) - {c})
        if e.success:
            inl[c] = v.pool.counts(v.pool.errors(e.model) < v.threshold_px)
    cams = list(inl)
    agree = [[inl[c][d] >= VERIFY_SHARE * inl[d][d] for d in cams] for c in cams]
    n, label = connected_components(np.array(agree), directed=False)  # (c, d or d, c)
    if n < 2:
        return None
    groups = [{c for c, g in zip(cams, label, strict=True) if g == k} for k in range(n)]
    groups.sort(key=len, reverse=True)
    fits = [v.solve(set(checked) - g) for g in groups[:2]]
    return _decided(v, est, fits, groups[:2], set(checked))


def _disagree(est: RSPoseEstimate, pool: StackedViews, cams: set[int]) -> RSPoseEstimate:
    """The failure ``cameras_disagree`` of cameras ``cams``, built as every failure is (no fit:
    :class:`~.result.RSPoseEstimate`) with what the joint fit ``est`` found before the cameras
    were found to disagree: its search's record, the gyro's check, its inliers per camera."""
    none = tuple(np.zeros(n, dtype=bool) for n in pool.sizes)
    return built_estimate(
        CAMERAS_DISAGREE, None, None, none, pool.counts(), sum(pool.sizes), solver=est.solver,
        ransac_iterations=est.ransac_iterations, timings=est.timings,
        implementation=est.implementation, ignored_inputs=est.ignored_inputs,
        gyro_rejected=est.gyro_rejected, gyro_rejection=est.gyro_rejection,
        gyro_chi2=est.gyro_chi2, num_inliers_per_view=est.num_inliers_per_view,
        disagreeing=tuple(sorted(cams)),
    )  # fmt: skip


def _restored(est: RSPoseEstimate, pool: StackedViews, out=(), view: int | None = None,
              **changes) -> RSPoseEstimate:  # fmt: skip
    """An estimate of views some of whose points were removed, or of the one view ``view``
    (a camera's own estimate), as one of the full views ``pool``: their valid point counts,
    its inliers per view counted again, none among the removed points, in the other views or
    in the views ``out``, and the fields ``changes`` by name (also over those). The voting
    cameras ``out`` are those the consensus outvoted: ``disagreeing`` (unless ``changes``
    names them)."""
    own = est.inliers_per_view
    if view is not None:
        own = tuple(
            own[0] if c == view else np.zeros(0, dtype=bool) for c in range(len(pool.sizes))
        )
    per = tuple(
        m if c not in out and len(m) == n else np.zeros(n, dtype=bool)
        for c, (m, n) in enumerate(zip(own, pool.sizes, strict=True))
    )
    fields = per_view_fields(per, pool.counts(), sum(pool.sizes), est.num_behind)
    return est._replaced(**(fields | {"disagreeing": tuple(sorted(out))} | changes))


def _by_prediction(pool: StackedViews, first, second, prediction) -> int | None:
    """0 or 1: the estimate whose pose is nearer the predicted model ``(R, C, ...)`` by
    :data:`PREDICTION_MARGIN` (the rotation angle in rad plus the positions' distance over the
    points' median depth, of :func:`~rs_localizer.accuracy.absolute_pose_errors`), None
    without a prediction or when neither is."""
    if prediction is None:
        return None
    depth = float(np.median(np.linalg.norm(pool.X @ first.model.R.T + first.model.C, axis=1)))
    a, b, p = (RSPose.from_model(m, 0.0) for m in (first.model, second.model, prediction))
    err = absolute_pose_errors([a.orientation, b.orientation], [a.position, b.position],
                               [p.orientation] * 2, [p.position] * 2)  # fmt: skip
    d = np.radians(err["rot_deg"]) + err["pos_m"] / max(depth, 0.1)
    if d[0] * PREDICTION_MARGIN <= d[1]:
        return 0
    return 1 if d[1] * PREDICTION_MARGIN <= d[0] else None


#: :func:`~.rig_batch.search_batch`'s subset of no subset (every pool point sampled)
_NO_SUBSET = np.zeros(0, dtype=np.int64)
#: :func:`~.rig_batch.search_batch`'s anchor of none (P3P pre-rotates the samples)
_NO_ANCHOR = np.zeros((0, 3))


class _RigSearch(RansacLoop):
    """The rig's :class:`~.ransac.RansacEstimator` on the single camera's
    :class:`~.ransac.RansacLoop`: samples of :meth:`~.view.StackedViews.samples` (or another
    ``pre_rotation``'s, :func:`estimate_rig_pose`) solved by :func:`_hypotheses` (compiled
    without a gyro, a batch drawn, solved and scored in one call, :meth:`_batch`), MSAC on
    every point's error in pixels; ``refine_model`` keeps the model (local optimization runs
    after the search), its inlier ratio among the seed's inliers ``subset`` when RANSAC
    verifies a seed."""

    def __init__(self, stages: _RigStages):
        pool, still, spread, prior, r = (stages.pool, stages.still, stages.spread, stages.prior,
                                         stages.options.ransac)  # fmt: skip
        super().__init__(3 if still else 6, r)
        self.pool, self.still, self.prior, hook = pool, still, prior, stages.pre_rotation
        # (the samples and their P3P poses: in one camera, or another pre-rotation's)
        self.draw = pool.samples if hook is None else functools.partial(hook.samples, pool)
        self.poses = None if hook is None else hook.poses
        self.spread = spread
        self.rng = SeededShuffle(r.seed)  # (the generator built on use)
        self.threshold_px = float(r.threshold_px)
        self.th2 = self.threshold_px**2
        self.solver_iterations = r.solver_iterations or 3
        p = stages.options.plausibility
        self.bounds = (float(p.max_angular_velocity), float(p.max_linear_velocity))
        self._w2max, self._v2max = self.bounds[0] ** 2, self.bounds[1] ** 2
        self._e, self._cost, self._costed = np.zeros(0), 0.0, []
        self.batches = r  # (:func:`~.ransac.batch_sizes` of the options)
        self._counts = np.array(pool.counts(), dtype=np.int64)
        self.cameras = int(np.count_nonzero(self._counts))  # (the cameras with points)
        #: (M,) bool, the cameras of 3 or more points the best model explains none of (None:
        #: none), whose global-shutter samples are corrected (:func:`_hypotheses`)
        self.missed = self._counts >= 3 if spread and still else None
        self.fused = hook is None and pool.compiled and (still or prior is None)
        self._no_missed = np.zeros(len(pool.sizes), dtype=bool)
        # (:meth:`_batch`'s kernels' arguments, the draws they took, its output buffers)
        self._args, self._drawn, self._out = None, 0, None
        self._n, self._missed = 0, self._no_missed

    def cost(self, model) -> float:
        """MSAC cost (px^2) of one model on every point (its errors kept for :meth:`errors`)."""
        for m, _, cost in self._costed:
            if m is model:  # (the same object, measured again: local optimization's)
                return cost
        e, cost = self.pool.scored(model, self.th2)
        self._kept(model, e, cost)
        return cost

    def _kept(self, model, e: np.ndarray, cost: float) -> None:
        self._costed = [*self._costed[-5:], (model, e, cost)]  # (the final refinement's 5)

    def errors(self, model) -> np.ndarray:
        """(N,) the errors (px) of ``model`` on every point, those :meth:`cost` kept when it is
        one of the last 6 models it measured (the same object)."""
        for m, e, _ in self._costed:
            if m is model:
                return e
        return self.pool.errors(model)

    def generate_models(self, loop: RansacLoop, K: int) -> tuple:
        if self.fused:
            return self._batch(K)
        pool, poses = self.pool, self.poses
        samples = self.draw(self.rng.generator(), K, self.subset)
        if self.still:
            rounds = SPREAD_CORRECTION_ROUNDS if self.spread else 1
            return _hypotheses(pool, samples, 0, poses=poses, missed=self.missed,
                               rounds=rounds), K  # fmt: skip
        anchor = self.best[:2] if self.anchored and self.best is not None else None
        hyp = _hypotheses(pool, samples, self.solver_iterations, anchor, self.prior,
                          self.threshold_px, poses)  # fmt: skip
        if hyp is None:
            return None, K
        ok = plausible_motion(None, hyp[1], hyp[2], hyp[3], self.bounds, pool.compiled)
        self.implausible += int(np.count_nonzero(~ok))
        return (tuple(a[ok] for a in hyp) if ok.any() else None), K

    def _batch(self, K: int) -> tuple:
        """``generate_models`` in one compiled call (:func:`~.rig_batch.search_batch`): K
        samples on the seed's next ``7 K`` random draws, solved and scored as a camera's batch
        is (the pre-test on a random order of the points, the seed's draws after the
        samples'). Returns ``((cost, model, errors, inliers, missed cameras) of the batch's
        best model, or None when none beat the best, K)``."""
        pool = self.pool
        if self._args is None:
            subset, N, n_draws = self.subset, len(pool.cam), 7 * int(self.batches.max_iterations)
            X, x, tau, (cam, Rm, cm, A) = pool.kernel_arrays
            self._args = (_NO_SUBSET if subset is None else subset, X, x, tau, cam, Rm, cm, A)
            stream = seeded_stream(self.rng.seed, "random", n_draws + N)
            self._draws = stream[:n_draws]
            self._order = np.argsort(stream[n_draws:], kind="stable")
        o = self._drawn
        self._drawn = o + 7 * K
        # (a batch that found a best model wrote it into these buffers: the search keeps them)
        if self._out is None:
            N, M = len(pool.cam), len(self._counts)
            self._out = (np.empty(N), np.empty((3, 3)), np.empty(3), np.zeros(3), np.zeros(3),
                         np.empty(M, dtype=bool))  # fmt: skip
        anchor = _NO_ANCHOR
        if self.anchored and self.best is not None and not self.still:
            anchor = np.ascontiguousarray(self.best[0], dtype=np.float64)
        h, cost, n, beyond = search_batch(
            self._draws[o : o + 7 * K].reshape((7, K)), *self._args, self._order, self.still,
            self._no_missed if self.missed is None else self.missed,
            SPREAD_CORRECTION_ROUNDS if self.spread else 1, anchor, self.solver_iterations,
            *self.bounds, self.th2, self.threshold_px, self._counts, self.score,
            self.pretest_points, self.pretest_min(len(pool.cam)), self._out,
        )  # fmt: skip
        self.implausible += beyond
        if h < 0:
            return None, K
        e, R, C, w, t, missed = self._out
        self._out = None
        return (cost, (R, C, w, t), e, n, missed), K

    def score_models(self, hyp: tuple) -> tuple[float, tuple]:
        if self.fused:  # (:meth:`_batch`'s best, scored)
            self._cost, model, self._e, self._n, self._missed = hyp
            return self._cost, model
        h, self._cost, self._e = self.pool.best_scored(*hyp, self.th2)
        return self._cost, tuple(a[h] for a in hyp)

    def refine_model(self, loop: RansacLoop, model: tuple) -> tuple[float, tuple, float]:
        pool = self.pool
        if pool.compiled:  # (the compiled errors and cost of :meth:`cost`, to the bit)
            self._kept(model, self._e, self._cost)
        if self.fused:  # (the batch's count of them, :func:`~.rig_batch.counted`)
            n, missed = self._n, self._missed
        else:
            inl = self._e < self.threshold_px
            missed = (self._counts >= 3) & (np.array(pool.counts(inl)) == 0)
            n = np.count_nonzero(inl if self.subset is None else inl[self.subset])
        if self.still and not self.spread:
            self.missed = missed if missed.any() else None
        self.count = int(np.count_nonzero(self._e < self.threshold_px))
        among = len(self._e) if self.subset is None else len(self.subset)
        return self._cost, model, float(n / among)


@dataclass
class _RigStages:
    """A rig frame's stacked views ``pool`` as the staged estimator's :class:`~.driver.Stages`
    (:func:`estimate_rig_pose`'s arguments), with the gyro ``prior`` (one second per unit of
    tau; ``gyro_time``: s from the rig's reference time) or without; ``still``: the
    global-shutter model or not (None: points whose observation times lie within
    :data:`STILL_SPREAD`).
    Second ways: a global-shutter search whose model has too few inliers runs again with every
    sample's P3P poses corrected across the cameras (``spread``: a pose between the cameras'
    own can explain every corner where each P3P pose explains one camera's); a rolling-shutter
    rig frame without a gyro that shows no motion, on the global-shutter model."""

    pool: StackedViews
    options: EstimateOptions
    initial_model: InitialModel | None
    pre_rotation: object = None
    prior: MotionPrior | None = None
    still: bool | None = None
    spread: bool = False
    gyro_time: float = 0.0

    def __post_init__(self) -> None:
        self.threshold_px = float(self.options.ransac.threshold_px)
        self.refine = self.options.refine.enabled
        self.search: _RigSearch | None = None
        self.last = None
        self.t_start = time.perf_counter()
        self.timings: dict[str, float] = {}  # (stage -> s, a camera's keys)
        if self.still is None:
            self.still = bool(len(self.pool.cam)) and self.pool.tau_spread <= STILL_SPREAD

    def prepared(self) -> None:
        pool = self.pool
        if len(pool.cam) < 6 or max(pool.counts()) < 3:
            raise EstimationFailed(TOO_FEW_POINTS)
        if pool.degenerate(np.ones(len(pool.X), dtype=bool), self.threshold_px, pool.compiled):
            raise EstimationFailed(DEGENERATE_GEOMETRY)
        self.timings["prepare"] = time.perf_counter() - self.t_start

    def searched(self) -> Model:
        pool, still, im = self.pool, self.still, self.initial_model
        self.search = search = _RigSearch(self)
        self.initial_used = False
        if im is not None:  # (as a single camera's: tested on every point)
            # (copies in the prediction's own memory order, which the kernels and BLAS see)
            gate, model = float(im.gate_px), tuple(np.array(a, dtype=float) for a in im.model)
            explained, seed, anchored = initial_model_seed(
                model, im.min_explained, not still, search.s, gate,
                *view_seed_steps(pool, self.threshold_px, gate, not still, self.prior),
            )  # fmt: skip
            if seed is not None:  # (scored as the search scores: its errors kept)
                seed, self.initial_used = (search.cost(seed[1]), *seed[1:]), True
            # (its inliers explain the frame, 3 of them in one camera: RANSAC only verifies
            # it, sampling among them, whose all-inlier probability is 1)
            need = max(int(im.min_explained), search.s + 1, 6)
            search.seeded((explained, seed, anchored), lambda inl: np.count_nonzero(inl) >= need
                          and np.bincount(pool.cam[inl]).max() >= 3)  # fmt: skip
        t0 = time.perf_counter()
        search.search(search, search.batches)
        self.timings["ransac"] = time.perf_counter() - t0
        return search.found()

    def polished(self, model: Model) -> Model:
        # (the single camera's rounds with the rig's steps, the rig solver on the inliers and
        # the final refinement's first; on a frame taken at one time that refinement alone,
        # kept where it lowers the cost)
        pool, search, prior, threshold_px = self.pool, self.search, self.prior, self.threshold_px
        exact = functools.partial(refined_model, pool, th=threshold_px, rolling=not self.still,
                                  prior=prior)  # fmt: skip

        def refit(m, inl):  # (a camera's linear step with the rig solver, 10 steps, twice)
            idx = np.flatnonzero(inl)
            if len(idx) < 6:
                return [m]
            solve = _rig_solver(pool, 10, prior, threshold_px)
            fit = linear_refit(idx, m[0], m[1], pool.x, pool.X, pool.tau, solve, rounds=2)
            return [m if fit is None else fit]

        def evaluate(m):
            return search.cost(m), search.errors(m) < threshold_px

        t0 = time.perf_counter()
        best = (search.score, model, search.errors(model) < threshold_px)
        steps = (None if self.still else refit, exact if self.refine else None)
        (_, model, _), self.last = polish(best, evaluate, *steps, LO_ROUNDS, min_inliers=0)
        self.timings["local_optimization"] = time.perf_counter() - t0
        return model

    def final(self, model: Model) -> FinalModel:
        pool, search, prior, threshold_px = self.pool, self.search, self.prior, self.threshold_px
        rolling, refine, last = not self.still, self.refine, self.last
        t0 = time.perf_counter()
        if refine:  # the final refinement, the model of the lowest MSAC cost
            # (local optimization's last refinement is the final one's first, whether it took
            # it or the model is still the one it started from)
            first = last[1] if last and (last[0] is model or last[1] is model) else None
            model = chosen_refinement(
                pool, model, threshold_px, rolling, prior, search.cost, search.errors,
                search.cameras, CONTRADICTION_GATE, first,
            )  # fmt: skip
        self.e = e = search.errors(model)
        # (a camera's final stages: the inliers, not on one 3D line, the final refinement's
        # Jacobian at the model, its covariance)
        copies = RSModel(*(np.array(a, dtype=float) for a in model))
        final = selected_final(pool, copies, threshold_px, self.options.ransac.min_inliers,
                               errors=e)  # fmt: skip
        inl = final.inliers
        collinear = collinear_points if pool.compiled else collinear_points_numpy
        if not inl.all() and collinear(pool.X, inl):
            raise EstimationFailed(DEGENERATE_GEOMETRY)
        ref, rate = None, None if prior is None else (self.gyro_time, prior.information()[3:, 3:])
        if refine and np.count_nonzero(inl) > 6:
            ref = frame_refinement(pool, final.model, threshold_px, rolling,
                                   prior if rolling else None, rolling,
                                   max_iterations=0)  # fmt: skip
        out = with_covariance(pool, final, ref, threshold_px, rolling, sensitivity=rolling,
                              alone=False, rate_prior=rate, errors=e)  # fmt: skip
        self.timings["refine"] = time.perf_counter() - t0
        return out

    def finished(self, final: FinalModel) -> RSPoseEstimate:
        pool, search, e, threshold_px = self.pool, self.search, self.e, self.threshold_px
        rolling = not self.still
        behind, out = checked_outputs(
            pool, final, rolling, pool.spr if rolling else 0.0,
            self.options.plausibility.consistent_fit, threshold_px, lambda: e,
            lambda: information_condition(final.information, rolling, pool.compiled),
            pool.view_planar, pool.compiled,
            bounds2=(search._w2max, search._v2max), support_share=AGREE_SHARE,
        )  # fmt: skip
        return posed_estimate(
            final, RSPose.from_model(final.model, 1.0, compiled=pool.compiled),
            (pool.per_camera(final.inliers), pool.counts(), sum(pool.sizes)), out, behind,
            rolling, search.iterations, (search.explained, self.initial_used),
            self.prior is not None, pool.compiled, solver=RIG_SOLVER,
            motion_prior_used=self.prior is not None,  # (the gyro's: MAP, as a camera's)
            timings=self.timings | {"total": time.perf_counter() - self.t_start},
        )  # fmt: skip

    def retried(self, failure: EstimationFailed) -> RSPoseEstimate | None:
        if self.still:
            if failure.reason != TOO_FEW_INLIERS or self.spread:
                return None
            return staged_estimate(replace(self, spread=True))
        if self.prior is not None or not self.refine:
            return None

        def again() -> RSPoseEstimate:  # (a frame that shows no motion: the global-shutter model)
            return staged_estimate(replace(self, still=True))

        return still_fallback(failure.reason, again, self.pool, self.threshold_px)

    def failed(self, failure: EstimationFailed) -> RSPoseEstimate:
        pool, iterations = self.pool, 0 if self.search is None else self.search.iterations
        none = np.zeros(len(pool.cam), dtype=bool)  # (as a camera's: the identity, no inlier)
        return failure.estimate(
            pool.per_camera(none), pool.counts(), sum(pool.sizes), solver=RIG_SOLVER,
            ransac_iterations=iterations, implementation=COMPILED if pool.compiled else NUMPY,
            timings=self.timings | {"total": time.perf_counter() - self.t_start},
        )  # fmt: skip

    def gyro_evidence(self, est: RSPoseEstimate) -> tuple:
        pool, th = self.pool, self.threshold_px
        image = image_alone(pool, est.model, th, None) if est.success else None

        def planar() -> bool:
            return coplanar(pool.X[pool.errors(est.model) < th], pool.compiled)

        return image, planar, len(pool.cam)
