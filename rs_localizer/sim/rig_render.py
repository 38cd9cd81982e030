"""Rendered images of a rig of rolling-shutter cameras (ROS-free): each camera's view of a
marker scene rendered at its own mounting-composed poses, with its own timing.

The rig (base frame: x forward, y left, z up, REP 103) moves along one of the renderer's
motions (:func:`~rs_localizer.sim.render.motion.make_motion`, a camera's motion in optical axes)
turned into the base frame: ``R_rig(t) = R_motion(t) R_FORWARD^T``. Each camera
(:class:`~rs_localizer.sim.rig_video.RigCameraSim`: its optical frame's pose on the rig, first
frame offset, frame rate) is rendered by :class:`~rs_localizer.sim.render.renderer.Renderer`
along :class:`~rs_localizer.sim.rig_video.MountedTrajectory`, the rig's motion
(:class:`~rs_localizer.sim.rig_video.RigTrajectory` of the renderer's motion) composed with its
mounting, every line at its own capture time. Ground truth:
:func:`~rs_localizer.sim.rig_video.rig_truth`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import rotvec_to_matrix
from .render.renderer import camera_preset
from .rig_video import MountedTrajectory, RigCameraSim, RigTrajectory
from .trajectory import R_FORWARD

__all__ = [
    "RenderedRigFrame",
    "render_rig_frames",
    "vga_rig",
]


def _yaw(deg: float) -> np.ndarray:
    return rotvec_to_matrix(np.array([0.0, 0.0, np.radians(deg)]))


def vga_rig(num_cameras: int = 3, offsets_s: tuple = (0.0, 0.004, 0.008)) -> list:
    """``num_cameras`` (1-3) 640x480 cameras (the renderer's ``vga`` preset, 30 ms readout)
    looking front, 35 deg left and 35 deg right, 5-15 cm off the rig origin, readouts
    top-down, bottom-up and left-right (62.5, 62.5 and 46.9 us/line), first frames
    ``offsets_s`` apart: a rig that sees the ``aruco_room`` walls from its viewpoint.

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
    out = []
    for k, (name, yaw, pos, readout) in enumerate(spec[:num_cameras]):
        cam = camera_preset("vga", readout=readout)
        out.append(RigCameraSim(name, cam, _yaw(yaw) @ R_FORWARD, np.array(pos), offsets_s[k]))
    return out


@dataclass(frozen=True, eq=False)
class RenderedRigFrame:
    """One camera's rendered frame: ``stamp_ns`` the capture time of its row 0 (the header
    stamp with ``rs.stamp_row = 0``; its first line read unless it reads bottom-up),
    ``image`` (480, 640, 3) uint8 RGB (or mono8), ``t_ref_ns`` its reference line's capture
    time."""

    name: str
    index: int
    stamp_ns: int
    t_ref_ns: int
    image: np.ndarray


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
) -> tuple[list[RenderedRigFrame], RigTrajectory]:
    """Render ``frames`` frames of every camera (frame ``k`` of camera c: its first line read
    at ``offset_c + k / fps_c`` s of rig time, stamped ``t0_ns`` + the capture time of its row
    0), sorted by stamp.

    Args:
        cameras: :class:`~rs_localizer.sim.rig_video.RigCameraSim` (e.g. :func:`vga_rig`).
        scene, motion: the renderer's scene and motion preset names (the motion spans the
            rendered time, around the scene's viewpoint).
        supersample, noise, mono: as :class:`~rs_localizer.sim.render.renderer.Renderer`.
    Returns:
        (frames, the rig's motion; :func:`~rs_localizer.sim.rig_video.rig_truth` gives its
        truth).
    """
    from .render.motion import make_motion
    from .render.renderer import NoiseModel, Renderer
    from .render.scene import load_scene

    sc = load_scene(scene)
    duration = max(c.offset + frames / c.fps for c in cameras)
    rig = RigTrajectory(make_motion(motion, sc, duration=duration))
    out = []
    for ci, c in enumerate(cameras):
        r = Renderer(sc, c.camera, supersample=supersample, noise=NoiseModel() if noise else None)
        mounted = MountedTrajectory(
            rig, np.asarray(c.R_rig_cam, float), np.asarray(c.p_rig_cam, float)
        )
        for k in range(int(frames)):
            t_first = c.offset + k / c.fps
            fr = r.render(
                mounted, t_first, index=k, mono=mono, rng=np.random.default_rng([seed, ci, k])
            )
            out.append(
                RenderedRigFrame(
                    c.name,
                    k,
                    fr.stamp_ns(t0_ns, 0.0, c.camera),
                    int(t0_ns) + int(round(fr.t_ref * 1e9)),
                    fr.image,
                )
            )
    order = {c.name: i for i, c in enumerate(cameras)}
    out.sort(key=lambda f: (f.stamp_ns, order[f.name]))
    return out, rig
