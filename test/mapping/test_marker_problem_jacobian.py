"""The bundle adjustment's analytic Jacobian (MarkerProblem.jacobian) against central finite
differences of its residuals, for every model the adjustment runs (rolling shutter with the
motion tie, the line delay and the corner offset; global shutter; a frame held as the gauge),
at a point away from the solution (perturbed poses, velocities, offset)."""

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.optimize._numdiff import approx_derivative

from rs_localizer.geometry import matrix_to_rotvec, rotvec_to_matrix
from rs_localizer.mapping.marker_problem import (
    MarkerProblem,
    inverse_left_jacobian,
    left_jacobian,
)
from rs_localizer.sim.marker_mapping import room_scene


@pytest.fixture(scope="module")
def scene():
    return room_scene(12)


def problem(scene, **changes):
    room, camera, _, frames, truth, opts = scene
    obs = {k: f.corners for k, f in enumerate(frames) if f.corners}
    fr = sorted(obs)
    init = SimpleNamespace(
        frames={
            k: (truth["orientation"][k].T, -truth["orientation"][k].T @ truth["position"][k])
            for k in fr
        },
        markers={int(m): (room.R[m], room.p[m]) for m in room.ids},
        stamps={k: frames[k].stamp for k in fr},
    )
    o = replace(opts, **{k: v for k, v in changes.items() if k != "fix"})
    seen = sorted({m for d in obs.values() for m in d} - {0})
    fix = 0 if changes.get("fix") else None
    anchor = None if fix is not None else 0
    if anchor is None:
        seen = sorted({m for d in obs.values() for m in d})
    prob = MarkerProblem(init, obs, camera, o, fr, seen, anchor, fix_frame=fix)
    x = prob.x0(init, camera.line_delay)
    rng = np.random.default_rng(1)
    x = x + rng.normal(scale=0.02, size=x.shape)  # (away from the truth: every term live)
    if prob.ld_col is not None:
        x[prob.ld_col] = 1e6 * camera.line_delay * 1.1
    if prob.co_col is not None:
        x[prob.co_col] = 0.3
        prob.noise_px = 0.5
    prob.keep[1] = False  # (a rejected detection: its rows are left out)
    return prob, x


@pytest.mark.parametrize(
    "changes",
    [
        {},
        {"calibrate_readout": True},
        {"corner_offset": False},
        {"global_shutter": True},
        {"fix": True},
    ],
    ids=["rs", "readout", "no-offset", "gs", "frame-gauge"],
)
def test_jacobian_matches_finite_differences(scene, changes):
    prob, x = problem(scene, **changes)
    J = prob.jacobian(x)
    assert J.shape == (len(prob.residuals(x)), prob.n)
    # the pattern lies inside the declared sparsity
    S = prob.sparsity().toarray().astype(bool)
    assert not (J.toarray().astype(bool) & ~S).any()
    num = approx_derivative(prob.residuals, x, method="3-point", abs_step=1e-7)
    err = np.abs(J.toarray() - num)
    assert err.max() <= 1e-5 * np.abs(num).max() + 1e-6


def test_left_jacobians():
    rng = np.random.default_rng(0)
    for q in [
        np.zeros(3),
        1e-7 * rng.normal(size=3),
        rng.normal(size=3),
        3.0 * np.array([0, 0, 1]),
    ]:
        Jl = left_jacobian(q)
        # expm([q + d]x) = expm([J_l d]x) expm([q]x) to first order
        d = 1e-6 * rng.normal(size=3)
        lhs = matrix_to_rotvec(rotvec_to_matrix(q + d) @ rotvec_to_matrix(q).T)
        np.testing.assert_allclose(lhs, Jl @ d, atol=1e-11)
        np.testing.assert_allclose(inverse_left_jacobian(q) @ Jl, np.eye(3), atol=1e-9)


def test_corner_offset_std_is_the_dense_inverse(scene):
    """The corner offset's std: its diagonal element of the dense (J^T J)^-1, the pixel rows
    and the offset's prior scaled by 1 / noise."""
    prob, x = problem(scene)
    J = prob.jacobian(x).toarray()
    n_px = 8 * int(prob.keep.sum())
    J[: n_px + 1] /= prob.noise_px  # (pixel rows, then the offset's prior)
    dense = np.sqrt(np.linalg.inv(J.T @ J)[prob.co_col, prob.co_col])
    assert prob.corner_offset_std(x) == pytest.approx(dense, rel=1e-6)
    no_offset, x = problem(scene, corner_offset=False)
    assert np.isnan(no_offset.corner_offset_std(x))
