"""On-a-robot benchmarks: node start-up time from a non-editable, read-only install,
and memory per camera with several cameras in one process.

    python -m rs_localizer.evaluation.bench_robot startup [--venv /tmp/rsl_venv] [--create]
        [--later 3] [--scenarios no-compile compile]
    python -m rs_localizer.evaluation.bench_robot rss [--cameras 1 4] [--frames 10] [--images]

``startup`` installs the package non-editable into ``--venv`` (``--create``: a new venv and
``pip install '.[ros]'`` from the source tree), makes the installed package directory
read-only (``chmod -R a-w``; when running as root, who ignores file modes, the directory is
also bind-mounted read-only in a private mount namespace with ``unshare -m``) and starts
``<venv>/bin/rs_localizer_node`` with the installed ``share/rs_localizer/config`` from a
directory outside the source tree, with an empty per-user cache (``XDG_CACHE_HOME``) for the
first start and the same cache for the later starts. For each start it reports:

* ``ready``: seconds from process start to the node's ``ready:`` log line (warm-up done,
  subscriptions up: a frame arriving now is solved without compiling);
* ``first pose``: seconds from process start until the pose of one frame of ``data/sample``
  published after ``ready`` arrived (adds DDS discovery of the publisher and one solve).

Scenarios: ``no-compile`` (the package's compiled kernels deleted: the node compiles at its
first start into ``~/.cache/rs_localizer/numba``) and ``compile`` (``rs-localizer compile`` run
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

ROOT = Path(__file__).resolve().parents[2]


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
) -> dict:
    """Start the installed node once; seconds to ``ready`` and to the first pose (see the
    module docstring). Returns ``{"ready_s", "first_pose_s", "log"}``."""
    from ..ros.bags.play import play
    from ..ros.process import random_domain_id, ros_env

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
            if ready is not None:
                res = play(
                    sample_bag,
                    lockstep=True,
                    limit=1,
                    domain_id=domain,
                    timeout=30.0,
                    topics=["/camera/correspondences", "/camera/camera_info"],
                    output_topics=("/camera/pose",),
                    wait_subscribers=30.0,
                    log=lambda *a, **k: None,
                )
                if res.answered:
                    first = time.monotonic() - t0
        finally:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
                try:
                    proc.wait(20)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait(5)
    return {"ready_s": ready, "first_pose_s": first, "log": log_path.read_text(errors="replace")}


def _startup(args) -> int:
    venv = Path(args.venv).absolute()
    if args.create:
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
                    venv, cache, work, mount, sample, log_path=work / f"{scen}_{k}.log"
                )
                label = "first start" if k == 0 else f"later start {k}"
                ready, first = (
                    None if m[key] is None else round(m[key], 2)
                    for key in ("ready_s", "first_pose_s")
                )
                print(f"[{scen}] {label}: ready {ready} s, first pose {first} s", flush=True)
                if k == 0:
                    for line in m["log"].splitlines():
                        if "warm-up" in line or "compiled" in line:
                            print(f"    {line}", flush=True)
                starts.append({k2: m[k2] for k2 in ("ready_s", "first_pose_s")})
                if m["ready_s"] is None:
                    print(m["log"], file=sys.stderr)
                    return 1
            out["starts"] = starts
            out["user_cache_files"] = sum(1 for _ in cache.rglob("*.nb*"))
            results["scenarios"][scen] = out
    finally:
        _set_writable(pkg, True)
    print(json.dumps(results, indent=1))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


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
    from ..ros.bags.play import play
    from ..ros.process import NodeProcess, random_domain_id, repo_file, ros_env, write_params_yaml

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
        prog="python -m rs_localizer.evaluation.bench_robot",
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
    s.add_argument("--later", type=int, default=3, help="later starts per scenario")
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
