"""How good a node's poses are (``rs-localizer evaluate``): its poses, read from a bag (a
``replay --out`` or a ``ros2 bag record`` of the node), a TUM file, or a live topic, matched by
stamp with a reference trajectory (a bag's ``/ground_truth/pose`` or a TUM file), and their
errors: the absolute and relative pose errors as evo computes them
(:func:`rs_localizer.accuracy.absolute_pose_errors`,
:func:`~rs_localizer.accuracy.relative_pose_errors`), optionally after an SE(3) Umeyama alignment
(:func:`~rs_localizer.accuracy.umeyama_alignment`),
the share of poses within 3 sigma of their stated covariance, and a plot.

Frames: every pose is body -> map (the camera optical frame's, or ``base_frame``'s, or the rig
frame's pose in ``map_frame``); the reference must describe the same body in the same map.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from ...accuracy import (
    GroundTruth,
    absolute_pose_errors,
    covariance_distances,
    error_statistics,
    relative_pose_errors,
    umeyama_alignment,
)
from .. import conversions as cv
from .bag_io import GT_POSE, bag_topics, iter_messages, typestore

__all__ = [
    "POSE_TYPES",
    "SIGMA3_PROBABILITY",
    "Trajectory",
    "capture_live",
    "evaluate_trajectory",
    "format_report",
    "is_tum_file",
    "plot_evaluation",
    "read_bag_trajectory",
    "read_tum",
    "write_tum",
]

#: the pose messages read (their pose and, where they have one, its covariance)
POSE_TYPES = (
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    "geometry_msgs/msg/PoseStamped",
    "nav_msgs/msg/Odometry",
)
#: the probability of a 1D normal within 3 sigma: the chi-square quantile of the 6-dof pose
#: error at this probability is the "within 3 sigma" bound
SIGMA3_PROBABILITY = 0.9973002039367398


@dataclass
class Trajectory:
    """Stamped body -> map poses: ``stamps`` (N,) int ns, ``orientation`` (N, 3, 3),
    ``position`` (N, 3) m, ``covariance`` (N, 6, 6) ROS order or None (none stated), and
    ``source`` (where they came from, for the report)."""

    stamps: np.ndarray
    orientation: np.ndarray
    position: np.ndarray
    covariance: np.ndarray | None = None
    source: str = ""

    def __len__(self) -> int:
        return len(self.stamps)

    @classmethod
    def from_poses(cls, rows: list, source: str) -> Trajectory:
        """From ``[(stamp_ns, R (3, 3), p (3,), covariance (6, 6) or None), ...]``, sorted by
        stamp; the covariance is kept when every row has one."""
        rows = sorted(rows, key=lambda r: r[0])
        covs = [r[3] for r in rows]
        have = bool(rows) and all(c is not None for c in covs)
        return cls(
            stamps=np.array([r[0] for r in rows], dtype=np.int64),
            orientation=np.array([r[1] for r in rows], dtype=float).reshape(-1, 3, 3),
            position=np.array([r[2] for r in rows], dtype=float).reshape(-1, 3),
            covariance=np.array(covs, dtype=float).reshape(-1, 6, 6) if have else None,
            source=source,
        )


def _pose_row(msg: Any, msgtype: str) -> tuple:
    """``(stamp_ns, R, p, covariance or None)`` of a pose message (:data:`POSE_TYPES`); an
    all-zero covariance (unknown) is None."""
    stamp = cv.stamp_to_ns(msg.header.stamp)
    if msgtype.endswith("PoseStamped") and not msgtype.endswith("CovarianceStamped"):
        R, p = cv.pose_from_msg(msg.pose)
        return stamp, R, p, None
    pwc = msg.pose  # PoseWithCovarianceStamped.pose, Odometry.pose: PoseWithCovariance
    R, p = cv.pose_from_msg(pwc.pose)
    C = np.asarray(pwc.covariance, dtype=float).reshape(6, 6)
    return stamp, R, p, (C if np.any(C) else None)


def _norm_type(msgtype: str) -> str:
    """``geometry_msgs/PoseStamped`` and ``geometry_msgs/msg/PoseStamped`` alike."""
    pkg, _, name = msgtype.rpartition("/")
    return f"{pkg.split('/')[0]}/msg/{name}"


def pose_topics(path: str | os.PathLike) -> dict[str, str]:
    """The pose topics (:data:`POSE_TYPES`) of a bag: topic -> message type."""
    return {t: _norm_type(mt) for t, mt in bag_topics(path).items() if _norm_type(mt) in POSE_TYPES}


def _default_topic(path: str | os.PathLike, topics: dict[str, str]) -> str:
    """The node's pose topic of a bag: the only namespace's ``pose_with_covariance`` (the pose
    with its covariance), else its ``pose``, else its ``odom``; the ground truth left out.
    Raises ValueError when there is none or several namespaces have one."""
    for suffix in ("pose_with_covariance", "pose", "odom"):
        found = [t for t in topics if t != GT_POSE and t.rsplit("/", 1)[-1] == suffix]
        if len(found) == 1:
            return found[0]
        if len(found) > 1:
            raise ValueError(
                f"{path}: several {suffix} topics {sorted(found)}: choose one with --topic"
            )
    raise ValueError(
        f"{path}: no pose topic of the node (PoseWithCovarianceStamped, PoseStamped or "
        f"Odometry besides {GT_POSE}; topics: {sorted(bag_topics(path))})"
    )


def read_bag_trajectory(path: str | os.PathLike, topic: str | None = None) -> Trajectory:
    """The poses of ``topic`` in the bag at ``path`` (default: the node's pose topic, see
    :func:`_default_topic`), by header stamp.

    Raises:
        ValueError: the topic is not in the bag, not a pose message (:data:`POSE_TYPES`), or
            has no message; no default topic.
    """
    topics = pose_topics(path)
    if topic is None:
        topic = _default_topic(path, topics)
    elif topic not in topics:
        all_topics = bag_topics(path)
        if topic in all_topics:
            raise ValueError(
                f"{path}: {topic} is a {all_topics[topic]}, not a pose ({', '.join(POSE_TYPES)})"
            )
        raise ValueError(f"{path}: no topic {topic} (pose topics: {sorted(topics)})")
    ts = typestore()
    rows = [
        _pose_row(ts.deserialize_cdr(raw, mt), _norm_type(mt))
        for _, mt, _, raw in iter_messages(path, {topic})
    ]
    if not rows:
        raise ValueError(f"{path}: {topic} has no message")
    return Trajectory.from_poses(rows, f"{path} {topic}")


def is_tum_file(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a file (a TUM trajectory), not a bag directory or its storage file
    (``.mcap``, ``.db3``)."""
    p = Path(path)
    return p.is_file() and p.suffix not in (".mcap", ".db3", ".yaml")


def read_tum(path: str | os.PathLike) -> Trajectory:
    """A TUM trajectory file: one pose a line, ``timestamp tx ty tz qx qy qz qw`` (s, m,
    body -> map quaternion), ``#`` comments. Raises ValueError on a line that is not 8 numbers
    or a file without poses."""
    rows = []
    for k, line in enumerate(Path(path).read_text().splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        try:
            v = [float(x) for x in line.replace(",", " ").split()]
        except ValueError:
            v = []
        if len(v) != 8 or not np.all(np.isfinite(v)) or np.linalg.norm(v[4:]) < 1e-9:
            raise ValueError(f"{path}:{k}: not a TUM pose (timestamp tx ty tz qx qy qz qw)")
        R = Rotation.from_quat(v[4:]).as_matrix()
        rows.append((int(round(v[0] * 1e9)), R, np.array(v[1:4]), None))
    if not rows:
        raise ValueError(f"{path}: no pose")
    return Trajectory.from_poses(rows, str(path))


def write_tum(traj: Trajectory, path: str | os.PathLike) -> None:
    """Write ``traj`` as a TUM trajectory file (see :func:`read_tum`), stamps in s with 9
    decimals."""
    q = Rotation.from_matrix(traj.orientation).as_quat()
    lines = [
        f"{s // 1_000_000_000}.{s % 1_000_000_000:09d} " + " ".join(f"{x:.9f}" for x in (*p, *qk))
        for s, p, qk in zip(traj.stamps.tolist(), traj.position, q, strict=True)
    ]
    Path(path).write_text("\n".join(lines) + "\n")


def capture_live(
    topic: str,
    seconds: float,
    truth_topic: str | None = None,
    context: Any = None,
    wait: float = 60.0,
    stop: Callable[[], bool] | None = None,
) -> tuple[Trajectory, Trajectory | None]:
    """The poses published on ``topic`` (and ``truth_topic``, if given) during ``seconds`` s
    from the first pose on ``topic``: a running node's outputs while a bag plays
    (``rs-localizer play``, ``ros2 bag play``). Each topic is subscribed as soon as it has a
    publisher, with the publisher's message type (one of :data:`POSE_TYPES`) and a
    reliability that matches the publishers' (reliable when they all are), depth 1000.

    ``context``: an initialized rclpy Context (default: a new one, shut down at the end).
    ``stop``: called while listening; true ends the capture.

    Raises:
        TimeoutError: no pose on ``topic`` within ``wait`` s.
        ValueError: a topic's type is not a pose (:data:`POSE_TYPES`).
    """
    import importlib

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    own = context is None
    if own:
        context = rclpy.Context()
        rclpy.init(args=[], context=context)
    node = rclpy.create_node("rs_localizer_evaluate", context=context)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(node)
    names = [topic] + ([truth_topic] if truth_topic else [])
    rows: dict[str, list] = {n: [] for n in names}
    waiting = list(names)

    def subscribe(name: str) -> bool:
        infos = node.get_publishers_info_by_topic(name)
        if not infos:
            return False
        mt = _norm_type(infos[0].topic_type)
        if mt not in POSE_TYPES:
            raise ValueError(f"{name} is a {mt}, not a pose ({', '.join(POSE_TYPES)})")
        reliable = all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in infos)
        qos = QoSProfile(
            depth=1000,
            reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        )
        pkg, _, cls = mt.split("/")
        msg_class = getattr(importlib.import_module(f"{pkg}.msg"), cls)
        node.create_subscription(
            msg_class, name, lambda msg: rows[name].append(_pose_row(msg, mt)), qos
        )
        return True

    t_wait = time.monotonic() + wait
    t_end = None
    try:
        while context.ok():
            waiting = [n for n in waiting if not subscribe(n)]
            ex.spin_once(timeout_sec=0.02)
            now = time.monotonic()
            if t_end is None and rows[topic]:
                t_end = now + seconds  # (the window starts at the first pose)
            if t_end is None and now > t_wait:
                raise TimeoutError(
                    f"no pose on {topic} within {wait:g} s"
                    + (" (no publisher)" if topic in waiting else "")
                )
            if (t_end is not None and now >= t_end) or (stop is not None and stop()):
                break
    except KeyboardInterrupt:  # (Ctrl-C: evaluate what came so far)
        pass
    finally:
        ex.shutdown()
        node.destroy_node()
        if own:
            rclpy.try_shutdown(context=context)
    est = Trajectory.from_poses(rows[topic], f"live {topic}")
    truth = Trajectory.from_poses(rows[truth_topic], f"live {truth_topic}") if truth_topic else None
    return est, truth


def _match(est: Trajectory, ref: Trajectory, tol_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(i_est, i_ref)`` of the estimates with a reference pose within ``tol_ns`` of
    their stamp (the nearest, :meth:`rs_localizer.accuracy.GroundTruth.nearest`)."""
    gt = GroundTruth(stamps=ref.stamps)
    index = {int(s): k for k, s in enumerate(ref.stamps.tolist())}
    ie, ir = [], []
    for k, s in enumerate(est.stamps.tolist()):
        r = gt.nearest(int(s), tol_ns)
        if r is not None:
            ie.append(k)
            ir.append(index[r])
    return np.array(ie, dtype=int), np.array(ir, dtype=int)


def evaluate_trajectory(
    est: Trajectory,
    ref: Trajectory,
    align: bool = False,
    delta: int = 1,
    tol_ns: int = 2_000_000,
) -> dict:
    """The errors of ``est`` against the reference ``ref``, matched by stamp (the reference
    pose nearest each estimate's stamp within ``tol_ns``).

    ``align``: first move the estimates by the SE(3) Umeyama alignment of their positions onto
    the reference's (evo's ``--align``); without it the two are compared as they are (same map).

    Returns a dict: ``estimates``, ``references``, ``matched`` (counts); ``alignment``
    (``rotation`` (3, 3) list, ``translation`` m, ``angle_deg``) or None; ``ape`` and
    ``rpe`` (``rot_deg`` and ``pos_m``: :func:`rs_localizer.accuracy.error_statistics` of
    :func:`~rs_localizer.accuracy.absolute_pose_errors` and of
    :func:`~rs_localizer.accuracy.relative_pose_errors` over ``delta`` matched poses), ``delta``;
    ``covariance`` (``poses`` with a covariance, ``within_3_sigma`` of them: squared
    Mahalanobis distance within the 6-dof chi-square quantile of :data:`SIGMA3_PROBABILITY`,
    ``share``, ``bound``; None when the estimates state none); ``per_pose`` (arrays for the
    plot: ``t`` s since the first matched stamp, ``rot_deg``, ``pos_m``, ``mahalanobis2``,
    ``est_position`` and ``ref_position`` (M, 3) after the alignment).

    Raises ValueError when no estimate matches a reference pose, or ``align`` with fewer than
    3 matches or matched positions on one line.
    """
    ie, ir = _match(est, ref, tol_ns)
    if not len(ie):
        raise ValueError(
            f"no estimate has a reference pose within {tol_ns / 1e6:g} ms of its stamp "
            f"({len(est)} estimates {_span(est)}, {len(ref)} reference poses {_span(ref)})"
        )
    R_e, p_e = est.orientation[ie], est.position[ie]
    R_r, p_r = ref.orientation[ir], ref.position[ir]
    alignment = None
    if align:
        R_a, t_a, _ = umeyama_alignment(p_e, p_r)
        R_e, p_e = R_a @ R_e, p_e @ R_a.T + t_a
        alignment = {
            "rotation": R_a.tolist(),
            "translation": t_a.tolist(),
            "angle_deg": float(np.degrees(Rotation.from_matrix(R_a).magnitude())),
        }
    ape = absolute_pose_errors(R_e, p_e, R_r, p_r)
    rpe = relative_pose_errors(R_e, p_e, R_r, p_r, delta)
    cov = None
    d2 = np.full(len(ie), np.nan)
    if est.covariance is not None:
        C = est.covariance[ie]
        if alignment is not None:  # (the covariance in the aligned frame: rotated by R_a)
            T = np.kron(np.eye(2), np.asarray(alignment["rotation"]))
            C = T @ C @ T.T
        d2 = covariance_distances(R_e, p_e, R_r, p_r, C)
        bound = float(chi2.ppf(SIGMA3_PROBABILITY, 6))
        stated = np.isfinite(d2)
        n_in = int(np.sum(d2[stated] <= bound))
        cov = {
            "poses": int(stated.sum()),
            "within_3_sigma": n_in,
            "share": n_in / stated.sum() if stated.any() else float("nan"),
            "bound": bound,
        }
    t0 = int(est.stamps[ie[0]])
    return {
        "estimates": len(est),
        "references": len(ref),
        "matched": len(ie),
        "tolerance_ms": tol_ns / 1e6,
        "alignment": alignment,
        "ape": {k: error_statistics(ape[k]) for k in ("rot_deg", "pos_m")},
        "rpe": {k: error_statistics(rpe[k]) for k in ("rot_deg", "pos_m")},
        "delta": delta,
        "covariance": cov,
        "per_pose": {
            "t": (est.stamps[ie] - t0) / 1e9,
            "rot_deg": ape["rot_deg"],
            "pos_m": ape["pos_m"],
            "mahalanobis2": d2,
            "est_position": p_e,
            "ref_position": p_r,
        },
    }


def _span(traj: Trajectory) -> str:
    if not len(traj):
        return "(none)"
    return f"[{traj.stamps[0] / 1e9:.3f}, {traj.stamps[-1] / 1e9:.3f}] s"


def format_report(res: dict, est: Trajectory, ref: Trajectory) -> str:
    """The evaluation as text: sources and counts, the APE and RPE statistics (rotation in
    deg, position in cm), the alignment, the covariance's consistency."""
    lines = [
        f"estimates: {est.source} ({res['estimates']} poses)",
        f"reference: {ref.source} ({res['references']} poses)",
        f"matched by stamp (within {res['tolerance_ms']:g} ms): {res['matched']}/"
        f"{res['estimates']} estimates",
    ]
    a = res["alignment"]
    if a is not None:
        lines.append(
            f"SE(3) Umeyama alignment: rotation {a['angle_deg']:.4g} deg, translation "
            + " ".join(f"{x:.4g}" for x in a["translation"])
            + " m"
        )

    def row(name: str, s: dict, scale: float, unit: str) -> str:
        if not s.get("count"):
            return f"  {name}: none"
        return f"  {name} ({unit}): " + "  ".join(
            f"{k} {s[k] * scale:.4g}" for k in ("median", "p90", "rmse", "mean", "max")
        )

    for key, title in (("ape", "APE"), ("rpe", f"RPE (delta {res['delta']} frames)")):
        lines.append(f"{title}, {res[key]['rot_deg'].get('count', 0)} "
                     + ("poses" if key == "ape" else "pairs") + ":")  # fmt: skip
        lines.append(row("rotation", res[key]["rot_deg"], 1.0, "deg"))
        lines.append(row("position", res[key]["pos_m"], 100.0, "cm"))
    c = res["covariance"]
    if c is None:
        lines.append("covariance: none stated (a PoseStamped topic; use pose_with_covariance)")
    else:
        lines.append(
            f"covariance: {c['within_3_sigma']}/{c['poses']} poses ({100 * c['share']:.1f} %) "
            f"within 3 sigma (6-dof squared Mahalanobis distance <= {c['bound']:.2f}; "
            f"{100 * SIGMA3_PROBABILITY:.2f} % expected of a consistent covariance)"
        )
    return "\n".join(lines)


def plot_evaluation(res: dict, path: str | os.PathLike, title: str = "") -> Path:
    """A PNG at ``path``: the rotation and position errors over time (the poses outside 3
    sigma of their covariance marked), and the top view (map x-y) of the reference and the
    estimated positions. Returns the path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pp = res["per_pose"]
    fig = plt.figure(figsize=(12, 6.5))
    gs = fig.add_gridspec(2, 2, width_ratios=[1.4, 1])
    ax_r = fig.add_subplot(gs[0, 0])
    ax_p = fig.add_subplot(gs[1, 0], sharex=ax_r)
    ax_t = fig.add_subplot(gs[:, 1])
    t = pp["t"]
    outside = np.isfinite(pp["mahalanobis2"])
    if res["covariance"] is not None:
        outside &= pp["mahalanobis2"] > res["covariance"]["bound"]
    else:
        outside[:] = False
    for ax, vals, label in (
        (ax_r, pp["rot_deg"], "rotation error (deg)"),
        (ax_p, 100 * pp["pos_m"], "position error (cm)"),
    ):
        ax.plot(t, vals, ".-", lw=0.8, ms=3, color="C0")
        if outside.any():
            ax.plot(t[outside], vals[outside], "x", color="C3", label="outside 3 sigma")
            ax.legend(loc="upper right", fontsize=8)
        ax.axhline(np.median(vals), color="0.5", ls="--", lw=0.8)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    ax_p.set_xlabel("time since the first matched pose (s)")
    ax_r.set_title(
        "APE" + (" after SE(3) alignment" if res["alignment"] else "") + " (dashed: median)"
    )
    ref, est = pp["ref_position"], pp["est_position"]
    ax_t.plot(ref[:, 0], ref[:, 1], "-", color="0.3", lw=1.5, label="reference")
    ax_t.plot(est[:, 0], est[:, 1], ".", color="C1", ms=3, label="estimate")
    ax_t.plot(ref[:1, 0], ref[:1, 1], "o", color="0.3", ms=5)
    ax_t.set_aspect("equal", adjustable="datalim")
    ax_t.set_xlabel("map x (m)")
    ax_t.set_ylabel("map y (m)")
    ax_t.set_title("top view (o: start)")
    ax_t.legend(fontsize=8)
    ax_t.grid(alpha=0.3)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
