"""``python -m benchmarks.bench_rig`` on a few small frames: looser versions of its targets
against the ground truth, and the command's output."""

import numpy as np
import pytest

pytest.importorskip("poselib")

from benchmarks.bench_rig import few_points, main, run, summary


def test_rig_against_single_cameras_and_poselib_on_three_cameras():
    """3 cameras x 120 points, 6 frames turning 1-2 rad/s: every method poses every frame;
    the rig's median rotation and position errors are below 0.8x the best single camera's,
    its rotation error below a fifth of PoseLib's generalized (global-shutter) estimate's, its
    angular velocity error no worse than the best single camera's; the errors are against the
    simulation's truth."""
    s = summary(run(3, 6, 120, seed=1))
    rig, gs = s["rig"], s["poselib"]
    cams = [v for k, v in s.items() if k.startswith("camera ")]
    assert len(cams) == 3
    assert all(v[0] == v[1] == 6 for v in s.values())
    assert rig[2] <= 0.8 * min(c[2] for c in cams)
    assert rig[3] <= 0.8 * min(c[3] for c in cams)
    assert rig[2] <= 0.2 * gs[2]
    assert rig[4] <= min(c[4] for c in cams)
    assert rig[2] < 0.05 and rig[3] < 0.5  # deg, cm


def test_twenty_and_three_points():
    """One camera with 20 points, the other with 3: every rig frame posed, camera 0's median
    pose error from the rig no worse than 1.2x camera 0 alone (the benchmark's target: better)."""
    r = few_points(8, seed=2)
    assert r["posed"] == r["frames"] == 8
    rig, one = np.median(r["rig"], axis=0), np.median(r["alone"], axis=0)
    assert (rig <= 1.2 * one).all(), (rig, one)


def test_bench_rig_prints_the_table_and_targets(capsys):
    main(["--frames", "2", "--points", "60", "--rigs", "3"])
    out = capsys.readouterr().out
    assert "PoseLib generalized GS" in out and "cameras averaged" in out
    assert out.count("PASS") + out.count("FAIL") == 7
