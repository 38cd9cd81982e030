"""A body's gyro input: the one component a camera's and a rig's video take their gyro from.

:class:`GyroInput` owns, for one IMU on one body (a camera, whose frame is its optical frame,
or a rig, whose frame is the rig frame):

- the samples (:class:`~rs_localizer.tracking.gyro.ImuBuffer`, fed by :meth:`GyroInput.add`);
- the online gyro-bias estimate (:class:`~rs_localizer.tracking.gyro_bias.GyroBiasEstimator`,
  with ``estimate_bias``);
- the check of the IMU's mounting against the rotation between posed frames
  (:class:`~rs_localizer.tracking.gyro_check.GyroMountCheck`): while it declares the gyro
  inconsistent, frames are solved without it;
- a frame's gyro measurement over its capture times (:meth:`GyroInput.measurement`, waiting up
  to ``wait`` for the samples) and the update of the check and the bias with a posed frame
  (:meth:`GyroInput.update`);
- a new timeline (:meth:`GyroInput.restart`) when the frames' clock is reset
  (:mod:`rs_localizer.tracking.clock`).

- what a frame's estimate says of the gyro (:meth:`GyroInput.solved`), one rule for a camera
  and a rig.

Counted through the owner's ``count(key, n)``: ``gyro_missing`` and
``gyro_missing.<reason>`` (:data:`~rs_localizer.tracking.gyro.GYRO_MISSING_REASONS`),
``gyro_disabled_inconsistent``, ``gyro_pairs_failed``, ``gyro_inconsistent_detections``,
``gyro_bias_rejected``, ``gyro_rejected`` and ``gyro_rejected.<reason>``
(:data:`~rs_localizer.estimation.result.GYRO_REJECTIONS`), ``frames_with_gyro`` (a rig:
``gyro_used``; a rig prefixes them all with ``rig.``).
:class:`~rs_localizer.tracking.sequence.SequenceLocalizer` and
:class:`~rs_localizer.tracking.video.Localizer` both use it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike

from ..camera import checked_stamp
from ..estimation.gyro import GyroMeasurement
from ..estimation.result import RSPoseEstimate
from .gyro import ImuBuffer
from .gyro_bias import GyroBiasEstimator, GyroBiasOptions
from .gyro_check import GyroMountCheck, MountCheckOptions

__all__ = [
    "GyroInput",
    "GyroReadouts",
    "GyroSettings",
    "SilentLog",
    "TrackLog",
    "gyro_calibration",
    "gyro_if_consistent",
    "update_gyro_checks",
]


@dataclass(frozen=True)
class GyroSettings:
    """How the gyro is used (the node's ``imu.*`` parameters:
    :func:`rs_localizer.tracking.settings.gyro_settings` builds it from their values).

    Attributes:
        R_cam_imu: (3, 3) rotation IMU -> camera optical frame (on a rig: IMU -> rig frame).
        time_offset: s added to the IMU stamps to get camera time.
        gyro_noise: rad/s, standard deviation of one sample.
        gyro_bias: (3,) rad/s, IMU frame; gyro_bias_sigma: its standard deviation per axis.
        estimate_bias: estimate the bias online (from ``gyro_bias`` with ``gyro_bias_sigma``);
            bias_random_walk: rad/s per sqrt(s), how fast it may drift.
        wait: s a frame waits for the samples covering its readout (0: none, e.g. offline).
        buffer: s of samples kept. max_rate: rad/s, the saturation (rejected beyond).
        max_gap: s between samples beyond which a readout is ``sparse``.
    """

    R_cam_imu: np.ndarray = field(default_factory=lambda: np.eye(3))
    time_offset: float = 0.0
    gyro_noise: float = 0.005
    gyro_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gyro_bias_sigma: float = 0.01
    wait: float = 0.0
    buffer: float = 2.0
    max_rate: float = 35.0
    max_gap: float = 0.02
    estimate_bias: bool = False
    bias_random_walk: float = 1e-4


def gyro_calibration(imu: GyroSettings) -> tuple:
    """The gyro calibration values of ``imu`` (mounting, time offset, noise, bias and its
    sigma) as a comparable tuple: the gyro-bias estimate and the mount check are started again
    when they change at run time."""
    return (
        tuple(np.round(imu.R_cam_imu, 12).ravel()),
        imu.time_offset,
        imu.gyro_noise,
        tuple(imu.gyro_bias),
        imu.gyro_bias_sigma,
    )


class TrackLog(Protocol):
    """What a video's trackers log through: ``info(text)`` and ``warning(key, text, count)``
    (``key`` names the warning for throttling, ``count`` how often it happened; the node's
    :class:`~rs_localizer.ros.pipeline.ThrottledLog`)."""

    def info(self, text: str) -> None: ...

    def warning(self, key: str, text: str, count: int = 0) -> None: ...


class SilentLog:
    """A :class:`TrackLog` that logs nothing (a tracker given no log)."""

    def info(self, text: str) -> None:
        pass

    def warning(self, key: str, text: str, count: int = 0) -> None:
        pass


def gyro_if_consistent(
    gyro: GyroMeasurement | None, check: GyroMountCheck | None, count: Callable[[str, int], None]
) -> GyroMeasurement | None:
    """``gyro`` (a frame's gyro measurement, or None), or None while ``check`` declares the
    gyro inconsistent with the image (counted ``gyro_disabled_inconsistent``): the frame is
    then solved without it. The single camera's
    (:class:`~rs_localizer.tracking.sequence.SequenceLocalizer`) and the rig's
    (:class:`~rs_localizer.tracking.video.Localizer`) rule."""
    if gyro is not None and check is not None and check.inconsistent:
        count("gyro_disabled_inconsistent", 1)
        return None
    return gyro


def update_gyro_checks(
    check: GyroMountCheck | None,
    bias: GyroBiasEstimator | None,
    buffer: ImuBuffer | None,
    imu: GyroSettings | None,
    *,
    stamp_ns: int,
    success: bool,
    orientation: ArrayLike | None,
    rotation_covariance: ArrayLike | None,
    new_track: bool,
    count: Callable[[str, int], None],
    log: TrackLog,
    what: str = "frames",
    mount: str = "IMU -> camera optical frame",
) -> None:
    """Feed a frame (a camera's, or a rig's) to the check of the gyro against the image and to
    the online bias estimator, as the single camera and the rig both do: a solved frame pairs
    with the previous one; a failed frame or a new track restarts the pairing. A pair the
    check fails is counted ``gyro_pairs_failed``; when the check declares the gyro
    inconsistent it is counted ``gyro_inconsistent_detections`` and warned about once (and
    when it agrees again), and the bias estimator gets no pairs until it is consistent again
    (a wrong mount would pull the bias). A pair the bias estimator's chi-square test rejects
    is counted ``gyro_bias_rejected``.

    Args:
        check: the :class:`~rs_localizer.tracking.gyro_check.GyroMountCheck` (None: none).
            bias: the :class:`~rs_localizer.tracking.gyro_bias.GyroBiasEstimator` (None: none).
        buffer: the gyro samples (None: no gyro, nothing done).
        imu: the :class:`GyroSettings` (``gyro_bias`` (3,) rad/s and ``gyro_bias_sigma`` rad/s:
            the bias the check assumes without an online estimate; None only with no
            ``buffer``).
        stamp_ns: the frame's time (ns, the camera clock). success: it was posed.
        orientation: (3, 3) body -> world at that time (the camera's, or the rig's);
            rotation_covariance: (3, 3) rad^2, world axes (None: NaN, the pair is not tested).
        new_track: the frame starts a new track (nothing pairs across it).
        count: ``count(key, n)`` of the counters above. log: the :class:`TrackLog` of the
            warnings.
        what, mount: the warning's words for the frames (``frames``, ``rig frames``) and the
            mounting under test (``IMU -> camera optical frame``, ``IMU -> base_frame``).
    """
    if buffer is None or (check is None and bias is None):
        return
    if new_track or not success:
        if check is not None:
            check.restart()
        if bias is not None:
            bias.restart()
    if not success:
        return
    cov = np.full((3, 3), np.nan) if rotation_covariance is None else rotation_covariance
    if check is not None:
        if bias is not None:
            b, Pb = bias.bias, bias.covariance
        else:
            b, Pb = np.asarray(imu.gyro_bias, float), imu.gyro_bias_sigma**2 * np.eye(3)
        was = check.inconsistent
        if check.update(stamp_ns, orientation, cov, buffer, b, Pb) == "failed":
            count("gyro_pairs_failed", 1)
        if check.inconsistent and not was:
            count("gyro_inconsistent_detections", 1)
            n_failed, n_pairs = check.window_failures
            log.warning(
                "gyro.inconsistent",
                f"the rotation between {what} contradicts the gyro ({n_failed} of the last "
                f"{n_pairs} pairs, last residual {check.last_residual_deg:.2f} deg): {what} "
                f"are solved without the gyro until it agrees again; check imu.rotation "
                f"({mount}), imu.time_offset and imu.gyro_bias",
            )
        elif was and not check.inconsistent:
            log.info(f"the gyro agrees with the image again: {what} use it")
    if bias is None:
        return
    if check is not None and check.inconsistent:
        bias.restart()
        return
    if bias.update(stamp_ns, orientation, cov, buffer) == "rejected":
        count("gyro_bias_rejected", 1)


class GyroInput:
    """One IMU's gyro on one body (module docstring). Starts without a gyro: :meth:`configure`.

    Args:
        count: ``count(key, n)`` of the counters (module docstring).
        log: the :class:`TrackLog` of the warnings (None: silent).
        stopped: ``stopped()`` true ends a frame's wait for its samples (shutdown).
        span: s of samples kept (None: the settings' ``buffer``; ``inf`` when every sample is
            added before the frames, e.g. a bag replayed offline).
        what: the frames' name in warnings (``frame``, ``rig frame``); key: the prefix of the
            warnings' keys (``gyro``, ``rig.gyro``); mount: the mounting under test in them
            (``IMU -> camera optical frame``, ``IMU -> base_frame``); used_key: the count of
            the frames posed with the gyro (``frames_with_gyro``, a rig's ``gyro_used``).

    Attributes:
        settings: the :class:`GyroSettings`, None: no gyro. buffer: the samples (None
            without a gyro). bias: the online bias estimate (None without ``estimate_bias``).
            check: the mount check (None without a gyro or when not checked).

    Threads: :meth:`add` from one thread while a frame's :meth:`measurement` runs on another;
    :meth:`restart` and :meth:`configure` under the owner's frame lock.
    """

    def __init__(
        self,
        count: Callable[[str, int], None],
        log: TrackLog | None = None,
        *,
        stopped: Callable[[], bool] = lambda: False,
        span: float | None = None,
        what: str = "frame",
        key: str = "gyro",
        mount: str = "IMU -> camera optical frame",
        used_key: str = "frames_with_gyro",
    ):
        self._count = count
        self.log: TrackLog = log if log is not None else SilentLog()
        self._stopped = stopped
        self._span = span
        self.what, self.key, self.mount, self.used_key = what, key, mount, used_key
        self.settings: GyroSettings | None = None
        self.buffer: ImuBuffer | None = None
        self.bias: GyroBiasEstimator | None = None
        self.check: GyroMountCheck | None = None
        self._bias_key = self._check_key = None

    # ---------------------------------------------------------------- configuration
    def configure(
        self, imu: GyroSettings | None, *, check: bool = True, max_interval: float = 0.5
    ) -> None:
        """Use the gyro settings ``imu`` (None: no gyro) from the next frame on. The samples
        are kept (a new buffer when ``max_rate`` or ``max_gap`` changed, the samples copied);
        the bias estimate and the mount check (``check``) are kept while the gyro calibration
        (:func:`gyro_calibration`) and ``max_interval`` (s: no pair of frames further apart,
        the video's gap) stay the same, else started again."""
        self.settings = imu
        if imu is None:
            self.buffer = None
        elif self.buffer is None or (self.buffer.max_rate, self.buffer.max_gap_ns) != (
            imu.max_rate,
            int(imu.max_gap * 1e9),
        ):
            old, self.buffer = self.buffer, self._new_buffer()
            if old is not None:  # (keep the samples received so far)
                for t, w in old.samples():
                    self.buffer.add(t, w)
        self._configure_bias(imu, max_interval)
        self._configure_check(imu if check else None, max_interval)

    def _new_buffer(self) -> ImuBuffer:
        imu = self.settings
        span = imu.buffer if self._span is None else self._span
        return ImuBuffer(span, imu.max_rate, imu.max_gap)

    def _configure_bias(self, imu: GyroSettings | None, gap: float) -> None:
        if imu is None or not imu.estimate_bias:
            self.bias = self._bias_key = None
            return
        key = (*gyro_calibration(imu), imu.bias_random_walk, gap)
        if self.bias is None or key != self._bias_key:
            self.bias = GyroBiasEstimator(
                imu.gyro_bias,
                imu.gyro_bias_sigma,
                imu.R_cam_imu,
                imu.gyro_noise,
                imu.time_offset,
                GyroBiasOptions(random_walk=imu.bias_random_walk, max_interval=gap),
            )
            self._bias_key = key

    def _configure_check(self, imu: GyroSettings | None, gap: float) -> None:
        if imu is None:
            self.check = self._check_key = None
            return
        key = (*gyro_calibration(imu), imu.estimate_bias, gap)
        if self.check is None or key != self._check_key:
            self.check = GyroMountCheck(
                imu.R_cam_imu,
                imu.gyro_noise,
                imu.time_offset,
                MountCheckOptions(max_interval=gap),
            )
            self._check_key = key

    # ---------------------------------------------------------------- read-outs
    @property
    def inconsistent(self) -> bool:
        """True while the rotation between posed frames contradicts the gyro and frames are
        solved without it (:class:`~rs_localizer.tracking.gyro_check.GyroMountCheck`)."""
        check = self.check
        return check is not None and check.inconsistent

    def bias_values(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The gyro bias the frames use and its standard deviation per axis ((3,), (3,) rad/s,
        IMU frame): the online estimate with ``estimate_bias``, else the settings'
        ``gyro_bias`` and ``gyro_bias_sigma``; None without a gyro."""
        imu = self.settings
        if imu is None:
            return None
        est = self.bias
        if est is not None:
            return est.bias.copy(), est.std
        return np.array(imu.gyro_bias, dtype=float), np.full(3, float(imu.gyro_bias_sigma))

    # ---------------------------------------------------------------- samples and frames
    def add(self, stamp_ns: int, rate: ArrayLike) -> str | None:
        """Buffer a gyro sample (``stamp_ns`` IMU clock, ``rate`` (3,) rad/s, IMU frame).
        Returns None, or why it was rejected: ``disabled`` (no gyro) or the reasons of
        :meth:`~rs_localizer.tracking.gyro.ImuBuffer.add` (a stamp going back or repeated,
        NaN or saturated rates).

        Raises:
            ValueError: a stamp that is not a finite number within the int64 nanosecond
                range (:func:`~rs_localizer.camera.checked_stamp`).
        """
        stamp = checked_stamp(stamp_ns, "IMU")
        buf = self.buffer
        if buf is None:
            return "disabled"
        return buf.add(stamp, rate)

    def measurement(self, window_ns: tuple[int, int]) -> GyroMeasurement | None:
        """The gyro measurement over a frame's capture times ``window_ns`` (its first and last
        line, ns, camera clock; in the body frame through ``R_cam_imu``), waiting up to
        ``wait`` s for the samples covering it; with the online bias and its covariance when
        estimated. None without a gyro, without the samples (``gyro_missing.<reason>``
        counted and warned about), or while the mount check declares the gyro inconsistent
        (``gyro_disabled_inconsistent``): the frame is then solved without it."""
        imu, buf = self.settings, self.buffer
        if imu is None or buf is None:
            return None
        first, last = window_ns
        off = int(round(imu.time_offset * 1e9))
        buf.wait_until(last - off, imu.wait, self._stopped)
        if self.bias is not None:  # (the online estimate and its covariance)
            gyro, reason = self.bias.measurement(buf, (first, last))
        else:
            gyro, reason = buf.measurement(
                (first, last),
                imu.R_cam_imu,
                imu.gyro_bias,
                imu.gyro_noise,
                imu.gyro_bias_sigma,
                imu.time_offset,
            )
        if gyro is None:
            self._without(
                "gyro_missing", reason, f"{self.key}.{reason}",
                f"{self.what} solved without the gyro ({reason}): check the imu topic, its "
                "rate and imu.time_offset",
            )  # fmt: skip
        # (the image refutes the gyro over the last pairs: solved without it)
        return gyro_if_consistent(gyro, self.check, self._count)

    def _without(self, kind: str, reason: str, key: str, text: str) -> None:
        """A frame solved without the gyro: counted ``kind`` and ``kind.<reason>``, warned
        about (``key``, throttled)."""
        self._count(kind, 1)
        self._count(f"{kind}.{reason}", 1)
        self.log.warning(key, text)

    def solved(self, stamp_ns: int, estimate: RSPoseEstimate | None, new_track: bool) -> None:
        """A frame (a camera's or a rig's) after its estimate: the one rule of both.

        Counted: ``<used>`` (``frames_with_gyro``; a rig's ``gyro_used``) when it was posed
        with the gyro's measurement, ``gyro_rejected`` and ``gyro_rejected.<reason>`` (the
        estimate's ``gyro_rejection``) when the image contradicted the gyro (warned about,
        throttled: the frame was solved without it); then the mount check and the bias
        estimate fed with it (:meth:`update`): a posed frame (its orientation, body ->
        world, and the (3, 3) rotation block of its (12, 12) ``covariance``, None when it
        has none: the pair is not tested) pairs with the previous one; a failed frame, a
        frame whose estimator raised (``estimate`` None) or a new track (``new_track``)
        restarts the pairing."""
        posed = estimate is not None and bool(estimate.success)
        if estimate is not None and estimate.gyro_rejected:
            self._without(
                "gyro_rejected", estimate.gyro_rejection, f"{self.key}.rejected",
                f"the image disagrees with the gyro: {self.what} solved without it (check "
                "imu.rotation, imu.time_offset and imu.gyro_bias)",
            )  # fmt: skip
        elif posed and estimate.gyro_used:
            self._count(self.used_key, 1)
        cov = None
        if posed and estimate.covariance is not None:
            cov = estimate.covariance[:3, :3]
        orientation = estimate.pose.orientation if posed else None
        self.update(stamp_ns, posed, orientation, cov, new_track)

    def update(
        self,
        stamp_ns: int,
        success: bool,
        orientation: ArrayLike | None,
        rotation_covariance: ArrayLike | None,
        new_track: bool,
    ) -> None:
        """Feed a frame to the mount check and the bias estimator
        (:func:`update_gyro_checks`): a posed frame
        (``orientation`` (3, 3) body -> world at ``stamp_ns``, ``rotation_covariance`` (3, 3)
        rad^2 or None) pairs with the previous one; a failed frame or a new track restarts
        the pairing."""
        update_gyro_checks(
            self.check,
            self.bias,
            self.buffer,
            self.settings,
            stamp_ns=stamp_ns,
            success=success,
            orientation=orientation,
            rotation_covariance=rotation_covariance,
            new_track=new_track,
            count=self._count,
            log=self.log,
            what=f"{self.what}s",
            mount=self.mount,
        )

    def restart(self, keep_from: int | None) -> None:
        """A new timeline (:mod:`rs_localizer.tracking.clock`): the samples stamped before
        ``keep_from`` (ns; None: all) dropped, the pairing of the bias estimator and of the
        mount check restarted (the bias estimate itself is kept: the same IMU)."""
        if self.buffer is not None:
            old, self.buffer = self.buffer, self._new_buffer()
            if keep_from is not None:
                for t, w in old.samples():
                    if t >= keep_from:
                        self.buffer.add(t, w)
        if self.check is not None:
            self.check.restart()
        if self.bias is not None:
            self.bias.restart()


class GyroReadouts:
    """The gyro read-outs a localizer offers, one camera's or a rig's
    (:class:`~rs_localizer.tracking.sequence.SequenceLocalizer`,
    :class:`~rs_localizer.tracking.video.Localizer`): views of its :class:`GyroInput`
    (attribute ``gyro_input``)."""

    gyro_input: GyroInput

    def add_imu(self, stamp_ns: int, rate: ArrayLike) -> str | None:
        """Buffer a gyro sample (``stamp_ns`` IMU clock, ``rate`` (3,) rad/s, IMU frame).
        Returns None, or why it was rejected: ``disabled`` (no gyro in the settings) or the
        reasons of :meth:`~rs_localizer.tracking.gyro.ImuBuffer.add` (a stamp going back or
        repeated, NaN or saturated rates).

        Raises:
            ValueError: a stamp that is not a finite number within the int64 nanosecond
                range (:func:`~rs_localizer.camera.checked_stamp`).
        """
        return self.gyro_input.add(stamp_ns, rate)

    @property
    def imu(self) -> ImuBuffer | None:
        """The gyro samples (:attr:`GyroInput.buffer`), None without a gyro."""
        return self.gyro_input.buffer

    @property
    def gyro_bias(self) -> GyroBiasEstimator | None:
        """The online gyro-bias estimate (``imu.estimate_bias``), else None."""
        return self.gyro_input.bias

    @property
    def gyro_check(self) -> GyroMountCheck | None:
        """The check of the gyro's mounting against the rotation between solved frames (a
        camera's or the rig's), else None."""
        return self.gyro_input.check

    @property
    def gyro_inconsistent(self) -> bool:
        """True while the rotation between solved frames contradicts the gyro (its
        ``imu.rotation``, time offset or bias likely wrong) and frames are solved without it
        (:class:`GyroMountCheck`)."""
        return self.gyro_input.inconsistent

    def gyro_bias_values(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The gyro bias the frames use and its standard deviation per axis ((3,), (3,) rad/s,
        IMU frame): the online estimate with ``estimate_bias``, else the settings'
        ``gyro_bias`` and ``gyro_bias_sigma``; None without a gyro
        (:meth:`GyroInput.bias_values`)."""
        return self.gyro_input.bias_values()
