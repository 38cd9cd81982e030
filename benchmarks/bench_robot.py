"""On-a-robot benchmarks: node start-up time from a non-editable, read-only install,
and memory per camera with several cameras in one process.

    python -m benchmarks.bench_robot startup [--venv /tmp/rsl_venv] [--create]
        [--fresh-copy] [--later 3] [--scenarios no-compile compile] [--rate-frames 40]
    python -m benchmarks.bench_robot rss [--cameras 1 4] [--frames 10] [--images]

``startup`` installs the package non-editable into ``--venv`` (``--create``: a new venv and
``pip install '.[ros]'`` from the source tree), makes the installed package directory
read-only (``chmod -R a-w``; when running as root, who ignores file modes, the directory is
also bind-mounted read-only in a private mount namespace with ``unshare -m``) and starts
``<venv>/bin/rs_localizer_node`` with the installed ``share/rs_localizer/config`` from a
directory outside the source tree, with an empty per-user cache (``XDG_CACHE_HOME``) for the
first start and the same cache for the later starts (``--fresh-copy``: instead of a venv, a
fresh copy of the committed source tree run with this interpreter, :func:`fresh_copy_env`).
For each start it reports:

* ``ready``: seconds from process start to the node's ``ready:`` log line (warm-up done,
  subscriptions up: a frame arriving now is solved without compiling);
* ``first pose``: seconds from process start until the pose of one frame of ``data/sample``
  published after ``ready`` arrived (adds DDS discovery of the publisher and one solve);
* ``poses of the first three frames``: the same for the third of three frames sent lock-step,
  and how many of the three were answered;
* on the first start, the lock-step rate over ``--rate-frames`` synthetic frames of 500
  correspondences sent next: on a cold cache the node solves them on the uncompiled path while
  its kernels compile in the background (whether they were loaded before the last frame is
  reported).

The targets are printed at the end: without the compile step, the poses of the first three
frames within 10 s, none lost, at least 10 Hz lock-step while compiling; ``rs-localizer
compile`` within 60 s; after it, the first pose of the first start within 5 s, of later
starts within 3 s.

Scenarios: ``no-compile`` (the package's compiled kernels deleted: at its first start the node
solves frames on the uncompiled path while it compiles them in the background into
``~/.cache/rs_localizer/numba``) and ``compile`` (``rs-localizer compile`` run
once after installing, while the package is writable, as docs/install.md's commands do;
its duration is reported too).

``rss`` starts ``rs_localizer_node`` (this environment) with ``cameras`` listing 1, then 4
namespaces (and once as a plain single node without ``cameras``), feeds ``--frames`` frames of
``data/sample`` (``--images``: the rendered ``data/sample_images`` through the ArUco front end)
to every camera in lock-step over DDS, and reads the process's resident memory (``VmRSS``, and
the peak ``VmHWM``) from ``/proc`` after the warm-up and after the frames. The cost of an extra
camera is ``(RSS(4) - RSS(1)) / 3``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

__all__ = ["installed_package_dir", "main", "measure_rss", "measure_start"]

ROOT = Path(__file__).resolve().parents[1]


def installed_package_dir(venv: Path) -> Path:
    out = subprocess.run(
        [
            str(venv / "bin" / "python"),
            "-c",
            "import importlib.util as u, os; "
            "print(os.path.dirname(u.find_spec('rs_localizer').origin))",
        ],
        capture_output=True,
        text=True,
        check=True,
        cwd="/",
    )
    return Path(out.stdout.strip().splitlines()[-1])


def _is_root() -> bool:
    return hasattr(os, "geteuid") and os.geteuid() == 0


def _set_writable(pkg: Path, writable: bool):
    mode = "u+w" if writable else "a-w"
    subprocess.run(["chmod", "-R", mode, str(pkg)], check=True)


def _remove_compiled(pkg: Path) -> int:
    n = 0
    for f in list(pkg.rglob("*.nbi")) + list(pkg.rglob("*.nbc")):
        f.unlink()
        n += 1
    return n


def measure_start(
    venv: Path,
    cache_home: Path,
    workdir: Path,
    read_only_mount: Path | None,
    sample_bag: Path,
    timeout: float = 600.0,
    log_path: Path | None = None,
    extra_args=(),
    rate_frames: int = 0,
) -> dict:
    """Start the installed node once; seconds to ``ready``, to the first pose and to the
    poses of the first three frames of ``sample_bag`` (lock-step), and with ``rate_frames``
    the lock-step rate of that many synthetic frames of 500 correspondences sent next (see
    the module docstring). Returns ``{"ready_s", "first_pose_s", "three_poses_s",
    "answered", "rate": {"hz", "answered", "frames", "compiled_before_end"} or None,
    "log"}``."""
    from rs_localizer.ros.bags.play import play
    from rs_localizer.ros.process import random_domain_id, ros_env

    domain = random_domain_id()
    env = ros_env(domain)
    env.update(XDG_CACHE_HOME=str(cache_home), HOME=str(workdir))
    env.pop("NUMBA_CACHE_DIR", None)
    env.pop("PYTHONPATH", None)
    share = venv / "share" / "rs_localizer" / "config" / "rs_localizer.yaml"
    node = [
        str(venv / "bin" / "rs_localizer_node"),
        "--ros-args",
        "--params-file",
        str(share),
        "-r",
        "__ns:=/camera",
        *extra_args,
    ]
    if read_only_mount is not None:
        p = str(read_only_mount)
        node = [
            "unshare",
            "-m",
            "sh",
            "-c",
            f"mount --bind '{p}' '{p}' && mount -o remount,bind,ro '{p}' '{p}' && exec \"$@\"",
            "sh",
            *node,
        ]
    log_path = log_path or Path(tempfile.mkstemp(prefix="rsl_start_", suffix=".log")[1])
    with open(log_path, "w") as logf:
        t0 = time.monotonic()
        proc = subprocess.Popen(
            node,
            env=env,
            cwd=workdir,
            stdout=logf,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        ready = first = None
        try:
            while time.monotonic() - t0 < timeout:
                text = log_path.read_text(errors="replace")
                if "ready:" in text:
                    ready = time.monotonic() - t0
                    break
                if proc.poll() is not None:
                    break
                time.sleep(0.02)
            answered_at = []
            rate = None
            if ready is not None:
                play(
                    sample_bag,
                    lockstep=True,
                    limit=3,
                    domain_id=domain,
                    timeout=30.0,
                    retries=0,
                    topics=["/camera/correspondences", "/camera/camera_info"],
                    output_topics=("/camera/pose",),
                    wait_subscribers=30.0,
                    log=lambda *a, **k: None,
                    on_frame=lambda f: answered_at.append(
                        time.monotonic() - t0 if f["outputs"] else None
                    ),
                )
                first = answered_at[0] if answered_at else None
                if rate_frames:
                    rate = _synthetic_rate(domain, rate_frames, log_path, sample_bag)
        finally:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
                try:
                    proc.wait(20)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait(5)
    three = answered_at[2] if len(answered_at) >= 3 and all(answered_at[:3]) else None
    return {
        "ready_s": ready,
        "first_pose_s": first,
        "three_poses_s": three,
        "answered": sum(1 for a in answered_at if a is not None),
        "rate": rate,
        "log": log_path.read_text(errors="replace"),
    }


def _synthetic_rate(domain: int, frames: int, log_path: Path, sample_bag: Path) -> dict:
    """Lock-step rate of the node in ``/camera`` on ``frames`` synthetic frames of 500
    correspondences (:mod:`rs_localizer.sim.trajectory`, their camera_info first), stamped
    after ``data/sample``'s; whether the node's log (``log_path``) said the kernels were
    loaded before the last frame was answered (None: no background compile, the kernels
    came from the cache)."""
    from rs_localizer.ros.bags.bag_io import CAMERA_INFO, PC2, RosbagsMessages, iter_messages
    from rs_localizer.ros.bags.play import play
    from rs_localizer.sim.trajectory import SequenceConfig, generate_sequence

    seq, _, cam, _ = generate_sequence(SequenceConfig(num_frames=10, num_points=500, seed=0))
    t_base = max(t for _, _, t, _ in iter_messages(sample_bag)) + 10_000_000_000
    period = 33_333_333
    rm = RosbagsMessages()
    msgs = [
        (
            "/camera/camera_info",
            CAMERA_INFO,
            t_base,
            bytes(rm.cdr(rm.camera_info(cam, t_base, "camera"), CAMERA_INFO)),
        )
    ]
    for i in range(frames):
        f = seq[i % len(seq)]
        stamp = t_base + (i + 1) * period
        raw = bytes(rm.cdr(rm.cloud(f.uv, f.xyz, f.ids, stamp, "camera"), PC2))
        msgs.append(("/camera/correspondences", PC2, stamp, raw))
    res = play(
        None,
        lockstep=True,
        messages=msgs,
        domain_id=domain,
        timeout=10.0,
        retries=0,
        output_topics=("/camera/pose",),
        wait_subscribers=30.0,
        log=lambda *a, **k: None,
    )
    text = log_path.read_text(errors="replace")
    return {
        "hz": res.answered / res.wall_time if res.wall_time > 0 else 0.0,
        "answered": res.answered,
        "frames": frames,
        "compiled_before_end": (
            "kernels compiled and loaded" in text
            if "compiling kernels in the background" in text
            else None
        ),
    }


def fresh_copy_env(dest: Path, python: str = sys.executable) -> Path:
    """A fresh copy of the source tree's committed files (``git archive HEAD``: no compiled
    kernels, no ``__pycache__``) in ``dest/src``, and ``dest/env`` laid out like a venv for
    :func:`measure_start`: ``bin/python``, ``bin/rs_localizer_node`` and ``bin/rs-localizer``
    run ``python`` (this interpreter: its site-packages) on the copy, ``share/rs_localizer``
    links to it. Returns ``dest/env``."""
    src, env = dest / "src", dest / "env"
    src.mkdir(parents=True)
    archive = subprocess.run(
        ["git", "-C", str(ROOT), "archive", "HEAD"], capture_output=True, check=True
    ).stdout
    subprocess.run(["tar", "-x", "-C", str(src)], input=archive, check=True)
    (env / "bin").mkdir(parents=True)
    (env / "share").mkdir()
    (env / "share" / "rs_localizer").symlink_to(src)
    runs = {
        "python": '"$@"',
        "rs_localizer_node": '-c "import sys; from rs_localizer.ros.runner import main; '
        'sys.exit(main())" "$@"',
        "rs-localizer": '-m rs_localizer "$@"',
    }
    for name, tail in runs.items():
        f = env / "bin" / name
        f.write_text(f"#!/bin/sh\nexport PYTHONPATH='{src}'\nexec '{python}' {tail}\n")
        f.chmod(0o755)
    return env


def _startup(args) -> int:
    venv = Path(args.venv).absolute()
    if args.fresh_copy:
        venv = fresh_copy_env(Path(tempfile.mkdtemp(prefix="rsl_fresh_")))
        print(f"fresh copy of the committed source tree (git archive HEAD): {venv.parent}")
    elif args.create:
        if venv.exists():
            pkg_old = None
            with contextlib.suppress(subprocess.CalledProcessError, FileNotFoundError):
                pkg_old = installed_package_dir(venv)
            if pkg_old is not None and pkg_old.exists():
                _set_writable(pkg_old, True)
            shutil.rmtree(venv)
        print(f"creating {venv} and installing {ROOT} (non-editable) ...", flush=True)
        subprocess.run([args.python, "-m", "venv", str(venv)], check=True)
        tic = time.monotonic()
        subprocess.run(
            [str(venv / "bin" / "pip"), "install", "-q", f"{ROOT}[ros]"], check=True, cwd="/"
        )
        print(f"pip install: {time.monotonic() - tic:.0f} s", flush=True)
        shutil.rmtree(ROOT / "build", ignore_errors=True)
    pkg = installed_package_dir(venv)
    sample = ROOT / "data" / "sample"
    mount = None
    if _is_root():
        if shutil.which("unshare") is None:
            print(
                "running as root without unshare: chmod alone does not make the package "
                "read-only for root",
                file=sys.stderr,
            )
            return 2
        mount = pkg
    work = Path(tempfile.mkdtemp(prefix="rsl_robot_"))
    results = {
        "package": str(pkg),
        "read_only": "chmod -R a-w"
        + (" + read-only bind mount (root ignores file modes)" if mount else ""),
        "scenarios": {},
    }
    print(f"package: {pkg} ({results['read_only']}); working directory {work}", flush=True)
    try:
        for scen in args.scenarios:
            _set_writable(pkg, True)
            out = {}
            if scen == "no-compile":
                print(
                    f"[{scen}] removed {_remove_compiled(pkg)} compiled kernel files from the "
                    "package",
                    flush=True,
                )
            elif scen == "compile":
                _remove_compiled(pkg)
                tic = time.monotonic()
                r = subprocess.run(
                    [str(venv / "bin" / "rs-localizer"), "compile"],
                    cwd=work,
                    capture_output=True,
                    text=True,
                    env={**os.environ, "HOME": str(work)},
                )
                out["compile_s"] = time.monotonic() - tic
                print(
                    r.stdout.strip().splitlines()[-1] if r.stdout.strip() else r.stderr, flush=True
                )
                print(f"[{scen}] rs-localizer compile: {out['compile_s']:.1f} s", flush=True)
                if r.returncode:
                    print(r.stderr, file=sys.stderr)
                    return 1
            else:
                raise ValueError(f"unknown scenario {scen!r}")
            _set_writable(pkg, False)
            cache = work / f"cache_{scen}"
            starts = []
            for k in range(1 + args.later):
                m = measure_start(
                    venv,
                    cache,
                    work,
                    mount,
                    sample,
                    log_path=work / f"{scen}_{k}.log",
                    rate_frames=args.rate_frames if k == 0 else 0,
                )
                label = "first start" if k == 0 else f"later start {k}"
                ready, first, three = (
                    None if m[key] is None else round(m[key], 2)
                    for key in ("ready_s", "first_pose_s", "three_poses_s")
                )
                print(
                    f"[{scen}] {label}: ready {ready} s, first pose {first} s, poses of the "
                    f"first three frames {three} s ({m['answered']}/3 answered)",
                    flush=True,
                )
                if m["rate"] is not None:
                    r = m["rate"]
                    when = {
                        True: "kernels compiled in the background and loaded before the end",
                        False: "kernels still compiling in the background at the end",
                        None: "kernels from the cache",
                    }[r["compiled_before_end"]]
                    print(
                        f"[{scen}] {label}: lock-step {r['hz']:.1f} Hz on {r['frames']} frames "
                        f"of 500 correspondences ({r['answered']} answered; {when})",
                        flush=True,
                    )
                if k == 0:
                    for line in m["log"].splitlines():
                        if any(w in line for w in ("warm-up", "compiled", "background")):
                            print(f"    {line}", flush=True)
                starts.append(
                    {
                        k2: m[k2]
                        for k2 in ("ready_s", "first_pose_s", "three_poses_s", "answered", "rate")
                    }
                )
                if m["ready_s"] is None:
                    print(m["log"], file=sys.stderr)
                    return 1
            out["starts"] = starts
            out["user_cache_files"] = sum(1 for _ in cache.rglob("*.nb*"))
            results["scenarios"][scen] = out
    finally:
        _set_writable(pkg, True)
    print(json.dumps(results, indent=1))
    for line in targets(results):
        print(line)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


def targets(results: dict) -> list[str]:
    """The start-up targets against ``results`` of :func:`_startup` (one line each: measured,
    target, met)."""
    sc = results.get("scenarios", {})
    rows = []

    def row(name, value, limit, unit="s", at_least=False):
        if value is None:
            rows.append(
                f"  {name}: not measured (target {'>=' if at_least else '<='} {limit} {unit})"
            )
            return
        met = value >= limit if at_least else value <= limit
        rows.append(
            f"  {name}: {value:.2f} {unit} (target {'>=' if at_least else '<='} {limit} {unit}: "
            f"{'met' if met else 'NOT met'})"
        )

    nc = sc.get("no-compile", {}).get("starts", [])
    if nc:
        row(
            "no compile step, first start: poses of the first three frames",
            nc[0]["three_poses_s"],
            10.0,
        )
        rows.append(
            f"  no compile step, first start: frames answered {nc[0]['answered']}/3 (target 3/3)"
        )
        r = nc[0].get("rate")
        if r:
            row(
                "no compile step, lock-step rate with 500 correspondences while compiling",
                r["hz"],
                10.0,
                "Hz",
                True,
            )
    c = sc.get("compile", {})
    if c:
        row("rs-localizer compile (wall)", c.get("compile_s"), 60.0)
        st = c.get("starts", [])
        if st:
            row("after compile, first start: first pose", st[0]["first_pose_s"], 5.0)
        for k, s in enumerate(st[1:], 1):
            row(f"after compile, later start {k}: first pose", s["first_pose_s"], 3.0)
    return ["targets:"] + rows


def _proc_memory(pid: int) -> dict:
    """``VmRSS`` and ``VmHWM`` of a process in MB (Linux ``/proc``)."""
    out = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key = line.split(":")[0]
        if key in ("VmRSS", "VmHWM"):
            out[key] = int(line.split()[1]) / 1024.0
    return out


def measure_rss(
    n_cameras: int | None, frames: int = 10, images: bool = False, timeout: float = 600.0, log=print
) -> dict:
    """One node process with ``n_cameras`` camera namespaces (None: a plain single node); RSS
    after the warm-up and after ``frames`` frames per camera. Returns ``{"ready": {VmRSS,
    VmHWM}, "after": {...}, "solved": frames answered}``."""
    from rs_localizer.ros.bags.play import play
    from rs_localizer.ros.process import (
        NodeProcess,
        random_domain_id,
        repo_file,
        ros_env,
        write_params_yaml,
    )

    domain = random_domain_id()
    env = ros_env(domain)
    cams = [f"cam{k}" for k in range(n_cameras or 1)]
    spaces = [f"/rss/{c}" for c in cams] if n_cameras else ["/rss"]
    bag = repo_file("data", "sample_images" if images else "sample")
    config = [repo_file("config", "rs_localizer.yaml")]
    params = {"warmup": True}
    if images:
        config.append(repo_file("config", "rs_localizer_images.yaml"))
        params["republish_correspondences"] = False
    if n_cameras:
        params["cameras"] = cams
    work = Path(tempfile.mkdtemp(prefix="rsl_rss_"))
    overlay = write_params_yaml(work / "p.yaml", params)
    node = NodeProcess(
        [*config, overlay],
        namespace="/rss",
        env=env,
        log=work / "node.log",
        remaps={"image": "image_raw"} if images else None,
    )
    try:
        if not node.wait_ready(timeout, count=len(spaces)):
            raise RuntimeError(f"node not ready:\n{node.log}")
        time.sleep(1.0)
        ready = _proc_memory(node.proc.pid)
        frame_topic = "/camera/image_raw" if images else "/camera/correspondences"
        solved = 0
        for ns in spaces:
            res = play(
                bag,
                lockstep=True,
                limit=frames,
                domain_id=domain,
                timeout=30.0,
                topics=[frame_topic, "/camera/camera_info"],
                remap={
                    frame_topic: f"{ns}/{'image_raw' if images else 'correspondences'}",
                    "/camera/camera_info": f"{ns}/camera_info",
                },
                output_topics=(f"{ns}/pose",),
                wait_subscribers=30.0,
                log=lambda *a, **k: None,
            )
            solved += res.answered
        time.sleep(1.0)
        after = _proc_memory(node.proc.pid)
    finally:
        node.stop()
    return {"ready": ready, "after": after, "solved": solved, "frames": frames * len(spaces)}


def _rss(args) -> int:
    rows = {}
    what = "images (ArUco front end)" if args.images else "correspondences"
    print(
        f"resident memory of one rs_localizer_node process, {args.frames} frames of "
        f"{what} per camera:",
        flush=True,
    )
    for n in [None] + list(args.cameras):
        m = measure_rss(n, frames=args.frames, images=args.images)
        label = "single node (no cameras)" if n is None else f"cameras: {n}"
        rows[str(n)] = m
        print(
            f"  {label:26s} RSS after warm-up {m['ready']['VmRSS']:6.1f} MB, after frames "
            f"{m['after']['VmRSS']:6.1f} MB (peak {m['after']['VmHWM']:6.1f} MB), "
            f"{m['solved']}/{m['frames']} frames solved",
            flush=True,
        )
    ks = [n for n in args.cameras if n > 1]
    if 1 in args.cameras and ks:
        for k in ks:
            for when in ("ready", "after"):
                extra = (rows[str(k)][when]["VmRSS"] - rows["1"][when]["VmRSS"]) / (k - 1)
                stage = "after warm-up" if when == "ready" else "after frames"
                print(f"  per extra camera ({k} vs 1, {stage}): {extra:.1f} MB", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.bench_robot",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = p.add_subparsers(dest="command", required=True)
    s = sub.add_parser("startup", help="node start-up time from a read-only install")
    s.add_argument("--venv", default="/tmp/rsl_venv")
    s.add_argument(
        "--create",
        action="store_true",
        help="(re)create the venv and pip install the source tree into it",
    )
    s.add_argument("--python", default=sys.executable, help="interpreter for --create")
    s.add_argument(
        "--fresh-copy",
        action="store_true",
        help="instead of a venv: a fresh copy of the committed source tree run with this "
        "interpreter (fresh_copy_env)",
    )
    s.add_argument("--later", type=int, default=3, help="later starts per scenario")
    s.add_argument(
        "--rate-frames",
        type=int,
        default=40,
        help="synthetic frames of 500 correspondences sent lock-step after the first start's "
        "three (0: none): the rate while the kernels compile (no-compile) or compiled",
    )
    s.add_argument(
        "--scenarios",
        nargs="+",
        default=["no-compile", "compile"],
        choices=["no-compile", "compile"],
    )
    s.add_argument("--json", default=None)
    s.set_defaults(func=_startup)
    r = sub.add_parser("rss", help="resident memory for 1 and N cameras in one process")
    r.add_argument("--cameras", type=int, nargs="+", default=[1, 4])
    r.add_argument("--frames", type=int, default=10, help="frames per camera")
    r.add_argument("--images", action="store_true", help="image mode (ArUco front end)")
    r.add_argument("--json", default=None)
    r.set_defaults(func=_rss)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
