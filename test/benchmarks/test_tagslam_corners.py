"""TagSLAMCorners, the benchmarks' corner-level problem in TagSLAM's inverse transforms
(benchmarks.joint_reference): on the synthetic rig of helpers.rig_corners its solve reaches
the optimum of the package's RigCorners from the same start, and it refuses a loss it does
not know."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.rig_corners import mount_errors, start

from benchmarks.joint_reference import TagSLAMCorners
from rs_localizer.calibration.corners import RigCorners


def _inverse(R, p):
    """The inverse transforms ``(R^T, -R^T p)`` of ``R`` (K, 3, 3), ``p`` (K, 3) m."""
    Ri = R.transpose(0, 2, 1)
    return Ri, -np.einsum("nij,nj->ni", Ri, p)


def _problems(seed: int):
    """The same corners and start as ``RigCorners`` and as ``TagSLAMCorners`` (world -> rig,
    rig -> camera), and the true mountings."""
    cam, (uv, X, f, m), start_g, start_m, free, truth = start(seed)
    args = (uv, [cam], np.zeros(len(uv), dtype=int), f, m)
    rig = RigCorners(*args, start_g, start_m, free, X)
    inverse = TagSLAMCorners(*args, _inverse(*start_g), _inverse(*start_m), free, X)
    return rig, inverse, truth


def test_the_inverse_transforms_reach_the_package_s_optimum():
    p, q, truth = _problems(0)
    sol = p.solve(2.0, ftol=1e-12, xtol=1e-12)
    e = mount_errors(sol.mounts, truth)
    # (0.5 px noise on 900 corners: well under 0.05 deg and 1 mm)
    assert np.abs(np.rad2deg(e[:, :3])).max() < 0.05 and np.abs(e[:, 3:]).max() < 1e-3
    # the start was 0.6-1 deg and 5-10 mm off; the same optimum from the inverse transforms
    # (under the same loss, SciPy's soft_l1 on each coordinate)
    sol_q = q.solve(2.0, loss="soft_l1", ftol=1e-12, xtol=1e-12)
    np.testing.assert_allclose(mount_errors(_inverse(*sol_q.mounts), truth), e, atol=1e-6)


def test_an_unknown_loss_and_the_mountings_covariance_are_refused():
    _, q, _ = _problems(2)
    with pytest.raises(ValueError, match="unknown loss"):
        q.solve(2.0, loss="huber")
    sol = q.solve(2.0)
    with pytest.raises(ValueError, match="inverse"):
        q.mounting_covariance(sol)
