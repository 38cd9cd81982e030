"""Spatially correlated image error in the estimator's covariance.

The refinement's covariance (:func:`rs_localizer.estimation.refine.refine_rs_pose`) assumes
independent image noise per point and axis, its variance estimated from the residuals. Real
cameras add a smooth systematic error that no pose explains: what the calibration's lens model
misses, corner-detector bias, a board that is not quite flat. Neighbouring points share it. On
OpenCV's still checkerboard photos (``test/data/photos/left*.jpg``) the global-shutter
residuals of neighbouring corners correlate by ~0.5, and the 6 velocities of the RS model
absorb that error as well with the column as "capture time" as with the row
(``python -m benchmarks.still_boards``): the white-noise covariance then reports
a still camera moving at 1-3 rad/s with twist Mahalanobis distances of 15-134.

Model (per image axis, the two axes independent)::

    e = n + m,   Cov(n_i, n_j) = sigma^2 delta_ij,
                 Cov(m_i, m_j) = s^2 exp(-|u_i - u_j|^2 / (2 l^2))

``u`` the measured pixels, ``sigma`` the white noise (the refinement's residual estimate, as
before), ``s`` (px) and ``l`` (px) the correlated error's standard deviation and correlation
length: camera properties, estimated once from still calibration views by restricted maximum
likelihood (:func:`fit_correlated_noise`), set with
``EstimateOptions(correlated_noise=CorrelatedNoise(sigma_px, length_px))`` (node:
``correlated_noise.sigma_px`` / ``.length_px``).

The estimate itself is unchanged (the white-noise (MAP) refinement); only its covariance is:
the sandwich covariance of that estimator under the model above,
:func:`correlated_noise_covariance`.

A square marker's corners share more than a smooth field: the detector fits the tag's four
edges together, and blur, lighting and the quad fit move the four corners of one tag in one
image as one (on real AprilTag recordings two corners' errors of one tag correlate by 0.6-0.9,
the common shift ~60 % of a corner's error variance, ``python -m benchmarks.reference_fit``).
Points given a group (:attr:`~rs_localizer.estimation.view.View.groups`, a marker's id) take
the model::

    e = n + g,   Cov(n_i, n_j) = s_n^2 delta_ij,   Cov(g_i, g_j) = s_g^2 [group_i = group_j]

per image axis, with ``s_n`` and ``s_g`` estimated from the frame's own residuals
(:func:`shared_shift_variances`), and the covariance is the sandwich under it
(:func:`shared_shift_covariance`). A frame of a few groups cannot tell a shift from its own
residuals (the pose absorbs the groups' shifts): there the covariance takes the share
``s_g^2 / (s_n^2 + s_g^2)`` the options give (``correlated_noise.shift_share``; 0, the
default: the white noise's covariance).
"""

from __future__ import annotations

from contextlib import ExitStack
from dataclasses import dataclass

import numpy as np

from ..camera import CameraModel
from .refine import RefineSettings, exact_jacobian, exact_residuals, refine_rs_pose

__all__ = [
    "MIN_SHIFT_DOF",
    "NoiseFit",
    "correlated_noise_covariance",
    "fit_correlated_noise",
    "pixel_jacobians",
    "shared_shift_covariance",
    "shared_shift_variances",
]

#: the fewest degrees of freedom of the groups' mean errors left after the fit (2 per group,
#: less what the model absorbs) for a frame to estimate the groups' common shift from its own
#: residuals; below it the covariance stays the white-noise one
MIN_SHIFT_DOF = 4.0


def _kernel(u_px, length_px):
    """(N, N) ``exp(-|u_i - u_j|^2 / (2 l^2))`` of pixels u (N, 2)."""
    d2 = np.sum((u_px[:, None, :] - u_px[None, :, :]) ** 2, axis=-1)
    return np.exp(-0.5 * d2 / (float(length_px) ** 2))


def correlated_noise_covariance(
    cov12: np.ndarray,
    sigma: float,
    R: np.ndarray,
    C: np.ndarray,
    w: np.ndarray,
    t: np.ndarray,
    X: np.ndarray,
    x: np.ndarray,
    tau: np.ndarray,
    u_px: np.ndarray,
    pixel_jac: np.ndarray,
    correlated_px: float,
    length_px: float,
    whitening: np.ndarray | None = None,
) -> np.ndarray:
    """Covariance of the refined (delta, C, w, t) under white plus correlated image noise.

    The refinement minimises ``sum |W_i r_i|^2 + sigma^2 (prior)`` over normalized residuals
    r (``W_i`` the point's whitening, :attr:`~.frame.Frame.W`; the identity without);
    linearised, its error is ``B sum J_i^T M_i e_i + B sigma^2 P (mu - z)`` with
    ``M_i = W_i^T W_i`` and ``B = (sum J_i^T M_i J_i + sigma^2 P)^-1 = cov12 / sigma^2``. The
    correlated error is in pixels (module doc); in normalized units
    ``Cov(e_i, e_j) = s^2 k_ij D_i^-1 D_j^-T`` (``D_i`` the projection's pixel Jacobian at
    point i, ``k_ij`` the kernel), so the covariance of the estimate is the sandwich::

        cov12 + s^2 B (G_x^T K G_x + G_y^T K G_y) B,   G_i = D_i^-T M_i J_i (2, 12)

    (``G_x``, ``G_y`` the x and y rows). ``correlated_px = 0`` returns a copy of cov12.

    Args:
        cov12: (12, 12) white-noise covariance of (delta, C, w, t) from
            :func:`~rs_localizer.estimation.refine.refine_rs_pose` (normalized units; zero
            rows and columns for fixed parameters).
        sigma: its residual sigma (normalized units, > 0).
        R (3, 3), C, w, t (3,): the refined model (``X_cam = R X + C`` at the reference row).
        X: (N, 3) world points, x: (N, 2) normalized observations, tau: (N,) ``r_i - r0`` of
            the points the covariance is computed on (the final inliers).
        u_px: (N, 2) their measured pixels (the correlation is over image distance).
        pixel_jac: (N, 2, 2) ``d pixel / d x`` at x (:func:`pixel_jacobians`).
        correlated_px, length_px: ``s`` and ``l`` of the module doc (px).
        whitening: (N, 2, 2) each point's whitening ``W_i`` in the refinement that gave
            cov12 (the rows of :attr:`~.frame.Frame.W` of these points, as its
            :meth:`~.frame.Frame.mountings`), or ``None``: none (``W_i`` the identity).
    Returns:
        (12, 12) covariance, same units and order as cov12.
    Raises:
        ValueError: for mismatched point arrays or a non-positive length or sigma.
    """
    cov12 = np.asarray(cov12, dtype=float)
    if correlated_px <= 0 or len(X) == 0:
        return cov12.copy()
    u = np.asarray(u_px, dtype=float)
    Dj = np.asarray(pixel_jac, dtype=float)
    Wn = None if whitening is None else np.asarray(whitening, dtype=float).reshape(-1, 2, 2)
    nw = len(Dj) if Wn is None else len(Wn)
    if not (len(u) == len(X) == len(x) == len(tau) == len(Dj) == nw):
        raise ValueError(
            f"point arrays disagree: {len(u)}, {len(X)}, {len(x)}, {len(tau)}, {len(Dj)}, {nw}"
        )
    if not (length_px > 0 and sigma > 0):
        raise ValueError(f"need length_px, sigma > 0, got {length_px}, {sigma}")
    J = exact_jacobian(np.r_[0.0, 0.0, 0.0, C, w, t], np.asarray(R, float), X, x, tau)
    J = J.reshape(-1, 2, 12)
    if Wn is not None:
        J = np.einsum("nba,nbc,nck->nak", Wn, Wn, J)  # M_i J_i
    G = np.linalg.solve(np.swapaxes(Dj, 1, 2), J)  # D_i^-T M_i J_i
    K = _kernel(u, length_px)
    Gx, Gy = G[:, 0, :], G[:, 1, :]
    M = Gx.T @ K @ Gx + Gy.T @ K @ Gy
    B = cov12 / sigma**2
    out = cov12 + correlated_px**2 * (B @ M @ B)
    return 0.5 * (out + out.T)


def _group_columns(groups: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """``(order (2N,), starts (2G,), 2G)`` of the groups' indicator Z (one column per group
    and image axis) over the 2N rows (x, y interleaved) of N points in ``groups`` (N,): the
    rows in the order of their columns and where each column's rows start in it
    (:func:`_group_sums`)."""
    g = np.asarray(groups, dtype=np.int64).reshape(-1)
    col = np.empty(2 * len(g), dtype=np.int64)
    col[0::2] = 2 * g
    col[1::2] = 2 * g + 1
    order = np.argsort(col, kind="stable")
    sorted_col = col[order]
    starts = np.flatnonzero(np.r_[True, sorted_col[1:] != sorted_col[:-1]])
    return order, starts, len(starts)


def _group_sums(A: np.ndarray, order: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """``Z^T A``: the rows of A ((2N,) or (2N, P)) summed per column of the groups' indicator
    Z (:func:`_group_columns`' ``order`` and ``starts``)."""
    return np.add.reduceat(A[order], starts, axis=0)


def _variances(r, J, K, order, starts, share=0.0) -> tuple[float, float, float, np.ndarray, bool]:
    """:func:`shared_shift_variances` with the groups as :func:`_group_columns` gives them,
    ``K Z`` (P, 2G) and whether the residuals told the shared variance (else the share's or
    none)."""
    n2, P = J.shape
    sums = _group_sums(np.column_stack([J, K.T, r]), order, starts)
    ZJ, KZ, Zr = sums[:, :P], sums[:, P : 2 * P].T, sums[:, -1]  # Z^T J, K Z, Z^T r
    counts = np.diff(np.r_[starts, n2]).astype(float)  # (Z^T Z, diagonal)
    JtJ, KKt = J.T @ J, K @ K.T
    cross = float(np.sum(ZJ * KZ.T))  # tr(Z^T J K Z)
    a11 = n2 - 2.0 * float(np.sum(K * J.T)) + float(np.sum(JtJ * KKt))
    tz = float(n2)
    a12 = tz - 2.0 * cross + float(np.sum(KZ * (JtJ @ KZ)))
    a21 = tz - 2.0 * cross + float(np.sum(ZJ * (ZJ @ KKt)))
    ZMZ = -(ZJ @ KZ)
    ZMZ[np.diag_indices(len(counts))] += counts
    a22 = float(np.sum(ZMZ**2))
    dof = float(np.sum(np.diag(ZMZ) / counts))
    q1, q2 = float(r @ r), float(Zr @ Zr)
    det = a11 * a22 - a12 * a21
    white = max(q1 / a11, 0.0) if a11 > 0 else 0.0
    if dof < MIN_SHIFT_DOF or not det > 1e-12 * a11 * a22:
        if share > 0.0 and a11 > 0:  # (E q1 = a11 s_n^2 + a12 s_g^2, s_g^2 = kappa s_n^2)
            kappa = share / (1.0 - share)
            s_n2 = max(q1 / (a11 + kappa * a12), 0.0)
            return s_n2, kappa * s_n2, dof, KZ, False
        return white, 0.0, dof, KZ, False
    s_n2 = (a22 * q1 - a12 * q2) / det
    s_g2 = (a11 * q2 - a21 * q1) / det
    if s_g2 <= 0.0:
        return white, 0.0, dof, KZ, True
    if s_n2 < 0.0:
        return 0.0, max(q1 / a12, 0.0) if a12 > 0 else 0.0, dof, KZ, True
    return float(s_n2), float(s_g2), dof, KZ, True


def shared_shift_variances(
    residuals: np.ndarray,
    J: np.ndarray,
    K: np.ndarray,
    groups: np.ndarray,
    share: float = 0.0,
) -> tuple[float, float, float]:
    """The white and the shared variance of a frame's image errors under the grouped model of
    the module doc, from the residuals of one least-squares fit (method of moments).

    The residuals of the fit are ``rho = M e``, ``M = I - J K`` (``K`` the map from the errors
    to the fitted parameters, ``delta = K e``); with ``Z`` the groups' indicator (one column
    per group and axis) ``E|rho|^2 = s_n^2 |M|^2 + s_g^2 |M Z|^2`` and ``E|Z^T rho|^2 = s_n^2
    |Z^T M|^2 + s_g^2 |Z^T M Z|^2`` (Frobenius norms); the two equations solved for ``s_n^2``,
    ``s_g^2`` (both at least 0).

    Args:
        residuals: (2N,) the fit's residuals, x and y of each point interleaved (any units:
            the variances come in their square).
        J: (2N, P) their Jacobian over the P fitted parameters. K: (P, 2N) the fit's gain
            (``H^-1 J^T W``: ``H`` the normal matrix, ``W`` the points' weights).
        groups: (N,) int each point's group (points of one group share a shift).
        share: the shift's share of a point's error variance, ``s_g^2 / (s_n^2 + s_g^2)`` in
            [0, 1), taken where the residuals cannot tell it (below): ``s_g^2 = kappa
            s_n^2``, ``kappa = share / (1 - share)``, and ``s_n^2`` from the first equation.
    Returns:
        ``(s_n^2, s_g^2, dof)``: the two variances and the degrees of freedom of the groups'
        mean errors the fit leaves (``tr(Z^T M Z (Z^T Z)^-1)``: 2 per group less what the
        fitted parameters absorb); where ``dof`` is below :data:`MIN_SHIFT_DOF` (a fit that
        absorbs the groups' shifts cannot tell them) ``s_g^2`` is ``share``'s, 0 without.
    Raises:
        ValueError: arrays of mismatched lengths, a share outside [0, 1).
    """
    r = np.asarray(residuals, dtype=float)
    J = np.asarray(J, dtype=float)
    K = np.asarray(K, dtype=float)
    g = np.asarray(groups)
    if not (J.shape[0] == len(r) == K.shape[1] == 2 * len(g) and J.shape[1] == K.shape[0]):
        raise ValueError(
            f"shared_shift_variances: residuals {r.shape}, J {J.shape}, K {K.shape} and "
            f"groups {g.shape} disagree"
        )
    if not 0.0 <= share < 1.0:
        raise ValueError(f"shared_shift_variances: share must be in [0, 1), got {share!r}")
    order, starts, _ = _group_columns(g)
    return _variances(r, J, K, order, starts, float(share))[:3]


def shared_shift_covariance(
    cov: np.ndarray,
    sigma: float,
    J: np.ndarray,
    weights: np.ndarray,
    residuals: np.ndarray,
    groups: np.ndarray,
    share: float = 0.0,
    floor: float = 0.0,
) -> tuple[np.ndarray, float, float]:
    """The covariance of a refined estimate under white noise plus a shift shared by each
    group's points (module doc), in place of the white noise's alone.

    The refinement minimised ``sum w_i |r_i|^2`` (+ a prior), its covariance ``cov = sigma^2
    H^-1``; linearised, its error is ``H^-1 J^T W e``. With the variances of
    :func:`shared_shift_variances` (``K = H^-1 J^T W``) the covariance is::

        cov + (s_n^2 - sigma^2) K K^T + s_g^2 (K Z)(K Z)^T

    (the white-noise part replaced by the sandwich under the grouped model; ``cov`` itself
    when the frame cannot tell a shared shift: ``s_g^2 = 0``).

    Args:
        cov: (P, P) the refinement's covariance over its P free parameters (the units of J's
            columns). sigma: its residual sigma (the residuals' units, > 0).
        J: (2N, P) the residuals' Jacobian at the estimate (x, y interleaved), the points the
            refinement weighed; weights: (N,) their weights ``w_i`` (Huber's; 1 inside the
            threshold). residuals: (2N,) their residuals. groups: (N,) their groups.
        share: the shift's share of a point's error variance where the residuals cannot
            tell it (:func:`shared_shift_variances`; 0: the white noise's covariance there).
        floor: the least white variance ``s_n^2`` (the residuals' units squared; a fit whose
            noise has a floor, e.g. a few points' pose, :mod:`.single_tag`); with ``share``
            the shared one follows it.
    Returns:
        ``(covariance (P, P) symmetrized, s_n^2, s_g^2)``.
    Raises:
        ValueError: arrays of mismatched lengths, a sigma that is not > 0 or a share outside
            [0, 1).
    """
    if not 0.0 <= share < 1.0:
        raise ValueError(f"shared_shift_covariance: share must be in [0, 1), got {share!r}")
    if not sigma > 0:
        raise ValueError(f"shared_shift_covariance: sigma must be > 0, got {sigma!r}")
    cov = np.asarray(cov, dtype=float)
    J = np.asarray(J, dtype=float)
    r = np.asarray(residuals, dtype=float)
    g = np.asarray(groups)
    w = np.asarray(weights, dtype=float)
    if not (J.shape == (len(r), len(cov)) == (2 * len(g), len(cov)) and len(w) == len(g)):
        raise ValueError(
            f"shared_shift_covariance: cov {cov.shape}, J {J.shape}, weights {w.shape}, "
            f"residuals {r.shape} and groups {g.shape} disagree"
        )
    K = (cov / sigma**2) @ (J * np.repeat(w, 2)[:, None]).T
    order, starts, _ = _group_columns(g)
    s_n2, s_g2, _, KZ, told = _variances(r, J, K, order, starts, float(share))
    if s_g2 <= 0.0:
        return cov.copy(), s_n2, 0.0
    if s_n2 < floor:
        s_n2 = float(floor)
        s_g2 = s_g2 if told else share / (1.0 - share) * s_n2
    out = cov + (s_n2 - sigma**2) * (K @ K.T) + s_g2 * (KZ @ KZ.T)
    return 0.5 * (out + out.T), s_n2, s_g2


@dataclass(frozen=True)
class NoiseFit:
    """Result of :func:`fit_correlated_noise` (all in pixels, per image axis).

    Attributes:
        white_px: standard deviation of the independent noise ``sigma``.
        correlated_px: standard deviation ``s`` of the correlated error.
        length_px: its correlation length ``l``.
        log_likelihood_ratio: restricted log-likelihood of the fit minus that of white noise
            alone (``s = 0``): twice it is ~chi-square with 2 dof when there is no correlated
            error (a value of a few means no evidence for it).
        views, points: views and points used.
    """

    white_px: float
    correlated_px: float
    length_px: float
    log_likelihood_ratio: float
    views: int
    points: int


def pixel_jacobians(camera: CameraModel, x: np.ndarray, step: float = 1e-6) -> np.ndarray:
    """(N, 2, 2) Jacobians ``d pixel / d x`` of the camera's projection (distortion and K) at
    the undistorted normalized points x (N, 2), by central differences of
    :meth:`~rs_localizer.camera.CameraModel.distort`."""
    x = np.asarray(x, dtype=float)
    out = np.empty((len(x), 2, 2))
    for a in range(2):
        h = np.zeros(2)
        h[a] = step
        out[:, :, a] = (camera.distort(x + h) - camera.distort(x - h)) / (2 * step)
    return out


def _view_terms(camera, uv, X, R, C):
    """Global-shutter refinement of one still view: (residuals px (2N,), their Jacobian
    (2N, 6) w.r.t. the pose, pixels (N, 2)), residuals and Jacobian mapped to pixels through
    the local projection Jacobian (so that the noise model is the one of the pixels)."""
    x, _, _ = camera.normalize(uv)
    tau = np.zeros(len(x))
    z3 = np.zeros(3)
    ref = refine_rs_pose(
        (R, C, z3, z3),
        X,
        x,
        tau,
        1e3,
        RefineSettings(rolling_shutter=False, max_iterations=50, tol=1e-14, covariance=False),
    )
    th = np.r_[0.0, 0.0, 0.0, ref.C, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    D = pixel_jacobians(camera, x)
    r = np.einsum("nab,nb->na", D, exact_residuals(th, ref.R, X, x, tau).reshape(-1, 2))
    J = np.einsum("nab,nbk->nak", D, exact_jacobian(th, ref.R, X, x, tau)[:, :6].reshape(-1, 2, 6))
    return r.ravel(), J.reshape(-1, 6), np.asarray(uv, dtype=float)


def _restricted_nll(p, terms):
    """Negative restricted log-likelihood (up to a constant) of log (sigma^2, s^2, l)."""
    from scipy.linalg import cho_factor, cho_solve, solve_triangular

    sw2, s2, ell = np.exp(p)
    tot = 0.0
    for r, J, u in terms:
        K1 = s2 * _kernel(u, ell)
        n = len(u)
        S = np.zeros((2 * n, 2 * n))
        S[0::2, 0::2] = K1
        S[1::2, 1::2] = K1
        S[np.diag_indices(2 * n)] += sw2
        try:
            L = np.linalg.cholesky(S)
        except np.linalg.LinAlgError:
            return np.inf
        LJ = solve_triangular(L, J, lower=True)
        Lr = solve_triangular(L, r, lower=True)
        A = LJ.T @ LJ
        b = LJ.T @ Lr
        cA = cho_factor(A)
        tot += (
            2.0 * np.log(np.diag(L)).sum()
            + 2.0 * np.log(np.diag(cA[0])).sum()
            + Lr @ Lr
            - b @ cho_solve(cA, b)
        )
    return 0.5 * tot


def fit_correlated_noise(
    camera: CameraModel,
    views: list,
    length_bounds_px: tuple[float | None, float] = (None, 2000.0),
) -> NoiseFit:
    """Estimate the image noise model of the module doc from still views of a known planar
    or 3D target (e.g. the calibration images), by restricted maximum likelihood (REML: the
    likelihood of the residuals with the 6 pose parameters of each view integrated out, so
    that what a pose absorbs is not mistaken for noise).

    Each view's pose is refined first (global shutter, maximum likelihood from the given
    pose). The views must be still (no motion during the readout): their residuals are then
    image error only.

    Args:
        camera: :class:`~rs_localizer.camera.CameraModel` (intrinsics and distortion; the
            readout timing is not used).
        views: iterable of ``(uv_px (N, 2), X (N, 3), R (3, 3), C (3,))``: measured pixels,
            world points and a starting pose (``X_cam = R X + C``, e.g. a P3P estimate or the
            calibration's extrinsics), all points inliers.
        length_bounds_px: search bounds of the correlation length (px); lower bound
            ``None``: the median distance between neighbouring points (a shorter correlation
            cannot be told from white noise: the fit would trade one for the other).
    Returns:
        :class:`NoiseFit`.
    Raises:
        ValueError: no view, or a view with fewer than 7 points.
    """
    from scipy.optimize import minimize  # (here: start-up time of the estimator's importers)

    terms = []
    for uv, X, R, C in views:
        if len(uv) < 7:
            raise ValueError(f"a view needs at least 7 points, got {len(uv)}")
        terms.append(
            _view_terms(
                camera,
                np.asarray(uv, float),
                np.asarray(X, float),
                np.asarray(R, float),
                np.asarray(C, float),
            )
        )
    if not terms:
        raise ValueError("no view")
    n = sum(len(t[2]) for t in terms)
    dof = sum(len(t[0]) - 6 for t in terms)
    v0 = sum(float(t[0] @ t[0]) for t in terms) / dof
    lmin, lmax = length_bounds_px
    if lmin is None:
        nn = []
        for _, _, u in terms:
            d = np.sqrt(np.sum((u[:, None] - u[None]) ** 2, axis=-1))
            np.fill_diagonal(d, np.inf)
            nn.append(d.min(axis=1))
        lmin = float(np.median(np.concatenate(nn)))
    lo, hi = np.log(lmin), np.log(max(lmax, lmin))
    bounds = [(np.log(v0) - 12, np.log(v0) + 3), (np.log(v0) - 12, np.log(v0) + 6), (lo, hi)]
    with ExitStack() as stack:  # small matrices: one BLAS thread is ~40x faster when shared
        try:
            from threadpoolctl import threadpool_limits

            stack.enter_context(threadpool_limits(limits=1))
        except ImportError:
            pass
        best = None
        for l0 in (30.0, 100.0, 300.0):  # a few starts: the length's likelihood can be bumpy
            p0 = np.array([np.log(0.5 * v0), np.log(0.5 * v0), np.clip(np.log(l0), lo, hi)])
            res = minimize(_restricted_nll, p0, args=(terms,), method="L-BFGS-B", bounds=bounds)
            if best is None or res.fun < best.fun:
                best = res
        sw2, s2, ell = np.exp(best.x)
        # white noise alone (s -> 0)
        white = _restricted_nll(np.array([np.log(v0), bounds[1][0] - 30, np.log(ell)]), terms)
    return NoiseFit(
        white_px=float(np.sqrt(sw2)),
        correlated_px=float(np.sqrt(s2)),
        length_px=float(ell),
        log_likelihood_ratio=float(white - best.fun),
        views=len(terms),
        points=int(n),
    )
