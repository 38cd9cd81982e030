"""The hypothesis stage a camera and a rig share: pre-rotated samples solved by the linear RS
solver (``prerotated_models``), the inliers refitted (``linear_refit``), samples drawn
(``draw_samples_numpy``); a camera is a rig of one camera at the identity mounting."""

import numpy as np
import pytest
from scipy.linalg import expm

from rs_localizer.estimation.hypotheses import (
    composed,
    linear_refit,
    prerotated_models,
    prerotated_points,
    still_models,
)
from rs_localizer.estimation.sampling import draw_samples, draw_samples_numpy
from rs_localizer.geometry import rotvec_to_matrix
from rs_localizer.solvers import r6p_1lin_batch
from rs_localizer.solvers.gr6p_1lin import gr6p_1lin_batch


def _skew(a):
    return np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])


def _frame(seed, n=40):
    """A rolling-shutter camera's exact observations (paper eq. 4) of n points."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(-1, 1, (n, 3)) + [0, 0, 5]
    R = rotvec_to_matrix(np.array([0.05, -0.1, 0.02]))
    C, w, t = np.array([0.1, -0.2, 0.3]), np.array([0.3, -0.2, 0.1]), np.array([0.2, 0.1, -0.1])
    r = rng.uniform(-1, 1, n) * 0.03
    P = np.array([expm(r[i] * _skew(w)) @ R @ X[i] + C + r[i] * t for i in range(n)])
    return P[:, :2] / P[:, 2:], X, r, (R, C, w, t)


def _camera(S, xs, Xs, rs, C0):
    return [r6p_1lin_batch(xs, Xs, rs, 0.0, iterations=5)]


def _rig_of_one(S, xs, Xs, rs, C0):
    cams = np.zeros(np.shape(S), dtype=np.int64)
    return [gr6p_1lin_batch(xs, Xs, rs, cams, np.eye(3)[None], np.zeros((1, 3)), 5)]


@pytest.mark.parametrize("compiled", [True, False])
def test_a_camera_is_a_rig_of_one_in_the_prerotated_solve(compiled):
    """The camera's solver and the rig solver with one camera at the identity mounting give
    the same models of the same pre-rotated samples; each model is the sample solved alone,
    its rotation ``expm([v]x) R_pre``, and near the truth (noise-free points, a pre-rotation
    a few hundredths of a radian off)."""
    x, X, r, (R, C, _, _) = _frame(3)
    rng = np.random.default_rng(4)
    S = np.array([rng.choice(len(X), 6, replace=False) for _ in range(8)])
    R_pre = np.stack([rotvec_to_matrix(np.array([0.06, -0.09, 0.01 * k])) for k in range(8)])
    C_pre = np.zeros((8, 3))
    cam = prerotated_models(S, R_pre, C_pre, x, X, r, _camera, compiled)
    rig = prerotated_models(S, R_pre, C_pre, x, X, r, _rig_of_one, compiled)
    for a, b in zip(cam, rig, strict=True):
        np.testing.assert_allclose(np.asarray(a, float), np.asarray(b, float), rtol=0, atol=1e-12)
    assert cam[4].all()
    for k in range(8):
        alone = r6p_1lin_batch(x[S[k]][None], (X[S[k]] @ R_pre[k].T)[None], r[S[k]][None], 0.0,
                               iterations=5)  # fmt: skip
        np.testing.assert_allclose(cam[0][k], expm(_skew(alone.v[0])) @ R_pre[k], atol=1e-12)
        np.testing.assert_allclose(cam[1][k], alone.C[0], atol=1e-12)
        np.testing.assert_allclose(cam[0][k], R, atol=2e-3)
        np.testing.assert_allclose(cam[1][k], C, atol=1e-2)


def test_prerotated_points_and_rotations_agree_compiled_and_numpy():
    """The compiled gather and Rodrigues give NumPy's pre-rotated points and composed
    rotations to rounding."""
    rng = np.random.default_rng(5)
    x, X, r = rng.normal(size=(30, 2)), rng.normal(size=(30, 3)), rng.normal(size=30)
    S = rng.integers(0, 30, (12, 6))
    R_pre = rotvec_to_matrix(rng.normal(size=(12, 3)))
    a, b = prerotated_points(S, R_pre, x, X, r), prerotated_points(S, R_pre, x, X, r, False)
    for u, v in zip(a, b, strict=True):
        np.testing.assert_allclose(u, v, rtol=0, atol=1e-13)
    np.testing.assert_allclose(b[1][2, 4], R_pre[2] @ X[S[2, 4]], atol=1e-13)
    v = 0.1 * rng.normal(size=(12, 3))
    np.testing.assert_allclose(composed(v, R_pre), composed(v, R_pre, False), atol=1e-14)
    np.testing.assert_allclose(composed(v, R_pre)[7], expm(_skew(v[7])) @ R_pre[7], atol=1e-14)


def test_the_inlier_refit_is_the_solver_on_every_inlier():
    """``linear_refit`` from a rotation off by a few hundredths of a radian recovers the
    truth as the solver on all the inliers does, the camera's and the rig of one's alike; a
    failed solve gives None."""
    x, X, r, (R, C, _, _) = _frame(6)
    idx = np.arange(0, 40, 2)
    R0 = rotvec_to_matrix(np.array([0.03, 0.02, -0.04])) @ R
    m = linear_refit(idx, R0, None, x, X, r, _camera)
    m1 = linear_refit(idx, R0, None, x, X, r, _rig_of_one)
    for a, b in zip(m, m1, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    np.testing.assert_allclose(m[0], R, atol=1e-3)
    np.testing.assert_allclose(m[1], C, atol=5e-3)

    def failing(S, xs, Xs, rs, C0):
        b = r6p_1lin_batch(xs, Xs, rs, 0.0, iterations=5)
        b.valid[:] = False
        return [b]

    assert linear_refit(idx, R0, None, x, X, r, failing) is None


def test_the_inlier_refit_in_rounds_is_each_round_from_the_last():
    """``linear_refit`` with ``rounds`` 2 is two refits in turn, the second pre-rotated by the
    first's model (bit for bit); a solve that fails in the second round gives None."""
    x, X, r, (R, C, _, _) = _frame(7)
    idx = np.arange(0, 40, 2)
    R0 = rotvec_to_matrix(np.array([0.08, -0.05, 0.06])) @ R
    m1 = linear_refit(idx, R0, C, x, X, r, _rig_of_one)
    m2 = linear_refit(idx, m1.R, m1.C, x, X, r, _rig_of_one)
    both = linear_refit(idx, R0, C, x, X, r, _rig_of_one, rounds=2)
    for a, b in zip(m2, both, strict=True):
        assert np.array_equal(a, b)
    calls = []

    def second_fails(S, xs, Xs, rs, C0):
        b = _rig_of_one(S, xs, Xs, rs, C0)[0]
        calls.append(C0)
        b.valid[:] = len(calls) < 2
        return [b]

    assert linear_refit(idx, R0, C, x, X, r, second_fails, rounds=2) is None and len(calls) == 2


def test_still_models_are_at_rest():
    R, C = rotvec_to_matrix(np.ones((2, 3))), np.ones((2, 3))
    R1, C1, w, t = still_models(R, C)
    assert R1 is R and C1 is C and not w.any() and not t.any() and w is not t


def _reference_draws(u, size, offset):
    """Each draw the ``floor(u (size - j))``-th free index of ``offset + range(size)``,
    one index at a time."""
    K, s = u.shape
    out = np.empty((K, s), dtype=np.int64)
    for k in range(K):
        chosen = []
        for j in range(s):
            free = [i for i in range(offset[k, j], offset[k, j] + size[k, j]) if i not in chosen]
            chosen.append(free[min(int(u[k, j] * (size[k, j] - j)), size[k, j] - j - 1)])
        out[k] = chosen
    return out


def test_a_rigs_samples_are_a_cameras_draws_with_the_first_in_one_camera():
    """Draws with each draw's own range (a rig's: three in one camera's points, then three
    in the whole pool) pick the free indices one at a time picks; with one range they are
    the compiled camera draws."""
    rng = np.random.default_rng(7)
    starts, counts, n = np.array([0, 9, 13]), np.array([9, 4, 11]), 24
    u = rng.random((200, 6))
    cams = rng.integers(0, 3, 200)
    size, offset = np.full((200, 6), n), np.zeros((200, 6), dtype=np.int64)
    size[:, :3], offset[:, :3] = counts[cams][:, None], starts[cams][:, None]
    got = draw_samples_numpy(u, size, offset)
    np.testing.assert_array_equal(got, _reference_draws(u, size, offset))
    first = got[:, :3] - starts[cams][:, None]
    assert ((first >= 0) & (first < counts[cams][:, None])).all()
    assert all(len(set(row)) == 6 for row in got.tolist())
    np.testing.assert_array_equal(draw_samples_numpy(u, n), draw_samples(u, n))
