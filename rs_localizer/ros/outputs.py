"""The messages of a frame's outputs (a :class:`~rs_localizer.ros.pipeline.FrameResult`), in the
order the node publishes them; shared by the node (publishers) and ``rs-localizer replay``
(the output bag).

Topics (relative names, as the node publishes them): ``pose`` (PoseStamped, map frame),
``twist_single_frame`` (the frame's own twist), ``twist`` and ``odom`` (the frame's own twist
without tracking, else the fused twist of an earlier frame when it is final, stamped with that
frame's time), ``pose_with_covariance`` and ``tf``. Frames, stamps and covariances:
:mod:`.conversions`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

from . import conversions as cv
from .pipeline import FrameResult, FusedOutput

__all__ = ["OUTPUT_TOPICS", "frame_messages", "fused_messages", "pose_messages"]

#: every output topic of a solved frame, in publishing order
OUTPUT_TOPICS = ("pose", "twist_single_frame", "twist", "odom", "pose_with_covariance", "tf")


def _everything(topic: str) -> bool:
    return True


def fused_messages(
    fused: Iterable[FusedOutput], map_frame: str, wanted: Callable[[str], bool] = _everything
) -> list[tuple[str, Any]]:
    """``(topic, message)`` of the twist and odom of frames whose fused twist is final
    (``wanted(topic)`` false: that topic's messages are not built)."""
    twist, odom = wanted("twist"), wanted("odom")
    out = []
    for f in fused:
        if twist:
            out.append(("twist", cv.twist_stamped(f.source.pose, f.stamp_ns, f.frame_id)))
        if odom:
            out.append(("odom", cv.odometry(f.source, f.stamp_ns, map_frame, f.frame_id)))
    return out


def frame_messages(
    res: FrameResult, map_frame: str, wanted: Callable[[str], bool] = _everything
) -> list[tuple[str, Any]]:
    """``(topic, message)`` of everything a frame's result publishes, in order: for a solved
    frame ``pose``, ``twist_single_frame``, then ``twist`` and ``odom`` (its own twist, or the
    fused twists now final), ``pose_with_covariance`` and ``tf``; for a failed one the fused
    twists now final. ``wanted(topic)`` false skips building a message nobody receives
    (``pose`` is always built); ``tf`` needs ``tf2_msgs``."""
    if not res.solved:
        return fused_messages(res.fused, map_frame, wanted)
    fused = () if res.twist_now else res.fused
    return pose_messages(
        res.output, res.out_stamp_ns, map_frame, res.output_frame, res.twist_now, fused, wanted
    )


def pose_messages(
    out: Any,
    stamp: int,
    map_frame: str,
    frame: str,
    twist_now: bool,
    fused: Iterable[FusedOutput] = (),
    wanted: Callable[[str], bool] = _everything,
) -> list[tuple[str, Any]]:
    """``(topic, message)`` of a published pose, of a camera's frame or a rig frame, in order:
    ``pose``, ``twist_single_frame``, then ``twist`` and ``odom`` (its own twist with
    ``twist_now``, e.g. without tracking; else the ``fused`` twists now final),
    ``pose_with_covariance`` and ``tf``. ``out``: a
    :class:`~rs_localizer.pose.PoseWithCovariance` (its ``pose`` in ``map_frame``, its twist
    in ``frame``), ``stamp``: ns."""
    msgs: list[tuple[str, Any]] = [("pose", cv.pose_stamped(out.pose, stamp, map_frame))]
    if wanted("twist_single_frame"):
        msgs.append(("twist_single_frame", cv.twist_stamped(out.pose, stamp, frame)))
    if twist_now:
        if wanted("twist"):
            msgs.append(("twist", cv.twist_stamped(out.pose, stamp, frame)))
        if wanted("odom"):
            msgs.append(("odom", cv.odometry(out, stamp, map_frame, frame)))
    msgs += fused_messages(fused, map_frame, wanted)
    if wanted("pose_with_covariance"):
        msgs.append(
            ("pose_with_covariance", cv.pose_with_covariance_stamped(out, stamp, map_frame))
        )
    if wanted("tf"):
        msgs.append(("tf", cv.tf_message(out.pose, stamp, map_frame, frame)))
    return msgs
