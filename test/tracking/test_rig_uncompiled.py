"""RigLocalizer while its kernels compile (its ``implementation`` says ``"numpy"``): each rig
frame posed alone on the NumPy implementation, against the rig's true trajectory, then
tracked once the compiled implementation is ready."""

from __future__ import annotations

import numpy as np
from helpers.rig import T0, assert_balanced, mounts_of

from rs_localizer.geometry import rotation_angle_deg
from rs_localizer.sim.rig_video import default_rig, generate_rig_video, rig_truth
from rs_localizer.tracking.rig import RigCameraFrame, RigLocalizer, RigSettings


def test_rig_frames_alone_on_numpy_then_tracked_once_compiled():
    """3 cameras, 20 % outliers: the first 6 rig frames on ``"numpy"``: each posed within
    0.05 deg and 5 mm of the truth, alone (no path, no fused twist, ``compiled`` False,
    counted ``rig.uncompiled``); then ``"compiled"``: a cold frame and tracked ones, every
    compiled frame's twist fused; the counts balance."""
    cams = default_rig(3)
    frames, _, traj = generate_rig_video(cams, duration=0.4, num_points=120, seed=7)
    by = {c.name: c.camera for c in cams}
    state = {"impl": "numpy"}
    rig = RigLocalizer(RigSettings(mounts_of(cams)), implementation=lambda: state["impl"])
    outs, fused = [], []
    for f in frames:
        for o in rig.add(RigCameraFrame(f.name, f.stamp_ns, by[f.name], f.uv, f.xyz)):
            outs.append(o)
            fused += o.fused
            if len(outs) == 6:
                state["impl"] = "compiled"
    for o in rig.close():
        outs.append(o)
        fused += o.fused
    fused += rig.flush()
    assert len(outs) == 12 and all(o.success for o in outs)
    early, late = outs[:6], outs[6:]
    assert [o.compiled for o in outs] == [False] * 6 + [True] * 6
    assert all(o.path is None and o.estimate.implementation == "numpy" for o in early)
    assert [o.path for o in late] == ["cold"] + ["tracked"] * 5
    assert all(o.estimate.implementation == "compiled" for o in late)
    assert [f.pose.stamp_ns for f in fused] == [o.stamp_ns for o in late]
    assert rig.counts["rig.uncompiled"] == 6
    for o in outs:
        R, p, _, _ = rig_truth(traj, (o.stamp_ns - T0) * 1e-9)
        pose = o.estimate.pose
        assert rotation_angle_deg(pose.orientation, R) < 0.05
        assert np.linalg.norm(pose.position - p) < 0.005
    assert_balanced(rig)
