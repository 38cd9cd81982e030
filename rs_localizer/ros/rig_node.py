"""What only a rig of several cameras needs in ``rs_localizer_node`` (``rig.cameras`` set; the
node's one mode, :class:`~rs_localizer.ros.mode.LocalizerMode`, takes each camera's frames on
its ``<c>/`` topics through the camera alone's steps and publishes the rig, ``base_frame``, as
one body; topics, parameters, counts and diagnostics: docs/rig_node.md): its cameras'
parameters (``rig.<c>.*``, :func:`declare_rig_cameras`, :func:`rig_values`; a change at run
time is refused for those a rig cannot take without a restart), its cameras' inputs and counts
with the frame queue grouping queued frames into rig frames (:func:`new_rig_cameras`,
:class:`SameRigFrame`: a full queue drops whole rig frames), its ready line and log lines
(:func:`rig_ready_subject`, :func:`rig_failure_line`) and its cameras' debug views
(:func:`rig_views`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ..runtime.background import ready_implementation
from ..tracking.video import Localizer, LocalizerOutput
from .camera_input import CameraCounts, DroppedFrame, rig_camera_inputs
from .config import LocalizerConfig, rig_camera_names, rig_change_refused, same_value
from .core import names_a_rig
from .declare import declare_dynamic, declare_parameters
from .outputs import CameraView, LogLine, rig_frame_views
from .params import RIG_CAMERA_PARAMETERS, RIG_PARAMETERS, ConfigError
from .pipeline import ThrottledLog

__all__ = [
    "RIG_TEXTS",
    "SameRigFrame",
    "declare_rig_cameras",
    "new_rig_cameras",
    "rig_failure_line",
    "rig_ready_subject",
    "rig_values",
    "rig_views",
]

#: the rig's topics and texts (:class:`~rs_localizer.ros.core.ModeBase`'s attributes): its
#: cameras' clouds on ``<c>/correspondences`` as ``cloud`` frames, images on ``<c>/image_raw``,
#: keypoints only with ``landmarks_file``, a frame dropped from a full queue counted
#: ``<c>.skipped.queue_full``
RIG_TEXTS = {
    "count_image_frames": False,
    "cloud_kind": "cloud",
    "image_topic": "image_raw",
    "keypoints_always": False,
    "busy_key": "queue_full",
    "busy_text": (
        "busy: frame queue full ({size} frames, queue_size {queue_size} per camera), dropped "
        "the oldest waiting frame [{dropped} dropped so far]"
    ),
    "mode_note": ", rig mode",
}


def declare_rig_cameras(node: Any) -> list[str]:
    """The rig's camera names of ``rig.cameras`` (they make parameter and topic names; none
    for the camera alone, ``rig.cameras`` empty), each camera's ``rig.<camera>.*`` declared
    on ``node`` on first use.

    Raises:
        ConfigError: names that cannot be used.
    """
    value = node.get_parameter("rig.cameras").value
    names = rig_camera_names(value) if names_a_rig(value) else []
    own = {k: v for k, v in RIG_CAMERA_PARAMETERS.items() if k != "mounting"}
    for n in names:
        if not node.has_parameter(f"rig.{n}.line_delay"):
            declare_parameters(node, {f"rig.{n}.{k}": v for k, v in own.items()})
            declare_dynamic(node, f"rig.{n}.mounting", RIG_CAMERA_PARAMETERS["mounting"])
    return names


def rig_values(node: Any, overrides: dict, current: LocalizerConfig | None = None
               ) -> tuple[dict, dict | None]:  # fmt: skip
    """A rig's own parameter values for :func:`.config.build_config`: ``(values, cameras)``,
    the :data:`~.params.RIG_PARAMETERS` (``rig.cameras`` its names) and each camera's
    ``rig.<c>.*``; ``({}, None)`` for the camera alone (``rig.cameras`` empty). With
    ``current``, the configuration the rig runs with (None: at configure, unchecked), a change
    of ``overrides`` (name -> value) is refused for the parameters a rig cannot take without
    a restart (:func:`.config.rig_change_refused`) unless their value stays the same.

    Raises:
        ConfigError: names that cannot be used, or a change refused (naming them).
    """
    value = node.get_parameter("rig.cameras").value
    if not names_a_rig(value):
        return {}, None
    if current is not None:
        changed = [
            n for n, v in overrides.items() if not same_value(v, node.get_parameter(n).value)
        ]
        refused = rig_change_refused(changed, current.settings.single_camera)
        if refused is not None:
            raise ConfigError(refused)
    names = rig_camera_names(value)
    values = {n: node.get_parameter(n).value for n in RIG_PARAMETERS if n != "rig.cameras"}
    values["rig.cameras"] = names
    cams = {
        n: {k: node.get_parameter(f"rig.{n}.{k}").value for k in RIG_CAMERA_PARAMETERS}
        for n in names
    }
    return values, cams


def new_rig_cameras(node: Any, config: LocalizerConfig) -> tuple[Localizer, CameraCounts, Any]:
    """A rig's cameras handed to ``node`` (:meth:`.core.NodeCore.set_cameras`): each camera's
    input (its camera_infos by stamp, its clouds' rows, its images,
    :func:`.camera_input.rig_camera_inputs`) and counts (the diagnostics' ``<c>.<key>``), the
    frame queue grouped by rig frame (:class:`SameRigFrame`), its log (each kind once per
    5 s). Returns the rig's localizer (its rig frames on the NumPy implementation while the
    kernels compile in the background), the rig's own counts (the worker's map-fit check
    over the rig frames, its times per stage, its IMU messages rejected) and the grouping."""
    log = ThrottledLog(node.get_logger(), period=5.0)
    rig = Localizer(config.settings, log=log, implementation=ready_implementation)
    counts = {c.name: CameraCounts(c.name) for c in config.cameras}
    inputs = rig_camera_inputs(config, log, lambda n, key, k=1: counts[n].add(key, k),
                               stopped=node.stopping, wait=config.camera_info_wait)  # fmt: skip
    grouping = SameRigFrame(config.settings, inputs)
    node.set_cameras(inputs, counts, log, grouping, "rs_localizer_rig_worker")
    return rig, CameraCounts(), grouping


class SameRigFrame:
    """Whether a waiting frame goes with the frames the worker takes (the frame queue's
    ``group``, :class:`~.frame_queue.FrameQueue`): another camera's whose reference-line time
    (by the camera's newest camera_info, ``inputs[name].newest``) is within ``rig.window`` of
    the first's, as the rig groups them
    (:meth:`~rs_localizer.tracking.video.LocalizerSettings.reference_ns` of ``settings``). A rig
    frame's frames are then taken together, and a full queue drops whole rig frames, not the
    rest of the one being solved."""

    def __init__(self, settings: Any, inputs: Mapping):
        self.settings, self.inputs = settings, inputs
        self.window_ns = int(settings.window * 1e9)

    def __call__(self, batch: list, item: Any) -> bool:
        if any(b.name == item.name for b in batch):
            return False
        if isinstance(item.stamp, DroppedFrame) or isinstance(batch[0].stamp, DroppedFrame):
            return False  # (a stamp the worker will refuse: not grouped)
        return abs(self._ref_ns(item) - self._ref_ns(batch[0])) <= self.window_ns

    def _ref_ns(self, item: Any) -> int:
        """A queued frame's time on the rig's clock (ns) by its camera's newest model (its
        stamp without one)."""
        return self.settings.reference_ns(item.name, item.stamp, self.inputs[item.name].newest)


def rig_ready_subject(cfg: LocalizerConfig, map_frame: str) -> str:
    """The subject of the rig's ``ready:`` line: its cameras' RS timing, its frames."""
    timing = "; ".join(
        f"{c.name} readout {c.readout_time * 1e3:.2f} ms {c.direction}" if c.readout_time > 0
        else f"{c.name} line delay {c.line_delay * 1e6:.2f} us/line {c.direction}"
        for c in cfg.cameras
    )  # fmt: skip
    return f"rig of {len(cfg.cameras)} cameras ({timing}) posed as {cfg.base_frame} in {map_frame}"


def rig_failure_line(rig: Localizer, out: LocalizerOutput) -> LogLine | None:
    """The line a rig frame logs (each reason at most once per 5 s): why it failed with the
    count of rig frames failed so far for that reason, or on a posed one the cameras outvoted
    by the others; None: nothing to say."""
    if out.error is not None:
        reason, detail = "error", f"the estimator raised {out.error}"
    elif out.estimate is not None and not out.success:
        reason = out.estimate.failure or "error"
        detail = f"{len(out.cameras)} cameras ({', '.join(out.cameras)})"
        if reason == "cameras_disagree" and out.outvoted:
            detail += f"; {', '.join(out.outvoted)} contradict each other"
    elif out.outvoted:
        names = ", ".join(out.outvoted)
        return LogLine(
            f"rig.outvoted.{names}",
            f"rig camera {names}: outvoted by the others (its points contradict their "
            "pose; its mounting, clock, line delay or matches are likely wrong) "
            f"[{rig.counts[f'{out.outvoted[0]}.outvoted']} rig frames so far]",
        )
    else:
        return None
    n = rig.counts[f"rig.failed.{reason}"]
    return LogLine(
        f"rig.failed.{reason}",
        f"rig frame failed ({reason}): {detail} [{n} rig frames failed so far with {reason}]",
    )


def rig_views(out: LocalizerOutput, cfg: LocalizerConfig, camera_viz: Mapping,
              images: Mapping) -> tuple[CameraView, ...]:  # fmt: skip
    """The cameras of a posed rig frame whose debug views are watched (``camera_viz``: camera
    -> its visualization; ``<c>/debug_image`` or ``<c>/markers``), each with its frame's
    image of ``images`` (camera -> its last kept ``(image, encoding, stamp_ns)``):
    :func:`.outputs.rig_frame_views`."""

    def wanted(n: str) -> bool:
        viz = camera_viz.get(n)
        return viz is not None and (viz.wants("debug_image") or viz.wants("markers"))

    return rig_frame_views(out, {c.name: c.mount for c in cfg.cameras}, wanted, images)
