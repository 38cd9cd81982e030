"""A gyro's angular velocity as a measurement in the per-frame estimator.

The RS model of one frame moves with constant angular velocity ``omega`` during the readout
(paper eq. 2-4; docs/architecture.md "Conventions"). On planar scenes one frame barely
separates ``omega`` from the rotation; a gyro rigidly mounted on the camera measures it
directly. A :class:`GyroMeasurement` is the mean angular velocity over one readout in the
camera optical frame with its covariance (made from a video's gyro samples by
:func:`rs_localizer.tracking.gyro.gyro_measurement`); :func:`gyro_prior` combines it with the
estimator's motion prior (information form), and ``estimate_rs_pose(..., gyro=...)`` solves
RANSAC's samples with the measured angular velocity
(:func:`~rs_localizer.solvers.r5p_w.r5p_w_batch`, 5 points) and uses the prior in local
optimization and the final refinement (maximum a posteriori) and, on planar frames, in the
damped hypothesis solves. :func:`gyro_consistency` and :func:`gyro_image_chi2` test whether
the image agreed with the gyro.

Conventions: IMU samples are in the IMU frame; ``R_cam_imu`` rotates IMU axes into the camera
optical frame (``omega_cam = R_cam_imu (omega_imu - bias)``); ``time_offset`` is added to IMU
stamps to put them on the camera clock (``t_cam = t_imu + time_offset``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, TypeVar

import numpy as np
from numpy.typing import ArrayLike

from .._jit import kernel
from .prior import MotionPrior, checked_symmetric, prior_arrays

__all__ = [
    "GYRO_CHI2_THRESHOLD",
    "GYRO_IMAGE_SCALE",
    "GYRO_INLIER_MARGIN",
    "GYRO_PLANAR_IMAGE_SCALE",
    "GYRO_PLANAR_RATE_CHANGE_FACTOR",
    "GYRO_RATE_CHANGE_FACTOR",
    "GYRO_RECHECK_FRACTION",
    "GyroMeasurement",
    "gyro_checked",
    "gyro_consistency",
    "gyro_image_chi2",
    "gyro_prior",
]


#: chi-square (3 dof) above which the image disagrees with the gyro: P(chi2_3 > 16.27) = 0.001
GYRO_CHI2_THRESHOLD = 16.27
#: :func:`gyro_image_chi2`: the image's covariance is scaled by this ...
GYRO_IMAGE_SCALE = 1.0
#: ... and the gyro's rate change over the readout times this is added as a standard deviation
GYRO_RATE_CHANGE_FACTOR = 0.1
#: the same two on planar frames (one plane separates the angular velocity from the rotation
#: weakly: a rate change within the readout moves the image's estimate further)
GYRO_PLANAR_IMAGE_SCALE = 2.0
GYRO_PLANAR_RATE_CHANGE_FACTOR = 0.2
#: a gyro-aided estimate explaining fewer than ``1 - GYRO_INLIER_MARGIN`` of the inliers of
#: the image alone (unaided RANSAC) is not used: the gyro led RANSAC to a wrong consensus
GYRO_INLIER_MARGIN = 0.1
#: the unaided estimate is run to compare inlier counts when the aided one explains fewer
#: than this fraction of the valid points (or the image-alone refinement explains more)
GYRO_RECHECK_FRACTION = 0.5


@dataclass(frozen=True)
class GyroMeasurement:
    """The camera's mean angular velocity during one frame's readout, measured by a gyro.

    Attributes:
        angular_velocity: (3,) rad/s, camera optical frame.
        covariance: (3, 3) rad^2/s^2, symmetric positive definite (noise of the averaged
            samples plus the uncertainty of the gyro bias).
        rate_change: (3,) rad/s, camera optical frame: how much the rate changed over the
            readout (the samples' least-squares slope times the readout time; zero when
            unknown). A rolling-shutter model turns at one rate per frame: the change is what
            it cannot represent, and :func:`gyro_image_chi2` allows for it.

    Raises ``ValueError`` (on construction) for non-finite values, wrong shapes or a
    covariance that is not symmetric positive definite.
    """

    angular_velocity: np.ndarray
    covariance: np.ndarray
    rate_change: np.ndarray | None = None

    def __post_init__(self) -> None:
        w = np.asarray(self.angular_velocity, dtype=float).reshape(-1)
        if w.shape != (3,) or not np.isfinite(w).all():
            raise ValueError(f"gyro angular_velocity must be 3 finite numbers, got {w!r}")
        S = checked_symmetric(self.covariance, 3, "gyro covariance", atol=1e-15)
        d = np.zeros(3) if self.rate_change is None else np.asarray(self.rate_change, float)
        if d.shape != (3,) or not np.isfinite(d).all():
            raise ValueError(f"gyro rate_change must be 3 finite numbers, got {d!r}")
        object.__setattr__(self, "angular_velocity", w)
        object.__setattr__(self, "covariance", 0.5 * (S + S.T))
        object.__setattr__(self, "rate_change", d)

    def rotated(self, R: np.ndarray) -> GyroMeasurement:
        """The same measurement in another frame: ``R`` (3, 3) turns this one's frame's
        vectors into that frame's (e.g. ``R_cam_imu``, or a camera's mounting ``R`` for a
        gyro on the rig): the rate and its change turned, the covariance ``R S R^T``."""
        R = np.asarray(R, dtype=float).reshape(3, 3)
        return GyroMeasurement(
            R @ self.angular_velocity, R @ self.covariance @ R.T, R @ self.rate_change
        )


_Estimate = TypeVar("_Estimate")


def gyro_checked(
    aided: _Estimate,
    gyro: GyroMeasurement,
    image: Any,
    planar: Callable[[], bool],
    num_valid: int,
    unaided: Callable[[], _Estimate],
    compiled: bool = True,
) -> _Estimate:
    """The gyro-aided estimate, or the image's own when the gyro is not to be trusted: the
    rule of the camera's and the rig's estimator alike.

    ``aided`` (a successful one) is kept when the image agrees with the gyro (``chi2``, from
    :func:`gyro_image_chi2` of what the image alone says near it, within
    :data:`GYRO_CHI2_THRESHOLD`) and it explains at least :data:`GYRO_RECHECK_FRACTION` of the
    ``num_valid`` points and within :data:`GYRO_INLIER_MARGIN` as many as the image-alone
    refinement; otherwise the unaided estimate (``unaided()``, run at most once) is run, and
    ``aided`` is still kept unless the unaided one succeeds with more than ``1 / (1 -
    margin)`` times its inliers. A rejected gyro gives the unaided estimate with
    ``gyro_rejected`` and ``gyro_rejection`` (``contradicted``, ``fewer_inliers`` or
    ``aided_failed``), unless both failed (then the unaided one as it is). The estimate
    returned records ``chi2`` (``gyro_chi2``) where ``aided`` succeeded.

    Args:
        aided: the gyro-aided estimate (``success``, ``num_inliers``).
        gyro: the measurement, in the frame of the estimate's angular velocity.
        image: what the image alone says near ``aided`` (``angular_velocity`` (3,) rad/s,
            ``covariance`` (3, 3), ``num_inliers``: :class:`~.finalize.ImageAlone`), or None
            (no rate: ``chi2`` is ``inf``).
        planar: ``planar()``: the aided estimate's inliers are coplanar (asked only with
            ``image``; :func:`gyro_image_chi2`).
        num_valid: the points the estimate could use.
        unaided: runs the estimator without the gyro.
        compiled: False: the chi-square in NumPy.
    """
    chi2, image_inliers = np.inf, 0
    if aided.success and image is not None:
        chi2 = gyro_image_chi2(
            gyro, image.angular_velocity, image.covariance, planar(), compiled
        )  # fmt: skip
        image_inliers = image.num_inliers
    done = None
    why = "aided_failed"
    if aided.success:
        if not chi2 <= GYRO_CHI2_THRESHOLD:
            why = "contradicted"
        elif aided.num_inliers >= GYRO_RECHECK_FRACTION * num_valid and image_inliers <= (
            aided.num_inliers * (1.0 + GYRO_INLIER_MARGIN)
        ):
            return replace(aided, gyro_chi2=float(chi2))
        else:
            done = unaided()
            if not (
                done.success and aided.num_inliers < (1.0 - GYRO_INLIER_MARGIN) * done.num_inliers
            ):
                return replace(aided, gyro_chi2=float(chi2))
            why = "fewer_inliers"
    if done is None:
        done = unaided()
    if aided.success or done.success:
        chi2 = float(chi2) if aided.success else float("nan")
        return replace(done, gyro_rejected=True, gyro_rejection=why, gyro_chi2=chi2)
    return done


def gyro_prior(
    gyro: GyroMeasurement, base: MotionPrior | None = None, compiled: bool = True
) -> MotionPrior:
    """The estimator's motion prior with a gyro measurement added (information form).

    ``Lambda = Lambda_base + Lambda_gyro`` (the gyro's information on the angular velocity
    block of the ROS twist order ``(v, omega)``), ``mean = Lambda^+ (Lambda_base m_base +
    Lambda_gyro omega_gyro)``; ``always`` is set (a measurement is used on every frame).

    Args:
        gyro: the frame's :class:`GyroMeasurement` (camera optical frame).
        base: the motion prior without the gyro (``None``: none, the linear velocity is then
            unconstrained).
        compiled: False: the arithmetic in NumPy (the estimator's NumPy implementation:
            nothing compiles).
    Returns:
        :class:`~rs_localizer.estimation.prior.MotionPrior` with ``information_matrix``.
    """
    on, mb, Lb = prior_arrays(base)
    combined = _combined if compiled else _combined.py_func
    mean, L = combined(gyro.covariance, gyro.angular_velocity, on, mb, Lb)
    return MotionPrior._from_information(mean, L, True)


@kernel
def _combined(Sg, w, on, mb, Lb):
    """:func:`gyro_prior`'s arithmetic in one compiled call (NumPy's small-matrix calls cost
    ~100 us per frame there): ``(mean (6,), L (6, 6))``; the mean is the least-squares
    solution (minimum norm: zero for a component neither prior constrains)."""
    Lg = np.linalg.inv(Sg)
    L = Lb.copy()
    L[3:, 3:] += Lg
    L = 0.5 * (L + L.T)
    if not on:
        mean = np.zeros(6)
        mean[3:] = w
        return mean, L
    rhs = Lb @ mb
    rhs[3:] += Lg @ w
    return np.linalg.lstsq(L, rhs)[0], L


def gyro_consistency(
    gyro: GyroMeasurement, angular_velocity: ArrayLike, posterior_covariance: ArrayLike
) -> float:
    """Chi-square (3 dof) of the gyro against a gyro-aided (MAP) estimate.

    In a linear-Gaussian model the residual ``r = omega_MAP - omega_gyro`` of a measurement
    used in the fit has covariance ``S_gyro - S_post`` (``S_post`` the estimate's posterior
    covariance of the angular velocity): ``r^T (S_gyro - S_post)^-1 r``, with the difference
    floored at 1 % of ``S_gyro`` (where the image adds almost nothing, planar frames, the
    residual is near zero anyway). Above :data:`GYRO_CHI2_THRESHOLD` the image disagrees with
    the gyro (a wrong camera-IMU rotation, time offset or bias).

    Args:
        gyro: the measurement used. angular_velocity: (3,) the estimate's (rad/s, camera
            frame). posterior_covariance: (3, 3) its covariance (rad^2/s^2).
    Returns:
        the chi-square value (``inf`` for non-finite input).
    """
    w = np.asarray(angular_velocity, dtype=np.float64).reshape(3)
    P = np.asarray(posterior_covariance, dtype=np.float64).reshape(3, 3)
    return float(_floored_chi2(w, gyro.angular_velocity, gyro.covariance, P))


@kernel
def _floored_chi2(w, wg, Sg, P):
    """:func:`gyro_consistency`'s chi-square in one compiled call (NumPy's 3x3 calls cost
    ~40 us per frame there): floor the eigenvalues of ``D = S_gyro - P`` relative to
    ``S_gyro`` (whiten by S_gyro's Cholesky factor, clip at 0.01, unwhiten); ``inf`` for
    non-finite input."""
    r = w - wg
    if not (np.isfinite(r).all() and np.isfinite(P).all()):
        return np.inf
    D = Sg - 0.5 * (P + P.T)
    Li = np.linalg.inv(np.linalg.cholesky(Sg))
    ev, V = np.linalg.eigh(Li @ D @ Li.T)
    y = V.T @ (Li @ r)
    chi2 = 0.0
    for a in range(3):
        chi2 += y[a] * y[a] / max(ev[a], 0.01)
    return chi2


def gyro_image_chi2(
    gyro: GyroMeasurement,
    angular_velocity: ArrayLike,
    image_covariance: ArrayLike,
    planar: bool = False,
    compiled: bool = True,
) -> float:
    """Chi-square (3 dof) of the gyro against the angular velocity the image alone gives.

    ``r = omega_image - omega_gyro`` with covariance ``S_gyro + S_image + Q``: the two are
    independent measurements of the readout's rate (``S_image`` from the data alone, no
    prior: :func:`~rs_localizer.estimation.finalize.image_alone`), and ``Q = (k |d|)^2 I``
    (``d`` the gyro's :attr:`~GyroMeasurement.rate_change` over the readout, ``k`` =
    :data:`GYRO_RATE_CHANGE_FACTOR`) allows for what a one-rate model cannot fit when the rate
    changes within the readout, with ``S_image`` scaled by :data:`GYRO_IMAGE_SCALE` (on planar
    frames :data:`GYRO_PLANAR_RATE_CHANGE_FACTOR` and :data:`GYRO_PLANAR_IMAGE_SCALE`). The
    constants are calibrated so that a right gyro exceeds :data:`GYRO_CHI2_THRESHOLD` with at
    most the stated probability (hand-held videos and single frames, 3D and planar:
    ``python -m benchmarks.bench_gyro --false-alarms``).

    Args:
        gyro: the measurement. angular_velocity: (3,) the image's (rad/s, camera frame).
        image_covariance: (3, 3) its covariance from the data alone (rad^2/s^2).
        planar: the frame's points are (nearly) coplanar.
        compiled: False: the arithmetic in NumPy (nothing compiles).
    Returns:
        the chi-square value (``inf`` for non-finite input or a singular covariance).
    """
    w = np.asarray(angular_velocity, dtype=np.float64).reshape(3)
    P = np.asarray(image_covariance, dtype=np.float64).reshape(3, 3)
    return float(
        (_image_chi2 if compiled else _image_chi2.py_func)(
            w - gyro.angular_velocity,
            gyro.covariance,
            P,
            GYRO_PLANAR_IMAGE_SCALE if planar else GYRO_IMAGE_SCALE,
            (GYRO_PLANAR_RATE_CHANGE_FACTOR if planar else GYRO_RATE_CHANGE_FACTOR) ** 2
            * float(gyro.rate_change @ gyro.rate_change),
        )
    )


@kernel
def _image_chi2(r, Sg, P, scale, q):
    """:func:`gyro_image_chi2`'s arithmetic in one compiled call (NumPy's 3x3 calls cost
    ~100 us per frame): ``r^T (Sg + scale P + q I)^-1 r`` by Cholesky; ``inf`` for
    non-finite input or a covariance that is not positive definite."""
    if not (np.isfinite(r).all() and np.isfinite(P).all()):
        return np.inf
    S = Sg + 0.5 * scale * (P + P.T)
    for a in range(3):
        S[a, a] += q
    # (3x3 Cholesky by hand: numba's raises on a non-positive-definite matrix)
    L = np.zeros((3, 3))
    for i in range(3):
        for j in range(i + 1):
            v = S[i, j]
            for k in range(j):
                v -= L[i, k] * L[j, k]
            if i == j:
                if not v > 0.0:
                    return np.inf
                L[i, i] = np.sqrt(v)
            else:
                L[i, j] = v / L[j, j]
    y = np.zeros(3)
    chi2 = 0.0
    for i in range(3):
        v = r[i]
        for k in range(i):
            v -= L[i, k] * y[k]
        y[i] = v / L[i, i]
        chi2 += y[i] * y[i]
    return chi2
