"""The library's settings of a camera's video and of a rig, built from values by field name,
without ROS.

The node's parameter table (:data:`rs_localizer.ros.params.PARAMETERS`) says which settings
field each parameter sets; :func:`rs_localizer.ros.params.option_fields` turns a set of
parameter values into a tree of those fields (``{"ransac": {"seed": 3}, "refine": {"enabled":
True}}``), and the functions here build the settings objects from such a tree. A library user
may pass a tree of their own.

- :func:`with_fields`: any frozen settings dataclass with some of its fields (nested ones too)
  replaced, e.g. :class:`~rs_localizer.estimation.options.EstimateOptions` or
  :class:`~rs_localizer.tracking.tracker.TrackerOptions`;
- :func:`gyro_settings`: the gyro's use in the estimate
  (:class:`~rs_localizer.tracking.sequence.GyroSettings`) from a mounting quaternion;
- :func:`rig_settings`: a rig's (:class:`~rs_localizer.tracking.video.LocalizerSettings`) from the
  single camera's estimator and tracker options.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any, TypeVar

import numpy as np

from ..estimation.options import EstimateOptions
from ..frames import Mounting
from .sequence import GyroSettings
from .tracker import TrackerOptions
from .video import SINGLE_CAMERA_SOLVER, LocalizerSettings

__all__ = ["gyro_settings", "rig_settings", "with_fields"]

T = TypeVar("T")


def with_fields(obj: T, fields: Mapping[str, Any]) -> T:
    """Frozen dataclass ``obj`` with the fields of ``fields`` replaced: a value replaces the
    field of its name, a mapping the fields of the nested dataclass of its name (recursively,
    ``{"ransac": {"seed": 3}}``); every other field keeps ``obj``'s value.

    Raises:
        TypeError: a name that is not a field of its dataclass. TypeError, ValueError: from
            the classes' own validation (e.g. a ``max_angular_velocity`` <= 0).
    """
    changes = {
        k: with_fields(getattr(obj, k), v) if isinstance(v, Mapping) else v
        for k, v in fields.items()
    }
    return dataclasses.replace(obj, **changes)


def gyro_settings(
    rotation: Sequence[float], gyro_bias: np.ndarray, fields: Mapping[str, Any]
) -> GyroSettings:
    """The gyro's use in the estimate.

    Args:
        rotation: quaternion x, y, z, w of the rotation IMU -> camera optical frame.
        gyro_bias: (3,) rad/s, IMU frame.
        fields: the other :class:`GyroSettings` fields by name (``time_offset``,
            ``gyro_noise``, ``gyro_bias_sigma``, ``wait``, ``buffer``, ``max_rate``,
            ``max_gap``, ``estimate_bias``, ``bias_random_walk``).

    Raises:
        ValueError: ``rotation`` not a quaternion (4 finite numbers of norm near 1). TypeError:
            a name in ``fields`` that is not a field.
    """
    R = Mounting.from_translation_quaternion([0.0, 0.0, 0.0], rotation).rotation
    return GyroSettings(R_cam_imu=R, gyro_bias=gyro_bias, **fields)


def rig_settings(
    mounts: Mapping[str, Mounting],
    options: EstimateOptions,
    tracking: TrackerOptions | None,
    *,
    window: float,
    stop_after: float,
    stamp_row: float,
    time_reset_ns: int,
    imu: GyroSettings | None = None,
    max_points: int | None = None,
    time_offsets: Mapping[str, float] | None = None,
    solver: str = SINGLE_CAMERA_SOLVER,
) -> LocalizerSettings:
    """A rig's settings with the single camera's estimator and tracker options as they are:
    ``options`` (the rig estimator takes the RANSAC threshold, iterations, confidence, inliers
    and seed, the refinement and the velocity bounds from them) and ``tracking`` (the gates,
    explained ratio, ``max_gap``, the twist filter; :attr:`LocalizerSettings.tracking`; None: every
    rig frame alone).

    Args:
        mounts: camera name -> its mounting on the rig, in the cameras' order.
        window, stop_after (s), stamp_row (px), time_reset_ns: see :class:`LocalizerSettings`.
        imu: a gyro on the rig (``R_cam_imu``: IMU -> rig), None: none; the rig solves a frame
            when its last camera arrives, so it never waits for samples (``wait`` set to 0).
        max_points: the most rows a camera's image gives the rig estimator, as for one camera
            (:attr:`LocalizerSettings.max_points`); None: no cap.
        time_offsets: camera -> s added to its stamps (:attr:`LocalizerSettings.time_offsets`);
            None: none.
        solver: the minimal solver of a rig of one camera (:attr:`LocalizerSettings.solver`:
            what its frames are solved with, as the camera's own video).

    Raises:
        ValueError: from :class:`LocalizerSettings` (e.g. no cameras).
    """
    return LocalizerSettings(
        dict(mounts),
        window=window,
        stop_after=stop_after,
        stamp_row=stamp_row,
        time_reset_ns=time_reset_ns,
        options=options,
        tracking=tracking,
        imu=None if imu is None else dataclasses.replace(imu, wait=0.0),
        max_points=max_points,
        time_offsets=dict(time_offsets or {}),
        solver=solver,
    )
