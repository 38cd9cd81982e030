"""tools/newcomer.py (``make newcomer``): it finds the docs' shell commands, runs the quick
ones, and every figure it checks is quoted by its page next to a command the page shows.
Cheap: nothing is run here but the page parsing (``make newcomer`` runs the commands)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _tool():
    spec = importlib.util.spec_from_file_location("newcomer", ROOT / "tools" / "newcomer.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["newcomer"] = mod  # (its dataclasses look their module up)
    spec.loader.exec_module(mod)
    return mod


def test_commands_are_found_and_classified():
    nc = _tool()
    readme = nc.shell_commands("README.md")
    assert "make demo" in readme and "make test" in readme
    node = next(c for c in readme if c.startswith(".venv/bin/rs_localizer_node"))
    play = readme[readme.index(node) + 1]
    assert play == ".venv/bin/rs-localizer play data/sample --lockstep"
    assert nc.why_skipped(node) == "" and nc.why_skipped(play) == ""
    assert nc.why_skipped("make demo") and nc.why_skipped("rs-localizer replay BAG --json")
    assert nc.why_skipped("rs-localizer map-features --images photos/ -o map.npz")
    assert nc.why_skipped(".venv/bin/rs-localizer export-image /tmp/x docs/debug_image.png")
    for page in nc.PAGES:  # every page parses and every command gets a verdict
        for c in nc.shell_commands(page):
            assert isinstance(nc.why_skipped(c), str), c
    assert "-o map.npz" in " ".join(nc.shell_commands("docs/feature_maps.md"))  # (joined \\)


def test_every_checked_figure_is_quoted_next_to_its_command():
    nc = _tool()
    assert nc.FIGURES
    for fig in nc.FIGURES:
        text = (ROOT / fig.page).read_text()
        cmds = nc.shell_commands(fig.page) + nc.INLINE_COMMANDS.get(fig.page, [])
        assert any(fig.command in c and not nc.why_skipped(c) for c in cmds), fig
        quoted = f"{fig.value:g}"
        assert quoted in text or f"{fig.value}" in text, (fig.page, quoted)


def test_the_day_checks_are_listed_and_selectable(capsys):
    nc = _tool()
    assert nc.main(["--list", "--only", "day"]) == 0
    out = capsys.readouterr().out
    for name, (_slow, fn) in nc.CHECKS.items():
        assert f"check {name}" in out and fn.__doc__, name
    assert nc.main(["--list", "--only", "gravity_frame,docs/tools.md"]) == 0
    out = capsys.readouterr().out
    assert "check gravity_frame (slow)" in out and "check replay_truth" not in out
    assert "docs/tools.md: " in out and "README.md: " not in out
    with pytest.raises(SystemExit):
        nc.main(["--only", "no_such_check"])


def test_the_day_reads_what_the_commands_print():
    nc = _tool()
    # the readout line map-markers --calibrate-readout is documented to print
    line = (
        "line delay 61.888 +- 1.479 us/line (readout time 29.706 ms) (calibrated, std): observable"
    )
    m = nc._READOUT_LINE.search(line)
    assert m and m.groups() == ("61.888", "1.479", "observable")
    assert nc._READOUT_LINE.search(line.replace(": observable", ": NOT observable")).group(3) == (
        "NOT observable"
    )
    assert nc._READOUT_LINE.search("line delay 58.60 us, detected corners") is None
    got = nc._diag_values("  frames_received=30 frames_skipped=0\n  latency_ms_median=1.28 x=a")
    assert got == {"frames_received": 30.0, "frames_skipped": 0.0, "latency_ms_median": 1.28}
    # docs/video.md's images-to-poses block is found (check python_example runs it)
    text = (ROOT / "docs" / "video.md").read_text()
    assert "process_image(stamp_ns, image, camera, encoding)" in text


def test_the_day_geometry_against_independent_computations():
    import numpy as np
    from scipy.spatial.transform import Rotation

    nc = _tool()
    rng = np.random.default_rng(0)
    for _ in range(20):
        rot = Rotation.random(random_state=rng)
        q = np.array(nc._quat_from_matrix(rot.as_matrix()))
        assert min(np.abs(q - rot.as_quat()).max(), np.abs(q + rot.as_quat()).max()) < 1e-9
    for R in (np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0])):
        q = nc._quat_from_matrix(R)  # (180 deg turns: the w ~ 0 branch)
        assert np.allclose(Rotation.from_quat(q).as_matrix(), R)
    src = rng.normal(size=(12, 3))
    R0, t0 = Rotation.random(random_state=rng).as_matrix(), np.array([1.0, -2.0, 0.5])
    R, t = nc._rigid_fit(src, src @ R0.T + t0)
    assert np.allclose(R, R0) and np.allclose(t, t0)


def test_the_rig_checks_are_listed_and_selectable(capsys):
    nc = _tool()
    assert nc.RIG_CHECKS and not set(nc.RIG_CHECKS) & set(nc.CHECKS)
    assert nc.main(["--list", "--only", "rig"]) == 0
    out = capsys.readouterr().out
    for name, (_slow, fn) in nc.RIG_CHECKS.items():
        assert f"check {name}" in out and fn.__doc__, name
    assert "check gravity_frame" not in out and "README.md: " not in out
    assert nc.main(["--list", "--only", "rig_calibrate,gravity_frame"]) == 0
    out = capsys.readouterr().out
    assert "check rig_calibrate (slow)" in out and "check gravity_frame (slow)" in out
    assert "check rig_lockstep" not in out
    assert nc.main(["--list"]) == 0  # (everything: the pages, both days)
    out = capsys.readouterr().out
    assert all(f"check {n}" in out for n in (*nc.CHECKS, *nc.RIG_CHECKS))
    # the diagnostics' per-camera accounting, as the rig checks read it
    v = nc._diag_values(
        "  front.received=40 front.solved=30 front.failed=1 front.skipped=8 front.pending=1\n"
        "  left.received=40 left.solved=39 left.failed=0 left.skipped=0 left.pending=0"
    )
    bad = nc._rig_accounting(v, ("front", "left", "right"))
    assert bad == ["left: received 40 != 39 + 0 + 0 + 0", "right: counts not printed"]
    assert nc._diag_words("  right.state=stopped right.camera_info=received") == {
        "right.state": "stopped",
        "right.camera_info": "received",
    }


def test_the_rig_day_helpers_against_independent_computations(tmp_path):
    from scipy.spatial.transform import Rotation

    nc = _tool()
    a = [0.1, 0.2, 0.3, *Rotation.from_euler("xyz", [10, 20, 30], degrees=True).as_quat()]
    turn = Rotation.from_euler("z", 5, degrees=True) * Rotation.from_quat(a[3:])
    b = [0.1, 0.2, 0.304, *turn.as_quat()]
    deg, mm = nc._mounting_error(a, b)
    assert abs(deg - 5.0) < 1e-9 and abs(mm - 4.0) < 1e-9
    # a copy of a bag with some messages left out (the faults' bags), its side files too
    from rs_localizer.ros.bags.bag_io import iter_messages

    src = ROOT / "data" / "sample"
    every = list(iter_messages(src))
    cut = sorted(t for _, _, t, _ in every)[len(every) // 2]
    n = nc._copy_bag(
        src, tmp_path / "cut", lambda topic, t: topic.endswith("camera_info") or t < cut
    )
    kept = list(iter_messages(tmp_path / "cut"))
    want = [m for m in every if m[0].endswith("camera_info") or m[2] < cut]
    assert n == len(kept) == len(want) < len(every)
    assert [(m[0], m[2], m[3]) for m in kept] == [(m[0], m[2], m[3]) for m in want]
    assert (tmp_path / "cut" / "sequence.json").exists()
