"""Correspondences whose 3D points are known to different precisions (a built map states a
standard deviation per marker): the final fit weighs each point by its total image noise
(:func:`weighted_final_model`, ``estimate_rs_pose(..., point_sigma=)``).

A map point known to ``sigma_map`` (m, per axis) at depth ``z`` moves its image by about
``f sigma_map / z``; with the detection noise ``sigma_det`` each point's image error has the
standard deviation ``sqrt(sigma_det^2 + (f sigma_map / z)^2)``. The estimator's inlier
threshold is two detection standard deviations, so ``sigma_det = threshold / 2``. RANSAC and
its inlier test are unchanged; the weighted fit refines the final model on the points whose
weighted error lies within :data:`~rs_localizer.estimation.finalize.FINAL_CUTOFF`
thresholds (Huber weights held fixed), by SciPy ``least_squares`` with the exact
constant-velocity model (paper eq. 4) and the frame's motion prior as the unweighted
refinement uses it.
"""

from __future__ import annotations

import numpy as np

from ..geometry import rotvec_to_matrix
from ..pose import RSModel
from ..solvers.registry import solver_info
from .finalize import FINAL_CUTOFF, FinalModel, posterior_if_consistent, selected_final
from .frame import Frame
from .plausibility import finite_model
from .prior import prior_arrays
from .refine import RefineResult, exact_errors, least_squares_exact_model
from .result import EstimationFailed

__all__ = ["check_point_sigma", "point_weights", "weighted_final_model"]


def check_point_sigma(point_sigma: np.ndarray, num_rows: int) -> np.ndarray:
    """``point_sigma`` as a float (num_rows,) array of finite values >= 0.

    Raises:
        ValueError: another shape, a negative or non-finite value.
    """
    s = np.asarray(point_sigma, dtype=float)
    if s.shape != (num_rows,):
        raise ValueError(f"point_sigma must have shape ({num_rows},), got {s.shape}")
    if not (np.isfinite(s).all() and (s >= 0).all()):
        raise ValueError("point_sigma must be finite and >= 0 (m)")
    return s


def point_weights(sigma_m: np.ndarray, depth: np.ndarray, sigma_det: float) -> np.ndarray:
    """Weights ``sigma_det / sqrt(sigma_det^2 + (sigma_m / depth)^2)`` in (0, 1] (normalized
    image units: ``sigma_det`` and ``sigma_m / depth``): 1 for an exact map point."""
    s_map = np.asarray(sigma_m, float) / np.maximum(np.asarray(depth, float), 1e-9)
    return sigma_det / np.sqrt(sigma_det**2 + s_map**2)


def weighted_final_model(
    fr: Frame, solver: str, final: FinalModel, point_sigma: np.ndarray, min_inliers: int
) -> FinalModel:
    """The final model refined with each point weighted by its map precision.

    The points: those whose weighted error on the unweighted final model lies within
    :data:`~.finalize.FINAL_CUTOFF` thresholds; each also gets the Huber weight of that
    error (scale the threshold; one reweighting, held fixed). The errors are those of the
    unweighted refinement (each point's whitened by :attr:`~.frame.Frame.W`: in pixels of the
    measured image). The fit: SciPy ``least_squares`` on the exact model, the residuals
    scaled by ``weight * huber``; with the
    frame's motion prior as the unweighted refinement uses it (:func:`~.finalize.final_refinement`):
    in the fit for planar frames (``fr.prior``, the weighted residuals' unit ``sigma_det`` as
    the noise that weighs it), else maximum likelihood and then, when it does not conflict
    with the data and would move them, the closed-form MAP step
    (:func:`~.refine.posterior_step`).

    Args:
        fr: the frame; solver: its solver (global shutter: ``w = t = 0`` stay fixed).
        final: the unweighted final model (:func:`~.finalize.refine_final_model`).
        point_sigma: (N,) the standard deviation (m, per axis) of each of the frame's 3D points
            (in the frame's row order).
        min_inliers: fewest inliers a model may have.
    Returns:
        A new :class:`~.finalize.FinalModel` (inliers and RMS on the weighted model, the
        covariance ``s^2 (J_w^T J_w)^-1`` with ``s^2`` the weighted residuals' variance, or
        the posterior's; no acceleration sensitivity), or ``final`` itself when the weighted
        fit cannot apply: all points exact, too few points, a fit that does not converge to
        a finite model, or fewer than ``min_inliers`` inliers.
    """
    if not np.any(point_sigma > 0):
        return final
    th = fr.threshold
    s_det = th / 2.0
    R, C, w, t = (np.asarray(a, dtype=float) for a in final.model)
    tau = fr.r - fr.r0
    depth = fr.X @ R[2] + C[2]
    wgt = point_weights(point_sigma, depth, s_det)
    e = wgt * exact_errors(R, C, w, t, fr.X, fr.x, tau, fr.W)
    use = np.isfinite(e) & (depth > 0) & (e < FINAL_CUTOFF * th)
    rolling = solver_info(solver).rolling and fr.spr > 0
    n_free = 12 if rolling else 6
    if use.sum() < max(min_inliers, n_free // 2 + 1):
        return final
    huber = np.sqrt(th / np.maximum(e[use], th))
    fit_prior = fr.prior if rolling else None
    fit = least_squares_exact_model(
        R,
        np.concatenate([np.zeros(3), C, w, t]),
        n_free,
        fr.X[use],
        fr.x[use],
        tau[use],
        fit_prior,
        fr.spr,
        s_det,
        row_weights=np.repeat(wgt[use] * huber, 2),
        mountings=fr.mountings(np.flatnonzero(use)),
    )
    res, th_ = fit.result, fit.theta
    model = RSModel(rotvec_to_matrix(th_[:3]) @ R, th_[3:6], th_[6:9], th_[9:12])
    if not res.success or not finite_model(*model):
        return final
    J = fit.jac(res.x)
    nd = 2 * int(use.sum())
    Jd, rd = J[:nd], res.fun[:nd]
    s2 = float(rd @ rd) / max(nd - n_free, 1)
    info = np.zeros((12, 12))
    info[:n_free, :n_free] = Jd.T @ Jd
    grad = np.zeros(12)
    grad[:n_free] = Jd.T @ rd
    cov = np.zeros((12, 12))
    try:
        cov[:n_free, :n_free] = s2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        cov = None
    prior_used = bool(prior_arrays(fit_prior)[0])  # (a prior that constrains nothing is not used)
    if cov is not None and np.isfinite(cov).all():
        ref = RefineResult(*model, cov, float(np.sqrt(s2)), True, int(res.nfev))
        ref.data_information, ref.data_gradient = info, grad
        if not prior_used and rolling and fr.final_prior is not None:
            post, used = posterior_if_consistent(ref, fr.final_prior, fr.spr)
            if used and finite_model(post.R, post.C, post.w, post.t):
                model = RSModel(post.R, post.C, post.w, post.t)
                cov, prior_used = post.covariance, True
    else:
        cov = None
    try:
        weighted = selected_final(fr, model, th, min_inliers, fr.f)
    except EstimationFailed:
        return final
    weighted.covariance, weighted.information, weighted.prior_used = cov, info, prior_used
    return weighted
