"""One pose for a rig of rolling-shutter cameras from one rig frame (RANSAC over all cameras).

A rig frame is one image of each of M cameras rigidly mounted on the rig, each with its own
intrinsics, lens distortion, line delay, readout direction and stamp. Camera ``c`` is mounted at
``x_cam = R_c x_rig + c_c``. The rig moves with constant angular velocity ``w`` and linear
velocity ``t`` through the frame (the exact constant-velocity model, paper eq. 4, in time)::

    x_rig(tau) = expm(tau [w]x) R X + C + tau t

with ``tau`` (s) the capture time of an observation minus the rig's reference time: for a point
on measured line ``r`` (RS coordinate, :class:`~rs_localizer.camera.CameraModel`) of camera c,
``tau = stamp_offset_c + (r - r0_c) * seconds_per_unit_r_c`` (``stamp_offset_c``: the capture
time of the camera's reference line minus the rig's reference time).

:func:`estimate_rig_pose` runs RANSAC on every camera's correspondences at once:

- a sample is 3 points of one camera (drawn with probability proportional to its number of
  points, among cameras with at least 3) and 3 more points drawn uniformly from every camera's
  remaining points, so samples spread over cameras as the points do;
- the camera's 3 points give P3P poses (Lambda Twist, global shutter), mapped to the rig
  (``R_rig = R_c^T R_cam``); each pre-rotates the sample's world points and the batched
  :func:`~rs_localizer.solvers.gr6p_1lin.gr6p_1lin_batch` solves the 6 points;
- hypotheses are scored by MSAC on the reprojection error in pixels with each camera's exact
  model (the rotation ``expm(tau [w]x)`` at the observation's own measured capture time, the
  camera's focal length turning normalized errors into pixels);
- the best model is refit on its inliers with the rig solver (pre-rotated by the model, twice),
  then refined by Levenberg-Marquardt on the exact model (SciPy), inliers re-selected in
  between, twice; a step that raises the MSAC cost of all points is not taken.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from scipy.optimize import least_squares

from ..camera import CameraModel
from ..geometry import rotvec_to_matrix
from ..solvers._common import DegenerateInputError
from ..solvers.gr6p_1lin import gr6p_1lin, gr6p_1lin_batch
from ..solvers.lambda_twist import lambda_twist_batch

__all__ = ["RIG_FAILURE_REASONS", "RigPoseEstimate", "RigView", "estimate_rig_pose"]

#: failure reason -> meaning
RIG_FAILURE_REASONS = {
    "too_few_points": "fewer than 6 valid correspondences over all cameras, or no camera with 3",
    "no_model": "no sample gave a valid model",
    "too_few_inliers": "the best model has fewer than min_inliers inliers",
}


@dataclass(frozen=True, eq=False)
class RigView:
    """One camera's part of a rig frame.

    Attributes:
        uv: (N, 2) measured (distorted) pixels. X: (N, 3) world points (m).
        camera: the camera's intrinsics and RS timing.
        R_mount: (3, 3) rig -> camera rotation. c_mount: (3,) rig -> camera offset (m):
            ``x_cam = R_mount x_rig + c_mount``.
        stamp_offset: capture time of the camera's reference line (``camera.reference_line``)
            minus the rig's reference time (s).
    """

    uv: np.ndarray
    X: np.ndarray
    camera: CameraModel
    R_mount: np.ndarray = field(default_factory=lambda: np.eye(3))
    c_mount: np.ndarray = field(default_factory=lambda: np.zeros(3))
    stamp_offset: float = 0.0


@dataclass(frozen=True, eq=False)
class RigPoseEstimate:
    """Result of :func:`estimate_rig_pose`.

    Attributes:
        success: a model with at least ``min_inliers`` inliers was found.
        failure: a key of :data:`RIG_FAILURE_REASONS`, ``None`` on success.
        R: (3, 3) world -> rig rotation at the reference time. C: (3,) world -> rig
            translation (m): ``x_rig = R X + C``.
        w: (3,) angular velocity (rad/s, rig frame: ``expm(tau [w]x)`` left of ``R``).
        t: (3,) linear velocity term of the model (m/s, rig frame).
        inliers: one (N_c,) bool array per camera (invalid rows False).
        num_inliers: inliers over all cameras. iterations: RANSAC samples drawn.
        rmse_px: RMS reprojection error of the inliers (pixels; NaN on failure).
    """

    success: bool
    failure: str | None
    R: np.ndarray
    C: np.ndarray
    w: np.ndarray
    t: np.ndarray
    inliers: tuple
    num_inliers: int
    iterations: int
    rmse_px: float

    @property
    def position(self) -> np.ndarray:
        """(3,) rig origin in the world at the reference time (m): ``-R^T C``."""
        return -self.R.T @ self.C


class _Pool:
    """Every camera's valid correspondences stacked: normalized points, world points, tau,
    camera index, the camera's focal length (px per normalized unit)."""

    def __init__(self, views: Sequence[RigView]):
        xs, Xs, taus, cams, rows, foc = [], [], [], [], [], []
        self.R_mount = np.array([np.asarray(v.R_mount, dtype=float) for v in views])
        self.c_mount = np.array([np.asarray(v.c_mount, dtype=float).reshape(3) for v in views])
        if self.R_mount.shape != (len(views), 3, 3):
            raise ValueError("estimate_rig_pose: every R_mount must be (3, 3)")
        if not (np.isfinite(self.R_mount).all() and np.isfinite(self.c_mount).all()):
            raise ValueError("estimate_rig_pose: mountings contain NaN or inf")
        self.sizes = []
        for c, v in enumerate(views):
            uv = np.asarray(v.uv, dtype=float).reshape(-1, 2)
            X = np.asarray(v.X, dtype=float).reshape(-1, 3)
            if len(uv) != len(X):
                raise ValueError(
                    f"estimate_rig_pose: camera {c} has {len(uv)} pixels and {len(X)} points"
                )
            self.sizes.append(len(uv))
            good = np.isfinite(uv).all(axis=1) & np.isfinite(X).all(axis=1)
            idx = np.flatnonzero(good)
            x, r, _ = v.camera.normalize(uv[idx])
            ok = np.isfinite(x).all(axis=1)
            idx, x, r = idx[ok], x[ok], r[ok]
            cam = v.camera
            xs.append(x)
            Xs.append(X[idx])
            taus.append(float(v.stamp_offset) + (r - cam.r0) * cam.seconds_per_unit_r)
            cams.append(np.full(len(idx), c, dtype=np.int64))
            rows.append(idx)
            foc.append(np.full(len(idx), cam.mean_focal))
        self.x = np.vstack(xs) if xs else np.zeros((0, 2))
        self.X = np.vstack(Xs) if Xs else np.zeros((0, 3))
        self.tau = np.concatenate(taus) if taus else np.zeros(0)
        self.cam = np.concatenate(cams) if cams else np.zeros(0, dtype=np.int64)
        self.row = np.concatenate(rows) if rows else np.zeros(0, dtype=np.int64)
        self.focal = np.concatenate(foc) if foc else np.zeros(0)

    def per_camera(self, mask: np.ndarray) -> tuple:
        """(N_pool,) bool -> one (N_c,) bool per camera over the input rows."""
        out = []
        for c, n in enumerate(self.sizes):
            m = np.zeros(n, dtype=bool)
            s = self.cam == c
            m[self.row[s]] = mask[s]
            out.append(m)
        return tuple(out)


@njit(cache=True)
def _residuals_kernel(R, C, w, t, X, tau, cam, Rm, cm, x, focal, out):
    """out[h, i]: the (2,) image error (px) of point i under model h (predicted minus measured,
    normalized difference times the focal length; inf behind the camera)."""
    H, N = R.shape[0], X.shape[0]
    for h in range(H):
        for i in range(N):
            # y = R X, then the exact rotation expm(tau [w]x) y (Rodrigues)
            y0 = R[h, 0, 0] * X[i, 0] + R[h, 0, 1] * X[i, 1] + R[h, 0, 2] * X[i, 2]
            y1 = R[h, 1, 0] * X[i, 0] + R[h, 1, 1] * X[i, 1] + R[h, 1, 2] * X[i, 2]
            y2 = R[h, 2, 0] * X[i, 0] + R[h, 2, 1] * X[i, 1] + R[h, 2, 2] * X[i, 2]
            ti = tau[i]
            p0, p1, p2 = ti * w[h, 0], ti * w[h, 1], ti * w[h, 2]
            th = np.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
            if th < 1e-12:
                z0 = y0 + p1 * y2 - p2 * y1
                z1 = y1 + p2 * y0 - p0 * y2
                z2 = y2 + p0 * y1 - p1 * y0
            else:
                k0, k1, k2 = p0 / th, p1 / th, p2 / th
                c, s = np.cos(th), np.sin(th)
                kd = (k0 * y0 + k1 * y1 + k2 * y2) * (1.0 - c)
                z0 = y0 * c + (k1 * y2 - k2 * y1) * s + k0 * kd
                z1 = y1 * c + (k2 * y0 - k0 * y2) * s + k1 * kd
                z2 = y2 * c + (k0 * y1 - k1 * y0) * s + k2 * kd
            z0 += C[h, 0] + ti * t[h, 0]
            z1 += C[h, 1] + ti * t[h, 1]
            z2 += C[h, 2] + ti * t[h, 2]
            c_ = cam[i]
            q0 = Rm[c_, 0, 0] * z0 + Rm[c_, 0, 1] * z1 + Rm[c_, 0, 2] * z2 + cm[c_, 0]
            q1 = Rm[c_, 1, 0] * z0 + Rm[c_, 1, 1] * z1 + Rm[c_, 1, 2] * z2 + cm[c_, 1]
            q2 = Rm[c_, 2, 0] * z0 + Rm[c_, 2, 1] * z1 + Rm[c_, 2, 2] * z2 + cm[c_, 2]
            if q2 <= 1e-9:
                out[h, i, 0] = np.inf
                out[h, i, 1] = np.inf
            else:
                out[h, i, 0] = focal[i] * (q0 / q2 - x[i, 0])
                out[h, i, 1] = focal[i] * (q1 / q2 - x[i, 1])


def _residuals(pool: _Pool, R, C, w, t, s: np.ndarray) -> np.ndarray:
    """(H, len(s), 2) image errors (px) of H models on the pool's points ``s``."""
    f = [np.ascontiguousarray(a, dtype=np.float64) for a in (R, C, w, t)]
    out = np.empty((len(f[0]), len(s), 2))
    _residuals_kernel(
        *f, pool.X[s], pool.tau[s], pool.cam[s], pool.R_mount, pool.c_mount, pool.x[s],
        pool.focal[s], out,
    )  # fmt: skip
    return out


def _errors_px(pool: _Pool, R, C, w, t) -> np.ndarray:
    """Reprojection errors (px) of H models R (H, 3, 3), C, w, t (H, 3) on the pool's points,
    with the exact rotation ``expm(tau [w]x)`` at each observation's measured capture time;
    inf for a point behind its camera. Returns (H, N)."""
    d = _residuals(pool, R, C, w, t, np.arange(len(pool.cam)))
    return np.sqrt(d[..., 0] ** 2 + d[..., 1] ** 2)


def _sample(rng, pool: _Pool, n_samples: int):
    """n_samples samples of 6 pool indices: 3 from one camera with >= 3 points (chosen in
    proportion to its points), then 3 distinct others from all cameras. Returns (S, 6)."""
    counts = np.bincount(pool.cam, minlength=len(pool.sizes))
    eligible = np.flatnonzero(counts >= 3)
    p = counts[eligible] / counts[eligible].sum()
    members = [np.flatnonzero(pool.cam == c) for c in range(len(counts))]
    n = len(pool.cam)
    out = np.empty((n_samples, 6), dtype=np.int64)
    for k in range(n_samples):
        c = eligible[rng.choice(len(eligible), p=p)]
        first = rng.choice(members[c], 3, replace=False)
        rest = rng.choice(n - 3, 3, replace=False)
        # map 0..n-4 onto the pool without the first three
        taken = np.sort(first)
        for j in taken:
            rest = rest + (rest >= j)
        out[k, :3] = first
        out[k, 3:] = rest
    return out


def _hypotheses(pool: _Pool, samples: np.ndarray, iterations: int):
    """Models (R, C, w, t) of the samples: P3P in the sample's first camera, mapped to the
    rig, pre-rotates the rig solver. Returns arrays of H valid models."""
    cam0 = pool.cam[samples[:, 0]]
    Rc = pool.R_mount[cam0]
    xs = pool.x[samples[:, :3]]
    bearings = np.concatenate([xs, np.ones(xs.shape[:2] + (1,))], axis=2)
    R_cam, _, own = lambda_twist_batch(
        np.ascontiguousarray(bearings), np.ascontiguousarray(pool.X[samples[:, :3]])
    )
    if len(own) == 0:
        return None
    R0 = np.einsum("hji,hjk->hik", Rc[own], R_cam)  # R_c^T R_cam
    S = samples[own]
    Xp = np.einsum("hij,hnj->hni", R0, pool.X[S])
    b = gr6p_1lin_batch(
        pool.x[S], Xp, pool.tau[S], pool.cam[S], pool.R_mount, pool.c_mount, iterations
    )
    ok = b.valid
    if not ok.any():
        return None
    R = np.einsum("hij,hjk->hik", rotvec_to_matrix(b.v[ok]), R0[ok])
    return R, b.C[ok], b.w[ok], b.t[ok]


def _refit(pool: _Pool, inl: np.ndarray, model, threshold_px: float, rounds: int = 2):
    """The rig solver on the inliers, pre-rotated by the current model, ``rounds`` times
    (``threshold_px``: unused, the signature of :func:`_refine`)."""
    R, C, w, t = model
    idx = np.flatnonzero(inl)
    if len(idx) < 6:
        return model
    for _ in range(rounds):
        try:
            s = gr6p_1lin(
                pool.x[idx], pool.X[idx] @ R.T, pool.tau[idx], pool.cam[idx],
                pool.R_mount, pool.c_mount, iterations=10, v_init=None,
            )  # fmt: skip
        except DegenerateInputError:
            return model
        R, C, w, t = rotvec_to_matrix(s.v) @ R, s.C, s.w, s.t
    return R, C, w, t


def _refine(pool: _Pool, inl: np.ndarray, model, threshold_px: float):
    """Levenberg-Marquardt (SciPy, Huber loss at the threshold) on the exact model over the
    inliers: 12 parameters (a rotation update left of R, C, w, t); residuals: the image errors
    (px) of :func:`_errors_px`."""
    R0, C0, w0, t0 = model
    idx = np.flatnonzero(inl)
    if len(idx) < 6:
        return model
    behind = 1e3 * threshold_px

    def res(u):
        R = (rotvec_to_matrix(u[0:3]) @ R0)[None]
        d = _residuals(pool, R, u[3:6][None], u[6:9][None], u[9:12][None], idx)[0]
        return np.where(np.isfinite(d), d, behind).ravel()

    u0 = np.concatenate([np.zeros(3), C0, w0, t0])
    sol = least_squares(res, u0, loss="huber", f_scale=threshold_px, x_scale="jac")
    if not np.isfinite(sol.x).all():
        return model
    u = sol.x
    return rotvec_to_matrix(u[0:3]) @ R0, u[3:6], u[6:9], u[9:12]


def _one(model):
    return tuple(np.asarray(a)[None] for a in model)


def estimate_rig_pose(
    views: Sequence[RigView],
    threshold_px: float = 2.0,
    max_iterations: int = 1000,
    confidence: float = 0.999,
    min_inliers: int = 8,
    batch_size: int = 32,
    solver_iterations: int = 3,
    refine: bool = True,
    seed: int | None = 0,
) -> RigPoseEstimate:
    """The pose and velocities of a rig of RS cameras from one rig frame (module docstring).

    Args:
        views: one :class:`RigView` per camera (pixels, world points, camera, mounting, stamp
            offset); a camera may have no points.
        threshold_px: inlier threshold on the reprojection error (px).
        max_iterations: most RANSAC samples. confidence: adaptive termination's confidence.
        min_inliers: inliers over all cameras for success.
        batch_size: samples solved per batched call.
        solver_iterations: rig-solver iterations per sample (after the P3P pre-rotation).
        refine: run the Levenberg-Marquardt refinement on the exact model.
        seed: random seed of the sampling.
    Returns:
        :class:`RigPoseEstimate`: the rig's world -> rig pose at the reference time, its
        angular velocity (rad/s) and linear velocity (m/s), the inliers per camera.
    Raises:
        ValueError: no views, mismatched pixel and point counts, bad mountings.

    Every observation at one time (global-shutter cameras with equal stamps) leaves ``w`` and
    ``t`` undetermined: the rig solver rejects every sample and the estimate fails with
    ``no_model``.
    """
    if len(views) == 0:
        raise ValueError("estimate_rig_pose: needs at least one camera")
    pool = _Pool(views)
    rng = np.random.default_rng(seed)
    counts = np.bincount(pool.cam, minlength=len(views))

    def failed(reason, its=0):
        z = np.zeros(3)
        no = pool.per_camera(np.zeros(len(pool.cam), dtype=bool))
        return RigPoseEstimate(False, reason, np.eye(3), z, z, z.copy(), no, 0, its, np.nan)

    if len(pool.cam) < 6 or counts.max() < 3:
        return failed("too_few_points")
    th2 = threshold_px**2
    best_cost, best = np.inf, None
    drawn = 0
    needed = max_iterations
    while drawn < min(needed, max_iterations):
        k = min(batch_size, max_iterations - drawn)
        samples = _sample(rng, pool, k)
        drawn += k
        hyp = _hypotheses(pool, samples, solver_iterations)
        if hyp is None:
            continue
        e = _errors_px(pool, *hyp)
        cost = np.minimum(e * e, th2).sum(axis=1)
        h = int(np.argmin(cost))
        if cost[h] < best_cost:
            best_cost = cost[h]
            best = tuple(a[h] for a in hyp)
            frac = np.mean(e[h] < threshold_px)
            if frac > 0:
                denom = np.log(max(1e-12, 1.0 - frac**6))
                needed = np.log(1.0 - confidence) / denom if denom < 0 else 0
    if best is None:
        return failed("no_model", drawn)
    model = best

    def msac(m):
        return float(np.minimum(_errors_px(pool, *_one(m))[0] ** 2, th2).sum())

    # each step is kept only if it does not raise the MSAC cost of the whole pool
    for _ in range(2):
        steps = (_refit, _refine) if refine else (_refit,)
        for step in steps:
            inl = _errors_px(pool, *_one(model))[0] < threshold_px
            cand = step(pool, inl, model, threshold_px)
            cost = msac(cand)
            if cost <= best_cost:
                model, best_cost = cand, cost
    e = _errors_px(pool, *_one(model))[0]
    inl = e < threshold_px
    n_in = int(inl.sum())
    if n_in < min_inliers:
        return failed("too_few_inliers", drawn)
    R, C, w, t = (np.array(a, dtype=float) for a in model)
    rmse = float(np.sqrt(np.mean(e[inl] ** 2)))
    return RigPoseEstimate(True, None, R, C, w, t, pool.per_camera(inl), n_in, drawn, rmse)
