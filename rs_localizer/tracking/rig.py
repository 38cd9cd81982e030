"""What only a rig of several cameras runs, as units the localizer
(:class:`~rs_localizer.tracking.video.Localizer`) holds and calls: a camera alone is a rig of
one, each of its frames a rig frame complete at once, which nothing refuses and no other camera
disagrees with. The rules as users meet them: docs/rig_node.md.

- :class:`RigGrouping`: the cameras' frames grouped into *rig frames* by their reference-line
  times, when a rig frame is complete, why a camera missed it, the apparent clock offsets;
- :class:`CameraAgreement`: the cameras that *disagree* with the rig, and those whose frames
  never join the others' (*apart*);
- :func:`refusal`: why a rig frame posed from one camera alone while others run is refused.
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Callable, Iterator, Mapping
from typing import Any

import numpy as np
from scipy.stats import chi2

from ..accuracy import absolute_pose_errors, covariance_distances
from ..estimation.estimate import estimate_rs_pose
from ..estimation.result import CONTRADICTS_TRACK, UNCONFIRMED, RSPoseEstimate
from ..estimation.rig import VOTE_MIN_POINTS
from ..estimation.view import View
from ..geometry import rotation_angle_deg
from ..pose import RSPose
from .fusion import FusedState
from .gyro_input import TrackLog
from .localizer import CameraFrame

__all__ = [
    "APART_HISTORY",
    "APART_MIN",
    "APART_SHARE",
    "CONFIRM_MIN_INLIERS",
    "CONTRADICTION_MIN_DEG",
    "CONTRADICTION_MIN_M",
    "CONTRADICTION_QUANTILE",
    "MISSED_REASONS",
    "STOP_INTERVALS",
    "CameraAgreement",
    "OpenRigFrame",
    "RigGrouping",
    "alone_deg",
    "offsets_text",
    "refusal",
    "window_ns",
]

#: why a camera is missing from a solved rig frame (counted ``<camera>.missed.<reason>``)
MISSED_REASONS = {
    "apart": "the camera had a frame within 2 x window of the rig frame but not within window: "
    "stamps too far apart to be one rig frame (unsynchronized cameras, a wrong stamp offset); "
    "that frame is in a rig frame of its own",
    "dropped": "no frame of the camera near the rig frame (it skipped one)",
    "stopped": "the camera sent no frame for stop_after s while the others did: the rig runs on "
    "the others",
    "no_camera_info": "the camera's frame within 2 x window of the rig frame had no camera model "
    "(its camera_info had not arrived: skipped.no_camera_info)",
    "skipped": "the camera's frame within 2 x window of the rig frame was skipped (Localizer."
    "drop, a reason of SKIP_REASONS: e.g. an image that did not decode), not a frame apart",
}
#: a pose contradicts the track when its normalized squared distance from the prediction
#: (rotation and position, the prediction's and the estimate's covariances) exceeds the
#: chi-square quantile (6 dof) of this probability, as the twist filter's gate does, and it is
#: at least CONTRADICTION_MIN_DEG or CONTRADICTION_MIN_M away from it
CONTRADICTION_QUANTILE = 0.9999
CONTRADICTION_MIN_DEG = 0.3
CONTRADICTION_MIN_M = 0.02
#: a camera too small to vote in the cameras' consensus (fewer than the estimator's
#: ``VOTE_MIN_POINTS`` points, e.g. one tag's 4 corners) confirms a tracked rig frame posed by
#: one voting camera when at least this many of its points are inliers of the rig's pose
#: (one more than the 3 that pose a camera, so that they check the pose rather than merely
#: fit it): the track's prediction does not refuse it. Not at a track's start
#: (``unconfirmed``): nothing else checks the pose there (docs/rig.md, TagSLAM's rigs)
CONFIRM_MIN_INLIERS = 4
#: a camera is *apart* (its clock likely off) when it missed, or was alone in, at least
#: APART_SHARE of its last APART_HISTORY rig frames as ``apart`` (at least APART_MIN of them)
APART_HISTORY = 10
APART_MIN = 6
APART_SHARE = 0.8
#: a camera counts as stopped only after this many of its own frame intervals without a frame
#: too (:meth:`RigGrouping.stop_ns`; docs/rig.md: TagSLAM's 2 Hz cameras)
STOP_INTERVALS = 2.0


# ---------------------------------------------------------------------- grouping
def window_ns(window: float) -> int:
    """A rig's ``window`` (s) in ns, rounded as every test of its grouping and queue takes it."""
    return int(round(window * 1e9))


class OpenRigFrame:
    """A rig frame being grouped: ``frames``, camera -> (its frame, its reference time ns);
    ``lo`` and ``hi``, its earliest and latest reference times (ns); a frame :meth:`fits` it
    when its camera is not in it and all their reference times lie within the window."""

    def __init__(self, name: str, frame: CameraFrame, ref: int):
        self.frames = {name: (frame, ref)}
        self.lo = self.hi = ref

    def fits(self, name: str, ref: int, window_ns: int) -> bool:
        return name not in self.frames and max(self.hi, ref) - min(self.lo, ref) <= window_ns

    def add(self, name: str, frame: CameraFrame, ref: int) -> None:
        self.frames[name] = (frame, ref)
        self.lo, self.hi = min(self.lo, ref), max(self.hi, ref)


class _RigCamera:
    """One camera of the rig: its frames as the grouping sees them, its agreement with the
    others (:class:`CameraAgreement`)."""

    def __init__(self, name: str):
        self.name = name
        self.newest: int | None = None  # ns, newest stamp (reference time when known)
        self.last_ref: int | None = None  # ns, the last accepted frame's reference time
        self.recent: deque = deque(maxlen=8)  # reference times of the last frames
        self.stopped = False
        self.no_info: deque = deque(maxlen=8)  # stamps of its last frames without a model
        self.dropped: deque = deque(maxlen=8)  # reference times of its last frames skipped
        self.flags: deque = deque()  # (per rig frame: its points fit far worse; maxlen history)
        self.disagrees = False
        self.partner: str | None = None  # (two cameras that disagree: the other one)
        self.apart_flags: deque = deque(maxlen=APART_HISTORY)  # (rig frames it was apart in)
        self.apart = False


class RigGrouping:
    """The grouping of a rig's cameras' frames into rig frames: a rig frame holds at most one
    frame per camera, all within ``window`` s of its earliest reference time
    (:func:`~rs_localizer.camera.reference_stamp_ns`); it is complete once every camera is in
    it, has moved past it or has stopped (:meth:`complete`), and a camera that sends again
    joins again. Its state: the rig frames open, each camera's frame times.

    Args:
        cameras: the cameras' names, in the rig's order.
        counts: the localizer's counters (``rig_frames``, ``<camera>.stopped``,
            ``rig.skipped[.time_reset]``). log: its warnings (a camera stopped, back).
        skip: ``skip(camera, reason)`` counts a camera's frame skipped (``skip("rig",
            "time_reset")``: a rig frame).
        ordered: its cameras' frames are kept in order (a frame not later than its camera's
            previous one, or older than the last rig frame closed, skipped); False: a rig of
            one, which takes every frame as its camera's video does (any step back of its
            stamps is a time reset, :mod:`~rs_localizer.tracking.clock`).

    Attributes:
        cams: camera -> its state, in the rig's order: ``newest`` (ns; None: no frame since the
            start or the last time reset), ``stopped`` (no frame for ``stop_after`` s while
            others send), with its agreement's (:class:`CameraAgreement`: ``apart``).
        open: the rig frames open, oldest first. last_closed: ns, the time of the last rig
            frame closed, None before one.
    """

    def __init__(self, cameras: tuple, counts: Counter, log: TrackLog,
                 skip: Callable[[str, str], Any], ordered: bool = True):  # fmt: skip
        self.cams = {n: _RigCamera(n) for n in cameras}
        self.ordered = ordered
        self.open: list[OpenRigFrame] = []
        self.last_closed: int | None = None
        self.counts, self.log, self._skip = counts, log, skip

    def skipped(self, name: str, t: int, reason: str) -> None:
        """Camera ``name``'s frame at ``t`` (ns) skipped for ``reason`` (a key of
        :data:`~rs_localizer.tracking.video.SKIP_REASONS`, counted): the camera counts as
        having sent a frame then (the rig does not wait for it); one without a camera model
        (``no_camera_info``, ``t`` its stamp) whatever its time."""
        cam, info = self.cams[name], reason == "no_camera_info"
        self._skip(name, reason)
        (cam.no_info if info else cam.dropped).append(t)
        if info or cam.last_ref is None or t > cam.last_ref:
            cam.newest = t if cam.newest is None else max(cam.newest, t)

    def take(self, name: str, frame: CameraFrame, ref: int, window: float) -> bool:
        """Camera ``name``'s ``frame`` at reference time ``ref`` (ns) into the rig frame it
        fits (within ``window`` s of its earliest), or a new one; False (skipped, counted) when
        it is not later than the camera's previous frame (``out_of_order``) or older than the
        last rig frame closed (``late``); unordered (a rig of one), every frame is taken (its
        rig frame complete at once)."""
        cam = self.cams[name]
        if self.ordered and cam.last_ref is not None and ref <= cam.last_ref:
            self._skip(name, "out_of_order")
            return False
        if self.ordered and self.last_closed is not None and ref < self.last_closed:
            self._skip(name, "late")
            cam.last_ref = ref
            return False
        cam.last_ref = ref
        cam.newest = ref if cam.newest is None else max(cam.newest, ref)
        cam.recent.append(ref)
        if cam.stopped:
            cam.stopped = False
            self.log.info(f"rig camera {name!r} sends frames again")
        w = window_ns(window)
        for g in self.open:
            if g.fits(name, ref, w):
                g.add(name, frame, ref)
                break
        else:
            self.open.append(OpenRigFrame(name, frame, ref))
            self.open.sort(key=lambda g: g.lo)
            self.counts["rig_frames"] += 1
        return True

    def complete(self, window: float, stop_after: float, first: int | None
                 ) -> Iterator[OpenRigFrame]:  # fmt: skip
        """The open rig frames every camera has joined, moved past (its newest frame later than
        the rig frame's earliest plus ``window`` s) or stopped for (no frame for ``stop_after``
        s, :meth:`stop_ns`, since its last or, without one, since ``first``, ns: when the
        video's clock began, :attr:`~rs_localizer.tracking.clock.VideoClock.first`; marked
        here, with a warning), oldest first, each taken out of :attr:`open` and closed as it is
        handed out (:meth:`_handed_out`)."""
        now = max((c.newest for c in self.cams.values() if c.newest is not None), default=None)
        if now is None:
            return
        stop_ns = stop_after * 1e9
        for cam in self.cams.values():
            gap = now - (cam.newest if cam.newest is not None else first)
            # (stop_after first: the camera's own intervals only lengthen it)
            if not cam.stopped and gap > stop_ns and gap > self.stop_ns(cam, stop_after):
                cam.stopped = True
                self.counts[f"{cam.name}.stopped"] += 1
                self.log.warning(
                    "rig.stopped",
                    f"rig camera {cam.name!r}: no frame for {gap * 1e-9:.2f} s "
                    "(stop_after): the rig runs on the other cameras",
                )
        w = window_ns(window)
        yield from self._handed_out(
            lambda g: all(
                n in g.frames or c.stopped or (c.newest is not None and c.newest > g.lo + w)
                for n, c in self.cams.items()
            )
        )

    def stop_ns(self, cam: _RigCamera, stop_after: float) -> float:
        """ns without a frame of ``cam`` after which it counts as stopped: ``stop_after`` s, or
        :data:`STOP_INTERVALS` of its own frame intervals (the median over its recent frames;
        before it has two, the rig's cameras' together) when that is longer, so that a
        camera slower than ``1 / stop_after`` frames per second is not taken as stopped
        between its frames."""
        steps = _frame_steps(cam.recent)
        if not len(steps):
            steps = np.concatenate([_frame_steps(c.recent) for c in self.cams.values()])
        stop_ns = stop_after * 1e9
        return max(stop_ns, STOP_INTERVALS * float(np.median(steps))) if len(steps) else stop_ns

    def close_all(self) -> Iterator[OpenRigFrame]:
        """Every rig frame still open (the end of a video), as :meth:`complete` hands them
        out."""
        return self._handed_out(lambda g: True)

    def _handed_out(self, ready: Callable[[OpenRigFrame], bool]) -> Iterator[OpenRigFrame]:
        """The open rig frames, oldest first, up to the first that is not ``ready``; each taken
        out of :attr:`open` and closed as it is handed out (:attr:`last_closed` its time: no
        later frame joins one before it)."""
        while self.open and ready(self.open[0]):
            g = self.open.pop(0)
            self.last_closed = g.lo
            yield g

    def missing_reason(self, name: str, g: OpenRigFrame, window: float) -> str:
        """Why camera ``name`` is missing from rig frame ``g`` (a key of
        :data:`MISSED_REASONS`; ``window`` s)."""
        cam = self.cams[name]
        w2 = 2 * window_ns(window)
        if any(abs(r - g.lo) <= w2 for r in cam.no_info):
            return "no_camera_info"
        if any(abs(r - g.lo) <= w2 for r in cam.dropped):
            return "skipped"
        if cam.stopped:
            return "stopped"
        if any(abs(r - g.lo) <= w2 for r in cam.recent):
            return "apart"
        return "dropped"

    def restart(self) -> None:
        """A time reset: the rig frames open dropped (counted ``time_reset``), every camera's
        timeline started again."""
        for g in self.open:
            for n in g.frames:
                self._skip(n, "time_reset")
            self._skip("rig", "time_reset")
        self.open = []
        for cam in self.cams.values():
            cam.newest = cam.last_ref = None
            cam.recent.clear()
            cam.stopped = False
        self.last_closed = None

    def clock_offsets(self, name: str) -> dict:
        """Camera ``name``'s apparent clock offset against each other camera (other camera ->
        s): the median over its recent frames of its reference time minus the nearest
        reference time of that camera's recent frames (empty before frames of both). Stamps
        alone tell an offset only up to the cameras' frame period.

        Raises:
            KeyError: a camera not in the rig.
        """
        cam = self.cams[name]
        out = {}
        mine = np.array(cam.recent, dtype=np.int64)
        for m, other in self.cams.items():
            if m == name or not other.recent or not len(mine):
                continue
            theirs = np.array(other.recent, dtype=np.int64)
            diff = mine[:, None] - theirs[None, :]
            near = diff[np.arange(len(mine)), np.argmin(np.abs(diff), axis=1)]
            out[m] = float(np.median(near)) * 1e-9
        return out


def _frame_steps(recent) -> np.ndarray:
    """The positive intervals (ns) between a camera's recent frames' reference times."""
    steps = np.diff(np.sort(np.asarray(recent, dtype=np.int64)))
    return steps[steps > 0]


# ---------------------------------------------------------------------- agreement
class CameraAgreement:
    """The cameras' agreement with the rig: which disagree with it (their points outliers far
    more often than the others' over several rig frames: a mounting off, or wrong matches;
    :meth:`update`), which of them with one other camera alone (:meth:`partner`), whose frames
    are kept apart from the others' (each camera's ``apart``, :meth:`update_apart`: its clock
    or stamp offset likely wrong; its stamps are not shifted, stamps alone giving an offset
    only up to the frame period).

    Args:
        history: rig frames a camera's disagreement looks back over (``disagree_history``).
        frames: the rig's :class:`RigGrouping`: its cameras (in the rig's order; their
            agreement kept with them), their apparent clock offsets, and the counters
            (``<camera>.disagreements``, ``<camera>.apart``) and warnings of its localizer.
    """

    def __init__(self, history: int, frames: RigGrouping):
        self.cams = frames.cams
        for cam in self.cams.values():
            cam.flags = deque(maxlen=history)
        self.frames, self.counts, self.log = frames, frames.counts, frames.log

    def disagrees(self, name: str) -> bool:
        """Camera ``name`` disagrees with the rig, or is the partner of one that disagrees with
        it alone (:meth:`partner`)."""
        return self.cams[name].disagrees or self.partner(name) is not None

    def partner(self, name: str) -> str | None:
        """The other camera when ``name`` is one of two cameras that disagree with each other
        and no third camera tells which mounting is wrong (both are named), else None."""
        own = self.cams[name].partner  # (a camera's partner is set only while it disagrees)
        if own is not None:
            return own
        return next((n for n, c in self.cams.items() if c.partner == name), None)

    def update_apart(self, cameras: tuple, missing: dict, window: float) -> None:
        """Flag the cameras whose frames are kept apart from the others', given a rig frame's
        ``cameras`` and ``missing`` (camera -> a key of :data:`MISSED_REASONS`; ``window`` s):
        a camera missing as ``apart`` from a rig frame of others, or alone in one the others
        missed as ``apart``; named (a warning with its apparent clock offsets,
        :meth:`RigGrouping.clock_offsets`) in :data:`APART_SHARE` of its last
        :data:`APART_HISTORY`."""
        alone = len(cameras) == 1 and "apart" in missing.values()
        for n, cam in self.cams.items():
            if n not in cameras and missing.get(n) != "apart":
                continue
            cam.apart_flags.append(alone or n not in cameras)
            f = cam.apart_flags
            apart = len(f) >= APART_MIN and sum(f) >= APART_SHARE * len(f)
            if apart and not cam.apart:
                self.counts[f"{n}.apart"] += 1
                text = offsets_text(self.frames.clock_offsets(n))
                self.log.warning(
                    f"rig.apart.{n}",
                    f"rig camera {n!r}: its frames never join the others' (window "
                    f"{1e3 * window:.0f} ms): stamps {text} (median of nearest "
                    "stamps): its clock or stamp offset is likely wrong (a constant offset: "
                    f"set its time offset, rig.{n}.time_offset in the node); its frames are "
                    "posed alone only where the rig's track agrees",
                )
            elif cam.apart and not apart:
                self.log.info(f"rig camera {n!r} joins the others' rig frames again")
            cam.apart = apart

    def update(self, names: list, views: list, est: RSPoseEstimate, settings: Any,
               implementation: str | None = None) -> tuple:  # fmt: skip
        """Flag the cameras whose points fit the rig's pose far worse than the others': a rig
        frame's cameras ``names``, their ``views`` and the estimate ``est`` (each camera's
        points and inliers, ``num_valid_per_view`` and ``num_inliers_per_view``; a camera
        found to disagree is posed alone on ``implementation`` for its warning), the rule's
        ``settings`` (``disagree_ratio``, ``disagree_min_points``, ``disagree_frames``). The
        others' verdict names a camera alone when at least two other cameras with points stand
        against it: when its points are compared with one other camera's only, the two
        disagree and either mounting may be the wrong one (the camera with fewer points is
        outvoted by the one with more, not shown wrong), so both are named (:meth:`partner`).
        Returns the cameras that disagree now (rig order)."""
        s = settings
        n_pts, n_in = np.asarray(est.num_valid_per_view), np.asarray(est.num_inliers_per_view)
        strong = [j for j in range(len(names)) if int(n_pts[j]) >= s.disagree_min_points]
        for k, n in enumerate(names):
            cam = self.cams[n]
            pts = int(n_pts[k])
            others_pts = int(n_pts.sum()) - pts
            if min(pts, others_pts) < s.disagree_min_points:
                continue
            others = (int(n_in.sum()) - int(n_in[k])) / others_pts
            cam.flags.append(bool(n_in[k] / pts < s.disagree_ratio * others))
            was, was_partner = cam.disagrees, cam.partner
            cam.disagrees = sum(cam.flags) >= s.disagree_frames
            witnesses = [names[j] for j in strong if j != k]
            weak = [m for j, m in enumerate(names) if j != k and int(n_pts[j]) > 0]
            # (two cameras whose contradiction the rig's track decided: the outvoted one alone)
            decided = bool(est.success and est.disagreeing)
            single = len(witnesses) == 1 and len(weak) == 1 and not decided
            cam.partner = witnesses[0] if cam.disagrees and single else None
            if cam.disagrees and (not was or cam.partner != was_partner):
                self.counts[f"{n}.disagreements"] += 1
                deg = alone_deg(views[k], est, implementation)
                text = self._warning(n, cam.partner, int(n_in[k]), pts, others, deg)
                self.log.warning(f"rig.disagrees.{n}", text)
            elif was and not cam.disagrees:
                self.log.info(f"rig camera {n!r} agrees with the others again")
        return tuple(n for n in self.cams if self.disagrees(n))

    def _warning(self, n: str, p: str | None, fit: int, pts: int, others: float,
                 deg: float | None) -> str:  # fmt: skip
        """The warning that camera ``n`` disagrees with the others (``p``: with that one camera
        alone): ``fit`` of its ``pts`` points inliers of the rig's pose, ``others`` the others'
        inlier share, ``deg`` its rotation posed alone from where its mounting puts it."""
        alone = ""
        if deg is not None and p is None:
            alone = f"; alone it is {deg:.1f} deg from where its mounting puts it"
        elif deg is not None:
            alone = f"; alone {n!r} is {deg:.1f} deg from where the mountings put it "
            alone += f"relative to {p!r}"
        if p is None:
            return (
                f"rig camera {n!r} disagrees with the others: {fit} of its {pts} "
                f"points fit the rig's pose ({100 * others:.0f} % of the others')"
                f"{alone}: its mounting is likely wrong (or its matches are, or its "
                f"clock: its stamps are {offsets_text(self.frames.clock_offsets(n))})"
            )
        return (
            f"rig cameras {n!r} and {p!r} disagree: {fit} of the {pts} points "
            f"of {n!r} fit the rig's pose ({100 * others:.0f} % of those of {p!r}){alone}: "
            "the mounting of one of them is likely wrong (or its matches are); two "
            "cameras cannot tell which (the rig frames they disagree on are "
            "refused unless the rig's track tells): "
            "check both mountings, or let a third camera see the map"
        )  # fmt: skip


def offsets_text(offsets: Mapping[str, float], quoted: bool = True, unknown: str = "unknown"
                 ) -> str:  # fmt: skip
    """A camera's apparent clock offsets (other camera -> s, :meth:`RigGrouping.clock_offsets`)
    as a log line says them, ``+12.7 ms from 'front''s, ...``, or (``quoted`` False) as the
    node's diagnostics do, ``+12.7 ms from front, ...``; ``unknown`` without any."""
    name = "{!r}'s" if quoted else "{}"
    return (
        ", ".join(f"{1e3 * v:+.1f} ms from {name.format(m)}" for m, v in offsets.items()) or unknown
    )


def alone_deg(view: View, est: RSPoseEstimate, implementation: str | None = None) -> float | None:
    """deg between the camera's rotation posed alone (the single-camera estimator, on
    ``implementation``) and where the rig's pose and the camera's mounting put it; None when
    it is not posed alone (or the rig frame was not posed)."""
    if not est.success:
        return None
    try:
        alone = estimate_rs_pose(view.uv, view.X, view.camera, implementation=implementation)
    except Exception:
        return None
    if not alone.success:
        return None
    # the camera's rotation (world -> camera) at its reference time, as the rig puts it
    R_c = view.camera_model(est.model).R
    return float(rotation_angle_deg(alone.model.R, R_c))


# ---------------------------------------------------------------------- refusal
def refusal(
    est: RSPoseEstimate, cameras: tuple, frames: RigGrouping, prediction: FusedState | None
) -> str | None:
    """Why a rig frame of ``cameras`` posed (``est``) from one voting camera alone (the others'
    points disagreeing, absent or too few) while another camera of the rig runs (``frames``:
    the rig's cameras, stopped or not) is refused
    (:data:`~rs_localizer.estimation.result.RIG_REFUSALS`), or None: its pose contradicts the
    track's ``prediction`` (``contradicts_track``) and no camera too small to vote confirms it
    (at least :data:`CONFIRM_MIN_INLIERS` of its points inliers of the pose), or there is no
    prediction and two or more other cameras run (``unconfirmed``)."""
    valid = np.asarray(est.num_valid_per_view)
    voting = [k for k in range(len(valid)) if valid[k] >= VOTE_MIN_POINTS]
    posing = [k for k in voting if k not in est.disagreeing]
    if len(posing) > 1:
        return None
    mine = {cameras[k] for k in posing} or set(cameras)
    running = sum(not c.stopped and n not in mine for n, c in frames.cams.items())
    if running == 0:
        return None  # (the rig runs on this camera alone)
    if prediction is None:
        return UNCONFIRMED if running >= 2 else None
    inliers = np.asarray(est.num_inliers_per_view)
    if posing and any(
        valid[k] < VOTE_MIN_POINTS and inliers[k] >= CONFIRM_MIN_INLIERS for k in range(len(valid))
    ):
        return None  # (posed by two cameras: the prediction does not outvote them)
    return CONTRADICTS_TRACK if _contradicts(est, prediction) else None


def _contradicts(est: RSPoseEstimate, pred) -> bool:
    """The estimate's pose is further from the prediction than their covariances allow
    (:data:`CONTRADICTION_QUANTILE`, the squared Mahalanobis distance of
    :func:`~rs_localizer.accuracy.covariance_distances`) and at least
    :data:`CONTRADICTION_MIN_DEG` or :data:`CONTRADICTION_MIN_M` away (the rotation angle and
    the positions' distance of :func:`~rs_localizer.accuracy.absolute_pose_errors`)."""
    a, b = RSPose.from_model(est.model, 1.0), pred.pose
    poses = (a.orientation[None], a.position[None], b.orientation[None], b.position[None])
    err = absolute_pose_errors(*poses)
    if err["rot_deg"][0] < CONTRADICTION_MIN_DEG and err["pos_m"][0] < CONTRADICTION_MIN_M:
        return False
    S = np.asarray(pred.pose_covariance, float)
    if est.pose_covariance is not None and np.isfinite(est.pose_covariance).all():
        S = S + np.asarray(est.pose_covariance, float)
    # (NaN, a contradiction, when S is not positive definite)
    d2 = covariance_distances(*poses, S[None])[0]
    return not d2 <= float(chi2.ppf(CONTRADICTION_QUANTILE, 6))
