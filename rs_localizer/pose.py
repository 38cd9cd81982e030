"""The rolling-shutter camera state, typed: :class:`RSPose` (what a localized frame is, in
physical units) and :class:`RSModel` (the same state as the minimal solvers' model).

Frames: world/map and the camera optical frame (REP 103). The two forms and the conversion
between them (Kukelova, Albl, Sugimoto, Pajdla, "Linear Solution to the Minimal Absolute Pose
Rolling Shutter Problem", ACCV 2018, eq. 4: a point seen at RS coordinate ``r`` projects as
``X_cam = (I + r [w]x) R X + C + r t``):

- :class:`RSModel` ``(R, C, w, t)``: ``R`` (3, 3) world -> camera and ``C`` (3,) at the
  reference row, ``w``, ``t`` (3,) per unit RS coordinate (rad, m per normalized unit). It is a
  ``NamedTuple``: it unpacks as the bare ``(R, C, w, t)`` tuple the numba kernels and the
  estimator's stages pass around.
- :class:`RSPose`: ``orientation`` (3, 3) camera -> world (``R^T``), ``position`` (3,) m, the
  camera centre in the world (``-R^T C``), ``angular_velocity`` (3,) rad/s and
  ``linear_velocity`` (3,) m/s of the camera in its own optical frame, at ``stamp_ns`` (the
  reference row's capture time, ns; None when unknown).

With ``s`` seconds per unit RS coordinate (``CameraModel.seconds_per_unit_r``), the camera's
angular velocity is ``-w / s`` and its linear velocity ``(w x C - t) / s`` (camera frame). The
conversion is written here once: :func:`model_twist` (model -> twist, a numba kernel; its
``py_func`` is the same code in plain Python, for code that compiles nothing),
:func:`model_twist_jacobian` (its Jacobian over the model's ``(delta, C, w, t)``) and
:func:`model_from_twist` (twist -> model); :meth:`RSPose.from_model` / :meth:`RSPose.model`
use them.

:class:`PoseWithCovariance` holds an :class:`RSPose` and its (6, 6) pose and twist covariances
(ROS order); the message conversions take it. The library's results are one (subclasses that
add their own fields): an estimate, a
camera's or a rig's (:class:`~rs_localizer.estimation.result.RSPoseEstimate`, which also
holds its ``model``), a fused frame
(:class:`~rs_localizer.tracking.sequence.FusedPose`) and a base state
(:func:`~rs_localizer.frames.camera_to_base`) hold ``pose``, ``pose_covariance`` and
``twist_covariance`` as their own fields: read ``x.pose.orientation``, ``x.pose.position``,
..., and the solver's model as ``x.model.R``, ... The fused state
(:class:`~rs_localizer.tracking.fusion.FusedState`) holds its ``pose`` and (12, 12)
``covariance``, and a predicted model (:class:`~rs_localizer.estimation.options.InitialModel`)
its ``model``. The numba kernels take the model's bare arrays (an :class:`RSModel` unpacks as
them). The twist filter fuses an estimate as it is
(:meth:`~rs_localizer.tracking.fusion.TwistFilter.update` takes the one result type of a
camera's and a rig's estimator, :class:`~rs_localizer.estimation.result.RSPoseEstimate`).
"""

from __future__ import annotations

import math
from dataclasses import MISSING, dataclass, field, fields
from typing import Any, NamedTuple

import numpy as np

from ._jit import kernel

__all__ = [
    "ROS_ORDER",
    "PoseWithCovariance",
    "RSModel",
    "RSPose",
    "frozen_instance",
    "model_from_twist",
    "model_twist",
    "model_twist_jacobian",
]


@kernel
def model_twist(C, w, t, s):
    """(6,) the camera's velocities ``z = (v, omega) = ((w x C - t) / s, -w / s)`` (ROS twist
    order; m/s, rad/s, camera frame) from the model's ``C`` (3,) m, ``w`` (3,) rad and ``t``
    (3,) m per unit RS coordinate and ``s > 0`` seconds per unit RS coordinate (module
    docstring; docs/architecture.md "Conventions"). A numba kernel; ``model_twist.py_func``
    runs the same code without compiling. Every caller (the estimator's outputs, prior,
    refinement and sensitivity, the NumPy path, :class:`RSPose`, mapping) goes through here, so
    the twist is the same to the last bit wherever it is computed: it multiplies by the one
    reciprocal ``1 / s`` (a division per entry can differ from it in the last bit, which the
    tracker's feedback would carry into the next frames)."""
    z = np.empty(6)
    inv = 1.0 / s
    z[0] = (w[1] * C[2] - w[2] * C[1] - t[0]) * inv
    z[1] = (w[2] * C[0] - w[0] * C[2] - t[1]) * inv
    z[2] = (w[0] * C[1] - w[1] * C[0] - t[2]) * inv
    for a in range(3):
        z[3 + a] = -w[a] * inv
    return z


@kernel
def model_twist_jacobian(C, w, s):
    """(6, 12) Jacobian of :func:`model_twist` over the model's ``(delta, C, w, t)`` (``delta``
    the rotation increment, on which the twist does not depend): ``dv/dC = [w]x / s``,
    ``dv/dw = -[C]x / s``, ``dv/dt = -I / s``, ``domega/dw = -I / s`` (each entry times the
    reciprocal ``1 / s``, as :func:`model_twist`). A numba kernel;
    ``model_twist_jacobian.py_func`` runs the same code without compiling."""
    Jz = np.zeros((6, 12))
    inv = 1.0 / s
    Jz[0, 4], Jz[0, 5] = -w[2] * inv, w[1] * inv
    Jz[1, 3], Jz[1, 5] = w[2] * inv, -w[0] * inv
    Jz[2, 3], Jz[2, 4] = -w[1] * inv, w[0] * inv
    Jz[0, 7], Jz[0, 8] = C[2] * inv, -C[1] * inv
    Jz[1, 6], Jz[1, 8] = -C[2] * inv, C[0] * inv
    Jz[2, 6], Jz[2, 7] = C[1] * inv, -C[0] * inv
    for a in range(3):
        Jz[a, 9 + a] = -inv
        Jz[3 + a, 6 + a] = -inv
    return Jz


def model_from_twist(
    C: np.ndarray,
    angular_velocity: np.ndarray,
    linear_velocity: np.ndarray,
    seconds_per_unit_r: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of :func:`model_twist`: the model's ``(w, t)`` (3,) per unit RS coordinate
    of a camera at ``C`` (3,) m moving with ``angular_velocity`` (3,) rad/s and
    ``linear_velocity`` (3,) m/s (camera frame), ``s = seconds_per_unit_r``:
    ``w = -omega s``, ``t = w x C - v s``. Plain NumPy (the cross product written out: NumPy's
    ``np.cross`` costs ~10x more at this size)."""
    s = float(seconds_per_unit_r)
    w = -np.asarray(angular_velocity, dtype=float) * s
    C = np.asarray(C, dtype=float)
    wxC = np.array(
        [w[1] * C[2] - w[2] * C[1], w[2] * C[0] - w[0] * C[2], w[0] * C[1] - w[1] * C[0]]
    )
    return w, wxC - np.asarray(linear_velocity, dtype=float) * s


class RSModel(NamedTuple):
    """The solvers' rolling-shutter model (see the module docstring): ``R`` (3, 3) world ->
    camera, ``C`` (3,) m, ``w`` (3,) rad and ``t`` (3,) m per unit RS coordinate."""

    R: np.ndarray
    C: np.ndarray
    w: np.ndarray
    t: np.ndarray

    @classmethod
    def identity(cls) -> RSModel:
        """The model of a camera at the world origin, axes aligned, not moving: ``R`` the
        (3, 3) identity, ``C``, ``w``, ``t`` (3,) zeros (new arrays on each call)."""
        return cls(np.eye(3), np.zeros(3), np.zeros(3), np.zeros(3))


def _zeros3() -> np.ndarray:
    return np.zeros(3)


#: per dataclass: (its init fields' names, those without a default, {name: default},
#: ((name, default factory), ...)), for :func:`frozen_instance`
_FROZEN_FIELDS: dict = {}


def frozen_instance(cls: type, values: dict[str, Any]) -> Any:
    """The instance of the frozen dataclass ``cls`` whose fields hold ``values`` (by name;
    every field not given at its default), as its constructor builds it (no copies, no
    checks of the values), without the constructor's field-by-field
    ``object.__setattr__``: the results built on every frame (:meth:`RSPose._trusted`,
    ``RSPoseEstimate._trusted``) cost a few dictionary stores. The values must not be
    changed afterwards.

    Raises:
        TypeError: a name that is no field of ``cls``, or a field without a default not given
            (as the constructor)."""
    hit = _FROZEN_FIELDS.get(cls)
    if hit is None:
        fs = [f for f in fields(cls) if f.init]
        hit = _FROZEN_FIELDS[cls] = (
            frozenset(f.name for f in fs),
            frozenset(f.name for f in fs if f.default is MISSING and f.default_factory is MISSING),
            {f.name: f.default for f in fs if f.default is not MISSING},
            tuple((f.name, f.default_factory) for f in fs if f.default_factory is not MISSING),
        )
    names, required, plain, factories = hit
    given = values.keys()
    if not (given <= names and required <= given):
        raise TypeError(f"{cls.__name__}: unknown or missing fields in {sorted(values)}")
    obj = object.__new__(cls)
    d = obj.__dict__
    if len(values) < len(names):  # (the defaults of the fields not given)
        d.update(plain)
        for name, factory in factories:
            if name not in values:
                d[name] = factory()
    d.update(values)
    return obj


@dataclass(frozen=True, eq=False)
class RSPose:
    """A camera's pose and twist at one time (see the module docstring for frames and units).

    Attributes:
        orientation: (3, 3) camera -> world rotation.
        position: (3,) camera centre in the world (m).
        angular_velocity: (3,) rad/s, camera frame. linear_velocity: (3,) m/s, camera frame.
        stamp_ns: the time of the pose (ns), or None.
    """

    orientation: np.ndarray = field(default_factory=lambda: np.eye(3))
    position: np.ndarray = field(default_factory=_zeros3)
    angular_velocity: np.ndarray = field(default_factory=_zeros3)
    linear_velocity: np.ndarray = field(default_factory=_zeros3)
    stamp_ns: int | None = None

    @classmethod
    def _trusted(
        cls,
        orientation: np.ndarray,
        position: np.ndarray,
        angular_velocity: np.ndarray,
        linear_velocity: np.ndarray,
        stamp_ns: int | None = None,
    ) -> RSPose:
        """An RSPose of these arrays (as the constructor: no copies, no checks) by
        :func:`frozen_instance` (the twist filter's and the estimators' hot paths: a state per
        frame and per prediction). The arrays must not be changed afterwards."""
        return frozen_instance(
            cls,
            {
                "orientation": orientation,
                "position": position,
                "angular_velocity": angular_velocity,
                "linear_velocity": linear_velocity,
                "stamp_ns": stamp_ns,
            },
        )

    @classmethod
    def from_model(
        cls,
        model: RSModel | tuple,
        seconds_per_unit_r: float,
        stamp_ns: int | None = None,
        compiled: bool = False,
    ) -> RSPose:
        """The pose of a solver's model ``(R, C, w, t)`` with ``seconds_per_unit_r`` s per
        unit RS coordinate (0: a global shutter, zero twist); ``compiled``: the twist by the
        compiled :func:`model_twist` (the same values; faster once compiled, so for callers
        on the compiled path).

        Raises:
            ValueError: ``seconds_per_unit_r`` negative or not finite.
        """
        s = float(seconds_per_unit_r)
        if not (math.isfinite(s) and s >= 0):
            raise ValueError(f"seconds_per_unit_r must be finite and >= 0, got {s}")
        R, C, w, t = model
        Rt, C = np.asarray(R, dtype=float).T, np.asarray(C, dtype=float)
        if s == 0:
            om, v = np.zeros(3), np.zeros(3)
        else:
            w, t = np.asarray(w, dtype=float), np.asarray(t, dtype=float)
            z = (model_twist if compiled else model_twist.py_func)(C, w, t, s)
            om, v = z[3:6], z[0:3]
        return cls._trusted(Rt, -Rt @ C, om, v, stamp_ns)

    def model(self, seconds_per_unit_r: float) -> RSModel:
        """The solver's model of this pose (the inverse of :meth:`from_model`): ``R = O^T``,
        ``C = -R p``, ``w = -omega s``, ``t = w x C - v s`` with ``s = seconds_per_unit_r``
        (s per unit RS coordinate); a global shutter (``s <= 0``) gives zero ``w`` and ``t``.
        The tracker's prediction of each frame goes through here."""
        s = float(seconds_per_unit_r)
        R = np.asarray(self.orientation, dtype=float).T
        C = -R @ np.asarray(self.position, dtype=float)
        if s <= 0:
            return RSModel(R, C, np.zeros(3), np.zeros(3))
        w, t = model_from_twist(C, self.angular_velocity, self.linear_velocity, s)
        return RSModel(R, C, w, t)

    @property
    def angular_velocity_world(self) -> np.ndarray:
        """(3,) rad/s, the angular velocity in world axes."""
        return np.asarray(self.orientation) @ np.asarray(self.angular_velocity)

    @property
    def linear_velocity_world(self) -> np.ndarray:
        """(3,) m/s, the linear velocity in world axes."""
        return np.asarray(self.orientation) @ np.asarray(self.linear_velocity)

    def with_twist(
        self,
        angular_velocity: np.ndarray,
        linear_velocity: np.ndarray,
        stamp_ns: int | None = None,
    ) -> RSPose:
        """The same pose with another twist (e.g. a fused one: (3,) rad/s and m/s, camera
        frame), at ``stamp_ns`` (ns; None: this pose's)."""
        return RSPose(
            self.orientation,
            self.position,
            angular_velocity,
            linear_velocity,
            self.stamp_ns if stamp_ns is None else stamp_ns,
        )


#: ROS order of a (6, 6) pose or twist covariance, (x, y, z, rot x, rot y, rot z) and (vx, vy,
#: vz, wx, wy, wz), as indices into the rotation-first order of the estimator's and the twist
#: filter's (12, 12) covariances (rotation, position; then omega, v at 6 + these) and of a
#: :class:`~rs_localizer.frames.Mounting`'s ``covariance`` (rotation, position):
#: ``C[np.ix_(ROS_ORDER, ROS_ORDER)]``. The same indices take ROS order back (the swap of the
#: two halves is its own inverse). Read-only.
ROS_ORDER = np.array([3, 4, 5, 0, 1, 2])
ROS_ORDER.setflags(write=False)


@dataclass(frozen=True, eq=False, kw_only=True)
class PoseWithCovariance:
    """A pose and twist with their covariances (geometry_msgs' ``PoseWithCovariance`` and
    ``TwistWithCovariance`` together); the results of the library are this type (they add
    their own fields), and the message conversions (:mod:`rs_localizer.ros.conversions`) take
    it. Keyword arguments only.

    Attributes:
        pose: the :class:`RSPose` (orientation (3, 3) body -> world, position (3,) m, angular
            (rad/s) and linear (m/s) velocity in the body frame, ``stamp_ns``). The body is
            the camera's optical frame, or the base's or the rig's frame for their states.
        pose_covariance: (6, 6) over (x, y, z [m], rot x, rot y, rot z [rad]) (ROS order),
            world frame (rotation about the world axes), or None: unknown.
        twist_covariance: (6, 6) over (vx, vy, vz [m/s], wx, wy, wz [rad/s]) (ROS order),
            body frame, or None: unknown (e.g. a global shutter, which measures no twist).
    """

    pose: RSPose = field(default_factory=RSPose)
    pose_covariance: np.ndarray | None = None
    twist_covariance: np.ndarray | None = None
