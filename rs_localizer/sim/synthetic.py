"""Synthetic rolling-shutter frames following the paper's protocol (sec. 4).

Points uniformly in ``[-1, 1]^3``; a camera at distance ``d in [2, 3]`` from the origin looking
at it; ``K = I`` with a 45 degree field of view; constant linear and angular velocity during the
frame (exact rotation ``expm(tau [w]x)``, not the solvers' linearization, unless ``model="eq5"``).
"RS speed" ``s`` means ``s * 30`` degrees and ``s * 0.3`` units of motion per frame (the paper's
maximum is ``s = 1``); per frame means over the whole image height, ``2 tan(22.5 deg)`` in units
of the RS coordinate ``r = y`` (top-to-bottom readout), with ``r0 = 0`` at the image centre.

Pixel noise is given in pixels of a nominal 1000 x 1000 image (focal length
``500 / tan(22.5 deg)`` px), as in R6P (Albl et al. 2015). :func:`paper_camera` returns that
camera as a :class:`~rs_localizer.camera.CameraModel` so frames can be fed to the estimator in
pixels.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..camera import CameraModel
from ..geometry import (
    camera_position,
    matrix_to_rotvec,
    nearest_rotation,
    rotvec_to_matrix,
    rs_project_exact,
    rs_project_linear,
    skew,
)

if TYPE_CHECKING:
    from ..estimation.estimate import EstimateOptions

__all__ = [
    "FOCAL_PX",
    "FOV_DEG",
    "FRAME_SPAN",
    "IMAGE_SIZE",
    "SyntheticFrame",
    "make_frame",
    "paper_camera",
    "protocol_options",
    "random_rotation",
]

FOV_DEG = 45.0
IMAGE_SIZE = 1000
HALF_TAN = float(np.tan(np.radians(FOV_DEG / 2)))
FOCAL_PX = IMAGE_SIZE / 2 / HALF_TAN
#: extent of the image along the readout axis in units of r (what "per frame" refers to)
FRAME_SPAN = 2 * HALF_TAN


@dataclass(frozen=True)
class SyntheticFrame:
    """One synthetic RS frame with ground truth.

    Attributes:
        x: (N, 2) observed normalized image points (noisy; outliers replaced).
        X: (N, 3) world points.
        r: (N,) observed RS coordinates (``x[:, 1]``; noise included, as a measured row is).
        r0: reference RS coordinate (0.0, the image centre row).
        R, C: ground truth world -> camera at r0 (``X_cam = R X + C``).
        w, t: ground truth angular (rad) and linear velocity per unit r.
        inlier: (N,) bool, False for generated outliers.
        points_px: (N, 2) the observations in pixels of :func:`paper_camera`.
        seconds_per_unit_r: time scale used for the physical velocities below.
        angular_velocity, linear_velocity: (3,) the camera's own velocity in its optical frame
            (rad/s, m/s), obtained by numerically differentiating the simulated trajectory.
        position: (3,) camera centre at r0 in the world.
    """

    x: np.ndarray
    X: np.ndarray
    r: np.ndarray
    r0: float
    R: np.ndarray
    C: np.ndarray
    w: np.ndarray
    t: np.ndarray
    inlier: np.ndarray
    points_px: np.ndarray
    seconds_per_unit_r: float
    angular_velocity: np.ndarray
    linear_velocity: np.ndarray
    position: np.ndarray


def paper_camera(readout_time: float = 0.03) -> CameraModel:
    """The nominal camera of the protocol: 1000 x 1000 px, 45 deg FOV, top-to-bottom readout,
    reference row at the image centre, ``readout_time`` seconds per frame, no distortion."""
    c = (IMAGE_SIZE - 1) / 2.0
    K = np.array([[FOCAL_PX, 0, c], [0, FOCAL_PX, c], [0, 0, 1.0]])
    return CameraModel.from_readout_time(K, readout_time, IMAGE_SIZE, IMAGE_SIZE)


def protocol_options() -> EstimateOptions:
    """:class:`EstimateOptions` for the paper protocol's frames: the defaults without
    the motion-plausibility bounds, since the protocol's scene has no physical scale and at
    RS speed 1.0 some frames move faster than 50 units/s (the default bound of a camera in
    metres), which the estimator would rightly refuse (3 of the 40 frames of ``python -m
    benchmarks.bench ml``, ~10 % of Exp. 7's fastest)."""
    from ..estimation.estimate import EstimateOptions, PlausibilityOptions

    unbounded = PlausibilityOptions(max_angular_velocity=np.inf, max_linear_velocity=np.inf)
    return EstimateOptions(plausibility=unbounded)


def random_rotation(rng: np.random.Generator, angle_deg: float | None = None) -> np.ndarray:
    """A uniformly random rotation, or one of exactly ``angle_deg`` about a random axis."""
    if angle_deg is None:
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        from scipy.spatial.transform import Rotation

        return Rotation.from_quat(q).as_matrix()
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    return rotvec_to_matrix(np.radians(angle_deg) * axis)


def _unit(rng):
    a = rng.normal(size=3)
    return a / np.linalg.norm(a)


def _physical_velocities(R, C, w, t, seconds_per_unit_r, h=1e-6):
    """Camera velocities by central differences of the simulated trajectory (independent of
    the closed-form conversion in :mod:`rs_localizer.estimation.estimate`)."""

    def pose(tau):
        Rt = rotvec_to_matrix(tau * w) @ R
        return Rt.T, camera_position(Rt, C + tau * t)  # camera->world orientation, centre

    Ra, ca = pose(-h)
    Rb, cb = pose(h)
    omega_body = matrix_to_rotvec(Ra.T @ Rb) / (2 * h) / seconds_per_unit_r
    v_world = (cb - ca) / (2 * h) / seconds_per_unit_r
    return omega_body, R @ v_world


def make_frame(
    rng: np.random.Generator | int = 0,
    n_points: int = 100,
    rs_speed: float = 0.5,
    noise_px: float = 0.0,
    outlier_ratio: float = 0.0,
    translation_only: bool = False,
    rotation_only: bool = False,
    angle_from_identity: float | None = None,
    rot_per_frame_deg: float | None = None,
    trans_per_frame: float | None = None,
    model: str = "exact",
    r0: float = 0.0,
    readout_time: float = 0.03,
    max_tries: int = 50,
) -> SyntheticFrame:
    """Generate one frame of the paper's synthetic protocol.

    Args:
        rng: a NumPy Generator or a seed.
        n_points: correspondences N (all inside the 45 degree field of view, in front).
        rs_speed: motion per frame as a fraction of the paper's maximum (30 deg, 0.3 units).
        rot_per_frame_deg, trans_per_frame: override the two magnitudes separately.
        noise_px: Gaussian pixel noise sigma on the nominal 1000 px image.
        outlier_ratio: fraction of observations replaced by uniform random image points.
        translation_only / rotation_only: zero angular / linear velocity.
        angle_from_identity: camera orientation exactly this many degrees from ``R = I``
            (paper Fig. 5); ``None`` draws a uniformly random orientation.
        model: ``"exact"`` (constant velocity, ``expm``) or ``"eq5"`` (paper eq. 5 exactly, with
            ``R = I + [v]x``; ``R`` in the result is then that matrix).
        r0: reference RS coordinate. readout_time: frame readout (s) for physical velocities.
    Returns:
        :class:`SyntheticFrame`.
    Raises:
        ValueError: for invalid arguments; RuntimeError if the field of view cannot be filled.
    """
    rng = np.random.default_rng(rng)
    if n_points < 1 or not 0 <= outlier_ratio <= 1 or noise_px < 0:
        raise ValueError("need n_points >= 1, 0 <= outlier_ratio <= 1, noise_px >= 0")
    if model not in ("exact", "eq5"):
        raise ValueError(f"model must be 'exact' or 'eq5', got {model!r}")
    rot = np.radians(30.0 * rs_speed if rot_per_frame_deg is None else rot_per_frame_deg)
    trans = 0.3 * rs_speed if trans_per_frame is None else trans_per_frame
    w = np.zeros(3) if translation_only else _unit(rng) * rot / FRAME_SPAN
    t = np.zeros(3) if rotation_only else _unit(rng) * trans / FRAME_SPAN
    if angle_from_identity is None:
        R = random_rotation(rng)
    else:
        R = random_rotation(rng, angle_from_identity)
    if model == "eq5":
        v = matrix_to_rotvec(R)
        R = np.eye(3) + skew(v)
    d = rng.uniform(2.0, 3.0)
    # camera centre on the optical axis through the origin: X_cam(0) = R*0 + C = (0, 0, d)
    C = np.array([0.0, 0.0, d])
    xs, Xs = [], []
    count = 0
    for _ in range(max_tries):
        X = rng.uniform(-1.0, 1.0, size=(4 * n_points, 3))
        if model == "exact":
            x, _r = rs_project_exact(X, R, C, w, t, r0)
        else:
            x, _r = rs_project_linear(X, R, C, w, t, r0)
        Xc = X @ R.T + C
        keep = np.isfinite(x).all(axis=1) & (np.abs(x) <= HALF_TAN).all(axis=1) & (Xc[:, 2] > 0.1)
        xs.append(x[keep])
        Xs.append(X[keep])
        count += int(keep.sum())
        if count >= n_points:
            break
    else:
        raise RuntimeError("could not place enough points in the field of view")
    x = np.concatenate(xs)[:n_points]
    X = np.concatenate(Xs)[:n_points]
    x = x + rng.normal(scale=noise_px / FOCAL_PX, size=x.shape)
    inlier = np.ones(n_points, dtype=bool)
    n_out = int(round(outlier_ratio * n_points))
    if n_out:
        idx = rng.choice(n_points, n_out, replace=False)
        x[idx] = rng.uniform(-HALF_TAN, HALF_TAN, size=(n_out, 2))
        inlier[idx] = False
    cam = paper_camera(readout_time)
    spr = cam.seconds_per_unit_r
    Rm = R if model == "exact" else nearest_rotation(R)  # I + [v]x is not a rotation
    omega, vel = _physical_velocities(Rm, C, w, t, spr)
    return SyntheticFrame(
        x=x,
        X=X,
        r=x[:, 1].copy(),
        r0=float(r0),
        R=R,
        C=C,
        w=w,
        t=t,
        inlier=inlier,
        points_px=cam.distort(x),
        seconds_per_unit_r=spr,
        angular_velocity=omega,
        linear_velocity=vel,
        position=camera_position(Rm, C),
    )
