"""``rs-localizer lifecycle``: a managed node's state and transitions
(``rs_localizer_lifecycle_node``), as ``ros2 lifecycle get|set`` does, without the ROS 2
command line (a pip install has rclpy but no ``ros2``)."""

from __future__ import annotations

import argparse

from . import args as A

__all__ = ["register", "run"]

HELP = "a managed node's state, or a transition (configure, activate, ...), no ROS install needed"
ACTIONS = ("get", "configure", "activate", "deactivate", "cleanup", "shutdown")


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``lifecycle`` subcommand to ``sub`` (``func`` = :func:`run`)."""
    lc = sub.add_parser(
        "lifecycle",
        help=HELP,
        description="Print the state of a managed node (rs_localizer_lifecycle_node) or take it "
        "through a transition, over its lifecycle_msgs services <node>/get_state and "
        "<node>/change_state: 'get' prints the state (unconfigured, inactive, active, "
        "finalized); a transition prints the state it left the node in. Exit code 1 when the "
        "node refused the transition (its log says why, e.g. an invalid parameter). The node "
        "is named in full (/camera/rs_localizer); 'rs-localizer lifecycle list' lists the "
        "managed nodes and their states.",
        formatter_class=A.HelpFormatter,
    )
    lc.add_argument("node", help="the managed node's full name, e.g. /camera/rs_localizer; or list")
    lc.add_argument(
        "action",
        nargs="?",
        choices=ACTIONS,
        default="get",
        help="get (the state) or the transition to request",
    )
    lc.add_argument(
        "--timeout",
        type=A.positive_float,
        default=300.0,
        help="s to wait for the node's reply (configure compiles the kernels on a cold "
        "numba cache: minutes)",
    )
    lc.set_defaults(func=run)
    return lc


def run(args: argparse.Namespace) -> int:
    """Print the state (or the state after the transition); returns 0, or 1 when the node
    refused the transition. Raises CliError when no managed node of that name answers."""
    from ..ros.lifecycle_client import (
        LifecycleError,
        change_state,
        client_session,
        get_state,
        lifecycle_nodes,
    )

    name = args.node if args.node == "list" or args.node.startswith("/") else f"/{args.node}"
    with client_session(2.0 if name == "list" else 0.0) as (node, executor):
        if name == "list":
            names = lifecycle_nodes(node)
            for n in names:
                try:
                    print(f"{n}: {get_state(node, executor, n, 5.0)}")
                except LifecycleError:
                    print(f"{n}: (no answer)")
            if not names:
                print("no managed node (is it running, on this ROS_DOMAIN_ID?)")
            return 0
        try:
            if args.action == "get":
                print(get_state(node, executor, name, min(args.timeout, 30.0)))
                return 0
            ok, state = change_state(node, executor, name, args.action, args.timeout)
        except LifecycleError as e:
            others = [n for n in lifecycle_nodes(node) if n != name]
            hint = f"; managed nodes: {', '.join(others)}" if others else ""
            raise A.CliError(f"{name}: {e}{hint}") from None
    if ok:
        print(f"{args.action}: {state}")
        return 0
    print(
        f"{args.action} refused: {name} is {state} (not valid from there, or the node's log "
        "says why)"
    )
    return 1
