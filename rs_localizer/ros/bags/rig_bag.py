"""What only a rig bag's replay and play do: each camera's accounting
(:func:`camera_counts`), the cameras that disagree with the others
(:func:`note_disagreeing`, :func:`disagreeing`), how far ahead of a frame the rig's gyro is
fed (:data:`GYRO_AHEAD_NS`), and the grouping of the cameras' frames into rig frames alone
(:func:`rig_frame_grouping`, what ``play --lockstep`` waits after). The rig's run itself is
:func:`~rs_localizer.ros.bags.replay.replay`'s, a camera's with the rig mode's frame step.

A rig bag (written by :func:`~rs_localizer.ros.bags.bag_io.write_rig_bag`) holds, per camera
``<c>``, ``<ns>/<c>/camera_info`` and ``<ns>/<c>/correspondences`` (u, v, x, y, z, id) and,
from ``render-bag --rig``, ``<ns>/<c>/image_raw`` (rgb8), each stamped with the camera's own
capture time of ``stamp_row``, the rig's ground truth ``/ground_truth/pose`` (``base_frame``
in ``map``) and ``/ground_truth/twist`` (rig frame) at every camera frame's reference-row
time, a ``sequence.json`` whose ``rig`` entry lists the cameras (name, mounting, RS timing),
and ``rig_params.yaml``: the node's parameter file for the rig (``--params-file`` of the node
and of ``replay``). With a gyro on the rig (``make-bag --rig N --imu-rate HZ``) it also holds
``<ns>/imu`` (``sensor_msgs/Imu``, the rig's ``imu`` topic), the ``rig`` entry's ``imu`` and
``imu.enabled``, ``imu.rotation`` (IMU -> base_frame) in ``rig_params.yaml``.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from .bag_frames import read_rig_frames

if TYPE_CHECKING:
    import os

    from ...tracking.video import Localizer

__all__ = [
    "GYRO_AHEAD_NS",
    "ROW_COUNTS",
    "camera_counts",
    "disagreeing",
    "note_disagreeing",
    "rig_frame_ends",
    "rig_frame_grouping",
]


#: the counts of a camera's rows a replay reports beside its frames' (the rig node's
#: diagnostics' ``<camera>.points_dropped`` and ``<camera>.capped_clouds``; with
#: ``landmarks_file`` also ``<camera>.unknown_landmark_ids``)
ROW_COUNTS = ("points_dropped", "capped_clouds")


def camera_counts(rig: Localizer, n: str, own: Mapping[str, int], keypoints: bool = False) -> dict:
    """Camera ``n``'s counts in a replay, those of the rig node's diagnostics
    (:func:`~rs_localizer.ros.diagnostics.rig_camera_section` of the rig's counts and the
    node's ``own``, its :class:`~rs_localizer.ros.camera_input.CameraCounts`' counts) without
    the ``<n>.`` prefix: its frames' (received, solved, failed, skipped, pending), its rows'
    (:data:`ROW_COUNTS`; with ``keypoints``, a replay with ``landmarks_file``, also
    ``unknown_landmark_ids``), then ``failed.<reason>`` for each reason the node failed its
    frames for before the rig (e.g. ``bad_stamp``: a stamp out of range) and
    ``skipped.<reason>`` for each reason it was skipped for (the node's and the rig's, e.g.
    ``bad_input``: clouds not read)."""
    from ..diagnostics import rig_camera_section
    from ..frame_queue import FRAME_ACCOUNTING

    section = rig_camera_section(rig, n, own)
    keys = (*FRAME_ACCOUNTING, *ROW_COUNTS, *(("unknown_landmark_ids",) if keypoints else ()))
    out = {k: section[f"{n}.{k}"] for k in keys}
    why = (f"{n}.failed.", f"{n}.skipped.")
    out.update({k[len(n) + 1 :]: v for k, v in section.items() if k.startswith(why) and v})
    return out


def note_disagreeing(rig: Localizer, outs: list, off_deg: dict) -> None:
    """For each posed rig frame of ``outs``, each of its cameras that disagrees with the others
    (:attr:`~rs_localizer.tracking.video.LocalizerOutput.outvoted` or ``disagreeing``): how far
    off it is (:meth:`~rs_localizer.tracking.video.Localizer.camera_off_deg` on the camera's frame
    of the rig frame, NaN when it cannot be posed alone) appended to ``off_deg[camera]``."""
    for o in outs:
        if not o.success:
            continue
        for n in o.cameras:
            if n not in o.outvoted and n not in o.disagreeing:
                continue
            frame = o.frames.get(n)
            deg = None if frame is None else rig.camera_off_deg(o, frame)
            off_deg.setdefault(n, []).append(float("nan") if deg is None else deg)


def disagreeing(off_deg: Mapping[str, list]) -> dict:
    """camera -> ``{"rig_frames": N, "median_deg": X}`` for each camera that disagreed with the
    others in N posed rig frames (``off_deg``: :func:`note_disagreeing`'s), X the median of how far
    off it was, deg (NaN: never posed alone)."""
    return {
        n: {
            "rig_frames": len(d),
            "median_deg": float(np.nanmedian(d)) if np.isfinite(d).any() else float("nan"),
        }
        for n, d in off_deg.items()
    }


#: ns: a rig bag's replay feeds the gyro samples up to this after a frame's stamp before the
#: frame (a camera's frame arrives after its readout; the bag logs it at its stamp)
GYRO_AHEAD_NS = 50_000_000


def rig_frame_ends(
    bag: str | os.PathLike,
    params_files: Iterable[str | os.PathLike] = (),
    params: Mapping[str, Any] | None = None,
) -> dict[tuple[str, int], int]:
    """The first item of :func:`rig_frame_grouping`: ``{(camera name, header stamp ns):
    number of rig frames its arrival completes}``."""
    return rig_frame_grouping(bag, params_files, params)[0]


def rig_frame_grouping(
    bag: str | os.PathLike,
    params_files: Iterable[str | os.PathLike] = (),
    params: Mapping[str, Any] | None = None,
) -> tuple[dict[tuple[str, int], int], int]:
    """Which camera frames of a rig bag complete a rig frame when played in log-time order
    into the rig mode (what ``play --lockstep`` waits after).

    The frames, read as the rig node reads them
    (:func:`~rs_localizer.ros.bags.bag_frames.read_rig_frames`: each cloud with the camera
    model of its stamp), go to the rig's own grouping
    (:class:`~rs_localizer.tracking.rig.RigGrouping`, run by the rig mode's
    :class:`~rs_localizer.tracking.video.Localizer` without solving), as the node hands them
    on (:func:`~rs_localizer.ros.camera_input.to_rig`): by reference-line time, one frame
    per camera within ``rig.window`` of the rig frame's earliest; a rig frame is complete once
    every camera has joined it, sent a frame past it, or stopped (no frame for ``rig.stop_after``
    s or a few of its own frame intervals); a forward time jump completes the open ones.
    Frames without a camera model (received before their camera's first camera_info), out of
    order or late join no rig frame. A cloud that cannot be read but has a readable stamp
    joins none either but counts as the camera's frame at that time
    (:meth:`~rs_localizer.tracking.video.Localizer.drop`); one without a readable stamp does
    nothing.
    Rig frames still open at the end (completed only when the node closes) are in no entry.

    Returns:
        ``({(camera name, header stamp ns): number of rig frames its arrival completes}``
        (frames completing none are left out), the number of rig frames formed in all (those
        still open at the end included: the rig node's ``rig_frames`` once it closes them)).
    Raises:
        ValueError: no ``rig.cameras`` or parameters the rig node refuses (as
        :func:`~rs_localizer.ros.bags.bag_frames.read_rig_frames`).
    """
    from ...tracking.video import GroupingOnly
    from ..camera_input import to_rig

    read = read_rig_frames(bag, params_files, params)
    rig = GroupingOnly(read.settings)
    out: dict[tuple[str, int], int] = {}
    for f in read.items:
        done = len(to_rig(rig, f))
        if done:
            out[(f.camera_name, f.stamp_ns)] = out.get((f.camera_name, f.stamp_ns), 0) + done
    return out, int(rig.counts["rig_frames"])
