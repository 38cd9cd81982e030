"""The RANSAC stage of the estimator: LO-RANSAC over one prepared frame (paper sec. 4).

One search for one camera or a rig of them (as PoseLib's ``ransac<Estimator>``):
:class:`RansacLoop` holds what every search keeps (the best model and its score, the samples
drawn, the adaptive termination: :func:`required_iterations`, the batches:
:func:`batch_sizes`) and asks a :class:`RansacEstimator` for the rest
(``generate_models``: a batch of hypotheses from minimal samples, ``score_models``,
``refine_model``: a new best). The single camera's :class:`Ransac` is its own estimator; the
rig's is in :mod:`.rig`. Both draw from one seeded random stream (:func:`seeded_rng`; the
start of it kept per seed by :func:`seeded_stream`: a frame's shuffle, a compiled rig
batch's draws), and both terminate by one rule (:func:`required_samples`, checked after
every batch).

:class:`Ransac` holds the search's state (the best model, its score and inliers, the
hypotheses drawn, the adaptive termination) and draws batches of minimal samples from a
:class:`~.hypotheses.HypothesisSource`; every new best is polished by local optimization
(:func:`~.local_optimization.local_optimization`). An initial model (a tracker's prediction)
can seed it (:meth:`Ransac.run`).
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable, Iterator
from typing import Any, Protocol

import numpy as np

from ..solvers.registry import sample_size
from .frame import Frame, Model
from .hypotheses import KNOWN_W_SAMPLE, HypothesisSource, ScoredBatch, hypothesis_source
from .local_optimization import Scored, local_optimization, seed_from_initial_model
from .options import EstimateOptions, InitialModel, RansacOptions
from .result import (
    DEGENERATE_GEOMETRY,
    IMPLAUSIBLE_MOTION,
    NO_HYPOTHESIS,
    TOO_FEW_INLIERS,
    EstimationFailed,
)

__all__ = [
    "Ransac",
    "RansacEstimator",
    "RansacLoop",
    "batch_sizes",
    "prosac_order",
    "required_iterations",
    "required_samples",
    "seeded_rng",
    "seeded_stream",
]


def _int_seed(seed) -> bool:
    """Whether ``seed`` is an int (a NumPy integer too, not a bool): a seed whose streams
    :func:`seeded_stream` keeps."""
    return type(seed) is int or (isinstance(seed, (int, np.integer)) and not isinstance(seed, bool))


@functools.lru_cache(maxsize=16)
def _seed_sequence(seed: int) -> np.random.SeedSequence:
    return np.random.SeedSequence(seed)


def seeded_rng(seed: int | np.integer | None) -> np.random.Generator:
    """``np.random.default_rng(seed)`` (the same stream) without hashing an int seed again on
    every frame (~6 us of ~20 at this call's cache state); other seeds as NumPy takes them."""
    if _int_seed(seed):
        return np.random.Generator(np.random.PCG64(_seed_sequence(int(seed))))
    return np.random.default_rng(seed)


@functools.lru_cache(maxsize=64)
def _seeded_stream(seed: int, kind: str, n: int) -> np.ndarray:
    rng = seeded_rng(seed)
    out = rng.permutation(n) if kind == "permutation" else rng.random(n)
    out.flags.writeable = False
    return out


def seeded_stream(seed: int | np.integer | None, kind: str, n: int) -> np.ndarray:
    """The start of ``seeded_rng(seed)``'s stream: its first ``permutation(n)`` (``kind``
    ``"permutation"``: a frame's shuffle, :class:`SeededShuffle`) or its first ``n`` uniform
    draws in [0, 1) (``"random"``: a compiled rig batch's, :mod:`.rig_batch`), (n,) and
    read-only. Kept for the last int seeds and sizes (every frame of a seed starts from the
    same stream); any other seed draws from a new generator."""
    if not _int_seed(seed):
        rng = seeded_rng(seed)
        return rng.permutation(n) if kind == "permutation" else rng.random(n)
    return _seeded_stream(int(seed), kind, int(n))


class SeededShuffle:
    """A frame's shuffle by ``seeded_rng(seed)`` (:func:`~.frame.prepare_frame`'s
    ``rng.permutation(rows)``, the same rows) and that generator after it
    (:meth:`generator`, the same stream), the generator built only when a search draws from
    it: a frame of a few points draws nothing more (for an int seed the shuffle of ``n``
    rows is kept; other seeds draw from the generator)."""

    def __init__(self, seed: int | np.integer | None):
        self.seed = seed
        self._n: int | None = None
        self._rng: np.random.Generator | None = None
        if not _int_seed(seed):
            self._rng = seeded_rng(seed)

    def permutation(self, rows: np.ndarray) -> np.ndarray:
        """(n,) the rows shuffled, as the generator's first ``permutation`` shuffles them."""
        if self._rng is not None:
            return self._rng.permutation(rows)
        self._n = len(rows)
        return rows.take(seeded_stream(self.seed, "permutation", self._n))

    def generator(self) -> np.random.Generator:
        """The generator, past the shuffle (:meth:`permutation`) when it was drawn."""
        if self._rng is None:
            self._rng = seeded_rng(self.seed)
            if self._n is not None:
                self._rng.permutation(self._n)
        return self._rng


def required_iterations(inlier_ratio: float, s: int, confidence: float) -> float:
    """Samples of size ``s`` to draw for one all-inlier sample with probability
    ``confidence`` at ``inlier_ratio`` (RANSAC's adaptive termination; ``inf`` at 0):
    :func:`required_samples` with ``log(1 - confidence)``."""
    return required_samples(inlier_ratio, s, np.log(1 - confidence))


def required_samples(inlier_ratio: float, s: int, log_miss: float) -> float:
    """:func:`required_iterations` with ``log_miss`` ``log(1 - confidence)``: the formula once
    for a camera's search and a rig's."""
    if inlier_ratio <= 0:
        return np.inf
    p = inlier_ratio ** float(s)  # (a float power, compiled too: pow(), not repeated products)
    if p >= 1:
        return 0.0
    return log_miss / np.log1p(-p)


def prosac_order(fr: Frame, scores: np.ndarray | None) -> np.ndarray:
    """The frame's points best-scored first (PROSAC-style sampling grows its pool along this
    order); ``arange(N)`` without scores.

    Args:
        scores: (num_rows,) match quality over the input rows, higher is better (non-finite:
            worst), or None.
    Raises:
        ValueError: ``scores`` of another shape.
    """
    if scores is None:
        return np.arange(len(fr.x))
    scores = np.asarray(scores, dtype=float)
    if scores.shape != (fr.num_rows,):
        raise ValueError(f"scores must have shape ({fr.num_rows},), got {scores.shape}")
    sc = scores[fr.rows]
    return np.argsort(-np.where(np.isfinite(sc), sc, -np.inf), kind="stable")


def batch_sizes(loop: RansacLoop, r: RansacOptions) -> Iterator[int]:
    """The sizes of the batches of minimal samples a search draws, until adaptive termination
    (``loop.needed``, read before each batch) or ``r.max_iterations``: the first batch
    ``r.batch_size``, each next one twice as large, but none more than termination still
    asks for (at least ``r.min_iterations`` in all). The caller adds the samples each drew to
    ``loop.iterations``."""
    batch = max(int(r.batch_size), 1)
    min_it, max_it = r.min_iterations, r.max_iterations
    while True:
        it, needed = loop.iterations, loop.needed
        if not (it < max_it and (it < needed or it < min_it)):
            return
        # batches double (fewer calls), but draw no more samples than termination asks for
        ask = math.ceil(min(needed, float(max_it)))
        yield min(batch, max_it - it, max(ask - it, min_it - it, 1))
        batch *= 2


class RansacEstimator(Protocol):
    """What :meth:`RansacLoop.search` asks of one estimator (a camera's, a rig's), as
    PoseLib's estimators' ``generate_models``, ``score_model`` and ``refine_model``."""

    def generate_models(self, loop: RansacLoop, K: int) -> tuple[Any, int]:
        """``(hypotheses, samples drawn)``: the hypotheses of up to ``K`` new minimal samples
        (``loop.iterations`` not yet counting them), or None when none gave a model, and the
        samples drawn (``K``); adds those dropped for their motion alone to
        ``loop.implausible``."""

    def score_models(self, hypotheses: Any) -> tuple[float, Any]:
        """The best of ``generate_models``'s hypotheses: (its MSAC score, its model)."""

    def refine_model(self, loop: RansacLoop, model: Any) -> tuple[float, Any, float]:
        """A new best model polished (local optimization, or as it is): (its score, the
        model, the inlier ratio that adaptive termination counts on)."""


class RansacLoop:
    """What every RANSAC search keeps, whatever its estimator.

    Attributes:
        s: the minimal sample's size. confidence: adaptive termination's.
        best: the best model so far or None; score: its MSAC score; count: its inliers
            among every point (the estimator's, or the seed's), which raises the pre-test's
            bound (:meth:`pretest_min`).
        iterations: hypotheses (minimal samples) drawn; needed: samples adaptive termination
            asks for; implausible: hypotheses rejected for their motion alone.
        explained: points an initial model explained (-1 without one); anchored: its
            rotation, then the best model's, pre-rotates the samples; subset: the seed's
            inliers (int indices) when RANSAC only verifies it, sampling among them, else None
            (:meth:`seeded`).
    """

    def __init__(self, s: int, r: RansacOptions):
        self.s = s
        self.confidence = r.confidence
        self._log_miss = np.log(1 - r.confidence)  # (required_iterations' log(1 - confidence))
        self.best: Any = None
        self.score = np.inf
        self.count = 0
        self.pretest_points = int(r.pretest_points)
        self.iterations = 0
        self.needed = float(r.max_iterations)
        self.implausible = 0
        self.explained, self.anchored, self.subset = -1, False, None

    def seeded(self, test: tuple, verified: Callable[[np.ndarray], bool],
               order: np.ndarray | None = None) -> None:  # fmt: skip
        """Start from an initial model's ``test`` (``(explained, seed, anchored)`` of
        :func:`~.local_optimization.initial_model_seed`): its seed (score, model, (N,) inlier
        mask), if any, is the first best model. When ``verified(inliers)`` (they explain the
        frame) RANSAC only verifies it with samples drawn from its inliers (as LO-RANSAC's
        inner sampling, so the all-inlier probability is that of the pool, not of the frame):
        ``subset`` is them in ``order`` (None: in index order) and no more samples are
        needed; else termination counts on the seed's inlier ratio."""
        self.explained, seed, self.anchored = test
        if seed is None:
            return
        self.score, self.best, inliers = seed
        self.count = int(np.count_nonzero(inliers))
        if verified(inliers):
            self.subset = (
                np.flatnonzero(inliers) if order is None else order.compress(inliers.take(order))
            )
            self.needed = 0.0
        else:
            ratio = np.count_nonzero(inliers) / len(inliers)
            self.needed = required_samples(ratio, self.s, self._log_miss)

    def pretest_min(self, n: int) -> int:
        """The pre-test's bound of the next batch on ``n`` points (:func:`~.scoring.msac_scores`'
        ``pretest_min``): half the inliers the best model predicts among the
        ``pretest_points`` first points, as every completed hypothesis raises it."""
        return int(0.5 * self.pretest_points * self.count / n)

    def search(self, estimator: RansacEstimator, r: RansacOptions) -> None:
        """Draw batches (:func:`batch_sizes`) of ``estimator``'s hypotheses; a better score
        than the best's is refined and becomes the best, and termination is updated from its
        inlier ratio (:func:`required_iterations`)."""
        for K in batch_sizes(self, r):
            hypotheses, drawn = estimator.generate_models(self, K)
            self.iterations += drawn
            if hypotheses is None:
                continue
            score, model = estimator.score_models(hypotheses)
            if score < self.score:
                self.score, self.best, ratio = estimator.refine_model(self, model)
                self.needed = required_samples(ratio, self.s, self._log_miss)

    def found(self) -> Any:
        """The best model.

        Raises:
            EstimationFailed: ``implausible_motion`` (no model, and some hypotheses moved too
                fast) or ``no_hypothesis`` (no sample gave a model).
        """
        if self.best is None:
            raise EstimationFailed(IMPLAUSIBLE_MOTION if self.implausible else NO_HYPOTHESIS)
        return self.best


class Ransac(RansacLoop):
    """LO-RANSAC on one frame with one solver: a :class:`RansacLoop` that is its own
    :class:`RansacEstimator`.

    Attributes:
        best: the best model (R, C, w, t) so far or None; score: its MSAC score; inliers: its
            (N,) inlier mask; count: their number.
        iterations: hypotheses (minimal samples) drawn; needed: samples adaptive termination
            asks for; implausible: hypotheses rejected for their motion alone.
        anchor: (R, C) pre-rotating the samples instead of P3P (an initial model, then the
            best model), or None; explained, subset: as :class:`RansacLoop`'s (the seed's
            inliers in ``order``).
        timings: ``ransac`` and ``local_optimization`` seconds once :meth:`run` returns.

    What needs compiled kernels is in four methods (:meth:`hypothesis_source`,
    :meth:`evaluate`, :meth:`local_optimization`, :meth:`seed_steps`) and ``compiled`` (the
    degeneracy test of :meth:`result`); the NumPy implementation's search
    (:mod:`.numpy_impl`) replaces those and keeps the rest: sampling, termination, the seed,
    the failure reasons.
    """

    #: the degeneracy test of :meth:`result` runs compiled (False: in NumPy)
    compiled = True

    def __init__(
        self,
        fr: Frame,
        solver: str,
        opts: EstimateOptions,
        rng: np.random.Generator,
        order: np.ndarray,
        scored: bool,
    ):
        # (with a gyro the samples are solved with the angular velocity known: 5 points)
        super().__init__(sample_size(solver) if fr.known_w is None else KNOWN_W_SAMPLE, opts.ransac)
        self.fr, self.solver, self.opts, self.rng = fr, solver, opts, rng
        self.order, self.scored = order, scored
        self.th2 = np.nan  # (squared normalized threshold: set by run, on the configured frame)
        self.inliers = np.zeros(len(fr.x), dtype=bool)
        self.anchor: tuple[np.ndarray, np.ndarray] | None = None
        self.timings: dict[str, float] = {}
        self._t_local = 0.0

    def run(self, initial: InitialModel | None = None) -> None:
        """Search until adaptive termination (or ``max_iterations``), starting from
        ``initial`` if given: it is tested first (:func:`seed_from_initial_model`); if it
        explains the frame it becomes the first best model, its rotation (then the best
        model's) pre-rotates every sample, and when it explains at least ``min_explained``
        points within the threshold RANSAC only verifies it, sampling among its inliers."""
        t0 = time.perf_counter()
        self.th2 = self.fr.threshold * self.fr.threshold
        if initial is not None:
            self._seed(initial)
        self._source = self.hypothesis_source()
        self.search(self, self.opts.ransac)
        self.timings = {
            "ransac": time.perf_counter() - t0 - self._t_local,
            "local_optimization": self._t_local,
        }

    def result(self, min_inliers: int, threshold_px: float) -> Model:
        """The best model, if it can be one.

        Raises:
            EstimationFailed: ``implausible_motion`` (no model, and some hypotheses moved too
                fast), ``no_hypothesis``, ``too_few_inliers`` (fewer than ``min_inliers``),
                ``degenerate_geometry`` (its inliers fix no pose).
        """
        self.found()
        if self.count < min_inliers:
            raise EstimationFailed(TOO_FEW_INLIERS)
        if self.fr.degenerate(self.inliers, threshold_px, self.compiled):
            raise EstimationFailed(DEGENERATE_GEOMETRY)
        return self.best

    def hypothesis_source(self) -> HypothesisSource:
        """The source of the samples' hypotheses (:func:`~.hypotheses.hypothesis_source`)."""
        return hypothesis_source(self.fr, self.solver, self.opts, self.th2, self.anchor is not None)

    def seed_steps(self) -> dict[str, Any]:
        """The steps :func:`~.local_optimization.seed_from_initial_model` tests an initial
        model with (none: its compiled defaults)."""
        return {}

    def evaluate(self, model: Model) -> tuple[float, np.ndarray]:
        """(MSAC score, (N,) inlier mask) of ``model`` on every point
        (:meth:`~.frame.Frame.evaluate`)."""
        return self.fr.evaluate(model, self.th2)

    def local_optimization(self, scored: Scored) -> Scored:
        """A new best (score, model, inlier mask) polished
        (:func:`~.local_optimization.local_optimization`)."""
        return local_optimization(self.fr, self.solver, scored, self.th2, self.opts)

    def _pool(self, K: int) -> int:
        """Points the next K samples are drawn from: the seed's inliers when verifying it, a
        PROSAC-style growing prefix of the best-scored points, or all."""
        N = len(self.fr.x)
        if self.subset is not None:
            return len(self.subset)
        if self.scored:
            growth = max(self.opts.ransac.prosac_growth, 1)
            return int(min(N, max(2 * self.s, np.ceil(N * (self.iterations + K) / growth))))
        return N

    def _seed(self, initial: InitialModel) -> None:
        t_lo = time.perf_counter()
        test = seed_from_initial_model(
            self.fr, self.solver, initial, self.th2, self.opts, **self.seed_steps()
        )
        need = max(initial.min_explained, self.s + 1)
        self.seeded(test, lambda inliers: np.count_nonzero(inliers) >= need, self.order)
        if self.anchored:
            self.anchor = (
                np.ascontiguousarray(initial.model.R, dtype=np.float64),
                np.ascontiguousarray(initial.model.C, dtype=np.float64),
            )
        if test[1] is not None:
            self.inliers = test[1][2]
        self._t_local += time.perf_counter() - t_lo

    def generate_models(self, loop: RansacLoop, K: int) -> tuple[ScoredBatch, int]:
        """The best of K samples' hypotheses, scored preemptively in the same compiled call
        (:meth:`~.hypotheses.HypothesisSource.best_of_batch`), and K."""
        pool = self._pool(K)
        pretest_min = self.pretest_min(len(self.fr.x))
        if self.anchor is not None and self.best is not None:
            self.anchor = (
                np.ascontiguousarray(self.best[0], dtype=np.float64),
                np.ascontiguousarray(self.best[1], dtype=np.float64),
            )
        order = self.order if self.subset is None else self.subset
        out = self._source.best_of_batch(
            self.rng.random((K, self.s)), pool, order, self.score, pretest_min, self.anchor
        )
        self.implausible += out.implausible
        return out, K

    def score_models(self, out: ScoredBatch) -> tuple[float, Model]:
        h = out.best
        return out.score, (out.R[h], out.C[h], out.w[h], out.t[h])

    def refine_model(self, loop: RansacLoop, model: Model) -> tuple[float, Model, float]:
        """LO-RANSAC: score a new best on every point, polish it (unless verifying a seed: a
        verification sample that beats the seed is polished by the final refinement, on every
        point, as local optimization would); the inlier ratio of termination is that of the
        verified seed's inliers when verifying it."""
        t_lo = time.perf_counter()
        score, self.inliers = self.evaluate(model)
        if self.subset is None:
            score, model, self.inliers = self.local_optimization((score, model, self.inliers))
        self._t_local += time.perf_counter() - t_lo
        self.count = int(np.count_nonzero(self.inliers))
        if self.subset is None:
            return score, model, self.count / len(self.fr.x)
        return score, model, np.count_nonzero(self.inliers[self.subset]) / len(self.subset)
