"""``rs-localizer replay``: the localizer node over a bag, offline (the node's parameters and
outputs, no ROS graph): a rig bag's cameras through the rig mode, a camera's bag through it as
a rig of one camera, reported alike."""

from __future__ import annotations

import argparse
import json
import sys

from ..camera import READOUT_DIRECTIONS
from ..solvers.registry import SOLVER_NAMES
from . import args as A

__all__ = ["register", "run"]

HELP = "run the localizer node over a bag offline (same parameters, same outputs)"


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``replay`` subcommand to ``sub`` (``func`` = :func:`run`)."""
    r = sub.add_parser(
        "replay",
        help=HELP,
        description="Run the node's frame step over every frame of a bag, with the "
        "node's parameters: the defaults, then each --params-file (ROS 2 format: the /** and "
        "rs_localizer sections), then --param and the options below. Tracking is on as in "
        "the node: twist and odom carry the fused twist, twist_single_frame each frame's own "
        "(--no-tracking: every frame alone). The RS timing (rs.line_delay, rs.direction, "
        "rs.reference_row, rs.stamp_row) that no parameter file or option sets comes from "
        "the bag's sequence.json (make-bag, render-bag), else the parameter's default.",
        formatter_class=A.HelpFormatter,
    )
    r.add_argument(
        "bag",
        help="bag directory (make-bag or render-bag output, or a recording) or its .mcap file",
    )
    unset = argparse.SUPPRESS  # (options only override: unset ones leave the parameters)
    A.node_parameter_options(
        r,
        "the node's ROS 2 parameter file, e.g. config/rs_localizer.yaml (repeatable; later ones "
        "win)",
        "set a node parameter (YAML value, as ros2 run -p; repeatable), e.g. tracking.lag:=2",
        default=unset,
    )

    def over(param: str, text: str) -> str:
        return f"{text}; sets the parameter {param} (default: {A.node_default(param)})"

    def timing(param: str, text: str) -> str:
        return (
            f"{text}; sets {param} (default: --params-file, else the bag's sequence.json, "
            f"else {A.node_default(param)})"
        )

    r.add_argument(
        "--solver",
        default=unset,
        choices=SOLVER_NAMES,
        help=over("solver", A.solver_help("minimal solver")),
    )
    r.add_argument(
        "--source",
        choices=["correspondences", "keypoints", "image"],
        default=unset,
        help="frame topic: */correspondences (u, v, x, y, z), */keypoints (u, v, id + a "
        "landmark map) or image (through the front end of the frontend parameter) "
        "(default: image with a front end, else correspondences)",
    )
    r.add_argument(
        "--landmarks",
        default=unset,
        help="CSV id,x,y,z for --source keypoints; sets landmarks_file (default: "
        "--params-file, else BAG/landmarks.csv)",
    )
    r.add_argument("--out", default=None, help="write the outputs to this bag directory")
    r.add_argument(
        "--debug-outputs",
        action="store_true",
        help="also write /rs_localizer/debug_image, markers and path into --out "
        "(the node's visualization topics, for Foxglove or RViz); of a rig bag "
        "/rs_localizer/<camera>/debug_image and markers for each camera, and path",
    )
    r.add_argument(
        "--path-length",
        type=A.positive_int,
        default=1000,
        help="poses kept in the path topic (--debug-outputs)",
    )
    r.add_argument(
        "--image-topic",
        default=None,
        help="with --source image: the frames (default: the bag's image topic); else the "
        "image drawn under debug_image (default: the bag's sensor_msgs/Image topic next to "
        "the frames, if any; else a blank canvas)",
    )
    r.add_argument(
        "--imu-topic",
        default=None,
        help="with -p imu.enabled:=true: the sensor_msgs/Imu topic of the gyro (default: the "
        "bag's only IMU topic)",
    )
    r.add_argument("--csv", default=None, help="write one line per frame")
    r.add_argument(
        "--storage", choices=["mcap", "sqlite3"], default="mcap", help="storage format of --out"
    )
    r.add_argument(
        "--threshold",
        type=A.positive_float,
        default=unset,
        help=over("ransac.threshold_px", "RANSAC threshold (px)"),
    )
    r.add_argument(
        "--max-iterations",
        type=A.positive_int,
        default=unset,
        help=over("ransac.max_iterations", "RANSAC hypotheses cap per frame"),
    )
    r.add_argument(
        "--confidence",
        type=A.probability,
        default=unset,
        help=over("ransac.confidence", "RANSAC adaptive-termination confidence"),
    )
    r.add_argument(
        "--min-inliers",
        type=A.positive_int,
        default=unset,
        help=over("ransac.min_inliers", "fewest inliers for a pose"),
    )
    r.add_argument(
        "--seed", type=A.nonneg_int, default=unset, help=over("ransac.seed", "RANSAC random seed")
    )
    r.add_argument(
        "--no-refine",
        dest="refine",
        action="store_const",
        const=False,
        default=unset,
        help=over("refine", "skip the final exact-model refinement (no covariance)"),
    )
    r.add_argument(
        "--no-tracking",
        dest="tracking",
        action="store_const",
        const=False,
        default=unset,
        help=over("tracking.enabled", "every frame alone: twist and odom carry its own twist"),
    )
    r.add_argument(
        "--line-delay", type=A.nonneg_float, default=unset, help=timing("rs.line_delay", "s/row")
    )
    r.add_argument(
        "--readout-time",
        type=A.nonneg_float,
        default=unset,
        help=over("rs.readout_time", "s/frame, wins over the line delay if > 0"),
    )
    r.add_argument(
        "--direction",
        default=unset,
        choices=list(READOUT_DIRECTIONS),
        help=timing("rs.direction", "readout direction"),
    )
    r.add_argument(
        "--reference-row",
        type=A.finite_float,
        default=unset,
        help=timing("rs.reference_row", "row (px) of the estimated pose, -1: centre"),
    )
    r.add_argument(
        "--stamp-row",
        type=A.finite_float,
        default=unset,
        help=timing("rs.stamp_row", "row (px) whose capture time is the header stamp"),
    )
    r.add_argument(
        "--json",
        action="store_true",
        help="print only the summary as JSON on stdout (the rest goes to stderr)",
    )
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.add_argument("--overwrite", action="store_true", help="replace --out if it exists")
    r.set_defaults(func=run)
    return r


#: replay options that set a node parameter: (argparse dest, parameter name)
_REPLAY_OVERRIDES = (
    ("solver", "solver"),
    ("threshold", "ransac.threshold_px"),
    ("max_iterations", "ransac.max_iterations"),
    ("confidence", "ransac.confidence"),
    ("min_inliers", "ransac.min_inliers"),
    ("seed", "ransac.seed"),
    ("refine", "refine"),
    ("tracking", "tracking.enabled"),
    ("line_delay", "rs.line_delay"),
    ("readout_time", "rs.readout_time"),
    ("direction", "rs.direction"),
    ("reference_row", "rs.reference_row"),
    ("stamp_row", "rs.stamp_row"),
    ("landmarks", "landmarks_file"),
)


def run(args: argparse.Namespace) -> int:
    """Replay the bag, a camera's or a rig's (:func:`rs_localizer.ros.bags.replay.replay`; a
    rig bag is reported a rig frame for a frame, with each camera's counts, each rig frame's
    own twist and the cameras that disagree with the others); returns 0, or 1 when no frame
    was solved. Raises CliError for a bag, parameter file, landmark file or output that
    cannot be used (before any frame), or a single camera's option given for a rig bag."""
    bag = A.bag_dir(args.bag, require_messages=True)
    A.parameter_files(getattr(args, "params_file", []))
    if hasattr(args, "landmarks"):
        A.input_file(args.landmarks, "landmark CSV (id,x,y,z)")
    params = A.param_overrides(getattr(args, "param", []))
    params.update({p: getattr(args, d) for d, p in _REPLAY_OVERRIDES if hasattr(args, d)})
    from ..ros.bags.bag_frames import is_rig_bag

    if args.debug_outputs and not args.out:
        raise A.CliError("--debug-outputs writes into the --out bag: give --out DIR")
    rig = is_rig_bag(bag, getattr(args, "params_file", []), params)
    if rig:
        _no_camera_options(args)
    out_bag = A.output_dir(args.out, args.overwrite, "output bag") if args.out else None
    if args.csv:
        A.output_file(args.csv, True, "CSV file")
    from ..ros.bags.replay import replay
    from ..ros.params import ConfigError

    try:
        res = replay(
            bag,
            params_files=getattr(args, "params_file", []),
            params=params,
            source=getattr(args, "source", None),
            out_bag=out_bag,
            out_csv=args.csv,
            storage=args.storage,
            overwrite=args.overwrite,
            progress=None if args.quiet else sys.stderr,
            debug_outputs=args.debug_outputs,
            path_length=args.path_length,
            image_topic=args.image_topic,
            imu_topic=getattr(args, "imu_topic", None),
            compile_note=sys.stderr,
        )
    except ConfigError as e:
        if not rig:
            raise
        raise A.CliError(f"invalid parameters: {e}") from None
    _print_report(args, res)
    return 0 if res.solved else 1


def _print_report(args: argparse.Namespace, res) -> None:
    """A replay's report (a camera's; a rig's a rig frame for a frame, with its cameras):
    the warnings, frames solved and failures, each camera's counts, the gyro, the cameras
    that disagree, the errors against ground truth, the files written; with ``--json`` the
    summary as JSON on stdout, the rest on stderr."""
    from ..accuracy import format_summary

    n, solver = len(res.rows), res.solver or "rig"
    unit = "rig frames" if res.cameras else "frames"
    text = sys.stderr if args.json else sys.stdout  # --json: stdout holds only the JSON
    for note in res.notes:
        print(f"warning: {note}", file=sys.stderr)
    line = _solved_line(solver, res.solved, n, unit, res.failures, res.tracked)
    if res.cameras:
        line = line.replace(" rig frames", f" rig frames of {len(res.cameras)} cameras", 1)
    print(line, file=text)
    for name in res.cameras:
        c = res.camera_counts[name]
        print(f"  {name}: " + ", ".join(f"{k} {v}" for k, v in c.items()), file=text)
    gyro = bool(res.parameters["imu.enabled"])
    if gyro:
        how = "estimated" if res.parameters["imu.estimate_bias"] else "imu.gyro_bias"
        bias = None if res.gyro_bias is None else (res.gyro_bias, res.gyro_bias_std)
        _print_gyro(res.counts, bias, how, unit, text)
    for name, d in res.disagreeing.items():
        print(
            f"  camera {name} disagrees with the others in {d['rig_frames']} rig frames (median "
            f"{d['median_deg']:.2f} deg off: its rotation posed alone against the rig's pose "
            "through its mounting; a wrong mounting shows its own error, a wrong clock or line "
            "delay a varying one)",
            file=text,
        )
    _print_accuracy(solver, res.summary, n, text, res.solved, unit)
    if res.cameras and res.own_twist.get("frames") and res.tracked:
        own = format_summary(solver, res.own_twist, n).split("; ", 1)[-1]
        print(f"  each rig frame's own twist: {own}", file=text)
    if res.out_bag:
        viz = "debug_image, markers, path"
        if res.cameras:
            viz = ", ".join(f"{n}/debug_image, {n}/markers" for n in res.cameras) + ", path"
        print(f"estimates: {res.out_bag}" + (f" (with {viz})" if args.debug_outputs else ""),
              file=text)  # fmt: skip
    if res.out_csv:
        print(f"csv: {res.out_csv}", file=text)
    if args.json:
        more = {}
        if res.cameras:
            more = {"own_twist": res.own_twist, "disagreeing": res.disagreeing,
                    "counts": res.camera_counts}  # fmt: skip
            if gyro:
                more["gyro"] = res.counts
        report = _report(solver, n, res.solved, res.failures, res.summary, res.out_bag,
                         res.out_csv, **more)  # fmt: skip
        print(json.dumps(report, indent=2))


def _solved_line(solver: str, solved: int, n: int, unit: str, failures: dict, tracked: bool) -> str:
    """The first line of a replay's report: frames (or rig frames) solved, failures by
    reason, and whether the twist is the fused one."""
    return (
        f"{solver}: solved {solved}/{n} {unit}"
        + (f"; failures {failures}" if failures else "")
        + (" (tracking: twist = the fused twist)" if tracked else "")
    )


def _print_gyro(c: dict, bias, how: str, unit: str, text) -> None:
    """The gyro's lines of a replay's report (a camera's counts, or a rig's by the same
    names): frames posed with it, contradicted by the image, solved without it while it
    contradicted the rotation between frames, without samples (by reason); the bias
    ``(bias (3,), std (3,))`` rad/s, IMU frame, when known (``how`` it was got)."""
    missing = {k[13:]: v for k, v in c.items() if k.startswith("gyro_missing.")}
    print(
        f"gyro: {c.get('frames_with_gyro', 0)} {unit} used it, "
        f"{c.get('gyro_rejected', 0)} contradicted by the image (solved without), "
        f"{c.get('gyro_disabled_inconsistent', 0)} solved without it while the rotation "
        f"between {unit} contradicted it, "
        f"{c.get('gyro_missing', 0)} without samples" + (f" {missing}" if missing else ""),
        file=text,
    )
    if bias is not None:
        print(
            f"gyro bias ({how}, rad/s, IMU frame): "
            + " ".join(f"{b:.5f}" for b in bias[0])
            + " +- "
            + " ".join(f"{b:.5f}" for b in bias[1])
            + f" ({c.get('gyro_bias_rejected', 0)} pairs of {unit} rejected)",
            file=text,
        )


def _print_accuracy(
    solver: str, summary: dict, n: int, text, solved: int = 0, unit: str = "frames"
) -> None:
    """The errors against ground truth of a replay's report (none without it), how many of
    the ``solved`` (rig) frames had no ground truth at their stamp (left out of the errors:
    a rig frame stamped by a camera whose clock is off), and after a rigid fit of the frames
    when the ground truth is in another frame."""
    from ..accuracy import format_summary

    if not summary.get("frames"):
        return
    print(format_summary(solver, summary, n), file=text)
    if solved > summary["frames"]:
        print(
            f"  {solved - summary['frames']} posed {unit} have no ground truth at their stamp "
            "and are not in these errors",
            file=text,
        )
    fit = summary.get("frame_fit")
    if fit and fit["other_frame"]:
        print(
            f"  the ground truth is in another frame than the map's (a rigid fit of the "
            f"frames moves them {fit['rot_deg']:.3g} deg, {100 * fit['pos_m']:.3g} cm); "
            "after that fit: " + format_summary(solver, fit["aligned"]),
            file=text,
        )


def _report(solver, n, solved, failures, summary, out_bag, out_csv, **more) -> dict:
    """The ``--json`` report of a camera's or a rig's replay (a rig's adds ``more``)."""
    return {
        "solver": solver,
        "frames_total": n,
        "solved": solved,
        "failures": failures,
        **summary,
        **more,
        "out_bag": str(out_bag) if out_bag else None,
        "csv": str(out_csv) if out_csv else None,
    }


_RIG_SOURCE = (
    "a rig bag is replayed from each camera's images through its front end when -p frontend "
    "is set (-p frontend_map: the bag's markers.yaml), else from its correspondences"
)
#: the options of a single camera's replay that a rig bag has no use for, and why
_RIG_REFUSED_OPTIONS = (
    ("solver", "--solver", "the rig estimator solves every camera's points at once, gr6p_1lin"),
    ("source", "--source", _RIG_SOURCE),
    ("landmarks", "--landmarks", _RIG_SOURCE),
    ("image_topic", "--image-topic", "each camera's images are <namespace>/<camera>/image_raw"),
    ("imu_topic", "--imu-topic", "the rig's gyro is <namespace>/imu"),
)


def _no_camera_options(args: argparse.Namespace) -> None:
    """Refuse a single camera's options given for a rig bag (:data:`_RIG_REFUSED_OPTIONS`),
    which the rig's replay would otherwise ignore.

    Raises:
        CliError: one of them given, naming it and what a rig bag takes instead.
    """
    for dest, flag, why in _RIG_REFUSED_OPTIONS:
        if getattr(args, dest, None) is not None:
            raise A.CliError(f"{flag} does not apply to a rig bag: {why}")
