"""Marker maps, stage (4): the markers' covariance at the adjustment's solution (the frames
marginalized, the detections weighted for errors that repeat from one viewpoint, widened for
the planar ambiguity of a marker's tilt) and the shape-only covariance of a point set."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np
from scipy.sparse import csr_matrix, diags
from scipy.sparse.linalg import splu

from ..calibration.marginal import marginal_information
from ..geometry import matrix_to_rotvec, rotvec_to_matrix, skew
from .marker_init import mirrored_tilt
from .marker_model import MappingOptions, marker_corners_local
from .marker_problem import MarkerProblem


def _marker_covariance(jac, n_rep: int, sigma: float, prob: MarkerProblem) -> np.ndarray:
    """Covariance (6 M, 6 M) of the adjusted markers' parameters (rotation vector, centre; M =
    ``prob.nm``) at the solution: the markers' block of ``(J^T J)^-1`` with the first ``n_rep``
    rows of ``jac`` (those in pixels) scaled by ``1 / sigma``, the other parameters (frames,
    line delay) marginalized (:func:`marginal_information`); where their block is singular,
    the dense pseudo-inverse of the whole ``J^T J``."""
    J = csr_matrix(jac)
    scale = np.ones(J.shape[0])
    scale[:n_rep] = 1.0 / max(sigma, 1e-12)
    J = diags(scale) @ J
    m0, m1 = prob.moff, prob.moff + 6 * prob.nm
    info = marginal_information(J, np.arange(m0, m1))
    if info is None:
        full = np.linalg.pinv((J.T @ J).toarray(), rcond=1e-12, hermitian=True)
        return full[m0:m1, m0:m1]
    return np.linalg.pinv(info[0], rcond=1e-12, hermitian=True)


def _view_clusters(prob: MarkerProblem, Rf, Cf, Rm_all: dict, angle: float) -> np.ndarray:
    """(D,) cluster label of every detection: detections of one marker whose viewing
    directions (marker -> camera, in the marker's frame) lie within ``angle`` rad of the
    cluster's first one and whose distances differ by less than 30 % share a label."""
    fidx = {k: i for i, k in enumerate(prob.frames)}
    labels = np.full(len(prob.det), -1)
    heads: dict = {}  # marker -> [(label, direction, distance)]
    nxt = 0
    cos_max = np.cos(angle)
    for d, (k, m) in enumerate(prob.det):
        i = fidx[k]
        R, p = Rm_all[m]
        v = R.T @ (-Rf[i].T @ Cf[i] - p)
        dist = float(np.linalg.norm(v))
        u = v / max(dist, 1e-9)
        for lab, u0, d0 in heads.setdefault(m, []):
            if u @ u0 > cos_max and abs(np.log(dist / d0)) < np.log(1.3):
                labels[d] = lab
                break
        else:
            heads[m].append((nxt, u, dist))
            labels[d] = nxt
            nxt += 1
    return labels


def _shared_error_weights(prob: MarkerProblem, x, labels: np.ndarray) -> tuple[np.ndarray, float]:
    """Weights (D,) of the detections in the covariance, and the correlation found.

    A detector's error on a marker repeats when the marker is seen again from the same
    viewpoint (the same image of it: same blur, same pixels on its edges), so detections from
    one viewpoint do not add independent information. The correlation ``rho`` of the
    residuals of consecutive detections of one marker within a viewpoint cluster is
    estimated from the adjustment's own residuals (0 for independent noise); a cluster of
    ``n`` detections then carries the information of ``n / (1 + (n - 1) rho)`` independent
    ones (the design effect of equally correlated samples), and each of its detections is
    weighted by ``1 / (1 + (n - 1) rho)``."""
    e8 = prob.corner_residuals(x).reshape(-1, 8)
    keep = prob.keep
    last: dict = {}
    num = den = 0.0
    for d in range(len(prob.det)):
        if not keep[d]:
            continue
        lab = labels[d]
        if lab in last:
            a, b = e8[last[lab]], e8[d]
            num += float(a @ b)
            den += float(np.sqrt((a @ a) * (b @ b)))
        last[lab] = d
    rho = float(np.clip(num / den, 0.0, 1.0)) if den > 0 else 0.0
    n = np.bincount(labels[keep], minlength=labels.max() + 1)
    w = 1.0 / (1.0 + (n[labels] - 1) * rho)
    return w, rho


def _gauge_covariance(prob: MarkerProblem, sol, weights: np.ndarray) -> tuple[np.ndarray, float]:
    """Joint covariance (6 M, 6 M) of the adjusted markers (gauge: the fixed marker) and the
    estimated pixel noise: reprojection rows weighted by ``weights`` (per detection) and
    scaled by the noise (:func:`_marker_covariance`)."""
    e = prob.corner_residuals(sol.x).reshape(-1, 8)[prob.keep]
    n_rep = e.size
    dof = max(n_rep - prob.n, 1)
    sigma = float(np.sqrt(np.sum(e**2) / dof))
    J = csr_matrix(sol.jac)
    scale = np.ones(J.shape[0])
    scale[:n_rep] = np.repeat(np.sqrt(weights[prob.keep]), 8)
    # (the corner offset's prior row follows the reprojections and is in pixels too)
    n_px = n_rep + (1 if prob.co_col is not None else 0)
    return _marker_covariance(diags(scale) @ J, n_px, sigma, prob), sigma


#: a marker's mirrored tilt whose weighted cost rise (in squared sigmas) exceeds this is
#: rejected: it no longer widens the marker's rotation covariance by the secant
MIRROR_PLAUSIBLE_RISE = 100.0


def _mirror_covariance(prob: MarkerProblem, x, weights, sigma: float, poses: dict) -> dict:
    """id -> (6, 6) covariance to add to a marker's pose for the planar ambiguity of its tilt.

    A square seen from about one direction has two poses that fit it: the true one and its
    tilt mirrored through the viewing direction (the two solutions of IPPE). Far and small,
    both fit almost equally, and the linearized covariance at one of them, which can be sharp
    there, says nothing of the other. For each marker the tilt is mirrored through its mean
    viewing direction (rotation ``delta``, the frames and the centre held), and the rise of
    its weighted reprojection cost ``d = sum w e^2 / sigma^2`` (the frames held, so it
    overstates the rise a re-adjusted map would show) gives the variance along ``delta``:
    up to ``MIRROR_PLAUSIBLE_RISE`` (the mirror within 10 sigmas) the cost's secant,
    ``|delta|^2 / d``; above it the mirror is rejected and the variance is that of the two
    tilts as two hypotheses, the mirror's probability ``p = 1 / (1 + exp(d / 2))``,
    ``p (1 - p) |delta|^2`` (about nothing). Where that exceeds the linearized variance
    along ``delta``, the difference is added along it (rotation block)."""
    Rf, Cf, *_ = prob.unpack(x)
    fidx = {k: i for i, k in enumerate(prob.frames)}
    midx = {m: i for i, m in enumerate(prob.markers)}
    e8 = prob.corner_residuals(x).reshape(-1, 8)
    out = {}
    for m, (R, p) in poses.items():
        rows = [d for d, (k, mm) in enumerate(prob.det) if mm == m and prob.keep[d]]
        if not rows:
            continue
        views = np.array([-Rf[fidx[prob.det[d][0]]].T @ Cf[fidx[prob.det[d][0]]] - p for d in rows])
        delta = mirrored_tilt(R, views)  # (world axes, left perturbation)
        if delta is None:
            continue
        ang = float(np.linalg.norm(delta))
        R_alt = rotvec_to_matrix(delta) @ R
        x_alt = np.array(x, dtype=float)
        Ra_save = prob.Ra
        if m in midx:
            M = x_alt[prob.moff : prob.moff + 6 * prob.nm].reshape(prob.nm, 6)
            M[midx[m], :3] = matrix_to_rotvec(R_alt @ prob.R0m[midx[m]].T)
        else:
            prob.Ra = R_alt
        try:
            e_alt = prob.corner_residuals(x_alt).reshape(-1, 8)
        finally:
            prob.Ra = Ra_save
        w = weights[rows]
        rise = float(np.sum(w * (np.sum(e_alt[rows] ** 2, 1) - np.sum(e8[rows] ** 2, 1))))
        rise = max(rise / sigma**2, 1.0)
        d = delta / ang
        if rise <= MIRROR_PLAUSIBLE_RISE:  # (the cost's secant up to the mirror)
            var = ang**2 / rise
        else:  # (rejected: the two tilts' mixture, the mirror's weight exp(-rise / 2))
            p = 1.0 / (1.0 + np.exp(min(0.5 * rise, 700.0)))
            var = ang**2 * p * (1.0 - p)
        out[m] = (d, var)
    return out


def shape_covariance(points: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """The shape-only part (3 N, 3 N) of the joint covariance ``cov`` (3 N, 3 N) of ``points``
    (N, 3): the covariance projected onto the complement of the rigid motions of all points
    together, ``P cov P^T`` with ``P = I - G G^+`` and ``G`` the (3 N, 6) stacked
    ``[I, -[x_i]x]`` (a small translation and rotation of the whole set). This is the
    minimum-trace (inner-constraint) gauge of bundle adjustment (Triggs, McLauchlan, Hartley,
    Fitzgibbon, "Bundle Adjustment: A Modern Synthesis", 2000, section 9): it does not depend
    on which gauge ``cov`` was computed in, and it is the covariance of the points after a
    best rigid fit of the whole set onto its mean (to first order). What it keeps is each
    point's error relative to the others, which is what a camera localized against the
    points sees; the uncertainty of where the whole set sits goes to the frame."""
    x = np.asarray(points, float)
    n = len(x)
    G = np.zeros((3 * n, 6))
    for i, c in enumerate(x - x.mean(0)):
        G[3 * i : 3 * i + 3, :3] = np.eye(3)
        G[3 * i : 3 * i + 3, 3:] = -skew(c)
    P = np.eye(3 * n) - G @ np.linalg.pinv(G)
    return P @ np.asarray(cov, float) @ P.T


def corner_jacobian(R_o: np.ndarray) -> np.ndarray:
    """(3, 6) derivative of a marker corner ``c = p + R o`` (m, map frame) with respect to its
    marker's pose perturbation (rotation vector applied on the left, rad; centre, m), the
    order of ``MarkerMapResult.marker_covariance``: ``[-[R o]x, I]``. ``R_o``: (3,) the
    corner's offset ``R o`` from the marker centre (m, map frame)."""
    return np.hstack([-skew(np.asarray(R_o, float)), np.eye(3)])


def corner_shape_std(poses: dict, ids: list, cov: np.ndarray, sides: dict, keep: Iterable) -> dict:
    """id -> (4,) shape-only std of each corner of the markers in ``keep`` (m, rms per axis:
    ``sqrt(trace / 3)``): the joint covariance of all their corners, ``J cov J^T`` with a
    corner ``c = p + R o`` moving by ``[-[R o]x, I]`` with its marker's pose perturbation
    (``ids``' order in ``cov``), projected by :func:`shape_covariance`."""
    ms = [m for m in ids if m in keep]
    ms = list(dict.fromkeys(ms))
    J = np.zeros((12 * len(ms), cov.shape[0]))
    pts = []
    for a, m in enumerate(ms):
        R, p = poses[m]
        j = 6 * ids.index(m)
        for k, o in enumerate(marker_corners_local(sides[m])):
            ro = R @ o
            r = 12 * a + 3 * k
            J[r : r + 3, j : j + 6] = corner_jacobian(ro)
            pts.append(p + ro)
    S = shape_covariance(np.array(pts), J @ cov @ J.T)
    d = np.clip(np.diag(S), 0.0, None).reshape(len(ms), 4, 3)
    return {m: np.sqrt(d[a].sum(1) / 3.0) for a, m in enumerate(ms)}


def line_delay_std(prob: MarkerProblem, sol: Any, weights: np.ndarray) -> float:
    """Standard deviation (s) of the calibrated line delay at the adjustment's solution: the
    line delay's diagonal element of ``(J^T J)^-1`` with the reprojection rows weighted as
    the markers' covariance (:func:`_gauge_covariance`: ``weights`` per detection, scaled by
    the estimated pixel noise), every other parameter (frames, markers, corner offset)
    marginalized (a sparse LU solve of ``J^T J x = e``; the dense pseudo-inverse where it is
    singular). The gauge marker is fixed; neither the corner model (in a world centred on each
    frame's camera) nor the motion tie depends on the world frame, so the output frame does not
    change the line delay or its std. NaN without ``calibrate_readout``."""
    if prob.ld_col is None:
        return float("nan")
    e = prob.corner_residuals(sol.x).reshape(-1, 8)[prob.keep]
    n_rep = e.size
    sigma = float(np.sqrt(np.sum(e**2) / max(n_rep - prob.n, 1)))
    scale = np.ones(sol.jac.shape[0])
    scale[:n_rep] = np.repeat(np.sqrt(weights[prob.keep]), 8) / max(sigma, 1e-12)
    n_px = n_rep + (1 if prob.co_col is not None else 0)
    scale[n_rep:n_px] /= max(sigma, 1e-12)
    J = diags(scale) @ csr_matrix(sol.jac)
    H = (J.T @ J).tocsc()
    rhs = np.zeros(H.shape[0])
    rhs[prob.ld_col] = 1.0
    try:
        with np.errstate(all="raise"):
            x = splu(H).solve(rhs)
        var = float(x[prob.ld_col])
        if not np.isfinite(var):
            raise FloatingPointError
    except (RuntimeError, FloatingPointError):
        var = float(
            np.linalg.pinv(H.toarray(), rcond=1e-12, hermitian=True)[prob.ld_col, prob.ld_col]
        )
    # (the parameter is in microseconds)
    return float(np.sqrt(max(var, 0.0))) * 1e-6


def covariance_in_gauge(
    prob: MarkerProblem, sol: Any, poses: dict, options: MappingOptions, gauge: int
) -> tuple[list, np.ndarray, float]:
    """Joint covariance of every marker's pose in the adjustment's gauge (the gauge marker
    held fixed): the viewpoint clusters of the detections (``options.view_cluster_rad``),
    their weights for errors that repeat from one viewpoint (:func:`_shared_error_weights`,
    when ``options.shared_errors``), the markers' block of ``(J^T J)^-1``
    (:func:`_gauge_covariance`) and, when ``options.planar_ambiguity``, each marker's rotation
    widened along its mirrored tilt (:func:`_mirror_covariance`). ``sol``: SciPy's
    ``least_squares`` result of ``prob``; ``poses``: id -> ``(R (3, 3), p (3,))`` in the
    adjustment's frame.

    Returns:
        ``(ids, cov, rho, line_delay_std)``: the adjusted markers then ``gauge``; the (6 M,
        6 M) covariance in that order (rotation vector rad, world axes, left perturbation;
        centre m; the gauge marker uncorrelated with the others, only its tilt's ambiguity);
        the correlation of the detections' errors from one viewpoint (0 when not estimated);
        the calibrated line delay's std (s, :func:`line_delay_std`; NaN when not calibrated).
    """
    Rf, Cf, *_ = prob.unpack(sol.x)
    labels = _view_clusters(prob, Rf, Cf, poses, options.view_cluster_rad)
    weights, rho = (
        _shared_error_weights(prob, sol.x, labels)
        if options.shared_errors
        else (np.ones(len(prob.det)), 0.0)
    )
    cov_gauge, sigma = _gauge_covariance(prob, sol, weights)
    # the gauge marker joins as a variable of its own, uncorrelated with the others: its
    # only uncertainty in the gauge is the ambiguity of its tilt
    ids = [*prob.markers, gauge]
    n = 6 * len(prob.markers)
    cov = np.zeros((n + 6, n + 6))
    cov[:n, :n] = cov_gauge
    if options.planar_ambiguity:
        for m, (d, var) in _mirror_covariance(prob, sol.x, weights, sigma, poses).items():
            i = 6 * ids.index(m)
            lin = float(d @ cov[i : i + 3, i : i + 3] @ d)
            if var > lin:
                cov[i : i + 3, i : i + 3] += (var - lin) * np.outer(d, d)
    return ids, cov, rho, line_delay_std(prob, sol, weights)
