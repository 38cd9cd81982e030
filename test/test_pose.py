"""The model <-> twist conversion of rs_localizer.pose (written once: the kernels, the NumPy
code and the pose types use it) against the camera's motion differentiated numerically, its
Jacobian against finite differences, the compiled kernel against its plain-Python code; the
results built without their constructor (``frozen_instance``) against the constructor's."""

import dataclasses

import numpy as np
import pytest

from rs_localizer.estimation.result import RSPoseEstimate
from rs_localizer.geometry import rotvec_to_matrix
from rs_localizer.pose import (
    RSPose,
    frozen_instance,
    model_from_twist,
    model_twist,
    model_twist_jacobian,
)

S = 0.024  # s per unit RS coordinate


def _model(seed):
    rng = np.random.default_rng(seed)
    R = rotvec_to_matrix(rng.normal(size=3))
    C, w, t = rng.normal(size=3), 0.01 * rng.normal(size=3), 0.01 * rng.normal(size=3)
    return R, C, w, t


def test_twist_is_the_cameras_own_motion():
    """With ``R(tau) = expm(tau [w]x) R`` and ``C(tau) = C + tau t`` (per unit r), the camera
    centre ``-R(tau)^T C(tau)`` and orientation ``R(tau)^T`` differentiated numerically give
    the twist in the camera frame."""
    for seed in range(5):
        R, C, w, t = _model(seed)
        h = 1e-6

        def centre(tau, R=R, C=C, w=w, t=t):
            Rt = rotvec_to_matrix(tau * w) @ R
            return -Rt.T @ (C + tau * t)

        dc = (centre(h) - centre(-h)) / (2 * h) / S  # world frame, m/s
        v_cam = R @ dc
        Rp, Rm = rotvec_to_matrix(h * w) @ R, rotvec_to_matrix(-h * w) @ R
        dO = (Rp.T - Rm.T) / (2 * h) / S  # d(orientation)/dt = O [omega]x
        Om = R @ dO
        omega = np.array([Om[2, 1], Om[0, 2], Om[1, 0]])
        z = model_twist(C, w, t, S)
        np.testing.assert_allclose(z[0:3], v_cam, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(z[3:6], omega, rtol=1e-6, atol=1e-9)


def test_jacobian_matches_finite_differences():
    _, C, w, t = _model(1)
    J = model_twist_jacobian(C, w, S)
    theta = np.concatenate([np.zeros(3), C, w, t])
    h = 1e-7
    for k in range(12):
        d = np.zeros(12)
        d[k] = h
        zp = model_twist((theta + d)[3:6], (theta + d)[6:9], (theta + d)[9:12], S)
        zm = model_twist((theta - d)[3:6], (theta - d)[6:9], (theta - d)[9:12], S)
        np.testing.assert_allclose(J[:, k], (zp - zm) / (2 * h), atol=1e-6)


def test_compiled_and_plain_python_agree_bit_for_bit():
    for seed in range(5):
        _, C, w, t = _model(seed)
        assert model_twist(C, w, t, S).tobytes() == model_twist.py_func(C, w, t, S).tobytes()
        assert (
            model_twist_jacobian(C, w, S).tobytes()
            == model_twist_jacobian.py_func(C, w, S).tobytes()
        )


def test_inverse_and_pose_round_trip():
    for seed in range(5):
        R, C, w, t = _model(seed)
        z = model_twist(C, w, t, S)
        w2, t2 = model_from_twist(C, z[3:6], z[0:3], S)
        np.testing.assert_allclose(w2, w, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(t2, t, rtol=1e-12, atol=1e-15)
        pose = RSPose.from_model((R, C, w, t), S)
        np.testing.assert_array_equal(pose.angular_velocity, z[3:6])
        np.testing.assert_array_equal(pose.linear_velocity, z[0:3])
        back = pose.model(S)
        np.testing.assert_allclose(back.R, R, atol=1e-15)
        np.testing.assert_allclose(back.C, C, atol=1e-12)
        np.testing.assert_allclose(back.w, w, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(back.t, t, rtol=1e-12, atol=1e-15)


def test_from_model_compiled_twist_is_the_python_twist():
    """``RSPose.from_model(..., compiled=True)`` (the compiled twist kernel, as the rig
    estimator builds its poses) gives the same pose and twist as the default plain-Python
    twist, to the bit."""
    rng = np.random.default_rng(7)
    for _ in range(20):
        R = rotvec_to_matrix(rng.normal(size=3))
        C, w, t = rng.normal(size=3), rng.normal(size=3), rng.normal(size=3)
        a = RSPose.from_model((R, C, w, t), 1.0)
        b = RSPose.from_model((R, C, w, t), 1.0, compiled=True)
        for name in ("orientation", "position", "angular_velocity", "linear_velocity"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_frozen_instance_is_what_the_constructor_builds():
    """``frozen_instance`` (the results' construction without the frozen dataclass'
    field-by-field stores) gives an object equal to the constructor's, field by field: the
    values given, the defaults and default factories of the others; an unknown field or a
    missing required one raises TypeError as the constructor does."""
    R, C, w, t = _model(3)
    pose = frozen_instance(
        RSPose,
        {"orientation": R, "position": C, "angular_velocity": w, "linear_velocity": t},
    )
    want = RSPose(R, C, w, t)
    for f in dataclasses.fields(RSPose):
        assert getattr(pose, f.name) is getattr(want, f.name)
    given = {"success": True, "solver": "p3p", "rmse_px": 0.25, "pose": pose, "num_valid": 4}
    est, ref = frozen_instance(RSPoseEstimate, given), RSPoseEstimate(**given)
    for f in dataclasses.fields(RSPoseEstimate):
        a, b = getattr(est, f.name), getattr(ref, f.name)
        if isinstance(b, np.ndarray):
            assert a is not b and a.dtype == b.dtype and np.array_equal(a, b)
        elif f.name == "model":  # (a new identity model of each)
            assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
        elif isinstance(b, float) and b != b:
            assert a != a
        else:
            assert a == b
    assert est.timings is not ref.timings  # (a factory's default: a new dict each)
    with pytest.raises(dataclasses.FrozenInstanceError):
        est.success = False
    with pytest.raises(TypeError):
        frozen_instance(RSPoseEstimate, {"success": True, "no_such_field": 1})
    with pytest.raises(TypeError):
        frozen_instance(RSPoseEstimate, {"solver": "p3p"})
