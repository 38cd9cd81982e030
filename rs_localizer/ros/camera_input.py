"""One camera's inputs before the estimator, the same for the single-camera node and for each
camera of the rig node: its camera_infos checked and kept by stamp, the camera model of a
frame's stamp, the rows of a correspondences cloud as the estimator takes them (non-finite rows
dropped, at most ``max_points``), an image decoded against the camera model.

:class:`CameraInput` is the camera's in :class:`~rs_localizer.ros.pipeline.FramePipeline`
(``rs_localizer_node`` and ``rs-localizer replay``) and each camera's in
:class:`~rs_localizer.ros.rig_node.RigCore` (the rig mode) and in the reader of a rig bag's
frames (:func:`~rs_localizer.ros.bags.rig_bag.iter_rig_frames`: ``replay``, ``calibrate-rig``
and the rig-frame grouping of ``play --lockstep``), both made by :func:`rig_camera_inputs`.
Its counts go to its owner's ``count(key, n)``: the single-camera node counts them as they
are (``camera_info_rejected``, ``camera_info_rejected.<reason>``, ``points_dropped``,
``capped_clouds``, ``capped_points``), the rig node per camera
(``<camera>.camera_info_rejected.<reason>``, ...). Its warnings go to its owner's throttled
log, each text after the camera's ``label`` (the rig's ``rig camera 'front':``). No
module-level ROS import: messages are duck-typed (rclpy or rosbags).

A rig camera's cloud becomes the rig's frame in one place, :func:`rig_cloud_frame`, for the rig
node and the reader of a rig bag alike: a :class:`~rs_localizer.tracking.localizer.CameraFrame`,
or an :class:`UnreadFrame` (``bad_input``) that :func:`hand_to_rig` passes to the rig as a
frame skipped (:meth:`~rs_localizer.tracking.video.Localizer.drop`); a rig camera's image
reaches the rig in one place too, :func:`hand_image_to_rig`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np

from ..camera import CameraModel, Stamp
from ..tracking.localizer import usable_rows
from . import conversions as cv
from .camera_info_history import CameraInfoHistory, calibration_key
from .pointcloud import Keypoints, read_correspondences, read_keypoints

if TYPE_CHECKING:
    from ..tracking.localizer import CameraFrame
    from ..tracking.video import Localizer, LocalizerOutput

__all__ = [
    "CameraInput",
    "UnreadFrame",
    "frame_camera",
    "hand_image_to_rig",
    "hand_to_rig",
    "rig_camera_inputs",
    "rig_cloud_frame",
    "rig_image_frame",
]


class CameraInput:
    """One camera's inputs (see the module docstring). :meth:`configure` before the first
    camera_info.

    Args:
        log: the owner's log: ``info(text)``, ``error(text)`` and ``warning(key, text)``,
            throttled per ``key`` (:class:`~rs_localizer.ros.pipeline.ThrottledLog`).
        count: ``count(key, n)`` adds ``n`` to the owner's counter ``key``.
        label: put before every text logged and every warning key (a rig's cameras share one
            log: each camera's warnings are throttled apart).
        stopped: ``stopped()`` true ends a frame's wait for its camera_info (shutdown).

    Threads: camera_infos on one thread, frames on another (the history is thread-safe).
    """

    def __init__(
        self,
        log: Any,
        count: Callable[[str, int], Any],
        label: str = "",
        stopped: Callable[[], bool] = lambda: False,
    ):
        self.log = log
        self.count = count
        self.label = label
        self.history = CameraInfoHistory()
        #: the camera model of the camera_info accepted last (None: none yet)
        self.newest: CameraModel | None = None
        self.max_points: int | None = None
        self.fallback: CameraModel | None = None
        self.wait = 0.0
        self._stopped = stopped
        self._make_camera: Callable[[Any], CameraModel] | None = None

    def configure(
        self,
        make_camera: Callable[[Any], CameraModel],
        max_points: int | None = None,
        fallback: CameraModel | None = None,
        wait: float = 0.0,
    ) -> None:
        """Use ``make_camera(msg)`` (a camera_info's model with the camera's rolling-shutter
        timing; raises :class:`~rs_localizer.ros.conversions.CameraInfoError` or ValueError for
        one it cannot use) from now on; the models of the camera_infos received so far are
        rebuilt with it (one it rejects is dropped and logged as an error). ``max_points``: the
        cap on a cloud's rows (None: none); ``fallback``: the model of a frame before any
        camera_info (the parameters' intrinsics; None: none); ``wait``: s a frame waits for its
        camera_info (:meth:`camera_for`). :attr:`newest` is the rebuilt model of the newest
        camera_info kept."""
        self._make_camera = make_camera
        self.max_points, self.fallback, self.wait = max_points, fallback, float(wait)
        for err in self.history.rebuild(make_camera):
            self.log.error(f"{self.label}camera_info unusable with the new parameters: {err}")
        kept = self.history.entries()
        self.newest = max(kept, key=lambda e: e.seq).camera if kept else None

    # ---------------------------------------------------------------- camera_info
    def add_camera_info(self, msg: Any) -> CameraModel | None:
        """Check a ``sensor_msgs/CameraInfo`` and add it to the history the frames pick their
        camera model from by stamp (the first one logged). Returns its camera model, or None
        when it is rejected: counted ``camera_info_rejected`` and
        ``camera_info_rejected.<reason>`` (``bad_stamp``, or a
        :data:`~rs_localizer.ros.conversions.CAMERA_INFO_REASONS` reason) and logged; the
        previous camera models stay."""
        try:
            stamp = cv.checked_stamp_ns(msg.header.stamp)
        except cv.StampError as e:
            return self._reject_camera_info("bad_stamp", str(e))
        key = calibration_key(msg)
        cam = self.history.camera_with_key(key)
        if cam is None:
            try:
                cam = self._make_camera(msg)
            except cv.CameraInfoError as e:
                return self._reject_camera_info(e.reason, str(e))
            except ValueError as e:  # (RS timing of the parameters: checked in the config)
                return self._reject_camera_info("bad_intrinsics", str(e))
        if self.history.add(stamp, key, msg, cam):
            self.log.info(
                f"{self.label}camera_info: {cam.width}x{cam.height}, fx {cam.K[0, 0]:.1f}, "
                f"{cam.distortion_model if cam.has_distortion else 'no distortion'}"
            )
        self.newest = cam
        return cam

    def _reject_camera_info(self, reason: str, detail: str) -> None:
        self.count("camera_info_rejected", 1)
        self.count(f"camera_info_rejected.{reason}", 1)
        self.log.warning(
            f"{self.label}camera_info.{reason}",
            f"{self.label}camera_info rejected ({reason}), the previous camera stays: {detail}",
        )
        return None

    def camera_for(self, stamp_ns: int) -> CameraModel | None:
        """The camera model of a frame stamped ``stamp_ns`` (ns): that of the newest
        camera_info stamped at or before it, else the fallback; waits up to ``wait`` s for it
        (:meth:`~rs_localizer.ros.camera_info_history.CameraInfoHistory.camera_for`). None: no
        camera_info and no fallback."""
        return self.history.camera_for(stamp_ns, self.fallback, self.wait, self._stopped)

    def wake(self) -> None:
        """Wake a frame waiting for its camera_info in :meth:`camera_for` (to see
        ``stopped()``)."""
        self.history.wake()

    # ---------------------------------------------------------------- frames
    def read_cloud(self, msg: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """The rows of a correspondences cloud (``sensor_msgs/PointCloud2``: u, v, x, y, z
        [, score]; :func:`~rs_localizer.ros.pointcloud.read_correspondences`) as the estimator
        takes them (:meth:`rows`): ``(points2d (N, 2) px, points3d (N, 3) m, scores (N,) or
        None)``.

        Raises:
            CloudError (a ValueError) with its ``reason``: a cloud that cannot be read.
        """
        c = read_correspondences(msg)
        return self.rows(c.uv, c.xyz, c.scores)

    def read_keypoints(
        self, msg: Any, landmarks: tuple | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """The rows of a keypoints cloud (``sensor_msgs/PointCloud2``: u, v, id [, score];
        :func:`~rs_localizer.ros.pointcloud.read_keypoints`) with the 3D points of their ids in
        ``landmarks`` (:func:`landmark_rows`, unknown ids counted ``unknown_landmark_ids``), as
        the estimator takes them (:meth:`rows`); none when no id is known.

        Raises:
            CloudError (a ValueError): a cloud that cannot be read. ValueError: no
                ``landmarks`` (no ``landmarks_file`` loaded).
        """
        if landmarks is None:
            raise ValueError("keypoints received but no landmarks_file is loaded")
        return self.rows(*landmark_rows(read_keypoints(msg), landmarks, self.count))

    def rows(
        self, uv: np.ndarray, xyz: np.ndarray, scores: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """A frame's rows ``uv`` (N, 2) px, ``xyz`` (N, 3) m, ``scores`` (N,) or None without
        the non-finite ones (counted ``points_dropped``), then capped to ``max_points``
        (counted ``capped_clouds``, ``capped_points``; a warning):
        :func:`~rs_localizer.tracking.localizer.usable_rows`."""
        return usable_rows(uv, xyz, scores, self.max_points, self.count, self._warn)

    def _warn(self, key: str, text: str) -> None:
        self.log.warning(f"{self.label}{key}", f"{self.label}{text}")

    def decode(self, msg: Any, camera: CameraModel | None) -> tuple[np.ndarray, str]:
        """A ``sensor_msgs/Image`` or ``CompressedImage`` decoded and checked against the
        frame's ``camera`` model (its size; None: not checked) and the front ends' smallest
        image: ``(array (H, W) or (H, W, C) uint8, encoding)``
        (:func:`~rs_localizer.ros.image_codec.decode_image`).

        Raises:
            ImageRejected (a ValueError) with its ``reason``: ``bad_image`` (does not decode,
            an unsupported encoding, below ``MIN_IMAGE_SIDE`` px a side) or
            ``image_size_mismatch`` (another size than the camera's).
        """
        from .image_codec import decode_image

        return decode_image(msg, camera)


def rig_camera_inputs(
    config: Any,
    log: Any,
    count: Callable[[str, str, int], Any],
    stopped: Callable[[], bool] = lambda: False,
    wait: float = 0.0,
) -> dict[str, CameraInput]:
    """Each camera of a rig its :class:`CameraInput`, configured as the rig node takes the
    camera's inputs: its camera_infos made models with the camera's rolling-shutter timing
    (``rig.<camera>.line_delay``, ``readout_time``, ``direction``, else the ``rs.*`` values)
    and the rig's reference row, its clouds' rows capped to the rig's ``max_points``. The rig
    node (:class:`~rs_localizer.ros.rig_node.RigCore`) and the reader of a rig bag's frames
    (:func:`~rs_localizer.ros.bags.rig_bag.iter_rig_frames`: ``replay``, ``calibrate-rig``,
    the rig-frame grouping of ``play --lockstep``) both read their cameras through them, so
    that both take the same rows of a cloud and count them alike.

    Args:
        config: the rig's :class:`~rs_localizer.ros.config.RigConfig`.
        log: the log the cameras share (:class:`CameraInput`'s ``log``); each camera's texts
            come after ``rig camera '<camera>': ``.
        count: ``count(camera, key, n)`` adds ``n`` to camera ``camera``'s count ``key``
            (``points_dropped``, ``capped_clouds``, ...).
        stopped: ``stopped()`` true ends a frame's wait for its camera_info.
        wait: s a camera's frame waits for its camera_info (the node's ``camera_info_wait``,
            as a camera's: :meth:`CameraInput.camera_for`; a bag's reader: 0, its messages in
            log-time order).

    Returns:
        camera name -> its :class:`CameraInput`, in the order of ``rig.cameras``.
    """
    inputs = {}
    for c in config.cameras:
        inp = CameraInput(log, partial(count, c.name), f"rig camera {c.name!r}: ", stopped)
        make_camera = partial(
            cv.camera_model_from_camera_info,
            line_delay=c.line_delay,
            readout_time=c.readout_time,
            readout=c.direction,
            reference_row=config.reference_row,
        )
        inp.configure(make_camera, config.settings.max_points, wait=wait)
        inputs[c.name] = inp
    return inputs


@dataclass(frozen=True)
class UnreadFrame:
    """A rig camera's frame whose message cannot be read, skipped as ``reason``
    (``bad_input``; the rig node's ``<camera>.skipped.bad_input`` and ``<camera>.bad_input``).

    Attributes:
        camera_name: the camera. stamp_ns: the message's checked header stamp; None: the stamp
            itself cannot be read (no rig frame can take the frame: the rig never sees it).
        camera: the camera model of that stamp (None: none yet, or no stamp).
        error: why it was not read. reason: the rig's skip reason
            (:data:`~rs_localizer.tracking.video.SKIP_REASONS`).
    """

    camera_name: str
    stamp_ns: Stamp | None
    camera: CameraModel | None
    error: ValueError
    reason: str = "bad_input"


def frame_camera(inp: CameraInput, stamp: Stamp | ValueError) -> CameraModel | None:
    """The camera model of a frame whose checked header stamp is ``stamp`` (or the error of
    that check: None), :meth:`CameraInput.camera_for`: it may wait up to the input's ``wait``
    for its camera_info (the rig node looks it up before it takes the rig's lock, so that
    camera_info and the diagnostics are served meanwhile)."""
    return None if isinstance(stamp, ValueError) else inp.camera_for(stamp)


def landmark_rows(
    kp: Keypoints, landmarks: tuple, count: Callable[..., Any]
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The keypoints ``kp`` (u, v, id [, score]) whose id is in ``landmarks`` (``(ids (M,)
    sorted, points (M, 3) m)``, the table of ``landmarks_file``), each with its landmark's 3D
    point: ``(points2d (K, 2) px, points3d (K, 3) m, scores (K,) or None)``; the keypoints of
    other ids left out, counted ``count("unknown_landmark_ids", n)``."""
    ids, pts = landmarks
    j = np.clip(np.searchsorted(ids, kp.ids), 0, len(ids) - 1)
    known = ids[j] == kp.ids
    n_unknown = int(np.count_nonzero(~known))
    if n_unknown:
        count("unknown_landmark_ids", n_unknown)
    scores = None if kp.scores is None else kp.scores[known]
    return kp.uv[known], pts[j[known]], scores


def rig_cloud_frame(
    name: str,
    inp: CameraInput,
    msg: Any,
    stamp: Stamp | ValueError,
    camera: CameraModel | None,
    landmarks: tuple | None = None,
    keypoints: bool = False,
) -> CameraFrame | UnreadFrame:
    """Camera ``name``'s correspondences cloud ``msg`` as the rig takes it, the rig node's and
    the rig bag reader's one path: ``stamp`` is its header stamp checked
    (:func:`~rs_localizer.ros.conversions.checked_stamp_ns`) or the error of that check,
    ``camera`` the camera model of that stamp (:func:`frame_camera`). Returns a
    :class:`~rs_localizer.tracking.localizer.CameraFrame` (the cloud's rows through
    :meth:`CameraInput.read_cloud`; tagged with its ``frame_id``, else ``name``), or an
    :class:`UnreadFrame`: the stamp cannot be read (``stamp_ns`` None), or the cloud cannot
    (no u, v, x, y, z fields, ...). ``keypoints``: ``msg`` is a keypoints cloud (u, v, id),
    its rows the points of ``landmarks`` it names (:meth:`CameraInput.read_keypoints`; not
    read without ``landmarks``; a frame without rows when none of its ids is known)."""
    from ..tracking.localizer import CameraFrame

    if isinstance(stamp, ValueError):
        return UnreadFrame(name, None, None, stamp)
    try:
        if keypoints:
            uv, xyz, _ = inp.read_keypoints(msg, landmarks)
        else:
            uv, xyz, _ = inp.read_cloud(msg)
    except ValueError as e:
        return UnreadFrame(name, stamp, camera, e)
    tag = msg.header.frame_id or name
    return CameraFrame(stamp, camera, uv, xyz, tag=tag, camera_name=name)


def rig_image_frame(
    name: str,
    inp: CameraInput,
    msg: Any,
    stamp: Stamp | ValueError,
    camera: CameraModel | None,
    frontend: Any,
) -> CameraFrame | UnreadFrame:
    """Camera ``name``'s image message ``msg`` as a frame of its front end's correspondences,
    without a rig to predict it (what ``calibrate-rig`` reads from a rig bag's images; the rig
    node and ``replay`` hand an image to the rig itself, :func:`hand_image_to_rig`): decoded
    and checked against ``camera``, the model of its checked header stamp ``stamp``
    (:meth:`CameraInput.decode`), the front end run on the whole image
    (``frontend.process(image, camera, encoding)``, a
    :class:`~rs_localizer.correspondences.Frontend`), its rows as a cloud's
    (:meth:`CameraInput.rows`: non-finite rows dropped, at most ``max_points``).

    Returns:
        a :class:`~rs_localizer.tracking.localizer.CameraFrame` tagged with its ``frame_id``
        (else ``name``; without ``camera``: no rows, as the rig takes a frame before its
        camera_info), or an :class:`UnreadFrame` skipped as ``bad_input`` (the stamp cannot
        be read), ``bad_image`` or ``image_size_mismatch`` (:meth:`CameraInput.decode`), or
        ``frontend_error`` (the front end raised).
    """
    from ..tracking.localizer import CameraFrame
    from .image_codec import ImageRejected

    if isinstance(stamp, ValueError):
        return UnreadFrame(name, None, None, stamp)
    tag = msg.header.frame_id or name
    if camera is None:
        return CameraFrame(stamp, None, np.zeros((0, 2)), np.zeros((0, 3)), tag=tag,
                           camera_name=name)  # fmt: skip
    try:
        image, encoding = inp.decode(msg, camera)
    except ImageRejected as e:
        return UnreadFrame(name, stamp, camera, e, e.reason)
    try:
        found = frontend.process(image, camera, encoding)
    except Exception as e:  # (any front end's failure: the frame is left out, counted)
        return UnreadFrame(name, stamp, camera, ValueError(f"{type(e).__name__}: {e}"),
                           "frontend_error")  # fmt: skip
    uv = np.asarray(found.points2d, float).reshape(-1, 2)
    xyz = np.asarray(found.points, float).reshape(-1, 3)
    uv, xyz, _ = inp.rows(uv, xyz, found.valid_scores())
    return CameraFrame(stamp, camera, uv, xyz, tag=tag, camera_name=name)


def hand_to_rig(rig: Localizer, item: CameraFrame | UnreadFrame) -> list[LocalizerOutput]:
    """A camera's frame of :func:`rig_cloud_frame` to the rig; returns the rig frames it
    completed, solved. A frame read: :meth:`~rs_localizer.tracking.video.Localizer.add`; an
    :class:`UnreadFrame` with a stamp: counted received and skipped for its reason, the rig
    no longer waiting for the camera at that time
    (:meth:`~rs_localizer.tracking.video.Localizer.drop`: a rig frame without it counts the
    camera ``missed.skipped``); one without a stamp: nothing (``[]``; its owner counts it)."""
    if not isinstance(item, UnreadFrame):
        return rig.add(item)
    if item.stamp_ns is None:
        return []
    return rig.drop(item.camera_name, item.stamp_ns, item.camera, item.reason)


def hand_image_to_rig(
    rig: Localizer,
    name: str,
    inp: CameraInput,
    msg: Any,
    stamp: Stamp,
    camera: CameraModel | None,
    log: Any,
    tag: object = None,
) -> tuple[list[LocalizerOutput], tuple | None]:
    """Camera ``name``'s image message ``msg`` (``sensor_msgs/Image`` or
    ``CompressedImage``) to the rig, the rig node's and the rig bag replay's one path:
    decoded and checked against ``camera``, the model of its checked header stamp ``stamp``
    (:meth:`CameraInput.decode`); a message rejected there (``bad_image``,
    ``image_size_mismatch``) is logged (``log.warning(key, text)``) and dropped for its reason
    (:meth:`~rs_localizer.tracking.video.Localizer.drop`: the rig does not wait for the camera
    at that time), any other goes through the camera's front end to the rig
    (:meth:`~rs_localizer.tracking.video.Localizer.process_image`), tagged ``tag`` (None:
    its ``frame_id``, else ``name``).

    Returns:
        (the rig frames it completed, solved; ``(image (H, W) or (H, W, C) uint8,
        encoding)`` decoded, or None when rejected).
    """
    from .image_codec import ImageRejected

    try:
        image, encoding = inp.decode(msg, camera)
    except ImageRejected as e:
        log.warning(f"image.{name}", f"rig camera {name!r}: image dropped ({e.reason}): {e}")
        return rig.drop(name, stamp, camera, e.reason), None
    if tag is None:
        tag = msg.header.frame_id or name
    return rig.process_image(name, stamp, image, camera, encoding, tag), (image, encoding)
