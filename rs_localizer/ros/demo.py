"""``rs-localizer demo`` (``make demo``): the node on the sample bag over real DDS.

Starts two node processes with ``config/rs_localizer.yaml``: the configured RS solver in
namespace ``/camera`` and, for comparison, the global-shutter ``p3p`` solver in ``/p3p`` (same
inputs, remapped). Plays the bag in lock-step (each frame waits for both poses and twists),
then prints per-frame and summary accuracy against the bag's ground truth.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["run_demo", "evaluate_outputs"]


def _solver_from_yaml(path) -> str:
    for line in Path(path).read_text().splitlines():
        s = line.split("#", 1)[0].strip()
        if s.startswith("solver:"):
            return s.split(":", 1)[1].strip().strip("'\"")
    return "r6p_1lin"


def evaluate_outputs(frames, gt, namespaces):
    """Per-frame errors of the pose/twist outputs of each namespace against ground truth.

    Returns ``{ns: [errors dict or None per frame]}`` (see :func:`bag.frame_errors`)."""
    from .bag import frame_errors
    from .conversions import pose_from_msg, stamp_to_ns, twist_from_msg

    out = {ns: [] for ns in namespaces}
    for f in frames:
        for ns in namespaces:
            pose = f["outputs"].get(f"{ns}/pose")
            twist = f["outputs"].get(f"{ns}/twist")
            if pose is None:
                out[ns].append(None)
                continue
            R, p = pose_from_msg(pose[1].pose)
            w = v = None
            if twist is not None:
                w, v = twist_from_msg(twist[1].twist)
            out[ns].append(frame_errors(R, p, w, v, gt, stamp_to_ns(pose[1].header.stamp)))
    return out


def _fmt(e, key, scale=1.0, width=7, prec=3):
    if not e or key not in e:
        return "-".rjust(width)
    return f"{e[key] * scale:{width}.{prec}f}"


def run_demo(bag=None, params=None, compare: str = "p3p", per_frame: bool = True,
             timeout: float = 5.0, out=sys.stdout) -> int:
    from .bag import format_summary, load_ground_truth, play, read_bag_info, summarize_errors
    from .process import NodeProcess, random_domain_id, repo_file, ros_env, write_params_yaml

    bag = Path(bag) if bag else repo_file("data", "sample")
    params = Path(params) if params else repo_file("config", "rs_localizer.yaml")
    if bag is None or not Path(bag).exists():
        print("sample bag not found (run `make sample-bag`)", file=sys.stderr)
        return 2
    if params is None or not Path(params).exists():
        print("config/rs_localizer.yaml not found", file=sys.stderr)
        return 2
    info = read_bag_info(bag)
    topics = info.get("topics", {})
    corr = topics.get("correspondences", "/camera/correspondences")
    cinfo = topics.get("camera_info", "/camera/camera_info")
    solver = _solver_from_yaml(params)
    domain = random_domain_id()
    env = ros_env(domain)
    import os

    os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    tmp = Path(tempfile.mkdtemp(prefix="rs_localizer_demo_"))
    qos = write_params_yaml(tmp / "qos.yaml", reliable_topics=[corr, cinfo])
    print(f"rs_localizer demo: bag {bag} ({info.get('frames', '?')} frames), params {params}, "
          f"ROS_DOMAIN_ID={domain}", file=out)
    nodes = {"/camera": NodeProcess([params, qos], namespace="/camera", env=env,
                                    log=tmp / "node_rs.log")}
    if compare:
        nodes["/p3p"] = NodeProcess(
            [params, qos], namespace="/p3p", node_name="rs_localizer_" + compare, env=env,
            remaps={"correspondences": corr, "camera_info": cinfo},
            params={"solver": compare}, log=tmp / "node_compare.log")
    names = {"/camera": solver, "/p3p": compare}
    try:
        t0 = time.monotonic()
        for ns, n in nodes.items():
            if not n.wait_ready(120):
                print(f"node {ns} did not start:\n{n.log}", file=sys.stderr)
                return 1
        print(f"nodes ready in {time.monotonic() - t0:.1f} s (JIT warm-up included); playing "
              "in lock-step over DDS ...", file=out)
        outs = tuple(f"{ns}/{k}" for ns in nodes for k in ("pose", "twist"))
        res = play(bag, lockstep=True, topics=[corr, cinfo], output_topics=outs,
                   timeout=timeout, retries=1, log=lambda m: print(m, file=out))
        gt = load_ground_truth(bag)
        errs = evaluate_outputs(res.frames, gt, list(nodes))
        n = len(res.frames)
        if per_frame:
            head = f"{'frame':>5} | {solver + ': rot[deg] pos[cm] w[rad/s] v[m/s]':<44}"
            if compare:
                head += f" | {compare + ': rot[deg] pos[cm]':<28} | gt |w| [rad/s]"
            print(head, file=out)
            for i, f in enumerate(res.frames):
                e = errs["/camera"][i]
                line = (f"{i:5d} | {' ' * (len(solver) + 1)}{_fmt(e, 'rot_deg')}  "
                        f"{_fmt(e, 'pos_m', 100, 6, 2)}  {_fmt(e, 'angvel')}  "
                        f"{_fmt(e, 'linvel')}")
                line = f"{line:<52}"
                if compare:
                    c = errs["/p3p"][i]
                    line += (f" | {' ' * (len(compare) + 1)}{_fmt(c, 'rot_deg')}  "
                             f"{_fmt(c, 'pos_m', 100, 6, 2)}")
                    line = f"{line:<84}"
                    ref = e or c
                    line += f" | {_fmt(ref, 'angvel_gt', 1, 5, 2)}"
                print(line, file=out)
        print("", file=out)
        print("summary (errors vs ground truth; the pose is at the image centre row):", file=out)
        summaries = {}
        for ns in nodes:
            summaries[ns] = summarize_errors(errs[ns])
            print("  " + format_summary(names[ns], summaries[ns], n), file=out)
        lat = res.latencies
        if len(lat):
            print(f"  lock-step round trip (publish -> all outputs): median "
                  f"{np.median(lat) * 1e3:.1f} ms, p99 {np.percentile(lat, 99) * 1e3:.1f} ms",
                  file=out)
        rs = summaries["/camera"]
        if compare and rs.get("rot_deg") and summaries["/p3p"].get("rot_deg"):
            a, b = rs["rot_deg"]["median"], summaries["/p3p"]["rot_deg"]["median"]
            pa, pb = rs["pos_m"]["median"], summaries["/p3p"]["pos_m"]["median"]
            print(f"  {solver} vs {compare}: median rotation error {b / max(a, 1e-12):.1f}x "
                  f"smaller, position error {pb / max(pa, 1e-12):.1f}x smaller; only {solver} "
                  "estimates the velocities", file=out)
        ok = rs.get("frames", 0) == n and n > 0
        if not ok:
            print(f"  {solver}: {rs.get('frames', 0)}/{n} frames with a pose; node log: "
                  f"{nodes['/camera'].log_path}", file=out)
        return 0 if ok else 1
    finally:
        for nd in nodes.values():
            nd.stop()
