"""The corners of a rig video as one least-squares problem (:class:`RigCorners`, what
``calibrate-rig`` refines its mountings on), its solve and the mountings' covariance.

Frames and units (``parameters="rig"``, the default): a rig pose is the rig -> world rotation
``R_g`` and the rig's position ``P_g`` (m) in the world (``x_world = R_g x_rig + P_g``); a
mounting is the camera -> rig rotation ``R_m`` and the camera's position ``p_m`` (m) in the
rig frame (``x_rig = R_m x_cam + p_m``); a tag's pose is tag -> world (``x_world = R_t x_tag
+ p_t``). The parameters are increments from the start: per block a rotation vector (rad)
composed on the left (world axes for a rig pose and a tag, rig axes for a mounting: the axes
of :attr:`~rs_localizer.frames.Mounting.covariance`) and a translation (m) added. With
``parameters="inverse"`` the rig poses and mountings are the inverse transforms, world -> rig
(``x_rig = R_f x_world + C_f``) and rig -> camera (``x_cam = R x_rig + c``, as
:class:`~rs_localizer.frames.Mounting`), with the increments composed on their left (rig and
camera axes), as TagSLAM parameterizes its factor graph.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix, csr_matrix, hstack, kron

from ..geometry import rotvec_to_matrix

__all__ = ["CornerSolution", "RigCorners", "TagPoints", "soft_l1"]

#: px, times the loss scale: the error given to a corner that no longer projects (it left its
#: camera's field of view during the solve), so that the solve moves away from it
UNPROJECTED_PENALTY = 1e3

#: an eigenvalue of the mountings' information (:meth:`RigCorners.mounting_covariance`) below
#: this share of the largest is a direction the corners do not constrain
UNCONSTRAINED_RTOL = 1e-12


def soft_l1(s: np.ndarray, f_scale: float) -> np.ndarray:
    """The robust loss of squared errors ``s`` (px^2): ``2 f^2 (sqrt(1 + s / f^2) - 1)``
    (``f`` = ``f_scale`` px): ``s`` for small errors, ``2 f |e|`` for large ones (SciPy's
    ``soft_l1``)."""
    return 2 * f_scale**2 * (np.sqrt(1 + s / f_scale**2) - 1)


@dataclass(frozen=True)
class TagPoints:
    """The corners' map points as corners of tags whose poses may be adjusted.

    Attributes:
        tag: (N,) int, each corner's tag (an index into ``R`` and ``p``).
        local: (N, 3) m, each corner in its tag's frame.
        R: (T, 3, 3) tag -> world rotations at the start. p: (T, 3) m, the tags' positions.
        free: (T,) bool, the tags adjusted (the others, e.g. the gauge's anchors, stay).
    """

    tag: np.ndarray
    local: np.ndarray
    R: np.ndarray
    p: np.ndarray
    free: np.ndarray


@dataclass
class CornerSolution:
    """:meth:`RigCorners.solve`'s solution.

    Attributes:
        rig: ``(R (G, 3, 3) rig -> world, P (G, 3) m)``, every rig frame's pose.
        mounts: ``(R (M, 3, 3) camera -> rig, p (M, 3) m)``, every mounting (the fixed ones as
            given).
        tags: ``(R (T, 3, 3), p (T, 3) m)`` tag -> world, or None without :class:`TagPoints`.
        keep: (N,) bool, the corners that took part (those projected at the start).
        result: SciPy's ``OptimizeResult`` (``x``, ``jac`` at the solution, ``fun``, ``cost``,
            ``nfev``, ``status``).
    """

    rig: tuple
    mounts: tuple
    tags: tuple | None
    keep: np.ndarray
    result: Any


class RigCorners:
    """Every corner's error (px) in the distorted image of its camera (its model's
    :meth:`~rs_localizer.camera.CameraModel.project`) through its rig frame's pose, its
    camera's mounting and, where a camera frame was carried to its rig frame's time, the
    camera's pose in its own frame relative to the carried one (frames, units and parameters:
    the module docstring). The parameters are the rig poses, the free tags' poses, the free
    mountings' (6 each), then the time offsets (``motion``; 1 each).

    Args:
        uv: (N, 2) px, the corners in the distorted image.
        cameras: the camera models; ``camera`` (N,) int: each corner's model (an index).
        frame: (N,) int, each corner's rig frame; ``mounting`` (N,) int, its camera mounting.
        rig: ``(R (G, 3, 3), P (G, 3))`` and ``mounts``: ``(R (M, 3, 3), p (M, 3))``, the rig
            poses and mountings to start from; ``free`` (M,) bool: the mountings adjusted.
        points: (N, 3) m, the corners' map points (fixed), or :class:`TagPoints`.
        offsets: ``(Dr (N, 3, 3), Dp (N, 3) m)``, each corner's camera pose at its own
            frame's time relative to its pose carried to the rig frame's time (camera ->
            world rotation ``O Dr``, position ``p + O Dp``); None: the same.
        parameters: ``"rig"`` or ``"inverse"`` (the module docstring).
        motion: ``(index (N,) int, angular (N, 3) rad/s, linear (N, 3) m/s)``: each corner's
            time offset (-1: none) and its camera's twist (world axes): a corner seen ``dt`` s
            after its rig frame's pose has its camera moved along the twist (rotation
            ``expm(dt [w]x) O``, position ``p + dt v``; Kalibr's ``timeshift``). None: none.

    Raises:
        ValueError: arrays of inconsistent lengths, an index out of range, an unknown
            ``parameters`` or ``offsets`` with ``"inverse"``.
    """

    def __init__(
        self,
        uv: np.ndarray,
        cameras: Sequence,
        camera: np.ndarray,
        frame: np.ndarray,
        mounting: np.ndarray,
        rig: tuple,
        mounts: tuple,
        free: np.ndarray,
        points: np.ndarray | TagPoints,
        offsets: tuple | None = None,
        parameters: str = "rig",
        motion: tuple | None = None,
    ):
        if parameters not in ("rig", "inverse") or (
            parameters == "inverse" and (offsets or motion)
        ):
            raise ValueError(
                f"RigCorners: parameters {parameters!r} (with offsets or motion: 'rig' only)"
            )
        self.inverse = parameters == "inverse"
        self.uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        n = len(self.uv)
        self.cameras = list(cameras)
        self.camera, self.frame, self.mounting = (np.asarray(a, dtype=int)
                                                  for a in (camera, frame, mounting))  # fmt: skip
        self.R0g, self.R0m = (np.asarray(a[0], float).reshape(-1, 3, 3) for a in (rig, mounts))
        self.P0g, self.p0m = (np.asarray(a[1], float).reshape(-1, 3) for a in (rig, mounts))
        self.free = np.asarray(free, dtype=bool)
        self.tags = points if isinstance(points, TagPoints) else None
        self.X = None if self.tags is not None else np.asarray(points, dtype=float).reshape(-1, 3)
        self.offsets = offsets
        self.motion = None
        if motion is not None:
            k, w, v = (np.asarray(a) for a in motion)
            self.motion = (k.astype(int), *(np.asarray(a, float).reshape(-1, 3) for a in (w, v)))
        lengths = {len(a) for a in (self.camera, self.frame, self.mounting, *(offsets or ()),
                                    *(self.motion or ()))}  # fmt: skip
        lengths.add(len(self.tags.tag) if self.tags is not None else len(self.X))
        if lengths != {n}:
            raise ValueError(f"RigCorners: {n} corners but per-corner arrays of lengths {lengths}")
        G, M = len(self.R0g), len(self.R0m)
        if len(self.P0g) != G or len(self.p0m) != M or len(self.free) != M:
            raise ValueError("RigCorners: rig poses or mountings of inconsistent lengths")
        tops = (("camera", self.camera, len(self.cameras)), ("frame", self.frame, G),
                ("mounting", self.mounting, M))  # fmt: skip
        for name, idx, top in tops:
            if n and (idx.min() < 0 or idx.max() >= top):
                raise ValueError(f"RigCorners: a corner's {name} index outside 0..{top - 1}")
        self.G, self.M = G, M
        self.T = int(self.tags.free.sum()) if self.tags is not None else 0
        self.F = int(self.free.sum())
        self.D = int(self.motion[0].max()) + 1 if self.motion is not None and n else 0
        self.n = 6 * (G + self.T + self.F) + self.D
        # each free mounting's parameter block (-1: fixed), each free tag's
        self.block_m = np.where(self.free, np.cumsum(self.free) - 1, -1)
        if self.tags is not None:
            self.block_t = np.where(self.tags.free, np.cumsum(self.tags.free) - 1, -1)
        self.by_cam = [np.flatnonzero(self.camera == i) for i in range(len(self.cameras))]
        self._views()
        self.keep = np.ones(n, dtype=bool)
        self.penalty = UNPROJECTED_PENALTY

    def _views(self) -> None:
        """``view`` (N,) int, each corner's group of corners that share their camera's pose
        (rig frame, mounting, time offset, pose offsets, twist), and per view its first corner
        ``first``: :meth:`errors` builds one camera pose per view."""
        n = len(self.uv)
        d = self.motion[0] if self.motion is not None else np.zeros(n, dtype=int)
        key = np.stack([self.frame, self.mounting, d], axis=1)
        _, first, view = np.unique(key, axis=0, return_index=True, return_inverse=True)
        view = view.ravel()
        shared = list(self.offsets or ()) + (list(self.motion[1:]) if self.motion else [])
        if not all((np.asarray(a)[first][view] == a).all() for a in shared):
            # (corners of one key with their own pose offsets or twists: one view each)
            first, view = np.arange(n), np.arange(n)
        self.first, self.view = first, view

    def unpack(self, x: np.ndarray) -> tuple:
        """``((R_g, P_g), (R_m, p_m), (R_t, p_t) or None)`` of the parameters ``x`` (n,) (with
        ``parameters="inverse"``: ``((R_f, C_f), (R, c), ...)``)."""
        G, T, F = self.G, self.T, self.F

        def moved(R, p, d, sel):  # (the blocks sel of R, p moved by d (k, 6))
            R, p = R.copy(), p.copy()
            if len(d):
                R[sel], p[sel] = rotvec_to_matrix(d[:, :3]) @ R[sel], p[sel] + d[:, 3:]
            return R, p

        rig = moved(self.R0g, self.P0g, x[: 6 * G].reshape(G, 6), slice(None))
        t = self.tags
        tags = None if t is None else moved(t.R, t.p, x[6 * G : 6 * (G + T)].reshape(T, 6), t.free)
        d = x[6 * (G + T) : 6 * (G + T + F)].reshape(F, 6)
        return rig, moved(self.R0m, self.p0m, d, self.free), tags

    def errors(self, x: np.ndarray) -> np.ndarray:
        """(N, 2) px: every corner's projection at the parameters ``x`` minus its pixel (NaN:
        not projected, e.g. behind its camera or outside its model's field of view)."""
        (Rg, Pg), (Rm, pm), tags = self.unpack(x)
        if tags is None:
            X = self.X
        else:
            t = self.tags.tag
            X = np.einsum("nij,nj->ni", tags[0][t], self.tags.local) + tags[1][t]
        # (each view's camera pose, then each corner through its view's)
        f, v = self.first, self.view
        g, m = self.frame[f], self.mounting[f]
        if self.inverse:  # (world -> rig, rig -> camera)
            R, c = Rm[m] @ Rg[g], np.einsum("nij,nj->ni", Rm[m], Pg[g]) + pm[m]
            x_cam = np.einsum("nij,nj->ni", R[v], X) + c[v]
        else:
            Ow = Rg[g] @ Rm[m]  # (camera -> world at the rig frame's time)
            p = Pg[g] + (Rg[g] @ pm[m][:, :, None])[:, :, 0]
            if self.offsets is not None:
                Dr, Dp = self.offsets[0][f], self.offsets[1][f]
                p = p + np.einsum("nij,nj->ni", Ow, Dp)
                Ow = Ow @ Dr
            if self.D:  # (each corner's camera dt later: moved along its twist, world axes)
                k, w, vel = (a[f] for a in self.motion)
                dt = np.where(k >= 0, self.time_offsets(x)[np.maximum(k, 0)], 0.0)[:, None]
                Ow = rotvec_to_matrix(dt * w) @ Ow
                p = p + dt * vel
            x_cam = np.einsum("nji,nj->ni", Ow[v], X - p[v])
        out = np.empty_like(self.uv)
        for cam, sel in zip(self.cameras, self.by_cam, strict=True):
            out[sel] = cam.project(x_cam[sel])
        return out - self.uv

    def time_offsets(self, x: np.ndarray) -> np.ndarray:
        """(D,) s: the time offsets of the parameters ``x`` (the last ``D``)."""
        return x[self.n - self.D :]

    def residuals(self, x: np.ndarray, corner_scale: float | None = None) -> np.ndarray:
        """(2 K,) px: the kept corners' errors, a corner that no longer projects at
        :data:`UNPROJECTED_PENALTY` times the loss scale of the last :meth:`solve` (1 px
        before any). ``corner_scale``: px; each corner's error scaled to the :func:`soft_l1`
        loss of its distance (``e sqrt(rho(|e|^2) / |e|^2)``); None: as they are."""
        e = self.errors(x)[self.keep]
        e = np.where(np.isfinite(e), e, self.penalty)
        if corner_scale is None:
            return e.ravel()
        s = (e * e).sum(axis=1)
        w = np.sqrt(soft_l1(s, corner_scale) / np.where(s > 0, s, 1.0))
        return (e * np.where(s > 0, w, 1.0)[:, None]).ravel()

    def sparsity(self) -> coo_matrix:
        """The Jacobian's nonzeros (2 K, n) for the kept corners: a corner's two rows depend on
        its rig pose, its tag (when free) and its mounting (when free)."""
        k = self.keep
        g, m = self.frame[k], self.block_m[self.mounting[k]]
        K = len(g)
        rows, cols = [np.arange(K)], [g]
        if self.tags is not None:
            t = self.block_t[self.tags.tag[k]]
            rows.append(np.flatnonzero(t >= 0))
            cols.append(self.G + t[t >= 0])
        rows.append(np.flatnonzero(m >= 0))
        cols.append(self.G + self.T + m[m >= 0])
        r, c = np.concatenate(rows), np.concatenate(cols)
        nb = (self.n - self.D) // 6
        sp = kron(coo_matrix((np.ones(len(r)), (r, c)), (K, nb)), np.ones((2, 6)))
        if not self.D:
            return sp
        d = self.motion[0][k]
        rd = np.flatnonzero(d >= 0)
        T = kron(coo_matrix((np.ones(len(rd)), (rd, d[rd])), (K, self.D)), np.ones((2, 1)))
        return hstack([sp, T]).tocoo()

    def solve(
        self,
        f_scale: float,
        loss: str = "soft_l1",
        max_nfev: int = 300,
        ftol: float = 1e-8,
        xtol: float = 1e-8,
        verbose: int = 0,
    ) -> CornerSolution | None:
        """The parameters minimizing the corners' robust cost from the start (SciPy
        ``least_squares``, ``trf``, ``lsmr``, the Jacobian's sparsity :meth:`sparsity`; its
        bounds ``max_nfev``, ``ftol``, ``xtol``), the corners not projected at the start left
        out (None: none projects). ``loss``: ``"soft_l1"``, SciPy's on each coordinate at
        ``f_scale`` px, or ``"corner_soft_l1"``, :func:`soft_l1` of each corner's distance.

        Raises:
            ValueError: an unknown ``loss``.
        """
        if loss not in ("soft_l1", "corner_soft_l1"):
            raise ValueError(f"RigCorners.solve: unknown loss {loss!r}")
        x0 = np.zeros(self.n)
        self.penalty = UNPROJECTED_PENALTY * f_scale
        self.keep = np.isfinite(self.errors(x0)).all(axis=1)
        if not self.keep.any():
            return None
        robust = {"loss": "soft_l1", "f_scale": f_scale} if loss == "soft_l1" else {
            "kwargs": {"corner_scale": f_scale}}  # fmt: skip
        res = least_squares(self.residuals, x0, jac_sparsity=self.sparsity(), x_scale="jac",
                            method="trf", tr_solver="lsmr", ftol=ftol, xtol=xtol,
                            max_nfev=max_nfev, verbose=verbose, **robust)  # fmt: skip
        rig, mounts, tags = self.unpack(res.x)
        return CornerSolution(rig, mounts, tags, self.keep.copy(), res)

    def mounting_covariance(self, sol: CornerSolution, clusters: np.ndarray | None = None) -> tuple:
        """``(covariances (F, 6, 6), std (D,) s)``: each free mounting's covariance over
        (rotation [rad, rig axes], position [m, rig frame]; ``parameters="rig"``) at ``sol``,
        the rig poses marginalized (the Schur complement ``S`` of their blocks in ``H = J^T J``,
        ``J`` the robust-weighted Jacobian ``least_squares`` returns; the free tags, if any,
        held at the solution).
        ``clusters`` None: ``s^2 S^-1`` with ``s^2 = 2 cost / (2 K - n)``, every corner's error
        independent; ``clusters`` (N,) int, each corner's group: the cluster-robust "sandwich"
        ``S^-1 (sum_c u_c u_c^T) S^-1`` (``u_c`` the group's gradient of the cost on the
        mountings, the rig poses' part projected out), so corners that share an error (a tag
        map's, a camera model's) count once per group; ``std``: the time offsets' standard
        deviations (``motion``; empty without). A parameter that the kept corners do not
        constrain (one in a direction of ``S`` of eigenvalue below :data:`UNCONSTRAINED_RTOL`
        of the largest, e.g. a mounting or time offset none of whose corners is kept) gets an
        infinite variance (its rows and columns inf; an infinite std), never the zero of
        ``S``'s pseudo-inverse.

        Raises:
            ValueError: a solution without free mountings, or ``parameters="inverse"``.
        """
        if not self.F or self.inverse:
            raise ValueError("RigCorners.mounting_covariance: no free mounting")
        J = csr_matrix(sol.result.jac)
        r = np.asarray(sol.result.fun, dtype=float)
        k, mc = 6 * self.G, 6 * self.F + self.D
        lo = 6 * (self.G + self.T)
        Jg, Jm = J[:, :k], J[:, lo : lo + mc]
        # (a corner's two rows touch its rig frame's block alone: H_gg is block diagonal)
        g = np.repeat(self.frame[self.keep], 2)
        coo = Jg.tocoo()
        Jgd = np.zeros((len(r), 6))
        np.add.at(Jgd, (coo.row, coo.col - 6 * g[coo.row]), coo.data)
        blocks = np.zeros((self.G, 6, 6))
        np.add.at(blocks, g, Jgd[:, :, None] * Jgd[:, None, :])
        inv = np.linalg.pinv(blocks)
        Hgm = (Jg.T @ Jm).toarray().reshape(self.G, 6, mc)
        W = np.einsum("gij,gjk->gik", inv, Hgm)  # (H_gg^-1 H_gm)
        S = (Jm.T @ Jm).toarray() - np.einsum("gji,gjk->ik", Hgm, W)
        S = 0.5 * (S + S.T)
        Sinv = np.linalg.pinv(S)
        if clusters is None:
            s2 = 2.0 * float(sol.result.cost) / max(len(r) - self.n, 1)
            C = s2 * Sinv
        else:
            # each corner's gradient on the mountings with the rig poses' part projected out:
            # J_m - J_g H_gg^-1 H_gm, row by row
            A = Jm.toarray() - np.einsum("ri,rik->rk", Jgd, W[g])
            c = np.repeat(np.asarray(clusters)[self.keep], 2)
            _, ci = np.unique(c, return_inverse=True)
            U = np.zeros((ci.max() + 1, mc))
            np.add.at(U, ci, A * r[:, None])
            C = Sinv @ (U.T @ U) @ Sinv
        C = 0.5 * (C + C.T)
        # (a direction no kept corner constrains, e.g. a mounting none of whose corners is
        # left: the pseudo-inverse gives it zero variance; its parameters get infinite)
        w, V = np.linalg.eigh(S)
        null = w <= max(float(w[-1]) if len(w) else 0.0, 0.0) * UNCONSTRAINED_RTOL
        if null.any():
            loose = np.flatnonzero(np.sum(V[:, null] ** 2, axis=1) > 1e-6)
            C[loose, :] = C[:, loose] = np.inf
        blocks = np.array([C[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] for i in range(self.F)])
        return blocks, np.sqrt(np.diag(C)[6 * self.F :])
