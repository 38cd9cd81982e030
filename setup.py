"""ament_python package rs_localizer (works with colcon and with plain pip).

pip:    pip install -e '.[ros]'   (ROS 2 Jazzy wheels from PyPI + rosbags)
colcon: colcon build --packages-select rs_localizer   (executables in lib/rs_localizer/)
"""

from glob import glob

from setuptools import find_packages, setup

package_name = "rs_localizer"

setup(
    name=package_name,
    version="0.1.0",
    # the library only: benchmarks/ (python -m benchmarks.X from a checkout), test/ and tools/
    # are not installed
    packages=find_packages(include=[package_name, f"{package_name}.*"]),
    package_data={"rs_localizer": ["scenes/*.yaml", "ros/fastdds_profile.xml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{package_name}"]),
        (f"share/{package_name}", ["package.xml"]),
        (f"share/{package_name}/config", glob("config/*.yaml")),
        # the Fast DDS profile the launch file applies (rs_localizer/ros/dds_profile.py)
        (f"share/{package_name}/config", ["rs_localizer/ros/fastdds_profile.xml"]),
        (f"share/{package_name}/launch", glob("launch/*.launch.py")),
        # RViz configuration and Foxglove layout of the node's outputs
        (f"share/{package_name}/rviz", glob("rviz/*.rviz")),
        (f"share/{package_name}/foxglove", glob("foxglove/*.json")),
        # the sample bags of `rs-localizer demo` (found via share/ outside the source tree)
        (f"share/{package_name}/data/sample", glob("data/sample/*")),
        (f"share/{package_name}/data/sample_images", glob("data/sample_images/*")),
    ],
    python_requires=">=3.10",
    # matplotlib: experiment plots (and Pillow for the CLI's image files);
    # pyyaml: parameter files, marker maps, boards and scenes; scikit-image: the photographs on
    # the textured_room walls (renderer); tqdm: progress bars of the long CLI steps
    install_requires=[
        "setuptools",
        "numpy",
        "scipy",
        "opencv-python-headless",
        "numba",
        "matplotlib",
        "pyyaml",
        "scikit-image",
        "tqdm",
        # the AprilTag 3 C library with Python bindings (AprilTag marker families; the distro
        # route uses Debian's python3-apriltag instead, package.xml's key apriltag)
        "pupil-apriltags",
    ],
    extras_require={
        # ROS 2 Jazzy from PyPI (never mix with the un-prefixed ros-* wheels: those are Kilted)
        "ros": [
            "ros-jazzy-rclpy",
            "ros-jazzy-common-interfaces",
            "ros-jazzy-rmw-fastrtps-cpp",
            "rosbags>=0.10",
        ],
        # benchmarks (and experiments): one BLAS thread (threadpoolctl); PoseLib, the
        # global-shutter reference of the benchmarks, experiments and tests and an optional P3P
        # backend (the default P3P is our own Lambda Twist; without PoseLib the "poselib"
        # backend falls back to OpenCV)
        "bench": ["threadpoolctl", "poselib"],
        # feature maps from photos (rs-localizer map-features): COLMAP's Python bindings
        "mapping": ["pycolmap>=4.2"],
        # a live view in the Foxglove app without a ROS install (rs-localizer view): the
        # Foxglove SDK's WebSocket server
        "view": ["foxglove-sdk>=0.30"],
        "test": ["pytest", "hypothesis", "ruff>=0.17,<0.18"],
    },
    tests_require=["pytest"],
    zip_safe=True,
    maintainer="rs_localizer maintainers",
    maintainer_email="maintainer@example.com",
    description="Rolling-shutter camera localization from 2D-3D correspondences for ROS 2",
    license="BSD-3-Clause",
    entry_points={
        "console_scripts": [
            "rs_localizer_node = rs_localizer.ros.runner:main",
            "rs_localizer_lifecycle_node = rs_localizer.ros.runner:lifecycle_main",
            "rs-localizer = rs_localizer.cli:main",
        ],
    },
)
