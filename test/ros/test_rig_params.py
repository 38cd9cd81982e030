"""The rig mode's parameters without ROS: documented in docs/rig_node.md with their defaults,
the page's example parameter file gives the mountings of the simulated rig, and the errors
name the camera."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from rs_localizer.ros.config import build_config
from rs_localizer.ros.param_files import read_params_file
from rs_localizer.ros.params import (
    RIG_CAMERA_PARAMETERS,
    RIG_PARAMETERS,
    ConfigError,
    default_values,
)
from rs_localizer.sim.trajectory import default_rig

DOC = Path(__file__).resolve().parents[2] / "docs" / "rig_node.md"


def _rows() -> dict:
    rows = {}
    for line in DOC.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        names = re.findall(r"`([^`]+)`", cells[0]) if line.startswith("|") else []
        if len(names) == 1 and names[0].startswith("rig."):
            rows[names[0]] = cells[1]
    return rows


def test_every_rig_parameter_is_documented_with_its_default():
    rows = _rows()
    expected = set(RIG_PARAMETERS) | {f"rig.<camera>.{k}" for k in RIG_CAMERA_PARAMETERS}
    assert set(rows) == expected, set(rows) ^ expected
    for name, par in {
        **RIG_PARAMETERS,
        **{f"rig.<camera>.{k}": v for k, v in RIG_CAMERA_PARAMETERS.items()},
    }.items():
        shown = re.findall(r"`([^`]*)`", rows[name])
        if name.endswith(".mounting"):
            assert "required" in rows[name]
        elif name.endswith(".mounting_covariance"):
            assert par.default == [0.0] * 36 and rows[name] == "36 zeros", name
        elif isinstance(par.default, list):
            assert shown == ["[]"], name
        elif isinstance(par.default, float):
            assert float(shown[0]) == par.default, name
        else:
            assert shown[0] == (par.default or '""'), name


def _values(tree: dict) -> tuple[dict, dict]:
    values = default_values()
    values.update({k: v.default for k, v in RIG_PARAMETERS.items()})
    values.update({k: v for k, v in tree.items() if k in values})
    cams = {}
    for n in values["rig.cameras"]:
        cams[n] = {k: tree.get(f"rig.{n}.{k}", p.default) for k, p in RIG_CAMERA_PARAMETERS.items()}
        cams[n]["mounting"] = tree.get(f"rig.{n}.mounting")
    return values, cams


def test_the_pages_example_gives_the_simulated_rigs_mountings(tmp_path):
    text = DOC.read_text().split("```yaml\n")[1].split("```")[0]
    (tmp_path / "rig.yaml").write_text(text)
    cfg = build_config(*_values(read_params_file(tmp_path / "rig.yaml")))
    assert cfg.base_frame == "base_link" and cfg.settings.window == 0.015
    for c, sim in zip(cfg.cameras, default_rig(3), strict=True):
        assert c.name == sim.name and c.direction == sim.camera.readout
        assert c.line_delay == pytest.approx(sim.camera.line_delay)
        assert np.allclose(c.mount.R, sim.mounting.R, atol=1e-6)
        assert np.allclose(c.mount.c, sim.mounting.c, atol=1e-6)


def test_errors_name_the_camera():
    good = {"rig.cameras": ["a", "b"], "rig.a.mounting": [0, 0, 0, 0, 0, 0, 1.0]}
    with pytest.raises(ConfigError, match="rig camera 'b' has no mounting"):
        build_config(*_values(good))
    with pytest.raises(ConfigError, match=r"rig\.b\.mounting must be 7"):
        build_config(*_values({**good, "rig.b.mounting": [1.0, 2.0]}))
    with pytest.raises(ConfigError, match=r"rig\.b\.direction"):
        bad = {**good, "rig.b.mounting": [0, 0, 0, 0, 0, 0, 1.0], "rig.b.direction": "sideways"}
        build_config(*_values(bad))
    with pytest.raises(ConfigError, match=r"rig\.a\.mounting_covariance must be 36"):
        build_config(*_values({**good, "rig.a.mounting_covariance": [1.0] * 6}))
    with pytest.raises(ConfigError, match="positive semi-definite"):
        build_config(*_values({**good, "rig.a.mounting_covariance": [-1.0] * 36}))
    with pytest.raises(ConfigError, match="listed twice"):
        build_config(*_values({**good, "rig.cameras": ["a", "a"]}))
    with pytest.raises(ConfigError, match="needs camera names"):
        build_config(*_values({"rig.cameras": []}))


def test_a_cameras_time_offset_reaches_the_rig():
    """rig.<camera>.time_offset (s, default 0) becomes the rig's ``time_offsets`` entry; a
    value beyond 1 s or not a number is refused naming the parameter."""
    one = {"rig.cameras": ["a", "b"], "rig.a.mounting": [0, 0, 0, 0, 0, 0, 1.0],
           "rig.b.mounting": [0.1, 0, 0, 0, 0, 0, 1.0]}  # fmt: skip
    assert build_config(*_values(one)).settings.time_offsets == {}
    cfg = build_config(*_values({**one, "rig.b.time_offset": -0.0125}))
    assert cfg.settings.time_offsets == {"b": -0.0125}
    assert cfg.settings.reference_ns("b", 10**9, None) == 10**9 - 12_500_000
    with pytest.raises(ConfigError, match=r"rig\.b\.time_offset must be within 1 s"):
        build_config(*_values({**one, "rig.b.time_offset": 1.5}))
    with pytest.raises(ConfigError, match=r"rig\.a\.time_offset must be a number"):
        build_config(*_values({**one, "rig.a.time_offset": "late"}))


@pytest.mark.parametrize(
    "written, frame",
    [(' " robot "', "robot"), (' ""', "base_link"), (" '  '", "base_link"), ("", "base_link"),
     (" ~", "base_link")],
)  # fmt: skip
def test_a_rigs_base_frame_is_base_link_when_empty_or_null(tmp_path, written, frame):
    """A rig's frame is its parameter file's ``base_frame`` stripped of spaces; empty, null
    (``base_frame:`` with no value) or missing: ``base_link``, in the node's configuration
    and in what replay and calibrate-rig read (the one rule, ``rig_base_frame``)."""
    from rs_localizer.ros.bags.bag_frames import rig_parameter_values
    from rs_localizer.ros.config import rig_base_frame

    f = tmp_path / "rig.yaml"
    f.write_text(
        "/**/rs_localizer:\n  ros__parameters:\n    rig:\n      cameras: [a]\n"
        f"      a: {{mounting: [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]}}\n    base_frame:{written}\n"
    )
    values, cams = rig_parameter_values(None, [f])
    assert build_config(values, cams).base_frame == frame
    assert rig_base_frame(values) == frame
    assert rig_base_frame({}) == "base_link"


@pytest.mark.parametrize("written", ["", " ~", ' ""', " '  '"])
def test_a_single_cameras_base_frame_follows_the_rigs_rule(tmp_path, written):
    """A single camera's ``base_frame`` is read by the rig's rule (``rig_base_frame``): stripped
    of spaces, empty when empty, null (``base_frame:`` with no value) or missing, where the
    camera's empty value means no base frame (its optical frame, no ``camera_to_base``
    mounting), the rig's ``base_link``; the same file's ``base_frame`` set: both use it."""
    from rs_localizer.ros.bags.bag_frames import rig_parameter_values
    from rs_localizer.ros.param_files import parameter_values

    f = tmp_path / "camera.yaml"
    f.write_text(f"/**/rs_localizer:\n  ros__parameters:\n    base_frame:{written}\n")
    cfg = build_config(parameter_values([f])[0])
    assert cfg.base_frame == "" and cfg.camera.mount is None
    cfg = build_config({**default_values(), "base_frame": None})
    assert cfg.base_frame == "" and cfg.camera.mount is None
    rig = {"rig.cameras": ["a"], "rig.a.mounting": [0.0] * 6 + [1.0]}
    assert build_config(*rig_parameter_values(None, [f], rig)).base_frame == "base_link"
    f.write_text("/**/rs_localizer:\n  ros__parameters:\n    base_frame: ' robot '\n")
    cfg = build_config(parameter_values([f])[0])
    assert cfg.base_frame == "robot" and cfg.camera.mount is not None
    assert build_config(*rig_parameter_values(None, [f], rig)).base_frame == "robot"


@pytest.mark.parametrize(
    "name, value, message",
    [("ransac.confidence", "high", "must be of type float"),
     ("ransac.seed", 1.5, "must be of type int"),
     ("ransac.max_iterations", 100.0, "must be of type int"),
     ("max_points", "many", "must be of type int"),
     ("ransac.confidence", 2.0, "is outside")],
)  # fmt: skip
def test_a_rigs_shared_parameters_are_checked_as_a_cameras(tmp_path, name, value, message):
    """A node parameter of the wrong type or outside its range in a rig's parameter file (or
    override) is refused with the message a single camera's gets, naming the parameter, by
    every reader of a rig's parameters (replay, calibrate-rig, compile, play): never taken
    as another type (a seed of 1.5 as 1) nor refused by what reads it later."""
    from rs_localizer.ros.bags.bag_frames import rig_parameter_values
    from rs_localizer.ros.param_files import parameter_values
    from rs_localizer.ros.params import ConfigError

    with pytest.raises(ConfigError) as camera:
        parameter_values([], {name: value})
    assert message in str(camera.value) and repr(name) in str(camera.value)
    rig = {"rig.cameras": ["a"], "rig.a.mounting": [0.0] * 6 + [1.0]}
    with pytest.raises(ConfigError) as given:
        rig_parameter_values(None, [], {**rig, name: value})
    assert str(given.value) == str(camera.value)
    f = tmp_path / "rig.yaml"
    f.write_text(
        "/**/rs_localizer:\n  ros__parameters:\n    rig:\n      cameras: [a]\n"
        f"      a: {{mounting: [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]}}\n    {name}: {value!r}\n"
    )
    with pytest.raises(ConfigError) as written:
        rig_parameter_values(None, [f])
    assert str(written.value) == str(camera.value)


def test_a_single_camera_is_a_rig_of_one_camera_named_empty():
    """Without ``rig.cameras`` the configuration holds one camera named "", built as a rig's
    cameras are: its ``camera_to_base.*`` pose in ``base_frame`` is the mounting a rig camera
    of the same ``rig.<camera>.mounting`` numbers gets, its timing the ``rs.*`` one a rig
    camera without its own takes; the camera model of a camera_info is the same. Without
    ``base_frame`` it has no mounting; a rig camera has no fallback model nor frame id."""
    from types import SimpleNamespace

    pose = [0.1, -0.2, 0.3, 0.5, -0.5, 0.5, -0.5]
    timing = {"rs.line_delay": 2e-5, "rs.direction": "left_to_right", "rs.reference_row": 100.0}
    single = build_config({**default_values(), **timing, "base_frame": "robot",
                           "camera_frame": "cam", "camera_to_base.translation": pose[:3],
                           "camera_to_base.rotation": pose[3:]})  # fmt: skip
    rig = build_config(*_values({**timing, "rig.cameras": ["a"], "rig.a.mounting": pose}))
    (cam,) = single.cameras
    assert cam.name == "" and single.camera is cam and single.base_frame == "robot"
    assert single.settings is None and cam.frame == "cam" and cam.fallback is None
    (a,) = rig.cameras
    assert a.name == "a" and a.frame == "" and a.fallback is None
    assert np.allclose(cam.mount.R, a.mount.R, atol=1e-12)
    assert np.allclose(cam.mount.position, pose[:3]) and np.allclose(a.mount.position, pose[:3])
    for k in ("line_delay", "readout_time", "direction", "reference_row"):
        assert getattr(cam, k) == getattr(a, k), k
    assert (cam.line_delay, cam.direction, cam.reference_row) == (2e-5, "left_to_right", 100.0)
    info = SimpleNamespace(k=[500.0, 0, 320, 0, 500, 240, 0, 0, 1], d=[0.0] * 5, width=640,
                           height=480, distortion_model="plumb_bob")  # fmt: skip
    m1, m2 = cam.camera_from_info(info), a.camera_from_info(info)
    assert np.array_equal(m1.K, m2.K) and m1.line_delay == m2.line_delay == 2e-5
    assert build_config(default_values()).camera.mount is None


def test_max_points_is_the_rigs_one_cap():
    """The one ``max_points`` parameter sets the rig's cap on its cameras' image rows
    (``LocalizerSettings.max_points``), 5000 by default; below what a pose needs it is refused."""
    one = {"rig.cameras": ["a"], "rig.a.mounting": [0, 0, 0, 0, 0, 0, 1.0]}
    assert build_config(*_values(one)).settings.max_points == default_values()["max_points"]
    assert build_config(*_values({**one, "max_points": 77})).settings.max_points == 77
    with pytest.raises(ConfigError, match="max_points 3 is below"):
        build_config(*_values({**one, "max_points": 3}))


def test_a_mounting_covariance_in_ros_order_is_the_mountings():
    """rig.<camera>.mounting_covariance (x, y, z, rot x, rot y, rot z) becomes the mounting's
    covariance over (rotation, position); all zero (the default): none."""
    cov = np.diag([1e-6, 2e-6, 3e-6, 1e-8, 2e-8, 3e-8])
    cov[0, 3] = cov[3, 0] = 1e-7
    tree = {
        "rig.cameras": ["a", "b"],
        "rig.a.mounting": [0, 0, 0, 0, 0, 0, 1.0],
        "rig.b.mounting": [0.1, 0, 0, 0, 0, 0, 1.0],
        "rig.b.mounting_covariance": [float(x) for x in cov.ravel()],
    }
    a, b = build_config(*_values(tree)).cameras
    assert a.mount.covariance is None
    P = [3, 4, 5, 0, 1, 2]
    assert np.array_equal(b.mount.covariance, cov[np.ix_(P, P)])
    assert b.mount.covariance[0, 0] == 1e-8 and b.mount.covariance[3, 3] == 1e-6


def test_a_time_offset_std_is_the_mountings():
    """rig.<camera>.time_offset_std (s) becomes the mounting's time_offset_std; 0 (the
    default): none; negative or not a number: an error naming the parameter."""
    tree = {
        "rig.cameras": ["a", "b"],
        "rig.a.mounting": [0, 0, 0, 0, 0, 0, 1.0],
        "rig.b.mounting": [0.1, 0, 0, 0, 0, 0, 1.0],
        "rig.b.time_offset": -0.004,
        "rig.b.time_offset_std": 0.002,
    }
    a, b = build_config(*_values(tree)).cameras
    assert a.mount.time_offset_std == 0.0 and b.mount.time_offset_std == 0.002
    assert b.time_offset == -0.004
    for bad in (-0.001, "x"):
        with pytest.raises(ConfigError, match=r"rig\.b\.time_offset_std must be"):
            build_config(*_values({**tree, "rig.b.time_offset_std": bad}))


@pytest.mark.parametrize(
    "cameras, error",
    [
        ("front", r"rig\.cameras must be a list of camera names: write \[front\], not front"),
        ([1, 2], r"rig\.cameras: camera name 1 is not valid in a topic name"),
        (["front cam"], r"camera name 'front cam' is not valid in a topic name"),
        (["1cam"], r"camera name '1cam' is not valid in a topic name"),
        (["front-cam"], r"camera name 'front-cam' is not valid in a topic name"),
        (["front", "~left"], r"camera name '~left' is not valid"),
    ],
)
def test_camera_names_must_be_a_list_of_topic_name_tokens(cameras, error):
    """Every name the rig refuses is refused by ROS as a topic name token too (checked with
    rclpy's own validator when it is there); one line names the parameter and the fix."""
    with pytest.raises(ConfigError, match=error) as e:
        build_config(*_values({"rig.cameras": cameras, "rig.front.mounting": [0.0] * 6 + [1.0]}))
    assert "\n" not in str(e.value)
    if isinstance(cameras, list) and all(isinstance(c, str) for c in cameras):
        rclpy_names = pytest.importorskip("rclpy.validate_topic_name")
        bad = [c for c in cameras if c != "front"]
        with pytest.raises(Exception, match="Invalid topic name"):
            rclpy_names.validate_topic_name(f"{bad[0]}/camera_info")


def test_names_ros_takes_are_taken_and_an_integer_mounting_is_read_as_floats():
    names = ["front", "_rear", "cam_2", "Left"]
    good = {"rig.cameras": names}
    good.update({f"rig.{n}.mounting": [0.0, 0.1 * k, 0.0, 0.0, 0.0, 0.0, 1.0]
                 for k, n in enumerate(names)})  # fmt: skip
    good["rig.front.mounting"] = [0, 0, 0, 0, 0, 0, 1]  # (integers, as YAML reads them)
    cfg = build_config(*_values(good))
    assert [c.name for c in cfg.cameras] == names
    assert np.allclose(cfg.cameras[0].mount.R, np.eye(3)) and np.allclose(cfg.cameras[0].mount.c, 0)
    assert np.allclose(cfg.cameras[2].mount.position, [0.0, 0.2, 0.0])
    with pytest.raises(ConfigError, match=r"rig\.front\.mounting must be 7 finite numbers"):
        build_config(*_values({**good, "rig.front.mounting": ["0"] * 6 + ["1"]}))


def test_the_node_takes_a_mounting_covariance(ros_context):
    """The node declares rig.<camera>.mounting_covariance and passes it to the rig's
    mounting; without it the mounting is exact."""
    pytest.importorskip("rclpy")
    from rclpy.parameter import Parameter

    from rs_localizer.ros.node import RSLocalizerNode

    cov = np.diag([1e-6, 1e-6, 1e-6, 1e-8, 1e-8, 1e-8])
    params = {
        "warmup": False,
        "rig.cameras": ["front", "left"],
        "rig.front.mounting": [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
        "rig.left.mounting": [0.0, 0.1, 0.0, 0.0, 0.0, 0.0, 1.0],
        "rig.left.mounting_covariance": [float(x) for x in cov.ravel()],
    }
    overrides = [Parameter(k, value=v) for k, v in params.items()]
    node = RSLocalizerNode("rs_localizer", context=ros_context, parameter_overrides=overrides)
    try:
        front, left = (c.mount for c in node.mode.cfg.cameras)
        assert front.covariance is None
        assert np.allclose(np.diag(left.covariance), [1e-8] * 3 + [1e-6] * 3)
    finally:
        node.destroy_node()


def test_the_node_caps_clouds_and_images_to_the_one_max_points(ros_context):
    """The node's ``max_points`` caps each camera's clouds (its ``CameraInput``) and the rows
    its front end finds in an image (the rig's ``LocalizerSettings.max_points``) alike."""
    pytest.importorskip("rclpy")
    from rclpy.parameter import Parameter

    from rs_localizer.ros.node import RSLocalizerNode

    params = {
        "warmup": False,
        "max_points": 37,
        "rig.cameras": ["front", "left"],
        "rig.front.mounting": [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
        "rig.left.mounting": [0.0, 0.1, 0.0, 0.0, 0.0, 0.0, 1.0],
    }
    overrides = [Parameter(k, value=v) for k, v in params.items()]
    node = RSLocalizerNode("rs_localizer", context=ros_context, parameter_overrides=overrides)
    try:
        assert node.mode.rig.settings.max_points == 37
        assert [node.inputs[n].max_points for n in ("front", "left")] == [37, 37]
    finally:
        node.destroy_node()


def test_a_running_rig_takes_the_estimators_parameters_and_says_why_not_the_others():
    """The parameters a running rig takes are those of its estimator, tracking and gyro,
    ``time_reset_threshold``, ``max_points``, ``queue_size`` and ``camera_info_wait``; every
    other one that ROS lets
    change is refused with a clause naming it and why (restart, or not used by the rig)."""
    from rs_localizer.ros.config import RIG_RUN_TIME_PARAMETERS, rig_change_refused
    from rs_localizer.ros.params import PARAMETERS

    estimator = {"ransac.threshold_px", "ransac.min_inliers", "refine", "max_angular_velocity",
                 "max_linear_velocity", "motion_prior.angular_velocity_sigma",
                 "correlated_noise.sigma_px"}  # fmt: skip
    others = {"tracking.enabled", "tracking.lag", "imu.rotation", "imu.time_offset",
              "max_points", "queue_size", "time_reset_threshold", "camera_info_wait"}  # fmt: skip
    assert estimator | others <= RIG_RUN_TIME_PARAMETERS
    assert rig_change_refused(sorted(RIG_RUN_TIME_PARAMETERS)) is None
    for name, par in PARAMETERS.items():
        if par.read_only or name in RIG_RUN_TIME_PARAMETERS:
            continue
        why = rig_change_refused(["max_points", name])
        assert why is not None and why.count(name) >= 1 and ";" not in why, (name, why)
        assert why.startswith(
            (f"restart the node to change {name}: ", f"{name} is not used in the rig mode: ")
        ), why
    assert "rs.stamp_row: each rig camera's rolling-shutter timing" in rig_change_refused(
        ["rs.stamp_row"]
    )
    assert rig_change_refused(["solver", "base_frame"]).count(";") == 1


def test_a_refused_rig_camera_value_is_named_again_when_configure_is_retried(ros_context):
    """A rig camera's value outside its range refuses the configure, naming the parameter; a
    configure retried names it again (the camera's parameters declared before it are not
    declared twice)."""
    pytest.importorskip("rclpy")
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from rs_localizer.ros.declare import declare_parameters
    from rs_localizer.ros.rig_node import rig_values

    overrides = [Parameter("rig.cameras", value=["front"]),
                 Parameter("rig.front.line_delay", value=0.5)]  # fmt: skip
    node = Node("rig_params", context=ros_context, parameter_overrides=overrides)
    try:
        declare_parameters(node, RIG_PARAMETERS, dynamic=("rig.cameras",))
        for _ in range(2):
            with pytest.raises(RuntimeError, match=r"rig\.front\.line_delay"):
                rig_values(node, {})
        assert node.has_parameter("rig.front.mounting_covariance")
    finally:
        node.destroy_node()
