"""What a new user meets first: ``rs-localizer -h`` of every subcommand, ``make demo ARGS=...``
and the README's library snippet (executed as written)."""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]

#: options whose values are a fixed set: they must list it (argparse ``choices``)
FIXED_SETS = {"solver", "compare", "direction", "storage", "source", "camera", "motion", "frontend"}


def _subparsers():
    from rs_localizer.cli import build_parser

    p = build_parser()
    sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices


def test_every_option_has_help_and_fixed_sets_have_choices():
    from rs_localizer.solvers.registry import SOLVER_NAMES

    missing, no_choices = [], []
    for name, sp in _subparsers().items():
        assert sp.description or sp.format_help()
        for a in sp._actions:
            if isinstance(a, argparse._HelpAction):
                continue
            if not (a.help and a.help.strip() and a.help != argparse.SUPPRESS):
                missing.append(f"{name} {'/'.join(a.option_strings) or a.dest}")
            if a.dest.replace("-", "_") in FIXED_SETS and not a.choices:
                no_choices.append(f"{name} {a.dest}")
    assert not missing, f"options without help: {missing}"
    assert not no_choices, f"options without choices: {no_choices}"
    sps = _subparsers()
    solver = next(a for a in sps["replay"]._actions if a.dest == "solver")
    assert tuple(solver.choices) == SOLVER_NAMES
    text = sps["replay"].format_help()
    assert all(n in text for n in SOLVER_NAMES) and "global shutter" in text
    camera = next(a for a in sps["render-bag"]._actions if a.dest == "camera")
    assert "640x480" in camera.help and "1280x720" in camera.help
    compare = next(a for a in sps["demo"]._actions if a.dest == "compare")
    assert set(compare.choices) == set(SOLVER_NAMES) | {""}
    # defaults are shown in the help text
    assert "(default: r6p_1lin)" in re.sub(r"\s+", " ", text)


def test_make_demo_passes_args():
    if shutil.which("make") is None:
        pytest.skip("no make")
    out = subprocess.run(
        ["make", "-n", "demo", "ARGS=--no-images --summary-only"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    line = next(ln for ln in out.stdout.splitlines() if "rs-localizer demo" in ln)
    assert line.rstrip().endswith("rs-localizer demo --no-images --summary-only"), line


def _readme_snippet() -> str:
    text = (ROOT / "README.md").read_text()
    section = text[text.index("## Library use") :]
    m = re.search(r"```python\n(.*?)```", section, re.S)
    assert m, "no python block in README 'Library use'"
    return m.group(1)


def test_readme_library_snippet_runs(tmp_path, monkeypatch):
    """The snippet as written: it localizes with the camera it builds, and the estimate agrees
    with the synthetic frame's ground truth; it writes the debug image."""
    from rs_localizer.geometry import rotation_angle_deg

    code = _readme_snippet()
    assert "paper_camera" not in code
    monkeypatch.chdir(tmp_path)
    ns = {}
    exec(compile(code, "README.md", "exec"), ns)
    est, frame, camera = ns["est"], ns["frame"], ns["camera"]
    assert est.success, est.failure
    assert est.solver == "r6p_1lin"
    assert rotation_angle_deg(est.pose.orientation, frame.orientation) < 0.1
    assert np.linalg.norm(est.pose.position - frame.position) < 0.03
    assert np.linalg.norm(est.pose.angular_velocity - frame.angular_velocity) < 0.2
    # the frame was generated with the snippet's camera (its size and intrinsics)
    assert camera.width == 1280 and np.allclose(camera.K[0, 0], 1000.0)
    assert frame.uv[:, 0].max() < camera.width and frame.uv[:, 1].max() < camera.height
    import cv2

    img = cv2.imread(str(tmp_path / "debug.png"))
    assert img is not None and img.shape == (720, 1280, 3)
