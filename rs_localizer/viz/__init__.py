"""What the localizer sees, drawn without ROS (the layer of the front ends).

* :mod:`.debug_image`: the ``debug_image`` picture of one frame (OpenCV drawing): inliers and
  outliers, scaled residual vectors, a virtual cube through the rolling-shutter model next to
  the global-shutter projection of the same pose, a text line with the numbers.
* :mod:`.scene3d`: the 3D geometry of the ``markers`` topic in the map frame (camera frustum,
  velocity arrows, inlier points). :mod:`rs_localizer.ros.visualization` turns both into
  messages.
"""

from .debug_image import COLORS, DebugImageOptions, draw_debug_image, frame_residuals
from .scene3d import frustum_corners, frustum_segments, velocity_arrows

__all__ = [
    "COLORS",
    "DebugImageOptions",
    "draw_debug_image",
    "frame_residuals",
    "frustum_corners",
    "frustum_segments",
    "velocity_arrows",
]
