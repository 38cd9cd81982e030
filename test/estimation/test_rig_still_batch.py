"""The rig's global-shutter RANSAC batch in one compiled call (``_still_batch``) against the same
batch step by step (the sampling, Lambda Twist mapped to the rig, the held rig solver's
correction) scored in NumPy (the ``"numpy"`` implementation's reprojection errors and MSAC
cost): the same best model, cost, errors, inliers and missed cameras."""

from dataclasses import replace

import numpy as np
import pytest

from rs_localizer.estimation import rig as rig_mod
from rs_localizer.frames import Mounting
from rs_localizer.geometry import rotvec_to_matrix
from rs_localizer.sim import rig as sim_rig


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
    """The batch as the search ran it before: ``_sample``, ``_hypotheses_still``, then the
    errors of every hypothesis in NumPy and the first lowest MSAC cost."""
    pool = rig_mod._Pool(views)
    samples = rig_mod._sample(np.random.default_rng(seed), pool, K, subset)
    hyp = rig_mod._hypotheses_still(pool, samples, None, missed, rounds)
    e = rig_mod._errors_px(rig_mod._Pool(views, numpy=True), *hyp)
    cost = np.minimum(e * e, th * th).sum(axis=1)
    h = int(np.argmin(cost))
    plain = rig_mod._hypotheses_still(pool, samples)  # (P3P alone, no correction)
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
    pool0 = rig_mod._Pool(views)
    subset = np.flatnonzero(np.arange(len(pool0.cam)) % 3 != 1) if guided else None
    hyp, e, cost, h, pool, n_p3p = _step_by_step(views, 7 + seed, K, m, rounds, subset, th)
    assert n_p3p > K // 2  # (P3P gave models; the correction added some for missed cameras)
    assert (len(hyp[0]) > n_p3p) == (m is not None)
    X, x, tau, (cam, Rm, cm, A) = rig_mod._kernel_arrays(pool)
    counts_all = np.bincount(pool.cam, minlength=len(counts))
    u = np.random.default_rng(7 + seed).random(7 * K).reshape(7, K)
    hf, cf, ef, Rf, Cf, n, missed_f = rig_mod._still_batch(
        u, rig_mod._sampling_of(pool, subset),
        rig_mod._NO_SUBSET if subset is None else subset, rig_mod._bearings(pool), X, x, tau,
        cam, Rm, cm, A, np.zeros(len(counts), bool) if m is None else m, rounds, th * th, th,
        counts_all,
    )  # fmt: skip
    assert hf == h
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
