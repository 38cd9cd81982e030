"""Nonlinear refinement of an RS pose on the exact constant-velocity model.

Model (the one the solvers linearize, paper eq. 2-4 with ``R(tau) = expm(tau [w]x) R``)::

    x_i ~ pi( expm(tau_i [w]x) R X_i + C + tau_i t ),   tau_i = r_i - r0 (measured line)

Parameters ``theta = (delta, C, w, t)`` with ``R = expm([delta]x) R_0``. Each residual is the
image-point error at the observation's measured capture time. The Jacobian is analytic (SO(3)
left Jacobian for the ``expm(tau [w]x)`` term). :func:`refine_rs_pose` is our own Huber-
weighted Levenberg-Marquardt, the whole loop in one numba call: one evaluation (cost and
normal equations) takes ~65 ns per point, a refinement of 300 points ~130 us with 6
evaluations (one core; ~70x faster than SciPy here). :func:`refine_rs_pose_scipy` solves the
same problem with SciPy's ``least_squares`` and serves as the reference in the tests.

A rig of cameras is the same problem (``mountings``, :class:`Mountings`): the model is the
rig's, observation i is seen by its camera through that camera's mounting, at its own capture
time ``tau_i`` and with its error in its camera's pixels::

    x_i ~ pi( R_c (expm(tau_i [w]x) R X_i + C + tau_i t) + c_c )

One camera alone is the rig of one camera at the identity mounting. The loop, the prior, the
covariance and the acceleration block are shared; only the points' Jacobian rows differ
(:func:`point_rows_mounted`, compiled as a second specialization, so the single camera keeps
its own :func:`point_rows`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from .._jit import kernel
from .._linalg import solve_symmetric
from .._so3 import FMA, INLINE, rotate_left_into, rotate_small
from ..geometry import exact_camera_points, rotvec_to_matrix, skew
from ..pose import RSModel, model_twist, model_twist_jacobian
from .prior import MotionPrior, prior_arrays
from .scoring import exact_error2, exact_error2_whitened

__all__ = [
    "LM_REFINE_KERNEL",
    "NUMPY_MAP_ROUNDS",
    "NUMPY_PASSES",
    "ExactModelFit",
    "KernelMountings",
    "Mountings",
    "RefineResult",
    "RefineSettings",
    "exact_errors",
    "exact_jacobian",
    "exact_mounting_jacobian",
    "exact_residuals",
    "exact_rows",
    "huber_fit_numpy",
    "huber_weights",
    "image_variance",
    "kernel_mountings",
    "least_squares_exact_model",
    "prior_residuals",
    "refine_backend",
    "refine_rs_pose",
    "refine_rs_pose_numpy",
    "refine_rs_pose_scipy",
    "untruncated_variance",
]

# The refinement kernels' packed float64 output (:func:`_lm_refine`, :func:`_posterior_step`),
# block by block at these offsets, matrices row-major: R (3, 3), C, w, t (3,) the model;
# the covariance (12, 12) of (delta, C, w, t); the data's information ``J^T W J`` (12, 12) and
# gradient ``J^T W e`` (12,); the acceleration block ``J^T W D`` (12, 6). Module-level ints:
# numba compiles them into the kernels as constants.
OUT_R = 0
OUT_C = 9
OUT_W = 12
OUT_T = 15
OUT_COV = 18
OUT_INFO = OUT_COV + 144
OUT_GRAD = OUT_INFO + 144
OUT_ACC = OUT_GRAD + 12
#: the buffer without / with the acceleration block
OUT_SIZE = OUT_ACC
OUT_SIZE_ACC = OUT_ACC + 72


def _left_jacobian(phi: np.ndarray) -> np.ndarray:
    """SO(3) left Jacobian ``J_l(phi)`` (..., 3, 3): ``d expm([phi]) / d phi`` in left form."""
    th = np.linalg.norm(phi, axis=-1)[..., None, None]
    K = skew(phi)
    small = th < 1e-6
    ths = np.where(small, 1.0, th)
    a = np.where(small, 0.5 - th**2 / 24, (1 - np.cos(ths)) / ths**2)
    b = np.where(small, 1.0 / 6 - th**2 / 120, (ths - np.sin(ths)) / ths**3)
    return np.eye(3) + a * K + b * (K @ K)


def _camera_points(theta, R0, X, tau):
    """The exact model's camera points (:func:`~rs_localizer.geometry.exact_camera_points`) at
    ``theta`` = (delta, C, w, t) with ``R = expm([delta]x) R0``, and that ``R``."""
    R = rotvec_to_matrix(theta[:3]) @ R0
    return exact_camera_points(R, theta[3:6], theta[6:9], theta[9:12], X, tau), R


class Mountings(NamedTuple):
    """Each observation's camera on a rig, for :func:`refine_rs_pose` and the exact model's
    NumPy functions: observation i is seen by camera ``cam[i]`` mounted at ``x_cam =
    R_mount[c] x_rig + c_mount[c]`` (the model's pose is then the rig's), and its image
    error is ``scale[i]`` times the normalized one (the camera's focal length: errors and
    thresholds in px), or the 2x2 ``scale[i]`` applied to it (the camera's
    :meth:`~rs_localizer.camera.CameraModel.pixel_jacobian` at the point: to first order the
    error in px of the measured, distorted image). One camera alone is the rig of one camera
    at the identity mounting with scale 1 (``mountings=None``), or with its points' 2x2
    whitening (:attr:`~.frame.Frame.W`).

    Attributes:
        cam: (N,) int64 camera index of each observation, in ``[0, M)``.
        R_mount: (M, 3, 3) rig -> camera rotations. c_mount: (M, 3) rig -> camera offsets (m).
        scale: (N,) the factor of each observation's normalized error (px per normalized
            unit), > 0; or (N, 2, 2) a matrix per observation.
    """

    cam: np.ndarray
    R_mount: np.ndarray
    c_mount: np.ndarray
    scale: np.ndarray

    def take(self, idx: np.ndarray) -> Mountings:
        """The observations ``idx`` (an index array or (N,) bool mask) on the same cameras."""
        return Mountings(self.cam[idx], self.R_mount, self.c_mount, self.scale[idx])


def _checked_mountings(mountings: Mountings, n: int) -> tuple:
    """The kernels' contiguous ``(cam, R_mount, c_mount, scale)`` of ``mountings`` for n
    observations, ``scale`` as (n, 4) row-major 2x2 matrices. Raises ValueError on shapes
    that do not match or an index out of range."""
    cam = np.ascontiguousarray(mountings.cam, dtype=np.int64)
    Rm = np.ascontiguousarray(mountings.R_mount, dtype=np.float64)
    cm = np.ascontiguousarray(mountings.c_mount, dtype=np.float64)
    s = np.asarray(mountings.scale, dtype=np.float64)
    M = Rm.shape[0] if Rm.ndim == 3 else -1
    if (
        Rm.shape != (M, 3, 3)
        or cm.shape != (M, 3)
        or cam.shape != (n,)
        or s.shape not in ((n,), (n, 2, 2))
    ):
        raise ValueError(
            f"mountings: cam must be ({n},), scale ({n},) or ({n}, 2, 2), R_mount (M, 3, 3) "
            f"and c_mount (M, 3), got {cam.shape}, {s.shape}, {Rm.shape}, {cm.shape}"
        )
    scale = np.zeros((n, 4))
    if s.ndim == 1:
        scale[:, 0] = s
        scale[:, 3] = s
    else:
        scale[:] = s.reshape(n, 4)
    if n and (cam.min() < 0 or cam.max() >= M):
        raise ValueError(f"mountings: camera index out of [0, {M})")
    return cam, Rm, cm, scale


class KernelMountings(NamedTuple):
    """A :class:`Mountings` of ``n`` observations checked once and in the refinement
    kernel's form (:func:`kernel_mountings`): :func:`refine_rs_pose` takes it as its
    ``mountings`` without checking and converting them again, for a caller that refines the
    same observations several times (a rig frame's local optimization, final refinement and
    covariance). It may share the :class:`Mountings`' arrays: build it again after changing
    them."""

    n: int
    views: tuple


def kernel_mountings(mountings: Mountings, n: int) -> KernelMountings:
    """``mountings`` of ``n`` observations checked and converted once (:class:`KernelMountings`).

    Raises:
        ValueError: shapes that do not match the n observations, or a camera index out of
            range (as :func:`refine_rs_pose`).
    """
    return KernelMountings(int(n), _checked_mountings(mountings, int(n)))


def _scale_matrices(mountings: Mountings) -> np.ndarray:
    """(N, 2, 2) each observation's :attr:`Mountings.scale` as a matrix."""
    s = np.asarray(mountings.scale, dtype=np.float64)
    return s[:, None, None] * np.eye(2) if s.ndim == 1 else s


def _mounted(p: np.ndarray, mountings: Mountings | None) -> np.ndarray:
    """(N, 3) rig-frame points ``p`` in their cameras' frames (unchanged without mountings)."""
    if mountings is None:
        return p
    c = np.asarray(mountings.cam)
    return (
        np.einsum("nij,nj->ni", np.asarray(mountings.R_mount)[c], p)
        + np.asarray(mountings.c_mount)[c]
    )


def exact_residuals(
    theta: np.ndarray,
    R0: np.ndarray,
    X: np.ndarray,
    x: np.ndarray,
    tau: np.ndarray,
    mountings: Mountings | None = None,
) -> np.ndarray:
    """(2N,) residuals ``pi(p_i) - x_i`` (normalized units) of the exact model; theta (12,).
    With ``mountings`` (:class:`Mountings`) ``p_i`` is in its camera's frame and the
    residuals are scaled by ``scale``."""
    return _residuals_and_depths(theta, R0, X, x, tau, mountings)[0].ravel()


def _residuals_and_depths(theta, R0, X, x, tau, mountings) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) :func:`exact_residuals` and (N,) the points' depths in their cameras."""
    p, _ = _camera_points(theta, R0, X, tau)
    p = _mounted(p, mountings)
    r = p[:, :2] / p[:, 2:3] - x
    if mountings is not None:
        r = np.einsum("nij,nj->ni", _scale_matrices(mountings), r)
    return r, p[:, 2]


def _projection_rows(p: np.ndarray, mountings: Mountings | None) -> np.ndarray:
    """(N, 2, 3) ``d residual / d p_rig`` at the rig-frame points p (N, 3)."""
    pc = _mounted(p, mountings)
    n, z = len(p), pc[:, 2]
    dpi = np.zeros((n, 2, 3))
    dpi[:, 0, 0] = 1 / z
    dpi[:, 1, 1] = 1 / z
    dpi[:, 0, 2] = -pc[:, 0] / z**2
    dpi[:, 1, 2] = -pc[:, 1] / z**2
    if mountings is None:
        return dpi
    return (
        _scale_matrices(mountings) @ dpi @ np.asarray(mountings.R_mount)[np.asarray(mountings.cam)]
    )


def exact_mounting_jacobian(
    theta: np.ndarray,
    R0: np.ndarray,
    X: np.ndarray,
    x: np.ndarray,
    tau: np.ndarray,
    mountings: Mountings,
) -> np.ndarray:
    """(2N, 6) analytic Jacobian of :func:`exact_residuals` (with ``mountings``) w.r.t. the
    mounting of each observation's own camera: its rotation on the rig (rad, rig axes:
    ``R_mount^T`` turned by ``expm([phi]x)``) and its optical centre in the rig frame (m),
    the parametrization of :attr:`~rs_localizer.frames.Mounting.covariance`.
    With ``x_cam = R_mount (y - o)``, o the centre: the rows are ``D x (y - o)`` and ``-D``,
    ``D`` the residual's row over the rig-frame point y."""
    y, _ = _camera_points(theta, R0, X, tau)
    c = np.asarray(mountings.cam)
    Rm = np.asarray(mountings.R_mount)
    o = -np.einsum("mji,mj->mi", Rm, np.asarray(mountings.c_mount))[c]
    D = _projection_rows(y, mountings)
    J = np.empty((len(X), 2, 6))
    J[:, :, :3] = np.cross(D, (y - o)[:, None, :])
    J[:, :, 3:] = -D
    return J.reshape(2 * len(X), 6)


def exact_time_jacobian(
    theta: np.ndarray,
    R0: np.ndarray,
    X: np.ndarray,
    x: np.ndarray,
    tau: np.ndarray,
    mountings: Mountings | None = None,
) -> np.ndarray:
    """(2N,) analytic derivative of :func:`exact_residuals` w.r.t. a shift of every
    observation's capture time ``tau`` (units of ``tau``: s in a rig): the image motion of
    each point under the model's twist. With ``p = expm(tau [w]x) q + C + tau t`` (``q = R
    X``, :func:`~rs_localizer.geometry.exact_camera_points`), ``dp/dtau = w x (p - C - tau
    t) + t`` through the residual's rows over ``p``."""
    p, _ = _camera_points(theta, R0, X, tau)
    C, w, t = theta[3:6], theta[6:9], theta[9:12]
    dp = np.cross(w, p - C - tau[:, None] * t) + t
    return np.einsum("nij,nj->ni", _projection_rows(p, mountings), dp).ravel()


def exact_jacobian(
    theta: np.ndarray,
    R0: np.ndarray,
    X: np.ndarray,
    x: np.ndarray,
    tau: np.ndarray,
    mountings: Mountings | None = None,
) -> np.ndarray:
    """(2N, 12) analytic Jacobian of :func:`exact_residuals` w.r.t. (delta, C, w, t)."""
    p, R = _camera_points(theta, R0, X, tau)
    q = X @ R.T
    A = rotvec_to_matrix(tau[:, None] * theta[6:9])
    Aq = np.einsum("nij,nj->ni", A, q)  # (the derivative's rotated points)
    n = len(X)
    dpi = _projection_rows(p, mountings)
    J = np.empty((n, 3, 12))
    # d(A R X)/d delta with R = expm([delta]x) R0: -A [q]x J_l(delta)
    J[:, :, 0:3] = -A @ skew(q) @ _left_jacobian(theta[:3])
    J[:, :, 3:6] = np.eye(3)
    J[:, :, 6:9] = -(skew(Aq) @ _left_jacobian(tau[:, None] * theta[6:9])) * tau[:, None, None]
    J[:, :, 9:12] = np.eye(3) * tau[:, None, None]
    return (dpi @ J).reshape(2 * n, 12)


#: The Gram kernel also reassociates its sums (besides FMA contraction, see ``_so3.FMA``),
#: which lets LLVM vectorize them (2.3x faster).
_FMA_REASSOC = FMA | {"reassoc"}


@kernel(inline=INLINE, fastmath=FMA)
def _rotation_rows(m0, m1, m2, a0, a1, a2, sa, ca, cb):
    """``A^T m`` and ``Jl^T m`` for ``A = I + sa [a]x + ca [a]x^2`` (Rodrigues) and its left
    Jacobian ``Jl = I + ca [a]x + cb [a]x^2``: six scalars."""
    h0 = a1 * m2 - a2 * m1
    h1 = a2 * m0 - a0 * m2
    h2 = a0 * m1 - a1 * m0
    l0 = a1 * h2 - a2 * h1
    l1 = a2 * h0 - a0 * h2
    l2 = a0 * h1 - a1 * h0
    return (
        m0 - sa * h0 + ca * l0,
        m1 - sa * h1 + ca * l1,
        m2 - sa * h2 + ca * l2,
        m0 - ca * h0 + cb * l0,
        m1 - ca * h1 + cb * l1,
        m2 - ca * h2 + cb * l2,
    )


@kernel(inline=INLINE, fastmath=FMA)
def _huber_terms(en, p2, k, cutoff, rho_cut):
    """A point's terms of :func:`point_rows` from its image distance ``en`` and depth ``p2``:
    ``(used, rho, sqrt of its Huber weight, e2_inside)`` (Huber: weight 1 inside k, k / e
    outside; the rows are scaled by the weight's square root)."""
    used = p2 > 1e-12 and not en > cutoff
    e2_inside = -1.0
    if en <= k:
        rho = en * en
        sw = 1.0
        if p2 > 1e-12:
            e2_inside = rho
    else:
        rho = 2.0 * k * en - k * k
        sw = np.sqrt(k / en)
    if not used:
        rho = rho_cut
    return used, rho, sw, e2_inside


@kernel(inline=INLINE)
def pose_scalars(R, C, w, t):
    """The pose ``R`` (3, 3), ``C``, ``w``, ``t`` (3,) as the 18 scalars :func:`point_rows`
    takes: ``R`` row-major, then ``C``, ``w``, ``t``."""
    return (R[0, 0], R[0, 1], R[0, 2], R[1, 0], R[1, 1], R[1, 2], R[2, 0], R[2, 1], R[2, 2],
            C[0], C[1], C[2], w[0], w[1], w[2], t[0], t[1], t[2])  # fmt: skip


@kernel(inline=INLINE, fastmath=FMA)
def point_rows(pose, X, x, tau, i, k, cutoff, rho_cut):
    """Point i's cost, residual and Jacobian rows at the pose ``(R (row-major), C, w, t)``
    given as 18 scalars. Everything is computed whether or not the point is used (no early
    exit: simpler, not slower).

    Returns ``(used, rho, e0, e1, P0, P1, W0, W1, d, d02, d12, tau_i, e2_inside)`` (vectors
    as 3 scalars): ``rho`` the point's cost (``rho_cut`` when not ``used``: behind the camera
    or beyond ``cutoff``); its two Jacobian rows, scaled by ``sqrt(Huber weight)`` like the
    residuals e0, e1, are ``(P_r, D_r, tau W_r, tau D_r)`` with ``D_0 = (d, 0, d02)``,
    ``D_1 = (0, d, d12)``; ``e2_inside`` the squared image distance if the point is in front
    of the camera and within ``k``, else -1. Values of unused points are garbage (possibly
    NaN).
    """
    (r00, r01, r02, r10, r11, r12, r20, r21, r22, C0, C1, C2, w0, w1, w2, t0, t1, t2) = pose
    X0, X1, X2 = X[i, 0], X[i, 1], X[i, 2]
    q0 = r00 * X0 + r01 * X1 + r02 * X2
    q1 = r10 * X0 + r11 * X1 + r12 * X2
    q2 = r20 * X0 + r21 * X1 + r22 * X2
    ti = tau[i]
    a0, a1, a2 = ti * w0, ti * w1, ti * w2
    Aq0, Aq1, Aq2, sa, ca, cb = rotate_small(a0, a1, a2, q0, q1, q2)  # Aq = expm([a]x) q
    p0 = Aq0 + C0 + ti * t0
    p1 = Aq1 + C1 + ti * t1
    p2 = Aq2 + C2 + ti * t2
    iz = 1.0 / (p2 if p2 > 1e-12 else 1.0)  # (unused point otherwise; no division by 0)
    u0 = p0 * iz
    u1 = p1 * iz
    e0 = u0 - x[i, 0]
    e1 = u1 - x[i, 1]
    en = np.sqrt(e0 * e0 + e1 * e1)
    used, rho, sw, e2_inside = _huber_terms(en, p2, k, cutoff, rho_cut)
    # rows of dpi/dp: D0 = (iz, 0, -u0 iz), D1 = (0, iz, -u1 iz). With m = Aq x D (the row D
    # times -[Aq]x) and A [q]x = [Aq]x A:
    #   d/ddelta = -D A [q]x = (A^T m)^T,  d/dw = -tau D [Aq]x Jl = tau (Jl^T m)^T,
    #   d/dC = D,  d/dt = tau D.
    d = sw * iz
    d02 = -u0 * d
    d12 = -u1 * d
    P00, P01, P02, W00, W01, W02 = _rotation_rows(
        Aq1 * d02, Aq2 * d - Aq0 * d02, -Aq1 * d, a0, a1, a2, sa, ca, cb
    )
    P10, P11, P12, W10, W11, W12 = _rotation_rows(
        Aq1 * d12 - Aq2 * d, -Aq0 * d12, Aq0 * d, a0, a1, a2, sa, ca, cb
    )
    return (
        used,
        rho,
        sw * e0,
        sw * e1,
        P00,
        P01,
        P02,
        P10,
        P11,
        P12,
        W00,
        W01,
        W02,
        W10,
        W11,
        W12,
        d,
        d02,
        d12,
        ti,
        e2_inside,
    )


@kernel(inline=INLINE)
def _store_rows(Jt, j0, j1, v):
    """Write a point's two weighted Jacobian rows (and residuals, row 12) from ``v`` (as
    returned by :func:`point_rows`) as columns j0 (even) and j1 = j0 + 1 of Jt (16, M), rows
    in parameter order (delta, C, w, t). The structural zeros (rows 4, 10 of even and 3, 9
    of odd columns) are set once by :func:`_workspace`."""
    e0, e1 = v[2], v[3]
    d, d02, d12, ti = v[16], v[17], v[18], v[19]
    Jt[0, j0], Jt[1, j0], Jt[2, j0], Jt[3, j0], Jt[5, j0] = v[4], v[5], v[6], d, d02
    Jt[6, j0], Jt[7, j0], Jt[8, j0] = ti * v[10], ti * v[11], ti * v[12]
    Jt[9, j0], Jt[11, j0], Jt[12, j0] = ti * d, ti * d02, e0
    Jt[0, j1], Jt[1, j1], Jt[2, j1], Jt[4, j1], Jt[5, j1] = v[7], v[8], v[9], d, d12
    Jt[6, j1], Jt[7, j1], Jt[8, j1] = ti * v[13], ti * v[14], ti * v[15]
    Jt[10, j1], Jt[11, j1], Jt[12, j1] = ti * d, ti * d12, e1


@kernel(inline=INLINE)
def _add_point(v, m, cost, ss, n_in, Jt):
    """Add a point from :func:`point_rows` to the running (m, cost, ss, n_in) of
    :func:`_fill_columns` and write its rows at columns 2m, 2m + 1 (overwritten by the next
    point if this one is not used)."""
    cost += v[1]
    if v[20] >= 0.0:
        ss += v[20]
        n_in += 1
    _store_rows(Jt, 2 * m, 2 * m + 1, v)
    return m + (1 if v[0] else 0), cost, ss, n_in


@kernel(inline=INLINE, fastmath=FMA)
def _fill_columns(pose, X, x, tau, k, cutoff, rho_cut, Jt):
    """Loop of :func:`_evaluate`: the used points' two rows as columns of Jt (the
    j-th used point's at 2j and 2j + 1). Returns (number of used points, cost, sum of e^2 and
    number of the points within k), sums in point order. Two points per iteration, computed
    before either is stored so that their dependency chains overlap (~7% faster)."""
    n = X.shape[0]
    m, cost, ss, n_in = 0, 0.0, 0.0, 0
    for i in range(0, n, 2):
        # (an odd n's last point is computed twice and added once: two inlined copies of
        # point_rows to compile, not three)
        j = i + 1 if i + 1 < n else i
        a = point_rows(pose, X, x, tau, i, k, cutoff, rho_cut)
        b = point_rows(pose, X, x, tau, j, k, cutoff, rho_cut)
        m, cost, ss, n_in = _add_point(a, m, cost, ss, n_in, Jt)
        if j > i:
            m, cost, ss, n_in = _add_point(b, m, cost, ss, n_in, Jt)
    return m, cost, ss, n_in


@kernel(inline=INLINE, fastmath=FMA)
def point_rows_mounted(pose, X, x, tau, i, k, cutoff, rho_cut, cam, Rm, cm, scale):
    """:func:`point_rows` for an observation of a camera mounted on a rig: the pose is the
    rig's, point i is seen by camera ``cam[i]`` at ``x_cam = Rm[c] x_rig + cm[c]`` and its
    image error is the row-major 2x2 ``scale[i]`` (4 scalars) times the normalized one (e.g.
    the focal length times the identity: errors in px; or the camera's pixel Jacobian at the
    point). With ``Rm = I``, ``cm = 0``, ``scale = I`` it is :func:`point_rows`' model.

    Returns ``(used, rho, e0, e1, P0, P1, W0, W1, D0, D1, tau_i, e2_inside)`` (vectors as 3
    scalars): as :func:`point_rows`, the rows ``(P_r, D_r, tau W_r, tau D_r)`` with ``D_r``
    the row of ``d pi / d x_rig`` (the camera's row times ``Rm[c]``), all three entries
    general.
    """
    (r00, r01, r02, r10, r11, r12, r20, r21, r22, C0, C1, C2, w0, w1, w2, t0, t1, t2) = pose
    X0, X1, X2 = X[i, 0], X[i, 1], X[i, 2]
    q0 = r00 * X0 + r01 * X1 + r02 * X2
    q1 = r10 * X0 + r11 * X1 + r12 * X2
    q2 = r20 * X0 + r21 * X1 + r22 * X2
    ti = tau[i]
    a0, a1, a2 = ti * w0, ti * w1, ti * w2
    Aq0, Aq1, Aq2, sa, ca, cb = rotate_small(a0, a1, a2, q0, q1, q2)  # Aq = expm([a]x) q
    y0 = Aq0 + C0 + ti * t0  # (the rig frame)
    y1 = Aq1 + C1 + ti * t1
    y2 = Aq2 + C2 + ti * t2
    c = cam[i]
    m00, m01, m02 = Rm[c, 0, 0], Rm[c, 0, 1], Rm[c, 0, 2]
    m10, m11, m12 = Rm[c, 1, 0], Rm[c, 1, 1], Rm[c, 1, 2]
    m20, m21, m22 = Rm[c, 2, 0], Rm[c, 2, 1], Rm[c, 2, 2]
    p0 = m00 * y0 + m01 * y1 + m02 * y2 + cm[c, 0]
    p1 = m10 * y0 + m11 * y1 + m12 * y2 + cm[c, 1]
    p2 = m20 * y0 + m21 * y1 + m22 * y2 + cm[c, 2]
    a00, a01, a10, a11 = scale[i, 0], scale[i, 1], scale[i, 2], scale[i, 3]
    iz = 1.0 / (p2 if p2 > 1e-12 else 1.0)  # (unused point otherwise; no division by 0)
    u0 = p0 * iz
    u1 = p1 * iz
    ex = u0 - x[i, 0]
    ey = u1 - x[i, 1]
    e0 = a00 * ex + a01 * ey
    e1 = a10 * ex + a11 * ey
    en = np.sqrt(e0 * e0 + e1 * e1)
    used, rho, sw, e2_inside = _huber_terms(en, p2, k, cutoff, rho_cut)
    # the camera's rows a (iz, 0, -u0 iz; 0, iz, -u1 iz) turned into the rig frame: D_r = D Rm
    c00 = sw * a00 * iz
    c01 = sw * a01 * iz
    c02 = -(u0 * c00 + u1 * c01)
    c10 = sw * a10 * iz
    c11 = sw * a11 * iz
    c12 = -(u0 * c10 + u1 * c11)
    g00 = c00 * m00 + c01 * m10 + c02 * m20
    g01 = c00 * m01 + c01 * m11 + c02 * m21
    g02 = c00 * m02 + c01 * m12 + c02 * m22
    g10 = c10 * m00 + c11 * m10 + c12 * m20
    g11 = c10 * m01 + c11 * m11 + c12 * m21
    g12 = c10 * m02 + c11 * m12 + c12 * m22
    # m = Aq x D_r, then the rows as in point_rows
    P00, P01, P02, W00, W01, W02 = _rotation_rows(
        Aq1 * g02 - Aq2 * g01, Aq2 * g00 - Aq0 * g02, Aq0 * g01 - Aq1 * g00,
        a0, a1, a2, sa, ca, cb,
    )  # fmt: skip
    P10, P11, P12, W10, W11, W12 = _rotation_rows(
        Aq1 * g12 - Aq2 * g11, Aq2 * g10 - Aq0 * g12, Aq0 * g11 - Aq1 * g10,
        a0, a1, a2, sa, ca, cb,
    )  # fmt: skip
    return (
        used, rho, sw * e0, sw * e1,
        P00, P01, P02, P10, P11, P12, W00, W01, W02, W10, W11, W12,
        g00, g01, g02, g10, g11, g12, ti, e2_inside,
    )  # fmt: skip


@kernel(inline=INLINE)
def _store_rows_mounted(Jt, j0, j1, v):
    """:func:`_store_rows` for :func:`point_rows_mounted`'s ``v`` (no structural zeros), and
    the point's ``tau`` in row 13 of the even column (for :func:`_acceleration_block`)."""
    ti = v[22]
    # (constant indices: v is a heterogeneous tuple)
    Jt[0, j0], Jt[1, j0], Jt[2, j0] = v[4], v[5], v[6]
    Jt[3, j0], Jt[4, j0], Jt[5, j0] = v[16], v[17], v[18]
    Jt[6, j0], Jt[7, j0], Jt[8, j0] = ti * v[10], ti * v[11], ti * v[12]
    Jt[9, j0], Jt[10, j0], Jt[11, j0] = ti * v[16], ti * v[17], ti * v[18]
    Jt[0, j1], Jt[1, j1], Jt[2, j1] = v[7], v[8], v[9]
    Jt[3, j1], Jt[4, j1], Jt[5, j1] = v[19], v[20], v[21]
    Jt[6, j1], Jt[7, j1], Jt[8, j1] = ti * v[13], ti * v[14], ti * v[15]
    Jt[9, j1], Jt[10, j1], Jt[11, j1] = ti * v[19], ti * v[20], ti * v[21]
    Jt[12, j0] = v[2]
    Jt[12, j1] = v[3]
    Jt[13, j0] = ti


@kernel(inline=INLINE)
def _add_point_mounted(v, m, cost, ss, n_in, Jt):
    """:func:`_add_point` for :func:`point_rows_mounted`'s ``v``."""
    cost += v[1]
    if v[23] >= 0.0:
        ss += v[23]
        n_in += 1
    _store_rows_mounted(Jt, 2 * m, 2 * m + 1, v)
    return m + (1 if v[0] else 0), cost, ss, n_in


@kernel(fastmath=FMA)
def _fill_columns_mounted(pose, X, x, tau, k, cutoff, rho_cut, Jt, cam, Rm, cm, scale):
    """:func:`_fill_columns` with :func:`point_rows_mounted` (arguments as there)."""
    n = X.shape[0]
    m, cost, ss, n_in = 0, 0.0, 0.0, 0
    for i in range(0, n, 2):
        j = i + 1 if i + 1 < n else i
        a = point_rows_mounted(pose, X, x, tau, i, k, cutoff, rho_cut, cam, Rm, cm, scale)
        b = point_rows_mounted(pose, X, x, tau, j, k, cutoff, rho_cut, cam, Rm, cm, scale)
        m, cost, ss, n_in = _add_point_mounted(a, m, cost, ss, n_in, Jt)
        if j > i:
            m, cost, ss, n_in = _add_point_mounted(b, m, cost, ss, n_in, Jt)
    return m, cost, ss, n_in


@kernel(fastmath=_FMA_REASSOC)
def _gram16(Jt, m, G):
    """``G[a, b] = sum_j Jt[a, j] Jt[b, j]`` over the first m columns of Jt (16, M) for the
    4 x 4 blocks with ``a < 12`` on or above the diagonal (the other entries of G (16, 16)
    are left alone). Each block is a register tile filled in one vectorized pass over the
    columns; the sums are reassociated (rounding-level changes)."""
    for a in range(0, 12, 4):
        r0, r1, r2, r3 = Jt[a], Jt[a + 1], Jt[a + 2], Jt[a + 3]
        for b in range(a, 16, 4):
            c0, c1, c2, c3 = Jt[b], Jt[b + 1], Jt[b + 2], Jt[b + 3]
            s00 = s01 = s02 = s03 = s10 = s11 = s12 = s13 = 0.0
            s20 = s21 = s22 = s23 = s30 = s31 = s32 = s33 = 0.0
            for j in range(m):
                v0, v1, v2, v3 = r0[j], r1[j], r2[j], r3[j]
                y0, y1, y2, y3 = c0[j], c1[j], c2[j], c3[j]
                s00 += v0 * y0
                s01 += v0 * y1
                s02 += v0 * y2
                s03 += v0 * y3
                s10 += v1 * y0
                s11 += v1 * y1
                s12 += v1 * y2
                s13 += v1 * y3
                s20 += v2 * y0
                s21 += v2 * y1
                s22 += v2 * y2
                s23 += v2 * y3
                s30 += v3 * y0
                s31 += v3 * y1
                s32 += v3 * y2
                s33 += v3 * y3
            G[a, b], G[a, b + 1], G[a, b + 2], G[a, b + 3] = s00, s01, s02, s03
            G[a + 1, b], G[a + 1, b + 1], G[a + 1, b + 2], G[a + 1, b + 3] = s10, s11, s12, s13
            G[a + 2, b], G[a + 2, b + 1], G[a + 2, b + 2], G[a + 2, b + 3] = s20, s21, s22, s23
            G[a + 3, b], G[a + 3, b + 1], G[a + 3, b + 2], G[a + 3, b + 3] = s30, s31, s32, s33


@kernel(fastmath=FMA)
def _evaluate(R, C, w, t, X, x, tau, k, cutoff, Jt, mountings):
    """Cost and weighted Jacobian of the exact model at (R, C, w, t), for the increments
    (delta, dC, dw, dt) of all 12 parameters, ``R <- expm([delta]x) R``.

    ``mountings``: None (one camera, the identity mounting: :func:`point_rows`) or the
    tuple ``(cam (N,) int64, R_mount (M, 3, 3), c_mount (M, 3), scale (N, 4))`` of
    :class:`Mountings` (a rig: :func:`point_rows_mounted`; k and cutoff in the units of
    ``scale`` times normalized ones). numba compiles each case on its own (the other branch
    is pruned), so the single camera runs its own code.

    Huber weight per point, on the image distance ``e`` (normalized units): 1 for ``e <= k``,
    ``k / e`` above (IRLS form of the Huber loss ``rho``). Points with ``e > cutoff`` or depth
    ``z <= 1e-12`` add the constant ``rho(cutoff)`` to the cost and nothing else (truncated
    loss). The m used points' Jacobian rows and residuals, scaled by ``sqrt(weight)``, go to
    the first 2m columns of Jt (from :func:`_workspace`); :func:`_normal_matrix` turns them
    into ``J^T W J`` and ``J^T W r``.

    Returns (m, cost ``sum_i rho(e_i)`` summed in point order, and for the residual variance
    the sum of ``e_i^2`` over the points in front of the camera with ``e_i <= k``, and their
    number).
    """
    rho_cut = cutoff * cutoff if cutoff <= k else 2.0 * k * cutoff - k * k
    pose = pose_scalars(R, C, w, t)
    if mountings is None:
        return _fill_columns(pose, X, x, tau, k, cutoff, rho_cut, Jt)
    cam, Rm, cm, scale = mountings
    return _fill_columns_mounted(pose, X, x, tau, k, cutoff, rho_cut, Jt, cam, Rm, cm, scale)


@kernel
def _normal_matrix(Jt, m, G, H, g):
    """H (12, 12) (full, symmetric) and g (12,) overwritten with ``J^T W J`` and ``J^T W r``
    from the m used points of :func:`_evaluate`; G (16, 16) workspace."""
    _gram16(Jt, 2 * m, G)
    for a in range(12):
        g[a] = G[a, 12]
        for b in range(a, 12):
            H[a, b] = G[a, b]
            H[b, a] = G[a, b]


@kernel
def _acceleration_block(Jt, m, B, mounted):
    """B (12, 6) overwritten with ``J^T W D`` over the m used points of :func:`_evaluate`,
    D the columns of an in-readout acceleration (beta, b): ``tau / 2`` times the w and t
    columns of J (see :mod:`.sensitivity`). A point's ``tau``: row 13 of its even column if
    ``mounted`` (:func:`_store_rows_mounted`), else read back from its rows (``Jt[9] / Jt[3]``
    of its even column: ``tau d / d``, ``d > 0`` for a used point)."""
    for a in range(12):
        for b in range(6):
            B[a, b] = 0.0
    for j in range(m):
        c0 = 2 * j
        h = 0.5 * Jt[13, c0] if mounted else 0.5 * Jt[9, c0] / Jt[3, c0]
        for c in range(c0, c0 + 2):
            for a in range(12):
                ra = Jt[a, c] * h
                if ra != 0.0:
                    for b in range(6):
                        B[a, b] += ra * Jt[6 + b, c]


@kernel
def _workspace(n):
    """Workspace (Jt (16, 2n), G (16, 16)) of :func:`_evaluate` and :func:`_normal_matrix`
    for n points, with the entries of Jt never written set to zero (padding rows 13-15,
    structural zeros)."""
    Jt = np.empty((16, 2 * n))
    Jt[13:] = 0.0
    Jt[4, ::2] = 0.0
    Jt[10, ::2] = 0.0
    Jt[3, 1::2] = 0.0
    Jt[9, 1::2] = 0.0
    return Jt, np.empty((16, 16))


@kernel
def _normal_equations(R, C, w, t, X, x, tau, k, n_free, cutoff, mountings):
    """Huber-weighted normal equations (see :func:`_evaluate`; ``mountings`` as there) for
    the first ``n_free`` parameters (6: global shutter, ``w = t = 0`` fixed). Returns
    (H (n_free, n_free), g (n_free,), cost)."""
    H = np.empty((12, 12))
    g = np.empty(12)
    Jt, G = _workspace(X.shape[0])
    m, cost, _, _ = _evaluate(R, C, w, t, X, x, tau, k, cutoff, Jt, mountings)
    _normal_matrix(Jt, m, G, H, g)
    return H[:n_free, :n_free].copy(), g[:n_free].copy(), cost


@kernel
def _rotate_left(v0, v1, v2, R):
    """(3, 3) ``expm([v]x) R`` (Rodrigues)."""
    out = np.empty((3, 3))
    rotate_left_into(v0, v1, v2, R, out)
    return out


@kernel
def untruncated_variance(s2, k):
    """Per-axis variance ``sigma^2`` of 2D Gaussian image noise from ``s2``, the variance
    estimated from the residuals inside the Huber threshold ``k`` only (``sum e^2 / (2 n)``).

    Inside ``e <= k`` the squared distance ``e^2 / sigma^2`` is chi-square with 2 dof
    truncated at ``a = k^2 / (2 sigma^2)``: ``E[e^2 | e <= k] = 2 sigma^2 g(a)``,
    ``g(a) = (1 - (1 + a) e^-a) / (1 - e^-a)``. So ``s2 = sigma^2 g(a)``, solved for sigma^2
    by fixed-point iteration (``g`` = 0.69 at ``k = 2 sigma``, 0.997 at ``k = 4 sigma``;
    without the correction a threshold of two sigmas understates the covariance 1.5x).
    Capped at ``k^2`` (``s2`` at or above ``k^2 / 4``, the mean of a uniform disc, has no
    Gaussian explanation)."""
    if not s2 > 0.0:
        return s2
    v = s2
    for _ in range(100):
        a = k * k / (2.0 * v)
        ea = np.exp(-a)
        g = (1.0 - (1.0 + a) * ea) / (1.0 - ea) if a > 1e-8 else 0.5 * a
        vn = min(s2 / max(g, 1e-300), k * k)
        if abs(vn - v) <= 1e-12 * v:
            return vn
        v = vn
    return v


@kernel
def _prior_terms(C, w, t, s, mu, Lam, scale2, H, g, add):
    """Motion prior of :func:`refine_rs_pose` at (C, w, t): ``scale2 (z - mu)^T Lam (z - mu)``
    with ``z = (v, omega)`` the camera's velocities (docs/architecture.md "Conventions":
    ``v = (w x C - t) / s``, ``omega = -w / s``; ROS twist order). If ``add``, adds its
    Gauss-Newton terms ``scale2 Jz^T Lam Jz`` to H (12, 12) and ``scale2 Jz^T Lam (z - mu)`` to
    g (12,), Jz (6, 12) the Jacobian of z w.r.t. (delta, C, w, t). Returns the cost."""
    dz = model_twist(C, w, t, s) - mu
    Ld = Lam @ dz
    cost = 0.0
    for a in range(6):
        cost += dz[a] * Ld[a]
    if add:
        Jz = model_twist_jacobian(C, w, s)
        LJ = Lam @ Jz
        for i in range(3, 12):
            gi = 0.0
            for a in range(6):
                gi += Jz[a, i] * Ld[a]
            g[i] += scale2 * gi
            for j in range(3, 12):
                hij = 0.0
                for a in range(6):
                    hij += Jz[a, i] * LJ[a, j]
                H[i, j] += scale2 * hij
    return scale2 * cost


@kernel(inline=INLINE)
def _store_model(R, C, w, t, out):
    """The model part of the refinement kernels' output (:data:`OUT_R`, ..., :data:`OUT_T`)."""
    for i in range(3):
        for j in range(3):
            out[OUT_R + 3 * i + j] = R[i, j]
        out[OUT_C + i] = C[i]
        out[OUT_W + i] = w[i]
        out[OUT_T + i] = t[i]


@kernel(inline=INLINE)
def _apply_step(R, C, w, t, B, n_free):
    """The model (R, C, w, t) moved by the step ``B[:n_free, 0]`` over (rotation, C, w, t)
    (rotation on the left, ``expm([d]x) R``): new (R, C, w, t); w, t are kept (the same
    arrays) unless n_free = 12."""
    Rn = _rotate_left(B[0, 0], B[1, 0], B[2, 0], R)
    Cn = np.array([C[0] + B[3, 0], C[1] + B[4, 0], C[2] + B[5, 0]])
    if n_free == 12:
        return (
            Rn,
            Cn,
            np.array([w[0] + B[6, 0], w[1] + B[7, 0], w[2] + B[8, 0]]),
            np.array([t[0] + B[9, 0], t[1] + B[10, 0], t[2] + B[11, 0]]),
        )
    return Rn, Cn, w, t


@kernel
def _lm_refine(
    R,
    C,
    w,
    t,
    X,
    x,
    tau,
    k,
    n_free,
    cutoff,
    max_iterations,
    tol,
    want_cov,
    out,
    prior_on,
    mu,
    Lam,
    s,
    noise2,
    want_acc,
    mountings,
):
    """The whole Levenberg-Marquardt loop of :func:`refine_rs_pose` (arguments as there;
    n_free 12 or 6, the latter keeping w, t fixed; ``mountings`` None or the tuple of
    :func:`_evaluate`; inputs are not modified).

    With ``prior_on`` (and n_free 12) the cost gains the motion prior of
    :func:`_prior_terms` (mean ``mu`` (6,), information ``Lam`` (6, 6), ``s`` seconds per unit
    r) weighted by the image-noise variance ``noise2`` (normalized units^2; <= 0: estimated
    from the starting point's residuals), so that the cost is ``noise2`` times the negative
    log-posterior. Without it the computation is exactly the maximum-likelihood one.

    Writes R, C, w, t and, if ``want_cov``, the (12, 12) covariance, the data's (12, 12)
    ``J^T W J`` and (12,) gradient ``J^T W e`` (both without the prior) into out
    (:data:`OUT_SIZE`,), and if ``want_acc`` (with ``want_cov``) the (12, 6) ``J^T W D`` of
    :func:`_acceleration_block` at the result (out then (:data:`OUT_SIZE_ACC`,)); the layout
    of :data:`OUT_R`. Returns
    (sigma, success, nfev); sigma NaN unless ``want_cov``.
    """
    H = np.empty((12, 12))
    g = np.empty(12)
    A = np.empty((12, 12))
    B = np.empty((12, 12))
    L = np.empty((12, 12))
    M = np.empty((12, 12))
    Jt, G = _workspace(X.shape[0])
    m, cost, ss, n_in = _evaluate(R, C, w, t, X, x, tau, k, cutoff, Jt, mountings)
    current = True  # Jt holds the rows at (R, C, w, t) (not at a rejected step)
    use_prior = prior_on and n_free == 12
    sp2 = 0.0
    if use_prior:
        sp2 = noise2 if noise2 > 0.0 else untruncated_variance(ss / max(2 * n_in - n_free, 1), k)
        cost += _prior_terms(C, w, t, s, mu, Lam, sp2, H, g, False)
    if max_iterations > 0 or want_cov:
        _normal_matrix(Jt, m, G, H, g)
        if use_prior:
            _prior_terms(C, w, t, s, mu, Lam, sp2, H, g, True)
    nfev = 1
    success = False
    lam = 1e-4
    for it in range(max_iterations):
        # step = -(H + lam diag(diag(H) + 1e-12))^-1 g  (into B[:, 0])
        for i in range(n_free):
            for j in range(n_free):
                A[i, j] = H[i, j]
            A[i, i] = H[i, i] + lam * (H[i, i] + 1e-12)
            B[i, 0] = -g[i]
        if not solve_symmetric(A, B, n_free, np.int64(1), L, M):
            break
        # converged: the Gauss-Newton model's decrease of the cost sum rho (~ -g . step, the
        # cost being ~ cost + 2 g.d + d^T H d) is below tol / 10 of it (a step ~0.01 of a
        # standard deviation long on 500 points at tol 1e-6); the step is not evaluated
        pred = 0.0
        for i in range(n_free):
            pred -= g[i] * B[i, 0]
        if pred <= 0.1 * tol * cost:
            break
        Rn, Cn, wn, tn = _apply_step(R, C, w, t, B, n_free)
        mn, cn, ssn, n_inn = _evaluate(Rn, Cn, wn, tn, X, x, tau, k, cutoff, Jt, mountings)
        current = False
        if use_prior:
            cn += _prior_terms(Cn, wn, tn, s, mu, Lam, sp2, H, g, False)
        nfev += 1
        if cn <= cost:
            rel = (cost - cn) / (1e-300 if cost < 1e-300 else cost)
            R, C, w, t, cost, ss, n_in, m = Rn, Cn, wn, tn, cn, ssn, n_inn, mn
            current = True
            lam = max(lam / 10, 1e-12)
            success = True
            last = rel < tol or it == max_iterations - 1
            if want_cov or not last:  # H, g only where used (rejected: keep the old ones)
                _normal_matrix(Jt, m, G, H, g)
                if use_prior:
                    _prior_terms(C, w, t, s, mu, Lam, sp2, H, g, True)
            if rel < tol:
                break
        else:
            lam *= 10
            if lam > 1e8:
                break
    _store_model(R, C, w, t, out)
    sigma = np.nan
    if want_cov:
        sigma2 = untruncated_variance(ss / max(2 * n_in - n_free, 1), k)
        sigma = np.sqrt(sigma2)
        if use_prior:
            # H holds J^T W J + sp2 P at the accepted point (P the prior's Gauss-Newton
            # information): the data part goes out alone, and the posterior information
            # J^T W J / sigma2 + P is sigma2^-1 (J^T W J + sigma2 P)
            A[:, :] = 0.0
            gp = np.zeros(12)
            _prior_terms(C, w, t, s, mu, Lam, 1.0, A, gp, True)
            for i in range(12):
                out[OUT_GRAD + i] = g[i] - sp2 * gp[i]
                for j in range(12):
                    out[OUT_INFO + 12 * i + j] = H[i, j] - sp2 * A[i, j]
                    H[i, j] += (sigma2 - sp2) * A[i, j]
        else:
            for i in range(12):
                out[OUT_GRAD + i] = g[i] if i < n_free else 0.0
                for j in range(12):
                    out[OUT_INFO + 12 * i + j] = H[i, j] if i < n_free and j < n_free else 0.0
        for i in range(n_free):  # B = H^-1; NaN if H is exactly singular (np.linalg.inv)
            for j in range(n_free):
                B[i, j] = 1.0 if i == j else 0.0
        ok = solve_symmetric(H, B, n_free, n_free, L, M)
        for i in range(12):
            for j in range(12):
                if not ok:
                    out[OUT_COV + 12 * i + j] = np.nan
                elif i < n_free and j < n_free:
                    out[OUT_COV + 12 * i + j] = sigma2 * B[i, j]
                else:
                    out[OUT_COV + 12 * i + j] = 0.0
        if want_acc:
            if not current:  # (the last step was rejected: rows at the result again)
                m, _, _, _ = _evaluate(R, C, w, t, X, x, tau, k, cutoff, Jt, mountings)
            _acceleration_block(Jt, m, A, mountings is not None)
            for i in range(12):
                for j in range(6):
                    out[OUT_ACC + 6 * i + j] = A[i, j]
    return sigma, success, nfev


#: the numba dispatcher of :func:`refine_rs_pose`'s loop (:func:`_lm_refine`), for the
#: runtime's look into numba's cache (:func:`rs_localizer.runtime.warmup.rig_cached`)
LM_REFINE_KERNEL = _lm_refine


@kernel
def _posterior_step(R, C, w, t, Hd, gd, sigma2, s, mu, Lam, out):
    """One Gauss-Newton step of the maximum-a-posteriori cost of :func:`_lm_refine` from
    (R, C, w, t) with the data's normal equations there (``Hd`` (12, 12) ``J^T W J``, ``gd``
    (12,) ``J^T W e``) and the prior weighted by ``sigma2``; writes R, C, w, t, the posterior
    covariance ``sigma2 (Hd + sigma2 Jz^T Lam Jz)^-1`` (Jz at the new point) into out
    (:data:`OUT_INFO`,) as :func:`_lm_refine` does. Returns False if the system is singular."""
    H = Hd.copy()
    g = gd.copy()
    _prior_terms(C, w, t, s, mu, Lam, sigma2, H, g, True)
    B = np.empty((12, 12))
    L = np.empty((12, 12))
    M = np.empty((12, 12))
    for i in range(12):
        B[i, 0] = -g[i]
    # (sizes as int64, not literals: one compiled solve_symmetric for every caller)
    n12, one = np.int64(12), np.int64(1)
    if not solve_symmetric(H.copy(), B, n12, one, L, M):
        return False
    Rn, Cn, wn, tn = _apply_step(R, C, w, t, B, 12)
    H[:, :] = Hd
    _prior_terms(Cn, wn, tn, s, mu, Lam, sigma2, H, g, True)
    for i in range(12):
        for j in range(12):
            B[i, j] = 1.0 if i == j else 0.0
    if not solve_symmetric(H, B, n12, n12, L, M):
        return False
    _store_model(Rn, Cn, wn, tn, out)
    for i in range(12):
        for j in range(12):
            out[OUT_COV + 12 * i + j] = sigma2 * B[i, j]
    return True


@kernel
def exact_errors(R, C, w, t, X, x, tau, W=None):
    """(N,) image distances (normalized units) of the exact model at the measured capture
    times; ``inf`` for points behind the camera. Same model as :func:`exact_residuals`.
    ``W``: optional (N, 4) whitening of each point's error (:attr:`~.frame.Frame.W`; a
    (0, 4) array or None: none)."""
    # (an "is None" test on the argument itself: the branch that cannot be typed is pruned)
    if W is None:  # noqa: SIM108 (numba prunes this branch on a None argument)
        Wa = np.zeros((0, 4))
    else:
        Wa = W
    n = X.shape[0]
    out = np.empty(n)
    for i in range(n):
        q0 = R[0, 0] * X[i, 0] + R[0, 1] * X[i, 1] + R[0, 2] * X[i, 2]
        q1 = R[1, 0] * X[i, 0] + R[1, 1] * X[i, 1] + R[1, 2] * X[i, 2]
        q2 = R[2, 0] * X[i, 0] + R[2, 1] * X[i, 1] + R[2, 2] * X[i, 2]
        if Wa.shape[0] > 0:
            e2 = exact_error2_whitened(
                x[i, 0], x[i, 1], tau[i], q0, q1, q2, C[0], C[1], C[2],
                w[0], w[1], w[2], t[0], t[1], t[2], Wa[i, 0], Wa[i, 1], Wa[i, 2], Wa[i, 3],
            )  # fmt: skip
        else:
            e2 = exact_error2(
                x[i, 0], x[i, 1], tau[i], q0, q1, q2, C[0], C[1], C[2],
                w[0], w[1], w[2], t[0], t[1], t[2],
            )  # fmt: skip
        out[i] = np.sqrt(e2)
    return out


#: w = t = 0 of global-shutter refinement (read only by the kernel)
_ZERO3 = np.zeros(3)
#: the mean and information of no prior (read only by the kernel)
_NO_PRIOR_MEAN, _NO_PRIOR_INFORMATION = np.zeros(6), np.zeros((6, 6))


class RefineResult:
    """Refined (R, C, w, t), the (12, 12) covariance of (delta, C, w, t), residual sigma, cost.

    ``data_information``: (12, 12) ``J^T W J`` of the data alone at the optimum (normalized
    units; divide by ``sigma^2`` for the Fisher information), when a covariance was computed,
    else ``None``; ``data_gradient``: (12,) ``J^T W e`` of the data alone there (the same
    condition; ~0 at a converged maximum-likelihood optimum). ``acceleration_block``: (12, 6)
    ``J^T W D`` when asked for (:func:`refine_rs_pose`), else ``None``."""

    def __init__(
        self,
        R: np.ndarray,
        C: np.ndarray,
        w: np.ndarray,
        t: np.ndarray,
        covariance: np.ndarray | None,
        sigma: float,
        success: bool,
        nfev: int,
    ):
        self.R, self.C, self.w, self.t = R, C, w, t
        self.covariance, self.sigma, self.success, self.nfev = covariance, sigma, success, nfev
        self.data_information = None
        self.data_gradient = None
        self.acceleration_block = None


def _unpack(
    out: np.ndarray, sigma: float, success: bool, nfev: int, covariance: bool
) -> RefineResult:
    """A :class:`RefineResult` of the model and covariance in a kernel's ``out`` (views)."""
    cov = out[OUT_COV:OUT_INFO].reshape(12, 12) if covariance else None
    return RefineResult(
        out[OUT_R:OUT_C].reshape(3, 3),
        out[OUT_C:OUT_W],
        out[OUT_W:OUT_T],
        out[OUT_T:OUT_COV],
        cov,
        sigma,
        success,
        nfev,
    )


@dataclass(frozen=True)
class RefineSettings:
    """How :func:`refine_rs_pose` runs (the defaults: the estimator's final refinement).

    Attributes: as the arguments of the same names in :func:`refine_rs_pose`.
    """

    rolling_shutter: bool = True
    max_iterations: int = 10
    tol: float = 1e-10
    covariance: bool = True
    cutoff: float = np.inf
    seconds_per_unit_r: float = 0.0
    noise: float | None = None
    acceleration_block: bool = False


DEFAULT_REFINE = RefineSettings()


def refine_rs_pose(
    model: RSModel | tuple,
    X: np.ndarray,
    x: np.ndarray,
    tau: np.ndarray,
    loss_scale: float,
    settings: RefineSettings = DEFAULT_REFINE,
    prior: MotionPrior | None = None,
    mountings: Mountings | None = None,
) -> RefineResult:
    """Robust (Huber) Levenberg-Marquardt refinement of one pose on the exact model, of one
    camera or of a rig of cameras (``mountings``).

    Args:
        model: the initial :class:`~rs_localizer.pose.RSModel` ``(R0, C0, w0, t0)`` (or the
            same 4-tuple): rotation (3, 3), translation, velocities per unit r (3,).
        X: (N, 3) world points; x: (N, 2) normalized observations; tau: (N,) ``r_i - r0``.
        loss_scale: Huber threshold in normalized units (the inlier threshold).
        settings: a :class:`RefineSettings`, its fields (all but ``prior``) as follows.
        rolling_shutter: False keeps ``w = t = 0`` fixed (global-shutter refinement, P3P).
        max_iterations: LM iterations; tol: stop when the relative cost decrease is below it,
            or when the Gauss-Newton model predicts a decrease below ``tol / 10`` for the next
            step (that step is then not taken).
        covariance: compute the covariance (skipped inside RANSAC's local optimization).
        cutoff: points farther than this (normalized units) are ignored at each iteration
            (truncated loss; lets RANSAC's local optimization run on all points).
        prior (argument): a :class:`~rs_localizer.estimation.prior.MotionPrior` on the camera's
            velocities (maximum a posteriori instead of maximum likelihood), or
            ``None``. Ignored for global-shutter refinement or ``seconds_per_unit_r <= 0``.
        seconds_per_unit_r: the camera's capture time per unit r (s), to express the prior on
            the model's (w, t) (docs/architecture.md "Conventions").
        noise: image noise sigma (normalized units) that weighs the prior against the data;
            ``None``: estimated from the residuals at the start
            (``sum e^2 / (2 n - 12)`` over the points inside ``loss_scale``, corrected for
            that truncation like the covariance's sigma).
        acceleration_block: also return ``J^T W D`` (12, 6) at the result (with
            ``covariance``; rolling shutter), D the columns of an in-readout acceleration:
            what :func:`~rs_localizer.estimation.sensitivity.acceleration_sensitivity` needs,
            from the refinement's last Jacobian instead of another pass over the points.
        mountings (argument): ``None`` (one camera) or a :class:`Mountings` (or the same
            checked once, :class:`KernelMountings`): the model is
            then a rig's, each observation seen by its camera through that camera's mounting
            (``tau`` each observation's own capture time, e.g. in s with
            ``seconds_per_unit_r = 1``), its error scaled by its ``scale``; ``loss_scale``,
            ``cutoff``, ``noise``, sigma and the normal equations are in those units (px with
            the focal lengths as ``scale``). The same loop, prior and covariance; only the
            points' Jacobian rows differ (:func:`point_rows_mounted`).
    Returns:
        :class:`RefineResult`; the covariance is ``sigma^2 H^-1`` over (delta, C, w, t) at the
        optimum (zero rows/columns for fixed parameters), ``sigma^2`` the residual variance of
        the points inside ``loss_scale``, corrected for that truncation
        (:func:`untruncated_variance`). With a prior, ``H = J^T W J + sigma^2 Jz^T P Jz``
        (P the prior information, Jz the Jacobian of the velocities): the posterior covariance.

    Matches SciPy's ``least_squares(loss="huber")`` on the same problem (see the tests). The
    loop runs in numba (:func:`_lm_refine`); measured on one core: ~70 us for 150 points and
    ~130 us for 300 with 6 evaluations (~20 us per evaluation of 300 points). The returned
    arrays are views of one buffer.

    Raises:
        ValueError: ``mountings`` whose shapes do not match the N observations, or a camera
            index out of range.
    """
    R0, C0, w0, t0 = model
    rolling_shutter, max_iterations, tol = (
        settings.rolling_shutter,
        settings.max_iterations,
        settings.tol,
    )
    covariance, cutoff, noise = settings.covariance, settings.cutoff, settings.noise
    seconds_per_unit_r, acceleration_block = (
        settings.seconds_per_unit_r,
        settings.acceleration_block,
    )
    f64 = np.float64
    nf = 12 if rolling_shutter else 6
    want_acc = bool(acceleration_block and covariance and rolling_shutter)
    out = np.empty(OUT_SIZE_ACC if want_acc else OUT_SIZE)
    if prior is None or not rolling_shutter or not seconds_per_unit_r > 0:
        on, mu, Lam = False, _NO_PRIOR_MEAN, _NO_PRIOR_INFORMATION  # (prior_arrays(None)'s)
    else:
        on, mu, Lam = prior_arrays(prior)
    noise2 = -1.0 if noise is None else float(noise) ** 2
    if mountings is None:
        views = None
    elif isinstance(mountings, KernelMountings):
        if mountings.n != len(X):
            raise ValueError(f"mountings: checked for {mountings.n} observations, got {len(X)}")
        views = mountings.views
    else:
        views = _checked_mountings(mountings, len(X))
    sigma, success, nfev = _lm_refine(
        np.ascontiguousarray(R0, dtype=f64),
        np.ascontiguousarray(C0, dtype=f64),
        np.ascontiguousarray(w0, dtype=f64) if rolling_shutter else _ZERO3,
        np.ascontiguousarray(t0, dtype=f64) if rolling_shutter else _ZERO3,
        np.ascontiguousarray(X, dtype=f64),
        np.ascontiguousarray(x, dtype=f64),
        np.ascontiguousarray(tau, dtype=f64),
        float(loss_scale),
        nf,
        float(cutoff),
        int(max_iterations),
        float(tol),
        bool(covariance),
        out,
        on,
        mu,
        Lam,
        float(seconds_per_unit_r) if on else 1.0,
        noise2,
        want_acc,
        views,
    )
    res = _unpack(out, float(sigma), success, nfev, covariance)
    if covariance:
        res.data_information = out[OUT_INFO:OUT_GRAD].reshape(12, 12)
        res.data_gradient = out[OUT_GRAD:OUT_ACC]
    if want_acc:
        res.acceleration_block = out[OUT_ACC:OUT_SIZE_ACC].reshape(12, 6)
    return res


def posterior_step(
    ml: RefineResult, prior: MotionPrior, seconds_per_unit_r: float
) -> RefineResult | None:
    """The maximum-a-posteriori estimate under ``prior`` from a maximum-likelihood
    :func:`refine_rs_pose` result (rolling shutter, with covariance), in closed form: one
    Gauss-Newton step of the MAP cost from the ML optimum with the data's normal equations
    there (``ml.data_information``, ``ml.data_gradient``), the prior weighted by ``ml.sigma``
    as :func:`refine_rs_pose` weighs it when ``noise`` is ``None``.

    At the ML optimum the data's gradient vanishes, so this is the Gaussian product of the ML
    estimate and the prior (linearized where the velocities ``(v, omega)`` depend on
    (C, w, t)). Converging the MAP cost with :func:`refine_rs_pose` instead costs three more
    passes over the points and lands within 6 % of the prior's shift of this (a prior as
    informative as the data, 0.5-2 std off, ``test_refine``; the truncated loss re-selects
    points near its threshold at the new estimate); the default prior moves far less. The
    covariance keeps the ML estimate's noise sigma (the residuals at the MAP point, pulled off
    the data by the prior, would inflate it).

    Args:
        ml: a rolling-shutter :class:`RefineResult` with covariance (``data_information``).
        prior: an enabled :class:`~rs_localizer.estimation.prior.MotionPrior`.
        seconds_per_unit_r: the camera's capture time per unit r (s), > 0.
    Returns:
        :class:`RefineResult` with the MAP (R, C, w, t) and posterior covariance; ``sigma``,
        ``data_information``, ``data_gradient`` (at the ML point) and ``acceleration_block``
        are the ML result's. ``None`` if the prior is disabled, ``ml`` carries no normal
        equations or a system is singular.
    Raises:
        ValueError: if ``seconds_per_unit_r <= 0``.
    """
    if not seconds_per_unit_r > 0:
        raise ValueError(f"seconds_per_unit_r must be > 0, got {seconds_per_unit_r}")
    on, mu, Lam = prior_arrays(prior)
    if not on or ml.data_information is None or not np.isfinite(ml.sigma):
        return None
    f64 = np.float64
    out = np.empty(OUT_INFO)
    if not _posterior_step(
        np.ascontiguousarray(ml.R, dtype=f64),
        np.ascontiguousarray(ml.C, dtype=f64),
        np.ascontiguousarray(ml.w, dtype=f64),
        np.ascontiguousarray(ml.t, dtype=f64),
        np.ascontiguousarray(ml.data_information, dtype=f64),
        np.ascontiguousarray(ml.data_gradient, dtype=f64),
        float(ml.sigma) ** 2,
        float(seconds_per_unit_r),
        mu,
        Lam,
        out,
    ):
        return None
    res = _unpack(out, ml.sigma, ml.success, ml.nfev, True)
    res.data_information = ml.data_information
    res.data_gradient = ml.data_gradient
    res.acceleration_block = ml.acceleration_block
    return res


def prior_residuals(
    theta: np.ndarray, mean: np.ndarray, U: np.ndarray, s: float, scale: float
) -> tuple[np.ndarray, np.ndarray]:
    """Residuals of a Gaussian motion prior, for a least-squares fit of the exact model.

    Args:
        theta: (12,) the model's parameters ``(delta, C, w, t)`` (docs/architecture.md
            "Conventions"; ``delta`` the rotation increment, unused here).
        mean: (6,) the prior's mean of the camera's velocities ``z = (v, omega)`` (m/s, rad/s).
        U: (6, 6) a square root of the prior's information matrix (``U^T U = Lambda``).
        s: seconds per unit of the row coordinate (the model's ``w`` and ``t`` are per unit).
        scale: the factor that puts the prior in the units of the image residuals
            (1 / the image noise those residuals are divided by).
    Returns:
        ``(r, J)``: (6,) whitened residuals ``scale U (z - mean)`` and their (6, 12) Jacobian
        with respect to ``theta``.
    """
    C, w, t = theta[3:6], theta[6:9], theta[9:12]
    z = model_twist.py_func(C, w, t, s)
    Jz = model_twist_jacobian.py_func(C, w, s)
    return scale * U @ (z - mean), scale * U @ Jz


@dataclass
class ExactModelFit:
    """What :func:`least_squares_exact_model` returns.

    Attributes:
        result: SciPy's ``OptimizeResult`` (``x`` the free parameters, ``fun`` the residuals:
            the (2 M,) weighted image rows, then the prior's 6 rows if any).
        theta: (12,) the fitted ``(delta, C, w, t)`` (the parameters not fitted as given).
        jac: the residuals' Jacobian at free parameters ``p`` (n_free,): (rows, n_free).
    """

    result: Any
    theta: np.ndarray
    jac: Callable[[np.ndarray], np.ndarray]


def least_squares_exact_model(
    R0: np.ndarray,
    theta0: np.ndarray,
    n_free: int,
    X: np.ndarray,
    x: np.ndarray,
    tau: np.ndarray,
    prior: MotionPrior | None,
    seconds_per_unit_r: float,
    noise: float,
    row_weights: np.ndarray | None = None,
    mountings: Mountings | None = None,
    **options: object,
) -> ExactModelFit:
    """The exact model (paper eq. 4) fitted by SciPy ``least_squares`` (trust region,
    ``x_scale="jac"``) from ``theta0``, the first ``n_free`` parameters free (12: rolling
    shutter; 6: rotation and centre).

    Args:
        R0: (3, 3) the rotation ``delta`` is applied to (camera from world).
        theta0: (12,) the starting ``(delta, C, w, t)``; C in m, w in rad and t in m per unit
            of the row coordinate.
        n_free: 6 or 12.
        X: (M, 3) world points (m). x: (M, 2) normalized image points. tau: (M,) their row
            coordinates relative to the reference row.
        prior: a motion prior (its six rows ``noise * U (z - mean)``, :func:`prior_residuals`,
            join the residuals), or None.
        seconds_per_unit_r: seconds per unit of the row coordinate (the prior's time scale).
        noise: the image noise the prior's rows are scaled by (normalized units).
        row_weights: optional (2 M,) factors of the image residual rows (not the prior's).
        mountings: optional :class:`Mountings` (a rig's observations, :func:`exact_residuals`).
        **options: passed on to ``least_squares`` (``loss``, ``f_scale``, tolerances).
    Returns:
        :class:`ExactModelFit`.
    """
    free = np.arange(n_free)
    on, mean, Lam = prior_arrays(prior)
    ev, V = np.linalg.eigh(Lam)
    U = (V * np.sqrt(np.clip(ev, 0.0, None))).T

    def full(p):
        th = theta0.copy()
        th[free] = p
        return th

    def fun(p):
        r = exact_residuals(full(p), R0, X, x, tau, mountings)
        if row_weights is not None:
            r = row_weights * r
        if on:
            r = np.concatenate([r, prior_residuals(full(p), mean, U, seconds_per_unit_r, noise)[0]])
        return r

    def jac(p):
        J = exact_jacobian(full(p), R0, X, x, tau, mountings)
        if row_weights is not None:
            J = row_weights[:, None] * J
        if on:
            J = np.concatenate([J, prior_residuals(full(p), mean, U, seconds_per_unit_r, noise)[1]])
        return J[:, free]

    from scipy.optimize import least_squares  # (here: 0.2 s of the node's start-up otherwise)

    res = least_squares(fun, theta0[free], jac=jac, method="trf", x_scale="jac", **options)
    return ExactModelFit(res, full(res.x), jac)


def refine_rs_pose_scipy(
    R0: np.ndarray,
    C0: np.ndarray,
    w0: np.ndarray,
    t0: np.ndarray,
    X: np.ndarray,
    x: np.ndarray,
    tau: np.ndarray,
    loss_scale: float,
    rolling_shutter: bool = True,
    prior: MotionPrior | None = None,
    seconds_per_unit_r: float = 0.0,
    noise: float = 0.0,
) -> RefineResult:
    """The same problem solved by SciPy ``least_squares`` (Huber loss, trust region).

    A reference for tests and benchmarks; :func:`refine_rs_pose` is the one the estimator uses.
    With a ``prior`` (rolling shutter only) the residuals gain six rows
    ``noise * U (z - mean)``, ``U^T U`` the prior information (the MAP problem of
    :func:`refine_rs_pose` with a given ``noise``; SciPy's Huber loss acts on every residual
    component, so compare with a ``loss_scale`` the residuals stay inside).
    """
    n_free = 12 if rolling_shutter else 6
    theta0 = np.concatenate(
        [
            np.zeros(3),
            C0,
            w0 if rolling_shutter else np.zeros(3),
            t0 if rolling_shutter else np.zeros(3),
        ]
    )
    fit = least_squares_exact_model(
        R0,
        theta0,
        n_free,
        X,
        x,
        tau,
        prior if rolling_shutter else None,
        seconds_per_unit_r,
        noise,
        loss="huber",
        f_scale=loss_scale,
        xtol=1e-12,
        ftol=1e-12,
        gtol=1e-12,
    )
    th = fit.theta
    return RefineResult(
        rotvec_to_matrix(th[:3]) @ R0,
        th[3:6],
        th[6:9],
        th[9:12],
        None,
        float("nan"),
        bool(fit.result.success),
        int(fit.result.nfev),
    )


#: fits of :func:`refine_rs_pose_numpy`, each on the points within the cutoff of the last
#: model (the compiled refinement selects them again at each iteration)
NUMPY_PASSES = 2
#: reweighting rounds of a maximum a posteriori fit of :func:`refine_rs_pose_numpy`
NUMPY_MAP_ROUNDS = 3


def _errors_numpy(theta, R0, X, x, tau, mountings) -> np.ndarray:
    """(N,) image errors of the exact model ``theta`` about ``R0`` (normalized units, or the
    ``mountings``' scaled units), ``inf`` behind the camera (:func:`exact_residuals`)."""
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        r, z = _residuals_and_depths(theta, R0, X, x, tau, mountings)
        e = np.linalg.norm(r, axis=1)
    e[~(z > 1e-9)] = np.inf
    return e


def image_variance(inside: np.ndarray, k: float, free: int, compiled: bool = True) -> float:
    """The per-axis image variance of a model's errors ``inside`` (those within the threshold
    ``k``, same units), ``2 n - free`` degrees of freedom, corrected for the threshold's
    truncation (:func:`untruncated_variance`; ``compiled=False``: in Python)."""
    variance = untruncated_variance if compiled else untruncated_variance.py_func
    # (np.add.reduce: np.sum's pairwise sum of the same squares, without its wrapper)
    return variance(float(np.add.reduce(inside * inside)) / max(2 * len(inside) - free, 1), k)


def refine_backend(compiled: bool) -> Callable[..., RefineResult]:
    """:func:`refine_rs_pose`, or with ``compiled`` False its NumPy and SciPy form
    :func:`refine_rs_pose_numpy` (the same arguments and result)."""
    return refine_rs_pose if compiled else refine_rs_pose_numpy


def exact_rows(
    model: RSModel | tuple,
    X: np.ndarray,
    x: np.ndarray,
    tau: np.ndarray,
    k: float,
    mountings: Mountings | None = None,
) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`exact_residuals` (2N,) and :func:`exact_jacobian` (2N, 12) of ``model``
    ``(R, C, w, t)`` at N points in front of their cameras, computed by the refinement's own
    compiled kernel (its rows scaled by the square root of each point's Huber weight at scale
    ``k``, then unscaled), with ``mountings`` as there; None where a point is behind its
    camera (the kernel skips it)."""
    R, C, w, t = (np.ascontiguousarray(a, dtype=np.float64) for a in model)
    f = np.float64
    X, x, tau = (np.ascontiguousarray(a, dtype=f) for a in (X, x, tau))
    n = len(X)
    km = None if mountings is None else kernel_mountings(mountings, n).views
    Jt, _ = _workspace(n)
    m = _evaluate(R, C, w, t, X, x, tau, float(k), np.inf, Jt, km)[0]
    if m != n:
        return None
    rows = Jt[:13, : 2 * n].T
    q = np.hypot(rows[0::2, 12], rows[1::2, 12])  # (sqrt(weight) times each point's error)
    s = np.repeat(np.where(q <= k, 1.0, q / k), 2)  # (1 / sqrt(weight))
    return rows[:, 12] * s, rows[:, :12] * s[:, None]


def huber_weights(e: np.ndarray, k: float) -> np.ndarray:
    """(N,) Huber weights of errors ``e`` at scale ``k``: 1 inside, ``k / e`` beyond."""
    return np.where(e <= k, 1.0, k / np.maximum(e, k))


def huber_fit_numpy(
    R0: np.ndarray,
    theta0: np.ndarray,
    free: int,
    X: np.ndarray,
    x: np.ndarray,
    tau: np.ndarray,
    prior: MotionPrior | None,
    spr: float,
    noise: float,
    k: float,
    mountings: Mountings | None = None,
    max_nfev: int | None = None,
    rounds: int = NUMPY_MAP_ROUNDS,
) -> np.ndarray:
    """One robust fit of the exact model in SciPy (:func:`least_squares_exact_model`, the
    arguments of the same names): the Huber loss at ``k`` on the image rows; with a
    ``prior`` instead ``rounds`` rounds of iteratively reweighted least squares (each point's
    rows weighed by the square root of its Huber weight at the round's start, no loss), so
    that the prior's rows stay quadratic as in the compiled refinement (SciPy's loss would act
    on them too and soften a gyro's prior where the image disagrees with it). Returns theta
    (12,) about ``R0``."""
    if not prior_arrays(prior)[0]:
        return least_squares_exact_model(
            R0, theta0, free, X, x, tau, None, spr, noise, mountings=mountings, loss="huber",
            f_scale=k, max_nfev=max_nfev,
        ).theta  # fmt: skip
    theta = theta0
    for _ in range(rounds):
        e = _errors_numpy(theta, R0, X, x, tau, mountings)
        wt = np.sqrt(huber_weights(e, k))
        theta = least_squares_exact_model(
            R0, theta, free, X, x, tau, prior, spr, noise, row_weights=np.repeat(wt, 2),
            mountings=mountings, max_nfev=max_nfev,
        ).theta  # fmt: skip
    return theta


def refine_rs_pose_numpy(
    model: RSModel | tuple,
    X: np.ndarray,
    x: np.ndarray,
    tau: np.ndarray,
    loss_scale: float,
    settings: RefineSettings = DEFAULT_REFINE,
    prior: MotionPrior | None = None,
    mountings: Mountings | None = None,
) -> RefineResult:
    """:func:`refine_rs_pose` in NumPy and SciPy (nothing compiles): the same arguments, the
    same exact model (with ``mountings``, a rig's) and the same outputs, for the estimator's
    ``"numpy"`` implementation.

    The fit is SciPy's ``least_squares`` (:func:`least_squares_exact_model`, analytic
    Jacobian) with the Huber loss at ``loss_scale`` on the points within ``settings.cutoff``
    of the model (with a prior: reweighted least squares, :func:`huber_fit_numpy`), at most
    ``max_iterations + 1`` evaluations, up to :data:`NUMPY_PASSES` times while the points
    within the cutoff change (the compiled loop selects them at every iteration); the prior's
    rows are weighed by ``settings.noise`` (None: estimated from the starting model's errors
    within ``loss_scale``, as the compiled refinement does). ``nfev`` is not counted. The model
    stays as given when fewer than 7 points are within the cutoff or a fit fails
    (``max_iterations=0``: no fit, the covariance at the model). With ``covariance``: at the
    result, over the points within the cutoff, ``H = J^T W J`` (``W`` the Huber weights,
    ``J`` :func:`exact_jacobian`, columns beyond the free parameters zero), ``sigma^2`` the
    per-axis variance of the errors within ``loss_scale`` (``2 n - free`` degrees of freedom,
    corrected for the truncation, :func:`untruncated_variance`), the covariance
    ``sigma^2 (H + sigma^2 Jz^T P Jz)^-1`` with a prior (``sigma^2 H^-1`` without, ``None``
    if singular) and ``J^T W D`` with ``acceleration_block`` (``D`` ``tau / 2`` times the
    ``w`` and ``t`` columns of ``J``)."""
    R, C, w, t = (np.array(a, dtype=float) for a in model)
    rolling, k = settings.rolling_shutter, float(loss_scale)
    free = 12 if rolling else 6
    if not rolling:
        w, t = np.zeros(3), np.zeros(3)
    spr = float(settings.seconds_per_unit_r)
    motion = prior if rolling and spr > 0 else None
    cut, max_iterations = float(settings.cutoff), int(settings.max_iterations)
    noise = settings.noise
    if noise is None and prior_arrays(motion)[0]:  # (from the start's errors, as compiled)
        e0 = _errors_numpy(np.concatenate([np.zeros(3), C, w, t]), R, X, x, tau, mountings)
        noise = np.sqrt(image_variance(e0[e0 <= k], k, free, compiled=False))
    noise = 0.0 if noise is None else float(noise)
    near, success = None, True
    for _ in range(NUMPY_PASSES if max_iterations > 0 else 0):
        theta = np.concatenate([np.zeros(3), C, w, t])
        sel = _errors_numpy(theta, R, X, x, tau, mountings) < cut
        if np.count_nonzero(sel) < 7 or (near is not None and np.array_equal(sel, near)):
            break
        near = sel
        try:
            th = huber_fit_numpy(
                R, theta, free, X[near], x[near], tau[near], motion, spr, noise, k,
                None if mountings is None else mountings.take(near), max_iterations + 1,
            )  # fmt: skip
        except (ValueError, np.linalg.LinAlgError):
            success = False
            break
        if not np.isfinite(th).all():
            success = False
            break
        R, C, w, t = rotvec_to_matrix(th[:3]) @ R, th[3:6].copy(), th[6:9].copy(), th[9:12].copy()
    res = RefineResult(R, C, w, t, None, float("nan"), success, 0)
    theta = np.concatenate([np.zeros(3), C, w, t])
    e = _errors_numpy(theta, R, X, x, tau, mountings)
    idx = np.flatnonzero(e < cut)
    if not settings.covariance or 2 * len(idx) < free:  # (too few rows: no covariance)
        return res
    sub = None if mountings is None else mountings.take(idx)
    J = exact_jacobian(theta, R, X[idx], x[idx], tau[idx], sub)
    J[:, free:] = 0.0
    ei = e[idx]
    WJ = np.repeat(huber_weights(ei, k), 2)[:, None] * J
    sigma2 = image_variance(ei[ei <= k], k, free, compiled=False)
    res.sigma = float(np.sqrt(sigma2))
    res.data_information = J.T @ WJ
    res.data_gradient = WJ.T @ exact_residuals(theta, R, X[idx], x[idx], tau[idx], sub)
    if settings.acceleration_block and rolling:
        res.acceleration_block = WJ.T @ (0.5 * np.repeat(tau[idx], 2)[:, None] * J[:, 6:12])
    H = res.data_information[:free, :free].copy()
    on, _, Lam = prior_arrays(motion)
    if on:
        Jz = model_twist_jacobian.py_func(C, w, spr)
        H += sigma2 * (Jz.T @ Lam @ Jz)[:free, :free]
    try:
        cov = np.zeros((12, 12))
        cov[:free, :free] = sigma2 * np.linalg.inv(H)
        res.covariance = cov if np.isfinite(cov).all() else None
    except np.linalg.LinAlgError:
        pass
    return res
