"""The estimate's acceleration sensitivity against finite differences of the refinement on data
generated with an accelerating camera."""

from __future__ import annotations

import numpy as np
import pytest

from rs_localizer.estimation.estimate import (
    EstimateOptions,
    RansacOptions,
    RefineOptions,
    estimate_rs_pose,
)
from rs_localizer.estimation.refine import RefineSettings, refine_rs_pose
from rs_localizer.estimation.sensitivity import acceleration_sensitivity
from rs_localizer.geometry import matrix_to_rotvec, rotvec_to_matrix
from rs_localizer.sim.trajectory import SequenceConfig, generate_sequence, make_trajectory


def _outputs(R, C, w, t, s):
    """(camera rotation, position, omega_cam, v_cam) from the model, by their definitions."""
    return R.T, -R.T @ C, -w / s, (np.cross(w, C) - t) / s


def test_sensitivity_matches_finite_differences():
    rng = np.random.default_rng(0)
    s = 30e-6 * 1000.0  # seconds per unit r
    n = 300
    R = rotvec_to_matrix(np.array([0.1, -0.3, 0.05]))
    C = np.array([0.4, -0.2, 1.0])
    w = np.array([0.02, -0.04, 0.01])  # ~1.5 rad/s
    t = np.array([0.03, 0.01, -0.02])
    Xc = np.stack([rng.uniform(-4, 4, n), rng.uniform(-3, 3, n), rng.uniform(3, 12, n)], 1)
    X = (Xc - C) @ R  # world points
    tau = rng.uniform(-0.36, 0.36, n)

    def observe(alpha, a):
        beta = -s * s * np.asarray(alpha)
        b = np.cross(beta, C) - s * s * np.asarray(a)
        rot = rotvec_to_matrix(tau[:, None] * w + 0.5 * tau[:, None] ** 2 * beta)
        p = (
            np.einsum("nij,nj->ni", rot, X @ R.T)
            + C
            + tau[:, None] * t
            + 0.5 * tau[:, None] ** 2 * b
        )
        return p[:, :2] / p[:, 2:]

    th = 2.0 / 1000.0
    G = acceleration_sensitivity(R, C, w, t, X, observe(np.zeros(3), np.zeros(3)), tau, s, th)
    assert G.shape == (12, 6)
    base = _outputs(R, C, w, t, s)
    for j in range(6):
        acc = np.zeros(6)
        acc[j] = 2.0  # rad/s^2 or m/s^2
        x = observe(acc[:3], acc[3:])
        ref = refine_rs_pose(
            (R, C, w, t), X, x, tau, th, RefineSettings(max_iterations=30, tol=1e-15)
        )
        out = _outputs(ref.R, ref.C, ref.w, ref.t, s)
        d = (
            np.concatenate(
                [
                    matrix_to_rotvec(out[0] @ base[0].T),
                    out[1] - base[1],
                    out[2] - base[2],
                    out[3] - base[3],
                ]
            )
            / 2.0
        )
        np.testing.assert_allclose(d, G[:, j], rtol=0.02, atol=1e-3 * np.abs(G[:, j]).max())
    # an angular acceleration moves the estimate measurably (the reason the filter models it)
    assert np.abs(G[6:9, :3]).max() > 1e-3 and np.abs(G[9:12, :3]).max() > 1e-3


def test_estimator_returns_it_on_request():
    traj = make_trajectory("shake")
    frames, _, cam, _ = generate_sequence(SequenceConfig(num_frames=8, seed=5), trajectory=traj)
    f = frames[1]
    plain = estimate_rs_pose(
        f.uv, f.xyz, cam, options=EstimateOptions(ransac=RansacOptions(seed=0))
    )
    assert plain.acceleration_sensitivity is None
    opts = EstimateOptions(
        ransac=RansacOptions(seed=0), refine=RefineOptions(acceleration_sensitivity=True)
    )
    est = estimate_rs_pose(f.uv, f.xyz, cam, options=opts)
    assert est.acceleration_sensitivity.shape == (12, 6)
    np.testing.assert_array_equal(est.model.R, plain.model.R)  # nothing else changes
    # removing the shift the true angular acceleration causes brings the per-frame angular
    # velocity closer to the truth (the shake turns at 20-30 rad/s^2)
    raw, corrected = [], []
    for f in frames:
        est = estimate_rs_pose(f.uv, f.xyz, cam, options=opts)
        t_ref = f.index / 30.0 + float(cam.line_time(cam.reference_line))
        h = 1e-4
        alpha = (traj.velocity_body(t_ref + h)[0] - traj.velocity_body(t_ref - h)[0]) / (2 * h)
        G = est.acceleration_sensitivity
        raw.append(np.linalg.norm(est.pose.angular_velocity - f.angular_velocity))
        corrected.append(
            np.linalg.norm(est.pose.angular_velocity - G[6:9, :3] @ alpha - f.angular_velocity)
        )
    assert np.median(corrected) < 0.7 * np.median(raw)


@pytest.mark.parametrize("n", [0])
def test_degenerate_input_gives_none(n):
    z = np.zeros(3)
    assert (
        acceleration_sensitivity(
            np.eye(3), z, z, z, np.zeros((n, 3)), np.zeros((n, 2)), np.zeros(n), 0.03, 1e-3
        )
        is None
    )


@pytest.mark.parametrize("max_iterations", [0, 1, 10])
def test_refinement_block_equals_a_separate_pass(max_iterations):
    """``refine_rs_pose(acceleration_block=True)`` gives J^T W D at its result: the same
    sensitivity as a separate pass over the points (also after a rejected last step), and
    J^T W D equal to one built with NumPy from the exact Jacobian (finite differences)."""
    from rs_localizer.estimation.refine import exact_residuals

    rng = np.random.default_rng(3)
    s, n = 0.03, 200
    R = rotvec_to_matrix(np.array([0.2, 0.1, -0.1]))
    C = np.array([0.1, 0.3, 0.5])
    w = np.array([0.01, 0.02, -0.01])
    t = np.array([0.01, -0.02, 0.005])
    Xc = np.stack([rng.uniform(-3, 3, n), rng.uniform(-2, 2, n), rng.uniform(3, 9, n)], 1)
    X = (Xc - C) @ R
    tau = rng.uniform(-0.4, 0.4, n)
    p = Xc + tau[:, None] * t  # (a slightly wrong model: residuals, Huber weights < 1)
    x = p[:, :2] / p[:, 2:] + rng.normal(0, 1.5e-3, (n, 2))
    x[:20] += 0.05  # outliers beyond the cutoff
    th = 2e-3
    ref = refine_rs_pose(
        (R, C, w, t),
        X,
        x,
        tau,
        th,
        RefineSettings(max_iterations=max_iterations, cutoff=5 * th, acceleration_block=True),
    )
    B = ref.acceleration_block
    assert B.shape == (12, 6)
    Hinv = ref.covariance / ref.sigma**2
    fast = acceleration_sensitivity(
        ref.R,
        ref.C,
        ref.w,
        ref.t,
        X,
        x,
        tau,
        s,
        th,
        cutoff=5 * th,
        normal_inverse=Hinv,
        acceleration_block=B,
    )
    slow = acceleration_sensitivity(
        ref.R, ref.C, ref.w, ref.t, X, x, tau, s, th, cutoff=5 * th, normal_inverse=Hinv
    )
    np.testing.assert_allclose(fast, slow, rtol=1e-9, atol=1e-12 * np.abs(slow).max())
    # independent: J^T W D with J from finite differences of the exact residuals, Huber
    # weights on the image distance, points beyond the cutoff left out
    theta0 = np.concatenate([np.zeros(3), ref.C, ref.w, ref.t])
    r0 = exact_residuals(theta0, ref.R, X, x, tau).reshape(-1, 2)
    e = np.linalg.norm(r0, axis=1)
    wgt = np.where(e <= th, 1.0, th / e) * (e <= 5 * th)
    J = np.empty((2 * n, 12))
    h = 1e-7
    for j in range(12):
        d = np.zeros(12)
        d[j] = h
        J[:, j] = (
            exact_residuals(theta0 + d, ref.R, X, x, tau)
            - exact_residuals(theta0 - d, ref.R, X, x, tau)
        ) / (2 * h)
    W = np.repeat(wgt, 2)
    D = 0.5 * np.repeat(tau, 2)[:, None] * J[:, 6:12]
    np.testing.assert_allclose(B, (J * W[:, None]).T @ D, rtol=1e-5, atol=1e-6 * np.abs(B).max())
