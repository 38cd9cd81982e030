"""Robot frames: the camera's pose, twist and covariances -> those of the robot base.

The estimator describes the camera optical frame (REP 103 optical: z forward, x right, y down):
its pose in the map ``T_map_cam = (R_mc, p_c)`` (camera -> map rotation, camera centre in m), its
velocity in its own frame (angular ``omega_c`` rad/s, linear ``v_c`` m/s = ``R_mc^T dp_c/dt``)
and 6x6 covariances (pose: ROS order x, y, z, rot x, rot y, rot z with the rotation perturbation
about the *map* axes, ``R_mc = expm([phi]x) R_mc_hat``; twist: vx, vy, vz, wx, wy, wz in the
camera frame). A robot wants the same quantities for its body frame ``base_link`` (REP 103
body: x forward, y left, z up).

The camera is rigidly mounted: :class:`Mounting` is the pose of the camera optical frame in the
base frame, ``T_base_cam = (R_bc, t_bc)`` (its ``rotation`` and ``translation``) with
``p_base = R_bc p_cam + t_bc`` -- the transform ``base_link -> camera_optical_frame`` of a
static TF publisher (parent base, child camera). Then

* pose: ``T_map_base = T_map_cam T_base_cam^-1``: ``R_mb = R_mc R_bc^T``,
  ``p_b = p_c - R_mb t_bc``;
* twist of the rigid body, in the base frame: ``omega_b = R_bc omega_c``,
  ``v_b = R_bc v_c + t_bc x omega_b`` (velocity of the base origin);
* covariances, first order (exact for the twist, which is linear): pose
  ``J = [[I, [R_mb t_bc]x], [0, I]]`` (map-axis rotation perturbations stay the same), twist
  ``J = [[R_bc, [t_bc]x R_bc], [0, R_bc]]``; ``Sigma_b = J Sigma_c J^T``.

Pure NumPy (model layer, no ROS); the node applies :func:`camera_to_base` in its publish step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from .geometry import skew
from .pose import PoseWithCovariance, RSPose

__all__ = [
    "OPTICAL_TO_BODY_QUATERNION",
    "Mounting",
    "base_pose",
    "base_pose_covariance",
    "base_twist",
    "base_twist_covariance",
    "camera_to_base",
]

#: ``(x, y, z, w)`` of the rotation optical -> body for a camera looking along the base's x axis
#: (camera z = base x, camera x = -base y, camera y = -base z): the REP 103 convention change
OPTICAL_TO_BODY_QUATERNION = (-0.5, 0.5, -0.5, 0.5)


@dataclass(frozen=True, eq=False)
class Mounting:
    """The pose of a camera's optical frame in a body frame (``base_link``, a rig's frame).

    Held in both of its forms, each exactly as it was given (the other derived from it):

    * the estimator's: ``x_cam = R x_body + c`` -- :attr:`R` (3, 3) body -> camera rotation,
      :attr:`c` (3,) m. ``Mounting(R, c)`` stores them as given.
    * tf's: ``p_body = rotation p_cam + translation`` -- :attr:`rotation` (3, 3) camera ->
      body (``R_bc = R^T``), :attr:`translation` (3,) m, the camera's optical centre in the
      body frame (``t_bc = -R^T c``), the transform ``body -> camera_optical_frame`` of a
      static TF publisher (parent body, child camera). :meth:`from_pose` and
      :meth:`from_translation_quaternion` store the translation as given (``R`` is the
      transpose of the rotation given, ``c = -R translation``).

    Attributes:
        R: (3, 3) body -> camera optical frame rotation. c: (3,) m.
        covariance: (6, 6) the mounting's uncertainty over (rotation of the camera on the
            body [rad, body axes: ``R_body_cam = expm([theta]x) R_body_cam_0``], the camera's
            position in the body frame [m]), e.g. from
            :func:`~rs_localizer.calibration.calibrate_mountings`; the rig estimator adds it
            to the rig pose's covariance. None: the mounting is taken as exact.
        time_offset_std: s, the standard deviation of the camera's time offset on the body's
            clock (its stamps' error, e.g. ``calibrate-rig``'s estimate's); the rig estimator
            adds, per rig frame, the pose's uncertainty of moving the camera's observations
            along that frame's twist by it. 0 (default): the camera's stamps are taken as
            exact.
        rotation: (3, 3) ``R_bc = R^T``, camera-frame vectors -> body-frame vectors.
        translation: (3,) m ``t_bc``, the camera's optical centre in the body frame (also
            :attr:`position`).

    Raises:
        ValueError: ``R`` or ``c`` not finite (``a mounting must be finite``), ``R`` not a
            rotation (``R R^T`` off the identity by more than 1e-6, or a reflection), a
            covariance that is not (6, 6), finite and positive semi-definite (it is stored
            symmetrized), a ``time_offset_std`` that is negative or not finite.
    """

    R: np.ndarray
    c: np.ndarray
    covariance: np.ndarray | None = None
    time_offset_std: float = 0.0
    rotation: np.ndarray = field(init=False, repr=False)
    translation: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        R = np.asarray(self.R, dtype=float).reshape(3, 3)
        c = np.asarray(self.c, dtype=float).reshape(3)
        if not (np.isfinite(R).all() and np.isfinite(c).all()):
            raise ValueError("a mounting must be finite")
        if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
            raise ValueError("a mounting's R must be a rotation")
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "c", c)
        object.__setattr__(self, "rotation", np.ascontiguousarray(R.T))
        object.__setattr__(self, "translation", -R.T @ c)
        if self.covariance is not None:
            C = np.asarray(self.covariance, dtype=float)
            if C.shape != (6, 6) or not np.isfinite(C).all():
                raise ValueError("a mounting's covariance must be (6, 6) and finite")
            C = 0.5 * (C + C.T)
            if np.linalg.eigvalsh(C).min() < -1e-12 * max(1.0, float(np.abs(C).max())):
                raise ValueError("a mounting's covariance must be positive semi-definite")
            object.__setattr__(self, "covariance", C)
        s = float(self.time_offset_std)
        if not (math.isfinite(s) and s >= 0.0):
            raise ValueError("a mounting's time_offset_std must be finite and >= 0")
        object.__setattr__(self, "time_offset_std", s)

    @classmethod
    def from_pose(
        cls,
        R_body_cam: np.ndarray,
        p_body_cam: np.ndarray,
        covariance: np.ndarray | None = None,
        time_offset_std: float = 0.0,
    ) -> Mounting:
        """The mounting of a camera whose optical frame is at ``p_body_cam`` (3,) m in the body
        frame, turned by ``R_body_cam`` (3, 3) camera -> body (a static transform body ->
        camera as tf gives it); ``covariance``, ``time_offset_std`` as the attributes.

        Raises:
            ValueError: not finite, not a rotation, or a covariance that is not (6, 6)
                positive semi-definite.
        """
        R = np.asarray(R_body_cam, dtype=float).T
        p = np.asarray(p_body_cam, dtype=float)
        mounting = cls(R, -R @ p, covariance, time_offset_std)
        object.__setattr__(mounting, "rotation", mounting.R.T.copy())
        object.__setattr__(mounting, "translation", p.reshape(3).copy())
        return mounting

    @classmethod
    def from_translation_quaternion(cls, translation, quaternion) -> Mounting:
        """From a translation ``(x, y, z)`` in m and a quaternion ``(x, y, z, w)`` (ROS order,
        normalized here), as in ``static_transform_publisher x y z qx qy qz qw base camera``:
        :meth:`from_pose` of their rotation and the translation.

        Raises:
            ValueError: translation not 3 finite numbers; quaternion not 4 finite numbers or
                of norm outside [0.5, 2] (a typo rather than rounding).
        """
        t = np.asarray(translation, dtype=float).reshape(-1)
        q = np.asarray(quaternion, dtype=float).reshape(-1)
        if t.shape != (3,) or not np.isfinite(t).all():
            raise ValueError(f"translation must be 3 finite numbers (m), got {t.tolist()}")
        if q.shape != (4,) or not np.isfinite(q).all():
            raise ValueError(
                f"rotation must be a quaternion of 4 finite numbers (x, y, z, w), got {q.tolist()}"
            )
        n = float(np.linalg.norm(q))
        if not 0.5 <= n <= 2.0:
            raise ValueError(
                f"rotation quaternion {q.tolist()} has norm {n:.3g}, expected 1 (order x, y, z, w)"
            )
        return cls.from_pose(Rotation.from_quat(q / n).as_matrix(), t)

    @property
    def position(self) -> np.ndarray:
        """(3,) m, the camera's optical centre in the body frame (:attr:`translation`)."""
        return self.translation

    @property
    def matrix(self) -> np.ndarray:
        """(4, 4) homogeneous ``T_body_cam`` (camera -> body)."""
        T = np.eye(4)
        T[:3, :3] = self.rotation
        T[:3, 3] = self.translation
        return T


def base_pose(orientation, position, mounting: Mounting):
    """Camera pose in the map -> base pose in the map.

    Args:
        orientation: (3, 3) camera -> map rotation ``R_mc``. position: (3,) camera centre (m).
    Returns:
        ``(R_mb (3, 3), p_b (3,))``: ``R_mb = R_mc R_bc^T``, ``p_b = p_c - R_mb t_bc``.
    """
    R_mb = np.asarray(orientation, dtype=float) @ mounting.rotation.T
    return R_mb, np.asarray(position, dtype=float) - R_mb @ mounting.translation


def base_twist(angular_velocity, linear_velocity, mounting: Mounting):
    """Camera velocity in the camera frame -> the base's rigid-body velocity in the base frame.

    Args:
        angular_velocity, linear_velocity: (3,) ``omega_c`` (rad/s), ``v_c`` (m/s, velocity of
            the camera centre in camera axes).
    Returns:
        ``(omega_b, v_b)``: ``omega_b = R_bc omega_c``, ``v_b = R_bc v_c + t_bc x omega_b``
        (velocity of the base origin in base axes).
    """
    om_b = mounting.rotation @ np.asarray(angular_velocity, dtype=float)
    v_b = mounting.rotation @ np.asarray(linear_velocity, dtype=float)
    return om_b, v_b + np.cross(mounting.translation, om_b)


def _covariance6(cov, what: str):
    """``cov`` as a (6, 6) float array (``None`` stays ``None``); ValueError if not 6x6."""
    if cov is None:
        return None
    cov = np.asarray(cov, dtype=float)
    if cov.shape != (6, 6):
        raise ValueError(f"{what} covariance must be 6x6, got {cov.shape}")
    return cov


def base_pose_covariance(cov, orientation, mounting: Mounting):
    """(6, 6) camera pose covariance (ROS order, map frame, map-axis rotation perturbation) ->
    base pose covariance in the same convention (first order). ``None`` stays ``None``.

    Args:
        cov: (6, 6) or None. orientation: (3, 3) camera -> map rotation ``R_mc``.
    Raises:
        ValueError: ``cov`` is not 6x6.
    """
    cov = _covariance6(cov, "pose")
    if cov is None:
        return None
    a = np.asarray(orientation, dtype=float) @ mounting.rotation.T @ mounting.translation
    J = np.eye(6)
    J[0:3, 3:6] = skew(a)
    return J @ cov @ J.T


def base_twist_covariance(cov, mounting: Mounting):
    """(6, 6) camera twist covariance (vx, vy, vz, wx, wy, wz; camera frame) -> base twist
    covariance (base frame); exact, the map is linear. ``None`` stays ``None``.

    Raises:
        ValueError: ``cov`` is not 6x6.
    """
    cov = _covariance6(cov, "twist")
    if cov is None:
        return None
    R, t = mounting.rotation, mounting.translation
    J = np.zeros((6, 6))
    J[0:3, 0:3] = R
    J[0:3, 3:6] = skew(t) @ R
    J[3:6, 3:6] = R
    return J @ cov @ J.T


def camera_to_base(camera: PoseWithCovariance, mounting: Mounting) -> PoseWithCovariance:
    """All of it at once: the camera's ``pose`` and (6, 6) ``pose_covariance`` and
    ``twist_covariance`` (or None; e.g. an :class:`~rs_localizer.RSPoseEstimate` or a
    :class:`~rs_localizer.tracking.FusedPose`) -> the base's: ``pose`` orientation (3, 3)
    base -> map ``R_mb``, position (3,) base origin in the map (m), angular and linear
    velocity (3,) of the base in the base frame (rad/s, m/s), the camera pose's
    ``stamp_ns``; ``pose_covariance`` (6, 6) ROS order, map frame (rotation about the map
    axes), ``twist_covariance`` (6, 6) ROS order, base frame; None stays None (module
    docstring).

    Raises:
        ValueError: a covariance that is not 6x6.
    """
    cam = camera.pose
    R_mb, p_b = base_pose(cam.orientation, cam.position, mounting)
    om_b, v_b = base_twist(cam.angular_velocity, cam.linear_velocity, mounting)
    return PoseWithCovariance(
        pose=RSPose(R_mb, p_b, om_b, v_b, cam.stamp_ns),
        pose_covariance=base_pose_covariance(camera.pose_covariance, cam.orientation, mounting),
        twist_covariance=base_twist_covariance(camera.twist_covariance, mounting),
    )
