"""Synthetic rolling-shutter frames of planar scenes: a large plane, a small board.

The per-frame RS model (12 unknowns: pose and both velocities) is near-degenerate on coplanar
points; these frames measure how the estimator copes. The protocol:

- camera: 640x480, f = 600 px, principal point at the image centre, no distortion, top-to-bottom
  readout at 40 us per line (19.2 ms per frame), reference line at the image centre
  (:func:`planar_camera`);
- ``plane``: ``n_points`` (300) points on one plane whose centre lies on the optical axis
  ``distance`` (4 m) away, its normal tilted from the optical axis by up to ``max_tilt_deg``
  (35 deg) about a random axis, the points spread over the whole image;
- ``board``: the inner corners of a checkerboard (``board_corners`` 6x7, ``square`` 8 cm),
  0.8-2 m away, tilted the same way, its centre anywhere such that every corner is in view;
- motion: constant angular velocity of 1-3 rad/s and linear velocity of 0.2-1 m/s in random
  directions of the camera frame; Gaussian pixel noise ``noise_px`` (0.5 px); no outliers
  unless ``outlier_ratio`` asks for them.

Every point is projected with the exact constant-velocity model
(:func:`rs_localizer.geometry.rs_project_exact`: the pose at its own capture line). The world
frame is the plane's: the plane is ``z = 0``, its normal +z points towards the camera side.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..camera import CameraModel
from ..geometry import camera_position, rotvec_to_matrix, rs_project_exact
from ..pose import model_from_twist
from .trajectory import Scene

__all__ = [
    "SEQUENCE_SCENES",
    "PlanarFrame",
    "board_corners",
    "make_planar_frame",
    "planar_camera",
    "sequence_scene",
]


@dataclass(frozen=True)
class PlanarFrame:
    """One planar RS frame with ground truth.

    Attributes:
        points_px: (N, 2) measured pixels (noisy). X: (N, 3) world points (m), all ``z = 0``.
        camera: the :class:`~rs_localizer.camera.CameraModel` that took it.
        R, C: world -> camera at the reference line (``X_cam = R X + C``, m).
        w, t: the model velocities per unit RS coordinate (rad, m), docs/architecture.md
        "Conventions".
        orientation, position: camera -> world rotation (``R^T``) and centre (m).
        angular_velocity, linear_velocity: (3,) the camera's own velocities in its optical
            frame (rad/s, m/s).
        points_clean: (N, 2) the noise-free pixels.
        inlier: (N,) bool, False for the generated outliers.
        scene: ``plane``, ``board`` or ``depth``.
    """

    points_px: np.ndarray
    X: np.ndarray
    camera: CameraModel
    R: np.ndarray
    C: np.ndarray
    w: np.ndarray
    t: np.ndarray
    orientation: np.ndarray
    position: np.ndarray
    angular_velocity: np.ndarray
    linear_velocity: np.ndarray
    points_clean: np.ndarray
    inlier: np.ndarray
    scene: str


def planar_camera(
    line_delay: float = 40e-6, focal: float = 600.0, width: int = 640, height: int = 480
) -> CameraModel:
    """The planar frames' camera: ``width`` x ``height`` px, ``focal`` px, principal point at the
    image centre, no distortion, top-to-bottom readout with ``line_delay`` s per line."""
    K = np.array(
        [[focal, 0.0, (width - 1) / 2.0], [0.0, focal, (height - 1) / 2.0], [0.0, 0.0, 1.0]]
    )
    return CameraModel(K=K, width=width, height=height, line_delay=line_delay)


def board_corners(corners: tuple[int, int] = (6, 7), square: float = 0.08) -> np.ndarray:
    """(n_x * n_y, 3) inner corners of a checkerboard in its own frame (m): ``z = 0``, centred
    on the origin, x along the first count, row-major like OpenCV's corner order."""
    nx, ny = int(corners[0]), int(corners[1])
    gx, gy = np.meshgrid(
        (np.arange(nx) - (nx - 1) / 2) * square, (np.arange(ny) - (ny - 1) / 2) * square
    )
    return np.stack([gx.ravel(), gy.ravel(), np.zeros(nx * ny)], axis=1)


def _unit(rng):
    a = rng.normal(size=3)
    return a / np.linalg.norm(a)


def _plane_pose(rng, centre_cam, max_tilt_deg):
    """World -> camera (R, C) for a plane through ``centre_cam`` (camera frame) whose normal is
    tilted from the optical axis by up to ``max_tilt_deg`` and randomly rolled. World origin =
    the plane centre, world z = the plane normal towards the camera."""
    tilt = np.radians(rng.uniform(0.0, max_tilt_deg))
    phi = rng.uniform(0.0, 2 * np.pi)
    axis = np.array([np.cos(phi), np.sin(phi), 0.0])
    nz = rotvec_to_matrix(tilt * axis) @ np.array([0.0, 0.0, -1.0])  # normal towards camera
    a = _unit(rng)
    ex = a - nz * (a @ nz)
    ex /= np.linalg.norm(ex)
    ey = np.cross(nz, ex)
    R = np.stack([ex, ey, nz], axis=1)  # columns: world axes in camera coordinates
    return R, np.asarray(centre_cam, dtype=float)


def make_planar_frame(
    rng: np.random.Generator | int = 0,
    scene: str = "plane",
    n_points: int = 300,
    distance: float = 4.0,
    board_distance: tuple[float, float] = (0.8, 2.0),
    board: tuple[int, int] = (6, 7),
    square: float = 0.08,
    max_tilt_deg: float = 35.0,
    angular_speed: tuple[float, float] = (1.0, 3.0),
    linear_speed: tuple[float, float] = (0.2, 1.0),
    noise_px: float = 0.5,
    outlier_ratio: float = 0.0,
    depth_range: tuple[float, float] = (2.0, 6.0),
    camera: CameraModel | None = None,
    max_tries: int = 200,
) -> PlanarFrame:
    """One frame of a planar scene (module docstring).

    Args:
        rng: a NumPy Generator or a seed.
        scene: ``plane`` (``n_points`` points over the image, plane ``distance`` m away on the
            optical axis) or ``board`` (the ``board`` inner corners with ``square`` m spacing,
            the centre ``board_distance`` (min, max) m away, every corner in view) or
            ``depth`` (the 3D reference: ``plane``'s camera, motion and image coverage, but
            each point at a depth drawn uniformly from ``depth_range`` (m) along its ray).
        max_tilt_deg: largest angle between the plane normal and the optical axis (deg).
        angular_speed, linear_speed: (min, max) speeds (rad/s, m/s), uniform, random direction.
        noise_px: Gaussian pixel noise sigma.
        outlier_ratio: fraction of the observations replaced by uniformly random pixels
            (wrong matches; ``inlier`` marks the others).
        camera: default :func:`planar_camera`.
    Returns:
        :class:`PlanarFrame`.
    Raises:
        ValueError: unknown scene or invalid sizes; RuntimeError if no placement keeps the
        points in view after ``max_tries`` attempts.
    """
    rng = np.random.default_rng(rng)
    if scene not in ("plane", "board", "depth"):
        raise ValueError(f"scene must be 'plane', 'board' or 'depth', got {scene!r}")
    if n_points < 3 or noise_px < 0 or not 0 <= outlier_ratio <= 1:
        raise ValueError("need n_points >= 3, noise_px >= 0 and 0 <= outlier_ratio <= 1")
    cam = camera or planar_camera()
    s = cam.seconds_per_unit_r
    Kinv = np.linalg.inv(cam.K)
    omega = _unit(rng) * rng.uniform(*angular_speed)
    vel = _unit(rng) * rng.uniform(*linear_speed)
    for _ in range(max_tries):
        if scene == "depth":
            # the plane's camera and image coverage, the points spread in depth instead
            R, C = _plane_pose(rng, [0.0, 0.0, distance], max_tilt_deg)
            uv = rng.uniform([0, 0], [cam.width - 1, cam.height - 1], (2 * n_points, 2))
            rays = np.concatenate([uv, np.ones((len(uv), 1))], axis=1) @ Kinv.T
            lam = rng.uniform(*depth_range, len(uv))
            X = (lam[:, None] * rays - C) @ R
        elif scene == "plane":
            R, C = _plane_pose(rng, [0.0, 0.0, distance], max_tilt_deg)
            # pixels all over the image, back-projected (reference pose) onto the plane z = 0
            uv = rng.uniform([0, 0], [cam.width - 1, cam.height - 1], (2 * n_points, 2))
            rays = np.concatenate([uv, np.ones((len(uv), 1))], axis=1) @ Kinv.T
            n = R[:, 2]  # plane normal in the camera frame; plane: n . (p - C) = 0
            lam = (n @ C) / (rays @ n)
            X = (lam[:, None] * rays - C) @ R  # R^T (p - C)
            X[:, 2] = 0.0
        else:
            uv = rng.uniform(
                [0.25 * cam.width, 0.25 * cam.height], [0.75 * cam.width, 0.75 * cam.height]
            )
            ray = Kinv @ np.array([uv[0], uv[1], 1.0])
            R, C = _plane_pose(
                rng, ray / np.linalg.norm(ray) * rng.uniform(*board_distance), max_tilt_deg
            )
            X = board_corners(board, square)
        w, t = model_from_twist(C, omega, vel, s)
        x, _ = rs_project_exact(X, R, C, w, t, cam.r0)
        px = cam.distort(np.nan_to_num(x, nan=1e3))
        keep = np.isfinite(x).all(axis=1) & cam.in_image(px, margin=-2.0)
        if scene == "board":
            if keep.all():
                break
        elif keep.sum() >= n_points:  # plane, depth
            sel = np.flatnonzero(keep)[:n_points]
            X, px = X[sel], px[sel]
            break
    else:
        raise RuntimeError("could not place the planar scene in view")
    noisy = px + rng.normal(0.0, noise_px, px.shape)
    inlier = np.ones(len(X), dtype=bool)
    n_out = int(round(outlier_ratio * len(X)))
    if n_out:
        idx = rng.choice(len(X), n_out, replace=False)
        noisy[idx] = rng.uniform([0, 0], [cam.width - 1, cam.height - 1], (n_out, 2))
        inlier[idx] = False
    return PlanarFrame(
        points_px=noisy,
        X=X,
        camera=cam,
        R=R,
        C=C,
        w=w,
        t=t,
        orientation=R.T,
        position=camera_position(R, C),
        angular_velocity=omega,
        linear_velocity=vel,
        points_clean=px,
        inlier=inlier,
        scene=scene,
    )


# ------------------------------------------------------------------------ sequences (make-bag)
#: scene kinds of :func:`sequence_scene` (``make-bag --scene``)
SEQUENCE_SCENES = ("corridor", "plane", "board")


def sequence_scene(
    kind: str,
    rng: np.random.Generator,
    num_landmarks: int = 6000,
    motion_scale: float = 1.0,
) -> tuple[Scene | None, Any]:
    """Landmarks and camera motion for a synthetic sequence
    (:func:`rs_localizer.sim.trajectory.generate_sequence`, ``rs-localizer make-bag --scene``).

    Args:
        kind: ``corridor`` (the 3D corridor of :func:`~rs_localizer.sim.trajectory.make_scene`
            and the default walk: returns ``(None, None)`` so that the sequence generator
            draws exactly what it always drew), ``plane`` (``num_landmarks`` points on one wall
            8 m ahead, 12 m wide and 6 m high, facing the default walk, which heads towards
            it) or ``board`` (the 42 inner corners of the built-in ``checkerboard`` scene: 6x7,
            8 cm squares, 1.2 m ahead, seen by the renderer's hand-held ``shake`` motion around
            the scene's viewpoint, up to ~1.1 rad/s).
        rng: NumPy Generator (the plane's landmarks). num_landmarks: landmarks of ``plane``.
        motion_scale: rotation amplitude scale of the ``board`` motion (``corridor`` and
            ``plane``: :class:`~rs_localizer.sim.trajectory.SequenceConfig` applies it).
    Returns:
        ``(Scene or None, Trajectory or None)``; ``None`` means the generator's default.
    Raises:
        ValueError: unknown kind.
    """
    if kind == "corridor":
        return None, None
    if kind == "plane":
        y = rng.uniform(-6.0, 6.0, num_landmarks)
        z = rng.uniform(-1.5, 4.5, num_landmarks)
        pts = np.round(np.stack([np.full(num_landmarks, 8.0), y, z], axis=1), 4)
        ids = np.arange(1, num_landmarks + 1, dtype=np.int64) * 7 + 100
        return Scene(pts, ids), None
    if kind == "board":
        from .render.motion import make_motion
        from .render.scene import load_scene

        board = load_scene("checkerboard")
        ids, pts = board.checkerboard_corner_points()
        return Scene(np.round(pts, 4), ids), make_motion(
            "shake", board, duration=2.0, scale=motion_scale
        )
    raise ValueError(f"unknown scene {kind!r}; expected one of {SEQUENCE_SCENES}")
