"""A replay's outputs (:func:`~rs_localizer.ros.bags.replay.replay`), of a camera's bag or a
rig bag alike: the rows of its frames with their errors against the bag's ground truth
(:class:`ReplayRows`, :func:`frame_row`), their CSV (:data:`CSV_COLUMNS`, :func:`write_csv`),
the output bag (:func:`open_out_bag`, :func:`write_messages`: the node's messages, built by
:mod:`rs_localizer.ros.outputs`) and its debug topics (:class:`DebugWriter`: the node's
``path``, ``debug_image`` and ``markers``, drawn on the bag's images, :class:`BagImages`).
"""

from __future__ import annotations

import csv
import math
import os
import shutil
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...accuracy import GroundTruth, frame_errors, frame_fit_summary, summarize_errors
from .. import conversions as cv
from .bag_io import OUT_TYPES, iter_messages, storage_plugin, typestore

if TYPE_CHECKING:
    from ...estimation.result import RSPoseEstimate
    from ...pose import PoseWithCovariance
    from ..outputs import PosedFrame
    from ..pipeline import FusedOutput

__all__ = [
    "CSV_COLUMNS",
    "BagImages",
    "DebugWriter",
    "ReplayRows",
    "frame_row",
    "open_out_bag",
    "to_cdr",
    "view_prefix",
    "write_csv",
    "write_messages",
]


def to_cdr(msg: Any, msgtype: str, ts: Any) -> bytes:
    """rclpy message -> CDR bytes with zeroed padding (rclpy leaves the alignment padding
    uninitialized, which makes bags non-reproducible): serialize, then let rosbags re-encode."""
    from rclpy.serialization import serialize_message

    return bytes(ts.serialize_cdr(ts.deserialize_cdr(serialize_message(msg), msgtype), msgtype))


def frame_row(stamp_ns: int | None, out_stamp_ns: int | None, success: bool, failure: str,
         solver: str, est: RSPoseEstimate | None, num_points: int = 0,
         time_ms: float | None = None) -> dict:  # fmt: skip
    """The row of a frame, a camera's or a rig frame (:meth:`ReplayRows.add` numbers it and
    adds its pose and twists): its stamps (ns; None: a camera's frame dropped before they were
    made), ``success``, ``failure`` ("" when solved), ``solver``; with an estimate (solved or
    failed): a camera's ``time_ms`` (the estimator's), ``num_points`` (a rig frame's: all its
    cameras'), the estimate's ``num_inliers`` and ``rmse_px``."""
    row = {"stamp_ns": stamp_ns, "out_stamp_ns": out_stamp_ns, "success": success,
           "failure": failure, "solver": solver}  # fmt: skip
    if est is not None:
        row.update(time_ms=time_ms, num_points=num_points, num_inliers=est.num_inliers,
                   rmse_px=est.rmse_px)  # fmt: skip
    return {k: v for k, v in row.items() if v is not None or k not in ("out_stamp_ns", "time_ms")}


def open_out_bag(out_bag: Path, storage: str, overwrite: bool, ts: Any) -> tuple[Any, dict]:
    """The output bag of a replay (of a camera or a rig): its open writer and its connections
    by output name (:data:`OUT_TYPES`, as ``/rs_localizer/<name>``).

    Raises:
        FileExistsError: ``out_bag`` exists and not ``overwrite``.
    """
    from rosbags.rosbag2 import Writer

    if out_bag.exists():
        if not overwrite:
            raise FileExistsError(f"{out_bag} exists (use --overwrite)")
        shutil.rmtree(out_bag)
    writer = Writer(out_bag, version=9, storage_plugin=storage_plugin(storage))
    writer.open()
    conns = {}
    for name, mt in OUT_TYPES.items():
        conns[name] = writer.add_connection(f"/rs_localizer/{name}", mt, typestore=ts)
    return writer, conns


def write_messages(
    writer: Any, conns: dict, ts: Any, t_log: int, messages: Iterable[tuple[str, Any]]
) -> None:
    """Write ``(topic, message)`` pairs (:mod:`rs_localizer.ros.outputs`) into an output bag of
    :func:`open_out_bag` at log time ``t_log`` (ns); topics it does not hold (``tf``) are left
    out by the caller's ``wanted``; ``writer`` None: nothing."""
    if writer is None:
        return
    for topic, m in messages:
        writer.write(conns[topic], t_log, to_cdr(m, OUT_TYPES[topic], ts))


def _xyz(prefix: str, v) -> dict:
    return {f"{prefix}{a}": float(v[k]) for k, a in enumerate("xyz")}


class ReplayRows:
    """The rows of a replay's CSV and summary, one per frame (a camera's frame, or a rig
    frame): the pose when solved, the published twist (the frame's own, or the fused one when
    it comes) and the errors against ground truth (``gt``). Columns: :data:`CSV_COLUMNS`."""

    def __init__(self, gt: GroundTruth):
        self.gt = gt
        self.rows: list[dict] = []
        self.waiting: dict[int, tuple] = {}  # out stamp -> (row, orientation, position)
        self.own: list[dict] = []  # the errors of each posed frame's own twist

    def add(
        self, row: dict, out: PoseWithCovariance | None, stamp: int | None, twist_now: bool
    ) -> None:
        """A frame's ``row`` (:func:`frame_row`; numbered here, ``frame``) and, when posed, its
        published pose ``out`` at ``stamp`` (ns; ``twist_now``: its own twist is the one
        published, else the fused one comes with :meth:`fused`)."""
        row = {"frame": len(self.rows), **row}
        self.rows.append(row)
        if out is None:
            return
        q = cv.quaternion_from_matrix(out.pose.orientation)
        row.update({f"q{a}": q[k] for k, a in enumerate("xyzw")})
        row.update(_xyz("p", out.pose.position))
        row.update(_xyz("single_w", out.pose.angular_velocity))
        row.update(_xyz("single_v", out.pose.linear_velocity))
        self.own.append(frame_errors(out.pose.orientation, out.pose.position,
                                     out.pose.angular_velocity, out.pose.linear_velocity,
                                     self.gt, stamp))  # fmt: skip
        self.waiting[stamp] = (row, out.pose.orientation, out.pose.position)
        if twist_now:
            self._twist(stamp, out.pose.angular_velocity, out.pose.linear_velocity)

    def fused(self, fused: Iterable[FusedOutput]) -> None:
        """The fused twists now final (of frames added before)."""
        for f in fused:
            self._twist(f.stamp_ns, f.source.pose.angular_velocity, f.source.pose.linear_velocity)

    def _twist(self, stamp: int, w, v) -> None:
        item = self.waiting.pop(stamp, None)
        if item is None:
            return
        row, R, p = item
        row.update(_xyz("w", w))
        row.update(_xyz("v", v))
        self._errors(row, R, p, w, v, stamp)

    def _errors(self, row, R, p, w, v, stamp) -> None:
        err = frame_errors(R, p, w, v, self.gt, stamp)
        if err:
            row.update({f"err_{k}": val for k, val in err.items()})

    def own_twist(self) -> dict:
        """The errors of the posed frames' own twists against ground truth (``frames``,
        ``angvel``, ``linvel`` of :func:`~rs_localizer.accuracy.summarize_errors`)."""
        s = summarize_errors(self.own)
        return {k: v for k, v in s.items() if k in ("frames", "angvel", "linvel")}

    def pose_pairs(self) -> tuple[list, list]:
        """The solved frames' poses ``(R, p)`` and their ground truth's, for the rigid fit of
        the frames."""
        est, gt = [], []
        for r in self.rows:
            s = self.gt.nearest(r.get("out_stamp_ns", r["stamp_ns"])) if "qw" in r else None
            if s is not None:
                q = [r[f"q{a}"] for a in "xyzw"]
                est.append((cv.matrix_from_quaternion(q), np.array([r[f"p{a}"] for a in "xyz"])))
                gt.append((self.gt.orientation[s], np.asarray(self.gt.position[s])))
        return est, gt

    def finish(self) -> list[dict]:
        """The rows; solved frames whose twist never came get their pose errors alone."""
        for stamp, (row, R, p) in self.waiting.items():
            self._errors(row, R, p, None, None, stamp)
        self.waiting.clear()
        return self.rows

    def summary(self) -> tuple[list[dict], dict[str, int], dict]:
        """``(rows, failures, summary)`` at the end of the video (:meth:`finish`):
        ``failures`` reason -> frames, ``summary`` the errors of the published pose and twist
        against ground truth (:func:`~rs_localizer.accuracy.summarize_errors`) and, with
        errors, ``frame_fit`` (the errors after a rigid fit of the frames,
        :func:`~rs_localizer.accuracy.frame_fit_summary`)."""
        rows = self.finish()
        failures: dict[str, int] = {}
        for r in rows:
            if not r["success"]:
                failures[r["failure"]] = failures.get(r["failure"], 0) + 1
        summary = summarize_errors(
            [{k[4:]: v for k, v in r.items() if k.startswith("err_")} for r in rows]
        )
        fit = frame_fit_summary(*self.pose_pairs())
        if fit is not None and summary.get("frames"):
            summary["frame_fit"] = fit
        return rows, failures, summary


class DebugWriter:
    """Writes the visualization topics of posed frames into the replay's output bag, drawn by
    the node's :class:`~rs_localizer.ros.visualization.VisualizationBuilder`:
    ``/rs_localizer/path`` and, for each camera prefix of ``cameras`` (a camera's ``""``; a
    rig's ``"<camera>/"``), ``/rs_localizer/<prefix>debug_image`` and ``<prefix>markers``.
    ``images``: the bag's images to draw on (:class:`BagImages`, by camera prefix; None:
    only those a frame brings)."""

    def __init__(
        self,
        writer: Any,
        conns: dict,
        ts: Any,
        path_length: int,
        map_frame: str,
        cameras: Iterable[str] = ("",),
        images: BagImages | None = None,
    ):
        from ..visualization import VIZ_TOPICS, VisualizationBuilder

        self.writer, self.conns, self.ts, self.map_frame = writer, conns, ts, map_frame
        self.types, self.images = VIZ_TOPICS, images
        names = [p + n for p in cameras for n in ("debug_image", "markers")] + ["path"]
        for name in names:
            conns[name] = writer.add_connection(
                f"/rs_localizer/{name}", VIZ_TOPICS[name.rsplit("/", 1)[-1]], typestore=ts
            )
        self.builder = VisualizationBuilder(path_length)

    def _write(self, name: str, t_log: int, msg: Any) -> None:
        kind = name.rsplit("/", 1)[-1]
        self.writer.write(self.conns[name], t_log, to_cdr(msg, self.types[kind], self.ts))

    def frame(self, t_log: int, estimate: RSPoseEstimate, posed: PosedFrame) -> None:
        """A posed frame's (a camera's or a rig's) ``path`` (``estimate``'s pose at the posed
        frame's stamp), then each of its cameras' views' ``debug_image`` (drawn on the view's
        image, else on the bag's of its stamp, else on a blank canvas) and ``markers``,
        logged at ``t_log`` (ns)."""
        self.builder.add_pose(estimate, posed.stamp_ns, self.map_frame)
        self._write("path", t_log, self.builder.path(posed.stamp_ns, self.map_frame))
        for v in posed.views:
            prefix = view_prefix(v.name)
            image = None if v.image is None else v.image[:2]
            if image is None and self.images is not None:
                image = self.images.take(prefix, v.stamp_ns)
            img, enc = (None, None) if image is None else image
            if img is not None and img.shape[:2] != (v.camera.height, v.camera.width):
                img, enc = None, None  # (not of the camera's size: a blank canvas)
            self._write(prefix + "debug_image", t_log, self.builder.debug_image(
                v.estimate, v.points2d, v.points3d, v.camera, v.stamp_ns, v.frame_id, img,
                enc))  # fmt: skip
            self._write(prefix + "markers", t_log, self.builder.markers(
                v.estimate, v.points3d, v.camera, v.ref_stamp_ns, self.map_frame))  # fmt: skip


def view_prefix(name: str) -> str:
    """The prefix of a camera's debug topics: ``""`` for the single camera (named ``""``), a
    rig camera's ``"<name>/"``."""
    return f"{name}/" if name else ""


class BagImages:
    """The images of a bag that the posed frames' debug images are drawn on (``topics``:
    topic -> camera prefix), read from the bag as they are asked for, in frame order
    (:meth:`take`). Each image read is kept undecoded by ``(prefix, header stamp)``, at most
    :attr:`MAX_HELD` per camera (the oldest dropped), and decoded when asked for, once."""

    MAX_HELD = 16

    def __init__(self, bag: str | os.PathLike, topics: Mapping[str, str]):
        self.topics = dict(topics)
        self.held: dict[str, dict[int, Any]] = {k: {} for k in self.topics.values()}
        self.newest: dict[str, int] = {}  # prefix -> the newest stamp of its images read
        self.ts = typestore()
        self._messages = iter_messages(bag, set(self.topics)) if self.topics else iter(())

    def take(self, key: str, stamp_ns: int) -> tuple | None:
        """``(image, encoding)`` of camera ``key``'s image stamped ``stamp_ns`` (None: the bag
        has none, or it cannot be decoded). The bag is read on until it is found, an image of
        that camera stamped later is read, or the bag ends."""
        from ..image_codec import ImageRejected, decode_image

        held = self.held.get(key)
        if held is None:
            return None
        while stamp_ns not in held and self.newest.get(key, stamp_ns - 1) < stamp_ns:
            if not self._read():
                break
        msg = held.pop(stamp_ns, None)
        if msg is None:
            return None
        try:
            return decode_image(msg)
        except ImageRejected:
            return None

    def close(self) -> None:
        """Close the bag (the images not read are not read)."""
        close = getattr(self._messages, "close", None)
        if close is not None:
            close()

    def _read(self) -> bool:
        item = next(self._messages, None)
        if item is None:
            return False
        topic, msgtype, _, raw = item
        key = self.topics[topic]
        msg = self.ts.deserialize_cdr(raw, msgtype)
        try:
            stamp = cv.checked_stamp_ns(msg.header.stamp)
        except ValueError:
            return True
        self.newest[key] = max(self.newest.get(key, stamp), stamp)
        held = self.held[key]
        held[stamp] = msg
        while len(held) > self.MAX_HELD:
            held.pop(min(held))
        return True


CSV_COLUMNS = [
    "frame",
    "stamp_ns",
    "out_stamp_ns",
    "solver",
    "success",
    "failure",
    "num_points",
    "num_inliers",
    "rmse_px",
    "time_ms",
    "qx",
    "qy",
    "qz",
    "qw",
    "px",
    "py",
    "pz",
    "wx",
    "wy",
    "wz",
    "vx",
    "vy",
    "vz",
    "err_rot_deg",
    "err_pos_m",
    "err_angvel",
    "err_linvel",
    "single_wx",
    "single_wy",
    "single_wz",
    "single_vx",
    "single_vy",
    "single_vz",
]


def write_csv(path: str | os.PathLike, rows: list[dict]) -> None:
    """Write a replay's ``rows`` (:class:`ReplayRows`) as CSV, :data:`CSV_COLUMNS`."""
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=CSV_COLUMNS, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow(
                {
                    k: (f"{v:.9g}" if isinstance(v, float) and math.isfinite(v) else v)
                    for k, v in r.items()
                }
            )
