"""The one time-reset policy of a video, a camera's or a rig's: when its frames' clock started
again.

:class:`VideoClock` notes each frame's time (ns) and tells a **time reset**
(:class:`TimeReset`, a reason of :data:`TIME_RESET_REASONS`):

- ``stamp_back``: the frame is older than its source's (its camera's) newest frame since the last
  reset by more than ``back_tolerance_ns`` (a bag replayed again, a driver restarted). The gyro's
  samples so far belong to the old timeline: all are dropped (:attr:`TimeReset.keep_from` None);
- ``stamp_jump``: the frame is newer than the video's newest frame by more than
  ``time_reset_ns`` (a gap in a bag, a clock that jumped ahead). The gyro's samples from the
  newest frame on are kept (:attr:`TimeReset.keep_from`), the older ones dropped.

A frame's time is its camera's stamp on the video's clock (the capture time of row
``stamp_row`` plus the camera's time offset), noted once, before its image is searched, a
camera's and a rig camera's alike, every frame received (one skipped, without a camera model or
that could not be decoded, too: :meth:`~rs_localizer.tracking.video.Localizer._note`).
On either reset, the gyro's timeline starts again
(:meth:`~rs_localizer.tracking.gyro_input.GyroInput.restart`: the samples above, the pairing of
the bias estimator and of the mount check). What else starts again is the localizer's:

- one camera (:class:`~rs_localizer.tracking.sequence.SequenceLocalizer`, through its rig of
  one: a :class:`~rs_localizer.tracking.video.Localizer` of the one camera,
  ``back_tolerance_ns`` 0: any step back is a reset): nothing else; its tracker resets itself
  on the same stamps (a stamp going back, or a gap beyond ``max_gap``, which
  ``time_reset_ns`` exceeds by default); the node counts ``time_resets``;
- a rig of several cameras (:class:`~rs_localizer.tracking.video.Localizer`,
  ``back_tolerance_ns`` =
  ``time_reset_ns``: its cameras' frames interleave, a smaller step back of one camera is that
  frame out of order): the rig frames still open are dropped (``stamp_back``, counted
  ``skipped.time_reset``) or solved as they are (``stamp_jump``: the old timeline's frames),
  the track ends and the cameras' timelines start again (no camera counts as stopped for the
  gap); counted ``rig.time_resets``.

A stamp equal to the newest is no reset (the same frame's stamp noted twice).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["TIME_RESET_REASONS", "TimeReset", "VideoClock"]

#: why a video's clock started again (:class:`VideoClock`)
TIME_RESET_REASONS = {
    "stamp_back": "a frame older than its source's previous frame (by more than the "
    "tolerance: any step back for one camera, time_reset_threshold for a rig's camera): a bag "
    "replayed again, a driver restarted",
    "stamp_jump": "a frame newer than the video's newest by more than time_reset_threshold: a "
    "gap in a bag, a clock that jumped ahead",
}


@dataclass(frozen=True)
class TimeReset:
    """A time reset (:class:`VideoClock`).

    Attributes:
        reason: a key of :data:`TIME_RESET_REASONS`.
        detail: the text of it (the stamps and their difference, s).
        keep_from: ns: the gyro samples stamped from this on go on in the new timeline (the
            newest frame before a jump ahead); None: none (the clock went back).
    """

    reason: str
    detail: str
    keep_from: int | None


class VideoClock:
    """A video's clock (module docstring).

    Args:
        time_reset_ns: a frame newer than the newest by more than this (ns) is a time reset.
        back_tolerance_ns: a frame older than its source's previous frame by more than this
            (ns) is a time reset (0: any step back).

    Attributes:
        newest: ns, the newest frame time noted since the last reset (None before one).
        first: ns, the first frame time noted since the start or the last reset (None before
            one): when the video's timeline began.
    """

    def __init__(self, time_reset_ns: int = 10**9, back_tolerance_ns: int = 0):
        self.time_reset_ns = time_reset_ns
        self.back_tolerance_ns = back_tolerance_ns
        self.newest: int | None = None
        self.first: int | None = None
        self._last: dict = {}  # (source -> its newest frame time since the last reset, ns)

    def step(self, stamp: int, source: str = "") -> TimeReset | None:
        """Note a frame's time ``stamp`` (ns) of ``source`` (a camera's name), compared with
        that source's newest frame time since the last reset (a step back) and with the
        video's :attr:`newest` (a jump ahead); for a video of one source they are the same
        time. Returns the time reset it makes, or None. After a reset :attr:`first`,
        :attr:`newest` and the source's newest are ``stamp``, the other sources have none."""
        last, previous = self.newest, self._last.get(source)
        reset = None
        if previous is not None and previous - stamp > self.back_tolerance_ns:
            reset = TimeReset(
                "stamp_back",
                f"stamp {stamp * 1e-9:.6f} s is {(previous - stamp) * 1e-9:.3f}"
                " s older than the previous frame",
                None,
            )
        elif last is not None and stamp - last > self.time_reset_ns:
            reset = TimeReset(
                "stamp_jump",
                f"{(stamp - last) * 1e-9:.3f} s since the previous frame (> time_reset_threshold)",
                last,
            )
        self.newest = stamp if reset is not None or last is None else max(last, stamp)
        if reset is not None or last is None:
            self.first = stamp
        if reset is not None:
            self._last = {}
        self._last[source] = stamp if previous is None or reset else max(previous, stamp)
        return reset

    def source_newest(self, source: str = "") -> int | None:
        """ns, ``source``'s newest frame time since the last reset (None: none since)."""
        return self._last.get(source)

    def reset(self) -> None:
        """Forget the frames' time (the video forgotten)."""
        self.newest = self.first = None
        self._last = {}
