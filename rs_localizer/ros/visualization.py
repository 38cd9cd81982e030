"""Visualization topics of a solved frame: ``debug_image``, ``markers`` and ``path``.

The drawing and the 3D geometry are ROS-free (:mod:`rs_localizer.viz`); this module turns them
into messages, for the node (:class:`NodeVisualization`: publishers created at start, messages
built only when someone subscribes) and for ``rs-localizer replay --debug-outputs``
(:class:`VisualizationBuilder`).

    debug_image  sensor_msgs/Image (bgr8)          stamp = input stamp, frame = camera frame
    markers      visualization_msgs/MarkerArray    map_frame, reference-line stamp: camera
                 frustum (ns ``frustum``, LINE_LIST), angular and linear velocity arrows
                 (``angular_velocity``, ``linear_velocity``, ARROW, in the map frame), inlier
                 3D points (``inliers``, POINTS)
    path         nav_msgs/Path                     map_frame: the last ``viz.path_length`` poses

Everything is in ``map_frame`` with identity marker poses, so RViz (fixed frame = map_frame) and
Foxglove show it without any TF.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from typing import TYPE_CHECKING, Any

import numpy as np
from geometry_msgs.msg import Point
from nav_msgs.msg import Path
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from sensor_msgs.msg import Image
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from ..camera import CameraModel
from ..estimation.result import RSPoseEstimate
from ..viz.debug_image import DebugImageOptions, draw_debug_image
from ..viz.scene3d import frustum_segments, velocity_arrows
from . import conversions as cv
from .image_codec import image_fields
from .qos import DEBUG_IMAGE_QOS, RELIABLE, output_events

if TYPE_CHECKING:
    from ..tracking.localizer import CameraFrame
    from ..tracking.video import LocalizerOutput

__all__ = [
    "MARKER_COLORS",
    "VIZ_PARAMETERS",
    "VIZ_TOPICS",
    "NodeVisualization",
    "VisualizationBuilder",
    "debug_image_msg",
    "marker_array",
    "path_msg",
    "rig_camera_views",
]

#: name -> (default, description, range); declared by :class:`NodeVisualization`
VIZ_PARAMETERS = {
    "viz.path_length": (
        1000,
        "poses kept in the path topic",
        IntegerRange(from_value=1, to_value=1_000_000, step=1),
    ),
    "viz.frustum_depth": (
        0.5,
        "depth of the camera frustum in the markers topic (m)",
        FloatingPointRange(from_value=1e-3, to_value=1e4, step=0.0),
    ),
    "viz.arrow_scale": (
        1.0,
        "velocity arrows in the markers topic: m of arrow per rad/s (angular) and per m/s (linear)",
        FloatingPointRange(from_value=0.0, to_value=1e4, step=0.0),
    ),
    "viz.residual_scale": (
        10.0,
        "residual vectors in debug_image are drawn this many times longer",
        FloatingPointRange(from_value=0.0, to_value=1e4, step=0.0),
    ),
    "viz.max_rate": (
        10.0,
        "Hz; debug_image, markers and path are drawn on their own thread at most this often, "
        "each time from the newest solved frame (frames in between are not drawn: viewers never "
        "hold up the estimation); 0: every solved frame, as fast as the thread draws",
        FloatingPointRange(from_value=0.0, to_value=1e3, step=0.0),
    ),
}
#: topic name -> message type name
VIZ_TOPICS = {
    "debug_image": "sensor_msgs/msg/Image",
    "markers": "visualization_msgs/msg/MarkerArray",
    "path": "nav_msgs/msg/Path",
}
#: topic -> the attribute of :class:`NodeVisualization` holding its publisher
_PUBLISHERS = {"debug_image": "pub_image", "markers": "pub_markers", "path": "pub_path"}
#: RGBA (0..1) of the markers
MARKER_COLORS = {
    "frustum": (0.0, 1.0, 1.0, 1.0),
    "angular_velocity": (1.0, 0.5, 0.0, 1.0),
    "linear_velocity": (0.2, 0.4, 1.0, 1.0),
    "inliers": (0.0, 1.0, 0.0, 1.0),
}
MAX_MARKER_POINTS = 5000


def debug_image_msg(bgr: np.ndarray, stamp_ns: int, frame_id: str) -> Image:
    """(H, W, 3) uint8 BGR -> ``sensor_msgs/Image`` (``bgr8``, no row padding:
    :func:`~rs_localizer.ros.image_codec.image_fields`).

    Raises:
        ValueError: an array of another shape.
    """
    img = np.asarray(bgr)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) image, got {img.shape}")
    f = image_fields(img, "bgr8")
    m = Image()
    m.header.stamp = cv.ns_to_stamp(stamp_ns)
    m.header.frame_id = frame_id
    m.height, m.width = int(f["height"]), int(f["width"])
    m.encoding = f["encoding"]
    m.is_bigendian = f["is_bigendian"]
    m.step = int(f["step"])
    m.data = f["data"].tobytes()
    return m


def _color(rgba) -> ColorRGBA:
    return ColorRGBA(r=float(rgba[0]), g=float(rgba[1]), b=float(rgba[2]), a=float(rgba[3]))


def _points(P) -> list:
    return [Point(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in np.asarray(P)]


def _marker(ns, kind, stamp_ns, frame_id) -> Marker:
    m = Marker()
    m.header.stamp = cv.ns_to_stamp(stamp_ns)
    m.header.frame_id = frame_id
    m.ns, m.id, m.type, m.action = ns, 0, kind, Marker.ADD
    m.pose.orientation.w = 1.0  # identity: the points are map coordinates
    m.color = _color(MARKER_COLORS[ns])
    return m


def marker_array(
    est: RSPoseEstimate,
    X: np.ndarray,
    camera: CameraModel,
    stamp_ns: int,
    map_frame: str,
    frustum_depth: float = 0.5,
    arrow_scale: float = 1.0,
) -> MarkerArray:
    """The ``markers`` of a solved frame, all in ``map_frame`` (identity poses, so no TF is
    needed):

    * ``frustum`` (LINE_LIST): :func:`rs_localizer.viz.scene3d.frustum_segments` of the
      reference-line pose at ``frustum_depth`` (m);
    * ``angular_velocity``, ``linear_velocity`` (ARROW from the camera centre,
      ``points = [start, end]``): the world-frame velocities times ``arrow_scale`` (m per rad/s,
      m per m/s); DELETE when the velocity is zero (global shutter);
    * ``inliers`` (POINTS): the inliers' world points ``X[est.inliers]`` (at most 5000, evenly
      spaced).

    Sizes follow ``frustum_depth``: lines 2 %, arrow shaft 4 %, points 5 % of it.
    """
    d = float(frustum_depth)
    out = MarkerArray()
    fr = _marker("frustum", Marker.LINE_LIST, stamp_ns, map_frame)
    fr.scale.x = 0.02 * d
    fr.points = _points(frustum_segments(camera, est.pose.orientation, est.pose.position, d))
    out.markers.append(fr)
    for ns, (a, b) in velocity_arrows(est.pose, arrow_scale).items():
        m = _marker(ns, Marker.ARROW, stamp_ns, map_frame)
        if np.linalg.norm(b - a) < 1e-9:
            m.action = Marker.DELETE
        else:
            m.points = _points([a, b])
            m.scale.x, m.scale.y, m.scale.z = 0.04 * d, 0.08 * d, 0.1 * d
        out.markers.append(m)
    pts = np.asarray(X, dtype=float).reshape(-1, 3)
    inl = np.asarray(est.inliers, dtype=bool)
    pts = pts[inl] if len(inl) == len(pts) else pts[:0]
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) > MAX_MARKER_POINTS:
        pts = pts[np.linspace(0, len(pts) - 1, MAX_MARKER_POINTS).astype(int)]
    m = _marker("inliers", Marker.POINTS, stamp_ns, map_frame)
    m.scale.x = m.scale.y = 0.05 * d
    m.points = _points(pts)
    out.markers.append(m)
    return out


def path_msg(poses: Iterable[Any], stamp_ns: int, map_frame: str) -> Path:
    """``nav_msgs/Path`` in ``map_frame`` of the ``PoseStamped`` messages ``poses``."""
    m = Path()
    m.header.stamp = cv.ns_to_stamp(stamp_ns)
    m.header.frame_id = map_frame
    m.poses = list(poses)
    return m


def rig_camera_views(
    out: LocalizerOutput, mounts: dict, wanted: Callable[[str], bool] | None = None
) -> Iterator[tuple[str, CameraFrame, RSPoseEstimate, int]]:
    """Each camera of the posed rig frame ``out``
    (:class:`~rs_localizer.tracking.video.LocalizerOutput`) as its ``<camera>/debug_image`` and
    ``<camera>/markers`` draw it: ``(name, its frame, its estimate, its reference line's
    stamp ns)``, the estimate the camera as the rig's pose and its mounting put it
    (:func:`~rs_localizer.estimation.result.camera_estimate`; a rig of one camera: its
    camera's own estimate, :attr:`~rs_localizer.tracking.video.LocalizerOutput.camera_estimate`,
    the one the rig's is made from), the stamp the rig frame's time plus the camera's offset.
    ``mounts``: camera name -> its mounting; ``wanted``: camera name -> whether to draw it
    (None: every camera with a frame in ``out``)."""
    from ..estimation.result import camera_estimate

    for k, n in enumerate(out.cameras):
        frame = out.frames.get(n)
        if frame is None or (wanted is not None and not wanted(n)):
            continue
        off = out.stamp_offsets.get(n, 0.0)
        if out.camera_estimate is not None:  # (a rig of one: its camera's own estimate)
            yield n, frame, out.camera_estimate, out.stamp_ns + int(round(off * 1e9))
            continue
        view = camera_estimate(out.estimate, k, frame.camera, mounts[n], off,
                               frame.points2d, frame.points3d)  # fmt: skip
        yield n, frame, view, out.stamp_ns + int(round(off * 1e9))


class VisualizationBuilder:
    """The visualization messages of consecutive solved frames (keeps the path).

    Args:
        path_length: poses kept for ``path`` (the oldest are dropped).
        frustum_depth, arrow_scale: see :func:`marker_array`.
        residual_scale: see :class:`rs_localizer.viz.DebugImageOptions`.
    """

    def __init__(
        self,
        path_length: int = 1000,
        frustum_depth: float = 0.5,
        arrow_scale: float = 1.0,
        residual_scale: float = 10.0,
    ):
        self.poses = deque(maxlen=max(int(path_length), 1))
        self.frustum_depth = float(frustum_depth)
        self.arrow_scale = float(arrow_scale)
        self.residual_scale = float(residual_scale)

    def set_path_length(self, n: int) -> None:
        n = max(int(n), 1)
        if n != self.poses.maxlen:
            self.poses = deque(self.poses, maxlen=n)

    def add_pose(
        self, est: RSPoseEstimate, out_stamp_ns: int, map_frame: str, message: Any = None
    ) -> None:
        """Append the frame's pose (reference-line stamp) to the path: ``message``, the
        ``PoseStamped`` of that pose already built (the node's published ``pose``), or one
        made here."""
        if message is None:
            message = cv.pose_stamped(est.pose, out_stamp_ns, map_frame)
        self.poses.append(message)

    def debug_image(
        self,
        est: RSPoseEstimate,
        uv: np.ndarray,
        X: np.ndarray,
        camera: CameraModel,
        stamp_ns: int,
        camera_frame: str,
        image: np.ndarray | None = None,
        encoding: str | None = None,
    ) -> Image:
        """``debug_image`` (:func:`rs_localizer.viz.draw_debug_image`), stamped like the input
        (``stamp_ns``) in ``camera_frame``."""
        bgr = draw_debug_image(
            camera,
            uv,
            X,
            est,
            image,
            encoding,
            DebugImageOptions(residual_scale=self.residual_scale),
        )
        return debug_image_msg(bgr, stamp_ns, camera_frame)

    def markers(
        self,
        est: RSPoseEstimate,
        X: np.ndarray,
        camera: CameraModel,
        out_stamp_ns: int,
        map_frame: str,
    ) -> MarkerArray:
        return marker_array(
            est, X, camera, out_stamp_ns, map_frame, self.frustum_depth, self.arrow_scale
        )

    def path(self, out_stamp_ns: int, map_frame: str, poses: Iterable[Any] | None = None) -> Path:
        """``path`` of the kept poses (or of ``poses``, a snapshot of them)."""
        return path_msg(self.poses if poses is None else poses, out_stamp_ns, map_frame)


class NodeVisualization:
    """The node's ``debug_image`` (reliable, depth 2), ``markers`` and ``path`` (reliable,
    depth 10) publishers (created at start) and the ``viz.*`` parameters (declared on the
    node). Each message is built only when its topic has a subscriber; the path keeps every
    solved pose regardless.

    Drawing is off the estimation path: :meth:`publish` only records the pose and hands the
    frame to a drawing thread, which keeps the newest frame only and draws at most
    ``viz.max_rate`` times a second. A slow viewer or a large debug image thus costs the
    frames nothing but a share of the CPU; frames solved while a drawing is under way are
    not drawn (the path still has their poses).

    ``prefix``: the topics' names start with it (the rig mode's cameras: ``front/``);
    ``topics``: the topics published (of :data:`VIZ_TOPICS`); the ``viz.*`` parameters are
    declared by the first one on the node.

    Usage in the node: ``viz = NodeVisualization(node)``; in image mode
    ``viz.set_image(img, encoding, stamp_ns)`` with the decoded input; after a frame is solved
    ``viz.publish(est, uv, X, camera, stamp_ns, out_stamp_ns, camera_frame, map_frame)``;
    ``viz.close()`` before the node is destroyed.
    """

    def __init__(self, node: Any, prefix: str = "", topics: Iterable[str] = tuple(VIZ_TOPICS)):
        self.node = node
        for name, (default, desc, rng) in VIZ_PARAMETERS.items():
            if node.has_parameter(name):  # (declared once: the rig mode has one per camera)
                continue
            d = ParameterDescriptor(description=desc)
            if isinstance(rng, FloatingPointRange):
                d.floating_point_range = [rng]
            else:
                d.integer_range = [rng]
            node.declare_parameter(name, default, d)
        topics = set(topics)
        self.pub_image, self.pub_markers, self.pub_path = (
            node.create_publisher(msg_type, prefix + topic, qos, event_callbacks=output_events())
            if topic in topics
            else None
            for msg_type, topic, qos in (
                (Image, "debug_image", DEBUG_IMAGE_QOS),  # (images are large: a short queue)
                (MarkerArray, "markers", RELIABLE),
                (Path, "path", RELIABLE),
            )
        )
        self._name = f"rs_localizer_viz{'_' + prefix.strip('/') if prefix else ''}"
        self.builder = VisualizationBuilder(
            *(
                node.get_parameter(n).value
                for n in (
                    "viz.path_length",
                    "viz.frustum_depth",
                    "viz.arrow_scale",
                    "viz.residual_scale",
                )
            )
        )
        self._image = None  # (image, encoding, stamp_ns) of the current input image
        # the drawing thread's mailbox: the newest frame to draw (None: nothing), whether a
        # drawing is under way, and whether the thread is to stop
        self._cond = threading.Condition()
        self._job: tuple | None = None
        self._busy = False
        self._closed = False
        self._thread: threading.Thread | None = None

    def set_image(self, image: np.ndarray, encoding: str, stamp_ns: int) -> None:
        """Remember the decoded input image of the frame stamped ``stamp_ns`` (image mode) for
        the next :meth:`publish`, only while ``debug_image`` has a subscriber: nothing else
        needs it, and an image can be hundreds of MB."""
        self._image = (image, encoding, int(stamp_ns)) if self.wants("debug_image") else None

    def wants(self, topic: str) -> bool:
        """Whether ``topic`` (``debug_image``, ``markers``, ``path``) is published and has a
        subscriber."""
        pub = getattr(self, _PUBLISHERS[topic])
        return pub is not None and pub.get_subscription_count() > 0

    def clear_image(self) -> None:
        """Forget the remembered input image (its frame was not solved: no publish)."""
        self._image = None

    def hold_image(self, image: tuple | None) -> None:
        """:meth:`set_image` with ``(image, encoding, stamp_ns)`` of a solved frame, or
        :meth:`clear_image` with ``None`` (a frame without an image, or not solved)."""
        if image is None:
            self.clear_image()
        else:
            self.set_image(*image)

    def _read_parameters(self):
        b, get = self.builder, self.node.get_parameter
        b.frustum_depth = float(get("viz.frustum_depth").value)
        b.arrow_scale = float(get("viz.arrow_scale").value)
        b.residual_scale = float(get("viz.residual_scale").value)

    def publish(
        self,
        est: RSPoseEstimate,
        uv: np.ndarray,
        X: np.ndarray,
        camera: CameraModel,
        stamp_ns: int,
        out_stamp_ns: int,
        camera_frame: str,
        map_frame: str,
        pose_message: Any = None,
    ) -> None:
        """Record the pose of a solved frame in the path and hand the frame to the drawing
        thread (which replaces a frame still waiting there): ``uv`` (N, 2) and ``X`` (N, 3) are
        the estimator's input rows, ``stamp_ns`` the input stamp, ``out_stamp_ns`` the
        reference line's (the pose's) stamp; ``pose_message``: the ``PoseStamped`` of
        ``est.pose`` at ``out_stamp_ns`` in ``map_frame`` when one is built already (not
        built again for the path). Returns at once."""
        self.builder.add_pose(est, out_stamp_ns, map_frame, pose_message)
        want = tuple(self.wants(t) for t in ("debug_image", "markers", "path"))
        image, self._image = self._image, None
        if not any(want):
            return
        # (read only while someone watches, as the other viz.* parameters; on this thread,
        # which alone appends to the path)
        self.builder.set_path_length(self.node.get_parameter("viz.path_length").value)
        img, enc = (image[0], image[1]) if image and image[2] == stamp_ns else (None, None)
        poses = tuple(self.builder.poses) if want[2] else ()  # (the path as of this frame)
        job = (want, est, uv, X, camera, stamp_ns, out_stamp_ns, camera_frame, map_frame)
        with self._cond:
            if self._closed:
                return
            self._job = (*job, img, enc, poses)
            self._cond.notify_all()
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name=self._name, daemon=True)
                self._thread.start()

    def wait_drawn(self, timeout: float = 10.0) -> bool:
        """Block until the drawing thread has drawn every frame handed to it (or ``timeout``
        s passed); True when it has."""
        with self._cond:
            return self._cond.wait_for(lambda: self._job is None and not self._busy, timeout)

    def close(self) -> None:
        """Stop the drawing thread (a drawing under way is finished; a waiting frame is not
        drawn)."""
        with self._cond:
            self._closed = True
            self._job = None
            self._cond.notify_all()
            th = self._thread
        if th is not None and th is not threading.current_thread():
            th.join(timeout=5.0)

    def _run(self) -> None:
        """The drawing thread: the newest frame, at most ``viz.max_rate`` times a second."""
        next_draw = 0.0
        cond = self._cond
        while True:
            with cond:
                cond.wait_for(lambda: self._job is not None or self._closed)
                # the rate cap: newer frames may replace the waiting one meanwhile
                delay = next_draw - time.monotonic()
                if delay > 0 and not self._closed:
                    cond.wait_for(lambda: self._closed, delay)
                if self._closed:
                    return
                job, self._job = self._job, None
                self._busy = job is not None
            if job is None:
                continue
            started = time.monotonic()
            try:
                self._draw(*job)
            finally:
                with cond:
                    self._busy = False
                    cond.notify_all()
            try:
                rate = float(self.node.get_parameter("viz.max_rate").value)
            except Exception:  # (the node is being destroyed)
                rate = 0.0
            next_draw = started + 1.0 / rate if rate > 0 else 0.0

    def _draw(
        self,
        want,
        est,
        uv,
        X,
        camera,
        stamp_ns,
        out_stamp_ns,
        camera_frame,
        map_frame,
        img,
        enc,
        poses,
    ) -> None:
        b = self.builder
        try:
            self._read_parameters()
            if want[0]:
                self.pub_image.publish(
                    b.debug_image(est, uv, X, camera, stamp_ns, camera_frame, img, enc)
                )
            if want[1]:
                self.pub_markers.publish(b.markers(est, X, camera, out_stamp_ns, map_frame))
            if want[2]:
                self.pub_path.publish(b.path(out_stamp_ns, map_frame, poses))
        except Exception as e:
            self.node.get_logger().warning(
                f"visualization failed: {type(e).__name__}: {e}", throttle_duration_sec=5.0
            )
