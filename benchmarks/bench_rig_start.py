"""A rig's start on an empty numba cache: what its first rig frames cost before any kernel is
compiled.

    python -m benchmarks.bench_rig_start [--points 100 300] [--rounds 2] [--node-rounds 3]
        [--sources . OTHER_CHECKOUT] [--no-node] [--json out.json]

``frame``: a fresh Python process with an empty ``NUMBA_CACHE_DIR`` poses 11 simulated rig
frames (3 cameras x ``--points`` correspondences each, 20 % outliers, 0.5 px noise, turning
1.5 rad/s) with ``estimate_rig_pose(..., implementation="numpy")`` (what a rig node's frames
take while its kernels compile in the background): the kernels numba compiled for the first
frame (``jit_cache.compile_progress``) and their seconds, the first frame's wall time, and the
median processor time of the other 10.

``node``: ``rs_localizer_node`` with ``rig.cameras`` (3 simulated cameras, ``warmup`` on) in a
subprocess with an empty ``NUMBA_CACHE_DIR``; this process sends each camera's correspondence
clouds (100 points) in turn, each after the camera's camera_info, and reports the seconds from
starting the node process to its ``ready:`` line and to the first pose on ``/rig/pose`` (the
kernels compile meanwhile in the node's background process, at a lower priority).

``--sources``: checkouts whose code runs (``PYTHONPATH``), interleaved round by round (a
comparison of two versions on one machine at the same load). One BLAS thread throughout.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["frame_run", "main", "node_run"]

ROOT = Path(__file__).resolve().parents[1]
ONE_THREAD = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}

_FRAME = """
import json, sys, time
import numpy as np
import rs_localizer
from rs_localizer.estimation.rig import estimate_rig_pose
from rs_localizer.runtime.jit_cache import compile_progress
from rs_localizer.sim import synthetic as sim_rig
n = int(sys.argv[1])
rng = np.random.default_rng(1)
rig = sim_rig.make_rig(3, rng)
frames = [sim_rig.rig_frame(rig, sim_rig.rig_motion(rng, 1.5, 1.5), [n] * 3, rng)
          for _ in range(11)]
with compile_progress() as prog:
    t = time.perf_counter()
    ok = [estimate_rig_pose(frames[0].views, implementation="numpy").success]
    first = time.perf_counter() - t
ts = []
for f in frames[1:]:
    t = time.process_time()
    ok.append(estimate_rig_pose(f.views, implementation="numpy").success)
    ts.append(time.process_time() - t)
print(json.dumps({"kernels": len(prog.kernels), "compile_s": prog.seconds,
                  "first_frame_s": first, "ms_median": 1e3 * float(np.median(ts)),
                  "solved": int(sum(ok)), "package": rs_localizer.__file__}))
"""


def _env(source: Path, cache: str) -> dict:
    return {**os.environ, **ONE_THREAD, "PYTHONPATH": str(source), "NUMBA_CACHE_DIR": cache}


def frame_run(source: Path, points: int) -> dict:
    """The ``frame`` measurement (module docstring) of the checkout ``source``."""
    with tempfile.TemporaryDirectory(prefix="rs_localizer_numba_") as cache:
        r = subprocess.run(
            [sys.executable, "-c", _FRAME, str(points)], env=_env(source, cache), cwd=source,
            capture_output=True, text=True, timeout=900, check=True,
        )  # fmt: skip
    out = json.loads(r.stdout.strip().splitlines()[-1])
    if not Path(out.pop("package")).is_relative_to(source):
        raise RuntimeError(f"the frame ran another checkout's code than {source}")
    return out


def node_run(source: Path, timeout: float = 300.0) -> dict:
    """The ``node`` measurement (module docstring) of the checkout ``source``."""
    import rclpy
    from geometry_msgs.msg import PoseStamped
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo, PointCloud2

    from rs_localizer.ros.conversions import camera_info_msg, ns_to_stamp, quaternion_from_matrix
    from rs_localizer.ros.pointcloud import correspondence_cloud
    from rs_localizer.ros.process import NodeProcess, random_domain_id, ros_env, write_params_yaml
    from rs_localizer.sim.trajectory import default_rig, generate_rig_video

    cams = default_rig(3)
    by = {c.name: c.camera for c in cams}
    frames, _, _ = generate_rig_video(cams, duration=1.0, num_points=100, seed=11)
    params = {"warmup": True, "publish_tf": False, "rig.cameras": [c.name for c in cams]}
    for c in cams:
        q = quaternion_from_matrix(c.R_rig_cam)
        params[f"rig.{c.name}.mounting"] = [float(x) for x in (*c.p_rig_cam, *q)]
        params[f"rig.{c.name}.line_delay"] = float(c.camera.line_delay)
        params[f"rig.{c.name}.direction"] = c.camera.readout
    domain = random_domain_id()
    tmp = Path(tempfile.mkdtemp(prefix="rs_localizer_bench_rig_start_"))
    env = ros_env(domain, _env(source, str(tmp / "numba")))
    os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
    yaml = write_params_yaml(tmp / "rig.yaml", params)
    here = os.getcwd()
    os.chdir(source)  # (python -m puts the working directory first on the node's path)
    try:
        t0 = time.perf_counter()
        proc = NodeProcess([yaml], namespace="/rig", env=env, log=tmp / "node.log")
    finally:
        os.chdir(here)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = rclpy.create_node("bench_rig_start", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    pub = {c.name: node.create_publisher(PointCloud2, f"/rig/{c.name}/correspondences", qos)
           for c in cams}  # fmt: skip
    info = {c.name: node.create_publisher(CameraInfo, f"/rig/{c.name}/camera_info", qos)
            for c in cams}  # fmt: skip
    poses: list = []
    node.create_subscription(PoseStamped, "/rig/pose", poses.append, qos)

    def wait(pred, seconds):
        end = time.monotonic() + seconds
        while time.monotonic() < end and not pred():
            ex.spin_once(timeout_sec=0.005)
        return pred()

    try:
        if not proc.wait_ready(timeout):
            raise RuntimeError(f"the node did not start:\n{proc.log}")
        ready = time.perf_counter() - t0
        probe = subprocess.run(
            [sys.executable, "-c", "import rs_localizer; print(rs_localizer.__file__)"],
            env=env, cwd=source, capture_output=True, text=True, check=True,
        )  # fmt: skip
        if not Path(probe.stdout.strip()).is_relative_to(source):
            raise RuntimeError(f"the node would run another checkout's code than {source}")
        subs = [*pub.values(), *info.values()]
        if not wait(lambda: all(p.get_subscription_count() > 0 for p in subs), 30.0):
            raise RuntimeError("the node and the client did not match")
        for f in frames:  # (camera_info with every cloud until the first pose)
            info[f.name].publish(camera_info_msg(by[f.name], f.name, f.stamp_ns))
            cloud = correspondence_cloud(
                f.uv, f.xyz, frame_id=f.name, stamp=ns_to_stamp(f.stamp_ns)
            )
            pub[f.name].publish(cloud)
            if wait(lambda: len(poses) > 0, 0.02):
                break
        if not wait(lambda: len(poses) > 0, timeout):
            raise RuntimeError(f"no rig pose within {timeout} s:\n{proc.log}")
        first = time.perf_counter() - t0
        return {"ready_s": ready, "first_pose_s": first, "load_average": os.getloadavg()[0]}
    finally:
        ex.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
        proc.stop()


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--points", type=int, nargs="+", default=[100, 300], help="per camera")
    p.add_argument("--rounds", type=int, default=2, help="frame measurements per source")
    p.add_argument("--node-rounds", type=int, default=3, help="node starts per source")
    p.add_argument("--sources", nargs="+", default=[str(ROOT)], help="checkouts to run")
    p.add_argument("--no-node", action="store_true", help="the frame measurement only")
    p.add_argument("--json", default=None)
    a = p.parse_args(argv)
    sources = [Path(s).resolve() for s in a.sources]
    rows = []
    for _ in range(a.rounds):
        for n in a.points:
            for s in sources:
                res = {"what": "frame", "source": str(s), "points": n, **frame_run(s, n)}
                print(json.dumps(res), flush=True)
                rows.append(res)
    if not a.no_node:
        for _ in range(a.node_rounds):
            for s in sources:
                res = {"what": "node", "source": str(s), **node_run(s)}
                print(json.dumps(res), flush=True)
                rows.append(res)
    print()
    for s in sources:
        print(s)
        for n in a.points:
            f = [x for x in rows if x["what"] == "frame" and x["source"] == str(s)
                 and x["points"] == n]  # fmt: skip
            if not f:
                continue
            print(f"  3 x {n} points: kernels compiled {sorted({x['kernels'] for x in f})}, "
                  f"first frame {min(x['first_frame_s'] for x in f):.3f}-"
                  f"{max(x['first_frame_s'] for x in f):.3f} s, then "
                  f"{min(x['ms_median'] for x in f):.1f}-{max(x['ms_median'] for x in f):.1f} "
                  "ms of processor time per rig frame (medians)")  # fmt: skip
        nd = [x for x in rows if x["what"] == "node" and x["source"] == str(s)]
        if nd:
            fp = np.array([x["first_pose_s"] for x in nd])
            rd = np.array([x["ready_s"] for x in nd])
            print(f"  node: ready {rd.min():.2f}-{rd.max():.2f} s, first rig pose "
                  f"{fp.min():.2f}-{fp.max():.2f} s after start ({len(nd)} starts)")  # fmt: skip
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
