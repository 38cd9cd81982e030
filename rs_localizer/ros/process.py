"""Run ``rs_localizer_node`` as a subprocess (demo, tests, benchmark; no ros2 launch needed)."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "NodeProcess",
    "random_domain_id",
    "repo_file",
    "ros_env",
    "share_dirs",
    "user_domain_id",
    "write_params_yaml",
]


def random_domain_id() -> int:
    """A random ROS domain id in [1, 101] (valid on every platform)."""
    return random.SystemRandom().randint(1, 101)


def user_domain_id(environ: Mapping[str, str] | None = None) -> int | None:
    """The ``ROS_DOMAIN_ID`` the user set (``environ``, default ``os.environ``), or None when
    it is unset or empty. Raises ValueError for a value that is no domain id (0-232)."""
    text = (os.environ if environ is None else environ).get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return None
    if not text.isdigit() or not 0 <= int(text) <= 232:
        raise ValueError(f"ROS_DOMAIN_ID={text!r} is no ROS domain id (a whole number 0-232)")
    return int(text)


def ros_env(domain_id: int | None = None, base: Mapping[str, str] | None = None) -> dict:
    """Environment for isolated local ROS processes: ``ROS_DOMAIN_ID`` and localhost-only
    discovery. Also applies them to ``os.environ`` of the caller when ``base`` is None."""
    env = dict(os.environ if base is None else base)
    if domain_id is None:
        domain_id = int(env.get("ROS_DOMAIN_ID", "0") or 0)
    env["ROS_DOMAIN_ID"] = str(domain_id)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.pop("ROS_LOCALHOST_ONLY", None)
    env.setdefault("PYTHONUNBUFFERED", "1")
    env.setdefault("RCUTILS_COLORIZED_OUTPUT", "0")
    return env


def _yaml_value(v) -> str:
    if isinstance(v, (bool, np.bool_)):
        return "true" if v else "false"
    if isinstance(v, (float, np.floating)):
        r = repr(float(v))
        return r if ("." in r or "e" in r or "n" in r) else r + ".0"
    if isinstance(v, np.integer):
        return str(int(v))
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_yaml_value(x) for x in v) + "]"
    if isinstance(v, str):
        return '"' + v.replace('"', '\\"') + '"'
    return str(v)


def write_params_yaml(
    path: str | os.PathLike,
    params: dict | None = None,
    reliable_topics: Iterable[str] = (),
    node: str = "/**",
) -> Path:
    """Write a ROS 2 parameter file: ``params`` (flat dotted names) and, for each topic in
    ``reliable_topics`` (fully qualified), a QoS override making its subscription reliable."""
    lines = [f"{node}:", "  ros__parameters:"]
    for k, v in (params or {}).items():
        lines.append(f"    {k}: {_yaml_value(v)}")
    if reliable_topics:
        lines.append("    qos_overrides:")
        for t in reliable_topics:
            lines += [
                f"      {t}:",
                "        subscription:",
                "          reliability: reliable",
                "          depth: 100",
            ]
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path


def share_dirs() -> list[Path]:
    """Where an installed ``rs_localizer`` keeps its data files (``config/``, ``launch/``,
    ``data/``), most specific first: ``<prefix>/share/rs_localizer`` of the prefix the package
    is installed in (``<prefix>/lib/pythonX.Y/site-packages/rs_localizer``: a pip venv or a
    colcon install space), the ament index (``AMENT_PREFIX_PATH``), then ``sys.prefix``."""
    pkg = Path(os.path.abspath(__file__)).parents[1]  # .../site-packages/rs_localizer
    out = []
    if pkg.parent.name in ("site-packages", "dist-packages"):
        out.append(pkg.parents[3] / "share" / "rs_localizer")
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            out.append(Path(prefix) / "share" / "rs_localizer")
    out.append(Path(sys.prefix) / "share" / "rs_localizer")
    seen, uniq = set(), []
    for d in out:
        if d not in seen:
            seen.add(d)
            uniq.append(d)
    return uniq


def repo_file(*parts: str) -> Path | None:
    """A file of the source tree (``data/sample``, ``config/...``): looked up from the current
    directory, then next to the package (a source checkout), then in the installed
    ``share/rs_localizer`` (:func:`share_dirs`). None if nowhere."""
    rel = Path(*parts)
    here = Path(__file__).resolve().parents[2]
    for base in (Path.cwd(), here, *share_dirs()):
        if (base / rel).exists():
            return base / rel
    return None


class NodeProcess:
    """``rs_localizer_node --ros-args ...`` (``python -m rs_localizer.ros.runner``) in a
    subprocess.

    Args:
        params_files: parameter files in order (later ones win).
        namespace: ``__ns`` remap; node_name: ``__node`` remap; remaps: ``{from: to}``.
        params: ``-p name:=value`` extra parameters.
        env: environment (see :func:`ros_env`). log: file for stdout+stderr (default: temp).
        cpus: pin the process (and all its threads) to these CPU ids (Linux).
        executable: ``rs_localizer_node`` or ``rs_localizer_lifecycle_node`` (the managed node):
            a key of :data:`rs_localizer.ros.runner.NODES`.
    """

    def __init__(
        self,
        params_files: Iterable[str | os.PathLike] = (),
        namespace: str = "/camera",
        node_name: str | None = None,
        remaps: Mapping[str, str] | None = None,
        params: Mapping[str, Any] | None = None,
        env: Mapping[str, str] | None = None,
        log: str | os.PathLike | None = None,
        cpus: Iterable[int] | None = None,
        executable: str = "rs_localizer_node",
    ):
        args = [sys.executable, "-m", "rs_localizer.ros.runner", executable, "--ros-args"]
        for f in params_files:
            args += ["--params-file", str(f)]
        if namespace:
            args += ["-r", f"__ns:={namespace}"]
        if node_name:
            args += ["-r", f"__node:={node_name}"]
        for a, b in (remaps or {}).items():
            args += ["-r", f"{a}:={b}"]
        for k, v in (params or {}).items():
            args += ["-p", f"{k}:={_yaml_value(v)}"]
        self.args = args
        self.env = env or ros_env()
        if log is None:
            fd, log = tempfile.mkstemp(prefix="rs_localizer_node_", suffix=".log")
            os.close(fd)
        self.log_path = Path(log)
        self._log = open(self.log_path, "w")  # noqa: SIM115 (open as long as the process; stop() closes it)
        preexec = None
        if cpus is not None and hasattr(os, "sched_setaffinity"):
            cpu_set = set(cpus)
            preexec = lambda: os.sched_setaffinity(0, cpu_set)  # noqa: E731
        self.proc = subprocess.Popen(
            args,
            env=self.env,
            stdout=self._log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
            preexec_fn=preexec,
        )

    @property
    def log(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text(errors="replace")

    def alive(self) -> bool:
        return self.proc.poll() is None

    def cpu_seconds(self) -> float:
        """CPU time (s, user + system, all threads) the process has used so far, from
        ``/proc/<pid>/stat`` (resolution one clock tick, usually 10 ms); NaN where there is no
        ``/proc`` or the process has ended."""
        try:
            fields = Path(f"/proc/{self.proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            return float("nan")
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def wait_ready(self, timeout: float = 60.0, count: int = 1, marker: str = "ready:") -> bool:
        """Wait for ``count`` ``ready`` log lines (after warm-up; one per camera node) or other
        ``marker`` lines."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            log = self.log
            if log.count(f"] {marker}") + log.count(f"]: {marker}") >= count:
                return True
            if not self.alive():
                return False
            time.sleep(0.05)
        return False

    def stop(self, timeout: float = 10.0) -> int:
        """SIGINT, then SIGKILL after ``timeout``. Returns the exit code."""
        if self.alive():
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        if not self._log.closed:
            self._log.close()
        return self.proc.returncode

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()
