"""The estimators' options and the camera's line delay refused out of their ranges with a
ValueError naming the option and its range: values that made RANSAC loop forever
(``batch_size=0``), accept anything (``min_inliers=0``, ``confidence=2``) or draw nothing
(``max_iterations=-5``), and line delays of seconds per line."""

from __future__ import annotations

import numpy as np
import pytest

from rs_localizer.camera import MAX_LINE_DELAY, MAX_READOUT_TIME, CameraModel
from rs_localizer.estimation import EstimateOptions, estimate_rs_pose
from rs_localizer.estimation.options import LocalOptimizationOptions, RansacOptions
from rs_localizer.estimation.rig import estimate_rig_pose
from rs_localizer.estimation.view import View
from rs_localizer.frames import Mounting
from rs_localizer.ros.params import PARAMETERS, RIG_CAMERA_PARAMETERS

K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])

BAD_RANSAC = [
    ("batch_size", 0, r"ransac\.batch_size must be an integer >= 1, got 0"),
    ("batch_size", 2.5, r"ransac\.batch_size must be an integer >= 1"),
    ("min_inliers", 0, r"ransac\.min_inliers must be an integer >= 1, got 0"),
    ("confidence", 2.0, r"ransac\.confidence must be in \(0, 1\)"),
    ("confidence", 1.0, r"ransac\.confidence must be in \(0, 1\)"),
    ("confidence", 0.0, r"ransac\.confidence must be in \(0, 1\)"),
    ("confidence", float("nan"), r"ransac\.confidence must be in \(0, 1\)"),
    ("max_iterations", -5, r"ransac\.max_iterations must be an integer >= 1, got -5"),
    ("max_iterations", True, r"ransac\.max_iterations must be an integer >= 1"),
    ("min_iterations", -1, r"ransac\.min_iterations must be an integer >= 0"),
    ("threshold_px", 0.0, r"ransac\.threshold_px must be a finite number > 0"),
    ("threshold_px", float("inf"), r"ransac\.threshold_px must be a finite number > 0"),
    ("seed", -1, r"ransac\.seed must be an integer >= 0"),
    ("prosac_growth", 0, r"ransac\.prosac_growth must be an integer >= 1"),
    ("pretest_points", -3, r"ransac\.pretest_points must be an integer >= 0"),
    ("solver_iterations", 0, r"ransac\.solver_iterations must be an integer >= 1"),
]


@pytest.mark.parametrize("name, value, message", BAD_RANSAC)
def test_ransac_options_out_of_range_are_refused(name, value, message):
    with pytest.raises(ValueError, match=message):
        RansacOptions(**{name: value})


def test_ransac_options_in_range_are_taken():
    """The edges of each range, NumPy integers and the documented None values."""
    o = RansacOptions(
        batch_size=1,
        min_inliers=1,
        confidence=0.5,
        max_iterations=np.int64(1),
        min_iterations=0,
        seed=0,
        pretest_points=0,
        solver_iterations=None,
    )
    assert o.max_iterations == 1 and o.batch_size == 1
    RansacOptions(solver_iterations=1, confidence=0.999999999, threshold_px=1e-3)


@pytest.mark.parametrize(
    "name, value, message",
    [
        ("steps", -1, r"local_optimization\.steps must be an integer >= 0"),
        ("refine_iterations", 1.5, r"local_optimization\.refine_iterations must be an integer"),
        ("max_points", 0, r"local_optimization\.max_points must be an integer >= 1"),
    ],
)
def test_local_optimization_options_out_of_range_are_refused(name, value, message):
    with pytest.raises(ValueError, match=message):
        LocalOptimizationOptions(**{name: value})
    LocalOptimizationOptions(steps=0, refine_iterations=0, max_points=1)  # (no LO: allowed)


def _rig_views():
    """Two cameras of a rig seeing 30 points each (the checks come before any work)."""
    rng = np.random.default_rng(0)
    cam = CameraModel(K=K, line_delay=30e-6)
    X = rng.uniform(-1, 1, (30, 3)) + [0, 0, 5]
    uv = X[:, :2] / X[:, 2:] * 500 + [320, 240]
    R0, R1 = np.eye(3), np.diag([-1.0, 1.0, -1.0])
    return [
        View(uv, X, cam, Mounting(R0, np.zeros(3))),
        View(uv, X, cam, Mounting(R1, np.zeros(3))),
    ]


@pytest.mark.parametrize("options", [RansacOptions(), {"threshold_px": 2.0}, 2.0])
def test_estimate_rig_pose_takes_the_camera_options_only(options):
    """The rig takes the single camera's EstimateOptions, whose constructors check every
    value (``batch_size=0`` made the rig's own RANSAC loop forever); anything else is
    refused before any work, naming the type."""
    with pytest.raises(ValueError, match=r"estimate_rig_pose: options must be an EstimateOptions"):
        estimate_rig_pose(_rig_views(), options)
    with pytest.raises(ValueError, match=r"ransac\.batch_size must be an integer >= 1, got 0"):
        estimate_rig_pose(_rig_views(), EstimateOptions(ransac=RansacOptions(batch_size=0)))


@pytest.mark.parametrize("options", [RansacOptions(), {"threshold_px": 2.0}, 2.0])
def test_estimate_rs_pose_takes_estimate_options_only(options):
    """A camera's estimator refuses what is not an EstimateOptions, and a gyro that is not a
    GyroMeasurement, with the rig's messages (the two estimators' one input check): before,
    a dict of options failed on an attribute deep in the frame's preparation."""
    from rs_localizer.estimation.gyro import GyroMeasurement

    cam = CameraModel(K=K, line_delay=30e-6)
    with pytest.raises(ValueError, match=r"estimate_rs_pose: options must be an EstimateOptions"):
        estimate_rs_pose(np.zeros((10, 2)), np.zeros((10, 3)), cam, options=options)
    for who, call in (
        ("estimate_rs_pose", lambda g: estimate_rs_pose(np.zeros((10, 2)), np.zeros((10, 3)),
                                                        cam, gyro=g)),
        ("estimate_rig_pose", lambda g: estimate_rig_pose(_rig_views(), gyro=g)),
    ):  # fmt: skip
        with pytest.raises(ValueError, match=rf"{who}: gyro must be a GyroMeasurement"):
            call(np.zeros(3))
    ok = GyroMeasurement(np.zeros(3), np.eye(3) * 1e-4)  # (a GyroMeasurement is taken)
    assert estimate_rs_pose(np.zeros((10, 2)), np.zeros((10, 3)), cam, gyro=ok).failure


def test_estimate_rs_pose_takes_a_bare_initial_model():
    """A bare model ``(R, C, w, t)`` as a camera's ``initial_model`` is an InitialModel with
    the default gate, as the rig's is: the same estimate as the InitialModel of it."""
    from rs_localizer.estimation import InitialModel
    from rs_localizer.sim.synthetic import make_frame, paper_camera

    f, cam = make_frame(4, 60, noise_px=0.5), paper_camera()
    model = (f.R, f.C, f.w, f.t)
    bare = estimate_rs_pose(f.points_px, f.X, cam, initial_model=model)
    wrapped = estimate_rs_pose(f.points_px, f.X, cam, initial_model=InitialModel(model))
    assert bare.success and bare.initial_used
    for a, b in zip(bare.model, wrapped.model, strict=True):
        np.testing.assert_array_equal(a, b)


def test_estimate_rs_pose_refuses_options_before_any_work():
    """The options are checked where they are built, so estimate_rs_pose never gets bad
    ones: ``dataclasses.replace`` runs the checks too."""
    import dataclasses

    with pytest.raises(ValueError, match=r"ransac\.batch_size"):
        dataclasses.replace(EstimateOptions().ransac, batch_size=0)
    with pytest.raises(ValueError, match=r"ransac\.confidence"):
        estimate_rs_pose(
            np.zeros((10, 2)),
            np.zeros((10, 3)),
            CameraModel(K=K, line_delay=30e-6),
            options=EstimateOptions(ransac=RansacOptions(confidence=2.0)),
        )


def test_line_delay_within_physical_bounds():
    """A line delay of seconds per line is refused (it was taken and published with a wrong
    angular velocity); the documented limits are the node's parameter ranges."""
    for bad in (1.0, 100.0, -1e-6, float("nan"), float("inf"), MAX_LINE_DELAY * 1.01):
        with pytest.raises(ValueError, match=r"line_delay must be in \[0, 0\.01\] s/line"):
            CameraModel(K=K, line_delay=bad)
    assert CameraModel(K=K, line_delay=MAX_LINE_DELAY).line_delay == MAX_LINE_DELAY
    for bad in (1.5, 100.0, -0.1, float("nan")):
        with pytest.raises(ValueError, match=r"readout_time must be in \[0, 1\] s"):
            CameraModel.from_readout_time(K, bad, 640, 480)
    cam = CameraModel.from_readout_time(K, MAX_READOUT_TIME, 640, 480)
    assert cam.readout_time == pytest.approx(1.0)
    # the node's ranges are the same limits
    assert PARAMETERS["rs.line_delay"].range.to_value == MAX_LINE_DELAY
    assert PARAMETERS["rs.readout_time"].range.to_value == MAX_READOUT_TIME
    assert RIG_CAMERA_PARAMETERS["line_delay"].range.to_value == MAX_LINE_DELAY
    assert RIG_CAMERA_PARAMETERS["readout_time"].range.to_value == MAX_READOUT_TIME


def test_rig_config_refuses_a_line_delay_of_seconds():
    """A rig camera's own line delay or readout time above the limits (a parameter file read
    without ROS's range check) stops the configuration, naming the camera."""
    from rs_localizer.ros.config import build_config
    from rs_localizer.ros.params import RIG_PARAMETERS, ConfigError, default_values

    values = {**default_values(), **{k: v.default for k, v in RIG_PARAMETERS.items()}}
    values["rig.cameras"] = ["a"]
    cam = {k: p.default for k, p in RIG_CAMERA_PARAMETERS.items()}
    cam["mounting"] = [0, 0, 0, 0, 0, 0, 1.0]
    assert build_config(values, {"a": cam}).cameras[0].line_delay == values["rs.line_delay"]
    with pytest.raises(ConfigError, match=r"rig\.a\.line_delay must be at most 0\.01 s"):
        build_config(values, {"a": {**cam, "line_delay": 1.0}})
    with pytest.raises(ConfigError, match=r"rig\.a\.readout_time must be at most 1 s"):
        build_config(values, {"a": {**cam, "readout_time": 100.0}})
