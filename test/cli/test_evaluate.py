"""``rs-localizer evaluate`` end to end: ``replay --out`` on the sample bag, then evaluate the
output bag against the sample bag's ground truth; its APE is replay's own printed errors; a TUM
copy of the estimates gives the same figures; ``--align`` undoes a rigid change of the map frame;
the plot is a PNG; mistakes are one-line errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

pytest.importorskip("rosbags")

from rs_localizer.cli import main


@pytest.fixture(scope="module")
def replayed(sample_bag, tmp_path_factory):
    """(replay's --json summary, the output bag) of the sample bag."""
    out = tmp_path_factory.mktemp("evaluate") / "out"
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main(["replay", str(sample_bag), "--out", str(out), "--quiet", "--json"]) == 0
    return json.loads(buf.getvalue()), out


def _evaluate(capsys, *argv) -> dict:
    capsys.readouterr()
    assert main(["evaluate", *map(str, argv), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_evaluate_agrees_with_replays_printed_errors(replayed, sample_bag, tmp_path, capsys):
    summary, out = replayed
    png = tmp_path / "eval.png"
    res = _evaluate(capsys, out, "--truth", sample_bag, "--plot", png)
    assert res["matched"] == summary["frames"] == summary["solved"] == 30
    for key in ("rot_deg", "pos_m"):
        for stat in ("median", "mean", "p90", "max"):
            assert res["ape"][key][stat] == pytest.approx(summary[key][stat], rel=1e-6)
    assert res["rpe"]["rot_deg"]["count"] == 29
    cov = res["covariance"]
    assert cov["poses"] == 30 and cov["within_3_sigma"] >= 27  # (the refinement's covariance)
    head = png.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    assert int.from_bytes(head[16:20], "big") >= 800  # (width)


def test_tum_estimates_and_alignment(replayed, sample_bag, tmp_path, capsys):
    _, out = replayed
    tum = tmp_path / "est.tum"
    base = _evaluate(capsys, out, "--truth", sample_bag, "--save-tum", tum)
    from_tum = _evaluate(capsys, tum, "--truth", sample_bag)
    for key in ("rot_deg", "pos_m"):  # (9 decimals in the file)
        assert from_tum["ape"][key]["median"] == pytest.approx(base["ape"][key]["median"], abs=1e-6)
    assert from_tum["covariance"] is None  # (a TUM file states none)
    # the estimates in another map frame: far off as they are; with --align as aligned before
    R = Rotation.from_rotvec([0.1, -0.3, 0.8]).as_matrix()
    t = np.array([2.0, -1.0, 0.3])
    rows = np.loadtxt(tum)
    moved = rows.copy()
    moved[:, 1:4] = rows[:, 1:4] @ R.T + t
    moved[:, 4:] = (Rotation.from_matrix(R) * Rotation.from_quat(rows[:, 4:])).as_quat()
    moved_file = tmp_path / "moved.tum"
    np.savetxt(moved_file, moved, fmt="%.9f")
    far = _evaluate(capsys, moved_file, "--truth", sample_bag)
    assert far["ape"]["pos_m"]["median"] > 1.0
    assert far["rpe"]["pos_m"]["median"] == pytest.approx(base["rpe"]["pos_m"]["median"], abs=1e-6)
    a = _evaluate(capsys, moved_file, "--truth", sample_bag, "--align")
    b = _evaluate(capsys, tum, "--truth", sample_bag, "--align")
    for key in ("rot_deg", "pos_m"):
        assert a["ape"][key]["median"] == pytest.approx(b["ape"][key]["median"], abs=1e-6)
    assert a["alignment"]["angle_deg"] == pytest.approx(
        np.degrees(np.linalg.norm([0.1, -0.3, 0.8])), abs=0.5
    )


def test_evaluate_mistakes_are_one_line_errors(replayed, sample_bag, tmp_path, capsys):
    _, out = replayed
    tum = tmp_path / "e.tum"
    tum.write_text("1.0 0 0 0 0 0 0 1\n")
    cases = [
        ([str(tum)], "needs --truth"),
        ([str(out)], "--truth"),  # (replay's bag has no ground truth)
        ([str(out), "--truth", str(sample_bag), "--topic", "/nope"], "no topic /nope"),
        ([str(out), "--truth", str(tum)], "no estimate has a reference pose"),
        (["--live", "1"], "--live needs --topic"),
        ([], "give the estimates"),
    ]
    for argv, msg in cases:
        capsys.readouterr()
        assert main(["evaluate", *argv]) == 2, argv
        err = capsys.readouterr().err
        assert msg in err and len(err.strip().splitlines()) == 1, err


def test_a_rig_replay_out_bag_evaluated_as_replay_prints_it(tmp_path, capsys):
    """``replay --out`` of a rig bag writes the rig's poses; evaluate's APE medians are the
    medians replay prints for the rig."""
    bag, out = tmp_path / "rig", tmp_path / "out"
    assert main(["make-bag", str(bag), "--rig", "2", "--frames", "8", "--points", "100",
                 "--quiet"]) == 0  # fmt: skip
    capsys.readouterr()
    assert main(["replay", str(bag), "--out", str(out), "--quiet", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    res = _evaluate(capsys, out, "--truth", bag)
    assert res["matched"] == s["solved"] == 8
    assert res["ape"]["rot_deg"]["median"] == pytest.approx(s["rot_deg"]["median"], rel=1e-6)
    assert res["ape"]["pos_m"]["median"] == pytest.approx(s["pos_m"]["median"], rel=1e-6)
    assert res["covariance"]["poses"] == 8
