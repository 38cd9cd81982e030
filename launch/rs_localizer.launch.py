"""Launch rs_localizer_node on a ROS 2 install (after `colcon build`).

    ros2 launch rs_localizer rs_localizer.launch.py [namespace:=camera]
        [params_file:=/path/to/params.yaml] [image_topic:=image_raw] [log_level:=info]
        [cameras:="front rear"] [lifecycle:=false] [rviz:=false]

Inputs are <namespace>/correspondences, <namespace>/keypoints, <namespace>/camera_info and,
with ``frontend: aruco|features|board`` in the parameter file, <namespace>/<image_topic>.

``cameras`` (namespaces separated by spaces or commas, relative to ``namespace`` unless they
start with ``/``) runs one localizer per camera in this one process (the node's ``cameras``
parameter): inputs and outputs under <namespace>/<camera>/. ``lifecycle:=true`` starts the
managed node ``rs_localizer_lifecycle_node`` (configure and activate it with ``ros2 lifecycle``
or a lifecycle manager). ``rviz:=true`` also opens RViz with the package's configuration
(rviz/rs_localizer.rviz: the camera's pose and path, the markers, the debug image; topics under
/camera, fixed frame map).

Unless FASTRTPS_DEFAULT_PROFILES_FILE or FASTDDS_DEFAULT_PROFILES_FILE is set, every process this
launch starts (and those started after it in an including launch) gets the package's Fast DDS
profile (share/rs_localizer/config/fastdds_profile.xml: a shared-memory segment large enough for
1280x720 RGB images at 30 Hz; docs/node.md "Image input"). A camera driver started in the same
launch file benefits too; one started elsewhere needs the variable exported.
"""

import os

from launch.actions import DeclareLaunchArgument, OpaqueFunction, SetEnvironmentVariable
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

from launch import LaunchDescription


def camera_list(text: str) -> list:
    """``"front, rear /abs"`` -> ``["front", "rear", "/abs"]``."""
    return [c for c in text.replace(",", " ").split() if c]


def dds_profile_actions(environ=os.environ) -> list:
    """Set FASTRTPS_DEFAULT_PROFILES_FILE to the package's profile unless the user chose one
    (or another middleware)."""
    if any(
        environ.get(k) for k in ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")
    ):
        return []
    if not environ.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp").startswith("rmw_fastrtps"):
        return []
    profile = PathJoinSubstitution(
        [FindPackageShare("rs_localizer"), "config", "fastdds_profile.xml"]
    )
    return [SetEnvironmentVariable("FASTRTPS_DEFAULT_PROFILES_FILE", profile)]


def _node(context):
    cameras = camera_list(LaunchConfiguration("cameras").perform(context))
    lifecycle = LaunchConfiguration("lifecycle").perform(context).lower() in ("1", "true", "yes")
    parameters = [LaunchConfiguration("params_file")]
    if cameras:
        parameters.append({"cameras": cameras})
    return dds_profile_actions() + [
        Node(
            package="rs_localizer",
            executable="rs_localizer_lifecycle_node" if lifecycle else "rs_localizer_node",
            name="rs_localizer",
            namespace=LaunchConfiguration("namespace"),
            parameters=parameters,
            remappings=[("image", LaunchConfiguration("image_topic"))],
            arguments=["--ros-args", "--log-level", LaunchConfiguration("log_level")],
            output="screen",
            emulate_tty=True,
        )
    ]


def _rviz(context):
    """RViz with the package's configuration when ``rviz:=true``."""
    if LaunchConfiguration("rviz").perform(context).lower() not in ("1", "true", "yes"):
        return []
    config = PathJoinSubstitution([FindPackageShare("rs_localizer"), "rviz", "rs_localizer.rviz"])
    return [Node(package="rviz2", executable="rviz2", arguments=["-d", config], output="screen")]


def generate_launch_description():
    default_params = PathJoinSubstitution(
        [FindPackageShare("rs_localizer"), "config", "rs_localizer.yaml"]
    )
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                "namespace",
                default_value="camera",
                description="namespace of the input and output topics",
            ),
            DeclareLaunchArgument(
                "params_file",
                default_value=default_params,
                description="parameter file (see config/rs_localizer.yaml)",
            ),
            DeclareLaunchArgument(
                "image_topic",
                default_value="image_raw",
                description="image topic (used when the frontend parameter is set)",
            ),
            DeclareLaunchArgument("log_level", default_value="info"),
            DeclareLaunchArgument(
                "cameras",
                default_value="",
                description="camera namespaces (spaces or commas): one localizer "
                "per camera in one process; empty = one camera in namespace",
            ),
            DeclareLaunchArgument(
                "lifecycle", default_value="false", description="start the managed (lifecycle) node"
            ),
            OpaqueFunction(function=_node),
            DeclareLaunchArgument(
                "rviz",
                default_value="false",
                description="also open RViz with rviz/rs_localizer.rviz (namespace camera)",
            ),
            OpaqueFunction(function=_rviz),
        ]
    )
