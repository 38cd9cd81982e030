"""``rs-localizer make-bag``: a synthetic rolling-shutter sequence (correspondences, keypoints,
ground truth, optionally an IMU) written as a ROS 2 bag."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..camera import READOUT_DIRECTIONS
from . import args as A

__all__ = ["register", "run"]

HELP = "write a synthetic rolling-shutter sequence (correspondences, ground truth) as a bag"


def _frame_list(text: str) -> tuple[int, ...]:
    from ..sim.bag_sequence import parse_frame_list

    try:
        return parse_frame_list(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``make-bag`` subcommand to ``sub`` (``func`` = :func:`run`)."""
    m = sub.add_parser(
        "make-bag",
        help=HELP,
        description="Simulate a rolling-shutter camera moving through a scene of landmarks and "
        "write its frames as a bag: <ns>/correspondences (u, v, x, y, z), <ns>/keypoints "
        "(u, v, id; the landmarks in BAG/landmarks.csv), <ns>/camera_info, the ground truth "
        "and sequence.json (RS timing and settings, read by replay).",
        formatter_class=A.HelpFormatter,
    )
    m.add_argument("out", help="output bag directory")
    m.add_argument("--frames", type=A.positive_int, default=40, help="frames to generate")
    m.add_argument("--points", type=A.positive_int, default=500, help="correspondences per frame")
    m.add_argument("--fps", type=A.positive_float, default=30.0, help="frame rate (Hz)")
    m.add_argument("--noise", type=A.nonneg_float, default=0.5, help="pixel noise sigma (px)")
    m.add_argument("--outliers", type=A.probability, default=0.2, help="outlier fraction (0..1)")
    m.add_argument("--seed", type=A.nonneg_int, default=0, help="random seed")
    m.add_argument(
        "--line-delay",
        type=A.nonneg_float,
        default=30e-6,
        help="s per row (the 1280x720 camera: 30e-6 = 21.6 ms readout)",
    )
    m.add_argument(
        "--direction",
        default="top_to_bottom",
        choices=list(READOUT_DIRECTIONS),
        help="readout direction",
    )
    m.add_argument(
        "--reference-row",
        type=A.finite_float,
        default=-1.0,
        help="row of the ground-truth pose (-1: image centre)",
    )
    m.add_argument("--stamp-row", type=A.finite_float, default=0.0, help="row of the header stamp")
    m.add_argument(
        "--motion-scale",
        type=A.nonneg_float,
        default=1.0,
        help="scale of the rotational motion (1: ~1.5 rad/s)",
    )
    m.add_argument("--landmarks", type=A.positive_int, default=6000, help="landmarks in the scene")
    m.add_argument(
        "--scene",
        choices=["corridor", "plane", "board"],
        default="corridor",
        help="corridor: 3D landmarks along a walk (default); plane: one wall ahead "
        "(planar scene); board: a 6x7-corner checkerboard under hand-held shake "
        "(42 points; see docs/planar.md)",
    )
    m.add_argument(
        "--storage", choices=["mcap", "sqlite3"], default="mcap", help="bag storage format"
    )
    m.add_argument("--namespace", default="/camera", help="namespace of the camera topics")
    m.add_argument(
        "--no-distortion",
        action="store_true",
        help="camera without lens distortion (default: mild plumb_bob)",
    )
    m.add_argument("--no-ids", action="store_true", help="omit the id field")
    m.add_argument("--scores", action="store_true", help="add a score field")
    m.add_argument("--no-keypoints", action="store_true", help="omit the keypoints topic")
    m.add_argument(
        "--no-correspondences", action="store_true", help="omit the correspondences topic"
    )
    m.add_argument(
        "--start-time",
        type=A.nonneg_float,
        default=1_700_000_000.0,
        help="capture time of the first frame (s since the epoch)",
    )
    m.add_argument(
        "--motion",
        default="walk",
        choices=["walk", "car", "shake", "pan"],
        help="walk (default: look-around walk), car (near-pure translation at "
        "5 m/s), shake (hand-held shake, ~30 rad/s^2), pan (turning ~1.5 rad/s)",
    )
    m.add_argument(
        "--drop-frames",
        type=_frame_list,
        default=(),
        metavar="LIST",
        help="frame indices to leave out, e.g. 10,20-23 (dropped frames; default: none)",
    )
    m.add_argument(
        "--teleport",
        type=A.nonneg_int,
        default=None,
        metavar="N",
        help="the camera jumps 8 m and turns 0.7 rad just before frame N",
    )
    m.add_argument(
        "--no-gt-twist",
        action="store_true",
        help="omit /ground_truth/twist (a bag without ground-truth velocities)",
    )
    m.add_argument(
        "--imu-rate",
        type=A.nonneg_float,
        default=0.0,
        help="also write a sensor_msgs/Imu topic at this rate (Hz; gyro with "
        "bias and noise, IMU axes x forward, y left, z up; 0: no IMU; with --rig: the rig's "
        "gyro on <namespace>/imu, noise only, its axes base_frame's)",
    )
    m.add_argument("--imu-topic", default="/imu/data", help="topic of --imu-rate")
    m.add_argument(
        "--imu-time-offset",
        type=A.finite_float,
        default=0.0,
        metavar="S",
        help="with --imu-rate: stamp the IMU on a clock S seconds behind the camera's "
        "(t_cam = t_imu + S, the node's imu.time_offset)",
    )
    m.add_argument(
        "--rig",
        type=A.positive_int,
        default=None,
        metavar="N",
        help="a rig bag instead: N (1-4) unsynchronized cameras (front, left, right, back; "
        "their own line delays, readout directions and first frames 4 ms apart) on one body "
        "walking the corridor, --frames per camera, topics <ns>/<camera>/correspondences and "
        "camera_info (--namespace default /rig), and BAG/rig_params.yaml, the node's rig "
        "parameters (docs/rig_node.md)",
    )
    m.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    m.add_argument("--quiet", action="store_true", help="no progress bar")
    m.set_defaults(func=run)
    return m


def run(args: argparse.Namespace) -> int:
    """Simulate (:func:`rs_localizer.sim.bag_sequence.simulate_bag_sequence`) and write the
    bag; returns 0. Raises CliError / ValueError for options that do not fit together or an
    output that cannot be written (checked before the simulation)."""
    A.output_dir(args.out, args.overwrite, "bag directory")
    if args.rig is not None:
        return _run_rig(args)
    if args.motion != "walk" and args.scene == "board":
        raise A.CliError(
            f"--motion applies to the corridor and plane scenes, not to {args.scene!r}"
        )
    from tqdm import tqdm

    from ..ros.bags.bag_io import write_sequence_bag
    from ..sim.bag_sequence import simulate_bag_sequence

    bar = tqdm(total=args.frames, desc="simulating", unit="frame", disable=args.quiet)
    seq = simulate_bag_sequence(
        frames=args.frames,
        points=args.points,
        fps=args.fps,
        noise=args.noise,
        outliers=args.outliers,
        seed=args.seed,
        line_delay=args.line_delay,
        direction=args.direction,
        reference_row=None if args.reference_row < 0 else args.reference_row,
        stamp_row=args.stamp_row,
        motion_scale=args.motion_scale,
        landmarks=args.landmarks,
        scene=args.scene,
        distortion=not args.no_distortion,
        start_time=args.start_time,
        motion=args.motion,
        drop_frames=args.drop_frames,
        teleport=args.teleport,
        imu_rate=args.imu_rate,
        imu_topic=args.imu_topic,
        imu_time_offset=args.imu_time_offset,
        progress=lambda k: bar.update(1),
    )
    bar.close()
    out = write_sequence_bag(
        args.out,
        seq.frames,
        seq.scene,
        seq.camera,
        storage=args.storage,
        namespace=args.namespace,
        with_ids=not args.no_ids,
        with_scores=args.scores,
        keypoints=not args.no_keypoints,
        correspondences=not args.no_correspondences,
        stamp_row=args.stamp_row,
        settings=seq.settings,
        overwrite=args.overwrite,
        gt_twist=not args.no_gt_twist,
        imu=seq.imu,
        imu_topic=args.imu_topic,
        extra=seq.extra,
    )
    size = sum(p.stat().st_size for p in Path(out).rglob("*") if p.is_file())
    cam = seq.camera
    print(
        f"wrote {out} ({len(seq.frames)} frames x {args.points} points, "
        f"{size / 1024:.0f} KiB, {args.storage}); line delay {cam.line_delay * 1e6:.1f} "
        f"us/row, readout {cam.readout_time * 1e3:.1f} ms"
    )
    return 0


def _run_rig(args: argparse.Namespace) -> int:
    """``make-bag --rig N``: a rig bag (:func:`rs_localizer.ros.bags.bag_io.write_rig_bag`)."""
    if not 1 <= args.rig <= 4:
        raise A.CliError(f"--rig takes 1 to 4 cameras, got {args.rig}")
    if args.scene != "corridor" or args.motion != "walk" or args.imu_time_offset != 0:
        raise A.CliError("--rig walks the corridor: without --scene, --motion or --imu-time-offset")
    from ..ros.bags.bag_io import write_rig_bag
    from ..sim.trajectory import default_rig, generate_rig_video

    cams = default_rig(args.rig)
    cams = [type(c)(**{**c.__dict__, "fps": args.fps}) for c in cams]
    t0 = int(round(args.start_time * 1e9))
    frames, _, traj = generate_rig_video(
        cams,
        duration=args.frames / args.fps,
        num_points=args.points,
        noise_px=args.noise,
        outlier_ratio=args.outliers,
        seed=args.seed,
        t0_ns=t0,
        stamp_row=args.stamp_row,
    )
    ns = "/rig" if args.namespace == "/camera" else args.namespace
    imu = None
    if args.imu_rate > 0:  # (a gyro on the rig, its axes the base frame's)
        import numpy as np

        from ..sim.trajectory import rig_gyro

        g = rig_gyro(traj, args.frames / args.fps, args.imu_rate, seed=args.seed, t0_ns=t0)
        imu = (g[0], g[1], np.eye(3))
    out = write_rig_bag(
        args.out,
        frames,
        cams,
        traj,
        t0_ns=t0,
        namespace=ns,
        stamp_row=args.stamp_row,
        storage=args.storage,
        overwrite=args.overwrite,
        settings={
            "points": args.points,
            "noise": args.noise,
            "outliers": args.outliers,
            "seed": args.seed,
            "fps": args.fps,
            "imu_rate": args.imu_rate,
        },
        imu=imu,
    )
    print(
        f"wrote {out}: a rig of {args.rig} cameras ({', '.join(c.name for c in cams)}), "
        f"{len(frames)} frames, {args.storage}; node parameters: {out / 'rig_params.yaml'}"
    )
    return 0
