"""The estimator's one-call plausibility kernels against the functions of
:mod:`rs_localizer.estimation.plausibility` they fuse, or against an independent computation
(NumPy's SVD), on the same inputs."""

import numpy as np
import pytest

from rs_localizer.estimation.plausibility import (
    check_final_model,
    collinear_points,
    collinear_points_numpy,
    degenerate_points,
    degenerate_points_numpy,
    depths_at_capture,
    final_model_check,
    finite_model,
    motion_bounds,
    plausible_motion,
)
from rs_localizer.geometry import rotvec_to_matrix
from rs_localizer.sim.synthetic import make_frame, paper_camera

CAM = paper_camera()


def _point_sets(rng):
    """(X, u_px, x) sets: generic, 3D points near a line, pixels near a line, few points."""
    f = make_frame(int(rng.integers(1000)), 40, rs_speed=0.5, noise_px=1.0)
    yield f.X, f.points_px, f.x
    d = rng.normal(size=3)
    for spread in (1e-6, 5e-4, 2e-3):
        yield (
            (rng.normal(size=3) + rng.normal(size=(40, 1)) * d + spread * rng.normal(size=(40, 3))),
            f.points_px,
            f.x,
        )
    for off_px in (0.5, 1.9, 2.1, 5.0):
        u = np.c_[np.linspace(10, 900, 40), 300 + off_px * rng.choice([-1.0, 1.0], 40)]
        yield f.X, u, CAM.normalize(u)[0]
    yield f.X[:2], f.points_px[:2], f.x[:2]


def _collinear_svd(X, tol=1e-3):
    """Fewer than 3 points, or the second singular value of the centred points below ``tol``
    times the first (NumPy's SVD)."""
    if len(X) < 3:
        return True
    s = np.linalg.svd(X - X.mean(axis=0), compute_uv=False)
    return not s[0] > 0 or s[1] < tol * s[0]


def _on_line_svd(u, x, focal, threshold_px):
    """The RMS distance of the pixels ``u``, or of ``x * focal``, from their
    total-least-squares line (the smaller singular value of the centred points over
    sqrt(N); 0 for fewer than 3) below ``threshold_px``."""
    if len(u) < 3:
        return True
    rms = [np.linalg.svd(p - p.mean(axis=0), compute_uv=False)[1] / np.sqrt(len(p))
           for p in (u, x * focal)]  # fmt: skip
    return min(rms) < threshold_px


def _both(*args):
    """:func:`degenerate_points`, compiled and in NumPy (equal)."""
    got = degenerate_points(*args)
    assert got == degenerate_points_numpy(*args)
    return got


def test_degenerate_points_of_one_camera_against_numpys_svd():
    rng = np.random.default_rng(0)
    focal = np.array([CAM.mean_focal])
    seen = set()
    for _ in range(5):
        for points in _point_sets(rng):
            X, u, x = (np.ascontiguousarray(a) for a in points)
            one = np.array([[0, len(X)]], dtype=np.int64)  # (one view: every row)
            for mask in (np.ones(len(X), dtype=bool), rng.random(len(X)) < 0.6):
                ref = _collinear_svd(X[mask]) or _on_line_svd(u[mask], x[mask], focal[0], 2.0)
                assert _both(X, u, x, mask, focal, one, 2.0) == ref
                assert collinear_points(X, mask) == _collinear_svd(X[mask])
                assert collinear_points_numpy(X, mask) == _collinear_svd(X[mask])
                seen.add(ref)
    assert seen == {False, True}


def test_degenerate_points_of_two_views_against_numpys_svd():
    """Two views' rows stacked, each with its own focal length: the world points collinear,
    or every view's points on one image line (a view of fewer than 3 points, or none, is)."""
    rng = np.random.default_rng(4)
    seen = set()
    for _ in range(5):
        sets = list(_point_sets(rng))
        for (X, u, x), (_, u2, x2) in zip(sets, sets[1:] + sets[:1], strict=True):
            for cut in (len(X) // 2, 2, 0, len(X)):
                X2, U, Xn = np.r_[X, X[::-1]], np.r_[u[:cut], u2], np.r_[x[:cut], x2]
                X2 = np.resize(X2, (len(U), 3))  # (the rows repeated to the views' length)
                focal = np.array([CAM.mean_focal, 300.0])
                views = [(0, cut), (cut, len(U))]
                every = np.ones(len(U), dtype=bool)
                ref = _collinear_svd(X2) or all(
                    _on_line_svd(U[a:b], Xn[a:b], f, 2.0)
                    for (a, b), f in zip(views, focal, strict=True)
                )
                got = _both(X2, U, Xn, every, focal, np.array(views, dtype=np.int64), 2.0)
                assert got == ref
                seen.add(got)
    assert seen == {False, True}


@pytest.mark.parametrize("bounds", [None, (0.05, 0.02), (5.0, 5.0)])
def test_one_model_plausibility_equals_the_batched_one(bounds):
    rng = np.random.default_rng(1)
    for _ in range(50):
        C, w, t = rng.normal(size=3), rng.normal(size=3) * 0.05, rng.normal(size=3) * 0.05
        if rng.random() < 0.1:
            w[rng.integers(3)] = np.nan
        assert plausible_motion(None, C, w, t, bounds) == bool(
            plausible_motion(None, C[None], w[None], t[None], bounds)[0]
        )


def test_finite_model_equals_numpy():
    rng = np.random.default_rng(3)
    for k in range(200):
        parts = [
            rng.normal(size=(3, 3)),
            rng.normal(size=3),
            rng.normal(size=3),
            rng.normal(size=3),
        ]
        if k % 2:  # one non-finite entry anywhere
            a = parts[rng.integers(4)]
            a.flat[rng.integers(a.size)] = (np.nan, np.inf, -np.inf)[k % 3]
        assert finite_model(*parts) == all(np.isfinite(a).all() for a in parts)
        assert finite_model(*parts) == (k % 2 == 0)


def test_final_model_check_equals_check_final_model_on_the_depths():
    rng = np.random.default_rng(2)
    f = make_frame(5, 200, rs_speed=1.0, noise_px=1.0, outlier_ratio=0.3)
    tau = f.r - f.r0
    bounds = motion_bounds(30.0, 100.0, CAM.seconds_per_unit_r)
    codes = {None: 0, "implausible_motion": 1, "cheirality": 2}
    seen = set()
    for k in range(40):
        R = rotvec_to_matrix(rng.normal(size=3) * (0.01 if k % 3 else 2.0)) @ f.R
        C = f.C + rng.normal(size=3) * (0.1 if k % 4 else 3.0)
        w = f.w * (1.0 if k % 5 else 50.0)
        t = f.t
        mask = rng.random(len(f.X)) < 0.5
        z = depths_at_capture(R, C, w, t, f.X, tau)
        ref = check_final_model(R, C, w, t, z[mask], bounds)
        code, behind = final_model_check(R, C, w, t, f.X, tau, mask, bounds[0] ** 2, bounds[1] ** 2)
        assert code == codes[ref]
        if code == 0 or code == 2:
            assert behind == int(np.count_nonzero(~(z > 0)))
        seen.add(code)
    assert seen == {0, 1, 2}
