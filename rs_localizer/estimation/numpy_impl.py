"""The estimator's NumPy implementation: NumPy, SciPy and OpenCV only, no compiled kernel.

``estimate_rs_pose(..., implementation="numpy")`` (:mod:`.implementation`) runs the
estimator's own stages (:func:`~.estimate.estimate_rs_pose`: the same options checks, frame
preparation, RANSAC loop, failure reasons, final checks and outputs) with the steps that need
compiled kernels taken from here. The compiled kernels (numba) are an accelerator, not a
precondition: until they are compiled (a cold cache: one to two minutes of CPU) or where numba
is unavailable, frames are solved this way, on the same model with the same outputs
(:class:`~.result.RSPoseEstimate` with pose, twist, covariances, inliers and failure reasons),
at a lower rate. Per stage:

1. prepare: :func:`.frame.prepare_frame` and :func:`.frame.configure_frame` with
   ``compiled=False`` (the same rows, shuffle and checks in NumPy; OpenCV undistortion);
2. RANSAC: the compiled implementation's search (:class:`NumpyRansac`, a
   :class:`~.ransac.Ransac`: the same samples from the same random stream, batches, adaptive
   termination and failure reasons) with its compiled steps in NumPy: an ``initial_model``
   tested and pulled in first as the compiled search does it
   (:func:`~.local_optimization.seed_from_initial_model` with this module's error, score and
   robust fit: the same gate, ``min_explained``, ``initial_explained`` and
   ``initial_used``), minimal samples pre-rotated by the initial model's rotation, then the
   best model's, when it explains the frame, else by OpenCV's P3P (``cv2.solveP3P`` on three
   points of each sample, the root with the least error on the sample's other points; paper
   sec. 4), the paper's linear R6P
   (R6P_{v,C,w,t}^{[v]x}, sec. 3.3, eq. 5-7) batched over the samples with
   ``np.linalg.solve`` on stacked 12 x 12 systems, MSAC on the reprojection error of the
   exact constant-velocity model at each point's measured capture time (eq. 4), all
   hypotheses of a batch scored at once (:class:`NumpySamples`);
3. local optimization: the compiled implementation's rounds
   (:func:`~.local_optimization.local_optimization`) with the linear solver on the inliers
   pre-rotated by the best model and a robust SciPy fit of the exact model;
4. finalize: the robust refinement on the exact model in NumPy and SciPy, the compiled
   refinement's own backend (:func:`final_model`: :func:`~.refine.refine_rs_pose_numpy`,
   Huber loss on the points within :data:`~.finalize.FINAL_CUTOFF` thresholds, maximum a
   posteriori with the motion prior on planar frames; its sigma, information and covariance
   from the analytic Jacobian as the compiled refinement forms them; the acceleration
   sensitivity from the same Jacobian, as :func:`~.sensitivity.acceleration_sensitivity`
   forms it), then the compiled
   implementation's :func:`~.finalize.final_estimate` with ``compiled=False`` (motion
   plausibility, cheirality, the consistent-fit test and the outputs, in NumPy).

A gyro measurement enters as on the compiled implementation through the motion prior
(:func:`~.gyro.gyro_prior`: local optimization and the final refinement are maximum a
posteriori with it) and is judged by the image alone (:func:`~.finalize.image_alone` on the
refinement's NumPy backend, then :func:`~.gyro.gyro_checked`: ``gyro_used``,
``gyro_rejected``, ``gyro_rejection``); its
minimal samples stay the linear R6P's (the compiled implementation solves them with the
gyro's angular velocity, R5P_{v,C,t}^{w}).

Not in this implementation (:data:`~.implementation.NUMPY_UNUSED`; an estimate lists those it
was given in ``ignored_inputs``): PROSAC ordering (``scores``: uniform sampling),
``point_sigma``, the correlated image-noise covariance and the groups' shared error
(``groups``).
Solvers: :data:`~.implementation.NUMPY_SOLVERS`. Nothing here calls a numba kernel, so nothing
compiles; where numba is missing or broken, :mod:`rs_localizer.runtime.jit_cache` puts a
stand-in in its place so that the package imports, and this implementation runs.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from ..geometry import cross, rotvec_to_matrix
from ..pose import RSModel
from ..solvers._linear import lstsq_stack
from ..solvers.registry import solver_info
from .finalize import FINAL_CUTOFF, FinalModel
from .frame import Frame, Model
from .hypotheses import ScoredBatch, composed, hypothesis_iterations, prerotated_points
from .local_optimization import Scored, local_optimization
from .options import EstimateOptions
from .plausibility import plausible_models
from .prior import prior_arrays
from .ransac import Ransac
from .refine import (
    RefineSettings,
    huber_fit_numpy,
    least_squares_exact_model,
    refine_rs_pose_numpy,
)
from .result import (
    TOO_FEW_INLIERS,
    EstimationFailed,
)
from .sampling import draw_samples_numpy, least_error_roots
from .scoring import exact_errors2_numpy
from .sensitivity import physical_sensitivity

__all__ = ["NumpyRansac", "NumpySamples", "errors2", "final_model", "p3p_prerotations"]

#: :func:`_refine`'s default prior: the frame's own
_FRAME_PRIOR = object()
#: models of a batch scored on all points after the preemptive test on a subset
_KEEP = 4
#: linear R6P iterations per minimal sample unless ``ransac.solver_iterations`` says (the
#: compiled kernels take one; these samples are not damped by the motion prior on planar
#: frames, and with one the planar frames of test_numpy_impl lose inliers against the
#: compiled path)
_SAMPLE_ITERATIONS = 5


def errors2(
    fr: Frame | Any,
    R: np.ndarray,
    C: np.ndarray,
    w: np.ndarray,
    t: np.ndarray,
    m: int | None = None,
) -> np.ndarray:
    """(H, n) squared reprojection errors of H models (R (H, 3, 3); C, w, t (H, 3)) at the
    first ``m`` points (default all) at their measured capture times ``fr.tau``, exact model
    (paper eq. 4; :func:`~.scoring.exact_errors2_numpy`); ``inf`` behind the camera. A
    camera's frame (``fr.views()`` None): normalized units. A rig frame's stacked views
    (:meth:`~.frame.RefinementView.views`: each camera's mounting and rows; every point,
    ``m`` None): each camera's points under the models seen from it (the rig's ``Rm R, Rm C
    + cm, Rm w, Rm t``, :func:`~.scoring.mounted_pose`), whitened into px by their pixel
    Jacobians ``fr.A`` (n, 4)."""
    views = fr.views()
    if views is None:
        return exact_errors2_numpy(R, C, w, t, fr.X[:m], fr.x[:m], fr.tau[:m])
    out = np.empty((len(R), len(fr.X)))
    for Rm, cm, (a, b) in zip(*views, strict=True):
        out[:, a:b] = exact_errors2_numpy(
            Rm @ R, C @ Rm.T + cm, w @ Rm.T, t @ Rm.T, fr.X[a:b], fr.x[a:b], fr.tau[a:b],
            fr.A[a:b],
        )  # fmt: skip
    return out


def p3p_roots(X3: np.ndarray, x3: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every root of OpenCV's P3P (``cv2.solveP3P``) for K triples of world points X3
    (K, 3, 3) seen at the normalized image points x3 (K, 3, 2): the camera's rotations
    (M, 3, 3) and translations (M, 3) (``x_cam = R X + c``) and the index (M,) of the triple
    each root solves (up to 4 per triple; a triple OpenCV rejects gives none)."""
    eye = np.eye(3)
    owner, rv, tv = [], [], []
    p3p = cv2.SOLVEPNP_P3P
    for k in range(len(X3)):
        try:
            n, rvecs, tvecs = cv2.solveP3P(X3[k], x3[k], eye, None, flags=p3p)
        except cv2.error:
            continue
        owner += [k] * n
        rv += rvecs
        tv += tvecs
    if not owner:
        return np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    R = rotvec_to_matrix(np.array(rv).reshape(-1, 3))
    return R, np.array(tv).reshape(-1, 3), np.array(owner, dtype=np.int64)


def p3p_prerotations(
    X: np.ndarray,
    x: np.ndarray,
    samples: np.ndarray,
    cam: np.ndarray | None = None,
    Rm: np.ndarray | None = None,
    cm: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each sample's P3P pose in NumPy, as the compiled estimator chooses it (a camera's:
    :func:`~.sampling.p3p_mounted`, then :func:`~.sampling.select_prerotations`; a rig's:
    :func:`~.sampling.p3p_mounted`): OpenCV's P3P (:func:`p3p_roots`) on the sample's first
    three points, then the root of least squared error on its other points (all of them for
    3-point samples), each in front of its camera (:func:`~.sampling.least_error_roots`).

    A camera alone: ``cam``, ``Rm``, ``cm`` None, the poses world -> camera
    (``x_cam = R X + C``). A rig: the first three points of a sample all of one camera
    ``c = cam[sample[0]]`` (``cam`` (N,) int64, mountings ``x_cam = Rm[c] x_rig + cm[c]``,
    ``Rm`` (M, 3, 3), ``cm`` (M, 3) m), its roots mapped to the rig, ``R = Rm[c]^T R_cam``,
    ``C = Rm[c]^T (C_cam - cm[c])``, and the other points seen through their own mountings.

    Args:
        X: (N, 3) world points (m).
        x: (N, 2) normalized image points.
        samples: (K, s) int64 indices into the points, s >= 3.
    Returns:
        (R (H, 3, 3), C (H, 3) m, own (H,) int64): the pose of the H <= K samples that kept
        one (a sample whose roots all put a point behind its camera, or that OpenCV rejects,
        keeps none), ``own`` their rows of ``samples`` in increasing order.
    """
    R, C, own = p3p_roots(X[samples[:, :3]], x[samples[:, :3]])
    if Rm is not None:
        c0 = cam[samples[own, 0]]
        RcT = Rm[c0].transpose(0, 2, 1)
        R, C = RcT @ R, (RcT @ (C - cm[c0])[..., None])[..., 0]
    if len(own) == 0:
        return R, C, own
    keep = least_error_roots(R, C, own, samples, X, x, cam, Rm, cm)
    return R[keep], C[keep], own[keep]


def _p3p(fr: Frame, samples: np.ndarray):
    """P3P pre-rotation of each sample (K, s) of the camera's frame (:func:`p3p_prerotations`).
    Returns (R (K, 3, 3), C (K, 3), ok (K,)); a sample without a pose: the identity, zero,
    False."""
    K = len(samples)
    Rs, Cs, ok = np.tile(np.eye(3), (K, 1, 1)), np.zeros((K, 3)), np.zeros(K, dtype=bool)
    R, C, own = p3p_prerotations(fr.X, fr.x, samples)
    Rs[own], Cs[own], ok[own] = R, C, True
    return Rs, Cs, ok


def _r6p_1lin(x, X, tau, iterations: int):
    """The paper's linear iterative R6P (sec. 3.3, eq. 6; :mod:`rs_localizer.solvers.r6p_1lin`)
    for K problems at once: x (K, n, 2), X (K, n, 3) (pre-rotated), tau (K, n); n >= 6 solves
    in the least-squares sense. Each iteration fixes ``v_hat`` in the nonlinear term
    ``tau [w]x [v_hat]x X`` of eq. 5; the iterate with the least algebraic error of eq. 5 is
    kept. Returns (v, C, w, t) (K, 3) each and ok (K,)."""
    K, n = x.shape[0], x.shape[1]
    # the two elimination rows E of each point (independent rows of [x]x): E0 = (0, -1, y),
    # E1 = (1, 0, -x)
    E = np.zeros((K, n, 2, 3))
    E[..., 0, 1], E[..., 0, 2] = -1.0, x[..., 1]
    E[..., 1, 0], E[..., 1, 2] = 1.0, -x[..., 0]
    te = tau[:, :, None, None]
    A = np.empty((K, n, 2, 12))
    A[..., 0:3] = cross(X[:, :, None, :], E)
    A[..., 3:6] = E
    A[..., 9:12] = te * E
    b = -np.einsum("knqa,kna->knq", E, X).reshape(K, 2 * n)
    vhat = np.zeros((K, 3))
    best = np.full(K, np.inf)
    out = np.full((K, 12), np.nan)
    ok = np.zeros(K, dtype=bool)
    for _ in range(iterations):
        Z = X + cross(vhat[:, None, :], X)
        A[..., 6:9] = te * cross(Z[:, :, None, :], E)
        u, good = lstsq_stack(A.reshape(K, 2 * n, 12), b, normal_equations=True)
        vn, Cn, wn, tn = u[:, None, 0:3], u[:, None, 3:6], u[:, None, 6:9], u[:, None, 9:12]
        # algebraic error of eq. 5 at the iterate
        vX = X + cross(vn, X)
        P = vX + tau[..., None] * (cross(wn, vX) + tn) + Cn
        res = np.einsum("knqa,kna->knq", E, P)
        err = np.sqrt(np.mean(res.reshape(K, -1) ** 2, axis=1))
        better = good & (err < best)
        out[better], best[better], ok[better] = u[better], err[better], True
        vhat = np.where(good[:, None], u[:, 0:3], vhat)
    return out[:, 0:3], out[:, 3:6], out[:, 6:9], out[:, 9:12], ok


def _hypotheses(
    fr: Frame, samples: np.ndarray, rolling: bool, iterations: int, anchor: np.ndarray | None
):
    """Models (R (H, 3, 3), C, w, t (H, 3)) of the minimal samples: P3P (global shutter) or
    R6P (``iterations`` linear steps) on the sample pre-rotated by its P3P pose, or by
    ``anchor`` (3, 3) when given (an initial model, then the best model: rotation
    ``expm([v]x) R_p``)."""
    if not rolling:
        Rp, Cp, ok = _p3p(fr, samples)
        z = np.zeros_like(Cp)
        return Rp[ok], Cp[ok], z[ok], z[ok]
    if anchor is None:
        Rp, _, ok = _p3p(fr, samples)
    else:
        Rp, ok = np.broadcast_to(anchor, (len(samples), 3, 3)), np.ones(len(samples), dtype=bool)
    Rp = Rp[ok]
    xs, Xs, taus = prerotated_points(samples[ok], Rp, fr.x, fr.X, fr.tau, compiled=False)
    v, C, w, t, good = _r6p_1lin(xs, Xs, taus, iterations)
    return composed(v[good], Rp[good], compiled=False), C[good], w[good], t[good]


class NumpySamples:
    """The hypotheses of a batch of minimal samples and their MSAC scores in NumPy (the
    :class:`~.hypotheses.HypothesisSource` of :class:`NumpyRansac`): the samples drawn as the
    compiled sources draw them (:func:`~.sampling.draw_samples_numpy`), P3P pre-rotation and
    linear R6P (:func:`_hypotheses`), the plausibility filter, then preemptive scoring: every
    model on the first ``2 * pretest_points`` points (the rows are shuffled: a random subset),
    the best :data:`_KEEP` of them on all."""

    def __init__(self, fr: Frame, solver: str, opts: EstimateOptions, th2: float):
        self.fr, self.th2 = fr, th2
        self.rolling = solver_info(solver).rolling
        it = opts.ransac.solver_iterations
        self.iterations = _SAMPLE_ITERATIONS if it is None else int(it)
        self.pretest = 2 * opts.ransac.pretest_points

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
        samples = order.take(draw_samples_numpy(uniforms, pool))
        R, C, w, t = _hypotheses(
            fr, samples, self.rolling, self.iterations, None if anchor is None else anchor[0]
        )
        fine = plausible_models(C, w, t, fr.motion_bounds)
        n_bad = int(np.count_nonzero(~fine))
        if not fine.any():
            return ScoredBatch(-1, np.inf, R, C, w, t, n_bad)
        R, C, w, t = R[fine], C[fine], w[fine], t[fine]
        if len(R) > _KEEP and len(fr.x) > 2 * self.pretest:
            part = np.minimum(errors2(fr, R, C, w, t, self.pretest), self.th2).sum(axis=1)
            keep = np.argpartition(part, _KEEP - 1)[:_KEEP]
            R, C, w, t = R[keep], C[keep], w[keep], t[keep]
        sc = np.minimum(errors2(fr, R, C, w, t), self.th2).sum(axis=1)
        h = int(np.argmin(sc))
        return ScoredBatch(h, float(sc[h]), R, C, w, t, n_bad)


class NumpyRansac(Ransac):
    """:class:`~.ransac.Ransac` (the same loop, sampling, termination and failure reasons)
    with its compiled steps in NumPy and SciPy: the hypotheses and their scores
    (:class:`NumpySamples`), the score of one model, and local optimization's steps
    (:func:`~.local_optimization.local_optimization`'s rounds with the linear R6P on the
    inliers and a SciPy robust fit, :func:`_lo_refine`)."""

    compiled = False

    def __init__(self, fr: Frame, *args: Any):
        super().__init__(fr, *args)
        fr.tau = fr.r - fr.r0  # (every point's capture time, as the NumPy steps take it)

    def hypothesis_source(self) -> NumpySamples:
        return NumpySamples(self.fr, self.solver, self.opts, self.th2)

    def evaluate(self, model: Model) -> tuple[float, np.ndarray]:
        R, C, w, t = (np.asarray(a, dtype=float) for a in model)
        if not plausible_models(C[None], w[None], t[None], self.fr.motion_bounds)[0]:
            return np.inf, np.zeros(len(self.fr.x), dtype=bool)
        e2 = errors2(self.fr, R[None], C[None], w[None], t[None])[0]
        return float(np.minimum(e2, self.th2).sum()), e2 < self.th2

    def seed_steps(self) -> dict[str, Any]:
        fr = self.fr

        def model_errors2(model) -> np.ndarray:
            R, C, w, t = (np.asarray(a, dtype=float)[None] for a in model)
            return errors2(fr, R, C, w, t)[0]

        return {"errors2": model_errors2, "evaluate": self.evaluate, "refine": _lo_refine}

    def local_optimization(self, scored: Scored) -> Scored:
        return local_optimization(
            self.fr,
            self.solver,
            scored,
            self.th2,
            self.opts,
            self.evaluate,
            _nonminimal,
            _lo_refine,
        )


def _nonminimal(fr: Frame, solver: str, inliers, R, opts: EstimateOptions, C=None) -> list:
    """:func:`~.hypotheses.nonminimal_models` in NumPy: the linear R6P on the ``inliers`` of
    ``fr``, pre-rotated by ``R`` (the motion prior's rows are not used)."""
    if not solver_info(solver).rolling or np.count_nonzero(inliers) < 6:
        return []
    iterations = max(hypothesis_iterations(solver, opts.ransac), 2)
    Xs = (fr.X[inliers] @ R.T)[None]
    v, C1, w, t, ok = _r6p_1lin(fr.x[inliers][None], Xs, (fr.r[inliers] - fr.r0)[None], iterations)
    if not ok[0]:
        return []
    return [RSModel(rotvec_to_matrix(v[0]) @ R, C1[0], w[0], t[0])]


def _lo_refine(
    fr: Frame,
    model,
    th: float,
    rolling: bool,
    prior=None,
    *,
    cutoff: float | None = None,
    max_iterations: int = 20,
) -> RSModel:
    """:func:`~.finalize.refined_model` as local optimization and an initial model's pull run
    it, on SciPy's ``least_squares`` (:func:`~.refine.least_squares_exact_model`): Huber loss
    (scale ``th``) on the points of ``fr`` within ``cutoff`` (None:
    :data:`~.finalize.FINAL_CUTOFF` thresholds) of ``model`` (selected once), at most
    ``max_iterations + 1`` evaluations; ``rolling``: the 12 parameters, else the pose's 6;
    MAP with ``prior`` (image noise ``th / 2``) on a rolling-shutter fit. The frame's pixel
    whitening is not used: the NumPy implementation measures errors in the undistorted plane,
    as its scoring does."""
    R0, C0, w0, t0 = (np.asarray(a, dtype=float) for a in model)
    X, x, tau = fr.X, fr.x, fr.r - fr.r0
    e = np.sqrt(exact_errors2_numpy(R0[None], C0[None], w0[None], t0[None], X, x, tau)[0])
    near = e < (FINAL_CUTOFF * th if cutoff is None else cutoff)
    if np.count_nonzero(near) < 7:
        return RSModel(R0, C0, w0, t0)
    n_free = 12 if rolling else 6
    theta0 = np.concatenate([np.zeros(3), C0, w0 * rolling, t0 * rolling])
    args = (R0, theta0, n_free, X[near], x[near], tau[near])
    max_nfev = max(max_iterations, 1) + 1
    try:
        if rolling and prior_arrays(prior)[0]:
            th_ = huber_fit_numpy(*args, prior, fr.spr, 0.5 * th, th,
                                  max_nfev=max_nfev, rounds=1)  # fmt: skip
        else:
            th_ = least_squares_exact_model(
                *args, None, 0.0, 0.0, loss="huber", f_scale=th, max_nfev=max_nfev
            ).theta
    except (ValueError, np.linalg.LinAlgError):
        return RSModel(R0, C0, w0, t0)
    return RSModel(rotvec_to_matrix(th_[:3]) @ R0, th_[3:6], th_[6:9], th_[9:12])


def _refine(fr: Frame, model, th: float, rolling: bool, prior=_FRAME_PRIOR, sens: bool = False):
    """The final refinement (:func:`~.finalize.final_refinement` in NumPy and SciPy,
    :func:`~.refine.refine_rs_pose_numpy`): Huber loss (scale ``th``) on the points within
    ``FINAL_CUTOFF * th`` of the model, selected again after each fit; MAP with ``prior`` (by
    default the frame's; None: maximum likelihood). Returns (R, C, w, t, covariance (12, 12)
    of (delta, C, w, t) or None, data information or None, the acceleration sensitivity
    (12, 6) with ``sens`` on a rolling-shutter fit, else None)."""
    if prior is _FRAME_PRIOR:
        prior = fr.prior
    acc = bool(sens and rolling and fr.spr > 0)
    settings = RefineSettings(
        rolling_shutter=rolling, cutoff=FINAL_CUTOFF * th, seconds_per_unit_r=fr.spr,
        acceleration_block=acc,
    )  # fmt: skip
    ref = refine_rs_pose_numpy(model, fr.X, fr.x, fr.tau, th, settings, prior)
    R, C, w, t = ref.R, ref.C, ref.w, ref.t
    cov, info = ref.covariance, ref.data_information
    G = None
    if acc and cov is not None and ref.acceleration_block is not None:
        # (:func:`~.sensitivity.acceleration_sensitivity`: G = H^-1 J^T W D at the
        # (posterior) H of the covariance)
        Hinv = cov / ref.sigma**2
        G = physical_sensitivity(Hinv @ ref.acceleration_block, R, C, w, fr.spr, False)
    return R, C, w, t, cov, info, G


def final_model(
    fr: Frame, solver: str, opts: EstimateOptions, model: Model, min_inliers: int
) -> FinalModel:
    """:func:`~.finalize.refine_final_model` in NumPy and SciPy: RANSAC's ``model`` refined
    (:func:`_refine`; without ``opts.refine.enabled`` as it is, with no covariance), its
    inliers and their RMS error (px) re-selected on it.

    Raises:
        EstimationFailed: ``too_few_inliers``: fewer than ``min_inliers`` on the refined
            model.
    """
    th = fr.threshold
    R, C, w, t = (np.array(a, dtype=float) for a in model)
    cov = info = sens = None
    if opts.refine.enabled:
        R, C, w, t, cov, info, sens = _refine(
            fr,
            (R, C, w, t),
            th,
            solver_info(solver).rolling,
            sens=opts.refine.acceleration_sensitivity,
        )
    e = np.sqrt(errors2(fr, R[None], C[None], w[None], t[None])[0])
    inl = e < th
    if np.count_nonzero(inl) < min_inliers:
        raise EstimationFailed(TOO_FEW_INLIERS)
    rmse_px = float(np.sqrt(np.mean(e[inl] ** 2)) * fr.f)
    return FinalModel(
        RSModel(R, C, w, t),
        inl,
        rmse_px,
        cov,
        info,
        sensitivity=sens,
        prior_used=fr.prior is not None,
    )
