"""Continuous-time camera trajectories for the renderer.

:class:`Motion` extends :class:`rs_localizer.sim.trajectory.Trajectory` (same sinusoidal rotation
model, same ground-truth velocities by central differences of the trajectory) with a base
viewing direction (yaw, pitch) and translation terms expressed in that base camera frame
(x right, y down, z forward), centred on ``t_center`` so that a sequence of ``duration`` seconds
stays around the scene's viewpoint:

    p(t) = p0 + R_base (velocity (t - t_center) + sway sin(2 pi sway_hz t + phase[:3]))
    R(t) = R_base expm([a(t)]x),  a(t) = rot_amp sin(...) + shake_amp sin(...)  (camera axes)

``R(t)`` is camera -> world (world z up), ``p(t)`` the camera centre. None of these motions is
the solvers' constant-velocity model: the angular velocity changes within a readout.

Presets (:data:`MOTIONS`, :func:`make_motion`): ``shake`` (hand-held look-around with head
shake, ~1 rad/s), ``pan`` (fast pan, ~1.3 rad/s), ``walk`` (1.2 m/s forward with bob and sway),
``drone`` (2.5 m/s sideways fly-by, slow yaw, high-frequency vibration), ``car`` (pure
translation, 3 m/s sideways, no rotation), ``static``. A rig's motion: a preset turned into the
rig's base frame (:func:`rig_trajectory`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ...geometry import rotvec_to_matrix
from ..trajectory import R_FORWARD, RigTrajectory, Trajectory

__all__ = [
    "MOTIONS",
    "Motion",
    "base_rotation",
    "make_motion",
    "motion_names",
    "rig_trajectory",
]


def base_rotation(yaw: float, pitch: float) -> np.ndarray:
    """Camera -> world rotation looking along ``yaw`` (about world z, 0 = +x) tilted up by
    ``pitch`` (rad)."""
    cy, sy = np.cos(yaw), np.sin(yaw)
    cp, sp = np.cos(pitch), np.sin(pitch)
    Rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]])
    return Rz @ R_FORWARD @ Rx


@dataclass(frozen=True)
class Motion(Trajectory):
    """A :class:`~rs_localizer.sim.trajectory.Trajectory` with a base view direction and
    translation in the base camera frame (see the module docstring). ``velocity``, ``sway``:
    base camera frame (m/s, m)."""

    name: str = "custom"
    yaw: float = 0.0
    pitch: float = 0.0
    t_center: float = 0.0

    @property
    def R_base(self) -> np.ndarray:
        return base_rotation(self.yaw, self.pitch)

    def position(self, t: float | np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)[..., None]
        local = np.asarray(self.velocity) * (t - self.t_center) + np.asarray(self.sway) * np.sin(
            2 * np.pi * np.asarray(self.sway_hz) * t + np.asarray(self.phase[:3])
        )
        return np.asarray(self.p0) + local @ self.R_base.T

    def orientation(self, t: float | np.ndarray) -> np.ndarray:
        return self.R_base @ rotvec_to_matrix(self._angles(t))

    def peak_rates(self, duration: float, fps: float = 200.0) -> tuple[float, float]:
        """(max |angular velocity| rad/s, max |linear velocity| m/s) over ``[0, duration]``."""
        t = np.linspace(0.0, duration, max(int(duration * fps), 2))
        w, v = self.velocity_body(t)
        return float(np.linalg.norm(w, axis=1).max()), float(np.linalg.norm(v, axis=1).max())


_ZERO = (0.0, 0.0, 0.0)

#: preset name -> Trajectory/Motion field overrides (base camera frame: x right, y down, z fwd)
MOTIONS = {
    "shake": dict(
        velocity=_ZERO,
        sway=(0.05, 0.03, 0.04),
        sway_hz=(0.9, 1.4, 0.7),
        rot_amp=(0.05, 0.10, 0.03),
        rot_hz=(0.8, 0.6, 0.7),
        shake_amp=(0.02, 0.035, 0.012),
        shake_hz=(2.7, 3.1, 2.3),
        phase=(0.3, -0.6, 2.0, 0.7, 1.9, 0.4),
    ),
    "pan": dict(
        velocity=_ZERO,
        sway=(0.02, 0.01, 0.01),
        sway_hz=(0.5, 0.9, 0.6),
        rot_amp=(0.05, 0.45, 0.02),
        rot_hz=(0.4, 0.45, 0.5),
        shake_amp=(0.003, 0.004, 0.002),
        shake_hz=(6.3, 5.1, 7.7),
        phase=(0.3, -0.2, 2.0, 0.7, 1.9, 0.4),
    ),
    "walk": dict(
        velocity=(0.0, 0.0, 1.2),
        sway=(0.04, 0.035, 0.0),
        sway_hz=(0.9, 1.8, 0.0),
        rot_amp=(0.03, 0.08, 0.02),
        rot_hz=(0.9, 0.45, 0.9),
        shake_amp=(0.004, 0.005, 0.003),
        shake_hz=(6.3, 5.1, 7.7),
        phase=(0.3, -0.6, 2.0, 0.7, 1.9, 0.4),
    ),
    "drone": dict(
        velocity=(2.5, 0.0, 0.0),
        sway=(0.0, 0.02, 0.02),
        sway_hz=(0.0, 0.7, 0.5),
        rot_amp=(0.03, 0.25, 0.04),
        rot_hz=(0.3, 0.25, 0.35),
        shake_amp=(0.002, 0.003, 0.002),
        shake_hz=(13.0, 17.0, 11.0),
        phase=(0.3, -1.2, 2.0, 0.7, 1.9, 0.4),
    ),
    "car": dict(
        velocity=(3.0, 0.0, 0.0),
        sway=(0.0, 0.004, 0.0),
        sway_hz=(0.0, 7.0, 0.0),
        rot_amp=_ZERO,
        rot_hz=(1.0, 1.0, 1.0),
        shake_amp=_ZERO,
        shake_hz=(1.0, 1.0, 1.0),
        phase=(0.0,) * 6,
    ),
    "static": dict(
        velocity=_ZERO,
        sway=_ZERO,
        sway_hz=(1.0, 1.0, 1.0),
        rot_amp=_ZERO,
        rot_hz=(1.0, 1.0, 1.0),
        shake_amp=_ZERO,
        shake_hz=(1.0, 1.0, 1.0),
        phase=(0.0,) * 6,
    ),
}


def motion_names() -> list:
    return sorted(MOTIONS)


def make_motion(
    name: str,
    scene: Any = None,
    position: np.ndarray | None = None,
    yaw: float | None = None,
    pitch: float | None = None,
    duration: float = 1.0,
    scale: float = 1.0,
    **overrides: Any,
) -> Motion:
    """A preset motion around a viewpoint.

    Args:
        name: one of :data:`MOTIONS`.
        scene: a :class:`~rs_localizer.sim.render.scene.Scene`; its viewpoint gives the default
            position, yaw and pitch.
        position, yaw, pitch: override the viewpoint (m, rad).
        duration: sequence length (s); translation is centred on ``duration / 2``.
        scale: multiplies the rotation amplitudes (like ``Trajectory.scale``).
        overrides: any other :class:`Motion` field.
    Raises:
        ValueError: unknown preset.
    """
    if name not in MOTIONS:
        raise ValueError(f"unknown motion {name!r}; expected one of {motion_names()}")
    p0, y0, pt0 = np.array([0.0, 0.0, 1.5]), 0.0, 0.0
    if scene is not None:
        p0, y0, pt0 = scene.viewpoint_pose()
    if position is not None:
        p0 = np.asarray(position, dtype=float)
    fields = dict(MOTIONS[name])
    fields.update(overrides)
    m = Motion(
        p0=tuple(float(x) for x in p0),
        name=name,
        yaw=float(y0 if yaw is None else yaw),
        pitch=float(pt0 if pitch is None else pitch),
        t_center=0.5 * float(duration),
        scale=float(scale),
    )
    return replace(m, **fields)


def rig_trajectory(
    motion: str = "pan", scene: Any = None, duration: float = 1.0, scale: float = 1.0
) -> RigTrajectory:
    """A rig's motion: the preset ``motion`` (``pan``: turning ~1.3 rad/s at ``scale`` 1;
    ``shake``, ``walk``, ...) around ``scene``'s viewpoint, rotation amplitudes times ``scale``,
    its camera axes turned into the rig's base frame (x forward, y left, z up:
    :class:`~rs_localizer.sim.trajectory.RigTrajectory`). Raises ValueError for an unknown
    preset."""
    return RigTrajectory(make_motion(motion, scene, duration=duration, scale=scale))
