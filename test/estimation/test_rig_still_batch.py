"""The rig's RANSAC batches in one compiled call (``search_batch``) against the
same batch step by step (the sampling, Lambda Twist mapped to the rig, the held rig solver's
correction) scored in NumPy (the ``"numpy"`` implementation's reprojection errors and MSAC
cost): the same best model, cost, errors, inliers and missed cameras, scored in full or with
the camera's pre-test on a random order of the points. The held rig solver the batches
correct with (``prerotated_solutions`` with the rig solver, held) against the batched rig
solver with the same prior rows (``gr6p_1lin_batch``), bit for bit."""

from dataclasses import replace

import numpy as np
import pytest

from rs_localizer._so3 import compose_rotvec
from rs_localizer.estimation import rig as rig_mod
from rs_localizer.estimation.batch import prerotated_solutions
from rs_localizer.estimation.numpy_impl import errors2
from rs_localizer.estimation.plausibility import plausible_motion
from rs_localizer.estimation.rig_batch import RIG_KERNELS, search_batch
from rs_localizer.estimation.sampling import batch_sampling, view_sampling
from rs_localizer.estimation.view import StackedViews
from rs_localizer.frames import Mounting
from rs_localizer.geometry import rotvec_to_matrix
from rs_localizer.sim import synthetic as sim_rig
from rs_localizer.solvers.gr6p_1lin import gr6p_1lin_batch
from rs_localizer.solvers.lambda_twist import lambda_twist

#: a batch's search state of no best model, scored in full: ``(best cost, pre-test points,
#: pre-test inliers)``
_NO_STOP = (np.inf, 0, 0)


def _buffers(N, M):
    """A batch's output buffers (NaN, so that a value not written shows): errors (N,), R, C,
    w, t, missed cameras (M,)."""
    f = [np.full(N, np.nan), np.full((3, 3), np.nan), np.full(3, np.nan)]
    f += [np.full(3, np.nan), np.full(3, np.nan)]
    return (*f, np.zeros(M, dtype=bool))


def still_batch(draws, o, K, subset, X, x, tau, cam, Rm, cm, A, missed, rounds, th2, k,
                pool_counts, *state):  # fmt: skip
    """``search_batch`` of a global-shutter rig frame (the points in order): ``(h, cost,
    inliers)``."""
    out = search_batch(draws[o : o + 7 * K].reshape((7, K)), subset, X, x, tau, cam, Rm, cm, A,
                       np.arange(len(cam)), True, missed, rounds, np.zeros((0, 3)), 1, np.inf,
                       np.inf, th2, k, pool_counts, *state)  # fmt: skip
    assert out[3] == 0
    return out[:3]


def moving_batch(draws, o, K, subset, X, x, tau, cam, Rm, cm, A, anchor, iterations, w_max,
                 v_max, th2, k, pool_counts, *state, order=None):  # fmt: skip
    """``search_batch`` of a rolling-shutter rig frame (the points in ``order``, None: in
    order): ``(h, cost, inliers, beyond the bounds)``."""
    missed = np.zeros(len(pool_counts), dtype=bool)
    order = np.arange(len(cam)) if order is None else order
    return search_batch(draws[o : o + 7 * K].reshape((7, K)), subset, X, x, tau, cam, Rm, cm, A,
                        order, False, missed, 1, anchor, iterations, w_max, v_max, th2, k,
                        pool_counts, *state)  # fmt: skip


def _frame(seed, counts, turn_deg=0.0):
    """A global-shutter rig frame (equal stamps, 0.5 px noise, 20 % outliers) of
    ``len(counts)`` cameras; the last camera's given mounting turned ``turn_deg`` about y (its
    points then missed by a model of the others)."""
    rng = np.random.default_rng(seed)
    rig = sim_rig.make_rig(len(counts), rng)
    cams = tuple(
        replace(c, camera=replace(c.camera, line_delay=0.0), stamp_offset=0.0) for c in rig.cameras
    )
    truth = sim_rig.rig_motion(rng)
    views = list(sim_rig.rig_frame(sim_rig.Rig(cams), truth, list(counts), rng, 0.5, 0.2).views)
    if turn_deg:
        m = views[-1].mounting
        bad = rotvec_to_matrix(np.radians([0.0, turn_deg, 0.0]))
        views[-1] = replace(views[-1], mounting=Mounting(bad @ m.R, m.c))
    return views


def _step_by_step(views, seed, K, missed, rounds, subset, th):
    """The batch step by step, an independent computation: ``_sample``, ``_hypotheses``
    (global shutter), then the errors of every hypothesis in NumPy and the first lowest MSAC
    cost."""
    pool = StackedViews(views)
    samples = pool.samples(np.random.default_rng(seed), K, subset)
    hyp = rig_mod._hypotheses(pool, samples, 0, missed=missed, rounds=rounds)
    e = np.sqrt(errors2(StackedViews(views, compiled=False), *hyp))
    cost = np.minimum(e * e, th * th).sum(axis=1)
    h = int(np.argmin(cost))
    plain = rig_mod._hypotheses(pool, samples, 0)  # (P3P alone, no correction)
    return hyp, e[h], cost, h, pool, len(plain[0])


@pytest.mark.parametrize(
    ("seed", "counts", "turn", "missed", "rounds", "guided"),
    [
        (1, (30, 24, 12), 0.0, None, 1, False),
        (2, (30, 24, 12), 3.0, (False, False, True), 1, False),
        (3, (16, 20), 3.0, (True, True), 2, False),
        (4, (30, 24, 12), 0.0, (True, False, True), 1, True),
    ],
)
def test_the_fused_still_batch_is_the_batch_step_by_step(seed, counts, turn, missed, rounds,
                                                         guided):  # fmt: skip
    th, K = 2.0, 40
    views = _frame(seed, counts, turn)
    m = None if missed is None else np.array(missed)
    pool0 = StackedViews(views)
    subset = np.flatnonzero(np.arange(len(pool0.cam)) % 3 != 1) if guided else None
    hyp, e, cost, h, pool, n_p3p = _step_by_step(views, 7 + seed, K, m, rounds, subset, th)
    assert n_p3p > K // 2  # (P3P gave models; the correction added some for missed cameras)
    assert (len(hyp[0]) > n_p3p) == (m is not None)
    X, x, tau, (cam, Rm, cm, A) = pool.kernel_arrays
    counts_all = np.bincount(pool.cam, minlength=len(counts))
    draws = np.random.default_rng(7 + seed).random(7 * K)
    out = _buffers(len(cam), len(counts))
    hf, cf, n = still_batch(
        draws, 0, K, rig_mod._NO_SUBSET if subset is None else subset, X, x, tau, cam, Rm, cm,
        A, np.zeros(len(counts), bool) if m is None else m, rounds, th * th, th, counts_all,
        *_NO_STOP, out,
    )  # fmt: skip
    ef, Rf, Cf, wf, tf, missed_f = out
    assert np.isnan(wf).all() and np.isnan(tf).all()  # (a still model's velocities: none)
    assert hf >= 0
    assert cf == pytest.approx(cost[h], rel=1e-12)
    np.testing.assert_allclose(ef, e, rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(Rf, hyp[0][h])
    np.testing.assert_array_equal(Cf, hyp[1][h])
    inl = e < th
    assert n == np.count_nonzero(inl if subset is None else inl[subset])
    hit = np.bincount(pool.cam[inl], minlength=len(counts))
    np.testing.assert_array_equal(missed_f, (counts_all >= 3) & (hit == 0))
    if turn and len(counts) == 3:  # (the turned camera's points: none an inlier)
        assert missed_f[-1]


def test_the_held_still_solve_is_the_batched_solver_with_held_prior_rows():
    """The rig's compiled solve of a global-shutter rig frame's samples with the velocities
    held at zero (``prerotated_solutions`` with the rig solver, held; ``_held_solve``'s: ``tau``
    zero, one step, prior rows the identity with right-hand side zero), its points gathered
    from the pool by sample and pre-rotated (here by the identity), gives the batched rig
    solver's v (as the rotation it composes), C and validity with those prior rows
    (``gr6p_1lin_batch``) bit for bit: the RANSAC samples of a frame of
    three cameras (noise, outliers) and a sample it refuses (one point six times: rank loss)."""
    pool = StackedViews(_frame(12, (24, 24, 24)))
    X, x, _, (cam, Rm, cm, _) = pool.kernel_arrays
    S = pool.samples(np.random.default_rng(12), 60)
    S[5] = S[5, 0]  # (one point six times: rank loss)
    K = len(S)
    held = (np.broadcast_to(np.eye(6), (K, 6, 6)).copy(), np.zeros((K, 6)))
    ref = gr6p_1lin_batch(x[S], X[S], np.zeros((K, 6)), cam[S], Rm, cm, 1, prior_rows=held)
    Rg = np.broadcast_to(np.eye(3), (K, 3, 3)).copy()
    still = (cam, Rm, cm, np.zeros(len(X)), True, np.arange(len(X)))  # (a still frame's views)
    R, C, w, t, ok = prerotated_solutions(S, Rg, np.ones(K, dtype=bool), x, X, still[3], 0.0,
                                          *RIG_KERNELS, 1, np.zeros((K, 3)), False,
                                          still)  # fmt: skip
    assert not ok[5] and ok.sum() == K - 1
    np.testing.assert_array_equal(ok, ref.valid)
    np.testing.assert_array_equal(R, compose_rotvec(np.ascontiguousarray(ref.v), Rg))
    np.testing.assert_array_equal(C, ref.C)
    assert not w.any() and not t.any()


def _moving_frame(seed, counts):
    """A rolling-shutter rig frame (readout 15-35 ms, stamps up to 10 ms apart, turning at
    1.5 rad/s, moving at 1.5 m/s; 0.5 px noise, 20 % outliers)."""
    rng = np.random.default_rng(seed)
    rig = sim_rig.make_rig(len(counts), rng)
    truth = sim_rig.rig_motion(rng, 1.5, 1.5)
    return list(sim_rig.rig_frame(rig, truth, list(counts), rng, 0.5, 0.2).views), truth


@pytest.mark.parametrize(
    ("seed", "counts", "anchored", "w_max", "guided", "pretest"),
    [
        (11, (36, 36, 36), False, np.inf, False, 0),
        (12, (30, 20), False, 2.0, False, 0),
        (13, (36, 36, 36), True, np.inf, False, 0),
        (14, (36, 24, 12), False, 2.0, True, 0),
        (11, (36, 36, 36), False, np.inf, False, 24),
        (15, (100, 100, 100), False, 2.0, False, 24),
    ],
)
def test_the_fused_rolling_shutter_batch_is_the_batch_step_by_step(seed, counts, anchored, w_max,
                                                                   guided, pretest):  # fmt: skip
    """``moving_batch`` against ``_sample``, ``_hypotheses`` (P3P or an anchor's rotation
    pre-rotating the rig solver) and the motion bounds, scored in NumPy: the same best model
    (its rotation to rounding: the compiled Rodrigues), cost, errors, inliers, and the same
    number of solutions beyond the bounds; scored in full, or with the camera's pre-test on
    the first ``pretest`` points of a random order (which leaves the batch's best model the
    best here: it drops models that cannot beat it)."""
    th, K, iterations, v_max = 2.0, 40, 3, 10.0
    views, truth = _moving_frame(seed, counts)
    pool = StackedViews(views)
    subset = np.flatnonzero(np.arange(len(pool.cam)) % 3 != 1) if guided else None
    anchor = (truth.R, truth.C) if anchored else None
    samples = pool.samples(np.random.default_rng(seed), K, subset)
    hyp = rig_mod._hypotheses(pool, samples, iterations, anchor)
    ok = plausible_motion(None, hyp[1], hyp[2], hyp[3], (w_max, v_max))
    beyond = int(np.count_nonzero(~ok))
    hyp = tuple(a[ok] for a in hyp)
    e = np.sqrt(errors2(StackedViews(views, compiled=False), *hyp))
    cost = np.minimum(e * e, th * th).sum(axis=1)
    h = int(np.argmin(cost))
    if w_max < np.inf:
        assert beyond > 0  # (the bounds drop some solutions)
    X, x, tau, (cam, Rm, cm, A) = pool.kernel_arrays
    draws = np.random.default_rng(seed).random(7 * K)
    out = _buffers(len(cam), len(counts))
    order = np.random.default_rng(seed).permutation(len(cam)) if pretest else None
    hf, cf, n, beyond_f = moving_batch(
        draws, 0, K, rig_mod._NO_SUBSET if subset is None else subset, X, x, tau, cam, Rm, cm,
        A, np.array(truth.R) if anchored else rig_mod._NO_ANCHOR, iterations, w_max,
        v_max, th * th, th, np.bincount(pool.cam, minlength=len(counts)), np.inf, pretest, 0,
        out, order=order,
    )  # fmt: skip
    ef, Rf, Cf, wf, tf, _ = out
    assert hf >= 0 and beyond_f == beyond
    assert cf == pytest.approx(cost[h], rel=1e-9)
    np.testing.assert_allclose(ef, e[h], rtol=1e-8, atol=1e-8)
    for got, want in zip((Rf, Cf, wf, tf), (a[h] for a in hyp), strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12)
    inl = e[h] < th
    assert n == np.count_nonzero(inl if subset is None else inl[subset])


@pytest.mark.parametrize(("counts", "every"), [((30, 24, 12), 0), ((16, 2, 20), 3), ((5, 4), 2)])
def test_the_compiled_sampling_distribution_is_the_pools(counts, every):
    """``batch_sampling`` (computed in each compiled batch) gives ``view_sampling``'s counts,
    starts, eligible cameras, cdf and point count, bit for bit, over the whole pool or a
    subset (every point but each ``every``-th)."""
    pool = StackedViews(_frame(31, counts))
    subset = np.flatnonzero(np.arange(len(pool.cam)) % every != 1) if every else None
    got = batch_sampling(pool.cam, np.bincount(pool.cam, minlength=len(counts)),
                         rig_mod._NO_SUBSET if subset is None else subset)  # fmt: skip
    want = view_sampling(pool.cam if subset is None else pool.cam[subset], len(counts))
    for g, w in zip(got[:4], want[:4], strict=True):
        np.testing.assert_array_equal(g, w)
        assert g.dtype == w.dtype
    assert got[4] == want[4]


@pytest.mark.parametrize(("counts", "every"), [((30, 24, 12), 0), ((16, 2, 20), 3), ((5, 4), 0),
                                               ((3, 9), 4)])  # fmt: skip
def test_the_compiled_samples_are_the_numpy_forms(counts, every):
    """The compiled samples (``batch_samples``: a camera's draws, ``draw_sample``, the first
    three in the chosen camera's range of the pool, the others in the whole pool) are the
    NumPy form's (``draw_samples_numpy`` with those ranges) from the same draws, bit for bit,
    over the whole pool or a subset (every point but each ``every``-th): the first three in
    one camera, all six distinct."""
    views = _frame(31, counts)
    pool = StackedViews(views)
    subset = np.flatnonzero(np.arange(len(pool.cam)) % every != 1) if every else None
    got = pool.samples(np.random.default_rng(5), 400, subset)
    want = StackedViews(views, compiled=False).samples(np.random.default_rng(5), 400, subset)
    np.testing.assert_array_equal(got, want)
    assert (pool.cam[got[:, :3]] == pool.cam[got[:, :1]]).all()
    assert all(len(set(row)) == 6 for row in got.tolist())
    if subset is not None:
        assert np.isin(got, subset).all()


def _least_error_pose(pool, sample):
    """Every Lambda Twist pose of ``sample``'s first 3 points (in their camera), mapped to the
    rig, and the index of the one of least global-shutter error on its other 3 points
    projected through their own cameras' mountings (None: every pose puts a point behind its
    camera): an independent computation of a rig sample's pre-rotation."""
    c = pool.cam[sample[0]]
    Rc, tc = lambda_twist(np.c_[pool.x[sample[:3]], np.ones(3)], pool.X[sample[:3]])
    poses, errors = [], []
    for R_cam, C_cam in zip(Rc, tc, strict=True):
        R = pool.R_mount[c].T @ R_cam
        C = pool.R_mount[c].T @ (C_cam - pool.c_mount[c])
        e = 0.0
        for i in sample[3:]:
            q = pool.R_mount[pool.cam[i]] @ (R @ pool.X[i] + C) + pool.c_mount[pool.cam[i]]
            e = e + np.sum((q[:2] / q[2] - pool.x[i]) ** 2) if q[2] > 0 else np.inf
        poses.append((R, C))
        errors.append(e)
    best = int(np.argmin(errors)) if np.isfinite(errors).any() else None
    return poses, best


@pytest.mark.parametrize("compiled", [True, False])
def test_a_rig_sample_keeps_one_p3p_pose_as_a_camera_does(compiled):
    """Each of a rig frame's samples pre-rotates the rig solver by one P3P pose, as a camera's
    sample does: the pose of least global-shutter error on the sample's other 3 points seen
    through their cameras' mountings. So a frame's moving hypotheses (one rig solve each) are
    at most its samples, not every P3P root's (up to 4 per sample)."""
    views = _moving_frame(5, (30, 24, 12))[0]
    pool = StackedViews(views, compiled=compiled)
    K = 60
    samples = pool.samples(np.random.default_rng(3), K, None)
    R, C, own = rig_mod._p3p_on_rig(pool, samples)
    assert len(np.unique(own)) == len(own) == len(R)
    several = 0
    for k, sample in enumerate(samples):
        poses, best = _least_error_pose(pool, sample)
        several += len(poses) > 1
        if best is None:
            assert k not in own
            continue
        assert k in own
        np.testing.assert_allclose(R[own == k][0], poses[best][0], atol=1e-7)
        np.testing.assert_allclose(C[own == k][0], poses[best][1], atol=1e-6)
    assert several > K // 4  # (many samples have more than one P3P pose to choose from)
    assert len(own) > K // 2
    moving = rig_mod._hypotheses(pool, samples, 3)
    assert len(moving[0]) <= K


def test_a_batch_that_poses_no_sample_finds_no_model():
    """A still rig frame's batch in which P3P poses none of the samples (every world point
    the same: no triangle) has no model to score: the batch reports none (``h`` -1, the
    best cost unchanged) and writes nothing, where reading the first score of no scores
    once took whatever lay beyond the arrays as the best model."""
    views = _frame(1, (30, 24, 12))
    pool = StackedViews(views)
    X, x, tau, (cam, Rm, cm, A) = pool.kernel_arrays
    X = np.ascontiguousarray(np.broadcast_to(X[0], X.shape))
    counts = np.bincount(cam, minlength=3)
    draws = np.random.default_rng(1).random(7 * 64)
    out = _buffers(len(cam), 3)
    missed = np.zeros(3, dtype=bool)
    got = still_batch(draws, 0, 64, rig_mod._NO_SUBSET, X, x, tau, cam, Rm, cm, A, missed, 1,
                      4.0, 2.0, counts, 7.0, 0, 0, out)  # fmt: skip
    assert got == (-1, 7.0, 0)
    assert all(np.isnan(a).all() for a in out[:5]) and not out[5].any()
