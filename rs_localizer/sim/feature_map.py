"""Feature maps of simulated scenes: global-shutter renders at known poses, reconstructed by
:func:`rs_localizer.frontends.features.feature_map_from_views` (the paper's real-data protocol:
a 3D map built from global-shutter views), and the poses of photos to build one from
(:func:`photo_walk`)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..camera import CameraModel
from ..frontends import feature_map_from_views
from ..maps.features import FeatureMap
from .render.motion import base_rotation
from .render.renderer import Renderer
from .render.scene import Scene

__all__ = ["build_feature_map", "photo_walk"]


def build_feature_map(
    scene: Scene,
    camera: CameraModel,
    poses: Sequence[tuple[np.ndarray, np.ndarray]],
    kind: str = "orb",
    n_features: int = 2000,
    merge_radius: float = 0.004,
    edge_margin_px: float = 2.0,
    supersample: int = 2,
    descriptors_per_landmark: int = 1,
) -> FeatureMap:
    """Reconstruct a feature map from global-shutter renders of ``scene`` at known ``poses``.

    Args:
        scene: :class:`~rs_localizer.sim.render.scene.Scene`. camera: its intrinsics/distortion
            (the line delay is ignored: the map views are global shutter).
        poses: iterable of (orientation camera -> world (3, 3), position (3,)); or a motion
            with ``pose(t)`` plus times: ``(motion, times)``.
        kind, n_features, merge_radius, edge_margin_px, descriptors_per_landmark: see
            :func:`~rs_localizer.frontends.features.feature_map_from_views`.
        supersample: anti-aliasing samples per axis of the renders.
    Returns:
        :class:`~rs_localizer.maps.features.FeatureMap`.
    """
    if isinstance(poses, tuple) and len(poses) == 2 and hasattr(poses[0], "pose"):
        motion, times = poses
        R, p = motion.pose(np.asarray(times, dtype=float))
        poses = list(zip(R, p, strict=False))
    renderer = Renderer(scene, camera, supersample=supersample)

    def views():
        for R, p in poses:

            def backproject(uv, pose=(R, p)):
                X, quad, _ = renderer.cast(uv, pose=pose)
                return X, quad

            yield renderer.render_pose(R, p, mono=True), backproject

    return feature_map_from_views(
        views(),
        kind=kind,
        n_features=n_features,
        merge_radius=merge_radius,
        edge_margin_px=edge_margin_px,
        descriptors_per_landmark=descriptors_per_landmark,
    )


def photo_walk(n: int) -> list:
    """(orientation camera -> world (3, 3), centre (3,) m) of ``n`` photos on a slow walk
    through ``textured_room``: 1.4 m forward, weaving +-0.5 m, looking +-35 deg around."""
    out = []
    for s in np.linspace(0.0, 1.0, int(n)):
        pos = np.array(
            [0.6 + 1.4 * s, 0.5 * np.sin(2 * np.pi * s), 1.45 + 0.05 * np.sin(4 * np.pi * s)]
        )
        yaw = np.deg2rad(35 * np.sin(3 * np.pi * s))
        pitch = np.deg2rad(-12 + 6 * np.cos(2 * np.pi * s))
        out.append((base_rotation(yaw, pitch), pos))
    return out
