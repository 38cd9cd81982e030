"""What only a rig of several cameras needs in ``rs_localizer_node`` (``rig.cameras`` set;
docs/rig_node.md): its cameras' parameters (``rig.<c>.*``, declared and read by
:func:`rig_values`) and the grouping of queued frames into rig frames (:class:`SameRigFrame`).
The rest of the rig runs where the camera alone's does, in the node's one mode
(:class:`~rs_localizer.ros.mode.LocalizerMode`: its cameras' inputs and counts, ready line),
:mod:`.outputs` (its log lines, debug views) and :mod:`.diagnostics` (its status).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ..tracking.rig import OpenRigFrame, window_ns
from .camera_input import DroppedFrame
from .config import LocalizerConfig, rig_camera_names, rig_change_refused, same_value
from .core import names_a_rig
from .declare import declare_parameters
from .params import RIG_CAMERA_PARAMETERS, ConfigError

__all__ = [
    "RIG_TEXTS",
    "SameRigFrame",
    "rig_values",
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


def rig_values(node: Any, overrides: dict, current: LocalizerConfig | None = None
               ) -> dict | None:  # fmt: skip
    """A rig's cameras' parameter values for :func:`.config.build_config` (the others:
    :meth:`.core.NodeCore.param_values`): camera -> its ``rig.<c>.*``
    (:data:`~.params.RIG_CAMERA_PARAMETERS`, ``mounting`` of any type), each declared on
    ``node`` once, by the first configure that names its camera (a configure retried declares
    those not declared yet); None for the camera alone (``rig.cameras`` empty). With
    ``current``, the configuration the rig runs with (None: at configure, unchecked), a change
    of ``overrides`` (name -> value) is refused for the parameters a rig cannot take without a
    restart (:func:`.config.rig_change_refused`) unless their value stays the same.

    Raises:
        ConfigError: names that cannot be used, or a change refused (naming them).
        RuntimeError: a camera's value of the wrong type or outside its range, naming the
            parameter (:func:`.declare.declare_parameters`; again at a retried configure).
    """
    value = node.get_parameter("rig.cameras").value
    if not names_a_rig(value):
        return None
    names = rig_camera_names(value)
    for n in names:  # (declared already: kept)
        own = {f"rig.{n}.{k}": v for k, v in RIG_CAMERA_PARAMETERS.items()}
        declare_parameters(node, own, dynamic=(f"rig.{n}.mounting",))
    if current is not None:
        changed = [
            n for n, v in overrides.items() if not same_value(v, node.get_parameter(n).value)
        ]
        refused = rig_change_refused(changed, current.settings.single_camera)
        if refused is not None:
            raise ConfigError(refused)
    return {
        n: {k: node.get_parameter(f"rig.{n}.{k}").value for k in RIG_CAMERA_PARAMETERS}
        for n in names
    }


class SameRigFrame:
    """Whether a waiting frame goes with the frames the worker takes (the frame queue's
    ``group``, :class:`~.frame_queue.FrameQueue`): another camera's that the rig's grouping
    would put in their rig frame (:meth:`~rs_localizer.tracking.rig.OpenRigFrame.fits`: the
    reference-line times of the taken frames and its own, by each camera's newest
    camera_info, ``inputs[name].newest``, all within ``rig.window``;
    :meth:`~rs_localizer.tracking.video.LocalizerSettings.reference_ns` of ``settings``). A rig
    frame's frames are then taken together, and a full queue drops whole rig frames, not the
    rest of the one being solved."""

    def __init__(self, settings: Any, inputs: Mapping):
        self.settings, self.inputs = settings, inputs

    def __call__(self, batch: list, item: Any) -> bool:
        if isinstance(item.stamp, DroppedFrame) or isinstance(batch[0].stamp, DroppedFrame):
            return False  # (a stamp the worker will refuse: not grouped)
        g = OpenRigFrame(batch[0].name, batch[0], self._ref_ns(batch[0]))
        for b in batch[1:]:  # (frames grouped with the first: none refused)
            g.add(b.name, b, self._ref_ns(b))
        return g.fits(item.name, self._ref_ns(item), window_ns(self.settings.window))

    def _ref_ns(self, item: Any) -> int:
        """A queued frame's time on the rig's clock (ns) by its camera's newest model (its
        stamp without one)."""
        return self.settings.reference_ns(item.name, item.stamp, self.inputs[item.name].newest)
