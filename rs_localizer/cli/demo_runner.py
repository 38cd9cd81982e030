"""The runner of ``rs-localizer demo`` (:mod:`.demo` parses its options; ``make demo``): the
node on the sample bags over real DDS.

Two parts, each with two node processes: the configured RS solver in namespace ``/camera`` and,
for comparison, the global-shutter ``p3p`` solver in ``/p3p`` (same inputs, remapped). Each bag
is played in lock-step (each frame waits for both poses and twists), then per-frame and summary
accuracy against the bag's ground truth is printed.

1. Correspondences (``data/sample``, ``config/rs_localizer.yaml``): synthetic 2D-3D clouds.
2. Images (``data/sample_images``, plus ``config/rs_localizer_images.yaml``): rendered
   rolling-shutter images; the nodes run the front end named in the bag's ``sequence.json``
   (ArUco markers, map file next to the bag) on every image, then the same estimator.
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TextIO

import numpy as np

__all__ = ["run_bag_demo", "run_demo"]


def _solver_from_yaml(*paths) -> str:
    """The ``solver`` parameter of the last file that sets it (a plain line scan)."""
    solver = "r6p_1lin"
    for path in paths:
        for line in Path(path).read_text().splitlines():
            s = line.split("#", 1)[0].strip()
            if s.startswith("solver:"):
                solver = s.split(":", 1)[1].strip().strip("'\"")
    return solver


def _fmt(e, key, scale=1.0, width=7, prec=3):
    if not e or key not in e:
        return "-".rjust(width)
    return f"{e[key] * scale:{width}.{prec}f}"


def _image_setup(bag: Path, info: dict):
    """Node parameters and remaps for image mode from the bag's ``sequence.json``: the front
    end and its map file (next to the bag), the RS timing of the rendered camera."""
    topics = info.get("topics", {})
    image = topics.get("image", "/camera/image_raw")
    params = {"republish_correspondences": True}
    fe = info.get("frontend") or {}
    if fe.get("kind") in ("aruco", "features") and fe.get("map"):
        params["frontend"] = fe["kind"]
        params["frontend_map"] = str((bag / fe["map"]).resolve())
    rs = info.get("rs") or {}
    if rs.get("line_delay") is not None:
        params["rs.line_delay"] = float(rs["line_delay"])
        params["rs.readout_time"] = 0.0
    if rs.get("stamp_row") is not None:
        params["rs.stamp_row"] = float(rs["stamp_row"])
    return image, params


def run_bag_demo(
    bag: str | os.PathLike,
    params_files: Sequence[str | os.PathLike],
    *,
    images: bool = False,
    compare: str = "p3p",
    per_frame: bool = True,
    timeout: float = 5.0,
    out: TextIO = sys.stdout,
) -> int:
    """One demo part: two nodes (RS solver, ``compare``) on one bag, lock-step, accuracy.

    ``images``: feed the bag's ``image`` topic (the nodes run the front end of its
    ``sequence.json``) instead of its ``correspondences``. Returns 0 when the RS node answered
    every frame."""
    from ..accuracy import format_summary, summarize_errors
    from ..ros.bags.accuracy import evaluate_outputs
    from ..ros.bags.bag_io import load_ground_truth, read_bag_info
    from ..ros.bags.play import play
    from ..ros.process import (
        NodeProcess,
        random_domain_id,
        ros_env,
        user_domain_id,
        write_params_yaml,
    )

    bag = Path(bag)
    info = read_bag_info(bag)
    topics = info.get("topics", {})
    cinfo = topics.get("camera_info", "/camera/camera_info")
    extra = {}
    if images:
        frame_topic, extra = _image_setup(bag, info)
        remap_key = "image"
    else:
        frame_topic = topics.get("correspondences", "/camera/correspondences")
        remap_key = "correspondences"
    solver = _solver_from_yaml(*params_files)
    domain = user_domain_id()
    domain = random_domain_id() if domain is None else domain  # (none set: an isolated one)
    env = ros_env(domain)
    os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    tmp = Path(tempfile.mkdtemp(prefix="rs_localizer_demo_"))
    qos = write_params_yaml(tmp / "qos.yaml", reliable_topics=[frame_topic, cinfo])
    files = [*params_files, qos]
    mode = "image mode" if images else "correspondences"
    print(
        f"rs_localizer demo ({mode}): bag {bag} ({info.get('frames', '?')} frames), params "
        + ", ".join(str(f) for f in params_files)
        + f", ROS_DOMAIN_ID={domain}",
        file=out,
    )
    if images:
        print(
            f"  {frame_topic} -> {extra.get('frontend', 'configured')} front end (map "
            f"{extra.get('frontend_map', 'from the parameter files')}), line delay "
            f"{extra.get('rs.line_delay', float('nan')) * 1e6:.2f} us/line",
            file=out,
        )
    remaps = {remap_key: frame_topic, "camera_info": cinfo}
    nodes = {
        "/camera": NodeProcess(
            files,
            namespace="/camera",
            env=env,
            remaps=remaps,
            params=extra,
            log=tmp / "node_rs.log",
        )
    }
    if compare:
        nodes["/p3p"] = NodeProcess(
            files,
            namespace="/p3p",
            node_name="rs_localizer_" + compare,
            env=env,
            remaps=remaps,
            params={**extra, "solver": compare, "republish_correspondences": False},
            log=tmp / "node_compare.log",
        )
    names = {"/camera": solver, "/p3p": compare}
    ok = False  # (the node logs in tmp are kept when something failed)
    try:
        t0 = time.monotonic()
        for ns, n in nodes.items():
            if not n.wait_ready(300):
                print(f"node {ns} did not start:\n{n.log}", file=sys.stderr)
                return 1
        print(
            f"nodes ready in {time.monotonic() - t0:.1f} s; playing in lock-step over DDS ...",
            file=out,
        )
        for ns, n in nodes.items():
            if "compiling kernels in the background" in n.log:
                print(
                    f"  {ns}: no compiled kernels cached yet: the node compiles them in the "
                    "background and solves frames on the uncompiled path meanwhile (every frame "
                    "alone, no tracking); `rs-localizer compile` once avoids this",
                    file=out,
                )
        outs = tuple(f"{ns}/{k}" for ns in nodes for k in ("pose", "twist"))
        if images:
            outs += ("/camera/correspondences_out",)
        res = play(
            bag,
            lockstep=True,
            topics=[frame_topic, cinfo],
            output_topics=outs,
            timeout=timeout,
            retries=1,
            domain_id=domain,
            log=lambda m: print(m, file=out),
            late_topics=tuple(f"{ns}/twist" for ns in nodes),
        )  # (fused: one frame late)
        gt = load_ground_truth(bag)
        errs = evaluate_outputs(res.frames, gt, list(nodes))
        n = len(res.frames)
        npts = [
            f["outputs"]["/camera/correspondences_out"][1].width
            if "/camera/correspondences_out" in f["outputs"]
            else None
            for f in res.frames
        ]
        if per_frame:
            head = f"{'frame':>5} | {solver + ': rot[deg] pos[cm] w[rad/s] v[m/s]':<44}"
            if compare:
                head += f" | {compare + ': rot[deg] pos[cm]':<28} | gt |w| [rad/s]"
            if images:
                head += " | corners"
            print(head, file=out)
            for i, _f in enumerate(res.frames):
                e = errs["/camera"][i]
                line = (
                    f"{i:5d} | {' ' * (len(solver) + 1)}{_fmt(e, 'rot_deg')}  "
                    f"{_fmt(e, 'pos_m', 100, 6, 2)}  {_fmt(e, 'angvel')}  "
                    f"{_fmt(e, 'linvel')}"
                )
                line = f"{line:<52}"
                if compare:
                    c = errs["/p3p"][i]
                    line += (
                        f" | {' ' * (len(compare) + 1)}{_fmt(c, 'rot_deg')}  "
                        f"{_fmt(c, 'pos_m', 100, 6, 2)}"
                    )
                    line = f"{line:<84}"
                    ref = e or c
                    line += f" | {_fmt(ref, 'angvel_gt', 1, 5, 2)}"
                    line = f"{line:<100}"
                if images:
                    line += f" | {'-' if npts[i] is None else npts[i]:>7}"
                print(line.rstrip(), file=out)
        print("", file=out)
        print(
            f"summary ({mode}; errors vs ground truth; the pose is at the image centre row):",
            file=out,
        )
        summaries = {}
        for ns in nodes:
            summaries[ns] = summarize_errors(errs[ns])
            print("  " + format_summary(names[ns], summaries[ns], n), file=out)
        got = [k for k in npts if k is not None]
        if images and got:
            print(
                f"  front end: {np.mean(got):.0f} marker corners per image "
                f"(min {min(got)}, max {max(got)})",
                file=out,
            )
        lat = res.latencies
        if len(lat):
            print(
                f"  lock-step round trip (publish -> all outputs): median "
                f"{np.median(lat) * 1e3:.1f} ms, p99 {np.percentile(lat, 99) * 1e3:.1f} ms"
                + (" (front end included)" if images else ""),
                file=out,
            )
        rs = summaries["/camera"]
        if compare and rs.get("rot_deg") and summaries["/p3p"].get("rot_deg"):
            a, b = rs["rot_deg"]["median"], summaries["/p3p"]["rot_deg"]["median"]
            pa, pb = rs["pos_m"]["median"], summaries["/p3p"]["pos_m"]["median"]
            print(
                f"  {solver} vs {compare}: median rotation error {b / max(a, 1e-12):.1f}x "
                f"smaller, position error {pb / max(pa, 1e-12):.1f}x smaller; only {solver} "
                "estimates the velocities",
                file=out,
            )
        if res.timeouts:
            print(
                f"  the player timed out on {res.timeouts} of {n} frames (no output within "
                f"{timeout:g} s); node log: {nodes['/camera'].log_path}",
                file=out,
            )
        ok = rs.get("frames", 0) == n and n > 0
        if not ok:
            print(
                f"  {solver}: {rs.get('frames', 0)}/{n} frames with a pose; node log: "
                f"{nodes['/camera'].log_path}",
                file=out,
            )
        return 0 if ok else 1
    finally:
        for nd in nodes.values():
            nd.stop()
        if ok:
            shutil.rmtree(tmp, ignore_errors=True)


def run_demo(
    bag: str | os.PathLike | None = None,
    params: str | os.PathLike | None = None,
    compare: str = "p3p",
    per_frame: bool = True,
    timeout: float = 5.0,
    out: TextIO = sys.stdout,
    images: bool = True,
    image_bag: str | os.PathLike | None = None,
    image_params: str | os.PathLike | None = None,
    correspondences: bool = True,
) -> int:
    """``make demo``: the correspondence demo on ``bag`` (default ``data/sample``) and, with
    ``images``, the image-mode demo on ``image_bag`` (default ``data/sample_images``) with
    ``params`` + ``image_params`` (default ``config/rs_localizer_images.yaml``).
    Returns 0 when every part succeeded, 2 when a bag or parameter file is missing."""
    from ..ros.process import repo_file

    params = Path(params) if params else repo_file("config", "rs_localizer.yaml")
    if params is None or not Path(params).exists():
        print("config/rs_localizer.yaml not found", file=sys.stderr)
        return 2
    parts = []
    if correspondences:
        bag = Path(bag) if bag else repo_file("data", "sample")
        if bag is None or not Path(bag).exists():
            print("sample bag not found (run `make sample-bag`)", file=sys.stderr)
            return 2
        parts.append((bag, [params], False))
    if images:
        ibag = Path(image_bag) if image_bag else repo_file("data", "sample_images")
        iparams = (
            Path(image_params) if image_params else repo_file("config", "rs_localizer_images.yaml")
        )
        if ibag is None or not Path(ibag).exists():
            print("image sample bag not found (run `make sample-bag`)", file=sys.stderr)
            return 2
        if iparams is None or not Path(iparams).exists():
            print("config/rs_localizer_images.yaml not found", file=sys.stderr)
            return 2
        parts.append((ibag, [params, iparams], True))
    rc = 0
    for k, (b, files, img) in enumerate(parts):
        if k:
            print("", file=out)
        rc = max(
            rc,
            run_bag_demo(
                b, files, images=img, compare=compare, per_frame=per_frame, timeout=timeout, out=out
            ),
        )
    return rc
