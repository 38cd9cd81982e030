"""The node reference (docs/node.md) documents every failure reason the node can emit, every
camera_info rejection reason, every node parameter with its default and every diagnostics key
(a reason, parameter or key the node has but the page does not is a defect, and the page names
nothing the node does not have). The README's short parameter table shows the same defaults.

Reasons are collected from the sources (the string literals passed to the frame pipeline's
``_Drop`` and ``_reject_camera_info``, the leading underscore optional, in any module of
``ros/``; the decoders' reason tuples; the estimator's ``FAILURE_REASONS``) and
compared with the first column of the page's ``| reason |`` tables, both ways. Diagnostics keys
are read from the status a live node publishes on ``/diagnostics``.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "rs_localizer"
NODE_DOC = ROOT / "docs" / "node.md"
README = ROOT / "README.md"


def _table_names(header: str, path: Path = NODE_DOC) -> set:
    """Backticked names in the first column of every table of ``path`` whose first header cell
    is ``header``."""
    names, inside = set(), False
    for line in path.read_text().splitlines():
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


def _literals(paths, *functions) -> set:
    """First string-literal arguments (``fn("reason")``, ``fn("a" if x else "b")``) of calls of
    ``functions`` (or of the same names without their leading underscore) in ``paths``."""
    out = set()
    for path in [paths] if isinstance(paths, Path) else paths:
        src = path.read_text()
        for fn in functions:
            name = re.escape(fn.lstrip("_"))
            for m in re.finditer(
                rf"(?<![\w.])(?:self\.|\w+\.)?_?{name}\(\s*\"([a-z_]+)\""
                rf"(?:\s+if\s+[\w.]+\s+else\s+\"([a-z_]+)\")?",
                src,
            ):
                out |= {g for g in m.groups() if g}
    return out


def _modules(package: str) -> list:
    return sorted((PKG / package).glob("*.py"))


def _node_reasons() -> set:
    from rs_localizer.estimation import FAILURE_REASONS

    reasons = _literals(_modules("ros"), "_fail", "_Drop", "_Refused", "ImageRejected", "Failed")
    reasons |= set(FAILURE_REASONS)
    from rs_localizer.tracking.sequence import FRONTEND_FAILURES  # (the images' front end)

    reasons |= set(FRONTEND_FAILURES)
    src = (PKG / "ros" / "pointcloud.py").read_text()
    reasons |= set(re.findall(r"CloudError\(\s*\"([a-z_]+)\"", src))
    reasons.add("bad_stamp")  # conversions.StampError.reason
    return reasons


def test_every_failure_reason_is_documented():
    emitted = _node_reasons()
    assert {
        "bad_layout",
        "implausible_motion",
        "cheirality",
        "bad_stamp",
        "no_camera_info",
        "degenerate_geometry",
        "internal_error",
        "bad_image",
        "frontend_too_few_points",
        "too_few_inliers",
    } <= emitted, emitted  # the scan works
    documented = _table_names("reason")
    assert emitted - documented == set(), f"undocumented failure reasons: {emitted - documented}"
    camera = set(_literals(_modules("ros"), "_reject_camera_info"))
    from rs_localizer.ros import conversions

    camera |= set(conversions.CAMERA_INFO_REASONS)
    assert {"bad_intrinsics", "bad_distortion", "bad_roi"} <= camera, camera  # the scan works
    doc_camera = _table_names("camera_info rejected")
    assert camera - doc_camera == set(), f"undocumented camera_info reasons: {camera - doc_camera}"
    stale = documented - emitted - camera
    assert stale == set(), f"docs/node.md reasons nothing emits: {stale}"
    assert doc_camera - camera == set(), doc_camera - camera


def _check_defaults(path: Path, parameters: dict) -> int:
    """The default column of ``path``'s one-parameter table rows equals the node's default;
    returns how many rows it checked."""
    checked = 0
    for line in path.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        names = re.findall(r"`([^`]+)`", cells[0]) if line.startswith("|") else []
        if len(names) != 1 or names[0] not in parameters or len(cells) < 3:
            continue
        shown = re.findall(r"`([^`]*)`", cells[1])
        default = parameters[names[0]][0]
        if len(shown) != 1 or isinstance(default, list):
            continue
        text = shown[0]
        where = (path.name, names[0], text, default)
        if isinstance(default, bool):
            assert text == str(default).lower(), where
        elif isinstance(default, (int, float)):
            assert float(text) == default, where
        else:
            assert text == (default if default else '""'), where
        checked += 1
    return checked


def test_every_parameter_is_documented_with_its_default():
    import pytest

    pytest.importorskip("rclpy")
    from rs_localizer.ros.node import PARAMETERS
    from rs_localizer.ros.visualization import VIZ_PARAMETERS

    documented = _table_names("parameter")
    missing = [p for p in PARAMETERS if p not in documented]
    assert not missing, f"parameters missing from the docs/node.md tables: {missing}"
    viz_missing = [p for p in VIZ_PARAMETERS if p not in documented]
    assert not viz_missing, f"viz parameters missing from docs/node.md: {viz_missing}"
    # ``cameras`` is read by the process runner (ros/runner.py), before the nodes exist
    assert '"cameras"' in (PKG / "ros" / "runner.py").read_text()
    known = set(PARAMETERS) | set(VIZ_PARAMETERS) | {"cameras"}
    stale = documented - known
    assert not stale, f"docs/node.md documents parameters the node does not have: {stale}"
    checked = _check_defaults(NODE_DOC, {**PARAMETERS, **VIZ_PARAMETERS})
    assert checked >= 20 + len(VIZ_PARAMETERS), checked
    # the README's short table: names the node has, with the same defaults
    in_readme = _table_names("parameter", README)
    assert in_readme and in_readme <= set(PARAMETERS), in_readme - set(PARAMETERS)
    assert _check_defaults(README, PARAMETERS) == len(in_readme)
    yaml_text = (ROOT / "config" / "rs_localizer.yaml").read_text()
    for p in PARAMETERS:
        leaf = p.split(".")[-1]
        assert re.search(rf"^\s*{re.escape(leaf)}:", yaml_text, re.M), (
            f"{p} missing from config/rs_localizer.yaml"
        )


def _published_diagnostics_keys(ctx, overrides: dict) -> set:
    """Keys of the first status a node (no warm-up) publishes on /diagnostics."""
    from helpers.ros import diagnostics_in_process

    got = diagnostics_in_process(ctx, "docs_sync", overrides)
    assert got, "no /diagnostics status from the node"
    return {kv.key for kv in got[0].values}


def test_every_diagnostics_key_is_documented(ros_context, tmp_path):
    """Correspondence mode, image mode (ArUco and features front ends) and with the gyro:
    every key the node publishes is in the page's ``| diagnostics key |`` table, and every key
    there is published in one of them (``failed.<reason>``, ``camera_info_rejected.<reason>``,
    ``gyro_missing.<reason>``, ``gyro_rejected.<reason>`` and ``imu_rejected.<reason>`` stand
    for their families)."""
    import numpy as np

    from rs_localizer.maps.features import FeatureMap

    rng = np.random.default_rng(0)
    fmap = FeatureMap(
        rng.normal(size=(20, 3)), rng.random((20, 128), np.float32), np.arange(20), "sift"
    ).save(tmp_path / "features.npz")
    keys = _published_diagnostics_keys(ros_context, {})
    keys |= _published_diagnostics_keys(
        ros_context, {"frontend": "aruco", "frontend_map": "aruco_room"}
    )
    keys |= _published_diagnostics_keys(
        ros_context, {"frontend": "features", "frontend_map": str(fmap)}
    )
    keys |= _published_diagnostics_keys(ros_context, {"imu.enabled": True})
    assert {"frames_received", "track_state", "frontend_ms_median", "imu_rate_hz"} <= keys, keys
    documented = _table_names("diagnostics key")
    families = {d.split("<")[0] for d in documented if "<" in d}
    assert families == {
        "failed.",
        "camera_info_rejected.",
        "gyro_missing.",
        "gyro_rejected.",
        "imu_rejected.",
    }, families
    undocumented = {k for k in keys if k not in documented and not k.startswith(tuple(families))}
    assert not undocumented, f"undocumented diagnostics keys: {sorted(undocumented)}"
    stale = {d for d in documented if "<" not in d} - keys
    assert not stale, f"docs/node.md diagnostics keys the node does not publish: {sorted(stale)}"


def test_parameter_defaults_follow_the_table():
    """docs/node.md's and the README's default columns and config/rs_localizer.yaml's values
    are those of ``rs_localizer.ros.params.PARAMETERS`` (``make params`` rewrites them), and
    the YAML sets every parameter; a wrong default is found and rewritten."""
    from rs_localizer.ros.param_docs import check, sync_table, sync_yaml
    from rs_localizer.ros.params import PARAMETERS

    assert check(ROOT) == []
    wrong = {**PARAMETERS, "ransac.threshold_px": (3.5,), "refine": (False,)}
    yaml_text = (ROOT / "config" / "rs_localizer.yaml").read_text()
    new, changed, missing = sync_yaml(yaml_text, wrong)
    assert [c[0] for c in changed] == ["ransac.threshold_px", "refine"] and not missing
    assert re.search(r"^\s+threshold_px: 3\.5 ", new, re.M)
    assert re.search(r"^\s+refine: false ", new, re.M)
    new, changed = sync_table(NODE_DOC.read_text(), wrong)
    assert {c[0] for c in changed} == {"ransac.threshold_px", "refine"}
    assert "| `ransac.threshold_px` | `3.5` |" in new


def test_the_frame_queue_s_skip_reasons_are_documented():
    """The reasons the frame queue counts a frame ``skipped.<reason>`` (the keys it counts in
    ros/frame_queue.py) are its ``QUEUE_SKIP_REASONS``, and docs/rig_node.md names each as
    ``<camera>.skipped.<reason>`` and lists exactly them as the node's reasons."""
    from rs_localizer.ros.frame_queue import QUEUE_SKIP_REASONS

    counted = set(
        re.findall(r"\"skipped\.([a-z_]+)\"", (PKG / "ros" / "frame_queue.py").read_text())
    )
    assert counted == set(QUEUE_SKIP_REASONS) == {"queue_full", "stopped"}
    doc = (ROOT / "docs" / "rig_node.md").read_text()
    for reason in QUEUE_SKIP_REASONS:
        assert f"`<camera>.skipped.{reason}`" in doc, reason
    (listed,) = re.findall(r"and the node's ((?:`[a-z_]+`(?:, )?)+)\)", doc)
    assert set(re.findall(r"`([a-z_]+)`", listed)) == set(QUEUE_SKIP_REASONS)
