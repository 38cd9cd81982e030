"""ROS message <-> rs_localizer conversions (CameraInfo, stamps, poses, quaternions).

Poses go out as an :class:`~rs_localizer.pose.RSPose` (``PoseStamped``, ``TwistStamped``,
``TFMessage``) or a :class:`~rs_localizer.pose.PoseWithCovariance` (an estimate, a fused frame,
a base or rig state: ``PoseWithCovarianceStamped``, ``Odometry``). Frames: the pose's
``orientation``/``position`` are the camera optical frame's (or the base's, the rig's) pose in
the map (body -> map), so they go into ``PoseStamped`` as they are; velocities are in the body
frame (the camera's REP 103 optical frame: z forward, x right, y down). Covariances are 6x6 in
ROS order (x, y, z, rot x, rot y, rot z) / (vx, vy, vz, wx, wy, wz), row-major.

The messages read (``CameraInfo``, ``Time``, ``Pose``, ``Twist``) may be rclpy's or rosbags'
classes: both have the fields read here.
"""

from __future__ import annotations

import functools
import importlib
import threading
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from ..camera import DISTORTION_MODELS, CameraModel, Stamp, checked_stamp
from ..geometry import nearest_rotation
from ..pose import PoseWithCovariance, RSPose

if TYPE_CHECKING:  # (the message packages are imported where a message is built)
    from builtin_interfaces.msg import Time
    from geometry_msgs.msg import (
        Pose,
        PoseStamped,
        PoseWithCovarianceStamped,
        Twist,
        TwistStamped,
    )
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import CameraInfo, Imu
    from tf2_msgs.msg import TFMessage

__all__ = [
    "CAMERA_INFO_REASONS",
    "STAMP_MAX_NS",
    "CameraInfoError",
    "ImuError",
    "StampError",
    "camera_info_msg",
    "camera_model",
    "camera_model_from_camera_info",
    "checked_stamp_ns",
    "covariance36",
    "gyro_sample",
    "have_tf2_msgs",
    "matrix_from_quaternion",
    "ns_to_stamp",
    "odometry",
    "pose_from_msg",
    "pose_stamped",
    "pose_with_covariance_stamped",
    "quaternion_from_matrix",
    "stamp_to_ns",
    "tf_message",
    "twist_from_msg",
    "twist_stamped",
]

_NS = 1_000_000_000


# ---------------------------------------------------------------- rotations
def _supports_assume_valid() -> bool:
    """Whether ``Rotation.from_matrix`` takes ``assume_valid`` (SciPy >= 1.15). Older
    SciPy (e.g. Debian 12's 1.10) builds it as a Cython builtin without a signature, so
    this tries the keyword instead of inspecting."""
    try:
        Rotation.from_matrix(np.eye(3), assume_valid=True)
    except TypeError:
        return False
    return True


#: SciPy >= 1.15 can skip projecting a matrix onto SO(3) (``assume_valid``; 4x faster)
_ASSUME_VALID = _supports_assume_valid()


def quaternion_from_matrix(R: ArrayLike, orthonormal: bool = False) -> np.ndarray:
    """(3, 3) rotation -> (4,) unit quaternion ``(x, y, z, w)`` (ROS order) with ``w >= 0``,
    via SciPy. A non-orthonormal input is first projected onto SO(3) (the nearest rotation
    in the Frobenius norm, by SVD; SciPy's own handling of such input differs between
    versions), unless ``orthonormal`` says it is a rotation to rounding already (an
    estimate's orientation: no projection, ~4x faster with SciPy >= 1.15).

    Raises ``ValueError`` on a matrix that is not (3, 3) or not finite."""
    R = np.asarray(R, dtype=float)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise ValueError(f"expected a finite (3, 3) rotation matrix, got shape {R.shape}")
    if orthonormal:
        rot = Rotation.from_matrix(R, **({"assume_valid": True} if _ASSUME_VALID else {}))
    else:
        rot = Rotation.from_matrix(nearest_rotation(R))
    q = rot.as_quat()
    return -q if q[3] < 0 else q


def matrix_from_quaternion(q: ArrayLike) -> np.ndarray:
    """(4,) quaternion ``(x, y, z, w)`` (normalized here) -> (3, 3) rotation."""
    q = np.asarray(q, dtype=float)
    n = np.linalg.norm(q)
    if not np.isfinite(n) or n < 1e-12:
        raise ValueError(f"invalid quaternion {q.tolist()}")
    return Rotation.from_quat(q / n).as_matrix()


# ---------------------------------------------------------------- time
#: the range of ``builtin_interfaces/Time`` this package reads and writes: int32 seconds >= 0
#: (rclpy.time.Time rejects negative times), nanoseconds < 1e9
STAMP_MAX_NS = 2**31 * _NS - 1


class StampError(ValueError):
    """An invalid ``builtin_interfaces/Time``; ``reason`` is ``bad_stamp``."""

    reason = "bad_stamp"


def stamp_to_ns(stamp: Time) -> int:
    """``builtin_interfaces/Time`` (rclpy or rosbags) -> integer nanoseconds (not checked: see
    :func:`checked_stamp_ns`)."""
    return int(stamp.sec) * _NS + int(stamp.nanosec)


def checked_stamp_ns(stamp: Time) -> Stamp:
    """Like :func:`stamp_to_ns`, for stamps from the outside world: the one check of a
    message's stamp, at the node's entry. Returns a checked
    :class:`~rs_localizer.camera.Stamp`, which the localizers take as it is.

    Raises:
        StampError (a ValueError, ``reason = "bad_stamp"``): ``nanosec >= 1e9`` (it would be
        read as extra seconds), ``sec < 0`` (ROS time is not negative) or beyond the int64
        nanosecond range (a ``sec`` no ``int32`` field holds).
    """
    sec, nsec = int(stamp.sec), int(stamp.nanosec)
    if not 0 <= nsec < _NS:
        raise StampError(f"invalid stamp: nanosec {nsec} is not in [0, 1e9)")
    if sec < 0:
        raise StampError(f"invalid stamp: negative sec {sec}")
    try:
        return checked_stamp(sec * _NS + nsec)
    except ValueError as e:
        raise StampError(f"invalid stamp: {e}") from None


class ImuError(ValueError):
    """A ``sensor_msgs/Imu`` without a usable gyro sample; ``reason``: ``no_angular_velocity``
    (covariance[0] = -1, the message's "no data") or ``bad_stamp``."""

    def __init__(self, reason: str, detail: str = ""):
        super().__init__(detail or reason)
        self.reason = reason


def gyro_sample(msg: Imu) -> tuple[int, tuple[float, float, float]]:
    """The gyro sample of a ``sensor_msgs/Imu`` (rclpy or rosbags): its stamp (ns, checked as
    :func:`checked_stamp_ns`) and angular velocity ``(x, y, z)`` (rad/s, the message's frame).

    Raises:
        ImuError: no angular velocity in the message, or an invalid stamp (``reason``).
    """
    if float(msg.angular_velocity_covariance[0]) == -1.0:
        raise ImuError("no_angular_velocity")
    try:
        stamp = checked_stamp_ns(msg.header.stamp)
    except StampError as e:
        raise ImuError("bad_stamp", str(e)) from None
    a = msg.angular_velocity
    return stamp, (a.x, a.y, a.z)


def ns_to_stamp(ns: int) -> Time:
    """Integer nanoseconds -> rclpy ``builtin_interfaces/Time``.

    Raises:
        StampError (a ValueError): ``ns`` outside [0, 2^31 s) (int32 seconds; never clamped or
        wrapped).
    """
    ns = int(ns)
    if not 0 <= ns <= STAMP_MAX_NS:
        raise StampError(f"stamp {ns} ns is outside [0, 2^31 s): not representable")
    sec, nsec = divmod(ns, _NS)
    return _message_class("builtin_interfaces", "Time")(sec=sec, nanosec=nsec)


# ---------------------------------------------------------------- cameras
class CameraInfoError(ValueError):
    """Intrinsics that cannot be used; ``reason`` is one of :data:`CAMERA_INFO_REASONS`."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


#: every ``CameraInfoError.reason``: ``bad_intrinsics`` (K not finite, fx or fy <= 0, last row
#: not (0, 0, 1)), ``bad_distortion`` (unsupported model, non-finite or ambiguous
#: coefficients), ``bad_size`` (zero image size or binning), ``bad_roi`` (a ROI outside the
#: image or with one zero side)
CAMERA_INFO_REASONS = ("bad_intrinsics", "bad_distortion", "bad_size", "bad_roi")


def camera_model(
    K: ArrayLike,
    D: ArrayLike,
    width: int,
    height: int,
    distortion_model: str = "plumb_bob",
    line_delay: float = 0.0,
    readout_time: float = 0.0,
    readout: str = "top_to_bottom",
    reference_row: float | None = None,
) -> CameraModel:
    """CameraModel with RS timing: ``readout_time > 0`` (s/frame) wins over ``line_delay``
    (s/line). ``reference_row`` < 0 or None = image centre line. ``K``: (3, 3) intrinsics
    (px); ``D``: distortion coefficients in OpenCV order (empty or all zero: none).

    Raises:
        CameraInfoError (a ValueError): see :data:`CAMERA_INFO_REASONS`; ValueError from
        :class:`CameraModel` for bad RS timing.
    """
    if reference_row is not None and reference_row < 0:
        reference_row = None
    K = np.asarray(K, dtype=float).reshape(3, 3)
    if not np.isfinite(K).all():
        raise CameraInfoError("bad_intrinsics", f"K has non-finite entries: {K.tolist()}")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise CameraInfoError("bad_intrinsics", "uncalibrated camera: K has fx or fy <= 0")
    if not np.array_equal(K[2], [0.0, 0.0, 1.0]):
        raise CameraInfoError("bad_intrinsics", f"K's last row is {K[2].tolist()}, not [0, 0, 1]")
    if int(width) <= 0 or int(height) <= 0:
        raise CameraInfoError("bad_size", f"invalid image size {width}x{height}")
    D = _normalize_distortion(np.asarray(D, dtype=float).ravel(), distortion_model)
    model = distortion_model or ("plumb_bob" if len(D) else "none")
    kw = dict(D=D, readout=readout, reference_row=reference_row, distortion_model=model)
    if readout_time and readout_time > 0:
        return CameraModel.from_readout_time(K, float(readout_time), int(width), int(height), **kw)
    return CameraModel(
        K=K, width=int(width), height=int(height), line_delay=float(line_delay), **kw
    )


def _normalize_distortion(D: np.ndarray, model: str) -> np.ndarray:
    """Check the coefficients and trim trailing zeros the model does not take (e.g. a
    14-vector of zeros, or plumb_bob ``k1 k2 p1 p2 k3 0``). A count the model does not take
    is never zero-padded: plumb_bob with 3 coefficients (``k1 k2 p1``? ``k1 k2 k3``?) or with a
    6th one is ambiguous and rejected."""
    model = model or "plumb_bob"
    if model not in DISTORTION_MODELS:
        raise CameraInfoError(
            "bad_distortion",
            f"unsupported distortion model {model!r}; supported: {sorted(DISTORTION_MODELS)}",
        )
    if not np.isfinite(D).all():
        raise CameraInfoError(
            "bad_distortion", f"distortion coefficients are not finite: {D.tolist()}"
        )
    if not np.any(D):
        return np.zeros(0)
    allowed = DISTORTION_MODELS[model]
    if len(D) in allowed:
        return D
    n = len(D)
    while n > 0 and D[n - 1] == 0 and n not in allowed:
        n -= 1  # drop trailing zeros down to a count the model takes
    if n in allowed and n > 0:
        return D[:n]
    nz = int(np.flatnonzero(D)[-1]) + 1
    if nz > max(allowed):
        raise CameraInfoError(
            "bad_distortion",
            f"{model}: {len(D)} coefficients with non-zero "
            f"terms beyond the first {max(allowed)} are not supported",
        )
    raise CameraInfoError(
        "bad_distortion",
        f"{model}: {nz} coefficients ({len(D)} given) "
        f"but the model takes {[a for a in allowed if a]}; not guessing "
        "which ones they are",
    )


def camera_model_from_camera_info(
    info: CameraInfo,
    line_delay: float = 0.0,
    readout_time: float = 0.0,
    readout: str = "top_to_bottom",
    reference_row: float | None = None,
) -> CameraModel:
    """``sensor_msgs/CameraInfo`` (rclpy or rosbags) -> :class:`CameraModel`.

    Uses K, D and ``distortion_model`` (pixels are measured, i.e. distorted: P/R are not used),
    and applies binning and ROI (REP 104) so that K matches the delivered image.

    Raises:
        CameraInfoError (a ValueError) with ``reason`` in :data:`CAMERA_INFO_REASONS`.
    """
    K = np.asarray(info.k, dtype=float).reshape(3, 3).copy()
    if not np.isfinite(K).all():
        raise CameraInfoError("bad_intrinsics", f"K has non-finite entries: {K.tolist()}")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise CameraInfoError("bad_intrinsics", "camera_info is uncalibrated (K has fx or fy <= 0)")
    width, height = int(info.width), int(info.height)
    if width <= 0 or height <= 0:
        raise CameraInfoError("bad_size", f"invalid image size {width}x{height}")
    bx = max(int(getattr(info, "binning_x", 0)), 1)
    by = max(int(getattr(info, "binning_y", 0)), 1)
    roi = getattr(info, "roi", None)
    if roi is not None:
        x0, y0 = int(roi.x_offset), int(roi.y_offset)
        rw, rh = int(roi.width), int(roi.height)
        if (rw, rh) != (0, 0) or (x0, y0) != (0, 0):  # all zeros = the full image
            if rw <= 0 or rh <= 0 or x0 < 0 or y0 < 0 or x0 + rw > width or y0 + rh > height:
                raise CameraInfoError(
                    "bad_roi",
                    f"roi (x {x0}, y {y0}, {rw}x{rh}) is not inside the {width}x{height} image",
                )
            if (rw, rh) != (width, height):
                K[0, 2] -= x0
                K[1, 2] -= y0
                width, height = rw, rh
    if bx > 1 or by > 1:
        K[0, :] /= bx
        K[1, :] /= by
        width, height = width // bx, height // by
        if width <= 0 or height <= 0:
            raise CameraInfoError("bad_size", f"binning {bx}x{by} leaves no image")
    model = str(info.distortion_model or "")
    D = np.asarray(info.d, dtype=float).ravel()
    if not model:
        model = "plumb_bob" if np.any(D) else "none"
    try:
        return camera_model(
            K, D, width, height, model, line_delay, readout_time, readout, reference_row
        )
    except CameraInfoError:
        raise
    except ValueError as e:  # (RS timing: the node's parameters, checked there)
        raise CameraInfoError("bad_intrinsics", str(e)) from None


@functools.cache
def _message_class(package: str, name: str):
    """``<package>.msg.<name>``, imported on first use (this module also serves rosbags users
    without rclpy's message packages)."""
    return getattr(importlib.import_module(f"{package}.msg"), name)


def _stamped(msg_type, stamp_ns: int, frame_id: str):
    """A new ``msg_type()`` (a message with a ``std_msgs/Header``) stamped ``stamp_ns``
    (integer ns) in ``frame_id``."""
    msg = msg_type()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.header.frame_id = frame_id
    return msg


def camera_info_msg(camera: CameraModel, frame_id: str = "", stamp_ns: int = 0) -> CameraInfo:
    """:class:`CameraModel` -> rclpy ``sensor_msgs/CameraInfo`` (P = [K | 0], R = I)."""
    from sensor_msgs.msg import CameraInfo

    msg = _stamped(CameraInfo, stamp_ns, frame_id)
    msg.width, msg.height = camera.width, camera.height
    msg.distortion_model = camera.distortion_model if camera.has_distortion else "plumb_bob"
    D = np.asarray(camera.D, dtype=float)
    if msg.distortion_model == "plumb_bob" and len(D) < 5:
        D = np.concatenate([D, np.zeros(5 - len(D))])
    msg.d = [float(x) for x in D]
    msg.k = [float(x) for x in camera.K.ravel()]
    msg.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    P = np.zeros((3, 4))
    P[:, :3] = camera.K
    msg.p = [float(x) for x in P.ravel()]
    return msg


# ---------------------------------------------------------------- estimates -> messages
def covariance36(C: ArrayLike | None) -> np.ndarray:
    """6x6 covariance -> (36,) float64 row-major; ``None``/non-finite -> zeros (unknown)."""
    if C is None:
        return np.zeros(36)
    C = np.asarray(C, dtype=np.float64).reshape(36)
    if not np.isfinite(C).all():
        return np.zeros(36)
    return np.ascontiguousarray(C)


def _quaternion(pose: RSPose) -> np.ndarray:
    """Quaternion of ``pose.orientation``, computed once per orientation array: a frame's pose
    and, frames later, its fused twist's odom share it (the last 8 are kept)."""
    R = pose.orientation
    with _QUATERNIONS_LOCK:  # (the worker thread and the executor's flush timer)
        hit = _QUATERNIONS.get(id(R))
        if hit is None or hit[0] is not R:
            if len(_QUATERNIONS) >= 8:
                del _QUATERNIONS[next(iter(_QUATERNIONS))]
            hit = _QUATERNIONS[id(R)] = (R, quaternion_from_matrix(R, orthonormal=True))
    return hit[1]


_QUATERNIONS: dict = {}  # id(orientation) -> (orientation, quaternion), oldest first
_QUATERNIONS_LOCK = threading.Lock()


def _fill_pose(pose, rs: RSPose):
    q = _quaternion(rs)
    p = np.asarray(rs.position, dtype=float)
    pose.position.x, pose.position.y, pose.position.z = (float(x) for x in p)
    (pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w) = (
        float(x) for x in q
    )
    return pose


def _fill_twist(twist, rs: RSPose):
    w = np.asarray(rs.angular_velocity, dtype=float)
    v = np.asarray(rs.linear_velocity, dtype=float)
    twist.linear.x, twist.linear.y, twist.linear.z = (float(x) for x in v)
    twist.angular.x, twist.angular.y, twist.angular.z = (float(x) for x in w)
    return twist


def pose_stamped(pose: RSPose, stamp_ns: int, map_frame: str) -> PoseStamped:
    """``geometry_msgs/PoseStamped``: ``pose``'s orientation (3, 3) and position (3,) m (the
    camera optical frame's, or the base's, pose in ``map_frame``), stamped ``stamp_ns`` (ns;
    the reference row's time). Raises :class:`StampError` on a stamp outside
    [0, 2^31 s)."""
    msg = _stamped(_message_class("geometry_msgs", "PoseStamped"), stamp_ns, map_frame)
    _fill_pose(msg.pose, pose)
    return msg


def twist_stamped(pose: RSPose, stamp_ns: int, camera_frame: str) -> TwistStamped:
    """``geometry_msgs/TwistStamped``: ``pose``'s angular (rad/s) and linear (m/s) velocity in
    its own frame ``camera_frame`` (the camera optical frame, or the base's), stamped
    ``stamp_ns`` (ns). Raises :class:`StampError` on a stamp outside [0, 2^31 s)."""
    msg = _stamped(_message_class("geometry_msgs", "TwistStamped"), stamp_ns, camera_frame)
    _fill_twist(msg.twist, pose)
    return msg


def pose_with_covariance_stamped(
    state: PoseWithCovariance, stamp_ns: int, map_frame: str
) -> PoseWithCovarianceStamped:
    """``geometry_msgs/PoseWithCovarianceStamped``: ``state.pose`` as :func:`pose_stamped` with
    ``state.pose_covariance`` (6, 6, ROS order, ``map_frame``; None: zeros, unknown)."""
    msg = _stamped(
        _message_class("geometry_msgs", "PoseWithCovarianceStamped"), stamp_ns, map_frame
    )
    _fill_pose(msg.pose.pose, state.pose)
    msg.pose.covariance = covariance36(state.pose_covariance)
    return msg


def odometry(
    state: PoseWithCovariance, stamp_ns: int, map_frame: str, camera_frame: str
) -> Odometry:
    """``nav_msgs/Odometry``: ``state.pose``'s pose in ``map_frame`` and twist in
    ``camera_frame`` (the child frame), with ``state.pose_covariance`` and
    ``state.twist_covariance`` (6, 6, ROS order; None: zeros, unknown), stamped ``stamp_ns``
    (ns)."""
    msg = _stamped(_message_class("nav_msgs", "Odometry"), stamp_ns, map_frame)
    msg.child_frame_id = camera_frame
    _fill_pose(msg.pose.pose, state.pose)
    msg.pose.covariance = covariance36(state.pose_covariance)
    _fill_twist(msg.twist.twist, state.pose)
    msg.twist.covariance = covariance36(state.twist_covariance)
    return msg


def have_tf2_msgs() -> bool:
    try:
        import tf2_msgs.msg  # noqa: F401
    except ImportError:
        return False
    return True


def tf_message(pose: RSPose, stamp_ns: int, map_frame: str, camera_frame: str) -> TFMessage:
    """``tf2_msgs/TFMessage`` with the transform ``map_frame`` -> ``camera_frame`` of ``pose``
    (orientation (3, 3), position (3,) m), stamped ``stamp_ns`` (ns). Raises ImportError
    without tf2_msgs (not in the PyPI wheels)."""
    from geometry_msgs.msg import TransformStamped
    from tf2_msgs.msg import TFMessage

    tr = _stamped(TransformStamped, stamp_ns, map_frame)
    tr.child_frame_id = camera_frame
    q = _quaternion(pose)
    p = np.asarray(pose.position, dtype=float)
    (tr.transform.translation.x, tr.transform.translation.y, tr.transform.translation.z) = (
        float(x) for x in p
    )
    (
        tr.transform.rotation.x,
        tr.transform.rotation.y,
        tr.transform.rotation.z,
        tr.transform.rotation.w,
    ) = (float(x) for x in q)
    return TFMessage(transforms=[tr])


def pose_from_msg(pose: Pose) -> tuple[np.ndarray, np.ndarray]:
    """``geometry_msgs/Pose`` (rclpy or rosbags) -> (orientation (3, 3), position (3,) m)."""
    q = [pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w]
    p = np.array([pose.position.x, pose.position.y, pose.position.z], dtype=float)
    return matrix_from_quaternion(q), p


def twist_from_msg(twist: Twist) -> tuple[np.ndarray, np.ndarray]:
    """``geometry_msgs/Twist`` (rclpy or rosbags) -> (angular (3,) rad/s, linear (3,) m/s)."""
    w = np.array([twist.angular.x, twist.angular.y, twist.angular.z], dtype=float)
    v = np.array([twist.linear.x, twist.linear.y, twist.linear.z], dtype=float)
    return w, v
