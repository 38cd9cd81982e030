"""Node benchmark: frames of 500 correspondences through the real node over DDS.

    python -m rs_localizer.bench_node [--frames 300] [--points 500] [--solver r6p_1lin]

Starts ``rs_localizer_node`` in a subprocess pinned to one CPU core (with single-threaded
BLAS/numba), and from this process (pinned to another core):

* lock-step: publish a frame, wait for its pose, repeat. Reports the throughput (frames/s)
  and the latency from publish to pose received (median, p99): the full round trip of
  serialization, DDS, decoding, estimation and publishing.
* pipelined: keep ``--window`` frames in flight (reliable QoS, nothing dropped), which is how
  a camera feeds the node; reports the sustained output rate.

The estimator alone (same frames, same process as the benchmark, no ROS) is timed too, so the
ROS overhead is visible. Frames come from :mod:`rs_localizer.trajectory` (a few distinct frames
replayed with increasing stamps).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["main", "run_benchmark"]

SINGLE_THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                     "NUMBA_NUM_THREADS": "1"}


def _frames(n_distinct, points, seed):
    from .trajectory import SequenceConfig, generate_sequence

    frames, _, cam, _ = generate_sequence(SequenceConfig(num_frames=n_distinct,
                                                         num_points=points, seed=seed))
    return frames, cam


def run_benchmark(frames: int = 300, points: int = 500, solver: str = "r6p_1lin",
                  window: int = 3, distinct: int = 20, node_cpu: int | None = 0,
                  seed: int = 0, log=print) -> dict:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rclpy.serialization import serialize_message
    from geometry_msgs.msg import PoseStamped
    from sensor_msgs.msg import CameraInfo, PointCloud2

    from .estimate import EstimateOptions, estimate_rs_pose
    from .ros.conversions import camera_info_msg, stamp_to_ns
    from .ros.pointcloud import correspondence_cloud
    from .ros.process import (NodeProcess, random_domain_id, repo_file, ros_env,
                              write_params_yaml)

    ncpu = os.cpu_count() or 1
    if node_cpu is not None and ncpu < 2:
        node_cpu = None
    log(f"generating {distinct} distinct frames of {points} correspondences ...")
    seq, cam = _frames(distinct, points, seed)
    offset = cam.time_offset(0.0, cam.reference_line)
    period = 33_333_333

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
    log(f"estimator alone ({solver}): median {np.median(t_est) * 1e3:.2f} ms "
        f"({1 / np.median(t_est):.0f} Hz)")

    domain = random_domain_id()
    env = ros_env(domain, {**os.environ, **SINGLE_THREAD_ENV})
    os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
    tmp = Path(tempfile.mkdtemp(prefix="rs_localizer_bench_"))
    overlay = write_params_yaml(tmp / "bench.yaml", {"solver": solver},
                                reliable_topics=["/bench/correspondences", "/bench/camera_info"])
    config = repo_file("config", "rs_localizer.yaml")
    node = NodeProcess([p for p in (config, overlay) if p], namespace="/bench", env=env,
                       log=tmp / "node.log",
                       cpus=None if node_cpu is None else [node_cpu])
    if node_cpu is not None and hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {(node_cpu + 1) % ncpu})
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    n = rclpy.create_node("rs_localizer_bench", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(n)
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    pub = n.create_publisher(PointCloud2, "/bench/correspondences", qos)
    pub_info = n.create_publisher(CameraInfo, "/bench/camera_info", qos)
    recv = {}
    # a consumer of every output, so that the node builds and sends all of them
    from geometry_msgs.msg import PoseWithCovarianceStamped, TwistStamped
    from nav_msgs.msg import Odometry

    for t, k in ((TwistStamped, "twist"), (Odometry, "odom"),
                 (PoseWithCovarianceStamped, "pose_with_covariance")):
        n.create_subscription(t, f"/bench/{k}", lambda m: None, qos)
    n.create_subscription(PoseStamped, "/bench/pose",
                          lambda m: recv.setdefault(stamp_to_ns(m.header.stamp),
                                                    time.perf_counter()), qos)
    result = {"solver": solver, "points": points, "frames": frames,
              "node_cpu": node_cpu, "estimator_ms_median": float(np.median(t_est) * 1e3),
              "estimator_hz": float(1 / np.median(t_est))}
    try:
        if not node.wait_ready(180):
            raise RuntimeError(f"node did not start:\n{node.log}")
        end = time.monotonic() + 30
        while (pub.get_subscription_count() == 0 or pub_info.get_subscription_count() == 0
               or n.count_publishers("/bench/pose") == 0
               or n.count_publishers("/bench/pose_with_covariance") == 0) \
                and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        t0 = seq[0].stamp_ns
        pub_info.publish(camera_info_msg(cam, "camera", t0))
        t_spin = time.perf_counter() + 0.3
        while time.perf_counter() < t_spin:
            ex.spin_once(timeout_sec=0.02)

        def raw_frame(i):
            f = seq[i % len(seq)]
            stamp = t0 + i * period
            return stamp, serialize_message(correspondence_cloud(
                f.uv, f.xyz, frame_id="camera", stamp=stamp))

        def run(tag, count, start, win):
            msgs = [raw_frame(start + i) for i in range(count)]  # serialized up front
            sent = {}
            out_stamp = {s: s + int(round(offset * 1e9)) for s, _ in msgs}
            k = 0
            wall0 = time.perf_counter()
            deadline = wall0 + 60 + count * 0.5
            while time.perf_counter() < deadline:
                done = sum(1 for s, _ in msgs[:k] if out_stamp[s] in recv)
                if done == count:
                    break
                if k < count and k - done < win:
                    s, raw = msgs[k]
                    sent[s] = time.perf_counter()
                    pub.publish(raw)
                    k += 1
                    continue
                ex.spin_once(timeout_sec=0.001)
            wall = time.perf_counter() - wall0
            lat = np.array([recv[out_stamp[s]] - sent[s] for s, _ in msgs
                            if s in sent and out_stamp[s] in recv])
            got = len(lat)
            r = {"frames": count, "answered": got, "wall_s": wall,
                 "hz": got / wall if wall > 0 else 0.0,
                 "latency_ms_median": float(np.median(lat) * 1e3) if got else float("nan"),
                 "latency_ms_p99": float(np.percentile(lat, 99) * 1e3) if got else float("nan"),
                 "latency_ms_max": float(lat.max() * 1e3) if got else float("nan")}
            log(f"{tag:>9}: {got}/{count} poses in {wall:.2f} s = {r['hz']:.1f} Hz; latency "
                f"median {r['latency_ms_median']:.2f} ms, p99 {r['latency_ms_p99']:.2f} ms, "
                f"max {r['latency_ms_max']:.2f} ms")
            return r

        diag = {}
        from diagnostic_msgs.msg import DiagnosticArray

        def on_diag(m):
            for st in m.status:
                if st.name.endswith("/bench/rs_localizer"):
                    diag.update({kv.key: kv.value for kv in st.values})
        n.create_subscription(DiagnosticArray, "/diagnostics", on_diag, qos)
        run("warm-up", 10, 0, 1)
        result["lockstep"] = run("lock-step", frames, 10, 1)
        result["pipelined"] = run(f"window {window}", frames, 10 + frames, window)
        t_spin = time.perf_counter() + 1.2
        while time.perf_counter() < t_spin:
            ex.spin_once(timeout_sec=0.02)
        result["node_stages_ms"] = {k[:-10]: float(v) for k, v in diag.items()
                                    if k.endswith("_ms_median")}
        log("inside the node (median ms): " + ", ".join(
            f"{k} {v:.2f}" for k, v in result["node_stages_ms"].items()))
    finally:
        ex.remove_node(n)
        n.destroy_node()
        ex.shutdown()
        rclpy.try_shutdown(context=ctx)
        node.stop()
    return result


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m rs_localizer.bench_node",
                                description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--points", type=int, default=500)
    p.add_argument("--solver", default="r6p_1lin")
    p.add_argument("--window", type=int, default=3, help="frames in flight (pipelined run)")
    p.add_argument("--distinct", type=int, default=20, help="distinct synthetic frames")
    p.add_argument("--node-cpu", type=int, default=0,
                   help="CPU core for the node (-1: no pinning)")
    p.add_argument("--target-hz", type=float, default=100.0)
    p.add_argument("--json", default=None, help="write the results to this file")
    args = p.parse_args(argv)
    res = run_benchmark(args.frames, args.points, args.solver, args.window, args.distinct,
                        None if args.node_cpu < 0 else args.node_cpu)
    hz = res["pipelined"]["hz"]
    print(f"node throughput with {args.solver}, {args.points} correspondences, one core: "
          f"{hz:.1f} Hz sustained (target {args.target_hz:.0f} Hz: "
          f"{'met' if hz >= args.target_hz else 'NOT met'}); lock-step "
          f"{res['lockstep']['hz']:.1f} Hz, latency median "
          f"{res['lockstep']['latency_ms_median']:.2f} ms, p99 "
          f"{res['lockstep']['latency_ms_p99']:.2f} ms")
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
