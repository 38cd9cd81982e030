"""``rs-localizer demo``: the node and the sample bags over DDS, with the accuracy against the
ground truth (what ``make demo`` runs)."""

from __future__ import annotations

import argparse

from ..solvers.registry import SOLVER_NAMES
from . import args as A

__all__ = ["register", "run"]

HELP = "run the node on the sample bags over DDS and print the accuracy vs ground truth"


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``demo`` subcommand to ``sub`` (``func`` = :func:`run`)."""
    d = sub.add_parser(
        "demo",
        help=HELP,
        description="Start the localizer node, play the sample correspondence bag into it in "
        "lock-step and compare its poses and velocities with the bag's ground truth (and a "
        "second solver's); then the same with the image bag and the front end in the node.",
        formatter_class=A.HelpFormatter,
    )
    d.add_argument("--bag", default=None, help="correspondence bag (default: data/sample)")
    d.add_argument(
        "--params", default=None, help="node parameter file (default: config/rs_localizer.yaml)"
    )
    d.add_argument(
        "--compare",
        default="p3p",
        choices=[*SOLVER_NAMES, ""],
        help="second solver run next to the configured one ('' to skip)",
    )
    d.add_argument("--summary-only", action="store_true", help="no per-frame lines")
    d.add_argument(
        "--timeout",
        type=A.positive_float,
        default=5.0,
        help="lock-step wait for each frame's pose (s)",
    )
    d.add_argument(
        "--images",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="also run the image-mode demo (front end in the node)",
    )
    d.add_argument("--image-bag", default=None, help="image bag (default: data/sample_images)")
    d.set_defaults(func=run)
    return d


def run(args: argparse.Namespace) -> int:
    """Run the demo; returns its exit code. Raises CliError for a bag or parameter file that
    cannot be used (before the node starts)."""
    from .demo_runner import run_demo

    if args.bag is not None:
        A.bag_dir(args.bag, require_messages=True)
    if args.images and args.image_bag is not None:
        A.bag_dir(args.image_bag, require_messages=True)
    if args.params is not None:
        A.yaml_file(args.params, "parameter file")
    return run_demo(
        bag=args.bag,
        params=args.params,
        compare=args.compare,
        per_frame=not args.summary_only,
        timeout=args.timeout,
        images=args.images,
        image_bag=args.image_bag,
    )
