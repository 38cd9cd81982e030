"""Tracking a rolling-shutter camera through a video: predicted RANSAC, relocalization, resets,
and the fused twist.

Every frame of a video can be solved alone (:func:`estimate_rs_pose`), but the previous frames
predict the pose to a fraction of a degree. :class:`RSTracker` keeps a
:class:`~rs_localizer.tracking.fusion.TwistFilter` over the per-frame estimates and, for
each new frame:

1. predicts the pose and twist at the frame's time with the filter's motion model (constant
   velocity or acceleration);
2. hands the prediction to the estimator as an
   :class:`~rs_localizer.estimation.estimate.InitialModel`: it is tested on all points first
   (points within ``gate_px`` count as explained, MSAC within the threshold), seeds RANSAC, and
   its rotation pre-rotates every minimal sample instead of a P3P pose (paper sec. 4 and
   Fig. 6: the linear solvers need a rotation within a few degrees, not P3P's);
3. falls back to the cold estimator when the prediction explains too few points (a
   *relocalization*: a teleport, a lost track), and restarts everything on a stamp going back
   or a gap longer than ``max_gap`` (a *reset*: :func:`predictable`, the one rule of when a
   frame is predicted, also for the front end's search);
4. fuses the estimate into the filter (the fused twist, final ``lag`` frames later).

Each :class:`TrackResult` says which path the frame took: ``cold`` (no state: the first
frame), ``tracked``, ``relocalized`` or ``reset``. A failed frame changes nothing but the
counters: no state is made up for it, so a bad frame never becomes a pose or a twist.

Steps 1-4 are :class:`TrackerPath`, the one tracker path of a camera and of a rig
(:class:`~rs_localizer.tracking.video.Localizer`; a camera alone is a rig of one): only its
estimator (:class:`PathEstimator`) differs: :class:`FrameViews`, one camera's view (the
single-camera estimator) or a rig's views (the rig estimator).

:meth:`RSTracker.predict` gives the prediction of step 1 before the frame is estimated (the
same one: :class:`~rs_localizer.tracking.sequence.SequenceLocalizer` hands its model to the
image front end, which searches where it puts the map); without a tracker (tracking off, or
driving a front end by hand) :class:`CarriedPrediction` carries the last solved frame at its
own twist instead.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np

from ..camera import CameraModel
from ..estimation.estimate import EstimateOptions, InitialModel, RSPoseEstimate, estimate_rs_pose
from ..estimation.gyro import GyroMeasurement
from ..estimation.implementation import NUMPY, default_implementation
from ..estimation.prior import MotionPrior
from ..estimation.result import TOO_FEW_POINTS
from ..estimation.rig import estimate_rig_pose
from ..estimation.view import View
from ..frames import Mounting
from ..geometry import rotvec_to_matrix
from ..pose import RSModel
from ..solvers.registry import solver_info
from .fusion import FusedState, FusionOptions, FusionStep, TwistFilter

__all__ = [
    "STATES",
    "CarriedPrediction",
    "FrameViews",
    "PathEstimator",
    "PathFrame",
    "RSTracker",
    "Solve",
    "TrackResult",
    "TrackerOptions",
    "TrackerPath",
    "carried_model",
    "frame_inlier_ratio",
    "model_from_state",
    "motion_prior_from_state",
    "predictable",
]

#: the paths a frame can take
STATES = ("cold", "tracked", "relocalized", "reset")

#: a camera's own frame: its view's mounting (:class:`FrameViews` of a camera does not read it)
_OWN_FRAME = Mounting(np.eye(3), np.zeros(3))


@dataclass(frozen=True)
class TrackerOptions:
    """Parameters of :class:`RSTracker`.

    Attributes:
        gate_px: a point is explained by the prediction if it reprojects within this many
            pixels of it (the prediction of a hand-held camera is off by ~2-15 px at 30 fps),
            or within ``gate_sigmas`` standard deviations of the predicted rotation (in pixels:
            times the focal length) when that is larger, up to ``max_gate_px`` (a prediction
            over dropped frames or just after a restart is less certain).
        min_explained_ratio: the prediction is used if it explains at least this fraction of
            the points the previous frame's inlier ratio promises (and at least
            ``min_inliers``); otherwise the frame relocalizes (cold estimator).
        max_gap: seconds; a longer gap between frames, or a stamp going back, resets the
            tracker (a prediction over that long is not trusted; :func:`predictable`).
            :class:`~rs_localizer.tracking.sequence.SequenceLocalizer` applies the same gap
            to everything it predicts or pairs across frames
            (:attr:`~rs_localizer.tracking.sequence.SequenceSettings.max_gap`).
        tracked_options: :class:`EstimateOptions` for tracked frames (``None``: the tracker's
            estimator options with ``min_iterations = tracked_min_iterations``).
        tracked_min_iterations: RANSAC's minimum number of samples on tracked frames (the
            prediction is a hypothesis already; adaptive termination still runs).
        tracked_max_iterations: RANSAC's maximum number of samples on tracked frames; None:
            a camera's estimator options' own (``ransac.max_iterations``; also a rig of one
            camera's), a rig's :data:`~rs_localizer.tracking.video.RIG_TRACKED_MAX_ITERATIONS`.
        prior_from_prediction: when the estimator's motion prior is the predicted twist with
            its covariance (:func:`motion_prior_from_state`) instead of the estimator options'
            own prior: ``"planar"`` (default: on tracked frames when the previous frame's
            inliers were coplanar, where it resolves the rotation/velocity trade-off of the
            per-frame RS model; on a synthetic wall it cut the rotation error from
            0.29 to 0.05 deg), ``"always"`` (every tracked frame; on 3D scenes the pose moves
            by a few percent and the frame costs ~0.1 ms more) or ``"never"``. The filter takes
            the prior's information out again before fusing.
        prior_inflation: the predicted twist covariance is multiplied by this for the prior.
        fusion: :class:`~rs_localizer.tracking.fusion.FusionOptions` of the filter (its
            ``max_gap`` is set to the tracker's).

    The options of a camera's tracker and of a rig's
    (:attr:`~rs_localizer.tracking.video.LocalizerSettings.tracking`); the rig estimator takes no
    motion prior and verifies its prediction with its own minimum of samples, so a rig of
    several cameras reads all of them but ``tracked_options``, ``tracked_min_iterations``,
    ``prior_from_prediction`` and ``prior_inflation`` (a rig of one camera, solved as the
    camera, reads them all: :attr:`~rs_localizer.tracking.video.LocalizerSettings.single_camera`).
    """

    gate_px: float = 20.0
    gate_sigmas: float = 3.0
    max_gate_px: float = 200.0
    min_explained_ratio: float = 0.5
    max_gap: float = 0.5
    tracked_options: EstimateOptions | None = None
    tracked_min_iterations: int = 16
    tracked_max_iterations: int | None = None
    prior_from_prediction: str = "planar"
    prior_inflation: float = 1.0
    fusion: FusionOptions = field(default_factory=FusionOptions)

    def __post_init__(self):
        if not (np.isfinite(self.gate_px) and self.gate_px > 0):
            raise ValueError(f"gate_px must be > 0, got {self.gate_px}")
        if not (self.gate_sigmas >= 0 and self.max_gate_px >= self.gate_px):
            raise ValueError("need gate_sigmas >= 0 and max_gate_px >= gate_px")
        if not (0.0 <= self.min_explained_ratio <= 1.0):
            raise ValueError(
                f"min_explained_ratio must be in [0, 1], got {self.min_explained_ratio}"
            )
        if not (np.isfinite(self.max_gap) and self.max_gap > 0):
            raise ValueError(f"max_gap must be > 0, got {self.max_gap}")
        if self.tracked_min_iterations < 0:
            raise ValueError("tracked_min_iterations must be >= 0")
        if self.tracked_max_iterations is not None and self.tracked_max_iterations < 1:
            raise ValueError("tracked_max_iterations must be >= 1 (or None)")
        if self.prior_from_prediction not in ("planar", "always", "never"):
            raise ValueError(
                f"prior_from_prediction must be planar, always or never, got "
                f"{self.prior_from_prediction!r}"
            )


@dataclass(frozen=True)
class TrackResult:
    """One frame through :meth:`RSTracker.process`.

    Attributes:
        estimate: the per-frame :class:`RSPoseEstimate` (pose, in-frame twist, covariances),
            as :func:`estimate_rs_pose` returns it; ``success=False`` for a bad frame.
        state: ``cold``, ``tracked``, ``relocalized`` or ``reset`` (see :data:`STATES`).
        fused: the filter's causal state at this frame (``None`` if the frame failed or the
            filter has no state; computed on first access).
        final: fused states that became final with this frame, oldest first (the frame
            ``lag`` frames back; on a reset, the frames still pending). Each is a
            :class:`~rs_localizer.tracking.fusion.FusedState` whose ``stamp_ns`` names its
            frame.
        predicted: the prediction used (``None`` on cold and reset frames).
        explained: points the prediction explained (-1 without a prediction).
    """

    estimate: RSPoseEstimate
    state: str
    step: object = field(default=None, repr=False)  # the filter's FusionStep (lazy ``fused``)
    final: list = field(default_factory=list)
    predicted: FusedState | None = None
    explained: int = -1

    @property
    def fused(self) -> FusedState | None:
        return None if self.step is None else self.step.current


def predictable(last_ns: int | None, stamp_ns: int, max_gap: float) -> bool:
    """Whether a frame at ``stamp_ns`` (ns) is predicted from the last solved frame at
    ``last_ns`` (ns; None: none yet): it is later, by at most ``max_gap`` s. A stamp going
    back (a bag replayed again), the same stamp again, or a longer gap (frames lost, a
    stalled camera) starts a new track: the tracker resets, and the front end is given no
    prediction (it searches the image whole). The one rule of the tracker and of
    :class:`~rs_localizer.tracking.sequence.SequenceLocalizer`'s prediction."""
    return last_ns is not None and stamp_ns > last_ns and (stamp_ns - last_ns) * 1e-9 <= max_gap


def carried_model(model: RSModel, dt: float, seconds_per_unit_r: float) -> RSModel:
    """A solved frame's model ``(R, C, w, t)`` carried ``dt`` s later at its own constant
    twist (``w``, ``t`` per unit RS coordinate, ``seconds_per_unit_r`` s each): ``R' =
    exp([dT w]x) R``, ``C' = C + dT t`` with ``dT = dt / seconds_per_unit_r``, the twist
    kept. Shapes (3, 3), (3,), (3,), (3,). Requires ``seconds_per_unit_r > 0`` (a global
    shutter's model has no twist to carry: the model is returned as it is)."""
    R, C, w, t = model
    if seconds_per_unit_r <= 0:
        return RSModel(R, C, w, t)
    dT = dt / seconds_per_unit_r
    return RSModel(rotvec_to_matrix(dT * w) @ R, C + dT * t, w, t)


class CarriedPrediction:
    """The prediction without a tracker: the last solved frame's model carried to the new
    frame's time at its own twist (:func:`carried_model`), under the tracker's time rule
    (:func:`predictable`). What
    :class:`~rs_localizer.tracking.sequence.SequenceLocalizer` gives its front end when
    no tracker predicts (tracking off, or no tracker state yet), and what a caller driving
    a front end by hand passes as its ``prediction``::

        carry = CarriedPrediction()
        for stamp, image in video:
            c = frontend.process(image, camera, "rgb8", carry.predict(stamp, camera))
            est = estimate_rs_pose(c.points2d, c.points, camera)
            frontend.observe(stamp, None, est)  # (the estimate: its FrameFeedback)
            carry.update(stamp, est)

    Args:
        max_gap: s; no prediction over a longer gap (:func:`predictable`).
    """

    def __init__(self, max_gap: float = TrackerOptions.max_gap):
        self.max_gap = float(max_gap)
        self.reset()

    def reset(self) -> None:
        """Forget the last solved frame (the next frame has no prediction)."""
        self.stamp_ns: int | None = None
        self.model: RSModel | None = None

    def update(self, stamp_ns: int, estimate: RSPoseEstimate | None) -> None:
        """Note a frame's estimate (``stamp_ns`` ns, the time ``predict`` is asked at): a
        solved one (``success``, ``model``) is the one carried from now on; a failed one (or
        None) changes nothing (the last solved frame is still carried)."""
        if estimate is not None and estimate.success:
            self.stamp_ns, self.model = int(stamp_ns), estimate.model

    def carried(self, stamp_ns: int) -> tuple[RSModel, float] | None:
        """The last solved frame's model as it was estimated and the time (s) from it to
        ``stamp_ns`` (ns), for a caller that carries it itself (a rig's, through a camera's
        mounting); None without a solved frame or when :func:`predictable` says the frame
        starts a new track."""
        if self.model is None or not predictable(self.stamp_ns, int(stamp_ns), self.max_gap):
            return None
        return self.model, (int(stamp_ns) - self.stamp_ns) * 1e-9

    def predict(self, stamp_ns: int, camera: CameraModel) -> RSModel | None:
        """The model (:class:`~rs_localizer.pose.RSModel`) of a frame at ``stamp_ns`` (ns)
        seen by ``camera``; None without a solved frame or when :func:`predictable` says
        the frame starts a new track."""
        c = self.carried(stamp_ns)
        return None if c is None else carried_model(c[0], c[1], camera.seconds_per_unit_r)


def model_from_state(state: FusedState, camera: CameraModel) -> RSModel:
    """The estimator's model ``(R, C, w, t)`` (:class:`~rs_localizer.pose.RSModel`) of a fused
    state: its pose's :meth:`~rs_localizer.pose.RSPose.model` with the camera's seconds per
    unit RS coordinate (the inverse of
    :func:`~rs_localizer.estimation.estimate.physical_velocities`; w = t = 0 for a global
    shutter). Shapes (3, 3), (3,), (3,), (3,)."""
    return state.pose.model(camera.seconds_per_unit_r)


def frame_inlier_ratio(estimate: RSPoseEstimate, num_rows: int) -> float:
    """A solved frame's inlier ratio as the tracker keeps it for the next frame's gate
    (:func:`predicted_initial_model`): its inliers over the ``num_rows`` rows it was given."""
    return estimate.num_inliers / max(num_rows, 1)


def predicted_initial_model(
    model: RSModel,
    predicted: FusedState,
    focal: float,
    num_points: int,
    inlier_ratio: float | None,
    min_inliers: int,
    options: TrackerOptions,
) -> InitialModel:
    """The track's prediction as the estimator's initial model
    (:class:`~rs_localizer.estimation.InitialModel`), the one rule of a camera's tracker and a
    rig's: ``model`` (the predicted state's, ``predicted``) explains a point within ``gate_px``
    px, or ``gate_sigmas`` standard deviations of the predicted rotation times ``focal`` (px)
    when larger, up to ``max_gate_px``; it is used when it explains at least
    ``min_explained_ratio`` of the ``num_points`` the previous frame's ``inlier_ratio``
    (None: none yet) promises, and at least ``min_inliers`` (the fields of ``options``, a
    camera's or a rig's :class:`TrackerOptions`)."""
    ratio = inlier_ratio if inlier_ratio is not None else 0.0
    need = max(min_inliers, int(options.min_explained_ratio * ratio * num_points))
    sigma_rot = float(np.sqrt(np.trace(predicted.covariance[:3, :3])))  # (>= largest)
    gate = min(max(options.gate_px, options.gate_sigmas * sigma_rot * focal), options.max_gate_px)
    return InitialModel(model, gate, need)


def motion_prior_from_state(state: FusedState, inflation: float = 1.0) -> MotionPrior:
    """The predicted twist as the estimator's motion prior: a
    :class:`~rs_localizer.estimation.prior.MotionPrior` with the state's linear and angular
    velocity (ROS twist order vx, vy, vz, wx, wy, wz; camera frame) as mean, its twist
    covariance times ``inflation`` as covariance, used on every frame (``always``)."""
    mean = np.concatenate([state.pose.linear_velocity, state.pose.angular_velocity])
    cov = np.asarray(state.twist_covariance, dtype=float) * float(inflation)
    return MotionPrior(mean=mean, covariance=0.5 * (cov + cov.T), always=True)


def _with_sensitivity(options: EstimateOptions) -> EstimateOptions:
    """``options`` with the acceleration sensitivity on (the filter models the estimate's error
    from acceleration during the readout)."""
    return replace(options, refine=replace(options.refine, acceleration_sensitivity=True))


@dataclass(frozen=True)
class Solve:
    """One solve of a frame by a :class:`PathEstimator`.

    Attributes:
        estimate: the estimator's result, a camera's or a rig's
            :class:`~rs_localizer.estimation.result.RSPoseEstimate`.
        prior: the options' :class:`~rs_localizer.estimation.prior.MotionPrior` the
            estimate's refinement holds (a camera's maximum a posteriori one; a rig's holds
            the gyro's rate alone), None: none (the twist filter takes its information out
            again).
        prior_from_prediction: the estimator was given the prediction's twist as its motion
            prior: when the prediction does not hold the frame is solved again without it.
    """

    estimate: RSPoseEstimate
    prior: MotionPrior | None = None
    prior_from_prediction: bool = False


class PathEstimator(Protocol):
    """One frame's estimator on the tracker path (:meth:`TrackerPath.solve`), the one part
    that differs between a camera and a rig: :class:`FrameViews`, a camera's view
    (:class:`RSTracker`) or a rig's views (:class:`~rs_localizer.tracking.video.Localizer`).

    Attributes:
        focal: px, the focal length of the prediction's gate (:func:`predicted_initial_model`).
        num_points: the frame's points (all views). min_inliers: the estimator's.
    """

    focal: float
    num_points: int
    min_inliers: int

    def ended(self, final: list) -> None:
        """The track ended by the time rule (:func:`predictable`) before the frame: its fused
        states not yet final (oldest first), handed on before the frame is solved."""

    def model(self, predicted: FusedState) -> RSModel:
        """The estimator's model ``(R, C, w, t)`` of the predicted state."""

    def cold(self) -> Solve:
        """The frame solved without a prediction (a track's first frame)."""

    def tracked(self, initial: InitialModel, predicted: FusedState) -> Solve:
        """The frame solved from the prediction: ``initial`` the estimator's initial model."""

    def relocalize(self, model: RSModel, predicted: FusedState) -> Solve:
        """The frame solved again when the prediction did not hold (``model``: the
        prediction's, at most a tie-breaker)."""


@dataclass(frozen=True)
class PathFrame:
    """A frame through :meth:`TrackerPath.solve`: ``estimate`` (the last solve's), ``path``
    (:data:`STATES`), ``predicted`` (the prediction used, None on cold and reset frames),
    ``explained`` (points the prediction explained, -1 without one) and ``prior`` (the motion
    prior the estimate's refinement used, for :meth:`TrackerPath.update`)."""

    estimate: RSPoseEstimate
    path: str
    predicted: FusedState | None = None
    explained: int = -1
    prior: MotionPrior | None = None


class TrackerPath:
    """The tracker path of a video of one camera or a rig (a camera alone is a rig of one):
    the time rule, the prediction, the path decision, the twist filter and the counters; only
    the estimator (:class:`PathEstimator`) differs. Per frame: :meth:`solve`, then
    :meth:`update` with the estimate the caller keeps.

    1. **time rule**: a frame not :func:`predictable` from the last solved frame (a longer gap
       than ``max_gap``, a stamp going back) ends the track (``reset``; the track's fused
       states not yet final go to :meth:`PathEstimator.ended`);
    2. no filter state: solved ``cold``;
    3. else the filter predicts the frame; :func:`predicted_initial_model` is the estimator's
       initial model; ``tracked`` when the estimate succeeded from it, else ``relocalized``:
       solved again (:meth:`PathEstimator.relocalize`) when the estimator leaned on the
       prediction's twist or failed for another reason than too few points;
    4. :meth:`update`: a solved frame is fused (``relocalized=``: its measurement may restart
       the filter) and its inlier ratio kept for the next frame's gate.

    Args:
        options: a camera's or a rig's :class:`TrackerOptions` (``max_gap``, ``fusion``
            and the gate's fields).

    Attributes:
        filter: the :class:`~rs_localizer.tracking.fusion.TwistFilter` (its ``max_gap`` the
            options'). inlier_ratio: the last solved frame's (None: none in this track).
        last_ns: ns, the last solved frame's time (None: none in this track).

    Counters: ``frames`` (solved or not), ``frames_tracked``, ``relocalizations``, ``resets``,
    ``failures`` (frames whose estimate failed).
    """

    def __init__(self, options: TrackerOptions):
        self.path_options = options
        self.filter = TwistFilter(replace(options.fusion, max_gap=options.max_gap))
        self.frames = self.frames_tracked = self.relocalizations = self.resets = 0
        self.failures = 0
        self.inlier_ratio: float | None = None
        self.last_ns: int | None = None
        self._predicted: FusedState | None = None  # (predict's last answer, until an update)

    @property
    def track_state(self) -> str:
        """``tracking`` (a prediction is available for the next frame) or ``lost``."""
        return "tracking" if self.filter.initialized else "lost"

    def track_counts(self) -> dict[str, int]:
        """The counters a video keeps over its tracks: ``frames_tracked``,
        ``relocalizations``, ``resets``."""
        return {
            "frames_tracked": self.frames_tracked,
            "relocalizations": self.relocalizations,
            "resets": self.resets,
        }

    def reset(self) -> list:
        """Forget the track. Returns the fused states not yet final, as they are (oldest
        first)."""
        out = self.filter.flush()
        self.filter.reset()
        self.inlier_ratio = None
        self.last_ns = None
        self._predicted = None
        return out

    def flush(self) -> list:
        """The fused states not yet final (oldest first, e.g. at the end of a video); they
        are not returned again and the track goes on."""
        return self.filter.flush()

    def predicts(self, stamp_ns: int) -> bool:
        """Whether a frame at ``stamp_ns`` (ns) is predicted: the filter has a state and the
        frame is :func:`predictable` from the last solved frame."""
        return self.filter.initialized and predictable(
            self.last_ns, int(stamp_ns), self.path_options.max_gap
        )

    def predict(self, stamp_ns: int, implementation: str | None = None) -> FusedState | None:
        """The filter's prediction of the state at ``stamp_ns`` (ns; computed once until the
        next update), None when the frame is not predicted (:meth:`predicts`).
        ``implementation``: the estimator's for the frame (on ``"numpy"`` the filter's steps
        run as plain Python: nothing compiles); None: the filter's kernels as they are."""
        if implementation is not None:
            self.filter.compiled = implementation != NUMPY
        return self._predict_at(stamp_ns)

    def _predict_at(self, stamp_ns: int) -> FusedState | None:
        """:meth:`predict` with the filter's kernels as they are set (a subclass's ``predict``
        may set them first)."""
        stamp_ns = int(stamp_ns)
        if not self.predicts(stamp_ns):
            return None
        p = self._predicted
        if p is None or p.pose.stamp_ns != stamp_ns:
            p = self._predicted = self.filter.predict(stamp_ns)
        return p

    def solve(self, stamp_ns: int, estimator: PathEstimator) -> PathFrame:
        """A frame at ``stamp_ns`` (ns) on the path (class docstring, steps 1-3).

        Raises:
            whatever the estimator raises (the frame counted, a reset done).
        """
        stamp_ns = int(stamp_ns)
        self.frames += 1
        path = "cold"
        if self.last_ns is not None and not predictable(
            self.last_ns, stamp_ns, self.path_options.max_gap
        ):
            estimator.ended(self.reset())
            path = "reset"
            self.resets += 1
        predicted = self._predict_at(stamp_ns)
        if predicted is None:
            s = estimator.cold()
            return PathFrame(s.estimate, path, None, -1, s.prior)
        model = estimator.model(predicted)
        initial = predicted_initial_model(
            model, predicted, estimator.focal, estimator.num_points, self.inlier_ratio,
            estimator.min_inliers, self.path_options,
        )  # fmt: skip
        s = estimator.tracked(initial, predicted)
        est, explained = s.estimate, s.estimate.initial_explained
        if est.success and est.initial_used:
            return PathFrame(est, "tracked", predicted, explained, s.prior)
        if s.prior_from_prediction or (not est.success and est.failure != TOO_FEW_POINTS):
            # the prediction does not hold (its twist must not be the prior), or it misled
            # RANSAC on a bad frame: solve the frame again
            s = estimator.relocalize(model, predicted)
        return PathFrame(s.estimate, "relocalized", predicted, explained, s.prior)

    def track(
        self,
        stamp_ns: int,
        estimator: FrameViews,
        judge: Callable[[PathFrame], PathFrame] | None = None,
    ) -> TrackResult:
        """One frame through the track: :meth:`solve` with ``estimator``, then :meth:`update`
        with the estimate kept (``judge``: the caller's last word on the solved frame, e.g. a
        rig's refusal of a pose it cannot stand behind; None: the estimate as solved), its
        inlier ratio over the rows given (:func:`frame_inlier_ratio` of
        ``estimator.num_points``) and the motion prior its refinement used. The one use of the
        tracker path, a camera's (:meth:`RSTracker.process`) and a rig's
        (:class:`~rs_localizer.tracking.video.Localizer`).

        Returns:
            :class:`TrackResult` (``final``: the states of a track ended before the frame,
            ``estimator.final``, then those the frame made final).
        Raises:
            whatever the estimator raises (as :meth:`solve`).
        """
        f = self.solve(stamp_ns, estimator)
        if judge is not None:
            f = judge(f)
        est = f.estimate
        if not est.success:
            self.update(stamp_ns, est, f.path)
            return TrackResult(est, f.path, None, estimator.final, f.predicted, f.explained)
        ratio = frame_inlier_ratio(est, estimator.num_points)
        step = self.update(stamp_ns, est, f.path, ratio, f.prior)
        return TrackResult(
            est, f.path, step, estimator.final + step.final, f.predicted, f.explained
        )

    def update(
        self,
        stamp_ns: int,
        estimate: RSPoseEstimate,
        path: str,
        inlier_ratio: float = 0.0,
        prior: MotionPrior | None = None,
    ) -> FusionStep | None:
        """The frame's estimate (the one the caller keeps) on its ``path``: a failed one is
        counted and changes nothing else (None); a solved one is counted by its path, fused
        into the filter (``relocalized``: its measurement may restart the filter; ``prior``:
        the motion prior its refinement used) and its ``inlier_ratio`` (inliers / points)
        kept. Returns the filter's :class:`~rs_localizer.tracking.fusion.FusionStep`."""
        if not estimate.success:
            self.failures += 1
            return None
        if path == "tracked":
            self.frames_tracked += 1
        elif path == "relocalized":
            self.relocalizations += 1
        stamp_ns = int(stamp_ns)
        self.last_ns = stamp_ns
        self.inlier_ratio = inlier_ratio
        self._predicted = None
        return self.filter.update(
            stamp_ns, estimate, relocalized=path == "relocalized", prior=prior
        )


class RSTracker(TrackerPath):
    """Track a rolling-shutter camera through a video (see the module docstring): the
    :class:`TrackerPath` with one camera's estimator (:func:`estimate_rs_pose`).

    Args:
        solver: estimator solver name (as :func:`estimate_rs_pose`).
        options: :class:`EstimateOptions` of cold frames (and of tracked frames unless
            ``tracker_options.tracked_options`` is given); ``acceleration_sensitivity`` is
            switched on (the filter uses it).
        tracker_options: :class:`TrackerOptions`.

    Counters: ``frames``, ``frames_tracked``, ``relocalizations``, ``resets``, ``failures``.
    """

    def __init__(
        self,
        solver: str = "r6p_1lin",
        options: EstimateOptions | None = None,
        tracker_options: TrackerOptions | None = None,
    ):
        self.solver = solver
        self.options = _with_sensitivity(options or EstimateOptions())
        self.tracker_options = to = tracker_options or TrackerOptions()
        cold = self.options.ransac
        self.tracked_options = _with_sensitivity(
            to.tracked_options
            or replace(
                self.options,
                ransac=replace(
                    cold,
                    min_iterations=min(cold.min_iterations, to.tracked_min_iterations),
                    max_iterations=to.tracked_max_iterations or cold.max_iterations,
                ),
            )
        )
        super().__init__(to)
        self._planar = False  # (the last solved frame's inliers were coplanar)

    def reset(self) -> list:
        """Forget the track (e.g. the solver or the camera changed). Returns the fused states
        not yet final, as they are (oldest first)."""
        self._planar = False
        return super().reset()

    def predict(self, stamp_ns: int, implementation: str | None = None) -> FusedState | None:
        """The filter's prediction of the pose and twist at ``stamp_ns`` (ns, the time
        :meth:`process` will be given): the one :meth:`process` then tests, seeds RANSAC with
        and takes the motion prior from (computed once). None when :meth:`process` will not
        predict the frame: no track yet, or it starts a new one (:func:`predictable`). Its
        model for a camera: :func:`model_from_state`. ``implementation``: as
        :meth:`process`'s (on ``"numpy"`` the filter compiles nothing either)."""
        self._implementation(implementation)
        return super().predict(stamp_ns)

    def process(
        self,
        stamp_ns: int,
        points2d: np.ndarray,
        points3d: np.ndarray,
        camera: CameraModel,
        scores: np.ndarray | None = None,
        *,
        gyro: GyroMeasurement | None = None,
        implementation: str | None = None,
        groups: np.ndarray | None = None,
    ) -> TrackResult:
        """Estimate one frame and update the track.

        Args:
            stamp_ns: the frame's time (ns). Any constant offset from the reference row's
                capture time is fine (e.g. the header stamp of row 0).
            points2d (N, 2), points3d (N, 3), camera, scores (N,) or None: as
                :func:`estimate_rs_pose`. The camera must not change without :meth:`reset`.
            gyro: optional gyro measurement of the frame's readout, passed to
                :func:`estimate_rs_pose` (it adds to the prediction's motion prior; the filter
                removes only the prior, so the gyro's information stays in the frame's twist).
            implementation: the estimator's implementation for this frame (``"compiled"``,
                ``"numpy"`` or None, as :func:`estimate_rs_pose`'s; on ``"numpy"`` the twist
                filter's steps run as plain Python too: nothing compiles): the prediction,
                the gyro and the filter are the same on either, so a track goes on across a
                switch.
            groups: (N,) int each point's group (one marker's corners: the marker's id), or
                None: as :func:`estimate_rs_pose`'s (the covariance includes the image error
                a group's points share; the estimate is the same).
        Returns:
            :class:`TrackResult`.
        Raises:
            ValueError: as :func:`estimate_rs_pose` (array shapes, unknown solver, groups
                that are not (N,) integers).
        """
        return self.track(
            stamp_ns,
            self.frame_views(points2d, points3d, camera, scores, gyro, implementation, groups),
        )

    def frame_views(
        self,
        points2d: np.ndarray,
        points3d: np.ndarray,
        camera: CameraModel,
        scores: np.ndarray | None = None,
        gyro: GyroMeasurement | None = None,
        implementation: str | None = None,
        groups: np.ndarray | None = None,
    ) -> FrameViews:
        """A camera's frame as the estimator of :meth:`~TrackerPath.track` (:meth:`process`'s
        arguments; ``groups`` its view's :attr:`~rs_localizer.estimation.view.View.groups`):
        its one view solved with the tracker's solver, options and tracked
        options (the prediction's twist as the tracked solve's motion prior where
        ``prior_from_prediction`` asks for it, a rolling shutter's); the twist filter's
        kernels set for ``implementation``."""
        self._implementation(implementation)
        to = self.tracker_options
        # (the prediction's twist as the motion prior: a rolling shutter's, where asked)
        prior = to.prior_from_prediction == "always" or (
            to.prior_from_prediction == "planar" and self._planar
        )
        return FrameViews(
            (View(points2d, points3d, camera, _OWN_FRAME, groups=groups),), self.options,
            self.tracked_options, solver=self.solver, scores=scores, gyro=gyro,
            implementation=implementation,
            prior_inflation=to.prior_inflation if prior and camera.seconds_per_unit_r > 0 else None,
        )  # fmt: skip

    def update(
        self,
        stamp_ns: int,
        estimate: RSPoseEstimate,
        path: str,
        inlier_ratio: float = 0.0,
        prior: MotionPrior | None = None,
    ) -> FusionStep | None:
        """:meth:`TrackerPath.update`; a solved frame's ``planar`` also decides whether the
        next frame takes the prediction's twist as its motion prior (``prior_from_prediction``
        ``"planar"``)."""
        if estimate.success:
            self._planar = bool(estimate.planar)
        return super().update(stamp_ns, estimate, path, inlier_ratio, prior)

    def _implementation(self, implementation: str | None) -> None:
        """The twist filter's kernels for ``implementation`` (the estimator's, None: its
        default for the solver): plain Python on ``"numpy"``
        (:attr:`~rs_localizer.tracking.fusion.TwistFilter.compiled`)."""
        if implementation is None:
            implementation = default_implementation(self.solver)
        self.filter.compiled = implementation != NUMPY


class FrameViews:
    """A frame's views as the tracker path's estimator (:class:`PathEstimator`), the one of a
    camera and of a rig (a camera alone is a rig of one view): a camera's own view is solved
    by the single-camera estimator (:func:`estimate_rs_pose` with its ``solver``; its model
    per unit RS coordinate, :func:`model_from_state`), a rig's views by the rig estimator
    (:func:`~rs_localizer.estimation.rig.estimate_rig_pose`; its model per second at the rig
    frame's time). Cold with ``options`` (a rig's with every camera also posed alone,
    ``verify_cameras``: no track checks them); tracked from the prediction with
    ``tracked_options`` (a camera's with the prediction's twist as its motion prior when
    ``prior_inflation`` is given); relocalized, when the prediction did not hold, with
    ``options`` again (a rig's with the prediction deciding between cameras that contradict
    each other; a camera has none to decide between: solved cold).

    Args:
        views: the frame's :class:`~rs_localizer.estimation.view.View`\\ s: a camera's
            one (its mounting and stamp offset unused; its ``groups`` given to
            :func:`estimate_rs_pose`) or a rig's.
        options, tracked_options: the estimator's
            :class:`~rs_localizer.estimation.options.EstimateOptions` of cold (and
            relocalized) solves and of tracked ones.
        solver: a camera's minimal solver (its one view solved by :func:`estimate_rs_pose`);
            None: a rig's views.
        scores: (N,) a camera's points' scores, or None. gyro: the frame's gyro measurement
            (a rig's in the rig frame, its window's middle ``gyro_time`` s after the rig
            frame's time), or None. implementation: the estimator's (None: its default).
        prior_inflation: a camera's tracked solve takes the prediction's twist as its motion
            prior (:func:`motion_prior_from_state`, its covariance times this); None: the
            options' own prior.
        ended: called with the fused states of a track ended before the frame (also kept,
            ``final``).
    """

    def __init__(
        self,
        views: Sequence[View],
        options: EstimateOptions,
        tracked_options: EstimateOptions,
        *,
        solver: str | None = None,
        scores: np.ndarray | None = None,
        gyro: GyroMeasurement | None = None,
        gyro_time: float | None = None,
        implementation: str | None = None,
        prior_inflation: float | None = None,
        ended: Callable[[list], Any] | None = None,
    ):
        self.views, self.options, self.tracked_options = views, options, tracked_options
        self.solver, self.scores, self.gyro, self.gyro_time = solver, scores, gyro, gyro_time
        self.implementation, self.prior_inflation = implementation, prior_inflation
        self._ended = ended
        self.focal = max(v.camera.mean_focal for v in views)
        self.num_points = sum(len(v.uv) for v in views)
        self.min_inliers = options.ransac.min_inliers
        # (the model's time unit: a camera's unit RS coordinate, a rig's second)
        self.seconds_per_unit = 1.0 if solver is None else views[0].camera.seconds_per_unit_r
        self.final: list = []

    @property
    def measures_twist(self) -> bool:
        """The frame's estimate measures a twist for the track to fuse (its fused twist, not
        its own, is then its final one): a rolling-shutter estimator's with readout time, the
        rig estimator's (its model per second, across its cameras' readouts and stamps; a rig
        frame at one instant fused as its pose) or a rolling-shutter solver's on a camera with
        readout time; not a global-shutter solver's nor a camera's taken at one instant."""
        rolling = self.solver is None or solver_info(self.solver).rolling
        return rolling and self.seconds_per_unit > 0

    def ended(self, final: list) -> None:
        self.final = final
        if self._ended is not None:
            self._ended(final)

    def model(self, predicted: FusedState) -> RSModel:
        return predicted.pose.model(self.seconds_per_unit)

    def cold(self) -> Solve:
        return self._solve(self.options)

    def tracked(self, initial: InitialModel, predicted: FusedState) -> Solve:
        opts = self.tracked_options
        if self.prior_inflation is not None:
            # (a covariance that is not positive definite keeps the options' prior)
            with contextlib.suppress(ValueError):
                prior = motion_prior_from_state(predicted, self.prior_inflation)
                opts = replace(opts, motion_prior=prior)
        return self._solve(opts, initial, None, opts is not self.tracked_options)

    def relocalize(self, model: RSModel, predicted: FusedState) -> Solve:
        return self._solve(self.options, None, model)

    def _solve(
        self,
        options: EstimateOptions,
        initial: InitialModel | None = None,
        prediction: RSModel | None = None,
        prior_from_prediction: bool = False,
    ) -> Solve:
        """The frame solved with ``options`` from the ``initial`` model or the
        ``prediction`` (a rig's tie-breaker), with the options' motion prior where its
        refinement used it: a camera's maximum a posteriori refinement holds it (with a gyro,
        with the gyro's rate), a rig's holds the gyro's rate alone (the rig estimator takes no
        motion prior), which the filter keeps as a camera's."""
        if self.solver is not None:  # (a camera's own view)
            v = self.views[0]
            est = estimate_rs_pose(
                v.uv, v.X, v.camera, self.solver, options, scores=self.scores, gyro=self.gyro,
                implementation=self.implementation, initial_model=initial, groups=v.groups,
            )  # fmt: skip
        else:
            est = estimate_rig_pose(
                self.views, options, initial_model=initial, gyro=self.gyro,
                gyro_time=self.gyro_time, prediction=prediction,
                verify_cameras=initial is None and prediction is None,
                implementation=self.implementation,
            )  # fmt: skip
        own = self.solver is not None and est.motion_prior_used
        return Solve(est, options.motion_prior if own else None, prior_from_prediction)
