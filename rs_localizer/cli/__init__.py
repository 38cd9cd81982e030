"""``rs-localizer``: the command line of the rolling-shutter localizer.

Each subcommand is a module of this package with ``register(sub)`` (its parser) and
``run(args)`` (its work); this module only lists them and dispatches. Input checks shared by all
of them are in :mod:`rs_localizer.cli.args`.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from . import args as A

__all__ = ["COMMANDS", "build_parser", "main"]

#: the subcommands' modules, in the order ``rs-localizer -h`` lists them: set-up, running the
#: localizer on bags, watching a running node, making maps, making data, research
COMMANDS = (
    "compile",
    "demo",
    "replay",
    "play",
    "lifecycle",
    "evaluate",
    "view",
    "diagnostics",
    "calibrate_readout",
    "calibrate_rig",
    "export_image",
    "map_markers",
    "map_features",
    "marker_map",
    "tag_map",
    "make_bag",
    "render_bag",
    "experiments",
)

#: errors a user can fix (a value, a path, a file's content): one line, exit code 2
USER_ERRORS = (A.CliError, ValueError, OSError)

_EPILOG = (
    "Run 'rs-localizer COMMAND -h' for a command's options. A mistake in the command line is "
    "reported on one line ('rs-localizer COMMAND: error: ...', exit code 2) before any work; "
    "'rs-localizer COMMAND ... --debug' shows the traceback of an unexpected error."
)


def build_parser() -> argparse.ArgumentParser:
    """The ``rs-localizer`` parser with every subcommand of :data:`COMMANDS`."""
    p = A.Parser(
        prog="rs-localizer",
        description="Localize rolling-shutter cameras: the node's offline and bag tools, map "
        "builders and the paper's experiments.",
        epilog=_EPILOG,
        formatter_class=A.HelpFormatter,
    )
    sub = p.add_subparsers(dest="command", required=True, title="commands", metavar="COMMAND")
    for name in COMMANDS:
        sp = importlib.import_module(f"{__name__}.{name}").register(sub)
        sp.add_argument(
            "--debug", action="store_true", help="show the traceback of an unexpected error"
        )
    return p


def _is_bag_error(e: BaseException) -> bool:
    """An error of rosbags reading a bag (its storage plugins raise their own types)."""
    return type(e).__module__.startswith("rosbags")


def main(argv: list[str] | None = None) -> int:
    """Parse the command line and run the command; returns its exit code.

    A mistake a user can fix (:data:`USER_ERRORS`, a bag rosbags cannot read) is printed as one
    line ``rs-localizer COMMAND: error: ...`` with exit code 2; any other exception as one line
    with a hint to rerun with ``--debug`` (exit code 1), and with ``--debug`` as a traceback.
    """
    args = build_parser().parse_args(argv)
    from ..ros.dds_profile import apply_default_profile

    apply_default_profile()  # (before any rclpy participant: images over shared memory)
    cmd = f"rs-localizer {args.command}"
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print(f"{cmd}: interrupted", file=sys.stderr)
        return 130
    except Exception as e:
        if args.debug:
            raise
        text = " ".join(str(e).split()) or type(e).__name__
        if isinstance(e, USER_ERRORS) or _is_bag_error(e):
            print(f"{cmd}: error: {text}", file=sys.stderr)
            return 2
        print(
            f"{cmd}: unexpected error: {type(e).__name__}: {text} (rerun with --debug for "
            "the traceback)",
            file=sys.stderr,
        )
        return 1


if __name__ == "__main__":
    sys.exit(main())
