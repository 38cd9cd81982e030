"""A view: one camera's correspondences with the camera, its mounting and its time.

The estimators take views: :func:`~rs_localizer.estimation.rig.estimate_rig_pose` one or many
(a rig frame), the video (:class:`~rs_localizer.tracking.tracker.FrameViews`) a camera's own
view or a rig frame's.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..camera import CameraModel
from ..frames import Mounting
from ..pose import RSModel
from .result import camera_model_of_rig

__all__ = ["View"]


@dataclass(frozen=True, eq=False)
class View:
    """One camera's part of a frame: its correspondences, its camera, its mounting on the
    body posed (a rig's cameras) and its time: a camera alone is one view at the identity
    mounting.

    Attributes:
        uv: (N, 2) measured (distorted) pixels. X: (N, 3) world points (m).
        camera: the camera's intrinsics and RS timing.
        mounting: the camera's :class:`~rs_localizer.frames.Mounting` on the rig (``x_cam =
            mounting.R x_rig + mounting.c``; default: the identity mounting). Its
            ``covariance`` (rotation of the camera on the rig [rad, rig axes], its optical
            centre in the rig frame [m]), when given, enters the rig pose's covariance to
            first order: the refined model's sensitivity to the mounting times this
            covariance; None takes the mounting as exact. ``mounting=None`` stands for a
            camera whose mounting is unknown:
            :func:`~rs_localizer.estimation.rig.estimate_rig_pose` refuses it, naming the
            camera.
        stamp_offset: capture time of the camera's reference line (``camera.reference_line``)
            minus the rig's reference time (s).
        name: the camera's name in error messages (default: its index in the rig frame).
    """

    uv: np.ndarray
    X: np.ndarray
    camera: CameraModel
    mounting: Mounting | None = field(default_factory=lambda: Mounting(np.eye(3), np.zeros(3)))
    stamp_offset: float = 0.0
    name: str = ""

    def camera_model(self, model: RSModel | tuple) -> RSModel:
        """This view's camera's own model at its reference line (per unit r, as its own
        estimate's ``model``) from the rig's ``model`` (``w``, ``t`` per second, an
        estimate's ``model``): :func:`~.result.camera_model_of_rig` at this view's mounting
        and stamp offset."""
        return camera_model_of_rig(
            model, self.mounting, self.stamp_offset, self.camera.seconds_per_unit_r
        )
