"""The paper's synthetic evaluation (Kukelova et al. ACCV 2018, sec. 4): the experiments.

The claims, plots and report written from their results are in :mod:`.report`.

``python -m rs_localizer.experiments [--quick] [--out docs/experiments] [--trials N]
[--seed S]``
(also ``rs-localizer experiments``) runs every experiment with fixed seeds on data from
:mod:`rs_localizer.sim.synthetic` and writes one PNG per experiment, ``report.md`` and
``results.json`` (every number of the report). ``--only exp6`` re-runs a subset and merges it
into an existing ``results.json``; ``--render-only`` redraws plots and report from it. For
another CLI: :func:`add_arguments` fills a subparser, :func:`run` executes the parsed args.

====  ==========================================================================  ==========
exp   what                                                                        paper
====  ==========================================================================  ==========
1     increasing camera motion (0.3 units and 30 deg per frame at RS speed 1),    Fig. 2
      R = I; errors of rotation, camera centre, angular and linear velocity
2     increasing image noise (general motion); pure translation with 1 px noise   Fig. 3
      incl. the joined solver
3     convergence: 1, 5 and 50 iterations; algebraic error per iteration          Fig. 4
4     orientation away from the linearization point R = I                         Fig. 5
5     P3P pre-rotation (random orientation), increasing motion                    Fig. 6
6     timing table (reuses :func:`.timing.bench_solvers`)                         Table 1
7     the robust estimator (RANSAC + refinement) vs PoseLib / OpenCV (GS)         (beyond)
====  ==========================================================================  ==========

Protocol (paper sec. 4): each trial draws one frame with 20 correspondences. The 6-point solvers
get points 0-5, R9P points 0-8, P3P every triplet of points 0-5 (up to 4 poses each; the pose
with the lowest global-shutter reprojection error on the 6 points is kept). The paper does not
say how one of R6P's up to 20 real roots is chosen; we keep the root with the lowest RS
reprojection error (eq. 5 model) on the held-out points 9-19 of the same frame. The joined
solver (sec. 4.1) runs R6P_{v,C,t}^{w} and R6P_{v,C,w,t}^{[v]x} and keeps the lower held-out
reprojection error too (on the 6 sample points both usually fit exactly, so selecting there is
uninformative). Iterative solvers run at most 5 iterations unless stated. Errors: rotation angle
(deg) of ``R_est^T R_gt``; camera centre distance (scene units, the camera is 2-3 units from
the scene centre); ``|w_est - w_gt|`` and ``|t_est - t_gt|`` of the model velocities (per unit
of the RS coordinate, converted to per frame: deg per frame, units per frame). A solver failure
(no real root, rank loss) counts as an infinite error, so medians include failures.
Plots show the median over the trials of every setting.
"""

from __future__ import annotations

import contextlib
import itertools
import time
from dataclasses import dataclass, replace

import numpy as np

from .. import solvers as S
from ..geometry import camera_position, rotation_angle_deg
from ..sim.synthetic import FRAME_SPAN, make_frame
from ..solvers.joined import rs_reprojection_rmse
from ..solvers.registry import SOLVERS as SOLVER_TABLE
from .timing import one_thread

__all__ = [
    "EXPERIMENTS",
    "FULL",
    "QUICK",
    "STYLE",
    "Config",
    "exp1_motion",
    "exp2_noise",
    "exp2_translation",
    "exp3_algebraic",
    "exp3_iterations",
    "exp4_orientation",
    "exp5_p3p_init",
    "exp6_timing",
    "exp7_estimator",
    "load_summary",
    "run_all",
    "save_summary",
    "summarize",
]

#: correspondences per synthetic frame: 0-5 minimal sample, 0-8 R9P, 9-19 held-out
N_POINTS = 20
HELD_OUT = slice(9, N_POINTS)
METRICS = ("rot", "pos", "angvel", "linvel")
METRIC_LABEL = {
    "rot": "rotation error [deg]",
    "pos": "camera centre error [units]",
    "angvel": "angular velocity error [deg/frame]",
    "linvel": "linear velocity error [units/frame]",
}

#: one label and colour per solver, used in every plot (paper Fig. 7 colours where it has them:
#: P3P red, R6P magenta, R6P_{v,C,w,t}^{[v]x} green, R6P_{v,C,t}^{w} cyan)
STYLE = {
    "p3p": ("P3P", "#d62728"),
    "r6p": ("R6P", "#e377c2"),
    "r6p_1lin": (r"R6P$_{v,C,w,t}^{[v]_\times}$ (r6p_1lin)", "#2ca02c"),
    "r6p_vC_wt": (r"R6P$_{v,C}^{w,t}$ (r6p_vC_wt)", "#ff7f0e"),
    "r6p_vCt_w": (r"R6P$_{v,C,t}^{w}$ (r6p_vCt_w)", "#17becf"),
    "r6p_vCt_wt": (r"R6P$_{v,C,t}^{w,t}$ (r6p_vCt_wt)", "#1f77b4"),
    "r9p": ("R9P", "#000000"),
    "r6p_joined": ("joined", "#9467bd"),
    "r6p_oracle": ("R6P, root closest to ground truth", "#f7b6d2"),
    "r6p_joined_lib": ("r6p_joined (selects on the 6 points)", "#c5b0d5"),
    "poselib": ("PoseLib estimate_absolute_pose (GS)", "#7f7f7f"),
    "opencv": ("OpenCV solvePnPRansac P3P (GS)", "#8c564b"),
}
#: plain-text names for the report
NAME = {
    **{k: v.paper_name for k, v in SOLVER_TABLE.items()},
    "r6p_oracle": "R6P (oracle root)",
    "r6p_joined_lib": "r6p_joined (on the 6)",
    "poselib": "PoseLib (GS)",
    "opencv": "OpenCV (GS)",
}
#: the paper's solvers: the registry's with a :data:`STYLE` row (a solver added to the registry
#: joins these figures with its label and colour there); the joined solver is run as its own
#: spec
ALL_SOLVERS = tuple(k for k in SOLVER_TABLE if k in STYLE and k != "r6p_joined")
#: the iterative ones among them (Fig. 6, the iterations)
ITERATIVE = tuple(k for k in ALL_SOLVERS if SOLVER_TABLE[k].iterative)

#: paper Table 1 (2.5 GHz i7), microseconds per iteration, and the maximum number of solutions
PAPER_US = {k: v.paper_us for k, v in SOLVER_TABLE.items() if v.paper_us is not None}

MAX_SOLUTIONS = {k: v.max_solutions for k, v in SOLVER_TABLE.items()}

_ITER_FN = {k: SOLVER_TABLE[k].single for k in ITERATIVE}


# ------------------------------------------------------------------------------ configuration
@dataclass(frozen=True)
class Config:
    """Trial counts and settings of every experiment (``FULL`` or ``QUICK``)."""

    trials: int = 200
    noise_px: float = 0.0  # image noise of Exp. 1, 3, 4, 5 (see report)
    exp1_speeds: tuple = tuple(np.round(np.arange(1, 11) / 10, 2))
    exp1_noisy_speeds: tuple = tuple(np.round(np.arange(0, 11) / 10, 2))
    exp1_noisy_px: float = 1.0
    exp2_noise: tuple = (0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0)
    exp2_speed: float = 0.5
    exp2_trans_speeds: tuple = (0.0, 0.2, 0.4, 0.6, 0.8, 1.0)
    exp3_speeds: tuple = tuple(np.round(np.arange(1, 11) / 10, 2))
    exp3_iterations: tuple = (1, 5, 50)
    exp3_alg_iterations: int = 50
    exp3_alg_speeds: tuple = (0.2, 0.5, 1.0)
    exp4_angles: tuple = (0, 5, 10, 15, 20, 25, 30, 35, 40)
    exp4_speed: float = 0.5
    exp5_speeds: tuple = tuple(np.round(np.arange(1, 11) / 10, 2))
    exp6_repeat: int = 200
    exp6_batch: int = 1000
    exp7_trials: int = 60
    exp7_speeds: tuple = (0.0, 0.25, 0.5, 0.75, 1.0)
    exp7_points: int = 200
    exp7_outliers: float = 0.3
    exp7_noise_px: float = 1.0
    exp7_r6p_iterations: int = 100
    seed: int = 0
    quick: bool = False


FULL = Config()
QUICK = Config(
    trials=15,
    exp1_speeds=(0.25, 0.5, 0.75, 1.0),
    exp1_noisy_speeds=(0.0, 0.5, 1.0),
    exp2_noise=(0.0, 1.0, 2.0),
    exp2_trans_speeds=(0.0, 0.5, 1.0),
    exp3_speeds=(0.5, 1.0),
    exp4_angles=(0, 15, 30, 40),
    exp5_speeds=(0.25, 0.5, 1.0),
    exp6_repeat=20,
    exp6_batch=100,
    exp7_trials=3,
    exp7_speeds=(0.0, 1.0),
    quick=True,
)


# ---------------------------------------------------------------------------------- one trial
def _frame(seed, code: int, setting: int, trial: int, **kw):
    """The frame of one trial: seeded by (seed, experiment, setting, trial), so a quick run's
    frames are the first trials of the full run's for the same setting."""
    return make_frame(np.random.default_rng([seed, code, setting, trial]), N_POINTS, **kw)


def _errors(R, C, w, t, f) -> np.ndarray:
    """(rotation deg, centre distance, |dw| deg/frame, |dt| units/frame) against ground truth."""
    if R is None or not (np.isfinite(R).all() and np.isfinite(C).all()):
        return np.full(4, np.inf)
    return np.array(
        [
            rotation_angle_deg(R, f.R),
            float(np.linalg.norm(camera_position(R, C) - f.position)),
            float(np.degrees(np.linalg.norm(np.asarray(w) - f.w)) * FRAME_SPAN),
            float(np.linalg.norm(np.asarray(t) - f.t) * FRAME_SPAN),
        ]
    )


def p3p_best(x, X):
    """P3P on every triplet of the (6) points; the pose with the lowest global-shutter
    reprojection error on all of them (paper sec. 4). Returns (R, C, n_solutions_max) or
    (None, None, 0)."""
    best, best_e, nmax = None, np.inf, 0
    for tri in itertools.combinations(range(len(x)), 3):
        idx = list(tri)
        sols = S.p3p(x[idx], X[idx])
        nmax = max(nmax, len(sols))
        for p in sols:
            Pc = X @ p.R.T + p.C
            if (Pc[:, 2] <= 0).any():
                continue
            e = float(np.sum((Pc[:, :2] / Pc[:, 2:3] - x) ** 2))
            if e < best_e:
                best, best_e = p, e
    if best is None:
        return None, None, nmax
    return best.R, best.C, nmax


def _pick(sols, xh, Xh):
    """The solution with the lowest RS reprojection error (eq. 5) on the held-out points."""
    errs = [rs_reprojection_rmse(s, xh, Xh) for s in sols]
    return sols[int(np.argmin(errs))]


def _solve(f, specs, prerotate: bool = False) -> tuple[dict, dict]:
    """Run the solver specs on one frame.

    ``specs``: names from :data:`ALL_SOLVERS` or ``"r6p_joined"``, optionally ``"name@k"`` for
    k iterations of an iterative solver. ``prerotate``: P3P (best of the triplets of the 6
    points) first, the world points rotated by its R, the RS solvers run on them and their
    rotation composed with it (paper sec. 4.1, "Using P3P as initial estimate").
    Returns ({spec: (4,) errors}, info) with info the number of R6P roots and P3P solutions.
    """
    x6, X6 = f.x[:6], f.X[:6]
    xh = f.x[HELD_OUT]
    out, info = {}, {}
    roots = []
    Rp = np.eye(3)
    if prerotate or "p3p" in specs:
        R3, C3, info["p3p_solutions"] = p3p_best(x6, X6)
        if "p3p" in specs:
            out["p3p"] = _errors(R3, C3, np.zeros(3), np.zeros(3), f)
        if prerotate:
            if R3 is None:
                return {s: np.full(4, np.inf) for s in specs}, info
            Rp = R3
    Xp = f.X @ Rp.T
    X6p, Xhp = Xp[:6], Xp[HELD_OUT]

    def done(spec, sol):
        out[spec] = (
            np.full(4, np.inf) if sol is None else _errors(sol.R @ Rp, sol.C, sol.w, sol.t, f)
        )

    for spec in specs:
        if spec == "p3p":
            continue
        name, _, its = spec.partition("@")
        iterations = int(its) if its else 5
        sol = None
        try:
            if name in ("r6p", "r6p_oracle"):
                if "r6p_roots" not in info:
                    roots = S.r6p(x6, X6p)
                    info["r6p_roots"] = len(roots)
                if not roots:
                    sol = None
                elif name == "r6p":
                    sol = _pick(roots, xh, Xhp)
                else:  # diagnostic: the root closest to the ground-truth rotation
                    sol = roots[int(np.argmin([rotation_angle_deg(r.R @ Rp, f.R) for r in roots]))]
            elif name == "r6p_joined_lib":  # the library's joined solver, selecting on the 6
                sol = S.r6p_joined(x6, X6p, iterations=iterations)
            elif name in _ITER_FN:
                sol = _ITER_FN[name](x6, X6p, iterations=iterations)
            elif name == "r9p":
                sol = S.r9p(f.x[:9], Xp[:9])
            elif name == "r6p_joined":
                cands = []
                for fn in (S.r6p_vCt_w, S.r6p_1lin):
                    with contextlib.suppress(ValueError):
                        cands.append(fn(x6, X6p, iterations=iterations))
                sol = _pick(cands, xh, Xhp) if cands else None
            else:
                raise KeyError(f"unknown solver spec {spec!r}")
        except ValueError:  # DegenerateInputError: rank loss (e.g. R9P without motion)
            sol = None
        done(spec, sol)
    return out, info


def _run(
    code: int, settings: list[dict], specs, trials: int, seed: int, prerotate: bool = False
) -> dict:
    """Errors of every spec over ``trials`` frames per setting (make_frame kwargs).

    Returns dict(errors={spec: (n_settings, trials, 4)}, r6p_roots=list, p3p_solutions=list).
    """
    errors = {s: np.full((len(settings), trials, 4), np.inf) for s in specs}
    roots, p3ps = [], []
    for i, kw in enumerate(settings):
        for k in range(trials):
            f = _frame(seed, code, i, k, **kw)
            res, info = _solve(f, specs, prerotate)
            for s, e in res.items():
                errors[s][i, k] = e
            if "r6p_roots" in info:
                roots.append(info["r6p_roots"])
            if "p3p_solutions" in info:
                p3ps.append(info["p3p_solutions"])
    return dict(errors=errors, r6p_roots=roots, p3p_solutions=p3ps)


def medians(errors: dict) -> dict:
    """{spec: (n_settings, 4)} medians over the trials (failures count as +inf)."""
    return {s: np.median(e, axis=1) for s, e in errors.items()}


def failure_rate(errors: dict) -> dict:
    return {s: np.mean(~np.isfinite(e[..., 0]), axis=1) for s, e in errors.items()}


def _result(kind, x, xlabel, run, **extra):
    return dict(
        kind=kind,
        x=list(map(float, x)),
        xlabel=xlabel,
        errors=run["errors"],
        medians=medians(run["errors"]),
        failures=failure_rate(run["errors"]),
        r6p_roots=run.get("r6p_roots", []),
        p3p_solutions=run.get("p3p_solutions", []),
        **extra,
    )


# --------------------------------------------------------------------------------- experiments
def exp1_motion(
    trials: int = 200,
    speeds=FULL.exp1_speeds,
    noise_px: float = 0.0,
    seed: int = 0,
    solvers=ALL_SOLVERS,
) -> dict:
    """Exp. 1 (Fig. 2): increasing RS speed s (s * 30 deg and s * 0.3 units per frame),
    R = I, ``noise_px`` image noise; all solvers at 5 iterations.

    Returns dict(x=speeds, errors={solver: (S, trials, 4)}, medians={solver: (S, 4)}, ...)
    with the 4 metrics of :data:`METRICS`."""
    settings = [dict(rs_speed=s, noise_px=noise_px, angle_from_identity=0.0) for s in speeds]
    code = 10 if noise_px == 0 else 11
    run = _run(code, settings, list(solvers) + ["r6p_oracle"], trials, seed)
    return _result(
        "exp1", speeds, "RS speed (x 30 deg, x 0.3 units per frame)", run, noise_px=noise_px
    )


def exp2_noise(
    trials: int = 200,
    noises=FULL.exp2_noise,
    speed: float = 0.5,
    seed: int = 0,
    solvers=ALL_SOLVERS + ("r6p_joined",),
) -> dict:
    """Exp. 2, Fig. 3 right: general motion at RS speed ``speed``, R = I, noise 0 .. 2 px."""
    settings = [dict(rs_speed=speed, noise_px=n, angle_from_identity=0.0) for n in noises]
    run = _run(20, settings, list(solvers), trials, seed)
    return _result("exp2_noise", noises, "image noise sigma [px]", run, speed=speed)


def exp2_translation(
    trials: int = 200,
    speeds=FULL.exp2_trans_speeds,
    noise_px: float = 1.0,
    seed: int = 0,
    solvers=ALL_SOLVERS + ("r6p_joined",),
) -> dict:
    """Exp. 2, Fig. 3 left: purely translational motion (0.3 units per frame at speed 1),
    ``noise_px`` noise, R = I, including the joined solver."""
    settings = [
        dict(rs_speed=s, noise_px=noise_px, angle_from_identity=0.0, translation_only=True)
        for s in speeds
    ]
    run = _run(21, settings, list(solvers) + ["r6p_joined_lib"], trials, seed)
    return _result(
        "exp2_translation",
        speeds,
        "translational speed (x 0.3 units per frame)",
        run,
        noise_px=noise_px,
    )


def exp3_iterations(
    trials: int = 200,
    speeds=FULL.exp3_speeds,
    iterations=(1, 5, 50),
    noise_px: float = 0.0,
    seed: int = 0,
) -> dict:
    """Exp. 3, Fig. 4 left: every iterative solver at 1, 5 and 50 iterations (specs
    ``name@k``) plus R6P and R9P, R = I, increasing RS speed."""
    specs = ["r6p", "r9p"] + [f"{n}@{k}" for n in ITERATIVE for k in iterations]
    settings = [dict(rs_speed=s, noise_px=noise_px, angle_from_identity=0.0) for s in speeds]
    run = _run(30, settings, specs, trials, seed)
    return _result(
        "exp3_iterations",
        speeds,
        "RS speed (x 30 deg, x 0.3 units per frame)",
        run,
        iterations=list(iterations),
        noise_px=noise_px,
    )


def exp3_algebraic(
    trials: int = 200,
    n_iterations: int = 50,
    speeds=(0.2, 0.5, 1.0),
    noise_px: float = 0.0,
    seed: int = 0,
) -> dict:
    """Exp. 3, Fig. 4 right: RMS algebraic error of eq. 5 after each iteration k = 1..n, R = I.

    ``r6p_1lin`` is run one iteration at a time, each seeded with the previous ``v``
    (``v_init``), which gives the raw fixed-point sequence. The alternating solvers have no
    warm start; they are called with ``iterations=k, tol=-1`` (exactly k alternations). Each of
    their half-steps is an exact least-squares minimisation of the same algebraic residual, so
    their sequence is non-increasing anyway (the solver returns the best iterate, here the last).

    Returns dict(x=1..n, speeds, errors={solver: (n_speeds, trials, n)},
    converged_at={solver: (n_speeds, trials)}) where ``converged_at`` is the first k with
    ``e_k <= e_n + 1e-6 e_1`` (within a millionth of the initial error of the final value;
    n + 1 if that happens only at k = n: still decreasing).
    """
    speeds = list(map(float, speeds))
    errs = {n: np.full((len(speeds), trials, n_iterations), np.nan) for n in ITERATIVE}
    for j, sp in enumerate(speeds):
        for k in range(trials):
            f = _frame(seed, 31, j, k, rs_speed=sp, noise_px=noise_px, angle_from_identity=0.0)
            x6, X6 = f.x[:6], f.X[:6]
            v = np.zeros(3)
            for i in range(n_iterations):
                try:
                    s = S.r6p_1lin(x6, X6, iterations=1, v_init=v)
                except ValueError:
                    break
                errs["r6p_1lin"][j, k, i] = s.algebraic_error
                v = s.v
            for n in ITERATIVE[1:]:
                for i in range(n_iterations):
                    try:
                        errs[n][j, k, i] = _ITER_FN[n](
                            x6, X6, iterations=i + 1, tol=-1.0
                        ).algebraic_error
                    except ValueError:
                        break
    conv = {}
    for n, e in errs.items():
        thr = e[..., -1] + 1e-6 * e[..., 0]
        ok = e <= thr[..., None]
        first = np.argmax(ok, axis=-1) + 1
        # reaching the final value only at the final iteration is not convergence
        conv[n] = np.where(ok.any(axis=-1) & (first < n_iterations), first, n_iterations + 1)
    return dict(
        kind="exp3_algebraic",
        x=list(range(1, n_iterations + 1)),
        xlabel="iteration",
        speeds=speeds,
        errors=errs,
        converged_at=conv,
        noise_px=noise_px,
    )


def exp4_orientation(
    trials: int = 200,
    angles=FULL.exp4_angles,
    speed: float = 0.5,
    noise_px: float = 0.0,
    seed: int = 0,
    solvers=ALL_SOLVERS,
) -> dict:
    """Exp. 4 (Fig. 5): camera orientation exactly ``angle`` degrees from R = I (random axis),
    RS speed 0.5 (15 deg and 0.15 units per frame), no pre-rotation."""
    settings = [
        dict(rs_speed=speed, noise_px=noise_px, angle_from_identity=float(a)) for a in angles
    ]
    run = _run(40, settings, list(solvers), trials, seed)
    return _result(
        "exp4", angles, "angle of R from the identity [deg]", run, speed=speed, noise_px=noise_px
    )


def exp5_p3p_init(
    trials: int = 200, speeds=FULL.exp5_speeds, noise_px: float = 0.0, seed: int = 0
) -> dict:
    """Exp. 5 (Fig. 6): random orientation, increasing RS speed, every RS solver on world
    points pre-rotated by the best P3P pose; alternating solvers at 50 iterations,
    ``r6p_1lin`` at 1."""
    specs = ["p3p", "r6p", "r6p_1lin@1", "r6p_vC_wt@50", "r6p_vCt_w@50", "r6p_vCt_wt@50", "r9p"]
    settings = [dict(rs_speed=s, noise_px=noise_px, angle_from_identity=None) for s in speeds]
    run = _run(50 if noise_px == 0 else 51, settings, specs, trials, seed, prerotate=True)
    return _result(
        "exp5", speeds, "RS speed (x 30 deg, x 0.3 units per frame)", run, noise_px=noise_px
    )


def exp6_timing(repeat: int = 200, batch: int = 1000, seed: int = 0) -> dict:
    """Exp. 6 (Table 1): :func:`rs_localizer.experiments.timing.bench_solvers` (one BLAS thread)
    next to the paper's microseconds per iteration and the maximum number of solutions."""
    from .timing import bench_solvers

    with one_thread():
        rows = bench_solvers(repeat=repeat, batch=batch, seed=seed)
    for r in rows:
        r["paper_us"] = PAPER_US.get(r["solver"])
        r["max_solutions"] = MAX_SOLUTIONS.get(r["solver"].split()[0])
    return dict(kind="exp6", rows=rows, repeat=repeat, batch=batch)


ESTIMATOR_METHODS = (
    "p3p",
    "r6p",
    "r6p_1lin",
    "r6p_vCt_w",
    "r9p",
    "r6p_joined",
    "poselib",
    "opencv",
)


def exp7_estimator(
    trials: int = 60,
    speeds=FULL.exp7_speeds,
    n_points: int = 200,
    outlier_ratio: float = 0.3,
    noise_px: float = 1.0,
    methods=ESTIMATOR_METHODS,
    r6p_iterations: int = 100,
    seed: int = 0,
) -> dict:
    """Exp. 7 (beyond the paper): the full robust estimator :func:`estimate_rs_pose` per solver
    and the global-shutter PoseLib / OpenCV estimators (:mod:`.references`) on
    frames with outliers, random orientation, increasing RS speed.

    R6P's RANSAC is capped at ``r6p_iterations`` hypotheses (its ~20 roots per sample make it
    ~10x slower). A failed estimate (``success=False``) counts as an infinite error. The GS
    baselines have no velocities (errors = |true velocity|). Also records seconds per frame.
    The estimator runs with :func:`~rs_localizer.sim.synthetic.protocol_options` (no
    motion-plausibility bounds: the protocol's scene has no physical scale).
    """
    from ..estimation.estimate import estimate_rs_pose
    from ..sim.synthetic import paper_camera, protocol_options
    from .references import opencv_estimate, poselib_estimate

    cam = paper_camera()
    opts = protocol_options()
    errors = {m: np.full((len(speeds), trials, 4), np.inf) for m in methods}
    secs = {m: np.full((len(speeds), trials), np.nan) for m in methods}
    inliers = {m: np.zeros((len(speeds), trials)) for m in methods}
    with one_thread():
        for i, s in enumerate(speeds):
            for k in range(trials):
                f = make_frame(
                    np.random.default_rng([seed, 70, i, k]),
                    n_points,
                    rs_speed=s,
                    noise_px=noise_px,
                    outlier_ratio=outlier_ratio,
                )
                for m in methods:
                    t0 = time.perf_counter()
                    if m == "poselib":
                        R, C, n = poselib_estimate(f, cam, opts.ransac.threshold_px)
                        w = t = np.zeros(3)
                    elif m == "opencv":
                        R, C, n = opencv_estimate(f, cam, opts.ransac.threshold_px)
                        w = t = np.zeros(3)
                    else:
                        o = (
                            replace(
                                opts, ransac=replace(opts.ransac, max_iterations=r6p_iterations)
                            )
                            if m == "r6p"
                            else opts
                        )
                        e = estimate_rs_pose(f.points_px, f.X, cam, m, o)
                        R, C, w, t, n = (
                            (e.model.R, e.model.C, e.model.w, e.model.t, e.num_inliers)
                            if e.success
                            else (None, None, None, None, 0)
                        )
                    secs[m][i, k] = time.perf_counter() - t0
                    errors[m][i, k] = _errors(R, C, w, t, f)
                    inliers[m][i, k] = n
    return dict(
        kind="exp7",
        x=list(map(float, speeds)),
        xlabel="RS speed (x 30 deg, x 0.3 units per frame)",
        errors=errors,
        medians=medians(errors),
        failures=failure_rate(errors),
        ms_median={m: 1e3 * np.median(v, axis=1) for m, v in secs.items()},
        inliers=inliers,
        n_points=n_points,
        outlier_ratio=outlier_ratio,
        noise_px=noise_px,
        r6p_iterations=r6p_iterations,
    )


# ------------------------------------------------------------------------------------- driver
EXPERIMENTS = ("exp1", "exp2", "exp3", "exp4", "exp5", "exp6", "exp7")


def run_all(cfg: Config = FULL, only=EXPERIMENTS, log=print, progress: bool = False) -> dict:
    """Run the selected experiments; returns {name: result dict} plus ``_seconds`` timings.
    ``log``: called with a line per experiment done; ``progress``: a progress bar on stderr
    (the log lines are written above it)."""
    res, secs = {}, {}
    t = cfg.trials
    steps = {
        "exp1": lambda: {
            "exp1": exp1_motion(t, cfg.exp1_speeds, cfg.noise_px, cfg.seed),
            "exp1_noisy": exp1_motion(t, cfg.exp1_noisy_speeds, cfg.exp1_noisy_px, cfg.seed),
        },
        "exp2": lambda: {
            "exp2_noise": exp2_noise(t, cfg.exp2_noise, cfg.exp2_speed, cfg.seed),
            "exp2_translation": exp2_translation(t, cfg.exp2_trans_speeds, 1.0, cfg.seed),
        },
        "exp3": lambda: {
            "exp3_iterations": exp3_iterations(
                t, cfg.exp3_speeds, cfg.exp3_iterations, cfg.noise_px, cfg.seed
            ),
            "exp3_algebraic": exp3_algebraic(
                t, cfg.exp3_alg_iterations, cfg.exp3_alg_speeds, cfg.noise_px, cfg.seed
            ),
        },
        "exp4": lambda: {
            "exp4": exp4_orientation(t, cfg.exp4_angles, cfg.exp4_speed, cfg.noise_px, cfg.seed)
        },
        "exp5": lambda: {
            "exp5": exp5_p3p_init(t, cfg.exp5_speeds, cfg.noise_px, cfg.seed),
            "exp5_noisy": exp5_p3p_init(t, cfg.exp5_speeds, cfg.exp1_noisy_px, cfg.seed),
        },
        "exp6": lambda: {"exp6": exp6_timing(cfg.exp6_repeat, cfg.exp6_batch, cfg.seed)},
        "exp7": lambda: {
            "exp7": exp7_estimator(
                cfg.exp7_trials,
                cfg.exp7_speeds,
                cfg.exp7_points,
                cfg.exp7_outliers,
                cfg.exp7_noise_px,
                r6p_iterations=cfg.exp7_r6p_iterations,
                seed=cfg.seed,
            )
        },
    }
    from tqdm import tqdm

    bar = tqdm([n for n in EXPERIMENTS if n in only], unit="exp", disable=not progress)
    for name in bar:
        bar.set_description(name)
        t0 = time.perf_counter()
        res.update(steps[name]())
        secs[name] = time.perf_counter() - t0
        if log:
            line = f"{name}: {secs[name]:.1f} s"
            if progress:
                bar.write(line)
            else:
                log(line)
    res["_seconds"] = secs
    return res


# ------------------------------------------------------------------------------------ summary
_ARRAY_FIELDS = (
    "medians",
    "failures",
    "median_curves",
    "converged_mean",
    "converged_median",
    "not_converged",
    "ms_median",
    "inliers_median",
)


def summarize(res: dict) -> dict:
    """Reduce raw results (per-trial errors) to what the plots, claims and report use: medians
    and failure rates per setting, convergence statistics, timing rows. JSON-able via
    :func:`save_summary`."""
    out = {}
    for key, r in res.items():
        if key.startswith("_") or r.get("kind") == "exp6":
            out[key] = r
            continue
        s = {
            k: v
            for k, v in r.items()
            if k not in ("errors", "r6p_roots", "p3p_solutions", "converged_at", "inliers")
        }
        if r["kind"] == "exp3_algebraic":
            e, c, n = r["errors"], r["converged_at"], len(r["x"])
            s["trials"] = int(e["r6p_1lin"].shape[1])
            s["median_curves"] = {k: np.nanmedian(v, axis=1) for k, v in e.items()}
            s["converged_mean"] = {k: np.mean(np.minimum(v, n), axis=1) for k, v in c.items()}
            s["converged_median"] = {k: np.median(v, axis=1) for k, v in c.items()}
            s["not_converged"] = {k: np.mean(v > n, axis=1) for k, v in c.items()}
        else:
            s["trials"] = int(next(iter(r["errors"].values())).shape[1])
        if r.get("r6p_roots"):
            s["r6p_roots_max"] = int(max(r["r6p_roots"]))
            s["r6p_roots_mean"] = float(np.mean(r["r6p_roots"]))
        if r.get("p3p_solutions"):
            s["p3p_solutions_max"] = int(max(r["p3p_solutions"]))
        if "inliers" in r:
            s["inliers_median"] = {m: np.median(v, axis=1) for m, v in r["inliers"].items()}
        out[key] = s
    return out


def _jsonable(o):
    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, np.ndarray):
        return _jsonable(o.tolist())
    if isinstance(o, (np.floating, float)):
        return float(o)
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, np.bool_):
        return bool(o)
    return o


def save_summary(summary: dict, path: str) -> None:
    """Write a summary as JSON (``Infinity`` marks failed medians)."""
    import json

    with open(path, "w") as fh:
        json.dump(_jsonable(summary), fh, indent=1)


def load_summary(path: str) -> dict:
    """Read :func:`save_summary` output back (arrays restored)."""
    import json

    with open(path) as fh:
        summary = json.load(fh)
    for r in summary.values():
        if not isinstance(r, dict):
            continue
        for f in _ARRAY_FIELDS:
            if f in r:
                r[f] = {k: np.array(v, dtype=float) for k, v in r[f].items()}
    return summary
