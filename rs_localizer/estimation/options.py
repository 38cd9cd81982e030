"""Options of :func:`~rs_localizer.estimation.estimate_rs_pose`, grouped by concern, and its
optional input :class:`InitialModel`.

``EstimateOptions()`` is the estimator's default; change one concern at a time, e.g.
``EstimateOptions(ransac=RansacOptions(threshold_px=1.0, seed=3))`` or, from existing options,
``dataclasses.replace(opts, refine=RefineOptions(acceleration_sensitivity=True))``. All are
frozen (hashable, safe to share between threads and frames).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..pose import RSModel
from ..solvers.registry import sample_size
from .prior import MotionPrior

__all__ = [
    "CorrelatedNoise",
    "EstimateOptions",
    "InitialModel",
    "LocalOptimizationOptions",
    "PlausibilityOptions",
    "RansacOptions",
    "RefineOptions",
    "check_ransac_settings",
    "points_needed",
]


def _check_int(name: str, value: object, low: int, high: int | None = None) -> None:
    """Raise ValueError unless ``value`` is an integer (``bool`` excluded) in
    ``[low, high]`` (``high`` None: no upper bound)."""
    ok = isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_)
    ok = ok and low <= int(value) and (high is None or int(value) <= high)
    if not ok:
        rng = f">= {low}" if high is None else f"in [{low}, {high}]"
        raise ValueError(f"{name} must be an integer {rng}, got {value!r}")


def _check_positive(name: str, value: object) -> None:
    """Raise ValueError unless ``value`` is a finite number > 0."""
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        v = float("nan")
    if not (np.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")


def check_ransac_settings(prefix: str = "", **settings: object) -> None:
    """Check RANSAC settings by name (those given): ``threshold_px`` finite > 0,
    ``max_iterations`` and ``batch_size`` integers >= 1, ``min_iterations`` and
    ``pretest_points`` integers >= 0, ``confidence`` in (0, 1), ``min_inliers`` an integer
    >= 1, ``seed`` an integer >= 0 (None allowed: a fresh random seed), ``prosac_growth`` an
    integer >= 1, ``solver_iterations`` None or an integer >= 1 (values that would make RANSAC
    run forever, never draw a sample or accept any model).

    Args:
        prefix: put before the names in the messages (e.g. ``"ransac."``).
        settings: name -> value.
    Raises:
        ValueError: naming the first setting out of its range, the range and the value.
    """
    for name, v in settings.items():
        label = prefix + name
        if name == "threshold_px":
            _check_positive(label, v)
        elif name in ("max_iterations", "batch_size", "min_inliers", "prosac_growth"):
            _check_int(label, v, 1)
        elif name in ("min_iterations", "pretest_points"):
            _check_int(label, v, 0)
        elif name == "solver_iterations":
            if v is not None:
                _check_int(label, v, 1)
        elif name == "seed":
            if v is not None:
                _check_int(label, v, 0)
        elif name == "confidence":
            try:
                c = float(v)  # type: ignore[arg-type]
            except (TypeError, ValueError):
                c = float("nan")
            if not 0.0 < c < 1.0:
                raise ValueError(f"{label} must be in (0, 1) (exclusive), got {v!r}")
        else:
            raise TypeError(f"check_ransac_settings: unknown setting {name!r}")


@dataclass(frozen=True)
class RansacOptions:
    """Sampling, scoring and termination of RANSAC.

    Attributes:
        threshold_px: inlier threshold on the RS reprojection error (pixels), at each point's
            measured capture time.
        max_iterations / min_iterations: bounds on the hypothesis samples drawn.
        confidence: adaptive termination confidence in (0, 1).
        min_inliers: fewest inliers for success (at least the solver's sample size + 1).
        seed: RNG seed (the estimate is deterministic for a fixed seed).
        batch_size: samples of the first batch solved at once by the batched solvers; each
            next batch doubles, but no batch draws more samples than adaptive termination
            still asks for.
        prosac_growth: with match scores, the sampling pool reaches all points after this
            many hypotheses (it starts at the best-scored ``2 * sample size``).
        pretest_points: T(d,d)-style pre-test size: a hypothesis with fewer than half the
            inliers the best model predicts among this many (shuffled) points is rejected
            early. 0 disables it.
        solver_iterations: linear iterations of the iterative 6-point solvers on minimal
            samples; ``None``: 1 for ``r6p_1lin`` (after the P3P pre-rotation one iteration is
            as good as R6P, paper Fig. 6) and 5 for the alternating solvers (the paper's
            default; they need them). Local optimization runs at least 2 (it starts from the
            current best rotation, so v is tiny and the [w]x[v]x term it fixes is second
            order).

    Raises:
        ValueError: a value out of its range (:func:`check_ransac_settings`: e.g.
            ``batch_size`` or ``max_iterations`` below 1, ``confidence`` outside (0, 1),
            ``min_inliers`` below 1), naming it.
    """

    threshold_px: float = 2.0
    max_iterations: int = 1000
    min_iterations: int = 20
    confidence: float = 0.9999
    min_inliers: int = 12
    seed: int = 0
    batch_size: int = 32
    prosac_growth: int = 200
    pretest_points: int = 24
    solver_iterations: int | None = None

    def __post_init__(self) -> None:
        check_ransac_settings(
            "ransac.",
            threshold_px=self.threshold_px,
            max_iterations=self.max_iterations,
            min_iterations=self.min_iterations,
            confidence=self.confidence,
            min_inliers=self.min_inliers,
            seed=self.seed,
            batch_size=self.batch_size,
            prosac_growth=self.prosac_growth,
            pretest_points=self.pretest_points,
            solver_iterations=self.solver_iterations,
        )


@dataclass(frozen=True)
class LocalOptimizationOptions:
    """LO-RANSAC: what polishes every new best hypothesis.

    Attributes:
        nonminimal: the first round re-runs the RS solver on all the hypothesis's inliers
            (else only the exact-model Levenberg-Marquardt polishes it).
        steps: maximum rounds per new best (they stop when the score stops improving).
        refine_iterations: Levenberg-Marquardt iterations of each round.
        max_points: rounds work on a random subset of this many points (the final
            refinement uses every point).

    Raises:
        ValueError: ``steps`` or ``refine_iterations`` not an integer >= 0, ``max_points`` not
            an integer >= 1.
    """

    nonminimal: bool = True
    steps: int = 4
    refine_iterations: int = 5
    max_points: int = 150

    def __post_init__(self) -> None:
        _check_int("local_optimization.steps", self.steps, 0)
        _check_int("local_optimization.refine_iterations", self.refine_iterations, 0)
        _check_int("local_optimization.max_points", self.max_points, 1)


@dataclass(frozen=True)
class RefineOptions:
    """The final refinement on the exact constant-velocity model (paper eq. 4).

    Attributes:
        enabled: run it (it also yields the covariance); ``False``: report RANSAC's model.
        acceleration_sensitivity: also return how the estimate moves per unit of angular and
            linear acceleration during the readout
            (:func:`rs_localizer.estimation.sensitivity.acceleration_sensitivity`, ~30 us;
            needs ``enabled`` and a rolling shutter; the video filter uses it).
    """

    enabled: bool = True
    acceleration_sensitivity: bool = False


@dataclass(frozen=True)
class PlausibilityOptions:
    """What an input point or a model may be.

    Attributes:
        max_angular_velocity: rad/s; models whose camera turns faster are implausible: they
            score as having no inliers in RANSAC and local optimization, and a final model
            beyond it fails with ``implausible_motion``. ``inf`` disables the bound. Not
            applied with global-shutter timing (``camera.seconds_per_unit_r == 0``).
        max_linear_velocity: m/s (map units per second), the same for the camera's speed.
        max_point_norm: 3D points farther than this from the origin (m) are dropped as
            points at infinity.
        consistent_fit: refuse a final model that fits only a part of the frame in a way
            true fits do not (``inconsistent_fit``; :func:`~.finalize.final_estimate`): its
            inliers one plane of a non-planar frame seen from behind (most other points
            beyond that plane), or a few percent of the points with a poorly conditioned
            pose. That is how mirrored images, maps in a mirrored frame and reflected
            correspondences fit. ``False``: no such check (e.g. a map whose points behind a
            wall are matched through a window).

    Raises:
        ValueError: a velocity bound that is not > 0 (NaN included).
    """

    max_angular_velocity: float = 20.0
    max_linear_velocity: float = 50.0
    max_point_norm: float = 1e6
    consistent_fit: bool = True

    def __post_init__(self) -> None:
        for name in ("max_angular_velocity", "max_linear_velocity"):
            if not float(getattr(self, name)) > 0:
                raise ValueError(f"{name} must be > 0 (inf: no bound), got {getattr(self, name)!r}")


@dataclass(frozen=True)
class CorrelatedNoise:
    """Spatially correlated image error in the covariance (:mod:`.noise_model`).

    Attributes:
        sigma_px: standard deviation (px, per image axis) of a spatially correlated image
            error (lens-model residue, corner bias, a board that is not flat) on top of the
            white noise the refinement estimates; the covariance becomes that of the same
            estimate under both (the estimate is unchanged). ``0``: white noise only
            (default). Estimate it with
            :func:`~rs_localizer.estimation.noise_model.fit_correlated_noise` on still
            calibration views. Costs O(N^2) in the inliers: ~1 ms at 54 points, ~13 ms at 300,
            ~90 ms at 1000 (one core, the covariance step alone).
        length_px: its correlation length (px, > 0).
        shift_share: for points given in groups (one marker's corners,
            :attr:`~rs_localizer.estimation.view.View.groups`): the share of a point's
            error variance its group shares (the marker's image shifted as a whole), in [0,
            1), taken by frames whose own residuals cannot tell it (too few groups for the
            fitted parameters, :func:`~.noise_model.shared_shift_variances`); frames that can
            estimate their own. ``0``: none there (default). Measure it on a recording with
            ``python -m benchmarks.reference_fit``.

    Raises:
        ValueError: a negative or non-finite ``sigma_px``, a ``length_px`` that is not > 0
            or a ``shift_share`` outside [0, 1).
    """

    sigma_px: float = 0.0
    length_px: float = 100.0
    shift_share: float = 0.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.sigma_px) and self.sigma_px >= 0):
            raise ValueError(
                f"correlated_noise.sigma_px must be finite and >= 0, got {self.sigma_px!r}"
            )
        if not (np.isfinite(self.length_px) and self.length_px > 0):
            raise ValueError(
                f"correlated_noise.length_px must be finite and > 0, got {self.length_px!r}"
            )
        if not (0.0 <= self.shift_share < 1.0):
            raise ValueError(
                f"correlated_noise.shift_share must be in [0, 1), got {self.shift_share!r}"
            )


@dataclass(frozen=True)
class EstimateOptions:
    """Options of :func:`~rs_localizer.estimation.estimate_rs_pose`, one group per concern.

    Attributes:
        ransac: :class:`RansacOptions` (threshold, iterations, seed, sampling).
        local_optimization: :class:`LocalOptimizationOptions` (LO-RANSAC).
        refine: :class:`RefineOptions` (the final exact-model refinement).
        motion_prior: Gaussian prior on the camera's velocities
            (:class:`~rs_localizer.estimation.prior.MotionPrior`, default 3 rad/s and
            1.5 m/s, zero mean), used where one frame cannot determine them: on planar scenes
            (coplanar 3D points) local optimization and the refinement are maximum a
            posteriori and the hypotheses use damped solves; on other scenes the final
            maximum-likelihood refinement is followed by a MAP one unless the data conflict
            with the prior (a camera much faster than it allows) or the prior would move the
            velocities by less than a tenth of their standard deviation (see
            :func:`~rs_localizer.estimation.finalize.final_refinement`). The covariance then
            includes the prior. With ``MotionPrior(always=True)`` (e.g. a tracker's
            prediction) it is used on every frame. ``None``: maximum likelihood everywhere.
        plausibility: :class:`PlausibilityOptions` (velocity bounds, points at infinity).
        correlated_noise: :class:`CorrelatedNoise` (the covariance's image-error model).
    """

    ransac: RansacOptions = RansacOptions()
    local_optimization: LocalOptimizationOptions = LocalOptimizationOptions()
    refine: RefineOptions = RefineOptions()
    motion_prior: MotionPrior | None = MotionPrior()
    plausibility: PlausibilityOptions = PlausibilityOptions()
    correlated_noise: CorrelatedNoise = CorrelatedNoise()


@dataclass(frozen=True)
class InitialModel:
    """A predicted model for :func:`~rs_localizer.estimation.estimate_rs_pose` (e.g. from the
    previous frames of a video, :class:`rs_localizer.tracking.tracker.RSTracker`).

    The model is first tested as a hypothesis: the points within ``gate_px`` of it are counted
    ("explained"). If at least ``min_explained`` are, it is pulled onto them (robust
    Levenberg-Marquardt), becomes RANSAC's first hypothesis, and its rotation, then the best
    model's, pre-rotates every minimal sample instead of a P3P pose (paper sec. 4 uses P3P for
    that pre-rotation; any rotation within a few degrees serves, Fig. 6); when it then explains
    at least ``min_explained`` points within the threshold, RANSAC samples only among those
    (a verification, as LO-RANSAC's inner sampling). Otherwise the estimator runs exactly as
    without it.

    Attributes:
        model: the predicted :class:`~rs_localizer.pose.RSModel` ``(R, C, w, t)`` (a bare
            4-tuple is converted): ``R`` (3, 3), ``C`` (3,) world -> camera at the reference
            row (``X_cam = R X + C``), ``w``, ``t`` (3,) model velocities per unit RS
            coordinate (rad, m per normalized unit; as ``RSPoseEstimate.model``; zeros: no
            motion during the readout).
        gate_px: distance (px) within which a point counts as explained.
        min_explained: fewest explained points to use the model.
    """

    model: RSModel
    gate_px: float = 20.0
    min_explained: int = 0

    def __post_init__(self):
        if not isinstance(self.model, RSModel):
            object.__setattr__(self, "model", RSModel(*self.model))


def points_needed(solver: str, options: EstimateOptions) -> int:
    """Fewest correspondences (and inliers) a pose of ``solver`` needs: the options'
    ``ransac.min_inliers``, and at least one more than the solver's minimal sample (a model
    fitted to exactly its sample has no redundancy to check it). The node refuses a
    ``max_points`` below this."""
    return max(options.ransac.min_inliers, sample_size(solver) + 1)
