"""Fused twist: a fixed-lag Kalman smoother over the per-frame RS estimates of a video.

One rolling-shutter frame measures the camera's pose to millimetres and its velocities during
the ~20 ms readout, the linear one only weakly (a few pixels of parallax). Consecutive poses
33 ms apart pin the velocity far better. :class:`TwistFilter` fuses both: an error-state
extended Kalman filter on ``SO(3) x R^3 x R^3 x R^3`` (orientation, position, body angular
velocity, world linear velocity), with the angular and linear accelerations
(``model="acceleration"``) or without (``model="velocity"``), continuous white noise on the
highest derivative, and the per-frame estimate (pose and in-frame twist with the
refinement's 12x12 covariance) as the measurement. The last ``lag`` frames' states are kept
in the filter state (stochastic cloning), so every measurement also corrects them: the estimate
of a frame is final ``lag`` frames later (a fixed-lag smoother). With ``lag = 1`` the twist of
a frame uses the poses before *and after* it, like a central difference, at one frame of
latency; ``lag = 0`` is the causal filter.

States and frames (as :class:`~rs_localizer.estimation.estimate.RSPoseEstimate`):

* ``O`` (3, 3): camera -> world orientation; errors are world-axis rotation vectors
  ``phi`` with ``O = expm([phi]x) O_hat``.
* ``p`` (3,): camera centre in the world (m).
* ``omega`` (3,): the camera's angular velocity in its optical frame (rad/s).
* ``v`` (3,): the camera's linear velocity in the world frame (m/s); the output gives it in the
  camera frame too (``O^T v``).
* ``alpha`` (3,, camera frame, rad/s^2), ``a`` (3,, world, m/s^2): acceleration model only.

Process model over ``dt``: ``O' = O expm([omega dt + alpha dt^2 / 2]x)``,
``p' = p + v dt + a dt^2 / 2``, ``omega' = omega + alpha dt``, ``v' = v + a dt``, driven by
white noise on ``alpha``/``a`` (acceleration model, spectral densities ``angular_noise^2``,
``linear_noise^2``) or on ``omega``/``v`` (velocity model), discretized exactly for chains of
integrators (Bar-Shalom, Li, Kirubarajan, *Estimation with Applications to Tracking and
Navigation*, 2001, sec. 6.2-6.3); the angular chain is driven in the camera frame, the linear
one in the world frame.

The measurement model accounts for what the per-frame estimate leaves out: the refinement fits
a constant velocity over the readout, so a camera that accelerates during it moves the
estimate by ``G (alpha, a_cam)``, G the estimate's ``acceleration_sensitivity``
(:mod:`rs_localizer.estimation.sensitivity`). With the acceleration model the filter predicts
that shift from its acceleration states (``z = h(x) + G (alpha, O^T a) + noise``); with the
velocity model it adds ``G diag(acceleration_std^2) G^T`` to the covariance. Without this the
per-frame covariance is 2.5x (walk) to 13x (hand-held shake) too small in variance (NEES of the
12 pose and twist errors 31 and 155 instead of 12 on the synthetic sequences; 12 and 13 with
the true accelerations' shift removed). ``measurement_scale`` can still inflate it.

A pose-only measurement (a global shutter: the frame says nothing of the velocities, the filter
has them from the differences of consecutive poses) is scaled by a factor the filter learns
from its own innovations (``adaptive_scale``). The stated covariance of a pose fitted to marker
corners holds the corners' noise only, not the error of the map, the mountings and the
lenses' calibration, which moves the pose by a step whenever other tags or cameras come into
view; the filter would take such steps for motion, difference them into velocity and
acceleration, and extrapolate them into a prediction off by far more than its covariance
says. The factor (never below 1: a measurement is never taken as more precise than stated, at
most :data:`ADAPT_MAX_SCALE`) rises by ``exp(ADAPT_RATE)`` (about) after each pose measurement
whose normalized innovation squared is beyond the :data:`ADAPT_QUANTILE` quantile of the
chi-square distribution and falls slowly after the others, so that that share of them falls
within it; a frame that restarts the filter does not count, and the factor is kept when the
filter restarts. Measurements with a twist (rolling shutter) are not scaled.
"""

from __future__ import annotations

import functools
import types
from collections.abc import Callable
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import numpy as np
from scipy.stats import chi2

from .._jit import kernel
from .._linalg import cholesky_into
from .._so3 import rotate_left_into, rotation_log_into, skew_matrix, so3_coefficients
from ..estimation.implementation import compiled_by_default
from ..estimation.prior import MotionPrior, prior_arrays
from ..estimation.result import RSPoseEstimate
from ..pose import ROS_ORDER, RSPose

__all__ = [
    "ADAPT_MAX_SCALE",
    "ADAPT_QUANTILE",
    "ADAPT_RATE",
    "MODELS",
    "FusedState",
    "FusionOptions",
    "FusionStep",
    "TwistFilter",
]

#: process models: constant acceleration (18 error states per frame) or constant velocity (12)
MODELS = ("acceleration", "velocity")
#: the pose measurements' learned scale (``FusionOptions.adaptive_scale``) keeps this share of
#: their normalized innovations squared within the chi-square quantile of 6 degrees of freedom
ADAPT_QUANTILE = 0.99
#: the learned scale's step (natural log) per pose measurement beyond that quantile (it falls
#: by ``ADAPT_RATE (1 - ADAPT_QUANTILE)`` per one within)
ADAPT_RATE = 0.2
#: the largest learned scale of the pose measurements' covariance (in variance)
ADAPT_MAX_SCALE = 1e4


@dataclass(frozen=True)
class FusionOptions:
    """Parameters of :class:`TwistFilter`.

    Attributes:
        model: ``"acceleration"`` (constant angular and linear acceleration between frames,
            white jerk) or ``"velocity"`` (constant velocities, white acceleration).
        lag: frames of smoothing delay (0: causal filter). The estimate of frame k is final
            when frame k + lag has been fused.
        angular_noise: square root of the spectral density of the angular process noise:
            rad/s^3/sqrt(Hz) (acceleration model) or rad/s^2/sqrt(Hz) (velocity model).
        linear_noise: the same for the linear motion: m/s^3/sqrt(Hz) or m/s^2/sqrt(Hz).
        measurement_scale: the per-frame covariance is multiplied by this (>= 1; see the module
            docstring).
        gate: chi-square quantile of the innovation gate (0 < gate <= 1; 1 disables it).
        max_rejections: consecutive gated measurements after which the filter restarts.
        angular_acceleration_std, linear_acceleration_std: standard deviations (rad/s^2,
            m/s^2) of the accelerations: the prior when the acceleration model (re)starts; for
            the velocity model, the in-readout acceleration whose effect on the measurement
            (``acceleration_sensitivity`` of the estimate) is added to its covariance.
        initial_velocity: prior standard deviation of each velocity (rad/s, m/s) when the
            filter starts from an estimate without twist covariance (global shutter).
        max_gap: seconds; a longer gap between two frames restarts the filter.
        adaptive_scale: pose-only measurements (no twist covariance: a global shutter) are
            scaled, on top of ``measurement_scale``, by a factor learned from their
            innovations (module docstring; :attr:`TwistFilter.pose_scale`).
    """

    model: str = "acceleration"
    lag: int = 1
    angular_noise: float = 30.0
    linear_noise: float = 5.0
    measurement_scale: float = 1.0
    gate: float = 0.9999
    max_rejections: int = 2
    angular_acceleration_std: float = 10.0
    linear_acceleration_std: float = 10.0
    initial_velocity: float = 10.0
    max_gap: float = 0.5
    adaptive_scale: bool = True

    def __post_init__(self):
        if self.model not in MODELS:
            raise ValueError(f"unknown fusion model {self.model!r}; expected one of {MODELS}")
        if int(self.lag) != self.lag or not 0 <= self.lag <= 10:
            raise ValueError(f"lag must be an integer in [0, 10], got {self.lag}")
        for name in (
            "angular_noise",
            "linear_noise",
            "angular_acceleration_std",
            "linear_acceleration_std",
            "initial_velocity",
            "max_gap",
        ):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be finite and > 0, got {v}")
        if not (np.isfinite(self.measurement_scale) and self.measurement_scale >= 1.0):
            raise ValueError(f"measurement_scale must be >= 1, got {self.measurement_scale}")
        if not (0.0 < self.gate <= 1.0):
            raise ValueError(f"gate must be in (0, 1], got {self.gate}")
        if int(self.max_rejections) != self.max_rejections or self.max_rejections < 0:
            raise ValueError(f"max_rejections must be an integer >= 0, got {self.max_rejections}")


@dataclass(frozen=True)
class FusedState:
    """The fused estimate of one frame. Frames and units as
    :class:`~rs_localizer.estimation.estimate.RSPoseEstimate`.

    Attributes:
        pose: the fused pose and twist, a :class:`~rs_localizer.pose.RSPose` at the frame's
            stamp (``pose.stamp_ns``, ns, as fed to the filter): ``orientation`` (3, 3)
            camera -> world, ``position`` (3,) camera centre (m), ``angular_velocity``,
            ``linear_velocity`` (3,) camera frame (rad/s, m/s).
        angular_acceleration (3,, camera frame, rad/s^2), linear_acceleration (3,, world,
            m/s^2): zero for the velocity model.
        covariance: (12, 12) over (rotation [rad, world axes], position [m, world], angular
            velocity [rad/s, camera], linear velocity [m/s, camera]), the layout of
            ``RSPoseEstimate.covariance``.
        pose_covariance, twist_covariance: (6, 6) ROS order (x, y, z, rot x, rot y, rot z;
            vx, vy, vz, wx, wy, wz): read-only blocks of ``covariance``, made on access (the
            filter hands out a state per frame and per prediction; most are never
            published).
        fused: the frame's own measurement was fused (False: gated out or unusable).
        restarted: the filter (re)started from this frame.
        smoothed: frames after this one have been fused into it (its lag).
        nis: normalized innovation squared of the frame's measurement (NaN if none).
    """

    pose: RSPose
    angular_acceleration: np.ndarray
    linear_acceleration: np.ndarray
    covariance: np.ndarray = field(repr=False)
    fused: bool = False
    restarted: bool = False
    smoothed: int = 0
    nis: float = float("nan")

    @property
    def pose_covariance(self) -> np.ndarray:
        """(6, 6) ROS order (x, y, z, rot x, rot y, rot z), world frame."""
        return self.covariance[_ROS_POSE]

    @property
    def twist_covariance(self) -> np.ndarray:
        """(6, 6) ROS order (vx, vy, vz, wx, wy, wz), camera frame."""
        return self.covariance[_ROS_TWIST]


class FusionStep:
    """What :meth:`TwistFilter.update` returns.

    Attributes:
        current: the filtered (causal) :class:`FusedState` at the new frame, ``None`` if the
            filter has no state (computed on first access).
        final: frames whose estimate is now final, oldest first: normally the frame ``lag``
            frames back; on a restart every frame not yet returned; the new frame for lag 0.
    """

    __slots__ = ("_current", "_make", "final")

    def __init__(self, make: Callable[[], FusedState] | None, final: list):
        self._make = make
        self._current = None
        self.final = final

    @property
    def current(self) -> FusedState | None:
        if self._current is None and self._make is not None:
            self._current, self._make = self._make(), None
        return self._current


class _Measurement:
    """A frame's measurement: m (12 or 6), orientation O (3, 3), position p, omega, v_cam
    (3,), covariance R (m, m), acceleration sensitivity G (m, 6) or None."""

    def __init__(self, m, Ori, p, omega, v, R):
        self.m, self.Ori, self.p, self.omega, self.v, self.R = m, Ori, p, omega, v, R
        self.G = None
        self.deprior = False


class _Entry:
    """Bookkeeping of one frame in the window; its nominal state is the frame's row of
    ``TwistFilter.X``."""

    __slots__ = ("age", "emitted", "fused", "nis", "restarted", "stamp")

    def __init__(self, stamp):
        self.stamp = int(stamp)
        self.fused = False
        self.restarted = False
        self.nis = float("nan")
        self.emitted = False
        self.age = 0


# A row of ``TwistFilter.X`` (one frame of the window) holds the nominal state at these
# offsets: the orientation O (3, 3) row-major (camera -> world), the position p (world), the
# angular velocity omega (camera frame), the linear velocity v (world), the angular and linear
# accelerations alpha, a, then the output ``v_cam = O^T v``. (The error state and the (12,)
# outputs are ordered phi, p, omega, v, alpha, a at 0, 3, 6, 9, 12, 15.) Module-level ints:
# numba compiles them into the kernels as constants.
ROW_O = 0
ROW_P = 9
ROW_OMEGA = 12
ROW_V = 15
ROW_ALPHA = 18
ROW_A = 21
ROW_V_CAM = 24
#: width of a row
_ROW = 27


# ------------------------------------------------------------------------- numba kernels
# (the filter runs once per frame next to a ~1 ms estimator: NumPy's per-call overhead on
# 3x3 to 36x36 matrices would cost more than the arithmetic)
@kernel
def _chain_q(dt, order):
    """Discrete covariance of an ``order``-fold integrator chain driven by unit continuous
    white noise on its last state, over ``dt`` (order 2: position, velocity; 3: with the
    acceleration)."""
    if order == 2:
        return np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    return np.array(
        [
            [dt**5 / 20, dt**4 / 8, dt**3 / 6],
            [dt**4 / 8, dt**3 / 3, dt**2 / 2],
            [dt**3 / 6, dt**2 / 2, dt],
        ]
    )


@kernel
def _mul3(A, B):
    """A B for A, B (3, 3) (plain loops: no BLAS call for 27 products)."""
    C = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            C[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]
    return C


@kernel
def _transition(x, dt, acc, qa, ql, out):
    """One step of the process model (module docstring) for ``dt`` s of the window row x
    (27,) (see ``_ROW``), written into the row ``out`` (but its v_cam: :func:`_outputs`).

    Returns (F (n, n), Q (n, n)) with n = 18 (``acc``) or 12; ``qa``, ``ql`` are the angular
    and linear spectral densities."""
    n = 18 if acc else 12
    h = 0.5 * dt * dt
    theta = np.empty(3)
    for i in range(3):
        theta[i] = x[ROW_OMEGA + i] * dt + h * x[ROW_ALPHA + i] if acc else x[ROW_OMEGA + i] * dt
    c1, c2, c3 = so3_coefficients(theta[0] ** 2 + theta[1] ** 2 + theta[2] ** 2)
    K = skew_matrix(theta)
    K2 = _mul3(K, K)
    E = np.empty((3, 3))  # expm([theta]x)
    Jr = np.empty((3, 3))  # right Jacobian: expm(th + d) ~ expm(th) expm(Jr d)
    Ori = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            one = 1.0 if i == j else 0.0
            E[i, j] = one + c1 * K[i, j] + c2 * K2[i, j]
            Jr[i, j] = one - c2 * K[i, j] + c3 * K2[i, j]
            Ori[i, j] = x[ROW_O + 3 * i + j]
    On = _mul3(Ori, E)
    OJ = _mul3(On, Jr)
    for i in range(3):
        for j in range(3):
            out[ROW_O + 3 * i + j] = On[i, j]
        p, w, v = x[ROW_P + i], x[ROW_OMEGA + i], x[ROW_V + i]
        al, a = x[ROW_ALPHA + i], x[ROW_A + i]
        if acc:
            out[ROW_P + i] = p + v * dt + h * a
            out[ROW_OMEGA + i] = w + al * dt
            out[ROW_V + i] = v + a * dt
        else:
            out[ROW_P + i], out[ROW_OMEGA + i], out[ROW_V + i] = p + v * dt, w, v
        out[ROW_ALPHA + i], out[ROW_A + i] = al, a
    F = np.eye(n)
    for i in range(3):
        F[3 + i, 9 + i] = dt
        for j in range(3):
            F[i, 6 + j] = OJ[i, j] * dt
        if acc:
            F[3 + i, 15 + i] = h
            F[6 + i, 12 + i] = dt
            F[9 + i, 15 + i] = dt
            for j in range(3):
                F[i, 12 + j] = OJ[i, j] * h
    # white noise drives the camera-frame angular chain (its rotation error maps to world
    # axes by O) and the world-frame linear chain; blocks (phi, omega, alpha) at 0, 6, 12
    # and (p, v, a) at 3, 9, 15
    order = 3 if acc else 2
    q = _chain_q(dt, order)
    Q = np.zeros((n, n))
    for bi in range(order):
        for bj in range(order):
            qa_ij = qa * q[bi, bj]
            for r in range(3):
                Q[6 * bi + 3 + r, 6 * bj + 3 + r] = ql * q[bi, bj]
                for c in range(3):
                    if bi == 0 and bj == 0:
                        val = qa_ij if r == c else 0.0
                    elif bi == 0:
                        val = qa_ij * On[r, c]  # world phi x camera-frame derivative
                    elif bj == 0:
                        val = qa_ij * On[c, r]
                    else:
                        val = qa_ij if r == c else 0.0
                    Q[6 * bi + r, 6 * bj + c] = val
    return F, Q


@kernel
def _shift_covariance(P, F, Q, n, keep):
    """``Fa P Fa^T + Q`` for the window: the newest block propagated by F, the ``keep``
    newest old blocks shifted back one place (the rest dropped). P (k n, k n) symmetric,
    F, Q (n, n); returns ((keep + 1) n, (keep + 1) n), symmetric. F (identity plus a few
    blocks, :func:`_transition`) is applied through its nonzero entries."""
    M = (keep + 1) * n
    kn = keep * n  # the old blocks that stay
    cols = max(kn, n)
    nz = 0
    fi, fk, fv = np.empty(n * n, np.int64), np.empty(n * n, np.int64), np.empty(n * n)
    for i in range(n):
        for k in range(n):
            if F[i, k] != 0.0:
                fi[nz], fk[nz], fv[nz] = i, k, F[i, k]
                nz += 1
    FP = np.zeros((n, cols))  # F P[:n, :cols]
    for e in range(nz):
        i, k, f = fi[e], fk[e], fv[e]
        for c in range(cols):
            FP[i, c] += f * P[k, c]
    FPF = np.zeros((n, n))  # F (F P[:n, :n])^T = (F P F^T)^T
    for e in range(nz):
        j, k, f = fi[e], fk[e], fv[e]
        for i in range(n):
            FPF[j, i] += f * FP[i, k]
    out = np.empty((M, M))
    for i in range(n):
        for j in range(n):
            out[i, j] = 0.5 * (FPF[i, j] + FPF[j, i]) + Q[i, j]
    for i in range(n):
        for c in range(kn):
            out[i, n + c] = FP[i, c]
            out[n + c, i] = FP[i, c]
    for r in range(kn):
        for c in range(kn):
            out[n + r, n + c] = P[r, c]
    return out


@kernel
def _cholesky(S):
    """Lower Cholesky factor L (n, n) of the symmetric S (n, n) and ok: False if S is not
    positive definite (L is not valid then); :func:`rs_localizer._linalg.cholesky_into` on
    all of S, the strict upper part of L zero."""
    n = S.shape[0]
    L = np.zeros((n, n))
    return L, cholesky_into(S, n, L)


@kernel
def _inverse_from_cholesky(L):
    """``S^-1 = L^-T L^-1`` (n, n), exactly symmetric, of ``S = L L^T`` from its lower
    Cholesky factor L (n, n). (Row operations, which the compiler vectorizes.)"""
    n = L.shape[0]
    X = np.zeros((n, n))  # L^-1 (lower), row by row: X[i] = (e_i - sum_k<i L[i, k] X[k]) / L[i, i]
    for i in range(n):
        X[i, i] = 1.0
        for k in range(i):
            lik = L[i, k]
            for c in range(k + 1):
                X[i, c] -= lik * X[k, c]
        d = 1.0 / L[i, i]
        for c in range(i + 1):
            X[i, c] *= d
    out = np.zeros((n, n))  # X^T X: sum over k of the rank-one terms of row k (upper part)
    for k in range(n):
        for i in range(k + 1):
            xki = X[k, i]
            for j in range(i, k + 1):
                out[i, j] += xki * X[k, j]
    for i in range(n):
        for j in range(i + 1, n):
            out[j, i] = out[i, j]
    return out


@kernel
def _kalman_update(P, H, y, R):
    """Kalman update with a measurement on the newest block (H (m, n) on the first n
    columns of the symmetric P (M, M)). Returns (nis, dx (M,), P' (M, M) symmetric (its
    upper triangle mirrored), ok); ok False if the innovation covariance is not positive
    definite (nothing else is valid then)."""
    m, n = H.shape
    M = P.shape[0]
    W = H @ np.ascontiguousarray(P[:n])  # H P (m, M)
    S = np.ascontiguousarray(W[:, :n]) @ np.ascontiguousarray(H.T)
    for i in range(m):
        for j in range(i, m):
            S[i, j] = S[j, i] = 0.5 * (S[i, j] + S[j, i]) + 0.5 * (R[i, j] + R[j, i])
    L, ok = _cholesky(S)
    if not ok:
        return np.inf, np.zeros(M), P, False
    # forward substitution: z = L^-1 y, W = L^-1 (H P) so that K S K^T = W^T W, K y = W^T z
    z = np.empty(m)
    for i in range(m):
        s = y[i]
        for k in range(i):
            s -= L[i, k] * z[k]
            lik = L[i, k]
            for c in range(M):
                W[i, c] -= lik * W[k, c]
        z[i] = s / L[i, i]
        inv = 1.0 / L[i, i]
        for c in range(M):
            W[i, c] *= inv
    P2 = P - np.ascontiguousarray(W.T) @ W
    for i in range(M):  # (the upper triangle, mirrored)
        for j in range(i + 1, M):
            P2[j, i] = P2[i, j]
    return z @ z, z @ W, P2, True


@kernel
def _innovation(Ori, p, omega, v, alpha, a, zO, zp, zomega, zv, m, n, G, use_G):
    """Innovation y (m,) and Jacobian H (m, n) on the newest state of a measurement of
    (rotation, position[, omega, v_cam = O^T v]); with ``use_G`` (acceleration model) the
    measurement also moves by ``G (alpha, O^T a)``."""
    y = np.zeros(m)
    H = np.zeros((m, n))
    rv = np.empty(3)
    rotation_log_into(zO @ Ori.T, rv)
    y[0:3] = rv
    for i in range(3):
        y[3 + i] = zp[i] - p[i]
        H[i, i] = 1.0
        H[3 + i, 3 + i] = 1.0
    Ot = np.ascontiguousarray(Ori.T)
    if m == 12:
        vc = Ot @ v
        A = Ot @ skew_matrix(v)
        for i in range(3):
            y[6 + i] = zomega[i] - omega[i]
            y[9 + i] = zv[i] - vc[i]
            H[6 + i, 6 + i] = 1.0
            for j in range(3):
                H[9 + i, j] = A[i, j]
                H[9 + i, 9 + j] = Ot[i, j]
    if use_G:
        Ga = np.ascontiguousarray(G[:, 3:6]) @ Ot
        ac = Ot @ a
        for r in range(m):
            for j in range(3):
                H[r, 12 + j] = G[r, j]
                H[r, 15 + j] = Ga[r, j]
                y[r] -= G[r, j] * alpha[j] + G[r, 3 + j] * ac[j]
    return y, H


@kernel
def _deprior(cov, p, omega, v, mean, info, G):
    """Take a twist prior (ROS order mean (6,), information (6, 6)) out of a posterior
    estimate (covariance (12, 12) over (rotation, position, omega, v), values p, omega, v;
    rotation 0 at the estimate): returns (ok, data values (12,) (rotation relative to the
    estimate), data covariance (12, 12), data sensitivity (12, 6) from the posterior's G);
    ok False (and the inputs back) when the posterior or the data information is not
    positive definite."""
    idx = 6 + ROS_ORDER  # (omega, v of the (12, 12) in ROS order: v first)
    L, ok = _cholesky(cov)
    if not ok:
        return False, np.zeros(12), cov, G
    L_post = _inverse_from_cholesky(L)
    L_d = L_post.copy()
    for a in range(6):
        for b in range(6):
            L_d[idx[a], idx[b]] -= info[a, b]
    L_d = 0.5 * (L_d + L_d.T)
    L, ok = _cholesky(L_d)
    if not ok:
        return False, np.zeros(12), cov, G
    R_d = _inverse_from_cholesky(L)
    zp = np.zeros(12)
    zp[3:6], zp[6:9], zp[9:12] = p, omega, v
    rhs = L_post @ zp
    for a in range(6):
        for b in range(6):
            rhs[idx[a]] -= info[a, b] * mean[b]
    return True, R_d @ rhs, R_d, R_d @ (L_post @ G)


@kernel
def _prepare_measurement(
    m, cov, Ori, p, omega, v, G, has_G, prior_on, mean, info, scale, acc, acc_var
):
    """The measurement of an estimate (see :meth:`TwistFilter._measurement`) from its arrays:
    m (12 or 6), covariance cov (12, 12) (its (m, m) block is used), O (3, 3), p, omega,
    v_cam (3,), acceleration sensitivity G (12, 6) (used if ``has_G``), the twist prior's
    mean (6,) and information (6, 6) (taken out if ``prior_on`` and m = 12), the
    ``measurement_scale``, ``acc`` (acceleration model) and the accelerations' variances
    acc_var (6,) (velocity model: their effect is added to R).

    Returns (usable, deprior, O (3, 3), p, omega, v_cam (3,), R (m, m), G (m, 6), has_G);
    usable False if cov's (m, m) block is not finite; has_G False if G is not finite or
    was moved into R."""
    zO, zp, zw, zv = Ori.copy(), p.copy(), omega.copy(), v.copy()
    for i in range(m):
        for j in range(m):
            if not np.isfinite(cov[i, j]):
                return False, False, zO, zp, zw, zv, np.zeros((m, m)), np.zeros((m, 6)), False
    if has_G:
        for i in range(12):
            for j in range(6):
                if not np.isfinite(G[i, j]):
                    has_G = False
    Gm = np.ascontiguousarray(G[:m]) if has_G else np.zeros((m, 6))
    R = np.ascontiguousarray(cov[:m, :m])
    deprior = False
    if prior_on and m == 12:
        ok, zd, R_d, G_d = _deprior(R, zp, zw, zv, mean, info, Gm)
        if ok:  # (else the data information is not positive definite: keep the posterior)
            rotate_left_into(zd[0], zd[1], zd[2], Ori, zO)  # (zO was O's copy)
            zp, zw, zv = zd[3:6].copy(), zd[6:9].copy(), zd[9:12].copy()
            R = R_d
            if has_G:
                Gm = G_d
            deprior = True
    R = scale * R
    if has_G and not acc:
        R = R + (Gm * acc_var) @ Gm.T
        has_G = False
    return True, deprior, zO, zp, zw, zv, R, Gm, has_G


@kernel
def _camera_covariance(x, P, b, out):
    """Write into out (12, 12) the covariance of (phi, p, omega, v_cam = O^T v) of the
    window row x (27,) from its (n, n) block of P at (b, b) over (phi, p, omega, v, ...):
    ``d v_cam = O^T [v]x phi + O^T dv`` (J P J^T with J the identity but for these rows;
    symmetric)."""
    v0, v1, v2 = x[ROW_V], x[ROW_V + 1], x[ROW_V + 2]
    A = np.empty((3, 3))  # O^T [v]x
    for i in range(3):
        o0, o1, o2 = x[ROW_O + i], x[ROW_O + 3 + i], x[ROW_O + 6 + i]  # column i of O
        A[i, 0] = o1 * v2 - o2 * v1
        A[i, 1] = o2 * v0 - o0 * v2
        A[i, 2] = o0 * v1 - o1 * v0
    T = np.empty((3, 12))  # the v_cam rows of J P
    for i in range(3):
        for c in range(12):
            s = 0.0
            for j in range(3):
                s += A[i, j] * P[b + j, b + c] + x[3 * j + i] * P[b + 9 + j, b + c]
            T[i, c] = s
    for r in range(9):
        for c in range(9):
            out[r, c] = 0.5 * (P[b + r, b + c] + P[b + c, b + r])
    for i in range(3):
        for c in range(9):
            out[9 + i, c] = T[i, c]
            out[c, 9 + i] = T[i, c]
        for k in range(3):
            s = 0.0
            for j in range(3):
                s += T[i, j] * A[k, j] + T[i, 9 + j] * x[3 * j + k]
            out[9 + i, 9 + k] = s
    for i in range(3):
        for k in range(i + 1, 3):
            out[9 + i, 9 + k] = out[9 + k, 9 + i] = 0.5 * (out[9 + i, 9 + k] + out[9 + k, 9 + i])


@kernel
def _outputs(X, P, n):
    """Fill ``v_cam = O^T v`` (columns 24:27) of the window rows X (k, 27) and return their
    (k, 12, 12) covariances of (phi, p, omega, v_cam) from the window covariance P
    (k n, k n) (:func:`_camera_covariance` of each (n, n) diagonal block)."""
    k = X.shape[0]
    C = np.empty((k, 12, 12))
    for i in range(k):
        x = X[i]
        for r in range(3):
            x[ROW_V_CAM + r] = (
                x[ROW_O + r] * x[ROW_V]
                + x[ROW_O + 3 + r] * x[ROW_V + 1]
                + x[ROW_O + 6 + r] * x[ROW_V + 2]
            )
        _camera_covariance(x, P, i * n, C[i])
    return C


@kernel
def _update_window(
    X,
    P,
    dt,
    keep,
    acc,
    qa,
    ql,
    limit,
    m,
    cov,
    Ori,
    p,
    omega,
    v,
    G,
    has_G,
    prior_on,
    mean,
    info,
    scale,
    acc_var,
):
    """The arithmetic of :meth:`TwistFilter.update` on a running window, in one call.

    X (k, 27) the window's rows (newest first, see ``_ROW``) and P (k n, k n) its error
    covariance (n = 18 with ``acc``, else 12). The newest state is propagated by ``dt`` s
    (:func:`_transition`, spectral densities ``qa``, ``ql``) and becomes the new row 0; the
    ``keep`` newest old rows follow (:func:`_shift_covariance`). With a measurement (m > 0;
    the remaining arguments as :func:`_prepare_measurement`) it is fused into every row
    when its NIS is <= ``limit`` (the gate; ``inf`` for none).

    Returns (status, nis, X' (keep + 1, 27), P', C (keep + 1, 12, 12) the rows'
    :func:`_outputs`): status -1 no usable measurement (nis NaN), 0 gated out (nis inf if
    the innovation covariance is not positive definite), 1 fused; X', P' are the propagated
    window unless fused."""
    n = 18 if acc else 12
    Xn = np.empty((keep + 1, _ROW))
    F, Q = _transition(X[0], dt, acc, qa, ql, Xn[0])
    Pn = _shift_covariance(P, F, Q, n, keep)
    Xn[1:] = X[:keep]
    status, nis = -1, np.nan
    if m > 0:
        usable, _, zO, zp, zw, zv, R, Gm, use_G = _prepare_measurement(
            m, cov, Ori, p, omega, v, G, has_G, prior_on, mean, info, scale, acc, acc_var
        )
        if usable:
            x = Xn[0]
            On = np.ascontiguousarray(x[ROW_O : ROW_O + 9]).reshape((3, 3))
            y, H = _innovation(
                On,
                x[ROW_P : ROW_P + 3],
                x[ROW_OMEGA : ROW_OMEGA + 3],
                x[ROW_V : ROW_V + 3],
                x[ROW_ALPHA : ROW_ALPHA + 3],
                x[ROW_A : ROW_A + 3],
                zO,
                zp,
                zw,
                zv,
                m,
                n,
                Gm,
                use_G,
            )
            nis, dx, P_upd, ok = _kalman_update(Pn, H, y, R)
            status = 0
            if ok and nis <= limit:
                status = 1
                Pn = P_upd
                nv = 18 if acc else 12  # (alpha, a are not states of the velocity model)
                for i in range(keep + 1):
                    Ori = Xn[i, ROW_O : ROW_O + 9].reshape((3, 3))  # (a view: rotated in place)
                    rotate_left_into(dx[i * n], dx[i * n + 1], dx[i * n + 2], Ori.copy(), Ori)
                    for j in range(3, nv):
                        Xn[i, ROW_P + j - 3] += dx[i * n + j]  # (error state j >= 3: p...)
    return status, nis, Xn, Pn, _outputs(Xn, Pn, n)


@kernel
def _predict_row(X, P, dt, acc, qa, ql):
    """The newest window row (of X (k, 27), error covariance P (k n, k n)) propagated by
    ``dt`` s: (row (27,), its (12, 12) covariance of (phi, p, omega, v_cam))."""
    n = 18 if acc else 12
    Xn = np.empty((1, _ROW))
    F, Q = _transition(X[0], dt, acc, qa, ql, Xn[0])
    C = _outputs(Xn, _shift_covariance(P, F, Q, n, np.int64(0)), n)  # (update()'s signature)
    return Xn[0], C[0]


_NO_G = np.zeros((12, 6))
#: the measurement arguments of _update_window when there is none (m = 0)
_NO_MEASUREMENT = (
    0,
    np.zeros((12, 12)),
    np.eye(3),
    np.zeros(3),
    np.zeros(3),
    np.zeros(3),
    _NO_G,
    False,
    False,
    np.zeros(6),
    np.zeros((6, 6)),
)
#: the (12, 12) covariance's pose and twist blocks in ROS order (FusedState's)
_ROS_POSE = np.ix_(ROS_ORDER, ROS_ORDER)
_ROS_TWIST = np.ix_(6 + ROS_ORDER, 6 + ROS_ORDER)


def _fused_state(stamp, x, cov, fused=False, restarted=False, smoothed=0, nis=float("nan")):
    """FusedState of a window row x (27,) (see ``_ROW``) and its (12, 12) covariance; the
    arrays are views of x (rows are never changed once the filter has handed them out).

    Built as the dataclass' ``__init__`` would (it only sets the fields, in ``__dict__``;
    ``test_fusion`` checks the result equals ``FusedState(...)``), at a fifth of its cost: the
    frozen dataclass' ``__init__`` goes through ``object.__setattr__`` field by field."""
    state = object.__new__(FusedState)
    state.__dict__.update(
        pose=RSPose._trusted(
            x[ROW_O : ROW_O + 9].reshape(3, 3),
            x[ROW_P : ROW_P + 3],
            x[ROW_OMEGA : ROW_OMEGA + 3],
            x[ROW_V_CAM : ROW_V_CAM + 3],
            stamp,
        ),
        angular_acceleration=x[ROW_ALPHA : ROW_ALPHA + 3],
        linear_acceleration=x[ROW_A : ROW_A + 3],
        covariance=cov,
        fused=fused,
        restarted=restarted,
        smoothed=smoothed,
        nis=nis,
    )
    return state


def _python_twin(kernel: Any, twins: dict) -> Callable:
    """The plain-Python function of a numba ``kernel`` (its ``py_func``) with every kernel it
    calls replaced by its own twin in turn (numba's dispatchers, or the stand-ins of
    :mod:`rs_localizer.runtime.jit_cache`, both carry ``py_func``): the same code that
    compiles nothing. ``twins``: the twins made so far, by kernel."""
    key = id(kernel)
    if key not in twins:
        f = kernel.py_func
        scope = dict(f.__globals__)
        twins[key] = types.FunctionType(
            f.__code__, scope, f.__name__, f.__defaults__, f.__closure__
        )
        for name in f.__code__.co_names:
            called = scope.get(name)
            if callable(called) and hasattr(called, "py_func"):
                scope[name] = _python_twin(called, twins)
    return twins[key]


@functools.lru_cache(maxsize=1)
def _python_kernels() -> SimpleNamespace:
    """:data:`_KERNELS` as plain Python (:func:`_python_twin`), for a filter that must not
    compile (``TwistFilter.compiled`` False): a few milliseconds per frame."""
    twins: dict = {}
    return SimpleNamespace(**{k: _python_twin(v, twins) for k, v in vars(_KERNELS).items()})


#: the kernels :class:`TwistFilter` calls
_KERNELS = SimpleNamespace(
    predict_row=_predict_row,
    prepare_measurement=_prepare_measurement,
    skew_matrix=skew_matrix,
    outputs=_outputs,
    update_window=_update_window,
)


class TwistFilter:
    """Fixed-lag error-state Kalman smoother over per-frame RS estimates (see the module
    docstring).

    Feed estimates in time order with :meth:`update`; :meth:`predict` gives the state at a
    later time without changing the filter (the tracker's motion model); :meth:`flush`
    returns the frames not yet returned. Stamps are integers in ns; a constant offset for all
    frames (e.g. header stamps of row 0 instead of the reference row) does not matter.

    The window (newest frame first): ``window`` (bookkeeping per frame), ``X`` (k, 27) the
    frames' nominal states, one row each (O (3, 3) row-major, p, omega, v, alpha, a, then
    v_cam = O^T v; zero accelerations for the velocity model), ``P`` (k n, k n) their joint
    error covariance (n = 18 or 12 error states per frame, module docstring), ``C`` (k, 12,
    12) each frame's covariance in the :class:`FusedState` layout. Updates replace these
    arrays, never change them in place (the states handed out are views of them).

    Args:
        options: :class:`FusionOptions`.

    Attributes:
        pose_scale: the learned factor on the covariance of pose-only measurements (>= 1;
            1 without ``adaptive_scale``; see the module docstring), kept by :meth:`reset`.
        compiled: the filter's steps run as numba kernels (default: unless this process
            cannot compile them, :func:`~rs_localizer.estimation.implementation.
            compiled_by_default`); False: the same code as plain Python, which compiles
            nothing (a frame solved on the estimator's NumPy implementation while the
            kernels compile in the background; the caller sets it per frame, the state is
            the same either way).
    """

    def __init__(self, options: FusionOptions | None = None):
        self.compiled = compiled_by_default()
        self.options = o = options or FusionOptions()
        self._acc = o.model == "acceleration"
        self.n = 18 if self._acc else 12
        self._limit = {m: (float(chi2.ppf(o.gate, m)) if o.gate < 1.0 else np.inf) for m in (6, 12)}
        self._qa, self._ql = float(o.angular_noise) ** 2, float(o.linear_noise) ** 2
        self._acc_var = np.repeat([o.angular_acceleration_std**2, o.linear_acceleration_std**2], 3)
        self._scale = float(o.measurement_scale)
        self.pose_scale = 1.0
        self._adapt_limit = float(chi2.ppf(ADAPT_QUANTILE, 6))
        self.reset()

    @property
    def _k(self) -> SimpleNamespace:
        """The kernels of this call: compiled, or as plain Python (:attr:`compiled`)."""
        return _KERNELS if self.compiled else _python_kernels()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget the state (frames not yet returned are dropped; see :meth:`flush`); the
        learned :attr:`pose_scale` is kept."""
        self.window: list[_Entry] = []  # newest first
        self.X = np.zeros((0, _ROW))
        self.P = np.zeros((0, 0))
        self.C = np.zeros((0, 12, 12))
        self.rejections = 0

    @property
    def initialized(self) -> bool:
        return bool(self.window)

    @property
    def stamp_ns(self) -> int | None:
        """Stamp of the newest frame, or None."""
        return self.window[0].stamp if self.window else None

    def _snapshot(self):
        """A function giving the newest state as it is now (for :class:`FusionStep`; X and C
        are replaced by updates, never changed in place)."""
        e = self.window[0]
        x, cov = self.X[0], self.C[0]
        stamp, fused, restarted, age, nis = e.stamp, e.fused, e.restarted, e.age, e.nis
        return lambda: _fused_state(stamp, x, cov, fused, restarted, age, nis)

    def state(self, i: int = 0) -> FusedState:
        """The current estimate of the frame ``i`` frames back in the window (0: newest).

        Raises:
            IndexError: no such frame in the window.
        """
        e = self.window[i]
        return _fused_state(e.stamp, self.X[i], self.C[i], e.fused, e.restarted, e.age, e.nis)

    def predict(self, stamp_ns: int) -> FusedState:
        """The newest state propagated to ``stamp_ns`` (>= its stamp; earlier stamps give the
        newest state), without changing the filter.

        Raises:
            RuntimeError: before the first update.
        """
        if not self.window:
            raise RuntimeError("TwistFilter.predict before the first update")
        stamp_ns = int(stamp_ns)
        dt = max((stamp_ns - self.window[0].stamp) * 1e-9, 0.0)
        x, cov = self._k.predict_row(self.X, self.P, dt, self._acc, self._qa, self._ql)
        return _fused_state(stamp_ns, x, cov)

    def flush(self) -> list:
        """Frames of the window not returned yet (oldest first), with their estimates so far;
        they are not returned again. The filter keeps its state."""
        out = []
        for i in range(len(self.window) - 1, -1, -1):
            e = self.window[i]
            if not e.emitted:
                e.emitted = True
                out.append(self.state(i))
        return out

    def _finalize(self) -> list:
        """Entries that reached the lag and were not returned yet (oldest first)."""
        out = []
        L = self.options.lag
        for i in range(len(self.window) - 1, -1, -1):
            e = self.window[i]
            if not e.emitted and e.age >= L:
                e.emitted = True
                out.append(self.state(i))
        return out

    # ------------------------------------------------------------------ measurement
    def _measurement_inputs(self, est: RSPoseEstimate, prior: MotionPrior | None = None):
        """The arguments of :func:`_prepare_measurement` for an estimate up to
        ``measurement_scale`` (m, cov, O, p, omega, v_cam, G, has_G, prior_on, mean, info),
        or None when it is unusable by its shapes (failed, no (12, 12) covariance;
        finiteness is checked by the kernel)."""
        if not est.success or est.covariance is None:
            return None
        cov = np.asarray(est.covariance, dtype=float)
        if cov.shape != (12, 12):
            return None
        m = 12 if est.twist_covariance is not None else 6
        G = est.acceleration_sensitivity
        if G is not None:
            G = np.asarray(G, dtype=float)
        has_G = G is not None and G.shape == (12, 6)
        if prior is not None and m == 12 and prior.enabled:
            _, mean, info = prior_arrays(prior)  # ROS (v, omega) order
            on = True
        else:
            on, mean, info = False, _NO_MEASUREMENT[9], _NO_MEASUREMENT[10]
        return (
            m,
            cov,
            np.asarray(est.pose.orientation, dtype=float),
            np.asarray(est.pose.position, dtype=float),
            np.asarray(est.pose.angular_velocity, dtype=float),
            np.asarray(est.pose.linear_velocity, dtype=float),
            G if has_G else _NO_G,
            has_G,
            on,
            mean,
            info,
        )

    def _measurement(self, est: RSPoseEstimate, prior: MotionPrior | None = None):
        """The measurement an estimate gives: a :class:`_Measurement` with m = 12 (pose and
        twist with the (12, 12) covariance) or 6 (pose only: no twist covariance, a global
        shutter), or None when unusable. R is scaled by ``measurement_scale``; G (m, 6) is the
        acceleration sensitivity or None (the velocity model adds its effect to R instead).

        ``prior``: the :class:`~rs_localizer.estimation.prior.MotionPrior` the estimate's
        refinement used (maximum a posteriori), whose information is taken out again (the
        filter fuses what the frame's data say: the prior may be the filter's own prediction).
        At the estimate, posterior information = data information + prior information (in
        the twist block), so the data-only measurement is ``z_d = L_d^-1 (L_post z_post -
        L_prior m)`` with ``L_d = L_post - L_prior``, and its sensitivity ``L_d^-1 L_post G``.
        (:meth:`update` does the same inside :func:`_update_window`.)
        """
        args = self._measurement_inputs(est, prior)
        if args is None:
            return None
        ok, deprior, Ori, p, w, v, R, G, has_G = self._k.prepare_measurement(
            *args, self._scale_of(args[0]), self._acc, self._acc_var
        )
        if not ok:
            return None
        z = _Measurement(args[0], Ori, p, w, v, R)
        z.G = G if has_G else None
        z.deprior = deprior
        return z

    def _scale_of(self, m: int) -> float:
        """The factor on the covariance of a measurement of ``m`` (12 or 6) values:
        ``measurement_scale``, times :attr:`pose_scale` for a pose only."""
        return self._scale * self.pose_scale if m == 6 else self._scale

    def _learn(self, nis: float, m: int) -> None:
        """Move :attr:`pose_scale` after a pose-only measurement whose normalized innovation
        squared was ``nis`` (module docstring)."""
        if m != 6 or not self.options.adaptive_scale or np.isnan(nis):
            return
        step = ADAPT_RATE * (float(nis > self._adapt_limit) - (1.0 - ADAPT_QUANTILE))
        self.pose_scale = min(max(self.pose_scale * float(np.exp(step)), 1.0), ADAPT_MAX_SCALE)

    def _start(self, stamp_ns, z) -> None:
        """(Re)start the window from the measurement ``z`` of one frame, taken with the
        motion prior its refinement used (``_measurement(estimate)``, no prior given): the
        filter then has no velocity information of its own, so the prior is counted once, and
        it is what keeps a twist the frame's data hardly determine (a slow readout, a plane)
        where the estimate put it. Without it the state would be the data-only twist, e.g.
        15 +- 11 rad/s from a still camera whose estimate says 1.7 +- 1.4, and its prediction
        one frame later would miss the next frame: relocalized, refused by the gate, started
        again from such a twist, frame after frame."""
        o = self.options
        n = self.n
        m, Rm, G = z.m, z.R, z.G
        Ori = np.array(z.Ori, dtype=float)
        omega = np.array(z.omega, dtype=float) if m == 12 else np.zeros(3)
        v = Ori @ z.v if m == 12 else np.zeros(3)
        e = _Entry(stamp_ns)
        e.fused, e.restarted = True, True
        P = np.zeros((n, n))
        # the state is z - G (alpha, a_cam) - noise: with the accelerations' prior A,
        # P_zz = R + G A G^T, P_z,acc = -G A (a_cam = O^T a: the world a's block maps by O)
        A = np.diag(self._acc_var)
        if G is not None:
            Ta = np.eye(6)
            Ta[3:6, 3:6] = Ori  # d(alpha, a_world) / d(alpha, a_cam)
            Rm = Rm + G @ A @ G.T
            cross = -(G @ A) @ Ta.T  # (m, 6) cov(z part, (alpha, a_world))
        else:
            cross = np.zeros((m, 6))
        J = np.eye(12)
        if m == 12:  # world-frame v = O v_cam: dv = -[v]x phi + O dv_cam
            J[9:12, 0:3] = -self._k.skew_matrix(v)
            J[9:12, 9:12] = Ori
        J = J[:, :m]
        P[:12, :12] = J @ Rm @ J.T
        if m == 6:
            P[6:12, 6:12] = np.eye(6) * o.initial_velocity**2
        if self._acc:
            Aw = np.diag(self._acc_var)
            Aw[3:6, 3:6] = Ori @ A[3:6, 3:6] @ Ori.T
            P[12:18, 12:18] = Aw
            P[:12, 12:18] = J @ cross
            P[12:18, :12] = P[:12, 12:18].T
        X = np.zeros((1, _ROW))
        X[0, 0:9], X[0, 9:12], X[0, 12:15], X[0, 15:18] = Ori.ravel(), z.p, omega, v
        self.window = [e]
        self.P = 0.5 * (P + P.T)
        self.C = self._k.outputs(X, self.P, n)
        self.X = X
        self.rejections = 0

    def update(
        self,
        stamp_ns: int,
        estimate: RSPoseEstimate,
        relocalized: bool = False,
        prior: MotionPrior | None = None,
    ) -> FusionStep:
        """Fuse one per-frame estimate.

        Args:
            stamp_ns: the frame's time (ns): the time of ``estimate.pose``.
            estimate: the frame's :class:`~rs_localizer.estimation.result.RSPoseEstimate` (a
                camera's or a rig's; read: ``success``, ``pose``, ``covariance``,
                ``twist_covariance``, ``acceleration_sensitivity``). A failed estimate or
                one without a finite (12, 12) ``covariance`` is not fused: the frame gets the
                prediction; one without ``twist_covariance`` (a global shutter) is fused as a
                pose only.
            relocalized: the frame was not found from the previous one (the tracker's
                relocalization): a measurement the gate rejects restarts the filter at once.
            prior: the :class:`~rs_localizer.estimation.prior.MotionPrior` the estimate's
                refinement holds, if any (a camera's ``RSPoseEstimate.motion_prior_used``;
                :class:`~rs_localizer.tracking.tracker.Solve`): its
                information is removed before fusing (see :meth:`_measurement`), but not from
                a frame the filter (re)starts from (:meth:`_start`).
        Returns:
            :class:`FusionStep`: the filtered state at the frame and the frames now final.
        """
        o = self.options
        stamp_ns = int(stamp_ns)
        flushed = []
        if self.window:
            dt = (stamp_ns - self.window[0].stamp) * 1e-9
            if dt <= 0 or dt > o.max_gap:
                flushed = self.flush()
                self.reset()
        if not self.window:
            meas = self._measurement(estimate)  # (a start keeps the prior: see _start)
            if meas is None:
                return FusionStep(None, flushed)
            self._start(stamp_ns, meas)
            return FusionStep(self._snapshot(), flushed + self._finalize())
        # propagate the newest entry and shift the window (the oldest falls out when full),
        # then fuse the measurement into every frame of the window (one kernel call)
        args = self._measurement_inputs(estimate, prior) or _NO_MEASUREMENT
        keep = min(len(self.window), o.lag)
        status, nis, self.X, self.P, self.C = self._k.update_window(
            self.X,
            self.P,
            dt,
            keep,
            self._acc,
            self._qa,
            self._ql,
            self._limit.get(args[0], np.inf),
            *args,
            self._scale_of(args[0]),
            self._acc_var,
        )
        for e in self.window[keep:]:  # fell out of the window (returned already unless lag 0)
            e.emitted = True
        new = _Entry(stamp_ns)
        self.window = [new] + self.window[:keep]
        for e in self.window[1:]:
            e.age += 1
        if status < 0:  # no usable measurement: the frame gets the prediction
            return FusionStep(self._snapshot(), self._finalize())
        new.nis = nis
        if status == 0:  # gated out
            self.rejections += 1
            if relocalized or self.rejections > o.max_rejections:
                new.emitted = True  # the frame restarts the filter instead
                flushed = self.flush()
                self._start(stamp_ns, self._measurement(estimate))
                self.window[0].nis = nis
                return FusionStep(self._snapshot(), flushed + self._finalize())
        else:
            self.rejections = 0
            new.fused = True
        self._learn(nis, args[0])  # (fused or gated out; not a frame that restarts the filter)
        return FusionStep(self._snapshot(), self._finalize())
