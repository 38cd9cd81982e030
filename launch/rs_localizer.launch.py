"""Launch rs_localizer_node on a ROS 2 install (after `colcon build`).

    ros2 launch rs_localizer rs_localizer.launch.py [namespace:=camera]
        [params_file:=/path/to/params.yaml] [image_topic:=image_raw] [log_level:=info]

Inputs are <namespace>/correspondences, <namespace>/keypoints, <namespace>/camera_info and,
with ``frontend: aruco|features`` in the parameter file, <namespace>/<image_topic>.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare


def generate_launch_description():
    default_params = PathJoinSubstitution(
        [FindPackageShare("rs_localizer"), "config", "rs_localizer.yaml"])
    return LaunchDescription([
        DeclareLaunchArgument("namespace", default_value="camera",
                              description="namespace of the input and output topics"),
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="parameter file (see config/rs_localizer.yaml)"),
        DeclareLaunchArgument("image_topic", default_value="image_raw",
                              description="image topic (used when the frontend parameter is set)"),
        DeclareLaunchArgument("log_level", default_value="info"),
        Node(
            package="rs_localizer",
            executable="rs_localizer_node",
            name="rs_localizer",
            namespace=LaunchConfiguration("namespace"),
            parameters=[LaunchConfiguration("params_file")],
            remappings=[("image", LaunchConfiguration("image_topic"))],
            arguments=["--ros-args", "--log-level", LaunchConfiguration("log_level")],
            output="screen",
            emulate_tty=True,
        ),
    ])
