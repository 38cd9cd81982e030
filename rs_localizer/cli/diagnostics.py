"""``rs-localizer diagnostics``: print a running node's ``/diagnostics`` live (counters,
timings), one compact block per status."""

from __future__ import annotations

import argparse
import shutil

from . import args as A

__all__ = ["register", "run"]

HELP = "print a running node's /diagnostics live (counters, timings), no ROS install needed"


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``diagnostics`` subcommand to ``sub`` (``func`` = :func:`run`)."""
    d = sub.add_parser(
        "diagnostics",
        help=HELP,
        description="Subscribe /diagnostics and print each status of a localizer node as one "
        "block: time, level, name and message, then its key=value pairs (frames, failures, "
        "latency and stage times in ms, ...; docs/node.md lists them). Stop with Ctrl-C.",
        formatter_class=A.HelpFormatter,
    )
    d.add_argument(
        "--ns",
        default=None,
        help="only the node(s) in this namespace, e.g. /camera (default: every localizer)",
    )
    d.add_argument(
        "--all",
        action="store_true",
        help="every status on /diagnostics, other nodes' too",
    )
    d.add_argument(
        "--keys",
        nargs="+",
        default=None,
        metavar="PATTERN",
        help="only the values whose key matches a shell pattern, e.g. frames_* 'latency*'",
    )
    d.add_argument("--once", action="store_true", help="print one status and exit")
    d.add_argument(
        "--timeout",
        type=A.nonneg_float,
        default=10.0,
        help="exit (code 2) when no status arrives for this many seconds (0: wait forever)",
    )
    d.set_defaults(func=run)
    return d


def run(args: argparse.Namespace) -> int:
    """Print statuses until Ctrl-C (one with ``--once``); returns 0. Raises CliError (exit code
    2) when none arrives within ``--timeout`` s."""
    from ..ros.echo import echo_diagnostics

    width = shutil.get_terminal_size((100, 24)).columns
    res = echo_diagnostics(
        lambda block: print(block, flush=True),
        ns=args.ns,
        every_status=args.all,
        once=args.once,
        timeout=args.timeout,
        keys=args.keys,
        width=width,
    )
    if res.timed_out:
        who = f"a localizer in {args.ns}" if args.ns else "a localizer"
        if args.all:
            who = "any node"
        what = "no" if not res.printed else "no further"
        msg = (
            f"{what} /diagnostics status from {who} within {args.timeout:g} s (is the node "
            "running, with the same ROS_DOMAIN_ID?)"
        )
        if res.others:
            msg += "; statuses left out: " + ", ".join(sorted(res.others))
        raise A.CliError(msg)
    return 0
