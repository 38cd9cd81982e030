"""The simulated rig (rs_localizer.sim.synthetic.make_rig, rig_frame): its layout, timing and frames
against the independent geometry of each camera."""

import numpy as np
import pytest

from rs_localizer.sim.synthetic import LAYOUTS, make_rig, rig_frame, rig_motion


@pytest.mark.parametrize("m", [2, 3, 4])
def test_layout_timing_and_exact_projection(m):
    """Cameras look along their layout's yaw (within the tilt), sit 5-20 cm off the origin,
    have different readout directions, stamps within 10 ms; the inlier pixels are the camera's
    projection at the rig's pose at their own capture time, to the noise."""
    rng = np.random.default_rng(m)
    rig = make_rig(m, rng)
    assert [k.name for k in rig.cameras] == [n for n, _ in LAYOUTS[m]]
    stamps = [k.stamp_offset for k in rig.cameras]
    assert max(stamps) - min(stamps) <= 0.01
    assert len({k.camera.readout for k in rig.cameras}) == m
    for k, (_, yaw) in zip(rig.cameras, LAYOUTS[m], strict=True):
        axis = k.mounting.R.T @ [0, 0, 1.0]  # the optical axis in the rig frame
        assert np.degrees(np.arccos(axis @ [np.sin(yaw), 0, np.cos(yaw)])) < 25
        assert 0.05 <= np.linalg.norm(k.centre) <= 0.2
    truth = rig_motion(rng, 2.0, 1.0)
    assert np.isclose(np.linalg.norm(truth.w), 2.0) and np.isclose(np.linalg.norm(truth.t), 1.0)
    f = rig_frame(rig, truth, [50] * m, rng, noise_px=0.0, outliers=0.3)
    R, C, w, t = truth
    for c, (v, k) in enumerate(zip(f.views, rig.cameras, strict=True)):
        assert 0 < f.outliers[c].sum() < 50
        good = ~f.outliers[c]
        cam = k.camera
        # independent check: the rig at the capture time of each pixel's own line
        x, r, _ = cam.normalize(v.uv[good])
        tau = k.stamp_offset + (r - cam.r0) * cam.seconds_per_unit_r
        for i, X in enumerate(v.X[good]):
            th = tau[i] * w
            a = np.linalg.norm(th)
            K = np.array([[0, -th[2], th[1]], [th[2], 0, -th[0]], [-th[1], th[0], 0]]) / a
            E = np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K
            p = k.mounting.R @ (E @ R @ X + C + tau[i] * t) + k.mounting.c
            assert np.allclose(p[:2] / p[2], x[i], atol=1e-7)
