"""Rendered rolling-shutter videos with their truth, shared by the front-end and benchmark
tests."""

import numpy as np

from rs_localizer.sim.feature_map import build_feature_map
from rs_localizer.sim.render.motion import make_motion
from rs_localizer.sim.render.renderer import NoiseModel, Renderer, camera_preset
from rs_localizer.sim.render.scene import load_scene


def shake_video(seconds: float, frames: int, seed: int):
    """A hand-held 640x480 video of ``textured_room`` with the SIFT map of four still views
    of its path: (map, rendered frames, camera, renderer, motion)."""
    scene = load_scene("textured_room")
    camera = camera_preset("vga")
    motion = make_motion("shake", scene, duration=seconds)
    fmap = build_feature_map(
        scene,
        camera_preset("vga", line_delay=0.0),
        (motion, np.linspace(0.0, seconds, 4)),
        kind="sift",
        n_features=1500,
    )
    renderer = Renderer(scene, camera, noise=NoiseModel())
    rendered = list(renderer.render_sequence(motion, frames, seed=seed))
    return fmap, rendered, camera, renderer, motion
