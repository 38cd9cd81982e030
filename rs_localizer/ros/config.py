"""The node's configuration built from its parameter values (no ROS needed).

The node, the managed node and ``rs-localizer replay`` turn a full set of parameter values
(:mod:`.params`: :data:`~.params.PARAMETERS`; :func:`.param_files.parameter_values` for files)
into a :class:`LocalizerConfig` with :func:`build_config`, which raises
:class:`~.params.ConfigError` naming the parameter when a value cannot be used: one camera's
(``rig.cameras`` empty) or a rig's, a single camera being a rig of one camera named "" (each
camera's :class:`CameraConfig` made by the one builder :func:`camera_config`). The
configuration holds values and paths:
the library's settings (the estimator's and tracker's options, the gyro's use, built with
:mod:`rs_localizer.tracking.settings`; the front end's options,
:func:`rs_localizer.frontends.registry.frontend_options`), the frames, the fallback camera,
the queue; the maps it names are loaded by :func:`load_maps` (into the process's shared map
cache, :data:`~rs_localizer.frontends.shared.SHARED_MAPS`).
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..camera import MAX_LINE_DELAY, MAX_READOUT_TIME, READOUT_DIRECTIONS, CameraModel
from ..estimation.options import EstimateOptions, points_needed
from ..frames import Mounting
from ..frontends.registry import FRONTEND_KINDS, frontend_kind, frontend_options
from ..frontends.shared import SHARED_MAPS, LoadedMaps
from ..pose import ROS_ORDER
from ..solvers.registry import SOLVER_NAMES as SOLVERS
from ..tracking.sequence import GyroSettings, SequenceSettings, rig_of_one
from ..tracking.settings import gyro_settings, rig_settings, with_fields
from ..tracking.tracker import TrackerOptions
from . import conversions as cv
from .params import IMAGE_TRANSPORTS, OPTION_GROUPS, PARAMETERS, ConfigError, option_fields

__all__ = [
    "RIG_RUN_TIME_PARAMETERS",
    "RIG_UNUSED_PARAMETERS",
    "CameraConfig",
    "LocalizerConfig",
    "build_config",
    "camera_config",
    "default_timing_note",
    "estimate_options",
    "imu_config",
    "load_maps",
    "mounting_covariance_values",
    "mounting_values",
    "rig_base_frame",
    "rig_change_refused",
    "rig_parameter_file",
    "rig_unused",
    "rig_unused_text",
    "same_value",
    "tracker_options",
]


def estimate_options(values: Mapping[str, Any]) -> EstimateOptions:
    """The estimator options of the parameters whose :attr:`~.params.Parameter.field` is in the
    ``estimate`` group (``ransac.*``, ``refine``, ``motion_prior.*``, ``max_angular_velocity``,
    ``max_linear_velocity``, ``correlated_noise.*``); every other option at its default.

    Raises:
        TypeError, ValueError: from :class:`EstimateOptions` (e.g. a
            ``max_angular_velocity`` <= 0).
    """
    return with_fields(EstimateOptions(), option_fields("estimate", values))


def tracker_options(values: Mapping[str, Any]) -> TrackerOptions | None:
    """The video tracker's options of the parameters in the ``tracking`` group; None when
    ``tracking.enabled`` is false (every frame alone).

    Raises:
        TypeError, ValueError: from :class:`TrackerOptions` / ``FusionOptions``.
    """
    if not bool(values["tracking.enabled"]):
        return None
    return with_fields(TrackerOptions(), option_fields("tracking", values))


def imu_config(values: Mapping[str, Any]) -> GyroSettings | None:
    """The gyro's use (:class:`~rs_localizer.tracking.sequence.GyroSettings`) of the ``imu.*``
    parameters; None when ``imu.enabled`` is false.

    Raises:
        ValueError: ``imu.rotation`` not a quaternion (4 finite numbers of norm near 1),
            ``imu.gyro_bias`` not 3 finite numbers.
    """
    if not bool(values["imu.enabled"]):
        return None
    bias = np.asarray(values["imu.gyro_bias"], dtype=float).reshape(-1)
    if bias.shape != (3,) or not np.isfinite(bias).all():
        raise ValueError(f"imu.gyro_bias must be 3 finite numbers (rad/s), got {bias.tolist()}")
    return gyro_settings(values["imu.rotation"], bias, option_fields("imu", values))


@dataclass(frozen=True)
class CameraConfig:
    """One camera of the localizer (built by :func:`camera_config`): the single camera, named
    "", or a camera of a rig, named as in ``rig.cameras``.

    Attributes:
        name: the camera's name ("" the single camera; a rig camera's topics are under
            ``<name>/``).
        line_delay (s/line), readout_time (s, > 0 wins), direction, reference_row (px, None =
            image centre): the rolling-shutter timing of its camera models.
        mount: its :class:`~rs_localizer.frames.Mounting` in ``base_frame`` (a rig camera's
            ``rig.<name>.mounting``; the single camera's ``camera_to_base.*``, the transform
            of its outputs to ``base_frame``, None without ``base_frame``).
        fallback: the camera model of the ``camera.*`` parameters (the single camera's; None:
            camera.fx <= 0, and a rig camera: its intrinsics are its camera_info's).
        frame: its frame id (``camera_frame``; "" = the input's frame id).
        time_offset: s added to its stamps on the rig's clock (``rig.<name>.time_offset``; 0
            for the single camera).
        landmarks_file: the landmark table (CSV) its keypoint frames name.
        frontend_kind (``none``, ``aruco``, ...), frontend_map, image_transport (``raw`` /
            ``compressed``), frontend_options (the front end's keyword arguments: the
            ``features.*`` and ``aruco.*`` parameters): its image input.

    Values and paths only: the maps they name are loaded by :func:`load_maps`.
    """

    name: str
    line_delay: float
    readout_time: float
    direction: str
    reference_row: float | None
    mount: Mounting | None
    fallback: CameraModel | None
    frame: str
    time_offset: float
    landmarks_file: str
    frontend_kind: str
    frontend_map: str
    image_transport: str
    #: keyword arguments of the front end (``features.*`` for ``features``)
    frontend_options: dict = dataclasses.field(default_factory=dict)

    def camera_from_info(self, msg: Any) -> CameraModel:
        """The camera model of a ``sensor_msgs/CameraInfo`` (rclpy or rosbags) with this
        camera's timing.

        Raises:
            CameraInfoError (a ValueError): see :func:`.conversions.camera_model_from_camera_info`.
        """
        return cv.camera_model_from_camera_info(
            msg, self.line_delay, self.readout_time, self.direction, self.reference_row
        )


@dataclass(frozen=True, eq=False)
class LocalizerConfig:
    """Everything the localizer derives from its parameters (see :data:`.params.PARAMETERS` for
    the meaning of each; built by :func:`build_config`), for one camera or a rig: a single
    camera is a rig of one camera named "".

    Attributes:
        cameras: each camera's :class:`CameraConfig`, in the order of ``rig.cameras`` (the
            single camera: one, named "").
        solver: minimal solver name. options: the estimator's options.
        tracking: the video tracker's options, None = every frame alone.
        imu: the gyro's use (:class:`~rs_localizer.tracking.sequence.GyroSettings`), None = no
            gyro.
        map_frame, base_frame: the output frames (the single camera's ``base_frame``: "" =
            none; a rig's: :func:`rig_base_frame`).
        stamp_row (px): the image row a frame's stamp is the capture time of.
        max_points: the cap on a frame's rows. time_reset_ns: a forward stamp jump larger
            than this (ns) resets the time-dependent state. queue_size: frames waiting (per
            camera). camera_info_wait: s a frame may wait for its camera_info.
        republish_correspondences: what a front end found published.
        settings: a rig's :class:`~rs_localizer.tracking.video.LocalizerSettings` (None for the
            single camera, whose pipeline makes its own).
        unused: a rig's: the single camera's parameters given a value other than their
            default, which the rig mode does not use (:func:`rig_unused`).

    Values and paths only: the maps they name are loaded by :func:`load_maps` where the
    pipeline is built.
    """

    cameras: tuple[CameraConfig, ...]
    solver: str
    options: EstimateOptions
    tracking: TrackerOptions | None
    imu: GyroSettings | None
    map_frame: str
    base_frame: str
    stamp_row: float
    max_points: int
    time_reset_ns: int
    queue_size: int
    camera_info_wait: float
    republish_correspondences: bool
    settings: Any = None
    unused: tuple = ()

    @property
    def camera(self) -> CameraConfig:
        """The first camera (the single camera's; the image input, front end and landmarks
        of every camera of a rig are the same parameters')."""
        return self.cameras[0]

    @property
    def min_points(self) -> int:
        """Fewest correspondences a pose needs (:func:`points_needed`)."""
        return points_needed(self.solver, self.options)

    @property
    def timings(self) -> dict[str, tuple[float, float, str]]:
        """Each camera's rolling-shutter timing: name -> ``(line_delay s/line, readout_time s,
        direction)`` (what a rig's kernels are warmed up with:
        :func:`~rs_localizer.runtime.warmup.warm_rig`)."""
        return {c.name: (c.line_delay, c.readout_time, c.direction) for c in self.cameras}

    @property
    def video_settings(self) -> Any:
        """The settings of the localizer of these cameras
        (:class:`~rs_localizer.tracking.video.LocalizerSettings`): a rig's :attr:`settings`;
        the single camera's its rig of one (:func:`~rs_localizer.tracking.sequence.rig_of_one`
        of its solver, estimator options, tracking, gyro, ``stamp_row``, ``time_reset_ns``,
        ``max_points``), made anew at each call."""
        if self.settings is not None:
            return self.settings
        return rig_of_one(SequenceSettings(
            solver=self.solver, options=self.options, tracking=self.tracking, imu=self.imu,
            stamp_row=self.stamp_row, time_reset_ns=self.time_reset_ns,
            max_points=self.max_points,
        ))  # fmt: skip

    @property
    def fused_frame(self) -> tuple[str | None, Mounting | None]:
        """``(frame_id, mounting)`` of the fused twists as published
        (:func:`~rs_localizer.ros.pipeline.fused_outputs`): a rig's in ``base_frame`` as the
        rig's pose; the single camera's in each frame's tag (None) or, with
        ``camera_to_base.*``, moved by its mounting to ``base_frame``."""
        if self.settings is not None:
            return self.base_frame, None
        mount = self.camera.mount
        return (None, None) if mount is None else (self.base_frame, mount)

    @property
    def unused_text(self) -> str | None:
        """The warning that names :attr:`unused` (:func:`rig_unused_text`), or None."""
        return rig_unused_text(self.unused)


def _estimation(
    p: Mapping[str, Any],
) -> tuple[EstimateOptions, TrackerOptions | None, GyroSettings | None]:
    """Stage of :func:`build_config`: solver, estimator options (and what a pose needs against
    ``max_points``), tracker options and the gyro's use."""
    if p["solver"] not in SOLVERS:
        raise ConfigError(f"unknown solver {p['solver']!r}; expected one of {list(SOLVERS)}")
    if p["rs.direction"] not in READOUT_DIRECTIONS:
        raise ConfigError(
            f"unknown rs.direction {p['rs.direction']!r}; expected one of "
            f"{list(READOUT_DIRECTIONS)}"
        )
    try:
        opts = estimate_options(p)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"invalid RANSAC options: {e}") from None
    need = points_needed(p["solver"], opts)
    if int(p["max_points"]) < need:
        raise ConfigError(
            f"max_points {p['max_points']} is below the {need} points a pose needs "
            f"(ransac.min_inliers {int(p['ransac.min_inliers'])}, solver {p['solver']}): every "
            "frame would fail"
        )
    try:
        tracking = tracker_options(p)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"invalid tracking parameters: {e}") from None
    try:
        imu = imu_config(p)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"invalid imu parameters: {e}") from None
    return opts, tracking, imu


def _timing(p: Mapping[str, Any]) -> tuple[float, float, str, float | None]:
    """Stage of :func:`camera_config`: the rolling-shutter timing ``(line_delay, readout_time,
    direction, reference_row or None)`` of the ``rs.*`` parameters (checked by
    :func:`_check_timing`)."""
    ref = float(p["rs.reference_row"])
    line_delay, readout_time = float(p["rs.line_delay"]), float(p["rs.readout_time"])
    return line_delay, readout_time, p["rs.direction"], (None if ref < 0 else ref)


def _fallback_camera(p: Mapping[str, Any], timing: tuple) -> CameraModel | None:
    """Stage of :func:`camera_config`: the camera model of the ``camera.*`` parameters (None:
    ``camera.fx <= 0``)."""
    if not all(
        math.isfinite(float(p[k])) for k in ("camera.fx", "camera.fy", "camera.cx", "camera.cy")
    ):
        raise ConfigError("invalid fallback camera parameters: camera.fx/fy/cx/cy must be finite")
    d = p["camera.d"] if p["camera.d"] is not None else []
    if not all(math.isfinite(float(x)) for x in d):
        raise ConfigError(
            f"invalid fallback camera parameters: camera.d must be finite, got {list(d)}"
        )
    if float(p["camera.fx"]) <= 0:
        return None
    K = np.array(
        [
            [p["camera.fx"], 0.0, p["camera.cx"]],
            [0.0, p["camera.fy"] or p["camera.fx"], p["camera.cy"]],
            [0.0, 0.0, 1.0],
        ],
        dtype=float,
    )
    try:
        return cv.camera_model(
            K, list(d), p["camera.width"], p["camera.height"], p["camera.distortion_model"],
            *timing,
        )  # fmt: skip
    except ValueError as e:
        raise ConfigError(f"invalid fallback camera parameters: {e}") from None


def _check_timing(timing: tuple) -> None:
    """Stage of :func:`camera_config`: the ``rs.*`` rolling-shutter timing checked on its own
    (a camera model made with it)."""
    try:
        cv.camera_model(np.eye(3), [], 10, 10, "plumb_bob", *timing)
    except ValueError as e:
        raise ConfigError(f"invalid rolling-shutter parameters: {e}") from None


def _mounting(p: Mapping[str, Any]) -> Mounting | None:
    """Stage of :func:`camera_config`: the single camera's ``base_frame -> camera`` mounting of
    ``camera_to_base.*`` (None without ``base_frame``: :func:`_base_frame` empty)."""
    if not _base_frame(p):
        return None
    try:
        return Mounting.from_translation_quaternion(
            p["camera_to_base.translation"], p["camera_to_base.rotation"]
        )
    except ValueError as e:
        raise ConfigError(f"invalid camera_to_base: {e}") from None


def _own_timing(n: str, own: Mapping[str, Any], timing: tuple) -> tuple[float, float, str]:
    """Stage of :func:`camera_config`: a rig camera's ``(line_delay, readout_time, direction)``
    of its ``rig.<n>.line_delay``, ``readout_time``, ``direction`` (negative or empty: the
    ``rs.*`` value of ``timing``)."""
    line_delay, readout_time, direction = timing[:3]
    ld = float(own.get("line_delay", -1.0))
    rt = float(own.get("readout_time", -1.0))
    for key, v, top in (("line_delay", ld, MAX_LINE_DELAY), ("readout_time", rt, MAX_READOUT_TIME)):
        if not (math.isfinite(v) and v <= top):  # (negative: the rs.* value)
            raise ConfigError(f"rig.{n}.{key} must be at most {top:g} s, got {v!r}")
    d = str(own.get("direction", "") or direction).strip()
    if d not in READOUT_DIRECTIONS:
        raise ConfigError(
            f"rig.{n}.direction: unknown readout direction {d!r}; expected one of "
            f"{list(READOUT_DIRECTIONS)}"
        )
    return (line_delay if ld < 0 else ld), (readout_time if rt < 0 else rt), d


def _time_offset(n: str, own: Mapping[str, Any]) -> float:
    """Stage of :func:`camera_config`: a rig camera's ``rig.<n>.time_offset`` (s)."""
    dt = own.get("time_offset", 0.0)
    if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not math.isfinite(dt):
        raise ConfigError(f"rig.{n}.time_offset must be a number of seconds, got {dt!r}")
    if abs(dt) > 1.0:
        raise ConfigError(f"rig.{n}.time_offset must be within 1 s, got {dt!r}")
    return float(dt)


def _image_input(p: Mapping[str, Any]) -> tuple[str, str, str]:
    """Stage of :func:`camera_config`: ``(front end kind, its map, image transport)``."""
    kind, fmap = str(p["frontend"]).strip().lower(), str(p["frontend_map"])
    choices = ("none", *FRONTEND_KINDS)  # (read now: the registry is the one list)
    if kind not in choices:
        raise ConfigError(f"unknown frontend {p['frontend']!r}; expected one of {list(choices)}")
    transport = str(p["image_transport"]).strip().lower()
    if transport not in IMAGE_TRANSPORTS:
        raise ConfigError(
            f"unknown image_transport {p['image_transport']!r}; expected one of "
            f"{list(IMAGE_TRANSPORTS)}"
        )
    if kind != "none" and not fmap:
        raise ConfigError(f"frontend {kind} needs frontend_map ({frontend_kind(kind).map_file})")
    return kind, fmap, transport


def camera_config(
    name: str, values: Mapping[str, Any], own: Mapping[str, Any] | None = None
) -> CameraConfig:
    """Camera ``name``'s configuration of a full set of :data:`.params.PARAMETERS` ``values``:
    the one builder of the single camera (``own`` None, ``name`` "": its fallback model of
    ``camera.*``, its output transform of ``camera_to_base.*`` with ``base_frame``, its frame
    id ``camera_frame``, the timing of ``rs.*``) and of each camera of a rig (``own``: its
    :data:`.params.RIG_CAMERA_PARAMETERS` values, ``mounting`` None: not given; its mounting,
    its timing over the ``rs.*`` one, its time offset; no fallback model, its input's frame
    id). Both: the image input, front end and landmarks of the node's parameters.

    Raises:
        ConfigError: naming the parameter: non-finite or invalid fallback intrinsics, the
            rolling-shutter timing, ``camera_to_base``; a rig camera without a usable
            mounting, timing or time offset; an unknown front end or transport, a front end
            without ``frontend_map``, front-end options it rejects.
    """
    timing = _timing(values)
    line_delay, readout_time, direction, reference_row = timing
    fallback = _fallback_camera(values, timing) if own is None else None
    _check_timing(timing)
    if own is None:
        mount, frame, offset = _mounting(values), values["camera_frame"], 0.0
    else:
        frame = ""
        mount = rig_mounting(
            name,
            own.get("mounting"),
            own.get("mounting_covariance"),
            own.get("time_offset_std", 0.0),
        )
        line_delay, readout_time, direction = _own_timing(name, own, timing)
        offset = _time_offset(name, own)
    kind, fmap, transport = _image_input(values)
    return CameraConfig(
        name=name,
        line_delay=line_delay,
        readout_time=readout_time,
        direction=direction,
        reference_row=reference_row,
        mount=mount,
        fallback=fallback,
        frame=frame,
        time_offset=offset,
        landmarks_file=values["landmarks_file"],
        frontend_kind=kind,
        frontend_map=fmap,
        image_transport=transport,
        frontend_options=_frontend_options(kind, values),
    )


def build_config(
    values: Mapping[str, Any], cameras: Mapping[str, Mapping[str, Any]] | None = None
) -> LocalizerConfig:
    """The configuration of a full set of parameter values (one per
    :data:`.params.PARAMETERS` name), values and paths (the maps are loaded by
    :func:`load_maps`): ``cameras`` None, the single camera (one camera named "",
    :func:`camera_config`); else a rig's, ``values`` also holding the
    :data:`.params.RIG_PARAMETERS` and ``cameras`` each camera of ``rig.cameras`` its
    :data:`.params.RIG_CAMERA_PARAMETERS` values (:func:`camera_config` per camera). Reads no
    file. Types and ranges are not checked here (ROS does it for the node,
    :func:`.params.check_parameter` for replay).

    Raises:
        ConfigError: the first unusable value, with a message naming the parameter (unknown
            solver, direction, front end or transport; estimator or tracking options their
            classes reject; ``max_points`` below what a pose needs; a camera's
            (:func:`camera_config`); a rig's: no cameras, a camera name that is not valid in
            a topic name or listed twice, settings the rig's localizer rejects).
    """
    p = values
    names = None if cameras is None else rig_camera_names(p["rig.cameras"])
    opts, tracking, imu = _estimation(p)
    shared = dict(
        solver=p["solver"],
        options=opts,
        tracking=tracking,
        imu=imu,
        map_frame=p["map_frame"],
        stamp_row=float(p["rs.stamp_row"]),
        max_points=int(p["max_points"]),
        time_reset_ns=int(float(p["time_reset_threshold"]) * 1e9),
        queue_size=int(p["queue_size"]),
        camera_info_wait=float(p["camera_info_wait"]),
        republish_correspondences=bool(p["republish_correspondences"]),
    )
    if names is None:
        return LocalizerConfig((camera_config("", p),), base_frame=_base_frame(p), **shared)
    out = tuple(camera_config(n, p, cameras.get(n, {})) for n in names)
    try:
        settings = rig_settings(
            {c.name: c.mount for c in out},
            opts,
            tracking,
            window=float(p["rig.window"]),
            stop_after=float(p["rig.stop_after"]),
            stamp_row=shared["stamp_row"],
            time_reset_ns=shared["time_reset_ns"],
            imu=imu,
            max_points=shared["max_points"],
            time_offsets={c.name: c.time_offset for c in out if c.time_offset},
            solver=str(p["solver"]),
        )
    except ValueError as e:
        raise ConfigError(f"rig: {e}") from None
    base = rig_base_frame(p)
    unused = rig_unused(p, settings.single_camera)
    return LocalizerConfig(out, base_frame=base, settings=settings, unused=unused, **shared)


def _base_frame(values: Mapping[str, Any]) -> str:
    """The parameter ``base_frame`` of ``values`` stripped of spaces, "" when it is empty,
    null or missing: the single camera's output frame ("": none, its optical frame) and a
    rig's (:func:`rig_base_frame`)."""
    return str(values.get("base_frame") or "").strip()


def rig_base_frame(values: Mapping[str, Any]) -> str:
    """A rig's frame, the one its pose and its cameras' mountings are in: the parameter
    ``base_frame`` of ``values`` stripped of spaces (:func:`_base_frame`), ``base_link``
    (REP 105's robot body frame) when it is empty, null or missing."""
    return _base_frame(values) or "base_link"


def _frontend_options(kind: str, p: Mapping[str, Any]) -> dict:
    """Stage of :func:`camera_config`: the front end's keyword arguments of the ``aruco.*`` and
    ``features.*`` parameters (:func:`~rs_localizer.frontends.registry.frontend_options`)."""
    try:
        return frontend_options(kind, p)
    except ValueError as e:
        raise ConfigError(str(e)) from None


def load_maps(
    camera: CameraConfig, *, owner: object | None = None, current: LoadedMaps | None = None
) -> LoadedMaps:
    """The maps ``camera`` (a :class:`CameraConfig`) names: the landmark table of
    ``landmarks_file`` and the front end of ``frontend_map``, loaded through
    :data:`~rs_localizer.frontends.shared.SHARED_MAPS` on behalf of ``owner`` (one copy per
    process, released with ``SHARED_MAPS.release(owner)``;
    :meth:`~rs_localizer.frontends.shared.MapCache.load_maps`). The front end of ``current``
    is reused when its kind and map are unchanged. Called where the node and replay build
    their pipeline, and again when a parameter names another file.

    Raises:
        ConfigError: a landmark table or front-end map that does not load (missing, not a
            regular file, malformed), naming the parameter.
    """
    try:
        return SHARED_MAPS.load_maps(
            camera.landmarks_file,
            camera.frontend_kind,
            camera.frontend_map,
            camera.frontend_options,
            owner=owner,
            current=current,
        )
    except ValueError as e:
        raise ConfigError(str(e)) from None


def default_timing_note(cfg: LocalizerConfig) -> str | None:
    """A warning when the RS timing is the parameters' default (``rs.line_delay`` unchanged,
    ``rs.readout_time`` unset): the line delay is then likely no camera's own, and a wrong
    one biases the angular and linear velocity. None when the timing was set (the single
    camera's, :attr:`LocalizerConfig.camera`)."""
    cam = cfg.camera
    if cam.line_delay != PARAMETERS["rs.line_delay"].default or cam.readout_time > 0:
        return None
    return (
        f"rs.line_delay is the default {cam.line_delay * 1e6:g} us/line (rs.readout_time "
        "unset): set your camera's, measured with `rs-localizer calibrate-readout` or from "
        "the published values in docs/video.md; a wrong line delay biases the angular and "
        "linear velocity"
    )


_TOPIC_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def rig_camera_names(value: Any) -> list[str]:
    """The ``rig.cameras`` value as its camera names: a list of names, each a valid ROS topic
    name token (a letter or ``_`` first, then letters, digits and ``_``: the camera's topics are
    ``<camera>/image_raw``, ``<camera>/camera_info``), none listed twice.

    Raises:
        ConfigError: not a list, an empty list, a name that is not a string or not a topic
            name token, a name listed twice (one line naming the parameter and the fix).
    """
    if isinstance(value, str):
        raise ConfigError(
            f"rig.cameras must be a list of camera names: write [{value}], not {value}"
        )
    if not isinstance(value, (list, tuple)) or not value:
        raise ConfigError(
            f"rig.cameras: needs camera names (a list, e.g. [front, left]), got {value!r}"
        )
    names = []
    for n in value:
        if not isinstance(n, str) or not _TOPIC_TOKEN.fullmatch(n.strip()):
            raise ConfigError(
                f"rig.cameras: camera name {n!r} is not valid in a topic name (<camera>/"
                "image_raw): use letters, digits and _, a letter or _ first, e.g. front_cam"
            )
        names.append(n.strip())
    if len(set(names)) != len(names):
        raise ConfigError(f"rig.cameras: a camera listed twice in {names}")
    return names


def rig_mounting(n: str, m: Any, cov_values: Any = None, time_std: Any = 0.0) -> Mounting:
    """Camera ``n``'s ``rig.<n>.mounting`` (7 numbers x, y, z, qx, qy, qz, qw: its optical
    frame's pose in ``base_frame``; integers taken as floats) with its
    ``rig.<n>.mounting_covariance`` (36 numbers, ROS order; None or all zero: none) and its
    ``rig.<n>.time_offset_std`` (``time_std``, s; 0: none) as a
    :class:`~rs_localizer.frames.Mounting`.

    Raises:
        ConfigError: no mounting, not 7 finite numbers, not a rotation, a covariance that
            is not 36 finite numbers, or a time offset std that is not a finite number
            >= 0, naming the parameter.
    """
    if m is None or (isinstance(m, (list, tuple)) and len(m) == 0):
        raise ConfigError(
            f"rig camera {n!r} has no mounting: set rig.{n}.mounting: [x, y, z, qx, qy, qz, "
            "qw] (its optical frame's pose in base_frame)"
        )
    numbers = isinstance(m, (list, tuple)) and all(
        isinstance(x, (int, float)) and not isinstance(x, bool) for x in m
    )
    if not numbers or len(m) != 7 or not np.isfinite(np.asarray(m, dtype=float)).all():
        raise ConfigError(
            f"rig.{n}.mounting must be 7 finite numbers x, y, z, qx, qy, qz, qw, got "
            f"{list(m) if isinstance(m, (list, tuple)) else m!r}"
        )
    m = [float(x) for x in m]
    cov = None
    try:
        C = np.asarray([] if cov_values is None else cov_values, dtype=float).ravel()
    except (TypeError, ValueError):
        C = np.full(1, np.nan)
    if C.any():
        if C.size != 36 or not np.isfinite(C).all():
            raise ConfigError(
                f"rig.{n}.mounting_covariance must be 36 finite numbers (6 x 6 over x, y, z, "
                f"rot x, rot y, rot z) or all zero, got {C.size} numbers"
            )
        cov = C.reshape(6, 6)[np.ix_(ROS_ORDER, ROS_ORDER)]  # (rotation first, as Mounting's)
    ok = isinstance(time_std, (int, float)) and not isinstance(time_std, bool)
    if not ok or not (math.isfinite(time_std) and time_std >= 0.0):
        raise ConfigError(
            f"rig.{n}.time_offset_std must be a finite number of seconds >= 0, got {time_std!r}"
        )
    try:
        return Mounting.from_pose(
            cv.matrix_from_quaternion(m[3:]), m[:3], covariance=cov, time_offset_std=time_std
        )
    except ValueError as e:
        raise ConfigError(f"rig.{n}.mounting: {e}") from None


def mounting_values(m: Mounting) -> list[float]:
    """A mounting as the node's ``rig.<camera>.mounting``, what :func:`rig_mounting` reads:
    x, y, z (m, the camera's optical centre in ``base_frame``), qx, qy, qz, qw (its optical
    frame's orientation in ``base_frame``), each rounded to 9 decimals."""
    q = cv.quaternion_from_matrix(m.R.T)
    return [round(float(x), 9) + 0.0 for x in (*m.position, *q)]


def mounting_covariance_values(m: Mounting) -> list[float] | None:
    """A mounting's covariance as the node's ``rig.<camera>.mounting_covariance``, what
    :func:`rig_mounting` reads: 36 numbers (6 significant digits), row by row over x, y, z
    (m), rot x, rot y, rot z (rad) in the rig frame; None without one."""
    if m.covariance is None:
        return None
    C = m.covariance[np.ix_(ROS_ORDER, ROS_ORDER)]  # (Mounting's: rotation first)
    return [float(f"{x:.6g}") + 0.0 for x in C.ravel()]


def rig_parameter_file(
    base_frame: str,
    stamp_row: float,
    cameras: Mapping[str, Mapping[str, Any]],
    extra: Mapping[str, Any] | None = None,
    notes: Iterable[str] = (),
) -> str:
    """The text of a rig node's parameter file (YAML for ``--params-file``, every node
    name): ``base_frame``, ``rs.stamp_row``, ``rig.cameras`` (the keys of ``cameras``, in
    order) and each camera's parameters (``cameras[name]``: ``mounting``,
    ``mounting_covariance``, ``line_delay``, ...), then the ``extra`` groups (e.g. ``imu``);
    ``notes``: comment lines on top."""
    import yaml

    body: dict[str, Any] = {
        "base_frame": base_frame,
        "rs": {"stamp_row": float(stamp_row)},
        "rig": {"cameras": list(cameras), **{n: dict(v) for n, v in cameras.items()}},
        **(extra or {}),
    }
    tree = {"/**/rs_localizer": {"ros__parameters": body}}
    head = "".join(f"# {line}\n" for line in notes)
    return head + yaml.safe_dump(tree, sort_keys=False, default_flow_style=None)


#: in their place: its own estimator (``gr6p_1lin`` on every camera's points at once), each
#: camera's camera_info (intrinsics), frame id and ``rig.<camera>.mounting``
RIG_UNUSED_PARAMETERS = (
    ("solver",),
    ("camera.",),
    ("camera_frame", "camera_to_base."),
)
_RIG_INSTEAD = (
    "the rig estimator solves every camera's points at once, gr6p_1lin",
    "each rig camera's intrinsics are those of its camera_info",
    "each rig camera's pose on the rig is rig.<camera>.mounting, in base_frame",
)


def _rig_unused_group(name: str, single: bool = False) -> int | None:
    """The entry of :data:`RIG_UNUSED_PARAMETERS` that holds parameter ``name``, or None;
    ``single``: a rig of one camera, which uses ``solver``."""
    if single and name == "solver":
        return None
    return next(
        (k for k, names in enumerate(RIG_UNUSED_PARAMETERS) if name.startswith(names)), None
    )


def rig_unused(values: Mapping[str, Any], single: bool = False) -> tuple[str, ...]:
    """The parameters of :data:`RIG_UNUSED_PARAMETERS` whose value in ``values`` (name ->
    value, e.g. a parameter file shared with single-camera nodes) is not their default: set
    for a single camera, without effect on a rig. ``single``: the rig is one camera at the
    identity mounting (:attr:`~rs_localizer.tracking.video.LocalizerSettings.single_camera`),
    solved with ``solver`` as that camera's video: ``solver`` is used. In
    :data:`~.params.PARAMETERS` order."""
    return tuple(
        name
        for name, par in PARAMETERS.items()
        if _rig_unused_group(name, single) is not None
        and name in values
        and not same_value(values[name], par.default)
    )


def same_value(a: Any, b: Any) -> bool:
    """Whether two parameter values are the same: sequences (a list, a tuple, ROS's
    ``array.array``) element by element, numbers by value (an int as the float it equals),
    strings as they are."""
    if isinstance(a, (str, bytes)) or isinstance(b, (str, bytes)):
        return a == b
    try:
        return list(a) == list(b)
    except TypeError:
        return a == b


def rig_unused_text(names: Iterable[str]) -> str | None:
    """A warning naming the single camera's parameters ``names`` that a rig does not use and
    what it takes instead; None for none."""
    groups: dict[int, list[str]] = {}
    for name in names:
        k = _rig_unused_group(name)
        if k is not None:
            groups.setdefault(k, []).append(name)
    if not groups:
        return None
    parts = [f"{', '.join(groups[k])} ({_RIG_INSTEAD[k]})" for k in sorted(groups)]
    return "a single camera's parameters set but not used in the rig mode: " + "; ".join(parts)


#: the parameters a running rig takes (``ros2 param set``; the node's
#: :meth:`~rs_localizer.ros.mode.LocalizerMode.apply_change`): those that only reach its
#: :class:`~rs_localizer.tracking.video.LocalizerSettings` (the estimator's options: ``ransac.*``,
#: ``refine``, ``motion_prior.*``, ``correlated_noise.*``, the velocity bounds; ``tracking.*``;
#: ``imu.*``; ``time_reset_threshold``; ``max_points``, also each camera's cloud cap),
#: ``queue_size`` and ``camera_info_wait`` (each camera's), ``republish_correspondences``
#: (each camera's ``<camera>/correspondences_out``); the read-only ones among them are
#: refused by ROS
RIG_RUN_TIME_PARAMETERS = frozenset(
    name
    for name, par in PARAMETERS.items()
    if (par.field or "").split(":")[0] in OPTION_GROUPS
    or name.startswith(("tracking.", "imu."))
    or name
    in (
        "max_points",
        "queue_size",
        "time_reset_threshold",
        "camera_info_wait",
        "republish_correspondences",
    )
)

#: why a running rig refuses a change of the other parameters, by name prefix
_RIG_RESTART = (
    (
        ("rs.",),
        "each rig camera's rolling-shutter timing is set at start: its camera models and the "
        "times its frames are grouped by are made with it (rs.* are the defaults of the "
        "read-only rig.<camera>.line_delay, readout_time and direction)",
    ),
    (("base_frame",), "the cameras' mountings (rig.<camera>.mounting) are poses in base_frame"),
    (("landmarks_file",), "the landmarks the cameras' keypoints name are loaded at start"),
    (
        ("frontend", "image_transport", "aruco.", "features."),
        "each camera's front end and image subscription are made at start",
    ),
)


def rig_change_refused(names: Iterable[str], single: bool = False) -> str | None:
    """Why a running rig refuses to change the parameters ``names`` (of
    :data:`~.params.PARAMETERS`) without a restart, one clause per parameter; None when it
    takes them all (:data:`RIG_RUN_TIME_PARAMETERS`). The others are its cameras' timing
    (``rs.*``), its frame (``base_frame``), its landmarks (``landmarks_file``), its front
    ends, and the single camera's parameters
    the rig mode does not use (``solver``: the rig estimator has its own; ``camera.*``: a rig
    camera's intrinsics are its camera_info's; ``camera_frame``,
    ``camera_to_base.*``: the mountings).
    ``single``: a rig of one camera at the identity mounting, which takes ``solver`` as its
    camera's video does (:func:`rig_unused`)."""
    why = []
    for name in names:
        if name in RIG_RUN_TIME_PARAMETERS or (single and name == "solver"):
            continue
        reason = next((r for prefixes, r in _RIG_RESTART if name.startswith(prefixes)), None)
        unused = _rig_unused_group(name, single)
        if reason is not None:
            why.append(f"restart the node to change {name}: {reason}")
        elif unused is not None:
            why.append(f"{name} is not used in the rig mode: {_RIG_INSTEAD[unused]}")
        else:
            why.append(f"{name} is not used in the rig mode")
    return "; ".join(why) or None
