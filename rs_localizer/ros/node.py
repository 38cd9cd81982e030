"""``rs_localizer_node``: rolling-shutter camera localization from 2D-3D correspondences.

A thin layer over :func:`rs_localizer.estimate_rs_pose` (no solver logic here):
decode the input, pick the camera model, call the estimator, publish, count. Images go through
an image front end (:mod:`rs_localizer.frontends`: ArUco markers or natural features against a
map) first, then down the same path as a correspondence cloud.

Threads: the subscription callbacks only count frames and put them into a bounded queue
(``queue_size``; a full queue drops its oldest frame, counted as skipped); one worker thread
solves and publishes, so the executor stays free for camera_info, parameters and diagnostics
however slow a frame is (the accounting: :mod:`rs_localizer.ros.frame_queue`).

Subscriptions (best effort, history 100 clouds / 10 images / 5 camera_info; overridable with
``qos_overrides.<topic>.subscription.*``):
    correspondences  sensor_msgs/PointCloud2  u, v [px, distorted], x, y, z [m, map frame]
                                              (+ id uint32, + score float32)
    keypoints        sensor_msgs/PointCloud2  u, v, id; 3D points from ``landmarks_file``
    camera_info      sensor_msgs/CameraInfo
    imu              sensor_msgs/Imu (sensor-data QoS), only with ``imu.enabled``: its gyro
    image            sensor_msgs/Image (mono8/rgb8/bgr8/rgba8/bgra8), only when ``frontend`` is
                     ``aruco`` or ``features``; header.stamp = capture time of ``rs.stamp_row``
    image/compressed sensor_msgs/CompressedImage (JPEG, PNG) instead, with
                     ``image_transport: compressed`` (topic: the resolved ``image`` + /compressed)
Publications (reliable, depth 10):
    pose                  geometry_msgs/PoseStamped              map_frame, reference-row time
    twist                 geometry_msgs/TwistStamped             camera frame, rad/s and m/s; with
                          tracking (default) the fused twist of the frame ``tracking.lag``
                          frames back, stamped with that frame's time
    twist_single_frame    geometry_msgs/TwistStamped             the frame's own twist
    pose_with_covariance  geometry_msgs/PoseWithCovarianceStamped
    odom                  nav_msgs/Odometry                      pose + (fused) twist, with the
                          twist's stamp
    /tf                   tf2_msgs/TFMessage (if importable and publish_tf)
    /diagnostics          diagnostic_msgs/DiagnosticArray
    correspondences_out   sensor_msgs/PointCloud2 (image mode, ``republish_correspondences``):
                          the front end's u, v, x, y, z, id (+ score), stamped like the image
    debug_image, markers, path  visualization, built only when subscribed
                          (:mod:`rs_localizer.ros.visualization`, parameters ``viz.*``)
"""

from __future__ import annotations

from rclpy.node import Node

from .core import NodeCore
from .mode import LocalizerMode
from .params import PARAMETERS

__all__ = ["PARAMETERS", "RSLocalizerNode"]


class RSLocalizerNode(NodeCore, Node):
    """The localizer node, for one camera (``rig.cameras`` empty: a rig of one camera named
    "") or a rig, in its one mode (:class:`~rs_localizer.ros.mode.LocalizerMode`): configured
    (JIT warm-up included), subscribed and publishing from construction. ``node_name`` and
    ``kwargs`` go to :class:`rclpy.node.Node`. The managed node is
    :class:`~rs_localizer.ros.lifecycle.RSLocalizerLifecycleNode`.

    Raises:
        RuntimeError: invalid parameters (the message names the parameter).
    """

    _mode = LocalizerMode
