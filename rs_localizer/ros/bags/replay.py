"""Offline replay: the localizer node over every frame of a bag, without middleware; a camera's
bag, or a rig bag's cameras (a camera alone is a rig of one).

Both go through the rig mode as the rig node runs it, configured from the node's parameters
(:mod:`..params`; :mod:`..param_files`: defaults, then ROS 2 parameter files, then
overrides): a rig bag's cameras (:func:`~rs_localizer.ros.bags.bag_frames.is_rig_bag`) a rig
frame for a frame, a camera's bag as a rig of one camera (its frames solved as the camera's
video solves them, with the camera's parameters), so that a replay publishes what the node
would: the pose, the frame's own twist (``twist_single_frame``) and, with tracking (the
default), the fused twist on ``twist`` and ``odom`` when it is final. It is one run: the
bag's messages read once in log-time order, each camera_info to its camera's input, the
gyro's samples read first, each frame message through the rig node's frame step, each rig
frame published as the node publishes it (:class:`..outputs.FrameOutcome`); and the outputs
are written by one path (:mod:`.replay_out`): a bag (``/rs_localizer/<topic>``), a CSV (one
line per frame, :data:`.replay_out.CSV_COLUMNS`), the comparison with the bag's ground truth
(``/ground_truth/*``) when it has one and, with ``debug_outputs``, the node's visualization
topics in the output bag (``debug_image``, ``markers``, ``path``:
:mod:`rs_localizer.ros.visualization`; of a rig, ``<camera>/debug_image`` and
``<camera>/markers`` per camera), to open in Foxglove or RViz.
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import time
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np

from ...accuracy import GroundTruth
from ...frontends.shared import SHARED_MAPS, LoadedMaps
from ...tracking.localizer import readout_warning
from ...tracking.rig import offsets_text
from ..camera_input import DroppedFrame
from ..config import LocalizerConfig, build_config, default_timing_note, load_maps
from ..outputs import FrameOutcome, frame_outcome, outcome_messages, rig_frame_views
from ..param_files import parameter_values, read_params_file
from ..pipeline import MapFitCheck, fused_outputs
from .bag_frames import (
    QuietLog,
    camera_messages,
    frame_topic,
    is_rig_bag,
    rig_bag_config,
    rig_frontends,
    rig_kinds,
    rig_landmarks,
)
from .bag_io import (
    CAMERA_INFO,
    GT_POSE,
    IMAGE,
    IMU,
    OUT_TYPES,
    RigTopics,
    bag_connections,
    bag_topics,
    load_ground_truth,
    progress_bar,
    read_bag_info,
    rig_namespace,
    typestore,
)
from .replay_out import (
    BagImages,
    DebugWriter,
    ReplayRows,
    frame_row,
    open_out_bag,
    view_prefix,
    write_csv,
    write_messages,
)

if TYPE_CHECKING:
    from ...camera import FrameTime
    from ...estimation.result import RSPoseEstimate
    from ...tracking.video import Localizer, LocalizerOutput

__all__ = [
    "BAG_TIMING",
    "GYRO_AHEAD_NS",
    "ReplayResult",
    "camera_counts",
    "frame_outcome",
    "replay",
    "replay_parameters",
]

#: RS timing parameters a replay takes from the bag's ``sequence.json`` (``rs`` section, written
#: by make-bag and render-bag) when neither a parameter file nor an override sets them
#: (``rs.readout_time`` is not among them: with 0 the line delay is used, as recorded)
BAG_TIMING = ("rs.line_delay", "rs.direction", "rs.reference_row", "rs.stamp_row")


@dataclass
class ReplayResult:
    """Outcome of :func:`replay`, of a camera's bag or a rig bag (a rig frame for a frame):
    ``rows`` (one dict per frame, the CSV's columns, :class:`.replay_out.ReplayRows`), ``summary``
    (accuracy against ground truth, :func:`~rs_localizer.accuracy.summarize_errors` of the
    published pose and twist, with ``frame_fit``), ``failures`` (reason -> frames), the files
    written, the configuration (a camera's or a rig's
    :class:`~rs_localizer.ros.config.LocalizerConfig`) and parameter values used, the maps
    loaded for a camera (``maps``: the landmarks and the front end,
    :class:`~rs_localizer.frontends.shared.LoadedMaps`; None for a rig, whose cameras load
    their own), ``solver`` (the estimator's name), ``tracked`` (``twist`` carries the fused
    twist), and the counters (``counts``: a camera's, as the node's diagnostics name them
    (its frames are its rows, not counted here): its rows' (``points_dropped``, with the
    rows its estimator left out, ``capped_clouds``, ``unknown_landmark_ids``...), its
    estimator's (``frames_compiled`` / ``frames_uncompiled``, ``frames_few_points``,
    ``frames_single_tag``), its front end's (``frontend_runs``, ``frontend_points``),
    ``time_resets``,
    ``imu_rejected.<reason>``, the gyro's (``frames_with_gyro``, ``gyro_rejected``,
    ``gyro_disabled_inconsistent``, ``gyro_missing.<reason>``...) and the map-fit check's
    (``frames_failed_with_matches``, ``map_fit_doubtful``); a rig's gyro counts by the same
    names, with its IMU messages rejected as the rig node counts them, ``imu_rejected`` and
    ``imu_rejected.<reason>``, when any were), ``gyro_bias`` and ``gyro_bias_std`` ((3,) rad/s,
    IMU frame: the bias the last frame used, the online estimate with ``imu.estimate_bias``;
    None without ``imu.enabled``), ``readout`` (the tracking's values at the end of the video
    with the check of the rolling-shutter timing, ``readout_suspect``, ``readout_contradicted``:
    :meth:`~rs_localizer.tracking.video.Localizer.tracking_values`), ``notes`` (warnings for the
    user).

    A rig bag's replay also has (empty for a camera's):

    - ``cameras``: the cameras' names (rig order); ``camera_counts``: ``rig``, its rig frames'
      ``rig_frames``, ``solved``, ``failed``, ``skipped``, ``pending``; per camera its counts
      as the rig node's diagnostics count them (:func:`camera_counts`: received = solved +
      failed + skipped + pending, its rows', why its frames failed or were skipped);
    - ``own_twist``: the errors of each rig frame's own twist (``frames``, ``angvel``,
      ``linvel``); ``off_deg``: camera -> one entry per posed rig frame in which it disagreed
      with the others (the cameras' consensus outvoted it, or the rig names it as
      disagreeing), how far off it is: deg between its rotation posed alone and where the
      rig's pose and its mounting put it (NaN where it could not be posed alone;
      :meth:`~rs_localizer.tracking.video.Localizer.camera_off_deg`), summed up by
      :attr:`disagreeing`.

    Both have ``outputs``, every rig frame's
    :class:`~rs_localizer.tracking.video.LocalizerOutput` (a camera's: its rig of one's, of
    each frame that reached it, the camera's video: its ``estimate`` the camera's own,
    :attr:`~rs_localizer.tracking.video.LocalizerSettings.camera_video`; each camera frame
    tagged with its frame id, as the rig node tags it), and ``flushed``, the fused poses still
    pending at the end of the video.
    """

    rows: list = field(default_factory=list)
    summary: dict = field(default_factory=dict)
    failures: dict = field(default_factory=dict)
    out_bag: Path | None = None
    out_csv: Path | None = None
    config: LocalizerConfig | None = None
    maps: LoadedMaps | None = None
    parameters: dict = field(default_factory=dict)
    solver: str = ""
    tracked: bool = False
    counts: dict = field(default_factory=dict)
    gyro_bias: np.ndarray | None = None
    gyro_bias_std: np.ndarray | None = None
    #: warnings about the replay's set-up for the user (e.g. a default line delay on images)
    notes: list = field(default_factory=list)
    readout: dict = field(default_factory=dict)
    cameras: tuple = ()
    camera_counts: dict = field(default_factory=dict)
    own_twist: dict = field(default_factory=dict)
    off_deg: dict = field(default_factory=dict)
    outputs: list = field(default_factory=list)
    flushed: list = field(default_factory=list)

    @property
    def solved(self) -> int:
        """Frames (rig frames) with a pose."""
        return sum(1 for r in self.rows if r["success"])

    @property
    def disagreeing(self) -> dict:
        """camera -> ``{"rig_frames": N, "median_deg": X}`` for each camera of a rig that
        disagreed with the others in N posed rig frames, X the median of :attr:`off_deg`, deg
        (NaN: never posed alone)."""
        return {
            n: {
                "rig_frames": len(d),
                "median_deg": float(np.nanmedian(d)) if np.isfinite(d).any() else float("nan"),
            }
            for n, d in self.off_deg.items()
        }


def replay_parameters(
    path: str | os.PathLike,
    params_files: Iterable[str | os.PathLike] = (),
    params: Mapping[str, Any] | None = None,
    source: str | None = None,
) -> tuple[dict[str, Any], list[str]]:
    """The node parameter values of a replay of the bag ``path``: the defaults, then
    ``params_files`` in order (ROS 2 parameter files, as ``--params-file`` gives them to the
    node), then ``params`` (overrides by parameter name). Then, for what none of them sets: the
    :data:`BAG_TIMING` values of the bag's ``sequence.json``, and with ``source`` keypoints the
    bag's ``landmarks.csv`` as ``landmarks_file``. Returns ``(values, ignored file entries)``.

    Raises:
        ConfigError (a ValueError): see :func:`..param_files.parameter_values`.
    """
    params_files = list(params_files)
    values, ignored = parameter_values(params_files, params)
    given = set(params or {}).union(*(read_params_file(f) for f in params_files))
    rs = read_bag_info(Path(path)).get("rs", {})
    for name in BAG_TIMING:
        key = name.split(".", 1)[1]
        if name not in given and rs.get(key) is not None:
            values[name] = str(rs[key]) if name == "rs.direction" else float(rs[key])
    if source == "keypoints" and not values["landmarks_file"]:
        values["landmarks_file"] = str(Path(path) / "landmarks.csv")
    return values, ignored


def _timing_given(path: Path, params_files: list, params: Mapping[str, Any] | None) -> bool:
    """Whether the parameters (files or overrides) or the bag's ``sequence.json`` set the RS
    timing (``rs.line_delay`` or ``rs.readout_time``)."""
    given = set(params or {}).union(*(read_params_file(f) for f in params_files))
    rs = read_bag_info(Path(path)).get("rs", {})
    from_bag = rs.get("line_delay") is not None or rs.get("readout_time") is not None
    return bool(given & {"rs.line_delay", "rs.readout_time"}) or from_bag


def _imu_mount_note(cfg: LocalizerConfig, info: dict) -> str | None:
    """A note when the bag's ``sequence.json`` (make-bag, render-bag) gives the IMU's mount
    (``imu.rotation_imu_from_camera``) and ``imu.rotation`` differs from it by over 1 deg:
    the gyro would contradict the image (a wrong mount), and the frames be solved without it."""
    R_imu_cam = info.get("imu", {}).get("rotation_imu_from_camera")
    if cfg.imu is None or R_imu_cam is None:
        return None
    from ...geometry import rotation_angle_deg
    from ..conversions import quaternion_from_matrix

    R = np.asarray(R_imu_cam, float).T  # (IMU -> camera optical frame, as imu.rotation)
    if rotation_angle_deg(R, np.asarray(cfg.imu.R_cam_imu, float)) <= 1.0:
        return None
    q = ", ".join(f"{v:.6g}" for v in quaternion_from_matrix(R, orthonormal=True))
    return (
        f"the bag's sequence.json gives the IMU's mount, imu.rotation:=[{q}], and imu.rotation "
        "differs from it: the gyro will contradict the image and frames be solved without it "
        f'(pass -p "imu.rotation:=[{q}]")'
    )


def replay(
    path: str | os.PathLike,
    *,
    params_files: Iterable[str | os.PathLike] = (),
    params: Mapping[str, Any] | None = None,
    source: str | None = None,
    out_bag: str | os.PathLike | None = None,
    out_csv: str | os.PathLike | None = None,
    storage: str = "mcap",
    progress: TextIO | None = sys.stderr,
    overwrite: bool = False,
    debug_outputs: bool = False,
    path_length: int = 1000,
    image_topic: str | None = None,
    imu_topic: str | None = None,
    log: Any = None,
    compile_note: TextIO | None = None,
) -> ReplayResult:
    """Run the localizer node over every frame of a bag, offline, through the rig mode
    (:class:`_Run`): a rig bag's cameras
    (:func:`~rs_localizer.ros.bags.bag_frames.is_rig_bag`: ``make-bag --rig``, ``render-bag
    --rig``, or a recording with ``rig.cameras`` in the parameters), a rig frame for a frame;
    a camera's bag as a rig of one camera, a frame for a frame.

    Args:
        path: bag directory (make-bag or render-bag output, or a recording), or its storage
            file (then its directory is read, with its sequence.json).
        params_files: the node's ROS 2 parameter files (later ones win; see
            :func:`..param_files.read_params_file` for the sections read; a rig bag's own
            ``rig_params.yaml`` comes first).
        params: overrides by parameter name (``{"solver": "p3p", "tracking.enabled": False}``).
            A camera's RS timing and keypoints' landmarks that nothing sets come from the bag
            (:func:`replay_parameters`).
        source: a camera's frames: ``correspondences`` (``*/correspondences``), ``keypoints``
            (``*/keypoints`` + ``landmarks_file``) or ``image`` (an image topic through the
            front end of the ``frontend`` parameter); None: ``image`` when ``frontend`` is not
            ``none``, else ``correspondences``. (A rig's cameras: their images with a front
            end, else their correspondences and, with ``landmarks_file``, keypoints.)
        out_bag: write the outputs here (``/rs_localizer/pose``, ``twist``,
            ``twist_single_frame``, ``pose_with_covariance``, ``odom``: the node's messages,
            each logged at the bag time of the frame that made it final; a rig frame's at its
            time). out_csv: one line per frame (:data:`.replay_out.CSV_COLUMNS`: the pose, the
            twist on ``twist`` and the frame's own twist, errors against ground truth). storage:
            ``mcap`` or ``sqlite3``.
        debug_outputs: (needs ``out_bag``) add, for every solved frame,
            ``/rs_localizer/debug_image`` (stamped like the input frame, drawn on the input
            image in image mode, else on the bag's image of the same stamp on ``image_topic``
            -- default: its ``sensor_msgs/Image`` topic in the frame topic's namespace, else
            the first one -- or on a blank canvas), ``/rs_localizer/markers`` and
            ``/rs_localizer/path`` (the last ``path_length`` poses), as the node publishes them;
            of a rig, ``path`` and per camera ``<camera>/debug_image`` (on the bag's
            ``<namespace>/<camera>/image_raw`` of its stamp) and ``<camera>/markers``, the
            camera as the rig's pose and its mounting put it, as the rig node draws them.
        image_topic: with ``source`` image the frames' topic (default: the bag's image topic,
            as ``sequence.json`` names it).
        imu_topic: with ``imu.enabled`` the ``sensor_msgs/Imu`` topic whose gyro the frames
            use (default: the bag's only IMU topic; a rig's ``<namespace>/imu``); all its
            samples are buffered first.
        progress: stream for the progress bar (None: none). log: logger (``info``,
            ``warning``) for a camera's warnings, worded and throttled as the camera node's
            (None: silent); of a rig bag, a frame whose step raised.
        compile_note: stream on which to say, before the first frame, that the kernels the
            frames run on are not in numba's cache and compile on it
            (:func:`~rs_localizer.runtime.background.cold_compile_note`; None: not said).

    A frame whose step raises (a defect) fails as in the node: its row (a camera's bag)
    or its camera's count ``failed.internal_error`` (a rig bag's), the exception logged, and
    the replay goes on.

    Raises:
        ValueError: no frame topic for ``source``; ``debug_outputs`` without ``out_bag``;
            ``imu.enabled`` without one IMU topic (or ``imu_topic`` not one); ``source``,
            ``image_topic`` or ``imu_topic`` for a rig bag; invalid parameters (a
            :class:`~rs_localizer.ros.params.ConfigError`; for a rig also a front end for a
            bag without camera images).
        FileExistsError: ``out_bag`` exists and not ``overwrite``.
    """
    path = Path(path)
    if path.is_file() and (path.parent / "metadata.yaml").is_file():
        path = path.parent  # BAG/BAG.mcap: the bag directory, with its sequence.json
    params_files = list(params_files)
    if debug_outputs and out_bag is None:
        raise ValueError("debug outputs need an output bag (--out)")
    if is_rig_bag(path, params_files, params):
        given = [n for n, v in (("source", source), ("image_topic", image_topic),
                                ("imu_topic", imu_topic)) if v is not None]  # fmt: skip
        if given:
            raise ValueError(f"{', '.join(given)}: not for a rig bag (its cameras' topics are "
                             "<namespace>/<camera>/..., its gyro's <namespace>/imu)")  # fmt: skip
        run = _Run.of_rig_bag(path, params_files, params, log)
    else:
        run = _Run.of_camera_bag(path, params_files, params, source, image_topic, imu_topic,
                                 debug_outputs, log)  # fmt: skip
    if compile_note is not None:
        from ...runtime.background import cold_compile_note
        from ..pipeline import config_kernels

        cold_compile_note(config_kernels(run.cfg), compile_note)
    result = run.result
    ts = typestore()
    gt = load_ground_truth(path) if GT_POSE in run.bag_topics else GroundTruth()
    writer, conns = None, {}
    if out_bag is not None:
        writer, conns = open_out_bag(Path(out_bag), storage, overwrite, ts)
        result.out_bag = Path(out_bag)
    viz = None
    if debug_outputs:
        images = BagImages(path, run.image_topics)
        viz = DebugWriter(writer, conns, ts, path_length, run.map_frame, run.views, images)
    rows = ReplayRows(gt)
    steps = run.steps(progress, viz is not None)
    try:
        for s in steps:
            posed = s.outcome.posed
            if s.row is not None:
                rows.add(s.row, *((posed.pose, posed.stamp_ns, posed.twist_now) if posed
                                  else (None, None, False)))  # fmt: skip
            rows.fused(s.outcome.fused)
            if writer is not None:
                messages = outcome_messages(s.outcome, run.map_frame, _WANTED)
                write_messages(writer, conns, ts, s.t_log, messages)
            if viz is not None and posed is not None and posed.views:
                viz.frame(s.t_log, s.estimate, posed)
    finally:
        steps.close()
        if viz is not None:
            viz.images.close()
        if writer is not None:
            writer.close()
    result.rows, result.failures, result.summary = rows.summary()
    run.finish(rows)  # (its counts, and its warnings of the video, e.g. the map-fit check's)
    bias = run.engine.gyro_bias_values()
    if bias is not None:
        result.gyro_bias, result.gyro_bias_std = bias
    result.readout = run.readout_values()
    if result.readout.get("readout_suspect") == "true":
        text = readout_warning(result.readout["readout_contradicted"], rig=bool(result.cameras))
        result.notes.append(text)
    if out_csv is not None:
        result.out_csv = Path(out_csv)
        write_csv(result.out_csv, result.rows)
    return result


@dataclass
class _Step:
    """What one frame (a camera's frame or a rig frame) gives the output path of
    :func:`replay`: its ``outcome`` as the node publishes it (:class:`..outputs.FrameOutcome`:
    the pose when posed, with its cameras' views for the debug outputs; the fused twists of
    earlier frames now final), logged at ``t_log`` (ns); its ``row``
    (:class:`.replay_out.ReplayRows`; None: the end of the video, only the fused twists still
    pending) and the ``estimate`` on the path."""

    t_log: int
    outcome: FrameOutcome
    row: dict | None = None
    estimate: RSPoseEstimate | None = None


#: the output topics a replay's bag holds (``tf`` is not among them)
_WANTED = OUT_TYPES.__contains__


class _Run:
    """The one run of :func:`replay`: a bag's cameras through the rig mode, as the rig node
    runs it, a rig bag's cameras (:meth:`of_rig_bag`) or a camera's bag as a rig of one camera
    named ``""`` (:meth:`of_camera_bag`). The IMU's samples are read first, then the bag's
    camera messages once, in log-time order
    (:func:`~rs_localizer.ros.bags.bag_frames.camera_messages`: each camera_info given to its
    camera's input), each frame message through the rig node's frame step (:meth:`frame`:
    :meth:`~rs_localizer.ros.camera_input.CameraInput.enter`: the entry checks, a frame they
    drop counted ``failed.<reason>``, then the camera's rows or image to the rig, a
    :class:`~rs_localizer.tracking.video.Localizer`), then the end of the video
    (:meth:`close`) and the fused twists still pending; each rig frame's :class:`_Step` from
    :meth:`steps`, published as the rig node publishes it (:func:`..outputs.outcome_messages`:
    its pose in ``map_frame``, its twists in :attr:`base_frame`).

    A camera's bag differs where a camera's frames do: each frame message is a row (also one
    dropped before its rig of one or skipped by it, with its reason; stamped with its header
    stamp), logged at its own log time; its IMU's samples are all buffered before the frames,
    in the bag's order; its outputs are moved to the robot's ``base_frame`` by
    ``camera_to_base.*`` when set (else in its frames' frame id).
    """

    #: a camera's bag: one row per frame message, logged at its log time (:meth:`of_camera_bag`)
    per_frame = False
    #: the outputs' frame (None: each frame's camera frame id) and the mounting that moves the
    #: rig's pose there (None: as it is)
    base_frame: str | None = None
    out_mount: Any = None

    @classmethod
    def of_rig_bag(cls, path: Path, params_files: list, params, log: Any = None) -> _Run:
        """A rig bag's cameras through the rig mode (:func:`replay`): configured from the
        parameters (:func:`~rs_localizer.ros.bags.bag_frames.rig_bag_config`: the defaults,
        the bag's ``rig_params.yaml``, ``params_files``, ``params``): the rig, each camera's
        input (:func:`~rs_localizer.ros.camera_input.rig_camera_inputs`) and front end.

        Each camera's frame message (its clouds; with a front end, ``frontend`` other than
        ``none``, its images ``<namespace>/<camera>/image_raw`` instead) takes the rig node's
        frame step, so that each camera's counts are the rig node's on the same messages
        (taken as they come, none dropped from a full queue). A gyro on the rig
        (``imu.enabled``) is read from ``<namespace>/imu``, its samples up to
        :data:`GYRO_AHEAD_NS` after a frame's stamp given to the rig before the frame. Each
        rig frame is logged at its time. A frame step that raises is the node's
        ``internal_error``, logged to ``log`` (:meth:`frame`).

        Raises:
            ~rs_localizer.ros.params.ConfigError: the parameters (e.g. a camera without
                mounting, no ``rig.cameras``, a front end whose map does not load), or a front
                end for a bag without camera images.
        """
        from ...tracking.video import Localizer
        from ..camera_input import rig_camera_inputs
        from ..pipeline import ThrottledLog

        run = cls()
        run.log = ThrottledLog(log)  # (a frame step's internal error, as the node logs it)
        values, _, cfg = rig_bag_config(path, params_files, params)
        run.path, run.cfg = path, cfg
        run.engine = rig = Localizer(cfg.settings)
        names = tuple(c.name for c in cfg.cameras)
        run._cameras({c.name: c.mount for c in cfg.cameras})
        ns = rig_namespace(path, names)
        run.imu_topic = f"{ns}/imu" if cfg.settings.imu is not None else None
        try:
            frontends = rig_frontends(cfg, owner=run)
            run.landmarks = rig_landmarks(cfg, owner=run)
        except BaseException:
            SHARED_MAPS.release(run)
            raise
        run.inputs = rig_camera_inputs(cfg, QuietLog(), run._count, landmarks=run.landmarks)
        for n, fe in (frontends or {}).items():  # (each camera's own, as the node runs them)
            rig.set_frontend(n, fe, str(values["frontend"]).strip())
        run.frontends = frontends is not None  # (images are read only with them)
        kinds = rig_kinds(run.inputs, run.frontends)
        run.topics = RigTopics(ns, names).of(("info", *kinds))
        run.total, run.unit = None, " rig frames"
        run.map_frame = str(values["map_frame"])
        run.base_frame = cfg.base_frame
        run.bag_topics = present = bag_topics(path)
        run.image_topics = {t: view_prefix(n) for t, (_, n) in RigTopics(ns, names).of(("image",))
                            .items() if t in present}  # fmt: skip
        run.result = ReplayResult(config=cfg, parameters=values, cameras=names,
                                  tracked=cfg.settings.tracking is not None)  # fmt: skip
        run.fit = MapFitCheck("rig frames")  # (the node's map-fit check, at the end)
        return run

    @classmethod
    def of_camera_bag(cls, path: Path, params_files: list, params, source, image_topic,
                      imu_topic, debug_outputs: bool, log: Any) -> _Run:  # fmt: skip
        """A camera's bag through the rig mode as a rig of one camera named ``""`` at the
        identity mounting (:func:`~rs_localizer.tracking.sequence.rig_of_one`: the camera's
        solver, estimator options, tracking, gyro, ``stamp_row``, ``time_reset_ns``,
        ``max_points``), configured from the node's parameters as the camera's node takes
        them (:func:`_replay_config`: ``camera.*`` and its camera_infos with the ``rs.*``
        timing, ``camera_frame``, ``camera_to_base.*``, ``imu.*``, the front end,
        ``landmarks_file``...); its topics found (:func:`_replay_topics`). The camera's input
        is the single camera's (:class:`~rs_localizer.ros.camera_input.CameraInput`: the
        frames it refuses dropped with their reasons, its stamps noted on its video's clock
        before their camera_info is looked up); its warnings and the gyro's to ``log``."""
        from ...tracking.gyro_input import GyroInput
        from ...tracking.sequence import SequenceSettings, rig_of_one
        from ...tracking.video import Localizer
        from ..camera_input import CameraInput
        from ..pipeline import ThrottledLog

        run = cls()
        run.per_frame = True
        values, cfg, maps, source = _replay_config(path, params_files, params, source)
        counted = bag_connections(path)  # (the bag's topics, read once)
        run.bag_topics = topics = {t: mt for t, (mt, _) in counted.items()}
        frames, info_topic, viz_topic, run.imu_topic = _replay_topics(
            path, topics, cfg, source, image_topic, imu_topic, debug_outputs)  # fmt: skip
        run.total, run.unit = counted[frames][1], "frame"
        run.topics = {frames: (source, "")}
        if info_topic is not None:
            run.topics[info_topic] = ("info", "")
        if cfg.imu is not None:
            # (offline every sample is buffered before the frames: no waiting)
            cfg = dataclasses.replace(cfg, imu=dataclasses.replace(cfg.imu, wait=0.0))
        run.path, run.cfg = path, cfg
        settings = rig_of_one(SequenceSettings(
            solver=cfg.solver, options=cfg.options, tracking=cfg.tracking, imu=cfg.imu,
            stamp_row=cfg.stamp_row, time_reset_ns=cfg.time_reset_ns, max_points=cfg.max_points,
        ))  # fmt: skip
        run.log = tlog = ThrottledLog(log)
        run._cameras(dict(settings.mounts))
        own = run.own[""]
        gyro = GyroInput(own.add, tlog, span=math.inf)  # (the camera's counts and wording)
        # (its warnings worded as the camera's: a time reset its input's alone)
        # (its camera named "": it speaks as the camera, LocalizerSettings.camera_video)
        run.engine = rig = Localizer(settings, tlog, gyro_input=gyro, count=own.add)
        run.landmarks = maps.landmarks
        inp = CameraInput(tlog, own.add, name="")
        cam = cfg.camera
        inp.configure(cam.camera_from_info, cfg.max_points, cam.fallback, 0.0, maps.landmarks,
                      cam.frame)  # fmt: skip
        run.inputs = {"": inp}
        if maps.frontend is not None:
            rig.set_frontend("", maps.frontend, cam.frontend_kind)
        run.frontends = maps.frontend is not None
        run.map_frame = cfg.map_frame
        if cam.mount is not None:
            run.base_frame, run.out_mount = cfg.base_frame, cam.mount
        run.image_topics = {viz_topic: ""} if viz_topic else {}
        run.result = ReplayResult(config=cfg, maps=maps, parameters=values, solver=cfg.solver,
                                  tracked=settings.tracking is not None)  # fmt: skip
        timing = None if _timing_given(path, params_files, params) else default_timing_note(cfg)
        for note in (timing, _imu_mount_note(cfg, read_bag_info(path))):
            if note is not None:
                run.result.notes.append(note)
        run.fit = MapFitCheck()
        return run

    def _cameras(self, mounts: dict) -> None:
        """The cameras' mountings (by name), the node's counts of each, their debug outputs'
        prefixes (:func:`.replay_out.view_prefix`)."""
        from ..camera_input import CameraCounts

        self.mounts = mounts
        names = tuple(mounts)
        self.views = tuple(view_prefix(n) for n in names)
        self.own = {n: CameraCounts(n) for n in names}  # (the node's counts of each)
        self.off_deg: dict[str, list] = {}
        self.t_log = 0

    def steps(self, progress: TextIO | None, views: bool) -> Iterator[_Step]:
        """Every frame's :class:`_Step` (each rig frame its cameras' frames complete, then
        those the end of the video closes), then the twists still pending at the end."""
        imu = self.imu_topic and camera_messages(self.path, {self.imu_topic: ("imu", "")}, {})
        self.start([msg for _, _, msg, _ in imu or ()])
        bar = progress_bar(progress, self.total, unit=self.unit)
        try:
            for kind, name, msg, t_log in camera_messages(self.path, self.topics, self.inputs):
                if kind != "info":
                    self.t_log = t_log
                    steps = self.frame(name, kind, msg, views)
                    yield from steps
                    bar.update(len(steps))
            steps, t_end, fused = self.close(views)
            yield from steps
            bar.update(len(steps))
            yield _Step(t_end, FrameOutcome(None, fused))
        finally:
            bar.close()
            SHARED_MAPS.release(self)  # (a rig's cameras' front ends and landmarks)

    def _count(self, name: str, key: str, n: int = 1) -> None:
        self.own[name].add(key, n)

    def start(self, imu: list) -> None:
        """The gyro's samples: a camera's all buffered now, in the bag's order (each rejected
        one counted ``imu_rejected.<reason>``: :func:`~rs_localizer.ros.pipeline.
        take_imu_message`); a rig's kept ``(stamp_ns, (wx, wy, wz))``, newest first (popped
        oldest first, :meth:`_gyro_to`), each message read as the rig node reads it
        (:func:`~rs_localizer.ros.conversions.gyro_sample`): one without an angular
        velocity or a readable stamp left out and counted ``imu_rejected.<reason>``
        (:meth:`_imu_rejected`)."""
        from .. import conversions as cv
        from ..pipeline import take_imu_message

        self.gyro: list = []
        self.imu_rejected: dict[str, int] = {}
        if self.per_frame:
            for msg in imu:
                take_imu_message(msg, self.engine, self.own[""].add, self.log.warning)
            return
        for msg in imu:
            try:
                self.gyro.append(cv.gyro_sample(msg))
            except cv.ImuError as e:
                self._imu_rejected(e.reason)
        self.gyro.sort(key=lambda x: x[0], reverse=True)

    def _imu_rejected(self, reason: str | None) -> None:
        """A rig's IMU message rejected for ``reason`` (None: taken), counted as the rig node
        counts it: ``imu_rejected`` and ``imu_rejected.<reason>``
        (:attr:`ReplayResult.counts`)."""
        if reason is not None:
            self.imu_rejected[reason] = self.imu_rejected.get(reason, 0) + 1

    def frame(self, name: str, kind: str, msg: Any, views: bool) -> list[_Step]:
        """A camera's frame message through its input to the rig, in the rig node's frame step
        (:meth:`~rs_localizer.ros.camera_input.CameraInput.enter`; a frame it drops counted
        ``failed.<reason>`` by the node alone; a camera's bag: its row), the gyro's samples up to
        :data:`GYRO_AHEAD_NS` after its stamp first: the steps of the rig frames it completes
        (a camera's bag: of its frame, also one dropped or skipped). A frame step that raises
        is a defect, as the node takes it: the frame failed (``internal_error``; a camera's
        bag: its row, a rig bag's camera: counted ``failed.internal_error``), logged with the
        exception, and the replay goes on."""
        own, inp = self.own[name], self.inputs[name]
        if not self.per_frame:  # (as the rig node: every message, taken at once; a camera's
            own.add("received")  # frames are its rows)
        stamp = inp.check(msg, kind)
        self._ft = None
        try:
            if not inp.rig and not isinstance(stamp, DroppedFrame):
                # (the single camera's stamp noted on its video's clock first: a time reset
                # acts before its camera_info is looked up)
                inp.note_time(stamp, self.engine.check_time)
            taken = inp.enter(self.engine, msg, kind, stamp, inp.camera_of(stamp),
                              self.frontends, self._gyro_to)  # fmt: skip
        except Exception as e:  # (as the node's worker: this frame failed, the next ones go on)
            self.log.warning("internal_error", inp.failed_text(e))
            taken = DroppedFrame(name, getattr(stamp, "stamp_ns", stamp), None, e, "internal_error")
        if isinstance(taken, DroppedFrame):
            if not self.per_frame:
                own.add(f"failed.{taken.reason}")
            return self._dropped(taken.stamp_ns, taken.reason)
        if isinstance(taken.item, DroppedFrame) and not inp.rig:  # (never given to its rig)
            return self._dropped(taken.item.stamp_ns, taken.item.reason)
        if self.per_frame and kind == "image":
            self._frontend_ran(name)
        if not taken.outs and self.per_frame:  # (its image skipped before the estimator)
            return self._dropped(taken.item.stamp_ns, self.engine.last_search(name).failure)
        return self._steps(taken.outs, views, taken)

    def _frontend_ran(self, name: str) -> None:
        """A camera's image searched by its front end: counted as its node counts it
        (``frontend_runs``, ``frontend_points``: the correspondences it found; not an image
        it found the previous one again or failed on)."""
        search = self.engine.last_search(name)
        if search is not None and search.found is not None:
            self.own[name].add("frontend_runs")
            self.own[name].add("frontend_points", len(search.found.points2d))

    def _dropped(self, stamp: int | None, reason: str) -> list[_Step]:
        """A camera's bag's frame that no rig frame poses: its failed row (its output stamp
        when its times were made); a rig bag's: nothing (its camera's counts have it)."""
        if not self.per_frame:
            return []
        out_stamp = None if self._ft is None else self._ft.reference_ns
        row = frame_row(stamp, out_stamp, False, reason, self.result.solver, None)
        return [_Step(self.t_log, FrameOutcome(), row)]

    def _gyro_to(self, ft: FrameTime) -> None:
        self._ft = ft  # (the frame's times, made once)
        while self.gyro and self.gyro[-1][0] <= ft.stamp_ns + GYRO_AHEAD_NS:  # (its readout's)
            self._imu_rejected(self.engine.add_imu(*self.gyro.pop()))

    def close(self, views: bool) -> tuple[list, int, list]:
        """The end of the video: the rig frames it closes, then the fused twists still
        pending, at the last rig frame's time (a camera's bag: its last message's)."""
        rig, result = self.engine, self.result
        tail = rig.close()
        result.flushed = rig.flush()
        steps = self._steps(tail, views)
        t_end = self.t_log if self.per_frame else (
            result.outputs[-1].stamp_ns if result.outputs else 0)  # fmt: skip
        return steps, t_end, fused_outputs(result.flushed, self.base_frame, self.out_mount)

    def _steps(self, outs: list, views: bool, taken: Any = None) -> list[_Step]:
        """The steps of rig frames ``outs`` (each camera frame tagged with its frame id, as
        the rig node tags it; ``taken``: the frame step that completed them, its time), each
        logged at its time (a camera's bag: at its frame message's), counted (:meth:`_counted`)
        and published (:meth:`_outcome`); how far off each camera of a posed one that
        disagrees with the others is, to :attr:`ReplayResult.off_deg`."""
        result, steps = self.result, []
        done = time.perf_counter()
        for o in outs:
            t, est = o.stamp_ns, o.estimate
            self._counted(o)
            failure = "" if o.success else (est.failure if est is not None else "error")
            stamp, ms, solver = t, None, est.solver if est is not None else ""
            if self.per_frame:  # (a camera's frame: its header stamp, its estimator's time)
                stamp, solver = o.frames[o.cameras[0]].stamp_ns, result.solver
                if not o.success:
                    failure = (est.failure if est is not None else None) or "estimator_error"
                ms = self._estimate_ms(taken, o, done)
            row = frame_row(stamp, t, o.success, failure, solver, est, o.num_points, ms)
            t_log = self.t_log if self.per_frame else t
            steps.append(_Step(t_log, self._outcome(o, views), row, est if o.success else None))
            result.outputs.append(o)
            off = [n for n in o.cameras if n in o.outvoted or n in o.disagreeing]
            for n in off if o.success else ():
                f = o.frames.get(n)
                deg = None if f is None else self.engine.camera_off_deg(o, f)
                self.off_deg.setdefault(n, []).append(math.nan if deg is None else deg)
        return steps

    def _counted(self, o: LocalizerOutput) -> None:
        """A rig frame's estimate counted: the estimator's name; a camera's counts as its node
        counts them (:meth:`~rs_localizer.tracking.video.LocalizerOutput.camera_counts`) and
        its map-fit check (:meth:`..pipeline.MapFitCheck.check`, warned); a rig's map-fit
        check (its counts are the rig's, its warning at the end)."""
        est = o.estimate
        if self.per_frame:
            for key, n in o.camera_counts():
                self.own[""].add(key, n)
        if est is None:
            return
        self.result.solver = self.result.solver or est.solver
        if self.per_frame:
            self.fit.check(o.num_points, est, self.own[""], self.log.warning)
        else:
            self.fit.update(o.num_points, est)

    def _outcome(self, o: LocalizerOutput, views: bool) -> FrameOutcome:
        """What a rig frame publishes (:func:`frame_outcome` in :attr:`base_frame`, moved
        there by :attr:`out_mount`) with, for the debug outputs (``views``), each camera's
        view (:func:`..visualization.rig_camera_views`; drawn on the bag's image of its
        stamp)."""
        seen = rig_frame_views(o, self.mounts) if views and o.success else ()
        return frame_outcome(o, self.base_frame, self.out_mount, seen)

    def _estimate_ms(self, taken: Any, o: Any, done: float) -> float | None:
        """ms, a camera's frame's estimator time: its frame step after its frame was taken
        (decoded, read), less its front end's search and the wait for its gyro samples."""
        if taken is None:
            return None
        search = self.engine.last_search(o.cameras[0]) if self.frontends else None
        front = search.seconds if search is not None else 0.0
        return (done - taken.taken_at - front - o.gyro_seconds) * 1e3

    def finish(self, rows: ReplayRows) -> None:
        """The counts and the warnings of the video into the result: a camera's counts (its
        input's, its gyro's, the map-fit check's, as the node's diagnostics name them); a
        rig's cameras' and the rig's counts, the gyro's, the rig frames' own twist, the
        cameras' disagreement and, as a note, each camera whose frames never join the others'
        at the end of the video (:meth:`~rs_localizer.tracking.video.Localizer.camera_apart`)."""
        result, rig = self.result, self.engine
        if self.per_frame:
            result.counts = self.own[""].counts()
        else:
            result.camera_counts = {"rig": rig.rig_counts()}
            for n in rig.cameras:
                result.camera_counts[n] = camera_counts(rig, n, self.own[n].counts(),
                                                        self.landmarks is not None)  # fmt: skip
            result.off_deg = self.off_deg
            result.own_twist = rows.own_twist()
            for n in rig.cameras:  # (as the rig node's diagnostics warn: frames_apart)
                apart = rig.camera_apart(n)
                if apart is not None:
                    offs = offsets_text(apart, quoted=False, unknown="offset unknown")
                    result.notes.append(
                        f"camera {n}: its frames never join the others' ({offs}): its clock "
                        f"or stamp offset is likely wrong (a constant offset: set "
                        f"rig.{n}.time_offset); its frames are posed alone only where the "
                        "rig's track agrees"
                    )
            if self.cfg.settings.imu is not None:
                result.counts = rig.gyro_counts()
                if self.imu_rejected:  # (as the rig node's diagnostics count them)
                    result.counts["imu_rejected"] = sum(self.imu_rejected.values())
                    result.counts.update(
                        {f"imu_rejected.{k}": v for k, v in sorted(self.imu_rejected.items())}
                    )
        if self.fit.doubtful:
            result.notes.append(self.fit.text())
        if self.cfg.unused_text:  # (a parameter file shared with cameras)
            result.notes.append(self.cfg.unused_text)

    def readout_values(self) -> dict:
        """The tracking's values, with the check of the cameras' rolling-shutter timing on
        the video (:meth:`~rs_localizer.tracking.video.Localizer.tracking_values`)."""
        return self.engine.tracking_values()


#: ns: a rig bag's replay feeds the gyro samples up to this after a frame's stamp before the
#: frame (a camera's frame arrives after its readout; the bag logs it at its stamp)
GYRO_AHEAD_NS = 50_000_000


def camera_counts(rig: Localizer, n: str, own: Mapping[str, int], keypoints: bool = False) -> dict:
    """Camera ``n``'s counts in a rig bag's replay, those of the rig node's diagnostics
    (:func:`~rs_localizer.ros.diagnostics.rig_camera_section` of the rig's counts and the
    node's ``own``, its :class:`~rs_localizer.ros.camera_input.CameraCounts`' counts) without
    the ``<n>.`` prefix: its frames' (received, solved, failed, skipped, pending), its rows'
    (``points_dropped``, ``capped_clouds``; with ``keypoints``, a replay with
    ``landmarks_file``, also ``unknown_landmark_ids``), then ``failed.<reason>`` for each
    reason the node failed its frames for before the rig (e.g. ``bad_stamp``: a stamp out of
    range) and ``skipped.<reason>`` for each reason it was skipped for (the node's and the
    rig's, e.g. ``bad_input``: clouds not read)."""
    from ..diagnostics import rig_camera_section
    from ..frame_queue import FRAME_ACCOUNTING

    section = rig_camera_section(rig, n, own)
    rows = ("points_dropped", "capped_clouds", *(("unknown_landmark_ids",) if keypoints else ()))
    out = {k: section[f"{n}.{k}"] for k in (*FRAME_ACCOUNTING, *rows)}
    why = (f"{n}.failed.", f"{n}.skipped.")
    out.update({k[len(n) + 1 :]: v for k, v in section.items() if k.startswith(why) and v})
    return out


def _replay_config(
    path: Path, params_files, params, source: str | None
) -> tuple[dict[str, Any], LocalizerConfig, LoadedMaps, str]:
    """A camera's replay's ``(parameter values, configuration, its maps loaded,
    source)``; ``source`` None becomes ``image`` with a front end, else ``correspondences``.

    Raises:
        ValueError: invalid parameters; ``source`` image without a front end.
    """
    values, _ = replay_parameters(path, params_files, params, source)
    token = object()
    try:
        cfg = build_config(values)
        maps = load_maps(cfg.camera, owner=token)
    finally:
        SHARED_MAPS.release(token)  # (maps keeps what it loaded)
    if source is None:
        source = "image" if maps.frontend is not None else "correspondences"
    if source == "image" and maps.frontend is None:
        raise ValueError("--source image needs a front end (the frontend parameter is none)")
    # (offline every camera_info before a frame has been read: no waiting)
    cfg = dataclasses.replace(cfg, camera_info_wait=0.0)
    return values, cfg, maps, source


def _replay_topics(
    path: Path,
    topics: dict[str, str],
    cfg: LocalizerConfig,
    source: str,
    image_topic: str | None,
    imu_topic: str | None,
    debug_outputs: bool,
) -> tuple[str, str | None, str | None, str | None]:
    """A camera's replay's bag topics ``(frames, camera_info, images to draw the
    debug image on or None, IMU or None)``.

    Raises:
        ValueError: no frame topic; ``imu.enabled`` without one IMU topic (or ``imu_topic``
            not one).
    """
    info = read_bag_info(path)
    prefer = (image_topic, info.get("topics", {}).get("image"))
    frames = frame_topic(topics, source, cfg.camera.image_transport == "compressed", prefer)
    info_topic = next((t for t, mt in topics.items() if mt == CAMERA_INFO), None)
    if frames is None:
        what = f"*/{source}" if source != "image" else f"{cfg.camera.image_transport} image"
        raise ValueError(f"{path}: no {what} topic (topics: {sorted(topics)})")
    if debug_outputs and source != "image" and image_topic is None:
        images = [t for t, mt in topics.items() if mt == IMAGE]
        ns = frames.rsplit("/", 1)[0] + "/"
        image_topic = next((t for t in images if t.startswith(ns)), images[0] if images else None)
    viz_topic = (image_topic if source != "image" else frames) if debug_outputs else None
    if cfg.imu is not None:
        imus = [t for t, mt in topics.items() if mt == IMU]
        if imu_topic is None and len(imus) == 1:
            imu_topic = imus[0]
        if imu_topic not in imus:
            raise ValueError(
                f"{path}: imu.enabled needs a sensor_msgs/Imu topic (--imu-topic; IMU topics: "
                f"{imus})"
            )
    return frames, info_topic, viz_topic, imu_topic
