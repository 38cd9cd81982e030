"""The localizer's per-frame pipeline, without ROS: what ``rs_localizer_node`` does with each
frame, and what ``rs-localizer replay`` does with each frame of a bag.

:class:`FramePipeline` takes a frame message (``sensor_msgs/PointCloud2`` correspondences or
keypoints, ``sensor_msgs/Image`` or ``CompressedImage``; rclpy or rosbags messages, which have
the same fields) and returns a :class:`FrameResult`. The camera's input stage
(:class:`.camera_input.CameraInput`, each rig camera's too) checks its stamp (once) and an
empty cloud, notes the stamp on the video's clock (a time reset: counted, logged, the
camera_infos stamped after it forgotten), gives the camera model of the frame's stamp (fed by
:meth:`FramePipeline.add_camera_info`) and makes the frame: the image decoded, or the 2D-3D
rows (cloud or landmark lookup) without the non-finite ones and capped to ``max_points``; then
the camera's video state, :class:`~rs_localizer.tracking.sequence.SequenceLocalizer` (the
library's video entry point: the gyro samples fed by :meth:`FramePipeline.add_imu`, the gyro
measurement of the frame's readout when ``imu.enabled``, the online gyro bias, the check of the
gyro against the image, the video tracker with ``tracking.enabled`` or else each frame alone;
a cloud's frame goes to its rig of one as a rig camera's frame goes to its rig,
:meth:`.camera_input.CameraInput.step`, an image through the front end first), and what is to be
published: the pose and the frame's own twist, and the fused twists that became final (a frame
``tracking.lag`` frames back). :mod:`.outputs` turns a result into messages. Counters for the
diagnostics are kept in :attr:`FramePipeline.stats`. No module-level ROS import.
"""

from __future__ import annotations

import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from ..camera import CameraModel
from ..correspondences import Correspondences
from ..estimation.result import RSPoseEstimate
from ..frames import camera_to_base
from ..frontends.shared import LoadedMaps
from ..pose import PoseWithCovariance
from ..runtime.background import ready_implementation
from ..tracking.gyro import ImuBuffer
from ..tracking.gyro_bias import GyroBiasEstimator
from ..tracking.gyro_check import GyroMountCheck
from ..tracking.gyro_input import GyroReadouts
from ..tracking.sequence import FusedPose, SequenceLocalizer, SequenceSettings
from . import conversions as cv
from .camera_input import CameraCounts, CameraInput, DroppedFrame, ImageFrame
from .config import LocalizerConfig

__all__ = [
    "FRAME_KINDS",
    "FramePipeline",
    "FrameResult",
    "FusedOutput",
    "MapFitCheck",
    "PipelineStats",
    "StatsSnapshot",
    "ThrottledLog",
    "fused_outputs",
    "log_warm_up",
    "take_imu_message",
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


def take_gyro_sample(msg: Any, add: Callable[[int, Any], str | None]) -> str | None:
    """A ``sensor_msgs/Imu``'s gyro sample handed on, for one camera and a rig alike: its
    stamp (ns) and angular velocity ``(x, y, z)`` (rad/s, the IMU's frame;
    :func:`.conversions.gyro_sample`) to ``add``, which returns None or why it rejected the
    sample; a message without a usable sample: its reason (``no_angular_velocity``,
    ``bad_stamp``). Returns None or the reason (counted ``imu_rejected.<reason>``)."""
    try:
        stamp, omega = cv.gyro_sample(msg)
    except cv.ImuError as e:
        return e.reason
    return add(stamp, omega)


def take_imu_message(
    msg: Any, video: GyroReadouts, count: Callable[[str], Any], warn: Callable[[str, str], Any]
) -> str | None:
    """The gyro sample of a ``sensor_msgs/Imu`` buffered by a camera's video (``video``: its
    :class:`~rs_localizer.tracking.sequence.SequenceLocalizer`, or its rig of one's
    :class:`~rs_localizer.tracking.video.Localizer`; :func:`take_gyro_sample`). Returns
    None, or the reason it was rejected: ``disabled`` (no gyro: nothing counted), else
    counted ``count("imu_rejected")`` and ``count("imu_rejected.<reason>")`` and warned
    ``warn("imu.<reason>", text)``; a buffered sample that this one shows to have been a
    lone stamp jump ahead (dropped from the buffer) likewise as ``stamp_jumped_ahead``."""
    buf = video.imu
    if buf is None:
        return "disabled"
    dropped = buf.dropped
    reason = take_gyro_sample(msg, video.add_imu)
    for why in ([reason] if reason is not None else []) + ["stamp_jumped_ahead"] * (
        buf.dropped - dropped
    ):
        count("imu_rejected")
        count(f"imu_rejected.{why}")
        warn(f"imu.{why}", f"IMU sample rejected ({why})")
    return reason


class _Drop(ValueError):
    """A frame dropped by an input stage: ``reason`` is counted as ``failed.<reason>``."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


def _taken(value):
    """``value`` of a :class:`.camera_input.CameraInput` step, raising :class:`_Drop` (its
    reason and text) for a :class:`.camera_input.DroppedFrame`."""
    if isinstance(value, DroppedFrame):
        raise _Drop(value.reason, str(value.error))
    return value


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


@dataclass
class FrameResult:
    """What became of one frame.

    Attributes:
        failure: None when solved, else the reason it was dropped (``failed.<reason>``), with
            ``detail`` (the log text).
        stamp_ns: the input header stamp (ns); out_stamp_ns: the reference line's time, the
            stamp of the outputs. frame_id: the camera optical frame of the outputs.
        camera: the camera model used. points2d (N, 2) px, points3d (N, 3) m: the estimator's
            input rows (after the cap).
        estimate: the :class:`~rs_localizer.estimation.RSPoseEstimate` (camera frame).
        output, output_frame: what pose / twist_single_frame / pose_with_covariance / tf
            describe: the estimate, or with ``base_frame`` the robot base's state.
        twist_now: twist / odom of this frame carry its own twist (no tracking, or a
            global-shutter solver or timing); else they come with :attr:`fused` later.
        fused: twist / odom of earlier frames that became final with this one (also on a
            failed frame).
        image: ``(array, encoding, stamp_ns)`` of a decoded input image.
        correspondences: the :class:`~rs_localizer.correspondences.Correspondences` the front
            end made of the image (with ``republish_correspondences``).
        times: s per stage (``decode``, ``frontend``, ``estimate``) of a frame that reached the
            estimator (``frontend`` alone for one the front end dropped).
        compiled: the frame was solved with the compiled kernels (False: on the uncompiled
            path while they compile, :mod:`rs_localizer.estimation.numpy_impl`).
    """

    failure: str | None = None
    detail: str = ""
    compiled: bool = True
    stamp_ns: int | None = None
    out_stamp_ns: int | None = None
    frame_id: str = ""
    camera: CameraModel | None = None
    points2d: np.ndarray | None = None
    points3d: np.ndarray | None = None
    estimate: RSPoseEstimate | None = None
    output: PoseWithCovariance | None = None
    output_frame: str = ""
    twist_now: bool = False
    fused: list[FusedOutput] = field(default_factory=list)
    image: tuple | None = None
    correspondences: Correspondences | None = None
    times: dict[str, float] = field(default_factory=dict)

    @property
    def solved(self) -> bool:
        """The frame has a pose (no failure)."""
        return self.failure is None


class FramePipeline:
    """The per-frame pipeline of the localizer (see the module docstring).

    Args:
        config: the :class:`~rs_localizer.ros.config.LocalizerConfig` of one camera (its
            :attr:`~rs_localizer.ros.config.LocalizerConfig.camera`; None: set it with
            :meth:`configure` before the first frame).
        maps: the landmarks and the front end loaded for ``config`` (:func:`~.config.load_maps`;
            None: none).
        log: :class:`ThrottledLog` (or a logger it wraps) for the warnings.
        stopped: ``stopped()`` true ends a frame's wait for its camera_info or gyro samples
            (shutdown).
        imu_span: seconds of gyro samples kept (default ``imu.buffer``; ``inf`` for a bag
            replayed offline, whose samples are all added before its frames).

    Threads: :meth:`process` on one thread at a time (the node's worker); camera_infos,
    :meth:`flush_idle`, :meth:`configure` and the diagnostics from others.
    """

    def __init__(
        self,
        config: LocalizerConfig | None = None,
        log: Any = None,
        stopped: Callable[[], bool] = lambda: False,
        imu_span: float | None = None,
        maps: LoadedMaps | None = None,
    ):
        self.log = log if isinstance(log, ThrottledLog) else ThrottledLog(log)
        self.stats = PipelineStats()
        #: the camera's camera_infos, the model of a frame's stamp, its rows, its image
        self.camera_input = CameraInput(self.log, self.stats.add, stopped=stopped)
        # (the map-fit check: (refused, reason, correspondences) of the last frames with many)
        self._map_fit = MapFitCheck()
        self._config: LocalizerConfig | None = None
        # the camera's video state: tracker, fused twists pending, gyro, bias, gyro check
        # (frames on the NumPy implementation while the kernels compile in the background)
        self.sequence = SequenceLocalizer(
            log=self.log,
            count=self.stats.add,
            stopped=stopped,
            imu_span=imu_span,
            implementation=ready_implementation,
        )
        self.maps = LoadedMaps()
        if config is not None:
            self.configure(config, maps)

    @property
    def config(self) -> LocalizerConfig | None:
        """The configuration frames are processed with."""
        return self._config

    def configure(self, config: LocalizerConfig, maps: LoadedMaps | None = None) -> None:
        """Use ``config`` and the ``maps`` loaded for it (:func:`~.config.load_maps`; None: no
        landmarks, no front end) from the next frame on; the camera models of the camera_infos
        received so far are rebuilt with its rolling-shutter timing (one it rejects is dropped
        and logged), the video state keeps what still applies
        (:meth:`~rs_localizer.tracking.sequence.SequenceLocalizer.configure`)."""
        self._config = config
        self.maps = maps if maps is not None else LoadedMaps()
        self.sequence.configure(
            SequenceSettings(
                solver=config.solver,
                options=config.options,
                tracking=config.tracking,
                imu=config.imu,
                stamp_row=config.stamp_row,
                time_reset_ns=config.time_reset_ns,
                max_points=config.max_points,
            )
        )
        cam = config.camera
        self.sequence.set_frontend(self.maps.frontend, cam.frontend_kind)
        self.camera_input.configure(
            cam.camera_from_info,
            config.max_points,
            cam.fallback,
            config.camera_info_wait,
            self.maps.landmarks,
            cam.frame,
        )

    @property
    def imu(self) -> ImuBuffer | None:
        """The gyro samples (``imu.enabled``), else None."""
        return self.sequence.imu

    @property
    def gyro_bias(self) -> GyroBiasEstimator | None:
        """The online gyro-bias estimate (``imu.estimate_bias``), else None."""
        return self.sequence.gyro_bias

    @property
    def gyro_check(self) -> GyroMountCheck | None:
        """The check of the gyro against the image (``imu.enabled``), else None."""
        return self.sequence.gyro_check

    @property
    def gyro_inconsistent(self) -> bool:
        """True while the rotation between solved frames contradicts the gyro and frames are
        solved without it (``imu.enabled``)."""
        return self.sequence.gyro_inconsistent

    def gyro_bias_values(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The gyro bias the frames use and its standard deviation per axis ((3,), (3,) rad/s,
        IMU frame): the online estimate with ``imu.estimate_bias``, else ``imu.gyro_bias``
        and ``imu.gyro_bias_sigma``; None without ``imu.enabled``."""
        if self._config is None:
            return None
        return self.sequence.gyro_bias_values()

    def camera_source(self) -> str:
        """Where the intrinsics come from: ``camera_info``, ``parameters`` (fallback) or
        ``missing`` (:meth:`.camera_input.CameraInput.source`)."""
        return self.camera_input.source()

    # ---------------------------------------------------------------- camera_info
    def add_camera_info(self, msg: Any) -> CameraModel | None:
        """Validate a ``sensor_msgs/CameraInfo`` and add it to the history the frames pick
        their camera from by stamp. Returns its camera model, or None when it is rejected
        (counted as ``camera_info_rejected.<reason>`` and logged; the previous cameras stay):
        :meth:`.camera_input.CameraInput.add_camera_info`."""
        return self.camera_input.add_camera_info(msg)

    # ---------------------------------------------------------------- gyro
    def add_imu(self, msg: Any) -> str | None:
        """Buffer the gyro sample of a ``sensor_msgs/Imu`` (rclpy or rosbags). Returns None, or
        the reason it was rejected, counted as ``imu_rejected.<reason>``: ``disabled``
        (``imu.enabled`` false: nothing counted), ``no_angular_velocity`` (covariance[0] = -1,
        the message's "no data"), ``bad_stamp`` and the reasons of
        :meth:`~rs_localizer.tracking.gyro.ImuBuffer.add` (a stamp going back or repeated,
        NaN or saturated rates). A buffered sample that this one shows to have been a lone
        stamp jump ahead (dropped from the buffer) is counted as
        ``imu_rejected.stamp_jumped_ahead``."""
        return take_imu_message(msg, self.sequence, self.stats.add, self.log.warning)

    # ---------------------------------------------------------------- frames
    def process(self, msg: Any, kind: str, stamp: Any = None) -> FrameResult:
        """One frame through the pipeline (see the module docstring). ``kind``: one of
        :data:`FRAME_KINDS`; ``stamp``: the message's :meth:`.camera_input.CameraInput.check`
        when it was checked as it arrived (the node's queue), None: checked here. Never
        raises: a dropped frame's result has ``failure`` and ``detail`` set (an unexpected
        exception: ``internal_error``)."""
        res = FrameResult()
        try:
            self._run(msg, kind, res, stamp)
        except _Drop as e:
            res.failure, res.detail = e.reason, str(e)
        except Exception as e:  # (a defect: this frame is dropped, the next ones go on)
            drop = _Drop("internal_error", f"{type(e).__name__}: {e}")
            res.failure, res.detail = drop.reason, str(drop)
        return res

    def _run(self, msg: Any, kind: str, res: FrameResult, checked: Any = None) -> None:
        """Fill ``res``; raises :class:`_Drop` for a dropped frame."""
        tic = time.perf_counter()
        cfg = self._config
        inp = self.camera_input
        res.frame_id = inp.tag_of(msg)
        stamp = _taken(inp.check(msg, kind) if checked is None else checked)
        res.stamp_ns = stamp
        inp.note_time(stamp, self.sequence.check_time)  # (a time reset: counted, logged)
        camera = _taken(inp.camera_of(stamp))
        res.camera = camera
        # (the frame's entry checks, a rig camera's too: its times, made once and taken as
        # they are from here on, its output stamp in range, an image with a front end)
        frontend = self.sequence.frontend is not None
        ft = _taken(inp.admit(kind, stamp, camera, self.sequence.frame_time, frontend))
        res.out_stamp_ns = ft.reference_ns
        # (as a rig camera's frame: to the camera's rig of one, CameraInput.step; an image
        # through its front end first)
        item, outs, t_decoded = inp.step(
            self.sequence.rig, msg, kind, stamp, camera, ft.reference_ns
        )
        _taken(item)
        if isinstance(item, ImageFrame):
            res.image = (item.image, item.encoding, stamp)
            out = self.sequence.image_output(ft, outs)
            self._frontend_ran(out, cfg, res)
            uv, xyz = out.points2d, out.points3d
            t_decoded += out.frontend_seconds
        else:
            uv, xyz = item.points2d, item.points3d
            out = self.sequence.output_of(outs[0])
        res.points2d, res.points3d = uv, xyz
        res.compiled = out.compiled
        self.stats.add("frames_compiled" if out.compiled else "frames_uncompiled")
        t_estimated = time.perf_counter()
        t_frontend = out.frontend_seconds
        res.times = {  # (the wait for the gyro samples counts as decoding, as for camera_info)
            "decode": t_decoded - tic - t_frontend + out.gyro_seconds,
            "frontend": t_frontend,
            "estimate": t_estimated - t_decoded - out.gyro_seconds,
        }
        res.fused = self._fused_outputs(out.fused, cfg)
        est = out.estimate
        if est is None:
            raise _Drop("estimator_error", out.error or "no estimate")
        self.stats.add("points_dropped", int(est.num_dropped))
        res.estimate = est
        self._map_fit.check(len(uv), est, self.stats, self.log.warning)
        if not est.success:
            raise _Drop(
                est.failure or "estimator_error",
                f"{len(uv)} points, {est.num_inliers} inliers, solver {cfg.solver}",
            )
        self.stats.solved(est.num_inliers, est.planar, est.condition_number)
        if est.few_points:
            self.stats.add("frames_few_points")
        if est.single_tag:
            self.stats.add("frames_single_tag")
        res.output, res.output_frame = est, res.frame_id
        if cfg.camera.mount is not None:
            res.output, res.output_frame = camera_to_base(est, cfg.camera.mount), cfg.base_frame
        res.twist_now = out.twist_now
        self.stats.stage_time("decode", res.times["decode"])
        self.stats.stage_time("estimate", res.times["estimate"])

    def map_fit_text(self) -> str:
        """The map-fit warning for the current window (:meth:`MapFitCheck.text`)."""
        return self._map_fit.text()

    def _frontend_ran(self, out: Any, cfg: LocalizerConfig, res: FrameResult) -> None:
        """Account for the front end's run on an image frame (its correspondences to
        republish with ``republish_correspondences``); raises :class:`_Drop` for a frame it
        dropped."""
        found = out.correspondences
        if found is None:  # (the front end raised)
            raise _Drop(out.failure, out.detail)
        res.times["frontend"] = out.frontend_seconds
        uv = found.points2d
        self.stats.frontend_ran(len(uv), out.frontend_seconds)
        if cfg.republish_correspondences:
            res.correspondences = Correspondences(uv, found.points, found.ids, found.valid_scores())
        if out.failure is not None:
            raise _Drop(out.failure, out.detail)

    # ---------------------------------------------------------------- tracking
    def drop_tracker(self) -> None:
        """End the track (e.g. the node is deactivated): the twists still pending are
        dropped; the next frame starts a new track."""
        self.sequence.end_track()

    def _fused_outputs(self, fused: list[FusedPose], cfg: LocalizerConfig) -> list[FusedOutput]:
        """twist / odom of the frames whose fused state is final (:func:`fused_outputs`: in
        the camera's frame, or with its mounting the robot's ``base_frame``)."""
        if cfg.camera.mount is None:
            return fused_outputs(fused)
        return fused_outputs(fused, cfg.base_frame, cfg.camera.mount)

    def flush_idle(self, now: float | None = None) -> list[FusedOutput]:
        """After ``tracking.max_gap`` s (wall clock) without frames the track is over (the
        next frame resets it): the twists still pending, now final."""
        cfg = self._config
        if cfg is None:
            return []
        return self._fused_outputs(self.sequence.flush_idle(now), cfg)

    def flush(self) -> list[FusedOutput]:
        """The end of the input (a bag): the twists still pending, as they are now."""
        if self._config is None:
            return []
        return self._fused_outputs(self.sequence.flush(), self._config)

    def tracking_values(self) -> dict[str, Any]:
        """Diagnostics of video tracking: track_state (tracking, lost or disabled),
        frames_tracked, relocalizations, resets, twists_own_frame, twists_implausible (over the
        pipeline's life)."""
        if self._config is None:
            return {**self.sequence.tracking_values(), "track_state": "disabled"}
        return self.sequence.tracking_values()
