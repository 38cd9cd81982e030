"""RigCorners, the corner-level problem of calibrate-rig's refinement: on a synthetic rig of
three global-shutter cameras with known mountings (helpers.rig_corners), its solve recovers
the truth, its mountings' covariance is the dense computation's (the rig poses marginalized,
plain and per group), and with independent corner noise the truth lies within the plain one as
often as a chi-square says. (The benchmarks' variant, TagSLAMCorners, in the inverse
transforms: test/benchmarks/test_tagslam_corners.py.)"""

from __future__ import annotations

import numpy as np
import pytest
from helpers.rig_corners import NOISE_PX, mount_errors, start
from scipy.stats import chi2

from rs_localizer.calibration.corners import RigCorners


def _problem(seed: int, **kw):
    cam, (uv, X, f, m), start_g, start_m, free, truth = start(seed, **kw)
    return RigCorners(uv, [cam], np.zeros(len(uv), dtype=int), f, m, start_g, start_m, free,
                      X), truth  # fmt: skip


def test_the_solve_recovers_the_mountings():
    # (the start was 0.6-1 deg and 5-10 mm off)
    p, truth = _problem(0)
    sol = p.solve(2.0, ftol=1e-12, xtol=1e-12)
    e = mount_errors(sol.mounts, truth)
    # (0.5 px noise on 900 corners: well under 0.05 deg and 1 mm)
    assert np.abs(np.rad2deg(e[:, :3])).max() < 0.05 and np.abs(e[:, 3:]).max() < 1e-3
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
        e = mount_errors(sol.mounts, truth)
        C = p.mounting_covariance(sol)[0]
        nees += [e[i] @ np.linalg.solve(C[i], e[i]) for i in range(2)]
    nees = np.array(nees)
    assert 4.5 < nees.mean() < 8.0, nees.mean()
    assert np.mean(nees < chi2.ppf(0.99, 6)) >= 0.9, nees


def test_inconsistent_input_is_refused():
    p, _ = _problem(2)
    with pytest.raises(ValueError, match="lengths"):
        RigCorners(p.uv, p.cameras, p.camera[:-1], p.frame, p.mounting, (p.R0g, p.P0g),
                   (p.R0m, p.p0m), p.free, p.X)  # fmt: skip
    with pytest.raises(ValueError, match="index"):
        RigCorners(p.uv, p.cameras, p.camera + 1, p.frame, p.mounting, (p.R0g, p.P0g),
                   (p.R0m, p.p0m), p.free, p.X)  # fmt: skip
