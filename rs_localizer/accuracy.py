"""Accuracy of an estimate against ground truth (per frame and summarized over a sequence).

Used by the offline replay, the demo and the node tests; the ground truth is read from bags by
:func:`rs_localizer.ros.bags.bag_io.load_ground_truth`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .geometry import rotation_angle_deg

__all__ = [
    "GroundTruth",
    "align_frames",
    "format_summary",
    "frame_errors",
    "frame_fit_summary",
    "summarize_errors",
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
