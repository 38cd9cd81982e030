"""Robust rolling-shutter pose estimation: RANSAC + local optimization + refinement.

Entry point: :func:`estimate_rs_pose` (in the spirit of PoseLib's ``estimate_absolute_pose``).
"""

from __future__ import annotations

import functools
import inspect
import time
from dataclasses import dataclass, field

import numpy as np

from .._so3 import compose_rotvec
from ..camera import CameraModel
from ..geometry import camera_position, rotvec_to_matrix
from ..solvers import p3p_batch, r6p
from ..solvers.kernels import kernel_ids
from ..solvers.registry import BATCHED, GLOBAL_SHUTTER, SOLVER_NAMES, sample_size, solver_info
from .batch import fused_kernels, nonminimal_solve, prerotated_batch, ransac_batch
from .degeneracy import PLANAR_TOLERANCE, condition_number, planarity
from .noise_model import correlated_noise_covariance, pixel_jacobians
from .outputs import final_inliers, output_covariance_kernel, physical_velocities_kernel
from .plausibility import (
    CHEIRALITY,
    IMPLAUSIBLE_MOTION,
    degenerate_points,
    final_model_check,
    finite_model,
    motion_bounds,
    plausible_motion,
)
from .prior import MotionPrior, prior_conflict, sample_prior_rows
from .refine import exact_errors, posterior_step, refine_rs_pose
from .sampling import (
    draw_samples,
    gather_prerotated,
    second_prerotations,
    select_prerotations,
    valid_rows,
)
from .scoring import errors2, msac_evaluate, msac_scores
from .sensitivity import acceleration_sensitivity

__all__ = [
    "SOLVERS",
    "EstimateOptions",
    "InitialModel",
    "MotionPrior",
    "RSPoseEstimate",
    "estimate_rs_pose",
    "physical_velocities",
    "sample_size",
]

#: solver names (:data:`rs_localizer.solvers.registry.SOLVERS` holds what is known of each)
SOLVERS = SOLVER_NAMES

#: The final refinement fits every point within this many inlier thresholds (Huber loss with
#: scale = the threshold, truncated here and re-selected at each iteration), not only RANSAC's
#: inliers: a fit on the points inside the threshold alone is a 2-sigma-truncated least
#: squares and doubled the angular-velocity error at RS speed 1 (0.49 % against the 0.24 %
#: of the maximum-likelihood fit on the true inliers; ``test/test_ml_accuracy.py``).
FINAL_CUTOFF = 2.0
#: The final refinement stops when an accepted step lowers the cost by less than this fraction
#: (steps of a few hundredths of the parameters' standard deviation): the velocities then
#: agree with those at 1e-10 to 1e-4 of the ML fit's spread (RS speed 0.5 and 1), with 4-5
#: cost evaluations instead of 6-8
FINAL_TOL = 1e-6
#: RANSAC and local optimization score points at their measured capture times
#: (:func:`.scoring.measured_error2`, the refinement's residual) instead of at the capture
#: row predicted by the first-order model (:func:`.scoring.project_error2`)
SCORE_AT_MEASURED_TIME = True


@dataclass(frozen=True)
class EstimateOptions:
    """Options of :func:`estimate_rs_pose`.

    Attributes:
        threshold_px: inlier threshold on the RS reprojection error (pixels).
        max_iterations / min_iterations: RANSAC iteration bounds (hypothesis samples).
        confidence: adaptive termination confidence in (0, 1).
        min_inliers: fewest inliers for success (at least the solver's sample size).
        seed: RNG seed (deterministic for a fixed seed).
        refine: run nonlinear least-squares refinement on the exact constant-velocity model.
        solver_iterations: linear iterations of the iterative 6-point solvers on RANSAC's
            minimal samples; ``None``: 1 for ``r6p_1lin`` (after the P3P pre-rotation one
            iteration is as good as R6P, paper Fig. 6) and 5 for the alternating solvers
            (paper default; they need them). Local optimization runs at least 2 (it starts
            from the current best rotation, so v is tiny and the [w]x[v]x term it fixes is
            second order).
        nonminimal: local optimization re-runs the RS solver on all inliers (else only the
            exact-model refinement polishes a new best).
        lo_refine_iterations: LM iterations of each local optimization round.
        lo_max_points: local optimization works on a random subset of this many points.
        batch_size: samples of the first batch solved at once by the batched solvers; each
            next batch doubles, but no batch draws more samples than adaptive termination
            still asks for.
        local_optimization_steps: maximum local optimization rounds per new best.
        prosac_growth: with scores, the sampling pool reaches all points after this many
            hypotheses (it starts at the best-scored ``2 * sample size``).
        max_point_norm: 3D points farther than this from the origin (m) are dropped as
            points at infinity.
        pretest_points: T(d,d)-style pre-test size: a hypothesis with fewer than half the
            inliers the best model predicts among this many (shuffled) points is rejected
            early. 0 disables it.
        motion_prior: Gaussian prior on the camera's velocities
            (:class:`~rs_localizer.estimation.prior.MotionPrior`, default 3 rad/s and
            1.5 m/s, zero mean), used where one frame cannot determine them: on
            planar scenes (coplanar 3D points) local optimization and the refinement are
            maximum a posteriori and the hypotheses use damped solves; on other scenes the
            final maximum-likelihood refinement is followed by a MAP one unless the data
            conflict with the prior (a camera much faster than it allows) or the prior would
            move the velocities by less than a tenth of their standard deviation (see
            :func:`_final_refinement`). The covariance then includes the prior. With
            ``MotionPrior(always=True)`` (e.g. a tracker's prediction) it is used on every
            frame. ``None``: maximum likelihood everywhere.
        max_angular_velocity: rad/s; models whose camera turns faster are implausible: they
            score as having no inliers in RANSAC and local optimization, and a final model
            beyond it fails with ``implausible_motion``. ``inf`` disables the bound. Not
            applied with global-shutter timing (``camera.seconds_per_unit_r == 0``).
        max_linear_velocity: m/s (map units per second), the same for the camera's speed.
        acceleration_sensitivity: also return how the estimate moves per unit of angular and
            linear acceleration during the readout
            (:func:`rs_localizer.estimation.sensitivity.acceleration_sensitivity`, ~30 us;
            needs ``refine`` and a rolling shutter; the video filter uses it).
        correlated_noise_px: standard deviation (px, per image axis) of a spatially
            correlated image error (lens-model residue, corner bias, a board that is not flat)
            on top of the white noise the refinement estimates; the covariance becomes that
            of the same estimate under both (:mod:`.noise_model`; the estimate is unchanged).
            ``0``: white noise only (default). Estimate it with
            :func:`~rs_localizer.estimation.noise_model.fit_correlated_noise` on still
            calibration views. Costs O(N^2) in the inliers: ~1 ms at 54 points, ~13 ms at
            300, ~90 ms at 1000 (one core, the covariance step alone).
        correlated_noise_length_px: its correlation length (px, > 0).

    Raises:
        ValueError: a velocity bound that is not > 0 (NaN included), a negative or non-finite
            ``correlated_noise_px`` or a ``correlated_noise_length_px`` that is not > 0.
    """

    threshold_px: float = 2.0
    max_iterations: int = 1000
    min_iterations: int = 20
    confidence: float = 0.9999
    min_inliers: int = 12
    seed: int = 0
    refine: bool = True
    solver_iterations: int | None = None
    nonminimal: bool = True
    batch_size: int = 32
    local_optimization_steps: int = 4
    lo_refine_iterations: int = 5
    lo_max_points: int = 150
    prosac_growth: int = 200
    max_point_norm: float = 1e6
    pretest_points: int = 24
    motion_prior: MotionPrior | None = MotionPrior()
    max_angular_velocity: float = 20.0
    max_linear_velocity: float = 50.0
    acceleration_sensitivity: bool = False
    correlated_noise_px: float = 0.0
    correlated_noise_length_px: float = 100.0

    def __post_init__(self):
        for name in ("max_angular_velocity", "max_linear_velocity"):
            if not float(getattr(self, name)) > 0:
                raise ValueError(f"{name} must be > 0 (inf: no bound), got {getattr(self, name)!r}")
        if not (np.isfinite(self.correlated_noise_px) and self.correlated_noise_px >= 0):
            raise ValueError(
                f"correlated_noise_px must be finite and >= 0, got {self.correlated_noise_px!r}"
            )
        if not (
            np.isfinite(self.correlated_noise_length_px) and self.correlated_noise_length_px > 0
        ):
            raise ValueError(
                f"correlated_noise_length_px must be finite and > 0, got "
                f"{self.correlated_noise_length_px!r}"
            )


@dataclass(frozen=True)
class InitialModel:
    """A predicted model for :func:`estimate_rs_pose` (e.g. from the previous frames of a
    video, :class:`rs_localizer.estimation.tracker.RSTracker`).

    The model is first tested as a hypothesis: the points within ``gate_px`` of it are counted
    ("explained"). If at least ``min_explained`` are, it is pulled onto them (robust
    Levenberg-Marquardt), becomes RANSAC's first hypothesis, and its rotation, then the best
    model's, pre-rotates every minimal sample instead of a P3P pose (paper sec. 4 uses P3P for
    that pre-rotation; any rotation within a few degrees serves, Fig. 6); when it then explains
    at least ``min_explained`` points within the threshold, RANSAC samples only among those
    (a verification, as LO-RANSAC's inner sampling). Otherwise the estimator runs exactly as
    without it.

    Attributes:
        R (3, 3), C (3,): world -> camera at the reference row (``X_cam = R X + C``).
        w, t (3,): model velocities per unit RS coordinate (as ``RSPoseEstimate.w``, ``t``).
        gate_px: distance (px) within which a point counts as explained.
        min_explained: fewest explained points to use the model.
    """

    R: np.ndarray
    C: np.ndarray
    w: np.ndarray = field(default_factory=lambda: np.zeros(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gate_px: float = 20.0
    min_explained: int = 0


@dataclass(frozen=True)
class RSPoseEstimate:
    """Result of :func:`estimate_rs_pose`. Frames: world/map, camera optical frame (REP 103).

    Attributes:
        success: a pose was found with at least ``min_inliers`` inliers.
        failure: reason code when not successful, else ``None``: ``too_few_points`` (fewer
            valid rows than ``min_inliers``), ``no_hypothesis`` (no sample gave a model),
            ``too_few_inliers``, ``degenerate_geometry`` (the points, or the inliers, are
            identical or on one 3D line, or their pixels lie within the inlier threshold of
            one image line), ``planar_scene`` (a solver that cannot work on coplanar points,
            R9P, given a planar scene), ``implausible_motion`` (the best model, or every
            hypothesis, moves faster than ``max_angular_velocity`` / ``max_linear_velocity``),
            ``cheirality`` (an inlier of the best model is not in front of the camera at its
            capture time).
        solver: solver name used.
        R, C: (3, 3), (3,) world -> camera at the reference row: ``X_cam = R X + C``.
        w, t: (3,) model velocities per unit RS coordinate (rad, m per normalized unit).
        orientation, position: (3, 3), (3,) camera -> world rotation (``R^T``) and camera
            centre in the world (m).
        angular_velocity, linear_velocity: (3,) camera's own velocity in its optical frame
            (rad/s, m/s).
        angular_velocity_world, linear_velocity_world: (3,) the same in the world frame.
        inliers: (N,) bool over the input rows (invalid rows are False).
        num_valid: rows that passed validation (finite, undistortable, within
            ``max_point_norm``); num_behind: valid rows behind the camera at their capture
            time under the final model (0 without one); num_dropped: rows not used, those
            that failed validation plus ``num_behind``.
        ransac_iterations: hypotheses drawn. timings: stage -> seconds.
        covariance: (12, 12) over (rotation of the camera in the world [rad, world axes],
            position [m, world], angular velocity [rad/s, camera frame], linear velocity [m/s,
            camera frame]), or ``None``.
        pose_covariance: (6, 6) ROS order (x, y, z, rot x, rot y, rot z), world frame.
        twist_covariance: (6, 6) ROS order (vx, vy, vz, wx, wy, wz), camera frame.
        rmse_px: RMS reprojection error of the inliers (pixels).
        planar: the inliers' 3D points are coplanar (:func:`~.degeneracy.planarity` below
            :data:`~.degeneracy.PLANAR_TOLERANCE`): the per-frame RS model is near-degenerate
            and the velocities (and the rotation they trade against) lean on the motion prior.
        planarity: that thickness-to-extent ratio of the inliers' 3D points (NaN on failure).
        condition_number: unit-free condition number of the data's information matrix of the
            refined parameters (:func:`~.degeneracy.condition_number`; NaN without
            refinement): ~5-300 on 3D scenes, 1e4-1e6 on planar ones.
        motion_prior_used: the final refinement was maximum a posteriori (see
            ``EstimateOptions.motion_prior``); on planar frames the velocities, and the
            rotation they trade against, lean on the prior.
        initial_explained: points within ``InitialModel.gate_px`` of the initial model (-1
            without one; failed estimates do not report it); initial_used: the initial model
            seeded RANSAC and pre-rotated its samples (False: too few points explained, the
            estimator ran as without it).
        acceleration_sensitivity: (12, 6) first-order change of (rotation, position, angular
            velocity, linear velocity) per (angular acceleration [rad/s^2], linear acceleration
            [m/s^2]) during the readout, camera frame; only with
            ``EstimateOptions.acceleration_sensitivity``, else ``None``.
    """

    success: bool
    failure: str | None = None
    solver: str = ""
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    C: np.ndarray = field(default_factory=lambda: np.zeros(3))
    w: np.ndarray = field(default_factory=lambda: np.zeros(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))
    orientation: np.ndarray = field(default_factory=lambda: np.eye(3))
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    angular_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    linear_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    angular_velocity_world: np.ndarray = field(default_factory=lambda: np.zeros(3))
    linear_velocity_world: np.ndarray = field(default_factory=lambda: np.zeros(3))
    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    num_valid: int = 0
    num_dropped: int = 0
    num_behind: int = 0
    ransac_iterations: int = 0
    timings: dict = field(default_factory=dict)
    covariance: np.ndarray | None = None
    pose_covariance: np.ndarray | None = None
    twist_covariance: np.ndarray | None = None
    rmse_px: float = float("nan")
    planar: bool = False
    planarity: float = float("nan")
    condition_number: float = float("nan")
    motion_prior_used: bool = False
    initial_explained: int = -1
    initial_used: bool = False
    acceleration_sensitivity: np.ndarray | None = None

    @property
    def num_inliers(self) -> int:
        return int(np.count_nonzero(self.inliers))


# ------------------------------------------------------------------------------------ solvers
def _hypothesis_iterations(solver: str, opts) -> int:
    """Linear iterations per minimal sample (see ``EstimateOptions.solver_iterations``)."""
    if opts.solver_iterations is not None:
        return int(opts.solver_iterations)
    return solver_info(solver).default_iterations or 1


def _batched_rs(solver: str, xs, Xs, rs, r0, iterations, prior_rows=None):
    """Run a solver's batched kernels on K pre-rotated samples; returns a list of RSBatch (2
    for the joined solver). R6P, with a variable number of roots, goes through
    :func:`_r6p_hypotheses`. ``prior_rows`` (P (K, 6, 6), q (K, 6)) go to the kernels that take
    them (damped solves for w and t, :func:`rs_localizer.solvers.r6p_1lin_batch`)."""
    info = solver_info(solver)
    if info.hypotheses != BATCHED:
        raise ValueError(f"solver {solver!r} has no batched kernel")
    return [
        fn(xs, Xs, rs, r0, iterations=iterations, prior_rows=prior_rows)
        if prior_rows is not None and _takes_prior_rows(fn)
        else fn(xs, Xs, rs, r0, iterations=iterations)
        for fn in info.batch
    ]


@functools.cache
def _takes_prior_rows(fn) -> bool:
    """The batched kernel ``fn`` accepts ``prior_rows`` (a damped linear solve)."""
    return "prior_rows" in inspect.signature(fn).parameters


def _prior_rows(fr: _Frame, opts, Xs, C0):
    """Linearized motion-prior rows for K pre-rotated samples (``Xs`` (K, n, 3), their P3P
    translations ``C0`` (K, 3)) when the frame asks for damped hypothesis solves (planar scene,
    prior on; see :func:`estimate_rs_pose`), else None. The rows are weighted as if the image
    noise were half the inlier threshold."""
    if not fr.regularize:
        return None
    return sample_prior_rows(fr.prior, Xs, C0, fr.spr, 0.5 * opts.threshold_px / fr.f)


# ---------------------------------------------------------------------------- the estimator
class _Frame:
    """Validated, normalized correspondences of one frame. ``spr``: the camera's seconds per
    unit r; ``planar``: the 3D points are coplanar; ``prior``: the motion prior of local
    optimization and refinement (None: maximum likelihood); ``regularize``: hypotheses use it
    too (planar scene); ``motion_bounds``: the velocity bounds per unit r
    (:func:`~rs_localizer.estimation.plausibility.motion_bounds`) that :func:`_evaluate`
    enforces."""

    spr = 0.0
    planar = False
    prior = None
    regularize = False
    motion_bounds = None

    def __init__(self, x, X, r, r0e, r0, d, f):
        self.x, self.X, self.r, self.r0e, self.r0, self.d, self.f = x, X, r, r0e, r0, d, f

    @property
    def bearings(self):
        """(N, 3) unit rays of the normalized points (for P3P), computed once."""
        if not hasattr(self, "_bearings"):
            b = np.concatenate([self.x, np.ones((len(self.x), 1))], axis=1)
            self._bearings = b / np.linalg.norm(b, axis=1, keepdims=True)
        return self._bearings


def _hypothesis_arrays(batches, R_pre):
    """Stack RSBatch results (pre-rotated by R_pre per sample) into rotation/velocity arrays."""
    Rs = [compose_rotvec(np.ascontiguousarray(b.v), R_pre) for b in batches]
    if len(batches) == 1:
        b = batches[0]
        return (
            Rs[0],
            np.ascontiguousarray(b.C),
            np.ascontiguousarray(b.w),
            np.ascontiguousarray(b.t),
            b.valid,
        )
    return (
        np.concatenate(Rs),
        np.concatenate([b.C for b in batches]),
        np.concatenate([b.w for b in batches]),
        np.concatenate([b.t for b in batches]),
        np.concatenate([b.valid for b in batches]),
    )


def _p3p_prerotations(fr: _Frame, samples, th2=None):
    """P3P on the first 3 points of every sample; the solution with the lowest global-shutter
    error on the sample's other points is the pre-rotation (paper sec. 4, "P3P as initial
    estimate"). Returns (R (K, 3, 3), C (K, 3), ok (K,)).

    With ``th2`` (squared inlier threshold, normalized; planar frames) each sample whose
    runner-up P3P solution scores close to the best (the planar two-fold ambiguity,
    :func:`~.sampling.second_prerotations`: within 2x the best squared error plus a quarter
    of ``th2``, i.e. half the threshold, per point) is repeated with it: returns
    (samples (K', s), R, C, ok) with K' >= K."""
    first3 = samples[:, :3]
    R, C, owner = p3p_batch(fr.bearings.take(first3, axis=0), fr.X.take(first3, axis=0))
    sel = select_prerotations(R, C, owner, samples, fr.X, fr.x, len(samples))
    if th2 is None:
        return sel
    R2, C2, kept = second_prerotations(
        R,
        C,
        owner,
        samples,
        fr.X,
        fr.x,
        len(samples),
        2.0,
        0.25 * th2 * max(samples.shape[1] - 3, 1),
    )
    kept &= sel[2]
    return (
        np.concatenate([samples, samples[kept]]),
        np.concatenate([sel[0], R2[kept]]),
        np.concatenate([sel[1], C2[kept]]),
        np.concatenate([sel[2], kept[kept]]),
    )


def _draw_samples(rng, pool: int, s: int, K: int) -> np.ndarray:
    """K samples of s distinct indices from range(pool), from the seeded ``rng``."""
    return draw_samples(rng.random((K, s)), pool)


def _required_iterations(inlier_ratio: float, s: int, confidence: float) -> float:
    if inlier_ratio <= 0:
        return np.inf
    p = inlier_ratio**s
    if p >= 1:
        return 0
    return np.log(1 - confidence) / np.log1p(-p)


def _generate(fr: _Frame, solver: str, samples, opts: EstimateOptions, R_pre=None):
    """Hypotheses (R, C, w, t, valid) from a batch of samples (on planar frames also from the
    samples' runner-up P3P pre-rotations, see :func:`_p3p_prerotations`). ``R_pre`` (3, 3),
    if given, pre-rotates every sample of an RS solver instead of its P3P pose (and ``C_p``,
    the linearization point of the motion prior's rows, is ``C_pre``)."""
    kind = solver_info(solver).hypotheses
    if R_pre is not None and kind != GLOBAL_SHUTTER:
        R_pre, C_pre = R_pre
        R_p = np.ascontiguousarray(np.broadcast_to(R_pre, (len(samples), 3, 3)))
        C_p = np.ascontiguousarray(np.broadcast_to(C_pre, (len(samples), 3)))
        ok_p = np.ones(len(samples), dtype=bool)
    elif fr.planar and kind != GLOBAL_SHUTTER:
        samples, R_p, C_p, ok_p = _p3p_prerotations(fr, samples, (opts.threshold_px / fr.f) ** 2)
    else:
        R_p, C_p, ok_p = _p3p_prerotations(fr, samples)
    if kind == GLOBAL_SHUTTER:
        z = np.zeros((len(samples), 3))
        return R_p, C_p, z, z.copy(), ok_p
    xs, Xs, rs = gather_prerotated(samples, R_p, fr.x, fr.X, fr.r)
    if kind != BATCHED:
        return _r6p_hypotheses(fr, samples, Xs, R_p, ok_p)
    batches = _batched_rs(
        solver,
        xs,
        Xs,
        rs,
        fr.r0,
        _hypothesis_iterations(solver, opts),
        _prior_rows(fr, opts, Xs, C_p),
    )
    Rs, Cs, ws, ts, ok = _hypothesis_arrays(batches, R_p)
    ok &= np.tile(ok_p, len(batches))
    return Rs, Cs, ws, ts, ok


def _r6p_hypotheses(fr: _Frame, samples, Xs, R_p, ok_p):
    """Every real root of R6P for each sample whose P3P pre-rotation succeeded (a variable
    number per sample), composed with that sample's pre-rotation."""
    R_all, C_all, w_all, t_all = [], [], [], []
    for k in np.flatnonzero(ok_p):
        try:
            roots = r6p(fr.x[samples[k]], Xs[k], fr.r[samples[k]], fr.r0)
        except ValueError:  # degenerate sample
            continue
        for sol in roots:
            R_all.append(rotvec_to_matrix(sol.v) @ R_p[k])
            C_all.append(sol.C), w_all.append(sol.w), t_all.append(sol.t)
    n = len(R_all)
    return (
        np.array(R_all).reshape(n, 3, 3),
        np.array(C_all).reshape(n, 3),
        np.array(w_all).reshape(n, 3),
        np.array(t_all).reshape(n, 3),
        np.ones(n, dtype=bool),
    )


def _nonminimal(fr: _Frame, solver: str, inl, R, opts: EstimateOptions, C=None):
    """Local optimization: the RS solver on all inliers, pre-rotated by the current R (with
    the current C, the linearization point of the motion prior's rows on planar frames).

    R6P (minimal only) uses R6P_{v,C,w,t}^{[v]x} here; P3P has no RS local optimization."""
    n_inl = int(inl.sum())
    if not solver_info(solver).rolling or n_inl < 6:
        return []
    names = [
        name if n_inl >= sample_size(name) else "r6p_1lin"
        for name in solver_info(solver).lo_solvers
    ]
    ids = [kernel_ids(name) for name in names]
    # one numba call (gather, solve) unless the solve is damped by the motion prior
    if not fr.regularize and all(k is not None and len(k) == 1 for k in ids):
        ok, Rs, Cs, ws, ts = nonminimal_solve(
            np.array([k[0][0] for k in ids], dtype=np.int64),
            np.array([k[0][1] for k in ids], dtype=np.int64),
            np.array([k[0][2] for k in ids], dtype=np.int64),
            inl,
            np.ascontiguousarray(R),
            fr.x,
            fr.X,
            fr.r,
            fr.r0,
            max(_hypothesis_iterations(solver, opts), 2),
        )
        return [(Rs[j], Cs[j], ws[j], ts[j]) for j in range(len(ids)) if ok[j]]
    Xr = fr.X[inl] @ R.T
    out = []
    for name in names:
        rows = None if C is None else _prior_rows(fr, opts, Xr[None], np.asarray(C)[None])
        b = _batched_rs(
            name,
            fr.x[inl][None],
            Xr[None],
            fr.r[inl][None],
            fr.r0,
            max(_hypothesis_iterations(solver, opts), 2),
            rows,
        )[0]
        if b.valid[0]:
            out.append((rotvec_to_matrix(b.v[0]) @ R, b.C[0], b.w[0], b.t[0]))
    return out


def _evaluate(fr: _Frame, model, th2, errors=None):
    """(MSAC score, inlier mask) of one model (R, C, w, t) on all points of the frame;
    ``(inf, all False)`` for a model with non-finite parameters or implausible motion
    (``fr.motion_bounds``). ``errors``: the model's (N,) squared errors at every point when
    they are at hand (:func:`errors2` as scored; finite parameters), instead of computing
    them again."""
    R, C, w, t = (np.ascontiguousarray(a, dtype=np.float64) for a in model)
    if fr.motion_bounds is not None and not plausible_motion(R, C, w, t, fr.motion_bounds):
        return np.inf, np.zeros(len(fr.x), dtype=bool)
    if errors is not None:
        return float(np.minimum(errors, th2).sum()), errors < th2
    sc, inl, _ = msac_evaluate(fr.x, fr.X, fr.r0e, fr.d, R, C, w, t, th2, SCORE_AT_MEASURED_TIME)
    return sc, inl


def _local_optimization(
    fr: _Frame, solver: str, best, best_score, best_inl, th2, opts: EstimateOptions
):
    """LO step of LO-RANSAC on a new best hypothesis (with its MSAC score and inlier mask).

    The first round re-solves with the (nonminimal) RS solver on the hypothesis's inliers,
    pre-rotated by its rotation. Every round then runs a few Levenberg-Marquardt iterations of
    the exact model on all points with a truncated Huber loss (points beyond twice the
    threshold are ignored, so the inlier set is re-selected at every iteration; the linear
    solvers alone fit the linearized model, which is biased on fast motion). Later rounds do
    not re-run the linear solver: starting from an exact-model fit it never won (0 of 80
    second rounds at RS speed 0.5 and 1.0). Rounds continue while the MSAC score improves and
    the inlier set grows (at most ``opts.local_optimization_steps``). P3P only gets the
    global-shutter refinement. Returns (score, (R, C, w, t), inlier mask).
    """
    th = np.sqrt(th2)
    rolling = solver_info(solver).rolling
    # the frame's points are shuffled: its first M points are a random subset (LO-RANSAC's
    # bounded inner sample); the final refinement uses every inlier
    M = min(len(fr.x), max(opts.lo_max_points, 2 * sample_size(solver)))
    sub = _Frame(fr.x[:M], fr.X[:M], fr.r[:M], fr.r0e[:M], fr.r0, fr.d, fr.f)
    sub.spr, sub.planar, sub.prior, sub.regularize = fr.spr, fr.planar, fr.prior, fr.regularize
    tau = sub.r - sub.r0
    for step in range(opts.local_optimization_steps):
        n_before = int(np.count_nonzero(best_inl))
        if n_before < 6:
            break
        start, start_score, start_inl = best, best_score, best_inl
        for cand in (
            _nonminimal(sub, solver, best_inl[:M], best[0], opts, best[1])
            if opts.nonminimal and step == 0
            else []
        ):
            sc, inl = _evaluate(fr, cand, th2)
            if sc < start_score:
                start, start_score, start_inl = cand, sc, inl
        ref = refine_rs_pose(
            *start,
            sub.X,
            sub.x,
            tau,
            th,
            rolling_shutter=rolling,
            max_iterations=opts.lo_refine_iterations,
            covariance=False,
            cutoff=2.0 * th,
            prior=fr.prior,
            seconds_per_unit_r=fr.spr,
        )
        cand = (ref.R, ref.C, ref.w, ref.t)
        sc, inl = _evaluate(fr, cand, th2)
        if sc < start_score:
            start, start_score, start_inl = cand, sc, inl
        if start_score >= best_score:
            break
        best, best_score, best_inl = start, start_score, start_inl
        if int(np.count_nonzero(best_inl)) <= n_before:
            break
    return best_score, best, best_inl


#: 6-dof chi-square quantile (P = 0.99) of the prior-data conflict test of
#: :func:`_final_refinement`
PRIOR_CONFLICT = 16.81
#: below this squared shift (in the data's own metric: a tenth of their standard deviation)
#: the prior's effect is negligible and the MAP refinement is skipped
PRIOR_NEGLIGIBLE = 0.01


def _final_refinement(fr: _Frame, model, th, rolling, prior, acceleration=False):
    """The final refinement, on every point of the frame with the truncated Huber loss of
    local optimization (scale ``th``, points beyond ``FINAL_CUTOFF * th`` ignored and the set
    re-selected at every iteration): fitting only RANSAC's inliers (the points inside ``th``)
    is a truncated least squares, about half as efficient on the velocities.

    With ``fr.prior`` (planar frames, or a prior with ``always``): MAP. Otherwise maximum
    likelihood first; then, if ``prior`` is not None and does not conflict with the data (the
    ML velocities ``z`` with their covariance ``S`` against the prior's mean ``m`` and
    covariance ``P``: ``(z - m)^T (S + P)^-1 (z - m)`` below :data:`PRIOR_CONFLICT`) and would
    move them by at least a tenth of their standard deviation (:func:`~.prior.prior_conflict`,
    :data:`PRIOR_NEGLIGIBLE`; else MAP and ML are the same for all purposes), MAP from the ML
    estimate in closed form (:func:`~.refine.posterior_step`: one Gauss-Newton step with the
    ML normal equations; the ML result's sigma and ``J^T W D``). A camera far faster than the
    prior allows (the paper's protocol: 8.7 rad/s, 5 m/s) keeps its ML estimate, so a
    zero-mean prior cannot bias it; where the data hardly determine the velocities (small or
    distant objects), the prior sharpens them.
    Returns (RefineResult, whether the prior was used)."""
    tau = fr.r - fr.r0
    X, x = fr.X, fr.x
    th = float(th)
    cut = FINAL_CUTOFF * th
    ref = refine_rs_pose(
        *model,
        X,
        x,
        tau,
        th,
        rolling_shutter=rolling,
        prior=fr.prior,
        seconds_per_unit_r=fr.spr,
        cutoff=cut,
        tol=FINAL_TOL,
        acceleration_block=acceleration,
    )
    if fr.prior is not None or prior is None:
        return ref, fr.prior is not None
    # (NaN in a failed refinement makes both tests false: the ML result stays)
    conflict, shift = prior_conflict(prior, ref.covariance, ref.C, ref.w, ref.t, fr.spr)
    if not (conflict < PRIOR_CONFLICT and shift >= PRIOR_NEGLIGIBLE):
        return ref, False
    post = posterior_step(ref, prior, fr.spr)  # (MAP from ML in closed form)
    return (ref, False) if post is None else (post, True)


def _seed(fr: _Frame, solver: str, model: InitialModel, th2, s: int, opts: EstimateOptions):
    """Test an :class:`InitialModel` on all points: (explained count, seed) where seed is None
    when it explains fewer than ``model.min_explained`` points (within its gate), else
    ``(score, (R, C, w, t), inlier mask)`` when it has more than ``s`` inliers within the
    threshold (after a robust Levenberg-Marquardt refinement on the explained points if it had
    fewer than ``min_explained`` there), or ``(None, None, None)`` (use its rotation for
    pre-rotation only)."""
    R, C, w, t = (
        np.ascontiguousarray(a, dtype=np.float64).copy()
        for a in (model.R, model.C, model.w, model.t)
    )
    rolling = solver_info(solver).rolling
    if not rolling:
        w, t = np.zeros(3), np.zeros(3)
    if not finite_model(R, C, w, t):
        return 0, None
    e2 = errors2(fr.x, fr.X, fr.r0e, fr.d, R, C, w, t, True, SCORE_AT_MEASURED_TIME)
    gate = float(model.gate_px) / fr.f
    near = e2 < gate * gate
    explained = int(np.count_nonzero(near))
    if explained < max(int(model.min_explained), 1):
        return explained, None
    best = (R, C, w, t)
    score, inl = _evaluate(fr, best, th2, errors=e2)
    if int(np.count_nonzero(inl)) < max(int(model.min_explained), s + 1):
        # a prediction a few pixels off (a hand-held camera's at 30 fps: ~2-15 px) explains
        # the frame within the gate, not within the threshold: pull it in with
        # Levenberg-Marquardt on (at most lo_max_points / 3 of) the explained points, truncated at
        # the gate (the seed's local optimization; a good seed is left to the final
        # refinement)
        # (a third of the local-optimization subset is plenty to pull a prediction in: the
        # final refinement fits every point)
        idx = np.flatnonzero(near)[: max(opts.lo_max_points // 3, 2 * s)]
        ref = refine_rs_pose(
            R,
            C,
            w,
            t,
            fr.X[idx],
            fr.x[idx],
            fr.r[idx] - fr.r0,
            np.sqrt(th2),
            rolling_shutter=rolling,
            max_iterations=2 * opts.lo_refine_iterations,
            covariance=False,
            cutoff=gate,
            prior=fr.prior,
            seconds_per_unit_r=fr.spr,
        )
        if finite_model(ref.R, ref.C, ref.w, ref.t):
            cand = (ref.R, ref.C, ref.w, ref.t)
            sc, inl_c = _evaluate(fr, cand, th2)
            if sc < score:
                best, score, inl = cand, sc, inl_c
    if int(np.count_nonzero(inl)) <= s:
        return explained, (None, None, None)
    return explained, (score, best, inl)


def _degenerate(fr: _Frame, u_px, mask, threshold_px: float) -> bool:
    """True if the points ``mask`` selects fix no pose: identical or collinear 3D points, or
    pixels within ``threshold_px`` of one image line (see :mod:`.plausibility`)."""
    return bool(degenerate_points(fr.X, u_px, fr.x, mask, float(fr.f), float(threshold_px)))


def _fail(reason, solver, n, n_valid=0, n_dropped=0, iters=0, timings=None):
    """An unsuccessful :class:`RSPoseEstimate` with ``reason``."""
    return RSPoseEstimate(
        success=False,
        failure=reason,
        solver=solver,
        inliers=np.zeros(n, dtype=bool),
        num_valid=n_valid,
        num_dropped=n_dropped,
        ransac_iterations=iters,
        timings=timings or {},
    )


def physical_velocities(R, C, w, t, seconds_per_unit_r: float):
    """Model velocities (per unit r) -> the camera's own velocities.

    With ``X_cam = R(tau) X + C(tau)``, ``R(tau) = (I + tau [w]x) R``, ``C(tau) = C + tau t`` and
    ``tau = time / seconds_per_unit_r``, the camera orientation ``R^T`` changes as
    ``d(R^T)/dtau = -R^T [w]x``, so its angular velocity in its own frame is ``-w`` per unit r,
    and the centre ``c = -R^T C`` moves with ``dc/dtau = R^T (w x C - t)``.

    Returns:
        (omega_cam rad/s, v_cam m/s, omega_world, v_world), each (3,); zeros for a global
        shutter (``seconds_per_unit_r == 0``).
    """
    if seconds_per_unit_r <= 0:
        z = np.zeros(3)
        return z, z.copy(), z.copy(), z.copy()
    f64 = np.float64
    return physical_velocities_kernel(
        np.ascontiguousarray(R, dtype=f64),
        np.ascontiguousarray(C, dtype=f64),
        np.ascontiguousarray(w, dtype=f64),
        np.ascontiguousarray(t, dtype=f64),
        float(seconds_per_unit_r),
    )


def _output_covariance(cov12, R, C, w, seconds_per_unit_r):
    """Propagate the (delta, C, w, t) covariance to (camera rotation in world, position,
    omega_cam, v_cam) and to the ROS pose/twist blocks.

    With ``R = expm(delta) R0`` the camera orientation ``R^T = R0^T expm(-delta)`` has the
    world-axis rotation perturbation ``phi = -R^T delta``; the position ``c = -R^T C`` has
    ``dc/ddelta = -R^T [C]x`` and ``dc/dC = -R^T``; the velocities follow
    :func:`physical_velocities` (``omega = -w / s``, ``v = (w x C - t) / s``). Returns (the
    (12, 12) covariance, the ROS pose block, the ROS twist block or ``None`` for a global
    shutter); computed in :func:`.outputs.output_covariance_kernel`."""
    s = float(seconds_per_unit_r)
    out, pose, twist = output_covariance_kernel(np.ascontiguousarray(cov12), R, C, w, s)
    return out, pose, (twist if s > 0 else None)


@functools.lru_cache(maxsize=16)
def _seed_sequence(seed):
    return np.random.SeedSequence(seed)


def _rng(seed):
    """``np.random.default_rng(seed)`` (the same stream) without hashing an int seed again on
    every frame (~6 us of ~20 at this call's cache state); other seeds as NumPy takes them."""
    if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
        return np.random.Generator(np.random.PCG64(_seed_sequence(int(seed))))
    return np.random.default_rng(seed)


def _prepare(points2d_px, points3d, camera, max_point_norm, rng=None):
    """Validate shapes and rows; returns (_Frame, rows) where ``rows`` are the input row
    indices of the frame's points (valid rows, shuffled by ``rng`` so that any prefix is a
    random subset for the pre-test). Raises ValueError for wrong array shapes."""
    u = np.asarray(points2d_px, dtype=np.float64)
    X = np.asarray(points3d, dtype=np.float64)
    if u.ndim != 2 or u.shape[1] != 2 or X.ndim != 2 or X.shape[1] != 3 or len(u) != len(X):
        raise ValueError(f"expected (N, 2) pixels and (N, 3) points, got {u.shape} and {X.shape}")
    rows = np.flatnonzero(valid_rows(u, X, max_point_norm))
    if rng is not None:
        rows = rng.permutation(rows)
    # (``take``: NumPy's fancy indexing costs ~10x more at this size)
    x, r, r0e = camera.normalize(u.take(rows, axis=0))
    if not (np.isfinite(x).all() and np.isfinite(r).all()):
        good = np.isfinite(x.sum(axis=1) + r)  # undistortion can fail far outside the image
        rows, x, r, r0e = rows[good], x[good], r[good], r0e[good]
    fr = _Frame(
        np.ascontiguousarray(x),
        X.take(rows, axis=0),
        np.ascontiguousarray(r),
        np.ascontiguousarray(r0e),
        camera.r0,
        camera.readout_vector,
        camera.mean_focal,
    )
    return fr, rows


def estimate_rs_pose(
    points2d_px,
    points3d,
    camera: CameraModel,
    solver: str = "r6p_1lin",
    options: EstimateOptions | None = None,
    scores=None,
    *,
    initial_model: InitialModel | None = None,
) -> RSPoseEstimate:
    """Robust rolling-shutter absolute pose from 2D-3D correspondences.

    Pipeline: validate and normalize (OpenCV undistortion; RS time from the measured, distorted
    line) -> RANSAC over minimal samples (P3P pre-rotation per sample, batched RS solver,
    preemptive MSAC score on the reprojection error of the exact constant-velocity model at
    each point's measured capture time, adaptive termination, PROSAC-style ordering when
    ``scores`` are given; one numba call per batch, :mod:`.batch`) -> local optimization (the
    RS solver on all inliers) -> robust refinement on the exact model (truncated Huber loss on
    all points within ``FINAL_CUTOFF`` thresholds) with covariance.

    Args:
        points2d_px: (N, 2) measured (distorted) pixel coordinates.
        points3d: (N, 3) world (map) points in metres.
        camera: :class:`~rs_localizer.camera.CameraModel` (intrinsics, distortion, RS timing).
        solver: one of :data:`SOLVERS`; ``p3p`` is the global-shutter baseline (w = t = 0).
        options: :class:`EstimateOptions`.
        scores: optional (N,) match quality, higher is better (PROSAC-style sample ordering).
        initial_model: optional :class:`InitialModel` (a prediction, e.g. from the previous
            frames of a video): tested first; if it explains enough points it seeds RANSAC and
            its rotation replaces P3P as the samples' pre-rotation. Without it the estimator is
            unchanged.
    Returns:
        :class:`RSPoseEstimate`. Data problems (NaN rows, too few points, all outliers,
        degenerate geometry) give ``success=False`` with a ``failure`` reason, never an
        exception or a NaN pose. Rows that fail validation are counted in ``num_dropped``.
    Raises:
        ValueError: unknown solver name, or arrays that are not (N, 2) / (N, 3) / (N,).
    """
    if solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}; expected one of {SOLVERS}")
    opts = options or EstimateOptions()
    t_start = time.perf_counter()
    timings = {}
    rng = _rng(opts.seed)
    fr, rows = _prepare(points2d_px, points3d, camera, opts.max_point_norm, rng)
    N = len(fr.x)
    n_in = len(np.asarray(points2d_px))
    n_dropped = n_in - N
    if scores is not None:
        scores = np.asarray(scores, dtype=float)
        if scores.shape != (n_in,):
            raise ValueError(f"scores must have shape ({n_in},), got {scores.shape}")
    s = sample_size(solver)
    min_inl = max(opts.min_inliers, s + 1)
    if min_inl > N:
        timings["prepare"] = time.perf_counter() - t_start
        return _fail("too_few_points", solver, n_in, N, n_dropped, 0, timings)
    # points that fix no pose (identical, on a 3D line, pixels on one image line): RANSAC
    # would only find absurd rolling-shutter "fits" of them
    u_fr = np.asarray(points2d_px, dtype=np.float64).take(rows, axis=0)
    all_rows = np.ones(N, dtype=bool)
    if _degenerate(fr, u_fr, all_rows, opts.threshold_px):
        timings["prepare"] = time.perf_counter() - t_start
        return _fail("degenerate_geometry", solver, n_in, N, n_dropped, 0, timings)
    # planar scenes: R9P cannot solve them; the RS solvers' hypotheses use the
    # motion prior (damped solves for w, t: the plain ones let w, t absorb the noise)
    fr.spr = spr = camera.seconds_per_unit_r
    fr.motion_bounds = motion_bounds(opts.max_angular_velocity, opts.max_linear_velocity, spr)
    fr.planar = bool(planarity(fr.X) < PLANAR_TOLERANCE)
    if fr.planar and not solver_info(solver).coplanar:
        timings["prepare"] = time.perf_counter() - t_start
        return _fail("planar_scene", solver, n_in, N, n_dropped, 0, timings)
    prior = opts.motion_prior
    prior_on = bool(
        prior is not None and prior.enabled and fr.spr > 0 and solver_info(solver).rolling
    )
    fr.prior = prior if prior_on and (fr.planar or prior.always) else None
    fr.regularize = bool(fr.prior is not None and fr.planar)
    timings["prepare"] = time.perf_counter() - t_start

    # PROSAC-style ordering: sample from the best-scored points first, growing the pool
    order = np.arange(N)
    if scores is not None:
        sc = np.where(np.isfinite(scores[rows]), scores[rows], -np.inf)
        order = np.argsort(-sc, kind="stable")
    th = opts.threshold_px / fr.f
    th2 = th * th
    best = None  # (R, C, w, t)
    best_score = np.inf
    best_inl = np.zeros(N, dtype=bool)
    best_count = 0
    iters = 0
    needed = float(opts.max_iterations)
    batch = max(int(opts.batch_size), 1)
    t_local = 0.0
    n_implausible = 0  # hypotheses rejected for their motion alone
    # one numba call per batch (the same hypotheses and scores as _generate); planar frames
    # of the RS solvers take _generate (runner-up pre-rotations, damped solves)
    fused = (
        None
        if fr.planar and solver_info(solver).hypotheses != GLOBAL_SHUTTER
        else fused_kernels(solver)
    )
    solver_its = _hypothesis_iterations(solver, opts)
    bounds = (
        (np.inf, np.inf) if fr.motion_bounds is None else tuple(float(b) for b in fr.motion_bounds)
    )
    t0 = time.perf_counter()
    R_pre = None  # P3P pre-rotation per sample unless an initial model explains the frame
    explained = -1
    guided = 0  # > 0: sample only from the first `guided` points of `order`
    if initial_model is not None:
        t_lo = time.perf_counter()
        explained, seeded = _seed(fr, solver, initial_model, th2, s, opts)
        if seeded is not None:
            R_pre = (
                np.ascontiguousarray(initial_model.R, dtype=np.float64),
                np.ascontiguousarray(initial_model.C, dtype=np.float64),
            )
            if seeded[0] is not None:
                best_score, best, best_inl = seeded
                best_count = int(np.count_nonzero(best_inl))
                needed = _required_iterations(best_count / N, s, opts.confidence)
                if best_count >= max(initial_model.min_explained, s + 1):
                    # the seed explains the frame: RANSAC verifies it with samples drawn from
                    # its inliers (as LO-RANSAC's inner sampling), so the all-inlier
                    # probability is that of the pool, not of the frame
                    first = best_inl.take(order)
                    order = np.concatenate([order.compress(first), order.compress(~first)])
                    guided = best_count
                    needed = 0.0
        t_local += time.perf_counter() - t_lo
    while iters < opts.max_iterations and (iters < needed or iters < opts.min_iterations):
        # batches double (fewer calls), but draw no more samples than termination asks for
        K = min(
            batch,
            opts.max_iterations - iters,
            max(
                int(np.ceil(min(needed, opts.max_iterations))) - iters,
                opts.min_iterations - iters,
                1,
            ),
        )
        batch *= 2
        pool = N
        if guided:
            pool = guided
        elif scores is not None:
            pool = int(min(N, max(2 * s, np.ceil(N * (iters + K) / max(opts.prosac_growth, 1)))))
        iters += K
        pre_min = int(0.5 * opts.pretest_points * best_count / N)
        if R_pre is not None and best is not None:  # pre-rotate by the best model so far
            R_pre = (
                np.ascontiguousarray(best[0], dtype=np.float64),
                np.ascontiguousarray(best[1], dtype=np.float64),
            )
        if fused is not None and (R_pre is None or not len(fused[0])):
            h, sc_h, Rs, Cs, ws, ts, n_bad = ransac_batch(
                rng.random((K, s)),
                pool,
                order,
                fr.x,
                fr.X,
                fr.r,
                fr.r0e,
                fr.d,
                fr.r0,
                fused[0],
                fused[1],
                solver_its,
                th2,
                best_score,
                opts.pretest_points,
                pre_min,
                SCORE_AT_MEASURED_TIME,
                *bounds,
            )
            n_implausible += n_bad
        elif fused is not None:  # the same with the initial model's pre-rotation
            h, sc_h, Rs, Cs, ws, ts, n_bad = prerotated_batch(
                rng.random((K, s)),
                pool,
                order,
                R_pre[0],
                fr.x,
                fr.X,
                fr.r,
                fr.r0e,
                fr.d,
                fr.r0,
                fused[0],
                fused[1],
                solver_its,
                th2,
                best_score,
                opts.pretest_points,
                pre_min,
                SCORE_AT_MEASURED_TIME,
                *bounds,
            )
            n_implausible += n_bad
        else:
            samples = order.take(_draw_samples(rng, pool, s, K))
            Rs, Cs, ws, ts, ok = _generate(fr, solver, samples, opts, R_pre)
            if fr.motion_bounds is not None:  # an implausible hypothesis has no inliers
                plausible = plausible_motion(Rs, Cs, ws, ts, fr.motion_bounds)
                n_implausible += int(np.count_nonzero(ok & ~plausible))
                ok = ok & plausible
            if not ok.any():
                continue
            sc, _cnt = msac_scores(
                fr.x,
                fr.X,
                fr.r0e,
                fr.d,
                np.ascontiguousarray(Rs),
                np.ascontiguousarray(Cs),
                np.ascontiguousarray(ws),
                np.ascontiguousarray(ts),
                th2,
                ok,
                best_score,
                True,
                opts.pretest_points,
                pre_min,
                0.5,
                SCORE_AT_MEASURED_TIME,
            )
            h = int(np.argmin(sc))
            sc_h = sc[h]
        if sc_h < best_score:
            t_lo = time.perf_counter()  # LO-RANSAC: polish every new best on its inliers
            best = (Rs[h], Cs[h], ws[h], ts[h])
            best_score, best_inl = _evaluate(fr, best, th2)
            if not guided:  # (a verification sample that beats the seed is polished by the
                # final refinement, on every point, like local optimization would)
                best_score, best, best_inl = _local_optimization(
                    fr, solver, best, best_score, best_inl, th2, opts
                )
            t_local += time.perf_counter() - t_lo
            best_count = int(np.count_nonzero(best_inl))
            needed = _required_iterations(
                (np.count_nonzero(best_inl[order[:guided]]) / guided) if guided else best_count / N,
                s,
                opts.confidence,
            )
    timings["ransac"] = time.perf_counter() - t0 - t_local
    timings["local_optimization"] = t_local
    if best is None:  # (every model moved implausibly fast: say so)
        return _fail(
            "implausible_motion" if n_implausible else "no_hypothesis",
            solver,
            n_in,
            N,
            n_dropped,
            iters,
            timings,
        )

    inl = best_inl
    if best_count < min_inl:
        return _fail("too_few_inliers", solver, n_in, N, n_dropped, iters, timings)
    if _degenerate(fr, u_fr, inl, opts.threshold_px):
        return _fail("degenerate_geometry", solver, n_in, N, n_dropped, iters, timings)
    R, C, w, t = (np.array(a, dtype=float) for a in best)
    rolling = solver_info(solver).rolling
    cov12 = info12 = sens = None
    t0 = time.perf_counter()
    tau = fr.r - fr.r0
    prior_used = fr.prior is not None
    if opts.refine:
        want_sens = bool(opts.acceleration_sensitivity and rolling and spr > 0)
        ref, prior_used = _final_refinement(
            fr, (R, C, w, t), th, rolling, prior if prior_on else None, want_sens
        )
        cand = (ref.R, ref.C, ref.w, ref.t)
        if finite_model(*cand):
            R, C, w, t = cand
            cov12 = ref.covariance if np.isfinite(ref.covariance).all() else None
            info12 = ref.data_information
        # final inliers on the refined exact model (errors at the measured capture time)
        inl_ref, n_ref, rms = final_inliers(exact_errors(R, C, w, t, fr.X, fr.x, tau), th)
        if n_ref >= min_inl:
            inl = inl_ref
        else:
            return _fail("too_few_inliers", solver, n_in, N, n_dropped, iters, timings)
        rmse = float(rms * fr.f)
        if want_sens:
            # on the final refinement's points (all, truncated) and its (posterior) H, with
            # J^T W D from its last Jacobian
            sens = acceleration_sensitivity(
                R,
                C,
                w,
                t,
                fr.X,
                fr.x,
                tau,
                spr,
                th,
                cutoff=FINAL_CUTOFF * th,
                normal_inverse=None if cov12 is None else cov12 / ref.sigma**2,
                acceleration_block=ref.acceleration_block,
            )
        if cov12 is not None and opts.correlated_noise_px > 0 and ref.sigma > 0:
            # the same estimate's covariance under white + correlated image error (on the
            # final inliers; noise_model)
            cov12 = correlated_noise_covariance(
                cov12,
                ref.sigma,
                R,
                C,
                w,
                t,
                fr.X[inl],
                fr.x[inl],
                tau[inl],
                u_fr[inl],
                pixel_jacobians(camera, fr.x[inl]),
                opts.correlated_noise_px,
                opts.correlated_noise_length_px,
            )
    else:
        rmse = float(
            np.sqrt(
                np.mean(
                    errors2(fr.x, fr.X, fr.r0e, fr.d, R, C, w, t, True, SCORE_AT_MEASURED_TIME)[inl]
                )
            )
            * fr.f
        )
    timings["refine"] = time.perf_counter() - t0
    # the last word: plausible motion, every inlier in front of the camera at its capture time
    # (plausibility.check_final_model on depths_at_capture, in one compiled call)
    w2max, v2max = (
        (np.inf, np.inf)
        if fr.motion_bounds is None
        else (float(fr.motion_bounds[0]) ** 2, float(fr.motion_bounds[1]) ** 2)
    )
    # (R, C, w, t are float64 and contiguous here: the refinement's result or np.array copies)
    code, n_behind = final_model_check(R, C, w, t, fr.X, tau, inl, w2max, v2max)
    if code:
        return _fail(
            IMPLAUSIBLE_MOTION if code == 1 else CHEIRALITY,
            solver,
            n_in,
            N,
            n_dropped,
            iters,
            timings,
        )

    om, vc, om_w, vc_w = physical_velocities(R, C, w, t, spr)
    cov, pose_cov, twist_cov = (None, None, None)
    if cov12 is not None:
        cov, pose_cov, twist_cov = _output_covariance(cov12, R, C, w, spr)
        if not rolling:
            twist_cov = None
    inliers = np.zeros(n_in, dtype=bool)
    inliers[rows[inl]] = True
    flat = planarity(fr.X, inl)
    n_free = 12 if rolling else 6
    cond = condition_number(info12[:n_free, :n_free]) if info12 is not None else float("nan")
    timings["total"] = time.perf_counter() - t_start
    return RSPoseEstimate(
        success=True,
        failure=None,
        solver=solver,
        R=R,
        C=C,
        w=w,
        t=t,
        orientation=R.T,
        position=camera_position(R, C),
        angular_velocity=om,
        linear_velocity=vc,
        angular_velocity_world=om_w,
        linear_velocity_world=vc_w,
        inliers=inliers,
        num_valid=N,
        num_dropped=n_dropped + n_behind,
        num_behind=n_behind,
        ransac_iterations=iters,
        timings=timings,
        covariance=cov,
        pose_covariance=pose_cov,
        twist_covariance=twist_cov,
        rmse_px=rmse,
        planar=bool(flat < PLANAR_TOLERANCE),
        planarity=flat,
        condition_number=cond,
        motion_prior_used=prior_used,
        initial_explained=explained,
        initial_used=R_pre is not None,
        acceleration_sensitivity=sens,
    )
