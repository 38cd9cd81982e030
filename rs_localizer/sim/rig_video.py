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

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..camera import CameraModel
from ..frames import Mounting
from ..geometry import rotvec_to_matrix
from .trajectory import (
    R_FORWARD,
    Scene,
    Trajectory,
    default_camera,
    imu_samples,
    make_scene,
    project_rs,
    truth_at,
)

__all__ = [
    "PLACES",
    "MountedTrajectory",
    "RigCameraSim",
    "RigFrameSim",
    "RigTrajectory",
    "default_rig",
    "generate_rig_video",
    "rig_gyro",
    "rig_truth",
]


@dataclass(frozen=True, eq=False)
class MountedTrajectory:
    """A body's trajectory carried by another's: the carrier's motion ``base`` (``pose(t)``)
    with the body fixed on it, turned by ``R_base_body`` (3, 3) body -> carrier and at
    ``p_base_body`` (3,) m in the carrier's frame (None: at its origin). ``pose(t)``:
    (orientation (..., 3, 3) body -> world, position (..., 3) m) at time(s) ``t`` (s); what
    the renderer and :func:`~rs_localizer.sim.trajectory.project_rs` take. A camera on the
    rig (:meth:`RigCameraSim.on`), the rig on the camera walk (:class:`RigTrajectory`)."""

    base: Any
    R_base_body: np.ndarray
    p_base_body: np.ndarray | None = None

    def pose(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        R, p = self.base.pose(t)
        if self.p_base_body is None:
            return R @ self.R_base_body, p
        return R @ self.R_base_body, p + R @ self.p_base_body

    def orientation(self, t: float | np.ndarray) -> np.ndarray:
        return self.pose(t)[0]

    def position(self, t: float | np.ndarray) -> np.ndarray:
        return self.pose(t)[1]

    #: (angular (rad/s), linear (m/s) velocity) in the body frame, by central differences
    velocity_body = Trajectory.velocity_body


class RigTrajectory(MountedTrajectory):
    """The rig's motion (base frame x forward, y left, z up): the camera walk ``base``
    (:class:`~rs_localizer.sim.trajectory.Trajectory` by default, or a renderer motion of
    :func:`~rs_localizer.sim.render.motion.make_motion`; optical-frame axes) turned into it,
    ``R_rig(t) = R_cam(t) R_FORWARD^T``, the rig's origin at the camera's centre."""

    def __init__(self, base: Any = None):
        super().__init__(Trajectory() if base is None else base, R_FORWARD.T)


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

    def on(self, rig: Any) -> MountedTrajectory:
        """The camera's trajectory: the rig's motion ``rig`` with its mounting."""
        return MountedTrajectory(rig, np.asarray(self.R_rig_cam, float), np.asarray(self.p_rig_cam))

    @classmethod
    def facing(
        cls,
        name: str,
        camera: CameraModel,
        yaw_deg: float,
        position: tuple | np.ndarray,
        offset: float = 0.0,
        fps: float = 30.0,
    ) -> RigCameraSim:
        """``camera`` turned ``yaw_deg`` about the base z axis from looking forward (along x),
        its optical centre at ``position`` (m, base frame); ``offset``, ``fps`` as the
        attributes."""
        R = rotvec_to_matrix(np.array([0.0, 0.0, np.radians(yaw_deg)])) @ R_FORWARD
        return cls(name, camera, R, np.array(position, float), offset, float(fps))


#: name -> (yaw deg about the base z axis, optical centre (m) in the base frame) of the
#: simulated rigs' cameras (:func:`default_rig`, :func:`~rs_localizer.sim.render.rig.rendered_rig`)
PLACES = {
    "front": (0.0, (0.15, 0.0, 0.10)),
    "left": (90.0, (0.0, 0.12, 0.12)),
    "right": (-90.0, (0.0, -0.12, 0.12)),
    "back": (180.0, (-0.15, 0.0, 0.10)),
}


@dataclass
class RigFrameSim:
    """One camera frame of a rig video, simulated (:func:`generate_rig_video`) or rendered
    (:func:`~rs_localizer.sim.render.rig.render_rig_video`). ``stamp_ns``: capture time of line
    ``stamp_row`` (the header stamp); ``t_ref_ns``: of the camera's reference line. ``uv``
    (N, 2) px, ``xyz`` (N, 3) m (map frame): its correspondences. ``orientation`` (3, 3) rig ->
    world and ``position`` (3,) m: the rig at ``t_ref_ns``. ``inlier`` (N,): False for the
    synthetic outliers (None: rendered). Rendered: ``image`` (H, W, 3) uint8 RGB, ``ids``
    (N,) the front end's (marker corners: ``4 * marker id + corner``), ``render_s`` and
    ``frontend_s`` the CPU time of rendering and of the front end, s."""

    name: str
    index: int
    stamp_ns: int
    t_ref_ns: int
    uv: np.ndarray
    xyz: np.ndarray
    orientation: np.ndarray
    position: np.ndarray
    inlier: np.ndarray | None = None
    image: np.ndarray | None = None
    ids: np.ndarray | None = None
    render_s: float = 0.0
    frontend_s: float = 0.0


def default_rig(num_cameras: int = 3, offsets_s: tuple = (0.0, 0.004, 0.008, 0.003)) -> list:
    """``num_cameras`` (1-4) cameras looking front, left, right and back (:data:`PLACES`),
    1280x720 with different line delays (30, 25, 20 us/line, 28 us/row) and readout
    directions (top-down, bottom-up, left-right, top-down), first frames ``offsets_s`` apart.

    Raises:
        ValueError: ``num_cameras`` outside 1-4.
    """
    if not 1 <= num_cameras <= 4:
        raise ValueError(f"num_cameras must be 1-4, got {num_cameras}")
    spec = [("front", 30e-6, "top_to_bottom"), ("left", 25e-6, "bottom_to_top"),
            ("right", 20e-6, "left_to_right"), ("back", 28e-6, "top_to_bottom")]  # fmt: skip
    cams = [(name, default_camera(line_delay=delay, readout=readout), *PLACES[name])
            for name, delay, readout in spec[:num_cameras]]  # fmt: skip
    return [RigCameraSim.facing(*c, offsets_s[k % 4]) for k, c in enumerate(cams)]


#: (orientation (3, 3) rig -> world, position (3,) m, angular velocity (3,) rad/s, linear
#: velocity (3,) m/s; velocities in the rig frame) of a rig's trajectory at rig time ``t`` (s)
rig_truth = truth_at


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
        mounted = rc.on(trajectory)
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
                    RigFrameSim(rc.name, k, t0_ns + int(round(stamp * 1e9)),
                                t0_ns + int(round(t_ref * 1e9)), noisy, xyz, R, p, inlier)
                )  # fmt: skip
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
    velocity in the rig frame, :func:`rig_truth`; ``n`` Gaussian, ``noise`` rad/s per axis):
    the gyro of :func:`~rs_localizer.sim.trajectory.imu_samples` at the rig's origin, stamped
    ``t0_ns + t * 1e9`` ns as :func:`generate_rig_video`'s frames.

    Args:
        trajectory: the rig's. duration: s. rate_hz: samples per second.
        R_rig_imu: (3, 3) rotation IMU -> rig frame (default identity). bias: (3,) rad/s, IMU
            frame (default zero). noise: rad/s. seed: of the noise.
    Returns:
        (stamps (M,) int64 ns, rates (M, 3) rad/s, IMU frame).
    """
    R = np.eye(3) if R_rig_imu is None else np.asarray(R_rig_imu, dtype=float)
    b = np.zeros(3) if bias is None else np.asarray(bias, dtype=float)
    t, rates, _ = imu_samples(trajectory, -margin, duration + margin, rate_hz, seed, noise, b,
                              R_imu_camera=R.T)  # fmt: skip
    return t0_ns + np.round(t * 1e9).astype(np.int64), rates
