"""Rig bags (several cameras, each its own timing) with ``rosbags``: written from a simulated
rig video, replayed offline through the rig mode's :class:`~rs_localizer.tracking.rig.
RigLocalizer` with the node's parameters.

A rig bag holds, per camera ``<c>``, ``<ns>/<c>/camera_info`` and ``<ns>/<c>/correspondences``
(u, v, x, y, z, id), each stamped with the camera's own capture time of ``stamp_row``, the
rig's ground truth ``/ground_truth/pose`` (``base_frame`` in ``map``) and
``/ground_truth/twist`` (rig frame) at every camera frame's reference-row time, a
``sequence.json`` whose ``rig`` entry lists the cameras (name, mounting, RS timing), and
``rig_params.yaml``: the node's parameter file for the rig (``--params-file`` of the node and
of ``replay``).
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from ...accuracy import frame_errors
from .. import conversions as cv
from ..params import (
    RIG_CAMERA_PARAMETERS,
    RIG_PARAMETERS,
    default_values,
    read_params_file,
    rig_config,
)
from ..pointcloud import read_correspondences
from .bag_io import (
    CAMERA_INFO,
    GT_POSE,
    GT_TWIST,
    PC2,
    POSE,
    TWIST,
    RosbagsMessages,
    iter_messages,
    load_ground_truth,
    read_bag_info,
    storage_plugin,
    typestore,
)

__all__ = [
    "RigReplay",
    "is_rig_bag",
    "read_rig_frames",
    "replay_rig",
    "rig_parameter_values",
    "write_rig_bag",
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
) -> Path:
    """Write a simulated rig video (:func:`rs_localizer.sim.rig_video.generate_rig_video`:
    ``frames``, ``cameras``, ``trajectory``; rig time 0 at ``t0_ns``) as a rig bag (module
    docstring); returns its path. Log times: camera_info at stamp + 1 ms, the cloud and the
    ground truth at stamp + 2 ms.

    Raises:
        FileExistsError: ``path`` exists and not ``overwrite``.
    """
    from rosbags.rosbag2 import Writer

    path = Path(path)
    if path.exists():
        if not overwrite:
            raise FileExistsError(f"{path} exists (use --overwrite)")
        shutil.rmtree(path)
    frames = list(frames)
    ns = namespace.rstrip("/")
    M = RosbagsMessages()
    topics = {}
    for c in cameras:
        topics[f"{c.name}/camera_info"] = f"{ns}/{c.name}/camera_info"
        topics[f"{c.name}/correspondences"] = f"{ns}/{c.name}/correspondences"
    by = {c.name: c for c in cameras}
    with Writer(path, version=9, storage_plugin=storage_plugin(storage)) as w:
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
        written = set()
        for f in frames:
            cam = by[f.name]
            frame_id = f"{f.name}_optical_frame"
            info = M.camera_info(cam.camera, f.stamp_ns, frame_id)
            w.write(
                conns[f"{f.name}/camera_info"], f.stamp_ns + 1_000_000, M.cdr(info, CAMERA_INFO)
            )
            ids = np.arange(len(f.uv), dtype=np.uint32)
            cloud = M.cloud(f.uv, f.xyz, ids, f.stamp_ns, frame_id)
            t_log = f.stamp_ns + 2_000_000
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
    meta = {
        "generator": "rs-localizer make-bag --rig",
        "topics": {**topics, "gt_pose": GT_POSE, "gt_twist": GT_TWIST},
        "frames": len(frames),
        "map_frame": map_frame,
        "rs": {"stamp_row": float(stamp_row)},
        "rig": rig,
        "settings": settings or {},
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
    tree = {"/**/rs_localizer": {"ros__parameters": body}}
    return yaml.safe_dump(tree, sort_keys=False, default_flow_style=None)


def rig_parameter_values(
    bag: str | os.PathLike,
    params_files: Iterable[str | os.PathLike] = (),
    params: Mapping[str, Any] | None = None,
) -> tuple[dict, dict]:
    """``(values, camera values)`` for :func:`~rs_localizer.ros.params.rig_config`: the
    defaults, then the bag's ``rig_params.yaml``, each parameter file, then ``params``."""
    values = default_values()
    values.update({k: (list(p.default) if isinstance(p.default, list) else p.default)
                   for k, p in RIG_PARAMETERS.items()})  # fmt: skip
    tree: dict[str, Any] = {}
    own = Path(bag) / "rig_params.yaml"
    for f in ([own] if own.is_file() else []) + list(params_files):
        tree.update(read_params_file(f))
    tree.update(params or {})
    values.update({k: v for k, v in tree.items() if k in values})
    cams = {}
    for n in values["rig.cameras"]:
        cams[n] = {k: tree.get(f"rig.{n}.{k}", p.default) for k, p in RIG_CAMERA_PARAMETERS.items()}
        cams[n]["mounting"] = tree.get(f"rig.{n}.mounting")
    return values, cams


@dataclass
class RigReplay:
    """What :func:`replay_rig` did: ``outputs`` (every rig frame's
    :class:`~rs_localizer.tracking.rig.RigOutput`), ``fused`` (the fused poses), the rig's
    ``counts`` (per camera and per rig frame), ``errors`` (per posed rig frame with ground
    truth: ``rot_deg``, ``pos_m``, ``angvel``, ``linvel`` of its own twist) and
    ``fused_errors`` (of the fused twist)."""

    outputs: list = field(default_factory=list)
    fused: list = field(default_factory=list)
    counts: dict = field(default_factory=dict)
    errors: list = field(default_factory=list)
    fused_errors: list = field(default_factory=list)
    cameras: tuple = ()

    @property
    def solved(self) -> int:
        return sum(o.success for o in self.outputs)

    def summary(self) -> dict:
        """Medians of the errors (NaN without ground truth) and the counts."""

        def med(rows, k):
            vals = [r[k] for r in rows if k in r]
            return float(np.median(vals)) if vals else float("nan")

        return {
            "rig_frames": len(self.outputs),
            "solved": self.solved,
            "rot_deg": med(self.errors, "rot_deg"),
            "pos_m": med(self.errors, "pos_m"),
            "angvel": med(self.errors, "angvel"),
            "linvel": med(self.errors, "linvel"),
            "fused_angvel": med(self.fused_errors, "angvel"),
            "fused_linvel": med(self.fused_errors, "linvel"),
        }


def replay_rig(
    bag: str | os.PathLike,
    params_files: Iterable[str | os.PathLike] = (),
    params: Mapping[str, Any] | None = None,
    progress: TextIO | None = None,
) -> RigReplay:
    """Every camera's frames of a rig bag, in log-time order, through the rig mode
    (:class:`~rs_localizer.tracking.rig.RigLocalizer` with the configuration of
    :func:`rig_parameter_values`), against the bag's ground truth.

    Raises:
        ~rs_localizer.ros.params.ConfigError: the parameters (e.g. a camera without mounting,
            no ``rig.cameras``).
    """
    from ...tracking.rig import RigCameraFrame, RigLocalizer

    values, cams = rig_parameter_values(bag, params_files, params)
    cfg = rig_config(values, cams)
    info = read_bag_info(bag)
    ns = str(info.get("rig", {}).get("namespace", "/rig")).rstrip("/")
    topics = {}
    for c in cfg.cameras:
        topics[f"{ns}/{c.name}/camera_info"] = ("info", c)
        topics[f"{ns}/{c.name}/correspondences"] = ("cloud", c)
    rig = RigLocalizer(cfg.settings)
    models = {c.name: None for c in cfg.cameras}
    ts = typestore()
    res = RigReplay(cameras=tuple(c.name for c in cfg.cameras))
    for topic, msgtype, _, raw in iter_messages(bag, set(topics)):
        kind, c = topics[topic]
        msg = ts.deserialize_cdr(raw, msgtype)
        if kind == "info":
            try:
                models[c.name] = cv.camera_model_from_camera_info(
                    msg, c.line_delay, c.readout_time, c.direction, cfg.reference_row
                )
            except ValueError:
                continue
            continue
        try:
            corr = read_correspondences(msg)
            stamp = cv.checked_stamp_ns(msg.header.stamp)
        except ValueError:
            continue
        outs = rig.add(RigCameraFrame(c.name, stamp, models[c.name], corr.pixels, corr.points))
        res.outputs += outs
        res.fused += [f for o in outs for f in o.fused]
        if progress is not None and outs:
            print(f"\rrig frames: {len(res.outputs)}", end="", file=progress)
    tail = rig.close()
    res.outputs += tail
    res.fused += [f for o in tail for f in o.fused] + rig.flush()
    if progress is not None:
        print(file=progress)
    res.counts = {"rig": rig.rig_counts(), **{n: rig.camera_counts(n) for n in rig.cameras}}
    gt = load_ground_truth(bag)
    for o in res.outputs:
        if o.success:
            q = o.measurement.pose
            e = frame_errors(q.orientation, q.position, q.angular_velocity,
                             q.linear_velocity, gt, o.stamp_ns)  # fmt: skip
            if e is not None:
                res.errors.append(e)
    for f in res.fused:
        q = f.pose
        e = frame_errors(q.orientation, q.position, q.angular_velocity, q.linear_velocity, gt,
                         q.stamp_ns)  # fmt: skip
        if e is not None:
            res.fused_errors.append(e)
    return res


def is_rig_bag(bag: str | os.PathLike) -> bool:
    """The bag's ``sequence.json`` has a ``rig`` entry (written by ``make-bag --rig``)."""
    return "rig" in read_bag_info(bag)


def read_rig_frames(
    bag: str | os.PathLike,
    params_files: Iterable[str | os.PathLike] = (),
    params: Mapping[str, Any] | None = None,
) -> tuple[list, dict, dict]:
    """Every camera's frames of a rig bag, without mountings (what ``calibrate-rig`` reads).

    The cameras are ``rig.cameras`` of :func:`rig_parameter_values` (the bag's
    ``rig_params.yaml``, the parameter files, ``params``); each camera's RS timing is its
    ``rig.<camera>.*`` value, else the ``rs.*`` one; its frames are read from
    ``<namespace>/<camera>/correspondences`` with the model of the camera_info received
    before them (frames before any camera_info have ``camera`` None).

    Returns:
        (frames: :class:`~rs_localizer.tracking.rig.RigCameraFrame` in log-time order, the
        parameter values, the cameras' values).
    Raises:
        ValueError: no ``rig.cameras``, or an unknown readout direction.
    """
    from ...camera import READOUT_DIRECTIONS
    from ...tracking.rig import RigCameraFrame

    values, cams = rig_parameter_values(bag, params_files, params)
    names = [str(n).strip() for n in values["rig.cameras"]]
    if not names:
        raise ValueError(f"{bag}: no rig.cameras (not a rig bag, and no --params-file with them)")
    ref = float(values["rs.reference_row"])
    timing = {}
    for n in names:
        c = cams[n]
        ld, rt = float(c.get("line_delay", -1.0)), float(c.get("readout_time", -1.0))
        d = str(c.get("direction", "") or values["rs.direction"]).strip()
        if d not in READOUT_DIRECTIONS:
            raise ValueError(f"rig.{n}.direction: unknown readout direction {d!r}")
        timing[n] = (
            float(values["rs.line_delay"]) if ld < 0 else ld,
            float(values["rs.readout_time"]) if rt < 0 else rt,
            d,
            None if ref < 0 else ref,
        )
    info = read_bag_info(bag)
    ns = str(info.get("rig", {}).get("namespace", "/rig")).rstrip("/")
    topics = {}
    for n in names:
        topics[f"{ns}/{n}/camera_info"] = ("info", n)
        topics[f"{ns}/{n}/correspondences"] = ("cloud", n)
    models: dict = {n: None for n in names}
    ts = typestore()
    frames = []
    for topic, msgtype, _, raw in iter_messages(bag, set(topics)):
        kind, n = topics[topic]
        msg = ts.deserialize_cdr(raw, msgtype)
        if kind == "info":
            try:
                models[n] = cv.camera_model_from_camera_info(msg, *timing[n])
            except ValueError:
                continue
            continue
        try:
            corr = read_correspondences(msg)
            stamp = cv.checked_stamp_ns(msg.header.stamp)
        except ValueError:
            continue
        frames.append(RigCameraFrame(n, stamp, models[n], corr.pixels, corr.points))
    return frames, values, cams
