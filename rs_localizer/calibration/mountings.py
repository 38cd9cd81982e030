"""A rig's camera mountings from a video of a known map (:func:`calibrate_mountings`, what
``rs-localizer calibrate-rig`` runs), each with its covariance, which the rig estimator adds
to the rig pose's (:attr:`~rs_localizer.frames.Mounting.covariance`). The method, step by
step, with its measurements: docs/rig_node.md, "Mountings from data" (its steps are cited
below as "step N").
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from itertools import permutations
from typing import Any, NamedTuple

import numpy as np
from scipy.linalg import block_diag
from scipy.optimize import least_squares
from scipy.sparse import bmat, coo_matrix, identity, kron
from scipy.stats import chi2

from ..camera import reference_stamp_ns
from ..estimation.estimate import estimate_rs_pose
from ..estimation.options import EstimateOptions
from ..frames import Mounting, base_pose
from ..geometry import compose, matrix_to_rotvec, moved, rotvec_to_matrix
from .corners import CornerSolution, RigCorners, marginal

__all__ = [
    "MOUNTING_BIAS_SHARE",
    "TIME_OFFSET_PRIOR",
    "TIME_OFFSET_ROUNDS",
    "TIME_OFFSET_TOL",
    "MountingEstimate",
    "calibrate_mountings",
]


@dataclass(frozen=True, eq=False)
class MountingEstimate:
    """A camera's mounting estimated from a rig video (:func:`calibrate_mountings`).

    Attributes:
        name: the camera. mount: its :class:`~rs_localizer.frames.Mounting` (``x_cam = R
            x_rig + c``) with its ``covariance`` (step 5; None for the reference camera).
        frames: rig frames the camera's pose entered the adjustment with; rejected: its camera
            frames left out as outliers.
        std_deg, std_mm: standard deviation of the mounting's rotation (deg) and position (mm),
            norms over the three axes, from ``mount.covariance``; zero for the reference.
        scatter_deg, scatter_mm: one camera frame's pose error about the adjusted rig (RMS).
        time_offset: s added to the camera's stamps (the given one, or the estimate);
            time_offset_std: s, the estimate's standard deviation (NaN: not estimated).
        corners_refined: the mounting was refined on the corners (step 4); False for a camera
            no corner of the refinement constrains (it keeps its pose-level estimate).
        exposure_offset: s, the time offset the pose-level adjustment shows when the cameras
            do not expose together (:data:`EXPOSED_APART_SHARE`); NaN otherwise.
        corner_misfit: the squared step from the pose-level to the refined mountings in the
            pose-level covariance per degree of freedom (at least :data:`MISFIT_FLOOR`, one for
            the rig); NaN when not refined."""

    name: str
    mount: Mounting
    frames: int
    rejected: int
    std_deg: float
    std_mm: float
    scatter_deg: float
    scatter_mm: float
    time_offset: float = 0.0
    time_offset_std: float = float("nan")
    corners_refined: bool = False
    exposure_offset: float = float("nan")
    corner_misfit: float = float("nan")


#: ``estimate_time_offsets``: the adjustment is run again at the time offsets found until
#: they change by less than this (s) ...
TIME_OFFSET_TOL = 1e-4
#: ... at most this many times
TIME_OFFSET_ROUNDS = 4
#: s: the standard deviation of a weak prior at 0 on each time offset, so that a video whose
#: rig hardly moves (no information on the offsets) still gives the mountings; the offset's
#: std then says it was not seen
TIME_OFFSET_PRIOR = 1.0

#: a camera whose time offset moves a corner by more than this share of the RANSAC threshold
#: does not expose with the reference (:func:`_exposed_apart`): the refinement on the corners
#: then adjusts a time offset per camera, else the mountings would take up the rig's motion
EXPOSED_APART_SHARE = 0.25

#: the systematic part of a mounting's standard deviation (:class:`MountingEstimate`), as a
#: share of one rig frame's scatter of the rotation and of the position: the bias of the
#: single-camera poses, which averaging over a video does not remove
MOUNTING_BIAS_SHARE = {"rotation": 0.1, "position": 0.2}

#: rig frames whose camera's whitened pose error (squared) is beyond this quantile of the
#: chi-square distribution with 6 degrees of freedom (times the median's scale) are left out
#: of the mountings' adjustment
_OUTLIER_QUANTILE = 0.999

#: the least misfit of a refined mounting's two estimates (:func:`_corner_covariance`): at it
#: no systematic error is added to the corners' covariance
MISFIT_FLOOR = 1.0

#: s: the longest interval between a camera's two frames to interpolate over (:func:`_carried`)
MAX_STEP = 0.1

#: ``least_squares``' bound on the evaluations of :func:`_refine_on_corners`
_CORNER_NFEV = 300

#: the rig frames of a refined mounting's covariance fall in this many runs of consecutive rig
#: frames, each run's corners one group (:func:`_corner_covariance`)
CORNER_BLOCKS = 10


def _std_of_mean(d: np.ndarray) -> float:
    """The standard deviation (norm over the axes) of the mean of deviations ``d`` (n, k) in
    time order by batch means (neighbouring frames share slow errors): the scatter of the means
    of 8 runs of consecutive frames; 0 with fewer than 2 frames per run."""
    n = len(d)
    k = min(8, n // 2)
    if k < 2:
        return 0.0
    means = np.array([b.mean(axis=0) for b in np.array_split(d, k)])
    return float(np.sqrt(np.sum((means - means.mean(axis=0)) ** 2) / (k - 1) / k))


def _posed_alone(frames: list, options: Any, stamp_row: float, given: dict):
    """Each camera's frames posed alone (:func:`~rs_localizer.estimation.estimate_rs_pose`,
    step 1; a frame's :attr:`~rs_localizer.tracking.localizer.CameraFrame.groups`, a marker's
    corners, enter the covariance as a shift they share), those with a finite covariance:
    camera -> list of ``(t ns on the rig's clock (plus the camera's ``given`` offset),
    orientation (3, 3) camera -> world, position (3,) m, angular rad/s and linear m/s velocity
    (3,) in camera axes, covariance (12, 12), inlier corners (pixels (K, 2), map points (K, 3)
    m, camera model))`` in time order."""
    poses: dict[str, list] = {}
    for f in frames:
        if f.camera is None:
            continue
        est = estimate_rs_pose(f.points2d, f.points3d, f.camera, options=options, groups=f.groups)
        poses.setdefault(f.camera_name, [])
        cov = est.covariance
        if not est.success or cov is None or not np.isfinite(cov[:6, :6]).all():
            continue
        t = reference_stamp_ns(f.stamp_ns, f.camera, stamp_row, given.get(f.camera_name, 0.0))
        q, inl = est.pose, np.asarray(est.inliers, dtype=bool)
        corners = (np.asarray(f.points2d, float)[inl], np.asarray(f.points3d, float)[inl], f.camera)
        poses[f.camera_name].append((t, q.orientation, q.position, q.angular_velocity,
                                     q.linear_velocity, cov, corners))  # fmt: skip
    for items in poses.values():
        items.sort(key=lambda i: i[0])
    return poses


def _carried(items: list, times: np.ndarray, t_r: int, window: float):
    """A camera's pose (camera -> world rotation, position, its frame's (12, 12) covariance)
    carried to ``t_r`` (ns) from its frame nearest in time (None beyond ``window`` s), at the
    constant twist between its own two frames around ``t_r`` (else its frame's own twist; frames
    at most :data:`MAX_STEP` apart); its motion there in world axes (angular rad/s, linear m/s),
    differenced between its frames before and after the nearest one (not from that frame's own
    pose, whose error it would share) or next to it, else its frame's own twist; the frame's
    index in ``items``."""
    k = int(np.argmin(np.abs(times - t_r)))
    dt = (t_r - times[k]) * 1e-9
    if abs(dt) > window:
        return None
    _, Oc, p, om, v, cov = items[k][:6]

    def near(j: int) -> bool:
        return 0 <= j < len(items) and 0 < abs(times[j] - times[k]) * 1e-9 <= MAX_STEP

    j = k + 1 if dt > 0 else k - 1
    twist = (Oc @ om, Oc @ v)
    pairs = [(k - 1, k + 1)] if near(k - 1) and near(k + 1) else []
    pairs += [(k, i) for i in (j, k + 1, k - 1) if near(i)]
    if pairs:
        a, b = pairs[0]
        Oa, pa = items[a][1], items[a][2]
        step = (times[b] - times[a]) * 1e-9
        twist = (Oa @ matrix_to_rotvec(Oa.T @ items[b][1]) / step, (items[b][2] - pa) / step)
    if dt == 0:
        return Oc, p, cov, twist, k
    if near(j):
        s_ = (t_r - times[k]) / (times[j] - times[k])
        O_t = Oc @ rotvec_to_matrix(s_ * matrix_to_rotvec(Oc.T @ items[j][1]))
        return O_t, p + s_ * (items[j][2] - p), cov, twist, k
    return Oc @ rotvec_to_matrix(om * dt), p + Oc @ v * dt, cov, twist, k


def _rig_frames(poses: dict, window: float) -> list:
    """The rig frames (step 2): every camera frame's time, in order, starts one unless within
    ``window`` of the current one's start; each camera with a frame within ``window`` carried to
    it (:func:`_carried`). Returns ``[(t_ns, {camera: _carried's tuple})]``, two cameras or more."""
    stamps = sorted(t for items in poses.values() for t, *_ in items)
    times = {n: np.array([i[0] for i in items]) for n, items in poses.items() if items}
    out, start = [], None
    for t in stamps:
        if start is not None and (t - start) * 1e-9 <= window:
            continue
        start = t
        seen = {n: c for n, ts in times.items()
                if (c := _carried(poses[n], ts, t, window)) is not None}  # fmt: skip
        if len(seen) >= 2:
            out.append((t, seen))
    return out


def _initial_mounts(rig_frames: list, reference: str, base: Mounting) -> dict:
    """Each camera's mounting (camera -> rig rotation, position) chained from the reference's
    over a spanning tree of the cameras that share rig frames (step 3: breadth first, the
    pairs that share the most rig frames first), each pair's relative pose the robust mean
    over its rig frames (the chordal mean of the rotations and the mean position over the
    inliers: rotations more than 3 times the median angle and 0.05 deg from the mean are
    outliers, twice; positions more than 3 times the median distance and 0.1 mm from the
    median); cameras not connected to the reference are missing."""
    rel: dict = {}
    for _, seen in rig_frames:
        for a, b in permutations(seen, 2):
            (Oa, pa), (Ob, pb) = seen[a][:2], seen[b][:2]
            rel.setdefault((a, b), []).append((Oa.T @ Ob, Oa.T @ (pb - pa)))
    mounts = {reference: (base.R.T, base.position)}
    frontier = [reference]
    while frontier:
        nxt = []
        for a in frontier:
            pairs = sorted(
                ((len(v), b) for (a_, b), v in rel.items() if a_ == a and b not in mounts),
                reverse=True,
            )
            for _, b in pairs:
                Rs, ps = (np.array(x) for x in zip(*rel[(a, b)], strict=True))
                keep = np.ones(len(Rs), dtype=bool)
                for _ in range(3):
                    U, _, Vt = np.linalg.svd(Rs[keep].sum(axis=0))
                    M = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
                    off = matrix_to_rotvec(np.einsum("ji,njk->nik", M, Rs))  # (M^T R_i)
                    angle = np.linalg.norm(off, axis=1)
                    keep = angle <= max(3.0 * float(np.median(angle[keep])), np.deg2rad(0.05))
                d = np.linalg.norm(ps - np.median(ps, axis=0), axis=1)
                keep &= d <= max(3.0 * float(np.median(d)), 1e-4)
                p = ps[keep].mean(axis=0) if keep.any() else np.median(ps, axis=0)
                mounts[b] = compose(*mounts[a], M, p)
                nxt.append(b)
        frontier = nxt
    return mounts


class _Fit(NamedTuple):
    """One pose-level adjustment (:func:`_adjust`); per observation (a camera frame in a rig
    frame, m of them) its rig pose ``gi``, rig frame ``g`` (an index into the rig frames),
    camera, orientation ``O`` (m, 3, 3) camera -> world, whitening ``W`` (m, 6, 6) and angular
    velocity ``w`` (m, 3) rad/s in world axes."""

    mounts: dict  # camera -> (camera -> rig rotation, position m), every adjusted camera's
    J: Any  # the whitened Jacobian (sparse; columns: rig poses, mountings, 6 each, offsets)
    r: np.ndarray  # (m, 6) the whitened errors
    gi: np.ndarray
    g: np.ndarray
    cam: np.ndarray
    O: np.ndarray  # noqa: E741
    W: np.ndarray
    w: np.ndarray
    free: list  # the adjusted cameras (all but the reference)
    dts: dict  # camera -> its time offset (s; {} without offsets)
    rig: tuple  # the rig poses: (rig -> world rotations (G, 3, 3), positions (G, 3) m)

    def errors(self) -> np.ndarray:
        """The pose errors (m, 6) (rotation rad, position m; world axes), unwhitened."""
        return np.linalg.solve(self.W, self.r[..., None])[..., 0]

    def outliers(self) -> set:
        """(rig frame, camera) of the camera frames that contradict the others: whitened
        error beyond :data:`_OUTLIER_QUANTILE` at the errors' median scale."""
        d2 = np.sum(self.r * self.r, axis=1)
        scale = max(float(np.median(d2)) / chi2.ppf(0.5, 6), 1.0)
        bad = d2 > scale * chi2.ppf(_OUTLIER_QUANTILE, 6)
        return {(int(g), str(n)) for g, n in zip(self.g[bad], self.cam[bad], strict=True)}


def _whitening(rig_frames: list) -> dict:
    """Per camera, the inverse Cholesky factor of its frames' typical pose covariance (the mean
    of those within 3 times the median trace) in its own axes, as the depth direction turns with
    the camera (make-bag --rig 3 --frames 300 --points 300: world axes 0.57/0.98 mm against the
    truth, camera axes 0.40/0.39 mm); a camera whose covariance is singular is missing."""
    covs: dict = {}
    for _, seen in rig_frames:
        for n, (R_wc, _, c6, *_) in seen.items():
            T = block_diag(R_wc.T, R_wc.T)
            covs.setdefault(n, []).append(T @ np.asarray(c6, dtype=float)[:6, :6] @ T.T)
    whiten = {}
    for n, cs in covs.items():
        cs = np.array(cs)
        tr = np.trace(cs, axis1=1, axis2=2)
        C6 = cs[tr <= 3.0 * np.median(tr)].mean(axis=0)
        try:
            whiten[n] = np.linalg.inv(np.linalg.cholesky(0.5 * (C6 + C6.T)))
        except np.linalg.LinAlgError:
            continue
    return whiten


def _adjust(rig_frames: list, mounts: dict, reference: str, outlier=frozenset(), offsets=False):
    """One least-squares adjustment (step 4; SciPy ``least_squares``, sparse Jacobian) of every
    rig frame's pose and every non-reference mounting (from ``mounts``) to the cameras' poses,
    each camera's errors whitened (:func:`_whitening`, scaled to each frame's covariance), the
    camera frames in ``outlier`` ((rig frame, camera)) and cameras cut off from the reference
    left out; ``offsets``: a time offset per free camera too (s, first order along the twist;
    prior :data:`TIME_OFFSET_PRIOR`). Returns a :class:`_Fit`."""
    whiten = _whitening(rig_frames)
    use = []
    for g, (_, seen) in enumerate(rig_frames):
        known = [n for n in seen if n in mounts and n in whiten and (g, n) not in outlier]
        if len(known) >= 2:
            use.append((g, known))
    # the cameras still connected to the reference through the rig frames used
    linked = {reference}
    while grown := {n for _, known in use if linked & set(known) for n in known} - linked:
        linked |= grown
    free = [n for n in mounts if n != reference and n in linked]
    obs, R0g, P0g = [], [], []  # (obs: the fields of _Fit from gi to v)
    for g, known in use:
        known = [n for n in known if n in linked]
        if len(known) < 2:
            continue
        seen = rig_frames[g][1]
        a = reference if reference in known else known[0]
        Rg, Pg = base_pose(*seen[a][:2], Mounting.from_pose(*mounts[a]))
        R0g.append(Rg)
        P0g.append(Pg)
        for n in known:
            Oc, p, c6, twist = seen[n][:4]
            # the typical covariance's shape, scaled to the size of the frame's own (its
            # mean variance in the typical's whitened units): a frame of few inliers
            # counts less, its own shape (noisy with few points) is not used
            Wn = whiten[n] @ block_diag(Oc.T, Oc.T)
            size = np.trace(Wn @ np.asarray(c6, dtype=float)[:6, :6] @ Wn.T) / 6.0
            obs.append((len(R0g) - 1, g, n, Oc, p, Wn / np.sqrt(max(size, 1e-12)), *twist))
    gi, g, cam, O, p, W, w, v = (np.array(x) for x in zip(*obs, strict=True))  # noqa: E741
    G, F, m = len(R0g), len(free), len(obs)
    D = F if offsets else 0  # (a time offset per free camera, s, after the mountings)
    # the mountings: the free ones', then the reference's (fixed; an observation's index -1)
    R0m, p0m = (np.array([mounts[n][i] for n in [*free, reference]]) for i in (0, 1))
    ci = np.array([free.index(n) if n in free else -1 for n in cam])
    R0g, P0g, O_T = np.array(R0g), np.array(P0g), np.array(O.transpose(0, 2, 1))

    def unpack(x):  # (the rig poses and the mountings at the parameters x)
        rig = moved(R0g, P0g, x[: 6 * G].reshape(G, 6), slice(None))
        return rig, moved(R0m, p0m, x[6 * G : 6 * (G + F)].reshape(F, 6), np.arange(F + 1) < F)

    def fun(x):
        ((Rg, Pg), (Rm, pm)), xd = unpack(x), x[6 * (G + F) :]
        Ot, p_t = O_T, p
        if D:  # (a time offset dt at the rig frame's time is the pose dt earlier on the
            # camera's own time, constant twist: O -> expm(-dt [w]x) O, p -> p - dt v)
            dt = np.concatenate([xd, [0.0]])[ci]  # (the reference's: 0)
            Ot, p_t = Ot @ rotvec_to_matrix(dt[:, None] * w), p - dt[:, None] * v
        e = np.concatenate(
            [matrix_to_rotvec(Rg[gi] @ Rm[ci] @ Ot),
             Pg[gi] + np.einsum("nij,nj->ni", Rg[gi], pm[ci]) - p_t], axis=1,
        )  # fmt: skip
        return np.concatenate([np.einsum("nij,nj->ni", W, e).ravel(), xd / TIME_OFFSET_PRIOR])

    # the Jacobian's structure: each observation's 6 rows on its rig frame's pose, its
    # camera's mounting and time offset (not the reference's), then the offsets' prior rows
    mine = np.flatnonzero(ci >= 0)
    rows, cols = np.r_[np.arange(m), mine], np.r_[gi, G + ci[mine]]
    sp = kron(coo_matrix((np.ones(len(rows)), (rows, cols)), (m, G + F)), np.ones((6, 6)))
    if D:
        T = coo_matrix((np.ones(len(mine)), (mine, ci[mine])), (m, F))
        sp = bmat([[sp, kron(T, np.ones((6, 1)))], [None, identity(D)]])
    res = least_squares(fun, np.zeros(6 * (G + F) + D), jac_sparsity=sp, method="trf",
                        xtol=1e-10, ftol=1e-10, max_nfev=100)  # fmt: skip
    rig, (Rm, pm) = unpack(res.x)
    out = {n: (Rm[i], pm[i]) for i, n in [(-1, reference), *enumerate(free)]}
    dts = {n: float(res.x[6 * (G + F) + i]) for i, n in enumerate(free)} if D else {}
    r = res.fun[: 6 * m].reshape(-1, 6)
    return _Fit(out, res.jac, r, gi, g, cam, O, W, w, free, dts, rig)


def _mounting_covariance(fit: _Fit) -> tuple[dict, dict]:
    """Each free camera's mounting covariance (6, 6) (rotation rad, rig axes; position m)
    from the adjustment ``fit`` (step 5): ``s^2 H^-1`` (the rig poses marginalized,
    :func:`~rs_localizer.calibration.corners.marginal`) inflated by :func:`_std_of_mean`, plus
    each camera's bias (:data:`MOUNTING_BIAS_SHARE` of its scatter in its own axes) propagated
    to first order; and each time offset's std (s, inflated alike). Infinite where the
    adjustment does not constrain it."""
    J, r, cam, free = fit.J, fit.r, fit.cam, fit.free
    n, k, mc = J.shape[1], 6 * len(fit.rig[0]), 6 * len(free)  # (rig, mountings, offsets)
    s2 = float(np.sum(r * r)) / max(6 * len(r) - n, 1)
    cams = np.unique(cam)
    inflate = 1.0
    for c in cams:
        rc = r[cam == c]
        if len(rc) >= 16:
            iid = np.sum(np.var(rc, axis=0, ddof=1)) / len(rc)
            inflate = max(inflate, _std_of_mean(rc) ** 2 / max(iid, 1e-300))
    Sinv, A, loose = marginal(J, k)
    Hinv = s2 * inflate * Sinv
    Hinv[loose, :] = Hinv[:, loose] = np.inf
    cov = Hinv[:mc, :mc]
    bias = np.repeat([MOUNTING_BIAS_SHARE["rotation"], MOUNTING_BIAS_SHARE["position"]], 3)
    e = fit.errors()
    for c in cams:
        i = np.flatnonzero(cam == c)
        Oc = fit.O[i]
        # (the whitened errors' derivative by the camera's pose error in its own axes)
        Z = np.concatenate([fit.W[i, :, :3] @ Oc, fit.W[i, :, 3:] @ Oc], axis=2)
        e_cam = np.concatenate([np.einsum("nji,nj->ni", Oc, e[i, :3]),
                                np.einsum("nji,nj->ni", Oc, e[i, 3:])], axis=1)  # fmt: skip
        B = np.diag((bias * np.sqrt(np.mean(np.square(e_cam), axis=0))) ** 2)
        K = (Sinv @ (A[(6 * i[:, None] + np.arange(6)).ravel()].T @ Z.reshape(-1, 6)))[:mc]
        cov = cov + K @ B @ K.T
    cov = 0.5 * (cov + cov.T)
    dt_std = {f: float(np.sqrt(Hinv[mc + i, mc + i])) for i, f in enumerate(free) if n > k + mc}
    return {name: cov[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] for i, name in enumerate(free)}, dt_std


def _rig_start(seen: dict, every: dict, mounts: dict, known: list, scale: float) -> tuple:
    """A rig frame's pose to start the corners' solve from (rig -> world rotation, position m):
    of the rig poses its camera frames give through their mountings, the one whose projections
    of all its corners miss least (squared px each, capped at ``(4 scale)^2``: a frame posed
    wrongly, e.g. a tag's mirrored pose, costs its corners the cap)."""
    best, out = np.inf, None
    for n in known:
        Rg, Pg = base_pose(*seen[n][:2], Mounting.from_pose(*mounts[n]))
        cost = 0.0
        for m in known:
            uv, X, cam = every[m][seen[m][4]][6]
            Ow = Rg @ mounts[m][0]
            x_cam = (X - (Pg + Rg @ mounts[m][1])) @ Ow
            e2 = np.sum((cam.project(x_cam) - uv) ** 2, axis=1)
            cost += float(np.minimum(np.nan_to_num(e2, nan=np.inf), (4.0 * scale) ** 2).sum())
        if cost < best:
            best, out = cost, (Rg, Pg)
    return out


class _Refined(NamedTuple):
    """:func:`_refine_on_corners`' result."""

    mounts: dict  # camera -> (camera -> rig rotation, position m)
    problem: RigCorners
    sol: CornerSolution
    times: list  # each rig frame's time (ns)


def _refine_on_corners(
    rig_frames, every, fit, mounts, reference, scale, window, timed=False, warm=None
) -> _Refined | None:
    """The mountings refined on the corners (step 4): every rig frame's pose (two or more
    cameras in ``mounts``) and every free mounting adjusted to the inlier corners of ``every``
    camera frame posed alone (:func:`_posed_alone`, few inliers too; grouped as
    :func:`_rig_frames` does) by :class:`~rs_localizer.calibration.corners.RigCorners`
    (``soft_l1`` at ``scale`` px), each camera frame at its pose relative to the one carried to
    its rig frame's time. A rig frame starts at ``warm``'s pose (time ns -> rig pose), else
    ``fit``'s, else :func:`_rig_start`'s. ``timed``: a time offset per free camera too.
    Global-shutter cameras only. None when no rig frame has two such cameras or no corner
    projects."""
    free = [n for n in mounts if n != reference]
    names = list(mounts)
    start_at = {rig_frames[g][0]: (fit.rig[0][i], fit.rig[1][i])
                for i, g in zip(fit.gi, fit.g, strict=True)}  # fmt: skip
    groups: dict = {}  # (camera name, model id) -> the lists of the corners' arrays
    Rg0, Pg0, times = [], [], []
    for t, seen in _rig_frames(every, window):
        known = [n for n in seen if n in mounts]
        if len(known) < 2:
            continue
        Rg, Pg = (warm or {}).get(t) or start_at.get(t) or _rig_start(seen, every, mounts, known,
                                                                     scale)  # fmt: skip
        times.append(t)
        Rg0.append(Rg)
        Pg0.append(Pg)
        for n in known:
            O_t, p_t, _, (w, v), k = seen[n]
            _, Oc, pc, _, _, _, (uv, X, cam) = every[n][k]
            K = len(uv)
            parts = (np.full(K, len(Rg0) - 1), np.full(K, names.index(n)),
                     np.broadcast_to(O_t.T @ Oc, (K, 3, 3)),
                     np.broadcast_to(O_t.T @ (pc - p_t), (K, 3)), uv, X,
                     np.full(K, free.index(n) if n in free else -1),
                     np.broadcast_to(w, (K, 3)), np.broadcast_to(v, (K, 3)))  # fmt: skip
            groups.setdefault((n, id(cam)), (cam, []))[1].append(parts)
    if not groups:  # (no rig frame of two cameras in ``mounts``)
        return None
    cams = [cam for cam, _ in groups.values()]
    per_cam = [[np.concatenate(a) for a in zip(*ls, strict=True)] for _, ls in groups.values()]
    camera = np.concatenate([np.full(len(a[0]), i) for i, a in enumerate(per_cam)])
    gi, m, Dr, Dp, uv, X, d, w, v = (np.concatenate(a) for a in zip(*per_cam, strict=True))
    problem = RigCorners(
        uv, cams, camera, gi, m, (np.array(Rg0), np.array(Pg0)),
        (np.array([mounts[n][0] for n in names]), np.array([mounts[n][1] for n in names])),
        np.array([n != reference for n in names]), X, offsets=(Dr, Dp),
        motion=(d, w, v) if timed else None,
    )  # fmt: skip
    sol = problem.solve(scale, max_nfev=_CORNER_NFEV)
    if sol is None:
        return None
    Rm, pm = sol.mounts
    return _Refined({n: (Rm[i], pm[i]) for i, n in enumerate(names)}, problem, sol, times)


def _corner_covariance(refined: _Refined, start: dict, reference: str, pose_cov: dict) -> tuple:
    """Each refined mounting's covariance (6, 6) (step 5): the corners' solve's
    (:meth:`~rs_localizer.calibration.corners.RigCorners.mounting_covariance`, runs of rig
    frames as :data:`CORNER_BLOCKS` groups, times ``B / (B - 1)``) plus ``(misfit - 1)
    pose_cov``, ``misfit`` the squared step from the pose-level mountings ``start`` (covariance
    ``pose_cov``) per degree of freedom (at least :data:`MISFIT_FLOOR`). A rig frame's exposure
    off the camera's time offset is not added here: it moves the rig pose, whose covariance
    takes the offset's std at the frame's own twist (``time_offset_std``). Returns
    ``(covariances, misfit, camera -> time offset std s ({} without))``."""
    problem, sol = refined.problem, refined.sol
    free = [n for n in refined.mounts if n != reference]
    blocks = min(CORNER_BLOCKS, problem.G)
    C, std = problem.mounting_covariance(sol, (problem.frame * blocks) // problem.G)
    k = blocks / max(blocks - 1, 1)
    C, std = C * k, std * np.sqrt(k)
    dt_std = dict(zip(free, std.tolist(), strict=True)) if problem.D else {}
    d = [np.r_[matrix_to_rotvec(refined.mounts[n][0] @ start[n][0].T),
               refined.mounts[n][1] - start[n][1]] for n in free]  # fmt: skip
    seen = [(di, n) for di, n, Ci in zip(d, free, C, strict=True)
            if np.isfinite(pose_cov[n]).all() and np.isfinite(Ci).all()]  # fmt: skip
    m2 = sum(float(di @ np.linalg.lstsq(pose_cov[n], di, rcond=None)[0]) for di, n in seen)
    misfit = max(MISFIT_FLOOR, m2 / max(6 * len(seen), 1))
    cov = {n: C[i] + (misfit - 1.0) * np.nan_to_num(pose_cov[n], posinf=0.0, neginf=0.0)
           for i, n in enumerate(free)}  # fmt: skip
    return cov, misfit, dt_std


def _exposed_apart(rig_frames, poses, fit: _Fit, reference: str, bad: set, px: float) -> tuple:
    """The cameras that do not expose with the reference (camera -> time offset s): those whose
    offset in an adjustment with offsets (from ``fit``, ``bad`` left out) is beyond 3 std and
    moves a corner by more than :data:`EXPOSED_APART_SHARE` of ``px`` at the rig's median
    angular speed; also that adjustment's mountings, covariance, time offsets (s) and their
    std (s)."""
    timed = _adjust(rig_frames, fit.mounts, reference, bad, True)
    cov, std = _mounting_covariance(timed)
    speed = np.linalg.norm(timed.w, axis=1)
    out = {}
    for n, dt in timed.dts.items():
        focal = poses[n][0][6][2].mean_focal
        shift = abs(dt) * float(np.median(speed[timed.cam == n])) * focal
        if abs(dt) > 3.0 * std.get(n, np.inf) and shift > EXPOSED_APART_SHARE * px:
            out[n] = dt
    return out, timed.mounts, cov, timed.dts, std


def _pose_level(rig_frames, poses, mounts, reference, timed, window) -> tuple:
    """The pose-level adjustment (step 4), again without the outliers; with ``timed`` the frames
    regrouped at the offsets found (beyond 3 std; ``poses`` shifted in place) until they change
    by less than :data:`TIME_OFFSET_TOL` (:data:`TIME_OFFSET_ROUNDS` at most). Returns ``(fit,
    (covariances, offsets' std), outliers, rig frames, camera -> offset regrouped at s)``."""
    shifted = {n: 0.0 for n in poses}
    rounds = TIME_OFFSET_ROUNDS if timed else 1
    for k in range(rounds):
        fit = _adjust(rig_frames, mounts, reference, offsets=timed)
        bad = fit.outliers()
        if bad:
            fit = _adjust(rig_frames, fit.mounts, reference, bad, offsets=timed)
        mounts, (cov, std) = fit.mounts, _mounting_covariance(fit)
        step = {n: dt for n, dt in fit.dts.items()
                if abs(dt) >= TIME_OFFSET_TOL and abs(dt) > 3.0 * std.get(n, np.inf)}  # fmt: skip
        if not step or k == rounds - 1:
            break
        for n, dt in step.items():
            shifted[n] += dt
            poses[n] = [(t + int(round(dt * 1e9)), *rest) for t, *rest in poses[n]]
        rig_frames = _rig_frames(poses, window)
    return fit, (cov, std), bad, rig_frames, shifted


def _cornered(refined: _Refined) -> set:
    """The mountings (indices) that some kept corner of ``refined``'s solve sees."""
    p = refined.problem
    return set(np.unique(p.mounting[refined.sol.keep]).tolist())


def _on_corners(rig_frames, every, poses, fit, cov, reference, bad, px, window):
    """The refinement on the corners (steps 4, 5) after the pose-level ``fit``: with cameras
    that expose apart a time offset each, the frames regrouped at the offsets found and solved
    again until they change by less than :data:`TIME_OFFSET_TOL`. A regrouping that leaves a
    camera no corner (its frames then in no rig frame with another camera's) is not taken: the
    last solve that saw it stands. A camera that no corner of the solve constrains keeps its
    pose-level mounting, covariance and time offset (not refined). Returns ``(cameras apart,
    None or (mountings, covariances, camera -> misfit of the refined ones, offsets, their
    std))``."""
    apart, timed, timed_cov, timed_dts, timed_std = _exposed_apart(rig_frames, poses, fit,
                                                                   reference, bad, px)  # fmt: skip

    def refine(shots: dict, mounts: dict, warm: dict | None = None) -> _Refined | None:
        return _refine_on_corners(rig_frames, shots, fit, mounts, reference, px, window,
                                  bool(apart), warm)  # fmt: skip

    corners = refine(every, fit.mounts)
    found: dict = {}  # (s: with apart, the offsets the corners' solves found, summed)
    for _ in range(TIME_OFFSET_ROUNDS - 1 if apart and corners is not None else 0):
        dt = corners.problem.time_offsets(corners.sol.result.x)
        if np.all(np.abs(dt) < TIME_OFFSET_TOL):
            break
        free = [n for n in corners.mounts if n != reference]
        moved, sums = dict(every), dict(found)
        for n, v in zip(free, dt.tolist(), strict=True):
            sums[n] = sums.get(n, 0.0) + v
            moved[n] = [(t + int(round(v * 1e9)), *rest) for t, *rest in every[n]]
        warm = dict(zip(corners.times, zip(*corners.sol.rig, strict=True), strict=True))
        again = refine(moved, corners.mounts, warm)
        if again is None or _cornered(corners) - _cornered(again):
            break  # (no rig frame of two cameras left, or a camera without corners)
        corners, every, found = again, moved, sums
    if corners is None:
        return apart, None
    # (the two estimates compared alike: with a time offset per camera or without)
    start, start_cov = (timed, timed_cov) if apart else (fit.mounts, cov)
    cov, misfit, dt_std = _corner_covariance(corners, start, reference, start_cov)
    dt = corners.problem.time_offsets(corners.sol.result.x)
    dts = {n: float(v) + found.get(n, 0.0) for n, v in zip(dt_std, dt, strict=True)}
    mounts, misfits = dict(corners.mounts), dict.fromkeys(corners.mounts, misfit)
    for n in [n for n in cov if not np.isfinite(cov[n]).all()]:
        # (no corner constrains it: its pose-level estimate, not a refined one)
        mounts[n], cov[n] = start[n], start_cov[n]
        del misfits[n]
        dts.pop(n, None)
        dt_std.pop(n, None)
        if apart:
            dts[n], dt_std[n] = timed_dts[n], timed_std[n]
    return apart, (mounts, cov, misfits, dts, dt_std)


def calibrate_mountings(
    frames: list,
    reference: str,
    *,
    reference_mount: Mounting | None = None,
    window: float = 0.015,
    stamp_row: float = 0.0,
    min_inliers: int = 20,
    options: Any = None,
    time_offsets: Mapping[str, float] | None = None,
    estimate_time_offsets: bool = False,
) -> dict:
    """Every camera's mounting on the rig from a video of a known map, adjusted jointly, each
    with its covariance (docs/rig_node.md, "Mountings from data", has each step and its
    measurements): each camera frame posed alone, grouped into rig frames; the mountings
    chained from the reference over the cameras that share rig frames (a ring or a chain is
    calibrated), then every rig frame's pose and every mounting adjusted in one least-squares
    problem, outliers left out; for global-shutter cameras without ``estimate_time_offsets``
    then refined on the corners (with a time offset per camera when they do not expose
    together, :data:`EXPOSED_APART_SHARE`).

    Args:
        frames: :class:`~rs_localizer.tracking.localizer.CameraFrame` of every camera (any
            order; frames without a camera model are skipped); a frame's ``groups`` (each
            corner's marker) make its pose's covariance, which weighs it in the pose-level
            adjustment, that of corners sharing a shift per marker (None: independent).
        reference: the camera whose optical frame is the rig frame, unless ``reference_mount``
            (its known mounting on the rig) places it.
        window: s; frames further apart are not one rig frame.
        stamp_row: the row whose capture time is a frame's stamp.
        min_inliers: frames posed with fewer inliers are left out of the pose-level
            adjustment (the refinement on the corners takes their corners).
        options: the single-camera estimator's
            :class:`~rs_localizer.estimation.EstimateOptions` (None: its defaults; its RANSAC
            threshold is the corners' loss scale).
        time_offsets: camera -> s added to its stamps (a rig's
            :attr:`~rs_localizer.tracking.video.LocalizerSettings.time_offsets`); None: none.
        estimate_time_offsets: also estimate every camera's time offset against the
            reference's (its given one kept), the frames regrouped at the offsets found until
            they change by less than :data:`TIME_OFFSET_TOL`; only a rig that moves shows an
            offset, its std says how well.
    Returns:
        camera name -> :class:`MountingEstimate` (cameras in the order they first appear;
        a camera not connected to the reference through shared rig frames is missing).
    Raises:
        ValueError: no frame of ``reference`` posed.
    """
    given = {n: float(v) for n, v in (time_offsets or {}).items()}
    # every camera frame posed alone (the corners' refinement takes them all), those with at
    # least min_inliers inliers for the pose-level adjustment
    every = _posed_alone(frames, options, stamp_row, given)
    poses = {n: [i for i in items if len(i[6][0]) >= min_inliers] for n, items in every.items()}
    if not poses.get(reference):
        raise ValueError(
            f"calibrate_mountings: no frame of the reference camera {reference!r} posed"
        )
    base = reference_mount if reference_mount is not None else Mounting(np.eye(3), np.zeros(3))
    rig_frames = _rig_frames(poses, window)
    mounts = _initial_mounts(rig_frames, reference, base)
    if len(mounts) < 2:  # (no camera shares a rig frame with the reference)
        n_ref = len(poses[reference])
        return {reference: MountingEstimate(reference, base, n_ref, 0, 0.0, 0.0, 0.0, 0.0)}
    fit, (cov, dt_std), bad, rig_frames, shifted = _pose_level(
        rig_frames, poses, mounts, reference, estimate_time_offsets, window
    )
    mounts, dts, misfits, apart, refined = fit.mounts, fit.dts, {}, {}, None
    rolling = any(i[6][2].readout_time != 0.0 for items in poses.values() for i in items)
    if not estimate_time_offsets and not rolling:
        px = (options if options is not None else EstimateOptions()).ransac.threshold_px
        apart, refined = _on_corners(rig_frames, every, poses, fit, cov, reference, bad, px,
                                     window)  # fmt: skip
        if refined is not None:
            mounts, cov, misfits, dts, dt_std = refined
    e = fit.errors()  # (the camera frames' pose errors about the adjusted rig)
    out = {}
    for name in poses:
        if name not in mounts or (name != reference and not np.isfinite(cov[name]).all()):
            continue
        n_used, n_bad = int(np.sum(fit.cam == name)), sum(1 for (_, n) in bad if n == name)
        offset = given.get(name, 0.0) + shifted.get(name, 0.0) + dts.get(name, 0.0)
        if name == reference:
            out[name] = MountingEstimate(name, base, n_used, n_bad, 0.0, 0.0, 0.0, 0.0, offset,
                                         corners_refined=refined is not None)  # fmt: skip
            continue
        C, mine = cov[name], e[fit.cam == name]
        scat = np.sqrt(np.mean(np.sum(mine[:, :3] ** 2, axis=1))), np.sqrt(
            np.mean(np.sum(mine[:, 3:] ** 2, axis=1)))  # fmt: skip
        out[name] = MountingEstimate(
            name, Mounting.from_pose(*mounts[name], covariance=C), n_used, n_bad,
            float(np.rad2deg(np.sqrt(np.trace(C[:3, :3])))),
            float(1e3 * np.sqrt(np.trace(C[3:, 3:]))),
            float(np.rad2deg(scat[0])), float(1e3 * scat[1]), offset, dt_std.get(name, np.nan),
            name in misfits, apart.get(name, np.nan), misfits.get(name, np.nan),
        )  # fmt: skip
    return out
