"""The node's rig mode on images over DDS: 3 cameras x 640x480 RGB, lock-step or at a rate.

    python -m benchmarks.bench_rig_node_images [--frames 30] [--cameras 3] [--rate HZ]

Renders every camera's view of the ``aruco_room`` marker scene at the rig's ``shake`` motion
composed with its mounting (:func:`rs_localizer.sim.render.renderer.render_rig_frames`: the ``vga``
camera preset, 30 ms readout, cameras looking front, 35 deg left and right, first frames 0, 4 and 8
ms apart), starts ``rs_localizer_node`` with ``rig.cameras`` (``frontend: aruco``, reliable image
subscriptions) in a subprocess pinned to one core, and from this process (pinned to the other; the
package's Fast DDS profile, so that an image goes through shared memory) publishes each rig frame's
images on ``/rig/<camera>/image_raw`` and waits for its pose (lock-step). Reports the rig frames
posed, the lock-step rate (rig frames per second of wall time, the round trip included), the node
process's CPU time per rig frame (all its threads, ``/proc``) and the poses' median and maximum
errors against the truth. The first ``--warm`` rig frames (numba caches loading, OpenCV's first
calls) are sent but not timed.

With ``--rate HZ`` the rig frames are sent at that rate, as cameras do, without waiting for
the poses; then the node's /diagnostics are read once it is idle: every camera's received,
solved, failed, skipped and pending frames (with the reasons), the rig frames' counts, and the
share of the poses more than 0.1 deg from the truth, and how long after the last images the
last pose came (how far the node lags behind the cameras).
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["main", "run_benchmark"]

T0 = 1_700_000_000_000_000_000


def _image_msg(img, stamp_ns, frame_id):
    from sensor_msgs.msg import Image

    from rs_localizer.ros.conversions import ns_to_stamp

    m = Image()
    m.header.stamp = ns_to_stamp(stamp_ns)
    m.header.frame_id = frame_id
    m.height, m.width = int(img.shape[0]), int(img.shape[1])
    m.encoding = "rgb8"
    img = np.ascontiguousarray(img)
    m.step = int(img.strides[0])
    m.data = img.tobytes()
    return m


def run_benchmark(
    frames: int = 30,
    cameras: int = 3,
    warm: int = 3,
    dds_profile: bool = True,
    log=print,
    rate: float | None = None,
    render_cache: str | None = None,
) -> dict:
    """Render, start the node, send lock-step (``rate`` None) or at ``rate`` Hz; returns the
    figures (see the module docstring). ``dds_profile`` False: this process (the images'
    sender) without the package's Fast DDS profile, as a camera driver started without it.
    ``render_cache``: a directory keeping the rendered images between runs (your own files:
    loaded with pickle)."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseStamped
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo, Image

    from rs_localizer.ros.conversions import camera_info_msg, quaternion_from_matrix
    from rs_localizer.ros.dds_profile import apply_default_profile
    from rs_localizer.ros.process import NodeProcess, random_domain_id, ros_env, write_params_yaml
    from rs_localizer.sim.render import render_rig_frames, vga_rig

    from .bench_client import SINGLE_THREAD_ENV

    cams = vga_rig(cameras)
    tic = time.perf_counter()
    cache = None if render_cache is None else Path(render_cache) / f"rig_{cameras}_{frames}.pkl"
    if cache is not None and cache.exists():
        with cache.open("rb") as f:
            rendered, motion = pickle.load(f)
    else:
        rendered, motion = render_rig_frames(cams, frames, seed=0)
        if cache is not None:
            cache.parent.mkdir(parents=True, exist_ok=True)
            with cache.open("wb") as f:
                pickle.dump((rendered, motion), f)
    log(f"rendered {len(rendered)} images in {time.perf_counter() - tic:.1f} s")
    params = {
        "warmup": False,
        "publish_tf": False,
        "frontend": "aruco",
        "frontend_map": "aruco_room",
        "rig.cameras": [c.name for c in cams],
    }
    for c in cams:
        q = quaternion_from_matrix(c.R_rig_cam)
        params[f"rig.{c.name}.mounting"] = [float(x) for x in (*c.p_rig_cam, *q)]
        params[f"rig.{c.name}.line_delay"] = float(c.camera.line_delay)
        params[f"rig.{c.name}.direction"] = c.camera.readout
    ncpu = os.cpu_count() or 1
    node_cpu = 0 if ncpu >= 2 else None
    domain = random_domain_id()
    env = ros_env(domain, {**os.environ, **SINGLE_THREAD_ENV})
    os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
    tmp = Path(tempfile.mkdtemp(prefix="rs_localizer_bench_rig_"))
    yaml = write_params_yaml(
        tmp / "rig.yaml",
        params,
        reliable_topics=[f"/rig/{c.name}/image_raw" for c in cams],
    )
    proc = NodeProcess(
        [yaml], namespace="/rig", env=env, log=tmp / "node.log",
        cpus=None if node_cpu is None else [node_cpu],
    )  # fmt: skip
    if node_cpu is not None and hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {(node_cpu + 1) % ncpu})
    if dds_profile:  # (the sender's shared-memory segment must hold an image)
        apply_default_profile()
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = rclpy.create_node("bench_rig_client", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    pub_img = {c.name: node.create_publisher(Image, f"/rig/{c.name}/image_raw", qos) for c in cams}
    pub_info = {
        c.name: node.create_publisher(CameraInfo, f"/rig/{c.name}/camera_info", qos) for c in cams
    }
    poses = []
    node.create_subscription(PoseStamped, "/rig/pose", poses.append, qos)

    def wait(pred, timeout):
        end = time.monotonic() + timeout
        while time.monotonic() < end and not pred():
            ex.spin_once(timeout_sec=0.005)
        return pred()

    try:
        if not proc.wait_ready(120.0):
            raise RuntimeError(f"the node did not start:\n{proc.log}")
        ok = wait(
            lambda: (
                all(p.get_subscription_count() > 0 for p in pub_img.values())
                and node.count_publishers("/rig/pose") > 0
            ),
            30.0,
        )
        if not ok:
            raise RuntimeError("the node and the client did not match")
        for _ in range(3):  # (camera_info: sensor-data QoS on the node's side)
            for c in cams:
                pub_info[c.name].publish(camera_info_msg(c.camera, c.name, T0))
            wait(lambda: False, 0.3)
        by_index: dict[int, list] = {}
        for f in rendered:
            by_index.setdefault(f.index, []).append(f)
        msgs = {k: [(f.name, _image_msg(f.image, f.stamp_ns, f.name)) for f in fs]
                for k, fs in by_index.items()}  # fmt: skip
        if rate is not None:
            return _send_at_rate(node, ex, wait, pub_img, msgs, poses, rate, motion, warm,
                                 DiagnosticArray)  # fmt: skip
        timed = []
        cpu0 = t0 = None
        for k in sorted(msgs):
            if k == warm:
                cpu0, t0 = proc.cpu_seconds(), time.perf_counter()
            n = len(poses)
            sent = time.perf_counter()
            for name, m in msgs[k]:
                pub_img[name].publish(m)
            if not wait(lambda n=n: len(poses) > n, 10.0):
                log(f"rig frame {k}: no pose within 10 s")
                continue
            if k >= warm:
                timed.append(time.perf_counter() - sent)
        wall = time.perf_counter() - t0
        cpu = proc.cpu_seconds() - cpu0
        n_timed = len(msgs) - warm
        e = _pose_errors(poses, motion)
        e = e if len(e) else np.full((1, 2), np.nan)
        out = {
            "cameras": len(cams),
            "rig_frames_sent": len(msgs),
            "rig_frames_posed": len(poses),
            "timed_rig_frames": n_timed,
            "lockstep_hz": n_timed / wall,
            "round_trip_ms_median": float(np.median(timed) * 1e3) if timed else float("nan"),
            "node_cpu_ms_per_rig_frame": cpu / n_timed * 1e3,
            "rotation_deg_median": float(np.median(e[:, 0])),
            "rotation_deg_max": float(np.max(e[:, 0])),
            "position_mm_median": float(np.median(e[:, 1])),
            "position_mm_max": float(np.max(e[:, 1])),
            "node_cpu": node_cpu,
            "sender_dds_profile": dds_profile,
            "load_average": os.getloadavg()[0],
        }
        return out
    finally:
        ex.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
        proc.stop()


def _pose_errors(poses, motion) -> np.ndarray:
    """(N, 2) rotation (deg) and position (mm) errors of the poses against the truth."""
    from rs_localizer.geometry import rotation_angle_deg
    from rs_localizer.ros.conversions import pose_from_msg
    from rs_localizer.sim.trajectory import rig_truth

    errs = []
    for m in poses:
        stamp = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
        R, p, _, _ = rig_truth(motion, (stamp - T0) * 1e-9)
        Re, pe = pose_from_msg(m.pose)
        errs.append((rotation_angle_deg(Re, R), np.linalg.norm(pe - p) * 1e3))
    return np.array(errs) if errs else np.zeros((0, 2))


def _send_at_rate(node, ex, wait, pub_img, msgs, poses, rate, motion, warm, diag_type) -> dict:
    """Send the first ``warm`` rig frames lock-step (the node's first calls), then rig frame
    k's images at k / rate s; read the node's counts once it is idle (no pose for 5 s)."""
    statuses = []
    node.create_subscription(diag_type, "/diagnostics", statuses.append, 10)
    keys = sorted(msgs)
    for k in keys[:warm]:
        n = len(poses)
        for name, m in msgs[k]:
            pub_img[name].publish(m)
        wait(lambda n=n: len(poses) > n, 60.0)
    t0 = time.perf_counter()
    late = 0.0
    for k in keys[warm:]:
        due = t0 + (k - keys[warm]) / rate
        while time.perf_counter() < due:
            ex.spin_once(timeout_sec=max(0.0, min(0.002, due - time.perf_counter())))
        late = max(late, time.perf_counter() - due)
        for name, m in msgs[k]:
            pub_img[name].publish(m)
    sent_s = time.perf_counter() - t0
    sent_at = time.monotonic()
    n, quiet = -1, time.monotonic()
    while time.monotonic() - quiet < 5.0:  # (until no pose for 5 s)
        if len(poses) != n:
            n, quiet = len(poses), time.monotonic()
        wait(lambda: False, 0.1)
    statuses.clear()
    wait(lambda: bool(statuses), 30.0)
    values = {}
    for arr in statuses[-1:]:
        for st in arr.status:
            values = {kv.key: kv.value for kv in st.values}
            values["level"], values["message"] = int.from_bytes(st.level, "little"), st.message
    e = _pose_errors(poses, motion)
    off = e[:, 0] > 0.1 if len(e) else np.zeros(0, bool)
    return {
        "rate_hz": rate,
        "rig_frames_sent": len(msgs),
        "rig_frames_sent_lockstep": min(warm, len(msgs)),
        "send_seconds": sent_s,
        "send_late_max_ms": late * 1e3,
        "last_pose_after_send_s": quiet - sent_at,
        "poses": len(poses),
        "poses_off_0.1deg": int(off.sum()),
        "rotation_deg_max": float(e[:, 0].max()) if len(e) else float("nan"),
        "position_mm_max": float(e[:, 1].max()) if len(e) else float("nan"),
        "diagnostics": values,
        "load_average": os.getloadavg()[0],
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=30, help="frames per camera (default 30)")
    ap.add_argument("--cameras", type=int, default=3, choices=(1, 2, 3))
    ap.add_argument("--warm", type=int, default=3, help="rig frames sent before timing")
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    ap.add_argument(
        "--no-dds-profile",
        action="store_true",
        help="send the images without the package's Fast DDS profile (as a driver without it)",
    )
    ap.add_argument(
        "--rate",
        type=float,
        default=None,
        help="send the rig frames at this rate (Hz) instead of lock-step and report the node's "
        "frame counts",
    )
    ap.add_argument(
        "--render-cache",
        default=None,
        help="a directory of your own keeping the rendered images between runs (pickle)",
    )
    a = ap.parse_args(argv)
    if a.frames <= a.warm:
        ap.error("--frames must exceed --warm")
    r = run_benchmark(
        a.frames,
        a.cameras,
        a.warm,
        not a.no_dds_profile,
        log=(lambda *x: None) if a.json else print,
        rate=a.rate,
        render_cache=a.render_cache,
    )
    if a.json or a.rate is not None:
        print(json.dumps(r, indent=1))
        return 0
    print(
        f"{r['cameras']} cameras x 640x480 RGB, lock-step: {r['rig_frames_posed']}/"
        f"{r['rig_frames_sent']} rig frames posed; {r['lockstep_hz']:.1f} rig frames/s over "
        f"{r['timed_rig_frames']} timed (round trip median {r['round_trip_ms_median']:.1f} ms); "
        f"node CPU {r['node_cpu_ms_per_rig_frame']:.1f} ms per rig frame; errors median/max "
        f"{r['rotation_deg_median']:.4f}/{r['rotation_deg_max']:.4f} deg, "
        f"{r['position_mm_median']:.2f}/{r['position_mm_max']:.2f} mm "
        f"(load average {r['load_average']:.1f})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
