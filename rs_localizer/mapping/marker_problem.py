"""Marker maps: the rolling-shutter bundle adjustment's problem (parameter layout, corner
residuals of the estimator's model with the exact rotation, paper eq. 4, the motion tie between
consecutive frames on their camera centres, independent of the world frame, the corner offset's
prior, the Jacobian's sparsity) solved by SciPy's ``least_squares`` (model:
:mod:`rs_localizer.mapping.marker_model`)."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any, Protocol

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix, lil_matrix

from ..camera import CameraModel
from ..geometry import matrix_to_rotvec, rotvec_to_matrix
from .marker_model import MappingOptions, marker_corners_local


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
                F[i, 9:12] = (self.C0f[b] - self.C0f[a]) / dt
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

    def corner_residuals(self, x: np.ndarray) -> np.ndarray:
        """(N, 2) reprojection residuals (pixels) of all corners."""
        Rf, Cf, W, T, Rm, pm, ld = self.unpack(x)
        Rm_all = np.concatenate([Rm, self.Ra[None]])
        pm_all = np.concatenate([pm, self.pa[None]])
        X = np.einsum("nij,nj->ni", Rm_all[self.mi], self.loc) + pm_all[self.mi]
        ts = self.tau * (ld * self.camera.focal)
        A = rotvec_to_matrix(ts[:, None] * W[self.fi])
        p = np.einsum("nij,nj->ni", A @ Rf[self.fi], X) + Cf[self.fi] + ts[:, None] * T[self.fi]
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
        v = np.einsum("nij,nj->ni", Rt, np.cross(W, Cf) - T)
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
            jac_sparsity=self.sparsity(),
            loss=loss,
            f_scale=f_scale,
            x_scale="jac",
            max_nfev=self.opts.max_nfev if max_nfev is None else max_nfev,
            ftol=tol,
            xtol=tol,
            method="trf",
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
