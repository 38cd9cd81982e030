"""The one mode of ``rs_localizer_node``: one camera or a rig of cameras, through one path.

:class:`LocalizerMode` is what the node (:class:`~rs_localizer.ros.core.NodeCore`) does with
its cameras: their configuration, what the worker does with a frame, what it publishes and its
status. ``rig.cameras`` empty: the node's camera is a rig of one camera named ``""`` at the
identity mounting (:func:`~rs_localizer.tracking.sequence.rig_of_one`: the camera's solver,
estimator options, tracking, gyro, ``stamp_row``, ``time_reset_ns``, ``max_points``), on the
topics without prefix, its frames, counts, diagnostics and log lines a camera's (docs/node.md);
``rig.cameras`` set: the rig's cameras, each on its ``<c>/`` topics, one pose for the rig
(docs/rig_node.md; what only a rig of several needs: :mod:`.rig_node`).

Either way each camera's frame message takes the one frame step into one
:class:`~rs_localizer.tracking.video.Localizer`, the rig mode's: its camera's input stage
(:class:`~rs_localizer.ros.camera_input.CameraInput`: its stamp checked as it arrived, its
camera model of that stamp from its camera_infos), the entry checks and the rows or the
image to the localizer (:meth:`~rs_localizer.ros.camera_input.CameraInput.enter`), then the
rig frames it completes published (:func:`.outputs.publish_frame`). The camera alone is its
rig of one as ``rs-localizer replay`` runs a camera's bag: its stamp noted on the localizer's
clock before its camera_info is looked up (a time reset forgets the camera_infos stamped after
it), its warnings worded as a camera's (a camera's video,
:attr:`~rs_localizer.tracking.video.LocalizerSettings.camera_video`), each frame counted
``solved`` or ``failed.<reason>`` with the line ``frame dropped (<reason>): <detail>``, its
pose in its optical frame (or with ``camera_to_base.*`` the robot's ``base_frame``).
"""

from __future__ import annotations

import time
from collections import Counter, deque
from typing import Any

import numpy as np

from ..correspondences import Correspondences
from ..frontends.shared import LoadedMaps
from ..runtime.background import ready_implementation
from ..tracking.gyro_input import GyroInput
from ..tracking.video import Localizer, LocalizerOutput
from .camera_input import (
    CameraCounts,
    CameraInput,
    DroppedFrame,
    FrameStep,
    ImageFrame,
    rig_camera_inputs,
)
from .config import LocalizerConfig, build_config, default_timing_note, load_maps
from .core import ModeBase, NodeCore, QueuedFrame, TakenFrame, names_a_rig
from .diagnostics import (
    CameraAlone,
    RigInputs,
    StatusParts,
    frontend_values,
    localizer_status_parts,
)
from .outputs import (
    CameraView,
    FrameOutcome,
    LogLine,
    frame_outcome,
    publish_frame,
    rig_frame_line,
    rig_frame_views,
)
from .pipeline import (
    Drop,
    FusedOutput,
    MapFitCheck,
    PipelineStats,
    ThrottledLog,
    fused_outputs,
    take_imu_message,
)
from .rig_node import (
    RIG_TEXTS,
    SameRigFrame,
    rig_values,
)

__all__ = ["CameraFrameResult", "LocalizerMode"]


class CameraFrameResult:
    """What a camera's frame gave in the frame step (:meth:`LocalizerMode.take_frame`): the
    rig frames it completed (``outs``; the camera alone's: its rig of one's, ``out``), its
    camera model, stamps (ns: header, reference line's), frame id, decoded image, what the
    front end found to republish and, failed, why (``failure``, ``detail``); the camera
    alone's also the rows its estimator was given, the fused twists now final and, posed, its
    count ``solved`` (``counted``; a rig camera's frame is solved or failed in its rig frame:
    the rig counts it)."""

    failure: str | None = None
    counted: tuple = ()
    detail: str = ""
    points2d: np.ndarray | None = None
    points3d: np.ndarray | None = None
    camera: Any = None
    stamp_ns: int | None = None
    out_stamp_ns: int | None = None
    image: tuple | None = None
    correspondences: Correspondences | None = None

    def __init__(self, frame_id: str):
        self.frame_id = frame_id
        self.outs: list[LocalizerOutput] = []
        self.fused: list[FusedOutput] = []

    def noted(self, ft: Any) -> None:
        """The frame's times as the localizer's entry made them (its reference-line stamp)."""
        self.out_stamp_ns = ft.reference_ns

    @property
    def out(self) -> LocalizerOutput | None:
        """The camera alone's rig frame (its rig of one's; None: none)."""
        return self.outs[0] if self.outs else None

    @property
    def solved(self) -> bool:
        """The frame has a pose (no failure)."""
        return self.failure is None

    @property
    def estimate(self) -> Any:
        """The camera's :class:`~rs_localizer.estimation.RSPoseEstimate` (camera frame;
        None: the estimator did not run)."""
        return None if self.out is None else self.out.camera_estimate

    @property
    def twist_now(self) -> bool:
        """The frame's own twist is final (no tracking, a global-shutter solver or timing);
        else its fused twist comes in a later frame's :attr:`fused`."""
        return self.out is not None and self.out.twist_now

    @property
    def compiled(self) -> bool:
        """Solved on the compiled kernels (False: on the uncompiled path while they compile)."""
        return self.out is None or self.out.compiled


class LocalizerMode(ModeBase):
    """The node's one mode (module docstring), for the camera alone (``rig.cameras`` empty,
    :attr:`alone`) or a rig. The node (:class:`~rs_localizer.ros.core.NodeCore`, ``node``)
    holds the plumbing, :class:`~rs_localizer.ros.core.ModeBase` the phases; this object its
    cameras and its localizer (:attr:`rig`, made at configure). The camera alone's input
    stage and counts (named "") are made with the node's state (``_init_state``), so that its
    camera_infos and counts outlast a change of parameters; a rig's at configure."""

    rig: Localizer | None = None  # (None: not configured)
    _grouping: SameRigFrame | None = None  # (a rig's grouping of queued frames)

    def __init__(self, node: NodeCore):
        super().__init__(node)
        #: the camera alone, a rig of one (``rig.cameras`` empty)
        self.alone = not names_a_rig(node.get_parameter("rig.cameras").value)
        self._loaded: dict = {}  # (camera name -> its maps in use)
        self._images: dict = {}  # (a rig camera -> its last decoded images, for debug_image)
        #: the fused twists' frame and mounting (:meth:`_fused`), set at configure
        self._fused_in: tuple = (None, None)
        if not self.alone:  # (a rig's topics are its cameras' <c>/..., the camera's today's)
            for k, v in RIG_TEXTS.items():
                setattr(self, k, v)

    def configured_as(self) -> str:
        """What the managed node's ``configured: ... (inactive)`` line names."""
        if self.alone:  # (the camera's line kept; a rig's names its cameras)
            return f"solver {self.cfg.solver}"
        return f"rig of {len(self.cfg.cameras)} cameras"

    def camera_of(self, item: QueuedFrame) -> Any:
        """The camera model of a rig camera's frame stamp, waiting up to ``camera_info_wait``
        for its camera_info: before the worker's frame, so that the steps run between two
        frames (the diagnostics) do not wait for it. None for the camera alone: its stamp is
        noted on its video's clock first (:meth:`_camera_at`)."""
        if self.alone:  # (its stamp first resets its clock, whose reset forgets camera_infos)
            return None
        return self.node.inputs[item.name].camera_of(item.stamp)

    # ---------------------------------------------------------------- configuration
    def changed_configuration(self, overrides: dict) -> tuple[LocalizerConfig, dict]:
        """The configuration of the parameters with ``overrides`` (none at configure; with a
        rig's cameras' parameters, :func:`.rig_node.rig_values`: each declared on first use, a
        change refused for those a rig cannot take without a restart) and each camera's maps
        (camera name -> its :class:`~rs_localizer.frontends.shared.LoadedMaps`, held by the
        node: the landmarks of ``landmarks_file``, the camera's own front end of
        ``frontend_map``, the one in use kept while its kind and map stay the same).

        Raises:
            ConfigError: a value that cannot be used, a map that does not load, a change
                refused (naming them).
            RuntimeError: a rig camera's value of the wrong type or outside its range, at
                its declaration (naming it).
        """
        cams = rig_values(self.node, overrides, self.cfg)
        cfg = build_config(self.node.param_values(overrides), cams)
        return cfg, {c.name: load_maps(c, owner=self.node, current=self._loaded.get(c.name))
                     for c in cfg.cameras}  # fmt: skip

    def _change_to(self, built: tuple, overrides: dict) -> None:
        """A run-time change taken from the next frame on, between two frames of the worker
        (:meth:`_start_with`: now while the worker is not on a frame, else by the worker
        after the frame it is on; the parameter callback does not wait for it); reloaded
        landmarks logged."""
        self.node.between_frames(lambda: self._start_with(built))
        landmarks, path = built[0].camera.landmarks_file, built[1][built[0].camera.name]
        if overrides.get("landmarks_file") and path.landmarks is not None:
            self.node.get_logger().info(
                f"reloaded {len(path.landmarks[0])} landmarks from {landmarks}"
            )

    def _new_cameras(self, cfg: LocalizerConfig, settings: Any) -> None:
        """The mode's cameras handed to the node (:meth:`.core.NodeCore.set_cameras`) and its
        localizer: the camera alone's (its counts :class:`~.pipeline.PipelineStats`, its
        frames', input stage's, estimates' and gyro's, worded as a camera's; its frames on
        the NumPy implementation of its solver while the kernels compile), or a rig's
        (each camera's input, :func:`.camera_input.rig_camera_inputs`: its camera_infos by
        stamp, its clouds' rows, its images; its counts, the diagnostics' ``<c>.<key>``; the
        rig's own counts: the map-fit check over the rig frames, its times per stage, its IMU
        messages rejected; the frame queue grouped by rig frame, :class:`.rig_node.SameRigFrame`;
        its log each kind once per 5 s; its rig frames on the NumPy implementation while the
        kernels compile in the background), with the localizer's ``settings``."""
        node = self.node
        if not self.alone:  # (a rig frame groups several cameras' frames: counted apart)
            log = ThrottledLog(node.get_logger(), period=5.0)
            self.rig = Localizer(cfg.settings, log=log, implementation=ready_implementation)
            counts = {c.name: CameraCounts(c.name) for c in cfg.cameras}
            add = lambda n, key, k=1: counts[n].add(key, k)  # noqa: E731
            inputs = rig_camera_inputs(
                cfg, log, add, stopped=node.stopping, wait=cfg.camera_info_wait
            )
            self._counts, self._grouping = CameraCounts(), SameRigFrame(cfg.settings, inputs)
            node.set_cameras(inputs, counts, log, self._grouping, "rs_localizer_rig_worker")
            self._map_fit = MapFitCheck("rig frames")
            self._images = {}
            return
        log = ThrottledLog(node.get_logger())
        self._own = self._counts = PipelineStats()
        self._map_fit = MapFitCheck()
        inp = CameraInput(log, self._own.add, stopped=node.stopping)
        gyro = GyroInput(self._own.add, inp.log, stopped=node.stopping)
        impl = lambda: ready_implementation(self.cfg.solver)  # noqa: E731
        self.rig = Localizer(settings, inp.log, impl, gyro_input=gyro, count=self._own.add)
        node.set_cameras({"": inp}, {"": self._own}, log)

    def _start_with(self, built: tuple) -> None:
        """The configuration ``built`` taken, at configure and at a change, by the camera
        alone and a rig alike: the mode's cameras made at configure (:meth:`_new_cameras`),
        else its localizer configured from its next frame on
        (:meth:`~rs_localizer.tracking.video.Localizer.configure`: the estimator's options,
        tracking, gyro, time resets, ``max_points``; its track, gyro and counts kept where
        they still apply), each camera's front end and input stage (the camera models of its
        camera_infos so far rebuilt with its RS timing, its clouds' ``max_points``, its
        ``camera_info_wait``, its landmarks), the rig frames' grouping, the node's settings
        (:meth:`~.core.ModeBase._settle`); a reloaded front end, the marker detector that runs
        and a default RS timing with images logged."""
        cfg, maps = built
        old, old_maps, log = self.cfg, self._loaded, self.node.get_logger()
        self.cfg, self._loaded = cfg, maps
        settings = cfg.video_settings
        if self.rig is None:
            self._new_cameras(cfg, settings)
        else:
            self.rig.configure(settings)
        if self._grouping is not None:
            self._grouping.settings = settings
        self._fused_in = cfg.fused_frame
        for c in cfg.cameras:
            self.rig.set_frontend(c.name, maps[c.name].frontend, c.frontend_kind)
            self.node.inputs[c.name].configure(c.camera_from_info, cfg.max_points, c.fallback,
                                               cfg.camera_info_wait, maps[c.name].landmarks,
                                               c.frame)  # fmt: skip
        cam = cfg.camera
        fe, old_fe = maps[cam.name].frontend, old_maps.get(cam.name, LoadedMaps()).frontend
        self._settle(cfg, maps[cam.name].landmarks)
        if old is not None and old_fe is not None and fe is not old_fe:
            log.info(f"reloaded the {cam.frontend_kind} front end from {cam.frontend_map}")
        detector = None if fe is None else fe.marker_detector_note()
        if detector is not None and fe is not old_fe:
            # (which marker detector runs; a missing AprilTag library: a warning with the
            # install line)
            line, fallback = detector
            (log.warning if fallback else log.info)(f"marker detector: {line}")
        note = default_timing_note(cfg) if fe is not None else None  # (images)
        if note is not None:
            self.node.warn_once("default_timing", note)

    def _ready_warnings(self) -> list[str]:
        """The camera alone's global-shutter timing (the twist is then zero); a rig's: the
        single camera's parameters set but not used by the rig."""
        if not self.alone:  # (the camera's warning kept; a rig warns of unused parameters)
            return [self.cfg.unused_text] if self.cfg.unused_text else []
        if self.cfg.camera.line_delay == 0 and self.cfg.camera.readout_time == 0:
            return [
                "rs.line_delay and rs.readout_time are 0: global-shutter "
                "timing, the published twist will be zero"
            ]
        return []

    def _ready_subject(self) -> str:
        cfg, cam = self.cfg, self.cfg.camera
        if not self.alone:  # (the camera's line kept; a rig's names each camera's RS timing)
            timing = "; ".join(
                f"{c.name} readout {c.readout_time * 1e3:.2f} ms {c.direction}"
                if c.readout_time > 0
                else f"{c.name} line delay {c.line_delay * 1e6:.2f} us/line {c.direction}"
                for c in cfg.cameras
            )
            return (
                f"rig of {len(cfg.cameras)} cameras ({timing}) posed as {cfg.base_frame} in "
                f"{self.node.map_frame}"
            )
        text = f"solver {cfg.solver}, line delay {cam.line_delay * 1e6:.2f} us/line"
        if cam.readout_time > 0:
            text += f", readout {cam.readout_time * 1e3:.2f} ms"
        return text + f", intrinsics from {'parameters' if cam.fallback else 'camera_info'}"

    # ---------------------------------------------------------------- gyro
    def _take_imu(self, msg: Any) -> str | None:
        """A gyro sample of the IMU to the localizer, for the camera alone and a rig alike
        (:func:`.pipeline.take_imu_message`); returns None or why it was rejected, counted
        ``imu_rejected`` and ``imu_rejected.<reason>`` in the mode's counts (the camera
        alone's, or the rig's own beside its cameras') and warned, a lone stamp jump ahead
        found later counted too (``stamp_jumped_ahead``)."""
        return take_imu_message(msg, self.rig, self._counts.add, self.node.warn)

    # ---------------------------------------------------------------- frames
    def take_frame(self, item: QueuedFrame, camera: Any = None) -> TakenFrame:
        """The worker: one camera frame through the one frame step, the camera alone's and a
        rig camera's alike: its camera model (a rig camera's looked up before the worker's
        lock, :meth:`camera_of`; the camera alone's after its stamp is noted on its clock,
        :meth:`_camera_at`), the entry checks and the frame into the localizer
        (:meth:`.camera_input.CameraInput.enter`: a header stamp or an output stamp out of
        range, ``bad_stamp``; an image without a front end, ``no_frontend``; the camera
        alone's frame without camera_info, ``no_camera_info``: the localizer never sees
        them), then what it gave noted (:meth:`_entered`). A frame dropped is counted
        ``failed.<reason>`` and its line logged when it is published (:meth:`outcomes`); the
        camera alone's frame is otherwise counted ``solved``, a rig camera's frame's fate is
        the rig's. An exception (a defect) is raised to the worker, which counts the frame
        ``failed.internal_error`` and logs ``frame failed (internal_error): <type>: <text>``,
        as ``replay`` does (:meth:`.core.NodeCore._process`). In the worker's frame with its
        count, so that a diagnostics snapshot sees the localizer's and the camera's counts of it
        at once; with ``republish_correspondences`` what the camera's front end found in an
        image."""
        name, kind, stamp = item.name, item.kind, item.stamp
        inp = self.node.inputs[name]
        res = CameraFrameResult(inp.tag_of(item.msg))
        tic = time.perf_counter()
        try:
            if not isinstance(stamp, DroppedFrame):
                res.stamp_ns = stamp
            if self.alone:  # (its stamp on its clock before its camera_info, camera_of)
                camera = self._camera_at(inp, stamp)
            elif kind == "image":
                self._warn_no_info(name, "images")
            res.camera = camera
            frontend = self.node.frontend_kind != "none"
            taken = inp.enter(self.rig, item.msg, kind, stamp, camera, frontend, res.noted)
            if isinstance(taken, DroppedFrame):  # (the localizer never sees it)
                raise Drop(taken.reason, str(taken.error))
            self._entered(name, kind, taken, tic, res)
        except Drop as e:
            res.failure, res.detail = e.reason, str(e)
        found = [] if res.correspondences is None else [(name, res.correspondences, res.stamp_ns)]
        counted = res.counted if res.failure is None else (f"failed.{res.failure}",)
        return TakenFrame(counted, res.failure, res, res.outs, found)

    def _camera_at(self, inp: CameraInput, stamp: Any) -> Any:
        """The camera alone's frame's camera model: its checked ``stamp`` noted on its rig of
        one's clock first (a time reset counted and logged, the camera_infos stamped after it
        forgotten), then the model of that stamp (a :class:`.camera_input.DroppedFrame`
        without one: ``no_camera_info``)."""
        if not isinstance(stamp, DroppedFrame):
            inp.note_time(stamp, self.rig.check_time)
        return inp.camera_of(stamp)

    def _entered(self, name: str, kind: str, taken: FrameStep, tic: float,
                 res: CameraFrameResult) -> None:  # fmt: skip
        """A camera frame's step into the localizer from ``tic`` (:func:`time.perf_counter`
        s), ``taken``, noted in ``res``: the rig frames it completed (``res.outs``), an
        image's decoded image (``res.image``) and, with ``republish_correspondences``, what
        the front end found in it. The camera alone's frame is then counted as its camera's
        (:meth:`_as_camera`; a :class:`~.pipeline.Drop` for a frame dropped). A rig camera's
        (docs/rig_node.md): a frame its input stage refused goes to the rig as skipped and is
        logged (:meth:`_not_taken`); a cloud before any camera_info warned about; an image
        kept for ``debug_image`` while someone watches; its times per stage to the
        diagnostics as the camera alone's
        (:meth:`.camera_input.CameraCounts.frame_stage_times`: the gyro wait as decoding)."""
        frame, outs, taken_at = taken
        res.outs = outs
        search = None
        if isinstance(frame, ImageFrame):
            res.image = (frame.image, frame.encoding, frame.stamp_ns)
            search = self.rig.last_search(name)
        if self.alone:  # (its frame is its rig frame: solved or dropped, counted as a camera's)
            self._as_camera(frame, search, taken_at, tic, res)
            return
        front = 0.0 if search is None else search.seconds
        if search is not None:
            self._counts.stage_time("frontend", front)
        self._counts.frame_stage_times(tic, taken_at, time.perf_counter(), front,
                                       sum(o.gyro_seconds for o in outs),
                                       any(o.success for o in outs))  # fmt: skip
        for out in outs:  # (the map-fit check over the rig frames: every camera's rows)
            if out.estimate is not None:
                self._map_fit.check(out.num_points, out.estimate, self._counts, self.node.warn)
        if isinstance(frame, DroppedFrame):
            self._not_taken(kind, frame)
        elif kind != "image":
            self._warn_no_info(name, "keypoints" if kind == "keypoints" else "correspondences")
        viz = self.node.camera_viz.get(name)
        if res.image is not None and viz is not None and viz.wants("debug_image"):
            # (only while someone watches; drawn when the rig frame is published)
            self._images.setdefault(name, deque(maxlen=4)).append(res.image)
        if kind == "image" and self.node.republish:
            res.correspondences = self.rig.last_correspondences(name)

    def _as_camera(self, frame: Any, search: Any, taken_at: float, tic: float,
                   res: CameraFrameResult) -> None:  # fmt: skip
        """The camera alone's frame counted as its camera's: a frame its input stage refused,
        its front end's run (:meth:`_frontend_ran`), its rig frame's counts as ``replay``
        counts a camera's frame (:meth:`~rs_localizer.tracking.video.LocalizerOutput.
        camera_counts`: ``frames_compiled`` or ``frames_uncompiled``, ``points_dropped``,
        ``frames_few_points``, ``frames_single_tag``), its estimate (:meth:`_solved_alone`)
        and its times per stage
        (:meth:`.camera_input.CameraCounts.frame_stage_times`: the wait for the gyro samples
        counts as decoding, as for camera_info). Raises :class:`~.pipeline.Drop` for a frame
        dropped, with its reason."""
        if isinstance(frame, DroppedFrame):
            raise Drop(frame.reason, str(frame.error))
        front = 0.0  # (s: the front end's search)
        if search is not None:
            self._frontend_ran(search, res)
            res.points2d, res.points3d, front = search.points2d, search.points3d, search.seconds
        else:
            res.points2d, res.points3d = frame.points2d, frame.points3d
        (out,) = res.outs
        for key, n in out.camera_counts():  # (as replay counts a camera's frame)
            self._own.add(key, n)
        t_estimated = time.perf_counter()
        res.fused = self._fused(out.fused)
        self._solved_alone(out, res)
        self._own.frame_stage_times(tic, taken_at, t_estimated, front, out.gyro_seconds)

    def _frontend_ran(self, search: Any, res: CameraFrameResult) -> None:
        """The front end's run on the camera alone's image (its rig of one's last search)
        counted (``frontend_runs``, ``frontend_points``, its time), what it found kept to
        republish; raises :class:`~.pipeline.Drop` for an image it dropped:
        ``frozen_image``, ``frontend_error``, ``frontend_too_few_points``."""
        cfg, label = self.cfg, self.rig.camera_frontend("").label
        if search.failure == "frozen_image":
            raise Drop(search.failure, (
                f"the image is the previous one again (mean difference {search.difference:.2f} "
                "gray levels over one pixel in 64): a driver re-sending its last frame or a "
                "stalled camera; the next new image is searched whole"))  # fmt: skip
        if search.failure == "frontend_error":
            e = search.error
            raise Drop(search.failure, f"{label}: {type(e).__name__}: {e}")
        found = search.found
        uv = found.points2d
        self._own.frontend_ran(len(uv), search.seconds)
        if cfg.republish_correspondences:
            res.correspondences = Correspondences(uv, found.points, found.ids,
                                                  found.valid_scores())  # fmt: skip
        if not res.outs:
            n = len(uv)
            what = f"{n // 4} markers" if label == "aruco" else f"{n} matches"
            text = f"{label} front end found {what}: {n} correspondences, {search.need} needed"
            raise Drop(search.failure, text)

    def _solved_alone(self, out: LocalizerOutput, res: CameraFrameResult) -> None:
        """The camera alone's estimate of its rig of one's rig frame ``out`` counted as its
        node counts it: the map-fit check (``frames_failed_with_matches``,
        ``map_fit_doubtful``), refused: :class:`~.pipeline.Drop` with its reason; posed, its
        inliers and planarity, and the frame counted ``solved`` (``res.counted``)."""
        est, n = out.camera_estimate, len(res.points2d)
        if est is None:
            raise Drop("estimator_error", out.error or "no estimate")
        self._map_fit.check(n, est, self._own, self.node.warn)
        if not est.success:
            text = f"{n} points, {est.num_inliers} inliers, solver {self.cfg.solver}"
            raise Drop(est.failure or "estimator_error", text)
        self._own.solved(est.num_inliers, est.planar, est.condition_number)
        res.counted = ("solved",)

    def _not_taken(self, kind: str, item: DroppedFrame) -> None:
        """A rig camera's frame of a checked stamp its input stage dropped (the rig counts it
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

    def _warn_no_info(self, name: str, kind: str) -> None:
        if self.node.inputs[name].newest is None:
            self.node.warn(
                f"no_info.{name}",
                f"rig camera {name!r}: {kind} but no camera_info yet on "
                f"{self.node.resolve_topic_name(f'{name}/camera_info')}: its frames wait (counted "
                f"{name}.skipped.no_camera_info), the rig runs on the others",
            )

    # ---------------------------------------------------------------- outputs
    def publish_taken(self, item: QueuedFrame, taken: TakenFrame) -> None:
        """The worker, after the frame is counted: what it gave published
        (:func:`.outputs.publish_frame` of each of :meth:`outcomes`), a posed one's delay
        since the frame arrived recorded, the time it took in the stage times. A frame step
        that raised (no result) publishes nothing: its frame was counted and logged
        ``internal_error`` when it raised."""
        if taken.result is None:
            return
        tic = time.perf_counter()
        res, posed = taken.result, False
        for outcome in self.outcomes(item.name, res):
            publish_frame(self.node, outcome)
            if outcome.posed is not None:
                posed = True
                # (a camera's stamp age is its header stamp's; a rig frame has several)
                stamp = res.stamp_ns if self.alone else outcome.posed.stamp_ns
                self.node.record_timing(item.arrived, stamp)
        if posed:
            self._counts.stage_time("publish", time.perf_counter() - tic)

    def outcomes(self, name: str, res: CameraFrameResult) -> list[FrameOutcome]:
        """What camera ``name``'s frame of the frame step (``res``) publishes
        (:class:`.outputs.FrameOutcome` s): dropped, the fused twists it made final and the
        line ``frame dropped (<reason>): <detail>`` (after the camera's label: a rig's
        ``rig camera '<c>':``, keyed ``<reason>.<c>``) with the count of frames failed so far
        for that reason; else each rig frame it completed (:meth:`_outcome`)."""
        if res.failure is not None:
            key = f"{res.failure}.{name}" if name else res.failure
            failed = self.node.camera_counts[name].get(f"failed.{res.failure}")
            text = f"{self.node.inputs[name].label}frame dropped ({res.failure}): {res.detail}"
            return [FrameOutcome(None, res.fused, (LogLine(key, text, failed),))]
        return [self._outcome(out, res, rig_frame_line(out, self.rig)) for out in res.outs]

    def _outcome(self, out: LocalizerOutput, res: CameraFrameResult | None = None,
                 line: LogLine | None = None) -> FrameOutcome:  # fmt: skip
        """What a rig frame publishes (:func:`.outputs.frame_outcome`, the one of the node
        and ``replay``): the fused twists it made final, its log ``line`` (a camera frame's
        rig frames: :func:`.outputs.rig_frame_line`, none for the camera alone, whose frame
        that cannot be posed is dropped in the frame step; none for the rig frames closed at
        the end of the video) and, posed, its pose at the rig frame's time (the camera
        alone's: its reference line's) with its own twist when that is final, in the fused
        twists' frame (:attr:`_fused_in`: a rig's ``base_frame``; the camera alone's optical
        frame, or with ``camera_to_base.*`` the robot's ``base_frame``), with its cameras'
        views (:meth:`_views`; ``res``: the camera frame that completed it, None: a rig frame
        closed at the end of the video)."""
        views = self._views(out, res) if out.success else ()
        return frame_outcome(out, *self._fused_in, views, () if line is None else (line,))

    def _views(self, out: LocalizerOutput, res: CameraFrameResult | None) -> tuple:
        """The cameras of a posed rig frame as their debug views draw them
        (:class:`.outputs.CameraView` s). The camera alone's is its frame as the frame step
        gave it (its rows, camera model, stamps, decoded image), always handed (its ``path``
        is drawn from its camera's pose); a rig's (a rig frame groups several cameras'
        frames) only those watched (its ``debug_image`` or ``markers``), each as the rig's pose
        and its mounting put it with the image kept for it by :meth:`_entered`
        (:func:`.outputs.rig_frame_views`)."""
        if self.alone and res is not None:  # (a rig frame's views are drawn from kept images)
            return (CameraView("", out.camera_estimate, res.points2d, res.points3d, res.camera,
                               res.stamp_ns, res.out_stamp_ns, res.frame_id,
                               res.image),)  # fmt: skip
        if self.node.viz is None:
            return ()
        viz = self.node.camera_viz

        def wanted(n: str) -> bool:
            v = viz.get(n)
            return v is not None and (v.wants("debug_image") or v.wants("markers"))

        mounts = {c.name: c.mount for c in self.cfg.cameras}
        return rig_frame_views(out, mounts, wanted, self._images)

    def _fused(self, fused: list) -> list[FusedOutput]:
        """twist / odom of the rig frames whose fused state is final
        (:func:`.pipeline.fused_outputs`): a rig's in ``base_frame``; the camera alone's in
        its frame (each frame's tag), or with its mounting the robot's ``base_frame``."""
        return fused_outputs(fused, *self._fused_in)

    def idle_twists(self) -> list[FusedOutput]:
        """:meth:`.core.NodeCore._flush_idle_track` (between two frames of the worker): the twists
        still pending after ``tracking.max_gap`` s without camera frames
        (:meth:`Localizer.flush_idle`; none unconfigured)."""
        return [] if self.rig is None else self._fused(self.rig.flush_idle())

    def close_track(self) -> list[FrameOutcome]:
        """:meth:`.core.NodeCore._end_video` (after the frame inputs' end, the frames still
        queued dropped): the rig frames still open (none for the camera alone: each frame is
        solved at once), solved, then the twists still pending (:meth:`Localizer.flush`, the
        fused twists' plausibility check as every one's), published, as ``replay`` does at a
        bag's end; then the track ends (a reactivated node starts a new one): a rig's video
        forgotten (:meth:`Localizer.reset`), the camera alone's track ended with its clock and
        gyro samples kept (:meth:`Localizer.end_track`). None unconfigured."""
        if self.rig is None:
            return []
        closed = [self._outcome(out) for out in self.rig.close()]
        fused = self.rig.flush()
        if self.alone:  # (its clock and gyro kept: a stamp going back after it is a time reset)
            self.rig.end_track()
        else:
            fused += self.rig.reset()
        return [*closed, FrameOutcome(fused=self._fused(fused))]

    # ---------------------------------------------------------------- diagnostics
    def diagnostics(self) -> tuple[str, StatusParts]:
        """The hardware id (the camera alone's ``camera_frame``, or ``camera``; a rig's
        ``base_frame``) and the status's parts of the one builder
        (:func:`.diagnostics.localizer_status_parts` of the localizer): the camera alone's of
        its counts (:class:`.diagnostics.CameraAlone`), a rig's of the node's counts and times
        per camera. Called between two frames of the worker (one consistent count:
        :meth:`.core.NodeCore.publish_diagnostics`)."""
        cfg, rig = self.cfg, self.rig
        if self.alone:  # (its counts as a camera's, its frames its rig frames: one section "")
            stats, fe = self._own.snapshot(), self._loaded[""].frontend
            frontend = None if fe is None else frontend_values(cfg.camera.frontend_kind, fe, stats)
            alone = CameraAlone(cfg.solver, self.node.inputs[""].source(), cfg.queue_size, stats,
                                self._own.messages_lost, frontend)  # fmt: skip
            return cfg.camera.frame or "camera", localizer_status_parts(rig, alone)
        waiting = {n for n, i in self.node.inputs.items() if i.newest is None}
        first = self.node.first_frame
        waited = first is not None and time.monotonic() - first > cfg.settings.stop_after
        counts = Counter(self._counts.counts())
        for cc in self.node.camera_counts.values():
            counts.update(cc.prefixed())
        frame_times = {n: cc.frame_times() for n, cc in self.node.camera_counts.items()}
        absent = [n for n in self.node.inputs if waited and counts[f"{n}.received"] == 0]
        imu = {k[len("imu_rejected.") :]: v for k, v in counts.items()
               if k.startswith("imu_rejected.")}  # fmt: skip
        inputs = RigInputs(counts, frame_times, imu, absent, self.node.frontend_kind != "none",
                           self._counts.stage_times())  # fmt: skip
        return cfg.base_frame, localizer_status_parts(rig, None, waiting, inputs)
