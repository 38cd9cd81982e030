"""The one localizer of a video of one camera or of a rig of cameras (:class:`Localizer`): a
camera alone is a rig of one. Its frames are camera frames
(:class:`~rs_localizer.tracking.localizer.CameraFrame`, each naming its camera); for each it
returns what became of it (:class:`LocalizerOutput`) and the earlier frames whose fused twist is
final now.

Each camera of the rig sends its own frames (2D-3D correspondences, its own stamp, its own
camera model; the cameras need not be synchronized). :class:`Localizer`:

1. **groups** the frames of a rig of several cameras into *rig frames* by the capture time of
   each frame's reference line (:class:`~rs_localizer.tracking.rig.RigGrouping`: at most one
   frame per camera, all within :attr:`LocalizerSettings.window` of its earliest; a rig frame
   is solved once every camera is in it, has moved past it or has stopped);
2. **estimates** the rig's pose at the rig frame's time (its earliest reference time) with
   :func:`~rs_localizer.estimation.rig.estimate_rig_pose` (each camera with its mounting and
   its own stamp offset);
3. **tracks** on the camera tracker's path (:class:`~rs_localizer.tracking.tracker.
   TrackerPath`, the rig's views its estimator as a camera's view is its camera's:
   :class:`~rs_localizer.tracking.tracker.FrameViews`):
   the twist filter's prediction at the rig frame's time is the rig estimator's initial model
   (:class:`~rs_localizer.estimation.InitialModel`, the points within ``gate_px``, or
   ``gate_sigmas`` of the predicted rotation, up to ``max_gate_px``, explained by it): when
   it explains enough points it seeds RANSAC, pre-rotates its samples and is verified with
   at most ``tracked_max_iterations`` samples (``tracked``); otherwise the rig frame is
   solved as without it (``relocalized``; again from scratch if that failed); a stamp going
   back or a gap longer than ``max_gap`` starts the track again (``reset``).
4. **fuses** the rig's twist with the camera tracker's filter
   (:class:`~rs_localizer.tracking.fusion.TwistFilter`, fixed lag), the rig frame being the
   filter's "camera": orientation rig -> world, position the rig origin, velocities in the
   rig frame. The filter's measurement is the rig estimator's: its covariance and its
   sensitivity to acceleration during the rig frame
   (:attr:`~rs_localizer.estimation.result.RSPoseEstimate.covariance`,
   :attr:`~rs_localizer.estimation.result.RSPoseEstimate.acceleration_sensitivity`), as a
   camera's estimate is for the camera tracker.

A posed frame's pose is out at once, its twist is final only when the fixed-lag smoother
releases its state (:class:`~rs_localizer.tracking.localizer.PendingTwists`):
:meth:`Localizer.flush` (the end of a video), :meth:`Localizer.flush_idle` (no frame for
``tracking.max_gap`` s, wall clock), :meth:`Localizer.end_track` (the twists still pending
dropped) hand them out as :class:`~rs_localizer.tracking.localizer.FusedPose`. A camera's
image front end searches with the prediction of its frame (:meth:`Localizer.predict_camera`):
the track's prediction of the body at the frame's reference time while the track has a state,
else (no tracking, a new track) the last posed frame carried at its own twist
(:class:`~rs_localizer.tracking.tracker.CarriedPrediction`), either seen by the camera through
its mounting. The video also checks the cameras' rolling-shutter timing
(:meth:`Localizer.readout_values`, :data:`~rs_localizer.tracking.localizer.READOUT_CHECK_SHARE`
of the last :data:`~rs_localizer.tracking.localizer.READOUT_CHECK_FRAMES` frames relocalized
or their twist refused: a suspect timing, logged once).

A camera alone is a rig of one: one camera at the identity mounting without a covariance
(:attr:`LocalizerSettings.single_camera`: the camera's frame is the rig's). The camera's
:class:`~rs_localizer.tracking.sequence.SequenceLocalizer` is its adapter, and its frames are
solved by this same class with the camera's policies. Each frame is solved at once on the
camera's tracker (:class:`~rs_localizer.tracking.tracker.RSTracker` with the settings'
:attr:`~LocalizerSettings.solver`, ``options`` and ``tracking``: cold frames with ``options``,
tracked ones with the tracked options and the prediction's twist as the motion prior where
``tracking.prior_from_prediction`` asks for it, a prediction that does not hold solved cold;
made again, the old track's twists out, when the solver, the options, the tracking options or
the camera model object change), or alone without tracking
(:func:`~rs_localizer.estimation.estimate_rs_pose` with the frame's scores), with the gyro's
measurement over the camera's readout from its stamp; each estimate is in the rig's terms
(:attr:`LocalizerOutput.estimate`: the model's velocities per second, one view), the camera's
own kept (:attr:`LocalizerOutput.camera_estimate`). Its time policy is the camera's: every
frame is taken (no ``out_of_order`` nor ``late``), a stamp going back or jumping ahead is a
time reset of the gyro's timeline only (:meth:`Localizer.check_time`; the track resets itself
on such stamps). The last posed frame is carried (the prediction without tracking) for
:meth:`Localizer.add` as for :meth:`Localizer.process_image`, a frozen image starts a new
track at the next frame (:meth:`Localizer.restart_track`), and, as for any frame, its own
twist is final when its estimator measures none (a global-shutter solver's, a camera's
without readout time: :attr:`LocalizerOutput.twist_now`). Given the camera's
``options`` (``EstimateOptions()``, not the default
:data:`~rs_localizer.estimation.rig.RIG_OPTIONS`), ``tracking`` and ``imu``, its estimates,
paths and fused twists are the camera's localizer's, bit for bit. What only a rig of several
cameras runs (:mod:`rs_localizer.tracking.rig`): the grouping into rig frames, the refusals of
a rig frame posed from one camera while others run
(:data:`~rs_localizer.estimation.result.RIG_REFUSALS`), the cameras' disagreement. Its images
(:meth:`Localizer.process_image`) are taken as the camera's: an image with fewer
correspondences than its solver needs is skipped before the estimator
(``frontend_too_few_points``). Its counters are the rig's (``rig.*``, ``<camera>.*``). As its
camera's own video (its camera named ``""``, :attr:`LocalizerSettings.camera_video`: the
single camera of :class:`~rs_localizer.tracking.sequence.SequenceLocalizer`, of the node and of
a camera's bag replayed) it speaks as the camera: its warnings, estimates and fused twists' tags
are the camera's, an image skipped before the estimator is its caller's to count and report
(:meth:`Localizer.last_search`), and its images' rows are counted by the caller's ``count``.

With a gyro on the rig (:attr:`LocalizerSettings.imu`; samples fed by
:meth:`Localizer.add_imu`) each rig frame is solved with the gyro's measurement over the rig
frame's capture times (from the first line of its earliest camera to the last line of its
latest, each camera's readout from its frame's stamp, the capture time of row ``stamp_row``, as
a camera's; none for a rig frame taken at one instant: global-shutter cameras at one stamp; in
the rig frame through the IMU's mounting): ``estimate_rig_pose(..., gyro=)``, which
rejects a gyro the image contradicts. With ``imu.estimate_bias`` the gyro's bias is estimated
online from the rotation between consecutive solved rig frames
(:class:`~rs_localizer.tracking.gyro_bias.GyroBiasEstimator`, the rig frame as its
"camera"), and the IMU's mounting is checked as a camera's
(:class:`~rs_localizer.tracking.gyro_check.GyroMountCheck`,
:func:`~rs_localizer.tracking.gyro_input.update_gyro_checks`): while the rotation between
posed rig frames contradicts the gyro, rig frames are solved without it. Counted:
``rig.gyro_used``, ``rig.gyro_rejected[.<reason>]``, ``rig.gyro_missing[.<reason>]``
(:data:`~rs_localizer.tracking.gyro.GYRO_MISSING_REASONS`), ``rig.gyro_pairs_failed``,
``rig.gyro_inconsistent_detections``, ``rig.gyro_disabled_inconsistent``,
``rig.gyro_bias_rejected``.

Per camera it counts ``received = solved + failed + skipped + pending`` (a frame is solved or
failed with its rig frame; skipped before any rig frame: :data:`SKIP_REASONS`; pending: in a
rig frame not solved yet), and per rig frame ``rig_frames = solved + failed + skipped +
pending``. Per solved rig frame and camera: its points, inliers and share of the rig's inliers
(:class:`CameraShare`); a camera that disagrees with the rig is named
(:attr:`LocalizerOutput.disagreeing`, :meth:`Localizer.camera_partner`), a camera whose frames
never join the others' with its apparent clock offsets (:meth:`Localizer.camera_apart`,
:meth:`Localizer.clock_offsets`): :class:`~rs_localizer.tracking.rig.CameraAgreement`.

The rig publishes only what its cameras agree on. The estimator's consensus
(:func:`~rs_localizer.estimation.rig.estimate_rig_pose`) outvotes a camera whose points
contradict the others' (the track's prediction decides, else the number of cameras, never
the number of points; a tie is refused, ``cameras_disagree``); without a track every camera
is also posed alone (``verify_cameras``). A rig frame posed from one camera's points alone
while other cameras run is refused when the track contradicts it or, without a track, when
two or more other cameras run (:func:`~rs_localizer.tracking.rig.refusal`).

Images: :meth:`Localizer.process_image` runs each camera's own front end
(:meth:`Localizer.set_frontend`) with the rig's prediction mapped into that camera
(:meth:`Localizer.predict_camera`), keeps the rows the estimator can use
(:func:`~rs_localizer.tracking.localizer.usable_correspondences`: non-finite rows dropped, then
at most :attr:`LocalizerSettings.max_points`; counted per camera), then takes the frame as
:meth:`Localizer.add` does, each row with its group (a marker front end's: the marker's id,
:attr:`~rs_localizer.correspondences.Correspondences.groups`), which the estimator's covariance
takes as a shared part of the image error of one marker's corners
(:attr:`~rs_localizer.estimation.view.View.groups`).

Example (``frames``: each camera's frames in any interleaving, e.g. by arrival)::

    rig = Localizer(LocalizerSettings({"front": Mounting.from_pose(R_base_front, p_front),
                                       "left": Mounting.from_pose(R_base_left, p_left)}))
    for f in frames:
        frame = CameraFrame(f.stamp_ns, camera[f.name], f.uv, f.xyz, camera_name=f.name)
        for out in rig.add(frame):
            if out.success:
                ...  # out.estimate.pose: the rig's pose and its own twist at out.stamp_ns
            for fused in out.fused:
                ...  # an earlier rig frame's pose with its fused twist
    for out in rig.close():  # the rig frames still open
        ...
    for fused in rig.flush():
        ...
"""

from __future__ import annotations

import math
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..camera import CameraModel, FrameTime, Stamp, checked_stamp, reference_stamp_ns
from ..correspondences import Correspondences, Frontend, VideoFrontend
from ..estimation.gyro import GyroMeasurement
from ..estimation.implementation import (
    COMPILED,
    NUMPY,
    compiled_by_default,
    default_implementation,
)
from ..estimation.options import EstimateOptions
from ..estimation.result import (
    CAMERAS_DISAGREE,
    CONTRADICTS_TRACK,
    RIG_REFUSALS,
    RSPoseEstimate,
    camera_estimate,
    camera_model_of_rig,
)
from ..estimation.rig import RIG_OPTIONS, VOTE_MIN_POINTS
from ..estimation.view import View
from ..frames import Mounting
from ..pose import RSModel
from ..solvers.registry import DEFAULT_SOLVER
from .clock import TimeReset, VideoClock
from .fusion import FusedState
from .gyro import readout_window
from .gyro_input import GyroInput, GyroReadouts, GyroSettings, SilentLog, TrackLog
from .localizer import (
    FROZEN_IMAGE_LEVEL,
    READOUT_CHECK_SHARE,
    CameraFrame,
    CameraFrontend,
    FrameOutput,
    FusedPose,
    ImageSearch,
    PendingTwists,
    readout_warning,
    search_image,
    too_few_points,
    usable_correspondences,
)
from .rig import MISSED_REASONS, CameraAgreement, OpenRigFrame, RigGrouping, alone_deg, refusal
from .tracker import (
    STATES,
    CarriedPrediction,
    FrameViews,
    PathFrame,
    RSTracker,
    TrackerOptions,
    TrackerPath,
    TrackResult,
    carried_model,
    model_from_state,
)

__all__ = [
    "MISSED_REASONS",
    "RIG_PATHS",
    "RIG_REFUSALS",
    "RIG_TRACKED_MAX_ITERATIONS",
    "SINGLE_CAMERA_SOLVER",
    "SKIP_REASONS",
    "CameraShare",
    "GroupingOnly",
    "Localizer",
    "LocalizerOutput",
    "LocalizerSettings",
]

#: why a camera's frame was dropped before any rig frame (counted ``<camera>.skipped.<reason>``)
SKIP_REASONS = {
    "no_camera_info": "the frame has no camera model (its camera_info has not arrived): the "
    "camera waits, the rig runs on the others",
    "out_of_order": "the frame's stamp is not later than the camera's previous frame's",
    "late": "the frame is older than the last rig frame solved (it came after the other "
    "cameras had moved past it)",
    "time_reset": "stamps went back by more than time_reset_ns: the rig frames waiting were "
    "dropped and the rig started again",
    "frontend_error": "an image: the camera's front end raised (Localizer.process_image)",
    "frozen_image": "an image: the camera's previous image again (a driver re-sending its last "
    "frame, a stalled camera; the single-camera localizer's frozen_image rule)",
    "frontend_too_few_points": "an image of a rig of one camera: its front end found fewer "
    "correspondences than its solver needs (the single-camera localizer's rule: dropped before "
    "the estimator)",
    "bad_image": "an image message that does not decode (the node: unsupported encoding, "
    "truncated data, a compressed payload that does not decode, an empty image)",
    "image_size_mismatch": "an image whose size is not its camera_info's (the node)",
    "bad_input": "a message with a readable stamp the caller could not read (the node: a cloud "
    "without its u, v, x, y, z fields)",
}

#: the paths a rig frame can take (the camera tracker's)
RIG_PATHS = STATES

#: RANSAC's most samples on a tracked rig frame (the prediction verified) when the tracking
#: options leave it open (``TrackerOptions.tracked_max_iterations`` None)
RIG_TRACKED_MAX_ITERATIONS = 200


#: the default minimal solver of one camera (:attr:`LocalizerSettings.solver` of a rig of one, and
#: :attr:`~rs_localizer.tracking.sequence.SequenceSettings.solver`): the registry's default
SINGLE_CAMERA_SOLVER = DEFAULT_SOLVER


@dataclass(frozen=True)
class LocalizerSettings:
    """The configuration of a :class:`Localizer`: a rig of cameras, or one camera alone (a rig
    of one, :attr:`single_camera`).

    Attributes:
        mounts: camera name -> :class:`~rs_localizer.frames.Mounting` (the camera in the rig
            frame); the order is the cameras' order in outputs. One camera alone: its name at
            the identity mounting.
        window: s; the frames of one rig frame lie within this of its earliest (reference-line
            capture times). Stamps further apart are different rig frames (``apart``).
        stop_after: s of stamp time without a frame of a camera (while others send) after
            which the rig stops waiting for it (``stopped``; also for a camera that never
            sent, counted from the rig's first frame); at least :data:`STOP_INTERVALS` of the
            camera's own frame intervals.
        stamp_row: the row (px along the readout) whose capture time is a frame's stamp.
        time_reset_ns: a time reset (:mod:`~rs_localizer.tracking.clock`, the single
            camera's policy, on each camera's stamps on the rig's clock: the stamp plus its
            :attr:`time_offsets` entry): a camera's frame older than its newest frame by more
            than this (ns; less is ``out_of_order``) starts the rig again (a bag played again:
            the open rig frames dropped), and so does a frame newer than the rig's newest by
            more than this (a gap in a bag, a clock jump: the open rig frames solved first);
            counted ``rig.time_resets``. A rig of one camera takes the camera's policy: any step
            back is a time reset, its frame solved (:meth:`Localizer.check_time`).
        options: the rig estimator's options, the single camera's
            :class:`~rs_localizer.estimation.options.EstimateOptions` (the RANSAC threshold,
            iterations, confidence, inliers and seed, the refinement and the velocity bounds;
            :func:`~rs_localizer.estimation.rig.estimate_rig_pose`; default
            :data:`~rs_localizer.estimation.rig.RIG_OPTIONS`). A rig of one camera
            (:attr:`single_camera`) runs the single-camera estimator with them, all of them:
            to get the camera's own results give it the camera's options (its default,
            ``EstimateOptions()``: the default here differs in ``ransac.min_inliers``, 8
            instead of 12).
        tracking: the camera tracker's
            :class:`~rs_localizer.tracking.tracker.TrackerOptions` (the gates, the explained
            ratio, ``max_gap``, ``tracked_max_iterations``: default
            :data:`RIG_TRACKED_MAX_ITERATIONS`, the twist filter's ``fusion``; a rig of one
            camera reads them all as the camera does, ``tracked_max_iterations`` None being
            ``options``' own); None: every rig frame alone, its own twist.
        disagree_ratio, disagree_min_points, disagree_frames, disagree_history: a camera with
            at least ``disagree_min_points`` valid points whose inlier ratio is below
            ``disagree_ratio`` times the other cameras' in ``disagree_frames`` of its last
            ``disagree_history`` rig frames *disagrees* with the rig (judged against the
            others' points when they number ``disagree_min_points`` too).
            ``disagree_min_points`` defaults to the points a camera votes with in a rig
            frame's consensus (:data:`~rs_localizer.estimation.rig.VOTE_MIN_POINTS`, 8): a
            camera the consensus can outvote is one the video can name (with a higher bar a
            camera of one or two tags, 8-11 corners, whose mounting is off is outvoted in
            every rig frame and never named; docs/rig.md).
        imu: a gyro on the rig: a :class:`~rs_localizer.tracking.gyro_input.GyroSettings`
            whose ``R_cam_imu`` is the rotation IMU -> **rig** frame (``R_rig_imu``: the rig's
            angular velocity is ``R_rig_imu (omega_imu - bias)``), ``time_offset`` s added to
            the IMU stamps to get the cameras' clock; ``wait``, ``buffer``, ``max_rate``,
            ``max_gap``, ``gyro_noise``, ``gyro_bias``, ``gyro_bias_sigma``,
            ``estimate_bias``, ``bias_random_walk`` as for one camera. None: no gyro.
        max_points: the most rows a camera's frame of :meth:`Localizer.process_image`
            gives the rig estimator, as a camera's
            :attr:`~rs_localizer.tracking.sequence.SequenceSettings.max_points`: the front
            end's rows with a NaN or inf dropped first, then the rest capped (highest scores
            first, else spread over the image;
            :func:`~rs_localizer.tracking.localizer.usable_rows`); None: no cap. Frames given
            to :meth:`Localizer.add` are taken as they are.
        time_offsets: camera -> s added to its stamps to put its frames on the rig's clock
            (default 0 for each camera): a camera whose driver stamps its frames late or
            early (at the end of its transfer, on another clock) by a known, constant amount,
            e.g. the apparent offset :meth:`Localizer.camera_apart` reports for a camera
            whose frames never join the others'. A camera's frame is then grouped, timed in
            its rig frame and gyro-aligned at :meth:`reference_ns`; its
            :class:`~rs_localizer.tracking.localizer.CameraFrame` keeps the stamp it was
            given. At most 1 s each (a clock further off is another
            clock: a time reset).
        solver: the minimal solver of a rig of one camera (:attr:`single_camera`), any of
            :mod:`rs_localizer.solvers.registry` as a camera's
            (:attr:`~rs_localizer.tracking.sequence.SequenceSettings.solver`; default
            :data:`SINGLE_CAMERA_SOLVER`); a rig of several cameras runs the rig estimator's
            own.
        check_gyro: check the gyro against the rotation between posed rig frames and solve
            without it while they disagree (as a camera's
            :attr:`~rs_localizer.tracking.sequence.SequenceSettings.check_gyro`; off only to
            show what the check prevents).
        frozen_image_level: a camera's image of :meth:`Localizer.process_image` whose
            pixel sample differs from its previous image's by at most this mean absolute
            difference (gray levels) is the same picture again, skipped as ``frozen_image``
            (as a camera's
            :attr:`~rs_localizer.tracking.sequence.SequenceSettings.frozen_image_level`).
            Negative: never.
    """

    mounts: dict
    window: float = 0.015
    stop_after: float = 0.5
    stamp_row: float = 0.0
    time_reset_ns: int = 10**9
    options: EstimateOptions = RIG_OPTIONS
    tracking: TrackerOptions | None = field(default_factory=TrackerOptions)
    disagree_ratio: float = 0.5
    disagree_min_points: int = VOTE_MIN_POINTS
    disagree_frames: int = 3
    disagree_history: int = 5
    imu: GyroSettings | None = None
    max_points: int | None = None
    time_offsets: dict = field(default_factory=dict)
    solver: str = SINGLE_CAMERA_SOLVER
    check_gyro: bool = True
    frozen_image_level: float = FROZEN_IMAGE_LEVEL

    def __post_init__(self):
        if not self.mounts:
            raise ValueError("a rig needs at least one camera")
        for name, m in self.mounts.items():
            if not isinstance(m, Mounting):
                raise ValueError(f"camera {name!r} has no mounting (a Mounting)")
        offsets = {}
        for name, dt in dict(self.time_offsets).items():
            if name not in self.mounts:
                raise ValueError(f"time_offsets: camera {name!r} is not in the rig")
            if not (isinstance(dt, (int, float)) and math.isfinite(dt) and abs(dt) <= 1.0):
                raise ValueError(f"time_offsets: {name!r} must be finite, at most 1 s, got {dt!r}")
            offsets[name] = float(dt)
        object.__setattr__(self, "time_offsets", offsets)
        if not (np.isfinite(self.window) and self.window >= 0):
            raise ValueError(f"window must be >= 0 s, got {self.window}")
        if not (np.isfinite(self.stop_after) and self.stop_after > 0):
            raise ValueError(f"stop_after must be > 0 s, got {self.stop_after}")
        if not 1 <= self.disagree_frames <= self.disagree_history:
            raise ValueError("need 1 <= disagree_frames <= disagree_history")

    @property
    def cameras(self) -> tuple:
        """The cameras' names, in order."""
        return tuple(self.mounts)

    @property
    def single_camera(self) -> bool:
        """The rig is its one camera: a rig of one camera at the identity mounting without a
        covariance (the camera's frame is the rig's). Its rig frames are solved as that
        camera's own video (:class:`~rs_localizer.tracking.sequence.SequenceLocalizer`):
        module docstring."""
        if len(self.mounts) != 1:
            return False
        (m,) = self.mounts.values()
        return bool(m.covariance is None and np.array_equal(m.R, np.eye(3)) and not np.any(m.c))

    @property
    def camera_video(self) -> bool:
        """The rig is a camera's own video: a rig of one (:attr:`single_camera`) whose camera
        is named ``""``, the name a single camera's configuration gives it
        (:func:`~rs_localizer.tracking.sequence.rig_of_one`,
        :func:`~rs_localizer.ros.config.build_config` without ``rig.cameras``). Its
        :class:`Localizer` speaks as the camera (:class:`Localizer`, ``camera_video``); a rig
        of one camera of another name speaks as a rig."""
        return self.cameras == ("",) and self.single_camera

    def reference_ns(self, name: str, stamp_ns: int, camera: CameraModel | None) -> int:
        """ns, camera ``name``'s frame stamped ``stamp_ns`` on the rig's clock: the capture
        time of its reference line (:func:`~rs_localizer.camera.reference_stamp_ns` from the
        row ``stamp_row``; without a ``camera`` model, the stamp) plus its
        :attr:`time_offsets` entry."""
        return reference_stamp_ns(
            stamp_ns, camera, self.stamp_row, self.time_offsets.get(name, 0.0)
        )

    @property
    def back_tolerance_ns(self) -> int:
        """ns a camera's stamp may go back from its previous frame's without a time reset (the
        frame ``out_of_order``, skipped): ``time_reset_ns`` for a rig of several cameras, whose
        grouping skips a camera's late frame while the others go on; 0 for a rig of one
        (:attr:`single_camera`), which takes every frame as its camera's video does, so that
        any step back is a time reset (:mod:`~rs_localizer.tracking.clock`)."""
        return 0 if self.single_camera else self.time_reset_ns

    @property
    def max_gap(self) -> float:
        """s: the rig's one gap policy, ``tracking.max_gap`` (the
        :class:`~rs_localizer.tracking.tracker.TrackerOptions` default, 0.5 s, without
        tracking), as a camera's
        :attr:`~rs_localizer.tracking.sequence.SequenceSettings.max_gap`: rig frames further
        apart share nothing across the gap (the track resets, the gyro's mount check and bias
        estimator form no pair)."""
        t = self.tracking
        return float(t.max_gap if t is not None else TrackerOptions.max_gap)


@dataclass(frozen=True)
class CameraShare:
    """One camera in a solved rig frame: its ``points``, ``inliers`` (reprojection error of the
    rig's pose within ``threshold_px``), ``share`` of the rig's inliers (0-1) and inlier
    ``ratio`` (inliers / points; NaN without points); ``outvoted``: the estimator's consensus
    left its points out (:attr:`LocalizerOutput.outvoted`)."""

    points: int
    inliers: int
    share: float
    ratio: float
    outvoted: bool = False


@dataclass
class LocalizerOutput(FrameOutput):
    """What became of a frame of :class:`Localizer`: a rig frame, a camera's frame alone (a rig
    of one). A :class:`~rs_localizer.tracking.localizer.FrameOutput` (``stamp_ns``, the frame's
    time: a rig frame's earliest reference-line capture time, the time of the pose;
    ``estimate``, the estimator's result: when ``success``, the rig's pose and own twist at
    ``stamp_ns`` (``estimate.pose``, rig frame) with their covariances, what the twist filter
    fuses; ``path``, :data:`RIG_PATHS`; ``fused``,
    :class:`~rs_localizer.tracking.localizer.FusedPose` in the rig frame; ``gyro``, the frame's
    measurement in the rig frame (None also when its samples are missing:
    ``rig.gyro_missing``); ``error``, ``compiled``, ``success``) with the cameras' fields.

    Attributes:
        cameras: the cameras in it (rig order); missing: camera -> a key of
            :data:`~rs_localizer.tracking.rig.MISSED_REASONS` for the others.
        stamp_offsets: camera -> s, its frame's reference time after ``stamp_ns``.
        shares: camera -> :class:`CameraShare` (solved frames).
        disagreeing: cameras that disagree with the rig now
            (:class:`~rs_localizer.tracking.rig.CameraAgreement`).
        tags: camera -> its frame's tag.
        frames: camera -> its :class:`~rs_localizer.tracking.localizer.CameraFrame` (the rows
            given to the estimator: the rig's inliers per camera index them; e.g. a camera's
            debug image).
        twist_now: the frame's own twist is its final twist, none comes in a later
            ``fused``: no tracking, or its estimator measures no twist
            (:attr:`~rs_localizer.tracking.tracker.FrameViews.measures_twist`: a rig of one
            camera whose solver is a global-shutter one or whose camera has no readout time,
            as a camera's :attr:`~rs_localizer.tracking.sequence.SequenceOutput.twist_now`).
        gyro_seconds: s spent getting the gyro measurement (waiting for samples included).
        camera_estimate: a rig of one camera (:attr:`LocalizerSettings.single_camera`): its
            camera's own estimate (:func:`~rs_localizer.estimation.estimate_rs_pose`'s, the
            model's velocities per unit RS coordinate), the one ``estimate`` is made from (a
            camera's video, :attr:`LocalizerSettings.camera_video`: ``estimate`` itself);
            None for a rig of several cameras or when the estimator did not run.
    """

    cameras: tuple = ()
    missing: dict = field(default_factory=dict)
    stamp_offsets: dict = field(default_factory=dict)
    shares: dict = field(default_factory=dict)
    disagreeing: tuple = ()
    tags: dict = field(default_factory=dict)
    frames: dict = field(default_factory=dict)
    twist_now: bool = True
    gyro_seconds: float = 0.0
    camera_estimate: RSPoseEstimate | None = None

    @property
    def num_points(self) -> int:
        """The rows given to the estimator, every camera's (:attr:`frames`) together."""
        return sum(len(f.points2d) for f in self.frames.values())

    @property
    def outvoted(self) -> tuple:
        """The cameras of :attr:`cameras` the estimator's consensus left out
        (:attr:`~rs_localizer.estimation.result.RSPoseEstimate.disagreeing`): on a posed rig
        frame those outvoted by the cameras that posed it, on ``cameras_disagree`` every
        camera of the groups that contradict each other; () otherwise."""
        est = self.estimate
        if est is None:
            return ()
        return tuple(self.cameras[k] for k in est.disagreeing if k < len(self.cameras))

    def camera_counts(self) -> list[tuple[str, int]]:
        """A rig of one camera's frame counted as its camera's node counts it (the node's
        diagnostics' names, in the order it counts them): ``frames_compiled`` or
        ``frames_uncompiled`` (:attr:`compiled`); with :attr:`camera_estimate`, the rows its
        estimator left out (``points_dropped``, also 0) and a pose from few points
        (``frames_few_points``) or from one tag (``frames_single_tag``). Returns ``(key, n)``
        pairs to add to the camera's counts."""
        out = [("frames_compiled" if self.compiled else "frames_uncompiled", 1)]
        est = self.camera_estimate
        if est is not None:
            out.append(("points_dropped", int(est.num_dropped)))
            if est.success and est.few_points:
                out.append(("frames_few_points", 1))
            if est.success and est.single_tag:
                out.append(("frames_single_tag", 1))
        return out


# ---------------------------------------------------------------------- bookkeeping
def _same_mount(a: Mounting, b: Mounting) -> bool:
    """Whether two mountings are the same (rotation, position, covariance and time offset
    std)."""
    if a is b:
        return True
    cov = (a.covariance is None) == (b.covariance is None) and (
        a.covariance is None or np.array_equal(a.covariance, b.covariance)
    )
    cov = cov and a.time_offset_std == b.time_offset_std
    return bool(cov and np.array_equal(a.R, b.R) and np.array_equal(a.c, b.c))


class _Camera:
    """One camera of the localizer: its name, its mounting, its share of the last solved frame
    it was in (what the prediction hooks take to name it)."""

    def __init__(self, name: str, mount: Mounting):
        self.name, self.mount = name, mount
        self.last_share: CameraShare | None = None


class _ImageInput:
    """The image input's state (:meth:`Localizer.process_image`): per camera its front end
    (:class:`~rs_localizer.tracking.localizer.CameraFrontend`: the front end, its label, its
    last image's fingerprint), per camera what its front end found in its last image (None:
    not searched) and its last search (:meth:`Localizer.last_search`)."""

    def __init__(self):
        self.frontends: dict[str, CameraFrontend] = {}
        self.found: dict[str, Correspondences | None] = {}
        self.searched: dict[str, ImageSearch | None] = {}


class _ImageFrame(CameraFrame):
    """A camera frame made from an image (:meth:`Localizer.process_image`): its camera's front
    end is told how its rig frame was solved (a frame given to :meth:`Localizer.add`, e.g. a
    cloud beside the front end, is not the front end's)."""


class Localizer(GyroReadouts):
    """The localizer of a video of one camera or of a rig of cameras (module docstring).

    Args:
        settings: :class:`LocalizerSettings`.
        log: the :class:`~rs_localizer.tracking.gyro_input.TrackLog` (None: silent) of a
            camera stopped or back, a camera that disagrees with the rig.
        implementation: ``implementation()`` names the rig estimator's implementation a rig
            frame runs on, ``"compiled"`` or ``"numpy"``
            (:func:`~rs_localizer.estimation.rig.estimate_rig_pose`'s ``implementation``),
            asked once per frame; None: the estimator's default (a camera alone's solver's,
            :func:`~rs_localizer.estimation.implementation.default_implementation`; the rig
            estimator's: compiled unless this process cannot compile). A node whose kernels
            compile in the background passes
            :func:`rs_localizer.runtime.background.ready_implementation`: until the kernels
            are ready the rig frames are solved on ``"numpy"`` (the refinement and covariance
            in NumPy/SciPy) with the track, the gyro and the twist filter as on the compiled
            kernels, a track under way going on across the switch (:attr:`LocalizerOutput.compiled`,
            counted ``rig.uncompiled``).
        gyro_input: the gyro's :class:`~rs_localizer.tracking.gyro_input.GyroInput` (its
            samples, bias, mount check, warnings and counters under the caller's names); None:
            the rig's own, counted ``rig.gyro_*``.
        count: the counter of its images' rows (``count(key, n)``: ``points_dropped``,
            ``capped_clouds``, ``capped_points``, under the caller's names; its capping warned
            as ``capped``), a camera video's or a rig of one's counted as its camera's; None:
            counted ``<camera>.points_dropped`` etc.

    A rig of one camera named ``""`` at the identity mounting
    (:attr:`LocalizerSettings.camera_video`) is that camera's own video. As its camera's video
    it speaks as the camera: its warnings are worded for a camera (the rolling-shutter timing's
    advice names the camera's ``rs.*`` parameters; a time reset, an image the front end failed
    on or found the previous one again are the caller's to report: :meth:`check_time`,
    :meth:`last_search`), its fused twists carry their frame's own tag rather than a camera ->
    tag dict, and its outputs' ``estimate`` is the camera's own
    (:attr:`LocalizerOutput.camera_estimate`: the model's velocities per unit RS coordinate, not
    per second; its ``pose`` and covariances are the rig's). Its images (:meth:`process_image`)
    are its camera's: an image the front end failed on, found the previous one again or found
    too few correspondences in is not the rig's to count (no frame received nor skipped, the
    idle timer not reset, no warning): the caller reads the failure from :meth:`last_search` and
    reports it.

    One camera and a rig share one clock and time-reset policy (a jump ahead counted
    ``<camera>.stamp_jumped_ahead``, every camera's last image forgotten), one gyro input and
    one gyro window (each camera's readout from its frame's stamp), one twist queue, one
    front-end driver per camera (:meth:`search_image`) and one way to solve a frame: the
    estimator's implementation (``implementation()``, else the estimator's default), the
    frame's estimator on the tracker path
    (:meth:`~rs_localizer.tracking.tracker.TrackerPath.track`: the same gate, update and
    restart after :meth:`restart_track`), the last posed frame carried (the prediction without
    tracking, for :meth:`add` as for :meth:`process_image`). A rig of one
    (:attr:`LocalizerSettings.single_camera`) differs only where a camera alone differs from
    a rig: no other camera to wait for (each frame its rig frame, complete at once; any step
    back a time reset: :attr:`LocalizerSettings.back_tolerance_ns`); its estimator is the
    camera's own, so its tracker is its camera's (:class:`~rs_localizer.tracking.tracker.
    RSTracker`, made per solver, options, tracking and camera model; it resets itself on a
    time reset, predicts in the camera's terms and is dropped when its track ends) and its own
    twist is final when its solver or camera measures none (:attr:`LocalizerOutput.twist_now`,
    as any frame's whose estimator measures none); and no other camera
    sees what it misses (a frozen image restarts its track, an image with too few
    correspondences never reaches its solver). A rig frame's pose is judged before the track
    takes it (the refusals, :data:`RIG_REFUSALS`).

    Counters (:attr:`counts`, a Counter): ``<camera>.received``, ``.solved``, ``.failed``,
    ``.skipped``, ``.skipped.<reason>`` (:data:`SKIP_REASONS`), ``.stamp_jumped_ahead`` (its
    frames that started the clock again by a jump ahead), ``.missed.<reason>``
    (:data:`MISSED_REASONS`), ``.stopped`` (times it stopped), ``.disagreements`` (times it
    was found to disagree), ``.apart`` (times its frames were found apart from the others'),
    ``.outvoted`` (posed rig frames whose consensus outvoted it, :attr:`LocalizerOutput.outvoted`),
    ``.points_dropped`` (rows of its images' correspondences with a NaN or inf),
    ``.capped_clouds`` and ``.capped_points`` (its images' frames capped to
    :attr:`LocalizerSettings.max_points`, the rows left out; :meth:`process_image`);
    ``rig_frames``, ``rig.solved``, ``rig.failed``, ``rig.failed.<reason>`` (the estimator's,
    :data:`RIG_REFUSALS`, or ``error``), ``rig.skipped``,
    ``rig.skipped.time_reset``, ``rig.time_resets`` (time resets,
    :attr:`LocalizerSettings.time_reset_ns`), ``rig.incomplete`` (solved without every camera),
    ``rig.path.<path>``, ``rig.uncompiled`` (rig frames solved on the NumPy implementation),
    ``rig.track_outvote_undone`` (tracked rig frames whose prediction outvoted a camera into a
    pose it contradicts itself, posed from the rig frame solved without it).
    Pending counts: :meth:`camera_counts`, :meth:`rig_counts`.

    Threads: :meth:`flush`, :meth:`flush_idle` and :meth:`end_track` take the localizer's lock
    (the one its frames are processed under).
    """

    def __init__(
        self,
        settings: LocalizerSettings,
        log: TrackLog | None = None,
        implementation: Callable[[], str] | None = None,
        *,
        gyro_input: GyroInput | None = None,
        count: Callable[[str, int], Any] | None = None,
    ):
        self.settings = settings
        # (a camera's own video: its warnings, its estimates, its fused twists' tags and its
        # images' failures are the camera's)
        self._rig = not settings.camera_video
        self._rows_count = count  # (a camera video's: its rows counted under its names)
        self._implementation = implementation
        self._impl: str | None = None  # (the rig frame being solved: its implementation)
        self.log: TrackLog = log if log is not None else SilentLog()
        self.counts: Counter = Counter()
        self._cams = {n: _Camera(n, m) for n, m in settings.mounts.items()}
        # the rig's grouping of its cameras' frames into rig frames, its cameras' agreement
        # (tracking/rig.py)
        self._frames = RigGrouping(settings.cameras, self.counts, self.log, self._skip,
                                   ordered=not settings.single_camera)  # fmt: skip
        self._agreement = CameraAgreement(settings.disagree_history, self._frames)
        # the frames waiting for their fused twist, their last camera frame's wall time
        # (tracking/localizer.py), the lock, the last posed frame carried
        self._twists = PendingTwists()
        self._lock = threading.RLock()
        self._carried = CarriedPrediction()
        self._readout_warned = False  # (the timing check's warning is out)
        self._gyro_time: float | None = None  # (s after its time: the last gyro window's middle)
        self._carried.max_gap = settings.max_gap  # (without tracking: the default, 0.5 s)
        self._carry: list[FusedPose] = []  # (twists of a track ended by a time reset)
        # the tracker path (tracking/tracker.py: the time rule, the prediction, the twist
        # filter), the rig's views its estimator; None without tracking. A rig of one's is its
        # camera's tracker, made at its first frame and again when what it was made for
        # changes (_track_key: solver, options, tracking, camera model)
        self._single = settings.single_camera  # (a rig of one; its mountings stay)
        self._track: TrackerPath | None = None if self._single else _new_track(settings)
        self._track_key = self._track_camera = None
        self._track_counts: Counter = Counter()  # (of the tracks ended)
        self._track_over = False  # (restart_track: the next rig frame starts a new track)
        # the gyro on the rig (its R_cam_imu: IMU -> rig frame): samples, bias, the check
        # of its mounting on the rig as a camera's, counted rig.gyro_* (or the caller's)
        if gyro_input is None:
            gyro_input = GyroInput(
                self._count_gyro, self.log, what="rig frame", key="rig.gyro",
                mount="IMU -> base_frame", used_key="gyro_used",
            )  # fmt: skip
        self.gyro_input = gyro_input
        self.gyro_input.configure(
            settings.imu, check=settings.check_gyro, max_interval=settings.max_gap
        )
        # the time-reset policy (tracking/clock.py): a camera's step back by more than
        # back_tolerance_ns (less: its frame out of order; a rig of one: any step back), a
        # jump ahead of the rig's newest
        self._clock = VideoClock(settings.time_reset_ns, settings.back_tolerance_ns)
        self._reset_solved: list = []  # (rig frames a time reset noted before its frame solved)
        self._img: _ImageInput | None = None  # (the image search, made on first use)
        # (the last time reset's number, detail and the new timeline's first time on the
        # clock, ns; each camera's number taken: took_time_reset)
        self._reset: tuple[int, str, int | None] = (0, "", None)
        self._reset_taken: dict[str, int] = {}
        self._gyro: GyroMeasurement | None = None  # (the rig frame being solved)
        self._tracked: tuple = (None, None)  # (settings, their tracked rig frames' options)

    def _count_gyro(self, key: str, n: int = 1) -> None:
        self.counts[f"rig.{key}"] += n

    def configure(self, settings: LocalizerSettings) -> None:
        """Use ``settings`` from the next rig frame on, as a camera's
        :meth:`~rs_localizer.tracking.sequence.SequenceLocalizer.configure`: the estimator's
        ``options``, ``tracking``, ``imu``, ``time_reset_ns`` and ``max_points``. The counts,
        the rig frames open and the gyro samples are kept; the gyro's bias estimate and mount
        check are kept while the gyro calibration they depend on stays the same, else started
        again; other ``tracking`` options end the track (its twists still pending go out with
        the next rig frame, :attr:`LocalizerOutput.fused`) and the next rig frame starts a new one.

        A rig of one camera (:attr:`LocalizerSettings.single_camera`) is configured as its camera's
        video: its ``solver``, ``options`` or ``tracking`` changed, or a new camera model
        object, end its track at its next frame (its twists still pending go out with it,
        counted a reset); it has no rig frames open, so its ``stamp_row``, ``time_offsets``,
        ``window`` and the rest may change too.

        Raises:
            ValueError: settings of another rig: other cameras or mountings, ``window``,
                ``stop_after``, ``stamp_row``, ``time_offsets`` or disagreement rule (the rig
                frames open and each camera's history were made with them: a new
                :class:`Localizer`).
        """
        old = self.settings
        shape = ("window", "stop_after", "stamp_row", "time_offsets", "disagree_ratio",
                 "disagree_min_points", "disagree_frames", "disagree_history")  # fmt: skip
        # (a rig of one has no grouping nor disagreement: nothing open depends on them)
        changed = [] if self._single else [
            k for k in shape if getattr(settings, k) != getattr(old, k)
        ]  # fmt: skip
        if settings.cameras != old.cameras or not all(
            _same_mount(settings.mounts[n], old.mounts[n]) for n in old.cameras
        ):
            changed.insert(0, "mounts")
        if changed:
            raise ValueError(f"a configured rig keeps its {', '.join(changed)}")
        with self._lock:
            # (a rig's track path ends here; a rig of one's camera tracker is made again at its
            # next frame when its solver, options, tracking or camera model changed, a reset,
            # as the camera's: _estimator)
            if not self._single and settings.tracking != old.tracking:
                # (the old track's twists: the old bounds)
                self._carry += self._end_track(keep=True)
                if self._track is not None:
                    self._track_counts.update(self._track.track_counts())
                self._track = _new_track(settings)
            self.settings = settings
            self._carried.max_gap = settings.max_gap
            self._clock.time_reset_ns = settings.time_reset_ns
            self._clock.back_tolerance_ns = settings.back_tolerance_ns
            self.gyro_input.configure(
                settings.imu, check=settings.check_gyro, max_interval=settings.max_gap
            )

    # ---------------------------------------------------------------- read-outs
    @property
    def cameras(self) -> tuple:
        return self.settings.cameras

    def camera_counts(self, name: str) -> dict:
        """``received``, ``solved``, ``failed``, ``skipped``, ``pending`` of a camera
        (received = the other four summed)."""
        c = self.counts
        pending = sum(name in g.frames for g in self._frames.open)
        keys = ("received", "solved", "failed", "skipped")
        out = {k: c[f"{name}.{k}"] for k in keys}
        out["pending"] = pending
        return out

    def rig_counts(self) -> dict:
        """``rig_frames``, ``solved``, ``failed``, ``skipped``, ``pending`` of the rig frames
        (rig_frames = the other four summed)."""
        c = self.counts
        return {
            "rig_frames": c["rig_frames"],
            "solved": c["rig.solved"],
            "failed": c["rig.failed"],
            "skipped": c["rig.skipped"],
            "pending": len(self._frames.open),
        }

    def gyro_counts(self) -> dict[str, int]:
        """The rig's gyro counts (``rig.gyro_*``, :mod:`~rs_localizer.tracking.gyro_input`) by
        the names a camera's localizer counts them under, the rig frames for a camera's frames:
        ``frames_with_gyro`` (rig frames posed with the gyro), ``gyro_rejected[.<reason>]``,
        ``gyro_missing[.<reason>]``, ``gyro_disabled_inconsistent``, ``gyro_pairs_failed``,
        ``gyro_inconsistent_detections``, ``gyro_bias_rejected``; those never counted are left
        out."""
        out = {}
        for k, v in sorted(self.counts.items()):
            if k.startswith("rig.gyro_"):
                k = k[len("rig.") :]
                out["frames_with_gyro" if k == "gyro_used" else k] = v
        return out

    def camera_state(self, name: str) -> str:
        """``waiting`` (no frame yet), ``running``, ``stopped`` or ``disagrees`` (also the
        partner of a camera that disagrees with it alone, :meth:`camera_partner`)."""
        cam = self._frames.cams[name]
        if self._agreement.disagrees(name):
            return "disagrees"
        if cam.stopped:
            return "stopped"
        return "waiting" if cam.newest is None else "running"

    def last_share(self, name: str) -> CameraShare | None:
        """The camera's :class:`CameraShare` in the last solved rig frame it was in."""
        return self._cams[name].last_share

    @property
    def track_state(self) -> str:
        """``tracking``, ``lost`` or ``disabled``."""
        t = self._track
        if self.settings.tracking is None:
            return "disabled"
        return "lost" if t is None else t.track_state

    def tracking_values(self) -> dict:
        """The rig's tracking, as a camera's video reports it: ``track_state``
        (:attr:`track_state`), ``frames_tracked``, ``relocalizations`` and ``resets`` (over
        the rig's tracks; a rig of one counts a new track made for other settings or another
        camera model, or after :meth:`restart_track`, as a reset), ``twists_own_frame`` and
        ``twists_implausible``
        (:meth:`twist_values`),
        ``readout_contradicted`` and ``readout_suspect``
        (:meth:`readout_values`)."""
        t = self._track
        tc = self._track_counts
        return {
            "track_state": self.track_state,
            "frames_tracked": tc["frames_tracked"] + (t.frames_tracked if t else 0),
            "relocalizations": tc["relocalizations"] + (t.relocalizations if t else 0),
            "resets": tc["resets"] + (t.resets if t else 0),
            **self.twist_values(),
            **self.readout_values(),
        }

    # ---------------------------------------------------------------- prediction
    def _predict(self, ref: int, camera: CameraModel, view: _Camera) -> RSModel | None:
        """The prediction of a frame at reference time ``ref`` (ns) seen by ``camera``
        (``view``: which of the body's cameras): its model
        (:class:`~rs_localizer.pose.RSModel` ``(R, C, w, t)`` at the camera's reference row,
        ``w``, ``t`` per unit RS coordinate), what its front end searches with. The track's
        prediction while the track has a state (:meth:`_tracked_prediction`), else the last
        posed frame carried at its own twist; None when nothing predicts the frame."""
        with self._lock:
            decided, state = self._tracked_prediction(ref, camera, view)
            if decided:
                return None if state is None else self._state_in_camera(state, camera, view)
            c = self._carried.carried(ref)
            return None if c is None else self._carried_in_camera(c[0], c[1], camera, view)

    # ---------------------------------------------------------------- time, gyro
    def _time_reset(self, reset: TimeReset | None) -> list:
        """The video's clock started again (``reset`` of :attr:`_clock`; None: the video is
        forgotten): the frames' timelines (:meth:`_timeline_ended`, its outputs returned), then
        the gyro's timeline (its samples from ``reset.keep_from`` on kept; None: none)."""
        out = self._timeline_ended(reset)
        with self._lock:
            self.gyro_input.restart(None if reset is None else reset.keep_from)
        return out

    def _forget_video(self) -> list:
        """Forget the video (:meth:`reset`): :meth:`_time_reset` of None, the last
        posed frame carried, the clock's frame times; returns :meth:`_timeline_ended`'s."""
        with self._lock:
            out = self._time_reset(None)
            self._forget_last_pose()
            self._clock.reset()
        return out

    def _frame_gyro(self, t0: int, clocks: list[tuple[CameraModel, int]]) -> GyroMeasurement | None:
        """A frame's gyro measurement (:meth:`~rs_localizer.tracking.gyro_input.GyroInput.
        measurement`), a camera's or a rig frame's (``t0``: its time, ns), over its capture
        times: from the first line of its cameras' earliest readout to the last line of the
        latest, each camera's readout from its frame's stamp on the clock (``clocks``:
        ``(camera, ns)``, :meth:`_on_clock`; the stamp the capture time of row ``stamp_row``,
        :func:`~rs_localizer.tracking.gyro.readout_window`); the window's middle kept
        (``_gyro_time``, s after ``t0``). None without a gyro, or for a frame taken at one
        instant (every camera without readout time, at one stamp: no motion within it to
        measure, as a global-shutter camera's frame)."""
        if self.gyro_input.settings is None:
            return None
        if all(c.line_delay <= 0 for c, _ in clocks) and len({t for _, t in clocks}) == 1:
            return None
        row = self.settings.stamp_row
        first, last = [], []
        for camera, t in clocks:
            a, b = readout_window(camera, 0.0, row)
            first.append(t + int(round(a * 1e9)))
            last.append(t + int(round(b * 1e9)))
        lo, hi = min(first), max(last)
        self._gyro_time = 0.5 * ((lo - t0) + (hi - t0)) * 1e-9
        return self.gyro_input.measurement((lo, hi))

    # ---------------------------------------------------------------- pending twists
    @property
    def pending(self) -> int:
        """Frames whose fused twist is not final yet."""
        return len(self._twists)

    def twist_values(self) -> dict[str, int]:
        """The fused twists handed out over the localizer's life: ``twists_own_frame`` (frames
        whose twist is their own, :attr:`~rs_localizer.tracking.localizer.FusedPose.own_twist`:
        the filter refused the frame's measurement or its fused twist was implausible) and
        ``twists_implausible`` (frames whose fused twist was beyond the plausibility bounds,
        :attr:`~rs_localizer.tracking.localizer.FusedPose.implausible`;
        never handed out)."""
        return {
            "twists_own_frame": self._twists.own_twists,
            "twists_implausible": self._twists.implausible_twists,
        }

    def readout_values(self) -> dict[str, Any]:
        """The check of the rolling-shutter timing (module docstring): ``readout_contradicted``
        (of the last :data:`~rs_localizer.tracking.localizer.READOUT_CHECK_FRAMES` frames with
        a twist of their own, those relocalized or whose twist the fused twist refused; ``-1``
        before that many) and ``readout_suspect`` (``"true"`` when they are at least
        :data:`~rs_localizer.tracking.localizer.READOUT_CHECK_SHARE` of them, else
        ``"false"``)."""
        share = self._twists.readout_share()
        return {
            "readout_contradicted": -1 if share is None else int(sum(self._twists.recent)),
            "readout_suspect": str(share is not None and share >= READOUT_CHECK_SHARE).lower(),
        }

    def _fused(self, final: list) -> list[FusedPose]:
        """The frames whose fused state is final: their pose with the fused twist
        (:meth:`~rs_localizer.tracking.localizer.PendingTwists.release`), within the
        estimator's plausibility bounds (``settings.options.plausibility``; the default
        options' when None). When the rolling-shutter timing becomes suspect
        (:meth:`readout_values`) it is logged once (``readout.suspect``)."""
        out = self._twists.release(final, self._twist_bounds())
        share = self._twists.readout_share() if out else None
        if share is None:
            return out
        suspect = share >= READOUT_CHECK_SHARE
        if suspect and not self._readout_warned:
            self.log.warning(
                "readout.suspect", readout_warning(sum(self._twists.recent), self._rig)
            )
        self._readout_warned = suspect
        return out

    def _twist_bounds(self) -> tuple[float, float]:
        """``(max_angular_velocity, max_linear_velocity)`` (rad/s, m/s) a published twist
        must stay within: the estimator's plausibility bounds, which every estimate passed."""
        opts = self.settings.options
        pl = (opts if opts is not None else EstimateOptions()).plausibility
        return float(pl.max_angular_velocity), float(pl.max_linear_velocity)

    def _end_track(self, keep: bool = False) -> list[FusedPose]:
        """End the track: its frames still pending released with their fused twists as they
        are now when ``keep``, else dropped."""
        return self._track_ended(self._forget_track(keep))  # ([] unless keep)

    def _track_ended(self, final: list) -> list[FusedPose]:
        """A track ended (its twist source reset): its pending frames released with the fused
        states ``final`` (oldest first; :meth:`_fused`), the others dropped."""
        out = self._fused(final)
        self._twists.clear()
        return out

    def _forget_last_pose(self) -> None:
        """Forget the last posed frame carried (:class:`~rs_localizer.tracking.tracker.
        CarriedPrediction`): the next frame is not predicted from it, however soon it comes
        (:meth:`end_track` and :meth:`reset`: a new video)."""
        with self._lock:
            self._carried.reset()

    def end_track(self) -> None:
        """End the track (e.g. the node is deactivated): the twists still pending are dropped;
        the next frame starts a new track and is not predicted. The gyro state is kept."""
        with self._lock:
            self._end_track()
            self._forget_last_pose()

    def flush(self) -> list[FusedPose]:
        """The end of the video: the twists still pending, as they are now (the track goes
        on)."""
        with self._lock:
            src = self._twist_source()
            if src is None or not self._twists:
                return []
            return self._fused(src.flush())

    # ---------------------------------------------------------------- frames
    def add(self, frame: CameraFrame, reference_ns: int | None = None) -> list[LocalizerOutput]:
        """Take one camera's frame; returns the rig frames it completed, solved (oldest first;
        often none, or one). ``reference_ns``: the frame's time on the rig's clock
        (:meth:`LocalizerSettings.reference_ns`) when the caller made it; None: made here.

        A rig of one camera (:attr:`LocalizerSettings.single_camera`) takes its frames as its
        camera's video does: each is solved at once, whatever its stamp (no ``out_of_order``
        nor ``late``): a stamp older than the previous one, or newer by more than
        ``time_reset_ns``, is a time reset (:meth:`check_time`) that starts the gyro's
        timeline again, and its track resets itself on such stamps (a step back, a gap over
        ``max_gap``).

        Raises:
            ValueError: a camera not in the rig.
        """
        name = frame.camera_name
        if name not in self._cams:
            raise ValueError(f"camera {name!r} is not in the rig {list(self._cams)}")
        if frame.camera is None:  # (counted and noted as every frame, skipped)
            return self._received(name, frame.stamp_ns, None, reason="no_camera_info")
        if reference_ns is None:
            reference_ns = self.settings.reference_ns(name, frame.stamp_ns, frame.camera)
        return self._received(name, frame.stamp_ns, reference_ns, frame)

    def _solved_by_reset(self) -> list[LocalizerOutput]:
        """The rig frames a time reset solved (a jump ahead: the old timeline's open rig
        frames, :meth:`_note`) not handed out yet; they go out with the frame that made it."""
        out, self._reset_solved = self._reset_solved, []
        return out

    def _received(self, name: str, stamp: Stamp, t: int | None, frame: CameraFrame | None = None,
                  reason: str = "") -> list[LocalizerOutput]:  # fmt: skip
        """Camera ``name``'s frame stamped ``stamp`` (checked) received, the one path of
        :meth:`add`, :meth:`drop` and :meth:`process_image`: counted, its stamp noted on the
        video's clock (:meth:`_note`: a time reset starts every camera's timeline again; an
        image's search noted it already), then ``frame`` (with its camera model) taken into
        its rig frame at its reference time ``t`` (ns; a rig of one's complete at once) or,
        without ``frame``, the frame skipped for ``reason`` at ``t`` (None: a frame without a
        camera model's, ``no_camera_info``: its stamp on the rig's clock); the rig frames
        complete solved (none after a frame refused as late or out of order), those a time
        reset at it solved (:meth:`_note`) first."""
        self.counts[f"{name}.received"] += 1
        self._twists.note_frame()
        on_clock = self._on_clock(name, stamp)
        self._note(name, on_clock)
        if frame is None:
            self._frames.skipped(name, on_clock if t is None else t, reason)
        elif not self._frames.take(name, frame, t, self.settings.window):
            return self._solved_by_reset()
        out = self._ready()
        return self._solved_by_reset() + out

    def check_time(self, stamp_ns: int, name: str | None = None) -> str | None:
        """Note camera ``name``'s frame stamp (ns, the capture time of row ``stamp_row``; None:
        a rig of one's camera) on the video's clock ahead of its frame, to act on a time reset
        before the frame is decoded (:meth:`_note`): returns the reset's reason text, else
        None. A stamp older than the camera's previous frame's (a rig of one: any step back; a
        rig's camera: by more than ``time_reset_ns``), or newer than the video's newest by
        more than ``time_reset_ns``, is a time reset: the gyro's timeline starts again (on a
        stamp going back the samples buffered so far are dropped, on a jump forward those
        older than the previous frame; the bias estimator's and the gyro check's pairing
        restart; counted ``rig.time_resets``), a rig's open rig frames are solved (a jump) or
        dropped (a step back). A rig of one's track resets itself on the same stamps.
        :meth:`add` (an image: :meth:`search_image`) notes each frame's stamp; the frame
        takes a stamp noted here as noted: a frame is noted once.

        Raises:
            ValueError: no ``name`` for a rig of several cameras, a camera not in the rig, a
                stamp beyond the int64 nanosecond range.
        """
        if name is None:
            if not self._single:
                raise ValueError("a rig's check_time names the camera")
            (name,) = self._cams
        elif name not in self._cams:
            raise ValueError(f"camera {name!r} is not in the rig {list(self._cams)}")
        reset = self._note(name, self._on_clock(name, checked_stamp(stamp_ns)))
        return None if reset is None else reset.detail

    def took_time_reset(self, name: str, stamp_ns: int | None = None) -> str | None:
        """Camera ``name``'s first call since the rig's clock last started again (a time
        reset, :meth:`add`) with a frame of the new timeline: that reset's detail; else None.
        ``stamp_ns``: the camera's frame's checked stamp (ns); one older than the new
        timeline's first time by more than ``time_reset_ns`` (on the rig's clock) is a late
        frame of the old timeline (after a jump ahead), which leaves the reset to the
        camera's next frame (None: any frame takes it). A rig camera's input stage calls it
        after each frame it takes, to note its stamp on the rig's clock
        (:meth:`~rs_localizer.ros.camera_input.CameraInput.note_time`: the camera_infos
        stamped after the camera's first frame of the new timeline forgotten, as one
        camera's)."""
        n, detail, start = self._reset
        if self._reset_taken.get(name, 0) == n:
            return None
        old = start is not None and stamp_ns is not None
        if old and start - self._on_clock(name, stamp_ns) > self._clock.time_reset_ns:
            return None  # (the old timeline's: the camera's new timeline not begun)
        self._reset_taken[name] = n
        return detail

    def _on_clock(self, name: str, stamp: Stamp) -> int:
        """ns: camera ``name``'s checked ``stamp`` on the rig's clock, its
        :attr:`LocalizerSettings.time_offsets` entry added (not its reference time): the time
        the video's clock and the rig's first frame note, a rig of one's gyro window starts
        from (:meth:`LocalizerSettings.reference_ns` without a camera model)."""
        return self.settings.reference_ns(name, stamp, None)

    def _note(self, name: str, t: int) -> TimeReset | None:
        """Camera ``name``'s frame at ``t`` (ns, its stamp on the rig's clock, :meth:`_on_clock`)
        noted on the video's clock, a camera's or a rig camera's the one way, once per frame
        and before its image is searched: :meth:`check_time` (a camera alone, ahead of the
        frame), the image search (:meth:`search_image`) and :meth:`add` take it as noted (a
        time equal to the camera's newest on the clock is noted already). The
        clock (:class:`~rs_localizer.tracking.clock.VideoClock`) compares it with the
        camera's newest frame time (a step back; a camera alone: the video's newest) and the
        video's newest (a jump ahead). On a time reset a jump ahead is counted
        ``<name>.stamp_jumped_ahead``, the video's timelines start again
        (:meth:`_time_reset`: a rig's open rig frames, solved on a jump ahead, go out with
        the frame, :meth:`_solved_by_reset`) and every camera's last image is forgotten (a
        new timeline's first image, this frame's too, is not compared with it: frozen
        image). Returns the time reset, or None."""
        if self._clock.source_newest(name) == t:  # (noted already: once per frame)
            return None
        reset = self._clock.step(t, name)
        if reset is None:
            return None
        if reset.reason == "stamp_jump":
            self.counts[f"{name}.stamp_jumped_ahead"] += 1
        self._reset_solved += self._time_reset(reset)
        for fe in () if self._img is None else self._img.frontends.values():
            fe.last_sample = None
        return reset

    def restart_track(self) -> None:
        """The next rig frame starts a new track, and nothing predicts a frame before it
        (:meth:`predict_camera` gives None): the cameras moved by an unknown amount meanwhile
        (a rig of one camera's frozen image, :meth:`process_image`: a prediction carried over
        the frozen frames would misplace the front end's search). The track's twists still
        pending go out with that rig frame, final as they are then; counted as a reset
        (:meth:`tracking_values`)."""
        with self._lock:
            self._track_over = True

    def _skip(self, name: str, reason: str) -> None:
        self.counts[f"{name}.skipped"] += 1
        self.counts[f"{name}.skipped.{reason}"] += 1

    def _timeline_ended(self, reset: TimeReset | None) -> list[LocalizerOutput]:
        """A time reset's rig part (:mod:`~rs_localizer.tracking.clock`; None: :meth:`reset`;
        the gyro's timeline starts again after it): the open rig frames solved as they are on
        a jump ahead (``stamp_jump``, returned), else dropped (``time_reset``); the track and
        the cameras' timelines started again; the old track's pending twists go out with the
        next rig frame (:attr:`LocalizerOutput.fused`). Counted ``rig.time_resets`` (not on
        :meth:`reset`). A rig of one camera, as its camera's video: a time reset ends nothing
        (its track resets itself on the same stamps); :meth:`reset` ends its track, its
        twists still pending dropped."""
        solved = []
        if reset is not None:
            self.counts["rig.time_resets"] += 1
            self._reset = (self._reset[0] + 1, reset.detail, self._clock.newest)
            if self._rig:  # (a camera's video: the caller reports it, check_time)
                self.log.warning("rig.time_reset", f"rig time reset: {reset.detail}")
            if reset.reason == "stamp_jump":  # (the old timeline's rig frames)
                solved = self.close()
        self._frames.restart()
        # (a rig's track path ends with its timeline; a rig of one's camera tracker resets
        # itself on the same stamps, counted there, so a time reset leaves it)
        if not self._single:
            self._carry += self._end_track(keep=True)
        elif reset is None:
            self._end_track()
            self._track_over = False
        return solved

    def _ready(self) -> list[LocalizerOutput]:
        """Solve the open rig frames every camera has joined, moved past or stopped for
        (:meth:`~rs_localizer.tracking.rig.RigGrouping.complete`)."""
        s = self.settings
        complete = self._frames.complete(s.window, s.stop_after, self._clock.first)
        return [self._solve(g) for g in complete]

    def close(self) -> list[LocalizerOutput]:
        """Solve every rig frame still open (the end of a video), oldest first."""
        return [self._solve(g) for g in self._frames.close_all()]

    def flush_idle(self, now: float | None = None) -> list[FusedPose]:
        """After ``tracking.max_gap`` s (wall clock, ``time.monotonic``; ``now`` to override)
        without a camera frame (:meth:`add`, :meth:`drop`) the video has stopped: the frames
        whose fused twist is still pending, final now (the rig frames still open stay open,
        and a frame more than ``max_gap`` later starts a new track).
        Empty without tracking, with nothing pending, or before that time."""
        tracking = self.settings.tracking
        if tracking is None or self._twist_source() is None:
            return []
        with self._lock:
            src = self._twist_source()
            if src is None or not self._twists.idle(tracking.max_gap, now):
                return []
            return self._fused(src.flush())

    def reset(self) -> list[FusedPose]:
        """Forget the video (the configuration stays): the rig frames open are dropped (counted
        as ``time_reset``), the track ends, the last rig frame posed is forgotten (the next
        frame is not predicted from it, without tracking either). Returns the track's twists
        still pending (a rig of one camera drops them, as its camera's video does)."""
        self._forget_video()
        out, self._carry = self._carry, []
        return out

    # ---------------------------------------------------------------- images
    def _image_input(self) -> _ImageInput:
        if self._img is None:
            self._img = _ImageInput()
        return self._img

    def set_frontend(
        self, name: str, frontend: Frontend | VideoFrontend | None, label: str | None = None
    ) -> None:
        """Use ``frontend`` for camera ``name``'s images (:meth:`process_image`; None: none): a
        :class:`~rs_localizer.correspondences.VideoFrontend` as it is, a per-image
        :class:`~rs_localizer.correspondences.Frontend` wrapped
        (:func:`~rs_localizer.correspondences.video_frontend`). Every camera needs its own
        front end object (a video front end keeps its last image's state); they may share a
        map. ``label``: its name in warnings (default: its class name).

        Raises:
            ValueError: a camera not in the rig. TypeError: an object without ``process``.
        """
        fe = self.camera_frontend(name)
        fe.set(frontend, None if frontend is None else label or type(frontend).__name__)

    def last_correspondences(self, name: str) -> Correspondences | None:
        """What camera ``name``'s front end found in its last image of :meth:`process_image`
        (every correspondence it returned, before the rows the estimator cannot use are
        dropped or capped; also for an image then skipped as ``frontend_too_few_points``);
        None before any, or when its last image was not searched (no camera model yet, a
        frozen image, the front end raised)."""
        return self._image_input().found.get(name)

    def last_search(self, name: str) -> ImageSearch | None:
        """Camera ``name``'s last image of :meth:`process_image` as searched
        (:class:`~rs_localizer.tracking.localizer.ImageSearch`: its failure, the frozen image's
        difference, the front end's error, correspondences, seconds and the points its solver
        needs; ``points2d`` (M, 2) px, ``points3d`` (M, 3) m, the rows given to the
        estimator); None before any, or without a camera model."""
        return self._image_input().searched.get(name)

    def frontend(self, name: str) -> VideoFrontend | None:
        """Camera ``name``'s front end (:meth:`set_frontend`), or None."""
        fe = self._image_input().frontends.get(name)
        return None if fe is None else fe.frontend

    def predict_camera(
        self, name: str, stamp_ns: int, camera: CameraModel, *, reference_ns: int | None = None
    ) -> RSModel | None:
        """Where the rig expects camera ``name``'s frame stamped ``stamp_ns`` (ns, capture time
        of row ``stamp_row``): the camera's model (:class:`~rs_localizer.pose.RSModel`
        ``(R, C, w, t)`` at its reference row, ``w``, ``t`` per unit RS coordinate, what
        :func:`~rs_localizer.estimation.estimate_rs_pose` estimates for it alone) of the
        rig's predicted pose and twist at the frame's reference time mapped through the
        camera's mounting (:func:`~rs_localizer.estimation.result.camera_model_of_rig`). The
        rig's prediction is the twist filter's while the track has a state, else (no
        tracking, a new track) the last rig frame posed (of :meth:`add` or
        :meth:`process_image`) carried at its own twist, as a camera's video predicts. None
        when nothing predicts the frame: no rig frame posed yet, or more than ``max_gap`` s
        (0.5 s without tracking) after the last, or not after it
        (:func:`~rs_localizer.tracking.tracker.predictable`). ``reference_ns``: the frame's
        time on the rig's clock (:meth:`LocalizerSettings.reference_ns`) when the caller
        made it; None: made here.

        Raises:
            ValueError: a camera not in the rig, a stamp beyond the int64 ns range.
        """
        cam = self._cams.get(name)
        if cam is None:
            raise ValueError(f"camera {name!r} is not in the rig {list(self._cams)}")
        ref = reference_ns
        if ref is None:
            ref = self.frame_time(name, stamp_ns, camera).reference_ns
        return self._predict(ref, camera, cam)

    def _filter_kernels(self, impl: str) -> None:
        """The twist filter's steps for a frame on ``impl``: plain Python on ``"numpy"``, so
        that nothing compiles while the kernels compile in the background
        (:attr:`~rs_localizer.tracking.fusion.TwistFilter.compiled`)."""
        if self._track is not None:
            self._track.filter.compiled = impl != NUMPY

    def _tracked_prediction(
        self, ref: int, camera: CameraModel, view: _Camera
    ) -> tuple[bool, FusedState | None]:
        """Whether the track decides the prediction (:meth:`predict_camera`) and its state
        predicted at ``ref``: after :meth:`restart_track` nothing predicts the next frame;
        the track decides while it has a state (a rig of one's camera tracker: made for the
        current settings and this camera model), else the last posed frame carried predicts
        (no tracking, a new track), a camera's and a rig's alike."""
        if self._track_over:
            return True, None
        t = self._track
        # (a rig of one's camera tracker is made per camera model and settings: another's
        # frame starts a new one)
        if self._single and self._track_key != self._key(camera):
            t = None
        if t is None or not t.filter.initialized:
            return False, None
        return True, t.predict(ref, self._implementation_now())

    def _implementation_now(self) -> str:
        """The estimator's implementation for the next frame, a camera's or a rig's:
        ``implementation()``, else the estimator's default: a camera alone's its solver's
        (:func:`~rs_localizer.estimation.implementation.default_implementation`), the rig
        estimator's (every step has a NumPy form: compiled unless this process cannot
        compile, :func:`~rs_localizer.estimation.implementation.compiled_by_default`)."""
        if self._implementation is not None:
            return self._implementation()
        if self._single:
            return default_implementation(self.settings.solver)
        return COMPILED if compiled_by_default() else NUMPY

    def _key(self, camera: CameraModel) -> tuple:
        """What a rig of one's tracker is made for: its solver, options, tracking options and
        camera model (a new object: a new track, as the camera's video)."""
        s = self.settings
        return (s.solver, s.options, s.tracking, id(camera))

    def _state_in_camera(self, state: FusedState, camera: CameraModel, view: _Camera) -> RSModel:
        """The camera's model of the rig's predicted state, through its mounting (a rig of
        one: the state's model in its camera, as the camera's own video has it)."""
        if self._single:
            return model_from_state(state, camera)
        rig = state.pose.model(1.0)  # (the rig's model: per second)
        return camera_model_of_rig(rig, view.mount, 0.0, camera.seconds_per_unit_r)

    def _carried_in_camera(
        self, model: RSModel, dt: float, camera: CameraModel, view: _Camera
    ) -> RSModel:
        """The camera's model of the last posed rig frame carried ``dt`` s, through its
        mounting (a rig of one: its camera's own model carried, as the camera's video does)."""
        if self._single:
            return carried_model(model, dt, camera.seconds_per_unit_r)
        return camera_model_of_rig(model, view.mount, dt, camera.seconds_per_unit_r)

    def drop(self, name: str, stamp_ns: int, camera: CameraModel | None, reason: str) -> list:
        """Count camera ``name``'s frame as received and skipped for ``reason`` (a key of
        :data:`SKIP_REASONS`: e.g. an image the caller could not decode); the camera still
        counts as having sent a frame at that time (the rig does not wait for it), its stamp
        noted on the video's clock as every frame's (:meth:`_note`: a stamp going back or
        jumping ahead is a time reset there, not at the camera's next frame). Returns the rig
        frames that completes, solved (as :meth:`add`; a time reset's first).

        Raises:
            ValueError: a camera not in the rig, an unknown reason.
        """
        cam = self._cams.get(name)
        if cam is None:
            raise ValueError(f"camera {name!r} is not in the rig {list(self._cams)}")
        if reason not in SKIP_REASONS:
            raise ValueError(
                f"unknown skip reason {reason!r}; expected one of {list(SKIP_REASONS)}"
            )
        t = self.frame_time(name, stamp_ns, camera)
        if self._img is not None:  # (its last image was not searched)
            self._img.found[name] = None
        return self._received(name, t.stamp_ns, t.reference_ns, reason=reason)

    def process_image(
        self,
        name: str,
        stamp_ns: int | FrameTime,
        image: np.ndarray,
        camera: CameraModel | None,
        encoding: str = "bgr8",
        tag: object = None,
    ) -> list[LocalizerOutput]:
        """Take one camera's image: its front end's correspondences
        (``frontend.process(image, camera, encoding, prediction)`` with the rig's
        prediction for this camera, :meth:`predict_camera`, when the front end takes one), the
        rows the estimator can use as a single camera's, with their scores and groups
        (:func:`~rs_localizer.tracking.localizer.usable_correspondences`: those with a NaN or
        inf dropped, counted ``<name>.points_dropped``; then at most
        :attr:`LocalizerSettings.max_points`, highest scores first, counted
        ``<name>.capped_clouds`` and ``<name>.capped_points``, with a warning), then
        :meth:`add`; each camera's front end is told how its frame was solved
        (``frontend.observe(stamp_ns, points2d, feedback)``, ``feedback`` the camera's part of
        the rig's estimate, :func:`~rs_localizer.estimation.result.camera_estimate`: the rig
        frame's success, the camera's inliers and its model from the rig's pose and its
        mounting) when its rig frame is solved: with unsynchronized
        cameras often after the camera's next image (a front end that searches around its last
        solved markers still does; one that tracks the pixels of its last image matches them
        by pixel and keeps those it finds). A camera's frame joins
        its rig frame whatever its number of correspondences (even none: the rig is posed from
        the others); an image whose front end raised (``frontend_error``) or that is the
        camera's previous image again (``frozen_image``) is skipped (:data:`SKIP_REASONS`);
        after a frozen image a rig of one camera's next frame starts a new track, searched
        whole, as its camera's video does (:meth:`restart_track`). Every camera's image has its time
        noted first, as a camera's video notes it (:meth:`check_time`, :meth:`_note`: after a time
        reset, this image's too, the image is not compared with the camera's last one); a rig of one
        camera's image whose front end found fewer correspondences than its solver needs
        (:func:`~rs_localizer.tracking.localizer.too_few_points`: unless they are one marker's
        coplanar corners or a few markers') skipped as ``frontend_too_few_points``.
        A camera's own video (:attr:`LocalizerSettings.camera_video`) returns no rig frame
        for an image skipped before the estimator and counts nothing for it (its caller
        reports the failure, :meth:`last_search`); its rows are counted by its ``count``. A
        camera's rows carry their scores (a rig of one's estimator, the camera's, weighs them;
        a rig of several's takes none).

        Args:
            name: a camera of the rig. stamp_ns: the capture time (ns) of row ``stamp_row``,
                or the frame's :meth:`frame_time` when the caller made it (taken as it is).
            image: (H, W) or (H, W, C) uint8 in ``encoding``.
            camera: the camera's model with its RS timing; None: not known yet (the frame is
                skipped as ``no_camera_info``, the front end does not run).
            tag: as :attr:`~rs_localizer.tracking.localizer.CameraFrame.tag`.
        Returns:
            the rig frames completed, solved (as :meth:`add`); what the front end found in
            the image: :meth:`last_correspondences`.
        Raises:
            ValueError: a camera not in the rig or without a front end (:meth:`set_frontend`),
                a stamp beyond the int64 ns range.
        """
        img = self._image_input()
        fe = img.frontends.get(name)
        if name not in self._cams or fe is None or fe.frontend is None:
            raise ValueError(f"rig camera {name!r} has no front end (set_frontend)")
        t = stamp_ns  # (once: the prediction, its rig frame)
        if not isinstance(t, FrameTime):
            t = self.frame_time(name, stamp_ns, camera)
        stamp, ref = t.stamp_ns, t.reference_ns
        img.found[name] = img.searched[name] = None
        if camera is None:  # (the front end does not run)
            return self._received(name, stamp, None, reason="no_camera_info")
        r = img.searched[name] = self._search(fe, name, t, image, camera, encoding)
        if r.failure is not None and not self._rig:  # (a camera's video: its caller's)
            img.found[name] = r.found
            return self._solved_by_reset()
        if r.failure == "frozen_image":
            self._warn_image(
                f"rig.frozen.{name}",
                f"rig camera {name!r}: the image is the previous one again (mean difference "
                f"{r.difference:.2f} gray levels): skipped",
            )
            return self._received(name, stamp, ref, reason=r.failure)
        if r.failure == "frontend_error":
            e = r.error
            self._warn_image(
                f"rig.frontend.{name}",
                f"rig camera {name!r}: {fe.label} front end failed: {type(e).__name__}: {e}",
            )
            return self._received(name, stamp, ref, reason=r.failure)
        found = img.found[name] = r.found
        if r.failure is not None:  # (frontend_too_few_points: a rig of one's)
            return self._received(name, stamp, ref, reason=r.failure)
        use = self._usable_rows(name, found)
        uv, xyz = r.points2d, r.points3d = use.points2d, use.points
        frame = _ImageFrame(stamp, camera, uv, xyz, use.scores, tag, name, use.groups)
        return self._received(name, stamp, ref, frame)

    def frame_time(self, name: str, stamp_ns: int, camera: CameraModel | None) -> FrameTime:
        """The times of camera ``name``'s frame stamped ``stamp_ns`` (ns, capture time of row
        ``stamp_row``): its stamp checked and its time on the rig's clock
        (:class:`~rs_localizer.camera.FrameTime`: ``stamp_ns``;
        ``reference_ns``, :meth:`LocalizerSettings.reference_ns`: its reference line's
        capture time plus the camera's time offset, the stamp without a camera model). Made
        once per frame, where it enters (:meth:`process_image`, :meth:`drop`,
        :meth:`search_image`, :meth:`predict_camera`) and handed on.

        Raises:
            ValueError: a stamp beyond the int64 nanosecond range (:func:`checked_stamp`).
        """
        stamp = checked_stamp(stamp_ns)
        return FrameTime(stamp, self.settings.reference_ns(name, stamp, camera))

    def search_image(
        self,
        name: str,
        stamp_ns: int | FrameTime,
        image: np.ndarray,
        camera: CameraModel,
        encoding: str = "bgr8",
    ) -> ImageSearch:
        """Camera ``name``'s image stamped ``stamp_ns`` (ns, capture time of row
        ``stamp_row``; or the frame's :meth:`frame_time` when the caller made it, taken as it
        is) through its front end (:meth:`set_frontend`), before the estimator, by the rules
        of its video (:func:`~rs_localizer.tracking.localizer.search_image`: the
        frozen-image check, then the front end's search with :meth:`predict_camera`); what
        :meth:`process_image` runs on a rig camera's image and a camera's alike
        (:meth:`~rs_localizer.tracking.sequence.SequenceLocalizer.process_image`).

        Its time is noted first, a camera's and a rig camera's alike (:meth:`_note`, unless the
        caller noted it already, :meth:`check_time`; after a time reset the image is not compared
        with the last one; a rig's open rig frames a jump ahead solves go out with the frame's
        :meth:`add`). A rig of one camera adds its camera's rules, which a rig of several does not
        have: a frozen image makes its next frame start a new track (:meth:`restart_track`: the
        camera moved by an unknown amount unseen, while a rig's other cameras keep its track), and
        an image with fewer correspondences than its solver needs fails ``frontend_too_few_points``
        (:func:`~rs_localizer.tracking.localizer.too_few_points`; a rig frame is posed from its
        other cameras' points as well).

        Returns:
            :class:`~rs_localizer.tracking.localizer.ImageSearch`.
        Raises:
            ValueError: a camera not in the rig or without a front end, a stamp beyond the
                int64 ns range.
        """
        fe = self._image_input().frontends.get(name)
        if name not in self._cams or fe is None or fe.frontend is None:
            raise ValueError(f"rig camera {name!r} has no front end (set_frontend)")
        t = stamp_ns if isinstance(stamp_ns, FrameTime) else self.frame_time(name, stamp_ns, camera)
        return self._search(fe, name, t, image, camera, encoding)

    def _search(
        self,
        fe: CameraFrontend,
        name: str,
        t: FrameTime,
        image: np.ndarray,
        camera: CameraModel,
        encoding: str,
    ) -> ImageSearch:
        """:meth:`search_image` with camera ``name``'s front end ``fe`` and the frame's times
        ``t`` (its stamp checked, its reference time)."""
        stamp, ref = t.stamp_ns, t.reference_ns
        self._note(name, self._on_clock(name, stamp))  # (first, unless check_time noted it)
        view = self._cams[name]
        r = search_image(
            fe, stamp, image, camera, encoding, lambda: self._predict(ref, camera, view),
            level=self.settings.frozen_image_level,
        )  # fmt: skip
        if not self._single:
            return r
        if r.failure == "frozen_image":  # (its camera moved on unseen)
            self.restart_track()
        elif r.failure is None:  # (too few correspondences never reach its solver)
            s = self.settings
            xyz = np.asarray(r.found.points, float).reshape(-1, 3)
            r.need = too_few_points(xyz, s.solver, s.options)
            if r.need is not None:
                r.failure = "frontend_too_few_points"
        return r

    def camera_frontend(self, name: str) -> CameraFrontend:
        """Camera ``name``'s front end driver
        (:class:`~rs_localizer.tracking.localizer.CameraFrontend`: its front end, label and
        last image's fingerprint; made without a front end, labelled ``frontend``, at the
        first call).

        Raises:
            ValueError: a camera not in the rig.
        """
        if name not in self._cams:
            raise ValueError(f"camera {name!r} is not in the rig {list(self._cams)}")
        img = self._image_input()
        fe = img.frontends.get(name)
        if fe is None:  # (kept when its front end is replaced: its last image's fingerprint)
            fe = img.frontends[name] = CameraFrontend(self.log)
        return fe

    def _usable_rows(self, name: str, found: Correspondences) -> Correspondences:
        """Camera ``name``'s front end's correspondences ``found`` as the rig estimator takes
        them, as a single camera's (:func:`~rs_localizer.tracking.localizer.usable_correspondences`:
        their scores and groups with their rows): without those holding a NaN or inf (counted
        ``<name>.points_dropped``), then at most :attr:`LocalizerSettings.max_points` (counted
        ``<name>.capped_clouds``, ``<name>.capped_points``; a warning)."""

        if self._rows_count is not None:  # (a camera's video: under its caller's names)
            return usable_correspondences(found, self.settings.max_points, self._rows_count,
                                          self.log.warning)  # fmt: skip

        def count(key: str, n: int) -> None:
            self.counts[f"{name}.{key}"] += n

        def warn(key: str, text: str) -> None:
            self.log.warning(f"rig.{key}.{name}", f"rig camera {name!r}: {text}")

        return usable_correspondences(found, self.settings.max_points, count, warn)

    def _warn_image(self, key: str, text: str) -> None:
        """A rig camera's image skipped (frozen, its front end failed): warned, unless worded
        for a camera (a camera's video: its caller reports it)."""
        if self._rig:
            self.log.warning(key, text)

    def _observed(self, out: LocalizerOutput) -> LocalizerOutput:
        """Tell each camera's front end how its image's frame in the rig frame ``out`` was
        solved (the frame its rig frame holds, :attr:`LocalizerOutput.frames`), once, as it is
        solved (:meth:`_solve`), whichever frame completed it (an image's, a cloud's, a
        dropped one's, a time reset's) or the video's end; returns ``out``."""
        img = self._img
        est, alone = out.estimate, out.camera_estimate  # (a rig of one: its camera's own)
        for k, n in enumerate(out.cameras if img is not None else ()):
            frame, fe = out.frames.get(n), img.frontends.get(n)
            if not isinstance(frame, _ImageFrame) or fe is None or fe.frontend is None:
                continue
            feedback = alone
            if est is not None and alone is None:
                mount, off = self._cams[n].mount, out.stamp_offsets.get(n, 0.0)
                feedback = camera_estimate(est, k, frame.camera, mount, off, frame.points2d)
            fe.observe(frame.stamp_ns, frame.points2d, feedback)
        return out

    def _twist_source(self) -> TrackerPath | None:
        """The tracker path (its fused states not yet final, :meth:`flush`)."""
        return self._track

    def _forget_track(self, keep: bool) -> list:
        """The track ends (the twist filter and the inlier ratio start again; a rig of one's
        tracker is dropped, its counters kept); returns the filter's fused states not yet final
        when ``keep``."""
        t = self._track
        if self._single:  # (its camera tracker is made again at its next frame)
            final = []
            if t is not None:
                self._track_counts.update(t.track_counts())
                final = t.reset() if keep else []
            self._track = self._track_key = self._track_camera = None
            return final
        final = [] if t is None else t.reset()
        return final if keep else []

    # ---------------------------------------------------------------- solving
    def _closed(self, g: OpenRigFrame) -> LocalizerOutput:
        """The rig frame ``g`` closed (no later frame joins one before it): its output with its
        cameras, not solved yet."""
        return LocalizerOutput(stamp_ns=g.lo, cameras=tuple(n for n in self._cams if n in g.frames))

    def _solve(self, g: OpenRigFrame) -> LocalizerOutput:
        """A rig frame complete (:meth:`_ready`, :meth:`close`): its cameras missing counted,
        then solved as every frame is (:meth:`_solve_frame`), its images' front ends told how
        (:meth:`_observed`)."""
        out = self._closed(g)
        for n in self._cams:
            if n not in g.frames:
                reason = self._frames.missing_reason(n, g, self.settings.window)
                out.missing[n] = reason
                self.counts[f"{n}.missed.{reason}"] += 1
        if out.missing:
            self.counts["rig.incomplete"] += 1
        self._agreement.update_apart(out.cameras, out.missing, self.settings.window)
        return self._observed(self._solve_frame(out, {n: g.frames[n] for n in out.cameras}))

    def _solve_frame(self, out: LocalizerOutput, frames: dict) -> LocalizerOutput:
        """Solve a frame, a camera's or a rig's (``frames``: camera -> ``(CameraFrame,
        reference time ns)``; ``out`` its output, at its time ``out.stamp_ns``), the one way:

        1. the twists of tracks ended before it go out with it (a time reset's, a configure's,
           :meth:`restart_track`'s: the track's pending twists final as they are);
        2. the estimator's implementation (:meth:`_implementation_now`) and the gyro's
           measurement over the frame's capture times (:meth:`_frame_gyro`);
        3. the estimator of its views (:meth:`_estimator`) on the track
           (:meth:`~rs_localizer.tracking.tracker.TrackerPath.track`; a rig's pose judged by
           :meth:`_judged` before the track takes it), cold without tracking;
        4. counted, its shares, its twist held for the fused twist unless final now (no
           tracking, or its estimator measures no twist:
           :attr:`~rs_localizer.tracking.tracker.FrameViews.measures_twist`), the states
           final released (:meth:`_fused`).

        A camera alone's estimate is its camera's own (:attr:`LocalizerOutput.camera_estimate`),
        in the rig's terms in ``estimate`` (:func:`_camera_as_rig`; a camera's video: its
        own). An estimator that raises fails the frame (``error``); the twists of a track
        that ended before it (a gap) go out with it all the same."""
        s = self.settings
        names = list(out.cameras)
        views = []
        for n in names:
            frame, ref = frames[n]
            out.stamp_offsets[n] = off = (ref - out.stamp_ns) * 1e-9
            out.tags[n] = frame.tag
            out.frames[n] = frame
            m = self._cams[n].mount
            views.append(
                View(frame.points2d, frame.points3d, frame.camera, m, off, groups=frame.groups)
            )
        with self._lock:
            out.fused, self._carry = self._carry, []
            self._restart_if_asked(out)
        # (while the kernels compile in the background: the NumPy implementation, tracked and
        # with the gyro all the same; runtime.background)
        self._impl = impl = self._implementation_now()
        out.compiled = impl != NUMPY
        if not out.compiled:
            self.counts["rig.uncompiled"] += 1
        t0 = time.perf_counter()  # (the gyro's samples waited for outside the lock)
        clocks = [(f.camera, self._on_clock(n, f.stamp_ns)) for n, (f, _) in frames.items()]
        out.gyro = self._gyro = self._frame_gyro(out.stamp_ns, clocks)
        out.gyro_seconds = time.perf_counter() - t0
        with self._lock:
            self._filter_kernels(impl)
            estimator = None
            try:
                estimator = self._estimator(out, views, frames[names[0]][0].scores)
                judge = None if self._single else lambda f: self._judged(out, f, estimator)
                if self._track is None:
                    f = PathFrame(estimator.cold().estimate, None)
                    f = f if judge is None else judge(f)
                    r = TrackResult(f.estimate, None)
                else:
                    r = self._track.track(out.stamp_ns, estimator, judge)
            except Exception as e:  # (the estimator raised: the frame failed)
                out.error = f"{type(e).__name__}: {e}"
                self._count_rig(names, "error")
                self.gyro_input.solved(out.stamp_ns, None, False)  # (the pairing restarts)
                if estimator is not None:  # (a track ended before it: its twists, final)
                    out.fused += self._fused(estimator.final)
                return out
            est, out.path = r.estimate, r.state
            if self._single:  # (a camera alone: its camera's own estimate kept)
                out.camera_estimate = est
                spr = views[0].camera.seconds_per_unit_r
                out.estimate = _camera_as_rig(est, spr) if self._rig else est
            else:
                out.estimate = est
            self._carried.update(out.stamp_ns, est)
            self.gyro_input.solved(out.stamp_ns, est, out.path in ("cold", "reset"))
            if not est.success:
                self._count_rig(names, est.failure or "error")
                if est.failure == CAMERAS_DISAGREE:  # (who disagrees: the joint fit's counts)
                    out.disagreeing = self._agreement.update(names, views, est, s, self._impl)
                out.fused += self._fused(r.final)
                return out
            self._count_rig(names, None)
            if out.path is not None:
                self.counts[f"rig.path.{out.path}"] += 1
            self._shares(out, est, views)
            # (its own twist final when nothing fuses it: no track, or no twist measured)
            out.twist_now = s.tracking is None or not estimator.measures_twist
            if not out.twist_now:  # (its fused twist comes when final)
                tag = out.tags[names[0]] if not self._rig else dict(out.tags)
                self._twists.hold(out.stamp_ns, est, tag, out.path == "relocalized")
            # (also with the frame's own twist final: an earlier track's, e.g. before the
            # solver became a global-shutter one)
            out.fused += self._fused(r.final)
        return out

    def _restart_if_asked(self, out: LocalizerOutput) -> None:
        """After :meth:`restart_track` the frame starts a new track: the track's pending twists
        out with ``out``, final as they are; counted a reset. Once, whatever becomes of the
        frame (an estimator that raises: the next frame continues the track it started)."""
        if not self._track_over:
            return
        self._track_over = False
        if self.settings.tracking is not None and self._track is not None:
            out.fused += self._end_track(keep=True)
            self._track_counts["resets"] += 1

    def _estimator(
        self, out: LocalizerOutput, views: list, scores: np.ndarray | None
    ) -> FrameViews:
        """The frame's views as the estimator of the tracker path
        (:class:`~rs_localizer.tracking.tracker.FrameViews`) with the frame's gyro on its
        implementation. A camera alone: its camera's tracker's
        (:meth:`~rs_localizer.tracking.tracker.RSTracker.frame_views`: its solver, options and
        tracked options, made again when its solver, options, tracking or camera model
        changed: the old track's twists out with ``out``, a reset) or, without tracking, its
        solver and ``options`` (the tracker dropped); ``scores``: its rows'. A rig: the rig
        estimator with ``options``, tracked with at most ``tracking.tracked_max_iterations``
        RANSAC samples (default :data:`RIG_TRACKED_MAX_ITERATIONS`)."""
        s = self.settings
        if self._single:
            v = views[0]
            if s.tracking is None:
                self._end_track()
                return FrameViews(views, s.options, s.options, solver=s.solver, scores=scores,
                                  gyro=self._gyro, implementation=self._impl)  # fmt: skip
            key = self._key(v.camera)
            if self._track is None or key != self._track_key:
                if self._track is not None:
                    out.fused += self._end_track(keep=True)
                    self._track_counts["resets"] += 1
                self._track = RSTracker(s.solver, s.options, s.tracking)
                self._track_key = key
                self._track_camera = v.camera  # (keeps id(camera) unique while in use)
            return self._track.frame_views(
                v.uv, v.X, v.camera, scores, self._gyro, self._impl, groups=v.groups
            )
        if self._tracked[0] is not s:  # (the tracked options: made once per settings)
            t = s.tracking
            n = None if t is None else t.tracked_max_iterations
            n = RIG_TRACKED_MAX_ITERATIONS if n is None else n
            o = s.options
            self._tracked = (s, replace(o, ransac=replace(o.ransac, max_iterations=n)))
        return FrameViews(
            views, s.options, self._tracked[1], gyro=self._gyro, gyro_time=self._gyro_time,
            implementation=self._impl,
        )  # fmt: skip

    def _judged(self, out: LocalizerOutput, f: PathFrame, estimator: FrameViews) -> PathFrame:
        """A rig frame's solve judged before the track takes it: a pose from one voting camera
        alone while another camera of the rig runs refused
        (:func:`~rs_localizer.tracking.rig.refusal`); when the prediction outvoted a camera
        into a pose it contradicts itself, the rig frame solved without the prediction stands
        if nothing refuses it (``relocalized``, counted ``rig.track_outvote_undone``)."""
        est = f.estimate
        why = refusal(est, out.cameras, self._frames, f.predicted) if est.success else None
        if why == CONTRADICTS_TRACK and est.disagreeing:
            # the prediction does not decide between these cameras; the rig frame solved
            # without it stands if it poses more than one camera (cameras a little apart)
            alone = estimator.cold()
            a = alone.estimate
            if a.success and refusal(a, out.cameras, self._frames, f.predicted) is None:
                self.counts["rig.track_outvote_undone"] += 1
                return replace(f, estimate=a, path="relocalized", prior=alone.prior)
        if why is None:
            return f
        if why == CONTRADICTS_TRACK:
            self.log.warning(
                "rig.contradicts_track",
                f"rig frame of camera {out.cameras[0]!r} alone refused: its pose contradicts "
                "the rig's track (its clock or stamp is likely off, or its matches are wrong)",
            )
        return replace(f, estimate=replace(est, success=False, failure=why))

    def _shares(self, out: LocalizerOutput, est: RSPoseEstimate, views: list) -> None:
        """A posed frame's :class:`CameraShare` per camera (a camera alone: its inliers of its
        rows) and, for a rig, its cameras outvoted and their agreement
        (:class:`~rs_localizer.tracking.rig.CameraAgreement`)."""
        names = list(out.cameras)
        total_in = int(est.num_inliers)
        if self._single:
            n_pts = len(views[0].uv)
            share = CameraShare(n_pts, total_in, 1.0 if total_in else 0.0,
                                total_in / n_pts if n_pts else float("nan"))  # fmt: skip
            out.shares[names[0]] = self._cams[names[0]].last_share = share
            return
        for k in est.disagreeing:  # (outvoted by the cameras that posed the rig)
            self.counts[f"{names[k]}.outvoted"] += 1
        n_pts = np.asarray(est.num_valid_per_view)
        n_in = np.asarray(est.num_inliers_per_view)
        for k, n in enumerate(names):
            pts, i = int(n_pts[k]), int(n_in[k])
            share = CameraShare(pts, i, i / total_in if total_in else 0.0,
                                i / pts if pts else float("nan"),
                                k in est.disagreeing)  # fmt: skip
            out.shares[n] = share
            self._cams[n].last_share = share
        out.disagreeing = self._agreement.update(names, views, est, self.settings, self._impl)

    def _count_rig(self, names, failure: str | None) -> None:
        if failure is None:
            self.counts["rig.solved"] += 1
            for n in names:
                self.counts[f"{n}.solved"] += 1
            return
        self.counts["rig.failed"] += 1
        self.counts[f"rig.failed.{failure}"] += 1
        for n in names:
            self.counts[f"{n}.failed"] += 1

    def clock_offsets(self, name: str) -> dict:
        """Camera ``name``'s apparent clock offset against each other camera (other camera ->
        s; :meth:`~rs_localizer.tracking.rig.RigGrouping.clock_offsets`).

        Raises:
            KeyError: a camera not in the rig.
        """
        return self._frames.clock_offsets(name)

    def camera_apart(self, name: str) -> dict | None:
        """The camera's apparent clock offsets (:meth:`clock_offsets`) when its frames are
        kept apart from the others' (its clock or stamp offset is likely wrong:
        :class:`~rs_localizer.tracking.rig.CameraAgreement`), else None.

        Raises:
            KeyError: a camera not in the rig.
        """
        return self.clock_offsets(name) if self._frames.cams[name].apart else None

    def camera_off_deg(self, out: LocalizerOutput, frame: CameraFrame) -> float | None:
        """deg between camera ``frame.camera_name``'s rotation posed alone from its frame in
        rig frame ``out`` (the single-camera estimator) and where ``out``'s pose and the
        camera's mounting put it: how far off a camera that disagrees with the others is
        (a wrong mounting shows its own error). None when ``out`` was not posed, the camera
        is not in it or its frame cannot be posed alone.

        Raises:
            KeyError: a camera not in the rig.
        """
        n = frame.camera_name
        m = self._cams[n].mount
        if not out.success or n not in out.stamp_offsets or frame.camera is None:
            return None
        view = View(frame.points2d, frame.points3d, frame.camera, m, out.stamp_offsets[n],
                    groups=frame.groups)  # fmt: skip
        return alone_deg(view, out.estimate)

    def camera_partner(self, name: str) -> str | None:
        """The other camera when ``name`` is one of two cameras that disagree with each other
        and no third camera tells which mounting is wrong (both are named: :meth:`camera_state`
        is ``disagrees`` for both), else None."""
        return self._agreement.partner(name)


class GroupingOnly(Localizer):
    """A :class:`Localizer` whose rig frames, once complete, come out unsolved (a
    :class:`LocalizerOutput` with its cameras and no estimate): every rule of the grouping is
    the localizer's own (:meth:`Localizer.add`, :meth:`Localizer.drop`: the window, a camera
    stopped after ``stop_after`` or its own frame intervals, late and out-of-order frames, time
    resets). What ``play --lockstep`` groups a rig bag's frames with, without solving them."""

    def _solve(self, g: OpenRigFrame) -> LocalizerOutput:
        return self._closed(g)


def _new_track(settings: LocalizerSettings) -> TrackerPath | None:
    """The tracker path of a rig of several cameras (None without tracking): the path alone,
    its estimator the rig's (a rig of one's is its camera's tracker,
    :class:`~rs_localizer.tracking.tracker.RSTracker`, made at its frames)."""
    to = settings.tracking
    return None if to is None else TrackerPath(to)


def _camera_as_rig(est: RSPoseEstimate, seconds_per_unit_r: float) -> RSPoseEstimate:
    """A camera's estimate (:func:`~rs_localizer.estimation.estimate_rs_pose`) as the rig
    estimate of a rig of one: the same pose, twist, covariances, inliers, per-view fields (its
    one view's) and record; the model's velocities per second (the rig's ``w``, ``t``: the
    camera's over ``seconds_per_unit_r`` s; a global shutter's zeros kept) and its
    ``model_covariance`` with them."""
    spr = float(seconds_per_unit_r)
    model, cov = est.model, est.model_covariance
    if spr > 0:
        R, C, w, t = model
        model = RSModel(R, C, w / spr, t / spr)
        if cov is not None:
            k = np.concatenate([np.ones(6), np.full(6, 1.0 / spr)])
            cov = cov * k[:, None] * k[None, :]
    return replace(est, model=model, model_covariance=cov)
