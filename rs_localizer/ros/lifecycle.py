"""``rs_localizer_lifecycle_node``: the localizer as a managed (lifecycle) node.

The same processing, parameters and topics as ``rs_localizer_node``
(:class:`~rs_localizer.ros.node.RSLocalizerNode`), driven by the lifecycle transitions
(``ros2 lifecycle set /camera/rs_localizer configure``, or a lifecycle manager through the
``lifecycle_msgs/srv/ChangeState`` service ``<node>/change_state``):

* unconfigured (after start): parameters declared, nothing loaded, no topics.
* configure: parameters -> configuration (fails, staying unconfigured, with the reason in the
  log, on invalid parameters), the landmark and front-end maps loaded, the JIT kernels compiled
  or loaded (the warm-up), the output publishers created (inactive) and ``camera_info`` (with
  ``imu.enabled`` also ``imu``) subscribed (so a calibration and the gyro's samples are at
  hand at activation).
* activate: the output publishers enabled, the frame inputs (``correspondences``,
  ``keypoints``, ``image``) subscribed, diagnostics published.
* deactivate: the frame inputs unsubscribed and diagnostics stopped: nothing is processed or
  published.
* cleanup: publishers, ``camera_info`` subscription, maps (unless another camera of the
  process uses them), camera model and counters released; back to unconfigured.
* shutdown: as cleanup, from any state.

The ``cameras`` parameter runs one managed node per camera namespace (:mod:`.runner`); each is
managed separately (``/robot/front/rs_localizer/change_state``, ...).

With ``rig.cameras`` set the node runs a rig (:class:`~.mode.LocalizerMode`, docs/rig_node.md):
configure reads the rig's parameters (each camera's ``rig.<camera>.*``; a camera without
mounting fails the transition, naming it), builds each camera's front end and creates the
publishers (inactive), the cameras' ``camera_info`` subscriptions and, with ``imu.enabled``,
``imu`` (as for one camera); activate subscribes
every camera's frame inputs (``<camera>/correspondences``, ``<camera>/image_raw``) and
publishes diagnostics; deactivate unsubscribes them, solves and publishes the rig frames still
open and ends the track (the next activation starts a new one; the counters go on); cleanup
releases everything (the counters too). Parameters may be changed while unconfigured; once
configured, a change is taken or refused as by ``rs_localizer_node``
(:meth:`.core.NodeCore._on_set_parameters`). ``rig.cameras`` is read-only: the mode is the
one the node was started with.
"""

from __future__ import annotations

from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn

from .core import NodeCore
from .mode import LocalizerMode
from .qos import output_events

__all__ = ["RSLocalizerLifecycleNode"]

_OK = TransitionCallbackReturn.SUCCESS


class RSLocalizerLifecycleNode(NodeCore, LifecycleNode):
    """The managed localizer node, for one camera or a rig (see the module docstring): the
    phases of :class:`~.core.NodeCore` run by the lifecycle transitions. ``node_name`` and
    ``kwargs`` go to :class:`rclpy.lifecycle.LifecycleNode`. The outputs are lifecycle
    publishers (``self._outputs``), enabled and disabled by the lifecycle node's own
    transitions.
    """

    _mode = LocalizerMode
    _outputs: list

    def _start(self) -> None:
        """The managed node's start (in the node's construction): the parameters declared,
        the node's state before ``configure`` (its mode), parameter changes taken (checked at
        ``configure``); nothing configured."""
        self._declare_parameters()
        self._init_state()
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._outputs = []
        self.get_logger().info(
            f"unconfigured (lifecycle node{self.mode.mode_note}: configure, then activate)"
        )

    def _make_publisher(self, msg_type, topic, qos):
        pub = self.create_lifecycle_publisher(msg_type, topic, qos, event_callbacks=output_events())
        self._outputs.append(pub)
        return pub

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self._configure()
        except RuntimeError as e:
            self.get_logger().error(f"configure failed: {e}")
            self._release()
            return TransitionCallbackReturn.FAILURE
        self._create_outputs()
        self._create_info_inputs()
        self.get_logger().info(f"configured: {self.mode.configured_as()} (inactive)")
        return super().on_configure(state)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        ret = super().on_activate(state)  # enables the lifecycle publishers
        if ret == _OK:
            self._create_frame_inputs()
            self._log_ready()
        return ret

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._destroy_frame_inputs()
        self._end_video()  # (published while the publishers are still active)
        self.get_logger().info("deactivated: frame inputs unsubscribed, not publishing")
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._release()
        self.get_logger().info("cleaned up: unconfigured")
        return super().on_cleanup(state)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._destroy_frame_inputs()
        self._release()
        return super().on_shutdown(state)

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.get_logger().error("error in a transition: releasing everything (unconfigured)")
        self._destroy_frame_inputs()
        self._release()
        return _OK

    def _release(self):
        """Drop what configure made: the publishers, then the rest
        (:meth:`.core.NodeCore._release_configured`)."""
        for pub in self._outputs:
            self.destroy_lifecycle_publisher(pub)
        self._outputs = []
        self._release_configured()
