"""gR6P_{v,C,w,t}^{[v]x}: the linear iterative solver of paper sec. 3.3 for a rig of RS cameras.

A rig carries M rolling-shutter cameras. Camera ``c`` is mounted at a known rotation ``R_c``
and offset ``c_c`` (rig -> camera: ``x_cam = R_c x_rig + c_c``). The rig moves with the
constant-velocity model of paper eq. 5, written in **time** instead of one camera's RS
coordinate: with ``tau`` the time of an observation relative to the rig's reference time,
the rig frame at that time sees a world point X at
``p(X, tau) = (I + tau [w]x)(I + [v]x) X + C + tau t``, and camera ``c`` observes it at ``x``::

    lambda [x; 1] = R_c p(X, tau) + c_c
                  = R_c ((I + tau [w]x)(I + [v]x) X + C + tau t) + c_c            (eq. 5, rig)

Unknowns (12, as R6P): ``v`` (rad, the linearized rig rotation at the reference time), ``C``
(rig translation at the reference time, world units), ``w`` (rad per unit of tau), ``t``
(world units per unit of tau).

Time. Each camera has its own line delay, readout direction and stamp, so one camera's RS
coordinate ``r`` is not a common clock. An observation at RS coordinate ``r`` of camera ``c``
(``r`` as in the single-camera solvers: the normalized image coordinate along the camera's
readout, e.g. ``x[:, 1]``) was taken at::

    tau = (stamp_c - t_ref) + line_delay_c * (r - r0_c)

with ``stamp_c`` the time of the camera's reference coordinate ``r0_c`` in that frame,
``t_ref`` the rig's reference time and ``line_delay_c`` the camera's readout time per unit of
``r`` (in seconds: the readout time of one pixel row times the focal length in pixels). The
solver takes ``tau`` itself, in any time unit; ``w`` and ``t`` come out per that unit (seconds
give rad/s and world units/s). Gaussian elimination with partial pivoting and the Householder
least squares do not depend on column scaling beyond the rank tolerance, so seconds
(tau ~ 1e-2) work as well as the single camera's ``r`` (tau ~ 1).

Linearization: :mod:`~.r6p_1lin`'s (eq. 6 of sec. 3.3). Each iteration fixes ``v_hat`` in the
one bilinear term, ``tau [w]x [v_hat]x X = tau w x Z`` with ``Z = X + v_hat x X`` (``v_init``,
default 0, then the previous estimate of ``v``); a fixed point satisfies the rig eq. 5 exactly.

Rows per point. lambda is eliminated with the camera's ray: the rows ``E`` (2, 3) of
``[x_hat]x`` (``E1 = [0, -1, y]``, ``E2 = [1, 0, -x]``, see ``_linear``) give
``E . (R_c p + c_c) = 0``, i.e. ``F . p = -E . c_c`` with ``F = R_c^T E`` (the elimination rows
turned into the rig frame). With the triple product ``F . (a x b) = a . (b x F)``, each row
``F`` of point i gives one linear equation in ``u = [v; C; w; t]``::

    [X x F | F | tau (Z x F) | tau F] . u = -F . X - E . c_c

so N points give 2N equations; a camera at identity mounting (``R_c = I``, ``c_c = 0``) with
``tau = r - r0`` gives exactly the rows of :func:`~.r6p_1lin.r6p_1lin`.

Minimal number of points. 12 unknowns, 2 equations per point: 6 points in total, spread over
the cameras in any way (all 6 in one camera is R6P_{v,C,w,t}^{[v]x} itself). The points must
not all share one tau (then ``w`` and ``t`` only appear as ``tau w``, ``tau t`` next to ``v``
and ``C``: rank 6): a global-shutter rig (every tau equal) is the generalized P3P problem, not
this solver's.
"""

from __future__ import annotations

import numpy as np

from ..geometry import cross
from ._common import RSBatch, RSSolution, check_batch, check_inputs
from ._linear import PATIENCE, lstsq_stack
from .r6p_1lin import run_mounted, solve_mounted

__all__ = ["gr6p_1lin", "gr6p_1lin_batch"]

NAME = "gr6p_1lin"
MIN_POINTS = 6


@np.errstate(invalid="ignore", over="ignore", divide="ignore")
def _solve_numpy(
    x, X, tau, cam, Rm, cm, iterations, tol, v_init, P, q, use_prior, out, ok, its, err
):
    """:func:`~.r6p_1lin.solve_mounted` in NumPy for all K problems at once (nothing
    compiles): the same arguments, rows, iteration, stopping rule (converged, or
    ``PATIENCE`` steps without a new best by more than ``tol``) and best iterate, the linear
    solves by :func:`~._linear.lstsq_stack`."""
    K, N = x.shape[0], x.shape[1]
    Rc, cc = Rm[cam], cm[cam]  # (K, N, 3, 3), (K, N, 3)
    xi, yi = x[..., 0:1], x[..., 1:2]
    F = np.empty((K, N, 2, 3))  # the elimination rows in the rig frame, R_c^T E
    F[..., 0, :] = -Rc[..., 1, :] + yi * Rc[..., 2, :]
    F[..., 1, :] = Rc[..., 0, :] - xi * Rc[..., 2, :]
    ec = np.stack(
        [-cc[..., 1] + yi[..., 0] * cc[..., 2], cc[..., 0] - xi[..., 0] * cc[..., 2]], axis=-1
    )
    rows = np.empty((K, N, 2, 12))
    rows[..., 0:3] = cross(X[:, :, None, :], F)
    rows[..., 3:6] = F
    te = tau[:, :, None, None]
    rows[..., 9:12] = te * F
    b = (-np.einsum("knqj,knj->knq", F, X) - ec).reshape(K, 2 * N)
    if use_prior:
        extra = np.zeros((K, 6, 12))
        extra[:, :, 6:12] = P
        b = np.concatenate([b, q], axis=1)
    vhat = np.array(v_init, dtype=float)
    err[:] = np.inf
    stale, active = np.zeros(K, dtype=np.int64), np.ones(K, dtype=bool)
    for it in range(iterations):
        k = np.flatnonzero(active)
        if len(k) == 0:
            break
        Z = X[k] + cross(vhat[k][:, None, :], X[k])
        rows[k, :, :, 6:9] = te[k] * cross(Z[:, :, None, :], F[k])
        A = rows[k].reshape(len(k), 2 * N, 12)
        if use_prior:
            A = np.concatenate([A, extra[k]], axis=1)
        u, good = lstsq_stack(A, b[k])
        active[k[~good]] = False  # (rank loss: the compiled solver stops there)
        k, u = k[good], u[good]
        # the RMS algebraic error of the rig eq. 5 at the iterate (mounted_error)
        v, C, w, t = u[:, None, 0:3], u[:, None, 3:6], u[:, None, 6:9], u[:, None, 9:12]
        y = X[k] + cross(v, X[k])
        p = y + tau[k][..., None] * (cross(w, y) + t) + C
        qc = np.einsum("knij,knj->kni", Rc[k], p) + cc[k]
        e1 = -qc[..., 1] + x[k, :, 1] * qc[..., 2]
        e2 = qc[..., 0] - x[k, :, 0] * qc[..., 2]
        e = np.sqrt(np.mean(e1 * e1 + e2 * e2, axis=1))
        its[k] = it + 1
        stale[k] = np.where(e < err[k] - tol, 0, stale[k] + 1)
        better = e < err[k]
        out[k[better]], err[k[better]], ok[k[better]] = u[better], e[better], True
        vhat[k] = u[:, 0:3]
        active[k[(e <= tol) | (stale[k] >= PATIENCE)]] = False


def _check(x, X, tau, cam, R_mount, c_mount, batched):
    """Shapes (N or K, N) of the inputs (a camera's solver's checks,
    :func:`~._common.check_inputs` with ``tau`` as its ``r``, every value finite, or
    :func:`~._common.check_batch`), the mountings (M, 3, 3), (M, 3) finite, camera indices in
    range; float64 (int64 for ``cam``) contiguous copies."""
    check = check_batch if batched else check_inputs
    x, X, tau, _ = check(x, X, np.asarray(tau, dtype=np.float64), 0.0, MIN_POINTS, NAME)
    lead = x.shape[:-1]
    Rm = np.ascontiguousarray(R_mount, dtype=np.float64)
    cm = np.ascontiguousarray(c_mount, dtype=np.float64)
    if Rm.ndim != 3 or Rm.shape[1:] != (3, 3):
        raise ValueError(f"{NAME}: R_mount must have shape (M, 3, 3), got {Rm.shape}")
    if cm.shape != (len(Rm), 3):
        raise ValueError(f"{NAME}: c_mount must have shape ({len(Rm)}, 3), got {cm.shape}")
    if not (np.isfinite(Rm).all() and np.isfinite(cm).all()):
        raise ValueError(f"{NAME}: mountings contain NaN or inf")
    cam = np.asarray(np.broadcast_to(np.asarray(cam), lead) if np.ndim(cam) == 0 else cam)
    if cam.size and not np.issubdtype(cam.dtype, np.integer):
        raise ValueError(f"{NAME}: cam must hold integer camera indices, got {cam.dtype}")
    cam = np.ascontiguousarray(cam, dtype=np.int64)
    if cam.size and (cam.min() < 0 or cam.max() >= len(Rm)):
        raise ValueError(f"{NAME}: cam indices must lie in [0, {len(Rm)}), got {cam.min()}..")
    if cam.shape != lead:
        raise ValueError(f"{NAME}: cam must have shape {lead}, got {cam.shape}")
    return x, X, tau, cam, Rm, cm


def gr6p_1lin(
    x: np.ndarray,
    X: np.ndarray,
    tau: np.ndarray,
    cam: np.ndarray,
    R_mount: np.ndarray,
    c_mount: np.ndarray,
    iterations: int = 5,
    v_init: np.ndarray | None = None,
    tol: float = 1e-12,
) -> RSSolution:
    """gR6P_{v,C,w,t}^{[v]x}: linear iterative absolute pose of a rig of RS cameras (paper
    sec. 3.3, eq. 5-6, generalized in the module docstring).

    Args:
        x: (N, 2) calibrated (undistorted, normalized) image points, each in its own camera;
            N >= 6 over all cameras, N > 6 solves each iteration in the least-squares sense.
        X: (N, 3) world points (any unit; C and t come out in it).
        tau: (N,) time of each observation relative to the rig's reference time, any time unit
            (module docstring, "Time": from each camera's RS coordinates, line delay and
            stamp); not all equal.
        cam: (N,) int index of the camera that observed each point (or one int for all).
        R_mount: (M, 3, 3) camera rotations on the rig (``x_cam = R_c x_rig + c_c``).
        c_mount: (M, 3) camera offsets ``c_c`` (world units).
        iterations: maximum linear iterations (each one 2N x 12 system).
        v_init: (3,) initial ``v_hat`` for the nonlinear term (default zeros).
        tol: stop when the RMS algebraic error is <= tol, or when it has not decreased by more
            than tol for 3 iterations.
    Returns:
        :class:`RSSolution` of the rig: v (rad), C (``x_rig = (I + [v]x) X + C`` at the
        reference time), w (rad per unit of tau), t (world units per unit of tau), the
        iterations run and the RMS algebraic error; the iterate with the lowest error is kept.
    Raises:
        ValueError: wrong shapes, N < 6, NaN/inf input, camera index out of range,
            iterations < 1.
        DegenerateInputError (a ValueError): rank-deficient system (collinear or duplicated
            points, every tau equal).
    """
    x, X, tau, cam, Rm, cm = _check(x, X, tau, cam, R_mount, c_mount, batched=False)
    return run_mounted(
        NAME, False, solve_mounted, x, X, tau, cam, Rm, cm, iterations, tol, v_init,
        degenerate="collinear or duplicated points, or every observation at the same time?",
    )  # fmt: skip


def gr6p_1lin_batch(
    x: np.ndarray,
    X: np.ndarray,
    tau: np.ndarray,
    cam: np.ndarray,
    R_mount: np.ndarray,
    c_mount: np.ndarray,
    iterations: int = 5,
    v_init: np.ndarray | None = None,
    tol: float = 1e-12,
    prior_rows: tuple[np.ndarray, np.ndarray] | None = None,
    numpy: bool = False,
) -> RSBatch:
    """Batched :func:`gr6p_1lin` for K problems (RANSAC hypotheses) on one rig.

    Args:
        x: (K, N, 2), X: (K, N, 3), tau: (K, N), cam: (K, N) int (or one int).
        R_mount: (M, 3, 3), c_mount: (M, 3): the mountings, shared by all problems.
        v_init: (3,) or (K, 3) or None.
        prior_rows: ``None``, or ``(P (K, 6, 6), q (K, 6))``: every linear solve then minimizes
            ``|A u - b|^2 + |P[k] (w, t) - q[k]|^2`` (a linearized motion prior on the rig's
            velocities, in the units of tau), as ``r6p_1lin_batch``.
        numpy: solve in NumPy, nothing compiled (the rig estimator's NumPy implementation):
            the same iteration and outputs, each linear solve by NumPy's stacked LU solve for
            square systems, its stacked QR otherwise (as the compiled one: Gaussian
            elimination, Householder QR; the solutions agree to rounding).
    Returns:
        :class:`RSBatch` with (K, 3) v, C, w, t and a (K,) ``valid`` mask (False for rank loss
        or non-finite input, never raises for those).
    Raises:
        ValueError: wrong shapes, N < 6, camera index out of range, non-finite mountings,
            iterations < 1, or ``prior_rows`` not of shapes (K, 6, 6), (K, 6).
    """
    x, X, tau, cam, Rm, cm = _check(x, X, tau, cam, R_mount, c_mount, batched=True)
    solve = _solve_numpy if numpy else solve_mounted
    return run_mounted(NAME, True, solve, x, X, tau, cam, Rm, cm, iterations, tol, v_init,
                       prior_rows)  # fmt: skip
