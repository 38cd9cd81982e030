"""``rs-localizer render-bag``: rendered rolling-shutter sequences as ROS 2 bags.

Composes the simulation (:mod:`rs_localizer.sim.render`: images and ground truth), an image front
end (:mod:`rs_localizer.frontends`: correspondences) and bag I/O
(:mod:`rs_localizer.ros.bags.bag_io`, rosbags only: no ROS installation needed).

:func:`render_bag` writes ``<ns>/image_raw`` (``sensor_msgs/Image``, rgb8 or mono8),
``<ns>/camera_info``, ``/ground_truth/pose`` (``PoseStamped``: camera optical frame in the map
at the reference line), ``/ground_truth/twist`` (``TwistStamped``: camera frame, rad/s and m/s)
and, with a front end, ``<ns>/correspondences`` (``PointCloud2``: u, v float32 pixels, x, y, z
float32 metres, id uint32) -- what the front end makes of each image. The bag directory also
gets ``sequence.json`` (topics, camera, RS timing, settings: the schema of ``make-bag``) and the
front end's map (``markers.yaml`` for ArUco, ``feature_map.npz`` for features).

Stamps: an image's header stamp is the capture time of its first line (``rs.stamp_row = 0``);
the ground truth is stamped with the reference line's capture time.

:func:`render_rig_bag` (``--rig N``) renders a rig of N unsynchronized rolling-shutter cameras
(:func:`rs_localizer.sim.render.renderer.render_rig_video`) into a rig bag
(:func:`rs_localizer.ros.bags.bag_io.write_rig_bag`: per camera its images, camera_info and
the front end's correspondences, the rig's ground truth, ``rig_params.yaml``), which
``replay``, ``play`` and ``calibrate-rig`` read like a ``make-bag --rig`` bag.

    rs-localizer render-bag data/sample_images --frames 20 --mono
    rs-localizer render-bag /tmp/rig --rig 3 --frames 30
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..camera import CameraModel
from ..maps.scenes import scene_names
from ..ros.bags.bag_io import (
    CAMERA_INFO,
    GT_POSE,
    GT_TWIST,
    IMAGE,
    IMU,
    PC2,
    POSE,
    TWIST,
    RosbagsMessages,
    write_sequence_json,
)
from . import args as A

if TYPE_CHECKING:  # (for the annotations only: imported when rendering)
    from ..correspondences import Frontend
    from ..maps.features import FeatureMap
    from ..sim.render.scene import Scene

__all__ = ["register", "render_bag", "render_rig_bag", "run"]

HELP = "render a rolling-shutter image sequence (images, correspondences, ground truth) to a bag"


def _make_frontend(
    frontend, scene, camera, motion, duration, bag_dir: Path, feature_map, n_map_views: int = 12
):
    """Front end object + metadata; writes its map file into the bag directory."""
    from ..frontends import ArucoFrontend

    if frontend is None or frontend == "none":
        return None, {"kind": "none"}
    if frontend == "aruco":
        from ..maps.markers import write_marker_map

        write_marker_map(
            bag_dir / "markers.yaml", scene.dictionary, scene.marker_corners(), scene=scene.name
        )
        return ArucoFrontend.from_scene(scene), {
            "kind": "aruco",
            "map": "markers.yaml",
            "dictionary": scene.dictionary,
        }
    if frontend == "features":
        from ..frontends import FeatureFrontend
        from ..maps.features import FeatureMap
        from ..sim.feature_map import build_feature_map

        if feature_map is None:
            fm = build_feature_map(scene, camera, (motion, np.linspace(0, duration, n_map_views)))
        elif isinstance(feature_map, FeatureMap):
            fm = feature_map
        else:
            fm = FeatureMap.load(feature_map)
        fm.save(bag_dir / "feature_map.npz")
        return FeatureFrontend(fm), {
            "kind": "features",
            "map": "feature_map.npz",
            "descriptor": fm.kind,
            "landmarks": fm.num_landmarks,
        }
    if hasattr(frontend, "process"):
        return frontend, {"kind": getattr(frontend, "name", type(frontend).__name__)}
    raise ValueError(
        f"unknown front end {frontend!r}; expected aruco, features, none or an "
        "object with process(image, camera)"
    )


def render_bag(
    path: str | os.PathLike,
    scene: str | os.PathLike | Scene = "aruco_room",
    motion: str | Any = "shake",
    frames: int = 30,
    *,
    camera: str | CameraModel = "vga",
    fps: float = 30.0,
    frontend: str | Frontend | None = "aruco",
    feature_map: FeatureMap | str | os.PathLike | None = None,
    mono: bool = False,
    noise: bool = True,
    exposure: float = 0.0,
    supersample: int = 2,
    shutter: str = "rolling",
    seed: int = 0,
    start_time: float = 1_700_000_000.0,
    namespace: str = "/camera",
    camera_frame: str = "camera_optical_frame",
    map_frame: str = "map",
    storage: str = "mcap",
    compress: bool = True,
    overwrite: bool = False,
    progress: Callable[[int, int, int], Any] | None = None,
    imu_rate: float = 0.0,
    imu_topic: str = "/imu/data",
    motion_scale: float = 1.0,
) -> Path:
    """Render a sequence into a ROS 2 bag directory; returns its path.

    Args:
        path: bag directory to create.
        scene: built-in scene name, YAML path or :class:`~rs_localizer.sim.render.scene.Scene`.
        motion: preset name (:data:`~rs_localizer.sim.render.motion.MOTIONS`) or a motion object
            with ``pose(t)``/``velocity_body(t)``; motion_scale: a preset's rotation
            amplitudes times this.
        frames, fps: sequence length; frame ``k``'s first line is read at ``k / fps``.
        camera: preset name (``vga``, ``hd``) or a :class:`CameraModel`.
        frontend: ``aruco``, ``features``, ``none``/None, or an object with
            ``process(image, camera) -> (uv, xyz, ids)``; its correspondences go to
            ``<ns>/correspondences``. feature_map: a :class:`FeatureMap` or ``.npz`` path for
            ``features`` (default: built from 12 global-shutter views along the motion).
        mono: mono8 images (else rgb8). noise: sensor noise. exposure: exposure time (s) for
            motion blur. supersample: anti-aliasing samples per axis. shutter: ``rolling`` or
            ``global``.
        start_time: time (s since the epoch) of frame 0. storage: ``mcap`` or ``sqlite3``;
            compress: zstd (mcap chunk compression / sqlite3 per-message).
        progress: callable ``(k, frames, n_correspondences)`` or None.
        imu_rate: > 0: also write a ``sensor_msgs/Imu`` topic ``imu_topic`` at this rate (Hz)
            from 0.1 s before the first frame to 0.1 s after the last, as ``make-bag
            --imu-rate`` does (:func:`rs_localizer.sim.trajectory.imu_samples`: the motion's
            angular velocity and specific force in IMU axes ``R_IMU_CAMERA``, with bias and
            noise); ``sequence.json`` records the mounting.
    Raises:
        FileExistsError: ``path`` exists and not ``overwrite``. ValueError: bad arguments.
    """
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

    from ..sim.render.motion import make_motion
    from ..sim.render.renderer import NoiseModel, Renderer, camera_preset, frame_times
    from ..sim.render.scene import Scene, load_scene
    from ..sim.trajectory import R_IMU_CAMERA, imu_samples

    path = Path(path)
    if path.exists():
        if not overwrite:
            raise FileExistsError(f"{path} exists (use overwrite)")
        shutil.rmtree(path)
    if storage not in ("mcap", "sqlite3"):
        raise ValueError(f"unknown storage {storage!r}; use mcap or sqlite3")
    if frames < 1:
        raise ValueError("frames must be >= 1")
    if not (imu_rate >= 0 and np.isfinite(imu_rate)):
        raise ValueError(f"imu_rate must be >= 0 (Hz), got {imu_rate}")
    sc = scene if isinstance(scene, Scene) else load_scene(scene)
    cam = camera if isinstance(camera, CameraModel) else camera_preset(str(camera))
    duration = frames / fps
    mot = (
        make_motion(motion, sc, duration=duration, scale=motion_scale)
        if isinstance(motion, str)
        else motion
    )
    renderer = Renderer(
        sc, cam, supersample=supersample, exposure=exposure, noise=NoiseModel() if noise else None
    )
    tmp_dir = path.parent / (path.name + ".meta.tmp")
    if tmp_dir.exists():
        shutil.rmtree(tmp_dir)
    tmp_dir.mkdir(parents=True)
    fe, fe_meta = _make_frontend(frontend, sc, cam, mot, duration, tmp_dir, feature_map)
    M = RosbagsMessages()
    ns = namespace.rstrip("/")
    topics = {
        "image": f"{ns}/image_raw",
        "camera_info": f"{ns}/camera_info",
        "gt_pose": GT_POSE,
        "gt_twist": GT_TWIST,
    }
    if fe is not None:
        topics["correspondences"] = f"{ns}/correspondences"
    extra = {}
    if imu_rate > 0:
        topics["imu"] = imu_topic
        extra["imu"] = {
            "topic": imu_topic,
            "rate": imu_rate,
            "rotation_imu_from_camera": R_IMU_CAMERA.tolist(),
        }
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    writer = Writer(path, version=9, storage_plugin=plugin)
    if compress:
        writer.set_compression(
            CompressionMode.STORAGE if storage == "mcap" else CompressionMode.MESSAGE,
            CompressionFormat.ZSTD,
        )
    t0_ns = int(round(start_time * 1e9))
    counts = []
    tic = time.perf_counter()
    with writer as w:
        c_info = w.add_connection(topics["camera_info"], CAMERA_INFO, typestore=M.ts)
        c_img = w.add_connection(topics["image"], IMAGE, typestore=M.ts)
        c_corr = (
            w.add_connection(topics["correspondences"], PC2, typestore=M.ts)
            if fe is not None
            else None
        )
        c_gtp = w.add_connection(GT_POSE, POSE, typestore=M.ts)
        c_gtt = w.add_connection(GT_TWIST, TWIST, typestore=M.ts)
        if imu_rate > 0:
            c_imu = w.add_connection(imu_topic, IMU, typestore=M.ts)
            t_imu, om, fo = imu_samples(mot, -0.1, duration + 0.1, imu_rate, seed=seed)
            for t, o, f in zip(t_imu, om, fo, strict=True):
                stamp_imu = t0_ns + int(round(t * 1e9))
                w.write(c_imu, stamp_imu, M.cdr(M.imu(o, f, stamp_imu, "imu_link"), IMU))
        for k in range(int(frames)):
            t_first = float(frame_times(k, fps))
            fr = renderer.render(
                mot,
                t_first,
                index=k,
                shutter=shutter,
                mono=mono,
                rng=np.random.default_rng([seed, k]),
            )
            stamp = fr.stamp_ns(t0_ns)
            t_ref_ns = t0_ns + int(round(fr.t_ref * 1e9))
            t_log = stamp + 1_000_000
            w.write(c_info, t_log, M.cdr(M.camera_info(cam, stamp, camera_frame), CAMERA_INFO))
            t_log += 1_000_000
            w.write(c_img, t_log, M.cdr(M.image(fr.image, stamp, camera_frame), IMAGE))
            if fe is not None:
                uv, xyz, ids = fe.process(fr.image, cam)
                counts.append(len(uv))
                w.write(c_corr, t_log, M.cdr(M.cloud(uv, xyz, ids, stamp, camera_frame), PC2))
            w.write(
                c_gtp, t_log, M.cdr(M.pose(fr.orientation, fr.position, t_ref_ns, map_frame), POSE)
            )
            w.write(
                c_gtt,
                t_log,
                M.cdr(
                    M.twist(fr.angular_velocity, fr.linear_velocity, t_ref_ns, camera_frame), TWIST
                ),
            )
            if progress:
                progress(k, frames, counts[-1] if counts else 0)
    for f in tmp_dir.iterdir():
        shutil.move(str(f), str(path / f.name))
    tmp_dir.rmdir()
    write_sequence_json(
        path,
        "rs-localizer render-bag",
        topics,
        frames,
        cam,
        camera_frame,
        map_frame,
        0.0,
        rolling_shutter=shutter == "rolling",
        frontend=fe_meta,
        settings={
            "scene": sc.name,
            "motion": getattr(mot, "name", str(motion)),
            "fps": fps,
            "shutter": shutter,
            "encoding": "mono8" if mono else "rgb8",
            "noise": bool(noise),
            "exposure": exposure,
            "supersample": supersample,
            "seed": seed,
            "start_time": start_time,
            "correspondences_per_frame": float(np.mean(counts)) if counts else 0.0,
            "render_seconds": round(time.perf_counter() - tic, 2),
        },
        **extra,
    )
    return path


def render_rig_bag(
    path: str | os.PathLike,
    cameras: int = 3,
    scene: str | os.PathLike | Scene = "apriltag_rig_room",
    motion: str = "pan",
    frames: int = 30,
    *,
    fps: float = 30.0,
    motion_scale: float = 1.0,
    noise: bool = True,
    supersample: int = 2,
    seed: int = 0,
    start_time: float = 1_700_000_000.0,
    namespace: str = "/rig",
    map_frame: str = "map",
    storage: str = "mcap",
    compress: bool = True,
    overwrite: bool = False,
    progress: Callable[[int, int, int], Any] | None = None,
    camera: str | Sequence[str] = "vga",
) -> Path:
    """Render a rig of ``cameras`` (1-4) rolling-shutter cameras into a rig bag; returns its
    path.

    The rig (:func:`rs_localizer.sim.render.renderer.rendered_rig`: 640x480 cameras front, back and
    to the sides, readout times 20-30 ms, four readout directions, first frames 0-9 ms apart)
    moves along the renderer's ``motion`` preset around ``scene``'s viewpoint (rotation
    amplitudes times ``motion_scale``: ``pan`` turns up to 1.4 rad/s at 1, 2.1 rad/s at 1.5).
    Each camera renders ``frames`` images at ``fps``; the marker front end
    (:class:`~rs_localizer.frontends.ArucoFrontend` of the scene's markers: AprilTag or ArUco
    by the scene's dictionary) turns each image into correspondences. Written: per camera
    ``<ns>/<camera>/image_raw`` (rgb8), ``camera_info`` and ``correspondences`` (u, v, x, y,
    z, id = 4 * marker id + corner), the rig's ground truth, ``sequence.json`` (the ``rig``
    entry: mountings, RS timing; ``settings``: the render's CPU time per camera frame),
    ``rig_params.yaml`` (the node's parameters) and ``markers.yaml`` (the front end's map).

    Args:
        path: bag directory. scene: built-in name, YAML path or
            :class:`~rs_localizer.sim.render.scene.Scene` with markers (default: the closed
            ``apriltag_rig_room``). progress: callable ``(k, total, n_correspondences)`` per
            camera frame or None. camera: the cameras' preset (``vga`` 640x480, ``hd``
            1280x720), or one per camera in the rig's order (mixed resolutions). Others as
            :func:`render_bag`.
    Raises:
        FileExistsError: ``path`` exists and not ``overwrite``. ValueError: bad arguments
        (cameras outside 1-4, a scene without markers, an unknown motion or storage).
    """
    from ..maps.markers import write_marker_map
    from ..ros.bags.bag_io import write_rig_bag
    from ..sim.render import render_rig_video, rendered_rig, rig_trajectory
    from ..sim.render.scene import Scene, load_scene

    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists (use overwrite)")
    if storage not in ("mcap", "sqlite3"):
        raise ValueError(f"unknown storage {storage!r}; use mcap or sqlite3")
    if frames < 1:
        raise ValueError("frames must be >= 1")
    sc = scene if isinstance(scene, Scene) else load_scene(scene)
    if not sc.markers:
        raise ValueError(f"scene {sc.name!r} has no markers: a rendered rig needs a marker scene")
    rig = rendered_rig(cameras, fps, camera=camera)
    duration = max(c.offset for c in rig) + frames / fps
    traj = rig_trajectory(motion, sc, duration, scale=motion_scale)
    t0_ns = int(round(start_time * 1e9))
    total = frames * len(rig)
    stats: dict = {"render_s": [], "frontend_s": [], "n": {c.name: [] for c in rig}}

    def frames_iter():
        for k, f in enumerate(
            render_rig_video(
                rig, sc, traj, frames, t0_ns=t0_ns, supersample=supersample, noise=noise,
                seed=seed,
            )
        ):  # fmt: skip
            stats["render_s"].append(f.render_s)
            stats["frontend_s"].append(f.frontend_s)
            stats["n"][f.name].append(len(f.uv))
            if progress:
                progress(k, total, len(f.uv))
            yield f

    settings = {
        "scene": sc.name,
        "motion": motion,
        "motion_scale": motion_scale,
        "fps": fps,
        "encoding": "rgb8",
        "noise": bool(noise),
        "supersample": supersample,
        "seed": seed,
        "start_time": start_time,
    }
    out = write_rig_bag(
        path,
        frames_iter(),
        rig,
        traj,
        t0_ns=t0_ns,
        namespace=namespace,
        map_frame=map_frame,
        storage=storage,
        overwrite=overwrite,
        settings=settings,
        generator="rs-localizer render-bag --rig",
        compress=compress,
        extra={"frontend": {"kind": "aruco", "map": "markers.yaml", "dictionary": sc.dictionary}},
    )
    write_marker_map(out / "markers.yaml", sc.dictionary, sc.marker_corners(), scene=sc.name)
    meta = json.loads((out / "sequence.json").read_text())
    meta["settings"].update(
        {
            "correspondences_per_frame": {
                n: round(float(np.mean(v)), 1) for n, v in stats["n"].items()
            },
            "render_cpu_ms_per_frame": round(1e3 * float(np.median(stats["render_s"])), 1),
            "frontend_cpu_ms_per_frame": round(1e3 * float(np.median(stats["frontend_s"])), 1),
        }
    )
    (out / "sequence.json").write_text(json.dumps(meta, indent=2) + "\n")
    return out


# ------------------------------------------------------------------------------ CLI
def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``render-bag`` subcommand to ``sub`` (``func`` = :func:`run`)."""
    from ..sim.render.motion import motion_names
    from ..sim.render.renderer import CAMERA_PRESETS

    p = sub.add_parser(
        "render-bag",
        help=HELP,
        description="Render a rolling-shutter camera moving through a textured scene with "
        "markers: the images, camera_info, the front end's correspondences, the ground truth "
        "and sequence.json, as a bag (and the front end's map beside it).",
        formatter_class=A.HelpFormatter,
    )
    p.add_argument("out", help="bag directory to write")
    p.add_argument(
        "--scene",
        default=None,
        help=f"built-in scene ({', '.join(scene_names())}) or a scene YAML (format: "
        "docs/images.md#scene-files); default aruco_room, with --rig apriltag_rig_room",
    )
    p.add_argument(
        "--motion",
        default=None,
        choices=motion_names(),
        help="camera motion preset; default shake, with --rig pan (the rig turning)",
    )
    p.add_argument(
        "--motion-scale",
        type=A.nonneg_float,
        default=1.0,
        help="scale of the motion's rotation amplitudes (pan: 1 turns up to 1.4 rad/s, "
        "1.5 up to 2.1 rad/s)",
    )
    p.add_argument(
        "--rig",
        type=A.positive_int,
        default=None,
        metavar="N",
        help="a rig bag instead: N (1-4) unsynchronized rolling-shutter cameras (--camera: "
        "640x480 by default) "
        "(2: front, back; 3: front, left, right; 4: front, right, back, left; readout 20-30 ms "
        "in four directions, first frames 0-9 ms apart) on one body, --frames per camera, "
        "topics /rig/<camera>/image_raw, camera_info and correspondences (the marker front "
        "end), the rig's ground truth and BAG/rig_params.yaml (docs/rig_node.md)",
    )
    p.add_argument("--frames", type=A.positive_int, default=30, help="frames to render")
    p.add_argument("--fps", type=A.positive_float, default=30.0, help="frame rate (Hz)")
    p.add_argument(
        "--camera",
        default="vga",
        choices=sorted(CAMERA_PRESETS),
        help="camera preset: "
        + ", ".join(
            f"{k} ({v[0]}x{v[1]}, fx {v[2]:g} px, {v[7] * 1e3:g} ms readout)"
            for k, v in sorted(CAMERA_PRESETS.items())
        )
        + "; with --rig every camera's (a rig camera keeps its own readout time)",
    )
    p.add_argument(
        "--rig-cameras",
        nargs="+",
        default=None,
        choices=sorted(CAMERA_PRESETS),
        metavar="PRESET",
        help="with --rig N: N presets, one per camera in the rig's order (mixed resolutions), "
        "e.g. --rig 3 --rig-cameras hd vga vga; instead of --camera",
    )
    p.add_argument(
        "--frontend",
        default="aruco",
        choices=("aruco", "features", "none"),
        help="front end whose correspondences are written (none: images only)",
    )
    p.add_argument(
        "--feature-map",
        default=None,
        help="feature map .npz (features front end; "
        "default: built from 12 global-shutter views of the motion)",
    )
    p.add_argument("--mono", action="store_true", help="mono8 images (default: rgb8)")
    p.add_argument("--no-noise", action="store_true", help="no sensor noise")
    p.add_argument(
        "--exposure", type=A.nonneg_float, default=0.0, help="exposure time [s] (motion blur)"
    )
    p.add_argument(
        "--supersample", type=A.positive_int, default=2, help="anti-aliasing samples per pixel axis"
    )
    p.add_argument(
        "--global-shutter",
        action="store_true",
        help="render a global-shutter sequence (same poses, no readout)",
    )
    p.add_argument("--seed", type=A.nonneg_int, default=0, help="sensor-noise random seed")
    p.add_argument(
        "--start-time",
        type=A.nonneg_float,
        default=1_700_000_000.0,
        help="capture time of the first frame (s since the epoch)",
    )
    p.add_argument(
        "--storage", default="mcap", choices=("mcap", "sqlite3"), help="bag storage format"
    )
    p.add_argument("--no-compression", action="store_true", help="no zstd compression")
    p.add_argument(
        "--imu-rate",
        type=A.nonneg_float,
        default=0.0,
        help="also write a sensor_msgs/Imu topic at this rate (Hz; gyro with bias and noise, "
        "IMU axes x forward, y left, z up), as make-bag does",
    )
    p.add_argument("--imu-topic", default="/imu/data", help="topic of --imu-rate")
    p.add_argument("--overwrite", action="store_true", help="replace the bag if it exists")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
    return p


def run(a: argparse.Namespace) -> int:
    """Render the bag (:func:`render_bag`) with a progress bar on stderr; returns 0. Raises
    CliError for an output, scene or feature map that cannot be used (before rendering)."""
    A.output_dir(a.out, a.overwrite, "bag directory")
    if a.scene is not None and Path(a.scene).suffix in (".yaml", ".yml"):
        A.yaml_file(a.scene, "scene YAML")
    if a.rig is not None:
        return _run_rig(a)
    if a.rig_cameras is not None:
        raise A.CliError("--rig-cameras gives the presets of a rig's cameras: it needs --rig N")
    a.scene = a.scene or "aruco_room"
    if a.feature_map is not None:
        A.input_file(a.feature_map, "feature map (.npz)")
    bar, prog = _progress_bar(a.frames, a.quiet)

    try:
        path = render_bag(
            a.out,
            a.scene,
            a.motion or "shake",
            a.frames,
            camera=a.camera,
            fps=a.fps,
            frontend=a.frontend,
            feature_map=a.feature_map,
            mono=a.mono,
            noise=not a.no_noise,
            exposure=a.exposure,
            supersample=a.supersample,
            shutter="global" if a.global_shutter else "rolling",
            seed=a.seed,
            start_time=a.start_time,
            storage=a.storage,
            compress=not a.no_compression,
            overwrite=a.overwrite,
            progress=prog,
            imu_rate=a.imu_rate,
            imu_topic=a.imu_topic,
            motion_scale=a.motion_scale,
        )
    finally:
        bar.close()
    size = sum(f.stat().st_size for f in Path(path).rglob("*") if f.is_file())
    print(f"wrote {path} ({size / 1e6:.1f} MB)")
    return 0


def _progress_bar(total: int, quiet: bool):
    """A tqdm bar over ``total`` rendered frames and the renderer's ``progress(k, n,
    correspondences)`` callback that advances it (showing the frame's correspondences)."""
    from tqdm import tqdm

    bar = tqdm(total=total, desc="rendering", unit="frame", disable=quiet)

    def prog(k, n, nc):
        bar.update(1)
        bar.set_postfix(correspondences=nc, refresh=False)

    return bar, prog


def _rig_presets(a: argparse.Namespace) -> str | list[str]:
    """The rig cameras' presets: ``--rig-cameras`` (one per camera) or ``--camera`` (every
    camera's). Raises CliError on another count than ``--rig``'s, or both options given."""
    if a.rig_cameras is None:
        return a.camera
    if a.camera != "vga":
        raise A.CliError("give --camera (every camera's preset) or --rig-cameras, not both")
    if len(a.rig_cameras) != a.rig:
        raise A.CliError(
            f"--rig-cameras: {len(a.rig_cameras)} presets for --rig {a.rig}: give one per camera"
        )
    return list(a.rig_cameras)


def _run_rig(a: argparse.Namespace) -> int:
    """``render-bag --rig N`` (:func:`render_rig_bag`)."""
    if not 1 <= a.rig <= 4:
        raise A.CliError(f"--rig takes 1 to 4 cameras, got {a.rig}")
    if a.frontend != "aruco" or a.feature_map is not None:
        raise A.CliError("--rig writes the marker front end's correspondences: no --frontend")
    if a.mono or a.global_shutter or a.exposure > 0 or a.imu_rate > 0:
        raise A.CliError(
            "--rig renders rgb8 rolling-shutter cameras without blur or IMU: "
            "no --mono, --global-shutter, --exposure or --imu-rate"
        )
    presets = _rig_presets(a)
    bar, prog = _progress_bar(a.rig * a.frames, a.quiet)

    try:
        path = render_rig_bag(
            a.out,
            a.rig,
            a.scene or "apriltag_rig_room",
            a.motion or "pan",
            a.frames,
            fps=a.fps,
            motion_scale=a.motion_scale,
            noise=not a.no_noise,
            supersample=a.supersample,
            seed=a.seed,
            start_time=a.start_time,
            storage=a.storage,
            compress=not a.no_compression,
            overwrite=a.overwrite,
            progress=prog,
            camera=presets,
        )
    except ValueError as e:
        raise A.CliError(str(e)) from None
    finally:
        bar.close()
    meta = json.loads((Path(path) / "sequence.json").read_text())
    st = meta["settings"]
    per = ", ".join(f"{n} {v:g}" for n, v in st["correspondences_per_frame"].items())
    size = sum(f.stat().st_size for f in Path(path).rglob("*") if f.is_file())
    print(
        f"wrote {path} ({size / 1e6:.1f} MB): a rig of {a.rig} cameras, {meta['frames']} "
        f"camera frames; correspondences per frame: {per}; CPU per camera frame: render "
        f"{st['render_cpu_ms_per_frame']:g} ms, front end {st['frontend_cpu_ms_per_frame']:g} "
        f"ms; node parameters: {Path(path) / 'rig_params.yaml'}"
    )
    return 0
