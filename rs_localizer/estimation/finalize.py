"""The last stage of the estimator: the final refinement of RANSAC's model on the exact
constant-velocity model (paper eq. 4) with its covariance (:func:`refine_final_model`), the
last checks and the outputs (:func:`final_estimate`).

A camera's frame and a rig frame's cameras go through the same stages, in the same order:
they take the frame as a :class:`~.frame.RefinementView` (a camera's :class:`~.frame.Frame`,
one view at the identity mounting, or the rig's cameras stacked, :mod:`~.rig`): the
refinement (:func:`frame_refinement`); the final model's inliers and their RMS error, enough
of them (:func:`selected_final`); its information, covariance with the mountings'
uncertainty (:func:`final_covariance`) and acceleration sensitivity
(:func:`final_sensitivity`) from its refinement (:func:`with_covariance`); the last checks
(:func:`last_checks`: finite model, motion bounds, cheirality of every camera's points), the
consistent-fit test (:func:`inconsistent_fit`, view by view) and the output covariances
(:func:`checked_outputs`), the successful estimate's fields (:func:`posed_estimate`); the
global-shutter fallback (:func:`still_fallback`) and the gyro's image-alone refinement
(:func:`image_alone`). What differs is given as arguments: a camera's refinement of RANSAC's
model (:func:`final_refinement`) or a rig's choice among refinements at the threshold
(:func:`chosen_refinement`) and its Jacobian at the chosen model, the units of the errors,
the velocity bounds, the views that support a fit."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import Any, TypeVar

import numpy as np

from .._jit import kernel
from .._linalg import solve_square
from ..camera import CameraModel
from ..geometry import camera_position
from ..pose import RSModel, RSPose
from ..solvers.registry import solver_info
from .degeneracy import PLANAR_TOLERANCE, condition_number, coplanar, far_side_fraction, planarity
from .frame import SCORE_AT_MEASURED_TIME, Frame, Model, RefinementView
from .implementation import NUMPY
from .noise_model import correlated_noise_covariance, pixel_jacobians, shared_shift_covariance
from .options import EstimateOptions
from .outputs import final_inliers
from .plausibility import (
    CHEIRALITY,
    IMPLAUSIBLE_MOTION,
    all_finite,
    final_check,
    finite_model,
)
from .prior import MotionPrior, prior_conflict
from .refine import (
    DEFAULT_REFINE,
    RefineResult,
    RefineSettings,
    exact_jacobian,
    exact_mounting_jacobian,
    exact_residuals,
    exact_rows,
    exact_time_jacobian,
    huber_weights,
    image_variance,
    posterior_step,
    refine_backend,
)
from .result import (
    INCONSISTENT_FIT,
    TOO_FEW_INLIERS,
    EstimationFailed,
    RSPoseEstimate,
    built_estimate,
    output_covariance,
    physical_velocities,
)
from .scoring import exact_errors2
from .sensitivity import acceleration_sensitivity

__all__ = [
    "FAR_SIDE_LIMIT",
    "FINAL_CUTOFF",
    "FINAL_TOL",
    "GLOBAL_SHUTTER",
    "INLIER_FIT_SIGNIFICANCE",
    "MIRRORED_FIT_FRACTION",
    "MOTION_SIGNIFICANCE",
    "MOTION_SIGNIFICANCE_CHI2",
    "NEAR_MISS_RATIO",
    "NEAR_MISS_WINDOW",
    "PARTIAL_FIT_CONDITION",
    "PARTIAL_FIT_FRACTION",
    "PRIOR_CONFLICT",
    "PRIOR_NEGLIGIBLE",
    "ROLLING_SHUTTER",
    "STILL_CHI2",
    "STILL_FALLBACK",
    "STILL_MIN_POINTS",
    "FinalModel",
    "ImageAlone",
    "checked_final",
    "checked_outputs",
    "chosen_refinement",
    "final_covariance",
    "final_estimate",
    "final_refinement",
    "final_sensitivity",
    "frame_refinement",
    "image_alone",
    "inconsistent_fit",
    "information_condition",
    "last_checks",
    "motion_chi2",
    "motion_significant",
    "posed_estimate",
    "posterior_if_consistent",
    "prior_at_rest",
    "refine_final_model",
    "refined_model",
    "rolling_shutter_check",
    "selected_final",
    "still_fallback",
    "still_final",
    "with_covariance",
]

#: the failures after which a rolling-shutter solver's frame is tried on the global-shutter
#: model (:func:`still_fallback`: a single camera's and a rig's): every
#: rolling-shutter model implausible (a readout of nanoseconds turns the noise into absurd
#: velocities), or RANSAC's best model explaining too few points (12 corners of three tags at
#: rest on which no rolling-shutter hypothesis found a consensus that P3P's does)
STILL_FALLBACK = (IMPLAUSIBLE_MOTION, TOO_FEW_INLIERS)

#: a single camera's or a rig's estimate (:func:`still_fallback`)
Estimate = TypeVar("Estimate")

#: The final refinement fits every point within this many inlier thresholds (Huber loss with
#: scale = the threshold, truncated here and re-selected at each iteration), not only RANSAC's
#: inliers: a fit on the points inside the threshold alone is a 2-sigma-truncated least
#: squares and doubled the angular-velocity error at RS speed 1 (0.49 % against the 0.24 %
#: of the maximum-likelihood fit on the true inliers; ``test/estimation/test_ml_accuracy.py``).
FINAL_CUTOFF = 2.0
#: The final refinement stops when an accepted step lowers the cost by less than this fraction
#: (steps of a few hundredths of the parameters' standard deviation): the velocities then
#: agree with those at 1e-10 to 1e-4 of the ML fit's spread (RS speed 0.5 and 1), with 4-5
#: cost evaluations instead of 6-8
FINAL_TOL = 1e-6
#: the refinements of :func:`refined_model` (local optimization's, an initial model's pull,
#: those :func:`chosen_refinement` compares by their MSAC cost) stop at this relative decrease
#: of the cost (the final refinement of one camera's frame at :data:`FINAL_TOL`): on the
#: rendered 3-camera rig the looser tolerance moved the median angular velocity error by 5 %
#: at no measurable saving
COMPARED_TOL = 1e-10
#: the final refinement of a frame of several views keeps the fit of its inliers alone (the
#: points within the threshold) instead of the fit over every point near the model only when
#: it lowers the MSAC cost by more than this many image variances (px^2): the 99 % quantile of
#: chi-square with the model's degrees of freedom (6: the pose, 12: with the velocities), by
#: which two fits of the same consistent points differ at most. Where no pose explains every
#: camera (mountings a few tenths of a degree off), the fit near every point settles between
#: the cameras at a cost tens of variances above the one that explains its inliers
INLIER_FIT_SIGNIFICANCE = {6: 16.81, 12: 26.22}
#: ``inconsistent_fit``: a planar inlier set of a non-planar frame with more than this fraction
#: of the other points beyond its plane, away from the camera (the plane seen from behind).
#: ``python -m benchmarks.bench_consistency``: true fits 0.0 with coplanar inliers
#: (p3p on rolling-shutter corridor frames with 20-70 % outliers); mirrored or reflected
#: correspondences 0.67-0.99
FAR_SIDE_LIMIT = 0.5
#: ``inconsistent_fit``: a fit explaining fewer than this fraction of the valid points ...
PARTIAL_FIT_FRACTION = 0.1
#: ... with a condition number (:func:`~.degeneracy.condition_number`) above this. Such
#: garbage fits measured 1.3e3-6e3 with 4-6 % of the points; true fits of 3D scenes 5-400
#: (corridor frames with up to 70 % outliers, the paper protocol's frames)
PARTIAL_FIT_CONDITION = 1e3
#: ``inconsistent_fit``: a fit explaining fewer than this fraction of the valid points of a
#: non-planar frame ...
MIRRORED_FIT_FRACTION = 0.5
#: ... with more near misses (points between 1 and :data:`NEAR_MISS_WINDOW` inlier thresholds
#: from the model) than this fraction of its inliers. Wrong matches land anywhere, and the noise
#: tail of true inliers beyond a threshold of 2 sigma is 0.16 of them; a part of a set of
#: correspondences no rigid pose explains (3D points reflected through the camera centre) is
#: fitted with its neighbours just missing: 0.7-1.9 in the paper protocol's frames at 1 px
#: noise, and 0.46-0.50 where a camera turned half a turn at the true centre explains a third of
#: them (no or 0.2 px noise: the points near the plane the turn maps onto itself); true fits at
#: most 0.25 (paper protocol's frames with 50-70 % outliers at 1 px noise, corridor frames;
#: ``python -m benchmarks.bench_consistency``)
NEAR_MISS_RATIO = 0.35
NEAR_MISS_WINDOW = 5.0
#: ``inconsistent_fit``: a fit explaining fewer than :data:`MIRRORED_FIT_FRACTION` of the valid
#: points of a non-planar frame with a condition number above this. 3D points reflected through
#: the camera centre, fitted by P3P on a fifth of a 60-point box from 11-14 m away (where the
#: near-miss test, rolling-shutter only, does not look and the inliers are too thick for the
#: far-side test): 5.1e3-5.1e4; true fits with fewer than half the points inliers at most 1.2e3
#: (corridor frames with 55 % and 70 % outliers, the paper protocol's frames; both solvers)
MIRRORED_FIT_CONDITION = 3e3
#: 6-dof chi-square quantile (P = 0.99) of the prior-data conflict test of
#: :func:`final_refinement`
PRIOR_CONFLICT = 16.81
#: below this squared shift (in the data's own metric: a tenth of their standard deviation)
#: the prior's effect is negligible and the MAP refinement is skipped
PRIOR_NEGLIGIBLE = 0.01


@dataclass
class FinalModel:
    """The refined model of one frame, before the last checks.

    Attributes:
        model: the :class:`~rs_localizer.pose.RSModel` ``(R, C, w, t)``: ``R`` (3, 3), ``C``
            (3,) world -> camera at the reference row, ``w``, ``t`` (3,) velocities per unit r.
        inliers: (N,) over the frame's points.
        rmse_px: RMS reprojection error of the inliers (px).
        covariance: (12, 12) over (delta, C, w, t), or None (no refinement, or not finite).
        information: (12, 12) the data's information matrix, or None.
        sensitivity: (12, 6) acceleration sensitivity, or None.
        prior_used: the refinement was maximum a posteriori.
        motion_chi2: :func:`motion_chi2` of the first refinement's velocities, maximum
            likelihood or (planar frames) MAP: the frame's own evidence of motion
            (:func:`final_refinement`; ``inf``: not computed).
    """

    model: RSModel
    inliers: np.ndarray
    rmse_px: float
    covariance: np.ndarray | None = None
    information: np.ndarray | None = None
    sensitivity: np.ndarray | None = None
    prior_used: bool = False
    motion_chi2: float = float("inf")


def frame_refinement(
    fr: RefinementView,
    model: Model,
    th: float,
    rolling: bool,
    prior: MotionPrior | None = None,
    acceleration: bool = False,
    *,
    cutoff: float | None = None,
    max_iterations: int = DEFAULT_REFINE.max_iterations,
    covariance: bool = True,
    tol: float = FINAL_TOL,
) -> RefineResult:
    """:func:`~.refine.refine_rs_pose` of ``model`` on every point of the frame with the final
    refinement's truncated Huber loss (scale ``th``, the frame's units: normalized for a
    camera, px for a rig; points beyond ``cutoff``, by default ``FINAL_CUTOFF * th``,
    ignored, re-selected at every iteration; stopping at a relative cost decrease below
    ``tol``, by default ``FINAL_TOL``; at most ``max_iterations``, 0: the Jacobian and
    covariance at ``model``): rolling-shutter or
    global-shutter (``rolling``), maximum likelihood or MAP with ``prior`` (the image noise
    that weighs it estimated from ``model``'s errors inside ``th``), ``covariance``: with the
    covariance (else skipped), ``acceleration``: with the ``J^T W D`` block. The one call
    every refinement of a camera's and of a rig's final stage makes, and the rig's local
    optimization (``fr``, :class:`~.frame.RefinementView`; ``fr.compiled`` False: in NumPy
    and SciPy, :func:`~.refine.refine_rs_pose_numpy`)."""
    th = float(th)
    return refine_backend(fr.compiled)(
        model,
        fr.X,
        fr.x,
        fr.r if fr.r0 == 0.0 else fr.r - fr.r0,  # (r - 0.0 is r, to the bit)
        th,
        _settings(
            rolling,
            float(fr.spr),
            FINAL_CUTOFF * th if cutoff is None else float(cutoff),
            acceleration,
            int(max_iterations),
            covariance,
            float(tol),
        ),
        prior=prior,
        mountings=fr.mountings(),
    )


def refined_model(
    fr: RefinementView,
    model: Model,
    th: float,
    rolling: bool,
    prior: MotionPrior | None = None,
    *,
    cutoff: float | None = None,
    max_iterations: int = 20,
) -> Model:
    """The model :class:`~rs_localizer.pose.RSModel` ``(R, C, w, t)`` of
    :func:`frame_refinement` of ``model`` without the covariance, stopping at
    :data:`COMPARED_TOL`: the step of local optimization (:func:`~.local_optimization.polish`:
    a camera's on its bounded random subset of points, a rig's on every point) and of the pull
    of an initial model onto the points it explains
    (:func:`~.local_optimization.pulled_in`), and the refinement :func:`chosen_refinement`
    compares. ``th``: the Huber scale in the frame's units (normalized for a camera, px for a
    rig); points beyond ``cutoff`` (None: :data:`FINAL_CUTOFF` thresholds) ignored,
    re-selected at each iteration; ``rolling``: the 12 parameters, else the pose's 6 (``w``,
    ``t`` held); ``prior``: maximum a posteriori (rolling shutter only). The arrays are the
    refinement's own (copies in NumPy)."""
    res = frame_refinement(
        fr, model, th, rolling, prior if rolling else None, cutoff=cutoff,
        max_iterations=max_iterations, covariance=False, tol=COMPARED_TOL,
    )  # fmt: skip
    if not fr.compiled:
        return RSModel(res.R.copy(), res.C.copy(), res.w.copy(), res.t.copy())
    # (views of the refinement's own buffer: no other model shares it)
    return RSModel(res.R, res.C, res.w, res.t)


def chosen_refinement(
    fr: RefinementView,
    model: Model,
    th: float,
    rolling: bool,
    prior: MotionPrior | None,
    cost: Callable[[Model], float],
    errors: Callable[[Model], np.ndarray],
    views: int,
    wide: float,
    first: Model | None = None,
) -> Model:
    """The final refinement of ``model`` on a frame of ``views`` views with points
    (``cost``: the MSAC cost of a model on every point, the estimate's own measure;
    ``errors``: its (N,) errors, in the units of the threshold ``th``): :func:`refined_model`
    (Huber loss at the threshold on every point within :data:`FINAL_CUTOFF` thresholds, the
    set re-selected at each iteration) from ``model`` and from ``model`` first fitted with
    ``wide`` thresholds as its threshold (a rig's: every camera's points within the largest
    inconsistency its cameras' consensus accepts between them), the one of the lower MSAC
    cost (the first alone when every point of the frame lies within the threshold of it: no
    point a few thresholds away for the wider fit to take in); unless the fit of the inliers
    alone (the points within the threshold, from ``model`` or from that one, the better)
    lowers the MSAC cost by more than :data:`INLIER_FIT_SIGNIFICANCE` image variances (tried
    only when some point lies between one and :data:`FINAL_CUTOFF` thresholds of that model:
    otherwise the inliers are every point its refinement weighed).

    RANSAC's models of a rig frame taken at one time are one camera's P3P poses: the
    refinement from the best of them stays near that camera's pose when another camera's
    points lie a few thresholds away, although a pose between the cameras explains more points
    at a lower cost (on TagSLAM's ``test_14``, PoseLib's pose refined the same way had the
    lower cost in 36 % of the rig frames). Where the cameras' mountings are off so that no pose
    explains them all, both refinements can settle between the cameras at a higher cost than
    the pose that explains its inliers (TagSLAM's ``test_6``: 10-32 % more MSAC cost on rig
    frames 1-1.8 deg from its reference): the inliers' own fit keeps that pose. On consistent
    points the two differ by a few variances, and the fit over every point near the model,
    the less noisy, stays. With a gyro (``prior``, maximum a posteriori, whose cost is not the
    MSAC cost) or one view (a camera alone, one view at the identity mounting): the first
    alone. ``first``: that first refinement (:func:`refined_model` of ``model`` at the
    threshold, or ``model`` itself when it is local optimization's refinement) when already
    computed, or None."""
    out = first if first is not None else refined_model(fr, model, th, rolling, prior)
    if prior is not None or views < 2:
        return out
    k = float(th)
    if errors(out).max() < k:
        return out  # (every point within the threshold: none a few thresholds away)
    wider = refined_model(fr, model, wide * k, rolling)
    wider = refined_model(fr, wider, k, rolling)
    c_out, c_wide = cost(out), cost(wider)
    best, c_best = (wider, c_wide) if c_wide < c_out else (out, c_out)

    e = errors(best)
    if not np.any((e >= k) & (e < FINAL_CUTOFF * k)):
        return best  # (no point the inliers' fit leaves out that the refinement weighs)

    def inliers_fit(m):
        fit = refined_model(fr, m, k, rolling, cutoff=k)
        return fit, cost(fit)

    # (``best`` is ``model`` itself when local optimization's refinement was the first and
    # the wider fit did not lower its cost: the same refinement from the same start, once)
    fits = inliers_fit(model)
    fits = (fits, fits if best is model else inliers_fit(best))
    tight, c_tight = min(fits, key=lambda fc: fc[1])
    free = 12 if rolling else 6
    margin = INLIER_FIT_SIGNIFICANCE[free] * image_variance(e[e < k], k, free, fr.compiled)
    return tight if c_tight < c_best - margin else best


@lru_cache(maxsize=64)
def _settings(
    rolling: bool,
    spr: float,
    cutoff: float,
    acceleration: bool,
    max_iterations: int,
    covariance: bool,
    tol: float,
) -> RefineSettings:
    """The :class:`~.refine.RefineSettings` of :func:`frame_refinement` (built once per
    setting: a rig refines a few times per frame)."""
    return RefineSettings(
        rolling_shutter=rolling,
        seconds_per_unit_r=spr,
        cutoff=cutoff,
        tol=tol,
        acceleration_block=acceleration and covariance,
        max_iterations=max_iterations,
        covariance=covariance,
    )


def final_refinement(
    fr: Frame,
    model: Model,
    th: float,
    rolling: bool,
    prior: MotionPrior | None,
    acceleration: bool = False,
) -> tuple[RefineResult, bool, float]:
    """The final refinement, on every point of the frame with the truncated Huber loss of
    local optimization (scale ``th``, normalized units; points beyond ``FINAL_CUTOFF * th``
    ignored and the set re-selected at every iteration): fitting only RANSAC's inliers (the
    points inside ``th``) is a truncated least squares, about half as efficient on the
    velocities.

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
    distant objects), the prior sharpens them. ``acceleration``: also compute the refinement's
    ``J^T W D`` block for :func:`~.sensitivity.acceleration_sensitivity`.

    Returns:
        (the refinement's result, whether the prior was used, :func:`motion_chi2` of the
        first refinement's velocities under its covariance (white image noise): the frame's own
        evidence of motion, of the maximum-likelihood fit, or where the refinement was MAP from
        the start (``fr.prior``: planar frames, where one plane barely separates the velocities
        from the pose) of the posterior, the planar problem's information with the prior's;
        ``inf``, not judged, for a global-shutter refinement).
    """
    ref = frame_refinement(fr, model, th, rolling, fr.prior, acceleration)
    evidence = np.inf
    if rolling:
        evidence = motion_chi2(ref.covariance, ref.w, ref.t)
    if fr.prior is not None or prior is None:
        return ref, fr.prior is not None, evidence
    return (*posterior_if_consistent(ref, prior, fr.spr), evidence)


def posterior_if_consistent(
    ref: RefineResult, prior: MotionPrior, seconds_per_unit_r: float
) -> tuple[RefineResult, bool]:
    """MAP from a maximum-likelihood refinement ``ref`` in closed form
    (:func:`~.refine.posterior_step`) when ``prior`` does not conflict with its velocities
    (:data:`PRIOR_CONFLICT`) and would move them by at least :data:`PRIOR_NEGLIGIBLE` of their
    standard deviation (:func:`~.prior.prior_conflict`; see :func:`final_refinement`).

    Args:
        ref: the ML result (with its covariance and ``data_information``/``data_gradient``).
        prior: the motion prior. seconds_per_unit_r: seconds per unit of the row coordinate.
    Returns:
        ``(the posterior, True)``, or ``(ref, False)`` when the prior does not apply or the
        step fails.
    """
    # (NaN in a failed refinement makes both tests false: the ML result stays)
    conflict, shift = prior_conflict(prior, ref.covariance, ref.C, ref.w, ref.t, seconds_per_unit_r)
    if not (conflict < PRIOR_CONFLICT and shift >= PRIOR_NEGLIGIBLE):
        return ref, False
    post = posterior_step(ref, prior, seconds_per_unit_r)  # (MAP from ML in closed form)
    return (ref, False) if post is None else (post, True)


#: 0.999 quantile of the chi-square distribution with 6 degrees of freedom: a frame whose
#: velocities ``(w, t)`` lie within this squared Mahalanobis distance of zero under their own
#: covariance shows no motion that its noise could not produce (:func:`motion_chi2`)
MOTION_SIGNIFICANCE_CHI2 = 22.458

#: the significance level of a frame's motion (:func:`motion_significant`)
MOTION_SIGNIFICANCE = 0.999

#: a rolling-shutter fit with fewer inliers switches to the global-shutter model only where
#: its velocities lie within :data:`STILL_CHI2` of zero, not wherever they are not significant
#: (:func:`still_final`): from a few markers' corners the velocities are so loosely determined
#: that "not significant" does not mean "small", and leaving them out can bend the pose more
#: than fitting them (a robot driving past 3-5 markers at 30 ms readout: 1.18 deg on the
#: global-shutter model against 0.38 deg on the rolling-shutter one, median)
STILL_MIN_POINTS = 50

#: ``RSPoseEstimate.motion_model`` of an estimate on the rolling-shutter model (eq. 4)
ROLLING_SHUTTER = "rolling_shutter"
#: ``RSPoseEstimate.motion_model`` of an estimate on the global-shutter model (``w = t = 0``)
GLOBAL_SHUTTER = "global_shutter"


def motion_chi2(
    covariance: np.ndarray | None, w: np.ndarray, t: np.ndarray, compiled: bool = True
) -> float:
    """Squared Mahalanobis distance of a frame's velocities ``(w, t)`` (per unit r, or per
    second with a covariance in the same units) from zero under their covariance (the (6, 6)
    block of the (12, 12) ``covariance`` over ``(delta, C, w, t)``): the frame's own evidence
    of motion, from its points' capture-time spread, their number and its noise. ``inf`` when
    the covariance is missing, not finite or singular (no evidence either way is claimed).
    ``compiled=False``: the same elimination in Python (no compiled kernel)."""
    if covariance is None:
        return float("inf")
    kernel = _velocity_chi2 if compiled else _velocity_chi2.py_func
    return float(
        kernel(
            np.ascontiguousarray(covariance, dtype=np.float64),
            np.ascontiguousarray(w, dtype=np.float64),
            np.ascontiguousarray(t, dtype=np.float64),
        )
    )


@kernel
def _velocity_chi2(cov, w, t):
    """:func:`motion_chi2` on arrays: ``z^T S^-1 z`` with ``z = (w, t)`` and ``S`` the
    ``[6:12, 6:12]`` block of ``cov``, by pivoted Gaussian elimination; ``inf`` where
    anything is not finite or ``S`` is singular."""
    S = np.empty((6, 6))
    z = np.empty(6)
    for i in range(6):
        z[i] = w[i] if i < 3 else t[i - 3]
        if not np.isfinite(z[i]):
            return np.inf
        for j in range(6):
            S[i, j] = cov[6 + i, 6 + j]
            if not np.isfinite(S[i, j]):
                return np.inf
    b = z.copy()
    u = np.empty(6)
    if not solve_square(S, b, u, 0.0):
        return np.inf
    out = 0.0
    for i in range(6):
        out += z[i] * u[i]
    return out


def prior_at_rest(prior: MotionPrior | None) -> bool:
    """The motion ``prior`` expects no motion: none, or a mean within
    :data:`MOTION_SIGNIFICANCE_CHI2` of zero under its own information (the default zero-mean
    prior; a tracker's prediction of a camera at rest). A prior that predicts motion (a
    tracked camera turning) keeps a frame on the rolling-shutter model even where the frame
    alone shows none."""
    if prior is None or not prior.enabled:
        return True
    m = prior.mean_vector()
    return float(m @ prior.information() @ m) < MOTION_SIGNIFICANCE_CHI2


def _finite_fit(fr: RefinementView, ref: RefineResult) -> bool:
    """The refinement ``ref`` of ``fr`` gave a finite model and a finite covariance (checked
    in Python where ``fr`` is not compiled: nothing compiles)."""
    m = (ref.R, ref.C, ref.w, ref.t)
    finite = bool(finite_model(*m)) if fr.compiled else all_finite(*m)
    cov = ref.covariance
    return finite and cov is not None and bool(np.isfinite(cov).all())


def rolling_shutter_check(
    fr: RefinementView, model: Model, th: float, prior: MotionPrior | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The rolling-shutter model refined from a global-shutter ``model`` on the frame's points
    (the final refinement's truncated loss at ``th``, the threshold in ``fr.errors``'s units),
    by maximum likelihood or, with ``prior``, MAP (the final refinement's ``fr.prior``: planar
    frames): the frame's evidence of motion around a global-shutter pose (:func:`motion_chi2`
    of its velocities; a camera's or a rig's, ``fr``), as :func:`still_fallback`'s ``motion``
    takes it: ``(covariance (12, 12) over (delta, C, w, t), w (3,), t (3,))``, per unit of the
    frame's time. ``None`` when the refinement gives no finite model or covariance, or the
    frame has no readout time (``fr.spr <= 0``)."""
    if not fr.spr > 0:
        return None
    R, C = (np.array(a, dtype=float) for a in model[:2])
    ref = frame_refinement(fr, (R, C, np.zeros(3), np.zeros(3)), th, True, prior)
    if not _finite_fit(fr, ref):
        return None
    return ref.covariance, ref.w, ref.t


@lru_cache(maxsize=512)
def _f_quantile(dof: int) -> float:
    """0.999 quantile of the F distribution with (6, ``dof``) degrees of freedom."""
    from scipy.stats import f

    return float(f.ppf(MOTION_SIGNIFICANCE, 6, dof))


def motion_significant(chi2: float, num_points: int) -> bool:
    """Whether a frame's velocities are significant: their :func:`motion_chi2` ``chi2``
    (computed with the noise the rolling-shutter fit estimates from its own residuals) over
    their six degrees of freedom against the :data:`MOTION_SIGNIFICANCE` quantile of the F
    distribution with (6, ``2 num_points - 12``) degrees of freedom: an F test, since the
    noise is estimated from the same points (with few points the F quantile is far above
    :data:`MOTION_SIGNIFICANCE_CHI2` / 6: twelve corners need chi2 above ~50; with hundreds it
    tends to it). ``num_points``: the points of the fit (its inliers). Not finite: True
    (nothing is claimed without evidence)."""
    if not np.isfinite(chi2):
        return True
    dof = max(2 * int(num_points) - 12, 1)
    return float(chi2) / 6.0 >= _f_quantile(dof)


def still_fallback(
    failure: str | None,
    solve: Callable[[], Estimate],
    fr: RefinementView,
    th: float,
    prior: MotionPrior | None = None,
) -> Estimate | None:
    """A rolling-shutter estimate that failed with ``failure``, posed on the global-shutter
    model when its points show no motion: a single camera's frame
    (:func:`~.estimate.estimate_rs_pose`) and a rig's (:func:`~.rig.estimate_rig_pose`), each
    with its own global-shutter estimator.

    A readout too short to observe motion (nanoseconds to microseconds per line) turns the
    noise's apparent motion into absurd velocities in every minimal sample; such frames are
    posed as P3P poses them. The alternative is a refusal, not a rolling-shutter estimate, so
    the test is that the motion is not significant (:func:`motion_significant`), not that it
    is small.

    Args:
        failure: the rolling-shutter estimate's failure reason; only those of
            :data:`STILL_FALLBACK` are tried.
        solve: ``solve()`` the estimate on the global-shutter model (P3P samples, the
            refinement of the pose alone): an estimate with ``success``, ``model`` (its
            ``R`` (3, 3), ``C`` (3,) first) and ``num_inliers``.
        fr: the frame (a camera's or a rig's, :class:`~.frame.RefinementView`; its
            ``compiled``: else the chi-square and the covariance in Python), on which the
            rolling-shutter model is refined from that estimate's pose
            (:func:`rolling_shutter_check` at the threshold ``th``, in ``fr.errors``'s units,
            MAP with ``prior``): velocities per unit of the frame's time, ``fr.spr`` s each.
    Returns:
        the global-shutter estimate with the twist covariance of the rolling-shutter fit
        (:func:`~.result.output_covariance`: what the points say of the velocities), or None:
        the failure is not one of :data:`STILL_FALLBACK`, the global-shutter estimate fails,
        the fit fails, or the velocities are significant (a frame that does show motion is not
        posed without it).
    """
    if failure not in STILL_FALLBACK:
        return None
    est = solve()
    if not est.success:
        return None
    fit = rolling_shutter_check(fr, est.model, th, prior)
    if fit is None:
        return None
    cov, w, t = fit
    compiled = fr.compiled
    if motion_significant(motion_chi2(cov, w, t, compiled), est.num_inliers):
        return None
    R, C = est.model[:2]
    return replace(est, **unobserved_twist(est.covariance, cov, R, C, fr.spr, compiled))


def unobserved_twist(
    pose_covariance: np.ndarray | None,
    fit_covariance: np.ndarray,
    R: np.ndarray,
    C: np.ndarray,
    seconds_per_unit: float,
    compiled: bool = True,
) -> dict:
    """The covariances of a global-shutter estimate (``w = t = 0``) of a frame whose
    rolling-shutter fit found no motion: the twist covariance of that fit
    (:func:`~.result.output_covariance` of ``fit_covariance`` (12, 12) over ``(delta, C, w,
    t)`` at the pose ``R``, ``C``; ``seconds_per_unit`` s per unit of its time), in the
    estimate's ``twist_covariance`` and in the velocity block of its (12, 12) ``covariance``
    (``pose_covariance``, the global-shutter refinement's, whose velocity rows and columns are
    zero: the velocities were held, not measured), so that both say what the frame says of
    the velocities. Returns the fields to replace: ``twist_covariance``, and ``covariance``
    unless ``pose_covariance`` is None."""
    out, _, twist = output_covariance(
        fit_covariance, R, C, np.zeros(3), seconds_per_unit, compiled
    )  # fmt: skip
    fields: dict = {"twist_covariance": twist}
    if pose_covariance is not None:
        cov = np.array(pose_covariance, dtype=float)
        cov[6:, 6:] = out[6:, 6:]
        fields["covariance"] = cov
    return fields


#: a frame whose velocities are loosely determined (planar, refined with the motion prior from
#: the start; or with fewer than :data:`STILL_MIN_POINTS` inliers) is posed on the
#: global-shutter model when its velocities lie within this squared Mahalanobis distance of
#: zero under their covariance (:func:`still_final`): the median of the chi-square
#: distribution with 6 degrees of freedom, what half of the frames of a camera at rest exceed.
#: There, "not significant" at :data:`MOTION_SIGNIFICANCE` does not mean "at rest": one plane
#: barely separates the velocities from the pose (a moving camera's motion fits into the pose
#: with little residual), and a few points leave the test little power.
#: ``python -m benchmarks.bench_global_shutter --planar-frames 60 --drive``: of 60 frames at
#: rest, 58-60 of a board and 60 of three tags switch at 0.001-2 us/line (51 and 57 at 30
#: us/line); moving at 1-3 rad/s and 0.2-1 m/s with 30 us/line, 4 board frames and 39 of the
#: three tags' (whose velocities 12 corners barely determine) switch, the median rotation
#: error 1.000x and 1.005x that of the rolling-shutter model on every frame (the 0.999 F
#: quantile instead switched about a third of the moving board frames and bent their median
#: rotation by a fifth). A robot driving past 3-5 markers (12-20 corners, 30 ms readout): 2 of
#: 31 frames switch, the median rotation error unchanged (0.56 deg)
STILL_CHI2 = 5.348


def still_final(fr: Frame, final: FinalModel, min_inliers: int) -> FinalModel | None:
    """The global-shutter model (``w = t = 0``) refined from a rolling-shutter ``final`` that
    shows no motion: the six velocity parameters would only fit its noise into the pose. The
    evidence is ``final.motion_chi2`` (:func:`final_refinement`):

    - a frame refined by maximum likelihood with at least :data:`STILL_MIN_POINTS` inliers
      (not planar): its velocities are not significant (:func:`motion_significant`, the F
      test of their contribution);
    - a planar frame refined with the motion prior (MAP) from the start, whose evidence is the
      posterior's, or a frame of fewer inliers: the velocities lie within
      :data:`STILL_CHI2` of zero.

    The inliers are re-selected on the refined model; the covariance stays the rolling-shutter
    fit's (its pose block is the pose's uncertainty with the velocities unknown, its twist block
    what the frame says of them: zero within that). ``None``: the frame shows motion, or the
    evidence is unknown (not finite), or a non-planar frame was refined with a prior on every
    frame (a tracker's prediction, ``prior.always``: its evidence is the prediction's as much as
    the frame's), or the global-shutter refinement gives no finite model or fewer than
    ``min_inliers`` inliers (the rolling-shutter model then stays).
    """
    n = int(np.count_nonzero(final.inliers))
    if fr.prior is not None and not fr.planar:
        return None
    if n >= STILL_MIN_POINTS and fr.prior is None and not fr.planar:
        if motion_significant(final.motion_chi2, n):
            return None
    elif not final.motion_chi2 < STILL_CHI2:
        return None
    th = float(fr.threshold)
    R, C = (np.array(a, dtype=float) for a in final.model[:2])
    zero = np.zeros(3)
    ref = frame_refinement(fr, (R, C, zero, zero), th, False)
    if not finite_model(ref.R, ref.C, zero, zero):
        return None
    R, C = np.array(ref.R, dtype=float), np.array(ref.C, dtype=float)
    try:
        still = selected_final(fr, RSModel(R, C, zero, zero.copy()), th, min_inliers, fr.f)
    except EstimationFailed:
        return None
    still.covariance, still.information = final.covariance, final.information
    return still


@dataclass(frozen=True)
class ImageAlone:
    """What the image alone says near a gyro-aided model (:func:`image_alone`).

    Attributes:
        angular_velocity: (3,) rad/s, camera optical frame.
        covariance: (3, 3) its covariance (rad^2/s^2), from the data alone.
        num_inliers: points within the inlier threshold of the image-alone model.
    """

    angular_velocity: np.ndarray
    covariance: np.ndarray
    num_inliers: int


def image_alone(
    fr: RefinementView, model: Model, th: float, prior: MotionPrior | None
) -> ImageAlone | None:
    """The final refinement of ``model`` on the frame's points without the gyro: the angular
    velocity the image alone gives near that model, with its covariance, and the inliers it
    explains. One refinement (a few cost evaluations), no RANSAC: the gyro-aided estimate's
    test of the gyro (``estimate_rs_pose(..., gyro=)``, ``estimate_rig_pose(..., gyro=)``). As
    in the unaided estimator, a planar frame (or a ``prior`` with ``always``) is refined with
    the motion ``prior`` without the gyro (one planar frame barely separates the angular
    velocity from the rotation), others by maximum likelihood.

    Args:
        fr: the frame (rolling shutter: ``fr.spr > 0``): a camera's or a rig's
            (:class:`~.frame.RefinementView`). model: the aided model.
        th: inlier threshold (in ``fr.errors``'s units: a camera's normalized units, a rig's
            px). prior: the motion prior without the gyro.
    Returns:
        :class:`ImageAlone`, or ``None`` when the refinement gives no finite model or
        covariance.
    """
    if not fr.spr > 0:
        return None
    on = prior is not None and prior.enabled and (fr.planar or prior.always)
    ref = frame_refinement(fr, model, th, True, prior if on else None)
    if not _finite_fit(fr, ref):
        return None
    cov = ref.covariance
    n = int(np.count_nonzero(fr.errors((ref.R, ref.C, ref.w, ref.t)) < th))
    # (omega = -w / s in the camera (rig) frame: physical_velocities)
    return ImageAlone(-ref.w / fr.spr, cov[6:9, 6:9] / fr.spr**2, int(n))


def refine_final_model(
    fr: Frame,
    camera: CameraModel,
    solver: str,
    opts: EstimateOptions,
    model: Model,
    inliers: np.ndarray,
    min_inliers: int,
) -> FinalModel:
    """Refine RANSAC's ``model`` (with its (N,) ``inliers``) on every point of the frame
    (:func:`final_refinement`), re-select the inliers on the refined exact model (errors at
    each point's measured capture time) and add what the options ask of the covariance
    (acceleration sensitivity, correlated image noise). Without ``opts.refine.enabled`` the
    model stays as it is (no covariance).

    Raises:
        EstimationFailed: ``too_few_inliers``: fewer than ``min_inliers`` on the refined
            model.
    """
    th = fr.threshold
    R, C, w, t = (np.array(a, dtype=float) for a in model)
    if not opts.refine.enabled:
        e2 = exact_errors2(fr.x, fr.X, fr.r0e, fr.d, R, C, w, t, SCORE_AT_MEASURED_TIME, fr.W)
        rmse = float(np.sqrt(np.mean(e2[inliers])) * fr.f)
        return FinalModel(RSModel(R, C, w, t), inliers, rmse, prior_used=fr.prior is not None)
    rolling = solver_info(solver).rolling
    want_sens = bool(opts.refine.acceleration_sensitivity and rolling and fr.spr > 0)
    ref, prior_used, evidence = final_refinement(
        fr, (R, C, w, t), th, rolling, fr.final_prior, want_sens
    )
    # (a refinement that gives no finite model leaves RANSAC's, without a covariance)
    fitted = bool(finite_model(ref.R, ref.C, ref.w, ref.t))
    model = RSModel(ref.R, ref.C, ref.w, ref.t) if fitted else RSModel(R, C, w, t)
    final = selected_final(fr, model, th, min_inliers, fr.f)
    final.prior_used, final.motion_chi2 = prior_used, evidence
    with_covariance(fr, final, ref, th, rolling, sensitivity=want_sens, fitted=fitted)
    corr = opts.correlated_noise
    if final.covariance is not None and corr.sigma_px > 0 and ref.sigma > 0:
        # the same estimate's covariance under white + correlated image error (on the final
        # inliers; noise_model)
        inl, tau = final.inliers, fr.r - fr.r0
        final.covariance = correlated_noise_covariance(
            final.covariance,
            ref.sigma,
            *final.model,
            fr.X[inl],
            fr.x[inl],
            tau[inl],
            fr.u_px[inl],
            pixel_jacobians(camera, fr.x[inl]),
            corr.sigma_px,
            corr.length_px,
            fr.W[inl].reshape(-1, 2, 2) if len(fr.W) else None,
        )
    return final


def selected_final(
    fr: RefinementView,
    model: Model,
    th: float,
    min_inliers: int,
    scale: float = 1.0,
    errors: np.ndarray | None = None,
) -> FinalModel:
    """The final model ``model`` of a camera's or a rig's frame (``fr``) with its inliers: the
    points whose errors (``errors``, (N,), or ``fr.errors(model)``, in the units of the
    threshold ``th``) lie below ``th`` (:func:`~.outputs.final_inliers`), and their RMS error
    times ``scale`` (px per unit of the errors: a camera's focal length, a rig's 1).

    Raises:
        EstimationFailed: ``too_few_inliers``: fewer than ``min_inliers``.
    """
    e = fr.errors(model) if errors is None else errors
    inl, n, rms = (final_inliers if fr.compiled else final_inliers.py_func)(e, th)
    if n < min_inliers:
        raise EstimationFailed(TOO_FEW_INLIERS)
    return FinalModel(model, inl, float(rms * scale))


def with_covariance(
    fr: RefinementView,
    final: FinalModel,
    ref: RefineResult | None,
    th: float,
    rolling: bool,
    *,
    sensitivity: bool = False,
    alone: bool = True,
    fitted: bool = True,
    rate_prior: tuple[float, np.ndarray] | None = None,
    errors: np.ndarray | None = None,
) -> FinalModel:
    """``final`` (a camera's or a rig's frame ``fr``) with what its final refinement ``ref``
    (:func:`frame_refinement` at ``final.model``, threshold ``th``, ``rolling``: the 12
    parameters, else the pose's 6; None: none ran) says of it, set in place: its information
    (``ref.data_information``) and its covariance (:func:`final_covariance`; ``errors``:
    ``final.model``'s (N,) errors when computed), unless the refinement gave no finite model
    (``fitted`` False), and with ``sensitivity`` its acceleration sensitivity
    (:func:`final_sensitivity`, ``rate_prior`` as there) from the refinement's covariance, or
    without a covariance (``alone``: a camera's) from the points alone."""
    if ref is None:
        return final
    if fitted:
        final.information = ref.data_information
        final.covariance = final_covariance(fr, final.model, ref, th, rolling, errors)
    if sensitivity and (alone or final.covariance is not None):
        normal = None if final.covariance is None else ref.covariance
        final.sensitivity = final_sensitivity(fr, final.model, normal, ref, th, rate_prior)
    return final


def final_covariance(
    fr: RefinementView,
    model: Model,
    ref: RefineResult,
    th: float,
    rolling: bool,
    errors: np.ndarray | None = None,
) -> np.ndarray | None:
    """The (12, 12) covariance over ``(delta, C, w, t)`` of a final model of a camera's or a
    rig's frame (``fr``) at ``model``: its final refinement's ``ref`` (``sigma^2 H^-1``, the
    posterior's with a prior; :func:`frame_refinement`), None where it is missing or not
    finite; with points in groups (:attr:`~.frame.RefinementView.groups`, one marker's
    corners) the white noise's share replaced by the sandwich under white noise plus a shift
    shared by each group's points, both estimated from the frame's residuals
    (:func:`~.noise_model.shared_shift_covariance`: unchanged where the residuals show no
    shared shift or cannot tell one); with cameras whose mountings have covariances
    (:meth:`~.frame.RefinementView.mounting_covariances`, a rig's) their share added to first
    order, ``A Sigma_m A^T`` per camera, ``A = H^-1 J^T W J_m`` the model's sensitivity to
    its mounting (``J``, ``J_m``: the image errors' analytic Jacobians over the model and the
    mounting, :func:`~.refine.exact_jacobian`, :func:`~.refine.exact_mounting_jacobian`, on
    the points within :data:`FINAL_CUTOFF` thresholds ``th``, ``W`` their Huber weights);
    with cameras whose time offsets have a std ``s_t`` (the mountings'
    :attr:`~rs_localizer.frames.Mounting.time_offset_std`) each one's ``s_t^2 a a^T``, ``a =
    H^-1 J^T W j_t``, ``j_t`` the image errors' derivative over the camera's capture times
    (:func:`~.refine.exact_time_jacobian`: its points moved along this frame's twist, the
    model's, or on the pose's 6 parameters the twist known from outside the frame, the
    mountings' fourth item, if any), then symmetrized. ``rolling``: over the 12 parameters,
    else the pose's 6. ``errors``: the model's (N,) errors (``fr.errors``) when already
    computed."""
    cov = ref.covariance
    if cov is None or not np.isfinite(cov).all():
        return None
    mounted = fr.mounting_covariances()
    groups = fr.groups
    if mounted is None and groups is None:
        return cov
    th = float(th)
    free = 12 if rolling else 6
    e = fr.errors(model) if errors is None else errors
    idx = np.flatnonzero(e < FINAL_CUTOFF * th)
    plain = fr.plain_mountings
    sub = None if plain is None else plain.take(idx)
    R0, C0, w0, t0 = model
    theta = np.concatenate([np.zeros(3), C0, w0, t0])
    X, x, tau = fr.X[idx], fr.x[idx], (fr.r - fr.r0)[idx]
    weights = huber_weights(e[idx], th)
    rows = None
    if groups is not None and fr.compiled:  # (the refinement's kernel: ~15x faster)
        rows = exact_rows(model, X, x, tau, th, sub)
    J = (exact_jacobian(theta, R0, X, x, tau, sub) if rows is None else rows[1])[:, :free]
    cov = cov.copy()
    if groups is not None and ref.sigma > 0:
        residuals = exact_residuals(theta, R0, X, x, tau, sub) if rows is None else rows[0]
        cov[:free, :free] = shared_shift_covariance(
            cov[:free, :free], ref.sigma, J, weights, residuals, groups[idx], fr.shift_share
        )[0]
    if mounted is None:
        return cov if np.isfinite(cov).all() else None
    _, mount_cov, time_std, twist = mounted
    WJ = J * np.repeat(weights, 2)[:, None]
    Jm = exact_mounting_jacobian(theta, R0, X, x, tau, sub)
    rows = np.repeat(sub.cam, 2)
    Hinv = ref.covariance[:free, :free] / ref.sigma**2
    share = np.zeros((free, free))
    for c, mc in enumerate(mount_cov):
        on = rows == c
        if mc is None or not on.any():
            continue
        A = Hinv @ (WJ[on].T @ Jm[on])
        share += A @ mc @ A.T
    if any(time_std):
        moving = theta
        if not rolling and twist is not None:  # (a global-shutter model: no twist of its own)
            moving = np.concatenate([theta[:6], *(np.asarray(a, dtype=float) for a in twist)])
        Jt = exact_time_jacobian(moving, R0, X, x, tau, sub)
        for c, s_t in enumerate(time_std):
            on = rows == c
            if s_t and on.any():
                a = s_t * (Hinv @ (WJ[on].T @ Jt[on]))
                share += np.outer(a, a)
    cov[:free, :free] += share
    cov = 0.5 * (cov + cov.T)
    return cov if np.isfinite(cov).all() else None


def final_sensitivity(
    fr: RefinementView,
    model: Model,
    covariance: np.ndarray | None,
    ref: RefineResult,
    th: float,
    rate_prior: tuple[float, np.ndarray] | None = None,
) -> np.ndarray | None:
    """The acceleration sensitivity (12, 6) of a final model of a camera's or a rig's frame
    (``fr``; :func:`~.sensitivity.acceleration_sensitivity`) on the final refinement's points
    (all, truncated at :data:`FINAL_CUTOFF` thresholds ``th``) from the final refinement
    ``ref`` (:func:`frame_refinement` with its ``J^T W D`` block) at ``model``: its (posterior)
    ``H^-1 = covariance / sigma^2`` (``covariance``: the refinement's (12, 12), finite, or None:
    computed again from the points, a camera's alone).

    ``rate_prior``: a gyro's ``(time (s after the frame's reference time), information (3, 3)
    on w)`` when the refinement was maximum a posteriori with it (a rig's): a frame that
    accelerates turns at the measured rate at that time, so the gyro's rows add
    ``sigma^2 P time`` per unit of angular acceleration to ``J^T W D``. None where the normal
    matrix is singular or the result not finite."""
    block = ref.acceleration_block
    if rate_prior is not None and block is not None and covariance is not None:
        time, info = rate_prior
        block = block.copy()
        block[6:9, 0:3] += ref.sigma**2 * time * info
    return acceleration_sensitivity(
        *model,
        fr.X,
        fr.x,
        fr.r - fr.r0,
        fr.spr,
        th,
        cutoff=FINAL_CUTOFF * th,
        normal_inverse=None if covariance is None else covariance / ref.sigma**2,
        acceleration_block=block,
        compiled=fr.compiled,
    )


def last_checks(
    fr: RefinementView,
    model: Model,
    inliers: np.ndarray,
    w_max2: float,
    v_max2: float,
    compiled: bool = True,
) -> tuple[str | None, int]:
    """The last word on a final model of a camera's or a rig's frame (``fr``, its
    :meth:`~.frame.RefinementView.views`): finite, moving within the squared bounds
    ``w_max2``, ``v_max2`` (per unit of the frame's time), every one of the (N,) ``inliers``
    in front of its camera at its capture time (:func:`~.plausibility.final_check`, one
    compiled call). Returns (the failure: ``implausible_motion``, ``cheirality`` or None;
    the number of all points behind their cameras, 0 with ``implausible_motion``).
    """
    R, C, w, t = model
    code, behind = final_check(
        R, C, w, t, fr.X, fr.r - fr.r0, inliers, w_max2, v_max2, compiled=compiled,
        views=fr.views(),
    )  # fmt: skip
    return (None, IMPLAUSIBLE_MOTION, CHEIRALITY)[code], behind


def information_condition(
    information: np.ndarray | None, rolling: bool, compiled: bool = True
) -> float:
    """The condition number (:func:`~.degeneracy.condition_number`) of a final refinement's
    (12, 12) ``information`` (``RefineResult.data_information``) over its free parameters
    (``rolling``: the 12, else the pose's 6); NaN without one."""
    if information is None:
        return float("nan")
    n_free = 12 if rolling else 6
    return condition_number(information[:n_free, :n_free], compiled)


def inconsistent_fit(
    X: np.ndarray,
    inliers: np.ndarray,
    model: Model,
    views: tuple | None,
    rolling: bool,
    threshold: float,
    errors: Callable[[], np.ndarray],
    condition: Callable[[], float],
    view_planar: Callable[[int], bool],
    compiled: bool = True,
    *,
    support_share: float = 0.0,
    flat: float | None = None,
) -> bool:
    """Whether a final fit is one no rigid camera, or rigid rig of cameras, explains
    (``consistent_fit``, :func:`final_estimate`; a camera is one view at the identity mounting,
    ``views`` None; the tests of :func:`final_estimate`'s ``consistent_fit``). The views that
    support the fit are those whose inlier ratio is at least ``support_share`` times the best
    view's (a rig's cameras' consensus: an outvoted camera's points, or a few of them explained
    by chance, do not count against it):

    - a supporting view whose inliers are one plane of its non-planar points must not see
      more than :data:`FAR_SIDE_LIMIT` of its other points beyond that plane (the plane seen
      from behind, from its camera's centre);
    - a fit of fewer than :data:`MIRRORED_FIT_FRACTION` of the supporting views' valid points,
      not coplanar, must not explain fewer than :data:`PARTIAL_FIT_FRACTION` of them with a
      condition number above :data:`PARTIAL_FIT_CONDITION`, nor have a condition number above
      :data:`MIRRORED_FIT_CONDITION`, nor (rolling shutter, ``threshold`` > 0) more near
      misses (errors between ``threshold`` and :data:`NEAR_MISS_WINDOW` times it) than
      :data:`NEAR_MISS_RATIO` of its inliers.

    Args:
        X: (N, 3) m, the valid world points (a rig's stacked by camera); inliers: (N,) bool.
        model: ``(R, C, w, t)``, world -> camera (rig with ``views``).
        views: None, or a rig's ``(R_mount (M, 3, 3), c_mount (M, 3), rows (M, 2))``
            (:func:`~.plausibility.final_check`).
        rolling: a rolling-shutter fit (the near-miss test is skipped otherwise).
        threshold: the inlier threshold in the units of ``errors`` (0 skips the near-miss
            test). errors: called only for the near-miss test: the (N,) errors of the fit.
        condition: called only for the partial-fit tests: the condition number of the fit's
            information matrix (NaN: unknown).
        view_planar: ``view_planar(m)``: view m's points are coplanar.
        compiled: False: the planarity in NumPy. flat: the inliers' planarity
            (:func:`~.degeneracy.planarity`) when known, for a single view.
    """
    R, C = np.asarray(model[0], dtype=float), np.asarray(model[1], dtype=float)
    if views is None:
        Rm, cm, rows = np.eye(3)[None], np.zeros((1, 3)), ((0, len(X)),)
    else:
        Rm, cm, rows = views
    sizes = [int(b) - int(a) for a, b in rows]
    counts = [int(np.count_nonzero(inliers[a:b])) for a, b in rows]
    ratio = [k / max(m, 1) for k, m in zip(counts, sizes, strict=True)]
    best = max(ratio, default=0.0)
    supporting, n, n_inl = [], 0, 0
    for m, (a, b) in enumerate(rows):
        if ratio[m] == 0.0 or ratio[m] < support_share * best:
            continue
        supporting.append(m)
        n, n_inl = n + sizes[m], n_inl + counts[m]
        # (the planarity of the view's points only when its inliers are one plane; every
        # point an inlier, or fewer than 3: not a plane seen from behind)
        if counts[m] == sizes[m] or counts[m] < 3:
            continue
        Xm, im = X[a:b], inliers[a:b]
        f = flat if flat is not None and views is None else planarity(Xm, im, compiled)
        if f >= PLANAR_TOLERANCE or view_planar(m):
            continue
        if views is None:
            centre = camera_position(R, C)
        else:
            centre = camera_position(Rm[m] @ R, Rm[m] @ C + cm[m])
        if far_side_fraction(Xm, im, centre) > FAR_SIDE_LIMIT:
            return True
    if n_inl >= MIRRORED_FIT_FRACTION * n:
        return False
    support = slice(None)  # (the supporting views' points)
    if views is not None:
        support = np.zeros(len(inliers), dtype=bool)
        for m in supporting:
            support[int(rows[m][0]) : int(rows[m][1])] = True
    if view_planar(0) if views is None else coplanar(X[support], compiled):
        return False
    cond = condition()
    if n_inl < PARTIAL_FIT_FRACTION * n and cond > PARTIAL_FIT_CONDITION:
        return True
    if cond > MIRRORED_FIT_CONDITION:
        return True
    if not (rolling and threshold > 0):
        return False
    e = errors()[support]
    near = np.count_nonzero((e >= threshold) & (e < NEAR_MISS_WINDOW * threshold))
    return bool(near > NEAR_MISS_RATIO * n_inl)


def checked_final(
    fr: RefinementView,
    final: FinalModel,
    compiled: bool = True,
    bounds2: tuple[float, float] | None = None,
) -> int:
    """The last checks of a final model (:func:`last_checks` on ``final`` within the squared
    velocity bounds ``bounds2``, per unit of the frame's time; None: a camera's
    :attr:`~.frame.Frame.motion_bounds`): the number of the frame's points behind their
    cameras.

    Raises:
        EstimationFailed: ``implausible_motion``, ``cheirality`` (with the points behind).
    """
    if bounds2 is None:
        bounds = fr.motion_bounds
        bounds2 = (
            (np.inf, np.inf) if bounds is None else (float(bounds[0]) ** 2, float(bounds[1]) ** 2)
        )
    # (R, C, w, t are float64 and contiguous here: the refinement's result or np.array copies)
    failure, n_behind = last_checks(fr, final.model, final.inliers, *bounds2, compiled)
    if failure is not None:
        raise EstimationFailed(failure, n_behind)
    return n_behind


def checked_outputs(
    fr: RefinementView,
    final: FinalModel,
    rolling: bool,
    seconds_per_unit: float,
    consistent_fit: bool,
    threshold: float,
    errors: Callable[[], np.ndarray],
    condition: Callable[[], float],
    view_planar: Callable[[int], bool],
    compiled: bool = True,
    *,
    bounds2: tuple[float, float] | None = None,
    support_share: float = 0.0,
    flat: float | None = None,
) -> tuple[int, tuple | None]:
    """The finish of a final model of a camera's or a rig's frame (``fr``, its
    :meth:`~.frame.RefinementView.views`), in order: the last checks (:func:`checked_final`
    within ``bounds2``), with ``consistent_fit`` the consistent-fit test
    (:func:`inconsistent_fit` with ``threshold``, ``errors``, ``condition``, ``view_planar``,
    ``support_share`` and ``flat`` as there), and the output covariances of
    ``final.covariance`` (:func:`~.result.output_covariance` at ``seconds_per_unit`` s per
    unit of the frame's time; 0: no twist).

    Args:
        rolling: a rolling-shutter fit.

    Returns:
        (the number of points behind their cameras, ``(covariance (12, 12), pose (6, 6),
        twist (6, 6) or None)`` in ROS order, or None without ``final.covariance``).

    Raises:
        EstimationFailed: ``implausible_motion``, ``cheirality``, ``inconsistent_fit``.
    """
    behind = checked_final(fr, final, compiled, bounds2)
    if consistent_fit and inconsistent_fit(
        fr.X, final.inliers, final.model, fr.views(), rolling, threshold, errors, condition,
        view_planar, compiled, support_share=support_share, flat=flat,
    ):  # fmt: skip
        raise EstimationFailed(INCONSISTENT_FIT)
    if final.covariance is None:
        return behind, None
    R, C, w, _ = final.model
    return behind, output_covariance(final.covariance, R, C, w, seconds_per_unit, compiled)


def final_estimate(
    fr: Frame,
    solver: str,
    final: FinalModel,
    iterations: int,
    initial: tuple[int, bool],
    timings: dict[str, float],
    /,
    consistent_fit: bool = False,
    gyro_used: bool = False,
    threshold: float = 0.0,
    ignored_inputs: tuple[str, ...] = (),
    compiled: bool = True,
    *,
    flat: float | None = None,
    condition: float | None = None,
    **fields: Any,
) -> RSPoseEstimate:
    """The successful :class:`RSPoseEstimate` of ``final``, after the last word on it:
    plausible motion and every inlier in front of the camera at its capture time
    (:func:`~.plausibility.final_check` on the depths at capture, one compiled call),
    and, with ``consistent_fit``, a consistent fit (else ``inconsistent_fit``):

    - inliers that are one plane of a non-planar frame must not have more than
      :data:`FAR_SIDE_LIMIT` of the other points beyond that plane
      (:func:`~.degeneracy.far_side_fraction`). A plane seen from behind is its own mirror
      image, so mirrored images, reflected maps or a map in a mirrored frame fit one wall of a
      3D scene exactly, from outside the scene, with a confident-looking covariance; a camera
      that really sees a wall sees it from the scene's side;
    - a fit of fewer than :data:`PARTIAL_FIT_FRACTION` of the valid points must not be poorly
      conditioned (above :data:`PARTIAL_FIT_CONDITION`): the same garbage's thicker partial
      fits;
    - a fit of fewer than :data:`MIRRORED_FIT_FRACTION` of the valid points must not be
      conditioned above :data:`MIRRORED_FIT_CONDITION`: a thick part of correspondences no
      rigid pose explains, fitted from far away (any solver);
    - a fit of fewer than :data:`MIRRORED_FIT_FRACTION` of the valid points must not have more
      than :data:`NEAR_MISS_RATIO` of its inlier count in near misses (between ``threshold``
      and :data:`NEAR_MISS_WINDOW` times it, normalized units; 0 skips the test): a part of
      correspondences no rigid pose explains (reflected through the camera centre) fitted with
      its neighbours just missing, where true outliers land anywhere (rolling-shutter solvers
      only: a global-shutter model leaves near misses on any rolling-shutter frame).

    ``initial``: (points the initial model explained or -1, whether it was used);
    ``gyro_used``: the model was solved with a gyro measurement (set on the estimate);
    ``ignored_inputs``: the estimate's (inputs given that were not used); ``compiled=False``:
    the checks and outputs in NumPy (the estimator's NumPy implementation, which the estimate
    records); ``flat``: the inliers' planarity and ``condition``: the condition number the
    estimate reports, when the caller has them (None: :func:`~.degeneracy.planarity` of the
    inliers, :func:`information_condition` of ``final.information``); ``fields``: other
    values of the estimate's fields, set or replacing those set here (``solver``,
    ``motion_model``, ``twist_covariance``, ...; :func:`~.result.built_estimate`). The
    estimate's per-view fields are those of its one view: ``inliers_per_view`` its
    ``inliers``, ``num_inliers_per_view`` its ``num_inliers``, ``num_valid_per_view`` its
    ``num_valid``.

    Raises:
        EstimationFailed: ``implausible_motion``, ``cheirality``, ``inconsistent_fit``.
    """
    (R, C, w, t), inl = final.model, final.inliers
    rolling = solver_info(solver).rolling
    flat = planarity(fr.X, inl, compiled) if flat is None else flat
    cond = information_condition(final.information, rolling, compiled)
    cond = cond if condition is None else condition
    n_behind, cov = checked_outputs(
        fr, final, rolling, fr.spr, consistent_fit, threshold,
        lambda: fr.errors(final.model, compiled), lambda: cond, lambda m: fr.planar, compiled,
        flat=flat,
    )  # fmt: skip
    om, vc = physical_velocities(R, C, w, t, fr.spr, compiled)[:2]
    if cov is not None and not rolling:
        cov = (cov[0], cov[1], None)
    mask = fr.input_mask(inl)
    record = {
        "solver": solver,
        "planar": bool(flat < PLANAR_TOLERANCE),
        "planarity": flat,
        "condition_number": cond,
        "timings": timings,
        "motion_prior_used": final.prior_used,
        "ignored_inputs": ignored_inputs,
    }
    return posed_estimate(
        final, RSPose._trusted(R.T, camera_position(R, C), om, vc),
        ((mask,), (len(fr.x),), fr.num_rows), cov, n_behind, rolling, iterations, initial,
        gyro_used, compiled, **(record | fields),
    )  # fmt: skip


def posed_estimate(
    final: FinalModel,
    pose: RSPose,
    views: tuple,
    covariances: tuple | None,
    num_behind: int,
    rolling: bool,
    iterations: int,
    initial: tuple[int, bool],
    gyro_used: bool,
    compiled: bool = True,
    **fields: Any,
) -> RSPoseEstimate:
    """The successful :class:`RSPoseEstimate` of the final model ``final`` of a camera's frame
    (:func:`final_estimate`) or of a rig frame (:func:`~.rig.estimate_rig_pose`), built by
    :func:`~.result.built_estimate`: its model, ``pose`` (its
    :class:`~rs_localizer.pose.RSPose`), ``views`` (each view's (N_c,) inliers over its input
    rows, each view's valid rows, the input rows of all), ``covariances`` (covariance (12,
    12), pose (6, 6), twist (6, 6) or None in ROS order, or None), ``num_behind`` points
    behind their cameras, its RMS error, model covariance and acceleration sensitivity, the
    ``motion_model`` of ``rolling``, the search's ``iterations`` and ``initial`` (points the
    initial model explained or -1, whether it was used), ``gyro_used`` and the
    ``implementation`` of ``compiled``; ``fields``: the estimator's other fields by name, set
    or replacing those set here."""
    record = {
        "num_behind": num_behind,
        "motion_model": ROLLING_SHUTTER if rolling else GLOBAL_SHUTTER,
        "ransac_iterations": iterations,
        "rmse_px": final.rmse_px,
        "initial_explained": initial[0],
        "initial_used": initial[1],
        "acceleration_sensitivity": final.sensitivity,
        "gyro_used": gyro_used,
        "model_covariance": final.covariance,
    }
    if not compiled:
        record["implementation"] = NUMPY
    R, C, w, t = final.model
    return built_estimate(None, RSModel(R, C, w, t), pose, *views, covariances, **(record | fields))
