"""The localizer's ``/diagnostics`` status (level, message, key-value pairs) from its counters,
without ROS: the node wraps it into a ``diagnostic_msgs/DiagnosticStatus``. One builder
(:func:`status`) makes the status of one camera or a rig from a description without the mode
(:class:`StatusParts`): the accounting of what is solved (a camera's frames, a rig's rig
frames: one :class:`~rs_localizer.ros.frame_queue.FrameCounts`) and a section per camera
(:class:`CameraPart`, its accounting of :func:`camera_section`: a camera alone's flat keys,
each rig camera's ``<c>.*``), from which it takes the keys' order, the level and the message
(one rule; a camera alone is solved in frames, any other set of cameras in rig frames);
shared by both: the estimator's path, the map-fit check, the timing keys
(:func:`timing_values`, the stage times a camera's counts keep,
:meth:`~.camera_input.CameraCounts.stage_time`) and the gyro's values
(:class:`GyroState`). The node (:meth:`.core.NodeCore.diagnostics_status`) calls it on what
its mode hands as data (:meth:`.mode.LocalizerMode.diagnostics`), the parts of one builder
(:func:`localizer_status_parts` of its localizer, :func:`status_parts`): a section per camera
(the camera alone's :class:`CameraAlone`, its counters and :func:`frontend_values`, its keys
at the top; each rig camera's of :func:`rig_camera_status`, its lines of grouping,
disagreement, mounting and clock offsets), the track's and the gyro's values, and a rig's
own part, its rig frames' counts."""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..correspondences import FrontendHooks
from ..runtime.background import background_state, compiled_ready
from ..tracking.localizer import readout_warning
from ..tracking.rig import offsets_text
from .frame_queue import FRAME_ACCOUNTING, FrameCounts, frame_accounting
from .pipeline import StatsSnapshot

if TYPE_CHECKING:
    from ..tracking.gyro import ImuBuffer
    from ..tracking.gyro_input import GyroSettings
    from ..tracking.video import Localizer

__all__ = [
    "ERROR",
    "FRAME_ACCOUNTING",
    "IMU_IDLE_WARN_S",
    "OK",
    "WARN",
    "CameraAlone",
    "CameraPart",
    "GyroState",
    "RigInputs",
    "StatusParts",
    "camera_section",
    "frontend_values",
    "localizer_status_parts",
    "rig_camera_frames",
    "rig_camera_part",
    "rig_camera_section",
    "rig_camera_status",
    "status",
    "status_parts",
    "timing_values",
]

#: levels of ``diagnostic_msgs/DiagnosticStatus``
OK, WARN, ERROR = 0, 1, 2
#: s; with ``imu.enabled``, no usable IMU sample for this long while frames arrive is a WARN
IMU_IDLE_WARN_S = 2.0


def _ms(seconds: Sequence[float]) -> np.ndarray:
    return np.array(list(seconds)) * 1e3


#: s: a frame whose stamp is further than this from the node's clock carries stamps of
#: another clock (a recorded bag played without ``use_sim_time``), not a stamp age
OFF_CLOCK_S = 60.0


def _median_ms(seconds: Sequence[float]) -> str:
    return f"{np.median(seconds) * 1e3:.3f}" if len(seconds) else "nan"


def timing_values(latencies: Sequence[float], stamp_ages: Sequence[float]) -> dict[str, Any]:
    """The timing keys of a status, of one camera or a rig (ms, strings; ``nan`` without a
    pose yet): ``latency_ms_last``, ``_median``, ``_p99`` (``latencies``: s from a frame's
    arrival to its pose published), ``stamp_age_ms_last``, ``_median`` (``stamp_ages``: s from
    the pose's stamp to its publication, node clock) and ``stamps_off_clock`` (stamp ages more
    than :data:`OFF_CLOCK_S` off: another clock's stamps, left out of the stamp age)."""
    lat, age = _ms(latencies), _ms(stamp_ages)
    on_clock = np.abs(age) <= OFF_CLOCK_S * 1e3
    off_clock, age = int(np.sum(~on_clock)), age[on_clock]
    return {
        "latency_ms_last": f"{lat[-1]:.3f}" if len(lat) else "nan",
        "latency_ms_median": f"{np.median(lat):.3f}" if len(lat) else "nan",
        "latency_ms_p99": f"{np.percentile(lat, 99):.3f}" if len(lat) else "nan",
        "stamp_age_ms_last": f"{age[-1]:.3f}" if len(age) else "nan",
        "stamp_age_ms_median": f"{np.median(age):.3f}" if len(age) else "nan",
        "stamps_off_clock": off_clock,
    }


def _compile_values(unit: str) -> tuple[dict[str, Any], str]:
    """``(values, note)``: the estimator's path (``compiled``: the compiled kernels in use;
    ``compile_state``, ``compile_failures``, ``compile_error``:
    :func:`rs_localizer.runtime.background.background_state`) and, off the compiled path, the
    message's note on it (``unit``: what is solved, ``frames`` or ``rig frames``; a lower rate
    while the kernels compile is not a fault)."""
    compiled, bg = compiled_ready(), background_state()
    values = {
        "compiled": str(compiled).lower(),
        "compile_state": bg["state"],
        "compile_failures": bg["failures"],
        "compile_error": bg["reason"] or "",
    }
    note = ""
    if not compiled:
        note = (
            f"; kernels compiling in the background: {unit} on the uncompiled path"
            if bg["state"] in ("compiling", "loading")
            else f"; {unit} on the uncompiled path"
        )
    return values, note


_INFO_REJECTED = "camera_info_rejected."

#: the single camera's names of the keys of its section that a rig camera's section names
#: otherwise (``<c>.`` and the key)
_FLAT_KEYS = {
    "received": "frames_received",
    "solved": "frames_solved",
    "failed": "frames_failed",
    "skipped": "frames_skipped",
    "pending": "frames_pending",
    "capped_clouds": "clouds_capped",
}


def camera_section(
    name: str,
    frames: FrameCounts,
    counts: Mapping[str, int] | None,
    more: Mapping[str, int] | None = None,
    frontend: bool = False,
    frame_times: Sequence[float] | None = None,
) -> dict[str, Any]:
    """One camera's accounting values: the single camera's (``name`` "": its flat keys, the
    frames' ``frames_<key>`` and ``clouds_capped``) and a rig camera's section (each key
    ``<name>.<key>``), both of a camera's
    :class:`~rs_localizer.ros.camera_input.CameraCounts`.

    Values: the frame accounting ``frames`` (``received``, ``solved``, ``failed``,
    ``skipped``, ``pending``; received = the other four summed; the single camera's
    :func:`~rs_localizer.ros.frame_queue.frame_accounting` of its counts, a rig camera's
    :func:`rig_camera_frames`); from the camera's own
    ``counts`` (keys without prefix; None: none known, only the frames and the rows' counts of
    ``more``): ``messages_lost`` (lost by the middleware), ``camera_info_rejected``,
    ``unknown_landmark_ids`` (keypoints' ids not in ``landmarks_file``), with a
    ``frontend`` ``frames_beside_frontend`` (clouds received while the front end runs on the
    images), ``camera_info_rejected.<reason>``; ``points_dropped`` (rows with a NaN or inf)
    and ``capped_clouds`` (clouds capped to ``max_points``); the frames' counts by reason
    (:meth:`~rs_localizer.ros.frame_queue.FrameCounts.reasons`: ``failed.<reason>``, then
    ``skipped.<reason>``); with ``frame_times`` (s
    per frame) ``camera_frame_ms_median``. ``more``: the camera's counts of another counter
    (a rig's, keys without prefix), added to its rows' and camera_info counts."""
    more = more or {}
    own = counts or {}

    def key(k: str) -> str:
        return f"{name}.{k}" if name else _FLAT_KEYS.get(k, k)

    values: dict[str, Any] = {key(k): v for k, v in frames.accounting().items()}
    for k in ("capped_clouds", "points_dropped"):
        values[key(k)] = own.get(k, 0) + more.get(k, 0)
    if counts is not None:
        for k in ("messages_lost", "camera_info_rejected", "unknown_landmark_ids"):
            values[key(k)] = own.get(k, 0)
        if frontend:
            values[key("frames_beside_frontend")] = own.get("frames_beside_frontend", 0)
    values.update({key(k): v for k, v in frames.reasons().items()})
    for k, v in sorted(own.items()):
        if k.startswith(_INFO_REJECTED):
            values[key(k)] = v + more.get(k, 0)
    if frame_times is not None:
        values[key("camera_frame_ms_median")] = _median_ms(frame_times)
    return values


@dataclass
class CameraPart:
    """One camera of a status, its section: ``name`` ("": a camera alone, its flat keys;
    else each key ``<name>.<key>``), its accounting (:func:`camera_section` of ``frames``,
    ``counts``, ``more``, ``frontend``, ``frame_times``), then a rig camera's own ``lines``
    (its state in the rig: grouping, disagreement, mounting; keys with the prefix, none
    replacing an accounting key) and ``warnings`` (texts for the status's message)."""

    name: str
    frames: FrameCounts
    counts: Mapping[str, int] | None = None
    more: Mapping[str, int] | None = None
    frontend: bool = False
    frame_times: Sequence[float] | None = None
    lines: Mapping[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    def section(self) -> dict[str, Any]:
        """The camera's values: its accounting, then its ``lines``."""
        values = camera_section(self.name, self.frames, self.counts, self.more, self.frontend,
                                self.frame_times)  # fmt: skip
        values.update({k: v for k, v in self.lines.items() if k not in values})
        return values


@dataclass
class GyroState:
    """A gyro's part of a status (with ``imu.enabled``): ``settings``, its ``counts`` by a
    camera's names (a rig's: the rig frames for its frames;
    :meth:`~rs_localizer.tracking.video.Localizer.gyro_counts`), the buffered samples'
    ``rate_hz``, ``bias`` ``(bias (3,), std (3,))`` rad/s in the IMU frame (None: the
    configured ``imu.gyro_bias``, ``imu.gyro_bias_sigma``), whether the rotation between
    frames contradicts it (``inconsistent``) and ``idle_s`` (s since the last usable sample;
    None: unknown)."""

    settings: GyroSettings
    counts: Mapping[str, int]
    rate_hz: float | None
    bias: tuple[Sequence[float], Sequence[float]] | None
    inconsistent: bool
    idle_s: float | None

    @classmethod
    def of(cls, settings: GyroSettings, counts: Mapping[str, int], imu: ImuBuffer | None,
           bias: tuple[Sequence[float], Sequence[float]] | None,
           inconsistent: bool) -> GyroState:  # fmt: skip
        """The gyro's state with its buffer of samples ``imu`` (None: no buffer; its
        :meth:`~rs_localizer.tracking.gyro.ImuBuffer.rate_hz` and
        :meth:`~rs_localizer.tracking.gyro.ImuBuffer.idle_seconds`)."""
        if imu is None:
            return cls(settings, counts, None, bias, inconsistent, None)
        return cls(settings, counts, imu.rate_hz(), bias, inconsistent, imu.idle_seconds())


@dataclass
class StatusParts:
    """A status described without its mode (one camera or a rig), laid out by :func:`status`.

    ``frames``: the accounting of what is solved (:class:`~rs_localizer.ros.frame_queue.
    FrameCounts`): a camera alone's frames, a rig's rig frames (``received`` the rig frames
    formed, ``failures`` the rig estimator's failures by reason). ``cameras``: a
    :class:`CameraPart` per camera, a camera alone's named "" (its flat keys), each rig
    camera's named (its section ``<c>.*``). A camera alone is solved in ``frames``, any other
    set of cameras in ``rig frames``: the unit of the keys and the message. The node's mode
    hands it (:meth:`~rs_localizer.ros.mode.LocalizerMode.diagnostics`), the node lays it
    out.

    Values, in publishing order: ``head``; the frame accounting (a camera alone's
    ``frames_received`` ... ``frames_pending``; a rig's ``rig_frames``, ``rig_frames_solved``
    ... ``rig_frames_pending``); the estimator's path (:func:`_compile_values`), ``path``
    (what follows it), a camera alone's input counts (``messages_lost``, ``points_dropped``,
    ``clouds_capped``, ``unknown_landmark_ids``, ``camera_info_rejected``), ``path_after``;
    with ``map_fit`` (counts) the map-fit check's ``<unit>_failed_with_matches`` and
    ``map_fit_doubtful``; ``tracking``; the timing keys: with the node's ``timing``
    (:func:`status`) :func:`timing_values`, with ``stage_times`` (stage -> s,
    :data:`~.camera_input.STAGES`) each stage's ``<stage>_ms_median`` (``frontend`` only
    ``with_frontend``),
    ``camera_frame_ms_median`` of the cameras' ``frame_times`` together (with any);
    ``frontend``; with ``gyro`` its values
    (:func:`_imu_values`); the failures by reason (a camera alone's ``failed.<reason>`` and
    ``camera_info_rejected.<reason>``; a rig's ``rig_frames_failed.<reason>``); each rig
    camera's section; then the ``gyro_missing.<reason>``, ``gyro_rejected.<reason>`` and
    ``imu_rejected.<reason>`` of ``counts``.

    ``warnings``: the mode's own after its cameras' (a rig's gyro's; the level and message:
    :func:`_level_and_message`); ``absent``: cameras that sent nothing (ERROR while nothing
    is solved)."""

    frames: FrameCounts
    cameras: Sequence[CameraPart] = ()
    warnings: list[str] = field(default_factory=list)
    head: dict[str, Any] = field(default_factory=dict)
    path: dict[str, Any] = field(default_factory=dict)
    path_after: dict[str, Any] = field(default_factory=dict)
    map_fit: Mapping[str, int] | None = None
    tracking: dict[str, Any] = field(default_factory=dict)
    stage_times: Mapping[str, Sequence[float]] | None = None
    with_frontend: bool = False
    frontend: dict[str, Any] = field(default_factory=dict)
    gyro: GyroState | None = None
    counts: Mapping[str, int] = field(default_factory=dict)
    absent: Sequence[str] = ()

    @property
    def alone(self) -> bool:
        """One camera alone (its section named "", solved in ``frames``)."""
        return [c.name for c in self.cameras] == [""]

    @property
    def unit(self) -> str:
        """What is solved: ``frames`` (a camera alone) or ``rig frames``."""
        return "frames" if self.alone else "rig frames"


#: a camera alone's input counts, after the estimator's path
_INPUT_KEYS = ("messages_lost", "points_dropped", "clouds_capped", "unknown_landmark_ids",
               "camera_info_rejected")  # fmt: skip


def status(
    p: StatusParts, timing: tuple[Sequence[float], Sequence[float]] | None = None
) -> tuple[int, str, dict[str, Any]]:
    """``(level, message, values)`` of a camera's or a rig's status, the one builder of both
    modes' statuses: from its :class:`StatusParts` and the node's ``timing`` (``(latencies,
    stamp_ages)``, s; None: no timing keys; values in its order, each camera's section of
    :meth:`CameraPart.section`; level and message :func:`_level_and_message`, with the map-fit
    check's note while it doubts the map and the level is not OK, then the estimator path's
    note off the compiled path, then the cameras that sent nothing named first while nothing
    is solved)."""
    f, unit = p.frames, p.unit
    compile_values, note = _compile_values(unit)
    sections = [c.section() for c in p.cameras]
    alone = sections[0] if p.alone else {}
    sections = [] if p.alone else sections
    if p.alone:
        accounting = {_FLAT_KEYS[k]: alone[_FLAT_KEYS[k]] for k in FRAME_ACCOUNTING}
        reasons = {k: v for k, v in alone.items() if k.startswith(("failed.", _INFO_REJECTED))}
    else:
        accounting = {"rig_frames": f.received}
        accounting.update({f"rig_frames_{k}": getattr(f, k) for k in FRAME_ACCOUNTING[1:]})
        reasons = {f"rig_frames_failed.{k}": v for k, v in sorted(f.failures.items())}
    values: dict[str, Any] = {**p.head, **accounting, **compile_values, **p.path}
    values.update({k: alone[k] for k in _INPUT_KEYS if k in alone})
    values.update(p.path_after)
    if p.map_fit is not None:
        key = unit.replace(" ", "_") + "_failed_with_matches"
        values[key] = p.map_fit.get(key, 0)
        values["map_fit_doubtful"] = str(bool(p.map_fit.get("map_fit_doubtful", 0))).lower()
    values.update(p.tracking)
    if timing is not None:
        values.update(timing_values(*timing))
    for k, d in (p.stage_times or {}).items():
        if p.with_frontend or k != "frontend":
            values[f"{k}_ms_median"] = _median_ms(d)
    times = [c.frame_times for c in p.cameras if c.frame_times is not None]
    if times:  # (the cameras' frames together)
        values["camera_frame_ms_median"] = _median_ms([t for ts in times for t in ts])
    values.update(p.frontend)
    if p.gyro is not None:
        values.update(_imu_values(p.gyro))
    values.update(reasons)
    for section in sections:
        values.update(section)
    prefixes = ("gyro_missing.", "gyro_rejected.", "imu_rejected.")
    values.update({k: v for k, v in sorted(p.counts.items()) if k.startswith(prefixes)})
    level, message = _level_and_message(p, values)
    if values.get("map_fit_doubtful") == "true" and level != OK:
        message += _map_fit_note(unit)
    message += note
    if p.absent and f.solved == 0:  # (a camera silent: named first)
        nothing = _nothing_solved(p)
        rest = "" if level == OK else message.removeprefix(f"{nothing}: ")
        rest = "" if rest == nothing else rest
        level = ERROR
        message = f"{nothing}: no frame from camera {', '.join(p.absent)}"
        message += f"; {rest}" if rest else ""
    return level, message, values


def _nothing_solved(p: StatusParts) -> str:
    """The message's head while nothing is solved: a camera alone's ``no frame solved`` with
    its failures by reason, a rig's ``no rig frame posed``."""
    failed = dict(sorted(p.frames.failures.items()))
    if not p.alone:
        return "no rig frame posed"
    return "no frame solved" + (f" ({failed})" if failed else "")


def _level_and_message(p: StatusParts, values: Mapping[str, Any]) -> tuple[int, str]:
    """The level and message of :func:`status` (before its notes), of the accounting
    ``p.frames`` and the warnings: ERROR while nothing is solved (:func:`_nothing_solved`; a
    camera alone: frames arrived and none was solved; a rig: rig frames were tried and none
    was posed; a rig's message goes on with its warnings and failures), WARN with a warning
    (the mode's ``warnings``; the gyro contradicting the image; the rolling-shutter timing
    suspect, ``readout_suspect``; no usable IMU sample for :data:`IMU_IDLE_WARN_S` while
    frames arrive; then a rig's cameras' frames dropped from a full queue, their messages
    lost and its failed rig frames by reason), else OK. The message lists every warning, a
    camera alone's after its count (``<solved>/<received> frames solved``, its skips; a
    failed or skipped frame, a lost message: the count says it), a rig's alone, OK
    ``<solved> rig frames posed``."""
    f, g, unit = p.frames, p.gyro, p.unit
    ws = [*dict.fromkeys(w for c in p.cameras for w in c.warnings), *p.warnings]
    fault = p.alone and (f.failed or values["messages_lost"] or f.skipped)  # (its count says it)
    if g is not None and g.inconsistent:
        ws.append(
            "the gyro contradicts the image (check imu.rotation, imu.time_offset): "
            f"{unit} solved without it"
        )
    if values.get("readout_suspect") == "true":
        ws.append(readout_warning(values["readout_contradicted"], rig=not p.alone))
    if g is not None and f.received and g.idle_s is not None and g.idle_s > IMU_IDLE_WARN_S:
        ws.append(_imu_idle_text(g.idle_s, g.counts.get("imu_rejected", 0), unit))
    if p.alone:  # (its count says its failed and skipped frames and its lost messages)
        tried, faults, failed = f.received, (), ""
        lead = f"{f.solved}/{f.received} frames solved" + (
            f", {f.skipped} skipped (busy)" if f.skipped else ""
        )
        calm = lead if f.received else "waiting for frames"
    else:  # (a rig frame still open or dropped is not tried)
        tried, lead, calm = f.received - f.pending - f.skipped, "", f"{f.solved} rig frames posed"
        own = [c.counts or {} for c in p.cameras]
        busy = sum(c.get("skipped.queue_full", 0) for c in own)
        lost = sum(c.get("messages_lost", 0) for c in own)
        why = ", ".join(f"{k} {v}" for k, v in sorted(f.failures.items()))
        failed = f"{f.failed} rig frames failed ({why})" if f.failed else ""
        faults = [
            busy and f"busy: {busy} camera frames dropped from a full queue (queue_size)",
            lost and f"{lost} camera messages lost by the middleware (QoS message_lost)",
        ]
    if tried > 0 and f.solved == 0:
        why = [] if p.alone else [w for w in (*ws, failed) if w]
        return ERROR, _nothing_solved(p) + (f": {'; '.join(why)}" if why else "")
    ws += [w for w in (*faults, failed) if w]
    return (WARN, "; ".join([lead, *ws] if lead else ws)) if ws or fault else (OK, calm)


def _map_fit_note(unit: str) -> str:
    """The message's note while the map-fit check doubts the map (``unit``: what is solved,
    ``frames`` or ``rig frames``; :class:`~rs_localizer.ros.pipeline.MapFitCheck`)."""
    return (
        f"; most {unit} with many matches refused: does the map fit this place? mirrored or "
        "another room?"
    )


def frontend_values(kind: str, frontend: FrontendHooks, stats: StatsSnapshot) -> dict[str, Any]:
    """The single camera's front-end values (``frontend``: its image front end of ``kind``,
    the camera's loaded maps'; ``stats``: its counters): ``frontend``,
    ``image_frames``, ``frames_beside_frontend``, ``frontend_ms_last``,
    ``frontend_correspondences_last``, ``frontend_correspondences_mean``, ``frontend_ms_p99``,
    then the front end's summary (a tracking front end's) or ``frontend_frames_global``, and
    a feature front end's ``frontend_few_match_frames``."""
    c = stats.counts
    values: dict[str, Any] = {}
    fe = stats.stage_times["frontend"]
    runs = c.get("frontend_runs", 0)
    values.update(
        {
            "frontend": kind,
            "image_frames": c.get("image_frames", 0),
            "frames_beside_frontend": c.get("frames_beside_frontend", 0),
            "frontend_ms_last": f"{fe[-1] * 1e3:.3f}" if fe else "nan",
            "frontend_correspondences_last": stats.frontend_last,
            "frontend_correspondences_mean": (
                f"{c.get('frontend_points', 0) / runs:.1f}" if runs else "0"
            ),
            "frontend_ms_p99": f"{np.percentile(fe, 99) * 1e3:.3f}" if fe else "nan",
        }
    )
    summary = frontend.summary()  # (a tracking front end's)
    values.update(summary if summary is not None else {"frontend_frames_global": runs})
    few = frontend.few_match_frames  # (a feature front end's)
    if few is not None:
        values["frontend_few_match_frames"] = few
    return values


def _imu_idle_text(idle_s: float, rejected: int, unit: str) -> str:
    """The warning of a gyro without a usable sample for ``idle_s`` s while ``unit`` (frames,
    rig frames) arrive."""
    return (
        f"no usable IMU sample for {idle_s:.1f} s ({rejected} IMU messages rejected): {unit} "
        "solved without the gyro; check the imu topic and its stamps"
    )


def _imu_values(g: GyroState) -> dict[str, Any]:
    """The gyro's values of a camera's or a rig's status (:class:`GyroState`): the buffered
    samples' rate, frames solved with the gyro, rejected by the image, without samples, IMU
    messages rejected, s without a usable sample, the bias used and its standard deviation
    (rad/s, IMU frame), pairs the bias estimator rejected, the check of the gyro against the
    rotation between frames (contradicted now, frames solved without it, pairs failed,
    detections)."""
    c, imu = g.counts, g.settings
    bias, std = g.bias or (imu.gyro_bias, np.full(3, imu.gyro_bias_sigma))
    return {
        "imu_rate_hz": f"{g.rate_hz or 0.0:.1f}",
        "frames_with_gyro": c.get("frames_with_gyro", 0),
        "gyro_rejected": c.get("gyro_rejected", 0),
        "gyro_missing": c.get("gyro_missing", 0),
        "imu_rejected": c.get("imu_rejected", 0),
        "imu_idle_s": "nan" if g.idle_s is None else f"{g.idle_s:.1f}",
        "gyro_bias": " ".join(f"{b:.5f}" for b in bias),
        "gyro_bias_std": " ".join(f"{b:.5f}" for b in std),
        "gyro_bias_rejected": c.get("gyro_bias_rejected", 0),
        "gyro_inconsistent": str(bool(g.inconsistent)).lower(),
        "gyro_disabled_inconsistent": c.get("gyro_disabled_inconsistent", 0),
        "gyro_pairs_failed": c.get("gyro_pairs_failed", 0),
        "gyro_inconsistent_detections": c.get("gyro_inconsistent_detections", 0),
    }


@dataclass
class CameraAlone:
    """The camera alone's own values of its status (:func:`status_parts`), its section's keys
    at the top: its ``solver``, where its intrinsics come from (``source``: ``camera_info`` or
    ``parameters``), ``queue_size``, its counters (``stats``: its
    :class:`~rs_localizer.ros.pipeline.PipelineStats` snapshot), the messages the middleware
    lost (``messages_lost``) and, with an image front end, its values (``frontend``,
    :func:`frontend_values`; None: no front end)."""

    solver: str
    source: str
    queue_size: int
    stats: StatsSnapshot
    messages_lost: int = 0
    frontend: dict[str, Any] | None = None

    def part(self) -> CameraPart:
        """Its one section (:class:`CameraPart` named ""): its frames
        (:func:`~rs_localizer.ros.frame_queue.frame_accounting` of its counts), its counts and
        ``messages_lost``."""
        c = self.stats.counts
        return CameraPart("", frame_accounting(c), {**c, "messages_lost": self.messages_lost},
                          frontend=self.frontend is not None)  # fmt: skip


def status_parts(
    cameras: Sequence[CameraPart],
    tracking: Mapping[str, Any],
    counts: Mapping[str, int] | None,
    gyro: GyroState | None = None,
    stage_times: Mapping[str, Sequence[float]] | None = None,
    with_frontend: bool = False,
    alone: CameraAlone | None = None,
    rig_frames: FrameCounts | None = None,
    rig_path: Mapping[str, Any] | None = None,
    warnings: Sequence[str] = (),
    absent: Sequence[str] = (),
    map_fit: bool = True,
) -> StatusParts:
    """The one builder of a status's parts, of the camera alone and of a rig (:func:`status`
    lays them out): a section per camera (``cameras``: the camera alone's
    :meth:`CameraAlone.part`, its flat keys; each rig camera's :func:`rig_camera_status`),
    the track's values (``tracking``:
    :meth:`~rs_localizer.tracking.video.Localizer.tracking_values`), the mode's ``counts``
    (the ``gyro_missing.<reason>``, ``gyro_rejected.<reason>``, ``imu_rejected.<reason>``
    and, ``map_fit``, the map-fit check's; None: none known), the ``gyro`` with ``imu.enabled``, the
    stage times (``frontend`` only ``with_frontend``). The camera alone (``alone``) is solved
    in its section's frames, with its own values at the top: ``solver``, ``camera``; after
    the estimator's path ``frames_compiled``, ``frames_uncompiled``, ``queue_size``,
    ``time_resets``, then ``frames_few_points``, ``frames_single_tag``; ``inliers_last``,
    ``inliers_mean``, ``planar`` before the track's values and ``condition_number_last``
    after them; its front end's values. A rig's own part: its rig frames (``rig_frames``),
    after the estimator's path ``rig_path`` (``rig_frames_uncompiled``, ``time_resets``), its
    ``warnings`` and the cameras that sent nothing (``absent``)."""
    head: dict[str, Any] = {}
    path_after: dict[str, Any] = {}
    frontend: dict[str, Any] = {}
    track = dict(tracking)
    if alone is not None:
        c, s = alone.stats.counts, alone.stats
        rig_frames = cameras[0].frames
        head = {"solver": alone.solver, "camera": alone.source}
        rig_path = {
            "frames_compiled": c.get("frames_compiled", 0),
            "frames_uncompiled": c.get("frames_uncompiled", 0),
            "queue_size": alone.queue_size,
            "time_resets": c.get("time_resets", 0),
        }
        path_after = {"frames_few_points": c.get("frames_few_points", 0),
                      "frames_single_tag": c.get("frames_single_tag", 0)}  # fmt: skip
        track = {
            "inliers_last": s.inliers[-1] if s.inliers else 0,
            "inliers_mean": f"{np.mean(s.inliers):.1f}" if s.inliers else "0",
            "planar": str(s.planar).lower(),
            **tracking,
            "condition_number_last": f"{s.condition_number:.3g}",
        }
        frontend = alone.frontend or {}
    return StatusParts(
        frames=rig_frames,
        cameras=list(cameras),
        warnings=list(warnings),
        head=head,
        path=dict(rig_path or {}),
        path_after=path_after,
        map_fit=counts if map_fit else None,
        tracking=track,
        stage_times=stage_times,
        with_frontend=with_frontend,
        frontend=frontend,
        gyro=gyro,
        counts=counts or {},
        absent=list(absent),
    )


def localizer_status_parts(
    rig: Localizer,
    alone: CameraAlone | None = None,
    waiting_info: Collection[str] = (),
    inputs: RigInputs | None = None,
) -> StatusParts:
    """The status's parts of the node's localizer ``rig`` (:func:`status_parts`), of the
    camera alone (``alone``: its own values and counts, its gyro counted in them) or of a rig
    of cameras: a section per camera (:func:`rig_camera_status`, ``waiting_info`` the
    cameras waiting for their camera_info; with the node's ``inputs``, None: the rig's counts
    alone, also its map-fit check, its stage times, each camera's and all cameras'
    ``camera_frame_ms_median``, the IMU messages rejected, ``imu_rejected.<reason>``, and the
    cameras that sent nothing, ``absent``) and the rig's own part: its rig frames
    (``rig_frames``, ``rig_frames_solved`` ... ``_pending``; the rig estimator's failures by
    reason, ``rig_frames_failed.<reason>``, ``error``: it raised), ``rig_frames_uncompiled``
    (rig frames solved on the uncompiled path), ``time_resets`` and its warning when the
    image rejects the gyro more often than it uses it (while the gyro is not found to
    contradict the image). Either way the track's values
    (:meth:`~rs_localizer.tracking.video.Localizer.tracking_values`) and, with
    ``imu.enabled``, the gyro's (:class:`GyroState`; a rig's counts
    :meth:`~rs_localizer.tracking.video.Localizer.gyro_counts`, the rig frames for its
    frames)."""
    warnings: list[str] = []
    if alone is not None:
        cameras, counts = [alone.part()], alone.stats.counts
        stage_times, frontend, gyro_counts = alone.stats.stage_times, alone.frontend, counts
        frames = path = None
        with_frontend = frontend is not None
    else:  # (a rig's own part: its rig frames, its cameras' state in it)
        cameras = [rig_camera_status(rig, n, waiting_info, inputs) for n in rig.cameras]
        counts, stage_times, imu_rejected = {}, None, {}
        if inputs is not None:
            imu_rejected, stage_times = inputs.imu_rejected, inputs.stage_times
            counts = {**inputs.counts, **{f"imu_rejected.{k}": v for k, v in imu_rejected.items()}}
        with_frontend = inputs is not None and inputs.frontend
        gyro_counts = {**rig.gyro_counts(), "imu_rejected": sum(imu_rejected.values())}
        r, failed = rig.rig_counts(), "rig.failed."
        failures = {k[len(failed) :]: v for k, v in rig.counts.items() if k.startswith(failed)}
        frames = FrameCounts(r["rig_frames"], *(r[k] for k in FRAME_ACCOUNTING[1:]),
                             failures=failures)  # fmt: skip
        path = {"rig_frames_uncompiled": rig.counts.get("rig.uncompiled", 0),
                "time_resets": rig.counts.get("rig.time_resets", 0)}  # fmt: skip
        c = gyro_counts
        if (rig.settings.imu is not None and not rig.gyro_inconsistent
                and c.get("gyro_rejected", 0) > c.get("frames_with_gyro", 0)):  # fmt: skip
            warnings.append("the image contradicts the gyro: check imu.rotation, its bias")
    gyro = None
    if rig.settings.imu is not None:
        gyro = GyroState.of(rig.settings.imu, gyro_counts, rig.imu, rig.gyro_bias_values(),
                            rig.gyro_inconsistent)  # fmt: skip
        if alone is None:
            counts = {**gyro_counts, **counts}
    absent = inputs.absent if inputs is not None else ()
    return status_parts(cameras, rig.tracking_values(), counts, gyro, stage_times, with_frontend,
                        alone, frames, path, warnings, absent,
                        map_fit=alone is not None or inputs is not None)  # fmt: skip


# ---------------------------------------------------------------------- a rig of cameras
@dataclass
class RigInputs:
    """What the node's mode (:class:`~rs_localizer.ros.mode.LocalizerMode`) knows of a rig's frames
    before they reach the rig, for its cameras' sections (:func:`rig_camera_status`).

    ``counts``: the node's map-fit check over the rig frames
    (``rig_frames_failed_with_matches``, ``map_fit_doubtful``) and each camera's
    :class:`~rs_localizer.ros.camera_input.CameraCounts` after ``<c>.``: ``received`` (by
    the subscriptions), ``skipped.<reason>`` (the
    node's reasons, :data:`~rs_localizer.ros.frame_queue.QUEUE_SKIP_REASONS`),
    ``failed.internal_error``, its input stage's counts (``capped_clouds``,
    ``points_dropped``, ``camera_info_rejected[.<reason>]``, ``unknown_landmark_ids``),
    ``frames_beside_frontend``, ``messages_lost`` (:func:`camera_section`) and ``bad_input``
    (clouds not read).
    ``frontend``: the cameras' front end runs. ``frame_times`` (camera -> s, the worker's time per
    camera frame: decoding, front end, rig), ``imu_rejected`` (reason -> IMU messages rejected),
    ``absent`` (cameras without a frame though the rig has waited ``rig.stop_after`` since the
    first), ``stage_times`` (the worker's times per stage: the rig's counts',
    :meth:`~.camera_input.CameraCounts.stage_times`)."""

    counts: Mapping[str, int] = field(default_factory=dict)
    frame_times: Mapping[str, Sequence[float]] = field(default_factory=dict)
    imu_rejected: Mapping[str, int] = field(default_factory=dict)
    absent: Sequence[str] = ()
    frontend: bool = False
    stage_times: Mapping[str, Sequence[float]] = field(default_factory=dict)


def rig_camera_frames(rig: Localizer, n: str, own: Mapping[str, int] | None = None) -> FrameCounts:
    """Camera ``n``'s frame accounting as the rig node reports it (received = solved + failed
    + skipped + pending): the rig's
    (:meth:`~rs_localizer.tracking.video.Localizer.camera_counts`, its ``<c>.skipped.<reason>``
    the skips by reason) alone, or with the node's own counts of the camera ``own`` (keys
    without the ``<c>.`` prefix, :class:`RigInputs`' ``counts``) the single camera's
    accounting of them with the rig's (:func:`~rs_localizer.ros.frame_queue.frame_accounting`:
    ``received`` the node's, every message; the node's ``skipped.<reason>`` and
    ``failed.<reason>`` with the rig's; the frames the node or the rig still holds
    ``pending``). The rig node's diagnostics and ``replay`` of a rig bag
    (:func:`~rs_localizer.ros.bags.replay.replay`) both count a camera's frames so."""
    skip = f"{n}.skipped."
    skips = {k[len(skip) :]: v for k, v in rig.counts.items() if k.startswith(skip)}
    handed = FrameCounts(**rig.camera_counts(n), skips=skips)
    return handed if own is None else frame_accounting(own, handed)


def rig_camera_part(
    rig: Localizer,
    n: str,
    own: Mapping[str, int] | None,
    frontend: bool = False,
    frame_times: Sequence[float] | None = None,
) -> CameraPart:
    """Camera ``n``'s accounting in a rig (a :class:`CameraPart` named ``n``, without its
    lines): its frames of :func:`rig_camera_frames` (the rig's and the node's ``own`` counts
    of the camera, keys without the ``<n>.`` prefix; None: the rig's alone), its rows' counts
    of the node's clouds and the rig's images (``Localizer.process_image``) summed, and with
    ``own`` its input stage's counts."""
    theirs = {k[len(n) + 1 :]: v for k, v in rig.counts.items() if k.startswith(f"{n}.")}
    return CameraPart(n, rig_camera_frames(rig, n, own), own, theirs, frontend, frame_times)


def rig_camera_section(rig: Localizer, n: str, own: Mapping[str, int] | None) -> dict[str, Any]:
    """Camera ``n``'s accounting values in a rig, each key ``<n>.<key>``
    (:func:`camera_section` of :func:`rig_camera_part`): the rig node's diagnostics and
    ``replay`` of a rig bag both take a camera's accounting from it."""
    return rig_camera_part(rig, n, own).section()


def rig_camera_status(
    rig: Localizer, n: str, waiting_info: Collection[str] = (), inputs: RigInputs | None = None
) -> CameraPart:
    """Camera ``n``'s section of the rig's status (``waiting_info``: the cameras waiting for their
    camera_info; ``inputs``: the node's, None: the rig's counts alone): its :func:`rig_camera_part`
    (with the node's ``inputs`` its counts and ``camera_frame_ms_median``) with the rig's own lines,
    each key ``<c>.<key>``: ``state`` (waiting, running, stopped, disagrees), ``camera_info``
    (received or waiting), ``inliers``, ``inlier_share``, ``inlier_ratio`` (of the last rig frame it
    was in), ``missed`` and the rig's ``skipped.<reason>`` / ``missed.<reason>`` counts,
    ``outvoted`` (posed rig frames whose consensus outvoted it), ``frames_apart`` (yes: its frames
    never join the others', ``Localizer.camera_apart``), then ``clock_offset_ms.<other>`` (its
    apparent clock offset from each other camera, ms); with ``inputs`` also ``stamp_jumped_ahead``
    (first) and ``bad_input`` (last: its clouds not read); its ``warnings``: its frames never join
    the others' (``camera left: frames never join the others' (+15.5 ms from front): clock likely
    off``), it disagrees with the rig or with its partner, the cameras' consensus outvoted it in its
    last rig frame, it stopped (``camera right stopped: no frame received from it (is
    right/correspondences published in the node's namespace?)`` when the node never received
    one), it waits for its camera_info."""
    own: dict[str, int] | None = None
    if inputs is not None:
        own = {k[len(n) + 1 :]: v for k, v in inputs.counts.items() if k.startswith(f"{n}.")}
    times = inputs.frame_times.get(n, ()) if inputs is not None else None
    camera = rig_camera_part(rig, n, own, inputs is not None and inputs.frontend, times)
    values: dict[str, Any] = {}  # (its lines, after its accounting)
    warnings = camera.warnings
    if own is not None:
        values[f"{n}.stamp_jumped_ahead"] = rig.counts.get(f"{n}.stamp_jumped_ahead", 0)
    state = rig.camera_state(n)
    if n in waiting_info and state in ("running", "stopped"):
        state = "waiting"  # (its frames wait for the camera_info)
    values[f"{n}.state"] = state
    values[f"{n}.camera_info"] = "waiting" if n in waiting_info else "received"
    s = rig.last_share(n)
    values[f"{n}.inliers"] = s.inliers if s else 0
    values[f"{n}.inlier_share"] = f"{s.share:.3f}" if s else "nan"
    values[f"{n}.inlier_ratio"] = f"{s.ratio:.3f}" if s else "nan"
    values[f"{n}.missed"] = sum(v for k, v in rig.counts.items() if k.startswith(f"{n}.missed."))
    for k, v in sorted(rig.counts.items()):
        if k.startswith((f"{n}.skipped.", f"{n}.missed.")) and k not in values:
            values[k] = v
    outvoted = rig.counts.get(f"{n}.outvoted", 0)
    values[f"{n}.outvoted"] = outvoted
    apart = rig.camera_apart(n)
    values[f"{n}.frames_apart"] = "yes" if apart is not None else "no"
    for m, off in (apart or {}).items():
        values[f"{n}.clock_offset_ms.{m}"] = f"{1e3 * off:+.1f}"
    if apart is not None:
        offs = offsets_text(apart, quoted=False, unknown="offset unknown")
        warnings.append(f"camera {n}: frames never join the others' ({offs}): clock likely off")
    partner = rig.camera_partner(n) if state == "disagrees" else None
    if partner is not None:
        warnings.append(  # (both cameras' text: the status names the pair once)
            f"cameras {min(n, partner)} and {max(n, partner)} disagree: the mounting of one "
            "of them is likely wrong (two cameras cannot tell which)"
        )
    elif state == "disagrees":
        also = f" (outvoted by the others in {outvoted} rig frames)" if outvoted else ""
        warnings.append(f"camera {n} disagrees with the rig{also}: likely a wrong mounting")
    elif s is not None and s.outvoted:
        warnings.append(
            f"camera {n} outvoted by the others in its last rig frame ({outvoted} so far): "
            "its mounting, clock, line delay or matches are likely wrong"
        )
    elif state == "stopped" and own is not None and not own.get("received", 0):
        topic = (
            f"{n}/image_raw" if inputs is not None and inputs.frontend else f"{n}/correspondences"
        )
        warnings.append(
            f"camera {n} stopped: no frame received from it (is {topic} published in the "
            "node's namespace?)"
        )
    elif state == "stopped":
        warnings.append(f"camera {n} stopped")
    if n in waiting_info:
        warnings.append(f"camera {n} waits for its camera_info")
    if own is not None:
        values[f"{n}.bad_input"] = own.get("bad_input", 0)
    camera.lines = values
    return camera
