"""The shape-only covariance of a point set (rs_localizer.mapping.shape_covariance),
the minimum-trace gauge of bundle adjustment, against independent computations: its
invariance to the gauge a covariance was computed in, and a Monte Carlo of the points after a
best rigid fit of the whole set onto the mean (SciPy's ``Rotation.align_vectors``)."""

import numpy as np
from scipy.spatial.transform import Rotation

from rs_localizer.geometry import skew
from rs_localizer.mapping import shape_covariance


def _scene(seed=0, n=12):
    rng = np.random.default_rng(seed)
    pts = rng.uniform([-2, -2, 0], [2, 2, 2.5], size=(n, 3))
    A = rng.normal(size=(3 * n, 3 * n)) * 0.01
    return rng, pts, A @ A.T + np.diag(rng.uniform(1e-5, 1e-4, 3 * n))


def _rigid_jacobian(pts):
    # (3 N, 6): a small translation and rotation (about the origin) of the whole set
    return np.vstack([np.hstack([np.eye(3), -skew(p)]) for p in pts])


def test_shape_covariance_does_not_depend_on_the_gauge():
    rng, pts, cov = _scene()
    S = shape_covariance(pts, cov)
    # another gauge: the same errors plus a rigid motion of the whole set, correlated with them
    G = _rigid_jacobian(pts)
    B = rng.normal(size=(6, 3 * len(pts))) * 0.01
    M = rng.normal(size=(6, 6)) * 0.05
    other = cov + G @ B + B.T @ G.T + G @ (M @ M.T) @ G.T
    assert not np.allclose(other, cov)
    np.testing.assert_allclose(shape_covariance(pts, other), S, atol=1e-12)
    # a rigid motion alone has no shape
    np.testing.assert_allclose(shape_covariance(pts, G @ (M @ M.T) @ G.T), 0.0, atol=1e-12)
    # the trace is the smallest over all gauges (minimum-trace gauge)
    assert np.trace(S) < np.trace(cov)
    assert np.trace(S) < np.trace(other)


def test_shape_covariance_is_the_spread_after_a_best_rigid_fit():
    rng, pts, cov = _scene(1)
    # half the errors are where the whole set sits (a gauge's frame): the fit removes them
    M = rng.normal(size=(6, 6)) * 0.03
    G = _rigid_jacobian(pts)
    cov = cov + G @ (M @ M.T) @ G.T
    scale = 1e-3  # small errors: the linear model holds
    L = np.linalg.cholesky(cov) * scale
    c0 = pts.mean(0)
    res = []
    for _ in range(4000):
        noisy = pts + (L @ rng.normal(size=3 * len(pts))).reshape(-1, 3)
        cn = noisy.mean(0)
        rot, _ = Rotation.align_vectors(pts - c0, noisy - cn)
        res.append(((noisy - cn) @ rot.as_matrix().T + c0 - pts).ravel())
    mc = np.cov(np.array(res).T)
    S = shape_covariance(pts, cov) * scale**2
    # the per-point spread (what the estimator uses) and the whole matrix, to Monte Carlo error
    d_mc = np.diag(mc).reshape(-1, 3).sum(1)
    d_S = np.diag(S).reshape(-1, 3).sum(1)
    np.testing.assert_allclose(d_mc, d_S, rtol=0.08)
    assert np.linalg.norm(mc - S) < 0.08 * np.linalg.norm(S)
