"""Online estimation of a gyro's bias from the rotation between solved frames.

A gyro's bias (rad/s, per axis) changes with temperature and from one power-up to the next, so
a bias calibrated once is off by a few 0.01 rad/s later. Two consecutive frames of a video
measure it: the rotation between their estimated poses (at their reference lines) against the
gyro's rotation integrated over the same interval. The gyro integral is off by about
``-R_cam_imu b dt`` for a bias error ``b`` over ``dt`` seconds, and the poses of a tracked
video are good to ~0.01-0.1 deg, so every pair of frames 33 ms apart measures the bias to a
few 0.01 rad/s and a few seconds of video to a few 0.001 rad/s (the gyro's own noise and the
pose errors average down; :mod:`benchmarks.bench_gyro` ``--video`` has the
numbers).

:class:`GyroBiasEstimator` is a Kalman filter on the bias alone (3 states, IMU frame; a random
walk, initialized from a prior such as the node's ``imu.gyro_bias`` and
``imu.gyro_bias_sigma``), updated once per pair of consecutive solved frames:

* measurement: ``r = log(dR_gyro(b_hat)^T O_prev^T O)`` (3,, rad, the camera frame of the
  later frame), ``dR_gyro(b)`` the product of ``expm([R_cam_imu (omega_i - b) h_i]x)`` over
  the samples between the two reference-line times (rates linearly interpolated at the ends,
  each segment at its mean rate);
* model: ``r = H (b - b_hat) + n`` with ``H = -R_cam_imu J`` and ``J`` the derivative of the
  integrated rotation with respect to the bias (the preintegration Jacobian of Forster,
  Carlone, Dellaert, Scaramuzza, "On-manifold preintegration for real-time visual-inertial
  odometry", IEEE T-RO 2017, eq. 44), ``n`` with covariance ``O^T (P_prev + P) O`` (the two
  poses' rotation covariances, world axes, taken as independent) plus the integrated sample
  noise ``noise^2 sum(c_i^2) I`` (``c_i`` the seconds each sample's rate is integrated over);
* a pair whose normalized innovation squared exceeds the chi-square threshold (3 dof) is not
  used (``rejected``: a pose or a gyro sample that is wrong); the later frame starts the next
  pair.

Why a separate filter and not bias states in :class:`~rs_localizer.tracking.fusion.
TwistFilter`: the smoother's measurements are the per-frame estimates, which already contain
the gyro (``estimate_rs_pose(..., gyro=...)`` is maximum a posteriori with it); a bias state
there would count the gyro twice, and the smoother is restarted on every gated measurement,
relocalization or gap, where the bias must persist (it is a property of the IMU, not of the
track). This filter is fed by the same solved frames, and its estimate and covariance go into
every frame's gyro measurement (:meth:`GyroBiasEstimator.measurement`), so the estimator, the
tracker and the smoother's fused twist use the estimated bias.

Approximations (documented rather than modelled): consecutive pairs share a pose, so their
pose errors are correlated (negatively: the errors of a frame enter two pairs with opposite
signs); treating them as independent overstates the bias uncertainty. The per-frame rotation
covariance, on the other hand, is too small under strong accelerations within a readout (the
pairs' mean normalized innovation squared is 3.7 on the synthetic ``walk`` video and 6.3 on
``shake``, 3 expected; ``bench_gyro --video``), which the chi-square test partly absorbs. The
per-frame estimates that used the gyro carry a little of the bias error back into their
rotation; the bias covariance added to every gyro measurement accounts for it.

Conventions as :mod:`rs_localizer.estimation.gyro`: ``omega_cam = R_cam_imu (omega_imu -
bias)``, ``t_cam = t_imu + time_offset``; poses are camera -> world at the frame's reference
line (:class:`~rs_localizer.estimation.estimate.RSPoseEstimate`), stamped on the camera clock.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..estimation.gyro import GYRO_CHI2_THRESHOLD, GyroMeasurement
from ..geometry import matrix_to_rotvec, rotvec_to_matrix, skew
from .gyro import ImuBuffer

__all__ = [
    "BIAS_UPDATE_OUTCOMES",
    "GyroBiasEstimator",
    "GyroBiasOptions",
    "checked_mount",
    "integrate_gyro",
    "pair_innovation",
]

#: what :meth:`GyroBiasEstimator.update` did with a frame: ``used`` (the pair updated the
#: bias), ``rejected`` (the pair failed the chi-square test), ``first`` (the frame starts a
#: pair: the first frame, or after :meth:`~GyroBiasEstimator.restart`), ``gap`` (too long
#: since the previous frame or a stamp going back: the frame starts a new pair), ``no_gyro``
#: (no samples cover the interval: the frame starts a new pair), ``bad_pose`` (a non-finite
#: pose or covariance: the pairing restarts)
BIAS_UPDATE_OUTCOMES = ("used", "rejected", "first", "gap", "no_gyro", "bad_pose")


@dataclass(frozen=True)
class GyroBiasOptions:
    """Parameters of :class:`GyroBiasEstimator`.

    Attributes:
        random_walk: the bias's random walk (rad/s per sqrt(s)): its variance grows by
            ``random_walk^2 dt`` per axis over ``dt`` seconds (MEMS gyros: ~1e-5 to 1e-4), so
            the estimate follows a drifting bias. >= 0.
        chi2_threshold: a pair with a larger normalized innovation squared (3 dof) is
            rejected (default: P = 0.001, as the estimator's gyro consistency test). > 0.
        max_interval: s; two solved frames further apart do not form a pair (the integrated
            rotation over a long interval is dominated by the bias's own uncertainty and an
            error in the time offset). > 0.
        min_interval: s; frames closer than this do not form a pair (a pair of nearly equal
            stamps measures nothing). >= 0.
    """

    random_walk: float = 1e-4
    chi2_threshold: float = GYRO_CHI2_THRESHOLD
    max_interval: float = 0.5
    min_interval: float = 1e-3

    def __post_init__(self):
        if not (np.isfinite(self.random_walk) and self.random_walk >= 0):
            raise ValueError(f"random_walk must be >= 0, got {self.random_walk}")
        if not (np.isfinite(self.chi2_threshold) and self.chi2_threshold > 0):
            raise ValueError(f"chi2_threshold must be > 0, got {self.chi2_threshold}")
        if not (np.isfinite(self.max_interval) and self.max_interval > 0):
            raise ValueError(f"max_interval must be > 0, got {self.max_interval}")
        if not (0 <= self.min_interval < self.max_interval):
            raise ValueError(
                f"need 0 <= min_interval < max_interval, got {self.min_interval}, "
                f"{self.max_interval}"
            )


def checked_mount(
    R_cam_imu: ArrayLike, noise: float, time_offset: float
) -> tuple[np.ndarray, float, float]:
    """The gyro's mounting and noise as :class:`GyroBiasEstimator` and
    :class:`~rs_localizer.tracking.gyro_check.GyroMountCheck` take them: ``(R_cam_imu (3, 3)
    float, noise rad/s per sample, time_offset s)``.

    Raises:
        ValueError: ``R_cam_imu`` not a (3, 3) rotation, ``noise <= 0`` or not finite, a
            non-finite ``time_offset``.
    """
    R = np.asarray(R_cam_imu, dtype=float)
    if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-6):
        raise ValueError("R_cam_imu must be a (3, 3) rotation")
    if not (np.isfinite(noise) and noise > 0):
        raise ValueError(f"noise must be > 0, got {noise}")
    if not np.isfinite(time_offset):
        raise ValueError(f"time_offset must be finite, got {time_offset}")
    return R, float(noise), float(time_offset)


def integrate_gyro(
    t: ArrayLike, rates: ArrayLike, span: float, bias: ArrayLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rotation of the IMU over ``[0, span]`` from its rate samples, with its derivative
    with respect to the bias.

    The rate is linearly interpolated between samples (and at the interval's ends); each
    segment between consecutive knots turns at its mean rate minus ``bias``:
    ``dR = prod_k expm([(omega_k - bias) h_k]x)`` (body frame, in time order).

    Args:
        t: (M,) sample times (s, relative to the interval's start), strictly increasing,
            ``t[0] <= 0`` and ``t[-1] >= span``.
        rates: (M, 3) rad/s, IMU frame.
        span: the interval's length (s), > 0.
        bias: (3,) rad/s, IMU frame, subtracted.
    Returns:
        ``(dR, J, c)``: ``dR`` (3, 3) the IMU's rotation from the interval's start to its end
        (IMU frame at the start -> at the end, as ``O_start^T O_end``); ``J`` (3, 3) with
        ``dR(bias + d) ~ dR(bias) expm([-J d]x)`` (rad per rad/s: about ``span I``); ``c``
        (M,) the seconds over which each sample's rate is integrated (``sum(c) = span``; the
        integrated noise of independent samples of standard deviation ``s`` is ``s^2
        sum(c^2)`` per axis).
    Raises:
        ValueError: shapes, non-finite values, unordered stamps, samples not covering the
            interval, ``span <= 0``.
    """
    t = np.asarray(t, dtype=float).reshape(-1)
    om = np.asarray(rates, dtype=float)
    b = np.asarray(bias, dtype=float).reshape(3)
    span = float(span)
    if om.shape != (len(t), 3) or len(t) < 2:
        raise ValueError(f"need t (M,) and rates (M, 3) with M >= 2, got {t.shape}, {om.shape}")
    if not (np.isfinite(t).all() and np.isfinite(om).all() and np.isfinite(b).all()):
        raise ValueError("gyro samples and bias must be finite")
    if not (np.isfinite(span) and span > 0):
        raise ValueError(f"span must be > 0, got {span}")
    if not (np.diff(t) > 0).all():
        raise ValueError("gyro stamps must be strictly increasing")
    if t[0] > 0 or t[-1] < span:
        raise ValueError(f"samples [{t[0]:.6f}, {t[-1]:.6f}] s do not cover [0, {span:.6f}] s")
    # knots: 0, the samples inside (0, span), span; each knot's rate is a linear combination
    # of the samples (M_knot (K, M))
    inner = np.flatnonzero((t > 0) & (t < span))
    knots = np.concatenate([[0.0], t[inner], [span]])
    Mk = np.zeros((len(knots), len(t)))
    for row, tk in enumerate(knots):
        k = min(max(int(np.searchsorted(t, tk, side="right")) - 1, 0), len(t) - 2)
        u = (tk - t[k]) / (t[k + 1] - t[k])
        Mk[row, k], Mk[row, k + 1] = 1.0 - u, u
    h = np.diff(knots)
    # segment k's mean rate: (knot k + knot k+1) / 2
    seg = 0.5 * (Mk[:-1] + Mk[1:])  # (K-1, M)
    c = h @ seg
    phis = (seg @ om - b) * h[:, None]  # (K-1, 3) rotation vectors per segment
    J = np.zeros((3, 3))
    # J = sum_k (prod_{j > k} R_j)^T Jr(phi_k) h_k (right Jacobian Jr; Forster et al. eq. 44),
    # accumulated backwards
    after = np.eye(3)
    for k in range(len(phis) - 1, -1, -1):
        J += after.T @ _right_jacobian(phis[k]) * h[k]
        after = rotvec_to_matrix(phis[k]) @ after
    return after, J, c


def _right_jacobian(phi: np.ndarray) -> np.ndarray:
    """(3, 3) right Jacobian of SO(3) at the rotation vector ``phi`` (3,)."""
    th = float(np.linalg.norm(phi))
    S = skew(phi)
    if th < 1e-6:
        return np.eye(3) - 0.5 * S + S @ S / 6.0
    return np.eye(3) - (1.0 - np.cos(th)) / th**2 * S + (th - np.sin(th)) / th**3 * (S @ S)


def pair_innovation(
    prev: tuple[int, np.ndarray, np.ndarray],
    cur: tuple[int, np.ndarray, np.ndarray],
    buffer: ImuBuffer,
    R_cam_imu: np.ndarray,
    bias: np.ndarray,
    bias_covariance: np.ndarray,
    noise: float,
    time_offset: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | str:
    """The rotation between two solved frames against the gyro's (the measurement of
    :class:`GyroBiasEstimator`, see the module docstring).

    Args:
        prev, cur: ``(stamp_ns, orientation (3, 3) camera -> world, rotation covariance (3, 3)
            rad^2, world axes)`` of the earlier and the later frame (camera clock).
        buffer: the IMU's samples. R_cam_imu: (3, 3) IMU -> camera optical frame.
        bias: (3,) rad/s, IMU frame, subtracted. bias_covariance: (3, 3) rad^2/s^2, its
            covariance. noise: rad/s per sample. time_offset: s added to the IMU stamps.
    Returns:
        ``(r, H, Rn, S)``: ``r`` (3,) rad, ``log(dR_gyro^T O_prev^T O)`` in the later camera
        frame; ``H`` (3, 3) its derivative with respect to the bias (``-R_cam_imu J``); ``Rn``
        (3, 3) the covariance of the poses and the sample noise; ``S = H P_b H^T + Rn`` the
        innovation's covariance; or the reason of ``no_gyro`` (no samples cover the interval).
    """
    t, rates, span, _ = buffer.interval((prev[0], cur[0]), time_offset)
    if t is None:
        return "no_gyro"
    dR, J, c = integrate_gyro(t, rates, span, bias)
    Rci = R_cam_imu
    dR_cam = Rci @ dR @ Rci.T
    Ori = cur[1]
    r = matrix_to_rotvec(dR_cam.T @ (prev[1].T @ Ori))
    H = -Rci @ J
    Rn = Ori.T @ (prev[2] + cur[2]) @ Ori + noise**2 * float(c @ c) * np.eye(3)
    S = H @ bias_covariance @ H.T + Rn
    return r, H, Rn, 0.5 * (S + S.T)


class GyroBiasEstimator:
    """A Kalman filter on one gyro's bias, measured by the rotation between consecutive
    solved frames (see the module docstring).

    Args:
        bias: (3,) the initial bias (rad/s, IMU frame).
        sigma: its standard deviation per axis (rad/s), >= 0 (0: known exactly; the random
            walk still lets it drift).
        R_cam_imu: (3, 3) rotation IMU -> camera optical frame.
        noise: standard deviation of one gyro sample (rad/s), > 0.
        time_offset: s added to the IMU stamps to put them on the camera clock.
        options: :class:`GyroBiasOptions`.

    Attributes:
        bias: (3,) the current estimate (rad/s, IMU frame).
        covariance: (3, 3) its covariance (rad^2/s^2, IMU frame).
        counts: how many frames had each outcome of :data:`BIAS_UPDATE_OUTCOMES`.
        last_nis: the normalized innovation squared of the last pair tested (NaN before).

    Raises:
        ValueError: shapes, non-finite values, ``sigma < 0`` or ``noise <= 0``.

    Not thread-safe: one thread updates it (the node's worker), others may read ``bias`` and
    ``covariance`` (replaced, never changed in place).
    """

    def __init__(
        self,
        bias: ArrayLike,
        sigma: float,
        R_cam_imu: ArrayLike,
        noise: float,
        time_offset: float = 0.0,
        options: GyroBiasOptions | None = None,
    ):
        b = np.asarray(bias, dtype=float).reshape(-1)
        if b.shape != (3,) or not np.isfinite(b).all():
            raise ValueError(f"bias must be 3 finite numbers (rad/s), got {b.tolist()}")
        if not (np.isfinite(sigma) and sigma >= 0):
            raise ValueError(f"need sigma >= 0, got {sigma}")
        self.R_cam_imu, self.noise, self.time_offset = checked_mount(R_cam_imu, noise, time_offset)
        self.options = options or GyroBiasOptions()
        self.bias = b.copy()
        self.covariance = float(sigma) ** 2 * np.eye(3)
        self.counts = {k: 0 for k in BIAS_UPDATE_OUTCOMES}
        self.last_nis = float("nan")
        self._prev: tuple[int, np.ndarray, np.ndarray] | None = None
        self._stamp: int | None = None  # of the last bias propagation

    @property
    def std(self) -> np.ndarray:
        """(3,) standard deviation of the estimate per IMU axis (rad/s)."""
        return np.sqrt(np.diag(self.covariance))

    def restart(self) -> None:
        """Forget the previous frame: the next frame starts a new pair (a tracker reset, a
        failed frame). The bias estimate is kept."""
        self._prev = None

    def measurement(
        self, buffer: ImuBuffer, window_ns: tuple[int, int], bias_sigma: float = 0.0
    ) -> tuple[GyroMeasurement | None, str]:
        """A readout's gyro measurement with the current bias estimate and its covariance
        (:meth:`~rs_localizer.tracking.gyro.ImuBuffer.measurement`; ``bias_sigma`` rad/s is
        added per axis). ``window_ns``: the readout's first and last line (camera clock, ns).
        Returns ``(measurement, "")`` or ``(None, reason)``."""
        return buffer.measurement(
            window_ns,
            self.R_cam_imu,
            self.bias,
            self.noise,
            bias_sigma,
            self.time_offset,
            self.covariance,
        )

    def update(
        self,
        stamp_ns: int,
        orientation: ArrayLike,
        rotation_covariance: ArrayLike,
        buffer: ImuBuffer,
    ) -> str:
        """Add a solved frame: with the previous one it measures the bias.

        Args:
            stamp_ns: the capture time of the frame's reference line (ns, camera clock: the
                time of ``orientation``).
            orientation: (3, 3) camera -> world at that time.
            rotation_covariance: (3, 3) covariance of the orientation (rad^2, world axes;
                ``RSPoseEstimate.covariance[:3, :3]``).
            buffer: the IMU's samples (:class:`~rs_localizer.tracking.gyro.ImuBuffer`).
        Returns:
            the outcome, one of :data:`BIAS_UPDATE_OUTCOMES` (also counted in ``counts``).
        """
        stamp_ns = int(stamp_ns)
        Ori = np.asarray(orientation, dtype=float).reshape(3, 3)
        P = np.asarray(rotation_covariance, dtype=float).reshape(3, 3)
        if not (np.isfinite(Ori).all() and np.isfinite(P).all()):
            self._prev = None
            return self._count("bad_pose")
        prev, self._prev = self._prev, (stamp_ns, Ori, 0.5 * (P + P.T))
        if prev is None:
            return self._count("first")
        dt = (stamp_ns - prev[0]) * 1e-9
        if not (self.options.min_interval <= dt <= self.options.max_interval):
            return self._count("gap")
        self._propagate(stamp_ns)
        inn = pair_innovation(
            prev,
            self._prev,
            buffer,
            self.R_cam_imu,
            self.bias,
            self.covariance,
            self.noise,
            self.time_offset,
        )
        if isinstance(inn, str):
            return self._count(inn)
        r, H, Rn, S = inn
        Pb = self.covariance
        try:
            Si = np.linalg.inv(S)
        except np.linalg.LinAlgError:
            return self._count("bad_pose")
        nis = float(r @ Si @ r)
        self.last_nis = nis
        if not np.isfinite(nis) or nis > self.options.chi2_threshold:
            return self._count("rejected")
        K = Pb @ H.T @ Si
        IKH = np.eye(3) - K @ H
        Pn = IKH @ Pb @ IKH.T + K @ Rn @ K.T  # (Joseph form)
        self.bias = self.bias + K @ r
        self.covariance = 0.5 * (Pn + Pn.T)
        return self._count("used")

    def _propagate(self, stamp_ns: int) -> None:
        """Grow the covariance by the random walk since the last propagation."""
        if self._stamp is not None and stamp_ns > self._stamp:
            q = self.options.random_walk**2 * (stamp_ns - self._stamp) * 1e-9
            self.covariance = self.covariance + q * np.eye(3)
        if self._stamp is None or stamp_ns > self._stamp:
            self._stamp = stamp_ns

    def _count(self, outcome: str) -> str:
        self.counts[outcome] += 1
        return outcome
