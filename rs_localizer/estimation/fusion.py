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
Measurements whose normalized innovation squared exceeds the ``gate`` quantile of the
chi-square distribution are not fused; the filter restarts from the measurement after
``max_rejections`` consecutive rejections (at once when the caller says the frame was
relocalized), and on a stamp going back or a gap longer than ``max_gap``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit
from scipy.stats import chi2

from .._so3 import skew_matrix, so3_coefficients
from .prior import prior_arrays

__all__ = ["FusionOptions", "FusedState", "FusionStep", "TwistFilter", "MODELS"]

#: process models: constant acceleration (18 error states per frame) or constant velocity (12)
MODELS = ("acceleration", "velocity")


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

    def __post_init__(self):
        if self.model not in MODELS:
            raise ValueError(f"unknown fusion model {self.model!r}; expected one of {MODELS}")
        if int(self.lag) != self.lag or not 0 <= self.lag <= 10:
            raise ValueError(f"lag must be an integer in [0, 10], got {self.lag}")
        for name in ("angular_noise", "linear_noise", "angular_acceleration_std",
                     "linear_acceleration_std", "initial_velocity", "max_gap"):
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
        stamp_ns: the frame's stamp (ns, as fed to the filter).
        orientation (3, 3), position (3,): camera -> world, camera centre (m).
        angular_velocity, linear_velocity (3,): camera frame (rad/s, m/s).
        linear_velocity_world (3,): world frame (m/s).
        angular_acceleration (3,, camera frame, rad/s^2), linear_acceleration (3,, world,
            m/s^2): zero for the velocity model.
        covariance: (12, 12) over (rotation [rad, world axes], position [m, world], angular
            velocity [rad/s, camera], linear velocity [m/s, camera]), the layout of
            ``RSPoseEstimate.covariance``.
        pose_covariance, twist_covariance: (6, 6) ROS order (x, y, z, rot x, rot y, rot z;
            vx, vy, vz, wx, wy, wz).
        fused: the frame's own measurement was fused (False: gated out or unusable).
        restarted: the filter (re)started from this frame.
        smoothed: frames after this one have been fused into it (its lag).
        nis: normalized innovation squared of the frame's measurement (NaN if none).
    """

    stamp_ns: int
    orientation: np.ndarray
    position: np.ndarray
    angular_velocity: np.ndarray
    linear_velocity: np.ndarray
    linear_velocity_world: np.ndarray
    angular_acceleration: np.ndarray
    linear_acceleration: np.ndarray
    covariance: np.ndarray = field(repr=False)
    fused: bool = False
    restarted: bool = False
    smoothed: int = 0
    nis: float = float("nan")

    @property
    def pose_covariance(self) -> np.ndarray:
        return self.covariance[_ROS_POSE]

    @property
    def twist_covariance(self) -> np.ndarray:
        return self.covariance[_ROS_TWIST]


class FusionStep:
    """What :meth:`TwistFilter.update` returns.

    Attributes:
        current: the filtered (causal) :class:`FusedState` at the new frame, ``None`` if the
            filter has no state (computed on first access).
        final: frames whose estimate is now final, oldest first: normally the frame ``lag``
            frames back; on a restart every frame not yet returned; the new frame for lag 0.
    """

    __slots__ = ("_make", "_current", "final")

    def __init__(self, make, final: list):
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

    def __init__(self, m, O, p, omega, v, R):
        self.m, self.O, self.p, self.omega, self.v, self.R = m, O, p, omega, v, R
        self.G = None
        self.deprior = False


class _Entry:
    """Nominal state of one frame in the window, with its bookkeeping."""

    __slots__ = ("stamp", "O", "p", "omega", "v", "alpha", "a", "fused", "restarted", "nis",
                 "emitted", "age")

    def __init__(self, stamp, O, p, omega, v, alpha, a):
        self.stamp, self.O, self.p, self.omega, self.v = int(stamp), O, p, omega, v
        self.alpha, self.a = alpha, a
        self.fused = False
        self.restarted = False
        self.nis = float("nan")
        self.emitted = False
        self.age = 0


# ------------------------------------------------------------------------- numba kernels
# (the filter runs once per frame next to a ~1 ms estimator: NumPy's per-call overhead on
# 3x3 to 36x36 matrices would cost more than the arithmetic)
@njit(cache=True)
def _exp(theta):
    """``expm([theta]x)`` (3, 3) (Rodrigues)."""
    a, b, _ = so3_coefficients(theta[0] ** 2 + theta[1] ** 2 + theta[2] ** 2)
    K = skew_matrix(theta)
    return np.eye(3) + a * K + b * (K @ K)


@njit(cache=True)
def _log(R):
    """Rotation vector (3,) of a rotation matrix (3, 3)."""
    c = min(max(0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0), -1.0), 1.0)
    th = np.arccos(c)
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if th < 1e-6:
        return 0.5 * v
    if th < np.pi - 1e-4:
        return v * (0.5 * th / np.sin(th))
    # near pi: the axis from the symmetric part (largest diagonal of R + I)
    B = 0.5 * (R + np.eye(3))
    k = np.argmax(np.array([B[0, 0], B[1, 1], B[2, 2]]))
    axis = B[:, k] / np.sqrt(max(B[k, k], 1e-300))
    axis /= np.sqrt(axis @ axis)
    if axis @ v < 0:
        axis = -axis
    return axis * th


@njit(cache=True)
def _chain_q(dt, order):
    """Discrete covariance of an ``order``-fold integrator chain driven by unit continuous
    white noise on its last state, over ``dt`` (order 2: position, velocity; 3: with the
    acceleration)."""
    if order == 2:
        return np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    return np.array([[dt**5 / 20, dt**4 / 8, dt**3 / 6],
                     [dt**4 / 8, dt**3 / 3, dt**2 / 2],
                     [dt**3 / 6, dt**2 / 2, dt]])


@njit(cache=True)
def _transition(O, p, omega, v, alpha, a, dt, acc, qa, ql):
    """One step of the process model (module docstring) for ``dt`` s.

    Returns (O', p', omega', v', F (n, n), Q (n, n)) with n = 18 (``acc``) or 12; ``qa``,
    ``ql`` are the angular and linear spectral densities."""
    n = 18 if acc else 12
    h = 0.5 * dt * dt
    theta = omega * dt + h * alpha if acc else omega * dt
    c1, c2, c3 = so3_coefficients(theta @ theta)
    K = skew_matrix(theta)
    K2 = K @ K
    On = O @ (np.eye(3) + c1 * K + c2 * K2)
    Jr = np.eye(3) - c2 * K + c3 * K2  # right Jacobian: expm(th + d) ~ expm(th) expm(Jr d)
    if acc:
        pn, wn, vn = p + v * dt + h * a, omega + alpha * dt, v + a * dt
    else:
        pn, wn, vn = p + v * dt, omega.copy(), v.copy()
    F = np.eye(n)
    OJ = On @ Jr
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
    return On, pn, wn, vn, F, Q


@njit(cache=True)
def _shift_covariance(P, F, Q, n, keep):
    """``Fa P Fa^T + Q`` for the window: the newest block propagated by F, the ``keep``
    newest old blocks shifted back one place (the rest dropped)."""
    M = (keep + 1) * n
    out = np.empty((M, M))
    FP = F @ np.ascontiguousarray(P[:n, :(keep + 1) * n])
    out[:n, :n] = np.ascontiguousarray(FP[:, :n]) @ np.ascontiguousarray(F.T) + Q
    if keep:
        out[:n, n:] = FP[:, :keep * n]
        out[n:, :n] = FP[:, :keep * n].T
        out[n:, n:] = P[:keep * n, :keep * n]
    return out


@njit(cache=True)
def _kalman_update(P, H, y, R):
    """Kalman update with a measurement on the newest block (H (m, n) on the first n
    columns of P (M, M)). Returns (nis, dx (M,), P' (M, M), ok); ok False if the innovation
    covariance is not positive definite (nothing else is valid then)."""
    m, n = H.shape
    PHt = np.ascontiguousarray(P[:, :n]) @ np.ascontiguousarray(H.T)
    S = H @ np.ascontiguousarray(PHt[:n]) + R
    S = 0.5 * (S + S.T)
    # Cholesky by hand (no exception inside numba for a non-positive matrix)
    L = np.zeros((m, m))
    for j in range(m):
        d = S[j, j] - L[j, :j] @ L[j, :j]
        if not d > 0.0:
            return np.inf, np.zeros(P.shape[0]), P, False
        L[j, j] = np.sqrt(d)
        for i in range(j + 1, m):
            L[i, j] = (S[i, j] - L[i, :j] @ L[j, :j]) / L[j, j]
    # forward substitution: z = L^-1 y, W = L^-1 (H P) so that K S K^T = W^T W, K y = W^T z
    z = np.empty(m)
    W = np.empty((m, P.shape[0]))
    B = np.ascontiguousarray(PHt.T)
    for i in range(m):
        z[i] = (y[i] - L[i, :i] @ z[:i]) / L[i, i]
        W[i] = (B[i] - L[i, :i] @ W[:i]) / L[i, i]
    P2 = P - W.T @ W
    return z @ z, W.T @ z, 0.5 * (P2 + P2.T), True


@njit(cache=True)
def _innovation(O, p, omega, v, alpha, a, zO, zp, zomega, zv, m, n, G, use_G):
    """Innovation y (m,) and Jacobian H (m, n) on the newest state of a measurement of
    (rotation, position[, omega, v_cam = O^T v]); with ``use_G`` (acceleration model) the
    measurement also moves by ``G (alpha, O^T a)``."""
    y = np.zeros(m)
    H = np.zeros((m, n))
    y[0:3] = _log(zO @ O.T)
    for i in range(3):
        y[3 + i] = zp[i] - p[i]
        H[i, i] = 1.0
        H[3 + i, 3 + i] = 1.0
    Ot = np.ascontiguousarray(O.T)
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


@njit(cache=True)
def _cholesky_ok(S):
    """True if the symmetric matrix S is positive definite (Cholesky runs through)."""
    n = S.shape[0]
    L = np.zeros((n, n))
    for j in range(n):
        d = S[j, j] - L[j, :j] @ L[j, :j]
        if not d > 0.0:
            return False
        L[j, j] = np.sqrt(d)
        for i in range(j + 1, n):
            L[i, j] = (S[i, j] - L[i, :j] @ L[j, :j]) / L[j, j]
    return True


@njit(cache=True)
def _deprior(cov, p, omega, v, mean, info, G):
    """Take a twist prior (ROS order mean (6,), information (6, 6)) out of a posterior
    estimate (covariance (12, 12) over (rotation, position, omega, v), values p, omega, v;
    rotation 0 at the estimate): returns (ok, data values (12,) (rotation relative to the
    estimate), data covariance (12, 12), data sensitivity (12, 6) from the posterior's G)."""
    idx = np.array([9, 10, 11, 6, 7, 8])
    if not _cholesky_ok(cov):
        return False, np.zeros(12), cov, G
    L_post = np.linalg.inv(cov)
    L_d = L_post.copy()
    mp = np.zeros(12)
    for a in range(6):
        mp[idx[a]] = mean[a]
        for b in range(6):
            L_d[idx[a], idx[b]] -= info[a, b]
    L_d = 0.5 * (L_d + L_d.T)
    if not _cholesky_ok(L_d):
        return False, np.zeros(12), cov, G
    R_d = np.linalg.inv(L_d)
    R_d = 0.5 * (R_d + R_d.T)
    zp = np.zeros(12)
    zp[3:6], zp[6:9], zp[9:12] = p, omega, v
    rhs = L_post @ zp
    for a in range(6):
        for b in range(6):
            rhs[idx[a]] -= info[a, b] * mean[b]
    return True, R_d @ rhs, R_d, R_d @ (L_post @ G)


@njit(cache=True)
def _camera_covariance(O, v, Pb):
    """(12, 12) covariance of (phi, p, omega, v_cam = O^T v) from the (n, n) block over
    (phi, p, omega, v, ...): ``d v_cam = O^T [v]x phi + O^T dv``."""
    J = np.zeros((12, 12))
    for i in range(9):
        J[i, i] = 1.0
    A = O.T @ skew_matrix(v)
    for i in range(3):
        for j in range(3):
            J[9 + i, j] = A[i, j]
            J[9 + i, 9 + j] = O[j, i]
    Pc = np.ascontiguousarray(Pb[:12, :12])
    cov = J @ Pc @ J.T
    return 0.5 * (cov + cov.T)


_NO_G = np.zeros((12, 6))
_ROS_POSE = np.ix_([3, 4, 5, 0, 1, 2], [3, 4, 5, 0, 1, 2])
#: indices of the ROS twist order (vx, vy, vz, wx, wy, wz) in the (12,) output layout
_TWIST_ROS = np.array([[9], [10], [11], [6], [7], [8]])
_ROS_TWIST = np.ix_([9, 10, 11, 6, 7, 8], [9, 10, 11, 6, 7, 8])


class TwistFilter:
    """Fixed-lag error-state Kalman smoother over per-frame RS estimates (see the module
    docstring).

    Feed estimates in time order with :meth:`update`; :meth:`predict` gives the state at a
    later time without changing the filter (the tracker's motion model); :meth:`flush`
    returns the frames not yet returned. Stamps are integers in ns; a constant offset for all
    frames (e.g. header stamps of row 0 instead of the reference row) does not matter.

    Args:
        options: :class:`FusionOptions`.
    """

    def __init__(self, options: FusionOptions | None = None):
        self.options = o = options or FusionOptions()
        self._acc = o.model == "acceleration"
        self.n = 18 if self._acc else 12
        self._limit = {m: (float(chi2.ppf(o.gate, m)) if o.gate < 1.0 else np.inf)
                       for m in (6, 12)}
        self._qa, self._ql = float(o.angular_noise) ** 2, float(o.linear_noise) ** 2
        self._acc_var = np.repeat([o.angular_acceleration_std**2,
                                   o.linear_acceleration_std**2], 3)
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget everything (frames not yet returned are dropped; see :meth:`flush`)."""
        self.window: list[_Entry] = []  # newest first
        self.P = np.zeros((0, 0))
        self.rejections = 0

    @property
    def initialized(self) -> bool:
        return bool(self.window)

    @property
    def stamp_ns(self) -> int | None:
        """Stamp of the newest frame, or None."""
        return self.window[0].stamp if self.window else None

    def _step(self, e: _Entry, dt: float):
        """Propagate one entry by ``dt``: (new entry, F (n, n), Q (n, n))."""
        O, p, w, v, F, Q = _transition(e.O, e.p, e.omega, e.v, e.alpha, e.a, float(dt),
                                       self._acc, self._qa, self._ql)
        return _Entry(e.stamp, O, p, w, v, e.alpha, e.a), F, Q

    def _state(self, e: _Entry, P: np.ndarray) -> FusedState:
        """FusedState of one entry with its (n, n) covariance block."""
        cov = _camera_covariance(e.O, e.v, P)
        # (the entries' arrays are replaced by updates, never changed in place: no copies)
        return FusedState(
            stamp_ns=e.stamp, orientation=e.O, position=e.p, angular_velocity=e.omega,
            linear_velocity=e.O.T @ e.v, linear_velocity_world=e.v,
            angular_acceleration=e.alpha, linear_acceleration=e.a, covariance=cov,
            fused=e.fused, restarted=e.restarted, smoothed=e.age, nis=e.nis)

    def _block(self, i: int) -> np.ndarray:
        n = self.n
        return self.P[i * n:(i + 1) * n, i * n:(i + 1) * n]

    def _snapshot(self):
        """A function giving the newest state as it is now (for :class:`FusionStep`; the
        entries' arrays and P are replaced by updates, never changed in place)."""
        src, P = self.window[0], self._block(0)
        e = _Entry(src.stamp, src.O, src.p, src.omega, src.v, src.alpha, src.a)
        e.fused, e.restarted, e.age, e.nis = src.fused, src.restarted, src.age, src.nis
        return lambda: self._state(e, P)

    def state(self, i: int = 0) -> FusedState:
        """The current estimate of the frame ``i`` frames back in the window (0: newest).

        Raises:
            IndexError: no such frame in the window.
        """
        return self._state(self.window[i], self._block(i))

    def predict(self, stamp_ns: int) -> FusedState:
        """The newest state propagated to ``stamp_ns`` (>= its stamp; earlier stamps give the
        newest state), without changing the filter.

        Raises:
            RuntimeError: before the first update.
        """
        if not self.window:
            raise RuntimeError("TwistFilter.predict before the first update")
        dt = max((int(stamp_ns) - self.window[0].stamp) * 1e-9, 0.0)
        e, F, Q = self._step(self.window[0], dt)
        e.stamp = int(stamp_ns)
        return self._state(e, _shift_covariance(self._block(0).copy(), F, Q, self.n, 0))

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
    def _measurement(self, est, prior=None):
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
        """
        if not getattr(est, "success", False):
            return None
        cov = getattr(est, "covariance", None)
        if cov is None:
            return None
        cov = np.asarray(cov, dtype=float)
        m = 12 if getattr(est, "twist_covariance", None) is not None else 6
        if cov.shape != (12, 12) or not np.isfinite(cov[:m, :m]).all():
            return None
        z = _Measurement(m, np.asarray(est.orientation, dtype=float),
                         np.asarray(est.position, dtype=float),
                         np.asarray(est.angular_velocity, dtype=float),
                         np.asarray(est.linear_velocity, dtype=float), cov[:m, :m].copy())
        G = getattr(est, "acceleration_sensitivity", None)
        if G is not None:
            G = np.asarray(G, dtype=float)
            G = np.ascontiguousarray(G[:m]) if G.shape == (12, 6) and np.isfinite(G).all() \
                else None
        if prior is not None and m == 12 and getattr(prior, "enabled", False):
            _, mean, info = prior_arrays(prior)  # ROS (v, omega) order
            ok, zd, R_d, G_d = _deprior(z.R, z.p, z.omega, z.v, mean, info,
                                        G if G is not None else np.zeros((12, 6)))
            if ok:  # (else the data information is not positive definite: keep the posterior)
                z = _Measurement(m, _exp(zd[0:3]) @ z.O, zd[3:6], zd[6:9], zd[9:12], R_d)
                G = G_d if G is not None else None
                z.deprior = True
        z.R = np.ascontiguousarray(self.options.measurement_scale * z.R)
        if G is not None and not self._acc:
            z.R = z.R + (G * self._acc_var) @ G.T
            G = None
        z.G = G
        return z

    def _start(self, stamp_ns, z) -> None:
        o = self.options
        n = self.n
        m, Rm, G = z.m, z.R, z.G
        O = np.array(z.O, dtype=float)
        omega = np.array(z.omega, dtype=float) if m == 12 else np.zeros(3)
        v = O @ z.v if m == 12 else np.zeros(3)
        e = _Entry(stamp_ns, O, np.array(z.p, dtype=float), omega, v, np.zeros(3), np.zeros(3))
        e.fused, e.restarted = True, True
        P = np.zeros((n, n))
        # the state is z - G (alpha, a_cam) - noise: with the accelerations' prior A,
        # P_zz = R + G A G^T, P_z,acc = -G A (a_cam = O^T a: the world a's block maps by O)
        A = np.diag(self._acc_var)
        if G is not None:
            Ta = np.eye(6)
            Ta[3:6, 3:6] = O  # d(alpha, a_world) / d(alpha, a_cam)
            Rm = Rm + G @ A @ G.T
            cross = -(G @ A) @ Ta.T  # (m, 6) cov(z part, (alpha, a_world))
        else:
            cross = np.zeros((m, 6))
        J = np.eye(12)
        if m == 12:  # world-frame v = O v_cam: dv = -[v]x phi + O dv_cam
            J[9:12, 0:3] = -skew_matrix(v)
            J[9:12, 9:12] = O
        J = J[:, :m]
        P[:12, :12] = J @ Rm @ J.T
        if m == 6:
            P[6:12, 6:12] = np.eye(6) * o.initial_velocity**2
        if self._acc:
            Aw = np.diag(self._acc_var)
            Aw[3:6, 3:6] = O @ A[3:6, 3:6] @ O.T
            P[12:18, 12:18] = Aw
            P[:12, 12:18] = J @ cross
            P[12:18, :12] = P[:12, 12:18].T
        self.window = [e]
        self.P = 0.5 * (P + P.T)
        self.rejections = 0

    def update(self, stamp_ns: int, estimate, relocalized: bool = False,
               prior=None) -> FusionStep:
        """Fuse one per-frame estimate.

        Args:
            stamp_ns: the frame's time (ns).
            estimate: an object with ``success``, ``orientation`` (3, 3), ``position``,
                ``angular_velocity``, ``linear_velocity`` (3,), ``covariance`` (12, 12) and
                ``twist_covariance`` as :class:`RSPoseEstimate`. A failed estimate or one
                without a finite covariance is not fused: the frame gets the prediction.
            relocalized: the frame was not found from the previous one (the tracker's
                relocalization): a measurement the gate rejects restarts the filter at once.
            prior: the :class:`~rs_localizer.estimation.prior.MotionPrior` the estimate's
                refinement used, if any (``RSPoseEstimate.motion_prior_used``): its
                information is removed before fusing (see :meth:`_measurement`).
        Returns:
            :class:`FusionStep`: the filtered state at the frame and the frames now final.
        """
        o = self.options
        n = self.n
        meas = self._measurement(estimate, prior)
        flushed = []
        if self.window:
            dt = (int(stamp_ns) - self.window[0].stamp) * 1e-9
            if dt <= 0 or dt > o.max_gap:
                flushed = self.flush()
                self.reset()
        if not self.window:
            if meas is None:
                return FusionStep(None, flushed)
            self._start(stamp_ns, meas)
            return FusionStep(self._snapshot(), flushed + self._finalize())
        # propagate the newest entry and shift the window (the oldest falls out when full)
        new, F, Q = self._step(self.window[0], dt)
        new.stamp = int(stamp_ns)
        keep = min(len(self.window), o.lag)
        P = _shift_covariance(self.P, F, Q, n, keep)
        for e in self.window[keep:]:  # fell out of the window (returned already unless lag 0)
            e.emitted = True
        self.window = [new] + self.window[:keep]
        for e in self.window[1:]:
            e.age += 1
        self.P = P
        if meas is None:
            return FusionStep(self._snapshot(), self._finalize())
        m, Rm, G = meas.m, meas.R, meas.G
        y, H = _innovation(new.O, new.p, new.omega, new.v, new.alpha, new.a, meas.O, meas.p,
                           meas.omega, meas.v, m, n, G if G is not None else _NO_G, G is not None)
        nis, dx, P_upd, ok = _kalman_update(P, H, y, Rm)
        new.nis = nis
        if not (ok and nis <= self._limit[m]):
            self.rejections += 1
            if relocalized or self.rejections > o.max_rejections:
                new.emitted = True  # the frame restarts the filter instead
                flushed = self.flush()
                self._start(stamp_ns, meas)
                self.window[0].nis = nis
                return FusionStep(self._snapshot(), flushed + self._finalize())
            return FusionStep(self._snapshot(), self._finalize())
        self.rejections = 0
        self.P = P_upd
        for i, e in enumerate(self.window):
            d = dx[i * n:(i + 1) * n]
            e.O = _exp(d[0:3]) @ e.O
            e.p, e.omega, e.v = e.p + d[3:6], e.omega + d[6:9], e.v + d[9:12]
            if self._acc:
                e.alpha, e.a = e.alpha + d[12:15], e.a + d[15:18]
        new.fused = True
        return FusionStep(self._snapshot(), self._finalize())
