"""``rs-localizer play``: publish a bag into the live ROS graph (as ``ros2 bag play``, with a
lock-step mode that waits for the node's answer to each frame)."""

from __future__ import annotations

import argparse

from . import args as A

__all__ = ["parse_remap", "register", "run"]

HELP = "publish a bag into the live ROS graph (optionally frame by frame in lock-step)"


def parse_remap(items: list[str] | None) -> dict[str, str]:
    """``["FROM:=TO", ...]`` -> {FROM: TO}. Raises CliError on an entry without ``:=``."""
    out = {}
    for it in items or ():
        a, sep, b = it.partition(":=")
        if not sep or not a or not b:
            raise A.CliError(f"--remap expects FROM:=TO, got {it!r}")
        out[a] = b
    return out


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``play`` subcommand to ``sub`` (``func`` = :func:`run`)."""
    pl = sub.add_parser(
        "play",
        help=HELP,
        description="Publish the messages of a bag on their topics, at the bag's pace (--rate) "
        "or in lock-step (--lockstep: each frame waits for the node's pose before the next "
        "is sent; prints the rate and latency). A bag image topic is published on the image "
        "topic the node subscribes in its namespace (/camera/image_raw as /camera/image), "
        "and a node running a front end gets the images, not the bag's correspondences "
        "(--source). A node still compiling its kernels is waited for. A rig bag (make-bag "
        "--rig, render-bag --rig) publishes every camera's topics; lock-step waits for the "
        "rig's pose (e.g. /rig/pose) after the camera frame that completes each rig frame; "
        "the rig frames it prints are counted as the rig node counts them. A recording of a "
        "rig's cameras (no sequence.json) plays as a rig bag given the rig node's parameter "
        "file (--params-file with rig.cameras).",
        formatter_class=A.HelpFormatter,
    )
    pl.add_argument("bag", help="bag directory (or its .mcap / .db3 file)")
    A.node_parameter_options(
        pl,
        "the rig node's parameter file (repeatable; later ones win; over a rig bag's "
        "rig_params.yaml): with rig.cameras, a recording of the rig's cameras plays as a rig "
        "bag, its frames grouped into rig frames with these parameters",
        "set a rig node parameter (YAML value, as ros2 run -p; repeatable; over the "
        "parameter files), e.g. rig.window:=0.02",
    )
    pl.add_argument(
        "--rate", type=A.nonneg_float, default=1.0, help="time scale (0: as fast as possible)"
    )
    pl.add_argument(
        "--lockstep",
        action="store_true",
        help="wait for the output of each frame before sending the next",
    )
    pl.add_argument(
        "--output-topic",
        action="append",
        default=None,
        help="topic(s) to wait for in lock-step (repeatable; default: the pose topic of the "
        "namespace each frame is played into, e.g. /camera/pose, or /robot/pose with "
        "--remap /camera/image:=/robot/image; a rig bag: the rig's, /rig/pose)",
    )
    pl.add_argument(
        "--timeout", type=A.positive_float, default=2.0, help="lock-step wait per frame (s)"
    )
    pl.add_argument(
        "--retries",
        type=A.nonneg_int,
        default=1,
        help="times a frame without answer is republished (lock-step)",
    )
    pl.add_argument(
        "--source",
        choices=("auto", "image", "correspondences"),
        default="auto",
        help="a camera with frames on several topics (a rendered bag's images and the "
        "correspondences computed from its true map): auto plays what the node listens to "
        "(the images when it subscribes an image topic, i.e. runs a front end; else the "
        "correspondences), or name it",
    )
    pl.add_argument(
        "--topics", nargs="+", default=None, help="only these bag topics (default: all)"
    )
    pl.add_argument(
        "--remap",
        nargs="+",
        default=None,
        metavar="FROM:=TO",
        help="publish topic FROM of the bag as TO; __ns:=NS publishes every other topic in "
        "namespace NS (/camera/image -> NS/camera/image)",
    )
    pl.add_argument(
        "--wait",
        type=A.nonneg_float,
        default=None,
        help="wait for subscribers (s; default 30 in lock-step, else 2)",
    )
    pl.add_argument(
        "--best-effort", action="store_true", help="publish best effort (default: reliable)"
    )
    pl.add_argument("--limit", type=A.positive_int, default=None, help="stop after N frames")
    pl.add_argument("--loop", type=A.positive_int, default=1, help="play N times")
    pl.add_argument(
        "--give-up",
        type=A.nonneg_int,
        default=3,
        help="lock-step: stop after N frames in a row without an answer while none was "
        "answered (0: never)",
    )
    pl.set_defaults(func=run)
    return pl


def run(args: argparse.Namespace) -> int:
    """Play the bag; returns 0, or 1 when a lock-step frame got no answer or lock-step gave
    up (no node answered the first frames). Raises CliError for
    a bag that cannot be read or has no messages on the chosen topics (before any waiting)."""
    bag = A.bag_dir(args.bag, require_messages=True)
    remap = parse_remap(args.remap)
    if args.topics is not None:
        from ..ros.bags.bag_io import bag_topics

        have = bag_topics(bag)
        if not any(t in have for t in args.topics):
            raise A.CliError(
                f"{bag}: none of the topics {' '.join(args.topics)} (topics: {sorted(have)})"
            )
    from ..ros.bags.play import play

    params = A.param_overrides(args.param)
    if args.params_file or params:
        from ..ros.bags.bag_frames import is_rig_bag

        try:
            rig = is_rig_bag(bag, args.params_file, params)
        except (OSError, ValueError) as e:
            raise A.CliError(f"--params-file / -p: {e}") from None
        if not rig:
            raise A.CliError(
                "--params-file / -p: play takes the node's parameters only for a rig's "
                "cameras (rig.cameras), and these name none; a camera's bag plays without them"
            )
    output_topics = tuple(args.output_topic) if args.output_topic else None
    res = play(
        bag,
        rate=args.rate,
        lockstep=args.lockstep,
        topics=args.topics,
        remap=remap,
        output_topics=output_topics,
        timeout=args.timeout,
        retries=args.retries,
        wait_subscribers=args.wait if args.wait is not None else (30.0 if args.lockstep else 2.0),
        reliable=not args.best_effort,
        limit=args.limit,
        loop=args.loop,
        give_up=args.give_up,
        source=args.source,
        params_files=args.params_file,
        params=params,
    )
    kind = "camera frames" if res.rig_frames_in_bag else "frames"
    msg = f"published {res.published} messages, {len(res.frames)} {kind} in {res.wall_time:.2f} s"
    if res.rig_frames_in_bag:  # (counted as the rig node counts its rig_frames)
        msg += (
            f" ({res.rig_frames_in_bag} rig frames: the camera frames grouped as the rig node "
            "groups them, one per camera within rig.window)"
        )
    if args.lockstep:
        lat = res.latencies
        what = " rig frames" if res.rig_frames_in_bag else ""
        n_answered = res.answered
        if what:
            msg += f"; {res.rig_frames} rig frames completed in {res.answered} waits answered"
        else:
            msg += f"; {n_answered} answered"
        msg += f", {res.timeouts} timed out"
        if res.republished:
            msg += f" ({res.republished} sent again after no answer)"
        if res.compile_waited:
            msg += f" ({res.compile_waited:.0f} s waited for the node to compile)"
        if len(lat):
            import numpy as np

            n = res.rig_frames or len(res.frames)
            msg += (
                f"; {n / max(res.wall_time, 1e-9):.1f} {'rig frames/s' if what else 'Hz'}, "
                f"latency median "
                f"{np.median(lat) * 1e3:.2f} ms p99 {np.percentile(lat, 99) * 1e3:.2f} ms"
            )
    print(msg)
    if res.gave_up:
        print(f"stopped: {res.gave_up}")
    return 0 if not args.lockstep or (res.timeouts == 0 and not res.gave_up) else 1
