"""Reproduction of the paper's synthetic evaluation (Kukelova et al. ACCV 2018, sec. 4).

``python -m rs_localizer.experiments [--quick] [--out docs/experiments] [--trials N]
[--seed S]`` (also ``rs-localizer experiments``): :mod:`.protocol` runs every experiment with
fixed seeds, :mod:`.report` writes one PNG per experiment, ``report.md`` and ``results.json``.
See :mod:`.protocol` for the experiments and the protocol.
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace

from .protocol import *  # noqa: F403  (the experiments: exp1_motion, ..., run_all)
from .protocol import EXPERIMENTS, FULL, QUICK, load_summary, run_all, summarize
from .report import claims, plot_all, write_outputs, write_report  # noqa: F401


# --------------------------------------------------------------------------------------- main
def build_parser(
    prog: str = "python -m rs_localizer.experiments",
) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=prog,
        description="Reproduce the paper's synthetic evaluation (sec. 4): PNG plots and report.md.",
    )
    add_arguments(p)
    return p


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The ``experiments`` options (for hooking into another CLI's subparser)."""
    p.add_argument(
        "--quick",
        action="store_true",
        help="~15 trials and fewer settings (CI); default: the full run",
    )
    p.add_argument("--out", default="docs/experiments", help="output directory")
    p.add_argument(
        "--trials",
        type=int,
        default=None,
        help="trials per setting for Exp. 1-5 (default 200, quick 15)",
    )
    p.add_argument(
        "--estimator-trials",
        type=int,
        default=None,
        help="frames per speed for Exp. 7 (default 60, quick 3)",
    )
    p.add_argument("--seed", type=int, default=0, help="base random seed of the trials")
    p.add_argument(
        "--noise", type=float, default=None, help="image noise (px) of Exp. 1, 3, 4, 5 (default 0)"
    )
    p.add_argument(
        "--only",
        default=",".join(EXPERIMENTS),
        help="comma-separated subset of " + ",".join(EXPERIMENTS),
    )
    p.add_argument("--dpi", type=int, default=80, help="resolution of the PNG plots")
    p.add_argument(
        "--render-only",
        action="store_true",
        help="only redraw the plots and report from OUT/results.json",
    )


def run(args) -> int:
    """Run from parsed arguments (see :func:`add_arguments`)."""
    cfg = QUICK if args.quick else FULL
    over = dict(seed=args.seed)
    if args.trials is not None:
        if args.trials < 1:
            raise SystemExit("--trials must be >= 1")
        over["trials"] = args.trials
    if args.estimator_trials is not None:
        over["exp7_trials"] = max(1, args.estimator_trials)
    if args.noise is not None:
        over["noise_px"] = args.noise
    cfg = replace(cfg, **over)
    only = [s.strip() for s in args.only.split(",") if s.strip()]
    bad = [s for s in only if s not in EXPERIMENTS]
    if bad:
        raise SystemExit(f"unknown experiment(s) {bad}; choose from {EXPERIMENTS}")
    prev = os.path.join(args.out, "results.json")
    if args.render_only:
        files = write_outputs(load_summary(prev), args.out, args.dpi)
        print(f"wrote {', '.join(files)} to {args.out}")
        return 0
    summary = {}
    if set(only) != set(EXPERIMENTS) and os.path.exists(prev):
        summary = load_summary(prev)  # re-running a subset keeps the other experiments
        print(f"updating {prev}: re-running {', '.join(only)}")
    t0 = time.perf_counter()
    res = run_all(cfg, only, log=lambda m: print(m, flush=True), progress=True)
    secs = time.perf_counter() - t0
    new = summarize(res)
    meta = summary.get("_meta", {})
    stamp = time.strftime("%Y-%m-%d %H:%M")
    for name, sec in res["_seconds"].items():
        trials = (
            cfg.exp6_repeat
            if name == "exp6"
            else (cfg.exp7_trials if name == "exp7" else cfg.trials)
        )
        meta[name] = dict(quick=cfg.quick, trials=trials, seed=cfg.seed, seconds=sec, date=stamp)
    new.pop("_seconds", None)
    summary.update(new)
    summary["_meta"] = meta
    files = write_outputs(summary, args.out, args.dpi)
    print(f"wrote {', '.join(files)} to {args.out} in {secs:.0f} s")
    if cfg.quick:
        print(
            f"quick run ({cfg.trials} trials per setting): the verdicts below are noisy; "
            "run without --quick for the report's numbers"
        )
    for c in claims(summary):
        if c["verdict"] != "agrees":
            print(
                f"  {c['verdict']}{' (quick, noisy)' if cfg.quick else ''}: exp {c['exp']}: "
                f"{c['paper']} -- {c['ours']}"
            )
    return 0


def main(argv=None) -> int:
    return run(build_parser().parse_args(argv))
