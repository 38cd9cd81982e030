"""RANSAC's hypotheses: models (R, C, w, t) from minimal samples and from inlier sets.

Every minimal sample is pre-rotated before the linear RS solver runs on it (paper sec. 4): by
its P3P pose (the cold start) or by a model the estimator already trusts (a tracker's
prediction, then the best model so far). :func:`hypothesis_source` picks one of three sources
with one interface (:class:`HypothesisSource`):

* :class:`ColdSamples`: P3P pre-rotation, the batched RS solver and preemptive MSAC scoring in
  one compiled call per batch (:func:`.batch.ransac_batch`);
* :class:`AnchoredSamples`: the same pre-rotated by the anchor model
  (:func:`.batch.prerotated_batch`);
* :class:`SampleBySample`: the same steps one NumPy call at a time, for what the compiled path
  does not cover (planar scenes: runner-up P3P pre-rotations and damped solves; R6P's variable
  number of roots; a P3P backend other than Lambda Twist).

All three draw their samples from the same uniforms, so a source change never changes the
random stream.

A rig's estimator (:mod:`.rig`) makes its hypotheses with the same steps: samples pre-rotated
by their P3P poses or an anchor (:func:`anchor_prerotations`) and solved by the linear RS
solver (:func:`prerotated_models`), inlier sets refitted so (:func:`linear_refit`), P3P poses
as still models (:func:`still_models`), its samples drawn by the camera's draws
(:func:`~.sampling.draw_samples_numpy`, the first three in one camera's points). What differs
is the solver (:data:`SampleSolver`): a camera's on its own points, the rig solver on points
seen through their cameras' mountings; a camera is a rig of one camera at the identity
mounting.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable
from typing import NamedTuple, Protocol

import numpy as np

from .._so3 import compose_rotvec
from ..geometry import rotvec_to_matrix
from ..pose import RSModel
from ..solvers import p3p_batch, r6p
from ..solvers.kernels import R5P_W, kernel_ids, kernel_set
from ..solvers.p3p import DEFAULT_BACKEND
from ..solvers.r5p_w import r5p_w_batch
from ..solvers.registry import BATCHED, GLOBAL_SHUTTER, sample_size, solver_info
from .batch import fused_kernels, nonminimal_solve, prerotated_batch, ransac_batch
from .frame import SCORE_AT_MEASURED_TIME, Frame, Model
from .options import EstimateOptions, RansacOptions
from .plausibility import plausible_motion
from .prior import sample_prior_rows
from .sampling import draw_samples, gather_prerotated, second_prerotations, select_prerotations
from .scoring import exact_msac_scores

__all__ = [
    "KNOWN_W_SAMPLE",
    "AnchoredSamples",
    "ColdSamples",
    "HypothesisSource",
    "SampleBySample",
    "SampleSolver",
    "ScoredBatch",
    "anchor_prerotations",
    "composed",
    "generate",
    "hypothesis_iterations",
    "hypothesis_source",
    "linear_refit",
    "nonminimal_models",
    "prerotated_models",
    "prerotated_points",
    "still_models",
]


#: minimal sample of RANSAC with a gyro: R5P_{v,C,t}^{w} (the angular velocity known, 9
#: unknowns, 2 equations per point)
KNOWN_W_SAMPLE = 5


def hypothesis_iterations(solver: str, ransac: RansacOptions, known_w: bool = False) -> int:
    """Linear iterations per minimal sample (see ``RansacOptions.solver_iterations``); with
    the angular velocity ``known_w`` (a gyro) one R5P_{v,C,t}^{w} solve by default."""
    if ransac.solver_iterations is not None:
        return int(ransac.solver_iterations)
    if known_w:
        return 1
    return solver_info(solver).default_iterations or 1


@functools.cache
def _takes_prior_rows(fn) -> bool:
    """The batched kernel ``fn`` accepts ``prior_rows`` (a damped linear solve)."""
    return "prior_rows" in inspect.signature(fn).parameters


def _batched_rs(solver: str, xs, Xs, rs, r0, iterations, prior_rows=None) -> list:
    """Run a solver's batched kernels on K pre-rotated samples; returns a list of RSBatch (2
    for the joined solver). ``prior_rows`` (P (K, 6, 6), q (K, 6)) go to the kernels that take
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


def _prior_rows(fr: Frame, Xs: np.ndarray, C0: np.ndarray):
    """Linearized motion-prior rows for K pre-rotated samples (``Xs`` (K, n, 3), their
    pre-rotation translations ``C0`` (K, 3)) when the frame asks for damped hypothesis solves
    (planar scene, prior on), else None. The rows are weighted as if the image noise were half
    the inlier threshold."""
    if not fr.regularize:
        return None
    return sample_prior_rows(fr.prior, Xs, C0, fr.spr, 0.5 * fr.threshold)


def composed(v: np.ndarray, R_pre: np.ndarray, compiled: bool = True) -> np.ndarray:
    """(K, 3, 3) ``expm([v_k]x) R_pre[k]``: the rotations of K solutions ``v`` (K, 3) of
    samples pre-rotated by ``R_pre`` (K, 3, 3) (``compiled``:
    :func:`rs_localizer._so3.compose_rotvec`, else NumPy's Rodrigues and product)."""
    if compiled:
        return compose_rotvec(np.ascontiguousarray(v), R_pre)
    return np.einsum("hij,hjk->hik", rotvec_to_matrix(v), R_pre)


def anchor_prerotations(anchor: tuple, K: int) -> tuple[np.ndarray, np.ndarray]:
    """K samples' pre-rotations by one ``anchor`` model ``(R (3, 3), C (3,), ...)`` (a
    tracker's prediction, the best model so far): ``(R (K, 3, 3), C (K, 3))``, contiguous."""
    R = np.ascontiguousarray(np.broadcast_to(np.asarray(anchor[0], dtype=float), (K, 3, 3)))
    return R, np.ascontiguousarray(np.broadcast_to(np.asarray(anchor[1], dtype=float), (K, 3)))


def prerotated_points(
    samples: np.ndarray,
    R_pre: np.ndarray,
    x: np.ndarray,
    X: np.ndarray,
    r: np.ndarray,
    compiled: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The linear RS solver's input of K samples (K, s) pre-rotated by ``R_pre`` (K, 3, 3):
    ``(x[samples] (K, s, 2), R_pre[k] X[samples[k]] (K, s, 3), r[samples] (K, s))``
    (``compiled``: :func:`~.sampling.gather_prerotated`, else NumPy)."""
    if compiled:
        return gather_prerotated(samples, R_pre, x, X, r)
    return x[samples], np.einsum("hij,hnj->hni", R_pre, X[samples]), r[samples]


#: the linear RS solver of pre-rotated samples: ``solve(samples (K, s), xs (K, s, 2),
#: Xs (K, s, 3) pre-rotated, rs (K, s), C_pre (K, 3))`` -> a list of
#: :class:`~rs_localizer.solvers.RSBatch` (a camera's solver with its motion prior's rows at
#: ``C_pre``, or the rig solver with the cameras' mountings of the samples' points)
SampleSolver = Callable[..., list]


def prerotated_models(
    samples: np.ndarray,
    R_pre: np.ndarray,
    C_pre: np.ndarray,
    x: np.ndarray,
    X: np.ndarray,
    r: np.ndarray,
    solve: SampleSolver,
    compiled: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The models of K samples (K, s) pre-rotated by ``R_pre`` (K, 3, 3) (their P3P poses or
    an anchor's rotation; ``C_pre`` (K, 3) the translations, where the motion prior's rows
    are linearized): the linear RS solver ``solve`` on the pre-rotated points
    (:func:`prerotated_points` of the points ``x`` (N, 2), ``X`` (N, 3) at ``r`` (N,)), each
    solution's rotation ``expm([v]x) R_pre`` (:func:`composed`). A camera's samples and a
    rig's are solved so; they differ in ``solve`` alone (a rig's solver sees each point
    through its camera's mounting).

    Returns:
        (R (M, 3, 3), C, w, t (M, 3), valid (M,)), the solver's batches one after the other
        (M = K per batch).
    """
    xs, Xs, rs = prerotated_points(samples, R_pre, x, X, r, compiled)
    batches = solve(samples, xs, Xs, rs, C_pre)
    Rs = [composed(b.v, R_pre, compiled) for b in batches]
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


def linear_refit(
    idx: np.ndarray,
    R: np.ndarray,
    C: np.ndarray | None,
    x: np.ndarray,
    X: np.ndarray,
    r: np.ndarray,
    solve: SampleSolver,
    rounds: int = 1,
) -> RSModel | None:
    """Local optimization's linear step on one inlier set: the linear RS solver ``solve``
    (:data:`SampleSolver`) on the points ``idx`` (n,) int of ``x`` (N, 2), ``X`` (N, 3) at
    ``r`` (N,), pre-rotated by the current ``R`` (3, 3) (``C`` (3,) the current position:
    where the motion prior's rows are linearized, or None), ``rounds`` times, each round
    pre-rotated by the previous one's model. Returns the last round's model (rotation
    ``expm([v]x) R``) or None when a solve failed. A camera's inliers and a rig's are
    refitted so, as their samples are (:func:`prerotated_models`)."""
    for _ in range(rounds):
        Xr = (X[idx] @ R.T)[None]
        C0 = None if C is None else np.asarray(C)[None]
        b = solve(idx[None], x[idx][None], Xr, r[idx][None], C0)[0]
        if not b.valid[0]:
            return None
        R, C = rotvec_to_matrix(b.v[0]) @ R, b.C[0]
    return RSModel(R, C, b.w[0], b.t[0])


def _p3p_prerotations(fr: Frame, samples, th2=None):
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


def _r6p_hypotheses(fr: Frame, samples, Xs, R_p, ok_p):
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


def generate(
    fr: Frame,
    solver: str,
    samples: np.ndarray,
    ransac: RansacOptions,
    anchor: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Hypotheses from a batch of minimal samples, one NumPy call at a time.

    Args:
        samples: (K, s) point indices of the frame.
        anchor: (R (3, 3), C (3,)) that pre-rotates every sample of an RS solver instead of
            its P3P pose (``C`` is the linearization point of the motion prior's rows).
    Returns:
        (R (M, 3, 3), C, w, t (M, 3), valid (M,)): on planar frames also the hypotheses of
        the samples' runner-up P3P pre-rotations (:func:`_p3p_prerotations`); R6P gives every
        real root; the joined solver two per sample. P3P's have ``w = t = 0``. With the
        frame's ``known_w`` (a gyro) an RS solver's samples are solved by
        :func:`~rs_localizer.solvers.r5p_w.r5p_w_batch` instead, one hypothesis each.
    """
    kind = solver_info(solver).hypotheses
    if anchor is not None and kind != GLOBAL_SHUTTER:
        R_p, C_p = anchor_prerotations(anchor, len(samples))
        ok_p = np.ones(len(samples), dtype=bool)
    elif fr.planar and kind != GLOBAL_SHUTTER:
        samples, R_p, C_p, ok_p = _p3p_prerotations(fr, samples, fr.threshold**2)
    else:
        R_p, C_p, ok_p = _p3p_prerotations(fr, samples)
    if kind == GLOBAL_SHUTTER:
        return (*still_models(R_p, C_p), ok_p)
    if fr.known_w is None and kind != BATCHED:
        Xs = gather_prerotated(samples, R_p, fr.x, fr.X, fr.r)[1]
        return _r6p_hypotheses(fr, samples, Xs, R_p, ok_p)
    known_w = fr.known_w is not None
    solve = _camera_solver(fr, solver, hypothesis_iterations(solver, ransac, known_w), known_w)
    Rs, Cs, ws, ts, ok = prerotated_models(samples, R_p, C_p, fr.x, fr.X, fr.r, solve)
    ok &= np.tile(ok_p, len(ok) // max(len(ok_p), 1))
    return Rs, Cs, ws, ts, ok


def still_models(R: np.ndarray, C: np.ndarray) -> tuple:
    """Global-shutter models of K poses ``R`` (K, 3, 3), ``C`` (K, 3) (a camera's or a rig's
    P3P poses): ``(R, C, w, t)`` with ``w = t = 0`` (K, 3), each its own array."""
    z = np.zeros((len(C), 3))
    return R, C, z, z.copy()


def _camera_solver(fr: Frame, solver: str, iterations: int, known_w: bool = False):
    """A camera's :data:`SampleSolver`: ``solver``'s batched kernels (with the frame's
    ``known_w``, a gyro's angular velocity:
    :func:`~rs_localizer.solvers.r5p_w.r5p_w_batch`), ``iterations`` linear steps, the
    motion prior's rows (:func:`_prior_rows`) where the frame asks for them and ``C_pre`` is
    given."""

    def solve(samples, xs, Xs, rs, C_pre) -> list:
        rows = None if C_pre is None else _prior_rows(fr, Xs, C_pre)
        if known_w:
            return [r5p_w_batch(xs, Xs, fr.known_w, rs, fr.r0, iterations, prior_rows=rows)]
        return _batched_rs(solver, xs, Xs, rs, fr.r0, iterations, rows)

    return solve


def nonminimal_models(
    fr: Frame,
    solver: str,
    inliers: np.ndarray,
    R: np.ndarray,
    opts: EstimateOptions,
    C: np.ndarray | None = None,
) -> list[Model]:
    """Local optimization's linear step: the RS solver on all ``inliers`` (N,) bool,
    pre-rotated by the current ``R`` (3, 3) (with the current ``C`` (3,), the linearization
    point of the motion prior's rows on planar frames). R6P (minimal only) uses
    R6P_{v,C,w,t}^{[v]x} here; P3P has no RS local optimization (returns ``[]``).

    Returns:
        the models (R, C, w, t) the solver found (0-2).
    """
    n_inl = int(inliers.sum())
    if not solver_info(solver).rolling or n_inl < 6:
        return []
    names = [
        name if n_inl >= sample_size(name) else "r6p_1lin"
        for name in solver_info(solver).lo_solvers
    ]
    ids = [kernel_ids(name) for name in names]
    iterations = max(hypothesis_iterations(solver, opts.ransac), 2)
    # one numba call (gather, solve) unless the solve is damped by the motion prior
    if not fr.regularize and all(k is not None and len(k) == 1 for k in ids):
        ok, Rs, Cs, ws, ts = nonminimal_solve(
            kernel_set(tuple(k[0][0] for k in ids)),
            np.array([k[0][1] for k in ids], dtype=np.int64),
            np.array([k[0][2] for k in ids], dtype=np.int64),
            inliers,
            np.ascontiguousarray(R),
            fr.x,
            fr.X,
            fr.r,
            fr.r0,
            iterations,
        )
        return [RSModel(Rs[j], Cs[j], ws[j], ts[j]) for j in range(len(ids)) if ok[j]]
    idx = np.flatnonzero(inliers)
    out = []
    for name in names:
        m = linear_refit(idx, R, C, fr.x, fr.X, fr.r, _camera_solver(fr, name, iterations))
        if m is not None:
            out.append(m)
    return out


class ScoredBatch(NamedTuple):
    """A batch of hypotheses with its best one: ``best`` indexes ``R`` (K, 3, 3), ``C``, ``w``,
    ``t`` (K, 3); ``score`` is its MSAC score (``inf``: no usable hypothesis); ``implausible``:
    hypotheses rejected for their motion alone."""

    best: int
    score: float
    R: np.ndarray
    C: np.ndarray
    w: np.ndarray
    t: np.ndarray
    implausible: int


class HypothesisSource(Protocol):
    """Makes and scores one batch of RANSAC hypotheses."""

    def best_of_batch(
        self,
        uniforms: np.ndarray,
        pool: int,
        order: np.ndarray,
        best_score: float,
        pretest_min: int,
        anchor: tuple[np.ndarray, np.ndarray] | None,
    ) -> ScoredBatch:
        """Hypotheses from K samples drawn with ``uniforms`` (K, s) in [0, 1) among the first
        ``pool`` points of ``order``, scored against ``best_score`` (preemptive MSAC with a
        pre-test needing ``pretest_min`` inliers among the first pre-test points); ``anchor``:
        (R, C) pre-rotating the samples, or None for P3P."""
        ...


class _Scoring:
    """What every source shares: the frame, solver, squared threshold (normalized),
    pre-test size, solver iterations and velocity bounds (per unit r)."""

    def __init__(self, fr: Frame, solver: str, opts: EstimateOptions, th2: float):
        self.fr, self.solver, self.th2 = fr, solver, th2
        self.ransac = opts.ransac
        self.iterations = hypothesis_iterations(solver, opts.ransac, fr.known_w is not None)
        # (the gyro's angular velocity for the fused batch's known-w kernel; an empty array
        # without one: one compiled signature of the fused batch for both)
        self.known_w = np.ascontiguousarray(
            np.zeros(0) if fr.known_w is None else fr.known_w, dtype=np.float64
        )
        self.bounds = (
            (np.inf, np.inf)
            if fr.motion_bounds is None
            else tuple(float(b) for b in fr.motion_bounds)
        )


class ColdSamples(_Scoring):
    """P3P-pre-rotated samples, one compiled call per batch (:func:`.batch.ransac_batch`)."""

    def __init__(
        self,
        fr: Frame,
        solver: str,
        opts: EstimateOptions,
        th2: float,
        kernels: tuple[np.ndarray, np.ndarray],
    ):
        super().__init__(fr, solver, opts, th2)
        self.kernels = kernels

    def best_of_batch(
        self,
        uniforms: np.ndarray,
        pool: int,
        order: np.ndarray,
        best_score: float,
        pretest_min: int,
        anchor: tuple[np.ndarray, np.ndarray] | None,
    ) -> ScoredBatch:
        fr = self.fr
        return ScoredBatch(
            *ransac_batch(
                uniforms,
                pool,
                order,
                fr.x,
                fr.X,
                fr.r,
                fr.r0e,
                fr.d,
                fr.r0,
                self.kernels[0],
                self.kernels[1],
                self.iterations,
                self.th2,
                best_score,
                self.ransac.pretest_points,
                pretest_min,
                SCORE_AT_MEASURED_TIME,
                *self.bounds,
                self.known_w,
                fr.W,
            )
        )


class AnchoredSamples(ColdSamples):
    """Samples pre-rotated by the anchor's rotation, one compiled call per batch
    (:func:`.batch.prerotated_batch`)."""

    def best_of_batch(
        self,
        uniforms: np.ndarray,
        pool: int,
        order: np.ndarray,
        best_score: float,
        pretest_min: int,
        anchor: tuple[np.ndarray, np.ndarray] | None,
    ) -> ScoredBatch:
        fr = self.fr
        return ScoredBatch(
            *prerotated_batch(
                uniforms,
                pool,
                order,
                anchor[0],
                fr.x,
                fr.X,
                fr.r,
                fr.r0e,
                fr.d,
                fr.r0,
                self.kernels[0],
                self.kernels[1],
                self.iterations,
                self.th2,
                best_score,
                self.ransac.pretest_points,
                pretest_min,
                SCORE_AT_MEASURED_TIME,
                *self.bounds,
                self.known_w,
                fr.W,
            )
        )


class SampleBySample(_Scoring):
    """The same steps as the compiled sources, one NumPy call at a time (:func:`generate`,
    the plausibility filter, :func:`.scoring.msac_scores`)."""

    def best_of_batch(
        self,
        uniforms: np.ndarray,
        pool: int,
        order: np.ndarray,
        best_score: float,
        pretest_min: int,
        anchor: tuple[np.ndarray, np.ndarray] | None,
    ) -> ScoredBatch:
        fr = self.fr
        samples = order.take(draw_samples(uniforms, pool))
        Rs, Cs, ws, ts, ok = generate(fr, self.solver, samples, self.ransac, anchor)
        n_bad = 0
        if fr.motion_bounds is not None:  # an implausible hypothesis has no inliers
            plausible = plausible_motion(Rs, Cs, ws, ts, fr.motion_bounds)
            n_bad = int(np.count_nonzero(ok & ~plausible))
            ok = ok & plausible
        if not ok.any():
            return ScoredBatch(-1, np.inf, Rs, Cs, ws, ts, n_bad)
        sc, _ = exact_msac_scores(
            fr.x,
            fr.X,
            fr.r0e,
            fr.d,
            np.ascontiguousarray(Rs),
            np.ascontiguousarray(Cs),
            np.ascontiguousarray(ws),
            np.ascontiguousarray(ts),
            self.th2,
            ok,
            best_score,
            self.ransac.pretest_points,
            pretest_min,
            0.5,
            SCORE_AT_MEASURED_TIME,
            fr.W,
        )
        h = int(np.argmin(sc))
        return ScoredBatch(h, sc[h], Rs, Cs, ws, ts, n_bad)


def hypothesis_source(
    fr: Frame, solver: str, opts: EstimateOptions, th2: float, anchored: bool
) -> HypothesisSource:
    """The source of ``solver``'s hypotheses on ``fr``: compiled (cold or ``anchored``) where
    the solver has a fused kernel (with a gyro: R5P_{v,C,t}^{w} for every RS solver) and the
    frame is not planar, else step by step."""
    planar_rs = fr.planar and solver_info(solver).hypotheses != GLOBAL_SHUTTER
    if planar_rs:
        kernels = None
    else:
        kernels = fused_kernels(solver)
        if kernels is None and fr.known_w is not None and DEFAULT_BACKEND == "lambda_twist":
            # (an RS solver without a fused kernel of its own: the gyro's kernel alone)
            kernels = (kernel_set((), R5P_W), np.zeros(0, dtype=np.int64))
    if kernels is None:
        return SampleBySample(fr, solver, opts, th2)
    if anchored and (len(kernels[0]) or fr.known_w is not None):
        return AnchoredSamples(fr, solver, opts, th2, kernels)
    return ColdSamples(fr, solver, opts, th2, kernels)
