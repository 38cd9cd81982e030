"""launch/rs_localizer.launch.py, evaluated against minimal stand-ins of ``launch`` and
``launch_ros`` (not in the PyPI wheels): the arguments become the right Node action."""

import importlib.util
import sys
import types
from pathlib import Path

import pytest

LAUNCH = Path(__file__).resolve().parents[2] / "launch" / "rs_localizer.launch.py"


class _Recorder:
    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


class _Config(_Recorder):
    def perform(self, context):
        return context[self.args[0]]


@pytest.fixture
def launch_file(monkeypatch):
    mods = {}
    for name in (
        "launch",
        "launch.actions",
        "launch.substitutions",
        "launch_ros",
        "launch_ros.actions",
        "launch_ros.substitutions",
    ):
        mods[name] = types.ModuleType(name)
        monkeypatch.setitem(sys.modules, name, mods[name])
    mods["launch"].LaunchDescription = lambda actions: list(actions)
    mods["launch.actions"].DeclareLaunchArgument = _Recorder
    mods["launch.actions"].OpaqueFunction = _Recorder
    mods["launch.actions"].SetEnvironmentVariable = _Recorder
    mods["launch.substitutions"].LaunchConfiguration = _Config
    mods["launch.substitutions"].PathJoinSubstitution = _Recorder
    mods["launch_ros.actions"].Node = _Recorder
    mods["launch_ros.substitutions"].FindPackageShare = _Recorder
    spec = importlib.util.spec_from_file_location("rs_localizer_launch", LAUNCH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _node(mod, **values):
    actions = mod.generate_launch_description()
    args = {a.args[0]: a.kwargs["default_value"] for a in actions if "default_value" in a.kwargs}
    assert {"namespace", "params_file", "image_topic", "log_level", "cameras", "lifecycle"} <= set(
        args
    )
    context = {**args, **values}
    opaque = [a for a in actions if "function" in a.kwargs]
    *env, node = opaque[0].kwargs["function"](context)
    assert all(isinstance(e, _Recorder) and e.args[0].endswith("PROFILES_FILE") for e in env)
    return node.kwargs


def test_one_camera_by_default(launch_file):
    kw = _node(launch_file)
    assert kw["executable"] == "rs_localizer_node" and kw["name"] == "rs_localizer"
    assert len(kw["parameters"]) == 1  # the parameter file only: no cameras parameter


def test_camera_list_and_lifecycle(launch_file):
    kw = _node(launch_file, cameras="front, rear /abs/cam3", lifecycle="true")
    assert kw["executable"] == "rs_localizer_lifecycle_node"
    assert kw["parameters"][1] == {"cameras": ["front", "rear", "/abs/cam3"]}
    assert launch_file.camera_list("  ") == []


def test_dds_profile_unless_the_user_set_one(launch_file):
    """The package's Fast DDS profile goes to every process of the launch, unless the user set
    a profile file or another middleware."""
    (env,) = launch_file.dds_profile_actions({})
    assert env.args[0] == "FASTRTPS_DEFAULT_PROFILES_FILE"
    assert env.args[1].args[0][1:] == ["config", "fastdds_profile.xml"]
    assert launch_file.dds_profile_actions({"FASTDDS_DEFAULT_PROFILES_FILE": "/x.xml"}) == []
    assert launch_file.dds_profile_actions({"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}) == []


def test_rviz_argument_opens_the_packaged_configuration(launch_file):
    actions = launch_file.generate_launch_description()
    args = {a.args[0]: a.kwargs["default_value"] for a in actions if "default_value" in a.kwargs}
    assert args["rviz"] == "false"
    rviz = [a for a in actions if "function" in a.kwargs][1].kwargs["function"]
    assert rviz({**args}) == []
    (node,) = rviz({**args, "rviz": "true"})
    assert node.kwargs["executable"] == "rviz2" and node.kwargs["arguments"][0] == "-d"
    config = node.kwargs["arguments"][1].args[0]
    assert config[1:] == ["rviz", "rs_localizer.rviz"]
    assert (LAUNCH.parents[1] / "rviz" / "rs_localizer.rviz").is_file()
