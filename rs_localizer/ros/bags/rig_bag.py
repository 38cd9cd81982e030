"""What a rig bag's replay does that a camera's does not: the cameras' frames, read as the rig
node reads them (:func:`~rs_localizer.ros.bags.bag_frames.iter_rig_frames`), grouped into rig
frames and posed by the rig mode's :class:`~rs_localizer.tracking.video.Localizer`
(:class:`RigRun`, which :func:`~rs_localizer.ros.bags.replay.replay` runs for a rig bag and
reports as a camera's replay), each camera's accounting (:func:`camera_counts`), the cameras
that disagree with the others (:func:`disagreeing`), and the grouping alone
(:func:`rig_frame_grouping`, what ``play --lockstep`` waits after).

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

import os
from collections.abc import Iterable, Iterator, Mapping
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np

from .. import conversions as cv
from .bag_frames import (
    QuietLog,
    iter_rig_frames,
    read_rig_frames,
    rig_bag_config,
    rig_frontends,
    rig_landmarks,
)
from .bag_io import iter_messages, progress_bar, rig_namespace, typestore

if TYPE_CHECKING:
    from ...tracking.video import Localizer, LocalizerOutput

__all__ = [
    "ROW_COUNTS",
    "RigRun",
    "camera_counts",
    "disagreeing",
    "rig_frame_ends",
    "rig_frame_grouping",
]


class RigRun:
    """A rig bag through the rig mode, for :func:`~rs_localizer.ros.bags.replay.replay`: the
    configuration of the parameters (:func:`~rs_localizer.ros.bags.bag_frames.rig_bag_config`:
    the defaults, the bag's ``rig_params.yaml``, ``params_files``, ``params``), the rig
    (:class:`~rs_localizer.tracking.video.Localizer`) and each camera's input
    (:func:`~rs_localizer.ros.camera_input.rig_camera_inputs`), made before any frame is read.

    Each camera's clouds are read through its
    :class:`~rs_localizer.ros.camera_input.CameraInput`, as the rig node reads them: rows with
    a NaN or inf dropped, then at most ``max_points`` rows (highest scores first), counted per
    camera (``points_dropped``, ``capped_clouds``). A cloud that cannot be read
    (:func:`~rs_localizer.ros.bags.bag_frames.iter_rig_frames`) is counted received and
    ``skipped.bad_input`` as the node counts it, and one with a readable stamp goes to the rig
    as a frame skipped (:func:`~rs_localizer.ros.camera_input.to_rig`): each camera's counts
    are the rig node's on the same messages (taken as they come, none dropped from a full
    queue); each frame's stamp is then noted on the rig's clock as the node's camera notes it
    (:meth:`~rs_localizer.ros.camera_input.CameraInput.note_on_rig`: after a time reset, the
    camera_infos stamped after the camera's first frame of the new timeline forgotten). With a
    front end (``frontend`` other than ``none``, its map ``frontend_map``; a
    ``render-bag --rig`` bag holds its ``markers.yaml``) each camera's images
    (``<namespace>/<camera>/image_raw``) are read instead, through the camera's own front end
    as the rig node runs it (decoded and checked against the camera model of its stamp, a
    rejected one skipped for its reason, the front end's rows as a cloud's). A gyro on the rig
    (``imu.enabled``) is read from ``<namespace>/imu``, its samples up to
    :data:`GYRO_AHEAD_NS` after a frame's stamp given to the rig before the frame.

    Attributes:
        values: the parameter values; cfg: the :class:`~rs_localizer.ros.config.RigConfig`.
        cameras: the cameras' names (rig order); mounts: camera -> its
            :class:`~rs_localizer.frames.Mounting` (in ``base_frame``).
        off_deg: camera -> one entry per posed rig frame in which it disagreed with the others
            (:func:`disagreeing`).
        flushed: the fused poses still pending at the end of the video (after :meth:`outputs`).

    Raises:
        ~rs_localizer.ros.params.ConfigError: the parameters (e.g. a camera without mounting,
            no ``rig.cameras``, a front end whose map does not load), or a front end for a bag
            without camera images.
    """

    def __init__(
        self,
        bag: str | os.PathLike,
        params_files: Iterable[str | os.PathLike] = (),
        params: Mapping[str, Any] | None = None,
    ):
        from ...frontends.shared import SHARED_MAPS
        from ...tracking.video import Localizer
        from ..camera_input import CameraCounts, rig_camera_inputs

        self.bag = bag
        self.values, _, self.cfg = rig_bag_config(bag, params_files, params)
        cfg = self.cfg
        self.rig = Localizer(cfg.settings)
        self.cameras = tuple(c.name for c in cfg.cameras)
        self.mounts = {c.name: c.mount for c in cfg.cameras}
        self.own = {n: CameraCounts(n) for n in self.cameras}  # (the node's counts of each)
        self.off_deg: dict[str, list] = {}
        self.flushed: list = []
        ns = rig_namespace(bag, self.cameras)
        self.gyro = _read_rig_gyro(bag, ns) if cfg.settings.imu is not None else []
        try:
            self.frontends = rig_frontends(bag, self.values, cfg, owner=self)
            self.landmarks = rig_landmarks(self.values, cfg, owner=self)
        except BaseException:
            SHARED_MAPS.release(self)
            raise
        self.inputs = rig_camera_inputs(cfg, QuietLog(), self._count, landmarks=self.landmarks)
        for n, fe in (self.frontends or {}).items():  # (each camera's own, as the node runs them)
            self.rig.set_frontend(n, fe, str(self.values["frontend"]).strip())

    def _count(self, name: str, key: str, n: int = 1) -> None:
        self.own[name].add(key, n)

    def outputs(self, progress: TextIO | None = None) -> Iterator[LocalizerOutput]:
        """Every rig frame's :class:`~rs_localizer.tracking.video.LocalizerOutput`, solved or
        failed, in order as the cameras' frames (in log-time order) complete them, then those
        the end of the video closes; each camera frame tagged with its frame id, as the rig
        node tags it (:meth:`~rs_localizer.ros.camera_input.CameraInput.tag_of`). Afterwards
        :attr:`flushed` holds the fused poses still pending."""
        from ...frontends.shared import SHARED_MAPS
        from ..camera_input import to_rig

        rig, own, gyro = self.rig, self.own, self.gyro
        bar = progress_bar(progress, None, unit=" rig frames")
        try:
            for item in iter_rig_frames(self.bag, self.inputs, images=self.frontends is not None):
                n = item.camera_name
                own[n].add("received")  # (as the node: every message, taken at once)
                stamp = item.stamp_ns
                if stamp is None:  # (a stamp out of range: skipped by the node alone)
                    own[n].add("skipped.bad_input")
                    continue
                while gyro and gyro[-1][0] <= stamp + GYRO_AHEAD_NS:  # (its readout's first)
                    rig.add_imu(*gyro.pop())
                outs = to_rig(rig, item)
                # (its stamp on the rig's clock, as the rig node's camera notes it: its
                # camera_infos stamped after a time reset forgotten)
                self.inputs[n].note_on_rig(rig, stamp)
                _note_disagreeing(rig, outs, self.off_deg)
                bar.update(len(outs))
                yield from outs
            tail = rig.close()
            _note_disagreeing(rig, tail, self.off_deg)
            self.flushed = rig.flush()
            bar.update(len(tail))
            yield from tail
        finally:
            SHARED_MAPS.release(self)
            bar.close()

    def camera_counts(self) -> dict:
        """``rig``: the rig frames' counts (``rig_frames``, ``solved``, ``failed``,
        ``skipped``, ``pending``), then camera -> :func:`camera_counts`, as the rig node's
        diagnostics count them."""
        out = {"rig": self.rig.rig_counts()}
        for n in self.rig.cameras:
            out[n] = camera_counts(self.rig, n, self.own[n].counts(), self.landmarks is not None)
        return out


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
    ``unknown_landmark_ids``), then ``skipped.<reason>`` for each reason it was skipped for
    (the node's and the rig's, e.g. ``bad_input``: clouds not read)."""
    from ..diagnostics import rig_camera_section
    from ..frame_queue import FRAME_ACCOUNTING

    section = rig_camera_section(rig, n, own)
    keys = (*FRAME_ACCOUNTING, *ROW_COUNTS, *(("unknown_landmark_ids",) if keypoints else ()))
    out = {k: section[f"{n}.{k}"] for k in keys}
    skip = f"{n}.skipped."
    out.update({k[len(n) + 1 :]: v for k, v in section.items() if k.startswith(skip) and v})
    return out


def _note_disagreeing(rig, outs: list, off_deg: dict) -> None:
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
    others in N posed rig frames (``off_deg``: :attr:`RigRun.off_deg`), X the median of how far
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


def _read_rig_gyro(bag: str | os.PathLike, ns: str) -> list:
    """The ``<ns>/imu`` samples of a rig bag as ``(stamp_ns, (wx, wy, wz))``, newest first
    (popped oldest first); samples without an angular velocity or a readable stamp left out."""
    ts = typestore()
    out = []
    for _, msgtype, _, raw in iter_messages(bag, {f"{ns}/imu"}):
        try:
            out.append(cv.gyro_sample(ts.deserialize_cdr(raw, msgtype)))
        except cv.ImuError:
            continue
    out.sort(key=lambda x: x[0])
    return out[::-1]


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
