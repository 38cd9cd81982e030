"""A camera's video, frame after frame (:class:`CameraFrame`), without ROS:
:class:`SequenceLocalizer` owns the video tracker, the frames waiting for their fused twist,
the gyro samples, the online gyro-bias estimate, the check of the gyro against the image and
the time resets. The node (:mod:`rs_localizer.ros.pipeline`), ``rs-localizer replay`` and the
video benchmarks drive it. A rig's cameras take the same frames
(:class:`~rs_localizer.tracking.rig.RigLocalizer`, ``camera_name`` set).
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

__all__ = [
    "CameraFrame",
    "FusedPose",
    "GyroSettings",
    "SequenceLocalizer",
    "SequenceOutput",
    "SequenceSettings",
    "reference_stamp_ns",
]
