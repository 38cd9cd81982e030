"""The fused RANSAC batch (one numba call: sampling, P3P pre-rotation, batched RS solver,
preemptive MSAC) against the step-by-step kernels it fuses, and the estimator with and
without it."""

import numpy as np
import pytest

import rs_localizer.estimation.hypotheses as hypotheses_module
from rs_localizer._so3 import compose_rotvec
from rs_localizer.estimation.batch import fused_kernels, ransac_batch
from rs_localizer.estimation.estimate import estimate_rs_pose
from rs_localizer.estimation.sampling import draw_samples, gather_prerotated, select_prerotations
from rs_localizer.estimation.scoring import msac_scores
from rs_localizer.sim.synthetic import make_frame, paper_camera
from rs_localizer.solvers import p3p_batch, solver_info

CAM = paper_camera()
#: the squared 2 px inlier threshold (normalized units)
TH2 = (2.0 / CAM.mean_focal) ** 2
SOLVERS = ["p3p", "r6p_1lin", "r6p_vC_wt", "r6p_vCt_w", "r6p_vCt_wt", "r9p", "r6p_joined"]
#: the fused kernel's MSAC score against msac_scores': two compiled functions, equal bit for
#: bit with numba's IR inlining, one ulp apart without it (Debian 12's numba 0.56, see
#: _so3.INLINE: 4.722655163880259e-4 against ...258)
SCORE_RTOL = 1e-12


def _same_score(a, b):
    """Equal MSAC scores of two compiled paths, to the last bits (inf == inf)."""
    return a == pytest.approx(b, rel=SCORE_RTOL, abs=0.0)


def _frame_arrays(seed):
    f = make_frame(seed, 200, rs_speed=0.5, noise_px=1.0, outlier_ratio=0.3)
    x, r, r0e = CAM.normalize(f.points_px)
    return f, np.ascontiguousarray(x), f.X, np.ascontiguousarray(r), np.ascontiguousarray(r0e)


def _batch_setup(frame_seed, rng_seed, solver):
    """What a fused-batch test draws from: the frame's arrays ``(f, x, X, r, r0e)``, the
    solver's ``(kinds, n_params)`` and registry entry, a generator seeded ``rng_seed`` and a
    random point order drawn from it."""
    arrays = _frame_arrays(frame_seed)
    rng = np.random.default_rng(rng_seed)
    order = rng.permutation(len(arrays[1])).astype(np.int64)
    return arrays, fused_kernels(solver), solver_info(solver), rng, order


def _step_by_step(u, pool, order, x, X, r, r0e, solver, th2, bail, pre_n, pre_min):
    """The same batch with the public kernels, one call each (as RANSAC did before fusing)."""
    info = solver_info(solver)
    samples = order[draw_samples(u, pool)]
    b = np.concatenate([x, np.ones((len(x), 1))], axis=1)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    R, C, own = p3p_batch(b[samples[:, :3]], X[samples[:, :3]], backend="lambda_twist")
    R_p, C_p, ok_p = select_prerotations(R, C, own, samples, X, x, len(samples))
    if not info.rolling:
        Rs, Cs, ws, ts, ok = R_p, C_p, np.zeros_like(C_p), np.zeros_like(C_p), ok_p
    else:
        xs, Xs, rs = gather_prerotated(samples, R_p, x, X, r)
        its = info.default_iterations or 1
        bs = [fn(xs, Xs, rs, CAM.r0, iterations=its) for fn in info.batch]
        Rs = np.concatenate([compose_rotvec(np.ascontiguousarray(q.v), R_p) for q in bs])
        Cs, ws, ts = (np.concatenate([getattr(q, a) for q in bs]) for a in "Cwt")
        ok = np.concatenate([q.valid & ok_p for q in bs])
    sc, _ = msac_scores(
        x,
        X,
        r0e,
        CAM.readout_vector,
        Rs,
        np.ascontiguousarray(Cs),
        np.ascontiguousarray(ws),
        np.ascontiguousarray(ts),
        th2,
        ok,
        bail,
        True,
        pre_n,
        pre_min,
    )
    return sc, Rs, Cs, ws, ts, ok


@pytest.mark.parametrize("solver", SOLVERS)
def test_fused_batch_equals_the_step_by_step_kernels(solver):
    (f, x, X, r, r0e), (kinds, n_params), info, rng, order = _batch_setup(5, 1, solver)
    s, th2 = info.sample_size, TH2
    for K, pool, bail, pre_n, pre_min in [
        (40, len(x), np.inf, 0, 0),
        (33, 60, np.inf, 24, 3),
        (50, len(x), 0.05, 24, 8),
    ]:
        u = rng.random((K, s))
        h, score, Rs, Cs, ws, ts, n_bad = ransac_batch(
            u,
            pool,
            order,
            x,
            X,
            r,
            r0e,
            CAM.readout_vector,
            CAM.r0,
            kinds,
            n_params,
            info.default_iterations or 1,
            th2,
            bail,
            pre_n,
            pre_min,
        )
        assert n_bad == 0  # no motion bounds given
        sc, Rs2, Cs2, ws2, ts2, ok = _step_by_step(
            u, pool, order, x, X, r, r0e, solver, th2, bail, pre_n, pre_min
        )
        assert len(Rs) == len(sc) == len(info.batch or (0,)) * K
        # bit for bit: the same kernels on the same numbers
        np.testing.assert_array_equal(Rs[ok], Rs2[ok])
        for a, b in ((Cs, Cs2), (ws, ws2), (ts, ts2)):
            np.testing.assert_array_equal(a[ok], b[ok])
        assert h == int(np.argmin(sc)) and _same_score(score, sc.min())
        if info.rolling:  # motion bounds below every hypothesis's: none is scored
            *_, n_rej = ransac_batch(
                u,
                pool,
                order,
                x,
                X,
                r,
                r0e,
                CAM.readout_vector,
                CAM.r0,
                kinds,
                n_params,
                info.default_iterations or 1,
                th2,
                bail,
                pre_n,
                pre_min,
                False,
                0.0,
                0.0,
            )
            assert n_rej == int(ok.sum())
    # the batch best of a plain batch is a good pose (sanity of the whole chain)
    if np.isfinite(score):
        from rs_localizer.geometry import rotation_angle_deg

        assert rotation_angle_deg(Rs[h], f.R) < 5.0


@pytest.mark.parametrize("solver", ["r6p_1lin", "r6p_vCt_w"])
def test_fused_batch_skips_implausible_motion(solver):
    """With motion bounds, the fused batch scores exactly the hypotheses that
    :func:`plausible_motion` accepts (the step-by-step path's filter) and counts the rest."""
    from rs_localizer.estimation.plausibility import plausible_motion

    (_f, x, X, r, r0e), (kinds, n_params), info, rng, order = _batch_setup(5, 2, solver)
    th2 = TH2
    u = rng.random((40, info.sample_size))
    args = (
        u,
        len(x),
        order,
        x,
        X,
        r,
        r0e,
        CAM.readout_vector,
        CAM.r0,
        kinds,
        n_params,
        info.default_iterations or 1,
        th2,
        np.inf,
        0,
        0,
        False,
    )
    _, _, Rs, Cs, ws, ts, n0 = ransac_batch(*args)
    sc, *_, ok = _step_by_step(u, len(x), order, x, X, r, r0e, solver, th2, np.inf, 0, 0)
    wn = np.linalg.norm(ws[ok], axis=1)
    bounds = (float(np.median(wn)), np.inf)  # about half the valid hypotheses too fast
    h, score, _, _, _, _, n_bad = ransac_batch(*args, *bounds)
    plausible = plausible_motion(Rs, Cs, ws, ts, bounds)
    assert n0 == 0 and n_bad == int(np.count_nonzero(ok & ~plausible)) > 0
    sc_ok = np.where(ok & plausible, sc, np.inf)
    assert _same_score(score, sc_ok.min()) and plausible[h]
    _, score_none, *_, n_all = ransac_batch(*args, 0.0, 0.0)  # nothing moves that slowly
    assert n_all == int(np.count_nonzero(ok & (np.linalg.norm(ws, axis=1) > 0)))
    assert not np.isfinite(score_none) or n_all < int(np.count_nonzero(ok))


def test_solvers_without_a_fused_path():
    assert fused_kernels("r6p") is None  # a variable number of roots per sample
    with pytest.raises(ValueError):
        fused_kernels("nope")


@pytest.mark.parametrize("solver", ["r6p_1lin", "p3p"])
def test_estimator_gives_the_same_result_with_and_without_fusion(solver, monkeypatch):
    for k in range(3):
        f = make_frame(
            20 + k, 300, rs_speed=0.5 if solver != "p3p" else 0.0, noise_px=1.0, outlier_ratio=0.3
        )
        a = estimate_rs_pose(f.points_px, f.X, CAM, solver)
        with monkeypatch.context() as m:
            m.setattr(hypotheses_module, "fused_kernels", lambda name: None)
            b = estimate_rs_pose(f.points_px, f.X, CAM, solver)
        assert a.success and b.success
        np.testing.assert_array_equal(a.model.R, b.model.R)
        np.testing.assert_array_equal(a.model.w, b.model.w)
        np.testing.assert_array_equal(a.inliers, b.inliers)
        assert a.ransac_iterations == b.ransac_iterations


def test_measured_time_scoring_is_the_refinement_residual():
    """``measured_error2`` (RANSAC's score) against ``refine.exact_errors`` (the refinement's
    residual, written separately) on a distorted camera with a bottom-to-top readout."""
    from rs_localizer.camera import CameraModel
    from rs_localizer.estimation.refine import exact_errors
    from rs_localizer.estimation.scoring import errors2, msac_evaluate

    K = np.array([[800.0, 0, 320], [0, 820, 240], [0, 0, 1]])
    cam = CameraModel.from_readout_time(
        K, 0.03, 640, 480, D=[-0.2, 0.05, 0.001, -0.001, 0.0], readout="bottom_to_top"
    )
    f = make_frame(7, 200, rs_speed=1.0, noise_px=0.5, outlier_ratio=0.2)
    x, r, r0e = cam.normalize(cam.distort(f.x))
    e_ref = exact_errors(f.R, f.C, f.w, f.t, f.X, x, r - cam.r0)
    e2 = errors2(x, f.X, r0e, cam.readout_vector, f.R, f.C, f.w, f.t, True, True)
    np.testing.assert_allclose(np.sqrt(e2), e_ref, rtol=1e-9, atol=1e-12)
    th2 = (2.0 / cam.mean_focal) ** 2
    sc, inl, n = msac_evaluate(x, f.X, r0e, cam.readout_vector, f.R, f.C, f.w, f.t, th2, True)
    assert inl.tolist() == (e_ref**2 < th2).tolist() and n == inl.sum()
    np.testing.assert_allclose(sc, np.minimum(e_ref**2, th2).sum(), rtol=1e-9)


def test_measured_time_scoring_counts_the_inliers_at_fast_motion():
    """At RS speed 1 the capture row of the first-order model misplaces points by pixels: the
    true model loses inliers under it, not at the measured times (what made RANSAC draw ~320
    instead of ~200 samples there)."""
    from rs_localizer.estimation.scoring import msac_evaluate

    lost_row, lost_measured = [], []
    for k in range(5):
        f = make_frame(40 + k, 400, rs_speed=1.0, noise_px=0.0)
        x, _r, r0e = CAM.normalize(f.points_px)
        th2 = (1.0 / CAM.mean_focal) ** 2
        for measured, lost in ((False, lost_row), (True, lost_measured)):
            _, _, n = msac_evaluate(
                x, f.X, r0e, CAM.readout_vector, f.R, f.C, f.w, f.t, th2, measured
            )
            lost.append(len(x) - n)
    assert sum(lost_measured) == 0 and sum(lost_row) > 0


@pytest.mark.parametrize("solver", ["r6p_1lin", "r6p_vCt_w", "r9p"])
def test_nonminimal_solve_equals_the_batched_solver_on_the_inliers(solver):
    """LO's one-call nonminimal step against the public batched solver on the same inliers,
    pre-rotated by the same R (NumPy), composed with R (NumPy Rodrigues)."""
    from rs_localizer.estimation.batch import nonminimal_solve
    from rs_localizer.geometry import rotation_angle_deg, rotvec_to_matrix

    f, x, X, r, _ = _frame_arrays(9)
    R = rotvec_to_matrix(np.array([0.01, -0.02, 0.015])) @ f.R
    inl = f.inlier.copy()
    kinds, n_params = fused_kernels(solver)
    mins = np.array([9 if solver == "r9p" else 6], dtype=np.int64)
    ok, Rs, Cs, ws, ts = nonminimal_solve(kinds, n_params, mins, inl, R, x, X, r, CAM.r0, 2)
    b = solver_info(solver).batch[0](
        x[inl][None], (X[inl] @ R.T)[None], r[inl][None], CAM.r0, iterations=2
    )
    assert ok[0] and b.valid[0]
    np.testing.assert_allclose(Rs[0], rotvec_to_matrix(b.v[0]) @ R, atol=1e-12)
    for a, c in ((Cs[0], b.C[0]), (ws[0], b.w[0]), (ts[0], b.t[0])):
        np.testing.assert_allclose(a, c, rtol=1e-9, atol=1e-12)
    assert rotation_angle_deg(Rs[0], f.R) < 0.5
    # too few points for the kernel: skipped and flagged, not run
    few = np.zeros(len(x), dtype=bool)
    few[: int(mins[0]) - 1] = True
    ok, *_ = nonminimal_solve(kinds, n_params, mins, few, R, x, X, r, CAM.r0, 2)
    assert not ok[0]


@pytest.mark.parametrize("solver", ["r6p_1lin", "r6p_vCt_w", "r6p_joined"])
def test_prerotated_batch_equals_the_step_by_step_kernels(solver):
    """A video tracker's batch: every sample pre-rotated by one given rotation (no P3P)."""
    from rs_localizer.estimation.batch import prerotated_batch
    from rs_localizer.geometry import rotvec_to_matrix

    (f, x, X, r, r0e), (kinds, n_params), info, rng, order = _batch_setup(6, 2, solver)
    s, th2 = info.sample_size, TH2
    R_pre = np.ascontiguousarray(rotvec_to_matrix(np.array([0.01, -0.02, 0.005])) @ f.R)
    u = rng.random((24, s))
    out = prerotated_batch(
        u,
        120,
        order,
        R_pre,
        x,
        X,
        r,
        r0e,
        CAM.readout_vector,
        CAM.r0,
        kinds,
        n_params,
        info.default_iterations or 1,
        th2,
        np.inf,
        24,
        0,
    )
    h, score, Rs, Cs, ws, ts = out[:6]
    samples = order[draw_samples(u, 120)]
    R_p = np.ascontiguousarray(np.broadcast_to(R_pre, (len(samples), 3, 3)))
    xs, Xs, rs = gather_prerotated(samples, R_p, x, X, r)
    bs = [fn(xs, Xs, rs, CAM.r0, iterations=info.default_iterations or 1) for fn in info.batch]
    Rs2 = np.concatenate([compose_rotvec(np.ascontiguousarray(q.v), R_p) for q in bs])
    ok = np.concatenate([q.valid for q in bs])
    np.testing.assert_array_equal(Rs[ok], Rs2[ok])
    for a, name in ((Cs, "C"), (ws, "w"), (ts, "t")):
        np.testing.assert_array_equal(a[ok], np.concatenate([getattr(q, name) for q in bs])[ok])
    sc, _ = msac_scores(
        x,
        X,
        r0e,
        CAM.readout_vector,
        Rs2,
        np.ascontiguousarray(np.concatenate([q.C for q in bs])),
        np.ascontiguousarray(np.concatenate([q.w for q in bs])),
        np.ascontiguousarray(np.concatenate([q.t for q in bs])),
        th2,
        ok,
        np.inf,
        True,
        24,
        0,
    )
    assert h == int(np.argmin(sc)) and _same_score(score, sc.min())
    from rs_localizer.geometry import rotation_angle_deg

    assert rotation_angle_deg(Rs[h], f.R) < 1.0  # near a good pre-rotation: a good pose
