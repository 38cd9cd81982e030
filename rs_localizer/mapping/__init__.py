"""Maps from the user's own data, for the front ends and the node's ``frontend_map``.

Without ROS. Above ``estimation/`` and ``frontends/`` (it uses the estimator and the detectors),
below ``ros/`` and ``cli/``.

Marker maps from a rolling-shutter video, by stage: ``marker_model`` (the model, the input
and the result), ``marker_init`` (initialization), ``marker_problem`` (the bundle adjustment's
problem), ``marker_covariance`` (the markers' covariance), ``marker_frame`` (the output
frame) and ``marker_map`` (:func:`map_markers`, the stages in order). Their public names are
imported from here.
"""

from .marker_covariance import corner_jacobian, shape_covariance
from .marker_map import concatenate_videos, map_markers
from .marker_model import (
    FrameDetections,
    MappingOptions,
    MarkerMapResult,
    OutputFrame,
    marker_corners_local,
)

__all__ = [
    "FrameDetections",
    "MappingOptions",
    "MarkerMapResult",
    "OutputFrame",
    "concatenate_videos",
    "corner_jacobian",
    "map_markers",
    "marker_corners_local",
    "shape_covariance",
]
