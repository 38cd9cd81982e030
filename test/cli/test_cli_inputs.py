"""Bad arguments and paths given to ``rs-localizer``: each fails before any work (under 5 s),
with exit code 2 and one line on stderr naming what was wrong, never a traceback, and writes
nothing."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers.paths import ROOT

from rs_localizer.cli import main

CAMERA_YAML = (
    "image_width: 320\nimage_height: 240\n"
    "camera_matrix: {rows: 3, cols: 3, data: [260, 0, 160, 0, 260, 120, 0, 0, 1]}\n"
    "distortion_model: plumb_bob\n"
    "distortion_coefficients: {rows: 1, cols: 5, data: [0, 0, 0, 0, 0]}\n"
)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    """A folder with a good bag and the bad inputs the cases below name (relative paths)."""
    d = tmp_path_factory.mktemp("cli_inputs")
    cwd = os.getcwd()
    os.chdir(d)
    try:
        rc = main(["make-bag", "bag", "--frames", "3", "--points", "40", "--landmarks", "400"])
        assert rc == 0
    finally:
        os.chdir(cwd)
    bag = d / "bag"
    (d / "notes.txt").write_text("not a bag\n")
    (d / "a_file").write_text("a file where a directory is expected\n")
    (d / "nometa").mkdir()
    (d / "photos").mkdir()
    (d / "outdir").mkdir()
    (d / "camera.yaml").write_text(CAMERA_YAML)
    (d / "broken.yaml").write_text("markers: [\n  - {id: 1, corners: [\n")
    # a truncated storage file, a corrupt metadata.yaml, a bag without messages
    for name in ("trunc", "corrupt"):
        (d / name).mkdir()
        for f in bag.iterdir():
            (d / name / f.name.replace("bag.", f"{name}.")).write_bytes(f.read_bytes())
        meta = (d / name / "metadata.yaml").read_text().replace("bag.mcap", f"{name}.mcap")
        (d / name / "metadata.yaml").write_text(meta)
    mcap = d / "trunc" / "trunc.mcap"
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    (d / "corrupt" / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  version: [\n")
    from rosbags.rosbag2 import Writer

    from rs_localizer.ros.bags.bag_io import PC2, typestore

    with Writer(d / "empty", version=9) as w:
        w.add_connection("/camera/correspondences", PC2, typestore=typestore())
    return d


def _snapshot(d: Path) -> dict:
    return {
        str(p.relative_to(d)): (p.stat().st_size, p.stat().st_mtime_ns)
        for p in sorted(d.rglob("*"))
    }


_M = ["--marker-size", "0.1"]
_MF = ["--images", "photos", "--camera", "camera.yaml", "-o", "m.npz"]

#: (command line, a word the error line must contain)
CASES = [
    # numbers: nan, inf, negative, zero, out of range
    (["map-markers", "bag", "-o", "m.yaml", *_M, "--readout-time", "nan"], "--readout-time"),
    (["map-markers", "bag", "-o", "m.yaml", "--marker-size", "-1"], "--marker-size"),
    (["map-markers", "bag", "-o", "m.yaml", "--marker-size", "inf"], "--marker-size"),
    (["map-markers", "bag", "-o", "m.yaml", *_M, "--marker-sizes", "3:nan"], "--marker-sizes"),
    (["map-markers", "bag", "-o", "m.yaml", *_M, "--fps", "0"], "--fps"),
    (["map-markers", "bag", "-o", "m.yaml", *_M, "--anchor-pose", *"0000000"], "quaternion"),
    (["map-markers", "bag", "-o", "m.yaml", *_M, "--anchor-pose", *"000000", "nan"], "nan"),
    (["map-features", *_MF, "--max-residual", "nan"], "--max-residual"),
    (["map-features", *_MF, "--scale", "-1"], "--scale"),
    (["map-features", *_MF, "--scale", "nan"], "--scale"),
    (["map-features", *_MF, "--min-track", "0"], "--min-track"),
    (["replay", "bag", "--threshold", "nan"], "--threshold"),
    (["replay", "bag", "--confidence", "2"], "--confidence"),
    (["replay", "bag", "--line-delay", "-1e-5"], "--line-delay"),
    (["replay", "bag", "-p", "ransac.seed"], "NAME:=VALUE"),
    (["play", "bag", "--rate", "-1"], "--rate"),
    (["play", "bag", "--timeout", "nan"], "--timeout"),
    (["calibrate-readout", "bag", "--threshold", "0"], "--threshold"),
    (["make-bag", "new", "--frames", "0"], "--frames"),
    (["make-bag", "new", "--fps", "nan"], "--fps"),
    (["make-bag", "new", "--outliers", "1.5"], "--outliers"),
    (["make-bag", "new", "--drop-frames", "x"], "--drop-frames"),
    (["render-bag", "new", "--frames", "0"], "--frames"),
    (["render-bag", "new", "--fps", "inf"], "--fps"),
    (["export-image", "bag", "x.png", "--index", "-1"], "--index"),
    (["experiments", "--trials", "0", "--out", "exp"], "--trials"),
    (["experiments", "--noise", "nan", "--out", "exp"], "--noise"),
    (["compile", "--jobs", "0"], "--jobs"),
    (["demo", "--timeout", "nan"], "--timeout"),
    # outputs that cannot be written
    (["map-markers", "bag", "-o", "a_file/m.yaml", *_M], "a_file"),
    (["map-markers", "bag", "-o", "outdir", *_M, "--overwrite"], "directory"),
    (["map-markers", "bag", "-o", "m.yaml", *_M, "--report", "a_file"], "a_file"),
    (["map-markers", "bag", "-o", "camera.yaml", *_M], "--overwrite"),
    (["map-features", *_MF[:4], "-o", "a_file/m.npz"], "a_file"),
    (["map-features", *_MF[:4], "-o", "outdir.npz/x/m.npz"], "no directory"),
    (["replay", "bag", "--out", "a_file/out"], "a_file"),
    (["replay", "bag", "--out", "bag"], "--overwrite"),
    (["replay", "bag", "--csv", "outdir"], "directory"),
    (["replay", "bag", "--debug-outputs"], "--out"),
    (["make-bag", "bag"], "--overwrite"),
    (["make-bag", "a_file/new"], "a_file"),
    (["make-bag", "a_file", "--overwrite"], "a_file"),
    (["render-bag", "a_file/new"], "a_file"),
    (["marker-map", "aruco_room", "a_file/m.yaml"], "a_file"),
    (["export-image", "bag", "a_file/x.png"], "a_file"),
    (["export-image", "bag", "x.txt"], ".png"),
    (["experiments", "--out", "a_file/exp"], "a_file"),
    # input files: missing, a directory, not parseable, not what is expected
    (["map-features", *_MF, "--align-markers", "nosuch.yaml"], "nosuch.yaml"),
    (["map-features", *_MF, "--align-markers", "outdir"], "outdir"),
    (["map-features", *_MF, "--align-markers", "broken.yaml"], "broken.yaml"),
    (["map-features", *_MF, "--align-markers", "notes.txt"], "notes.txt"),
    (["map-features", "--images", "photos", "--camera", "nosuch.yaml", "-o", "m.npz"], "nosuch"),
    (["map-features", "--images", "nosuch", "--camera", "camera.yaml", "-o", "m.npz"], "nosuch"),
    (["map-features", "--colmap", "nosuch", "-o", "m.npz"], "nosuch"),
    (["map-markers", "photos", "-o", "m.yaml", *_M], "--camera"),
    (["map-markers", "photos", "-o", "m.yaml", *_M, "--camera", "notes.txt"], "notes.txt"),
    (["replay", "bag", "--params-file", "nosuch.yaml"], "nosuch.yaml"),
    (["replay", "bag", "--params-file", "broken.yaml"], "broken.yaml"),
    (["replay", "bag", "--params-file", "notes.txt"], "notes.txt"),
    (["calibrate-rig", "bag", "--params-file", "nosuch.yaml"], "nosuch.yaml"),
    (["calibrate-rig", "bag", "--params-file", "broken.yaml"], "broken.yaml"),
    (["calibrate-rig", "bag", "--params-file", "notes.txt"], "notes.txt"),
    (["compile", "--params-file", "notes.txt"], "notes.txt"),
    (["replay", "bag", "--landmarks", "nosuch.csv"], "nosuch.csv"),
    (["render-bag", "new", "--scene", "nosuch.yaml"], "nosuch.yaml"),
    (["render-bag", "new", "--feature-map", "nosuch.npz"], "nosuch.npz"),
    (["demo", "--params", "nosuch.yaml"], "nosuch.yaml"),
    (["calibrate-readout", "bag", "--imu-topic", "/nope"], "/nope"),
    (["export-image", "bag", "x.png", "--topic", "/nope"], "/nope"),
    (["export-image", "bag", "x.png"], "no image topic"),
    # bag paths
    *[
        ([cmd, path], word)
        for cmd in ("replay", "play", "calibrate-readout", "export-image")
        for path, word in (
            ("nosuch", "no such bag"),
            ("notes.txt", "not a bag"),
            ("nometa", "no metadata.yaml"),
            ("trunc", "cannot read the bag"),
            ("corrupt", "cannot read the bag"),
            ("empty", "no messages"),
            ("a_file", "not a bag"),
        )
    ],
    (["map-markers", "nosuch", "-o", "m.yaml", *_M], "nosuch"),
    (["map-markers", "notes.txt", "-o", "m.yaml", *_M], "not a bag"),
    (["map-markers", "trunc", "-o", "m.yaml", *_M], "cannot read the bag"),
    (["map-markers", "empty", "-o", "m.yaml", *_M], "no messages"),
    (["map-markers", "bag", "-o", "m.yaml", *_M], "no image topic (sensor_msgs/Image"),
    (["demo", "--bag", "nosuch"], "no such bag"),
]


def _ids(case):
    return " ".join(case[0])


@pytest.mark.parametrize("argv, word", CASES, ids=[_ids(c) for c in CASES])
def test_bad_input_fails_early_in_one_line(argv, word, inputs, monkeypatch, capsys):
    if argv[:1] == ["export-image"] and len(argv) == 2:
        argv = [*argv, "x.png"]
    monkeypatch.chdir(inputs)
    before = _snapshot(inputs)
    t0 = time.perf_counter()
    try:
        rc = main(argv)
    except SystemExit as e:  # (argparse)
        rc = e.code
    seconds = time.perf_counter() - t0
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2, err
    assert len(lines) == 1, err
    assert lines[0].startswith(f"rs-localizer {argv[0]}: error: "), err
    assert "Traceback" not in err
    assert word in lines[0], err
    assert seconds < 5.0, f"{seconds:.1f} s: {err}"
    assert _snapshot(inputs) == before, "the command wrote something"


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write into a read-only directory")
def test_read_only_output_directory(inputs, tmp_path, monkeypatch, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    monkeypatch.chdir(inputs)
    try:
        for argv in (
            ["map-markers", "bag", "-o", str(ro / "m.yaml"), *_M],
            ["map-markers", "bag", "-o", "m.yaml", *_M, "--report", str(ro / "report")],
            ["make-bag", str(ro / "new")],
            ["replay", "bag", "--csv", str(ro / "x.csv")],
        ):
            assert main(argv) == 2
            err = capsys.readouterr().err
            assert "not writable" in err and len(err.splitlines()) == 1, err
        assert not any(ro.iterdir())
    finally:
        ro.chmod(0o700)


def test_replay_of_the_storage_file_uses_the_bag_directory(inputs, monkeypatch, capsys):
    """``replay BAG/BAG.mcap`` reads the bag directory: its sequence.json's RS timing and
    ground truth apply, exactly as for ``replay BAG``."""
    import json

    monkeypatch.chdir(inputs)
    assert main(["replay", "bag", "--json", "--quiet"]) == 0
    whole = json.loads(capsys.readouterr().out)
    assert main(["replay", "bag/bag.mcap", "--json", "--quiet"]) == 0
    file = json.loads(capsys.readouterr().out)
    assert whole["frames"] == 3 and file == whole


def test_unexpected_error_is_one_line_with_a_hint(monkeypatch, capsys):
    from rs_localizer.cli import compile as command

    def boom(args):
        raise RuntimeError("something\nbroke")

    monkeypatch.setattr(command, "run", boom)
    assert main(["compile"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "RuntimeError: something broke" in err and "--debug" in err
    with pytest.raises(RuntimeError):
        main(["compile", "--debug"])


def test_command_line_error_as_a_user_sees_it(inputs):
    """The installed entry point's path: a new interpreter, one line, exit code 2."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run(
        [sys.executable, "-m", "rs_localizer", "replay", "notes.txt"],
        cwd=inputs,
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )
    assert out.returncode == 2
    assert out.stderr.splitlines() == [
        "rs-localizer replay: error: notes.txt: not a bag (expected a ROS 2 bag directory "
        "with metadata.yaml, or its .mcap/.db3 file)"
    ]


def test_help_shows_defaults_once_and_no_markup():
    import argparse

    from rs_localizer.cli import build_parser

    p = build_parser()
    sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
    top = p.format_help()
    assert list(sub.choices)[:3] == ["compile", "demo", "replay"]
    for name, sp in sub.choices.items():
        assert sp.description, name
        assert name in top
        text = sp.format_help()
        for bad in ("(default: None)", "(default: False)", "``", ":func:", ":mod:", ":class:"):
            assert bad not in text, (name, bad)
        for a in sp._actions:
            shown = sp._get_formatter()._expand_help(a) if a.help else ""
            assert not re.search(r"\(default:[^)]*\)\s*\(default:", shown), (name, shown)
    rb = sub.choices["render-bag"].format_help()
    assert "(default: 30)" in " ".join(rb.split())
    cr = " ".join(sub.choices["calibrate-readout"].format_help().split())
    assert "(default: 2.0)" in cr and "(default: r6p_1lin)" in cr


def test_export_image_all_writes_every_image_of_the_bag(tmp_path, capsys):
    """``export-image --all`` on the sample image bag: one PNG per message in bag order, each
    equal to the single-image export of the same index (the topic found without --topic)."""
    import cv2
    import numpy as np

    from rs_localizer.ros.bags.bag_io import bag_topics, iter_messages

    bag = ROOT / "data" / "sample_images"
    if not (bag / "metadata.yaml").exists():
        pytest.skip("no sample image bag")
    topic = "/camera/image_raw"
    assert topic in bag_topics(bag)
    n = sum(1 for _ in iter_messages(bag, {topic}))
    assert main(["export-image", str(bag), str(tmp_path / "all"), "--all", "--quiet"]) == 0
    files = sorted((tmp_path / "all").iterdir())
    assert [f.name for f in files] == [f"{k:06d}.png" for k in range(n)] + ["stamps.csv"]
    assert main(["export-image", str(bag), str(tmp_path / "one.png"), "--index", "7"]) == 0
    assert f"message 7 of {topic}" in capsys.readouterr().out
    np.testing.assert_array_equal(cv2.imread(str(files[7])), cv2.imread(str(tmp_path / "one.png")))
    # into a folder that is not empty: only with --overwrite
    assert main(["export-image", str(bag), str(tmp_path / "all"), "--all"]) == 2
    assert "--overwrite" in capsys.readouterr().err


def test_compile_compiles_what_the_configured_node_and_the_demo_run(tmp_path):
    """``rs-localizer compile`` without arguments: the node's default solver (its parameter
    table, config/rs_localizer.yaml), p3p (the demo's comparison), the tracker, no gyro
    (imu.enabled is off by default); with --params-file: that configuration's solver, tracker
    and gyro."""
    from rs_localizer.cli.args import CliError
    from rs_localizer.cli.compile import compile_targets
    from rs_localizer.ros.params import PARAMETERS

    what = compile_targets()
    assert what["solvers"] == [PARAMETERS["solver"].default, "p3p"]
    assert what["tracking"] is not None and what["gyro"] is False
    assert compile_targets([ROOT / "config" / "rs_localizer.yaml"])["solvers"] == ["r6p_1lin"]
    f = tmp_path / "robot.yaml"
    f.write_text(
        "/**:\n  ros__parameters:\n    solver: r6p\n    imu: {enabled: true}\n"
        "    tracking: {enabled: false}\n"
    )
    what = compile_targets([f])
    assert what["solvers"] == ["r6p"] and what["tracking"] is None and what["gyro"] is True
    assert compile_targets([f], ["p3p"])["solvers"] == ["p3p"]
    f.write_text("/**:\n  ros__parameters:\n    solver: nope\n")
    with pytest.raises(CliError, match="solver"):
        compile_targets([f])
