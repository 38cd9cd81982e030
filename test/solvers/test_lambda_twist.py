"""Lambda Twist P3P (rs_localizer.solvers.lambda_twist) against ground truth, against PoseLib's
``poselib.p3p`` on the same inputs, on degenerate input, and batched against single calls."""

import sys

import numpy as np
import poselib
import pytest

from rs_localizer.sim.synthetic import make_frame
from rs_localizer.solvers.lambda_twist import _cubic_root, lambda_twist, lambda_twist_batch

P = sys.modules["rs_localizer.solvers.p3p"]  # the package exports a function named p3p


def _bearings(x):
    b = np.concatenate([x, np.ones(x.shape[:-1] + (1,))], axis=-1)
    return b / np.linalg.norm(b, axis=-1, keepdims=True)


def _frames(seed, n):
    rng = np.random.default_rng(seed)
    frames = [make_frame(rng, 3, rs_speed=0.0) for _ in range(n)]
    return (
        np.array([_bearings(f.x) for f in frames]),
        np.array([f.X for f in frames]),
        np.array([f.R for f in frames]),
        np.array([f.C for f in frames]),
    )


def _pose_distance(R, C, R2, C2):
    """max(|R - R2|_max, |C - C2|_max / (1 + |C2|)) for every pair: (n, m)."""
    dR = np.abs(R[:, None] - R2[None]).max(axis=(2, 3))
    dC = np.abs(C[:, None] - C2[None]).max(axis=2) / (1.0 + np.linalg.norm(C2, axis=1))[None]
    return np.maximum(dR, dC)


def test_true_pose_is_among_the_solutions():
    b, X, R, C = _frames(0, 2000)
    err = np.zeros(len(b))
    for k in range(len(b)):
        Rs, Cs = lambda_twist(b[k], X[k])
        assert 1 <= len(Rs) <= 4
        err[k] = _pose_distance(Rs, Cs, R[k : k + 1], C[k : k + 1]).min()
        # every solution is a rotation putting the three points on their rays, in front
        np.testing.assert_allclose(
            np.einsum("nji,njk->nik", Rs, Rs), np.broadcast_to(np.eye(3), Rs.shape), atol=1e-12
        )  # the Newton-Schulz polish
        np.testing.assert_allclose(np.linalg.det(Rs), 1.0, atol=1e-9)
        Xc = np.einsum("nij,pj->npi", Rs, X[k]) + Cs[:, None]
        assert np.all(Xc[..., 2] > 0)
        np.testing.assert_allclose(
            Xc / np.linalg.norm(Xc, axis=2, keepdims=True),
            np.broadcast_to(b[k], Xc.shape),
            atol=1e-9,
        )
    assert (err < 1e-9).mean() >= 0.999, (err < 1e-9).mean()
    # the Gauss-Newton refinement of the depths (paper sec. 3.8) matters in the tail: 4e-13
    # here, 3e-12 without it
    assert np.quantile(err, 0.99) < 1e-12, np.quantile(err, 0.99)


def test_same_solutions_as_poselib():
    """Same number of solutions and the same poses (to 1e-6) as PoseLib's Lambda Twist."""
    b, X, _, _ = _frames(1, 1000)
    same = 0
    for k in range(len(b)):
        Rs, Cs = lambda_twist(b[k], X[k])
        ref = poselib.p3p(b[k], X[k])
        Rp = np.array([p.R for p in ref]).reshape(-1, 3, 3)
        Cp = np.array([p.t for p in ref]).reshape(-1, 3)
        if len(Rs) == len(Rp) and len(Rs) > 0:
            d = _pose_distance(Rs, Cs, Rp, Cp)
            same += bool((d.min(axis=0) < 1e-6).all() and (d.min(axis=1) < 1e-6).all())
    assert same >= 0.995 * len(b), same


def _degenerate_cases():
    rng = np.random.default_rng(2)
    b, X, _, _ = _frames(3, 1)
    b, X = b[0], X[0]
    collinear = X.copy()
    collinear[2] = X[0] + 0.4 * (X[1] - X[0])
    dup_X = X.copy()
    dup_X[1] = X[0]
    dup_b = b.copy()
    dup_b[2] = b[1]
    all_same = np.repeat(X[:1], 3, axis=0)
    nan_b = b.copy()
    nan_b[0, 1] = np.nan
    inf_X = X.copy()
    inf_X[2, 0] = np.inf
    near_collinear = collinear + 1e-13 * rng.normal(size=(3, 3))
    return {
        "collinear X": (b, collinear),
        "duplicated X": (b, dup_X),
        "duplicated bearing": (dup_b, X),
        "one point thrice": (b, all_same),
        "zeros": (np.zeros((3, 3)), np.zeros((3, 3))),
        "NaN bearing": (nan_b, X),
        "inf point": (b, inf_X),
        "collinear X up to 1e-13": (b, near_collinear),
    }


@pytest.mark.parametrize("name", list(_degenerate_cases()))
def test_degenerate_input_gives_no_solution(name):
    bk, Xk = _degenerate_cases()[name]
    Rs, Cs = lambda_twist(bk, Xk)
    assert Rs.shape == (0, 3, 3) and Cs.shape == (0, 3)


def test_random_and_near_degenerate_input_gives_finite_rotations():
    """Unstructured, nearly collinear, coplanar-ray and nearly parallel-ray triplets over 16
    orders of magnitude of scale: never NaN, every returned R orthonormal."""
    rng = np.random.default_rng(4)
    total = 0
    for i in range(3000):
        y = rng.normal(size=(3, 3))
        X = rng.normal(size=(3, 3)) * 10.0 ** rng.uniform(-8, 8)
        mode = i % 4
        if mode == 1:
            X[2] = (
                X[0] + rng.normal() * (X[1] - X[0]) + 1e-12 * np.abs(X).max() * rng.normal(size=3)
            )
        elif mode == 2:
            y[2] = y[0] + rng.normal() * (y[1] - y[0])
        elif mode == 3:
            y[1] = y[0] + 1e-9 * rng.normal(size=3)
        Rs, Cs = lambda_twist(y, X)
        total += len(Rs)
        assert np.isfinite(Rs).all() and np.isfinite(Cs).all()
        if len(Rs):
            assert np.abs(np.einsum("nji,njk->nik", Rs, Rs) - np.eye(3)).max() < 1e-5
    assert total > 0  # the loop did exercise solutions


def test_nearly_collinear_points_give_rotations_or_nothing():
    """Exact data with the third world point 1e-6 (relative) off the line through the others:
    the depths are ill-conditioned there, so ``Y X^-1`` is far from a rotation; such solutions
    are dropped, whatever is returned is orthonormal. At 1e-2 off the line the true pose is
    found."""
    rng = np.random.default_rng(10)
    for offset, found_min in ((1e-6, 0), (1e-2, 95)):
        found = 0
        for _ in range(100):
            Xc = np.c_[rng.uniform(-1, 1, (3, 2)), rng.uniform(2, 6, 3)]  # camera frame
            Xc[2] = Xc[0] + rng.uniform(0.2, 0.8) * (Xc[1] - Xc[0]) + offset * rng.normal(size=3)
            R0 = np.linalg.qr(rng.normal(size=(3, 3)))[0]
            R0 *= np.linalg.det(R0)
            C0 = rng.normal(size=3)
            X = (Xc - C0) @ R0  # X_cam = R0 X + C0
            Rs, Cs = lambda_twist(_bearings(Xc[:, :2] / Xc[:, 2:]), X)
            assert np.isfinite(Rs).all() and np.isfinite(Cs).all()
            if len(Rs):
                assert np.abs(np.einsum("nji,njk->nik", Rs, Rs) - np.eye(3)).max() <= 1e-6
                found += _pose_distance(Rs, Cs, R0[None], C0[None]).min() < 1e-6
        assert found >= found_min, (offset, found)


def test_batch_equals_single_calls():
    b, X, _, _ = _frames(5, 60)
    cases = list(_degenerate_cases().values())
    b = np.concatenate([b, np.array([c[0] for c in cases])])
    X = np.concatenate([X, np.array([c[1] for c in cases])])
    perm = np.random.default_rng(6).permutation(len(b))
    b, X = np.ascontiguousarray(b[perm]), np.ascontiguousarray(X[perm])
    R, C, owner = lambda_twist_batch(b, X)
    assert owner.dtype == np.int64 and np.all(np.diff(owner) >= 0)
    assert np.isfinite(R).all() and np.isfinite(C).all()
    singles = [lambda_twist(b[k], X[k]) for k in range(len(b))]
    np.testing.assert_array_equal(owner, np.repeat(np.arange(len(b)), [len(s[0]) for s in singles]))
    np.testing.assert_array_equal(R, np.concatenate([s[0] for s in singles]))
    np.testing.assert_array_equal(C, np.concatenate([s[1] for s in singles]))
    empty = lambda_twist_batch(np.zeros((0, 3, 3)), np.zeros((0, 3, 3)))
    assert [a.shape for a in empty] == [(0, 3, 3), (0, 3), (0,)]


@pytest.mark.parametrize("backend", ["lambda_twist", "poselib", "opencv"])
def test_p3p_batch_backends_contain_ground_truth(backend):
    b, X, R, C = _frames(7, 30)
    # OpenCV's own P3P is less exact in 4.6 (Debian 12: 1.3e-6 here) than in 5.x
    tol = 1e-5 if backend == "opencv" else 1e-6
    Rs, Cs, owner = P.p3p_batch(b, X, backend=backend)
    assert Rs.shape == (len(owner), 3, 3) and Cs.shape == (len(owner), 3)
    assert np.all(np.diff(owner) >= 0)
    for k in range(len(b)):
        mine = owner == k
        assert 1 <= mine.sum() <= 4
        assert _pose_distance(Rs[mine], Cs[mine], R[k : k + 1], C[k : k + 1]).min() < tol


def test_p3p_default_backend_is_lambda_twist_and_matches_poselib():
    rng = np.random.default_rng(8)
    f = make_frame(rng, 3, rs_speed=0.0)
    assert P.DEFAULT_BACKEND == "lambda_twist"  # RS_LOCALIZER_P3P is not set in the tests
    ours = P.p3p(f.x, f.X)
    Rl, Cl = lambda_twist(_bearings(f.x), f.X)
    np.testing.assert_array_equal(np.array([s.R for s in ours]), Rl)
    ref = P.p3p(f.x, f.X, backend="poselib")
    d = _pose_distance(Rl, Cl, np.array([s.R for s in ref]), np.array([s.C for s in ref]))
    assert len(ref) == len(ours) and (d.min(axis=1) < 1e-6).all()
    with pytest.raises(ValueError):
        P.p3p(f.x, f.X, backend="nope")
    with pytest.raises(ValueError):
        P.p3p_batch(_bearings(f.x)[None], f.X[None], backend="nope")
    with pytest.raises(ValueError):
        P.p3p(f.x[:2], f.X[:2])
    bad = f.X.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError):
        P.p3p(f.x, bad)


def test_cubic_root_is_the_best_conditioned_real_root():
    """Against numpy.roots: a real root, and of the real roots the one with the largest |f'|."""
    rng = np.random.default_rng(9)
    for _ in range(500):
        b, c, d = rng.normal(size=3) * 10.0 ** rng.uniform(-2, 2, size=3)
        g = _cubic_root(b, c, d)
        roots = np.roots([1.0, b, c, d])
        real = roots[np.abs(roots.imag) <= 1e-7 * (1 + np.abs(roots))].real
        assert np.abs(real - g).min() <= 1e-7 * (1 + abs(g))
        df = np.abs(3 * real**2 + 2 * b * real + c)
        assert abs(3 * g * g + 2 * b * g + c) >= (1 - 1e-6) * df.max() - 1e-9
