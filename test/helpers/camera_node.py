"""The node's camera alone (``rig.cameras`` empty) without DDS: its one mode
(:class:`rs_localizer.ros.mode.LocalizerMode`) over a stand-in for the node's plumbing, each
frame message through the worker's frame step (``take_frame``) as the node takes it."""

from __future__ import annotations

import logging
from types import SimpleNamespace
from typing import Any


class _Plumbing:
    """What the mode calls on the node (:class:`rs_localizer.ros.core.NodeCore`): its
    cameras, log, settings; nothing published."""

    def __init__(self, logger: Any):
        self._logger = logger if logger is not None else logging.getLogger("rs_localizer.test")
        from rs_localizer.ros.frame_queue import BetweenFrames

        self._between = BetweenFrames()  # (the worker's frames: the node's)
        self.inputs, self.camera_counts, self.landmarks = {}, {}, None
        self.frontend_kind, self.republish, self.map_frame = "none", False, "map"
        self.images_of, self.queue_size, self.image_transport = {}, 10, "raw"
        self.viz, self.camera_viz, self._warned = None, {}, set()

    def get_parameter(self, name: str) -> SimpleNamespace:
        return SimpleNamespace(value=[] if name == "rig.cameras" else False)

    def get_logger(self) -> Any:
        return self._logger

    def stopping(self) -> bool:
        return False

    def set_cameras(self, inputs, counts, log, group=None, worker="") -> None:
        self.inputs, self.camera_counts, self._log = inputs, counts, log

    def warn(self, key: str, text: str, count: int = 0) -> None:
        self._log.warning(key, text, count)

    def warn_once(self, key: str, text: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            self._logger.warning(text)

    def open_found_output(self, name: str = "") -> None:
        pass

    def between_frames(self, step) -> None:
        self._between.run(step)


class CameraNode:
    """The camera alone of the node's one mode, configured with ``cfg``
    (:class:`~rs_localizer.ros.config.LocalizerConfig`) and ``maps`` (its loaded maps; None:
    none), its warnings to ``log`` (a logger; None: Python's logging). :meth:`process` takes
    a frame message as the node's worker does (its stamp checked as it arrived, then the
    mode's frame step) and returns the mode's
    :class:`~rs_localizer.ros.mode.CameraFrameResult`, without counting it (the node's queue
    and worker count ``received``, ``solved``, ``failed.<reason>``); an exception of the
    frame step is raised (the node's worker counts it ``failed.internal_error``)."""

    def __init__(self, cfg: Any = None, log: Any = None, maps: Any = None):
        from rs_localizer.ros.mode import LocalizerMode

        self.node = _Plumbing(log)
        self.mode = LocalizerMode(self.node)
        if cfg is not None:
            self.configure(cfg, maps)

    def configure(self, cfg: Any, maps: Any = None) -> None:
        """The configuration taken, as at configure and at a parameter change."""
        from rs_localizer.frontends.shared import LoadedMaps

        maps = maps if maps is not None else LoadedMaps()
        own = maps.frontend is not None and cfg.camera.frontend_kind == "none"
        if own:  # (a test's own front end, not a parameter's)
            self.mode._start_with((cfg, {"": LoadedMaps(landmarks=maps.landmarks)}))
            self.set_frontend(maps.frontend, "custom")
            return
        self.mode._start_with((cfg, {"": maps}))

    def set_frontend(self, frontend: Any, label: str) -> None:
        """A test's own front end on the camera's images."""
        self.rig.set_frontend("", frontend, label)
        self.node.frontend_kind = label

    @property
    def input(self) -> Any:
        """The camera's :class:`~rs_localizer.ros.camera_input.CameraInput`."""
        return self.node.inputs[""]

    @property
    def stats(self) -> Any:
        """The camera's counts (:class:`~rs_localizer.ros.pipeline.PipelineStats`)."""
        return self.node.camera_counts[""]

    @property
    def rig(self) -> Any:
        """The camera's rig of one (:class:`~rs_localizer.tracking.video.Localizer`)."""
        return self.mode.rig

    def add_camera_info(self, msg: Any) -> Any:
        return self.input.add_camera_info(msg)

    def add_imu(self, msg: Any) -> str | None:
        """The node's ``imu`` callback's step (the mode's gyro input)."""
        return self.mode._take_imu(msg)

    def process(self, msg: Any, kind: str) -> Any:
        from rs_localizer.ros.core import QueuedFrame

        stamp = self.input.check(msg, kind)
        return self.mode.take_frame(QueuedFrame("", kind, msg, 0.0, stamp)).result

    def outcome(self, res: Any) -> Any:
        """What the node publishes for the frame's result (a
        :class:`~rs_localizer.ros.outputs.FrameOutcome`)."""
        (outcome,) = self.mode.outcomes("", res)
        return outcome

    def flush(self) -> list:
        """The end of the video: the fused twists still pending, as published."""
        return self.mode._fused(self.rig.flush())

    def tracking_values(self) -> dict:
        return self.rig.tracking_values()

    def camera_source(self) -> str:
        return self.input.source()

    @property
    def gyro_bias(self) -> Any:
        return self.rig.gyro_bias

    @property
    def gyro_check(self) -> Any:
        return self.rig.gyro_check

    @property
    def gyro_inconsistent(self) -> bool:
        return self.rig.gyro_inconsistent

    def gyro_bias_values(self) -> Any:
        return self.rig.gyro_bias_values()

    def diagnostics(self) -> Any:
        """The mode's ``(hardware_id, StatusParts)``."""
        return self.mode.diagnostics()
