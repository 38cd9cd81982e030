"""A camera's video, frame after frame, without ROS: :class:`SequenceLocalizer` owns the video
tracker, the frames waiting for their fused twist, the gyro samples, the online gyro-bias
estimate, the check of the gyro against the image and the time resets. The node
(:mod:`rs_localizer.ros.pipeline`), ``rs-localizer replay`` and the video benchmarks drive it.
"""

from .sequence import (
    FusedPose,
    GyroSettings,
    SequenceFrame,
    SequenceLocalizer,
    SequenceOutput,
    SequenceSettings,
    reference_stamp_ns,
)

__all__ = [
    "FusedPose",
    "GyroSettings",
    "SequenceFrame",
    "SequenceLocalizer",
    "SequenceOutput",
    "SequenceSettings",
    "reference_stamp_ns",
]
