"""A new user's first hour, scripted: the shell commands of README.md and docs/*.md, run as
written (``rs-localizer`` through this interpreter and this checkout), with their exit codes
and, where the docs quote what a command prints, the figures compared (within 3 %); then a
marker user's first day as named checks.

    .venv/bin/python tools/newcomer.py [--list] [--only NAME[,NAME]] [--skip-slow]
        [--timeout S] [--workdir DIR]                  # or: make newcomer [ARGS="--only day"]

Commands that install or build (pip, make, colcon, rosdep, apt-get), need a ROS install
(``ros2``), are templates (``BAG``, ``[...]``, ``|``), write into the repository, or take
minutes (benchmarks: ``python -m benchmarks.X``; experiments, map building, rendering,
compiling) are listed as skipped with the reason. The node quick start (``rs_localizer_node``
in one shell, ``play`` in a second one) runs both, the node in the background on a random
ROS_DOMAIN_ID.

The marker user's day: a rolling-shutter RGB camera (``render-bag --scene apriltag_room``,
640x480, 62.5 us/line, standing in for the user's camera) in a room of AprilTag 36h11 tags,
taken as the docs tell a new user: ``rs-localizer compile``, the video, ``map-markers
--calibrate-readout`` (the readout time with its std and verdict, under ``--quiet``, in the
map, the same with ``--anchor-pose``), the map's gravity-aligned frame, ``replay`` against the
ground truth, docs/video.md's images-to-poses Python block run as written, ``export-image
--all`` stamps, ``calibrate-readout``'s errors without a map, ``play --lockstep`` into another
namespace, ``rs-localizer diagnostics``, the node with viewers subscribed on a 30 Hz video,
and ``make demo``'s ROS_DOMAIN_ID and figures against the README. Each check prints PASS or
FAIL with what it measured (REPORT: measured, not judged, e.g. a latency on a loaded shared
machine), then a summary. ``--only`` runs single pages or checks (``pages``, ``day``: all of
them; a check runs the steps it needs, e.g. the video and the map), ``--skip-slow`` leaves out
the day's slow checks (the whole day takes 20-30 min on a 2-core machine). Not part of ``make
test``. Exit status 1 when a command fails, a figure is off or a check fails.

The rig user's day (``--only rig``): a wheeled robot with three rolling-shutter cameras
(front, left, right; ``render-bag --rig 3 --frames 60``, 640x480 each) in a lab of AprilTag
36h11 tags, as docs/rig_node.md and docs/tools.md tell it: ``rig_render`` (the bag),
``rig_calibrate`` (``calibrate-rig``: the mountings against the renderer's, the printed std
covering the error, the rig frame named), ``rig_lockstep`` (the rig node and ``play
--lockstep``: every rig frame answered, ``evaluate --live`` against the truth),
``rig_realtime`` (``play`` at the bag's rate: every camera frame accounted in /diagnostics),
``rig_replay_evaluate`` (``replay --out`` and ``evaluate`` of its output), the faults
``rig_unplugged`` (a camera's topics end half way: ``stopped``, WARN), ``rig_absent`` (a camera
never sends: ERROR naming it after ``rig.stop_after``), ``rig_no_camera_info`` (``waiting``,
``skipped.no_camera_info``, a log line naming its topic), ``rig_mounting_off`` (a mounting 5
deg off: the node and ``replay`` name the camera), ``rig_lifecycle`` (the managed rig node
driven through configure, activate, deactivate, cleanup: ``rs-localizer lifecycle`` if the CLI
has it, else rclpy's lifecycle services, the check says which) and ``rig_view`` (``rs-localizer
view`` and a Foxglove WebSocket client receiving the poses). About 15 min on a loaded 2-core
machine.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PAGES = ["README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md"))]

#: first word(s) of a command -> why it is not run
SKIP_PREFIXES = {
    "make": "a make target (make demo / make test run on their own)",
    "python3.11": "creates a venv (the checker runs in one already)",
    "pip": "installs packages",
    ".venv/bin/pip": "installs packages",
    "rosdep": "needs a ROS install",
    "colcon": "needs a ROS install",
    "ros2": "needs a ROS install",
    "sudo": "installs system packages",
    "cd": "a ROS workspace",
    "/usr/bin/python3": "creates a venv",
    "install/rs_localizer/lib/rs_localizer/rs-localizer": "needs a colcon build",
    "install/rs_localizer/lib/rs_localizer/rs_localizer_node": "needs a colcon build",
    "OPENBLAS_NUM_THREADS=1": "a benchmark (minutes)",
    "python": "a benchmark (minutes)",
}
#: rs-localizer subcommands that take minutes
SLOW_COMMANDS = {
    "compile": "compiles every kernel (1-3 min on a cold cache)",
    "experiments": "the paper's experiments (minutes)",
    "map-markers": "a bundle adjustment (minutes)",
    "map-features": "a COLMAP reconstruction (minutes)",
    "render-bag": "renders a video (minutes on a shared machine)",
}
#: rs-localizer subcommands that watch a running node (test/ros/test_view.py runs them)
LIVE_COMMANDS = {
    "view": "serves a running node to the Foxglove app until Ctrl-C",
    "diagnostics": "prints a running node's /diagnostics until Ctrl-C",
    "lifecycle": "drives a running managed node (the rig day's rig_lifecycle check and "
    "test/ros/test_lifecycle_cli.py run it)",
}
TEMPLATE = re.compile(r"\bBAG\b|\bOUT\b|\bMOTION\b|\[-|\.\.\.|\s\|\s")  # ([--option], a | b)


@dataclass
class Figure:
    """A number the docs quote from a command's output: ``pattern`` (one group) on the
    output of the first command containing ``command``, against ``value`` within ``rel``."""

    page: str
    command: str
    pattern: str
    value: float
    rel: float = 0.03
    json_key: str = ""  # "a.b": the figure is this entry of the command's JSON output


_GYRO = (
    '-p imu.enabled:=true -p "imu.rotation:=[0.5,-0.5,0.5,0.5]" '
    '-p "imu.gyro_bias:=[0.01,-0.02,0.005]"'
)
#: commands a page quotes in its text (not in a fenced block) next to figures: run after the
#: page's fenced commands
INLINE_COMMANDS = {
    "docs/video.md": [
        "rs-localizer replay /tmp/imubag --json -p tracking.enabled:=false",
        f"rs-localizer replay /tmp/imubag --json -p tracking.enabled:=false {_GYRO}",
        "rs-localizer replay /tmp/imubag --json",
        f"rs-localizer replay /tmp/imubag --json {_GYRO}",
    ],
}
#: the table "On a video through the node's pipeline" of docs/video.md: rotation (deg), angular
#: velocity (rad/s), linear velocity (m/s), medians over 60 frames, per INLINE_COMMANDS row
_GYRO_TABLE = [
    (0.0129, 0.0336, 0.216),
    (0.0111, 0.0029, 0.135),
    (0.0130, 0.0101, 0.022),
    (0.0110, 0.0029, 0.016),
]
#: figures of the docs checked against what their commands print
FIGURES = [
    Figure(
        "docs/tools.md",
        "calibrate-readout /tmp/late",
        r"gyro time offset ([\d.]+) \+- [\d.]+ ms",
        10.299,
    ),
    Figure("docs/tools.md", "calibrate-readout /tmp/late", r"line delay ([\d.]+) \+-", 29.93),
    Figure(
        "docs/video.md",
        "calibrate-readout /tmp/imubag",
        r"std about camera x/y/z [\d.]+/([\d.]+)/",
        0.724,
    ),
    Figure(
        "docs/video.md",
        "calibrate-readout /tmp/imubag",
        r"gyro bias \[[-\d.]+, ([-\d.]+),",
        -0.0173,
    ),
    *[
        Figure("docs/video.md", cmd, "", value, 0.05, key)
        for cmd, row in zip(INLINE_COMMANDS["docs/video.md"], _GYRO_TABLE, strict=True)
        for key, value in zip(
            ("rot_deg.median", "angvel.median", "linvel.median"), row, strict=True
        )
    ],
]


@dataclass
class Step:
    page: str
    command: str
    skip: str = ""
    rc: int | None = None
    seconds: float = 0.0
    output: str = ""
    problems: list[str] = field(default_factory=list)


def shell_commands(page: str) -> list[str]:
    """The commands of a page's fenced bash blocks: continuation lines joined, comments
    (``#`` after whitespace or at the start) dropped."""
    text = (ROOT / page).read_text()
    out = []
    for block in re.findall(r"```(?:bash|sh|shell)\n(.*?)```", text, re.S):
        joined = re.sub(r"\\\n\s*", " ", block)
        for line in joined.splitlines():
            line = re.sub(r"(^|\s)#.*$", "", line).strip()
            if line:
                out.append(line)
    return out


def why_skipped(cmd: str) -> str:
    words = cmd.split()
    if words[0] in SKIP_PREFIXES:
        return SKIP_PREFIXES[words[0]]
    if TEMPLATE.search(cmd):
        return "a template (placeholders)"
    if "rs_localizer_lifecycle_node" in words[0]:
        return "a managed node, driven by rs-localizer lifecycle (the rig_lifecycle check runs it)"
    if "rs_localizer_node" in words[0]:
        return ""  # (run with the play command that follows it)
    if not words[0].endswith("rs-localizer"):
        return f"not an rs-localizer command ({words[0]})"
    sub = words[1] if len(words) > 1 else ""
    if sub in SLOW_COMMANDS:
        return SLOW_COMMANDS[sub]
    if sub in LIVE_COMMANDS:
        return LIVE_COMMANDS[sub]
    if sub == "evaluate" and "--live" in words:
        return "records a running node (the rig day's rig_lockstep check runs it)"
    if any(a.startswith(("docs/", "data/", "test/", "config/")) for a in words[2:]) and sub in (
        "export-image",
        "make-bag",
        "render-bag",
    ):
        return "writes into the repository"
    return ""


def _env(domain: int) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    env["ROS_DOMAIN_ID"] = str(domain)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    return env


def _argv(cmd: str) -> list[str]:
    words = shlex.split(cmd)
    if words[0].endswith("rs-localizer"):
        return [sys.executable, "-m", "rs_localizer", *words[1:]]
    if words[0].endswith(("rs_localizer_node", "rs_localizer_lifecycle_node")):
        executable = words[0].rsplit("/", 1)[-1]
        return [sys.executable, "-m", "rs_localizer.ros.runner", executable, *words[1:]]
    return words


def _tmp_paths(cmd: str) -> set[str]:
    return {w for w in shlex.split(cmd) if w.startswith("/tmp/")}


def _fresh(cmd: str) -> None:
    """A new user has no output of an earlier run: remove the bag a make-bag, render-bag or
    replay --out of ``cmd`` would write (only a directory that holds a bag)."""
    words = shlex.split(cmd)
    sub = words[1] if len(words) > 1 else ""
    targets = words[2:3] if sub in ("make-bag", "render-bag") else []
    targets += [words[i + 1] for i, w in enumerate(words[:-1]) if w == "--out"]
    for t in targets:
        p = Path(t)
        if t.startswith("/tmp/") and p.is_dir() and (p / "metadata.yaml").exists():
            shutil.rmtree(p)


def _figure(fig: Figure, output: str) -> float | None:
    """The figure in a command's output (its regex group, or its JSON entry)."""
    if fig.json_key:
        start = output.find("{")
        try:
            value = json.JSONDecoder().raw_decode(output[start:])[0] if start >= 0 else None
            for k in fig.json_key.split("."):
                value = value[k]
            return float(value)
        except (ValueError, KeyError, TypeError):
            return None
    m = re.search(fig.pattern, output)
    return float(m.group(1)) if m else None


def run_page(page: str, timeout: float, domain: int) -> list[Step]:
    cmds = shell_commands(page) + INLINE_COMMANDS.get(page, [])
    steps = [Step(page, c, why_skipped(c)) for c in cmds]
    node = None
    missing: set[str] = set()  # /tmp paths that a skipped command would have written
    for k, st in enumerate(steps):
        if not st.skip and _tmp_paths(st.command) & missing:
            st.skip = "its input comes from a skipped command"
        if st.skip:
            missing |= _tmp_paths(st.command)
            continue
        if node is None and " play " in f" {st.command} " and "--lockstep" in st.command:
            st.skip = "lock-step with no node running (a node the page starts otherwise)"
            continue
        _fresh(st.command)
        if "rs_localizer_node" in st.command.split()[0]:
            nxt = steps[k + 1] if k + 1 < len(steps) else None
            if nxt is None or " play " not in f" {nxt.command} ":
                st.skip = "the node alone (no play command follows)"
                continue
            node = subprocess.Popen(
                _argv(st.command),
                cwd=ROOT,
                env=_env(domain),
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
            )
            # as a user would: start the player once the node says it is ready
            t0, st.rc = time.perf_counter(), 0
            lines: list[str] = []
            threading.Thread(target=lines.extend, args=(node.stdout,), daemon=True).start()
            while not any("ready:" in ln for ln in lines) and node.poll() is None:
                if time.perf_counter() - t0 > timeout:
                    st.problems.append(f"not ready within {timeout:g} s")
                    break
                time.sleep(0.2)
            st.seconds, st.output = time.perf_counter() - t0, "".join(lines)
            if node.poll() is not None:
                st.rc = node.returncode
                st.problems.append(f"the node ended: {st.output.strip()[-300:]}")
            continue
        t0 = time.perf_counter()
        try:
            res = subprocess.run(
                _argv(st.command),
                cwd=ROOT,
                env=_env(domain),
                capture_output=True,
                text=True,
                timeout=timeout,
            )
            st.rc, st.output = res.returncode, res.stdout + res.stderr
        except subprocess.TimeoutExpired:
            st.rc, st.problems = -1, [f"no answer within {timeout:g} s"]
        st.seconds = time.perf_counter() - t0
        if st.rc not in (0, None) and not st.problems:
            st.problems.append(f"exit code {st.rc}: {st.output.strip()[-300:]}")
        if node is not None and " play " in f" {st.command} ":
            node.terminate()
            try:
                node.wait(10)
            except subprocess.TimeoutExpired:
                node.kill()
            node = None
            if "no answer" in st.output or re.search(r"\b0 answered\b", st.output):
                st.problems.append("the node answered no frame")
    for fig in FIGURES:
        if fig.page != page:
            continue
        done = [s for s in steps if s.rc == 0]
        st = next((s for s in done if s.command == fig.command), None) or next(
            (s for s in done if fig.command in s.command), None
        )
        if st is None:
            continue
        got = _figure(fig, st.output)
        if got is None:
            st.problems.append(f"no {fig.pattern or fig.json_key!r} in the output")
        elif abs(got - fig.value) > fig.rel * abs(fig.value):
            st.problems.append(
                f"{fig.json_key or 'prints'} {got:.4g} where {page} says {fig.value} (more "
                f"than {fig.rel:.0%} apart)"
            )
    return steps


# ---------------------------------------------------------------------------------------------
# A marker user's first day: a rolling-shutter RGB camera (the renderer standing in: 640x480,
# 62.5 us/line) filming a room of AprilTag 36h11 tags, from the video to a map, the readout
# time, poses in Python and the node with viewers. Each check prints PASS or FAIL with what it
# measured (REPORT: measured, not judged).

#: the day's video: ``render-bag`` of the built-in AprilTag room, a hand-held walk
DAY_FRAMES = 60
DAY_RENDER = (
    "rs-localizer render-bag {bag} --scene apriltag_room --frames 60 --motion walk "
    "--imu-rate 200 --quiet"
)
#: node parameters of the image-mode quick start (a marker map on images)
IMAGE_PARAMS = "config/rs_localizer_images.yaml"


class CheckFailed(Exception):
    """A step a check needs did not work (its message says which and why)."""


@dataclass
class Run:
    command: str
    rc: int
    output: str
    seconds: float


@dataclass
class Check:
    name: str
    verdict: str = "PASS"  # PASS, FAIL, REPORT (measured only), SKIP
    value: str = ""
    notes: list[str] = field(default_factory=list)
    seconds: float = 0.0

    def fail(self, why: str) -> None:
        self.verdict = "FAIL"
        self.notes.append(why)

    def expect(self, ok: bool, why: str) -> bool:
        """Fail with ``why`` unless ``ok``; returns ``ok``."""
        if not ok:
            self.fail(why)
        return bool(ok)


def _tail(text: str, n: int = 400) -> str:
    text = text.strip()
    return text if len(text) <= n else "..." + text[-n:]


def _quat_from_matrix(R: np.ndarray) -> list[float]:
    """(x, y, z, w) of a rotation matrix (3, 3)."""
    w = np.sqrt(max(0.0, 1.0 + np.trace(R))) / 2.0
    if w > 1e-6:
        return [(R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w),
                (R[1, 0] - R[0, 1]) / (4 * w), w]  # fmt: skip
    i = int(np.argmax(np.diag(R)))
    j, k = (i + 1) % 3, (i + 2) % 3
    q = np.zeros(4)
    q[i] = np.sqrt(max(0.0, 1.0 + R[i, i] - R[j, j] - R[k, k])) / 2.0
    q[j] = (R[j, i] + R[i, j]) / (4 * q[i])
    q[k] = (R[k, i] + R[i, k]) / (4 * q[i])
    q[3] = (R[k, j] - R[j, k]) / (4 * q[i])
    return q.tolist()


def _rigid_fit(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares ``R, t`` with ``dst ~ R src + t`` (points (N, 3))."""
    cs, cd = src.mean(0), dst.mean(0)
    U, _, Vt = np.linalg.svd((dst - cd).T @ (src - cs))
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    return R, cd - R @ cs


def _corners(path: Path) -> dict[int, np.ndarray]:
    import yaml

    data = yaml.safe_load(path.read_text())
    return {int(m["id"]): np.asarray(m["corners"], float) for m in data["markers"]}


class Day:
    """The day's shared steps, each run once when a check first needs it (the video, the
    maps, the demo, a node): ``--only`` a single check still runs what it needs."""

    def __init__(self, work: Path, domain: int, timeout: float):
        self.work, self.domain, self.timeout = work, domain, timeout
        self._done: dict[str, object] = {}
        self.ran: list[str] = []  # the commands run for the current check, as typed

    def run(
        self, cmd: str, timeout: float | None = None, env: dict | None = None, cwd: Path = ROOT
    ) -> Run:
        """Run ``cmd`` (an ``rs-localizer`` command line as a user types it) in the checkout;
        a command that does not answer within the timeout has rc -1."""
        self.ran.append(cmd)
        t0 = time.perf_counter()
        try:
            argv = [sys.executable, *cmd.split()[1:]] if cmd.startswith("python ") else _argv(cmd)
            res = subprocess.run(
                argv,
                cwd=cwd,
                env=env or _env(self.domain),
                capture_output=True,
                text=True,
                timeout=timeout or self.timeout,
            )
            rc, out = res.returncode, res.stdout + res.stderr
        except subprocess.TimeoutExpired as e:
            rc, out = -1, f"no answer within {timeout or self.timeout:g} s " + str(e.output or "")
        return Run(cmd, rc, out, time.perf_counter() - t0)

    def once(self, key: str, make):
        if key not in self._done:
            try:
                self._done[key] = make()
            except CheckFailed as e:
                self._done[key] = e
        got = self._done[key]
        if isinstance(got, CheckFailed):
            raise got
        return got

    def must(self, cmd: str, timeout: float | None = None) -> Run:
        r = self.run(cmd, timeout)
        if r.rc != 0:
            raise CheckFailed(f"`{cmd}` exit code {r.rc}: {_tail(r.output)}")
        return r

    # -- the video, as the user's camera would record it
    def bag(self) -> Path:
        def make():
            bag = self.work / "apriltag_room"
            if bag.exists():
                shutil.rmtree(bag)
            r = self.must(DAY_RENDER.format(bag=bag), max(self.timeout, 600))
            self._done["render_seconds"] = r.seconds
            return bag

        return self.once("bag", make)

    def truth(self) -> dict:
        """What the user knows of their camera and tags: the tags' sizes (printed), and for
        checking only: the true line delay and the tags' true corners (the renderer's)."""

        def make():
            bag = self.bag()
            info = json.loads((bag / "sequence.json").read_text())
            corners = _corners(bag / info["frontend"]["map"])
            sizes = {m: float(np.linalg.norm(c[0] - c[1])) for m, c in corners.items()}
            common = max(set(np.round(list(sizes.values()), 3)), key=list(
                np.round(list(sizes.values()), 3)).count)  # fmt: skip
            others = ",".join(f"{m}:{s:.3f}" for m, s in sizes.items() if abs(s - common) > 1e-4)
            return {
                "line_delay": float(info["rs"]["line_delay"]),
                "corners": corners,
                "size_args": f"--marker-size {common:.3f} --marker-sizes {others}",
                "info": info,
            }

        return self.once("truth", make)

    def map_default(self) -> tuple[Path, Run]:
        """map-markers as the docs' first map: default frame, readout calibrated, report."""

        def make():
            out = self.work / "markers.yaml"
            cmd = (
                f"rs-localizer map-markers {self.bag()} -o {out} {self.truth()['size_args']} "
                f"--calibrate-readout --report {self.work / 'report'} --overwrite"
            )
            return out, self.must(cmd, max(self.timeout, 1200))

        return self.once("map_default", make)

    def map_anchored(self) -> tuple[Path, Run]:
        """The same video, the map put into the room's frame by the anchor's surveyed pose
        (a pure change of the output frame), under ``--quiet``."""

        def make():
            import yaml

            first, _ = self.map_default()
            anchor = int(yaml.safe_load(first.read_text()).get("anchor", -1))
            c = self.truth()["corners"].get(anchor)
            if c is None:
                raise CheckFailed(f"the first map's anchor {anchor} is not a tag of the room")
            x = (c[1] - c[0]) / np.linalg.norm(c[1] - c[0])  # TL -> TR: right on the face
            y = (c[0] - c[3]) / np.linalg.norm(c[0] - c[3])  # BL -> TL: up on the face
            R = np.column_stack([x, y, np.cross(x, y)])
            pose = " ".join(f"{v:.6f}" for v in [*c.mean(0), *_quat_from_matrix(R)])
            out = self.work / "markers_room.yaml"
            cmd = (
                f"rs-localizer map-markers {self.bag()} -o {out} {self.truth()['size_args']} "
                f"--calibrate-readout --anchor {anchor} --anchor-pose {pose} --quiet --overwrite "
                f"--report {self.work / 'report_room'}"
            )
            return out, self.must(cmd, max(self.timeout, 1200))

        return self.once("map_anchored", make)

    def demo(self, user_domain: int) -> Run:
        def make():
            env = _env(self.domain)
            env["ROS_DOMAIN_ID"] = str(user_domain)
            return self.run("rs-localizer demo", max(self.timeout, 900), env=env)

        return self.once("demo", make)

    def node(self, ros_args: str, timeout: float = 120.0, marker: str = "ready:"):
        """Start ``rs_localizer_node --ros-args ROS_ARGS`` in the background; returns
        ``(process, output lines, seconds to the line with ``marker``)``."""
        cmd = f"rs_localizer_node --ros-args {ros_args}"
        self.ran.append(cmd + " &")
        proc = subprocess.Popen(
            _argv(cmd),
            cwd=ROOT,
            env=_env(self.domain),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        lines: list[str] = []
        threading.Thread(target=lines.extend, args=(proc.stdout,), daemon=True).start()
        t0 = time.perf_counter()
        while not any(marker in ln for ln in lines):
            if proc.poll() is not None or time.perf_counter() - t0 > timeout:
                _stop(proc)
                raise CheckFailed(f"the node did not start: {_tail(''.join(lines))}")
            time.sleep(0.1)
        return proc, lines, time.perf_counter() - t0


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _diag_values(text: str) -> dict[str, float]:
    """The numeric key=value pairs ``rs-localizer diagnostics`` printed (the last of each)."""
    out = {}
    for k, v in re.findall(r"([\w.<>-]+)=([-+\d.eE]+|nan|inf)\b", text):
        out[k] = float(v)  # (the pattern takes numbers only)
    return out


# ---- the checks, in the order of the day


def check_compile(day: Day, c: Check) -> None:
    """`rs-localizer compile` (the README's install step) on an empty kernel cache, as right
    after the install: in a copy of the package without its `__pycache__` (the checkout's is
    warm from the pages' commands, and a cache folder of its own would be seeded from it): its
    time against the 60 s target (report-only on a loaded machine); then as written, for the
    checkout's cache the later checks use."""
    before = os.getloadavg()[0]  # (others' load: the compile's own comes after)
    cold = day.work / "cold_install"
    shutil.rmtree(cold, ignore_errors=True)
    shutil.copytree(
        ROOT / "rs_localizer", cold / "rs_localizer", ignore=shutil.ignore_patterns("__pycache__")
    )
    env = _env(day.domain)
    env["PYTHONPATH"] = str(cold)
    env.pop("NUMBA_CACHE_DIR", None)
    r = day.run("rs-localizer compile", max(day.timeout, 900), env=env, cwd=cold)
    day.ran[-1] = f"(cd {cold}: the package copied without __pycache__) {day.ran[-1]}"
    cores = os.cpu_count() or 1
    c.value = (
        f"{r.seconds:.0f} s on an empty cache (target <= 60 s; load {before:.1f} on {cores} "
        "cores before)"
    )
    if not c.expect(r.rc == 0, f"exit code {r.rc}: {_tail(r.output)}"):
        return
    c.notes += [
        m.strip() for m in re.findall(r"^(?:numba cache:|.*: ready in ).*$", r.output, re.M)
    ]
    if r.seconds > 60 and before > 0.5 * cores:
        c.verdict = "REPORT"
        c.notes.append("over 60 s on a loaded machine: not judged (run again on a quiet one)")
    else:
        c.expect(r.seconds <= 60, f"compile took {r.seconds:.0f} s > 60 s on a quiet machine")
    again = day.run("rs-localizer compile", max(day.timeout, 900))
    c.notes.append(f"into the checkout's cache: {again.seconds:.0f} s")
    c.expect(again.rc == 0, f"exit code {again.rc}: {_tail(again.output)}")


def check_scenes_listed(day: Day, c: Check) -> None:
    """`render-bag -h` lists every built-in scene; tools.md lists them too; the scene YAML
    format has its documented section."""
    scenes = sorted(p.stem for p in (ROOT / "rs_localizer" / "scenes").glob("*.yaml"))
    r = day.run("rs-localizer render-bag -h")
    helptext = re.sub(r"\s+", " ", r.output)
    missing = [s for s in scenes if s not in helptext]
    tools = (ROOT / "docs" / "tools.md").read_text()
    undocumented = [s for s in scenes if f"`{s}`" not in tools]
    c.value = f"{len(scenes) - len(missing)}/{len(scenes)} built-in scenes in render-bag -h"
    c.expect(r.rc == 0, f"render-bag -h: exit code {r.rc}")
    c.expect(not missing, f"render-bag -h does not list {missing}")
    c.expect(not undocumented, f"docs/tools.md (render-bag) does not list {undocumented}")
    c.expect("apriltag_room" in scenes, "no built-in AprilTag room")
    images = (ROOT / "docs" / "images.md").read_text()
    c.expect(
        re.search(r"^#+ Scene files", images, re.M | re.I) and "apriltag" in images.lower(),
        "docs/images.md has no 'Scene files' section with an AprilTag room",
    )


def check_render(day: Day, c: Check) -> None:
    """The day's video: the AprilTag room rendered as the user's camera would record it."""
    bag = day.bag()
    info = day.truth()["info"]
    cam = info["camera"]
    c.value = (
        f"{info['frames']} frames {cam['width']}x{cam['height']}, "
        f"{1e6 * info['rs']['line_delay']:.1f} us/line, {len(day.truth()['corners'])} tags, "
        f"{day._done.get('render_seconds', 0):.0f} s"
    )
    c.expect(info["frames"] == DAY_FRAMES, f"{info['frames']} frames written of {DAY_FRAMES}")
    c.expect((bag / "metadata.yaml").exists(), "no bag written")


_READOUT_LINE = re.compile(
    r"line delay ([\d.]+) \+- ([\d.]+) us/line.*?:\s*(NOT observable|not observable|observable)"
)


def check_readout_calibrated(day: Day, c: Check) -> None:
    """`map-markers --calibrate-readout` prints the line delay with its std and an observable
    verdict; an observable value lies within 3 std (or 2 %) of the truth."""
    _, r = day.map_default()
    true = day.truth()["line_delay"] * 1e6
    m = _READOUT_LINE.search(r.output)
    if not m:
        plain = re.search(r"line delay ([\d.]+) us", r.output)
        c.value = (
            f"{plain.group(1)} us/line (true {true:.2f})" if plain else "no line delay printed"
        )
        c.fail("no 'line delay X +- STD us/line ...: observable|NOT observable' line")
        return
    val, std, verdict = float(m.group(1)), float(m.group(2)), m.group(3)
    err = (val - true) / true
    c.value = f"{val:.2f} +- {std:.2f} us/line ({verdict}), true {true:.2f} ({100 * err:+.1f} %)"
    if verdict == "observable":
        c.expect(
            abs(val - true) <= max(3 * std, 0.02 * true),
            f"off the truth by {abs(val - true) / std:.1f} std and {100 * abs(err):.1f} %",
        )


def check_readout_quiet(day: Day, c: Check) -> None:
    """`--quiet` still prints the readout line (it is the command's result)."""
    _, r = day.map_anchored()
    m = _READOUT_LINE.search(r.output)
    c.value = m.group(0) if m else "nothing printed under --quiet"
    c.expect(m is not None, "map-markers --calibrate-readout --quiet prints no readout line")


def check_readout_in_map(day: Day, c: Check) -> None:
    """The calibrated readout is written into the map (its `readout` entry)."""
    import yaml

    path, _ = day.map_default()
    ro = yaml.safe_load(path.read_text()).get("readout") or {}
    c.value = json.dumps(ro) if ro else "no readout entry in the map"
    need = {"line_delay_s", "readout_time_s", "calibrated", "line_delay_std_s", "observable"}
    c.expect(not need - set(ro), f"the map's readout entry lacks {sorted(need - set(ro))}")
    c.expect(ro.get("calibrated") is True, "readout.calibrated is not true")


def check_readout_frame_invariant(day: Day, c: Check) -> None:
    """The same video with and without `--anchor-pose` (a pure change of the output frame)
    gives the same line delay (relative difference <= 1e-4)."""
    import yaml

    _, a = day.map_default()
    _, b = day.map_anchored()
    vals = []
    for r, report in ((a, "report"), (b, "report_room")):
        m = _READOUT_LINE.search(r.output) or re.search(r"line delay ([\d.]+) us", r.output)
        if m is None:  # (not printed: the report's value)
            c.notes.append(f"`{r.command[:60]}...` printed no line delay: read its report.yaml")
            rep = yaml.safe_load((day.work / report / "report.yaml").read_text())
            m = [None, 1e6 * float(rep["line_delay_s"])] if "line_delay_s" in rep else None
        vals.append(float(m[1]) if m else None)
    if None in vals:
        c.value = f"default frame {vals[0]}, --anchor-pose {vals[1]} us/line"
        c.fail("no line delay from both runs")
        return
    rel = abs(vals[0] - vals[1]) / vals[0]
    c.value = f"{vals[0]:.3f} vs {vals[1]:.3f} us/line with --anchor-pose (rel. diff {rel:.1e})"
    c.expect(rel <= 1e-4, "the output frame changes the line delay")


def check_gravity_frame(day: Day, c: Check) -> None:
    """The map's frame is gravity-aligned by default (z up, REP 105), the choice printed:
    the map's z axis against the room's up after a rigid fit of the map onto the true tags."""
    import yaml

    path, r = day.map_default()
    data = yaml.safe_load(path.read_text())
    frame = data.get("frame") or {}
    got, truth = _corners(path), day.truth()["corners"]
    ids = sorted(set(got) & set(truth))
    R, _ = _rigid_fit(np.vstack([got[m] for m in ids]), np.vstack([truth[m] for m in ids]))
    tilt = float(np.degrees(np.arccos(np.clip((R @ [0, 0, 1.0])[2], -1, 1))))
    printed = re.search(r"^\s*map frame:.*$", r.output, re.M)  # (its own line)
    c.value = (
        f"frame kind {frame.get('kind')!r}, map z {tilt:.2f} deg from up ({len(ids)} tags fitted)"
    )
    c.expect(frame.get("kind") == "gravity", f"frame kind {frame.get('kind')!r}, not 'gravity'")
    c.expect(tilt <= 2.0, f"the map's z axis is {tilt:.1f} deg from up (> 2 deg)")
    c.expect(printed is not None, "map-markers does not print the frame it chose ('map frame:')")
    if printed:
        c.notes.append(printed.group(0).strip())


def _replay(day: Day, map_path: Path) -> dict:
    r = day.run(
        f"rs-localizer replay {day.bag()} --source image -p frontend:=aruco "
        f"-p frontend_map:={map_path} --json --quiet",
        max(day.timeout, 600),
    )
    if r.rc != 0:
        raise CheckFailed(f"replay exit code {r.rc}: {_tail(r.output)}")
    start = r.output.find("{\n")
    try:
        return json.JSONDecoder().raw_decode(r.output[start:])[0]
    except ValueError:
        raise CheckFailed(f"replay printed no JSON: {_tail(r.output)}") from None


def check_replay_truth(day: Day, c: Check) -> None:
    """`replay` against the bag's ground truth: small errors with the map in the room's frame
    (`--anchor-pose`); with the default map (another frame than the truth's) it says so and
    gives the errors after a rigid fit of the frames."""
    room, _ = day.map_anchored()
    s = _replay(day, room)
    rot, pos = s["rot_deg"]["median"], 100 * s["pos_m"]["median"]
    vals = [f"room frame: {s['solved']}/{s['frames_total']} solved, {rot:.3f} deg, {pos:.2f} cm"]
    c.expect(s["solved"] >= 0.95 * s["frames_total"], f"room frame: solved {s['solved']}")
    c.expect(
        rot <= 0.5 and pos <= 5,
        f"room frame: median {rot:.3f} deg, {pos:.2f} cm (> 0.5 deg or 5 cm)",
    )
    own, _ = day.map_default()
    s = _replay(day, own)
    rot, pos = s["rot_deg"]["median"], 100 * s["pos_m"]["median"]
    fit = s.get("frame_fit")
    if fit and fit.get("aligned"):
        a = fit["aligned"]
        frot, fpos = a["rot_deg"]["median"], 100 * a["pos_m"]["median"]
        vals.append(f"map's own frame: raw {rot:.3g} deg, {pos:.3g} cm; after the rigid fit "
                    f"{frot:.3f} deg, {fpos:.2f} cm")  # fmt: skip
        c.expect(frot <= 0.5 and fpos <= 5, "errors after the rigid fit > 0.5 deg or 5 cm")
        c.expect(
            fit.get("other_frame") == (rot > 1 or pos > 5),
            "other_frame disagrees with the raw errors",
        )
    else:
        vals.append(f"map's own frame: raw {rot:.3g} deg, {pos:.3g} cm, no rigid fit reported")
        c.expect(
            rot <= 1 and pos <= 5,
            "the ground truth is in another frame than the map's and replay reports no errors "
            "after a rigid fit of the frames (no 'frame_fit' in --json)",
        )
    c.value = "; ".join(vals)


def check_python_example(day: Day, c: Check) -> None:
    """docs/video.md's 'images to poses' Python block, run as written; its poses against the
    bag's ground truth."""
    text = (ROOT / "docs" / "video.md").read_text()
    blocks = [b for b in re.findall(r"```python\n(.*?)```", text, re.S) if "process_image" in b]
    if not c.expect(blocks, "docs/video.md has no Python block with process_image"):
        return
    check = """
from rs_localizer.ros.bags.bag_io import load_ground_truth
from rs_localizer.geometry import rotation_angle_deg
import numpy as _np
_gt = load_ground_truth(bag)
_rot, _pos = [], []
for _s, _p in poses.items():
    _k = _gt.nearest(_s)
    if _k is not None:
        _rot.append(rotation_angle_deg(_p.orientation, _gt.orientation[_k]))
        _pos.append(float(_np.linalg.norm(_p.position - _gt.position[_k])))
print("NEWCOMER", len(poses), info["frames"], _np.median(_rot), _np.median(_pos), len(_rot))
"""
    script = day.work / "video_example.py"
    script.write_text(blocks[0] + check)
    r = day.run(f"python {script}")
    m = re.search(r"NEWCOMER (\d+) (\d+) ([\d.eE+-]+|nan) ([\d.eE+-]+|nan) (\d+)", r.output)
    if not c.expect(r.rc == 0 and m, f"exit code {r.rc}: {_tail(r.output)}"):
        return
    n, total, rot, pos = int(m.group(1)), int(m.group(2)), float(m.group(3)), float(m.group(4))
    c.value = f"{n}/{total} frames with a pose, median {rot:.3f} deg, {100 * pos:.2f} cm"
    c.expect(n >= 0.9 * total, f"only {n} of {total} frames got a pose")
    c.expect(rot <= 0.5 and pos <= 0.05, "poses off the ground truth (> 0.5 deg or 5 cm)")


def check_export_stamps(day: Day, c: Check) -> None:
    """`export-image --all` keeps each image's stamp (stamps.csv), equal to the bag's."""
    out = day.work / "frames"
    if out.exists():
        shutil.rmtree(out)
    bag = ROOT / "data" / "sample_images"
    r = day.run(f"rs-localizer export-image {bag} {out} --all --quiet")
    if not c.expect(r.rc == 0, f"exit code {r.rc}: {_tail(r.output)}"):
        return
    images = sorted(out.glob("*.png"))
    csv = out / "stamps.csv"
    if not c.expect(csv.exists(), f"{len(images)} images and no stamps.csv"):
        c.value = f"{len(images)} images, no stamps"
        return
    rows = [ln.split(",") for ln in csv.read_text().splitlines() if ln.strip()]
    stamps = [int(x[-1]) for x in rows if x[-1].strip().isdigit()]
    info = json.loads((bag / "sequence.json").read_text())
    start = int(round(float(info["settings"].get("start_time", 1700000000.0)) * 1e9))
    c.value = f"{len(images)} images, {len(stamps)} stamps in stamps.csv"
    c.expect(len(stamps) == len(images) == info["frames"], "a stamp per image, per frame")
    c.expect(stamps == sorted(stamps) and len(set(stamps)) == len(stamps), "stamps not increasing")
    c.expect(
        bool(stamps) and abs(stamps[0] - start) < 10**9,
        f"first stamp {stamps[:1]} not the video's start {start}",
    )


def check_readout_howto(day: Day, c: Check) -> None:
    """The readout-time how-to (docs/video.md) starts from what a user without a map has:
    `map-markers --calibrate-readout`."""
    text = (ROOT / "docs" / "video.md").read_text()
    sec = text.split("### What is my camera's readout time?", 1)[-1].split("\n## ", 1)[0]
    sec = sec.split("| camera |", 1)[0]  # (the prose before the table)
    ok = "map-markers" in sec and "--calibrate-readout" in sec
    c.value = "names map-markers --calibrate-readout" if ok else "only calibrate-readout"
    c.expect(
        ok, "docs/video.md's readout how-to does not start from map-markers --calibrate-readout"
    )


def check_calibrate_errors(day: Day, c: Check) -> None:
    """`calibrate-readout` on an image bag without a marker map (a recording: no
    sequence.json): the error names what is missing."""
    src = ROOT / "data" / "sample_images"
    bag = day.work / "recording"
    if bag.exists():
        shutil.rmtree(bag)
    bag.mkdir()
    for f in src.iterdir():  # the camera's recording: images, no sequence.json, no map
        if f.name == "metadata.yaml" or f.suffix in (".mcap", ".db3"):
            shutil.copy(f, bag / f.name)
    said = []
    for cmd, want, what in (
        (f"rs-localizer calibrate-readout {bag} --source image --frontend aruco",
         r"--frontend-map|marker map|\bmap\b", "the map"),
        (f"rs-localizer calibrate-readout {bag} --source image", r"--frontend\b|front end",
         "the front end"),
    ):  # fmt: skip
        r = day.run(cmd)
        msg = _tail(r.output, 300).replace("\n", " ")
        said.append(msg)
        c.expect(r.rc not in (0, -1), f"`{cmd}` exit code {r.rc}")
        c.expect(re.search(want, r.output, re.I), f"`{cmd}` does not name {what}: {msg}")
        if what == "the map":
            c.expect(
                "no front end given" not in r.output,
                f"`{cmd}` says 'no front end given' (one was)",
            )
    c.value = " | ".join(said)


def check_lockstep_ns(day: Day, c: Check) -> None:
    """`play --lockstep` into another namespace waits on that namespace's pose topic: a node
    in /robot/camera answers every frame played with `--remap __ns:=/robot`, a node in /robot
    every frame played with its topics remapped there; played where no node runs it stops
    within a minute with a clear message (the 30 s wait for a subscriber included)."""
    base = "--params-file config/rs_localizer.yaml -r __ns:="
    nodes = []
    answered = []
    try:
        nodes.append(day.node(base + "/robot/camera")[0])
        nodes.append(day.node(base + "/robot")[0])
        for how, remap in (
            ("__ns", "__ns:=/robot"),
            ("remaps", "/camera/correspondences:=/robot/correspondences "
                       "/camera/camera_info:=/robot/camera_info"),
        ):  # fmt: skip
            r = day.run(f"rs-localizer play data/sample --lockstep --remap {remap}", 300)
            m = re.search(r"(\d+) answered, (\d+) timed out", r.output)
            ans = f"{m.group(1)} answered, {m.group(2)} timed out" if m else "no count"
            answered.append(f"{how}: {ans}")
            c.expect(
                r.rc == 0 and m and int(m.group(1)) == 30,
                f"play with --remap {remap}: {_tail(r.output, 300)}",
            )
        d = day.run("rs-localizer diagnostics --ns /robot/camera --once --timeout 20", 60)
        day._done["diagnostics"] = d
        t0 = time.perf_counter()
        r2 = day.run("rs-localizer play data/sample --lockstep --remap __ns:=/nobody", 300)
        waited = time.perf_counter() - t0
        clear = re.search(r"no node answered", r2.output)
        c.expect(r2.rc != 0 and clear, f"into /nobody: no clear stop: {_tail(r2.output, 300)}")
        c.expect(waited <= 60, f"into /nobody: gave up after {waited:.0f} s (> 60 s)")
        c.value = "; ".join(answered) + f"; into /nobody: stopped after {waited:.1f} s"
        if clear:
            c.notes.append(next(ln for ln in r2.output.splitlines() if clear.group(0) in ln))
    finally:
        for node in nodes:
            _stop(node)


def check_diagnostics(day: Day, c: Check) -> None:
    """`rs-localizer diagnostics` prints a running node's counters (the /robot/camera node of
    lockstep_ns after its 30 frames)."""
    if "diagnostics" not in day._done:
        check_lockstep_ns(day, Check("lockstep_ns"))
    d = day._done.get("diagnostics")
    if d is None:
        c.fail("the node of lockstep_ns did not run")
        return
    v = _diag_values(d.output)
    c.value = ", ".join(f"{k}={v[k]:g}" for k in ("frames_received", "frames_solved",
                                                  "latency_ms_median") if k in v)  # fmt: skip
    c.expect(d.rc == 0, f"exit code {d.rc}: {_tail(d.output, 300)}")
    c.expect(v.get("frames_received") == 30, f"frames_received {v.get('frames_received')} of 30")


def _viewer_run(day: Day, viewers: bool) -> dict:
    """The node on the day's video played at 30 Hz (not lock-step), with or without a viewer
    subscribed to debug_image, markers and path; the node's diagnostics at the end."""
    bag = day.bag()
    fmap = day.map_anchored()[0]
    node, _, ready = day.node(
        f"--params-file config/rs_localizer.yaml --params-file {IMAGE_PARAMS} -r __ns:=/camera "
        f"-r image:=image_raw -p frontend_map:={fmap}"
    )
    viewer = None
    try:
        if viewers:
            day.ran.append("(a viewer subscribing /camera/debug_image, markers and path)")
            viewer = subprocess.Popen(
                [sys.executable, "-c", _VIEWER],
                cwd=ROOT,
                env=_env(day.domain),
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
            )
            time.sleep(3.0)  # (discovery)
        day.must(f"rs-localizer play {bag} --topics /camera/image_raw /camera/camera_info", 120)
        time.sleep(2.0)
        d = day.run("rs-localizer diagnostics --ns /camera --once --timeout 20", 60)
        counts = ""
        if viewer is not None:
            viewer.send_signal(signal.SIGINT)
            counts = viewer.communicate(timeout=15)[0]
        v = _diag_values(d.output)
        v["ready_s"] = ready
        m = re.search(r"VIEWER (\d+) (\d+) (\d+)", counts)
        v["viewer"] = tuple(map(int, m.groups())) if m else None
        return v
    finally:
        if viewer is not None and viewer.poll() is None:
            viewer.kill()
        _stop(node)


_VIEWER = """
import signal, rclpy
from rclpy.qos import qos_profile_sensor_data as q
from sensor_msgs.msg import Image
from visualization_msgs.msg import MarkerArray
from nav_msgs.msg import Path
rclpy.init()
n = rclpy.create_node("newcomer_viewer")
c = [0, 0, 0]
def sub(t, topic, i):
    def cb(_m):
        c[i] += 1
    n.create_subscription(t, topic, cb, q)
sub(Image, "/camera/debug_image", 0)
sub(MarkerArray, "/camera/markers", 1)
sub(Path, "/camera/path", 2)
try:
    rclpy.spin(n)
except (KeyboardInterrupt, Exception):
    pass
print("VIEWER", *c, flush=True)
"""


def check_viewers(day: Day, c: Check) -> None:
    """The node on a 30 Hz 640x480 marker video keeps every frame with debug_image, markers
    and path subscribed: fails when frames are dropped with viewers and not without (or many
    more); when the node drops frames without viewers too, the machine does not keep up and
    it is reported, not judged. The latency median rise (<= 2 ms) is measured and reported
    only (a shared machine's load moves it more than that)."""
    _viewer_run(day, viewers=False)  # warm-up: a first node's start loads and caches kernels
    base = _viewer_run(day, viewers=False)
    seen = _viewer_run(day, viewers=True)
    n = DAY_FRAMES

    def dropped(v):
        return (
            n - v.get("frames_received", 0) + v.get("frames_skipped", 0) + v.get("messages_lost", 0)
        )

    def desc(v):
        return (f"received {v.get('frames_received', 0):g}/{n}, skipped "
                f"{v.get('frames_skipped', 0):g}, lost {v.get('messages_lost', 0):g}, latency "
                f"median {v.get('latency_ms_median', float('nan')):.1f} ms")  # fmt: skip

    rise = seen.get("latency_ms_median", np.nan) - base.get("latency_ms_median", np.nan)
    c.value = f"with viewers: {desc(seen)}; without: {desc(base)}; median rise {rise:+.1f} ms"
    c.notes.append(
        f"REPORT (not judged on a shared machine): latency median rise {rise:+.1f} ms "
        f"(target <= 2 ms); node ready in {base['ready_s']:.1f} / {seen['ready_s']:.1f} s "
        "(README: ~2.5 s)"
    )
    if seen.get("viewer"):
        c.notes.append("the viewer got debug_image/markers/path: {}/{}/{}".format(*seen["viewer"]))
    c.expect(seen.get("viewer") and min(seen["viewer"]) > 0, "the viewer received nothing")
    lost, lost0 = dropped(seen), dropped(base)
    if lost0 == 0:
        c.expect(lost == 0, f"with viewers {lost} of {n} frames were not solved (none without)")
    elif lost > lost0 + max(2, n // 10):
        c.fail(f"with viewers {lost} of {n} frames were not solved, without {lost0}")
    elif c.verdict == "PASS":
        c.verdict = "REPORT"
        c.notes.append(
            f"not judged: the node drops frames without viewers too ({lost0} of {n}; load "
            f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores), with viewers {lost}: the "
            "machine does not keep up at 30 Hz; run again on a quieter one"
        )


def check_demo_domain(day: Day, c: Check) -> None:
    """`make demo` (`rs-localizer demo`) keeps a ROS_DOMAIN_ID the user set."""
    make = subprocess.run(["make", "-n", "demo"], cwd=ROOT, capture_output=True, text=True)
    recipe = [ln for ln in make.stdout.splitlines() if " demo" in ln]
    c.expect(not any("ROS_DOMAIN_ID" in ln for ln in recipe), f"make demo sets it: {recipe}")
    user = 1 + (day.domain + 50) % 100  # (another id than the checker's own)
    r = day.demo(user)
    used = sorted(set(re.findall(r"ROS_DOMAIN_ID=(\d+)", r.output)))
    c.value = f"set {user}, the demo used {', '.join(used) or 'nothing printed'}"
    c.expect(r.rc == 0, f"demo exit code {r.rc}: {_tail(r.output)}")
    c.expect(used == [str(user)], "the demo did not keep the user's ROS_DOMAIN_ID")


def check_demo_figures(day: Day, c: Check) -> None:
    """The README's rotation-accuracy ratio range holds what `make demo` prints (both parts),
    and after `rs-localizer compile` the demo does not ask for it again."""
    r = day.demo(1 + (day.domain + 50) % 100)
    ratios = [float(x) for x in re.findall(r"median rotation error ([\d.]+)x smaller", r.output)]
    readme = (ROOT / "README.md").read_text()
    m = re.search(r"it is ([\d.]+)-([\d.]+)x more accurate\s+in rotation", readme)
    c.value = f"demo prints {ratios}x; README says {m.group(1)}-{m.group(2)}x" if m else f"{ratios}"
    if not c.expect(m, "README states no 'X-Yx more accurate in rotation' range"):
        return
    lo, hi = float(m.group(1)), float(m.group(2))
    half = 0.5 * 10.0 ** -len(m.group(2).partition(".")[2])  # (the README's rounding)
    c.expect(len(ratios) == 2, f"{len(ratios)} ratios printed (expected 2: both parts)")
    c.expect(
        all(lo - half <= x < hi + half for x in ratios),
        "a printed ratio is outside the README's range (as rounded there)",
    )
    c.expect(
        "no compiled kernels cached yet" not in r.output,
        "the demo asks for `rs-localizer compile` (run before it, by check compile)",
    )


# ---------------------------------------------------------------------------------------------
# A rig user's first day: a wheeled robot with three rolling-shutter cameras (front, left,
# right; the renderer standing in: ``render-bag --rig 3``, 640x480 each) in a lab with AprilTag
# 36h11 tags on its walls: the mountings from data, the rig node in lock-step and at the bag's
# rate, replay and evaluate, the faults a robot meets (a camera unplugged, absent, without
# camera_info, a mounting off), the managed node and the viewer.

#: the rig's video: frames per camera (each a rig frame)
RIG_FRAMES = 60
RIG_RENDER = "rs-localizer render-bag {bag} --rig 3 --frames {n}"
RIG_CAMERAS = ("front", "left", "right")
#: calibrate-rig against the renderer's mountings: largest error (deg, mm) on the short video
#: (docs/rig_node.md: 0.1 deg and 5 mm on 300 frames), and the std covers the error within
#: this many standard deviations
RIG_CAL_TOL = (0.3, 10.0)
RIG_CAL_SIGMAS = 3.0


def _rig_params(path: Path) -> dict:
    """The ``ros__parameters`` of a rig parameter file (``rig_params.yaml``)."""
    import yaml

    data = yaml.safe_load(path.read_text())
    return next(iter(data.values()))["ros__parameters"]


def _mounting_error(a: list[float], b: list[float]) -> tuple[float, float]:
    """Rotation (deg) and position (mm) between two mountings ``[x, y, z, qx, qy, qz, qw]``."""
    from scipy.spatial.transform import Rotation

    rot = Rotation.from_quat(a[3:]).inv() * Rotation.from_quat(b[3:])
    return float(np.degrees(rot.magnitude())), 1e3 * float(
        np.linalg.norm(np.subtract(a[:3], b[:3]))
    )


def _diag_words(text: str) -> dict[str, str]:
    """Every key=value pair ``rs-localizer diagnostics`` printed, as text (the last of each)."""
    return dict(re.findall(r"([\w.<>-]+)=(\S+)", text))


def _rig_accounting(v: dict[str, float], cams=RIG_CAMERAS) -> list[str]:
    """Per camera ``received = solved + failed + skipped + pending`` from the diagnostics'
    numbers: the cameras where it does not hold (or is not printed), described."""
    bad = []
    for cam in cams:
        parts = [
            v.get(f"{cam}.{k}") for k in ("received", "solved", "failed", "skipped", "pending")
        ]
        if None in parts:
            bad.append(f"{cam}: counts not printed")
        elif parts[0] != sum(parts[1:]):
            bad.append(f"{cam}: received {parts[0]:g} != {' + '.join(f'{p:g}' for p in parts[1:])}")
    return bad


def _rig_counts(v: dict[str, float], cams=RIG_CAMERAS) -> str:
    return "; ".join(
        f"{c} {v.get(c + '.received', 0):g} = {v.get(c + '.solved', 0):g} + "
        f"{v.get(c + '.failed', 0):g} + {v.get(c + '.skipped', 0):g} + {v.get(c + '.pending', 0):g}"
        for c in cams
    )


def _reasons(v: dict[str, float]) -> str:
    """The nonzero ``<camera>.skipped.<reason>``, ``.failed.<reason>`` and
    ``rig_frames_failed.<reason>`` counts of the diagnostics."""
    keys = [
        k for k, x in v.items() if x and re.search(r"\.(skipped|failed)\.|^rig_frames_failed\.", k)
    ]
    return ", ".join(f"{k}={v[k]:g}" for k in keys) or "none"


def _copy_bag(src: Path, dst: Path, keep) -> int:
    """A copy of the rig bag ``src`` at ``dst`` with the messages ``keep(topic, log_time_ns)``
    accepts (its parameter files too), as a robot would have recorded it; returns the number
    of messages written."""
    from rosbags.rosbag2 import Reader, Writer

    from rs_localizer.ros.bags.bag_io import storage_plugin, typestore

    shutil.rmtree(dst, ignore_errors=True)
    ts, n = typestore(), 0
    with Reader(src) as r, Writer(dst, version=9, storage_plugin=storage_plugin("mcap")) as w:
        conns = {c.id: w.add_connection(c.topic, c.msgtype, typestore=ts) for c in r.connections}
        for conn, t_ns, raw in r.messages():
            if keep(conn.topic, t_ns):
                w.write(conns[conn.id], t_ns, raw)
                n += 1
    for f in src.iterdir():
        if f.suffix in (".yaml", ".json") and f.name != "metadata.yaml":
            shutil.copy(f, dst / f.name)
    return n


class RigDay:
    """The rig day's shared steps on top of a :class:`Day` (its commands, node, work folder)."""

    def __init__(self, day: Day):
        self.day = day

    def bag(self) -> Path:
        def make():
            bag = self.day.work / "rig"
            shutil.rmtree(bag, ignore_errors=True)
            r = self.day.must(RIG_RENDER.format(bag=bag, n=RIG_FRAMES), max(self.day.timeout, 900))
            self.day._done["rig_render_seconds"] = r.seconds
            return bag

        return self.day.once("rig_bag", make)

    def lean(self) -> Path:
        """The rig bag without its images (the rig node takes the correspondences): the faults'
        bags are cut from it."""

        def make():
            out = self.day.work / "rig_lean"
            _copy_bag(self.bag(), out, lambda topic, _t: not topic.endswith("image_raw"))
            return out

        return self.day.once("rig_lean", make)

    def node(self, params: str, extra: str = "", marker: str = "ready:"):
        return self.day.node(f"--params-file {params} -r __ns:=/rig {extra}".strip(), marker=marker)

    def diagnostics(self) -> tuple[Run, dict[str, float], dict[str, str]]:
        time.sleep(2.0)  # (a status after the last frame)
        d = self.day.run("rs-localizer diagnostics --ns /rig --once --timeout 20", 60)
        return d, _diag_values(d.output), _diag_words(d.output)


def _rig(day: Day) -> RigDay:
    return day.once("rig_day", lambda: RigDay(day))


def check_rig_render(day: Day, c: Check) -> None:
    """The robot's video: `render-bag --rig 3` (front, left, right rolling-shutter cameras,
    640x480, in a lab of AprilTag 36h11 tags) writes every camera's images, camera_info and
    correspondences, the rig's ground truth and the true mountings (`rig_params.yaml`)."""
    from rs_localizer.ros.bags.bag_io import bag_topics

    bag = _rig(day).bag()
    topics = bag_topics(bag)
    kinds = ("image_raw", "camera_info", "correspondences")
    want = {f"/rig/{cam}/{t}" for cam in RIG_CAMERAS for t in kinds} | {"/ground_truth/pose"}
    cams = _rig_params(bag / "rig_params.yaml").get("rig", {}).get("cameras", [])
    from rs_localizer.ros.bags.bag_io import iter_messages

    n = sum(1 for _ in iter_messages(bag, {f"/rig/{cam}/correspondences" for cam in RIG_CAMERAS}))
    c.value = (
        f"{len(cams)} cameras {cams}, {n} camera frames ({RIG_FRAMES} per camera), "
        f"{day._done.get('rig_render_seconds', 0):.0f} s"
    )
    c.expect(list(cams) == list(RIG_CAMERAS), f"rig_params.yaml names cameras {cams}")
    c.expect(not want - set(topics), f"topics missing: {sorted(want - set(topics))}")
    c.expect(n == 3 * RIG_FRAMES, f"{n} camera frames of {3 * RIG_FRAMES}")


def check_rig_calibrate(day: Day, c: Check) -> None:
    """`calibrate-rig` (`--min-inliers 8`: the side cameras see few tags, docs/rig_node.md)
    finds every camera's mounting within 0.3 deg and 10 mm of the renderer's, its printed std
    covering the error (within 3 std), and names the rig frame it wrote."""
    bag = _rig(day).bag()
    out = day.work / "rig_calibrated.yaml"
    r = day.run(f"rs-localizer calibrate-rig {bag} -o {out} --min-inliers 8 --json")
    if not c.expect(r.rc == 0, f"exit code {r.rc}: {_tail(r.output)}"):
        return
    got = json.loads(r.output[r.output.find("{") :].rsplit("}", 1)[0] + "}")
    truth = _rig_params(bag / "rig_params.yaml")["rig"]
    vals = []
    for cam, m in got["cameras"].items():
        if cam == got.get("reference"):
            continue
        deg, mm = _mounting_error(m["mounting"], truth[cam]["mounting"])
        vals.append(f"{cam} {deg:.3f} deg {mm:.2f} mm (std {m['std_deg']:.3f} deg "
                    f"{m['std_mm']:.2f} mm, {m['frames']} frames)")  # fmt: skip
        c.expect(
            deg <= RIG_CAL_TOL[0] and mm <= RIG_CAL_TOL[1],
            f"{cam}: {deg:.3f} deg, {mm:.2f} mm off the truth (> {RIG_CAL_TOL[0]} deg or "
            f"{RIG_CAL_TOL[1]} mm)",
        )
        c.expect(
            deg <= RIG_CAL_SIGMAS * m["std_deg"] and mm <= RIG_CAL_SIGMAS * m["std_mm"],
            f"{cam}: the std does not cover the error ({deg / max(m['std_deg'], 1e-12):.1f} "
            f"and {mm / max(m['std_mm'], 1e-12):.1f} std)",
        )
    named = re.search(r"rig frame (\S+)", r.output)
    c.value = "; ".join(vals) + (f"; rig frame {named.group(1)}" if named else "")
    c.expect(named, "calibrate-rig does not name the rig frame it wrote")
    c.expect(got.get("rig_frame") == _rig_params(bag / "rig_params.yaml").get("base_frame"),
             f"rig frame {got.get('rig_frame')!r}, the parameters' base_frame differs")  # fmt: skip
    c.expect(out.exists() and "mounting" in out.read_text(), "no parameter file written")


#: play's lock-step count on a rig bag: rig frames completed, waits answered, timed out
PLAY_RIG_COUNT = re.compile(r"(\d+) rig frames completed in \d+ waits answered, (\d+) timed out")


def check_rig_lockstep(day: Day, c: Check) -> None:
    """The rig node (`rs_localizer_node` with the bag's `rig_params.yaml`) and `play
    --lockstep` with the true mountings, after the install step `rs-localizer compile
    --params-file` with the rig's parameters (docs/install.md): every rig frame posed (play's
    count of rig frames completed, none timed out, and the node's rig_frames_solved; a failed
    one is named with its reason), the poses (`evaluate --live` on /rig/pose_with_covariance
    against the bag's truth) within 0.1 deg and 5 mm (median)."""
    rig = _rig(day)
    bag = rig.bag()
    r = day.run(f"rs-localizer compile --params-file {bag / 'rig_params.yaml'}", 900)
    c.expect(r.rc == 0, f"compile exit code {r.rc}: {_tail(r.output, 200)}")
    node = rig.node(bag / "rig_params.yaml")[0]
    ev = None
    try:
        cmd = (f"rs-localizer evaluate --live 40 --wait 120 --topic /rig/pose_with_covariance "
               f"--truth {bag} --json")  # fmt: skip
        day.ran.append(cmd + " &")
        ev = subprocess.Popen(_argv(cmd), cwd=ROOT, env=_env(day.domain), text=True,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE)  # fmt: skip
        time.sleep(4.0)  # (evaluate subscribes)
        r = day.run(f"rs-localizer play {bag} --lockstep --timeout 10", 600)
        m = PLAY_RIG_COUNT.search(r.output)
        _, v, _ = rig.diagnostics()
        out, err = ev.communicate(timeout=120)
    finally:
        if ev is not None and ev.poll() is None:
            ev.kill()
        _stop(node)
    solved, failed = v.get("rig_frames_solved", 0), v.get("rig_frames_failed", 0)
    reasons = {k: x for k, x in v.items() if k.startswith("rig_frames_failed.")}
    vals = [
        f"play: {m.group(1)} rig frames completed, {m.group(2)} timed out"
        if m
        else "play: no count",
        f"{solved:g}/{RIG_FRAMES} rig frames posed, {failed:g} failed {reasons or ''}",
    ]
    c.expect(r.rc == 0 and m, f"play exit code {r.rc}: {_tail(r.output, 200)}")
    c.expect(solved + failed == RIG_FRAMES, f"{solved + failed:g} of {RIG_FRAMES} rig frames done")
    c.expect(solved == RIG_FRAMES, f"{solved:g} of {RIG_FRAMES} rig frames posed")
    c.expect(m and int(m.group(1)) == RIG_FRAMES, "play: not every rig frame answered")
    try:
        res = json.loads(out)
        rot, pos = res["ape"]["rot_deg"]["median"], 1e3 * res["ape"]["pos_m"]["median"]
        vals.append(f"evaluate: {res['matched']} poses matched, APE median {rot:.4f} deg "
                    f"{pos:.2f} mm")  # fmt: skip
        c.expect(
            rot <= 0.1 and pos <= 5, f"APE median {rot:.4f} deg {pos:.2f} mm (> 0.1 deg or 5 mm)"
        )
        c.expect(
            res["matched"] >= solved - 1, f"evaluate matched {res['matched']} of {solved:g} poses"
        )
    except (ValueError, KeyError, TypeError):
        c.fail(f"evaluate --live printed no figures: {_tail(out + err, 300)}")
    c.value = "; ".join(vals)


def check_rig_realtime(day: Day, c: Check) -> None:
    """The rig node and `play` at the bag's rate (30 Hz per camera, not lock-step): every camera
    frame accounted in /diagnostics (per camera received = solved + failed + skipped +
    pending, received = the frames played)."""
    rig = _rig(day)
    bag = rig.bag()
    node = rig.node(bag / "rig_params.yaml")[0]
    try:
        r = day.run(f"rs-localizer play {bag}", 600)
        d, v, _ = rig.diagnostics()
    finally:
        _stop(node)
    c.value = _rig_counts(v) + f"; rig frames posed {v.get('rig_frames_solved', 0):g}/{RIG_FRAMES}"
    c.notes.append("not solved: " + _reasons(v))
    c.expect(r.rc == 0, f"play exit code {r.rc}: {_tail(r.output, 300)}")
    c.expect(d.rc == 0, f"diagnostics exit code {d.rc}: {_tail(d.output, 300)}")
    for bad in _rig_accounting(v):
        c.fail(bad)
    for cam in RIG_CAMERAS:
        got = v.get(f"{cam}.received", 0) + v.get(f"{cam}.messages_lost", 0)
        c.expect(got == RIG_FRAMES, f"{cam}: {got:g} of {RIG_FRAMES} frames received or lost")


def check_rig_replay_evaluate(day: Day, c: Check) -> None:
    """`replay` of the rig bag (`--out`, `--json`): its counts and median errors; `rs-localizer
    evaluate` of the recorded output against the bag's truth gives the same medians (5 %, or
    0.001 deg and 0.05 mm) within 0.1 deg and 5 mm."""
    bag = _rig(day).bag()
    out = day.work / "rig_out"
    shutil.rmtree(out, ignore_errors=True)
    r = day.run(f"rs-localizer replay {bag} --out {out} --json --quiet", max(day.timeout, 900))
    if not c.expect(r.rc == 0, f"replay exit code {r.rc}: {_tail(r.output)}"):
        return
    try:
        s = json.JSONDecoder().raw_decode(r.output[r.output.find("{\n") :])[0]
    except ValueError:
        c.fail(f"replay printed no JSON: {_tail(r.output)}")
        return
    try:
        rot, pos = s["rot_deg"]["median"], 1e3 * s["pos_m"]["median"]
    except (KeyError, TypeError):
        c.fail(f"replay printed no errors against the truth: {_tail(r.output)}")
        return
    vals = [f"replay {s['solved']}/{s['frames_total']} posed, {rot:.4f} deg {pos:.3f} mm"]
    c.expect(s["solved"] >= 0.95 * s["frames_total"], f"replay posed {s['solved']}")
    for cam in RIG_CAMERAS:
        k = s["counts"].get(cam, {})
        c.expect(k.get("received") == sum(k.get(x, 0) for x in ("solved", "failed", "skipped",
                 "pending")), f"replay {cam}: {k}")  # fmt: skip
    e = day.run(f"rs-localizer evaluate {out} --truth {bag} --json")
    try:
        res = json.loads(e.output[e.output.find("{\n") :].rsplit("}", 1)[0] + "}")
        erot, epos = res["ape"]["rot_deg"]["median"], 1e3 * res["ape"]["pos_m"]["median"]
    except (ValueError, KeyError, TypeError):
        c.fail(f"evaluate exit code {e.rc}: {_tail(e.output)}")
        c.value = vals[0]
        return
    vals.append(f"evaluate {res['matched']} matched, APE median {erot:.4f} deg {epos:.3f} mm")
    c.value = "; ".join(vals)
    c.expect(res["matched"] == s["solved"], f"evaluate matched {res['matched']} of {s['solved']}")
    c.expect(abs(erot - rot) <= max(0.05 * rot, 1e-3) and abs(epos - pos) <= max(0.05 * pos, 0.05),
             "evaluate's medians differ from replay's")  # fmt: skip
    c.expect(erot <= 0.1 and epos <= 5, "APE median > 0.1 deg or 5 mm")


def _rig_fault_run(day: Day, c: Check, bag: Path, params: Path, play: str, extra: str = "",
                   watch: bool = False):  # fmt: skip
    """The rig node with ``params`` and ``play`` of ``bag``; returns (node log, the final
    diagnostics (numbers, words, text) and, with ``watch``, every status printed meanwhile)."""
    rig = _rig(day)
    node, lines, _ = rig.node(params, extra)
    watcher, seen = None, day.work / "rig_diagnostics.txt"
    try:
        if watch:
            cmd = "rs-localizer diagnostics --ns /rig --timeout 60"
            day.ran.append(cmd + " &")
            env = _env(day.domain)
            env["PYTHONUNBUFFERED"] = "1"  # (its output is read after it is stopped)
            with seen.open("w") as f:
                watcher = subprocess.Popen(_argv(cmd), cwd=ROOT, env=env, text=True, stdout=f,
                                           stderr=subprocess.STDOUT)  # fmt: skip
            time.sleep(3.0)
        r = day.run(f"rs-localizer play {bag} {play}".strip(), 600)
        c.expect(r.rc == 0, f"play exit code {r.rc}: {_tail(r.output, 300)}")
        d, v, w = rig.diagnostics()
        return "".join(lines), v, w, d.output, seen.read_text() if watch else ""
    finally:
        if watcher is not None:
            _stop(watcher)
        _stop(node)


def check_rig_unplugged(day: Day, c: Check) -> None:
    """A camera unplugged mid-run: the right camera's topics end half way (a copy of the bag
    cut there), played at half the bag's rate (the loaded machine keeps up): the right
    camera's state is `stopped` with a WARN status, the rig poses rig frames without it (more
    than the right camera's solved frames), every frame accounted."""
    rig = _rig(day)
    lean = rig.lean()
    from rs_localizer.ros.bags.bag_io import iter_messages

    stamps = sorted(t for _, _, t, _ in iter_messages(lean, {"/rig/right/correspondences"}))
    cut = stamps[len(stamps) // 2]
    bag = day.work / "rig_unplugged"
    _copy_bag(lean, bag, lambda topic, t: not (topic.startswith("/rig/right/") and t >= cut))
    day.ran.append(f"(a copy of the bag without the right camera's messages from frame "
                   f"{len(stamps) // 2} on: {bag})")  # fmt: skip
    _, v, w, text, _ = _rig_fault_run(day, c, bag, bag / "rig_params.yaml", "--rate 0.5")
    head = re.search(r"\[(\w+)\] [^\n]*", text)
    status = head.group(0) if head else "no status"
    c.value = (f"right.state={w.get('right.state')}, {status}; rig frames posed "
               f"{v.get('rig_frames_solved', 0):g}; " + _rig_counts(v))  # fmt: skip
    c.expect(w.get("right.state") == "stopped", f"right.state {w.get('right.state')!r}")
    c.expect(head and head.group(1) == "WARN", "the status is not WARN")
    c.expect(v.get("rig_frames_solved", 0) > v.get("right.solved", 0),
             "the rig posed no rig frame without the right camera")  # fmt: skip
    for bad in _rig_accounting(v):
        c.fail(bad)
    c.notes.append("not solved: " + _reasons(v))


def check_rig_absent(day: Day, c: Check) -> None:
    """A camera absent from the start (the right camera's topics not played; played at half
    the bag's rate): while the rig waits for it the status is ERROR naming it (`no frame from
    camera right`, after `rig.stop_after`); then the rig runs on the other two."""
    rig = _rig(day)
    lean = rig.lean()
    topics = " ".join(f"/rig/{cam}/{t}" for cam in ("front", "left")
                      for t in ("camera_info", "correspondences"))  # fmt: skip
    _, v, w, text, seen = _rig_fault_run(
        day, c, lean, lean / "rig_params.yaml", f"--rate 0.5 --topics {topics}",
        extra="-p diagnostics_period:=0.25", watch=True,
    )  # fmt: skip
    err = re.search(r"\[ERROR\] [^\n]*no frame from camera right[^\n]*", seen)
    head = re.search(r"\[(\w+)\] [^\n]*", text)
    status = head.group(0) if head else "no status"
    c.value = (f"{err.group(0) if err else 'no ERROR naming right seen'}; at the end {status}, "
               f"rig frames posed {v.get('rig_frames_solved', 0):g}, "
               f"right.state={w.get('right.state')}")  # fmt: skip
    c.expect(err, "no ERROR status naming the absent camera while the rig waited")
    c.expect(v.get("rig_frames_solved", 0) > 0, "the rig did not run on the other two")
    c.expect(v.get("right.received", -1) == 0, f"right.received {v.get('right.received')}")


def check_rig_no_camera_info(day: Day, c: Check) -> None:
    """A camera without camera_info (the left camera's not played; half the bag's rate): its
    state `waiting`, none of its frames used and every one waiting counted
    `skipped.no_camera_info`, a log line naming its camera_info topic, the rig runs on the
    others (rig frames posed)."""
    rig = _rig(day)
    lean = rig.lean()
    topics = " ".join(f"/rig/{cam}/{t}" for cam in RIG_CAMERAS for t in ("camera_info",
                      "correspondences") if not (cam == "left" and t == "camera_info"))  # fmt: skip
    log, v, w, _, _ = _rig_fault_run(day, c, lean, lean / "rig_params.yaml",
                                     f"--rate 0.5 --topics {topics}")  # fmt: skip
    named = next((ln.strip() for ln in log.splitlines() if "/rig/left/camera_info" in ln), "")
    c.value = (f"left.state={w.get('left.state')}, left.skipped.no_camera_info="
               f"{v.get('left.skipped.no_camera_info', 0):g} of {v.get('left.received', 0):g}, "
               f"rig frames posed {v.get('rig_frames_solved', 0):g}")  # fmt: skip
    c.expect(w.get("left.state") == "waiting", f"left.state {w.get('left.state')!r}")
    c.expect(
        v.get("left.received", 0) > 0 and v.get("left.skipped.no_camera_info", 0) > 0,
        "left's frames not counted skipped.no_camera_info",
    )
    c.expect(v.get("left.solved", 0) + v.get("left.failed", 0) == 0, "left's frames were used")
    c.expect(named, "no log line names /rig/left/camera_info")
    c.expect(v.get("rig_frames_solved", 0) > 0, "the rig did not run on the others")
    for bad in _rig_accounting(v):
        c.fail(bad)
    c.notes.append("not solved: " + _reasons(v))
    if named:
        c.notes.append(named[-200:])


def check_rig_mounting_off(day: Day, c: Check) -> None:
    """The right camera's mounting given 5 deg off (turned about the rig's z axis), the bag
    played at half its rate: the node's status names `right` as disagreeing (state
    `disagrees`), and so does `replay` with that parameter file."""
    import yaml
    from scipy.spatial.transform import Rotation

    rig = _rig(day)
    lean = rig.lean()
    data = yaml.safe_load((lean / "rig_params.yaml").read_text())
    p = next(iter(data.values()))["ros__parameters"]
    m = p["rig"]["right"]["mounting"]
    q = (Rotation.from_euler("z", 5, degrees=True) * Rotation.from_quat(m[3:])).as_quat()
    p["rig"]["right"]["mounting"] = [*m[:3], *map(float, q)]
    off = day.work / "rig_right_off5deg.yaml"
    off.write_text(yaml.safe_dump(data))
    day.ran.append(f"(the rig's parameters, right's mounting turned by 5 deg: {off})")
    _, v, w, text, _ = _rig_fault_run(day, c, lean, off, "--rate 0.5")
    head = re.search(r"\[(\w+)\] [^\n]*", text)
    c.notes.append(f"rig frames posed {v.get('rig_frames_solved', 0):g}/{RIG_FRAMES}; not solved: "
                   + _reasons(v))  # fmt: skip
    c.expect(w.get("right.state") == "disagrees", f"right.state {w.get('right.state')!r}")
    c.expect(head and re.search(r"\bright\b[^\n]*disagree", head.group(0)),
             "the status does not name right as disagreeing")  # fmt: skip
    r = day.run(f"rs-localizer replay {lean} --params-file {off}", max(day.timeout, 900))
    said = next((ln.strip() for ln in r.output.splitlines() if "disagree" in ln), "")
    status = head.group(0) if head else "no status"
    c.value = (f"node: {status}, right.state={w.get('right.state')}; replay: "
               f"{said or 'names no camera disagreeing'}")  # fmt: skip
    c.expect(r.rc == 0, f"replay exit code {r.rc}: {_tail(r.output, 300)}")
    c.expect("right" in said, "replay does not name right as disagreeing")


_LIFECYCLE = """
import sys, rclpy
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
rclpy.init()
n = rclpy.create_node("newcomer_lifecycle")
name = sys.argv[1]
change = n.create_client(ChangeState, name + "/change_state")
get = n.create_client(GetState, name + "/get_state")
def call(cli, req):
    assert cli.wait_for_service(timeout_sec=60.0), cli.srv_name
    for _ in range(4):
        fut = cli.call_async(req)
        rclpy.spin_until_future_complete(n, fut, timeout_sec=30.0)
        if fut.done():
            return fut.result()
        cli.remove_pending_request(fut)
    raise SystemExit(cli.srv_name + " did not answer")
for word in sys.argv[2:]:
    ok = True
    if word != "state":
        tid = getattr(Transition, "TRANSITION_" + word.upper())
        ok = call(change, ChangeState.Request(transition=Transition(id=tid))).success
    label = call(get, GetState.Request()).current_state.label
    print("LIFECYCLE", word, ok, label, flush=True)
"""


def check_rig_lifecycle(day: Day, c: Check) -> None:
    """The managed rig node (`rs_localizer_lifecycle_node` with the rig's parameters):
    configure, activate (through `rs-localizer lifecycle` if the CLI has it, else rclpy's
    lifecycle services; the check says which), `play --lockstep` answered (>= 95 % of the rig
    frames; rig_lockstep judges every one), then deactivate and cleanup, each transition's
    state read back."""
    rig = _rig(day)
    lean = rig.lean()
    helptext = day.run("rs-localizer --help").output
    has_cli = "lifecycle" in re.findall(r"^\s{4}(\w[\w-]*)", helptext, re.M)
    params = lean / "rig_params.yaml"
    cmd = f"rs_localizer_lifecycle_node --ros-args --params-file {params} -r __ns:=/rig"
    day.ran.append(cmd + " &")
    proc = subprocess.Popen(_argv(cmd), cwd=ROOT, env=_env(day.domain), text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)  # fmt: skip
    lines: list[str] = []
    threading.Thread(target=lines.extend, args=(proc.stdout,), daemon=True).start()

    def services(*words) -> list[tuple[str, str, str]]:
        """(transition, succeeded, state label after it) of each word through rclpy's lifecycle
        services (``state``: the state only)."""
        r = subprocess.run([sys.executable, "-c", _LIFECYCLE, "/rig/rs_localizer", *words],
                           cwd=ROOT, env=_env(day.domain), capture_output=True, text=True,
                           timeout=600)  # fmt: skip
        got = re.findall(r"LIFECYCLE (\w+) (\w+) (\w+)", r.stdout)
        if len(got) != len(words):
            raise CheckFailed(f"lifecycle services: {_tail(r.stdout + r.stderr, 300)}")
        return got

    def drive(*words) -> list[tuple[str, str, str]]:
        if not has_cli:
            day.ran.append(f"(rclpy's lifecycle services of /rig/rs_localizer: {' '.join(words)})")
            return services(*words)
        got = []
        for wd in words:
            r = day.run(f"rs-localizer lifecycle /rig/rs_localizer {wd}", 180)
            got.append((wd, str(r.rc == 0), services("state")[0][2]))
        return got

    try:
        t0 = time.perf_counter()
        while not any("unconfigured" in ln for ln in lines):
            if proc.poll() is not None or time.perf_counter() - t0 > 120:
                raise CheckFailed(f"the lifecycle node did not start: {_tail(''.join(lines))}")
            time.sleep(0.2)
        up = drive("configure", "activate")
        r = day.run(f"rs-localizer play {lean} --lockstep --timeout 10", 600)
        m = PLAY_RIG_COUNT.search(r.output)
        down = drive("deactivate", "cleanup")
    finally:
        _stop(proc)
    how = "`rs-localizer lifecycle`" if has_cli else "rclpy's lifecycle services (no CLI command)"
    steps = ", ".join(f"{wd} -> {label}" for wd, _, label in up + down)
    answered = int(m.group(1)) if m else 0
    c.value = f"via {how}: {steps}; play --lockstep {answered}/{RIG_FRAMES} answered"
    c.expect(all(ok == "True" for _, ok, _ in up + down), f"a transition failed: {steps}")
    want = ["inactive", "active", "inactive", "unconfigured"]
    c.expect([label for *_, label in up + down] == want, f"states {steps}")
    c.expect(answered >= 0.95 * RIG_FRAMES, f"{answered} of {RIG_FRAMES} rig frames answered")


def check_rig_view(day: Day, c: Check) -> None:
    """`rs-localizer view --ns /rig` next to the running rig node: a Foxglove WebSocket client
    (as the app) connects, gets the server's info and the node's outputs advertised, and
    receives poses while the bag plays."""
    sys.path.insert(0, str(ROOT / "test"))
    from helpers.foxglove_ws import FoxgloveClient

    rig = _rig(day)
    lean = rig.lean()
    node = rig.node(lean / "rig_params.yaml")[0]
    port = 20000 + random.randint(0, 20000)
    cmd = f"rs-localizer view --ns /rig --port {port} --duration 120"
    day.ran.append(cmd + " &")
    view = subprocess.Popen(_argv(cmd), cwd=ROOT, env=_env(day.domain), text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)  # fmt: skip
    client = None
    try:
        t0 = time.perf_counter()
        while client is None:
            try:
                client = FoxgloveClient(port)
            except OSError:
                if view.poll() is not None or time.perf_counter() - t0 > 60:
                    said = view.stdout.read() if view.poll() is not None else ""
                    raise CheckFailed(f"view does not listen: {_tail(said)}") from None
                time.sleep(0.5)
        client.poll(3.0)
        pose = next((t for t in client.channels if t.endswith("/pose")), None)
        if pose:
            client.subscribe([pose])
        r = day.run(f"rs-localizer play {lean}", 600)
        client.poll(3.0)
        got = len(client.received(pose)) if pose else 0
    finally:
        if client is not None:
            client.close()
        if view.poll() is None:
            view.send_signal(signal.SIGINT)
            try:
                view.wait(15)
            except subprocess.TimeoutExpired:
                view.kill()
        _stop(node)
    c.value = (f"connected ({client.protocol}), {len(client.channels)} channels advertised, "
               f"{got} poses received on {pose}")  # fmt: skip
    c.expect(client.server_info is not None, "no serverInfo from view")
    c.expect(pose is not None, f"no pose channel among {sorted(client.channels)}")
    c.expect(got > 0, "no pose arrived over the WebSocket while the bag played")
    c.expect(r.rc == 0, f"play exit code {r.rc}")


#: name -> (slow, function); in the order of the day
CHECKS = {
    "compile": (True, check_compile),
    "scenes_listed": (False, check_scenes_listed),
    "render": (True, check_render),
    "readout_calibrated": (True, check_readout_calibrated),
    "readout_quiet": (True, check_readout_quiet),
    "readout_in_map": (True, check_readout_in_map),
    "readout_frame_invariant": (True, check_readout_frame_invariant),
    "gravity_frame": (True, check_gravity_frame),
    "replay_truth": (True, check_replay_truth),
    "python_example": (False, check_python_example),
    "export_stamps": (False, check_export_stamps),
    "readout_howto": (False, check_readout_howto),
    "calibrate_errors": (False, check_calibrate_errors),
    "lockstep_ns": (False, check_lockstep_ns),
    "diagnostics": (False, check_diagnostics),
    "viewers": (True, check_viewers),
    "demo_domain": (True, check_demo_domain),
    "demo_figures": (True, check_demo_figures),
}
#: the rig user's day (``--only rig``): name -> (slow, function), in the order of the day
RIG_CHECKS = {
    "rig_render": (True, check_rig_render),
    "rig_calibrate": (True, check_rig_calibrate),
    "rig_lockstep": (True, check_rig_lockstep),
    "rig_realtime": (True, check_rig_realtime),
    "rig_replay_evaluate": (True, check_rig_replay_evaluate),
    "rig_unplugged": (True, check_rig_unplugged),
    "rig_absent": (True, check_rig_absent),
    "rig_no_camera_info": (True, check_rig_no_camera_info),
    "rig_mounting_off": (True, check_rig_mounting_off),
    "rig_lifecycle": (True, check_rig_lifecycle),
    "rig_view": (True, check_rig_view),
}
ALL_CHECKS = {**CHECKS, **RIG_CHECKS}


def run_day(
    names: list[str], skip_slow: bool, work: Path, domain: int, timeout: float
) -> list[Check]:
    """Run the named checks in the day's order, printing each as it ends."""
    day = Day(work, domain, timeout)
    out = []
    for name, (slow, fn) in ALL_CHECKS.items():
        if name not in names:
            continue
        c = Check(name)
        if skip_slow and slow:
            c.verdict, c.value = "SKIP", "slow (--skip-slow)"
        else:
            day.ran = []
            t0 = time.perf_counter()
            try:
                fn(day, c)
            except CheckFailed as e:
                c.fail(str(e))
            except Exception as e:  # a bug of the check itself is a failure too, shown
                c.fail(f"{type(e).__name__}: {e}")
            c.seconds = time.perf_counter() - t0
            c.notes[:0] = [f"$ {cmd}" for cmd in day.ran]
        print(f"{c.verdict:<6} {name}: {c.value}  ({c.seconds:.0f} s)", flush=True)
        for note in c.notes:
            print(f"         {note}", flush=True)
        out.append(c)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog="checks of the marker user's day: " + ", ".join(CHECKS) + "; of the rig user's "
        "day: " + ", ".join(RIG_CHECKS),
    )
    ap.add_argument("--list", action="store_true", help="only list the commands and checks")
    ap.add_argument(
        "--only",
        help="comma-separated pages (docs/tools.md) and checks (gravity_frame, rig_calibrate); "
        "'pages': every page, 'day': every check of the marker user's day, 'rig': of the rig "
        "user's day (default: all three)",
    )
    ap.add_argument(
        "--skip-slow",
        action="store_true",
        help="skip the day's slow checks (compile, the rendered video and its maps, the "
        "viewers, the demo: about 20 min in all)",
    )
    ap.add_argument("--timeout", type=float, default=300.0, help="s per command (300)")
    ap.add_argument(
        "--workdir",
        type=Path,
        default=None,
        help="where the day's video, maps and images go (default: a new temporary folder)",
    )
    args = ap.parse_args(argv)
    wanted = args.only.split(",") if args.only else ["pages", "day", "rig"]
    unknown = [w for w in wanted if w not in ("pages", "day", "rig", *PAGES, *ALL_CHECKS)]
    if unknown:
        ap.error(f"--only: unknown {unknown} (pages: {', '.join(PAGES)}; checks: "
                 f"{', '.join(ALL_CHECKS)})")  # fmt: skip
    pages = PAGES if "pages" in wanted else [w for w in wanted if w in PAGES]
    checks = [
        name
        for name in ALL_CHECKS
        if name in wanted
        or ("day" in wanted and name in CHECKS)
        or ("rig" in wanted and name in RIG_CHECKS)
    ]
    domain = random.randint(1, 101)
    failed = ran = skipped = 0
    for page in pages:
        if args.list:
            for c in shell_commands(page):
                why = why_skipped(c)
                print(f"{page}: {'skip (' + why + ')' if why else 'run '}: {c}")
            continue
        for st in run_page(page, args.timeout, domain):
            if st.skip:
                skipped += 1
                print(f"skip  {page}: {st.command}  ({st.skip})")
                continue
            ran += 1
            ok = not st.problems
            failed += not ok
            print(f"{'ok  ' if ok else 'FAIL'}  {page}: {st.command}  ({st.seconds:.1f} s)")
            for p in st.problems:
                print(f"      {p}")
    if args.list:
        for name in checks:
            slow, fn = ALL_CHECKS[name]
            doc = " ".join(fn.__doc__.split())
            print(f"check {name}{' (slow)' if slow else ''}: {doc}")
        return 0
    if pages:
        print(f"{ran} commands run, {failed} failed, {skipped} skipped", flush=True)
    results = []
    if checks:
        days = [what for what, table in (
            ("the marker user's day (AprilTag room, 640x480 rolling shutter)", CHECKS),
            (f"the rig user's day (3 rolling-shutter cameras, 640x480, {RIG_FRAMES} frames)",
             RIG_CHECKS),
        ) if set(checks) & set(table)]  # fmt: skip
        print("\n" + "; ".join(days) + ":", flush=True)
        work = args.workdir or Path(tempfile.mkdtemp(prefix="rs_newcomer_"))
        work.mkdir(parents=True, exist_ok=True)
        print(f"  work folder {work}, ROS_DOMAIN_ID {domain}", flush=True)
        results = run_day(checks, args.skip_slow, work, domain, args.timeout)
    if results:
        print("\nsummary of the day:")
        for c in results:
            print(f"  {c.verdict:<6} {c.name}: {c.value}")
        tally = {
            v: sum(c.verdict == v for c in results) for v in ("PASS", "FAIL", "REPORT", "SKIP")
        }
        print("  " + ", ".join(f"{n} {v}" for v, n in tally.items()))
    if pages:
        print(f"docs' commands: {ran} run, {failed} failed, {skipped} skipped")
    return 1 if failed or any(c.verdict == "FAIL" for c in results) else 0


if __name__ == "__main__":
    sys.exit(main())
