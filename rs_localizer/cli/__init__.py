"""``rs-localizer``: bag tools for the rolling-shutter localizer.

rs-localizer make-bag OUT [--frames 40 --points 500 --scene corridor|plane|board ...]
rs-localizer play BAG [--rate 1.0 | --lockstep] [--topics ...] [--remap FROM:=TO ...]
rs-localizer replay BAG [--params-file config/rs_localizer.yaml] [-p NAME:=VALUE]
                        [--solver r6p_1lin] [--out DIR [--debug-outputs]] [--csv FILE] [--json]
rs-localizer export-image BAG OUT.png [--topic /rs_localizer/debug_image] [--index 0]
rs-localizer demo [--bag data/sample] [--params config/rs_localizer.yaml] [--no-images]
rs-localizer render-bag OUT [--scene aruco_room --motion shake --frames 20 ...]
rs-localizer marker-map SCENE OUT
rs-localizer map-markers IMAGES -o MAP.yaml --camera CAMERA.yaml --marker-size S [--anchor ID]
rs-localizer map-features (--colmap MODEL_DIR | --images DIR --camera CAMERA.yaml) -o MAP.npz
rs-localizer experiments [--quick] [--out docs/experiments]
rs-localizer compile [--solvers r6p_1lin] [--jobs 2]   (once after installing: JIT kernels)
rs-localizer calibrate-readout BAG [--source correspondences|keypoints|image] [--json]
    [--imu-topic T]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..camera import READOUT_DIRECTIONS
from ..solvers.registry import SOLVER_NAMES, solver_info

__all__ = ["build_parser", "main"]


def _frame_list(text: str) -> tuple:
    """``"3,5-7"`` -> (3, 5, 6, 7)."""
    out = []
    for part in filter(None, (p.strip() for p in text.split(","))):
        a, _, b = part.partition("-")
        out.extend(range(int(a), int(b or a) + 1))
    return tuple(out)


def _make_bag(args) -> int:
    import numpy as np

    from ..ros.bag_io import write_sequence_bag
    from ..sim.planar import sequence_scene
    from ..sim.trajectory import (
        R_IMU_CAMERA,
        SequenceConfig,
        Teleport,
        default_camera,
        generate_sequence,
        imu_samples,
        make_trajectory,
    )

    ref = None if args.reference_row < 0 else args.reference_row
    camera = default_camera(
        line_delay=args.line_delay,
        reference_row=ref,
        distortion=not args.no_distortion,
        readout=args.direction,
    )
    drop = _frame_list(args.drop_frames) if args.drop_frames else ()
    cfg = SequenceConfig(
        num_frames=args.frames,
        num_points=args.points,
        fps=args.fps,
        noise_px=args.noise,
        outlier_ratio=args.outliers,
        seed=args.seed,
        stamp_row=args.stamp_row,
        motion_scale=args.motion_scale,
        num_landmarks=args.landmarks,
        t0_ns=int(round(args.start_time * 1e9)),
        drop_frames=drop,
    )
    scene, trajectory = sequence_scene(
        args.scene, np.random.default_rng([args.seed, 16]), args.landmarks, args.motion_scale
    )
    if args.motion != "walk":
        if trajectory is not None:
            raise ValueError(
                f"--motion applies to the corridor and plane scenes, not to {args.scene!r}"
            )
        trajectory = make_trajectory(args.motion, args.motion_scale)
    if args.teleport is not None:  # jump in the gap before frame N's readout
        trajectory = Teleport(
            trajectory or make_trajectory("walk", args.motion_scale),
            time=(args.teleport - 0.25) / args.fps,
        )
    frames, scene, camera, trajectory = generate_sequence(
        cfg, camera=camera, trajectory=trajectory, scene=scene
    )
    settings = {
        k: getattr(cfg, k)
        for k in (
            "num_frames",
            "num_points",
            "fps",
            "noise_px",
            "outlier_ratio",
            "seed",
            "motion_scale",
            "num_landmarks",
        )
    }
    if args.scene != "corridor":
        settings["scene"] = args.scene
    # new options are recorded only when used (the committed bags stay as they are)
    if args.motion != "walk":
        settings["motion"] = args.motion
    if drop:
        settings["drop_frames"] = list(drop)
    if args.teleport is not None:
        settings["teleport_before_frame"] = args.teleport
    extra, imu = {}, None
    if args.imu_rate:
        t, om, fo = imu_samples(
            trajectory, -0.1, args.frames / args.fps + 0.1, args.imu_rate, seed=args.seed
        )
        # (stamped on the IMU's clock: t_cam = t_imu + time_offset)
        imu = (cfg.t0_ns + np.round((t - args.imu_time_offset) * 1e9).astype(np.int64), om, fo)
        extra["imu"] = {
            "topic": args.imu_topic,
            "rate": args.imu_rate,
            "rotation_imu_from_camera": R_IMU_CAMERA.tolist(),
        }
        if args.imu_time_offset:
            extra["imu"]["time_offset"] = args.imu_time_offset
    out = write_sequence_bag(
        args.out,
        frames,
        scene,
        camera,
        storage=args.storage,
        namespace=args.namespace,
        with_ids=not args.no_ids,
        with_scores=args.scores,
        keypoints=not args.no_keypoints,
        correspondences=not args.no_correspondences,
        stamp_row=args.stamp_row,
        settings=settings,
        overwrite=args.overwrite,
        gt_twist=not args.no_gt_twist,
        imu=imu,
        imu_topic=args.imu_topic,
        extra=extra,
    )
    size = sum(p.stat().st_size for p in Path(out).rglob("*") if p.is_file())
    print(
        f"wrote {out} ({len(frames)} frames x {args.points} points, "
        f"{size / 1024:.0f} KiB, {args.storage}); line delay {camera.line_delay * 1e6:.1f} "
        f"us/row, readout {camera.readout_time * 1e3:.1f} ms"
    )
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

    res = play(
        args.bag,
        rate=args.rate,
        lockstep=args.lockstep,
        topics=args.topics,
        remap=_parse_remap(args.remap),
        output_topics=tuple(args.output_topic),
        timeout=args.timeout,
        retries=args.retries,
        wait_subscribers=args.wait if args.wait is not None else (30.0 if args.lockstep else 2.0),
        reliable=not args.best_effort,
        limit=args.limit,
        loop=args.loop,
    )
    msg = f"published {res.published} messages, {len(res.frames)} frames in {res.wall_time:.2f} s"
    if args.lockstep:
        lat = res.latencies
        msg += f"; {res.answered} answered, {res.timeouts} timed out"
        if len(lat):
            import numpy as np

            msg += (
                f"; {len(res.frames) / max(res.wall_time, 1e-9):.1f} Hz, latency median "
                f"{np.median(lat) * 1e3:.2f} ms p99 {np.percentile(lat, 99) * 1e3:.2f} ms"
            )
    print(msg)
    return 0 if not args.lockstep or res.timeouts == 0 else 1


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


def _param_overrides(items) -> dict:
    """``NAME:=VALUE`` (the value in YAML, as ``ros2 run ... -p``) -> {NAME: value}."""
    import yaml

    out = {}
    for it in items or ():
        name, sep, text = it.partition(":=")
        if not sep or not name.strip():
            raise ValueError(f"--param expects NAME:=VALUE, got {it!r}")
        out[name.strip()] = yaml.safe_load(text)
    return out


def _replay(args) -> int:
    from ..accuracy import format_summary
    from ..ros.replay import replay

    params = _param_overrides(getattr(args, "param", []))
    params.update({p: getattr(args, d) for d, p in _REPLAY_OVERRIDES if hasattr(args, d)})
    out_bag = Path(args.out) if args.out else None
    res = replay(
        args.bag,
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
    )
    n = len(res.rows)
    solver = res.config.solver
    text = sys.stderr if args.json else sys.stdout  # --json: stdout holds only the JSON
    print(
        f"{solver}: solved {res.solved}/{n} frames"
        + (f"; failures {res.failures}" if res.failures else "")
        + ("" if res.config.tracking is None else " (tracking: twist = the fused twist)"),
        file=text,
    )
    if res.config.imu is not None:
        c = res.counts
        missing = {k[13:]: v for k, v in c.items() if k.startswith("gyro_missing.")}
        print(
            f"gyro: {c.get('frames_with_gyro', 0)} frames used it, "
            f"{c.get('gyro_rejected', 0)} contradicted by the image (solved without), "
            f"{c.get('gyro_disabled_inconsistent', 0)} solved without it while the rotation "
            "between frames contradicted it, "
            f"{c.get('gyro_missing', 0)} without samples" + (f" {missing}" if missing else ""),
            file=text,
        )
        if res.gyro_bias is not None:
            how = "estimated" if res.config.imu.estimate_bias else "imu.gyro_bias"
            print(
                f"gyro bias ({how}, rad/s, IMU frame): "
                + " ".join(f"{b:.5f}" for b in res.gyro_bias)
                + " +- "
                + " ".join(f"{b:.5f}" for b in res.gyro_bias_std)
                + f" ({c.get('gyro_bias_rejected', 0)} pairs of frames rejected)",
                file=text,
            )
    if res.summary.get("frames"):
        print(format_summary(solver, res.summary, n), file=text)
    if res.out_bag:
        print(
            f"estimates: {res.out_bag}"
            + (" (with debug_image, markers, path)" if args.debug_outputs else ""),
            file=text,
        )
    if res.out_csv:
        print(f"csv: {res.out_csv}", file=text)
    if args.json:
        print(
            json.dumps(
                {
                    "solver": solver,
                    "frames_total": n,
                    "solved": res.solved,
                    "failures": res.failures,
                    **res.summary,
                    "out_bag": str(res.out_bag) if res.out_bag else None,
                    "csv": str(res.out_csv) if res.out_csv else None,
                },
                indent=2,
            )
        )
    return 0 if res.solved else 1


def _export_image(args) -> int:
    import cv2
    import numpy as np

    from ..frontends.image import image_from_msg
    from ..ros.bag_io import IMAGE, bag_topics, iter_messages, typestore
    from ..viz.debug_image import to_bgr

    topics = bag_topics(args.bag)
    if topics.get(args.topic) != IMAGE:
        images = sorted(t for t, mt in topics.items() if mt == IMAGE)
        raise ValueError(
            f"{args.bag}: no sensor_msgs/Image topic {args.topic!r} (image "
            f"topics: {images or 'none'})"
        )
    ts = typestore()
    count = 0
    for k, (_, mt, _, raw) in enumerate(iter_messages(args.bag, {args.topic})):
        count += 1
        if k == args.index:
            img, enc = image_from_msg(ts.deserialize_cdr(raw, mt))
            out = Path(args.out)
            if out.parent and not out.parent.exists():
                out.parent.mkdir(parents=True)
            bgr = to_bgr(img, enc)
            if args.colors:
                from PIL import Image  # (Pillow comes with matplotlib)

                Image.fromarray(np.ascontiguousarray(bgr[:, :, ::-1])).quantize(
                    colors=args.colors, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE
                ).save(str(out), optimize=True)
            elif not cv2.imwrite(str(out), bgr, [cv2.IMWRITE_PNG_COMPRESSION, 9]):
                raise ValueError(f"cannot write {out} (use a .png or .jpg name)")
            print(
                f"wrote {out}: message {k} of {args.topic} ({img.shape[1]}x{img.shape[0]}, "
                f"{enc}, {out.stat().st_size / 1024:.0f} KiB)"
            )
            return 0
    raise ValueError(f"{args.topic} has {count} messages; --index {args.index} is out of range")


def _demo(args) -> int:
    from ..evaluation.demo import run_demo

    return run_demo(
        bag=args.bag,
        params=args.params,
        compare=args.compare,
        per_frame=not args.summary_only,
        timeout=args.timeout,
        images=args.images,
        image_bag=args.image_bag,
    )


def _render_bag(args) -> int:
    from . import render_bag as bagout

    return int(bagout.run_from_args(args) or 0)


def _marker_map(args) -> int:
    from ..sim.render.scene import load_scene, save_marker_map

    scene = load_scene(args.scene)
    out = save_marker_map(args.out, scene)
    print(f"wrote {out}: {len(scene.markers)} markers ({scene.dictionary}) of scene {scene.name}")
    return 0


def _calibrate_readout(args) -> int:
    import numpy as np

    from ..estimation.estimate import EstimateOptions, RansacOptions
    from ..estimation.readout import calibrate_line_delay
    from ..ros.bag_frames import read_bag_frames, read_gyro

    bag = read_bag_frames(
        args.bag,
        source=args.source,
        landmarks_file=args.landmarks,
        frontend=args.frontend,
        frontend_map=args.frontend_map,
        direction=args.direction,
    )
    gyro = read_gyro(args.bag, args.imu_topic) if args.imu_topic else None
    stamp_row = bag.stamp_row if args.stamp_row is None else args.stamp_row
    res = calibrate_line_delay(
        bag.frames,
        bag.camera,
        solver=args.solver,
        options=EstimateOptions(ransac=RansacOptions(threshold_px=args.threshold, seed=0)),
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
        lines.append("  imu.rotation: [" + ", ".join(f"{v:.6f}" for v in q) + "]")
        lines.append("  imu.gyro_bias: [" + ", ".join(f"{v:.6f}" for v in res.gyro_bias) + "]")
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


def _experiments(args) -> int:
    from ..evaluation.experiments import run

    return run(args)


def _solver_help(prefix: str) -> str:
    """Help text listing the registry's solvers with their paper names."""

    def entry(n: str) -> str:
        info = solver_info(n)
        return f"{n} ({info.paper_name}{'' if info.rolling else ', global shutter'})"

    return prefix + ": " + ", ".join(entry(n) for n in SOLVER_NAMES)


def _compile(args) -> int:
    from ..jit_cache import cache_state
    from ..warmup import compile_kernels

    st = cache_state()
    print(
        f"numba cache: {st['dir']} ({st['mode']}"
        + (f", {st['seeded']} files copied from the package" if st["seeded"] else "")
        + ")",
        flush=True,
    )
    res = compile_kernels(args.solvers, log=lambda m: print(m, flush=True), jobs=args.jobs)
    n = len(res["kernels"])
    print(
        f"{', '.join(res['solvers'])}: ready in {res['seconds']:.1f} s ("
        + (
            f"compiled {n} kernels, {sum(d for _, d in res['kernels']):.1f} s of compiling"
            + (f" in {args.jobs} processes" if args.jobs > 1 else "")
            if n
            else "all kernels loaded from the cache"
        )
        + ")"
    )
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="rs-localizer",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = p.add_subparsers(dest="command", required=True)
    fmt = dict(formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    directions = list(READOUT_DIRECTIONS)

    m = sub.add_parser(
        "make-bag", help="write a synthetic rolling-shutter sequence as a bag", **fmt
    )
    m.add_argument("out", help="output bag directory")
    m.add_argument("--frames", type=int, default=40, help="frames to generate")
    m.add_argument("--points", type=int, default=500, help="correspondences per frame")
    m.add_argument("--fps", type=float, default=30.0, help="frame rate (Hz)")
    m.add_argument("--noise", type=float, default=0.5, help="pixel noise sigma (px)")
    m.add_argument("--outliers", type=float, default=0.2, help="outlier fraction (0..1)")
    m.add_argument("--seed", type=int, default=0, help="random seed")
    m.add_argument(
        "--line-delay",
        type=float,
        default=30e-6,
        help="s per row (the 1280x720 camera: 30e-6 = 21.6 ms readout)",
    )
    m.add_argument(
        "--direction", default="top_to_bottom", choices=directions, help="readout direction"
    )
    m.add_argument(
        "--reference-row",
        type=float,
        default=-1.0,
        help="row of the ground-truth pose (-1: image centre)",
    )
    m.add_argument("--stamp-row", type=float, default=0.0, help="row of the header stamp")
    m.add_argument(
        "--motion-scale",
        type=float,
        default=1.0,
        help="scale of the rotational motion (1: ~1.5 rad/s)",
    )
    m.add_argument("--landmarks", type=int, default=6000, help="landmarks in the scene")
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
        type=float,
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
        default=None,
        metavar="LIST",
        help="frame indices to leave out, e.g. 10,20-23 (dropped frames)",
    )
    m.add_argument(
        "--teleport",
        type=int,
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
        type=float,
        default=0.0,
        help="also write a sensor_msgs/Imu topic at this rate (Hz; gyro with "
        "bias and noise, IMU axes x forward, y left, z up)",
    )
    m.add_argument("--imu-topic", default="/imu/data", help="topic of --imu-rate")
    m.add_argument(
        "--imu-time-offset",
        type=float,
        default=0.0,
        metavar="S",
        help="with --imu-rate: stamp the IMU on a clock S seconds behind the camera's "
        "(t_cam = t_imu + S, the node's imu.time_offset)",
    )
    m.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    m.set_defaults(func=_make_bag)

    pl = sub.add_parser("play", help="publish a bag into the live ROS graph", **fmt)
    pl.add_argument("bag", help="bag directory")
    pl.add_argument("--rate", type=float, default=1.0, help="time scale (0: as fast as possible)")
    pl.add_argument(
        "--lockstep",
        action="store_true",
        help="wait for the output of each frame before sending the next",
    )
    pl.add_argument(
        "--output-topic",
        action="append",
        default=None,
        help="pose topic(s) to wait for in lock-step (repeatable; default /camera/pose)",
    )
    pl.add_argument("--timeout", type=float, default=2.0, help="lock-step wait per frame (s)")
    pl.add_argument(
        "--retries",
        type=int,
        default=1,
        help="times a frame without answer is republished (lock-step)",
    )
    pl.add_argument(
        "--topics", nargs="+", default=None, help="only these bag topics (default: all)"
    )
    pl.add_argument(
        "--remap",
        nargs="+",
        default=None,
        metavar="FROM:=TO",
        help="publish topic FROM of the bag as TO",
    )
    pl.add_argument(
        "--wait",
        type=float,
        default=None,
        help="wait for subscribers (s; default 30 in lock-step, else 2)",
    )
    pl.add_argument(
        "--best-effort", action="store_true", help="publish best effort (default: reliable)"
    )
    pl.add_argument("--limit", type=int, default=None, help="stop after N frames")
    pl.add_argument("--loop", type=int, default=1, help="play N times")
    pl.set_defaults(func=_play)

    r = sub.add_parser(
        "replay",
        help="the localizer node over a bag, offline (same parameters, same outputs)",
        description="Run the node's per-frame pipeline over every frame of a bag, with the "
        "node's parameters: the defaults, then each --params-file (ROS 2 format: the /** and "
        "rs_localizer sections), then --param and the options below. Tracking is on as in "
        "the node: twist and odom carry the fused twist, twist_single_frame each frame's own "
        "(--no-tracking: every frame alone). The RS timing (rs.line_delay, rs.direction, "
        "rs.reference_row, rs.stamp_row) that no parameter file or option sets comes from "
        "the bag's sequence.json (make-bag, render-bag), else the parameter's default.",
        **fmt,
    )
    r.add_argument("bag", help="bag directory (make-bag or render-bag output)")
    unset = argparse.SUPPRESS  # (options only override: unset ones leave the parameters)
    r.add_argument(
        "--params-file",
        action="append",
        default=unset,
        metavar="FILE",
        help="the node's ROS 2 parameter file, e.g. config/rs_localizer.yaml (repeatable; "
        "later ones win)",
    )
    r.add_argument(
        "-p",
        "--param",
        action="append",
        default=unset,
        metavar="NAME:=VALUE",
        help="set a node parameter (YAML value, as ros2 run -p; repeatable), e.g. tracking.lag:=2",
    )

    def over(param: str, text: str) -> str:
        from ..ros.params import PARAMETERS

        return f"{text}; sets the parameter {param} (default: {PARAMETERS[param][0]})"

    def timing(param: str, text: str) -> str:
        from ..ros.params import PARAMETERS

        return (
            f"{text}; sets {param} (default: --params-file, else the bag's sequence.json, "
            f"else {PARAMETERS[param][0]})"
        )

    r.add_argument(
        "--solver",
        default=unset,
        choices=SOLVER_NAMES,
        help=over("solver", _solver_help("minimal solver")),
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
        "(the node's visualization topics, for Foxglove or RViz)",
    )
    r.add_argument(
        "--path-length",
        type=int,
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
        type=float,
        default=unset,
        help=over("ransac.threshold_px", "RANSAC threshold (px)"),
    )
    r.add_argument(
        "--max-iterations",
        type=int,
        default=unset,
        help=over("ransac.max_iterations", "RANSAC hypotheses cap per frame"),
    )
    r.add_argument(
        "--confidence",
        type=float,
        default=unset,
        help=over("ransac.confidence", "RANSAC adaptive-termination confidence"),
    )
    r.add_argument(
        "--min-inliers",
        type=int,
        default=unset,
        help=over("ransac.min_inliers", "fewest inliers for a pose"),
    )
    r.add_argument(
        "--seed", type=int, default=unset, help=over("ransac.seed", "RANSAC random seed")
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
    r.add_argument("--line-delay", type=float, default=unset, help=timing("rs.line_delay", "s/row"))
    r.add_argument(
        "--readout-time",
        type=float,
        default=unset,
        help=over("rs.readout_time", "s/frame, wins over the line delay if > 0"),
    )
    r.add_argument(
        "--direction",
        default=unset,
        choices=directions,
        help=timing("rs.direction", "readout direction"),
    )
    r.add_argument(
        "--reference-row",
        type=float,
        default=unset,
        help=timing("rs.reference_row", "row (px) of the estimated pose, -1: centre"),
    )
    r.add_argument(
        "--stamp-row",
        type=float,
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
    r.set_defaults(func=_replay)

    e = sub.add_parser(
        "export-image",
        help="write one sensor_msgs/Image of a bag as PNG "
        "(e.g. a replay --debug-outputs debug_image)",
        **fmt,
    )
    e.add_argument("bag", help="bag directory")
    e.add_argument("out", help="image file to write (.png, .jpg)")
    e.add_argument("--topic", default="/rs_localizer/debug_image", help="image topic")
    e.add_argument("--index", type=int, default=0, help="message number on the topic (0 = first)")
    e.add_argument(
        "--colors",
        type=int,
        default=0,
        help="PNG with a palette of this many colours (smaller file; 0: full colour)",
    )
    e.set_defaults(func=_export_image)

    d = sub.add_parser("demo", help="node + sample bag over DDS, accuracy vs ground truth", **fmt)
    d.add_argument("--bag", default=None, help="correspondence bag (default: data/sample)")
    d.add_argument(
        "--params", default=None, help="node parameter file (default: config/rs_localizer.yaml)"
    )
    d.add_argument(
        "--compare",
        default="p3p",
        choices=[*SOLVER_NAMES, ""],
        help="second solver run next to the configured one ('' to skip)",
    )
    d.add_argument("--summary-only", action="store_true", help="no per-frame lines")
    d.add_argument(
        "--timeout", type=float, default=5.0, help="lock-step wait for each frame's pose (s)"
    )
    d.add_argument(
        "--images",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="also run the image-mode demo (front end in the node)",
    )
    d.add_argument("--image-bag", default=None, help="image bag (default: data/sample_images)")
    d.set_defaults(func=_demo)

    from . import render_bag as bagout

    mm = sub.add_parser(
        "marker-map",
        help="write the ArUco marker map of a scene (for the "
        "node's frontend_map / the aruco front end)",
        **fmt,
    )
    mm.add_argument("scene", help="built-in scene (aruco_room, textured_room) or scene YAML")
    mm.add_argument("out", help="marker map YAML to write")
    mm.set_defaults(func=_marker_map)

    rb = sub.add_parser(
        "render-bag",
        help="render a rolling-shutter image sequence to a bag "
        "(images, camera_info, front-end correspondences, ground truth)",
        **fmt,
    )
    bagout.add_arguments(rb, positional_out=True)
    rb.set_defaults(func=_render_bag)

    cr = sub.add_parser(
        "calibrate-readout",
        help="estimate the line delay (s per line) "
        "from a bag with rotation, ignoring the RS timing it states",
    )
    cr.add_argument("bag", help="bag directory with a rotating sequence")
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
    cr.add_argument("--threshold", type=float, default=2.0, help="RANSAC threshold (px)")
    cr.add_argument(
        "--direction",
        default=None,
        choices=directions,
        help="readout direction (default: the bag's sequence.json)",
    )
    cr.add_argument(
        "--stamp-row",
        type=float,
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
    cr.set_defaults(func=_calibrate_readout)

    from .map_features import register as register_map_features

    register_map_features(sub)

    from ..evaluation.experiments import add_arguments as experiment_arguments

    ex = sub.add_parser(
        "experiments",
        help="reproduce the paper's synthetic experiments (PNG plots + markdown report)",
        **fmt,
    )
    experiment_arguments(ex)
    ex.set_defaults(func=_experiments)

    from ..warmup import DEFAULT_JOBS, DEFAULT_SOLVERS

    c = sub.add_parser(
        "compile",
        help="compile the JIT kernels now (run once after installing, "
        "while the package directory is writable: the node then starts in "
        "seconds)",
        **fmt,
    )
    c.add_argument(
        "--solvers",
        nargs="+",
        default=list(DEFAULT_SOLVERS),
        choices=SOLVER_NAMES,
        help="solvers to compile for (the demo's global-shutter baseline: add p3p)",
    )
    c.add_argument(
        "--jobs",
        type=int,
        default=DEFAULT_JOBS,
        help="processes compiling at once (the fused RANSAC kernels in a second one)",
    )
    c.set_defaults(func=_compile)
    from . import map_markers

    map_markers.register(sub)
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
