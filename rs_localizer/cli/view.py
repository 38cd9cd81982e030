"""``rs-localizer view``: a live view of a localizer in the Foxglove app without a ROS install
(the Foxglove SDK's WebSocket server forwarding the node's outputs)."""

from __future__ import annotations

import argparse

from . import args as A

__all__ = ["register", "run"]

HELP = "serve a running node's outputs to the Foxglove app (ws://localhost:8765), no ROS install"

_INSTALL = (
    "the live view needs the Foxglove SDK: pip install 'rs_localizer[view]' (in a clone: "
    ".venv/bin/pip install -e '.[view]', or .venv/bin/pip install foxglove-sdk)"
)


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``view`` subcommand to ``sub`` (``func`` = :func:`run`)."""
    v = sub.add_parser(
        "view",
        help=HELP,
        description="Forward a running localizer's outputs (pose, path, markers, debug_image, "
        "odom, twist, /diagnostics, /tf) to the Foxglove app over the Foxglove SDK's "
        "WebSocket server: in Foxglove, Open connection, Foxglove WebSocket, "
        "ws://localhost:8765, and import the layout foxglove/rs_localizer.json. The outputs "
        "NS/<name> are served as /camera/<name>, the layout's names, whatever NS (--ns "
        "/rs_localizer for a 'rs-localizer replay --out BAG --debug-outputs' bag played with "
        "'rs-localizer play'). A topic is subscribed only while Foxglove shows it. Needs the "
        "'view' extra (foxglove-sdk). Stop with Ctrl-C.",
        formatter_class=A.HelpFormatter,
    )
    v.add_argument(
        "--ns",
        default="/camera",
        help="namespace of the node's outputs (/rs_localizer: a replay bag's)",
    )
    v.add_argument("--port", type=A.nonneg_int, default=8765, help="TCP port (0: a free one)")
    v.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to listen on (127.0.0.1: this machine only; 0.0.0.0: every interface)",
    )
    v.add_argument(
        "--keep-names",
        action="store_true",
        help="serve the outputs under their ROS names (NS/<name>) instead of the layout's "
        "(/camera/<name>)",
    )
    v.add_argument(
        "--duration",
        type=A.positive_float,
        default=None,
        help="stop after this many seconds (default: at Ctrl-C)",
    )
    v.set_defaults(func=run)
    return v


def run(args: argparse.Namespace) -> int:
    """Serve until Ctrl-C (or ``--duration``); returns 0. Raises CliError when the Foxglove SDK
    is missing or the port cannot be opened."""
    from ..ros.view import LAYOUT_NS, foxglove_available, serve

    if not foxglove_available():
        raise A.CliError(_INSTALL)
    try:
        serve(
            ns=args.ns,
            port=args.port,
            host=args.host,
            channel_ns=None if args.keep_names else LAYOUT_NS,
            duration=args.duration,
            log=lambda m: print(m, flush=True),
        )
    except RuntimeError as e:
        raise A.CliError(f"{e} (another view or foxglove_bridge? try --port)") from e
    return 0
