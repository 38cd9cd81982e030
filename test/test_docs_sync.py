"""The README documents every failure reason the node can emit, every camera_info rejection
reason, and every node parameter (a reason emitted but not documented is a defect).

Reasons are collected from the sources (the string literals passed to the frame pipeline's
``_Drop`` and ``_reject_camera_info``, the decoders' reason tuples, the estimator's ``_fail``
calls) and compared with the first column of the README's ``| reason |`` tables, both ways.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "rs_localizer"


def _readme_table_names(header: str) -> set:
    """Backticked names in the first column of every README table whose first header cell is
    ``header``."""
    names, inside = set(), False
    for line in (ROOT / "README.md").read_text().splitlines():
        cells = (
            [c.strip() for c in line.strip().strip("|").split("|")]
            if line.startswith("|")
            else None
        )
        if cells is None:
            inside = False
            continue
        if cells[0] == header:
            inside = True
            continue
        if inside and not set(cells[0]) <= set("-: "):
            names |= set(re.findall(r"`([^`]+)`", cells[0]))
    return names


def _literals(path: Path, *functions) -> set:
    src = path.read_text()
    out = set()
    for fn in functions:
        for m in re.finditer(
            rf"{fn}\(\s*\"([a-z_]+)\"(?:\s+if\s+[\w.]+\s+else\s+\"([a-z_]+)\")?", src
        ):
            out |= {g for g in m.groups() if g}
    return out


def _node_reasons() -> set:
    from rs_localizer.estimation import plausibility

    reasons = _literals(PKG / "ros" / "pipeline.py", "_Drop")
    reasons |= _literals(PKG / "estimation" / "estimate.py", "_fail")
    reasons |= {plausibility.IMPLAUSIBLE_MOTION, plausibility.CHEIRALITY}
    src = (PKG / "ros" / "pointcloud.py").read_text()
    reasons |= set(re.findall(r"CloudError\(\s*\"([a-z_]+)\"", src))
    reasons.add("bad_stamp")  # conversions.StampError.reason
    return reasons


def test_every_failure_reason_is_in_the_readme():
    emitted = _node_reasons()
    assert {
        "bad_layout",
        "implausible_motion",
        "cheirality",
        "bad_stamp",
        "no_camera_info",
        "degenerate_geometry",
        "internal_error",
    } <= emitted, emitted  # the scan works
    documented = _readme_table_names("reason")
    assert emitted - documented == set(), f"undocumented failure reasons: {emitted - documented}"
    camera = set(_literals(PKG / "ros" / "pipeline.py", "_reject_camera_info"))
    from rs_localizer.ros import conversions

    camera |= set(conversions.CAMERA_INFO_REASONS)
    doc_camera = _readme_table_names("camera_info rejected")
    assert camera - doc_camera == set(), f"undocumented camera_info reasons: {camera - doc_camera}"
    stale = documented - emitted - camera
    assert stale == set(), f"README reasons nothing emits: {stale}"
    assert doc_camera - camera == set(), doc_camera - camera


def test_every_parameter_is_documented_with_its_default():
    import pytest

    pytest.importorskip("rclpy")
    from rs_localizer.ros.node import PARAMETERS

    documented = _readme_table_names("parameter")
    missing = [p for p in PARAMETERS if p not in documented]
    assert not missing, f"parameters missing from the README tables: {missing}"
    # the default column of one-parameter rows
    checked = 0
    for line in (ROOT / "README.md").read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        names = re.findall(r"`([^`]+)`", cells[0]) if line.startswith("|") else []
        if len(names) != 1 or names[0] not in PARAMETERS or len(cells) < 3:
            continue
        shown = re.findall(r"`([^`]*)`", cells[1])
        default = PARAMETERS[names[0]][0]
        if len(shown) != 1 or isinstance(default, list):
            continue
        text = shown[0]
        if isinstance(default, bool):
            assert text == str(default).lower(), (names[0], text, default)
        elif isinstance(default, (int, float)):
            assert float(text) == default, (names[0], text, default)
        else:
            assert text == (default if default else '""'), (names[0], text, default)
        checked += 1
    assert checked >= 20, checked
    yaml_text = (ROOT / "config" / "rs_localizer.yaml").read_text()
    for p in PARAMETERS:
        leaf = p.split(".")[-1]
        assert re.search(rf"^\s*{re.escape(leaf)}:", yaml_text, re.M), (
            f"{p} missing from config/rs_localizer.yaml"
        )
