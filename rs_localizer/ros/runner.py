"""The entry points of ``rs_localizer_node`` (:func:`main`) and ``rs_localizer_lifecycle_node``
(:func:`lifecycle_main`): one node, or one node per camera in one process.

The ``cameras`` parameter (string array, read once at start; from the parameter file or
``-p cameras:="[front, rear]"``) lists camera namespaces. Empty (the default): one node, as
usual. Otherwise the process runs one localizer node per entry, named like the single node
would be (``rs_localizer`` or the ``__node`` remap) in the namespace ``<process namespace>/
<entry>`` (an entry starting with ``/`` is absolute), all on one executor: one Python
interpreter, one numba JIT (the kernels compile or load once), and one copy of each map file
that several cameras name (:mod:`rs_localizer.frontends.shared`). Each camera node gets every
command-line ROS argument except the namespace and node-name remaps (so ``--params-file``,
``-p`` and topic remaps such as ``-r image:=image_raw`` apply to every camera) and reads its own
section of the parameter file too, e.g. ``/robot/front/rs_localizer: ros__parameters:
{camera_frame: front_optical}``.

With ``rig.cameras`` set (the rig mode, docs/rig_node.md) the process runs one node
(:class:`~rs_localizer.ros.node.RSLocalizerNode`; ``rs_localizer_lifecycle_node``:
:class:`~rs_localizer.ros.lifecycle.RSLocalizerLifecycleNode`) posing all of the rig's cameras
as one body, whatever ``cameras`` says.

From a checkout: ``python -m rs_localizer.ros.runner --ros-args ...`` (``rs_localizer_node``) or
``python -m rs_localizer.ros.runner rs_localizer_lifecycle_node --ros-args ...``.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

import rclpy

from .core import names_a_rig
from .lifecycle import RSLocalizerLifecycleNode
from .node import RSLocalizerNode

__all__ = [
    "NODES",
    "camera_namespaces",
    "lifecycle_main",
    "main",
    "node_cli_args",
    "read_cameras",
    "read_rig_cameras",
    "run",
]

#: executable name -> the node's class (one camera or, with ``rig.cameras`` set, a rig)
NODES = {
    "rs_localizer_node": RSLocalizerNode,
    "rs_localizer_lifecycle_node": RSLocalizerLifecycleNode,
}


def camera_namespaces(cameras: Sequence[str], base_namespace: str = "/") -> list[str]:
    """Absolute namespaces of the ``cameras`` entries: relative ones under ``base_namespace``.

    Raises:
        ValueError: an empty entry or a namespace listed twice.
    """
    base = "/" + base_namespace.strip("/") if base_namespace.strip("/") else ""
    out = []
    for c in cameras:
        c = str(c).strip()
        if not c.strip("/"):
            raise ValueError(f"cameras: empty camera namespace in {list(cameras)}")
        ns = "/" + c.strip("/") if c.startswith("/") else f"{base}/{c.strip('/')}"
        if ns in out:
            raise ValueError(f"cameras: namespace {ns} listed twice")
        out.append(ns)
    return out


def _is_name_remap(rule: str) -> bool:
    target = rule.split(":=", 1)[0]
    target = target.split(":", 1)[-1] if ":" in target else target  # node-targeted: n:__ns
    return target in ("__ns", "__node", "__name")


def node_cli_args(argv: Sequence[str]) -> list[str]:
    """The ROS arguments of ``argv`` (every ``--ros-args`` section) without the namespace and
    node-name remaps, as one ``--ros-args`` list for a node created with
    ``use_global_arguments=False``."""
    out, in_ros, skip = [], False, False
    argv = list(argv)
    for k, a in enumerate(argv):
        if skip:
            skip = False
            continue
        if a == "--ros-args":
            in_ros = True
            continue
        if a == "--":
            in_ros = False
            continue
        if not in_ros:
            continue
        if a in ("-r", "--remap") and k + 1 < len(argv):
            if not _is_name_remap(argv[k + 1]):
                out += [a, argv[k + 1]]
            skip = True
            continue
        out.append(a)
    return ["--ros-args", *out] if out else []


def read_cameras(node_name: str = "rs_localizer") -> tuple[list[str], str, str]:
    """``(cameras, namespace, node name)`` as the single node would see them (its parameter
    file sections and remaps), via a short-lived probe node."""
    from rcl_interfaces.msg import ParameterDescriptor
    from rclpy.exceptions import ParameterUninitializedException
    from rclpy.parameter import Parameter

    probe = rclpy.create_node(node_name)
    try:
        probe.declare_parameter(
            "cameras",
            Parameter.Type.STRING_ARRAY,
            ParameterDescriptor(
                description="camera namespaces: one localizer per camera in this process",
                read_only=True,
            ),
        )
        try:
            cams = list(probe.get_parameter("cameras").value or [])
        except ParameterUninitializedException:
            cams = []
        return cams, probe.get_namespace(), probe.get_name()
    finally:
        probe.destroy_node()


def read_rig_cameras(node_name: str = "rs_localizer") -> list[str]:
    """The ``rig.cameras`` parameter as the node would see it (empty: no rig,
    :func:`.core.names_a_rig`), via a short-lived probe node; a value of another type than a
    list of names (``front`` for ``[front]``, integers) as a one-element list, for the node's
    rig mode to refuse naming the fix."""
    from rcl_interfaces.msg import ParameterDescriptor

    probe = rclpy.create_node(node_name)
    try:
        d = ParameterDescriptor(read_only=True, dynamic_typing=True)
        probe.declare_parameter("rig.cameras", None, d)
        value = probe.get_parameter("rig.cameras").value
        if not names_a_rig(value):
            return []
        return list(value) if isinstance(value, (list, tuple)) else [value]
    finally:
        probe.destroy_node()


def run(prog: str = "rs_localizer_node", args: list[str] | None = None) -> int:
    """Initialize rclpy with ``args`` (default ``sys.argv``), create the node(s) of the
    executable ``prog`` (a key of :data:`NODES`; see the module docstring) and spin them until
    shutdown. Returns the exit code (1 with a one-line error for invalid parameters).

    Raises:
        KeyError: ``prog`` is not in :data:`NODES`.
    """
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    from .dds_profile import apply_default_profile, profile_in_effect

    node_class = NODES[prog]
    argv = sys.argv if args is None else args
    apply_default_profile()  # (before the first participant: images over shared memory)
    rclpy.init(args=argv)
    nodes = []
    executor = None
    try:
        cams, base_ns, name = read_cameras()
        if cams and not read_rig_cameras():  # (a rig: one node for all of its cameras)
            cli = node_cli_args(argv)
            try:
                namespaces = camera_namespaces(cams, base_ns)
            except ValueError as e:
                raise RuntimeError(str(e)) from None
            for ns in namespaces:
                nodes.append(
                    node_class(name, namespace=ns, use_global_arguments=False, cli_args=cli)
                )
            from ..frontends.shared import SHARED_MAPS

            nodes[0].get_logger().info(
                f"{len(nodes)} cameras in this process: {', '.join(namespaces)}; "
                f"{SHARED_MAPS.loads} map files loaded ({len(SHARED_MAPS)} in use)"
            )
        else:
            nodes.append(node_class())
        dds = profile_in_effect()  # (Fast DDS's own XML errors do not say what is in effect)
        (nodes[0].get_logger().info if dds.ok else nodes[0].get_logger().warning)(dds.message())
        executor = SingleThreadedExecutor()
        for n in nodes:
            executor.add_node(n)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RuntimeError as e:  # invalid parameters at start: a clear message, no traceback
        print(f"{prog}: error: {e}", file=sys.stderr)
        return 1
    finally:
        if executor is not None:
            executor.shutdown(timeout_sec=1.0)
        for n in nodes:
            n.destroy_node()
        rclpy.try_shutdown()
    return 0


def main(args: list[str] | None = None) -> int:
    """Entry point of ``rs_localizer_node`` (``ros2 run rs_localizer rs_localizer_node``): one
    node, one per camera namespace in the ``cameras`` parameter, or the rig node."""
    return run("rs_localizer_node", args)


def lifecycle_main(args: list[str] | None = None) -> int:
    """Entry point of ``rs_localizer_lifecycle_node``: the managed node(s), as :func:`main`."""
    return run("rs_localizer_lifecycle_node", args)


if __name__ == "__main__":
    sys.exit(run(sys.argv[1] if sys.argv[1:2] and sys.argv[1] in NODES else "rs_localizer_node"))
