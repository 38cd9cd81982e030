"""Node benchmark: frames of 500 correspondences through the real node over DDS.

    python -m benchmarks.bench_node [--frames 300] [--points 500] [--solver r6p_1lin]
    python -m benchmarks.bench_node --cameras 4 [--rate 30] [--seconds 20]

Starts ``rs_localizer_node`` in a subprocess pinned to one CPU core (with single-threaded
BLAS/numba), and from this process (pinned to another core):

* lock-step: publish a frame, wait for its pose, repeat. Reports the throughput (frames/s)
  and the latency from publish to pose received (median, p99): the full round trip of
  serialization, DDS, decoding, estimation and publishing.
* the uncompiled path (NumPy/SciPy/OpenCV, :mod:`rs_localizer.estimation.numpy_impl`: what a
  node solves with while its kernels compile in the background): timed alone, and the node on
  it lock-step (started with ``RS_LOCALIZER_COMPILED=0``; ``--no-uncompiled-node``: not);
* pipelined: keep ``--window`` frames in flight (reliable QoS, nothing dropped), which is how
  a camera feeds the node; reports the sustained output rate.

What the node runs on a frame is also timed alone (same frames, this process, no ROS): with
the default configuration the video tracker (``tracking.enabled``), else the single-frame
estimator. The node's overhead is the lock-step latency median minus that median: decoding,
the queue, message building, publishing, the executor and the DDS round trip. A last
lock-step run with only ``pose`` subscribed shows what the other outputs cost. Every run also
reports the node process's CPU time per frame (all its threads).

Back to back, the timing alone runs on warm caches; the node solves each frame after an idle
gap (the round trip). The tracker is timed once more with that gap as a pause between frames,
and the overhead over it is reported too.

``--cameras N``: instead, N cameras in one node process (the ``cameras`` parameter) on one core,
each streaming ``--rate`` frames per second for ``--seconds`` (staggered, reliable): frames
answered and skipped per camera and the latency from publish to pose (median, p99, max).

Frames come from :mod:`rs_localizer.sim.trajectory` (a few distinct frames replayed with
increasing stamps).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

__all__ = ["main", "run_benchmark"]


def _frames(n_distinct, points, seed):
    from rs_localizer.sim.trajectory import SequenceConfig, generate_sequence

    frames, _, cam, _ = generate_sequence(
        SequenceConfig(num_frames=n_distinct, num_points=points, seed=seed)
    )
    return frames, cam


def run_benchmark(
    frames: int = 300,
    points: int = 500,
    solver: str = "r6p_1lin",
    window: int = 3,
    distinct: int = 20,
    node_cpu: int | None = 0,
    seed: int = 0,
    log=print,
    uncompiled_node: bool = True,
) -> dict:
    """Generate ``distinct`` synthetic frames, time what the node runs on them alone, then the
    node over DDS (:func:`benchmarks.bench_client.measure_node`), then alone again with
    the lock-step idle time as a pause between frames. Returns the results, with
    ``overhead_ms``: lock-step latency median minus the alone median, and
    ``overhead_paced_ms``: minus the paced alone median. Both estimator paths are reported:
    the uncompiled one (:mod:`rs_localizer.estimation.numpy_impl`, the path of a node whose
    kernels compile in the background) timed alone (``uncompiled_ms_median``,
    ``uncompiled_hz``) and, with ``uncompiled_node``, the node on it lock-step
    (``uncompiled_node``: the node started with ``RS_LOCALIZER_COMPILED=0``)."""
    from .bench_client import measure_node

    log(f"generating {distinct} distinct frames of {points} correspondences ...")
    seq, cam = _frames(distinct, points, seed)
    what, t_est = _alone(seq, cam, solver, max(frames, 3 * distinct))
    log(
        f"{what} alone ({solver}): median {np.median(t_est) * 1e3:.2f} ms "
        f"({1 / np.median(t_est):.0f} Hz)"
    )
    result = {
        "solver": solver,
        "points": points,
        "frames": frames,
        "alone": what,
        "estimator_ms_median": float(np.median(t_est) * 1e3),
        "estimator_hz": float(1 / np.median(t_est)),
    }
    t_unc, cpu_unc = _alone_uncompiled(seq, cam, solver, min(frames, 2 * distinct))
    result["uncompiled_ms_median"] = float(np.median(t_unc) * 1e3)
    result["uncompiled_cpu_ms_median"] = float(np.median(cpu_unc) * 1e3)
    result["uncompiled_hz"] = float(1 / np.median(t_unc))
    log(
        f"uncompiled path alone ({solver}, every frame alone, no tracking): median "
        f"{result['uncompiled_ms_median']:.1f} ms ({result['uncompiled_hz']:.1f} Hz; CPU "
        f"{result['uncompiled_cpu_ms_median']:.1f} ms of this thread): the rate while the "
        "kernels compile in the background after a start on a cold cache"
    )
    if uncompiled_node:
        result["uncompiled_node"] = _node_uncompiled(
            seq, cam, solver, min(frames, 60), node_cpu, log
        )
    result = measure_node(seq, cam, solver, frames, window, node_cpu, result, log)
    lock = result["lockstep"]
    result["overhead_ms"] = lock["latency_ms_median"] - result["estimator_ms_median"]
    log(
        f"node overhead (lock-step latency median - {what} alone): "
        f"{result['overhead_ms']:.2f} ms per frame"
    )
    # the node solves a frame after an idle gap (the round trip), with the caches cold
    pause = max(lock["wall_s"] / max(lock["answered"], 1) - np.median(t_est), 0.0)
    _, t_paced = _alone(seq, cam, solver, max(frames, 3 * distinct), pause)
    result["paced_pause_ms"] = pause * 1e3
    result["estimator_paced_ms_median"] = float(np.median(t_paced) * 1e3)
    result["overhead_paced_ms"] = lock["latency_ms_median"] - result["estimator_paced_ms_median"]
    log(
        f"{what} alone with {pause * 1e3:.2f} ms pauses between frames (the lock-step idle "
        f"time): median {result['estimator_paced_ms_median']:.2f} ms; node overhead over it "
        f"{result['overhead_paced_ms']:.2f} ms per frame"
    )
    return result


def _alone_uncompiled(seq, cam, solver: str, frames: int) -> tuple[np.ndarray, np.ndarray]:
    """The uncompiled path (every frame alone, the node's options) timed on ``frames``
    frames: (wall s, CPU s of this thread) per frame."""
    from rs_localizer.estimation.estimate import estimate_rs_pose
    from rs_localizer.ros import config as C
    from rs_localizer.ros import params as P

    cfg = C.build_config({**P.default_values(), "solver": solver})
    times, cpu = [], []
    for i in range(frames + 2):
        f = seq[i % len(seq)]
        tic, tic_cpu = time.perf_counter(), time.thread_time()
        estimate_rs_pose(f.uv, f.xyz, cam, solver, cfg.options, implementation="numpy")
        times.append(time.perf_counter() - tic)
        cpu.append(time.thread_time() - tic_cpu)
    return np.array(times[2:]), np.array(cpu[2:])


def _node_uncompiled(seq, cam, solver: str, frames: int, node_cpu, log) -> dict:
    """The node on the uncompiled path (``RS_LOCALIZER_COMPILED=0`` in its environment),
    lock-step and pipelined on ``frames`` frames (:func:`measure_node`)."""
    import os

    from rs_localizer.estimation.implementation import COMPILED_ENV

    from .bench_client import measure_node

    before = os.environ.get(COMPILED_ENV)
    os.environ[COMPILED_ENV] = "0"
    try:
        res = measure_node(seq, cam, solver, frames, 1, node_cpu, {}, lambda *a, **k: None)
    finally:
        if before is None:
            os.environ.pop(COMPILED_ENV, None)
        else:
            os.environ[COMPILED_ENV] = before
    lock = res["lockstep"]
    log(
        f"node on the uncompiled path: lock-step {lock['hz']:.1f} Hz, latency median "
        f"{lock['latency_ms_median']:.1f} ms ({frames} frames)"
    )
    return {"lockstep": lock}


def _alone(seq, cam, solver: str, frames: int, pause: float = 0.0) -> tuple[str, np.ndarray]:
    """What the node with its default configuration runs on a frame (the video tracker, or the
    single-frame estimator without tracking), timed in this process on ``frames`` frames (the
    distinct frames replayed with increasing stamps), ``pause`` s of sleep between frames:
    (``"tracker"`` or ``"estimator"``, s per frame)."""
    from rs_localizer.estimation import estimate_rs_pose
    from rs_localizer.ros import config as C
    from rs_localizer.ros import params as P
    from rs_localizer.tracking.tracker import RSTracker

    cfg = C.build_config({**P.default_values(), "solver": solver})
    period = 33_333_333
    if cfg.tracking is not None:
        tracker = RSTracker(solver, cfg.options, cfg.tracking)

        def run(i, f):
            tracker.process(seq[0].stamp_ns + i * period, f.uv, f.xyz, cam)

        what = "tracker"
    else:

        def run(i, f):
            estimate_rs_pose(f.uv, f.xyz, cam, solver=solver, options=cfg.options)

        what = "estimator"
    times = []
    for i in range(frames + 10):  # (the first 10: JIT warm-up and the track's start)
        if pause > 0:
            time.sleep(pause)
        tic = time.perf_counter()
        run(i, seq[i % len(seq)])
        times.append(time.perf_counter() - tic)
    return what, np.array(times[10:])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.bench_node",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--points", type=int, default=500)
    p.add_argument("--solver", default="r6p_1lin")
    p.add_argument("--window", type=int, default=3, help="frames in flight (pipelined run)")
    p.add_argument("--distinct", type=int, default=20, help="distinct synthetic frames")
    p.add_argument("--node-cpu", type=int, default=0, help="CPU core for the node (-1: no pinning)")
    p.add_argument("--target-hz", type=float, default=100.0)
    p.add_argument("--json", default=None, help="write the results to this file")
    p.add_argument(
        "--no-uncompiled-node",
        action="store_true",
        help="do not run the node on the uncompiled path (it is still timed alone)",
    )
    p.add_argument(
        "--cameras", type=int, default=0, help="N cameras in one process at --rate each (0: off)"
    )
    p.add_argument("--rate", type=float, default=30.0, help="frames per second per camera")
    p.add_argument("--seconds", type=float, default=20.0, help="length of the camera streams")
    args = p.parse_args(argv)
    if args.cameras > 0:
        return _cameras(args)
    res = run_benchmark(
        args.frames,
        args.points,
        args.solver,
        args.window,
        args.distinct,
        None if args.node_cpu < 0 else args.node_cpu,
        uncompiled_node=not args.no_uncompiled_node,
    )
    hz = res["pipelined"]["hz"]
    print(
        f"node throughput with {args.solver}, {args.points} correspondences, one core: "
        f"{hz:.1f} Hz sustained (target {args.target_hz:.0f} Hz: "
        f"{'met' if hz >= args.target_hz else 'NOT met'}); lock-step "
        f"{res['lockstep']['hz']:.1f} Hz, latency median "
        f"{res['lockstep']['latency_ms_median']:.2f} ms, p99 "
        f"{res['lockstep']['latency_ms_p99']:.2f} ms; node overhead {res['overhead_ms']:.2f} ms"
        f" ({res['alone']} alone {res['estimator_ms_median']:.2f} ms; paced "
        f"{res['estimator_paced_ms_median']:.2f} ms, overhead over it "
        f"{res['overhead_paced_ms']:.2f} ms); node CPU "
        f"{res['lockstep']['node_cpu_ms_per_frame']:.2f} ms per frame; pose only subscribed: "
        f"lock-step {res['pose_only']['hz']:.1f} Hz, latency median "
        f"{res['pose_only']['latency_ms_median']:.2f} ms"
    )
    unc = res.get("uncompiled_node", {}).get("lockstep")
    print(
        f"uncompiled path (while the kernels compile after a start on a cold cache): alone "
        f"{res['uncompiled_hz']:.1f} Hz"
        + (f", node lock-step {unc['hz']:.1f} Hz" if unc else "")
        + " (target >= 10 Hz lock-step)"
    )
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2) + "\n")
    return 0


def _cameras(args) -> int:
    from .bench_client import measure_cameras

    seq, cam = _frames(args.distinct, args.points, 0)
    res = measure_cameras(
        seq,
        cam,
        args.cameras,
        args.rate,
        args.seconds,
        args.solver,
        None if args.node_cpu < 0 else args.node_cpu,
    )
    skipped = sum(max(r["frames_skipped"], 0) for r in res["cameras"].values())
    print(
        f"{args.cameras} cameras x {args.rate:.0f} Hz in one process on one core, {args.solver}, "
        f"{args.points} correspondences: {res['answered']}/{res['sent']} frames with a pose, "
        f"{skipped} skipped by the node; latency median {res['latency_ms_median']:.2f} ms, "
        f"p99 {res['latency_ms_p99']:.2f} ms, max {res['latency_ms_max']:.2f} ms; node CPU "
        f"{res['node_cpu_ms_per_frame']:.2f} ms per frame"
    )
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2) + "\n")
    return 0 if res["answered"] == res["sent"] else 1


if __name__ == "__main__":
    sys.exit(main())
