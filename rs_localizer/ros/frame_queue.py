"""The frames between the subscription callbacks and the thread that solves them.

Callbacks :meth:`FrameQueue.put` frames into a bounded queue and return at once (the executor
stays free for camera_info, parameters and diagnostics however slow a frame is); one worker
thread takes them out in order and hands each to ``process``. When the queue is full the oldest
waiting frame is dropped (skipped), so the newest frames are the ones solved.

Accounting: each frame is counted in its camera's counts (``counts_of(item)``, a
:class:`~rs_localizer.ros.camera_input.CameraCounts`: the single camera's and each rig
camera's alike): ``received`` as it is put, ``skipped.<reason>`` when the queue drops it, and
its outcome by ``process`` (:meth:`~rs_localizer.ros.camera_input.CameraCounts.frame_done`,
``solved`` or ``failed.<reason>``; a rig camera's frame handed on is the rig's to count), so
that every frame received is, at every instant, exactly one of solved, failed, skipped or
pending (waiting, or taken by the worker and not yet counted): ``received = solved + failed +
skipped + pending`` in every snapshot (:func:`frame_accounting` of the camera's counts, a rig
camera's with the rig's). No ROS import.
"""

from __future__ import annotations

import threading
from collections import Counter, deque
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Protocol

__all__ = [
    "FRAME_ACCOUNTING",
    "QUEUE_SKIP_REASONS",
    "BetweenFrames",
    "Failed",
    "FrameCounts",
    "FrameQueue",
    "Outcome",
    "frame_accounting",
]


class Outcome(Protocol):
    """What ``process`` returns for a frame: ``failure`` is None when it was solved, else the
    reason it was dropped (counted as ``failed.<reason>``)."""

    failure: str | None


@dataclass(frozen=True)
class Failed:
    """The outcome of a frame whose processing raised: ``failure`` is ``internal_error``."""

    failure: str
    detail: str


#: a camera's frame accounting (received = the other four summed)
FRAME_ACCOUNTING = ("received", "solved", "failed", "skipped", "pending")

QUEUE_SKIP_REASONS = {
    "queue_full": "the node was busy: the frame queue was full (``queue_size`` frames per "
    "camera) and this, the oldest waiting frame, was dropped so that the newest are solved",
    "stopped": "the frame inputs stopped (deactivate) while the frame waited in the queue",
}
"""Why the queue drops a frame before it is solved (counted ``skipped.<reason>`` in its
camera's counts, a rig camera's beside the rig's own
:data:`~rs_localizer.tracking.video.SKIP_REASONS`)."""


@dataclass(frozen=True)
class FrameCounts:
    """A camera's frame accounting, the one form of both modes: ``received == solved +
    failed + skipped + pending``; ``failures`` counts each failure reason (their sum is
    ``failed``), ``skips`` each skip reason known (the rig camera's; the single camera's
    queue counts its skips without reason): :func:`frame_accounting` of the camera's counts
    (a rig camera's with the rig's,
    :func:`~rs_localizer.ros.diagnostics.rig_camera_frames`)."""

    received: int = 0
    solved: int = 0
    failed: int = 0
    skipped: int = 0
    pending: int = 0
    failures: dict[str, int] = field(default_factory=dict)
    skips: dict[str, int] = field(default_factory=dict)

    def accounting(self) -> dict[str, int]:
        """``received``, ``solved``, ``failed``, ``skipped``, ``pending``, in that order."""
        return {k: getattr(self, k) for k in FRAME_ACCOUNTING}

    def reasons(self) -> dict[str, int]:
        """The counts by reason: ``failed.<reason>``, then ``skipped.<reason>``, each sorted
        by reason."""
        out = {f"failed.{k}": v for k, v in sorted(self.failures.items())}
        out.update({f"skipped.{k}": v for k, v in sorted(self.skips.items())})
        return out


def frame_accounting(counts: Mapping[str, int], handed: FrameCounts | None = None) -> FrameCounts:
    """A camera's frame accounting, the single camera's and a rig camera's alike, from its
    counts (keys without prefix, a :meth:`~rs_localizer.ros.camera_input.CameraCounts.counts`
    snapshot: ``received``, ``solved``, ``failed.<reason>`` and ``skipped.<reason>``, the
    node's) and, for a camera whose frames the node hands on to a rig, ``handed``: the rig's
    accounting of the frames it was handed (its ``solved``, ``failed``, ``skipped`` and
    ``skips`` by reason; None: the node solves them itself). ``solved``, ``failed`` and
    ``skipped`` are the node's and the rig's summed, the failures by reason the node's, the
    rest of ``received`` pending (queued, being solved or in an open rig frame). Skips by
    reason: with ``handed`` the node's and the rig's (a rig camera's section lists them);
    without, none (the single camera's status counts its skips without reason)."""
    failures = {k[len("failed.") :]: v for k, v in counts.items() if k.startswith("failed.")}
    skips = Counter(
        {k[len("skipped.") :]: v for k, v in counts.items() if k.startswith("skipped.")}
    )
    received = counts.get("received", 0)
    solved, failed, skipped = counts.get("solved", 0), sum(failures.values()), sum(skips.values())
    if handed is not None:
        solved, failed, skipped = (
            solved + handed.solved,
            failed + handed.failed,
            skipped + handed.skipped,
        )
        skips.update(handed.skips)
    return FrameCounts(
        received=received,
        solved=solved,
        failed=failed,
        skipped=skipped,
        pending=received - solved - failed - skipped,
        failures=failures,
        skips=dict(skips) if handed is not None else {},
    )


class BetweenFrames:
    """The worker's frames and what must run between two of them, without the caller
    waiting for the frame the worker is on.

    The worker takes each frame inside :meth:`frame` (its lock held). :meth:`run` runs a step
    between two frames from any thread: at once when no frame is being taken, else handed to
    the worker, which runs the steps handed to it at the end of the frame it is on, before
    its next, in the order they were handed (a state change taken from the next frame on, a
    snapshot of counts that change together with a frame). The caller never waits for a
    frame: a subscription, timer or parameter callback on the executor's thread returns at
    once while the worker solves, so that the executor goes on taking messages. Whoever
    releases the lock runs what was handed meanwhile, so that no step waits for a later
    frame. A step's exception goes to ``on_error`` (default: ignored); the others still run.
    No ROS import.
    """

    def __init__(self, on_error: Callable[[BaseException], None] | None = None):
        self._lock = threading.Lock()
        self._handed: deque[Callable[[], None]] = deque()
        self._on_error = on_error

    @contextmanager
    def frame(self) -> Iterator[None]:
        """The worker's frame (or an end of the video's, taken while no worker runs): the
        lock held (waiting for a frame being taken), then the steps handed meanwhile run."""
        self._lock.acquire()
        try:
            yield
        finally:
            self._release()

    def run(self, step: Callable[[], None]) -> bool:
        """``step()`` between two frames: now when no frame is being taken (True), else
        handed to the worker, which runs it after the frame it is on (False). Never waits
        for a frame."""
        self._handed.append(step)
        return self._run_handed_if_free()

    def hold_if_free(self) -> bool:
        """The lock taken if no frame is being taken (True; :meth:`release` it), else False
        at once (nothing taken)."""
        return self._lock.acquire(blocking=False)

    def release(self) -> None:
        """The lock of :meth:`hold_if_free` released, the steps handed meanwhile run first."""
        self._release()

    def _run_handed_if_free(self) -> bool:
        if not self._lock.acquire(blocking=False):
            return False
        self._release()
        return True

    def _release(self) -> None:
        """Run the steps handed (the lock held), release the lock; a step handed after the
        last check while the lock was still held runs now (its caller found the lock taken)."""
        try:
            while self._handed:
                step = self._handed.popleft()
                try:
                    step()
                except Exception as e:
                    if self._on_error is not None:
                        self._on_error(e)
        finally:
            self._lock.release()
        if self._handed:
            self._run_handed_if_free()


class FrameQueue:
    """A bounded frame queue with one worker thread.

    Args:
        process: ``process(item) -> outcome``, run on the worker thread for each frame in
            arrival order; it counts the frame's outcome in ``counts_of(item)`` (module
            docstring). An exception counts the frame ``failed.internal_error`` (its outcome
            is then a :class:`Failed`).
        deliver: ``deliver(item, outcome)``, run on the worker thread after ``process``
            (publishing: whoever receives a frame's output sees it counted); its exceptions
            propagate to ``on_error`` (default: ignored) and do not change the counts.
        name: the worker thread's name.
        counts_of: ``counts_of(item)``: the counts of the frame's camera (``add(key)``,
            ``frame_done(seconds, *keys)``: a
            :class:`~rs_localizer.ros.camera_input.CameraCounts`), where :meth:`put` counts
            it ``received`` and a drop ``skipped.<reason>``: ``queue_full`` (:meth:`put`) or
            ``stopped`` (:meth:`request_stop` with ``drop_queued``); None: not counted.
        group: ``group(batch, item) -> bool``: with it the worker takes, with the oldest
            waiting frame, every waiting frame that belongs with those it took (``batch``, a
            list, oldest first), e.g. the other cameras' frames of one rig frame; they are
            then solved one after another and no longer dropped by a full queue (still
            pending). A full queue drops its oldest frame with the waiting frames that belong
            with it. None: one frame at a time.
    """

    def __init__(
        self,
        process: Callable[[Any], Outcome],
        deliver: Callable[[Any, Outcome], None] | None = None,
        on_error: Callable[[BaseException], None] | None = None,
        name: str = "rs_localizer_worker",
        counts_of: Callable[[Any], Any] | None = None,
        group: Callable[[list, Any], bool] | None = None,
    ):
        self._process = process
        self._deliver = deliver
        self._on_error = on_error
        self._name = name
        self._counts_of = counts_of
        self._group = group
        self._cond = threading.Condition()
        self._queue: deque = deque()
        self._in_flight = 0  # frames the worker took and has not finished yet
        self._stop = False
        self._worker: threading.Thread | None = None
        #: frames dropped unsolved so far (a full queue's and a stop's)
        self.dropped = 0

    def _count(self, item: Any, key: str) -> None:
        if self._counts_of is not None:
            self._counts_of(item).add(key)

    # ---------------------------------------------------------------- producer side
    def put(self, item: Any, max_waiting: int) -> int:
        """Count a received frame and queue it; when ``max_waiting`` frames already wait the
        oldest ones are dropped (counted as skipped). Returns how many were dropped."""
        with self._cond:
            self._count(item, "received")
            skipped = 0
            while self._queue and len(self._queue) >= max_waiting:
                for dropped in self._take_group():
                    skipped += 1
                    self._count(dropped, "skipped.queue_full")
            self.dropped += skipped
            self._queue.append(item)
            self._cond.notify_all()
        return skipped

    @property
    def pending(self) -> int:
        """Frames waiting or taken by the worker and not finished (delivered) yet."""
        with self._cond:
            return len(self._queue) + self._in_flight

    @property
    def stopping(self) -> bool:
        """A stop was requested (a frame in progress may check it to stop waiting)."""
        return self._stop

    # ---------------------------------------------------------------- the worker
    def start(self) -> None:
        """Start the worker thread (after :meth:`stop`: a new one)."""
        with self._cond:
            self._stop = False
        self._worker = threading.Thread(target=self._work, name=self._name, daemon=True)
        self._worker.start()

    def request_stop(self, drop_queued: bool = False) -> None:
        """Ask the worker to stop after the frame it is on; ``drop_queued``: the frames still
        waiting are dropped (counted as skipped), else they stay for a later :meth:`start`."""
        with self._cond:
            self._stop = True
            if drop_queued:
                self.dropped += len(self._queue)
                for item in self._queue:
                    self._count(item, "skipped.stopped")
                self._queue.clear()
            self._cond.notify_all()

    def join(self, timeout: float = 10.0) -> None:
        """Wait for the worker to end (not from the worker itself)."""
        worker = self._worker
        if worker is not None and worker.is_alive() and threading.current_thread() is not worker:
            worker.join(timeout=timeout)
        self._worker = None

    def stop(self, drop_queued: bool = False, timeout: float = 10.0) -> None:
        """:meth:`request_stop`, then :meth:`join`."""
        self.request_stop(drop_queued)
        self.join(timeout)

    def _work(self) -> None:
        while True:
            with self._cond:
                while not self._queue and not self._stop:
                    self._cond.wait()
                if self._stop:
                    return
                batch = self._take_group()
                self._in_flight = len(batch)
            for item in batch:
                self._solve(item)

    def _take_group(self) -> list:
        """Take the oldest waiting frame and those that belong with it (``group``; with the
        lock held)."""
        batch = [self._queue.popleft()]
        if self._group is not None and self._queue:
            rest: deque = deque()
            for other in self._queue:
                (batch if self._group(batch, other) else rest).append(other)
            self._queue = rest
        return batch

    def _solve(self, item: Any) -> None:
        try:
            outcome = self._process(item)
        except Exception as e:
            outcome = Failed("internal_error", f"{type(e).__name__}: {e}")
            if self._counts_of is not None:
                self._counts_of(item).frame_done(0.0, "failed.internal_error")
        try:
            if self._deliver is not None:
                self._deliver(item, outcome)
        except Exception as e:
            if self._on_error is not None:
                self._on_error(e)
        finally:
            with self._cond:
                self._in_flight -= 1
