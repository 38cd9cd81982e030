"""A camera's or a rig's video, frame after frame (:class:`CameraFrame`), without ROS: one
localizer for one camera or a rig of cameras (:class:`Localizer`; a camera alone is a rig of
one) owns the tracker, the frames waiting for their fused twist, the gyro samples, the online
gyro-bias estimate, the check of the gyro against the image and the time resets; a rig's
cameras name themselves in their frames (``camera_name``). :class:`SequenceLocalizer` is a
camera's adapter over it, with the camera's settings and outputs. The node
(:mod:`rs_localizer.ros.pipeline`, :mod:`rs_localizer.ros.rig_node`), ``rs-localizer replay``
and the video benchmarks drive them.
"""

from .localizer import CameraFrame
from .sequence import (
    FusedPose,
    GyroSettings,
    SequenceLocalizer,
    SequenceOutput,
    SequenceSettings,
    reference_stamp_ns,
)
from .video import Localizer, LocalizerOutput, LocalizerSettings

__all__ = [
    "CameraFrame",
    "FusedPose",
    "GyroSettings",
    "Localizer",
    "LocalizerOutput",
    "LocalizerSettings",
    "SequenceLocalizer",
    "SequenceOutput",
    "SequenceSettings",
    "reference_stamp_ns",
]
