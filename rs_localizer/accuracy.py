"""Accuracy of an estimate against ground truth (per frame and summarized over a sequence).

Used by the offline replay, the demo and the node tests; the ground truth is read from bags by
:func:`rs_localizer.ros.bags.bag_io.load_ground_truth`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .geometry import rotation_angle_deg

__all__ = ["GroundTruth", "format_summary", "frame_errors", "summarize_errors"]


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
