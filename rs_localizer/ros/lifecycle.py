"""``rs_localizer_lifecycle_node``: the localizer as a managed (lifecycle) node.

The same processing, parameters and topics as ``rs_localizer_node``
(:class:`~rs_localizer.ros.node.RSLocalizerNode`), driven by the lifecycle transitions
(``ros2 lifecycle set /camera/rs_localizer configure``, or a lifecycle manager through the
``lifecycle_msgs/srv/ChangeState`` service ``<node>/change_state``):

* unconfigured (after start): parameters declared, nothing loaded, no topics.
* configure: parameters -> configuration (fails, staying unconfigured, with the reason in the
  log, on invalid parameters), the landmark and front-end maps loaded, the JIT kernels compiled
  or loaded (the warm-up), the output publishers created (inactive) and ``camera_info``
  subscribed (so a calibration is at hand at activation).
* activate: the output publishers enabled, the frame inputs (``correspondences``,
  ``keypoints``, ``image``) subscribed, diagnostics published.
* deactivate: the frame inputs unsubscribed and diagnostics stopped: nothing is processed or
  published.
* cleanup: publishers, ``camera_info`` subscription, maps (unless another camera of the
  process uses them), camera model and counters released; back to unconfigured.
* shutdown: as cleanup, from any state.

The ``cameras`` parameter runs one managed node per camera namespace (:mod:`.runner`); each is
managed separately (``/robot/front/rs_localizer/change_state``, ...).

With ``rig.cameras`` set the process runs the rig mode as one managed node
(:class:`RigLocalizerLifecycleNode`, :mod:`.rig_node`): configure reads the rig's parameters
(each camera's ``rig.<camera>.*``; a camera without mounting fails the transition, naming it),
builds each camera's front end and creates the publishers (inactive) and the cameras'
``camera_info`` subscriptions; activate subscribes every camera's frame inputs
(``<camera>/correspondences``, ``<camera>/image_raw``) and publishes diagnostics; deactivate
unsubscribes them, solves and publishes the rig frames still open and ends the track (the next
activation starts a new one; the counters go on); cleanup releases everything (the counters
too). Parameters may be changed while unconfigured; once configured, changes are refused
until cleanup.

Both managed nodes run the transitions of one template, :class:`ManagedTransitions`: the
camera and the rig node each name the phases of their core (:class:`~.node.LocalizerCore`,
:class:`~.rig_node.RigCore`) that a transition runs.
"""

from __future__ import annotations

from typing import Any

from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn

from ..frontends.shared import SHARED_MAPS
from .node import LocalizerCore
from .qos import output_events
from .rig_node import RigCore

__all__ = ["ManagedTransitions", "RSLocalizerLifecycleNode", "RigLocalizerLifecycleNode"]

_OK = TransitionCallbackReturn.SUCCESS


class ManagedTransitions:
    """The lifecycle transitions of a managed node, written once (see the module docstring).

    Mixed in before the node's core and :class:`rclpy.lifecycle.LifecycleNode`
    (``class X(ManagedTransitions, Core, LifecycleNode)``); the node class names its core's
    phases in the hooks below. Its outputs are lifecycle publishers (``self._outputs``),
    enabled and disabled by the lifecycle node's own transitions.
    """

    _outputs: list

    # ------------------------------------------------------------------ hooks
    def _configure_core(self) -> None:
        """Parameters -> configuration. Raises RuntimeError for invalid parameters."""
        raise NotImplementedError

    def _create_configured(self) -> str:
        """Create the outputs (inactive) and the ``camera_info`` inputs; returns what the log
        line ``configured: ... (inactive)`` names."""
        raise NotImplementedError

    def _create_inputs(self) -> None:
        """Subscribe the frame inputs, start diagnostics and log ``ready: ...``."""
        raise NotImplementedError

    def _destroy_inputs(self) -> None:
        """Undo :meth:`_create_inputs`."""
        raise NotImplementedError

    def _end_track(self) -> None:
        """At deactivate, the frame inputs gone and the publishers still active: publish what
        the track still holds (nothing, unless the node says so)."""

    def _release_core(self) -> None:
        """Drop what configure made besides the publishers."""
        raise NotImplementedError

    # ------------------------------------------------------------------ the template
    def _make_publisher(self, msg_type, topic, qos):
        pub = self.create_lifecycle_publisher(msg_type, topic, qos, event_callbacks=output_events())
        self._outputs.append(pub)
        return pub

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self._configure_core()
        except RuntimeError as e:
            self.get_logger().error(f"configure failed: {e}")
            self._release()
            return TransitionCallbackReturn.FAILURE
        what = self._create_configured()
        self.get_logger().info(f"configured: {what} (inactive)")
        return super().on_configure(state)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        ret = super().on_activate(state)  # enables the lifecycle publishers
        if ret == _OK:
            self._create_inputs()
        return ret

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._destroy_inputs()
        self._end_track()  # (published while the publishers are still active)
        self.get_logger().info("deactivated: frame inputs unsubscribed, not publishing")
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._release()
        self.get_logger().info("cleaned up: unconfigured")
        return super().on_cleanup(state)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._destroy_inputs()
        self._release()
        return super().on_shutdown(state)

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.get_logger().error("error in a transition: releasing everything (unconfigured)")
        self._destroy_inputs()
        self._release()
        return _OK

    def _release(self):
        """Drop what configure made: the publishers, then the core's part."""
        for pub in self._outputs:
            self.destroy_lifecycle_publisher(pub)
        self._outputs = []
        self._release_core()


class RSLocalizerLifecycleNode(ManagedTransitions, LocalizerCore, LifecycleNode):
    """The managed localizer node (see the module docstring). ``node_name`` and ``kwargs`` go to
    :class:`rclpy.lifecycle.LifecycleNode`."""

    def __init__(self, node_name: str = "rs_localizer", **kwargs: Any):
        LifecycleNode.__init__(self, node_name, **kwargs)
        self._declare_parameters()
        self._init_state()
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._outputs = []
        self.get_logger().info("unconfigured (lifecycle node: configure, then activate)")

    def _configure_core(self) -> None:
        self._configure()

    def _create_configured(self) -> str:
        self._create_outputs()
        self._create_camera_info_input()
        return f"solver {self.cfg.solver}"

    def _create_inputs(self) -> None:
        self._create_frame_inputs()
        self._log_ready()

    def _destroy_inputs(self) -> None:
        self._destroy_frame_inputs()

    def _release_core(self) -> None:
        """The camera_info and imu subscriptions, maps, the camera model, the configuration
        and the counters."""
        self.pub_diag = None
        for sub in (self.sub_info, self.sub_imu):
            if sub is not None:
                self.destroy_subscription(sub)
        SHARED_MAPS.release(self)
        self._init_state()  # (a new pipeline without configuration; publishers, sub_* and
        # the counters reset too)


class RigLocalizerLifecycleNode(ManagedTransitions, RigCore, LifecycleNode):
    """The rig mode as a managed node (see the module docstring). ``node_name`` and ``kwargs``
    go to :class:`rclpy.lifecycle.LifecycleNode`."""

    def __init__(self, node_name: str = "rs_localizer", **kwargs: Any):
        LifecycleNode.__init__(self, node_name, **kwargs)
        self._declare_rig_parameters()
        self.add_on_set_parameters_callback(self._refuse_changes)
        self.get_logger().info("unconfigured (lifecycle node, rig mode: configure, then activate)")

    def _configure_core(self) -> None:
        self._configure_rig()

    def _create_configured(self) -> str:
        self._create_rig_outputs()
        self._create_rig_info_inputs()
        return f"rig of {len(self.config.cameras)} cameras"

    def _create_inputs(self) -> None:
        self._create_rig_frame_inputs()
        self._log_rig_ready()

    def _destroy_inputs(self) -> None:
        self._destroy_rig_frame_inputs()

    def _end_track(self) -> None:
        self._end_rig_video()

    def _release_core(self) -> None:
        self._release_rig()

    def destroy_node(self) -> None:
        SHARED_MAPS.release(self)
        return super().destroy_node()
