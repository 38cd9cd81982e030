"""A TagSLAM recording's reference optimized in full: one bundle adjustment of every rig pose,
every tag's pose and every camera's mounting from all the corners (:func:`solve_joint`,
:func:`joint_reference` with its cache, :func:`with_reference` to measure against it).

TagSLAM publishes its rig poses while it runs; in ``optimizer_mode: fast`` they are not
optimized again with the later frames, so they can miss the corners by pixels. The joint
solution is what a full optimization of the same factor graph gives: the residuals are each
corner's error in the distorted image of its camera (the camera's own model,
:meth:`~rs_localizer.camera.CameraModel.project`), under a robust loss (SciPy's ``soft_l1``
at ``f_scale`` px: quadratic up to about that, linear beyond), minimized by SciPy's
``least_squares`` (``trf``, ``lsmr``, a finite-difference Jacobian of the known sparsity
``jac_sparsity``) from TagSLAM's reference. The gauge is TagSLAM's: the tags ``tagslam.yaml``
gives a pose (:attr:`~benchmarks.tagslam_data.RealRig.anchors`) and the first camera's
mounting (``camera_poses.yaml``'s prior) stay at the reference's; the tags keep their sizes.
Only the rig frames with a reference pose take part (their poses start at it).
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix
from scipy.spatial.transform import Rotation

from benchmarks.tagslam_data import RealRig, tag_corners

__all__ = [
    "CACHE",
    "JointSolution",
    "joint_reference",
    "soft_l1",
    "solve_joint",
    "with_reference",
]

#: where :func:`joint_reference` keeps its solutions (outside the repository)
CACHE = Path("/tmp/rs_localizer_joint_reference")
# (least_squares' bounds: at most 400 evaluations, a relative cost decrease of 1e-8 to stop
# at; every recording but test_14, whose mountings move a degree from the start, stops at the
# cost's within 50)
_MAX_NFEV, _FTOL = 400, 1e-8


@dataclass
class JointSolution:
    """A recording's joint solution (:func:`solve_joint`).

    Attributes:
        poses: stamp (s) -> ``(R (3, 3), C (3,) m)``: the rig's pose ``x_rig = R X + C``.
        tags: tag id -> ``(R (3, 3), p (3,) m, side m)``: ``x_map = R x_tag + p``.
        mounts: camera name -> ``(R (3, 3), c (3,) m)``: ``x_cam = R x_rig + c``.
        info: ``seconds`` (CPU), ``nfev``, ``status`` (``least_squares``'), ``cost_start``,
            ``cost`` (its robust cost, px^2), ``corners``, ``outliers`` (corners left out:
            not projected at the start).
    """

    poses: dict
    tags: dict
    mounts: dict
    info: dict = field(default_factory=dict)


def _observations(rig: RealRig):
    """The corners of the rig frames with a reference pose: frame, tag, corner and camera
    indices and the pixels."""
    names = list(rig.cameras)
    stamps = [s for s, _ in rig.frames if s in rig.reference]
    ids = sorted(rig.tags)
    t_of = {i: k for k, i in enumerate(ids)}
    f_idx, t_idx, c_idx, uvs = [], [], [], []
    views_of = dict(rig.frames)
    for f, stamp in enumerate(stamps):
        for name, (uv, _) in views_of[stamp].items():
            tags = rig.tag_ids[stamp][name]
            f_idx.append(np.full(len(uv), f))
            t_idx.append(np.repeat([t_of[i] for i in tags], 4))
            c_idx.append(np.full(len(uv), names.index(name)))
            uvs.append(uv)
    n = sum(len(u) for u in uvs)
    return (stamps, ids, names, np.concatenate(f_idx), np.concatenate(t_idx),
            np.tile(np.arange(4), n // 4), np.concatenate(c_idx), np.concatenate(uvs))  # fmt: skip


def soft_l1(s: np.ndarray, f_scale: float) -> np.ndarray:
    """The robust loss of corners of squared error ``s`` (px^2): ``2 f^2 (sqrt(1 + s / f^2) -
    1)`` (``f`` = ``f_scale`` px): ``s`` for small errors, ``2 f |e|`` for large ones (SciPy's
    ``soft_l1``, applied to a corner's error, both coordinates together)."""
    return 2 * f_scale**2 * (np.sqrt(1 + s / f_scale**2) - 1)


class _Problem:
    """The bundle adjustment's parameters (increments from the start: a rotation vector
    composed on the left, a translation added; rig poses, then the free tags, then the free
    mountings) and residuals (px, the distorted image)."""

    def __init__(self, rig: RealRig, f_scale: float):
        self.f_scale = f_scale
        (self.stamps, self.ids, self.names, self.f, self.t, self.k, self.c,
         self.uv) = _observations(rig)  # fmt: skip
        self.cams = [rig.cameras[n] for n in self.names]
        self.R0f = np.array([rig.reference[s][0] for s in self.stamps])
        self.C0f = np.array([rig.reference[s][1] for s in self.stamps])
        self.R0t = np.array([rig.tags[i][0] for i in self.ids])
        self.p0t = np.array([rig.tags[i][1] for i in self.ids])
        self.local = np.array([tag_corners(rig.tags[i][2]) for i in self.ids])  # (T, 4, 3)
        self.R0m = np.array([rig.mounts[n][0] for n in self.names])
        self.c0m = np.array([rig.mounts[n][1] for n in self.names])
        self.free_t = np.array([i not in rig.anchors for i in self.ids])
        self.free_m = np.arange(len(self.names)) > 0
        self.F, self.T, self.M = len(self.stamps), int(self.free_t.sum()), len(self.names) - 1
        self.n = 6 * (self.F + self.T + self.M)
        self.by_cam = [np.flatnonzero(self.c == i) for i in range(len(self.names))]
        self.keep = np.ones(len(self.uv), dtype=bool)

    def unpack(self, x: np.ndarray):
        """``(R_f, C_f, R_t, p_t, R_m, c_m)`` of the parameters ``x``."""
        F, T = self.F, self.T
        d = x[: 6 * F].reshape(F, 6)
        Rf = Rotation.from_rotvec(d[:, :3]).as_matrix() @ self.R0f
        Cf = self.C0f + d[:, 3:]
        Rt, pt = self.R0t.copy(), self.p0t.copy()
        d = x[6 * F : 6 * (F + T)].reshape(T, 6)
        if T:
            Rt[self.free_t] = Rotation.from_rotvec(d[:, :3]).as_matrix() @ self.R0t[self.free_t]
            pt[self.free_t] += d[:, 3:]
        Rm, cm = self.R0m.copy(), self.c0m.copy()
        d = x[6 * (F + T) :].reshape(self.M, 6)
        if self.M:
            Rm[self.free_m] = Rotation.from_rotvec(d[:, :3]).as_matrix() @ self.R0m[self.free_m]
            cm[self.free_m] += d[:, 3:]
        return Rf, Cf, Rt, pt, Rm, cm

    def errors(self, x: np.ndarray) -> np.ndarray:
        """(N, 2) every corner's projection minus its pixel (px; nan: not projected)."""
        Rf, Cf, Rt, pt, Rm, cm = self.unpack(x)
        t, f, c = self.t, self.f, self.c
        X = np.einsum("nij,nj->ni", Rt[t], self.local[t, self.k]) + pt[t]
        X = np.einsum("nij,nj->ni", Rf[f], X) + Cf[f]
        X = np.einsum("nij,nj->ni", Rm[c], X) + cm[c]
        out = np.empty_like(self.uv)
        for cam, sel in zip(self.cams, self.by_cam, strict=True):
            out[sel] = cam.project(X[sel])
        return out - self.uv

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """Each kept corner's error scaled to the robust loss: ``e sqrt(rho(|e|^2) / |e|^2)``
        (their squares sum to the loss over the corners, :func:`soft_l1`)."""
        e = self.errors(x)[self.keep]
        e = np.where(np.isfinite(e), e, 0.0)
        s = (e * e).sum(axis=1)
        w = np.sqrt(soft_l1(s, self.f_scale) / np.where(s > 0, s, 1.0))
        return (e * np.where(s > 0, w, 1.0)[:, None]).ravel()

    def sparsity(self):
        """The Jacobian's nonzeros: a corner's two rows depend on its rig pose, its tag (when
        free) and its camera's mounting (when free)."""
        n = int(self.keep.sum())
        f, t, c = self.f[self.keep], self.t[self.keep], self.c[self.keep]
        free_t = np.cumsum(self.free_t) - 1  # (the free tag's parameter block)
        cols = [6 * f]
        rows = [np.arange(n)]
        ok = self.free_t[t]
        cols.append(6 * (self.F + free_t[t[ok]]))
        rows.append(np.flatnonzero(ok))
        ok = c > 0
        cols.append(6 * (self.F + self.T + c[ok] - 1))
        rows.append(np.flatnonzero(ok))
        r = np.concatenate(rows)
        col = np.concatenate(cols)
        rr = (2 * r[:, None] + np.arange(2)[None, :])[:, :, None]
        cc = (col[:, None] + np.arange(6)[None, :])[:, None, :]
        rr, cc = np.broadcast_arrays(rr, cc)
        return coo_matrix((np.ones(rr.size), (rr.ravel(), cc.ravel())), shape=(2 * n, self.n))


def solve_joint(
    rig: RealRig,
    f_scale: float = 2.0,
    max_nfev: int = _MAX_NFEV,
    ftol: float = _FTOL,
    verbose: int = 0,
) -> JointSolution:
    """The joint bundle adjustment of ``rig`` (a :class:`~benchmarks.tagslam_data.RealRig`
    with its tag poses, :func:`~benchmarks.tagslam_data.load_tagslam`), started at its
    reference: every rig pose of a rig frame with a reference pose, every tag's pose but the
    anchored ones', every camera's mounting but the first camera's, from every corner of
    those rig frames (px in the distorted image of its camera, ``soft_l1`` loss at
    ``f_scale`` px; corners the start does not project left out). ``max_nfev`` and ``ftol``:
    ``least_squares``' bound on its evaluations and its relative cost decrease to stop at.

    Raises:
        ValueError: the rig has no tag poses or no rig frame with a reference pose.
    """
    if not rig.tags or not any(s in rig.reference for s, _ in rig.frames):
        raise ValueError(f"{rig.name}: no tag poses or no rig frame with a reference pose")
    t0 = time.process_time()
    p = _Problem(rig, f_scale)
    x0 = np.zeros(p.n)
    p.keep = np.isfinite(p.errors(x0)).all(axis=1)
    res = least_squares(p.residuals, x0, jac_sparsity=p.sparsity(), x_scale="jac",
                        method="trf", tr_solver="lsmr", max_nfev=max_nfev,
                        ftol=ftol, xtol=1e-12, verbose=verbose)  # fmt: skip
    Rf, Cf, Rt, pt, Rm, cm = p.unpack(res.x)
    info = {
        "seconds": time.process_time() - t0,
        "nfev": int(res.nfev),
        "status": int(res.status),
        "cost_start": 0.5 * float((p.residuals(x0) ** 2).sum()),
        "cost": float(res.cost),
        "corners": len(p.uv),
        "outliers": int((~p.keep).sum()),
    }
    return JointSolution(
        {s: (Rf[i], Cf[i]) for i, s in enumerate(p.stamps)},
        {i: (Rt[k], pt[k], rig.tags[i][2]) for k, i in enumerate(p.ids)},
        {n: (Rm[k], cm[k]) for k, n in enumerate(p.names)},
        info,
    )


def _key(rig: RealRig, f_scale: float) -> str:
    """A digest of what the solution depends on: the corners, the start, ``f_scale`` and
    :func:`solve_joint`'s bounds."""
    h = hashlib.sha1(repr((f_scale, _MAX_NFEV, _FTOL)).encode())
    for stamp, views in rig.frames:
        if stamp not in rig.reference:
            continue
        h.update(np.float64(stamp).tobytes())
        h.update(np.ascontiguousarray(rig.reference[stamp][1]).tobytes())
        for name in sorted(views):
            h.update(name.encode())
            h.update(np.ascontiguousarray(views[name][0]).tobytes())
    for i in sorted(rig.tags):
        h.update(np.ascontiguousarray(rig.tags[i][1]).tobytes())
    return h.hexdigest()[:16]


def joint_reference(
    rig: RealRig, cache: Path | None = CACHE, f_scale: float = 2.0, verbose: int = 0
) -> JointSolution:
    """:func:`solve_joint`'s solution of ``rig``, read from ``cache`` (a folder; None: none)
    when it holds one of the same corners, start and ``f_scale``, else solved and saved
    there (``<name>_<digest>.npz``)."""
    path = None if cache is None else Path(cache) / f"{rig.name}_{_key(rig, f_scale)}.npz"
    if path is not None and path.is_file():
        z = np.load(path, allow_pickle=False)
        names = [str(n) for n in z["names"]]
        return JointSolution(
            {float(s): (R, C) for s, R, C in zip(z["stamps"], z["Rf"], z["Cf"], strict=True)},
            {
                int(i): (R, p, float(w))
                for i, R, p, w in zip(z["ids"], z["Rt"], z["pt"], z["side"], strict=True)
            },
            {n: (R, c) for n, R, c in zip(names, z["Rm"], z["cm"], strict=True)},
            {k[5:]: z[k].item() for k in z.files if k.startswith("info_")},
        )
    sol = solve_joint(rig, f_scale, verbose=verbose)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        stamps = list(sol.poses)
        ids = list(sol.tags)
        names = list(sol.mounts)
        np.savez(
            path,
            stamps=np.array(stamps),
            Rf=np.array([sol.poses[s][0] for s in stamps]),
            Cf=np.array([sol.poses[s][1] for s in stamps]),
            ids=np.array(ids),
            Rt=np.array([sol.tags[i][0] for i in ids]),
            pt=np.array([sol.tags[i][1] for i in ids]),
            side=np.array([sol.tags[i][2] for i in ids]),
            names=np.array(names),
            Rm=np.array([sol.mounts[n][0] for n in names]),
            cm=np.array([sol.mounts[n][1] for n in names]),
            **{f"info_{k}": v for k, v in sol.info.items()},
        )
    return sol


def with_reference(rig: RealRig, sol: JointSolution) -> RealRig:
    """``rig`` measured against ``sol``: its views' map points are ``sol``'s tags' corners,
    its mountings ``sol``'s, its reference poses ``sol``'s (the rig frames without one keep
    none); the detections, cameras and grouping are ``rig``'s."""
    corners = {i: tag_corners(w) @ R.T + p for i, (R, p, w) in sol.tags.items()}
    frames = [
        (stamp, {n: (uv, np.concatenate([corners[i] for i in rig.tag_ids[stamp][n]]))
                 for n, (uv, _) in views.items()})
        for stamp, views in rig.frames
    ]  # fmt: skip
    return RealRig(rig.cameras, dict(sol.mounts), frames, dict(sol.poses), rig.name,
                   rig.stamps_shared, rig.tolerance, rig.messages, dict(sol.tags),
                   rig.tag_ids, rig.anchors)  # fmt: skip
