"""The corners of a rig video as one least-squares problem (:class:`RigCorners`, what
``calibrate-rig`` refines its mountings on), its solve and the mountings' covariance.

Frames and units: a rig pose is the rig -> world rotation ``R_g`` and the rig's position
``P_g`` (m) in the world (``x_world = R_g x_rig + P_g``); a mounting is the camera -> rig
rotation ``R_m`` and the camera's position ``p_m`` (m) in the rig frame (``x_rig = R_m x_cam
+ p_m``). The parameters are increments from the start: per block a rotation vector (rad)
composed on the left (world axes for a rig pose, rig axes for a mounting: the axes of
:attr:`~rs_localizer.frames.Mounting.covariance`) and a translation (m) added.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix, csr_matrix, hstack, kron

from ..geometry import moved, rotvec_to_matrix
from .marginal import loose_inverse, marginal_information

__all__ = ["CornerSolution", "RigCorners", "marginal"]

#: px, times the loss scale: the error given to a corner that no longer projects (it left its
#: camera's field of view during the solve), so that the solve moves away from it
UNPROJECTED_PENALTY = 1e3


def marginal(J, k: int) -> tuple:
    """The covariance factor of the parameters of columns ``k`` on of the Jacobian ``J`` (rows,
    k + c) (the mountings', the time offsets'), the first ``k`` (the rig poses') marginalized
    (:func:`~rs_localizer.calibration.marginal.marginal_information`; where their block is
    singular, its dense pseudo-inverse): ``(S^+ (c, c), A (rows, c), loose)``, ``S^+`` the
    pseudo-inverse of their information ``S``, ``A`` each row's Jacobian on them with the rig
    poses' part projected out, ``loose`` the parameters ``S`` does not constrain
    (:func:`~rs_localizer.calibration.marginal.loose_inverse`; e.g. a mounting none of whose
    rows is left): their variance is infinite, never the zero of the pseudo-inverse."""
    J = csr_matrix(J)
    info = marginal_information(J, np.arange(k, J.shape[1]))
    if info is None:  # (a rig pose its rows do not fix)
        H = (J.T @ J).toarray()
        X = np.linalg.pinv(H[:k, :k], hermitian=True) @ H[:k, k:]
        info = H[k:, k:] - H[:k, k:].T @ X, X
    S, X = info
    Sinv, loose = loose_inverse(S)
    return Sinv, J[:, k:].toarray() - J[:, :k] @ X, loose


@dataclass
class CornerSolution:
    """:meth:`RigCorners.solve`'s solution.

    Attributes:
        rig: ``(R (G, 3, 3) rig -> world, P (G, 3) m)``, every rig frame's pose.
        mounts: ``(R (M, 3, 3) camera -> rig, p (M, 3) m)``, every mounting (the fixed ones as
            given).
        keep: (N,) bool, the corners that took part (those projected at the start).
        result: SciPy's ``OptimizeResult`` (``x``, ``jac`` at the solution, ``fun``, ``cost``,
            ``nfev``, ``status``).
    """

    rig: tuple
    mounts: tuple
    keep: np.ndarray
    result: Any


class RigCorners:
    """Every corner's error (px) in the distorted image of its camera (its model's
    :meth:`~rs_localizer.camera.CameraModel.project`) through its rig frame's pose, its
    camera's mounting and, where a camera frame was carried to its rig frame's time, the
    camera's pose in its own frame relative to the carried one (frames, units and parameters:
    the module docstring). The parameters are the rig poses', the free mountings' (6 each),
    then the time offsets (``motion``; 1 each).

    A variant of the problem (the benchmarks' joint reference: tags' poses free, TagSLAM's
    inverse transforms) replaces the steps :meth:`world_points`, :meth:`camera_points`,
    :meth:`corner_blocks` and :meth:`robust_loss`, and puts its own parameter blocks between
    the rig poses' and the mountings' (:attr:`lead`).

    Args:
        uv: (N, 2) px, the corners in the distorted image.
        cameras: the camera models; ``camera`` (N,) int: each corner's model (an index).
        frame: (N,) int, each corner's rig frame; ``mounting`` (N,) int, its camera mounting.
        rig: ``(R (G, 3, 3), P (G, 3))`` and ``mounts``: ``(R (M, 3, 3), p (M, 3))``, the rig
            poses and mountings to start from; ``free`` (M,) bool: the mountings adjusted.
        points: (N, 3) m, the corners' map points in the world (fixed).
        offsets: ``(Dr (N, 3, 3), Dp (N, 3) m)``, each corner's camera pose at its own
            frame's time relative to its pose carried to the rig frame's time (camera ->
            world rotation ``O Dr``, position ``p + O Dp``); None: the same.
        motion: ``(index (N,) int, angular (N, 3) rad/s, linear (N, 3) m/s)``: each corner's
            time offset (-1: none) and its camera's twist (world axes): a corner seen ``dt`` s
            after its rig frame's pose has its camera moved along the twist (rotation
            ``expm(dt [w]x) O``, position ``p + dt v``; Kalibr's ``timeshift``). None: none.

    Raises:
        ValueError: arrays of inconsistent lengths or an index out of range.
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
        points: np.ndarray,
        offsets: tuple | None = None,
        motion: tuple | None = None,
    ):
        self.uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        n = len(self.uv)
        self.cameras = list(cameras)
        self.camera, self.frame, self.mounting = (np.asarray(a, dtype=int)
                                                  for a in (camera, frame, mounting))  # fmt: skip
        self.R0g, self.R0m = (np.asarray(a[0], float).reshape(-1, 3, 3) for a in (rig, mounts))
        self.P0g, self.p0m = (np.asarray(a[1], float).reshape(-1, 3) for a in (rig, mounts))
        self.free = np.asarray(free, dtype=bool)
        self.X = np.asarray(points, dtype=float).reshape(-1, 3)
        self.offsets = offsets
        self.motion = None
        if motion is not None:
            k, w, v = (np.asarray(a) for a in motion)
            self.motion = (k.astype(int), *(np.asarray(a, float).reshape(-1, 3) for a in (w, v)))
        lengths = {len(a) for a in (self.camera, self.frame, self.mounting, self.X,
                                    *(offsets or ()), *(self.motion or ()))}  # fmt: skip
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
        self.F = int(self.free.sum())
        self.D = int(self.motion[0].max()) + 1 if self.motion is not None and n else 0
        #: the parameter blocks (6 each) before the mountings': the rig poses'
        self.lead = G
        # each free mounting's parameter block (-1: fixed)
        self.block_m = np.where(self.free, np.cumsum(self.free) - 1, -1)
        self.by_cam = [np.flatnonzero(self.camera == i) for i in range(len(self.cameras))]
        self._views()
        self.keep = np.ones(n, dtype=bool)
        self.penalty = UNPROJECTED_PENALTY

    @property
    def n(self) -> int:
        """The number of parameters: ``6 (lead + F) + D``."""
        return 6 * (self.lead + self.F) + self.D

    def _views(self) -> None:
        """``view`` (N,) int, each corner's group of corners that share their camera's pose
        (rig frame, mounting, time offset, pose offsets, twist), and per view its first corner
        ``first``: :meth:`camera_points` builds one camera pose per view."""
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
        """``((R_g, P_g), (R_m, p_m))``: the rig poses and mountings of the parameters ``x``
        (n,)."""
        G, F, lo = self.G, self.F, 6 * self.lead
        rig = moved(self.R0g, self.P0g, x[: 6 * G].reshape(G, 6), slice(None))
        return rig, moved(self.R0m, self.p0m, x[lo : lo + 6 * F].reshape(F, 6), self.free)

    def errors(self, x: np.ndarray) -> np.ndarray:
        """(N, 2) px: every corner's projection at the parameters ``x`` minus its pixel (NaN:
        not projected, e.g. behind its camera or outside its model's field of view)."""
        x_cam = self.camera_points(x, self.world_points(x))
        out = np.empty_like(self.uv)
        for cam, sel in zip(self.cameras, self.by_cam, strict=True):
            out[sel] = cam.project(x_cam[sel])
        return out - self.uv

    def world_points(self, x: np.ndarray) -> np.ndarray:
        """(N, 3) m: the corners' map points in the world at the parameters ``x`` (here fixed:
        ``points``)."""
        return self.X

    def camera_points(self, x: np.ndarray, X: np.ndarray) -> np.ndarray:
        """(N, 3) m: each corner's map point ``X`` (N, 3) m in the world, in its camera's
        frame at the parameters ``x``: each view's camera pose (:meth:`_views`), then each
        corner through its view's."""
        (Rg, Pg), (Rm, pm) = self.unpack(x)
        f, v = self.first, self.view
        g, m = self.frame[f], self.mounting[f]
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
        return np.einsum("nji,nj->ni", Ow[v], X - p[v])

    def time_offsets(self, x: np.ndarray) -> np.ndarray:
        """(D,) s: the time offsets of the parameters ``x`` (the last ``D``)."""
        return x[self.n - self.D :]

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """(2 K,) px: the kept corners' errors, a corner that no longer projects at
        :data:`UNPROJECTED_PENALTY` times the loss scale of the last :meth:`solve` (1 px
        before any)."""
        e = self.errors(x)[self.keep]
        return np.where(np.isfinite(e), e, self.penalty).ravel()

    def corner_blocks(self, keep: np.ndarray) -> list:
        """The parameter blocks (6 each) of the kept corners (``keep`` (N,) bool; the K kept
        numbered in order): ``[(kept corners (k,) int, their blocks (k,) int), ...]``, each
        corner's rig pose's, then its mounting's (when free)."""
        g, m = self.frame[keep], self.block_m[self.mounting[keep]]
        return [(np.arange(len(g)), g), (np.flatnonzero(m >= 0), self.lead + m[m >= 0])]

    def sparsity(self) -> coo_matrix:
        """The Jacobian's nonzeros (2 K, n) for the kept corners: a corner's two rows depend on
        its parameter blocks (:meth:`corner_blocks`) and its time offset (``motion``)."""
        k = self.keep
        K = int(k.sum())
        r, c = (np.concatenate(a) for a in zip(*self.corner_blocks(k), strict=True))
        nb = (self.n - self.D) // 6
        sp = kron(coo_matrix((np.ones(len(r)), (r, c)), (K, nb)), np.ones((2, 6)))
        if not self.D:
            return sp
        d = self.motion[0][k]
        rd = np.flatnonzero(d >= 0)
        T = kron(coo_matrix((np.ones(len(rd)), (rd, d[rd])), (K, self.D)), np.ones((2, 1)))
        return hstack([sp, T]).tocoo()

    def robust_loss(self, f_scale: float) -> dict:
        """``least_squares``' arguments of the robust loss: SciPy's ``soft_l1`` on each
        coordinate at ``f_scale`` px."""
        return {"loss": "soft_l1", "f_scale": f_scale}

    def solve(
        self,
        f_scale: float,
        max_nfev: int = 300,
        ftol: float = 1e-8,
        xtol: float = 1e-8,
        verbose: int = 0,
    ) -> CornerSolution | None:
        """The parameters minimizing the corners' robust cost (:meth:`robust_loss` at
        ``f_scale`` px) from the start (SciPy ``least_squares``, ``trf``, ``lsmr``, the
        Jacobian's sparsity :meth:`sparsity`; its bounds ``max_nfev``, ``ftol``, ``xtol``), the
        corners not projected at the start left out (None: none projects)."""
        x0 = np.zeros(self.n)
        self.penalty = UNPROJECTED_PENALTY * f_scale
        self.keep = np.isfinite(self.errors(x0)).all(axis=1)
        if not self.keep.any():
            return None
        res = least_squares(self.residuals, x0, jac_sparsity=self.sparsity(), x_scale="jac",
                            method="trf", tr_solver="lsmr", ftol=ftol, xtol=xtol,
                            max_nfev=max_nfev, verbose=verbose,
                            **self.robust_loss(f_scale))  # fmt: skip
        rig, mounts = self.unpack(res.x)
        return CornerSolution(rig, mounts, self.keep.copy(), res)

    def mounting_covariance(self, sol: CornerSolution, clusters: np.ndarray | None = None) -> tuple:
        """``(covariances (F, 6, 6), std (D,) s)``: each free mounting's covariance over
        (rotation [rad, rig axes], position [m, rig frame]; ``parameters="rig"``) at ``sol``,
        the rig poses marginalized (:func:`marginal`: the pseudo-inverse of the Schur
        complement ``S`` of their blocks in ``H = J^T J``, ``J`` the robust-weighted Jacobian
        ``least_squares`` returns; a variant's blocks between the rig poses' and the
        mountings', :attr:`lead`, held at the solution). ``clusters`` None: ``s^2 S^-1`` with
        ``s^2 = 2 cost / (2 K - n)``, every corner's error independent; ``clusters`` (N,) int,
        each corner's group: the cluster-robust "sandwich" ``S^-1 (sum_c u_c u_c^T) S^-1``
        (``u_c`` the group's gradient of the cost on the mountings, the rig poses' part
        projected out), so corners that share an error (a tag map's, a camera model's) count
        once per group; ``std``: the time offsets' standard deviations (``motion``; empty
        without). A parameter that the kept corners do not constrain (e.g. a mounting or time
        offset none of whose corners is kept) gets an infinite variance (its rows and columns
        inf; an infinite std).

        Raises:
            ValueError: a solution without free mountings.
        """
        if not self.F:
            raise ValueError("RigCorners.mounting_covariance: no free mounting")
        J = csr_matrix(sol.result.jac)
        r = np.asarray(sol.result.fun, dtype=float)
        k, lo = 6 * self.G, 6 * self.lead
        Sinv, A, loose = marginal(hstack([J[:, :k], J[:, lo : lo + 6 * self.F + self.D]]), k)
        if clusters is None:
            C = 2.0 * float(sol.result.cost) / max(len(r) - self.n, 1) * Sinv
        else:
            c = np.repeat(np.asarray(clusters)[self.keep], 2)
            _, ci = np.unique(c, return_inverse=True)
            U = np.zeros((ci.max() + 1, A.shape[1]))
            np.add.at(U, ci, A * r[:, None])
            C = Sinv @ (U.T @ U) @ Sinv
        C = 0.5 * (C + C.T)
        C[loose, :] = C[:, loose] = np.inf
        blocks = np.array([C[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] for i in range(self.F)])
        return blocks, np.sqrt(np.diag(C)[6 * self.F :])
