"""``rs-localizer evaluate``: how good a node's poses are, against a bag's ground truth or a
reference trajectory (APE and RPE as evo computes them, the covariance's consistency, a plot)."""

from __future__ import annotations

import argparse
import json
import sys

from . import args as A

__all__ = ["register", "run"]

HELP = "errors of a node's poses (a recorded bag, a TUM file or a live topic) against the truth"


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``evaluate`` subcommand to ``sub`` (``func`` = :func:`run`)."""
    e = sub.add_parser(
        "evaluate",
        help=HELP,
        description="Match the node's poses with a reference trajectory by stamp and print the "
        "errors: the absolute pose error (APE: rotation angle and position distance of each "
        "pose against its reference) and the relative pose error (RPE: of the motion over "
        "--delta poses) as evo computes them (median, p90, RMSE, mean, max), and the share of "
        "poses within 3 sigma of their stated covariance (pose_with_covariance, odom). The "
        "poses: a bag (replay --out, or a ros2 bag record of the node), a TUM file, or --live "
        "SECONDS of a running node's topic. The reference: --truth (a bag's /ground_truth/pose "
        "or a TUM file); default: the estimates' bag's own /ground_truth/pose, live: the "
        "/ground_truth/pose published while the bag plays.",
        formatter_class=A.HelpFormatter,
    )
    e.add_argument(
        "estimates",
        nargs="?",
        default=None,
        help="the node's poses: a bag directory (or its .mcap) or a TUM file "
        "(timestamp tx ty tz qx qy qz qw); not with --live",
    )
    e.add_argument(
        "--topic",
        default=None,
        help="the pose topic (PoseWithCovarianceStamped, PoseStamped or Odometry; default in a "
        "bag: its node's pose_with_covariance, else pose, else odom; required with --live, "
        "e.g. /camera/pose_with_covariance or /rig/pose_with_covariance)",
    )
    e.add_argument(
        "--truth",
        default=None,
        help="the reference: a bag (e.g. the bag the node ran on) or a TUM file (default: the "
        "estimates' bag; with --live: the topic --truth-topic, live)",
    )
    e.add_argument(
        "--truth-topic",
        default="/ground_truth/pose",
        help="the reference's pose topic in a bag or live",
    )
    e.add_argument(
        "--live",
        type=A.positive_float,
        default=None,
        metavar="SECONDS",
        help="subscribe to --topic (and --truth-topic without --truth) and listen for this "
        "many seconds from the first pose (start it, then play the bag)",
    )
    e.add_argument(
        "--wait",
        type=A.positive_float,
        default=60.0,
        help="with --live: give up when no pose arrives on --topic within this many seconds",
    )
    e.add_argument(
        "--align",
        action="store_true",
        help="first align the estimate's positions onto the reference's with an SE(3) Umeyama "
        "fit (as evo's --align): for a map in another frame than the ground truth's",
    )
    e.add_argument(
        "--delta", type=A.positive_int, default=1, help="RPE: poses between the pair's two"
    )
    e.add_argument(
        "--tolerance",
        type=A.positive_float,
        default=2.0,
        help="largest stamp difference of a matched pair (ms)",
    )
    e.add_argument("--plot", default=None, metavar="PNG", help="write the plot here")
    e.add_argument(
        "--save-tum",
        default=None,
        metavar="FILE",
        help="also write the estimates as a TUM file (e.g. of a --live capture)",
    )
    e.add_argument(
        "--json",
        action="store_true",
        help="print only the figures as JSON on stdout (the report goes to stderr)",
    )
    e.set_defaults(func=run)
    return e


def _load(path: str, topic: str | None, what: str):
    """A trajectory from a TUM file or a bag (its ``topic``). Raises CliError."""
    from ..ros.bags.evaluate import is_tum_file, read_bag_trajectory, read_tum

    if is_tum_file(path):
        return read_tum(A.input_file(path, f"{what} (TUM file)"))
    return read_bag_trajectory(A.bag_dir(path, require_messages=True), topic)


def run(args: argparse.Namespace) -> int:
    """Evaluate; returns 0. Raises CliError (exit code 2) on inputs that cannot be used: no
    estimates, no reference, a topic that is not a pose, no stamp matched."""
    from ..ros.bags.evaluate import (
        capture_live,
        evaluate_trajectory,
        format_report,
        is_tum_file,
        plot_evaluation,
        write_tum,
    )

    if args.plot:
        A.output_file(args.plot, True, "plot (PNG)")
    if args.save_tum:
        A.output_file(args.save_tum, True, "TUM file")
    if args.live is not None:
        if args.estimates:
            raise A.CliError("give the estimates (a bag or a TUM file) or --live, not both")
        if not args.topic:
            raise A.CliError("--live needs --topic, e.g. /camera/pose_with_covariance")
        ref = _load(args.truth, args.truth_topic, "reference") if args.truth else None
        print(
            f"listening to {args.topic}"
            + ("" if ref is not None else f" and {args.truth_topic}")
            + f" for {args.live:g} s from its first pose (waiting up to {args.wait:g} s)",
            file=sys.stderr,
        )
        try:
            est, live_ref = capture_live(
                args.topic,
                args.live,
                None if ref is not None else args.truth_topic,
                wait=args.wait,
            )
        except TimeoutError as err:
            raise A.CliError(
                f"{err} (is the node running and the bag playing, with the same ROS_DOMAIN_ID?)"
            ) from None
        if ref is None:
            ref = live_ref
            if not len(ref):
                raise A.CliError(
                    f"no pose on {args.truth_topic} while listening (give the reference with "
                    "--truth BAG or FILE)"
                )
    else:
        if not args.estimates:
            raise A.CliError("give the estimates: a bag or a TUM file (or --live SECONDS)")
        est = _load(args.estimates, args.topic, "estimates")
        truth = args.truth
        if truth is None:
            if is_tum_file(args.estimates):
                raise A.CliError("a TUM file of estimates needs --truth")
            truth = args.estimates
        try:
            ref = _load(truth, args.truth_topic, "reference")
        except ValueError as err:
            hint = "" if args.truth else " (give the reference with --truth BAG or FILE)"
            raise A.CliError(f"{err}{hint}") from None
    if args.save_tum:
        write_tum(est, args.save_tum)
    res = evaluate_trajectory(est, ref, args.align, args.delta, int(args.tolerance * 1e6))
    text = sys.stderr if args.json else sys.stdout
    print(format_report(res, est, ref), file=text)
    if args.plot:
        out = plot_evaluation(res, args.plot, title=f"{est.source} against {ref.source}")
        print(f"plot: {out}", file=text)
    if args.save_tum:
        print(f"estimates (TUM): {args.save_tum}", file=text)
    if args.json:
        print(json.dumps({k: v for k, v in res.items() if k != "per_pose"}, indent=2))
    return 0
