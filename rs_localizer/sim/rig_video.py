"""Synthetic video of a rig of rolling-shutter cameras (ROS-free): each camera its own timing.

A rig (base frame: x forward, y left, z up, REP 103) walks down the corridor of
:func:`~rs_localizer.sim.trajectory.make_scene` along a :class:`RigTrajectory` (the camera
walk of :class:`~rs_localizer.sim.trajectory.Trajectory` turned into the base frame: turning
up to ~1.7 rad/s). Cameras are mounted on it (:class:`RigCameraSim`: the camera's optical
frame's pose on the rig) and run free: each its own frame rate, first-frame offset, readout
direction and line delay, dropped frames, a time its frames stop. Every landmark is projected
with the camera's pose at the capture time of its own line
(:func:`~rs_localizer.sim.trajectory.project_rs`), so the frames are what unsynchronized RS
cameras on one body would measure. Ground truth: the rig's pose and velocities at any time
(:func:`rig_truth`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..camera import CameraModel
from ..frames import Mounting
from ..geometry import rotvec_to_matrix
from .trajectory import R_FORWARD, Scene, Trajectory, default_camera, make_scene, project_rs

__all__ = [
    "MountedTrajectory",
    "RigCameraSim",
    "RigFrameSim",
    "RigTrajectory",
    "default_rig",
    "generate_rig_video",
    "rig_gyro",
    "rig_truth",
]


@dataclass(frozen=True)
class RigTrajectory:
    """The rig's motion: ``orientation(t)`` (..., 3, 3) rig -> world and ``position(t)``
    (..., 3) m, the rig origin in the world; the base frame is x forward, y left, z up. The
    camera walk ``base`` (:class:`~rs_localizer.sim.trajectory.Trajectory`, or a renderer
    motion of :func:`~rs_localizer.sim.render.motion.make_motion`; optical-frame axes) turned
    into it: ``R_rig(t) = R_cam(t) R_FORWARD^T``."""

    base: Trajectory = field(default_factory=Trajectory)

    def orientation(self, t: float | np.ndarray) -> np.ndarray:
        return self.base.orientation(t) @ R_FORWARD.T

    def position(self, t: float | np.ndarray) -> np.ndarray:
        return self.base.position(t)

    def pose(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.orientation(t), self.position(t)

    #: (angular (rad/s), linear (m/s) velocity) in the rig frame, by central differences
    velocity_body = Trajectory.velocity_body


@dataclass(frozen=True)
class MountedTrajectory:
    """A camera's trajectory: the rig's (``rig``) with the camera's mounting (``R_rig_cam``
    (3, 3) optical frame -> rig, ``p_rig_cam`` (3,) m); ``pose(t)``: (orientation (..., 3, 3)
    camera -> world, position (..., 3) m) at rig time(s) ``t`` (s); what the renderer takes."""

    rig: RigTrajectory
    R_rig_cam: np.ndarray
    p_rig_cam: np.ndarray

    def pose(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        R, p = self.rig.pose(t)
        return R @ self.R_rig_cam, p + R @ self.p_rig_cam

    def orientation(self, t: float | np.ndarray) -> np.ndarray:
        return self.pose(t)[0]

    def position(self, t: float | np.ndarray) -> np.ndarray:
        return self.pose(t)[1]

    #: (angular (rad/s), linear (m/s) velocity) in the camera frame, by central differences
    velocity_body = Trajectory.velocity_body


@dataclass(frozen=True, eq=False)
class RigCameraSim:
    """One camera of the simulated rig.

    Attributes:
        name: the camera's name. camera: its intrinsics and RS timing.
        R_rig_cam: (3, 3) camera optical frame -> rig frame rotation (the camera's orientation
            on the rig). p_rig_cam: (3,) m, its optical centre in the rig frame.
        offset: s, the first line of its frame k is read at ``offset + k / fps`` (rig time).
        fps: frames per second.
        drop: frame indices left out (the camera skipped them).
        stop: s (rig time): no frames from then on (None: never).
    """

    name: str
    camera: CameraModel
    R_rig_cam: np.ndarray
    p_rig_cam: np.ndarray
    offset: float = 0.0
    fps: float = 30.0
    drop: tuple = ()
    stop: float | None = None

    @property
    def mounting(self) -> Mounting:
        """The camera's :class:`~rs_localizer.frames.Mounting` on the rig (of ``R_rig_cam``
        and ``p_rig_cam``)."""
        return Mounting.from_pose(self.R_rig_cam, self.p_rig_cam)


@dataclass
class RigFrameSim:
    """One camera frame. ``stamp_ns``: capture time of line ``stamp_row`` (the header stamp);
    ``t_ref_ns``: of the camera's reference line. ``inlier`` (N,): False for the synthetic
    outliers. ``orientation`` (3, 3) rig -> world and ``position`` (3,) m: the rig at
    ``t_ref_ns``."""

    name: str
    index: int
    stamp_ns: int
    t_ref_ns: int
    uv: np.ndarray
    xyz: np.ndarray
    inlier: np.ndarray
    orientation: np.ndarray
    position: np.ndarray


def _yaw(deg: float) -> np.ndarray:
    return rotvec_to_matrix(np.array([0.0, 0.0, np.radians(deg)]))


def default_rig(num_cameras: int = 3, offsets_s: tuple = (0.0, 0.004, 0.008, 0.003)) -> list:
    """``num_cameras`` (1-4) cameras looking front, left, right and back, 10-20 cm off the rig
    origin, 1280x720 with different line delays (30, 25, 20 us/line, 28 us/row) and readout
    directions (top-down, bottom-up, left-right, top-down), first frames ``offsets_s`` apart.

    Raises:
        ValueError: ``num_cameras`` outside 1-4.
    """
    if not 1 <= num_cameras <= 4:
        raise ValueError(f"num_cameras must be 1-4, got {num_cameras}")
    spec = [
        ("front", 0.0, (0.15, 0.0, 0.10), 30e-6, "top_to_bottom"),
        ("left", 90.0, (0.0, 0.12, 0.12), 25e-6, "bottom_to_top"),
        ("right", -90.0, (0.0, -0.12, 0.12), 20e-6, "left_to_right"),
        ("back", 180.0, (-0.15, 0.0, 0.10), 28e-6, "top_to_bottom"),
    ]
    out = []
    for k, (name, yaw, pos, delay, readout) in enumerate(spec[:num_cameras]):
        cam = default_camera(line_delay=delay, readout=readout)
        out.append(RigCameraSim(name, cam, _yaw(yaw) @ R_FORWARD, np.array(pos), offsets_s[k % 4]))
    return out


def rig_truth(trajectory: RigTrajectory, t: float) -> tuple:
    """(orientation (3, 3) rig -> world, position (3,) m, angular velocity (3,) rad/s, linear
    velocity (3,) m/s; velocities in the rig frame) at rig time ``t`` (s)."""
    R, p = trajectory.pose(t)
    w, v = trajectory.velocity_body(t)
    return R, p, w, v


def generate_rig_video(
    cameras: list,
    duration: float = 1.0,
    num_points: int = 200,
    noise_px: float = 0.5,
    outlier_ratio: float = 0.2,
    seed: int = 0,
    t0_ns: int = 1_700_000_000_000_000_000,
    stamp_row: float = 0.0,
    trajectory: RigTrajectory | None = None,
    scene: Scene | None = None,
) -> tuple[list[RigFrameSim], Scene, RigTrajectory]:
    """Every camera's frames over ``duration`` s, sorted by stamp (ties: the cameras' order).

    Per frame: ``num_points`` of the landmarks visible in the RS image (drawn from twice as
    many landmarks in the camera's view; fewer when fewer are visible), Gaussian pixel noise
    ``noise_px``, a fraction ``outlier_ratio`` replaced by uniformly random pixels. Rig time
    ``t`` is stamped ``t0_ns + t * 1e9`` ns.

    Returns:
        (frames, scene, trajectory); the scene: a 40 m corridor from x = -10 m, 12000 landmarks.
    """
    rng = np.random.default_rng(seed)
    trajectory = trajectory or RigTrajectory()
    scene = scene or make_scene(rng, 12000, length=40.0, x0=-10.0)
    frames = []
    for rc in cameras:
        cam = rc.camera
        mounted = MountedTrajectory(
            trajectory, np.asarray(rc.R_rig_cam, float), np.asarray(rc.p_rig_cam)
        )
        lim = np.array([cam.width, cam.height]) / np.diag(cam.K)[:2]
        k = 0
        while True:
            t_first = rc.offset + k / rc.fps
            if t_first >= duration or (rc.stop is not None and t_first >= rc.stop):
                break
            t_ref = t_first + float(cam.line_time(cam.reference_line))
            Rc, pc = mounted.pose(t_ref)
            Xc = (scene.points - pc) @ Rc
            z = np.where(Xc[:, 2] > 0.3, Xc[:, 2], np.inf)
            near = np.all(np.abs(Xc[:, :2] / z[:, None]) < 0.6 * lim, axis=1)  # (the view)
            cand = np.flatnonzero((Xc[:, 2] > 0.3) & (Xc[:, 2] < 25.0) & near)
            if len(cand) > 2 * num_points:  # (the exact projection of twice as many)
                cand = np.sort(rng.choice(cand, 2 * num_points, replace=False))
            uv, ok = project_rs(cam, mounted, t_first, scene.points[cand])
            vis, uv = cand[ok], uv[ok]
            n = min(num_points, len(vis))
            pick = rng.choice(len(vis), n, replace=False)
            xyz = scene.points[vis[pick]]
            noisy = uv[pick] + rng.normal(0.0, noise_px, (n, 2))
            inlier = rng.random(n) >= outlier_ratio
            noisy[~inlier] = rng.uniform([0, 0], [cam.width - 1, cam.height - 1], (n, 2))[~inlier]
            if k not in rc.drop:
                R, p = trajectory.pose(t_ref)
                stamp = t_first + float(cam.line_time(stamp_row))
                frames.append(
                    RigFrameSim(
                        rc.name,
                        k,
                        t0_ns + int(round(stamp * 1e9)),
                        t0_ns + int(round(t_ref * 1e9)),
                        noisy,
                        xyz,
                        inlier,
                        R,
                        p,
                    )
                )
            k += 1
    order = {rc.name: i for i, rc in enumerate(cameras)}
    frames.sort(key=lambda f: (f.stamp_ns, order[f.name]))
    return frames, scene, trajectory


def rig_gyro(
    trajectory: RigTrajectory,
    duration: float,
    rate_hz: float = 400.0,
    R_rig_imu: np.ndarray | None = None,
    bias: np.ndarray | None = None,
    noise: float = 0.003,
    seed: int = 0,
    t0_ns: int = 1_700_000_000_000_000_000,
    margin: float = 0.05,
) -> tuple[np.ndarray, np.ndarray]:
    """A gyro on the rig: its samples over ``[-margin, duration + margin]`` s of rig time.

    ``omega_imu = R_rig_imu^T omega_rig + bias + n`` (``omega_rig`` the trajectory's angular
    velocity in the rig frame, :func:`rig_truth`; ``n`` Gaussian, ``noise`` rad/s per axis),
    stamped ``t0_ns + t * 1e9`` ns as :func:`generate_rig_video`'s frames.

    Args:
        trajectory: the rig's. duration: s. rate_hz: samples per second.
        R_rig_imu: (3, 3) rotation IMU -> rig frame (default identity). bias: (3,) rad/s, IMU
            frame (default zero). noise: rad/s. seed: of the noise.
    Returns:
        (stamps (M,) int64 ns, rates (M, 3) rad/s, IMU frame).
    """
    rng = np.random.default_rng(seed)
    t = np.arange(-margin, duration + margin, 1.0 / rate_hz)
    w, _ = trajectory.velocity_body(t)
    R = np.eye(3) if R_rig_imu is None else np.asarray(R_rig_imu, dtype=float)
    b = np.zeros(3) if bias is None else np.asarray(bias, dtype=float)
    rates = w @ R + b + rng.normal(0.0, noise, (len(t), 3))
    return t0_ns + np.round(t * 1e9).astype(np.int64), rates
