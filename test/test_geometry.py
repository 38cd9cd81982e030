"""Geometry: rotations and the RS projections against independent computations."""

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from rs_localizer.geometry import (
    camera_position,
    compose,
    invert,
    nearest_rotation,
    reprojection_errors,
    rotation_angle_deg,
    rotvec_to_matrix,
    rs_project_exact,
    rs_project_first_order,
    rs_project_linear,
    skew,
    vee,
)

rng = np.random.default_rng(42)


def test_skew_is_cross_product_and_vee_inverts_it():
    a, b = rng.normal(size=(2, 3))
    np.testing.assert_allclose(skew(a) @ b, np.cross(a, b), atol=1e-15)
    np.testing.assert_allclose(vee(skew(a)), a, atol=1e-15)
    M = rng.normal(size=(3, 3))
    np.testing.assert_allclose(vee(M), vee(0.5 * (M - M.T)))
    with pytest.raises(ValueError):
        skew(np.zeros(2))


@pytest.mark.parametrize("angle", [0.0, 1e-10, 1e-4, 0.3, 3.0])
def test_rodrigues_matches_expm_and_scipy(angle):
    axis = rng.normal(size=3)
    v = angle * axis / np.linalg.norm(axis)
    np.testing.assert_allclose(rotvec_to_matrix(v), expm(skew(v)), atol=1e-13)
    np.testing.assert_allclose(rotvec_to_matrix(v), Rotation.from_rotvec(v).as_matrix(), atol=1e-13)


def test_nearest_rotation_and_angle():
    R = Rotation.random(random_state=1).as_matrix()
    np.testing.assert_allclose(nearest_rotation(R + 1e-3 * rng.normal(size=(3, 3))), R, atol=5e-3)
    R2 = rotvec_to_matrix([0, 0, np.radians(10)]) @ R
    assert rotation_angle_deg(R, R2) == pytest.approx(10.0)


def _brute_force_row(X, R, C, w, t, r0, d, exact):
    """Solve r = d . pi(p(r)) by dense 1-D search + bisection (independent of the closed form)."""
    out = []
    for Xi in X:

        def f(r, Xi=Xi):
            M = expm((r - r0) * skew(w)) if exact else np.eye(3) + (r - r0) * skew(w)
            p = M @ R @ Xi + C + (r - r0) * t
            return r - d @ (p[:2] / p[2]), p

        grid = np.linspace(-1, 1, 2001)
        vals = np.array([f(r)[0] for r in grid])
        k = np.flatnonzero(np.sign(vals[:-1]) != np.sign(vals[1:]))[0]
        lo, hi = grid[k], grid[k + 1]
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            if np.sign(f(mid)[0]) == np.sign(f(lo)[0]):
                lo = mid
            else:
                hi = mid
        p = f(lo)[1]
        out.append(p[:2] / p[2])
    return np.array(out)


@pytest.mark.parametrize("d", [(0.0, 1.0), (0.0, -1.0), (1.0, 0.0)])
@pytest.mark.parametrize("exact", [False, True])
def test_rs_projection_matches_brute_force(d, exact):
    d = np.array(d)
    R = rotvec_to_matrix([0.1, -0.2, 0.05])
    C = np.array([0.1, -0.1, 3.0])
    w = np.array([0.2, -0.3, 0.25])
    t = np.array([0.2, 0.1, -0.1])
    X = rng.uniform(-1, 1, (8, 3))
    r0 = 0.07
    fn = rs_project_exact if exact else rs_project_linear
    x, r = fn(X, R, C, w, t, r0, d)
    np.testing.assert_allclose(r, x @ d, atol=1e-12)  # the row constraint holds
    np.testing.assert_allclose(x, _brute_force_row(X, R, C, w, t, r0, d, exact), atol=1e-10)


def test_global_shutter_limits_agree():
    R = rotvec_to_matrix([0.3, 0.1, -0.2])
    C = np.array([0.0, 0.0, 3.0])
    X = rng.uniform(-1, 1, (20, 3))
    Xc = X @ R.T + C
    z = np.zeros(3)
    for fn in (rs_project_linear, rs_project_exact):
        x, _ = fn(X, R, C, z, z, 0.3)
        np.testing.assert_allclose(x, Xc[:, :2] / Xc[:, 2:], atol=1e-14)


def test_first_order_per_point_r0_and_invalid_points():
    P0 = np.array([[0.1, 0.2, 2.0], [0.0, 0.0, -1.0]])
    P1 = np.array([[0.0, 0.1, 0.0], [0.0, 0.0, 0.0]])
    x, r = rs_project_first_order(P0, P1, np.array([0.05, 0.0]))
    assert np.isfinite(x[0]).all() and np.isnan(x[1]).all()  # behind the camera -> nan
    assert r[0] == pytest.approx((0.2 + (r[0] - 0.05) * 0.1) / 2.0)


def test_reprojection_errors_zero_on_model_and_inf_behind():
    R, C = np.eye(3), np.array([0, 0, 3.0])
    w, t = np.array([0.0, 0.2, 0.0]), np.array([0.1, 0, 0])
    X = rng.uniform(-1, 1, (10, 3))
    x, _ = rs_project_linear(X, R, C, w, t)
    assert np.max(reprojection_errors(x, X, R, C, w, t)) < 1e-14
    X[0] = [0, 0, -10]
    assert np.isinf(reprojection_errors(x, X, R, C, w, t)[0])


def test_camera_position():
    R = rotvec_to_matrix([0.2, 0.3, -0.1])
    c = np.array([1.0, 2.0, -3.0])
    assert np.allclose(camera_position(R, -R @ c), c)


def test_compose_and_invert_match_homogeneous_matrices():
    def T(R, C):
        M = np.eye(4)
        M[:3, :3], M[:3, 3] = R, C
        return M

    R1, R2 = rotvec_to_matrix([0.1, 0.2, 0.3]), rotvec_to_matrix([-0.4, 0.0, 0.2])
    C1, C2 = np.array([1.0, 2.0, 3.0]), np.array([-0.5, 0.1, 0.2])
    np.testing.assert_allclose(T(*compose(R1, C1, R2, C2)), T(R1, C1) @ T(R2, C2), atol=1e-14)
    np.testing.assert_allclose(T(*invert(R1, C1)), np.linalg.inv(T(R1, C1)), atol=1e-14)
