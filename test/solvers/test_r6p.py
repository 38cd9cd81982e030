"""Tests of the minimal R6P solver (all roots of paper eq. 5) against synthetic ground truth.

Every instance is generated exactly from eq. 5::

    lambda_i [x_i; 1] = (I + (r_i - r0)[w]x)(I + [v]x) X_i + C + (r_i - r0) t

either with random RS coordinates r_i (x_i then follows from eq. 5) or with r_i = y_i, the
self-consistent rolling-shutter projection of :func:`rs_localizer.geometry.rs_project_linear`.
"""

import importlib
import zlib

import numpy as np
import pytest

from rs_localizer.geometry import rs_project_linear, skew
from rs_localizer.solvers._common import DegenerateInputError, RSSolution, algebraic_error
from rs_localizer.solvers.r6p import r6p

GT_TOL = 1e-8  # relative error of the ground-truth root


def _eq5_points(X, v, C, w, t, r, r0):
    """Right-hand side p_i of eq. 5 (camera coordinates at each point's RS coordinate)."""
    tau = np.asarray(r) - r0
    P = X @ (np.eye(3) + skew(v)).T
    return P + tau[:, None] * (P @ skew(w).T) + C + tau[:, None] * t


def _instance(rng, omega, r0, mode="rows", planar=False):
    """Random R6P instance from eq. 5.

    omega: |w| in rad per unit r (and the bound of |v| in rad). mode: "rows" (r = y, via
    rs_project_linear) or "random" (random r in [-1, 1]). Returns (x, X, r, gt) with
    gt = (v, C, w, t) stacked (12,), and r = None in "rows" mode (the solver default x[:, 1]).
    """
    while True:
        v = rng.normal(size=3)
        v *= rng.uniform(0.0, omega) / np.linalg.norm(v)
        w = rng.normal(size=3)
        w *= omega / np.linalg.norm(w)
        t = rng.normal(size=3) * 0.2
        X = rng.uniform(-1.0, 1.0, (6, 3))
        if planar:
            X[:, 2] = 0.0
        C = np.r_[rng.uniform(-0.3, 0.3, 2), rng.uniform(2.0, 3.0)]
        if mode == "rows":
            x, r = rs_project_linear(X, np.eye(3) + skew(v), C, w, t, r0)
            if not np.isfinite(x).all():
                continue
        else:
            r = rng.uniform(-1.0, 1.0, 6)
            p = _eq5_points(X, v, C, w, t, r, r0)
            x = p[:, :2] / p[:, 2:]
        p = _eq5_points(X, v, C, w, t, r, r0)
        if (p[:, 2] < 0.5).any():
            continue
        # the data satisfy eq. 5 exactly (up to rounding)
        assert algebraic_error(x, X, r, r0, v, C, w, t) < 1e-13
        return x, X, (None if mode == "rows" else r), np.r_[v, C, w, t]


def _z(sol):
    return np.r_[sol.v, sol.C, sol.w, sol.t]


def _gt_error(sols, gt):
    """Smallest relative error of any returned root w.r.t. the ground truth."""
    if not sols:
        return np.inf
    return min(np.linalg.norm(_z(s) - gt) / np.linalg.norm(gt) for s in sols)


def _term_scale(x, X, r, r0, s):
    """Magnitude of the terms of eq. 5 at a root (rounding in the residual grows with it)."""
    tau = np.abs(r - r0)
    Y = np.linalg.norm(X @ (np.eye(3) + skew(s.v)).T, axis=1)
    T = Y * (1 + tau * np.linalg.norm(s.w)) + np.linalg.norm(s.C) + tau * np.linalg.norm(s.t)
    return float(np.max(T * (1 + np.abs(x).max(axis=1))))


def _check_roots(x, X, r, r0, sols):
    """Every returned root is a finite, sorted, exact root of eq. 5."""
    r_eff = x[:, 1] if r is None else r
    errs = [s.algebraic_error for s in sols]
    assert errs == sorted(errs)
    for s in sols:
        assert isinstance(s, RSSolution)
        for a in (s.v, s.C, s.w, s.t):
            assert a.shape == (3,) and np.isfinite(a).all()
        assert s.iterations >= 0
        # the reported error is the RMS residual of eq. 5 (same value as _common.algebraic_error
        # up to rounding, which is all there is at a root)
        e = algebraic_error(x, X, r_eff, r0, s.v, s.C, s.w, s.t)
        T = _term_scale(x, X, r_eff, r0, s)
        assert abs(s.algebraic_error - e) <= 1e-6 * e + 1e-14 * max(1.0, T) ** 2
        # at machine precision: <= 1e-8 absolute for every root of physical size, relative to
        # the size of the terms of eq. 5 for the (rare) huge spurious roots
        assert e <= (1e-8 if T <= 100 else 1e-10 * T), (e, T)


@pytest.mark.parametrize("omega", [0.05, 0.5])
@pytest.mark.parametrize("r0", [0.0, 0.37, -0.8])
@pytest.mark.parametrize("mode", ["rows", "random"])
def test_recovers_ground_truth(omega, r0, mode):
    rng = np.random.default_rng(zlib.crc32(f"{omega} {r0} {mode}".encode()))
    for _ in range(5):
        x, X, r, gt = _instance(rng, omega, r0, mode)
        sols = r6p(x, X, r, r0)
        assert _gt_error(sols, gt) <= GT_TOL
        _check_roots(x, X, r, r0, sols)
        # the ground-truth root itself has a residual at machine precision
        best = min(sols, key=lambda s: np.linalg.norm(_z(s) - gt))
        assert best.algebraic_error < 1e-12


def test_default_r_and_r0():
    rng = np.random.default_rng(1)
    x, X, r, gt = _instance(rng, 0.3, 0.0, "rows")
    assert r is None
    a = r6p(x, X)
    b = r6p(x, X, x[:, 1], 0.0)
    assert len(a) == len(b) > 0
    assert _gt_error(a, gt) <= GT_TOL
    for s1, s2 in zip(a, b, strict=False):
        np.testing.assert_allclose(_z(s1), _z(s2), rtol=1e-12, atol=1e-14)


def test_world_frame_invariance():
    """Far, large-scale world frame: the internal normalisation must be exact."""
    rng = np.random.default_rng(2)
    for r0 in (0.0, 0.4):
        x, X, r, gt = _instance(rng, 0.3, r0, "random")
        v, C, w, t = gt[0:3], gt[3:6], gt[6:9], gt[9:12]
        scale, offset = 50.0, np.array([1000.0, -300.0, 250.0])
        Xw = scale * X + offset
        # p * scale = (I + tau[w]x)(I + [v]x)(Xw - offset) + scale C + tau scale t
        Ro = offset + np.cross(v, offset)
        gt_w = np.r_[v, scale * C - Ro, w, scale * t - np.cross(w, Ro)]
        sols = r6p(x, Xw, r, r0)
        assert _gt_error(sols, gt_w) <= GT_TOL


def test_many_random_instances():
    """1,000 instances: even number of real roots <= 20, ground truth in >= 99.5 %."""
    rng = np.random.default_rng(12345)
    n, found, counts = 1000, 0, []
    for k in range(n):
        omega = (0.05, 0.5)[k % 2]
        r0 = 0.0 if (k // 2) % 2 == 0 else rng.uniform(-1.0, 1.0)
        mode = ("rows", "random")[(k // 4) % 2]
        x, X, r, gt = _instance(rng, omega, r0, mode)
        sols = r6p(x, X, r, r0)
        counts.append(len(sols))
        found += _gt_error(sols, gt) <= GT_TOL
        if k % 50 == 0:
            _check_roots(x, X, r, r0, sols)
    counts = np.array(counts)
    assert counts.max() <= 20
    assert np.all(counts % 2 == 0), np.flatnonzero(counts % 2)
    assert found >= 0.995 * n, found


def test_coplanar_points_best_effort():
    """Coplanar world points (a structurally special case, see the r6p docstring)."""
    rng = np.random.default_rng(7)
    n, found = 200, 0
    for k in range(n):
        x, X, r, gt = _instance(
            rng, (0.05, 0.5)[k % 2], (0.0, 0.3)[k % 3 == 0], ("rows", "random")[k % 2], planar=True
        )
        sols = r6p(x, X, r, 0.0 if k % 3 else 0.3)
        _check_roots(x, X, r, 0.0 if k % 3 else 0.3, sols)
        found += _gt_error(sols, gt) <= GT_TOL
    assert found >= 0.95 * n, found


# --------------------------------------------------------------------------- bad input
def _good(rng=None):
    rng = rng or np.random.default_rng(3)
    x, X, r, _gt = _instance(rng, 0.3, 0.0, "random")
    return x, X, r


@pytest.mark.parametrize("n", [0, 5, 7, 12])
def test_wrong_number_of_points(n):
    rng = np.random.default_rng(n)
    with pytest.raises(ValueError):
        r6p(rng.normal(size=(n, 2)), rng.normal(size=(n, 3)), rng.normal(size=n))


@pytest.mark.parametrize("what", ["x", "X", "r", "r0"])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_input(what, bad):
    x, X, r = _good()
    r0 = 0.0
    if what == "x":
        x[2, 1] = bad
    elif what == "X":
        X[4, 0] = bad
    elif what == "r":
        r[1] = bad
    else:
        r0 = bad
    with pytest.raises(ValueError):
        r6p(x, X, r, r0)


def test_wrong_shapes():
    x, X, r = _good()
    for args in [
        (x.T, X, r),
        (x, X.T, r),
        (x[:, :1], X, r),
        (x, X[:, :2], r),
        (x, X[:5], r),
        (x, X, r[:5]),
        (x, X, r[:, None]),
        (x.ravel(), X, r),
        (x[None], X, r),
    ]:
        with pytest.raises(ValueError):
            r6p(*args)


def test_collinear_points_raise():
    x, _X, r = _good()
    d = np.array([0.3, -0.5, 0.8])
    Xc = np.array([0.1, 0.2, 0.3]) + np.linspace(-1, 1, 6)[:, None] * d
    with pytest.raises(DegenerateInputError):
        r6p(x, Xc, r)
    with pytest.raises(DegenerateInputError):  # all points equal
        r6p(x, np.ones((6, 3)), r)


def test_duplicated_points_raise():
    x, X, r = _good()
    X[3] = X[1]
    x[3] = x[1]
    r[3] = r[1]
    with pytest.raises(DegenerateInputError):
        r6p(x, X, r)
    assert issubclass(DegenerateInputError, ValueError)


def test_constant_rs_coordinate_raises():
    x, X, _ = _good()
    with pytest.raises(DegenerateInputError):  # tau = 0: C and t not separable
        r6p(x, X, np.full(6, 0.2), 0.2)
    with pytest.raises(DegenerateInputError):  # tau constant: the same
        r6p(x, X, np.full(6, 0.5), 0.2)


def test_near_degenerate_and_random_input_never_nan():
    """Nearly collinear points and pure noise: an exception or finite roots, never NaN."""
    rng = np.random.default_rng(5)
    d = np.array([0.3, -0.5, 0.8])
    for k in range(60):
        x = rng.normal(size=(6, 2)) * 0.5
        r = rng.uniform(-1, 1, 6) if k % 2 else None
        if k < 20:
            X = np.linspace(-1, 1, 6)[:, None] * d + rng.normal(size=(6, 3)) * 10.0 ** -(k % 10 + 3)
        elif k < 40:
            X = rng.normal(size=(6, 3))
        else:
            X = rng.normal(size=(6, 3))
            X[1] = X[0] + rng.normal(size=3) * 1e-9  # nearly duplicated
        try:
            sols = r6p(x, X, r, 0.1)
        except DegenerateInputError:
            continue
        for s in sols:
            assert np.isfinite(_z(s)).all() and np.isfinite(s.algebraic_error)


def test_lapack_fallback_matches(monkeypatch):
    """If the hand-written Francis QR does not converge, LAPACK's eig gives the same roots."""
    mod = importlib.import_module("rs_localizer.solvers.r6p")  # the package re-exports r6p
    rng = np.random.default_rng(9)
    cases = [_instance(rng, 0.3, 0.2, "random") for _ in range(5)]
    ref = [r6p(x, X, r, 0.2) for x, X, r, _ in cases]
    monkeypatch.setattr(mod, "_real_candidates", lambda M, shift, tol: (False, np.zeros((0, 3))))
    # (the compiled one-call path keeps its own _real_candidates: take the step-by-step one)
    monkeypatch.setattr(mod, "_solve_core", lambda x, X, r, r0: (-1, None, None, None))
    for (x, X, r, gt), a in zip(cases, ref, strict=False):
        b = mod.r6p(x, X, r, 0.2)
        assert _gt_error(b, gt) <= GT_TOL
        assert len(a) == len(b)
        # same set of roots (the order by algebraic error, all ~1e-16, is arbitrary)
        for s1 in a:
            assert min(np.linalg.norm(_z(s1) - _z(s2)) for s2 in b) <= 1e-9 * np.linalg.norm(_z(s1))


def test_equal_image_points_raise():
    x, X, r = _good()
    x[:] = x[0]
    with pytest.raises(DegenerateInputError):
        r6p(x, X, r)
