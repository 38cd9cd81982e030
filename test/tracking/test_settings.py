"""The library's settings built from values by field name (tracking/settings.py), against the
settings classes' own constructors and SciPy's quaternion conversion."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rs_localizer.estimation.options import EstimateOptions, RefineOptions
from rs_localizer.frames import Mounting
from rs_localizer.tracking.fusion import FusionOptions
from rs_localizer.tracking.sequence import GyroSettings
from rs_localizer.tracking.settings import gyro_settings, rig_settings, with_fields
from rs_localizer.tracking.tracker import TrackerOptions


def test_with_fields_replaces_nested_fields_and_keeps_the_rest():
    base = EstimateOptions()
    got = with_fields(
        base, {"ransac": {"seed": 3, "threshold_px": 1.5}, "refine": {"enabled": False}}
    )
    want = dataclasses.replace(
        base,
        ransac=dataclasses.replace(base.ransac, seed=3, threshold_px=1.5),
        refine=RefineOptions(enabled=False),
    )
    assert got == want and got.ransac.max_iterations == base.ransac.max_iterations
    t = with_fields(TrackerOptions(), {"max_gap": 0.25, "fusion": {"lag": 3}})
    assert t.max_gap == 0.25 and t.fusion == dataclasses.replace(FusionOptions(), lag=3)


def test_with_fields_refuses_unknown_fields_and_invalid_values():
    with pytest.raises(TypeError):
        with_fields(EstimateOptions(), {"ransac": {"no_such_field": 1}})
    with pytest.raises(ValueError):  # the class's own validation
        with_fields(EstimateOptions(), {"plausibility": {"max_angular_velocity": 0.0}})


def test_gyro_settings_rotation_from_the_quaternion():
    q = Rotation.from_euler("xyz", [0.3, -1.1, 2.0]).as_quat()  # x, y, z, w
    bias = np.array([0.01, -0.02, 0.003])
    g = gyro_settings(list(q), bias, {"gyro_noise": 0.004, "wait": 0.0, "estimate_bias": True})
    assert isinstance(g, GyroSettings)
    np.testing.assert_allclose(g.R_cam_imu, Rotation.from_quat(q).as_matrix(), atol=1e-12)
    np.testing.assert_array_equal(g.gyro_bias, bias)
    assert (g.gyro_noise, g.wait, g.estimate_bias) == (0.004, 0.0, True)
    assert g.max_rate == GyroSettings().max_rate  # (not given: the class's default)
    with pytest.raises(ValueError):
        gyro_settings([0.0, 0.0, 0.0, 0.0], bias, {})


def test_rig_settings_take_the_camera_estimator_and_tracker_options():
    opts = with_fields(EstimateOptions(), {"ransac": {"threshold_px": 1.25, "seed": 7}})
    tr = with_fields(TrackerOptions(), {"gate_px": 12.0, "max_gap": 0.3, "fusion": {"lag": 2}})
    mounts = {"front": Mounting.from_pose(np.eye(3), [0.1, 0.0, 0.0])}
    s = rig_settings(
        mounts, opts, tr, window=0.02, stop_after=0.4, stamp_row=5.0, time_reset_ns=2 * 10**9
    )
    assert list(s.mounts) == ["front"] and s.mounts["front"] is mounts["front"]
    assert s.options is opts and (s.options.ransac.threshold_px, s.options.ransac.seed) == (
        1.25,
        7,
    )
    assert (s.window, s.stop_after, s.stamp_row, s.time_reset_ns) == (0.02, 0.4, 5.0, 2 * 10**9)
    t = s.tracking
    assert (t.gate_px, t.gate_sigmas, t.max_gate_px, t.min_explained_ratio, t.max_gap) == (
        12.0,
        tr.gate_sigmas,
        tr.max_gate_px,
        tr.min_explained_ratio,
        0.3,
    )
    assert t.fusion == tr.fusion
    alone = rig_settings(
        mounts, opts, None, window=0.02, stop_after=0.4, stamp_row=0.0, time_reset_ns=10**9
    )
    assert alone.tracking is None and alone.max_points is None
    capped = rig_settings(
        mounts, opts, None, window=0.02, stop_after=0.4, stamp_row=0.0, time_reset_ns=10**9,
        max_points=300,
    )  # fmt: skip
    assert capped.max_points == 300
    with pytest.raises(ValueError):  # no cameras
        rig_settings({}, opts, tr, window=0.02, stop_after=0.4, stamp_row=0.0, time_reset_ns=1)
