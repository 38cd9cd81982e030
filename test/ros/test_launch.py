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
    (node,) = opaque[0].kwargs["function"](context)
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
