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

Frames in pixels of a camera moving as an :class:`~rs_localizer.pose.RSModel`
(:func:`camera_frame`: points in its view, its exact RS projection, noise and outliers), and of
rigs of such cameras: a rig frame is its cameras' frames, each of the rig's model composed with
the camera's mounting and stamp offset (:func:`rig_frame`; a camera alone is a rig of one, at the
identity mounting). A :class:`Rig` (:func:`make_rig`) carries 1 to 4 cameras looking front,
back and to the sides (:data:`LAYOUTS`), each mounted 5-20 cm off the rig's origin with a few
degrees of tilt, with its own focal length, readout time and direction, and a stamp up to
``stamp_spread`` from the others (unsynchronized cameras). The rig frame is camera-like (x right,
y down, z forward); a camera of yaw ``psi`` looks along ``(sin psi, 0, cos psi)`` of the rig. The
tests of the rig estimator and ``python -m benchmarks.bench_rig`` use them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..camera import CameraModel
from ..frames import Mounting
from ..geometry import (
    camera_position,
    matrix_to_rotvec,
    nearest_rotation,
    rotvec_to_matrix,
    rs_project_exact,
    rs_project_linear,
    skew,
)
from ..pose import RSModel

if TYPE_CHECKING:
    from ..estimation.estimate import EstimateOptions

__all__ = [
    "FOCAL_PX",
    "FOV_DEG",
    "FRAME_SPAN",
    "IMAGE_SIZE",
    "LAYOUTS",
    "READOUTS",
    "Rig",
    "RigCamera",
    "RigFrame",
    "SyntheticFrame",
    "camera_frame",
    "make_frame",
    "make_rig",
    "paper_camera",
    "protocol_options",
    "random_rotation",
    "rig_frame",
    "rig_motion",
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


# ------------------------------------------------------------ cameras and rigs of an RSModel
#: cameras of a rig of M cameras: (name, yaw rad) each
LAYOUTS = {
    1: (("front", 0.0),),
    2: (("front", 0.0), ("back", np.pi)),
    3: (("front", 0.0), ("left", -np.pi / 2), ("right", np.pi / 2)),
    4: (("front", 0.0), ("right", np.pi / 2), ("back", np.pi), ("left", -np.pi / 2)),
}
#: readout directions, in the order the cameras of a rig take them
READOUTS = ("top_to_bottom", "left_to_right", "bottom_to_top", "right_to_left")


def camera_frame(
    camera: CameraModel,
    model: RSModel | tuple,
    n: int,
    rng: np.random.Generator,
    noise_px: float = 0.5,
    outliers: float = 0.2,
    depth: tuple[float, float] = (2.0, 8.0),
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One camera's frame of ``n`` correspondences: world points drawn in its field of view at
    ``depth`` (m) from it at its reference line, projected by its exact RS projection
    (:meth:`~rs_localizer.camera.CameraModel.project_rs`) of ``model`` ``(R, C, w, t)`` (per
    unit r; points that leave the image at their capture time are drawn again), noised
    (``noise_px`` per axis, px) and a share ``outliers`` of them (each row with that
    probability) replaced by pixels uniform over the image.

    Returns:
        (pixels (n, 2), world points (n, 3) m, outlier rows (n,) bool).
    """
    Rp, Cp, wp, tp = model
    half = 0.5 * np.array([camera.width, camera.height]) / np.diag(camera.K)[:2] * 0.95
    uv, X = np.zeros((0, 2)), np.zeros((0, 3))
    while len(uv) < n:
        xn = rng.uniform(-half, half, (4 * n, 2))
        z = rng.uniform(*depth, 4 * n)
        Xw = (np.c_[xn * z[:, None], z] - Cp) @ Rp
        p = camera.project_rs(Xw, Rp, Cp, wp, tp)
        ok = np.isfinite(p).all(axis=1) & camera.in_image(p)
        uv = np.vstack([uv, p[ok]])[:n]
        X = np.vstack([X, Xw[ok]])[:n]
    uv = uv + rng.normal(size=uv.shape) * noise_px
    bad = rng.random(n) < outliers
    uv[bad] = rng.uniform([0, 0], [camera.width - 1, camera.height - 1], (int(bad.sum()), 2))
    return uv, X, bad


@dataclass(frozen=True, eq=False)
class RigCamera:
    """One camera of a simulated rig.

    Attributes:
        name: its place on the rig (``front``, ``back``, ``left``, ``right``).
        camera: intrinsics and RS timing (no lens distortion).
        mounting: its :class:`~rs_localizer.frames.Mounting` on the rig (``x_cam = R x_rig +
            c``).
        stamp_offset: its reference line's capture time minus the rig's reference time (s).
    """

    name: str
    camera: CameraModel
    mounting: Mounting
    stamp_offset: float

    @property
    def centre(self) -> np.ndarray:
        """(3,) the camera centre in the rig frame (m)."""
        return self.mounting.position

    def model(self, truth: RSModel) -> RSModel:
        """The camera's single-camera model at its reference line (per unit r) of the rig's
        ``truth`` (:func:`~rs_localizer.estimation.result.camera_model_of_rig`)."""
        from ..estimation.result import camera_model_of_rig

        spr = self.camera.seconds_per_unit_r
        return camera_model_of_rig(truth, self.mounting, self.stamp_offset, spr)


@dataclass(frozen=True, eq=False)
class Rig:
    """A simulated rig: its cameras (:class:`RigCamera`)."""

    cameras: tuple[RigCamera, ...]

    def __len__(self) -> int:
        return len(self.cameras)


@dataclass(frozen=True, eq=False)
class RigFrame:
    """One simulated rig frame.

    Attributes:
        views: one :class:`~rs_localizer.estimation.view.View` per camera (what
            :func:`~rs_localizer.estimation.rig.estimate_rig_pose` takes).
        truth: the rig's :class:`~rs_localizer.pose.RSModel` ``(R, C, w, t)`` at its reference
            time (``w`` rad/s, ``t`` m/s: :mod:`~rs_localizer.estimation.rig`).
        outliers: one (N_c,) bool per camera: rows replaced by outliers.
        rig: the rig.
    """

    views: list
    truth: RSModel
    outliers: tuple
    rig: Rig

    def camera_truth(self, c: int) -> RSModel:
        """Camera c's true single-camera model at its reference line (per unit r)."""
        return self.rig.cameras[c].model(self.truth)


def make_rig(
    m: int,
    rng: np.random.Generator,
    readout_time: tuple[float, float] = (0.015, 0.035),
    stamp_spread: float = 0.01,
    lever: tuple[float, float] = (0.05, 0.2),
    tilt: float = 0.05,
    focal: tuple[float, float] = (450.0, 600.0),
    size: tuple[int, int] = (640, 480),
) -> Rig:
    """A rig of ``m`` (1-4) cameras laid out as :data:`LAYOUTS`.

    Args:
        m: number of cameras. rng: the random generator.
        readout_time: (lo, hi) s, each camera's frame readout time drawn uniformly (0, 0: global
            shutter cameras).
        stamp_spread: s, the stamps drawn uniformly within ``+- stamp_spread / 2`` of the rig's
            reference time (at most ``stamp_spread`` apart; 0: synchronized).
        lever: (lo, hi) m, each camera centre's distance from the rig's origin.
        tilt: rad, the standard deviation of each mounting's random tilt off its layout.
        focal: (lo, hi) px, each camera's focal length. size: (width, height) px.
    Raises:
        ValueError: ``m`` not in 1..4.
    """
    if m not in LAYOUTS:
        raise ValueError(f"make_rig: a rig has 1 to 4 cameras, got {m}")
    width, height = size
    cams = []
    for k, (name, yaw) in enumerate(LAYOUTS[m]):
        f = rng.uniform(*focal)
        K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1.0]])
        cam = CameraModel.from_readout_time(
            K, rng.uniform(*readout_time), width, height, readout=READOUTS[k % 4]
        )
        # camera axes in the rig frame: the layout's yaw about y, then a small tilt
        axes = rotvec_to_matrix([0.0, yaw, 0.0]) @ rotvec_to_matrix(rng.normal(size=3) * tilt)
        Rc = axes.T
        d = rng.normal(size=3)
        centre = d / np.linalg.norm(d) * rng.uniform(*lever)
        stamp = rng.uniform(-0.5, 0.5) * stamp_spread
        cams.append(RigCamera(name, cam, Mounting(Rc, -Rc @ centre), float(stamp)))
    return Rig(tuple(cams))


def rig_motion(
    rng: np.random.Generator, angular_speed: float = 1.5, linear_speed: float = 1.5
) -> RSModel:
    """A random rig pose and constant velocity: ``R`` uniform-ish (a normal rotation vector),
    ``C`` normal (m), ``w`` of norm ``angular_speed`` (rad/s), ``t`` of norm ``linear_speed``
    (m/s), in random directions. Returns the rig's :class:`~rs_localizer.pose.RSModel`."""
    w = rng.normal(size=3)
    t = rng.normal(size=3)
    return RSModel(
        rotvec_to_matrix(rng.normal(size=3)),
        rng.normal(size=3),
        w * angular_speed / np.linalg.norm(w),
        t * linear_speed / np.linalg.norm(t),
    )


def rig_frame(
    rig: Rig,
    truth: RSModel | tuple,
    counts: list[int] | tuple[int, ...],
    rng: np.random.Generator,
    noise_px: float = 0.5,
    outliers: float = 0.2,
    depth: tuple[float, float] = (2.0, 8.0),
) -> RigFrame:
    """One rig frame: ``counts[c]`` correspondences of camera c, its :func:`camera_frame` of
    the rig's ``truth`` composed with its mounting and stamp offset (:meth:`RigCamera.model`).

    Args:
        rig: the rig. truth: the rig's ``(R, C, w, t)`` (:func:`rig_motion`).
        counts: (M,) points per camera (0 allowed). rng: the random generator.
        noise_px, outliers, depth: as :func:`camera_frame`.
    Returns:
        :class:`RigFrame`.
    Raises:
        ValueError: ``counts`` of another length than the rig's cameras.
    """
    from ..estimation.view import View

    if len(counts) != len(rig):
        raise ValueError(f"rig_frame: {len(counts)} counts for {len(rig)} cameras")
    truth = RSModel(*(np.asarray(a, dtype=float) for a in truth))
    views, bad_rows = [], []
    for k, n in zip(rig.cameras, counts, strict=True):
        uv, X, bad = camera_frame(k.camera, k.model(truth), n, rng, noise_px, outliers, depth)
        views.append(View(uv, X, k.camera, k.mounting, k.stamp_offset, name=k.name))
        bad_rows.append(bad)
    return RigFrame(views, truth, tuple(bad_rows), rig)
