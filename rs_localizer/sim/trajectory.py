"""Synthetic rolling-shutter sequences (ROS-free): trajectory, scene, exact RS projection.

A camera moves along a smooth continuous-time trajectory (a walk at 1.2 m/s with sway and bob,
a quick look-around pan and tilt with slight hand shake: angular speeds up to ~1.7 rad/s, like a
hand-held phone or a head-mounted action camera) through a corridor of landmarks. Every
landmark is projected with the camera pose **at the capture time of its own line**: the line
constraint ``line = image_line(project(X, pose(t0 + line_time(line))))`` is solved by
fixed-point iteration, through the lens distortion (:meth:`CameraModel.distort`),
so the pixels are what a real RS sensor would measure. Ground truth per frame: the pose at the
reference line (camera -> world orientation, camera centre in the world) and the camera's angular
and linear velocity in its own optical frame, obtained by numerically differentiating the
trajectory (independent of any solver formula).

A rig of cameras is simulated by the same code: a camera on a body (:class:`RigCameraSim`: its
mounting, first-frame offset, frame rate) moves along the body's trajectory composed with its
mounting (:class:`MountedTrajectory`), and :func:`generate_rig_video` gives every camera's frames
(:func:`observe` of each, as :func:`generate_sequence` for one camera) sorted by stamp; the rig
(base frame x forward, y left, z up, REP 103) walks the camera walk turned into its base frame
(:class:`RigTrajectory`).

World frame: z up (ROS ``map`` convention). Camera optical frame (REP 103): z forward, x right,
y down.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..camera import CameraModel
from ..frames import Mounting
from ..geometry import matrix_to_rotvec, rotvec_to_matrix

__all__ = [
    "GRAVITY",
    "PLACES",
    "R_IMU_CAMERA",
    "TRAJECTORIES",
    "Frame",
    "MountedTrajectory",
    "RigCameraSim",
    "RigFrameSim",
    "RigTrajectory",
    "Scene",
    "SequenceConfig",
    "Teleport",
    "Trajectory",
    "default_camera",
    "default_rig",
    "generate_rig_video",
    "generate_sequence",
    "ground_truth",
    "imu_samples",
    "make_scene",
    "make_trajectory",
    "observe",
    "project_rs",
    "rig_gyro",
    "rig_truth",
    "truth_at",
]

#: camera looking along world +x with z up: columns are the camera x (right), y (down),
#: z (forward) axes in world coordinates
R_FORWARD = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def default_camera(
    line_delay: float = 30e-6,
    reference_row: float | None = None,
    distortion: bool = True,
    readout: str = "top_to_bottom",
) -> CameraModel:
    """A 1280x720 phone/action camera: fx ~ 1000 px (~65 deg horizontal FOV), mild barrel
    plumb_bob distortion, 30 us/row line delay (21.6 ms readout)."""
    K = np.array([[1002.5, 0.0, 641.3], [0.0, 1001.8, 358.2], [0.0, 0.0, 1.0]])
    D = np.array([0.062, -0.118, 4e-4, -3e-4, 0.041]) if distortion else np.zeros(0)
    return CameraModel(
        K=K,
        D=D,
        width=1280,
        height=720,
        line_delay=line_delay,
        readout=readout,
        reference_row=reference_row,
        distortion_model="plumb_bob",
    )


@dataclass(frozen=True)
class Trajectory:
    """Smooth camera motion: ``p(t)`` (camera centre, world) and ``R(t)`` (camera -> world).

    ``p(t) = p0 + v t + sway/bob sinusoids``;
    ``R(t) = R_FORWARD expm([a(t)]x)`` with ``a(t)`` a sum of sinusoids per camera axis (slow
    pan/tilt/roll plus a slight fast shake; angular accelerations stay below ~10 rad/s^2, so
    the velocity is nearly constant during one 22 ms readout). ``scale`` multiplies all rotation
    amplitudes.
    """

    p0: tuple = (0.0, 0.0, 1.5)
    velocity: tuple = (1.2, 0.0, 0.0)  # m/s, world
    sway: tuple = (0.0, 0.12, 0.05)  # m amplitude per world axis
    sway_hz: tuple = (0.0, 0.8, 1.8)
    rot_amp: tuple = (0.15, 0.60, 0.15)  # rad about camera x (tilt), y (pan), z (roll)
    rot_hz: tuple = (0.5, 0.4, 0.45)
    shake_amp: tuple = (0.003, 0.004, 0.002)  # rad, hand shake
    shake_hz: tuple = (6.3, 5.1, 7.7)
    phase: tuple = (0.3, -0.6, 2.0, 0.7, 1.9, 0.4)
    scale: float = 1.0

    def _angles(self, t):
        t = np.asarray(t, dtype=float)[..., None]
        ph = np.asarray(self.phase)
        a = np.asarray(self.rot_amp) * np.sin(
            2 * np.pi * np.asarray(self.rot_hz) * t + ph[:3]
        ) + np.asarray(self.shake_amp) * np.sin(2 * np.pi * np.asarray(self.shake_hz) * t + ph[3:])
        return self.scale * a

    def position(self, t: float | np.ndarray) -> np.ndarray:
        """(..., 3) camera centre in the world (m)."""
        t = np.asarray(t, dtype=float)[..., None]
        return (
            np.asarray(self.p0)
            + np.asarray(self.velocity) * t
            + np.asarray(self.sway)
            * np.sin(2 * np.pi * np.asarray(self.sway_hz) * t + np.asarray(self.phase[:3]))
        )

    def orientation(self, t: float | np.ndarray) -> np.ndarray:
        """(..., 3, 3) camera -> world rotation."""
        return R_FORWARD @ rotvec_to_matrix(self._angles(t))

    def pose(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.orientation(t), self.position(t)

    def velocity_body(
        self, t: float | np.ndarray, h: float = 1e-5
    ) -> tuple[np.ndarray, np.ndarray]:
        """Angular (rad/s) and linear (m/s) velocity of the camera in its optical frame by
        central differences of the trajectory: ``w = log(R(t-h)^T R(t+h)) / 2h``,
        ``v = R(t)^T (p(t+h) - p(t-h)) / 2h``."""
        t = np.asarray(t, dtype=float)
        Ra, Rb = self.orientation(t - h), self.orientation(t + h)
        w = matrix_to_rotvec(np.swapaxes(Ra, -1, -2) @ Rb) / (2 * h)
        dp = (self.position(t + h) - self.position(t - h)) / (2 * h)
        v = np.einsum("...ji,...j->...i", self.orientation(t), dp)
        return w, v


#: trajectory presets for video sequences in the corridor (:func:`make_trajectory`), as
#: :class:`Trajectory` field overrides: ``walk`` is the default trajectory above; ``car``
#: drives along the corridor at 5 m/s with a gentle suspension bounce and a vibration of the
#: mount (near-pure translation, < 0.1 rad/s); ``shake`` is a hand-held camera held nearly still
#: with a strong
#: 3.5-5 Hz shake (angular velocity up to ~1.5 rad/s, angular acceleration up to ~40 rad/s^2,
#: far from constant during a readout); ``pan`` looks around (~1.5 rad/s about the vertical
#: axis) while walking slowly, the motion for readout calibration.
TRAJECTORIES = {
    "walk": {},
    "car": dict(
        velocity=(5.0, 0.0, 0.0),
        sway=(0.0, 0.003, 0.002),
        sway_hz=(0.0, 1.3, 3.1),
        rot_amp=(0.003, 0.006, 0.002),
        rot_hz=(0.4, 0.3, 0.5),
        shake_amp=(0.0005, 0.0004, 0.0003),
        shake_hz=(11.0, 13.0, 9.0),
    ),
    "shake": dict(
        velocity=(0.2, 0.0, 0.0),
        sway=(0.0, 0.03, 0.02),
        sway_hz=(0.0, 1.1, 1.7),
        rot_amp=(0.08, 0.15, 0.05),
        rot_hz=(0.3, 0.25, 0.35),
        shake_amp=(0.03, 0.04, 0.015),
        shake_hz=(4.3, 3.6, 5.1),
    ),
    "pan": dict(
        velocity=(0.5, 0.0, 0.0),
        sway=(0.0, 0.05, 0.03),
        sway_hz=(0.0, 0.8, 1.6),
        rot_amp=(0.1, 0.8, 0.05),
        rot_hz=(0.3, 0.3, 0.25),
        shake_amp=(0.002, 0.003, 0.001),
        shake_hz=(6.3, 5.1, 7.7),
    ),
}


def make_trajectory(name: str = "walk", scale: float = 1.0) -> Trajectory:
    """A :data:`TRAJECTORIES` preset; ``scale`` multiplies its rotation amplitudes.

    Raises:
        ValueError: unknown preset name.
    """
    if name not in TRAJECTORIES:
        raise ValueError(f"unknown trajectory {name!r}; expected one of {sorted(TRAJECTORIES)}")
    return Trajectory(scale=float(scale), **TRAJECTORIES[name])


@dataclass(frozen=True)
class Teleport:
    """A trajectory that jumps to another place at ``time`` (s): from then on the camera is
    moved by ``offset`` (m, world) and turned by ``yaw`` (rad, about world z through its
    position), as a tracker sees a relocalization (a cut in a video, a kidnapped robot).
    Pose and velocities as :class:`Trajectory` (the velocities are continuous across the jump
    except for the rotation by ``yaw``)."""

    base: Trajectory
    time: float
    offset: tuple = (8.0, 0.0, 0.0)
    yaw: float = 0.7

    def _jumped(self, t):
        return np.asarray(t, dtype=float) >= self.time

    def position(self, t: float | np.ndarray) -> np.ndarray:
        p = self.base.position(t)
        return np.where(self._jumped(t)[..., None], p + np.asarray(self.offset), p)

    def orientation(self, t: float | np.ndarray) -> np.ndarray:
        R = self.base.orientation(t)
        Rz = rotvec_to_matrix(np.array([0.0, 0.0, self.yaw]))
        return np.where(self._jumped(t)[..., None, None], Rz @ R, R)

    def pose(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.orientation(t), self.position(t)

    velocity_body = Trajectory.velocity_body


#: rotation camera optical frame -> IMU frame of :func:`imu_samples` (IMU x forward, y left,
#: z up, the usual body convention): ``omega_imu = R_IMU_CAMERA omega_cam``
R_IMU_CAMERA = R_FORWARD.copy()
#: gravity in the world frame (m/s^2, z up)
GRAVITY = np.array([0.0, 0.0, -9.81])


def imu_samples(
    trajectory: Trajectory,
    t_start: float,
    t_end: float,
    rate: float,
    seed: int = 0,
    gyro_noise: float = 0.003,
    gyro_bias: tuple[float, float, float] | np.ndarray = (0.01, -0.02, 0.005),
    accel_noise: float = 0.05,
    R_imu_camera: np.ndarray = R_IMU_CAMERA,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gyro and accelerometer samples of an IMU rigidly mounted on the camera (same origin).

    Args:
        trajectory: a :class:`Trajectory` (or anything with ``orientation``, ``position`` and
            ``velocity_body``).
        t_start, t_end: seconds (trajectory time); rate: samples per second.
        seed, gyro_noise (rad/s per sample), gyro_bias (3,) rad/s, accel_noise (m/s^2).
        R_imu_camera: (3, 3) rotation camera optical frame -> IMU frame.
    Returns:
        (t (M,) s, omega (M, 3) rad/s, specific_force (M, 3) m/s^2), IMU frame:
        ``omega = R_imu_camera omega_cam + bias + noise``, ``f = R_imu_camera R^T (a - g) +
        noise`` (a the second difference of the position).
    """
    rng = np.random.default_rng(seed)
    t = np.arange(t_start, t_end, 1.0 / rate)
    w, _ = trajectory.velocity_body(t)
    h = 1e-4
    acc = (
        trajectory.position(t + h) - 2 * trajectory.position(t) + trajectory.position(t - h)
    ) / h**2
    f_cam = np.einsum("nji,nj->ni", trajectory.orientation(t), acc - GRAVITY)
    omega = w @ R_imu_camera.T + np.asarray(gyro_bias) + rng.normal(0, gyro_noise, w.shape)
    f = f_cam @ R_imu_camera.T + rng.normal(0, accel_noise, f_cam.shape)
    return t, omega, f


@dataclass
class Scene:
    """Landmarks (M, 3) in the world (m) with integer ids (M,)."""

    points: np.ndarray
    ids: np.ndarray

    def lookup(self, ids: Iterable[int]) -> np.ndarray:
        index = {int(i): k for k, i in enumerate(self.ids)}
        return self.points[[index[int(i)] for i in ids]]


def make_scene(
    rng: np.random.Generator,
    num_landmarks: int = 6000,
    length: float = 40.0,
    x0: float = -2.0,
    half_width: float = 3.0,
    floor: float = -0.2,
    ceiling: float = 4.0,
    clutter: float = 0.25,
) -> Scene:
    """A corridor along world x: landmarks on the two walls, floor and ceiling, plus clutter
    (a fraction ``clutter`` of points) inside it, away from the walking line. Coordinates are
    rounded to 0.1 mm so that float32 clouds and CSV files carry them without loss that matters.
    """
    n_clutter = int(clutter * num_landmarks)
    n_surf = num_landmarks - n_clutter
    face = rng.integers(0, 4, n_surf)
    x = rng.uniform(x0, x0 + length, n_surf)
    y = rng.uniform(-half_width, half_width, n_surf)
    z = rng.uniform(floor, ceiling, n_surf)
    y = np.where(face == 0, -half_width, np.where(face == 1, half_width, y))
    z = np.where(face == 2, floor, np.where(face == 3, ceiling, z))
    surf = np.stack([x, y, z], axis=1) + rng.normal(0, 0.05, (n_surf, 3))  # wall relief
    cx = rng.uniform(x0, x0 + length, n_clutter)
    cy = rng.uniform(-half_width, half_width, n_clutter)
    cz = rng.uniform(floor, ceiling, n_clutter)
    away = np.abs(cy) > 1.2  # keep a free walking lane
    clut = np.stack([cx, cy, cz], axis=1)[away]
    pts = np.round(np.concatenate([surf, clut]), 4)
    ids = np.arange(1, len(pts) + 1, dtype=np.int64) * 7 + 100  # non-contiguous ids
    return Scene(pts, ids)


def project_rs(
    camera: CameraModel,
    trajectory: Trajectory,
    t_first_line: float,
    X: np.ndarray,
    iterations: int = 30,
    tol: float = 1e-9,
) -> tuple[np.ndarray, np.ndarray]:
    """Exact RS projection of world points ``X`` (N, 3) for the frame whose first line is read
    at ``t_first_line`` (s).

    Solves ``line = pixel_line(distort(project(X, pose(t_first_line + line_time(line)))))`` by
    fixed-point iteration (a contraction: the image moves far less than one line per line delay).

    Returns:
        (uv, ok): (N, 2) pixels and (N,) bool (in front of the camera, converged, inside image).
    """
    X = np.asarray(X, dtype=float)
    axis = 1 if camera.readout in ("top_to_bottom", "bottom_to_top") else 0
    line = np.full(len(X), camera.reference_line)
    uv = np.full((len(X), 2), np.nan)
    ok = np.ones(len(X), dtype=bool)
    lim = np.array([camera.width, camera.height]) / np.diag(camera.K)[:2]
    for _ in range(iterations):
        t = t_first_line + camera.line_time(np.clip(line, -camera.lines, 2 * camera.lines))
        R, p = trajectory.pose(t)
        Xc = np.einsum("nji,nj->ni", R, X - p)  # R^T (X - p)
        z = Xc[:, 2]
        ok &= z > 0.2
        xn = Xc[:, :2] / np.where(ok, z, 1.0)[:, None]
        ok &= np.all(np.abs(xn) < 1.3 * lim, axis=1)  # keep cv2 away from wild extrapolation
        xn[~ok] = 0.0
        uv = camera.distort(xn)
        new_line = uv[:, axis]
        delta = np.abs(new_line - line)
        line = new_line
        if np.all(delta[ok] < tol):
            break
    ok &= np.isfinite(uv).all(axis=1) & (delta < 1e-6)
    ok &= camera.in_image(uv)
    uv[~ok] = np.nan
    return uv, ok


@dataclass
class Frame:
    """One synthetic image: correspondences and ground truth.

    ``stamp_ns``: capture time of line ``stamp_row`` (the header stamp); ``t_ref_ns``: capture
    time of the reference line (the ground-truth stamp). ``orientation``/``position``: camera ->
    world at the reference line; ``angular_velocity``/``linear_velocity``: camera optical frame
    (rad/s, m/s). ``inlier``: (N,) False for the synthetic outliers.
    """

    index: int
    stamp_ns: int
    t_ref_ns: int
    uv: np.ndarray
    xyz: np.ndarray
    ids: np.ndarray
    scores: np.ndarray
    inlier: np.ndarray
    orientation: np.ndarray
    position: np.ndarray
    angular_velocity: np.ndarray
    linear_velocity: np.ndarray
    uv_clean: np.ndarray = field(default=None, repr=False)


@dataclass(frozen=True)
class SequenceConfig:
    """Parameters of :func:`generate_sequence`. ``drop_frames``: indices of frames that are
    generated but left out of the output (a camera dropping frames: the other frames are the
    same as without it)."""

    num_frames: int = 40
    num_points: int = 500
    fps: float = 30.0
    noise_px: float = 0.5
    outlier_ratio: float = 0.2
    seed: int = 0
    t0_ns: int = 1_700_000_000_000_000_000
    stamp_row: float = 0.0
    motion_scale: float = 1.0
    num_landmarks: int = 6000
    drop_frames: tuple = ()


def truth_at(trajectory: Trajectory, t: float) -> tuple:
    """(orientation (3, 3) body -> world, position (3,) m, angular velocity (3,) rad/s, linear
    velocity (3,) m/s; velocities in the body frame) of ``trajectory`` (a camera's, a rig's)
    at ``t`` (s)."""
    R, p = trajectory.pose(t)
    w, v = trajectory.velocity_body(t)
    return R, p, w, v


def ground_truth(
    camera: CameraModel, trajectory: Trajectory, t_first_line: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """(orientation, position, angular_velocity, linear_velocity, t_ref) at the reference line
    (:func:`truth_at`)."""
    t_ref = t_first_line + float(camera.line_time(camera.reference_line))
    return (*truth_at(trajectory, t_ref), t_ref)


def observe(
    camera: CameraModel,
    trajectory: Any,
    t_first: float,
    points: np.ndarray,
    num_points: int,
    noise_px: float,
    rng: np.random.Generator,
    view: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What a camera moving along ``trajectory`` (a camera's, or a body's composed with the
    camera's mounting: :class:`MountedTrajectory`) sees of the landmarks ``points`` (M, 3) m in
    its frame whose first line is read at ``t_first`` (s).

    The landmarks 0.3-25 m in front of the camera at its reference line are pre-selected (with
    ``view``: only those within ``view`` times the image's half-extent of the optical axis, and
    at most ``2 num_points`` of them drawn at random), projected exactly (:func:`project_rs`),
    ``num_points`` of the visible ones drawn at random (fewer when fewer are visible) and
    Gaussian noise of ``noise_px`` px per axis added.

    Returns:
        (rows (n,) into ``points``, clean pixels (n, 2), noisy pixels (n, 2)).
    """
    R, p = trajectory.pose(t_first + float(camera.line_time(camera.reference_line)))
    Xc = (points - p) @ R
    pre = (Xc[:, 2] > 0.3) & (Xc[:, 2] < 25.0)
    if view is not None:
        lim = np.array([camera.width, camera.height]) / np.diag(camera.K)[:2]
        z = np.where(Xc[:, 2] > 0.3, Xc[:, 2], np.inf)
        pre &= np.all(np.abs(Xc[:, :2] / z[:, None]) < view * lim, axis=1)
    cand = np.flatnonzero(pre)
    if view is not None and len(cand) > 2 * num_points:  # the exact projection of twice as many
        cand = np.sort(rng.choice(cand, 2 * num_points, replace=False))
    uv, ok = project_rs(camera, trajectory, t_first, points[cand])
    vis, uv = cand[ok], uv[ok]
    pick = rng.choice(len(vis), min(num_points, len(vis)), replace=False)
    clean = uv[pick]
    return vis[pick], clean, clean + rng.normal(0.0, noise_px, clean.shape)


def generate_sequence(
    config: SequenceConfig = SequenceConfig(),
    camera: CameraModel | None = None,
    trajectory: Trajectory | None = None,
    scene: Scene | None = None,
    progress: Callable[[int], object] | None = None,
) -> tuple[list[Frame], Scene, CameraModel, Trajectory]:
    """Generate ``config.num_frames`` frames. Returns ``(frames, scene, camera, trajectory)``.
    ``progress``: None or a callable, called with each frame's index before the frame is made.

    Per frame: all landmarks visible in the RS image are projected exactly, ``num_points`` of
    them are drawn at random, Gaussian pixel noise ``noise_px`` is added, and a fraction
    ``outlier_ratio`` get a uniformly random pixel (wrong matches). Scores are higher for inliers
    on average (like descriptor match scores), but overlap.
    """
    rng = np.random.default_rng(config.seed)
    camera = camera or default_camera()
    trajectory = trajectory or Trajectory(scale=config.motion_scale)
    scene = scene or make_scene(rng, config.num_landmarks)
    frames = []
    period = 1.0 / config.fps
    for k in range(config.num_frames):
        if progress is not None:
            progress(k)
        t_first = k * period
        R, p, w, v, t_ref = ground_truth(camera, trajectory, t_first)
        rows, clean, noisy = observe(
            camera, trajectory, t_first, scene.points, config.num_points, config.noise_px, rng
        )
        n = len(rows)
        ids, xyz = scene.ids[rows], scene.points[rows]
        noisy[:, 0] = np.clip(noisy[:, 0], 0, camera.width - 1)
        noisy[:, 1] = np.clip(noisy[:, 1], 0, camera.height - 1)
        n_out = int(round(config.outlier_ratio * n))
        inlier = np.ones(n, dtype=bool)
        out_idx = rng.choice(n, n_out, replace=False)
        inlier[out_idx] = False
        noisy[out_idx] = rng.uniform([0, 0], [camera.width - 1, camera.height - 1], (n_out, 2))
        scores = np.where(inlier, rng.uniform(0.3, 1.0, n), rng.uniform(0.0, 0.7, n))
        stamp = t_first + float(camera.line_time(config.stamp_row))
        if k in config.drop_frames:
            continue
        frames.append(
            Frame(
                index=k,
                stamp_ns=config.t0_ns + int(round(stamp * 1e9)),
                t_ref_ns=config.t0_ns + int(round(t_ref * 1e9)),
                uv=noisy,
                xyz=xyz,
                ids=ids,
                scores=scores,
                inlier=inlier,
                orientation=R,
                position=p,
                angular_velocity=w,
                linear_velocity=v,
                uv_clean=clean,
            )
        )
    return frames, scene, camera, trajectory


# ------------------------------------------------------------------ cameras on a body (a rig)
@dataclass(frozen=True, eq=False)
class MountedTrajectory:
    """A body's trajectory carried by another's: the carrier's motion ``base`` (``pose(t)``)
    with the body fixed on it, turned by ``R_base_body`` (3, 3) body -> carrier and at
    ``p_base_body`` (3,) m in the carrier's frame (None: at its origin). ``pose(t)``:
    (orientation (..., 3, 3) body -> world, position (..., 3) m) at time(s) ``t`` (s); what
    the renderer and :func:`project_rs` take. A camera on the rig (:meth:`RigCameraSim.on`),
    the rig on the camera walk (:class:`RigTrajectory`)."""

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
    (:class:`Trajectory` by default, or a renderer motion of
    :func:`~rs_localizer.sim.render.motion.make_motion`; optical-frame axes) turned into it,
    ``R_rig(t) = R_cam(t) R_FORWARD^T``, the rig's origin at the camera's centre."""

    def __init__(self, base: Any = None):
        super().__init__(Trajectory() if base is None else base, R_FORWARD.T)


@dataclass(frozen=True, eq=False)
class RigCameraSim:
    """A simulated camera on a rig (a camera alone: at the identity mounting).

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
#: simulated rigs' cameras (:func:`default_rig`,
#: :func:`~rs_localizer.sim.render.renderer.rendered_rig`)
PLACES = {
    "front": (0.0, (0.15, 0.0, 0.10)),
    "left": (90.0, (0.0, 0.12, 0.12)),
    "right": (-90.0, (0.0, -0.12, 0.12)),
    "back": (180.0, (-0.15, 0.0, 0.10)),
}


@dataclass
class RigFrameSim:
    """One camera frame of a rig video, simulated (:func:`generate_rig_video`) or rendered
    (:func:`~rs_localizer.sim.render.renderer.render_rig_video`). ``stamp_ns``: capture time
    of line ``stamp_row`` (the header stamp); ``t_ref_ns``: of the camera's reference line.
    ``uv`` (N, 2) px, ``xyz`` (N, 3) m (map frame): its correspondences. ``orientation`` (3, 3)
    rig -> world and ``position`` (3,) m: the rig at ``t_ref_ns``. ``inlier`` (N,): False for
    the synthetic outliers (None: rendered). Rendered: ``image`` (H, W, 3) uint8 RGB, ``ids``
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

    Per frame: what the camera sees along the rig's trajectory composed with its mounting
    (:func:`observe`: ``num_points`` of the landmarks visible in the RS image, drawn from twice
    as many landmarks in the camera's view, Gaussian pixel noise ``noise_px``), each row
    replaced with probability ``outlier_ratio`` by a uniformly random pixel. Rig time ``t`` is
    stamped ``t0_ns + t * 1e9`` ns.

    Returns:
        (frames, scene, trajectory); the scene: a 40 m corridor from x = -10 m, 12000 landmarks.
    """
    rng = np.random.default_rng(seed)
    trajectory = trajectory or RigTrajectory()
    scene = scene or make_scene(rng, 12000, length=40.0, x0=-10.0)
    frames = []
    for rc in cameras:
        cam, mounted = rc.camera, rc.on(trajectory)
        k = 0
        while True:
            t_first = rc.offset + k / rc.fps
            if t_first >= duration or (rc.stop is not None and t_first >= rc.stop):
                break
            rows, _, noisy = observe(cam, mounted, t_first, scene.points, num_points, noise_px,
                                     rng, view=0.6)  # fmt: skip
            n = len(rows)
            inlier = rng.random(n) >= outlier_ratio
            noisy[~inlier] = rng.uniform([0, 0], [cam.width - 1, cam.height - 1], (n, 2))[~inlier]
            if k not in rc.drop:
                t_ref = t_first + float(cam.line_time(cam.reference_line))
                R, p = trajectory.pose(t_ref)
                stamp = t_first + float(cam.line_time(stamp_row))
                frames.append(
                    RigFrameSim(rc.name, k, t0_ns + int(round(stamp * 1e9)),
                                t0_ns + int(round(t_ref * 1e9)), noisy, scene.points[rows], R, p,
                                inlier)
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
    """A gyro on the rig: :func:`imu_samples` at the rig's origin over ``[-margin, duration +
    margin]`` s of rig time, stamped ``t0_ns + t * 1e9`` ns as :func:`generate_rig_video`'s
    frames: ``omega_imu = R_rig_imu^T omega_rig + bias + n`` (``omega_rig`` the trajectory's
    angular velocity in the rig frame, :func:`rig_truth`; ``n`` Gaussian, ``noise`` rad/s per
    axis).

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
