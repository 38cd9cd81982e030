"""The node's per-frame helpers, without ROS, for one camera and a rig alike: the throttled
log (:class:`ThrottledLog`), a camera's counters for the diagnostics (:class:`PipelineStats`),
the map-fit check (:class:`MapFitCheck`), a gyro sample taken from a ``sensor_msgs/Imu``
(:func:`take_imu_message`), the fused twists that became final as published
(:class:`FusedOutput`, :func:`fused_outputs`), the kernels' warm-up (:func:`warm_localizer`,
:func:`log_warm_up`, :func:`warm_kernels`) and a frame dropped with its reason (``Drop``).
What the node does with each frame is its mode's (:class:`~rs_localizer.ros.mode.LocalizerMode`);
``rs-localizer replay`` takes a bag's frames the same way. No module-level ROS import.
"""

from __future__ import annotations

import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, cast

import numpy as np

from ..estimation.result import RSPoseEstimate
from ..frames import camera_to_base
from ..pose import PoseWithCovariance
from ..tracking.gyro_input import GyroReadouts
from . import conversions as cv
from .camera_input import CameraCounts

__all__ = [
    "FRAME_KINDS",
    "Drop",
    "FusedOutput",
    "MapFitCheck",
    "PipelineStats",
    "StatsSnapshot",
    "ThrottledLog",
    "fused_outputs",
    "log_warm_up",
    "take_imu_message",
    "warm_localizer",
]

#: kinds of frame message: a correspondence cloud, a keypoint cloud (ids into the landmark
#: map), an image (raw or compressed) for the front end
FRAME_KINDS = ("correspondences", "keypoints", "image")
#: s between two log lines of the same kind (per failure reason)
LOG_PERIOD = 2.0
_STATS_KEPT = 1000
#: the map-fit check: a frame with at least ``MAP_FIT_MIN_POINTS`` correspondences that the
#: estimator refused for one of ``MAP_FIT_REASONS`` (no pose explains its matches) counts in
#: ``frames_failed_with_matches``; when at least 80 % of the last ``MAP_FIT_WINDOW`` frames
#: with that many correspondences (at least half that many of them) were so refused, the map
#: is doubted (``map_fit_doubtful``, a throttled warning): a mirrored (left-handed) map or a
#: map of another place gives many matches and no pose
MAP_FIT_MIN_POINTS = 20
MAP_FIT_WINDOW = 20
MAP_FIT_REASONS = (
    "implausible_motion",
    "too_few_inliers",
    "inconsistent_fit",
    "cheirality",
    "no_hypothesis",
    "degenerate_geometry",
)


class MapFitCheck:
    """Whether the map fits the place (:data:`MAP_FIT_REASONS`), over a camera's frames or a
    rig's rig frames: each one of at least :data:`MAP_FIT_MIN_POINTS` correspondences solved
    or refused for its geometry joins a window of the last :data:`MAP_FIT_WINDOW`; when 80 %
    or more of the window (at least half of it full) were refused, the map is doubted
    (:attr:`doubtful`). ``unit``: what the warning names (``frames``, ``rig frames``) and
    :meth:`check` counts (``<unit>_failed_with_matches``, blanks as ``_``)."""

    def __init__(self, unit: str = "frames"):
        self.unit = unit
        self.failed_key = f"{unit.replace(' ', '_')}_failed_with_matches"
        self.doubtful = False
        self._fit: deque[tuple[bool, str, int]] = deque(maxlen=MAP_FIT_WINDOW)

    def update(self, n_points: int, est: RSPoseEstimate) -> tuple[bool | None, bool]:
        """Take a frame of ``n_points`` correspondences and its estimate. Returns
        ``(refused, warn)``: ``refused`` None when the frame does not join the window (too
        few points, or refused for another reason), else whether it was refused for its
        geometry; ``warn``: it was, and the map is doubted now."""
        if n_points < MAP_FIT_MIN_POINTS:
            return None, False
        refused = not est.success and est.failure in MAP_FIT_REASONS
        if not est.success and not refused:
            return None, False
        self._fit.append((refused, est.failure or "", n_points))
        w = self._fit
        n_refused = sum(r for r, _, _ in w)
        self.doubtful = len(w) >= MAP_FIT_WINDOW // 2 and n_refused >= 0.8 * len(w)
        return refused, self.doubtful and refused

    def check(self, n_points: int, est: RSPoseEstimate, counts: CameraCounts,
              warn: Callable[[str, str], None]) -> None:  # fmt: skip
        """:meth:`update` with a frame (a camera's or a rig's) of ``n_points``
        correspondences and its estimate, counted in ``counts``: ``<unit>_failed_with_matches``
        (:attr:`failed_key`: ``frames_failed_with_matches``,
        ``rig_frames_failed_with_matches``) and ``map_fit_doubtful``; the warning that names
        the map as the likely cause to ``warn(key, text)`` (a throttled log) when the map is
        doubted."""
        refused, warn_now = self.update(n_points, est)
        if refused:
            counts.add(self.failed_key)
        if refused is not None:
            counts.set("map_fit_doubtful", int(self.doubtful))
        if warn_now:
            warn("map_fit", self.text())

    def text(self) -> str:
        """The map-fit warning for the current window."""
        w = self._fit
        reasons = Counter(why for r, why, _ in w if r)
        median = int(np.median([n for _, _, n in w])) if w else 0
        return (
            f"{sum(reasons.values())} of the last {len(w)} {self.unit} with "
            f"{MAP_FIT_MIN_POINTS} or more correspondences (median {median}) were refused "
            f"({', '.join(f'{k} {v}' for k, v in reasons.most_common())}): does the map fit "
            "this place? mirrored (left-handed, z -> -z) or another room? Matches that no pose "
            "explains point at the map, not at the camera"
        )


def log_warm_up(
    solver: str,
    options: Any,
    tracking: Any,
    logger: Any,
    gyro: bool = False,
    background: bool = False,
) -> None:
    """Run the estimator (and, with ``tracking``, the video tracker) on small synthetic RS
    problems so that the numba JIT compiles (or loads from its cache) every kernel the node
    will use before the first real frame (:func:`~rs_localizer.runtime.warmup.warm_up`),
    logging the cache, each kernel compiled and the time to ``logger``
    (``info``/``warning``). ``options``: the estimator options; ``tracking``: the tracker's
    (None: every frame alone); ``gyro``: also the gyro-aided path (``imu.enabled``). On a
    machine with two cores or more, kernels not yet compiled compile in two processes. With
    ``background`` and kernels not cached, nothing waits: the frames are solved on the
    uncompiled path while they compile in the background
    (:func:`~rs_localizer.runtime.background.start_background_compile`), and a warm-up that fails (a
    corrupt cache) leaves the frames on the uncompiled path. Never raises (a failure is
    logged). Its steps are :func:`warm_kernels`' (the rig node's too)."""
    from ..runtime.background import CameraKernels, fall_back_uncompiled
    from ..runtime.jit_cache import cache_state
    from ..runtime.warmup import DEFAULT_JOBS, warm_up

    st = cache_state()  # (before a background compile starts)
    cache = f"{st['dir']} ({st['mode']}" + (
        f", {st['seeded']} files copied from the package)" if st["seeded"] else ")"
    )

    def warm() -> tuple[float, str]:
        logger.info(f"warm-up ({solver}): numba cache {cache}")
        dt, est = warm_up(solver, options, tracking, jobs=DEFAULT_JOBS, log=logger.info, gyro=gyro)
        return dt, "ok" if est.success else str(est.failure)

    def failed(text: str) -> None:  # (e.g. a corrupt numba cache: frames would fail on them)
        fall_back_uncompiled(solver, f"warm-up: {text}", logger.warning)

    kernels = CameraKernels(solver, options, tracking, gyro)
    warm_kernels(kernels, solver, warm, logger, background, "`rs-localizer compile`",
                 failed if background else None)  # fmt: skip


def warm_localizer(cfg: Any, logger: Any) -> None:
    """The kernels of a configuration (``cfg``, a :class:`~.config.LocalizerConfig`) compiled
    or loaded in the background, for the camera alone and a rig alike (:func:`warm_kernels`):
    the camera alone's estimator's of its solver, tracking and gyro (:func:`log_warm_up`), a
    rig's (``cfg.settings``) in numba's cache
    (:func:`~rs_localizer.runtime.warmup.rig_cached`) loaded before the next frame
    (:func:`~rs_localizer.runtime.warmup.warm_rig` with the rig's settings and every camera's
    RS timing), else compiled in another process
    (:class:`~rs_localizer.runtime.background.RigKernels`) while the rig frames are solved on
    the NumPy implementation."""
    if cfg.settings is None:  # (the camera alone: its own estimator's kernels)
        log_warm_up(cfg.solver, cfg.options, cfg.tracking, logger, cfg.imu is not None, True)
        return
    from ..runtime.warmup import warm_rig

    def warm() -> tuple[float, str]:
        tic = time.perf_counter()
        posed = warm_rig(cfg.settings, cfg.timings)
        return time.perf_counter() - tic, f"{posed} synthetic rig frames posed"

    warm_kernels(config_kernels(cfg), "rig", warm, logger, True,
                 "`rs-localizer compile --params-file`")  # fmt: skip


def config_kernels(cfg: Any) -> Any:
    """The kernels the frames of a configuration (``cfg``, a :class:`~.config.LocalizerConfig`)
    run on: the camera alone's (``cfg.settings`` None) a
    :class:`~rs_localizer.runtime.background.CameraKernels` of its solver, estimator options,
    tracking and gyro; a rig's a :class:`~rs_localizer.runtime.background.RigKernels` of its
    settings and its cameras' RS timing."""
    from ..runtime.background import CameraKernels, RigKernels

    if cfg.settings is None:
        return CameraKernels(cfg.solver, cfg.options, cfg.tracking, cfg.imu is not None)
    return RigKernels(cfg.settings, cfg.timings)


def warm_kernels(
    kernels: Any,
    label: str,
    warm: Callable[[], tuple[float, str]],
    logger: Any,
    background: bool,
    hint: str,
    failed: Callable[[str], None] | None = None,
) -> None:
    """The node's warm-up of one camera's or a rig's kernels, written once: with
    ``background`` and ``kernels`` (a :class:`~rs_localizer.runtime.background.CameraKernels`
    or :class:`~rs_localizer.runtime.background.RigKernels`) not in numba's cache, they
    compile in another process
    (:func:`~rs_localizer.runtime.background.start_background_compile`) and nothing waits;
    else ``warm()`` (-> ``(s, outcome)``: the warm-up's time and what it
    gave) with each kernel compiled logged, and the line ``warm-up (<label>): <s> s,
    <outcome>, compiled N kernels (<hint> after installing avoids this)`` (or ``kernels from
    the cache``) to ``logger`` (``info``/``warning``). Never raises: a failure is logged as
    ``warm-up (<label>) failed: ...`` and its text handed to ``failed``."""
    from ..runtime.background import start_background_compile
    from ..runtime.jit_cache import compile_progress

    if background and not kernels.cached():
        try:
            if start_background_compile(kernels, logger.info, logger.warning):
                return
        except Exception as e:
            logger.warning(f"background compile ({label}) failed to start: {e}")
    try:
        with compile_progress(logger.info) as prog:
            seconds, outcome = warm()
    except Exception as e:
        text = f"{type(e).__name__}: {e}"
        logger.warning(f"warm-up ({label}) failed: {text}")
        if failed is not None:
            failed(text)
        return
    done = (
        f"compiled {len(prog.kernels)} kernels ({hint} after installing avoids this)"
        if prog.kernels
        else "kernels from the cache"
    )
    logger.info(f"warm-up ({label}): {seconds:.2f} s, {outcome}, {done}")


def take_imu_message(
    msg: Any, video: GyroReadouts, count: Callable[[str], Any], warn: Callable[[str, str], Any]
) -> str | None:
    """The gyro sample of a ``sensor_msgs/Imu`` buffered by a camera's or a rig's video
    (``video``: its :class:`~rs_localizer.tracking.video.Localizer`): its stamp (ns) and
    angular velocity ``(x, y, z)`` (rad/s, the IMU's frame; :func:`.conversions.gyro_sample`)
    to ``video.add_imu``. Returns None, or the reason it was rejected: ``disabled`` (no
    gyro: nothing counted), a message without a usable sample (``no_angular_velocity``,
    ``bad_stamp``, ...) or a sample the buffer refused, each
    counted ``count("imu_rejected")`` and ``count("imu_rejected.<reason>")`` and warned
    ``warn("imu.<reason>", text)``; a buffered sample that this one shows to have been a
    lone stamp jump ahead (dropped from the buffer) likewise as ``stamp_jumped_ahead``."""
    buf = video.imu
    if buf is None:
        return "disabled"
    dropped = buf.dropped
    try:
        stamp, omega = cv.gyro_sample(msg)
    except cv.ImuError as e:
        reason = e.reason
    else:
        reason = video.add_imu(stamp, omega)
    for why in ([reason] if reason is not None else []) + ["stamp_jumped_ahead"] * (
        buf.dropped - dropped
    ):
        count("imu_rejected")
        count(f"imu_rejected.{why}")
        warn(f"imu.{why}", f"IMU sample rejected ({why})")
    return reason


class Drop(ValueError):
    """A frame dropped (the node's camera alone's frame step): ``reason`` is counted as
    ``failed.<reason>``, the text is the log line's detail."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


class ThrottledLog:
    """Warnings at most once per :data:`LOG_PERIOD` per key, over a logger with ``info``,
    ``warning`` and ``error`` methods (an rclpy logger, a :class:`logging.Logger`); None:
    silent."""

    def __init__(self, logger: Any = None, period: float = LOG_PERIOD):
        self.logger = logger
        self.period = period
        self._last: dict[str, float] = {}

    def info(self, text: str) -> None:
        """Log ``text`` (not throttled)."""
        if self.logger is not None:
            self.logger.info(text)

    def error(self, text: str) -> None:
        """Log ``text`` as an error (not throttled)."""
        if self.logger is not None:
            self.logger.error(text)

    def warning(self, key: str, text: str, count: int = 0) -> None:
        """Log ``text`` unless a ``key`` line was logged less than ``period`` s ago;
        ``count`` > 1 is appended as ``[count so far]``."""
        now = time.monotonic()
        if self.logger is not None and now - self._last.get(key, -1e9) >= self.period:
            self._last[key] = now
            self.logger.warning(text + (f" [{count} so far]" if count > 1 else ""))


@dataclass(frozen=True)
class StatsSnapshot:
    """A consistent copy of :class:`PipelineStats`."""

    counts: dict[str, int]
    inliers: list[int]
    planar: bool
    condition_number: float
    frontend_last: int
    stage_times: dict[str, list[float]]


class PipelineStats(CameraCounts):
    """The single camera's counters for the diagnostics (thread-safe): its
    :class:`~.camera_input.CameraCounts` (name "": keys as they are; the node's frame
    accounting, counted by its queue and worker as a rig camera's: received, solved,
    failed.<reason>, skipped.<reason> (:func:`.frame_queue.frame_accounting`; ``replay``
    counts none of them); time_resets,
    points_dropped, capped_clouds, capped_points, unknown_landmark_ids,
    camera_info_rejected[.<reason>], frontend_runs, frontend_points, image_frames,
    frames_beside_frontend, ...; the messages lost per input; the stage times, s: decode,
    frontend, estimate, publish), the last 1000 inlier counts, the planarity of the last pose
    and the front end's last correspondence count."""

    def __init__(self):
        super().__init__("", kept=_STATS_KEPT)
        self._inliers: deque[int] = deque(maxlen=_STATS_KEPT)
        self._planar = (False, float("nan"))
        self._frontend_last = 0

    def solved(self, inliers: int, planar: bool, condition_number: float) -> None:
        """Record a solved frame's inlier count and the planarity of its points."""
        with self._lock:
            self._inliers.append(inliers)
            self._planar = (planar, condition_number)

    def frontend_ran(self, correspondences: int, seconds: float) -> None:
        """Record a front-end run: the correspondences it made and its time (s)."""
        with self._lock:
            self._stages["frontend"].append(seconds)
            self._counts["frontend_runs"] += 1
            self._counts["frontend_points"] += correspondences
            self._frontend_last = correspondences

    def snapshot(self) -> StatsSnapshot:
        """A consistent copy of every counter."""
        with self._lock:
            return StatsSnapshot(
                counts=dict(self._counts),
                inliers=list(self._inliers),
                planar=self._planar[0],
                condition_number=self._planar[1],
                frontend_last=self._frontend_last,
                stage_times={k: list(d) for k, d in self._stages.items()},
            )


@dataclass(frozen=True)
class FusedOutput:
    """The twist / odom of an earlier frame, final now: ``source`` has the frame's pose and
    covariance and its fused twist and covariance (in ``frame_id``: the camera's or, with
    ``base_frame``, the robot's), stamped ``stamp_ns`` (the frame's output stamp)."""

    stamp_ns: int
    source: PoseWithCovariance
    frame_id: str


def fused_outputs(
    fused: list, frame_id: str | None = None, mounting: Any = None
) -> list[FusedOutput]:
    """twist / odom of the frames whose fused state is final, a camera's or a rig's alike
    (:class:`~rs_localizer.tracking.localizer.FusedPose` s): each frame's own pose (as
    published) with its fused twist and their covariances, stamped with the frame's time, in
    ``frame_id`` (None: each frame's tag, the camera's frame); ``mounting``: the camera's
    :class:`~rs_localizer.frames.Mounting` on the robot, each frame moved to ``frame_id``
    (:func:`~rs_localizer.frames.camera_to_base`; None: as it is)."""
    out = []
    for f in fused:
        src: PoseWithCovariance = f if mounting is None else camera_to_base(f, mounting)
        frame = cast(str, f.tag) if frame_id is None else frame_id  # (a tag is a frame_id)
        out.append(FusedOutput(f.pose.stamp_ns, src, frame))
    return out
