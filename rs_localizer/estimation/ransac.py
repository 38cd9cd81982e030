"""The RANSAC stage of the estimator: LO-RANSAC over one prepared frame (paper sec. 4).

:class:`Ransac` holds the search's state (the best model, its score and inliers, the
hypotheses drawn, the adaptive termination) and draws batches of minimal samples from a
:class:`~.hypotheses.HypothesisSource`; every new best is polished by local optimization
(:func:`~.local_optimization.local_optimization`). An initial model (a tracker's prediction)
can seed it (:meth:`Ransac.run`).
"""

from __future__ import annotations

import functools
import time

import numpy as np

from ..solvers.registry import sample_size
from .frame import Frame, Model
from .hypotheses import KNOWN_W_SAMPLE, hypothesis_source
from .local_optimization import local_optimization, seed_from_initial_model
from .options import EstimateOptions, InitialModel
from .result import (
    DEGENERATE_GEOMETRY,
    IMPLAUSIBLE_MOTION,
    NO_HYPOTHESIS,
    TOO_FEW_INLIERS,
    EstimationFailed,
)

__all__ = ["Ransac", "prosac_order", "required_iterations", "seeded_rng"]


@functools.lru_cache(maxsize=16)
def _seed_sequence(seed: int) -> np.random.SeedSequence:
    return np.random.SeedSequence(seed)


def seeded_rng(seed: int | np.integer | None) -> np.random.Generator:
    """``np.random.default_rng(seed)`` (the same stream) without hashing an int seed again on
    every frame (~6 us of ~20 at this call's cache state); other seeds as NumPy takes them."""
    if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
        return np.random.Generator(np.random.PCG64(_seed_sequence(int(seed))))
    return np.random.default_rng(seed)


def required_iterations(inlier_ratio: float, s: int, confidence: float) -> float:
    """Samples of size ``s`` to draw for one all-inlier sample with probability
    ``confidence`` at ``inlier_ratio`` (RANSAC's adaptive termination; ``inf`` at 0)."""
    if inlier_ratio <= 0:
        return np.inf
    p = inlier_ratio**s
    if p >= 1:
        return 0
    return np.log(1 - confidence) / np.log1p(-p)


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


class Ransac:
    """LO-RANSAC on one frame with one solver.

    Attributes:
        best: the best model (R, C, w, t) so far or None; score: its MSAC score; inliers: its
            (N,) inlier mask; count: their number.
        iterations: hypotheses (minimal samples) drawn; needed: samples adaptive termination
            asks for; implausible: hypotheses rejected for their motion alone.
        anchor: (R, C) pre-rotating the samples instead of P3P (an initial model, then the
            best model), or None; explained: points the initial model explained (-1 without
            one); guided: > 0 when RANSAC verifies a seed by sampling only among its first
            ``guided`` points of ``order`` (its inliers).
        timings: ``ransac`` and ``local_optimization`` seconds once :meth:`run` returns.
    """

    def __init__(
        self,
        fr: Frame,
        solver: str,
        opts: EstimateOptions,
        rng: np.random.Generator,
        order: np.ndarray,
        scored: bool,
    ):
        self.fr, self.solver, self.opts, self.rng = fr, solver, opts, rng
        self.order, self.scored = order, scored
        # (with a gyro the samples are solved with the angular velocity known: 5 points)
        self.s = sample_size(solver) if fr.known_w is None else KNOWN_W_SAMPLE
        self.th2 = np.nan  # (squared normalized threshold: set by run, on the configured frame)
        self.best: Model | None = None
        self.score = np.inf
        self.inliers = np.zeros(len(fr.x), dtype=bool)
        self.count = 0
        self.iterations = 0
        self.needed = float(opts.ransac.max_iterations)
        self.implausible = 0
        self.anchor: tuple[np.ndarray, np.ndarray] | None = None
        self.explained = -1
        self.guided = 0
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
        source = hypothesis_source(
            self.fr, self.solver, self.opts, self.th2, self.anchor is not None
        )
        r = self.opts.ransac
        batch = max(int(r.batch_size), 1)
        N = len(self.fr.x)
        while self.iterations < r.max_iterations and (
            self.iterations < self.needed or self.iterations < r.min_iterations
        ):
            # batches double (fewer calls), but draw no more samples than termination asks for
            K = min(
                batch,
                r.max_iterations - self.iterations,
                max(
                    int(np.ceil(min(self.needed, r.max_iterations))) - self.iterations,
                    r.min_iterations - self.iterations,
                    1,
                ),
            )
            batch *= 2
            pool = self._pool(K)
            self.iterations += K
            pretest_min = int(0.5 * r.pretest_points * self.count / N)
            if self.anchor is not None and self.best is not None:
                self.anchor = (
                    np.ascontiguousarray(self.best[0], dtype=np.float64),
                    np.ascontiguousarray(self.best[1], dtype=np.float64),
                )
            out = source.best_of_batch(
                self.rng.random((K, self.s)), pool, self.order, self.score, pretest_min, self.anchor
            )
            self.implausible += out.implausible
            if out.score < self.score:
                h = out.best
                self._new_best((out.R[h], out.C[h], out.w[h], out.t[h]))
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
        if self.best is None:
            raise EstimationFailed(IMPLAUSIBLE_MOTION if self.implausible else NO_HYPOTHESIS)
        if self.count < min_inliers:
            raise EstimationFailed(TOO_FEW_INLIERS)
        if self.fr.degenerate(self.inliers, threshold_px):
            raise EstimationFailed(DEGENERATE_GEOMETRY)
        return self.best

    def _pool(self, K: int) -> int:
        """Points the next K samples are drawn from: the seed's inliers when verifying it, a
        PROSAC-style growing prefix of the best-scored points, or all."""
        N = len(self.fr.x)
        if self.guided:
            return self.guided
        if self.scored:
            growth = max(self.opts.ransac.prosac_growth, 1)
            return int(min(N, max(2 * self.s, np.ceil(N * (self.iterations + K) / growth))))
        return N

    def _seed(self, initial: InitialModel) -> None:
        t_lo = time.perf_counter()
        self.explained, seed, anchored = seed_from_initial_model(
            self.fr, self.solver, initial, self.th2, self.opts
        )
        if anchored:
            self.anchor = (
                np.ascontiguousarray(initial.model.R, dtype=np.float64),
                np.ascontiguousarray(initial.model.C, dtype=np.float64),
            )
        if seed is not None:
            self.score, self.best, self.inliers = seed
            self.count = int(np.count_nonzero(self.inliers))
            self.needed = required_iterations(
                self.count / len(self.fr.x), self.s, self.opts.ransac.confidence
            )
            if self.count >= max(initial.min_explained, self.s + 1):
                # the seed explains the frame: RANSAC verifies it with samples drawn from its
                # inliers (as LO-RANSAC's inner sampling), so the all-inlier probability is
                # that of the pool, not of the frame
                first = self.inliers.take(self.order)
                self.order = np.concatenate(
                    [self.order.compress(first), self.order.compress(~first)]
                )
                self.guided = self.count
                self.needed = 0.0
        self._t_local += time.perf_counter() - t_lo

    def _new_best(self, model: Model) -> None:
        """LO-RANSAC: score a new best on every point, polish it (unless verifying a seed: a
        verification sample that beats the seed is polished by the final refinement, on every
        point, as local optimization would) and update the termination."""
        t_lo = time.perf_counter()
        self.best = model
        self.score, self.inliers = self.fr.evaluate(model, self.th2)
        if not self.guided:
            self.score, self.best, self.inliers = local_optimization(
                self.fr, self.solver, (self.score, self.best, self.inliers), self.th2, self.opts
            )
        self._t_local += time.perf_counter() - t_lo
        self.count = int(np.count_nonzero(self.inliers))
        ratio = (
            np.count_nonzero(self.inliers[self.order[: self.guided]]) / self.guided
            if self.guided
            else self.count / len(self.fr.x)
        )
        self.needed = required_iterations(ratio, self.s, self.opts.ransac.confidence)
