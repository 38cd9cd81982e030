"""The accuracy of a node's outputs recorded by :func:`~.play.play` against a bag's ground
truth (:func:`~.bag_io.load_ground_truth`): what ``rs-localizer demo`` prints and the node's
tests check."""

from __future__ import annotations

from collections.abc import Sequence

from ...accuracy import GroundTruth, frame_errors
from ..conversions import pose_from_msg, stamp_to_ns, twist_from_msg

__all__ = ["evaluate_outputs"]


def evaluate_outputs(
    frames: Sequence[dict], gt: GroundTruth, namespaces: Sequence[str]
) -> dict[str, list[dict | None]]:
    """Per-frame errors of the pose/twist outputs of each namespace against ground truth.

    ``frames``: :attr:`PlayResult.frames <.play.PlayResult>` of a lock-step play that waited
    for ``{ns}/pose`` (``geometry_msgs/PoseStamped``) and ``{ns}/twist``
    (``geometry_msgs/TwistStamped``) of each namespace. The pose is compared at its own stamp,
    the twist at the twist's stamp (a fused twist may come a frame late).

    Returns ``{ns: [errors dict or None per frame]}``: ``rot_deg`` (deg), ``pos_m`` (m) and,
    with a twist, ``angvel`` (rad/s), ``linvel`` (m/s) and ``angvel_gt`` (rad/s) (see
    :func:`rs_localizer.accuracy.frame_errors`); None where the namespace published no pose or
    the bag has no ground truth near the stamp."""
    out = {ns: [] for ns in namespaces}
    for f in frames:
        for ns in namespaces:
            pose = f["outputs"].get(f"{ns}/pose")
            twist = f["outputs"].get(f"{ns}/twist")
            if pose is None:
                out[ns].append(None)
                continue
            R, p = pose_from_msg(pose[1].pose)
            err = frame_errors(R, p, None, None, gt, stamp_to_ns(pose[1].header.stamp))
            if twist is not None and err is not None:  # (at the twist's own stamp: a fused
                w, v = twist_from_msg(twist[1].twist)  # twist may come a frame late)
                tw = frame_errors(R, p, w, v, gt, stamp_to_ns(twist[1].header.stamp))
                if tw is not None:
                    err.update({k: tw[k] for k in ("angvel", "linvel", "angvel_gt") if k in tw})
            out[ns].append(err)
    return out
