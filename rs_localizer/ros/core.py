"""The localizer node, written once for one camera and for a rig.

:class:`NodeCore` is the base of the node, :class:`~rs_localizer.ros.node.RSLocalizerNode`,
and of the managed node, :class:`~rs_localizer.ros.lifecycle.RSLocalizerLifecycleNode`: the
output publishers (``pose``, ``twist``, ``pose_with_covariance``, ``odom``,
``twist_single_frame``, ``/tf``, ``/diagnostics``, ``correspondences_out``), each camera's
``camera_info`` and frame subscriptions (the mode's topic names as data: ``correspondences``,
``keypoints``, ``image`` of the single camera; ``<c>/correspondences``, ``<c>/keypoints``,
``<c>/image_raw`` of a rig camera), the frame queue's worker and the timers (diagnostics, the
idle track's flush) started and stopped with the frame inputs, the subscriptions destroyed,
the visualizations closed, the latency and stamp-age record, the diagnostics published and
the node destroyed. What differs is the node's one mode (:attr:`NodeCore.mode`,
:class:`~rs_localizer.ros.mode.LocalizerMode`: the camera alone, a rig of one camera named
"", with ``rig.cameras`` empty, else the rig's cameras; either way one
:class:`~rs_localizer.tracking.video.Localizer`): its configuration, what the worker does with
a frame, what it publishes and its status.

The node's phases, run at construction (:meth:`NodeCore._start_unmanaged`) or by the managed
node's transitions: ``_declare_parameters``, ``_init_state`` (the mode made),
``_configure``, ``_create_outputs``, ``_create_info_inputs``, ``_create_frame_inputs``,
``_log_ready``, then ``_destroy_frame_inputs``, ``_end_video``, ``_release_configured``.

A mode derives from :class:`ModeBase` (``configure()``, RuntimeError for invalid parameters;
``apply_change(built, overrides)``, ``log_ready()``, ``imu_input()``, ``close_track()``,
``frame_inputs_destroyed()``, its topics and texts as data, written once) and adds
``configured_as()``, ``camera_of(item)``, ``take_frame(item, camera)``,
``publish_taken(item, taken)``, ``idle_twists()`` (between two frames of the worker),
``changed_configuration(overrides)``, ``diagnostics()`` (its status as data, between two
frames of the worker) and the steps
:class:`ModeBase` names. What a mode calls on the node:
``set_cameras(inputs, counts, log, group, worker)`` (its cameras and a frame queue for them),
``stopping()``, ``between_frames(step)`` (``step`` run between two frames of the worker,
never waiting for one), ``first_frame``,
``param_values(overrides)``, ``open_found_output(name)``, ``warn(key, text, count)`` (the
throttled log), ``warn_once(key, text)`` and ``record_timing(arrived, stamp_ns)``; its
frames' outcomes (``close_track()``'s too) it publishes with
:func:`.outputs.publish_frame` (which calls ``publish_messages(messages)``,
``wanted(topic)``, ``warn`` and the views); what the front end found in an image it hands
back in its :class:`TakenFrame` (``found``), which the node publishes on the camera's
``correspondences_out``.

A frame's checks before it is solved are the same for both modes, in the camera's input stage:
its header stamp as it arrives (:meth:`.camera_input.CameraInput.check`), its camera model
(:meth:`.camera_input.CameraInput.camera_of`), then at the localizer's entry its times, its
output stamp's range and an image's front end (:meth:`.camera_input.CameraInput.admit`); a
frame they drop is counted in its camera's counts under its reason
(:data:`.camera_input.DROP_REASONS`), so that per camera ``received = solved + failed +
skipped + pending``.

The worker is one for both: the subscription callbacks (:meth:`NodeCore._take_frames`: the
message the executor took and every other one waiting on the frame subscriptions) hand each
of a camera's frame messages to :meth:`NodeCore._enqueue` (its stamp checked by the camera's
input stage, a :class:`QueuedFrame` queued; the queue counts it ``received`` in the camera's
counts), the
worker takes it (:meth:`NodeCore._process`: the mode's ``take_frame``, in one of the
worker's frames, :class:`~.frame_queue.BetweenFrames`, and the frame's outcome counted in the
camera's counts in the same step), then publishes what it gave (:meth:`NodeCore._deliver`:
the front end's ``correspondences_out``, then the mode's ``publish_taken``). The single camera
is named "" (its topics and counts without prefix); a rig's cameras by their names.

No callback on the executor's thread waits for the worker: what must see the mode between two
frames (the diagnostics timer's status, a parameter change, the idle track's flush) runs at
once while the worker is not on a frame, else the diagnostics and a parameter change are
handed to the worker, which runs them after the frame it is on (the idle track's flush waits
for the next tick: the worker on a frame is not idle). While a frame is solved the executor
thus goes on taking the frame messages (counted ``received``) instead of letting a reliable
stream overflow the subscriptions' history.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, TwistStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import SetParametersResult
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.exceptions import InvalidHandle
from rclpy.qos import qos_profile_sensor_data
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, Imu, PointCloud2

from ..frontends.shared import SHARED_MAPS
from . import conversions as cv
from .declare import declare_parameters
from .diagnostics import status
from .frame_queue import BetweenFrames, FrameQueue
from .outputs import FrameOutcome, publish_frame
from .params import PARAMETERS, RIG_PARAMETERS, ConfigError
from .pipeline import warm_localizer
from .pointcloud import correspondence_cloud
from .qos import CLOUD_QOS, IMAGE_QOS, IMU_QOS, RELIABLE, output_events
from .status_msg import status_message
from .visualization import NodeVisualization

if TYPE_CHECKING:
    from ..tracking.video import LocalizerOutput

__all__ = ["ModeBase", "NodeCore", "QueuedFrame", "TakenFrame", "names_a_rig"]

_yield_cpu = getattr(os, "sched_yield", lambda: None)  # (POSIX)

#: the output topics of a pose (relative names, as :mod:`.outputs` names them) and their types
POSE_OUTPUTS = (
    ("pose", PoseStamped),
    ("twist", TwistStamped),
    ("pose_with_covariance", PoseWithCovarianceStamped),
    ("odom", Odometry),
    ("twist_single_frame", TwistStamped),
)

#: s: the idle-track timer's period (every timer tick rebuilds the executor's wait set in
#: Python; at 10 Hz the pending twists go out within 0.1 s of ``tracking.max_gap``)
FLUSH_PERIOD_S = 0.1


def names_a_rig(value: Any) -> bool:
    """Whether a ``rig.cameras`` value (of any type: a wrong one is refused by the rig's
    configure, naming the fix) sets the rig mode: anything but unset or empty."""
    return not (value is None or (isinstance(value, (list, tuple, str)) and len(value) == 0))


@dataclass(frozen=True)
class QueuedFrame:
    """A camera's frame in the queue: the camera's ``name`` ("" for the single camera),
    ``kind`` (``correspondences`` or ``cloud``, ``keypoints``, ``image``), the message, its
    arrival (``time.perf_counter``) and its header stamp, checked once as it arrived
    (:meth:`.camera_input.CameraInput.check`): a :class:`~rs_localizer.camera.Stamp`, or the
    :class:`~rs_localizer.ros.camera_input.DroppedFrame` of a stamp out of range (or the
    single camera's empty cloud)."""

    name: str
    kind: str
    msg: Any
    arrived: float
    stamp: Any


@dataclass
class TakenFrame:
    """The worker's outcome of one camera frame (:meth:`NodeCore._process`).

    Attributes:
        counted: the keys counted for it in its camera's counts (``solved``,
            ``failed.<reason>``, a rig camera's ``skipped.<reason>``; None: none).
        failure: the frame dropped for this reason (None: solved, or a rig camera's frame
            handed to the rig, whose fate is the rig's).
        result: the camera alone's :class:`~rs_localizer.ros.mode.CameraFrameResult`.
        outs: the rig frames it completed (a rig camera's).
        found: ``(camera, correspondences, stamp_ns)``: what the camera's front end found in
            the image (a :class:`~rs_localizer.correspondences.Correspondences`) and the
            image's stamp, for its ``correspondences_out`` (``republish_correspondences``).
    """

    counted: tuple = ()
    failure: str | None = None
    result: Any = None
    outs: list[LocalizerOutput] = field(default_factory=list)
    found: list = field(default_factory=list)


class ModeBase:
    """What the node's mode (:class:`~rs_localizer.ros.mode.LocalizerMode`, the camera alone
    or a rig) does at each phase, written once. A mode adds
    its configuration (``changed_configuration(overrides)``: at configure without overrides,
    at run time with the changed values; -> ``built``, whose first item is its
    :class:`~.config.LocalizerConfig`, of one camera or of the rig, :attr:`cfg` once taken),
    how it takes it (``_start_with(built)``, ``_change_to(built, overrides)``), its gyro's
    input (``_take_imu``) and its ``ready`` line's subject and warnings (``_ready_subject()``,
    ``_ready_warnings()``). The topics and texts as data are the single camera's (the rig's
    mode sets its own)."""

    #: the single camera counts its image frames (``image_frames``)
    count_image_frames = True
    cloud_kind = "correspondences"
    image_topic = "image"
    keypoints_always = True
    busy_key = "skipped"
    busy_text = (
        "busy: frame queue full (queue_size {size}), dropped the oldest waiting frame "
        "[{dropped} skipped so far]"
    )
    #: the mode in the managed node's start line (``unconfigured (lifecycle node...)``)
    mode_note = ""
    cfg = None  # (the configuration of the parameters; None: not configured)

    def __init__(self, node: NodeCore):
        self.node = node

    def configure(self) -> None:
        """Parameters -> configuration, taken, then the kernels warmed up (:meth:`_warm_up`).
        Raises RuntimeError for invalid parameters (naming them; the maps loaded released)."""
        try:
            built = self.changed_configuration({})
        except ConfigError as e:
            SHARED_MAPS.release(self.node)
            raise RuntimeError(f"invalid parameters: {e}") from None
        self._start_with(built)
        self._warm_up(built)

    def _warm_up(self, built: tuple) -> None:
        """With ``warmup``, the kernels of ``built`` loaded from numba's cache or compiled in
        another process while the frames are solved uncompiled (nothing waits;
        :func:`.pipeline.warm_localizer`, the camera alone's and a rig's)."""
        if self.node.get_parameter("warmup").value:
            warm_localizer(built[0], self.node.get_logger())

    def apply_change(self, built: tuple, overrides: dict) -> None:
        """A run-time parameter change (:meth:`NodeCore._on_set_parameters`): a solver change
        logged and its kernels warmed up (:meth:`_warm_up`), then the configuration taken."""
        old, new = self.cfg.solver, built[0].solver
        if new != old:
            self.node.get_logger().info(f"solver: {old} -> {new}")
            self._warm_up(built)
        self._change_to(built, overrides)

    def _settle(self, cfg: Any, landmarks: Any) -> None:
        """The node's settings of ``cfg`` (:attr:`NodeCore.queue_size` ... ``map_frame``;
        ``landmarks``: ``(ids, points)`` or None); with ``republish_correspondences`` and a
        front end each camera's ``correspondences_out`` made (once the outputs exist)."""
        node = self.node
        node.queue_size, node.frontend_kind = cfg.queue_size, cfg.camera.frontend_kind
        node.image_transport, node.landmarks = cfg.camera.image_transport, landmarks
        node.republish, node.map_frame = bool(cfg.republish_correspondences), cfg.map_frame
        if node.republish and cfg.camera.frontend_kind != "none":
            for name in node.inputs:
                node.open_found_output(name)

    def imu_input(self) -> Callable[[Any], str | None] | None:
        """With ``imu.enabled``, what takes an ``imu`` message (the mode's gyro); else None."""
        return None if self.cfg.imu is None else self._take_imu

    def log_ready(self) -> None:
        """The mode's warnings, then ``ready: <subject>``, the landmarks of
        ``landmarks_file`` and the front end on the images with its map."""
        cfg, log, node = self.cfg, self.node.get_logger(), self.node
        for warning in self._ready_warnings():
            log.warning(warning)
        text = f"ready: {self._ready_subject()}"
        if node.landmarks:
            text += f", {len(node.landmarks[0])} landmarks from {cfg.camera.landmarks_file}"
        if node.images_of:
            images = node.images_of.get("", f"each camera's {self.image_topic}")
            cam = cfg.camera
            text += f", {cam.frontend_kind} front end on {images} (map {cam.frontend_map})"
        log.info(text)

    def frame_inputs_destroyed(self) -> None:
        """After the frame inputs' end (:meth:`NodeCore._destroy_frame_inputs`): nothing."""

    def close_track(self) -> list[FrameOutcome]:
        """:meth:`NodeCore._end_video`: nothing left to publish."""
        return []


class NodeCore:
    """The node, for one camera or a rig (module docstring), mixed into an rclpy ``Node`` (or
    a ``LifecycleNode``): the plumbing, and the mode (:attr:`mode`) for what differs. The
    mode hands the node its cameras (:meth:`set_cameras`: their inputs and counts, its
    :class:`~.pipeline.ThrottledLog`, a new :class:`~rs_localizer.ros.frame_queue.FrameQueue`)
    before :meth:`_start_frames`, and its outputs as data (the attributes below).

    Attributes:
        inputs: camera name ("" for the single camera) -> its
            :class:`~.camera_input.CameraInput` (its camera_infos, its frames' stamps and
            rows); empty before ``configure`` (a rig's) .
        camera_counts: camera name -> its :class:`~.camera_input.CameraCounts` (the frame
            accounting of its frames).
        queue_size: frames per camera the queue holds (``queue_size``).
        images_of: camera name -> where its front end's images come from, as a warning names
            them (its image topic; absent: no front end on its images).
        frontend_kind: the front end on the images (``frontend``).
        image_transport: ``raw`` or ``compressed`` (``image_transport``).
        landmarks: the table of ``landmarks_file`` (``(ids, points)``) keypoints name (None:
            none).
        republish: ``republish_correspondences``: what a front end found in an image to its
            camera's ``correspondences_out``.
        map_frame: the frame the poses and fused twists are published in (``map_frame``).
        mode: the node's one mode, :class:`~rs_localizer.ros.mode.LocalizerMode` (the camera
            alone or a rig by ``rig.cameras``; made by :meth:`_init_state` from the node
            class's ``_mode``).
    """

    _frames = None  # (the frame queue: made by the mode)
    _log = None  # (the mode's ThrottledLog: made by the mode)
    pub_diag = None
    viz = None  # (the node's visualization: made with the outputs)
    camera_viz: Mapping = MappingProxyType({})  # (each camera's: made with the outputs)
    inputs: Mapping = MappingProxyType({})  # (made by the mode)
    camera_counts: Mapping = MappingProxyType({})  # (made by the mode)
    queue_size = 0
    images_of: Mapping = MappingProxyType({})  # (made with the frame inputs)
    frontend_kind = "none"
    image_transport = "raw"
    landmarks = None
    republish = False
    map_frame = "map"
    _configured = False  # (configure done: the node's configuration in use)
    mode = None  # (the mode: made with the node's state, :meth:`_init_state`)
    _mode: Any = None  # (the node class's: its one mode, LocalizerMode)
    _first_frame: float | None = None  # (monotonic s: the first frame received)
    _unmanaged = False  # (every phase at construction: :meth:`_start_unmanaged`)

    def _make_publisher(self, msg_type, topic, qos):
        """Publishers of the outputs (the managed node makes lifecycle publishers), without QoS
        event handlers (:func:`.qos.output_events`)."""
        return self.create_publisher(msg_type, topic, qos, event_callbacks=output_events())

    def _declare_parameters(self) -> None:
        """Every parameter, each once: :data:`~.params.PARAMETERS` and the rig's
        :data:`~.params.RIG_PARAMETERS` (``rig.cameras`` of any type, checked at configure; a
        rig camera's ``rig.<camera>.*`` are declared by the rig's configure)."""
        declare_parameters(self, {**PARAMETERS, **RIG_PARAMETERS}, dynamic=("rig.cameras",))

    def __init__(self, node_name: str = "rs_localizer", **kwargs: Any):
        """The node (``node_name`` and ``kwargs`` to the rclpy ``Node`` or ``LifecycleNode``
        it is mixed into), then its start (:meth:`_start`).

        Raises:
            RuntimeError: a node that is not managed, with invalid parameters (the message
                names them).
        """
        self._warned_once: set = set()  # (warn_once's keys: once per node)
        super().__init__(node_name, **kwargs)
        self._start()

    def _start(self) -> None:
        """The node's start (a node that is not managed: :meth:`_start_unmanaged`; the
        managed node's: :meth:`.lifecycle.RSLocalizerLifecycleNode._start`)."""
        self._start_unmanaged()

    def _init_state(self) -> None:
        """The node's state before ``configure``: the shared plumbing's
        (:meth:`_init_plumbing`), then its mode (:attr:`_mode`) for ``rig.cameras``
        (read-only: the one the node is configured with): the camera alone with
        ``rig.cameras`` empty (its input stage and counts, unconfigured), else the rig's
        (made at configure)."""
        self._init_plumbing()
        self.inputs, self.camera_counts, self._configured = {}, {}, False
        self.mode = self._mode(self)

    def _configure(self) -> None:
        """Parameters -> configuration (the mode's; RuntimeError for invalid parameters,
        naming them): the node's configuration in use from then on."""
        self.mode.configure()
        self._configured = True

    def _log_ready(self) -> None:
        """The ``ready: ...`` line (the mode's)."""
        self.mode.log_ready()

    def _release_configured(self) -> None:
        """Drop what configure made but the publishers (the managed node destroys those): the
        camera_info and imu subscriptions, the maps (:meth:`_release_inputs`), then the
        mode's state, its configuration and the counters (:meth:`_init_state`)."""
        self._release_inputs()
        self._init_state()

    def _start_unmanaged(self) -> None:
        """The construction of a node that is not managed
        (:class:`~rs_localizer.ros.node.RSLocalizerNode`): every phase at once, the
        parameter changes taken (:meth:`_on_set_parameters`) once configured.

        Raises:
            RuntimeError: invalid parameters (the message names them).
        """
        self._unmanaged = True
        self._declare_parameters()
        self._init_state()
        self._configure()
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._create_outputs()
        self._create_info_inputs()
        self._create_frame_inputs()
        self._log_ready()

    def _init_plumbing(self) -> None:
        """The state of the shared plumbing before the inputs exist."""
        self._pubs: dict = {}  # output topic (as rs_localizer.ros.outputs names it) -> publisher
        self.pub_diag = None
        self._info_subs: list = []  # camera_info, imu: made by configure
        self._frame_subs: list = []  # the frame inputs: made by activate
        self._frame_inputs: list = []  # (subscription, camera name, kind) of each frame input
        self._diag_timer = self._flush_timer = None
        self._timing_lock = threading.Lock()
        #: the worker's frames and the steps run between two of them (the diagnostics: the
        #: mode's and the cameras' counts of a frame at once; a parameter change)
        self._between = BetweenFrames(self._between_failed)
        self._diagnostics_handed = False  # (a diagnostics status waits for the worker's frame)
        self._corr_out: dict = {}  # camera -> its correspondences_out, made when first needed
        self.latencies = deque(maxlen=1000)  # s, arrival (subscription callback) -> published
        self.stamp_ages = deque(maxlen=1000)  # s, input header.stamp -> published (ROS clock)

    # ---------------------------------------------------------------- parameters
    def param_values(self, overrides: Mapping) -> dict:
        """Every parameter of :data:`~.params.PARAMETERS` and :data:`~.params.RIG_PARAMETERS`
        (``rig.cameras`` as set) by name: its value in ``overrides`` (a change being checked),
        else the node's."""
        return {
            name: overrides[name] if name in overrides else self.get_parameter(name).value
            for name in (*PARAMETERS, *RIG_PARAMETERS)
        }

    def _has_configuration(self) -> bool:
        """Whether the node is configured (a managed node before ``configure`` is not)."""
        return self._configured

    def _on_set_parameters(self, params) -> SetParametersResult:
        """A parameter change at run time (``ros2 param set``), for one camera and for a rig
        alike: the configuration is built anew from the changed values
        (:meth:`_changed_configuration`); one that cannot be built is rejected with the error
        as the reason (logged) and the node goes on with its configuration; else the node runs
        with it from the next frame on (:meth:`_apply_change`). Parameters not in
        :data:`~.params.PARAMETERS` (``viz.*``, read when drawing; ``use_sim_time``) are
        taken as they are; before ``configure`` (a managed node) every change is taken and
        checked at ``configure``."""
        overrides = {p.name: p.value for p in params if p.name in PARAMETERS}
        if not overrides or not self._has_configuration():
            return SetParametersResult(successful=True)
        try:
            built = self.mode.changed_configuration(overrides)
        except ConfigError as e:
            self.get_logger().warning(f"rejected parameter change: {e}")
            return SetParametersResult(successful=False, reason=str(e))
        self.mode.apply_change(built, overrides)
        return SetParametersResult(successful=True)

    def _create_outputs(self) -> None:
        """The outputs: the pose outputs and ``/diagnostics`` (:meth:`_create_pose_outputs`),
        the debug views (:meth:`_create_views`) and, with a front end and
        ``republish_correspondences``, each camera's ``correspondences_out`` (else made when
        first needed)."""
        self._create_pose_outputs()
        self._create_views()
        if self.republish and self.frontend_kind != "none":
            for name in self._camera_names():
                self._corr_out_publisher(name)

    def _create_info_inputs(self) -> None:
        """Each camera's ``camera_info`` (:meth:`_subscribe_info`), then with ``imu.enabled``
        the gyro's ``imu`` (:meth:`_subscribe_imu`), created at configure (a managed node's:
        before activate), before the frame inputs: a camera_info or IMU sample ready together
        with a frame is taken first."""
        for name in self._camera_names():
            self._subscribe_info(name)
        self._subscribe_imu()

    def _subscribe_imu(self) -> None:
        """With ``imu.enabled``, ``imu`` (sensor_msgs/Imu, sensor-data QoS, overridable as
        ``qos_overrides./imu.subscription.*``): each sample to the mode's gyro (its
        ``imu_input()``: the camera's or the rig's; None: no gyro). Kept with the configured
        inputs (destroyed at cleanup)."""
        take = self.mode.imu_input()
        if take is not None:
            self._info_subs.append(self.create_subscription(
                Imu, "imu", take, IMU_QOS,
                qos_overriding_options=QoSOverridingOptions.with_default_policies(),
            ))  # fmt: skip

    def _create_frame_inputs(self) -> None:
        """The frame subscriptions (:meth:`_subscribe_frame_inputs`), then the diagnostics
        timer, the idle-track timer and the worker thread (:meth:`_start_frames`)."""
        self._subscribe_frame_inputs()
        self._start_frames()

    def _subscribe_frame_inputs(self) -> None:
        """Each camera's frame inputs (a rig camera's under ``<c>/``; :meth:`_subscribe_frames`):
        ``correspondences``; ``keypoints`` (a rig's: with a ``landmarks_file``); with a front
        end its images (``image`` of the single camera, ``<c>/image_raw`` of a rig camera;
        ``image_transport: compressed``: that topic resolved (a remap of it moves its
        compressed topic too, as image_transport names it) + ``/compressed``, sensor_msgs/
        CompressedImage), noted in :attr:`images_of`."""
        images = {}
        for n in self._camera_names():
            p = f"{n}/" if n else ""
            self._subscribe_frames(n, self.mode.cloud_kind, PointCloud2, f"{p}correspondences",
                                   CLOUD_QOS)  # fmt: skip
            if self.mode.keypoints_always or self.landmarks is not None:
                self._subscribe_frames(n, "keypoints", PointCloud2, f"{p}keypoints", CLOUD_QOS)
            if self.frontend_kind == "none":
                continue
            topic, msg_type = p + self.mode.image_topic, Image
            if self.image_transport == "compressed":  # (on image_transport's topic name)
                topic, msg_type = self.resolve_topic_name(topic) + "/compressed", CompressedImage
            sub = self._subscribe_frames(n, "image", msg_type, topic, IMAGE_QOS)
            images[n] = sub.topic_name
        self.images_of = images

    def _create_pose_outputs(self) -> None:
        """The publishers of the pose outputs (:data:`POSE_OUTPUTS`), ``/tf`` with
        ``publish_tf`` (warns when tf2_msgs is not importable) and ``/diagnostics``."""
        self._pubs = {
            topic: self._make_publisher(msg_type, topic, RELIABLE)
            for topic, msg_type in POSE_OUTPUTS
        }
        self.pub_diag = self._make_publisher(DiagnosticArray, "/diagnostics", RELIABLE)
        if self.get_parameter("publish_tf").value:
            if cv.have_tf2_msgs():
                from tf2_msgs.msg import TFMessage

                self._pubs["tf"] = self._make_publisher(TFMessage, "/tf", RELIABLE)
            else:
                self.get_logger().warning(
                    "publish_tf is true but tf2_msgs is not importable (not in the PyPI "
                    "wheels): not publishing /tf"
                )

    def _create_views(self) -> None:
        """The debug views (:class:`.visualization.NodeVisualization`, built only while
        subscribed), once per node (the first declares the ``viz.*`` parameters; a rig's
        camera names are read-only, so they stay the cameras' of every configure): ``viz``,
        the ``path`` of the node's poses, and in ``camera_viz`` each camera's
        ``debug_image`` and ``markers`` (a rig camera's ``<c>/debug_image``); the single
        camera's ("") are its ``viz`` with the path (one drawing thread, the path its
        poses)."""
        if self.viz is not None:
            return
        names = self._camera_names()
        if names == [""]:
            self.viz = NodeVisualization(self)
            self.camera_viz = {"": self.viz}
            return
        self.viz = NodeVisualization(self, topics=("path",))
        self.camera_viz = {
            n: NodeVisualization(self, f"{n}/", ("debug_image", "markers")) for n in names
        }

    def _start_frames(self) -> None:
        """After the frame subscriptions: the diagnostics timer (``diagnostics_period``), the
        idle-track timer and the worker thread."""
        self._diag_timer = self.create_timer(
            float(self.get_parameter("diagnostics_period").value), self.publish_diagnostics
        )
        self._flush_timer = self.create_timer(FLUSH_PERIOD_S, self._flush_idle_track)
        # the worker holds the GIL in its Python between the compiled kernels (which release
        # it); hand it to the subscription callbacks often, so that frames leave the
        # middleware's queue quickly (0.5 ms, CPython: 5 ms)
        sys.setswitchinterval(min(sys.getswitchinterval(), 5e-4))
        self._frames.start()

    def _warn_busy(self, size: int) -> None:
        """A full queue of ``size`` frames dropped its oldest (:meth:`_enqueue`): a throttled
        warning (the mode's :attr:`_busy_key` and :attr:`_busy_text`)."""
        text = self.mode.busy_text.format(size=size, queue_size=self.queue_size,
                                      dropped=self._frames.dropped)  # fmt: skip
        self._log.warning(self.mode.busy_key, text)

    def _subscribe_info(self, name: str):
        """Camera ``name``'s ``camera_info`` (a rig camera's ``<name>/camera_info``;
        sensor-data QoS, overridable as ``qos_overrides.<topic>.subscription.*``), each
        message to the camera's input stage
        (:meth:`.camera_input.CameraInput.add_camera_info`: checked, kept by stamp). Kept with
        the configured inputs."""
        sub = self.create_subscription(
            CameraInfo,
            f"{name}/camera_info" if name else "camera_info",
            lambda msg: self._input_of(name).add_camera_info(msg),
            qos_profile_sensor_data,
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
        )
        self._info_subs.append(sub)
        return sub

    def _found_cloud(self, name: str, found, msg, stamp_ns: int):
        """What camera ``name``'s front end found in an image message ``msg`` (``found``, a
        :class:`~rs_localizer.correspondences.Correspondences`) as its
        ``correspondences_out`` cloud: ``u, v, x, y, z, id`` (``score`` with scores), stamped
        like the image (``stamp_ns``), in the frame's tag
        (:meth:`.camera_input.CameraInput.tag_of`)."""
        return correspondence_cloud(found.points2d, found.points, found.ids,
                                    found.valid_scores(), self._input_of(name).tag_of(msg),
                                    stamp_ns)  # fmt: skip

    def _subscribe_frames(self, name: str, kind: str, msg_type, topic: str, qos):
        """Camera ``name``'s ``kind`` input on ``topic`` (QoS overridable as
        ``qos_overrides.<topic>.subscription.*``): each message to the node's
        ``_on_frame(name, kind, msg)``; its QoS ``message_lost`` events (messages the
        middleware lost before the node saw them, never received) counted in the camera's
        counts (``messages_lost``). Kept with the frame inputs (destroyed with them)."""

        def on_lost(status):
            self._counts_of(name).lost(kind, status.total_count)

        sub = self.create_subscription(
            msg_type,
            topic,
            lambda msg: self._take_frames(name, kind, msg),
            qos,
            event_callbacks=SubscriptionEventCallbacks(message_lost=on_lost),
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
        )
        self._frame_subs.append(sub)
        self._frame_inputs.append((sub, name, kind))
        return sub

    # ---------------------------------------------------------------- the worker
    def _new_queue(self, name: str = "rs_localizer_worker", group=None) -> FrameQueue:
        """The frame queue of the worker (:meth:`_process`, :meth:`_deliver`), each frame
        counted in its camera's counts; ``group``: :class:`~.frame_queue.FrameQueue`'s."""
        return FrameQueue(self._process, self._deliver, self._delivery_failed, name,
                          counts_of=lambda item: self._counts_of(item.name),
                          group=group)  # fmt: skip

    def _on_frame(self, name: str, kind: str, msg) -> None:
        """Camera ``name``'s frame message (subscription callback), queued
        (:meth:`_enqueue`); the single camera's image counted ``image_frames``; a
        correspondences or keypoints cloud of a camera whose front end runs on its images
        (:attr:`images_of`) counted ``frames_beside_frontend`` and, the first time, a warning
        naming both inputs (:meth:`_frame_beside_frontend`: such a cloud is solved as given,
        not from the images and the front end's map)."""
        if kind == "image":
            if self.mode.count_image_frames:
                self._counts_of(name).add("image_frames")
        elif name in self.images_of:
            leaf = "correspondences" if kind == "cloud" else kind
            self._frame_beside_frontend(self._counts_of(name), leaf, self.frontend_kind,
                                        self.images_of[name])  # fmt: skip
        self._enqueue(name, kind, msg)

    def _take_frames(self, name: str, kind: str, msg) -> None:
        """A frame subscription's callback: the message the executor took, then every message
        already waiting in the readers of the node's frame subscriptions (:attr:`_frame_inputs`,
        one of each per round, in subscription order, as the executor takes one of each ready
        subscription per turn; at most the deepest history's number of rounds), each to
        :meth:`_on_frame` (queued and counted ``received``), then the CPU handed to the worker
        once. One executor turn empties the readers: the executor rebuilds its wait set in
        Python for every turn and, while the worker runs Python between its compiled kernels
        (which release the GIL), waits for the GIL at each turn, so that taking one message
        per turn falls behind a stream and a reader's history (keep last) overwrites frames
        the node never counts; the frame queue drops the oldest and
        counts them instead (``skipped.queue_full``)."""
        self._on_frame(name, kind, msg)
        inputs = list(self._frame_inputs)
        rounds = max((int(sub.qos_profile.depth) for sub, _, _ in inputs), default=0)
        for _ in range(rounds):
            took = False
            for sub, n, k in inputs:
                try:
                    with sub.handle:
                        taken = sub.handle.take_message(sub.msg_type, sub.raw)
                except InvalidHandle:  # (destroyed: the frame inputs ended)
                    continue
                if taken is not None:
                    took = True
                    self._on_frame(n, k, taken[0])
            if not took:
                break
        _yield_cpu()  # the worker starts on it in ~0.05 ms, not after the executor (~0.9 ms)

    def _enqueue(self, name: str, kind: str, msg) -> None:
        """Subscription callbacks: camera ``name``'s frame message, its stamp checked once
        (:meth:`.camera_input.CameraInput.check`), queued for the worker (counted
        ``received``; the first frame's time noted). A full queue (:attr:`queue_size` frames
        per camera) drops its oldest frame (counted ``skipped.queue_full``; ``_warn_busy``):
        the newest frames are the ones solved."""
        if self._first_frame is None:
            self._first_frame = time.monotonic()
        stamp = self._input_of(name).check(msg, kind)
        size = self.queue_size * len(self.inputs)
        item = QueuedFrame(name, kind, msg, time.perf_counter(), stamp)
        skipped = self._frames.put(item, size)
        if skipped:
            self._warn_busy(size)

    def _process(self, item: QueuedFrame) -> TakenFrame:
        """The worker: one camera frame taken (the mode's ``take_frame``, in one of the
        worker's frames, :meth:`.frame_queue.BetweenFrames.frame`) and counted in its camera's
        counts in the same step (its time and the keys of its outcome), so that a diagnostics
        snapshot sees it once; then what was handed to the worker meanwhile (the diagnostics,
        a parameter change) run. An
        exception is a defect: the frame is counted ``failed.internal_error`` and logged, the
        node goes on."""
        tic = time.perf_counter()
        camera = self.mode.camera_of(item)
        with self._between.frame():
            try:
                taken = self.mode.take_frame(item, camera)
            except Exception as e:
                taken = TakenFrame(("failed.internal_error",), "internal_error")
                self._log.warning("internal_error", self._input_of(item.name).failed_text(e))
            counts = self._counts_of(item.name)
            counts.frame_done(time.perf_counter() - tic, *taken.counted)
        return taken

    def _deliver(self, item: QueuedFrame, taken: TakenFrame) -> None:
        """The worker, after the frame is counted: what the camera's front end found in its
        image to its ``correspondences_out`` (``republish_correspondences``,
        :meth:`_found_cloud`), then what the frame gave (the mode's ``publish_taken``)."""
        for name, found, stamp_ns in taken.found:
            self._corr_out_publisher(name).publish(
                self._found_cloud(name, found, item.msg, stamp_ns)
            )
        self.mode.publish_taken(item, taken)

    def _corr_out_publisher(self, name: str = ""):
        """Camera ``name``'s ``correspondences_out`` (``<name>/correspondences_out`` of a rig
        camera; reliable), made when first needed."""
        pub = self._corr_out.get(name)
        if pub is None:
            topic = f"{name}/correspondences_out" if name else "correspondences_out"
            pub = self._corr_out[name] = self._make_publisher(PointCloud2, topic, RELIABLE)
        return pub

    def _camera_names(self) -> list[str]:
        """The names of the node's cameras ("" for the single camera), each with its input
        stage (:meth:`_input_of`) and counts (:meth:`_counts_of`); none before a rig's
        ``configure``."""
        return list(self.inputs)

    def _input_of(self, name: str):
        """Camera ``name``'s :class:`~.camera_input.CameraInput` (:attr:`inputs`)."""
        return self.inputs[name]

    def _counts_of(self, name: str):
        """Camera ``name``'s :class:`~.camera_input.CameraCounts` (:attr:`camera_counts`)."""
        return self.camera_counts[name]

    def _wake_worker(self) -> None:
        """A stop was requested: wake a frame waiting for its camera's camera_info
        (:meth:`.camera_input.CameraInput.wake`, every camera's)."""
        for name in self._camera_names():
            self._input_of(name).wake()

    def _stop_worker(self, drop_queued: bool = False) -> None:
        """Stop the worker thread (the frame it is on is finished); ``drop_queued``: forget
        the frames still waiting (counted as skipped), else they stay pending."""
        if self._frames is None:
            return
        self._frames.request_stop(drop_queued)
        self._wake_worker()
        self._frames.join()

    def _destroy_frame_inputs(self) -> None:
        """Undo :meth:`_start_frames` and the frame subscriptions; frames still queued are
        dropped (counted as skipped), then :meth:`_frame_inputs_destroyed`."""
        for sub in self._frame_subs:
            self.destroy_subscription(sub)
        self._frame_subs, self._frame_inputs = [], []
        self.images_of = {}
        for timer in (self._diag_timer, self._flush_timer):
            if timer is not None:
                self.destroy_timer(timer)
        self._diag_timer = self._flush_timer = None
        self._stop_worker(drop_queued=True)
        self.mode.frame_inputs_destroyed()

    def _end_video(self) -> None:
        """The end of the frame inputs: what the track still holds (the mode's
        ``close_track()``, in a frame of its own after the worker's: the outcomes of the
        frames it completes and of the twists still pending) published
        (:func:`.outputs.publish_frame`); the next frame starts a new track."""
        with self._between.frame():
            closed = self.mode.close_track()
        for outcome in closed:
            publish_frame(self, outcome)

    def _flush_idle_track(self) -> None:
        """Timer: after ``tracking.max_gap`` s without frames the track is over (the next
        frame starts a new one): publish the twists still pending (the mode's
        ``idle_twists()``, fused outputs, taken between two frames of the worker; nothing
        while the worker is on a frame: not idle, and the timer does not wait for it)."""
        if not self._between.hold_if_free():
            return
        try:
            fused = self.mode.idle_twists()
        finally:
            self._between.release()
        publish_frame(self, FrameOutcome(fused=fused))

    def _release_inputs(self) -> None:
        """The first part of :meth:`_release_configured`: the camera_info and imu
        subscriptions, the shared maps and the diagnostics publisher (the managed node
        destroys the publishers)."""
        for sub in self._info_subs:
            self.destroy_subscription(sub)
        self._info_subs = []
        SHARED_MAPS.release(self)
        self.pub_diag = None

    # ---------------------------------------------------------------- what a mode calls
    # (the node's cameras, worker, outputs, log and timing record, as a mode and
    # outputs.publish_frame use them: set_cameras, stopping, between_frames, first_frame,
    # param_values, open_found_output, publish_messages, wanted, warn, warn_once,
    # record_timing)
    def set_cameras(self, inputs: Mapping, counts: Mapping, log: Any,
                    group: Callable[[list, Any], bool] | None = None,
                    worker: str = "rs_localizer_worker") -> None:  # fmt: skip
        """The mode's cameras handed to the node: ``inputs`` (camera name -> its
        :class:`~.camera_input.CameraInput`, :attr:`inputs`), ``counts`` (camera name -> its
        :class:`~.camera_input.CameraCounts`, :attr:`camera_counts`), ``log`` (the mode's
        :class:`~.pipeline.ThrottledLog`, :meth:`warn`'s), and a new frame queue for them
        (its worker thread named ``worker``; ``group``: :class:`~.frame_queue.FrameQueue`'s);
        the first frame's time and the timing record start again."""
        self._log, self.inputs, self.camera_counts = log, inputs, counts
        self._frames = self._new_queue(worker, group)
        self._first_frame = None
        with self._timing_lock:
            self.latencies.clear()
            self.stamp_ages.clear()

    def stopping(self) -> bool:
        """A stop of the worker was requested (a frame waiting for its camera_info or gyro
        samples stops waiting)."""
        return self._frames is not None and self._frames.stopping

    def between_frames(self, step: Callable[[], None]) -> None:
        """``step()`` run between two frames of the worker (a change of the mode's state):
        at once when the worker is not on a frame, else after the frame it is on, before its
        next (:meth:`.frame_queue.BetweenFrames.run`); the caller never waits for the frame.
        An exception of a step handed to the worker is logged (:meth:`_between_failed`)."""
        self._between.run(step)

    def _between_failed(self, e: BaseException) -> None:
        self.get_logger().error(f"between frames: {type(e).__name__}: {e}")

    @property
    def first_frame(self) -> float | None:
        """monotonic s: when the first frame was received (None: none yet)."""
        return self._first_frame

    def open_found_output(self, name: str = "") -> None:
        """Camera ``name``'s ``correspondences_out`` made now, once the node's outputs exist
        (``republish_correspondences`` turned on at run time; else it is made with the
        outputs, or when first needed)."""
        if self._pubs:
            self._corr_out_publisher(name)

    def warn_once(self, key: str, text: str) -> None:
        """A warning logged once in the node's life for ``key`` (whatever its configures)."""
        if key not in self._warned_once:
            self._warned_once.add(key)
            self.get_logger().warning(text)

    def warn(self, key: str, text: str, count: int = 0) -> None:
        """A warning of the node's throttled log (the mode's
        :class:`~rs_localizer.ros.pipeline.ThrottledLog`: at most once per period per
        ``key``; ``count`` > 1 appended as ``[count so far]``)."""
        self._log.warning(key, text, count)

    def wanted(self, topic: str) -> bool:
        """Whether an output has a subscriber (messages nobody receives are not built)."""
        pub = self._pubs.get(topic)
        return pub is not None and pub.get_subscription_count() > 0

    def publish_messages(self, messages: list) -> None:
        """Publish ``(topic, message)`` pairs (:mod:`.outputs`)."""
        for topic, msg in messages:
            self._pubs[topic].publish(msg)

    def _frame_beside_frontend(self, counts, leaf: str, frontend: str, images: str) -> None:
        """A camera's ``leaf`` frame (``correspondences`` or ``keypoints``) while its
        ``frontend`` front end runs on its ``images``: counted ``frames_beside_frontend`` in
        the camera's ``counts`` (its :class:`~.camera_input.CameraCounts`) and, the first
        time in the node, a warning naming both inputs (the frame is solved as given: the
        front end and its map play no part)."""
        counts.add("frames_beside_frontend")
        if "frames_beside_frontend" in self._warned_once:
            return
        topic = self.resolve_topic_name(f"{counts.name}/{leaf}" if counts.name else leaf)
        self.warn_once(
            "frames_beside_frontend",
            f"received {leaf} on {topic} while the {frontend} front end runs on {images}: "
            f"these frames are solved from the given {leaf}, not from the images and the "
            f"front end's map (counted {counts.prefix}frames_beside_frontend; play a bag's "
            "images only: rs-localizer play --source image)",
        )

    def _delivery_failed(self, e: BaseException) -> None:
        self._log.warning("publishing_failed", f"publishing failed: {type(e).__name__}: {e}")

    def record_timing(self, arrived: float, stamp_ns: int) -> None:
        """A pose published: its latency from the frame's arrival (``time.perf_counter``) and
        its stamp's age on the node's clock."""
        toc = time.perf_counter()
        age = (self.get_clock().now().nanoseconds - stamp_ns) * 1e-9
        with self._timing_lock:
            self.latencies.append(toc - arrived)
            self.stamp_ages.append(age)

    def _timing_snapshot(self) -> tuple[list, list]:
        """(latencies, stamp ages) in s, the last 1000 poses."""
        with self._timing_lock:
            return list(self.latencies), list(self.stamp_ages)

    # ---------------------------------------------------------------- diagnostics
    def _status(self, hardware_id: str, level: int, message: str, values) -> DiagnosticStatus:
        """The node's ``DiagnosticStatus`` (named after the node)."""
        name = f"rs_localizer: {self.get_fully_qualified_name()}"
        return status_message(name, hardware_id, level, message, values)

    def diagnostics_status(self) -> DiagnosticStatus:
        """The node's status (:meth:`_status_between_frames`), taken after the frame the
        worker is on (waiting for it: not for the executor's thread, whose timer uses
        :meth:`publish_diagnostics`)."""
        with self._between.frame():
            return self._status_between_frames()

    def _status_between_frames(self) -> DiagnosticStatus:
        """The node's status, named after the node (:meth:`_status`), between two frames of
        the worker (one consistent count): what the mode hands, ``diagnostics()`` ->
        ``(hardware_id, parts)`` (its :class:`~.diagnostics.StatusParts`), laid out by the one
        builder of both modes (:func:`.diagnostics.status`) with the node's latencies and
        stamp ages (s, the last 1000 poses: :meth:`_timing_snapshot`)."""
        hardware_id, parts = self.mode.diagnostics()
        return self._status(hardware_id, *status(parts, self._timing_snapshot()))

    def publish_diagnostics(self) -> None:
        """The diagnostics timer: the node's status published on ``/diagnostics`` between two
        frames of the worker (:meth:`_publish_status`: now while the worker is not on a
        frame, else by the worker after it; the timer never waits for it, and one status
        waits at most); nothing unconfigured."""
        if self.pub_diag is None or self._diagnostics_handed:
            return
        self._diagnostics_handed = True
        self._between.run(self._publish_status)

    def _publish_status(self) -> None:
        """:meth:`_status_between_frames` published on ``/diagnostics``, stamped now."""
        self._diagnostics_handed = False
        pub = self.pub_diag
        if pub is None:
            return
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [self._status_between_frames()]
        pub.publish(msg)

    # ---------------------------------------------------------------- the end
    def _close_viz(self) -> None:
        """Stop the drawing threads of the visualizations (before the node is destroyed)."""
        for viz in dict.fromkeys([self.viz, *self.camera_viz.values()]):  # (each once)
            if viz is not None:
                viz.close()

    def _before_destroy(self) -> None:
        """:meth:`destroy_node`, the worker stopped: a node that is not managed publishes what
        its track still holds (:meth:`_end_video`; a managed node did at deactivate)."""
        if self._unmanaged:
            with contextlib.suppress(Exception):  # (shutting down: the context may be gone)
                self._end_video()

    def destroy_node(self) -> None:
        """Stop the worker thread (the frame it is on is finished), :meth:`_before_destroy`,
        close the visualizations, release the shared maps (maps no other camera of the process
        uses are freed), then destroy the node."""
        self._stop_worker()
        self._before_destroy()
        self._close_viz()
        SHARED_MAPS.release(self)
        return super().destroy_node()
