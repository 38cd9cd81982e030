"""One camera's input stage before the localizer, the same for the single-camera node and for
each camera of the rig node: its camera_infos checked and kept by stamp, and each frame message
(a ``sensor_msgs/PointCloud2`` of correspondences or keypoints, a ``sensor_msgs/Image`` or
``CompressedImage``) made what the localizer takes, or dropped for one reason.

:class:`CameraInput` is the camera's in the node's mode
(:class:`~rs_localizer.ros.mode.LocalizerMode`: the camera alone's and each rig camera's) and
in ``rs-localizer replay``, and each camera's in the reader of a rig bag's
frames (:func:`~rs_localizer.ros.bags.bag_frames.iter_rig_frames`: ``calibrate-rig`` and the
rig-frame grouping of ``play --lockstep``) and in ``replay`` of a rig bag, the rig's made by
:func:`rig_camera_inputs`. A frame message goes through it in three steps:
:meth:`CameraInput.check` (its header stamp checked, once), :meth:`CameraInput.camera_of` (the
camera model of that stamp, from the camera_infos; the single camera notes the stamp on its
video's clock first, :meth:`CameraInput.note_time`), :meth:`CameraInput.take` (the image decoded
and checked against that model, or the cloud's rows as the estimator takes them: non-finite
rows dropped, at most ``max_points``, a keypoint's 3D point from the landmarks). What comes out
is a :class:`~rs_localizer.tracking.localizer.CameraFrame` (a cloud's rows), an
:class:`ImageFrame` (the decoded image for the camera's front end) or a :class:`DroppedFrame`
with its reason (:data:`DROP_REASONS`); :func:`to_rig` hands any of them to a rig. The single
camera and the rig node take a frame to their rig in one step, :meth:`CameraInput.step`
(:meth:`CameraInput.take`, :func:`to_rig`, and a rig camera's stamp noted on the rig's clock
after it, :meth:`CameraInput.note_time`: its camera_infos after a time reset forgotten).

Its counts go to its owner's ``count(key, n)``, the camera's :class:`CameraCounts` (the
single-camera node's and each rig camera's: ``camera_info_rejected``,
``camera_info_rejected.<reason>``, ``time_resets`` (the single camera's), ``points_dropped``,
``capped_clouds``, ``capped_points``, ``unknown_landmark_ids``; reported as they are for the
single camera, after ``<camera>.`` for a rig's). Its warnings go to its owner's throttled log,
each text after the camera's ``label`` (the rig's ``rig camera 'front':``). No
module-level ROS import: messages are duck-typed (rclpy or rosbags).
"""

from __future__ import annotations

import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from ..camera import CameraModel, FrameTime, Stamp
from ..tracking.localizer import CameraFrame, usable_correspondences, usable_rows
from . import conversions as cv
from .camera_info_history import CameraInfoHistory, calibration_key
from .pointcloud import Keypoints, read_correspondences, read_keypoints

if TYPE_CHECKING:
    from ..correspondences import Correspondences
    from ..tracking.video import Localizer, LocalizerOutput

__all__ = [
    "DROP_REASONS",
    "STAGES",
    "CameraCounts",
    "CameraInput",
    "DroppedFrame",
    "ImageFrame",
    "landmark_rows",
    "rig_camera_inputs",
    "to_rig",
]

#: the worker's stages of a frame whose times a camera's counts keep
#: (:meth:`CameraCounts.stage_time`; the diagnostics' ``<stage>_ms_median``)
STAGES = ("decode", "frontend", "estimate", "publish")

#: the reasons :class:`CameraInput` drops a frame message for. The single camera's
#: (``failed.<reason>``): ``bad_stamp``, ``empty_cloud``, ``no_camera_info``, a cloud's
#: :data:`~rs_localizer.ros.pointcloud.CLOUD_REASONS`, ``no_landmarks``,
#: ``unknown_landmarks``, ``bad_image``, ``image_size_mismatch``, ``no_frontend``; a rig
#: camera's (``<camera>.skipped.<reason>``): ``bad_input`` (a cloud that cannot be read),
#: ``bad_image``, ``image_size_mismatch``, and as the single camera's
#: (``<camera>.failed.<reason>``, :meth:`CameraInput.admit`): ``bad_stamp`` (its header
#: stamp or its output stamp), ``no_frontend``
DROP_REASONS = {
    "bad_stamp": "the header stamp is out of range (negative, or past 2^31 s), or the output "
    "stamp (the reference row's time) is",
    "empty_cloud": "the cloud has no points",
    "no_camera_info": "no camera_info before the frame (after camera_info_wait) and no "
    "fallback intrinsics",
    "no_landmarks": "keypoints received but no landmarks_file is loaded",
    "unknown_landmarks": "none of the keypoints' ids is in the landmarks",
    "bad_image": "the image does not decode, has an unsupported encoding or is too small",
    "image_size_mismatch": "the image is another size than its camera_info's",
    "bad_input": "a rig camera's cloud that cannot be read (its fields, its landmarks)",
    "no_frontend": "an image while ``frontend`` is none",
}


class CameraCounts:
    """One camera's counters (thread-safe), the same for the single-camera node (its
    :class:`~rs_localizer.ros.pipeline.PipelineStats`), each camera of the rig node and of a rig
    bag's ``replay``: counts by key (each key written once, here, without the camera's
    prefix), the messages the middleware lost per input, the last ``kept`` times (s) of the
    camera's frames and the last ``kept`` times (s) per stage of :data:`STAGES`
    (:meth:`stage_time`: the single camera's frames, or a rig's worker's). :attr:`prefix` is
    what its keys carry in a report of many cameras:
    ``<name>.``, or "" for the single camera (``name`` "").

    Typical keys: ``received``, ``solved`` (the single camera's), ``skipped.<reason>``,
    ``failed.<reason>`` (a rig camera's: before the rig), ``points_dropped``,
    ``capped_clouds``, ``capped_points``, ``unknown_landmark_ids``,
    ``camera_info_rejected[.<reason>]`` (:class:`CameraInput`'s), ``frames_beside_frontend``,
    ``bad_input``."""

    def __init__(self, name: str = "", kept: int = 1000):
        self.name = name
        self.prefix = f"{name}." if name else ""
        self._lock = threading.Lock()
        self._counts: Counter = Counter()
        self._lost: dict[str, int] = {}
        self._times: deque[float] = deque(maxlen=kept)
        self._stages = {k: deque(maxlen=kept) for k in STAGES}

    def add(self, key: str, n: int = 1) -> None:
        """Add ``n`` to the counter ``key``."""
        with self._lock:
            self._counts[key] += n

    def get(self, key: str) -> int:
        """The counter ``key`` (0: never counted)."""
        with self._lock:
            return self._counts[key]

    def set(self, key: str, value: int) -> None:
        """Set the counter ``key`` to ``value`` (a state, e.g. ``map_fit_doubtful``)."""
        with self._lock:
            self._counts[key] = value

    def frame_done(self, seconds: float, *keys: str | None) -> None:
        """A frame handled in ``seconds`` (s): its time kept and each of ``keys`` (None:
        none) counted once, together (a snapshot sees all or none of them)."""
        with self._lock:
            for k in keys:
                if k is not None:
                    self._counts[k] += 1
            self._times.append(seconds)

    def lost(self, kind: str, total: int) -> None:
        """The middleware's count of messages lost on the camera's ``kind`` input so far (a
        QoS ``message_lost`` event's ``total_count``)."""
        with self._lock:
            self._lost[kind] = int(total)

    @property
    def messages_lost(self) -> int:
        """Messages lost by the middleware over all the camera's inputs."""
        with self._lock:
            return sum(self._lost.values())

    def counts(self) -> dict[str, int]:
        """A consistent copy of the counts, keys without the prefix; with messages lost on
        an input, ``messages_lost`` (their sum)."""
        with self._lock:
            out = dict(self._counts)
            if self._lost:
                out["messages_lost"] = out.get("messages_lost", 0) + sum(self._lost.values())
            return out

    def prefixed(self) -> dict[str, int]:
        """:meth:`counts` with each key after :attr:`prefix`."""
        return {self.prefix + k: v for k, v in self.counts().items()}

    def stage_time(self, stage: str, seconds: float) -> None:
        """Record the time (s) a frame spent in ``stage`` (one of :data:`STAGES`)."""
        with self._lock:
            self._stages[stage].append(seconds)

    def frame_stage_times(self, tic: float, taken_at: float, toc: float, front_s: float,
                          gyro_s: float, posed: bool = True) -> None:  # fmt: skip
        """A camera frame's times through the worker (:func:`time.perf_counter` s), the camera
        alone's and a rig camera's one way: taken by its input stage from ``tic`` to
        ``taken_at``, then the localizer until ``toc``. ``decode``: the input stage (decoding,
        its stamp and camera_info) and the wait for the gyro samples (``gyro_s``, the
        localizer's ``gyro_seconds`` of the rig frames it completed); when it completed a
        posed rig frame (``posed``), ``estimate``: the rest less its front end's search
        (``front_s``, recorded under ``frontend`` by its caller) and the gyro wait."""
        with self._lock:
            self._stages["decode"].append(taken_at - tic + gyro_s)
            if posed:
                self._stages["estimate"].append(toc - taken_at - front_s - gyro_s)

    def stage_times(self) -> dict[str, list[float]]:
        """A consistent copy of the kept stage times: stage -> s, oldest first."""
        with self._lock:
            return {k: list(d) for k, d in self._stages.items()}

    def frame_times(self) -> list[float]:
        """The kept frame times (s), oldest first."""
        with self._lock:
            return list(self._times)


class _Refused(ValueError):
    """A frame message the stage refuses, for ``reason``."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True)
class DroppedFrame:
    """A camera's frame message that :class:`CameraInput` did not make a frame of.

    Attributes:
        camera_name: the camera (the rig's name; "" for the single camera).
        stamp_ns: the message's checked header stamp; None: the stamp itself cannot be read
            (no rig frame can take the frame: a rig never sees it).
        camera: the camera model of that stamp (None: none yet, or no stamp).
        error: why (its text is the log's and the result's detail).
        reason: one of :data:`DROP_REASONS`.
    """

    camera_name: str
    stamp_ns: Stamp | None
    camera: CameraModel | None
    error: ValueError
    reason: str = "bad_input"


@dataclass(frozen=True)
class ImageFrame:
    """A camera's image message decoded for its front end: ``image`` (H, W) or (H, W, C)
    uint8 in ``encoding``, of the checked header stamp ``stamp_ns`` (ns) and the camera model
    ``camera`` of that stamp (None: a rig camera's before its first camera_info), ``tag`` as
    :attr:`~rs_localizer.tracking.localizer.CameraFrame.tag`."""

    camera_name: str
    stamp_ns: Stamp
    camera: CameraModel | None
    image: np.ndarray
    encoding: str
    tag: object = None


class FrameStep(NamedTuple):
    """A frame message through :meth:`CameraInput.step`: what :meth:`CameraInput.take` made
    of it (``item``), the rig frames it completed (``outs``: solved, oldest first) and the
    :func:`time.perf_counter` s when it was taken (decoded, before the rig)."""

    item: CameraFrame | ImageFrame | DroppedFrame
    outs: list
    taken_at: float


class CameraInput:
    """One camera's input stage (see the module docstring). :meth:`configure` before the
    first camera_info.

    Args:
        log: the owner's log: ``info(text)``, ``error(text)`` and ``warning(key, text)``,
            throttled per ``key`` (:class:`~rs_localizer.ros.pipeline.ThrottledLog`).
        count: ``count(key, n)`` adds ``n`` to the owner's counter ``key``.
        label: put before every text logged and every warning key (a rig's cameras share one
            log: each camera's warnings are throttled apart).
        stopped: ``stopped()`` true ends a frame's wait for its camera_info (shutdown).
        name: the camera's name in the rig ("" for the single camera): its frames'
            ``camera_name``, and their tag without a ``frame_id``.
        rig: take frames as a rig does: a frame without a camera model (before its
            camera_info), an empty cloud, a keypoints cloud of no known id go on to the rig
            (which counts them), not dropped; a cloud that cannot be read is dropped as
            ``bad_input``; the rows keep their scores (a rig of one solves them with the
            camera's estimator, which weighs them; a rig of several's takes none). Else as
            the single camera: each of those dropped for its own reason
            (:data:`DROP_REASONS`).

    Threads: camera_infos on one thread, frames on another (the history is thread-safe).
    """

    def __init__(
        self,
        log: Any,
        count: Callable[[str, int], Any],
        label: str = "",
        stopped: Callable[[], bool] = lambda: False,
        name: str = "",
        rig: bool = False,
    ):
        self.log = log
        self.count = count
        self.label = label
        self.name = name
        self.rig = rig
        self.history = CameraInfoHistory()
        #: the camera model of the camera_info accepted last (None: none yet)
        self.newest: CameraModel | None = None
        self.max_points: int | None = None
        self.fallback: CameraModel | None = None
        self.wait = 0.0
        #: the table of ``landmarks_file`` (``(ids (M,) sorted, points (M, 3) m)``) the
        #: keypoints' ids name; None: none loaded
        self.landmarks: tuple | None = None
        #: the frames' tag before their own ``frame_id`` (the single camera's
        #: ``camera_frame``); "": their ``frame_id``
        self.frame_id = ""
        self._stopped = stopped
        self._make_camera: Callable[[Any], CameraModel] | None = None

    def configure(
        self,
        make_camera: Callable[[Any], CameraModel],
        max_points: int | None = None,
        fallback: CameraModel | None = None,
        wait: float = 0.0,
        landmarks: tuple | None = None,
        frame_id: str = "",
    ) -> None:
        """Use ``make_camera(msg)`` (a camera_info's model with the camera's rolling-shutter
        timing; raises :class:`~rs_localizer.ros.conversions.CameraInfoError` or ValueError for
        one it cannot use) from now on; the models of the camera_infos received so far are
        rebuilt with it (one it rejects is dropped and logged as an error). ``max_points``: the
        cap on a cloud's rows (None: none); ``fallback``: the model of a frame before any
        camera_info (the parameters' intrinsics; None: none); ``wait``: s a frame waits for its
        camera_info (:meth:`camera_of`); ``landmarks``: :attr:`landmarks`; ``frame_id``:
        :attr:`frame_id`. :attr:`newest` is the rebuilt model of the newest camera_info
        kept."""
        self._make_camera = make_camera
        self.max_points, self.fallback, self.wait = max_points, fallback, float(wait)
        self.landmarks, self.frame_id = landmarks, frame_id
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

    def source(self) -> str:
        """Where the camera's intrinsics come from: ``camera_info`` (one kept), ``parameters``
        (the fallback) or ``missing``."""
        if len(self.history):
            return "camera_info"
        return "parameters" if self.fallback is not None else "missing"

    def wake(self) -> None:
        """Wake a frame waiting for its camera_info in :meth:`camera_for` (to see
        ``stopped()``)."""
        self.history.wake()

    # ---------------------------------------------------------------- frames
    def tag_of(self, msg: Any) -> str:
        """The tag of a frame message's frame: :attr:`frame_id`, else its header's
        ``frame_id``, else the camera's name (``camera`` for the single camera)."""
        return self.frame_id or msg.header.frame_id or self.name or "camera"

    def failed_text(self, error: BaseException) -> str:
        """The warning of a frame whose step raised ``error`` (a defect: the frame is failed
        ``internal_error`` and the next ones go on), as the node and replay log it."""
        return f"{self.label}frame failed (internal_error): {type(error).__name__}: {error}"

    def check(self, msg: Any, kind: str) -> Stamp | DroppedFrame:
        """A frame message's header stamp checked, the frame's one check of it
        (:func:`~rs_localizer.ros.conversions.checked_stamp_ns`): the stamp (ns), or a
        :class:`DroppedFrame` (``stamp_ns`` None) for a stamp out of range (``bad_stamp``, the
        single camera's and a rig camera's alike: :meth:`admit` returns it); the single
        camera's cloud (``kind`` other than ``image``)
        without points: ``empty_cloud``."""
        try:
            stamp = cv.checked_stamp_ns(msg.header.stamp)
        except cv.StampError as e:
            return DroppedFrame(self.name, None, None, e, e.reason)
        if not self.rig and kind != "image" and int(msg.width) * int(msg.height) == 0:
            return self._dropped(stamp, None, _Refused("empty_cloud", "cloud has no points"))
        return stamp

    def admit(
        self,
        kind: str,
        stamp: Stamp | DroppedFrame,
        camera: CameraModel | DroppedFrame | None,
        frame_time: Callable[[Stamp, CameraModel | None], FrameTime],
        frontend: bool,
    ) -> FrameTime | DroppedFrame:
        """The checks of a frame before it is solved, the single camera's and a rig camera's
        alike (the frame's one entry into its localizer): its ``stamp`` of :meth:`check` and
        its ``camera`` of :meth:`camera_of` (a :class:`DroppedFrame` of either returned as it
        is), then its times, made once here (``frame_time(stamp, camera)``: the localizer's,
        :meth:`~rs_localizer.tracking.sequence.SequenceLocalizer.frame_time` or
        :meth:`~rs_localizer.tracking.video.Localizer.frame_time`), whose reference time, the
        stamp of the outputs, must lie in [0, 2^31 s) (else a :class:`DroppedFrame`,
        ``bad_stamp``); an image (``kind``) without a front end (``frontend`` false): dropped,
        ``no_frontend``. Returns the frame's :class:`~rs_localizer.camera.FrameTime`, or the
        :class:`DroppedFrame` its owner counts ``failed.<reason>`` (the rig never sees it)."""
        for given in (stamp, camera):
            if isinstance(given, DroppedFrame):
                return given
        ft = frame_time(stamp, camera)
        out_stamp = ft.reference_ns
        if not 0 <= out_stamp <= cv.STAMP_MAX_NS:
            why = _Refused(
                "bad_stamp",
                f"output stamp {out_stamp} ns (input {stamp} ns + the reference row's offset) "
                "is outside [0, 2^31 s)",
            )
            return DroppedFrame(self.name, stamp, camera, why, why.reason)
        if kind == "image" and not frontend:  # (the node subscribes images only with one)
            why = _Refused("no_frontend", "image received but frontend is none")
            return DroppedFrame(self.name, stamp, camera, why, why.reason)
        return ft

    def note_time(self, stamp: Stamp, clock: Callable[[Stamp], str | None]) -> None:
        """A checked frame ``stamp`` (ns) noted on the clock of the camera's video, in frame
        order: ``clock(stamp)`` returns why the stamp is a time reset (older than the previous
        frame's, or newer by more than ``time_reset_threshold``), else None
        (:meth:`~rs_localizer.tracking.sequence.SequenceLocalizer.check_time`). A time reset
        is counted ``time_resets`` and logged (``time reset: <why>``, after the label), and
        the camera_infos stamped after it are forgotten
        (:meth:`~rs_localizer.ros.camera_info_history.CameraInfoHistory.forget_after`). No
        frame is dropped for it. A rig camera's time reset is the rig's to count and log
        (``rig.time_resets``, ``rig time reset: <why>``): only its camera_infos are forgotten."""
        why = clock(stamp)
        if why is None:
            return
        if not self.rig:
            self.count("time_resets", 1)
            self._warn("time_reset", f"time reset: {why}")
        self.history.forget_after(stamp)

    def camera_of(self, stamp: Stamp | DroppedFrame) -> CameraModel | DroppedFrame | None:
        """The camera model of a frame whose :meth:`check` gave ``stamp``
        (:meth:`camera_for`: it may wait up to :attr:`wait` for its camera_info; the rig node
        looks it up before it takes the rig's lock, so that camera_info and the diagnostics
        are served meanwhile). None: a frame dropped by :meth:`check`, or a rig camera's before
        any camera_info; the single camera's without one: a :class:`DroppedFrame`
        (``no_camera_info``)."""
        if isinstance(stamp, DroppedFrame):
            return None
        camera = self.camera_for(stamp)
        if camera is None and not self.rig:
            why = _Refused(
                "no_camera_info",
                f"no camera_info received (waited {self.wait:.3f} s) and no fallback "
                "intrinsics (camera.fx <= 0)",
            )
            return self._dropped(stamp, None, why)
        return camera

    def take(
        self, msg: Any, kind: str, stamp: Stamp | DroppedFrame, camera: CameraModel | None
    ) -> CameraFrame | ImageFrame | DroppedFrame:
        """A frame message as the localizer takes it, with ``stamp`` of :meth:`check` and
        ``camera`` the model of that stamp (:meth:`camera_of`; a :class:`DroppedFrame` of
        either is returned as it is). ``kind``: ``correspondences`` (or ``cloud``: u, v, x, y,
        z [, score]; :func:`~rs_localizer.ros.pointcloud.read_correspondences`), ``keypoints``
        (u, v, id [, score]: each the 3D point of its id in :attr:`landmarks`,
        :func:`landmark_rows`) or ``image`` (``sensor_msgs/Image`` or ``CompressedImage``,
        :meth:`decode`).

        Returns:
            an :class:`ImageFrame`; a :class:`~rs_localizer.tracking.localizer.CameraFrame`
            of the cloud's rows as the estimator takes them (:meth:`rows`), tagged
            :meth:`tag_of`; or a :class:`DroppedFrame`: a cloud that cannot be read
            (a :data:`~rs_localizer.ros.pointcloud.CLOUD_REASONS` reason; a rig's
            ``bad_input``), keypoints without :attr:`landmarks` (``no_landmarks``; a rig's
            ``bad_input``) or, for the single camera, of no known id
            (``unknown_landmarks``), an image refused by :meth:`decode` (``bad_image``,
            ``image_size_mismatch``).
        """
        for given in (stamp, camera):
            if isinstance(given, DroppedFrame):
                return given
        tag = self.tag_of(msg)
        try:
            if kind == "image":
                image, encoding = self.decode(msg, camera)
                return ImageFrame(self.name, stamp, camera, image, encoding, tag)
            uv, xyz, scores = self._rows_of(msg, kind)
        except ValueError as e:
            # (a defect, the caller's internal_error; a rig drops any cloud it cannot read)
            if not hasattr(e, "reason") and (kind == "image" or not self.rig):
                raise
            return self._dropped(stamp, camera, e)
        return CameraFrame(stamp, camera, uv, xyz, scores, tag, self.name)

    def step(
        self,
        rig: Localizer,
        msg: Any,
        kind: str,
        stamp: Stamp | DroppedFrame,
        camera: CameraModel | DroppedFrame | None,
        reference_ns: int | None = None,
    ) -> FrameStep:
        """A camera's frame message of a checked ``stamp`` (:meth:`check`) and its ``camera``
        (:meth:`camera_of`) to ``rig``, the one frame step of the single camera (its rig of
        one) and of a rig's camera (the node's mode, ``replay``): :meth:`take`, then
        :func:`to_rig` (``reference_ns`` as there);
        a rig camera's stamp then noted on the rig's clock (:meth:`note_time` with
        :meth:`~rs_localizer.tracking.video.Localizer.took_time_reset`: its camera_infos after
        a time reset forgotten, as the single camera's, which notes its stamp ahead of the
        frame). A frame the single camera drops does not go to its rig (its owner counts it
        ``failed.<reason>``); a rig camera's with a stamp goes there as skipped."""
        item = self.take(msg, kind, stamp, camera)
        taken_at = time.perf_counter()
        if isinstance(item, DroppedFrame) and not self.rig:
            return FrameStep(item, [], taken_at)
        outs = to_rig(rig, item, reference_ns)
        if self.rig and not isinstance(stamp, DroppedFrame):
            self.note_on_rig(rig, stamp)
        return FrameStep(item, outs, taken_at)

    def enter(self, rig: Localizer, msg: Any, kind: str, stamp: Stamp | DroppedFrame,
              camera: CameraModel | None, frontend: bool,
              before: Callable[[FrameTime], Any] | None = None
              ) -> FrameStep | DroppedFrame:  # fmt: skip
        """A rig camera's frame message of a checked ``stamp`` (:meth:`check`) and its
        ``camera`` (:meth:`camera_of`) into ``rig``, the rig node's frame step and a rig bag's
        replay's: :meth:`admit` with its times on the rig's clock
        (:meth:`~rs_localizer.tracking.video.Localizer.frame_time`; ``frontend``: the rig's
        cameras have front ends), a :class:`DroppedFrame` returned as it is (its owner counts
        it ``failed.<reason>``: the rig never sees it); else ``before(frame time)`` when given
        (a replay's gyro samples up to the frame), then :meth:`step`."""
        ft = self.admit(kind, stamp, camera, partial(rig.frame_time, self.name), frontend)
        if isinstance(ft, DroppedFrame):
            return ft
        if before is not None:
            before(ft)
        return self.step(rig, msg, kind, ft.stamp_ns, camera, ft.reference_ns)

    def note_on_rig(self, rig: Localizer, stamp: Stamp) -> None:
        """A rig camera's checked frame ``stamp`` noted on ``rig``'s clock after its frame went
        to the rig (:meth:`note_time` with
        :meth:`~rs_localizer.tracking.video.Localizer.took_time_reset`: after a time reset,
        the camera_infos stamped after the camera's first frame of the new timeline
        forgotten; a late frame of the old timeline forgets none, the camera's next frame
        takes the reset); the rig node's (:meth:`step`) and a rig bag's replay's."""
        self.note_time(stamp, lambda stamp: rig.took_time_reset(self.name, stamp))

    def _dropped(
        self, stamp: Stamp | None, camera: CameraModel | None, error: ValueError
    ) -> DroppedFrame:
        """The frame dropped for ``error``'s ``reason``; a rig's cloud that cannot be read (all
        but an image refused by :meth:`decode`): ``bad_input``."""
        from .image_codec import ImageRejected

        reason = getattr(error, "reason", "bad_input")
        if self.rig and not isinstance(error, ImageRejected):
            reason = "bad_input"
        return DroppedFrame(self.name, stamp, camera, error, reason)

    def _rows_of(self, msg: Any, kind: str) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """The rows of a cloud (:meth:`take`). Raises CloudError, :class:`_Refused`."""
        if kind != "keypoints":
            c = read_correspondences(msg)
            return self.rows(c.uv, c.xyz, c.scores)
        if self.landmarks is None:
            raise _Refused("no_landmarks", "keypoints received but no landmarks_file is loaded")
        kp = read_keypoints(msg)
        uv, xyz, scores = landmark_rows(kp, self.landmarks, self.count)
        if not len(uv) and not self.rig:
            raise _Refused("unknown_landmarks", f"none of the {len(kp)} keypoint ids is in the map")
        return self.rows(uv, xyz, scores)

    def rows(
        self, uv: np.ndarray, xyz: np.ndarray, scores: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """A frame's rows ``uv`` (N, 2) px, ``xyz`` (N, 3) m, ``scores`` (N,) or None without
        the non-finite ones (counted ``points_dropped``), then capped to ``max_points``
        (counted ``capped_clouds``, ``capped_points``; a warning):
        :func:`~rs_localizer.tracking.localizer.usable_rows`."""
        return usable_rows(uv, xyz, scores, self.max_points, self.count, self._warn)

    def usable(self, found: Correspondences) -> Correspondences:
        """A front end's correspondences ``found`` with :meth:`rows`' rows (counted and
        warned alike), each row's ``ids`` and ``groups`` kept (a marker's corners keep their
        group): :func:`~rs_localizer.tracking.localizer.usable_correspondences`."""
        return usable_correspondences(found, self.max_points, self.count, self._warn)

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
    landmarks: tuple | None = None,
) -> dict[str, CameraInput]:
    """Each camera of a rig its :class:`CameraInput` (``rig`` true), configured as the rig
    node takes the camera's inputs: its camera_infos made models with the camera's
    rolling-shutter timing (``rig.<camera>.line_delay``, ``readout_time``, ``direction``, else
    the ``rs.*`` values) and the rig's reference row, its clouds' rows capped to the rig's
    ``max_points``. The node's rig (:class:`~rs_localizer.ros.mode.LocalizerMode`), ``replay`` of
    a rig bag and the reader of a rig bag's frames
    (:func:`~rs_localizer.ros.bags.bag_frames.iter_rig_frames`: ``calibrate-rig``, the
    rig-frame grouping of ``play --lockstep``) all read their cameras through them, so that
    all take the same rows of a cloud and count them alike.

    Args:
        config: the rig's :class:`~rs_localizer.ros.config.LocalizerConfig` (each camera's
            models made by its :meth:`~rs_localizer.ros.config.CameraConfig.camera_from_info`).
        log: the log the cameras share (:class:`CameraInput`'s ``log``); each camera's texts
            come after ``rig camera '<camera>': ``.
        count: ``count(camera, key, n)`` adds ``n`` to camera ``camera``'s count ``key``
            (``points_dropped``, ``capped_clouds``, ...).
        stopped: ``stopped()`` true ends a frame's wait for its camera_info.
        wait: s a camera's frame waits for its camera_info (the node's ``camera_info_wait``,
            as a camera's: :meth:`CameraInput.camera_for`; a bag's reader: 0, its messages in
            log-time order).
        landmarks: the table of ``landmarks_file`` the cameras' keypoints name (None: none).

    Returns:
        camera name -> its :class:`CameraInput`, in the order of ``rig.cameras``.
    """
    inputs = {}
    for c in config.cameras:
        inp = CameraInput(log, partial(count, c.name), f"rig camera {c.name!r}: ", stopped,
                          name=c.name, rig=True)  # fmt: skip
        inp.configure(c.camera_from_info, config.settings.max_points, wait=wait,
                      landmarks=landmarks)  # fmt: skip
        inputs[c.name] = inp
    return inputs


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


def to_rig(
    rig: Localizer,
    item: CameraFrame | ImageFrame | DroppedFrame,
    reference_ns: int | None = None,
) -> list[LocalizerOutput]:
    """A rig camera's frame of :meth:`CameraInput.take` to the rig, the rig node's and the rig
    bag reader's one path (and the single camera's frames of correspondences, to its rig of
    one); returns the rig frames it completed, solved. A
    :class:`~rs_localizer.tracking.localizer.CameraFrame`:
    :meth:`~rs_localizer.tracking.video.Localizer.add` (``reference_ns``: the frame's time on
    the rig's clock when the caller made it; None: made there); an :class:`ImageFrame`: through the
    camera's front end (:meth:`~rs_localizer.tracking.video.Localizer.process_image`, with
    ``reference_ns`` as well; the single camera's images go to its rig of one so); a
    :class:`DroppedFrame` with a stamp: counted received and skipped for its reason, the rig
    no longer waiting for the camera at that time
    (:meth:`~rs_localizer.tracking.video.Localizer.drop`: a rig frame without it counts the
    camera ``missed.skipped``); one without a stamp: nothing (``[]``; its owner counts it)."""
    if isinstance(item, ImageFrame):
        t = item.stamp_ns if reference_ns is None else FrameTime(item.stamp_ns, reference_ns)
        return rig.process_image(item.camera_name, t, item.image, item.camera, item.encoding,
                                 item.tag)  # fmt: skip
    if not isinstance(item, DroppedFrame):
        return rig.add(item) if reference_ns is None else rig.add(item, reference_ns)
    if item.stamp_ns is None:
        return []
    return rig.drop(item.camera_name, item.stamp_ns, item.camera, item.reason)
