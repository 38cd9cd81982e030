"""RigCorners, the corner-level problem of calibrate-rig's refinement and the joint reference:
on a synthetic rig of three global-shutter cameras with known mountings, its solve recovers
the truth in either parameterization, its mountings' covariance is the dense computation's
(the rig poses marginalized, plain and per group), and with independent corner noise the
truth lies within the plain one as often as a chi-square says."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from rs_localizer.calibration.corners import RigCorners
from rs_localizer.geometry import matrix_to_rotvec, rotvec_to_matrix
from rs_localizer.sim.trajectory import default_camera, default_rig

NOISE_PX = 0.5


def _scene(seed: int, frames: int = 10, points: int = 30, noise: float = NOISE_PX):
    """Three cameras (front, left, right: the simulator's rig) on ``frames`` rig poses, each
    seeing ``points`` points 3-8 m away; returns the truth (rig poses rig -> world, mountings
    camera -> rig) and the corners (pixels with ``noise`` px of Gaussian noise)."""
    rng = np.random.default_rng(seed)
    cam = default_camera(line_delay=0.0)
    rig = default_rig(3, (0.0,) * 4)
    Rm = np.array([c.R_rig_cam for c in rig])
    pm = np.array([c.p_rig_cam for c in rig])
    Rg = rotvec_to_matrix(rng.normal(0, 0.3, (frames, 3)))
    Pg = rng.normal(0, 1.0, (frames, 3))
    uv, X, f_idx, m_idx = [], [], [], []
    for g in range(frames):
        for m in range(3):
            xy = rng.uniform(-0.5, 0.5, (points, 2))
            x_cam = np.column_stack([xy, np.ones(points)]) * rng.uniform(3, 8, (points, 1))
            X.append((x_cam @ Rm[m].T + pm[m]) @ Rg[g].T + Pg[g])
            uv.append(cam.project(x_cam) + rng.normal(0, noise, (points, 2)))
            f_idx.append(np.full(points, g))
            m_idx.append(np.full(points, m))
    corners = tuple(np.concatenate(v) for v in (uv, X, f_idx, m_idx))
    return cam, (Rg, Pg), (Rm, pm), corners, rng


def _turned(R, rng, rad):
    return rotvec_to_matrix(rng.normal(0, rad, (len(R), 3))) @ R


def _problem(seed: int, inverse: bool = False, **kw):
    cam, (Rg, Pg), (Rm, pm), (uv, X, f, m), rng = _scene(seed, **kw)
    start_m = (np.r_[Rm[:1], _turned(Rm[1:], rng, 0.01)], pm + rng.normal(0, 0.005, pm.shape))
    start_g = (_turned(Rg, rng, 0.01), Pg + rng.normal(0, 0.01, Pg.shape))
    start_m[1][0] = pm[0]
    if inverse:  # (world -> rig, rig -> camera)
        Rgi = start_g[0].transpose(0, 2, 1)
        Rmi = start_m[0].transpose(0, 2, 1)
        start_g = (Rgi, -np.einsum("nij,nj->ni", Rgi, start_g[1]))
        start_m = (Rmi, -np.einsum("nij,nj->ni", Rmi, start_m[1]))
    free = np.array([False, True, True])
    p = RigCorners(uv, [cam], np.zeros(len(uv), dtype=int), f, m, start_g, start_m, free, X,
                   parameters="inverse" if inverse else "rig")  # fmt: skip
    return p, (Rm, pm)


def _mount_errors(sol, truth, inverse=False):
    """(2, 6) the free mountings' errors (rotation rad rig axes, position m)."""
    R, p = sol.mounts
    if inverse:
        R, p = R.transpose(0, 2, 1), -np.einsum("nji,nj->ni", R, p)
    Rt, pt = truth
    return np.array([np.r_[matrix_to_rotvec(R[i] @ Rt[i].T), p[i] - pt[i]] for i in (1, 2)])


def test_the_solve_recovers_the_mountings_in_either_parameterization():
    p, truth = _problem(0)
    sol = p.solve(2.0, ftol=1e-12, xtol=1e-12)
    e = _mount_errors(sol, truth)
    # (0.5 px noise on 900 corners: well under 0.05 deg and 1 mm)
    assert np.abs(np.rad2deg(e[:, :3])).max() < 0.05 and np.abs(e[:, 3:]).max() < 1e-3
    # the start was 0.6-1 deg and 5-10 mm off; the same optimum from the inverse transforms
    q, _ = _problem(0, inverse=True)
    sol_q = q.solve(2.0, ftol=1e-12, xtol=1e-12)
    np.testing.assert_allclose(_mount_errors(sol_q, truth, inverse=True), e, atol=1e-6)
    # the residuals at the solution are the noise
    r = p.errors(sol.result.x)
    assert 0.8 * NOISE_PX < np.sqrt(np.mean(r**2)) < 1.1 * NOISE_PX


def test_the_mountings_covariance_is_the_dense_one_with_the_rig_poses_marginalized():
    p, _ = _problem(1)
    sol = p.solve(2.0, ftol=1e-12, xtol=1e-12)
    J = sol.result.jac.toarray()
    r = sol.result.fun
    Hinv = np.linalg.inv(J.T @ J)
    k = 6 * p.G
    s2 = 2 * sol.result.cost / (len(r) - p.n)
    C = p.mounting_covariance(sol)[0]
    dense = s2 * Hinv[k:, k:]
    for i in range(2):
        np.testing.assert_allclose(C[i], dense[6 * i : 6 * i + 6, 6 * i : 6 * i + 6],
                                   rtol=1e-6, atol=1e-15)  # fmt: skip
    # grouped by rig frame: the sandwich H^-1 (sum_c J_c^T r_c r_c^T J_c) H^-1, mountings' block
    groups = np.repeat(p.frame, 2)
    B = sum(np.outer(J[groups == g].T @ r[groups == g], J[groups == g].T @ r[groups == g])
            for g in range(p.G))  # fmt: skip
    dense = (Hinv @ B @ Hinv)[k:, k:]
    C = p.mounting_covariance(sol, p.frame)[0]
    for i in range(2):
        np.testing.assert_allclose(C[i], dense[6 * i : 6 * i + 6, 6 * i : 6 * i + 6],
                                   rtol=1e-6, atol=1e-15)  # fmt: skip


def test_a_mounting_no_corner_sees_gets_an_infinite_covariance():
    """The right camera's corners dropped (its mounting still free): the corners do not
    constrain it, so its covariance is infinite (the pseudo-inverse would say 0), the left
    camera's the same as without the right camera's mounting in the problem at all (but for
    the residual variance's degrees of freedom)."""
    p, _ = _problem(1)
    seen = p.mounting != 2
    args = (p.uv[seen], [p.cameras[0]], p.camera[seen], p.frame[seen], p.mounting[seen],
            (p.R0g, p.P0g))  # fmt: skip
    q = RigCorners(*args, (p.R0m, p.p0m), np.array([False, True, True]), p.X[seen])
    sol = q.solve(2.0, ftol=1e-12, xtol=1e-12)
    C = q.mounting_covariance(sol)[0]
    assert np.isinf(C[1]).all() and np.isfinite(C[0]).all()
    alone = RigCorners(*args, (p.R0m[:2], p.p0m[:2]), np.array([False, True]), p.X[seen])
    C_alone = alone.mounting_covariance(alone.solve(2.0, ftol=1e-12, xtol=1e-12))[0]
    dof = (2 * len(q.uv) - q.n) / (2 * len(q.uv) - alone.n)  # (s^2 over 6 parameters more)
    np.testing.assert_allclose(C[0] * dof, C_alone[0], rtol=1e-5, atol=1e-13)


def test_the_truth_is_within_the_covariance_as_often_as_chi_square_says():
    """Independent corner noise: each free camera's mounting NEES (6 degrees of freedom)
    averages 6 and stays below its 99 % quantile in nearly every one of 30 videos."""
    nees = []
    for seed in range(30):
        p, truth = _problem(100 + seed, frames=8, points=20)
        sol = p.solve(2.0, ftol=1e-12, xtol=1e-12)
        e = _mount_errors(sol, truth)
        C = p.mounting_covariance(sol)[0]
        nees += [e[i] @ np.linalg.solve(C[i], e[i]) for i in range(2)]
    nees = np.array(nees)
    assert 4.5 < nees.mean() < 8.0, nees.mean()
    assert np.mean(nees < chi2.ppf(0.99, 6)) >= 0.9, nees


def test_inconsistent_input_is_refused():
    p, _ = _problem(2)
    with pytest.raises(ValueError, match="unknown loss"):
        p.solve(2.0, loss="huber")
    with pytest.raises(ValueError, match="lengths"):
        RigCorners(p.uv, p.cameras, p.camera[:-1], p.frame, p.mounting, (p.R0g, p.P0g),
                   (p.R0m, p.p0m), p.free, p.X)  # fmt: skip
    with pytest.raises(ValueError, match="index"):
        RigCorners(p.uv, p.cameras, p.camera + 1, p.frame, p.mounting, (p.R0g, p.P0g),
                   (p.R0m, p.p0m), p.free, p.X)  # fmt: skip
