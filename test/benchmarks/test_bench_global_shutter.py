"""benchmarks/bench_global_shutter.py --rig: a rig of fast-readout cameras posed as a
global-shutter rig."""

import numpy as np

from benchmarks.bench_global_shutter import rig_frames, rig_rows
from rs_localizer.estimation.rig import estimate_rig_pose


def test_the_rig_frames_differ_only_in_their_line_delay():
    """The rows compare like with like: at every line delay the same points, mountings and
    motion (one seed per frame), only the cameras' line delay changed."""
    a, b = rig_frames(0.0, 2), rig_frames(1e-7, 2)
    for (va, ta), (vb, tb) in zip(a, b, strict=True):
        assert np.array_equal(ta.R, tb.R)
        for x, y in zip(va, vb, strict=True):
            assert np.array_equal(x.X, y.X) and np.array_equal(x.mounting.R, y.mounting.R)
            assert x.camera.line_delay == 0.0 and y.camera.line_delay == 1e-7


def test_the_rig_table_meets_its_target_and_says_so(capsys):
    """At 0.1 us per line every rig frame is posed on the global-shutter model (the estimator
    itself, not only the table's summary) and the table prints its target as met."""
    for views, _ in rig_frames(1e-7, 4):
        est = estimate_rig_pose(views)
        assert est.success and est.motion_model == "global_shutter"
    assert rig_rows([1e-7], 4)
    out = capsys.readouterr().out
    assert "rig target up to 2 us/line" in out and "met" in out and "MISSED" not in out
