"""Rig bags (several cameras, each its own timing) with ``rosbags``: written from a simulated
rig video, replayed offline through the rig mode's :class:`~rs_localizer.tracking.video.
Localizer` with the node's parameters.

A rig bag holds, per camera ``<c>``, ``<ns>/<c>/camera_info`` and ``<ns>/<c>/correspondences``
(u, v, x, y, z, id) and, from ``render-bag --rig``, ``<ns>/<c>/image_raw`` (rgb8), each
stamped with the camera's own capture time of ``stamp_row``, the
rig's ground truth ``/ground_truth/pose`` (``base_frame`` in ``map``) and
``/ground_truth/twist`` (rig frame) at every camera frame's reference-row time, a
``sequence.json`` whose ``rig`` entry lists the cameras (name, mounting, RS timing), and
``rig_params.yaml``: the node's parameter file for the rig (``--params-file`` of the node and
of ``replay``). With a gyro on the rig (``make-bag --rig N --imu-rate HZ``) it also holds
``<ns>/imu`` (``sensor_msgs/Imu``, the rig's ``imu`` topic), the ``rig`` entry's ``imu`` and
``imu.enabled``, ``imu.rotation`` (IMU -> base_frame) in ``rig_params.yaml``.
"""

from __future__ import annotations

import json
import os
import shutil
from collections import Counter
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np

from ...accuracy import frame_errors, summarize_errors
from .. import conversions as cv
from ..config import RigConfig, rig_config
from ..param_files import read_params_file
from ..params import RIG_CAMERA_PARAMETERS, RIG_PARAMETERS, ConfigError, default_values
from .bag_io import (
    CAMERA_INFO,
    GT_POSE,
    GT_TWIST,
    IMAGE,
    IMU,
    OUT_TYPES,
    PC2,
    POSE,
    TWIST,
    RosbagsMessages,
    bag_topics,
    iter_messages,
    load_ground_truth,
    progress_bar,
    read_bag_info,
    storage_plugin,
    typestore,
)

if TYPE_CHECKING:
    from ...camera import CameraModel, Stamp
    from ...tracking.localizer import CameraFrame
    from ...tracking.video import LocalizerSettings
    from ..camera_input import CameraInput, DroppedFrame, ImageFrame

__all__ = [
    "RigFrames",
    "RigReplay",
    "RigTopics",
    "is_rig_bag",
    "iter_rig_frames",
    "read_rig_frames",
    "replay_rig",
    "rig_bag_config",
    "rig_namespace",
    "rig_parameter_values",
    "write_rig_bag",
    "write_rig_outputs",
]


def _mounting(cam) -> list[float]:
    q = cv.quaternion_from_matrix(cam.R_rig_cam)
    return [float(x) for x in (*cam.p_rig_cam, *q)]


def write_rig_bag(
    path: str | os.PathLike,
    frames: Iterable[Any],
    cameras: list,
    trajectory: Any,
    *,
    t0_ns: int = 1_700_000_000_000_000_000,
    namespace: str = "/rig",
    base_frame: str = "base_link",
    map_frame: str = "map",
    stamp_row: float = 0.0,
    storage: str = "mcap",
    overwrite: bool = False,
    settings: dict | None = None,
    generator: str = "rs-localizer make-bag --rig",
    compress: bool = False,
    extra: dict | None = None,
    imu: tuple | None = None,
) -> Path:
    """Write a simulated rig video as a rig bag (module docstring); returns its path.

    Args:
        frames: camera frames in stamp order, each with ``name``, ``stamp_ns``, ``t_ref_ns``,
            ``uv`` (N, 2) px, ``xyz`` (N, 3) m, optionally ``ids`` (N,) (default 0..N-1) and
            ``image`` ((H, W, 3) uint8 RGB: then ``<ns>/<c>/image_raw`` is written too):
            :func:`rs_localizer.sim.rig_video.generate_rig_video`,
            :func:`rs_localizer.sim.render.rig.render_rig_video`; an iterator is consumed
            as it is written.
        cameras: the rig's cameras (``name``, ``camera``, ``R_rig_cam``, ``p_rig_cam``,
            ``offset``, ``fps``). trajectory: the rig's motion (``pose(t)``,
            ``velocity_body(t)``; rig time 0 at ``t0_ns``).
        generator, settings, extra: recorded in ``sequence.json`` (``extra``: further
            top-level entries, e.g. the front end). compress: zstd (mcap chunks, sqlite3
            messages).
        imu: optional ``(t_ns (M,), omega (M, 3) rad/s, R_rig_imu (3, 3))``, a gyro on the
            rig (:func:`rs_localizer.sim.rig_video.rig_gyro`) written on ``<namespace>/imu``
            at its stamps.

    Log times: camera_info at stamp + 1 ms, the image, the cloud and the ground truth at
    stamp + 2 ms.

    Raises:
        FileExistsError: ``path`` exists and not ``overwrite``.
    """
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, Writer

    path = Path(path)
    if path.exists():
        if not overwrite:
            raise FileExistsError(f"{path} exists (use --overwrite)")
        shutil.rmtree(path)
    ns = namespace.rstrip("/")
    M = RosbagsMessages()
    topics = {}
    for c in cameras:
        topics[f"{c.name}/camera_info"] = f"{ns}/{c.name}/camera_info"
        topics[f"{c.name}/correspondences"] = f"{ns}/{c.name}/correspondences"
    by = {c.name: c for c in cameras}
    writer = Writer(path, version=9, storage_plugin=storage_plugin(storage))
    if compress:
        writer.set_compression(
            CompressionMode.STORAGE if storage == "mcap" else CompressionMode.MESSAGE,
            CompressionFormat.ZSTD,
        )
    n_frames = 0
    with writer as w:
        conns = {}
        for c in cameras:
            conns[f"{c.name}/camera_info"] = w.add_connection(
                topics[f"{c.name}/camera_info"], CAMERA_INFO, typestore=M.ts
            )
            conns[f"{c.name}/correspondences"] = w.add_connection(
                topics[f"{c.name}/correspondences"], PC2, typestore=M.ts
            )
        gt_pose = w.add_connection(GT_POSE, POSE, typestore=M.ts)
        gt_twist = w.add_connection(GT_TWIST, TWIST, typestore=M.ts)
        if imu is not None:  # (a gyro on the rig)
            c_imu = w.add_connection(f"{ns}/imu", IMU, typestore=M.ts)
            for t_ns, om in zip(imu[0], imu[1], strict=True):
                w.write(c_imu, int(t_ns), M.cdr(M.imu(om, np.zeros(3), int(t_ns), "imu_link"), IMU))
        written = set()
        for f in frames:
            n_frames += 1
            cam = by[f.name]
            frame_id = f"{f.name}_optical_frame"
            info = M.camera_info(cam.camera, f.stamp_ns, frame_id)
            w.write(
                conns[f"{f.name}/camera_info"], f.stamp_ns + 1_000_000, M.cdr(info, CAMERA_INFO)
            )
            t_log = f.stamp_ns + 2_000_000
            image = getattr(f, "image", None)
            if image is not None:
                key = f"{f.name}/image_raw"
                if key not in conns:
                    topics[key] = f"{ns}/{f.name}/image_raw"
                    conns[key] = w.add_connection(topics[key], IMAGE, typestore=M.ts)
                w.write(conns[key], t_log, M.cdr(M.image(image, f.stamp_ns, frame_id), IMAGE))
            ids = getattr(f, "ids", None)
            ids = np.arange(len(f.uv), dtype=np.uint32) if ids is None else ids.astype(np.uint32)
            cloud = M.cloud(f.uv, f.xyz, ids, f.stamp_ns, frame_id)
            w.write(conns[f"{f.name}/correspondences"], t_log, M.cdr(cloud, PC2))
            if f.t_ref_ns in written:
                continue
            written.add(f.t_ref_ns)
            t = (f.t_ref_ns - t0_ns) * 1e-9
            R, p = trajectory.pose(t)
            om, v = trajectory.velocity_body(t)
            w.write(gt_pose, t_log, M.cdr(M.pose(R, p, f.t_ref_ns, map_frame), POSE))
            w.write(gt_twist, t_log, M.cdr(M.twist(om, v, f.t_ref_ns, base_frame), TWIST))
    rig = {
        "namespace": ns,
        "base_frame": base_frame,
        "cameras": [
            {
                "name": c.name,
                "mounting": _mounting(c),
                "line_delay": c.camera.line_delay,
                "direction": c.camera.readout,
                "offset_s": c.offset,
                "fps": c.fps,
            }
            for c in cameras
        ],
    }
    if imu is not None:
        q = cv.quaternion_from_matrix(np.asarray(imu[2], dtype=float))
        rig["imu"] = {"topic": f"{ns}/imu", "rotation": [float(x) for x in q]}
    meta = {
        "generator": generator,
        "topics": {**topics, "gt_pose": GT_POSE, "gt_twist": GT_TWIST},
        "frames": n_frames,
        "map_frame": map_frame,
        "rs": {"stamp_row": float(stamp_row)},
        "rig": rig,
        "settings": settings or {},
        **(extra or {}),
    }
    (path / "sequence.json").write_text(json.dumps(meta, indent=2) + "\n")
    (path / "rig_params.yaml").write_text(_params_yaml(rig, stamp_row))
    return path


def _params_yaml(rig: dict, stamp_row: float) -> str:
    """The node's parameter file of a rig bag's ``rig`` entry."""
    import yaml

    cams = {
        c["name"]: {
            "mounting": [round(float(x), 9) + 0.0 for x in c["mounting"]],
            "line_delay": float(c["line_delay"]),
            "direction": c["direction"],
        }
        for c in rig["cameras"]
    }
    body = {
        "base_frame": rig["base_frame"],
        "rs": {"stamp_row": float(stamp_row)},
        "rig": {"cameras": [c["name"] for c in rig["cameras"]], **cams},
    }
    if "imu" in rig:
        body["imu"] = {"enabled": True, "rotation": [round(x, 12) for x in rig["imu"]["rotation"]]}
    tree = {"/**/rs_localizer": {"ros__parameters": body}}
    return yaml.safe_dump(tree, sort_keys=False, default_flow_style=None)


def rig_parameter_values(
    bag: str | os.PathLike | None,
    params_files: Iterable[str | os.PathLike] = (),
    params: Mapping[str, Any] | None = None,
) -> tuple[dict, dict]:
    """``(values, camera values)`` for :func:`~rs_localizer.ros.config.rig_config`: the
    defaults, then the bag's ``rig_params.yaml`` (``bag`` None: none), each parameter file,
    then ``params``."""
    values = default_values()
    values.update({k: (list(p.default) if isinstance(p.default, list) else p.default)
                   for k, p in RIG_PARAMETERS.items()})  # fmt: skip
    tree: dict[str, Any] = {}
    own = None if bag is None else Path(bag) / "rig_params.yaml"
    for f in ([own] if own is not None and own.is_file() else []) + list(params_files):
        tree.update(read_params_file(f))
    tree.update(params or {})
    values.update({k: v for k, v in tree.items() if k in values})
    cams = {}
    for n in values["rig.cameras"]:
        cams[n] = {k: tree.get(f"rig.{n}.{k}", p.default) for k, p in RIG_CAMERA_PARAMETERS.items()}
        cams[n]["mounting"] = tree.get(f"rig.{n}.mounting")
    return values, cams


#: the mounting every camera is read with where the mountings play no part (the frames of a
#: rig bag read for ``calibrate-rig`` and ``play --lockstep``): the identity
_ANY_MOUNTING = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]


def rig_bag_config(
    bag: str | os.PathLike | None,
    params_files: Iterable[str | os.PathLike] = (),
    params: Mapping[str, Any] | None = None,
    *,
    mountings: bool = True,
) -> tuple[dict, dict, RigConfig]:
    """``(values, camera values, config)``: the parameter values of
    :func:`rig_parameter_values` and the rig's configuration of them
    (:func:`~rs_localizer.ros.config.rig_config`), as the rig node takes them.

    ``mountings`` False: the cameras' mountings are not read (the config's are the identity;
    the camera values keep the parameters' own), for readers of the cameras' frames alone
    (:func:`read_rig_frames`): a rig without mountings yet is read as well.

    Raises:
        ~rs_localizer.ros.params.ConfigError: the parameters (e.g. a camera without mounting,
            no ``rig.cameras``).
    """
    values, cams = rig_parameter_values(bag, params_files, params)
    given = cams
    if not mountings:
        given = {str(n).strip(): {**c, "mounting": _ANY_MOUNTING, "mounting_covariance": None}
                 for n, c in cams.items()}  # fmt: skip
    return values, cams, rig_config(values, given)


@dataclass
class RigReplay:
    """What :func:`replay_rig` did, reported as a camera's replay
    (:class:`~rs_localizer.ros.bags.replay.ReplayResult`) is, a rig frame for a frame:

    - ``rows``: one per rig frame solved or failed (:class:`~rs_localizer.ros.bags.replay.
      ReplayRows`, the CSV's columns: the rig's pose in the map, its own twist and the twist
      published on ``twist``, the fused one with tracking, in the rig frame, errors against
      ground truth); ``failures``: reason -> rig frames; ``summary``: the errors of the
      published pose and twist (:func:`~rs_localizer.accuracy.summarize_errors`, with
      ``frame_fit``), as a camera's; ``own_twist``: the same of each rig frame's own twist
      (``frames``, ``angvel``, ``linvel``); ``solver``: the rig estimator's;
    - ``outputs`` (every rig frame's :class:`~rs_localizer.tracking.video.LocalizerOutput`),
      ``fused`` (the fused poses: the outputs', then ``flushed``, those still pending at the end);
      ``twist_now``: without tracking, a rig frame's own twist is the one published;
    - ``counts``: ``rig``, its rig frames' ``rig_frames``, ``solved``, ``failed``,
      ``skipped``, ``pending``; per camera its frames' ``received``, ``solved``, ``failed``,
      ``skipped``, ``pending`` (received = the other four summed), its rows'
      ``points_dropped`` (rows with a NaN or inf) and ``capped_clouds`` (clouds capped to
      ``max_points``), then ``skipped.<reason>`` for each reason its frames were skipped for
      (e.g. ``bad_input``: clouds not read; ``no_camera_info``), as the rig node's
      diagnostics count them ``<camera>.received``, ..., ``<camera>.skipped.<reason>``;
    - ``gyro_counts`` (with a gyro on the rig): the rig's gyro counts by a camera's names
      (``frames_with_gyro``, ``gyro_rejected``, ``gyro_disabled_inconsistent``,
      ``gyro_missing``, ``gyro_missing.<reason>``, ``gyro_bias_rejected``, ...), and
      ``gyro_bias``, ``gyro_bias_std`` ((3,) rad/s, IMU frame; None without a gyro);
    - ``off_deg``: camera -> one entry per posed rig frame in which it disagreed with the
      others (the cameras' consensus outvoted it, or the rig names it as disagreeing), how
      far off it is: deg between its rotation posed alone and where the rig's pose and its
      mounting put it (NaN where it could not be posed alone;
      :meth:`~rs_localizer.tracking.video.Localizer.camera_off_deg`); ``readout``: the
      check of the cameras' rolling-shutter timing on the video at its end
      (:meth:`~rs_localizer.tracking.video.Localizer.readout_values`); ``notes``:
      warnings for the user, as a camera's replay has them (the node's map-fit check over
      the rig frames, :class:`~rs_localizer.ros.pipeline.MapFitCheck`);
    - ``mounts``: camera -> its :class:`~rs_localizer.frames.Mounting` (in the rig's
      ``base_frame``), as configured. Each camera frame of ``outputs`` is tagged with
      ``(its header stamp ns, its frame id)``.
    """

    rows: list = field(default_factory=list)
    failures: dict = field(default_factory=dict)
    summary: dict = field(default_factory=dict)
    own_twist: dict = field(default_factory=dict)
    solver: str = ""
    outputs: list = field(default_factory=list)
    fused: list = field(default_factory=list)
    counts: dict = field(default_factory=dict)
    gyro_counts: dict = field(default_factory=dict)
    gyro_bias: np.ndarray | None = None
    gyro_bias_std: np.ndarray | None = None
    flushed: list = field(default_factory=list)
    twist_now: bool = False
    cameras: tuple = ()
    off_deg: dict = field(default_factory=dict)
    readout: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    mounts: dict = field(default_factory=dict)

    @property
    def solved(self) -> int:
        """Rig frames posed."""
        return sum(o.success for o in self.outputs)

    @property
    def disagreeing(self) -> dict:
        """camera -> ``{"rig_frames": N, "median_deg": X}`` for each camera that disagreed
        with the others in N posed rig frames, X the median of :attr:`off_deg` (NaN: never
        posed alone)."""
        return {
            n: {
                "rig_frames": len(d),
                "median_deg": float(np.nanmedian(d)) if np.isfinite(d).any() else float("nan"),
            }
            for n, d in self.off_deg.items()
        }


def replay_rig(
    bag: str | os.PathLike,
    params_files: Iterable[str | os.PathLike] = (),
    params: Mapping[str, Any] | None = None,
    progress: TextIO | None = None,
) -> RigReplay:
    """Every camera's frames of a rig bag, in log-time order, through the rig mode
    (:class:`~rs_localizer.tracking.video.Localizer` with the configuration of
    :func:`rig_parameter_values`), against the bag's ground truth. Each camera's clouds are
    read through its :class:`~rs_localizer.ros.camera_input.CameraInput`, as the rig node
    reads them (:func:`~rs_localizer.ros.camera_input.rig_camera_inputs`): rows with a NaN
    or inf dropped, then at most ``max_points`` rows (highest scores first), counted per
    camera (:attr:`RigReplay.counts`: ``points_dropped``, ``capped_clouds``). A cloud that
    cannot be read (:func:`iter_rig_frames`) is counted received and ``skipped.bad_input``
    as the node counts it, and one with a readable stamp goes to the rig as a frame skipped
    (:func:`~rs_localizer.ros.camera_input.to_rig`): each camera's counts are the rig
    node's on the same messages (taken as they come, none dropped from a full queue).

    With a front end (``frontend`` other than ``none``, its map ``frontend_map``; a
    ``render-bag --rig`` bag holds its ``markers.yaml``) each camera's images
    (``<namespace>/<camera>/image_raw``) are replayed instead, through the camera's own front
    end as the rig node runs it (:meth:`~rs_localizer.ros.camera_input.CameraInput.take`,
    :func:`~rs_localizer.ros.camera_input.to_rig`: decoded and checked against the camera
    model of its stamp, a rejected one skipped for its reason, the front end's rows as a
    cloud's).

    Raises:
        ~rs_localizer.ros.params.ConfigError: the parameters (e.g. a camera without mounting,
            no ``rig.cameras``, a front end whose map does not load), or a front end for a bag
            without camera images.
    """
    from dataclasses import replace

    from ...frontends.shared import SHARED_MAPS
    from ...tracking.video import Localizer
    from ..camera_input import CameraCounts, DroppedFrame, rig_camera_inputs, to_rig
    from ..pipeline import MapFitCheck

    values, _, cfg = rig_bag_config(bag, params_files, params)
    rig = Localizer(cfg.settings)
    res = RigReplay(cameras=tuple(c.name for c in cfg.cameras),
                    mounts={c.name: c.mount for c in cfg.cameras})  # fmt: skip
    own = {n: CameraCounts(n) for n in res.cameras}  # (the node's counts of each camera)

    def count(name: str, key: str, n: int = 1) -> None:
        own[name].add(key, n)

    ns = rig_namespace(bag, res.cameras)
    gyro = _read_rig_gyro(bag, ns) if cfg.settings.imu is not None else []
    frontends = rig_frontends(bag, values, cfg, owner=res)
    landmarks = rig_landmarks(values, cfg, owner=res)
    inputs = rig_camera_inputs(cfg, _QuietLog(), count, landmarks=landmarks)
    images = frontends is not None
    for n, fe in (frontends or {}).items():  # (each camera's own, as the rig node runs them)
        rig.set_frontend(n, fe, str(values["frontend"]).strip())
    bar = progress_bar(progress, None, unit=" rig frames")
    try:
        for item in iter_rig_frames(bag, inputs, images=images):
            n = item.camera_name
            own[n].add("received")  # (as the node: every message, taken at once)
            stamp = item.stamp_ns
            if stamp is None:  # (a stamp out of range: skipped by the node alone)
                own[n].add("skipped.bad_input")
                continue
            while gyro and gyro[-1][0] <= stamp + GYRO_AHEAD_NS:  # (its readout's first)
                rig.add_imu(*gyro.pop())
            if not isinstance(item, DroppedFrame):  # (tagged with its stamp and frame id)
                item = replace(item, tag=(stamp, item.tag))
            outs = to_rig(rig, item)
            _note_disagreeing(rig, outs, res.off_deg)
            res.outputs += outs
            res.fused += [f for o in outs for f in o.fused]
            bar.update(len(outs))
    finally:
        SHARED_MAPS.release(res)
    tail = rig.close()
    _note_disagreeing(rig, tail, res.off_deg)
    res.outputs += tail
    res.flushed = rig.flush()
    res.fused += [f for o in tail for f in o.fused] + res.flushed
    bar.update(len(tail))
    bar.close()
    res.counts = {"rig": rig.rig_counts()}
    for n in rig.cameras:
        res.counts[n] = _camera_counts(rig, n, own[n].counts(), landmarks is not None)
    res.readout = rig.readout_values()
    if cfg.settings.imu is not None:
        res.gyro_counts = rig.gyro_counts()
        bias = rig.gyro_bias_values()
        if bias is not None:
            res.gyro_bias, res.gyro_bias_std = bias
    res.twist_now = cfg.settings.tracking is None
    _rows_of(res, load_ground_truth(bag), res.twist_now)
    fit = MapFitCheck("rig frames")  # (the node's map-fit check, at the end of the video)
    for o in res.outputs:
        if o.estimate is not None:
            fit.update(o.num_points, o.estimate)
    if fit.doubtful:
        res.notes.append(fit.text())
    if cfg.unused_text:  # (a parameter file shared with single-camera nodes, as the node says)
        res.notes.append(cfg.unused_text)
    return res


def rig_frontends(
    bag: str | os.PathLike, values: Mapping[str, Any], cfg: RigConfig, owner: object
) -> dict | None:
    """Each camera's front end of the parameter ``values`` (``frontend``, ``frontend_map``,
    ``aruco.*``, ...; one map loaded, a front end object per camera, as the rig node makes
    them, on behalf of ``owner``: release with
    ``rs_localizer.frontends.shared.SHARED_MAPS.release(owner)``), camera name -> front end;
    None when ``frontend`` is ``none`` (the bag's correspondences are read instead).

    Raises:
        ~rs_localizer.ros.params.ConfigError: a front end for a bag without the cameras'
            images (``<namespace>/<camera>/image_raw``), or whose map does not load.
    """
    from ..config import build_config, load_maps, rig_used_values

    kind = str(values.get("frontend", "none")).strip() or "none"
    if kind == "none":
        return None
    names = tuple(c.name for c in cfg.cameras)
    wanted = RigTopics(rig_namespace(bag, names), names).of(("image",))
    if not set(wanted) & set(bag_topics(bag)):
        raise ConfigError(
            f"frontend {kind}: the rig bag has no camera images ({', '.join(wanted)}); "
            "without a front end (frontend: none) its correspondences are read"
        )
    single = build_config(rig_used_values(values, cfg.settings.single_camera))
    return {c.name: load_maps(single, owner=owner).frontend for c in cfg.cameras}


def rig_landmarks(values: Mapping[str, Any], cfg: RigConfig, owner: object) -> tuple | None:
    """The landmarks of the parameter ``landmarks_file`` that the cameras' keypoints name
    (``(ids (M,), points (M, 3) m)``), loaded as the rig node loads them (on behalf of
    ``owner``: release with ``rs_localizer.frontends.shared.SHARED_MAPS.release(owner)``);
    None without one.

    Raises:
        ~rs_localizer.ros.params.ConfigError: a landmark table that does not load.
    """
    from ..config import build_config, load_maps, rig_used_values

    if not str(values.get("landmarks_file", "")).strip():
        return None
    only = rig_used_values({**values, "frontend": "none"}, cfg.settings.single_camera)
    return load_maps(build_config(only), owner=owner).landmarks


def _rows_of(res: RigReplay, gt, twist_now: bool) -> None:
    """The rows, failures and summaries of ``res`` from its outputs and fused poses
    (``twist_now``: no tracking, a rig frame's own twist is the one published; so it is for a
    rig of one camera whose twist is final at once, a global shutter's,
    :attr:`~rs_localizer.tracking.video.LocalizerOutput.twist_now`)."""
    from ..pipeline import FusedOutput
    from .replay import ReplayRows

    rows = ReplayRows(gt)
    own = []
    fused_at: dict[int, list] = {}
    for f in res.fused:  # (each rig frame's fused twist, added after the rig frame)
        fused_at.setdefault(f.pose.stamp_ns, []).append(FusedOutput(f.pose.stamp_ns, f, ""))
    for i, o in enumerate(res.outputs):
        rows.add_rig(i, o, twist_now or o.twist_now)
        if o.success:
            q = o.estimate.pose
            own.append(frame_errors(q.orientation, q.position, q.angular_velocity,
                                    q.linear_velocity, gt, o.stamp_ns))  # fmt: skip
            rows.fused(fused_at.pop(o.stamp_ns, ()))
        if o.estimate is not None and not res.solver:
            res.solver = o.estimate.solver
    res.rows, res.failures, res.summary = rows.summary()
    s = summarize_errors(own)
    res.own_twist = {k: v for k, v in s.items() if k in ("frames", "angvel", "linvel")}


#: the counts of a camera's rows a replay reports beside its frames' (the rig node's
#: diagnostics' ``<camera>.points_dropped`` and ``<camera>.capped_clouds``; with
#: ``landmarks_file`` also ``<camera>.unknown_landmark_ids``)
ROW_COUNTS = ("points_dropped", "capped_clouds")


def _camera_counts(rig, n: str, own: Mapping[str, int], keypoints: bool = False) -> dict:
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


class _QuietLog:
    """The cameras' inputs' log in a replay: nothing logged (what they drop is counted)."""

    def info(self, text: str) -> None:
        pass

    def error(self, text: str) -> None:
        pass

    def warning(self, key: str, text: str) -> None:
        pass


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


def is_rig_bag(
    bag: str | os.PathLike,
    params_files: Iterable[str | os.PathLike] = (),
    params: Mapping[str, Any] | None = None,
) -> bool:
    """The bag is a rig's: its ``sequence.json`` has a ``rig`` entry (``make-bag --rig``,
    ``render-bag --rig``), or the parameter files and ``params`` name ``rig.cameras`` (a
    recording of a rig's cameras, replayed with the rig node's parameters)."""
    if "rig" in read_bag_info(bag):
        return True
    if not params_files and not (params or {}).get("rig.cameras"):
        return False
    values = rig_parameter_values(None, params_files, params)[0]
    return any(str(n).strip() for n in values["rig.cameras"] or ())


@dataclass
class RigFrames:
    """What :func:`read_rig_frames` read: ``items`` (every camera's clouds in log-time order,
    as :func:`iter_rig_frames` yields them: a
    :class:`~rs_localizer.tracking.localizer.CameraFrame`, or an
    :class:`~rs_localizer.ros.camera_input.DroppedFrame` for a cloud not read), ``values`` (the
    parameter values), ``cameras`` (the cameras' values, :func:`rig_parameter_values`) and
    ``counts``: camera -> :data:`READ_COUNTS`, the counts of its rows, ``points_dropped``
    (rows with a NaN or inf), ``capped_clouds`` (clouds capped to ``max_points``) and
    ``capped_points`` (the rows the cap left out), and of its clouds not read, ``bad_input``
    (an invalid stamp, no u, v, x, y, z fields: the rig node's
    ``<camera>.skipped.bad_input``); ``settings``: the rig's
    :class:`~rs_localizer.tracking.video.LocalizerSettings` of those parameters (every mounting the
    identity: not read)."""

    items: list
    values: dict
    cameras: dict
    counts: dict
    settings: LocalizerSettings | None = None

    @property
    def frames(self) -> list:
        """The frames read (every :class:`~rs_localizer.tracking.localizer.CameraFrame` of
        :attr:`items`), in log-time order."""
        from ..camera_input import DroppedFrame

        return [f for f in self.items if not isinstance(f, DroppedFrame)]


#: the counts of a camera's rows and clouds :func:`read_rig_frames` reports
READ_COUNTS = ("points_dropped", "capped_clouds", "capped_points", "bad_input")


def read_rig_frames(
    bag: str | os.PathLike,
    params_files: Iterable[str | os.PathLike] = (),
    params: Mapping[str, Any] | None = None,
) -> RigFrames:
    """Every camera's frames of a rig bag, without mountings (what ``calibrate-rig`` reads).

    The cameras are ``rig.cameras`` of :func:`rig_parameter_values` (the bag's
    ``rig_params.yaml``, the parameter files, ``params``), configured as the rig node
    configures them (:func:`rig_bag_config`, the mountings not read); each camera's frames
    are read through its :class:`~rs_localizer.ros.camera_input.CameraInput`
    (:func:`iter_rig_frames`), as the rig node and ``replay`` read them: each cloud with the
    model of the camera_info of its stamp (None before the camera's first camera_info), its
    rows with a NaN or inf dropped, then at most ``max_points`` rows, counted per camera
    (:attr:`RigFrames.counts`); a cloud that cannot be read (an invalid stamp, no u, v, x, y,
    z fields) is in no frame, counted ``bad_input`` for its camera (as the rig node's
    ``<camera>.skipped.bad_input``).

    Raises:
        ValueError: no ``rig.cameras``;
            :class:`~rs_localizer.ros.params.ConfigError` (a ValueError): parameters the rig
            node refuses (e.g. an unknown readout direction).
    """
    from ...frontends.shared import SHARED_MAPS
    from ..camera_input import CameraCounts, DroppedFrame, rig_camera_inputs

    values = rig_parameter_values(bag, params_files, params)[0]
    if not [str(n).strip() for n in values["rig.cameras"]]:
        raise ValueError(f"{bag}: no rig.cameras (not a rig bag, and no --params-file with them)")
    values, cams, cfg = rig_bag_config(bag, params_files, params, mountings=False)
    counts = {c.name: CameraCounts(c.name) for c in cfg.cameras}

    def count(name: str, key: str, n: int = 1) -> None:
        counts[name].add(key, n)

    owner = object()  # (the front ends' maps, released once read)
    try:
        frontends = rig_frontends(bag, values, cfg, owner)
        landmarks = rig_landmarks(values, cfg, owner)
        inputs = rig_camera_inputs(cfg, _QuietLog(), count, landmarks=landmarks)
        items = list(iter_rig_frames(bag, inputs, frontends))
    finally:
        SHARED_MAPS.release(owner)
    for f in items:
        if isinstance(f, DroppedFrame):
            count(f.camera_name, f.reason)
    rows = {}
    for n, cc in counts.items():  # (READ_COUNTS, then the images' skip reasons counted)
        c = cc.counts()
        rows[n] = {k: int(c.get(k, 0)) for k in READ_COUNTS}
        rows[n].update({k: int(v) for k, v in c.items() if k not in READ_COUNTS})
    return RigFrames(items, values, cams, rows, cfg.settings)


def rig_namespace(bag: str | os.PathLike, cameras: Iterable[str] = ()) -> str:
    """The namespace of a rig bag's camera topics, without a trailing slash:
    ``sequence.json``'s ``rig.namespace`` (``make-bag --rig``, ``render-bag --rig``); else,
    for a recording of the ``cameras``, the namespace ``<ns>`` under which the bag holds the
    most of their ``<ns>/<camera>/camera_info`` topics (``""`` for ``/front/camera_info``,
    ``/robot`` for ``/robot/front/camera_info``: the rig node's topics, which are relative to
    its namespace); else ``/rig``."""
    info = read_bag_info(bag).get("rig")
    if info is not None:
        return str(info.get("namespace", "/rig")).rstrip("/")
    found: Counter = Counter()
    for topic in bag_topics(bag) if cameras else ():
        for n in cameras:
            leaf = f"/{n}/camera_info"
            if topic.endswith(leaf):
                found[topic[: -len(leaf)]] += 1
    return found.most_common(1)[0][0] if found else "/rig"


@dataclass(frozen=True)
class RigTopics:
    """A rig bag's topics of the cameras ``names``: ``<namespace>/<camera>/camera_info``,
    ``.../correspondences``, ``.../keypoints`` and ``.../image_raw`` (:meth:`of`: topic ->
    ``(kind, camera)``, kind ``info``, ``cloud``, ``keypoints`` or ``image``)."""

    namespace: str
    names: tuple

    def topic(self, name: str, kind: str) -> str:
        """The topic of camera ``name``'s ``kind`` (``info``, ``cloud``, ``keypoints``,
        ``image``)."""
        leaf = {"info": "camera_info", "cloud": "correspondences", "keypoints": "keypoints",
                "image": "image_raw"}[kind]  # fmt: skip
        return f"{self.namespace}/{name}/{leaf}"

    def of(self, kinds: Iterable[str] = ("info", "cloud")) -> dict[str, tuple[str, str]]:
        return {self.topic(n, k): (k, n) for n in self.names for k in kinds}


def iter_rig_frames(
    bag: str | os.PathLike,
    inputs: Mapping[str, CameraInput],
    frontends: Mapping | None = None,
    images: bool = False,
) -> Iterator[CameraFrame | ImageFrame | DroppedFrame]:
    """The one reader of a rig bag's camera frames: every camera of ``inputs`` (camera name ->
    its :class:`~rs_localizer.ros.camera_input.CameraInput`,
    :func:`~rs_localizer.ros.camera_input.rig_camera_inputs`), in log-time order, from
    ``<namespace>/<camera>/correspondences``, read through the camera's input stage as the
    rig node reads them: its camera_infos checked and kept by their stamps (one rejected is
    counted ``camera_info_rejected.<reason>``, the previous ones stay) and each cloud given
    the model of its own stamp (:meth:`~rs_localizer.ros.camera_input.CameraInput.camera_of`:
    the newest camera_info stamped at or before it, the oldest for a cloud older than all;
    None before the camera's first camera_info is received), its rows with a NaN or inf
    dropped, counted ``points_dropped``, then at most its ``max_points``, highest scores
    first, counted ``capped_clouds``, ``capped_points``
    (:meth:`~rs_localizer.ros.camera_input.CameraInput.take`). One that cannot be read (an
    invalid stamp, no x, y, z / u, v fields) is yielded as a
    :class:`~rs_localizer.ros.camera_input.DroppedFrame` (``bad_input``), which the node
    counts received and skipped, and, when its stamp is readable, hands to the rig as a frame
    skipped (:func:`~rs_localizer.ros.camera_input.to_rig`). With the cameras' landmarks
    (``landmarks_file``, :func:`rig_landmarks`, given to :func:`rig_camera_inputs`) each
    camera's keypoints (``.../keypoints``: u, v, id) are read too, beside its clouds, as the
    rig node reads them (each row the 3D point of its id; unknown ids counted
    ``unknown_landmark_ids``).

    With ``images`` each camera's images (``.../image_raw``) are read instead, as
    :class:`~rs_localizer.ros.camera_input.ImageFrame` (decoded and checked against the camera
    model of their stamp; one refused is a ``DroppedFrame`` with its reason, ``bad_image``,
    ``image_size_mismatch``), for the rig's front ends. With ``frontends`` (camera name -> its
    front end, :func:`rig_frontends`) too, each image's frame is the front end's
    correspondences on the whole image, without a rig to predict it (what ``calibrate-rig``
    reads; :func:`_found_frame`).

    Yields:
        :class:`~rs_localizer.tracking.localizer.CameraFrame` (name, header stamp ns, model,
        pixels (N, 2) px, points (N, 3) m, tagged with its ``frame_id``),
        :class:`~rs_localizer.ros.camera_input.ImageFrame` or
        :class:`~rs_localizer.ros.camera_input.DroppedFrame`.
    """
    from ..camera_input import ImageFrame

    if frontends is not None or images:
        kinds: tuple = ("image",)
    elif any(inp.landmarks is not None for inp in inputs.values()):
        kinds = ("cloud", "keypoints")
    else:
        kinds = ("cloud",)
    for n, kind, msg, stamp, camera in rig_messages(bag, inputs, *kinds):
        item = inputs[n].take(msg, kind, stamp, camera)
        if frontends is not None and isinstance(item, ImageFrame):
            item = _found_frame(inputs[n], item, frontends[n])
        yield item


def _found_frame(inp: CameraInput, item: ImageFrame, frontend: Any) -> CameraFrame | DroppedFrame:
    """A camera's decoded image ``item`` as a frame of its front end's correspondences,
    without a rig to predict it (``calibrate-rig``): ``frontend.process(image, camera,
    encoding)`` (a :class:`~rs_localizer.correspondences.Frontend`) on the whole image, its
    rows as a cloud's (:meth:`~rs_localizer.ros.camera_input.CameraInput.rows`: non-finite
    rows dropped, at most ``max_points``). Without a camera model: a frame without rows, as
    the rig takes a frame before its camera_info. A front end that raises: a
    :class:`~rs_localizer.ros.camera_input.DroppedFrame` (``frontend_error``)."""
    from ...tracking.localizer import CameraFrame
    from ..camera_input import DroppedFrame

    name, stamp, camera, tag = item.camera_name, item.stamp_ns, item.camera, item.tag
    if camera is None:
        return CameraFrame(stamp, None, np.zeros((0, 2)), np.zeros((0, 3)), tag=tag,
                           camera_name=name)  # fmt: skip
    try:
        found = frontend.process(item.image, camera, item.encoding)
    except Exception as e:  # (any front end's failure: the frame is left out, counted)
        return DroppedFrame(name, stamp, camera, ValueError(f"{type(e).__name__}: {e}"),
                            "frontend_error")  # fmt: skip
    uv = np.asarray(found.points2d, float).reshape(-1, 2)
    xyz = np.asarray(found.points, float).reshape(-1, 3)
    uv, xyz, _ = inp.rows(uv, xyz, found.valid_scores())
    return CameraFrame(stamp, camera, uv, xyz, tag=tag, camera_name=name)


def rig_messages(
    bag: str | os.PathLike, inputs: Mapping[str, CameraInput], *kinds: str
) -> Iterator[tuple[str, str, Any, Stamp | DroppedFrame, CameraModel | None]]:
    """Every camera's frame messages of ``kinds`` (``cloud``: ``<namespace>/<camera>/
    correspondences``, ``keypoints``: ``.../keypoints``, ``image``: ``.../image_raw``) of a
    rig bag in log-time order, each
    camera's camera_infos given to its input (``inputs``: camera name -> its
    :class:`~rs_localizer.ros.camera_input.CameraInput`) as they come, as
    :func:`iter_rig_frames` reads them.

    Yields:
        ``(camera name, kind, message, its header stamp checked (ns) or the
        :class:`~rs_localizer.ros.camera_input.DroppedFrame` of that check, the camera model
        of that stamp or None)`` (:meth:`~rs_localizer.ros.camera_input.CameraInput.check`,
        :meth:`~rs_localizer.ros.camera_input.CameraInput.camera_of`).
    """

    topics = RigTopics(rig_namespace(bag, inputs), tuple(inputs)).of(("info", *kinds))
    ts = typestore()
    for topic, msgtype, _, raw in iter_messages(bag, set(topics)):
        k, n = topics[topic]
        msg = ts.deserialize_cdr(raw, msgtype)
        if k == "info":
            inputs[n].add_camera_info(msg)
            continue
        stamp = inputs[n].check(msg, k)
        yield n, k, msg, stamp, inputs[n].camera_of(stamp)


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

    The frames, read as the rig node reads them (:func:`read_rig_frames`: each cloud with the
    camera model of its stamp), go to the rig's own grouping
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
        :func:`read_rig_frames`).
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


def write_rig_outputs(
    res: RigReplay,
    out: str | os.PathLike,
    map_frame: str = "map",
    base_frame: str = "base_link",
    storage: str = "mcap",
    overwrite: bool = False,
    *,
    debug_bag: str | os.PathLike | None = None,
    path_length: int = 1000,
) -> Path:
    """Write the rig frames of ``res`` into the bag ``out`` as the rig node publishes them
    (:func:`~rs_localizer.ros.outputs.pose_messages`,
    :func:`~rs_localizer.ros.outputs.fused_messages`, as a camera's replay writes its frames,
    :func:`~rs_localizer.ros.bags.replay.open_out_bag`): for each posed rig frame
    ``/rs_localizer/pose`` and ``pose_with_covariance`` (the rig's pose in ``map_frame``),
    ``twist_single_frame`` (its own twist in ``base_frame``), with each rig frame the fused
    ``twist`` and ``odom`` it made final (without tracking its own), all stamped with the rig
    frame's time they are of and logged at the time of the rig frame that made them final
    (the last rig frame's for those still pending at the end). Returns the bag's path.

    ``debug_bag``: the rig bag ``res`` was replayed from; then the rig node's visualization
    topics are written too, logged with the rig frame's other outputs: for each posed rig
    frame ``/rs_localizer/path`` (the rig's last ``path_length`` poses) and, for each of its
    cameras, ``/rs_localizer/<camera>/debug_image`` (stamped like the camera's frame, in its
    frame id, drawn on the bag's ``<namespace>/<camera>/image_raw`` of that stamp, else on a
    blank canvas) and ``/rs_localizer/<camera>/markers``, the camera as the rig's pose and its
    mounting put it (:func:`~rs_localizer.ros.visualization.rig_camera_views`), as the rig
    node draws them. The bag's images are read as the rig frames are drawn, and only those of
    their cameras' frames are kept until drawn (:class:`_RigImages`).

    Raises:
        FileExistsError: ``out`` exists and not ``overwrite``.
    """
    from ..outputs import fused_messages, pose_messages
    from ..pipeline import FusedOutput
    from .replay import open_out_bag, write_messages

    def fused(poses) -> list:
        return fused_messages(
            [FusedOutput(f.pose.stamp_ns, f, base_frame) for f in poses], map_frame, wanted
        )

    wanted = OUT_TYPES.__contains__
    out = Path(out)
    ts = typestore()
    writer, conns = open_out_bag(out, storage, overwrite, ts)
    t = 0
    viz = None
    try:
        if debug_bag is not None:
            viz = _RigDebugWriter(writer, conns, ts, res, debug_bag, path_length, map_frame)
        for o in res.outputs:
            t = o.stamp_ns
            msgs = []
            if o.success:
                msgs = pose_messages(o.estimate, t, map_frame, base_frame, res.twist_now, (),
                                     wanted)  # fmt: skip
            write_messages(writer, conns, ts, t, msgs + fused(o.fused))
            if viz is not None and o.success:
                viz.frame(o, t)
        write_messages(writer, conns, ts, t, fused(res.flushed))
    finally:
        if viz is not None:
            viz.images.close()
        writer.close()
    return out


class _RigImages:
    """The images of a rig bag (``<namespace>/<camera>/image_raw``) that the posed rig frames
    of ``outputs`` draw on, read from the bag as they are asked for, in rig-frame order
    (:meth:`take`). Only an image whose ``(camera, header stamp)`` is a camera frame of a
    posed rig frame not yet drawn is decoded and kept, at most :attr:`MAX_HELD` per camera
    (the oldest dropped), and each is given out once."""

    MAX_HELD = 16

    def __init__(self, bag: str | os.PathLike, outputs: Iterable[Any], names: Iterable[str]):
        present = bag_topics(bag)
        names = tuple(names)
        self.topics = {t: n for t, (_, n) in RigTopics(rig_namespace(bag, names), names)
                       .of(("image",)).items() if t in present}  # fmt: skip
        with_images = set(self.topics.values())
        self.wanted = {(n, f.stamp_ns) for o in outputs if o.success
                       for n, f in o.frames.items() if n in with_images}  # fmt: skip
        self.held: dict[str, dict[int, tuple]] = {n: {} for n in with_images}
        self.newest: dict[str, int] = {}  # camera -> the newest stamp of its images read
        self.ts = typestore()
        self._messages = iter_messages(bag, set(self.topics)) if self.topics else iter(())

    def take(self, name: str, stamp_ns: int) -> tuple | None:
        """``(image, encoding)`` of camera ``name``'s image stamped ``stamp_ns`` (None: the bag
        has none). The bag is read on until it is found, an image of that camera stamped
        later is read, or the bag ends."""
        key = (name, stamp_ns)
        if key not in self.wanted:
            return None
        held = self.held[name]
        while stamp_ns not in held and self.newest.get(name, stamp_ns - 1) < stamp_ns:
            if not self._read():
                break
        self.wanted.discard(key)
        return held.pop(stamp_ns, None)

    def close(self) -> None:
        """Close the bag (the images not read are not read)."""
        close = getattr(self._messages, "close", None)
        if close is not None:
            close()

    def _read(self) -> bool:
        from ..image_codec import ImageRejected, decode_image

        item = next(self._messages, None)
        if item is None:
            return False
        topic, msgtype, _, raw = item
        n = self.topics[topic]
        msg = self.ts.deserialize_cdr(raw, msgtype)
        try:
            stamp = cv.checked_stamp_ns(msg.header.stamp)
        except ValueError:
            return True
        self.newest[n] = max(self.newest.get(n, stamp), stamp)
        if (n, stamp) not in self.wanted:
            return True
        try:
            image = decode_image(msg)
        except ImageRejected:
            return True
        held = self.held[n]
        held[stamp] = image
        while len(held) > self.MAX_HELD:
            held.pop(min(held))
        return True


class _RigDebugWriter:
    """The rig node's visualization topics of posed rig frames written into a replay's output
    bag (:func:`write_rig_outputs`): the rig's ``path`` and each camera's ``debug_image`` and
    ``markers``, by the camera replay's
    :class:`~rs_localizer.ros.bags.replay.DebugWriter`, on the images of :class:`_RigImages`."""

    def __init__(self, writer, conns, ts, res: RigReplay, bag, path_length: int, map_frame: str):
        from .replay import DebugWriter

        self.rig = DebugWriter(writer, conns, ts, path_length, map_frame, topics=("path",))
        self.cameras = {n: DebugWriter(writer, conns, ts, path_length, map_frame, f"{n}/",
                                        ("debug_image", "markers"))
                        for n in res.cameras}  # fmt: skip
        self.mounts = res.mounts
        self.images = _RigImages(bag, res.outputs, res.cameras)

    def frame(self, o, t_log: int) -> None:
        """Posed rig frame ``o``, logged at ``t_log``."""
        from ..visualization import rig_camera_views

        self.rig.path(o.estimate, o.stamp_ns, t_log)
        for n, frame, view, ref in rig_camera_views(o, self.mounts):
            w = self.cameras[n]
            tag = frame.tag
            frame_id = (tag[1] if isinstance(tag, tuple) else tag) or n
            image = self.images.take(n, frame.stamp_ns)
            w.debug_image(view, frame.points2d, frame.points3d, frame.camera, frame.stamp_ns,
                          frame_id, t_log, image)  # fmt: skip
            w.markers(view, frame.points3d, frame.camera, ref, t_log)
