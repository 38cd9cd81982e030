"""Rendered rigs of rolling-shutter cameras (ROS-free): every camera's images at its
mounting-composed poses with its own timing (:func:`render_rig_images`, the one rendering
core; each a :class:`~rs_localizer.sim.rig_video.RigFrameSim`, as the simulated rig video's
frames), and a rig's rendered video with an image front end's correspondences
(:func:`render_rig_video`, for ``render-bag --rig`` and the rendered-rig benchmark).

The rig (base frame x forward, y left, z up, REP 103) moves along a motion preset of the
renderer (:func:`rig_trajectory`: :func:`~rs_localizer.sim.render.motion.make_motion` around the
scene's viewpoint, a camera's motion in optical axes turned into the base frame as
:class:`~rs_localizer.sim.rig_video.RigTrajectory` does: ``R_rig(t) = R_motion(t) R_FORWARD^T``).
Each camera (:class:`~rs_localizer.sim.rig_video.RigCameraSim`: its optical frame's pose on the
rig, first-frame offset, frame rate) is rendered by
:class:`~rs_localizer.sim.render.renderer.Renderer` along
:class:`~rs_localizer.sim.rig_video.MountedTrajectory`, the rig's motion composed with its
mounting, every line at its own capture time. Ground truth:
:func:`~rs_localizer.sim.rig_video.rig_truth`.

Two rigs: :func:`rendered_rig` (1-4 cameras laid out as :data:`rs_localizer.sim.rig.LAYOUTS`,
mild lens distortion; the built-in scene ``apriltag_rig_room``, a closed room with tags on all
four walls, gives every camera markers to see) and :func:`vga_rig` (1-3 cameras looking front,
left and right, seeing the ``aruco_room`` walls; the image tests' rig, rendered by
:func:`render_rig_frames`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Sequence

import numpy as np

from ..rig import LAYOUTS, READOUTS
from ..rig_video import PLACES, RigCameraSim, RigFrameSim, RigTrajectory
from .motion import make_motion
from .renderer import NoiseModel, Renderer, camera_preset
from .scene import Scene, load_scene

__all__ = [
    "RIG_TIMING",
    "render_rig_frames",
    "render_rig_images",
    "render_rig_video",
    "rendered_rig",
    "rig_trajectory",
    "vga_rig",
]

#: name -> (frame readout time s, first-frame offset s) of the rendered rig's cameras (placed
#: as :data:`~rs_localizer.sim.rig_video.PLACES`)
RIG_TIMING = {
    "front": (0.030, 0.000),
    "left": (0.025, 0.004),
    "right": (0.020, 0.009),
    "back": (0.028, 0.002),
}


def vga_rig(num_cameras: int = 3, offsets_s: tuple = (0.0, 0.004, 0.008)) -> list:
    """``num_cameras`` (1-3) 640x480 cameras (the renderer's ``vga`` preset, 30 ms readout)
    looking front, 35 deg left and 35 deg right, 5-15 cm off the rig origin, readouts
    top-down, bottom-up and left-right (62.5, 62.5 and 46.9 us/line), first frames
    ``offsets_s`` apart, 30 fps: a rig that sees the ``aruco_room`` walls from its viewpoint.

    Raises:
        ValueError: ``num_cameras`` outside 1-3.
    """
    if not 1 <= num_cameras <= 3:
        raise ValueError(f"num_cameras must be 1-3, got {num_cameras}")
    spec = [
        ("front", 0.0, (0.10, 0.0, 0.05), "top_to_bottom"),
        ("left", 35.0, (0.0, 0.08, 0.06), "bottom_to_top"),
        ("right", -35.0, (0.0, -0.08, 0.06), "left_to_right"),
    ]
    return [
        RigCameraSim.facing(name, camera_preset("vga", readout=readout), yaw, pos, offsets_s[k])
        for k, (name, yaw, pos, readout) in enumerate(spec[:num_cameras])
    ]


def rendered_rig(
    num_cameras: int = 3,
    fps: float = 30.0,
    names: tuple[str, ...] | None = None,
    camera: str | Sequence[str] = "vga",
) -> list[RigCameraSim]:
    """``num_cameras`` (1-4) cameras laid out as :data:`rs_localizer.sim.rig.LAYOUTS` (2:
    front, back; 3: front, left, right; 4: front, right, back, left), each the ``camera``
    preset (default 640x480, mild plumb_bob distortion; a sequence: one preset per camera, in
    layout order, e.g. ``("hd", "vga", "vga")``) placed as
    :data:`~rs_localizer.sim.rig_video.PLACES`, with its :data:`RIG_TIMING` readout
    time (30, 25, 20, 28 ms: front, left, right, back) over its lines, the readout directions
    of :data:`rs_localizer.sim.rig.READOUTS` in layout order (top-down, left-right, bottom-up,
    right-left), and first frames 0-9 ms apart (unsynchronized).

    Raises:
        ValueError: ``num_cameras`` outside 1-4, an unknown name, or a sequence of presets of
            another length than the cameras.
    """
    if names is None:
        if num_cameras not in LAYOUTS:
            raise ValueError(f"a rendered rig has 1 to 4 cameras, got {num_cameras}")
        names = tuple(n for n, _ in LAYOUTS[num_cameras])
    presets = [camera] * len(names) if isinstance(camera, str) else list(camera)
    if len(presets) != len(names):
        raise ValueError(
            f"{len(presets)} camera presets {presets} for the {len(names)} cameras {list(names)}"
        )
    out = []
    for k, name in enumerate(names):
        if name not in RIG_TIMING:
            raise ValueError(f"unknown rig camera {name!r}; expected one of {sorted(RIG_TIMING)}")
        readout_time, offset = RIG_TIMING[name]
        cam = camera_preset(presets[k], readout_time=readout_time, readout=READOUTS[k % 4])
        out.append(RigCameraSim.facing(name, cam, *PLACES[name], offset, fps))
    return out


def rig_trajectory(
    motion: str = "pan", scene: Scene | None = None, duration: float = 1.0, scale: float = 1.0
) -> RigTrajectory:
    """The rig's motion: the renderer's preset ``motion`` (``pan``: turning ~1.3 rad/s
    at ``scale`` 1; ``shake``, ``walk``, ...) around ``scene``'s viewpoint, rotation amplitudes
    times ``scale``, its camera axes turned into the rig's base frame (x forward, y left,
    z up). Raises ValueError for an unknown preset."""
    return RigTrajectory(make_motion(motion, scene, duration=duration, scale=scale))


def _duration(cameras: list[RigCameraSim], frames: int) -> float:
    """s of rig time until the last camera's last frame starts."""
    return max(c.offset + frames / c.fps for c in cameras)


def render_rig_images(
    cameras: list[RigCameraSim],
    scene: Scene,
    trajectory: RigTrajectory,
    frames: int,
    *,
    t0_ns: int = 1_700_000_000_000_000_000,
    stamp_row: float = 0.0,
    supersample: int = 2,
    noise: bool = True,
    seed: int = 0,
    mono: bool = False,
) -> Iterator[RigFrameSim]:
    """Yield every camera's rendered images (``frames`` per camera), sorted by stamp (then by
    camera, in ``cameras`` order), each rendered when it is asked for: a
    :class:`~rs_localizer.sim.rig_video.RigFrameSim` with its ``image`` ((H, W, 3) uint8 RGB,
    or (H, W) mono8), ``render_s`` (CPU s), the rig's pose at its reference line and no
    correspondences.

    Camera c's frame k has its first line read at rig time ``c.offset + k / c.fps`` (rig time
    t is stamped ``t0_ns + t * 1e9`` ns; the header stamp is the capture time of line
    ``stamp_row``); each line is rendered with the camera's pose on the rig (``trajectory``
    composed with its mounting) at its own capture time.

    Args:
        cameras: the rig (:func:`rendered_rig`, :func:`vga_rig`). scene: the scene.
        trajectory: the rig's motion (:func:`rig_trajectory`).
        supersample: anti-aliasing samples per axis. noise: sensor noise
            (:class:`~rs_localizer.sim.render.renderer.NoiseModel`), seeded per camera and frame
            from ``seed``. mono: mono8 images instead of RGB.
    """
    cameras = list(cameras)
    jobs = []
    for ci, c in enumerate(cameras):
        for k in range(int(frames)):
            t_first = c.offset + k / c.fps
            jobs.append((t_first + float(c.camera.line_time(stamp_row)), ci, k, t_first))
    jobs.sort()
    renderers = [
        Renderer(scene, c.camera, supersample=supersample, noise=NoiseModel() if noise else None)
        for c in cameras
    ]
    mounted = [c.on(trajectory) for c in cameras]
    for stamp, ci, k, t_first in jobs:
        tic = time.process_time()
        fr = renderers[ci].render(
            mounted[ci], t_first, index=k, mono=mono, rng=np.random.default_rng([seed, ci, k])
        )
        render_s = time.process_time() - tic
        R, p = trajectory.pose(fr.t_ref)
        yield RigFrameSim(
            cameras[ci].name, k, int(t0_ns) + int(round(stamp * 1e9)),
            int(t0_ns) + int(round(fr.t_ref * 1e9)), np.zeros((0, 2)), np.zeros((0, 3)), R, p,
            image=fr.image, render_s=render_s,
        )  # fmt: skip


def render_rig_frames(
    cameras: list,
    frames: int,
    *,
    scene: str = "aruco_room",
    motion: str = "shake",
    seed: int = 0,
    t0_ns: int = 1_700_000_000_000_000_000,
    supersample: int = 1,
    noise: bool = True,
    mono: bool = False,
) -> tuple[list[RigFrameSim], RigTrajectory]:
    """Render ``frames`` frames of every camera, stamped at their row 0, sorted by stamp:
    :func:`render_rig_images` along the renderer's ``motion`` preset over the rendered time,
    around ``scene``'s viewpoint.

    Args:
        cameras: :class:`~rs_localizer.sim.rig_video.RigCameraSim` (e.g. :func:`vga_rig`).
        scene, motion: the renderer's scene and motion preset names.
        supersample, noise, mono: as :func:`render_rig_images`.
    Returns:
        (frames, the rig's motion; :func:`~rs_localizer.sim.rig_video.rig_truth` gives its
        truth).
    """
    sc = load_scene(scene)
    rig = rig_trajectory(motion, sc, _duration(cameras, frames))
    images = render_rig_images(
        cameras, sc, rig, frames, t0_ns=t0_ns, supersample=supersample, noise=noise, seed=seed,
        mono=mono,
    )  # fmt: skip
    return list(images), rig


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
) -> Iterator[RigFrameSim]:
    """Yield every camera's rendered frames (``frames`` per camera; :func:`render_rig_images`),
    sorted by stamp, each with its front end's correspondences and the rig's pose at its
    reference line.

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
    trajectory = trajectory or rig_trajectory("pan", sc, _duration(cameras, frames))
    make_fe = frontend or (lambda name: ArucoFrontend.from_scene(sc))
    by_name = {c.name: (c.camera, make_fe(c.name)) for c in cameras}
    images = render_rig_images(
        cameras, sc, trajectory, frames, t0_ns=t0_ns, stamp_row=stamp_row,
        supersample=supersample, noise=noise, seed=seed,
    )  # fmt: skip
    for f in images:
        camera, fe = by_name[f.name]
        tic = time.process_time()
        uv, xyz, ids = fe.process(f.image, camera)
        f.uv, f.xyz = np.asarray(uv, float).reshape(-1, 2), np.asarray(xyz, float).reshape(-1, 3)
        f.ids = np.asarray(ids, np.uint32).reshape(-1)
        f.frontend_s = time.process_time() - tic
        yield f
