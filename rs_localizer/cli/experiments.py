"""``rs-localizer experiments``: the paper's synthetic experiments (PNG plots and a markdown
report; :mod:`rs_localizer.experiments`)."""

from __future__ import annotations

import argparse

from . import args as A

__all__ = ["register", "run"]

HELP = "reproduce the paper's synthetic experiments (PNG plots + markdown report)"

#: checked types of the experiments' numeric options
_TYPES = {
    "trials": A.positive_int,
    "estimator_trials": A.positive_int,
    "seed": A.nonneg_int,
    "noise": A.nonneg_float,
    "dpi": A.positive_int,
}


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``experiments`` subcommand to ``sub`` (``func`` = :func:`run`)."""
    from ..experiments import add_arguments

    ex = sub.add_parser(
        "experiments",
        help=HELP,
        description="Run the synthetic experiments of Kukelova, Albl, Sugimoto, Pajdla, "
        "'Linear Solution to the Minimal Absolute Pose Rolling Shutter Problem' (ACCV 2018) "
        "on the registry's solvers, and write the plots and a report into --out.",
        formatter_class=A.HelpFormatter,
    )
    add_arguments(ex)
    for a in ex._actions:
        if a.dest in _TYPES:
            a.type = _TYPES[a.dest]
    ex.set_defaults(func=run)
    return ex


def run(args: argparse.Namespace) -> int:
    """Run the experiments; returns their exit code. Raises CliError for an output directory
    that cannot be written or an unknown experiment (before any trial)."""
    from ..experiments import EXPERIMENTS
    from ..experiments import run as run_experiments

    A.writable_dir(args.out, "output directory")
    unknown = [e.strip() for e in args.only.split(",") if e.strip() not in (*EXPERIMENTS, "")]
    if unknown:
        raise A.CliError(
            f"--only: unknown experiments {unknown} (choose from {', '.join(EXPERIMENTS)})"
        )
    return run_experiments(args)
