"""A video's gyro samples and the gyro measurement of each frame's readout.

:class:`ImuBuffer` keeps the recent samples of one IMU (thread-safe: the node's IMU callback
adds while a frame waits for the samples covering its readout); :func:`readout_window` gives
the capture times of a frame's first and last line, and :func:`gyro_measurement` turns the
samples of one readout into the mean angular velocity the rolling-shutter model sees over it,
in the camera optical frame with its covariance: the
:class:`~rs_localizer.estimation.gyro.GyroMeasurement` the per-frame estimator takes
(``estimate_rs_pose(..., gyro=...)``).

Conventions: IMU samples are in the IMU frame; ``R_cam_imu`` rotates IMU axes into the camera
optical frame (``omega_cam = R_cam_imu (omega_imu - bias)``); ``time_offset`` is added to IMU
stamps to put them on the camera clock (``t_cam = t_imu + time_offset``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike

from ..camera import CameraModel
from ..estimation.gyro import GyroMeasurement
from ..estimation.prior import checked_symmetric

__all__ = [
    "GYRO_MISSING_REASONS",
    "IMU_JUMP_NS",
    "IMU_NEW_TIMELINE_SAMPLES",
    "IMU_SAMPLE_REJECTIONS",
    "GyroMeasurement",
    "ImuBuffer",
    "gyro_measurement",
    "readout_window",
]


def readout_window(
    camera: CameraModel, stamp: float, stamp_line: float | None = None
) -> tuple[float, float]:
    """Capture times (s) of the first and the last line read out of a frame.

    Args:
        camera: the camera (line delay, readout direction, lines).
        stamp: the frame's stamp (s, camera clock).
        stamp_line: the line (pixel coordinate along the readout axis) whose capture time is
            ``stamp``; ``None``: the camera's reference line (the estimate's time).
    Returns:
        ``(t_first, t_last)`` with ``t_last - t_first = line_delay * (lines - 1)``.
    """
    line = camera.reference_line if stamp_line is None else float(stamp_line)
    t0 = float(stamp) - float(camera.line_time(line))
    return t0, t0 + camera.line_delay * (camera.lines - 1)


def gyro_measurement(
    stamps: ArrayLike,
    rates: ArrayLike,
    window: tuple[float, float],
    R_cam_imu: ArrayLike | None = None,
    bias: ArrayLike | None = None,
    noise: float = 0.003,
    bias_sigma: float = 0.0,
    time_offset: float = 0.0,
    bias_covariance: ArrayLike | None = None,
) -> GyroMeasurement:
    """The angular velocity the rolling-shutter model sees during a readout, from gyro samples.

    The RS model turns at a constant rate during the readout (paper eq. 2); on a rotation that
    accelerates, its best fit is the least-squares slope of the rotation angle over the
    readout window ``[m - h, m + h]``, i.e. the rate weighted by ``3 (h^2 - (t - m)^2) /
    (4 h^3)`` (integrating ``t theta(t)`` by parts). For a rate linear in time that is the
    mean rate (the rate at the window's middle); with a jerk ``j`` it is ``omega(m) + j
    h^2 / 10``, where the mean would be ``omega(m) + j h^2 / 6``. The rate between samples is
    linearly interpolated (the weighted integral is then exact by Simpson's rule); for a
    zero-length window (a global-shutter camera) the measurement is the rate at that instant.
    It is rotated into the camera optical frame after subtracting the bias. The covariance is
    ``noise^2 sum(c_i^2) I + bias_sigma^2 I + R bias_covariance R^T`` with ``c`` the samples'
    weights in the measurement (independent sample noise averages down; the bias does not).

    Args:
        stamps: (M,) IMU sample times (s, IMU clock), strictly increasing, M >= 2.
        rates: (M, 3) angular rates (rad/s, IMU frame).
        window: ``(t_first, t_last)`` capture times of the first and last line (s, camera
            clock; :func:`readout_window`).
        R_cam_imu: (3, 3) rotation IMU -> camera optical frame (default identity).
        bias: (3,) gyro bias (rad/s, IMU frame) subtracted from the rates (default zero).
        noise: standard deviation of one sample (rad/s), > 0.
        bias_sigma: standard deviation of the bias error per axis (rad/s), >= 0.
        time_offset: added to the IMU stamps to put them on the camera clock (s).
        bias_covariance: (3, 3) covariance of the bias error (rad^2/s^2, IMU frame; e.g. of an
            online estimate, :class:`~rs_localizer.tracking.gyro_bias.GyroBiasEstimator`),
            added to ``bias_sigma^2 I`` (default none).
    Returns:
        :class:`GyroMeasurement`.
    Raises:
        ValueError: shapes, non-finite values, stamps not strictly increasing, ``noise <= 0``,
            ``bias_sigma < 0``, a window with ``t_last < t_first``, samples that do not
            cover the window, or a ``bias_covariance`` that is not (3, 3) symmetric positive
            semi-definite.
    """
    t = np.asarray(stamps, dtype=float).reshape(-1) + float(time_offset)
    om = np.asarray(rates, dtype=float)
    if om.ndim != 2 or om.shape[1] != 3 or len(om) != len(t) or len(t) < 2:
        raise ValueError(f"gyro needs stamps (M,) and rates (M, 3) with M >= 2, got {om.shape}")
    if not (np.isfinite(t).all() and np.isfinite(om).all()):
        raise ValueError("gyro stamps and rates must be finite")
    if not (np.diff(t) > 0).all():
        raise ValueError("gyro stamps must be strictly increasing")
    if not (np.isfinite(noise) and noise > 0) or not (np.isfinite(bias_sigma) and bias_sigma >= 0):
        raise ValueError(f"gyro noise must be > 0 and bias_sigma >= 0, got {noise}, {bias_sigma}")
    a, b = float(window[0]), float(window[1])
    if not (np.isfinite(a) and np.isfinite(b) and b >= a):
        raise ValueError(f"readout window must be finite with t_last >= t_first, got {window}")
    if a < t[0] or b > t[-1]:
        raise ValueError(
            f"gyro samples [{t[0]:.6f}, {t[-1]:.6f}] s do not cover the readout "
            f"[{a:.6f}, {b:.6f}] s"
        )
    c = _sample_weights(t, a, b)
    rate = c @ om
    if bias is not None:
        rate = rate - np.asarray(bias, dtype=float).reshape(3)
    R = np.eye(3) if R_cam_imu is None else np.asarray(R_cam_imu, dtype=float).reshape(3, 3)
    cov = (noise**2 * float(c @ c) + bias_sigma**2) * np.eye(3)
    if bias_covariance is not None:
        cov = cov + checked_symmetric(bias_covariance, 3, "gyro bias covariance", definite=False)
    return GyroMeasurement(rate, cov, _rate_change(t, om, a, b)).rotated(R)


def _rate_change(t: np.ndarray, om: np.ndarray, a: float, b: float) -> np.ndarray:
    """(3,) the rates' least-squares slope over the samples from the last at or before ``a``
    to the first at or after ``b``, times ``b - a`` (rad/s; zero for a zero-length window)."""
    if b <= a:
        return np.zeros(3)
    i0 = max(int(np.searchsorted(t, a, side="right")) - 1, 0)
    i1 = min(int(np.searchsorted(t, b, side="left")), len(t) - 1)
    ts, ws = t[i0 : i1 + 1], om[i0 : i1 + 1]
    if len(ts) < 2:
        return np.zeros(3)
    dt = ts - ts.mean()
    return (dt @ (ws - ws.mean(axis=0))) / float(dt @ dt) * (b - a)


def _sample_weights(t: np.ndarray, a: float, b: float) -> np.ndarray:
    """(M,) weights ``c`` (summing to 1) of the samples at times ``t`` in the readout's
    measurement over ``[a, b]`` (:func:`gyro_measurement`): the parabolic weight times the
    linear interpolation between samples, integrated by Simpson's rule per segment (exact:
    the product is cubic)."""
    c = np.zeros(len(t))
    k0 = int(np.searchsorted(t, a, side="right")) - 1
    if b <= a:  # (global shutter: the interpolated rate at a)
        k0 = min(max(k0, 0), len(t) - 2)
        u = (a - t[k0]) / (t[k0 + 1] - t[k0])
        c[k0], c[k0 + 1] = 1.0 - u, u
        return c
    m, h = 0.5 * (a + b), 0.5 * (b - a)
    k = max(k0, 0)
    while k < len(t) - 1 and t[k] < b:
        s0, s1 = max(t[k], a), min(t[k + 1], b)
        if s1 > s0:
            ts = np.array([s0, 0.5 * (s0 + s1), s1])
            w = 3.0 * (h * h - (ts - m) ** 2) / (4.0 * h**3)
            u = (ts - t[k]) / (t[k + 1] - t[k])  # the later sample's interpolation weight
            simpson = (s1 - s0) / 6.0 * np.array([1.0, 4.0, 1.0])
            c[k] += simpson @ (w * (1.0 - u))
            c[k + 1] += simpson @ (w * u)
        k += 1
    return c / c.sum()  # (sums to 1 but for rounding)


#: why an IMU sample is not buffered (:meth:`ImuBuffer.add`)
IMU_SAMPLE_REJECTIONS = ("stamp_not_increasing", "stamp_far_from_frames", "non_finite", "saturated")
#: why a frame is solved without the gyro (:meth:`ImuBuffer.measurement`)
GYRO_MISSING_REASONS = ("no_samples", "not_covered", "sparse")
#: a sample more than this after the one before it (ns) is a jump: if the next sample goes
#: back before it, the jump was a lone bad stamp and is dropped (:meth:`ImuBuffer.add`)
IMU_JUMP_NS = 500_000_000
#: this many consecutive samples that go back before the newest one, each after the one before
#: it, are a new timeline (a bag played again, a clock reset): the buffer starts over with them
IMU_NEW_TIMELINE_SAMPLES = 10


class ImuBuffer:
    """The recent gyro samples of one IMU, for the frames' :class:`GyroMeasurement`.

    Samples come in stamp order (a ``sensor_msgs/Imu`` stream); those older than ``span``
    seconds before the newest are dropped. Thread-safe: one thread may :meth:`add` while
    another asks for a :meth:`measurement` (and waits for the samples covering a readout).

    A bad stamp never locks the buffer: once a frame's time is known (:meth:`note_frame`,
    also noted by :meth:`wait_until` and :meth:`measurement`), a sample further than
    ``max_skew`` before it, or after it and after the newest sample, is rejected
    (``stamp_far_from_frames``); a sample that jumped more
    than :data:`IMU_JUMP_NS` ahead of its predecessor and is followed by one before it is
    dropped as a lone bad stamp; :data:`IMU_NEW_TIMELINE_SAMPLES` consecutive increasing samples
    before the newest one start the buffer over (the IMU's clock went back). A time reset of
    the frames calls :meth:`reset`.

    Args:
        span: seconds of samples kept (> 0; ``inf``: all, e.g. a bag replayed offline).
        max_rate: rates with any component beyond this (rad/s) are the sensor's saturation
            and rejected.
        max_gap: a readout whose samples are further apart than this (s) is ``sparse``: an
            IMU at 10 Hz cannot describe the rotation within a 20 ms readout.
        max_skew: s; a sample stamped further than this before the last frame's time (IMU
            clock), or after it and after the newest sample, is rejected (``inf``: no bound).

    Attributes:
        received: samples given to :meth:`add` (since construction).
        accepted: samples buffered (since construction).
        dropped: buffered samples later dropped as a lone bad stamp.
        resets: times the buffer started over (:meth:`reset`, a new timeline).
        last_accepted: ``time.monotonic()`` of the last buffered sample (None before).
    """

    def __init__(
        self,
        span: float = 2.0,
        max_rate: float = 35.0,
        max_gap: float = 0.02,
        max_skew: float = 1.0,
    ):
        if not (span > 0 and max_rate > 0 and max_gap > 0 and max_skew > 0):
            raise ValueError(
                "span, max_rate, max_gap, max_skew must be > 0, got "
                f"{span, max_rate, max_gap, max_skew}"
            )
        self.span_ns = np.inf if not np.isfinite(span) else int(span * 1e9)
        self.max_rate, self.max_gap_ns = float(max_rate), int(max_gap * 1e9)
        self.max_skew_ns = np.inf if not np.isfinite(max_skew) else int(max_skew * 1e9)
        self._t: list[int] = []
        self._w: list[tuple[float, float, float]] = []
        self._cond = threading.Condition()
        self._first: int | None = None
        self._frame_ns: int | None = None
        self._run: list[tuple[int, tuple[float, float, float]]] = []
        self.received = self.accepted = self.dropped = self.resets = 0
        self.last_accepted: float | None = None
        self._created = time.monotonic()

    def idle_seconds(self) -> float:
        """Seconds (monotonic clock) since the last buffered sample, or since the buffer was
        made when none was."""
        with self._cond:
            last = self._created if self.last_accepted is None else self.last_accepted
        return time.monotonic() - last

    def __len__(self) -> int:
        return len(self._t)

    def reset(self) -> None:
        """Forget every sample and the frames' time (a time reset of the frames: a new
        timeline); the counters are kept, :attr:`resets` counts it."""
        with self._cond:
            self._clear()
            self._frame_ns = None

    def _clear(self) -> None:
        self._t.clear()
        self._w.clear()
        self._run.clear()
        self._first = None
        self.resets += 1

    def note_frame(self, stamp_ns: int) -> None:
        """The frames' current time (ns, IMU clock: a frame's stamp minus ``time_offset``;
        the bound of ``max_skew`` is far larger than any offset), against which new samples
        are judged."""
        with self._cond:
            self._frame_ns = int(stamp_ns)

    def add(self, stamp_ns: int, rate: ArrayLike) -> str | None:
        """Buffer one sample: ``stamp_ns`` (IMU clock, ns), ``rate`` (3,) rad/s (IMU frame).
        Returns ``None``, or the reason it was rejected (:data:`IMU_SAMPLE_REJECTIONS`):
        a stamp not after the last one (going back or duplicated), a stamp further than
        ``max_skew`` from the frames' time, a NaN/inf rate, a saturated one (see the class
        docstring for how a bad stamp is recovered from)."""
        w = np.asarray(rate, dtype=float).reshape(3)
        stamp_ns = int(stamp_ns)
        with self._cond:
            self.received += 1
            if not np.isfinite(w).all():
                return "non_finite"
            if np.abs(w).max() > self.max_rate:
                return "saturated"
            if self._far(stamp_ns):
                return "stamp_far_from_frames"
            sample = (float(w[0]), float(w[1]), float(w[2]))
            if self._t and stamp_ns <= self._t[-1]:
                if (
                    len(self._t) >= 2
                    and self._t[-2] < stamp_ns
                    and (self._t[-1] - self._t[-2] > IMU_JUMP_NS)
                ):  # (the newest sample jumped ahead alone: a bad stamp, dropped)
                    del self._t[-1], self._w[-1]
                    self.dropped += 1
                elif not self._new_timeline(stamp_ns, sample):
                    return "stamp_not_increasing"
                else:
                    return None
            self._run.clear()
            self._append(stamp_ns, sample)
        return None

    def _far(self, stamp_ns: int) -> bool:
        """Whether a sample is further than ``max_skew`` behind the frames' time, or ahead of
        it and of the newest sample (a stream that went on while a frame took long to solve
        is not far: it continues from its newest sample)."""
        f = self._frame_ns
        if f is None:
            return False
        if f - stamp_ns > self.max_skew_ns:
            return True
        ahead_of_newest = not self._t or stamp_ns - self._t[-1] > self.max_skew_ns
        return stamp_ns - f > self.max_skew_ns and ahead_of_newest

    def _new_timeline(self, stamp_ns: int, sample: tuple[float, float, float]) -> bool:
        """Collect samples that go back before the newest one; once
        :data:`IMU_NEW_TIMELINE_SAMPLES` in a row increase, start over with them (True)."""
        if self._run and stamp_ns <= self._run[-1][0]:
            self._run.clear()
        self._run.append((stamp_ns, sample))
        if len(self._run) < IMU_NEW_TIMELINE_SAMPLES:
            return False
        run = list(self._run)
        self._clear()
        for t, s in run:
            self._append(t, s)
        return True

    def _append(self, stamp_ns: int, sample: tuple[float, float, float]) -> None:
        self._t.append(stamp_ns)
        self._w.append(sample)
        self.accepted += 1
        self.last_accepted = time.monotonic()
        if self._first is None:
            self._first = stamp_ns
        cut = stamp_ns - self.span_ns
        k = 0  # (samples come in order: the old ones are a short prefix)
        while self._t[k] < cut:
            k += 1
        if k:
            del self._t[:k], self._w[:k]
        self._cond.notify_all()

    def samples(self) -> list[tuple[int, tuple[float, float, float]]]:
        """A copy of the buffered samples: ``(stamp_ns, (wx, wy, wz))``, oldest first."""
        with self._cond:
            return list(zip(self._t, self._w, strict=True))

    def rate_hz(self) -> float:
        """The mean sample rate of the buffered samples (Hz; 0 with fewer than two)."""
        with self._cond:
            if len(self._t) < 2:
                return 0.0
            return (len(self._t) - 1) / ((self._t[-1] - self._t[0]) * 1e-9)

    def wait_until(
        self, stamp_ns: int, timeout: float, stopped: Callable[[], bool] = lambda: False
    ) -> bool:
        """Wait up to ``timeout`` s for a sample at or after ``stamp_ns`` (IMU clock); True
        when there is one. ``stopped()`` true ends the wait (shutdown). ``stamp_ns`` is noted as
        the frames' time (:meth:`note_frame`)."""
        end = time.monotonic() + max(float(timeout), 0.0)
        with self._cond:
            self._frame_ns = int(stamp_ns)
            while not (self._t and self._t[-1] >= stamp_ns):
                left = end - time.monotonic()
                if left <= 0 or stopped():
                    return False
                self._cond.wait(min(left, 0.05))
            return True

    def measurement(
        self,
        window_ns: tuple[int, int],
        R_cam_imu: np.ndarray,
        bias: np.ndarray,
        noise: float,
        bias_sigma: float,
        time_offset: float = 0.0,
        bias_covariance: np.ndarray | None = None,
    ) -> tuple[GyroMeasurement | None, str]:
        """The gyro measurement of a readout ``window_ns`` (first and last line, camera
        clock, ns) from the buffered samples (:func:`gyro_measurement`; ``time_offset`` s is
        added to the IMU stamps; ``bias_covariance`` (3, 3) rad^2/s^2, IMU frame, is added to
        the bias uncertainty). Returns ``(measurement, "")`` or ``(None, reason)``
        with a reason of :data:`GYRO_MISSING_REASONS`: no samples, samples that do not
        cover the window, or samples in or around it further apart than ``max_gap``. The
        window's end is noted as the frames' time (:meth:`note_frame`)."""
        self.note_frame(int(window_ns[1]) - int(round(time_offset * 1e9)))
        ts, ws, span, reason = self.interval(window_ns, time_offset)
        if ts is None:
            return None, reason
        g = gyro_measurement(
            ts, ws, (0.0, span), R_cam_imu, bias, noise, bias_sigma, 0.0, bias_covariance
        )
        return g, ""

    def interval(
        self, window_ns: tuple[int, int], time_offset: float = 0.0
    ) -> tuple[np.ndarray | None, np.ndarray | None, float, str]:
        """The buffered samples around the interval ``window_ns`` (start and end, camera
        clock, ns; ``time_offset`` s is added to the IMU stamps).

        Returns:
            ``(t, rates, span, "")``: ``t`` (M,) the sample times in s relative to the
            interval's start (the first at or before 0, the last at or after ``span``),
            ``rates`` (M, 3) rad/s in the IMU frame, ``span`` the interval's length (s); or
            ``(None, None, span, reason)`` with a reason of :data:`GYRO_MISSING_REASONS`
            (no samples, samples that do not cover the interval, samples further apart than
            ``max_gap``).
        """
        off = int(round(time_offset * 1e9))
        a, b = int(window_ns[0]) - off, int(window_ns[1]) - off  # in the IMU clock
        span = (b - a) * 1e-9
        with self._cond:
            if len(self._t) < 2:
                return None, None, span, "no_samples"
            if a < self._t[0] or b > self._t[-1]:
                return None, None, span, "not_covered"
            t = np.asarray(self._t, dtype=np.int64)
            i0 = max(int(np.searchsorted(t, a, side="right")) - 1, 0)
            i1 = min(int(np.searchsorted(t, b, side="left")), len(t) - 1)
            ts = t[i0 : i1 + 1]
            ws = np.asarray(self._w[i0 : i1 + 1], dtype=float)
        if len(ts) < 2 or np.diff(ts).max() > self.max_gap_ns:
            return None, None, span, "sparse"
        # (times relative to the interval start: seconds with full precision)
        return (ts - a) * 1e-9, ws, span, ""
