"""RANSAC's numba kernels against independent NumPy computations: sampling, the pre-rotated
gather, the P3P pre-rotation choice and the preemptive MSAC scoring."""

import numpy as np
import pytest

from rs_localizer.estimation.sampling import draw_samples, gather_prerotated, select_prerotations
from rs_localizer.estimation.scoring import errors2, msac_scores
from rs_localizer.geometry import rotation_angle_deg, rotvec_to_matrix
from rs_localizer.sim.synthetic import make_frame
from rs_localizer.solvers import p3p_batch


def test_draw_samples_are_distinct_in_range_and_uniform():
    rng = np.random.default_rng(0)
    pool, s, K = 20, 6, 20000
    S = draw_samples(rng.random((K, s)), pool)
    assert S.shape == (K, s) and S.min() >= 0 and S.max() < pool
    srt = np.sort(S, axis=1)
    assert not (srt[:, 1:] == srt[:, :-1]).any()
    # every position, and the pairs of the first two, are uniform (chi-square, ~5 sigma bounds)
    for j in range(s):
        counts = np.bincount(S[:, j], minlength=pool)
        chi2 = ((counts - K / pool) ** 2 / (K / pool)).sum()
        assert chi2 < (pool - 1) + 5 * np.sqrt(2 * (pool - 1))
    pairs = np.bincount(S[:, 0] * pool + S[:, 1], minlength=pool * pool)
    expected = K / (pool * (pool - 1))
    valid = np.ones((pool, pool), dtype=bool)
    np.fill_diagonal(valid, False)
    assert (pairs.reshape(pool, pool)[~valid] == 0).all()
    chi2 = ((pairs.reshape(pool, pool)[valid] - expected) ** 2 / expected).sum()
    dof = pool * (pool - 1) - 1
    assert chi2 < dof + 5 * np.sqrt(2 * dof)


def test_draw_samples_edge_cases_and_reproducibility():
    u = np.random.default_rng(1).random((50, 6))
    perm = draw_samples(u, 6)  # pool == s: permutations
    assert (np.sort(perm, axis=1) == np.arange(6)).all()
    assert (draw_samples(u, 100) == draw_samples(u.copy(), 100)).all()
    top = draw_samples(np.full((3, 6), np.nextafter(1.0, 0.0)), 10)  # u -> 1 stays in range
    assert top.max() < 10 and (np.sort(top, axis=1)[:, 1:] != np.sort(top, axis=1)[:, :-1]).all()


def test_gather_prerotated_matches_numpy():
    rng = np.random.default_rng(2)
    x, X, r = rng.normal(size=(30, 2)), rng.normal(size=(30, 3)), rng.normal(size=30)
    S = draw_samples(rng.random((7, 6)), 30)
    R = np.array([rotvec_to_matrix(v) for v in rng.normal(size=(7, 3))])
    xs, Xs, rs = gather_prerotated(S, R, x, X, r)
    np.testing.assert_array_equal(xs, x[S])
    np.testing.assert_array_equal(rs, r[S])
    np.testing.assert_allclose(Xs, np.einsum("kij,knj->kni", R, X[S]), atol=1e-14)


def test_select_prerotations_picks_the_consistent_p3p_root():
    rng = np.random.default_rng(3)
    frames = [make_frame(rng, 6, rs_speed=0.0) for _ in range(25)]
    x = np.concatenate([f.x for f in frames])
    X = np.concatenate([f.X for f in frames])
    # one world frame per sample is not needed: each sample only uses its own rows
    S = np.arange(len(x)).reshape(25, 6)
    b = np.concatenate([x, np.ones((len(x), 1))], axis=1)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    R, C, owner = p3p_batch(b[S[:, :3]], X[S[:, :3]])
    Rsel, Csel, ok = select_prerotations(R, C, owner, S, X, x, len(S))
    assert ok.all()
    for k, f in enumerate(frames):
        assert rotation_angle_deg(Rsel[k], f.R) < 1e-5
        np.testing.assert_allclose(Csel[k], f.C, atol=1e-6)


@pytest.mark.parametrize("pretest", [0, 24])
def test_preemptive_msac_finds_the_brute_force_best(pretest):
    rng = np.random.default_rng(4)
    f = make_frame(rng, 300, rs_speed=0.5, noise_px=1.0, outlier_ratio=0.3)
    H = 40
    Rs = np.empty((H, 3, 3))
    Cs, ws, ts = np.empty((H, 3)), np.empty((H, 3)), np.empty((H, 3))
    for h in range(H):  # perturbations of the truth, from small to gross
        s = 10.0 ** rng.uniform(-4, -0.5)
        Rs[h] = rotvec_to_matrix(rng.normal(size=3) * s) @ f.R
        Cs[h], ws[h], ts[h] = (
            f.C + rng.normal(size=3) * s,
            f.w + rng.normal(size=3) * s,
            f.t + rng.normal(size=3) * s,
        )
    valid = rng.random(H) > 0.1
    d, r0e = np.array([0.0, 1.0]), np.full(len(f.x), f.r0)
    th2 = (2.0 / 1207.0) ** 2
    full = np.array(
        [
            np.minimum(errors2(f.x, f.X, r0e, d, Rs[h], Cs[h], ws[h], ts[h]), th2).sum()
            for h in range(H)
        ]
    )
    full[~valid] = np.inf
    sc, cnt = msac_scores(f.x, f.X, r0e, d, Rs, Cs, ws, ts, th2, valid, np.inf, True, pretest, 0)
    best = int(np.argmin(full))
    assert int(np.argmin(sc)) == best
    np.testing.assert_allclose(sc[best], full[best], rtol=1e-12)
    e2 = errors2(f.x, f.X, r0e, d, Rs[best], Cs[best], ws[best], ts[best])
    assert cnt[best] == np.count_nonzero(e2 < th2)
    finite = np.isfinite(sc)
    np.testing.assert_allclose(sc[finite], full[finite], rtol=1e-12)  # never a partial score
    assert not finite[~valid].any()
    # a bound below every hypothesis leaves nothing
    none, _ = msac_scores(
        f.x, f.X, r0e, d, Rs, Cs, ws, ts, th2, valid, 0.5 * full[best], True, pretest, 0
    )
    assert np.isinf(none).all()


@pytest.mark.parametrize("shuffled", [False, True])
def test_a_rig_of_one_camera_at_the_identity_is_scored_as_the_camera_bit_for_bit(shuffled):
    """``msac_scores`` with the mountings (a rig's scoring: each point's error its camera's,
    the points visited in ``order``) of one camera mounted at the identity, its capture times
    the camera's measured ones and its pixel Jacobian the camera's whitening, gives the
    camera's scores and inlier counts, pre-test included, bit for bit: on the points in order,
    and in a random order against the camera's points shuffled by it. ``mounted_errors``
    gives the camera's errors (the square roots of ``errors2``'s)."""
    from rs_localizer.estimation.scoring import mounted_errors

    rng = np.random.default_rng(5)
    f = make_frame(rng, 300, rs_speed=0.5, noise_px=1.0, outlier_ratio=0.3)
    H = 40
    Rs = np.array([rotvec_to_matrix(rng.normal(size=3) * 10.0 ** rng.uniform(-4, -1)) @ f.R
                   for _ in range(H)])  # fmt: skip
    Cs, ws, ts = (v + rng.normal(size=(H, 3)) * 1e-3 for v in (f.C, f.w, f.t))
    valid = rng.random(H) > 0.1
    N = len(f.x)
    d, r0e = np.array([0.0, 1.0]), np.full(N, f.r0)
    W = np.tile([1.1, 0.05, -0.02, 0.9], (N, 1))
    th2 = (2.0 / 1207.0) ** 2
    order = rng.permutation(N) if shuffled else np.arange(N)
    x, X, r, Wo = f.x[order], f.X[order], r0e[order], W[order]
    want = msac_scores(x, X, r, d, Rs, Cs, ws, ts, th2, valid, np.inf, True, 24, 0, 0.5, True, Wo)
    tau = f.x[:, 1] - r0e  # (the camera's measured capture time, d . x - r0e)
    mount = (np.zeros(N, dtype=np.int64), np.eye(3)[None], np.zeros((1, 3)), tau, False, order)
    got = msac_scores(f.x, f.X, r0e, d, Rs, Cs, ws, ts, th2, valid, np.inf, True, 24, 0, 0.5,
                      True, W, mount)  # fmt: skip
    assert np.isfinite(want[0]).sum() >= 2  # (several completed: the bound and the pre-test act)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    h = int(np.argmin(got[0]))
    e2 = errors2(f.x, f.X, r0e, d, Rs[h], Cs[h], ws[h], ts[h], True, True, W)
    np.testing.assert_array_equal(mounted_errors(Rs, Cs, ws, ts, h, f.X, f.x, W, mount),
                                  np.sqrt(e2))  # fmt: skip
