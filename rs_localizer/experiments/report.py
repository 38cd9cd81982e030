"""Claims, plots and the markdown report of the paper's synthetic evaluation (from the results
of :mod:`.protocol`)."""

from __future__ import annotations

import os

import numpy as np

from .protocol import (
    ALL_SOLVERS,
    ESTIMATOR_METHODS,
    EXPERIMENTS,
    ITERATIVE,
    METRIC_LABEL,
    METRICS,
    NAME,
    PAPER_US,
    STYLE,
    save_summary,
)

__all__ = ["claims", "plot_all", "write_outputs", "write_report"]


# ------------------------------------------------------------------------------------- claims
def _ratio(a, b):
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.asarray(a, dtype=float) / np.asarray(b, dtype=float)


def _fmt(v, nd=3):
    if v is None or (isinstance(v, float) and np.isnan(v)):
        return "-"
    if not np.isfinite(v):
        return "fail"
    if v == 0:
        return "0"
    a = abs(v)
    if a >= 100:
        return f"{v:.0f}"
    if a >= 1e-3:
        return f"{v:.{nd}g}"
    return f"{v:.2e}"


def claims(res: dict) -> list[dict]:
    """Paper claims next to our numbers. Each dict: exp, paper (claim), ours (numbers),
    verdict (``agrees`` / ``partly`` / ``differs``), criterion (how the verdict is decided)."""
    out = []

    def add(exp, paper, ours, ok, criterion, partly=False):
        out.append(
            dict(
                exp=exp,
                paper=paper,
                ours=ours,
                criterion=criterion,
                verdict="agrees" if ok else ("partly" if partly else "differs"),
            )
        )

    if "exp1" in res:
        m, x = res["exp1"]["medians"], res["exp1"]["x"]
        r = _ratio(m["p3p"][-1, :2], m["r6p"][-1, :2])
        add(
            "1 (Fig. 2)",
            "R6P is much better than P3P (RS model).",
            f"at speed {x[-1]:g}: P3P/R6P median error = {r[0]:.1f}x (rotation), "
            f"{r[1]:.1f}x (centre)",
            bool((r >= 3).all()),
            "ratio >= 3 at the highest speed",
        )
        d = np.abs(_ratio(m["r6p_1lin"][:, :2], m["r6p"][:, :2]) - 1)
        add(
            "1 (Fig. 2)",
            "R6P_{v,C,w,t}^{[v]x} gives almost identical results to R6P.",
            "largest relative difference of the medians over all speeds: "
            f"{100 * d[:, 0].max():.1f}% (rotation), {100 * d[:, 1].max():.1f}% (centre)",
            bool(d.max() <= 0.1),
            "within 10% at every speed",
        )
        r = _ratio(m["r9p"][:, :2], m["r6p"][:, :2])
        add(
            "1 (Fig. 2)",
            "R9P gives the best camera pose (slightly better than R6P).",
            "R9P/R6P median ratio per speed: rotation "
            + ", ".join(f"{v:.2f}" for v in r[:, 0])
            + "; centre "
            + ", ".join(f"{v:.2f}" for v in r[:, 1]),
            bool((r <= 1).all()),
            "ratio <= 1 at every speed",
            partly=bool((r <= 1).mean() >= 0.5),
        )
        if "exp1_noisy" in res:
            mn = res["exp1_noisy"]["medians"]
            rn = _ratio(mn["r9p"][:, :2], mn["r6p"][:, :2])
            add(
                "1 (Fig. 2), 1 px noise",
                "(same claim, our variant with 1 px noise)",
                "R9P/R6P median ratio per speed: rotation "
                + ", ".join(f"{v:.2f}" for v in rn[:, 0]),
                bool((rn <= 1).all()),
                "ratio <= 1 at every speed",
                partly=bool((rn <= 1).mean() >= 0.5),
            )
        alt = ["r6p_vC_wt", "r6p_vCt_w", "r6p_vCt_wt"]
        ra = np.array([_ratio(m[a][:, 0], m["p3p"][:, 0]) for a in alt])
        rr = np.array([_ratio(m[a][:, 0], m["r6p"][:, 0]) for a in alt])
        noisy, worse = "", 0.0
        if "exp1_noisy" in res:
            mn = res["exp1_noisy"]["medians"]
            rn = np.array([_ratio(mn[a][:, 0], mn["p3p"][:, 0]) for a in alt])
            worse = float((rn > 1).mean())
            noisy = (
                f". With {res['exp1_noisy']['noise_px']:g} px noise, / P3P's: "
                + "; ".join(
                    f"{NAME[a]} {rn[j].min():.2f}-{rn[j].max():.2f}" for j, a in enumerate(alt)
                )
                + f" (worse than P3P in {100 * worse:.0f}% of the (solver, speed) pairs)"
            )
        add(
            "1 (Fig. 2)",
            "The other 6-point iterative solvers (5 iterations) perform very poorly, "
            "often worse than P3P.",
            "noise-free, rotation median / P3P's: "
            + "; ".join(f"{NAME[a]} {ra[j].min():.2f}-{ra[j].max():.2f}" for j, a in enumerate(alt))
            + f"; / R6P's: {rr.min():.1f}-{rr.max():.1f}x"
            + noisy,
            bool((rr >= 2).all() and ((ra > 1).mean() >= 0.25 or worse >= 0.25)),
            "at least 2x worse than R6P everywhere, and worse than P3P in >= 25% of the cases "
            "at one of the noise levels ('often')",
            partly=bool((rr >= 2).all()),
        )
    if "exp2_noise" in res:
        m, x = res["exp2_noise"]["medians"], res["exp2_noise"]["x"]
        r1 = _ratio(m["r6p_1lin"][:, 0], m["r6p"][:, 0])
        r9 = _ratio(m["r9p"][:, 0], m["r6p"][:, 0])
        add(
            "2 (Fig. 3 right)",
            "The new solvers have approximately the same noise sensitivity as R6P.",
            f"median rotation error / R6P's at noise {x[1]:g}..{x[-1]:g} px: "
            f"R6P_{{v,C,w,t}}^{{[v]x}} {np.nanmin(r1[1:]):.2f}-{np.nanmax(r1[1:]):.2f}, "
            f"R9P {np.nanmin(r9[1:]):.2f}-{np.nanmax(r9[1:]):.2f}",
            bool((np.abs(r1[1:] - 1) <= 0.1).all() and (r9[1:] <= 1.25).all()),
            "R6P_{v,C,w,t}^{[v]x} within 10%, R9P within 25% of R6P at every noise > 0",
            partly=bool((np.abs(r1[1:] - 1) <= 0.1).all()),
        )
    if "exp2_translation" in res:
        m, x = res["exp2_translation"]["medians"], res["exp2_translation"]["x"]
        best_ref = np.minimum(m["r6p"][:, :2], m["r6p_1lin"][:, :2])
        rw = _ratio(m["r6p_vCt_w"][:, :2], best_ref)
        rwt = _ratio(m["r6p_vCt_wt"][:, :2], best_ref)
        add(
            "2 (Fig. 3 left)",
            "Pure translation, 1 px noise: R6P_{v,C,t}^{w} and "
            "R6P_{v,C,t}^{w,t} outperform R6P and R6P_{v,C,w,t}^{[v]x}.",
            f"median / min(R6P, R6P_{{v,C,w,t}}^{{[v]x}}) over speeds: R6P_{{v,C,t}}^{{w}} "
            f"{rw.min():.2f}-{rw.max():.2f}, R6P_{{v,C,t}}^{{w,t}} {rwt.min():.2f}-{rwt.max():.2f}"
            " (rotation and centre)",
            bool((rw < 1).all() and (rwt < 1).all()),
            "ratio < 1 at every speed",
        )
        rj = _ratio(m["r6p_joined"][:, :2], m["r6p"][:, :2])
        mg = res.get("exp2_noise", {}).get("medians")
        gen = ""
        ok_gen = True
        if mg is not None:
            rg = _ratio(mg["r6p_joined"][:, 0], mg["r6p"][:, 0])
            gen = f"; general motion (Exp. 2 noise): joined/R6P {rg.min():.2f}-{rg.max():.2f}"
            ok_gen = bool((rg <= 1.1).all())
        add(
            "2 (Fig. 3 left)",
            "The joined solver (R6P_{v,C,t}^{w} + R6P_{v,C,w,t}^{[v]x}) performs better than R6P.",
            f"pure translation: joined/R6P median {rj.min():.2f}-{rj.max():.2f}{gen}",
            bool((rj < 1).all() and ok_gen),
            "better than R6P under translation and within 10% of it in general motion",
        )
    if "exp3_iterations" in res:
        e3 = res["exp3_iterations"]
        m, its = e3["medians"], e3["iterations"]
        lo, hi = min(its), max(its)
        alt = ["r6p_vC_wt", "r6p_vCt_w", "r6p_vCt_wt"]
        imp = np.array([_ratio(m[f"{a}@{hi}"][:, 0], m[f"{a}@5"][:, 0]) for a in alt])
        far = np.array([_ratio(m[f"{a}@{hi}"][:, 0], m["r6p"][:, 0]) for a in alt])
        add(
            "3 (Fig. 4 left)",
            f"{hi} instead of 5 iterations improve the alternating solvers, "
            "but they stay far below R6P, R6P_{v,C,w,t}^{[v]x} and R9P.",
            f"median rotation error {hi} it. / 5 it.: {np.nanmin(imp):.2f}-{np.nanmax(imp):.2f};"
            f" {hi} it. / R6P: {np.nanmin(far):.1f}-{np.nanmax(far):.1f}x",
            bool((imp <= 1.0).all() and (far >= 2).all()),
            f"{hi} it. never worse than 5 it., and still >= 2x R6P's error",
            partly=bool((far >= 2).all()),
        )
        r1 = _ratio(m[f"r6p_1lin@{lo}"][:, :2], m["r6p"][:, :2])
        add(
            "3 (Fig. 4 left)",
            "R6P_{v,C,w,t}^{[v]x} performs as well as R6P even with a single iteration.",
            f"1-iteration median / R6P's: rotation {r1[:, 0].min():.3f}-{r1[:, 0].max():.3f}, "
            f"centre {r1[:, 1].min():.3f}-{r1[:, 1].max():.3f}",
            bool((np.abs(r1 - 1) <= 0.1).all()),
            "within 10% at every speed",
        )
    if "exp3_algebraic" in res:
        a3 = res["exp3_algebraic"]
        cm, nc, n, sp = a3["converged_mean"], a3["not_converged"], len(a3["x"]), a3["speeds"]
        means = {v: float(np.mean(cm[v])) for v in ITERATIVE}
        viable = ["r6p_1lin", "r6p_vCt_w", "r6p_vCt_wt"]
        add(
            "3 (Fig. 4 right)",
            "The algebraic error of the three viable solvers converges within 8 steps on average.",
            f"mean iterations until e_k <= e_{n} + 1e-6 e_1 (still decreasing at {n} counts as "
            f"{n}) at speeds "
            + "/".join(f"{v:g}" for v in sp)
            + ": "
            + "; ".join(
                f"{NAME[v]} "
                + ", ".join(f"{c:.1f}" for c in cm[v])
                + f" (still decreasing at {n}: {100 * np.mean(nc[v]):.0f}%)"
                for v in ITERATIVE
            ),
            bool(max(means[v] for v in viable) <= 8),
            "mean <= 8 for R6P_{v,C,w,t}^{[v]x}, R6P_{v,C,t}^{w}, R6P_{v,C,t}^{w,t} (our reading "
            "of 'three viable')",
            partly=bool(means["r6p_1lin"] <= 12),
        )
    if "exp4" in res:
        m, x = res["exp4"]["medians"], np.array(res["exp4"]["x"])

        def crossing(j):
            worse = m["r6p"][:, j] > m["p3p"][:, j]
            return float(x[np.argmax(worse)]) if worse.any() else None

        cr, cc = crossing(0), crossing(1)
        d1 = np.abs(_ratio(m["r6p_1lin"][:, :2], m["r6p"][:, :2]) - 1)
        r9 = _ratio(m["r9p"][:, :2], m["r6p"][:, :2])
        add(
            "4 (Fig. 5)",
            "R6P beats P3P up to ~6 deg from R = I for the camera centre and ~15 deg "
            "for the orientation (Albl et al.); the ACCV paper reports similar behaviour.",
            f"first angle where R6P's median exceeds P3P's: orientation "
            f"{f'none up to {x[-1]:g}' if cr is None else f'{cr:g} deg'}, centre "
            f"{f'none up to {x[-1]:g}' if cc is None else f'{cc:g} deg'}",
            bool(cr is not None and cc is not None and cc <= 10 and cr <= 20),
            "crossings within ~5 deg of Albl et al.'s (centre <= 10, orientation <= 20 deg); "
            "'partly' if R6P loses to P3P only further out",
            partly=bool(cr is not None or cc is not None),
        )
        add(
            "4 (Fig. 5)",
            "R6P_{v,C,w,t}^{[v]x} gives results identical to R6P away from R = I.",
            f"largest relative difference of the medians: {100 * d1[:, 0].max():.1f}% (rotation), "
            f"{100 * d1[:, 1].max():.1f}% (centre)",
            bool(d1.max() <= 0.1),
            "within 10%",
        )
        add(
            "4 (Fig. 5)",
            "R9P is comparable, slightly better in orientation.",
            "R9P/R6P median per angle: rotation "
            + ", ".join(f"{v:.2f}" for v in r9[:, 0])
            + "; centre "
            + ", ".join(f"{v:.2f}" for v in r9[:, 1]),
            bool((r9[:, 0] <= 1.05).mean() >= 0.5 and (r9 <= 2).all()),
            "rotation ratio <= 1.05 at >= half the angles, never worse than 2x",
            partly=bool((r9 <= 2).all()),
        )
    if "exp5" in res:
        m, x = res["exp5"]["medians"], res["exp5"]["x"]
        r1 = _ratio(m["r6p_1lin@1"][:, :2], m["r6p"][:, :2])
        r9 = _ratio(m["r9p"][:, :2], m["r6p"][:, :2])
        noisy, ok_noisy = "", True
        if "exp5_noisy" in res:
            mn = res["exp5_noisy"]["medians"]
            q1 = _ratio(mn["r6p_1lin@1"][:, :2], mn["r6p"][:, :2])
            q9 = _ratio(mn["r9p"][:, :2], mn["r6p"][:, :2])
            noisy = (
                f". With {res['exp5_noisy']['noise_px']:g} px noise: R6P_{{v,C,w,t}}^{{[v]x}}"
                f" (1 it.) {q1.min():.2f}-{q1.max():.2f}, R9P {q9.min():.2f}-{q9.max():.2f}"
            )
            ok_noisy = bool((q1 <= 1.1).all())
        add(
            "5 (Fig. 6)",
            "With P3P initialization R6P_{v,C,w,t}^{[v]x} after a single iteration "
            "is at least as good as R6P; R9P comparable or better.",
            f"noise-free, median / R6P's over speeds: R6P_{{v,C,w,t}}^{{[v]x}} (1 it.) rotation "
            f"{r1[:, 0].min():.2f}-{r1[:, 0].max():.2f}, centre {r1[:, 1].min():.2f}-"
            f"{r1[:, 1].max():.2f}; R9P rotation {r9[:, 0].min():.2f}-{r9[:, 0].max():.2f}, "
            f"centre {r9[:, 1].min():.2f}-{r9[:, 1].max():.2f}" + noisy,
            bool((r1 <= 1.1).all() and (r9 <= 1.5).all() and ok_noisy),
            "R6P_{v,C,w,t}^{[v]x} (1 it.) <= 1.1x and R9P <= 1.5x R6P's median at every speed "
            "(both noise levels for the former)",
            partly=bool(ok_noisy or (r1 <= 1.1).mean() >= 0.5),
        )
        alt = ["r6p_vC_wt@50", "r6p_vCt_w@50", "r6p_vCt_wt@50"]
        rp = np.array([_ratio(m[a][:, 0], m["p3p"][:, 0]) for a in alt])
        rr = np.array([_ratio(m[a][:, 0], m["r6p"][:, 0]) for a in alt])
        add(
            "5 (Fig. 6)",
            "With 50 iterations the alternating solvers beat P3P but stay worse than R6P.",
            f"rotation median / P3P's: {rp.min():.2f}-{rp.max():.2f}; / R6P's: "
            f"{rr.min():.1f}-{rr.max():.1f}x",
            bool((rp < 1).all() and (rr > 1).all()),
            "below P3P and above R6P at every speed",
            partly=bool((rp < 1).mean() >= 0.5),
        )
    if "exp6" in res:
        rows = {r["solver"]: r for r in res["exp6"]["rows"]}
        r6 = rows["r6p"]["us_call"]
        lin = rows["r6p_1lin"]
        li, l5 = lin["us_per_iteration"], lin["us_call"]
        b1, b5 = lin["us_batched_1_iteration"], lin["us_batched"]
        b9 = rows["r9p"]["us_batched"]
        alt = [
            rows[a]["us_batched_per_iteration"] for a in ("r6p_vC_wt", "r6p_vCt_w", "r6p_vCt_wt")
        ]
        bi = lin["us_batched_per_iteration"]
        add(
            "6 (Table 1)",
            "One iteration of R6P_{v,C,w,t}^{[v]x} is two orders of magnitude "
            "faster than R6P (paper: 1700 vs 10 us, 170x; 5 iterations 34x).",
            f"R6P {r6:.0f} us per call. R6P_{{v,C,w,t}}^{{[v]x}}: {li:.2f} us per iteration "
            f"({r6 / li:.0f}x), one iteration batched {b1:.2f} us ({r6 / b1:.0f}x); 5 iterations "
            f"{l5:.1f} us per Python call ({r6 / l5:.1f}x, call overhead dominates) or "
            f"{b5:.1f} us batched ({r6 / b5:.0f}x)",
            bool(r6 / li >= 50 and r6 / b1 >= 50),
            "per-iteration speed-up >= 50x",
            partly=bool(r6 / b5 >= 10),
        )
        add(
            "6 (Table 1)",
            "R9P costs about 2 iterations of R6P_{v,C,w,t}^{[v]x} (20 vs 10 us); "
            "an alternating iteration ~3x one R6P_{v,C,w,t}^{[v]x} iteration (24-30 us).",
            f"batched: R9P {b9:.2f} us = {b9 / b1:.1f} one-iteration R6P_{{v,C,w,t}}^{{[v]x}} "
            f"calls ({b1:.2f} us); alternating {min(alt):.2f}-{max(alt):.2f} us per iteration = "
            f"{min(alt) / bi:.1f}-{max(alt) / bi:.1f}x R6P_{{v,C,w,t}}^{{[v]x}}'s {bi:.2f} us",
            bool(b9 / b1 <= 4 and min(alt) / bi >= 1 and max(alt) / bi <= 6),
            "R9P <= 4 one-iteration calls; alternating 1-6x per iteration (batched kernels, "
            "no Python overhead)",
            partly=bool(b9 / b1 <= 4 or max(alt) / bi <= 6),
        )
        nr = res.get("exp1", {}).get("r6p_roots_max", "-")
        add(
            "6 (Table 1)",
            "Maximum number of solutions: P3P 4, R6P 20, linear solvers 1.",
            f"same by construction; most real R6P roots seen in one Exp. 1 trial: {nr}",
            True,
            "structural",
        )
    if "exp7" in res:
        m, x = res["exp7"]["medians"], res["exp7"]["x"]
        ours = _ratio(m["r6p_1lin"][-1, :2], m["poselib"][-1, :2])
        add(
            "7 (beyond)",
            "(not in the paper) the RS estimator beats global-shutter estimators "
            "under fast motion and matches them without motion.",
            f"at speed {x[-1]:g}: R6P_{{v,C,w,t}}^{{[v]x}} estimator / PoseLib median error "
            f"{ours[0]:.3f} (rotation), {ours[1]:.3f} (centre); at speed {x[0]:g}: "
            f"{_fmt(m['r6p_1lin'][0, 0])} vs {_fmt(m['poselib'][0, 0])} deg",
            bool((ours <= 1 / 3).all() and m["r6p_1lin"][0, 0] <= 1.5 * m["poselib"][0, 0]),
            "at least 3x better at the highest speed, within 1.5x without motion",
        )
        fr = res["exp7"]["failures"]
        rs = [k for k in fr if k not in ("p3p", "poselib", "opencv")]
        worst = max(rs, key=lambda k: fr[k].max())
        add(
            "7 (beyond)",
            "(ours) the RS estimators return a pose on every frame (30% outliers).",
            "failure rate per speed: "
            + "; ".join(
                f"{NAME[k]} " + "/".join(f"{100 * v:.0f}%" for v in fr[k])
                for k in rs
                if fr[k].max() > 0
            )
            + f" (others 0%); worst: {NAME[worst]}",
            bool(max(fr[k].max() for k in rs) <= 0.02),
            "<= 2% failures for every RS solver",
            partly=bool(fr["r6p_1lin"].max() <= 0.02),
        )
    return out


# ----------------------------------------------------------------------------------- plotting
def _figure(ncols, nrows=1, w=5.0, h=3.6):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w * ncols, h * nrows))
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False)
    return fig, axes.ravel()


def _style(spec):
    name, _, its = spec.partition("@")
    label, color = STYLE[name]
    return (label + (f", {its} it." if its else "")), color


def _plot_lines(ax, x, meds, specs, j, ylabel, title=None, dashes=None):
    for s in specs:
        if s not in meds:
            continue
        label, color = _style(s)
        y = np.where(np.isfinite(meds[s][:, j]) & (meds[s][:, j] > 0), meds[s][:, j], np.nan)
        ls = (dashes or {}).get(s, "-")
        wide = s == "r6p"  # drawn wide and underneath: R6P_{v,C,w,t}^{[v]x} often covers it
        ax.plot(
            x,
            y,
            ls,
            color=color,
            marker="o",
            ms=6 if wide else 3,
            lw=5 if wide else 1.5,
            alpha=0.6 if wide else 1.0,
            zorder=1 if wide else 2,
            label=label,
        )
    ax.set_yscale("log")
    ax.set_ylabel(ylabel)
    ax.grid(True, which="both", alpha=0.3)
    if title:
        ax.set_title(title, fontsize=10)


def _save(fig, path, dpi):
    """Save as a small PNG: 8-bit palette (the plots have few colours), optimized."""
    import io

    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, dpi=dpi, format="png")
    try:
        from PIL import Image

        buf.seek(0)
        img = Image.open(buf).convert("RGB").quantize(colors=128, method=Image.Quantize.MEDIANCUT)
        img.save(path, optimize=True)
    except ImportError:  # pragma: no cover - Pillow is a matplotlib dependency
        with open(path, "wb") as fh:
            fh.write(buf.getvalue())


def plot_all(res: dict, out: str, dpi: int = 80) -> list[str]:
    """One PNG per experiment into ``out``; returns the file names."""
    files = []

    def grid(key, fname, specs, title, metrics=METRICS, dashes=None):
        r = res[key]
        fig, axes = _figure(2, (len(metrics) + 1) // 2)
        for ax, mname in zip(axes, metrics, strict=False):
            j = METRICS.index(mname)
            _plot_lines(ax, r["x"], r["medians"], specs, j, METRIC_LABEL[mname], dashes=dashes)
            ax.set_xlabel(r["xlabel"])
        axes[0].legend(fontsize=7)
        fig.suptitle(title, fontsize=11)
        _save(fig, os.path.join(out, fname), dpi)
        files.append(fname)

    if "exp1" in res:
        grid(
            "exp1",
            "exp1_motion.png",
            ALL_SOLVERS,
            "Exp. 1 (Fig. 2): increasing motion, R = I, no noise, median of "
            f"{res['exp1']['trials']} trials (P3P velocity = |true velocity|)",
        )
    if "exp1_noisy" in res:
        grid(
            "exp1_noisy",
            "exp1_motion_noise1px.png",
            ALL_SOLVERS,
            f"Exp. 1 with {res['exp1_noisy']['noise_px']:g} px noise",
        )
    if "exp2_noise" in res and "exp2_translation" in res:
        fig, axes = _figure(2, 2)
        for row, key in enumerate(("exp2_translation", "exp2_noise")):
            r = res[key]
            for c, j in enumerate((0, 1)):
                ax = axes[2 * row + c]
                _plot_lines(
                    ax,
                    r["x"],
                    r["medians"],
                    ALL_SOLVERS + ("r6p_joined",),
                    j,
                    METRIC_LABEL[METRICS[j]],
                    title=(
                        "pure translation, 1 px noise"
                        if row == 0
                        else f"general motion (speed {r['speed']:g}), increasing noise"
                    ),
                )
                ax.set_xlabel(r["xlabel"])
        axes[0].legend(fontsize=7)
        fig.suptitle("Exp. 2 (Fig. 3)", fontsize=11)
        _save(fig, os.path.join(out, "exp2_noise_translation.png"), dpi)
        files.append("exp2_noise_translation.png")
    if "exp3_iterations" in res:
        r = res["exp3_iterations"]
        its = r["iterations"]
        specs = ["r6p", "r9p"] + [f"{n}@{k}" for n in ITERATIVE for k in its]
        ls = {1: ":", 5: "--"}
        dashes = {f"{n}@{k}": ls.get(k, "-") for n in ITERATIVE for k in its}
        fig, axes = _figure(3, 1)
        for c, j in enumerate((0, 1)):
            _plot_lines(
                axes[c], r["x"], r["medians"], specs, j, METRIC_LABEL[METRICS[j]], dashes=dashes
            )
            axes[c].set_xlabel(r["xlabel"])
        axes[0].legend(fontsize=6, ncol=2)
        if "exp3_algebraic" in res:
            a = res["exp3_algebraic"]
            ax = axes[2]
            sls = [":", "-", "--", "-."]
            for n in ITERATIVE:
                label, color = _style(n)
                for j in range(len(a["speeds"])):
                    med = a["median_curves"][n][j]
                    ax.plot(
                        a["x"],
                        np.maximum(med, 1e-18),
                        sls[j % 4],
                        color=color,
                        lw=1.3,
                        label=label if j == 0 else None,
                    )
            for j, sp in enumerate(a["speeds"]):
                ax.plot([], [], sls[j % 4], color="gray", label=f"speed {sp:g}")
            ax.set_yscale("log")
            ax.set_xlabel("iteration")
            ax.set_ylabel("RMS algebraic error of eq. 5 (median)")
            ax.set_title("algebraic error per iteration, R = I", fontsize=10)
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=6)
        fig.suptitle(
            "Exp. 3 (Fig. 4): 1 (dotted), 5 (dashed), 50 (solid) iterations; "
            "algebraic error per iteration",
            fontsize=11,
        )
        _save(fig, os.path.join(out, "exp3_convergence.png"), dpi)
        files.append("exp3_convergence.png")
    if "exp4" in res:
        grid(
            "exp4",
            "exp4_orientation.png",
            ALL_SOLVERS,
            f"Exp. 4 (Fig. 5): orientation away from R = I, speed {res['exp4']['speed']:g}",
            metrics=("rot", "pos"),
        )
    if "exp5" in res:
        grid(
            "exp5",
            "exp5_p3p_init.png",
            ["p3p", "r6p", "r6p_1lin@1", "r6p_vC_wt@50", "r6p_vCt_w@50", "r6p_vCt_wt@50", "r9p"],
            "Exp. 5 (Fig. 6): P3P pre-rotation, random orientation, no noise",
        )
    if "exp5_noisy" in res:
        grid(
            "exp5_noisy",
            "exp5_p3p_init_noise1px.png",
            ["p3p", "r6p", "r6p_1lin@1", "r6p_vC_wt@50", "r6p_vCt_w@50", "r6p_vCt_wt@50", "r9p"],
            f"Exp. 5 with {res['exp5_noisy']['noise_px']:g} px noise",
            metrics=("rot", "pos"),
        )
    if "exp6" in res:
        rows = [r for r in res["exp6"]["rows"] if r["solver"] in PAPER_US]
        fig, axes = _figure(1, 1, w=7.0, h=3.6)
        ax = axes[0]
        names = [r["solver"] for r in rows]
        ours = [r.get("us_per_iteration", r["us_call"]) for r in rows]
        paper = [PAPER_US[n] for n in names]
        xs = np.arange(len(names))
        ax.bar(xs - 0.2, paper, 0.4, color="#cccccc", label="paper (C++, 2.5 GHz i7)")
        ax.bar(xs + 0.2, ours, 0.4, color=[STYLE[n][1] for n in names], label="ours")
        ax.set_xticks(xs, [NAME[n] for n in names], rotation=20, fontsize=7)
        ax.set_yscale("log")
        ax.set_ylabel("us per iteration (per call if not iterative)")
        ax.legend(fontsize=8)
        ax.set_title("Exp. 6 (Table 1): time per iteration", fontsize=10)
        _save(fig, os.path.join(out, "exp6_timing.png"), dpi)
        files.append("exp6_timing.png")
    if "exp7" in res:
        grid(
            "exp7",
            "exp7_estimator.png",
            ESTIMATOR_METHODS,
            f"Exp. 7: robust estimators, {res['exp7']['n_points']} points, "
            f"{100 * res['exp7']['outlier_ratio']:.0f}% outliers, "
            f"{res['exp7']['noise_px']:g} px noise, random orientation",
        )
    return files


# ------------------------------------------------------------------------------------- report
def _table(r, specs, j, xname, header_fmt="{:g}"):
    lines = [
        "| "
        + xname
        + " | "
        + " | ".join(
            NAME[s.split("@")[0]] + (f" ({s.split('@')[1]} it.)" if "@" in s else "") for s in specs
        )
        + " |",
        "|" + "---|" * (len(specs) + 1),
    ]
    for i, xv in enumerate(r["x"]):
        cells = []
        for s in specs:
            v = r["medians"][s][i, j]
            fr = r["failures"][s][i]
            cells.append(_fmt(v) + (f" ({100 * fr:.1f}% fail)" if fr > 0 else ""))
        lines.append(f"| {header_fmt.format(xv)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_report(res: dict, out: str, files: list[str] | None = None) -> str:
    """Write ``report.md`` from a summary (see :func:`summarize`); returns its path."""
    L = []
    add = L.append
    meta = res.get("_meta", {})
    g = lambda key, field, default=None: res.get(key, {}).get(field, default)  # noqa: E731
    add("# Reproduction of the synthetic evaluation of Kukelova et al. (ACCV 2018)\n")
    add(
        "Generated by `python -m rs_localizer.experiments` "
        "(= `rs-localizer experiments`); `results.json` holds every number below. Runs:\n"
    )
    add("| experiment | mode | trials per setting | seed | seconds | date |")
    add("|---|---|---|---|---|---|")
    for name in EXPERIMENTS:
        m = meta.get(name)
        if m:
            add(
                f"| {name} | {'quick' if m['quick'] else 'full'} | {m['trials']} | {m['seed']} | "
                f"{m['seconds']:.0f} | {m['date']} |"
            )
    add("")
    add("## Protocol\n")
    add(
        "* Data: `rs_localizer.sim.synthetic.make_frame` (paper sec. 4): points in [-1, 1]^3, "
        "camera 2-3 units away looking at them, K = I, 45 deg field of view, constant angular "
        "and linear velocity with the exact rotation `expm(tau [w]x)` (not the solvers' "
        "linearization). RS speed s = s * 30 deg and s * 0.3 units per frame. Pixel noise is "
        "given on a nominal 1000 x 1000 px image (focal length 1207 px). Every trial is a new "
        "frame seeded by (seed, experiment, setting, trial)."
    )
    add(
        "* Plots and tables show **medians** over the trials of each setting; a solver failure "
        "(no real root, rank loss) counts as an infinite error, and failure rates are shown in "
        "the tables when non-zero."
    )
    add(
        "* 6 points for R6P and every 6-point solver, 9 for R9P, all 20 triplets of the 6 points"
        " for P3P (the pose with the lowest global-shutter reprojection error on the 6 points is "
        "kept). Iterative solvers run at most 5 iterations unless stated (they stop earlier once "
        "converged and return their best iterate)."
    )
    root = ""
    if "exp1" in res and "r6p_oracle" in res["exp1"]["medians"]:
        m = res["exp1"]["medians"]
        d = np.abs(_ratio(m["r6p_oracle"][:, :2], m["r6p"][:, :2]) - 1)
        root = (
            f" Choosing the root closest to the ground truth instead (an oracle) changes "
            f"R6P's medians in Exp. 1 by at most {100 * np.nanmax(d):.1f}%"
            f" (mean number of real roots {g('exp1', 'r6p_roots_mean', float('nan')):.1f},"
            f" at most {g('exp1', 'r6p_roots_max', '-')})."
        )
    joined = ""
    if "exp2_translation" in res and "r6p_joined_lib" in res["exp2_translation"]["medians"]:
        m = res["exp2_translation"]["medians"]
        rj = _ratio(m["r6p_joined_lib"][:, 0], m["r6p_1lin"][:, 0])
        joined = (
            f" The library's `r6p_joined` selects on its own input points; on a minimal "
            f"sample both solvers fit the 6 points (almost) exactly, so under pure "
            f"translation its median rotation error is {rj.min():.2f}-{rj.max():.2f}x "
            f"R6P_{{v,C,w,t}}^{{[v]x}}'s, i.e. it mostly returns that solver."
        )
    add(
        "* **R6P root choice** (the paper does not state it): among the real roots, the one with "
        "the lowest RS reprojection error (eq. 5 model) on the 11 held-out points 9-19 of the "
        "same frame." + root + " The **joined solver** (sec. 4.1) likewise keeps whichever of "
        "R6P_{v,C,t}^{w} and R6P_{v,C,w,t}^{[v]x} reprojects the held-out points better." + joined
    )
    n1 = g("exp1", "noise_px", 0.0)
    add(
        f"* **Noise**: the paper gives the noise only for Fig. 3 (1 px under pure translation; "
        f"0-2 px with general motion). Exp. 1, 3, 4 and 5 use {n1:g} px (the errors are then the"
        " model error of each solver, which is what those experiments vary); Exp. 1 and 5 are "
        f"repeated with {g('exp1_noisy', 'noise_px', 1.0):g} px noise. Without motion and noise "
        "every solver is exact and R9P is degenerate (its t is undetermined), so the noise-free "
        "sweeps start at s = 0.1."
    )
    add(
        "* **Errors**: rotation = angle of R_est^T R_gt (deg); centre = distance between the "
        "estimated and true camera centres -R^T C (scene units); velocities = |w_est - w_gt| "
        "and |t_est - t_gt| of the **model velocities** w, t of eq. 5 against the generator's "
        "`frame.w`, `frame.t`, expressed per frame (deg/frame, units/frame). P3P and the "
        "global-shutter baselines estimate no velocity; their velocity error is the magnitude "
        "of the true velocity. R9P's w is recovered from R_RS (the paper does not extract it); "
        "its t is poorly determined."
    )
    add(
        "* Colours are the same in every plot (P3P red, R6P magenta (drawn wide, under "
        "R6P_{v,C,w,t}^{[v]x} green), R6P_{v,C,t}^{w} cyan, R6P_{v,C,t}^{w,t} blue, "
        "R6P_{v,C}^{w,t} orange, R9P black, joined purple).\n"
    )

    add("## Claims: paper vs. ours\n")
    quick = sorted(n for n in EXPERIMENTS if meta.get(n, {}).get("quick"))
    if quick:
        add(
            f"**Quick run** ({', '.join(quick)}: few trials per setting): these verdicts are "
            "noisy and may flip between seeds; the full run (`rs-localizer experiments` "
            "without `--quick`) is the one to compare with the paper.\n"
        )
    add("| exp | paper | ours | verdict | criterion |")
    add("|---|---|---|---|---|")
    for c in claims(res):
        add(f"| {c['exp']} | {c['paper']} | {c['ours']} | **{c['verdict']}** | {c['criterion']} |")
    add("")

    def section(key, title, specs, metrics=("rot", "pos"), png=None, xname="speed", text=""):
        if key not in res:
            return
        r = res[key]
        add(f"## {title}\n")
        if text:
            add(text + "\n")
        if png:
            add(f"![{key}]({png})\n")
        for mname in metrics:
            add(f"Median {METRIC_LABEL[mname]}:\n")
            add(_table(r, specs, METRICS.index(mname), xname) + "\n")

    section(
        "exp1",
        "Exp. 1 (Fig. 2): increasing camera motion, R = I",
        ALL_SOLVERS,
        METRICS,
        "exp1_motion.png",
    )
    section(
        "exp1_noisy",
        f"Exp. 1 with {g('exp1_noisy', 'noise_px', 1.0):g} px noise",
        ALL_SOLVERS,
        METRICS,
        "exp1_motion_noise1px.png",
    )
    section(
        "exp2_translation",
        "Exp. 2 (Fig. 3 left): pure translation, 1 px noise",
        ALL_SOLVERS + ("r6p_joined",),
        png="exp2_noise_translation.png",
    )
    section(
        "exp2_noise",
        "Exp. 2 (Fig. 3 right): increasing noise, general motion "
        f"(speed {g('exp2_noise', 'speed', 0.5):g}, R = I)",
        ALL_SOLVERS + ("r6p_joined",),
        xname="noise px",
    )
    if "exp3_iterations" in res:
        r = res["exp3_iterations"]
        specs = ["r6p", "r9p"] + [f"{n}@{k}" for n in ITERATIVE for k in r["iterations"]]
        section(
            "exp3_iterations",
            "Exp. 3 (Fig. 4): 1, 5 and 50 iterations, R = I",
            specs,
            ("rot",),
            "exp3_convergence.png",
        )
    if "exp3_algebraic" in res:
        a = res["exp3_algebraic"]
        n = len(a["x"])
        add(
            f"Algebraic error (RMS of eq. 5 on the 6 points; median over {a['trials']} trials)"
            f" per iteration, and the iteration k from which e_k <= e_{n} + 1e-6 e_1 (within a "
            f"millionth of the first error of the final value; 'still decreasing' = only at "
            f"k = {n}, counted as {n} in the mean):\n"
        )
        ks = [k for k in (1, 2, 3, 5, 8, 10, 20, 50) if k <= n]
        add(
            "| solver | speed | "
            + " | ".join(f"it. {k}" for k in ks)
            + f" | converged at: mean / median | still decreasing at {n} |"
        )
        add("|---|---|" + "---|" * (len(ks) + 2))
        for s in ITERATIVE:
            for j, sp in enumerate(a["speeds"]):
                med = a["median_curves"][s][j]
                add(
                    f"| {NAME[s]} | {sp:g} | "
                    + " | ".join(_fmt(med[k - 1]) for k in ks)
                    + f" | {a['converged_mean'][s][j]:.1f} / {a['converged_median'][s][j]:.0f} | "
                    f"{100 * a['not_converged'][s][j]:.0f}% |"
                )
        add("")
    section(
        "exp4",
        "Exp. 4 (Fig. 5): orientation away from R = I "
        f"(speed {g('exp4', 'speed', 0.5):g}: 30 s deg and 0.3 s units per frame)",
        ALL_SOLVERS,
        png="exp4_orientation.png",
        xname="angle deg",
    )
    section(
        "exp5",
        "Exp. 5 (Fig. 6): P3P pre-rotation, random orientation, increasing motion",
        ["p3p", "r6p", "r6p_1lin@1", "r6p_vC_wt@50", "r6p_vCt_w@50", "r6p_vCt_wt@50", "r9p"],
        METRICS,
        "exp5_p3p_init.png",
        text="P3P (best of the 20 triplets) first; the world points are rotated by its R, "
        "every RS solver runs on them, and its rotation is composed with P3P's. "
        "R6P_{v,C,w,t}^{[v]x} at 1 iteration, the alternating solvers at 50.",
    )
    section(
        "exp5_noisy",
        f"Exp. 5 with {g('exp5_noisy', 'noise_px', 1.0):g} px noise",
        ["p3p", "r6p", "r6p_1lin@1", "r6p_vC_wt@50", "r6p_vCt_w@50", "r6p_vCt_wt@50", "r9p"],
        ("rot", "pos"),
        "exp5_p3p_init_noise1px.png",
    )
    if "exp6" in res:
        e6 = res["exp6"]
        add("## Exp. 6 (Table 1): timings\n")
        add(
            "`rs_localizer.experiments.timing.bench_solvers("
            f"repeat={e6['repeat']}, batch={e6['batch']})`, one BLAS thread, median microseconds. "
            "Ours are Python-called numba kernels on a 2-core machine shared with other jobs "
            "(noisy); the paper's are C++/MEX on a 2.5 GHz i7. "
            "'per iteration' = (5 forced iterations - 1) / 4; 'batched' = per problem when "
            f"{e6['batch']} minimal problems are solved in one call (as RANSAC does).\n"
        )
        add("![exp6](exp6_timing.png)\n")
        add(
            "| solver | us per call | us per iteration | batched us per problem | "
            "batched us per iteration | paper us per iteration | max # solutions |"
        )
        add("|---|---|---|---|---|---|---|")
        for r in e6["rows"]:
            add(
                f"| {r['solver']} | {_fmt(r.get('us_call'))} | {_fmt(r.get('us_per_iteration'))} "
                f"| {_fmt(r.get('us_batched'))} | {_fmt(r.get('us_batched_per_iteration'))} | "
                f"{_fmt(r.get('paper_us'))} | {r.get('max_solutions') or '-'} |"
            )
        add("\n`us per call` of the iterative solvers is 5 forced iterations.\n")
    if "exp7" in res:
        e7 = res["exp7"]
        add("## Exp. 7 (beyond the paper): robust estimators on frames with outliers\n")
        add(
            f"`estimate_rs_pose` (LO-RANSAC with P3P pre-rotation, MSAC, exact-model refinement;"
            f" default options, R6P capped at {e7['r6p_iterations']} RANSAC iterations) per "
            f"solver vs PoseLib `estimate_absolute_pose` and OpenCV `solvePnPRansac` (global "
            f"shutter), {e7['trials']} frames per speed (fewer than Exp. 1-5: ~0.5 s per frame"
            f" for all methods), {e7['n_points']} correspondences, "
            f"{100 * e7['outlier_ratio']:.0f}% outliers, {e7['noise_px']:g} px noise, random "
            "orientation, 2 px threshold. A failed estimate counts as an infinite error.\n"
        )
        add("![exp7](exp7_estimator.png)\n")
        for mname in METRICS:
            add(f"Median {METRIC_LABEL[mname]}:\n")
            add(_table(e7, list(ESTIMATOR_METHODS), METRICS.index(mname), "speed") + "\n")
        add("Median milliseconds per frame:\n")
        add("| speed | " + " | ".join(NAME[m] for m in ESTIMATOR_METHODS) + " |")
        add("|---|" + "---|" * len(ESTIMATOR_METHODS))
        for i, xv in enumerate(e7["x"]):
            add(
                f"| {xv:g} | "
                + " | ".join(f"{e7['ms_median'][m][i]:.1f}" for m in ESTIMATOR_METHODS)
                + " |"
            )
        add("")
    path = os.path.join(out, "report.md")
    with open(path, "w") as fh:
        fh.write("\n".join(L) + "\n")
    return path


def write_outputs(summary: dict, out: str, dpi: int = 80) -> list[str]:
    """``results.json``, plots and ``report.md`` into ``out`` (created) from a summary.
    Returns the written file names."""
    os.makedirs(out, exist_ok=True)
    save_summary(summary, os.path.join(out, "results.json"))
    files = plot_all(summary, out, dpi)
    write_report(summary, out, files)
    return ["results.json"] + files + ["report.md"]
