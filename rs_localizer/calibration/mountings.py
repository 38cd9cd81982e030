"""A rig's camera mountings from a video of a known map (:func:`calibrate_mountings`, what
``rs-localizer calibrate-rig`` runs), each with its covariance, which the rig estimator adds
to the rig pose's (:attr:`~rs_localizer.frames.Mounting.covariance`). The method, step by
step, with its measurements: docs/rig_node.md, "Mountings from data".
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from itertools import permutations
from typing import Any

import numpy as np
from scipy.linalg import LinAlgWarning, block_diag, lu_factor, lu_solve
from scipy.optimize import least_squares
from scipy.sparse import bmat, coo_matrix, identity, kron
from scipy.stats import chi2

from ..camera import reference_stamp_ns
from ..estimation.estimate import estimate_rs_pose
from ..estimation.options import EstimateOptions
from ..frames import Mounting
from ..geometry import matrix_to_rotvec, rotvec_to_matrix
from .corners import CornerSolution, RigCorners

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
            x_rig + c``) with its ``covariance`` (None for the reference camera, whose
            mounting is given): the pose-level adjustment's ``s^2 (J^T J)^-1``, inflated for
            the errors neighbouring frames share, plus the bias of the single-camera poses
            that averaging does not remove (:data:`MOUNTING_BIAS_SHARE`); a mounting refined
            on the corners (``corners_refined``): the corners' solve's, runs of rig frames
            as groups, plus the error the two estimates disagree by (``corner_misfit``,
            :func:`_corner_covariance`; docs/rig_node.md, "Mountings from data", step 5);
            with time offsets on the corners the offsets' covariance is part of it (a rig
            frame's exposure off the offset is the rig pose's: ``time_offset_std``).
        frames: rig frames the camera's pose entered the adjustment with (rig frames with at
            least two cameras); rejected: its camera frames left out as outliers.
        std_deg, std_mm: standard deviation of the mounting's rotation (deg, the norm over
            its three axes) and of the camera's position on the rig (mm, norm), from
            ``mount.covariance``; zero for the reference camera.
        scatter_deg, scatter_mm: one camera frame's pose error about the adjusted rig (RMS).
        time_offset: s added to the camera's stamps to put its frames on the rig's clock (the
            reference camera's: as given): the one it was calibrated with, or with
            ``estimate_time_offsets`` the estimate.
        time_offset_std: s, that estimate's standard deviation (the adjustment's, inflated as
            the mounting's); NaN: not estimated (given, or the reference camera's).
        corners_refined: the mounting was refined on the corners (:func:`_refine_on_corners`).
        exposure_offset: s, the camera's time offset the pose-level adjustment shows when
            the cameras do not expose together (:data:`EXPOSED_APART_SHARE`; the refinement
            on the corners then estimates a time offset per camera: ``time_offset``); NaN
            otherwise.
        corner_misfit: the squared step from the pose-level to the refined mountings in
            the pose-level covariance per degree of freedom (at least :data:`MISFIT_FLOOR`;
            the same for every camera of the rig): its excess over 1 times the pose-level
            covariance is in the refined one; NaN when not refined.
    """

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

#: a camera whose time offset, estimated as with ``estimate_time_offsets`` (one adjustment),
#: is beyond 3 of its std and moves a corner by more than this share of the RANSAC threshold
#: at the rig's median angular speed (its frames' twist; the camera's mean focal length) does
#: not expose with the reference: the refinement on the corners then adjusts a time offset per
#: camera, else its mountings would take up the rig's motion between the exposures
EXPOSED_APART_SHARE = 0.25

#: the systematic part of a mounting's standard deviation (:class:`MountingEstimate`), as a
#: share of one rig frame's scatter of the rotation and of the position: the bias of the
#: single-camera poses, which averaging over a video does not remove
MOUNTING_BIAS_SHARE = {"rotation": 0.1, "position": 0.2}


def _std_of_mean(d: np.ndarray, blocks: int = 8) -> float:
    """The standard deviation (norm over the axes) of the mean of deviations ``d`` (n, 3) in
    time order, by batch means: the frames of a video are not independent (a slow error, e.g.
    of the motion, is shared by neighbours), so the means of ``blocks`` consecutive runs
    scatter by what the mean's error is; 0 with fewer than 2 frames per block."""
    n = len(d)
    k = min(blocks, n // 2)
    if k < 2:
        return 0.0
    means = np.array([b.mean(axis=0) for b in np.array_split(d, k)])
    return float(np.sqrt(np.sum((means - means.mean(axis=0)) ** 2) / (k - 1) / k))


def _carried(items: list, times: np.ndarray, t_r: int, window: float, max_step: float):
    """A camera's pose (camera -> world rotation, position, its frame's (12, 12) covariance)
    carried to ``t_r`` (ns) from its frame nearest in time (None beyond ``window`` s): the
    constant twist between its own two frames around ``t_r`` (interpolated poses), or its
    frame's own twist when it has no frame on the other side within ``max_step`` s. Also the
    camera's motion there in world axes, ``(angular rad/s, linear m/s)``: the pose's rate of
    change with the camera's time, between its frames before and after the nearest one (its
    own pose's error left out: a twist differenced from it would correlate with that error),
    else between its nearest frame and the next or previous one within ``max_step`` (a
    global-shutter frame has no twist of its own), else its frame's own twist. Last, that
    frame's index in ``items``."""
    k = int(np.argmin(np.abs(times - t_r)))
    dt = (t_r - times[k]) * 1e-9
    if abs(dt) > window:
        return None
    _, Oc, p, om, v, cov = items[k][:6]

    def near(j: int) -> bool:
        return 0 <= j < len(items) and 0 < abs(times[j] - times[k]) * 1e-9 <= max_step

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


def _rig_frames(poses: dict, window: float, max_step: float) -> list:
    """The rig frames of cameras posed alone: every camera frame's time, in order, starts a
    rig frame unless within ``window`` of the current one's start; per rig frame, each camera
    with a frame within ``window`` carried to the start (:func:`_carried`). Returns a list of
    ``(t_ns, {camera: (O, p, cov, twist, frame index)})`` with at least two cameras."""
    stamps = sorted(t for items in poses.values() for t, *_ in items)
    times = {n: np.array([i[0] for i in items]) for n, items in poses.items() if items}
    out, start = [], None
    for t in stamps:
        if start is not None and (t - start) * 1e-9 <= window:
            continue
        start = t
        seen = {n: c for n, ts in times.items()
                if (c := _carried(poses[n], ts, t, window, max_step)) is not None}  # fmt: skip
        if len(seen) >= 2:
            out.append((t, seen))
    return out


def _pair_mean(rel: list) -> tuple:
    """Relative poses ``(R, p)`` of one camera in another's frame over rig frames -> their
    robust mean: the chordal mean of the rotations and the mean position over the inliers
    (rotations more than 3 times the median angle and 0.05 deg from the mean are outliers,
    twice; positions more than 3 times the median distance and 0.1 mm from the median)."""
    Rs, ps = (np.array(x) for x in zip(*rel, strict=True))
    keep = np.ones(len(Rs), dtype=bool)
    for _ in range(3):
        U, _, Vt = np.linalg.svd(Rs[keep].sum(axis=0))
        M = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
        a = np.linalg.norm(matrix_to_rotvec(np.einsum("ji,njk->nik", M, Rs)), axis=1)
        keep = a <= max(3.0 * float(np.median(a[keep])), np.deg2rad(0.05))
    d = np.linalg.norm(ps - np.median(ps, axis=0), axis=1)
    keep &= d <= max(3.0 * float(np.median(d)), 1e-4)
    return M, ps[keep].mean(axis=0) if keep.any() else np.median(ps, axis=0)


def _initial_mounts(rig_frames: list, reference: str, base: Mounting) -> dict:
    """Each camera's mounting (camera -> rig rotation, position) chained from the reference's
    over a spanning tree of the cameras that share rig frames (breadth first, the pairs that
    share the most rig frames first); cameras not connected to the reference are missing."""
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
                M, p = _pair_mean(rel[(a, b)])
                Ra, pa = mounts[a]
                mounts[b] = (Ra @ M, pa + Ra @ p)
                nxt.append(b)
        frontier = nxt
    return mounts


#: rig frames whose camera's whitened pose error (squared) is beyond this quantile of the
#: chi-square distribution with 6 degrees of freedom (times the median's scale) are left out
#: of the mountings' adjustment
_OUTLIER_QUANTILE = 0.999


def _adjust(
    rig_frames: list,
    mounts: dict,
    reference: str,
    outlier: frozenset | set = frozenset(),
    offsets: bool = False,
):
    """One least-squares adjustment (SciPy ``least_squares``, sparse Jacobian) of every rig
    frame's pose and every non-reference camera's mounting (``mounts``: name -> (camera ->
    rig rotation, position), the start) to the cameras' poses posed alone; camera frames in
    ``outlier`` ((rig frame, camera) pairs) and cameras no longer connected to the
    reference left out. ``offsets``: each free camera's time offset (s) adjusted too, to
    first order (its frames' poses moved along their twist). Returns ``(mounts, the whitened
    Jacobian (sparse; columns: the rig frames' poses, the mountings, 6 each, then the
    offsets), whitened errors (m, 6), the observations (rig frame used, rig frame, camera, O,
    p, whitening, twist), rig frames used, adjusted cameras, their offsets (s; {} without
    ``offsets``), the rig frames' poses (rig -> world rotations (G, 3, 3), positions (G, 3)
    m))``."""
    # each camera's pose errors weighted by its frames' typical covariance (the mean of
    # those within 3 times the median trace) in its own axes (block_diag(R_wc^T, R_wc^T):
    # world -> camera axes), as the depth direction turns with the camera (on make-bag --rig
    # 3 --frames 300 --points 300 world axes gave 0.57/0.98 mm against the truth, camera
    # axes 0.40/0.39 mm); each frame's weight then scaled by its own covariance's size
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
    fidx = {n: i for i, n in enumerate(free)}
    obs = []  # (rig frame index, its index in rig_frames, camera, O, p, whitening (6, 6))
    R0g, P0g = [], []
    for g, known in use:
        known = [n for n in known if n in linked]
        if len(known) < 2:
            continue
        seen = rig_frames[g][1]
        a = reference if reference in known else known[0]
        Ra, pa = mounts[a]
        Oa, ppa = seen[a][:2]
        gi = len(R0g)
        R0g.append(Oa @ Ra.T)
        P0g.append(ppa - R0g[-1] @ pa)
        for n in known:
            Oc, p, c6, twist = seen[n][:4]
            # the typical covariance's shape, scaled to the size of the frame's own (its
            # mean variance in the typical's whitened units): a frame of few inliers
            # counts less, its own shape (noisy with few points) is not used
            Wn = whiten[n] @ block_diag(Oc.T, Oc.T)
            size = np.trace(Wn @ np.asarray(c6, dtype=float)[:6, :6] @ Wn.T) / 6.0
            obs.append((gi, g, n, Oc, p, Wn / np.sqrt(max(size, 1e-12)), twist))
    G, F = len(R0g), len(free)
    D = F if offsets else 0  # (a time offset per free camera, s, after the mountings)
    R0m = np.array([mounts[n][0] for n in free]).reshape(-1, 3, 3)
    p0m = np.array([mounts[n][1] for n in free]).reshape(-1, 3)
    Rref, pref = mounts[reference]
    gi_ = np.array([o[0] for o in obs], dtype=int)
    ci_ = np.array([fidx.get(o[2], -1) for o in obs], dtype=int)  # (the reference's: -1)
    Ot = np.array([o[3].T for o in obs]).reshape(-1, 3, 3)
    po = np.array([o[4] for o in obs]).reshape(-1, 3)
    Whs = np.array([o[5] for o in obs]).reshape(-1, 6, 6)
    # each camera frame's pose changes with its camera's time at its twist (world axes): a
    # time offset dt seen at the rig frame's time is the pose dt earlier on the camera's
    # own time (constant twist), O -> expm(-dt [w]x) O, p -> p - dt v
    ang = np.array([o[6][0] for o in obs]).reshape(-1, 3)
    lin = np.array([o[6][1] for o in obs]).reshape(-1, 3)
    R0g_, P0g_ = np.array(R0g).reshape(-1, 3, 3), np.array(P0g).reshape(-1, 3)

    def fun(x):
        xg = x[: 6 * G].reshape(G, 6)
        xm = x[6 * G : 6 * (G + F)].reshape(F, 6)
        xd = x[6 * (G + F) :]
        Rg = rotvec_to_matrix(xg[:, :3]) @ R0g_
        Rm = np.concatenate([rotvec_to_matrix(xm[:, :3]) @ R0m, Rref[None]]) if F else Rref[None]
        pm = np.concatenate([p0m + xm[:, 3:], pref[None]])
        Rgi, O_t, p_t = Rg[gi_], Ot, po
        if D:
            dt = np.concatenate([xd, [0.0]])[ci_]  # (the reference's: 0)
            O_t = Ot @ rotvec_to_matrix(dt[:, None] * ang)  # ((expm(-dt [w]x) O)^T)
            p_t = po - dt[:, None] * lin
        e = np.concatenate(
            [matrix_to_rotvec(Rgi @ Rm[ci_] @ O_t),
             (P0g_ + xg[:, 3:])[gi_] + np.einsum("nij,nj->ni", Rgi, pm[ci_]) - p_t], axis=1,
        )  # fmt: skip
        return np.concatenate([np.einsum("nij,nj->ni", Whs, e).ravel(), xd / TIME_OFFSET_PRIOR])

    # the Jacobian's structure: each observation's 6 rows on its rig frame's pose, its
    # camera's mounting and time offset (not the reference's), then the offsets' prior rows
    m, mine = len(obs), np.flatnonzero(ci_ >= 0)
    rows, cols = np.r_[np.arange(m), mine], np.r_[gi_, G + ci_[mine]]
    sp = kron(coo_matrix((np.ones(len(rows)), (rows, cols)), (m, G + F)), np.ones((6, 6)))
    if D:
        T = coo_matrix((np.ones(len(mine)), (mine, ci_[mine])), (m, F))
        sp = bmat([[sp, kron(T, np.ones((6, 1)))], [None, identity(D)]])
    res = least_squares(fun, np.zeros(6 * (G + F) + D), jac_sparsity=sp, method="trf",
                        xtol=1e-10, ftol=1e-10, max_nfev=100)  # fmt: skip
    xm, xd = res.x[6 * G : 6 * (G + F)].reshape(F, 6), res.x[6 * (G + F) :]
    out = {reference: (Rref, pref)}
    for i, n in enumerate(free):
        out[n] = (rotvec_to_matrix(xm[i, :3]) @ R0m[i], p0m[i] + xm[i, 3:])
    shifts = {n: float(xd[i]) for i, n in enumerate(free)} if D else {}
    xg = res.x[: 6 * G].reshape(G, 6)
    rig = (rotvec_to_matrix(xg[:, :3]) @ R0g_, P0g_ + xg[:, 3:])
    return out, res.jac, res.fun[: 6 * m].reshape(-1, 6), obs, G, free, shifts, rig


def _mounting_covariance(J, r: np.ndarray, obs: list, G: int, free: list) -> tuple[dict, dict]:
    """Each free camera's mounting covariance (6, 6) over (rotation [rad, rig axes], position
    [m, rig frame]) from the adjustment (:func:`_adjust`): ``s^2 H^-1`` (``H = J^T J``)
    inflated by the batch means of :func:`_std_of_mean`, plus each camera's bias
    (:data:`MOUNTING_BIAS_SHARE` of its per-axis scatter in its own axes) propagated through
    the adjustment to first order (docs/rig_node.md, "Mountings from data", step 5). Also
    each free camera's time offset's std (s) when the adjustment had them, inflated alike.
    NaN where ``H`` is singular."""
    n, k, mc = J.shape[1], 6 * G, 6 * len(free)  # (columns: rig frames, mountings, offsets)
    s2 = float(np.sum(r * r)) / max(6 * len(r) - n, 1)
    cam = np.array([o[2] for o in obs])
    cams = sorted(set(cam))
    inflate = 1.0
    for c in cams:
        rc = r[cam == c]
        if len(rc) >= 16:
            iid = np.sum(np.var(rc, axis=0, ddof=1)) / len(rc)
            inflate = max(inflate, _std_of_mean(rc) ** 2 / max(iid, 1e-300))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LinAlgWarning)
        lu = lu_factor((J.T @ J).toarray())
    Hinv = s2 * inflate * lu_solve(lu, np.eye(n)[:, k:])[k:]
    cov = Hinv[:mc, :mc]
    dt_std = {f: float(np.sqrt(Hinv[mc + i, mc + i])) for i, f in enumerate(free) if n > k + mc}
    Jt = J.T.tocsr()
    bias = np.repeat([MOUNTING_BIAS_SHARE["rotation"], MOUNTING_BIAS_SHARE["position"]], 3)
    e = _errors(obs, r)
    for c in cams:
        Z = np.zeros((J.shape[0], 6))  # (the offsets' prior rows, if any, last)
        e_cam = []
        for i in np.flatnonzero(cam == c):
            Oc = obs[i][3]
            Z[6 * i : 6 * i + 6] = obs[i][5] @ block_diag(Oc, Oc)
            e_cam.append(np.concatenate([Oc.T @ e[i, :3], Oc.T @ e[i, 3:]]))
        B = np.diag((bias * np.sqrt(np.mean(np.square(e_cam), axis=0))) ** 2)
        K = lu_solve(lu, Jt @ Z)[k : k + mc]
        cov = cov + K @ B @ K.T
    cov = 0.5 * (cov + cov.T)
    return {name: cov[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] for i, name in enumerate(free)}, dt_std


def _errors(obs: list, r: np.ndarray) -> np.ndarray:
    """The adjustment's pose errors (m, 6) (rotation rad, position m; world axes) from its
    whitened ones ``r`` (m, 6): each unwhitened by its observation's whitening."""
    return np.linalg.solve(np.array([o[5] for o in obs]).reshape(-1, 6, 6), r[..., None])[..., 0]


#: the least misfit of a refined mounting's two estimates (:func:`_corner_covariance`): at it
#: no systematic error is added to the corners' covariance
MISFIT_FLOOR = 1.0

#: ``least_squares``' bound on the evaluations of :func:`_refine_on_corners`
_CORNER_NFEV = 300


def _rig_start(seen: dict, every: dict, mounts: dict, known: list, scale: float) -> tuple:
    """A rig frame's pose to start the corners' solve from (rig -> world rotation, position
    m): of the rig poses its camera frames give through their mountings (``seen``: camera ->
    :func:`_carried`'s tuple; ``every``: camera -> :func:`_posed_alone`'s items), the one
    whose projections of all its cameras' corners miss least (the sum of each corner's squared
    error in px, capped at ``(4 scale)^2``: a camera frame posed wrongly, e.g. one tag's
    mirrored pose, costs its corners the cap)."""
    best, out = np.inf, None
    for n in known:
        O_t, p_t = seen[n][:2]
        Rm, pm = mounts[n]
        Rg = O_t @ Rm.T
        Pg = p_t - Rg @ pm
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


def _refine_on_corners(
    rig_frames: list,
    every: dict,
    obs: list,
    rig: tuple,
    mounts: dict,
    reference: str,
    scale: float,
    window: float,
    max_step: float,
    timed: bool = False,
    warm: dict | None = None,
) -> tuple[dict, RigCorners, CornerSolution, dict] | None:
    """The mountings refined on the corners: the pose of every rig frame with two or more
    cameras in ``mounts`` and every free camera's mounting adjusted to the inlier corners of
    those cameras' frames (:class:`~rs_localizer.calibration.corners.RigCorners`: each
    corner's error in the distorted image of its camera under SciPy's ``soft_l1`` loss at
    ``scale`` px). The camera frames are ``every`` camera frame posed alone (camera -> the
    items of :func:`_posed_alone`), those with fewer inliers than the pose-level adjustment
    takes among them (a frame of one or two tags: its pose alone is too loose to average,
    its corners fix the mountings as well as any), grouped into rig frames as
    :func:`_rig_frames` does (``window``, ``max_step``). A rig frame starts at the pose-level
    adjustment's pose of the rig frame of the same time (:func:`_adjust`: its ``rig_frames``,
    observations ``obs``, rig poses ``rig`` and ``mounts``), else at the rig pose of the
    camera frame whose pose best predicts the rig frame's corners (:func:`_rig_start`).
    Camera frames the adjustment left out as outliers take part: their corners, not their
    poses. A camera frame carried to its rig frame's time (:func:`_carried`) keeps its pose
    relative to the carried one. ``timed``: each free camera's time offset (s added to its
    stamps) adjusted too, started at 0: its corners' camera pose moved along its twist at
    its rig frame (:class:`~rs_localizer.calibration.corners.RigCorners` ``motion``; the
    offsets in the free cameras' order of ``mounts``). ``warm``: rig frame time (ns) -> rig
    pose (rotation, position) of a previous solve to start that rig frame from. Only for
    global-shutter cameras (a rolling-shutter corner's time is not modelled here: the caller
    keeps the pose-level adjustment for those). Returns ``(mounts, the problem, its
    solution, each rig frame's time (ns))``; None when no corner projects."""
    free = [n for n in mounts if n != reference]
    start_at = {rig_frames[g][0]: (rig[0][gi], rig[1][gi]) for gi, g, *_ in obs}
    groups: dict = {}  # (camera name, model id) -> lists of rig frame, pose offsets, corners
    Rg0, Pg0 = [], []
    times = []
    warm = warm or {}
    for t, seen in _rig_frames(every, window, max_step):
        known = [n for n in seen if n in mounts]
        if len(known) < 2:
            continue
        Rg, Pg = warm.get(t) or start_at.get(t) or _rig_start(seen, every, mounts, known, scale)
        gi = len(Rg0)
        times.append(t)
        Rg0.append(Rg)
        Pg0.append(Pg)
        for n in known:
            O_t, p_t, _, twist, k = seen[n]
            _, Oc, pc, _, _, _, (uv, X, cam) = every[n][k]
            a = groups.setdefault((n, id(cam)), (cam, [], [], [], [], [], [], []))
            a[1].append(np.full(len(uv), gi))
            a[2].append(np.broadcast_to(O_t.T @ Oc, (len(uv), 3, 3)))
            a[3].append(np.broadcast_to(O_t.T @ (pc - p_t), (len(uv), 3)))
            a[4].append(uv)
            a[5].append(X)
            a[6].append(np.broadcast_to(twist[0], (len(uv), 3)))
            a[7].append(np.broadcast_to(twist[1], (len(uv), 3)))
    names = list(mounts)
    cams, parts = [], []
    for i, ((n, _), (cam, *lists)) in enumerate(groups.items()):
        cams.append(cam)
        gi, Dr, Dp, uv, X, w, v = (np.concatenate(v) for v in lists)
        d = np.full(len(gi), free.index(n) if n in free else -1)
        parts.append((np.full(len(gi), i), gi, np.full(len(gi), names.index(n)), Dr, Dp, uv, X,
                      d, w, v))  # fmt: skip
    camera, gi, m, Dr, Dp, uv, X, d, w, v = (np.concatenate(v) for v in zip(*parts, strict=True))
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
    return {n: (Rm[i], pm[i]) for i, n in enumerate(names)}, problem, sol, times


#: the rig frames of a refined mounting's covariance fall in this many runs of consecutive rig
#: frames, each run's corners one group (:func:`_corner_covariance`)
CORNER_BLOCKS = 10


def _corner_covariance(
    refined: dict,
    problem: RigCorners,
    sol: CornerSolution,
    start: dict,
    reference: str,
    pose_cov: dict,
) -> tuple[dict, float, dict, dict]:
    """Each refined mounting's covariance (6, 6) over (rotation [rad, rig axes], position [m,
    rig frame]): the corners' solve's (:meth:`RigCorners.mounting_covariance`, the rig poses
    marginalized), the rig frames in :data:`CORNER_BLOCKS` runs of consecutive ones, each
    run's corners a group whose errors may be correlated (a tag map's or a camera model's
    error is shared by the frames that see the same tags from about the same place), runs
    independent (times ``B / (B - 1)`` for the few groups), plus the systematic error the two
    estimates disagree by: the pose-level adjustment's ``start`` (its covariance
    ``pose_cov``) and the corners' ``refined`` estimate the same mountings from the same
    corners, so their difference ``d`` has about the pose-level covariance (the corners'
    estimate's is much the smaller); its excess ``m = d^T pose_cov^-1 d`` per degree of
    freedom over all cameras, beyond 1 (also returned, at least :data:`MISFIT_FLOOR`), is
    an error both carry, not the corners' noise (a camera model or a map slightly off, which
    a camera posed alone takes up its own way): ``(m - 1) pose_cov`` is added. With time
    offsets (``motion``), each free camera's (camera -> s, those runs as groups alike) and
    one run's offset's variance about it (camera -> s^2,
    :meth:`~rs_localizer.calibration.corners.RigCorners.mounting_covariance`'s scatter plus
    the offset's own variance: how far a rig frame's exposure is from the offset written);
    without, two empty dicts."""
    free = [n for n in refined if n != reference]
    blocks = min(CORNER_BLOCKS, problem.G)
    runs = (problem.frame * blocks) // problem.G
    dt_std, scatter = {}, {}
    if problem.D:
        C, std, var = problem.mounting_covariance(sol, runs, True)
        std = std * np.sqrt(blocks / max(blocks - 1, 1))
        dt_std = dict(zip(free, std.tolist(), strict=True))
        scatter = {n: float(v) + dt_std[n] ** 2 for n, v in zip(free, var, strict=True)}
    else:
        C = problem.mounting_covariance(sol, runs)
    C = C * (blocks / max(blocks - 1, 1))
    d = [np.r_[matrix_to_rotvec(refined[n][0] @ start[n][0].T), refined[n][1] - start[n][1]]
         for n in free]  # fmt: skip
    seen = [(di, n) for di, n in zip(d, free, strict=True) if np.isfinite(pose_cov[n]).all()]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LinAlgWarning)
        m2 = sum(float(di @ np.linalg.lstsq(pose_cov[n], di, rcond=None)[0]) for di, n in seen)
    misfit = max(MISFIT_FLOOR, m2 / max(6 * len(seen), 1))
    cov = {n: C[i] + (misfit - 1.0) * np.nan_to_num(pose_cov[n]) for i, n in enumerate(free)}
    return cov, misfit, dt_std, scatter


def _exposed_apart(
    rig_frames: list, poses: dict, mounts: dict, reference: str, bad: set, px: float
) -> tuple[dict, dict, dict]:
    """The cameras that do not expose with the reference: camera -> its time offset (s), those
    the pose-level adjustment with a time offset per camera (:func:`_adjust`, ``offsets``;
    started at ``mounts``, the camera frames in ``bad`` left out) finds beyond 3 of its std
    (:func:`_mounting_covariance`) and large enough to move a corner by more than
    :data:`EXPOSED_APART_SHARE` of ``px`` at the rig's median angular speed (the norm of its
    frames' angular velocity, rad/s) times the camera's mean focal length (px). Also that
    adjustment's mountings and their covariance (:func:`_mounting_covariance`)."""
    adjusted, J, r, obs, G, free, dts, _ = _adjust(rig_frames, mounts, reference, bad, True)
    cov, std = _mounting_covariance(J, r, obs, G, free)
    cam = np.array([o[2] for o in obs])
    speed = np.linalg.norm(np.array([o[6][0] for o in obs]).reshape(-1, 3), axis=1)
    out = {}
    for n, dt in dts.items():
        focal = poses[n][0][6][2].mean_focal
        shift = abs(dt) * float(np.median(speed[cam == n])) * focal
        if abs(dt) > 3.0 * std.get(n, np.inf) and shift > EXPOSED_APART_SHARE * px:
            out[n] = dt
    return out, adjusted, cov


def _posed_alone(frames: list, options: Any, min_inliers: int, stamp_row: float, given: dict):
    """Each camera's frames posed alone (:func:`~rs_localizer.estimation.estimate_rs_pose`),
    those with at least ``min_inliers`` inliers and a finite covariance: camera -> list of
    ``(t ns on the rig's clock, orientation (3, 3) camera -> world, position (3,) m, angular
    (3,) rad/s and linear (3,) m/s velocity in camera axes, covariance (12, 12), its inlier
    corners ``(pixels (K, 2), map points (K, 3) m, camera model)``)`` in time order (``t``: the
    reference line's capture time plus the camera's ``given`` offset, s)."""
    poses: dict[str, list] = {}
    for f in frames:
        if f.camera is None:
            continue
        est = estimate_rs_pose(f.points2d, f.points3d, f.camera, options=options)
        poses.setdefault(f.camera_name, [])
        if not est.success or est.num_inliers < min_inliers or est.covariance is None:
            continue
        if not np.isfinite(est.covariance[:6, :6]).all():
            continue
        t = reference_stamp_ns(f.stamp_ns, f.camera, stamp_row)
        t += int(round(given.get(f.camera_name, 0.0) * 1e9))
        q, inl = est.pose, np.asarray(est.inliers, dtype=bool)
        corners = (np.asarray(f.points2d, float)[inl], np.asarray(f.points3d, float)[inl], f.camera)
        poses[f.camera_name].append((t, q.orientation, q.position, q.angular_velocity,
                                     q.linear_velocity, est.covariance, corners))  # fmt: skip
    for items in poses.values():
        items.sort(key=lambda i: i[0])
    return poses


def calibrate_mountings(
    frames: list,
    reference: str,
    *,
    reference_mount: Mounting | None = None,
    window: float = 0.015,
    stamp_row: float = 0.0,
    min_inliers: int = 20,
    options: Any = None,
    max_step: float = 0.1,
    time_offsets: Mapping[str, float] | None = None,
    estimate_time_offsets: bool = False,
) -> dict:
    """Every camera's mounting on the rig from a video of a known map, adjusted jointly
    (docs/rig_node.md, "Mountings from data", has each step and its measurements).

    Each camera frame is posed alone (:func:`~rs_localizer.estimation.estimate_rs_pose`: its
    pose, twist and covariance at its reference line's capture time, camera optical frame);
    every camera frame's time starts a rig frame unless within ``window`` of the current one's
    start, each camera's nearest frame carried to it with the camera's motion (interpolated
    between its own two frames around it). The mountings start from the cameras' relative
    poses chained from the reference over the cameras that share rig frames (any set of
    cameras connected through shared rig frames, a ring or a chain, is calibrated), then every
    rig frame's pose and every mounting are adjusted in one least-squares problem (SciPy
    ``least_squares``, sparse Jacobian; each camera's pose errors whitened by its frames'
    typical covariance in its own axes, scaled to each frame's own covariance's size); camera
    frames beyond the 99.9 % chi-square quantile (6 degrees of freedom, at the errors' median
    scale) are left out and the adjustment is run again. When every camera reads out at once
    (global shutter), no time offset is estimated and the cameras expose together (no
    camera's time offset, estimated as with ``estimate_time_offsets``, beyond 3 of its std and
    moving a corner by more than :data:`EXPOSED_APART_SHARE` of the RANSAC threshold at the
    rig's median angular speed), the mountings are then refined on the
    corners of every camera frame posed alone, those with fewer than ``min_inliers`` inliers
    too (:func:`_refine_on_corners`: one rig pose per rig frame, each inlier corner's error
    in the distorted image, ``soft_l1`` at the RANSAC threshold of ``options``), each with
    the covariance of that solve, the rig poses marginalized, runs of rig frames as groups,
    plus the error the pose-level and the refined mountings disagree by beyond the pose-level
    covariance (:func:`_corner_covariance`).

    Args:
        frames: :class:`~rs_localizer.tracking.localizer.CameraFrame` of every camera (any
            order; frames without a camera model are skipped).
        reference: the camera whose optical frame is the rig frame, unless ``reference_mount``
            (its known mounting on the rig) places it: the rig frame is then that mounting's.
        window: s; frames further apart are not one rig frame.
        stamp_row: the row whose capture time is a frame's stamp.
        min_inliers: frames posed with fewer inliers are left out of the pose-level
            adjustment (the refinement on the corners takes their corners).
        max_step: s; the longest interval between a camera's two frames to interpolate over
            (beyond it a frame is carried by its own twist).
        options: the single-camera estimator's
            :class:`~rs_localizer.estimation.EstimateOptions` (None: its defaults).
        time_offsets: camera -> s added to its stamps (a rig's
            :attr:`~rs_localizer.tracking.video.LocalizerSettings.time_offsets`); None: none.
        estimate_time_offsets: also estimate every camera's time offset against the
            reference camera's (its given one kept): a parameter per camera in the adjustment
            (a camera frame's pose moved along its own twist), the frames regrouped at the
            offsets found (those beyond 3 of their std) and the adjustment run again until
            they change by less than :data:`TIME_OFFSET_TOL` (at most
            :data:`TIME_OFFSET_ROUNDS` times). Only a rig that moves shows an offset: its std
            says how well.
    Returns:
        camera name -> :class:`MountingEstimate` (cameras in the order they first appear;
        a camera not connected to the reference through shared rig frames is missing).
    Raises:
        ValueError: no frame of ``reference`` posed.
    """
    given = {n: float(v) for n, v in (time_offsets or {}).items()}
    # every camera frame posed alone (the corners' refinement takes them all), those with at
    # least min_inliers inliers for the pose-level adjustment
    every = _posed_alone(frames, options, 0, stamp_row, given)
    poses = {n: [i for i in items if len(i[6][0]) >= min_inliers] for n, items in every.items()}
    if not poses.get(reference):
        raise ValueError(
            f"calibrate_mountings: no frame of the reference camera {reference!r} posed"
        )
    base = reference_mount if reference_mount is not None else Mounting(np.eye(3), np.zeros(3))
    rig_frames = _rig_frames(poses, window, max_step)
    mounts = _initial_mounts(rig_frames, reference, base)
    if len(mounts) < 2:  # (no camera shares a rig frame with the reference)
        n_ref = len(poses[reference])
        return {reference: MountingEstimate(reference, base, n_ref, 0, 0.0, 0.0, 0.0, 0.0)}
    shifted = {n: 0.0 for n in poses}  # (s: the time offsets found so far, beyond the given)
    rounds = TIME_OFFSET_ROUNDS if estimate_time_offsets else 1
    for k in range(rounds):
        covariances = None  # (of this round's adjustment, once computed)
        mounts, J, r, obs, G, free, dts, rig = _adjust(
            rig_frames, mounts, reference, offsets=estimate_time_offsets
        )
        # camera frames that contradict the others, left out (at the errors' median scale)
        d2 = np.sum(r * r, axis=1)
        scale = max(float(np.median(d2)) / chi2.ppf(0.5, 6), 1.0)
        bad = {(g, n) for (_, g, n, *_), e in zip(obs, d2, strict=True)
               if e > scale * chi2.ppf(_OUTLIER_QUANTILE, 6)}  # fmt: skip
        if bad:
            mounts, J, r, obs, G, free, dts, rig = _adjust(
                rig_frames, mounts, reference, bad, offsets=estimate_time_offsets
            )
        if not dts or k == rounds - 1:
            break  # (the offsets of the last adjustment: dts, beyond those shifted)
        # the cameras' frames regrouped at the offsets found, those the video shows (beyond
        # 3 std; a rig that hardly moves shows none: its offsets stay)
        covariances = _mounting_covariance(J, r, obs, G, free)
        std = covariances[1]
        step = {n: dt for n, dt in dts.items()
                if abs(dt) >= TIME_OFFSET_TOL and abs(dt) > 3.0 * std.get(n, np.inf)}  # fmt: skip
        if not step:
            break
        for n, dt in step.items():
            shifted[n] += dt
            poses[n] = [(t + int(round(dt * 1e9)), *rest) for t, *rest in poses[n]]
        rig_frames = _rig_frames(poses, window, max_step)
    # (the last round's, when it regrouped nothing, is the final adjustment's)
    cov, dt_std = covariances or _mounting_covariance(J, r, obs, G, free)
    refined, apart, misfit = False, {}, float("nan")
    rolling = any(i[6][2].readout_time != 0.0 for items in poses.values() for i in items)
    if not estimate_time_offsets and not rolling:
        px = (options if options is not None else EstimateOptions()).ransac.threshold_px
        apart, timed, timed_cov = _exposed_apart(rig_frames, poses, mounts, reference, bad, px)
        corners = _refine_on_corners(
            rig_frames, every, obs, rig, mounts, reference, px, window, max_step, bool(apart)
        )
        found: dict = {}  # (s: with apart, the offsets the corners' solves found, summed)
        for _ in range(TIME_OFFSET_ROUNDS - 1 if apart and corners is not None else 0):
            # the camera frames regrouped at the offsets found and solved again from the
            # solution (the offsets the motion's first order leaves), until they change by
            # less than TIME_OFFSET_TOL
            dt = corners[1].time_offsets(corners[2].result.x)
            if np.all(np.abs(dt) < TIME_OFFSET_TOL):
                break
            free = [n for n in corners[0] if n != reference]
            for n, v in zip(free, dt.tolist(), strict=True):
                found[n] = found.get(n, 0.0) + v
                every[n] = [(t + int(round(v * 1e9)), *rest) for t, *rest in every[n]]
            warm = dict(zip(corners[3], zip(*corners[2].rig, strict=True), strict=True))
            again = _refine_on_corners(rig_frames, every, obs, rig, corners[0], reference, px,
                                       window, max_step, True, warm)  # fmt: skip
            if again is None:
                break
            corners = again
        refined = corners is not None
        if refined:
            # (the two estimates compared alike: with a time offset per camera or without)
            start, start_cov = (timed, timed_cov) if apart else (mounts, cov)
            cov, misfit, dt_c, _ = _corner_covariance(*corners[:3], start, reference, start_cov)
            mounts = corners[0]
            if apart:
                dt = corners[1].time_offsets(corners[2].result.x)
                dts = {n: float(v) + found.get(n, 0.0) for n, v in zip(dt_c, dt, strict=True)}
                dt_std = dt_c
    cam, e = [o[2] for o in obs], _errors(obs, r)  # (the camera frames' pose errors)
    out = {}
    for name in poses:
        if name not in mounts or (name != reference and not np.isfinite(cov[name]).all()):
            continue
        n_used, n_bad = cam.count(name), sum(1 for (_, n) in bad if n == name)
        offset = given.get(name, 0.0) + shifted.get(name, 0.0) + dts.get(name, 0.0)
        if name == reference:
            out[name] = MountingEstimate(
                name, base, n_used, n_bad, 0.0, 0.0, 0.0, 0.0, offset, corners_refined=refined
            )
            continue
        R, p = mounts[name]
        C = cov[name]
        # one camera frame's scatter about the rig: its pose errors against the adjustment
        mine = e[np.array(cam) == name]
        scat_r = float(np.sqrt(np.mean(np.sum(mine[:, :3] ** 2, axis=1))))
        scat_p = float(np.sqrt(np.mean(np.sum(mine[:, 3:] ** 2, axis=1))))
        out[name] = MountingEstimate(
            name, Mounting.from_pose(R, p, covariance=C), n_used, n_bad,
            float(np.rad2deg(np.sqrt(np.trace(C[:3, :3])))),
            float(1e3 * np.sqrt(np.trace(C[3:, 3:]))),
            float(np.rad2deg(scat_r)), 1e3 * scat_p, offset, dt_std.get(name, float("nan")),
            refined, apart.get(name, float("nan")), misfit,
        )  # fmt: skip
    return out
