"""``python -m benchmarks.bench_rig_rendered`` on a few rendered rig frames: the rig against
each camera alone and PoseLib's generalized estimate against the rendered truth, and the
command's output."""

import numpy as np
import pytest

pytest.importorskip("poselib")

from benchmarks.bench_rig_rendered import main, render, run, summary


@pytest.mark.slow  # (renders the rigs)
def test_rendered_rig_against_single_cameras_and_poselib(capsys):
    """3 cameras, 4 rendered rig frames turning ~1.5-2 rad/s: the rig poses every frame, its
    median rotation and position errors (against the renderer's truth) below 0.5x the best
    single camera's and a fifth of PoseLib's generalized (global-shutter) estimate's; the
    printed table and targets."""
    res = run(render(3, 4, 1.5))
    s = summary(res)
    rig, gs = s["rig"], s["poselib"]
    cams = [v for k, v in s.items() if k.startswith("camera ")]
    assert len(cams) == 3 and rig[0] == rig[1] == 4
    assert rig[2] <= 0.5 * min(c[2] for c in cams) and rig[3] <= 0.5 * min(c[3] for c in cams)
    assert rig[2] <= 0.2 * gs[2]
    assert rig[2] < 0.05 and rig[3] < 0.1  # deg, cm
    assert (res["speed"] > 1.0).all() and res["points"].shape == (4, 3)
    assert np.all(res["points"] >= 4)
    main(["--frames", "2", "--rigs", "3"])
    out = capsys.readouterr().out
    assert "PoseLib generalized GS" in out and "cameras averaged" in out
    assert out.count("PASS") + out.count("FAIL") >= 5
