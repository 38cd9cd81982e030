"""Rolling-shutter image rendering (ROS-free): scenes, motions, renderer, bags.

from rs_localizer.sim.render import load_scene, make_motion, Renderer, camera_preset
scene = load_scene("aruco_room")
camera = camera_preset("vga")                      # 640x480, 30 ms readout, mild distortion
motion = make_motion("shake", scene, duration=1.0)
frame = Renderer(scene, camera).render(motion, t_first=0.1)
frame.image, frame.orientation, frame.position, frame.angular_velocity, frame.line_times

A rig's cameras rendered at their mounting-composed poses: ``render_rig_images``,
``render_rig_video`` (``rendered_rig``, ``vga_rig``; the rig's motion: ``rig_trajectory``).
"""

from .motion import MOTIONS, Motion, make_motion, motion_names, rig_trajectory
from .renderer import (
    CAMERA_PRESETS,
    RIG_TIMING,
    NoiseModel,
    RenderedFrame,
    Renderer,
    camera_preset,
    camera_rays,
    frame_times,
    render_rig_frames,
    render_rig_images,
    render_rig_video,
    rendered_rig,
    vga_rig,
)
from .scene import Scene, load_scene, scene_names

__all__ = [
    "CAMERA_PRESETS",
    "MOTIONS",
    "RIG_TIMING",
    "Motion",
    "NoiseModel",
    "RenderedFrame",
    "Renderer",
    "Scene",
    "camera_preset",
    "camera_rays",
    "frame_times",
    "load_scene",
    "make_motion",
    "motion_names",
    "render_rig_frames",
    "render_rig_images",
    "render_rig_video",
    "rendered_rig",
    "rig_trajectory",
    "scene_names",
    "vga_rig",
]
