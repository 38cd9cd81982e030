"""The rig mode of ``rs_localizer_node``: one pose for a rig of rolling-shutter cameras.

With ``rig.cameras`` set (docs/rig_node.md) the process runs this node instead of one localizer
per camera. Every camera of the rig sends its own frames, unsynchronized; the node hands them
to a :class:`~rs_localizer.tracking.video.Localizer` (frames grouped into rig frames by stamp,
one pose per rig frame from all cameras, tracked, the rig's twist fused) and publishes the rig,
``base_frame``, as one body.

Subscriptions (relative names; remap as usual), per camera ``<c>`` of ``rig.cameras``:
    <c>/correspondences  sensor_msgs/PointCloud2  u, v [px, distorted], x, y, z [m, map frame];
                         rows with a NaN or inf dropped (``<c>.points_dropped``), then at most
                         ``max_points`` rows (``<c>.capped_clouds``), as by the single-camera
                         node
    <c>/keypoints        sensor_msgs/PointCloud2  with ``landmarks_file``: u, v, id; each row
                         the 3D point of its id in the landmarks (ids not there counted
                         ``<c>.unknown_landmark_ids``), then as a correspondences cloud
    <c>/camera_info      sensor_msgs/CameraInfo   the camera's intrinsics, checked as by the
                         single-camera node (a rejected one is counted
                         ``<c>.camera_info_rejected.<reason>`` and logged, the camera's
                         previous model stays; the first one accepted is logged); until one
                         arrives the camera's frames wait (state ``waiting``, counted
                         ``<c>.skipped.no_camera_info``, a warning names the topic) and the
                         rig runs on the others
    <c>/image_raw        sensor_msgs/Image (mono8/rgb8/bgr8/rgba8/bgra8), when ``frontend`` is
                         set: each camera's own front end (``frontend``, ``frontend_map``,
                         ``aruco.*`` / ``features.*``) searching with the rig's prediction
                         mapped into the camera, its rows dropped and capped as a cloud's
                         (``<c>.points_dropped``, ``<c>.capped_clouds``); decoded and checked
                         as the single-camera node does (``bad_image``, ``image_size_mismatch``,
                         counted ``<c>.skipped.<reason>``); ``image_transport: compressed``:
                         ``<c>/image_raw/compressed`` (sensor_msgs/CompressedImage; of
                         ``<c>/image_raw`` resolved: a remap of it moves it too)
    The frame inputs are best effort (history 100 clouds / 10 images); they and the
    camera_infos are overridable as the single-camera node's
    (``qos_overrides./rig/front/image_raw.subscription.reliability``).
and, with ``imu.enabled``, one for the rig:
    imu                  sensor_msgs/Imu (sensor-data QoS): a gyro on the rig, ``imu.rotation``
                         its rotation IMU -> base_frame; every rig frame is solved with its
                         angular velocity over the rig frame's capture times (rejected when
                         the image contradicts it; counted ``rig.gyro_used``,
                         ``rig.gyro_rejected``, ``rig.gyro_missing``); a rig frame does not
                         wait for samples (``imu.wait`` unused: it is solved once its cameras
                         moved past it)
Publications (reliable, depth 10), the rig's (``base_frame``) pose in ``map_frame``:
    pose, pose_with_covariance, twist_single_frame (the rig frame's own twist), twist and odom
    (the fused twist ``tracking.lag`` rig frames later, stamped with that rig frame's time;
    the own twist without tracking), /tf (map_frame -> base_frame, with ``publish_tf``),
    /diagnostics (one status: the rig's counts and every camera's, with warnings);
    path (the rig's poses), <c>/debug_image and <c>/markers (each camera as the rig's pose and
    its mounting put it): the single-camera node's visualization (:mod:`.visualization`,
    ``viz.*``), built only when subscribed; <c>/correspondences_out with a front end and
    ``republish_correspondences``: what camera ``<c>``'s front end found in each image, as the
    single-camera node's ``correspondences_out`` (stamped like the image, published even when
    the rig frame then fails). After ``tracking.max_gap`` without camera frames
    the twists still pending are published (as by the single-camera node).

The subscription callbacks count each camera frame and queue it (:mod:`.frame_queue`, at most
``queue_size`` frames per camera waiting; a full queue drops its oldest rig frame, counted
``<c>.skipped.queue_full``); one worker thread hands them to the rig in arrival order (a rig
frame's frames taken together) and publishes what they complete, so the executor stays free
for the cameras' next frames however slow a rig frame is. Per camera ``received = solved +
failed + skipped + pending`` in every diagnostics snapshot (pending: waiting in the queue or
in an open rig frame). Each camera's inputs are taken by a
:class:`~rs_localizer.ros.camera_input.CameraInput`, as the single-camera node's: its
camera_infos kept by stamp (a frame uses the camera_info of its stamp,
:mod:`.camera_info_history`), its clouds' rows, its images decoded, and each frame checked at
the localizer's entry in the single camera's code (:meth:`.camera_input.CameraInput.admit`:
a header stamp out of range, or its time on the rig's clock, the rig frame's stamp, out of
[0, 2^31 s) counted ``<c>.failed.bad_stamp``, an image without a front end
``<c>.failed.no_frontend``; the rig never sees them). A parameter change at
run time takes the single-camera node's path (:meth:`.core.NodeCore._on_set_parameters`): the
parameters of the rig's estimator, tracking and gyro, ``time_reset_threshold``,
``max_points`` and ``queue_size`` apply from the next rig frame on
(:data:`.config.RIG_RUN_TIME_PARAMETERS`), ``viz.*`` are read when drawing, and the others
are refused with why (:func:`.config.rig_change_refused`). The managed node
(:class:`~rs_localizer.ros.lifecycle.RSLocalizerLifecycleNode`) runs the same mode.
"""

from __future__ import annotations

import time
from collections import Counter, deque
from collections.abc import Collection, Iterator

from ..camera import CameraModel
from ..runtime.background import ready_implementation
from ..tracking.video import Localizer, LocalizerOutput
from .camera_input import (
    CameraCounts,
    DroppedFrame,
    FrameStep,
    ImageFrame,
    rig_camera_inputs,
)
from .config import (
    LocalizerConfig,
    build_config,
    load_maps,
    rig_camera_names,
    rig_change_refused,
    same_value,
)
from .core import ModeBase, NodeCore, QueuedFrame, TakenFrame
from .declare import declare_dynamic, declare_parameters
from .diagnostics import GyroState, RigInputs, StatusParts, rig_camera_status
from .frame_queue import FRAME_ACCOUNTING, FrameCounts
from .outputs import CameraView, FrameOutcome, LogLine, PosedFrame, publish_frame
from .params import RIG_CAMERA_PARAMETERS, RIG_PARAMETERS, ConfigError
from .pipeline import (
    FusedOutput,
    MapFitCheck,
    ThrottledLog,
    fused_outputs,
    take_gyro_sample,
    warm_kernels,
)
from .visualization import rig_camera_views

__all__ = ["RigMode", "note_camera_frame", "rig_status_parts"]


INPUT_SKIP_REASONS = {
    "queue_full": "the node was busy: the frame queue was full (``queue_size`` frames per "
    "camera) and this, the oldest waiting frame, was dropped so that the newest are solved",
    "stopped": "the frame inputs stopped (deactivate) while the frame waited in the queue",
}
"""The node's reasons for a camera frame dropped before it reaches the rig (counted
``<c>.skipped.<reason>``, beside the rig's own
:data:`~rs_localizer.tracking.video.SKIP_REASONS`)."""


def note_camera_frame(counts: CameraCounts, tic: float, taken_at: float,
                      frontend_s: float | None, posed: bool, toc: float) -> None:  # fmt: skip
    """A rig camera's frame through the worker (:func:`time.perf_counter` s), its times per
    stage in the rig's ``counts`` (:meth:`.camera_input.CameraCounts.stage_time`): taken by
    its input stage from ``tic`` to ``taken_at`` (``decode``: decoding, its stamp and
    camera_info), then the rig until ``toc``: the front end's ``frontend_s`` on an image (None:
    not searched) and, when it completed a posed rig frame (``posed``), the rest
    (``estimate``: grouping, the rig's estimate, its gyro wait and tracking)."""
    counts.stage_time("decode", taken_at - tic)
    if frontend_s is not None:
        counts.stage_time("frontend", frontend_s)
    if posed:
        counts.stage_time("estimate", toc - taken_at - (frontend_s or 0.0))


class RigMode(ModeBase):
    """The rig's part of :class:`~rs_localizer.ros.node.RSLocalizerNode` (``rig.cameras``
    set; module docstring): each camera's topics under ``<c>/``, its frames to one
    :class:`~rs_localizer.tracking.video.Localizer` on the node's worker thread, the rig
    frames they complete published, the rig's diagnostics with a section per camera. The node
    (:class:`~rs_localizer.ros.core.NodeCore`, ``node``) holds the plumbing, the modes' shared
    base (:class:`~rs_localizer.ros.core.ModeBase`) what both modes do alike; this object
    what only the rig's does (the single camera's is
    :class:`~rs_localizer.ros.node.CameraMode`). Nothing before ``configure``
    (:meth:`_start_with`: the cameras, their inputs and counts, the frame queue, the
    localizer)."""

    #: the rig's topics and texts (:class:`~rs_localizer.ros.core.NodeCore`)
    count_image_frames = False
    cloud_kind = "cloud"
    image_topic = "image_raw"
    keypoints_always = False
    busy_key = "queue_full"
    busy_text = (
        "busy: frame queue full ({size} frames, queue_size {queue_size} per camera), dropped "
        "the oldest waiting frame [{dropped} dropped so far]"
    )
    mode_note = ", rig mode"
    rig = None  # (None: not configured)

    def __init__(self, node: NodeCore):
        super().__init__(node)
        self.imu_rejected: dict[str, int] = {}

    def configured_as(self) -> str:
        """What the managed node's ``configured: ... (inactive)`` line names."""
        return f"rig of {len(self.cfg.cameras)} cameras"

    def _configuration(self) -> tuple[LocalizerConfig, dict]:
        """The configuration at configure (each camera's ``rig.<camera>.*`` declared on first
        use; :meth:`changed_configuration` unchecked) and the landmarks and front-end map
        loaded once, a front end object per camera (camera name -> its maps).

        Raises:
            ConfigError: a value that cannot be used (naming it).
        """
        node = self.node
        # (the names first: they make parameter and topic names)
        names = rig_camera_names(node.get_parameter("rig.cameras").value)
        own = {k: v for k, v in RIG_CAMERA_PARAMETERS.items() if k != "mounting"}
        for n in names:
            if not node.has_parameter(f"rig.{n}.line_delay"):
                declare_parameters(node, {f"rig.{n}.{k}": v for k, v in own.items()})
                declare_dynamic(node, f"rig.{n}.mounting", RIG_CAMERA_PARAMETERS["mounting"])
        (config,) = self.changed_configuration({}, check=False)
        return config, {c.name: load_maps(c, owner=node) for c in config.cameras}

    def _start_with(self, built: tuple[LocalizerConfig, dict]) -> None:
        """The configuration taken: the node's settings (:meth:`~.core.ModeBase._settle`), a
        front end per camera when ``frontend`` is set, the rig localizer, the cameras' inputs
        and counts and their frame queue (:meth:`.core.NodeCore.set_cameras`)."""
        node = self.node
        config, loaded = built
        self.cfg = config
        log = ThrottledLog(node.get_logger(), period=5.0)  # (each kind once per 5 s)
        # (rig frames on the NumPy implementation while the kernels compile in the background)
        self.rig = Localizer(config.settings, log=log, implementation=ready_implementation)
        for c in config.cameras:
            if c.frontend_kind != "none":
                self.rig.set_frontend(c.name, loaded[c.name].frontend, c.frontend_kind)
        self._group_ns = int(config.settings.window * 1e9)
        # (the worker's map-fit check over the rig frames, its times per stage)
        self._rig_counts = CameraCounts()
        # each camera's own counts (the diagnostics' inputs, ``<c>.<key>``: its frames
        # received, handed on, skipped or failed before the rig, its input stage's counts, its
        # messages lost, the worker's time per frame) and its input (its camera_infos by
        # stamp, its clouds' rows, its images), a frame queue for them
        counts = {c.name: CameraCounts(c.name) for c in config.cameras}
        #: (the landmarks of ``landmarks_file``, ``(ids, points)``, the cameras' keypoints name)
        landmarks = next(iter(loaded.values())).landmarks
        inputs = rig_camera_inputs(config, log, self._count_input, stopped=node.stopping,
                                   wait=config.camera_info_wait,
                                   landmarks=landmarks)  # fmt: skip
        node.set_cameras(inputs, counts, log, self._same_rig_frame, "rs_localizer_rig_worker")
        self._settle(config, landmarks)
        self._images: dict = {}  # (camera -> its last decoded images, for debug_image)
        self._map_fit = MapFitCheck("rig frames")  # (the worker's)

    def _warm_kernels(self, built: tuple) -> None:
        """The rig's kernels (:func:`.pipeline.warm_kernels`, as the single camera's): in
        numba's cache (:func:`~rs_localizer.runtime.warmup.rig_cached`), loaded before the
        next frame (:func:`~rs_localizer.runtime.warmup.warm_rig` with the rig's settings and
        every camera's RS timing); else compiled in another process
        (:class:`~rs_localizer.runtime.background.RigKernels`) while the rig frames are solved
        on the NumPy implementation. Without ``warmup`` the first rig frame pays for them
        while the cameras' frames queue."""
        from ..runtime.background import RigKernels
        from ..runtime.warmup import warm_rig

        config = built[0]
        timing = config.timings

        def warm() -> tuple[float, str]:
            tic = time.perf_counter()
            posed = warm_rig(config.settings, timing)
            return time.perf_counter() - tic, f"{posed} synthetic rig frames posed"

        kernels = RigKernels(config.settings, timing)
        warm_kernels(kernels, "rig", warm, self.node.get_logger(), True,
                     "`rs-localizer compile --params-file`")  # fmt: skip

    def close_track(self) -> list[FrameOutcome]:
        """:meth:`.core.NodeCore._end_video`: the rig frames still open, solved, then the
        twists still pending (none unconfigured)."""
        if self.rig is None:
            return []
        closed = [self._outcome(out) for out in self.rig.close()]
        pending = self.rig.flush() + self.rig.reset()
        return [*closed, FrameOutcome(fused=fused_outputs(pending, self.cfg.base_frame))]

    def _ready_warnings(self) -> list[str]:
        """The single camera's parameters set but not used by the rig."""
        return [self.cfg.unused_text] if self.cfg.unused_text else []

    def _ready_subject(self) -> str:
        timing = []
        for c in self.cfg.cameras:
            t = (
                f"readout {c.readout_time * 1e3:.2f} ms"
                if c.readout_time > 0
                else f"line delay {c.line_delay * 1e6:.2f} us/line"
            )
            timing.append(f"{c.name} {t} {c.direction}")
        return (
            f"rig of {len(self.cfg.cameras)} cameras ({'; '.join(timing)}) posed as "
            f"{self.cfg.base_frame} in {self.node.map_frame}"
        )

    # ---------------------------------------------------------------- parameters
    def changed_configuration(self, overrides: dict, check: bool = True) -> tuple[LocalizerConfig]:
        """The rig's configuration of the parameters with ``overrides`` (name -> value of
        :data:`~.params.PARAMETERS`; ``{}``: at configure) and each camera's ``rig.<c>.*``, as
        :func:`.config.build_config` makes it. ``check``: a change while the rig runs, refused
        for the parameters it cannot take without a restart (:func:`.config.rig_change_refused`)
        unless their value stays the same.

        Raises:
            ConfigError: a value that cannot be used, or a change refused (naming them).
        """
        if check:
            changed = [
                n
                for n, v in overrides.items()
                if not same_value(v, self.node.get_parameter(n).value)
            ]
            refused = rig_change_refused(changed, self.cfg.settings.single_camera)
            if refused is not None:
                raise ConfigError(refused)
        names = rig_camera_names(self.node.get_parameter("rig.cameras").value)
        values = self.node.param_values(overrides)
        values.update(
            {n: self.node.get_parameter(n).value for n in RIG_PARAMETERS if n != "rig.cameras"}
        )
        values["rig.cameras"] = names
        cams = {
            n: {k: self.node.get_parameter(f"rig.{n}.{k}").value for k in RIG_CAMERA_PARAMETERS}
            for n in names
        }
        return (build_config(values, cams),)

    def _change_to(self, built: tuple[LocalizerConfig], overrides: dict) -> None:
        """The rig takes the new settings from its next rig frame on
        (:meth:`~rs_localizer.tracking.video.Localizer.configure`: the estimator's options,
        tracking, gyro, time resets, ``max_points``; the counts and the rig frames open kept,
        a tracking change starting a new track), each camera's clouds the new ``max_points``,
        the queue the new ``queue_size``, each camera's frames the new ``camera_info_wait``."""
        (config,) = built
        with self.node.between_frames():  # (between two camera frames of the worker)
            self.rig.configure(config.settings)
            self.cfg = config
            for inp in self.node.inputs.values():
                inp.max_points = config.settings.max_points
                inp.wait = float(config.camera_info_wait)
        self._settle(config, self.node.landmarks)

    # ---------------------------------------------------------------- inputs
    def _count_input(self, name: str, key: str, n: int = 1) -> None:
        """Add ``n`` to camera ``name``'s count ``<name>.<key>`` (the node's own counts)."""
        self.node.camera_counts[name].add(key, n)

    def _same_rig_frame(self, batch: list, item) -> bool:
        """Whether a waiting frame goes with the frames the worker takes (``batch``): another
        camera's whose reference-line time (by the camera's newest camera_info) is within
        ``rig.window`` of the first's, as the rig groups them. A rig frame's frames are then
        taken together, and a full queue drops whole rig frames, not the rest of the one
        being solved."""
        if any(b.name == item.name for b in batch):
            return False
        if isinstance(item.stamp, DroppedFrame) or isinstance(batch[0].stamp, DroppedFrame):
            return False  # (a stamp the worker will refuse: not grouped)
        return abs(self._ref_ns(item) - self._ref_ns(batch[0])) <= self._group_ns

    def _ref_ns(self, item: QueuedFrame) -> int:
        """A queued frame's time on the rig's clock (ns) by its camera's newest model (its
        stamp without one), as the rig groups it
        (:meth:`~rs_localizer.tracking.video.LocalizerSettings.reference_ns`)."""
        return self.cfg.settings.reference_ns(
            item.name, item.stamp, self.node.inputs[item.name].newest
        )

    def camera_of(self, item: QueuedFrame) -> CameraModel | None:
        """The camera model of the frame's stamp, waiting up to ``camera_info_wait`` for its
        camera_info: outside the worker's lock, which the diagnostics take on the executor
        that delivers it."""
        return self.node.inputs[item.name].camera_of(item.stamp)

    def take_frame(self, item: QueuedFrame, camera: CameraModel | None) -> TakenFrame:
        """The worker: one camera frame to the rig (:meth:`_take`), or why not (the rig never
        sees it): the single camera's entry checks (:meth:`.camera_input.CameraInput.admit`:
        a header stamp or an output stamp out of range, ``bad_stamp``; an image without a
        front end, ``no_frontend``), counted ``failed.<reason>`` and logged. Under the
        worker's lock with its count, so that a diagnostics snapshot sees the rig's and the
        camera's counts of it at once; with
        ``republish_correspondences`` what the camera's front end found in an image."""
        name, kind, msg, stamp = item.name, item.kind, item.msg, item.stamp
        if kind == "image":
            self._warn_no_info(name, "images")
        tic = time.perf_counter()
        # (the single camera's entry checks: its stamp, its times made once, its output stamp
        # in range; then the frame step, a rig bag's replay's too)
        frontend = self.node.frontend_kind != "none"
        taken = self.node.inputs[name].enter(self.rig, msg, kind, stamp, camera, frontend)
        if isinstance(taken, DroppedFrame):  # (the rig never sees it either)
            self.node.warn(
                f"{taken.reason}.{name}",
                f"rig camera {name!r}: frame dropped ({taken.reason}): {taken.error}",
                self.node.camera_counts[name].get(f"failed.{taken.reason}") + 1,
            )
            return TakenFrame((f"failed.{taken.reason}",), taken.reason)
        found = []
        outs = self._take(name, kind, taken, tic)
        if kind == "image" and self.node.republish:
            corr = self.rig.last_correspondences(name)
            if corr is not None:  # (also an image where it found nothing)
                found.append((name, corr, stamp))
        return TakenFrame(outs=outs, found=found)

    def _take(self, name: str, kind: str, taken: FrameStep, tic: float) -> list:
        """A camera frame's step into the rig from ``tic`` (:func:`time.perf_counter` s;
        :meth:`.camera_input.CameraInput.enter`: its checked times, then the single camera's
        frame step, :meth:`.camera_input.CameraInput.step`: :meth:`~.camera_input.
        CameraInput.take`, :func:`.camera_input.to_rig`, the stamp then noted on the rig's
        clock: the camera's camera_infos stamped after a time reset forgotten), ``taken``,
        counted and logged; returns the rig frames it completed.

        A cloud (``kind`` ``cloud``, or ``keypoints``: u, v, id, its rows the points of the
        ``landmarks_file`` it names, unknown ids counted ``<c>.unknown_landmark_ids``, none
        known: a frame without rows, which the rig frame is posed without): its rows as the
        single-camera node takes them (the non-finite ones dropped, counted
        ``<c>.points_dropped``; capped to ``max_points``, counted ``<c>.capped_clouds``). One
        that cannot be read is counted ``<c>.skipped.bad_input`` and goes to the rig as a
        frame skipped (:meth:`Localizer.drop`), so the rig frame without it counts the camera
        ``missed.skipped``, not ``missed.apart`` (a camera whose frames are apart is named as
        one whose clock is off).

        An image: decoded and checked against ``camera`` as by the single-camera node (a
        message that does not decode or is smaller than the front ends take: ``bad_image``;
        another size than the camera_info's: ``image_size_mismatch``; both logged and counted
        ``<c>.skipped.<reason>``, the rig not waiting for the camera at that time), then the
        camera's front end and the rig (:meth:`Localizer.process_image`: the front end's rows
        as a cloud's, the non-finite ones dropped and the rest capped to ``max_points``,
        counted by the rig as ``<c>.points_dropped``, ``<c>.capped_clouds``); its decoded
        image kept for ``debug_image`` while someone watches. The frame's times per stage go
        to the diagnostics (:func:`note_camera_frame`)."""
        item, outs, taken_at = taken
        search = self.rig.last_search(name) if isinstance(item, ImageFrame) else None
        note_camera_frame(self._rig_counts, tic, taken_at, search and search.seconds,
                          any(o.success for o in outs), time.perf_counter())  # fmt: skip
        if isinstance(item, DroppedFrame):
            self._not_taken(kind, item)
        elif kind != "image":
            self._warn_no_info(name, "keypoints" if kind == "keypoints" else "correspondences")
        viz = self.node.camera_viz.get(name)
        if isinstance(item, ImageFrame) and viz is not None and viz.wants("debug_image"):
            # (only while someone watches; drawn when the rig frame is published)
            self._images.setdefault(name, deque(maxlen=4)).append(
                (item.image, item.encoding, item.stamp_ns)
            )
        return outs

    def _not_taken(self, kind: str, item: DroppedFrame) -> None:
        """A frame of a checked stamp the camera's input stage dropped (the rig counts it
        skipped, :func:`.camera_input.to_rig`), logged: one whose cloud cannot be read
        (``bad_input``) also counted ``<c>.bad_input``."""
        name, error = item.camera_name, item.error
        if item.reason != "bad_input":  # (an image refused: bad_image, image_size_mismatch)
            self.node.warn(
                f"image.{name}", f"rig camera {name!r}: image dropped ({item.reason}): {error}"
            )
            return
        self.node.camera_counts[name].add("bad_input")
        if kind in ("cloud", "keypoints"):
            self.node.warn(f"{kind}.{name}", f"rig camera {name!r}: frame not read: {error}")
        else:
            self.node.warn(f"image.{name}", f"rig camera {name!r}: image not read: {error}")

    def publish_taken(self, item: QueuedFrame, taken: TakenFrame) -> None:
        """The worker, after the frame is counted: the rig frames it completed through the
        map-fit check (:meth:`.pipeline.MapFitCheck.check`, every camera's rows of the rig
        frame together: counted ``rig_frames_failed_with_matches``, ``map_fit_doubtful``; a
        throttled warning), then published with their log lines
        (:func:`.outputs.publish_frame`, :meth:`_outcome`)."""
        tic = time.perf_counter()
        for out in taken.outs:
            if out.estimate is not None:
                self._map_fit.check(out.num_points, out.estimate, self._rig_counts,
                                    self.node.warn)  # fmt: skip
            publish_frame(self.node, self._outcome(out, logged=True))
            if out.success:
                self.node.record_timing(item.arrived, out.stamp_ns)
        if any(o.success for o in taken.outs):
            self._rig_counts.stage_time("publish", time.perf_counter() - tic)

    def _failure_line(self, out: LocalizerOutput) -> LogLine | None:
        """The line a rig frame logs (each reason at most once per 5 s): why it failed with
        the count of rig frames failed so far for that reason, or on a posed one the cameras
        outvoted by the others; None: nothing to say."""
        if out.error is not None:
            reason, detail = "error", f"the estimator raised {out.error}"
        elif out.estimate is not None and not out.estimate.success:
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
                f"[{self.rig.counts[f'{out.outvoted[0]}.outvoted']} rig frames so far]",
            )
        else:
            return None
        n = self.rig.counts[f"rig.failed.{reason}"]
        return LogLine(
            f"rig.failed.{reason}",
            f"rig frame failed ({reason}): {detail} [{n} rig frames failed so far with {reason}]",
        )

    def _warn_no_info(self, name: str, kind: str) -> None:
        if self.node.inputs[name].newest is None:
            self.node.warn(
                f"no_info.{name}",
                f"rig camera {name!r}: {kind} but no camera_info yet on "
                f"{self.node.resolve_topic_name(f'{name}/camera_info')}: its frames wait (counted "
                f"{name}.skipped.no_camera_info), the rig runs on the others",
            )

    def _take_imu(self, msg) -> str | None:
        """A gyro sample of the rig's IMU; returns None or why it was rejected (counted
        ``imu_rejected.<reason>``, as the single-camera node's)."""
        reason = take_gyro_sample(msg, self.rig.add_imu)
        if reason is not None:
            self.imu_rejected[reason] = self.imu_rejected.get(reason, 0) + 1
        return reason

    # ---------------------------------------------------------------- outputs
    def idle_twists(self) -> list[FusedOutput]:
        """:meth:`.core.NodeCore._flush_idle_track` (under the worker's lock): the twists
        still pending after ``tracking.max_gap`` s without camera frames
        (:meth:`Localizer.flush_idle`; none unconfigured)."""
        if self.rig is None:
            return []
        return fused_outputs(self.rig.flush_idle(), self.cfg.base_frame)

    def _outcome(self, out: LocalizerOutput, logged: bool = False) -> FrameOutcome:
        """What a rig frame publishes (:class:`.outputs.FrameOutcome`): posed, the rig's pose
        (``base_frame``) at the rig frame's time with its own twist when that is final at
        once (without tracking, or a rig of one camera with a global shutter or a
        global-shutter solver), and each camera of it whose ``<c>/debug_image`` or
        ``<c>/markers`` is watched as the rig's pose and its mounting put it
        (:func:`.visualization.rig_camera_views`, with its image kept by :meth:`_take`); the
        fused twists it made final; ``logged``: its :meth:`_failure_line`."""
        base = self.cfg.base_frame
        fused = fused_outputs(out.fused, base)
        line = self._failure_line(out) if logged else None
        log = () if line is None else (line,)
        if not out.success:
            return FrameOutcome(None, fused, log)
        views = () if self.node.viz is None else tuple(self._views(out))
        return FrameOutcome(PosedFrame(out.estimate, out.stamp_ns, base, out.twist_now, views),
                            fused, log)  # fmt: skip

    def _views(self, out: LocalizerOutput) -> Iterator[CameraView]:
        """The cameras of a posed rig frame whose debug views are watched, as
        :class:`.outputs.CameraView` s (their frame's image, the last kept of its stamp)."""
        mounts = {c.name: c.mount for c in self.cfg.cameras}

        def wanted(n: str) -> bool:
            viz = self.node.camera_viz.get(n)
            return viz is not None and (viz.wants("debug_image") or viz.wants("markers"))

        for n, frame, view, ref in rig_camera_views(out, mounts, wanted):
            image = None
            for img in self._images.get(n, ()):
                if img[2] == frame.stamp_ns:
                    image = img
            yield CameraView(n, view, frame.points2d, frame.points3d, frame.camera,
                             frame.stamp_ns, ref, frame.tag or n, image)  # fmt: skip

    def diagnostics(self) -> tuple[str, StatusParts]:
        """The rig's hardware id (``base_frame``) and status (:func:`rig_status_parts` of the
        node's counts and times per camera)."""
        waiting = {n for n, i in self.node.inputs.items() if i.newest is None}
        first = self.node.first_frame
        waited = first is not None and time.monotonic() - first > self.cfg.settings.stop_after
        with self.node.between_frames():  # (after the frame the worker is on: one consistent count)
            counts = Counter(self._rig_counts.counts())
            for cc in self.node.camera_counts.values():
                counts.update(cc.prefixed())
            frame_times = {n: cc.frame_times() for n, cc in self.node.camera_counts.items()}
            absent = [n for n in self.node.inputs if waited and counts[f"{n}.received"] == 0]
            inputs = RigInputs(counts, frame_times, dict(self.imu_rejected), absent,
                               self.node.frontend_kind != "none",
                               self._rig_counts.stage_times())  # fmt: skip
            return self.cfg.base_frame, rig_status_parts(self.rig, waiting, inputs)


def rig_status_parts(
    rig: Localizer, waiting_info: Collection[str] = (), inputs: RigInputs | None = None
) -> StatusParts:
    """The rig's status as data (:func:`.diagnostics.status` lays it out, as one camera's):
    its rig frames (``rig_frames``, ``rig_frames_solved`` ... ``_pending``; the rig
    estimator's failures by reason, ``rig_frames_failed.<reason>``, ``error``: it raised), a
    section per camera (:func:`.diagnostics.rig_camera_status`, ``waiting_info`` the cameras
    waiting for their camera_info), after the estimator's path ``rig_frames_uncompiled``
    (rig frames solved on the uncompiled path) and ``time_resets``; ``track_state``, the
    fused twists' and the rolling-shutter timing check's values as a camera's; with a gyro
    the camera's gyro values (:meth:`~rs_localizer.tracking.video.Localizer.gyro_counts`:
    the rig frames for its frames) and the rig's own warning when the image rejects the gyro
    more often than it uses it (while the gyro is not found to contradict the image). With
    the node's ``inputs`` (None: the rig's counts alone) also its map-fit check, its stage
    times, each camera's and all cameras' ``camera_frame_ms_median``, the IMU messages
    rejected (``imu_rejected.<reason>``) and the cameras that sent nothing (``absent``)."""
    gyro, warnings, counts = None, [], {}
    if rig.settings.imu is not None:
        c = rig.gyro_counts()
        c["imu_rejected"] = sum(inputs.imu_rejected.values()) if inputs is not None else 0
        if not rig.gyro_inconsistent and c.get("gyro_rejected", 0) > c.get("frames_with_gyro", 0):
            warnings.append("the image contradicts the gyro: check imu.rotation, its bias")
        gyro = GyroState.of(rig.settings.imu, c, rig.imu, rig.gyro_bias_values(),
                            rig.gyro_inconsistent)  # fmt: skip
        counts = dict(c)
    if inputs is not None:
        counts.update({f"imu_rejected.{k}": v for k, v in inputs.imu_rejected.items()})
    r, failed = rig.rig_counts(), "rig.failed."
    failures = {k[len(failed) :]: v for k, v in rig.counts.items() if k.startswith(failed)}
    return StatusParts(
        frames=FrameCounts(r["rig_frames"], *(r[k] for k in FRAME_ACCOUNTING[1:]),
                           failures=failures),
        cameras=[rig_camera_status(rig, n, waiting_info, inputs) for n in rig.cameras],
        warnings=warnings,
        path={"rig_frames_uncompiled": rig.counts.get("rig.uncompiled", 0),
              "time_resets": rig.counts.get("rig.time_resets", 0)},
        map_fit=inputs.counts if inputs is not None else None,
        tracking={"track_state": rig.track_state, **rig.twist_values(), **rig.readout_values()},
        stage_times=inputs.stage_times if inputs is not None else None,
        with_frontend=inputs is not None and inputs.frontend,
        gyro=gyro,
        counts=counts,
        absent=list(inputs.absent) if inputs is not None else [],
    )  # fmt: skip
