"""Motion prior of the estimator: a Gaussian on the camera's velocities.

On planar scenes (a board, a marker, a facade, a floor) the 12-parameter RS model of one frame
is near-degenerate: the Fisher information of pose + velocities is near-singular, and the
maximum-likelihood fit trades rotation against angular velocity by degrees. A weak prior on the
velocities in physical units (rad/s, m/s) removes that freedom: the estimate becomes the
maximum a posteriori one and its covariance reflects prior and data. On well-conditioned 3D
scenes the data outweigh a weak prior by orders of magnitude.

The prior is on ``z = (v, omega)``, the camera's linear and angular velocity in its own optical
frame, in ROS twist order (vx, vy, vz, wx, wy, wz; m/s, rad/s), the order of
:attr:`RSPoseEstimate.twist_covariance <rs_localizer.estimation.estimate.RSPoseEstimate>`: a
video tracker can pass its predicted twist and covariance per frame. With the model's velocities
per unit RS coordinate (docs/architecture.md "Conventions", ``s`` = seconds per unit r)::

    omega = -w / s,   v = (w x C - t) / s
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._jit import kernel
from .._linalg import solve_square
from ..pose import model_twist, model_twist_jacobian

__all__ = [
    "MotionPrior",
    "checked_symmetric",
    "linear_prior_rows",
    "prior_arrays",
    "prior_conflict",
    "sample_prior_rows",
]


def checked_symmetric(
    M: np.ndarray, n: int, what: str, definite: bool = True, atol: float | None = None
) -> np.ndarray:
    """``M`` as an (n, n) float array after checking that it is finite, symmetric (to a
    relative 1e-9, and ``atol``: default 1e-12 of its largest entry) and positive definite
    (``definite``: it has a Cholesky factor) or positive semi-definite (eigenvalues above
    -1e-9 of its largest entry).

    Raises:
        ValueError: naming ``what``, for the first check that fails.
    """
    S = np.asarray(M, dtype=float)
    if S.shape != (n, n) or not np.isfinite(S).all():
        raise ValueError(f"{what} must be a finite ({n}, {n}) matrix, got shape {S.shape}")
    scale = max(np.abs(S).max(), 1e-300)
    if not np.allclose(S, S.T, rtol=1e-9, atol=1e-12 * scale if atol is None else atol):
        raise ValueError(f"{what} must be symmetric")
    if definite:
        try:
            np.linalg.cholesky(S)
        except np.linalg.LinAlgError:
            raise ValueError(f"{what} must be positive definite") from None
    elif np.linalg.eigvalsh(0.5 * (S + S.T)).min() < -1e-9 * scale:
        raise ValueError(f"{what} must be positive semi-definite")
    return S


def _vector6(a, name):
    v = np.asarray(a, dtype=float).reshape(-1)
    if v.shape != (6,) or not np.isfinite(v).all():
        raise ValueError(
            f"motion prior {name} must be 6 finite numbers (ROS twist order "
            f"vx, vy, vz, wx, wy, wz), got {a!r}"
        )
    return v


@dataclass(frozen=True)
class MotionPrior:
    """Gaussian prior on the camera's velocities during the readout.

    Attributes:
        angular_velocity_sigma: standard deviation of each angular velocity component (rad/s,
            camera optical frame); ``0``, ``None`` or ``inf``: no prior on it.
        linear_velocity_sigma: the same for the linear velocity (m/s).
        mean: (6,) prior mean in ROS twist order (vx, vy, vz, wx, wy, wz; m/s, rad/s, camera
            optical frame), e.g. a tracker's prediction; ``None``: zero (a camera at rest is
            the most likely a priori; the sigmas say how fast it may move).
        covariance: (6, 6) prior covariance in the same order; replaces the two sigmas when
            given (symmetric positive definite).
        information_matrix: (6, 6) inverse covariance in the same order; replaces the sigmas
            and ``covariance`` when given (symmetric positive semi-definite: zero rows leave a
            component unconstrained, e.g. a gyro measures the angular velocity only,
            :func:`rs_localizer.estimation.gyro.gyro_prior`).
        always: use the prior on every frame, in local optimization and refinement. Default
            False: on planar frames always; on other frames only in the final refinement and
            only if the maximum-likelihood velocities do not conflict with it (a chi-square
            test, :func:`rs_localizer.estimation.estimate._final_refinement`), so that a
            zero-mean prior cannot bias a camera much faster than it allows (the paper's
            protocol moves at 8.7 rad/s and 5 m/s: ~7 % more angular velocity error with it).

    The default (3 rad/s, 1.5 m/s, zero mean) is weak: a hand-held or walking camera (turning
    at 1-3 rad/s, moving at up to ~1.5 m/s) lies within ~1 sigma. The linear sigma is the one
    that matters on planes (rotation trades against linear velocity there; the angular sigma
    barely changes the result); it is a compromise measured with
    ``python -m benchmarks.bench_planar`` (docs/planar.md). Raises ValueError
    (on construction) for negative sigmas, a mean or
    covariance of the wrong shape, non-finite entries, or a covariance that is not symmetric
    positive definite.
    """

    angular_velocity_sigma: float | None = 3.0
    linear_velocity_sigma: float | None = 1.5
    mean: np.ndarray | None = None
    covariance: np.ndarray | None = None
    always: bool = False
    information_matrix: np.ndarray | None = None

    def __post_init__(self):
        for name in ("angular_velocity_sigma", "linear_velocity_sigma"):
            v = getattr(self, name)
            if v is not None and (np.isnan(v) or v < 0):
                raise ValueError(f"motion prior {name} must be >= 0 (0 or None: off), got {v}")
        if self.mean is not None:
            object.__setattr__(self, "mean", _vector6(self.mean, "mean"))
        if self.covariance is not None:
            S = checked_symmetric(self.covariance, 6, "motion prior covariance")
            object.__setattr__(self, "covariance", S)
        if self.information_matrix is not None:
            L = checked_symmetric(
                self.information_matrix, 6, "motion prior information_matrix", definite=False
            )
            object.__setattr__(self, "information_matrix", 0.5 * (L + L.T))
        # (on, mean, information) for the kernels, computed once (the prior is immutable)
        if self.enabled:
            Lam = self.information()
            arrays = (True, self.mean_vector(), np.ascontiguousarray(0.5 * (Lam + Lam.T)))
        else:
            arrays = (False, np.zeros(6), np.zeros((6, 6)))
        object.__setattr__(self, "_arrays", arrays)

    @classmethod
    def _from_information(
        cls, mean: np.ndarray, information: np.ndarray, always: bool
    ) -> MotionPrior:
        """The prior with ``mean`` (6,) and ``information`` (6, 6), both finite, the
        information symmetric positive semi-definite and not zero by construction (the
        caller's; :func:`rs_localizer.estimation.gyro.gyro_prior`): the checks of the
        constructor (~60 us, per frame there) are skipped."""
        prior = object.__new__(cls)
        for name, value in (
            ("angular_velocity_sigma", None),
            ("linear_velocity_sigma", None),
            ("mean", mean),
            ("covariance", None),
            ("always", bool(always)),
            ("information_matrix", information),
            ("_arrays", (True, mean.copy(), information.copy())),
        ):
            object.__setattr__(prior, name, value)
        return prior

    @staticmethod
    def _inverse_variance(sigma):
        if sigma is None or sigma == 0 or not np.isfinite(sigma):
            return 0.0
        return 1.0 / float(sigma) ** 2

    @property
    def enabled(self) -> bool:
        """True if the prior constrains anything (a covariance, or a positive finite sigma)."""
        if self.information_matrix is not None:
            return bool(np.abs(self.information_matrix).max() > 0)
        return self.covariance is not None or bool(
            self._inverse_variance(self.angular_velocity_sigma)
            or self._inverse_variance(self.linear_velocity_sigma)
        )

    def mean_vector(self) -> np.ndarray:
        """(6,) prior mean, ROS twist order (zeros when not given)."""
        return np.zeros(6) if self.mean is None else self.mean.copy()

    def information(self) -> np.ndarray:
        """(6, 6) information matrix (inverse covariance), ROS twist order; zero rows and
        columns for unconstrained components."""
        if self.information_matrix is not None:
            return self.information_matrix.copy()
        if self.covariance is not None:
            return np.linalg.inv(self.covariance)
        return np.diag(
            [self._inverse_variance(self.linear_velocity_sigma)] * 3
            + [self._inverse_variance(self.angular_velocity_sigma)] * 3
        )


def prior_arrays(prior: MotionPrior | None) -> tuple[bool, np.ndarray, np.ndarray]:
    """``(on, mean (6,), information (6, 6))`` for the numba kernels; ``on`` False (and zero
    arrays) for ``None`` or a prior that constrains nothing."""
    if prior is None:
        return False, np.zeros(6), np.zeros((6, 6))
    return prior._arrays


def linear_prior_rows(
    prior: MotionPrior, C0: np.ndarray, seconds_per_unit_r: float, scale: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """The prior as linear equations on the model's ``(w, t)`` (per unit r), for the damped
    linear solves of hypothesis generation (``prior_rows`` of
    :func:`rs_localizer.solvers.r6p_1lin_batch`).

    ``z = (v, omega)`` is linear in (w, t) once ``w x C`` is linearized at a rough centre
    ``C0`` (the sample's P3P pose): ``w x C ~ w x C0``, so ``z ~ M (w, t)`` with
    ``M = [[-[C0]x, -I], [-I, 0]] / s`` (docs/architecture.md "Conventions"): the (w, t)
    columns of :func:`rs_localizer.pose.model_twist_jacobian` at ``C0``.

    Args:
        prior: an enabled :class:`MotionPrior`.
        C0: (3,) or (K, 3) rough translations (world -> camera, m).
        seconds_per_unit_r: the camera's capture time per unit r (s), > 0.
        scale: scalar or (K,) weight of the rows against the solver's algebraic equations
            (the algebraic noise: image noise in normalized units times the depth).
    Returns:
        (P (K, 6, 6), q (K, 6)) (K = 1 for a single C0) with
        ``|P (w, t) - q|^2 = scale^2 (z - mean)^T information (z - mean)`` under that
        linearization: ``P = scale U M``, ``q = scale U mean``, ``U^T U = information``.
    Raises:
        ValueError: a disabled prior, or ``seconds_per_unit_r <= 0`` (global shutter).
    """
    if not prior.enabled:
        raise ValueError("linear_prior_rows needs an enabled prior")
    s = float(seconds_per_unit_r)
    if not s > 0:
        raise ValueError(f"seconds_per_unit_r must be > 0, got {seconds_per_unit_r}")
    c = np.atleast_2d(np.asarray(C0, dtype=float))
    K = len(c)
    # M: the twist's Jacobian over (w, t), which does not depend on w (pose.model_twist_jacobian)
    zero = np.zeros(3)
    M = np.array([model_twist_jacobian.py_func(ck, zero, s)[:, 6:12] for ck in c])
    Lam = prior.information()
    ev, V = np.linalg.eigh(0.5 * (Lam + Lam.T))
    U = (V * np.sqrt(np.clip(ev, 0.0, None))).T
    k = np.broadcast_to(np.asarray(scale, dtype=float), (K,))
    P = k[:, None, None] * np.einsum("ij,kjl->kil", U, M)
    q = k[:, None] * (U @ prior.mean_vector())[None, :]
    return np.ascontiguousarray(P), np.ascontiguousarray(q)


@kernel
def _rows_kernel(U, Um, Xs, C0, s, noise, distance, P, q):
    """:func:`sample_prior_rows` for K samples (loops instead of NumPy's per-call overhead)."""
    K, n = Xs.shape[0], Xs.shape[1]
    for k in range(K):
        depth = 0.0
        if distance:
            for i in range(n):
                a0 = Xs[k, i, 0] + C0[k, 0]
                a1 = Xs[k, i, 1] + C0[k, 1]
                a2 = Xs[k, i, 2] + C0[k, 2]
                depth += np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
            depth = depth / n
        else:
            for i in range(n):
                depth += Xs[k, i, 2]
            depth = depth / n + C0[k, 2]
        sc = noise[k] * max(depth, 1e-9) / s
        c0, c1, c2 = C0[k, 0], C0[k, 1], C0[k, 2]
        for a in range(6):
            u0, u1, u2 = U[a, 0], U[a, 1], U[a, 2]
            # (v rows) U[a, :3] (-[C0]x) w = (C0 x U[a, :3]) . w; -U[a, :3] t; (omega) -U[a, 3:] w
            P[k, a, 0] = sc * (c1 * u2 - c2 * u1 - U[a, 3])
            P[k, a, 1] = sc * (c2 * u0 - c0 * u2 - U[a, 4])
            P[k, a, 2] = sc * (c0 * u1 - c1 * u0 - U[a, 5])
            P[k, a, 3] = -sc * u0
            P[k, a, 4] = -sc * u1
            P[k, a, 5] = -sc * u2
            q[k, a] = sc * s * Um[a]


def sample_prior_rows(
    prior: MotionPrior,
    Xs: np.ndarray,
    C0: np.ndarray,
    seconds_per_unit_r: float,
    noise: float | np.ndarray,
    distance: bool = False,
    compiled: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`linear_prior_rows` for K pre-rotated samples, weighted like their equations.

    The solver's algebraic equations (``E . p``, p the point in the camera) have noise of
    about the image noise times the depth, so each sample's rows get
    ``scale = noise * (mean depth of its points)``.

    Args:
        prior: an enabled :class:`MotionPrior`.
        Xs: (K, n, 3) the samples' points pre-rotated by their P3P rotations.
        C0: (K, 3) their P3P translations (the depth is ``Xs[..., 2] + C0[2]``).
        seconds_per_unit_r: > 0 (s). noise: image noise (normalized units), one for every
            sample or (K,) one per sample (a rig's: its first camera's).
        distance: the depth is the points' distance ``|Xs + C0|`` instead (a rig's frame,
            :mod:`~.rig`, has no optical axis).
        compiled: False: the same loops in Python (code that compiles nothing).
    Returns:
        (P (K, 6, 6), q (K, 6)) for ``prior_rows``; equal to :func:`linear_prior_rows` with
        that scale.
    """
    Lam = prior.information()
    ev, V = np.linalg.eigh(0.5 * (Lam + Lam.T))
    U = np.ascontiguousarray((V * np.sqrt(np.clip(ev, 0.0, None))).T)
    K = len(C0)
    P = np.empty((K, 6, 6))
    q = np.empty((K, 6))
    (_rows_kernel if compiled else _rows_kernel.py_func)(
        U,
        U @ prior.mean_vector(),
        np.ascontiguousarray(Xs, dtype=np.float64),
        np.ascontiguousarray(C0, dtype=np.float64),
        float(seconds_per_unit_r),
        np.ascontiguousarray(np.broadcast_to(np.asarray(noise, dtype=np.float64), (K,))),
        bool(distance),
        P,
        q,
    )
    return P, q


@kernel
def _conflict(cov12, C, w, t, s, mean, Lam):
    z = model_twist(C, w, t, s)
    Jz = model_twist_jacobian(C, w, s)
    S = Jz @ cov12 @ Jz.T
    d = z - mean
    # (S + Lam^-1)^-1 = Lam (I + S Lam)^-1, defined for a singular Lam too
    M = np.eye(6) + S @ Lam
    # (LU with partial pivoting, as np.linalg.solve: the solvers' own, already compiled; numba's
    # np.linalg.solve costs seconds of compiling on a cold start)
    y = np.empty(6)
    if not solve_square(M, d.copy(), y, 0.0):
        return np.inf, np.inf
    Ly = Lam @ y
    # the linear-Gaussian posterior moves z by S Lam y; in the data's own metric S^-1 that is
    # y^T Lam S Lam y
    return d @ Ly, Ly @ (S @ Ly)


def prior_conflict(
    prior: MotionPrior,
    covariance: np.ndarray,
    C: np.ndarray,
    w: np.ndarray,
    t: np.ndarray,
    seconds_per_unit_r: float,
) -> tuple[float, float]:
    """How an estimate's velocities relate to the prior (linear-Gaussian approximation).

    ``z = (v, omega)`` from the model's C, w, t per unit r (docs/architecture.md "Conventions"),
    with the
    covariance ``S`` propagated from ``covariance`` ((12, 12) over (delta, C, w, t)); the prior
    has mean ``m`` and covariance ``P``.

    Returns:
        (conflict, shift): ``conflict = (z - m)^T (S + P)^-1 (z - m)``, chi-square with 6 dof
        if the prior is right; ``shift = dz^T S^-1 dz`` for the move ``dz = S (S + P)^-1
        (z - m)`` the prior causes (MAP against maximum likelihood), in the data's own metric
        (0.01: a tenth of the data's standard deviation). ``(inf, inf)`` if singular; ``(0,
        0)`` for a disabled prior.
    """
    on, mean, Lam = prior_arrays(prior)
    if not on:
        return 0.0, 0.0
    f64 = np.float64
    try:
        c, sh = _conflict(
            np.ascontiguousarray(covariance, dtype=f64),
            np.ascontiguousarray(C, dtype=f64),
            np.ascontiguousarray(w, dtype=f64),
            np.ascontiguousarray(t, dtype=f64),
            float(seconds_per_unit_r),
            mean,
            Lam,
        )
        return float(c), float(sh)
    except Exception:  # (a singular system returns inf itself; numba raises for a wrong shape)
        return float("inf"), float("inf")
