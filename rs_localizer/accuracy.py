"""Accuracy of an estimate against ground truth (per frame and summarized over a sequence).

Used by the offline replay, the demo and the node tests; the ground truth is read from bags by
:func:`rs_localizer.ros.bags.bag_io.load_ground_truth`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from .geometry import rotation_angle_deg

__all__ = [
    "GroundTruth",
    "absolute_pose_errors",
    "align_frames",
    "covariance_distances",
    "error_statistics",
    "format_summary",
    "frame_errors",
    "frame_fit_summary",
    "relative_pose_errors",
    "summarize_errors",
    "umeyama_alignment",
]

#: a rigid fit of the estimate's frame onto the ground truth's beyond these (deg, m) means the
#: two are in different frames (a map not in the ground truth's frame)
OTHER_FRAME_DEG, OTHER_FRAME_M = 1.0, 0.05


@dataclass
class GroundTruth:
    """Ground truth per reference-row stamp (ns): camera -> map pose and camera-frame twist."""

    stamps: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    orientation: dict = field(default_factory=dict)
    position: dict = field(default_factory=dict)
    angular_velocity: dict = field(default_factory=dict)
    linear_velocity: dict = field(default_factory=dict)

    def __len__(self):
        return len(self.stamps)

    def nearest(self, stamp_ns: int, tol_ns: int = 2_000_000):
        """Ground-truth stamp nearest ``stamp_ns`` within ``tol_ns``, else None."""
        if not len(self.stamps):
            return None
        i = int(np.searchsorted(self.stamps, stamp_ns))
        best = None
        for j in (i - 1, i):
            if 0 <= j < len(self.stamps):
                d = abs(int(self.stamps[j]) - int(stamp_ns))
                if d <= tol_ns and (best is None or d < best[0]):
                    best = (d, int(self.stamps[j]))
        return None if best is None else best[1]


def frame_errors(
    orientation, position, angular_velocity, linear_velocity, gt: GroundTruth, stamp_ns: int
) -> dict | None:
    """Errors of one estimate against ground truth: rotation (deg), position (m), angular
    velocity (rad/s, norm of the difference), linear velocity (m/s). None if no ground truth."""
    s = gt.nearest(stamp_ns)
    if s is None:
        return None
    out = {
        "rot_deg": rotation_angle_deg(orientation, gt.orientation[s]),
        "pos_m": float(np.linalg.norm(np.asarray(position) - gt.position[s])),
    }
    if s in gt.angular_velocity and angular_velocity is not None:
        out["angvel"] = float(np.linalg.norm(np.asarray(angular_velocity) - gt.angular_velocity[s]))
        out["linvel"] = float(np.linalg.norm(np.asarray(linear_velocity) - gt.linear_velocity[s]))
        out["angvel_gt"] = float(np.linalg.norm(gt.angular_velocity[s]))
    return out


def align_frames(est: list, gt: list) -> tuple[np.ndarray, np.ndarray]:
    """The rigid transform ``(R (3, 3), t (3,))`` taking the estimate's frame onto the ground
    truth's, from pairs of camera -> frame poses ``(R, p)`` (``est``, ``gt``: same length):
    the rotation is the chordal mean of ``R_gt R_est^T`` (SVD projection of their sum), the
    translation the mean of ``p_gt - R p_est``. Raises ValueError without pairs."""
    if not est or len(est) != len(gt):
        raise ValueError(f"align_frames: {len(est)} estimates for {len(gt)} ground truths")
    M = sum(np.asarray(g[0]) @ np.asarray(e[0]).T for e, g in zip(est, gt, strict=True))
    U, _, Vt = np.linalg.svd(M)
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    t = np.mean([np.asarray(g[1]) - R @ np.asarray(e[1]) for e, g in zip(est, gt, strict=True)], 0)
    return R, t


def frame_fit_summary(est: list, gt: list) -> dict | None:
    """The estimate's poses against ground truth after the rigid fit of the frames
    (:func:`align_frames`): ``rot_deg``/``pos_m`` of the fit itself, ``other_frame`` (the fit
    moves more than ``OTHER_FRAME_DEG`` or ``OTHER_FRAME_M``: the ground truth is in another
    frame than the estimate's) and ``aligned`` (:func:`summarize_errors` of the rotation and
    position errors after the fit). None for fewer than 3 pairs."""
    if len(est) < 3:
        return None
    R, t = align_frames(est, gt)
    errs = [
        {
            "rot_deg": rotation_angle_deg(R @ np.asarray(e[0]), g[0]),
            "pos_m": float(np.linalg.norm(R @ np.asarray(e[1]) + t - g[1])),
        }
        for e, g in zip(est, gt, strict=True)
    ]
    rot = rotation_angle_deg(R, np.eye(3))
    pos = float(np.linalg.norm(t))
    return {
        "rot_deg": rot,
        "pos_m": pos,
        "other_frame": bool(rot > OTHER_FRAME_DEG or pos > OTHER_FRAME_M),
        "aligned": summarize_errors(errs),
    }


def summarize_errors(errors: list) -> dict:
    """Median / mean / max of each error over frames (None entries skipped)."""
    errors = [e for e in errors if e]
    out = {"frames": len(errors)}
    for key in ("rot_deg", "pos_m", "angvel", "linvel"):
        vals = np.array([e[key] for e in errors if key in e])
        if len(vals):
            out[key] = {
                "median": float(np.median(vals)),
                "mean": float(np.mean(vals)),
                "p90": float(np.percentile(vals, 90)),
                "max": float(np.max(vals)),
            }
    return out


def format_summary(name: str, summary: dict, total: int | None = None) -> str:
    parts = [
        f"{name}: {summary['frames']}" + (f"/{total}" if total is not None else "") + " frames"
    ]
    units = {
        "rot_deg": ("rotation", "deg", 1),
        "pos_m": ("position", "cm", 100),
        "angvel": ("ang.vel", "rad/s", 1),
        "linvel": ("lin.vel", "m/s", 1),
    }
    for key, (label, unit, scale) in units.items():
        if key in summary:
            s = summary[key]
            parts.append(
                f"{label} median {s['median'] * scale:.3g} mean {s['mean'] * scale:.3g} "
                f"max {s['max'] * scale:.3g} {unit}"
            )
    return "; ".join(parts)


# ---------------------------------------------------------------- trajectories (evaluate)
def umeyama_alignment(
    source: np.ndarray,
    target: np.ndarray,
    with_scale: bool = False,
    weights: np.ndarray | None = None,
    any_on_line: bool = False,
) -> tuple[np.ndarray, np.ndarray, float]:
    """The similarity ``(R (3, 3), t (3,), s)`` minimizing ``sum_i w_i |target_i - (s R
    source_i + t)|^2`` over the point pairs ``source``, ``target`` (N, 3) (Umeyama, IEEE TPAMI
    13(4), 1991); ``weights`` (N,) ``w_i`` (None: equal); ``s = 1`` unless ``with_scale``.
    Raises ValueError for shapes that differ, fewer than 3 pairs or points on one line (the
    rotation is not determined), unless ``any_on_line`` (then one of the rotations that fit:
    the line-delay calibration's gyro rates about one axis, whose covariance says which axis is
    free)."""
    x = np.asarray(source, dtype=float)
    y = np.asarray(target, dtype=float)
    if x.shape != y.shape or x.ndim != 2 or x.shape[1] != 3 or (len(x) < 3 and not any_on_line):
        raise ValueError(
            f"umeyama_alignment: expected two (N >= 3, 3) arrays, got {x.shape}, {y.shape}"
        )
    w = np.ones(len(x)) if weights is None else np.asarray(weights, dtype=float)
    W = w / w.sum()
    mx, my = W @ x, W @ y
    xc, yc = x - mx, y - my
    U, d, Vt = np.linalg.svd((yc * W[:, None]).T @ xc)
    if d[1] <= 1e-12 * max(d[0], 1e-300) and not any_on_line:
        raise ValueError("umeyama_alignment: the points are on one line (rotation undetermined)")
    S = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    R = U @ S @ Vt
    var_x = float(np.sum(W * np.sum(xc * xc, axis=1)))
    s = float(np.trace(np.diag(d) @ S) / max(var_x, 1e-300)) if with_scale else 1.0
    return R, my - s * R @ mx, s


def _angles_deg(R: np.ndarray) -> np.ndarray:
    """Rotation angles (deg) of a stack of rotations (N, 3, 3)."""
    c = (np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def absolute_pose_errors(
    R_est: np.ndarray, p_est: np.ndarray, R_ref: np.ndarray, p_ref: np.ndarray
) -> dict[str, np.ndarray]:
    """The absolute pose error (APE) of matched poses, as evo defines it: ``E_i = Q_i^-1 P_i``
    with ``P_i`` the estimate, ``Q_i`` the reference (body -> map: orientations (N, 3, 3),
    positions (N, 3) in m). Returns ``rot_deg`` (N,): the angle of ``E_i``'s rotation (deg),
    ``pos_m`` (N,): the norm of its translation (m), which is ``|p_est - p_ref|``."""
    R_est, R_ref = np.asarray(R_est, float), np.asarray(R_ref, float)
    return {
        "rot_deg": _angles_deg(np.swapaxes(R_ref, 1, 2) @ R_est),
        "pos_m": np.linalg.norm(np.asarray(p_est, float) - np.asarray(p_ref, float), axis=1),
    }


def relative_pose_errors(
    R_est: np.ndarray,
    p_est: np.ndarray,
    R_ref: np.ndarray,
    p_ref: np.ndarray,
    delta: int = 1,
    all_pairs: bool = False,
) -> dict[str, np.ndarray]:
    """The relative pose error (RPE) of matched poses over ``delta`` frames, as evo defines it
    (its default ``--delta_unit f``): ``E_ij = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` for the pairs
    ``(i, j = i + delta)``, ``i`` = 0, delta, 2 delta, ... (``all_pairs``: every ``i``).
    Arguments as :func:`absolute_pose_errors`. Returns ``rot_deg`` (deg) and ``pos_m`` (m),
    the rotation angle and translation norm of each ``E_ij``, and ``pairs`` (M, 2) the indices.
    Raises ValueError for ``delta < 1``."""
    if delta < 1:
        raise ValueError(f"relative_pose_errors: delta must be >= 1, got {delta}")
    R_est, R_ref = np.asarray(R_est, float), np.asarray(R_ref, float)
    p_est, p_ref = np.asarray(p_est, float), np.asarray(p_ref, float)
    n = len(R_est)
    i = np.arange(n - delta) if all_pairs else np.arange(0, n, delta)[:-1]
    i = i[i + delta < n]
    j = i + delta

    def motion(R, p):  # T_i^-1 T_j: rotation R_i^T R_j, translation R_i^T (p_j - p_i)
        Ri_T = np.swapaxes(R[i], 1, 2)
        return Ri_T @ R[j], np.einsum("nab,nb->na", Ri_T, p[j] - p[i])

    Rq, tq = motion(R_ref, p_ref)
    Rp, tp = motion(R_est, p_est)
    Rq_T = np.swapaxes(Rq, 1, 2)  # E = (Rq, tq)^-1 (Rp, tp) = (Rq^T Rp, Rq^T (tp - tq))
    return {
        "rot_deg": _angles_deg(Rq_T @ Rp),
        "pos_m": np.linalg.norm(tp - tq, axis=1),
        "pairs": np.stack([i, j], 1),
    }


def covariance_distances(
    R_est: np.ndarray,
    p_est: np.ndarray,
    R_ref: np.ndarray,
    p_ref: np.ndarray,
    covariance: np.ndarray,
) -> np.ndarray:
    """The squared Mahalanobis distance ``e^T C^-1 e`` (N,) of each pose error under its stated
    covariance ``C`` (N, 6, 6), ROS order (x, y, z, rot x, rot y, rot z), map frame, rotation
    about the map axes as the node publishes it: ``e = (p_est - p_ref, log(R_est R_ref^T))``
    (m, rad). NaN where ``C`` is not positive definite (unknown: zeros)."""
    R_est, R_ref = np.asarray(R_est, float), np.asarray(R_ref, float)
    dR = R_est @ np.swapaxes(R_ref, 1, 2)
    rot = Rotation.from_matrix(dR).as_rotvec()
    e = np.concatenate([np.asarray(p_est, float) - np.asarray(p_ref, float), rot], 1)
    out = np.full(len(e), np.nan)
    for k, (ek, C) in enumerate(zip(e, np.asarray(covariance, float), strict=True)):
        try:
            L = np.linalg.cholesky(C)
        except np.linalg.LinAlgError:
            continue
        z = np.linalg.solve(L, ek)
        out[k] = float(z @ z)
    return out


def error_statistics(values) -> dict:
    """``count``, ``rmse``, ``mean``, ``median``, ``p90``, ``std``, ``min``, ``max`` of the
    finite ``values`` (evo's statistics plus the 90th percentile); ``{"count": 0}`` without."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if not len(v):
        return {"count": 0}
    return {
        "count": len(v),
        "rmse": float(np.sqrt(np.mean(v**2))),
        "mean": float(np.mean(v)),
        "median": float(np.median(v)),
        "p90": float(np.percentile(v, 90)),
        "std": float(np.std(v)),
        "min": float(np.min(v)),
        "max": float(np.max(v)),
    }
