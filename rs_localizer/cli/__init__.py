"""``rs-localizer``: bag tools for the rolling-shutter localizer.

    rs-localizer make-bag OUT [--frames 40 --points 500 --storage mcap ...]
    rs-localizer play BAG [--rate 1.0 | --lockstep] [--topics ...] [--remap FROM:=TO ...]
    rs-localizer replay BAG [--solver r6p_1lin] [--out DIR] [--csv FILE]
    rs-localizer demo [--bag data/sample] [--params config/rs_localizer.yaml] [--no-images]
    rs-localizer render-bag OUT [--scene aruco_room --motion shake --frames 20 ...]
    rs-localizer marker-map SCENE OUT
    rs-localizer experiments [--quick] [--out docs/experiments]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..solvers.registry import SOLVER_NAMES

__all__ = ["main", "build_parser"]


def _make_bag(args) -> int:
    from ..ros.bag_io import write_sequence_bag
    from ..sim.trajectory import SequenceConfig, default_camera, generate_sequence

    ref = None if args.reference_row < 0 else args.reference_row
    camera = default_camera(line_delay=args.line_delay, reference_row=ref,
                            distortion=not args.no_distortion, readout=args.direction)
    cfg = SequenceConfig(num_frames=args.frames, num_points=args.points, fps=args.fps,
                         noise_px=args.noise, outlier_ratio=args.outliers, seed=args.seed,
                         stamp_row=args.stamp_row, motion_scale=args.motion_scale,
                         num_landmarks=args.landmarks,
                         t0_ns=int(round(args.start_time * 1e9)))
    frames, scene, camera, _ = generate_sequence(cfg, camera=camera)
    settings = {k: getattr(cfg, k) for k in ("num_frames", "num_points", "fps", "noise_px",
                                             "outlier_ratio", "seed", "motion_scale",
                                             "num_landmarks")}
    out = write_sequence_bag(args.out, frames, scene, camera, storage=args.storage,
                             namespace=args.namespace, with_ids=not args.no_ids,
                             with_scores=args.scores, keypoints=not args.no_keypoints,
                             correspondences=not args.no_correspondences,
                             stamp_row=args.stamp_row, settings=settings,
                             overwrite=args.overwrite)
    size = sum(p.stat().st_size for p in Path(out).rglob("*") if p.is_file())
    print(f"wrote {out} ({len(frames)} frames x {args.points} points, "
          f"{size / 1024:.0f} KiB, {args.storage}); line delay {camera.line_delay * 1e6:.1f} "
          f"us/row, readout {camera.readout_time * 1e3:.1f} ms")
    return 0


def _parse_remap(items):
    out = {}
    for it in items or ():
        if ":=" not in it:
            raise SystemExit(f"--remap expects FROM:=TO, got {it!r}")
        a, b = it.split(":=", 1)
        out[a] = b
    return out


def _play(args) -> int:
    from ..ros.play import play

    res = play(args.bag, rate=args.rate, lockstep=args.lockstep, topics=args.topics,
               remap=_parse_remap(args.remap), output_topics=tuple(args.output_topic),
               timeout=args.timeout, retries=args.retries,
               wait_subscribers=args.wait if args.wait is not None else
               (30.0 if args.lockstep else 2.0),
               reliable=not args.best_effort, limit=args.limit, loop=args.loop)
    msg = f"published {res.published} messages, {len(res.frames)} frames in {res.wall_time:.2f} s"
    if args.lockstep:
        lat = res.latencies
        msg += f"; {res.answered} answered, {res.timeouts} timed out"
        if len(lat):
            import numpy as np

            msg += (f"; {len(res.frames) / max(res.wall_time, 1e-9):.1f} Hz, latency median "
                    f"{np.median(lat) * 1e3:.2f} ms p99 {np.percentile(lat, 99) * 1e3:.2f} ms")
    print(msg)
    return 0 if not args.lockstep or res.timeouts == 0 else 1


def _replay(args) -> int:
    from ..estimation.estimate import EstimateOptions
    from ..accuracy import format_summary
    from ..ros.replay import replay

    opts = EstimateOptions(threshold_px=args.threshold, max_iterations=args.max_iterations,
                           confidence=args.confidence, min_inliers=args.min_inliers,
                           seed=args.seed, refine=not args.no_refine)
    out_bag = Path(args.out) if args.out else None
    res = replay(args.bag, solver=args.solver, options=opts, source=args.source,
                 line_delay=args.line_delay, readout_time=args.readout_time,
                 direction=args.direction, reference_row=args.reference_row,
                 stamp_row=args.stamp_row, landmarks_file=args.landmarks, out_bag=out_bag,
                 out_csv=args.csv, storage=args.storage, overwrite=args.overwrite,
                 progress=None if args.quiet else sys.stderr)
    n = len(res.rows)
    print(f"{args.solver}: solved {res.solved}/{n} frames"
          + (f"; failures {res.failures}" if res.failures else ""))
    if res.summary.get("frames"):
        print(format_summary(args.solver, res.summary, n))
    if args.json:
        print(json.dumps(res.summary, indent=2))
    if res.out_bag:
        print(f"estimates: {res.out_bag}")
    if res.out_csv:
        print(f"csv: {res.out_csv}")
    return 0 if res.solved else 1


def _demo(args) -> int:
    from ..evaluation.demo import run_demo

    return run_demo(bag=args.bag, params=args.params, compare=args.compare,
                    per_frame=not args.summary_only, timeout=args.timeout,
                    images=args.images, image_bag=args.image_bag)


def _render_bag(args) -> int:
    from . import render_bag as bagout

    return int(bagout.run_from_args(args) or 0)


def _marker_map(args) -> int:
    from ..sim.render.scene import load_scene, save_marker_map

    scene = load_scene(args.scene)
    out = save_marker_map(args.out, scene)
    print(f"wrote {out}: {len(scene.markers)} markers ({scene.dictionary}) of scene {scene.name}")
    return 0


def _experiments(args) -> int:
    from ..evaluation.experiments import run

    return run(args)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="rs-localizer", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True)

    m = sub.add_parser("make-bag", help="write a synthetic rolling-shutter sequence as a bag")
    m.add_argument("out", help="output bag directory")
    m.add_argument("--frames", type=int, default=40)
    m.add_argument("--points", type=int, default=500, help="correspondences per frame")
    m.add_argument("--fps", type=float, default=30.0)
    m.add_argument("--noise", type=float, default=0.5, help="pixel noise sigma (px)")
    m.add_argument("--outliers", type=float, default=0.2, help="outlier fraction")
    m.add_argument("--seed", type=int, default=0)
    m.add_argument("--line-delay", type=float, default=30e-6, help="s per row")
    m.add_argument("--direction", default="top_to_bottom",
                   choices=["top_to_bottom", "bottom_to_top", "left_to_right", "right_to_left"])
    m.add_argument("--reference-row", type=float, default=-1.0,
                   help="row of the ground-truth pose (-1: image centre)")
    m.add_argument("--stamp-row", type=float, default=0.0, help="row of the header stamp")
    m.add_argument("--motion-scale", type=float, default=1.0,
                   help="scale of the rotational motion (1: ~1.5 rad/s)")
    m.add_argument("--landmarks", type=int, default=6000, help="landmarks in the scene")
    m.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap")
    m.add_argument("--namespace", default="/camera")
    m.add_argument("--no-distortion", action="store_true")
    m.add_argument("--no-ids", action="store_true", help="omit the id field")
    m.add_argument("--scores", action="store_true", help="add a score field")
    m.add_argument("--no-keypoints", action="store_true", help="omit the keypoints topic")
    m.add_argument("--no-correspondences", action="store_true",
                   help="omit the correspondences topic")
    m.add_argument("--start-time", type=float, default=1_700_000_000.0,
                   help="capture time of the first frame (s since the epoch)")
    m.add_argument("--overwrite", action="store_true")
    m.set_defaults(func=_make_bag)

    pl = sub.add_parser("play", help="publish a bag into the live ROS graph")
    pl.add_argument("bag")
    pl.add_argument("--rate", type=float, default=1.0, help="time scale (0: as fast as possible)")
    pl.add_argument("--lockstep", action="store_true",
                    help="wait for the output of each frame before sending the next")
    pl.add_argument("--output-topic", action="append", default=None,
                    help="pose topic(s) to wait for in lock-step (default /camera/pose)")
    pl.add_argument("--timeout", type=float, default=2.0, help="lock-step wait per frame (s)")
    pl.add_argument("--retries", type=int, default=1, help="republish a frame without answer")
    pl.add_argument("--topics", nargs="+", default=None, help="only these bag topics")
    pl.add_argument("--remap", nargs="+", default=None, metavar="FROM:=TO")
    pl.add_argument("--wait", type=float, default=None,
                    help="wait for subscribers (s; default 30 in lock-step, else 2)")
    pl.add_argument("--best-effort", action="store_true", help="publish best effort")
    pl.add_argument("--limit", type=int, default=None, help="stop after N frames")
    pl.add_argument("--loop", type=int, default=1, help="play N times")
    pl.set_defaults(func=_play)

    r = sub.add_parser("replay", help="run the estimator over a bag offline")
    r.add_argument("bag")
    r.add_argument("--solver", default="r6p_1lin", choices=SOLVER_NAMES,
                   help="minimal solver (p3p = global shutter)")
    r.add_argument("--source", choices=["correspondences", "keypoints"],
                   default="correspondences")
    r.add_argument("--landmarks", default=None, help="CSV id,x,y,z (keypoints source)")
    r.add_argument("--out", default=None, help="write estimates to this bag directory")
    r.add_argument("--csv", default=None, help="write one line per frame")
    r.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap")
    r.add_argument("--threshold", type=float, default=2.0, help="RANSAC threshold (px)")
    r.add_argument("--max-iterations", type=int, default=1000)
    r.add_argument("--confidence", type=float, default=0.9999)
    r.add_argument("--min-inliers", type=int, default=12)
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--no-refine", action="store_true")
    r.add_argument("--line-delay", type=float, default=None, help="s/row (default: bag)")
    r.add_argument("--readout-time", type=float, default=None, help="s/frame, wins if > 0")
    r.add_argument("--direction", default=None)
    r.add_argument("--reference-row", type=float, default=None)
    r.add_argument("--stamp-row", type=float, default=None)
    r.add_argument("--json", action="store_true", help="print the summary as JSON")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.add_argument("--overwrite", action="store_true")
    r.set_defaults(func=_replay)

    d = sub.add_parser("demo", help="node + sample bag over DDS, accuracy vs ground truth")
    d.add_argument("--bag", default=None, help="default: data/sample")
    d.add_argument("--params", default=None, help="default: config/rs_localizer.yaml")
    d.add_argument("--compare", default="p3p", help="second solver ('' to skip)")
    d.add_argument("--summary-only", action="store_true")
    d.add_argument("--timeout", type=float, default=5.0)
    d.add_argument("--images", action=argparse.BooleanOptionalAction, default=True,
                   help="also run the image-mode demo (front end in the node)")
    d.add_argument("--image-bag", default=None, help="default: data/sample_images")
    d.set_defaults(func=_demo)

    from . import render_bag as bagout

    mm = sub.add_parser("marker-map", help="write the ArUco marker map of a scene (for the "
                        "node's frontend_map / the aruco front end)")
    mm.add_argument("scene", help="built-in scene (aruco_room, textured_room) or scene YAML")
    mm.add_argument("out", help="marker map YAML to write")
    mm.set_defaults(func=_marker_map)

    rb = sub.add_parser("render-bag", help="render a rolling-shutter image sequence to a bag "
                        "(images, camera_info, front-end correspondences, ground truth)")
    bagout.add_arguments(rb, positional_out=True)
    rb.set_defaults(func=_render_bag)

    from ..evaluation.experiments import add_arguments as experiment_arguments

    ex = sub.add_parser("experiments", help="reproduce the paper's synthetic experiments "
                        "(PNG plots + markdown report)")
    experiment_arguments(ex)
    ex.set_defaults(func=_experiments)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if getattr(args, "output_topic", "unset") is None:
        args.output_topic = ["/camera/pose"]
    try:
        return int(args.func(args) or 0)
    except (FileExistsError, FileNotFoundError, ValueError) as e:
        print(f"rs-localizer {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
