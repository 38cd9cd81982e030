"""``rs-localizer compile``: compile the solvers' JIT kernels once after installing."""

from __future__ import annotations

import argparse

from ..solvers.registry import SOLVER_NAMES
from . import args as A

__all__ = ["register", "run"]

HELP = "compile the JIT kernels now (once after installing: the node then starts in seconds)"


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``compile`` subcommand to ``sub`` (``func`` = :func:`run`)."""
    c = sub.add_parser(
        "compile",
        help=HELP,
        description="Compile the JIT (numba) kernels of the solvers now and cache them, once "
        "after installing while the package directory is writable: the node then starts in "
        "seconds instead of compiling on its first frames.",
        formatter_class=A.HelpFormatter,
    )
    c.add_argument(
        "--solvers",
        nargs="+",
        default=None,
        choices=SOLVER_NAMES,
        help="solvers to compile for (default: r6p_1lin, the node's; the demo's "
        "global-shutter baseline: add p3p)",
    )
    c.add_argument(
        "--jobs",
        type=A.positive_int,
        default=None,
        help="processes compiling at once, the fused RANSAC kernels in a second one (default: "
        "2 on a machine with two cores or more, else 1)",
    )
    c.set_defaults(func=run)
    return c


def run(args: argparse.Namespace) -> int:
    """Compile (or load from the cache) the kernels; returns 0."""
    from ..runtime.jit_cache import cache_state
    from ..runtime.warmup import DEFAULT_JOBS, DEFAULT_SOLVERS, compile_kernels

    st = cache_state()
    print(
        f"numba cache: {st['dir']} ({st['mode']}"
        + (f", {st['seeded']} files copied from the package" if st["seeded"] else "")
        + ")",
        flush=True,
    )
    solvers = args.solvers or list(DEFAULT_SOLVERS)
    jobs = args.jobs or DEFAULT_JOBS
    res = compile_kernels(solvers, log=lambda m: print(m, flush=True), jobs=jobs)
    n = len(res["kernels"])
    print(
        f"{', '.join(res['solvers'])}: ready in {res['seconds']:.1f} s ("
        + (
            f"compiled {n} kernels, {sum(d for _, d in res['kernels']):.1f} s of compiling"
            + (f" in {jobs} processes" if jobs > 1 else "")
            if n
            else "all kernels loaded from the cache"
        )
        + ")"
    )
    return 0
