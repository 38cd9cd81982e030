"""A new user's first hour, scripted: the shell commands of README.md and docs/*.md, run as
written (``rs-localizer`` through this interpreter and this checkout), with their exit codes
and, where the docs quote what a command prints, the figures compared (within 3 %).

    .venv/bin/python tools/newcomer.py [--list] [--only PAGE] [--timeout S]   # or: make newcomer

Commands that install or build (pip, make, colcon, rosdep, apt-get), need a ROS install
(``ros2``), are templates (``BAG``, ``[...]``, ``|``), write into the repository, or take
minutes (benchmarks: ``python -m benchmarks.X``; experiments, map building, rendering,
compiling) are listed as skipped with the reason. The node quick start (``rs_localizer_node``
in one shell, ``play`` in a second one) runs both, the node in the background on a random
ROS_DOMAIN_ID. Exit status 1 when a command fails or a figure is off.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import shlex
import shutil
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

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
    if "rs_localizer_node" in words[0] or "rs_localizer_lifecycle_node" in words[0]:
        return ""  # (run with the play command that follows it)
    if not words[0].endswith("rs-localizer"):
        return f"not an rs-localizer command ({words[0]})"
    sub = words[1] if len(words) > 1 else ""
    if sub in SLOW_COMMANDS:
        return SLOW_COMMANDS[sub]
    if sub in LIVE_COMMANDS:
        return LIVE_COMMANDS[sub]
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
    if words[0].endswith("rs_localizer_node"):
        return [sys.executable, "-m", "rs_localizer.ros.node", *words[1:]]
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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--list", action="store_true", help="only list the commands and verdicts")
    ap.add_argument("--only", help="one page (e.g. docs/tools.md)")
    ap.add_argument("--timeout", type=float, default=300.0, help="s per command (300)")
    args = ap.parse_args(argv)
    pages = [args.only] if args.only else PAGES
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
    if not args.list:
        print(f"{ran} commands run, {failed} failed, {skipped} skipped")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
