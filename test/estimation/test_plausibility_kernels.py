"""The estimator's one-call plausibility kernels against the functions of
:mod:`rs_localizer.estimation.plausibility` they fuse (on the same inputs)."""

import numpy as np
import pytest

from rs_localizer.estimation.plausibility import (
    check_final_model,
    collinear_3d,
    degenerate_points,
    depths_at_capture,
    final_model_check,
    finite_model,
    image_degenerate,
    motion_bounds,
    plausible_motion,
    views_degenerate,
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


def test_degenerate_points_equals_collinear_3d_or_image_degenerate():
    rng = np.random.default_rng(0)
    n = 0
    for _ in range(5):
        for X, u, x in _point_sets(rng):
            for mask in (np.ones(len(X), dtype=bool), rng.random(len(X)) < 0.6):
                ref = collinear_3d(X[mask]) or image_degenerate(
                    u[mask], x[mask], CAM.mean_focal, 2.0
                )
                got = degenerate_points(
                    np.ascontiguousarray(X),
                    np.ascontiguousarray(u),
                    np.ascontiguousarray(x),
                    mask,
                    CAM.mean_focal,
                    2.0,
                )
                assert got == ref
                n += ref
    assert n > 0  # both outcomes occur


def test_views_degenerate_equals_collinear_3d_or_every_view_image_degenerate():
    """Two views' rows stacked (each with its own focal length): the compiled test is
    ``collinear_3d(X) or`` every view of 3 or more rows ``image_degenerate``, or undecided
    (-1) only where the collinearity test needs eigenvalues."""
    rng = np.random.default_rng(4)
    seen = set()
    for _ in range(5):
        sets = list(_point_sets(rng))
        for (X, u, x), (_, u2, x2) in zip(sets, sets[1:] + sets[:1], strict=True):
            for cut in (len(X) // 2, 2, len(X)):
                X2, U, Xn = np.r_[X, X[::-1]], np.r_[u[:cut], u2], np.r_[x[:cut], x2]
                X2 = X2[: len(U)]
                focal = np.r_[np.full(cut, CAM.mean_focal), np.full(len(u2), 300.0)]
                views = [(0, cut), (cut, len(U))]
                ref = collinear_3d(X2) or all(
                    b - a < 3 or image_degenerate(U[a:b], Xn[a:b], focal[a], 2.0) for a, b in views
                )
                got = views_degenerate(
                    np.ascontiguousarray(X2), np.ascontiguousarray(U), np.ascontiguousarray(Xn),
                    focal, np.array(views, dtype=np.int64), 2.0,
                )  # fmt: skip
                assert got == -1 or got == int(ref)
                seen.add(got)
    assert {0, 1} <= seen  # (both outcomes occur)


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
