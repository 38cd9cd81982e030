"""Marker maps: the rolling-shutter bundle adjustment's problem (parameter layout, corner
residuals of the estimator's model with the exact rotation, paper eq. 4, in a world centred on
each frame's camera, the motion tie between consecutive frames on their camera centres: both
independent of the world frame; the corner offset's prior, the Jacobian's sparsity) solved by
SciPy's ``least_squares`` and, last, by Levenberg-Marquardt steps with exact sparse solves
(:meth:`MarkerProblem.polish`; model: :mod:`rs_localizer.mapping.marker_model`)."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any, Protocol

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix, csr_matrix, lil_matrix

from ..camera import CameraModel
from ..geometry import matrix_to_rotvec, rotvec_to_matrix, skew
from .marker_model import MappingOptions, frame_velocities, marker_corners_local


class Placement(Protocol):
    """The starting point of an adjustment (:class:`~rs_localizer.mapping.marker_init.MarkerInit`).

    Attributes:
        frames: frame index -> ``(R (3, 3), C (3,))`` world -> camera.
        markers: id -> ``(R (3, 3) marker -> world, p (3,) centre, m)``.
        stamps: frame index -> capture time (s).
    """

    frames: dict
    markers: dict
    stamps: dict


def left_jacobian(q: np.ndarray) -> np.ndarray:
    """(..., 3, 3) left Jacobian of SO(3) at rotation vectors ``q`` (..., 3) (rad):
    ``J_l(q) = I + (1 - cos t) / t^2 [q]x + (t - sin t) / t^3 [q]x^2``, ``t = |q|``, so that
    ``expm([q + d]x) = expm([J_l(q) d]x) expm([q]x)`` to first order in ``d``."""
    q = np.asarray(q, dtype=float)
    t = np.linalg.norm(q, axis=-1)[..., None, None]
    K = skew(q)
    small = t < 1e-6
    th = np.where(small, 1.0, t)
    b = np.where(small, 0.5 - t**2 / 24.0, (1.0 - np.cos(th)) / th**2)
    c = np.where(small, 1.0 / 6.0 - t**2 / 120.0, (th - np.sin(th)) / th**3)
    return np.eye(3) + b * K + c * (K @ K)


def inverse_left_jacobian(q: np.ndarray) -> np.ndarray:
    """(..., 3, 3) inverse of :func:`left_jacobian`:
    ``I - [q]x / 2 + (1 / t^2 - (1 + cos t) / (2 t sin t)) [q]x^2``, ``t = |q| < pi``."""
    q = np.asarray(q, dtype=float)
    t = np.linalg.norm(q, axis=-1)[..., None, None]
    K = skew(q)
    small = t < 1e-4
    th = np.where(small, 1.0, t)
    c = np.where(
        small, 1.0 / 12.0 + t**2 / 720.0, 1.0 / th**2 - (1 + np.cos(th)) / (2 * th * np.sin(th))
    )
    return np.eye(3) - 0.5 * K + c * (K @ K)


class MarkerProblem:
    """Parameter layout, residuals and Jacobian sparsity of the bundle adjustment."""

    def __init__(
        self,
        init: Placement,
        obs_px: dict,
        camera: CameraModel,
        opts: MappingOptions,
        frames: list,
        markers: list,
        anchor: int,
        fix_frame: int | None = None,
        exclude: Iterable = (),
    ) -> None:
        self.camera = camera
        self.opts = opts
        self.frames = frames  # frame indices, parameter order
        self.markers = markers  # adjusted marker ids (anchor excluded)
        self.anchor = anchor
        self.vel = not opts.global_shutter
        self.fpar = 12 if self.vel else 6
        self.nf = len(frames)
        self.nm = len(markers)
        self.moff = self.nf * self.fpar
        self.ld_col = self.moff + 6 * self.nm if opts.calibrate_readout else None
        self.n = self.moff + 6 * self.nm + (1 if opts.calibrate_readout else 0)
        self.co_col = self.n if opts.corner_offset else None
        self.n += 1 if opts.corner_offset else 0
        # pixel noise of the detections (the reprojection rows are in pixels, unweighted): the
        # corner offset's prior row is scaled by it so that it weighs as its sigma says
        self.noise_px = 1.0
        self.R0f = np.array([init.frames[k][0] for k in frames])
        self.C0f = np.array([init.frames[k][1] for k in frames])
        self.R0m = np.array([init.markers[m][0] for m in markers])
        self.p0m = np.array([init.markers[m][1] for m in markers])
        self.fix = fix_frame
        if anchor is None:
            self.Ra, self.pa = np.eye(3), np.zeros(3)
        else:
            self.Ra, self.pa = init.markers[anchor]
        self.local = {m: marker_corners_local(opts.side(m)) for m in {*markers, anchor} - {None}}
        fidx = {k: i for i, k in enumerate(frames)}
        midx = {m: i for i, m in enumerate(markers)}
        # one row block per detection (4 corners)
        self.det = []  # (frame index, marker id)
        fi, mi, loc, xs, taus = [], [], [], [], []
        for k in frames:
            for m, uv in obs_px[k].items():
                if (m != anchor and m not in midx) or (k, m) in exclude:
                    continue
                x, r, _ = camera.normalize(uv)
                self.det.append((k, m))
                fi.append(np.full(4, fidx[k]))
                mi.append(np.full(4, midx.get(m, -1)))
                loc.append(self.local[m])
                xs.append(x)
                taus.append(r - camera.r0)
        self.fi = np.concatenate(fi)
        self.mi = np.concatenate(mi)
        self.loc = np.concatenate(loc)
        self.x = np.concatenate(xs)
        self.tau = np.concatenate(taus)
        self.keep = np.ones(len(self.det), dtype=bool)
        self.fxy = np.array([camera.K[0, 0], camera.K[1, 1]])
        # motion tie between consecutive frames
        self.ties = []
        if self.vel and opts.motion_sigma_rot is not None and opts.motion_sigma_pos is not None:
            st = np.array([init.stamps[k] for k in frames])
            dts = np.diff(st)
            if len(dts):
                med = np.median(dts)
                self.ties = [
                    (i, i + 1, dts[i])
                    for i in range(len(dts))
                    if 0 < dts[i] <= opts.max_frame_gap * med
                ]
        if opts.calibrate_readout and not self.ties:
            raise ValueError(
                "calibrating the line delay needs consecutive frames tied by the motion model "
                "(a video with stamps, the rolling-shutter model and motion_sigma_* set)"
            )

    def x0(self, init: Placement, line_delay: float) -> np.ndarray:
        x = np.zeros(self.n)
        F = x[: self.moff].reshape(self.nf, self.fpar)
        F[:, 3:6] = self.C0f
        if self.vel:
            st = np.array([init.stamps[k] for k in self.frames])
            for i in range(self.nf):
                a, b = max(i - 1, 0), min(i + 1, self.nf - 1)
                dt = st[b] - st[a]
                if b == a or dt <= 0 or dt > 3 * self.opts.max_frame_gap * np.median(np.diff(st)):
                    continue
                F[i, 6:9] = matrix_to_rotvec(self.R0f[b] @ self.R0f[a].T) / dt
                # (T = -R dc/dt, the camera centre c = -R^T C: dC/dt - W x C)
                F[i, 9:12] = (self.C0f[b] - self.C0f[a]) / dt - np.cross(F[i, 6:9], self.C0f[i])
        x[self.moff : self.moff + 6 * self.nm].reshape(self.nm, 6)[:, 3:6] = self.p0m
        if self.ld_col is not None:
            x[self.ld_col] = line_delay * 1e6
        return x

    def unpack(self, x: np.ndarray) -> tuple:
        F = x[: self.moff].reshape(self.nf, self.fpar)
        Rf = rotvec_to_matrix(F[:, :3]) @ self.R0f
        Cf = F[:, 3:6]
        W = F[:, 6:9] if self.vel else np.zeros((self.nf, 3))
        T = F[:, 9:12] if self.vel else np.zeros((self.nf, 3))
        M = x[self.moff : self.moff + 6 * self.nm].reshape(self.nm, 6)
        Rm = rotvec_to_matrix(M[:, :3]) @ self.R0m
        pm = M[:, 3:6]
        ld = x[self.ld_col] * 1e-6 if self.ld_col is not None else self.camera.line_delay
        return Rf, Cf, W, T, Rm, pm, ld

    def corner_offset(self, x: np.ndarray) -> float:
        """The detector's corner offset (pixels, inwards) in ``x``; 0 when not estimated."""
        return float(x[self.co_col]) if self.co_col is not None else 0.0

    def corner_offset_std(self, x: np.ndarray) -> float:
        """Standard deviation (pixels) of the corner offset at the solution ``x``: its diagonal
        element of ``(J^T J)^-1`` (:meth:`jacobian`; the rows in pixels and the offset's prior
        scaled by ``1 / noise_px``, every detection independent; the frames, markers and line
        delay marginalized). NaN when it is not estimated or the normal matrix is singular."""
        if self.co_col is None:
            return float("nan")
        from scipy.sparse import diags
        from scipy.sparse.linalg import splu

        J = self.jacobian(x)
        scale = np.ones(J.shape[0])
        n_px = 8 * int(self.keep.sum())
        scale[:n_px] = 1.0 / max(self.noise_px, 1e-12)
        scale[n_px + (6 if self.fix is not None else 0)] = 1.0 / max(self.noise_px, 1e-12)
        J = diags(scale) @ J
        e = np.zeros(self.n)
        e[self.co_col] = 1.0
        try:
            with np.errstate(all="raise"):
                v = float(splu((J.T @ J).tocsc()).solve(e)[self.co_col])
        except (RuntimeError, FloatingPointError):
            return float("nan")
        return float(np.sqrt(v)) if v > 0 else float("nan")

    def corner_residuals(self, x: np.ndarray) -> np.ndarray:
        """(N, 2) reprojection residuals (pixels) of all corners."""
        Rf, Cf, W, T, Rm, pm, ld = self.unpack(x)
        Rm_all = np.concatenate([Rm, self.Ra[None]])
        pm_all = np.concatenate([pm, self.pa[None]])
        X = np.einsum("nij,nj->ni", Rm_all[self.mi], self.loc) + pm_all[self.mi]
        ts = self.tau * (ld * self.camera.focal)
        A = rotvec_to_matrix(ts[:, None] * W[self.fi])
        # (the point in the frame's camera at its reference line, turned by the rotation over
        # tau: the model in a world centred on that camera, the same wherever the world lies)
        Pc = np.einsum("nij,nj->ni", Rf[self.fi], X) + Cf[self.fi]
        p = np.einsum("nij,nj->ni", A, Pc) + ts[:, None] * T[self.fi]
        z = np.where(p[:, 2] > 1e-6, p[:, 2], 1e-6)
        u = p[:, :2] / z[:, None] * self.fxy
        e = u - self.x * self.fxy
        if self.co_col is not None:  # detections lie inside the square along its diagonals
            q = u.reshape(-1, 4, 2)  # (the four corners of each detection)
            d = (q - q.mean(axis=1, keepdims=True)).reshape(-1, 2)
            d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
            e = e - x[self.co_col] * d
        return e

    def residuals(self, x: np.ndarray) -> np.ndarray:
        e = self.corner_residuals(x).reshape(-1, 8)[self.keep].ravel()
        if self.fix is not None:  # gauge on a frame: its pose held (stiff prior)
            F = x[: self.moff].reshape(self.nf, self.fpar)
            e = np.concatenate(
                [e, 1e3 * F[self.fix, :3], 1e3 * (F[self.fix, 3:6] - self.C0f[self.fix])]
            )
        if self.co_col is not None:  # the corner offset's prior: zero mean
            prior = x[self.co_col] / self.opts.corner_offset_sigma_px * self.noise_px
            e = np.concatenate([e, [prior]])
        if not self.ties:
            return e
        Rf, Cf, W, T, *_ = self.unpack(x)
        i = np.array([a for a, _, _ in self.ties])
        j = np.array([b for _, b, _ in self.ties])
        dt = np.array([d for _, _, d in self.ties])[:, None]
        er = matrix_to_rotvec(Rf[j] @ np.swapaxes(Rf[i], 1, 2)) - dt * 0.5 * (W[i] + W[j])
        # the camera centres c = -R^T C and their velocities R^T (W x C - T) (world axes): the
        # same residual wherever the world's origin lies (its norm, however the axes turn)
        Rt = np.swapaxes(Rf, 1, 2)
        c = -np.einsum("nij,nj->ni", Rt, Cf)
        v = np.einsum("nij,nj->ni", Rt, frame_velocities(W, T)[1])
        ec = c[j] - c[i] - dt * 0.5 * (v[i] + v[j])
        o = self.opts
        # the angular velocity changes by about the angular acceleration times the time between
        # frames (without it the mean of two frames' velocities is tied, their difference free)
        ew = (W[j] - W[i]) / (o.motion_sigma_angular_accel * dt)
        return np.concatenate(
            [
                e,
                (er / o.motion_sigma_rot).ravel(),
                (ec / o.motion_sigma_pos).ravel(),
                ew.ravel(),
            ]
        )

    def jacobian(self, x: np.ndarray) -> csr_matrix:
        """Sparse analytic Jacobian of :meth:`residuals` at ``x`` (rows and columns as there;
        the pattern of :meth:`sparsity`). Rotations are perturbed as the parameters are: on
        the left of the starting rotation, ``expm([r + d]x) = expm([J_l(r) d]x) expm([r]x)``
        (:func:`left_jacobian`)."""
        Rf, Cf, W, T, Rm, pm, ld = self.unpack(x)
        fpar, fi, mi = self.fpar, self.fi, self.mi
        F = x[: self.moff].reshape(self.nf, fpar)
        M = x[self.moff : self.moff + 6 * self.nm].reshape(self.nm, 6)
        Jlf = left_jacobian(F[:, :3])
        Jlm = np.concatenate([left_jacobian(M[:, :3]), np.eye(3)[None]])  # (anchor last)
        Rm_all = np.concatenate([Rm, self.Ra[None]])
        pm_all = np.concatenate([pm, self.pa[None]])
        Y = np.einsum("nij,nj->ni", Rm_all[mi], self.loc)
        X = Y + pm_all[mi]
        foc = self.camera.focal
        ts = self.tau * (ld * foc)
        A = rotvec_to_matrix(ts[:, None] * W[fi])
        ARf = A @ Rf[fi]
        # AQ: the point turned by the rotation over tau (camera-centred world, module docstring)
        AQ = np.einsum("nij,nj->ni", A, np.einsum("nij,nj->ni", Rf[fi], X) + Cf[fi])
        p = AQ + ts[:, None] * T[fi]
        N = len(p)
        has_ld = self.ld_col is not None
        nl = fpar + 6 + has_ld  # local columns: frame, marker, line delay
        dp = np.zeros((N, 3, nl))
        # frame rotation: p = A expm(r) R0 X + ...
        Q = np.einsum("nij,nj->ni", Rf[fi], X)
        dp[:, :, 0:3] = A @ (-skew(Q) @ Jlf[fi])
        dp[:, :, 3:6] = A
        if self.vel:
            tW = ts[:, None] * W[fi]
            dp[:, :, 6:9] = (-skew(AQ) @ left_jacobian(tW)) * ts[:, None, None]
            dp[:, :, 9:12] = np.eye(3) * ts[:, None, None]
        dp[:, :, fpar : fpar + 3] = ARf @ (-skew(Y) @ Jlm[mi])
        dp[:, :, fpar + 3 : fpar + 6] = ARf
        if has_ld:  # ts = tau * ld * focal, ld = x * 1e-6
            dts = np.einsum("nij,nj->ni", skew(W[fi]), AQ) + T[fi]
            dp[:, :, -1] = dts * (self.tau * foc * 1e-6)[:, None]
        z = p[:, 2]
        live = z > 1e-6
        zc = np.where(live, z, 1e-6)
        P = np.zeros((N, 2, 3))
        P[:, 0, 0] = self.fxy[0] / zc
        P[:, 1, 1] = self.fxy[1] / zc
        P[:, 0, 2] = np.where(live, -self.fxy[0] * p[:, 0] / zc**2, 0.0)
        P[:, 1, 2] = np.where(live, -self.fxy[1] * p[:, 1] / zc**2, 0.0)
        de = P @ dp  # (N, 2, nl)
        if self.co_col is not None:  # e -= co * d, d the unit direction of u from its centre
            u = p[:, :2] / zc[:, None] * self.fxy
            v = (u.reshape(-1, 4, 2) - u.reshape(-1, 4, 2).mean(axis=1, keepdims=True)).reshape(
                -1, 2
            )
            nv = np.maximum(np.linalg.norm(v, axis=1), 1e-9)
            d = v / nv[:, None]
            q4 = de.reshape(-1, 4, 2, nl)
            dv = (q4 - q4.mean(axis=1, keepdims=True)).reshape(N, 2, nl)
            proj = (np.eye(2) - d[:, :, None] * d[:, None, :]) / nv[:, None, None]
            de = de - x[self.co_col] * (proj @ dv)
        # rows of the kept detections (two per corner)
        kc = np.repeat(self.keep, 4)
        de, d_kept = de[kc], (d[kc] if self.co_col is not None else None)
        fk, mk = fi[kc], mi[kc]
        nk = len(fk)
        rows = np.arange(2 * nk).reshape(nk, 2)
        cols = np.empty((nk, nl), dtype=np.int64)
        cols[:, :fpar] = fk[:, None] * fpar + np.arange(fpar)
        cols[:, fpar : fpar + 6] = self.moff + 6 * mk[:, None] + np.arange(6)
        if has_ld:
            cols[:, -1] = self.ld_col
        use = np.ones((nk, nl), dtype=bool)
        use[:, fpar : fpar + 6] = (mk >= 0)[:, None]  # (the anchor is not adjusted)
        R_ = np.broadcast_to(rows[:, :, None], (nk, 2, nl))
        C_ = np.broadcast_to(cols[:, None, :], (nk, 2, nl))
        U_ = np.broadcast_to(use[:, None, :], (nk, 2, nl))
        r_l, c_l, v_l = [R_[U_]], [C_[U_]], [de[U_]]
        if self.co_col is not None:
            r_l.append(rows.ravel())
            c_l.append(np.full(2 * nk, self.co_col))
            v_l.append(-d_kept.ravel())
        row = 2 * nk
        if self.fix is not None:
            r_l.append(row + np.arange(6))
            c_l.append(self.fix * fpar + np.arange(6))
            v_l.append(np.full(6, 1e3))
            row += 6
        if self.co_col is not None:
            r_l.append([row])
            c_l.append([self.co_col])
            v_l.append([self.noise_px / self.opts.corner_offset_sigma_px])
            row += 1
        if self.ties:
            o = self.opts
            i = np.array([a for a, _, _ in self.ties])
            j = np.array([b for _, b, _ in self.ties])
            dt = np.array([dd for _, _, dd in self.ties])
            nt = len(i)
            phi = matrix_to_rotvec(Rf[j] @ np.swapaxes(Rf[i], 1, 2))
            Jinv = inverse_left_jacobian(phi)
            eye = np.broadcast_to(np.eye(3), (nt, 3, 3))
            blocks = []  # (row offset, frame index per tie, first column in the frame, (nt, 3, 3))
            blocks.append((0, j, 0, Jinv @ Jlf[j] / o.motion_sigma_rot))
            blocks.append((0, i, 0, -np.swapaxes(Jinv, 1, 2) @ Jlf[i] / o.motion_sigma_rot))
            hw = (-0.5 * dt / o.motion_sigma_rot)[:, None, None] * eye
            blocks += [(0, i, 6, hw), (0, j, 6, hw)]
            # ec = c_j - c_i - dt / 2 (v_i + v_j), c = -R^T C, v = R^T u, u = -T; with
            # R -> expm([a]x) R, a = J_l d: dc = -R^T [C]x a, dv = R^T [u]x a
            Rt = np.swapaxes(Rf, 1, 2)
            u = frame_velocities(W, T)[1]
            sp = 1.0 / o.motion_sigma_pos
            h = (0.5 * dt * sp)[:, None, None]
            for fr, sign in ((j, sp), (i, -sp)):
                Rtn, Jn = Rt[fr], Jlf[fr]
                dc_r = -Rtn @ skew(Cf[fr]) @ Jn
                dv_r = Rtn @ skew(u[fr]) @ Jn
                blocks.append((3 * nt, fr, 0, sign * dc_r - h * dv_r))
                blocks.append((3 * nt, fr, 3, -sign * Rtn))
                blocks.append((3 * nt, fr, 9, h * Rtn))
            ia = (1.0 / (o.motion_sigma_angular_accel * dt))[:, None, None] * eye
            blocks += [(6 * nt, j, 6, ia), (6 * nt, i, 6, -ia)]
            for off, fr, c0, B in blocks:
                rr = row + off + 3 * np.arange(nt)[:, None, None] + np.arange(3)[None, :, None]
                cc = fr[:, None, None] * fpar + c0 + np.arange(3)[None, None, :]
                r_l.append(np.broadcast_to(rr, (nt, 3, 3)).ravel())
                c_l.append(np.broadcast_to(cc, (nt, 3, 3)).ravel())
                v_l.append(B.ravel())
            row += 9 * nt
        J = coo_matrix(
            (np.concatenate(v_l), (np.concatenate(r_l), np.concatenate(c_l))),
            shape=(row, self.n),
        )
        return J.tocsr()

    def solve(
        self,
        x0: np.ndarray,
        *,
        loss: str = "linear",
        f_scale: float = 1.0,
        tol: float = 1e-6,
        max_nfev: int | None = None,
    ) -> Any:
        """SciPy ``least_squares`` (trust region reflective with this problem's Jacobian
        sparsity, Jacobian-scaled variables) on :meth:`residuals` from ``x0``; ``loss``,
        ``f_scale``, ``tol`` (``ftol`` and ``xtol``) and ``max_nfev`` (default: the options')
        as SciPy's."""
        return least_squares(
            self.residuals,
            x0,
            jac=self.jacobian,
            loss=loss,
            f_scale=f_scale,
            x_scale="jac",
            max_nfev=self.opts.max_nfev if max_nfev is None else max_nfev,
            ftol=tol,
            xtol=tol,
            method="trf",
        )

    def polish(self, x0: np.ndarray, *, max_iter: int = 50, rtol: float = 1e-12) -> Any:
        """Plain least squares on :meth:`residuals` from ``x0`` run to convergence:
        Levenberg-Marquardt steps ``(J^T J + lam diag(J^T J)) dx = -J^T r`` with this problem's
        sparse Jacobian solved exactly (SuperLU), ``lam`` divided by 10 after a step that lowers
        the cost and multiplied by 10 (the step refused) otherwise. Stops when a step lowers
        the cost by less than ``rtol`` times it (or the step is refused at the largest
        damping), or after ``max_iter`` steps. The exact solves make the end point the cost's
        minimum to the solver's precision wherever the world frame lies (SciPy's trust-region
        reflective with its iterative ``lsmr`` solves creeps towards it on an ill-conditioned
        problem and stops by its tolerance at a point that depends on where it started).

        Returns:
            ``scipy.optimize.OptimizeResult`` with ``x``, ``fun`` (the residuals), ``cost``
            (half their squared norm), ``jac`` (:meth:`jacobian` at ``x``), ``nfev``, ``nit``,
            ``status`` (1: converged, 0: ``max_iter`` reached) and ``success``.
        """
        from scipy.optimize import OptimizeResult
        from scipy.sparse import diags
        from scipy.sparse.linalg import splu

        x = np.array(x0, dtype=float)
        r = self.residuals(x)
        cost = 0.5 * float(r @ r)
        lam, nfev, status, it = 1e-6, 1, 0, 0
        J = self.jacobian(x)
        for it in range(1, max_iter + 1):  # noqa: B007 (the count is reported)
            H = (J.T @ J).tocsc()
            g = J.T @ r
            d = np.maximum(H.diagonal(), 1e-12)
            accepted = False
            while lam <= 1e8:
                try:
                    with np.errstate(all="raise"):
                        dx = -splu((H + diags(lam * d)).tocsc()).solve(g)
                except (RuntimeError, FloatingPointError):
                    lam *= 10.0
                    continue
                rn = self.residuals(x + dx)
                nfev += 1
                cn = 0.5 * float(rn @ rn)
                if np.isfinite(cn) and cn < cost:
                    accepted = True
                    break
                lam *= 10.0
            if not accepted:
                status = 1
                break
            x, r, gain, cost = x + dx, rn, cost - cn, cn
            lam = max(lam / 10.0, 1e-12)
            J = self.jacobian(x)
            if gain <= rtol * cost:
                status = 1
                break
        return OptimizeResult(
            x=x, fun=r, cost=cost, jac=J, nfev=nfev, nit=it, status=status, success=status == 1
        )

    def sparsity(self) -> csr_matrix:
        nd = int(self.keep.sum())
        nfix = 6 if self.fix is not None else 0
        nco = 1 if self.co_col is not None else 0
        S = lil_matrix((8 * nd + nfix + nco + 9 * len(self.ties), self.n), dtype=np.int8)
        midx = {m: i for i, m in enumerate(self.markers)}
        fidx = {k: i for i, k in enumerate(self.frames)}
        row = 0
        for (k, m), kept in zip(self.det, self.keep, strict=True):
            if not kept:
                continue
            f0 = fidx[k] * self.fpar
            S[row : row + 8, f0 : f0 + self.fpar] = 1
            if m in midx:
                m0 = self.moff + 6 * midx[m]
                S[row : row + 8, m0 : m0 + 6] = 1
            if self.ld_col is not None:
                S[row : row + 8, self.ld_col] = 1
            if self.co_col is not None:
                S[row : row + 8, self.co_col] = 1
            row += 8
        if nfix:
            S[row : row + 6, self.fix * self.fpar : self.fix * self.fpar + 6] = 1
            row += 6
        if nco:
            S[row, self.co_col] = 1
            row += 1
        for _ in range(3):  # rotation, position and angular velocity rows of all ties
            for i, j, _ in self.ties:
                for a in (i, j):
                    S[row : row + 3, a * self.fpar : (a + 1) * self.fpar] = 1
                row += 3
        return S.tocsr()
