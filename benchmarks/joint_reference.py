"""A TagSLAM recording's reference optimized in full: one bundle adjustment of every rig pose,
every tag's pose and every camera's mounting from all the corners (:func:`solve_joint`,
:func:`joint_reference` with its cache, :func:`with_reference` to measure against it).

TagSLAM publishes its rig poses while it runs; in ``optimizer_mode: fast`` they are not
optimized again with the later frames, so they can miss the corners by pixels. The joint
solution is what a full optimization of the same factor graph gives: the residuals are each
corner's error in the distorted image of its camera (the camera's own model,
:meth:`~rs_localizer.camera.CameraModel.project`) through its rig pose, its camera's mounting
and its tag's pose, the problem ``calibrate-rig`` refines its mountings on
(:class:`~rs_localizer.calibration.corners.RigCorners`) with the tags' poses free and TagSLAM's
parameters (:class:`TagSLAMCorners`), under a robust loss (:func:`soft_l1` of each corner's
distance at ``f_scale`` px: quadratic up to about that, linear beyond), minimized by SciPy's
``least_squares`` (``trf``, ``lsmr``, a finite-difference Jacobian of the known sparsity
``jac_sparsity``) from TagSLAM's reference. The gauge is TagSLAM's: the tags ``tagslam.yaml``
gives a pose (:attr:`~benchmarks.tagslam_data.RealRig.anchors`) and the first camera's mounting
(``camera_poses.yaml``'s prior) stay at the reference's; the tags keep their sizes.
Only the rig frames with a reference pose take part (their poses start at it).
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from benchmarks.tagslam_data import RealRig, tag_corners
from rs_localizer.calibration.corners import CornerSolution, RigCorners
from rs_localizer.geometry import moved

__all__ = [
    "CACHE",
    "JointSolution",
    "TagPoints",
    "TagSLAMCorners",
    "cached_solution",
    "halves",
    "joint_reference",
    "main",
    "mounting_coverage",
    "print_coverage",
    "recording",
    "recording_parser",
    "rig_part",
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

    def world(self, R: np.ndarray | None = None, p: np.ndarray | None = None) -> np.ndarray:
        """(N, 3) m: the corners in the world with the tags at ``R`` (T, 3, 3) tag -> world,
        ``p`` (T, 3) m (None: at the start)."""
        R, p = (self.R, self.p) if R is None else (R, p)
        return np.einsum("nij,nj->ni", R[self.tag], self.local) + p[self.tag]


class TagSLAMCorners(RigCorners):
    """:class:`~rs_localizer.calibration.corners.RigCorners` as TagSLAM parameterizes its
    factor graph: the rig poses and mountings are the inverse transforms, world -> rig
    (``x_rig = R_f x_world + C_f``) and rig -> camera (``x_cam = R x_rig + c``, as
    :class:`~rs_localizer.frames.Mounting`), their increments composed on their left (rig and
    camera axes); the map points fixed or the corners of tags whose poses (tag -> world,
    ``x_world = R_t x_tag + p_t``, increments composed on the left, world axes) may be
    adjusted (:class:`TagPoints`); each corner's error under :func:`soft_l1` of its distance
    (:meth:`solve`'s ``loss``). The parameters are the rig poses', the free tags', then the
    free mountings' (6 each). Its solution's ``rig`` and ``mounts`` are the inverse transforms
    (``(R_f, C_f)``, ``(R, c)``); the tags' poses: :meth:`tag_poses`.

    Args:
        uv, cameras, camera, frame, mounting, free: as ``RigCorners``'.
        rig: ``(R_f (G, 3, 3), C_f (G, 3) m)`` and ``mounts``: ``(R (M, 3, 3), c (M, 3) m)``,
            the rig poses and mountings to start from.
        points: (N, 3) m, the corners' map points in the world (fixed), or :class:`TagPoints`.

    Raises:
        ValueError: as ``RigCorners``' (inconsistent lengths, an index out of range).
    """

    def __init__(self, uv, cameras, camera, frame, mounting, rig, mounts, free,
                 points: np.ndarray | TagPoints):  # fmt: skip
        self.tags = points if isinstance(points, TagPoints) else None
        X = points if self.tags is None else self.tags.world()
        super().__init__(uv, cameras, camera, frame, mounting, rig, mounts, free, X)
        self.T = int(self.tags.free.sum()) if self.tags is not None else 0
        self.lead = self.G + self.T
        self.corner_loss = True
        if self.tags is not None:  # (each free tag's parameter block, -1: fixed)
            self.block_t = np.where(self.tags.free, np.cumsum(self.tags.free) - 1, -1)

    def tag_poses(self, x: np.ndarray) -> tuple | None:
        """``(R_t (T, 3, 3), p_t (T, 3) m)``: every tag's pose at the parameters ``x`` (the
        fixed ones as given); None without :class:`TagPoints`."""
        t = self.tags
        if t is None:
            return None
        return moved(t.R, t.p, x[6 * self.G : 6 * self.lead].reshape(self.T, 6), t.free)

    def world_points(self, x: np.ndarray) -> np.ndarray:
        """(N, 3) m: the fixed map points, or the tags' corners at :meth:`tag_poses`."""
        if self.tags is None:
            return super().world_points(x)
        return self.tags.world(*self.tag_poses(x))

    def camera_points(self, x: np.ndarray, X: np.ndarray) -> np.ndarray:
        """(N, 3) m: each corner's map point ``X`` (N, 3) m in its camera's frame at the
        parameters ``x``: each view's world -> camera transform ``(R R_f, R C_f + c)``, then
        each corner through its view's."""
        (Rf, Cf), (Rm, cm) = self.unpack(x)
        f, v = self.first, self.view
        g, m = self.frame[f], self.mounting[f]
        R, c = Rm[m] @ Rf[g], np.einsum("nij,nj->ni", Rm[m], Cf[g]) + cm[m]
        return np.einsum("nij,nj->ni", R[v], X) + c[v]

    def corner_blocks(self, keep: np.ndarray) -> list:
        """``RigCorners``' blocks with each kept corner's tag's (when free) between its rig
        pose's and its mounting's."""
        rig, mounts = super().corner_blocks(keep)
        if self.tags is None:
            return [rig, mounts]
        t = self.block_t[self.tags.tag[keep]]
        return [rig, (np.flatnonzero(t >= 0), self.G + t[t >= 0]), mounts]

    def residuals(self, x: np.ndarray, corner_scale: float | None = None) -> np.ndarray:
        """(2 K,) px: ``RigCorners``' residuals; ``corner_scale``: px, each corner's error
        scaled to the :func:`soft_l1` loss of its distance (``e sqrt(rho(|e|^2) / |e|^2)``);
        None: as they are."""
        r = super().residuals(x)
        if corner_scale is None:
            return r
        e = r.reshape(-1, 2)
        s = (e * e).sum(axis=1)
        w = np.sqrt(soft_l1(s, corner_scale) / np.where(s > 0, s, 1.0))
        return (e * np.where(s > 0, w, 1.0)[:, None]).ravel()

    def robust_loss(self, f_scale: float) -> dict:
        """:func:`soft_l1` of each corner's distance at ``f_scale`` px (:meth:`residuals`), or
        with ``loss="soft_l1"`` SciPy's on each coordinate."""
        if self.corner_loss:
            return {"kwargs": {"corner_scale": f_scale}}
        return super().robust_loss(f_scale)

    def solve(
        self, f_scale: float, loss: str = "corner_soft_l1", **bounds
    ) -> CornerSolution | None:
        """``RigCorners``' solve (``bounds``: its ``max_nfev``, ``ftol``, ``xtol``,
        ``verbose``) under ``loss``: ``"corner_soft_l1"``, :func:`soft_l1` of each corner's
        distance at ``f_scale`` px, or ``"soft_l1"``, SciPy's on each coordinate.

        Raises:
            ValueError: an unknown ``loss``.
        """
        if loss not in ("soft_l1", "corner_soft_l1"):
            raise ValueError(f"TagSLAMCorners.solve: unknown loss {loss!r}")
        self.corner_loss = loss == "corner_soft_l1"
        return super().solve(f_scale, **bounds)

    def mounting_covariance(self, sol, clusters=None) -> tuple:
        """Not given in the inverse transforms.

        Raises:
            ValueError: always.
        """
        raise ValueError("TagSLAMCorners.mounting_covariance: no covariance of the inverse "
                         "transforms")  # fmt: skip


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


def cached_solution(path: Path | None, solve) -> JointSolution:
    """The solution kept at ``path`` (an ``.npz``; None: none kept), else ``solve()``'s (->
    :class:`JointSolution`), saved there."""
    if path is not None and path.is_file():
        z = np.load(path, allow_pickle=False)
        return JointSolution(
            {float(s): (R, C) for s, R, C in zip(z["stamps"], z["Rf"], z["Cf"], strict=True)},
            {
                int(i): (R, p, float(w))
                for i, R, p, w in zip(z["ids"], z["Rt"], z["pt"], z["side"], strict=True)
            },
            {str(n): (R, c) for n, R, c in zip(z["names"], z["Rm"], z["cm"], strict=True)},
            {k[5:]: z[k].item() for k in z.files if k.startswith("info_")},
        )
    sol = solve()
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        stamps, ids, names = list(sol.poses), list(sol.tags), list(sol.mounts)
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
    stamps, ids, names, f, t, k, c, uv = _observations(rig)
    R0f = np.array([rig.reference[s][0] for s in stamps])
    C0f = np.array([rig.reference[s][1] for s in stamps])
    R0m = np.array([rig.mounts[n][0] for n in names])
    c0m = np.array([rig.mounts[n][1] for n in names])
    tags = TagPoints(
        t,
        np.array([tag_corners(rig.tags[i][2]) for i in ids])[t, k],
        np.array([rig.tags[i][0] for i in ids]),
        np.array([rig.tags[i][1] for i in ids]),
        np.array([i not in rig.anchors for i in ids]),
    )
    problem = TagSLAMCorners(uv, [rig.cameras[n] for n in names], c, f, c, (R0f, C0f),
                             (R0m, c0m), np.arange(len(names)) > 0, tags)  # fmt: skip
    sol = problem.solve(f_scale, loss="corner_soft_l1", max_nfev=max_nfev, ftol=ftol,
                        xtol=1e-12, verbose=verbose)  # fmt: skip
    if sol is None:
        raise ValueError(f"{rig.name}: no corner projects at TagSLAM's solution")
    (Rf, Cf), (Rc, cm), (Rt, pt) = sol.rig, sol.mounts, problem.tag_poses(sol.result.x)
    res = sol.result
    info = {
        "seconds": time.process_time() - t0,
        "nfev": int(res.nfev),
        "status": int(res.status),
        "cost_start": 0.5 * float((problem.residuals(np.zeros(problem.n), f_scale) ** 2).sum()),
        "cost": float(res.cost),
        "corners": len(uv),
        "outliers": int((~sol.keep).sum()),
    }
    return JointSolution(
        {s: (Rf[i], Cf[i]) for i, s in enumerate(stamps)},
        {i: (Rt[j], pt[j], rig.tags[i][2]) for j, i in enumerate(ids)},
        {n: (Rc[j], cm[j]) for j, n in enumerate(names)},
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
    return cached_solution(path, lambda: solve_joint(rig, f_scale, verbose=verbose))


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


def rig_part(rig: RealRig, frames: list) -> RealRig:
    """``rig`` with only ``frames`` (a part of its rig frames)."""
    return RealRig(rig.cameras, rig.mounts, frames, rig.reference, rig.name, rig.stamps_shared,
                   rig.tolerance, rig.messages, rig.tags, rig.tag_ids, rig.anchors)  # fmt: skip


def mounting_coverage(est: dict, mounts: dict, first: str) -> dict:
    """Each calibrated mounting (``est``: camera -> ``MountingEstimate``) against a
    reference's (``mounts``: camera -> ``(R, c)``, ``x_cam = R x_rig + c``; the reference
    camera ``first`` left out): camera -> ``{"error_deg", "error_mm", "std_deg", "std_mm",
    "k": the largest |error| / std over the 6 axes (rotation rig axes, position), "nees":
    the error's squared Mahalanobis distance in the mounting's covariance (6 degrees of
    freedom), "within": k <= 3 and nees below the 99.73 % chi-square quantile}``."""
    from scipy.stats import chi2

    from rs_localizer.geometry import matrix_to_rotvec

    out = {}
    for n, e in est.items():
        if n == first or n not in mounts or e.mount.covariance is None:
            continue
        R, c = mounts[n]
        err = np.r_[matrix_to_rotvec(e.mount.R.T @ R), e.mount.position + R.T @ c]
        C = e.mount.covariance
        k = float(np.max(np.abs(err) / np.sqrt(np.diag(C))))
        nees = float(err @ np.linalg.lstsq(C, err, rcond=None)[0])
        out[n] = {
            "error_deg": float(np.rad2deg(np.linalg.norm(err[:3]))),
            "error_mm": float(1e3 * np.linalg.norm(err[3:])),
            "std_deg": e.std_deg,
            "std_mm": e.std_mm,
            "k": k,
            "nees": nees,
            "within": bool(k <= 3.0 and nees <= chi2.ppf(0.9973, 6)),
        }
    return out


def print_coverage(cover: dict, cameras) -> None:
    """One line per camera of ``cameras`` in ``cover`` (:func:`mounting_coverage`): its error
    (deg, mm), std (deg, mm), largest |error| / std of the 6 axes, NEES and whether it is
    within 3 sigma."""
    for n, c in ((n, cover[n]) for n in cameras if n in cover):
        print(
            f"  {n}: {c['error_deg']:.3f} deg {c['error_mm']:.1f} mm; std {c['std_deg']:.3f}"
            f" deg {c['std_mm']:.1f} mm; {c['k']:.1f}; {c['nees']:.1f}; within 3 sigma: "
            f"{'yes' if c['within'] else 'no'}"
        )


def halves(est_a: dict, est_b: dict, first: str) -> dict:
    """Two calibrations of the same rig from disjoint parts of a video (camera ->
    ``MountingEstimate``; the reference camera ``first`` left out) against each other, an
    independent check of their std (a reference solved from the same corners shares their
    errors): camera -> ``{"diff_deg", "diff_mm", "k": the largest |difference| / std over
    the 6 axes (rotation rig axes, position; the difference's covariance: the sum of the
    two), "std_deg", "std_mm": the difference's std (norms over the 3 axes)}``."""
    from rs_localizer.geometry import matrix_to_rotvec

    out = {}
    for n, a in est_a.items():
        b = est_b.get(n)
        if n == first or b is None or a.mount.covariance is None or b.mount.covariance is None:
            continue
        d = np.r_[matrix_to_rotvec(a.mount.R.T @ b.mount.R), a.mount.position - b.mount.position]
        s = np.sqrt(np.diag(a.mount.covariance + b.mount.covariance))
        out[n] = {
            "diff_deg": float(np.rad2deg(np.linalg.norm(d[:3]))),
            "diff_mm": float(1e3 * np.linalg.norm(d[3:])),
            "k": float(np.max(np.abs(d) / s)),
            "std_deg": float(np.rad2deg(np.linalg.norm(s[:3]))),
            "std_mm": float(1e3 * np.linalg.norm(s[3:])),
        }
    return out


def recording_parser(doc: str):
    """The command line of a benchmark over one TagSLAM recording: ``--folder`` (the
    recording), ``--cache`` (the joint solutions' folder); ``doc``: the benchmark's ``main``
    docstring, whose first line the help prints."""
    import argparse

    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--folder", type=Path, required=True, help="a TagSLAM test folder")
    ap.add_argument("--cache", type=Path, default=CACHE, help="the joint solutions' folder")
    return ap


def recording(a) -> tuple[RealRig, JointSolution] | None:
    """The recording in ``a.folder`` (:func:`~benchmarks.tagslam_data.load_tagslam`) and its
    joint solution (:func:`joint_reference`, cached in ``a.cache``); None, said on stdout,
    when the folder is absent (the data is not on this machine)."""
    from benchmarks.tagslam_data import load_tagslam

    if not a.folder.is_dir():
        print(f"{a.folder} absent: nothing to measure")
        return None
    rig = load_tagslam(a.folder)
    return rig, joint_reference(rig, a.cache)


def main(argv: list[str] | None = None) -> None:
    """``python -m benchmarks.joint_reference --folder PATH/test_N``: the recording's joint
    solution, then ``calibrate-rig`` (the first of ``--min-inliers`` that calibrates every
    camera) on TagSLAM's tag map against TagSLAM's extrinsics and on the joint solution's
    against its mountings: each mounting's error, std, the largest error over std of its 6
    axes and its NEES; then the rig posed with those mountings, rig poses within 3 sigma of
    the reference's (``real_rig_mountings.calibrated_rig_run``); on the joint solution's map also
    calibrate-rig on each half of the video, the halves against each other (:func:`halves`:
    an independent check of the std, which the joint solution, solved from the same corners,
    is not)."""
    from benchmarks.real_rig_mountings import (
        calibrate_estimates,
        calibrate_every_camera,
        calibrated_rig_run,
    )

    ap = recording_parser(main.__doc__)
    ap.add_argument("--min-inliers", type=int, nargs="+", default=[20, 8])
    a = ap.parse_args(argv)
    if (loaded := recording(a)) is None:
        return
    rig, sol = loaded
    print(f"{rig.name}: joint solution {sol.info}")
    first = next(iter(rig.cameras))
    for label, r in (("TagSLAM's", rig), ("the joint solution's", with_reference(rig, sol))):

        def failed(mi: int, exc: ValueError, label: str = label) -> None:
            print(f"calibrate-rig (min_inliers {mi}) on {label} tag map: {exc}")

        est, mi = calibrate_every_camera(r, a.min_inliers, failed)
        if est is None:
            continue
        e = next(v for k, v in est.items() if k != first)
        how = f"refined on the corners, misfit {e.corner_misfit:.1f}" if e.corners_refined else ""
        print(
            f"calibrate-rig (min_inliers {mi}) on {label} tag map vs its mountings ("
            + (how or "pose-level")
            + "): error deg, mm; std deg, mm; largest |error| / std of the 6 axes; NEES (6)"
        )
        print_coverage(mounting_coverage(est, r.mounts, first), r.cameras)
        for v, (inside, posed, total) in calibrated_rig_run(r, est).items():
            print(
                f"  the rig with these mountings ({v}): {inside} of {posed} rig poses within "
                f"3 sigma of the reference ({100 * inside / max(posed, 1):.1f} %; {total} rig "
                "frames)"
            )
        if label == "TagSLAM's":
            continue
        h = len(r.frames) // 2
        try:
            video_halves = (r.frames[:h], r.frames[h:])
            parts = [calibrate_estimates(rig_part(r, fr), mi) for fr in video_halves]
        except ValueError as exc:
            print(f"  each half of the video: {exc}")
            continue
        print(
            f"  calibrate-rig on each half of the video (min_inliers {mi}), the halves against "
            "each other: difference deg, mm; its std deg, mm (both halves'); largest "
            "|difference| / std of the 6 axes"
        )
        for n, c in halves(*parts, first).items():
            print(
                f"    {n}: {c['diff_deg']:.3f} deg {c['diff_mm']:.1f} mm; std "
                f"{c['std_deg']:.3f} deg {c['std_mm']:.1f} mm; {c['k']:.1f}"
            )


if __name__ == "__main__":
    main()
