"""rs_localizer.frames against an independent computation: 4x4 homogeneous transforms of a
simulated trajectory, twists by finite differences of those 4x4 matrices, and covariances
through numerical Jacobians of the 4x4 composition."""

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from rs_localizer.frames import (
    OPTICAL_TO_BODY_QUATERNION,
    Mounting,
    base_pose_covariance,
    base_twist_covariance,
    camera_to_base,
)
from rs_localizer.pose import PoseWithCovariance, RSPose
from rs_localizer.sim.trajectory import Trajectory


def _T(R, p):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


def _body_twist_fd(T_of_t, t, h=1e-5):
    """(omega, v) in the moving frame from T^-1 dT/dt by central differences of 4x4 matrices."""
    Td = (T_of_t(t + h) - T_of_t(t - h)) / (2 * h)
    X = np.linalg.inv(T_of_t(t)) @ Td
    W = 0.5 * (X[:3, :3] - X[:3, :3].T)
    return np.array([W[2, 1], W[0, 2], W[1, 0]]), X[:3, 3]


def _Cam(R, p, om, v, pc=None, tc=None):
    return PoseWithCovariance(pose=RSPose(R, p, om, v), pose_covariance=pc, twist_covariance=tc)


def _random_mounting(rng):
    q = rng.normal(size=4)
    return Mounting.from_translation_quaternion(rng.uniform(-0.5, 0.5, 3), q / np.linalg.norm(q))


def test_optical_to_body_quaternion_is_the_rep103_axis_change():
    ext = Mounting.from_translation_quaternion([0, 0, 0], OPTICAL_TO_BODY_QUATERNION)
    # camera z (forward) = base x, camera x (right) = base -y, camera y (down) = base -z
    np.testing.assert_allclose(ext.rotation @ [0, 0, 1], [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(ext.rotation @ [1, 0, 0], [0, -1, 0], atol=1e-15)
    np.testing.assert_allclose(ext.rotation @ [0, 1, 0], [0, 0, -1], atol=1e-15)


@pytest.mark.parametrize("seed", range(4))
def test_pose_and_twist_match_4x4_transforms_and_finite_differences(seed):
    rng = np.random.default_rng(seed)
    traj = Trajectory()
    ext = _random_mounting(rng)
    T_bc = ext.matrix
    T_cb = np.linalg.inv(T_bc)

    def T_mc(t):
        R, p = traj.orientation(t), traj.position(t)
        return _T(R, p)

    def T_mb(t):  # the base follows from the camera by a fixed 4x4 product
        return T_mc(t) @ T_cb

    for t in rng.uniform(0.0, 5.0, 5):
        om_c, v_c = _body_twist_fd(T_mc, t)
        out = camera_to_base(_Cam(traj.orientation(t), traj.position(t), om_c, v_c), ext)
        assert isinstance(out, PoseWithCovariance)
        want = T_mb(t)
        np.testing.assert_allclose(out.pose.orientation, want[:3, :3], atol=1e-12)
        np.testing.assert_allclose(out.pose.position, want[:3, 3], atol=1e-12)
        om_b, v_b = _body_twist_fd(T_mb, t)
        assert np.linalg.norm(om_b) > 0.05 and np.linalg.norm(v_b) > 0.5  # a real motion
        np.testing.assert_allclose(out.pose.angular_velocity, om_b, atol=2e-7)
        np.testing.assert_allclose(out.pose.linear_velocity, v_b, atol=2e-7)
        assert out.pose_covariance is None and out.twist_covariance is None


def test_twist_is_the_velocity_of_the_base_origin():
    """A camera 1 m in front of the base, the robot turning on the spot at 1 rad/s about z: the
    camera moves at 1 m/s sideways, the base origin does not move."""
    ext = Mounting.from_translation_quaternion([1.0, 0, 0], OPTICAL_TO_BODY_QUATERNION)
    om_c = ext.rotation.T @ [0, 0, 1.0]  # yaw rate 1 rad/s in camera axes
    v_c = ext.rotation.T @ [0, 1.0, 0]  # camera centre moving to the left (base +y)
    out = camera_to_base(_Cam(ext.rotation, [1.0, 0, 0], om_c, v_c), ext)
    np.testing.assert_allclose(out.pose.angular_velocity, [0, 0, 1.0], atol=1e-15)
    np.testing.assert_allclose(out.pose.linear_velocity, [0, 0, 0], atol=1e-15)
    np.testing.assert_allclose(out.pose.position, [0, 0, 0], atol=1e-15)
    np.testing.assert_allclose(out.pose.orientation, np.eye(3), atol=1e-15)


def _random_cov(rng, scale):
    A = rng.normal(size=(6, 6)) * scale
    return A @ A.T + np.eye(6) * 1e-6


def test_pose_covariance_matches_the_numerical_jacobian_of_the_4x4_composition():
    rng = np.random.default_rng(7)
    for _ in range(5):
        ext = _random_mounting(rng)
        R_mc = Rotation.random(random_state=rng).as_matrix()
        p_c = rng.normal(size=3)
        T_cb = np.linalg.inv(ext.matrix)

        def base_of(
            delta, R_mc=R_mc, p_c=p_c, T_cb=T_cb
        ):  # camera pose perturbed (x, y, z, rot about map axes) -> base
            T = (
                _T(
                    expm(
                        np.array(
                            [
                                [0, -delta[5], delta[4]],
                                [delta[5], 0, -delta[3]],
                                [-delta[4], delta[3], 0],
                            ]
                        )
                    )
                    @ R_mc,
                    p_c + delta[:3],
                )
                @ T_cb
            )
            R0 = (_T(R_mc, p_c) @ T_cb)[:3, :3]
            phi = Rotation.from_matrix(T[:3, :3] @ R0.T).as_rotvec()  # map-axis perturbation
            return np.concatenate([T[:3, 3], phi])

        h = 1e-6
        J = np.stack([(base_of(h * e) - base_of(-h * e)) / (2 * h) for e in np.eye(6)], axis=1)
        cov = _random_cov(rng, 0.05)
        got = base_pose_covariance(cov, R_mc, ext)
        np.testing.assert_allclose(got, J @ cov @ J.T, atol=1e-8 * np.abs(got).max())
        assert np.allclose(got, got.T)


def test_twist_covariance_matches_the_numerical_jacobian_of_finite_differences():
    """Camera moving with a constant body twist xi: ``T_mc(s) = T_mc(0) expm(s xi^)``; the
    base's twist comes from finite differences of ``T_mc(s) T_cb``."""
    rng = np.random.default_rng(11)
    ext = _random_mounting(rng)
    T0 = _T(Rotation.random(random_state=rng).as_matrix(), rng.normal(size=3))
    T_cb = np.linalg.inv(ext.matrix)

    def base_twist_of(xi):  # xi = (vx, vy, vz, wx, wy, wz), camera frame
        X = np.zeros((4, 4))
        w = xi[3:]
        X[:3, :3] = [[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]
        X[:3, 3] = xi[:3]
        om, v = _body_twist_fd(lambda s: T0 @ expm(s * X) @ T_cb, 0.0, h=1e-6)
        return np.concatenate([v, om])

    J = np.stack([base_twist_of(e) for e in np.eye(6)], axis=1)  # linear map: columns
    xi = rng.normal(size=6)
    cam = _Cam(T0[:3, :3], T0[:3, 3], xi[3:], xi[:3])
    out = camera_to_base(cam, ext)
    np.testing.assert_allclose(
        np.concatenate([out.pose.linear_velocity, out.pose.angular_velocity]), J @ xi, atol=1e-7
    )
    cov = _random_cov(rng, 0.1)
    np.testing.assert_allclose(base_twist_covariance(cov, ext), J @ cov @ J.T, atol=1e-7)
    out = camera_to_base(
        _Cam(T0[:3, :3], T0[:3, 3], xi[3:], xi[:3], _random_cov(rng, 0.1), cov), ext
    )
    np.testing.assert_allclose(out.twist_covariance, J @ cov @ J.T, atol=1e-7)


def test_identity_mounting_changes_nothing():
    ext = Mounting.from_translation_quaternion([0, 0, 0], [0, 0, 0, 1])
    rng = np.random.default_rng(3)
    R = Rotation.random(random_state=rng).as_matrix()
    pc, tc = _random_cov(rng, 0.1), _random_cov(rng, 0.1)
    cam = _Cam(R, rng.normal(size=3), rng.normal(size=3), rng.normal(size=3), pc, tc)
    out = camera_to_base(cam, ext)
    for a in ("orientation", "position", "angular_velocity", "linear_velocity"):
        np.testing.assert_allclose(getattr(out.pose, a), getattr(cam.pose, a), atol=1e-14)
    for a in ("pose_covariance", "twist_covariance"):
        np.testing.assert_allclose(getattr(out, a), getattr(cam, a), atol=1e-14)


@pytest.mark.parametrize(
    "t, q",
    [
        ([0, 0], [0, 0, 0, 1]),
        ([0, 0, np.nan], [0, 0, 0, 1]),
        ([0, 0, 0], [0, 0, 0]),
        ([0, 0, 0], [0, 0, 0, 0]),
        ([0, 0, 0], [0, 0, 0, np.inf]),
        ([0, 0, 0], [0, 0, 0, 5.0]),
    ],
)
def test_bad_mounting_raises(t, q):
    with pytest.raises(ValueError):
        Mounting.from_translation_quaternion(t, q)


def test_quaternion_is_normalized():
    a = Mounting.from_translation_quaternion([0, 0, 0], [0, 0, 0.1, 1.0])
    np.testing.assert_allclose(a.rotation @ a.rotation.T, np.eye(3), atol=1e-14)
    np.testing.assert_allclose(
        a.rotation, Rotation.from_rotvec([0, 0, 2 * np.arctan(0.1)]).as_matrix(), atol=1e-14
    )


def test_mounting_forms_agree_and_keep_what_was_given():
    rng = np.random.default_rng(7)
    R_bc = Rotation.random(random_state=3).as_matrix()
    p = rng.uniform(-0.5, 0.5, 3)
    tf = Mounting.from_pose(R_bc, p)
    # tf's form as given, the estimator's form R = R_bc^T, c = -R p
    assert np.array_equal(tf.rotation, R_bc) and np.array_equal(tf.translation, p)
    assert np.array_equal(tf.R, R_bc.T) and np.array_equal(tf.c, -R_bc.T @ p)
    assert np.array_equal(tf.position, p)
    np.testing.assert_array_equal(tf.matrix, _T(R_bc, p))
    # the estimator's form as given, tf's derived: x_cam = R x_body + c
    est = Mounting(tf.R, tf.c)
    assert np.array_equal(est.R, tf.R) and np.array_equal(est.c, tf.c)
    np.testing.assert_allclose(est.translation, p, atol=1e-15)
    np.testing.assert_allclose(est.matrix, tf.matrix, atol=1e-15)
    x_body = rng.normal(size=3)
    np.testing.assert_allclose(est.R @ x_body + est.c, np.linalg.solve(tf.matrix, [*x_body, 1])[:3])


@pytest.mark.parametrize(
    "R, c, cov, match",
    [
        (np.diag([1.0, 1.0, -1.0]), np.zeros(3), None, "must be a rotation"),
        (2 * np.eye(3), np.zeros(3), None, "must be a rotation"),
        (np.eye(3), [0, 0, np.nan], None, "must be finite"),
        (np.eye(3), np.zeros(3), np.eye(5), r"\(6, 6\) and finite"),
        (np.eye(3), np.zeros(3), np.full((6, 6), np.inf), r"\(6, 6\) and finite"),
        (np.eye(3), np.zeros(3), -np.eye(6), "positive semi-definite"),
    ],
)
def test_bad_mounting_is_refused(R, c, cov, match):
    with pytest.raises(ValueError, match=match):
        Mounting(R, c, cov)


def test_mounting_covariance_is_stored_symmetric():
    C = np.eye(6) * 1e-4
    C[0, 1] = 2e-5
    m = Mounting.from_pose(np.eye(3), np.zeros(3), covariance=C)
    np.testing.assert_array_equal(m.covariance, m.covariance.T)
    assert m.covariance[0, 1] == m.covariance[1, 0] == 1e-5
    assert Mounting(np.eye(3), np.zeros(3)).covariance is None
