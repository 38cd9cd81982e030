"""The paper's qualitative claims (sec. 4) on quick runs of ``rs_localizer.experiments``.

Every experiment runs with 15 trials per setting (the full run, ``docs/experiments``, uses 200)
and a fixed seed, so the tests are deterministic; the thresholds below are chosen so they hold
for other seeds too (checked on seeds 0-2) while a solver that lost its claimed property would
miss them by a wide margin. Each threshold says why it is what it is.
"""

import json
import os

import numpy as np
import pytest

import rs_localizer.experiments as E

TRIALS = 15
SPEEDS = (0.25, 0.5, 0.75, 1.0)
ROT, POS = 0, 1  # metric columns of the medians


@pytest.fixture(scope="module")
def exp1():
    return E.exp1_motion(TRIALS, SPEEDS)


@pytest.fixture(scope="module")
def exp2t():
    return E.exp2_translation(TRIALS, (0.0, 0.5, 1.0), noise_px=1.0)


@pytest.fixture(scope="module")
def exp3():
    return E.exp3_iterations(TRIALS, (0.5, 1.0), (1, 5, 50))


@pytest.fixture(scope="module")
def exp3_alg():
    return E.exp3_algebraic(10, 30, (0.5,))


@pytest.fixture(scope="module")
def exp4():
    return E.exp4_orientation(TRIALS, (0, 10, 40))


@pytest.fixture(scope="module")
def exp5():
    return E.exp5_p3p_init(TRIALS, (0.25, 1.0))


def ratio(m, a, b, col=slice(0, 2)):
    return m[a][:, col] / m[b][:, col]


# ---------------------------------------------------------------------------------- Exp. 1
def test_r6p_1lin_matches_r6p_at_every_motion_level(exp1):
    # Paper (Fig. 2): R6P_{v,C,w,t}^{[v]x} is "almost identical" to R6P. With R = I its five
    # iterations converge to R6P's root of eq. 5 on the same 6 points, so the medians agree to
    # < 1% here; 10% is the margin the issue asks for and still fails for e.g. a solver that
    # stops after an un-converged first iteration at high speed.
    r = ratio(exp1["medians"], "r6p_1lin", "r6p")
    assert np.all(np.abs(r - 1) <= 0.10), r


def test_p3p_much_worse_than_r6p_at_the_highest_motion(exp1):
    # Paper: R6P "much better" than P3P thanks to the RS model. At 30 deg and 0.3 units per frame
    # we measure 10-15x; 3x (the bound) leaves room for the 15-trial spread.
    r = ratio(exp1["medians"], "p3p", "r6p")[-1]
    assert np.all(r >= 3), r


def test_r9p_comparable_to_r6p(exp1):
    # Paper: R9P gives the best pose, "slightly outperforming" R6P. Noise-free we measure
    # R9P/R6P 0.2-0.9 at most speeds, up to 1.3 at single speeds on 15 trials. Comparable =
    # never worse than 1.5x, and better than R6P on the median over the speeds.
    r = ratio(exp1["medians"], "r9p", "r6p")
    assert np.all(r <= 1.5), r
    assert np.median(r[:, ROT]) < 1 and np.median(r[:, POS]) < 1, r


def test_alternating_solvers_poor_with_five_iterations(exp1):
    # Paper: the other 6-point iterative solvers "perform really bad" at 5 iterations. We
    # measure 6-40x R6P's rotation error; at least 2x at every speed from 0.5 up is a claim a
    # working alternation that converged in 5 steps would break.
    m = exp1["medians"]
    for a in ("r6p_vC_wt", "r6p_vCt_w", "r6p_vCt_wt"):
        r = m[a][1:, ROT] / m["r6p"][1:, ROT]
        assert np.all(r >= 2), (a, r)


def test_velocities_recovered(exp1):
    # Not a paper number, but Fig. 2 plots velocity errors: R6P's angular and linear velocity
    # errors must be well below the true velocity (P3P's error, it estimates none). Measured:
    # angular 7-50x below, 3x required; linear velocity is the least observable quantity (2.5x
    # below at the highest speed, 17x at the lowest), 2x required.
    m = exp1["medians"]
    assert np.all(m["r6p"][:, 2] * 3 <= m["p3p"][:, 2])
    assert np.all(m["r6p"][:, 3] * 2 <= m["p3p"][:, 3])


# ---------------------------------------------------------------------------------- Exp. 2
def test_translation_only_favours_vCt_solvers(exp2t):
    # Paper (Fig. 3 left): under pure translation with 1 px noise R6P_{v,C,t}^{w} and
    # R6P_{v,C,t}^{w,t} outperform R6P and R6P_{v,C,w,t}^{[v]x}. Measured ratio 0.2-0.5 of the
    # better of the two; < 0.75 demands a clear win, not a tie.
    m = exp2t["medians"]
    ref = np.minimum(m["r6p"][:, :2], m["r6p_1lin"][:, :2])
    for a in ("r6p_vCt_w", "r6p_vCt_wt"):
        r = m[a][:, :2] / ref
        assert np.all(r < 0.75), (a, r)


def test_joined_solver_beats_r6p_under_translation(exp2t):
    # Paper: the joined solver "gives better performance than R6P". Selecting on held-out
    # points it tracks R6P_{v,C,t}^{w} (ratio 0.25-0.5 to R6P measured); < 0.75 as above.
    r = ratio(exp2t["medians"], "r6p_joined", "r6p")
    assert np.all(r < 0.75), r


# ---------------------------------------------------------------------------------- Exp. 3
def test_more_iterations_help_alternating_solvers(exp3):
    # Paper (Fig. 4 left): 50 instead of 5 iterations improve R6P_{v,C}^{w,t},
    # R6P_{v,C,t}^{w}, R6P_{v,C,t}^{w,t}. Measured 1.5-10x lower median rotation error at 50;
    # strictly lower than at 5 and at 1 iteration at every speed is required.
    m = exp3["medians"]
    for a in ("r6p_vC_wt", "r6p_vCt_w", "r6p_vCt_wt"):
        assert np.all(m[f"{a}@50"][:, ROT] < m[f"{a}@5"][:, ROT]), a
        assert np.all(m[f"{a}@50"][:, ROT] < m[f"{a}@1"][:, ROT]), a


def test_one_iteration_of_r6p_1lin_close_to_r6p(exp3):
    # Paper: R6P_{v,C,w,t}^{[v]x} "performs as well as the R6P even with a single iteration".
    # With R = I the first iteration drops only [w]x[v]x with v ~ 0; measured within 0-10%
    # (15 trials); 25% tolerates the 15-trial spread but fails if the first iteration were
    # e.g. the pose-only half of an alternation (2-10x worse).
    r = ratio(exp3["medians"], "r6p_1lin@1", "r6p")
    assert np.all(np.abs(r - 1) <= 0.25), r


def test_algebraic_error_converges(exp3_alg):
    # Paper (Fig. 4 right): the algebraic error converges within ~8 steps. r6p_1lin is the raw
    # fixed-point sequence (v_init chaining): its median must fall by 6 orders of magnitude by
    # iteration 10 (measured: machine precision by ~8) and the mean convergence iteration must
    # be <= 12 (measured 7 at this speed).
    e = exp3_alg["errors"]["r6p_1lin"][0]
    med = np.nanmedian(e, axis=0)
    assert med[9] < 1e-6 * med[0], med[:10]
    assert np.mean(np.minimum(exp3_alg["converged_at"]["r6p_1lin"][0], 30)) <= 12
    # the alternating solvers minimise one least-squares residual block by block, so their
    # error can never increase (up to rounding) and must have dropped after 30 iterations
    for a in ("r6p_vC_wt", "r6p_vCt_w", "r6p_vCt_wt"):
        ea = exp3_alg["errors"][a][0]
        assert np.all(np.diff(ea, axis=1) <= 1e-9 * ea[:, :1]), a
        assert np.all(ea[:, -1] < ea[:, 0]), a


# ---------------------------------------------------------------------------------- Exp. 4
def test_linearization_point(exp4):
    # Paper (Fig. 5): the further from R = I, the worse; R6P beats P3P near R = I and loses to
    # it far away (Albl et al.: beyond ~6-15 deg). Measured R6P rotation error 0.15 deg at 0 and
    # 11-14 deg at 40 deg (P3P ~3.5 deg at every angle).
    m = exp4["medians"]
    assert m["r6p"][-1, ROT] > 10 * m["r6p"][0, ROT]
    assert np.all(m["r6p"][0, :2] < m["p3p"][0, :2])
    assert np.all(m["r6p"][-1, :2] > m["p3p"][-1, :2])
    # "R6P_{v,C,w,t}^{[v]x} matches R6P": within 10% up to 10 deg (measured identical);
    # at 40 deg both are >10 deg off and 5 iterations are not always converged (measured up to
    # 17% apart on 15 trials), so only a factor 1.5 there
    r = ratio(m, "r6p_1lin", "r6p")
    assert np.all(np.abs(r[:2] - 1) <= 0.10), r
    assert np.all(np.abs(r - 1) <= 0.5), r


# ---------------------------------------------------------------------------------- Exp. 5
def test_p3p_initialization(exp5):
    # Paper (Fig. 6): with P3P pre-rotation (random orientation) R6P_{v,C,w,t}^{[v]x} after ONE
    # iteration is "at least as good" as R6P and R9P comparable. Noise-free, our full run
    # measures 1 iteration at 1.1-1.2x R6P (within 8% with 1 px noise, see the report); 15-trial
    # medians spread 0.6-1.5x, so 1.6x guards against losing the property, not the 20%.
    m = exp5["medians"]
    assert np.all(ratio(m, "r6p_1lin@1", "r6p") <= 1.6)
    assert np.all(ratio(m, "r9p", "r6p") <= 1.6)
    # every RS solver beats P3P (R6P by 7-50x measured; 3x required at the highest speed),
    # the alternating ones at 50 iterations too (paper: "now perform better than P3P")
    assert np.all(ratio(m, "p3p", "r6p")[-1] >= 3)
    for a in ("r6p_vC_wt@50", "r6p_vCt_w@50", "r6p_vCt_wt@50"):
        assert np.all(m[a][:, ROT] < m["p3p"][:, ROT]), a


# ------------------------------------------------------------------------- Exp. 6 and 7
def test_timing_table_shape_and_speedup():
    # Paper (Table 1): one R6P_{v,C,w,t}^{[v]x} iteration is two orders of magnitude cheaper
    # than R6P. Measured ~100x on this (shared, noisy) machine; 10x is safe against load.
    t = E.exp6_timing(repeat=5, batch=50)
    rows = {r["solver"]: r for r in t["rows"]}
    assert rows["r6p"]["max_solutions"] == 20 and rows["r6p_1lin"]["max_solutions"] == 1
    assert rows["r6p"]["paper_us"] == 1700
    assert rows["r6p"]["us_call"] > 10 * rows["r6p_1lin"]["us_batched_1_iteration"]


def test_estimator_beats_global_shutter_under_fast_motion():
    # Beyond the paper: the RS estimator vs PoseLib's GS estimator at 30 deg / 0.3 units per
    # frame. Measured 0.03 vs 2 deg (60x); 3x required on 3 frames.
    r = E.exp7_estimator(3, (1.0,), methods=("r6p_1lin", "poselib"))
    m = r["medians"]
    assert np.all(np.isfinite(m["r6p_1lin"][:, :2]))
    assert np.all(m["r6p_1lin"][:, :2] * 3 <= m["poselib"][:, :2])


# ------------------------------------------------------------------------------- outputs
def test_outputs_from_results(tmp_path, exp1, exp2t, exp3, exp3_alg, exp4, exp5):
    # report, plots and results.json from the fixtures' raw results (no re-run)
    res = dict(
        exp1=exp1,
        exp2_translation=exp2t,
        exp3_iterations=exp3,
        exp3_algebraic=exp3_alg,
        exp4=exp4,
        exp5=exp5,
    )
    summary = E.summarize(res)
    files = E.write_outputs(summary, str(tmp_path))
    for f in files:
        assert (tmp_path / f).stat().st_size > 0, f
    assert {
        "exp1_motion.png",
        "exp3_convergence.png",
        "exp4_orientation.png",
        "exp5_p3p_init.png",
        "report.md",
        "results.json",
    } <= set(files)
    report = (tmp_path / "report.md").read_text()
    assert "## Claims: paper vs. ours" in report and "R6P root choice" in report
    back = E.load_summary(str(tmp_path / "results.json"))
    np.testing.assert_allclose(back["exp1"]["medians"]["r6p"], summary["exp1"]["medians"]["r6p"])
    verdicts = {c["verdict"] for c in E.claims(back)}
    assert verdicts <= {"agrees", "partly", "differs"}


def test_main_quick_subset_and_merge(tmp_path, capsys):
    out = str(tmp_path / "ex")
    assert E.main(["--quick", "--only", "exp4", "--trials", "3", "--out", out]) == 0
    assert E.main(["--quick", "--only", "exp6", "--out", out]) == 0  # merges into results.json
    with open(os.path.join(out, "results.json")) as fh:
        data = json.load(fh)
    assert {"exp4", "exp6", "_meta"} <= set(data)
    assert data["_meta"]["exp4"]["trials"] == 3 and data["_meta"]["exp4"]["quick"]
    assert (
        "quick run (3 trials per setting): the verdicts below are noisy" in capsys.readouterr().out
    )
    with open(os.path.join(out, "report.md")) as fh:
        assert "**Quick run** (exp4, exp6" in fh.read()  # the report says so too
    assert E.main(["--out", out, "--render-only"]) == 0
    assert os.path.exists(os.path.join(out, "exp6_timing.png"))
    with pytest.raises(SystemExit):
        E.main(["--only", "exp9", "--out", out])
