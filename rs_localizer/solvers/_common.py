"""Shared types and input validation for the rolling-shutter solvers.

Every solver works on calibrated image points ``x`` (N, 2), world points ``X`` (N, 3), the RS
coordinate ``r`` (N,) of each observation (default ``x[:, 1]``: rows read top to bottom) and the
reference coordinate ``r0``. The model is paper eq. 5::

    lambda_i [x_i; 1] = (I + (r_i - r0)[w]x)(I + [v]x) X_i + C + (r_i - r0) t
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..geometry import rotvec_to_matrix, skew

__all__ = [
    "DegenerateInputError",
    "RSBatch",
    "RSSolution",
    "algebraic_error",
    "check_batch",
    "check_inputs",
]


class DegenerateInputError(ValueError):
    """The correspondences do not determine a solution (collinear/duplicated points, rank loss)."""


def _frozen(a) -> np.ndarray:
    a = np.array(a, dtype=np.float64)
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class RSSolution:
    """One solution of the RS absolute pose problem (paper eq. 5).

    Attributes:
        v: (3,) linearized camera rotation (``R ~ I + [v]x``), radians.
        C: (3,) translation at the reference coordinate (``X_cam = R X + C``), world units.
        w: (3,) RS angular velocity per unit of RS coordinate ``r`` (rad per normalized unit).
        t: (3,) RS linear velocity per unit of ``r`` (world units per normalized unit).
        R_rs: (3, 3) general matrix of R9P (paper eq. 8), ``None`` for the other solvers.
        iterations: linear iterations that ran (0 for non-iterative solvers).
        algebraic_error: RMS algebraic residual of eq. 5 on the input points (eq. 8 for R9P).
    """

    v: np.ndarray
    C: np.ndarray
    w: np.ndarray
    t: np.ndarray
    R_rs: np.ndarray | None = None
    iterations: int = 0
    algebraic_error: float = float("nan")

    def __post_init__(self):
        for name in ("v", "C", "w", "t"):
            object.__setattr__(self, name, _frozen(getattr(self, name)))
        if self.R_rs is not None:
            object.__setattr__(self, "R_rs", _frozen(self.R_rs))

    @classmethod
    def _trusted(cls, v, C, w, t, iterations, algebraic_error):
        """An RSSolution from read-only float64 (3,) arrays, without the copies of
        ``__init__`` (the solvers' hot path; the arrays must not be writeable)."""
        self = object.__new__(cls)
        for name, a in (("v", v), ("C", C), ("w", w), ("t", t)):
            object.__setattr__(self, name, a)
        object.__setattr__(self, "R_rs", None)
        object.__setattr__(self, "iterations", iterations)
        object.__setattr__(self, "algebraic_error", algebraic_error)
        return self

    @property
    def R(self) -> np.ndarray:
        """(3, 3) rotation at the reference coordinate: Rodrigues of ``v`` (``expm([v]x)``)."""
        return rotvec_to_matrix(self.v)

    @property
    def R_linear(self) -> np.ndarray:
        """(3, 3) the linearized rotation ``I + [v]x`` that appears in eq. 5."""
        return np.eye(3) + skew(self.v)


@dataclass(frozen=True)
class RSBatch:
    """Solutions of K independent problems solved at once (one per RANSAC hypothesis).

    Attributes:
        v, C, w, t: (K, 3) arrays as in :class:`RSSolution`.
        valid: (K,) bool, False where the problem was degenerate (its rows are then zero).
        iterations: (K,) int, linear iterations that ran.
        algebraic_error: (K,) RMS algebraic residual.
        R_rs: (K, 3, 3) for R9P, else ``None``.
    """

    v: np.ndarray
    C: np.ndarray
    w: np.ndarray
    t: np.ndarray
    valid: np.ndarray
    iterations: np.ndarray
    algebraic_error: np.ndarray
    R_rs: np.ndarray | None = field(default=None)

    def __len__(self) -> int:
        return len(self.valid)

    def solution(self, k: int) -> RSSolution:
        """The k-th problem's solution as an :class:`RSSolution`."""
        return RSSolution(
            self.v[k],
            self.C[k],
            self.w[k],
            self.t[k],
            None if self.R_rs is None else self.R_rs[k],
            int(self.iterations[k]),
            float(self.algebraic_error[k]),
        )


def check_inputs(
    x: np.ndarray,
    X: np.ndarray,
    r: np.ndarray | None = None,
    r0: float = 0.0,
    min_points: int = 6,
    name: str = "solver",
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Validate and convert solver inputs.

    Args:
        x: (N, 2) normalized image points. X: (N, 3) world points. r: (N,) RS coordinates or
        ``None`` for ``x[:, 1]``. r0: reference RS coordinate (finite float).
        min_points: the solver's minimal N.
    Returns:
        (x, X, r, r0) as contiguous float64 arrays and a float.
    Raises:
        ValueError: on wrong shapes, N < ``min_points``, or non-finite values.
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    X = np.ascontiguousarray(X, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 2:
        raise ValueError(f"{name}: x must have shape (N, 2), got {x.shape}")
    if X.ndim != 2 or X.shape[1] != 3:
        raise ValueError(f"{name}: X must have shape (N, 3), got {X.shape}")
    if len(x) != len(X):
        raise ValueError(f"{name}: x and X have different lengths ({len(x)} vs {len(X)})")
    if len(x) < min_points:
        raise ValueError(f"{name}: needs at least {min_points} correspondences, got {len(x)}")
    r = x[:, 1].copy() if r is None else np.ascontiguousarray(r, dtype=np.float64)
    if r.shape != (len(x),):
        raise ValueError(f"{name}: r must have shape ({len(x)},), got {r.shape}")
    r0 = float(r0)
    if not (
        np.isfinite(x).all() and np.isfinite(X).all() and np.isfinite(r).all() and np.isfinite(r0)
    ):
        raise ValueError(f"{name}: inputs contain NaN or inf")
    return x, X, r, r0


def check_batch(
    x: np.ndarray,
    X: np.ndarray,
    r: np.ndarray | None = None,
    r0: float = 0.0,
    min_points: int = 6,
    name: str = "solver",
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Batched version of :func:`check_inputs`: x (K, N, 2), X (K, N, 3), r (K, N) or None.

    Non-finite values are allowed here (those problems come back ``valid = False``); shapes and
    ``N >= min_points`` are checked.
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    X = np.ascontiguousarray(X, dtype=np.float64)
    if x.ndim != 3 or x.shape[2] != 2:
        raise ValueError(f"{name}: x must have shape (K, N, 2), got {x.shape}")
    if X.ndim != 3 or X.shape[2] != 3 or X.shape[:2] != x.shape[:2]:
        raise ValueError(f"{name}: X must have shape {x.shape[:2] + (3,)}, got {X.shape}")
    if x.shape[1] < min_points:
        raise ValueError(f"{name}: needs at least {min_points} correspondences, got {x.shape[1]}")
    r = np.ascontiguousarray(x[:, :, 1]) if r is None else np.ascontiguousarray(r, dtype=np.float64)
    if r.shape != x.shape[:2]:
        raise ValueError(f"{name}: r must have shape {x.shape[:2]}, got {r.shape}")
    return x, X, r, float(r0)


def algebraic_error(
    x: np.ndarray,
    X: np.ndarray,
    r: np.ndarray,
    r0: float,
    v: np.ndarray,
    C: np.ndarray,
    w: np.ndarray,
    t: np.ndarray,
) -> float:
    """RMS algebraic residual of eq. 5 (first two rows of ``[x_hat]x p``) for one solution."""
    tau = np.asarray(r) - r0
    P = np.asarray(X) @ (np.eye(3) + skew(v)).T
    p = P + tau[:, None] * (P @ skew(w).T) + C + tau[:, None] * t
    e1 = -p[:, 1] + x[:, 1] * p[:, 2]
    e2 = p[:, 0] - x[:, 0] * p[:, 2]
    return float(np.sqrt(np.mean(e1 * e1 + e2 * e2)))
