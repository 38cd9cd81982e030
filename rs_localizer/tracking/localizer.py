"""What the localizer of a camera's or a rig's video
(:class:`~rs_localizer.tracking.video.Localizer`; a camera alone is a rig of one) and the
camera's adapter (:class:`~rs_localizer.tracking.sequence.SequenceLocalizer`) share:

- the frame they take (:class:`CameraFrame`, of one camera, naming it in a rig) and the part
  of what they return for a frame that both have (:class:`FrameOutput`);
- the frames waiting for their fused twist (:class:`PendingTwists`): a posed frame's pose is
  out at once, its twist is final only when the fixed-lag smoother
  (:class:`~rs_localizer.tracking.fusion.TwistFilter`, inside the tracker path,
  :class:`~rs_localizer.tracking.tracker.TrackerPath`) releases its state, handed out as
  :class:`FusedPose`;
- each camera's image front end (:class:`CameraFrontend`, :func:`search_image`): the
  frozen-image check (:func:`same_image`), the search with the prediction (``process``), its
  one-time warning, the feedback of how the frame was solved (``observe``), and the rows the
  estimator can use (:func:`usable_rows`, :func:`usable_correspondences`,
  :func:`too_few_points`).

A video also checks the cameras' rolling-shutter timing (:class:`PendingTwists`,
:meth:`Localizer.readout_values <rs_localizer.tracking.video.Localizer.readout_values>`): a
frame's twist fitted over its readout must predict the next frames. When
:data:`READOUT_CHECK_SHARE` or more of the last :data:`READOUT_CHECK_FRAMES` rolling-shutter
frames were relocalized (the track's prediction, carried at the last twist, did not explain
them) or had their twist refused by the fused twist's gate, the frames' motion is not the
camera's: a wrong ``line_delay`` or readout direction, or intrinsics the rolling-shutter model
bends into motion. The videos of ``python -m benchmarks.bench_video`` (data/sample, shake, car,
pan, walk) with their true timing have none of the last 30 contradicted; the same videos with
the line delay doubled or halved, or the readout direction reversed, 20-29.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..camera import CameraModel, checked_stamp
from ..correspondences import (
    Correspondences,
    FrameFeedback,
    Frontend,
    VideoFrontend,
    checked_groups,
    video_frontend,
)
from ..estimation.gyro import GyroMeasurement
from ..estimation.options import EstimateOptions, points_needed
from ..estimation.points import capped_rows
from ..estimation.result import RSPoseEstimate
from ..estimation.single_tag import few_points
from ..pose import PoseWithCovariance, RSModel, RSPose
from .fusion import FusedState
from .gyro_input import SilentLog, TrackLog

if TYPE_CHECKING:
    from ..estimation.result import RSPoseEstimate

__all__ = [
    "FROZEN_IMAGE_LEVEL",
    "MAX_PENDING",
    "CameraFrame",
    "CameraFrontend",
    "FrameOutput",
    "FusedPose",
    "ImageSearch",
    "PendingTwists",
    "image_sample",
    "same_image",
    "search_image",
    "too_few_points",
    "usable_correspondences",
    "usable_rows",
]

#: frames whose fused twist may wait at most (the oldest beyond are dropped)
MAX_PENDING = 64
#: a frozen image: the mean absolute difference (gray levels) of the two images' pixel
#: samples (:func:`image_sample`) at most this; a camera's own noise alone gives more
FROZEN_IMAGE_LEVEL = 0.25


@dataclass(frozen=True)
class CameraFrame:
    """One camera's frame of correspondences: what a video localizer takes, of one camera
    (:meth:`SequenceLocalizer.process <rs_localizer.tracking.sequence.SequenceLocalizer.process>`)
    or of one of a rig's cameras
    (:meth:`Localizer.add <rs_localizer.tracking.video.Localizer.add>`).

    Attributes:
        stamp_ns: the capture time (ns, camera clock) of row ``stamp_row`` (the header stamp).
        camera: the camera model, with its rolling-shutter timing; None: not known yet (its
            camera_info has not arrived). A rig skips such a frame as ``no_camera_info``; one
            camera's localizer refuses it (TypeError).
        points2d: (N, 2) px, distorted image points; points3d: (N, 3) m, world points.
        scores: (N,) match quality (higher is better) or None.
        tag: anything the caller wants back with the frame (e.g. its frame id): with its
            fused twist (one camera), in its rig frame's ``tags`` (a rig).
        camera_name: the camera's name in the rig
            (:attr:`~rs_localizer.tracking.video.LocalizerSettings.mounts`); "" for one camera.
        groups: (N,) int64 each correspondence's group (one marker's corners: the marker's
            id; :attr:`~rs_localizer.correspondences.Correspondences.groups`), or None: what
            the estimator's covariance takes as a shared part of their image error
            (:attr:`~rs_localizer.estimation.view.View.groups`).

    Raises:
        ValueError: a stamp that is not a finite number within the int64 nanosecond range
            (:func:`~rs_localizer.camera.checked_stamp`); ``groups`` that are not one integer
            per row of ``points2d``. TypeError: a ``camera`` that is neither a
            :class:`~rs_localizer.camera.CameraModel` nor None.
    """

    stamp_ns: int
    camera: CameraModel | None
    points2d: np.ndarray
    points3d: np.ndarray
    scores: np.ndarray | None = None
    tag: object = None
    camera_name: str = ""
    groups: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "stamp_ns", checked_stamp(self.stamp_ns))
        if self.groups is not None:
            n = len(np.asarray(self.points2d).reshape(-1, 2))
            object.__setattr__(self, "groups", checked_groups(self.groups, n))
        if self.camera is not None:
            check_camera(self.camera)


def check_camera(camera: object) -> None:
    """Raises TypeError naming the type of a ``camera`` that is not a
    :class:`~rs_localizer.camera.CameraModel` (None included: a frame to solve needs one)."""
    if not isinstance(camera, CameraModel):
        raise TypeError(
            f"a frame needs a CameraModel (with its rolling-shutter timing), got "
            f"{type(camera).__name__}"
        )


def image_sample(image: np.ndarray) -> tuple[np.ndarray, tuple]:
    """A cheap fingerprint of an image (H, W) or (H, W, C) uint8: ``(one pixel in 8 x 8, every
    channel, as int16 (K,), the image's shape)`` (images of different shapes never compare
    equal). About 1/64 of the image is read."""
    a = np.asarray(image)
    if a.ndim < 2:
        return np.zeros(0, np.int16), a.shape
    return a[::8, ::8].astype(np.int16).ravel(), a.shape


def same_image(prev: tuple | None, cur: tuple, level: float = FROZEN_IMAGE_LEVEL) -> float | None:
    """The mean absolute difference (gray levels) of two :func:`image_sample` fingerprints
    when it is at most ``level`` (the same picture: a driver re-sending its last frame, a
    stalled camera, a frozen stream), else None: also for images of different shapes, and
    for an image without content (its sample's standard deviation under 2 gray levels: a
    black or uniform image, which gives no correspondences anyway)."""
    if prev is None or prev[1] != cur[1] or len(prev[0]) != len(cur[0]) or len(cur[0]) == 0:
        return None
    d = float(np.mean(np.abs(prev[0] - cur[0])))
    if not d <= level:  # (a new picture, every frame of a moving camera: no spread needed)
        return None
    return None if float(np.std(cur[0])) < 2.0 else d


def _usable_indices(
    uv: np.ndarray,
    xyz: np.ndarray,
    scores: np.ndarray | None,
    max_points: int | None,
    count: Callable[[str, int], Any],
    warn: Callable[[str, str], Any],
) -> np.ndarray | None:
    """The rows of :func:`usable_rows` as indices (increasing) into the N rows given, or None:
    every row (counted and warned as :func:`usable_rows` says)."""
    good = np.isfinite(uv).all(axis=1) & np.isfinite(xyz).all(axis=1)
    n = int(np.count_nonzero(good))
    rows = None
    if n < len(uv):
        count("points_dropped", len(uv) - n)
        rows = np.flatnonzero(good)
    if max_points is not None and n > max_points:
        count("capped_clouds", 1)
        count("capped_points", n - max_points)
        warn("capped", f"cloud of {n} points capped to max_points {max_points}")
        s = scores if rows is None or scores is None else scores[rows]
        keep = capped_rows(n, max_points, s)
        rows = keep if rows is None else rows[keep]
    return rows


def too_few_points(
    points3d: np.ndarray, solver: str, options: EstimateOptions | None
) -> int | None:
    """The rule by which a camera's image is dropped before the estimator: the number of
    correspondences ``solver`` needs with ``options`` (None: the defaults;
    :func:`~rs_localizer.estimation.options.points_needed`) when the front end found fewer
    (``points3d`` (N, 3) m, its rows) and they are not one marker's coplanar corners or a few
    markers' (which the estimator poses alone,
    :func:`~rs_localizer.estimation.single_tag.few_points`); None when the frame goes on to
    the estimator."""
    need = points_needed(solver, options if options is not None else EstimateOptions())
    return need if len(points3d) < need and not few_points(points3d) else None


def usable_rows(
    uv: np.ndarray,
    xyz: np.ndarray,
    scores: np.ndarray | None,
    max_points: int | None,
    count: Callable[[str, int], Any],
    warn: Callable[[str, str], Any],
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """A frame's rows ``uv`` (N, 2) px, ``xyz`` (N, 3) m, ``scores`` (N,) or None as the
    estimator takes them: without those holding a NaN or inf (counted
    ``count("points_dropped", n)``; before the cap, so that the cap keeps valid rows), then
    at most ``max_points`` of them (None: no cap) spread over the image
    (:func:`~rs_localizer.estimation.points.cap_points`; counted ``capped_clouds`` and
    ``capped_points``, and ``warn("capped", text)``). Each camera's images, a camera video's
    and a rig's (:meth:`~rs_localizer.tracking.video.Localizer.process_image`), and the
    node's per-camera input (:class:`~rs_localizer.ros.camera_input.CameraInput`) use it
    (an image's front end's rows: :func:`usable_correspondences`)."""
    rows = _usable_indices(uv, xyz, scores, max_points, count, warn)
    if rows is None:
        return uv, xyz, scores
    return uv[rows], xyz[rows], None if scores is None else scores[rows]


def usable_correspondences(
    found: Correspondences,
    max_points: int | None,
    count: Callable[[str, int], Any],
    warn: Callable[[str, str], Any],
) -> Correspondences:
    """A front end's :class:`~rs_localizer.correspondences.Correspondences` ``found`` as the
    estimator takes them: its rows by :func:`usable_rows` (those with a NaN or inf dropped,
    then at most ``max_points``; counted and warned alike), ``points2d`` (M, 2) px and
    ``points`` (M, 3) m as float, with the same rows of ``ids``, ``scores`` (the
    :meth:`~rs_localizer.correspondences.Correspondences.valid_scores`: None unless one per
    row) and ``groups`` (a marker's corners keep their group).

    Raises:
        ValueError: ``points2d`` or ``points`` that do not make (N, 2) and (N, 3).
    """
    uv = np.asarray(found.points2d, float).reshape(-1, 2)
    xyz = np.asarray(found.points, float).reshape(-1, 3)
    scores = found.valid_scores()
    ids = found.ids if found.ids is not None and len(found.ids) == len(uv) else None
    rows = _usable_indices(uv, xyz, scores, max_points, count, warn)
    c = Correspondences(uv, xyz, ids, scores, found.groups)
    return c if rows is None else c.take(rows)


@dataclass(frozen=True)
class FusedPose(PoseWithCovariance):
    """A frame's pose as estimated with its fused twist: what the node's twist and odom carry
    (a :class:`~rs_localizer.pose.PoseWithCovariance`; keyword arguments). A rig's fused rig
    frame is one too, in the rig frame.

    Attributes:
        pose: a :class:`~rs_localizer.pose.RSPose` at the frame's reference time
            (``pose.stamp_ns``, ns): ``orientation`` (3, 3) camera -> world and ``position``
            (3,) m as estimated, ``angular_velocity`` (3,) rad/s and ``linear_velocity`` (3,)
            m/s fused (camera frame).
        pose_covariance: (6, 6) of the estimated pose (ROS order, world frame).
        twist_covariance: (6, 6) of the fused twist (ROS order, camera frame).
        tag: the frame's tag (:attr:`CameraFrame.tag`; a
            rig frame's: camera -> its frame's tag).
        state: the tracker's fused state itself (the smoothed pose too, and the 12x12
            covariance of pose and twist).
        own_twist: the twist is the frame's own (as ``twist_single_frame``), with the
            estimate's covariance: the filter did not fuse the frame's own measurement (its
            innovation gate refused it, or it was unusable), so its state there is a prediction
            that the frame's data do not support; or the fused twist is implausible
            (:attr:`implausible`). A global-shutter estimate (no twist of its own) keeps the
            prediction.
        implausible: the fused twist turns or moves faster than the estimator's plausibility
            bounds (``PlausibilityOptions.max_angular_velocity``, ``max_linear_velocity``),
            which every published estimate passed: the frame's own twist replaces it
            (:meth:`PendingTwists.release`).
    """

    tag: object = None
    state: FusedState | None = None
    own_twist: bool = False
    implausible: bool = False

    @classmethod
    def of(
        cls, estimate: RSPoseEstimate, fused: FusedState, tag: object = None, own: bool = False
    ) -> FusedPose:
        """The estimate's pose (a camera's or a rig's
        :class:`~rs_localizer.estimation.result.RSPoseEstimate`) with the fused state's twist,
        at the fused state's stamp; the estimate's own twist and covariance where the filter
        did not fuse the frame (:attr:`own_twist`), or with ``own`` (the fused twist is
        implausible, :attr:`implausible`) if the estimate has a twist of its own."""
        est, stamp = estimate.pose, fused.pose.stamp_ns
        if (own or not fused.fused) and estimate.twist_covariance is not None:
            return cls(
                pose=est.with_twist(est.angular_velocity, est.linear_velocity, stamp),
                pose_covariance=estimate.pose_covariance,
                twist_covariance=estimate.twist_covariance,
                tag=tag,
                state=fused,
                own_twist=True,
                implausible=own,
            )
        return cls(
            pose=est.with_twist(fused.pose.angular_velocity, fused.pose.linear_velocity, stamp),
            pose_covariance=estimate.pose_covariance,
            twist_covariance=fused.twist_covariance,
            tag=tag,
            state=fused,
        )


@dataclass
class FrameOutput:
    """What became of a frame in a video: the fields a camera's frame
    (:class:`~rs_localizer.tracking.sequence.SequenceOutput`) and a frame of the localizer
    (:class:`~rs_localizer.tracking.video.LocalizerOutput`: a rig frame, a camera's frame
    alone) share, each adding its own fields to these.

    Attributes:
        stamp_ns: the frame's reference time (ns): the time of the estimated pose (a rig
            frame's: its earliest reference-line capture time).
        estimate: the estimator's :class:`~rs_localizer.estimation.result.RSPoseEstimate`
            (check ``success``); None when the estimator raised (``error``) or did not run.
        path: the tracker's path for the frame (``cold``, ``tracked``, ``relocalized``,
            ``reset``: :data:`~rs_localizer.tracking.tracker.STATES`); None without tracking.
        fused: earlier frames (and, on a reset, the track's last ones) whose fused twist is
            final now, oldest first (:class:`FusedPose`; also after a failed frame).
        gyro: the gyro measurement the frame was solved with, or None (no gyro, or its
            samples missing); the estimate says whether it was used or rejected.
        error: ``"<exception type>: <message>"`` when the estimator raised, else None.
        compiled: the frame was solved on the compiled implementation; False: on the NumPy
            implementation while the kernels compile in the background
            (:mod:`rs_localizer.runtime.background`): tracked, with the gyro and fused all the
            same.
    """

    stamp_ns: int = 0
    estimate: RSPoseEstimate | None = None
    path: str | None = None
    fused: list[FusedPose] = field(default_factory=list)
    gyro: GyroMeasurement | None = None
    error: str | None = None
    compiled: bool = True

    @property
    def success(self) -> bool:
        """The frame was posed (``estimate.success``)."""
        return self.estimate is not None and self.estimate.success


def _beyond(pose: RSPose, bounds: tuple[float, float]) -> bool:
    """The twist of ``pose`` (an :class:`~rs_localizer.pose.RSPose`) turns faster than
    ``bounds[0]`` rad/s or moves faster than ``bounds[1]`` m/s, or is not finite."""
    w = float(np.linalg.norm(pose.angular_velocity))
    v = float(np.linalg.norm(pose.linear_velocity))
    return not (w <= bounds[0] and v <= bounds[1])


#: the rolling-shutter timing check looks at this many of the last frames released with a
#: twist of their own (:meth:`PendingTwists.readout_share`)
READOUT_CHECK_FRAMES = 30

#: the timing is suspect when at least this share of those frames was relocalized or had its
#: twist refused by the fused twist
READOUT_CHECK_SHARE = 1.0 / 3.0


def readout_warning(contradicted: int, rig: bool = False) -> str:
    """The warning of a suspect rolling-shutter timing (:meth:`Localizer.readout_values`)
    of a camera's video or (``rig``) a rig's: ``contradicted`` of the last
    :data:`READOUT_CHECK_FRAMES` frames relocalized or their twist refused, and what to check
    (the node's parameters of a camera's or the rig cameras' timing)."""
    what = "rig frames" if rig else "frames"
    advice = (
        "check each camera's line_delay and direction (rig.<camera>.*) and calibration"
        if rig
        else "check rs.line_delay (measure it: rs-localizer calibrate-readout), rs.direction "
        "and the camera calibration"
    )
    return (
        f"the {what}' rolling-shutter motion does not predict the video ({contradicted} of "
        f"the last {READOUT_CHECK_FRAMES} {what} relocalized or their twist refused): {advice}"
    )


class PendingTwists:
    """The posed frames whose fused twist is not final yet: frame time (ns, the time the
    twist filter was given) -> (estimate, tag), released as :class:`FusedPose` when the filter
    hands out their final state.

    Args:
        limit: frames held at most (the oldest beyond are dropped).

    Attributes:
        own_twists: released frames whose twist is their own (:attr:`FusedPose.own_twist`),
            over the queue's life. implausible_twists: frames whose fused twist was beyond the
            plausibility bounds (:meth:`release`), over the queue's life. last_wall:
            ``time.monotonic()`` s of the last frame noted (:meth:`note_frame`), None before
            one. recent: per released frame with a twist of its own (a rolling-shutter
            estimate), the last :data:`READOUT_CHECK_FRAMES`: True when the frame was
            relocalized or its twist is its own (the fused twist refused it).
    """

    def __init__(self, limit: int = MAX_PENDING):
        self.limit = int(limit)
        self._items: dict[int, tuple] = {}
        self.own_twists = 0
        self.implausible_twists = 0
        self.last_wall: float | None = None
        self.recent: deque[bool] = deque(maxlen=READOUT_CHECK_FRAMES)

    def __len__(self) -> int:
        return len(self._items)

    def hold(
        self,
        stamp_ns: int,
        estimate: RSPoseEstimate,
        tag: object = None,
        relocalized: bool = False,
    ) -> None:
        """Hold a posed frame (``stamp_ns``: its time in the twist filter) until its fused
        state is final; ``relocalized``: the track's prediction did not explain it (the
        tracker's path ``relocalized``)."""
        self._items[stamp_ns] = (estimate, tag, bool(relocalized))

    def release(self, final: list, bounds: tuple[float, float] | None = None) -> list[FusedPose]:
        """The frames of the final fused states ``final`` (oldest first), each its estimate's
        pose with the fused twist (:meth:`FusedPose.of`); states of frames not held are
        skipped. Then the oldest frames beyond ``limit`` are dropped (never left behind for
        long).

        ``bounds``: ``(max_angular_velocity, max_linear_velocity)`` (rad/s, m/s; the
        estimator's plausibility bounds): a fused twist that turns or moves faster (norms) is
        never handed out. The frame carries its own twist instead (:attr:`FusedPose.implausible`)
        when it has one within the bounds; else (a global-shutter estimate) the frame is not
        released at all (no twist or odom for it). Both are counted in
        :attr:`implausible_twists`."""
        out = []
        for f in final:
            item = self._items.pop(f.pose.stamp_ns, None)
            if item is None:
                continue
            fp = FusedPose.of(item[0], f, item[1])
            if bounds is not None and not fp.own_twist and _beyond(fp.pose, bounds):
                self.implausible_twists += 1
                est = item[0]
                if est.twist_covariance is None or _beyond(est.pose, bounds):
                    continue
                fp = FusedPose.of(est, f, item[1], own=True)
            out.append(fp)
            self.own_twists += fp.own_twist
            if item[0].twist_covariance is not None:
                self.recent.append(item[2] or fp.own_twist)
        if len(self._items) > self.limit:
            for k in sorted(self._items)[: -self.limit]:
                del self._items[k]
        return out

    def readout_share(self) -> float | None:
        """The share of the last :data:`READOUT_CHECK_FRAMES` frames with a twist of their own
        that were relocalized or had their twist refused (:attr:`recent`), None before that
        many."""
        if len(self.recent) < READOUT_CHECK_FRAMES:
            return None
        return sum(self.recent) / len(self.recent)

    def clear(self) -> None:
        """Drop every frame held (their track is over)."""
        self._items.clear()

    def note_frame(self, now: float | None = None) -> None:
        """A frame came (``now``: ``time.monotonic()`` s, None: now)."""
        self.last_wall = time.monotonic() if now is None else now

    def idle(self, max_gap: float, now: float | None = None) -> bool:
        """Frames are held and none came for ``max_gap`` s (wall clock, ``time.monotonic``;
        ``now`` to override): the video has stopped."""
        last = self.last_wall
        if last is None or not self._items:
            return False
        return (time.monotonic() if now is None else now) - last >= max_gap


class CameraFrontend:
    """One camera's image front end as a video drives it (:meth:`~rs_localizer.tracking.
    sequence.SequenceLocalizer.process_image`, :meth:`~rs_localizer.tracking.video.Localizer.
    process_image`): the calls of :class:`~rs_localizer.correspondences.VideoFrontend`, its
    warnings logged, and the fingerprint of the camera's last image (kept when the front end
    is replaced).

    Args:
        log: the :class:`~rs_localizer.tracking.gyro_input.TrackLog` of its warnings (None:
            silent). label: its name in warnings and errors (e.g. ``aruco``).

    Attributes:
        frontend: the :class:`~rs_localizer.correspondences.VideoFrontend`, None: none.
        last_sample: the :func:`image_sample` of the camera's last image, None before one.
    """

    def __init__(self, log: TrackLog | None = None, label: str = "frontend"):
        self.log: TrackLog = log if log is not None else SilentLog()
        self.label = label
        self.frontend: VideoFrontend | None = None
        self.last_sample: tuple | None = None

    def set(self, frontend: Frontend | VideoFrontend | None, label: str | None = None) -> None:
        """Use ``frontend`` (None: none): a :class:`~rs_localizer.correspondences.VideoFrontend`
        as it is, a per-image :class:`~rs_localizer.correspondences.Frontend` wrapped
        (:func:`~rs_localizer.correspondences.video_frontend`); ``label``: its name (None:
        unchanged).

        Raises:
            TypeError: an object without ``process``.
        """
        self.frontend = None if frontend is None else video_frontend(frontend)
        if label is not None:
            self.label = label

    def frozen(self, image: np.ndarray, level: float) -> float | None:
        """Note the camera's image (H, W) or (H, W, C) uint8; the mean absolute difference
        (gray levels) from its last image when it is the same picture again
        (:func:`same_image` within ``level``), else None (also with ``level`` < 0: never, and
        without a last image: the first, or the first after a time reset)."""
        sample = image_sample(image)
        prev, self.last_sample = self.last_sample, sample
        if level < 0:
            return None
        return same_image(prev, sample, level)

    def search(
        self, image: np.ndarray, camera: CameraModel, encoding: str, prediction: RSModel | None
    ) -> Correspondences:
        """The front end's correspondences of the image (``process(image, camera, encoding,
        prediction)``; ``prediction``: the frame's predicted
        :class:`~rs_localizer.pose.RSModel` in this camera, or None); its one-time warning
        logged (``<label>.warning``).

        Raises:
            whatever the front end raises.
        """
        fe = self.frontend
        found = Correspondences.of(
            fe.process(image, camera, encoding=encoding, prediction=prediction)
        )
        text = fe.pop_warning()
        if text:
            self.log.warning(f"{self.label}.warning", text)
        return found

    def observe(
        self, stamp_ns: int, points2d: np.ndarray | None, feedback: FrameFeedback | None
    ) -> None:
        """Tell the front end how its frame stamped ``stamp_ns`` was solved (``observe``;
        ``points2d`` (M, 2) the rows given to the estimator and ``feedback`` a
        :class:`~rs_localizer.correspondences.FrameFeedback`, or None and None: the frame
        was not solved, its next image is searched whole). An error there is logged
        (``frontend_error``); the video goes on."""
        try:
            self.frontend.observe(stamp_ns, points2d, feedback)
        except Exception as e:
            self.log.warning("frontend_error", f"{self.label}.observe: {type(e).__name__}: {e}")


@dataclass
class ImageSearch:
    """What a camera's front end made of an image (:func:`search_image`).

    Attributes:
        failure: None (searched), ``frozen_image`` (the camera's last image again: not
            searched), ``frontend_error`` (the front end raised) or, for a camera alone
            (:meth:`~rs_localizer.tracking.video.Localizer.search_image`),
            ``frontend_too_few_points`` (searched: fewer correspondences than its solver
            needs, :func:`too_few_points`).
        difference: gray levels, the mean absolute difference from the last image
            (``frozen_image``). error: the front end's exception (``frontend_error``).
        found: the front end's :class:`~rs_localizer.correspondences.Correspondences`
            (searched). seconds: s spent in the front end's search.
        need: the correspondences the solver needs (``frontend_too_few_points``), else None.
        points2d: (M, 2) px and points3d: (M, 3) m, the rows of ``found`` given to the
            estimator (:func:`usable_rows`; set by
            :meth:`~rs_localizer.tracking.video.Localizer.process_image`), else None.
    """

    failure: str | None = None
    difference: float = 0.0
    error: Exception | None = None
    found: Correspondences | None = None
    seconds: float = 0.0
    need: int | None = None
    points2d: np.ndarray | None = None
    points3d: np.ndarray | None = None


def search_image(
    fe: CameraFrontend,
    stamp_ns: int,
    image: np.ndarray,
    camera: CameraModel,
    encoding: str,
    prediction: Callable[[], RSModel | None],
    *,
    level: float = FROZEN_IMAGE_LEVEL,
) -> ImageSearch:
    """A camera's image through its front end ``fe``, before the estimator: the frozen-image
    check (:meth:`CameraFrontend.frozen` within ``level``: the front end told that its tracks
    are stale, ``observe(stamp_ns, None, None)``), the frame's prediction
    (``prediction()``: the video's model of the frame seen by ``camera``, None when nothing
    predicts it; asked only for an image that is searched), the front end's search with it.
    What a camera's video and each camera of a rig run on an image."""
    diff = fe.frozen(image, level)
    if diff is not None:
        fe.observe(stamp_ns, None, None)  # (its tracks are stale: searched whole next)
        return ImageSearch("frozen_image", difference=diff)
    predicted = prediction()
    t0 = time.perf_counter()
    try:
        found = fe.search(image, camera, encoding, predicted)
    except Exception as e:
        return ImageSearch("frontend_error", error=e)
    return ImageSearch(found=found, seconds=time.perf_counter() - t0)
