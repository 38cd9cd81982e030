"""Throughput and latency of the running node over DDS: a client that publishes frames and
waits for their poses (lock-step and pipelined). :mod:`benchmarks.bench_node`
drives it with synthetic frames."""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["SINGLE_THREAD_ENV", "measure_cameras", "measure_node"]

SINGLE_THREAD_ENV = {
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "NUMBA_NUM_THREADS": "1",
}


class _BenchGraph:
    """The node under test, ``rs_localizer_node`` with ``config/rs_localizer.yaml`` + ``params``
    in namespace ``/bench`` as a subprocess on a fresh ROS domain (pinned to ``node_cpu`` with
    single-threaded BLAS/numba; this process to the next core), and this process's rclpy node
    ``name`` with its executor and a reliable QoS (depth 100). ``node_cpu`` becomes None on a
    single core. :meth:`close` shuts both down."""

    def __init__(self, name: str, params: dict, reliable_topics: list, node_cpu: int | None):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        from rs_localizer.ros.process import (
            NodeProcess,
            random_domain_id,
            repo_file,
            ros_env,
            write_params_yaml,
        )

        ncpu = os.cpu_count() or 1
        if node_cpu is not None and ncpu < 2:
            node_cpu = None
        self.node_cpu = node_cpu
        domain = random_domain_id()
        env = ros_env(domain, {**os.environ, **SINGLE_THREAD_ENV})
        os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
        tmp = Path(tempfile.mkdtemp(prefix="rs_localizer_bench_"))
        overlay = write_params_yaml(tmp / "bench.yaml", params, reliable_topics=reliable_topics)
        self.process = NodeProcess(
            [p for p in (repo_file("config", "rs_localizer.yaml"), overlay) if p],
            namespace="/bench",
            env=env,
            log=tmp / "node.log",
            cpus=None if node_cpu is None else [node_cpu],
        )
        if node_cpu is not None and hasattr(os, "sched_setaffinity"):
            os.sched_setaffinity(0, {(node_cpu + 1) % ncpu})
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.node = rclpy.create_node(name, context=self.ctx)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)

    def consume_outputs(self, ns: str) -> list:
        """Subscriptions (that drop what they get) to ``ns``'s outputs besides ``pose``, so
        that the node builds and sends all of them."""
        from geometry_msgs.msg import PoseWithCovarianceStamped, TwistStamped
        from nav_msgs.msg import Odometry

        return [
            self.node.create_subscription(t, f"{ns}/{k}", lambda m: None, self.qos)
            for t, k in (
                (TwistStamped, "twist"),
                (TwistStamped, "twist_single_frame"),
                (Odometry, "odom"),
                (PoseWithCovarianceStamped, "pose_with_covariance"),
            )
        ]

    def spin(self, seconds: float) -> None:
        """Run the executor for ``seconds``."""
        end = time.perf_counter() + seconds
        while time.perf_counter() < end:
            self.ex.spin_once(timeout_sec=0.02)

    def close(self) -> None:
        import rclpy

        self.ex.remove_node(self.node)
        self.node.destroy_node()
        self.ex.shutdown()
        rclpy.try_shutdown(context=self.ctx)
        self.process.stop()


def measure_node(
    seq,
    cam,
    solver: str = "r6p_1lin",
    frames: int = 300,
    window: int = 3,
    node_cpu: int | None = 0,
    result: dict | None = None,
    log=print,
) -> dict:
    """Start ``rs_localizer_node`` (pinned to ``node_cpu`` with single-threaded BLAS/numba) and
    feed it frames from this process (pinned to another core).

    Args:
        seq: frames with ``uv`` (N, 2) px and ``xyz`` (N, 3) m (replayed cyclically with
            stamps 33.3 ms apart). cam: their :class:`~rs_localizer.camera.CameraModel`.
        solver: the node's solver. frames: frames per run. window: frames in flight in the
            pipelined run. node_cpu: core of the node (None: no pinning).
        result: dict to add the measurements to.
    Returns:
        ``result`` with ``lockstep`` and ``pipelined`` (every default output subscribed),
        ``pose_only`` (lock-step with only ``pose`` subscribed) (each: hz,
        latency_ms_median/p99/max, node_cpu_ms_per_frame: the node process's CPU time, all
        its threads, over the run divided by its frames, ...) and ``node_stages_ms`` (the
        node's own stage medians from its diagnostics).
    Raises:
        RuntimeError: the node did not start.
    """
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseStamped
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import CameraInfo, PointCloud2

    from rs_localizer.ros.conversions import camera_info_msg, stamp_to_ns
    from rs_localizer.ros.pointcloud import correspondence_cloud

    result = {} if result is None else result
    offset = cam.time_offset(0.0, cam.reference_line)
    period = 33_333_333
    graph = _BenchGraph(
        "rs_localizer_bench",
        {"solver": solver},
        ["/bench/correspondences", "/bench/camera_info"],
        node_cpu,
    )
    node, n, ex, qos = graph.process, graph.node, graph.ex, graph.qos
    node_cpu = graph.node_cpu
    pub = n.create_publisher(PointCloud2, "/bench/correspondences", qos)
    pub_info = n.create_publisher(CameraInfo, "/bench/camera_info", qos)
    recv = {}
    others = graph.consume_outputs("/bench")
    n.create_subscription(
        PoseStamped,
        "/bench/pose",
        lambda m: recv.setdefault(stamp_to_ns(m.header.stamp), time.perf_counter()),
        qos,
    )
    result.update(node_cpu=node_cpu)
    try:
        if not node.wait_ready(180):
            raise RuntimeError(f"node did not start:\n{node.log}")
        end = time.monotonic() + 30
        while (
            pub.get_subscription_count() == 0
            or pub_info.get_subscription_count() == 0
            or n.count_publishers("/bench/pose") == 0
            or n.count_publishers("/bench/pose_with_covariance") == 0
        ) and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        t0 = seq[0].stamp_ns
        pub_info.publish(camera_info_msg(cam, "camera", t0))
        graph.spin(0.3)

        def raw_frame(i):
            f = seq[i % len(seq)]
            stamp = t0 + i * period
            return stamp, serialize_message(
                correspondence_cloud(f.uv, f.xyz, frame_id="camera", stamp=stamp)
            )

        def run(tag, count, start, win):
            msgs = [raw_frame(start + i) for i in range(count)]  # serialized up front
            sent = {}
            out_stamp = {s: s + int(round(offset * 1e9)) for s, _ in msgs}
            k = 0  # frames sent
            waiting = []  # output stamps of the frames sent and not answered yet
            cpu0 = node.cpu_seconds()
            wall0 = time.perf_counter()
            deadline = wall0 + 60 + count * 0.5
            while time.perf_counter() < deadline:
                waiting = [o for o in waiting if o not in recv]
                if k == count and not waiting:
                    break
                if k < count and len(waiting) < win:
                    s, raw = msgs[k]
                    sent[s] = time.perf_counter()
                    pub.publish(raw)
                    waiting.append(out_stamp[s])
                    k += 1
                    continue
                ex.spin_once(timeout_sec=0.001)
            wall = time.perf_counter() - wall0
            cpu = node.cpu_seconds() - cpu0
            lat = np.array(
                [
                    recv[out_stamp[s]] - sent[s]
                    for s, _ in msgs
                    if s in sent and out_stamp[s] in recv
                ]
            )
            got = len(lat)
            r = {
                "frames": count,
                "answered": got,
                "wall_s": wall,
                "hz": got / wall if wall > 0 else 0.0,
                "latency_ms_median": float(np.median(lat) * 1e3) if got else float("nan"),
                "latency_ms_p99": float(np.percentile(lat, 99) * 1e3) if got else float("nan"),
                "latency_ms_max": float(lat.max() * 1e3) if got else float("nan"),
                "node_cpu_ms_per_frame": cpu / count * 1e3,
            }
            log(
                f"{tag:>9}: {got}/{count} poses in {wall:.2f} s = {r['hz']:.1f} Hz; latency "
                f"median {r['latency_ms_median']:.2f} ms, p99 {r['latency_ms_p99']:.2f} ms, "
                f"max {r['latency_ms_max']:.2f} ms; node CPU {r['node_cpu_ms_per_frame']:.2f} ms "
                "per frame"
            )
            return r

        diag = {}

        def on_diag(m):
            for st in m.status:
                if st.name.endswith("/bench/rs_localizer"):
                    diag.update({kv.key: kv.value for kv in st.values})

        n.create_subscription(DiagnosticArray, "/diagnostics", on_diag, qos)
        run("warm-up", 10, 0, 1)
        result["lockstep"] = run("lock-step", frames, 10, 1)
        result["pipelined"] = run(f"window {window}", frames, 10 + frames, window)
        for sub in others:  # the node builds only the pose now (once it has seen them go)
            n.destroy_subscription(sub)
        end = time.monotonic() + 10
        while n.count_subscribers("/bench/odom") and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        graph.spin(0.5)
        result["pose_only"] = run("pose only", frames, 10 + 2 * frames, 1)
        graph.spin(1.2)
        result["node_stages_ms"] = {
            k[:-10]: float(v) for k, v in diag.items() if k.endswith("_ms_median")
        }
        log(
            "inside the node (median ms): "
            + ", ".join(f"{k} {v:.2f}" for k, v in result["node_stages_ms"].items())
        )
    finally:
        graph.close()
    return result


def measure_cameras(
    seq,
    cam,
    n_cameras: int = 4,
    rate_hz: float = 30.0,
    seconds: float = 20.0,
    solver: str = "r6p_1lin",
    node_cpu: int | None = 0,
    log=print,
) -> dict:
    """Several cameras in one ``rs_localizer_node`` process (the ``cameras`` parameter), the
    process pinned to ``node_cpu`` with single-threaded BLAS/numba: every camera streams
    ``rate_hz`` frames for ``seconds`` (reliable QoS, the cameras' frames staggered evenly over
    the period, as free-running cameras are), every default output subscribed.

    Args:
        seq: frames with ``uv`` (N, 2) px and ``xyz`` (N, 3) m, replayed cyclically by every
            camera. cam: their :class:`~rs_localizer.camera.CameraModel`. n_cameras: camera
            namespaces ``cam0``.. under ``/bench``. rate_hz: frames per second per camera.
            seconds: length of the stream (after a 1 s warm-up stream that is not counted).
        solver: the node's solver. node_cpu: core of the node (None: no pinning).
    Returns:
        ``{"cameras": {name: {"sent", "answered", "latency_ms_median", "latency_ms_p99",
        "latency_ms_max", "frames_received", "frames_solved", "frames_failed",
        "frames_skipped", "frames_pending"}}, "answered", "sent", "latency_ms_median",
        "latency_ms_p99", "node_cpu_ms_per_frame"}`` (latency: publish -> pose received, all
        cameras pooled; the frame counts from each camera's diagnostics after the stream; CPU:
        the node process's, all threads, from the stream's start to its last pose, per frame
        streamed, warm-up frames included).
    Raises:
        RuntimeError: the node did not start.
    """
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseStamped
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import CameraInfo, PointCloud2

    from rs_localizer.ros.conversions import camera_info_msg, stamp_to_ns
    from rs_localizer.ros.pointcloud import correspondence_cloud

    offset_ns = int(round(cam.time_offset(0.0, cam.reference_line) * 1e9))
    period = int(round(1e9 / rate_hz))
    names = [f"cam{k}" for k in range(n_cameras)]
    spaces = [f"/bench/{c}" for c in names]
    graph = _BenchGraph(
        "rs_localizer_bench_cameras",
        {"solver": solver, "cameras": names},
        [f"{ns}/{t}" for ns in spaces for t in ("correspondences", "camera_info")],
        node_cpu,
    )
    node, n, ex, qos = graph.process, graph.node, graph.ex, graph.qos
    pubs, infos, recv, diag = {}, {}, {}, {}
    keep = []
    for ns in spaces:
        pubs[ns] = n.create_publisher(PointCloud2, f"{ns}/correspondences", qos)
        infos[ns] = n.create_publisher(CameraInfo, f"{ns}/camera_info", qos)
        keep += graph.consume_outputs(ns)
        keep.append(
            n.create_subscription(
                PoseStamped,
                f"{ns}/pose",
                lambda m, ns=ns: recv.setdefault(
                    (ns, stamp_to_ns(m.header.stamp)), time.perf_counter()
                ),
                qos,
            )
        )

    def on_diag(m):
        for st in m.status:
            for ns in spaces:
                if st.name.endswith(f"{ns}/rs_localizer"):
                    diag[ns] = {kv.key: kv.value for kv in st.values}

    n.create_subscription(DiagnosticArray, "/diagnostics", on_diag, qos)
    sent = {}
    try:
        if not node.wait_ready(300, count=n_cameras):
            raise RuntimeError(f"node did not start:\n{node.log}")
        end = time.monotonic() + 30
        while time.monotonic() < end and not all(
            pubs[ns].get_subscription_count() and n.count_publishers(f"{ns}/pose") for ns in spaces
        ):
            ex.spin_once(timeout_sec=0.05)
        t0 = seq[0].stamp_ns
        for ns in spaces:
            infos[ns].publish(camera_info_msg(cam, "camera", t0))
        graph.spin(0.5)
        raw = {}  # (frame index) -> serialized cloud, built before the stream

        def message(i):
            if i not in raw:
                f = seq[i % len(seq)]
                raw[i] = serialize_message(
                    correspondence_cloud(f.uv, f.xyz, frame_id="camera", stamp=t0 + i * period)
                )
            return raw[i]

        warm = int(round(rate_hz))
        count = warm + int(round(rate_hz * seconds))
        for i in range(count):
            message(i)
        events = sorted(
            (i * period + k * period // n_cameras, i, ns)
            for i in range(count)
            for k, ns in enumerate(spaces)
        )
        cpu0 = node.cpu_seconds()
        wall0 = time.perf_counter()
        for due_ns, i, ns in events:
            due = wall0 + due_ns * 1e-9
            while True:
                left = due - time.perf_counter()
                if left <= 0:
                    break
                ex.spin_once(timeout_sec=min(left, 0.002) if left > 0.002 else 0)
            if i >= warm:
                sent[(ns, t0 + i * period + offset_ns)] = time.perf_counter()
            pubs[ns].publish(message(i))
        end = time.perf_counter() + 5.0
        while time.perf_counter() < end and not all(k in recv for k in sent):
            ex.spin_once(timeout_sec=0.01)
        cpu_per_frame = (node.cpu_seconds() - cpu0) / len(events)
        graph.spin(1.5)  # the diagnostics after the stream
    finally:
        graph.close()

    def stats(lat):
        lat = np.asarray(lat) * 1e3
        if not len(lat):
            return dict.fromkeys(("latency_ms_median", "latency_ms_p99", "latency_ms_max"), np.nan)
        return {
            "latency_ms_median": float(np.median(lat)),
            "latency_ms_p99": float(np.percentile(lat, 99)),
            "latency_ms_max": float(lat.max()),
        }

    result = {"cameras": {}}
    pooled = []
    for ns in spaces:
        lat = [recv[k] - t for k, t in sent.items() if k[0] == ns and k in recv]
        pooled += lat
        d = diag.get(ns, {})
        row = {"sent": sum(1 for k in sent if k[0] == ns), "answered": len(lat), **stats(lat)}
        for key in ("received", "solved", "failed", "skipped", "pending"):
            row[f"frames_{key}"] = int(float(d[f"frames_{key}"])) if f"frames_{key}" in d else -1
        result["cameras"][ns] = row
        log(
            f"{ns}: {row['answered']}/{row['sent']} poses; node counted received "
            f"{row['frames_received']}, solved {row['frames_solved']}, failed "
            f"{row['frames_failed']}, skipped {row['frames_skipped']}; latency median "
            f"{row['latency_ms_median']:.2f} ms, p99 {row['latency_ms_p99']:.2f} ms, max "
            f"{row['latency_ms_max']:.2f} ms"
        )
    result.update(
        sent=len(sent),
        answered=len(pooled),
        node_cpu_ms_per_frame=cpu_per_frame * 1e3,
        **stats(pooled),
    )
    return result
