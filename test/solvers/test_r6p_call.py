"""The public ``r6p`` call: its one-call fast path (float64 (6, 2) / (6, 3) arrays, default r)
gives the same roots and the same errors as the general path (validated by ``check_inputs``,
solved stage by stage)."""

import importlib

import numpy as np
import pytest

from rs_localizer.sim.synthetic import make_frame
from rs_localizer.solvers import DegenerateInputError, r6p

mod = importlib.import_module("rs_localizer.solvers.r6p")  # the package re-exports r6p


def _instances(n=8):
    rng = np.random.default_rng(11)
    return [
        make_frame(rng, 6, rs_speed=0.6, angle_from_identity=float(a), model="eq5")
        for a in rng.uniform(0, 20, n)
    ]


def _step_by_step(x, X):
    """The general path: lists (so no fast path), solved by the stage-by-stage ``_solve``."""
    x, X = np.array(x), np.array(X)
    Z, its, err = mod._solve(x, X, x[:, 1].copy(), 0.0)
    return Z, its, err


def test_fast_path_equals_the_stage_by_stage_solver(monkeypatch):
    for f in _instances():
        x, X = np.ascontiguousarray(f.x), np.ascontiguousarray(f.X)
        Z, its, err = _step_by_step(x.tolist(), X.tolist())
        with monkeypatch.context() as m:  # the fast path validates without check_inputs
            m.setattr(mod, "check_inputs", lambda *a, **k: pytest.fail("slow path taken"))
            sols = r6p(x, X)
        general = r6p(x.tolist(), X.tolist())
        assert len(sols) == len(general) == int(np.isfinite(err).sum()) > 0
        for s, g, z, k in zip(sols, general, Z, its, strict=False):
            for a, b in (
                (s.v, z[0:3]),
                (s.w, z[3:6]),
                (s.C, z[6:9]),
                (s.t, z[9:12]),
                (g.v, z[0:3]),
                (g.t, z[9:12]),
            ):
                np.testing.assert_array_equal(a, b)
            assert s.iterations == k and s.R_rs is None
            for a in (s.v, s.C, s.w, s.t):
                assert not a.flags.writeable
        assert any(np.linalg.norm(s.w - f.w) < 1e-8 * np.linalg.norm(f.w) for s in sols)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
@pytest.mark.parametrize("where", ["x", "X", "r0"])
def test_fast_path_rejects_non_finite_input(where, bad):
    f = _instances(1)[0]
    x, X, r0 = f.x.copy(), f.X.copy(), 0.0
    if where == "x":
        x[3, 0] = bad
    elif where == "X":
        X[5, 2] = bad
    else:
        r0 = bad
    with pytest.raises(ValueError, match="NaN or inf"):
        r6p(x, X, None, r0)


def test_fast_path_degenerate_input():
    f = _instances(1)[0]
    line = np.array([0.1, 0.2, 0.3]) + np.linspace(-1, 1, 6)[:, None] * np.array([0.3, -0.5, 0.8])
    with pytest.raises(DegenerateInputError, match="coincident or collinear"):
        r6p(f.x.copy(), line)
    with pytest.raises(DegenerateInputError):
        r6p(f.x.copy(), np.ones((6, 3)))
    X = f.X.copy()
    X[4] = X[2]
    with pytest.raises(DegenerateInputError, match="duplicated"):
        r6p(f.x.copy(), X)
    with pytest.raises(ValueError, match="exactly 6"):
        r6p(np.zeros((7, 2)), np.zeros((7, 3)))
    with pytest.raises(ValueError):
        r6p(f.x.T.copy(), f.X)
