"""A frame with too few points for the robust estimator but a few coplanar ones, above all the
four corners of one square marker (the most common AprilTag or ArUco scene), or a few on more
than one plane (the corners of two or three markers on different walls or faces): posed from
them alone (:func:`few_points_estimate`).

Points on more than one plane (at least :data:`MIN_SPREAD_POINTS`) have one pose: OpenCV's
SQPnP (``cv2.solvePnPGeneric`` with ``SOLVEPNP_SQPNP``, Terzakis and Lourakis 2020, the
global minimum of the algebraic error) starts the fit. A plane has two: OpenCV's IPPE
(``cv2.solvePnPGeneric`` with ``SOLVEPNP_IPPE``, Collins and Bartoli 2014) gives the two poses
a plane admits. Each start is refined on the exact model (paper eq. 4) with the velocities
held fixed: those of the tracker's prediction or the gyro where there is one, else zero (the
global-shutter model). A plane seen small and nearly frontally is ambiguous (the two poses
mirror each other about the line of sight and fit the corners equally well); the image
decides where the other pose fits clearly worse (:data:`AMBIGUITY_CHI2`), the prediction
where it is clearly nearer one of them (:data:`PREDICTION_RATIO`); otherwise the frame is
refused as ``ambiguous_tag``. The pose must pass the estimator's last checks
(:func:`~.finalize.final_estimate`: plausible motion, every point in front of the camera at
its capture time), and the points must fit it within the inlier threshold (their RMS error):
none is rejected, so a wrong match fails the frame.

The corners' errors (the fit, the ambiguity test, the inlier test, ``rmse_px``, the
covariance) are in pixels of the measured image, as the robust estimator's: each corner's
error in the undistorted plane whitened by the camera's pixel Jacobian there
(:attr:`~.frame.Frame.W`; a camera without distortion and with ``fx = fy`` has none and is
unchanged). Four corners leave 2 degrees of freedom to estimate their noise, so the ambiguity
test and the covariance do not go below :data:`MIN_CORNER_SIGMA_PX`, the AprilTag library's
corner noise measured on real tags.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import NamedTuple

import cv2
import numpy as np
from scipy.optimize import least_squares

from .._jit import kernel
from ..geometry import rotation_angle_deg, skew
from ..pose import RSModel
from .degeneracy import PLANAR_TOLERANCE, condition_number, coplanar, planarity
from .finalize import GLOBAL_SHUTTER, FinalModel, final_estimate
from .frame import Frame
from .noise_model import shared_shift_covariance
from .options import EstimateOptions, InitialModel
from .prior import MotionPrior
from .refine import (
    LM_REFINE_KERNEL,
    OUT_C,
    OUT_INFO,
    OUT_SIZE,
    exact_errors,
    exact_jacobian,
    exact_residuals,
    exact_rows,
)
from .result import (
    AMBIGUOUS_TAG,
    DEGENERATE_GEOMETRY,
    TOO_FEW_INLIERS,
    TOO_FEW_POINTS,
    EstimationFailed,
    RSPoseEstimate,
)

__all__ = [
    "AMBIGUITY_CHI2",
    "MIN_CORNER_SIGMA_PX",
    "MIN_PLANAR_POINTS",
    "MIN_SPREAD_POINTS",
    "PREDICTED_MOTION",
    "PREDICTION_RATIO",
    "SAME_POSE_DEG",
    "FewPointsModel",
    "coplanar_points",
    "few_points",
    "few_points_estimate",
    "few_points_model",
    "few_points_planarity",
    "planar_points",
    "posed_planarity",
]

#: fewest coplanar points the path poses (one square marker's four corners)
MIN_PLANAR_POINTS = 4
#: fewest points on more than one plane the path poses: the 6 pose parameters fitted to them
#: leave 2N - 6 = 6 residual degrees of freedom to judge the fit by (a marker's four corners,
#: whose square shape is known, leave 2); two markers' corners are 8
MIN_SPREAD_POINTS = 6
#: the image alone decides between the two IPPE poses when the other one's sum of squared
#: reprojection errors (after its own refinement) exceeds the better one's by at least this
#: many corner noise variances (the variance from the better fit's residuals, 2N - 6 degrees
#: of freedom, at least :data:`MIN_CORNER_SIGMA_PX` squared): a 3-sigma separation
AMBIGUITY_CHI2 = 9.0
#: a prediction decides when the rotation to one pose is at most this fraction of the
#: rotation to the other (the two poses of an ambiguous plane differ by a turn about an axis
#: in the plane: a prediction within a few degrees tells them apart)
PREDICTION_RATIO = 0.5
#: two refined poses whose rotations differ by less than this (degrees) are one pose (both IPPE
#: solutions of a plane seen off its axis often refine to the same minimum)
SAME_POSE_DEG = 0.05
#: the corner noise (px of the measured image) below which the ambiguity test and the covariance
#: do not go: 4 corners leave 2 degrees of freedom to estimate it from, and a fit that happens
#: to be near exact is not a sure pose. The AprilTag library's corner noise on real tags,
#: ``python -m benchmarks.bench_single_tag --corner-noise`` (each detection's 4 corners posed
#: alone, ``sqrt(median(SSE / 2) / ln 2)``, the median-based estimate of Gaussian noise from
#: 2-dof fits): 0.188 px on TagSLAM's test_22 (a T265 fisheye, 41 detections of a 30-37 px tag),
#: 0.105 px on its test_23 (a D435, 1896 detections of 49 mm tags); the larger (the fisheye's,
#: the harder case) rounded up: a floor below the real noise would let noise decide between
#: mirror poses, one above it refuses tags the image tells apart
MIN_CORNER_SIGMA_PX = 0.2
#: ``RSPoseEstimate.motion_model`` of a pose on the rolling-shutter model with the velocities
#: held at the prediction's or the gyro's (not estimated from the frame)
PREDICTED_MOTION = "predicted_motion"


def coplanar_points(points3d: np.ndarray) -> bool:
    """At least :data:`MIN_PLANAR_POINTS` of the (N, 3) world points (m), coplanar
    (:func:`~.degeneracy.planarity` below :data:`~.degeneracy.PLANAR_TOLERANCE`): what
    :func:`single_tag_estimate` poses when they are too few for the solver."""
    X = np.ascontiguousarray(points3d, dtype=np.float64).reshape(-1, 3)
    if len(X) < MIN_PLANAR_POINTS or not np.isfinite(X).all():
        return False
    return coplanar(X)


def planar_points(fr: Frame) -> bool:
    """The frame's valid points are one marker's or a plane's (:func:`coplanar_points`):
    :func:`few_points_estimate` poses them from IPPE's two poses."""
    return coplanar_points(fr.X)


def few_points(points3d: np.ndarray) -> bool:
    """The (N, 3) world points (m) are what :func:`few_points_estimate` poses when they are
    too few for the solver's robust estimate: :func:`coplanar_points`, or at least
    :data:`MIN_SPREAD_POINTS` finite ones."""
    X = np.ascontiguousarray(points3d, dtype=np.float64).reshape(-1, 3)
    return posed_planarity(X) is not None


def posed_planarity(X: np.ndarray) -> float | None:
    """:func:`~.degeneracy.planarity` of the (N, 3) world points ``X`` (m, float64,
    C-contiguous) when :func:`few_points_estimate` poses them (:func:`coplanar_points`, or at
    least :data:`MIN_SPREAD_POINTS` finite ones), else None: the one rule of
    :func:`few_points` and :func:`few_points_planarity`."""
    if len(X) < MIN_PLANAR_POINTS:
        return None
    flat = float(planarity(X))
    if flat != flat:  # (NaN: a point not finite)
        return None
    return _posed(flat, len(X))


def _posed(flat: float, n: int) -> float | None:
    """The planarity ``flat`` of ``n`` finite points when :func:`few_points_estimate` poses
    them (coplanar, or at least :data:`MIN_SPREAD_POINTS`), else None."""
    return flat if flat < PLANAR_TOLERANCE or n >= MIN_SPREAD_POINTS else None


def few_points_planarity(fr: Frame, min_inliers: int) -> float | None:
    """:func:`~.degeneracy.planarity` of the frame's points (one compiled call for the choice
    and the estimate) when :func:`few_points_estimate` poses the frame: fewer valid points
    than ``min_inliers`` (the solver's) and :func:`few_points`, or exactly
    :data:`MIN_PLANAR_POINTS` coplanar ones (one square marker's corners, whatever the
    solver); None otherwise."""
    n = len(fr.x)
    if not (n < min_inliers or n == MIN_PLANAR_POINTS):
        return None
    # (exactly four points and enough for the solver: posed only as one marker, coplanar)
    return posed_planarity(fr.X)


def _fixed_velocities(
    fr: Frame, initial_model: InitialModel | None, known_w: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, bool, RSModel | None, int]:
    """The velocities held in the fit, as ``(w, b)`` per unit r with the model's
    ``t = w x C + b`` (``b = -s v``: the camera's own linear velocity ``v`` held, whatever its
    fitted ``C``): the prediction's if it explains every point within its ``gate_px``, with
    the gyro's angular velocity instead of the prediction's when ``known_w`` is set, else
    zero; whether they are not both zero (the fit is on the rolling-shutter model); the
    prediction if it explains them (else ``None``), and how many points it explains (-1:
    none given)."""
    w, b = np.zeros(3), np.zeros(3)
    pred, explained, held = None, -1, False
    if initial_model is not None:
        m = initial_model.model
        e = exact_errors(
            *(np.ascontiguousarray(a, dtype=float) for a in m), fr.X, fr.x, fr.r - fr.r0, fr.W
        )
        explained = int(np.count_nonzero(e * fr.f <= initial_model.gate_px))
        if explained == len(fr.x):
            pred = m
            if fr.spr > 0:
                w = np.array(m.w, dtype=float)
                b = np.array(m.t, dtype=float) - np.cross(w, np.asarray(m.C, dtype=float))
                held = True
    if known_w is not None and fr.spr > 0:
        w, held = np.array(known_w, dtype=float), True
    return w, b, held and bool(w.any() or b.any()), pred, explained


def _starts(fr: Frame) -> tuple[np.ndarray, np.ndarray]:
    """The starting poses of the frame's points as OpenCV gives them: ``(rotation vectors
    (k, 3), translations (k, 3))`` (world -> camera, k <= 2, none when it fails), IPPE's two
    poses of coplanar points (:attr:`~.frame.Frame.planar`) or SQPnP's one of points on more
    than one plane (:func:`_opencv_starts`). IPPE poses the points projected onto their
    least-squares plane: OpenCV's IPPE returns no pose for points a millimetre off one plane
    (e.g. two tags on a real floor), which :func:`coplanar_points` accepts; the fit
    (:func:`_fit_starts`, :func:`_fit`) then starts from these poses on the points as given."""
    if fr.planar:
        X = np.ascontiguousarray(fr.X, dtype=np.float64)
        return _opencv_starts(_on_plane(X.tobytes()), fr.x, cv2.SOLVEPNP_IPPE)
    return _opencv_starts(fr.X, fr.x, cv2.SOLVEPNP_SQPNP)


@lru_cache(maxsize=256)
def _on_plane(points: bytes) -> np.ndarray:
    """(N, 3) the world points (float64 bytes, N x 3 row-major; m) projected onto their
    least-squares plane (read-only), for :func:`_starts`: kept for the next frames of the same
    marker, whose corners are the same points in the same order."""
    X = np.frombuffer(points, dtype=np.float64).reshape(-1, 3)
    centre = X.mean(axis=0)
    normal = np.linalg.svd(X - centre)[2][2]
    P = X - np.outer((X - centre) @ normal, normal)
    P.flags.writeable = False
    return P


#: the camera matrix of normalized image points (read only)
_IDENTITY = np.eye(3)
_IDENTITY.flags.writeable = False
#: no starting pose: ``(rotation vectors (0, 3), translations (0, 3))``
_NO_STARTS = (np.zeros((0, 3)), np.zeros((0, 3)))


def _opencv_starts(X: np.ndarray, x: np.ndarray, flag: int) -> tuple[np.ndarray, np.ndarray]:
    """The poses ``cv2.solvePnPGeneric`` gives with ``flag`` for the (N, 3) world points ``X``
    (m) and their (N, 2) normalized image points ``x``: ``(rotation vectors (k, 3),
    translations (k, 3))`` (world -> camera; none when it raises). Not checked for finite
    values (:func:`_fit_starts` and :func:`_rotation_of` skip those that are not)."""
    try:
        n, rvecs, tvecs, _ = cv2.solvePnPGeneric(
            np.ascontiguousarray(X, dtype=np.float64),
            np.ascontiguousarray(x, dtype=np.float64),
            _IDENTITY,
            None,
            flags=flag,
        )
    except cv2.error:
        return _NO_STARTS
    if n <= 0:
        return _NO_STARTS
    rv = np.array(rvecs[:n], dtype=np.float64).reshape(n, 3)
    return rv, np.array(tvecs[:n], dtype=np.float64).reshape(n, 3)


@kernel
def _rodrigues(r, R):
    """Write into ``R`` (3, 3) the rotation of the rotation vector ``r`` (3,) (rad) as OpenCV's
    ``cv2.Rodrigues`` computes it, the same operations in the same order (its values to the
    bit): ``cos(theta) I + (1 - cos(theta)) u u^T + sin(theta) [u]x``, ``u = r / theta``; the
    identity below ``theta`` = machine epsilon."""
    rx, ry, rz = r[0], r[1], r[2]
    theta = math.sqrt(rx * rx + ry * ry + rz * rz)
    if theta < 2.220446049250313e-16:  # (DBL_EPSILON)
        for i in range(3):
            for j in range(3):
                R[i, j] = 1.0 if i == j else 0.0
        return
    c, s = math.cos(theta), math.sin(theta)
    c1, itheta = 1.0 - c, 1.0 / theta
    rx, ry, rz = rx * itheta, ry * itheta, rz * itheta
    rrt = (rx * rx, rx * ry, rx * rz, rx * ry, ry * ry, ry * rz, rx * rz, ry * rz, rz * rz)
    r_x = (0.0, -rz, ry, rz, 0.0, -rx, -ry, rx, 0.0)
    for k in range(9):
        eye = 1.0 if k % 4 == 0 else 0.0
        R[k // 3, k % 3] = c * eye + c1 * rrt[k] + s * r_x[k]


def _rotation_of(rv: np.ndarray) -> np.ndarray | None:
    """(3, 3) the rotation of the rotation vector ``rv`` (3,) (:func:`_rodrigues`), None
    when it is not finite."""
    R = np.empty((3, 3))
    _rodrigues(np.ascontiguousarray(rv, dtype=np.float64), R)
    return R if np.isfinite(R).all() else None


#: the fit's loss: least squares (the compiled refinement's Huber loss at this scale, in
#: normalized units, weighs every point alike: errors of a few points are far below it)
_LEAST_SQUARES = 1e6
#: the fit's relative cost decrease at which the compiled refinement stops (SciPy's
#: ``ftol`` of the held-velocity fit)
_FIT_TOL = 1e-12
#: at most this many iterations of the compiled fit (SciPy's default for 6 parameters: 700)
_FIT_ITERATIONS = 200


@kernel
def _best_first(R, rms):
    """The order of m fits by their RMS errors ``rms`` (m,) (a stable sort: ties in their
    order), without the second when its rotation (``R`` (m, 3, 3)) is within
    :data:`SAME_POSE_DEG` of the first's (both IPPE poses refined to the same one: no
    ambiguity): (<= m,) int64 indices, best first."""
    m = rms.shape[0]
    order = np.arange(m)
    for a in range(1, m):
        b = a
        while b > 0 and rms[order[b]] < rms[order[b - 1]]:
            order[b - 1], order[b] = order[b], order[b - 1]
            b -= 1
    if m > 1:  # (the angle of R_a^T R_b, geometry.rotation_angle_deg)
        A, B = R[order[0]], R[order[1]]
        c = 0.0
        for i in range(3):
            c += A[0, i] * B[0, i] + A[1, i] * B[1, i] + A[2, i] * B[2, i]
        if math.degrees(math.acos(min(max((c - 1.0) / 2.0, -1.0), 1.0))) < SAME_POSE_DEG:
            return order[:1]
    return order


@kernel
def _fit_all(rv, tv, X, x, tau, W, views, R, C, H, sse):
    """:func:`_fit_starts` with the frame's kernel mountings ``views`` (None: the plain
    errors)."""
    k, n = rv.shape[0], X.shape[0]
    z = np.zeros(3)
    mu, lam = np.zeros(6), np.zeros((6, 6))
    out = np.empty(OUT_SIZE)
    R0 = np.empty((3, 3))
    index = np.empty(k, dtype=np.int64)
    rms = np.empty(k)
    m = 0
    for j in range(k):
        _rodrigues(rv[j], R0)
        C0 = tv[j].copy()
        if not (np.isfinite(R0).all() and np.isfinite(C0).all()):
            continue
        LM_REFINE_KERNEL(
            R0, C0, z, z, X, x, tau, _LEAST_SQUARES, 6, np.inf, _FIT_ITERATIONS, _FIT_TOL,
            True, out, False, mu, lam, 1.0, -1.0, False, views,
        )  # fmt: skip
        for a in range(3):
            C[j, a] = out[OUT_C + a]
            for b in range(3):
                R[j, a, b] = out[3 * a + b]
        for a in range(6):
            for b in range(6):
                H[j, a, b] = out[OUT_INFO + 12 * a + b]
        e = exact_errors(R[j], C[j], z, z, X, x, tau, W)
        sse[j] = np.dot(e, e)
        if np.isfinite(R[j]).all() and math.isfinite(sse[j]):
            index[m], rms[m] = j, math.sqrt(sse[j] / n)
            m += 1
    return index[:m][_best_first(R[index[:m]], rms[:m])]


@kernel
def _fit_starts(rv, tv, X, x, tau, W, R, C, H, sse):
    """The global-shutter fit of the frame's points (the velocities zero) from each of k
    starting poses, in one compiled call: start ``j`` (rotation vector ``rv[j]`` (3,) rad,
    :func:`_rodrigues`, translation ``tv[j]`` (3,) m, as OpenCV gives them) refined on the
    (N, 3) world points ``X``, (N, 2) normalized points ``x`` and (N,) times ``tau``, each
    point's error whitened by ``W`` (N, 4) (:attr:`~.frame.Frame.W`, the refinement's
    mountings as :meth:`~.frame.Frame.mountings` gives them; (0, 4): the plain
    errors), by the compiled refinement (:func:`~.refine.refine_rs_pose`'s kernel: the pose
    alone, least squares (:data:`_LEAST_SQUARES`), every point, at most
    :data:`_FIT_ITERATIONS` iterations to :data:`_FIT_TOL`). Writes its rotation into
    ``R[j]`` (3, 3), its translation into ``C[j]`` (3,), ``J^T J`` of the pose at the fit
    into ``H[j]`` (6, 6) and its sum of squared errors (normalized units) into ``sse[j]``.
    Starts that are not finite are skipped. Returns the indices of the finite fits in
    :func:`_best_first`'s order."""
    if W.shape[0] == 0:
        return _fit_all(rv, tv, X, x, tau, W, None, R, C, H, sse)
    n = X.shape[0]
    views = (np.zeros(n, dtype=np.int64), np.eye(3).reshape((1, 3, 3)), np.zeros((1, 3)), W)
    return _fit_all(rv, tv, X, x, tau, W, views, R, C, H, sse)


def _fits(fr: Frame, w: np.ndarray, b: np.ndarray, moving: bool) -> list[tuple]:
    """The fits of the frame's points from each starting pose (:func:`_starts`) with the
    velocities held (:func:`_fixed_velocities`' ``w``, ``b``; ``moving``: not both zero):
    ``(RMS error, R, C, t, sum of squared errors, (6, 6) J^T J)`` (normalized units, whitened
    into measured pixels over the focal length) of each finite one, in :func:`_best_first`'s
    order. With the velocities at zero (the global-shutter model) every start is fitted in
    one compiled call (:func:`_fit_starts`), else each by :func:`_fit`."""
    rv, tv = _starts(fr)
    n = len(fr.x)
    tau = fr.r - fr.r0
    if not moving:
        k = len(rv)
        R, C, H, sse = np.empty((k, 3, 3)), np.empty((k, 3)), np.empty((k, 6, 6)), np.empty(k)
        kept = _fit_starts(rv, tv, fr.X, fr.x, tau, fr.W, R, C, H, sse)
        z = np.zeros(3)
        return [(math.sqrt(sse[j] / n), R[j], C[j], z, float(sse[j]), H[j]) for j in kept.tolist()]
    fits = []
    for r0, C0 in zip(rv, tv, strict=True):
        R0 = _rotation_of(r0)
        if R0 is None or not np.isfinite(C0).all():
            continue
        R, C, t, sse, H = _fit(fr, R0, C0, w, b, tau)
        if np.isfinite(R).all() and math.isfinite(sse):
            fits.append((math.sqrt(sse / n), R, C, t, sse, H))
    rms = np.array([f[0] for f in fits])
    order = _best_first(np.array([f[1] for f in fits]).reshape(-1, 3, 3), rms)
    return [fits[j] for j in order.tolist()]


def _fit(
    fr: Frame,
    R0: np.ndarray,
    C0: np.ndarray,
    w: np.ndarray,
    b: np.ndarray,
    tau: np.ndarray,
):
    """Least-squares pose (6 parameters) on the exact model with ``w`` and the camera's linear
    velocity fixed and not both zero (``t = w x C + b``, :func:`_fixed_velocities`), from
    ``(R0, C0)``: ``(R, C, t, the sum of squared errors, (6, 6) J^T J at the fit)``,
    normalized units (whitened into measured pixels over the focal length): SciPy's
    Levenberg-Marquardt on the held-velocity parametrization, with the analytic Jacobian.
    ``tau``: the frame's ``r - r0``. (Zero velocities: :func:`_fit_starts`.)"""
    X, x = fr.X, fr.x
    W = skew(w)
    m = fr.mountings()  # (each corner's error whitened into measured pixels; None: plain)

    def theta(p):
        return np.concatenate([p, w, np.cross(w, p[3:]) + b])

    def jac(p):
        J = exact_jacobian(theta(p), R0, X, x, tau, m)
        return np.concatenate([J[:, :3], J[:, 3:6] + J[:, 9:12] @ W], axis=1)

    sol = least_squares(
        lambda p: exact_residuals(theta(p), R0, X, x, tau, m),
        np.concatenate([np.zeros(3), C0]),
        jac=jac,
        method="lm",
        xtol=1e-12,
        ftol=1e-12,
    )
    R, C = cv2.Rodrigues(sol.x[:3])[0] @ R0, sol.x[3:].copy()
    q = np.concatenate([np.zeros(3), C])
    J = exact_jacobian(theta(q), R, X, x, tau, m)  # (at the refined pose, not the start's R0)
    J = np.concatenate([J[:, :3], J[:, 3:6] + J[:, 9:12] @ W], axis=1)
    res = exact_residuals(theta(q), R, X, x, tau, m)
    return R, C, theta(q)[9:12], float(res @ res), J.T @ J


def _velocity_covariance(prior: MotionPrior | None, C: np.ndarray, s: float) -> np.ndarray:
    """(6, 6) covariance of the model's ``(w, t)`` per unit r held at a prediction: the motion
    prior's twist covariance (the tracker puts its prediction's there; else the default
    prior's), mapped with ``w = -s omega``, ``t = s (C x omega) - s v``."""
    cov = None
    if prior is not None and prior.enabled:
        info = prior.information()
        if np.linalg.matrix_rank(info) == 6:
            cov = np.linalg.inv(info)
    if cov is None:
        cov = np.linalg.inv(MotionPrior().information())
    A = np.zeros((6, 6))  # d(w, t) / d(v, omega), ROS twist order
    A[0:3, 3:6] = -s * np.eye(3)
    A[3:6, 0:3] = -s * np.eye(3)
    A[3:6, 3:6] = s * skew(np.asarray(C, dtype=float))
    return A @ cov @ A.T


def _every_point(n: int) -> np.ndarray:
    """(n,) bool, every point an inlier (``np.ones(n, dtype=bool)``'s array at a third of its
    cost)."""
    mask = np.empty(n, dtype=bool)
    mask.fill(True)
    return mask


class FewPointsModel(NamedTuple):
    """The pose of a frame of a few points before the last checks (:func:`few_points_model`).

    Attributes:
        final: the :class:`~.finalize.FinalModel`: the model, every point an inlier, the RMS
            error (px), the (12, 12) covariance.
        information: (6, 6) ``J^T J`` of the pose at the fit (normalized units).
        moving: the velocities are held at a prediction's or a gyro's (not zero).
        initial: (points the prediction explained, -1 without one; whether it gave the
            velocities), :func:`~.finalize.final_estimate`'s ``initial``.
    """

    final: FinalModel
    information: np.ndarray
    moving: bool
    initial: tuple[int, bool]


def few_points_model(
    fr: Frame, opts: EstimateOptions, initial_model: InitialModel | None
) -> FewPointsModel:
    """:func:`few_points_estimate`'s model of the frame, before the last checks (its
    arguments as there; ``opts.motion_prior``: the held velocities' covariance).

    Raises:
        EstimationFailed: ``too_few_points``, ``degenerate_geometry``, ``ambiguous_tag``,
            ``too_few_inliers`` (:func:`few_points_estimate`).
    """
    planar = fr.planar
    if not (planar or len(fr.x) >= MIN_SPREAD_POINTS):  # (not few_points)
        raise EstimationFailed(TOO_FEW_POINTS)
    w, b, moving, pred, explained = _fixed_velocities(fr, initial_model, fr.known_w)
    fits = _fits(fr, w, b, moving)
    if not fits:
        raise EstimationFailed(DEGENERATE_GEOMETRY)
    th, n = float(fr.threshold), len(fr.x)
    sigma2 = max(n * fits[0][0] ** 2 / max(2 * n - 6, 1), (MIN_CORNER_SIGMA_PX / fr.f) ** 2)
    choice = fits[0]
    if len(fits) > 1 and n * (fits[1][0] ** 2 - fits[0][0] ** 2) < AMBIGUITY_CHI2 * sigma2:
        if initial_model is None:
            raise EstimationFailed(AMBIGUOUS_TAG)
        d = [rotation_angle_deg(f[1], initial_model.model.R) for f in fits[:2]]
        near = int(np.argmin(d))
        if not d[near] <= PREDICTION_RATIO * d[1 - near]:
            raise EstimationFailed(AMBIGUOUS_TAG)
        choice = fits[near]
    rms, R, C, t, sse, H = choice
    if rms > th:
        raise EstimationFailed(TOO_FEW_INLIERS)
    sigma2 = max(sse / max(2 * n - 6, 1), (MIN_CORNER_SIGMA_PX / fr.f) ** 2)
    cov = np.zeros((12, 12))
    try:
        cov[:6, :6] = sigma2 * np.linalg.inv(H)
    except np.linalg.LinAlgError:
        raise EstimationFailed(DEGENERATE_GEOMETRY) from None
    if fr.groups is not None and fr.shift_share > 0:
        # (each marker's corners share a shift: the options' share of the corner's noise,
        # the few points cannot tell it themselves; noise_model)
        rows = exact_rows((R, C, w, t), fr.X, fr.x, fr.r - fr.r0, th, fr.mountings())
        if rows is not None:
            r, J = rows
            cov[:6, :6] = shared_shift_covariance(
                cov[:6, :6], math.sqrt(sigma2), J[:, :6], np.ones(n), r, fr.groups,
                fr.shift_share, floor=sigma2,
            )[0]  # fmt: skip
    if moving:
        cov[6:, 6:] = _velocity_covariance(opts.motion_prior, C, fr.spr)
    final = FinalModel(
        RSModel(R, C, w, t.copy()),  # (w: _fixed_velocities' own array)
        _every_point(n),
        float(rms * fr.f),
        covariance=cov,
    )
    return FewPointsModel(final, H, moving, (explained, pred is not None))


def few_points_estimate(
    fr: Frame,
    solver: str,
    opts: EstimateOptions,
    initial_model: InitialModel | None,
    gyro_used: bool,
    timings: dict[str, float],
    ignored_inputs: tuple[str, ...] = (),
    *,
    flat: float | None = None,
    name: str | None = None,
) -> RSPoseEstimate:
    """The pose of a frame of a few points (:func:`few_points`; too few for ``solver``'s
    robust estimate): one square marker's four corners or a few coplanar points, or at least
    :data:`MIN_SPREAD_POINTS` on more than one plane (e.g. two markers' corners).

    The starting poses, IPPE's two for coplanar points and SQPnP's one otherwise, are each
    refined (Levenberg-Marquardt on the 6 pose parameters, the
    exact model at each point's measured capture time) with the velocities fixed: the
    prediction's ``(w, t)`` when ``initial_model`` explains every point within its
    ``gate_px``, the gyro's angular velocity when ``fr.known_w`` is set, else zero. Of two
    fits the better
    is taken when the other one's squared errors exceed its own by
    :data:`AMBIGUITY_CHI2` corner noise variances; else the pose the prediction's rotation is
    nearer by :data:`PREDICTION_RATIO` (whether or not it explains the points: a prediction
    from frames long before, off by more than the gate, still tells two poses tens of degrees
    apart). Every point is an inlier when their RMS error is within the
    threshold (none is rejected: a wrong match fails the frame). The covariance is the pose
    fit's (``sigma^2 (J^T J)^-1``, ``sigma`` from the
    residuals with 2N - 6 degrees of freedom, at least :data:`MIN_CORNER_SIGMA_PX`); held
    velocities carry the motion prior's covariance in the (12, 12) ``covariance``
    (``opts.motion_prior``: a tracker's prediction), zero velocities none. The
    ``twist_covariance`` is ``None`` either way: the frame does not measure its velocities
    (a video's twist filter takes its pose only).

    Args:
        fr: the prepared frame (:func:`~.frame.prepare_frame`), its threshold, timing and
            velocity bounds set (:func:`~.frame.configure_frame`'s fields), and ``planar``:
            :func:`planar_points`.
        solver: the estimator's solver.
        gyro_used: ``fr.known_w`` is a gyro's (set on the estimate).
        flat: :func:`~.degeneracy.planarity` of the frame's points when the caller has it
            (:func:`few_points_planarity`; None: computed here).
        name: the solver recorded on the estimate (None: ``solver``).

    Returns:
        the successful :class:`RSPoseEstimate`: ``few_points`` set, ``single_tag`` too for
        coplanar points; ``motion_model`` ``"global_shutter"`` (zero
        velocities) or :data:`PREDICTED_MOTION`; ``initial_used`` when the prediction
        explained every point (it then gives the velocities);
        ``ransac_iterations`` 0.

    Raises:
        EstimationFailed: ``too_few_points`` (not :func:`few_points`),
            ``degenerate_geometry`` (no starting pose), ``ambiguous_tag`` (neither the
            image nor a prediction tells IPPE's two poses apart), ``too_few_inliers`` (the RMS
            error is above the threshold), and those of :func:`~.finalize.final_estimate`.
    """
    fit = few_points_model(fr, opts, initial_model)
    flat = float(planarity(fr.X)) if flat is None else flat
    return final_estimate(
        fr,
        solver if fit.moving else "p3p",
        fit.final,
        0,
        fit.initial,
        timings,
        gyro_used=gyro_used,
        ignored_inputs=ignored_inputs,
        flat=flat,
        condition=condition_number(fit.information),
        solver=solver if name is None else name,
        motion_model=PREDICTED_MOTION if fit.moving else GLOBAL_SHUTTER,
        single_tag=fr.planar,
        few_points=True,
        twist_covariance=None,
    )
