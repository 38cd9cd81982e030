"""What one frame's outcome publishes, for one camera and a rig alike: its messages, in the
order the node publishes them (shared by the node's publishers and ``rs-localizer replay``'s
output bag), its debug views and its log line.

The node's mode (:class:`~rs_localizer.ros.mode.LocalizerMode`) turns what a frame gave (the
camera alone's frame, or a rig frame, a :class:`~rs_localizer.tracking.video.LocalizerOutput`)
into a :class:`FrameOutcome` and hands it to :func:`publish_frame`.

Topics (relative names, as the node publishes them): ``pose`` (PoseStamped, map frame),
``twist_single_frame`` (the frame's own twist), ``twist`` and ``odom`` (the frame's own twist
without tracking, else the fused twist of an earlier frame when it is final, stamped with that
frame's time), ``pose_with_covariance`` and ``tf``; ``path``, and each camera's
``debug_image`` and ``markers`` (:mod:`.visualization`). Frames, stamps and covariances:
:mod:`.conversions`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple, Protocol

import numpy as np

from ..camera import CameraModel
from ..estimation.result import RSPoseEstimate
from ..frames import camera_to_base
from ..pose import PoseWithCovariance
from . import conversions as cv
from .pipeline import FusedOutput, fused_outputs

if TYPE_CHECKING:
    from ..frames import Mounting
    from ..tracking.video import Localizer, LocalizerOutput
    from .visualization import NodeVisualization

__all__ = [
    "OUTPUT_TOPICS",
    "CameraView",
    "FrameOutcome",
    "LogLine",
    "OutputNode",
    "PosedFrame",
    "frame_outcome",
    "fused_messages",
    "outcome_messages",
    "pose_messages",
    "publish_frame",
    "rig_frame_line",
    "rig_frame_views",
]

#: every output topic of a solved frame, in publishing order
OUTPUT_TOPICS = ("pose", "twist_single_frame", "twist", "odom", "pose_with_covariance", "tf")


class LogLine(NamedTuple):
    """A warning of the node's throttled log (:meth:`.core.NodeCore.warn`): at most one
    ``key`` line per period; ``count`` > 1 appended as ``[count so far]``."""

    key: str
    text: str
    count: int = 0


@dataclass(frozen=True)
class CameraView:
    """A camera of a posed frame as its ``debug_image`` and ``markers`` draw it
    (:meth:`.visualization.NodeVisualization.publish`): ``name`` ("" for the single
    camera, whose views also draw the ``path``), ``estimate`` the camera's pose (map frame)
    and twist, ``points2d`` (N, 2) px and ``points3d`` (N, 3) m the estimator's rows of the
    camera, ``camera`` its model, ``stamp_ns`` its input stamp (the debug image's),
    ``ref_stamp_ns`` its reference line's (the markers'), ``frame_id`` its optical frame,
    ``image`` ``(array, encoding, stamp_ns)`` of its decoded input image (None: none)."""

    name: str
    estimate: RSPoseEstimate
    points2d: np.ndarray
    points3d: np.ndarray
    camera: CameraModel
    stamp_ns: int
    ref_stamp_ns: int
    frame_id: str
    image: tuple | None = None


@dataclass(frozen=True)
class PosedFrame:
    """The pose a frame publishes: ``pose`` (its ``pose`` in the map frame, its twist in
    ``frame_id``: the camera's optical frame, the robot's ``base_frame`` or the rig's) at
    ``stamp_ns`` (ns, the reference line's time); ``twist_now``: ``twist`` and ``odom``
    carry its own twist (no tracking, a global-shutter solver or timing), else its fused
    twist comes in a later frame's :attr:`FrameOutcome.fused`; ``views``: the cameras drawn
    (:class:`CameraView`; the ``path`` takes the single camera's view's pose, else
    ``pose``)."""

    pose: PoseWithCovariance
    stamp_ns: int
    frame_id: str
    twist_now: bool
    views: tuple[CameraView, ...] = ()


@dataclass(frozen=True)
class FrameOutcome:
    """What one frame's outcome publishes (:func:`publish_frame`): its pose (``posed``, None:
    not posed), the twists of earlier frames it made final (``fused``, ``twist`` and
    ``odom``), the lines it logs (``log``: why it failed, with the count of such frames)."""

    posed: PosedFrame | None = None
    fused: Sequence[FusedOutput] = ()
    log: tuple[LogLine, ...] = ()


def frame_outcome(
    out: LocalizerOutput,
    base_frame: str | None,
    mount: Mounting | None = None,
    views: tuple[CameraView, ...] = (),
    log: tuple[LogLine, ...] = (),
) -> FrameOutcome:
    """What a rig frame ``out`` of a :class:`~rs_localizer.tracking.video.Localizer` publishes
    (:class:`FrameOutcome`), a camera's frame (its rig of one) or a rig's alike, in the node
    and in ``rs-localizer replay``: the fused twists it made final
    (:func:`.pipeline.fused_outputs`), its ``log`` lines and, posed, its pose at its time
    (``out.stamp_ns``, ns: the rig frame's reference-line time) with its own twist when that
    is final (:attr:`~rs_localizer.tracking.video.LocalizerOutput.twist_now`) and the
    cameras' ``views``. In ``base_frame`` (None: the frame id of its first camera's frame),
    moved there by the camera's ``mount`` (:func:`~rs_localizer.frames.camera_to_base`;
    None: as it is, the rig's pose)."""
    fused = fused_outputs(out.fused, base_frame, mount)
    if not out.success:
        return FrameOutcome(None, fused, log)
    est = out.estimate
    pose = est if mount is None else camera_to_base(est, mount)
    frame = base_frame or out.tags[out.cameras[0]]
    return FrameOutcome(PosedFrame(pose, out.stamp_ns, frame, out.twist_now, views), fused, log)


def rig_frame_views(
    out: LocalizerOutput,
    mounts: Mapping[str, Any],
    wanted: Callable[[str], bool] | None = None,
    images: Mapping[str, Iterable[tuple]] | None = None,
) -> tuple[CameraView, ...]:
    """The cameras of a posed rig frame ``out`` as their debug views draw them, in the node
    and in ``replay``'s debug outputs: each camera (``wanted``: camera name -> whether it is
    drawn; None: each) as the rig's pose and its mounting (``mounts``: camera name -> its
    mounting) put it (:func:`.visualization.rig_camera_views`), with its frame's image, the
    last of ``images`` (camera -> its kept ``(image, encoding, stamp_ns)``) of its stamp
    (None: none)."""
    from .visualization import rig_camera_views  # (its module only for the debug views)

    views = []
    for n, f, view, ref in rig_camera_views(out, dict(mounts), wanted):
        image = None
        for img in (images or {}).get(n, ()):
            if img[2] == f.stamp_ns:
                image = img
        views.append(CameraView(n, view, f.points2d, f.points3d, f.camera, f.stamp_ns, ref,
                                f.tag or n, image))  # fmt: skip
    return tuple(views)


def rig_frame_line(out: LocalizerOutput, rig: Localizer) -> LogLine | None:
    """The line a rig's rig frame logs (each reason at most once per 5 s): why it failed with
    the count of rig frames failed so far for that reason (the localizer ``rig``'s counts), or
    on a posed one the cameras outvoted by the others; None: nothing to say."""
    if out.error is not None:
        reason, detail = "error", f"the estimator raised {out.error}"
    elif out.estimate is not None and not out.success:
        reason = out.estimate.failure or "error"
        detail = f"{len(out.cameras)} cameras ({', '.join(out.cameras)})"
        if reason == "cameras_disagree" and out.outvoted:
            detail += f"; {', '.join(out.outvoted)} contradict each other"
    elif out.outvoted:
        names = ", ".join(out.outvoted)
        return LogLine(
            f"rig.outvoted.{names}",
            f"rig camera {names}: outvoted by the others (its points contradict their "
            "pose; its mounting, clock, line delay or matches are likely wrong) "
            f"[{rig.counts[f'{out.outvoted[0]}.outvoted']} rig frames so far]",
        )
    else:
        return None
    n = rig.counts[f"rig.failed.{reason}"]
    return LogLine(
        f"rig.failed.{reason}",
        f"rig frame failed ({reason}): {detail} [{n} rig frames failed so far with {reason}]",
    )


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


def outcome_messages(
    outcome: FrameOutcome, map_frame: str, wanted: Callable[[str], bool] = _everything
) -> list[tuple[str, Any]]:
    """``(topic, message)`` of everything a frame's outcome publishes, in order: posed,
    :func:`pose_messages` with its fused twists; else the fused twists
    (:func:`fused_messages`). ``wanted(topic)`` false skips building a message nobody
    receives (``pose`` is always built)."""
    p = outcome.posed
    if p is None:
        return fused_messages(outcome.fused, map_frame, wanted)
    return pose_messages(p.pose, p.stamp_ns, map_frame, p.frame_id, p.twist_now,
                         outcome.fused, wanted)  # fmt: skip


def pose_messages(
    out: PoseWithCovariance,
    stamp: int,
    map_frame: str,
    frame: str,
    twist_now: bool,
    fused: Iterable[FusedOutput] = (),
    wanted: Callable[[str], bool] = _everything,
) -> list[tuple[str, Any]]:
    """``(topic, message)`` of a published pose, of a camera's frame or a rig frame, in order:
    ``pose``, ``twist_single_frame``, then ``twist`` and ``odom`` (the ``fused`` twists of
    earlier frames now final, then its own twist with ``twist_now``, e.g. without tracking:
    each topic's stamps in order), ``pose_with_covariance`` and ``tf``. ``out``: a
    :class:`~rs_localizer.pose.PoseWithCovariance` (its ``pose`` in ``map_frame``, its twist
    in ``frame``), ``stamp``: ns."""
    msgs: list[tuple[str, Any]] = [("pose", cv.pose_stamped(out.pose, stamp, map_frame))]
    if wanted("twist_single_frame"):
        msgs.append(("twist_single_frame", cv.twist_stamped(out.pose, stamp, frame)))
    msgs += fused_messages(fused, map_frame, wanted)  # (earlier frames': their stamps first)
    if twist_now:
        if wanted("twist"):
            msgs.append(("twist", cv.twist_stamped(out.pose, stamp, frame)))
        if wanted("odom"):
            msgs.append(("odom", cv.odometry(out, stamp, map_frame, frame)))
    if wanted("pose_with_covariance"):
        msgs.append(
            ("pose_with_covariance", cv.pose_with_covariance_stamped(out, stamp, map_frame))
        )
    if wanted("tf"):
        msgs.append(("tf", cv.tf_message(out.pose, stamp, map_frame, frame)))
    return msgs


class OutputNode(Protocol):
    """What :func:`publish_frame` uses of the node (:class:`~.core.NodeCore`): the frame its
    poses are published in, whether a topic has a subscriber, its publishers, its
    visualizations (``viz`` the ``path``'s, None: none; ``camera_viz`` each camera's by name)
    and its throttled log."""

    map_frame: str
    viz: NodeVisualization | None
    camera_viz: Mapping[str, NodeVisualization]

    def wanted(self, topic: str) -> bool: ...

    def publish_messages(self, messages: list) -> None: ...

    def warn(self, key: str, text: str, count: int = 0) -> None: ...


def publish_frame(node: OutputNode, outcome: FrameOutcome) -> None:
    """Publish a frame's outcome on ``node``'s outputs, for one camera and a rig alike: its
    messages (:func:`outcome_messages` in the node's ``map_frame``, only those with a
    subscriber built), then, posed, its pose to the ``path`` and each camera's view to its
    ``debug_image`` and ``markers`` (``node.camera_viz``; drawn on their thread, only while
    subscribed), then its log lines (:meth:`.core.NodeCore.warn`)."""
    mf, posed = node.map_frame, outcome.posed
    messages = outcome_messages(outcome, mf, node.wanted)
    node.publish_messages(messages)
    if posed is not None and node.viz is not None:
        pose_msg = messages[0][1]  # (the path takes it when it is the one drawn)
        if not any(node.camera_viz.get(v.name) is node.viz for v in posed.views):
            node.viz.publish(posed.pose, None, None, None, posed.stamp_ns, posed.stamp_ns,
                             "", mf, pose_msg)  # fmt: skip
        for v in posed.views:
            viz = node.camera_viz[v.name]
            viz.hold_image(v.image)
            viz.publish(v.estimate, v.points2d, v.points3d, v.camera, v.stamp_ns,
                        v.ref_stamp_ns, v.frame_id, mf,
                        pose_msg if v.estimate is posed.pose else None)  # fmt: skip
    for line in outcome.log:
        node.warn(*line)
