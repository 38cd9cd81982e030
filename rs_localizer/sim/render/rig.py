"""Rendered video of a rig of rolling-shutter cameras (ROS-free): images, the front end's
correspondences and the rig's ground truth.

A rig (base frame x forward, y left, z up, REP 103) of 1-4 cameras (:func:`rendered_rig`:
640x480 with mild lens distortion, each its own line delay, readout direction and
first-frame offset, mounted front, back and to the sides as in
:data:`rs_localizer.sim.rig.LAYOUTS`) moves along a motion preset of the renderer
(:func:`rig_trajectory`: :func:`~rs_localizer.sim.render.motion.make_motion` around the
scene's viewpoint, turned into the base frame as
:class:`~rs_localizer.sim.rig_video.RigTrajectory` does). Every camera renders its own
rolling-shutter images (:class:`~rs_localizer.sim.render.renderer.Renderer`: every line at its
own capture time, with the camera's pose on the rig) and an image front end turns each image
into correspondences, as ``render-bag`` does for one camera.

The built-in scene ``apriltag_rig_room`` (a closed room with tags on all four walls) gives
every camera of the rig markers to see.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from ...camera import CameraModel
from ...geometry import rotvec_to_matrix
from ..rig import LAYOUTS, READOUTS
from ..rig_video import MountedTrajectory, RigCameraSim, RigTrajectory
from ..trajectory import R_FORWARD
from .motion import make_motion
from .renderer import NoiseModel, Renderer, camera_preset
from .scene import Scene, load_scene

__all__ = [
    "RIG_MOUNTS",
    "RigRenderedFrame",
    "render_rig_video",
    "rendered_rig",
    "rig_trajectory",
]

#: name -> (yaw deg about the base z axis, optical centre (m) in the base frame, frame readout
#: time s, first-frame offset s) of the rendered rig's cameras
RIG_MOUNTS = {
    "front": (0.0, (0.15, 0.0, 0.10), 0.030, 0.000),
    "left": (90.0, (0.0, 0.12, 0.12), 0.025, 0.004),
    "right": (-90.0, (0.0, -0.12, 0.12), 0.020, 0.009),
    "back": (180.0, (-0.15, 0.0, 0.10), 0.028, 0.002),
}


@dataclass
class RigRenderedFrame:
    """One rendered camera frame of a rig.

    ``stamp_ns``: capture time of line ``stamp_row`` (the header stamp); ``t_ref_ns``: of the
    camera's reference line. ``image``: (H, W, 3) uint8 RGB. ``uv`` (N, 2) px, ``xyz`` (N, 3)
    m (map frame), ``ids`` (N,): the front end's correspondences of the image (marker
    corners: ``4 * marker id + corner``). ``orientation`` (3, 3) rig -> world and ``position``
    (3,) m: the rig at ``t_ref_ns``. ``cpu_s``: CPU time of rendering (``render_s``) and of the
    front end (``frontend_s``), s."""

    name: str
    index: int
    stamp_ns: int
    t_ref_ns: int
    image: np.ndarray
    uv: np.ndarray
    xyz: np.ndarray
    ids: np.ndarray
    orientation: np.ndarray
    position: np.ndarray
    render_s: float = 0.0
    frontend_s: float = 0.0


def rendered_rig(
    num_cameras: int = 3,
    fps: float = 30.0,
    names: tuple[str, ...] | None = None,
    camera: str = "vga",
) -> list[RigCameraSim]:
    """``num_cameras`` (1-4) cameras laid out as :data:`rs_localizer.sim.rig.LAYOUTS` (2:
    front, back; 3: front, left, right; 4: front, right, back, left), each the ``camera``
    preset (default 640x480, mild plumb_bob distortion) with its :data:`RIG_MOUNTS` readout
    time (30, 25, 20, 28 ms: front, left, right, back) over its lines, the readout directions
    of :data:`rs_localizer.sim.rig.READOUTS` in layout order (top-down, left-right, bottom-up,
    right-left), and first frames 0-9 ms apart (unsynchronized).

    Raises:
        ValueError: ``num_cameras`` outside 1-4, or an unknown name.
    """
    if names is None:
        if num_cameras not in LAYOUTS:
            raise ValueError(f"a rendered rig has 1 to 4 cameras, got {num_cameras}")
        names = tuple(n for n, _ in LAYOUTS[num_cameras])
    out = []
    for k, name in enumerate(names):
        if name not in RIG_MOUNTS:
            raise ValueError(f"unknown rig camera {name!r}; expected one of {sorted(RIG_MOUNTS)}")
        yaw, pos, readout_time, offset = RIG_MOUNTS[name]
        cam = camera_preset(camera, readout_time=readout_time, readout=READOUTS[k % 4])
        R = rotvec_to_matrix(np.array([0.0, 0.0, np.radians(yaw)])) @ R_FORWARD
        out.append(RigCameraSim(name, cam, R, np.array(pos, float), offset, float(fps)))
    return out


def rig_trajectory(
    motion: str = "pan", scene: Scene | None = None, duration: float = 1.0, scale: float = 1.0
) -> RigTrajectory:
    """The rig's motion: the renderer's preset ``motion`` (``pan``: turning ~1.3 rad/s
    at ``scale`` 1; ``shake``, ``walk``, ...) around ``scene``'s viewpoint, rotation amplitudes
    times ``scale``, its camera axes turned into the rig's base frame (x forward, y left,
    z up). Raises ValueError for an unknown preset."""
    return RigTrajectory(make_motion(motion, scene, duration=duration, scale=scale))


def render_rig_video(
    cameras: list[RigCameraSim],
    scene: str | Scene = "apriltag_rig_room",
    trajectory: RigTrajectory | None = None,
    frames: int = 30,
    *,
    frontend: Callable | None = None,
    t0_ns: int = 1_700_000_000_000_000_000,
    stamp_row: float = 0.0,
    supersample: int = 2,
    noise: bool = True,
    seed: int = 0,
) -> Iterator[RigRenderedFrame]:
    """Yield every camera's rendered frames (``frames`` per camera), sorted by stamp.

    Camera c's frame k has its first line read at rig time ``c.offset + k / c.fps`` (rig time
    t is stamped ``t0_ns + t * 1e9`` ns); each line is rendered with the camera's pose on the
    rig at its own capture time.

    Args:
        cameras: the rig (:func:`rendered_rig`). scene: a built-in name, YAML path or
            :class:`Scene`. trajectory: the rig's motion (default :func:`rig_trajectory`
            ``pan`` over the video).
        frontend: ``make(camera_name) -> object with process(image, camera) -> (uv, xyz,
            ids)``, one front end per camera (default: the AprilTag/ArUco front end of the
            scene's markers, :class:`~rs_localizer.frontends.ArucoFrontend`).
        supersample: anti-aliasing samples per axis. noise: sensor noise, seeded per camera and
            frame from ``seed``.
    """
    from ...frontends import ArucoFrontend

    sc = scene if isinstance(scene, Scene) else load_scene(scene)
    cameras = list(cameras)
    duration = max(c.offset + frames / c.fps for c in cameras)
    trajectory = trajectory or rig_trajectory("pan", sc, duration)
    make_fe = frontend or (lambda name: ArucoFrontend.from_scene(sc))
    jobs = []
    for ci, c in enumerate(cameras):
        cam: CameraModel = c.camera
        for k in range(int(frames)):
            t_first = c.offset + k / c.fps
            jobs.append((t_first + float(cam.line_time(stamp_row)), ci, k, t_first))
    jobs.sort()
    renderers = [
        Renderer(sc, c.camera, supersample=supersample, noise=NoiseModel() if noise else None)
        for c in cameras
    ]
    mounted = [
        MountedTrajectory(
            trajectory, np.asarray(c.R_rig_cam, float), np.asarray(c.p_rig_cam, float)
        )
        for c in cameras
    ]
    fes = [make_fe(c.name) for c in cameras]
    for stamp, ci, k, t_first in jobs:
        c, r = cameras[ci], renderers[ci]
        tic = time.process_time()
        img = r.render_image(mounted[ci], t_first)
        if r.noise is not None:
            img = r.noise.apply(img, np.random.default_rng([seed, ci, k]))
        img = np.clip(np.rint(img), 0, 255).astype(np.uint8)
        toc = time.process_time()
        uv, xyz, ids = fes[ci].process(img, c.camera)
        t_ref = t_first + float(c.camera.line_time(c.camera.reference_line))
        R, p = trajectory.pose(t_ref)
        yield RigRenderedFrame(
            c.name,
            k,
            t0_ns + int(round(stamp * 1e9)),
            t0_ns + int(round(t_ref * 1e9)),
            img,
            np.asarray(uv, float).reshape(-1, 2),
            np.asarray(xyz, float).reshape(-1, 3),
            np.asarray(ids, np.uint32).reshape(-1),
            R,
            p,
            toc - tic,
            time.process_time() - toc,
        )
