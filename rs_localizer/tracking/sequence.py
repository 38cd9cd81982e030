"""The library's video entry point: one rolling-shutter camera's frames, in order, with its gyro.

A camera alone is a rig of one: :class:`SequenceLocalizer` is the camera's adapter over a
:class:`~rs_localizer.tracking.video.Localizer` of the one camera at the identity mounting
(:attr:`~rs_localizer.tracking.video.LocalizerSettings.single_camera`), whose code solves a camera's
frames and a rig's. That rig of one holds the camera's video state (in the spirit of OpenVINS'
``VioManager``, which its ROS wrappers and bag runner only drive):

- the video tracker (:class:`~rs_localizer.tracking.tracker.RSTracker`: predicted RANSAC,
  relocalization, resets, the fused twist), made again when the solver, the estimator or
  tracking options or the camera model change;
- the frames whose pose is out but whose fused twist is final only ``tracking.lag`` frames
  later (:attr:`SequenceOutput.fused` hands them out when they are);
- the gyro samples (:class:`~rs_localizer.tracking.gyro.ImuBuffer`, fed by :meth:`add_imu`)
  and each frame's gyro measurement over its readout;
- the online gyro-bias estimate (:class:`~rs_localizer.tracking.gyro_bias.GyroBiasEstimator`,
  with ``estimate_bias``) and the check of the gyro against the rotation between solved frames
  (:class:`~rs_localizer.tracking.gyro_check.GyroMountCheck`: frames are solved without the
  gyro while it is declared inconsistent);
- the time policy (:class:`SequenceSettings`): a frame stamp older than the previous one, or
  newer by more than ``time_reset_ns`` (:meth:`check_time`), starts the gyro's timeline again
  (the samples of the previous timeline, the bias estimator's and the check's pairing);
  frames further apart than :attr:`SequenceSettings.max_gap` share nothing across the gap
  (the track resets, the front end gets no prediction, the gyro check and the bias estimator
  form no pair);
- the prediction of each frame (:meth:`predict`): the tracker's, the one its estimator
  starts from, is what the front end searches with (no front end keeps a pose);
- the optional image front end (:meth:`set_frontend`) and its search by the camera's rules
  (:meth:`Localizer.search_image <rs_localizer.tracking.video.Localizer.search_image>`: the
  time noted first, the frozen-image check, an image whose front end found fewer
  correspondences than the solver needs dropped before the estimator).

The adapter itself keeps what is the camera's own: its settings, its frames' times
(:meth:`frame_time`), its counters, its outputs (:class:`SequenceOutput`, with why an image
was dropped) and the front end's feedback: what :meth:`process_image` calls on the front end
is the :class:`~rs_localizer.correspondences.VideoFrontend` protocol.

API: :meth:`add_imu` (a gyro sample), :meth:`process` (a frame's 2D-3D correspondences ->
:class:`SequenceOutput`), :meth:`process_image` (an image, through the front end ->
:class:`SequenceOutput`), :meth:`flush` (end of the video: the twists still pending),
:meth:`reset` (forget everything but the configuration). Stamps are checked (a finite number
within the int64 nanosecond range, else ValueError) and so is a frame's camera model (else
TypeError). The node (:class:`~rs_localizer.ros.mode.LocalizerMode`) and ``rs-localizer
replay`` run a camera's messages on the same rig of one (:attr:`SequenceLocalizer.rig`)
directly; ``benchmarks/bench_gyro.py`` and ``benchmarks/bench_video.py`` drive this object.

Example (a video of correspondences and a gyro; ``camera`` a
:class:`~rs_localizer.camera.CameraModel` with its rolling-shutter timing)::

    seq = SequenceLocalizer(SequenceSettings(imu=GyroSettings(R_cam_imu=R)))
    for t_ns, w in gyro_samples:
        seq.add_imu(t_ns, w)
    for stamp_ns, uv, xyz in frames:
        out = seq.process(CameraFrame(stamp_ns, camera, uv, xyz))
        if out.estimate is not None and out.estimate.success:
            ...  # out.estimate: pose and the frame's own twist
        for f in out.fused:
            ...  # f.pose: an earlier frame's pose with its fused twist
    for f in seq.flush():
        ...
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..camera import (
    MAX_STAMP_NS,
    CameraModel,
    FrameTime,
    Stamp,
    checked_stamp,
    reference_stamp_ns,
)
from ..correspondences import Correspondences, Frontend, VideoFrontend
from ..estimation.estimate import EstimateOptions
from ..estimation.implementation import default_implementation
from ..frames import Mounting
from ..pose import RSModel
from .gyro_input import GyroInput, GyroReadouts, GyroSettings, SilentLog, TrackLog
from .localizer import (
    FROZEN_IMAGE_LEVEL,
    MAX_PENDING,
    CameraFrame,
    FrameOutput,
    FusedPose,
    check_camera,
)
from .tracker import TrackerOptions
from .video import SINGLE_CAMERA_SOLVER, Localizer, LocalizerOutput, LocalizerSettings

__all__ = [
    "FRONTEND_FAILURES",
    "MAX_PENDING",
    "MAX_STAMP_NS",
    "FusedPose",
    "GyroSettings",
    "SequenceLocalizer",
    "SequenceOutput",
    "SequenceSettings",
    "reference_stamp_ns",
    "rig_of_one",
]

#: why :meth:`SequenceLocalizer.process_image` drops an image before the estimator
#: (:attr:`SequenceOutput.failure`): the front end raised, or found fewer correspondences
#: than the solver needs, or the image is the previous one again (:func:`same_image`)
FRONTEND_FAILURES = ("frontend_error", "frontend_too_few_points", "frozen_image")


@dataclass(frozen=True)
class SequenceSettings:
    """The configuration of a :class:`SequenceLocalizer`.

    Attributes:
        solver: minimal solver name (:mod:`rs_localizer.solvers.registry`).
        options: the estimator's :class:`~rs_localizer.estimation.estimate.EstimateOptions`
            (None: the defaults).
        tracking: the video tracker's
            :class:`~rs_localizer.tracking.tracker.TrackerOptions`; None: every frame alone.
        imu: how the gyro is used (:class:`GyroSettings`); None: no gyro.
        stamp_row: the row (px along the readout) whose capture time is a frame's stamp.
        time_reset_ns: a forward stamp jump larger than this (ns), or any step back, is a time
            reset: the clock may have started again (a bag replayed, a driver restarted), so
            the gyro's timeline starts again (its samples older than the previous frame are
            dropped; the node counts ``time_resets``). Longer than :attr:`max_gap` by default
            (1 s against 0.5 s): frames lost for half a second leave the gyro's samples
            usable, while nothing is predicted across the gap.
        frozen_image_level: an image of :meth:`SequenceLocalizer.process_image` whose pixel
            sample differs from the previous image's by at most this mean absolute
            difference (gray levels; :func:`same_image`) is the same picture again (a driver
            re-sending its last frame, a USB stall, a frozen stream): it is dropped as
            ``frozen_image`` before the front end (its pose would be the old frame's, at a new
            time), and the next new image is searched whole and starts a new track (the
            camera moved by an unknown amount meanwhile: a prediction carried over the frozen
            frames misplaced the optical flow's tracks). Negative: never.
        max_points: the most rows a frame of :meth:`SequenceLocalizer.process_image` gives
            the estimator (spread over the image, :func:`~rs_localizer.estimation.points.
            cap_points`; :func:`~rs_localizer.tracking.localizer.usable_rows`); None: no cap.
        check_gyro: check the gyro against the rotation between solved frames and solve
            without it while they disagree (the node always does; off only to show what the
            check prevents).
    """

    solver: str = SINGLE_CAMERA_SOLVER
    options: EstimateOptions | None = None
    tracking: TrackerOptions | None = field(default_factory=TrackerOptions)
    imu: GyroSettings | None = None
    stamp_row: float = 0.0
    time_reset_ns: int = 10**9
    check_gyro: bool = True
    max_points: int | None = None
    frozen_image_level: float = FROZEN_IMAGE_LEVEL

    @property
    def max_gap(self) -> float:
        """s: the one gap policy of the video, ``tracking.max_gap`` (the
        :class:`~rs_localizer.tracking.tracker.TrackerOptions` default, 0.5 s, without
        tracking). Frames further apart, or a stamp going back or repeated, share nothing
        across the gap (:func:`~rs_localizer.tracking.tracker.predictable`): the tracker
        resets, the front end gets no prediction (it searches the image whole), and the gyro
        check and the gyro-bias estimator form no pair across it (their ``max_interval``);
        after this long without frames (wall clock) the pending twists go out
        (:meth:`SequenceLocalizer.flush_idle`)."""
        t = self.tracking
        return float(t.max_gap if t is not None else TrackerOptions.max_gap)


@dataclass
class SequenceOutput(FrameOutput):
    """What became of a frame in :meth:`SequenceLocalizer.process`: a
    :class:`~rs_localizer.tracking.localizer.FrameOutput` (``stamp_ns``, the frame's
    reference time; ``estimate``, ``path``, ``fused``, ``gyro``, ``error``, ``compiled``,
    ``success``) with a camera's own fields.

    Attributes:
        twist_now: the frame's own twist is its final twist (no tracking, a global-shutter
            solver or no readout timing); else its fused twist comes in a later ``fused``.
        new_track: the frame started a track (first frame, reset, new tracker).
        gyro_seconds: s spent getting the gyro measurement (waiting for samples included).
        failure, detail: an image frame (:meth:`SequenceLocalizer.process_image`) dropped
            before the estimator: ``frontend_error`` (the front end raised) or
            ``frontend_too_few_points`` (fewer correspondences than the solver needs), with
            the text; else None and "".
        correspondences: what the front end made of the image (before non-finite rows are
            dropped and the cap), or None (no image, or the front end raised).
        points2d, points3d: (M, 2) px and (M, 3) m, the rows the estimator was given (after
            :func:`~rs_localizer.tracking.localizer.usable_rows`); None when it did not run.
        frontend_seconds: s spent in the front end.
    """

    twist_now: bool = True
    new_track: bool = False
    gyro_seconds: float = 0.0
    failure: str | None = None
    detail: str = ""
    correspondences: Correspondences | None = None
    points2d: np.ndarray | None = None
    points3d: np.ndarray | None = None
    frontend_seconds: float = 0.0


#: the one camera's mounting in its rig of one: the camera's frame is the rig's
_IDENTITY = Mounting(np.eye(3), np.zeros(3))
#: the one camera's name in its rig of one (a :class:`CameraFrame`'s default ``camera_name``)
_CAMERA = ""


def rig_of_one(settings: SequenceSettings) -> LocalizerSettings:
    """The :class:`~rs_localizer.tracking.video.LocalizerSettings` of a camera's rig of one (the
    camera, named ``""``, at the identity mounting:
    :attr:`~rs_localizer.tracking.video.LocalizerSettings.single_camera`) that solves the
    frames of a :class:`SequenceLocalizer` with ``settings``: its solver, estimator options
    (None: the defaults, ``EstimateOptions()``), tracking, gyro and its check, ``stamp_row``,
    ``time_reset_ns``, ``max_points`` and ``frozen_image_level``."""
    options = settings.options if settings.options is not None else EstimateOptions()
    return LocalizerSettings(
        {_CAMERA: _IDENTITY},
        stamp_row=settings.stamp_row,
        time_reset_ns=settings.time_reset_ns,
        options=options,
        tracking=settings.tracking,
        imu=settings.imu,
        max_points=settings.max_points,
        solver=settings.solver,
        check_gyro=settings.check_gyro,
        frozen_image_level=settings.frozen_image_level,
    )


class SequenceLocalizer(GyroReadouts):
    """A camera's video (see the module docstring): the single-camera adapter over its rig of
    one (:func:`rig_of_one`).

    Args:
        settings: the :class:`SequenceSettings` (None: the defaults; change them at run time
            with :meth:`configure`).
        log: where warnings go, a :class:`~rs_localizer.tracking.gyro_input.TrackLog`
            (``warning(key, text)``, ``key``: the kind, for throttling; ``info(text)``);
            None: silent.
        count: ``count(key, n)`` for each counter (the node's diagnostics keys:
            ``frames_with_gyro``, ``gyro_rejected``, ``gyro_missing[.<reason>]``,
            ``gyro_disabled_inconsistent``, ``gyro_pairs_failed``,
            ``gyro_inconsistent_detections``, ``gyro_bias_rejected``; ``points_dropped``,
            ``capped_clouds``, ``capped_points`` of an image's rows,
            :func:`~rs_localizer.tracking.localizer.usable_rows`); None: counted in
            :attr:`counts`.
        stopped: ``stopped()`` true ends a frame's wait for its gyro samples (shutdown).
        imu_span: s of gyro samples kept (default ``imu.buffer``; ``inf`` when every sample is
            added before the frames, e.g. a bag replayed offline).
        frontend: the image front end of :meth:`process_image` (any
            :class:`~rs_localizer.correspondences.Frontend`; see :meth:`set_frontend`), or
            None; frontend_name: its name in warnings and errors (e.g. ``aruco``).
        implementation: ``implementation(solver)`` names the estimator implementation a frame
            runs on, ``"compiled"`` or ``"numpy"``
            (:mod:`rs_localizer.estimation.implementation`), asked once per frame. Default:
            the compiled kernels wherever numba works. A node whose kernels compile in the
            background passes :func:`rs_localizer.runtime.background.ready_implementation`:
            until the kernels are ready its frames are solved on the NumPy implementation,
            with the tracker (predicted RANSAC, the twist filter), the gyro and its checks as
            on the compiled kernels; a track under way goes on across the switch.

    Threads: :meth:`process` on one thread at a time; :meth:`add_imu`, :meth:`flush_idle`
    and the read-outs from others.
    """

    def __init__(
        self,
        settings: SequenceSettings | None = None,
        *,
        log: TrackLog | None = None,
        count: Callable[[str, int], None] | None = None,
        stopped: Callable[[], bool] = lambda: False,
        imu_span: float | None = None,
        frontend: Frontend | VideoFrontend | None = None,
        frontend_name: str = "frontend",
        implementation: Callable[[str], str] = default_implementation,
    ):
        self.log: TrackLog = log if log is not None else SilentLog()
        self.counts: Counter = Counter()
        self._count = count if count is not None else self._count_here
        self.settings = settings = settings or SequenceSettings()
        # the gyro: its samples, bias, mount check and counters (the camera's names)
        self.gyro_input = GyroInput(self._count, self.log, stopped=stopped, span=imu_span)
        # the camera's rig of one: the tracker, the twists pending, the last posed frame
        # carried, the clock, the gyro's use (tracking/video.py)
        self._rig = Localizer(
            rig_of_one(settings),
            self.log,
            lambda: implementation(self.settings.solver),
            gyro_input=self.gyro_input,
            count=self._count,
        )
        # the front end and the fingerprint of the previous image: the rig of one's camera's
        # (Localizer.camera_frontend)
        self._camera_frontend = self._rig.camera_frontend(_CAMERA)
        self.set_frontend(frontend, frontend_name)

    def _count_here(self, key: str, n: int = 1) -> None:
        self.counts[key] += n

    # ---------------------------------------------------------------- configuration
    def configure(self, settings: SequenceSettings) -> None:
        """Use ``settings`` from the next frame on. The gyro samples are kept; the bias
        estimate and the gyro check are kept while the gyro calibration they depend on stays
        the same, else started again (a corrected ``imu.rotation`` given at run time is tested
        anew); the tracker is made again at the next frame when the solver, the options or the
        tracking options changed."""
        self.settings = settings
        self._rig.configure(rig_of_one(settings))

    # ---------------------------------------------------------------- read-outs
    def tracking_values(self) -> dict[str, Any]:
        """Video tracking: ``track_state`` (tracking, lost or disabled), ``frames_tracked``,
        ``relocalizations``, ``resets``, ``twists_own_frame`` and ``twists_implausible``
        (:meth:`twist_values`), ``readout_contradicted`` and ``readout_suspect`` (the check of
        the rolling-shutter timing, :meth:`readout_values`)."""
        return self._rig.tracking_values()

    @property
    def pending(self) -> int:
        """Frames whose fused twist is not final yet."""
        return self._rig.pending

    def twist_values(self) -> dict[str, int]:
        """The fused twists handed out over the video's life: ``twists_own_frame`` and
        ``twists_implausible``
        (:meth:`~rs_localizer.tracking.video.Localizer.twist_values`)."""
        return self._rig.twist_values()

    def readout_values(self) -> dict[str, Any]:
        """The check of the rolling-shutter timing: ``readout_contradicted`` and
        ``readout_suspect``
        (:meth:`~rs_localizer.tracking.video.Localizer.readout_values`)."""
        return self._rig.readout_values()

    # ---------------------------------------------------------------- time
    def frame_time(self, stamp_ns: int | FrameTime, camera: CameraModel) -> FrameTime:
        """The times of a frame stamped ``stamp_ns`` (ns, the capture time of row
        ``stamp_row``) seen by ``camera``: its stamp checked and its reference time
        (:class:`~rs_localizer.camera.FrameTime`, with the settings' ``stamp_row``). Made once
        per frame; :meth:`process_image`, :meth:`predict` and :meth:`process` take it as it is
        (a :class:`~rs_localizer.camera.FrameTime` given here is returned unchanged: it must be
        this camera's, with this ``stamp_row``).

        Raises:
            ValueError: a stamp that is not a finite number within the int64 nanosecond range
                (:func:`checked_stamp`). TypeError: ``camera`` is not a
                :class:`~rs_localizer.camera.CameraModel`.
        """
        if isinstance(stamp_ns, FrameTime):
            check_camera(camera)
            return stamp_ns
        stamp = checked_stamp(stamp_ns)
        check_camera(camera)
        return self._frame_time(stamp, camera)

    def _frame_time(self, stamp: Stamp, camera: CameraModel) -> FrameTime:
        """:meth:`frame_time` of a checked ``stamp`` seen by a checked ``camera``: its rig of
        one's (:meth:`LocalizerSettings.reference_ns
        <rs_localizer.tracking.video.LocalizerSettings.reference_ns>`)."""
        return FrameTime(stamp, self._rig.settings.reference_ns(_CAMERA, stamp, camera))

    def check_time(self, stamp_ns: int) -> str | None:
        """Note a frame's stamp (ns). A stamp older than the previous frame's, or newer by more
        than ``time_reset_ns``, is a time reset: returns why (else None), and the gyro's
        timeline starts again: on a stamp going back the samples buffered so far (the old
        timeline's) are dropped, on a jump forward those older than the previous frame; the
        bias estimator's and the gyro check's pairing restart. (The tracker resets itself on
        the same stamps.) :meth:`process` (an image: :meth:`process_image`) calls it; called
        first for the frame's stamp (to act on a reset before the frame is decoded), the frame
        takes it as noted: a frame is noted once
        (:meth:`Localizer.check_time <rs_localizer.tracking.video.Localizer.check_time>`), and
        after a time reset noted here the frame's image is not compared with the last one, as
        when :meth:`process_image` notes it (:attr:`SequenceSettings.frozen_image_level`).

        Raises:
            ValueError: a stamp beyond the int64 nanosecond range (:func:`checked_stamp`).
        """
        return self._rig.check_time(stamp_ns)

    # ---------------------------------------------------------------- images
    @property
    def frontend(self) -> VideoFrontend | None:
        """The image front end of :meth:`process_image` (None: none)."""
        return self._camera_frontend.frontend

    @property
    def frontend_name(self) -> str:
        """The front end's name in warnings and errors (e.g. ``aruco``)."""
        return self._camera_frontend.label

    @frontend_name.setter
    def frontend_name(self, name: str) -> None:
        self._camera_frontend.label = name

    def set_frontend(
        self, frontend: Frontend | VideoFrontend | None, name: str | None = None
    ) -> None:
        """Use ``frontend`` for the images from the next one on (None: none): a
        :class:`~rs_localizer.correspondences.VideoFrontend` as it is, a per-image
        :class:`~rs_localizer.correspondences.Frontend` wrapped
        (:func:`~rs_localizer.correspondences.video_frontend`); ``name``: its name in
        warnings and errors (None: unchanged).

        Raises:
            TypeError: an object without ``process``.
        """
        self._camera_frontend.set(frontend, name)

    def process_image(
        self,
        stamp_ns: int | FrameTime,
        image: np.ndarray,
        camera: CameraModel,
        encoding: str = "bgr8",
        tag: object = None,
    ) -> SequenceOutput:
        """Localize one image of the video: the front end's correspondences
        (``frontend.process(image, camera, encoding, prediction)``, with the frame's
        :meth:`predict`; its one-time warning logged), the rows the estimator can use
        (:func:`~rs_localizer.tracking.localizer.usable_rows`, counted by ``count``), solved as
        :meth:`process` solves a frame, then the front end told how the frame was solved
        (``frontend.observe`` with its estimate, a
        :class:`~rs_localizer.correspondences.FrameFeedback`; an error there is logged, the
        frame goes on). The calls are those of
        :class:`~rs_localizer.correspondences.VideoFrontend`. Its rig of one's
        (:meth:`Localizer.process_image
        <rs_localizer.tracking.video.Localizer.process_image>`, as a rig camera's image), made
        the camera's output by :meth:`image_output`.

        Args:
            stamp_ns: the capture time (ns, camera clock) of row ``stamp_row``, or the frame's
                :meth:`frame_time` (taken as it is).
            image: (H, W) or (H, W, C) uint8 in ``encoding`` (``bgr8``, ``rgb8``, ``mono8``,
                ...).
            camera: the frame's :class:`~rs_localizer.camera.CameraModel` with its
                rolling-shutter timing.
            tag: as :attr:`~rs_localizer.tracking.localizer.CameraFrame.tag`.

        Returns:
            :class:`SequenceOutput`; a frame dropped before the estimator has ``failure``
            (``frontend_error``, ``frontend_too_few_points``, ``frozen_image``: the previous
            image again, see :attr:`SequenceSettings.frozen_image_level`; the next new image
            starts a new track, :meth:`Localizer.restart_track
            <rs_localizer.tracking.video.Localizer.restart_track>`) and ``detail``.

        Raises:
            ValueError: no front end (:meth:`set_frontend`), or a stamp beyond the int64
                nanosecond range (:func:`checked_stamp`). TypeError: ``camera`` is not a
                :class:`~rs_localizer.camera.CameraModel`.
        """
        t = self.frame_time(stamp_ns, camera)
        if self._camera_frontend.frontend is None:
            raise ValueError("process_image needs a front end (set_frontend)")
        outs = self._rig.process_image(_CAMERA, t, image, camera, encoding, tag)
        return self.image_output(t, outs)

    def image_output(self, frame_time: FrameTime, outs: list[LocalizerOutput]) -> SequenceOutput:
        """The camera's output (:class:`SequenceOutput`) of its image with times
        ``frame_time`` given to its rig of one
        (:meth:`~rs_localizer.tracking.video.Localizer.process_image`, which returned ``outs``):
        the rig frame as :meth:`output_of` gives it, with the front end's correspondences,
        seconds and the rows given to the estimator; an image skipped before the estimator
        (no rig frame) as its ``failure`` with a ``detail`` text, stamped with its reference
        time."""
        r = self._rig.last_search(_CAMERA)
        if outs:
            (rig_frame,) = outs
            res = self.output_of(rig_frame)
            res.correspondences, res.frontend_seconds = r.found, r.seconds
            res.points2d, res.points3d = r.points2d, r.points3d
            return res
        out = SequenceOutput(stamp_ns=frame_time.reference_ns, failure=r.failure)
        if r.failure == FRONTEND_FAILURES[2]:
            out.detail = (
                f"the image is the previous one again (mean difference {r.difference:.2f} gray "
                "levels over one pixel in 64): a driver re-sending its last frame or a stalled "
                "camera; the next new image is searched whole"
            )
            return out
        name = self._camera_frontend.label
        if r.failure == FRONTEND_FAILURES[0]:
            out.detail = f"{name}: {type(r.error).__name__}: {r.error}"
            return out
        out.correspondences, out.frontend_seconds = r.found, r.seconds
        n = len(r.found.points2d)
        what = f"{n // 4} markers" if name == "aruco" else f"{n} matches"
        out.detail = f"{name} front end found {what}: {n} correspondences, {r.need} needed"
        return out

    def predict(self, stamp_ns: int | FrameTime, camera: CameraModel) -> RSModel | None:
        """The prediction of a frame at ``stamp_ns`` (ns, header stamp: the capture time of
        row ``stamp_row``) seen by ``camera``: its model (:class:`~rs_localizer.pose.RSModel`
        ``(R, C, w, t)``, at the reference row's capture time) before it is estimated, what
        :meth:`process_image` hands the front end to search with. While the tracker tracks
        with this camera and configuration, its prediction
        (:meth:`~rs_localizer.tracking.tracker.RSTracker.predict`: the model the estimator
        then tests first); else (tracking off, no tracker state)
        the last solved frame carried to the stamp at its own twist
        (:class:`~rs_localizer.tracking.tracker.CarriedPrediction`). None when nothing
        predicts the frame: no frame solved yet, or it starts a new track (a stamp going back
        or repeated, more than :attr:`SequenceSettings.max_gap` after the last solved
        frame: :func:`~rs_localizer.tracking.tracker.predictable`; or the first image after a
        ``frozen_image``). The rig of one's
        (:meth:`~rs_localizer.tracking.video.Localizer.predict_camera`).

        ``stamp_ns`` may be the frame's :meth:`frame_time` (taken as it is).

        Raises:
            ValueError: a stamp beyond the int64 nanosecond range (:func:`checked_stamp`).
            TypeError: ``camera`` is not a :class:`~rs_localizer.camera.CameraModel`.
        """
        t = self.frame_time(stamp_ns, camera)
        return self._rig.predict_camera(_CAMERA, t.stamp_ns, camera, reference_ns=t.reference_ns)

    # ---------------------------------------------------------------- frames
    def process(self, frame: CameraFrame, frame_time: FrameTime | None = None) -> SequenceOutput:
        """Estimate one frame (its gyro measurement from the buffered samples, the tracker's
        prediction), update the gyro bias and check, and hand out the fused twists that became
        final. ``frame_time``: the frame's :meth:`frame_time` when the caller made it (None: made
        here). Never raises for a frame the estimator rejects (``estimate.success`` false,
        with ``estimate.failure``) or raises on (``error``).

        Raises:
            ValueError: a ``time`` of another stamp than the frame's. TypeError: a frame
                without a camera model (``camera`` None).
        """
        check_camera(frame.camera)
        ft = frame_time
        if ft is None:  # (the frame's stamp: checked, a CameraFrame's)
            ft = self._frame_time(frame.stamp_ns, frame.camera)
        elif ft.stamp_ns != frame.stamp_ns:
            raise ValueError(
                f"frame time of stamp {ft.stamp_ns} ns given for a frame of {frame.stamp_ns} ns"
            )
        return self._process(frame, ft)

    def _process(self, frame: CameraFrame, ft: FrameTime) -> SequenceOutput:
        """:meth:`process` of a frame with its times ``ft``: its rig of one's rig frame
        (:meth:`~rs_localizer.tracking.video.Localizer.add`) as the camera's output."""
        if frame.camera_name != _CAMERA:
            frame = replace(frame, camera_name=_CAMERA)
        (r,) = self._rig.add(frame, ft.reference_ns)
        return self.output_of(r)

    @property
    def rig(self) -> Localizer:
        """The camera's rig of one (:func:`rig_of_one`: the camera named ``""`` at the
        identity mounting), whose :meth:`~rs_localizer.tracking.video.Localizer.add` solves
        its frames: a caller that takes the camera's frames as it takes a rig camera's may
        hand a frame of the camera (a
        :class:`~rs_localizer.tracking.localizer.CameraFrame` named ``""``, with its camera
        model) to it directly, the rig frame it gives made the camera's output by
        :meth:`output_of`, as :meth:`process` gives it."""
        return self._rig

    @staticmethod
    def output_of(r: LocalizerOutput) -> SequenceOutput:
        """The camera's output (:class:`SequenceOutput`) of its rig of one's rig frame ``r``
        (a :class:`~rs_localizer.tracking.video.LocalizerOutput`): the camera's own estimate
        (its ``camera_estimate``), its path, fused twists, gyro measurement, error, implementation,
        whether its own twist is final and the gyro's time."""
        return SequenceOutput(
            stamp_ns=r.stamp_ns,
            estimate=r.camera_estimate,
            path=r.path,
            fused=r.fused,
            gyro=r.gyro,
            error=r.error,
            compiled=r.compiled,
            twist_now=r.twist_now,
            new_track=r.path in ("cold", "reset"),
            gyro_seconds=r.gyro_seconds,
        )

    # ---------------------------------------------------------------- the video
    def flush(self) -> list[FusedPose]:
        """The end of the video: the twists still pending, as they are now (the track goes
        on)."""
        return self._rig.flush()

    def flush_idle(self, now: float | None = None) -> list[FusedPose]:
        """After ``tracking.max_gap`` s (wall clock, ``time.monotonic``; ``now`` to override)
        without frames the track is over (the next frame more than ``max_gap`` later resets
        it): the twists still pending, final now. Empty without tracking, with nothing
        pending, or before that time."""
        return self._rig.flush_idle(now)

    def end_track(self) -> None:
        """End the track (e.g. the node is deactivated): the twists still pending are dropped;
        the next frame starts a new track and is not predicted. The gyro state is kept."""
        self._rig.end_track()

    def reset(self) -> None:
        """Forget the video (the configuration stays): the track and the twists pending, the
        gyro samples, the bias estimator's and the gyro check's pairing, the last posed frame
        carried (the next frame is not predicted from it), the last stamp, the last image. The
        bias estimate itself is kept (the same IMU)."""
        self._rig.reset()
        self._camera_frontend.last_sample = None
