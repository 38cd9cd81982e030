"""Node benchmark: frames of 500 correspondences through the real node over DDS.

    python -m rs_localizer.evaluation.bench_node [--frames 300] [--points 500] [--solver r6p_1lin]

Starts ``rs_localizer_node`` in a subprocess pinned to one CPU core (with single-threaded
BLAS/numba), and from this process (pinned to another core):

* lock-step: publish a frame, wait for its pose, repeat. Reports the throughput (frames/s)
  and the latency from publish to pose received (median, p99): the full round trip of
  serialization, DDS, decoding, estimation and publishing.
* pipelined: keep ``--window`` frames in flight (reliable QoS, nothing dropped), which is how
  a camera feeds the node; reports the sustained output rate.

The estimator alone (same frames, same process as the benchmark, no ROS) is timed too, so the
ROS overhead is visible. Frames come from :mod:`rs_localizer.sim.trajectory` (a few distinct frames
replayed with increasing stamps).
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
    from ..sim.trajectory import SequenceConfig, generate_sequence

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
) -> dict:
    """Generate ``distinct`` synthetic frames, time the estimator alone on them, then the node
    over DDS (:func:`rs_localizer.ros.bench_client.measure_node`). Returns the results."""
    from ..estimation import EstimateOptions, estimate_rs_pose
    from ..ros.bench_client import measure_node

    log(f"generating {distinct} distinct frames of {points} correspondences ...")
    seq, cam = _frames(distinct, points, seed)

    # estimator alone (this process), after a JIT warm-up
    opts = EstimateOptions()
    for f in seq[:2]:
        estimate_rs_pose(f.uv, f.xyz, cam, solver=solver, options=opts)
    t_est = []
    for f in seq:
        tic = time.perf_counter()
        estimate_rs_pose(f.uv, f.xyz, cam, solver=solver, options=opts)
        t_est.append(time.perf_counter() - tic)
    t_est = np.array(t_est)
    log(
        f"estimator alone ({solver}): median {np.median(t_est) * 1e3:.2f} ms "
        f"({1 / np.median(t_est):.0f} Hz)"
    )

    result = {
        "solver": solver,
        "points": points,
        "frames": frames,
        "estimator_ms_median": float(np.median(t_est) * 1e3),
        "estimator_hz": float(1 / np.median(t_est)),
    }
    return measure_node(seq, cam, solver, frames, window, node_cpu, result, log)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m rs_localizer.evaluation.bench_node",
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
    args = p.parse_args(argv)
    res = run_benchmark(
        args.frames,
        args.points,
        args.solver,
        args.window,
        args.distinct,
        None if args.node_cpu < 0 else args.node_cpu,
    )
    hz = res["pipelined"]["hz"]
    print(
        f"node throughput with {args.solver}, {args.points} correspondences, one core: "
        f"{hz:.1f} Hz sustained (target {args.target_hz:.0f} Hz: "
        f"{'met' if hz >= args.target_hz else 'NOT met'}); lock-step "
        f"{res['lockstep']['hz']:.1f} Hz, latency median "
        f"{res['lockstep']['latency_ms_median']:.2f} ms, p99 "
        f"{res['lockstep']['latency_ms_p99']:.2f} ms"
    )
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
