"""LO-RANSAC's polishing of a new best hypothesis, and the test of an initial model (a
tracker's prediction) that may seed RANSAC."""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np

from ..pose import RSModel
from ..solvers.registry import sample_size, solver_info
from .finalize import refined_model
from .frame import SCORE_AT_MEASURED_TIME, Frame, Model, RefinementView
from .hypotheses import nonminimal_models
from .options import EstimateOptions, InitialModel
from .plausibility import all_finite, finite_model
from .prior import MotionPrior
from .scoring import exact_errors2

__all__ = [
    "Scored",
    "initial_model_seed",
    "local_optimization",
    "polish",
    "pulled_in",
    "seed_from_initial_model",
    "view_seed_steps",
]

#: (MSAC score, model (R, C, w, t), (N,) inlier mask)
Scored = tuple[float, Model, np.ndarray]


def local_optimization(
    fr: Frame,
    solver: str,
    best: Scored,
    th2: float,
    opts: EstimateOptions,
    evaluate: Callable[[Model], tuple[float, np.ndarray]] | None = None,
    nonminimal: Callable[..., list[Model]] = nonminimal_models,
    refine: Callable[..., Model] = refined_model,
) -> Scored:
    """LO step of LO-RANSAC on a new ``best`` (score, model, inlier mask); ``th2``: squared
    inlier threshold (normalized units).

    The first round re-solves with the (nonminimal) RS solver on the hypothesis's inliers,
    pre-rotated by its rotation. Every round then runs a few Levenberg-Marquardt iterations of
    the exact model (paper eq. 4) on the frame's first ``max_points`` points (a random subset)
    with a truncated Huber loss (points beyond twice the threshold are ignored, so the inlier
    set is re-selected at every iteration; the linear solvers alone fit the linearized model,
    which is biased on fast motion). Later rounds do not re-run the linear solver: starting
    from an exact-model fit it never won (0 of 80 second rounds at RS speed 0.5 and 1.0).
    Rounds continue while the MSAC score improves and the inlier set grows (at most
    ``opts.local_optimization.steps``; the rounds are :func:`polish`'s). P3P only gets the
    global-shutter refinement.

    The steps themselves are arguments (the NumPy implementation, :mod:`.numpy_impl`, passes
    its own): ``evaluate(model)`` (score, (N,) inlier mask) on every point (default
    :meth:`~.frame.Frame.evaluate`), ``nonminimal`` as :func:`~.hypotheses.nonminimal_models`,
    ``refine`` as :func:`~.finalize.refined_model` (the refinement a rig's local optimization
    runs on every point).

    Returns:
        the polished (score, model, inlier mask), scored on every point.
    """
    if evaluate is None:
        evaluate = functools.partial(fr.evaluate, th2=th2)
    lo = opts.local_optimization
    th = np.sqrt(th2)
    rolling = solver_info(solver).rolling
    M = min(len(fr.x), max(lo.max_points, 2 * sample_size(solver)))
    sub = fr.take(slice(M))

    def linear(model: Model, inliers: np.ndarray) -> list[Model]:
        return nonminimal(sub, solver, inliers[:M], model[0], opts, model[1])

    def exact(model: Model) -> Model:
        return refine(sub, model, th, rolling, fr.prior, max_iterations=lo.refine_iterations)

    return polish(best, evaluate, linear if lo.nonminimal else None, exact, lo.steps)[0]


def polish(
    best: Scored,
    evaluate: Callable[[Model], tuple[float, np.ndarray]],
    nonminimal: Callable[[Model, np.ndarray], list[Model]] | None,
    refine: Callable[[Model], Model] | None,
    rounds: int,
    min_inliers: int = 6,
) -> tuple[Scored, tuple[Model, Model] | None]:
    """The rounds of local optimization on a new ``best`` (score, model, (N,) inlier mask),
    whatever the frame: a single camera's (:func:`local_optimization`) and a rig's
    (:func:`~.rig.estimate_rig_pose`), each with its own steps.

    A round takes the better (lower score) of its start and the models of each step: in the
    first round ``nonminimal(model, inliers)`` (the linear re-solve on the (N,) inlier mask;
    None: no such step), then ``refine(model)`` (the exact-model refinement, from the better
    of the start and the linear models; None: no such step). Rounds stop at ``rounds``, at a
    round that does not lower the score, after a round whose inliers did not grow, and before
    a round that would start with fewer than ``min_inliers`` inliers.

    Args:
        evaluate: ``evaluate(model)`` the (score, (N,) inlier mask) of a model on every point.

    Returns:
        (the polished (score, model, inlier mask), the last refinement's ``(start, result)``
        whether it was taken or not, None without one): a final refinement that starts from
        the polished model need not run that refinement again.
    """
    best_score, model, best_inl = best
    refined = None
    for step in range(rounds):
        n_before = int(np.count_nonzero(best_inl))
        if n_before < min_inliers:
            break
        start, start_score, start_inl = model, best_score, best_inl
        linear = nonminimal(model, best_inl) if nonminimal is not None and step == 0 else []
        for cand in linear:
            sc, inl = evaluate(cand)
            if sc < start_score:
                start, start_score, start_inl = cand, sc, inl
        if refine is not None:
            cand = refine(start)
            refined = (start, cand)
            sc, inl = evaluate(cand)
            if sc < start_score:
                start, start_score, start_inl = cand, sc, inl
        if start_score >= best_score:
            break
        model, best_score, best_inl = start, start_score, start_inl
        if step + 1 == rounds or int(np.count_nonzero(best_inl)) <= n_before:
            break
    return (best_score, model, best_inl), refined


def seed_from_initial_model(
    fr: Frame,
    solver: str,
    initial: InitialModel,
    th2: float,
    opts: EstimateOptions,
    errors2: Callable[[Model], np.ndarray] | None = None,
    evaluate: Callable[[Model], tuple[float, np.ndarray]] | None = None,
    refine: Callable[..., Model] = refined_model,
) -> tuple[int, Scored | None, bool]:
    """Test an :class:`InitialModel` on all points of ``fr`` (:func:`initial_model_seed`
    with the frame's steps, ``th2`` the squared inlier threshold, normalized units).

    The steps are arguments, as :func:`local_optimization`'s (the NumPy implementation,
    :mod:`.numpy_impl`, passes its own): ``errors2(model)`` the (N,) squared errors at every
    point's measured capture time (default the compiled :func:`~.scoring.exact_errors2`),
    ``evaluate(model)`` (score, (N,) inlier mask) on every point (default
    :meth:`~.frame.Frame.evaluate` on those errors), ``refine`` as
    :func:`~.finalize.refined_model`.

    Returns:
        (explained, seed, anchor) as :func:`initial_model_seed`. A prediction a few pixels off
        (a hand-held camera's at 30 fps: ~2-15 px) explains the frame within the gate, not
        within the threshold: the pull onto the explained points (:func:`pulled_in`) runs on
        at most a third of local optimization's ``max_points`` of them, with twice its
        iterations (a third is plenty to pull a prediction in: the final refinement fits
        every point).
    """
    finite = finite_model if errors2 is None else all_finite
    if errors2 is None:

        def errors2(m: Model) -> np.ndarray:
            return exact_errors2(fr.x, fr.X, fr.r0e, fr.d, *m, SCORE_AT_MEASURED_TIME, fr.W)

    given = evaluate
    evaluate = evaluate or functools.partial(fr.evaluate, th2=th2)

    def score(m: Model, e2: np.ndarray) -> tuple[float, np.ndarray]:
        return fr.evaluate(m, th2, errors=e2) if given is None else given(m)

    gate = float(initial.gate_px) / fr.f
    rolling, size = solver_info(solver).rolling, sample_size(solver)
    lo = opts.local_optimization

    def pull(seed: Scored, near: np.ndarray) -> Scored:
        sub = fr.take(np.flatnonzero(near)[: max(lo.max_points // 3, 2 * size)])
        steps = (2 * lo.refine_iterations, evaluate, refine, finite)
        return pulled_in(seed, sub, np.sqrt(th2), gate, rolling, fr.prior, *steps)

    model = tuple(np.ascontiguousarray(a, dtype=np.float64).copy() for a in initial.model)
    return initial_model_seed(
        model, initial.min_explained, rolling, size, gate * gate, errors2, score, pull, finite
    )


def initial_model_seed(
    model: tuple,
    min_explained: int,
    rolling: bool,
    size: int,
    bound: float,
    errors: Callable[[Model], np.ndarray],
    evaluate: Callable[[Model, np.ndarray], tuple[float, np.ndarray]],
    pull: Callable[[Scored, np.ndarray], Scored],
    finite: Callable[..., bool] = all_finite,
) -> tuple[int, Scored | None, bool]:
    """Test an initial model (a tracker's prediction, :class:`InitialModel`) on every point:
    the decision a single camera (:func:`seed_from_initial_model`) and a rig
    (:func:`~.rig.estimate_rig_pose`) share, each with its own errors and steps.

    Args:
        model: the initial model's ``(R (3, 3), C, w, t (3,))``, the caller's own copy (the
            seed keeps its arrays); ``min_explained``: its
            :attr:`~.options.InitialModel.min_explained`; ``rolling``: False sets
            ``w = t = 0`` (a global-shutter model); ``size``: the minimal sample's number of
            points.
        bound: the gate in the units of ``errors`` (a camera's squared normalized errors: the
            squared gate over the focal length; a rig's errors in px: the gate).
        errors: ``errors(model)`` (N,) each point's error at its measured capture time, in
            the caller's units; ``evaluate(model, e)`` (MSAC score, (N,) inlier mask) of the
            model with those errors ``e``; ``pull(seed, near)`` the better of the scored
            ``seed`` and the model pulled onto the explained points ``near`` ((N,) bool);
            ``finite(R, C, w, t)``: whether the parameters are finite (default in NumPy).
    Returns:
        (explained, seed, anchor): ``explained`` counts the points within the gate;
        ``anchor`` is True when at least ``min_explained`` (and one) are (the model then
        pre-rotates RANSAC's samples); ``seed`` is (score, model, inlier mask) when it has
        more than ``size`` inliers, after ``pull`` where it had fewer than
        ``max(min_explained, size + 1)``, else None.
    """
    R, C, w, t = model
    if not rolling:
        w, t = np.zeros(3), np.zeros(3)
    if not finite(R, C, w, t):
        return 0, None, False
    model = RSModel(R, C, w, t)
    e = errors(model)
    near = e < bound
    explained = int(np.count_nonzero(near))
    if explained < max(int(min_explained), 1):
        return explained, None, False
    score, inl = evaluate(model, e)
    seed = (score, model, inl)
    if int(np.count_nonzero(seed[2])) < max(int(min_explained), size + 1):
        seed = pull(seed, near)
    if int(np.count_nonzero(seed[2])) <= size:
        return explained, None, True
    return explained, seed, True


def view_seed_steps(
    fr: RefinementView, th: float, gate: float, rolling: bool, prior: MotionPrior | None
) -> tuple[Callable, Callable, Callable]:
    """The ``errors``, ``evaluate`` and ``pull`` steps of :func:`initial_model_seed` on a
    frame whose errors (:meth:`~.frame.RefinementView.errors`) are in the threshold's units
    (a rig's, px): the MSAC score and inliers at ``th``, and the pull onto the explained points
    (:func:`pulled_in`) on every point, at most 10 iterations, truncated at ``gate`` (at least
    the threshold; ``rolling``, ``prior`` as there)."""
    k = float(th)
    th2 = k**2

    def evaluate(model: Model, e: np.ndarray) -> tuple[float, np.ndarray]:
        return np.minimum(e * e, th2).sum(), e < k

    def pull(seed: Scored, near: np.ndarray) -> Scored:
        scored = lambda m: evaluate(m, fr.errors(m))  # noqa: E731
        return pulled_in(seed, fr, k, max(float(gate), k), rolling, prior, 10, scored)

    return fr.errors, evaluate, pull


def pulled_in(
    seed: Scored,
    fr: RefinementView,
    th: float,
    gate: float,
    rolling: bool,
    prior: MotionPrior | None,
    iterations: int,
    evaluate: Callable[[Model], tuple[float, np.ndarray]],
    refine: Callable[..., Model] = refined_model,
    finite: Callable[..., bool] = all_finite,
) -> Scored:
    """The better (lower score) of ``seed`` (score, model, inlier mask) and its model pulled
    onto the points of ``fr`` (an initial model's explained points: a camera's,
    :func:`seed_from_initial_model`; every point of a rig's, :func:`view_seed_steps`):
    ``refine`` (:func:`~.finalize.refined_model`: at most ``iterations`` iterations of Huber
    loss at the threshold ``th``, in ``fr``'s units, on the points within ``gate``, re-selected
    at each iteration; ``rolling``, ``prior`` as there), kept where its parameters are
    ``finite`` and ``evaluate(model)`` (score, (N,) inlier mask on every point) lowers the
    score."""
    model = refine(fr, seed[1], th, rolling, prior, cutoff=gate, max_iterations=iterations)
    if finite(*model):
        score, inliers = evaluate(model)
        if score < seed[0]:
            return score, model, inliers
    return seed
