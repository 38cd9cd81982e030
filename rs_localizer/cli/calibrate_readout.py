"""``rs-localizer calibrate-readout``: the line delay (readout time) of a rolling-shutter camera
from a bag in which it rotates, optionally with a gyro (camera-IMU rotation, bias, time offset)."""

from __future__ import annotations

import argparse
import json
import sys

from ..camera import READOUT_DIRECTIONS
from ..solvers.registry import SOLVER_NAMES
from . import args as A

__all__ = ["register", "run"]

HELP = "estimate the camera's line delay (readout time) from a bag with rotation"


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``calibrate-readout`` subcommand to ``sub`` (``func`` = :func:`run`)."""
    cr = sub.add_parser(
        "calibrate-readout",
        help=HELP,
        description="Estimate the camera's line delay (s per line; the readout time is the line "
        "delay times the lines) from a bag in which the camera rotates, ignoring the RS timing "
        "the bag states: from the rotation between frames, or with --imu-topic from a gyro "
        "(then also the camera-IMU rotation, the gyro bias and the time offset).",
        formatter_class=A.HelpFormatter,
    )
    cr.add_argument("bag", help="bag directory (or its .mcap / .db3 file) with a rotating sequence")
    cr.add_argument(
        "--source",
        choices=["correspondences", "keypoints", "image"],
        default="correspondences",
        help="frames from correspondence clouds, keypoints + landmark map, or "
        "images through a front end",
    )
    cr.add_argument(
        "--json",
        action="store_true",
        help="print one JSON object on stdout (line_delay, line_delay_std, "
        "frames_used, observable); the summary goes to stderr",
    )
    cr.add_argument(
        "--imu-topic",
        default=None,
        help="sensor_msgs/Imu topic: use its gyro instead of the rotation between "
        "frames (camera and IMU rigidly mounted; their rotation, the gyro bias and the "
        "gyro's time offset within +-50 ms are estimated)",
    )
    cr.add_argument(
        "--solver",
        default="r6p_1lin",
        choices=SOLVER_NAMES,
        help="RS solver of the per-frame estimates",
    )
    cr.add_argument("--threshold", type=A.positive_float, default=2.0, help="RANSAC threshold (px)")
    cr.add_argument(
        "--direction",
        default=None,
        choices=list(READOUT_DIRECTIONS),
        help="readout direction (default: the bag's sequence.json)",
    )
    cr.add_argument(
        "--stamp-row",
        type=A.finite_float,
        default=None,
        help="row whose capture time is the header stamp (gyro only; default: "
        "the bag's sequence.json, else 0)",
    )
    cr.add_argument("--landmarks", default=None, help="CSV id,x,y,z (keypoints source)")
    cr.add_argument(
        "--frontend",
        default=None,
        choices=["aruco", "features"],
        help="image source: front end (default: the bag's sequence.json)",
    )
    cr.add_argument("--frontend-map", default=None, help="image source: front-end map")
    cr.set_defaults(func=run)
    return cr


def run(args: argparse.Namespace) -> int:
    """Calibrate and print; returns 0, or 3 when the line delay is not observable. Raises
    CliError for a bag, landmark or map file that cannot be used (before any frame)."""
    path = A.bag_dir(args.bag, require_messages=True)
    if args.landmarks is not None:
        A.input_file(args.landmarks, "landmark CSV (id,x,y,z)")
    if args.frontend_map is not None:
        A.input_file(args.frontend_map, "front-end map")
    if args.imu_topic is not None:
        from ..ros.bags.bag_io import IMU, bag_topics

        if bag_topics(path).get(args.imu_topic) != IMU:
            raise A.CliError(f"{path}: no sensor_msgs/Imu topic {args.imu_topic!r}")
    import numpy as np

    from ..calibration.readout import calibrate_line_delay
    from ..ros.bags.bag_frames import read_bag_frames, read_gyro
    from ..runtime.background import frames_alone_options

    bag = read_bag_frames(
        path,
        source=args.source,
        landmarks_file=args.landmarks,
        frontend=args.frontend,
        frontend_map=args.frontend_map,
        direction=args.direction,
    )
    gyro = read_gyro(path, args.imu_topic) if args.imu_topic else None
    stamp_row = bag.stamp_row if args.stamp_row is None else args.stamp_row
    options = frames_alone_options(args.threshold, args.solver)
    res = calibrate_line_delay(
        bag.frames,
        bag.camera,
        solver=args.solver,
        options=options,
        gyro=gyro,
        stamp_row=stamp_row,
    )
    cam = bag.camera
    lines = [
        f"calibrate-readout {args.bag}: {len(bag.frames)} frames ({args.source}"
        + (f", gyro {args.imu_topic}" if gyro is not None else ", rotation between frames")
        + f"), {res.frames_failed} not solved"
        + (f", skipped {bag.skipped}" if bag.skipped else "")
    ]
    if res.observable:
        lines.append(
            f"line delay {res.line_delay * 1e6:.4f} +- {res.line_delay_std * 1e6:.4f} "
            f"us/line ({res.line_delay_std / res.line_delay * 100:.2f} %), readout "
            f"{res.readout_time * 1e3:.3f} ms over {cam.lines} lines; "
            f"{res.samples} samples from {res.frames_used} frames, rotation rms "
            f"{res.rotation_rms:.2f} rad/s"
        )
    else:
        lines.append(f"not observable: {res.reason}")
    if res.camera_imu_rotation is not None:
        lines.append(
            "camera <- IMU rotation (estimated): "
            + np.array2string(res.camera_imu_rotation, precision=3, suppress_small=True).replace(
                "\n", ""
            )
        )
    lines += res.gyro_lines()  # each with its std and whether the motion determined it
    if res.camera_imu_rotation is not None and res.gyro_bias is not None:
        from ..ros.conversions import quaternion_from_matrix

        q = quaternion_from_matrix(res.camera_imu_rotation)
        if res.time_offset is not None:
            lines.append(
                f"gyro time offset {res.time_offset * 1e3:.3f} +- "
                f"{res.time_offset_std * 1e3:.3f} ms (t_cam = t_imu + offset)"
            )
        else:
            lines.append(f"gyro time offset not observable: {res.time_offset_reason}")
        lines.append("for the node's parameters:")
        unsure = "  # not determined by this motion: see WARNING above"
        lines.append(
            "  imu.rotation: ["
            + ", ".join(f"{v:.6f}" for v in q)
            + "]"
            + ("" if res.camera_imu_rotation_observable else unsure)
        )
        lines.append(
            "  imu.gyro_bias: ["
            + ", ".join(f"{v:.6f}" for v in res.gyro_bias)
            + "]"
            + ("" if res.gyro_bias_observable else unsure)
        )
        sigma = float(np.max(res.gyro_bias_std)) if res.gyro_bias_std is not None else np.inf
        if not res.gyro_bias_observable and np.isfinite(sigma):  # (the default: 0.005)
            lines.append(f"  imu.gyro_bias_sigma: {sigma:.6f}")
        if res.time_offset is not None:
            lines.append(f"  imu.time_offset: {res.time_offset:.6f}")
        else:
            lines.append("  # imu.time_offset: not estimated (see above)")
    text = "\n".join(lines)
    if args.json:
        print(text, file=sys.stderr)
        print(json.dumps(res.as_dict()))
    else:
        print(text)
    return 0 if res.observable else 3
