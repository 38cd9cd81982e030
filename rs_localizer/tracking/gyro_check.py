"""Whether a gyro agrees with the image over a video: a wrong camera-IMU mount or time offset.

Per frame, :func:`~rs_localizer.estimation.gyro.gyro_consistency` tests the gyro against the
image's angular velocity; on planar scenes one frame barely determines the angular velocity, so
a gyro mounted 90 deg off passes it and pulls every frame's estimate. The rotation between two
solved frames is well determined even there: :class:`GyroMountCheck` compares it with the
gyro's rotation integrated over the same interval (the measurement of
:class:`~rs_localizer.tracking.gyro_bias.GyroBiasEstimator`, :func:`~rs_localizer.estimation.
gyro_bias.pair_innovation`) and keeps the outcome of the last ``window`` pairs:

* a pair **fails** when its normalized innovation squared exceeds the chi-square threshold
  (3 dof, P = 0.001) *and* the residual rotation exceeds ``min_residual_deg``: the poses'
  rotation covariance is too small under strong accelerations (the pairs' mean normalized
  innovation squared is 3.7-6.3 on the hand-held videos, 3 expected), so the chi-square test
  alone would flag a correct mount now and then;
* a pair that passes while the gyro turned less than ``min_rotation_deg`` says nothing about
  the mount (a mount error only shows in proportion to the rotation) and is not counted;
* ``failures`` failed pairs among the last ``window`` counted ones, *and* a mount error that
  explains them, declare the gyro **inconsistent** with the image. The mount error is the
  rotation ``Q`` that best maps the gyro's rotations onto the image's over the window
  (``log(O_prev^T O) ~ Q phi_gyro``, both in the camera frame; the weighted least-squares
  rotation of SciPy's ``Rotation.align_vectors``, Kabsch's fit without a centroid, repeated with
  Huber weights): it must exceed ``min_mount_error_deg`` and halve the pairs' median residual.
  Poses that are wrong now and then (a planar pose ambiguity, a tracker glitch: the image is
  wrong, not the gyro) fail pairs in every direction, which no rotation of the mount explains; a
  wrong mount (an axis swapped, a sign) fails them all the same way. A time offset error is not
  a rotation either: on a 3D scene the per-frame test rejects the frames it spoils, on a planar
  one it is mostly left in (a window of poorly posed frames can happen to fit a rotation: in the
  measurements below, on two of three videos of the wall, after 3.8 and 5.5 s). While the gyro
  is inconsistent, the frames are solved without it (the caller's decision; the node counts them
  in ``gyro_disabled_inconsistent``), and pairs are still tested with the gyro's own rotation,
  so that the gyro is **consistent** again once at most ``recover_failures`` of the last
  ``window`` pairs fail (the data became consistent, e.g. a corrected ``imu.rotation``).

A wrong mount by an angle ``a`` leaves a residual of about ``2 sin(a / 2) |omega| dt`` per pair
(2.7 deg at 1 rad/s over 33 ms for 90 deg); a time offset error ``d`` one of about ``d
|omega(t1) - omega(t0)|`` (up to 0.8 deg on a hand-held shake for 10 ms). The numbers (frames
until detection, false alarms with the right mount, errors against no gyro) are in
docs/node.md "Gyro", from ``python -m benchmarks.bench_gyro --video --mount``.

Conventions as :mod:`rs_localizer.estimation.gyro`.
"""

from __future__ import annotations

import warnings
from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from ..estimation.gyro import GYRO_CHI2_THRESHOLD
from ..geometry import matrix_to_rotvec, rotvec_to_matrix
from .gyro import ImuBuffer
from .gyro_bias import checked_mount, pair_innovation

__all__ = ["MOUNT_CHECK_OUTCOMES", "GyroMountCheck", "MountCheckOptions"]

#: what :meth:`GyroMountCheck.update` did with a frame: ``passed`` and ``failed`` (the pair's
#: test), ``uninformative`` (passed while the gyro barely turned: not counted), ``first`` (the
#: frame starts a pair), ``gap`` (too long since the previous frame), ``no_gyro`` (no samples
#: cover the interval), ``bad_pose`` (a non-finite pose or covariance)
MOUNT_CHECK_OUTCOMES = ("passed", "failed", "uninformative", "first", "gap", "no_gyro", "bad_pose")


@dataclass(frozen=True)
class MountCheckOptions:
    """Parameters of :class:`GyroMountCheck` (see the module docstring).

    Attributes:
        window: pairs (counted ones) the decision looks at, >= 1.
        failures: failed pairs among the last ``window`` that declare the gyro inconsistent,
            1 <= failures <= window.
        recover_failures: at most this many failed pairs among the last ``window`` make an
            inconsistent gyro consistent again, 0 <= recover_failures < failures.
        chi2_threshold: normalized innovation squared (3 dof) above which a pair can fail.
        min_residual_deg: deg; a pair fails only with a residual rotation above this.
        min_rotation_deg: deg; a pair that passes while the gyro turned less is not counted.
        min_mount_error_deg: deg; a mount error below this does not declare the gyro
            inconsistent (a small one hardly shows against the pose noise).
        max_interval, min_interval: s; frames further apart (closer) do not form a pair.
    """

    window: int = 10
    failures: int = 6
    recover_failures: int = 1
    chi2_threshold: float = GYRO_CHI2_THRESHOLD
    min_residual_deg: float = 0.5
    min_rotation_deg: float = 0.5
    min_mount_error_deg: float = 20.0
    max_interval: float = 0.5
    min_interval: float = 1e-3

    def __post_init__(self):
        if not (self.window >= 1 and 1 <= self.failures <= self.window):
            raise ValueError(f"need 1 <= failures <= window, got {self.failures}, {self.window}")
        if not 0 <= self.recover_failures < self.failures:
            raise ValueError(
                f"need 0 <= recover_failures < failures, got {self.recover_failures}, "
                f"{self.failures}"
            )
        for name in ("chi2_threshold", "max_interval"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be > 0, got {v}")
        for name in ("min_residual_deg", "min_rotation_deg", "min_interval", "min_mount_error_deg"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be >= 0, got {v}")
        if not self.min_interval < self.max_interval:
            raise ValueError("min_interval must be < max_interval")


class GyroMountCheck:
    """Tests consecutive solved frames against the gyro and decides whether the gyro agrees
    with the image (see the module docstring).

    Args:
        R_cam_imu: (3, 3) rotation IMU -> camera optical frame (the mount under test).
        noise: standard deviation of one gyro sample (rad/s), > 0.
        time_offset: s added to the IMU stamps to put them on the camera clock.
        options: :class:`MountCheckOptions`.

    Attributes:
        inconsistent: True while the gyro is declared inconsistent with the image.
        counts: frames per outcome of :data:`MOUNT_CHECK_OUTCOMES`.
        detections: how many times the gyro was declared inconsistent.
        last_residual_deg, last_nis: the last tested pair's residual rotation (deg) and
            normalized innovation squared (NaN before).
        mount_error: (3, 3) ``Q`` of the last decision (the rotation that maps the gyro's
            rotations onto the image's; ``Q R_cam_imu`` is the mount the window suggests), or
            ``None``.

    Raises:
        ValueError: a ``R_cam_imu`` that is not a rotation, ``noise <= 0``, a non-finite
            ``time_offset``.

    Not thread-safe: one thread updates it (the node's worker); others may read
    ``inconsistent``.
    """

    def __init__(
        self,
        R_cam_imu: ArrayLike,
        noise: float,
        time_offset: float = 0.0,
        options: MountCheckOptions | None = None,
    ):
        self.R_cam_imu, self.noise, self.time_offset = checked_mount(R_cam_imu, noise, time_offset)
        self.options = options or MountCheckOptions()
        self.inconsistent = False
        self.detections = 0
        self.counts = {k: 0 for k in MOUNT_CHECK_OUTCOMES}
        self.last_residual_deg = self.last_nis = float("nan")
        self._window: deque[tuple[bool, np.ndarray, np.ndarray]] = deque(maxlen=self.options.window)
        self.mount_error: np.ndarray | None = None
        self._prev: tuple[int, np.ndarray, np.ndarray] | None = None

    @property
    def window_failures(self) -> tuple[int, int]:
        """``(failed, counted)``: failed pairs among the counted pairs of the window."""
        return int(sum(w[0] for w in self._window)), len(self._window)

    @property
    def mount_error_deg(self) -> float:
        """The angle of :attr:`mount_error` (deg; NaN before a decision)."""
        if self.mount_error is None:
            return float("nan")
        return float(np.rad2deg(np.linalg.norm(matrix_to_rotvec(self.mount_error))))

    def _explained_by_mount(self) -> bool:
        """Whether a rotation of the mount explains the window's pairs (module docstring);
        sets :attr:`mount_error`."""
        phi = np.array([w[1] for w in self._window])  # the gyro's rotations (camera frame)
        psi = np.array([w[2] for w in self._window])  # the image's
        wts = np.ones(len(phi))
        with warnings.catch_warnings():  # (rotations about one axis: every Q turning the
            # gyro's axis onto the image's fits them, and the test below needs one of them)
            warnings.filterwarnings("ignore", "Optimal rotation is not uniquely", UserWarning)
            for _ in range(5):  # Huber weights: Q minimizes sum wts |psi - Q phi|^2
                Q = Rotation.align_vectors(psi, phi, weights=wts)[0].as_matrix()
                rn = np.linalg.norm(psi - phi @ Q.T, axis=1)
                k = 1.5 * np.median(rn) + 1e-12
                wts = np.where(rn <= k, 1.0, k / np.maximum(rn, 1e-300))
        self.mount_error = Q
        before = np.median(np.linalg.norm(psi - phi, axis=1))
        after = np.median(np.linalg.norm(psi - phi @ Q.T, axis=1))
        return self.mount_error_deg > self.options.min_mount_error_deg and after < 0.5 * before

    def restart(self) -> None:
        """Forget the previous frame (a failed frame, a track reset): the next frame starts a
        new pair. The window and the decision are kept."""
        self._prev = None

    def update(
        self,
        stamp_ns: int,
        orientation: ArrayLike,
        rotation_covariance: ArrayLike,
        buffer: ImuBuffer,
        bias: ArrayLike,
        bias_covariance: ArrayLike,
    ) -> str:
        """Add a solved frame; with the previous one it forms a pair that is tested.

        Args:
            stamp_ns: capture time of the frame's reference line (ns, camera clock).
            orientation: (3, 3) camera -> world at that time.
            rotation_covariance: (3, 3) its covariance (rad^2, world axes).
            buffer: the IMU's samples.
            bias: (3,) the gyro bias subtracted (rad/s, IMU frame).
            bias_covariance: (3, 3) its covariance (rad^2/s^2, IMU frame).
        Returns:
            the outcome, one of :data:`MOUNT_CHECK_OUTCOMES`; :attr:`inconsistent` is updated.
        """
        Ori = np.asarray(orientation, dtype=float).reshape(3, 3)
        P = np.asarray(rotation_covariance, dtype=float).reshape(3, 3)
        if not (np.isfinite(Ori).all() and np.isfinite(P).all()):
            self._prev = None
            return self._count("bad_pose")
        prev, self._prev = self._prev, (int(stamp_ns), Ori, 0.5 * (P + P.T))
        if prev is None:
            return self._count("first")
        dt = (self._prev[0] - prev[0]) * 1e-9
        if not (self.options.min_interval <= dt <= self.options.max_interval):
            return self._count("gap")
        b = np.asarray(bias, dtype=float).reshape(3)
        Pb = np.asarray(bias_covariance, dtype=float).reshape(3, 3)
        inn = pair_innovation(
            prev, self._prev, buffer, self.R_cam_imu, b, Pb, self.noise, self.time_offset
        )
        if isinstance(inn, str):
            return self._count(inn)
        r, _, _, S = inn
        Psi = prev[1].T @ Ori  # the image's rotation between the frames (earlier frame)
        psi = matrix_to_rotvec(Psi)
        phi = matrix_to_rotvec(Psi @ rotvec_to_matrix(r).T)  # the gyro's (camera frame)
        try:
            nis = float(r @ np.linalg.solve(S, r))
        except np.linalg.LinAlgError:
            return self._count("bad_pose")
        res = float(np.rad2deg(np.linalg.norm(r)))
        self.last_nis, self.last_residual_deg = nis, res
        o = self.options
        failed = (not np.isfinite(nis) or nis > o.chi2_threshold) and res > o.min_residual_deg
        if not failed and np.rad2deg(np.linalg.norm(phi)) < o.min_rotation_deg:
            return self._count("uninformative")
        self._window.append((failed, phi, psi))
        n_failed = self.window_failures[0]
        if not self.inconsistent and n_failed >= o.failures and self._explained_by_mount():
            self.inconsistent = True
            self.detections += 1
        elif self.inconsistent and len(self._window) == o.window and n_failed <= o.recover_failures:
            self.inconsistent = False
        return self._count("failed" if failed else "passed")

    def _count(self, outcome: str) -> str:
        self.counts[outcome] += 1
        return outcome
