"""The calibrations a camera has sent (``sensor_msgs/CameraInfo``), and which one a frame uses.

A frame uses the camera model of the newest camera_info stamped at or before it (the oldest one
if the frame is older than all), so that a calibration change applies from its own stamp even
when frames and camera_infos arrive out of order. Consecutive camera_infos with the same
calibration share one entry (and one camera model). No ROS import: messages are duck-typed
(rclpy or rosbags).
"""

from __future__ import annotations

import bisect
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ..camera import CameraModel

__all__ = ["CameraInfoEntry", "CameraInfoHistory", "calibration_key"]

#: entries kept (distinct calibrations, by stamp)
HISTORY_SIZE = 32
#: stamps of the last camera_infos and frames remembered to tell whether camera_info comes with
#: every frame
_STAMPS_KEPT = 64


def calibration_key(msg: Any) -> tuple:
    """What makes two camera_infos the same calibration: K, D, distortion model, image size,
    binning and ROI (not the stamp or frame id)."""
    return (
        tuple(msg.k),
        tuple(msg.d),
        msg.distortion_model,
        msg.width,
        msg.height,
        msg.binning_x,
        msg.binning_y,
        msg.roi.x_offset,
        msg.roi.y_offset,
        msg.roi.width,
        msg.roi.height,
    )


@dataclass
class CameraInfoEntry:
    """One calibration of the history.

    Attributes:
        stamp_ns: the stamp from which it applies (ns).
        key: :func:`calibration_key` of its message. msg: the camera_info it was made of.
        camera: its camera model (with the configured rolling-shutter timing).
        seq: arrival number of the last camera_info it stands for (the highest is the newest).
    """

    stamp_ns: int
    key: tuple
    msg: Any
    camera: CameraModel
    seq: int


class CameraInfoHistory:
    """The camera_info entries by stamp, shared by the thread receiving camera_infos and the one
    solving frames (thread-safe; a frame may wait for its camera_info, see :meth:`camera_for`).
    """

    def __init__(self, size: int = HISTORY_SIZE):
        self.size = int(size)
        self._cond = threading.Condition()
        self._entries: list[CameraInfoEntry] = []  # sorted by stamp
        self._seq = 0
        self._info_stamps: deque[int] = deque(maxlen=_STAMPS_KEPT)
        self._frame_stamps: deque[int] = deque(maxlen=_STAMPS_KEPT)
        #: a frame waited for the first camera_info in vain: the next ones do not wait
        self._waited_in_vain = False

    def __len__(self) -> int:
        with self._cond:
            return len(self._entries)

    def entries(self) -> list[CameraInfoEntry]:
        """A copy of the entries, oldest stamp first."""
        with self._cond:
            return list(self._entries)

    def camera_with_key(self, key: tuple) -> CameraModel | None:
        """The camera model of an entry with this calibration, if any (not rebuilt for it)."""
        with self._cond:
            return next((e.camera for e in self._entries if e.key == key), None)

    def add(self, stamp_ns: int, key: tuple, msg: Any, camera: CameraModel) -> bool:
        """Record a camera_info stamped ``stamp_ns`` with its camera model; wakes the frames
        waiting for one. Returns True for the first camera_info of the history."""
        with self._cond:
            first = not self._entries
            hist = self._entries
            i = bisect.bisect_right([e.stamp_ns for e in hist], stamp_ns)
            self._seq += 1
            if i > 0 and hist[i - 1].key == key:
                hist[i - 1].seq = self._seq  # the entry before already covers this stamp
            else:
                hist.insert(i, CameraInfoEntry(stamp_ns, key, msg, camera, self._seq))
                if i + 1 < len(hist) and hist[i + 1].key == key:
                    del hist[i + 1]  # now covered from an earlier stamp
                if len(hist) > self.size:
                    del hist[0]
            self._info_stamps.append(stamp_ns)
            self._waited_in_vain = False
            self._cond.notify_all()
            return first

    def camera_for(
        self,
        stamp_ns: int,
        fallback: CameraModel | None = None,
        wait: float = 0.0,
        stopped: Callable[[], bool] = lambda: False,
    ) -> CameraModel | None:
        """The camera model of a frame stamped ``stamp_ns``: from the newest camera_info
        stamped at or before it (the oldest one if the frame is older than all), else
        ``fallback`` (the parameters' intrinsics, or None).

        Waits up to ``wait`` s (while not ``stopped()``; :meth:`wake` interrupts the wait) when
        no camera_info has arrived yet and there is no fallback, or when camera_info comes with
        every frame (each of the last two frames got one with its stamp) and this frame's has
        not arrived yet. A camera that sends no camera_info holds one frame only: once a
        frame has waited the whole ``wait`` for the first one, the next frames do not wait
        until one arrives (a rig's other cameras' frames, and a camera's frame queue, are not
        held up by it). Records the frame's stamp for that test.
        """
        with self._cond:
            if not self._entries and self._waited_in_vain:
                wait = 0.0
            deadline = time.monotonic() + wait
            infos = set(self._info_stamps)
            synced = len(self._frame_stamps) >= 2 and all(
                self._frame_stamps[-k] in infos for k in (1, 2)
            )
            self._frame_stamps.append(stamp_ns)
            while not stopped():
                if self._entries:
                    if (
                        not synced
                        or stamp_ns in self._info_stamps
                        or self._entries[-1].stamp_ns >= stamp_ns
                    ):
                        break
                elif fallback is not None:
                    return fallback
                if time.monotonic() >= deadline:
                    break
                self._cond.wait(deadline - time.monotonic())
            hist = self._entries
            if not hist:
                self._waited_in_vain = self._waited_in_vain or (wait > 0.0 and not stopped())
                return fallback
            i = bisect.bisect_right([e.stamp_ns for e in hist], stamp_ns)
            return hist[max(i - 1, 0)].camera

    def wake(self) -> None:
        """Wake the frames waiting in :meth:`camera_for` (to see ``stopped()``)."""
        with self._cond:
            self._cond.notify_all()

    def forget_after(self, stamp_ns: int) -> None:
        """Time went back or jumped: drop the entries stamped after ``stamp_ns`` (the newest
        one stays when nothing else would) and the frame stamps of the every-frame test."""
        with self._cond:
            keep = [e for e in self._entries if e.stamp_ns <= stamp_ns]
            if not keep and self._entries:
                keep = [max(self._entries, key=lambda e: e.seq)]
            self._entries = keep
            self._frame_stamps.clear()

    def rebuild(self, make_camera: Callable[[Any], CameraModel]) -> list[str]:
        """Remake every entry's camera model from its message with ``make_camera`` (the
        rolling-shutter timing changed). Entries it rejects (ValueError) are dropped; returns
        their error messages."""
        errors = []
        with self._cond:
            kept = []
            for e in self._entries:
                try:
                    kept.append(
                        CameraInfoEntry(e.stamp_ns, e.key, e.msg, make_camera(e.msg), e.seq)
                    )
                except ValueError as err:
                    errors.append(str(err))
            self._entries = kept
        return errors
